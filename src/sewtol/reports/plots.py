"""Plots a designer would otherwise draw by hand. Each takes data and an ax and returns the ax."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
matplotlib.rcParams["svg.hashsalt"] = "sewtol"  # fixed SVG ids: reruns are byte-identical
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..io import write_bytes_atomic  # noqa: E402


def deviation_vs_crank(curves: dict, ax=None, limit_um: float | None = None):
    """d(phi) in um against crank angle for each labelled frame (columns phi_deg, d_um)."""
    ax = ax or plt.gca()
    for label, frame in curves.items():
        ax.plot(frame["phi_deg"], frame["d_um"], label=label, lw=1.2)
    if limit_um is not None:
        ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_xlabel("crank angle phi (deg)")
    ax.set_ylabel("deviation d from the guide (um)")
    ax.set_xlim(0, 360)
    ax.set_xticks(np.arange(0, 361, 60))
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7)
    return ax


def sum_delta_vs_beta(betas, totals_um, beta_opt: float, window: tuple[float, float],
                      limit_um: float, ax=None):
    """SumDelta against beta with the limit line and the window where it holds."""
    ax = ax or plt.gca()
    ax.plot(betas, totals_um, color="C0", label="SumDelta, guide fixed")
    ax.axhline(limit_um, color="C3", ls="--", lw=1, label=f"limit {limit_um:g} um")
    if np.all(np.isfinite(window)):
        ax.axvspan(window[0], window[1], color="C2", alpha=0.15,
                   label=f"window {window[0]:.2f} ... {window[1]:.2f} deg")
    ax.axvline(beta_opt, color="C1", lw=1, label=f"beta* = {beta_opt:.2f} deg")
    ax.set_xlabel("regulating angle beta (deg)")
    ax.set_ylabel("total deviation SumDelta (um)")
    ax.set_ylim(bottom=0)
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7)
    return ax


def save(fig, path: Path) -> Path:
    """PNG without timestamps in its metadata, written atomically, so reruns are byte-identical."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=130, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    write_bytes_atomic(Path(path), buf.getvalue())
    return Path(path)


def scan_deviation_grid(nominal_curve, limit_curves: dict, limit_um: float = 10.0):
    """One panel per parameter: d(phi) nominal against the upper and lower limit (beta*)."""
    k = len(limit_curves)
    cols = 3
    rows = int(np.ceil(k / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(11, 2.8 * rows), sharex=True, squeeze=False)
    for ax, (param, curves) in zip(axes.ravel(), limit_curves.items(), strict=False):
        ax.plot(nominal_curve["phi_deg"], nominal_curve["d_um"], color="0.3", lw=1, label="nominal")
        for (label, frame), color in zip(curves.items(), ("C3", "C0"), strict=False):
            ax.plot(frame["phi_deg"], frame["d_um"], color=color, lw=1, label=label)
        ax.axhline(limit_um / 2, color="C3", ls=":", lw=0.6)
        ax.axhline(-limit_um / 2, color="C3", ls=":", lw=0.6)
        ax.set_title(param, fontsize=9)
        ax.set_ylabel("d (um)")
        ax.grid(True, lw=0.3)
        ax.legend(fontsize=6)
    for ax in axes.ravel()[k:]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("crank angle phi (deg)")
        ax.set_xticks(np.arange(0, 361, 90))
    return fig


def montecarlo_histograms(fixed_um, adjusted_um, limit_um: float, yields: tuple[float, float],
                          ax=None):
    """Histograms of SumDelta with beta fixed and with beta adjusted, the limit and the yields."""
    ax = ax or plt.gca()
    data = [np.asarray(x)[np.isfinite(x)] for x in (fixed_um, adjusted_um)]
    top = max(np.quantile(np.concatenate(data), 0.995), limit_um * 1.5)
    bins = np.linspace(0, top, 60)
    ax.hist(data[0], bins=bins, alpha=0.5, color="C1", label=f"beta fixed, yield {yields[0]:.1%}")
    ax.hist(data[1], bins=bins, alpha=0.5, color="C0",
            label=f"beta adjusted, yield {yields[1]:.1%}")
    ax.axvline(limit_um, color="C3", ls="--", lw=1, label=f"limit {limit_um:g} um")
    ax.set_xlabel("total deviation SumDelta (um)")
    ax.set_ylabel("machines")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7)
    return ax


def beta_histogram(beta_deg, range_deg, ax=None):
    ax = ax or plt.gca()
    b = np.asarray(beta_deg)[np.isfinite(beta_deg)]
    ax.hist(b, bins=50, color="C2", alpha=0.7)
    for edge in range_deg:
        ax.axvline(edge, color="0.4", ls=":", lw=1)
    ax.set_xlabel("beta* per machine (deg)")
    ax.set_ylabel("machines")
    ax.grid(True, lw=0.3)
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


def tooth_paths(traj, plate_mm: float, material_mm: float = 0.0, ax=None):
    """Both middle-tooth paths with the plate line (and the material's top, if any)."""
    ax = ax or plt.gca()
    for dog, color in (("lower", "C0"), ("upper", "C1")):
        x, y = traj[f"{dog}_x_mm"], traj[f"{dog}_y_mm"]
        ax.plot(np.r_[x, x[:1]], np.r_[y, y[:1]], color=color, label=f"{dog} dog, middle tooth")
        ax.annotate("", xy=(x.iloc[6], y.iloc[6]), xytext=(x.iloc[0], y.iloc[0]),
                    arrowprops={"arrowstyle": "->", "color": color})
    ax.axhline(plate_mm, color="k", lw=1, label=f"needle plate y = {plate_mm:g} mm")
    if material_mm > 0:
        ax.axhline(plate_mm + material_mm, color="0.5", ls="--", lw=1,
                   label=f"material top (+{material_mm:g} mm)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    return ax


def feed_xy_vs_phi(traj, plate_mm: float, axes):
    """x and y of both teeth against the main-shaft angle, on two axes."""
    for dog, color in (("lower", "C0"), ("upper", "C1")):
        axes[0].plot(traj["phi_deg"], traj[f"{dog}_x_mm"], color=color, label=f"{dog} dog")
        axes[1].plot(traj["phi_deg"], traj[f"{dog}_y_mm"], color=color, label=f"{dog} dog")
    axes[1].axhline(plate_mm, color="k", lw=1, label="needle plate")
    axes[0].set_ylabel("x (mm)")
    axes[1].set_ylabel("y (mm)")
    for ax in axes:
        ax.set_xlabel("main-shaft angle phi (deg)")
        ax.set_xlim(0, 360)
        ax.set_xticks(np.arange(0, 361, 60))
        ax.grid(True, lw=0.3)
        ax.legend(fontsize=7)
    return axes


def regulator_curve(sweep, b_nominal: float, ax=None):
    """Feed step of both dogs against the regulator setting b, with neutral and reverse."""
    ax = ax or plt.gca()
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
