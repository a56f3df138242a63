-- =================================================================================================
-- Title    : mcp2510_ctrl
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   MCP2510 controller: initialisation, frame receive/transmit, interrupts, status.
-- Purpose:
--   Turns "receive a frame", "send this frame" and "what happened?" into MCP2510 SPI
--   instructions (through mcp2510_instr and the SPI engine). It knows the chip, not CANopen.
--   * Initialisation after reset or reinit_i: RESET instruction, wait the oscillator start-up
--     time, one WRITE of masks + CNF3..CNF1 + CANINTE + CANINTF, WRITEs of filters + BFPCTRL +
--     TXRTSCTRL and of RXB0CTRL/RXB1CTRL, read-back check of CNF1-3/CANINTE, request normal mode
--     with BIT MODIFY and poll CANSTAT.OPMOD a bounded number of times. Any failure is retried
--     INIT_RETRIES times, then init_fail_o is raised (thesis St0 "initialisation failed" path);
--     nothing waits without a bound. CNF1-3 are computed at elaboration (mcp2510_pkg).
--   * Receive: the RX0BF/RX1BF pins are configured as buffer-full interrupts. A low pin starts
--     one READ from RXBnSIDH that stops after the DLC byte plus the data bytes the frame has,
--     then a BIT MODIFY clears RXnIF. Frames go to an RX FIFO (valid/ready towards the user);
--     a buffer is only read when the FIFO has room, so nothing is dropped inside the FPGA.
--   * Transmit: the caller picks the TX buffer and its TXP priority; one WRITE loads it (from
--     TXBnCTRL when the priority changes, else from TXBnSIDH) and, if tx_send_i, an RTS starts
--     it. The frame is not copied: the caller holds tx_id_i .. tx_data_i from the edge that
--     accepts it (tx_ready_o) while tx_busy_o is 1 (until that WRITE has ended). A preloaded
--     buffer can be started later by tx_fire_i through its TXnRTS pin, with no SPI traffic
--     (the SYNC path uses this).
--   * INT (enabled for TX0-2 done, ERR and MERR): one READ of CANINTF and EFLG, a READ of the
--     pending buffers' TXBnCTRL after a message error (TXERR/MLOA), one BIT MODIFY clearing the
--     handled flags and, on receive overflow, one clearing EFLG.RXnOVR. Every cause is reported
--     with a strobe (tx_done_o, tx_err_o, tx_arb_lost_o, rx_overflow_o, int_valid_o + flags).
--   * Status on request: READ STATUS, TEC/REC, CANINTF/EFLG and TXB0-2CTRL (status_valid_o).
--   * tx_abort_i aborts all pending transmissions (CANCTRL.ABAT) and reports them; tx_cancel_i
--     cancels one buffer (BIT MODIFY TXBnCTRL.TXREQ = 0, outcome by READ STATUS one longest
--     frame later, with RX served meanwhile).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.mcp2510_pkg.all;
    use work.canopen_util_pkg.all;

entity mcp2510_ctrl is
    generic (
        CLK_FREQ_HZ     : positive                  := 50_000_000; -- clk_i frequency [Hz]
        SPI_SCLK_HZ     : positive                  := 5_000_000;  -- max SCK [Hz], <= 5 MHz
        CS_SETUP_NS     : natural range 0 to 10_000 := 100;        -- tCSS [ns]
        CS_HOLD_NS      : natural range 0 to 10_000 := 100;        -- tCSH [ns]
        CS_DISABLE_NS   : natural range 0 to 10_000 := 100;        -- tCSD [ns]
        OSC_FREQ_HZ     : positive                  := 16_000_000; -- MCP2510 oscillator [Hz]
        CAN_BITRATE_BPS : positive                  := 1_000_000;  -- CAN bit rate [bit/s]
        RESET_WAIT_US   : positive                  := 20;         -- after RESET [us]
        MODE_POLL_US    : positive                  := 20;         -- between OPMOD polls [us]
        MODE_POLL_MAX   : positive range 1 to 255   := 32;         -- OPMOD polls per attempt
        INIT_RETRIES    : natural range 0 to 15     := 3;          -- extra init attempts
        RX_STD_MASK     : natural range 0 to 2047   := 0;          -- RXM0/1 standard-id mask
        RX_STD_FILTER   : natural range 0 to 2047   := 0;          -- RXF standard-id filter
        RX_ACCEPT_EXT   : boolean                   := true;       -- also receive extended ids
        RX_ROLLOVER     : boolean                   := true;       -- RXB0 full -> RXB1 (BUKT)
        RX_FIFO_DEPTH   : positive range 1 to 16    := 4;          -- frames buffered in the FPGA
        TXRTS_PINS      : natural range 0 to 7      := 7;          -- TXnRTS pins enabled (mask)
        TXRTS_LOW_NS    : positive                  := 500;        -- TXnRTS low pulse [ns]
        PIN_SETTLE_NS   : positive                  := 200;        -- ignore RXnBF/INT after clear
        ERR_POLL_US     : positive range 1 to 1000  := 500         -- TEC/REC/EFLG poll [us]
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low
        -- control and status
        reinit_i    : in    std_logic;                    -- pulse: re-run initialisation
        init_done_o : out   std_logic;                    -- chip in normal mode, running
        init_fail_o : out   std_logic;                    -- initialisation failed
        chip_lost_o : out   std_logic;                    -- strobe: chip found reset, re-init
        busy_o      : out   std_logic;                    -- an SPI sequence is running
        state_o     : out   std_logic_vector(4 downto 0); -- sequencer state (debug)
        -- transmit request
        tx_valid_i  : in    std_logic;                     -- load (and send) a frame
        tx_ready_o  : out   std_logic;                     -- request accepted now
        tx_busy_o   : out   std_logic;                     -- the accepted frame is being read
        tx_buf_i    : in    std_logic_vector(1 downto 0);  -- TX buffer 0..2
        tx_txp_i    : in    std_logic_vector(1 downto 0);  -- buffer priority (3 highest)
        tx_send_i   : in    std_logic;                     -- 1: RTS after load; 0: preload
        tx_id_i     : in    std_logic_vector(28 downto 0); -- identifier (std: 10..0)
        tx_ide_i    : in    std_logic;                     -- extended identifier
        tx_rtr_i    : in    std_logic;                     -- remote frame
        tx_dlc_i    : in    std_logic_vector(3 downto 0);  -- data length code
        tx_data_i   : in    std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        tx_fire_i   : in    std_logic_vector(2 downto 0);  -- pulse: start buffer by pin
        tx_abort_i  : in    std_logic;                     -- pulse: abort all pending
        tx_cancel_i : in    std_logic_vector(2 downto 0);  -- pulse: cancel this pending buffer
        -- transmit events
        tx_loaded_o    : out   std_logic;                    -- strobe: request executed
        tx_pending_o   : out   std_logic_vector(2 downto 0); -- TXREQ set (as known here)
        tx_done_o      : out   std_logic_vector(2 downto 0); -- strobe: sent (TXnIF)
        tx_err_o       : out   std_logic_vector(2 downto 0); -- strobe: TXERR seen
        tx_errors_o    : out   std_logic;                    -- strobe: one own frame destroyed
        tx_arb_lost_o  : out   std_logic_vector(2 downto 0); -- strobe: MLOA seen
        tx_aborted_o   : out   std_logic_vector(2 downto 0); -- strobe: aborted/cancelled
        tx_fire_drop_o : out   std_logic_vector(2 downto 0); -- strobe: fire of an unloaded buffer
        -- received frames (FIFO head, first-word fall-through)
        rx_valid_o : out   std_logic;                     -- a frame is available
        rx_ready_i : in    std_logic;                     -- pop the frame
        rx_id_o    : out   std_logic_vector(28 downto 0); -- identifier (std: 10..0)
        rx_ide_o   : out   std_logic;                     -- extended identifier
        rx_rtr_o   : out   std_logic;                     -- remote frame
        rx_dlc_o   : out   std_logic_vector(3 downto 0);  -- data length code
        rx_data_o  : out   std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        rx_buf_o   : out   std_logic;                     -- MCP2510 buffer it came from
        -- error and interrupt events
        int_valid_o   : out   std_logic;                    -- strobe: INT handled
        int_canintf_o : out   std_logic_vector(7 downto 0); -- CANINTF read on that INT
        int_eflg_o    : out   std_logic_vector(7 downto 0); -- EFLG read on that INT
        rx_overflow_o : out   std_logic_vector(1 downto 0); -- strobe: RXnOVR (frame lost)
        -- live error state (polled every ERR_POLL_US and after every error INT, 0 after RESET)
        err_valid_o : out   std_logic;                    -- strobe: TEC/REC/EFLG read
        err_tec_o   : out   std_logic_vector(7 downto 0); -- TEC
        err_rec_o   : out   std_logic_vector(7 downto 0); -- REC
        err_eflg_o  : out   std_logic_vector(7 downto 0); -- EFLG
        -- status snapshot on request
        status_req_i     : in    std_logic;                     -- pulse: read status registers
        status_valid_o   : out   std_logic;                     -- strobe: snapshot updated
        status_rdstat_o  : out   std_logic_vector(7 downto 0);  -- READ STATUS byte
        status_tec_o     : out   std_logic_vector(7 downto 0);  -- TEC
        status_rec_o     : out   std_logic_vector(7 downto 0);  -- REC
        status_intf_o    : out   std_logic_vector(7 downto 0);  -- CANINTF
        status_eflg_o    : out   std_logic_vector(7 downto 0);  -- EFLG
        status_txbctrl_o : out   std_logic_vector(23 downto 0); -- TXB2/1/0CTRL
        -- MCP2510 pins
        spi_cs_n_o    : out   std_logic;                    -- chip select, active low
        spi_sck_o     : out   std_logic;                    -- serial clock
        spi_mosi_o    : out   std_logic;                    -- to SI
        spi_miso_i    : in    std_logic;                    -- from SO
        mcp_int_n_i   : in    std_logic;                    -- INT, active low
        mcp_rx0bf_n_i : in    std_logic;                    -- RX0BF, active low
        mcp_rx1bf_n_i : in    std_logic;                    -- RX1BF, active low
        mcp_txrts_n_o : out   std_logic_vector(2 downto 0); -- TX2RTS..TX0RTS, active low
        mcp_reset_n_o : out   std_logic                     -- RESET pin, active low
    );
