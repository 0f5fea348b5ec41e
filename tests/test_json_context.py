"""Every study's --format json is an object with a `context` block (tolerance set, seed, n,
strategy; the needle's also frame and guide), and --plot FILE on every table-shaped study."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run, strict_loads

ROOT = Path(__file__).resolve().parents[1]
SLIDER = str(ROOT / "tests" / "data" / "crank_slider.toml")
NEEDLE_FILE = str(ROOT / "examples" / "needle_208.toml")

# (argv, expected context: tolerances, seed, n, strategy); None where the study draws nothing
NEEDLE = [
    (("scan",), ("base", None, None, "beta")),
    (("scan", "--adjust", "beta,guide_shift_um"), ("base", None, None, "beta+guide_shift_um")),
    (("montecarlo", "--n", "20", "--seed", "3"), ("base", 3, 20, "beta")),
    (("montecarlo", "--n", "20", "--seed", "3", "--adjust", "beta,guide_shift_um"),
     ("base", 3, 20, "beta+guide_shift_um")),
    (("sobol", "--n", "16", "--seed", "4"), ("base", 4, 16, "beta")),
    (("sobol", "--n", "16", "--seed", "4", "--second-order"), ("base", 4, 16, "beta")),
    (("strategies", "--n", "6", "--seed", "5"), ("base", 5, 6, None)),
    (("guides", "--n", "20", "--seed", "6"), ("base", 6, 20, "beta")),
    (("allocation", "--n", "50", "--seed", "7", "--target", "0.5"), ("base", 7, 50, "beta")),
    (("worst-case",), ("base", None, None, "beta")),
    (("ppm", "--budget", "200", "--target", "0.1", "--seed", "8"), ("base", 8, None, "beta")),
]
# `feed STUDY` is `run feed_131 STUDY`: run's context, on the file's first set (links)
FEED = [
    (("scan",), ("links", None, None, "none")),
    (("montecarlo", "--n", "40", "--seed", "3", "--tolerances", "assumed"),
     ("assumed", 3, 40, "none")),
    (("sobol", "--n", "16", "--seed", "4"), ("links", 4, 16, "none")),
]
RUN = [
    ((SLIDER, "nominal"), (None, None, None, "none")),
    ((SLIDER, "scan"), ("normal", None, None, "none")),
    ((SLIDER, "worst-case", "--adjust", "rod"), ("normal", None, None, "rod")),
    ((SLIDER, "montecarlo", "--n", "20", "--seed", "3"), ("normal", 3, 20, "none")),
    ((SLIDER, "sobol", "--n", "16", "--seed", "4"), ("normal", 4, 16, "none")),
    ((SLIDER, "ppm", "--n", "200", "--limit", "20.1", "--target", "0.1", "--seed", "5"),
     ("normal", 5, 200, "none")),
    ((SLIDER, "allocation", "--n", "50", "--limit", "20.1", "--seed", "6"),
     ("normal", 6, 50, "none")),
]


def _context_of(argv):
    code, out, err = run(*argv, "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    assert isinstance(obj, dict) and isinstance(obj.get("context"), dict), argv
    return obj, obj["context"]


def _check(ctx, expected):
    tolerances, seed, n, strategy = expected
    assert {"tolerances", "seed", "n", "strategy"} <= set(ctx)
    assert ctx["tolerances"] == tolerances and ctx["seed"] == seed and ctx["n"] == n
    if strategy is not None:
        assert ctx["strategy"] == strategy


@pytest.mark.parametrize("argv,expected", NEEDLE, ids=[" ".join(a) for a, _ in NEEDLE])
def test_every_needle_study_json_carries_its_context(argv, expected):
    obj, ctx = _context_of(("needle", *argv, "--frame", "window", "--guide-shift-um", "5"))
    _check(ctx, expected)
    assert ctx["frame"] == "window" and ctx["guide_shift_um"] == 5.0
    from sewtol.mechanisms.needle_208.model import Needle208

    # the guide's angle parameter of that frame (about 20 deg off vertical)
    assert ctx["guide_angle_deg"] == float(Needle208.nominal("window").guide_angle)
    assert abs(abs(ctx["guide_angle_deg"]) - 20.0) < 0.01
    if argv[0] == "strategies":  # every strategy compared, in the table's order
        assert ctx["strategy"] == [r["strategy"] for r in obj["rows"]]
        assert ctx["strategy"][:2] == ["none", "beta"]
    if argv[0] == "sobol":  # one shape with and without --second-order
        assert len(obj["indices"]) == 12 and obj["n"] == 16
        assert ("second_order" in obj) == ("--second-order" in argv)
    if argv[0] == "scan":
        assert [(r["param"], r["side"]) for r in obj["rows"]][:2] == [("LF", "upper"),
                                                                    ("LF", "lower")]


@pytest.mark.parametrize("argv,expected", FEED, ids=[" ".join(a) for a, _ in FEED])
def test_every_feed_study_json_carries_its_context(argv, expected):
    _, ctx = _context_of(("feed", *argv, "--set", "b=25"))
    _check(ctx, expected)
    assert ctx["mechanism"] == "feed_131" and ctx["mechanism_file"] == "feed_131"


@pytest.mark.parametrize("argv,expected", RUN, ids=[" ".join(a[1:]) for a, _ in RUN])
def test_every_run_study_json_carries_its_context(argv, expected, tmp_path):
    obj, ctx = _context_of(("run", *argv, "--out", str(tmp_path / "o")))
    _check(ctx, expected)
    assert ctx["mechanism"] == "crank_slider" and ctx["mechanism_file"] == SLIDER
    # the file in --out is the printed object, context included
    name = argv[1].replace("-", "_") + ".json"
    assert strict_loads((tmp_path / "o" / name).read_text()) == obj


def test_needle_nominal_json_names_its_frame_guide_and_range():
    obj, ctx = _context_of(("needle", "nominal", "--frame", "window", "--guide-shift-um", "5",
                            "--beta-range", "15", "30", "--limit-um", "12"))
    _check(ctx, (None, None, None, "beta"))
    assert ctx["frame"] == "window" and ctx["guide_shift_um"] == 5.0
    assert ctx["beta_search_range_deg"] == [15.0, 30.0] and ctx["limit_um"] == 12.0
    assert obj["beta_search_range_deg"] == [15.0, 30.0]


def test_the_needle_fast_path_of_run_carries_the_needle_context():
    _, ctx = _context_of(("run", NEEDLE_FILE, "montecarlo", "--n", "20", "--seed", "3"))
    _check(ctx, ("base", 3, 20, "beta"))
    assert ctx["frame"] == "sewtol-0.1" and ctx["guide_shift_um"] == 0.0


PLOTS = [
    ("needle", "scan"),
    ("needle", "strategies", "--n", "6"),
    ("needle", "guides", "--n", "20"),
    ("needle", "worst-case"),
    ("needle", "allocation", "--n", "100"),
]


@pytest.mark.parametrize("argv", PLOTS, ids=" ".join)
def test_plot_writes_each_study_figure_as_png_and_svg(argv, tmp_path):
    texts = {}
    for suffix, magic in ((".png", b"\x89PNG"), (".svg", b"<?xml")):
        path = tmp_path / f"fig{suffix}"
        code, out, err = run(*argv, "--format", "json", "--plot", str(path))
        assert code == 0, err
        data = path.read_bytes()
        assert len(data) > 5000 and data.startswith(magic)
        texts[suffix] = out
    # the figure changes nothing printed
    assert texts[".png"] == texts[".svg"]


def test_plot_draws_the_scan_rows_it_prints(tmp_path):
    """The scan figure's bars are the printed total_um at each limit (upper, then lower)."""
    import matplotlib.pyplot as plt
    import pandas as pd

    from sewtol.cli.common import scan_figure

    code, out, _ = run("needle", "scan", "--format", "json")
    rows = strict_loads(out)["rows"]
    frame = pd.DataFrame(rows)
    fig, ax = plt.subplots()
    scan_figure(frame, "total_um", ax, "SumDelta", 10.0)
    heights = [p.get_height() for p in ax.patches]
    upper = [r["total_um"] for r in rows if r["side"] == "upper"]
    lower = [r["total_um"] for r in rows if r["side"] == "lower"]
    assert heights == pytest.approx(upper + lower, abs=1e-12)
    plt.close(fig)


