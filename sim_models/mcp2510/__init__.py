"""Behavioural model of the Microchip MCP2510 stand-alone CAN controller (not the MCP2515).

* :mod:`sim_models.mcp2510.regs`: opcodes, register addresses, bits, reset values.
* :mod:`sim_models.mcp2510.chip`: :class:`Mcp2510` (SPI byte interface, CAN node, pins) and
  :class:`Mcp2510Error`.
* :mod:`sim_models.mcp2510.bittiming`: CNF1..CNF3 decoding and checks.
* :mod:`sim_models.mcp2510.filters`: identifier packing and acceptance filtering.

See ``docs/mcp2510_model.md``.
"""

from sim_models.mcp2510 import regs
from sim_models.mcp2510.bittiming import BitTiming, decode_cnf, encode_cnf
from sim_models.mcp2510.chip import MODE_NAMES, Mcp2510, Mcp2510Error

__all__ = [
    "BitTiming",
    "MODE_NAMES",
    "Mcp2510",
    "Mcp2510Error",
    "decode_cnf",
    "encode_cnf",
    "regs",
]
