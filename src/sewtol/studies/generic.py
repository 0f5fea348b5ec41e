"""Studies of any mechanism file (sewtol.mechanism.FileMechanism) and its outputs.

Nothing here names a mechanism: a study takes the mechanism, a tolerance set and the output(s)
it looks at, and returns a frozen result with to_dataframe() and to_dict(). The scan, the
worst case, the Monte-Carlo and the Sobol indices are sewtol.studies.scan, worst_case,
montecarlo and sobol.

- nominal: every output of the nominal machine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from sewtol.errors import AssemblyError


@dataclass(frozen=True)
class NominalResult:
    mechanism: str
    rows: pd.DataFrame  # output, unit, value, doc

    def to_dataframe(self) -> pd.DataFrame:
        return self.rows

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "status": "ok",
                "outputs": {r["output"]: r["value"] for r in self.rows.to_dict("records")},
                "rows": self.rows.to_dict("records")}


def nominal(mech) -> NominalResult:
    """Every output of the nominal machine; AssemblyError if it cannot run a full turn."""
    ev = mech.evaluate()
    if ev.status[0] != "ok":
        g, status = ev.failed_group[0], ev.status[0]
        state = mech.state()
        cl = state.closures[g]
        if status == "cannot_close":
            miss = np.nan_to_num(np.broadcast_to(cl.miss_mm, state.shape)[0], nan=np.inf)
            k = int(np.argmax(miss))
            raise AssemblyError(g, np.degrees(state.q_rad[k]), float(miss[k]),
                                mech.nominal_values(), "driving angle q of "
                                f"{mech.path}; the nominal machine cannot make a full turn")
        t = np.broadcast_to(cl.transmission_deg, state.shape)[0]
        k = int(np.nanargmin(t))
        raise AssemblyError(g, np.degrees(state.q_rad[k]), 0.0, mech.nominal_values(),
                            f"driving angle q of {mech.path}; dead point: the links are "
                            f"{float(t[k]):.3f} deg from collinear (< 1), the joint can flip to "
                            "its other assembly (branch flip)")
    rows = pd.DataFrame([{"output": o.name, "unit": o.unit, "value": float(ev.outputs[o.name][0]),
                          "doc": o.doc} for o in mech.outputs])
    return NominalResult(mech.name, rows)


