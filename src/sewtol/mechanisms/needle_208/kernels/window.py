"""Exact per-machine optimum of beta (and the guide shift) as a sliding-window problem.

Structure: B = A + AB e(theta + s beta) with the rocker angle theta swinging
over [lo, hi] independently of beta (mechanisms/needle_208.rocker_interval). With
psi = theta + s beta the needle point E(psi) and d(psi) = n.(E(psi) - G) are ONE function of psi
per machine, and beta only slides the window W(u) = [u, u + w], u = lo + s beta, w = hi - lo,
along it. With F(u) = max_W d, G(u) = min_W d and the guide shift t (mm) in [T0, T1]

    SumDelta(u) = min_t max(0, F - t) + max(0, t - G) = max(F - G, F - T1, T0 - G)

(T0 = T1 = the machine's own shift when the shift is not a compensator).

Algorithm, per machine:
1. The feasible windows in closed form: dyad B-C-D closes with a transmission angle >= 1 deg
   exactly where |D - B|(psi) lies in an interval, i.e. cos(psi - ang(A->D)) lies in an
   interval: up to two arcs of psi. A window is feasible iff it lies inside one arc (the
   feasibility semantics of needle_208.metrics.feasibility).
2. d, d', d'' (analytic) at nodes of spacing h = w / m (m = ceil(w / h_target)), aligned so that
   both window ends of every grid window fall on nodes; d is replaced by its cubic Hermite
   interpolant p, whose error is |d''''| h^4 / 384 (estimated per cell from the jump between
   p'' and the exact d'' at the nodes: err = h^2 |p'' - d''| / 32; h is halved until the
   estimate is below 1e-3 um). With the measured |d''''| <= ~120 mm/rad^4 (recommended and base
   sets) and h = 2 deg that is ~4e-4 um (3e-5 um at 1 deg).
3. Every cell's exact extremes (nodes and the roots of p'), hence F and G at any u in O(1) from
   the cells inside the window and the two partial end cells. SumDelta at every grid u.
4. A lower bound per u-cell from the cells inside every window of that cell; cells whose bound
   is not below the best grid value cannot hold the optimum. In the others SumDelta is sampled
   at spacing delta with K delta^2 / 8 <= 2e-3 um, where K = max|p''| at both window ends bounds
   the concavity of every piece of SumDelta (an upper envelope of A - B, A - c, c - B, ... with
   A, B the cubics at the window ends), and each sampled descent is polished by golden section.
5. The plateau: the connected range of u around the optimum where SumDelta <= min + tol; beta*
   is its centre. The shift's range at beta* is [max(G, T0), min(F, T1)] (its centre is used).
tests/test_adjust.py holds it to a dense brute-force search and to the numpy reference.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sewtol.mechanisms.needle_208.kernels.fused import guide_normal, guide_offset_on, needle_point

_INVPHI = (math.sqrt(5.0) - 1.0) / 2.0
DEAD_POINT_DEG = 1.0  # mechanisms.needle_208.DEAD_POINT_DEG (kept equal by a test)
# output columns of optimise_batch
COLUMNS = ("beta_deg", "total_um", "plus_um", "minus_um", "beta_low_deg", "beta_high_deg",
           "shift_um", "shift_low_um", "shift_high_um", "status", "surrogate_err_um",
           "min_total_um")
STATUS = ("ok", "cannot assemble", "dead point")
SURROGATE_TOL_MM = 1e-6   # 1e-3 um: the Hermite interpolant's estimated error
SAMPLE_TOL_MM = 2e-6      # 2e-3 um: K delta^2 / 8 for the sampling inside a candidate u-cell


@nb.njit(cache=True)
def _wrap(x):
    """x into (-pi, pi]."""
    return math.atan2(math.sin(x), math.cos(x))


@nb.njit(cache=True)
def _arc_limits(p, gamma_min_deg):
    """(a1, a2): B-C-D closes with transmission >= gamma_min iff a1 <= |wrap(psi - g)| <= a2,
    g = ang(A->D); returns a1 > a2 when no psi qualifies."""
    AB, BC, CD = p[0], p[1], p[3]
    vx, vy = p[7] - p[5], p[8] - p[6]
    AD = math.sqrt(vx * vx + vy * vy)
    cg = math.cos(gamma_min_deg * math.pi / 180.0)
    dlo2 = BC * BC + CD * CD - 2.0 * BC * CD * cg
    dhi2 = BC * BC + CD * CD + 2.0 * BC * CD * cg
    # |D-B|^2 = AD^2 + AB^2 - 2 AB AD cos(psi - g)
    ca = (AD * AD + AB * AB - dhi2) / (2.0 * AB * AD)
    cb = (AD * AD + AB * AB - dlo2) / (2.0 * AB * AD)
    if ca > 1.0 or cb < -1.0 or ca > cb:
        return 1.0, 0.0
    a1 = math.acos(min(cb, 1.0))
    a2 = math.acos(max(ca, -1.0))
    return a1, a2


@nb.njit(cache=True)
def feasible_segments(p, P0, P1, gamma_min_deg, seg):
    """Feasible sub-intervals of [P0, P1] (rows of seg); returns their count."""
    a1, a2 = _arc_limits(p, gamma_min_deg)
    if a1 > a2:
        return 0
    g = math.atan2(p[8] - p[6], p[7] - p[5])
    bps = np.empty(20)
    nb_ = 0
    bps[nb_] = P0
    nb_ += 1
    bps[nb_] = P1
    nb_ += 1
    for tgt in (a1, -a1, a2, -a2):
        base = g + tgt
        k0 = int(math.floor((P0 - base) / (2.0 * math.pi)))
        for kk in range(k0, k0 + 3):
            x = base + 2.0 * math.pi * kk
            if P0 < x < P1 and nb_ < 20:
                bps[nb_] = x
                nb_ += 1
    b = np.sort(bps[:nb_])
    n = 0
    for i in range(nb_ - 1):
        if b[i + 1] <= b[i]:
            continue
        mid = 0.5 * (b[i] + b[i + 1])
        dl = abs(_wrap(mid - g))
        if a1 <= dl <= a2:
            if n > 0 and seg[n - 1, 1] >= b[i]:
                seg[n - 1, 1] = b[i + 1]
            else:
                seg[n, 0] = b[i]
                seg[n, 1] = b[i + 1]
                n += 1
    return n


@nb.njit(cache=True)
def _cubic(c, j, x):
    return c[j, 0] + x * (c[j, 1] + x * (c[j, 2] + x * c[j, 3]))


# inlined by numba itself: as a called function returning a tuple, `needle strategies --n 1000`
# took 1.35-1.45 times the CPU of the two loops written out (same bits either way)
@nb.njit(cache=True, inline="always")
def _extremes(c, crit, ncrit, imax, imin, m, k, ta, tb):
    """(F, G): the largest and least d over cell k from tb on, the cells between whole
    (imax, imin) and cell k + m up to ta; with ta = tb = tau, those of the window starting at
    node k + tau."""
    A = _cubic(c, k, tb)
    B = _cubic(c, k + m, ta)
    F = max(imax[k], A, B)
    G = min(imin[k], A, B)
    for r in range(ncrit[k]):
        if crit[k, r, 0] > tb:
            v = crit[k, r, 1]
            F = max(F, v)
            G = min(G, v)
    j = k + m
    for r in range(ncrit[j]):
        if crit[j, r, 0] < ta:
            v = crit[j, r, 1]
            F = max(F, v)
            G = min(G, v)
    return F, G


@nb.njit(cache=True)
def _s_at(c, crit, ncrit, imax, imin, m, k, tau, T0, T1, out3):
    """SumDelta (mm), F, G for the window starting at node k + tau."""
    F, G = _extremes(c, crit, ncrit, imax, imin, m, k, tau, tau)
    out3[1] = F
    out3[2] = G
    s = max(F - G, max(F - T1, T0 - G))
    out3[0] = s
    return s


@nb.njit(cache=True)
def _s_lb(c, crit, ncrit, imax, imin, m, k, ta, tb, T0, T1):
    """A lower bound (mm) of _s_at over the window starts k + tau, tau in [ta, tb]: every such
    window covers cell k from tb on and cell k + m up to ta, so its F is at least the extremes
    there and its G at most (the same comparisons as _s_at), less 1e-12 mm for the rounding of
    a cubic's value at a computed root (~1e-17 mm)."""
    F, G = _extremes(c, crit, ncrit, imax, imin, m, k, ta, tb)
    return max(F - G, max(F - T1, T0 - G)) - 1e-12


