"""sewtol.mechanism.compiled: a file's groups generated into one numba kernel, held to the numpy
evaluation (FileMechanism.evaluate, the reference) on every example file and built-in, and the
generic adjuster searching on it held to the same adjuster searching on numpy.

Tolerances, from conditioning: the kernel takes e^{i ang(P->Q)} as (Q - P) / |Q - P| and |d| as
sqrt(dx^2 + dy^2) where numpy takes arctan2, cos, sin and hypot, so a position differs by a few
units in the last place of ~100 mm (2.2e-16 x 100 mm ~ 2e-14 mm per operation); through a chain of
two dyads (each can amplify a position's error by its transmission, up to ~1/sin(1 deg) = 57
at the dead-point limit) that stays below 1e-12 mm, i.e. 1e-9 um, and 1e-12 mm over a 10 mm
lever, 1e-13 rad ~ 6e-12 deg; TOL takes 1e-10 deg (a transmission angle near 90 deg is
arcsin near 1, where arcsin's slope grows). An argmin/argmax angle is a sample index: two
samples within rounding of each other may swap, so it is held to one sample step."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sewtol import adjuster as A
from sewtol.mechanism import load
from sewtol.mechanism.compiled import compiled, kernel_dir, unsupported

ROOT = Path(__file__).resolve().parents[1]
FILES = sorted({p.resolve() for p in (ROOT / "examples").glob("*.toml")}
               | {(ROOT / "tests" / "data" / "crank_slider.toml").resolve()})
TOL = {"um": 1e-9, "mm": 1e-12, "deg": 1e-10}
SEED = 2026


def _covered(mech):
    return [n for n in mech.output_names if not unsupported(mech, [n])]


def _machines(mech, n, scale, seed=SEED):
    """The nominal machine and n of the file's first tolerance set with deviations `scale` times
    as large (scale 20 puts some needle machines past closing); machines a positive length of
    which the scale would turn negative are left out (the file refuses them)."""
    nominal = mech.nominal_values()
    if not mech.tolerance_sets:
        return {}
    dev = next(iter(mech.tolerance_sets.values())).sample(np.random.default_rng(seed), n)
    values = {k: np.concatenate([[nominal[k]], nominal[k] + scale * np.asarray(v, float)])
              for k, v in dev.items() if k in nominal}
    positive = [p.name for p in mech.parameters if p.rule == "positive" and p.name in values]
    keep = np.all([values[k] > 0 for k in positive], axis=0) if positive else slice(None)
    return {k: v[keep] for k, v in values.items()}


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.parent.name if p.name ==
                         "mechanism.toml" else p.stem)
@pytest.mark.parametrize("scale", [1.0, 20.0])
def test_compiled_kernel_equals_the_numpy_evaluation(path, scale):
    mech = load(path)
    names = _covered(mech)
    spatial = [g.name for g in mech.groups if g.type.startswith("spatial")]
    if spatial:  # a spatial group is not compiled: the reason names it
        assert compiled(mech) is None and spatial[0] in unsupported(mech)
        return
    assert names, "every planar file has outputs the kernel covers"
    values = _machines(mech, 300, scale)
    ref = mech.evaluate(values, names)
    got = compiled(mech, names).evaluate(values)
    assert list(got.status) == list(ref.status)
    assert list(got.failed_group) == list(ref.failed_group)
    step = 360.0 / mech.samples
    for n in names:
        o = mech.output(n)
        a, b = ref.outputs[n], got.outputs[n]
        assert np.array_equal(np.isnan(a), np.isnan(b)), n
        ok = ~np.isnan(a)
        if o.fields.get("measure") in ("argmax_deg", "argmin_deg"):
            d = np.abs(a[ok] - b[ok]) % 360.0
            assert np.all(np.minimum(d, 360.0 - d) <= step * (1 + 1e-12)), n
        else:
            assert np.max(np.abs(a[ok] - b[ok]), initial=0.0) <= TOL[o.unit], n


def test_failures_are_counted_as_the_reference_counts_them():
    """The needle at 20 x its tolerances: machines that cannot close, named by the same group."""
    mech = load(ROOT / "examples" / "needle_208.toml")
    values = _machines(mech, 300, 20.0)
    got = compiled(mech, ["SumDelta_um"]).evaluate(values)
    counts = got.counts()
    assert counts["cannot_close"] > 0 and counts["ok"] + counts["cannot_close"] + \
        counts["dead_point"] == counts["n"] == 301
    assert np.all(np.isnan(got.outputs["SumDelta_um"][got.status != "ok"]))


def test_unsupported_outputs_and_clearances_are_refused_with_the_reason():
    mech = load(ROOT / "examples" / "needle_208.toml")
    assert compiled(mech, ["E_speed_m_s"]) is None
    assert unsupported(mech, ["E_speed_m_s"]) == "output E_speed_m_s is of type speed"
    assert unsupported(mech, ["SumDelta_um", "transmission_BCD_deg"]) == ""


def test_the_kernel_is_a_file_named_by_its_source(tmp_path, monkeypatch):
    """numba caches a function of a real file only: the generated source is written once under
    the kernel folder, named by its hash, and compiled with cache=True."""
    monkeypatch.setenv("SEWTOL_KERNEL_DIR", str(tmp_path))
    assert kernel_dir() == tmp_path
    mech = load(ROOT / "examples" / "m6_needle.toml")
    model = compiled(mech, ["travel_mm"])
    assert "cache=True" in model.source
    again = compiled(mech, ["travel_mm"])
    assert again.kernel is model.kernel and again.source == model.source


@pytest.fixture(scope="module")
def needle():
    return load(ROOT / "examples" / "needle_208.toml")


def test_adjuster_on_the_kernel_equals_the_adjuster_on_numpy(needle):
    """300 needle machines, beta: the search on the kernel against the search on
    FileMechanism.evaluate. The answer at the settings is evaluated by numpy either way; a
    decision that flips on a difference in the last bits can move a setting by at most the
    plateau bisection's last step (box / 2^BISECTIONS, twice) and the value by rounding."""
    values = _machines(needle, 300, 1.0)
    fast = A.adjust(needle, values, "SumDelta_um", "beta")
    ref = A.adjust(needle, values, "SumDelta_um", "beta", compiled=False)
    assert fast.evaluations == ref.evaluations
    assert list(fast.status) == list(ref.status)
    assert np.max(np.abs(fast.value - ref.value)) <= TOL["um"]
    c = needle.compensators["beta"]
    step = 2.0 * (c.high - c.low) / 2**A.BISECTIONS
    assert np.max(np.abs(fast.settings["beta"] - ref.settings["beta"])) <= step


