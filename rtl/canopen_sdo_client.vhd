-- =================================================================================================
-- Title    : canopen_sdo_client
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   CiA 301 SDO client: expedited and segmented download and upload, aborts, timeout.
-- Purpose:
--   The host starts one transfer at a time (req_valid_i) on an object of one server node. The
--   client builds the SDO request frames, hands them to the master FSM (tx_req_o / tx_ack_i)
--   and checks the server's responses, which the FSM passes in (rx_valid_i, answered by
--   rx_done_o two clock cycles later, three when a buffer access is still running).
--   * Download, 1..4 bytes: expedited initiate (e = 1, s = 1, n = 4 - size). 0 or 5..BUF_BYTES
--     bytes: initiate with s = 1 and the 32-bit size, then segments of up to 7 bytes (toggle
--     from 0, c = 1 on the last one; size 0 sends one empty segment with n = 7, c = 1).
--   * Upload: initiate upload; an expedited response (size 4 - n, or 4 when s = 0) or segments
--     requested until c = 1. The bytes go to the transfer buffer from address 0.
--   * Checks, each answered by an abort frame from the client: command specifier (0504 0001h,
--     also for a DLC other than 8), multiplexer of an initiate response (0800 0000h), toggle bit
--     (0503 0000h), indicated or received size above BUF_BYTES (0504 0005h), received total
--     different from the indicated size (0607 0010h), no response within timeout_ms_i
--     (0504 0000h; timeout_ms_i = 0 means TIMEOUT_DEF_MS), more than EMPTY_SEGS_MAX upload
--     segments with c = 0 and no data (0800 0000h). A server abort with our multiplexer ends
--     the transfer with its code. A transfer ends (done_o) once its abort frame has been taken.
--   * Liveness: every wait has a timeout and every transfer a bounded number of requests
--     (download: one per 7 bytes; upload: every segment but EMPTY_SEGS_MAX of them carries a
--     byte, and at most BUF_BYTES are accepted), so every transfer ends within a bound
--     (docs/canopen_sdo_client.md, "Bounds"). A remote frame (rx_rtr_i) is never a response:
--     it is flagged unexpected and changes nothing.
--   * Transfer buffer: BUF_BYTES bytes in four byte lanes (bytes 4w+k in lane k), each a simple
--     dual-port RAM with a registered read (M9K). The host reads and writes 32-bit words; the
--     client reads 7 bytes for the next download segment in two cycles (prefetched while the
--     previous segment is on the bus) and writes up to 7 received bytes in two cycles. While
--     busy_o = 1 the buffer belongs to the client: host writes are ignored and buf_rdata_o is
--     undefined.
--   Timing: see docs/canopen_sdo_client.md.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_pkg.all;
    use work.canopen_util_pkg.all;

entity canopen_sdo_client is
    generic (
        BUF_BYTES      : positive range 8 to 1024  := 256;  -- transfer buffer [bytes], power of 2
        TIMEOUT_DEF_MS : positive range 1 to 65535 := 1000; -- timeout used for timeout_ms_i = 0
        EMPTY_SEGS_MAX : natural range 0 to 255    := 3     -- empty non-final upload segments
    );
    port (
        -- clock and reset
        clk_i     : in    std_logic; -- system clock
        rst_n_i   : in    std_logic; -- async reset, active low (synced)
        tick_ms_i : in    std_logic; -- 1-cycle strobe every ms (timeout base)
        -- request from the host registers
        req_valid_i    : in    std_logic;                     -- pulse: start (ignored if busy)
        req_upload_i   : in    std_logic;                     -- 1 = upload, 0 = download
        req_node_i     : in    std_logic_vector(6 downto 0);  -- server node-ID 1..127
        req_index_i    : in    std_logic_vector(15 downto 0); -- object index
        req_subindex_i : in    std_logic_vector(7 downto 0);  -- object subindex
        req_size_i     : in    std_logic_vector(10 downto 0); -- download: bytes to send
        cob_req_i      : in    std_logic_vector(10 downto 0); -- client->server, 0 = 600h+node
        cob_resp_i     : in    std_logic_vector(10 downto 0); -- server->client, 0 = 580h+node
        timeout_ms_i   : in    std_logic_vector(15 downto 0); -- per wait [ms], 0 = TIMEOUT_DEF_MS
        -- status
        busy_o       : out   std_logic;                     -- a transfer is running
        done_o       : out   std_logic;                     -- strobe: transfer ended
        error_o      : out   std_logic;                     -- the transfer ended in an abort
        abort_code_o : out   std_logic_vector(31 downto 0); -- received or sent abort code
        abort_sent_o : out   std_logic;                     -- 1: client aborted, 0: server
        size_o       : out   std_logic_vector(10 downto 0); -- bytes transferred
        -- host access to the transfer buffer (32-bit words, little-endian bytes)
        buf_addr_i  : in    std_logic_vector(7 downto 0);  -- word address
        buf_we_i    : in    std_logic;                     -- write buf_wdata_i (idle only)
        buf_wdata_i : in    std_logic_vector(31 downto 0); -- word to write
        buf_rdata_o : out   std_logic_vector(31 downto 0); -- word read, 1 cycle after address
        -- frame to transmit (towards the FSM)
        tx_req_o  : out   std_logic;                     -- level: a frame is waiting
        tx_id_o   : out   std_logic_vector(10 downto 0); -- identifier
        tx_dlc_o  : out   std_logic_vector(3 downto 0);  -- data length code (always 8)
        tx_data_o : out   std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        tx_ack_i  : in    std_logic;                     -- strobe: frame taken
        -- received frame (from the FSM)
        rx_valid_i      : in    std_logic;                     -- strobe: process this frame
        rx_id_i         : in    std_logic_vector(10 downto 0); -- identifier
        rx_rtr_i        : in    std_logic;                     -- remote frame (never ours)
        rx_dlc_i        : in    std_logic_vector(3 downto 0);  -- data length code
        rx_data_i       : in    std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        rx_done_o       : out   std_logic;                     -- strobe: frame processed
        rx_reply_o      : out   std_logic;                     -- with rx_done_o: tx_req_o set
        rx_unexpected_o : out   std_logic;                     -- with rx_done_o: not ours
        state_o         : out   std_logic_vector(3 downto 0)   -- internal state (debug)
    );
