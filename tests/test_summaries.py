"""sewtol.studies.summaries: the tables of several outputs, generic over mechanisms. They give
the feed report's committed numbers, and the same tables on another mechanism equal their
definitions computed by hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cli_helpers import study_script
from sewtol.errors import ParameterError
from sewtol.mechanism import load
from sewtol.mechanisms import mechanism_file
from sewtol.studies import summaries as SU
from sewtol.studies.montecarlo import contributors, montecarlo
from sewtol.studies.sobol import sobol

REPORT = Path(__file__).parents[1] / "reports" / "feed_131-42-3"


def _report():
    """studies/feed_131_report.py, which wrote REPORT: its outputs and tables."""
    return study_script("feed_131_report")


def _committed(name: str) -> pd.DataFrame:
    return pd.read_csv(REPORT / f"{name}.csv", comment="#")


def test_feed_summary_contributors_and_screening_are_the_committed_report():
    # the report's run: seed 2026, 2000 machines of the file's assumed set
    T = _report()
    mech = T.feed_file()
    ts = mech.tolerance_sets["assumed"]
    mc = T.montecarlo(mech, ts, 2000, 2026)
    got = SU.output_summary(mc, T.OUTPUTS)
    ref = _committed("montecarlo")
    assert list(got.columns) == list(ref.columns)
    assert list(got["output"]) == list(ref["output"])
    assert (got[["n", "failed"]].to_numpy() == ref[["n", "failed"]].to_numpy()).all()
    # the CSV prints 9 significant digits
    num = ["mean", "std", "p1", "p99", "min", "max"]
    np.testing.assert_allclose(got[num].to_numpy(float), ref[num].to_numpy(float), rtol=1e-8)
    contrib = SU.contributor_table(mc, ts, T.CONTRIBUTOR_OUTPUTS)
    ref = _committed("contributors")
    assert list(contrib["output"]) == list(ref["output"])
    assert list(contrib["param"]) == list(ref["param"])
    np.testing.assert_allclose(contrib["variance_pct"], ref["variance_pct"], rtol=1e-8,
                               atol=1e-9)
    # the tolerances each output's Sobol indices ran over (sobol.md's header)
    header = (REPORT / "sobol.md").read_text()
    for output in T.SOBOL_OUTPUTS:
        names = SU.important_parameters(mc, ts, output)
        assert f"- parameters of {output}: {', '.join(names)}\n" in header


def _rocker():
    mech = load(mechanism_file("spatial_crank_rocker"))
    return mech, mech.tolerance_sets["illustrative"]


def test_output_summary_on_another_mechanism_is_its_definition():
    mech, ts = _rocker()
    res = montecarlo(mech, ts, 400, 11)
    m = res.machines
    outputs = ["rocker_swing_deg", "transmission_min_deg"]
    levels = (0.00135, 0.5, 0.99865)
    f = SU.output_summary(m, outputs, levels).set_index("output")
    assert [SU.quantile_column(q) for q in levels] == ["p0.135", "p50", "p99.865"]
    for k in outputs:
        v = m[k].dropna().to_numpy()
        assert f.loc[k, "n"] == 400 and f.loc[k, "failed"] == 400 - v.size
        assert f.loc[k, "mean"] == pytest.approx(v.mean(), rel=1e-14)
        assert f.loc[k, "std"] == pytest.approx(v.std(ddof=1), rel=1e-12)
        for q in levels:
            assert f.loc[k, SU.quantile_column(q)] == pytest.approx(np.quantile(v, q),
                                                                    rel=1e-14)
        assert (f.loc[k, "min"], f.loc[k, "max"]) == (v.min(), v.max())
    # a mask leaves machines out of the statistics and counts them as failed
    keep = np.arange(400) % 2 == 0
    half = SU.output_summary(m, outputs, levels, ok=keep,
                             nominal={k: 1.0 for k in outputs}).set_index("output")
    v = m["rocker_swing_deg"].to_numpy()[keep]
    assert half.loc["rocker_swing_deg", "failed"] == 400 - np.isfinite(v).sum()
    assert half.loc["rocker_swing_deg", "p50"] == pytest.approx(np.nanmedian(v), rel=1e-14)
    assert list(half.columns[:3]) == ["nominal", "n", "failed"]
    with pytest.raises(ParameterError, match="levels: must be quantile levels"):
        SU.output_summary(m, outputs, (1.5,))


def test_contributors_and_screening_on_another_mechanism():
    mech, ts = _rocker()
    m = montecarlo(mech, ts, 400, 5).machines
    outputs = ["rocker_swing_deg", "rocker_max_deg"]
    table = SU.contributor_table(m, ts, outputs, top=3)
    for k in outputs:
        block = table[table["output"] == k]
        single = contributors(m, ts.active().params, k)
        # the top 3 in eta^2's order, then the sum over every tolerance and the remainder
        assert list(block["param"])[:3] == list(single["param"])[:3] and len(block) == 5
        assert block["variance_pct"].iloc[3] == pytest.approx(single["variance_pct"].sum(),
                                                              rel=1e-14)
        np.testing.assert_allclose(block["variance_pct"].iloc[:3],
                                   single["variance_pct"].iloc[:3], rtol=1e-14)
        # what single tolerances explain plus the interaction remainder is the whole variance
        assert block["variance_pct"].iloc[-2:].sum() == pytest.approx(100.0, abs=1e-9)
        chosen = SU.important_parameters(m, ts, k, share=0.5, min_params=2, max_params=3)
        assert 2 <= len(chosen) <= 3 and chosen == list(single["param"])[:len(chosen)]
        # cumulative share reached: the shortest prefix holding half (or the floor of 2)
        cum = single["cumulative_pct"].to_numpy()
        assert len(chosen) == min(max(int(np.searchsorted(cum, 50.0)) + 1, 2), 3)


def test_screened_sobol_is_sobol_on_each_outputs_screened_set():
    mech, ts = _rocker()
    m = montecarlo(mech, ts, 300, 2).machines
    outputs = ("rocker_swing_deg", "rocker_max_deg")
    res, chosen = SU.screened_sobol(mech, ts, outputs, 16, 9, m, min_params=2, max_params=3)
    assert list(res.convergence["case"]) == list(outputs)
    for k in outputs:
        assert chosen[k] == SU.important_parameters(m, ts, k, min_params=2, max_params=3)
        sub = type(ts)(ts.name, tuple(t for t in ts.items if t.param in chosen[k]),
                       ts.description)
        one = sobol(mech, sub, k, 16, 9)
        got = res.indices[res.indices["case"] == k].reset_index(drop=True)
        pd.testing.assert_frame_equal(got, one.indices)
        assert res.convergence.set_index("case").loc[k, "params"] == len(chosen[k])
        assert res.failed[k] == one.failed[k]
    with pytest.raises(ParameterError, match="output: must be one of"):
        SU.screened_sobol(mech, ts, ("nope",), 16, 9, m)
