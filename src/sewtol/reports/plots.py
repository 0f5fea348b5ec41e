"""Plots a designer would otherwise draw by hand. Each takes data and an ax and returns the ax."""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
matplotlib.rcParams["svg.hashsalt"] = "sewtol"  # fixed SVG ids: reruns are byte-identical
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sewtol.errors import ParameterError  # noqa: E402
from sewtol.io import write_bytes_atomic  # noqa: E402

FIGURE_DPI = 200  # print resolution: a 7 in wide figure is 1400 px, sharp at 100 % in a report
FIGURE_FORMATS = ("png", "svg", "pdf")
MICRO = "\u00b5m"  # every label says µm; data columns keep _um


def deviation_vs_crank(curves: dict, ax=None, limit_um: float | None = None):
    """d(phi) in µm against crank angle for each labelled frame (columns phi_deg, d_um), with the
    sign convention on the axis and, if limit_um is given, each curve's SumDelta against it."""
    ax = ax or plt.gca()
    for label, frame in curves.items():
        d = np.asarray(frame["d_um"], float)
        total = max(0.0, np.nanmax(d)) + max(0.0, -np.nanmin(d))
        ax.plot(frame["phi_deg"], d, lw=1.2, label=f"{label}: \u03a3\u0394 = {total:.2f} {MICRO}")
    ax.axhline(0.0, color="k", lw=0.7, label="guide line (d = 0)")
    if limit_um is not None:
        ax.text(0.01, 0.02, f"limit: \u03a3\u0394 = \u0394+ + \u0394\u2212 = max(d, 0) + "
                f"max(\u2212d, 0) \u2264 {limit_um:g} {MICRO}", transform=ax.transAxes,
                fontsize=7, va="bottom")
    ax.set_xlabel("crank angle \u03c6 (deg)")
    ax.set_ylabel(f"deviation d ({MICRO})\n> 0: needle point right of the guide")
    ax.set_xlim(0, 360)
    ax.set_xticks(np.arange(0, 361, 60))
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return ax


def sum_delta_vs_beta(betas, totals_um, beta_opt: float, window: tuple[float, float],
                      limit_um: float, ax=None):
    """SumDelta against beta with the limit line and the window where it holds."""
    ax = ax or plt.gca()
    ax.plot(betas, totals_um, color="C0", label="\u03a3\u0394, guide fixed")
    ax.axhline(limit_um, color="C3", ls="--", lw=1, label=f"limit {limit_um:g} {MICRO}")
    if np.all(np.isfinite(window)):
        ax.axvspan(window[0], window[1], color="C2", alpha=0.15,
                   label=f"window {window[0]:.2f} ... {window[1]:.2f} deg")
    ax.axvline(beta_opt, color="C1", lw=1, label=f"\u03b2* = {beta_opt:.2f} deg")
    ax.set_xlabel("regulating angle \u03b2 (deg)")
    ax.set_ylabel(f"total deviation \u03a3\u0394 ({MICRO})")
    ax.set_ylim(bottom=0)
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7)
    return ax


