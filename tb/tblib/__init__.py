"""Shared bench helpers: runner (GHDL build/run from pytest), clock/reset, SPI pin bridge."""
