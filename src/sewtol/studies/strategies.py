"""Yield by adjustment strategy, of any mechanism (the protocol): the same machines adjusted
under each named strategy.

Every strategy sees the SAME machines (common random numbers: `law.draw(n, seed)`, the one
sampler, so the machines of `montecarlo` for that seed), so differences between rows are the
strategies', not sampling noise. A strategy is a set of compensators: names of the
mechanism's compensators, a map parameter -> box, or compensator objects (the needle's
Strategy); each machine is adjusted through `sewtol.studies.adjusting.adjusted` (the
mechanism's plug-in where it takes the set, else the generic optimiser), an empty set leaves
the machine as built. Per row (`row`, the one implementation for every mechanism): counts
ok + out_of_spec + cannot_close + dead_point = n (against the output's spec), the yield with its
Clopper-Pearson interval, p50/p95/p99 of the adjusted output (a machine that cannot run ranks as
infinitely bad), Cpk, the share of machines with any / each compensator at an end of its box,
the achieved yield, the distinct settings of stepped compensators, and each compensator's
settings spread over the machines that run with the share at an end of its box. A mechanism's
own words for these columns are data: `Plugins.columns["strategies"]` (the needle's).

Setting the compensators as a fitter does (`set_in_order`): where a compensator has a
resolution or a setting error (sewtol.setting_error), the fitter sets the compensators one at a
time in the fitting order (the strategy's `fitting_order` where it has one, as the needle's
does; else the order given: a file's declaration order): before each imperfect one, the
compensators not yet set are optimised jointly given those already set; it is set to its
optimum rounded to its resolution plus its drawn error (clipped to its box), and the exact ones
before it in the order are set at that joint optimum; after the last imperfect one the rest are
set at their joint optimum given all that. Every row states its compensators' resolution and
setting error. The errors are drawn from the study's seed, one stream per compensator beside
the machines' (`setting_error.unit_draws`): the same seed gives the same tables for any chunking
or n_jobs, and every row and every level of `yield_curve` uses the same draws (only the scale
changes). With every compensator exact the row is the joint optimum, as before.

Setting from a measurement (`measurement`, sewtol.measurement_error): every stage's optimum is
then the optimum of the output as the fitter READS it (the mechanism's `measured_adjuster`
plug-in: the needle's reads d at equally spaced crank angles, each reading with a normal
error), and the machine's figure is the true output at the settings made. The reading errors
are drawn per machine from a stream of their own (`measurement_error.normal_draws`), the same
for every row and every level of `measurement_curve` (only the scale changes); sd 0 is exact
(the rows without the option, bit for bit).
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from sewtol import measurement_error as me
from sewtol import setting_error as se
from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson
from sewtol.measurement_error import MeasurementError
from sewtol.mechanism.spec import Compensator as FileCompensator
from sewtol.protocol import input_law, machines, plugins, tolerance_set
from sewtol.setting_error import SettingError
from sewtol.studies.adjusting import Adjusted, adjusted
from sewtol.studies.montecarlo import WORDS, check_memory, check_seed, contributors, quantiles
from sewtol.studies.parallel import chunk_bounds, local_workers, run_chunks

if TYPE_CHECKING:
    import pandas as pd

# machines per chunk, for any n_jobs: the machines are adjusted one by one, but a batch
# optimum need not be bit-identical across batch sizes (the needle's joint optimum differs by
# ~1e-11 um on 2 of 2000 machines between chunks of 250 and 500), so the chunking is part of
# the study's identity: 250, as the needle's strategies report has always used
CHUNK = 250
STATUSES = ("ok", "out_of_spec", "cannot_close", "dead_point")


def default_strategies(mech) -> dict[str, tuple[str, ...]]:
    """none, each compensator of the mechanism alone, and all of them (where there are two or
    more)."""
    names = tuple(mech.compensators)
    rows = {"none": (), **{name: (name,) for name in names}}
    if len(names) > 1:
        rows["all"] = names
    return rows


def parse_strategies(items, mech) -> dict[str, tuple[str, ...]]:
    """`--strategy NAME=C1,C2` items (C: compensators of the mechanism; NAME= alone: none)."""
    out = {}
    for item in items:
        name, eq, comps = item.partition("=")
        names = tuple(c.strip() for c in comps.split(",") if c.strip())
        if not eq or not name.strip() or name.strip() in out:
            raise ParameterError("--strategy", "must be NAME=C1,C2,... with a new NAME", item)
        for c in names:
            if c not in mech.compensators:
                raise ParameterError("--strategy", "must name compensators of the mechanism ("
                                     + (", ".join(mech.compensators) or "it has none") + ")", c)
        out[name.strip()] = names
    return out


def _names(compensators) -> list[str]:
    comps = getattr(compensators, "compensators", compensators)
    if isinstance(comps, Mapping):
        return list(comps)
    return [getattr(c, "name", c) for c in comps]


def _measured_stage(mech, values, compensators, output, measured, options) -> Adjusted:
    """The optimum of `output` as read (measured = (MeasurementError, reading errors (n, K)))
    over `compensators`, by the mechanism's measured_adjuster; the value the true output."""
    measurement, noise = measured
    pl = plugins(mech)
    objs = compensator_objects(mech, compensators)
    names = [c.name for c in objs]
    if pl.measured_adjuster is None or output != pl.adjusted_output \
            or not pl.adjusts_strategy(names):
        raise ParameterError("measurement_error", "needs a mechanism whose plug-in sets its "
                             "compensators from a measured curve (the needle's, with its own "
                             "compensators)", f"{mech.name}: {', '.join(names)}")
    r = pl.measured_adjuster(mech, values or {}, tuple(objs), measurement.crank_angles_rad(),
                             noise, **options)
    known = ("value", "settings", "status", "at_bound")
    return Adjusted(r["value"], dict(r["settings"]), r["status"], dict(r["at_bound"]),
                    {k: v for k, v in r.items() if k not in known}, pl.name, "own")