def study_parser(doc: str, seed: int | None = 2026, jobs: bool | str = False,
                 progress: bool = False, figures: bool = False, **counts: int):
    """The report scripts' command line: --out, --seed (None: none), a whole number per count
    (n_mc=10000: --n-mc), --n-jobs (jobs: True or its help), --progress, --figure-format."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--out", default="reports")
    ints = ({} if seed is None else {"seed": seed}) | counts | ({"n_jobs": 1} if jobs else {})
    for name, default in ints.items():
        ap.add_argument("--" + name.replace("_", "-"), type=int, default=default,
                        help=jobs if name == "n_jobs" and isinstance(jobs, str) else None)
    if progress:
        ap.add_argument("--progress", action="store_true")
    if figures:
        ap.add_argument("--figure-format", choices=FIGURE_FORMATS, default="png",
                        help=f"png (the default, {FIGURE_DPI} dpi), svg or pdf (pdf also writes "
                        "the png the HTML report embeds)")
    return ap


def save(fig, path: Path, fmt: str | None = None) -> Path:
    """The figure as PNG (FIGURE_DPI), SVG or PDF (fmt, default the path's suffix) without
    timestamps in its metadata, written atomically, so reruns are byte-identical. A PDF comes
    with a PNG beside it (the HTML report cannot embed a PDF)."""
    path = Path(path)
    fmt = fmt or path.suffix.lstrip(".") or "png"
    if fmt not in FIGURE_FORMATS:
        raise ParameterError("--figure-format", f"must be one of {', '.join(FIGURE_FORMATS)}", fmt)
    path = path.with_suffix("." + fmt)
    for f in (fmt, "png") if fmt == "pdf" else (fmt,):
        buf = io.BytesIO()
        with matplotlib.rc_context({"svg.hashsalt": "sewtol", "svg.fonttype": "none"}):
            fig.savefig(buf, format=f, dpi=FIGURE_DPI, bbox_inches="tight",
                        metadata={"png": {"Software": None}, "svg": {"Date": None},
                                  "pdf": {"CreationDate": None, "Producer": None}}[f])
        write_bytes_atomic(path.with_suffix("." + f), buf.getvalue())
    plt.close(fig)
    return path


def scan_deviation_grid(nominal_curve, limit_curves: dict, limit_um: float = 10.0,
                        nominal_total_um: float | None = None):
    """One panel per parameter: d(phi) nominal against the upper and lower limit (beta*). The
    legend (each curve's label should carry its SumDelta) sits under each panel, off the curves."""
    k = len(limit_curves)
    cols = 3
    rows = int(np.ceil(k / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(11, 3.6 * rows), sharex=True, squeeze=False)
    nom_label = "nominal" if nominal_total_um is None else \
        f"nominal, \u03a3\u0394 {nominal_total_um:.2f} {MICRO}"
    for ax, (param, curves) in zip(axes.ravel(), limit_curves.items(), strict=False):
        ax.plot(nominal_curve["phi_deg"], nominal_curve["d_um"], color="0.3", lw=1, label=nom_label)
        for (label, frame), color in zip(curves.items(), ("C3", "C0"), strict=False):
            ax.plot(frame["phi_deg"], frame["d_um"], color=color, lw=1, label=label)
        ax.axhline(limit_um / 2, color="C3", ls=":", lw=0.6)
        ax.axhline(-limit_um / 2, color="C3", ls=":", lw=0.6)
        ax.set_title(param, fontsize=9)
        ax.set_ylabel(f"d ({MICRO})")
        ax.grid(True, lw=0.3)
        ax.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.1), frameon=False)
        ax.tick_params(labelbottom=True)
        ax.set_xticks(np.arange(0, 361, 90))
    for ax in axes.ravel()[k:]:
        ax.set_visible(False)
    fig.supxlabel("crank angle \u03c6 (deg)", fontsize=9)
    fig.tight_layout(h_pad=3.5)
    return fig


def binned(values, edges) -> dict:
    """Counts of values in the bins `edges`, plus the machines above the last edge (overflow)
    and the non-finite ones (failed); counts.sum() + overflow + below + failed == n."""
    x = np.asarray(values, float)
    ok = np.isfinite(x)
    counts, _ = np.histogram(x[ok], bins=edges)
    return {"counts": counts, "edges": np.asarray(edges, float),
            "overflow": int(np.sum(x[ok] > edges[-1])), "below": int(np.sum(x[ok] < edges[0])),
            "failed": int(np.sum(~ok)), "n": int(x.size)}


def montecarlo_histograms(fixed_um, adjusted_um, limit_um: float, yields: tuple[float, float],
                          ax=None, top_um: float | None = None, nbins: int = 60):
    """Step histograms of SumDelta with beta fixed and with beta adjusted (no blended overlap),
    the limit and the yields. Nothing is dropped: machines above top_um stand in an overflow bar
    with its count, failed machines (non-finite SumDelta) are counted in the legend."""
    ax = ax or plt.gca()
    both = np.concatenate([np.asarray(x, float) for x in (fixed_um, adjusted_um)])
    finite = both[np.isfinite(both)]
    if top_um is None:
        top_um = max(np.quantile(finite, 0.98) if finite.size else 0.0, limit_um * 1.5)
    edges = np.linspace(0, top_um, nbins + 1)
    width = edges[1] - edges[0]
    parts = []
    for j, (values, color, name, y) in enumerate(((fixed_um, "C1", "\u03b2 fixed", yields[0]),
                                                 (adjusted_um, "C0", "\u03b2 adjusted",
                                                  yields[1]))):
        b = binned(values, edges)
        parts.append(b)
        ax.stairs(b["counts"], edges, color=color, lw=1.4,
                  label=f"{name}: yield {y:.1%}, {b['overflow']} > {top_um:.0f} {MICRO}, "
                  f"{b['failed']} failed of {b['n']}")
        # the overflow: one bar per case side by side past the last edge, its count on top
        x0 = top_um + width * (1.0 + 1.2 * j)
        ax.bar(x0, b["overflow"], width * 1.1, align="edge", color=color, alpha=0.9,
               hatch="//", edgecolor="k", lw=0.4)
        ax.annotate(str(b["overflow"]), (x0 + 0.55 * width, b["overflow"]), ha="center",
                    va="bottom", fontsize=6, color=color)
    ax.axvline(limit_um, color="C3", ls="--", lw=1, label=f"limit {limit_um:g} {MICRO}")
    ax.axvline(top_um, color="0.4", lw=0.6)
    ax.set_xlabel(f"total deviation \u03a3\u0394 ({MICRO}); hatched bars: the machines above "
                  f"{top_um:.0f} {MICRO}")
    ax.set_ylabel("machines")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.18), frameon=False)
    ax.binned = parts  # what was drawn, for the tests and the report text
    return ax


