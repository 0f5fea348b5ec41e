"""Joint clearances in studies: the clearance Jacobian, the worst case, random journals, and the
guide pair as the criterion.

A revolute pair j with radial clearance c_j lets its journal sit anywhere in a circle
|r_j| <= c_j (`sewtol.mechanism.clearance`: r_j = (dx, dy) is a pair parameter of the model).
To first order the output's signal s(phi) at each crank angle (the signed deviation d of a point
from a line for a ``line_deviation`` output, the coordinate for ``coordinate``, the angle for
``angle``) moves by  sum_j J_j(phi) . r_j , with J_j = (ds/ddx_j, ds/ddy_j) taken by central
finite differences of the real model (`jacobian`). So:

- **worst case**: the vectors chosen adversarially at each angle give |delta s| <= W(phi) =
  sum_j c_j |J_j(phi)|, reached in either sign (`worst_case`);
- **Ting's bound** (Ting, Zhu & Watkins 2000, Mech. Mach. Theory 35, 391-401): in a single loop
  the link directions depend on the clearance vectors only through their sum R = sum_j r_j, so
  every pair of the loop has the same |J_j| for a link's direction, and the worst direction error
  is (sum_j c_j) |d theta / d R|; a point P reached from the frame through the pairs K of an open
  chain moves by those pairs' vectors plus its links' turns, |delta P| <= sum_{j in K} c_j +
  (sum_j c_j) sum_i l_i |d theta_i / d R|. `ting_bound` computes it for a four-bar and the
  tests hold the worst case to it (equal for the direction and for a single link);
- **random**: per machine each journal uniform in its circle, or on its rim
  (`random_offsets`), seeded, evaluated through the real model (nonlinear, not first order).

`guide_criterion` is the guide pair as the criterion of a zero-mobility drive (the 208 needle):
see its docstring. Assumptions: rigid links, small clearances (first order for W), no impact
dynamics; the offsets are held over the turn in the frame's axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.fits import iso_fit
from sewtol.mechanism.clearance import offset_names

H_MM = 1e-4  # the finite-difference step: 1/25 of the smallest radial clearance of a fine fit
SIGNAL_TYPES = ("line_deviation", "coordinate", "angle")
DEG = np.pi / 180.0


def revolute(mech) -> tuple:
    """The mechanism's revolute pairs with a clearance (refused when it has none)."""
    pairs = tuple(c for c in getattr(mech, "clearances", ()) if c.pair == "revolute")
    if not pairs:
        raise ParameterError("clearances", "the mechanism file declares no revolute "
                                           "[[clearances]]", getattr(mech, "name", mech))
    return pairs


def signal(mech, state, output: str) -> np.ndarray:
    """The output's signal over the sampled angles, shape (m, samples): the signed distance d
    (um) of a line_deviation's point from its line, a coordinate's x or y (mm), an angle's
    direction (deg, unwrapped)."""
    from sewtol.mechanism.model import resolved
    from sewtol.mechanism.outputs import OUTPUT_TYPES

    o = mech.output(output)
    if o.type not in SIGNAL_TYPES:
        raise ParameterError("output", "must be an output of type "
                             + ", ".join(SIGNAL_TYPES) + " (a signal over the turn)",
                             f"{output} ({o.type})")
    f = resolved(o.fields, OUTPUT_TYPES[o.type].fields, state.points, state.angles, state.values)
    if o.type == "line_deviation":
        a = f["angle_deg"] * DEG
        n = np.cos(a) - 1j * np.sin(a)
        g = f["x"] + 1j * f["y"] + n * (f["shift_um"] * 1e-3)
        return 1e3 * (np.conjugate(n) * (f["point"].p - g)).real
    if o.type == "coordinate":
        p = f["point"]
        return np.broadcast_to(p.x if f["axis"] == "x" else p.y, state.shape)
    base = f["angle"] if f.get("angle") is not None else f["direction"]
    return np.degrees(np.unwrap(np.broadcast_to(base.a, state.shape), axis=-1))


def _signal(mech, values, output):
    state = mech.state(values)
    status, _ = mech.status_of(state)
    s = np.array(signal(mech, state, output), float)
    s[status != "ok"] = np.nan
    return s, status


def jacobian(mech, values: dict | None, output: str, h_mm: float = H_MM) -> dict:
    """joint -> J_j, complex (m, samples): ds/ddx_j + i ds/ddy_j (signal unit per mm) at each
    machine of `values` and angle, by central differences of step h_mm."""
    pairs = revolute(mech)
    values = {k: np.atleast_1d(np.asarray(v, float)) for k, v in (values or {}).items()}
    m = max([v.size for v in values.values()], default=1)
    values = {k: np.broadcast_to(v, (m,)) for k, v in values.items()}
    names = [n for c in pairs for n in offset_names(c.joint)]
    # one evaluation of 2 * len(names) * m machines: every +h and -h side by side
    big = {k: np.tile(v, 2 * len(names)) for k, v in values.items()}
    for k, name in enumerate(names):
        col = np.array(big.get(name, np.zeros(2 * len(names) * m)), float)
        col[2 * k * m:(2 * k + 1) * m] += h_mm
        col[(2 * k + 1) * m:(2 * k + 2) * m] -= h_mm
        big[name] = col
    s, _ = _signal(mech, big, output)
    s = s.reshape(len(names), 2, m, -1)
    d = (s[:, 0] - s[:, 1]) / (2.0 * h_mm)
    return {c.joint: d[2 * i] + 1j * d[2 * i + 1] for i, c in enumerate(pairs)}