def _stage(mech, values, compensators, output, fast, options, measured=None) -> Adjusted:
    """The joint optimum of `compensators` (names, or objects) on machines `values` (as read,
    with `measured`); none: the machine as built."""
    if measured is not None and _names(compensators):
        return _measured_stage(mech, values, compensators, output, measured, options)
    if _names(compensators) or (fast and plugins(mech).adjusts_strategy(())):
        return adjusted(mech, values, compensators, output, fast=fast, **options)
    ev = mech.evaluate(values, [output])  # nothing to set: the machine as built
    return Adjusted(ev.outputs[output], {}, ev.status, {}, {"failed_group": ev.failed_group})


def compensator_objects(mech, compensators) -> list:
    """The row's compensators as objects (a name: the file's [compensators.NAME]), in the
    row's order."""
    comps = getattr(compensators, "compensators", compensators)
    if isinstance(comps, Mapping):  # parameter -> box: exact by construction
        return []
    if isinstance(comps, str):
        comps = [comps]
    out = []
    for c in comps:
        if isinstance(c, str):
            if c not in mech.compensators:
                raise ParameterError("strategy", "must name compensators of the mechanism ("
                                     + (", ".join(mech.compensators) or "it has none") + ")", c)
            c = mech.compensators[c]
        out.append(c)
    return out


def _exact(c) -> bool:
    return not getattr(c, "resolution", 0.0) and getattr(c, "setting_error", None) is None


def _parameter(c) -> str:
    return getattr(c, "parameter", c.name)


def _top(c) -> float:
    return float(c.settings()[-1]) if getattr(c, "step", None) else float(c.high)


def _stage_arg(comps: list):
    """What `adjusted` takes for these compensators: a file's by name (its boxes, its modes),
    others (the needle's) as objects."""
    return tuple(c.name if isinstance(c, FileCompensator) else c for c in comps)


def fitting_order(mech, compensators) -> list:
    """The compensators in the order the fitter sets them: the strategy's `fitting_order`
    where it declares one (the needle's), else the order given."""
    order = getattr(compensators, "fitting_order", None)
    return list(order) if order is not None else compensator_objects(mech, compensators)


