"""The input law of a study: the joint distribution of a mechanism's parameter deviations.

A study never reads a tolerance set's columns one by one; it asks the law: the set's marginals
joined by its dependence (`sewtol.dependence`: a Gaussian copula from `correlation` and `setup`
in the tolerance file), or their product when it declares none (`independent` is True). A study
that needs independence (Sobol indices) checks `independent` and says so when it cannot hold,
instead of assuming it.

    law = InputLaw.of(tolerance_set)
    u = law.sample_unit(rng, n)          # (n, d) numbers in (0, 1): the machines' ranks
                                         # (law.ranks of independent uniforms)
    dev = law.deviations(u)              # parameter -> deviation from nominal (its unit)

`law.draw(n, seed)` is the one sampler of every study (Monte-Carlo, strategies, ppm by plain
Monte-Carlo, allocation): machine k is row k % STREAM of the standard uniforms drawn from child
k // STREAM of the seed, tied by `ranks` (the copula; the identity for an independent law, so
its draws are byte for byte those of the product law) and mapped by `deviations`; so one seed
and one law give the same machines in every study, for any number of workers. `law.sample(rng, n)` equals
`law.deviations(law.sample_unit(rng, n))` and, for the independent law,
`ToleranceSet.sample(rng, n)` bit for bit.

Relations (`sewtol.relations`, e.g. a limit on AB - BE) condition the law: a machine is
built only when its deviations keep every relation. The sampler then draws candidates from each
stream in batches of STREAM rows, in order, and machine k is the (k % STREAM)-th candidate of
stream k // STREAM that keeps them; the rest are rejected and counted (`rank_rows`,
`acceptance`). Selective assembly (`sewtol.selective`) matches two parts within lots of STREAM
candidates drawn from the stream in turn; machine k is then the (k % STREAM)-th matched machine
of stream k // STREAM.
So the window property holds (a stream's accepted candidates do not depend on how many are
asked for) and a law without relations draws exactly what it drew before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol import selective
from sewtol.dependence import Dependence
from sewtol.errors import ParameterError
from sewtol.relations import Relation
from sewtol.selective import Selective
from sewtol.tolerances import Tolerance, ToleranceSet

# machines per stream of the sampler: machine k draws from child k // STREAM of the seed
STREAM = 500
# a stream that needs more candidates than this per machine it gives (acceptance below 1e-3)
# is refused: the relations leave almost nothing of the tolerances
MAX_CANDIDATES_PER_MACHINE = 1000


def refuse_conditioned(law, relation: str | None = None, selective: str | None = None) -> None:
    """Refuse in one line a set or law with relations (rule `relation`) or selective assembly
    (rule `selective`): a study that does not draw that conditioning (None: it does)."""
    if relation and law.relations:
        raise ParameterError(law.relations[0].where, relation, law.relations[0].expr)
    if selective and law.selective is not None:
        raise ParameterError(law.selective.where, selective, law.selective.as_dict())


@dataclass(frozen=True)
class InputLaw:
    """The joint law of the toleranced parameters' deviations.

    Parameters
    ----------
    name : str
        The tolerance set it comes from (labels tables and study folders).
    marginals : tuple of Tolerance
        One per parameter that scatters (zero-width tolerances are left nominal), in the set's
        order: limits and distribution of each deviation.
    dependence : Dependence or None
        The copula tying some of them (None: independent).
    relations : tuple of Relation
        Limits on derived quantities the machines keep (the law is conditioned on them).
    selective : Selective or None
        Two parts sorted into classes and matched at assembly (sewtol.selective).
    """

    name: str
    marginals: tuple[Tolerance, ...]
    dependence: Dependence | None = None
    relations: tuple[Relation, ...] = ()
    selective: Selective | None = None

    @classmethod
    def of(cls, tolerances: ToleranceSet) -> InputLaw:
        """The law of a tolerance set: its active tolerances, tied by its dependence and
        conditioned on its relations."""
        active = tolerances.active()
        return cls(tolerances.name, active.items, active.dependence, active.relations,
                   active.selective)

    @property
    def params(self) -> list[str]:
        """The parameters that scatter, in order."""
        return [t.param for t in self.marginals]

    @property
    def dim(self) -> int:
        return len(self.marginals)

    @property
    def independent(self) -> bool:
        """True: every deviation is drawn on its own (the product of the marginals, no
        relation conditioning it)."""
        return self.dependence is None and not self.relations and self.selective is None

    def accepts(self, dev: dict[str, np.ndarray]) -> np.ndarray:
        """True per machine whose deviations keep every relation."""
        n = len(next(iter(dev.values()))) if dev else 0
        ok = np.ones(n, bool)
        for r in self.relations:
            ok &= r.holds(dev, n)
        return ok

    def rank_rows(self, streams: list[np.random.SeedSequence], start: int = 0,
                  stop: int | None = None) -> tuple[np.ndarray, int]:
        """The ranks (stop - start, dim) of machines start .. stop-1 of these streams
        (`ranks` of `draw_units`; with relations or selective assembly, of the candidates
        matched and kept, the module docstring) and the candidates drawn for them (stop - start
        without either; with selective assembly whole lots of STREAM parts)."""
        if not self.relations and self.selective is None:
            u = draw_units(streams, self.dim, start, stop)
            return self.ranks(u), len(u)
        stop = len(streams) * STREAM if stop is None else int(stop)
        first = start // STREAM
        rows, drawn = [], 0
        for j in range(first, -(-stop // STREAM)):
            need = min(STREAM, stop - j * STREAM)
            gen = np.random.default_rng(streams[j])
            kept, got, tried = [], 0, 0
            while got < need:
                if tried >= MAX_CANDIDATES_PER_MACHINE * STREAM:
                    what = self.relations[0] if self.relations else self.selective
                    raise ParameterError(what.where, "leave(s) almost no machine of the "
                                         f"tolerances: {got} of {tried} candidates built",
                                         [r.expr for r in self.relations])
                lot = self.ranks(gen.random((STREAM, self.dim)))
                if self.selective is not None:
                    lot = self.matched(lot)
                ok = self.accepts(self.deviations(lot)) if self.relations else \
                    np.ones(len(lot), bool)
                idx = np.flatnonzero(ok)[:need - got]
                kept.append(lot[idx])
                got += len(idx)
                tried += STREAM if self.selective is not None or got < need else int(idx[-1]) + 1
            rows.append(np.concatenate(kept))
            drawn += tried
        r = np.concatenate(rows) if rows else np.empty((0, self.dim))
        return r[start - first * STREAM:], drawn

    def matched(self, lot: np.ndarray) -> np.ndarray:
        """The machines of one lot of ranks (m, dim) after selective assembly: the pairs
        sewtol.selective.match makes, each the first part's machine with the second part of
        its partner (fewer rows: the unmatched parts are left out)."""
        sel = self.selective
        b = self.params.index(sel.params[1])
        dev = self.deviations(lot)
        lim = {t.param: (t.lower, t.upper) for t in self.marginals}
        ia, ib = selective.match(
            selective.classes(dev[sel.params[0]], sel.groups, sel.by, lim[sel.params[0]]),
            selective.classes(dev[sel.params[1]], sel.groups, sel.by, lim[sel.params[1]]),
            sel.groups)
        out = lot[ia].copy()
        out[:, b] = lot[ib, b]
        return out

    def window(self, streams: list[np.random.SeedSequence], start: int = 0,
               stop: int | None = None) -> dict[str, np.ndarray]:
        """The deviations of machines start .. stop-1 of these streams (`rank_rows`, mapped)."""
        return self.deviations(self.rank_rows(streams, start, stop)[0])

    def acceptance(self, n: int, seed: int | np.random.Generator) -> tuple[int, int]:
        """(machines, candidates drawn for them) of machines 0 .. n-1 of `seed`: the share
        built is their ratio (n, n without relations or selective assembly)."""
        return int(n), self.rank_rows(unit_streams(seed, n), 0, n)[1]

    def ranks(self, u: np.ndarray) -> np.ndarray:
        """The machines' ranks (n, dim) of independent standard uniforms u (n, dim): the
        copula's columns replaced, the others (all of an independent law's) u itself."""
        if self.dependence is None:
            return u
        cols = [self.params.index(p) for p in self.dependence.params]
        out = np.array(u, float)
        out[:, cols] = self.dependence.ranks(out[:, cols])
        return out

    def of_uniforms(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """The deviations of machines drawn as independent standard uniforms u (n, dim):
        `deviations(ranks(u))`, what every study maps the sampler's uniforms with."""
        return self.deviations(self.ranks(u))

    def sample_unit(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n machines as ranks in (0, 1), shape (n, dim), from the Generator `rng` (the
        copula only: `draw` and `rank_rows` honour relations and selective assembly)."""
        return self.ranks(rng.random((int(n), self.dim)))

    def deviations(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """The deviations (parameter -> array, in the parameter's unit) of ranks u (n, dim)."""
        u = np.asarray(u, float)
        return {t.param: t.from_unit(u[:, i]) for i, t in enumerate(self.marginals)}

    def sample(self, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
        """n machines' deviations from nominal, one array per parameter (with relations or
        selective assembly: the first n candidates of `rng`, in lots of max(n, STREAM), that
        are matched and keep the relations)."""
        if not self.relations and self.selective is None:
            return self.deviations(self.sample_unit(rng, n))
        kept, got, tried = [], 0, 0
        while got < n:
            if tried >= MAX_CANDIDATES_PER_MACHINE * max(int(n), STREAM):
                what = self.relations[0] if self.relations else self.selective
                raise ParameterError(what.where, "leave(s) almost no machine of the "
                                     f"tolerances: {got} of {tried} candidates built",
                                     [r.expr for r in self.relations])
            lot = self.sample_unit(rng, max(int(n), STREAM))
            tried += len(lot)
            if self.selective is not None:
                lot = self.matched(lot)
            ok = np.flatnonzero(self.accepts(self.deviations(lot)))[:int(n) - got]
            kept.append(lot[ok])
            got += len(ok)
        return self.deviations(np.concatenate(kept))

    def draw(self, n: int, seed: int | np.random.Generator) -> dict[str, np.ndarray]:
        """Machines 0 .. n-1 of the one sampler (the module docstring): deviations per
        parameter, the same for one seed in every study."""
        return self.window(unit_streams(seed, n), 0, n)

    def box(self) -> dict[str, tuple[float, float]]:
        """The smallest and largest deviation each parameter can draw (its reach)."""
        return {t.param: t.reach() for t in self.marginals}


def unit_streams(seed: int | np.random.Generator, n: int) -> list[np.random.SeedSequence]:
    """The seed's children, one per STREAM machines: machine k draws from child k // STREAM.

    seed: a whole number, or a Generator whose children are spawned (rare_event's plain
    Monte-Carlo; numpy.random.default_rng(s) gives the same streams as s)."""
    ss = seed.bit_generator.seed_seq if isinstance(seed, np.random.Generator) \
        else np.random.SeedSequence(int(seed))
    return ss.spawn(-(-int(n) // STREAM))


def draw_units(streams: list[np.random.SeedSequence], d: int, start: int = 0,
               stop: int | None = None) -> np.ndarray:
    """Standard uniforms (stop - start, d) of machines start .. stop-1: machine k is row
    k % STREAM of the draw from streams[k // STREAM] (a fresh Generator per stream, so any
    window of machines draws the same numbers; `stream_window` gives a worker its slice)."""
    stop = len(streams) * STREAM if stop is None else int(stop)
    first = start // STREAM
    rows = [np.random.default_rng(streams[j]).random((min(STREAM, stop - j * STREAM), d))
            for j in range(first, -(-stop // STREAM))]
    return (np.concatenate(rows) if rows else np.empty((0, d)))[start - first * STREAM:]


def stream_window(streams: list, a: int, b: int) -> tuple[list, int, int]:
    """The streams machines a .. b-1 draw from and their rows in them (draw_units(streams, d,
    start, stop) then draws them without sending a worker every stream): (streams, start, stop)."""
    first = a // STREAM
    return streams[first: -(-b // STREAM)], a - first * STREAM, b - first * STREAM