def radii(mech, which: str = "max") -> dict[str, float]:
    """joint -> radial clearance (mm) of each revolute pair: its largest ("max") or smallest
    ("min")."""
    if which not in ("min", "max"):
        raise ParameterError("clearance", "must be min or max", which)
    return {c.joint: (c.radial_max_mm if which == "max" else c.radial_min_mm)
            for c in revolute(mech)}


@dataclass(frozen=True)
class ClearanceWorstCase:
    """The first-order worst case of an output's signal under the pin clearances, per machine
    and angle: W = sum_j c_j |J_j| (`total`, signal unit), each pair's share c_j |J_j|
    (`by_pair`), and the offsets that reach +W (`argmax_mm`: joint -> complex r_j)."""

    output: str
    unit: str
    q_deg: np.ndarray
    total: np.ndarray
    by_pair: dict[str, np.ndarray]
    radius_mm: dict[str, float]
    argmax_mm: dict[str, np.ndarray] = field(default_factory=dict)

    def to_dataframe(self) -> pd.DataFrame:
        """One row per (machine, angle): W and each pair's c_j |J_j|."""
        m, k = self.total.shape
        f = pd.DataFrame({"machine": np.repeat(np.arange(m), k),
                          "q_deg": np.tile(self.q_deg, m),
                          f"W_{self.unit}": self.total.reshape(-1)})
        for j, v in self.by_pair.items():
            f[f"{j}_{self.unit}"] = v.reshape(-1)
        return f

    def shares(self) -> pd.DataFrame:
        """Each pair's share of W at the angle where W is largest, per machine (mean)."""
        k = np.nanargmax(np.nan_to_num(self.total, nan=-1.0), axis=-1)
        rows = np.arange(self.total.shape[0])
        tot = self.total[rows, k]
        return pd.DataFrame({"pair": list(self.by_pair),
                             "radial_mm": [self.radius_mm[j] for j in self.by_pair],
                             f"at_max_{self.unit}": [float(np.nanmean(v[rows, k]))
                                                     for v in self.by_pair.values()],
                             "share": [float(np.nanmean(v[rows, k] / tot))
                                       for v in self.by_pair.values()]})


def worst_case(mech, values: dict | None, output: str, clearance: str = "max",
               h_mm: float = H_MM) -> ClearanceWorstCase:
    """The worst case of `output`'s signal under the file's pin clearances (the radial clearance
    of each pair: its "max" or "min"), first order, per machine of `values` and angle."""
    c = radii(mech, clearance)
    jac = jacobian(mech, values, output, h_mm)
    by = {j: c[j] * np.abs(J) for j, J in jac.items()}
    # J_j . r_j = Re(conj(J_j) r_j) is largest at r_j = c_j J_j / |J_j| (as dx + i dy)
    arg = {j: c[j] * J / np.where(np.abs(J) > 0, np.abs(J), 1.0) for j, J in jac.items()}
    total = sum(by.values())
    return ClearanceWorstCase(output, mech.output(output).unit, np.degrees(mech.angles_rad()),
                              total, by, c, arg)


def random_offsets(mech, n: int, rng: np.random.Generator, *, rim: bool = False,
                   clearance: str = "max") -> dict[str, np.ndarray]:
    """Pair parameters of n machines: each journal uniform in its clearance circle (area-uniform),
    or on its rim (rim=True), of the pair's radial clearance ("max", "min", or "drawn": uniform
    between them per machine)."""
    if not isinstance(rng, np.random.Generator):
        raise ParameterError("rng", "must be a numpy Generator", type(rng).__name__)
    if clearance not in ("min", "max", "drawn"):
        raise ParameterError("clearance", "must be min, max or drawn", clearance)
    out = {}
    for c in revolute(mech):
        if clearance == "drawn":
            radius = rng.uniform(c.radial_min_mm, c.radial_max_mm, n)
        else:
            radius = np.full(n, c.radial_max_mm if clearance == "max" else c.radial_min_mm)
        t = rng.uniform(0.0, 2.0 * np.pi, n)
        rho = radius if rim else radius * np.sqrt(rng.uniform(0.0, 1.0, n))
        dx, dy = offset_names(c.joint)
        out[dx], out[dy] = rho * np.cos(t), rho * np.sin(t)
    return out


def fit_gap_um(fit: str, diameter_mm: float) -> tuple[float, float]:
    """The diametral clearance range (um) of a clearance fit (refused otherwise)."""
    f = iso_fit(fit, diameter_mm)
    if f.kind != "clearance":
        raise ParameterError("fit", f"must be a clearance fit for a guide that slides (this is "
                                    f"{f.kind})", fit)
    return f.clearance_min_um, f.clearance_max_um
