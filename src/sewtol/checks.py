"""The shared suite every implementation of the mechanism protocol passes (sewtol.protocol).

As scikit-learn's ``check_estimator`` holds every estimator to one contract, `check_mechanism`
holds every mechanism, built-in or a user's file, to the checks of `CHECKS` (each one's
docstring says what it holds): the protocol's parts, the nominal machine, honest vectorisation,
counted failures, specs, compensators, tolerance sets and the same machines for a seed, a fused
kernel within its bound, an exact adjuster not beaten by a grid, and override.

    from sewtol.checks import check_mechanism
    check_mechanism(sewtol.mechanism.load("my.toml"))      # raises AssertionError naming the check
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sewtol import protocol as pr

STATUSES = ("ok", "cannot_close", "dead_point")
SEED = 20261125
BATCH = 4
# evaluation of one machine alone and within a batch: the same arithmetic, so equal to rounding
BATCH_RTOL = 1e-12
# the adjuster's optimum against a grid of this many settings per compensator over its box
ADJUSTER_GRID = 41


def _fail(check: str, what: str):
    raise AssertionError(f"{check}: {what}")


def _batch(mech, m: int = BATCH) -> dict[str, np.ndarray]:
    """m machines from the mechanism's first tolerance set (without one: nominal copies)."""
    sets = list(mech.tolerance_sets.values())
    dev = pr.input_law(mech, sets[0]).sample(np.random.default_rng(SEED), m) if sets else {}
    if not dev:
        first = mech.parameters[0].name
        return {first: np.full(m, mech.nominal_values()[first])}
    return pr.machines(mech, dev)


def check_protocol(mech) -> None:
    """The protocol's parts are there; parameter and output names are unique; units given."""
    if not isinstance(mech, pr.Mechanism):
        _fail("check_protocol", f"{type(mech).__name__} lacks a part of sewtol.protocol.Mechanism")
    for kind, items in (("parameter", mech.parameters), ("output", mech.outputs)):
        names = [i.name for i in items]
        if len(set(names)) != len(names):
            _fail("check_protocol", f"{kind} names repeat: {names}")
        for i in items:
            if not getattr(i, "unit", ""):
                _fail("check_protocol", f"{kind} {i.name} has no unit")


def check_nominal_assembles(mech) -> None:
    """The nominal machine runs and every output is a finite number."""
    ev = mech.evaluate()
    if list(ev.status) != ["ok"]:
        _fail("check_nominal_assembles", f"nominal status {ev.status[0]!r} at group "
              f"{ev.failed_group[0]!r}")
    bad = [k for k, v in ev.outputs.items() if not np.all(np.isfinite(v))]
    if bad:
        _fail("check_nominal_assembles", f"outputs not finite at nominal: {bad}")


def check_batch_consistent(mech) -> None:
    """m machines evaluated together give, machine by machine, what each gives alone."""
    vals = _batch(mech)
    together = mech.evaluate(vals)
    for j in range(BATCH):
        alone = mech.evaluate({k: v[j:j + 1] for k, v in vals.items()})
        if alone.status[0] != together.status[j]:
            _fail("check_batch_consistent", f"machine {j}: status {alone.status[0]!r} alone, "
                  f"{together.status[j]!r} in the batch")
        for k, v in alone.outputs.items():
            a, b = v[0], together.outputs[k][j]
            if not (np.isnan(a) and np.isnan(b)) and not np.isclose(a, b, rtol=BATCH_RTOL,
                                                                    atol=0.0):
                _fail("check_batch_consistent", f"machine {j}, {k}: {a!r} alone, {b!r} in "
                      "the batch")


