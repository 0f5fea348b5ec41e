"""User tolerance sets from TOML: accepted forms and the errors for bad files."""

import pytest

from sewtol.errors import ParameterError
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.mechanisms.params import field_names
from sewtol.tolerances import NEEDLE_208_SETS, load_toml, resolve

VALID = field_names(Needle208)


def write(tmp_path, text):
    p = tmp_path / "tol.toml"
    p.write_text(text)
    return p


def test_sets_from_toml(tmp_path):
    p = write(tmp_path, """
[sets.housing]
description = "frame pivots too"
LF = { lower = -0.05, upper = 0.02, dist = "truncnorm" }
CD = { plus_minus = 0.01 }
Ax = 0.02
""")
    sets = load_toml(p, VALID)
    ts = sets["housing"]
    assert ts.params == ["LF", "CD", "Ax"]
    assert (ts.items[0].lower, ts.items[0].upper, ts.items[0].dist) == (-0.05, 0.02, "truncnorm")
    assert (ts.items[2].lower, ts.items[2].upper) == (-0.02, 0.02)
    assert resolve(str(p), NEEDLE_208_SETS, VALID).name == "housing"
    assert resolve(f"{p}:housing", NEEDLE_208_SETS, VALID).name == "housing"


def test_malformed_toml_reports_line_and_column(tmp_path):
    p = write(tmp_path, "[sets.x]\nLF = { lower = -0.05, upper = }\n")
    with pytest.raises(ParameterError, match=r"is not valid TOML.*line 2, column"):
        load_toml(p, VALID)


@pytest.mark.parametrize("body,message", [
    ("[sets.x]\nQQ = 0.1\n", "QQ: unknown parameter in tolerance set 'x'; valid names are LF"),
    ("[sets.x]\nLF = { lower = 0.1, upper = -0.1 }\n", "LF.lower: must not be above the upper"),
    ("[sets.x]\nLF = { lower = 0.1 }\n", "x.LF: needs both lower and upper"),
    ("[sets.x]\nLF = { plus_minus = -1 }\n", "x.LF.plus_minus: must not be negative"),
    ("[sets.x]\nLF = { pm = 1 }\n", "x.LF: unknown keys ['pm']"),
    ("title = 'no sets'\n", "must hold at least one [sets.NAME] table"),
])
def test_bad_sets_name_field_and_rule(tmp_path, body, message):
    with pytest.raises(ParameterError) as exc:
        load_toml(write(tmp_path, body), VALID)
    assert message in str(exc.value)


def test_missing_file_and_unknown_set(tmp_path):
    with pytest.raises(ParameterError, match="cannot be read"):
        load_toml(tmp_path / "none.toml", VALID)
    p = write(tmp_path, "[sets.a]\nLF = 0.1\n[sets.b]\nLM = 0.1\n")
    with pytest.raises(ParameterError, match="name one as FILE.toml:NAME, one of a, b"):
        resolve(str(p), NEEDLE_208_SETS, VALID)
    with pytest.raises(ParameterError, match="no set 'c' in the file"):
        resolve(f"{p}:c", NEEDLE_208_SETS, VALID)
