# =================================================================================================
# Title    : canopen_master_hw.tcl
# Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
# SPDX-License-Identifier: Apache-2.0
# =================================================================================================
# Platform Designer (Qsys) component description of canopen_master_top (rtl/canopen_master_top.vhd).
# Add the folder of this file to the IP search path; see docs/platform_designer.md.
#
# Written by hand (not by the Component Editor) and checked against the VHDL entity and
# rtl/files.f by tb/test_ip_package.py. It has NOT been loaded in Quartus/Platform Designer by
# this project (no Quartus in the CI environment).
#
# Interfaces:
#   clock    clock sink       clk_i
#   reset    reset sink       rst_n_i (active low; asynchronous assertion, synchronised release
#                             inside the core, so no synchronisation is required from the fabric)
#   s0       Avalon-MM slave  32-bit data, 8-bit WORD address (256 words = 1 KiB), fixed read
#                             latency 2, no waitrequest (never stalls), no bursts
#   irq      interrupt sender irq_o, level high, serviced through s0
#   mcp2510  conduit          SPI and MCP2510 pins (export it)
#   debug    conduit          FSM states and avs_readdatavalid_o (may be left unconnected)
# =================================================================================================

# 13.1: Quartus II 13.1 is the last release with Cyclone III support; newer Platform Designer
# releases still accept components written against an older API version.
package require -exact qsys 13.1

# -------------------------------------------------------------------------------------------------
# Module
# -------------------------------------------------------------------------------------------------
set_module_property NAME                         canopen_master
set_module_property VERSION                      1.0
set_module_property DISPLAY_NAME                 "CANopen master (MCP2510 over SPI)"
set_module_property GROUP                        "Interface Protocols/CAN"
set_module_property AUTHOR                       "canopen_master project"
set_module_property DESCRIPTION                  "CiA 301 CANopen master (NMT master, SYNC producer, heartbeat/guarding, EMCY, SDO client, PDO engine, automatic slave configuration) driving a Microchip MCP2510 CAN controller over SPI. Avalon-MM slave with a level interrupt."
set_module_property INTERNAL                     false
set_module_property OPAQUE_ADDRESS_MAP           true
set_module_property INSTANTIATE_IN_SYSTEM_MODULE true
# hand-written: the Component Editor would rewrite (and reformat) this file
set_module_property EDITABLE                     false
set_module_property ELABORATION_CALLBACK         elaborate
set_module_property VALIDATION_CALLBACK          validate