end entity mcp2510_ctrl;

architecture rtl of mcp2510_ctrl is

    -- ---------------------------------------------------------------------------------------------
    -- Elaboration-time configuration
    -- ---------------------------------------------------------------------------------------------
    constant bit_timing_c : mcp_bit_timing_t := mcp_bit_timing_checked(OSC_FREQ_HZ,
                                                                       CAN_BITRATE_BPS);
    constant cnf1_c       : byte_t           := mcp_cnf1(bit_timing_c);
    constant cnf2_c       : byte_t           := mcp_cnf2(bit_timing_c);
    constant cnf3_c       : byte_t           := mcp_cnf3(bit_timing_c);

    function us_to_cycles (us : natural) return natural is
    begin

        return us * ((CLK_FREQ_HZ + 999_999) / 1_000_000);

    end function us_to_cycles;

    constant reset_wait_c : positive := us_to_cycles(RESET_WAIT_US);
    constant mode_poll_c  : positive := us_to_cycles(MODE_POLL_US);
    constant txrts_low_c  : positive := ns_to_cycles(TXRTS_LOW_NS, CLK_FREQ_HZ) + 1;
    constant pin_settle_c : positive := ns_to_cycles(PIN_SETTLE_NS, CLK_FREQ_HZ) + 2;
    -- ABAT cannot stop a frame already on the wire: wait one longest frame (160 bits, extended,
    -- 8 bytes, stuffed) plus an error frame and intermission (~20 bits) before deciding
    constant abort_wait_c  : positive := 192 * ((CLK_FREQ_HZ + CAN_BITRATE_BPS - 1)
                                                / CAN_BITRATE_BPS);
    constant abort_polls_c : positive := 4;
    constant err_poll_c    : positive := us_to_cycles(ERR_POLL_US);
    -- TX turnaround: after a TX-done the core gets this long to present the frame for the freed
    -- buffer before an error poll may start (the poll would lengthen the bus gap between two
    -- frames of one buffer by its 5 + 3 bytes of SPI); 2 us covers the core's FSM path
    constant tx_turn_c   : positive := us_to_cycles(2);
    constant timer_max_c : positive := reset_wait_c + mode_poll_c + abort_wait_c;

    function check_config return boolean is
    begin

        assert CAN_BITRATE_BPS >= 10_000 and CAN_BITRATE_BPS <= 1_000_000
            report "mcp2510_ctrl: CAN_BITRATE_BPS = " & integer'image(CAN_BITRATE_BPS)
                   & " outside 10 kbit/s .. 1 Mbit/s"
            severity failure;
        assert OSC_FREQ_HZ <= MCP_OSC_MAX_HZ_C
            report "mcp2510_ctrl: OSC_FREQ_HZ = " & integer'image(OSC_FREQ_HZ)
                   & " Hz above the MCP2510 maximum of 25 MHz"
            severity failure;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    -- register values written at initialisation
    constant bfpctrl_c   : byte_t := MCP_BFPCTRL_B0BFM_C or MCP_BFPCTRL_B1BFM_C
                                     or MCP_BFPCTRL_B0BFE_C or MCP_BFPCTRL_B1BFE_C;
    constant txrtsctrl_c : byte_t := std_logic_vector(to_unsigned(TXRTS_PINS, 8));
    constant caninte_c   : byte_t := MCP_CANINTE_MERRE_C or MCP_CANINTE_ERRIE_C
                                     or MCP_CANINTE_TX2IE_C or MCP_CANINTE_TX1IE_C
                                     or MCP_CANINTE_TX0IE_C;
    constant tx_flags_c  : byte_t := MCP_CANINTF_TX0IF_C or MCP_CANINTF_TX1IF_C
                                     or MCP_CANINTF_TX2IF_C;
    constant int_clear_c : byte_t := tx_flags_c or MCP_CANINTF_ERRIF_C or MCP_CANINTF_WAKIF_C
                                     or MCP_CANINTF_MERRF_C;
    constant eflg_ovr_c  : byte_t := MCP_EFLG_RX0OVR_C or MCP_EFLG_RX1OVR_C;

    function rxbctrl (bukt : boolean) return byte_t is

        variable v : byte_t := x"00"; -- RXM = 00: filters decide, standard and extended

    begin

        if bukt then
            v := v or MCP_RXB0CTRL_BUKT_C;
        end if;

        return v;

    end function rxbctrl;

    -- SIDH, SIDL, EID8, EID0 of a mask or filter for an 11-bit identifier; ext selects EXIDE

    function id_regs (sid : natural; ext : boolean) return std_logic_vector is

        variable v   : std_logic_vector(31 downto 0) := (others => '0');
        variable s11 : std_logic_vector(10 downto 0);

    begin

        s11             := std_logic_vector(to_unsigned(sid, 11));
        v(7 downto 0)   := s11(10 downto 3);
        v(15 downto 13) := s11(2 downto 0);

        if ext then
            v(15 downto 8) := v(15 downto 8) or MCP_SIDL_EXIDE_C;
        end if;

        return v; -- byte 0 = SIDH, byte 1 = SIDL, byte 2 = EID8, byte 3 = EID0

    end function id_regs;

    -- filters RXF0..5: even ones for standard ids, odd ones for extended ids (if accepted)

    function filter_regs (first : natural; count : natural) return std_logic_vector is

        variable v : std_logic_vector(32 * count - 1 downto 0);

    begin

        for k in 0 to count - 1 loop

            v(32 * k + 31 downto 32 * k) := id_regs(RX_STD_FILTER,
                                                    RX_ACCEPT_EXT and ((first + k) mod 2 = 1));

        end loop;

        return v;

    end function filter_regs;

    -- ---------------------------------------------------------------------------------------------
    -- Sequencer states (the chip-level sequencer; the CANopen FSM lives elsewhere)
    -- ---------------------------------------------------------------------------------------------

    type seq_state_t is (
        S_POR_WAIT,     -- after reset: give the chip its start-up time
        S_RESET_CMD,    -- RESET instruction
        S_RESET_WAIT,   -- oscillator start-up time after RESET
        S_CFG_MASKS,    -- WRITE RXM0, RXM1, CNF3, CNF2, CNF1, CANINTE, CANINTF (0x20..0x2C)
        S_CFG_FILT_A,   -- WRITE RXF0-2, BFPCTRL, TXRTSCTRL (0x00..0x0D)
        S_CFG_FILT_B,   -- WRITE RXF3-5 (0x10..0x1B)
        S_CFG_RXB0,     -- WRITE RXB0CTRL
        S_CFG_RXB1,     -- WRITE RXB1CTRL
        S_CFG_VERIFY,   -- READ CNF3..CANINTE back and compare
        S_MODE_REQ,     -- BIT MODIFY CANCTRL.REQOP = normal
        S_MODE_POLL,    -- READ CANSTAT, check OPMOD
        S_MODE_WAIT,    -- wait before the next poll
        S_FAILED,       -- initialisation failed: wait for reinit_i
        S_IDLE,         -- dispatch: RX > INT > abort > TX > status
        S_RX_READ,      -- READ RXBn from SIDH, DLC-limited
        S_RX_CLEAR,     -- BIT MODIFY CANINTF.RXnIF = 0
        S_INT_READ,     -- READ CANINTF, EFLG
        S_INT_TXB,      -- READ TXBnCTRL of pending buffers after a message error
        S_INT_CLEAR,    -- BIT MODIFY CANINTF handled flags = 0
        S_INT_CLR_OVR,  -- BIT MODIFY EFLG.RXnOVR = 0
        S_TX_LOAD,      -- WRITE TXBnCTRL/SIDH .. data
        S_TX_RTS,       -- RTS
        S_ABORT_SET,    -- BIT MODIFY CANCTRL.ABAT = 1
        S_ABORT_WAIT,   -- let a frame already on the wire finish
        S_ABORT_STATUS, -- READ STATUS: which buffers are no longer pending
        S_ABORT_CLEAR,  -- BIT MODIFY CANCTRL.ABAT = 0
        S_STAT_RDSTAT,  -- READ STATUS
        S_STAT_ERRCNT,  -- READ TEC, REC
        S_STAT_FLAGS,   -- READ CANINTF, EFLG
        S_STAT_TXB,     -- READ TXB0..2CTRL
        S_ERR_CNT,      -- error poll: READ TEC, REC
        S_ERR_FLG       -- error poll: READ EFLG
    );

    -- the states that send one instruction and then always go on to the same state

    function simple_next (st : seq_state_t) return seq_state_t is
    begin

        case st is

            when S_CFG_MASKS =>

                return S_CFG_FILT_A;

            when S_CFG_FILT_A =>

                return S_CFG_FILT_B;

            when S_CFG_FILT_B =>

                return S_CFG_RXB0;

            when S_CFG_RXB0 =>

                return S_CFG_RXB1;

            when S_CFG_RXB1 =>

                return S_CFG_VERIFY;

            when S_STAT_RDSTAT =>

                return S_STAT_ERRCNT;

            when S_STAT_ERRCNT =>

                return S_STAT_FLAGS;

            when S_ERR_CNT =>

                return S_ERR_FLG;

            when others =>

                return S_IDLE; -- S_ABORT_CLEAR

        end case;

    end function simple_next;

    signal state : seq_state_t;
    -- '0': the state's command has not been issued yet, '1': waiting for its response
    signal issued  : std_logic;
    signal attempt : natural range 0 to 15;
    signal polls   : natural range 0 to 255;
    -- general-purpose wait timer (start-up, poll interval)
    signal timer : natural range 0 to timer_max_c;
    -- RX buffer being read (0/1); TX buffer index for INT/status loops
    signal rx_buf  : natural range 0 to 1;
    signal buf_idx : natural range 0 to 2;

    -- latched TX request
    signal txq_buf  : natural range 0 to 2;
    signal txq_txp  : std_logic_vector(1 downto 0);
    signal txq_send : std_logic;
    -- the frame fields are not copied: the caller holds tx_id_i .. tx_data_i from the accepting
    -- edge until the WRITE into the TX buffer has ended (txl_busy, tx_busy_o)
    signal txl_busy : std_logic;
    -- TXP last written per buffer ('1' in txp_known when it is known)

    type txp_array_t is array (0 to 2) of std_logic_vector(1 downto 0);

    signal txp_cache : txp_array_t;
    signal txp_known : std_logic_vector(2 downto 0);
    signal pending   : std_logic_vector(2 downto 0);
    -- buffer completely written since the last RESET (only such a buffer may be fired by pin)
    signal txb_loaded : std_logic_vector(2 downto 0);
    signal abort_req  : std_logic;
    -- cancel of single buffers (tx_cancel_i): BIT MODIFY TXBnCTRL.TXREQ = 0 still to send, the
    -- buffers whose outcome is still open, the time left until READ STATUS tells it, that READ
    -- falling due, and how often it was repeated (a frame still on the wire)
    signal cancel_req   : std_logic_vector(2 downto 0);
    signal cancel_wait  : std_logic_vector(2 downto 0);
    signal cancel_tmr   : natural range 0 to abort_wait_c;
    signal cancel_chk   : std_logic;
    signal cancel_polls : natural range 0 to abort_polls_c;
    -- S_ABORT_SET / S_ABORT_STATUS serve a cancel ('1') or the ABAT abort ('0'), of this buffer
    signal cancel_op  : std_logic;
    signal cancel_buf : natural range 0 to 2;
    -- lowest buffer with a cancel to send, and the state a cancel dispatch goes to
    signal cancel_first : natural range 0 to 2;
    signal cancel_next  : seq_state_t;
    -- TXREQ bits of a READ STATUS answer; a cancelled frame still on the wire (look again)
    signal cancel_stat  : std_logic_vector(2 downto 0);
    signal cancel_again : std_logic;
    -- buffers an abort/cancel decides on, the states after its BIT MODIFY and after READ STATUS
    signal abort_sel      : std_logic_vector(2 downto 0);
    signal abort_set_next : seq_state_t;
    signal abort_end_next : seq_state_t;
    -- reinit_i seen (a pulse that arrives while an SPI sequence runs is kept)
    signal reinit_req : std_logic;
    signal status_req : std_logic;
    -- error poll: due (interval over, or an error INT was handled), and the interval counter
    signal err_req : std_logic;
    signal err_cnt : natural range 0 to err_poll_c;
    -- TX turnaround left (tx_turn_c), the poll waits while it runs
    signal turn_cnt : natural range 0 to tx_turn_c;
    -- destroyed frames of this node from TEC steps: TEC of the last poll (0 after RESET), and
    -- the errors still to report on tx_errors_o (one strobe per cycle)
    signal tec_base : unsigned(7 downto 0);
    -- CANSTAT of the error poll (its third byte), and "OPMOD of it is not normal"
    signal canstat_q : byte_t;
    signal chip_lost : std_logic;
    -- the INT just read asks for an error poll
    signal poll_on_int : std_logic;
    signal terr_pend   : natural range 0 to 63;
    signal terr_add    : natural range 0 to 32; -- errors of the last TEC read, added a cycle later

    -- values read on an INT
    signal intf_q    : byte_t;
    signal eflg_q    : byte_t;
    signal txerr_acc : std_logic_vector(2 downto 0);
    signal mloa_acc  : std_logic_vector(2 downto 0);

    -- synchronised pins and settle blanking
    signal int_sync  : std_logic_vector(1 downto 0);
    signal rx0_sync  : std_logic_vector(1 downto 0);
    signal rx1_sync  : std_logic_vector(1 downto 0);
    signal blank_cnt : natural range 0 to pin_settle_c;

    -- instruction executor interface
    signal cmd_valid : std_logic;
    signal cmd_ready : std_logic;
    signal cmd_instr : byte_t;
    signal cmd_addr  : byte_t;
    signal cmd_len   : std_logic_vector(3 downto 0);
    signal cmd_rxbuf : std_logic;
    -- write bytes: cmd_wd holds the data phase of every state except S_TX_LOAD (constants and a
    -- byte or two of flags), txl_regs the queued frame in TX buffer register order, txl_hdr = 1
    -- when the TX load starts at TXBnCTRL (priority changed); the executor asks for byte
    -- cmd_widx and gets cmd_wbyte in the same cycle
    signal cmd_wd    : std_logic_vector(111 downto 0);
    signal txl_regs  : std_logic_vector(103 downto 0);
    signal txl_hdr   : std_logic;
    signal cmd_widx  : std_logic_vector(3 downto 0);
    signal cmd_wbyte : byte_t;
    signal rsp_valid : std_logic;
    signal rsp_rdata : std_logic_vector(111 downto 0);

    -- RX FIFO: id(29) ide rtr dlc(4) data(64) buf = 100 bits; its RAM declared with at least
    -- 16 words (free in the 3 M9K that 100 bits need; yosys maps 4 x 100 bits to flip-flops)
    constant fifo_w_c         : natural := 100;
    constant fifo_ram_words_c : natural := 16;

    -- (canopen_fifo on block RAM): push of a decoded frame, the frame, no room for another one,
    -- no frame visible, the head
    signal fifo_push  : std_logic;
    signal fifo_din   : std_logic_vector(fifo_w_c - 1 downto 0);
    signal fifo_full  : std_logic;
    signal fifo_empty : std_logic;
    signal fifo_q     : std_logic_vector(fifo_w_c - 1 downto 0);

    -- TXnRTS pulse generators

    type rts_cnt_array_t is array (0 to 2) of natural range 0 to txrts_low_c;

    signal rts_cnt  : rts_cnt_array_t;
    signal fire_set : std_logic_vector(2 downto 0);

    -- byte k of a 14-byte vector

    function byte_of (v : std_logic_vector(111 downto 0); k : natural) return byte_t is
    begin

        return v(8 * k + 7 downto 8 * k);

    end function byte_of;

    -- three bits of a READ STATUS byte, TXB2..TXB0 order (masks from mcp2510_pkg)

    function status_bits (st : byte_t; m0 : byte_t; m1 : byte_t; m2 : byte_t)
        return std_logic_vector is

        variable v : std_logic_vector(2 downto 0);

    begin

        v(0) := or_reduce(st and m0);
        v(1) := or_reduce(st and m1);
        v(2) := or_reduce(st and m2);
        return v;

    end function status_bits;

    function buf_bit (n : natural) return std_logic_vector is

        variable v : std_logic_vector(2 downto 0) := "000";

    begin

        v(n) := '1';
        return v;

    end function buf_bit;

