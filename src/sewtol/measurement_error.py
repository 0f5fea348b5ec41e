"""The measurement error of the needle path: a fitter sets the compensators from a measurement.

On the line a fitter does not see the true deviation of the needle bar from its guide; he reads
it with a dial gauge (or an electronic probe) at a number of handwheel positions and sets the
compensators so that the deviation he READS is smallest. sewtol models that reading as

    measured d_k = true d(phi_k; settings) + e_k,   e_k ~ normal(0, sd_um),  k = 1 .. positions

at `positions` crank angles phi_k = 360 deg * k / positions (a graduated handwheel turned in equal
steps), one error e_k per position and machine, the same for every setting tried (the error of
that reading: the gauge's indication error at that point of its travel, the needle bar's form
error under the probe; a fitter who re-measured every trial setting with fresh errors would
search a different function every time). The setting chosen is the optimum of the measured
SumDelta (max over k of the reading, minus min, the guide shift centring the band); the
machine's figure is then the TRUE SumDelta at that setting (exact extremes over the whole
cycle). Two things separate it from the exact optimum: the positions miss the true extremes
between them, and the errors move the reading's extremes.

Typical values (assumptions, stated as such in every table): a mechanical dial gauge graduated in
0.01 mm repeats to about 3 um, one graduated in 0.001 mm (or a dial test indicator) to about
0.5-1 um, an inductive probe to a few tenths of a um (ISO 463:2006 gives the maximum
permissible errors of mechanical dial gauges; makers' data sheets give repeatability of this
order). Against a 10 um criterion only the finer instruments make sense; the strategies report
draws the yield against sd 0 ... 3 um.

The draws: machine k's errors are `normal_draws(seed, k, k + 1, positions)`, standard normals of
a stream of their own (spawn key (MEASURE_KEY, block)) beside the machines' and the setting
errors', drawn per block of STREAM machines as the one sampler does: the same seed gives the same
tables for any chunking, adding the option changes no other stream, and every level of a curve
uses the same draws (only the scale changes: common random numbers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sewtol.errors import ParameterError
from sewtol.law import STREAM, draw_units

# handwheel every 10 deg: the positions a fitter reads per machine unless told otherwise
DEFAULT_POSITIONS = 36
MAX_POSITIONS = 3600
# the first spawn-key word of the measurement streams (the machines' streams are children 0 ..
# of SeedSequence(seed), the setting errors' (0x5E771E, crc32(NAME), block))
MEASURE_KEY = 0x3EA5E


@dataclass(frozen=True)
class MeasurementError:
    """A normal reading error of standard deviation `sd_um` at each of `positions` equally
    spaced crank angles (see the module docstring). Validated at construction; sd 0 is exact
    (the studies then take the exact optimum, as without the option)."""

    sd_um: float
    positions: int = DEFAULT_POSITIONS

    def __post_init__(self):
        sd = self.sd_um
        if isinstance(sd, bool) or not isinstance(sd, (int, float)) or not math.isfinite(sd) \
                or sd < 0:
            raise ParameterError("measurement_error.sd_um", "must be a finite number >= 0", sd)
        object.__setattr__(self, "sd_um", float(sd))
        k = self.positions
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) \
                or not 3 <= k <= MAX_POSITIONS:
            raise ParameterError("measurement_error.positions",
                                 f"must be a whole number in 3 .. {MAX_POSITIONS}", k)
        object.__setattr__(self, "positions", int(k))

    @property
    def exact(self) -> bool:
        return self.sd_um == 0.0

    def crank_angles_rad(self) -> np.ndarray:
        """The measured positions: 2 pi k / positions, k = 0 .. positions - 1."""
        return np.arange(self.positions) * (2.0 * np.pi / self.positions)

    def scaled(self, sd_um: float) -> MeasurementError:
        """The same positions with another sd."""
        return MeasurementError(sd_um, self.positions)

    def label(self) -> str:
        """``normal sd 1 um at 36 positions`` (``none`` when exact)."""
        return "none" if self.exact else \
            f"normal sd {self.sd_um:g} um at {self.positions} positions"

    def to_dict(self) -> dict:
        return {"dist": "normal", "sd_um": self.sd_um, "positions": self.positions}


def normal_draws(seed: int, start: int, stop: int, positions: int) -> np.ndarray:
    """Standard normals (stop - start, positions) of machines start .. stop-1: machine k is row
    k % STREAM of block k // STREAM of the stream (seed, MEASURE_KEY, block)."""
    start, stop = int(start), int(stop)
    if stop <= start:
        return np.empty((0, int(positions)))
    streams = [np.random.SeedSequence(int(seed), spawn_key=(MEASURE_KEY, j))
               for j in range(-(-stop // STREAM))]
    from scipy import special

    return special.ndtri(draw_units(streams, int(positions), start, stop))


def parse_cli(sd_text, positions=DEFAULT_POSITIONS,
              flag: str = "--measurement-error") -> MeasurementError | None:
    """`--measurement-error SD_UM [--measured-positions K]`: None for none or 0."""
    if sd_text is None:
        return None
    try:
        sd = float(sd_text)
    except (TypeError, ValueError):
        raise ParameterError(flag, "must be a number of um (the sd of a reading)",
                             sd_text) from None
    if not (math.isfinite(sd) and sd >= 0):
        raise ParameterError(flag, "must be a finite number >= 0 (um)", sd_text)
    try:
        m = MeasurementError(sd, positions)
    except ParameterError as exc:
        raise ParameterError("--measured-positions", exc.rule, positions) from None
    return None if m.exact else m


def label(measurement: MeasurementError | None) -> str:
    return "none" if measurement is None else measurement.label()