def set_in_order(mech, values, compensators, output, units: Mapping | None = None, *,
                 fast: bool = True, measured=None, **options) -> Adjusted:
    """Each machine adjusted as a fitter sets the compensators (the module docstring): in the
    fitting order, each imperfect one (a resolution or a setting error) at the joint optimum of
    those not yet set, rounded to its resolution, plus its error ``setting_error.from_unit(
    units[name])`` per machine, clipped to its box; the rest re-set optimally given it. With
    every compensator exact: the joint optimum (one call). The settings reported for an
    imperfect compensator are the settings made (with their errors). measured: (MeasurementError,
    reading errors (n, K)) or None: every optimum is that of the output as read."""
    objs = compensator_objects(mech, compensators)
    if all(_exact(c) for c in objs):
        return _stage(mech, values, compensators, output, fast, options, measured)
    order = fitting_order(mech, compensators)
    n = len(next(iter(values.values())))
    nominal = mech.nominal_values()
    vals = {k: np.asarray(v, float) for k, v in values.items()}
    made, made_bound, first, terms = {}, {}, None, None
    start = 0
    for i, comp in enumerate(order):
        if _exact(comp):
            continue
        a = _stage(mech, vals, _stage_arg(order[start:]), output, fast, options, measured)
        first = a if first is None else first
        terms = a.terms if terms is None else terms
        for c in order[start:i + 1]:
            p = _parameter(c)
            as_built = np.broadcast_to(np.asarray(vals.get(p, nominal[p]), float), (n,))
            x = np.asarray(a.settings[p], float)
            own = x if (a.terms == "own" or c.mode == "absolute") else x - as_built
            if c is comp:
                own = se.snap(own, c.resolution)
                if c.setting_error is not None:
                    if units is None or c.name not in units:
                        raise ParameterError("units", "must give the setting-error draws of "
                                             "every compensator with a setting error", c.name)
                    own = own + c.setting_error.from_unit(units[c.name])
                own = np.where(np.isfinite(own), np.clip(own, c.low, _top(c)), own)
            absolute = own if c.mode == "absolute" else as_built + own
            vals[p] = np.where(np.isfinite(absolute), absolute, as_built)
            made[p] = own if a.terms == "own" else absolute
            eps = 1e-6 * (c.high - c.low)
            made_bound[p] = (own <= c.low + eps) | (own >= _top(c) - eps)
        start = i + 1
    last = _stage(mech, vals, _stage_arg(order[start:]), output, fast, options, measured)
    extras = {}
    for k, v in last.extras.items():
        if isinstance(v, Mapping):  # per-compensator figures: each from the stage that set it
            merged = {**first.extras.get(k, {}), **v}
            if k == "at_limit":
                merged.update(made_bound)
            extras[k] = merged
        else:
            extras[k] = v
    if "total_before_um" in first.extras:  # as built, not as left by the earlier stages
        extras["total_before_um"] = first.extras["total_before_um"]
    return Adjusted(last.value, {**made, **last.settings}, last.status,
                    {**made_bound, **last.at_bound}, extras, last.path, terms or last.terms)


def _units(seed: int, mech, rows, a: int, b: int) -> dict[str, np.ndarray]:
    """The standard uniforms of every setting error in the rows, machines a .. b-1."""
    names = sorted({c.name for r in rows for c in compensator_objects(mech, r)
                    if getattr(c, "setting_error", None) is not None})
    return {name: se.unit_draws(seed, name, a, b) for name in names}


def _chunk(mech, values, strategies, output, fast, options, threads, units=None, measured=None):
    """Each strategy's `set_in_order` on these machines. threads (a worker process's share,
    one): the mechanism's kernels on this thread without numba where it can (its plug-in's
    `serial`: the needle's compiled ahead of time), else numba on that many threads (2 x 2
    threads ran slower)."""
    serial = plugins(mech).serial if threads is not None else None
    with serial() if serial is not None else contextlib.nullcontext(False) as numba_free:
        before = None
        if threads is not None and not numba_free:
            import numba

            before = numba.get_num_threads()
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        try:
            return [set_in_order(mech, values, s, output, units, fast=fast, measured=measured,
                                 **options) for s in strategies]
        finally:
            if before is not None:
                numba.set_num_threads(before)


def _drawn_chunk(mech, dev, strategies, output, fast, options, threads, seed, window,
                 measurement=None):
    """`_chunk` of machines window = (a, b) with deviations `dev`: their parameter values and
    their setting-error and reading draws made here (each machine's draws are its own: the
    numbers of a draw of all n, cut to the window), never held for all n by the parent."""
    a, b = window
    noise = None if measurement is None else (measurement, measurement.sd_um * me.normal_draws(
        seed, a, b, measurement.positions))
    return _chunk(mech, machines(mech, dev), strategies, output, fast, options, threads,
                  _units(seed, mech, strategies, a, b), noise)


# what `row` reads of an adjuster's extras; the others (the needle's plateaus, plus and minus,
# SumDelta before) only its per-machine tables
ROW_EXTRAS = ("at_limit", "achieved_um")


# what the study holds per machine (`held_bytes`): its deviations, 8 bytes each; per row the
# adjusted output, the status (a pointer to a shared word) and the achieved figure, and per
# compensator its setting and two flags (at bound, at limit); with per_machine the adjuster's
# other figures too (the needle's: four per row, each compensator's plateau ends); and the
# working copies of the row being summarised (`row`: its status words as a list and an array,
# the quantiles' two copies, masks)
ROW_BYTES, COMPENSATOR_BYTES = 3 * 8, 8 + 2
FIGURES_ROW_BYTES, FIGURES_COMPENSATOR_BYTES = 4 * 8, 2 * 8
WORKING_BYTES = 6 * 8


