"""`sewtol needle STUDY ARGS` is `sewtol run needle_208 STUDY ARGS` for every study of the
needle_208 fast path: the same parser (the same namespace for any flags), the same function,
so the same bytes in every format, in the study folder and in the figure. The flags of the
needle plug-in (--frame, --beta-range, --limit-um, --housing, ...) are flags of `run`, refused
in one line where nothing reads them. ALIASES is keyed by alias; `needle guides` is `run
needle_208 settings` (RUN_STUDY), `needle largest-tolerances` the generic study on the plug-in.
`sewtol feed STUDY` is `sewtol run feed_131 STUDY` (the same parser and function): the same
bytes in every format and folder."""

from __future__ import annotations

import pytest

from cli_helpers import run, strict_loads

# three tolerances (8 corners) keep worst-case, sobol and allocation small; same widths as base
SMALL = "[sets.small]\nLF = 0.05\nAB = 0.05\nBE = 0.05\n"

# alias -> (the run form's first words, [(study, flags given alike to both forms)])
ALIASES = {
    "needle": (("run", "needle_208"), [
        ("scan", ()),
        ("scan", ("--adjust", "none", "--set", "CD=30.01")),
        ("scan", ("--adjust", "beta,guide_shift_um", "--frame", "window", "--housing")),
        ("scan", ("--limit-um", "8", "--beta-range", "22", "23", "--guide-shift-um", "20")),
        ("worst-case", ("--tolerances", "{small}")),
        ("worst-case", ("--tolerances", "{small}", "--adjust", "beta", "--beta-range", "23.5",
                        "24")),
        ("montecarlo", ("--n", "40", "--seed", "3")),
        ("montecarlo", ("--n", "40", "--seed", "5", "--limit", "8", "--tolerances",
                        "recommended", "--housing")),
        ("montecarlo", ("--n", "40", "--adjust", "beta,guide_shift_um", "--step",
                        "guide_shift_um=10")),
        ("sobol", ("--n", "16", "--seed", "3", "--tolerances", "{small}")),
        ("sobol", ("--n", "16", "--tolerances", "{small}", "--second-order", "--adjust",
                   "beta")),
        ("ppm", ("--n", "200", "--seed", "2")),
        ("ppm", ("--budget", "300", "--seed", "4", "--limit-um", "8", "--method", "mc",
                 "--target", "0.01", "--adjust", "none")),
        ("allocation", ("--n", "40", "--tolerances", "{small}")),
        ("allocation", ("--n", "40", "--seed", "2", "--target", "0.99", "--adjust", "beta",
                        "--tolerances", "{small}")),
        ("strategies", ("--n", "20", "--seed", "1")),
        ("strategies", ("--n", "20", "--adjust", "guide_angle", "--measurement-error", "1",
                        "--measured-positions", "12", "--set", "CD=30.01")),
        ("guides", ("--n", "20", "--seed", "1")),
        ("guides", ("--n", "20", "--tolerances", "{small}", "--adjust", "beta,guide_shift_um",
                    "--limit-um", "8", "--beta-range", "20", "26", "--housing")),
        ("largest-tolerances", ("--tolerances", "{small}")),
        ("largest-tolerances", ("--tolerances", "{small}", "--adjust", "none", "--limit", "12",
                                "--set", "CD=30.01")),
    ]),
}
# the alias whose run form names the study otherwise
RUN_STUDY = {"guides": "settings"}
CASES = [(alias, study, flags) for alias, (_, rows) in ALIASES.items()
         for study, flags in rows]
IDS = [" ".join((alias, study, *flags)).replace("{small}", "S") for alias, study, flags in CASES]


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    path = tmp_path_factory.mktemp("tol") / "small.toml"
    path.write_text(SMALL)
    return f"{path}:small"


def _forms(alias, study, flags, small):
    argv = [a.format(small=small) for a in flags]
    return [alias, study, *argv], [*ALIASES[alias][0], RUN_STUDY.get(study, study), *argv]


