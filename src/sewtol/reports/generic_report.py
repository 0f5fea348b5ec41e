"""A report of any mechanism file: nominal, scan, worst case, Monte-Carlo, in one folder.

`build(mech, tolerances, ...)` runs the studies and returns a frozen GenericReport; `write(report,
out)` writes every table as CSV and Markdown, a histogram per output, index.md and a
self-contained report.html, opening with the file's title, source, assumptions, the dominant
tolerances of each output and, with a limit, the yield.
"""

from __future__ import annotations

import base64
import html
import io
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson
from sewtol.io import write_bytes_atomic, write_text_atomic
from sewtol.reports.tables import to_csv, write_table
from sewtol.studies import generic as G
from sewtol.studies import montecarlo as MC
from sewtol.studies import scan as S
from sewtol.studies import worst_case as W
from sewtol.studies.rare_event import check_limits, limits_text

# the histogram's range: these quantiles of the machines that run, widened to show the limits;
# machines outside are counted as "beyond the plot" in the legend
PLOT_QUANTILES = (0.001, 0.999)
BINS = 40
TOP = 3  # dominant tolerances named per output


@dataclass(frozen=True)
class GenericReport:
    mechanism: object
    tolerances: object
    n: int
    seed: int
    limit_output: str | None
    upper: float | None
    lower: float | None
    nominal: pd.DataFrame
    scan: pd.DataFrame
    dominance: pd.DataFrame  # output, rank, param, change (max |change| over sides), share
    worst_case: pd.DataFrame
    mc_summary: pd.DataFrame
    machines: pd.DataFrame
    yield_row: dict | None = None
    notes: list = field(default_factory=list)

    def words(self) -> list[str]:
        """The opening paragraphs in words (Markdown)."""
        m = self.mechanism
        h = m.header
        out = [f"# {h.title or m.name}", "",
               f"Mechanism file `{m.path}` (`{m.name}`); tolerance set `{self.tolerances.name}`"
               f" ({', '.join(_tol_text(t) for t in self.tolerances.items)}); Monte-Carlo "
               f"{self.n} machines, seed {self.seed}.", ""]
        if h.source:
            out += [f"**Source.** {h.source}", ""]
        if h.assumptions:
            out += ["**Assumptions.**", ""] + [f"- {a}" for a in h.assumptions] + [""]
        out += ["**Which tolerances dominate** (from the scan: each tolerance at its limits, "
                "the others nominal; share = its largest change over the sum of all):", ""]
        for name in self.nominal["output"]:
            d = self.dominance[self.dominance["output"] == name]
            unit = _unit(m, name)
            if d.empty or not (d["change"] > 0).any():
                out.append(f"- {name}: no tolerance changes it at the file's {m.samples} "
                           "sampled angles")
                continue
            parts = [f"{r['param']} ({r['change']:.4g} {unit}, {100 * r['share']:.0f} %)"
                     for r in d.head(TOP).to_dict("records")]
            out.append(f"- {name}: " + ", ".join(parts))
        out.append("")
        if self.yield_row is not None:
            y = self.yield_row
            out += [f"**Yield.** {y['yield'] * 100:.2f} % of {y['n']} machines pass "
                    f"{y['condition']} (95 % interval {y['ci_low'] * 100:.2f} ... "
                    f"{y['ci_high'] * 100:.2f} %): {y['out_of_limits']} beyond the limits, "
                    f"{y['cannot_close']} cannot close, {y['dead_point']} at a dead point.", ""]
        failed = self.machines["status"] != "ok"
        if failed.any():
            groups = self.machines.loc[failed, "failed_group"].value_counts().sort_index()
            out += [f"**Machines that cannot run:** {int(failed.sum())} of {self.n} ("
                    + ", ".join(f"{k}: {v}" for k, v in groups.items())
                    + "); they are counted in every table, never dropped.", ""]
        out += [f"- {n}" for n in self.notes] + ([""] if self.notes else [])
        return out