def at_bound(beta_deg, range_deg, tol_deg: float = 1e-3) -> tuple[int, int]:
    """Machines whose beta* sits on the lower / upper end of the searched range (the optimum
    may lie beyond it: those machines are adjusted as far as the regulator goes)."""
    b = np.asarray(beta_deg, float)
    return (int(np.sum(np.abs(b - range_deg[0]) <= tol_deg)),
            int(np.sum(np.abs(b - range_deg[1]) <= tol_deg)))


def beta_histogram(beta_deg, range_deg, ax=None, tol_deg: float = 1e-3):
    """beta* per machine; the machines at either end of the searched range drawn in red with
    their count (their optimum may lie beyond the range)."""
    ax = ax or plt.gca()
    b = np.asarray(beta_deg, float)
    b = b[np.isfinite(b)]
    low, high = at_bound(b, range_deg, tol_deg)
    inside = b[(np.abs(b - range_deg[0]) > tol_deg) & (np.abs(b - range_deg[1]) > tol_deg)]
    edges = np.linspace(range_deg[0], range_deg[1], 51)
    ax.hist(inside, bins=edges, color="C2", alpha=0.8, label=f"inside the range: {inside.size}")
    w = edges[1] - edges[0]
    ax.bar([range_deg[0] - w, range_deg[1]], [low, high], w, align="edge", color="C3",
           label=f"at a bound: {low} at {range_deg[0]:g}, {high} at {range_deg[1]:g} deg")
    for edge in range_deg:
        ax.axvline(edge, color="0.4", ls=":", lw=1)
    ax.set_xlabel("\u03b2* per machine (deg); dotted: searched range")
    ax.set_ylabel("machines")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.18), frameon=False)
    return ax


