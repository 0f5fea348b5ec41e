"""Mechanisms as data: a TOML file that reads like the drawing, checked, then evaluated by the
generic engine (docs/mechanism_files.md).

    from sewtol.mechanism import load
    mech = load("src/sewtol/mechanisms/needle_208/mechanism.toml")
    ev = mech.evaluate({"LF": [6.70, 6.75, 6.80]})
    ev.outputs["SumDelta_um"], ev.status

New group types and output kinds register themselves here (register_group, register_output);
studies over a FileMechanism live in sewtol.studies.generic.
"""

from sewtol.mechanism.expressions import ExpressionError
from sewtol.mechanism.expressions import parse as parse_expression
from sewtol.mechanism.groups import GROUPS, register_group
from sewtol.mechanism.loader import load, loads
from sewtol.mechanism.model import DEAD_POINT_DEG, Evaluation, FileMechanism, State
from sewtol.mechanism.outputs import OUTPUT_TYPES, OUTPUTS, register_output
from sewtol.mechanism.spec import Spec

__all__ = [
    "DEAD_POINT_DEG", "Evaluation", "ExpressionError", "FileMechanism", "GROUPS", "OUTPUTS",
    "OUTPUT_TYPES", "Spec", "State", "load", "loads", "parse_expression", "register_group",
    "register_output",
]
