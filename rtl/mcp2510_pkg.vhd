-- =================================================================================================
-- Title    : mcp2510_pkg
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   MCP2510 constants and bit-timing computation.
-- Purpose:
--   Every SPI instruction opcode, register address and register bit the core uses, named as in
--   the Microchip MCP2510 data sheet (DS21291) with the prefix MCP_ and the suffix _C. The
--   values are checked constant by constant against the Python model's
--   sim_models/mcp2510/regs.py by tb/test_consistency.py (single source of truth by test).
--   The MCP2515-only instructions (READ RX BUFFER, LOAD TX BUFFER, RX STATUS) are deliberately
--   absent: the MCP2510 does not have them.
--   mcp_bit_timing() derives CNF1-3 at elaboration from the oscillator frequency and the CAN
--   bit rate (sample point as close to 87.5 % as the chip allows).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

package mcp2510_pkg is

    subtype byte_t is std_logic_vector(7 downto 0);

    -- ---------------------------------------------------------------------------------------------
    -- SPI instructions (DS21291 section 11)
    -- ---------------------------------------------------------------------------------------------
    constant MCP_INSTR_RESET_C       : byte_t := x"C0";
    constant MCP_INSTR_READ_C        : byte_t := x"03";
    constant MCP_INSTR_WRITE_C       : byte_t := x"02";
    constant MCP_INSTR_RTS_C         : byte_t := x"80"; -- 1000 0nnn, n = TXB2..TXB0
    constant MCP_INSTR_READ_STATUS_C : byte_t := x"A0";
    constant MCP_INSTR_BIT_MODIFY_C  : byte_t := x"05";

    -- READ STATUS output byte
    constant MCP_STATUS_RX0IF_C      : byte_t := x"01";
    constant MCP_STATUS_RX1IF_C      : byte_t := x"02";
    constant MCP_STATUS_TXB0_TXREQ_C : byte_t := x"04";
    constant MCP_STATUS_TX0IF_C      : byte_t := x"08";
    constant MCP_STATUS_TXB1_TXREQ_C : byte_t := x"10";
    constant MCP_STATUS_TX1IF_C      : byte_t := x"20";
    constant MCP_STATUS_TXB2_TXREQ_C : byte_t := x"40";
    constant MCP_STATUS_TX2IF_C      : byte_t := x"80";

    -- ---------------------------------------------------------------------------------------------
    -- Register addresses
    -- ---------------------------------------------------------------------------------------------
    constant MCP_RXF0SIDH_C  : byte_t := x"00";
    constant MCP_BFPCTRL_C   : byte_t := x"0C";
    constant MCP_TXRTSCTRL_C : byte_t := x"0D";
    constant MCP_CANSTAT_C   : byte_t := x"0E";
    constant MCP_CANCTRL_C   : byte_t := x"0F";
    constant MCP_RXF3SIDH_C  : byte_t := x"10";
    constant MCP_TEC_C       : byte_t := x"1C";
    constant MCP_REC_C       : byte_t := x"1D";
    constant MCP_RXM0SIDH_C  : byte_t := x"20";
    constant MCP_RXM1SIDH_C  : byte_t := x"24";
    constant MCP_CNF3_C      : byte_t := x"28";
    constant MCP_CNF2_C      : byte_t := x"29";
    constant MCP_CNF1_C      : byte_t := x"2A";
    constant MCP_CANINTE_C   : byte_t := x"2B";
    constant MCP_CANINTF_C   : byte_t := x"2C";
    constant MCP_EFLG_C      : byte_t := x"2D";
    constant MCP_TXB0CTRL_C  : byte_t := x"30";
    constant MCP_TXB0SIDH_C  : byte_t := x"31";
    constant MCP_TXB1CTRL_C  : byte_t := x"40";
    constant MCP_TXB2CTRL_C  : byte_t := x"50";
    constant MCP_RXB0CTRL_C  : byte_t := x"60";
    constant MCP_RXB0SIDH_C  : byte_t := x"61";
    constant MCP_RXB1CTRL_C  : byte_t := x"70";
    constant MCP_RXB1SIDH_C  : byte_t := x"71";

    -- ---------------------------------------------------------------------------------------------
    -- Register bits (single-bit masks) and fields
    -- ---------------------------------------------------------------------------------------------
    -- BFPCTRL: RXnBF pins as "buffer full" interrupt outputs
    constant MCP_BFPCTRL_B0BFM_C : byte_t := x"01";
    constant MCP_BFPCTRL_B1BFM_C : byte_t := x"02";
    constant MCP_BFPCTRL_B0BFE_C : byte_t := x"04";
    constant MCP_BFPCTRL_B1BFE_C : byte_t := x"08";
    -- TXRTSCTRL: TXnRTS pins request transmission (falling edge)
    constant MCP_TXRTSCTRL_B0RTSM_C : byte_t := x"01";
    constant MCP_TXRTSCTRL_B1RTSM_C : byte_t := x"02";
    constant MCP_TXRTSCTRL_B2RTSM_C : byte_t := x"04";
    -- CANSTAT / CANCTRL
    constant MCP_CANSTAT_OPMOD_MASK_C : byte_t  := x"E0";
    constant MCP_CANCTRL_REQOP_MASK_C : byte_t  := x"E0";
    constant MCP_CANCTRL_ABAT_C       : byte_t  := x"10";
    constant MCP_OPMODE_NORMAL_C      : natural := 0;
    constant MCP_OPMODE_CONFIG_C      : natural := 4;
    -- CANINTE / CANINTF
    constant MCP_CANINTF_RX0IF_C     : byte_t  := x"01";
    constant MCP_CANINTF_RX1IF_C     : byte_t  := x"02";
    constant MCP_CANINTF_TX0IF_C     : byte_t  := x"04";
    constant MCP_CANINTF_TX1IF_C     : byte_t  := x"08";
    constant MCP_CANINTF_TX2IF_C     : byte_t  := x"10";
    constant MCP_CANINTF_ERRIF_C     : byte_t  := x"20";
    constant MCP_CANINTF_WAKIF_C     : byte_t  := x"40";
    constant MCP_CANINTF_MERRF_C     : byte_t  := x"80";
    constant MCP_CANINTF_ERRIF_BIT_C : natural := 5; -- bit index of ERRIF (error interrupt)
    constant MCP_CANINTE_TX0IE_C     : byte_t  := x"04";
    constant MCP_CANINTE_TX1IE_C     : byte_t  := x"08";
    constant MCP_CANINTE_TX2IE_C     : byte_t  := x"10";
    constant MCP_CANINTE_ERRIE_C     : byte_t  := x"20";
    constant MCP_CANINTE_MERRE_C     : byte_t  := x"80";
    -- EFLG
    constant MCP_EFLG_RX0OVR_C   : byte_t  := x"40";
    constant MCP_EFLG_RX1OVR_C   : byte_t  := x"80";
    constant MCP_EFLG_TXBO_BIT_C : natural := 5; -- bit index of TXBO (bus-off)
    -- TXBnCTRL
    constant MCP_TXBCTRL_ABTF_C  : byte_t := x"40";
    constant MCP_TXBCTRL_MLOA_C  : byte_t := x"20";
    constant MCP_TXBCTRL_TXERR_C : byte_t := x"10";
    constant MCP_TXBCTRL_TXREQ_C : byte_t := x"08";
    -- RXBnCTRL: RXM receive mode field (bits 6:5) and BUKT rollover (RXB0 only)
    constant MCP_RXBCTRL_RXM_SHIFT_C : natural := 5;
    constant MCP_RXB0CTRL_BUKT_C     : byte_t  := x"04";
    -- identifier layout in SIDL (filters, masks, buffers)
    constant MCP_SIDL_SRR_C   : byte_t := x"10"; -- RX buffers: standard frame was a remote frame
    constant MCP_SIDL_IDE_C   : byte_t := x"08"; -- RX buffers: extended identifier
    constant MCP_SIDL_EXIDE_C : byte_t := x"08"; -- TX buffers and filters: extended identifier
    constant MCP_DLC_RTR_C    : byte_t := x"40"; -- TXBnDLC / RXBnDLC: remote frame

    -- buffer geometry
    constant MCP_BUF_SIZE_C   : natural := 14; -- CTRL, SIDH, SIDL, EID8, EID0, DLC, D0..D7
    constant MCP_TXB_STRIDE_C : natural := 16;
    constant MCP_OSC_MAX_HZ_C : natural := 25_000_000;

    -- ---------------------------------------------------------------------------------------------
    -- Bit timing (DS21291 section 5)
    -- ---------------------------------------------------------------------------------------------
    -- Nominal bit = Sync(1) + PropSeg + PS1 + PS2 time quanta, TQ = 2 (BRP + 1) / F_OSC.

    type mcp_bit_timing_t is record
        brp         : natural range 0 to 63;   -- baud rate prescaler (CNF1.BRP)
        prseg       : natural range 1 to 8;    -- propagation segment [TQ]
        phseg1      : natural range 1 to 8;    -- phase segment 1 [TQ]
        phseg2      : natural range 2 to 8;    -- phase segment 2 [TQ]
        sjw         : natural range 1 to 4;    -- synchronisation jump width [TQ]
        tq_count    : natural range 8 to 25;   -- TQ per bit (data sheet: 8..25)
        sp_permille : natural range 0 to 1000; -- sample point [0.1 %]
        found       : boolean;                 -- an exact setting exists
    end record mcp_bit_timing_t;

    function mcp_bit_timing (osc_hz : positive; bitrate_bps : positive) return mcp_bit_timing_t;

    -- mcp_bit_timing() that stops elaboration with a clear message when no exact setting
    -- exists, and reports the chosen one as a note (used by mcp2510_ctrl).

    function mcp_bit_timing_checked (osc_hz : positive; bitrate_bps : positive)
        return mcp_bit_timing_t;

    function mcp_cnf1 (bt : mcp_bit_timing_t) return byte_t;

    function mcp_cnf2 (bt : mcp_bit_timing_t) return byte_t;

    function mcp_cnf3 (bt : mcp_bit_timing_t) return byte_t;

