"""The HTML report and the report figures: conclusions first, every table of the Markdown report
in the HTML one, every image embedded, "µm" in every label, histograms that drop nothing."""

from __future__ import annotations

import base64
import json
import re
import shutil
from pathlib import Path

import matplotlib

from cli_helpers import study_script

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402
from matplotlib.patches import Rectangle, StepPatch  # noqa: E402

from sewtol.reports import html as rh  # noqa: E402
from sewtol.reports import plots  # noqa: E402
from sewtol.reports.tables import to_markdown  # noqa: E402


def figure_texts(fig) -> list[str]:
    """Every string a reader sees on a figure: titles, axis labels, tick labels, legend entries,
    annotations (what the label tests check instead of pixels)."""
    out = [t.get_text() for t in fig.texts]
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        out += [ax.get_title(loc) for loc in ("left", "center", "right")]
        out += [ax.get_xlabel(), ax.get_ylabel()]
        out += [t.get_text() for t in ax.get_xticklabels() + ax.get_yticklabels()]
        out += [t.get_text() for t in ax.texts]
        leg = ax.get_legend()
        if leg is not None:
            out += [t.get_text() for t in leg.get_texts()]
            out.append(leg.get_title().get_text())
    return [t for t in out if t]


ROOT = Path(__file__).resolve().parents[1]
COMMITTED = ROOT / "reports" / "needle_208"
# "um" as a unit in a label: not inside a word or an identifier (guide_shift_um, "number")
UM_LABEL = re.compile(r"(?<![A-Za-z_])um(?![A-Za-z_])")


def _script(name: str):
    return study_script(name)


@pytest.fixture(scope="module")
def needle_report(tmp_path_factory):
    """The index and report.html made from a copy of the committed needle tables and figures."""
    if not (COMMITTED / "run.json").exists():
        pytest.skip("no committed needle report to index")
    out = tmp_path_factory.mktemp("reports")
    shutil.copytree(COMMITTED, out / "needle_208",
                    ignore=shutil.ignore_patterns("index.md", "report.html", "*.svg", "*.pdf"))
    _script("needle_208_index").main(["--out", str(out)])
    folder = out / "needle_208"
    return folder, (folder / "index.md").read_text(), (folder / "report.html").read_text()


def _conclusions(page: str) -> str:
    body = page[page.index('<section class="conclusions"'):]
    return body[:body.index("</section>")]


def test_html_opens_with_the_headline_then_the_conclusions_taken_from_the_tables(needle_report):
    folder, index_md, page = needle_report
    body = page[page.index("<body>"):]
    headings = re.findall(r"<h2>([^<]*)</h2>", body)
    assert headings[0] == "Conclusions"
    assert body.index('id="headline"') < body.index('id="conclusions"') < body.index("<table")
    # the headline's three lines are the first three lines of index.md after its title
    first = [x for x in index_md.splitlines()[1:] if x.strip()][:3]
    assert [x.split("**")[1] for x in first] == ["Yield", "What to do", "Frame"]
    st = pd.read_csv(folder / "strategies.csv", comment="#")
    other = pd.read_csv(folder / "strategies_frames.csv", comment="#")
    base = st[st.tolerances == "base"].set_index("strategy")
    beta = base.loc["beta"]
    # the yield: the designed machine (beta adjusted), with its interval and n
    assert (f"{100 * beta['yield']:.1f} % of machines meet SumDelta ≤ 10 µm (95 % interval "
            f"{100 * beta.yield_ci_low:.1f}–{100 * beta.yield_ci_high:.1f} %, n = {beta.n}"
            in first[0])
    # the recommendation: the realistic strategy best on its worst frame, recomputed here
    every = pd.concat([st.assign(frame="sewtol-0.1"), other])
    every = every[(every.tolerances == "base") & ~every.strategy.str.endswith(" exact")]
    worst = every.groupby("strategy")["yield"].min()
    best = worst.idxmax()
    rec = base.loc[best]
    assert f"(strategy {best}): {100 * beta['yield']:.1f} % → {100 * rec['yield']:.1f} %" in first[1]
    assert "normal sd 0.01 deg" in first[1] and "idealisation" in first[1]
    exact = base.loc["beta+shift+angle exact", "yield"]
    assert (f"beta+shift+angle gives {100 * base.loc['beta+shift+angle', 'yield']:.1f} % at "
            f"that precision, {100 * exact:.1f} % only with every compensator set exactly"
            in first[1])
    # the frame: the range of the recommendation and of beta over every frame
    lo, hi = worst[best], every[every.strategy == best]["yield"].max()
    assert f"{best} {100 * lo:.1f}–{100 * hi:.1f} %" in first[2]
    # every strategy yield of the conclusions has the frame range beside it
    conclusions = _conclusions(body)
    for strategy, g in every.groupby("strategy"):
        assert (f"{strategy} {100 * base.loc[strategy, 'yield']:.1f} % (frames "
                f"{100 * g['yield'].min():.1f}–{100 * g['yield'].max():.1f} %)") in conclusions
    for verdict, cls in (("holds in every frame", "holds"), ("fails in every frame", "fails"),
                         ("frame-dependent", "dependent")):
        assert f'<span class="{cls}">{verdict}</span>' in conclusions
    assert "never lowers" not in conclusions