def _unit(mech, output):
    u = mech.output(output).unit
    return "" if u == "1" else u


def _tol_text(t):
    if t.lower == -t.upper:
        s = f"{t.param} +/-{t.upper:g}"
    else:
        s = f"{t.param} [{t.lower:g}, {t.upper:g}]"
    return s + ("" if t.dist == "uniform" else f" {t.dist}")


def law_notes(tolerances, inspection: dict | None) -> list[str]:
    """What the set declares beyond its limits, in words (nothing for an independent set, so
    its report reads as before): the copula, the relations (and the worst case's polytope),
    the matching, and how many candidates the machines were built from."""
    out = []
    dep = tolerances.active().dependence
    if dep is not None:
        pairs = [f"{a}-{b} {dep.array[i, j]:g}" for i, a in enumerate(dep.params)
                 for j, b in enumerate(dep.params) if j > i and dep.array[i, j]]
        out.append("the set ties " + ", ".join(pairs) + " (Gaussian copula of the normal scores)")
    for r in tolerances.relations:
        out.append(f"relation {r.expr} within [{r.lower:g}, {r.upper:g}]: machines that break "
                   "it are rejected at inspection; the worst case searches what it leaves of "
                   "the box")
    if tolerances.selective is not None:
        sel = tolerances.selective
        out.append(f"{sel.params[0]} and {sel.params[1]} are matched in {sel.groups} classes of "
                   f"equal {sel.by} (lots of 500)")
    if inspection is not None:
        out.append(f"inspection: {inspection['built']} machines built from "
                   f"{inspection['candidates']} candidates ({100 * inspection['acceptance']:.1f} "
                   "%); the others broke a relation or were left unmatched")
    return out


def dominance(scan_rows: pd.DataFrame) -> pd.DataFrame:
    """Per output, the toleranced parameters ranked by their largest |change| over both sides
    (a side whose machine cannot run counts as an infinite change) and their share of the sum."""
    rows = []
    s = scan_rows.copy()
    s["abs_change"] = np.where(s["status"] == "ok", s["change"].abs(), np.inf)
    for name, grp in s.groupby("output", sort=False):
        per = grp.groupby("param", sort=False)["abs_change"].max()
        finite = per[np.isfinite(per)]
        total = float(finite.sum())
        per = per.sort_values(ascending=False, kind="stable")
        for rank, (p, c) in enumerate(per.items(), start=1):
            rows.append({"output": name, "rank": rank, "param": p, "change": float(c),
                         "share": (1.0 if not np.isfinite(c) else
                                   (c / total if total > 0 else 0.0))})
    return pd.DataFrame(rows, columns=["output", "rank", "param", "change", "share"])


