"""Gesture drawings (Bessmeltsev, Vining and Sheffer 2016, "Gesture3D").

Part 1, the 2D skeletal embedding: :func:`fit_drawing` places the joints of a rigged
character in a contour drawing and matches contour segments to bones.
"""

from .types import Embedding2D, Occlusion, SolvingSkeleton

__all__ = ["Embedding2D", "Occlusion", "SolvingSkeleton"]