def sobol_bars(indices, ax=None, title: str = ""):
    """S1 and ST per parameter with their confidence intervals (columns of SobolResult)."""
    ax = ax or plt.gca()
    x = np.arange(len(indices))
    ax.bar(x - 0.2, indices["S1"], 0.4, yerr=indices["S1_conf"], capsize=3, label="S1 (first order)")
    ax.bar(x + 0.2, indices["ST"], 0.4, yerr=indices["ST_conf"], capsize=3, label="ST (total)")
    ax.set_xticks(x)
    ax.set_xticklabels(indices["param"])
    ax.set_ylabel("Sobol index")
    ax.set_xlabel("tolerance")
    ax.set_title(title, fontsize=9)
    ax.grid(True, axis="y", lw=0.3)
    ax.legend(fontsize=7)
    return ax


def panels(names, draw, height_in: float = 2.6):
    """A figure of one panel per name, stacked; draw(name, ax) fills each (the figures of
    `sewtol run FILE scan|montecarlo|sobol`, a panel per output)."""
    fig, axes = plt.subplots(len(names), 1, figsize=(7, height_in * len(names)), squeeze=False)
    for ax, name in zip(axes[:, 0], names, strict=True):
        draw(name, ax)
    fig.tight_layout()
    return fig


def _at_phi(traj, column: str, phi_deg: float) -> float:
    """A trajectory column at a phase, interpolated periodically (traj is sampled on phi_deg)."""
    phi = np.asarray(traj["phi_deg"], float)
    return float(np.interp(phi_deg % 360.0, phi, np.asarray(traj[column], float), period=360.0))


PHASE_LABEL = "phase-label"  # gid of the phase labels tooth_paths places (tests find them by it)
PHASE_MARKER = "phase-marker"  # gid of the entry/exit markers


def densify(xy: np.ndarray, step_px: float = 1.0) -> np.ndarray:
    """A polyline in display pixels resampled to points at most step_px apart (so a small box
    lying across a segment between two samples still contains some of it)."""
    seg = np.diff(xy, axis=0)
    k = np.maximum(1, np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / step_px).astype(int))
    parts = [xy[i] + np.outer(np.arange(k[i]) / k[i], seg[i]) for i in range(len(seg))]
    return np.vstack([*parts, xy[-1:]])


def box_overlap(a, b) -> float:
    """The area two display boxes (matplotlib Bbox) share, in px^2."""
    w = min(a.x1, b.x1) - max(a.x0, b.x0)
    h = min(a.y1, b.y1) - max(a.y0, b.y0)
    return max(w, 0.0) * max(h, 0.0)


def place_labels(ax, labels, curves, avoid=(), hlines=(), distances_pt=(5.0, 9.0, 14.0),
                 gid=PHASE_LABEL):
    """Annotate each (text, (x, y), color) of `labels` beside its point, at the offset (eight
    directions at each of distances_pt) whose box overlaps nothing already there: no label
    placed before it, no artist of `avoid` (markers), no stretch of the `curves` (list of (x, y)
    arrays in data units) or of the horizontal lines at the heights `hlines`, inside the axes.
    The figure is drawn first so the limits and the aspect are final; the choice is made in
    display pixels from the data, not by hand (the least-covered offset wins if none is free)."""
    fig = ax.figure
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    x0, x1 = ax.get_xlim()
    curves = [*curves, *(([x0, x1], [h, h]) for h in hlines)]
    pts = np.vstack([densify(ax.transData.transform(np.column_stack(c))) for c in curves])
    blocked = [a.get_window_extent(renderer) for a in avoid]
    inside = ax.get_window_extent(renderer)
    placed = []
    angles = np.deg2rad(np.arange(0.0, 360.0, 45.0))
    for text, (x, y), color in labels:
        best = None
        for dist in distances_pt:
            for t in angles:
                c, s = np.cos(t), np.sin(t)
                kw = {"ha": "left" if c > 0.3 else "right" if c < -0.3 else "center",
                      "va": "bottom" if s > 0.3 else "top" if s < -0.3 else "center"}
                ann = ax.annotate(text, (x, y), xytext=(dist * c, dist * s),
                                  textcoords="offset points", fontsize=6, color=color, **kw)
                bb = ann.get_window_extent(renderer)
                ann.remove()
                grown = bb.expanded(1.0, 1.0).padded(1.0)
                on_curve = int(np.sum((pts[:, 0] >= grown.x0) & (pts[:, 0] <= grown.x1)
                                      & (pts[:, 1] >= grown.y0) & (pts[:, 1] <= grown.y1)))
                cost = (1e6 * sum(box_overlap(grown, o) > 0 for o in (*placed, *blocked))
                        + 1e4 * (not (inside.x0 <= bb.x0 and bb.x1 <= inside.x1
                                      and inside.y0 <= bb.y0 and bb.y1 <= inside.y1))
                        + on_curve + 0.01 * dist)
                if best is None or cost < best[0]:
                    best = (cost, (dist * c, dist * s), kw, bb)
        _, offset, kw, bb = best
        ann = ax.annotate(text, (x, y), xytext=offset, textcoords="offset points", fontsize=6,
                          color=color, **kw)
        ann.set_gid(gid)
        placed.append(bb)
    return ax


