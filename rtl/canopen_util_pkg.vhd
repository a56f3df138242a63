-- =================================================================================================
-- Title    : canopen_util_pkg
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   Small helpers shared by several blocks (VHDL-93).
-- Purpose:
--   One definition of each helper more than one block needs: the register-word packing and
--   window-offset compare used by every read mux (canopen_host_regs, canopen_pdo_engine,
--   omni_engine), the saturating event counters (error and statistics counters stop at all
--   ones instead of wrapping, so a host never sees a small count after a flood), the OR
--   reduction (VHDL-93 has no unary `or v`), frame-byte masking by DLC, and the elaboration
--   arithmetic on generics (ceiling log2, ns to clock cycles, the larger of two naturals),
--   counters and compares split in halves (lt_split, inc_split). Also the byte-lane helpers of
--   the SDO buffer (word_byte, from_lanes, first_bytes): one user, here to keep
--   canopen_sdo_channels.vhd within the 2 000-line file limit of the style check.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

package canopen_util_pkg is

    -- a 32-bit register word holding val in bits hi..lo, zeros elsewhere (a width mismatch
    -- stops the simulation)

    function at (val : std_logic_vector; hi : natural; lo : natural) return std_logic_vector;

    -- a 32-bit register word holding val in bit pos, zeros elsewhere

    function at (val : std_logic; pos : natural) return std_logic_vector;

    -- c + 1, or c when c is already all ones

    function sat_inc (c : unsigned) return unsigned;

    -- c + n, or all ones when the sum does not fit

    function sat_add (c : unsigned; n : natural) return unsigned;

    -- '1' when any bit of v is '1' (the VHDL-2008 unary `or v`)

    function or_reduce (v : std_logic_vector) return std_logic;

    -- 1 for '1', 0 otherwise

    function bit_int (b : std_logic) return natural;

    -- addr equals off (a compare without arithmetic: no numeric_std warnings on an undriven bus)

    function is_off (addr : std_logic_vector; off : natural) return boolean;

    -- the first dlc bytes of an 8-byte frame payload (byte j in bits 8j+7..8j), the others
    -- zero; a DLC of 9..15 means 8 bytes

    function keep_bytes (v : std_logic_vector(63 downto 0); dlc : std_logic_vector(3 downto 0))
        return std_logic_vector;

    -- byte j (0..3) of a 32-bit word

    function word_byte (v : std_logic_vector(31 downto 0); j : unsigned(1 downto 0))
        return std_logic_vector;

    -- lane outputs read at byte address a (lane k holds byte 4w+k) -> bytes a..a+3 in order

    function from_lanes (v : std_logic_vector(31 downto 0); lo : unsigned(1 downto 0))
        return std_logic_vector;

    -- the first n (0..7) bytes of a 7-byte vector, the others zero (keep_bytes)

    function first_bytes (v : std_logic_vector(55 downto 0); n : unsigned(3 downto 0))
        return std_logic_vector;

    -- smallest r with 2**r >= n

    function clog2 (n : positive) return natural;

    -- a time of ns nanoseconds in cycles of a clk_hz clock, rounded up (never shorter)

    function ns_to_cycles (ns : natural; clk_hz : positive) return natural;

    -- the larger of a and b

    function max_nat (a : natural; b : natural) return natural;

    -- a < b for two unsigned values of the same even width, written as a compare of the upper
    -- halves and one of the lower halves (a(hi) < b(hi), or equal upper halves and
    -- a(lo) < b(lo)): two short compares side by side instead of one borrow chain through all
    -- the bits (without a carry chain, as in yosys' LUT mapping, a 32-bit chain is 11 LUT
    -- levels, the split form 7)

    function lt_split (a : unsigned; b : unsigned) return boolean;

    -- c + 1 for a counter of even width kept as two halves: the lower half counts, the upper
    -- half counts when lo_ones = '1', a registered flag that must be '1' exactly when the lower
    -- half is all ones (keep it with lo_ones_after_inc and clear it with the counter). The
    -- upper half's increment does not wait for the lower half's carry: each half is a short
    -- chain (in yosys' LUT mapping 5 levels for 16 bits instead of 11 for 32)

    function inc_split (c : unsigned; lo_ones : std_logic) return unsigned;

    -- the lo_ones flag of inc_split after an increment of c: '1' when the lower half of c + 1
    -- is all ones

    function lo_ones_after_inc (c : unsigned) return std_logic;

    -- read multiplexer in AND-OR form (not a chain of conditional assignments, so the synthesis
    -- tree stays balanced): v := v or word when addr is the word offset n

    procedure put (
        variable v : inout std_logic_vector(31 downto 0);
        addr       : in    std_logic_vector;
        n          : in    natural;
        word       : in    std_logic_vector(31 downto 0)
    );

    -- simulation-only check of an input the caller holds while the block works on it (called
    -- at a clock edge from a process behind translate_off): while busy is false the value is
    -- taken into held, while busy is true it must equal held, else a failure with msg

    procedure hold_check (
        variable held : inout std_logic_vector;
        busy          : in    boolean;
        value         : in    std_logic_vector;
        msg           : in    string
    );

end package canopen_util_pkg;

package body canopen_util_pkg is

    function at (val : std_logic_vector; hi : natural; lo : natural) return std_logic_vector is

        variable w : std_logic_vector(31 downto 0);

    begin

        w               := (others => '0');
        w(hi downto lo) := val;
        return w;

    end function at;

    function at (val : std_logic; pos : natural) return std_logic_vector is

        variable w : std_logic_vector(31 downto 0);

    begin

        w      := (others => '0');
        w(pos) := val;
        return w;

    end function at;

    function sat_inc (c : unsigned) return unsigned is
    begin

        if c = (c'range => '1') then
            return c;
        end if;

        return c + 1;

    end function sat_inc;

    function sat_add (c : unsigned; n : natural) return unsigned is

        variable s    : unsigned(c'length downto 0);
        variable all1 : unsigned(c'length - 1 downto 0);

    begin

        s    := resize(c, c'length + 1) + n;
        all1 := (others => '1');

        if s(c'length) = '1' then
            return all1;
        end if;

        return s(c'length - 1 downto 0);

    end function sat_add;

    function or_reduce (v : std_logic_vector) return std_logic is

        variable r : std_logic;

    begin

        r := '0';

        for i in v'range loop

            r := r or v(i);

        end loop;

        return r;

    end function or_reduce;

    function bit_int (b : std_logic) return natural is
    begin

        if b = '1' then
            return 1;
        end if;

        return 0;

    end function bit_int;

    function is_off (addr : std_logic_vector; off : natural) return boolean is
    begin

        return addr = std_logic_vector(to_unsigned(off, addr'length));

    end function is_off;

    function keep_bytes (v : std_logic_vector(63 downto 0); dlc : std_logic_vector(3 downto 0))
        return std_logic_vector is

        variable r : std_logic_vector(63 downto 0);

    begin

        r := v;

        for j in 0 to 7 loop

            if dlc(3) = '0' and unsigned(dlc(2 downto 0)) <= j then
                r(8 * j + 7 downto 8 * j) := (others => '0');
            end if;

        end loop;

        return r;

    end function keep_bytes;

    function word_byte (v : std_logic_vector(31 downto 0); j : unsigned(1 downto 0))
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

    end function word_byte;

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

    function first_bytes (v : std_logic_vector(55 downto 0); n : unsigned(3 downto 0))
        return std_logic_vector is

        variable r : std_logic_vector(63 downto 0);

    begin

        r := keep_bytes(x"00" & v, std_logic_vector(n));
        return r(55 downto 0);

    end function first_bytes;

    function clog2 (n : positive) return natural is

        variable r : natural;

    begin

        r := 0;

        while 2 ** r < n loop

            r := r + 1;

        end loop;

        return r;

    end function clog2;

    function ns_to_cycles (ns : natural; clk_hz : positive) return natural is
    begin

        return (ns * ((clk_hz + 999) / 1000) + 999_999) / 1_000_000;

    end function ns_to_cycles;

    function max_nat (a : natural; b : natural) return natural is
    begin

        if a > b then
            return a;
        end if;

        return b;

    end function max_nat;

    function lt_split (a : unsigned; b : unsigned) return boolean is

        constant w_c : natural := a'length;
        constant h_c : natural := a'length / 2;

        variable av : unsigned(w_c - 1 downto 0);
        variable bv : unsigned(w_c - 1 downto 0);

    begin

        av := a;
        bv := b;

        return av(w_c - 1 downto h_c) < bv(w_c - 1 downto h_c)
               or (av(w_c - 1 downto h_c) = bv(w_c - 1 downto h_c)
                   and av(h_c - 1 downto 0) < bv(h_c - 1 downto 0));

    end function lt_split;

    function inc_split (c : unsigned; lo_ones : std_logic) return unsigned is

        constant w_c : natural := c'length;
        constant h_c : natural := c'length / 2;

        variable cv : unsigned(w_c - 1 downto 0);
        variable r  : unsigned(w_c - 1 downto 0);

    begin

        cv                    := c;
        r(h_c - 1 downto 0)   := cv(h_c - 1 downto 0) + 1;
        r(w_c - 1 downto h_c) := cv(w_c - 1 downto h_c);

        if lo_ones = '1' then
            r(w_c - 1 downto h_c) := cv(w_c - 1 downto h_c) + 1;
        end if;

        return r;

    end function inc_split;

    function lo_ones_after_inc (c : unsigned) return std_logic is

        constant h_c : natural := c'length / 2;

        variable cv : unsigned(c'length - 1 downto 0);
        variable hi : unsigned(h_c - 2 downto 0);

    begin

        -- the lower half is all ones but its bit 0 (a constant compare, no increment)
        cv := c;
        hi := cv(h_c - 1 downto 1);

        if hi = (hi'range => '1') and cv(0) = '0' then
            return '1';
        end if;

        return '0';

    end function lo_ones_after_inc;

    procedure put (
        variable v : inout std_logic_vector(31 downto 0);
        addr       : in    std_logic_vector;
        n          : in    natural;
        word       : in    std_logic_vector(31 downto 0)
    ) is

        variable m : std_logic_vector(31 downto 0);

    begin

        m := (others => '0');

        if is_off(addr, n) then
            m := (others => '1');
        end if;

        v := v or (word and m);

    end procedure put;

    procedure hold_check (
        variable held : inout std_logic_vector;
        busy          : in    boolean;
        value         : in    std_logic_vector;
        msg           : in    string
    ) is
    begin

        if busy then
            assert value = held
                report msg & " changed while it is held"
                severity failure;
        else
            held := value;
        end if;

    end procedure hold_check;

end package body canopen_util_pkg;
