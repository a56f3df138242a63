# =================================================================================================
# Title    : ep3c80_reference_pins.tcl
# Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
# SPDX-License-Identifier: Apache-2.0
# =================================================================================================
# Pin locations and I/O standards of canopen_master_top as a stand-alone top on an EP3C80F484C8.
#
#   !!! PLACEHOLDER LOCATIONS: they are NOT the pins of any board this project has. !!!
#   Replace every set_location_assignment below with your board's pins before you program a
#   device. They are valid user-I/O ball names of the F484 package, chosen so that the project
#   is meant to fit: the balls that the Terasic DE0 board (EP3C16F484, same package) uses for
#   its 50 MHz clock (G21), a push button (H2) and the first 11 lines of its GPIO 0 header
#   (rows AA/AB). No Quartus run has checked them against the EP3C80F484 pin-out on this
#   project's machines (no Quartus here).
#
# Quartus Tcl (quartus_sh), with the project open (bus bits in braces: [0] is Tcl command syntax). Sourced by scripts/quartus_project.tcl and by
# the FuseSoC `quartus` target (canopen_master.core). The Avalon-MM, IRQ and debug ports of the
# stand-alone top have no location here: Quartus places them (that project is a compile and
# timing check of the core; in a Platform Designer system they are internal signals).
# In a Platform Designer system the exported pins are named <export>_<role> (docs/integration.md).
# =================================================================================================

# -------------------------------------------------------------------------------- PLACEHOLDERS
set_location_assignment PIN_G21  -to clk_i
set_location_assignment PIN_H2   -to rst_n_i
set_location_assignment PIN_AB16 -to spi_cs_n_o
set_location_assignment PIN_AA16 -to spi_sck_o
set_location_assignment PIN_AA15 -to spi_mosi_o
set_location_assignment PIN_AB15 -to spi_miso_i
set_location_assignment PIN_AA14 -to mcp_int_n_i
set_location_assignment PIN_AB14 -to mcp_rx0bf_n_i
set_location_assignment PIN_AB13 -to mcp_rx1bf_n_i
set_location_assignment PIN_AA13 -to {mcp_txrts_n_o[0]}
set_location_assignment PIN_AB10 -to {mcp_txrts_n_o[1]}
set_location_assignment PIN_AA10 -to {mcp_txrts_n_o[2]}
set_location_assignment PIN_AB8  -to mcp_reset_n_o

# ------------------------------------------------------------------------------- I/O standards
# 3.3 V LVTTL towards the MCP2510; a 5 V MCP2510 needs level shifting on SO, INT#, RX0BF#, RX1BF#
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to clk_i
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to rst_n_i
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to spi_cs_n_o
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to spi_sck_o
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to spi_mosi_o
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to spi_miso_i
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to mcp_int_n_i
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to mcp_rx0bf_n_i
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to mcp_rx1bf_n_i
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to {mcp_txrts_n_o[0]}
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to {mcp_txrts_n_o[1]}
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to {mcp_txrts_n_o[2]}
set_instance_assignment -name IO_STANDARD "3.3-V LVTTL" -to mcp_reset_n_o

# SO is high impedance while the MCP2510 does not drive it (CS high, its own reset and start-up):
# a pull-up makes a read of an absent or resetting chip return FFh, a defined value (the FPGA's
# weak pull-up here; an external 10 kOhm pull-up does the same)
set_instance_assignment -name WEAK_PULL_UP_RESISTOR ON -to spi_miso_i
