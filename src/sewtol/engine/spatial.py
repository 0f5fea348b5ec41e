"""Spatial crank-rocker RSSR (Polukhin): cylindrical pairs at A and D, ball joints at B and C;
and its crank-slider analogue RSSP (`spatial_slider`, frame and derivation in the comment block
before it: the slider C = (e, s, 0) on a guide along Y inclined at alpha to the crank's plane).

Geometry (lengths mm, angles radians). The crank axis and the rocker axis cross at the angle
alpha; their common normal is OQ = e, O on the crank axis, Q on the rocker axis. Frame: X along
OQ (from the crank axis to the rocker axis), Z parallel to the rocker axis, Y = Z x X. The crank
axis is then k = (0, sin alpha, cos alpha) (tilted from Z towards +Y for alpha > 0); the crank
AB = a turns in the plane through A = O + f k, the rocker CD = c in the plane through
D = Q + g Z, the coupler BC = b joins the two ball joints:

    B(phi) = (a cos phi,  f sin(alpha) + a cos(alpha) sin phi,  f cos(alpha) - a sin(alpha) sin phi)
    C(psi) = (e + c cos psi,  c sin psi,  g)

phi is measured from +X about k, psi from +X about Z, both counter-clockwise by the right-hand
rule; at alpha = 0 the two are the planar crank and rocker angles, B = a e^{i phi} and
C = e + c e^{i psi} in the XY plane.

Position function. |B - C|^2 = b^2 with |B|^2 = a^2 + f^2 and
|C|^2 = e^2 + 2 e c cos psi + c^2 + g^2 gives

    F(phi, psi) = A(phi) sin psi + B(phi) cos psi + C(phi) = 0,
    A = -2c (f sin(alpha) + a cos(alpha) sin phi),   B = 2c (e - a cos phi),
    C = 2a (g sin(alpha) sin phi - e cos phi) + a^2 - b^2 + c^2 + e^2 + f^2 + g^2 - 2 f g cos(alpha),

(A, B, C: coefficients, not the joints), which is term for term the function printed by the
source: the printed F agrees with this derivation for the axis orientation above (with the
crank axis tilted towards -Y instead, every sin(alpha) term changes sign). With
R = sqrt(A^2 + B^2) and delta = atan2(A, B), F = R cos(psi - delta) + C, so
psi = delta + branch * arccos(-C / R).

branch = +1 takes sin(psi - delta) > 0, i.e. F_psi = -R sin(psi - delta) < 0. In the planar
limit delta is the direction of B -> Q, so branch +1 puts C on the left of B -> Q: the same root
as engine.rrr(B, b, Q, c, branch) for the dyad B-C-Q. A branch can only be left through
F_psi = 0, a dead point.

Transfer functions (the source's printed partial derivatives contain typesetting errors; these
are derived from F above). Implicit differentiation of F(phi, psi(phi)) = 0:

    psi'   = -F_phi / F_psi
    psi''  = -(F_phiphi + 2 F_phipsi psi' + F_psipsi psi'^2) / F_psi
    psi''' = -(F_phiphiphi + 3 F_phiphipsi psi' + 3 F_phipsipsi psi'^2 + F_psipsipsi psi'^3
               + 3 (F_phipsi + F_psipsi psi') psi'') / F_psi

Extreme rocker positions (psi' = 0) satisfy F_phi = 0, i.e.

    sin(phi) (c cos psi + e) = cos(phi) (c cos(alpha) sin psi - g sin(alpha)),

the source's tan(phi) = (c cos(alpha) sin psi - g sin(alpha)) / (c cos psi + e), which is
correct (written as a tangent it loses the half-turn: phi and phi + pi both satisfy it, F = 0
picks one). Geometrically, the crank pin's velocity is then perpendicular to the coupler.
Writing F = U(psi) sin phi + V(psi) cos phi + W(psi), F = F_phi = 0 forces
W^2 = U^2 + V^2, a trigonometric polynomial of degree 2 in psi solved here by the eigenvalues
of its companion matrix (`rocker_extremes`).

Closure. The distance from B to a point of the rocker circle ranges over [d_min, d_max] with
d_min^2 = C + b^2 - R and d_max^2 = C + b^2 + R (|C| > R means b lies outside it); miss_mm =
max(d_min - b, b - d_max, 0) is how much the coupler would have to change length to assemble:
in the planar limit it equals engine.rrr's miss for the dyad B-C-Q. transmission_deg is the
angle between the coupler BC and the plane normal to the rocker's velocity at C, that is
90 deg minus the pressure angle (the angle between the force along BC and C's velocity t,
folded into [0, 90]): sin(transmission) = |(C - B) . t| / b = |F_psi| / (2 b c). It is 0 at a
dead point and, in the planar limit, equals the angle between coupler and rocker that
engine.rrr reports.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol.engine.dyad import Closure
from sewtol.engine.motion import Angle, Motion


@dataclass(frozen=True)
class _Coefficients:
    """A, B, C of F = A sin psi + B cos psi + C and their derivatives in phi (index = order)."""

    A: tuple
    B: tuple
    C: tuple


def _coefficients(phi, a, b, c, e, f, g, alpha) -> _Coefficients:
    sa, ca = np.sin(alpha), np.cos(alpha)
    s, co = np.sin(phi), np.cos(phi)
    k = a * a - b * b + c * c + e * e + f * f + g * g - 2.0 * f * g * ca
    A = (-2.0 * c * (f * sa + a * ca * s), -2.0 * c * a * ca * co, 2.0 * c * a * ca * s,
         2.0 * c * a * ca * co)
    B = (2.0 * c * (e - a * co), 2.0 * c * a * s, 2.0 * c * a * co, -2.0 * c * a * s)
    C = (2.0 * a * (g * sa * s - e * co) + k, 2.0 * a * (g * sa * co + e * s),
         2.0 * a * (e * co - g * sa * s), -2.0 * a * (g * sa * co + e * s))
    return _Coefficients(A, B, C)


def position_function(phi, psi, a, b, c, e, f, g, alpha_rad):
    """F(phi, psi) (mm^2): zero where the coupler BC has its length b."""
    k = _coefficients(np.asarray(phi, float), a, b, c, e, f, g, alpha_rad)
    return k.A[0] * np.sin(psi) + k.B[0] * np.cos(psi) + k.C[0]


def _partials(k: _Coefficients, psi, order: int = 3):
    """F's partial derivatives up to `order`, keyed by (order in phi, order in psi)."""
    s, co = np.sin(psi), np.cos(psi)
    out = {}
    for i in range(order + 1):
        out[i, 0] = k.A[i] * s + k.B[i] * co + k.C[i]
        if i + 1 <= order:
            out[i, 1] = k.A[i] * co - k.B[i] * s
        if i + 2 <= order:
            out[i, 2] = -k.A[i] * s - k.B[i] * co
        if i + 3 <= order:
            out[i, 3] = -out[i, 1]
    return out


