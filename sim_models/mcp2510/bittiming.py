"""Decode and check the MCP2510 bit-timing registers CNF1..CNF3 (DS21291 section 5).

Nominal bit time in time quanta (TQ)::

    TQ        = 2 * (BRP + 1) / F_OSC
    bit time  = SyncSeg (1) + PropSeg (PRSEG + 1) + PS1 (PHSEG1 + 1) + PS2
    PS2       = PHSEG2 + 1                 when CNF2.BTLMODE = 1
              = max(PS1, IPT = 2 TQ)       when CNF2.BTLMODE = 0
    SJW       = CNF1.SJW + 1
    sample point = end of PS1

Rules checked (section 5 "Bit timing" / "Programming time segments"):

* PropSeg + PS1 >= PS2
* PS2 > SJW
* PS2 >= IPT (2 TQ)
* 8 TQ <= bit time <= 25 TQ
"""

from __future__ import annotations

from dataclasses import dataclass

from sim_models.mcp2510 import regs as R


@dataclass(frozen=True)
class BitTiming:
    """Bit timing derived from CNF1..CNF3 and the oscillator frequency."""

    osc_hz: int
    brp: int
    sjw_tq: int
    prop_tq: int
    ps1_tq: int
    ps2_tq: int
    btlmode: bool
    sam: bool

    @property
    def tq_per_bit(self) -> int:
        return 1 + self.prop_tq + self.ps1_tq + self.ps2_tq

    @property
    def tq_ps(self) -> float:
        """Length of one time quantum in ps."""
        return 2 * (self.brp + 1) * 1e12 / self.osc_hz

    @property
    def bitrate_exact(self) -> float:
        return self.osc_hz / (2 * (self.brp + 1) * self.tq_per_bit)

    @property
    def bitrate_bps(self) -> int:
        return round(self.bitrate_exact)

    @property
    def bit_time_ps(self) -> int:
        return round(self.tq_ps * self.tq_per_bit)

    @property
    def sample_point(self) -> float:
        """Sample point as a fraction of the bit time (end of PS1)."""
        return (1 + self.prop_tq + self.ps1_tq) / self.tq_per_bit

    def problems(self) -> list[str]:
        """Every rule of DS21291 section 5 that this setting breaks (empty when valid)."""
        out: list[str] = []
        if self.prop_tq + self.ps1_tq < self.ps2_tq:
            out.append(f"PropSeg + PS1 = {self.prop_tq + self.ps1_tq} TQ < PS2 = {self.ps2_tq} TQ")
        if self.ps2_tq <= self.sjw_tq:
            out.append(f"PS2 = {self.ps2_tq} TQ must be > SJW = {self.sjw_tq} TQ")
        if self.ps2_tq < R.IPT_TQ:
            out.append(f"PS2 = {self.ps2_tq} TQ < information processing time {R.IPT_TQ} TQ")
        if not R.BIT_TQ_MIN <= self.tq_per_bit <= R.BIT_TQ_MAX:
            out.append(f"bit time {self.tq_per_bit} TQ outside {R.BIT_TQ_MIN}..{R.BIT_TQ_MAX} TQ")
        return out

    def describe(self) -> str:
        return (
            f"BRP={self.brp} SJW={self.sjw_tq} Prop={self.prop_tq} PS1={self.ps1_tq} "
            f"PS2={self.ps2_tq} ({self.tq_per_bit} TQ, {self.bitrate_exact:.1f} bit/s, "
            f"sample point {100 * self.sample_point:.1f} %)"
        )


def decode_cnf(cnf1: int, cnf2: int, cnf3: int, osc_hz: int) -> BitTiming:
    """Decode the three configuration registers (raw register values)."""
    brp = cnf1 & R.CNF1_BRP_MASK
    sjw = ((cnf1 & R.CNF1_SJW_MASK) >> R.CNF1_SJW_SHIFT) + 1
    btlmode = bool(cnf2 & R.CNF2_BTLMODE)
    sam = bool(cnf2 & R.CNF2_SAM)
    ps1 = ((cnf2 & R.CNF2_PHSEG1_MASK) >> R.CNF2_PHSEG1_SHIFT) + 1
    prop = (cnf2 & R.CNF2_PRSEG_MASK) + 1
    if btlmode:
        ps2 = (cnf3 & R.CNF3_PHSEG2_MASK) + 1
    else:
        ps2 = max(ps1, R.IPT_TQ)
    return BitTiming(
        osc_hz=osc_hz,
        brp=brp,
        sjw_tq=sjw,
        prop_tq=prop,
        ps1_tq=ps1,
        ps2_tq=ps2,
        btlmode=btlmode,
        sam=sam,
    )


def encode_cnf(
    brp: int, prop_tq: int, ps1_tq: int, ps2_tq: int, sjw_tq: int = 1, sam: bool = False
) -> tuple[int, int, int]:
    """Register values (CNF1, CNF2, CNF3) for a setting with BTLMODE = 1 (helper for tests)."""
    cnf1 = ((sjw_tq - 1) << R.CNF1_SJW_SHIFT) | brp
    cnf2 = R.CNF2_BTLMODE | (R.CNF2_SAM if sam else 0)
    cnf2 |= ((ps1_tq - 1) << R.CNF2_PHSEG1_SHIFT) | (prop_tq - 1)
    cnf3 = ps2_tq - 1
    return cnf1, cnf2, cnf3