def build(mech, tolerances, n: int = 1000, seed: int = 0, limit_output: str | None = None,
          upper: float | None = None, lower: float | None = None) -> GenericReport:
    """Run nominal, scan, worst case (every output) and Monte-Carlo on the file; the yield of
    limit_output within upper/lower, by default within the file's [[specs]] entry."""
    if upper is not None or lower is not None:
        upper, lower = check_limits(upper, lower)
    limit_output, spec, _ = mech.resolve_spec(limit_output, upper, lower)
    if spec is None:
        limit_output = None
    else:
        upper, lower = spec.upper, spec.lower
    nom = G.nominal(mech).rows
    sc = S.scan(mech, tolerances, fast=False).rows
    wc_rows, notes = [], []
    for name in mech.output_names:
        try:
            r = W.worst_case(mech, tolerances, name, fast=False)
        except ParameterError as exc:
            # too many corners, or every corner fails: said in the report, not dropped
            notes.append(f"worst case of {name} not computed ({exc.field}: {exc.rule})")
            continue
        f = r.rows[["extreme", "output", "value", "corner_value", "interior"]].copy()
        f["monotone_on_axes"] = r.monotone_on_axes
        f["failed_corners"] = r.failed_corners
        wc_rows.append(f)
    wc = pd.concat(wc_rows, ignore_index=True) if wc_rows else pd.DataFrame(
        columns=["extreme", "output", "value", "corner_value", "interior"])
    mc = MC.montecarlo(mech, tolerances, n, seed, limit=upper, lower_limit=lower,
                       limit_output=limit_output)
    notes += law_notes(tolerances, mc.inspection())
    machines = mc.machines
    yield_row = None
    if limit_output is not None:
        c = mc.counts(limit_output)
        ci_low, ci_high = clopper_pearson(c["ok"], c["n"])
        yield_row = {"output": limit_output, "limit": upper, "lower_limit": lower,
                     "condition": limits_text(limit_output, upper, lower,
                                              mech.output(limit_output).unit),
                     "n": c["n"], "ok": c["ok"], "out_of_limits": c["out_of_spec"],
                     "cannot_close": c["cannot_close"], "dead_point": c["dead_point"],
                     "yield": c["ok"] / c["n"], "ci_low": ci_low,
                     "ci_high": ci_high}
    return GenericReport(mech, tolerances, int(n), int(seed), limit_output, upper, lower, nom,
                         sc, dominance(sc), wc, mc.summary_frame(), machines,
                         yield_row, notes)


def axis_label(output: str, unit: str) -> str:
    """`name (unit)`, without repeating a unit the name already ends with (stroke_mm ->
    "stroke (mm)", speed_max_m_s -> "speed_max (m/s)")."""
    if not unit:
        return output
    suffix = "_" + unit.replace("/", "_").replace("^", "")
    stem = output[:-len(suffix)] if output.endswith(suffix) and len(output) > len(suffix) \
        else output
    shown = "\u00b5m" if unit == "um" else unit
    return f"{stem} ({shown})"


def histogram(report: GenericReport, output: str, ax):
    """The report's histogram of one output (`output_histogram`), its limits and nominal."""
    limits = (report.lower, report.upper) if report.limit_output == output else ()
    return output_histogram(report.machines[output], ax, axis_label(output, _unit(
        report.mechanism, output)), limits, report.nominal.set_index("output")["value"].get(
        output), f"{output}: {report.n} machines, seed {report.seed}")


def output_histogram(values, ax, label: str, limits=(), nom=None, title: str = ""):
    """Histogram of one output over the machines that run, its limits (None: none) dashed, its
    nominal value (if any) a grey line; the legend counts the machines in and beyond the
    plotted range and the machines that cannot run, which add up to n (the report's
    figures and `sewtol run FILE montecarlo --plot`'s panels)."""
    v = np.asarray(values, float)
    ok = v[np.isfinite(v)]
    failed = int(v.size - ok.size)
    lines = [x for x in limits if x is not None]
    beyond = 0
    if ok.size:
        lo, hi = np.quantile(ok, PLOT_QUANTILES)
        lo, hi = min([lo, *lines]), max([hi, *lines])
        if hi <= lo:
            lo, hi = lo - 0.5 * max(abs(lo), 1e-9), hi + 0.5 * max(abs(hi), 1e-9)
        inside = ok[(ok >= lo) & (ok <= hi)]
        beyond = int(ok.size - inside.size)
        ax.hist(inside, bins=BINS, range=(lo, hi), color="C0",
                label=f"{inside.size} machines in range")
    ax.plot([], [], " ", label=f"{beyond} beyond the plotted range")
    ax.plot([], [], " ", label=f"{failed} cannot run (cannot close / dead point)")
    for x in lines:
        ax.axvline(x, color="C3", ls="--", lw=1)
    if lines:
        ax.plot([], [], color="C3", ls="--", lw=1, label="limit")
    if nom is not None and np.isfinite(nom):
        ax.axvline(nom, color="0.3", lw=0.8)
        ax.plot([], [], color="0.3", lw=0.8, label=f"nominal {nom:.6g}")
    ax.set_xlabel(label)
    ax.set_ylabel("machines")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, lw=0.3)
    return ax


