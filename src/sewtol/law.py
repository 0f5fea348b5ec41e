"""The input law of a study: the joint distribution of a mechanism's parameter deviations.

A study never reads a tolerance set's columns one by one; it asks the law. Today's laws are
the product of the set's marginals (every deviation drawn on its own: `independent` is True);
the joint form (a copula over the marginals, parts made in one setup) will add a dependence
here without changing any study's call. A study that needs independence (Sobol indices, the
rare-event transform to standard normal space) checks `independent` and says so when it
cannot hold, instead of assuming it.

    law = InputLaw.of(tolerance_set)
    u = law.sample_unit(rng, n)          # (n, d) numbers in (0, 1): the machines' ranks
    dev = law.deviations(u)              # parameter -> deviation from nominal (its unit)

`law.sample(rng, n)` equals `law.deviations(law.sample_unit(rng, n))` and, for the
independent law, `ToleranceSet.sample(rng, n)` bit for bit: the same seed gives the same
machines whichever of them a study calls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol.tolerances import Tolerance, ToleranceSet


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
    """

    name: str
    marginals: tuple[Tolerance, ...]

    @classmethod
    def of(cls, tolerances: ToleranceSet) -> InputLaw:
        """The law of a tolerance set: its active tolerances, drawn independently."""
        return cls(tolerances.name, tolerances.active().items)

    @property
    def params(self) -> list[str]:
        """The parameters that scatter, in order."""
        return [t.param for t in self.marginals]

    @property
    def dim(self) -> int:
        return len(self.marginals)

    @property
    def independent(self) -> bool:
        """True: every deviation is drawn on its own (the product of the marginals)."""
        return True

    def sample_unit(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n machines as ranks in (0, 1), shape (n, dim), from the Generator `rng`."""
        return rng.random((int(n), self.dim))

    def deviations(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """The deviations (parameter -> array, in the parameter's unit) of ranks u (n, dim)."""
        u = np.asarray(u, float)
        return {t.param: t.from_unit(u[:, i]) for i, t in enumerate(self.marginals)}

    def sample(self, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
        """n machines' deviations from nominal, one array per parameter."""
        return self.deviations(self.sample_unit(rng, n))

    def box(self) -> dict[str, tuple[float, float]]:
        """The smallest and largest deviation each parameter can draw (its reach)."""
        return {t.param: t.reach() for t in self.marginals}
