"""Generic studies: they take any mechanism (a mechanism file, sewtol.mechanism) and any output,
and name no mechanism.

scan.py (the per-parameter scan, largest tolerances), worst_case.py, settings.py (named settings
compared), adjusting.py (the one adjustment dispatch: a mechanism's plug-in, else the generic
optimiser), all on the mechanism protocol; generic.py: nominal, Monte-Carlo, Sobol of any file;
generic_yield.py: ppm and allocation of any file; montecarlo.py, sobol.py, rare_event.py: the
sampling, SALib and rare-event machinery every mechanism's studies share; parallel.py,
checkpoint.py: chunked, reproducible, resumable execution. A mechanism's own studies (the
needle's exact beta optimiser) live in its folder under sewtol.mechanisms.
"""
