"""The setting error of a compensator: how far from the setting aimed at a fitter's setting lands.

    setting made = round(setting aimed at, resolution) + error,  clipped to the compensator's range

in the compensator's own unit; the error is ``normal`` (``sd``) or ``uniform`` (+-``half_width``).
A mechanism file declares ``setting_error = {dist = "normal", sd = 0.005}`` (a bare number is a
uniform half-width), the needle's command line ``--setting-error NAME=SD`` or
``NAME=uniform:HALF_WIDTH``. Machine k's error on NAME is ``from_unit(u)`` of one uniform of the
stream (seed, NAME) (`unit_draws`), per block of STREAM machines as the one sampler draws, so
any chunking gives the same numbers and every strategy and level of a curve uses the same u.
docs/adjustment.md, "Setting as a fitter does it".
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np

from sewtol.errors import ParameterError, real
from sewtol.law import STREAM, draw_units

DISTS = ("normal", "uniform")
# the first spawn-key word of every setting-error stream: the machines' streams are children
# 0 .. n/STREAM - 1 of SeedSequence(seed), these are (SETTING_KEY, crc32(NAME), block)
SETTING_KEY = 0x5E771E


@dataclass(frozen=True)
class SettingError:
    """A compensator's setting error: ``normal`` with standard deviation `width`, or
    ``uniform`` on +-`width` (the compensator's unit). Validated at construction."""

    dist: str
    width: float

    def __post_init__(self):
        if self.dist not in DISTS:
            raise ParameterError("setting_error.dist", f"must be one of {', '.join(DISTS)}",
                                 self.dist)
        w = self.width
        if not real(w, finite=True) or w < 0:
            raise ParameterError(f"setting_error.{self.key}", "must be a finite number >= 0", w)
        object.__setattr__(self, "width", float(w))

    @property
    def key(self) -> str:
        """The name of the width: ``sd`` (normal) or ``half_width`` (uniform)."""
        return "sd" if self.dist == "normal" else "half_width"

    @property
    def sd(self) -> float:
        """The standard deviation of the error (a uniform's is half_width / sqrt 3)."""
        return self.width if self.dist == "normal" else self.width / math.sqrt(3.0)

    @property
    def exact(self) -> bool:
        return self.width == 0.0

    def from_unit(self, u) -> np.ndarray:
        """Errors of standard uniforms u in (0, 1)."""
        u = np.asarray(u, float)
        if self.dist == "normal":
            from scipy import special

            return self.width * special.ndtri(u)
        return self.width * (2.0 * u - 1.0)

    def scaled(self, width: float) -> SettingError:
        """The same law with another width."""
        return SettingError(self.dist, width)

    def label(self, unit: str = "") -> str:
        """``normal sd 0.01 deg`` / ``uniform +-0.01 deg``."""
        u = f" {unit}" if unit else ""
        return (f"normal sd {self.width:g}{u}" if self.dist == "normal"
                else f"uniform +-{self.width:g}{u}")

    def to_dict(self) -> dict:
        return {"dist": self.dist, self.key: self.width}


def parse(value, where: str) -> SettingError | None:
    """A setting error from a mechanism file's value: a table ``{dist = "normal", sd = S}`` or
    ``{dist = "uniform", half_width = H}``, or a bare number (a uniform half-width); 0 gives
    None (exact). Errors name `where`, the rule and the value."""
    if isinstance(value, SettingError):
        return None if value.exact else value
    if isinstance(value, dict):
        dist = value.get("dist")
        if dist not in DISTS:
            raise ParameterError(f"{where}.dist", f"must be one of {', '.join(DISTS)}", dist)
        key = "sd" if dist == "normal" else "half_width"
        extra = sorted(set(value) - {"dist", key})
        if extra:
            raise ParameterError(f"{where}", f"a {dist} setting error takes dist and {key} only",
                                 extra)
        if key not in value:
            raise ParameterError(f"{where}.{key}", f"is required for a {dist} setting error",
                                 value)
        width = value[key]
        where = f"{where}.{key}"
    else:
        dist, width = "uniform", value
    if not real(width, finite=True) or width < 0:
        raise ParameterError(where, "must be a finite number >= 0", width)
    return None if width == 0 else SettingError(dist, float(width))


def parse_cli(flag: str, name: str, text: str) -> SettingError | None:
    """``SD`` (normal) or ``normal:SD`` / ``uniform:HALF_WIDTH`` of ``--setting-error NAME=...``."""
    dist, sep, rest = str(text).partition(":")
    if not sep:
        dist, rest = "normal", text
    dist = dist.strip()
    if dist not in DISTS:
        raise ParameterError(f"{flag} {name}", "must be SD, normal:SD or uniform:HALF_WIDTH",
                             text)
    try:
        width = float(rest)
    except (TypeError, ValueError):
        raise ParameterError(f"{flag} {name}", "must be a number (SD, normal:SD or "
                             "uniform:HALF_WIDTH)", text) from None
    if not (math.isfinite(width) and width >= 0):
        raise ParameterError(f"{flag} {name}", "must be a finite number >= 0", text)
    return None if width == 0 else SettingError(dist, width)


def label(error: SettingError | None, unit: str = "") -> str:
    return "exact" if error is None or error.exact else error.label(unit)


def _streams(seed: int, name: str, blocks: int) -> list[np.random.SeedSequence]:
    tag = zlib.crc32(name.encode())
    return [np.random.SeedSequence(int(seed), spawn_key=(SETTING_KEY, tag, j))
            for j in range(blocks)]


def unit_draws(seed: int, name: str, start: int, stop: int) -> np.ndarray:
    """Standard uniforms of machines start .. stop-1 for compensator `name`'s setting error:
    machine k is row k % STREAM of the block k // STREAM (a Generator per block, so any window
    of machines draws the same numbers)."""
    start, stop = int(start), int(stop)
    if stop <= start:
        return np.empty(0)
    return draw_units(_streams(seed, name, -(-stop // STREAM)), 1, start, stop)[:, 0]


def snap(setting, resolution: float) -> np.ndarray:
    """A setting rounded to the nearest multiple of the resolution (a tie to the even multiple;
    0: unchanged)."""
    s = np.asarray(setting, float)
    return s if not resolution else np.round(s / resolution) * resolution