@nb.njit(cache=True)
def _descent(sv, i, q):
    """Sample i of sv[0 .. q] is a local minimum, strict on one side at least."""
    left = sv[i - 1] if i > 0 else np.inf
    right = sv[i + 1] if i < q else np.inf
    return sv[i] <= left and sv[i] <= right and (sv[i] < left or sv[i] < right)


@nb.njit(cache=True)
def _locate(u, ua, h, K, tlast):
    k = int(math.floor((u - ua) / h))
    if k < 0:
        k = 0
    if k > K - 1:
        k = K - 1
    tau = u - ua - k * h
    lim = h if k < K - 1 else tlast
    if tau < 0.0:
        tau = 0.0
    if tau > lim:
        tau = lim
    return k, tau


@nb.njit(cache=True)
def _grid(ua, ub, w, h_target):
    """The node grid of [ua, ub + w]: (m, h, K, tlast, nn); every window end on a node."""
    m = max(1, int(math.ceil(w / h_target - 1e-9)))
    h = w / m
    R = ub - ua
    K = max(1, int(math.ceil(R / h - 1e-9)))
    tlast = R - (K - 1) * h
    if tlast < 0.0:
        tlast = 0.0
    return m, h, K, tlast, K + m + 1


@nb.njit(cache=True)
def _nodes(ua, ub, w, h, nn):
    x = np.empty(nn)
    for j in range(nn - 1):
        x[j] = ua + j * h
    x[nn - 1] = ub + w
    return x


@nb.njit(cache=True)
def _solve_interval(p, ua, ub, w, h_target, T0, T1, tol_mm, res, plateau=True):
    """Minimise SumDelta over u in [ua, ub] (every window feasible). res receives
    (S*, u_centre, F, G at the centre, range_lo, range_hi, S at the centre, err estimate);
    plateau=False: only S* and the error estimate (res[0], res[7])."""
    m, h, K, tlast, nn = _grid(ua, ub, w, h_target)
    x = _nodes(ua, ub, w, h, nn)
    f = np.empty(nn)
    f1 = np.empty(nn)
    f2 = np.empty(nn)
    shift = p[14] * 1e-3
    nx, ny, off = guide_normal(p)  # guide_offset's, once for every node
    for j in range(nn):
        Ex, Ey, E1x, E1y, E2x, E2y = needle_point(p, 0.0, x[j])
        if math.isnan(Ex):
            return False
        f[j] = nx * Ex + ny * Ey - off + shift  # d without the machine's own guide shift
        f1[j] = nx * E1x + ny * E1y
        f2[j] = nx * E2x + ny * E2y
    return _solve_nodes(x, f, f1, f2, ua, ub, m, h, K, tlast, T0, T1, tol_mm, res, plateau,
                        _work(nn))


@nb.njit(cache=True)
def _inner_extremes(f, cmax, cmin, m, K, imax, imin, pmax, pmin, smax, smin):
    """imax[k], imin[k]: the extremes of nodes k+1, k+m and cells k+1 .. k+m-1 (every window
    starting in u-cell k covers them), for k < K: a sliding maximum over blocks of m-1 cells
    (van Herk / Gil-Werman), O(K + m) instead of O(K m); max and min are exact, so the values
    are those of the direct loop."""
    L = m - 1
    for k in range(K):
        imax[k] = max(f[k + 1], f[k + m])
        imin[k] = min(f[k + 1], f[k + m])
    if L < 1:
        return
    N = K + L - 1  # cells 1 .. K + m - 2 (the buffers hold at least N)
    for t in range(N):
        if t % L == 0:
            pmax[t] = cmax[t + 1]
            pmin[t] = cmin[t + 1]
        else:
            pmax[t] = max(pmax[t - 1], cmax[t + 1])
            pmin[t] = min(pmin[t - 1], cmin[t + 1])
    for t in range(N - 1, -1, -1):
        if t % L == L - 1 or t == N - 1:
            smax[t] = cmax[t + 1]
            smin[t] = cmin[t + 1]
        else:
            smax[t] = max(smax[t + 1], cmax[t + 1])
            smin[t] = min(smin[t + 1], cmin[t + 1])
    for k in range(K):
        imax[k] = max(imax[k], max(smax[k], pmax[k + L - 1]))
        imin[k] = min(imin[k], min(smin[k], pmin[k + L - 1]))


@nb.njit(cache=True)
def _work(cap):
    """Scratch arrays of _solve_nodes for up to cap nodes, allocated once and reused by every
    solve of a machine (the outer search makes ~60 per setting of CD)."""
    return (np.empty((cap, 4)), np.empty((cap, 2, 2)), np.empty(cap, np.int64), np.empty(cap),
            np.empty(cap), np.empty(cap), np.empty(cap), np.empty(cap), np.empty(cap),
            np.empty(cap), np.empty(cap), np.empty(cap), np.empty(65), np.empty(3))


