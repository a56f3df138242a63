# Compile order of the canopen_master VHDL library (VHDL-93; it also analyses as VHDL-2008, the
# standard of the simulations), read by every flow:
# tb/tblib/runner.py (simulation), scripts/synth.py (ghdl --synth + yosys), scripts/lint.sh.
# One file per line, relative to this directory; packages first. '#' starts a comment.
mcp2510_pkg.vhd
canopen_master_pkg.vhd
canopen_pkg.vhd
canopen_regs_pkg.vhd
canopen_util_pkg.vhd
canopen_sdp_ram.vhd
canopen_counter_bank.vhd
canopen_fifo.vhd
canopen_sdo_channels.vhd
canopen_autoconfig.vhd
canopen_pdo_engine.vhd
omni_feasibility.vhd
omni_node_table.vhd
omni_engine.vhd
canopen_node_monitor.vhd
mcp2510_spi_master.vhd
mcp2510_instr.vhd
mcp2510_ctrl.vhd
canopen_sync_timebase.vhd
canopen_fault_supervisor.vhd
canopen_tx_path.vhd
canopen_master_fsm.vhd
canopen_host_regs.vhd
canopen_master_core.vhd
canopen_master_top.vhd
