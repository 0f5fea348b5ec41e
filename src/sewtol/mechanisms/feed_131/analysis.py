"""The 131-42+3 feed's own analysis of one machine: trajectories and velocities of the teeth,
the working figures, the stitch regulator (sweep, the b for a step, the b range for a ratio band)
and the source's read-offs with the explanations tested against them. It stays in the folder:
these are the model's own figures and the reconstruction of the source's data, not a tolerance
study; the tolerance studies run on the protocol (sewtol.studies on the folder's
mechanism.toml)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from sewtol.errors import AssemblyError, ParameterError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.feed_131 import model as fd
from sewtol.mechanisms.feed_131.metrics import dog_figures, pair_figures
from sewtol.mechanisms.feed_131.model import Feed131
from sewtol.optimize import bisect_root


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
    out = fd.chains(P.column(params, None), np.radians(phi))
    return pd.DataFrame({"phi_deg": phi, "lower_x_mm": out["Q1"].p.real,
                         "lower_y_mm": out["Q1"].p.imag, "upper_x_mm": out["Q2"].p.real,
                         "upper_y_mm": out["Q2"].p.imag})


@dataclass(frozen=True)
class FeedMetrics:
    lower: dict
    upper: dict
    differential_ratio: float
    mismatch_mm: float
    overlap_deg: float
    settings: dict

    def to_dict(self) -> dict:
        return asdict(self)

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
    """The runs of the grid of b (step_deg apart) where the ratio lies in band: each run's first
    and last b and the ratio there."""
    b = np.arange(b_range[0], b_range[1] + 1e-9, step_deg)
    r = regulator_sweep(params, b)["differential_ratio"].to_numpy()
    inside = np.r_[False, (r >= band[0]) & (r <= band[1]), False]
    lo = np.flatnonzero(inside[1:] & ~inside[:-1])
    hi = np.flatnonzero(inside[:-1] & ~inside[1:]) - 1
    frame = pd.DataFrame({"b_low_deg": b[lo], "b_high_deg": b[hi], "ratio_at_low": r[lo],
                          "ratio_at_high": r[hi]})
    frame.attrs["grid_step_deg"] = step_deg
    return frame


# The source's read-offs from its plots of the program's output (docs/feed_131.md restates
# them): (dog, figure, value). Lower: top point of
# the middle tooth; upper: bottom point of the middle tooth; plate level not stated. The steps
# are read as travel (a length); feed_direction is +1 where the tooth feeds forward (T > 0), as
# the source's dogs both do ("vertical differential": both feed in step).
READOFFS = (
    ("lower", "entry_phi_deg", 202.0), ("lower", "exit_phi_deg", 9.0),
    ("lower", "feed_step_mm", 2.2), ("lower", "feed_direction", 1.0),
    ("lower", "max_rise_mm", 1.1),
    ("lower", "max_rise_phi_deg", 285.0), ("lower", "vertical_travel_mm", 2.2),
    ("upper", "entry_phi_deg", 4.0), ("upper", "exit_phi_deg", 180.0),
    ("upper", "feed_step_mm", 3.1), ("upper", "feed_direction", 1.0),
    ("upper", "max_rise_mm", 1.2),
    ("upper", "max_rise_phi_deg", 102.0), ("upper", "vertical_travel_mm", 2.5),
)


@dataclass(frozen=True)
class Explanation:
    """One way a careful reader could have read the source: parameter changes to the note's
    data and the working side each dog's figures are read on (None: the dog's own)."""

    name: str
    changes: dict
    why: str
    upper_side: str | None = None


def _wrap_deg(r):
    return 180.0 - np.mod(180.0 - np.asarray(r, float), 360.0)


def _phase_misfit(figs, dog: str) -> np.ndarray:
    """Largest |phase residual| (deg) of a dog's entry, exit and rise phase, per machine."""
    src = {f: v for d, f, v in READOFFS if d == dog and f.endswith("_deg")}
    return np.max(np.abs(np.stack([_wrap_deg(getattr(figs, f) - v) for f, v in src.items()])),
                  axis=0)