@nb.njit(cache=True)
def _solve_nodes(x, f, f1, f2, ua, ub, m, h, K, tlast, T0, T1, tol_mm, res, plateau, ws):
    """_solve_interval on given node values of d, d', d'' (the guide shift removed), with its
    scratch arrays (_work(cap), cap >= the nodes)."""
    nn = x.size
    nc = nn - 1
    c = ws[0][:nc]
    crit = ws[1][:nc]
    ncrit = ws[2][:nc]
    cmax = ws[3][:nc]
    cmin = ws[4][:nc]
    ddmax = ws[5][:nc]  # max |p''| on the cell
    err = 0.0
    for j in range(nc):
        L = x[j + 1] - x[j]
        c[j, 0] = f[j]
        c[j, 1] = f1[j]
        if L > 1e-14:
            dl = (f[j + 1] - f[j]) / L
            c[j, 2] = (3.0 * dl - 2.0 * f1[j] - f1[j + 1]) / L
            c[j, 3] = (f1[j] + f1[j + 1] - 2.0 * dl) / (L * L)
        else:
            c[j, 2] = 0.0
            c[j, 3] = 0.0
        pa = 2.0 * c[j, 2]
        pb = 2.0 * c[j, 2] + 6.0 * c[j, 3] * L
        ddmax[j] = max(abs(pa), abs(pb))
        e = L * L / 32.0 * max(abs(pa - f2[j]), abs(pb - f2[j + 1]))
        if L > 1e-14 and e > err:
            err = e
        hi_ = max(f[j], f[j + 1])
        lo_ = min(f[j], f[j + 1])
        # roots of p' = c1 + 2 c2 x + 3 c3 x^2 inside (0, L)
        qa, qb, qc = 3.0 * c[j, 3], 2.0 * c[j, 2], c[j, 1]
        nr = 0
        roots = (np.nan, np.nan)
        if abs(qa) > 1e-300:
            disc = qb * qb - 4.0 * qa * qc
            if disc >= 0.0:
                sq = math.sqrt(disc)
                qq = -0.5 * (qb + (sq if qb >= 0 else -sq))
                r1 = qq / qa
                r2 = qc / qq if qq != 0.0 else r1
                roots = (r1, r2)
        elif abs(qb) > 1e-300:
            roots = (-qc / qb, np.nan)
        for r in roots:
            if r == r and 0.0 < r < L:
                v = _cubic(c, j, r)
                crit[j, nr, 0] = r
                crit[j, nr, 1] = v
                nr += 1
                hi_ = max(hi_, v)
                lo_ = min(lo_, v)
        ncrit[j] = nr
        cmax[j] = hi_
        cmin[j] = lo_
    res[7] = err
    # cells and nodes inside every window of u-cell k: nodes k+1..k+m, cells k+1..k+m-1
    imax = ws[6][:K]
    imin = ws[7][:K]
    _inner_extremes(f, cmax, cmin, m, K, imax, imin, ws[8], ws[9], ws[10], ws[11])
    out3 = ws[13]
    best = np.inf
    bk = 0
    bt = 0.0
    for k in range(K):
        s = _s_at(c, crit, ncrit, imax, imin, m, k, 0.0, T0, T1, out3)
        if s < best:
            best, bk, bt = s, k, 0.0
    s = _s_at(c, crit, ncrit, imax, imin, m, K - 1, tlast, T0, T1, out3)
    if s < best:
        best, bk, bt = s, K - 1, tlast
    sv = ws[12]
    for k in range(K):
        lb = max(imax[k] - imin[k], max(imax[k] - T1, T0 - imin[k]))
        if lb >= best:
            continue
        Lu = h if k < K - 1 else tlast
        if Lu <= 0.0:
            continue
        kc = ddmax[k] + ddmax[k + m]
        q = int(math.ceil(Lu * math.sqrt(kc / (8.0 * SAMPLE_TOL_MM))))
        q = min(max(q, 2), 64)
        dt = Lu / q
        for i in range(q + 1):
            sv[i] = _s_at(c, crit, ncrit, imax, imin, m, k, i * dt, T0, T1, out3)
        least = np.inf  # the least descent of the cell: every one below updates best to it
        for i in range(q + 1):
            if _descent(sv, i, q):
                least = min(least, sv[i])
        for i in range(q + 1):
            if not _descent(sv, i, q):
                continue
            if sv[i] < best:
                best, bk, bt = sv[i], k, i * dt
            a = max(i - 1, 0) * dt
            b = min(i + 1, q) * dt
            # a polish that can reach neither below the best so far nor down to the cell's
            # least descent changes neither the minimum nor where it is first found: skipped
            lb = _s_lb(c, crit, ncrit, imax, imin, m, k, a, b, T0, T1)
            if lb >= best or lb > least:
                continue
            cg = b - _INVPHI * (b - a)
            dg = a + _INVPHI * (b - a)
            fc = _s_at(c, crit, ncrit, imax, imin, m, k, cg, T0, T1, out3)
            fd = _s_at(c, crit, ncrit, imax, imin, m, k, dg, T0, T1, out3)
            while b - a > 1e-10:
                if fc < fd:
                    b, dg, fd = dg, cg, fc
                    cg = b - _INVPHI * (b - a)
                    fc = _s_at(c, crit, ncrit, imax, imin, m, k, cg, T0, T1, out3)
                else:
                    a, cg, fc = cg, dg, fd
                    dg = a + _INVPHI * (b - a)
                    fd = _s_at(c, crit, ncrit, imax, imin, m, k, dg, T0, T1, out3)
            if fc < best:
                best, bk, bt = fc, k, cg
            if fd < best:
                best, bk, bt = fd, k, dg
    res[0] = best
    if not plateau:
        return True
    # the plateau: connected range around the optimum where SumDelta <= best + tol
    ustar = ua + bk * h + bt
    level = best + tol_mm
    step = h / 8.0
    lims = np.empty(2)
    for side in range(2):
        sg = -1.0 if side == 0 else 1.0
        edge = ua if side == 0 else ub
        u = ustar
        lim = edge
        while (u - edge) * sg < 0.0:
            un = u + sg * step
            if (un - edge) * sg > 0.0:
                un = edge
            kk, tt = _locate(un, ua, h, K, tlast)
            if _s_at(c, crit, ncrit, imax, imin, m, kk, tt, T0, T1, out3) > level:
                inner, outer = u, un
                for _ in range(50):
                    mid = 0.5 * (inner + outer)
                    kk, tt = _locate(mid, ua, h, K, tlast)
                    if _s_at(c, crit, ncrit, imax, imin, m, kk, tt, T0, T1, out3) > level:
                        outer = mid
                    else:
                        inner = mid
                lim = inner
                break
            u = un
        lims[side] = lim
    uc = 0.5 * (lims[0] + lims[1])
    kk, tt = _locate(uc, ua, h, K, tlast)
    sc = _s_at(c, crit, ncrit, imax, imin, m, kk, tt, T0, T1, out3)
    res[0] = best
    res[1] = uc
    res[2] = out3[1]
    res[3] = out3[2]
    res[4] = lims[0]
    res[5] = lims[1]
    res[6] = sc
    return True