@pytest.mark.parametrize("alias,study,flags", CASES, ids=IDS)
def test_the_alias_parses_to_the_run_forms_namespace(alias, study, flags, small):
    from sewtol.cli import build_parser

    a, b = (vars(build_parser().parse_args(f)) for f in _forms(alias, study, flags, small))
    for ns in (a, b):
        ns.pop("group")
        ns.pop("command", None)
    assert a == b


# the needle's strategies table of each set of arguments, computed once for the six runs of a
# case (two forms, three formats): ~10 CPU-s a run with --measurement-error, whatever n
_STRATEGIES = {}


@pytest.fixture
def strategies_once(monkeypatch):
    """`tables.needle_208.strategies_table` answering a call whose arguments pickle to the same
    bytes as an earlier call's with (a copy of) that call's result. Both forms reach it with
    the arguments they parsed: an alias that passed anything else (another n, seed, set,
    strategy, reading) computes its own table, and what each form prints from the table is
    still compared byte for byte."""
    import copy
    import pickle

    from sewtol.tables import needle_208 as T

    real = T.strategies_table

    def once(*args, **kwargs):
        try:
            key = pickle.dumps((args, sorted(kwargs.items())))
        except (pickle.PicklingError, TypeError, AttributeError):
            return real(*args, **kwargs)
        if key not in _STRATEGIES:
            _STRATEGIES[key] = real(*args, **kwargs)
        return copy.deepcopy(_STRATEGIES[key])

    monkeypatch.setattr(T, "strategies_table", once)


@pytest.mark.parametrize("fmt", ["json", "csv", "table"])
@pytest.mark.parametrize("alias,study,flags", CASES, ids=IDS)
def test_the_alias_prints_the_run_forms_bytes(alias, study, flags, fmt, small, strategies_once):
    a, b = (run(*f, "--format", fmt) for f in _forms(alias, study, flags, small))
    assert a[0] == b[0] == 0, a[2] + b[2]
    assert a[1] == b[1] and a[2] == b[2] == ""
    if fmt == "json":
        ctx = strict_loads(a[1])["context"]
        assert ctx["mechanism"] == "needle_208" and ctx["path"] == "needle_208"


@pytest.mark.parametrize("study,flags,files", [
    ("scan", ("--plot", "{d}/f.svg"), ("scan.json", "scan.csv", "f.svg")),
    ("montecarlo", ("--n", "40", "--plot", "{d}/f.svg"),
     ("montecarlo.json", "machines.csv", "summary.csv", "f.svg")),
    ("ppm", ("--n", "200", "--seed", "2"), ("ppm.json", "levels.csv")),
    ("strategies", ("--n", "20", "--plot", "{d}/f.svg"), ("strategies.json", "f.svg")),
    ("largest-tolerances", ("--tolerances", "recommended"),
     ("largest_tolerances.json", "largest_tolerances.csv")),
    # the guide's settings write no study folder (--out leaves the fast path): the figure alone
    ("guides", ("--n", "20", "--plot", "{d}/f.svg"), ("f.svg",)),
])
def test_the_alias_writes_the_run_forms_files(study, flags, files, tmp_path):
    a, b = tmp_path / "alias", tmp_path / "run"
    folder = any(not name.endswith(".svg") for name in files)
    for d, words in ((a, ("needle", study)), (b, ("run", "needle_208", RUN_STUDY.get(study,
                                                                                     study)))):
        argv = [f.format(d=d) for f in flags]
        d.mkdir()
        code, _, err = run(*words, *argv, *(("--out", str(d / "out")) if folder else ()),
                           "--format", "json")
        assert code == 0, err
    for name in files:
        where = "" if name.endswith(".svg") else "out/"
        assert (a / where / name).read_bytes() == (b / where / name).read_bytes(), name
    if folder:
        ra, rb = (strict_loads((d / "out" / "run.json").read_text())["inputs"] for d in (a, b))
        assert ra == rb and ra["mechanism_file"] == "needle_208"


