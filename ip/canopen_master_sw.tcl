# =================================================================================================
# Title    : canopen_master_sw.tcl
# Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
# SPDX-License-Identifier: Apache-2.0
# =================================================================================================
# Nios II Software Build Tools (SBT) driver package of the canopen_master component
# (ip/canopen_master_hw.tcl). The BSP tools find it through --librarian-path "<repo>/ip,$" (or in
# an ip/ folder under the Quartus project) and copy the C driver of sw/ into every HAL BSP whose
# system contains the core (docs/integration.md, section 3).
#
# The driver is the portable C HAL of sw/ (docs/c_driver.md): it reaches the registers only
# through the read/write callbacks the application gives it (on Nios II: IORD/IOWR on
# <INSTANCE>_BASE from system.h), so it needs no alt_sys_init() entry (auto_initialize false).
#
# Paths are relative to this file (SBT rule) and point into ../sw, so the repository is not
# duplicated. The SBT copies each file to <BSP>/<bsp_subdirectory>/<path as written>; with
# bsp_subdirectory drivers/canopen_master/ip the "../" lands in drivers/canopen_master/sw/ inside
# the BSP. Written from Intel's SBT command reference; checked by tb/test_integration_kit.py
# against the files and the _hw.tcl; NOT yet run by nios2-bsp on this project's machines.
# =================================================================================================

create_driver canopen_master_driver

# the component NAME in ip/canopen_master_hw.tcl
set_sw_property hw_class_name canopen_master

# driver version = component VERSION; it works with that register map and newer (1.x)
set_sw_property version 1.0
set_sw_property min_compatible_hw_version 1.0

# the application calls the driver's init with its register callbacks itself
set_sw_property auto_initialize false

set_sw_property bsp_subdirectory drivers/canopen_master/ip

# C sources and headers (sw/ of the repository)
add_sw_property c_source ../sw/canopen_master.c
add_sw_property include_source ../sw/canopen_master.h
add_sw_property include_source ../sw/include/canopen_master_regs.h

# so that applications and the driver find "canopen_master.h" and "canopen_master_regs.h"
add_sw_property include_directory ../sw
add_sw_property include_directory ../sw/include

add_sw_property supported_bsp_type HAL
