-- =================================================================================================
-- Title    : canopen_sdo_channels
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   N_SDO concurrent CiA 301 SDO client channels served by ONE shared client engine: the
--   per-channel transfer state lives in block RAM words, the transfer buffers of all channels
--   in one RAM set (channel number = upper address bits). One host port, one FSM frame
--   interface and one owner port for the configuration list.
-- Purpose:
--   Lets SDO transfers to different nodes interleave on the bus (the host reads a diagnostic
--   object of one drive while another is being configured), one transfer at a time per node,
--   while an extra channel costs RAM words and a few flags, not a second client.
--   * Transfers: expedited and segmented download and upload, aborts, timeouts, exactly as the
--     former per-channel canopen_sdo_client (docs/canopen_sdo_client.md): command specifier
--     (0504 0001h, also DLC /= 8), multiplexer of an initiate response (0800 0000h), toggle
--     (0503 0000h), size above BUF_BYTES (0504 0005h), received total /= indicated size
--     (0607 0010h), no response within the timeout (0504 0000h; timeout_ms_i = 0 means
--     TIMEOUT_DEF_MS), more than EMPTY_SEGS_MAX empty non-final upload segments (0800 0000h).
--     A server abort with the transfer's multiplexer ends it with the server's code. A remote
--     frame is never a response.
--   * Engine: a channel's state word (toggle, index/subindex, sizes, position, timer, abort
--     code, ...) is read from the context RAM when the channel has work (tx_ack_i of its frame,
--     a received response, an accepted request, a ms-tick sweep), processed by the one
--     sequencer (with the buffer read/write units) and written back. One work item takes 6
--     cycles (+3 for a buffer read, +2 for a buffer write); items are served in the order
--     tx ack > received frame > start > timer sweep. Bounds: docs/canopen_sdo_channels.md.
--   * Frames to send are kept in a frame RAM (one word per channel); the channels with a frame
--     waiting are presented to the FSM round robin (tx_req_o level until tx_ack_i or until the
--     channel's timeout withdraws it; the presented frame never changes while tx_req_o = 1).
--   * Admission (combinational in the request cycle, as before): a request is refused when
--     enable_i = 0, the node-ID is 0 or above 127, the channel is busy, channel 0 belongs to the
--     configuration list, or another running transfer (or the list's waiting request) uses the
--     same request or response COB-ID. refused_o shows the decision in the cycle of the request.
--   * Receive (St6): the frame goes to the busy channel whose response COB-ID it carries; a
--     frame no channel waits for is answered two cycles later with rx_unexpected_o.
--   * Buffers: two copies of four byte lanes (bytes 4w+k in lane k, word c*BUF_BYTES/4 + w for
--     channel c): the host copy (read by the host port, written by host writes and by received
--     upload bytes) and the engine copy (read by the download segment builder, written by host
--     and owner writes). A received-byte write waits for a cycle without a host buffer write.
--   * Aborts: every transfer ending in an abort gives one cnt_abort_o strobe (none lost).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_pkg.all;
    use work.canopen_util_pkg.all;

entity canopen_sdo_channels is
    generic (
        N_SDO          : positive range 1 to 4     := 2;    -- SDO client channels
        BUF_BYTES      : positive range 8 to 1024  := 256;  -- buffer per channel [bytes], 2**n
        TIMEOUT_DEF_MS : positive range 1 to 65535 := 1000; -- timeout used for timeout_ms_i = 0
        EMPTY_SEGS_MAX : natural range 0 to 255    := 3     -- empty non-final upload segments
    );
    port (
        -- clock and reset
        clk_i     : in    std_logic; -- system clock
        rst_n_i   : in    std_logic; -- async reset, active low (synced)
        tick_ms_i : in    std_logic; -- 1-cycle strobe every ms (timeouts)
        enable_i  : in    std_logic; -- 0: every request is refused (Omni-ID mode)
        -- host request (SDO_SEL, SDO_OBJ, SDO_CMD, SDO_COB, SDO_TIMEOUT_MS)
        host_chan_i    : in    std_logic_vector(1 downto 0);  -- selected channel (< N_SDO)
        host_req_i     : in    std_logic;                     -- pulse: SDO_CMD written
        host_upload_i  : in    std_logic;                     -- 1 upload, 0 download
        host_node_i    : in    std_logic_vector(7 downto 0);  -- server node-ID, 1..127
        host_index_i   : in    std_logic_vector(15 downto 0); -- object index
        host_sub_i     : in    std_logic_vector(7 downto 0);  -- object sub-index
        host_size_i    : in    std_logic_vector(10 downto 0); -- download size [bytes]
        host_cob_req_i : in    std_logic_vector(10 downto 0); -- request COB-ID, 0 = 600h+node
        host_cob_rsp_i : in    std_logic_vector(10 downto 0); -- response COB-ID, 0 = 580h+node
        timeout_ms_i   : in    std_logic_vector(15 downto 0); -- response timeout, all channels
        -- host buffer port (selected channel)
        buf_addr_i  : in    std_logic_vector(7 downto 0);  -- word address
        buf_we_i    : in    std_logic;                     -- write (idle channel only)
        buf_wdata_i : in    std_logic_vector(31 downto 0); -- write data
        buf_rdata_o : out   std_logic_vector(31 downto 0); -- read data (+1 cycle)
        -- status of the selected channel (abort code, abort sent, size: of the host_chan_i of
        -- the previous cycle, from the result RAM, like buf_rdata_o)
        busy_o       : out   std_logic;                     -- transfer running (or owned)
        error_o      : out   std_logic;                     -- last transfer aborted
        abort_code_o : out   std_logic_vector(31 downto 0); -- its abort code (+1 cycle)
        abort_sent_o : out   std_logic;                     -- 1: the master aborted (+1)
        size_o       : out   std_logic_vector(10 downto 0); -- bytes transferred (+1)
        refused_o    : out   std_logic;                     -- the last request was refused
        -- all channels (bit c = channel c, bits >= N_SDO read 0)
        chan_busy_o : out   std_logic_vector(3 downto 0); -- transfer running (or owned)
        chan_done_o : out   std_logic_vector(3 downto 0); -- strobe: host transfer ended
        chan_go_o   : out   std_logic_vector(3 downto 0); -- strobe: host request accepted
        cnt_abort_o : out   std_logic;                    -- strobe: one transfer aborted
        -- owner of channel 0 (canopen_autoconfig), default COB-IDs
        own_i          : in    std_logic;                     -- channel 0 belongs to the owner
        own_req_i      : in    std_logic;                     -- pulse: start a download
        own_node_i     : in    std_logic_vector(6 downto 0);  -- server node-ID
        own_index_i    : in    std_logic_vector(15 downto 0); -- object index
        own_sub_i      : in    std_logic_vector(7 downto 0);  -- object sub-index
        own_size_i     : in    std_logic_vector(10 downto 0); -- bytes (expedited: 1..4)
        own_buf_we_i   : in    std_logic;                     -- write buffer word 0
        own_buf_data_i : in    std_logic_vector(31 downto 0); -- its value
        own_idle_o     : out   std_logic;                     -- channel 0 idle, nothing waits
        own_done_o     : out   std_logic;                     -- strobe: owner's transfer ended
        own_error_o    : out   std_logic;                     -- with done: it failed
        own_abort_o    : out   std_logic_vector(31 downto 0); -- its abort code
        -- frame to transmit (towards the FSM, St9 -> St11)
        tx_req_o   : out   std_logic;                     -- level: a frame is waiting
        tx_id_o    : out   std_logic_vector(10 downto 0); -- identifier
        tx_dlc_o   : out   std_logic_vector(3 downto 0);  -- data length code
        tx_data_o  : out   std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        tx_ack_i   : in    std_logic;                     -- strobe: frame taken
        tx_abort_o : out   std_logic;                     -- the presented frame is an abort
        -- withdraw of an ended transfer's request (towards the core's TXB1 cancel): the
        -- transfer with request COB-ID wdr_id_o ended (or is aborted); its DONE waits for
        -- wdr_ack_i (its request can no longer reach the server: cancelled or already sent)
        wdr_req_o : out   std_logic;                     -- level: a withdraw is asked for
        wdr_id_o  : out   std_logic_vector(10 downto 0); -- its request COB-ID
        wdr_ack_i : in    std_logic;                     -- strobe: withdrawn (with wdr_req_o)
        -- received frame (from the FSM, St6): rx_*_i are read where they are, not copied: the
        -- caller holds them from rx_valid_i until rx_done_o
        rx_match_o      : out   std_logic;                     -- rx_id_i = a running response
        rx_valid_i      : in    std_logic;                     -- strobe: process this frame
        rx_id_i         : in    std_logic_vector(10 downto 0); -- identifier
        rx_rtr_i        : in    std_logic;                     -- remote frame
        rx_dlc_i        : in    std_logic_vector(3 downto 0);  -- data length code
        rx_data_i       : in    std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        rx_done_o       : out   std_logic;                     -- strobe: frame processed
        rx_reply_o      : out   std_logic;                     -- with done: a frame follows
        rx_unexpected_o : out   std_logic;                     -- with done: nobody waited
        -- debugging
        state_o : out   std_logic_vector(3 downto 0) -- state code of the selected channel
    );
end entity canopen_sdo_channels;

architecture rtl of canopen_sdo_channels is

    constant addr_w_c : positive := clog2(BUF_BYTES); -- byte address width (one channel)
    constant word_w_c : positive := addr_w_c - 2;     -- word address width (one channel)
    constant words_c  : positive := BUF_BYTES / 4;    -- words per channel in each lane RAM
    constant cnt_w_c  : positive := addr_w_c + 1;     -- byte counts 0..BUF_BYTES
    constant depth_c  : positive := N_SDO * words_c;  -- words of each lane RAM
    -- width of the empty-segment counter (0..EMPTY_SEGS_MAX)
    constant emp_w_c : positive := max_nat(1, clog2(EMPTY_SEGS_MAX + 1));
    -- context word: the fields of ctx_t, packed by ctx_pack (131 bits with the defaults: four
    -- M9K at x36)
    constant ctx_w_c : positive := 93 + emp_w_c + 4 * cnt_w_c;
    -- frame word: the data bytes (the identifier is the channel's run_req)
    constant frm_w_c : positive := 64;
    -- result word: abort code, abort sent, size
    constant res_w_c : positive := 44;
    -- depth of the context and frame RAMs: at least 8 words, so that the synthesis maps them
    -- to block RAM (yosys' minimum efficiency for an M9K), not to flip-flops
    constant small_d_c : positive := max_nat(N_SDO, 8);

    function check_config return boolean is
    begin

        assert 2 ** addr_w_c = BUF_BYTES
            report "canopen_sdo_channels: BUF_BYTES = " & integer'image(BUF_BYTES)
                   & " is not a power of 2"
            severity failure;
        assert false
            report "canopen_sdo_channels: " & integer'image(N_SDO) & " channels, one engine; "
                   & "context RAM " & integer'image(N_SDO) & " x " & integer'image(ctx_w_c)
                   & " bits, frame RAM " & integer'image(N_SDO) & " x "
                   & integer'image(frm_w_c) & " bits, buffers 2 copies x 4 byte lanes x "
                   & integer'image(depth_c) & " words"
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

    -- transfer state of a channel (kept in flip-flops per channel: busy, state_o). At rest a
    -- channel is in S_IDLE, S_START or one of the *_TX / *_WAIT / S_ABORT_TX states; S_FINISH
    -- only exists while the engine works on the channel.

    type state_t is (
        S_IDLE,         -- no transfer
        S_START,        -- accepted, waiting for the engine (download: buffer read first)
        S_DL_INIT_TX,   -- initiate download request waiting for tx_ack_i
        S_DL_INIT_WAIT, -- waiting for the initiate download response
        S_DL_SEG_TX,    -- download segment request waiting for tx_ack_i
        S_DL_SEG_WAIT,  -- waiting for the download segment response
        S_UL_INIT_TX,   -- initiate upload request waiting for tx_ack_i
        S_UL_INIT_WAIT, -- waiting for the initiate upload response
        S_UL_SEG_TX,    -- upload segment request waiting for tx_ack_i
        S_UL_SEG_WAIT,  -- waiting for the upload segment response
        S_ABORT_TX,     -- abort frame from the client waiting for tx_ack_i
        S_FINISH,       -- upload: last bytes being written to the buffer (engine only)
        S_END           -- ended, result stored: DONE waits for the withdraw of its request
    );

    type state_arr_t is array (0 to N_SDO - 1) of state_t;

    -- per-channel transfer context (one context RAM word per channel)

    type ctx_t is record
        upload     : std_logic;                      -- 1 = upload
        idx        : std_logic_vector(15 downto 0);  -- object index
        sub        : std_logic_vector(7 downto 0);   -- object subindex
        size_req   : unsigned(cnt_w_c - 1 downto 0); -- download: bytes to send
        expedited  : std_logic;                      -- download fits one expedited frame
        pos        : unsigned(cnt_w_c - 1 downto 0); -- bytes put into frames / received
        acked      : unsigned(cnt_w_c - 1 downto 0); -- download: bytes confirmed
        last_seg   : std_logic;                      -- download: segment in flight is last
        toggle     : std_logic;                      -- toggle of the segment in flight
        size_known : std_logic;                      -- upload: size indicated
        ind_size   : unsigned(cnt_w_c - 1 downto 0); -- upload: indicated size
        tmo_ms     : unsigned(15 downto 0);          -- timeout of the transfer [ms]
        tmo_cnt    : unsigned(15 downto 0);          -- ms ticks left
        empty_cnt  : unsigned(emp_w_c - 1 downto 0); -- empty upload segments so far
        abort_code : std_logic_vector(31 downto 0);  -- abort code (received or sent)
    end record ctx_t;

    function ctx_pack (c : ctx_t) return std_logic_vector is
    begin

        return c.upload & c.idx & c.sub & std_logic_vector(c.size_req) & c.expedited
               & std_logic_vector(c.pos) & std_logic_vector(c.acked) & c.last_seg & c.toggle
               & c.size_known & std_logic_vector(c.ind_size) & std_logic_vector(c.tmo_ms)
               & std_logic_vector(c.tmo_cnt) & std_logic_vector(c.empty_cnt) & c.abort_code;

    end function ctx_pack;

    function ctx_unpack (w : std_logic_vector(ctx_w_c - 1 downto 0)) return ctx_t is

        variable c : ctx_t;
        variable p : natural; -- next bit (from the top)

    begin

        p            := ctx_w_c;
        c.upload     := w(p - 1);
        p            := p - 1;
        c.idx        := w(p - 1 downto p - 16);
        p            := p - 16;
        c.sub        := w(p - 1 downto p - 8);
        p            := p - 8;
        c.size_req   := unsigned(w(p - 1 downto p - cnt_w_c));
        p            := p - cnt_w_c;
        c.expedited  := w(p - 1);
        p            := p - 1;
        c.pos        := unsigned(w(p - 1 downto p - cnt_w_c));
        p            := p - cnt_w_c;
        c.acked      := unsigned(w(p - 1 downto p - cnt_w_c));
        p            := p - cnt_w_c;
        c.last_seg   := w(p - 1);
        c.toggle     := w(p - 2);
        c.size_known := w(p - 3);
        p            := p - 3;
        c.ind_size   := unsigned(w(p - 1 downto p - cnt_w_c));
        p            := p - cnt_w_c;
        c.tmo_ms     := unsigned(w(p - 1 downto p - 16));
        p            := p - 16;
        c.tmo_cnt    := unsigned(w(p - 1 downto p - 16));
        p            := p - 16;
        c.empty_cnt  := unsigned(w(p - 1 downto p - emp_w_c));
        c.abort_code := w(31 downto 0);
        return c;

    end function ctx_unpack;

    function state_code (s : state_t) return std_logic_vector is
    begin

        return std_logic_vector(to_unsigned(state_t'pos(s), 4));

    end function state_code;

    subtype chan_vec_t is std_logic_vector(N_SDO - 1 downto 0);

    type cob_arr_t is array (0 to N_SDO - 1) of std_logic_vector(10 downto 0);

    type lane_addr_array_t is array (0 to 3) of natural range 0 to depth_c - 1;

    type lane_data_array_t is array (0 to 3) of std_logic_vector(7 downto 0);

    -- engine work item kinds

    type ev_t is (EV_ACK, EV_RX, EV_START, EV_TICK);

    -- engine phases: pick an item, read the channel's context, load it, process it, wait for
    -- the buffer units (and build a download frame), write the context back
    -- (and, for a received frame answered by a new frame, wait until a frame is presented)

    type eng_t is (E_IDLE, E_READ, E_LOAD, E_RUN, E_WAIT, E_WB, E_RXD);

    -- decision on a received frame (rx_dec_proc), applied by the engine in E_RUN

    type rxd_t is record
        unexp    : std_logic;                       -- not for the transfer
        abort    : std_logic;                       -- answer with an abort frame (code)
        code     : std_logic_vector(31 downto 0);   -- abort code / the server's code
        csel     : natural range 0 to 5;            -- the abort code (abort_code_of)
        srv      : std_logic;                       -- server abort: the transfer ends
        ok_end   : std_logic;                       -- the download ends successfully
        dl_seg   : std_logic;                       -- next download segment (toggle tgl)
        ul_seg   : std_logic;                       -- next upload segment request (tgl)
        tgl      : std_logic;                       -- toggle of the next segment
        wr       : std_logic;                       -- write wr_n received bytes at wr_a
        fin      : std_logic;                       -- the upload ends after the write
        wr_a     : unsigned(addr_w_c - 1 downto 0); -- byte address of the write
        wr_n     : unsigned(3 downto 0);            -- bytes to write
        wr_d     : std_logic_vector(55 downto 0);   -- the bytes
        wexp     : std_logic;                       -- expedited upload: bytes 4..7 at 0
        pos      : unsigned(cnt_w_c - 1 downto 0);  -- position after the write
        acked_up : std_logic;                       -- download: bytes confirmed = acked
        acked    : unsigned(cnt_w_c - 1 downto 0);  -- its value
        ack_sz   : std_logic;                       -- acked = size_req (else pos)
        init_ul  : std_logic;                       -- segmented upload: known / ind
        known    : std_logic;                       -- size indicated
        ind      : unsigned(cnt_w_c - 1 downto 0);  -- indicated size
        empty    : std_logic;                       -- one more empty segment
    end record rxd_t;

    -- frame building still to do once the buffer read unit has the bytes

    type bld_t is (B_NONE, B_INIT, B_SEG);

    -- ---------------------------------------------------------------------------------------------
    -- per-channel flip-flops
    -- ---------------------------------------------------------------------------------------------
    -- transfer state
    signal ch_state : state_arr_t;
    -- busy: state /= S_IDLE
    signal c_busy : chan_vec_t;
    -- effective request / response COB-IDs of each channel's running transfer
    signal run_req : cob_arr_t;
    signal run_rsp : cob_arr_t;
    -- a frame of the channel waits in the frame RAM (presented or not yet)
    signal txw : chan_vec_t;
    -- a ms tick has not yet been applied to the channel's timer
    signal todo : chan_vec_t;
    -- result of the last transfer (host status): the error flag here, the abort code, the
    -- abort-sent flag and the size in the result RAM (written at the end of a transfer);
    -- res_ok: the channel's RAM word holds the result of its last transfer (0 from a start
    -- until its end: the result reads as 0); res_oom: the last start was refused for its size
    -- (0504 0005h, sent by the client, size 0, without a RAM write)
    signal res_err : chan_vec_t;
    signal res_ok  : chan_vec_t;
    signal res_oom : chan_vec_t;
    -- strobe: the channel's transfer ended (result above valid)
    signal c_done : chan_vec_t;
    -- result RAM (one word per channel: abort code 43:12, abort sent 11, size 10:0), written
    -- at the end of a transfer, read at host_chan_i; ok / out-of-memory flags of the channel
    -- read in the same cycle (the outputs are registered: +1 cycle after host_chan_i)
    signal res_we    : std_logic;
    signal res_wdata : std_logic_vector(res_w_c - 1 downto 0);
    signal res_q     : std_logic_vector(res_w_c - 1 downto 0);
    signal res_ok_q  : std_logic;
    signal res_oom_q : std_logic;
    -- channel 0's abort code for the owner (canopen_autoconfig reads it with own_done_o)
    signal own_code : std_logic_vector(31 downto 0);
    -- sticky refused flag per channel
    signal refused : chan_vec_t;
    -- the transfer ended or is aborted: its request must be withdrawn from TXB1 first (the
    -- channel's abort frame is not presented and its DONE waits until wdr_ack_i)
    signal wdr : chan_vec_t;
    -- the withdraw shown on wdr_req_o / wdr_id_o, and its channel
    signal wdr_cur : std_logic;
    signal wdr_ch  : natural range 0 to N_SDO - 1;
    -- the engine's channel has a withdraw open that is not acknowledged in this cycle
    signal wdr_keep : std_logic;
    -- a running transfer that takes responses (busy, not in S_END)
    signal c_live : chan_vec_t;

    -- ---------------------------------------------------------------------------------------------
    -- admission
    -- ---------------------------------------------------------------------------------------------
    signal host_req_cob : std_logic_vector(10 downto 0);
    signal host_rsp_cob : std_logic_vector(10 downto 0);
    signal own_req_cob  : std_logic_vector(10 downto 0);
    signal own_rsp_cob  : std_logic_vector(10 downto 0);
    -- the selected channel as an index, and whether it exists
    signal sel    : natural range 0 to N_SDO - 1;
    signal sel_ok : std_logic;
    -- the request collides with a running transfer on another channel
    signal host_clash : std_logic;
    signal own_clash  : std_logic;
    -- a request is accepted this cycle; the node-ID is valid
    signal host_go : std_logic;
    signal node_ok : std_logic;
    -- the owner's request waits for its node to be free (and for its buffer word)
    signal own_pend : std_logic;
    signal own_go   : std_logic;
    -- the start of this cycle (host or owner): channel, fields, and its initial context
    signal st_go     : std_logic;
    signal st_ch     : natural range 0 to N_SDO - 1;
    signal st_upload : std_logic;
    signal st_size   : std_logic_vector(10 downto 0);
    signal st_big    : std_logic;
    signal st_ctx    : std_logic_vector(ctx_w_c - 1 downto 0);

    -- ---------------------------------------------------------------------------------------------
    -- engine
    -- ---------------------------------------------------------------------------------------------
    signal eng   : eng_t;
    signal ev    : ev_t;
    signal ev_ch : natural range 0 to N_SDO - 1;
    -- the loaded context and the channel's state (as loaded, and as the item leaves it)
    signal ctx      : ctx_t;
    signal state_ld : state_t;
    signal state    : state_t;
    -- results of the item: the transfer ended (error, sent by the client, size)
    signal done_q : std_logic;
    -- the item ended or aborted the transfer (not an end after the abort frame): withdraw
    signal wdr_new_q    : std_logic;
    signal error_q      : std_logic;
    signal abort_sent_q : std_logic;
    signal size_q       : unsigned(cnt_w_c - 1 downto 0);
    -- a new frame was built (tx_data), a download frame is still to build
    signal new_frame : std_logic;
    signal tx_data   : std_logic_vector(63 downto 0);
    signal bld       : bld_t;
    -- upload: the transfer ends once the write unit has stored the last bytes
    signal fin_pend : std_logic;
    -- the item was a received frame: its outcome (reply frame built / not for the transfer)
    signal rx_item_reply : std_logic;
    signal rx_item_unexp : std_logic;
    -- context RAM ports
    signal ctx_we    : std_logic;
    signal ctx_waddr : natural range 0 to N_SDO - 1;
    signal ctx_wdata : std_logic_vector(ctx_w_c - 1 downto 0);
    signal ctx_rdata : std_logic_vector(ctx_w_c - 1 downto 0);
    -- engine write-back this cycle (not stalled by a start)
    signal wb_go : std_logic;
    -- the next work item (disp_proc)
    signal disp_go : std_logic;
    signal disp_ev : ev_t;
    signal disp_ch : natural range 0 to N_SDO - 1;
    -- the decision on the received frame (rx_dec_proc, from the context RAM's read data in
    -- E_LOAD), registered with the context for E_RUN
    signal rxd   : rxd_t;
    signal rxd_q : rxd_t;
    -- the context's timer is 0 (from the read data in E_LOAD, for the tick in E_RUN)
    signal tmo_zero_q : std_logic;
    -- strobes of the engine to chan_proc (one cycle late): timer reloaded, request withdrawn
    signal reload_q : std_logic;
    signal wd_q     : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- transmit presentation
    -- ---------------------------------------------------------------------------------------------
    -- a frame is presented (tx_req_o) and whose it is
    signal tx_full : std_logic;
    signal tx_ch   : natural range 0 to N_SDO - 1;
    -- a taken frame's ack still to be processed by the engine, and its channel
    signal ack_pend : std_logic;
    signal ack_ch   : natural range 0 to N_SDO - 1;
    -- next channel with a waiting frame after tx_ch (round robin), and a grant this cycle
    signal gr_ch  : natural range 0 to N_SDO - 1;
    signal gr_any : std_logic;
    signal grant  : std_logic;
    -- frame RAM ports
    signal frm_we    : std_logic;
    signal frm_wdata : std_logic_vector(frm_w_c - 1 downto 0);
    signal frm_rdata : std_logic_vector(frm_w_c - 1 downto 0);

    -- ---------------------------------------------------------------------------------------------
    -- receive
    -- ---------------------------------------------------------------------------------------------
    signal rx_hit     : chan_vec_t;
    signal rx_hit_ch  : natural range 0 to N_SDO - 1;
    signal nohit_pipe : std_logic_vector(1 downto 0);
    -- a frame (held on rx_*_i) waiting for the engine, for channel rx_ch
    signal rx_pend : std_logic;
    signal rx_ch   : natural range 0 to N_SDO - 1;
    -- rx strobes of the engine
    signal rx_done_q  : std_logic;
    signal rx_reply_q : std_logic;
    signal rx_unexp_q : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- buffers
    -- ---------------------------------------------------------------------------------------------
    -- host write accepted this cycle (selected channel idle and the host's)
    signal host_we : std_logic;
    -- host port word address (channel + word)
    signal host_waddr : natural range 0 to depth_c - 1;
    -- owner's buffer word waiting to be written (engine copy, channel 0 word 0)
    signal own_wpend : std_logic;
    signal own_wdata : std_logic_vector(31 downto 0);
    -- read unit: phase (0 idle, 1 bytes a..a+3 addressed, 2 bytes a+4..a+7 addressed, 3 last
    -- capture), byte address a, the 7 bytes read
    signal fetch_ph   : natural range 0 to 3;
    signal fetch_addr : unsigned(addr_w_c - 1 downto 0);
    signal seg_buf    : std_logic_vector(55 downto 0);
    -- the next download segment's size min(size_req - pos, 7) and last flag (taken during the read)
    signal seg_cnt_q  : unsigned(3 downto 0);
    signal seg_last_q : std_logic;
    -- write unit: phase (0 idle, 1 bytes 0..3, 2 bytes 4..6), byte address, count, bytes
    signal wr_ph   : natural range 0 to 2;
    signal wr_addr : unsigned(addr_w_c - 1 downto 0);
    signal wr_cnt  : unsigned(3 downto 0);
    signal wr_data : std_logic_vector(55 downto 0);
    -- the write unit writes this cycle (no host write)
    signal wr_go : std_logic;
    -- host copy lane ports (written by host and write unit, read by the host)
    signal a_we    : std_logic_vector(3 downto 0);
    signal a_waddr : lane_addr_array_t;
    signal a_wdata : lane_data_array_t;
    signal a_raddr : natural range 0 to depth_c - 1;
    signal a_rdata : std_logic_vector(31 downto 0);
    -- engine copy lane ports (written by host and owner, read by the read unit)
    signal b_we    : std_logic;
    signal b_waddr : natural range 0 to depth_c - 1;
    signal b_wdata : std_logic_vector(31 downto 0);
    signal b_raddr : lane_addr_array_t;
    signal b_rdata : std_logic_vector(31 downto 0);

    -- aborts ended but not yet counted
    signal abort_pend : unsigned(2 downto 0);

begin

    -- ---------------------------------------------------------------------------------------------
    -- Request admission: one transfer per SDO server (request or response COB-ID) at a time
    -- ---------------------------------------------------------------------------------------------
    sel    <= to_integer(unsigned(host_chan_i)) when to_integer(unsigned(host_chan_i)) < N_SDO else
              0;
    sel_ok <= '1' when to_integer(unsigned(host_chan_i)) < N_SDO else
              '0';

    -- node-ID 1..127 (CiA 301); 0 and 128..255 are refused
    node_ok <= '1' when host_node_i(7) = '0' and host_node_i(6 downto 0) /= "0000000" else
               '0';

    host_req_cob <= eff_cob(host_cob_req_i, FC_SDO_RX_C, host_node_i(6 downto 0));
    host_rsp_cob <= eff_cob(host_cob_rsp_i, FC_SDO_TX_C, host_node_i(6 downto 0));
    own_req_cob  <= cob_id(FC_SDO_RX_C, own_node_i);
    own_rsp_cob  <= cob_id(FC_SDO_TX_C, own_node_i);

    busy_gen : for c in 0 to N_SDO - 1 generate
        c_busy(c) <= '0' when ch_state(c) = S_IDLE else
                     '1';
        c_live(c) <= '0' when ch_state(c) = S_IDLE or ch_state(c) = S_END else
                     '1';
    end generate busy_gen;

    clash_proc : process (c_busy, host_req_cob, host_rsp_cob, own_pend, own_req_cob, own_rsp_cob,
                          run_req, run_rsp, sel) is

        variable hc : std_logic;
        variable oc : std_logic;

    begin

        hc := '0';
        oc := '0';

        for c in 0 to N_SDO - 1 loop

            if c_busy(c) = '1' and c /= sel
               and (run_req(c) = host_req_cob or run_rsp(c) = host_rsp_cob) then
                hc := '1';
            end if;

            if c_busy(c) = '1' and c /= 0
               and (run_req(c) = own_req_cob or run_rsp(c) = own_rsp_cob) then
                oc := '1';
            end if;

        end loop;

        -- the owner's waiting request counts as running on channel 0
        if own_pend = '1' and sel /= 0
           and (own_req_cob = host_req_cob or own_rsp_cob = host_rsp_cob) then
            hc := '1';
        end if;

        host_clash <= hc;
        own_clash  <= oc;

    end process clash_proc;

    host_go <= '1' when host_req_i = '1' and enable_i = '1' and sel_ok = '1' and node_ok = '1'
                        and c_busy(sel) = '0' and host_clash = '0'
                        and not (sel = 0 and (own_i = '1' or own_pend = '1')) else
               '0';
    -- the owner's start waits for a cycle without a host request (one context write per cycle)
    -- and for its buffer word to be in the RAM
    own_go <= own_pend and not own_clash and not c_busy(0) and not host_req_i and not own_wpend;

    -- the start of this cycle and the channel's initial context word
    st_go     <= host_go or own_go;
    st_ch     <= sel when host_go = '1' else
                 0;
    st_upload <= host_upload_i when host_go = '1' else
                 '0';
    st_size   <= host_size_i when host_go = '1' else
                 own_size_i;
    -- download larger than the buffer: both sources compared, then selected (the compare is
    -- not behind the start decision)
    st_big <= '1' when host_go = '1' and host_upload_i = '0'
                       and unsigned(host_size_i) > BUF_BYTES else
              '1' when host_go = '0' and unsigned(own_size_i) > BUF_BYTES else
              '0';

    st_ctx_proc : process (host_go, host_index_i, host_sub_i, own_index_i,
                           own_sub_i, st_size, st_upload, timeout_ms_i) is

        variable c : ctx_t;

    begin

        c.upload := st_upload;

        if host_go = '1' then
            c.idx := host_index_i;
            c.sub := host_sub_i;
        else
            c.idx := own_index_i;
            c.sub := own_sub_i;
        end if;

        c.size_req   := resize(unsigned(st_size), cnt_w_c);
        c.expedited  := '0';
        c.pos        := (others => '0');
        c.acked      := (others => '0');
        c.last_seg   := '0';
        c.toggle     := '0';
        c.size_known := '0';
        c.ind_size   := (others => '0');

        -- every wait is bounded: 0 selects the default timeout
        if unsigned(timeout_ms_i) = 0 then
            c.tmo_ms := to_unsigned(TIMEOUT_DEF_MS, 16);
        else
            c.tmo_ms := unsigned(timeout_ms_i);
        end if;

        c.tmo_cnt    := c.tmo_ms;
        c.empty_cnt  := (others => '0');
        c.abort_code := (others => '0');
        st_ctx       <= ctx_pack(c);

    end process st_ctx_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Context RAM (one word per channel) and frame RAM (the frame each channel waits to send)
    -- ---------------------------------------------------------------------------------------------
    wb_go     <= '1' when eng = E_WB and st_go = '0' else
                 '0';
    ctx_we    <= (st_go and not st_big) or wb_go;
    ctx_waddr <= st_ch when st_go = '1' else
                 ev_ch;
    ctx_wdata <= st_ctx when st_go = '1' else
                 ctx_pack(ctx);

    ctx_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => small_d_c,
            WIDTH => ctx_w_c
        )
        port map (
            clk_i   => clk_i,
            we_i    => ctx_we,
            waddr_i => ctx_waddr,
            wdata_i => ctx_wdata,
            re_i    => '1',
            raddr_i => ev_ch,
            rdata_o => ctx_rdata
        );

    frm_we    <= wb_go and new_frame;
    frm_wdata <= tx_data;

    frm_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => small_d_c,
            WIDTH => frm_w_c
        )
        port map (
            clk_i   => clk_i,
            we_i    => frm_we,
            waddr_i => ev_ch,
            wdata_i => frm_wdata,
            re_i    => grant,
            raddr_i => gr_ch,
            rdata_o => frm_rdata
        );

    -- result RAM: written with the write-back that ends a transfer (done_q), read for the host
    res_we    <= wb_go and done_q;
    res_wdata <= ctx.abort_code & abort_sent_q & std_logic_vector(resize(size_q, 11));

    res_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => small_d_c,
            WIDTH => res_w_c
        )
        port map (
            clk_i   => clk_i,
            we_i    => res_we,
            waddr_i => ev_ch,
            wdata_i => res_wdata,
            re_i    => '1',
            raddr_i => sel,
            rdata_o => res_q
        );

    wdr_keep <= '1' when wdr(ev_ch) = '1'
                         and not (wdr_cur = '1' and wdr_ack_i = '1' and wdr_ch = ev_ch) else
                '0';

    -- round robin: the next channel after tx_ch with a frame waiting
    grant_proc : process (tx_ch, txw, wdr) is

        variable ch_v  : natural range 0 to N_SDO - 1;
        variable any_v : std_logic;

    begin

        ch_v  := tx_ch;
        any_v := '0';

        for k in N_SDO downto 1 loop

            if txw((tx_ch + k) mod N_SDO) = '1' and wdr((tx_ch + k) mod N_SDO) = '0' then
                ch_v  := (tx_ch + k) mod N_SDO;
                any_v := '1';
            end if;

        end loop;

        gr_ch  <= ch_v;
        gr_any <= any_v;

    end process grant_proc;

    -- a frame is presented when none is and no taken frame waits for the engine; never while the
    -- engine may be withdrawing one (E_RUN and the cycle after)
    grant <= '1' when gr_any = '1' and tx_full = '0' and ack_pend = '0' and eng /= E_RUN
                      and wd_q = '0' else
             '0';

    -- ---------------------------------------------------------------------------------------------
    -- Receive: to the channel whose running transfer has this response COB-ID
    -- ---------------------------------------------------------------------------------------------

    hit_gen : for c in 0 to N_SDO - 1 generate
        rx_hit(c) <= '1' when c_live(c) = '1' and run_rsp(c) = rx_id_i else
                     '0';
    end generate hit_gen;

    hit_ch_proc : process (rx_hit) is

        variable ch_v : natural range 0 to N_SDO - 1;

    begin

        ch_v := 0;

        for c in N_SDO - 1 downto 0 loop

            if rx_hit(c) = '1' then
                ch_v := c;
            end if;

        end loop;

        rx_hit_ch <= ch_v;

    end process hit_ch_proc;

    rx_match_o <= or_reduce(rx_hit);

    -- ---------------------------------------------------------------------------------------------
    -- Buffers: host copy (A) and engine copy (B), four byte lanes each. Byte a+j of a 4-byte
    -- group at byte address a lives in lane (a+j) mod 4, word (a+j)/4 (+ channel base).
    -- ---------------------------------------------------------------------------------------------
    host_we    <= '1' when buf_we_i = '1' and sel_ok = '1' and c_busy(sel) = '0'
                           and not (sel = 0 and own_i = '1') else
                  '0';
    host_waddr <= sel * words_c + to_integer(unsigned(buf_addr_i(word_w_c - 1 downto 0)));
    wr_go      <= '1' when wr_ph /= 0 and host_we = '0' else
                  '0';

    lane_ports_proc : process (buf_wdata_i, ev_ch, fetch_addr, fetch_ph, host_waddr, host_we,
                               wr_addr, wr_cnt, wr_data, wr_ph) is

        variable ga   : unsigned(addr_w_c - 1 downto 0);
        variable grp  : std_logic_vector(31 downto 0);
        variable gcnt : unsigned(3 downto 0);
        variable j    : unsigned(1 downto 0);
        variable base : natural range 0 to depth_c - 1;

    begin

        base := ev_ch * words_c;

        -- host copy, write port: host word, else the write unit
        if host_we = '1' or wr_ph = 0 then

            for b in 0 to 3 loop

                a_waddr(b) <= host_waddr;
                a_wdata(b) <= buf_wdata_i(8 * b + 7 downto 8 * b);
                a_we(b)    <= host_we;

            end loop;

        else
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
                    a_waddr(b) <= base + to_integer(ga(addr_w_c - 1 downto 2) + 1);
                else
                    a_waddr(b) <= base + to_integer(ga(addr_w_c - 1 downto 2));
                end if;

                a_wdata(b) <= word_byte(grp, j);

                if resize(j, 4) < gcnt then
                    a_we(b) <= '1';
                else
                    a_we(b) <= '0';
                end if;

            end loop;

        end if;

        -- engine copy, read port: bytes a..a+3 in phase 1, a+4..a+7 in phase 2
        if fetch_ph = 2 then
            ga := fetch_addr + 4;
        else
            ga := fetch_addr;
        end if;

        for b in 0 to 3 loop

            if to_unsigned(b, 2) < ga(1 downto 0) then
                b_raddr(b) <= base + to_integer(ga(addr_w_c - 1 downto 2) + 1);
            else
                b_raddr(b) <= base + to_integer(ga(addr_w_c - 1 downto 2));
            end if;

        end loop;

    end process lane_ports_proc;

    a_raddr <= host_waddr;
    -- engine copy, write port: host word, else the owner's word (channel 0, word 0)
    b_we    <= host_we or own_wpend;
    b_waddr <= host_waddr when host_we = '1' else
               0;
    b_wdata <= buf_wdata_i when host_we = '1' else
               own_wdata;

    lane_gen : for b in 0 to 3 generate

        a_ram_inst : entity work.canopen_sdp_ram
            generic map (
                DEPTH => depth_c,
                WIDTH => 8
            )
            port map (
                clk_i   => clk_i,
                we_i    => a_we(b),
                waddr_i => a_waddr(b),
                wdata_i => a_wdata(b),
                re_i    => '1',
                raddr_i => a_raddr,
                rdata_o => a_rdata(8 * b + 7 downto 8 * b)
            );

        b_ram_inst : entity work.canopen_sdp_ram
            generic map (
                DEPTH => depth_c,
                WIDTH => 8
            )
            port map (
                clk_i   => clk_i,
                we_i    => b_we,
                waddr_i => b_waddr,
                wdata_i => b_wdata(8 * b + 7 downto 8 * b),
                re_i    => '1',
                raddr_i => b_raddr(b),
                rdata_o => b_rdata(8 * b + 7 downto 8 * b)
            );

    end generate lane_gen;

    -- ---------------------------------------------------------------------------------------------
    -- The engine's next work item: tx ack > received frame > start (lowest channel) > timer
    -- sweep (lowest channel)
    -- ---------------------------------------------------------------------------------------------
    disp_proc : process (ack_ch, ack_pend, ch_state, eng, rx_ch, rx_pend, todo) is

        variable go_v : std_logic;
        variable ev_v : ev_t;
        variable ch_v : natural range 0 to N_SDO - 1;

    begin

        go_v := '0';
        ev_v := EV_TICK;
        ch_v := 0;

        if eng = E_IDLE then
            if ack_pend = '1' then
                go_v := '1';
                ev_v := EV_ACK;
                ch_v := ack_ch;
            elsif rx_pend = '1' then
                go_v := '1';
                ev_v := EV_RX;
                ch_v := rx_ch;
            else

                for c in N_SDO - 1 downto 0 loop

                    if todo(c) = '1' then
                        go_v := '1';
                        ev_v := EV_TICK;
                        ch_v := c;
                    end if;

                end loop;

                for c in N_SDO - 1 downto 0 loop

                    if ch_state(c) = S_START then
                        go_v := '1';
                        ev_v := EV_START;
                        ch_v := c;
                    end if;

                end loop;

            end if;
        end if;

        disp_go <= go_v;
        disp_ev <= ev_v;
        disp_ch <= ch_v;

    end process disp_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Per-channel flip-flops: admission, start, transmit presentation, ms-tick sweep flags, and
    -- the engine's results (state, frame flag, transfer result at write-back)
    -- ---------------------------------------------------------------------------------------------
    chan_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            ch_state  <= (others => S_IDLE);
            run_req   <= (others => (others => '0'));
            run_rsp   <= (others => (others => '0'));
            txw       <= (others => '0');
            todo      <= (others => '0');
            res_err   <= (others => '0');
            res_ok    <= (others => '0');
            res_oom   <= (others => '0');
            res_ok_q  <= '0';
            res_oom_q <= '0';
            own_code  <= (others => '0');
            c_done    <= (others => '0');
            refused   <= (others => '0');
            own_pend  <= '0';
            own_wpend <= '0';
            tx_full   <= '0';
            tx_ch     <= 0;
            ack_pend  <= '0';
            ack_ch    <= 0;
            wdr       <= (others => '0');
            wdr_cur   <= '0';
            wdr_ch    <= 0;
        elsif rising_edge(clk_i) then
            c_done <= (others => '0');
            -- the result flags of the selected channel, in step with the result RAM's read
            res_ok_q  <= res_ok(sel);
            res_oom_q <= res_oom(sel);

            -- withdraw: one at a time (lowest channel first); acknowledged, the channel's abort
            -- frame may be presented and an ended transfer reports DONE
            if wdr_cur = '1' and wdr_ack_i = '1' then
                wdr_cur     <= '0';
                wdr(wdr_ch) <= '0';

                if ch_state(wdr_ch) = S_END then
                    ch_state(wdr_ch) <= S_IDLE;
                    c_done(wdr_ch)   <= '1';
                end if;
            elsif wdr_cur = '0' then

                for c in N_SDO - 1 downto 0 loop

                    if wdr(c) = '1' then
                        wdr_cur <= '1';
                        wdr_ch  <= c;
                    end if;

                end loop;

            end if;

            -- admission ----------------------------------------------------------------------
            if host_req_i = '1' and host_go = '0' and sel_ok = '1' then
                refused(sel) <= '1';
            end if;

            if host_go = '1' then
                refused(sel) <= '0';
                run_req(sel) <= host_req_cob;
                run_rsp(sel) <= host_rsp_cob;
            end if;

            if own_req_i = '1' then
                own_pend <= '1';
            elsif own_go = '1' then
                own_pend   <= '0';
                run_req(0) <= own_req_cob;
                run_rsp(0) <= own_rsp_cob;
            end if;

            -- the owner's buffer word: written to the engine copy in a cycle without host write
            if own_buf_we_i = '1' then
                own_wpend <= '1';
                own_wdata <= own_buf_data_i;
            elsif host_we = '0' then
                own_wpend <= '0';
            end if;

            -- a start (host or owner): the context word is written by the RAM port above
            if st_go = '1' then
                res_err(st_ch) <= '0';
                res_ok(st_ch)  <= '0';
                res_oom(st_ch) <= '0';
                if st_ch = 0 then
                    own_code <= (others => '0');
                end if;

                if st_big = '1' then
                    -- a download larger than the buffer: refused by the client without a frame
                    c_done(st_ch)  <= '1';
                    res_err(st_ch) <= '1';
                    res_oom(st_ch) <= '1';
                    if st_ch = 0 then
                        own_code <= SDO_ABORT_OUT_OF_MEM_C;
                    end if;
                else
                    ch_state(st_ch) <= S_START;
                    todo(st_ch)     <= '0';
                    txw(st_ch)      <= '0';
                end if;
            end if;

            -- transmit: tx_ack_i takes the presented frame; then the next channel is presented
            -- (a request taken: the channel waits for the response from this edge on, as state_o
            -- shows; the engine's ack item reloads the timer; an abort frame taken: the item
            -- ends the transfer)
            if tx_ack_i = '1' and tx_full = '1' then
                tx_full    <= '0';
                ack_pend   <= '1';
                ack_ch     <= tx_ch;
                txw(tx_ch) <= '0';

                case ch_state(tx_ch) is

                    when S_DL_INIT_TX =>

                        ch_state(tx_ch) <= S_DL_INIT_WAIT;

                    when S_DL_SEG_TX =>

                        ch_state(tx_ch) <= S_DL_SEG_WAIT;

                    when S_UL_INIT_TX =>

                        ch_state(tx_ch) <= S_UL_INIT_WAIT;

                    when S_UL_SEG_TX =>

                        ch_state(tx_ch) <= S_UL_SEG_WAIT;

                    when others =>

                        null;

                end case;

            end if;

            if grant = '1' then
                tx_full <= '1';
                tx_ch   <= gr_ch;
            end if;

            -- the engine took an item
            if disp_go = '1' and disp_ev = EV_ACK then
                ack_pend <= '0';
            end if;

            if disp_go = '1' and disp_ev = EV_TICK then
                todo(disp_ch) <= '0';
            end if;

            -- the engine withdrew the channel's waiting request (in the cycle before)
            if wd_q = '1' then
                txw(ev_ch) <= '0';

                if tx_full = '1' and tx_ch = ev_ch then
                    tx_full <= '0';
                end if;
            end if;

            -- the engine reloaded the channel's timer in the cycle before: a tick of that
            -- cycle does not count (the former per-channel timer's rule), a tick of this one does
            if reload_q = '1' then
                todo(ev_ch) <= '0';
            end if;

            -- write-back of the engine's item
            if wb_go = '1' then
                -- only a change: tx_ack_i may have moved the channel on meanwhile
                if state /= state_ld then
                    ch_state(ev_ch) <= state;
                end if;

                if new_frame = '1' then
                    txw(ev_ch) <= '1';
                end if;

                if wdr_new_q = '1' then
                    wdr(ev_ch) <= '1';
                end if;

                if done_q = '1' then
                    -- DONE once no request of the transfer can reach the server any more
                    if wdr_new_q = '1' or wdr_keep = '1' then
                        ch_state(ev_ch) <= S_END;
                    else
                        c_done(ev_ch) <= '1';
                    end if;
                    todo(ev_ch)    <= '0';
                    res_err(ev_ch) <= error_q;
                    res_ok(ev_ch)  <= '1';
                    if ev_ch = 0 then
                        own_code <= ctx.abort_code;
                    end if;
                end if;
            end if;

            -- ms tick: every waiting channel's timer is due for one decrement (the sweep); last,
            -- so that a tick is never lost
            if tick_ms_i = '1' then

                for c in 0 to N_SDO - 1 loop

                    if ch_state(c) /= S_IDLE and ch_state(c) /= S_START
                       and ch_state(c) /= S_END then
                        todo(c) <= '1';
                    end if;

                end loop;

            end if;
        end if;

    end process chan_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Decision on the received frame for the loaded channel (applied by the engine in E_RUN)
    -- ---------------------------------------------------------------------------------------------
    rx_dec_proc : process (ctx_rdata, rx_data_i, rx_dlc_i, rx_rtr_i, state) is

        variable d      : rxd_t;
        variable cmd    : std_logic_vector(7 downto 0);
        variable mux_ok : boolean;
        variable cnt    : unsigned(3 downto 0);
        variable total  : unsigned(cnt_w_c downto 0);
        variable ind_v  : unsigned(31 downto 0);
        variable c      : ctx_t;

    begin

        c := ctx_unpack(ctx_rdata);

        d.unexp    := '0';
        d.abort    := '0';
        d.code     := rx_data_i(63 downto 32);
        d.csel     := 0;
        d.wexp     := '0';
        d.ack_sz   := '0';
        d.srv      := '0';
        d.ok_end   := '0';
        d.dl_seg   := '0';
        d.ul_seg   := '0';
        d.tgl      := '0';
        d.wr       := '0';
        d.fin      := '0';
        d.wr_a     := (others => '0');
        d.wr_n     := (others => '0');
        d.wr_d     := rx_data_i(63 downto 8);
        d.pos      := c.pos;
        d.acked_up := '0';
        d.acked    := c.pos;
        d.init_ul  := '0';
        d.known    := '0';
        d.ind      := (others => '0');
        d.empty    := '0';

        cmd    := rx_data_i(7 downto 0);
        mux_ok := rx_data_i(31 downto 8) = c.sub & c.idx;
        ind_v  := unsigned(rx_data_i(63 downto 32));
        cnt    := sdo_seg_bytes_c - resize(unsigned(cmd(sdo_n_hi_c downto sdo_seg_n_lo_c)), 4);
        total  := resize(c.pos, cnt_w_c + 1) + cnt;

        if (state /= S_DL_INIT_WAIT and state /= S_DL_SEG_WAIT and state /= S_UL_INIT_WAIT
            and state /= S_UL_SEG_WAIT) or rx_rtr_i = '1' then
            -- no response expected now, or a remote frame (a request, never a response): not
            -- ours
            d.unexp := '1';
        elsif rx_dlc_i /= sdo_dlc_c then
            d.abort := '1';
            d.code  := SDO_ABORT_CS_C;
            d.csel  := 1;
        elsif cmd(sdo_cs_hi_c downto sdo_cs_lo_c) = SDO_CS_ABORT_C then
            -- server abort: only for our multiplexer
            if mux_ok then
                d.srv := '1';
            else
                d.unexp := '1';
            end if;
        else

            case state is

                when S_DL_INIT_WAIT =>

                    if cmd(sdo_cs_hi_c downto sdo_cs_lo_c) /= SDO_SCS_DL_INIT_C then
                        d.abort := '1';
                        d.code  := SDO_ABORT_CS_C;
                        d.csel  := 1;
                    elsif not mux_ok then
                        d.abort := '1';
                        d.code  := SDO_ABORT_GENERAL_C;
                        d.csel  := 2;
                    elsif c.expedited = '1' then
                        d.acked_up := '1';
                        d.acked    := c.size_req;
                        d.ack_sz   := '1';
                        d.ok_end   := '1';
                    else
                        d.dl_seg := '1';
                    end if;

                when S_DL_SEG_WAIT =>

                    if cmd(sdo_cs_hi_c downto sdo_cs_lo_c) /= SDO_SCS_DL_SEG_C then
                        d.abort := '1';
                        d.code  := SDO_ABORT_CS_C;
                        d.csel  := 1;
                    elsif cmd(sdo_t_bit_c) /= c.toggle then
                        d.abort := '1';
                        d.code  := SDO_ABORT_TOGGLE_C;
                        d.csel  := 3;
                    else
                        d.acked_up := '1';

                        if c.last_seg = '1' then
                            d.ok_end := '1';
                        else
                            d.dl_seg := '1';
                            d.tgl    := not c.toggle;
                        end if;
                    end if;

                when S_UL_INIT_WAIT =>

                    if cmd(sdo_cs_hi_c downto sdo_cs_lo_c) /= SDO_SCS_UL_INIT_C then
                        d.abort := '1';
                        d.code  := SDO_ABORT_CS_C;
                        d.csel  := 1;
                    elsif not mux_ok then
                        d.abort := '1';
                        d.code  := SDO_ABORT_GENERAL_C;
                        d.csel  := 2;
                    elsif cmd(sdo_e_bit_c) = '1' then
                        -- expedited: 4 - n bytes (4 when the size is not indicated)
                        if cmd(sdo_s_bit_c) = '1' then
                            d.wr_n := sdo_exp_bytes_c
                                      - resize(unsigned(cmd(sdo_n_hi_c downto sdo_init_n_lo_c)),
                                                 4);
                        else
                            d.wr_n := to_unsigned(sdo_exp_bytes_c, 4);
                        end if;
                        d.wr   := '1';
                        d.fin  := '1';
                        d.wr_d := x"000000" & rx_data_i(63 downto 32);
                        d.wexp := '1';
                        d.pos  := resize(d.wr_n, cnt_w_c);
                    elsif cmd(sdo_s_bit_c) = '1' and ind_v > BUF_BYTES then
                        d.abort := '1';
                        d.code  := SDO_ABORT_OUT_OF_MEM_C;
                        d.csel  := 4;
                    else
                        d.init_ul := '1';
                        d.known   := cmd(sdo_s_bit_c);
                        d.ind     := resize(ind_v, cnt_w_c);
                        d.ul_seg  := '1';
                    end if;

                when S_UL_SEG_WAIT =>

                    if cmd(sdo_cs_hi_c downto sdo_cs_lo_c) /= SDO_SCS_UL_SEG_C then
                        d.abort := '1';
                        d.code  := SDO_ABORT_CS_C;
                        d.csel  := 1;
                    elsif cmd(sdo_t_bit_c) /= c.toggle then
                        d.abort := '1';
                        d.code  := SDO_ABORT_TOGGLE_C;
                        d.csel  := 3;
                    elsif cmd(sdo_c_bit_c) = '0' and cnt = 0
                          and c.empty_cnt = EMPTY_SEGS_MAX then
                        -- one more segment without data and without an end: the server keeps
                        -- the transfer alive without progress
                        d.abort := '1';
                        d.code  := SDO_ABORT_GENERAL_C;
                        d.csel  := 2;
                    elsif c.size_known = '1' and total > c.ind_size then
                        d.abort := '1';
                        d.code  := SDO_ABORT_LENGTH_C;
                        d.csel  := 5;
                    elsif total > BUF_BYTES then
                        d.abort := '1';
                        d.code  := SDO_ABORT_OUT_OF_MEM_C;
                        d.csel  := 4;
                    elsif cmd(sdo_c_bit_c) = '1' and c.size_known = '1'
                          and total /= c.ind_size then
                        d.abort := '1';
                        d.code  := SDO_ABORT_LENGTH_C;
                        d.csel  := 5;
                    else
                        d.wr   := '1';
                        d.wr_a := c.pos(addr_w_c - 1 downto 0);
                        d.wr_n := cnt;
                        d.pos  := total(cnt_w_c - 1 downto 0);

                        if cmd(sdo_c_bit_c) = '1' then
                            d.fin := '1';
                        else
                            d.ul_seg := '1';
                            d.tgl    := not c.toggle;

                            if cnt = 0 then
                                d.empty := '1';
                            end if;
                        end if;
                    end if;

                when others =>

                    null;

            end case;

        end if;

        rxd <= d;

    end process rx_dec_proc;

    -- ---------------------------------------------------------------------------------------------
    -- The engine: one work item at a time (read the context, process, write back), the buffer
    -- units, the receive capture
    -- ---------------------------------------------------------------------------------------------
    eng_proc : process (clk_i, rst_n_i) is

        variable tmo_exp   : boolean;
        variable cnt       : unsigned(3 downto 0);
        variable last_v    : std_logic;
        variable rem_v     : unsigned(cnt_w_c - 1 downto 0);
        variable tgl_v     : std_logic;
        variable data_v    : std_logic_vector(55 downto 0);
        variable do_dl_seg : boolean;
        variable do_ul_seg : boolean;
        variable do_abort  : boolean;
        variable abort_v   : std_logic_vector(31 downto 0);
        variable do_end    : boolean;
        variable withdraw  : boolean;
        variable reload    : boolean;
        variable end_err   : std_logic;
        variable end_code  : std_logic_vector(31 downto 0);
        variable end_sent  : std_logic;

    begin

        if rst_n_i = '0' then
            eng           <= E_IDLE;
            ev            <= EV_ACK;
            ev_ch         <= 0;
            state         <= S_IDLE;
            state_ld      <= S_IDLE;
            done_q        <= '0';
            wdr_new_q     <= '0';
            error_q       <= '0';
            abort_sent_q  <= '0';
            size_q        <= (others => '0');
            new_frame     <= '0';
            bld           <= B_NONE;
            fin_pend      <= '0';
            rx_item_reply <= '0';
            rx_item_unexp <= '0';
            rx_pend       <= '0';
            rx_ch         <= 0;
            rx_done_q     <= '0';
            reload_q      <= '0';
            wd_q          <= '0';
            rx_reply_q    <= '0';
            rx_unexp_q    <= '0';
            nohit_pipe    <= (others => '0');
            fetch_ph      <= 0;
            wr_ph         <= 0;
            seg_cnt_q     <= (others => '0');
            seg_last_q    <= '0';
        elsif rising_edge(clk_i) then
            rx_done_q  <= '0';
            reload_q   <= '0';
            wd_q       <= '0';
            rx_reply_q <= '0';
            rx_unexp_q <= '0';
            do_dl_seg  := false;
            do_ul_seg  := false;
            do_abort   := false;
            abort_v    := (others => '0');
            do_end     := false;
            withdraw   := false;
            reload     := false;
            end_err    := '0';
            end_code   := (others => '0');
            end_sent   := '0';
            tgl_v      := '0';
            tmo_exp    := false;

            -- buffer read unit ---------------------------------------------------------------
            case fetch_ph is

                when 1 =>

                    -- the segment's size ahead of the build in E_WAIT, out of its path (the
                    -- cycle after do_dl_seg; ctx.size_req and ctx.pos do not change in the read)
                    fetch_ph   <= 2;
                    rem_v      := ctx.size_req - ctx.pos;
                    seg_cnt_q  <= to_unsigned(sdo_seg_bytes_c, 4);
                    seg_last_q <= '0';
                    if rem_v <= sdo_seg_bytes_c then
                        seg_cnt_q  <= rem_v(3 downto 0);
                        seg_last_q <= '1';
                    end if;

                when 2 =>

                    seg_buf(31 downto 0) <= from_lanes(b_rdata, fetch_addr(1 downto 0));
                    fetch_ph             <= 3;

                when 3 =>

                    data_v(31 downto 0)   := from_lanes(b_rdata, fetch_addr(1 downto 0));
                    seg_buf(55 downto 32) <= data_v(23 downto 0);
                    fetch_ph              <= 0;

                when others =>

                    null;

            end case;

            -- buffer write unit (a host write to the host copy goes first) -------------------
            if wr_go = '1' then
                if wr_ph = 1 and wr_cnt > sdo_exp_bytes_c then
                    wr_ph <= 2;
                else
                    wr_ph <= 0;
                end if;
            end if;

            -- engine -------------------------------------------------------------------------
            case eng is

                when E_IDLE =>

                    -- the next work item (disp_proc): tx ack > received frame > start > sweep
                    if disp_go = '1' then
                        ev    <= disp_ev;
                        ev_ch <= disp_ch;
                        eng   <= E_READ;
                    end if;

                when E_READ =>

                    -- the context word is read at this edge; the state with it
                    state    <= ch_state(ev_ch);
                    state_ld <= ch_state(ev_ch);
                    eng      <= E_LOAD;

                when E_LOAD =>

                    ctx        <= ctx_unpack(ctx_rdata);
                    rxd_q      <= rxd;
                    tmo_zero_q <= '0';
                    if ctx_unpack(ctx_rdata).tmo_cnt = 0 then
                        tmo_zero_q <= '1';
                    end if;
                    done_q        <= '0';
                    wdr_new_q     <= '0';
                    error_q       <= '0';
                    abort_sent_q  <= '0';
                    new_frame     <= '0';
                    bld           <= B_NONE;
                    fin_pend      <= '0';
                    rx_item_reply <= '0';
                    rx_item_unexp <= '0';

                    if state = S_IDLE or state = S_END then
                        -- the channel's transfer ended before the item was taken: a received
                        -- frame is then not for a transfer; nothing is written back
                        if ev = EV_RX then
                            rx_pend    <= '0';
                            rx_done_q  <= '1';
                            rx_unexp_q <= '1';
                        end if;
                        eng <= E_IDLE;
                    else
                        eng <= E_RUN;
                    end if;

                when E_RUN =>

                    eng <= E_WAIT;

                    -- received frame (decided by rx_dec_proc) ----------------------------------
                    if ev = EV_RX then
                        rx_item_unexp <= rxd_q.unexp;

                        if rxd_q.abort = '1' then
                            do_abort := true;
                            abort_v  := abort_code_of(rxd_q.csel, rx_data_i(63 downto 32));
                        end if;

                        if rxd_q.srv = '1' then
                            -- server abort: the transfer ends with its code, no frame
                            do_end   := true;
                            end_err  := '1';
                            end_code := rx_data_i(63 downto 32);
                            end_sent := '0';
                        end if;

                        if rxd_q.ok_end = '1' then
                            do_end := true;
                        end if;

                        if rxd_q.acked_up = '1' then
                            if rxd_q.ack_sz = '1' then
                                ctx.acked <= ctx.size_req;
                            else
                                ctx.acked <= ctx.pos;
                            end if;
                        end if;

                        if rxd_q.dl_seg = '1' then
                            do_dl_seg := true;
                            tgl_v     := rxd_q.tgl;
                        end if;

                        if rxd_q.ul_seg = '1' then
                            do_ul_seg := true;
                            tgl_v     := rxd_q.tgl;
                        end if;

                        if rxd_q.wr = '1' then
                            wr_ph  <= 1;
                            wr_cnt <= rxd_q.wr_n;
                            if rxd_q.wexp = '1' then
                                wr_addr <= (others => '0');
                                wr_data <= x"000000" & rx_data_i(63 downto 32);
                            else
                                wr_addr <= ctx.pos(addr_w_c - 1 downto 0);
                                wr_data <= rx_data_i(63 downto 8);
                            end if;
                            ctx.pos <= rxd_q.pos;
                        end if;

                        if rxd_q.fin = '1' then
                            state    <= S_FINISH;
                            fin_pend <= '1';
                        end if;

                        if rxd_q.init_ul = '1' then
                            ctx.size_known <= rxd_q.known;
                            ctx.ind_size   <= resize(unsigned(rx_data_i(63 downto 32)), cnt_w_c);
                        end if;

                        if rxd_q.empty = '1' then
                            ctx.empty_cnt <= ctx.empty_cnt + 1;
                        end if;

                        if rxd_q.abort = '1' or rxd_q.dl_seg = '1' or rxd_q.ul_seg = '1' then
                            rx_item_reply <= '1';
                        end if;
                    end if;

                    -- timer sweep: expires at the (timeout + 1)-th ms tick after the last
                    -- reload (tmo_ms is never 0)
                    if ev = EV_TICK then
                        if tmo_zero_q = '1' then
                            tmo_exp := true;
                        else
                            ctx.tmo_cnt <= ctx.tmo_cnt - 1;
                        end if;
                    end if;

                    -- per state ----------------------------------------------------------------
                    case state is

                        when S_START =>

                            if ev = EV_START then
                                if ctx.upload = '1' then
                                    tx_data   <= x"00000000" & ctx.sub & ctx.idx
                                                 & SDO_CCS_UL_INIT_C & sdo_reserved5_c;
                                    new_frame <= '1';
                                    reload    := true;
                                    state     <= S_UL_INIT_TX;
                                else
                                    -- download: the first 7 bytes are read first
                                    fetch_ph   <= 1;
                                    fetch_addr <= (others => '0');
                                    bld        <= B_INIT;
                                end if;
                            end if;

                        when S_DL_INIT_TX | S_DL_SEG_TX | S_UL_INIT_TX | S_UL_SEG_TX =>

                            if tmo_exp then
                                -- the FSM did not take the request: give up (no frame sent)
                                withdraw := true;
                                do_end   := true;
                                end_err  := '1';
                                end_code := SDO_ABORT_TIMEOUT_C;
                                end_sent := '1';
                            end if;

                        when S_DL_INIT_WAIT | S_DL_SEG_WAIT | S_UL_INIT_WAIT | S_UL_SEG_WAIT =>

                            -- the request was taken (the state changed at tx_ack_i): the response
                            -- timer starts again
                            if ev = EV_ACK then
                                reload := true;
                            end if;

                            if tmo_exp then
                                do_abort := true;
                                abort_v  := SDO_ABORT_TIMEOUT_C;
                            end if;

                        when S_ABORT_TX =>

                            if ev = EV_ACK or tmo_exp then
                                withdraw := true;
                                do_end   := true;
                                end_err  := '1';
                                end_code := ctx.abort_code;
                                end_sent := '1';
                            end if;

                        when others =>

                            null;

                    end case;

                when E_WAIT =>

                    -- the buffer units are idle: build the download frame, end an upload
                    if fetch_ph = 0 and wr_ph = 0 then
                        eng <= E_WB;
                        bld <= B_NONE;

                        if bld = B_INIT then
                            new_frame <= '1';
                            reload    := true;
                            state     <= S_DL_INIT_TX;

                            if ctx.size_req /= 0 and ctx.size_req <= sdo_exp_bytes_c then
                                -- expedited, size indicated: n = 4 - size
                                cnt           := resize(ctx.size_req, 4);
                                data_v        := first_bytes(seg_buf, cnt);
                                cnt           := sdo_exp_bytes_c - cnt;
                                tx_data       <= data_v(31 downto 0) & ctx.sub & ctx.idx
                                                 & SDO_CCS_DL_INIT_C & '0'
                                                 & std_logic_vector(cnt(1 downto 0))
                                                 & sdo_exp_sized_c;
                                ctx.expedited <= '1';
                            else
                                -- segmented, size indicated
                                tx_data       <= std_logic_vector(resize(ctx.size_req, 32))
                                                 & ctx.sub & ctx.idx & SDO_CCS_DL_INIT_C
                                                 & sdo_init_seg_c;
                                ctx.expedited <= '0';
                            end if;
                        elsif bld = B_SEG then
                            -- the next download segment from the bytes just read
                            cnt          := seg_cnt_q;
                            last_v       := seg_last_q;
                            data_v       := first_bytes(seg_buf, cnt);
                            tx_data      <= data_v & SDO_CCS_DL_SEG_C & ctx.toggle
                                            & std_logic_vector(to_unsigned(sdo_seg_bytes_c, 3)
                                                                 - cnt(2 downto 0))
                                            & last_v;
                            new_frame    <= '1';
                            reload       := true;
                            ctx.last_seg <= last_v;
                            ctx.pos      <= ctx.pos + cnt;
                        end if;

                        if fin_pend = '1' then
                            do_end := true;
                        end if;
                    end if;

                when E_WB =>

                    -- write back (the context RAM port is the start's in a start cycle)
                    -- (state, frame flag and result go to the channel's flip-flops: chan_proc)
                    if st_go = '0' then
                        eng <= E_IDLE;

                        if ev = EV_RX then
                            rx_pend <= '0';

                            if rx_item_reply = '1' then
                                eng <= E_RXD;
                            else
                                rx_done_q  <= '1';
                                rx_unexp_q <= rx_item_unexp;
                            end if;
                        end if;
                    end if;

                when E_RXD =>

                    -- rx_reply_o comes with tx_req_o = 1 (the new frame, or one presented
                    -- before it: the FSM's St9 takes the presented one); the grant follows the
                    -- write-back in the next cycle (no ack can be pending while the FSM is in St6)
                    if grant = '1' or tx_full = '1' or ack_pend = '1' then
                        rx_done_q  <= '1';
                        rx_reply_q <= '1';
                        eng        <= E_IDLE;
                    end if;

            end case;

            -- actions --------------------------------------------------------------------------
            if do_dl_seg then
                -- read the next 7 bytes, the frame is built in E_WAIT
                ctx.toggle <= tgl_v;
                state      <= S_DL_SEG_TX;
                fetch_ph   <= 1;
                fetch_addr <= ctx.pos(addr_w_c - 1 downto 0);
                bld        <= B_SEG;
            end if;

            if do_ul_seg then
                tx_data    <= x"00000000000000" & SDO_CCS_UL_SEG_C & tgl_v & "0000";
                new_frame  <= '1';
                ctx.toggle <= tgl_v;
                reload     := true;
                state      <= S_UL_SEG_TX;
            end if;

            if do_abort then
                tx_data        <= abort_v & ctx.sub & ctx.idx & SDO_CS_ABORT_C & sdo_reserved5_c;
                new_frame      <= '1';
                ctx.abort_code <= abort_v;
                reload         := true;
                state          <= S_ABORT_TX;
            end if;

            if reload then
                -- a tick before this reload does not count (the old per-channel timer's rule)
                ctx.tmo_cnt <= ctx.tmo_ms;
                reload_q    <= '1';
            end if;

            if withdraw then
                -- the waiting request is withdrawn (chan_proc, next cycle)
                wd_q <= '1';
            end if;

            -- every end or abort of the transfer withdraws its request still waiting in TXB1
            -- (not an end after the abort frame: that withdraw was done before the frame)
            if do_abort or (do_end and state_ld /= S_ABORT_TX) then
                wdr_new_q <= '1';
            end if;

            if do_end then
                state   <= S_IDLE;
                done_q  <= '1';
                error_q <= end_err;

                if end_err = '1' then
                    ctx.abort_code <= end_code;
                    abort_sent_q   <= end_sent;
                end if;

                if ctx.upload = '1' then
                    size_q <= ctx.pos;
                elsif end_err = '0' then
                    size_q <= ctx.size_req;
                else
                    size_q <= ctx.acked;
                end if;
            end if;

            -- receive: capture last, so that a frame arriving as one is finished is kept --------
            if rx_valid_i = '1' and or_reduce(rx_hit) = '1' then
                rx_pend <= '1';
                rx_ch   <= rx_hit_ch;
            end if;

            nohit_pipe(0) <= rx_valid_i and not or_reduce(rx_hit);
            nohit_pipe(1) <= nohit_pipe(0);
        end if;

    end process eng_proc;

    -- simulation only: the received frame must not change from rx_valid_i until rx_done_o
    -- pragma translate_off
    rx_hold_check_proc : process (clk_i) is

        variable held : std_logic_vector(68 downto 0);

    begin

        if rising_edge(clk_i) then
            hold_check(held, rx_pend = '1', rx_rtr_i & rx_dlc_i & rx_data_i,
                       "canopen_sdo_channels: rx_*_i (until rx_done_o)");
        end if;

    end process rx_hold_check_proc;

    -- pragma translate_on

    rx_done_o       <= rx_done_q or nohit_pipe(1);
    rx_reply_o      <= rx_reply_q;
    rx_unexpected_o <= rx_unexp_q or nohit_pipe(1);

    tx_req_o   <= tx_full;
    tx_abort_o <= '1' when ch_state(tx_ch) = S_ABORT_TX else
                  '0';
    wdr_req_o  <= wdr_cur;
    wdr_id_o   <= run_req(wdr_ch);
    tx_id_o    <= run_req(tx_ch);
    tx_dlc_o   <= sdo_dlc_c;
    tx_data_o  <= frm_rdata;

    -- ---------------------------------------------------------------------------------------------
    -- Abort counting: one strobe per aborted transfer, none lost when two end together
    -- ---------------------------------------------------------------------------------------------
    abort_proc : process (clk_i, rst_n_i) is

        variable n : unsigned(2 downto 0);

    begin

        if rst_n_i = '0' then
            abort_pend  <= (others => '0');
            cnt_abort_o <= '0';
        elsif rising_edge(clk_i) then
            n := abort_pend;

            for c in 0 to N_SDO - 1 loop

                if c_done(c) = '1' and res_err(c) = '1' then
                    n := n + 1;
                end if;

            end loop;

            if n /= 0 then
                cnt_abort_o <= '1';
                n           := n - 1;
            else
                cnt_abort_o <= '0';
            end if;
            abort_pend <= n;
        end if;

    end process abort_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Status
    -- ---------------------------------------------------------------------------------------------

    status_gen : for c in 0 to 3 generate

        have_gen : if c < N_SDO generate
            chan_busy_o(c) <= c_busy(c) or own_i or own_pend when c = 0 else
                              c_busy(c);
            chan_done_o(c) <= c_done(c) and not own_i when c = 0 else
                              c_done(c);
            chan_go_o(c)   <= host_go when sel = c else
                              '0';
        end generate have_gen;

        none_gen : if c >= N_SDO generate
            chan_busy_o(c) <= '0';
            chan_done_o(c) <= '0';
            chan_go_o(c)   <= '0';
        end generate none_gen;

    end generate status_gen;

    busy_o       <= c_busy(sel) or own_i or own_pend when sel = 0 else
                    c_busy(sel);
    error_o      <= res_err(sel);
    abort_code_o <= SDO_ABORT_OUT_OF_MEM_C when res_oom_q = '1' else
                    res_q(43 downto 12) when res_ok_q = '1' else
                    (others => '0');
    abort_sent_o <= res_oom_q or (res_ok_q and res_q(11));
    size_o       <= res_q(10 downto 0) when res_ok_q = '1' else
                    (others => '0');
    -- in the cycle a request is decided its outcome is shown, not the previous one (a read right
    -- after the SDO_CMD write sees the outcome of that write)
    refused_o   <= not host_go when host_req_i = '1' and sel_ok = '1' else
                   refused(sel);
    buf_rdata_o <= a_rdata;
    state_o     <= state_code(ch_state(sel));

    own_idle_o  <= not c_busy(0) and not own_pend;
    own_done_o  <= c_done(0) and own_i;
    own_error_o <= res_err(0);
    own_abort_o <= own_code;

end architecture rtl;