def _wrap(x):
    """An angle in (-2 pi, 2 pi] wrapped to (-pi, pi]."""
    x = np.where(x > np.pi, x - 2.0 * np.pi, x)
    return np.where(x <= -np.pi, x + 2.0 * np.pi, x)


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def _solve(phi, a, b, c, e, f, g, alpha, branch, order: int = 3):
    """psi (wrapped to (-pi, pi]), psi', psi'', psi''' in phi (None above `order`), miss_mm,
    transmission_deg."""
    a, b, c, e, f, g, alpha = (np.asarray(v, float) for v in (a, b, c, e, f, g, alpha))
    k = _coefficients(phi, a, b, c, e, f, g, alpha)
    r = np.hypot(k.A[0], k.B[0])
    delta = np.arctan2(k.A[0], k.B[0])
    # |B - C(psi)|^2 = F + b^2 = R cos(psi - delta) + C + b^2 runs over base -+ r
    base = k.C[0] + b * b
    d_max = np.sqrt(np.maximum(base + r, 0.0))
    d_min = np.sqrt(np.maximum(base - r, 0.0))
    miss = np.maximum(np.maximum(d_min - b, b - d_max), 0.0)
    # B on the rocker's axis (closer than 1e-12 mm): every point of the circle is as far, no
    # psi is defined (like engine.rrr's coincident centres)
    apart = r / (2.0 * c) > 1e-12
    miss = np.where(apart, miss, np.inf)
    cos_gamma = np.clip(-k.C[0] / np.where(apart, r, np.nan), -1.0, 1.0)
    gamma = np.arccos(np.where(miss > 0.0, np.nan, cos_gamma))
    psi = _wrap(delta + np.asarray(branch, float) * gamma)
    p = _partials(k, psi, max(order, 1))
    d1 = -p[1, 0] / p[0, 1] if order >= 1 else None
    d2 = -(p[2, 0] + 2.0 * p[1, 1] * d1 + p[0, 2] * d1**2) / p[0, 1] if order >= 2 else None
    d3 = None
    if order >= 3:
        d3 = -(p[3, 0] + 3.0 * p[2, 1] * d1 + 3.0 * p[1, 2] * d1**2 + p[0, 3] * d1**3
               + 3.0 * (p[1, 1] + p[0, 2] * d1) * d2) / p[0, 1]
    sin_mu = np.abs(p[0, 1]) / (2.0 * b * c)
    transmission = np.degrees(np.arcsin(np.minimum(sin_mu, 1.0)))
    return psi, d1, d2, d3, miss, transmission


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def spatial_rocker(phi: Angle, a, b, c, e, f, g, alpha_rad, branch) -> tuple[Angle, Closure]:
    """Rocker angle psi of the spatial crank-rocker for the crank angle phi.

    `phi` carries the crank angle and its transfer functions with respect to the chain's driving
    angle q (engine.driving_angle(q) when the crank is the driver); psi's transfer functions are
    with respect to q as well. Parameters broadcast over (samples, angles). Where the chain cannot
    close, psi is NaN and the Closure says by how much the coupler misses (mm).
    """
    psi, d1, d2, _, miss, transmission = _solve(np.asarray(phi.a, float), a, b, c, e, f, g,
                                                alpha_rad, branch, order=2)
    dq = d1 * phi.da
    ddq = d2 * phi.da**2 + d1 * phi.dda
    shape = np.broadcast(psi, dq, ddq).shape
    return (Angle(np.broadcast_to(psi, shape), np.broadcast_to(dq, shape),
                  np.broadcast_to(ddq, shape)),
            Closure(np.broadcast_to(miss, shape), np.broadcast_to(transmission, shape)))


