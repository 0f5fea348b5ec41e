"""The `sewtol` command: a thin layer over the library. Only this and study scripts write files."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from .errors import AssemblyError, ParameterError

FORMATS = ("table", "json", "csv")


class CliError(Exception):
    pass


def parse_sets(items, cls) -> dict:
    """--set NAME=VALUE pairs checked against the parameter names of `cls`."""
    from .mechanisms.params import field_names

    valid = field_names(cls)
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError("--set", "must be NAME=VALUE", item)
        name, _, text = item.partition("=")
        name = name.strip()
        if name not in valid:
            raise ParameterError(name, f"unknown parameter; valid names are {', '.join(valid)}",
                                 name)
        try:
            value = float(text)
        except ValueError:
            raise ParameterError(name, "must be a number", text) from None
        out[name] = value
    return out


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def emit(fmt: str, *, obj=None, frame=None) -> None:
    if fmt == "json":
        data = obj if obj is not None else frame.to_dict(orient="records")
        sys.stdout.write(json.dumps(data, indent=2, default=_json_default, allow_nan=True) + "\n")
    elif fmt == "csv":
        sys.stdout.write(frame.to_csv(index=False, float_format="%.9g", lineterminator="\n"))
    else:
        sys.stdout.write(frame.to_markdown(index=False, floatfmt=".4f") + "\n")


def _needle_params(args):
    from .mechanisms.needle_208 import Needle208

    return Needle208.nominal().override(**parse_sets(args.set, Needle208))


def cmd_needle_nominal(args):
    from .needle import nominal_figures

    fig = nominal_figures(_needle_params(args), tuple(args.beta_range), args.limit_um)
    if args.format == "csv":
        raise CliError("--format: nominal prints json or table, not csv")
    emit(args.format, obj=fig.to_dict(), frame=fig.to_dataframe())


def cmd_needle_deviation(args):
    from .needle import deviation_table

    if not (0 < args.step_deg <= 90):
        raise ParameterError("--step-deg", "must be in (0, 90]", args.step_deg)
    p = _needle_params(args)
    if args.beta is not None:
        p = p.override(beta=args.beta)
    frame = deviation_table(p, args.step_deg)
    emit(args.format, frame=frame)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="sewtol", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="group", required=True)
    needle = sub.add_parser("needle", help="208-class needle drive")
    nsub = needle.add_subparsers(dest="command", required=True)

    def common(p):
        p.add_argument("--set", action="append", metavar="NAME=VALUE",
                       help="override a parameter (repeatable), e.g. --set LF=6.8")
        p.add_argument("--format", choices=FORMATS, default="table")

    p = nsub.add_parser("nominal", help="beta*, deviation figures, window, guide, stroke")
    common(p)
    p.add_argument("--beta-range", nargs=2, type=float, default=[10.0, 35.0],
                   metavar=("LOW", "HIGH"), help="regulating range searched for beta* (deg)")
    p.add_argument("--limit-um", type=float, default=10.0, help="SumDelta limit of the window")
    p.set_defaults(func=cmd_needle_nominal)

    p = nsub.add_parser("deviation", help="E and d(phi) over one crank turn")
    common(p)
    p.add_argument("--beta", type=float, default=None, help="beta (deg); default: the nominal")
    p.add_argument("--step-deg", type=float, default=1.0, help="crank-angle step (deg)")
    p.set_defaults(func=cmd_needle_deviation)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (ParameterError, AssemblyError, CliError) as exc:
        print(f"sewtol: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
