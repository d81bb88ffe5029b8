"""Line-of-action stroke posing.

Mahmudi et al. 2016, "Artist-oriented 3D character posing from 2D strokes", Computers &
Graphics 58.
"""

from .options import PlaneMode, StrokeOptions, Tracking
from .solve import StrokePoseResult, pose_from_stroke

__all__ = ["PlaneMode", "StrokeOptions", "StrokePoseResult", "Tracking", "pose_from_stroke"]
