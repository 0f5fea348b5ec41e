"""Named frames of the 208: package data, API, CLI, and the residual table regenerated from the model."""

import json

import numpy as np
import pytest

from sewtol.cli import main
from sewtol.errors import ParameterError
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208 import calibration as cal
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME, frame_names, list_frames, load_frame, resolve
from sewtol.mechanisms.needle_208.model import Needle208, load_nominal_record


def test_at_least_the_named_frames_ship():
    names = frame_names()
    assert "sewtol-0.1" in names and "window" in names
    assert DEFAULT_FRAME in names


def test_sewtol_01_is_bit_for_bit_the_01_geometry():
    old = load_nominal_record()["params"]
    assert load_frame("sewtol-0.1").params == old
    assert Needle208.nominal("sewtol-0.1") == Needle208(**old)


def test_api_takes_a_name_a_frame_or_nothing():
    f = load_frame("window")
    assert Needle208.nominal(f) == Needle208.nominal("window") == Needle208(**f.params)
    assert Needle208.nominal() == Needle208.nominal(DEFAULT_FRAME)
    assert resolve(None).name == DEFAULT_FRAME


def test_unknown_frame_names_the_valid_ones():
    with pytest.raises(ParameterError) as exc:
        load_frame("nope")
    assert exc.value.field == "frame" and "sewtol-0.1" in str(exc.value)
    with pytest.raises(ParameterError):
        resolve(3.0)


def test_window_frame_reproduces_the_published_lm_direction():
    """Table 4.1: beta* 24 at LM's upper limit, 19 at its lower; the window frame's family has
    branch_M * beta_sense = +1, sewtol-0.1's -1 (its beta* moves the other way). beta* can sit on
    a plateau, so the near-sets (SumDelta within 0.1 um of the best, 0.01 deg grid) are compared,
    not the optimiser's pick: the whole UL near-set lies above (or below) the LL one."""
    betas = np.round(np.arange(19.0, 25.0 + 1e-9, 0.01), 10)
    for name, sign in (("window", 1.0), ("table41", 1.0), ("sewtol-0.1", -1.0)):
        f = load_frame(name)
        assert f.lm_direction == sign
        m = Needle208.nominal(f)
        sets = {}
        for side, lm in (("UL", 58.5), ("LL", 57.5)):
            c, _ = nm.columns(m.override(LM=lm))
            tot = sb.totals_on_grid(c, betas)[0]
            runs = cal._near_set(betas, tot, np.nanmin(tot))
            sets[side] = (runs[0][0], runs[-1][1])
        if sign > 0:
            assert sets["UL"][0] > sets["LL"][1], (name, sets)
        else:
            assert sets["UL"][1] < sets["LL"][0], (name, sets)


def test_stored_residual_table_regenerated_from_the_model():
    """Every model figure of the stored table against Table 4.1 is recomputed: Delta+/Delta- and
    2Delta to 1e-4 um (the extremes are exact to < 1e-3 um, identical code both times), the
    near-sets to one grid step, the model beta* inside its own near-set (not its bits: several
    rows are plateaus)."""
    for f in list_frames():
        rows, sign = cal.table41_residuals(Needle208.nominal(f), f.provenance["table41_guide_sign"])
        stored = [r for r in f.published if r["kind"] != "nominal"]
        assert len(rows) == len(stored)
        for new, old in zip(rows, stored, strict=True):
            assert (new["kind"], new["param"], new["side"]) == (old["kind"], old["param"],
                                                                 old["side"])
            assert new["published"] == old["published"]
            if new["kind"] == "beta":
                runs = new["near_set_deg"]
                assert any(a - 1e-9 <= new["model"] <= b + 1e-9 for a, b in runs)
                assert len(runs) == len(old["near_set_deg"])
                for (a, b), (c, d) in zip(runs, old["near_set_deg"], strict=True):
                    assert abs(a - c) <= 0.0100001 and abs(b - d) <= 0.0100001
                assert abs(new["distance_deg"] - old["distance_deg"]) <= 0.0100001
            else:
                assert abs(new["model"] - old["model"]) < 1e-4