def _rise_level(params: Feed131, values: dict) -> np.ndarray:
    """Per machine, the plate level at which the lower dog's highest rise is the read 1.1 mm
    (the highest point from a 1 deg grid, Newton-polished on the analytic velocity)."""
    from sewtol.mechanisms.feed_131.metrics import polish_extremes

    c, _ = columns(params.override(**values))
    y = fd.chains(c, np.radians(np.arange(0.0, 360.0, 1.0)).reshape(1, -1))["Q1"].p.imag
    y = np.broadcast_to(y, (c["b"].shape[0], y.shape[-1]))
    _, top = polish_extremes(c, "Q1", np.radians(np.argmax(y, axis=1)).reshape(-1, 1))
    return np.maximum(top.ravel(), y.max(axis=1)) - 1.1


def _grid_fit(params: Feed131, name: str, lo: float, hi: float, step: float, dog: str,
              plate_from_rise: bool, fixed: dict | None = None) -> float:
    """The value of `name` in [lo, hi] with the smallest largest phase residual of `dog`: a grid
    search at `step`, then a grid of step / 20 around the best point (first of ties)."""

    def misfit(grid):
        values = {name: grid, **(fixed or {})}
        if plate_from_rise:
            values["plate_mm"] = _rise_level(params, values)
        c, _ = columns(params.override(**values))
        m = _phase_misfit(dog_figures(c, dog), dog)
        return np.where(np.isfinite(m), m, np.inf)

    grid = np.arange(lo, hi + step / 2, step)
    best = grid[int(np.argmin(misfit(grid)))]
    fine = np.round(best + np.arange(-20, 21) * step / 20, 9)
    return float(fine[int(np.argmin(misfit(fine)))])


def readoff_explanations(params: Feed131) -> tuple[Explanation, ...]:
    """The explanations tested against the read-offs (see docs/feed_131.md). Fitted values come
    from grid searches (2 deg on phases, 2 mm along the bar, then a grid 20 times finer around
    the best), each scored by its dog's largest phase residual."""
    h_rise = round(float(_rise_level(params, {})[0]), 4)
    tooth_u = _grid_fit(params, "tooth1_u", 30.0, 100.0, 2.0, "lower", True)
    h_tooth = round(float(_rise_level(params, {"tooth1_u": np.array([tooth_u])})[0]), 4)
    lift = _grid_fit(params, "lift_phase", 0.0, 358.0, 2.0, "lower", True)
    h_lift = round(float(_rise_level(params, {"lift_phase": np.array([lift])})[0]), 4)
    upper_c = _grid_fit(params, "upper_phase", 0.0, 358.0, 2.0, "upper", False,
                        fixed={"upper_sense": 1.0})
    return (
        Explanation("note", {}, "the note's data, plate y = 32.5 (sewtol's default)"),
        Explanation("plate 30", {"plate_mm": 30.0}, "plate drawn at y = 30"),
        Explanation("plate 33.5", {"plate_mm": 33.5}, "plate drawn at y = 33.5"),
        Explanation(f"plate {h_rise:g}", {"plate_mm": h_rise},
                    "the plate level at which the lower rise is the read 1.1 mm"),
        Explanation("program dog bar", {"dog_bar_program": 1.0},
                    "the program's dog-bar arithmetic (u from EN = 98.66)"),
        Explanation(f"lower tooth at u = {tooth_u:g}", {"tooth1_u": tooth_u, "plate_mm": h_tooth},
                    "another tooth of the lower dog: the point along the bar (30 ... 100 mm "
                    "from E, v = 9.3) fitted to the lower phases, plate at the 1.1 mm rise"),
        Explanation(f"lower lift phase {lift:g}", {"lift_phase": lift, "plate_mm": h_lift},
                    "the lift eccentric's phase fitted to the lower phases (data 224), plate at "
                    "the 1.1 mm rise"),
        Explanation("upper return stroke", {}, "the upper read-offs describe where its tooth is "
                    "above the plate (its return), not below", upper_side="above"),
        Explanation(f"upper {params.upper_phase + 180:g} - phi",
                    {"upper_phase": params.upper_phase + 180.0},
                    f"upper eccentric half a turn off: A2 = O5 + {params.O5A2:g} "
                    f"e({params.upper_phase + 180:g} - phi)"),
        Explanation(f"upper phi + {params.upper_phase:g}", {"upper_sense": 1.0},
                    f"upper shaft turning with the main shaft: A2 = O5 + {params.O5A2:g} "
                    f"e(phi + {params.upper_phase:g})"),
        Explanation(f"upper phi + {upper_c:g}", {"upper_sense": 1.0, "upper_phase": upper_c},
                    "upper shaft turning with the main shaft, its phase fitted to the upper "
                    "phases"),
    )


