"""The M6 needle drive on the 208 frame: crank, sliding block, slotted lever, needle-bar slider
(docs: README.md in this folder). ``mechanism.toml`` is the mechanism as data; ``model.py`` the
reconstructed layout, the motion at 4000 rpm and the kinetostatic joint reactions."""