def tooth_paths(traj, plate_mm: float, material_mm: float = 0.0, ax=None,
                phases: dict | None = None, mark_every_deg: float = 30.0):
    """Both middle-tooth paths with the plate line (and the material's top, if any), the sense
    of travel, a dot every mark_every_deg of phi (labelled every 90 deg) and, with phases =
    {dog: (entry_phi_deg, exit_phi_deg)}, where each tooth enters and leaves its working part.
    The phase labels are placed by `place_labels` off the curves, the markers and each other."""
    ax = ax or plt.gca()
    labels, curves, markers = [], [], []
    for dog, color in (("lower", "C0"), ("upper", "C1")):
        x, y = traj[f"{dog}_x_mm"], traj[f"{dog}_y_mm"]
        ax.plot(np.r_[x, x[:1]], np.r_[y, y[:1]], color=color, label=f"{dog} dog, middle tooth")
        curves.append((np.r_[x, x[:1]], np.r_[y, y[:1]]))
        ax.annotate("", xy=(x.iloc[6], y.iloc[6]), xytext=(x.iloc[0], y.iloc[0]),
                    arrowprops={"arrowstyle": "->", "color": color})
        for phi in np.arange(0.0, 360.0, mark_every_deg):
            px, py = _at_phi(traj, f"{dog}_x_mm", phi), _at_phi(traj, f"{dog}_y_mm", phi)
            ax.plot(px, py, ".", color=color, ms=3)
            if phi % 90 == 0:
                labels.append((f"{phi:.0f}\u00b0", (px, py), color))
        if phases and dog in phases:
            for phi, marker, what in zip(phases[dog], ("^", "v"), ("entry", "exit"),
                                         strict=True):
                if not np.isfinite(phi):
                    continue
                (m,) = ax.plot(_at_phi(traj, f"{dog}_x_mm", phi),
                               _at_phi(traj, f"{dog}_y_mm", phi), marker, color=color, mec="k",
                               ms=7, label=f"{dog} {what} at \u03c6 = {phi:.1f}\u00b0")
                m.set_gid(PHASE_MARKER)
                markers.append(m)
    ax.axhline(plate_mm, color="k", lw=1, label=f"needle plate y = {plate_mm:g} mm")
    if material_mm > 0:
        ax.axhline(plate_mm + material_mm, color="0.5", ls="--", lw=1,
                   label=f"material top (+{material_mm:g} mm)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0),
              title=f"dots every {mark_every_deg:g}\u00b0 of \u03c6", title_fontsize=7)
    place_labels(ax, labels, curves, markers,
                 [plate_mm, plate_mm + material_mm] if material_mm > 0 else [plate_mm])
    return ax


