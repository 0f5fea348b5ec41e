"""Event-driven contact dynamics of the presser foot on its crank-slider (numba, one machine per
loop iteration; the model: model.py and this folder's README.md). Crank-angle domain: phi in
radians, derivatives d/dphi, lengths mm, accelerations mm/rad^2 (times omega^2 for mm/s^2).
Inputs per machine: the slider (crank r, rod L, offset a), the foot's normalised oscillator (nu
= natural frequency / crank speed, damping ratio zeta, balance x_eq in the seat coordinate y)
and the material level y_m (+inf: none). Between events the foot's motion is the exact damped
free vibration; events are sampled at STEP_RAD and bisected to ROOT_TOL_RAD.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

STEP_RAD = math.radians(0.25)     # sampling step for event detection
ROOT_TOL_RAD = 1e-12              # bisection stops below this bracket width (rad)
MAX_TURNS = 3.0                   # a lost interval must close within this many turns
# status codes (mechanisms.presser_foot.STATUS names them)
OK, NO_LOSS, NO_CONTACT, NOT_REGAINED, CANNOT_ASSEMBLE = 0, 1, 2, 3, 4
COLUMNS = ("loss_deg", "regain_deg", "lost_deg", "separation_mm", "impacts", "landed",
           "status", "lost_by_force", "intervals")


@nb.njit(cache=True)
def slider(phi, r, L, a):
    """y, dy/dphi, d2y/dphi2 of the seat: y = sqrt(L^2 - (r sin phi)^2) + r cos phi + a."""
    s = math.sin(phi)
    c = math.cos(phi)
    S = math.sqrt(L * L - r * r * s * s)
    y = S + r * c + a
    d1 = -r * s - r * r * s * c / S
    d2 = -r * c - r * r * (c * c - s * s) / S - r ** 4 * s * s * c * c / (S * S * S)
    return y, d1, d2


@nb.njit(cache=True)
def free(dphi, x0, v0, nu, zeta, x_eq):
    """Exact damped free vibration about x_eq: position and velocity dphi after (x0, v0)."""
    wd = nu * math.sqrt(1.0 - zeta * zeta)
    u0 = x0 - x_eq
    e = math.exp(-zeta * nu * dphi)
    c = math.cos(wd * dphi)
    s = math.sin(wd * dphi)
    b = (v0 + zeta * nu * u0) / wd
    u = e * (u0 * c + b * s)
    du = e * (-zeta * nu * (u0 * c + b * s) + (-u0 * wd * s + b * wd * c))
    return x_eq + u, du


@nb.njit(cache=True)
def contact_force(phi, r, L, a, nu, zeta, x_eq):
    """The seat's push on the foot per unit mass (mm/rad^2), foot riding on the seat.
    >= 0: contact holds; < 0: the seat accelerates away faster than the foot can follow."""
    y, d1, d2 = slider(phi, r, L, a)
    return nu * nu * (x_eq - y) - 2.0 * zeta * nu * d1 - d2


@nb.njit(cache=True)
def _loss_fn(phi, r, L, a, nu, zeta, x_eq, y_m):
    # < 0 once contact is lost: by the force, or by the seat passing the material level
    y = slider(phi, r, L, a)[0]
    f = contact_force(phi, r, L, a, nu, zeta, x_eq)
    return min(f, y_m - y)


@nb.njit(cache=True)
def _gap(phi, phi0, x0, v0, r, L, a, nu, zeta, x_eq, y_m):
    """Seat minus foot in flight (>= 0 while apart); and the foot minus the material level."""
    x = free(phi - phi0, x0, v0, nu, zeta, x_eq)[0]
    return slider(phi, r, L, a)[0] - x, y_m - x


@nb.njit(cache=True)
def _bisect_loss(lo, hi, r, L, a, nu, zeta, x_eq, y_m):
    # _loss_fn(lo) >= 0 > _loss_fn(hi)
    while hi - lo > ROOT_TOL_RAD:
        mid = 0.5 * (lo + hi)
        if _loss_fn(mid, r, L, a, nu, zeta, x_eq, y_m) >= 0.0:
            lo = mid
        else:
            hi = mid
    return hi


@nb.njit(cache=True)
def _bisect_flight(lo, hi, which, phi0, x0, v0, r, L, a, nu, zeta, x_eq, y_m):
    # the gap (which = 0) or the material clearance (which = 1) is > 0 at lo, <= 0 at hi
    while hi - lo > ROOT_TOL_RAD:
        mid = 0.5 * (lo + hi)
        g = _gap(mid, phi0, x0, v0, r, L, a, nu, zeta, x_eq, y_m)
        if g[which] > 0.0:
            lo = mid
        else:
            hi = mid
    return hi


@nb.njit(cache=True)
def _max_gap(lo, hi, phi0, x0, v0, r, L, a, nu, zeta, x_eq, y_m):
    # golden section for the largest gap in [lo, hi] (bracketing a sampled maximum)
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c = hi - g * (hi - lo)
    d = lo + g * (hi - lo)
    while hi - lo > 1e-10:
        if _gap(c, phi0, x0, v0, r, L, a, nu, zeta, x_eq, y_m)[0] > \
                _gap(d, phi0, x0, v0, r, L, a, nu, zeta, x_eq, y_m)[0]:
            hi = d
        else:
            lo = c
        c = hi - g * (hi - lo)
        d = lo + g * (hi - lo)
    return _gap(0.5 * (lo + hi), phi0, x0, v0, r, L, a, nu, zeta, x_eq, y_m)[0]


@nb.njit(cache=True)
def _max_seat(lo, hi, r, L, a):
    # golden section for the seat's largest y in [lo, hi] (bracketing a sampled maximum)
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c = hi - g * (hi - lo)
    d = lo + g * (hi - lo)
    while hi - lo > 1e-10:
        if slider(c, r, L, a)[0] > slider(d, r, L, a)[0]:
            hi = d
        else:
            lo = c
        c = hi - g * (hi - lo)
        d = lo + g * (hi - lo)
    return slider(0.5 * (lo + hi), r, L, a)[0]


@nb.njit(cache=True)
def _interval(start, stop, h, r, L, a, nu, zeta, x_eq, y_m):
    """The first lost interval after `start` (the foot riding on the seat there), if contact
    is lost before `stop`: (phi_loss, phi_regain, separation_mm, impacts, landed, status,
    lost_by_force), angles in radians, unwrapped. The interval runs to the re-contact after
    which contact holds (a re-contact with a negative push is a bounce: counted in `impacts`,
    the flight goes on)."""
    nan = np.nan
    phi_l = -1.0
    prev = start
    p = start
    while p < stop:
        p = min(p + h, stop)
        if _loss_fn(p, r, L, a, nu, zeta, x_eq, y_m) < 0.0:
            phi_l = _bisect_loss(prev, p, r, L, a, nu, zeta, x_eq, y_m)
            break
        prev = p
    if phi_l < 0.0:
        return nan, nan, 0.0, 0, 0, NO_LOSS, 0
    y, d1, _ = slider(phi_l, r, L, a)
    by_force = 1 if contact_force(phi_l, r, L, a, nu, zeta, x_eq) < 0.0 else 0
    landed = 0
    impacts = 0
    sep = 0.0
    # flight state: starts at phi_s with foot at (x0, v0)
    phi_s, x0, v0 = phi_l, y, d1
    on_material = False
    if y_m - y <= 0.0 and contact_force(phi_l, r, L, a, nu, zeta, x_eq) >= 0.0:
        # the seat passed the material level: the sole stops there (plastic) and stays if its
        # spring and weight press it on; otherwise it is pulled back up from rest
        if nu * nu * (x_eq - y_m) >= 0.0:
            on_material = True
        else:
            phi_s, x0, v0 = phi_l, y_m, 0.0
    p = phi_l
    end = phi_l + MAX_TURNS * 2.0 * math.pi
    while p < end:
        if on_material:
            # resting at y_m (pressed by its spring) until the seat comes back to it
            landed = 1
            q_prev = p
            found = False
            p_max = -1.0
            g_best = -np.inf
            while p < end:
                p += h
                gm = slider(p, r, L, a)[0] - y_m
                if gm > g_best:
                    g_best = gm
                    p_max = p
                if gm <= 0.0:
                    lo, hi = q_prev, p
                    while hi - lo > ROOT_TOL_RAD:
                        mid = 0.5 * (lo + hi)
                        if slider(mid, r, L, a)[0] - y_m > 0.0:
                            lo = mid
                        else:
                            hi = mid
                    p = hi
                    found = True
                    break
                q_prev = p
            if not found:
                break
            if p_max > 0.0:
                sep = max(sep, _max_seat(p_max - h, p_max + h, r, L, a) - y_m)
            # pick-up by the seat: the foot takes the seat's speed
            if contact_force(p, r, L, a, nu, zeta, x_eq) >= 0.0:
                return phi_l, p, sep, impacts, landed, OK, by_force
            impacts += 1
            y, d1, _ = slider(p, r, L, a)
            phi_s, x0, v0 = p, y, d1
            on_material = False
            continue
        # flight: sample the gap and the material clearance
        q_prev = p
        i_max = -1.0
        g_max = -np.inf
        event = -1
        while p < end:
            p += h
            g, cm = _gap(p, phi_s, x0, v0, r, L, a, nu, zeta, x_eq, y_m)
            if cm <= 0.0:
                event = 1
                break
            if g <= 0.0:
                event = 0
                break
            if g > g_max:
                g_max = g
                i_max = p
            q_prev = p
        if event < 0:
            break
        if i_max > 0.0:
            lo = max(i_max - h, phi_s)
            hi = min(i_max + h, p)
            sep = max(sep, _max_gap(lo, hi, phi_s, x0, v0, r, L, a, nu, zeta, x_eq, y_m))
        p = _bisect_flight(q_prev, p, event, phi_s, x0, v0, r, L, a, nu, zeta, x_eq, y_m)
        if event == 1:
            # the sole meets the material: a plastic stop
            if nu * nu * (x_eq - y_m) >= 0.0:
                on_material = True
                continue
            phi_s, x0, v0 = p, y_m, 0.0  # pulled back at once: a new flight from rest
            continue
        # re-contact with the seat: plastic impact, the foot takes the seat's speed
        if contact_force(p, r, L, a, nu, zeta, x_eq) >= 0.0 and \
                slider(p, r, L, a)[0] < y_m:
            return phi_l, p, sep, impacts, landed, OK, by_force
        impacts += 1
        y, d1, _ = slider(p, r, L, a)
        phi_s, x0, v0 = p, y, d1
    return phi_l, nan, sep, impacts, landed, NOT_REGAINED, by_force


@nb.njit(cache=True)
def one_machine(r, L, a, nu, zeta, x_eq, y_m):
    """(loss_deg, regain_deg, lost_deg, separation_mm, impacts, landed, status, lost_by_force,
    intervals) of one machine; angles are crank angles phi (from the y axis), mod 360.

    The foot starts riding on the seat where its push is largest (phi0) and is followed
    interval by interval over one turn. A turn can hold several lost intervals (e.g. a hop on
    the way up and the stop on the material); the one reported is the interval with the largest
    separation, `intervals` counts them all, `impacts` counts the bounces of all."""
    nan = np.nan
    if not (r > 0.0 and L > r):
        return nan, nan, nan, nan, 0, 0, CANNOT_ASSEMBLE, 0, 0
    n = int(math.ceil(2.0 * math.pi / STEP_RAD))
    h = 2.0 * math.pi / n
    best = -np.inf
    phi0 = 0.0
    for i in range(n):
        f = _loss_fn(i * h, r, L, a, nu, zeta, x_eq, y_m)
        if f > best:
            best = f
            phi0 = i * h
    if best < 0.0:
        return nan, nan, nan, nan, 0, 0, NO_CONTACT, 0, 0
    stop = phi0 + 2.0 * math.pi
    start = phi0
    count = 0
    impacts = 0
    res_l, res_r, res_sep, res_land, res_force = nan, nan, -1.0, 0, 0
    while start < stop:
        lo, re, sep, imp, land, st, bf = _interval(start, stop, h, r, L, a, nu, zeta, x_eq,
                                                   y_m)
        if st == NO_LOSS:
            break
        count += 1
        impacts += imp
        if st == NOT_REGAINED:
            return math.degrees(lo) % 360.0, nan, nan, sep, impacts, land, NOT_REGAINED, bf, \
                count
        if sep > res_sep:
            res_l, res_r, res_sep, res_land, res_force = lo, re, sep, land, bf
        start = re
    if count == 0:
        return nan, nan, nan, nan, 0, 0, NO_LOSS, 0, 0
    return (math.degrees(res_l) % 360.0, math.degrees(res_r) % 360.0,
            math.degrees(res_r - res_l), res_sep, impacts, res_land, OK, res_force, count)


@nb.njit(cache=True)
def batch(r, L, a, nu, zeta, x_eq, y_m):
    """one_machine over equal-length 1-D arrays; returns (m, 9) floats (COLUMNS order)."""
    m = r.shape[0]
    out = np.empty((m, 9))
    for i in range(m):
        lo, re, lost, sep, imp, land, st, bf, cnt = one_machine(r[i], L[i], a[i], nu[i], zeta[i],
                                                       x_eq[i], y_m[i])
        out[i, 0] = lo
        out[i, 1] = re
        out[i, 2] = lost
        out[i, 3] = sep
        out[i, 4] = imp
        out[i, 5] = land
        out[i, 6] = st
        out[i, 7] = bf
        out[i, 8] = cnt
    return out
