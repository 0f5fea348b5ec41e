"""sewtol's exact optimum against a second implementation written from the description alone.

The reference (tests/data/*.csv) was computed by an independent model of the needle drive (plain
numpy, crank-angle sampling and a brute force over beta; no sewtol kernel, metric or optimiser
code), for machines of the recommended-set Monte-Carlo of seed 2026. sewtol's adjusted SumDelta
must be the global minimum to 0.01 um (the issue's bound); its surrogate is exact to 1e-3 um, so
it may also lie at most that far below the reference.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from cli_helpers import beta_adjusted, fixed_um
from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import adjust
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208.model import Needle208

DATA = Path(__file__).parent / "data"
LINKS = ("LF", "LM", "AM", "AB", "BC", "BE", "CD")
SURROGATE_UM = 1e-3  # the kernel's stated error bound on d(psi)


def _read(name):
    frame = pd.read_csv(DATA / name, comment="#")
    return frame, {k: frame[f"dev_{k}"].to_numpy() for k in LINKS}


def test_adjusted_sum_delta_is_the_independent_global_minimum():
    ref, dev = _read("independent_beta_reference.csv")
    out = beta_adjusted(Needle208.nominal("sewtol-0.1"), dev, (10.0, 35.0))
    excess = out.total_um - ref["best_sum_delta_um"].to_numpy()
    assert np.all(excess <= 0.01), ref["machine"][excess > 0.01].tolist()
    assert np.all(excess >= -2 * SURROGATE_UM)
    # machine 6155, where sewtol 0.1 stopped in the other dip at 13.0 deg (11.50 um)
    i = int(np.flatnonzero(ref["machine"].to_numpy() == 6155)[0])
    assert abs(out.total_um[i] - 11.31804) < 0.01
    assert ref["range_lo_deg"][i] - 0.01 <= out.settings["beta"][i] <= ref["range_hi_deg"][i] + 0.01


def test_fixed_beta_sum_delta_equals_the_independent_crank_sampling():
    ref, dev = _read("independent_beta_reference.csv")
    nominal = Needle208.nominal("sewtol-0.1")
    assert nominal.beta == 22.584880336093065  # the beta the reference was computed at
    out = fixed_um(nominal, dev)
    assert np.max(np.abs(out - ref["sum_delta_at_nominal_beta_um"])) < 1e-6


def test_joint_optimum_with_guide_shift_and_angle_is_the_independent_minimum():
    ref, dev = _read("independent_joint_reference.csv")
    c, _ = nm.columns(P.with_deviations(Needle208.nominal("sewtol-0.1"), dev))
    for boxes, column in (({"beta": (10, 35), "guide_shift_um": (-100, 100)}, "bs_sum_delta_um"),
                          ({"beta": (10, 35), "guide_shift_um": (-100, 100),
                            "guide_angle": (-0.1, 0.1)}, "bsa_sum_delta_um")):
        total = np.asarray(adjust.optimise(c, boxes).total_um)
        excess = total - ref[column].to_numpy()
        assert np.all(excess <= 0.01), (column, float(excess.max()))
        assert np.all(excess >= -2 * SURROGATE_UM), (column, float(excess.min()))