@dataclass(frozen=True)
class ReadoffResiduals:
    """The model against every read-off of the source, under each explanation."""

    rows: pd.DataFrame  # explanation, dog, figure, source, model, residual
    explanations: tuple[Explanation, ...]

    def to_dataframe(self) -> pd.DataFrame:
        return self.rows.copy()

    def wide(self) -> pd.DataFrame:
        """One row per read-off, model value and residual per explanation side by side."""
        base = self.rows[self.rows.explanation == self.explanations[0].name][
            ["dog", "figure", "source"]].reset_index(drop=True)
        for e in self.explanations:
            r = self.rows[self.rows.explanation == e.name].reset_index(drop=True)
            base[f"{e.name}: model"] = r["model"]
            base[f"{e.name}: residual"] = r["residual"]
        return base

    def summary(self) -> pd.DataFrame:
        """Per explanation: largest |residual| of the phases (deg) and lengths (mm) per dog,
        and how many read-offs it cannot produce (no crossing: NaN)."""
        out = []
        for e in self.explanations:
            r = self.rows[self.rows.explanation == e.name]
            row = {"explanation": e.name, "why": e.why}
            for dog in ("lower", "upper"):
                d = r[r.dog == dog]
                ph = d[d.figure.str.endswith("_deg")]["residual"].abs()
                mm = d[d.figure.str.endswith("_mm")]["residual"].abs()
                sense = d[d.figure == "feed_direction"]["model"].iloc[0]
                row[f"{dog}_feeds"] = ("n/a" if not np.isfinite(sense) else
                                       "forward" if sense > 0 else "reverse")
                row[f"{dog}_max_phase_residual_deg"] = ph.max() if ph.notna().all() else np.nan
                row[f"{dog}_max_length_residual_mm"] = mm.max() if mm.notna().all() else np.nan
            row["not_produced"] = int(r["model"].isna().sum())
            out.append(row)
        return pd.DataFrame(out)


def readoff_residuals(params: Feed131 | None = None,
                      explanations: tuple[Explanation, ...] | None = None) -> ReadoffResiduals:
    """Residual (model - source) of every read-off under each explanation. Phase residuals are
    wrapped to (-180, 180]; the feed step keeps its sign (the source's T is positive forward).
    The step is compared as a length (|T|) and its sense as feed_direction (+1 forward). A
    figure the variant cannot produce (its tooth never crosses the level) is NaN."""

    params = params or Feed131()
    explanations = explanations or readoff_explanations(params)
    rows = []
    for e in explanations:
        c, _ = columns(params.override(**e.changes))
        figs = {"lower": dog_figures(c, "lower").to_dict(),
                "upper": dog_figures(c, "upper", side=e.upper_side).to_dict()}
        for dog, fig, src in READOFFS:
            if fig == "feed_direction":
                model = float(np.sign(figs[dog]["feed_step_mm"]))
            elif fig == "feed_step_mm":
                model = abs(figs[dog][fig])
            else:
                model = figs[dog][fig]
            res = model - src
            if fig.endswith("_deg"):
                res = float(_wrap_deg(res))
            rows.append({"explanation": e.name, "dog": dog, "figure": fig, "source": src,
                         "model": model, "residual": res})
    return ReadoffResiduals(pd.DataFrame(rows), tuple(explanations))
