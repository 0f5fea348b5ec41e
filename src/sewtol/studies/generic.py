"""Studies of any mechanism file (sewtol.mechanism.FileMechanism) and its outputs.

Nothing here names a mechanism: a study takes the mechanism, a tolerance set and the output(s)
it looks at, and returns a frozen result with to_dataframe() and to_dict(). The scan, the
worst case and the Sobol indices are sewtol.studies.scan, worst_case and sobol.

- nominal: every output of the nominal machine.
- montecarlo: n machines drawn exactly as studies.montecarlo.sample_machines draws them (chunk i
  from child i of the seed: same seed, same table, for any n_jobs); every machine keeps its
  status, so ok + out_of_spec + cannot_close + dead_point = n; out_of_spec by the file's
  [[specs]] unless limits are given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from sewtol.errors import AssemblyError, ParameterError
from sewtol.mechanism.spec import Spec
from sewtol.studies import montecarlo as mc
from sewtol.tolerances import ToleranceSet

CHUNK = mc.CHUNK


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


# --- Monte-Carlo ---------------------------------------------------------------------------

def _file_model(record, dev, mech, outputs, compensator=None, target=None):
    values = deviated_values(mech, dev)
    ev = mech.evaluate(values, outputs)
    out = {**ev.outputs, "status": ev.status, "failed_group": ev.failed_group}
    if compensator is not None:
        a = optimise_compensator(mech, values, target, compensator)
        out.update({f"{target}_adjusted": a.value,
                    f"{mech.compensators[compensator].parameter}_setting": a.setting,
                    "status_adjusted": a.status, "failed_group_adjusted": a.failed_group})
    return out


@dataclass(frozen=True)
class GenericMonteCarloResult:
    mechanism: str
    machines: pd.DataFrame  # machine, deviations, outputs, status, failed_group
    outputs: tuple[str, ...]
    tolerances: str
    seed: int
    limit_output: str  # the spec'd output of the JSON's cases (its spec may be None)
    specs: tuple[Spec, ...] = ()  # the limits in force, at most one per output
    spec_source: str | None = None  # of limit_output's spec: "file", "command line" or None
    adjust: str | None = None  # the compensator of the adjusted case (column NAME_adjusted)
    unit: str = ""  # limit_output's unit

    @property
    def n(self) -> int:
        return len(self.machines)

    @property
    def adjusted_output(self) -> str | None:
        return None if self.adjust is None else f"{self.limit_output}_adjusted"

    def spec(self, output: str | None = None) -> Spec | None:
        """The limits in force for an output (its adjusted case keeps the output's limits)."""
        if output is None or output == self.adjusted_output:
            output = self.limit_output
        return next((s for s in self.specs if s.output == output), None)

    def cases(self) -> dict[str, str]:
        """Case name -> column: "fixed" (every machine as drawn), or with a compensator C the
        cases "fixed_C" (C at its nominal) and "adjusted_C" (C set per machine)."""
        if self.adjust is None:
            return {"fixed": self.limit_output}
        return {f"fixed_{self.adjust}": self.limit_output,
                f"adjusted_{self.adjust}": self.adjusted_output}

    def status(self, output: str | None = None) -> np.ndarray:
        """Per machine: ok, out_of_spec (outside the output's spec; no value fails a spec),
        cannot_close, dead_point (the adjusted case: at the machine's chosen setting)."""
        col = "status_adjusted" if output is not None and output == self.adjusted_output \
            else "status"
        s = self.machines[col].to_numpy(object).copy()
        spec = self.spec(output) if output is not None else None
        if spec is not None:
            s[(s == "ok") & ~spec.passes(self.machines[output].to_numpy(float))] = "out_of_spec"
        return s

    def counts(self, output: str | None = None) -> dict[str, int]:
        """ok + out_of_spec + failed = n, failed = cannot_close + dead_point (+ unexplained,
        always 0 here: the keys of the needle's counts)."""
        s = self.status(output)
        c = {k: int(np.sum(s == k)) for k in ("ok", "out_of_spec", "cannot_close", "dead_point",
                                              "unexplained")}
        c["failed"] = c["cannot_close"] + c["dead_point"]
        c["n"] = int(s.size)
        return c

    def failed_groups(self, adjusted: bool = False) -> dict[str, int]:
        g = self.machines["failed_group_adjusted" if adjusted else "failed_group"]
        return {str(k): int(v) for k, v in g[g != ""].value_counts().sort_index().items()}

    def to_dataframe(self) -> pd.DataFrame:
        """One row per machine: deviations, outputs, status and the group that failed."""
        return self.machines.copy()

    def summary_frame(self) -> pd.DataFrame:
        rows = []
        for name in self.outputs:
            v = self.machines[name].to_numpy(float)
            ok = v[~np.isnan(v)]
            c = self.counts(name)
            row = {"output": name, **{k: c[k] for k in ("n", "ok", "out_of_spec",
                                                         "cannot_close", "dead_point")}}
            # machines that run but whose output has no value (e.g. the contact-loss angle of a
            # presser foot that never loses contact): counted here, left out of the statistics
            running = np.isin(self.status(name), ("ok", "out_of_spec"))
            row["undefined"] = int(np.sum(running & np.isnan(v)))
            if ok.size:
                q = np.quantile(ok, [0.5, 0.95, 0.99])
                row.update({"mean": float(ok.mean()),
                            "std": float(ok.std(ddof=1)) if ok.size > 1 else float("nan"),
                            "min": float(ok.min()), "p50": q[0], "p95": q[1], "p99": q[2],
                            "max": float(ok.max())})
            else:
                row.update(dict.fromkeys(("mean", "std", "min", "p50", "p95", "p99", "max"),
                                         float("nan")))
            spec = self.spec(name)
            if spec is not None:
                k = c["ok"]
                ci = stats.binomtest(k, c["n"]).proportion_ci(0.95, method="exact")
                row.update({"limit": spec.upper, "lower_limit": spec.lower, "yield": k / c["n"],
                            "yield_ci_low": float(ci.low), "yield_ci_high": float(ci.high)})
            rows.append(row)
        return pd.DataFrame(rows)

    def to_dict(self) -> dict:
        """The Monte-Carlo JSON every path shares (studies.montecarlo.record); extra: the
        compensator, the groups that failed per case and the summary of every output."""
        cases = self.cases()
        return mc.record(
            mechanism=self.mechanism, n=self.n, seed=self.seed, tolerances=self.tolerances,
            output=self.limit_output, unit=self.unit, spec=self.spec(),
            counts={c: self.counts(o) for c, o in cases.items()},
            quantiles={c: mc.quantiles(self.machines[o]) for c, o in cases.items()},
            extra={"adjust": self.adjust, "failed_groups": self.failed_groups(),
                   **({} if self.adjust is None else {
                       "failed_groups_adjusted": self.failed_groups(adjusted=True)}),
                   "summary": self.summary_frame().to_dict("records")})


def montecarlo(mech, tolerances: ToleranceSet, n: int, seed: int, outputs=None,
               limit: float | None = None, limit_output: str | None = None, n_jobs: int = 1,
               progress=False, chunk_size: int = CHUNK, adjust: str | None = None,
               lower_limit: float | None = None) -> GenericMonteCarloResult:
    """n machines of the file (see the module doc). Every output with a [[specs]] entry in the
    file splits its ok machines into ok and out_of_spec; `limit`/`lower_limit` replace the
    spec of limit_output (default: the first output studied with limits given, else the first
    output of the file's specs, else the first output). `adjust` (a compensator of the file)
    adds the adjusted case: limit_output minimised over the compensator on each machine
    (`optimise_compensator`), columns NAME_adjusted, PARAM_setting, status_adjusted,
    failed_group_adjusted."""
    names = tuple(mech.output_names if outputs is None else outputs)
    for name in names:
        mech.output(name)
    if adjust is not None and adjust not in mech.compensators:
        raise ParameterError("adjust", "must name a compensator of the file ("
                             + (", ".join(mech.compensators) or "it has none") + ")", adjust)
    given = limit is not None or lower_limit is not None
    if limit_output is None and (given or not mech.specs):
        limit_output = names[0]
    limit_output, spec, source = mech.resolve_spec(limit_output, limit, lower_limit)
    if limit_output not in names:
        names = (*names, limit_output)
    specs = tuple(s for s in mech.specs if s.output in names and s.output != limit_output)
    specs += () if spec is None else (spec,)
    record = mech.parameter_record()
    mc.check_seed(seed)
    mc.check_sampling(record, tolerances, n, seed, chunk_size,
                      columns=len(tolerances.items) + len(names) + 3)
    machines = mc.sample_machines(_file_model, record, tolerances, n, seed, n_jobs, progress,
                                  chunk_size=chunk_size, desc=f"Monte-Carlo {mech.name}",
                                  mech=mech, outputs=list(names), compensator=adjust,
                                  target=limit_output)
    if adjust is not None:
        names = (*names, f"{limit_output}_adjusted")
    return GenericMonteCarloResult(mech.name, machines, names, tolerances.name, int(seed),
                                   limit_output, specs, source, adjust,
                                   mech.output(limit_output).unit)

