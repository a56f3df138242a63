"""Drive the byte interface of ``mcp2510_spi_master`` from Python, one SPI transaction per call.

The engine only shifts bytes; benches that talk to a device through it (for example the
MCP2510 model on the pins) build the instruction bytes themselves and hand them to
:func:`stream_transaction`, which streams them gaplessly (valid/ready, ``tx_last_i`` on the
final byte) and collects what the engine presents on ``rx_valid_o``/``rx_data_o``.

The DUT handle must have the engine's ports: ``clk_i``, ``tx_valid_i``, ``tx_data_i``,
``tx_last_i``, ``tx_ready_o``, ``rx_valid_o``, ``rx_data_o``, ``done_o``.
"""

from __future__ import annotations

from collections.abc import Sequence

from cocotb.handle import SimHandleBase
from cocotb.triggers import RisingEdge

#: what :func:`miso_bytes` puts where the slave left MISO floating (a pulled-up line)
HIGH_Z_BYTE = 0xFF


def _rx_byte(value) -> int | None:
    """``rx_data_o`` as an int, None when any bit is not 0/1 (MISO was high impedance)."""
    return int(value) if value.is_resolvable else None


async def stream_transaction(dut: SimHandleBase, data: bytes | Sequence[int]) -> list[int | None]:
    """Stream ``data`` as one SPI transaction and return the byte received during each one.

    The bytes are offered back to back (``tx_valid_i`` stays high), so the engine shifts them
    without a gap; the last one carries ``tx_last_i``. The call returns on the ``done_o`` strobe
    (CS high). Element k of the result is what the engine received while byte k was shifted
    out, ``None`` where the slave did not drive MISO (high impedance) during that byte.
    Handshake values are sampled on the rising clock edge, as the engine sees them.
    """
    data = bytes(data)
    if not data:
        raise ValueError("an SPI transaction needs at least one byte")
    clk = dut.clk_i
    received: list[int | None] = []
    idx = 0

    def offer(i: int) -> None:
        if i < len(data):
            dut.tx_valid_i.value = 1
            dut.tx_data_i.value = data[i]
            dut.tx_last_i.value = int(i == len(data) - 1)
        else:
            dut.tx_valid_i.value = 0
            dut.tx_last_i.value = 0

    dut.tx_end_i.value = 0
    offer(0)
    while True:
        await RisingEdge(clk)
        if dut.rx_valid_o.value == 1:
            received.append(_rx_byte(dut.rx_data_o.value))
        if dut.done_o.value == 1:
            break
        if idx < len(data) and dut.tx_ready_o.value == 1:
            idx += 1
            offer(idx)
    if idx != len(data) or len(received) != len(data):
        raise AssertionError(
            f"engine took {idx} and returned {len(received)} of {len(data)} bytes before done_o"
        )
    return received


def miso_bytes(received: Sequence[int | None]) -> bytes:
    """The received bytes with high impedance read as :data:`HIGH_Z_BYTE` (pulled-up MISO)."""
    return bytes(HIGH_Z_BYTE if b is None else b for b in received)
