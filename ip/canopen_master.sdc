# =================================================================================================
# Title    : canopen_master.sdc
# Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
# SPDX-License-Identifier: Apache-2.0
# =================================================================================================
# Timing exceptions of canopen_master_top inside a Platform Designer system (QUARTUS_SYNTH
# fileset of ip/canopen_master_hw.tcl; Quartus reads it with the generated .qip). Only the
# clock-domain crossings of the core itself: clocks, I/O delays of the exported MCP2510 pins
# (<export>_spi_miso ...) and board timing belong to the project's own SDC.
#
# The patterns name registers by their RTL names and do not depend on the system, the instance
# or the export name: "*canopen_master_top:*|" matches the core at any depth and any instance
# name (e.g. "soc:u0|canopen_master_top:canopen_master_0|"). Checked against rtl/ by
# tb/test_integration_kit.py (entity names, instance chain, signal names and widths); not yet
# read by Quartus on this project's machines.
# =================================================================================================

# Reset synchroniser (canopen_master_top, rst_sync_proc): rst_n_i asserts the two flops
# asynchronously; their release is synchronised, and every other register is reset from
# rst_sync[1] (timed normally: recovery/removal). The asynchronous clear of the two flops
# themselves is not a timing path.
set_false_path -to [get_pins -compatibility_mode {*canopen_master_top:*|rst_sync[*]|clrn}]

# MCP2510 INT#, RX0BF#, RX1BF# (mcp2510_ctrl, sync_proc): asynchronous to clk_i, each through a
# 2-flop synchroniser; the path from the pin into the first flop is not a timing path.
set_false_path -to [get_registers {*canopen_master_top:*|mcp2510_ctrl:*|int_sync[0]}]
set_false_path -to [get_registers {*canopen_master_top:*|mcp2510_ctrl:*|rx0_sync[0]}]
set_false_path -to [get_registers {*canopen_master_top:*|mcp2510_ctrl:*|rx1_sync[0]}]
