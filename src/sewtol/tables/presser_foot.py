"""The presser foot's tolerance tables: Monte-Carlo (the one sampler, `InputLaw.draw`) and
one-at-a-time scan of its contact cycle on the kernel (model.evaluate; docs/presser_foot.md).

Every machine gets a status (mechanisms.presser_foot.STATUS); the counts add up to n. Among
the "ok" machines three modes are counted as well: the principal interval began by the force
(the foot flew before the material), bounces at re-contact, and turns with more than one lost
interval (e.g. a hop off the seat on the way up besides the stop on the material).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from sewtol.law import InputLaw
from sewtol.mechanisms import params as P
from sewtol.mechanisms.presser_foot import model as PF
from sewtol.studies.montecarlo import check_sampling
from sewtol.tolerances import Tolerance, ToleranceSet

OUTPUTS = ("loss_deg", "regain_deg", "lost_deg", "separation_mm")
ANGLE_OUTPUTS = ("loss_deg", "regain_deg")

# Assumed tolerances (the source gives none): links as for the 208's links, the material level
# as the scatter of the fabric's thickness, spring rate, mass and preload +/-10 %.
PRESSER_SETS = {
    "assumed": ToleranceSet("assumed", (
        Tolerance("crank_mm", -0.02, 0.02), Tolerance("rod_mm", -0.05, 0.05),
        Tolerance("offset_mm", -0.05, 0.05), Tolerance("material_mm", -0.1, 0.1),
        Tolerance("stiffness_n_per_mm", -0.045, 0.045), Tolerance("mass_kg", -0.005, 0.005),
        Tolerance("preload_n", -0.8, 0.8)),
        "assumed: crank +/-0.02, rod and offset +/-0.05, material +/-0.1 mm; spring rate, "
        "mass and preload +/-10 %"),
    # the spring, mass and preload only: the family the table cannot tell apart
    "spring": ToleranceSet("spring", (
        Tolerance("stiffness_n_per_mm", -0.2233, 0.2233), Tolerance("mass_kg", -0.025, 0.025),
        Tolerance("preload_n", -4.0, 4.0)),
        "spring rate, mass and preload +/-50 %"),
}


def _unwrap(values: np.ndarray, about: float) -> np.ndarray:
    """Angles as nominal + deviation in (-180, 180] (regain sits near 0/360)."""
    return about + (np.asarray(values, float) - about + 180.0) % 360.0 - 180.0


def _frame(nominal: PF.PresserFoot, machines: PF.PresserFoot) -> pd.DataFrame:
    nom = PF.evaluate(nominal).to_dataframe().iloc[0]
    f = PF.evaluate(machines).to_dataframe()
    for k in ANGLE_OUTPUTS:
        if np.isfinite(nom[k]):
            f[k] = _unwrap(f[k], float(nom[k]))
    return f


@dataclass(frozen=True)
class PresserMonteCarlo:
    tolerances: str
    n: int
    seed: int
    machines: pd.DataFrame      # deviations, outputs and status per machine
    nominal: dict

    def counts(self) -> dict[str, int]:
        """Per status (adding up to n), then the modes among "ok" machines."""
        st = self.machines["status"].to_numpy()
        out = {s: int(np.sum(st == s)) for s in PF.STATUS}
        ok = st == "ok"
        out["ok_lost_by_force"] = int(np.sum(ok & self.machines["lost_by_force"].to_numpy()))
        out["ok_bounced"] = int(np.sum(ok & (self.machines["impacts"].to_numpy() > 0)))
        out["ok_several_intervals"] = int(np.sum(ok & (self.machines["intervals"].to_numpy()
                                                       > 1)))
        return out

    def summary_frame(self) -> pd.DataFrame:
        """Per output over the "ok" machines: nominal, mean, std, the 0.135 / 50 / 99.865 %
        quantiles, min and max (angles in shaft degrees, unwrapped about the nominal)."""
        ok = self.machines[self.machines["status"] == "ok"]
        rows = []
        for k in OUTPUTS:
            v = ok[k].to_numpy(float)
            q = np.quantile(v, [0.00135, 0.5, 0.99865]) if v.size else [math.nan] * 3
            rows.append({"output": k, "nominal": self.nominal[k], "n_ok": int(v.size),
                         "mean": float(v.mean()) if v.size else math.nan,
                         "std": float(v.std(ddof=1)) if v.size > 1 else math.nan,
                         "p0.135": q[0], "p50": q[1], "p99.865": q[2],
                         "min": float(v.min()) if v.size else math.nan,
                         "max": float(v.max()) if v.size else math.nan})
        return pd.DataFrame(rows)

    def to_dataframe(self) -> pd.DataFrame:
        return self.machines.copy()


def montecarlo(nominal: PF.PresserFoot, tolerances: ToleranceSet, n: int,
               seed: int) -> PresserMonteCarlo:
    """n machines drawn as every sewtol Monte-Carlo draws them (chunk i from child i of the
    seed), each run through the contact cycle."""
    check_sampling(nominal, tolerances, n, seed)
    dev = InputLaw.of(tolerances).draw(int(n), int(seed))
    machines = P.with_deviations(nominal, dev)
    f = _frame(nominal, machines)
    table = pd.DataFrame({k: v for k, v in dev.items()})
    table = pd.concat([table, f], axis=1)
    table.insert(0, "machine", np.arange(int(n)))
    nom = PF.evaluate(nominal).to_dataframe().iloc[0]
    return PresserMonteCarlo(tolerances.name, int(n), int(seed), table,
                             {k: float(nom[k]) for k in OUTPUTS})


def scan(nominal: PF.PresserFoot, tolerances: ToleranceSet) -> pd.DataFrame:
    """Each tolerance alone at its upper and lower limit: the outputs, their change from
    nominal (angles in shaft degrees) and the status."""
    tolerances.check_against(nominal)
    params, sides, deltas, dev = tolerances.limit_variants()
    machines = P.with_deviations(nominal, dev)
    f = _frame(nominal, machines)
    nom = PF.evaluate(nominal).to_dataframe().iloc[0]
    out = pd.DataFrame({"param": params, "side": sides, "deviation": deltas})
    for k in OUTPUTS:
        out[k] = f[k]
        out[f"d_{k}"] = f[k] - float(nom[k])
    out["status"] = f["status"]
    out["lost_by_force"] = f["lost_by_force"]
    return out
