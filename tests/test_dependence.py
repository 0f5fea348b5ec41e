"""Tolerance sets that declare dependence (sewtol.dependence) and mean shifts: the forms, the
refusals, and the copula held to OpenTURNS and to closed forms."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from sewtol.dependence import Dependence
from sewtol.errors import ParameterError
from sewtol.mechanism import loads
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.mechanisms.params import field_names
from sewtol.tolerances import Tolerance, load_toml

VALID = field_names(Needle208)
NEEDLE_FILE = Path(__file__).parents[1] / "src/sewtol/mechanisms/needle_208/mechanism.toml"


def one_set(tmp_path, text):
    p = tmp_path / "tol.toml"
    p.write_text("[sets.x]\nAB = 0.05\nBE = 0.05\nBC = 0.05\nLF = 0.05\n" + text)
    return load_toml(p, VALID)["x"]


def test_pairs_matrix_and_setup_make_one_matrix(tmp_path):
    ts = one_set(tmp_path, 'correlation = [["BE", "AB", 0.9]]\n'
                 'setup = [{ params = ["BC", "LF"], share = 0.5 }]\n')
    dep = ts.dependence
    # the set's order, not the file's
    assert dep.params == ("AB", "BE", "BC", "LF")
    np.testing.assert_array_equal(dep.array, [[1, .9, 0, 0], [.9, 1, 0, 0], [0, 0, 1, .5],
                                              [0, 0, .5, 1]])
    full = one_set(tmp_path, 'correlation = { params = ["AB", "BE"], matrix = [[1, 0.9], '
                   '[0.9, 1]] }\n').dependence
    assert full.params == ("AB", "BE") and full.matrix == ((1.0, 0.9), (0.9, 1.0))
    # a set without either key is independent; a zero-width member leaves the active copula
    assert one_set(tmp_path, "").dependence is None
    assert ts.scaled({"BC": 0.0}).active().dependence.params == ("AB", "BE")
    assert ts.scaled({"AB": 0.0, "BC": 0.0}).active().dependence is None


@pytest.mark.parametrize("text,message", [
    ('correlation = [["AB", "BE", 0.9], ["AB", "BC", 0.9], ["BE", "BC", -0.9]]\n',
     "x.correlation: must be positive semi-definite (no set of parameters AB, BE, BC has these "
     "correlations); its smallest eigenvalue is -0.8"),
    ('correlation = { params = ["AB", "BE"], matrix = [[1, 0.9], [0.8, 1]] }\n',
     "x.correlation: must be symmetric"),
    ('correlation = [["AB", "CD", 0.5]]\n', "x.correlation[0]: names 'CD', not a parameter of "
     "the set (AB, BE, BC, LF)"),
    ('correlation = [["AB", "BE", 1.2]]\n', "x.correlation[AB, BE]: must be a correlation within "
     "[-1, 1] (got 1.2)"),
    ('correlation = [["AB", "AB", 0.5]]\n', "x.correlation[0]: must pair two different"),
    ('correlation = [["AB", "BE", 0.5]]\nsetup = [{ params = ["BE", "AB"] }]\n',
     "x.setup[0]: gives the pair BE, AB a second time (first in x.correlation[0])"),
    ('setup = [{ params = ["AB", "BE"], share = 0 }]\n', "x.setup[0].share: must be the setup"),
    ('correlation = [["AB", 0.5]]\n', 'x.correlation[0]: must be ["A", "B", rho]'),
])
def test_bad_dependence_refused_in_one_line(tmp_path, text, message):
    with pytest.raises(ParameterError) as exc:
        one_set(tmp_path, text)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_mechanism_file_sets_declare_dependence_too():
    text = NEEDLE_FILE.read_text() + '\n[tolerances.tied]\nAB = 0.05\nBE = 0.05\n' \
        'correlation = [["AB", "BE", 0.9]]\n'
    assert loads(text).tolerance_sets["tied"].dependence.matrix == ((1.0, 0.9), (0.9, 1.0))
    with pytest.raises(ParameterError, match=r"\[tolerances.bad\]: bad.correlation\[AB, BE\]: "
                       "must be a correlation within"):
        loads(text + '[tolerances.bad]\nAB = 0.05\nBE = 0.05\ncorrelation = [["AB", "BE", 2]]\n')


@pytest.mark.parametrize("r", [[[1, 0.9], [0.9, 1]], [[1, .3, -.5], [.3, 1, .2], [-.5, .2, 1]],
                               [[1, 0.999], [0.999, 1]]])
def test_copula_equals_openturns_normal_copula(r):
    ot = pytest.importorskip("openturns")
    u = np.random.default_rng(4).random((2000, len(r)))
    dep = Dependence(tuple("ABC"[:len(r)]), tuple(map(tuple, r)))
    ref = np.array(ot.NormalCopula(ot.CorrelationMatrix(r)).getInverseIsoProbabilisticTransformation()(
        stats.norm.ppf(u)))
    np.testing.assert_allclose(dep.ranks(u), ref, rtol=0, atol=1e-12)
    # the first parameter's rank is the one drawn (common random numbers with the product law)
    np.testing.assert_allclose(dep.ranks(u)[:, 0], u[:, 0], rtol=0, atol=1e-12)


def test_copula_closed_forms():
    u = np.random.default_rng(7).random((200_000, 3))
    rho = 0.9
    ranks = Dependence(("A", "B", "C"), ((1, rho, 0), (rho, 1, 0), (0, 0, 1))).ranks(u)
    # Gaussian copula: Spearman's rho_S = (6 / pi) arcsin(rho / 2), Kendall's tau = (2 / pi)
    # arcsin(rho); standard error of both < 0.002 at this n
    assert stats.spearmanr(ranks[:, 0], ranks[:, 1])[0] == pytest.approx(
        6 / np.pi * np.arcsin(rho / 2), abs=0.004)
    z = stats.norm.ppf(ranks)
    assert np.corrcoef(z.T)[0, 1] == pytest.approx(rho, abs=0.002)
    assert abs(np.corrcoef(z.T)[0, 2]) < 0.01
    # a one-setup group with share 1 is singular: its members draw the same rank, exactly
    same = Dependence(("A", "B", "C"), ((1, 1, 1), (1, 1, 1), (1, 1, 1))).ranks(u)
    np.testing.assert_array_equal(same[:, 1], same[:, 0])
    np.testing.assert_array_equal(same[:, 2], same[:, 0])
    # share s: every pair of the group correlated s, and L L^T = R
    dep = Dependence(("A", "B", "C"), ((1, .6, .6), (.6, 1, .6), (.6, .6, 1)))
    np.testing.assert_allclose(dep.factor() @ dep.factor().T, dep.array, atol=1e-15)


def test_mean_shift_and_cpk(tmp_path):
    ts = one_set(tmp_path, 'CD = { plus_minus = 0.03, dist = "normal", shift = 0.01 }\n'
                 'LM = { lower = -0.3, upper = 0.3, dist = "truncnorm", shift = -0.05 }\n')
    cd, lm = ts.items[-2:]
    assert cd.mean == pytest.approx(0.01) and cd.cpk == pytest.approx(2 / 3)
    u = np.random.default_rng(1).random(400_000)
    x = cd.from_unit(u)
    assert x.mean() == pytest.approx(0.01, abs=3e-5) and x.std() == pytest.approx(0.01, rel=5e-3)
    # truncnorm: the shifted normal cut at the limits, so its mean is the closed form
    y = lm.from_unit(u)
    a, b = (-0.3 + 0.05) / 0.1, (0.3 + 0.05) / 0.1
    assert y.min() >= -0.3 and y.max() <= 0.3
    assert y.mean() == pytest.approx(stats.truncnorm.mean(a, b, -0.05, 0.1), abs=3e-4)
    assert ts.scaled({"CD": 2}).items[-2].shift == pytest.approx(0.02)
    assert lm.salib_dist() == ("truncnorm", [-0.3, 0.3, -0.05, pytest.approx(0.1)])


def test_shift_refusals():
    with pytest.raises(ParameterError, match="CD.shift: needs dist normal or truncnorm"):
        Tolerance("CD", -0.03, 0.03, "uniform", 0.01)
    with pytest.raises(ParameterError, match=r"CD.shift: must keep the mean inside the limits"):
        Tolerance("CD", -0.03, 0.03, "normal", 0.03)


def test_law_draws_the_joint_law_with_the_same_seed_contract():
    from sewtol.law import InputLaw, draw_units, unit_streams
    from sewtol.tolerances import NEEDLE_208_SETS

    base = NEEDLE_208_SETS["base"]
    n, seed = 20_000, 5
    ind = InputLaw.of(base)
    assert ind.independent
    # the independent law draws today's machines, byte for byte
    today = base.active().from_unit(draw_units(unit_streams(seed, n), len(base.items), 0, n))
    for k, v in ind.draw(n, seed).items():
        np.testing.assert_array_equal(v, today[k])
    tied = replace(base, dependence=Dependence(("AB", "BE"), ((1, 0.9), (0.9, 1))))
    law = InputLaw.of(tied)
    assert not law.independent
    dev = law.draw(n, seed)
    # every parameter not tied to an earlier one keeps its draw (AB through Phi(Phi^-1(u)))
    for k in ("LF", "LM", "AM", "BC"):
        np.testing.assert_array_equal(dev[k], today[k])
    np.testing.assert_allclose(dev["AB"], today["AB"], rtol=0, atol=1e-15)
    assert stats.spearmanr(dev["AB"], dev["BE"])[0] == pytest.approx(
        6 / np.pi * np.arcsin(0.45), abs=0.01)
    # sample(rng) = deviations(sample_unit(rng)), the copula inside sample_unit
    a = law.sample(np.random.default_rng(3), 50)
    b = law.deviations(law.sample_unit(np.random.default_rng(3), 50))
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_monte_carlo_and_strategies_draw_the_joint_law():
    from sewtol.mechanism import load
    from sewtol.studies import montecarlo as mc
    from sewtol.studies.montecarlo import montecarlo as montecarlo_study
    from sewtol.studies.strategies import strategies

    mech = load(Path(__file__).parent / "data" / "crank_slider.toml")
    tol = replace(mech.tolerance_sets["normal"],
                  dependence=Dependence(("r", "L"), ((1, -0.95), (-0.95, 1))))
    want = mc.draw_deviations(tol, 620, 11)
    assert np.corrcoef(want["r"], want["L"])[0, 1] == pytest.approx(-0.95, abs=0.01)
    for chunk in (mc.CHUNK, 150):
        m = mc.sample_machines(lambda nom, dev: {"x": dev["r"]}, mech.parameter_record(), tol,
                               620, 11, chunk_size=chunk)
        for k in want:
            np.testing.assert_array_equal(m[k], want[k])
    m = montecarlo_study(mech, tol, 620, 11).machines
    s = strategies(mech, tol, 620, 11)
    for k in want:
        np.testing.assert_array_equal(m[k], want[k])
        np.testing.assert_array_equal(s.deviations[k], want[k])


def test_sobol_refuses_a_correlated_law_in_one_line(tmp_path):
    from cli_helpers import run
    from sewtol.mechanism import load
    from sewtol.studies.sobol import sobol

    mech = load(Path(__file__).parent / "data" / "crank_slider.toml")
    tol = replace(mech.tolerance_sets["normal"],
                  dependence=Dependence(("r", "L"), ((1, 0.5), (0.5, 1))))
    with pytest.raises(ParameterError, match=r"^tolerances: ties r, L \(a correlation\); Sobol "
                       r"indices need independent inputs: use the Shapley effects"):
        sobol(mech, tol, mech.outputs[0].name, 16, 0)
    p = tmp_path / "tied.toml"
    p.write_text('[sets.tied]\nAB = 0.05\nBE = 0.05\ncorrelation = [["AB", "BE", 0.9]]\n')
    for argv in (("run", "needle_208", "sobol"), ("needle", "sobol")):
        code, out, err = run(*argv, "--tolerances", f"{p}:tied", "--n", "16")
        assert code == 2 and out == ""
        assert err == ("sewtol: error: --tolerances: ties AB, BE (a correlation); Sobol indices "
                       "need independent inputs: use the Shapley effects (sewtol run NAME "
                       "shapley) (got 'tied')\n")


def test_allocation_keeps_the_copula(monkeypatch):
    from sewtol.mechanism import load
    from sewtol.studies import allocation as AL
    from sewtol.studies import montecarlo as mc

    mech = load(Path(__file__).parent / "data" / "crank_slider.toml")
    tol = replace(mech.tolerance_sets["normal"],
                  dependence=Dependence(("r", "L"), ((1, 0.8), (0.8, 1))))
    calls = []
    monkeypatch.setattr(AL, "machines", lambda m, dev: calls.append(dev) or
                        {k: m.nominal_values()[k] + v for k, v in dev.items()})
    a = AL.allocate(mech, tol, "stroke_mm", 0.9, upper=20.02, lower=19.98, n=300, seed=4)
    assert a.as_tolerance_set().dependence == tol.dependence
    # one trial (the reported scale) drew the allocated set's machines, copula included
    want = mc.draw_deviations(a.as_tolerance_set(), 300, 4)
    assert any(all(np.allclose(d[k], v, rtol=1e-12, atol=0) for k, v in want.items())
               for d in calls)


def test_a_study_folder_records_the_copula_so_a_tied_run_never_resumes_untied_chunks(tmp_path):
    """The needle path's manifest binds its chunks to the set's dependence as run.json does:
    the same items with a correlation are another study (refused, not resumed). In this
    process: the folder is the point, not the process boundary."""
    from cli_helpers import run

    untied = tmp_path / "untied.toml"
    untied.write_text("[sets.s]\nAB = 0.05\nBE = 0.05\n")
    tied = tmp_path / "tied.toml"
    tied.write_text('[sets.s]\nAB = 0.05\nBE = 0.05\ncorrelation = [["AB", "BE", 0.9]]\n')
    argv = ["needle", "montecarlo", "--n", "600", "--seed", "1", "--out", str(tmp_path / "D")]
    code, _, err = run(*argv, "--tolerances", f"{untied}:s")
    assert code == 0, err
    code, _, err = run(*argv, "--tolerances", f"{tied}:s", "--resume")
    assert code == 2 and "tolerances" in err, err


@pytest.mark.parametrize("rho, seed", [(0.0, 21), (0.9, 22), (0.99, 23)])
def test_beta_only_yield_under_the_copula_matches_an_independent_model(rho, seed):
    """The issue's done-when: with correlation [["AB", "BE", rho]] on the base set, the yield
    with beta adjusted per machine (sewtol's strategies study, 4000 machines) matches an
    independent model within 3.5 percentage points: OpenTURNS' JointDistribution of the six
    uniforms with a NormalCopula (not sewtol's copula or sampler), another seed, scored by the
    needle's numpy reference optimum (engine="numpy": no kernel, no surrogate). Both are
    binomial estimates of one yield at n 4000 (standard error of the difference at most 0.011,
    so 3.5 points is 3.2 of them). Measured at these seeds (the reference scored by the numba
    engine, equal to 3e-4 um): 8.3/7.4, 25.4/27.1, 50.2/50.8 %."""
    import sys

    ot = pytest.importorskip("openturns")
    sys.path.insert(0, str(Path(__file__).parent))
    from cli_helpers import beta_adjusted
    from sewtol.mechanisms.needle_208.compensators import strategy_of
    from sewtol.tables import needle_208 as T
    from sewtol.tolerances import NEEDLE_208_SETS

    n = 4000
    nominal = Needle208.nominal()
    tied = replace(NEEDLE_208_SETS["base"], name=f"rho {rho}",
                   dependence=Dependence(("AB", "BE"), ((1, rho), (rho, 1))))
    ours = T.strategies_table(nominal, tied, n, seed,
                              strategies=[strategy_of(("beta",), name="beta")])
    y_ours = float(ours.to_dataframe().set_index("strategy").loc["beta", "yield"])
    r = ot.CorrelationMatrix(6)
    r[3, 5] = rho  # AB, BE in the base set's order LF, LM, AM, AB, BC, BE
    ot.RandomGenerator.SetSeed(seed + 1000)
    marginals = [ot.Uniform(-t.upper, t.upper) for t in NEEDLE_208_SETS["base"].active().items]
    x = np.array(ot.JointDistribution(marginals, ot.NormalCopula(r)).getSample(n))
    dev = dict(zip(NEEDLE_208_SETS["base"].active().params, x.T, strict=True))
    ref = beta_adjusted(nominal, dev, (10.0, 35.0), engine="numpy")
    y_ref = float(np.mean((ref.status == "ok") & (ref.total_um <= 10.0)))
    assert abs(y_ours - y_ref) <= 0.035, (rho, y_ours, y_ref)


def test_needle_allocation_draws_its_trials_from_the_copula(monkeypatch):
    """The needle's allocation builds its own trial sets (shapes scaled by k): they keep the
    set's copula, so AB and BE tied at 0.99 allow a larger common scale than untied at a 99 %
    yield after beta (the same seed, the same uniforms: only the ties differ)."""
    from sewtol.studies import allocation as A
    from sewtol.tables import needle_208 as T
    from sewtol.tolerances import NEEDLE_208_SETS

    seen = []
    real = A.allocate
    monkeypatch.setattr(A, "allocate", lambda mech, tol, *a, **k: seen.append(
        (tol, k.get("limits"))) or real(mech, tol, *a, **k))
    nominal = Needle208.nominal()
    base = NEEDLE_208_SETS["base"]
    tied = replace(base, dependence=Dependence(("AB", "BE"), ((1, 0.99), (0.99, 1))))
    free = T.allocate(nominal, base, target=0.99, n=300, seed=3, steps=10, max_mm=4.0)
    held = T.allocate(nominal, tied, target=0.99, n=300, seed=3, steps=10, max_mm=4.0)
    assert seen[0][0].dependence is None and seen[1][0].dependence == tied.dependence
    assert held.as_tolerance_set().dependence == tied.dependence
    # measured: 0.957 and 1.492 (bisection steps of 4 / 2^10 = 0.004)
    assert not (free.capped or held.capped)
    assert held.scale > 1.3 * free.scale, (free.scale, held.scale)
