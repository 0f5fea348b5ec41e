"""Feed chains of the 131-42+3: trajectories, working figures, the stitch regulator and
tolerance studies on the feed step and the differential ratio."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .errors import AssemblyError, ParameterError
from .mechanisms import feed_131 as fd
from .mechanisms import params as P
from .mechanisms.feed_131 import Feed131
from .metrics.feed import pair_figures
from .optimize import bisect_root
from .studies.montecarlo import contributors, sample_machines
from .tolerances import Tolerance, ToleranceSet

OUTPUTS = ("lower_step_mm", "upper_step_mm", "differential_ratio", "mismatch_mm")


def columns(params: Feed131) -> tuple[dict, int]:
    n = P.batch_size(params) or 1
    return {k: np.broadcast_to(np.asarray(v, float).reshape(-1, 1), (n, 1)).copy()
            for k, v in P.column(params, n).items()}, n


def trajectory(params: Feed131, step_deg: float = 1.0) -> pd.DataFrame:
    """Both middle teeth over one turn; raises AssemblyError naming the dyad and angle."""
    if not (0 < step_deg <= 90):
        raise ParameterError("step_deg", "must be in (0, 90]", step_deg)
    phi = np.arange(0.0, 360.0, step_deg)
    fd.check_assembly(params, np.radians(phi))
    c = P.column(params, None)
    out = fd.chains(c, np.radians(phi))
    return pd.DataFrame({"phi_deg": phi, "lower_x_mm": out["Q1"].p.real,
                         "lower_y_mm": out["Q1"].p.imag, "upper_x_mm": out["Q2"].p.real,
                         "upper_y_mm": out["Q2"].p.imag})


def velocities(params: Feed131, step_deg: float = 1.0) -> pd.DataFrame:
    """Tooth velocities per unit main-shaft speed (mm/rad) and accelerations (mm/rad^2)."""
    phi = np.arange(0.0, 360.0, step_deg)
    fd.check_assembly(params, np.radians(phi))
    out = fd.chains(P.column(params, None), np.radians(phi))
    return pd.DataFrame({"phi_deg": phi,
                         "lower_vx": out["Q1"].dp.real, "lower_vy": out["Q1"].dp.imag,
                         "upper_vx": out["Q2"].dp.real, "upper_vy": out["Q2"].dp.imag,
                         "lower_ax": out["Q1"].ddp.real, "lower_ay": out["Q1"].ddp.imag,
                         "upper_ax": out["Q2"].ddp.real, "upper_ay": out["Q2"].ddp.imag})


@dataclass(frozen=True)
class FeedMetrics:
    lower: dict
    upper: dict
    differential_ratio: float
    mismatch_mm: float
    overlap_deg: float
    settings: dict

    def to_dict(self) -> dict:
        return {"lower": self.lower, "upper": self.upper,
                "differential_ratio": self.differential_ratio, "mismatch_mm": self.mismatch_mm,
                "overlap_deg": self.overlap_deg, "settings": self.settings}

    def to_dataframe(self) -> pd.DataFrame:
        rows = [{"dog": d, **getattr(self, d)} for d in ("lower", "upper")]
        return pd.DataFrame(rows)


def metrics(params: Feed131) -> FeedMetrics:
    fd.check_assembly(params, np.radians(np.arange(0.0, 360.0, 0.5)))
    c, _ = columns(params)
    pf = pair_figures(c)
    for dog, figs in (("lower", pf.lower), ("upper", pf.upper)):
        if not figs.ok[0]:
            raise AssemblyError(f"{dog} dog", float("nan"), 0.0, P.as_dict(params),
                                "its tooth does not cross the working level exactly twice a "
                                "turn (plate_mm / material_mm)")
    return FeedMetrics(pf.lower.to_dict(), pf.upper.to_dict(), float(pf.differential_ratio[0]),
                       float(pf.mismatch_mm[0]), float(pf.overlap_deg[0]),
                       {"b_deg": float(params.b), "plate_mm": float(params.plate_mm),
                        "material_mm": float(params.material_mm)})


def outputs(nominal: Feed131, deviations: dict) -> dict:
    """Feed steps, ratio and mismatch of machines nominal + deviations (NaN where they fail)."""
    c, _ = columns(P.with_deviations(nominal, deviations) if deviations else nominal)
    m = len(next(iter(deviations.values()))) if deviations else 1
    c = {k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()}
    pf = pair_figures(c)
    return {"lower_step_mm": pf.lower.feed_step_mm, "upper_step_mm": pf.upper.feed_step_mm,
            "differential_ratio": pf.differential_ratio, "mismatch_mm": pf.mismatch_mm}


def regulator_sweep(params: Feed131, b_deg) -> pd.DataFrame:
    """Stitch length of both dogs against the regulator setting b (NaN where it cannot run)."""
    b = np.asarray(b_deg, float)
    out = outputs(params, {"b": b - params.b})
    return pd.DataFrame({"b_deg": b, **out})


def b_for_step(params: Feed131, step_mm: float, b_range=(0.0, 60.0)) -> float:
    """The regulator setting b (deg) at which the lower dog's feed step is step_mm."""
    lo, hi = b_range
    sweep = regulator_sweep(params, np.linspace(lo, hi, 121))
    f = sweep["lower_step_mm"].to_numpy() - step_mm
    s = np.sign(f)
    k = np.where(np.isfinite(f[:-1]) & np.isfinite(f[1:]) & (s[:-1] * s[1:] <= 0))[0]
    if not len(k):
        ok = sweep["lower_step_mm"].dropna()
        raise ParameterError("step_mm", f"must lie within the regulator's range "
                             f"{ok.min():.3f} ... {ok.max():.3f} mm for b in {b_range}", step_mm)
    b = sweep["b_deg"].to_numpy()
    root = bisect_root(lambda x: outputs(params, {"b": x - params.b})["lower_step_mm"] - step_mm,
                       np.array([b[k[0]]]), np.array([b[k[0] + 1]]), xtol=1e-9)
    return float(root[0])