@nb.njit(cache=True)
def _optimise_one(p, lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, out):
    for i in range(out.size):
        out[i] = np.nan
    if math.isnan(lo) or math.isnan(hi):
        out[9] = 1.0
        return
    s = p[10]
    deg = math.pi / 180.0
    geo = np.empty((12, 2))
    n, w = _segments(p, lo, hi, blo, bhi, geo)
    res = np.empty(8)
    best = np.empty(8)
    best[0] = np.inf
    found = False
    for i in range(n):
        ua, ub = geo[i, 0], geo[i, 1]
        ht = h_deg * deg
        ok = False
        for _ in range(4):
            ok = _solve_interval(p, ua, ub, w, ht, T0, T1, tol_mm, res)
            if not ok or res[7] <= SURROGATE_TOL_MM:
                break
            ht *= 0.5
        if ok and res[0] < best[0]:
            best[:] = res
            found = True
    if not found:
        # no feasible window: does B-C-D fail to close everywhere, or only pass a dead point?
        closes = False
        seg2 = np.empty((12, 2))
        u0 = lo + min(s * blo, s * bhi) * deg
        u1 = lo + max(s * blo, s * bhi) * deg
        n_closed = feasible_segments(p, u0, u1 + w, 0.0, seg2)
        for i in range(n_closed):
            if seg2[i, 1] - seg2[i, 0] >= w:
                closes = True
        out[9] = 2.0 if closes else 1.0
        return
    F, G = best[2], best[3]
    tl = max(G, T0)
    th = min(F, T1)
    if tl > th:  # the band lies outside the shift's box: the nearer limit
        tl = th = (T1 if G > T1 else T0)
    t = 0.5 * (tl + th)
    b_c = (best[1] - lo) / (s * deg)
    b_a = (best[4] - lo) / (s * deg)
    b_b = (best[5] - lo) / (s * deg)
    out[0] = b_c
    out[2] = max(F - t, 0.0) * 1e3
    out[3] = max(t - G, 0.0) * 1e3
    out[1] = out[2] + out[3]
    out[4] = min(b_a, b_b)
    out[5] = max(b_a, b_b)
    out[6] = t * 1e3
    out[7] = tl * 1e3
    out[8] = th * 1e3
    out[9] = 0.0
    out[10] = best[7] * 1e3
    out[11] = best[0] * 1e3


@nb.njit(cache=True, parallel=True)
def optimise_batch(P, lo, hi, blo, bhi, shift_lo_um, shift_hi_um, shift_active, h_deg=2.0,
                   tol_um=1e-3):
    """Per machine (rows of P follow needle_numba.FIELDS; lo, hi the rocker interval in rad,
    NaN where L-M-A fails): the columns of COLUMNS. With shift_active False the guide shift is
    the machine's own (P[:, 14]), else free in [shift_lo_um, shift_hi_um]."""
    n = P.shape[0]
    out = np.empty((n, len(COLUMNS)))
    for i in nb.prange(n):
        if shift_active:
            T0, T1 = shift_lo_um * 1e-3, shift_hi_um * 1e-3
        else:
            T0 = T1 = P[i, 14] * 1e-3
        _optimise_one(P[i], lo[i], hi[i], blo, bhi, T0, T1, h_deg, tol_um * 1e-3, out[i])
    return out


@nb.njit(cache=True)
def _fixed_one(p, beta, lo, hi, h_target):
    """(max d, min d) in mm over the window of a fixed beta: the Hermite surrogate on nodes
    <= h_target apart locates every extremum, and each candidate whose surrogate value is within
    1e-5 mm of the best (10x the surrogate's error bound) is polished by Newton on the exact d
    inside its cell, so the figures are exact, not the surrogate's."""
    nx, ny, off = guide_normal(p)
    u = lo + p[10] * beta * math.pi / 180.0
    w = hi - lo
    m = max(2, int(math.ceil(w / h_target - 1e-9)))
    h = w / m
    f = np.empty(m + 1)
    f1 = np.empty(m + 1)
    for j in range(m + 1):
        a, b, _ = guide_offset_on(p, 0.0, u + j * h, nx, ny, off)
        if math.isnan(a):
            return np.nan, np.nan
        f[j] = a
        f1[j] = b
    # candidates: (location, surrogate value, cell) for interior roots of p'
    cx = np.empty(2 * m)
    cv = np.empty(2 * m)
    cj = np.empty(2 * m, np.int64)
    nc = 0
    fmax = -np.inf
    fmin = np.inf
    for j in range(m + 1):
        fmax = max(fmax, f[j])
        fmin = min(fmin, f[j])
    for j in range(m):
        dl = (f[j + 1] - f[j]) / h
        c2 = (3.0 * dl - 2.0 * f1[j] - f1[j + 1]) / h
        c3 = (f1[j] + f1[j + 1] - 2.0 * dl) / (h * h)
        qa, qb, qc = 3.0 * c3, 2.0 * c2, f1[j]
        r1 = np.nan
        r2 = np.nan
        if abs(qa) > 1e-300:
            disc = qb * qb - 4.0 * qa * qc
            if disc >= 0.0:
                sq = math.sqrt(disc)
                qq = -0.5 * (qb + (sq if qb >= 0 else -sq))
                r1 = qq / qa
                r2 = qc / qq if qq != 0.0 else r1
        elif abs(qb) > 1e-300:
            r1 = -qc / qb
        for r in (r1, r2):
            if r == r and 0.0 < r < h:
                cx[nc] = r
                cv[nc] = f[j] + r * (f1[j] + r * (c2 + r * c3))
                cj[nc] = j
                nc += 1
    smax = fmax
    smin = fmin
    for k in range(nc):
        smax = max(smax, cv[k])
        smin = min(smin, cv[k])
    for k in range(nc):
        near_max = cv[k] >= smax - 1e-5
        near_min = cv[k] <= smin + 1e-5
        if not (near_max or near_min):
            continue
        a0 = u + cj[k] * h
        b0 = a0 + h
        t = u + cj[k] * h + cx[k]
        for _ in range(6):
            _, d1, d2 = guide_offset_on(p, 0.0, t, nx, ny, off)
            if d2 == 0.0 or math.isnan(d2):
                break
            tn = t - d1 / d2
            tn = min(max(tn, a0), b0)
            if abs(tn - t) < 1e-13:
                t = tn
                break
            t = tn
        v, _, _ = guide_offset_on(p, 0.0, t, nx, ny, off)
        if near_max:
            fmax = max(fmax, v)
        if near_min:
            fmin = min(fmin, v)
    return fmax, fmin


@nb.njit(cache=True, parallel=True)
def fixed_batch(P, beta, lo, hi, h_deg=2.0):
    """Delta+, Delta- (um) per machine at its own beta (lo, hi NaN where it cannot run)."""
    n = P.shape[0]
    out = np.empty((n, 2))
    for i in nb.prange(n):
        if math.isnan(lo[i]) or math.isnan(hi[i]):
            out[i, 0] = out[i, 1] = np.nan
            continue
        fmax, fmin = _fixed_one(P[i], beta[i], lo[i], hi[i], h_deg * math.pi / 180.0)
        if math.isnan(fmax):
            out[i, 0] = out[i, 1] = np.nan
            continue
        out[i, 0] = max(fmax, 0.0) * 1e3
        out[i, 1] = max(-fmin, 0.0) * 1e3
    return out


# --- the outer search over the guide angle or CD, fused: one call for every machine ----------
#
# needle_208.adjust's outer search (a grid over the compensator's box, then golden section
# around each of the three best local minima of the grid, per machine) evaluated the exact inner
# minimum through optimise_batch once per trial value, for every machine, from Python. Here each
# machine runs its whole search in one thread, and a trial computes only the minimum (column
# min_total_um of optimise_batch, bit for bit the same operations) without its plateau. For the
# guide angle the needle point E and its derivatives at the nodes do not depend on the angle
# (only the normal they are projected on does), so they are computed once per machine and every
# trial angle projects them (needle_point/guide_normal: the same floating-point operations as
# guide_offset, so the same d).


