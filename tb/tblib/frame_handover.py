"""The FSM's St5 hand-over of one received frame to a protocol block, as a bench would drive it.

Every protocol block behind the master FSM (SDO client, PDO engine, ...) takes a received frame
on ``rx_id_i``/``rx_dlc_i``/``rx_data_i`` (and ``rx_rtr_i`` where it has one) with a one-cycle
``rx_valid_i`` strobe and answers with ``rx_done_o`` a bounded number of cycles later, with
``rx_reply_o``/``rx_unexpected_o`` valid in that cycle. Block benches use :func:`hand_over_frame`
so the hand-over protocol is driven, and its latency bound checked, the same way everywhere.
"""

from __future__ import annotations

import can
from cocotb.triggers import ReadOnly, RisingEdge

from tb.tblib.model_clock import sim_time_ps


async def hand_over_frame(dut, msg: can.Message, max_latency: int, *,
                          has_rtr: bool = True) -> tuple[int, int]:
    """Drive ``msg`` with ``rx_valid_i`` (call at a falling edge) and wait for ``rx_done_o``.

    Returns ``(t_sample_ps, latency)``: the time of the clock edge that sampled ``rx_valid_i``
    and the number of edges from that one to the one that samples ``rx_done_o`` (1 = the same
    edge). Returns in the ReadOnly phase of that edge, so the caller reads the block's outputs
    as the FSM would. Fails when ``rx_done_o`` does not come within ``max_latency`` edges.
    """
    dut.rx_id_i.value = msg.arbitration_id
    if has_rtr:
        dut.rx_rtr_i.value = int(msg.is_remote_frame)
    dut.rx_dlc_i.value = msg.dlc
    dut.rx_data_i.value = int.from_bytes(bytes(msg.data).ljust(8, b"\0"), "little")
    dut.rx_valid_i.value = 1
    await RisingEdge(dut.clk_i)  # rx_valid_i sampled here
    t_sample = sim_time_ps()
    dut.rx_valid_i.value = 0
    await ReadOnly()
    latency = 1  # rx_done_o seen now is sampled at the next edge
    while dut.rx_done_o.value != 1:
        assert latency < max_latency, f"rx_done_o not within {max_latency} cycles of rx_valid_i"
        await RisingEdge(dut.clk_i)
        await ReadOnly()
        latency += 1
    return t_sample, latency
