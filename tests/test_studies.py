"""Tolerance studies: Sobol against Ishigami, yield against an exact case, scan against direct
calls, determinism across workers, worst case against sampling."""

import numpy as np
import pytest

from cli_helpers import stretched_CD
from sewtol.errors import ParameterError
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.optimize import bisect_root
from sewtol.studies.sobol import case_indices, sample
from sewtol.tables.needle_208 import montecarlo, scan, worst_case
from sewtol.tolerances import NEEDLE_208_SETS, Tolerance, ToleranceSet


def test_sobol_pipeline_reproduces_ishigami_indices():
    a, b = 7.0, 0.1
    problem = {"num_vars": 3, "names": ["x1", "x2", "x3"], "bounds": [[-np.pi, np.pi]] * 3}

    def ishigami(X):
        return np.sin(X[:, 0]) + a * np.sin(X[:, 1]) ** 2 + b * X[:, 2] ** 4 * np.sin(X[:, 0])

    X = sample(problem, 2**13, 11)
    c = case_indices(problem, X, ishigami(X), 2**13, 11)
    idx, conv, failed = c.indices, c.convergence, c.failed
    full = idx[idx.n == 2**13].set_index("param")
    v = a**2 / 8 + b * np.pi**4 / 5 + b**2 * np.pi**8 / 18 + 0.5
    v1 = 0.5 * (1 + b * np.pi**4 / 5) ** 2
    v2 = a**2 / 8
    v13 = b**2 * np.pi**8 * (1 / 18 - 1 / 50)
    s1 = [v1 / v, v2 / v, 0.0]
    st = [(v1 + v13) / v, v2 / v, v13 / v]
    assert np.allclose(full["S1"], s1, atol=0.03)
    assert np.allclose(full["ST"], st, atol=0.03)
    assert failed == 0 and conv["max_abs_dST"].iloc[0] < 0.05


def cd_only(width=0.01):
    return ToleranceSet("cd", (Tolerance("CD", -width, width),))


def test_montecarlo_yield_matches_exactly_computable_case(nominal):
    """Only CD scatters, uniform +/-0.01: the exact yield is the share of [-0.01, 0.01] where
    SumDelta <= 10 um, found by root finding on the deterministic model."""
    from sewtol.mechanisms.needle_208 import metrics as nm

    c, _ = nm.columns(nominal)

    def total(delta, adjust):
        cc = nm.with_values(nm.repeat(c, np.size(delta)), CD=nominal.CD + np.atleast_1d(delta))
        if adjust:
            return sb.optimise_beta_columns(cc, window=False).total_um
        return nm.deviation_figures(cc).total_um

    grid = np.linspace(-0.01, 0.01, 401)
    for adjust, case in ((False, "fixed"), (True, "adjusted")):
        ok = total(grid, adjust) <= 10.0
        # a single interval around nominal, so two roots give the exact yield
        assert ok[200] and np.sum(np.abs(np.diff(ok.astype(int)))) <= 2
        inside = grid[ok]
        lo_edge = -0.01 if ok[0] else bisect_root(
            lambda d, a=adjust: total(d, a) - 10.0, np.array([inside[0] - 5e-5]),
            np.array([inside[0]]), xtol=1e-9)[0]
        hi_edge = 0.01 if ok[-1] else bisect_root(
            lambda d, a=adjust: total(d, a) - 10.0, np.array([inside[-1]]),
            np.array([inside[-1] + 5e-5]), xtol=1e-9)[0]
        exact = (hi_edge - lo_edge) / 0.02
        res = montecarlo(nominal, cd_only(), 3000, seed=5)
        sigma = np.sqrt(exact * (1 - exact) / 3000)
        assert abs(res.yield_of(case) - exact) < 4 * sigma, (case, exact)


def test_unassemblable_machines_are_counted_against_yield(nominal):
    res = montecarlo(nominal, ToleranceSet("wild", (Tolerance("CD", -25.0, 0.0),)), 400, seed=1)
    assert res.failed > 0
    assert res.yield_of("adjusted") <= 1 - res.failed / res.n
    assert res.to_dict()["failed"] == res.failed
    assert np.isinf(res.quantiles("fixed")["p99"])


def test_same_seed_same_machines_for_any_number_of_workers(nominal):
    ts = NEEDLE_208_SETS["recommended"]
    one = montecarlo(nominal, ts, 1200, seed=42, n_jobs=1, chunk_size=500)
    two = montecarlo(nominal, ts, 1200, seed=42, n_jobs=2, chunk_size=500)
    assert one.machines.equals(two.machines)
    assert one.to_dict() == two.to_dict()
    other = montecarlo(nominal, ts, 1200, seed=43)
    assert not one.machines.equals(other.machines)


