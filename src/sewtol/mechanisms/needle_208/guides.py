"""Guide settings compared in one table: beta*, SumDelta, window and the Monte-Carlo yields (an
instance of sewtol.studies.settings: each guide placement a named setting of the design).

With `strategy=` every variant's machines (the same n machines for every variant, and the
same ones `montecarlo` draws from the seed: common random numbers) are adjusted by the strategy's exact joint
optimum (needle_208.adjustment.adjust), its compensators acting on top of the variant's guide; the
row then gives the yield after the strategy with its counts (ok + out_of_spec +
cannot_assemble + dead_point = n) and the yield with beta fixed at the variant's beta* on the
same machines.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208.single import nominal_figures
from sewtol.mechanisms.needle_208.tables import montecarlo
from sewtol.studies.montecarlo import check_sampling, draw_deviations
from sewtol.studies.settings import Setting, compare
from sewtol.tolerances import ToleranceSet, needle_set

if TYPE_CHECKING:
    from distributed import Client

    from sewtol.mechanisms.needle_208.compensators import Strategy
    from sewtol.mechanisms.needle_208.model import Needle208

DEFAULT_VARIANTS = (
    ("nominal", 0.0, 0.0),
    ("shift +50 um", 50.0, 0.0),
    ("shift -50 um", -50.0, 0.0),
    ("angle +0.02 deg", 0.0, 0.02),
    ("angle -0.02 deg", 0.0, -0.02),
)


def compare_guides(nominal: Needle208, tolerances: ToleranceSet | str, n: int, seed: int,
                   variants: Sequence[tuple[str, float, float]] = DEFAULT_VARIANTS,
                   range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
                   n_jobs: int = 1, progress: bool | Callable[[int, int], None] = False,
                   scheduler: str | Client | None = None, strategy: Strategy | None = None,
                   limit_um: float = sb.DEFAULT_LIMIT_UM) -> pd.DataFrame:
    """One row per guide setting (shift um along the guide normal, turn deg about its point).

    Every setting sees the same machines (the ones `montecarlo` draws from the seed), so the
    rows differ by the guide alone.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    tolerances : ToleranceSet or str
        What the machines draw from.
    n : int
        Monte-Carlo machines per setting.
    seed : int
        The seed (>= 0), as in `montecarlo`.
    variants : sequence of (str, float, float)
        ``(label, shift_um, turn_deg)`` per setting: a shift along the guide's normal (um) and
        a turn about its point (deg). Default: nominal, +/-50 um, +/-0.02 deg.
    range_deg : tuple of float
        The regulating range for beta, (low, high) in deg.
    n_jobs : int
        Worker processes on this machine; the table does not depend on it.
    progress : bool or callable
        True: a bar on stderr; or ``progress(done, total)`` as chunks finish.
    scheduler : str, distributed.Client or None
        A Dask scheduler address or client.
    strategy : Strategy or None
        None: beta re-optimised per machine. A strategy: its joint optimum on top of each
        setting, with the counts after it.
    limit_um : float
        The SumDelta limit (um).

    Returns
    -------
    pandas.DataFrame
        Per setting: ``guide``, ``shift_um``, ``angle_from_vertical_deg``, ``beta_opt_deg``,
        ``total_um`` (nominal SumDelta at beta*), the beta window (deg) and the yields with
        beta fixed and adjusted (or after the strategy, with its counts).
    """
    tolerances = needle_set(tolerances)
    settings = [Setting(label, {"guide_shift_um": nominal.guide_shift_um + shift_um,
                                "guide_angle": nominal.guide_angle + dangle},
                        {"shift_um": shift_um}) for label, shift_um, dangle in variants]
    if strategy is not None:
        return compare(nominal, settings, _adjusted_figures(nominal, tolerances, n, seed,
                                                            range_deg, strategy, limit_um),
                       "guide").to_dataframe()

    def figures(p, setting):
        fig, row = _guide_figures(p, range_deg, limit_um)
        mc = montecarlo(p.override(beta=fig.beta_opt_deg), tolerances, n, seed,
                        limit_um=limit_um, range_deg=range_deg, n_jobs=n_jobs,
                        progress=progress, scheduler=scheduler)
        return {**row, "yield_fixed_beta": mc.yield_of("fixed"),
                "yield_adjusted_beta": mc.yield_of("adjusted"), "failed": mc.failed}
    return compare(nominal, settings, figures, "guide").to_dataframe()


def _guide_figures(p, range_deg, limit_um=sb.DEFAULT_LIMIT_UM):
    """The nominal figures of the machine with a guide setting, and the row's columns."""
    fig = nominal_figures(p, range_deg, limit_um)
    row = {"angle_from_vertical_deg": p.guide_angle,
           "beta_opt_deg": fig.beta_opt_deg, "total_um": fig.total_um,
           "window_low_deg": fig.window_deg[0], "window_high_deg": fig.window_deg[1],
           "window_width_deg": fig.window_deg[1] - fig.window_deg[0]
           if np.all(np.isfinite(fig.window_deg)) else np.nan,
           "beta_at_bound": fig.beta_at_bound}
    return fig, row


def _adjusted_figures(nominal, tolerances, n, seed, range_deg, strategy, limit_um):
    """Each setting's figures with the strategy's joint optimum on the same machines."""
    from sewtol.mechanisms.needle_208.adjustment import adjust, columns_of
    from sewtol.mechanisms.needle_208.compensators import Strategy

    check_sampling(nominal, tolerances, n, seed)  # as montecarlo checks the same machines
    dev = draw_deviations(tolerances, n, seed)  # montecarlo's machines for this seed

    def figures(p, setting):
        fig, row = _guide_figures(p, range_deg, limit_um)
        c = columns_of(p.override(beta=fig.beta_opt_deg), dev)
        fixed = adjust(c, Strategy("none"), limit_um)
        adj = adjust(c, strategy, limit_um, plateaus=False)
        k = adj.counts()
        return {
            **row,
            "yield_fixed_beta": float(np.mean(fixed.status == "ok")),
            "strategy": strategy.name, "yield_adjusted": k["ok"] / adj.n,
            "n": adj.n, "ok": k["ok"], "out_of_spec": k["out of spec"],
            "cannot_assemble": k["cannot assemble"], "dead_point": k["dead point"],
            "p95_after_um": float(np.percentile(np.where(np.isfinite(adj.total_um),
                                                         adj.total_um, np.inf), 95)),
        }
    return figures
