"""Compiled kernels held to the numpy reference and to the plain loop."""

import dataclasses

import numpy as np

from cli_helpers import beta_adjusted, fixed_um, needle_columns
from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208 import kernels
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208 import model as nd
from sewtol.mechanisms.needle_208.kernels import positions as KP
from sewtol.tolerances import NEEDLE_208_SETS


def test_position_kernel_equals_loop_and_engine(nominal, rng):
    phi = np.linspace(0, 2 * np.pi, 721)
    names = ("LF", "LM", "AM", "AB", "BC", "BE", "CD", "Ax", "Ay", "Dx", "Dy")
    batch = dataclasses.replace(nominal, **{k: getattr(nominal, k) + rng.uniform(-0.3, 0.3, 12)
                                            for k in names})
    M = KP.pack(batch)
    fast = KP.positions_kernel(M, phi)
    serial = KP.positions_kernel_serial(M, phi)
    loop = KP.positions_loop(M, phi)
    c, _ = nm.columns(batch)
    eng = nd.chain_from_crank(c, phi.reshape(1, -1))["E"].p
    assert np.array_equal(np.isnan(fast[..., 0]), np.isnan(loop[..., 0]))
    assert np.nanmax(np.abs(fast - loop)) < 1e-9
    assert np.array_equal(fast, serial)
    assert np.nanmax(np.abs(fast[..., 0] + 1j * fast[..., 1] - eng)) < 1e-9


def test_chunked_positions_cover_every_machine(nominal):
    M = np.repeat(KP.pack(nominal), 10, axis=0)
    phi = np.linspace(0, 2 * np.pi, 50)
    whole = KP.positions_kernel(M, phi)
    parts = dict(KP.positions_chunked(M, phi, chunk_machines=3))
    assert sorted(parts) == [0, 3, 6, 9]
    assert np.array_equal(np.concatenate([parts[k] for k in sorted(parts)]), whole)


def test_fixed_beta_kernel_equals_reference(nominal):
    dev = NEEDLE_208_SETS["recommended"].sample(np.random.default_rng(8), 300)
    a = fixed_um(nominal, dev)
    b = nm.deviation_figures(needle_columns(nominal, dev)).total_um
    assert np.max(np.abs(a - b)) < 1e-9


def test_beta_kernel_matches_reference_on_small_deviations(nominal, rng):
    """Both engines reach the same minimum (the kernel's cubic surrogate is within its 1e-3 um
    error estimate, the sampling bound 2e-3 um). beta* is unique only where the minimum is
    sharp: where both extreme touches lie inside the rocker window SumDelta does not depend on
    beta over a plateau, and each engine reports the plateau's range, which must overlap."""
    dev = {k: rng.uniform(-0.004, 0.004, 60) for k in ("LF", "AM", "BC", "CD")}
    a = beta_adjusted(nominal, dev, engine="numba")
    b = beta_adjusted(nominal, dev, engine="numpy")
    assert np.max(np.abs(a.min_total_um - b.min_total_um)) < 3e-3
    assert np.all(a.low["beta"] <= b.high["beta"] + 1e-6)
    assert np.all(b.low["beta"] <= a.high["beta"] + 1e-6)
    c, _ = nm.columns(P.with_deviations(nominal, dev))
    b_opt = b.settings["beta"]
    rise = np.minimum(sb.total_at(c, b_opt - 0.05), sb.total_at(c, b_opt + 0.05))
    sharp = rise - b.total_um > 1e-3
    assert sharp.sum() >= 10 and (~sharp).sum() >= 1  # both kinds occur in this sample
    # a sharp optimum has a short plateau (SumDelta within 1e-3 um), both engines inside it
    assert np.max(np.abs(a.settings["beta"] - b_opt)[sharp]) < 0.02


def test_beta_kernel_reports_global_minima(nominal):
    """On any machine the kernel's SumDelta is the model's value at its beta* (to the
    surrogate's 1e-3 um) and no beta of a 0.1-deg grid over the range does better (machines
    from the recommended set, many with multimodal SumDelta(beta); the dense brute force is in
    tests/test_adjust.py)."""
    dev = NEEDLE_208_SETS["recommended"].sample(np.random.default_rng(9), 60)
    out = beta_adjusted(nominal, dev)
    c, _ = nm.columns(P.with_deviations(nominal, dev))
    ok = np.isfinite(out.settings["beta"])
    assert ok.all()
    ref = sb.total_at(c, out.settings["beta"])
    assert np.max(np.abs(ref - out.total_um)) < 1e-3
    grid = sb.totals_on_grid(c, np.linspace(10, 35, 251))
    assert np.all(out.min_total_um <= np.nanmin(grid, axis=1) + 1e-3)


def test_kernel_packs_fields_in_order(nominal):
    c, _ = nm.columns(nominal)
    row = kernels.pack(c)[0]
    assert [row[kernels.FIELDS.index(f)] for f in ("AB", "CD", "guide_angle")] == \
        [nominal.AB, nominal.CD, nominal.guide_angle]


def test_sumdelta_kernel_equals_deviation_figures(nominal):
    """metrics.total_um_kernel (the outer searches' plateau measure) against the numpy
    deviation_figures: both exact extremes (Newton on d' against interval_extremes), so equal to
    far below the plateau tolerance of 1e-3 um, and NaN (cannot run) on the same machines,
    with beta and CD spread over their boxes and machines that cannot assemble among them."""
    dev = NEEDLE_208_SETS["base"].sample(np.random.default_rng(8), 400)
    dev["CD"] = np.random.default_rng(9).uniform(-0.3, 0.3, 400)
    dev["CD"][:5] = -20.0  # B-C-D cannot close
    c, _ = nm.columns(P.with_deviations(nominal, dev))
    c = {k: np.broadcast_to(v, (400, 1)).copy() for k, v in c.items()}
    c["beta"] = np.random.default_rng(10).uniform(10.0, 35.0, (400, 1))
    want = nm.deviation_figures(c).total_um
    got = nm.total_um_kernel(c)
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.isnan(got[:5]).all()
    assert np.isfinite(got).sum() >= 390
    assert np.nanmax(np.abs(got - want)) < 1e-9