@nb.njit(cache=True)
def _segments(p, lo, hi, blo, bhi, geo):
    """The ranges [ua, ub] of window starts inside the feasible arcs (rows of geo), a hair
    inside the arcs so no node sits exactly on the 1-deg limit; returns (count, window width
    w). _optimise_one and the outer searches solve on them."""
    s = p[10]
    deg = math.pi / 180.0
    u0 = lo + min(s * blo, s * bhi) * deg
    u1 = lo + max(s * blo, s * bhi) * deg
    w = hi - lo
    seg = np.empty((12, 2))
    n = feasible_segments(p, u0, u1 + w, DEAD_POINT_DEG, seg)
    k = 0
    for i in range(n):
        if seg[i, 1] - seg[i, 0] < w:
            continue
        ua = max(seg[i, 0] + 1e-10, u0)
        ub = min(seg[i, 1] - 1e-10 - w, u1)
        if ub < ua:
            continue
        geo[k, 0] = ua
        geo[k, 1] = ub
        k += 1
    return k, w


@nb.njit(cache=True)
def _halve(p, ua, ub, w, ht, T0, T1, tol_mm, res):
    """The rest of _optimise_one's refinement loop after a first solve whose surrogate error
    was too large: up to three more solves, each on nodes half as far apart."""
    ok = True
    for _ in range(3):
        ht *= 0.5
        ok = _solve_interval(p, ua, ub, w, ht, T0, T1, tol_mm, res, False)
        if not ok or res[7] <= SURROGATE_TOL_MM:
            break
    return ok


@nb.njit(cache=True)
def _minimum(p, geo, k, w, h_deg, T0, T1, tol_mm, res):
    """optimise_batch's min_total_um (um; NaN where no window runs) of machine p."""
    best = np.inf
    found = False
    ht0 = h_deg * (math.pi / 180.0)
    for i in range(k):
        ok = _solve_interval(p, geo[i, 0], geo[i, 1], w, ht0, T0, T1, tol_mm, res, False)
        if ok and res[7] > SURROGATE_TOL_MM:
            ok = _halve(p, geo[i, 0], geo[i, 1], w, ht0, T0, T1, tol_mm, res)
        if ok and res[0] < best:
            best = res[0]
            found = True
    return best * 1e3 if found else np.nan


@nb.njit(cache=True)
def _points(p, geo, k, w, h_deg, EN, XN, ok):
    """E, E', E'' at the first node grid of every segment (EN[i, j, :6]; XN[i, j] the node),
    ok[i]: every node of segment i runs."""
    ht0 = h_deg * (math.pi / 180.0)
    for i in range(k):
        m, h, K, tlast, nn = _grid(geo[i, 0], geo[i, 1], w, ht0)
        x = _nodes(geo[i, 0], geo[i, 1], w, h, nn)
        ok[i] = True
        for j in range(nn):
            XN[i, j] = x[j]
            e = needle_point(p, 0.0, x[j])
            for q in range(6):
                EN[i, j, q] = e[q]
            if math.isnan(e[0]):
                ok[i] = False
                break


@nb.njit(cache=True)
def _minimum_angle(p, geo, k, w, h_deg, T0, T1, tol_mm, res, EN, XN, ok, ws, fb):
    """_minimum of machine p (its guide angle p[13] set) from the needle points of _points;
    ws, fb: scratch arrays (_work(cap), (3, cap)) for up to cap nodes."""
    best = np.inf
    found = False
    ht0 = h_deg * (math.pi / 180.0)
    nx, ny, off = guide_normal(p)
    shift = p[14] * 1e-3
    for i in range(k):
        if not ok[i]:
            continue
        ua, ub = geo[i, 0], geo[i, 1]
        m, h, K, tlast, nn = _grid(ua, ub, w, ht0)
        f = fb[0, :nn]
        f1 = fb[1, :nn]
        f2 = fb[2, :nn]
        for j in range(nn):
            f[j] = nx * EN[i, j, 0] + ny * EN[i, j, 1] - off + shift
            f1[j] = nx * EN[i, j, 2] + ny * EN[i, j, 3]
            f2[j] = nx * EN[i, j, 4] + ny * EN[i, j, 5]
        good = _solve_nodes(XN[i, :nn], f, f1, f2, ua, ub, m, h, K, tlast, T0, T1, tol_mm, res,
                            False, ws)
        if good and res[7] > SURROGATE_TOL_MM:
            good = _halve(p, ua, ub, w, ht0, T0, T1, tol_mm, res)
        if good and res[0] < best:
            best = res[0]
            found = True
    return best * 1e3 if found else np.nan


@nb.njit(cache=True)
def _trial_min(p, col, own, rel, lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, res, geo, k, w,
               EN, XN, ok, ws, fb):
    q = p.copy()
    q[col] = own + rel
    if col == 13:
        return _minimum_angle(q, geo, k, w, h_deg, T0, T1, tol_mm, res, EN, XN, ok, ws, fb)
    k2, w2 = _segments(q, lo, hi, blo, bhi, geo)
    return _minimum(q, geo, k2, w2, h_deg, T0, T1, tol_mm, res)


@nb.njit(cache=True)
def _angle_bound(p, grid, vals, EN, geo, k, w, ok, h):
    """A lower bound (um) of the trial minimum over the guide angle's whole box from its values
    at the grid. Turning the guide by da (rad) about its point turns its normal n by da, so
    each d = n.(E - guide point) - shift moves by at most R da (R: the largest |E - guide
    point|) and F - G (max and min of d over a window) by at most D da (D: the largest
    |E - E'| between two needle points), so SumDelta = max(F - G, F - T1, T0 - G), and its
    minimum over beta and the shift (whose feasible windows no angle changes), by at most
    max(R, D) da. Between two grid points the minimum is then at least the mean of their
    values less that slope times half their gap, less 0.01 um for the surrogate's and the
    sampling's errors (SURROGATE_TOL_MM, SAMPLE_TOL_MM). R and D from the nodes (EN of
    _points, <= h rad apart) plus h (max |E'| + h max |E''|) for each point between them."""
    r = 0.0
    dd = 0.0
    d1 = 0.0
    d2 = 0.0
    for i in range(k):
        if not ok[i]:
            continue
        nn = _grid(geo[i, 0], geo[i, 1], w, h)[4]
        for j in range(nn):
            ex, ey = EN[i, j, 0], EN[i, j, 1]
            r = max(r, math.hypot(ex - p[11], ey - p[12]))
            d1 = max(d1, math.hypot(EN[i, j, 2], EN[i, j, 3]))
            d2 = max(d2, math.hypot(EN[i, j, 4], EN[i, j, 5]))
            for i2 in range(i, k):
                if not ok[i2]:
                    continue
                for j2 in range(j + 1 if i2 == i else 0, _grid(geo[i2, 0], geo[i2, 1], w, h)[4]):
                    dd = max(dd, math.hypot(EN[i2, j2, 0] - ex, EN[i2, j2, 1] - ey))
    gap = h * (d1 + h * d2)
    slope = max(r + gap, dd + 2.0 * gap) * (math.pi / 180.0) * 1e3
    lb = np.inf
    for g in range(grid.size - 1):
        lb = min(lb, 0.5 * (vals[g] + vals[g + 1] - slope * (grid[g + 1] - grid[g])))
    return lb - 0.01


