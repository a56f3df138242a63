-- =================================================================================================
-- Title    : canopen_autoconfig
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   Automatic slave configuration: a table of SDO downloads run before each node is started.
-- Purpose:
--   The boot sequence of the Hefei thesis: configure every slave by SDO (PDO communication and
--   mapping parameters 1400h/1600h/1800h/1A00h, heartbeat producer time 1017h, drive mode
--   objects...), then start it with NMT, then exchange PDOs.
--   The host fills (ACFG_* registers) a table of entries {node, index, subindex,
--   size 1..4, value}. On start_i the block walks the table from entry 0 until an entry with
--   node 0 (or the end): consecutive entries with the same node form that node's list. Each entry
--   is one expedited SDO download through canopen_sdo_channels (its value is written into the
--   client's buffer word 0 first). When all entries of a node succeeded the node is counted as
--   configured and, with start_nodes_i, an NMT start for it is requested. The first failing
--   entry of a node (server abort, client abort, timeout) stops that node: its remaining
--   entries are skipped, it is not started, and the failure is reported with node, entry and
--   abort code in a failure log (the first 16 failing nodes of the run, read by
--   index: log_sel_i, 0 = first); the walk continues with the next node. Every wait is bounded
--   by the SDO client's own timeout.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

entity canopen_autoconfig is
    generic (
        CFG_DEPTH : positive range 2 to 256 := 64 -- table entries
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low
        -- table write port (host)
        tbl_we_i    : in    std_logic;                     -- write entry tbl_addr_i
        tbl_addr_i  : in    std_logic_vector(7 downto 0);  -- entry number
        tbl_node_i  : in    std_logic_vector(6 downto 0);  -- node-ID (0 ends the table)
        tbl_index_i : in    std_logic_vector(15 downto 0); -- object index
        tbl_sub_i   : in    std_logic_vector(7 downto 0);  -- subindex
        tbl_size_i  : in    std_logic_vector(2 downto 0);  -- value size 1..4 bytes
        tbl_value_i : in    std_logic_vector(31 downto 0); -- value, little-endian bytes
        -- control and status
        start_i       : in    std_logic;                     -- pulse: run the table
        start_nodes_i : in    std_logic;                     -- NMT start each configured node
        busy_o        : out   std_logic;                     -- walking the table
        done_o        : out   std_logic;                     -- strobe: table finished
        nodes_ok_o    : out   std_logic_vector(7 downto 0);  -- nodes configured in the last run
        nodes_fail_o  : out   std_logic_vector(7 downto 0);  -- nodes that failed in the last run
        log_sel_i     : in    std_logic_vector(3 downto 0);  -- failure log read index
        fail_node_o   : out   std_logic_vector(6 downto 0);  -- failure log_sel_i: node (+1)
        fail_entry_o  : out   std_logic_vector(7 downto 0);  -- failure log_sel_i: entry (+1)
        fail_abort_o  : out   std_logic_vector(31 downto 0); -- failure log_sel_i: abort (+1)
        ev_fail_o     : out   std_logic;                     -- strobe: a node failed
        -- SDO client (owned by this block while busy_o = '1')
        sdo_req_o       : out   std_logic;                     -- pulse: start a download
        sdo_node_o      : out   std_logic_vector(6 downto 0);  -- server node-ID
        sdo_index_o     : out   std_logic_vector(15 downto 0); -- index
        sdo_sub_o       : out   std_logic_vector(7 downto 0);  -- subindex
        sdo_size_o      : out   std_logic_vector(10 downto 0); -- bytes (1..4: expedited)
        sdo_buf_we_o    : out   std_logic;                     -- write buffer word 0
        sdo_buf_wdata_o : out   std_logic_vector(31 downto 0); -- the value
        sdo_done_i      : in    std_logic;                     -- strobe: transfer ended
        sdo_error_i     : in    std_logic;                     -- with done: it failed
        sdo_abort_i     : in    std_logic_vector(31 downto 0); -- abort code
        -- NMT start request (to the master's NMT generation)
        nmt_req_o   : out   std_logic;                    -- pulse: start node nmt_node_o
        nmt_node_o  : out   std_logic_vector(6 downto 0); -- node to start
        nmt_ready_i : in    std_logic                     -- the NMT path can take a request
    );
end entity canopen_autoconfig;

architecture rtl of canopen_autoconfig is

    -- entry: node(7) & size(3) & index(16) & sub(8) & value(32) = 66 bits
    constant entry_w_c : natural := 66;

    type table_t is array (0 to CFG_DEPTH - 1) of std_logic_vector(entry_w_c - 1 downto 0);

    -- failure log: node(7) & entry(8) & abort code(32) of the k-th failing node of the run
    constant log_depth_c : positive := 16;
    constant log_w_c     : natural  := 47;

    type log_t is array (0 to log_depth_c - 1) of std_logic_vector(log_w_c - 1 downto 0);

    type state_t is (
        S_IDLE,   -- waiting for start_i
        S_FETCH,  -- table read address applied
        S_DECODE, -- entry available: end of table, skip, or download
        S_LOAD,   -- value into the SDO buffer, request the download
        S_WAIT,   -- download running
        S_NMT     -- request NMT start of the node just configured
    );

    -- table RAM (synchronous read, one clocked process, no reset: an M9K); its output register
    -- reads only in S_FETCH and holds the entry being run (no copy of it) until the next fetch
    signal table    : table_t;
    signal rd_addr  : natural range 0 to CFG_DEPTH - 1;
    signal rd_entry : std_logic_vector(entry_w_c - 1 downto 0);
    -- failure log RAM (synchronous read, no reset), its write port and read data
    signal log_ram   : log_t;
    signal log_we    : std_logic;
    signal log_waddr : natural range 0 to log_depth_c - 1;
    signal log_wdata : std_logic_vector(log_w_c - 1 downto 0);
    signal log_rdata : std_logic_vector(log_w_c - 1 downto 0);
    -- the selected index holds a failure of the last run
    signal log_valid : std_logic;
    -- walk
    signal state : state_t;
    signal idx   : natural range 0 to CFG_DEPTH;
    -- node whose entries are being run, and whether it already failed (skip the rest)
    signal cur_node  : std_logic_vector(6 downto 0);
    signal node_fail : std_logic;
    signal have_node : std_logic;
    signal n_ok      : unsigned(7 downto 0);
    signal n_fail    : unsigned(7 downto 0);
    -- the end of the table was reached: report done after the last node's NMT start
    signal ending : std_logic;

    function e_node (e : std_logic_vector(entry_w_c - 1 downto 0)) return std_logic_vector is
    begin

        return e(65 downto 59);

    end function e_node;

begin

    table_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if tbl_we_i = '1' and unsigned(tbl_addr_i) < CFG_DEPTH then
                table(to_integer(unsigned(tbl_addr_i))) <= tbl_node_i & tbl_size_i & tbl_index_i
                                                           & tbl_sub_i & tbl_value_i;
            end if;
            if state = S_FETCH then
                rd_entry <= table(rd_addr);
            end if;
        end if;

    end process table_proc;

    log_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if log_we = '1' then
                log_ram(log_waddr) <= log_wdata;
            end if;
            log_rdata <= log_ram(to_integer(unsigned(log_sel_i)));
            if unsigned(log_sel_i) < n_fail then
                log_valid <= '1';
            else
                log_valid <= '0';
            end if;
        end if;

    end process log_proc;

    walk_proc : process (clk_i, rst_n_i) is

        -- a node's list ended (next node, or end of table): count it, maybe start it, then
        -- continue (fetch the next node's entry again) or finish

        procedure node_finished (at_end : boolean) is

            variable start_it : boolean;

        begin

            start_it := have_node = '1' and node_fail = '0' and start_nodes_i = '1';

            if have_node = '1' and node_fail = '0' then
                n_ok <= n_ok + 1;
            end if;

            if at_end then
                ending <= '1';
            end if;

            if start_it then
                state <= S_NMT;
            elsif at_end then
                done_o <= '1';
                state  <= S_IDLE;
            else
                state <= S_FETCH;
            end if;

        end procedure node_finished;

    begin

        if rst_n_i = '0' then
            state        <= S_IDLE;
            idx          <= 0;
            rd_addr      <= 0;
            have_node    <= '0';
            node_fail    <= '0';
            n_ok         <= (others => '0');
            n_fail       <= (others => '0');
            log_we       <= '0';
            ending       <= '0';
            done_o       <= '0';
            ev_fail_o    <= '0';
            sdo_req_o    <= '0';
            sdo_buf_we_o <= '0';
            nmt_req_o    <= '0';
        elsif rising_edge(clk_i) then
            done_o       <= '0';
            ev_fail_o    <= '0';
            sdo_req_o    <= '0';
            sdo_buf_we_o <= '0';
            nmt_req_o    <= '0';
            log_we       <= '0';

            case state is

                when S_IDLE =>

                    if start_i = '1' then
                        idx       <= 0;
                        rd_addr   <= 0;
                        have_node <= '0';
                        node_fail <= '0';
                        n_ok      <= (others => '0');
                        n_fail    <= (others => '0');
                        ending    <= '0';
                        state     <= S_FETCH;
                    end if;

                when S_FETCH =>

                    -- the RAM presents table(rd_addr) on the next edge
                    state <= S_DECODE;

                when S_DECODE =>

                    if idx = CFG_DEPTH or e_node(rd_entry) = "0000000" then
                        -- end of the table: close the last node, then report
                        node_finished(true);
                    elsif have_node = '1' and e_node(rd_entry) /= cur_node then
                        -- a new node begins: close the previous one first, re-read this entry
                        node_finished(false);
                        have_node <= '0';
                    else
                        if have_node = '0' then
                            cur_node  <= e_node(rd_entry);
                            have_node <= '1';
                            node_fail <= '0';
                        end if;
                        if have_node = '1' and node_fail = '1' then
                            -- this node already failed: skip its remaining entries
                            idx     <= idx + 1;
                            rd_addr <= (idx + 1) mod CFG_DEPTH;
                            state   <= S_FETCH;
                        else
                            state <= S_LOAD;
                        end if;
                    end if;

                when S_LOAD =>

                    sdo_buf_we_o <= '1';
                    sdo_req_o    <= '1';
                    state        <= S_WAIT;

                when S_WAIT =>

                    if sdo_done_i = '1' then
                        if sdo_error_i = '1' then
                            node_fail <= '1';
                            n_fail    <= n_fail + 1;
                            ev_fail_o <= '1';
                            if n_fail < log_depth_c then
                                log_we    <= '1';
                                log_waddr <= to_integer(n_fail(3 downto 0));
                                log_wdata <= cur_node & std_logic_vector(to_unsigned(idx, 8))
                                             & sdo_abort_i;
                            end if;
                        end if;
                        idx     <= idx + 1;
                        rd_addr <= (idx + 1) mod CFG_DEPTH;
                        state   <= S_FETCH;
                    end if;

                when S_NMT =>

                    if nmt_ready_i = '1' then
                        nmt_req_o <= '1';
                        if ending = '1' then
                            done_o <= '1';
                            state  <= S_IDLE;
                        else
                            state <= S_FETCH;
                        end if;
                    end if;

            end case;

        end if;

    end process walk_proc;

    busy_o          <= '0' when state = S_IDLE else '1';
    nodes_ok_o      <= std_logic_vector(n_ok);
    nodes_fail_o    <= std_logic_vector(n_fail);
    sdo_node_o      <= e_node(rd_entry);
    sdo_size_o      <= "00000000" & rd_entry(58 downto 56);
    sdo_index_o     <= rd_entry(55 downto 40);
    sdo_sub_o       <= rd_entry(39 downto 32);
    sdo_buf_wdata_o <= rd_entry(31 downto 0);
    nmt_node_o      <= cur_node;
    -- failure log_sel_i of the last run, 0 when the run had fewer failures
    fail_node_o  <= log_rdata(46 downto 40) when log_valid = '1' else
                    (others => '0');
    fail_entry_o <= log_rdata(39 downto 32) when log_valid = '1' else
                    (others => '0');
    fail_abort_o <= log_rdata(31 downto 0) when log_valid = '1' else
                    (others => '0');

end architecture rtl;
