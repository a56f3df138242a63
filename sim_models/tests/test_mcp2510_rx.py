"""MCP2510 model: reception, filters, rollover, overflow, pins, interrupts (DS21291 4, 7)."""

from __future__ import annotations

import can
import pytest

from sim_models.can_bus import CanBus, QueueNode
from sim_models.mcp2510 import Mcp2510
from sim_models.mcp2510 import regs as R
from sim_models.mcp2510.testing import configure, new_chip, read_rx, same_frame, std, write_id_group
from sim_models.sim_time import PS_PER_MS, Scheduler

BITRATE = 500_000
STD_ONLY = R.RXM_STD_ONLY << R.RXBNCTRL_RXM_SHIFT
EXT_ONLY = R.RXM_EXT_ONLY << R.RXBNCTRL_RXM_SHIFT
FILTERED = R.RXM_VALID_FILTERED << R.RXBNCTRL_RXM_SHIFT
ANY = R.RXM_ANY << R.RXBNCTRL_RXM_SHIFT


def ext(can_id: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=can_id, is_extended_id=True, dlc=len(data), data=data)


class Rig:
    """A chip and a peer node on a 500 kbit/s bus."""

    def __init__(self) -> None:
        self.sched = Scheduler()
        self.bus = CanBus(self.sched, BITRATE)
        self.chip = self.bus.attach(new_chip(self.sched))
        self.peer = self.bus.attach(QueueNode("peer", BITRATE))

    def send(self, *msgs: can.Message) -> None:
        self.peer.send(*msgs)
        self.sched.run_until(self.sched.now_ps + len(msgs) * PS_PER_MS // 2)

    def intf(self) -> int:
        return self.chip.peek(R.CANINTF)

    def clear(self, flags: int) -> None:
        self.chip.spi_bit_modify(R.CANINTF, flags, 0)


@pytest.fixture
def rig() -> Rig:
    return Rig()


def setup_filters(
    rig: Rig,
    rxb0: int,
    rxb1: int,
    masks: tuple[tuple[int, bool], tuple[int, bool]],
    filters: dict[int, tuple[int, bool]],
    **kw: int,
) -> None:
    chip = rig.chip
    configure(chip, BITRATE, rxb0ctrl=rxb0, rxb1ctrl=rxb1, opmode=None, **kw)
    write_id_group(chip, R.RXM0SIDH, *masks[0])
    write_id_group(chip, R.RXM1SIDH, *masks[1])
    bases = (R.RXF0SIDH, R.RXF1SIDH, R.RXF2SIDH, R.RXF3SIDH, R.RXF4SIDH, R.RXF5SIDH)
    for n, (fid, fext) in filters.items():
        write_id_group(chip, bases[n], fid, fext)
    chip.spi_bit_modify(R.CANCTRL, R.CANCTRL_REQOP_MASK, R.OPMODE_NORMAL << 5)


# ------------------------------------------------------------------------------ filters
def test_standard_filters_and_filhit(rig: Rig) -> None:
    setup_filters(
        rig,
        FILTERED,
        FILTERED,
        ((0x7FF, False), (0x7FF, False)),
        {0: (0x123, False), 1: (0x456, False), 2: (0x700, False), 5: (0x701, False)},
    )
    rig.send(std(0x456, b"\x01\x02"))
    ctrl, msg = read_rx(rig.chip, 0)
    assert ctrl & R.RXB0CTRL_FILHIT0 == 1 and same_frame(msg, std(0x456, b"\x01\x02"))
    rig.clear(R.CANINTF_RX0IF)
    rig.send(std(0x123))
    assert read_rx(rig.chip, 0)[0] & R.RXB0CTRL_FILHIT0 == 0
    rig.send(std(0x701))
    ctrl, msg = read_rx(rig.chip, 1)
    assert ctrl & R.RXB1CTRL_FILHIT_MASK == 5 and msg.arbitration_id == 0x701
    rig.clear(R.CANINTF_RX0IF | R.CANINTF_RX1IF)
    rig.send(std(0x124), std(0x702))  # match no filter
    assert rig.intf() == 0 and rig.chip.overflow_count == 0


def test_mask_bits_zero_accept_anything(rig: Rig) -> None:
    setup_filters(
        rig,
        FILTERED,
        FILTERED,
        ((0x700, False), (0x7FF, False)),
        {0: (0x1FF, False), 1: (0x7FF, True)},
    )
    rig.send(std(0x1AB))
    assert read_rx(rig.chip, 0)[1].arbitration_id == 0x1AB
    rig.clear(R.CANINTF_RX0IF)
    rig.send(std(0x2AB))
    assert rig.intf() == 0


def test_extended_filters(rig: Rig) -> None:
    setup_filters(
        rig,
        FILTERED,
        FILTERED,
        ((0x7FF, False), (0x1FFFFFFF, True)),
        {2: (0x1ABCDE00, True), 3: (0x0ABCDE01, True)},
    )
    rig.send(ext(0x0ABCDE01, b"\xff"))
    ctrl, msg = read_rx(rig.chip, 1)
    assert ctrl & R.RXB1CTRL_FILHIT_MASK == 3
    assert same_frame(msg, ext(0x0ABCDE01, b"\xff"))
    rig.clear(R.CANINTF_RX1IF)
    rig.send(ext(0x0ABCDE02))  # one EID bit differs
    assert rig.intf() == 0
    rig.send(std(0x1ABCDE00 >> 18))  # same SID as filter 2, but a standard frame
    assert rig.intf() == 0


def test_exide_must_match_the_frame_type_even_with_mask_zero(rig: Rig) -> None:
    setup_filters(
        rig,
        FILTERED,
        FILTERED,
        ((0, False), (0, False)),
        {0: (0, True), 1: (0, True), 2: (0, True), 3: (0, True), 4: (0, True), 5: (0, True)},
    )
    rig.send(std(0x555))
    assert rig.intf() == 0
    rig.send(ext(0x555))
    assert rig.intf() == R.CANINTF_RX0IF


@pytest.mark.parametrize(
    ("rxm", "std_ok", "ext_ok"),
    [(FILTERED, True, True), (STD_ONLY, True, False), (EXT_ONLY, False, True), (ANY, True, True)],
)
def test_rxm_modes(rig: Rig, rxm: int, std_ok: bool, ext_ok: bool) -> None:
    # mask 0 with one standard and one extended filter: only RXM decides
    setup_filters(
        rig,
        rxm,
        FILTERED,
        ((0, False), (0x7FF, False)),
        {0: (0, False), 1: (0, True), 2: (0x7FF, False)},
    )
    rig.send(std(0x10))
    assert bool(rig.intf() & R.CANINTF_RX0IF) == std_ok
    rig.clear(R.CANINTF_RX0IF)
    rig.send(ext(0x10))
    assert bool(rig.intf() & R.CANINTF_RX0IF) == ext_ok
    if ext_ok and rxm != ANY:
        assert read_rx(rig.chip, 0)[0] & R.RXB0CTRL_FILHIT0 == 1


# ------------------------------------------------------------------------------ rollover
def test_bukt_rollover_then_overflow(rig: Rig) -> None:
    configure(
        rig.chip,
        BITRATE,
        rxb0ctrl=ANY | R.RXB0CTRL_BUKT,
        rxb1ctrl=FILTERED,
        caninte=R.CANINTE_ERRIE,
    )
    rig.send(std(0x1), std(0x2), std(0x3))
    assert read_rx(rig.chip, 0)[1].arbitration_id == 0x1
    ctrl1, msg1 = read_rx(rig.chip, 1)
    assert msg1.arbitration_id == 0x2
    assert ctrl1 & R.RXB1CTRL_FILHIT_MASK == 0  # rolled over from RXB0 (RXF0 code)
    assert rig.chip.peek(R.EFLG) == R.EFLG_RX1OVR
    assert rig.intf() & R.CANINTF_ERRIF and rig.chip.int_n == 0
    assert rig.chip.overflow_count == 1
    assert rig.chip.overflows[0][1] == 1 and rig.chip.overflows[0][2].arbitration_id == 0x3


def test_no_rollover_means_rxb0_overflow(rig: Rig) -> None:
    configure(rig.chip, BITRATE, rxb0ctrl=ANY, rxb1ctrl=ANY)
    rig.send(std(0x1), std(0x2))
    assert rig.chip.peek(R.EFLG) == R.EFLG_RX0OVR
    assert rig.intf() == R.CANINTF_RX0IF | R.CANINTF_ERRIF
    assert read_rx(rig.chip, 0)[1].arbitration_id == 0x1  # the old frame is kept
    # freeing the buffer lets the next frame in; the host clears RX0OVR
    rig.clear(R.CANINTF_RX0IF | R.CANINTF_ERRIF)
    rig.chip.spi_bit_modify(R.EFLG, R.EFLG_RX0OVR, 0)
    rig.send(std(0x3))
    assert read_rx(rig.chip, 0)[1].arbitration_id == 0x3
    assert rig.chip.peek(R.EFLG) == 0


def test_remote_frames_set_rxrtr(rig: Rig) -> None:
    configure(rig.chip, BITRATE)
    rig.send(can.Message(arbitration_id=0x701, is_extended_id=False, is_remote_frame=True, dlc=1))
    raw = rig.chip.spi_read(R.RXB0CTRL, 6)
    assert raw[0] & R.RXBNCTRL_RXRTR
    assert raw[2] & R.RXBNSIDL_SRR and not raw[2] & R.RXBNSIDL_IDE
    assert raw[5] == 1
    rig.clear(R.CANINTF_RX0IF)
    rig.send(can.Message(arbitration_id=0x3, is_extended_id=True, is_remote_frame=True, dlc=0))
    raw = rig.chip.spi_read(R.RXB0CTRL, 6)
    assert raw[0] & R.RXBNCTRL_RXRTR and raw[2] & R.RXBNSIDL_IDE
    assert raw[5] == R.RXBNDLC_RTR


# ------------------------------------------------------------------------------ pins
def test_rxbf_pins_in_interrupt_mode(rig: Rig) -> None:
    changes: list[tuple[int, int, int]] = []
    chip = rig.chip
    chip.on_pins_changed = lambda: changes.append((chip.int_n, chip.rx0bf_n, chip.rx1bf_n))
    bfp = R.BFPCTRL_B0BFE | R.BFPCTRL_B0BFM | R.BFPCTRL_B1BFE | R.BFPCTRL_B1BFM
    assert bfp == 0x0F  # the thesis' setting
    configure(chip, BITRATE, rxb0ctrl=ANY | R.RXB0CTRL_BUKT, bfpctrl=bfp)
    assert (chip.rx0bf_n, chip.rx1bf_n, chip.int_n) == (1, 1, 1)
    rig.send(std(0x1))
    assert (chip.rx0bf_n, chip.rx1bf_n) == (0, 1)
    rig.send(std(0x2))
    assert (chip.rx0bf_n, chip.rx1bf_n) == (0, 0)
    assert chip.int_n == 1  # RXnIE not enabled: INT stays high
    rig.clear(R.CANINTF_RX0IF)
    assert (chip.rx0bf_n, chip.rx1bf_n) == (1, 0)
    assert changes == [(1, 0, 1), (1, 0, 0), (1, 1, 0)]


def test_rxbf_pins_as_digital_outputs_or_disabled(chip: Mcp2510) -> None:
    assert (chip.rx0bf_n, chip.rx1bf_n) == (1, 1)  # disabled: high impedance (pulled up)
    chip.spi_write(R.BFPCTRL, [R.BFPCTRL_B0BFE | R.BFPCTRL_B1BFE | R.BFPCTRL_B1BFS])
    assert (chip.rx0bf_n, chip.rx1bf_n) == (0, 1)
    chip.spi_bit_modify(R.BFPCTRL, R.BFPCTRL_B0BFS | R.BFPCTRL_B1BFS, R.BFPCTRL_B0BFS)
    assert (chip.rx0bf_n, chip.rx1bf_n) == (1, 0)
    chip.poke(R.CANINTF, R.CANINTF_RX0IF)  # no effect in digital-output mode
    assert chip.rx0bf_n == 1


@pytest.fixture
def chip() -> Mcp2510:
    return new_chip(Scheduler())


# ------------------------------------------------------------------------------ INT / ICOD
@pytest.mark.parametrize(
    ("inte", "flags", "icod", "int_n"),
    [
        (0xFF, 0, R.ICOD_NONE, 1),
        (0xFF, R.CANINTF_ERRIF | R.CANINTF_RX0IF, R.ICOD_ERROR, 0),
        (0xFF, R.CANINTF_WAKIF | R.CANINTF_TX2IF, R.ICOD_WAKE, 0),
        (0xFF, R.CANINTF_TX0IF | R.CANINTF_TX1IF, R.ICOD_TXB0, 0),
        (0xFF, R.CANINTF_TX1IF | R.CANINTF_RX1IF, R.ICOD_TXB1, 0),
        (0xFF, R.CANINTF_TX2IF | R.CANINTF_RX0IF, R.ICOD_TXB2, 0),
        (0xFF, R.CANINTF_RX0IF | R.CANINTF_RX1IF, R.ICOD_RXB0, 0),
        (0xFF, R.CANINTF_RX1IF | R.CANINTF_MERRF, R.ICOD_RXB1, 0),
        (0xFF, R.CANINTF_MERRF, R.ICOD_NONE, 0),  # MERRF drives INT but has no ICOD
        (R.CANINTE_RX1IE, R.CANINTF_ERRIF | R.CANINTF_RX1IF, R.ICOD_RXB1, 0),
        (R.CANINTE_TX0IE, R.CANINTF_ERRIF | R.CANINTF_RX1IF, R.ICOD_NONE, 1),
    ],
)
def test_icod_priority_and_int_pin(
    chip: Mcp2510, inte: int, flags: int, icod: int, int_n: int
) -> None:
    chip.spi_write(R.CANINTE, [inte])
    chip.spi_bit_modify(R.CANINTF, 0xFF, flags)  # the host may set flags itself
    assert chip.spi_read(R.CANSTAT)[0] == 0x80 | (icod << 1)
    assert chip.int_n == int_n