def test_every_table_of_the_markdown_report_is_in_the_html(needle_report):
    folder, index_md, page = needle_report
    linked = sorted(set(re.findall(r"\]\(([\w.+\-]+)\.md\)", index_md)))
    assert len(linked) >= 30
    for stem in linked:
        md = (folder / f"{stem}.md").read_text()
        start = page.index(f'<div class="table" id="{rh.anchor_of(stem)}">')
        block = page[start:page.index("</div>", start)]
        title = md.splitlines()[0].lstrip("# ").strip()
        assert rh._inline(title) in block, stem
        # every row of every pipe table (header + body, not the separator line)
        md_rows = [x for x in md.splitlines() if x.startswith("|") and not
                   re.fullmatch(r"\|[\s:|-]+\|", x.strip())]
        assert block.count("<tr>") == len(md_rows), stem


def test_every_image_is_embedded(needle_report):
    folder, index_md, page = needle_report
    srcs = re.findall(r'<img src="([^"]+)"', page)
    assert srcs, "no figure in the report"
    assert all(s.startswith("data:image/png;base64,") for s in srcs)
    assert not re.search(r'(src|href)="(https?:|file:|[\w./-]+\.(png|svg|pdf))', page)
    embedded = {base64.b64decode(s.split(",", 1)[1]) for s in srcs}
    figures = re.findall(r"!\[[^\]]*\]\(([\w.+\-]+\.png)\)", index_md)
    assert len(figures) == len(srcs) >= 10
    for name in figures:  # the Markdown index shows the same figures, byte for byte
        assert (folder / name).read_bytes() in embedded


def test_markdown_to_html_keeps_settings_and_rows():
    frame = pd.DataFrame({"param": ["AB", "BE"], "total_um": [1.25, 3.5]})
    md = to_markdown(frame, "Scan <limits>", {"seed": 2026, "guide": "fixed"})
    out = rh.markdown_to_html(md)
    assert "<h2>Scan &lt;limits&gt;</h2>" in out
    assert "<li>seed: 2026</li>" in out and out.count("<tr>") == 3
    long = to_markdown(pd.DataFrame({"x": range(50)}), "long")
    assert "<details><summary>50 rows" in rh.markdown_to_html(long, collapse_rows=40)


def _mc_axes(fixed, adjusted, top):
    fig, ax = plt.subplots()
    plots.montecarlo_histograms(fixed, adjusted, 10.0, (0.1, 0.2), ax, top_um=top)
    return fig, ax


