"""MCP2510 instruction opcodes, register addresses, bit masks and reset values.

Every name follows the Microchip MCP2510 data sheet (DS21291) spelling, upper-cased. All values
are plain module-level ``int`` constants so that ``rtl/mcp2510_pkg.vhd`` can be checked against
this file constant by constant. Section numbers refer to DS21291 (the MCP2515 data sheet,
DS21801/DS20001801, uses the same layout one section later from "Register Map" onwards).

Conventions:

* ``<REG>_<BIT>`` is a single-bit mask (e.g. ``CANINTF_RX0IF = 0x01``).
* ``<REG>_<FIELD>_MASK`` / ``<REG>_<FIELD>_SHIFT`` describe a multi-bit field.
* ``<REG>_<BIT>_BIT`` is the index of a single bit, for the RTL that tests one bit of a byte.
* ``<REG>_RESET`` is the value after power-on / RESET (bits the data sheet lists as 'x',
  unknown, are modelled as 0).
* ``TXBNxxx`` / ``RXBNxxx`` names describe the per-buffer layout (offsets from the buffer's
  control register) and the bits of the n-th buffer's registers.
"""

from __future__ import annotations

# --------------------------------------------------------------------------------------------
# SPI instruction set (DS21291 section 11, Table 11-1)
# --------------------------------------------------------------------------------------------
INSTR_RESET = 0xC0
INSTR_READ = 0x03
INSTR_WRITE = 0x02
INSTR_RTS = 0x80  # 1000 0nnn: n bit 0 = TXB0, bit 1 = TXB1, bit 2 = TXB2
INSTR_RTS_MASK = 0xF8  # opcode & INSTR_RTS_MASK == INSTR_RTS
INSTR_RTS_TXB0 = 0x81
INSTR_RTS_TXB1 = 0x82
INSTR_RTS_TXB2 = 0x84
INSTR_RTS_ALL = 0x87
INSTR_READ_STATUS = 0xA0
INSTR_BIT_MODIFY = 0x05

# MCP2515-only instructions (DS21801 Table 12-1). They do NOT exist on the MCP2510; the model
# rejects them. Listed so that the RTL package can assert it never uses them.
INSTR_MCP2515_READ_RX_BUFFER = 0x90  # 1001 0nm0: 0x90, 0x92, 0x94, 0x96
INSTR_MCP2515_READ_RX_BUFFER_MASK = 0xF9
INSTR_MCP2515_LOAD_TX_BUFFER = 0x40  # 0100 0abc: 0x40 .. 0x45
INSTR_MCP2515_LOAD_TX_BUFFER_LAST = 0x45
INSTR_MCP2515_RX_STATUS = 0xB0

# --------------------------------------------------------------------------------------------
# READ STATUS output byte (DS21291 section 11, READ STATUS figure; same layout as DS21801
# Figure 12-8)
# --------------------------------------------------------------------------------------------
STATUS_RX0IF = 0x01  # CANINTF.RX0IF
STATUS_RX1IF = 0x02  # CANINTF.RX1IF
STATUS_TXB0_TXREQ = 0x04  # TXB0CTRL.TXREQ
STATUS_TX0IF = 0x08  # CANINTF.TX0IF
STATUS_TXB1_TXREQ = 0x10  # TXB1CTRL.TXREQ
STATUS_TX1IF = 0x20  # CANINTF.TX1IF
STATUS_TXB2_TXREQ = 0x40  # TXB2CTRL.TXREQ
STATUS_TX2IF = 0x80  # CANINTF.TX2IF

# --------------------------------------------------------------------------------------------
# Register map (DS21291 Table 11-1 / "Register map"); 7-bit address space 0x00-0x7F
# --------------------------------------------------------------------------------------------
REG_ADDR_MAX = 0x7F