def spatial_rocker_third(phi_rad, a, b, c, e, f, g, alpha_rad, branch) -> np.ndarray:
    """d3 psi / d phi3 (rad/rad^3) with respect to the crank angle itself (NaN where it cannot close)."""
    return _solve(np.asarray(phi_rad, float), a, b, c, e, f, g, alpha_rad, branch)[3]


def _crank_pin(phi_rad, a, f, alpha_rad) -> np.ndarray:
    """The crank's ball joint B(phi) (mm, last axis x, y, z) in the X, Y, Z frame."""
    phi = np.asarray(phi_rad, float)
    sa, ca = np.sin(alpha_rad), np.cos(alpha_rad)
    return np.stack(np.broadcast_arrays(a * np.cos(phi), f * sa + a * ca * np.sin(phi),
                                        f * ca - a * sa * np.sin(phi)), -1)


def spatial_joints(phi_rad, psi_rad, a, c, e, f, g, alpha_rad) -> tuple[np.ndarray, np.ndarray]:
    """3-D positions (mm, last axis x, y, z) of the ball joints B(phi) and C(psi) in the X, Y, Z frame."""
    psi = np.asarray(psi_rad, float)
    cx = e + c * np.cos(psi)
    cy = c * np.sin(psi)
    cz = g + 0.0 * psi
    return _crank_pin(phi_rad, a, f, alpha_rad), np.stack(np.broadcast_arrays(cx, cy, cz), -1)