def _tables(report: GenericReport) -> list[tuple[str, str, pd.DataFrame]]:
    t = [("nominal", "Nominal machine", report.nominal),
         ("dominance", "Which tolerances dominate (scan)", report.dominance),
         ("scan", "Scan: each tolerance at its limits", report.scan),
         ("worst_case", "Worst case over the tolerance box", report.worst_case),
         ("montecarlo_summary", "Monte-Carlo summary", report.mc_summary)]
    if report.yield_row is not None:
        t.append(("yield", "Yield", pd.DataFrame([report.yield_row])))
    return t


def write(report: GenericReport, out) -> list[Path]:
    """Every table (CSV + Markdown), machines.csv, one PNG per output, index.md, report.html."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    m = report.mechanism
    base = {"mechanism": m.name, "file": m.path, "tolerances": report.tolerances.name}
    sampled = {**base, "n": report.n, "seed": report.seed}
    written = []
    tables = _tables(report)
    for name, title, frame in tables:
        written += write_table(frame, out, name, title,
                               sampled if name in ("montecarlo_summary", "yield") else base)
    write_text_atomic(out / "machines.csv", to_csv(report.machines, sampled))
    written.append(out / "machines.csv")
    figures = {}
    for name in m.output_names:
        fig, ax = plt.subplots(figsize=(6.0, 3.6))
        histogram(report, name, ax)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
        plt.close(fig)
        path = out / f"hist_{name}.png"
        write_bytes_atomic(path, buf.getvalue())
        figures[name] = (path, buf.getvalue())
        written.append(path)
    words = report.words()
    md = words + ["## Tables", ""]
    md += [f"- [{title}]({name}.md) ([CSV]({name}.csv))" for name, title, _ in tables]
    md += ["- [every machine](machines.csv)", "", "## Histograms", ""]
    md += [f"![{name}](hist_{name}.png)" for name in figures]
    write_text_atomic(out / "index.md", "\n".join(md) + "\n")
    write_text_atomic(out / "report.html", _html(report, words, tables, figures))
    return written + [out / "index.md", out / "report.html"]


def _inline(text: str) -> str:
    """Markdown bold and code of the opening words as HTML (the text escaped first)."""
    t = html.escape(text)
    t = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", t)
    return re.sub(r"`(.+?)`", r"<code>\1</code>", t)


def _html(report, words, tables, figures) -> str:
    body, in_list = [], False
    for line in words:
        if line.startswith("- "):
            if not in_list:
                body.append("<ul>")
                in_list = True
            body.append(f"<li>{_inline(line[2:])}</li>")
            continue
        if in_list:
            body.append("</ul>")
            in_list = False
        if line.startswith("# "):
            body.append(f"<h1>{_inline(line[2:])}</h1>")
        elif line:
            body.append(f"<p>{_inline(line)}</p>")
    if in_list:
        body.append("</ul>")
    for _name, title, frame in tables:
        body.append(f"<h2>{html.escape(title)}</h2>")
        body.append(frame.to_html(index=False, na_rep="", float_format=lambda x: f"{x:.6g}",
                                  border=0, classes="t"))
    body.append("<h2>Histograms</h2>")
    for name, (_, png) in figures.items():
        b64 = base64.b64encode(png).decode("ascii")
        body.append(f'<figure><img alt="{html.escape(name)}" src="data:image/png;base64,{b64}">'
                    f"<figcaption>{html.escape(name)}</figcaption></figure>")
    title = html.escape(report.mechanism.header.title or report.mechanism.name)
    style = ("body{font-family:sans-serif;max-width:60em;margin:2em auto;line-height:1.4}"
             "table.t{border-collapse:collapse;font-size:0.85em;margin:0.5em 0}"
             "table.t td,table.t th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
             "img{max-width:100%}")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{title}</title><style>{style}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")
