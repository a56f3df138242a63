"""cocotb benches of the canopen_master RTL (one file per entity) and their shared helpers."""