def test_table_and_window_contradict_in_every_frame():
    """The note's argument, checked on each frame: LF -0.8 and AM +0.5 only shorten the rocker
    swing, so their SumDelta (beta in 19..25) never exceeds the nominal's; the table's 10.3 and
    10.2 um would need a nominal above the window's 10 um."""
    for f in list_frames():
        c = f.provenance["contradiction"]
        for key in ("LF_LL", "AM_UL"):
            assert c[key]["model_total_um"] <= c["nominal_total_um"] + 1e-6
            assert c[key]["published_total_um"] > 10.0
        m = Needle208.nominal(f)
        cm, _ = nm.columns(m)
        # the window ends as stored bound the nominal's SumDelta in 19..25 from above
        assert c["nominal_total_um"] <= max(sb.total_at(cm, 19.0)[0], sb.total_at(cm, 25.0)[0])


def test_cli_lists_frames_with_residuals(capsys):
    assert main(["needle", "frames", "--format", "json"]) == 0
    obj = json.loads(capsys.readouterr().out)
    # an object like every study's JSON: the context, then one full record per frame
    assert obj["context"] == {"mechanism": "208 needle drive", "default_frame": DEFAULT_FRAME}
    data = obj["rows"]
    assert len(data) >= 2 and [f["name"] for f in data] == frame_names()
    assert [f["name"] for f in data if f["default"]] == [DEFAULT_FRAME]
    for f in data:
        assert set(f["provenance"]["residuals"]) == set(f["provenance"]["targets"])
        assert any(r["kind"] == "delta" for r in f["published"])
    assert sum(f["default"] for f in data) == 1


def test_every_needle_command_takes_frame(capsys):
    assert main(["needle", "nominal", "--frame", "window", "--format", "json"]) == 0
    win = json.loads(capsys.readouterr().out)
    m = Needle208.nominal(load_frame("window"))
    assert win["A_mm"] == [m.Ax, m.Ay]
    for cmd in (["deviation", "--step-deg", "90"], ["scan"], ["montecarlo", "--n", "2"],
                ["sobol", "--n", "2"]):
        ns = __import__("sewtol.cli", fromlist=["build_parser"]).build_parser().parse_args(
            ["needle", *cmd, "--frame", "window"])
        assert ns.frame == "window"


def test_unknown_frame_on_the_command_line_is_one_line_exit_2(capsys):
    assert main(["needle", "nominal", "--frame", "nope"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "frame" in err and "nope" in err


def _calibration_script():
    from cli_helpers import study_script

    return study_script("calibrate_needle_208")


def test_calibration_report_uses_the_packaged_frames_and_never_writes_package_data(tmp_path):
    mod = _calibration_script()
    package = {p.name: p.read_bytes() for p in mod.PACKAGE_FRAMES.iterdir()}
    assert mod.main(["--stored", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "needle_208" / "calibration.md").read_text()
    for f in list_frames():
        assert f"## Frame `{f.name}`" in text
        # one geometry throughout: the report prints the packaged frame's numbers
        assert f"A = ({f.params['Ax']:.4f}, {f.params['Ay']:.4f}) mm" in text
        assert f"- beta = {f.params['beta']:.4f} deg" in text
    assert "singular values" in text and "poorly determined" in text
    # sewtol 0.1's --data flag: the default frame's record, nothing refitted
    assert mod.main(["--out", str(tmp_path), "--data", str(tmp_path / "g.json")]) == 0
    assert json.loads((tmp_path / "g.json").read_text())["params"] == load_frame(
        DEFAULT_FRAME).params
    assert {p.name: p.read_bytes() for p in mod.PACKAGE_FRAMES.iterdir()} == package


def test_calibration_script_refuses_an_unknown_frame(tmp_path, capsys):
    mod = _calibration_script()
    assert mod.main(["--frame", "nope", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--frame" in err and "nope" in err
    assert not (tmp_path / "needle_208").exists()


def test_frame_files_are_strict_json():
    from importlib import resources

    def refuse(c):
        raise ValueError(f"non-standard JSON constant {c}")

    folder = resources.files("sewtol.mechanisms.needle_208").joinpath("data", "frames")
    for name in frame_names():
        json.loads(folder.joinpath(f"{name}.json").read_text(), parse_constant=refuse)
