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
