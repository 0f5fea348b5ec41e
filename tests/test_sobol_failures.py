"""Sobol with machines that cannot be built (studies.sobol.POLICY): counted, never refused,
never dropped; checked on Ishigami with a cut against quadrature of the conditional law."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from SALib.analyze import sobol as sobol_analyze

from cli_helpers import run, strict_loads
from sewtol.mechanism import load
from sewtol.studies import sobol as so
from sewtol.tables.needle_208 import needle_sobol
from sewtol.tolerances import Tolerance, ToleranceSet

PI = np.pi
PROBLEM = {"num_vars": 3, "names": ["x1", "x2", "x3"], "bounds": [[-PI, PI]] * 3}
FILE = str(Path(__file__).parent / "data" / "crank_slider.toml")
MQ, VQ = PI**4 / 5, PI**8 / 9 - PI**8 / 25  # mean and variance of x3^4, x3 ~ U(-pi, pi)


def ishigami(X):
    return np.sin(X[:, 0]) + 7 * np.sin(X[:, 1]) ** 2 + 0.1 * X[:, 2] ** 4 * np.sin(X[:, 0])


def _run(cut, n=4096, seed=7):
    X = so.sample(PROBLEM, n, seed)
    y = ishigami(X)
    y[cut(X)] = np.nan
    return so.case_indices(PROBLEM, X, y, n, seed, "cut")


def _at_n(c):
    return c.indices[c.indices["n"] == c.indices["n"].max()].set_index("param")


def _within(est, conf, truth, k=3.0):
    assert np.all(np.abs(np.asarray(est) - np.asarray(truth)) <= k * np.asarray(conf)), \
        (np.asarray(est), np.asarray(truth), np.asarray(conf))


def _indicator_of_sum(g_a, g_b):
    """S1 and ST of I = 1[feasible] for a cut through two independent inputs a, b, from
    g_a(a) = P(feasible | a) and g_b(b) on uniform grids: S1_a = Var g_a / V,
    ST_a = E[g_b (1 - g_b)] / V (the variance left in I when b is fixed), V = p (1 - p)."""
    p = g_a.mean()
    v = p * (1 - p)
    return (np.var(g_a) / v, np.mean(g_b * (1 - g_b)) / v), (np.var(g_b) / v,
                                                                np.mean(g_a * (1 - g_a)) / v)


def test_box_cut_gives_the_indices_of_the_truncated_box():
    # x1 > 1 fails: the machines that assemble are a box, x1 ~ U(-pi, 1), x2, x3 ~ U(-pi, pi)
    # independent. With s = sin x1, q = x3^4: V1 = Var s (1 + 0.1 E q)^2, V2 = 49/8,
    # V3 = 0.01 (E s)^2 Var q, V13 = 0.01 Var s Var q
    c = 1.0
    span = c + PI
    ms = (-1 - np.cos(c)) / span
    vs = (span / 2 - np.sin(2 * c) / 4) / span - ms**2
    v1, v2, v3, v13 = vs * (1 + 0.1 * MQ) ** 2, 49 / 8, 0.01 * ms**2 * VQ, 0.01 * vs * VQ
    v = v1 + v2 + v3 + v13
    s1, st = np.array([v1, v2, v3]) / v, np.array([v1 + v13, v2, v3 + v13]) / v
    res = _run(lambda X: X[:, 0] > c)
    f = _at_n(res)
    # the complete base samples are a Saltelli design of the truncated box: exact indices
    _within(f["S1"], f["S1_conf"], s1)
    _within(f["ST"], f["ST_conf"], st)
    _within(f["S1_given"], f["S1_given_conf"], s1)
    # x2 alone explains the same share of the conditional law as of the full box (49/8 / V)
    assert f.loc["x2", "S1_given"] == pytest.approx(s1[1], abs=0.02)
    # assembling is decided by x1 alone: S1 = ST = 1 for x1, exactly 0 for the others
    feas = res.feasibility.set_index("param")
    _within(feas[["S1", "ST"]].loc["x1"], feas[["S1_conf", "ST_conf"]].loc["x1"], [1.0, 1.0])
    assert (feas.loc[["x2", "x3"], ["S1", "ST"]].to_numpy() == 0.0).all()


def test_cut_across_two_inputs_against_quadrature_of_the_conditional_law():
    # x1 + x2 > 1 fails: under the law of the machines that assemble x1 and x2 are dependent;
    # S1_given estimates Var(E[Y | x_i]) / Var(Y) of that law, computed here by quadrature
    c, grid = 1.0, 2000
    x = -PI + (np.arange(grid) + 0.5) * 2 * PI / grid
    s, h = np.sin(x), 7 * np.sin(x) ** 2
    ok = (x[:, None] + x[None, :]) <= c  # [x1, x2]
    a = 1 + 0.1 * MQ
    w = ok / ok.sum()
    es, eh = np.sum(w * s[:, None]), np.sum(w * h[None, :])
    ey = a * es + eh
    ey2 = ((a**2 + 0.01 * VQ) * np.sum(w * s[:, None] ** 2)
           + 2 * a * np.sum(w * s[:, None] * h[None, :]) + np.sum(w * h[None, :] ** 2))
    v = ey2 - ey**2
    m1 = a * s + (ok * h[None, :]).sum(1) / ok.sum(1)
    m2 = a * (ok * s[:, None]).sum(0) / ok.sum(0) + h
    s1 = [np.sum(ok.sum(1) / ok.sum() * (m1 - ey) ** 2) / v,
          np.sum(ok.sum(0) / ok.sum() * (m2 - ey) ** 2) / v, 0.01 * VQ * es**2 / v]
    assert s1 == pytest.approx([0.2965, 0.4984, 0.0290], abs=2e-3)  # the reference itself
    res = _run(lambda X: X[:, 0] + X[:, 1] > c)
    f = _at_n(res)
    _within(f["S1_given"], f["S1_given_conf"], s1)
    # the indicator: P(assembles | x1) = clip((c - x1 + pi) / 2 pi, 0, 1), the same for x2
    g = np.clip((c - x + PI) / (2 * PI), 0, 1)
    (s1_1, st_1), (s1_2, st_2) = _indicator_of_sum(g, g)
    feas = res.feasibility.set_index("param")
    _within(feas["S1"], feas["S1_conf"], [s1_1, s1_2, 0.0])
    _within(feas["ST"], feas["ST_conf"], [st_1, st_2, 0.0])
    assert feas.loc["x3", "ST"] == 0.0


def test_counts_add_up_and_the_same_seed_gives_the_same_answer():
    cut = lambda X: X[:, 0] + X[:, 1] > 1.0  # noqa: E731
    a, b = _run(cut, n=256, seed=3), _run(cut, n=256, seed=3)
    for name in ("indices", "convergence", "outcomes", "feasibility"):
        pd.testing.assert_frame_equal(getattr(a, name), getattr(b, name))
    rows = 256 * 5
    assert a.outcomes["rows"].sum() == rows
    assert a.failed == int(a.outcomes.loc[a.outcomes["outcome"] != "assembled", "rows"].sum())
    X = so.sample(PROBLEM, 256, 3)
    assert a.failed == int(np.sum(cut(X)))
    blocks = (~cut(X)).reshape(256, 5).all(axis=1)
    assert a.complete == int(blocks.sum()) < 256
    res = so.result_of([a], 256, 3, "ishigami", model_runs=rows)
    c = res.counts()["cut"]
    assert c["rows"] == c["assembled"] + c["no_value"] == rows
    assert c["complete_base_samples"] == a.complete and res.has_failures
    assert set(res.frames()) == {"indices", "convergence", "outcomes", "feasibility"}
    assert res.assembly()["counts"] == res.counts() and len(res.notes()) == 1


def test_too_few_machines_that_assemble_give_undefined_indices_not_guesses():
    X = so.sample(PROBLEM, 16, 1)
    for kept in (0, so.MIN_COMPLETE - 1):  # complete base samples
        y = np.where(np.arange(len(X)) < 5 * kept, ishigami(X), np.nan)
        c = so.case_indices(PROBLEM, X, y, 16, 1, "few")
        assert c.complete == kept and c.failed == len(X) - 5 * kept
        assert c.indices[["S1", "S1_conf", "ST", "ST_conf"]].isna().all().all()
        # S1_given needs MIN_GIVEN_ROWS assembled rows, not complete base samples
        assert c.indices["S1_given"].isna().all() == (5 * kept < so.MIN_GIVEN_ROWS)
        assert c.outcomes["rows"].sum() == len(X)
        assert (c.feasibility is None) == (kept == 0)
    res = so.result_of([c], 16, 1, "few", model_runs=len(X))
    assert strict_loads(strict_json(res.assembly()))["counts"]["few"]["no_value"] == c.failed
    assert strict_loads(strict_json(res.to_records()))[0]["S1"] is None


def test_without_failures_the_numbers_are_the_plain_saltelli_analysis():
    X = so.sample(PROBLEM, 256, 5)
    y = ishigami(X)
    c = so.case_indices(PROBLEM, X, y, 256, 5, "y")
    ref = sobol_analyze.analyze(PROBLEM, y, calc_second_order=False, num_resamples=200,
                                conf_level=0.95, seed=5)
    f = _at_n(c)
    for k in ("S1", "S1_conf", "ST", "ST_conf"):
        np.testing.assert_array_equal(f[k].to_numpy(), ref[k])
    assert "S1_given" not in c.indices and c.feasibility is None and c.failed == 0
    res = so.result_of([c], 256, 5, "ishigami", model_runs=len(X))
    assert not res.has_failures and res.assembly() is None and res.notes() == []
    assert set(res.frames()) == {"indices", "convergence"}
    assert list(res.to_records()[0]) == ["param", "S1", "S1_conf", "ST", "ST_conf", "case"]
    assert res.counts()["y"] == {"rows": len(X), "assembled": len(X), "cannot_close": 0,
                                 "dead_point": 0, "failed_groups": {}, "base_samples": 256,
                                 "complete_base_samples": 256}


def test_needle_sobol_counts_machines_that_cannot_close(nominal):
    # CD +/-12 mm: B-C-D cannot close on about a sixth of the machines (fewer once beta is
    # re-optimised); every one is counted under its reason and dyad
    wild = ToleranceSet("wild", (Tolerance("CD", -12.0, 12.0), Tolerance("LF", -0.05, 0.05)))
    res = needle_sobol(nominal, wild, 64, seed=1)
    counts = res.counts()
    assert set(counts) == {"fixed_beta", "adjusted_beta"}
    for case, c in counts.items():
        failures = sum(v for k, v in c.items() if k not in (
            "rows", "assembled", "failed_groups", "base_samples", "complete_base_samples"))
        assert c["rows"] == c["assembled"] + failures == res.model_runs == 64 * 4
        assert c["cannot_close"] > 0 and res.failed[case] == failures
        assert c["complete_base_samples"] == res.complete[case] < 64
        assert sum(c["failed_groups"].values()) == failures - c.get("unexplained", 0)
        assert set(c["failed_groups"]) <= {f"{s} at {d}" for s in ("cannot_close", "dead_point")
                                           for d in ("L-M-A", "B-C-D")}
    # CD alone decides whether a machine assembles, LF (+/-0.05 mm) hardly
    feas = res.feasibility.set_index(["case", "param"])
    for case in counts:
        assert feas.loc[(case, "CD"), "ST"] > 0.9 > 0.05 > feas.loc[(case, "LF"), "ST"]
    assert np.isfinite(res.to_dataframe()[["S1", "ST", "S1_given"]].to_numpy()).all()


def test_file_sobol_counts_the_rod_that_cannot_reach(tmp_path):
    # L = 10.5 + dL, r = 10 + dr: the rod cannot reach the guide at q = 90 deg when L < r, i.e.
    # dL - dr < -0.5; P(assembles | dr) = (1.5 - dr) / 2, P(assembles | dL) = (dL + 0.8) / 0.6
    # clipped to [0, 1]
    mech = load(FILE, {"L": 10.5})
    wide = ToleranceSet("wide", (Tolerance("r", -0.3, 0.3), Tolerance("L", -1.0, 1.0)))
    res = so.sobol(mech, wide, "stroke_mm", 1024, seed=2)
    c = res.counts()["stroke_mm"]
    assert c["rows"] == c["assembled"] + c["cannot_close"] == 1024 * 4
    assert c["failed_groups"] == {"cannot_close at J": c["cannot_close"]} and c["cannot_close"]
    u = (np.arange(4000) + 0.5) / 4000
    g_r, g_l = (1.5 - (-0.3 + 0.6 * u)) / 2, np.clip((-1 + 2 * u + 0.8) / 0.6, 0, 1)
    (s1_r, st_r), (s1_l, st_l) = _indicator_of_sum(g_r, g_l)
    feas = res.feasibility.set_index("param")
    _within(feas["S1"], feas["S1_conf"], [s1_r, s1_l])
    _within(feas["ST"], feas["ST_conf"], [st_r, st_l])
    # stroke = 2 r on every machine that assembles: r explains it all (S1 = 1), and L its
    # share through the dependence the cut makes (a short rod only assembles with a short
    # crank): Var(E[2 r | L]) / Var(2 r) over the machines that assemble, by quadrature
    dr, dl = -0.3 + 0.6 * u, -1 + 2 * u
    ok = dl[None, :] - dr[:, None] >= -0.5  # [dr, dL]
    y = 2 * dr[:, None] * np.ones_like(ok)
    w = ok / ok.sum()
    ey = np.sum(w * y)
    per_l = ok.sum(0)
    m_l = (ok * y).sum(0) / np.maximum(per_l, 1)
    s1_l = np.sum(per_l / ok.sum() * (m_l - ey) ** 2) / (np.sum(w * y**2) - ey**2)
    f = res.to_dataframe().set_index("param")
    _within(f.loc["L", "S1_given"], f.loc["L", "S1_given_conf"], s1_l)
    # r's bootstrap interval is ~1e-4 wide; the bins cost a linear response about 1/bins^2 of
    # its variance (36 bins here)
    assert f.loc["r", "S1_given"] == pytest.approx(1.0, abs=2e-3)
    assert 0.05 < s1_l < 0.1
    # the CLI: the same counts in the JSON, the outcomes and feasibility in the study folder
    tol = tmp_path / "wide.toml"
    tol.write_text("[sets.wide]\nr = { plus_minus = 0.3 }\nL = { plus_minus = 1.0 }\n")
    code, out, err = run("run", FILE, "sobol", "--set", "L=10.5", "--tolerances", str(tol),
                         "--n", "1024", "--seed", "2", "--format", "json", "--out",
                         str(tmp_path / "study"))
    assert code == 0, err
    obj = strict_loads(out)
    assert obj["assembly"]["counts"] == strict_loads(strict_json(res.counts()))
    assert (tmp_path / "study" / "outcomes.csv").exists()
    assert (tmp_path / "study" / "feasibility.csv").exists()


def strict_json(obj):
    from sewtol.io import to_json

    return to_json(obj)


def _needle_design(nominal, n, seed, second_order):
    """SumDelta (beta fixed) of the needle on a Sobol design of the base tolerances."""
    from sewtol.tables.needle_208 import OUTPUT, as_mechanism
    from sewtol.tolerances import needle_set

    problem = so.problem_of(needle_set("base"))
    X = so.sample(problem, n, seed, second_order)
    (y,) = so.case_values(as_mechanism(nominal), OUTPUT, {OUTPUT: None}, problem["names"], X)
    return problem, X, y


# cells None: one block; 3: blocks of 3 columns; 5: of 5, the last column joining a block
@pytest.mark.parametrize(("cells", "seed", "second_order"),
                         [(None, 0, False), (3, 11, False), (3, 0, True), (5, 11, True)])
def test_blocked_bootstrap_is_salibs_analysis_bit_for_bit(nominal, monkeypatch, cells, seed,
                                                          second_order):
    """The bootstrap over blocks of resample columns (bounded memory) gives SALib's analyze
    exactly: point indices and intervals of S1, ST, S2 at n and n/2, and of the indicator
    "assembles"; on Ishigami and on the needle, seed 0 (mapped by so._salib_seed's rule) and
    another. cells: BOOTSTRAP_CELLS as a multiple of n (blocks of that many columns)."""
    n, resamples = 64, 41  # 41 = 13 blocks of 3 + 2; = 8 blocks of 5 + 1, the 1 joined
    needle = _needle_design(nominal, n, seed, second_order)
    x_ishigami = so.sample(PROBLEM, n, seed, second_order)
    for problem, X, y in (needle, (PROBLEM, x_ishigami, ishigami(x_ishigami))):
        step = so.rows_per_sample(problem["num_vars"], second_order)
        fail = np.zeros(len(X), bool)
        fail[::7] = True  # some rows fail: the indices of "assembles" too
        for m in (n // 2, n):
            monkeypatch.setattr(so, "BOOTSTRAP_CELLS",
                                so.BOOTSTRAP_CELLS if cells is None else cells * m)
            for values, feasibility in ((y, False), (np.where(fail, np.nan, y), True)):
                c = so.case_indices(problem, X[: m * step], values[: m * step], m, seed,
                                    resamples=resamples, second_order=second_order)
                got = (c.feasibility if feasibility else
                       c.indices[c.indices["n"] == m].reset_index(drop=True))
                ref = sobol_analyze.analyze(
                    problem, (~fail if feasibility else y)[: m * step].astype(float),
                    calc_second_order=second_order, num_resamples=resamples,
                    conf_level=0.95, seed=so._salib_seed(seed))
                for k in ("S1", "S1_conf", "ST", "ST_conf"):
                    assert np.array_equal(got[k].to_numpy(), ref[k]), (k, m, feasibility)
                if second_order and not feasibility:
                    iu = np.triu_indices(problem["num_vars"], 1)
                    assert np.array_equal(c.pairs["S2"].to_numpy(), ref["S2"][iu])
                    assert np.array_equal(c.pairs["S2_conf"].to_numpy(), ref["S2_conf"][iu])


def test_s1_given_draws_its_resamples_one_at_a_time_as_the_rows_of_one_draw():
    """_given_s1 draws each resample when it uses it, again for each input: numpy gives the rows
    of one (resamples, blocks) draw, so the intervals are those of the draw held whole."""
    for blocks, seed in ((37, so._salib_seed(0)), (2**15 + 3, 11), (2**17, 2026)):
        whole = np.random.default_rng(seed).integers(blocks, size=(20, blocks))
        rng = np.random.default_rng(seed)
        assert all(np.array_equal(row, rng.integers(blocks, size=blocks)) for row in whole)


def test_salibs_resamples_drawn_as_int32_are_its_int64_draws():
    """_analyze holds SALib's r as int32: numpy draws integers below 2**32 by one 32-bit path
    whatever the dtype, so the same generator gives the same numbers."""
    for n, seed in ((4096, so._salib_seed(0)), (2**15 + 3, 11), (2**17, 2026)):
        assert np.array_equal(np.random.default_rng(seed).integers(n, size=(n // 64, 200)),
                              np.random.default_rng(seed).integers(n, size=(n // 64, 200),
                                                                   dtype=np.int32))