# Acceptance filters: SIDH, SIDL, EID8, EID0 each
RXF0SIDH = 0x00
RXF0SIDL = 0x01
RXF0EID8 = 0x02
RXF0EID0 = 0x03
RXF1SIDH = 0x04
RXF1SIDL = 0x05
RXF1EID8 = 0x06
RXF1EID0 = 0x07
RXF2SIDH = 0x08
RXF2SIDL = 0x09
RXF2EID8 = 0x0A
RXF2EID0 = 0x0B
BFPCTRL = 0x0C
TXRTSCTRL = 0x0D
CANSTAT = 0x0E  # mirrored at every xEh address
CANCTRL = 0x0F  # mirrored at every xFh address
RXF3SIDH = 0x10
RXF3SIDL = 0x11
RXF3EID8 = 0x12
RXF3EID0 = 0x13
RXF4SIDH = 0x14
RXF4SIDL = 0x15
RXF4EID8 = 0x16
RXF4EID0 = 0x17
RXF5SIDH = 0x18
RXF5SIDL = 0x19
RXF5EID8 = 0x1A
RXF5EID0 = 0x1B
TEC = 0x1C
REC = 0x1D
# Acceptance masks
RXM0SIDH = 0x20
RXM0SIDL = 0x21
RXM0EID8 = 0x22
RXM0EID0 = 0x23
RXM1SIDH = 0x24
RXM1SIDL = 0x25
RXM1EID8 = 0x26
RXM1EID0 = 0x27
# Bit timing, interrupts, errors
CNF3 = 0x28
CNF2 = 0x29
CNF1 = 0x2A
CANINTE = 0x2B
CANINTF = 0x2C
EFLG = 0x2D
# Transmit buffers (14 bytes each: CTRL, SIDH, SIDL, EID8, EID0, DLC, D0..D7)
TXB0CTRL = 0x30
TXB0SIDH = 0x31
TXB0SIDL = 0x32
TXB0EID8 = 0x33
TXB0EID0 = 0x34
TXB0DLC = 0x35
TXB0D0 = 0x36
TXB0D7 = 0x3D
TXB1CTRL = 0x40
TXB1SIDH = 0x41
TXB1SIDL = 0x42
TXB1EID8 = 0x43
TXB1EID0 = 0x44
TXB1DLC = 0x45
TXB1D0 = 0x46
TXB1D7 = 0x4D
TXB2CTRL = 0x50
TXB2SIDH = 0x51
TXB2SIDL = 0x52
TXB2EID8 = 0x53
TXB2EID0 = 0x54
TXB2DLC = 0x55
TXB2D0 = 0x56
TXB2D7 = 0x5D
# Receive buffers (14 bytes each, same layout)
RXB0CTRL = 0x60
RXB0SIDH = 0x61
RXB0SIDL = 0x62
RXB0EID8 = 0x63
RXB0EID0 = 0x64
RXB0DLC = 0x65
RXB0D0 = 0x66
RXB0D7 = 0x6D
RXB1CTRL = 0x70
RXB1SIDH = 0x71
RXB1SIDL = 0x72
RXB1EID8 = 0x73
RXB1EID0 = 0x74
RXB1DLC = 0x75
RXB1D0 = 0x76
RXB1D7 = 0x7D

# Offsets inside a filter/mask group and inside a TX/RX buffer
ID_SIDH_OFFSET = 0
ID_SIDL_OFFSET = 1
ID_EID8_OFFSET = 2
ID_EID0_OFFSET = 3
BUF_CTRL_OFFSET = 0
BUF_SIDH_OFFSET = 1
BUF_SIDL_OFFSET = 2
BUF_EID8_OFFSET = 3
BUF_EID0_OFFSET = 4
BUF_DLC_OFFSET = 5
BUF_D0_OFFSET = 6
BUF_SIZE = 14  # CTRL .. D7
TXB_STRIDE = 0x10
NUM_TX_BUFFERS = 3
NUM_RX_BUFFERS = 2

