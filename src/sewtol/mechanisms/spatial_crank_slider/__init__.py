"""Polukhin's spatial crank-slider (RSSP): cylindrical pair at A, ball joints at B and C, the
slider C on a straight guide (docs: README.md in this folder). ``mechanism.toml`` is the
mechanism as data (the group ``spatial_slider`` of sewtol.engine.spatial); its dimensions are
illustrative (none are published)."""
