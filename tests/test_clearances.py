"""Joint clearances in mechanism files ([[clearances]]): parsed into Clearance data (fits through
ISO 286), refused with the file's line, and not yet used by any evaluation."""

from pathlib import Path

import numpy as np
import pytest

from sewtol.errors import ParameterError
from sewtol.mechanism import loads
from sewtol.mechanism.clearance import Clearance

M6 = Path(__file__).resolve().parents[1] / "examples" / "m6_needle.toml"
BASE = M6.read_text()
# M6: revolute joints O1 (crank centre), A (crank pin, the rpr block), O2 (rpr pivot), J and B
# (the rrp joint and its p1); prismatic pairs f (block A in the slotted arm) and J (needle bar)
CLEARANCES = """
[[clearances]]
joint = "J"
pair = "prismatic"
fit = "H7/g6"
diameter_mm = 8
length_mm = 30
doc = "needle bar in its guide"

[[clearances]]
joint = "B"
radial_mm = [0.002, 0.01]

[[clearances]]
joint = "O1"
radial_mm = 0.005

[[clearances]]
joint = "f"
pair = "prismatic"
gap_mm = [0.01, 0.03]
length_mm = 12
"""


def test_clearances_load_as_data_and_change_no_output():
    mech = loads(BASE + CLEARANCES, "m6.toml")
    guide, pin, crank, slot = mech.clearances
    first = BASE.count("\n") + 2  # the line of the first [[clearances]]
    # H7/g6 at 8 mm: hole 0/+15 um, shaft -5/-14 um (ISO 286-1 Tables 1-2): 5 to 29 um
    assert guide == Clearance(joint="J", pair="prismatic", clearance_min_mm=0.005,
                              clearance_max_mm=0.029, length_mm=30.0, fit="H7/g6",
                              diameter_mm=8.0, doc="needle bar in its guide", line=first)
    assert (guide.radial_min_mm, guide.radial_max_mm) == (0.0025, 0.0145)
    # a radial clearance c is half the diametral range the pair stores
    assert (pin.pair, pin.clearance_min_mm, pin.clearance_max_mm) == ("revolute", 0.004, 0.02)
    assert (pin.radial_min_mm, pin.radial_max_mm, pin.length_mm) == (0.002, 0.01, None)
    assert (crank.clearance_min_mm, crank.clearance_max_mm, crank.fit) == (0.01, 0.01, None)
    assert (slot.joint, slot.clearance_min_mm, slot.clearance_max_mm, slot.length_mm) == (
        "f", 0.01, 0.03, 12.0)
    assert loads(BASE, "m6.toml").clearances == ()
    # data only: every output of every machine is what the file without clearances gives
    values = {"rod_mm": [67.9, 68.0, 68.1]}
    with_c = mech.evaluate(values).outputs
    without = loads(BASE, "m6.toml").evaluate(values).outputs
    assert with_c.keys() == without.keys()
    for name in with_c:
        np.testing.assert_array_equal(with_c[name], without[name])


@pytest.mark.parametrize(("snippet", "key", "rule"), [
    ('joint = "E"\nradial_mm = 0.01', "joint",
     "must name a joint point of a crank, rrr, rrp or rpr group: A, B, J, O1, O2"),
    ('joint = "B"\npair = "prismatic"\ngap_mm = 0.01\nlength_mm = 5', "joint",
     "must name an rrp, rpr or spatial_slider group: J, f"),
    ('joint = "B"\npair = "ball"\nradial_mm = 0.01', "pair", "must be one of revolute, prismatic"),
    # H7/p6 at 8 mm: p6 ei = +15 = IT7, so the largest clearance is 0
    ('joint = "B"\nfit = "H7/p6"\ndiameter_mm = 8', "fit",
     "must be a clearance fit for a pair that moves (this is interference: -24 to 0 um)"),
    ('joint = "B"\nfit = "H7/k6"\ndiameter_mm = 8', "fit", "this is transition: -10 to 14 um"),
    ('joint = "B"\nfit = "H7/g6"', "diameter_mm", "goes with fit, and fit needs it"),
    ('joint = "B"\nfit = "H7/g6"\ndiameter_mm = 600', "diameter_mm",
     "must be a diameter over 0 up to and including 500 mm"),
    ('joint = "B"\nfit = "G7/h6"\ndiameter_mm = 8', "fit", "the hole must be H"),
    ('joint = "B"\nradial_mm = 0.01\nfit = "H7/g6"\ndiameter_mm = 8', "radial_mm",
     "give exactly one of radial_mm, fit"),
    ('joint = "B"', "radial_mm", "give exactly one of radial_mm, fit"),
    ('joint = "B"\nradial_mm = [0.01, 0.002]', "radial_mm", "must be a number >= 0 or [min, max]"),
    ('joint = "B"\nradial_mm = -0.01', "radial_mm", "must be a number >= 0 or [min, max]"),
    ('joint = "B"\ngap_mm = 0.01', "gap_mm", "is not a key of a revolute pair (give radial_mm)"),
    ('joint = "B"\nradial_mm = 0.01\nlength_mm = 5', "length_mm",
     "is a key of a prismatic pair only"),
    ('joint = "J"\npair = "prismatic"\ngap_mm = 0.01', "length_mm",
     "is required for a prismatic pair"),
    ('joint = "J"\npair = "prismatic"\ngap_mm = 0.01\nlength_mm = 0', "length_mm",
     "must be a positive length in mm"),
    ('joint = "B"\nradial_mm = 0.01\nclearance_mm = 0.01', "clearance_mm", "unknown key; allowed"),
])
def test_bad_clearances_are_refused_at_their_line(snippet, key, rule):
    text = BASE + "\n[[clearances]]\n" + snippet + "\n"
    with pytest.raises(ParameterError) as err:
        loads(text, "m6.toml")
    lines = text.splitlines()
    at = next((i for i in range(len(lines) - 1, -1, -1) if lines[i].startswith(f"{key} =")),
              lines.index("[[clearances]]")) + 1
    assert err.value.field == f"m6.toml:{at}: [[clearances]] #1.{key}"
    assert rule in err.value.rule


def test_a_second_clearance_on_the_same_pair_and_a_clearances_table_are_refused():
    twice = BASE + CLEARANCES + '\n[[clearances]]\njoint = "B"\nradial_mm = 0.003\n'
    with pytest.raises(ParameterError, match=r"#5.joint: has a revolute clearance already "
                                             r"\(got 'B'\)"):
        loads(twice, "m6.toml")
    # a prismatic and a revolute clearance at J are two pairs
    both = BASE + CLEARANCES + '\n[[clearances]]\njoint = "J"\nradial_mm = 0.003\n'
    assert [c.pair for c in loads(both, "m6.toml").clearances if c.joint == "J"] == [
        "prismatic", "revolute"]
    with pytest.raises(ParameterError, match=r"\[\[clearances\]\]: must be an array of tables"):
        loads(BASE + '\n[clearances]\nB = 0.01\n', "m6.toml")


def test_a_prismatic_pairs_tilt_is_its_gap_over_its_length():
    c = Clearance("J", "prismatic", 0.005, 0.029, length_mm=30.0)
    assert c.tilt_max_deg == pytest.approx(np.degrees(np.arctan(0.029 / 30.0)), rel=1e-15)
    assert Clearance("B", "revolute", 0.005, 0.029).tilt_max_deg is None
