"""The 208-class overlock needle drive: two four-bars in series whose coupler point carries the
needle bar on a fixed guide (docs: README.md in this folder, the site's "208 needle drive").

Data and topology: ``mechanism.toml`` (the file `sewtol run needle_208 ...` runs) and
``model.py`` (`Needle208`, the chain group by group, the rocker interval, assembly checks);
the reconstructed frames with their provenance: ``frames.py`` and ``data/``.

Outputs and their exact evaluation: ``metrics.py`` (d(phi), Delta+, Delta-, SumDelta on the
exact rocker interval), ``single.py`` (one machine's figures), ``status.py`` (why a machine
does not run).

Compensators, exactly: ``beta.py`` (beta* by the sliding-window optimum), ``adjust.py`` (the
joint optimum of beta and the guide), ``adjustment.py`` (any strategy's compensators, batched),
``kernels/`` (the fused numba fast paths, held equal to the numpy reference by tests),
``fast_path.py`` (the check that lets a mechanism file use them, and the protocol's plug-ins:
the exact SumDelta kernel, the exact beta / beta + guide-shift adjuster, the strategy
adjuster, the failure naming and the source's column names as data).

No study lives here: every study is written once in sewtol.studies and runs on this machine as
a protocol mechanism; ``sewtol.tables.needle_208`` (``as_mechanism``) gives their tables in
the source's columns and words (scan, worst case, Monte-Carlo, strategies, Sobol, ppm, allocation, the guide
settings compared). ``calibration.py`` reconstructs the unpublished frame.
"""

from sewtol.mechanisms.needle_208.model import (
    Needle208,
    chain_from_crank,
    check_assembly,
    rocker_interval,
)

FAST_PATHS = {"needle_208": "sewtol.mechanisms.needle_208.fast_path"}

__all__ = ["Needle208", "chain_from_crank", "check_assembly", "rocker_interval"]