@nb.njit(cache=True)
def _minima(vals):
    """Each value that is no greater than its neighbours (a local minimum of the grid), inf
    elsewhere."""
    G = vals.size
    score = np.empty(G)
    for g in range(G):
        left = vals[g - 1] if g > 0 else np.inf
        right = vals[g + 1] if g < G - 1 else np.inf
        score[g] = vals[g] if (vals[g] <= left and vals[g] <= right) else np.inf
    return score


@nb.njit(cache=True)
def _outer_one(p, col, lo, hi, blo, bhi, T0, T1, grid, h_deg, tol_mm, rounds, n_min, cutoff):
    G = grid.size
    own = p[col]
    res = np.empty(8)
    geo = np.empty((12, 2))
    k, w = 0, 0.0
    EN = np.empty((1, 1, 6))
    XN = np.empty((1, 1))
    ok = np.zeros(12, np.bool_)
    cap = 1
    if col == 13 and not (math.isnan(lo) or math.isnan(hi)):
        k, w = _segments(p, lo, hi, blo, bhi, geo)
        nmax = 1
        for i in range(k):
            nmax = max(nmax, _grid(geo[i, 0], geo[i, 1], w, h_deg * (math.pi / 180.0))[4])
        EN = np.empty((max(k, 1), nmax, 6))
        XN = np.empty((max(k, 1), nmax))
        _points(p, geo, k, w, h_deg, EN, XN, ok)
        cap = nmax
    ws = _work(cap)
    fb = np.empty((3, cap))
    vals = np.empty(G)
    for g in range(G):
        v = np.nan
        if not (math.isnan(lo) or math.isnan(hi)):
            v = _trial_min(p, col, own, grid[g], lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, res,
                           geo, k, w, EN, XN, ok, ws, fb)
        vals[g] = np.inf if math.isnan(v) else v
    score = _minima(vals)
    i0 = np.argmin(vals)
    best_rel = grid[i0]
    best_val = vals[i0]
    if col == 13 and cutoff < np.inf and _angle_bound(
            p, grid, vals, EN, geo, k, w, ok, h_deg * (math.pi / 180.0)) > cutoff:
        rounds = 0  # no angle can bring this machine down to the cutoff: the grid's best
    for _ in range(rounds):
        i = np.argmin(score)
        if not score[i] < np.inf:
            break
        score[i] = np.inf
        a = grid[max(i - 1, 0)]
        b = grid[min(i + 1, G - 1)]
        x1 = b - _INVPHI * (b - a)
        x2 = a + _INVPHI * (b - a)
        f1 = _trial_min(p, col, own, x1, lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, res, geo,
                        k, w, EN, XN, ok, ws, fb)
        f2 = _trial_min(p, col, own, x2, lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, res, geo,
                        k, w, EN, XN, ok, ws, fb)
        for it in range(40):
            # as the batched search: until the bracket is below 1e-9, at least as many steps
            # as a bracket of two grid cells takes (all machines stepped together before)
            if b - a < 1e-9 and it >= n_min:
                break
            left = not (f1 >= f2)  # NaN counts as worse
            if left:
                b = x2
                x2 = x1
                f2 = f1
                x1 = b - _INVPHI * (b - a)
                f1 = _trial_min(p, col, own, x1, lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, res,
                                geo, k, w, EN, XN, ok, ws, fb)
            else:
                a = x1
                x1 = x2
                f1 = f2
                x2 = a + _INVPHI * (b - a)
                f2 = _trial_min(p, col, own, x2, lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, res,
                                geo, k, w, EN, XN, ok, ws, fb)
        if f1 < best_val:
            best_val = f1
            best_rel = x1
        if f2 < best_val:
            best_val = f2
            best_rel = x2
    return best_rel


@nb.njit(cache=True, parallel=True)
def outer_batch(P, col, lo, hi, blo, bhi, shift_lo_um, shift_hi_um, shift_active, grid,
                h_deg=2.0, tol_um=1e-3, rounds=3, cutoff_um=None):
    """Per machine (rows of P with the compensator's own value in column col: 13 the guide
    angle, deg; 3 CD, mm): the offset from its own value, one of `grid` or refined, where the
    exact minimum of SumDelta over beta (and the guide shift) is least: a grid over `grid`,
    then golden section around each of the `rounds` best local minima of the grid (to a
    bracket below 1e-9). needle_208.adjust._with_outer's search (tests/test_adjust.py holds
    the two to each other). cutoff_um (per machine, the guide angle): where _angle_bound
    proves that no angle reaches it, the grid's best, not refined (its minimum is above it)."""
    n = P.shape[0]
    out = np.empty(n)
    if cutoff_um is None:
        cut = np.full(n, np.inf)
    else:
        cut = cutoff_um
    step = 2.0 * (grid[1] - grid[0])
    n_min = 0
    while step >= 1e-9 and n_min < 40:
        step *= _INVPHI
        n_min += 1
    n_min = max(n_min - 1, 0)
    for i in nb.prange(n):
        if shift_active:
            T0, T1 = shift_lo_um * 1e-3, shift_hi_um * 1e-3
        else:
            T0 = T1 = P[i, 14] * 1e-3
        out[i] = _outer_one(P[i], col, lo[i], hi[i], blo, bhi, T0, T1, grid, h_deg,
                            tol_um * 1e-3, rounds, n_min, cut[i])
    return out


# --- the guide angle inside CD: the joint search of both, by kink searches ---------------------

KINK_CAP = 96  # known points one kink search holds (its grid and its steps)


@nb.njit(cache=True)
def _cross(xa, fa, xb, fb, xc, fc, xd, fd):
    """Where the line through (xa, fa), (xb, fb) meets the line through (xc, fc), (xd, fd), its
    value there, and whether the first falls and the second rises (a V)."""
    sa = (fb - fa) / (xb - xa)
    sc = (fd - fc) / (xd - xc)
    if not (sa < 0.0 < sc) or not (math.isfinite(sa) and math.isfinite(sc)):
        return np.nan, np.inf, False
    xk = (fc - fa + sa * xa - sc * xc) / (sa - sc)
    return xk, fa + sa * (xk - xa), True