PARAMETERS = ("a", "b", "c", "e", "f", "g", "alpha_rad")


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def rocker_sensitivities(phi_rad, a, b, c, e, f, g, alpha_rad, branch) -> dict[str, np.ndarray]:
    """d psi / d p at a fixed crank angle for every dimension p (rad per mm; rad per rad for alpha).

    From F(phi, psi; p) = 0: d psi / d p = -F_p / F_psi. At an extreme position (psi' = 0) the
    crank angle of the extreme moves with p but psi does not change to first order through it
    (the envelope theorem), so evaluated at `rocker_extremes`' crank angles these are the
    derivatives of psi_max and psi_min, and their difference that of the swing.
    """
    phi = np.asarray(phi_rad, float)
    psi = _solve(phi, a, b, c, e, f, g, alpha_rad, branch, order=1)[0]
    a, b, c, e, f, g, alpha = (np.asarray(v, float) for v in (a, b, c, e, f, g, alpha_rad))
    k = _coefficients(phi, a, b, c, e, f, g, alpha)
    f_psi = _partials(k, psi)[0, 1]
    sa, ca = np.sin(alpha), np.cos(alpha)
    s, co = np.sin(phi), np.cos(phi)
    sp, cp = np.sin(psi), np.cos(psi)
    # (dA/dp, dB/dp, dC/dp) of F = A sin psi + B cos psi + C
    parts = {
        "a": (-2.0 * c * ca * s, -2.0 * c * co, 2.0 * (g * sa * s - e * co) + 2.0 * a),
        "b": (0.0, 0.0, -2.0 * b),
        "c": (k.A[0] / c, k.B[0] / c, 2.0 * c),
        "e": (0.0, 2.0 * c, -2.0 * a * co + 2.0 * e),
        "f": (-2.0 * c * sa, 0.0, 2.0 * f - 2.0 * g * ca),
        "g": (0.0, 0.0, 2.0 * a * sa * s + 2.0 * g - 2.0 * f * ca),
        "alpha_rad": (-2.0 * c * (f * ca - a * sa * s), 0.0, 2.0 * a * g * ca * s + 2.0 * f * g * sa),
    }
    return {name: -(da * sp + db * cp + dc) / f_psi for name, (da, db, dc) in parts.items()}


def _quartic_roots(low_first: np.ndarray) -> np.ndarray:
    """The roots of z^4 + c3 z^3 + ... + c0, one quartic per row of low_first = (c0 ... c3):
    the eigenvalues of its companion matrix (complex or real, as the coefficients)."""
    companion = np.zeros((low_first.shape[0], 4, 4), low_first.dtype)
    companion[:, 1:, :-1] = np.eye(3)
    companion[:, :, -1] = -low_first
    return np.linalg.eigvals(companion)


@dataclass(frozen=True)
class RockerExtremes:
    """Extreme rocker positions on one branch (radians; NaN where there are not exactly two)."""

    psi_min: np.ndarray
    phi_at_min: np.ndarray
    psi_max: np.ndarray
    phi_at_max: np.ndarray

    @property
    def swing(self) -> np.ndarray:
        """The rocker's swing psi_max - psi_min, taken the way the rocker turns from min to max."""
        return np.mod(self.psi_max - self.psi_min, 2.0 * np.pi)