begin

    -- ---------------------------------------------------------------------------------------------
    -- Input synchronisers (INT and RXnBF come from the chip's own clock domain)
    -- ---------------------------------------------------------------------------------------------
    sync_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            int_sync <= (others => '1');
            rx0_sync <= (others => '1');
            rx1_sync <= (others => '1');
        elsif rising_edge(clk_i) then
            int_sync <= int_sync(0) & mcp_int_n_i;
            rx0_sync <= rx0_sync(0) & mcp_rx0bf_n_i;
            rx1_sync <= rx1_sync(0) & mcp_rx1bf_n_i;
        end if;

    end process sync_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Command table: the MCP2510 instruction each sequencer state issues (latched by the
    -- executor on cmd_valid, one cycle after the state is entered).
    -- ---------------------------------------------------------------------------------------------
    cmd_table_proc : process (buf_idx, cancel_buf, cancel_op, intf_q, rx_buf, state, txl_hdr,
                              txq_buf, tx_dlc_i, tx_rtr_i) is

        variable wd     : std_logic_vector(111 downto 0);
        variable hdr    : natural range 0 to 1;
        variable n_data : natural range 0 to 8;

    begin

        wd        := (others => '0');
        cmd_instr <= MCP_INSTR_READ_C;
        cmd_addr  <= x"00";
        cmd_len   <= x"0";
        cmd_rxbuf <= '0';

        case state is

            when S_RESET_CMD =>

                cmd_instr <= MCP_INSTR_RESET_C;

            -- masks, bit timing, interrupt enables, and all interrupt flags cleared
            when S_CFG_MASKS =>

                wd(31 downto 0)   := id_regs(RX_STD_MASK, false);
                wd(63 downto 32)  := id_regs(RX_STD_MASK, false);
                wd(71 downto 64)  := cnf3_c;
                wd(79 downto 72)  := cnf2_c;
                wd(87 downto 80)  := cnf1_c;
                wd(95 downto 88)  := caninte_c;
                wd(103 downto 96) := x"00";
                cmd_instr         <= MCP_INSTR_WRITE_C;
                cmd_addr          <= MCP_RXM0SIDH_C;
                cmd_len           <= x"D";

            when S_CFG_FILT_A =>

                wd(95 downto 0)    := filter_regs(0, 3);
                wd(103 downto 96)  := bfpctrl_c;
                wd(111 downto 104) := txrtsctrl_c;
                cmd_instr          <= MCP_INSTR_WRITE_C;
                cmd_addr           <= MCP_RXF0SIDH_C;
                cmd_len            <= x"E";

            when S_CFG_FILT_B =>

                wd(95 downto 0) := filter_regs(3, 3);
                cmd_instr       <= MCP_INSTR_WRITE_C;
                cmd_addr        <= MCP_RXF3SIDH_C;
                cmd_len         <= x"C";

            when S_CFG_RXB0 =>

                wd(7 downto 0) := rxbctrl(RX_ROLLOVER);
                cmd_instr      <= MCP_INSTR_WRITE_C;
                cmd_addr       <= MCP_RXB0CTRL_C;
                cmd_len        <= x"1";

            when S_CFG_RXB1 =>

                wd(7 downto 0) := rxbctrl(false);
                cmd_instr      <= MCP_INSTR_WRITE_C;
                cmd_addr       <= MCP_RXB1CTRL_C;
                cmd_len        <= x"1";

            -- CNF3, CNF2, CNF1, CANINTE read back
            when S_CFG_VERIFY =>

                cmd_addr <= MCP_CNF3_C;
                cmd_len  <= x"4";

            -- BIT MODIFY CANCTRL: mask REQOP, data 000 (normal mode)
            when S_MODE_REQ =>

                wd(7 downto 0) := MCP_CANCTRL_REQOP_MASK_C;
                cmd_instr      <= MCP_INSTR_BIT_MODIFY_C;
                cmd_addr       <= MCP_CANCTRL_C;
                cmd_len        <= x"2";

            when S_MODE_POLL =>

                cmd_addr <= MCP_CANSTAT_C;
                cmd_len  <= x"1";

            -- RX buffer from SIDH, length decided by the executor from the DLC byte
            when S_RX_READ =>

                if rx_buf = 0 then
                    cmd_addr <= MCP_RXB0SIDH_C;
                else
                    cmd_addr <= MCP_RXB1SIDH_C;
                end if;

                cmd_len   <= x"D";
                cmd_rxbuf <= '1';

            -- BIT MODIFY CANINTF: mask RXnIF, data 0 (releases the buffer and its RXnBF pin)
            when S_RX_CLEAR =>

                if rx_buf = 0 then
                    wd(7 downto 0) := MCP_CANINTF_RX0IF_C;
                else
                    wd(7 downto 0) := MCP_CANINTF_RX1IF_C;
                end if;

                cmd_instr <= MCP_INSTR_BIT_MODIFY_C;
                cmd_addr  <= MCP_CANINTF_C;
                cmd_len   <= x"2";

            -- CANINTF and EFLG
            when S_INT_READ | S_STAT_FLAGS =>

                cmd_addr <= MCP_CANINTF_C;
                cmd_len  <= x"2";

            when S_INT_TXB | S_STAT_TXB =>

                cmd_addr <= std_logic_vector(unsigned(MCP_TXB0CTRL_C) + MCP_TXB_STRIDE_C * buf_idx);
                cmd_len  <= x"1";

            -- BIT MODIFY CANINTF: clear exactly the flags that were read
            when S_INT_CLEAR =>

                wd(7 downto 0) := intf_q and int_clear_c;
                cmd_instr      <= MCP_INSTR_BIT_MODIFY_C;
                cmd_addr       <= MCP_CANINTF_C;
                cmd_len        <= x"2";

            when S_INT_CLR_OVR =>

                wd(7 downto 0) := MCP_EFLG_RX0OVR_C or MCP_EFLG_RX1OVR_C;
                cmd_instr      <= MCP_INSTR_BIT_MODIFY_C;
                cmd_addr       <= MCP_EFLG_C;
                cmd_len        <= x"2";

            -- TX buffer load: from TXBnCTRL when the priority changes, else from TXBnSIDH; the
            -- bytes come from txl_regs (cmd_byte_proc)
            when S_TX_LOAD =>

                hdr    := bit_int(txl_hdr);
                n_data := 0;

                if tx_rtr_i = '0' then
                    if unsigned(tx_dlc_i) > 8 then
                        n_data := 8;
                    else
                        n_data := to_integer(unsigned(tx_dlc_i));
                    end if;
                end if;

                cmd_instr <= MCP_INSTR_WRITE_C;

                if hdr = 1 then
                    cmd_addr <= std_logic_vector(unsigned(MCP_TXB0CTRL_C)
                                                 + MCP_TXB_STRIDE_C * txq_buf);
                else
                    cmd_addr <= std_logic_vector(unsigned(MCP_TXB0SIDH_C)
                                                 + MCP_TXB_STRIDE_C * txq_buf);
                end if;

                cmd_len <= std_logic_vector(to_unsigned(hdr + 5 + n_data, 4));

            when S_TX_RTS =>

                cmd_instr <= MCP_INSTR_RTS_C or ("00000" & buf_bit(txq_buf));

            -- BIT MODIFY CANCTRL.ABAT = 1 / = 0; a cancel: BIT MODIFY TXBnCTRL.TXREQ = 0
            when S_ABORT_SET =>

                if cancel_op = '1' then
                    wd(7 downto 0) := MCP_TXBCTRL_TXREQ_C;
                    cmd_addr       <= std_logic_vector(unsigned(MCP_TXB0CTRL_C)
                                                       + MCP_TXB_STRIDE_C * cancel_buf);
                else
                    wd(7 downto 0)  := MCP_CANCTRL_ABAT_C;
                    wd(15 downto 8) := MCP_CANCTRL_ABAT_C;
                    cmd_addr        <= MCP_CANCTRL_C;
                end if;

                cmd_instr <= MCP_INSTR_BIT_MODIFY_C;
                cmd_len   <= x"2";

            when S_ABORT_CLEAR =>

                wd(7 downto 0) := MCP_CANCTRL_ABAT_C;
                cmd_instr      <= MCP_INSTR_BIT_MODIFY_C;
                cmd_addr       <= MCP_CANCTRL_C;
                cmd_len        <= x"2";

            when S_ABORT_STATUS | S_STAT_RDSTAT =>

                cmd_instr <= MCP_INSTR_READ_STATUS_C;
                cmd_len   <= x"1";

            -- TEC, REC
            when S_STAT_ERRCNT =>

                cmd_addr <= MCP_TEC_C;
                cmd_len  <= x"2";

            -- TEC, REC and CANSTAT (1Eh: CANSTAT is mirrored at every xEh address)
            when S_ERR_CNT =>

                cmd_addr <= MCP_TEC_C;
                cmd_len  <= x"3";

            when S_ERR_FLG =>

                cmd_addr <= MCP_EFLG_C;
                cmd_len  <= x"1";

            -- states that issue no instruction
            when S_POR_WAIT | S_RESET_WAIT | S_MODE_WAIT | S_FAILED | S_IDLE | S_ABORT_WAIT =>

                null;

        end case;

        cmd_wd <= wd;

    end process cmd_table_proc;

    -- the accepted frame, still held on tx_*_i, as the TX buffer registers SIDH, SIDL, EID8,
    -- EID0, DLC, D0..D7 (wiring)
    txl_regs_proc : process (tx_data_i, tx_dlc_i, tx_id_i, tx_ide_i, tx_rtr_i) is
    begin

        if tx_ide_i = '1' then
            txl_regs(7 downto 0)   <= tx_id_i(28 downto 21);
            txl_regs(15 downto 8)  <= (tx_id_i(20 downto 18) & "000" & tx_id_i(17 downto 16))
                                      or MCP_SIDL_EXIDE_C;
            txl_regs(23 downto 16) <= tx_id_i(15 downto 8);
            txl_regs(31 downto 24) <= tx_id_i(7 downto 0);
        else
            txl_regs(7 downto 0)   <= tx_id_i(10 downto 3);
            txl_regs(15 downto 8)  <= tx_id_i(2 downto 0) & "00000";
            txl_regs(31 downto 16) <= (others => '0');
        end if;

        txl_regs(39 downto 32)  <= "0" & tx_rtr_i & "00" & tx_dlc_i;
        txl_regs(103 downto 40) <= tx_data_i;

    end process txl_regs_proc;

    txl_hdr <= '0' when txp_known(txq_buf) = '1' and txp_cache(txq_buf) = txq_txp else
               '1';

    -- the data byte the executor asks for: byte cmd_widx of the state's data phase
    cmd_byte_proc : process (cmd_wd, cmd_widx, state, txl_hdr, txl_regs, txq_txp) is

        variable k : natural range 0 to 15;
        variable j : natural range 0 to 15;

    begin

        k := to_integer(unsigned(cmd_widx));
        j := (k - bit_int(txl_hdr)) mod 16;

        if state = S_TX_LOAD then
            if txl_hdr = '1' and k = 0 then
                cmd_wbyte <= "000000" & txq_txp;
            elsif j < 13 then
                cmd_wbyte <= txl_regs(8 * j + 7 downto 8 * j);
            else
                cmd_wbyte <= x"00";
            end if;
        elsif k < 14 then
            cmd_wbyte <= cmd_wd(8 * k + 7 downto 8 * k);
        else
            cmd_wbyte <= x"00";
        end if;

    end process cmd_byte_proc;

    -- simulation only: what the executor reads must not change while a command runs, and the
    -- caller holds the accepted frame on tx_*_i while it is written (tx_busy_o)
    -- pragma translate_off
    hold_check_proc : process (clk_i) is

        variable held     : std_logic_vector(111 + 3 downto 0);
        variable held_frm : std_logic_vector(28 + 1 + 1 + 4 + 64 downto 0);

    begin

        if rising_edge(clk_i) then
            hold_check(held, cmd_ready = '0', cmd_wd & txl_hdr & txq_txp,
                       "mcp2510_ctrl: write bytes of the running command (until its response)");
            hold_check(held_frm, txl_busy = '1',
                       tx_id_i & tx_ide_i & tx_rtr_i & tx_dlc_i & tx_data_i,
                       "mcp2510_ctrl: tx_id_i .. tx_data_i of the accepted frame (tx_busy_o)");
        end if;

    end process hold_check_proc;

    -- pragma translate_on

    -- ---------------------------------------------------------------------------------------------
    -- Sequencer
    -- ---------------------------------------------------------------------------------------------
    seq_proc : process (clk_i, rst_n_i) is

        -- hand the instruction of this state (cmd_table_proc) to the executor; the state then
        -- waits for rsp_valid

        procedure issue is
        begin

            cmd_valid <= '1';
            issued    <= '1';

        end procedure issue;

        procedure go (nxt : seq_state_t) is
        begin

            state  <= nxt;
            issued <= '0';

        end procedure go;

        -- an initialisation step failed: retry from RESET or give up

        procedure init_failed is
        begin

            if attempt < INIT_RETRIES then
                attempt <= attempt + 1;
                go(S_RESET_CMD);
            else
                go(S_FAILED);
            end if;

        end procedure init_failed;

        variable pend_v : std_logic_vector(2 downto 0);
        variable mask_v : byte_t;
        variable rd     : std_logic_vector(111 downto 0);

    begin

        if rst_n_i = '0' then
            state          <= S_POR_WAIT;
            issued         <= '0';
            attempt        <= 0;
            polls          <= 0;
            timer          <= reset_wait_c;
            cmd_valid      <= '0';
            txp_known      <= (others => '0');
            pending        <= (others => '0');
            txb_loaded     <= (others => '0');
            txl_busy       <= '0';
            err_req        <= '0';
            err_cnt        <= err_poll_c;
            err_valid_o    <= '0';
            abort_req      <= '0';
            cancel_op      <= '0';
            cancel_buf     <= 0;
            reinit_req     <= '0';
            status_req     <= '0';
            blank_cnt      <= 0;
            init_done_o    <= '0';
            init_fail_o    <= '0';
            fifo_push      <= '0';
            tx_loaded_o    <= '0';
            tx_done_o      <= (others => '0');
            tx_err_o       <= (others => '0');
            tx_arb_lost_o  <= (others => '0');
            tx_aborted_o   <= (others => '0');
            int_valid_o    <= '0';
            rx_overflow_o  <= (others => '0');
            status_valid_o <= '0';
        elsif rising_edge(clk_i) then
            -- strobes
            err_valid_o    <= '0';
            cmd_valid      <= '0';
            fifo_push      <= '0';
            tx_loaded_o    <= '0';
            tx_done_o      <= (others => '0');
            tx_err_o       <= (others => '0');
            tx_arb_lost_o  <= (others => '0');
            tx_aborted_o   <= (others => '0');
            int_valid_o    <= '0';
            rx_overflow_o  <= (others => '0');
            status_valid_o <= '0';

            -- remember requests that arrive while busy
            if tx_abort_i = '1' then
                abort_req <= '1';
            end if;
            if reinit_i = '1' then
                reinit_req <= '1';
            end if;
            if status_req_i = '1' then
                status_req <= '1';
            end if;
            if blank_cnt /= 0 then
                blank_cnt <= blank_cnt - 1;
            end if;
            pending <= pending or fire_set;
            -- the error poll falls due every ERR_POLL_US (counted from the last one)
            if err_cnt /= 0 then
                err_cnt <= err_cnt - 1;
            else
                err_req <= '1';
            end if;

            case state is

                -- ----------------------------------------------------------------------------
                -- initialisation
                -- ----------------------------------------------------------------------------
                when S_POR_WAIT | S_RESET_WAIT =>

                    if timer = 0 then
                        go(S_CFG_MASKS);
                        if state = S_POR_WAIT then
                            go(S_RESET_CMD);
                        end if;
                    else
                        timer <= timer - 1;
                    end if;

                when S_RESET_CMD =>

                    -- the chip forgets everything: TX buffers undefined, TEC/REC/EFLG = 0
                    init_done_o <= '0';
                    init_fail_o <= '0';
                    txp_known   <= (others => '0');
                    pending     <= (others => '0');
                    txb_loaded  <= (others => '0');
                    err_req     <= '0';
                    err_cnt     <= err_poll_c;
                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        timer <= reset_wait_c;
                        go(S_RESET_WAIT);
                    end if;

                -- one instruction, then always the same next state (simple_next)
                when S_CFG_MASKS | S_CFG_FILT_A | S_CFG_FILT_B | S_CFG_RXB0 | S_CFG_RXB1
                     | S_ABORT_CLEAR | S_STAT_RDSTAT | S_STAT_ERRCNT | S_ERR_CNT =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        go(simple_next(state));
                    end if;

                when S_CFG_VERIFY =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        if byte_of(rsp_rdata, 0) = cnf3_c and byte_of(rsp_rdata, 1) = cnf2_c
                           and byte_of(rsp_rdata, 2) = cnf1_c
                           and byte_of(rsp_rdata, 3) = caninte_c then
                            go(S_MODE_REQ);
                        else
                            init_failed;
                        end if;
                    end if;

                when S_MODE_REQ =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        polls <= 0;
                        go(S_MODE_POLL);
                    end if;

                when S_MODE_POLL =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        if unsigned(byte_of(rsp_rdata, 0) and MCP_CANSTAT_OPMOD_MASK_C)
                           = MCP_OPMODE_NORMAL_C then
                            init_done_o <= '1';
                            attempt     <= 0;
                            go(S_IDLE);
                        elsif polls + 1 >= MODE_POLL_MAX then
                            init_failed;
                        else
                            polls <= polls + 1;
                            timer <= mode_poll_c;
                            go(S_MODE_WAIT);
                        end if;
                    end if;

                when S_MODE_WAIT =>

                    if timer = 0 then
                        go(S_MODE_POLL);
                    else
                        timer <= timer - 1;
                    end if;

                when S_FAILED =>

                    init_fail_o <= '1';
                    if reinit_req = '1' then
                        reinit_req <= '0';
                        attempt    <= 0;
                        go(S_RESET_CMD);
                    end if;

                -- ----------------------------------------------------------------------------
                -- dispatch
                -- ----------------------------------------------------------------------------
                when S_IDLE =>

                    if reinit_req = '1' then
                        reinit_req <= '0';
                        attempt    <= 0;
                        go(S_RESET_CMD);
                    elsif blank_cnt = 0 and rx0_sync(1) = '0' and fifo_full = '0' then
                        rx_buf <= 0;
                        go(S_RX_READ);
                    elsif blank_cnt = 0 and rx1_sync(1) = '0' and fifo_full = '0' then
                        rx_buf <= 1;
                        go(S_RX_READ);
                    elsif blank_cnt = 0 and int_sync(1) = '0' then
                        go(S_INT_READ);
                    elsif abort_req = '1' then
                        abort_req <= '0';
                        cancel_op <= '0';
                        go(S_ABORT_SET);
                    elsif tx_valid_i = '1' and unsigned(tx_buf_i) <= 2
                          and pending(to_integer(unsigned(tx_buf_i)) mod 3) = '0' then
                        txq_buf  <= to_integer(unsigned(tx_buf_i));
                        txq_txp  <= tx_txp_i;
                        txq_send <= tx_send_i;
                        txl_busy <= '1';
                        -- a buffer being rewritten must not be fired before the WRITE ends
                        for b in 0 to 2 loop

                            if b = to_integer(unsigned(tx_buf_i)) then
                                txb_loaded(b) <= '0';
                            end if;

                        end loop;

                        go(S_TX_LOAD);
                    elsif err_req = '1' and turn_cnt = 0 then
                        err_req <= '0';
                        err_cnt <= err_poll_c;
                        go(S_ERR_CNT);
                    elsif cancel_chk = '1' or cancel_req /= "000" then
                        cancel_op  <= '1';
                        cancel_buf <= cancel_first;
                        go(cancel_next);
                    elsif status_req = '1' then
                        status_req <= '0';
                        go(S_STAT_RDSTAT);
                    end if;

                -- ----------------------------------------------------------------------------
                -- receive
                -- ----------------------------------------------------------------------------
                when S_RX_READ =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        -- rx_decode_proc decodes the held response into fifo_din
                        fifo_push <= '1';
                        go(S_RX_CLEAR);
                    end if;

                when S_RX_CLEAR =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        blank_cnt <= pin_settle_c;
                        go(S_IDLE);
                    end if;

                -- ----------------------------------------------------------------------------
                -- interrupts: TX done, errors, overflow
                -- ----------------------------------------------------------------------------
                when S_INT_READ =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        buf_idx <= 0;
                        -- an error interrupt: read TEC/REC/EFLG as soon as the INT is handled
                        if poll_on_int = '1' then
                            err_req <= '1';
                        end if;
                        if (byte_of(rsp_rdata, 0) and int_clear_c) = x"00"
                           and (byte_of(rsp_rdata, 1) and eflg_ovr_c) = x"00" then
                            -- nothing (left) to handle: the re-read after an overflow clear,
                            -- or INT already released
                            blank_cnt <= pin_settle_c;
                            go(S_IDLE);
                        elsif (byte_of(rsp_rdata, 0) and MCP_CANINTF_MERRF_C) /= x"00"
                              and pending /= "000" then
                            go(S_INT_TXB);
                        else
                            go(S_INT_CLEAR);
                        end if;
                    end if;

                when S_INT_TXB =>

                    if pending(buf_idx) = '0' and issued = '0' then
                        -- skip buffers with nothing pending
                        if buf_idx = 2 then
                            go(S_INT_CLEAR);
                        else
                            buf_idx <= buf_idx + 1;
                        end if;
                    elsif issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        if buf_idx = 2 then
                            go(S_INT_CLEAR);
                        else
                            buf_idx <= buf_idx + 1;
                            issued  <= '0';
                        end if;
                    end if;

                when S_INT_CLEAR =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        -- report after the flags are cleared
                        -- TX2IF..TX0IF
                        pend_v        := intf_q(4 downto 2);
                        tx_done_o     <= pend_v;
                        pending       <= (pending and not pend_v) or fire_set;
                        tx_err_o      <= txerr_acc;
                        tx_arb_lost_o <= mloa_acc;
                        int_valid_o   <= '1';
                        rx_overflow_o <= eflg_q(7 downto 6);
                        blank_cnt     <= pin_settle_c;
                        if (eflg_q and eflg_ovr_c) /= x"00" then
                            go(S_INT_CLR_OVR);
                        else
                            go(S_IDLE);
                        end if;
                    end if;

                when S_INT_CLR_OVR =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        -- read CANINTF/EFLG once more: an overflow that arrived after the read
                        -- set its RXnOVR bit again (and ERRIF was cleared meanwhile)
                        go(S_INT_READ);
                    end if;

                -- ----------------------------------------------------------------------------
                -- transmit
                -- ----------------------------------------------------------------------------
                when S_TX_LOAD =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        -- the frame is in the chip: the caller may change tx_*_i
                        txl_busy <= '0';
                        -- the command table used the old cache while the executor latched it
                        -- static indices: a dynamic-index write makes GHDL 2.0 infer a memory
                        for b in 0 to 2 loop

                            if b = txq_buf then
                                txp_cache(b)  <= txq_txp;
                                txp_known(b)  <= '1';
                                txb_loaded(b) <= '1';
                            end if;

                        end loop;

                        if txq_send = '1' then
                            go(S_TX_RTS);
                        else
                            tx_loaded_o <= '1';
                            go(S_IDLE);
                        end if;
                    end if;

                when S_TX_RTS =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        pending     <= pending or buf_bit(txq_buf) or fire_set;
                        tx_loaded_o <= '1';
                        go(S_IDLE);
                    end if;

                -- ----------------------------------------------------------------------------
                -- abort all pending transmissions
                -- ----------------------------------------------------------------------------
                when S_ABORT_SET =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        polls <= 0;
                        timer <= abort_wait_c;
                        go(abort_set_next);
                    end if;

                when S_ABORT_WAIT =>

                    if timer = 0 then
                        go(S_ABORT_STATUS);
                    else
                        timer <= timer - 1;
                    end if;

                when S_ABORT_STATUS =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        -- READ STATUS: bit 2/4/6 = TXB0/1/2 TXREQ, bit 3/5/7 = TX0/1/2IF
                        rd     := rsp_rdata;
                        pend_v := status_bits(byte_of(rd, 0), MCP_STATUS_TXB0_TXREQ_C,
                                              MCP_STATUS_TXB1_TXREQ_C, MCP_STATUS_TXB2_TXREQ_C);
                        mask_v := "00000" & status_bits(byte_of(rd, 0), MCP_STATUS_TX0IF_C,
                                                        MCP_STATUS_TX1IF_C, MCP_STATUS_TX2IF_C);
                        if cancel_op = '0' and (pending and pend_v) /= "000"
                           and polls + 1 < abort_polls_c then
                            -- still on the wire (a long frame at a low bit rate): wait again
                            polls <= polls + 1;
                            timer <= abort_wait_c;
                            go(S_ABORT_WAIT);
                        elsif cancel_op = '0' or cancel_again = '0' then
                            -- aborted: was pending (and selected), TXREQ clear, not completed
                            -- (TXnIF = 0); completed ones are reported by the INT path (TXnIF)
                            tx_aborted_o <= abort_sel and pending and not pend_v
                                            and not mask_v(2 downto 0);
                            pending      <= (pending and not (abort_sel and not pend_v
                                                              and not mask_v(2 downto 0)))
                                            or fire_set;
                            go(abort_end_next);
                        else
                            go(S_IDLE); -- a cancelled frame still on the wire: look again later
                        end if;
                    end if;

                -- ----------------------------------------------------------------------------
                -- status snapshot
                -- ----------------------------------------------------------------------------
                when S_STAT_FLAGS =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        buf_idx <= 0;
                        go(S_STAT_TXB);
                    end if;

                when S_STAT_TXB =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        if buf_idx = 2 then
                            status_valid_o <= '1';
                            go(S_IDLE);
                        else
                            buf_idx <= buf_idx + 1;
                            issued  <= '0';
                        end if;
                    end if;

                -- ----------------------------------------------------------------------------
                -- error poll: TEC, REC, then EFLG (err_proc keeps the values)
                -- ----------------------------------------------------------------------------
                when S_ERR_FLG =>

                    if issued = '0' then
                        issue;
                    elsif rsp_valid = '1' then
                        err_valid_o <= '1';
                        go(S_IDLE);
                        if chip_lost = '1' then
                            go(S_RESET_CMD);
                        end if;
                    end if;

            end case;

        end if;

    end process seq_proc;

    -- ---------------------------------------------------------------------------------------------
    -- RX frame decode (combinational): the RX buffer bytes of the executor's response (0 SIDH,
    -- 1 SIDL, 2 EID8, 3 EID0, 4 DLC, 5.. data) as one FIFO entry. No register of its own: the
    -- executor holds rsp_rdata from rsp_valid until it accepts the next command, and the push
    -- (the cycle after rsp_valid of S_RX_READ) comes before S_RX_CLEAR's command is accepted.
    -- ---------------------------------------------------------------------------------------------
    rx_decode_proc : process (rsp_rdata, rx_buf) is

        variable rd   : std_logic_vector(111 downto 0);
        variable id_v : std_logic_vector(28 downto 0);

    begin

        rd   := rsp_rdata;
        id_v := (others => '0');

        if (byte_of(rd, 1) and MCP_SIDL_IDE_C) /= x"00" then
            id_v         := byte_of(rd, 0) & rd(15 downto 13) & rd(9 downto 8)
                            & byte_of(rd, 2) & byte_of(rd, 3);
            fifo_din(70) <= '1';
            -- extended frames: RTR is DLC bit 6
            fifo_din(69) <= rd(32 + 6);
        else
            id_v(10 downto 0) := byte_of(rd, 0) & rd(15 downto 13);
            fifo_din(70)      <= '0';
            -- standard frames: RTR is SIDL.SRR
            fifo_din(69) <= rd(8 + 4);
        end if;

        fifo_din(99 downto 71) <= id_v;
        fifo_din(68 downto 65) <= rd(35 downto 32);
        fifo_din(64 downto 1)  <= rd(103 downto 40);

        if rx_buf = 0 then
            fifo_din(0) <= '0';
        else
            fifo_din(0) <= '1';
        end if;

    end process rx_decode_proc;

    -- simulation only: a push takes the response of an RX buffer read, still held by the
    -- executor (no command accepted since that response)
    -- pragma translate_off
    rx_hold_check_proc : process (clk_i) is

        variable rx_held : boolean := false;

    begin

        if rising_edge(clk_i) then
            assert fifo_push = '0' or rx_held
                report "mcp2510_ctrl: RX FIFO push without the RX buffer read's response"
                severity failure;
            if cmd_valid = '1' and cmd_ready = '1' then
                rx_held := false;
            end if;
            if rsp_valid = '1' and state = S_RX_READ then
                rx_held := true;
            end if;
        end if;

    end process rx_hold_check_proc;

    -- pragma translate_on

    -- ---------------------------------------------------------------------------------------------
    -- Response capture (datapath): decode what the chip answered in the state that asked for it
    -- ---------------------------------------------------------------------------------------------
    capture_proc : process (clk_i) is

        variable rd : std_logic_vector(111 downto 0);

    begin

        if rising_edge(clk_i) then
            rd := rsp_rdata;
            if rsp_valid = '1' then

                case state is

                    when S_INT_READ =>

                        intf_q    <= byte_of(rd, 0);
                        eflg_q    <= byte_of(rd, 1);
                        txerr_acc <= (others => '0');
                        mloa_acc  <= (others => '0');

                    when S_INT_TXB =>

                        if (byte_of(rd, 0) and MCP_TXBCTRL_TXERR_C) /= x"00" then
                            txerr_acc(buf_idx) <= '1';
                        end if;
                        if (byte_of(rd, 0) and MCP_TXBCTRL_MLOA_C) /= x"00" then
                            mloa_acc(buf_idx) <= '1';
                        end if;

                    when S_STAT_RDSTAT =>

                        status_rdstat_o <= byte_of(rd, 0);

                    when S_ERR_CNT =>

                        canstat_q <= byte_of(rd, 2);

                    when S_STAT_ERRCNT =>

                        status_tec_o <= byte_of(rd, 0);
                        status_rec_o <= byte_of(rd, 1);

                    when S_STAT_FLAGS =>

                        status_intf_o <= byte_of(rd, 0);
                        status_eflg_o <= byte_of(rd, 1);

                    when S_STAT_TXB =>

                        for b in 0 to 2 loop

                            if b = buf_idx then
                                status_txbctrl_o(8 * b + 7 downto 8 * b) <= byte_of(rd, 0);
                            end if;

                        end loop;

                    -- the other states' responses carry nothing to keep
                    when others =>

                        null;

                end case;

            end if;
        end if;

    end process capture_proc;

    -- a request is taken in S_IDLE when nothing more urgent is waiting
    tx_ready_o <= '1' when state = S_IDLE and reinit_req = '0' and reinit_i = '0'
                           and not (blank_cnt = 0 and (rx0_sync(1) = '0' or rx1_sync(1) = '0'
                                                 or int_sync(1) = '0'))
                                   and abort_req = '0' and tx_valid_i = '1'
                                   and unsigned(tx_buf_i) <= 2
                                   and pending(to_integer(unsigned(tx_buf_i)) mod 3) = '0' else
                  '0';

    -- error poll: OPMOD of its CANSTAT byte not normal while the chip was initialised in normal
    -- mode (S_ERR_FLG is only reached from S_IDLE): the chip was reset behind the controller's
    -- back (RESET# glitch, brown-out); its registers, TXRTSCTRL and TX buffers are gone, so
    -- S_ERR_FLG reports it (chip_lost_o) and runs the initialisation again from RESET
    chip_lost <= '1' when unsigned(canstat_q and MCP_CANSTAT_OPMOD_MASK_C)
                          /= MCP_OPMODE_NORMAL_C else
                 '0';

    -- an error poll after an INT with ERRIF or MERRF and, while TEC /= 0, after one with TXnIF
    -- (terr_proc: fewer than 8 successes of this node between two polls)
    poll_on_int <= '1' when (byte_of(rsp_rdata, 0)
                                and (MCP_CANINTF_ERRIF_C or MCP_CANINTF_MERRF_C)) /= x"00" else
                   '1' when (byte_of(rsp_rdata, 0) and tx_flags_c) /= x"00" and tec_base /= 0 else
                   '0';

    -- S_RESET_CMD clears init_done_o one cycle later (attempt is 0 since the last success)
    chip_lost_o <= '1' when state = S_ERR_FLG and issued = '1' and rsp_valid = '1'
                            and chip_lost = '1' else
                   '0';

    busy_o       <= '0' when state = S_IDLE or state = S_FAILED else '1';
    state_o      <= std_logic_vector(to_unsigned(seq_state_t'pos(state), 5));
    tx_pending_o <= pending;
    tx_busy_o    <= txl_busy;

    -- ---------------------------------------------------------------------------------------------
    -- Cancel of single TX buffers (tx_cancel_i): the BIT MODIFY TXBnCTRL.TXREQ = 0 still to send,
    -- the buffers whose outcome is open, and READ STATUS falling due one longest frame later (a
    -- frame already on the wire ends first; RX and INT are served meanwhile). seq_proc sends the
    -- instructions (S_ABORT_SET, S_ABORT_STATUS with cancel_op = '1') and updates pending.
    -- ---------------------------------------------------------------------------------------------
    cancel_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            cancel_req   <= (others => '0');
            cancel_wait  <= (others => '0');
            cancel_tmr   <= 0;
            cancel_chk   <= '0';
            cancel_polls <= 0;
        elsif rising_edge(clk_i) then
            -- only a pending buffer can be cancelled
            cancel_req <= cancel_req or (tx_cancel_i and pending);
            if cancel_tmr > 1 then
                cancel_tmr <= cancel_tmr - 1;
            elsif cancel_tmr = 1 then
                cancel_tmr <= 0;
                cancel_chk <= '1';
            end if;
            if state = S_ABORT_SET and cancel_op = '1' and issued = '1' and rsp_valid = '1' then
                cancel_req(cancel_buf)  <= '0';
                cancel_wait(cancel_buf) <= '1';
                cancel_tmr              <= abort_wait_c;
                cancel_polls            <= 0;
            end if;
            if state = S_ABORT_STATUS and cancel_op = '1' then
                cancel_chk <= '0';
                if issued = '1' and rsp_valid = '1' and cancel_again = '1' then
                    cancel_polls <= cancel_polls + 1;
                    cancel_tmr   <= abort_wait_c;
                elsif issued = '1' and rsp_valid = '1' then
                    cancel_wait <= (others => '0');
                end if;
            end if;
            -- the chip's RESET forgets every request
            if state = S_RESET_CMD then
                cancel_req  <= (others => '0');
                cancel_wait <= (others => '0');
                cancel_tmr  <= 0;
                cancel_chk  <= '0';
            end if;
        end if;

    end process cancel_proc;

    cancel_first   <= 0 when cancel_req(0) = '1' else
                      1 when cancel_req(1) = '1' else
                      2;
    cancel_next    <= S_ABORT_STATUS when cancel_chk = '1' else
                      S_ABORT_SET;
    cancel_stat    <= status_bits(byte_of(rsp_rdata, 0), MCP_STATUS_TXB0_TXREQ_C,
                                  MCP_STATUS_TXB1_TXREQ_C, MCP_STATUS_TXB2_TXREQ_C);
    cancel_again   <= '1' when (cancel_wait and pending and cancel_stat) /= "000"
                               and cancel_polls + 1 < abort_polls_c else
                      '0';
    abort_sel      <= cancel_wait when cancel_op = '1' else
                      "111";
    abort_set_next <= S_IDLE when cancel_op = '1' else
                      S_ABORT_WAIT;
    abort_end_next <= S_IDLE when cancel_op = '1' else
                      S_ABORT_CLEAR;

    -- ---------------------------------------------------------------------------------------------
    -- TXnRTS pins: a tx_fire_i pulse drives the pin low for TXRTS_LOW_NS (falling edge = start)
    -- ---------------------------------------------------------------------------------------------
    rts_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            rts_cnt        <= (others => 0);
            fire_set       <= (others => '0');
            tx_fire_drop_o <= (others => '0');
        elsif rising_edge(clk_i) then
            fire_set       <= (others => '0');
            tx_fire_drop_o <= (others => '0');

            for n in 0 to 2 loop

                if rts_cnt(n) /= 0 then
                    rts_cnt(n) <= rts_cnt(n) - 1;
                elsif tx_fire_i(n) = '1' and txb_loaded(n) = '1' then
                    rts_cnt(n)  <= txrts_low_c;
                    fire_set(n) <= '1';
                elsif tx_fire_i(n) = '1' then
                    -- not written since the last RESET (or being rewritten): the chip would
                    -- send undefined contents (ID 000h after a reset); dropped and reported
                    tx_fire_drop_o(n) <= '1';
                end if;

            end loop;

        end if;

    end process rts_proc;

    rts_pins_gen : for n in 0 to 2 generate
        mcp_txrts_n_o(n) <= '0' when rts_cnt(n) /= 0 else '1';
    end generate rts_pins_gen;

    mcp_reset_n_o <= rst_n_i;

    -- ---------------------------------------------------------------------------------------------
    -- Live error state: TEC/REC/EFLG of the last error poll (an error INT starts one at once),
    -- 0 from the RESET instruction on (the chip's own values after a reset)
    -- ---------------------------------------------------------------------------------------------
    err_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            err_tec_o  <= (others => '0');
            err_rec_o  <= (others => '0');
            err_eflg_o <= (others => '0');
        elsif rising_edge(clk_i) then
            if state = S_RESET_CMD then
                err_tec_o  <= (others => '0');
                err_rec_o  <= (others => '0');
                err_eflg_o <= (others => '0');
            elsif rsp_valid = '1' and state = S_ERR_CNT then
                err_tec_o <= byte_of(rsp_rdata, 0);
                err_rec_o <= byte_of(rsp_rdata, 1);
            elsif rsp_valid = '1' and state = S_ERR_FLG then
                err_eflg_o <= byte_of(rsp_rdata, 0);
            end if;
        end if;

    end process err_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Destroyed frames of this node, counted from TEC (+8 per transmit error, -1 per success
    -- while TEC > 0): a poll that reads TEC higher than the previous one reports
    -- ceil((TEC - previous) / 8) errors on tx_errors_o, one strobe per cycle from the second
    -- cycle after the read. Exact while fewer than 8 successes of this node lie between two polls
    -- (the poll follows every MERRF and, while TEC /= 0, every TXnIF); TXBnCTRL.TXERR cannot
    -- count, it stays set over the retries and MERRF comes for other nodes' errors too (fuzz
    -- finding 5).
    -- ---------------------------------------------------------------------------------------------
    terr_proc : process (clk_i, rst_n_i) is

        variable new_v  : unsigned(7 downto 0);
        variable add_v  : natural range 0 to 32;
        variable pend_v : natural range 0 to 95;

    begin

        if rst_n_i = '0' then
            tec_base    <= (others => '0');
            terr_pend   <= 0;
            terr_add    <= 0;
            tx_errors_o <= '0';
        elsif rising_edge(clk_i) then
            add_v  := 0;
            pend_v := terr_pend;
            new_v  := unsigned(byte_of(rsp_rdata, 0));
            if state = S_RESET_CMD then
                tec_base <= (others => '0');
            elsif rsp_valid = '1' and state = S_ERR_CNT then
                if new_v > tec_base then
                    add_v := to_integer(shift_right(resize(new_v - tec_base, 9) + 7, 3));
                end if;
                tec_base <= new_v;
            end if;
            tx_errors_o <= '0';
            if pend_v /= 0 then
                tx_errors_o <= '1';
                pend_v      := pend_v - 1;
            end if;
            -- the errors of a TEC read join the pending ones one cycle later (the subtraction and
            -- the addition are not on one path)
            terr_add <= add_v;
            pend_v   := pend_v + terr_add;
            if pend_v > 63 then
                pend_v := 63;
            end if;
            terr_pend <= pend_v;
        end if;

    end process terr_proc;

    -- ---------------------------------------------------------------------------------------------
    -- TX turnaround (tx_turn_c): armed when an INT sequence reports a TX-done, ended by the next
    -- TX load; the error poll does not start while it runs (seq_proc, S_IDLE)
    -- ---------------------------------------------------------------------------------------------
    turn_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            turn_cnt <= 0;
        elsif rising_edge(clk_i) then
            if state = S_INT_CLEAR and issued = '1' and rsp_valid = '1'
               and intf_q(4 downto 2) /= "000" then
                turn_cnt <= tx_turn_c;
            elsif state = S_TX_LOAD then
                turn_cnt <= 0;
            elsif turn_cnt /= 0 then
                turn_cnt <= turn_cnt - 1;
            end if;
        end if;

    end process turn_proc;

    -- ---------------------------------------------------------------------------------------------
    -- RX FIFO (first-word fall-through, block RAM). A frame is pushed 2 cycles before rx_valid_o
    -- shows it; S_IDLE reads an RX buffer only while fifo_full = '0' (the count includes a push
    -- of the previous cycle), so a push is never refused and no frame is lost here. rx_ready_i
    -- while empty is ignored by the FIFO.
    -- ---------------------------------------------------------------------------------------------
    rx_fifo_inst : entity work.canopen_fifo
        generic map (
            WIDTH         => fifo_w_c,
            DEPTH         => RX_FIFO_DEPTH,
            MIN_RAM_WORDS => fifo_ram_words_c
        )
        port map (
            clk_i   => clk_i,
            rst_n_i => rst_n_i,
            push_i  => fifo_push,
            data_i  => fifo_din,
            full_o  => fifo_full,
            ovf_o   => open,
            pop_i   => rx_ready_i,
            empty_o => fifo_empty,
            data_o  => fifo_q,
            count_o => open
        );

    rx_valid_o <= not fifo_empty;
    rx_id_o    <= fifo_q(99 downto 71);
    rx_ide_o   <= fifo_q(70);
    rx_rtr_o   <= fifo_q(69);
    rx_dlc_o   <= fifo_q(68 downto 65);
    rx_data_o  <= fifo_q(64 downto 1);
    rx_buf_o   <= fifo_q(0);

    int_canintf_o <= intf_q;
    int_eflg_o    <= eflg_q;

    -- ---------------------------------------------------------------------------------------------
    -- Instruction executor + SPI engine
    -- ---------------------------------------------------------------------------------------------
    instr_inst : entity work.mcp2510_instr
        generic map (
            CLK_FREQ_HZ   => CLK_FREQ_HZ,
            SPI_SCLK_HZ   => SPI_SCLK_HZ,
            CS_SETUP_NS   => CS_SETUP_NS,
            CS_HOLD_NS    => CS_HOLD_NS,
            CS_DISABLE_NS => CS_DISABLE_NS
        )
        port map (
            clk_i       => clk_i,
            rst_n_i     => rst_n_i,
            cmd_valid_i => cmd_valid,
            cmd_ready_o => cmd_ready,
            cmd_instr_i => cmd_instr,
            cmd_addr_i  => cmd_addr,
            cmd_len_i   => cmd_len,
            cmd_rxbuf_i => cmd_rxbuf,
            cmd_widx_o  => cmd_widx,
            cmd_wbyte_i => cmd_wbyte,
            rsp_valid_o => rsp_valid,
            rsp_rdata_o => rsp_rdata,
            rsp_len_o   => open,
            spi_cs_n_o  => spi_cs_n_o,
            spi_sck_o   => spi_sck_o,
            spi_mosi_o  => spi_mosi_o,
            spi_miso_i  => spi_miso_i
        );

end architecture rtl;