def feed_xy_vs_phi(traj, plate_mm: float, axes, phases: dict | None = None):
    """x and y of both teeth against the main-shaft angle, on two axes; with phases =
    {dog: (entry_phi_deg, exit_phi_deg)} the working part of each dog is shaded."""
    for dog, color in (("lower", "C0"), ("upper", "C1")):
        axes[0].plot(traj["phi_deg"], traj[f"{dog}_x_mm"], color=color, label=f"{dog} dog")
        axes[1].plot(traj["phi_deg"], traj[f"{dog}_y_mm"], color=color, label=f"{dog} dog")
        if phases and dog in phases and np.all(np.isfinite(phases[dog])):
            # each dog's working part as its own strip along the top (no blended overlap)
            a, b = (float(v) % 360.0 for v in phases[dog])
            spans = [(a, b)] if a < b else [(a, 360.0), (0.0, b)]
            strip = (0.93, 0.965) if dog == "lower" else (0.965, 1.0)
            for k, (lo, hi) in enumerate(spans):
                for ax in axes:
                    ax.axvspan(lo, hi, *strip, color=color, alpha=0.9, lw=0,
                               label=(f"{dog} works {a:.1f}\u00b0 \u2192 {b:.1f}\u00b0 (strip)"
                                      if k == 0 and ax is axes[1] else None))
    axes[1].axhline(plate_mm, color="k", lw=1, label="needle plate")
    if phases:
        for ax in axes:  # head room for the strips above the curves
            lo, hi = ax.get_ylim()
            ax.set_ylim(lo, hi + 0.12 * (hi - lo))
    axes[0].set_ylabel("x (mm)")
    axes[1].set_ylabel("y (mm)")
    for ax in axes:
        ax.set_xlabel("main-shaft angle \u03c6 (deg)")
        ax.set_xlim(0, 360)
        ax.set_xticks(np.arange(0, 361, 60))
        ax.grid(True, lw=0.3)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return axes


def regulator_curve(sweep, b_nominal: float, ax=None):
    """Feed step of both dogs against the regulator setting b, with neutral and reverse, and the
    range of b over which the chain assembles (the regulator's usable range in this model; the
    source states no range of its own) shaded."""
    ax = ax or plt.gca()
    ok = np.isfinite(sweep["lower_step_mm"]) & np.isfinite(sweep["upper_step_mm"])
    b = np.asarray(sweep["b_deg"], float)
    if ok.any():
        lo, hi = float(b[ok].min()), float(b[ok].max())
        ax.axvspan(lo, hi, color="C2", alpha=0.08,
                   label=f"chain assembles: b = {lo:g} ... {hi:g} deg")
    if (~ok).any():
        bad = b[~ok]
        for k, side in enumerate((bad[bad < lo], bad[bad > hi]) if ok.any() else (bad,)):
            if side.size:
                ax.axvspan(side.min(), side.max(), color="C3", alpha=0.12, lw=0,
                           label="cannot assemble" if k == 0 or not (bad < lo).any() else None)
    ax.plot(sweep["b_deg"], sweep["lower_step_mm"], color="C0", label="lower dog")
    ax.plot(sweep["b_deg"], sweep["upper_step_mm"], color="C1", label="upper dog")
    ax.axhline(0, color="k", lw=0.8)
    ax.axvline(b_nominal, color="0.5", ls=":", label=f"b = {b_nominal:g} deg (data)")
    ax.set_xlabel("regulator setting b (deg)")
    ax.set_ylabel("feed step T (mm; > 0 forward, < 0 reverse)")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7)
    return ax


PLOT_FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}
# the metadata key that would stamp the time into each format (dropped: reruns are identical)
_NO_DATE = {"png": {"Software": None}, "svg": {"Date": None}, "pdf": {"CreationDate": None}}


def save_as(fig, path: Path) -> Path:
    """`save` for any of PLOT_FORMATS, chosen by the file's suffix (the CLI's --plot FILE)."""
    path = Path(path)
    fmt = PLOT_FORMATS[path.suffix.lower()]
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=130, bbox_inches="tight", metadata=_NO_DATE[fmt])
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())
    return path