def _uvw(psi, a, b, c, e, f, g, alpha):
    """F = U sin phi + V cos phi + W as functions of psi, and their derivatives in psi."""
    sa, ca = np.sin(alpha), np.cos(alpha)
    s, co = np.sin(psi), np.cos(psi)
    k = a * a - b * b + c * c + e * e + f * f + g * g - 2.0 * f * g * ca
    u = 2.0 * a * (g * sa - c * ca * s)
    v = -2.0 * a * (c * co + e)
    w = -2.0 * c * f * sa * s + 2.0 * c * e * co + k
    du = -2.0 * a * c * ca * co
    dv = 2.0 * a * c * s
    dw = -2.0 * c * f * sa * co - 2.0 * c * e * s
    return u, v, w, du, dv, dw


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def rocker_extremes(a, b, c, e, f, g, alpha_rad, branch) -> RockerExtremes:
    """The rocker's extreme positions from F = F_phi = 0 (see the module docstring).

    h(psi) = W^2 - U^2 - V^2 is a trigonometric polynomial of degree 2: its five Fourier
    coefficients come exactly from five samples, z^2 h(z) (z = e^{i psi}) is a quartic whose
    roots on the unit circle are the candidates, polished by Newton steps on h. Each gives the
    crank angle through (sin phi, cos phi) = -W (U, V) / (U^2 + V^2); the roots on `branch` with
    psi'' < 0 are maxima, with psi'' > 0 minima. Parameters broadcast to one shape.
    """
    params = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                   (a, b, c, e, f, g, alpha_rad, branch)))
    shape = params[0].shape
    a, b, c, e, f, g, alpha, br = (p.reshape(-1, 1) for p in params)
    nodes = 2.0 * np.pi * np.arange(5) / 5.0
    u, v, w, *_ = _uvw(nodes, a, b, c, e, f, g, alpha)
    h = w * w - u * u - v * v
    orders = np.arange(-2, 3)
    coef = (h[:, None, :] * np.exp(-1j * orders[:, None] * nodes)).mean(-1)  # h_k, k = -2..2
    lead = coef[:, 4]
    degenerate = np.abs(lead) <= 1e-12 * np.abs(coef).max(-1)
    lead = np.where(degenerate, 1.0, lead)
    z = _quartic_roots(coef[:, :4] / lead[:, None])
    on_circle = np.abs(np.abs(z) - 1.0) < 1e-6
    psi = np.angle(z)
    for _ in range(4):
        u, v, w, du, dv, dw = _uvw(psi, a, b, c, e, f, g, alpha)
        hv = w * w - u * u - v * v
        dh = 2.0 * (w * dw - u * du - v * dv)
        psi = psi - np.where(dh != 0.0, hv / dh, 0.0)
    psi = np.angle(np.exp(1j * psi))
    u, v, w, *_ = _uvw(psi, a, b, c, e, f, g, alpha)
    n2 = u * u + v * v
    phi = np.arctan2(-w * u / n2, -w * v / n2)
    k = _coefficients(phi, a, b, c, e, f, g, alpha)
    side = np.sign(np.sin(psi - np.arctan2(k.A[0], k.B[0])))
    p = _partials(k, psi)
    curvature = -p[2, 0] / p[0, 1]  # psi'' where psi' = 0
    keep = on_circle & (side == br) & ~degenerate[:, None]
    is_max = keep & (curvature < 0.0)
    is_min = keep & (curvature > 0.0)
    good = (is_max.sum(-1) == 1) & (is_min.sum(-1) == 1)

    def pick(mask, values):
        out = np.where(mask, values, 0.0).sum(-1)
        return np.where(good, out, np.nan).reshape(shape)

    return RockerExtremes(pick(is_min, psi), pick(is_min, phi), pick(is_max, psi),
                          pick(is_max, phi))


# --- the spatial crank-slider -------------------------------------------------------------------
# Polukhin's crank-slider analogue (RSSP): the rocker CD is replaced by a slider C on a straight
# guide. The crank is as above (axis k = (0, sin alpha, cos alpha) through O, plane at OA = f);
# X runs along the common normal OQ = e of the crank axis and the guide, Z is the direction the
# rocker's axis had (normal to the plane of OQ and the guide), Y = Z x X runs along the guide.
# The guide is the line through Q = (e, 0, 0) along +Y, so
#
#     C(s) = (e, s, 0),   s = QC (mm, positive along +Y),
#
# and alpha is the angle between the guide and the crank's plane (the guide crosses the crank
# axis at 90 deg - alpha): alpha = 0, f = 0 is the planar offset crank-slider with the crank
# turning about O in the XY plane and the slider on the line x = e. There is no g: an offset
# along the guide only moves the origin of s. From |B - C|^2 = b^2 with |B|^2 = a^2 + f^2,
# |C|^2 = e^2 + s^2 and B.C = a e cos phi + s m:
#
#     F(phi, s) = s^2 - 2 s m(phi) + K(phi) = 0,
#     m = B_y = f sin(alpha) + a cos(alpha) sin phi,   K = a^2 + f^2 + e^2 - b^2 - 2 a e cos phi,
#
# a quadratic in s: s = m + branch sqrt(D), D = m^2 - K = b^2 - rho^2, rho^2 = (B_x - e)^2 + B_z^2
# the squared distance of B from the guide. branch +1 takes the root further along +Y (F_s > 0),
# the convention of engine.rrp; the branches meet only where D = 0, a dead point (F_s = 0).
# The transfer functions follow from F by the same implicit differentiation as psi's, with
# F_s = 2 (s - m), F_ss = 2, F_sss = 0, F_phis = -2 m', F_phiphis = -2 m'', F_phiss = 0.


