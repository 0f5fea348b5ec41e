"""The feed chains of the 131-42+3 class: lower and upper feed dogs (docs: README.md in this
folder, the site's "131-42+3 feed").

Data and topology: ``mechanism.toml`` (the file `sewtol run feed_131 ...` runs; its q is the
main-shaft angle) and ``model.py`` (`Feed131`, the chains in the source's order). Outputs:
``metrics.py`` (working figures of the dogs: feed step, dog rise, phases, the differential
ratio; the file's outputs of kind feed_dogs). The machine's own analysis (trajectories, the
stitch regulator, the source's read-offs): ``analysis.py``; the tolerance studies are the
generic ones on ``mechanism.toml`` (its default set: [tolerances.assumed]).
"""

# the custom output kind a mechanism file may name, and the module that registers it
OUTPUT_KINDS = {"feed_dogs": "sewtol.mechanisms.feed_131.metrics"}
