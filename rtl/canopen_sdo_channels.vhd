-- =================================================================================================
-- Title    : canopen_sdo_channels
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   N_SDO independent SDO client channels (canopen_sdo_client each) behind one host port, one
--   FSM frame interface and one owner port for the configuration list.
-- Purpose:
--   Lets SDO transfers to different nodes interleave on the bus (the host reads a diagnostic
--   object of one drive while another is being configured), one transfer at a time per node.
--   * Host port: the host selects a channel (SDO_SEL.CHAN = host_chan_i); SDO_CMD starts a
--     transfer on it with the object fields of the host registers, the status outputs and the
--     buffer port show / access the selected channel.
--   * A request is refused, nothing is sent and the channel's refused flag is set, when the
--     core is in Omni-ID mode (enable_i = 0), the node-ID is 0 or above 127, the channel is
--     busy, channel 0 belongs to the configuration list (own_i = 1), or another running
--     transfer (or the list's waiting request) uses the same request or response COB-ID: one
--     transfer per SDO server at a time, so every response frame belongs to exactly one
--     channel. The flag describes the last request on that channel: it clears with the next
--     accepted one; refused_o shows the decision already in the cycle of the request, so a
--     host read right after the SDO_CMD write sees it. chan_go_o marks an accepted request
--     (the host block clears that channel's DONE with it).
--   * Owner port: while own_i = 1 channel 0 belongs to canopen_autoconfig (default COB-IDs,
--     600h/580h + node). Its request waits (never refused) until no other channel talks to the
--     same node; every other channel's transfer ends within its bound (canopen_sdo_client), so
--     the wait is bounded. Channel 0's done strobe goes to the owner, not to the host.
--   * Transmit: the channels' frames are taken in round-robin order. tx_req_o shows the request
--     of the channel that tx_sel points at; tx_sel only moves (to the next requesting channel)
--     in a cycle where its own request is low, so the frame the FSM copies in St11 and the
--     registered tx_ack_i that follows both belong to the same channel.
--   * Receive (St6): the frame goes to the busy channel whose response COB-ID it carries; a
--     frame no channel waits for is answered by this block (rx_done_o two cycles later,
--     rx_unexpected_o = 1), with the same timing as a client. rx_match_o tells the St4
--     classifier that a frame outside 580h..5FFh carries a running transfer's response COB-ID.
--   * Aborts: every transfer ending in an abort gives one cnt_abort_o strobe; transfers ending in
--     the same cycle are counted one per cycle afterwards (none lost).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_pkg.all;
    use work.canopen_util_pkg.all;

entity canopen_sdo_channels is
    generic (
        N_SDO     : positive range 1 to 4    := 2;  -- SDO client channels
        BUF_BYTES : positive range 8 to 1024 := 256 -- transfer buffer per channel [bytes]
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
        -- status of the selected channel
        busy_o       : out   std_logic;                     -- transfer running (or owned)
        error_o      : out   std_logic;                     -- last transfer aborted
        abort_code_o : out   std_logic_vector(31 downto 0); -- its abort code
        abort_sent_o : out   std_logic;                     -- 1: the master aborted
        size_o       : out   std_logic_vector(10 downto 0); -- bytes transferred
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
        tx_req_o  : out   std_logic;                     -- level: a frame is waiting
        tx_id_o   : out   std_logic_vector(10 downto 0); -- identifier
        tx_dlc_o  : out   std_logic_vector(3 downto 0);  -- data length code
        tx_data_o : out   std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        tx_ack_i  : in    std_logic;                     -- strobe: frame taken
        -- received frame (from the FSM, St6)
        rx_match_o      : out   std_logic;                     -- rx_id_i = a running response
        rx_valid_i      : in    std_logic;                     -- strobe: process this frame
        rx_id_i         : in    std_logic_vector(10 downto 0); -- identifier
        rx_rtr_i        : in    std_logic;                     -- remote frame
        rx_dlc_i        : in    std_logic_vector(3 downto 0);  -- data length code
        rx_data_i       : in    std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        rx_done_o       : out   std_logic;                     -- strobe: frame processed
        rx_reply_o      : out   std_logic;                     -- with done: tx_req_o set
        rx_unexpected_o : out   std_logic                      -- with done: nobody waited
    );
end entity canopen_sdo_channels;

architecture rtl of canopen_sdo_channels is

    subtype chan_vec_t is std_logic_vector(N_SDO - 1 downto 0);

    type cob_arr_t is array (0 to N_SDO - 1) of std_logic_vector(10 downto 0);

    type w32_arr_t is array (0 to N_SDO - 1) of std_logic_vector(31 downto 0);

    type w64_arr_t is array (0 to N_SDO - 1) of std_logic_vector(63 downto 0);

    type w11_arr_t is array (0 to N_SDO - 1) of std_logic_vector(10 downto 0);

    type w4_arr_t is array (0 to N_SDO - 1) of std_logic_vector(3 downto 0);

    -- effective COB-ID: the configured one, or the default function code + node

    function eff_cob (cfg : std_logic_vector(10 downto 0); fc : func_code_t;
        node : std_logic_vector(6 downto 0)) return std_logic_vector is
    begin

        if unsigned(cfg) = 0 then
            return cob_id(fc, node);
        end if;

        return cfg;

    end function eff_cob;

    -- client ports
    signal c_req      : chan_vec_t;
    signal c_upload   : chan_vec_t;
    signal c_node     : std_logic_vector(6 downto 0);
    signal c0_node    : std_logic_vector(6 downto 0);
    signal c0_index   : std_logic_vector(15 downto 0);
    signal c0_sub     : std_logic_vector(7 downto 0);
    signal c0_size    : std_logic_vector(10 downto 0);
    signal c0_cob_req : std_logic_vector(10 downto 0);
    signal c0_cob_rsp : std_logic_vector(10 downto 0);
    signal c_busy     : chan_vec_t;
    signal c_done     : chan_vec_t;
    signal c_error    : chan_vec_t;
    signal c_abort    : w32_arr_t;
    signal c_asent    : chan_vec_t;
    signal c_size     : w11_arr_t;
    signal c_buf_we   : chan_vec_t;
    signal c0_buf_a   : std_logic_vector(7 downto 0);
    signal c0_buf_d   : std_logic_vector(31 downto 0);
    signal c_rdata    : w32_arr_t;
    signal c_tx_req   : chan_vec_t;
    signal c_tx_id    : cob_arr_t;
    signal c_tx_dlc   : w4_arr_t;
    signal c_tx_data  : w64_arr_t;
    signal c_tx_ack   : chan_vec_t;
    signal c_rx_valid : chan_vec_t;
    signal c_rx_done  : chan_vec_t;
    signal c_rx_reply : chan_vec_t;
    signal c_rx_unexp : chan_vec_t;

    -- effective request / response COB-IDs of each channel's running transfer
    signal run_req : cob_arr_t;
    signal run_rsp : cob_arr_t;
    -- effective COB-IDs of the host's request and of the owner's request
    signal host_req_cob : std_logic_vector(10 downto 0);
    signal host_rsp_cob : std_logic_vector(10 downto 0);
    signal own_req_cob  : std_logic_vector(10 downto 0);
    signal own_rsp_cob  : std_logic_vector(10 downto 0);
    -- the selected channel as an index, and whether it exists
    signal sel    : natural range 0 to N_SDO - 1;
    signal sel_ok : std_logic;
    -- the host's request collides with a running transfer on another channel (or the owner's
    -- waiting request); the owner's request collides with a running transfer on channels 1..
    signal host_clash : std_logic;
    signal own_clash  : std_logic;
    -- the host request is accepted on the selected channel this cycle; its node-ID is valid
    signal host_go : std_logic;
    signal node_ok : std_logic;
    -- the owner's request waits for its node to be free
    signal own_pend : std_logic;
    signal own_go   : std_logic;
    -- sticky refused flag per channel
    signal refused : chan_vec_t;
    -- channel whose frame tx_req_o presents
    signal tx_sel : natural range 0 to N_SDO - 1;
    -- a frame no channel waits for: answered two cycles later
    signal rx_hit     : chan_vec_t;
    signal nohit_pipe : std_logic_vector(1 downto 0);
    -- aborts ended but not yet counted
    signal abort_pend : unsigned(2 downto 0);

begin

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

    -- ---------------------------------------------------------------------------------------------
    -- Request admission: one transfer per SDO server (request or response COB-ID) at a time
    -- ---------------------------------------------------------------------------------------------
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
    own_go  <= own_pend and not own_clash and not c_busy(0);

    admit_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            refused  <= (others => '0');
            own_pend <= '0';
            run_req  <= (others => (others => '0'));
            run_rsp  <= (others => (others => '0'));
        elsif rising_edge(clk_i) then
            if host_req_i = '1' and host_go = '0' and sel_ok = '1' then
                refused(sel) <= '1';
            end if;

            for c in 0 to N_SDO - 1 loop

                if host_go = '1' and sel = c then
                    refused(c) <= '0';
                    run_req(c) <= host_req_cob;
                    run_rsp(c) <= host_rsp_cob;
                end if;

            end loop;

            if own_req_i = '1' then
                own_pend <= '1';
            elsif own_go = '1' then
                own_pend   <= '0';
                run_req(0) <= own_req_cob;
                run_rsp(0) <= own_rsp_cob;
            end if;
        end if;

    end process admit_proc;

    -- channel requests and fields: channel 0 is the owner's while own_i = 1

    req_gen : for c in 0 to N_SDO - 1 generate
        c_req(c)    <= '1' when host_go = '1' and sel = c else
                       own_go when c = 0 else
                       '0';
        c_upload(c) <= host_upload_i when host_go = '1' and sel = c else
                       '0';
        c_buf_we(c) <= '1' when buf_we_i = '1' and sel_ok = '1' and sel = c
                                and not (c = 0 and own_i = '1') else
                       own_buf_we_i when c = 0 and own_i = '1' else
                       '0';
    end generate req_gen;

    c_node     <= host_node_i(6 downto 0);
    c0_node    <= own_node_i when own_i = '1' else
                  host_node_i(6 downto 0);
    c0_index   <= own_index_i when own_i = '1' else
                  host_index_i;
    c0_sub     <= own_sub_i when own_i = '1' else
                  host_sub_i;
    c0_size    <= own_size_i when own_i = '1' else
                  host_size_i;
    c0_cob_req <= (others => '0') when own_i = '1' else
                  host_cob_req_i;
    c0_cob_rsp <= (others => '0') when own_i = '1' else
                  host_cob_rsp_i;
    c0_buf_a   <= (others => '0') when own_i = '1' else
                  buf_addr_i;
    c0_buf_d   <= own_buf_data_i when own_i = '1' else
                  buf_wdata_i;

    -- ---------------------------------------------------------------------------------------------
    -- The channels
    -- ---------------------------------------------------------------------------------------------

    chan_gen : for c in 0 to N_SDO - 1 generate

        chan0_gen : if c = 0 generate

            client_inst : entity work.canopen_sdo_client
                generic map (
                    BUF_BYTES => BUF_BYTES
                )
                port map (
                    clk_i           => clk_i,
                    rst_n_i         => rst_n_i,
                    tick_ms_i       => tick_ms_i,
                    req_valid_i     => c_req(c),
                    req_upload_i    => c_upload(c),
                    req_node_i      => c0_node,
                    req_index_i     => c0_index,
                    req_subindex_i  => c0_sub,
                    req_size_i      => c0_size,
                    cob_req_i       => c0_cob_req,
                    cob_resp_i      => c0_cob_rsp,
                    timeout_ms_i    => timeout_ms_i,
                    busy_o          => c_busy(c),
                    done_o          => c_done(c),
                    error_o         => c_error(c),
                    abort_code_o    => c_abort(c),
                    abort_sent_o    => c_asent(c),
                    size_o          => c_size(c),
                    buf_addr_i      => c0_buf_a,
                    buf_we_i        => c_buf_we(c),
                    buf_wdata_i     => c0_buf_d,
                    buf_rdata_o     => c_rdata(c),
                    tx_req_o        => c_tx_req(c),
                    tx_id_o         => c_tx_id(c),
                    tx_dlc_o        => c_tx_dlc(c),
                    tx_data_o       => c_tx_data(c),
                    tx_ack_i        => c_tx_ack(c),
                    rx_valid_i      => c_rx_valid(c),
                    rx_id_i         => rx_id_i,
                    rx_rtr_i        => rx_rtr_i,
                    rx_dlc_i        => rx_dlc_i,
                    rx_data_i       => rx_data_i,
                    rx_done_o       => c_rx_done(c),
                    rx_reply_o      => c_rx_reply(c),
                    rx_unexpected_o => c_rx_unexp(c),
                    state_o         => open
                );

        end generate chan0_gen;

        chan_n_gen : if c /= 0 generate

            client_inst : entity work.canopen_sdo_client
                generic map (
                    BUF_BYTES => BUF_BYTES
                )
                port map (
                    clk_i           => clk_i,
                    rst_n_i         => rst_n_i,
                    tick_ms_i       => tick_ms_i,
                    req_valid_i     => c_req(c),
                    req_upload_i    => c_upload(c),
                    req_node_i      => c_node,
                    req_index_i     => host_index_i,
                    req_subindex_i  => host_sub_i,
                    req_size_i      => host_size_i,
                    cob_req_i       => host_cob_req_i,
                    cob_resp_i      => host_cob_rsp_i,
                    timeout_ms_i    => timeout_ms_i,
                    busy_o          => c_busy(c),
                    done_o          => c_done(c),
                    error_o         => c_error(c),
                    abort_code_o    => c_abort(c),
                    abort_sent_o    => c_asent(c),
                    size_o          => c_size(c),
                    buf_addr_i      => buf_addr_i,
                    buf_we_i        => c_buf_we(c),
                    buf_wdata_i     => buf_wdata_i,
                    buf_rdata_o     => c_rdata(c),
                    tx_req_o        => c_tx_req(c),
                    tx_id_o         => c_tx_id(c),
                    tx_dlc_o        => c_tx_dlc(c),
                    tx_data_o       => c_tx_data(c),
                    tx_ack_i        => c_tx_ack(c),
                    rx_valid_i      => c_rx_valid(c),
                    rx_id_i         => rx_id_i,
                    rx_rtr_i        => rx_rtr_i,
                    rx_dlc_i        => rx_dlc_i,
                    rx_data_i       => rx_data_i,
                    rx_done_o       => c_rx_done(c),
                    rx_reply_o      => c_rx_reply(c),
                    rx_unexpected_o => c_rx_unexp(c),
                    state_o         => open
                );

        end generate chan_n_gen;

    end generate chan_gen;

    -- ---------------------------------------------------------------------------------------------
    -- Transmit: round robin, the selection only moves while its own request is low
    -- ---------------------------------------------------------------------------------------------
    tx_sel_proc : process (clk_i, rst_n_i) is

        variable next_v : natural range 0 to N_SDO - 1;
        variable found  : boolean;

    begin

        if rst_n_i = '0' then
            tx_sel <= 0;
        elsif rising_edge(clk_i) then
            if c_tx_req(tx_sel) = '0' then
                next_v := tx_sel;
                found  := false;

                for k in 1 to N_SDO loop

                    if not found and c_tx_req((tx_sel + k) mod N_SDO) = '1' then
                        next_v := (tx_sel + k) mod N_SDO;
                        found  := true;
                    end if;

                end loop;

                tx_sel <= next_v;
            end if;
        end if;

    end process tx_sel_proc;

    tx_req_o  <= c_tx_req(tx_sel);
    tx_id_o   <= c_tx_id(tx_sel);
    tx_dlc_o  <= c_tx_dlc(tx_sel);
    tx_data_o <= c_tx_data(tx_sel);

    ack_gen : for c in 0 to N_SDO - 1 generate
        c_tx_ack(c) <= tx_ack_i when tx_sel = c else
                       '0';
    end generate ack_gen;

    -- ---------------------------------------------------------------------------------------------
    -- Receive: to the channel whose running transfer has this response COB-ID
    -- ---------------------------------------------------------------------------------------------

    hit_gen : for c in 0 to N_SDO - 1 generate
        rx_hit(c)     <= '1' when c_busy(c) = '1' and run_rsp(c) = rx_id_i else
                         '0';
        c_rx_valid(c) <= rx_valid_i and rx_hit(c);
    end generate hit_gen;

    rx_match_o <= or_reduce(rx_hit);

    nohit_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            nohit_pipe <= (others => '0');
        elsif rising_edge(clk_i) then
            nohit_pipe(0) <= rx_valid_i and not or_reduce(rx_hit);
            nohit_pipe(1) <= nohit_pipe(0);
        end if;

    end process nohit_proc;

    rx_done_o       <= or_reduce(c_rx_done) or nohit_pipe(1);
    rx_reply_o      <= or_reduce(c_rx_done and c_rx_reply);
    rx_unexpected_o <= or_reduce(c_rx_done and c_rx_unexp) or nohit_pipe(1);

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

                if c_done(c) = '1' and c_error(c) = '1' then
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
    error_o      <= c_error(sel);
    abort_code_o <= c_abort(sel);
    abort_sent_o <= c_asent(sel);
    size_o       <= c_size(sel);
    -- in the cycle a request is decided its outcome is shown, not the previous one (a read right
    -- after the SDO_CMD write sees the outcome of that write)
    refused_o   <= not host_go when host_req_i = '1' and sel_ok = '1' else
                   refused(sel);
    buf_rdata_o <= c_rdata(sel);

    own_idle_o  <= not c_busy(0) and not own_pend;
    own_done_o  <= c_done(0) and own_i;
    own_error_o <= c_error(0);
    own_abort_o <= c_abort(0);

end architecture rtl;