def test_chunks_evaluated_together_give_the_chunks_numbers(nominal, monkeypatch):
    """On the plug-ins the fast Monte-Carlo evaluates TOGETHER consecutive chunks in one call
    of the model; every chunk is still counted on its own and every number is the one of chunk
    by chunk (each machine's figures are its own)."""
    from sewtol.studies import montecarlo as MC

    calls, real = [], MC._montecarlo_chunk

    def counted(record, dev, *a, **k):
        calls.append(len(next(iter(dev.values()))))
        return real(record, dev, *a, **k)

    monkeypatch.setattr(MC, "_montecarlo_chunk", counted)
    ts, runs = NEEDLE_208_SETS["recommended"], {}
    for together in (4, 1):
        monkeypatch.setattr(MC, "TOGETHER", together)
        seen, calls[:] = [], []
        runs[together] = montecarlo(nominal, ts, 1150, seed=3, chunk_size=100,
                                    progress=lambda done, total, seen=seen:
                                    seen.append((done, total)))
        assert seen == [(k, 12) for k in range(13)]  # 11 chunks of 100, one of 50
        # runs of four consecutive chunks, the last run holding the short chunk
        assert calls == ([400, 400, 350] if together == 4 else [100] * 11 + [50])
    assert runs[4].machines.equals(runs[1].machines)
    assert runs[4].to_dict() == runs[1].to_dict()


def test_scan_rows_equal_direct_model_calls(nominal):
    res = scan(nominal, NEEDLE_208_SETS["recommended"], guide_shift_um=20.0)
    for param, side, delta in (("BC", "upper", 0.05), ("LF", "lower", -0.8), ("CD", "lower", -0.01)):
        row = res.rows[(res.rows.param == param) & (res.rows.side == side)].iloc[0]
        direct = sb.optimise_beta(nominal.override(**{param: getattr(nominal, param) + delta},
                                                   guide_shift_um=20.0), window=False)
        assert row.delta_mm == delta
        assert abs(row.beta_deg - direct.beta_deg[0]) < 1e-6
        assert abs(row.total_um - direct.total_um[0]) < 1e-9
        assert abs(row.plus_um + row.minus_um - row.total_um) < 1e-12


def test_guide_shift_moves_a_one_sided_path_by_the_shift(nominal):
    """Shifting the guide by s along its normal changes d by -s everywhere."""
    from sewtol.mechanisms.needle_208 import metrics as nm

    c, _ = nm.columns(nominal)
    a = nm.deviation_figures(c)
    b = nm.deviation_figures(nm.with_values(c, guide_shift_um=[100.0]))
    # the path lies wholly on the minus side after a 100 um shift: Delta- = 100 + max d
    assert b.plus_um[0] == 0.0
    assert abs(b.minus_um[0] - (100.0 + a.plus_um[0])) < 1e-6


def test_worst_case_bounds_every_sampled_machine(nominal):
    ts = ToleranceSet("three", (Tolerance("LF", -0.05, 0.05), Tolerance("BC", -0.05, 0.05),
                                Tolerance("CD", -0.01, 0.01)))
    wc = worst_case(nominal, ts, adjust=False)
    mc = montecarlo(nominal, ts, 500, seed=9)
    assert wc["total_um"] >= mc.machines["total_fixed_um"].max() - 1e-9
    assert wc["total_um"] >= wc["worst_corner_total_um"] - 1e-12


def test_tolerance_rules():
    with pytest.raises(ParameterError, match="LF.lower: must not be above the upper limit"):
        Tolerance("LF", 0.1, -0.1)
    with pytest.raises(ParameterError, match="LF.dist: must be one of uniform, normal"):
        Tolerance("LF", -0.1, 0.1, "cauchy")


def test_normal_and_truncated_normal_draws():
    rng = np.random.default_rng(3)
    n = Tolerance("AB", -0.03, 0.03, "normal").from_unit(rng.random(200_000))
    assert abs(n.std() - 0.01) < 2e-4 and abs(n.mean()) < 1e-4
    t = Tolerance("AB", -0.03, 0.03, "truncnorm").from_unit(rng.random(200_000))
    assert t.min() >= -0.03 and t.max() <= 0.03
    u = Tolerance("LF", -0.8, 0.25).from_unit(rng.random(200_000))
    assert abs(u.mean() - (-0.275)) < 2e-3


def test_sobol_confidence_intervals_repeat_for_seed_zero():
    """SALib seeds its bootstrap only `if seed:`; seed 0 must still give the same intervals."""
    problem = {"num_vars": 2, "names": ["a", "b"], "bounds": [[0, 1], [0, 1]]}
    y = np.random.default_rng(1).random(16 * 4)
    for seed in (0, 5):
        a, b = (case_indices(problem, None, y, 16, seed).indices for _ in range(2))
        assert a.equals(b), seed


