"""Issue 23 part 2: ISO 286 fits held to the standard's table values, and `sewtol fit`.

T1 = ISO 286-1:2010 Table 1 (standard tolerance values IT, um); T2 = Table 2 (fundamental
deviations of shafts a to j: the upper deviation es); T3 = Table 3 (shafts k to zc: the lower
deviation ei). A hole H has EI = 0 and ES = +IT; a shaft a..h has ei = es - IT; a shaft k..u has
es = ei + IT; js is +/- IT/2. Size rows are "over a up to and including b" (mm)."""

import time

import pytest

from cli_helpers import run, strict_loads
from sewtol.errors import ParameterError
from sewtol.fits import iso_fit

# (fit, diameter mm, part, upper um, lower um, where the value is in the standard)
TABLE = [
    ("H7/h6", 25, "hole", 21, 0, "T1 IT7, over 18 to 30: 21"),
    ("H7/h6", 30, "hole", 21, 0, "T1 IT7, over 18 to 30: 21 (30 mm is the row's upper limit)"),
    ("H7/h6", 30.001, "hole", 25, 0, "T1 IT7, over 30 to 50: 25"),
    ("H8/f7", 8, "hole", 22, 0, "T1 IT8, over 6 to 10: 22"),
    ("H5/h5", 10, "hole", 6, 0, "T1 IT5, over 6 to 10: 6"),
    ("H9/d9", 18, "hole", 43, 0, "T1 IT9, over 10 to 18: 43"),
    ("H10/h10", 6, "hole", 48, 0, "T1 IT10, over 3 to 6: 48"),
    ("H11/c11", 400, "hole", 360, 0, "T1 IT11, over 315 to 400: 360"),
    ("H7/h6", 8, "shaft", 0, -9, "T1 IT6, over 6 to 10: 9; T2 h: es = 0"),
    ("H7/h6", 50, "shaft", 0, -16, "T1 IT6, over 30 to 50: 16 (50 mm is the row's upper limit)"),
    ("H7/g6", 25, "shaft", -7, -20, "T2 g, over 18 to 30: -7; T1 IT6, over 18 to 30: 13"),
    ("H7/g6", 200, "shaft", -15, -44, "T2 g, over 180 to 250: -15; T1 IT6, over 180 to 250: 29"),
    ("H8/f7", 8, "shaft", -13, -28, "T2 f, over 6 to 10: -13; T1 IT7, over 6 to 10: 15"),
    ("H7/f7", 3, "shaft", -6, -16, "T2 f, up to 3: -6; T1 IT7, up to 3: 10"),
    ("H8/e8", 8, "shaft", -25, -47, "T2 e, over 6 to 10: -25; T1 IT8, over 6 to 10: 22"),
    ("H7/e7", 500, "shaft", -135, -198, "T2 e, over 400 to 500: -135; T1 IT7, over 400 to 500: 63"),
    ("H9/d9", 40, "shaft", -80, -142, "T2 d, over 30 to 50: -80; T1 IT9, over 30 to 50: 62"),
    ("H11/c11", 45, "shaft", -130, -290, "T2 c, over 40 to 50: -130; T1 IT11, over 30 to 50: 160"),
    ("H7/k6", 8, "shaft", 10, 1, "T3 k (IT4 to IT7), over 6 to 10: +1; T1 IT6, over 6 to 10: 9"),
    ("H8/k8", 20, "shaft", 33, 0, "T3 k (above IT7), all sizes: 0; T1 IT8, over 18 to 30: 33"),
    ("H7/m6", 12, "shaft", 18, 7, "T3 m, over 10 to 18: +7; T1 IT6, over 10 to 18: 11"),
    ("H7/m6", 0.5, "shaft", 8, 2, "T3 m, up to 3: +2; T1 IT6, up to 3: 6"),
    ("H7/n6", 100, "shaft", 45, 23, "T3 n, over 80 to 120: +23; T1 IT6, over 80 to 120: 22"),
    ("H7/p6", 25, "shaft", 35, 22, "T3 p, over 18 to 30: +22; T1 IT6, over 18 to 30: 13"),
    ("H7/s6", 60, "shaft", 72, 53, "T3 s, over 50 to 65: +53; T1 IT6, over 50 to 80: 19"),
    ("H7/u6", 24, "shaft", 54, 41, "T3 u, over 18 to 24: +41; T1 IT6, over 18 to 30: 13"),
    ("H7/u6", 25, "shaft", 61, 48, "T3 u, over 24 to 30: +48; T1 IT6, over 18 to 30: 13"),
    ("H7/js6", 25, "shaft", 6.5, -6.5, "js6 = +/- IT6/2; T1 IT6, over 18 to 30: 13"),
]


@pytest.mark.parametrize(("fit", "diameter", "part", "upper", "lower", "where"), TABLE,
                         ids=[f"{r[0]}@{r[1]}-{r[2]}" for r in TABLE])