def held_bytes(rows, dims: int, per_machine: bool = True) -> int:
    """Bytes the study holds per machine of `rows` (each row's compensators, in any form
    `strategies` takes) and `dims` deviations (check_memory's bytes_per_row)."""
    row = ROW_BYTES + (FIGURES_ROW_BYTES if per_machine else 0)
    comp = COMPENSATOR_BYTES + (FIGURES_COMPENSATOR_BYTES if per_machine else 0)
    return 8 * int(dims) + sum(row + comp * len(_names(r)) for r in rows) + WORKING_BYTES


def _put(held, part, a: int, n: int):
    """A chunk's figures (arrays, dicts of them) written into `held` at machines a .., each
    n-long array made by the first chunk to arrive (promoted as np.concatenate would); a
    figure of the whole batch (a scalar, the same in every chunk) kept as it is."""
    if isinstance(part, Mapping):
        held = {} if held is None else held
        for k, v in part.items():
            held[k] = _put(held.get(k), v, a, n)
        return held
    if np.ndim(part) == 0:
        return part
    v = np.asarray(part, object if isinstance(part[0], str) else None)
    if held is None or np.result_type(held, v) != held.dtype:
        held = np.empty(n, v.dtype) if held is None else held.astype(np.result_type(held, v))
    held[a:a + v.size] = v
    return held


# a row's columns in the generic words and order; a mechanism's `Plugins.columns["strategies"]`
# (generic name -> its name, in its order) picks and renames them, "at_limit_*" standing for
# the at_limit_NAME column of every compensator of the table
COLUMNS = ("strategy", "compensators", "resolution", "setting_error", "measurement_error",
           *STATUSES, "failed", "n", "yield", "yield_ci_low", "yield_ci_high", "p50", "p95",
           "p99", "Cpk", "at_limit_share", "at_limit_*", "achieved_yield", "distinct_settings",
           "settings")


def cpk(values, spec) -> float:
    """Cpk over the machines that run (finite values): (U - mean) / 3 s, (mean - L) / 3 s or
    the smaller of the two; NaN without a spec, with fewer than two values or no scatter."""
    run = np.asarray(values, float)
    run = run[np.isfinite(run)]
    if spec is None or run.size < 2 or not np.std(run, ddof=1) > 0:
        return float("nan")
    s = np.std(run, ddof=1)
    sides = ([] if spec.upper is None else [(spec.upper - run.mean()) / (3 * s)]) + \
        ([] if spec.lower is None else [(run.mean() - spec.lower) / (3 * s)])
    return float(min(sides))


def status_of(a: Adjusted, spec) -> np.ndarray:
    """Per machine: ok, out_of_spec, cannot_close or dead_point (the protocol's words)."""
    s = np.array([WORDS.get(w, w) for w in a.status], dtype=object)
    if spec is not None:
        s[(s == "ok") & ~spec.passes(np.asarray(a.value, float))] = "out_of_spec"
    return s


