"""Studies of any mechanism file (sewtol.mechanism.FileMechanism) and its outputs.

Nothing here names a mechanism: a study takes the mechanism, a tolerance set and the output(s)
it looks at, and returns a frozen result with to_dataframe() and to_dict().

- nominal: every output of the nominal machine.
- scan: each toleranced parameter at its upper and lower limit, the others nominal.
- worst_case: the largest and smallest value of one output over the tolerance box: every
  corner and the centre, then L-BFGS-B from the best corner inside the box. Not proven global:
  the corner answer is exact only if the output is monotone in each parameter over the box
  (`monotone_on_axes` checks that along the axes through the centre, which supports but does not
  prove it).
- montecarlo: n machines drawn exactly as studies.montecarlo.sample_machines draws them (chunk i
  from child i of the seed: same seed, same table, for any n_jobs); every machine keeps its
  status, so ok + out_of_spec + cannot_close + dead_point = n.
- sobol: first and total Sobol indices of one output with studies.sobol (SALib); a sample with
  machines that cannot run is refused in one line.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats
from scipy.optimize import minimize

from sewtol import adjuster as ADJ
from sewtol.errors import AssemblyError, ParameterError
from sewtol.studies import montecarlo as mc
from sewtol.studies import sobol as so
from sewtol.tolerances import ToleranceSet

MAX_CORNER_PARAMS = 12
# central-difference step of the local search, as a fraction of each tolerance width
FD_STEP = 1e-4
CHUNK = mc.CHUNK


def _values(mech, dev: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    nominal = mech.nominal_values()
    return {k: nominal[k] + np.asarray(v, float) for k, v in dev.items()}


def _check_tolerances(mech, tolerances: ToleranceSet) -> ToleranceSet:
    tol = tolerances.active()
    if not tol.items:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    tolerances.check_against(mech.parameter_record())
    return tol


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


# --- scan ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class ScanResult:
    mechanism: str
    tolerances: str
    rows: pd.DataFrame

    def to_dataframe(self) -> pd.DataFrame:
        return self.rows

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "tolerances": self.tolerances,
                "rows": self.rows.to_dict("records")}


def scan(mech, tolerances: ToleranceSet, outputs=None, adjust=None,
         objective=None) -> ScanResult:
    """Each toleranced parameter at its upper and lower limit (others nominal): every output's
    value and change from nominal; machines that cannot run keep their status. With `adjust`
    (compensators: a name, "a,b" or a list; sewtol.adjuster), rows NAME_adjusted add the first
    output adjusted for `objective` (default minimised) with the settings (`setting` for one
    compensator, PARAM_setting for several)."""
    tol = _check_tolerances(mech, tolerances)
    names = mech.output_names if outputs is None else list(outputs)
    base = nominal(mech).rows.set_index("output")["value"]
    params, sides, deltas, dev = tol.limit_variants()
    values = _values(mech, dev)
    ev = mech.evaluate(values, names)
    adj = adj0 = None
    if adjust is not None:
        adj = ADJ.adjust(mech, values, names[0], adjust, objective)
        adj0 = ADJ.adjust(mech, None, names[0], adjust, objective)
    rows = []
    for i, (p, s, d) in enumerate(zip(params, sides, deltas, strict=True)):
        for name in names:
            v = float(ev.outputs[name][i])
            rows.append({"param": p, "side": s, "deviation": d, "output": name,
                         "nominal": float(base[name]), "value": v,
                         "change": v - float(base[name]), "status": ev.status[i],
                         "failed_group": ev.failed_group[i]})
        if adj is not None:
            v, v0 = float(adj.value[i]), float(adj0.value[0])
            rows.append({"param": p, "side": s, "deviation": d,
                         "output": f"{names[0]}_adjusted", "nominal": v0, "value": v,
                         "change": v - v0, "status": adj.status[i],
                         "failed_group": adj.failed_group[i], **_settings_row(adj, i)})
    return ScanResult(mech.name, tolerances.name, pd.DataFrame(rows))


def _settings_row(adj, i) -> dict:
    if len(adj.names) == 1:
        return {"setting": float(adj.settings[adj.names[0]][i])}
    return {f"{p}_setting": float(adj.settings[n][i])
            for n, p in zip(adj.names, adj.parameters, strict=True)}


# --- worst case ----------------------------------------------------------------------------

@dataclass(frozen=True)
class WorstCaseResult:
    mechanism: str
    tolerances: str
    output: str
    rows: pd.DataFrame  # extreme (max/min), value, corner_value, interior, deviations
    corners: int
    failed_corners: int
    monotone_on_axes: bool
    adjust: str | None = None
    objective: str = "minimise"

    method = ("every corner and the centre of the tolerance box, then L-BFGS-B inside the box "
              "from the best corner (never below any evaluated point); not proven global: the "
              "corner answer is exact when the output is monotone in each parameter over the box")

    def to_dataframe(self) -> pd.DataFrame:
        return self.rows

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "tolerances": self.tolerances,
                "output": self.output, "adjust": self.adjust,
                **({} if self.objective == "minimise" else {"objective": self.objective}),
                "method": self.method,
                "corners": self.corners,
                "failed_corners": self.failed_corners,
                "monotone_on_axes": self.monotone_on_axes,
                "rows": self.rows.to_dict("records")}


def _output_of(mech, names, output, compensator=None, objective=None):
    def f(X):
        X = np.atleast_2d(X)
        dev = {k: X[:, i] for i, k in enumerate(names)}
        if compensator is not None:
            return ADJ.adjust(mech, _values(mech, dev), output, compensator, objective).value
        return mech.evaluate(_values(mech, dev), [output]).outputs[output]
    return f


def worst_case(mech, tolerances: ToleranceSet, output: str, maxiter: int = 100,
               adjust=None, objective=None) -> WorstCaseResult:
    """Largest and smallest `output` over the tolerance box (see the module doc); with `adjust`
    (compensators, sewtol.adjuster), of the output adjusted for `objective` (default
    minimised) on each trial machine."""
    mech.output(output)
    objective = ADJ.Objective.parse(objective)
    if adjust is not None:
        ADJ.compensators_of(mech, adjust)
    tol = _check_tolerances(mech, tolerances)
    names = tol.params
    if len(names) > MAX_CORNER_PARAMS:
        raise ParameterError("tolerances", f"worst case enumerates corners; at most "
                             f"{MAX_CORNER_PARAMS} toleranced parameters", len(names))
    lo = np.array([t.lower for t in tol.items])
    hi = np.array([t.upper for t in tol.items])
    f = _output_of(mech, names, output, adjust, objective)
    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
    cands = np.vstack([corners, 0.5 * (lo + hi)])
    val = f(cands)
    failed = int(np.sum(np.isnan(val[:-1])))
    width = hi - lo
    rows = []
    for extreme, sign in (("max", 1.0), ("min", -1.0)):
        s = np.where(np.isnan(val), -np.inf, sign * val)
        if not np.isfinite(s).any():
            raise ParameterError("tolerances", f"no corner of the box gives a value of {output} "
                                 "(every machine fails)", tolerances.name)
        k = int(np.argmax(s))
        best_x, best_s = cands[k], float(s[k])
        corner_s = float(np.max(s[:-1]))
        def neg_and_grad(z, sign=sign):
            # value and central differences in one batch of 2d + 1 machines
            pts = [z] + [np.clip(z + dz, 0, 1) for i in range(len(z))
                         for dz in (FD_STEP * np.eye(len(z))[i], -FD_STEP * np.eye(len(z))[i])]
            y = sign * f(lo + np.array(pts) * width)
            y = np.where(np.isnan(y), -1e12, y)
            g = np.array([(y[1 + 2 * i] - y[2 + 2 * i]) / (pts[1 + 2 * i][i] - pts[2 + 2 * i][i])
                          if pts[1 + 2 * i][i] != pts[2 + 2 * i][i] else 0.0
                          for i in range(len(z))])
            return -float(y[0]), -g

        z0 = np.where(width > 0, (best_x - lo) / np.where(width > 0, width, 1.0), 0.5)
        res = minimize(neg_and_grad, z0, jac=True, method="L-BFGS-B",
                       bounds=[(0.0, 1.0)] * len(names), options={"maxiter": maxiter})
        x_opt = lo + res.x * width
        v_opt = sign * float(f(x_opt)[0])
        if np.isfinite(v_opt) and v_opt > best_s:
            best_s, best_x = v_opt, x_opt
        at_corner = bool(np.all(np.isclose(best_x, lo) | np.isclose(best_x, hi)))
        row = {"extreme": extreme,
               "output": output if adjust is None else f"{output}_adjusted",
               "value": sign * best_s,
               "corner_value": sign * corner_s, "interior": not at_corner}
        row.update({f"{k}_dev": float(v) for k, v in zip(names, best_x, strict=True)})
        rows.append(row)
    return WorstCaseResult(mech.name, tolerances.name, output, pd.DataFrame(rows),
                           len(corners), failed, _monotone_on_axes(f, lo, hi),
                           ADJ.adjust_label(adjust), str(objective))


def _monotone_on_axes(f, lo, hi, points: int = 7) -> bool:
    """True if the output is monotone along every axis of the box through its centre."""
    centre = 0.5 * (lo + hi)
    X = []
    for i in range(len(lo)):
        for t in np.linspace(lo[i], hi[i], points):
            x = centre.copy()
            x[i] = t
            X.append(x)
    y = f(np.array(X)).reshape(len(lo), points)
    if np.isnan(y).any():
        return False
    d = np.diff(y, axis=1)
    tol = 1e-12 * np.maximum(1.0, np.abs(y).max())
    return bool(np.all(np.all(d >= -tol, axis=1) | np.all(d <= tol, axis=1)))


# --- Monte-Carlo ---------------------------------------------------------------------------

def _file_model(record, dev, mech, outputs, compensator=None, target=None, objective=None):
    values = _values(mech, dev)
    ev = mech.evaluate(values, outputs)
    out = {**ev.outputs, "status": ev.status, "failed_group": ev.failed_group}
    if compensator is not None:
        a = ADJ.adjust(mech, values, target, compensator, objective)
        out.update({f"{target}_adjusted": a.value,
                    **{f"{p}_setting": a.settings[n]
                       for n, p in zip(a.names, a.parameters, strict=True)},
                    "status_adjusted": a.status, "failed_group_adjusted": a.failed_group})
    return out


@dataclass(frozen=True)
class GenericMonteCarloResult:
    mechanism: str
    machines: pd.DataFrame  # machine, deviations, outputs, status, failed_group
    outputs: tuple[str, ...]
    tolerances: str
    seed: int
    limit: float | None = None
    limit_output: str | None = None
    adjust: str | None = None  # the compensator of the adjusted case (column NAME_adjusted)

    @property
    def n(self) -> int:
        return len(self.machines)

    @property
    def adjusted_output(self) -> str | None:
        return None if self.adjust is None else f"{self.limit_output}_adjusted"

    def status(self, output: str | None = None) -> np.ndarray:
        """Per machine: ok, out_of_spec (only for the limited output and its adjusted case),
        cannot_close, dead_point (the adjusted case: at the machine's chosen setting)."""
        col = "status_adjusted" if output is not None and output == self.adjusted_output \
            else "status"
        s = self.machines[col].to_numpy(object).copy()
        if self.limit is not None and output in (self.limit_output, self.adjusted_output):
            v = self.machines[output].to_numpy(float)
            s[(s == "ok") & (v > self.limit)] = "out_of_spec"
        return s

    def counts(self, output: str | None = None) -> dict[str, int]:
        s = self.status(output)
        c = {k: int(np.sum(s == k)) for k in ("ok", "out_of_spec", "cannot_close", "dead_point")}
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
            if self.limit is not None and name in (self.limit_output, self.adjusted_output):
                k = c["ok"]
                ci = stats.binomtest(k, c["n"]).proportion_ci(0.95, method="exact")
                row.update({"limit": self.limit, "yield": k / c["n"],
                            "yield_ci_low": float(ci.low), "yield_ci_high": float(ci.high)})
            rows.append(row)
        return pd.DataFrame(rows)

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "n": self.n, "seed": self.seed,
                "tolerances": self.tolerances, "limit": self.limit,
                "limit_output": self.limit_output,
                "counts": {name: self.counts(name) for name in self.outputs},
                "failed_groups": self.failed_groups(),
                **({} if self.adjust is None else {
                    "adjust": self.adjust,
                    "failed_groups_adjusted": self.failed_groups(adjusted=True)}),
                "summary": self.summary_frame().to_dict("records")}


