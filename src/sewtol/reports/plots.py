"""Plots a designer would otherwise draw by hand. Each takes data and an ax and returns the ax."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
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