@pytest.mark.parametrize("alias", ["guides", "largest-tolerances"])
def test_the_alias_helps_with_the_run_forms_flags(alias):
    """`--help` of both forms: the same flags, each with the same help (the usage line names
    the command as given)."""
    a, b = run("needle", alias, "--help"), run("run", "needle_208", RUN_STUDY.get(alias, alias),
                                               "--help")
    assert a[0] == b[0] == 0 and a[2] == b[2] == ""
    assert a[1].split("\noptions:\n")[1] == b[1].split("\noptions:\n")[1]
    assert "--beta-range" in a[1] and "--limit-um" in a[1] and "--tolerances" in a[1]


@pytest.mark.parametrize("argv,message", [
    # a plug-in flag on another mechanism, on a study that does not read it, off the fast path
    (("run", "khujand_feed", "montecarlo", "--n", "10", "--frame", "window"),
     "--frame: is read by the needle_208 fast path only; `run khujand_feed montecarlo` has none"),
    (("needle", "worst-case", "--limit-um", "8"), "--limit-um: is not used by `run worst-case`"),
    (("needle", "allocation", "--beta-range", "10", "30"),
     "--beta-range: is not used by `run allocation`"),
    (("needle", "scan", "--housing", "--path", "generic"),
     "--housing: is read by the needle_208 fast path only, which this run leaves (--path "
     "generic)"),
    (("needle", "montecarlo", "--n", "10", "--lower-limit", "1", "--beta-range", "10", "30"),
     "--beta-range: is read by the needle_208 fast path only, which this run leaves "
     "(--lower-limit: the needle commands limit SumDelta from above only)"),
    (("needle", "ppm", "--budget", "300", "--n", "300"),
     "--budget: is --n in the needle's words; give one of them"),
    (("needle", "guides", "--n", "20", "--out", "x", "--housing"),
     "--housing: is read by the needle_208 fast path only, which this run leaves (--out: "
     "`needle guides` writes no study folder)"),
    (("needle", "largest-tolerances", "--limit-um", "8"),
     "--limit-um: is not used by `run largest-tolerances`"),
    # a study without a figure off the fast path (scan, montecarlo, sobol and refine have one)
    (("run", "feed_131", "worst-case", "--plot", "x.svg"),
     "--plot: is read by the needle_208 fast path only; `run feed_131 worst-case` has none"),
    (("run", "feed_131", "ppm", "--plot", "x.svg"), "--plot: is not used by `run ppm`"),
])
def test_a_flag_nothing_reads_is_refused_in_one_line(argv, message):
    code, out, err = run(*argv)
    assert code == 2 and out == "" and err == f"sewtol: error: {message} (got " + \
        err.split("(got ", 1)[1]
    assert len(err.strip().splitlines()) == 1


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
# parser) and the same output, on the file's first set (links) in both forms without flags.
# Three machines: the forms' bytes agree or not whatever n, and each machine the generic
# adjuster brings to the objective costs both forms about 0.5 CPU-s in each of three formats
FEED = {
    "scan": ("--set", "b=25", "--tolerances", "assumed"),
    "montecarlo": ("--n", "3", "--seed", "2", "--output", "lower_step_mm", "--adjust", "b",
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


# the figures' runs: the default set (six links), every output, a panel each
FEED_PLOTS = {"scan": (), "montecarlo": ("--n", "30", "--seed", "2"), "sobol": FEED["sobol"]}


@pytest.mark.parametrize("study", list(FEED_PLOTS))
def test_the_feed_figure_is_its_run_forms_and_a_rerun_is_the_same(study, tmp_path):
    """`feed STUDY --plot` draws run's figure: the same SVG bytes in both forms and on a rerun,
    and the figure changes nothing printed."""
    plain = run("feed", study, *FEED_PLOTS[study], "--format", "json")
    outs = []
    for name, form in (("a", ("feed",)), ("b", ("run", "feed_131")), ("c", ("feed",))):
        code, out, err = run(*form, study, *FEED_PLOTS[study], "--format", "json", "--plot",
                             str(tmp_path / f"{name}.svg"))
        assert code == 0 and err == "", err
        outs.append(out)
    a, b, c = ((tmp_path / f"{name}.svg").read_bytes() for name in "abc")
    assert a == b == c and a.startswith(b"<?xml")
    assert outs == [plain[1]] * 3