def montecarlo(mech, tolerances: ToleranceSet, n: int, seed: int, outputs=None,
               limit: float | None = None, limit_output: str | None = None, n_jobs: int = 1,
               progress=False, chunk_size: int = CHUNK, adjust=None,
               objective=None) -> GenericMonteCarloResult:
    """n machines of the file (see the module doc); `limit` (an upper limit of limit_output,
    default the first output) splits ok machines into ok and out_of_spec. `adjust`
    (compensators of the file: a name, "a,b" or a list) adds the adjusted case: limit_output
    adjusted for `objective` (default minimised) on each machine (sewtol.adjuster), columns
    NAME_adjusted, PARAM_setting per compensator, status_adjusted, failed_group_adjusted."""
    names = tuple(mech.output_names if outputs is None else outputs)
    for name in names:
        mech.output(name)
    objective = ADJ.Objective.parse(objective)
    if adjust is not None:
        ADJ.compensators_of(mech, adjust)
    if limit is not None or adjust is not None:
        limit_output = limit_output or names[0]
        mech.output(limit_output)
        if limit_output not in names:
            names = (*names, limit_output)
        if limit is not None and not np.isfinite(limit):
            raise ParameterError("limit", "must be a finite number", limit)
    record = mech.parameter_record()
    mc.check_seed(seed)
    mc.check_sampling(record, tolerances, n, seed, chunk_size,
                      columns=len(tolerances.items) + len(names) + 3)
    machines = mc.sample_machines(_file_model, record, tolerances, n, seed, n_jobs, progress,
                                  chunk_size=chunk_size, desc=f"Monte-Carlo {mech.name}",
                                  mech=mech, outputs=list(names), compensator=adjust,
                                  target=limit_output, objective=objective)
    if adjust is not None:
        names = (*names, f"{limit_output}_adjusted")
    return GenericMonteCarloResult(mech.name, machines, names, tolerances.name, int(seed),
                                   None if limit is None else float(limit), limit_output,
                                   ADJ.adjust_label(adjust))


# --- Sobol ---------------------------------------------------------------------------------

def sobol(mech, tolerances: ToleranceSet, output: str, n: int, seed: int,
          resamples: int = 200) -> so.SobolResult:
    """Sobol indices of one output at n and n/2 base samples (studies.sobol)."""
    mech.output(output)
    record = mech.parameter_record()
    so.check_sobol(record, tolerances, n, seed)
    problem = so.problem_of(tolerances)
    X = so.sample(problem, n, seed)
    dev = {k: X[:, i] for i, k in enumerate(problem["names"])}
    ev = mech.evaluate(_values(mech, dev), [output])
    y = ev.outputs[output]
    bad = ev.status != "ok"
    if bad.any():
        groups = sorted(set(ev.failed_group[bad]))
        raise ParameterError("sobol", f"{int(bad.sum())} of {bad.size} samples cannot run "
                             f"({', '.join(f'{s}' for s in sorted(set(ev.status[bad])))} at "
                             f"{', '.join(groups)}); Sobol indices need a model defined on the "
                             "whole tolerance box", int(bad.sum()))
    both, conv, _ = so._indices_from(problem, y, n, seed, output, resamples)
    return so.SobolResult(both, conv, int(n), int(seed), {output: 0}, tolerances.name)
