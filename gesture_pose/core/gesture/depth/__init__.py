"""Gesture drawings, part 2: the 3D pose a drawing depicts (Gesture3D Section 7).

:func:`solve_pose3d` lifts a 2D skeletal embedding (:class:`..types.Embedding2D`) to a 3D
pose with exact bone lengths; :func:`flip_depth` mirrors a limb's depth for the cases the
drawing leaves open.
"""

from .energies import ViewFrame, view_frame
from .evaluation import PoseError, joints_of, pose_error
from .ordering import OrderingConstraint, ordering_constraints
from .qp import LinearConstraint, QPProblem, QPResult, build_qp, solve_qp
from .solve3d import DepthOptions, Pose3DResult, solve_pose3d
from .symmetry import flip_depth, symmetrize

__all__ = [
    "DepthOptions",
    "LinearConstraint",
    "OrderingConstraint",
    "PoseError",
    "Pose3DResult",
    "QPProblem",
    "QPResult",
    "ViewFrame",
    "build_qp",
    "flip_depth",
    "joints_of",
    "ordering_constraints",
    "pose_error",
    "solve_pose3d",
    "solve_qp",
    "symmetrize",
    "view_frame",
]