def _slider_mk(phi, a, b, e, f, alpha):
    """m, K of F = s^2 - 2 s m + K and their derivatives in phi (index = order, up to 3)."""
    sa, ca = np.sin(alpha), np.cos(alpha)
    s, co = np.sin(phi), np.cos(phi)
    m = (f * sa + a * ca * s, a * ca * co, -a * ca * s, -a * ca * co)
    k = (a * a + f * f + e * e - b * b - 2.0 * a * e * co, 2.0 * a * e * s, 2.0 * a * e * co,
         -2.0 * a * e * s)
    return m, k


def slider_position_function(phi, s, a, b, e, f, alpha_rad):
    """F(phi, s) (mm^2) of the spatial crank-slider: zero where the coupler BC has its length b."""
    m, k = _slider_mk(np.asarray(phi, float), a, b, e, f, alpha_rad)
    s = np.asarray(s, float)
    return s * s - 2.0 * s * m[0] + k[0]


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def _solve_slider(phi, a, b, e, f, alpha, branch, order: int = 3):
    """s, s', s'', s''' in phi (None above `order`), miss_mm, transmission_deg."""
    a, b, e, f, alpha = (np.asarray(v, float) for v in (a, b, e, f, alpha))
    m, k = _slider_mk(phi, a, b, e, f, alpha)
    disc = m[0] * m[0] - k[0]  # b^2 - rho^2
    rho = np.sqrt(np.maximum(b * b - disc, 0.0))
    miss = np.maximum(rho - b, 0.0)
    root = np.sqrt(np.where(miss > 0.0, np.nan, np.maximum(disc, 0.0)))
    s = m[0] + np.asarray(branch, float) * root
    f_s = 2.0 * (s - m[0])
    # F_phi^(i) = -2 s m^(i) + K^(i); F_phi^(i) s = -2 m^(i)
    f_p = [None] + [-2.0 * s * m[i] + k[i] for i in (1, 2, 3)]
    d1 = -f_p[1] / f_s if order >= 1 else None
    d2 = -(f_p[2] - 4.0 * m[1] * d1 + 2.0 * d1**2) / f_s if order >= 2 else None
    d3 = None
    if order >= 3:
        d3 = -(f_p[3] - 6.0 * m[2] * d1 + 3.0 * (-2.0 * m[1] + 2.0 * d1) * d2) / f_s
    # pressure angle theta: between the coupler force (along BC) and C's velocity (along the
    # guide, Y); cos(theta) = |(C - B).Y| / b = |s - m| / b; transmission = 90 deg - theta
    sin_mu = np.abs(s - m[0]) / b
    transmission = np.degrees(np.arcsin(np.minimum(sin_mu, 1.0)))
    return s, d1, d2, d3, miss, transmission


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def spatial_slider(phi: Angle, a, b, e, f, alpha_rad, branch) -> tuple[Motion, Closure]:
    """The slider point C of the spatial crank-slider for the crank angle phi.

    C = (e, s, 0) lies in the XY plane of the frame (see `slider_position_function`'s section of
    the module), so it is returned as the planar point e + i s: its y coordinate is the slider's
    displacement s = QC along the guide and its motion is C's true motion. `phi` carries the
    crank angle and its transfer functions with respect to the chain's driving angle q; the
    returned transfer functions are with respect to q. Where the coupler cannot reach the guide,
    s is NaN and the Closure gives the miss (mm) and, elsewhere, the transmission angle.
    """
    s, d1, d2, _, miss, transmission = _solve_slider(np.asarray(phi.a, float), a, b, e, f,
                                                     alpha_rad, branch, order=2)
    dq = d1 * phi.da
    ddq = d2 * phi.da**2 + d1 * phi.dda
    e = np.asarray(e, float)
    shape = np.broadcast(s, dq, ddq, e).shape
    p = np.broadcast_to(e + 1j * s, shape)
    return (Motion(p, np.broadcast_to(1j * dq, shape), np.broadcast_to(1j * ddq, shape)),
            Closure(np.broadcast_to(miss, shape), np.broadcast_to(transmission, shape)))


