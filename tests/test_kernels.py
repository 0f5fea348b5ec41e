"""Compiled kernels held to the numpy reference and to the plain loop."""

import dataclasses

import numpy as np

from sewtol.kernels import needle_numba as KB
from sewtol.kernels import needle_positions as KP
from sewtol.mechanisms import needle_208 as nd
from sewtol.mechanisms import params as P
from sewtol.metrics import needle as nm
from sewtol.studies import beta as sb
from sewtol.studies.needle_eval import evaluate
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
    a = evaluate(nominal, dev, adjust=False, engine="numba")
    b = evaluate(nominal, dev, adjust=False, engine="numpy")
    assert np.max(np.abs(a.total_fixed_um - b.total_fixed_um)) < 1e-9


def test_beta_kernel_matches_reference_on_small_deviations(nominal, rng):
    """Small deviations keep SumDelta(beta) unimodal: both searches reach the same minimum.
    beta* itself is unique only where the minimum is sharp: where both extreme touches lie
    inside the rocker window, SumDelta does not depend on beta over a plateau."""
    dev = {k: rng.uniform(-0.004, 0.004, 60) for k in ("LF", "AM", "BC", "CD")}
    a = evaluate(nominal, dev, engine="numba")
    b = evaluate(nominal, dev, engine="numpy")
    assert np.max(np.abs(a.total_adjusted_um - b.total_adjusted_um)) < 1e-6
    c, _ = nm.columns(P.with_deviations(nominal, dev))
    rise = np.minimum(sb.total_at(c, b.beta_opt_deg - 0.05), sb.total_at(c, b.beta_opt_deg + 0.05))
    sharp = rise - b.total_adjusted_um > 1e-3
    assert sharp.sum() >= 10 and (~sharp).sum() >= 1  # both kinds occur in this sample
    assert np.max(np.abs(a.beta_opt_deg - b.beta_opt_deg)[sharp]) < 1e-5


def test_beta_kernel_reports_true_local_minima(nominal):
    """On any machine the kernel's SumDelta is the reference value at its beta*, and beta* is a
    local minimum (machines from the recommended set, many with multimodal SumDelta(beta))."""
    dev = NEEDLE_208_SETS["recommended"].sample(np.random.default_rng(9), 200)
    out = evaluate(nominal, dev, engine="numba")
    c, _ = nm.columns(P.with_deviations(nominal, dev))
    ok = np.isfinite(out.beta_opt_deg)
    assert ok.all()
    ref = sb.total_at(c, out.beta_opt_deg)
    assert np.max(np.abs(ref - out.total_adjusted_um)) < 1e-9
    inside = (out.beta_opt_deg > 10.01) & (out.beta_opt_deg < 34.99)
    for step in (-1e-3, 1e-3):
        near = sb.total_at(c, out.beta_opt_deg + step)
        assert np.all(near[inside] >= out.total_adjusted_um[inside] - 1e-9)


def test_kernel_packs_fields_in_order(nominal):
    c, _ = nm.columns(nominal)
    row = KB.pack(c)[0]
    assert [row[KB.FIELDS.index(f)] for f in ("AB", "CD", "guide_angle")] == \
        [nominal.AB, nominal.CD, nominal.guide_angle]