# --------------------------------------------------------------------------------------------
# Register bits
# --------------------------------------------------------------------------------------------
# BFPCTRL - RXnBF pin control and status (DS21291 section 4, register 4-?; BFPCTRL)
BFPCTRL_B0BFM = 0x01  # 1 = RX0BF is an interrupt output (low while RX0IF), 0 = digital output
BFPCTRL_B1BFM = 0x02
BFPCTRL_B0BFE = 0x04  # 1 = pin function enabled, 0 = pin high impedance
BFPCTRL_B1BFE = 0x08
BFPCTRL_B0BFS = 0x10  # pin level in digital-output mode
BFPCTRL_B1BFS = 0x20
BFPCTRL_WRITE_MASK = 0x3F
BFPCTRL_RESET = 0x00

# TXRTSCTRL - TXnRTS pin control and status
TXRTSCTRL_B0RTSM = 0x01  # 1 = TX0RTS pin requests transmission of TXB0 (falling edge)
TXRTSCTRL_B1RTSM = 0x02
TXRTSCTRL_B2RTSM = 0x04
TXRTSCTRL_B0RTS = 0x08  # read-only: TX0RTS pin level in digital-input mode
TXRTSCTRL_B1RTS = 0x10
TXRTSCTRL_B2RTS = 0x20
TXRTSCTRL_WRITE_MASK = 0x07
TXRTSCTRL_RESET = 0x00  # BnRTS bits follow the pins (idle high with BnRTSM = 0 -> read 1)

# CANSTAT
CANSTAT_OPMOD_MASK = 0xE0
CANSTAT_OPMOD_SHIFT = 5
CANSTAT_ICOD_MASK = 0x0E
CANSTAT_ICOD_SHIFT = 1
CANSTAT_RESET = 0x80  # configuration mode, no interrupt

# CANCTRL
CANCTRL_REQOP_MASK = 0xE0
CANCTRL_REQOP_SHIFT = 5
CANCTRL_ABAT = 0x10
CANCTRL_OSM_MCP2515 = 0x08  # one-shot mode exists on the MCP2515 only; unimplemented here
CANCTRL_CLKEN = 0x04
CANCTRL_CLKPRE_MASK = 0x03
CANCTRL_WRITE_MASK = 0xF7
CANCTRL_RESET = 0x87  # REQOP = configuration, CLKEN = 1, CLKPRE = 11 (CLKOUT = F_OSC / 8)

# Operation modes (REQOP / OPMOD values)
OPMODE_NORMAL = 0
OPMODE_SLEEP = 1
OPMODE_LOOPBACK = 2
OPMODE_LISTEN_ONLY = 3
OPMODE_CONFIG = 4

# Interrupt codes (CANSTAT.ICOD), highest priority first after NONE
ICOD_NONE = 0
ICOD_ERROR = 1
ICOD_WAKE = 2
ICOD_TXB0 = 3
ICOD_TXB1 = 4
ICOD_TXB2 = 5
ICOD_RXB0 = 6
ICOD_RXB1 = 7

# CNF1
CNF1_SJW_MASK = 0xC0
CNF1_SJW_SHIFT = 6
CNF1_BRP_MASK = 0x3F
CNF1_RESET = 0x00
# CNF2
CNF2_BTLMODE = 0x80
CNF2_SAM = 0x40
CNF2_PHSEG1_MASK = 0x38
CNF2_PHSEG1_SHIFT = 3
CNF2_PRSEG_MASK = 0x07
CNF2_RESET = 0x00
# CNF3
CNF3_SOF_MCP2515 = 0x80  # start-of-frame output: MCP2515 only, unimplemented on the MCP2510
CNF3_WAKFIL = 0x40
CNF3_PHSEG2_MASK = 0x07
CNF3_WRITE_MASK = 0x47
CNF3_RESET = 0x00

