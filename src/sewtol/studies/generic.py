"""Studies of any mechanism file (sewtol.mechanism.FileMechanism) and its outputs.

Nothing here names a mechanism: a study takes the mechanism, a tolerance set and the output(s)
it looks at, and returns a frozen result with to_dataframe() and to_dict(). The scan, the
worst case, the Monte-Carlo and the Sobol indices are sewtol.studies.scan, worst_case,
montecarlo_study and sobol.

- nominal: every output of the nominal machine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from sewtol.errors import AssemblyError, ParameterError


def deviated_values(mech, dev: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    nominal = mech.nominal_values()
    return {k: nominal[k] + np.asarray(v, float) for k, v in dev.items()}


# --- adjustment at assembly: an output minimised over one compensator ----------------------

# settings of the first pass over the compensator's range, then golden-section steps inside the
# brackets of its BASINS best local minima: 25 + 3 * 32 evaluations per machine, each bracket
# (two grid steps) shrunk by 0.618^30 = 5e-7
ADJUST_GRID, ADJUST_ITERATIONS, BASINS = 25, 30, 3
_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class Adjusted:
    """Per machine: the smallest output over the compensator's range, the setting that gives it,
    and the status there (at the nominal setting when no setting in the range runs)."""

    value: np.ndarray
    setting: np.ndarray
    status: np.ndarray
    failed_group: np.ndarray


def optimise_compensator(mech, values: dict | None, output: str, compensator: str,
           grid: int = ADJUST_GRID, iterations: int = ADJUST_ITERATIONS) -> Adjusted:
    """Minimise `output` over compensator `compensator` (a [compensators.NAME] of the file) on
    each machine of `values` (absolute parameter values; the rest nominal): a grid of `grid`
    settings over [low, high], then golden-section search in the brackets of the BASINS best
    local minima of the grid. Exact for an output unimodal in the compensator near those
    minima; a basin narrower than two grid steps can be missed (not proven global)."""
    mech.output(output)
    if compensator not in mech.compensators:
        raise ParameterError("adjust", "must name a compensator of the file ("
                             + (", ".join(mech.compensators) or "it has none") + ")", compensator)
    comp = mech.compensators[compensator]
    cols, m = mech.columns(values)
    base = {k: np.asarray(v, float)[:, 0] for k, v in cols.items()}

    def f(x, reps=1):
        # machine j repeated `reps` times, next to each other, against the settings x
        y = mech.evaluate({**{k: np.repeat(v, reps) for k, v in base.items()},
                           comp.parameter: x}, [output]).outputs[output]
        return np.where(np.isnan(y), np.inf, y)

    s = np.linspace(comp.low, comp.high, grid)
    y = f(np.tile(s, m), grid).reshape(m, grid)
    # refine the BASINS best local minima of the grid (an output such as SumDelta can have two
    # nearly equal basins far apart); candidate c of machine j sits at j * BASINS + c
    padded = np.pad(y, ((0, 0), (1, 1)), constant_values=np.inf)
    local = (y <= padded[:, :-2]) & (y <= padded[:, 2:]) & np.isfinite(y)
    k = np.argsort(np.where(local, y, np.inf), axis=1, kind="stable")[:, :BASINS].ravel()
    a = s[np.maximum(k - 1, 0)]
    b = s[np.minimum(k + 1, grid - 1)]
    best_x, best_y = s[k], np.repeat(y, BASINS, axis=0)[np.arange(k.size), k]
    c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
    fc, fd = f(c, BASINS), f(d, BASINS)
    for x, fx in ((c, fc), (d, fd)):
        better = fx < best_y
        best_x, best_y = np.where(better, x, best_x), np.where(better, fx, best_y)
    for _ in range(iterations):
        left = fc <= fd  # the minimum is in [a, d]
        a, b = np.where(left, a, c), np.where(left, d, b)
        c_new = np.where(left, b - _GOLDEN * (b - a), d)
        d_new = np.where(left, c, a + _GOLDEN * (b - a))
        x = np.where(left, c_new, d_new)
        fx = f(x, BASINS)
        fc, fd = np.where(left, fx, fd), np.where(left, fc, fx)
        c, d = c_new, d_new
        better = fx < best_y
        best_x, best_y = np.where(better, x, best_x), np.where(better, fx, best_y)
    pick = np.argmin(best_y.reshape(m, BASINS), axis=1)
    best_x = best_x.reshape(m, BASINS)[np.arange(m), pick]
    best_y = best_y.reshape(m, BASINS)[np.arange(m), pick]
    runs = np.isfinite(best_y)
    setting = np.where(runs, best_x, base[comp.parameter])
    ev = mech.evaluate({**base, comp.parameter: setting}, [output])
    return Adjusted(ev.outputs[output], setting, ev.status, ev.failed_group)


# --- nominal -------------------------------------------------------------------------------

@dataclass(frozen=True)
class NominalResult:
    mechanism: str
    rows: pd.DataFrame  # output, unit, value, doc

    def to_dataframe(self) -> pd.DataFrame:
        return self.rows

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "status": "ok",
                "outputs": {r["output"]: r["value"] for r in self.rows.to_dict("records")},
                "rows": self.rows.to_dict("records")}


def nominal(mech) -> NominalResult:
    """Every output of the nominal machine; AssemblyError if it cannot run a full turn."""
    ev = mech.evaluate()
    if ev.status[0] != "ok":
        g, status = ev.failed_group[0], ev.status[0]
        state = mech.state()
        cl = state.closures[g]
        if status == "cannot_close":
            miss = np.nan_to_num(np.broadcast_to(cl.miss_mm, state.shape)[0], nan=np.inf)
            k = int(np.argmax(miss))
            raise AssemblyError(g, np.degrees(state.q_rad[k]), float(miss[k]),
                                mech.nominal_values(), "driving angle q of "
                                f"{mech.path}; the nominal machine cannot make a full turn")
        t = np.broadcast_to(cl.transmission_deg, state.shape)[0]
        k = int(np.nanargmin(t))
        raise AssemblyError(g, np.degrees(state.q_rad[k]), 0.0, mech.nominal_values(),
                            f"driving angle q of {mech.path}; dead point: the links are "
                            f"{float(t[k]):.3f} deg from collinear (< 1), the joint can flip to "
                            "its other assembly (branch flip)")
    rows = pd.DataFrame([{"output": o.name, "unit": o.unit, "value": float(ev.outputs[o.name][0]),
                          "doc": o.doc} for o in mech.outputs])
    return NominalResult(mech.name, rows)


