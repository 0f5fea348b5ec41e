"""Polukhin's spatial crank-rocker (cylindrical pairs at A and D, ball joints at B and C; docs:
README.md in this folder). ``mechanism.toml`` is the mechanism as data (the group
``spatial_rocker`` of sewtol.engine.spatial); tests/spatial_rocker_reference.py is the same
machine written again in Python, the reference the file is checked against."""