# CANINTE / CANINTF (same bit positions)
CANINTE_RX0IE = 0x01
CANINTE_RX1IE = 0x02
CANINTE_TX0IE = 0x04
CANINTE_TX1IE = 0x08
CANINTE_TX2IE = 0x10
CANINTE_ERRIE = 0x20
CANINTE_WAKIE = 0x40
CANINTE_MERRE = 0x80
CANINTE_RESET = 0x00
CANINTF_RX0IF = 0x01
CANINTF_RX1IF = 0x02
CANINTF_TX0IF = 0x04
CANINTF_TX1IF = 0x08
CANINTF_TX2IF = 0x10
CANINTF_ERRIF = 0x20
CANINTF_ERRIF_BIT = 5
CANINTF_WAKIF = 0x40
CANINTF_MERRF = 0x80
CANINTF_RESET = 0x00

# EFLG
EFLG_EWARN = 0x01  # TEC or REC >= 96
EFLG_RXWAR = 0x02  # REC >= 96
EFLG_TXWAR = 0x04  # TEC >= 96
EFLG_RXEP = 0x08  # REC >= 128
EFLG_TXEP = 0x10  # TEC >= 128
EFLG_TXBO = 0x20  # bus-off
EFLG_TXBO_BIT = 5
EFLG_RX0OVR = 0x40  # RXB0 overflow; host may clear, never set
EFLG_RX1OVR = 0x80  # RXB1 overflow; host may clear, never set
EFLG_OVR_MASK = 0xC0
EFLG_RESET = 0x00
ERROR_WARNING_LIMIT = 96
ERROR_PASSIVE_LIMIT = 128

TEC_RESET = 0x00
REC_RESET = 0x00

# TXBnCTRL
TXBNCTRL_ABTF = 0x40  # read-only: aborted (ABAT)
TXBNCTRL_MLOA = 0x20  # read-only: lost arbitration
TXBNCTRL_TXERR = 0x10  # read-only: bus error during transmission
TXBNCTRL_TXREQ = 0x08
TXBNCTRL_TXP_MASK = 0x03  # 3 = highest priority
TXBNCTRL_WRITE_MASK = 0x0B
TXBNCTRL_RESET = 0x00
# TXBnSIDL
TXBNSIDL_SID_MASK = 0xE0
TXBNSIDL_EXIDE = 0x08
TXBNSIDL_EID_MASK = 0x03
TXBNSIDL_WRITE_MASK = 0xEB
# TXBnDLC
TXBNDLC_RTR = 0x40
TXBNDLC_DLC_MASK = 0x0F
TXBNDLC_WRITE_MASK = 0x4F

# RXBnCTRL
RXBNCTRL_RXM_MASK = 0x60
RXBNCTRL_RXM_SHIFT = 5
RXBNCTRL_RXRTR = 0x08  # read-only: remote frame received
RXB0CTRL_BUKT = 0x04  # rollover RXB0 -> RXB1 enable
RXB0CTRL_BUKT1 = 0x02  # read-only copy of BUKT
RXB0CTRL_FILHIT0 = 0x01  # read-only: 0 = RXF0, 1 = RXF1
RXB0CTRL_WRITE_MASK = 0x64
RXB0CTRL_RESET = 0x00
RXB1CTRL_FILHIT_MASK = 0x07  # read-only: 0..5 = RXF0..RXF5 (0/1 after a rollover)
RXB1CTRL_WRITE_MASK = 0x60
RXB1CTRL_RESET = 0x00
# RXM values
RXM_VALID_FILTERED = 0  # standard and extended frames that pass a filter
RXM_STD_ONLY = 1  # standard frames that pass a filter
RXM_EXT_ONLY = 2  # extended frames that pass a filter
RXM_ANY = 3  # masks and filters off, every frame
# RXBnSIDL
RXBNSIDL_SRR = 0x10  # standard remote frame
RXBNSIDL_IDE = 0x08  # extended frame
# RXBnDLC
RXBNDLC_RTR = 0x40  # extended remote frame

