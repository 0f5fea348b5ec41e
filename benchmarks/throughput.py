"""Positions per second on the 208 needle drive: sewtol's kernel, a plain per-angle Python loop
of the same equations (the reference) and pylinkage (the Python linkage peer), in one process.

    python benchmarks/throughput.py --json        (make bench: own venv with pylinkage)

Every figure is a median over repeats of CPU time (the machine is shared with other work); the
ratios compare medians taken in this same process.
Each solver runs on one thread (per core). Before timing, the three are checked to give the same
needle-bar positions (max difference reported, must be below 1e-9 mm).

The machine's practical limit (issue 11) is estimated by a hand-fused, SIMD-friendly loop of the
same equations: machines in structure-of-arrays columns, the angle loop outside and the machine
loop inside (contiguous, branch-free; fastmath and numpy's error model, i.e. no division-by-zero
check, so LLVM vectorises sqrt and division: vsqrtpd in its assembly), every per-machine
constant hoisted. It costs 63 flops per position (incl. 2 divisions and 2 square
roots); its rate, its GFLOP/s and the kernel's distance from it are printed. Targets: the
kernel at >= 25x pylinkage's step_fast and within 3x of the practical limit.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numba as nb  # noqa: E402
import numpy as np  # noqa: E402

from sewtol.mechanisms.needle_208.kernels import positions as K  # noqa: E402
from sewtol.mechanisms.needle_208.model import Needle208  # noqa: E402


def median_rate(fn, positions: int, repeats: int) -> float:
    """Positions per CPU second of this (single-threaded) process: on a shared machine the CPU
    time, not the wall time, is what the solver costs."""
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return positions / statistics.median(times)


def build_pylinkage(p: Needle208, steps: int):
    """The same mechanism in pylinkage 1.x: Crank, RRRDyad (branch by initial guess), FixedDyad."""
    import pylinkage as pl

    E0 = K.positions_loop(K.pack(p), np.array([0.0]))  # initial guesses on sewtol's branches
    from sewtol.mechanisms.needle_208 import metrics as nm
    from sewtol.mechanisms.needle_208 import model as nd

    o = nd.chain_from_crank(nm.columns(p)[0], np.array([[0.0]]))
    F = pl.Ground(0.0, 0.0, name="F")
    A = pl.Ground(p.Ax, p.Ay, name="A")
    D = pl.Ground(p.Dx, p.Dy, name="D")
    crank = pl.Crank(anchor=F, radius=p.LF, angular_velocity=2 * math.pi / steps,
                     initial_angle=0.0, name="L")
    M = pl.RRRDyad(anchor1=crank.output, anchor2=A, distance1=p.LM, distance2=p.AM,
                   x=float(o["M"].x[0, 0]), y=float(o["M"].y[0, 0]), name="M")
    B = pl.FixedDyad(anchor1=A, anchor2=M, distance=p.AB,
                     angle=p.beta_sense * math.radians(p.beta), name="B")
    C = pl.RRRDyad(anchor1=B, anchor2=D, distance1=p.BC, distance2=p.CD,
                   x=float(o["C"].x[0, 0]), y=float(o["C"].y[0, 0]), name="C")
    E = pl.FixedDyad(anchor1=B, anchor2=C, distance=p.BE, angle=math.radians(p.CBE), name="E")
    linkage = pl.Linkage([F, A, D, crank, M, B, C, E])
    return linkage, E0


FLOPS_PER_POSITION = 63


@nb.njit(cache=True, fastmath=True, error_model="numpy")
def _limit_soa(cols, cphi, sphi, out_x, out_y):
    """The hand-fused loop: cols (16, n) in needle_positions.FIELDS order, angles outside."""
    n = cols.shape[1]
    LF, LM, AM, AB, BC, BE, CD = cols[0], cols[1], cols[2], cols[3], cols[4], cols[5], cols[6]
    ax, ay, dx, dy, bm, bc = cols[9], cols[10], cols[11], cols[12], cols[13], cols[14]
    arm_c = np.empty(n)
    arm_s = np.empty(n)
    rod_c = np.empty(n)
    rod_s = np.empty(n)
    k1 = np.empty(n)
    k2 = np.empty(n)
    lm2 = np.empty(n)
    bc2 = np.empty(n)
    for i in range(n):
        ra = cols[15, i] * cols[8, i] * math.pi / 180.0
        arm_c[i] = AB[i] / AM[i] * math.cos(ra)
        arm_s[i] = AB[i] / AM[i] * math.sin(ra)
        rc = cols[7, i] * math.pi / 180.0
        rod_c[i] = BE[i] / BC[i] * math.cos(rc)
        rod_s[i] = BE[i] / BC[i] * math.sin(rc)
        k1[i] = LM[i] * LM[i] - AM[i] * AM[i]
        k2[i] = BC[i] * BC[i] - CD[i] * CD[i]
        lm2[i] = LM[i] * LM[i]
        bc2[i] = BC[i] * BC[i]
    for k in range(cphi.size):
        c0 = cphi[k]
        s0 = sphi[k]
        ox = out_x[k]
        oy = out_y[k]
        for i in range(n):
            lx = LF[i] * c0
            ly = LF[i] * s0
            ux = ax[i] - lx
            uy = ay[i] - ly
            d2 = ux * ux + uy * uy
            inv = 1.0 / d2
            a = 0.5 * (k1[i] + d2) * inv
            h = math.sqrt(max(lm2[i] * inv - a * a, 0.0))
            mx = lx + a * ux - bm[i] * h * uy
            my = ly + a * uy + bm[i] * h * ux
            vx = mx - ax[i]
            vy = my - ay[i]
            bx = ax[i] + arm_c[i] * vx - arm_s[i] * vy
            by = ay[i] + arm_s[i] * vx + arm_c[i] * vy
            ux = dx[i] - bx
            uy = dy[i] - by
            d2 = ux * ux + uy * uy
            inv = 1.0 / d2
            a = 0.5 * (k2[i] + d2) * inv
            h = math.sqrt(max(bc2[i] * inv - a * a, 0.0))
            wx = a * ux - bc[i] * h * uy
            wy = a * uy + bc[i] * h * ux
            ox[i] = bx + rod_c[i] * wx - rod_s[i] * wy
            oy[i] = by + rod_s[i] * wx + rod_c[i] * wy


def practical_limit(P, phi, repeats):
    """Positions/s of the hand-fused loop and its max difference from the kernel (mm)."""
    cols = np.ascontiguousarray(P.T)
    cphi, sphi = np.cos(phi), np.sin(phi)
    ox = np.empty((phi.size, P.shape[0]))
    oy = np.empty((phi.size, P.shape[0]))
    _limit_soa(cols, cphi, sphi, ox, oy)
    ref = K.positions_kernel_serial(P, phi)
    diff = float(max(np.max(np.abs(ox.T - ref[..., 0])), np.max(np.abs(oy.T - ref[..., 1]))))
    rate = median_rate(lambda: _limit_soa(cols, cphi, sphi, ox, oy), P.shape[0] * phi.size,
                       repeats)
    return rate, diff


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--angles", type=int, default=3600)
    ap.add_argument("--machines", type=int, default=200)
    args = ap.parse_args(argv)

    p = Needle208.nominal()
    P1 = K.pack(p)
    P = np.repeat(P1, args.machines, axis=0)
    phi = np.linspace(0.0, 2 * math.pi, args.angles, endpoint=False)
    ref = K.positions_loop(P1, phi)
    fast = K.positions_kernel_serial(P, phi)  # compiles (cache) and checks
    diff_loop = float(np.max(np.abs(fast[0] - ref[0])))

    sewtol_rate = median_rate(lambda: K.positions_kernel_serial(P, phi), P.shape[0] * phi.size,
                              args.repeats)
    loop_angles = max(args.angles // 10, 36)
    loop_rate = median_rate(lambda: K.positions_loop(P1, phi[:loop_angles]), loop_angles,
                            max(3, args.repeats // 2))

    limit_rate, diff_limit = practical_limit(P, phi, args.repeats)
    result = {"sewtol_positions_per_s": sewtol_rate, "loop_positions_per_s": loop_rate,
              "vs_loop": sewtol_rate / loop_rate, "max_diff_vs_loop_mm": diff_loop,
              "practical_limit_positions_per_s": limit_rate,
              "practical_limit_gflops": limit_rate * FLOPS_PER_POSITION / 1e9,
              "flops_per_position": FLOPS_PER_POSITION,
              "limit_over_sewtol (target <= 3)": limit_rate / sewtol_rate,
              "max_diff_vs_limit_loop_mm": diff_limit,
              "load_average": os.getloadavg()[0],
              "threads": 1, "machines": args.machines, "angles": args.angles,
              "repeats": args.repeats}
    try:
        import pylinkage
    except ImportError:
        result.update({"pylinkage_positions_per_s": None, "vs_pylinkage (target >= 25)": None,
                       "pylinkage": "not installed (make bench installs it in .venv-bench)"})
    else:
        linkage, _ = build_pylinkage(p, args.angles)
        names = [c.name for c in linkage.components]
        traj = linkage.step_fast(iterations=args.angles)
        # pylinkage records the state after each step: step k is at crank angle (k+1) * dphi
        e_pl = traj[:, names.index("E"), :]
        e_ref = np.roll(fast[0], -1, axis=0)
        diff_pl = float(np.nanmax(np.abs(e_pl - e_ref)))

        def run_pylinkage():
            linkage.step_fast(iterations=args.angles)

        linkage.step_fast(iterations=args.angles)
        pl_rate = median_rate(run_pylinkage, args.angles, args.repeats)
        result.update({"pylinkage_positions_per_s": pl_rate,
                       "vs_pylinkage (target >= 25)": sewtol_rate / pl_rate,
                       "pylinkage_version": pylinkage.__version__ if hasattr(pylinkage, "__version__")
                       else "unknown", "pylinkage_solver": "Linkage.step_fast (numba)",
                       "max_diff_vs_pylinkage_mm": diff_pl})
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for k, v in result.items():
            print(f"{k:28s} {v}")
    return 0 if diff_loop < 1e-9 else 1


if __name__ == "__main__":
    sys.exit(main())
