# =================================================================================================
# Title    : nios2_canopen_qsys.tcl
# Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
# SPDX-License-Identifier: Apache-2.0
# =================================================================================================
# Platform Designer (Qsys) reference system: Nios II/e + 32 KiB on-chip RAM + JTAG UART + the
# CANopen master, one 50 MHz clock, on the Cyclone III EP3C80F484C8. A qsys-script; from the
# repository root (ip/ must be on the IP search path so that canopen_master is found):
#
#   qsys-script --script=ip/reference_system/nios2_canopen_qsys.tcl --search-path="ip,$"
#   qsys-generate nios2_canopen.qsys --synthesis=VHDL
#
# It writes nios2_canopen.qsys in the current directory; open it in Platform Designer to look
# at it or change it. Written against the 13.1 Qsys API (the last Quartus II with Cyclone III;
# Nios II "Classic" component altera_nios2_qsys, interface names of that release). NOT run on
# this project's machines (no Quartus there): tb/test_integration_kit.py runs it in tclsh with
# stub commands and checks every interface name of the CANopen core against
# ip/canopen_master_hw.tcl and the connections below.
#
# Address map (data master, byte addresses):
#   0x0000_0000  onchip_ram.s1               32 KiB, reset and exception vectors
#   0x0001_0000  canopen.s0                  1 KiB (256 registers, register n at 4 * n)
#   0x0001_0800  cpu.jtag_debug_module       2 KiB
#   0x0001_1000  jtag_uart.avalon_jtag_slave 8 bytes
# IRQs: canopen.irq = 0, jtag_uart.irq = 1.
# Exported: clk (clk_0.clk_in), reset (clk_0.clk_in_reset, active low: reset_reset_n) and
# mcp2510 (the core's MCP2510 pins: mcp2510_spi_cs_n, mcp2510_spi_sck, ...). The debug conduit
# of the core stays unconnected.
# =================================================================================================

package require -exact qsys 13.1

set_project_property DEVICE_FAMILY "Cyclone III"
set_project_property DEVICE        EP3C80F484C8

# ------------------------------------------------------------------------------------ instances
add_instance clk_0 clock_source
set_instance_parameter_value clk_0 clockFrequency        50000000
set_instance_parameter_value clk_0 clockFrequencyKnown   true
set_instance_parameter_value clk_0 resetSynchronousEdges NONE

# Nios II/e ("Tiny"), vectors in the on-chip RAM
add_instance cpu altera_nios2_qsys
set_instance_parameter_value cpu impl            Tiny
set_instance_parameter_value cpu resetSlave      onchip_ram.s1
set_instance_parameter_value cpu resetOffset     0
set_instance_parameter_value cpu exceptionSlave  onchip_ram.s1
set_instance_parameter_value cpu exceptionOffset 32

add_instance onchip_ram altera_avalon_onchip_memory2
set_instance_parameter_value onchip_ram dataWidth  32
set_instance_parameter_value onchip_ram memorySize 32768
set_instance_parameter_value onchip_ram writable   1

add_instance jtag_uart altera_avalon_jtag_uart

# the CANopen master (ip/canopen_master_hw.tcl); CLK_FREQ_HZ follows clk_0 (SYSTEM_INFO)
add_instance canopen canopen_master 1.0
set_instance_parameter_value canopen SPI_SCLK_HZ     5000000
set_instance_parameter_value canopen OSC_FREQ_HZ     16000000
set_instance_parameter_value canopen CAN_BITRATE_BPS 1000000

# --------------------------------------------------------------------------- clocks and resets
foreach sink {cpu.clk onchip_ram.clk1 jtag_uart.clk canopen.clock} {
    add_connection clk_0.clk $sink
}
foreach sink {cpu.reset_n onchip_ram.reset1 jtag_uart.reset canopen.reset} {
    add_connection clk_0.clk_reset $sink
    add_connection cpu.jtag_debug_module_reset $sink
}

# ------------------------------------------------------------------------------- address map
add_connection cpu.instruction_master onchip_ram.s1
set_connection_parameter_value cpu.instruction_master/onchip_ram.s1 baseAddress 0x00000000
add_connection cpu.instruction_master cpu.jtag_debug_module
set_connection_parameter_value cpu.instruction_master/cpu.jtag_debug_module baseAddress 0x00010800

add_connection cpu.data_master onchip_ram.s1
set_connection_parameter_value cpu.data_master/onchip_ram.s1 baseAddress 0x00000000
add_connection cpu.data_master canopen.s0
set_connection_parameter_value cpu.data_master/canopen.s0 baseAddress 0x00010000
add_connection cpu.data_master cpu.jtag_debug_module
set_connection_parameter_value cpu.data_master/cpu.jtag_debug_module baseAddress 0x00010800
add_connection cpu.data_master jtag_uart.avalon_jtag_slave
set_connection_parameter_value cpu.data_master/jtag_uart.avalon_jtag_slave baseAddress 0x00011000

# ---------------------------------------------------------------------------------- interrupts
add_connection cpu.d_irq canopen.irq
set_connection_parameter_value cpu.d_irq/canopen.irq irqNumber 0
add_connection cpu.d_irq jtag_uart.irq
set_connection_parameter_value cpu.d_irq/jtag_uart.irq irqNumber 1

# ------------------------------------------------------------------------------------ exports
add_interface clk clock sink
set_interface_property clk EXPORT_OF clk_0.clk_in
add_interface reset reset sink
set_interface_property reset EXPORT_OF clk_0.clk_in_reset
add_interface mcp2510 conduit end
set_interface_property mcp2510 EXPORT_OF canopen.mcp2510

save_system nios2_canopen.qsys