def test_two_compensator_search_on_the_kernel_ends_within_its_tolerance(needle):
    """beta + guide shift (4 machines: ~10,000 evaluations each, ~3 CPU-s per machine on
    numpy): the branch and bound cuts thousands of cells whose order a last-bit difference can
    change, so the two searches may stop at different points (measured: up to 1e-6 um apart on
    8 machines); each stops within the search's tol of its optimum, so they agree to tol."""
    values = _machines(needle, 3, 1.0)
    fast = A.adjust(needle, values, "SumDelta_um", "beta,guide_shift")
    ref = A.adjust(needle, values, "SumDelta_um", "beta,guide_shift", compiled=False)
    assert list(fast.status) == list(ref.status)
    assert np.max(np.abs(fast.value - ref.value)) <= A.TOL["um"]


def test_adjuster_without_a_kernel_is_the_numpy_adjuster():
    """The spatial rocker (a spatial group: no kernel): compiled=True changes nothing."""
    mech = load(ROOT / "examples" / "spatial_crank_rocker.toml")
    values = _machines(mech, 6, 1.0)
    names = list(mech.compensators)[:2]
    out = mech.output_names[0]
    a = A.adjust(mech, values, out, names, "minimise")
    b = A.adjust(mech, values, out, names, "minimise", compiled=False)
    assert np.array_equal(a.value, b.value, equal_nan=True)
    for k in a.settings:
        assert np.array_equal(a.settings[k], b.settings[k], equal_nan=True)