end package mcp2510_pkg;

package body mcp2510_pkg is

    -- Search every TQ count from 25 down to 8 for an exact prescaler; among the exact ones keep
    -- the sample point closest to 87.5 % (CiA 301 recommendation), the larger TQ count on ties.
    -- PS2 >= 2 TQ (information processing time), PS1 >= PS2 is not required by the chip but
    -- PropSeg + PS1 >= PS2 is, SJW = min(4, PS2 - 1, PS1) keeps SJW < PS2 and SJW <= PS1.

    function mcp_bit_timing (osc_hz : positive; bitrate_bps : positive) return mcp_bit_timing_t is

        variable best    : mcp_bit_timing_t;
        variable div     : natural;
        variable ps2     : natural;
        variable tseg1   : natural;
        variable ps1     : natural;
        variable sp      : natural;
        variable err     : natural;
        variable err_min : natural := 1001;

    begin

        best :=
        (
            brp => 0,
            prseg => 1,
            phseg1 => 1,
            phseg2 => 2,
            sjw => 1,
            tq_count => 8,
            sp_permille => 0,
            found => false
        );

        for n in 25 downto 8 loop

            -- exact: F_OSC = 2 * (BRP + 1) * n * bitrate
            if osc_hz mod (2 * n * bitrate_bps) = 0 then
                div := osc_hz / (2 * n * bitrate_bps);
                if div >= 1 and div <= 64 then
                    -- PS2 = round(n / 8) (12.5 % of the bit), at least 2 TQ, at most 8
                    ps2 := (n + 4) / 8;
                    if ps2 < 2 then
                        ps2 := 2;
                    end if;
                    tseg1 := n - 1 - ps2;
                    if ps2 <= 8 and tseg1 >= 2 and tseg1 <= 16 then
                        ps1 := (tseg1 + 1) / 2;
                        if ps1 > 8 then
                            ps1 := 8;
                        end if;
                        if tseg1 - ps1 > 8 then
                            ps1 := tseg1 - 8;
                        end if;
                        sp := (1000 * (n - ps2)) / n;
                        if sp > 875 then
                            err := sp - 875;
                        else
                            err := 875 - sp;
                        end if;
                        if err < err_min then
                            err_min          := err;
                            best.brp         := div - 1;
                            best.phseg2      := ps2;
                            best.phseg1      := ps1;
                            best.prseg       := tseg1 - ps1;
                            best.tq_count    := n;
                            best.sp_permille := sp;
                            best.sjw         := 1;
                            if ps2 - 1 > 1 then
                                best.sjw := ps2 - 1;
                            end if;
                            if best.sjw > 4 then
                                best.sjw := 4;
                            end if;
                            if best.sjw > ps1 then
                                best.sjw := ps1;
                            end if;
                            best.found := true;
                        end if;
                    end if;
                end if;
            end if;

        end loop;

        return best;

    end function mcp_bit_timing;

    function mcp_bit_timing_checked (osc_hz : positive; bitrate_bps : positive)
        return mcp_bit_timing_t is

        -- GHDL 2.0 --synth crashes on integer'image() of a record field inside a report string
        -- (and on a function-local constant initialised by a function call): copy the fields
        -- into plain integer variables first.
        variable bt    : mcp_bit_timing_t;
        variable brp   : natural;
        variable n     : natural;
        variable prseg : natural;
        variable ps1   : natural;
        variable ps2   : natural;
        variable sjw   : natural;
        variable sp    : natural;

    begin

        bt    := mcp_bit_timing(osc_hz, bitrate_bps);
        brp   := bt.brp;
        n     := bt.tq_count;
        prseg := bt.prseg;
        ps1   := bt.phseg1;
        ps2   := bt.phseg2;
        sjw   := bt.sjw;
        sp    := bt.sp_permille;
        assert bt.found
            report "mcp2510: no exact MCP2510 bit timing for CAN_BITRATE_BPS = "
                   & integer'image(bitrate_bps) & " with OSC_FREQ_HZ = " & integer'image(osc_hz)
                   & " (need OSC = 2 x (BRP+1) x N x bitrate, BRP 0..63, N 8..25 TQ)"
            severity failure;
        assert false
            report "mcp2510: " & integer'image(bitrate_bps) & " bit/s from "
                   & integer'image(osc_hz) & " Hz: BRP=" & integer'image(brp)
                   & " TQ/bit=" & integer'image(n) & " prop/ps1/ps2/sjw="
                   & integer'image(prseg) & "/" & integer'image(ps1) & "/" & integer'image(ps2)
                   & "/" & integer'image(sjw) & " sample point=" & integer'image(sp) & " permille"
            severity note;
        return bt;

    end function mcp_bit_timing_checked;

    -- CNF1 = SJW<1:0> (SJW - 1) & BRP<5:0>

    function mcp_cnf1 (bt : mcp_bit_timing_t) return byte_t is
    begin

        return std_logic_vector(to_unsigned(bt.sjw - 1, 2))
               & std_logic_vector(to_unsigned(bt.brp, 6));

    end function mcp_cnf1;

    -- CNF2 = BTLMODE (1: PS2 from CNF3) & SAM (0: one sample) & PHSEG1<2:0> & PRSEG<2:0>

    function mcp_cnf2 (bt : mcp_bit_timing_t) return byte_t is
    begin

        return "10" & std_logic_vector(to_unsigned(bt.phseg1 - 1, 3))
               & std_logic_vector(to_unsigned(bt.prseg - 1, 3));

    end function mcp_cnf2;

    -- CNF3 = WAKFIL (0) & PHSEG2<2:0>

    function mcp_cnf3 (bt : mcp_bit_timing_t) return byte_t is
    begin

        return "00000" & std_logic_vector(to_unsigned(bt.phseg2 - 1, 3));

    end function mcp_cnf3;

end package body mcp2510_pkg;