@nb.njit(cache=True)
def _kink_next(x, f, cnt, xtol, st):
    """The next point of a kink search (NaN: done), from its cnt known points x (increasing)
    and values f (inf where the mechanism does not run). The minimum is taken to be unimodal
    and lie between the known points either side of the least; a row ends when they are less
    than xtol apart. A step is, in this order of preference: a probe xtol * 0.49 beside the
    least where it is at an end of the box, or where the V model puts the minimum at it (a V:
    the line through two known points on one side meets the line through the least and its
    neighbour on the other; of the two ways the one whose meeting point lies in the bracket with
    the lower value; on an exact V it is the kink, in one step); the model's point; a golden-
    section step into the larger side, where the model fails, was wrong (a probe beat the least)
    or the bracket has not halved in two steps. st (4,): the search's state (widths of the last
    two brackets, whether the last step probed, the least then), inf, inf, 0, NaN at the start."""
    j = _least(f, cnt)
    xb, fb = x[j], f[j]
    if not fb < np.inf or cnt < 2:
        return np.nan
    no_l, no_r = j == 0, j == cnt - 1
    xl1 = xb if no_l else x[j - 1]
    xr1 = xb if no_r else x[j + 1]
    width = xr1 - xl1
    if width < xtol:
        return np.nan
    if no_l or no_r:  # the least at an end of the box: beside it
        st[0], st[1], st[2], st[3] = st[1], width, 1.0, xb
        return xb + 0.49 * xtol if no_l else xb - 0.49 * xtol
    model, vbest = np.nan, np.inf
    if j + 2 < cnt:  # the least on the falling line
        xk, v, ok = _cross(x[j - 1], f[j - 1], xb, fb, x[j + 1], f[j + 1], x[j + 2], f[j + 2])
        if ok and xl1 < xk < xr1:
            model, vbest = xk, v
    if j >= 2:  # the least on the rising line
        xk, v, ok = _cross(x[j - 2], f[j - 2], x[j - 1], f[j - 1], xb, fb, x[j + 1], f[j + 1])
        if ok and xl1 < xk < xr1 and (math.isnan(model) or v < vbest):
            model = xk
    gap_r, gap_l = xr1 - xb, xb - xl1
    if abs(gap_r - gap_l) <= 0.1 * width:  # even sides: towards the larger rise (a lopsided V)
        right = f[j + 1] - fb >= f[j - 1] - fb
    else:
        right = gap_r > gap_l
    golden = xb + (1.0 - _INVPHI) * gap_r if right else xb - (1.0 - _INVPHI) * gap_l
    at_best = abs(model - xb) < 0.25 * xtol  # False for a NaN model
    wrong = st[2] > 0.0 and xb != st[3]
    near = at_best and not wrong
    if near:
        prop = xb + 0.49 * xtol if gap_r >= gap_l else xb - 0.49 * xtol
    elif math.isnan(model) or at_best or width > 0.5 * st[0]:
        prop = golden
    else:
        prop = model
    prop = min(max(prop, xl1 + 0.25 * xtol), xr1 - 0.25 * xtol)
    st[0], st[1], st[2], st[3] = st[1], width, 1.0 if near else 0.0, xb
    return prop


@nb.njit(cache=True)
def _least(f, cnt):
    """The index of the least of f[:cnt] (the first where several are)."""
    j = 0
    for i in range(1, cnt):
        if f[i] < f[j]:
            j = i
    return j


@nb.njit(cache=True)
def _insert(x, f, cnt, xn, fn):
    i = cnt
    while i > 0 and x[i - 1] > xn:
        x[i] = x[i - 1]
        f[i] = f[i - 1]
        i -= 1
    x[i] = xn
    f[i] = fn
    return cnt + 1


@nb.njit(cache=True)
def _kink_run(q, own, xs, fs, cnt, xtol_a, geo, k, w, h_deg, T0, T1, tol_mm, res, EN, XN, ok,
              ws, fb):
    """A kink search over the guide angle from its cnt known points; the least and where."""
    st = np.array([np.inf, np.inf, 0.0, np.nan])
    while cnt < KINK_CAP:
        rel = _kink_next(xs, fs, cnt, xtol_a, st)
        if math.isnan(rel):
            break
        v = _minimum_angle_at(q, own, rel, geo, k, w, h_deg, T0, T1, tol_mm, res, EN, XN, ok,
                              ws, fb)
        cnt = _insert(xs, fs, cnt, rel, v)
    j = _least(fs, cnt)
    return fs[j], xs[j]


@nb.njit(cache=True)
def _angle_kink(q, lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, a_lo, a_hi, n_a, xtol_a, start,
                cutoff=np.inf, rounds=3):
    """The least SumDelta (um; inf where no setting runs) of machine q (its CD set) over the
    guide angle's offsets [a_lo, a_hi] (deg; the exact optimum over beta and the shift at each),
    that offset, and whether the grid saw one local minimum. start NaN: a grid of n_a angles,
    then a kink search to xtol_a in the two cells around each of the `rounds` least local
    minima of the grid (as outer_batch's golden sections); else (start: the optimum at a nearby
    CD, where the angle has one minimum) a bracket a quarter of a grid cell either side of
    start, widened (doubling) until the least is inside it or at an end of the box, then one
    kink search. cutoff (um): where _angle_bound proves from the grid that no angle reaches it,
    the grid's least, not refined (a value above the cutoff, as outer_batch's)."""
    own = q[13]
    res = np.empty(8)
    geo = np.empty((12, 2))
    k, w = _segments(q, lo, hi, blo, bhi, geo)
    nmax = 1
    ht = h_deg * (math.pi / 180.0)
    for i in range(k):
        nmax = max(nmax, _grid(geo[i, 0], geo[i, 1], w, ht)[4])
    EN = np.empty((max(k, 1), nmax, 6))
    XN = np.empty((max(k, 1), nmax))
    ok = np.zeros(12, np.bool_)
    _points(q, geo, k, w, h_deg, EN, XN, ok)
    ws = _work(nmax)
    fb = np.empty((3, nmax))
    xs = np.empty(KINK_CAP)
    fs = np.empty(KINK_CAP)
    if not math.isnan(start):
        cnt = 0
        step = 0.25 * (a_hi - a_lo) / (n_a - 1)
        x0 = min(max(start, a_lo), a_hi)
        for rel in (x0, max(x0 - step, a_lo), min(x0 + step, a_hi)):
            if cnt > 0 and rel == x0:  # x0 at an end of the box
                continue
            v = _minimum_angle_at(q, own, rel, geo, k, w, h_deg, T0, T1, tol_mm, res, EN, XN,
                                  ok, ws, fb)
            cnt = _insert(xs, fs, cnt, rel, v)
        while cnt < KINK_CAP // 2:
            j = _least(fs, cnt)
            if j == 0 and xs[0] > a_lo:
                rel = max(xs[0] - 2.0 * (xs[1] - xs[0]), a_lo)
            elif j == cnt - 1 and xs[cnt - 1] < a_hi:
                rel = min(xs[cnt - 1] + 2.0 * (xs[cnt - 1] - xs[cnt - 2]), a_hi)
            else:
                break
            v = _minimum_angle_at(q, own, rel, geo, k, w, h_deg, T0, T1, tol_mm, res, EN, XN,
                                  ok, ws, fb)
            cnt = _insert(xs, fs, cnt, rel, v)
        v, x = _kink_run(q, own, xs, fs, cnt, xtol_a, geo, k, w, h_deg, T0, T1, tol_mm, res, EN,
                         XN, ok, ws, fb)
        return v, x, True
    grid = np.empty(n_a)
    vals = np.full(n_a, np.nan)
    for g in range(n_a):
        grid[g] = a_lo + (a_hi - a_lo) * g / (n_a - 1)
    if cutoff < np.inf:
        # every fourth grid angle first: where they prove that no angle reaches the cutoff,
        # their least (a value above the cutoff), the other grid angles never evaluated
        sub = np.append(np.arange(0, n_a - 1, 4), n_a - 1)
        for g in sub:
            vals[g] = _minimum_angle_at(q, own, grid[g], geo, k, w, h_deg, T0, T1, tol_mm, res,
                                        EN, XN, ok, ws, fb)
        if _angle_bound(q, grid[sub], vals[sub], EN, geo, k, w, ok, ht) > cutoff:
            j = sub[np.argmin(vals[sub])]
            return vals[j], grid[j], np.sum(_minima(vals[sub]) < np.inf) == 1
    for g in range(n_a):
        if math.isnan(vals[g]):
            vals[g] = _minimum_angle_at(q, own, grid[g], geo, k, w, h_deg, T0, T1, tol_mm, res,
                                        EN, XN, ok, ws, fb)
    score = _minima(vals)
    n_loc = np.sum(score < np.inf)
    i0 = np.argmin(vals)
    best_v, best_x = vals[i0], grid[i0]
    if cutoff < np.inf and _angle_bound(q, grid, vals, EN, geo, k, w, ok, ht) > cutoff:
        rounds = 0
    for _ in range(rounds):
        i = np.argmin(score)
        if not score[i] < np.inf:
            break
        score[i] = np.inf
        cnt = 0
        for g in range(max(i - 1, 0), min(i + 2, n_a)):
            cnt = _insert(xs, fs, cnt, grid[g], vals[g])
        v, x = _kink_run(q, own, xs, fs, cnt, xtol_a, geo, k, w, h_deg, T0, T1, tol_mm, res, EN,
                         XN, ok, ws, fb)
        if v < best_v:
            best_v, best_x = v, x
    return best_v, best_x, n_loc == 1