def spatial_slider_displacement(phi_rad, a, b, e, f, alpha_rad, branch) -> tuple[np.ndarray, ...]:
    """s, ds/dphi, d2s/dphi2, d3s/dphi3 (mm, mm/rad, ...) with respect to the crank angle itself,
    then miss_mm and transmission_deg (NaN where it cannot close)."""
    return _solve_slider(np.asarray(phi_rad, float), a, b, e, f, alpha_rad, branch)


def slider_joints(phi_rad, s, a, e, f, alpha_rad) -> tuple[np.ndarray, np.ndarray]:
    """3-D positions (mm, last axis x, y, z) of the ball joints B(phi) and C(s) of the slider."""
    s = np.asarray(s, float)
    z = 0.0 * s
    return _crank_pin(phi_rad, a, f, alpha_rad), np.stack(np.broadcast_arrays(e + z, s, z), -1)


@dataclass(frozen=True)
class SliderExtremes:
    """Extreme slider positions on one branch (mm and radians; NaN where the crank does not turn
    all round with the coupler on the guide)."""

    s_min: np.ndarray
    phi_at_min: np.ndarray
    s_max: np.ndarray
    phi_at_max: np.ndarray

    @property
    def stroke(self) -> np.ndarray:
        """The slider's stroke s_max - s_min (mm)."""
        return self.s_max - self.s_min