end entity canopen_sdo_client;

architecture rtl of canopen_sdo_client is

    constant addr_w_c : positive := clog2(BUF_BYTES); -- byte address width
    constant word_w_c : positive := addr_w_c - 2;     -- word (lane RAM) address width
    constant words_c  : positive := BUF_BYTES / 4;    -- words per lane RAM
    constant cnt_w_c  : positive := addr_w_c + 1;     -- byte counts 0..BUF_BYTES

    function check_config return boolean is
    begin

        assert 2 ** addr_w_c = BUF_BYTES
            report "canopen_sdo_client: BUF_BYTES = " & integer'image(BUF_BYTES)
                   & " is not a power of 2"
            severity failure;
        assert false
            report "canopen_sdo_client: transfer buffer " & integer'image(BUF_BYTES)
                   & " bytes = 4 byte lanes x " & integer'image(words_c) & " words"
            severity note;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    -- SDO frame layout (CiA 301 7.2.4.3; not in canopen_pkg): fields of byte 0
    constant sdo_cs_hi_c     : natural := 7; -- command specifier: bits 7..5
    constant sdo_cs_lo_c     : natural := 5;
    constant sdo_t_bit_c     : natural := 4; -- toggle (segment frames)
    constant sdo_n_hi_c      : natural := 3; -- n: bits 3..2 (initiate), 3..1 (segment)
    constant sdo_init_n_lo_c : natural := 2;
    constant sdo_seg_n_lo_c  : natural := 1;
    constant sdo_e_bit_c     : natural := 1; -- expedited (initiate frames)
    constant sdo_s_bit_c     : natural := 0; -- size indicated (initiate frames)
    constant sdo_c_bit_c     : natural := 0; -- no more segments (segment frames)
    -- byte 0 bits 4..0 of an initiate download: segmented with size (x = 0, n = 0, e = 0,
    -- s = 1); bits 1..0 of an expedited one with size (e = 1, s = 1); reserved bits are 0
    constant sdo_init_seg_c  : std_logic_vector(4 downto 0) := "00001";
    constant sdo_exp_sized_c : std_logic_vector(1 downto 0) := "11";
    constant sdo_reserved5_c : std_logic_vector(4 downto 0) := "00000";
    -- SDO frames always have 8 data bytes; a segment carries up to 7, an expedited frame 4
    constant sdo_dlc_c       : std_logic_vector(3 downto 0) := "1000";
    constant sdo_seg_bytes_c : natural                      := 7;
    constant sdo_exp_bytes_c : natural                      := 4;

    type state_t is (
        S_IDLE,         -- no transfer
        S_FETCH,        -- download: the first 7 buffer bytes are being read
        S_DL_INIT_TX,   -- initiate download request waiting for tx_ack_i
        S_DL_INIT_WAIT, -- waiting for the initiate download response
        S_DL_SEG_TX,    -- download segment request waiting for tx_ack_i
        S_DL_SEG_WAIT,  -- waiting for the download segment response
        S_UL_INIT_TX,   -- initiate upload request waiting for tx_ack_i
        S_UL_INIT_WAIT, -- waiting for the initiate upload response
        S_UL_SEG_TX,    -- upload segment request waiting for tx_ack_i
        S_UL_SEG_WAIT,  -- waiting for the upload segment response
        S_ABORT_TX,     -- abort frame from the client waiting for tx_ack_i
        S_FINISH        -- upload: last bytes being written to the buffer
    );

    function state_code (s : state_t) return std_logic_vector is
    begin

        return std_logic_vector(to_unsigned(state_t'pos(s), 4));

    end function state_code;

    -- byte j (0..3) of a word

    function byte_of (v : std_logic_vector(31 downto 0); j : unsigned(1 downto 0))
        return std_logic_vector is
    begin

        case j is

            when "00" =>

                return v(7 downto 0);

            when "01" =>

                return v(15 downto 8);

            when "10" =>

                return v(23 downto 16);

            when others =>

                return v(31 downto 24);

        end case;

    end function byte_of;

    -- lane outputs read at byte address a (lane k holds byte 4w+k) -> bytes a..a+3 in order

    function from_lanes (v : std_logic_vector(31 downto 0); lo : unsigned(1 downto 0))
        return std_logic_vector is
    begin

        case lo is

            when "00" =>

                return v;

            when "01" =>

                return v(7 downto 0) & v(31 downto 8);

            when "10" =>

                return v(15 downto 0) & v(31 downto 16);

            when others =>

                return v(23 downto 0) & v(31 downto 24);

        end case;

    end function from_lanes;

    -- the first n bytes of a 7-byte vector, the others zero

    function keep_bytes (v : std_logic_vector(55 downto 0); n : unsigned(3 downto 0))
        return std_logic_vector is

        variable r : std_logic_vector(55 downto 0);

    begin

        r := v;

        for j in 0 to sdo_seg_bytes_c - 1 loop

            if n <= j then
                r(8 * j + 7 downto 8 * j) := (others => '0');
            end if;

        end loop;

        return r;

    end function keep_bytes;

    type lane_addr_array_t is array (0 to 3) of unsigned(word_w_c - 1 downto 0);

    type lane_data_array_t is array (0 to 3) of std_logic_vector(7 downto 0);

    type lane_ram_t is array (0 to words_c - 1) of std_logic_vector(7 downto 0);

    -- transfer state
    signal state : state_t;
    -- request latched at req_valid_i
    signal upload : std_logic;
    signal idx    : std_logic_vector(15 downto 0);
    signal sub    : std_logic_vector(7 downto 0);
    signal cob_tx : std_logic_vector(10 downto 0);
    signal cob_rx : std_logic_vector(10 downto 0);
    -- download: bytes to send; '1' when they fit in one expedited frame
    signal size_req  : unsigned(cnt_w_c - 1 downto 0);
    signal expedited : std_logic;
    -- download: bytes put into frames so far; upload: bytes received so far
    signal pos : unsigned(cnt_w_c - 1 downto 0);
    -- download: bytes confirmed by the server
    signal acked : unsigned(cnt_w_c - 1 downto 0);
    -- download: the segment in flight is the last one
    signal last_seg : std_logic;
    -- toggle bit of the segment request in flight
    signal toggle : std_logic;
    -- upload: the server indicated the size (ind_size, already checked against BUF_BYTES)
    signal size_known : std_logic;
    signal ind_size   : unsigned(cnt_w_c - 1 downto 0);
    -- response timeout: value of the transfer [ms] and ms ticks left
    signal tmo_ms  : unsigned(15 downto 0);
    signal tmo_cnt : unsigned(15 downto 0);
    -- upload: segments with c = 0 and no data received so far in this transfer
    signal empty_cnt : natural range 0 to EMPTY_SEGS_MAX;
    -- frame towards the FSM
    signal tx_req  : std_logic;
    signal tx_data : std_logic_vector(63 downto 0);
    -- received frame waiting to be processed
    signal rx_pend   : std_logic;
    signal rx_id_q   : std_logic_vector(10 downto 0);
    signal rx_rtr_q  : std_logic;
    signal rx_dlc_q  : std_logic_vector(3 downto 0);
    signal rx_data_q : std_logic_vector(63 downto 0);
    -- rx strobes
    signal rx_done_q  : std_logic;
    signal rx_reply_q : std_logic;
    signal rx_unexp_q : std_logic;
    -- status towards the host
    signal done_q       : std_logic;
    signal error_q      : std_logic;
    signal abort_code_q : std_logic_vector(31 downto 0);
    signal abort_sent_q : std_logic;
    signal size_q       : unsigned(cnt_w_c - 1 downto 0);
    -- buffer read unit: phase (0 idle, 1 bytes a..a+3 addressed, 2 bytes a+4..a+7 addressed,
    -- 3 last capture), byte address a, the 7 bytes read (next download segment)
    signal fetch_ph   : natural range 0 to 3;
    signal fetch_addr : unsigned(addr_w_c - 1 downto 0);
    signal seg_buf    : std_logic_vector(55 downto 0);
    -- buffer write unit: phase (0 idle, 1 bytes 0..3, 2 bytes 4..6), byte address, byte count
    -- and the bytes (byte j at 8j+7..8j)
    signal wr_ph   : natural range 0 to 2;
    signal wr_addr : unsigned(addr_w_c - 1 downto 0);
    signal wr_cnt  : unsigned(3 downto 0);
    signal wr_data : std_logic_vector(55 downto 0);
    -- lane RAM ports
    signal lane_we    : std_logic_vector(3 downto 0);
    signal lane_waddr : lane_addr_array_t;
    signal lane_wdata : lane_data_array_t;
    signal lane_raddr : lane_addr_array_t;
    signal lane_rdata : std_logic_vector(31 downto 0);

begin

    -- ---------------------------------------------------------------------------------------------
    -- Lane RAM ports: the client's read/write units when active, the host otherwise. Byte a+j
    -- of a 4-byte group at byte address a lives in lane (a+j) mod 4, word (a+j)/4.
    -- ---------------------------------------------------------------------------------------------
    lane_ports_proc : process (buf_addr_i, buf_wdata_i, buf_we_i, fetch_addr, fetch_ph, state,
                               wr_addr, wr_cnt, wr_data, wr_ph) is

        variable ga   : unsigned(addr_w_c - 1 downto 0);
        variable grp  : std_logic_vector(31 downto 0);
        variable gcnt : unsigned(3 downto 0);
        variable j    : unsigned(1 downto 0);

    begin

        -- write port
        if wr_ph /= 0 then
            if wr_ph = 1 then
                ga   := wr_addr;
                grp  := wr_data(31 downto 0);
                gcnt := wr_cnt;
            else
                ga   := wr_addr + 4;
                grp  := x"00" & wr_data(55 downto 32);
                gcnt := wr_cnt - 4;
            end if;

            for b in 0 to 3 loop

                j := to_unsigned(b, 2) - ga(1 downto 0);

                if to_unsigned(b, 2) < ga(1 downto 0) then
                    lane_waddr(b) <= ga(addr_w_c - 1 downto 2) + 1;
                else
                    lane_waddr(b) <= ga(addr_w_c - 1 downto 2);
                end if;

                lane_wdata(b) <= byte_of(grp, j);

                if resize(j, 4) < gcnt then
                    lane_we(b) <= '1';
                else
                    lane_we(b) <= '0';
                end if;

            end loop;

        else

            for b in 0 to 3 loop

                lane_waddr(b) <= unsigned(buf_addr_i(word_w_c - 1 downto 0));
                lane_wdata(b) <= buf_wdata_i(8 * b + 7 downto 8 * b);

                if state = S_IDLE then
                    lane_we(b) <= buf_we_i;
                else
                    lane_we(b) <= '0';
                end if;

            end loop;

        end if;

        -- read port
        if fetch_ph = 1 or fetch_ph = 2 then
            if fetch_ph = 1 then
                ga := fetch_addr;
            else
                ga := fetch_addr + 4;
            end if;

            for b in 0 to 3 loop

                if to_unsigned(b, 2) < ga(1 downto 0) then
                    lane_raddr(b) <= ga(addr_w_c - 1 downto 2) + 1;
                else
                    lane_raddr(b) <= ga(addr_w_c - 1 downto 2);
                end if;

            end loop;

        else

            for b in 0 to 3 loop

                lane_raddr(b) <= unsigned(buf_addr_i(word_w_c - 1 downto 0));

            end loop;

        end if;

    end process lane_ports_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Four byte-lane RAMs (simple dual port, registered read, no reset: M9K)
    -- ---------------------------------------------------------------------------------------------

    lane_gen : for b in 0 to 3 generate

        -- bytes 4w+b of the transfer buffer (only the transferred bytes are defined)
        signal ram : lane_ram_t;

    begin

        ram_proc : process (clk_i) is
        begin

            if rising_edge(clk_i) then
                if lane_we(b) = '1' then
                    ram(to_integer(lane_waddr(b))) <= lane_wdata(b);
                end if;
                lane_rdata(8 * b + 7 downto 8 * b) <= ram(to_integer(lane_raddr(b)));
            end if;

        end process ram_proc;

    end generate lane_gen;

    -- ---------------------------------------------------------------------------------------------
    -- Transfer sequencer
    -- ---------------------------------------------------------------------------------------------
    main_proc : process (clk_i, rst_n_i) is

        variable cmd       : std_logic_vector(7 downto 0);
        variable mux_ok    : boolean;
        variable is_wait   : boolean;
        variable rx_go     : boolean;
        variable tmo_exp   : boolean;
        variable cnt       : unsigned(3 downto 0);
        variable rem_v     : unsigned(cnt_w_c - 1 downto 0);
        variable total     : unsigned(cnt_w_c downto 0);
        variable ind_v     : unsigned(31 downto 0);
        variable last_v    : std_logic;
        variable tgl_v     : std_logic;
        variable data_v    : std_logic_vector(55 downto 0);
        variable do_dl_seg : boolean;
        variable do_ul_seg : boolean;
        variable do_abort  : boolean;
        variable abort_v   : std_logic_vector(31 downto 0);
        variable do_end    : boolean;
        variable end_err   : std_logic;
        variable end_code  : std_logic_vector(31 downto 0);
        variable end_sent  : std_logic;

    begin

        if rst_n_i = '0' then
            state        <= S_IDLE;
            upload       <= '0';
            expedited    <= '0';
            last_seg     <= '0';
            toggle       <= '0';
            size_known   <= '0';
            size_req     <= (others => '0');
            pos          <= (others => '0');
            acked        <= (others => '0');
            ind_size     <= (others => '0');
            tmo_ms       <= (others => '0');
            tmo_cnt      <= (others => '0');
            empty_cnt    <= 0;
            tx_req       <= '0';
            rx_pend      <= '0';
            rx_done_q    <= '0';
            rx_reply_q   <= '0';
            rx_unexp_q   <= '0';
            done_q       <= '0';
            error_q      <= '0';
            abort_code_q <= (others => '0');
            abort_sent_q <= '0';
            size_q       <= (others => '0');
            fetch_ph     <= 0;
            wr_ph        <= 0;
        elsif rising_edge(clk_i) then
            done_q     <= '0';
            rx_done_q  <= '0';
            rx_reply_q <= '0';
            rx_unexp_q <= '0';
            do_dl_seg  := false;
            do_ul_seg  := false;
            do_abort   := false;
            abort_v    := (others => '0');
            do_end     := false;
            end_err    := '0';
            end_code   := (others => '0');
            end_sent   := '0';
            tgl_v      := '0';

            -- response timer: expires at the (timeout + 1)-th ms tick, i.e. after at least
            -- timeout_ms_i ms; every frame built and every tx_ack_i reloads it (tmo_ms is never
            -- 0: timeout_ms_i = 0 loads TIMEOUT_DEF_MS)
            tmo_exp := false;

            if tick_ms_i = '1' then
                if tmo_cnt = 0 then
                    tmo_exp := true;
                else
                    tmo_cnt <= tmo_cnt - 1;
                end if;
            end if;

            -- buffer read unit ---------------------------------------------------------------
            case fetch_ph is

                when 1 =>

                    fetch_ph <= 2;

                when 2 =>

                    seg_buf(31 downto 0) <= from_lanes(lane_rdata, fetch_addr(1 downto 0));
                    fetch_ph             <= 3;

                when 3 =>

                    data_v(31 downto 0)   := from_lanes(lane_rdata, fetch_addr(1 downto 0));
                    seg_buf(55 downto 32) <= data_v(23 downto 0);
                    fetch_ph              <= 0;

                when others =>

                    null;

            end case;

            -- buffer write unit --------------------------------------------------------------
            if wr_ph = 1 then
                if wr_cnt > sdo_exp_bytes_c then
                    wr_ph <= 2;
                else
                    wr_ph <= 0;
                end if;
            elsif wr_ph = 2 then
                wr_ph <= 0;
            end if;

            -- received frame -----------------------------------------------------------------
            -- A response is only processed once the buffer units are idle (at most one cycle
            -- of delay in practice, see docs).
            is_wait := state = S_DL_INIT_WAIT or state = S_DL_SEG_WAIT
                       or state = S_UL_INIT_WAIT or state = S_UL_SEG_WAIT;
            rx_go   := rx_pend = '1' and not (is_wait and (fetch_ph /= 0 or wr_ph /= 0));
            cmd     := rx_data_q(7 downto 0);
            mux_ok  := rx_data_q(31 downto 8) = sub & idx;

            if rx_go then
                rx_pend   <= '0';
                rx_done_q <= '1';

                if not is_wait or rx_id_q /= cob_rx or rx_rtr_q = '1' then
                    -- idle, no response expected now, another node, or a remote frame (a
                    -- request, never a response): not ours
                    rx_unexp_q <= '1';
                elsif rx_dlc_q /= sdo_dlc_c then
                    do_abort := true;
                    abort_v  := SDO_ABORT_CS_C;
                elsif cmd(sdo_cs_hi_c downto sdo_cs_lo_c) = SDO_CS_ABORT_C then
                    -- server abort: only for our multiplexer
                    if mux_ok then
                        do_end   := true;
                        end_err  := '1';
                        end_code := rx_data_q(63 downto 32);
                        end_sent := '0';
                    else
                        rx_unexp_q <= '1';
                    end if;
                else

                    case state is

                        when S_DL_INIT_WAIT =>

                            if cmd(sdo_cs_hi_c downto sdo_cs_lo_c) /= SDO_SCS_DL_INIT_C then
                                do_abort := true;
                                abort_v  := SDO_ABORT_CS_C;
                            elsif not mux_ok then
                                do_abort := true;
                                abort_v  := SDO_ABORT_GENERAL_C;
                            elsif expedited = '1' then
                                acked  <= size_req;
                                do_end := true;
                            else
                                do_dl_seg := true;
                                tgl_v     := '0';
                            end if;

                        when S_DL_SEG_WAIT =>

                            if cmd(sdo_cs_hi_c downto sdo_cs_lo_c) /= SDO_SCS_DL_SEG_C then
                                do_abort := true;
                                abort_v  := SDO_ABORT_CS_C;
                            elsif cmd(sdo_t_bit_c) /= toggle then
                                do_abort := true;
                                abort_v  := SDO_ABORT_TOGGLE_C;
                            else
                                acked <= pos;

                                if last_seg = '1' then
                                    do_end := true;
                                else
                                    do_dl_seg := true;
                                    tgl_v     := not toggle;
                                end if;
                            end if;

                        when S_UL_INIT_WAIT =>

                            ind_v := unsigned(rx_data_q(63 downto 32));

                            if cmd(sdo_cs_hi_c downto sdo_cs_lo_c) /= SDO_SCS_UL_INIT_C then
                                do_abort := true;
                                abort_v  := SDO_ABORT_CS_C;
                            elsif not mux_ok then
                                do_abort := true;
                                abort_v  := SDO_ABORT_GENERAL_C;
                            elsif cmd(sdo_e_bit_c) = '1' then
                                -- expedited: 4 - n bytes (4 when the size is not indicated)
                                if cmd(sdo_s_bit_c) = '1' then
                                    cnt := sdo_exp_bytes_c
                                           - resize(unsigned(cmd(sdo_n_hi_c
                                                                    downto sdo_init_n_lo_c)), 4);
                                else
                                    cnt := to_unsigned(sdo_exp_bytes_c, 4);
                                end if;
                                wr_ph                <= 1;
                                wr_addr              <= (others => '0');
                                wr_cnt               <= cnt;
                                wr_data(31 downto 0) <= rx_data_q(63 downto 32);
                                pos                  <= resize(cnt, cnt_w_c);
                                state                <= S_FINISH;
                            elsif cmd(sdo_s_bit_c) = '1' and ind_v > BUF_BYTES then
                                do_abort := true;
                                abort_v  := SDO_ABORT_OUT_OF_MEM_C;
                            else
                                size_known <= cmd(sdo_s_bit_c);
                                ind_size   <= resize(ind_v, cnt_w_c);
                                do_ul_seg  := true;
                                tgl_v      := '0';
                            end if;

                        when S_UL_SEG_WAIT =>

                            cnt   := sdo_seg_bytes_c
                                     - resize(unsigned(cmd(sdo_n_hi_c downto sdo_seg_n_lo_c)), 4);
                            total := resize(pos, cnt_w_c + 1) + cnt;

                            if cmd(sdo_cs_hi_c downto sdo_cs_lo_c) /= SDO_SCS_UL_SEG_C then
                                do_abort := true;
                                abort_v  := SDO_ABORT_CS_C;
                            elsif cmd(sdo_t_bit_c) /= toggle then
                                do_abort := true;
                                abort_v  := SDO_ABORT_TOGGLE_C;
                            elsif cmd(sdo_c_bit_c) = '0' and cnt = 0
                                  and empty_cnt = EMPTY_SEGS_MAX then
                                -- one more segment without data and without an end: the server
                                -- keeps the transfer alive without progress
                                do_abort := true;
                                abort_v  := SDO_ABORT_GENERAL_C;
                            elsif size_known = '1' and total > ind_size then
                                do_abort := true;
                                abort_v  := SDO_ABORT_LENGTH_C;
                            elsif total > BUF_BYTES then
                                do_abort := true;
                                abort_v  := SDO_ABORT_OUT_OF_MEM_C;
                            elsif cmd(sdo_c_bit_c) = '1' and size_known = '1'
                                  and total /= ind_size then
                                do_abort := true;
                                abort_v  := SDO_ABORT_LENGTH_C;
                            else
                                wr_ph   <= 1;
                                wr_addr <= pos(addr_w_c - 1 downto 0);
                                wr_cnt  <= cnt;
                                wr_data <= rx_data_q(63 downto 8);
                                pos     <= total(cnt_w_c - 1 downto 0);

                                if cmd(sdo_c_bit_c) = '1' then
                                    state <= S_FINISH;
                                else
                                    do_ul_seg := true;
                                    tgl_v     := not toggle;

                                    if cnt = 0 then
                                        empty_cnt <= empty_cnt + 1;
                                    end if;
                                end if;
                            end if;

                        when others =>

                            null;

                    end case;

                end if;
            end if;

            -- per state ----------------------------------------------------------------------
            case state is

                when S_IDLE =>

                    if req_valid_i = '1' then
                        upload       <= req_upload_i;
                        idx          <= req_index_i;
                        sub          <= req_subindex_i;
                        empty_cnt    <= 0;
                        error_q      <= '0';
                        abort_code_q <= (others => '0');
                        abort_sent_q <= '0';
                        size_q       <= (others => '0');
                        pos          <= (others => '0');
                        acked        <= (others => '0');
                        size_known   <= '0';
                        last_seg     <= '0';
                        toggle       <= '0';

                        -- every wait is bounded: 0 selects the default timeout
                        if unsigned(timeout_ms_i) = 0 then
                            tmo_ms  <= to_unsigned(TIMEOUT_DEF_MS, 16);
                            tmo_cnt <= to_unsigned(TIMEOUT_DEF_MS, 16);
                        else
                            tmo_ms  <= unsigned(timeout_ms_i);
                            tmo_cnt <= unsigned(timeout_ms_i);
                        end if;

                        if unsigned(cob_req_i) = 0 then
                            cob_tx <= cob_id(FC_SDO_RX_C, req_node_i);
                        else
                            cob_tx <= cob_req_i;
                        end if;

                        if unsigned(cob_resp_i) = 0 then
                            cob_rx <= cob_id(FC_SDO_TX_C, req_node_i);
                        else
                            cob_rx <= cob_resp_i;
                        end if;

                        if req_upload_i = '1' then
                            tx_data <= x"00000000" & req_subindex_i & req_index_i
                                       & SDO_CCS_UL_INIT_C & sdo_reserved5_c;
                            tx_req  <= '1';
                            state   <= S_UL_INIT_TX;
                        elsif unsigned(req_size_i) > BUF_BYTES then
                            -- more than the buffer holds: refused without a frame
                            done_q       <= '1';
                            error_q      <= '1';
                            abort_code_q <= SDO_ABORT_OUT_OF_MEM_C;
                            abort_sent_q <= '1';
                        else
                            size_req   <= resize(unsigned(req_size_i), cnt_w_c);
                            fetch_ph   <= 1;
                            fetch_addr <= (others => '0');
                            state      <= S_FETCH;
                        end if;
                    end if;

                when S_FETCH =>

                    if fetch_ph = 0 then
                        tmo_cnt <= tmo_ms;
                        tx_req  <= '1';
                        state   <= S_DL_INIT_TX;

                        if size_req /= 0 and size_req <= sdo_exp_bytes_c then
                            -- expedited, size indicated: n = 4 - size
                            cnt       := resize(size_req, 4);
                            data_v    := keep_bytes(seg_buf, cnt);
                            cnt       := sdo_exp_bytes_c - cnt;
                            tx_data   <= data_v(31 downto 0) & sub & idx & SDO_CCS_DL_INIT_C
                                         & '0' & std_logic_vector(cnt(1 downto 0))
                                         & sdo_exp_sized_c;
                            expedited <= '1';
                        else
                            -- segmented, size indicated
                            tx_data   <= std_logic_vector(resize(size_req, 32)) & sub & idx
                                         & SDO_CCS_DL_INIT_C & sdo_init_seg_c;
                            expedited <= '0';
                        end if;
                    end if;

                when S_DL_INIT_TX | S_DL_SEG_TX | S_UL_INIT_TX | S_UL_SEG_TX =>

                    if tx_ack_i = '1' then
                        tx_req  <= '0';
                        tmo_cnt <= tmo_ms;

                        case state is

                            when S_DL_INIT_TX =>

                                state <= S_DL_INIT_WAIT;

                            when S_DL_SEG_TX =>

                                state <= S_DL_SEG_WAIT;

                            when S_UL_INIT_TX =>

                                state <= S_UL_INIT_WAIT;

                            when others =>

                                state <= S_UL_SEG_WAIT;

                        end case;

                    elsif tmo_exp then
                        -- the FSM did not take the request: give up (no frame can be sent)
                        tx_req   <= '0';
                        do_end   := true;
                        end_err  := '1';
                        end_code := SDO_ABORT_TIMEOUT_C;
                        end_sent := '1';
                    end if;

                when S_DL_INIT_WAIT | S_DL_SEG_WAIT | S_UL_INIT_WAIT | S_UL_SEG_WAIT =>

                    if tmo_exp and not rx_go then
                        do_abort := true;
                        abort_v  := SDO_ABORT_TIMEOUT_C;
                    end if;

                when S_ABORT_TX =>

                    if tx_ack_i = '1' or tmo_exp then
                        tx_req   <= '0';
                        do_end   := true;
                        end_err  := '1';
                        end_code := abort_code_q;
                        end_sent := '1';
                    end if;

                when S_FINISH =>

                    if wr_ph = 0 then
                        do_end := true;
                    end if;

            end case;

            -- actions ------------------------------------------------------------------------
            if do_dl_seg then
                -- next download segment from the prefetched bytes, then prefetch the one after
                rem_v := size_req - pos;

                if rem_v > sdo_seg_bytes_c then
                    cnt    := to_unsigned(sdo_seg_bytes_c, 4);
                    last_v := '0';
                else
                    cnt    := rem_v(3 downto 0);
                    last_v := '1';
                end if;

                data_v   := keep_bytes(seg_buf, cnt);
                tx_data  <= data_v & SDO_CCS_DL_SEG_C & tgl_v
                            & std_logic_vector(to_unsigned(sdo_seg_bytes_c, 3) - cnt(2 downto 0))
                            & last_v;
                tx_req   <= '1';
                toggle   <= tgl_v;
                last_seg <= last_v;
                pos      <= pos + cnt;
                tmo_cnt  <= tmo_ms;
                state    <= S_DL_SEG_TX;

                if last_v = '0' then
                    fetch_ph   <= 1;
                    fetch_addr <= pos(addr_w_c - 1 downto 0) + resize(cnt, addr_w_c);
                end if;
            end if;

            if do_ul_seg then
                tx_data <= x"00000000000000" & SDO_CCS_UL_SEG_C & tgl_v & "0000";
                tx_req  <= '1';
                toggle  <= tgl_v;
                tmo_cnt <= tmo_ms;
                state   <= S_UL_SEG_TX;
            end if;

            if do_abort then
                tx_data      <= abort_v & sub & idx & SDO_CS_ABORT_C & sdo_reserved5_c;
                tx_req       <= '1';
                abort_code_q <= abort_v;
                abort_sent_q <= '1';
                tmo_cnt      <= tmo_ms;
                state        <= S_ABORT_TX;
            end if;

            if rx_go and (do_dl_seg or do_ul_seg or do_abort) then
                rx_reply_q <= '1';
            end if;

            if do_end then
                state   <= S_IDLE;
                done_q  <= '1';
                error_q <= end_err;

                if end_err = '1' then
                    abort_code_q <= end_code;
                    abort_sent_q <= end_sent;
                end if;

                if upload = '1' then
                    size_q <= pos;
                elsif end_err = '0' then
                    size_q <= size_req;
                else
                    size_q <= acked;
                end if;
            end if;

            -- capture last, so that a frame arriving in the cycle one is processed is kept
            if rx_valid_i = '1' then
                rx_pend   <= '1';
                rx_id_q   <= rx_id_i;
                rx_rtr_q  <= rx_rtr_i;
                rx_dlc_q  <= rx_dlc_i;
                rx_data_q <= rx_data_i;
            end if;
        end if;

    end process main_proc;

    busy_o          <= '0' when state = S_IDLE else '1';
    done_o          <= done_q;
    error_o         <= error_q;
    abort_code_o    <= abort_code_q;
    abort_sent_o    <= abort_sent_q;
    size_o          <= std_logic_vector(resize(size_q, 11));
    buf_rdata_o     <= lane_rdata;
    tx_req_o        <= tx_req;
    tx_id_o         <= cob_tx;
    tx_dlc_o        <= sdo_dlc_c;
    tx_data_o       <= tx_data;
    rx_done_o       <= rx_done_q;
    rx_reply_o      <= rx_reply_q;
    rx_unexpected_o <= rx_unexp_q;
    state_o         <= state_code(state);

end architecture rtl;