def check_failures_counted(mech) -> None:
    """Every machine has a known status; outputs are NaN exactly where it is not ok; the
    counts add up to n (a machine far outside its tolerances included)."""
    vals = _batch(mech)
    # one more machine with every length-like parameter 3x nominal: often one that cannot close
    big = {p.name: np.array([p.nominal * (3.0 if p.rule == "positive" else 1.0)])
           for p in mech.parameters}
    nominal = mech.nominal_values()
    vals = {k: np.concatenate([np.broadcast_to(vals.get(k, nominal[k]), (BATCH,)), big[k]])
            for k in big}
    ev = mech.evaluate(vals)
    unknown = set(ev.status) - set(STATUSES)
    if unknown:
        _fail("check_failures_counted", f"unknown statuses {sorted(unknown)}")
    counts = ev.counts()
    if sum(counts[s] for s in STATUSES) != counts["n"] or counts["n"] != BATCH + 1:
        _fail("check_failures_counted", f"counts {counts} do not add up to {BATCH + 1}")
    ok = ev.status == "ok"
    # a machine that runs may still leave an output undefined (NaN: the presser foot that never
    # loses contact has no separation); studies count those as "undefined"
    for k, v in ev.outputs.items():
        if not np.all(np.isnan(v[~ok])):
            _fail("check_failures_counted", f"{k} is a number where the machine does not run")
    for s, g in zip(ev.status, ev.failed_group, strict=True):
        if (s == "ok") != (g == ""):
            _fail("check_failures_counted", f"status {s!r} with failed group {g!r}")
    table = pr.plugins(mech).failure_table
    words = set(STATUSES) - {"ok"} | {"unexplained"}
    if table is not None and not set(table(mech, vals)["status"][~ok]) <= words:
        _fail("check_failures_counted", "the plug-in's failure_table names a machine that does "
              f"not run otherwise than {sorted(words)}")


def check_specs(mech) -> None:
    """Specs name outputs, limits are finite and ordered, and the nominal machine meets them."""
    outputs = {o.name for o in mech.outputs}
    ev = None
    for s in mech.specs:
        if s.output not in outputs:
            _fail("check_specs", f"spec on {s.output!r}, not an output")
        lo, hi = s.lower, s.upper
        if lo is None and hi is None:
            _fail("check_specs", f"spec on {s.output} has no limit")
        if any(v is not None and not np.isfinite(v) for v in (lo, hi)):
            _fail("check_specs", f"spec on {s.output} has a limit that is not finite")
        if lo is not None and hi is not None and not lo < hi:
            _fail("check_specs", f"spec on {s.output}: lower {lo} not below upper {hi}")
        ev = ev or mech.evaluate()
        y = float(ev.outputs[s.output][0])
        if (lo is not None and y < lo) or (hi is not None and y > hi):
            _fail("check_specs", f"the nominal {s.output} = {y:.6g} is outside its spec "
                  f"[{lo}, {hi}]")


def check_compensators(mech) -> None:
    """Each compensator sets a parameter; its box is ordered and holds the nominal setting
    (absolute ones) or zero (offsets); steps fit the box; resolutions and errors >= 0."""
    params = {p.name: p for p in mech.parameters}
    for name, c in mech.compensators.items():
        if c.parameter not in params:
            _fail("check_compensators", f"{name} sets {c.parameter!r}, not a parameter")
        if not (np.isfinite(c.low) and np.isfinite(c.high) and c.low < c.high):
            _fail("check_compensators", f"{name}: box [{c.low}, {c.high}] not ordered")
        mode = getattr(c, "mode", "absolute")
        here = params[c.parameter].nominal if mode == "absolute" else 0.0
        if not c.low <= here <= c.high:
            _fail("check_compensators", f"{name}: box [{c.low}, {c.high}] ({mode}) does not "
                  f"hold the nominal setting {here}")
        step = getattr(c, "step", None)
        if step is not None:
            k = (c.high - c.low) / step
            if not (step > 0 and abs(k - round(k)) < 1e-9 * max(1.0, k)):
                _fail("check_compensators", f"{name}: step {step} does not divide its box")
        v = getattr(c, "resolution", 0.0) or 0.0
        if not (np.isfinite(v) and v >= 0):
            _fail("check_compensators", f"{name}: resolution {v} must be >= 0")
        err = getattr(c, "setting_error", None)
        if err is not None and not (np.isfinite(err.width) and err.width >= 0):
            _fail("check_compensators", f"{name}: setting error {err} must be >= 0")


