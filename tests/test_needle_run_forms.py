"""`sewtol needle STUDY` and `sewtol run needle_208 STUDY` are one command: for every needle
study with a run form the two print the same JSON, without flags (the file's [defaults] adjust =
["beta"] is the needle's own default) and with the flags both take (the same name, the same
meaning). The differences that remain are listed in docs/cli.md. `sewtol feed STUDY` is `sewtol
run feed_131 STUDY` (the same parser and function): the same bytes in every format and folder."""

from __future__ import annotations

import pytest

from cli_helpers import run, strict_loads

# three tolerances (8 corners) keep worst-case, sobol and allocation small; same widths as base
SMALL = "[sets.small]\nLF = 0.05\nAB = 0.05\nBE = 0.05\n"

# each study at a small size; the flags are given alike to both commands
DEFAULTS = {
    "scan": (),
    "worst-case": ("--tolerances", "{small}"),
    "montecarlo": ("--n", "40", "--seed", "3"),
    "sobol": ("--n", "16", "--seed", "3", "--tolerances", "{small}"),
    "ppm": ("--n", "200", "--seed", "2"),
    "allocation": ("--n", "40", "--tolerances", "{small}"),
    "strategies": ("--n", "20", "--seed", "1"),
}
# flags of the same name and meaning in both forms (--n is needle ppm's --budget, --limit its
# --limit-um, --method mc its montecarlo, --adjust none "beta stays at the nominal's beta*")
SHARED = {
    "scan": ("--adjust", "none", "--set", "CD=30.01"),
    "worst-case": ("--tolerances", "{small}", "--set", "CD=30.01"),
    "montecarlo": ("--n", "40", "--seed", "5", "--limit", "8", "--n-jobs", "1",
                   "--tolerances", "recommended"),
    "ppm": ("--n", "300", "--seed", "4", "--limit", "8", "--method", "mc", "--target", "0.01",
            "--adjust", "none"),
    "allocation": ("--n", "40", "--seed", "2", "--target", "0.99", "--adjust", "none",
                   "--tolerances", "{small}"),
    "strategies": ("--n", "20", "--seed", "4", "--n-jobs", "1", "--set", "CD=30.01"),
}


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    path = tmp_path_factory.mktemp("tol") / "small.toml"
    path.write_text(SMALL)
    return f"{path}:small"


def _both(study, flags, small, fmt="json"):
    argv = [a.format(small=small) for a in flags]
    a = run("needle", study, *argv, "--format", fmt)
    b = run("run", "needle_208", study, *argv, "--format", fmt)
    assert a[0] == 0 and b[0] == 0, a[2] + b[2]
    return a, b


@pytest.mark.parametrize("study", list(DEFAULTS))
def test_the_needle_command_and_its_run_form_print_the_same_json(study, small):
    a, b = _both(study, DEFAULTS[study], small)
    assert a[1] == b[1] and a[2] == b[2] == ""
    obj = strict_loads(a[1])
    assert obj["context"]["mechanism"] == "needle_208" and obj["context"]["path"] == "needle_208"
    if study in ("scan", "ppm", "allocation"):  # beta adjusted on each machine, as the source
        assert obj["context"]["strategy"] == "beta"


@pytest.mark.parametrize("study", list(SHARED))
def test_the_flags_both_forms_take_mean_the_same(study, small):
    a, b = _both(study, SHARED[study], small)
    assert a[1] == b[1] and a[2] == b[2] == ""


def test_adjust_none_turns_the_files_default_off():
    """`run needle_208 ppm` adjusts beta (the file's default) and prints the needle's numbers;
    --adjust none holds beta at the nominal's beta* and fails more machines (the same draws)."""
    argv = ("--n", "400", "--seed", "2", "--method", "mc", "--target", "0.01")
    adjusted = strict_loads(run("run", "needle_208", "ppm", *argv, "--format", "json")[1])
    fixed = strict_loads(run("run", "needle_208", "ppm", *argv, "--adjust", "none",
                             "--format", "json")[1])
    assert adjusted["adjust"] == "beta" and fixed["adjust"] == "none"
    assert adjusted["failures"] < fixed["failures"]


# `sewtol feed STUDY` is `sewtol run feed_131 STUDY` under another name: the same flags (run's
# parser) and the same output, on the file's first set (links) in both forms without flags
FEED = {
    "scan": ("--set", "b=25", "--tolerances", "assumed"),
    "montecarlo": ("--n", "30", "--seed", "2", "--output", "lower_step_mm", "--adjust", "b",
                   "--objective", "target=2.2"),
    "sobol": ("--n", "16", "--seed", "3", "--output", "lower_step_mm"),
}


@pytest.mark.parametrize("fmt", ["json", "csv", "text"])  # text: run's name of table
@pytest.mark.parametrize("study", list(FEED))
def test_the_feed_command_is_its_run_form_in_every_format(study, fmt):
    a = run("feed", study, *FEED[study], "--format", fmt)
    b = run("run", "feed_131", study, *FEED[study], "--format", fmt)
    assert a[0] == b[0] == 0 and a[2] == b[2] == "", a[2] + b[2]
    assert a[1] == b[1] and a[1]
    if fmt == "json":
        ctx = strict_loads(a[1])["context"]
        assert ctx["mechanism"] == "feed_131"
        assert ctx["tolerances"] == ("assumed" if study == "scan" else "links")


def test_the_feed_default_set_is_the_files_first_in_both_forms():
    """Without --tolerances both forms study `links`, the file's first set (its six lower-dog
    links): 12 rows per output, so worst-case's corners stay few on the default set."""
    from sewtol.mechanism import load
    from sewtol.mechanisms import mechanism_file

    mech = load(mechanism_file("feed_131"))
    a, b = (strict_loads(run(*form, "scan", "--format", "json")[1])
            for form in (("feed",), ("run", "feed_131")))
    assert a == b and a["tolerances"] == next(iter(mech.tolerance_sets)) == "links"
    assert {r["param"] for r in a["rows"]} == set(mech.tolerance_sets["links"].params)


def test_the_feed_study_folder_is_its_run_forms_but_for_the_command_line(tmp_path):
    argv = ("montecarlo", "--n", "30", "--seed", "2")
    a = run("feed", *argv, "--out", str(tmp_path / "a"))
    b = run("run", "feed_131", *argv, "--out", str(tmp_path / "b"))
    assert a[0] == b[0] == 0 and a[1] == b[1]
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "b").iterdir())
    assert {"montecarlo.json", "machines.csv", "summary.csv", "run.json"} <= set(names)
    for name in names:
        x, y = ((tmp_path / d / name).read_bytes() for d in "ab")
        if name != "run.json":
            assert x == y, name
            continue
        x, y = strict_loads(x), strict_loads(y)
        for k in ("command_line", "started_utc", "finished_utc"):
            x.pop(k), y.pop(k)
        assert x == y


def test_the_feed_refuses_as_run_refuses():
    for argv in (("sobol", "--n", "100"), ("scan", "--n-jobs", "2"),
                 ("montecarlo", "--objective", "target=2")):
        a, b = run("feed", *argv), run("run", "feed_131", *argv)
        assert a[0] == b[0] == 2 and a[1] == b[1] == "" and a[2] == b[2], argv
        assert len(a[2].strip().splitlines()) == 1
