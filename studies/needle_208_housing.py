"""The housing tolerances' share of the 208's SumDelta, on the set base_housing.

The housing features (the upper-shaft bore A, the rear-rocker pivot bore D, the guide bore's
point N1 and direction; ASSUMED tolerances, docs/needle_208.md "Housing tolerances") against the
links (LF, LM, AM, AB, BC, BE): per parameter and summed per group,

- the Sobol total index ST of SumDelta with beta fixed at the nominal beta* and with beta
  adjusted per machine (sewtol.studies.sobol; ST shares: each ST over the sum of ST);
- the correlation-ratio share (eta^2, `montecarlo.contributors`) of the SumDelta left after
  beta + guide shift, over the machines that run (the strategies study's
  `failure_contributors`).

Writes reports/needle_208/housing_share.csv/.md (one row per parameter, then one per group) and
housing_share.json (the same plus `headline`: one sentence the index page can quote).

    python studies/needle_208_housing.py [--out reports] [--seed 2026] [--n-sobol 1024]
        [--n 2000] [--n-jobs 1]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd

from sewtol.io import write_text_atomic
from sewtol.mechanisms.needle_208.compensators import exact, strategy_of
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.provenance import now, run_record
from sewtol.reports import plots
from sewtol.reports.tables import write_table
from sewtol.tables.needle_208 import needle_sobol, strategies_table
from sewtol.tolerances import NEEDLE_208_HOUSING, NEEDLE_208_HOUSING_SETS

SET = "base_housing"
HOUSING = tuple(t.param for t in NEEDLE_208_HOUSING)


def share_table(sobol: pd.DataFrame, eta: pd.DataFrame) -> pd.DataFrame:
    """Per parameter: its group, ST with beta fixed and adjusted, the ST shares (% of the sum
    of ST of the case) and the eta^2 share after beta + shift (%); then one row per group (the
    sums)."""
    st = sobol.pivot(index="param", columns="case", values="ST")
    params = list(dict.fromkeys(sobol.param))
    rows = []
    for p in params:
        rows.append({"param": p, "group": "housing" if p in HOUSING else "link",
                     "ST_fixed_beta": float(st.loc[p, "fixed_beta"]),
                     "ST_adjusted_beta": float(st.loc[p, "adjusted_beta"])})
    f = pd.DataFrame(rows)
    for case in ("fixed_beta", "adjusted_beta"):
        col = f[f"ST_{case}"].clip(lower=0.0)  # a small negative ST is estimator noise
        f[f"ST_share_{case}_pct"] = 100 * col / col.sum()
    f["eta2_share_beta_shift_pct"] = f.param.map(eta.set_index("param")["share_all_pct"])
    groups = f.groupby("group", sort=False).sum(numeric_only=True).reset_index()
    groups.insert(0, "param", [f"{g} (all {int((f.group == g).sum())})" for g in groups.group])
    return pd.concat([f, groups], ignore_index=True)


def headline(table: pd.DataFrame, n_sobol: int, n: int) -> str:
    g = table[table.param.str.startswith("housing (")].iloc[0]
    return (f"With the assumed housing tolerances (base_housing: bores A, D and the guide at "
            f"+/-0.02 mm, the guide's direction +/-0.0229 deg), the housing carries "
            f"{g.ST_share_fixed_beta_pct:.0f} % of SumDelta's Sobol total indices with beta "
            f"fixed, {g.ST_share_adjusted_beta_pct:.0f} % with beta adjusted, and "
            f"{g.eta2_share_beta_shift_pct:.0f} % of its scatter after beta + guide shift "
            f"(Sobol N = {n_sobol}, {n} machines; the links the rest).")


def main(argv=None) -> int:
    ap = plots.study_parser(__doc__, jobs=True, n_sobol=1024, n=2000)
    args = ap.parse_args(argv)
    started = now()
    out = Path(args.out) / "needle_208"
    out.mkdir(parents=True, exist_ok=True)
    p, ts = Needle208.nominal(), NEEDLE_208_HOUSING_SETS[SET]
    sob = needle_sobol(p, ts, args.n_sobol, args.seed, n_jobs=args.n_jobs).to_dataframe()
    row = exact(strategy_of(("beta", "guide_shift_um"), name="beta+shift"))
    eta = strategies_table(p, ts, args.n, args.seed, [row],
                           n_jobs=args.n_jobs).failure_contributors("beta+shift")
    table = share_table(sob, eta)
    line = headline(table, args.n_sobol, args.n)
    settings = {"tolerances": f"{SET} ({ts.description})", "seed": args.seed,
                "Sobol N": args.n_sobol, "machines (eta^2)": args.n,
                "ST_*": "Sobol total index of SumDelta (beta fixed at the nominal beta* / "
                        "adjusted per machine); ST_share_*_pct: % of the sum of ST (negative "
                        "estimates counted as 0)",
                "eta2_share_beta_shift_pct": "correlation-ratio share of the SumDelta left "
                                             "after beta + guide shift (machines that run)",
                "housing": ", ".join(HOUSING) + " (assumed tolerances, docs/needle_208.md)"}
    write_table(table, out, "housing_share", "Housing tolerances against the links, "
                "208 needle drive (base_housing)", {"headline": line, **settings})
    write_text_atomic(out / "housing_share.json", json.dumps(
        {"headline": line, "tolerances": SET, "seed": args.seed, "n_sobol": args.n_sobol,
         "n": args.n, "rows": table.to_dict("records"),
         "run": run_record(started, {"study": "housing_share", "seed": args.seed,
                                     "n_sobol": args.n_sobol, "n": args.n})},
        indent=2) + "\n")
    print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