def test_limits_equal_the_standard_tables(fit, diameter, part, upper, lower, where):
    f = iso_fit(fit, diameter)
    assert (getattr(f, f"{part}_upper_um"), getattr(f, f"{part}_lower_um")) == (upper, lower), where


def test_the_table_covers_grades_letters_and_sizes():
    assert len(TABLE) >= 20
    assert {int(r[0].split("/")[0][1:]) for r in TABLE if r[2] == "hole"} == {5, 7, 8, 9, 10, 11}
    assert {r[0].split("/")[1].rstrip("0123456789") for r in TABLE if r[2] == "shaft"} == {
        "c", "d", "e", "f", "g", "h", "js", "k", "m", "n", "p", "s", "u"}


@pytest.mark.parametrize(("fit", "diameter", "clearance", "kind"), [
    ("H7/g6", 25, (7, 41), "clearance"),      # hole 0/+21, shaft -20/-7
    ("H7/h6", 25, (0, 34), "clearance"),      # zero minimum clearance is still a clearance fit
    ("H7/k6", 8, (-10, 14), "transition"),    # hole 0/+15, shaft +1/+10
    ("H7/p6", 25, (-35, -1), "interference"),  # hole 0/+21, shaft +22/+35
])
def test_clearance_range_and_kind(fit, diameter, clearance, kind):
    f = iso_fit(fit, diameter)
    assert (f.clearance_min_um, f.clearance_max_um) == clearance and f.kind == kind
    assert f.hole_it_um + f.shaft_it_um == f.clearance_max_um - f.clearance_min_um


@pytest.mark.parametrize(("fit", "diameter", "field", "rule"), [
    ("H7g6", 8, "fit", "must be a hole-basis ISO 286 fit"),
    (" H7/g6", 8, "fit", "must be a hole-basis ISO 286 fit"),
    (7, 8, "fit", "must be a hole-basis ISO 286 fit"),
    ("G7/h6", 8, "fit", "the hole must be H"),
    ("H7/z6", 8, "fit", "the shaft letter must be one of c, d, e"),
    ("H7/G6", 8, "fit", "the shaft letter must be one of"),
    ("H12/g6", 8, "fit", "IT grades must be 5 to 11"),
    ("H7/g6", 0, "diameter_mm", "over 0 up to and including 500 mm"),
    ("H7/g6", 500.001, "diameter_mm", "over 0 up to and including 500 mm"),
    ("H7/g6", float("inf"), "diameter_mm", "over 0 up to and including 500 mm"),
    ("H7/g6", True, "diameter_mm", "over 0 up to and including 500 mm"),
])
def test_bad_fits_and_diameters_name_field_rule_and_value(fit, diameter, field, rule):
    with pytest.raises(ParameterError) as err:
        iso_fit(fit, diameter)
    assert err.value.field == field and rule in err.value.rule
    assert err.value.value is (fit if field == "fit" else diameter)


def test_parsing_a_long_hostile_string_is_fast():
    """The pattern has no nested quantifiers: a 10^6-character near miss fails in linear time."""
    for text in ("H" * 10**6, "H7/" + "g" * 10**6, "H7/g6" * 200_000):
        start = time.perf_counter()
        with pytest.raises(ParameterError):
            iso_fit(text, 8)
        assert time.perf_counter() - start < 0.5


def test_cli_prints_the_limits_and_the_clearance_range():
    code, out, err = run("fit", "H7/g6", "25")
    assert code == 0 and err == ""
    assert "H7/g6 at 25 mm: clearance fit" in out
    assert "hole  H7    IT7 = 21 um   +21 / 0 um   25.0210 / 25.0000 mm" in out
    assert "shaft g6    IT6 = 13 um   -7 / -20 um   24.9930 / 24.9800 mm" in out
    assert "clearance 7 to 41 um" in out
    code, out, err = run("fit", "H8/f7", "8", "--format", "json")
    assert code == 0 and err == ""
    got = strict_loads(out)
    assert (got["clearance_min_um"], got["clearance_max_um"]) == (13.0, 50.0)
    assert (got["hole_upper_um"], got["hole_lower_um"]) == (22.0, 0.0)
    assert (got["shaft_upper_um"], got["shaft_lower_um"]) == (-13.0, -28.0)
    assert (got["hole_grade"], got["shaft_grade"], got["kind"]) == (8, 7, "clearance")
    assert got["source"].startswith("ISO 286-1:2010")


@pytest.mark.parametrize(("argv", "message"), [
    (("fit", "H7/x6", "8"), "fit: the shaft letter must be one of"),
    (("fit", "H7/g6", "eight"), "DIAMETER_MM: must be a number (mm) (got 'eight')"),
    (("fit", "H7/g6", "501"), "DIAMETER_MM: must be a diameter over 0 up to and including 500 mm"),
])
def test_cli_refuses_bad_input_in_one_line(argv, message):
    code, out, err = run(*argv)
    assert code == 2 and out == "" and err.count("\n") == 1 and message in err