def row(name: str, compensators, a: Adjusted, spec, labels=("none", "none"),
        measurement: str = "none") -> dict:
    """One strategy's figures in the generic words (COLUMNS): the counts (they add up to n),
    the yield and its Clopper-Pearson interval, p50/p95/p99 of the adjusted output, Cpk, the
    share of machines with any / each compensator at an end of its box (the adjuster's
    ``at_limit`` where it reports one, else its ``at_bound``), the achieved yield (the
    adjuster's ``achieved_um`` where it reports one: the worst within half a resolution), the
    distinct settings of each stepped compensator over the ok machines, and each setting's
    spread. `compensators`: the row's compensator objects (or names of parameters)."""
    status = status_of(a, spec)
    c = {k: int(np.sum(status == k)) for k in STATUSES}
    c["failed"] = c["cannot_close"] + c["dead_point"]
    c["n"] = n = int(status.size)
    ci_low, ci_high = clopper_pearson(c["ok"], n)
    comps = [(getattr(x, "name", x), _parameter(x) if hasattr(x, "low") else x, x)
             for x in compensators]
    limit = a.extras.get("at_limit", {})
    at = {name_: np.asarray(limit[name_] if name_ in limit else a.at_bound[key], bool)
          for name_, key, _ in comps}
    achieved = np.asarray(a.extras.get("achieved_um", a.value), float)
    ok, runs = status == "ok", np.isin(status, ("ok", "out_of_spec"))
    spread = []
    for k, v in a.settings.items():
        x = np.asarray(v, float)[runs]
        bound = float(np.mean(np.asarray(a.at_bound.get(k, np.zeros(n)), bool)))
        spread.append(f"{k} {x.min():.6g}..{x.max():.6g} (at bound {bound:.1%})" if x.size
                      else f"{k} -")
    return {"strategy": name, "compensators": ",".join(x for x, _, _ in comps) or "-",
            "resolution": labels[0], "setting_error": labels[1],
            "measurement_error": measurement if comps else "none", **c, "yield": c["ok"] / n,
            "yield_ci_low": ci_low, "yield_ci_high": ci_high, **quantiles(a.value),
            "Cpk": cpk(a.value, spec),
            "at_limit_share": float(np.logical_or.reduce([*at.values(), np.zeros(n, bool)])
                                    .mean()),
            **{f"at_limit_{k}": float(np.mean(v)) for k, v in at.items()},
            "at_limit": ", ".join(f"{k} {np.mean(v):.1%}" for k, v in at.items()),
            "achieved_yield": float(np.mean(np.isfinite(achieved) if spec is None
                                            else spec.passes(achieved))),
            "distinct_settings": ", ".join(
                f"{x} {np.unique(np.round(np.asarray(a.settings[k], float)[ok], 9)).size}"
                for x, k, obj in comps if getattr(obj, "step", None) is not None),
            "settings": "; ".join(spread)}


def table(rows: list[dict], columns: Mapping | None = None) -> pd.DataFrame:
    """Rows of `row` as one table: every column of COLUMNS (measurement_error only where a row
    was set from a reading), or `columns` (a mechanism's words, in its order); at_limit_NAME
    of every compensator of the table, NaN in a row without it."""
    import pandas as pd

    split = list(dict.fromkeys(k for r in rows for k in r if k.startswith("at_limit_")
                               and k not in ("at_limit_share", "at_limit_*")))
    if columns is None:
        columns = {k: k for k in COLUMNS if k != "measurement_error"
                   or any(r[k] != "none" for r in rows)}
    names = {}
    for k, v in columns.items():
        names.update({c: c for c in split} if k == "at_limit_*" else {k: v})
    return pd.DataFrame([{names[k]: r.get(k, np.nan) for k in names} for r in rows],
                        columns=list(names.values()))