def check_tolerance_sets(mech) -> None:
    """Sets name parameters of the mechanism, and the same seed draws the same machines."""
    names = [p.name for p in mech.parameters]
    for key, ts in mech.tolerance_sets.items():
        try:
            law = pr.input_law(mech, ts)
        except ValueError as exc:
            _fail("check_tolerance_sets", f"set {key}: {exc}")
        a = law.sample(np.random.default_rng(SEED), 8)
        b = law.sample(np.random.default_rng(SEED), 8)
        if any(not np.array_equal(a[k], b[k]) for k in a) or set(a) - set(names):
            _fail("check_tolerance_sets", f"set {key}: the same seed drew other machines")
        for t in law.marginals:
            lo, hi = t.reach()
            if np.any(a[t.param] < lo) or np.any(a[t.param] > hi):
                _fail("check_tolerance_sets", f"set {key}: {t.param} drawn outside its reach")


def check_kernel(mech) -> None:
    """A fused kernel's outputs equal the generic evaluation within the bound it derives."""
    pl = pr.plugins(mech)
    if pl.kernel is None:
        return
    vals = _batch(mech)
    fast = pl.kernel(mech, vals)
    slow = mech.evaluate(vals, list(fast))
    bound = pl.kernel_bound(mech, vals) if pl.kernel_bound else {}
    for k, y in fast.items():
        g = slow.outputs[k]
        runs = slow.status == "ok"
        if not np.array_equal(np.isnan(y[runs]), np.isnan(g[runs])):
            _fail("check_kernel", f"{k}: the kernel and the generic path disagree on which "
                  "machines run")
        b = np.broadcast_to(bound.get(k, 0.0), y.shape)
        d = np.abs(y - g)[runs]
        if not np.all(d <= b[runs]):
            _fail("check_kernel", f"{k}: kernel and generic differ by {np.max(d):.3g} > bound "
                  f"{np.max(b[runs]):.3g}")


def check_adjuster(mech) -> None:
    """An exact adjuster's optimum is not beaten, on any machine, by a grid over its box
    (settings evaluated by the kernel where there is one, else generically)."""
    pl = pr.plugins(mech)
    if pl.adjuster is None:
        return
    by_param = {c.parameter: c for c in mech.compensators.values()}
    vals = _batch(mech, 2)
    for params in pl.adjuster_sets:
        if not params <= set(by_param):
            continue
        boxes = {p: (by_param[p].low, by_param[p].high) for p in params}
        got = pl.adjuster(mech, vals, boxes)["value"]
        axes = [np.linspace(lo, hi, ADJUSTER_GRID) for lo, hi in boxes.values()]
        grid = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
        for j in range(2):
            trial = {k: np.full(len(grid), v[j]) for k, v in vals.items()}
            trial.update({p: grid[:, i] for i, p in enumerate(boxes)})
            if pl.kernel is not None:
                y = pl.kernel(mech, trial)[pl.adjusted_output]
            else:
                y = mech.evaluate(trial, [pl.adjusted_output]).outputs[pl.adjusted_output]
            best = np.nanmin(y)
            if got[j] > best + pl.adjuster_tol:
                _fail("check_adjuster", f"{sorted(params)}, machine {j}: optimum {got[j]!r} "
                      f"beaten by the grid's {best!r}")


def check_override(mech) -> None:
    """A copy with new nominal values evaluates as those machines do (design refinement)."""
    p = next((p for p in mech.parameters if p.rule == "positive"), None)
    if p is None:
        return
    moved = mech.override(**{p.name: p.nominal * 1.001})
    a = moved.evaluate()
    b = mech.evaluate({p.name: np.array([p.nominal * 1.001])})
    if moved.nominal_values()[p.name] != p.nominal * 1.001 or \
            mech.nominal_values()[p.name] != p.nominal:
        _fail("check_override", "override changed the original or not the copy")
    for k in a.outputs:
        x, y = a.outputs[k][0], b.outputs[k][0]
        if not (np.isnan(x) and np.isnan(y)) and not np.isclose(x, y, rtol=BATCH_RTOL, atol=0):
            _fail("check_override", f"{k}: {x!r} as a nominal, {y!r} as a machine")


CHECKS: tuple[Callable, ...] = (
    check_protocol, check_nominal_assembles, check_batch_consistent, check_failures_counted,
    check_specs, check_compensators, check_tolerance_sets, check_kernel, check_adjuster,
    check_override,
)


def check_mechanism(mech) -> None:
    """Run every check of the protocol suite on `mech`; the first failure raises
    AssertionError naming the check and what failed."""
    for check in CHECKS:
        check(mech)