def test_histogram_bars_overflow_and_failed_add_up_to_n():
    rng = np.random.default_rng(7)
    n = 1000
    fixed = rng.gamma(2.0, 15.0, n)
    adjusted = fixed * 0.8
    adjusted[:37] = np.nan  # 37 machines that cannot assemble
    fixed[:5] = np.inf
    top = 90.0
    fig, ax = _mc_axes(fixed, adjusted, top)
    steps = [p for p in ax.patches if isinstance(p, StepPatch)]
    bars = [p for p in ax.patches if isinstance(p, Rectangle) and p.get_hatch() == "//"]
    labels = [t.get_text() for t in ax.get_legend().get_texts()][:2]
    assert len(steps) == 2 and len(bars) == 2
    for values, step, bar, label in zip((fixed, adjusted), steps, bars, labels, strict=True):
        drawn = int(step.get_data().values.sum())
        overflow = int(round(bar.get_height()))
        failed, of_n = map(int, re.search(r"(\d+) failed of (\d+)", label).groups())
        assert drawn + overflow + failed == of_n == n
        assert overflow == int(np.sum(np.isfinite(values) & (values > top)))
        assert failed == int(np.sum(~np.isfinite(values)))
        assert f"{overflow} > {top:.0f}" in label
    plt.close(fig)


def test_beta_at_the_search_bounds_is_counted_and_drawn():
    beta = np.r_[np.full(14, 35.0), np.full(3, 10.0), np.linspace(12, 30, 83), np.nan]
    assert plots.at_bound(beta, (10.0, 35.0)) == (3, 14)
    fig, ax = plt.subplots()
    plots.beta_histogram(beta, (10.0, 35.0), ax)
    red = [p.get_height() for p in ax.patches if p.get_facecolor()[:3] == matplotlib.colors.
           to_rgb("C3")]
    assert sorted(red) == [3, 14]
    assert any("3 at 10, 14 at 35 deg" in t.get_text() for t in ax.get_legend().get_texts())
    plt.close(fig)


def _example_figures():
    """Every plot function of reports.plots, on data shaped like the reports'."""
    phi = np.arange(0.0, 360.0, 2.0)
    curve = pd.DataFrame({"phi_deg": phi, "d_um": 3 * np.sin(np.radians(2 * phi))})
    figs = []
    fig, ax = plt.subplots()
    plots.deviation_vs_crank({"beta* 22.6": curve}, ax, limit_um=10.0)
    figs.append(fig)
    fig, ax = plt.subplots()
    plots.sum_delta_vs_beta(np.arange(15, 30.0), np.linspace(20, 5, 15), 22.0, (19.0, 25.0),
                            10.0, ax)
    figs.append(fig)
    figs.append(plots.scan_deviation_grid(curve, {"AB": {"upper": curve, "lower": curve}},
                                          nominal_total_um=4.6))
    figs.append(_mc_axes(np.linspace(0, 120, 50), np.linspace(0, 90, 50), None)[0])
    fig, ax = plt.subplots()
    plots.sobol_bars(pd.DataFrame({"param": ["AB"], "S1": [0.5], "S1_conf": [0.1],
                                   "ST": [0.9], "ST_conf": [0.1]}), ax)
    figs.append(fig)
    traj = pd.DataFrame({"phi_deg": phi, "lower_x_mm": np.cos(np.radians(phi)),
                         "lower_y_mm": 32.5 + np.sin(np.radians(phi)),
                         "upper_x_mm": np.cos(np.radians(phi)),
                         "upper_y_mm": 32.5 - np.sin(np.radians(phi))})
    fig, ax = plt.subplots()
    plots.tooth_paths(traj, 32.5, 0.0, ax, phases={"lower": (10.0, 170.0),
                                                   "upper": (190.0, 350.0)})
    figs.append(fig)
    fig, axes = plt.subplots(2, 1)
    plots.feed_xy_vs_phi(traj, 32.5, axes, phases={"lower": (200.0, 20.0)})
    figs.append(fig)
    fig, ax = plt.subplots()
    sweep = pd.DataFrame({"b_deg": [-30.0, 0.0, 30.0, 70.0], "lower_step_mm": [np.nan, -3, 2, np.nan],
                          "upper_step_mm": [np.nan, -4, 2.5, np.nan]})
    plots.regulator_curve(sweep, 30.0, ax)
    figs.append(fig)
    return figs