# -------------------------------------------------------------------------------------------------
# Files: rtl/files.f in the same order (packages first). The VHDL sources refer to each other as
# the working library (e.g. "entity work.canopen_master_core"), so they compile into whatever
# library the generated system chooses (add_fileset_file has no documented per-file library
# argument); see "VHDL library" in docs/platform_designer.md.
# The RTL is VHDL-93 (Quartus' default VHDL_INPUT_VERSION VHDL_1993; VHDL_2008 compiles it too).
# QUARTUS_SYNTH also carries canopen_master.sdc (false paths of the reset and pin synchronisers).
# -------------------------------------------------------------------------------------------------
add_fileset QUARTUS_SYNTH QUARTUS_SYNTH "" ""
set_fileset_property QUARTUS_SYNTH TOP_LEVEL                     canopen_master_top
set_fileset_property QUARTUS_SYNTH ENABLE_RELATIVE_INCLUDE_PATHS false
set_fileset_property QUARTUS_SYNTH ENABLE_FILE_OVERWRITE_MODE    false
add_fileset_file mcp2510_pkg.vhd          VHDL PATH ../rtl/mcp2510_pkg.vhd
add_fileset_file canopen_master_pkg.vhd   VHDL PATH ../rtl/canopen_master_pkg.vhd
add_fileset_file canopen_pkg.vhd          VHDL PATH ../rtl/canopen_pkg.vhd
add_fileset_file canopen_regs_pkg.vhd     VHDL PATH ../rtl/canopen_regs_pkg.vhd
add_fileset_file canopen_util_pkg.vhd     VHDL PATH ../rtl/canopen_util_pkg.vhd
add_fileset_file canopen_sdp_ram.vhd      VHDL PATH ../rtl/canopen_sdp_ram.vhd
add_fileset_file canopen_counter_bank.vhd VHDL PATH ../rtl/canopen_counter_bank.vhd
add_fileset_file canopen_fifo.vhd         VHDL PATH ../rtl/canopen_fifo.vhd
add_fileset_file canopen_sdo_channels.vhd VHDL PATH ../rtl/canopen_sdo_channels.vhd
add_fileset_file canopen_autoconfig.vhd   VHDL PATH ../rtl/canopen_autoconfig.vhd
add_fileset_file canopen_pdo_engine.vhd   VHDL PATH ../rtl/canopen_pdo_engine.vhd
add_fileset_file omni_feasibility.vhd     VHDL PATH ../rtl/omni_feasibility.vhd
add_fileset_file omni_node_table.vhd      VHDL PATH ../rtl/omni_node_table.vhd
add_fileset_file omni_engine.vhd          VHDL PATH ../rtl/omni_engine.vhd
add_fileset_file canopen_node_monitor.vhd VHDL PATH ../rtl/canopen_node_monitor.vhd
add_fileset_file mcp2510_spi_master.vhd   VHDL PATH ../rtl/mcp2510_spi_master.vhd
add_fileset_file mcp2510_instr.vhd        VHDL PATH ../rtl/mcp2510_instr.vhd
add_fileset_file mcp2510_ctrl.vhd         VHDL PATH ../rtl/mcp2510_ctrl.vhd
add_fileset_file canopen_sync_timebase.vhd VHDL PATH ../rtl/canopen_sync_timebase.vhd
add_fileset_file canopen_fault_supervisor.vhd VHDL PATH ../rtl/canopen_fault_supervisor.vhd
add_fileset_file canopen_tx_path.vhd      VHDL PATH ../rtl/canopen_tx_path.vhd
add_fileset_file canopen_master_fsm.vhd   VHDL PATH ../rtl/canopen_master_fsm.vhd
add_fileset_file canopen_host_regs.vhd    VHDL PATH ../rtl/canopen_host_regs.vhd
add_fileset_file canopen_master_core.vhd  VHDL PATH ../rtl/canopen_master_core.vhd
add_fileset_file canopen_master_top.vhd   VHDL PATH ../rtl/canopen_master_top.vhd TOP_LEVEL_FILE
# timing exceptions of the core's synchronisers (register names, independent of the instance name)
add_fileset_file canopen_master.sdc       SDC  PATH canopen_master.sdc

add_fileset SIM_VHDL SIM_VHDL "" ""
set_fileset_property SIM_VHDL TOP_LEVEL                     canopen_master_top
set_fileset_property SIM_VHDL ENABLE_RELATIVE_INCLUDE_PATHS false
set_fileset_property SIM_VHDL ENABLE_FILE_OVERWRITE_MODE    false
add_fileset_file mcp2510_pkg.vhd          VHDL PATH ../rtl/mcp2510_pkg.vhd
add_fileset_file canopen_master_pkg.vhd   VHDL PATH ../rtl/canopen_master_pkg.vhd
add_fileset_file canopen_pkg.vhd          VHDL PATH ../rtl/canopen_pkg.vhd
add_fileset_file canopen_regs_pkg.vhd     VHDL PATH ../rtl/canopen_regs_pkg.vhd
add_fileset_file canopen_util_pkg.vhd     VHDL PATH ../rtl/canopen_util_pkg.vhd
add_fileset_file canopen_sdp_ram.vhd      VHDL PATH ../rtl/canopen_sdp_ram.vhd
add_fileset_file canopen_counter_bank.vhd VHDL PATH ../rtl/canopen_counter_bank.vhd
add_fileset_file canopen_fifo.vhd         VHDL PATH ../rtl/canopen_fifo.vhd
add_fileset_file canopen_sdo_channels.vhd VHDL PATH ../rtl/canopen_sdo_channels.vhd
add_fileset_file canopen_autoconfig.vhd   VHDL PATH ../rtl/canopen_autoconfig.vhd
add_fileset_file canopen_pdo_engine.vhd   VHDL PATH ../rtl/canopen_pdo_engine.vhd
add_fileset_file omni_feasibility.vhd     VHDL PATH ../rtl/omni_feasibility.vhd
add_fileset_file omni_node_table.vhd      VHDL PATH ../rtl/omni_node_table.vhd
add_fileset_file omni_engine.vhd          VHDL PATH ../rtl/omni_engine.vhd
add_fileset_file canopen_node_monitor.vhd VHDL PATH ../rtl/canopen_node_monitor.vhd
add_fileset_file mcp2510_spi_master.vhd   VHDL PATH ../rtl/mcp2510_spi_master.vhd
add_fileset_file mcp2510_instr.vhd        VHDL PATH ../rtl/mcp2510_instr.vhd
add_fileset_file mcp2510_ctrl.vhd         VHDL PATH ../rtl/mcp2510_ctrl.vhd
add_fileset_file canopen_sync_timebase.vhd VHDL PATH ../rtl/canopen_sync_timebase.vhd
add_fileset_file canopen_fault_supervisor.vhd VHDL PATH ../rtl/canopen_fault_supervisor.vhd
add_fileset_file canopen_tx_path.vhd      VHDL PATH ../rtl/canopen_tx_path.vhd
add_fileset_file canopen_master_fsm.vhd   VHDL PATH ../rtl/canopen_master_fsm.vhd
add_fileset_file canopen_host_regs.vhd    VHDL PATH ../rtl/canopen_host_regs.vhd
add_fileset_file canopen_master_core.vhd  VHDL PATH ../rtl/canopen_master_core.vhd
add_fileset_file canopen_master_top.vhd   VHDL PATH ../rtl/canopen_master_top.vhd TOP_LEVEL_FILE

