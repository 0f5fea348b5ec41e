"""THE Monte-Carlo of any mechanism (the protocol): n machines of the one sampler
(sewtol.studies.montecarlo.sample_machines: machine k from child k // 500 of the seed; same
seed, same table, for any n_jobs, chunk size or cluster), every output and each machine's
status (ok + out_of_spec + cannot_close + dead_point = n, out_of_spec by the mechanism's
[[specs]] unless limits are given) and, with a compensator, the adjusted case through
sewtol.studies.adjusting.adjusted (the generic optimiser; with fast=True the mechanism's
plug-ins: its kernel for the outputs it gives, its exact adjuster). The JSON is
sewtol.studies.montecarlo.record, the shape every Monte-Carlo shares. The needle's beta fixed
and adjusted table (`sewtol needle montecarlo`) is this study on
needle_208.tables.as_mechanism, in the source's columns (needle_208.tables.montecarlo).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from sewtol.errors import ParameterError
from sewtol.mechanism.spec import Spec
from sewtol.studies.montecarlo import (
    CHUNK,
    WORDS,
    check_sampling,
    check_seed,
    quantiles,
    record,
    sample_machines,
)
from sewtol.tolerances import ToleranceSet


def _file_model(record, dev, mech, outputs, compensator=None, target=None, fast=False):
    """One chunk of `montecarlo`: the outputs of machines nominal + dev as built (the plug-in
    kernel where it gives every output, the status of the machines it cannot run from
    mech.evaluate) and, with a compensator, the adjusted case."""
    from sewtol.protocol import NO_PLUGINS, machines, plugins
    from sewtol.studies.adjusting import adjusted

    values = machines(mech, dev)
    pl = plugins(mech) if fast else NO_PLUGINS
    if pl.kernel is not None and set(outputs) <= set(pl.kernel_outputs):
        got = pl.kernel(mech, values)
        out = {o: got[o] for o in outputs}
        m = len(got[outputs[0]])
        status, group = np.full(m, "ok", object), np.full(m, "", object)
        bad = ~np.all([np.isfinite(v) for v in out.values()], axis=0)
        if bad.any():
            ev = mech.evaluate({k: v[bad] for k, v in values.items()}, outputs)
            status[bad], group[bad] = ev.status, ev.failed_group
        out.update({"status": status, "failed_group": group})
    else:
        ev = mech.evaluate(values, outputs)
        out = {**ev.outputs, "status": ev.status, "failed_group": ev.failed_group}
    if compensator is not None:
        comps = [compensator] if isinstance(compensator, str) else compensator
        a = adjusted(mech, values, comps, target, fast=fast)
        out[f"{target}_adjusted"] = a.value
        for param, setting in a.settings.items():
            out[f"{param}_setting"] = setting
            if a.path != "generic":  # a plug-in's plateau of optimal settings and its bound
                out[f"{param}_low"] = a.extras["low"][param]
                out[f"{param}_high"] = a.extras["high"][param]
                out[f"{param}_at_bound"] = np.asarray(a.at_bound[param], float)
        out["status_adjusted"] = np.array([WORDS.get(w, w) for w in a.status], object)
        out["failed_group_adjusted"] = a.extras.get("failed_group", np.full(len(a.value), ""))
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
        return record(
            mechanism=self.mechanism, n=self.n, seed=self.seed, tolerances=self.tolerances,
            output=self.limit_output, unit=self.unit, spec=self.spec(),
            counts={c: self.counts(o) for c, o in cases.items()},
            quantiles={c: quantiles(self.machines[o]) for c, o in cases.items()},
            extra={"adjust": self.adjust, "failed_groups": self.failed_groups(),
                   **({} if self.adjust is None else {
                       "failed_groups_adjusted": self.failed_groups(adjusted=True)}),
                   "summary": self.summary_frame().to_dict("records")})


def montecarlo(mech, tolerances: ToleranceSet, n: int, seed: int, outputs=None,
               limit: float | None = None, limit_output: str | None = None, n_jobs: int = 1,
               progress=False, chunk_size: int = CHUNK, adjust: str | None = None,
               lower_limit: float | None = None, *, fast: bool = False, backend=None,
               store=None, scheduler=None) -> GenericMonteCarloResult:
    """n machines of the file (see the module doc). Every output with a [[specs]] entry in the
    file splits its ok machines into ok and out_of_spec; `limit`/`lower_limit` replace the
    spec of limit_output (default: the first output studied with limits given, else the first
    output of the file's specs, else the first output). `adjust` (a compensator of the file)
    adds the adjusted case: limit_output minimised over the compensator on each machine
    (`sewtol.studies.adjusting.adjusted`: the generic optimiser, or with fast=True the
    mechanism's plug-in where it takes the compensator), columns NAME_adjusted, PARAM_setting,
    status_adjusted, failed_group_adjusted; `adjust` may also map one parameter to its box (a
    plug-in's search range). fast=True: the plug-in kernel for the outputs it gives. backend,
    store, scheduler: as `sample_machines` (joblib backend, study folder, Dask cluster)."""
    names = tuple(mech.output_names if outputs is None else outputs)
    for name in names:
        mech.output(name)
    for name in adjust.split(",") if isinstance(adjust, str) else ():
        if name.strip() not in mech.compensators:
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
    nominal = mech.parameter_record()
    check_seed(seed)
    check_sampling(nominal, tolerances, n, seed, chunk_size,
                   columns=len(tolerances.items) + len(names) + 3)
    machines = sample_machines(_file_model, nominal, tolerances, n, seed, n_jobs, progress,
                               backend, chunk_size, desc=f"Monte-Carlo {mech.name}",
                               store=store, scheduler=scheduler, mech=mech, outputs=list(names),
                               compensator=adjust, target=limit_output, fast=fast)
    if adjust is not None:
        names = (*names, f"{limit_output}_adjusted")
        adjust = adjust if isinstance(adjust, str) else ",".join(adjust)
    return GenericMonteCarloResult(mech.name, machines, names, tolerances.name, int(seed),
                                   limit_output, specs, source, adjust,
                                   mech.output(limit_output).unit)