@dataclass(frozen=True)
class StrategiesResult:
    """The machines (deviations), each strategy's adjusted batch and the spec they meet."""

    mechanism: str
    output: str
    unit: str
    spec: object  # sewtol.mechanism.Spec or None (every machine that runs is ok)
    tolerances: str
    seed: int
    deviations: dict
    names: tuple[str, ...]
    rows: tuple  # per row: its compensators as given (names, a map parameter -> box, objects)
    adjusted: tuple[Adjusted, ...]
    labels: tuple[tuple[str, str], ...] = ()  # per row: (resolution, setting error) labels
    measurement: str = "none"  # the reading the compensators are set from (none: the truth)
    limits: dict = field(default_factory=dict)  # param -> (lower, upper) of the tolerance set
    columns: Mapping | None = None  # the mechanism's words (Plugins.columns["strategies"])
    per_machine: bool = True  # False: each row kept only what its table row reads (`row`)

    @property
    def n(self) -> int:
        return len(self.adjusted[0].value)

    def get(self, name: str) -> Adjusted:
        if name not in self.names:
            raise ParameterError("strategy", f"not in this table; rows are "
                                 f"{', '.join(self.names)}", name)
        return self.adjusted[self.names.index(name)]

    def status(self, name: str) -> np.ndarray:
        """Per machine: ok, out_of_spec, cannot_close or dead_point after the strategy."""
        return status_of(self.get(name), self.spec)

    def row(self, i: int) -> dict:
        """Row i in the generic words (`row`)."""
        r = self.rows[i]
        comps = list(r) if isinstance(r, Mapping) else list(getattr(r, "compensators", r))
        return row(self.names[i], comps, self.adjusted[i], self.spec,
                   self.labels[i] if self.labels else ("none", "none"), self.measurement)

    def to_dataframe(self) -> pd.DataFrame:
        """One row per strategy (`row`), in the mechanism's words where it has them."""
        return table([self.row(i) for i in range(len(self.names))], self.columns)

    def to_dict(self) -> dict:
        """`context` (what decides the numbers, the output and its spec) and `rows`."""
        return {"context": {"mechanism": self.mechanism, "tolerances": self.tolerances,
                            "seed": self.seed, "n": self.n, "strategy": list(self.names),
                            "output": self.output, "unit": self.unit,
                            "spec": None if self.spec is None else self.spec.to_dict(),
                            "measurement_error": self.measurement,
                            "yield_ci_method": "Clopper-Pearson exact binomial interval of "
                                               "ok / n, 95 %"},
                "rows": self.to_dataframe().to_dict("records")}

    def failure_contributors(self, strategy: str, bins: int = 10) -> pd.DataFrame:
        """Which tolerances drive the machines still out of spec after `strategy`.

        Two views side by side: the correlation-ratio shares (montecarlo.contributors) of the
        adjusted output over all machines that run and over the out-of-spec ones alone, and
        the conditional shift of each deviation: the mean of (deviation - mid) / half-width
        over the failing machines, with mid and half-width those of the tolerance (about 0 for
        a tolerance that does not matter, towards +/-1 for one whose limit the failures sit
        at), and the mean |z| over the failing machines next to that over all machines.
        """
        import pandas as pd

        params = list(self.deviations)
        frame = pd.DataFrame(self.deviations)
        frame["_adjusted"] = self.get(strategy).value
        fail = self.status(strategy) == "out_of_spec"
        out = pd.DataFrame({"param": params})
        all_c = contributors(frame, params, "_adjusted", bins).set_index("param")
        out["share_all_pct"] = out.param.map(all_c["share_pct"])
        if fail.sum() > bins + 1:
            f_c = contributors(frame[fail], params, "_adjusted", bins).set_index("param")
            out["share_failing_pct"] = out.param.map(f_c["share_pct"])
        else:
            out["share_failing_pct"] = np.nan
        lo, hi = np.array([self.limits[p] for p in params]).T[:, :, None]
        z = (frame[params].to_numpy().T.copy() - 0.5 * (hi + lo)) / (0.5 * (hi - lo))
        out["mean_z_failing"] = z[:, fail].mean(axis=1) if fail.any() else np.nan
        out["mean_abs_z_failing"] = np.abs(z[:, fail]).mean(axis=1) if fail.any() else np.nan
        out["mean_abs_z_all"] = np.abs(z).mean(axis=1)
        out.insert(1, "n_failing", int(fail.sum()))
        return out.sort_values("mean_abs_z_failing", ascending=False, na_position="last") \
            .reset_index(drop=True)


def strategies(mech, tolerances, n: int, seed: int, strategies: Mapping | None = None,
               output: str | None = None, spec=None, *, fast: bool = True, n_jobs: int = 1,
               progress=False, measurement: MeasurementError | None = None,
               per_machine: bool = True, **options) -> StrategiesResult:
    """The machines 0 .. n-1 of `seed` (`law.draw`) under each strategy (name -> compensators;
    None: `default_strategies`), `output` (default: that of the mechanism's first spec, else its
    first) adjusted and held to `spec` (default: the mechanism's spec of it; none: every machine
    that runs is ok). fast=False: the generic optimiser always; chunks of CHUNK machines, one
    after another (n_jobs 1) or on n_jobs worker processes, with the same numbers for any
    n_jobs; progress: a bar (or callback) per chunk; options go to the mechanism's strategy
    adjuster (e.g.
    the needle's limit_um). measurement: the compensators set from a reading of the output
    with this error (sewtol.measurement_error; None or sd 0: from the truth). per_machine=False:
    each row keeps per machine only what its table row reads (`row`: the value, status,
    settings, bound flags, ROW_EXTRAS), the adjuster's other figures dropped as each chunk
    arrives (the needle's per-machine tables then cannot be made). A run whose machines
    (`held_bytes`) cannot fit in the memory left is refused before anything is drawn, naming
    the largest n that fits."""
    if isinstance(n, bool) or int(n) != n or n < 2:
        raise ParameterError("n", "must be a whole number >= 2", n)
    check_seed(seed)
    output, file_spec, _ = mech.resolve_spec(output)
    spec = file_spec if spec is None else spec
    strategies = default_strategies(mech) if strategies is None else dict(strategies)
    if not strategies:
        raise ParameterError("strategies", "must name at least one strategy", strategies)
    law = input_law(mech, tolerances)
    if law.dim == 0:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width", law.name)
    if measurement is not None and not isinstance(measurement, MeasurementError):
        raise ParameterError("measurement", "must be a MeasurementError or None",
                             type(measurement).__name__)
    if measurement is not None and measurement.exact:
        measurement = None
    rows = list(strategies.values())
    check_memory(n, 0, bytes_per_row=held_bytes(rows, law.dim, per_machine),
                 workers=0 if n_jobs == 1 else local_workers(n_jobs))
    dev = law.draw(int(n), seed)
    # chunks of CHUNK machines for any n_jobs (one at a time with n_jobs 1): the adjusters'
    # working arrays stay those of one chunk, and the numbers do not depend on n_jobs
    bounds, held = chunk_bounds(int(n), CHUNK), [{} for _ in rows]

    def keep(i, chunk):  # written in place as each chunk arrives: joined at the end, the
        # chunks and their copy were held together and the chunks' freed memory left unused
        for h, a in zip(held, chunk, strict=True):
            _put(h, {**vars(a), "extras": {k: v for k, v in a.extras.items()
                                           if per_machine or k in ROW_EXTRAS}},
                 bounds[i][0], int(n))

    run_chunks(_drawn_chunk, [(mech, {k: v[a:b] for k, v in dev.items()}, rows, output, fast,
                               options, 1 if n_jobs != 1 else None, seed, (a, b), measurement)
                              for a, b in bounds],
               n_jobs=n_jobs, progress=progress, desc="strategies", keep=keep)
    adj = [Adjusted(**h) for h in held]
    active = tolerance_set(mech, tolerances).active()
    return StrategiesResult(
        mech.name, output, mech.output(output).unit, spec, law.name, int(seed), dev,
        tuple(strategies), tuple(s if isinstance(s, Mapping) or hasattr(s, "compensators")
                                 else tuple(compensator_objects(mech, s)) for s in rows),
        tuple(adj), tuple(setting_labels(mech, s) for s in rows), me.label(measurement),
        {t.param: (t.lower, t.upper) for t in active.items},
        plugins(mech).columns.get("strategies") if fast else None, bool(per_machine))