@nb.njit(cache=True)
def _minimum_angle_at(q, own, rel, geo, k, w, h_deg, T0, T1, tol_mm, res, EN, XN, ok, ws, fb):
    r = q.copy()
    r[13] = own + rel
    v = _minimum_angle(r, geo, k, w, h_deg, T0, T1, tol_mm, res, EN, XN, ok, ws, fb)
    return np.inf if math.isnan(v) else v


@nb.njit(cache=True)
def _cd_value(q, own, rel, lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, a_lo, a_hi, n_a, xtol_a,
              start, best, cut=False):
    """_angle_kink at CD offset rel; best (4,): the least SumDelta so far, its angle, 1 while
    every grid so far saw one local minimum (else 0), and its CD offset, updated; start: begin
    the angle's search at best's angle (else on its grid); cut: the least so far as the angle
    search's cutoff (a value above it is never the least)."""
    q[3] = own + rel
    v, a, one = _angle_kink(q, lo, hi, blo, bhi, T0, T1, h_deg, tol_mm, a_lo, a_hi, n_a, xtol_a,
                            best[1] if start else np.nan, best[0] if cut else np.inf)
    if v < best[0]:
        best[0], best[1], best[3] = v, a, rel
    if not one:
        best[2] = 0.0
    return v


@nb.njit(cache=True, parallel=True)
def cd_angle_batch(P, lo, hi, blo, bhi, shift_lo_um, shift_hi_um, shift_active, cd_grid, a_lo,
                   a_hi, n_a=21, h_deg=2.0, tol_um=1e-3, xtol_cd=3e-6, xtol_a=2e-7):
    """Per machine (rows of P): the CD offset (mm, in [cd_grid[0], cd_grid[-1]]) where the least
    SumDelta over the guide angle's offsets [a_lo, a_hi] (deg) and, at each, the exact optimum
    over beta in [blo, bhi] and the guide shift (shift_active: in [shift_lo_um, shift_hi_um],
    absolute; else the machine's own, P[:, 14]) is least, and that SumDelta (um). CD: on
    cd_grid, then golden section on the best grid point's two cells to a bracket below
    xtol_cd (mm), never worse than the grid (as adjustment._search's nested search, which it
    replaces for this pair). The angle at every CD of the grid: on n_a points, each of the three
    least local minima refined by a kink search to xtol_a (deg) (outer_batch refines them by
    golden section to 1e-9 deg); at golden section's CDs, where every grid CD's angle grid saw
    one minimum, one kink search from the best CD's angle so far, else as on the grid
    (_angle_kink). Returns (n, 3) of the least point tried (never worse than the grid): CD
    offset, SumDelta (NaN where no setting runs), guide angle offset."""
    n = P.shape[0]
    out = np.empty((n, 3))
    G = cd_grid.size
    tol_mm = tol_um * 1e-3
    for i in nb.prange(n):
        if shift_active:
            T0, T1 = shift_lo_um * 1e-3, shift_hi_um * 1e-3
        else:
            T0 = T1 = P[i, 14] * 1e-3
        li, hi_ = lo[i], hi[i]
        if math.isnan(li) or math.isnan(hi_):
            out[i, 0] = cd_grid[(G - 1) // 2]
            out[i, 1] = out[i, 2] = np.nan
            continue
        q = P[i].copy()
        own = q[3]
        vals = np.empty(G)
        best = np.array([np.inf, np.nan, 1.0, cd_grid[(G - 1) // 2]])
        for m in range(G):  # from the middle of the box out, so the least comes early and the
            # cutoff (the least so far) skips the refinement of CDs that cannot beat it: a value
            # above the cutoff is never the grid's least
            g = (G - 1) // 2 + ((m + 1) // 2) * (1 if m % 2 else -1)
            vals[g] = _cd_value(q, own, cd_grid[g], li, hi_, blo, bhi, T0, T1, h_deg, tol_mm,
                                a_lo, a_hi, n_a, xtol_a, False, best, True)
        # golden's CDs: the angle's search from the best's angle so far where every grid CD's
        # angle grid saw one minimum; else on its grid with each local minimum refined
        warm = best[0] < np.inf and best[2] > 0.0
        j = np.argmin(vals)
        a = cd_grid[max(j - 1, 0)]
        b = cd_grid[min(j + 1, G - 1)]
        c = b - _INVPHI * (b - a)
        d = a + _INVPHI * (b - a)
        fc = _cd_value(q, own, c, li, hi_, blo, bhi, T0, T1, h_deg, tol_mm, a_lo, a_hi, n_a,
                       xtol_a, warm, best)
        fd = _cd_value(q, own, d, li, hi_, blo, bhi, T0, T1, h_deg, tol_mm, a_lo, a_hi, n_a,
                       xtol_a, warm, best)
        for _ in range(200):
            if b - a < xtol_cd:
                break
            if fc < fd:
                b, d, fd = d, c, fc
                c = b - _INVPHI * (b - a)
                fc = _cd_value(q, own, c, li, hi_, blo, bhi, T0, T1, h_deg, tol_mm, a_lo, a_hi,
                               n_a, xtol_a, warm, best)
            else:
                a, c, fc = c, d, fd
                d = a + _INVPHI * (b - a)
                fd = _cd_value(q, own, d, li, hi_, blo, bhi, T0, T1, h_deg, tol_mm, a_lo, a_hi,
                               n_a, xtol_a, warm, best)
        _cd_value(q, own, 0.5 * (a + b), li, hi_, blo, bhi, T0, T1, h_deg, tol_mm, a_lo, a_hi,
                  n_a, xtol_a, warm, best)
        # the least of every point tried (the grid's, golden section's and the bracket's centre)
        out[i, 0] = best[3]
        out[i, 1] = best[0] if best[0] < np.inf else np.nan
        out[i, 2] = best[1]
    return out
