"""The mechanisms' tables: the generic studies of sewtol.studies in each source's own columns and
words (the needle's Table 4.1 layout, the presser foot's modes).

Each module turns a mechanism's parameter dataclass into its protocol mechanism and renames
the studies' figures; the studies themselves live in sewtol.studies, the models in
sewtol.mechanisms.
"""