def b_range_for_ratio(params: Feed131, band=(1.0, 1.2), b_range=(0.0, 60.0),
                      step_deg: float = 0.25) -> pd.DataFrame:
    """Intervals of b (on a grid, edges refined by bisection) where the ratio lies in band."""
    b = np.arange(b_range[0], b_range[1] + 1e-9, step_deg)
    r = regulator_sweep(params, b)["differential_ratio"].to_numpy()
    inside = (r >= band[0]) & (r <= band[1])
    rows = []
    k = 0
    while k < len(b):
        if inside[k]:
            j = k
            while j + 1 < len(b) and inside[j + 1]:
                j += 1
            rows.append({"b_low_deg": b[k], "b_high_deg": b[j],
                         "ratio_at_low": r[k], "ratio_at_high": r[j]})
            k = j + 1
        else:
            k += 1
    frame = pd.DataFrame(rows, columns=["b_low_deg", "b_high_deg", "ratio_at_low",
                                        "ratio_at_high"])
    frame.attrs["grid_step_deg"] = step_deg
    return frame


def default_tolerances(params: Feed131 | None = None, link_mm: float = 0.05,
                       pivot_mm: float = 0.05) -> ToleranceSet:
    """An assumed set (the source gives no feed tolerances): every link length +/- link_mm and
    every frame-pivot coordinate +/- pivot_mm, uniform."""
    names = list(Feed131.LENGTHS)
    pivots = [f for f in P.field_names(Feed131) if f[-1] in "xy" and f[:-1] in
              ("O2", "O3", "O4", "O5", "O6", "O7", "O8", "X", "U")]
    items = tuple(Tolerance(n, -link_mm, link_mm) for n in names) + \
        tuple(Tolerance(n, -pivot_mm, pivot_mm) for n in pivots)
    return ToleranceSet("feed_assumed", items,
                        f"assumed: links +/-{link_mm} mm, frame pivots +/-{pivot_mm} mm, uniform")


def scan(params: Feed131, tolerances: ToleranceSet) -> pd.DataFrame:
    """Each tolerance at its limits, others nominal: feed steps and ratio, and their changes."""
    names, sides, deltas, dev = tolerances.limit_variants()
    out = outputs(params, dev)
    nom = outputs(params, {})
    frame = pd.DataFrame({"param": names, "side": sides, "delta_mm": deltas, **out})
    for k in ("lower_step_mm", "upper_step_mm", "differential_ratio"):
        frame[f"change_{k}"] = frame[k] - float(nom[k][0])
    return frame


def montecarlo(params: Feed131, tolerances: ToleranceSet, n: int, seed: int, n_jobs: int = 1,
               progress: bool = False) -> pd.DataFrame:
    return sample_machines(outputs, params, tolerances, n, seed, n_jobs, progress,
                           desc="feed Monte-Carlo")


def montecarlo_summary(machines: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for k in OUTPUTS:
        x = machines[k]
        ok = x.dropna()
        rows.append({"output": k, "n": len(x), "failed": int(x.isna().sum()),
                     "mean": ok.mean(), "std": ok.std(ddof=1), "p1": ok.quantile(0.01),
                     "p99": ok.quantile(0.99), "min": ok.min(), "max": ok.max()})
    return pd.DataFrame(rows)


def contributor_table(machines: pd.DataFrame, tolerances: ToleranceSet, top: int = 10):
    frames = []
    for k in ("lower_step_mm", "differential_ratio", "mismatch_mm"):
        f = contributors(machines, tolerances.active().params, k).head(top)
        f.insert(0, "output", k)
        frames.append(f)
    return pd.concat(frames, ignore_index=True)