# -------------------------------------------------------------------------------------------------
# Parameters = generics of canopen_master_top (same names, defaults and ranges; VHDL positive is
# 1:2147483647, natural 0:2147483647). The RTL checks the combinations again at elaboration.
# -------------------------------------------------------------------------------------------------
add_display_item "" "Clock and SPI" GROUP ""
add_display_item "" "CAN" GROUP ""
add_display_item "" "CANopen master" GROUP ""

# clk_i frequency: taken from the clock connected to the "clock" interface
add_parameter CLK_FREQ_HZ INTEGER 50000000
set_parameter_property CLK_FREQ_HZ DEFAULT_VALUE  50000000
set_parameter_property CLK_FREQ_HZ TYPE           INTEGER
set_parameter_property CLK_FREQ_HZ ALLOWED_RANGES 1:2147483647
set_parameter_property CLK_FREQ_HZ UNITS          Hertz
set_parameter_property CLK_FREQ_HZ DISPLAY_NAME   "Clock frequency (from the clock interface)"
set_parameter_property CLK_FREQ_HZ DESCRIPTION    "clk_i frequency in Hz, a whole number of MHz; taken from the clock connected to the clock interface"
set_parameter_property CLK_FREQ_HZ SYSTEM_INFO    {CLOCK_RATE clock}
set_parameter_property CLK_FREQ_HZ HDL_PARAMETER  true
add_display_item "Clock and SPI" CLK_FREQ_HZ PARAMETER

add_parameter SPI_SCLK_HZ INTEGER 5000000
set_parameter_property SPI_SCLK_HZ DEFAULT_VALUE  5000000
set_parameter_property SPI_SCLK_HZ TYPE           INTEGER
set_parameter_property SPI_SCLK_HZ ALLOWED_RANGES 1:2147483647
set_parameter_property SPI_SCLK_HZ UNITS          Hertz
set_parameter_property SPI_SCLK_HZ DISPLAY_NAME   "SPI SCK (maximum)"
set_parameter_property SPI_SCLK_HZ DESCRIPTION    "Highest SCK frequency; at most 5 MHz (MCP2510) and at most CLK_FREQ_HZ / 4"
set_parameter_property SPI_SCLK_HZ HDL_PARAMETER  true
add_display_item "Clock and SPI" SPI_SCLK_HZ PARAMETER

add_parameter CS_SETUP_NS INTEGER 100
set_parameter_property CS_SETUP_NS DEFAULT_VALUE  100
set_parameter_property CS_SETUP_NS TYPE           INTEGER
set_parameter_property CS_SETUP_NS ALLOWED_RANGES 0:10000
set_parameter_property CS_SETUP_NS UNITS          Nanoseconds
set_parameter_property CS_SETUP_NS DISPLAY_NAME   "CS# setup time (tCSS)"
set_parameter_property CS_SETUP_NS HDL_PARAMETER  true
add_display_item "Clock and SPI" CS_SETUP_NS PARAMETER

