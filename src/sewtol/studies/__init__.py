"""Studies on mechanisms: beta optimisation, tolerance scans, worst case, Monte-Carlo, Sobol."""