def _largest_guide_distance(a, e, f, alpha):
    """max over phi of rho^2 = (B_x - e)^2 + B_z^2 = r0 + r1 cos phi + q1 sin phi + r2 cos 2 phi.

    A trigonometric polynomial of degree 2: its critical points are the roots on the unit circle
    of a quartic in z = e^{i phi} (companion matrix); 64 samples are added as candidates, which
    also covers r2 = 0 (alpha = 90 deg), where the quartic loses its leading term."""
    a, e, f, alpha = (np.reshape(v, (-1, 1)) for v in (a, e, f, alpha))
    sa, ca = np.sin(alpha), np.cos(alpha)
    r0 = 0.5 * a * a + e * e + f * f * ca * ca + 0.5 * a * a * sa * sa
    r1, q1, r2 = -2.0 * a * e, -2.0 * a * f * sa * ca, 0.5 * a * a * ca * ca

    def rho2(p):
        return r0 + r1 * np.cos(p) + q1 * np.sin(p) + r2 * np.cos(2.0 * p)

    # d rho^2 / d phi times 2 i z^2: -2 r2 z^4 + (i q1 - r1) z^3 + (r1 + i q1) z + 2 r2
    lead = -2.0 * r2
    ok = np.abs(lead) > 1e-12 * (np.abs(r1) + np.abs(q1) + np.abs(r2) + 1e-300)
    lead = np.where(ok, lead, 1.0)
    n = lead.shape[0]
    coef = np.concatenate([2.0 * r2 + 0j, r1 + 1j * q1, 0.0 * r1 + 0j, 1j * q1 - r1], -1)
    roots = np.where(ok, np.angle(_quartic_roots(coef / lead)), 0.0)
    grid = 2.0 * np.pi * np.arange(64) / 64.0
    cand = np.concatenate([roots, np.broadcast_to(grid, (n, 64))], -1)
    for _ in range(3):  # Newton steps on d rho^2 / d phi = 0 (they keep a root a root)
        d1 = -r1 * np.sin(cand) + q1 * np.cos(cand) - 2.0 * r2 * np.sin(2.0 * cand)
        d2 = -r1 * np.cos(cand) - q1 * np.sin(cand) - 4.0 * r2 * np.cos(2.0 * cand)
        step = np.where(d2 < 0.0, d1 / np.where(d2 < 0.0, d2, 1.0), 0.0)
        cand = cand - np.clip(step, -0.1, 0.1)
    return np.max(rho2(cand), axis=-1)  # shape (n,)


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def slider_extremes(a, b, e, f, alpha_rad, branch) -> SliderExtremes:
    """The slider's extreme positions on `branch` from F = F_phi = 0.

    s' = 0 means F_phi = 0: s cos(alpha) cos(phi) = e sin(phi) (the crank pin's velocity is
    normal to the coupler). Writing F = U(s) sin phi + V(s) cos phi + W(s) with
    U = -2 a s cos(alpha), V = -2 a e, W = s^2 - 2 s f sin(alpha) + a^2 + f^2 + e^2 - b^2,
    F = F_phi = 0 forces W^2 = U^2 + V^2, a quartic in s:

        s^4 - 4 p s^3 + (4 p^2 + 2 k - 4 a^2 cos^2 alpha) s^2 - 4 p k s + k^2 - 4 a^2 e^2 = 0,
        p = f sin(alpha), k = a^2 + f^2 + e^2 - b^2.

    Its real roots give (sin phi, cos phi) = -W (U, V) / (U^2 + V^2); those on `branch`
    (sign(s - m) = branch) with s'' < 0 are maxima, with s'' > 0 minima; the largest maximum and
    the smallest minimum are returned. NaN where the coupler does not reach the guide all round
    (max rho > b, checked exactly) or no maximum and minimum are found. Parameters broadcast.
    """
    params = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                   (a, b, e, f, alpha_rad, branch)))
    shape = params[0].shape
    a, b, e, f, alpha, br = (p.reshape(-1, 1) for p in params)
    sa, ca = np.sin(alpha), np.cos(alpha)
    p = f * sa
    k = a * a + f * f + e * e - b * b
    coef = np.concatenate([-4.0 * p, 4.0 * p * p + 2.0 * k - 4.0 * a * a * ca * ca,
                           -4.0 * p * k, k * k - 4.0 * a * a * e * e], -1)  # s^3 ... s^0
    z = _quartic_roots(coef[:, ::-1])
    scale = 1.0 + np.abs(z)
    real = np.abs(z.imag) < 1e-6 * scale
    s = z.real
    for _ in range(3):  # Newton polish on the quartic
        val = (((s + coef[:, :1]) * s + coef[:, 1:2]) * s + coef[:, 2:3]) * s + coef[:, 3:]
        der = ((4.0 * s + 3.0 * coef[:, :1]) * s + 2.0 * coef[:, 1:2]) * s + coef[:, 2:3]
        s = s - np.where(der != 0.0, val / np.where(der != 0.0, der, 1.0), 0.0)
    u = -2.0 * a * s * ca
    v = -2.0 * a * e + 0.0 * s
    w = s * s - 2.0 * s * p + k
    n2 = u * u + v * v
    phi = np.arctan2(-w * u / n2, -w * v / n2)
    m, kk = _slider_mk(phi, a, b, e, f, alpha)
    side = np.sign(s - m[0])
    f_s = 2.0 * (s - m[0])
    curvature = -(-2.0 * s * m[2] + kk[2]) / f_s  # s'' where s' = 0
    keep = real & (side == br) & (n2 > 0.0)
    is_max = keep & (curvature < 0.0)
    is_min = keep & (curvature > 0.0)
    closes = _largest_guide_distance(a[:, 0], e[:, 0], f[:, 0], alpha[:, 0]) <= b[:, 0] ** 2
    good = is_max.any(-1) & is_min.any(-1) & closes

    def pick(mask, values, largest):
        fill = -np.inf if largest else np.inf
        v = np.where(mask, s, fill)
        i = np.argmax(v, -1) if largest else np.argmin(v, -1)
        out = np.take_along_axis(values, i[:, None], -1)[:, 0]
        return np.where(good, out, np.nan).reshape(shape)

    return SliderExtremes(pick(is_min, s, False), pick(is_min, phi, False),
                          pick(is_max, s, True), pick(is_max, phi, True))