add_parameter CS_HOLD_NS INTEGER 100
set_parameter_property CS_HOLD_NS DEFAULT_VALUE  100
set_parameter_property CS_HOLD_NS TYPE           INTEGER
set_parameter_property CS_HOLD_NS ALLOWED_RANGES 0:10000
set_parameter_property CS_HOLD_NS UNITS          Nanoseconds
set_parameter_property CS_HOLD_NS DISPLAY_NAME   "CS# hold time (tCSH)"
set_parameter_property CS_HOLD_NS HDL_PARAMETER  true
add_display_item "Clock and SPI" CS_HOLD_NS PARAMETER

add_parameter CS_DISABLE_NS INTEGER 100
set_parameter_property CS_DISABLE_NS DEFAULT_VALUE  100
set_parameter_property CS_DISABLE_NS TYPE           INTEGER
set_parameter_property CS_DISABLE_NS ALLOWED_RANGES 0:10000
set_parameter_property CS_DISABLE_NS UNITS          Nanoseconds
set_parameter_property CS_DISABLE_NS DISPLAY_NAME   "CS# disable time (tCSD)"
set_parameter_property CS_DISABLE_NS HDL_PARAMETER  true
add_display_item "Clock and SPI" CS_DISABLE_NS PARAMETER

add_parameter OSC_FREQ_HZ INTEGER 16000000
set_parameter_property OSC_FREQ_HZ DEFAULT_VALUE  16000000
set_parameter_property OSC_FREQ_HZ TYPE           INTEGER
set_parameter_property OSC_FREQ_HZ ALLOWED_RANGES 1:2147483647
set_parameter_property OSC_FREQ_HZ UNITS          Hertz
set_parameter_property OSC_FREQ_HZ DISPLAY_NAME   "MCP2510 oscillator"
set_parameter_property OSC_FREQ_HZ DESCRIPTION    "Crystal/oscillator of the MCP2510 (at most 25 MHz); CNF1-3 are computed from it"
set_parameter_property OSC_FREQ_HZ HDL_PARAMETER  true
add_display_item "CAN" OSC_FREQ_HZ PARAMETER

add_parameter CAN_BITRATE_BPS INTEGER 1000000
set_parameter_property CAN_BITRATE_BPS DEFAULT_VALUE  1000000
set_parameter_property CAN_BITRATE_BPS TYPE           INTEGER
set_parameter_property CAN_BITRATE_BPS ALLOWED_RANGES 1:2147483647
set_parameter_property CAN_BITRATE_BPS UNITS          BitsPerSecond
set_parameter_property CAN_BITRATE_BPS DISPLAY_NAME   "CAN bit rate"
set_parameter_property CAN_BITRATE_BPS DESCRIPTION    "10 kbit/s to 1 Mbit/s; must have an exact MCP2510 bit timing for OSC_FREQ_HZ (checked at elaboration)"
set_parameter_property CAN_BITRATE_BPS HDL_PARAMETER  true
add_display_item "CAN" CAN_BITRATE_BPS PARAMETER

add_parameter RX_FIFO_DEPTH INTEGER 4
set_parameter_property RX_FIFO_DEPTH DEFAULT_VALUE  4
set_parameter_property RX_FIFO_DEPTH TYPE           INTEGER
set_parameter_property RX_FIFO_DEPTH ALLOWED_RANGES 1:16
set_parameter_property RX_FIFO_DEPTH UNITS          None
set_parameter_property RX_FIFO_DEPTH DISPLAY_NAME   "Receive FIFO depth (frames)"
set_parameter_property RX_FIFO_DEPTH HDL_PARAMETER  true
add_display_item "CAN" RX_FIFO_DEPTH PARAMETER

add_parameter RESET_WAIT_US INTEGER 20
set_parameter_property RESET_WAIT_US DEFAULT_VALUE  20
set_parameter_property RESET_WAIT_US TYPE           INTEGER
set_parameter_property RESET_WAIT_US ALLOWED_RANGES 1:2147483647
set_parameter_property RESET_WAIT_US UNITS          None
set_parameter_property RESET_WAIT_US DISPLAY_NAME   "MCP2510 start-up wait after reset (us)"
set_parameter_property RESET_WAIT_US HDL_PARAMETER  true
add_display_item "CAN" RESET_WAIT_US PARAMETER