def _unit(mech, c) -> str:
    unit = getattr(c, "unit", None)
    if unit is None:
        unit = next((p.unit for p in mech.parameters if p.name == _parameter(c)), "")
    return "" if unit == "1" else unit


def setting_labels(mech, compensators) -> tuple[str, str]:
    """A row's (resolution, setting error) for tables: ``NAME VALUE UNIT`` per compensator
    that has one (``; `` between), "none" where every compensator is exact."""
    objs = compensator_objects(mech, compensators)
    res = [f"{c.name} {c.resolution:g} {_unit(mech, c)}".rstrip() for c in objs
           if getattr(c, "resolution", 0.0)]
    err = [f"{c.name} {se.label(c.setting_error, _unit(mech, c))}" for c in objs
           if getattr(c, "setting_error", None) is not None]
    return "; ".join(res) or "none", "; ".join(err) or "none"


@dataclass(frozen=True)
class Curve:
    """The yield of one strategy against the width of one error: a compensator's setting error
    (`yield_curve`: compensator, dist, unit) or the reading the compensators are set from
    (`measurement_curve`: positions). The same machines and the same draws at every width (only
    the scale changes), so width 0 is the row without that error."""

    mechanism: str
    strategy: str
    tolerances: str
    seed: int
    n: int
    widths: tuple[float, ...]
    rows: tuple[dict, ...]  # per width: its `row` (the generic words)
    column: str  # the width's: sd_UNIT or half_width_UNIT, or measurement_sd_um
    compensator: str = ""
    dist: str = ""  # "normal" (widths are standard deviations) or "uniform" (half-widths)
    unit: str = ""
    positions: int = 0  # the reading's crank positions (a measurement curve)

    @property
    def yields(self) -> np.ndarray:
        return np.array([r["ok"] / r["n"] for r in self.rows])

    @property
    def yield_ci(self) -> tuple[tuple[float, float], ...]:
        return tuple((float(r["yield_ci_low"]), float(r["yield_ci_high"])) for r in self.rows)

    def _head(self) -> dict:
        return {"positions": self.positions} if self.positions else \
            {"compensator": self.compensator, "dist": self.dist}

    def to_dataframe(self) -> pd.DataFrame:
        """One row per width: the width's column (with a setting error's compensator and dist
        before it, or a reading's positions after it), the counts (they add up to n), the
        yield with its 95 % Clopper-Pearson interval, the quantiles."""
        import pandas as pd

        keys = (*STATUSES, "n", "yield", "yield_ci_low", "yield_ci_high", "p50", "p95", "p99")
        return pd.DataFrame([{"strategy": self.strategy, **({self.column: w, **self._head()}
                                                             if self.positions else
                                                             {**self._head(), self.column: w}),
                              **{k: r[k] for k in keys}}
                             for w, r in zip(self.widths, self.rows, strict=True)])

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "strategy": self.strategy, **self._head(),
                **({} if self.positions else {"unit": self.unit}),
                "tolerances": self.tolerances, "seed": self.seed, "n": self.n,
                "yield_ci_method": "Clopper-Pearson exact binomial interval of ok / n, 95 %",
                "rows": self.to_dataframe().to_dict("records")}