# RXFnSIDL / RXMnSIDL
RXFNSIDL_EXIDE = 0x08  # filter applies to extended (1) or standard (0) frames only
RXFNSIDL_WRITE_MASK = 0xEB
RXMNSIDL_WRITE_MASK = 0xE3

# --------------------------------------------------------------------------------------------
# Timing (DS21291 section 8 "Oscillator", section 12 "Electrical characteristics")
# --------------------------------------------------------------------------------------------
OST_OSC_CYCLES = 128  # oscillator start-up timer after power-up / RESET
SPI_SCK_MAX_HZ = 5_000_000  # "5 MHz at 4.5V I temp" (front page feature list)
BIT_TQ_MIN = 8  # nominal bit time 8..25 TQ (DS21291 section 5)
BIT_TQ_MAX = 25
IPT_TQ = 2  # information processing time; PS2 >= 2 TQ

# --------------------------------------------------------------------------------------------
# Register names, for messages
# --------------------------------------------------------------------------------------------
REG_NAMES: dict[int, str] = {}


def _build_names() -> None:
    for n, base in enumerate((RXF0SIDH, RXF1SIDH, RXF2SIDH, RXF3SIDH, RXF4SIDH, RXF5SIDH)):
        for off, suffix in enumerate(("SIDH", "SIDL", "EID8", "EID0")):
            REG_NAMES[base + off] = f"RXF{n}{suffix}"
    for n, base in enumerate((RXM0SIDH, RXM1SIDH)):
        for off, suffix in enumerate(("SIDH", "SIDL", "EID8", "EID0")):
            REG_NAMES[base + off] = f"RXM{n}{suffix}"
    REG_NAMES.update(
        {
            BFPCTRL: "BFPCTRL",
            TXRTSCTRL: "TXRTSCTRL",
            TEC: "TEC",
            REC: "REC",
            CNF3: "CNF3",
            CNF2: "CNF2",
            CNF1: "CNF1",
            CANINTE: "CANINTE",
            CANINTF: "CANINTF",
            EFLG: "EFLG",
        }
    )
    for kind, bases in (("TXB", (TXB0CTRL, TXB1CTRL, TXB2CTRL)), ("RXB", (RXB0CTRL, RXB1CTRL))):
        for n, base in enumerate(bases):
            names = ["CTRL", "SIDH", "SIDL", "EID8", "EID0", "DLC"] + [f"D{i}" for i in range(8)]
            for off, suffix in enumerate(names):
                REG_NAMES[base + off] = f"{kind}{n}{suffix}"
    for row in range(8):
        REG_NAMES[row * 0x10 + 0x0E] = "CANSTAT"
        REG_NAMES[row * 0x10 + 0x0F] = "CANCTRL"


_build_names()


def reg_name(addr: int) -> str:
    """Data-sheet name of a register address, e.g. ``reg_name(0x2C) == 'CANINTF'``."""
    return REG_NAMES.get(addr, f"0x{addr:02X}")


# --------------------------------------------------------------------------------------------
# Aliases with the shorter names used by rtl/mcp2510_pkg.vhd (MCP_<NAME>_C there)
# --------------------------------------------------------------------------------------------
TXBCTRL_ABTF = TXBNCTRL_ABTF
TXBCTRL_MLOA = TXBNCTRL_MLOA
TXBCTRL_TXERR = TXBNCTRL_TXERR
TXBCTRL_TXREQ = TXBNCTRL_TXREQ
RXBCTRL_RXM_SHIFT = RXBNCTRL_RXM_SHIFT
SIDL_SRR = RXBNSIDL_SRR
SIDL_IDE = RXBNSIDL_IDE
SIDL_EXIDE = TXBNSIDL_EXIDE
DLC_RTR = TXBNDLC_RTR
OSC_MAX_HZ = 25_000_000  # highest oscillator frequency accepted (1-25 MHz) [M]
