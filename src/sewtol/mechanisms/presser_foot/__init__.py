"""The embroidery presser foot on an elastic link (docs: README.md in this folder).

``mechanism.toml`` is the crank-slider as data with the contact cycle as a custom output;
``model.py`` the crank-slider and the foot on its spring, with the fitted stiffness and mass
and the spring's identifiability bound; ``kernel.py`` the event-driven contact dynamics (numba);
``sewtol.tables.presser_foot`` its Monte-Carlo and scan tables (the generic studies on
``mechanism.toml``, whose [tolerances] hold the assumed sets).
"""

# the custom output kind a mechanism file may name, and the module that registers it
OUTPUT_KINDS = {"presser_contact": "sewtol.mechanisms.presser_foot.model"}
