"""The public namespace: every advertised name resolves, and a study runs from it alone."""

from __future__ import annotations

import numpy as np
import pytest

import sewtol


def test_every_public_name_resolves():
    for name in sewtol.__all__:
        assert getattr(sewtol, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        sewtol.nope  # noqa: B018


def test_a_study_from_the_public_namespace_equals_the_module_path():
    from sewtol.tables.needle_208 import montecarlo
    from sewtol.tolerances import NEEDLE_208_SETS

    ts = sewtol.tolerance_set("recommended")
    assert ts is NEEDLE_208_SETS["recommended"] and sewtol.tolerance_set(ts) is ts
    a = sewtol.montecarlo(sewtol.Needle208.nominal(), ts, 40, seed=7)
    b = montecarlo(sewtol.Needle208.nominal(), NEEDLE_208_SETS["recommended"], 40, seed=7)
    assert np.array_equal(a.machines["total_adjusted_um"], b.machines["total_adjusted_um"])
    with pytest.raises(sewtol.ParameterError, match="--tolerances"):
        sewtol.tolerance_set("nope")


def test_needle_studies_take_a_tolerance_set_by_name():
    """tolerances="recommended" is the set itself in every study (same seed, same numbers);
    anything else is refused naming the parameter."""
    import sewtol
    from sewtol.errors import ParameterError

    nominal = sewtol.Needle208.nominal()
    by_name = sewtol.montecarlo(nominal, "recommended", n=200, seed=4)
    by_set = sewtol.montecarlo(nominal, sewtol.tolerance_set("recommended"), n=200, seed=4)
    assert by_name.summary_frame().equals(by_set.summary_frame())
    assert sewtol.scan(nominal, "base").to_dataframe().equals(
        sewtol.scan(nominal, sewtol.tolerance_set("base")).to_dataframe())
    with pytest.raises(ParameterError, match="tolerances"):
        sewtol.montecarlo(nominal, 3, n=200, seed=4)
    with pytest.raises(ParameterError, match="--tolerances"):
        sewtol.montecarlo(nominal, "recomended", n=200, seed=4)