def test_allocation_plot_draws_the_printed_widths():
    import matplotlib.pyplot as plt
    import pandas as pd

    from sewtol.cli.needle import allocation_figure

    code, out, err = run("needle", "allocation", "--n", "100", "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    table = pd.DataFrame(obj["rows"])
    fig, ax = plt.subplots()
    allocation_figure(table, obj["tolerances"], obj["target"], ax)
    heights = [p.get_height() for p in ax.patches]
    ref = [1000 * (r["reference_upper_mm"] - r["reference_lower_mm"]) for r in obj["rows"]]
    got = [1000 * (r["upper_mm"] - r["lower_mm"]) for r in obj["rows"]]
    assert heights == pytest.approx(ref + got, rel=1e-12)
    plt.close(fig)



@pytest.mark.parametrize("argv, key", [
    (("needle", "deviation", "--step-deg", "30", "--frame", "window", "--set", "AB=10.01",
      "--guide-shift-um", "4"), "rows"),
    (("feed", "trajectory", "--step-deg", "30", "--set", "b=20"), "rows"),
    (("feed", "regulator", "--b-range", "0", "40", "20", "--set", "b=20"), "rows"),
    (("feed", "metrics", "--set", "b=20"), None),
], ids=["needle deviation", "feed trajectory", "feed regulator", "feed metrics"])
def test_single_machine_json_names_its_machine_and_keeps_the_csv_rows(argv, key):
    import io

    import pandas as pd

    code, out, err = run(*argv, "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    ctx = obj["context"]
    if argv[0] == "needle":
        assert ctx["frame"] == "window" and ctx["guide_shift_um"] == 4.0
        assert ctx["set"] == {"AB": 10.01} and ctx["step_deg"] == 30.0
        assert ctx["mechanism"] == "208 needle drive" and "beta_deg" in ctx
    else:
        assert ctx["set"] == {"b": 20.0} and ctx["b_deg"] == 20.0
        assert ctx["mechanism"] == "131-42+3 feed"
    if key is None:
        return
    code, text, _ = run(*argv, "--format", "csv")
    frame = pd.read_csv(io.StringIO(text))
    assert list(frame.columns) == list(obj[key][0])
    np_rows = pd.DataFrame(obj[key])
    assert len(np_rows) == len(frame)
    # the CSV prints each unit at its resolution (mm to 1e-7, um to 1e-6, ...): half a unit of
    # the coarsest printed place
    assert np.allclose(np_rows.to_numpy(float), frame.to_numpy(float), rtol=0, atol=5.1e-7,
                       equal_nan=True)


FOUR_BAR = "examples/four_bar.toml"
FILE_PLOTS = {"scan": ("--adjust", "frame"), "montecarlo": ("--n", "200", "--adjust", "frame"),
              "sobol": ("--n", "32", "--seed", "4")}


@pytest.mark.parametrize("study", list(FILE_PLOTS))
def test_a_file_mechanisms_figure_is_the_same_on_a_rerun(study, tmp_path):
    from pathlib import Path

    file = str(Path(__file__).parents[1] / FOUR_BAR)
    for suffix, magic in ((".svg", b"<?xml"), (".png", b"\x89PNG")):
        paths = [tmp_path / f"{k}{suffix}" for k in "ab"]
        for path in paths:
            code, _, err = run("run", file, study, *FILE_PLOTS[study], "--plot", str(path))
            assert code == 0, err
        a, b = (p.read_bytes() for p in paths)
        assert a == b and a.startswith(magic)


def _drawn(monkeypatch, study, *argv):
    """The printed JSON of `run four_bar STUDY ARGV --plot` and the figure it saves."""
    from pathlib import Path

    import sewtol.cli.run as R

    figs = []
    monkeypatch.setattr(R, "save_figure", lambda args, fig: figs.append(fig))
    file = str(Path(__file__).parents[1] / FOUR_BAR)
    code, out, err = run("run", file, study, *argv, "--format", "json", "--plot", "x.svg")
    assert code == 0, err
    assert len(figs) == 1
    return strict_loads(out), figs[0]


def test_the_file_scan_figure_draws_the_printed_changes(monkeypatch):
    """A panel per output (the adjusted case its own), its bars the printed change at each
    tolerance's upper limits, then its lower ones."""
    obj, fig = _drawn(monkeypatch, "scan", *FILE_PLOTS["scan"])
    outputs = list(dict.fromkeys(r["output"] for r in obj["rows"]))
    assert outputs == ["rocker_swing_deg", "rocker_swing_deg_adjusted"]
    assert len(fig.axes) == len(outputs)
    for ax, name in zip(fig.axes, outputs, strict=True):
        rows = [r for r in obj["rows"] if r["output"] == name]
        want = [r["change"] for side in ("upper", "lower") for r in rows if r["side"] == side]
        assert [p.get_height() for p in ax.patches] == pytest.approx(want, abs=1e-12)
        assert ax.get_title().startswith(name + ":")


def test_the_file_montecarlo_figure_counts_every_machine(monkeypatch):
    """A panel per case (fixed, adjusted), the report's histogram: the legend's machines in
    range, beyond it and that cannot run add up to n (the bars hold those in range; the printed
    failures are those that cannot run), the dashed line is the spec's upper limit, 46.1 deg."""
    obj, fig = _drawn(monkeypatch, "montecarlo", *FILE_PLOTS["montecarlo"])
    assert obj["cases"] == ["fixed_frame", "adjusted_frame"] and len(fig.axes) == 2
    for ax, case in zip(fig.axes, obj["cases"], strict=True):
        counts = [int(t.get_text().split()[0]) for t in ax.get_legend().get_texts()[:3]]
        assert sum(counts) == obj["counts"][case]["n"] == 200
        assert sum(p.get_height() for p in ax.patches) == counts[0]
        assert counts[2] == obj["counts"][case]["failed"]
        assert [line.get_xdata()[0] for line in ax.get_lines() if len(line.get_xdata())] \
            == [46.1]
    assert obj["counts"]["fixed_frame"]["out_of_spec"] > 0  # the limit cuts the fixed panel


def test_the_file_sobol_figure_draws_the_printed_indices(monkeypatch):
    obj, fig = _drawn(monkeypatch, "sobol", *FILE_PLOTS["sobol"])
    (ax,) = fig.axes
    rows = obj["rows"]
    want = [r["S1"] for r in rows] + [r["ST"] for r in rows]
    assert [p.get_height() for p in ax.patches] == pytest.approx(want, abs=1e-12)
