"""Sketch abstractions and draw-over posing (Hahn et al., SCA 2015).

A sketch abstraction is a set of rigged curves; the rig parameters are optimized so that the
abstraction's projection matches newly drawn strokes: ICP alternating correspondences
(in-order or closest point) with bounded Gauss-Newton updates solved as QPs (OSQP), with the
regularizers of Eqs. 8-10 on k-means representative vertices (Eq. 12).

Modules: :mod:`.parameters` (p and its increments), :mod:`.rig` (LBS, Eq. 13, Jacobians),
:mod:`.blackbox` (finite differences), :mod:`.curves` (resampling), :mod:`.correspondences`,
:mod:`.coarsening`, :mod:`.energies`, :mod:`.qp`, :mod:`.solver`, :mod:`.drawover`,
:mod:`.problem` (builders).
"""

from .blackbox import FiniteDifferenceRig
from .coarsening import Coarsening, coarsen
from .correspondences import BY_ORDER, BY_PROXIMITY, CLOSEST, IN_ORDER
from .curves import CurveLayout
from .drawover import SurfaceCurve, project_onto_mesh
from .parameters import ParameterSpace, RigPose
from .problem import (
                      build_blackbox_problem,
                      build_drawover_problem,
                      build_lbs_problem,
                      lbs_mismatch,
                      rest_from_posed,
)
from .qp import StepLimits
from .rig import LbsRig, lbs_weighted_rest, pose_bones, skin
from .solver import AbstractionProblem, SolveOptions, SolveResult, solve_abstraction

__all__ = [
    "BY_ORDER", "BY_PROXIMITY", "CLOSEST", "IN_ORDER", "AbstractionProblem", "Coarsening",
    "CurveLayout", "FiniteDifferenceRig", "LbsRig", "ParameterSpace", "RigPose",
    "SolveOptions", "SolveResult", "StepLimits", "SurfaceCurve", "build_blackbox_problem",
    "build_drawover_problem", "build_lbs_problem", "coarsen", "lbs_mismatch",
    "lbs_weighted_rest", "pose_bones", "project_onto_mesh", "rest_from_posed", "skin",
    "solve_abstraction",
]
