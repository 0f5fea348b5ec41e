"""The Khujand feed with a conical-spring store, as a template (docs: README.md in this folder).
No dimension is published: ``mechanism.toml`` holds illustrative lengths that assemble, for a
designer to replace with their own."""