add_parameter MAX_NODES INTEGER 8
set_parameter_property MAX_NODES DEFAULT_VALUE  8
set_parameter_property MAX_NODES TYPE           INTEGER
set_parameter_property MAX_NODES ALLOWED_RANGES 1:16
set_parameter_property MAX_NODES UNITS          None
set_parameter_property MAX_NODES DISPLAY_NAME   "Supervised nodes (heartbeat/guarding slots)"
set_parameter_property MAX_NODES HDL_PARAMETER  true
add_display_item "CANopen master" MAX_NODES PARAMETER

add_parameter EMCY_DEPTH INTEGER 8
set_parameter_property EMCY_DEPTH DEFAULT_VALUE  8
set_parameter_property EMCY_DEPTH TYPE           INTEGER
set_parameter_property EMCY_DEPTH ALLOWED_RANGES 2:64
set_parameter_property EMCY_DEPTH UNITS          None
set_parameter_property EMCY_DEPTH DISPLAY_NAME   "EMCY FIFO entries"
set_parameter_property EMCY_DEPTH HDL_PARAMETER  true
add_display_item "CANopen master" EMCY_DEPTH PARAMETER

add_parameter N_TPDO INTEGER 8
set_parameter_property N_TPDO DEFAULT_VALUE  8
set_parameter_property N_TPDO TYPE           INTEGER
set_parameter_property N_TPDO ALLOWED_RANGES 1:32
set_parameter_property N_TPDO UNITS          None
set_parameter_property N_TPDO DISPLAY_NAME   "TPDO channels (sent by the master)"
set_parameter_property N_TPDO HDL_PARAMETER  true
add_display_item "CANopen master" N_TPDO PARAMETER

add_parameter N_RPDO INTEGER 8
set_parameter_property N_RPDO DEFAULT_VALUE  8
set_parameter_property N_RPDO TYPE           INTEGER
set_parameter_property N_RPDO ALLOWED_RANGES 1:32
set_parameter_property N_RPDO UNITS          None
set_parameter_property N_RPDO DISPLAY_NAME   "RPDO channels (received by the master)"
set_parameter_property N_RPDO HDL_PARAMETER  true
add_display_item "CANopen master" N_RPDO PARAMETER

add_parameter N_SDO INTEGER 2
set_parameter_property N_SDO DEFAULT_VALUE  2
set_parameter_property N_SDO TYPE           INTEGER
set_parameter_property N_SDO ALLOWED_RANGES 1:4
set_parameter_property N_SDO UNITS          None
set_parameter_property N_SDO DISPLAY_NAME   "SDO client channels (concurrent transfers to different nodes)"
set_parameter_property N_SDO HDL_PARAMETER  true
add_display_item "CANopen master" N_SDO PARAMETER

add_parameter CFG_DEPTH INTEGER 64
set_parameter_property CFG_DEPTH DEFAULT_VALUE  64
set_parameter_property CFG_DEPTH TYPE           INTEGER
set_parameter_property CFG_DEPTH ALLOWED_RANGES 2:256
set_parameter_property CFG_DEPTH UNITS          None
set_parameter_property CFG_DEPTH DISPLAY_NAME   "Configuration list entries"
set_parameter_property CFG_DEPTH HDL_PARAMETER  true
add_display_item "CANopen master" CFG_DEPTH PARAMETER

add_parameter OMNI_ENABLE BOOLEAN true
set_parameter_property OMNI_ENABLE DEFAULT_VALUE  true
set_parameter_property OMNI_ENABLE TYPE           BOOLEAN
set_parameter_property OMNI_ENABLE DISPLAY_NAME   "Build the Omni-ID protocol engine"
set_parameter_property OMNI_ENABLE DESCRIPTION    "false: CANopen-only core (about 5200 LUTs smaller); CTRL.OMNI then has no effect"
set_parameter_property OMNI_ENABLE HDL_PARAMETER  true
add_display_item "CANopen master" OMNI_ENABLE PARAMETER