def test_no_figure_label_says_um():
    texts = [t for fig in _example_figures() for t in figure_texts(fig)]
    plt.close("all")
    assert any("\u00b5m" in t for t in texts)
    assert not [t for t in texts if UM_LABEL.search(t)]


def test_the_report_scripts_figures_say_um(monkeypatch, tmp_path):
    """The labels the nominal report script adds itself (titles, legends) pass too."""
    seen = []

    def capture(fig, path, fmt=None):
        seen.extend(figure_texts(fig))
        plt.close(fig)
        return Path(path)

    monkeypatch.setattr(plots, "save", capture)
    _script("needle_208_nominal").main(["--out", str(tmp_path)])
    assert len(seen) > 20
    assert not [t for t in seen if UM_LABEL.search(t)]


def test_saved_figures_print_resolution_and_formats(tmp_path):
    from PIL import Image

    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([0, 1], [0, 1])
    png = plots.save(fig, tmp_path / "a.png")
    with Image.open(png) as im:
        assert round(im.info["dpi"][0]) == plots.FIGURE_DPI >= 200
    fig, ax = plt.subplots()
    svg = plots.save(fig, tmp_path / "a.png", "svg")
    assert svg.suffix == ".svg" and svg.read_text().lstrip().startswith("<?xml")
    fig, ax = plt.subplots()
    pdf = plots.save(fig, tmp_path / "b.png", "pdf")
    assert pdf.read_bytes()[:4] == b"%PDF" and (tmp_path / "b.png").exists()
    # SVG embeds inline, with no external reference
    page = rh.figure_html(rh.Figure("a", "x", svg.read_bytes(), "svg"))
    assert page.count("<svg") == 1 and "<?xml" not in page