def test_named_failures_leaves_the_callers_table_as_it_was(nominal):
    """named_failures takes a shallow copy: its new status columns never reach the frame it
    was given (the failing machines' reasons come from the plug-in on those machines only)."""
    from sewtol.protocol import plugins
    from sewtol.studies.montecarlo import _file_model, named_failures, sample_machines
    from sewtol.tables.needle_208 import as_mechanism

    mech = as_mechanism(nominal)
    wild = ToleranceSet("wild", (Tolerance("CD", -25.0, 0.0),))
    frame = sample_machines(_file_model, mech.parameter_record(), wild, 60, seed=1, mech=mech,
                            outputs=["SumDelta_um"], fast=True)
    before = frame.copy()
    named = named_failures(mech, plugins(mech).failure_table, frame, ("CD",), "SumDelta_um",
                           None, None)
    assert frame.equals(before) and list(frame) == list(before)
    failed = named["SumDelta_um"].isna().to_numpy()
    assert 0 < failed.sum() < 60
    assert (named["status"][~failed] == "ok").all()
    assert set(named["status"][failed]) <= {"cannot_close", "dead_point", "unexplained"}
    assert named["failed_group"][failed].str.len().gt(0).all()
    assert (named["failed_group"][~failed] == "").all()


@pytest.mark.parametrize("n_jobs", [1, 2])
def test_streamed_summary_equals_the_table_based_one(nominal, n_jobs):
    """The Monte-Carlo keeps its chunks compact (outputs as arrays, words as codes, deviations
    drawn again): its table equals the one joined from whole chunks and named afterwards, and
    every count, group, quantile and capability equals the same figure taken from that table,
    on a set where machines cannot close, hit a dead point and fall out of spec in both cases."""
    from sewtol.protocol import plugins
    from sewtol.studies import montecarlo as MC
    from sewtol.tables.needle_208 import as_mechanism

    # 0.3 mm from B-C-D's stretched position (test_contracts): it cannot close or passes a dead
    # point at the nominal beta, but closes at its adjusted beta
    wild = ToleranceSet("near", (Tolerance("CD", -0.35, 0.05), Tolerance("AB", -0.01, 0.01)))
    mech = as_mechanism(nominal.override(CD=stretched_CD(nominal) + 0.3))
    box = {"beta": (10.0, 35.0)}
    res = MC.montecarlo(mech, wild, 1300, 7, ["SumDelta_um"], 10.0, adjust=box, fast=True,
                        n_jobs=n_jobs, chunk_size=500)
    # the table-based reference: whole chunks joined, then named, ordered and renamed
    frame = MC.sample_machines(MC._file_model, mech.parameter_record(), wild, 1300, 7,
                               chunk_size=500, mech=mech, outputs=["SumDelta_um"],
                               compensator=box, target="SumDelta_um", fast=True)
    pl = plugins(mech)
    spec = res.spec()
    frame = MC.named_failures(mech, pl.failure_table, frame, ("CD", "AB"), "SumDelta_um", spec,
                              box)
    columns = pl.columns["montecarlo"]
    first = ["machine", "CD", "AB", *(k for k in columns if k in frame)]
    frame = frame[first + [k for k in frame if k not in first]].rename(columns=columns)
    assert res.machines.equals(frame) and list(res.machines) == list(frame)
    assert res.machines.dtypes.equals(frame.dtypes)
    words = ("ok", "out_of_spec", "cannot_close", "dead_point", "unexplained")
    seen = set()
    for case, out, status, group in (("fixed", "total_fixed_um", "status_fixed",
                                      "fail_dyad_fixed"),
                                     ("adjusted", "total_adjusted_um", "status_adjusted",
                                      "fail_dyad_adjusted")):
        v = frame[out].to_numpy(float)
        s = frame[status].to_numpy(object).copy()
        s[(s == "ok") & ~spec.passes(v)] = "out_of_spec"
        want = {k: int(np.sum(s == k)) for k in words}
        got = res.counts(case)
        assert {k: got[k] for k in words} == want and got["n"] == 1300
        assert got["ok"] + got["out_of_spec"] + got["failed"] == 1300
        seen |= {k for k in words if want[k]}
        assert list(res.status(case)) == list(s)
        x = np.where(np.isnan(v), np.inf, v)
        assert res.quantiles(case) == {f"p{q}": float(np.quantile(x, q / 100, method="higher"))
                                       for q in (50, 95, 99)}
        x = v[~np.isnan(v)]
        p50, p99865 = np.quantile(x, [0.5, 0.99865])
        assert res.capability(case) == {
            "Cpu": (10.0 - x.mean()) / (3 * x.std(ddof=1)),
            "Cpu_percentile": float((10.0 - p50) / (p99865 - p50))}
        g = frame[group]
        assert res.failed_groups(case == "adjusted") == {
            str(k): int(c) for k, c in g[g != ""].value_counts().sort_index().items()}
    assert {"out_of_spec", "cannot_close", "dead_point"} <= seen
    beta = frame["beta_opt_deg"].dropna()
    assert res.setting_range("beta") == (float(beta.min()), float(beta.max()))
    at = frame["beta_at_bound"].to_numpy(float) == 1.0
    assert res.at_bound("beta") == int(at.sum())
    assert res.at_bound("beta", pinned=True) == int(np.sum(
        at & ((frame["beta_high_deg"] - frame["beta_low_deg"]).to_numpy() < MC.PINNED_PLATEAU)))
