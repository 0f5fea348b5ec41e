"""An independent model of the 208 needle drive, written from docs/needle_208.md alone, for the
refinement tests: plain numpy, the crank sampled densely, the dyads closed by the circle
intersection formula; no sewtol engine, metric, kernel or optimiser code.

Conventions (docs/needle_208.md): F at the origin; L = LF e(phi); M on side branch_M of L->A
(left: +1) with |LM| = LM, |AM| = AM; B = A + AB e(ang(A->M) + beta_sense * beta); C on side
branch_C of B->D with |BC|, |CD|; E = B + BE e(ang(B->C) + CBE); the guide through
(guide_x, guide_y) along u = (sin a, cos a), normal n = (cos a, -sin a), moved guide_shift_um
along n. d = n.(E - G) in um.
"""

from __future__ import annotations

import numpy as np

DEG = np.pi / 180.0


def _circles(p, r1, q, r2, side):
    """The intersection of circles (p, r1) and (q, r2) on side `side` of p->q (left +1);
    NaN where they miss."""
    v = q - p
    dist = np.abs(v)
    a = (r1 * r1 - r2 * r2 + dist * dist) / (2 * dist)
    h2 = r1 * r1 - a * a
    h = np.sqrt(np.where(h2 >= 0, h2, np.nan))
    ev = v / dist
    return p + a * ev + side * h * 1j * ev


def _transmission(r1, r2, s):
    c = np.clip((r1 * r1 + r2 * r2 - s * s) / (2 * r1 * r2), -1, 1)
    g = np.degrees(np.arccos(c))
    return np.minimum(g, 180 - g)


def figures(p: dict, samples: int = 72000) -> dict:
    """SumDelta (um), stroke (mm, along the guide), the smallest transmission angle of each dyad
    (deg) over a crank turn, and whether every angle closes."""
    phi = np.arange(samples) * 2 * np.pi / samples
    A = p["Ax"] + 1j * p["Ay"]
    D = p["Dx"] + 1j * p["Dy"]
    L = p["LF"] * np.exp(1j * phi)
    M = _circles(L, p["LM"], A, p["AM"], p["branch_M"])
    theta = np.angle(M - A)
    B = A + p["AB"] * np.exp(1j * (theta + p["beta_sense"] * p["beta"] * DEG))
    C = _circles(B, p["BC"], D, p["CD"], p["branch_C"])
    E = B + p["BE"] * np.exp(1j * (np.angle(C - B) + p["CBE"] * DEG))
    a = p["guide_angle"] * DEG
    n = np.cos(a) - 1j * np.sin(a)
    u = np.sin(a) + 1j * np.cos(a)
    G = p["guide_x"] + 1j * p["guide_y"] + n * p["guide_shift_um"] * 1e-3
    d = ((np.conjugate(n) * (E - G)).real) * 1e3
    along = (np.conjugate(u) * E).real
    return {
        "closes": bool(np.all(np.isfinite(E))),
        "SumDelta_um": float(max(d.max(), 0) + max(-d.min(), 0)),
        "stroke_mm": float(along.max() - along.min()),
        "transmission_LMA_deg": float(_transmission(p["LM"], p["AM"], np.abs(A - L)).min()),
        "transmission_BCD_deg": float(_transmission(p["BC"], p["CD"], np.abs(D - B)).min()),
    }


def _loops(p):
    """The two loop-closure residuals, written from the description: loop 1 closes the crank,
    the connecting rod and the first rocker (unknowns: the rod's angle a and the rocker's t);
    loop 2 closes the ternary rod's B-C and the rear rocker (unknowns: B->C's angle g and
    D->C's angle s)."""
    A = p["Ax"] + 1j * p["Ay"]
    D = p["Dx"] + 1j * p["Dy"]

    def loop1(x, phi):
        a, t = x
        r = p["LF"] * np.exp(1j * phi) + p["LM"] * np.exp(1j * a) - A - p["AM"] * np.exp(1j * t)
        return [r.real, r.imag]

    def B_of(t):
        return A + p["AB"] * np.exp(1j * (t + p["beta_sense"] * p["beta"] * DEG))

    def loop2(x, B):
        g, s = x
        r = B + p["BC"] * np.exp(1j * g) - D - p["CD"] * np.exp(1j * s)
        return [r.real, r.imag]

    return A, D, loop1, B_of, loop2


def _cross(u, v):
    return (np.conjugate(u) * v).imag


