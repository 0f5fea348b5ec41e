"""Named frames of the 208 needle drive: versioned package data with their provenance.

The frame of the 208 (A, D, the dyad branches, the sense of beta, the side the guide leans to)
is not published; every reconstruction is a reading of the study's statements. Each one ships
as needle_208/data/frames/<name>.json with the targets it was fitted to, the family, the fitted
values, the residual per target and the conditioning of the fit (studies/calibrate_needle_208.py
rebuilds any of them). docs/needle_208.md says why each exists and why the default is the
default.

    >>> from sewtol import Needle208
    >>> Needle208.nominal("sewtol-0.1")  # the geometry shipped by sewtol 0.1
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from typing import TYPE_CHECKING

from sewtol.errors import ParameterError

if TYPE_CHECKING:
    import pandas as pd

# the frame Needle208.nominal() and every needle command use unless told otherwise
# (docs/needle_208.md, "Which frame is the default")
DEFAULT_FRAME = "sewtol-0.1"
"""The frame `Needle208.nominal()` and every needle command use unless told otherwise."""


@dataclass(frozen=True)
class Frame:
    """One reconstruction of the frame: the nominal machine and where it came from.

    Read with `load_frame`; ``Needle208.nominal(frame)`` is the nominal machine on it.

    Parameters
    ----------
    name : str
        The frame's name (``"sewtol-0.1"``, ``"window"``, ``"table41"``).
    version : int
        The version of the record; a refit that changes the geometry raises it.
    summary : str
        One line saying what the frame was fitted to.
    params : dict
        Every `Needle208` parameter of the nominal machine (mm, deg, um).
    provenance : dict
        Targets, achieved values, residuals, the fit's conditioning and its settings.
    published : tuple
        Rows of the residual table against every published figure of the source study.
    """

    name: str
    version: int
    summary: str
    params: dict
    provenance: dict
    published: tuple = ()  # rows of the residual table against the study's figures

    @property
    def family(self) -> dict:
        return {k: self.params[k] for k in ("branch_M", "branch_C", "beta_sense")} | {
            "lean": 1.0 if self.params["guide_angle"] >= 0 else -1.0}

    @property
    def lm_direction(self) -> float:
        """+1 where beta* moves with LM as the study's Table 4.1 says (24 at UL, 19 at LL)."""
        return self.params["branch_M"] * self.params["beta_sense"]

    def to_dict(self) -> dict:
        return {"name": self.name, "version": self.version, "summary": self.summary,
                "default": self.name == DEFAULT_FRAME, "family": self.family,
                "lm_direction": self.lm_direction, "params": self.params,
                "provenance": self.provenance, "published": list(self.published)}

    def summary_row(self) -> dict:
        """One line per frame: where it is, what it was fitted to and how well it meets the
        published figures (every number in full: to_dict / `--format json`)."""
        p = self.provenance
        scaled = {k: p["residuals"][k] / p["scales"][k] for k in p["targets"]}
        worst = max(scaled, key=lambda k: abs(scaled[k]))
        row = {"frame": self.name, "version": self.version,
               "default": self.name == DEFAULT_FRAME, "kind": p.get("kind", "window"),
               "family": _family_label(self.family), "lm_direction": self.lm_direction,
               "A_mm": f"({self.params['Ax']:.3f}, {self.params['Ay']:.3f})",
               "D_mm": f"({self.params['Dx']:.3f}, {self.params['Dy']:.3f})",
               "guide_angle_deg": self.params["guide_angle"], "beta_deg": self.params["beta"],
               "cost": p.get("cost"), "worst_target": worst,
               "worst_residual": p["residuals"][worst]}
        nominal = {r["param"]: r["model"] for r in self.published if r.get("kind") == "nominal"}
        for key, label in (("SumDelta at beta* (um)", "total_um_at_beta_opt"),
                           ("SumDelta at beta 19 (um)", "total_um_at_19"),
                           ("SumDelta at beta 25 (um)", "total_um_at_25")):
            if key in nominal:
                row[label] = nominal[key]
        pub = [r for r in self.published if r.get("kind") == "delta"]
        if pub:
            row["table41_delta_rms_um"] = (sum(r["residual_um"] ** 2 for r in pub)
                                           / len(pub)) ** 0.5
        betas = [r for r in self.published if r.get("kind") == "beta"]
        if betas:
            row["table41_beta_in_near_set"] = f"{sum(r['in_near_set'] for r in betas)}/{len(betas)}"
        return row


def _family_label(f: dict) -> str:
    s = {1.0: "+", -1.0: "-"}
    return f"M{s[f['branch_M']]}C{s[f['branch_C']]}s{s[f['beta_sense']]}L{s[f['lean']]}"


def _folder():
    return resources.files("sewtol.mechanisms.needle_208").joinpath("data", "frames")


def frame_names() -> list[str]:
    return sorted(p.name[:-5] for p in _folder().iterdir() if p.name.endswith(".json"))


def frame_from_record(record: dict) -> Frame:
    return Frame(record["name"], int(record["version"]), record["summary"], dict(record["params"]),
                 dict(record["provenance"]), tuple(record.get("published", ())))


def load_frame(name: str) -> Frame:
    """The named frame, read from the package data.

    Parameters
    ----------
    name : str
        A frame name (see `list_frames`; the default is ``DEFAULT_FRAME``).

    Returns
    -------
    Frame
        The frame record with its nominal parameters and provenance.

    Raises
    ------
    ParameterError
        For an unknown name; the message lists the valid ones.
    """
    names = frame_names()
    if name not in names:
        raise ParameterError("frame", f"unknown frame; valid names are {', '.join(names)}", name)
    record = json.loads(_folder().joinpath(f"{name}.json").read_text())
    return frame_from_record(record)


def resolve(frame) -> Frame:
    """A Frame from a name, a Frame, or None (the default frame)."""
    if frame is None:
        return load_frame(DEFAULT_FRAME)
    if isinstance(frame, Frame):
        return frame
    if isinstance(frame, str):
        return load_frame(frame)
    raise ParameterError("frame", "must be a frame name or a needle_208.frames.Frame",
                         repr(frame))


def list_frames() -> list[Frame]:
    """Every frame shipped with sewtol.

    Returns
    -------
    list of Frame
        One record per named frame, in name order.
    """
    return [load_frame(n) for n in frame_names()]


def frames_table() -> pd.DataFrame:
    import pandas as pd  # here: the command line's parser reads DEFAULT_FRAME from this module

    return pd.DataFrame([f.summary_row() for f in list_frames()])
