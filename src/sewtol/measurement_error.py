"""The measurement error of the needle path: a fitter sets the compensators from a reading.

measured d_k = true d(phi_k; settings) + e_k, e_k ~ normal(0, sd_um), at `positions` crank
angles phi_k = 360 deg * k / positions, one error per position and machine, the same for every
setting tried. The setting is the optimum of the measured SumDelta; the machine's figure is
the TRUE SumDelta there. The errors are standard normals of a stream of their own (spawn key
(MEASURE_KEY, block), per block of STREAM machines as the one sampler draws): the same seed
gives the same tables for any chunking, and every level of a curve uses the same draws. The
model and typical instrument sd: docs/adjustment.md, "Setting from a measurement".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sewtol.errors import ParameterError, real
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
        if not real(sd, finite=True) or sd < 0:
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