YieldCurve = MeasurementCurve = Curve  # the names of the two curves before they were one


def with_setting_error(mech, compensators, name: str, error: SettingError | None):
    """The row `compensators` with compensator `name`'s setting error replaced (a strategy
    object keeps its type and fitting order; names become the file's compensator objects)."""
    objs = compensator_objects(mech, compensators)
    if name not in [c.name for c in objs]:
        raise ParameterError("compensator", "must be one of the strategy's ("
                             + (", ".join(c.name for c in objs) or "it has none") + ")", name)
    if error is not None and error.exact:
        error = None
    new = tuple(replace(c, setting_error=error) if c.name == name else c for c in objs)
    if hasattr(compensators, "compensators"):
        return replace(compensators, compensators=new)
    return new


def yield_curve(mech, tolerances, n: int, seed: int, strategy, compensator: str, widths,
                dist: str | None = None, output: str | None = None, spec=None, *,
                fast: bool = True, n_jobs: int = 1, progress=False, **options) -> Curve:
    """The yield of `strategy` (names of the mechanism's compensators, or a strategy object)
    on machines 0 .. n-1 of `seed` with `compensator`'s setting error at each of `widths`
    (its unit; the sd of a normal error or the half-width of a uniform one; `dist` default:
    the compensator's own law, else normal), the other compensators as declared. The same
    machines and error draws at every width (`set_in_order`), so the curve is smooth in the
    width and width 0 is the row without a setting error."""
    widths = tuple(float(w) for w in widths)
    if not widths or any(not (np.isfinite(w) and w >= 0) for w in widths):
        raise ParameterError("widths", "must be finite numbers >= 0", widths)
    objs = {c.name: c for c in compensator_objects(mech, strategy)}
    own = getattr(objs.get(compensator), "setting_error", None)
    dist = dist or (own.dist if own is not None else "normal")
    if dist not in se.DISTS:
        raise ParameterError("dist", f"must be one of {', '.join(se.DISTS)}", dist)
    rows = {f"{w!r}": with_setting_error(mech, strategy, compensator,
                                         SettingError(dist, w) if w else None)
            for w in widths}
    r = strategies(mech, tolerances, n, seed, rows, output, spec, fast=fast, n_jobs=n_jobs,
                   progress=progress, per_machine=False, **options)
    unit, key = _unit(mech, objs[compensator]), "sd" if dist == "normal" else "half_width"
    return Curve(mech.name, getattr(strategy, "name", "+".join(objs)), r.tolerances, int(seed),
                 r.n, widths, tuple(r.row(i) for i in range(len(r.names))),
                 f"{key}_{unit}" if unit else key, compensator, dist, unit)


def measurement_curve(mech, tolerances, n: int, seed: int, strategy, sds_um,
                      positions: int = me.DEFAULT_POSITIONS, output: str | None = None,
                      spec=None, *, fast: bool = True, n_jobs: int = 1, progress=False,
                      **options) -> Curve:
    """The yield of `strategy` on machines 0 .. n-1 of `seed` with its compensators set from a
    reading of `output` at `positions` crank angles, each with a normal error of each sd of
    `sds_um` (sd 0: from the truth). The same machines, setting errors and reading errors (up
    to the scale) at every sd: common random numbers."""
    sds = tuple(float(w) for w in sds_um)
    if not sds or any(not (np.isfinite(w) and w >= 0) for w in sds):
        raise ParameterError("sds_um", "must be finite numbers >= 0", sds_um)
    rows = []
    for w in sds:
        r = strategies(mech, tolerances, n, seed, {"row": strategy}, output, spec, fast=fast,
                       n_jobs=n_jobs, progress=progress, per_machine=False,
                       measurement=MeasurementError(w, positions), **options)
        rows.append(r.row(0))
    return Curve(mech.name, getattr(strategy, "name", "+".join(_names(strategy))), r.tolerances,
                 int(seed), r.n, sds, tuple(rows), "measurement_sd_um", positions=int(positions))
