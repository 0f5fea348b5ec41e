"""The presser foot's tables: the generic Monte-Carlo, scan and output summary (sewtol.studies)
on the folder's mechanism.toml (outputs of kind presser_contact: the contact cycle and its
modes; the tolerance sets), read in the model's words: its field names (crank_mm, ... for the
file's r, ...), a STATUS word per machine (counts add up to n; cannot_assemble where the
crank-slider cannot run), the modes among "ok" machines, and the circular loss and regain
angles as the nominal machine's plus a deviation in (-180, 180] (docs/presser_foot.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
import pandas as pd

from sewtol.mechanism.loader import builtin
from sewtol.mechanisms.presser_foot import model as PF
from sewtol.studies import summaries as SU
from sewtol.tolerances import ToleranceSet

OUTPUTS = ("loss_deg", "regain_deg", "lost_deg", "separation_mm")
ANGLE_OUTPUTS = ("loss_deg", "regain_deg")
MODES = ("contact_status", "impacts", "intervals", "lost_by_force")
LEVELS = (0.00135, 0.5, 0.99865)  # p0.135 and p99.865: the +/-3 sigma equivalents


@cache
def field_names() -> dict[str, str]:
    """The file's parameter -> the model's field, as its presser_contact outputs map them."""
    out = next(o for o in builtin("presser_foot").outputs if o.kind == "presser_contact")
    return {e.text: k for k, e in out.fields.items()
            if getattr(e, "text", None) in builtin("presser_foot").parameter_names}


def as_mechanism(nominal: PF.PresserFoot):
    """The folder's mechanism file with the machine's values as its nominals."""
    return builtin("presser_foot").override(**{p: float(getattr(nominal, f))
                                               for p, f in field_names().items()})


def tolerance_sets() -> dict[str, ToleranceSet]:
    """The file's sets: assumed, and spring (the family the source's table cannot tell apart)."""
    return dict(builtin("presser_foot").tolerance_sets)


def _read(f: pd.DataFrame, nominal: dict) -> pd.DataFrame:
    """Machines in the model's words (see the module docstring)."""
    f = f.rename(columns=field_names())
    code = f.pop("contact_status").to_numpy(float)
    words = np.asarray(PF.STATUS, object)[np.nan_to_num(code).astype(int)]
    f["status"] = np.where((f["status"] == "ok") & np.isfinite(code), words,
                           "cannot_assemble").astype(str)
    f["lost_by_force"] = f["lost_by_force"].to_numpy(float) == 1.0
    for k in ANGLE_OUTPUTS:
        if np.isfinite(nominal[k]):
            f[k] = nominal[k] + (f[k].to_numpy(float) - nominal[k] + 180.0) % 360.0 - 180.0
    return f.drop(columns="failed_group")


def _nominal(mech) -> dict[str, float]:
    ev = mech.evaluate(None, OUTPUTS)
    return {k: float(ev.outputs[k][0]) for k in OUTPUTS}


@dataclass(frozen=True)
class PresserMonteCarlo:
    tolerances: str
    n: int
    seed: int
    machines: pd.DataFrame      # deviations, outputs, modes and status per machine
    nominal: dict

    def counts(self) -> dict[str, int]:
        """Per status (adding up to n), then the modes among "ok" machines."""
        m, ok = self.machines, self.machines["status"].to_numpy() == "ok"
        return {**{s: int(np.sum(m["status"].to_numpy() == s)) for s in PF.STATUS},
                "ok_lost_by_force": int(np.sum(ok & m["lost_by_force"].to_numpy())),
                "ok_bounced": int(np.sum(ok & (m["impacts"].to_numpy() > 0))),
                "ok_several_intervals": int(np.sum(ok & (m["intervals"].to_numpy() > 1)))}

    def summary_frame(self) -> pd.DataFrame:
        """Per output over the "ok" machines (summaries.output_summary): nominal, mean, std,
        the 0.135 / 50 / 99.865 % quantiles, min and max (angles about the nominal)."""
        f = SU.output_summary(self.machines, OUTPUTS, LEVELS, self.machines["status"] == "ok",
                              self.nominal)
        f.insert(2, "n_ok", f.pop("n") - f.pop("failed"))
        return f

    def to_dataframe(self) -> pd.DataFrame:
        return self.machines.copy()


def montecarlo(nominal: PF.PresserFoot, tolerances: ToleranceSet, n: int,
               seed: int) -> PresserMonteCarlo:
    """n machines of the one sampler (sewtol.studies.montecarlo on the file)."""
    from sewtol.studies.montecarlo import montecarlo as mc

    mech = as_mechanism(nominal)
    nom = _nominal(mech)
    res = mc(mech, tolerances, n, seed, OUTPUTS + MODES)
    return PresserMonteCarlo(tolerances.name, int(n), int(seed), _read(res.machines, nom), nom)


def scan(nominal: PF.PresserFoot, tolerances: ToleranceSet) -> pd.DataFrame:
    """Each tolerance alone at its limits (sewtol.studies.scan on the file): the outputs, their
    change from nominal (d_OUTPUT), the status and whether the foot flew."""
    from sewtol.studies.scan import scan as generic_scan

    mech, names = as_mechanism(nominal), OUTPUTS + ("contact_status", "lost_by_force")
    nom, r = _nominal(mech), generic_scan(mech, tolerances, names)
    t = SU.scan_table(r, names).assign(status=r.rows["status"].to_numpy()[::len(names)],
                                        failed_group="")
    t = _read(t, nom).assign(param=lambda f: f["param"].map(field_names()))
    for k in OUTPUTS:
        t[f"d_{k}"] = t[k] - nom[k]
    return t[["param", "side", "deviation", *(c for k in OUTPUTS for c in (k, f"d_{k}")),
              "status", "lost_by_force"]]
