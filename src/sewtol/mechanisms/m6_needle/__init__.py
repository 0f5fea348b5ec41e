"""The M6 needle drive on the 208 frame: crank, sliding block, slotted lever, needle-bar slider
(docs: README.md in this folder). ``mechanism.toml`` is the mechanism as data; ``model.py`` the
reconstructed layout, the motion at 4000 rpm, the exact travel and the kinetostatic joint
reactions; ``fast_path.py`` the exact travel as the protocol's kernel plug-in (the check that a
file is this chain, the kernel and its bound against the file's sampled travel)."""

FAST_PATHS = {"m6_needle": "sewtol.mechanisms.m6_needle.fast_path"}