def test_report_tolerances_from_a_file(tmp_path, capsys):
    from sewtol.errors import ParameterError
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.mechanisms.params import field_names
    from sewtol.tolerances import NEEDLE_208_SETS, resolve_all

    path = tmp_path / "my.toml"
    path.write_text("[sets.shop]\nAB = 0.01\nBE = {lower = -0.02, upper = 0.01}\n"
                    "[sets.supplier]\nCD = 0.005\n")
    valid = field_names(Needle208)
    assert list(resolve_all(None, NEEDLE_208_SETS, valid)) == list(NEEDLE_208_SETS)
    both = resolve_all([str(path)], NEEDLE_208_SETS, valid)
    assert list(both) == ["shop", "supplier"]
    assert both["shop"].items[1].lower == -0.02 and both["shop"].items[1].upper == 0.01
    one = resolve_all([f"{path}:supplier", "base"], NEEDLE_208_SETS, valid)
    assert list(one) == ["supplier", "base"] and one["supplier"].items[0].upper == 0.005
    with pytest.raises(ParameterError, match="names a set twice"):
        resolve_all([str(path), f"{path}:shop"], NEEDLE_208_SETS, valid)
    # the report script refuses a bad set before it runs anything: one line, exit 2
    rc = _script("needle_208_tolerances").main(["--out", str(tmp_path), "--tolerances",
                                                f"{path}:nope"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert "--tolerances" in err[0] and "no set 'nope'" in err[0] and "shop, supplier" in err[0]
    assert not (tmp_path / "needle_208").exists()


def test_strategies_in_chunks_are_the_strategies_in_one_piece():
    """The parallel path of the strategies report adjusts chunks of machines and concatenates
    them: machine by machine the same numbers as one piece (compared exactly)."""
    from sewtol.mechanisms.needle_208.compensators import default_strategies
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.protocol import machines
    from sewtol.studies import strategies as S
    from sewtol.tables.needle_208 import as_mechanism
    from sewtol.tolerances import NEEDLE_208_SETS

    mech = as_mechanism(Needle208.nominal())
    tol = NEEDLE_208_SETS["recommended"].active()
    values = machines(mech, tol.sample(np.random.default_rng(3), 30))
    chosen = [s for s in default_strategies() if s.name in ("beta", "beta+shift", "beta+CD")]
    args = ("SumDelta_um", True, {"limit_um": 10.0}, None)
    whole = S._chunk(mech, values, chosen, *args)
    windows = ((0, 7), (7, 19), (19, 30))
    parts = [S._chunk(mech, {k: v[a:b] for k, v in values.items()}, chosen, *args)
             for a, b in windows]
    for i, one in enumerate(whole):
        held = {}
        for (a, _), part in reversed(list(zip(windows, parts, strict=True))):  # any order
            S._put(held, vars(part[i]), a, 30)
        joined = S.Adjusted(**held)
        np.testing.assert_array_equal(joined.value, one.value)
        np.testing.assert_array_equal(joined.status, one.status)
        for key in ("settings", "at_bound", "extras"):
            for k, v in getattr(one, key).items():
                got = getattr(joined, key)[k]
                for name in (v if isinstance(v, dict) else {k: v}):
                    np.testing.assert_array_equal(*((got, v) if not isinstance(v, dict)
                                                    else (got[name], v[name])))


def test_feed_file_outputs_are_the_closed_form_for_each_output():
    """The feed studies evaluate the mechanism file, whose dog outputs (kind feed_dogs) are the
    closed form's: the same numbers, exactly, output by output and all together (including the
    machines that fail)."""
    from sewtol.mechanisms.feed_131 import analysis
    from sewtol.mechanisms.feed_131.model import Feed131
    from sewtol.protocol import machines

    tables = _script("feed_131_report")
    p = Feed131()
    mech = tables.feed_file()
    dev = mech.tolerance_sets["assumed"].sample(np.random.default_rng(11), 40)
    dev["O1A1"] = dev["O1A1"].copy()
    dev["O1A1"][:2] = 30.0  # an eccentric longer than the chain can take: two machines fail
    full = analysis.outputs(p, dev)
    assert np.isnan(full["lower_step_mm"][:2]).all()
    together = mech.evaluate(machines(mech, dev), tables.OUTPUTS)
    assert list(together.status[:2]) == ["cannot_close"] * 2
    for k in tables.OUTPUTS:
        alone = mech.evaluate(machines(mech, dev), [k]).outputs[k]
        np.testing.assert_array_equal(alone, full[k], err_msg=k)
        np.testing.assert_array_equal(together.outputs[k], full[k], err_msg=k)


def test_feed_conclusions_come_from_the_tables():
    folder = ROOT / "reports" / "feed_131-42-3"
    if not (folder / "readoff_explanations.csv").exists():
        pytest.skip("no committed feed report")
    mod = _script("feed_131_report")
    expl = pd.read_csv(folder / "readoff_explanations.csv", comment="#")
    found = {c.text.split(" feeds ")[0]: c for c in mod.reading_conclusions(expl) if c.verdict}
    for dog in ("lower", "upper"):
        made = expl[expl[f"{dog}_feeds"].notna()]  # pandas reads the table's n/a as NaN
        senses = set(made[f"{dog}_feeds"])
        c = found[f"the {dog} dog"]
        assert c.verdict == ("holds under every reading" if len(senses) == 1 else
                             "reading-dependent")
        assert f"under the {len(made)} explanations" in c.text
    contrib = pd.read_csv(folder / "contributors.csv", comment="#")
    sob = pd.read_csv(folder / "sobol.csv", comment="#")
    lines = mod.tighten_conclusions(contrib, sob)
    assert len(lines) == contrib["output"].nunique()
    top = contrib[contrib.output == "lower_step_mm"].iloc[0]
    share = top.variance_pct if "variance_pct" in contrib else top.share_pct
    assert lines[0].text.startswith(f"lower_step_mm: {top.param} {share:.1f} %")


def test_feed_pages_hold_every_table_and_figure(tmp_path):
    """The feed's index.md and report.html (write_pages) from a copy of the committed tables and
    figures: every table the index links is in the page, every figure embedded."""
    folder = ROOT / "reports" / "feed_131-42-3"
    if not (folder / "regulator.png").exists():
        pytest.skip("no committed feed report")
    out = tmp_path / "feed"
    shutil.copytree(folder, out, ignore=shutil.ignore_patterns("index.md", "report.html"))
    mod = _script("feed_131_report")
    conclusions = {"What holds": [rh.Conclusion("lower feeds forward",
                                                "holds under every reading")]}
    mod.write_pages(out, "intro", conclusions, {"seed": 2026})
    index_md, page = (out / "index.md").read_text(), (out / "report.html").read_text()
    assert re.findall(r"<h2>([^<]*)</h2>", page)[0] == "Conclusions"
    linked = set(re.findall(r"\]\(([\w.+\-]+)\.md\)", index_md))
    assert linked == {t for _, tables, _ in mod.SECTIONS for t in tables}
    for stem in linked:
        assert f'<div class="table" id="{rh.anchor_of(stem)}">' in page
    srcs = re.findall(r'<img src="([^"]+)"', page)
    assert len(srcs) == len(re.findall(r"!\[", index_md)) == 3
    for name in re.findall(r"!\[[^\]]*\]\(([\w.+\-]+\.png)\)", index_md):
        assert "data:image/png;base64," + base64.b64encode((out / name).read_bytes()).decode() \
            in srcs


def test_the_tolerance_report_figures_say_um(monkeypatch, tmp_path):
    """Scan panels, Monte-Carlo and Sobol figures as the tolerance script titles them (small n:
    the labels do not depend on it)."""
    seen = []

    def capture(fig, path, fmt=None):
        seen.extend(figure_texts(fig))
        plt.close(fig)
        return Path(path)

    monkeypatch.setattr(plots, "save", capture)
    rc = _script("needle_208_tolerances").main([
        "--out", str(tmp_path), "--n-mc", "64", "--n-sobol", "16", "--n-alloc", "32",
        "--n-guides", "16", "--tolerances", "base"])
    assert rc == 0
    assert any("\u03a3\u0394" in t for t in seen) and any("\u00b5m" in t for t in seen)
    assert not [t for t in seen if UM_LABEL.search(t)]


def test_inline_svgs_keep_their_ids_apart(tmp_path):
    svgs = []
    for name in ("a", "b"):
        fig, ax = plt.subplots()
        ax.plot([0, 1], [0, 1])
        svgs.append(rh.Figure(name, name, plots.save(fig, tmp_path / f"{name}.svg").read_bytes(),
                              "svg"))
    page = "\n".join(rh.figure_html(f) for f in svgs)
    ids = re.findall(r'\bid="([^"]+)"', page)
    assert len(ids) == len(set(ids)) > 4
    for ref in re.findall(r"url\(#([^)]+)\)", page):  # every reference finds its target
        assert ref in ids


def test_tighten_conclusions_rank_only_the_sets_tolerances_and_end_in_one_recommendation(
        needle_report):
    """Every set gets its eta^2 shares, its total Sobol indices, its largest S2 pair and its
    tightest single tolerances, each with the table's own numbers and only over the parameters
    the set tolerances (the base set has no CD); then one recommendation with the allocation's
    reached yield, its interval and n."""
    folder, index, _ = needle_report
    run = json.loads((folder / "run.json").read_text())
    section = index[index.index("## Which tolerances to tighten"):]
    section = section[:section.index("\n## ", 5)]
    items = [x for x in section.splitlines() if x.startswith("- ")]
    for name, line in zip(("base", "recommended"), items, strict=False):
        params = list(run["inputs"]["tolerance_sets"][name])
        assert line.startswith(f"- {name} tolerances ({', '.join(params)}; beta adjusted)")
        sob = pd.read_csv(folder / f"sobol_{name}.csv", comment="#")
        top = sob[sob["case"] == "adjusted_beta"].sort_values("ST", ascending=False).iloc[0]
        assert f"{top.param} {top.ST:.3f} ± {top.ST_conf:.3f}" in line
        s2 = pd.read_csv(folder / f"sobol_{name}_second_order.csv", comment="#")
        pair = s2[s2["case"] == "adjusted_beta"].sort_values("S2", ascending=False).iloc[0]
        assert f"S2({pair.param_i}, {pair.param_j}) = {pair.S2:.3f} ± {pair.S2_conf:.3f}" in line
        ranked = re.findall(r"\b([A-Z]{2}) (?:[0-9.]+ %|±|[0-9.]+ ±)", line)
        assert ranked and set(ranked) <= set(params), (name, ranked)
    assert "CD" not in items[0]
    assert len(items) == 3 and items[2].startswith("- **Recommendation**: tighten AB and BE")
    md = (folder / "allocation.md").read_text()
    achieved = float(re.search(r"achieved yield: ([0-9.]+)", md).group(1))
    n = int(re.search(r"Monte-Carlo, (\d+) machines", md).group(1))
    # the interval is the strategies table's Clopper-Pearson: same k, n, same bounds
    st = pd.read_csv(folder / "strategies.csv", comment="#")
    cp = _script("needle_208_index").clopper_pearson
    for r in st.head(4).itertuples():
        assert np.allclose(cp(r.ok, r.n), (r.yield_ci_low, r.yield_ci_high), atol=5e-5)
    lo, hi = cp(round(achieved * n), n)
    assert (f"it reached {100 * achieved:.1f} % (95 % interval {100 * lo:.1f}–{100 * hi:.1f} %"
            in items[2])
    assert f"n = {n}" in items[2]


def test_clearance_conclusions_come_from_the_tables(needle_report):
    folder, _, page = needle_report
    if not (folder / "clearance_share.csv").exists():
        pytest.skip("no committed clearance tables")
    conclusions = _conclusions(page)
    share = pd.read_csv(folder / "clearance_share.csv")
    for name, rows in share.groupby("tolerances"):
        r = rows.set_index("case")
        assert f"{name} tolerances, H7/g6" in conclusions
        assert f"{r.loc['links', 'yield']:.1%} of machines with ideal pins" in conclusions
        assert f"{r.loc['both', 'yield']:.1%} with the journals random" in conclusions
    guide = pd.read_csv(folder / "clearance_guide.csv")
    for r in guide.itertuples():
        strategy = "no adjustment" if r.strategy == "none" else r.strategy
        fit = "no fit rated" if r.tightest_fit_95pct_run == "none" else r.tightest_fit_95pct_run
        assert f"{r.tolerances}, {strategy}: {fit}" in conclusions
    assert f'id="{rh.anchor_of("clearances")}"' in page


def test_tooth_path_phase_labels_overlap_nothing():
    """The feed figure's phase labels (0, 90, 180, 270 deg of both dogs): as drawn, no two label
    boxes overlap, none covers an entry/exit marker or a stretch of either path or the plate
    line, and all sit inside the axes (boxes from get_window_extent, in display pixels)."""
    from sewtol.mechanisms.feed_131 import analysis as feed
    from sewtol.mechanisms.feed_131.model import Feed131

    p = Feed131()
    m = feed.metrics(p)
    phases = {dog: (getattr(m, dog)["entry_phi_deg"], getattr(m, dog)["exit_phi_deg"])
              for dog in ("lower", "upper")}
    traj = feed.trajectory(p, 1.0)
    fig, ax = plt.subplots(figsize=(6, 5))
    plots.tooth_paths(traj, p.plate_mm, p.material_mm, ax, phases=phases)
    ax.set_title("131-42+3 feed dogs: middle-tooth paths", fontsize=10)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    labels = [t for t in ax.texts if t.get_gid() == plots.PHASE_LABEL]
    markers = [a for a in ax.lines if a.get_gid() == plots.PHASE_MARKER]
    assert sorted(t.get_text() for t in labels) == sorted(
        f"{a}\u00b0" for a in (0, 90, 180, 270) for _ in range(2))
    assert len(markers) == 4
    boxes = [t.get_window_extent(renderer) for t in labels]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            assert plots.box_overlap(a, b) == 0.0, (a, b)
        for mk in markers:
            assert plots.box_overlap(a, mk.get_window_extent(renderer)) == 0.0
    x0, x1 = ax.get_xlim()
    paths = [np.column_stack([traj[f"{d}_x_mm"], traj[f"{d}_y_mm"]]) for d in ("lower", "upper")]
    paths.append(np.array([[x0, p.plate_mm], [x1, p.plate_mm]]))
    pts = np.vstack([plots.densify(ax.transData.transform(xy)) for xy in paths])
    inside = ax.get_window_extent(renderer)
    for t, bb in zip(labels, boxes, strict=True):
        hit = ((pts[:, 0] >= bb.x0) & (pts[:, 0] <= bb.x1) & (pts[:, 1] >= bb.y0)
               & (pts[:, 1] <= bb.y1))
        assert not hit.any(), (t.get_text(), bb)
        assert inside.x0 <= bb.x0 and bb.x1 <= inside.x1 and inside.y0 <= bb.y0 <= bb.y1 <= \
            inside.y1
    plt.close(fig)


def test_frame_verdicts_have_three_distinct_labels():
    """A statement that holds on every frame, on none, or on some: three labels (a statement
    that fails everywhere is not 'frame-dependent'); the tautology about beta is gone."""
    frames = _script("needle_208_frames")
    assert frames.label([True, True, True]) == "holds in every frame"
    assert frames.label([False, False, False]) == "fails in every frame"
    assert frames.label([True, False, True]) == "frame-dependent"
    text = (COMMITTED / "frames.md").read_text()
    assert "never lowers" not in text and "**robust**" not in text
    # the committed statements: the >= 99 % yields fail on every frame (7.8, 1.4, 5.1 %)
    line = next(x for x in text.splitlines() if "base tolerances >= 99 %" in x)
    assert line.startswith("- **fails in every frame**:"), line


def test_headline_without_the_other_frames_says_the_frame_was_not_assessed(tmp_path):
    """Only the default frame's strategies table (a custom run before the frames study): the
    yield and the recommendation from it, and the frame line says it was not assessed; an extra
    set only the other frames' table has is left out."""
    index = _script("needle_208_index")
    shutil.copy(COMMITTED / "strategies.csv", tmp_path / "strategies.csv")
    lines = dict(index.headline(tmp_path, ["base", "recommended"]))
    assert lines["Frame"].startswith("not assessed")
    assert "(strategy all)" in lines["What to do"]
    other = pd.read_csv(COMMITTED / "strategies_frames.csv", comment="#")
    other.assign(tolerances="only_elsewhere").to_csv(tmp_path / "strategies_frames.csv",
                                                     index=False)
    ranges = index.frame_ranges(index.strategy_frames(tmp_path))
    assert set(ranges.tolerances) == {"base", "recommended"}
    assert (ranges.frames == 1).all()
