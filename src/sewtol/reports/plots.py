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