def figures_root(p: dict, samples: int = 3600) -> dict:
    """SumDelta (um) and stroke (mm) of a design by a second, plain route: every position by
    scipy.optimize.root on the loop-closure equations (continued from the previous crank
    angle; the first angle's branch picked by the side rules of the description), then each
    extreme of d and of the travel along the guide refined by a bounded scalar search in the
    crank angle around the sampled one. No sewtol code, no circle-intersection formula."""
    from scipy.optimize import minimize_scalar, root

    A, D, loop1, B_of, loop2 = _loops(p)
    a_ = p["guide_angle"] * DEG
    n = np.cos(a_) - 1j * np.sin(a_)
    u = np.sin(a_) + 1j * np.cos(a_)
    G = p["guide_x"] + 1j * p["guide_y"] + n * p["guide_shift_um"] * 1e-3

    def branch_ok(phi, x1, x2):
        L = p["LF"] * np.exp(1j * phi)
        M = A + p["AM"] * np.exp(1j * x1[1])
        B = B_of(x1[1])
        C = D + p["CD"] * np.exp(1j * x2[1])
        return (np.sign(_cross(A - L, M - L)) == p["branch_M"]
                and np.sign(_cross(D - B, C - B)) == p["branch_C"])

    def solve(phi, g1, g2):
        r1 = root(loop1, g1, args=(phi,), tol=1e-13)
        B = B_of(r1.x[1])
        r2 = root(loop2, g2, args=(B,), tol=1e-13)
        # closed when the residuals vanish (root's own flag also reports slow progress)
        ok = (np.max(np.abs(loop1(r1.x, phi))) < 1e-9
              and np.max(np.abs(loop2(r2.x, B))) < 1e-9)
        return r1.x, r2.x, ok

    def E_of(x1, x2):
        return B_of(x1[1]) + p["BE"] * np.exp(1j * (x2[0] + p["CBE"] * DEG))

    # the first angle: a grid of guesses, the solution on the described branches
    guesses = np.linspace(-np.pi, np.pi, 12, endpoint=False)
    start = None
    for ga in guesses:
        for gt in guesses:
            x1, _, _ = solve(0.0, [ga, gt], [0.0, 0.0])
            for gg in guesses:
                for gs in guesses:
                    x1b, x2, ok = solve(0.0, x1, [gg, gs])
                    if ok and branch_ok(0.0, x1b, x2):
                        start = (x1b, x2)
                        break
                if start:
                    break
            if start:
                break
        if start:
            break
    if start is None:
        return {"closes": False}
    phis = np.arange(samples) * 2 * np.pi / samples
    X1 = np.empty((samples, 2))
    X2 = np.empty((samples, 2))
    g1, g2 = start
    closes = True
    for k, phi in enumerate(phis):
        g1, g2, ok = solve(phi, g1, g2)
        closes &= bool(ok and branch_ok(phi, g1, g2))
        X1[k], X2[k] = g1, g2
    E = np.array([E_of(a, b) for a, b in zip(X1, X2, strict=True)])
    d = (np.conjugate(n) * (E - G)).real * 1e3
    along = (np.conjugate(u) * E).real
    h = 2 * np.pi / samples

    def extreme(values, sign, near):
        # at a minimax optimum several peaks are (nearly) equal: every sampled peak within
        # `near` of the highest is refined, the highest refined one is the extreme
        v = sign * values
        peaks = np.flatnonzero((v >= np.roll(v, 1)) & (v >= np.roll(v, -1))
                               & (v >= v.max() - near))
        best = -np.inf
        for k in peaks:
            def f(phi, k=k):
                x1, x2, _ = solve(phi, X1[k], X2[k])
                e = E_of(x1, x2)
                w = ((np.conjugate(n) * (e - G)).real * 1e3 if values is d
                     else (np.conjugate(u) * e).real)
                return -sign * w

            r = minimize_scalar(f, bounds=(phis[k] - h, phis[k] + h), method="bounded",
                                options={"xatol": 1e-10})
            best = max(best, v[k], -r.fun)
        return best * sign

    dmax, dmin = extreme(d, 1.0, 1e-2), extreme(d, -1.0, 1e-2)
    return {"closes": closes,
            "SumDelta_um": float(max(dmax, 0) + max(-dmin, 0)),
            "stroke_mm": float(extreme(along, 1.0, 1e-5) - extreme(along, -1.0, 1e-5)),
            "d_um": d}