def presser_cycle(path, lowest_mm: float, material_mm: float, ax=None, label: str = "",
                  shade: bool = True, style: str = "-", seat: bool = True):
    """Seat and foot over one shaft turn (a mechanisms.presser_foot.foot_path frame), drawn as
    heights above the seat's lowest point (mm, up is up); the lost interval shaded."""
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 4))
    th = path["shaft_deg"].to_numpy()
    seat_h = lowest_mm - path["seat_mm"].to_numpy()
    foot = lowest_mm - path["foot_mm"].to_numpy()
    if seat:
        ax.plot(th, seat_h, "k" + style, lw=1.2, label=f"seat D{label}")
    ax.plot(th, foot, "C3" + style, lw=1.6 if style == "-" else 1.0, label=f"foot lug{label}")
    if shade:
        lost = ~path["contact"].to_numpy()
        ax.fill_between(th, 0, 1, where=lost, transform=ax.get_xaxis_transform(),
                        color="C1", alpha=0.15, label="contact lost")
        ax.axhline(lowest_mm - material_mm, color="C2", ls=":", lw=1.0,
                   label="material (foot sole on it)")
    ax.set_xlabel("shaft angle (deg)")
    ax.set_ylabel("height above the seat's lowest point (mm)")
    ax.set_xlim(0, 360)
    ax.set_xticks(range(0, 361, 45))
    ax.grid(alpha=0.3)
    return ax


def grouped_bars(labels, series: dict, ax=None, ylabel: str = "", title: str = "",
                 limit: float | None = None, errors: dict | None = None):
    """One group of bars per label, one bar per series (name -> values in the labels' order),
    optional (low, high) interval per series in `errors` and a dotted `limit` line: the figure
    of the table-shaped studies (scan, strategies, guides, worst case, feed contributors)."""
    ax = ax or plt.gca()
    x = np.arange(len(labels))
    width = 0.8 / max(len(series), 1)
    for i, (name, values) in enumerate(series.items()):
        values = np.asarray(values, dtype=float)
        yerr = None
        if errors and name in errors:
            low, high = (np.asarray(v, dtype=float) for v in errors[name])
            yerr = np.vstack([values - low, high - values])
        ax.bar(x + (i - (len(series) - 1) / 2) * width, values, width, yerr=yerr, capsize=3,
               label=name)
    if limit is not None:
        ax.axhline(limit, color="C3", ls=":", lw=0.8, label=f"limit {limit:g}")
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=30 if len(labels) > 6 else 0, ha="right"
                       if len(labels) > 6 else "center", fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.grid(True, axis="y", lw=0.3)
    ax.legend(fontsize=7)
    return ax


def _yield_band(ax, curve, widths, label, xlabel: str, against: str):
    """A yield curve (%) against an error's width, its 95 % interval as a band."""
    w = np.asarray(widths, float)
    y = curve.yields * 100
    lo, hi = (np.array([c[i] for c in curve.yield_ci]) * 100 for i in (0, 1))
    line, = ax.plot(w, y, marker="o", ms=3, label=label or f"{curve.strategy}")
    ax.fill_between(w, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("yield (%)")
    ax.set_ylim(-2, 102)
    ax.set_title(f"Yield against the {against}, {curve.n} machines "
                 f"({curve.tolerances}, 95 % interval)", fontsize=9)
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7)
    return ax


def yield_vs_setting_error(curve, ax=None, label: str | None = None):
    """The yield of a strategy (%) against one compensator's setting error, with its 95 %
    interval as a band (`sewtol.studies.strategies.yield_curve`'s result)."""
    unit = curve.unit.replace("um", MICRO)
    what = "sd" if curve.dist == "normal" else "half-width"
    return _yield_band(ax or plt.gca(), curve, curve.widths, label,
                       f"{curve.compensator} setting error, {curve.dist} {what} ({unit})",
                       "setting error")


def yield_vs_measurement_error(curve, ax=None, label: str | None = None):
    """The yield of a strategy (%) against the sd of the reading its compensators are set from,
    with its 95 % interval as a band (`sewtol.studies.strategies.measurement_curve`'s result)."""
    return _yield_band(ax or plt.gca(), curve, curve.widths, label,
                       f"reading error of the needle path, normal sd ({MICRO}) at "
                       f"{curve.positions} positions", "measurement error")
