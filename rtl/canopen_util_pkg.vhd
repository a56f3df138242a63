-- =================================================================================================
-- Title    : canopen_util_pkg
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   Small helpers shared by the blocks that own host-visible registers.
-- Purpose:
--   One definition of the register-word packing used by every read mux (canopen_host_regs,
--   canopen_pdo_engine) and of the saturating event counter (error and statistics counters
--   stop at all ones instead of wrapping, so a host never sees a small count after a flood).
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

end package body canopen_util_pkg;
