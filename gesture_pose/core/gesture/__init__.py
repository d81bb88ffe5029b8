"""Gesture drawings (Bessmeltsev, Vining and Sheffer 2016, "Gesture3D").

Part 1, the 2D skeletal embedding: :func:`fit_drawing` places the joints of a rigged
character in a contour drawing and matches contour segments to bones;
:func:`trace_contours` and :func:`perturb` make test drawings from a posed mesh.
"""

from .embedding import GestureParams, fit_drawing
from .trace import Perturbation, TraceParams, perturb, trace_contours
from .types import Embedding2D, Occlusion, SolvingSkeleton

__all__ = ["Embedding2D", "GestureParams", "Occlusion", "Perturbation", "SolvingSkeleton",
           "TraceParams", "fit_drawing", "perturb", "trace_contours"]
