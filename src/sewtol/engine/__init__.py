"""Vectorised kinematic engine of Assur groups over (samples, angles) arrays.

Each group returns positions with analytic first and second transfer functions with respect to
the chain's driving angle. Groups never raise on a chain that cannot close: they return NaN and
a Closure with the miss distance, and the mechanism decides whether that is an error (a single
run) or a counted failure (a study).
"""

from sewtol.engine.crank import crank
from sewtol.engine.dyad import Closure, rrr
from sewtol.engine.motion import Angle, Motion, direction, driving_angle, fixed, on_body, polar
from sewtol.engine.slider import rpr, rrp
from sewtol.engine.spatial import (
    RockerExtremes,
    SliderExtremes,
    position_function,
    rocker_extremes,
    rocker_sensitivities,
    slider_extremes,
    slider_joints,
    slider_position_function,
    spatial_joints,
    spatial_rocker,
    spatial_rocker_third,
    spatial_slider,
    spatial_slider_displacement,
)

__all__ = [
    "Angle", "Closure", "Motion", "crank", "direction", "driving_angle", "fixed", "on_body",
    "polar", "rpr", "rrp", "rrr",
    "RockerExtremes", "position_function", "rocker_extremes", "rocker_sensitivities",
    "spatial_joints", "spatial_rocker", "spatial_rocker_third",
    "SliderExtremes", "slider_extremes", "slider_joints", "slider_position_function",
    "spatial_slider", "spatial_slider_displacement",
]