add_parameter WATCHDOG_US INTEGER 20000
set_parameter_property WATCHDOG_US DEFAULT_VALUE  20000
set_parameter_property WATCHDOG_US TYPE           INTEGER
set_parameter_property WATCHDOG_US ALLOWED_RANGES 1:2147483647
set_parameter_property WATCHDOG_US UNITS          None
set_parameter_property WATCHDOG_US DISPLAY_NAME   "FSM state watchdog (us)"
set_parameter_property WATCHDOG_US HDL_PARAMETER  true
add_display_item "CANopen master" WATCHDOG_US PARAMETER

# -------------------------------------------------------------------------------------------------
# Callbacks
# -------------------------------------------------------------------------------------------------
# Early, readable errors for the combinations the RTL would reject at elaboration (the RTL checks
# stay authoritative; these mirror docs/canopen_master_top.md).
proc validate {} {
    set clk  [get_parameter_value CLK_FREQ_HZ]
    set sclk [get_parameter_value SPI_SCLK_HZ]
    set osc  [get_parameter_value OSC_FREQ_HZ]
    set bps  [get_parameter_value CAN_BITRATE_BPS]
    if {$clk <= 0} {
        send_message error "The clock rate of the clock interface is unknown: connect a clock whose frequency is known (clock source or clock bridge with a frequency set)."
    } elseif {$clk % 1000000 != 0} {
        send_message error "CLK_FREQ_HZ = $clk Hz: the core needs a whole number of MHz (exact microsecond timebase)."
    } elseif {$clk < 4 * $sclk} {
        send_message error "CLK_FREQ_HZ = $clk Hz must be at least 4 x SPI_SCLK_HZ = [expr {4 * $sclk}] Hz."
    }
    if {$sclk > 5000000} {
        send_message error "SPI_SCLK_HZ = $sclk Hz exceeds the MCP2510 maximum SCK of 5 MHz."
    }
    if {$osc > 25000000} {
        send_message error "OSC_FREQ_HZ = $osc Hz exceeds the MCP2510 maximum of 25 MHz."
    }
    if {$bps < 10000 || $bps > 1000000} {
        send_message error "CAN_BITRATE_BPS = $bps bit/s: supported range is 10 kbit/s to 1 Mbit/s."
    }
}

# Values for the Nios II BSP (system.h: <INSTANCE>_<NAME>).
proc elaborate {} {
    foreach name {CLK_FREQ_HZ CAN_BITRATE_BPS MAX_NODES EMCY_DEPTH N_TPDO N_RPDO N_SDO CFG_DEPTH \
                  RX_FIFO_DEPTH} {
        set_module_assignment embeddedsw.CMacro.$name [get_parameter_value $name]
    }
}

# -------------------------------------------------------------------------------------------------
# Interface: clock (clock sink)
# -------------------------------------------------------------------------------------------------
add_interface clock clock end
set_interface_property clock clockRate 0
set_interface_property clock ENABLED   true
add_interface_port clock clk_i clk Input 1

# -------------------------------------------------------------------------------------------------
# Interface: reset (reset sink). rst_n_i is asserted asynchronously and released through the
# core's own 2-flop synchroniser, so the core asks for no synchronous edge (NONE).
# -------------------------------------------------------------------------------------------------
add_interface reset reset end
set_interface_property reset associatedClock  clock
set_interface_property reset synchronousEdges NONE
set_interface_property reset ENABLED          true
add_interface_port reset rst_n_i reset_n Input 1

