"""The generic adjuster (sewtol.adjuster) against brute force on n machines of two files.

- needle_208 (tolerance set `base`): beta and guide_shift minimise SumDelta_um. The brute force
  uses the structure where it is exact: SumDelta at guide shift s is max(D1 - s, 0) +
  max(s - D0, 0), D0 and D1 the smallest and largest deviation over the turn (read from the file
  itself at s = +-1e4 um), so its minimum over the shift box is analytic per beta; beta: a grid
  of 251 settings over 10 ... 35 deg (0.1 deg), then 5 zooms of 21 settings over +-1 step
  around each of the 4 lowest local minima of that grid (to 1e-6 deg).
- spatial_crank_rocker (set `illustrative`): rocker_arm and rocker_collar bring rocker_swing_deg
  to a target at the edge of their reach (some machines reach it, some stop at a corner); brute
  force: adjuster.brute_force (a 31 x 31 grid, then 4 zooms of 9 x 9).

Prints max |generic - brute| of the minimised quantity, max (generic - brute) (how far the
generic search stops above the brute force's best), the certificate's largest gap bound and
the time, after every chunk of machines (a running report). Run:
python benchmarks/validate_generic_adjuster.py [--n 2000] [--seed 2026] [--only needle|rocker]
    [--part I/P]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from sewtol import adjuster as A
from sewtol.mechanism import load

BIG_UM = 1e4
SWING_TARGET_DEG = 53.45


def needle_brute_force(mech, values, points=251, zoom=21, zooms=5, basins=4):
    """min over (beta, guide_shift) of SumDelta_um: analytic in the shift, grids in beta."""
    comp, shift = mech.compensators["beta"], mech.compensators["guide_shift"]
    m = len(next(iter(values.values())))

    def g(rows, beta):
        v = {k: np.asarray(a, float)[rows] for k, a in values.items()}
        v["beta"] = beta
        own = v.get("guide_shift_um", np.zeros(rows.size))
        y = [mech.evaluate({**v, "guide_shift_um": own + s}, ["SumDelta_um"]).outputs[
            "SumDelta_um"] for s in (BIG_UM, -BIG_UM)]
        d0, d1 = BIG_UM - y[0], y[1] - BIG_UM  # extremes of the deviation at offset 0
        s = np.clip(np.clip(0.0, d0, d1), shift.low, shift.high)  # nearest the plateau
        val = np.maximum(d1 - s, 0.0) + np.maximum(s - d0, 0.0)
        return np.where(np.isnan(val), np.inf, val)

    B = np.linspace(comp.low, comp.high, points)
    Y = g(np.repeat(np.arange(m), points), np.tile(B, m)).reshape(m, points)
    # every basin of the grid, not only the best cell: zoom around the `basins` lowest local
    # minima of each machine's grid (a basin whose grid value is a little higher can hold the
    # global minimum between two grid points)
    pad = np.pad(Y, ((0, 0), (1, 1)), constant_values=np.inf)
    local = (Y <= pad[:, :-2]) & (Y <= pad[:, 2:]) & np.isfinite(Y)
    ranked = np.argsort(np.where(local, Y, np.inf), axis=1, kind="stable")[:, :basins]
    rows = np.repeat(np.arange(m), basins)
    x = B[ranked.ravel()]
    fx = Y[rows, ranked.ravel()]
    h = B[1] - B[0]
    u = np.linspace(-1.0, 1.0, zoom)
    for _ in range(zooms):
        C = np.clip(x[:, None] + u * h, comp.low, comp.high)
        Yc = g(np.repeat(rows, zoom), C.ravel()).reshape(rows.size, zoom)
        j = Yc.argmin(axis=1)
        k = np.arange(rows.size)
        better = Yc[k, j] < fx
        x = np.where(better, C[k, j], x)
        fx = np.minimum(fx, Yc[k, j])
        h *= 2.0 / (zoom - 1)
    fx, x = fx.reshape(m, basins), x.reshape(m, basins)
    best = fx.argmin(axis=1)
    return fx[np.arange(m), best], x[np.arange(m), best]


def machines(mech, set_name, n, seed):
    dev = mech.tolerance_sets[set_name].sample(np.random.default_rng(seed), n)
    nominal = mech.nominal_values()
    return {k: nominal[k] + v for k, v in dev.items()}


def run(name, mech, vals, output, adjust, objective, brute, chunk):
    """The generic adjuster and the brute force, chunk by chunk (a running report each)."""
    n = len(next(iter(vals.values())))
    diffs, gaps, evals, t_gen, t_brute, reached, at_end = [], [], 0, 0.0, 0.0, 0, 0
    for a in range(0, n, chunk):
        part = {k: v[a:a + chunk] for k, v in vals.items()}
        t = time.perf_counter()
        got = A.adjust(mech, part, output, adjust, objective)
        t1 = time.perf_counter()
        best = brute(part)
        t_gen, t_brute = t_gen + t1 - t, t_brute + time.perf_counter() - t1
        diffs.append(got.loss - best)
        gaps.append(got.gap_bound)
        evals += got.evaluations
        reached += int(np.sum(got.loss < 1e-6))
        at_end += int(np.sum(np.any(list(got.at_bound.values()), axis=0)))
        d = np.concatenate(diffs)
        ok = np.isfinite(d)
        print(f"{name}: {d.size} machines, {int(ok.sum())} compared; max |generic - brute| "
              f"{np.max(np.abs(d[ok])):.3g}, max (generic - brute) {np.max(d[ok]):.3g}, min "
              f"{np.min(d[ok]):.3g}; above brute by > 1e-3: {int(np.sum(d[ok] > 1e-3))}; "
              f"largest gap bound {np.nanmax(np.concatenate(gaps)):.3g}; generic {t_gen:.0f} s "
              f"({evals / d.size:.0f} evaluations per machine), brute force {t_brute:.0f} s; "
              f"loss < 1e-6: {reached}, a setting at a bound: {at_end}", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--chunk", type=int, default=100)
    ap.add_argument("--only", choices=("needle", "rocker"), default=None)
    ap.add_argument("--part", default="0/1", help="I/P: run the I-th of P equal slices of the n "
                    "machines (the same draws whatever P), so P processes share one run")
    args = ap.parse_args(argv)
    i, p = (int(x) for x in args.part.split("/"))
    if not 0 <= i < p:
        ap.error(f"--part: must be I/P with 0 <= I < P, got {args.part}")

    def part(vals):
        n = len(next(iter(vals.values())))
        a, b = n * i // p, n * (i + 1) // p
        return {k: v[a:b] for k, v in vals.items()}

    needle = load("examples/needle_208.toml")
    if args.only != "rocker":
        run("needle_208 beta,guide_shift minimise SumDelta_um", needle,
            part(machines(needle, "base", args.n, args.seed)), "SumDelta_um", "beta,guide_shift",
            None, lambda v: needle_brute_force(needle, v)[0], args.chunk)
    if args.only == "needle":
        return
    rocker = load("src/sewtol/mechanisms/spatial_crank_rocker/mechanism.toml")
    goal = f"target={SWING_TARGET_DEG}"
    comps = "rocker_arm,rocker_collar"
    run(f"spatial_crank_rocker {comps} {goal} rocker_swing_deg", rocker,
        part(machines(rocker, "illustrative", args.n, args.seed)), "rocker_swing_deg", comps, goal,
        lambda v: A.brute_force(rocker, v, "rocker_swing_deg", comps, goal, points=31, zoom=9,
                                zooms=4)[0], args.chunk)


if __name__ == "__main__":
    main()
