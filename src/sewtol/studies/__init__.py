"""Generic studies: they take any mechanism (a mechanism file, sewtol.mechanism) and any output,
and name no mechanism.

scan.py (the per-parameter scan, largest tolerances), worst_case.py, settings.py (named settings
compared), adjusting.py (the one adjustment dispatch: a mechanism's plug-in, else the generic
optimiser), sobol.py (Sobol indices), rare_event.py (failures per million: the limit state of
any output and its estimators), allocation.py (the largest common scale of a set), all on the
mechanism protocol; generic.py: nominal and Monte-Carlo of any file; montecarlo.py: the
sampling every mechanism's studies share; summaries.py: tables of several outputs (summary at
chosen quantiles, contributors, screening, Sobol over screened tolerances); parallel.py,
checkpoint.py: chunked, reproducible, resumable execution. A mechanism's own studies (the
needle's exact beta optimiser) live in its folder under sewtol.mechanisms.
"""