# -------------------------------------------------------------------------------------------------
# Interface: s0 (Avalon-MM slave). Word addressing (address = register number), 32-bit words.
# Every Avalon input ends in a flip-flop (address, read, write, writedata, byteenable), and the
# read data comes from registers. Reads: the read is accepted in the cycle read is high and
# readdata is valid exactly two cycles later, for every address -> fixed latency: readLatency 2,
# readWaitTime 0; reads may follow each other in every cycle. Writes are accepted in the cycle
# write is high (they act one cycle later, in order with the reads) -> writeWaitTime 0. No
# waitrequest (the slave never stalls: nothing in it can refuse or delay an access).
# avs_readdatavalid_o is NOT mapped here: a slave with readdatavalid is "pipelined with variable
# latency", which the Avalon specification pairs with waitrequest; it is on the debug conduit.
# -------------------------------------------------------------------------------------------------
add_interface s0 avalon end
set_interface_property s0 addressUnits                   WORDS
set_interface_property s0 associatedClock                clock
set_interface_property s0 associatedReset                reset
set_interface_property s0 bitsPerSymbol                  8
set_interface_property s0 burstOnBurstBoundariesOnly     false
set_interface_property s0 burstcountUnits                WORDS
set_interface_property s0 explicitAddressSpan            0
set_interface_property s0 holdTime                       0
set_interface_property s0 linewrapBursts                 false
set_interface_property s0 maximumPendingReadTransactions 0
set_interface_property s0 readLatency                    2
set_interface_property s0 readWaitTime                   0
set_interface_property s0 setupTime                      0
set_interface_property s0 timingUnits                    Cycles
set_interface_property s0 writeWaitTime                  0
set_interface_property s0 bridgesToMaster                ""
set_interface_property s0 ENABLED                        true
add_interface_port s0 avs_address_i    address    Input  8
add_interface_port s0 avs_read_i       read       Input  1
add_interface_port s0 avs_write_i      write      Input  1
add_interface_port s0 avs_writedata_i  writedata  Input  32
add_interface_port s0 avs_byteenable_i byteenable Input  4
add_interface_port s0 avs_readdata_o   readdata   Output 32
set_interface_assignment s0 embeddedsw.configuration.isFlash             0
set_interface_assignment s0 embeddedsw.configuration.isMemoryDevice      0
set_interface_assignment s0 embeddedsw.configuration.isNonVolatileStorage 0
set_interface_assignment s0 embeddedsw.configuration.isPrintableDevice   0

# -------------------------------------------------------------------------------------------------
# Interface: irq (interrupt sender). Level high = OR(IRQ_STATUS and IRQ_ENABLE); it stays high
# until software clears the pending bits through s0.
# -------------------------------------------------------------------------------------------------
add_interface irq interrupt end
set_interface_property irq associatedAddressablePoint s0
set_interface_property irq associatedClock            clock
set_interface_property irq associatedReset            reset
set_interface_property irq bridgedReceiverOffset      0
set_interface_property irq bridgesToReceiver          ""
set_interface_property irq irqScheme                  NONE
set_interface_property irq ENABLED                    true
add_interface_port irq irq_o irq Output 1

# -------------------------------------------------------------------------------------------------
# Interface: mcp2510 (conduit, export it to the FPGA pins). Roles are the port names without the
# mcp_ prefix and the _i/_o suffix; MCP2510 pin in the comment.
# -------------------------------------------------------------------------------------------------
add_interface mcp2510 conduit end
set_interface_property mcp2510 associatedClock clock
set_interface_property mcp2510 associatedReset reset
set_interface_property mcp2510 ENABLED         true
add_interface_port mcp2510 spi_cs_n_o    spi_cs_n Output 1
add_interface_port mcp2510 spi_sck_o     spi_sck  Output 1
add_interface_port mcp2510 spi_mosi_o    spi_mosi Output 1
add_interface_port mcp2510 spi_miso_i    spi_miso Input  1
add_interface_port mcp2510 mcp_int_n_i   int_n    Input  1
add_interface_port mcp2510 mcp_rx0bf_n_i rx0bf_n  Input  1
add_interface_port mcp2510 mcp_rx1bf_n_i rx1bf_n  Input  1
add_interface_port mcp2510 mcp_txrts_n_o txrts_n  Output 3
add_interface_port mcp2510 mcp_reset_n_o reset_n  Output 1
# CS# SCK SI SO INT# RX0BF# RX1BF# TX2RTS#..TX0RTS# RESET#

# -------------------------------------------------------------------------------------------------
# Interface: debug (conduit, optional). FSM state (thesis St number), MCP2510 sequencer state and
# the read-data-valid strobe (avs_read_i delayed by one cycle) for monitoring.
# -------------------------------------------------------------------------------------------------
add_interface debug conduit end
set_interface_property debug associatedClock clock
set_interface_property debug associatedReset reset
set_interface_property debug ENABLED         true
add_interface_port debug fsm_state_o         fsm_state     Output 4
add_interface_port debug ctrl_state_o        ctrl_state    Output 5
add_interface_port debug avs_readdatavalid_o readdatavalid Output 1
