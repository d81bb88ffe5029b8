"""Embeddings of known poses: the 3D step's input without a drawing.

Projecting a known 3D pose gives the embedding a perfect 2D fit would produce. Tests and
benchmarks use it to measure the 3D lifting alone, separately from the 2D fit.
"""

from __future__ import annotations

import numpy as np

from ...camera import Camera
from ...skeleton import Pose, Skeleton
from ..solving import build_solving_skeleton
from ..types import Embedding2D, Occlusion, SolvingSkeleton


def solving_skeleton(skeleton: Skeleton, bones: np.ndarray | None = None) -> SolvingSkeleton:
    """The solving skeleton over ``bones`` (full indices; default every bone)."""
    mask = np.zeros(skeleton.n_bones, dtype=bool)
    mask[np.arange(skeleton.n_bones) if bones is None else np.asarray(bones, int)] = True
    return build_solving_skeleton(skeleton, mask)


def project_embedding(skeleton: Skeleton, solving: SolvingSkeleton, pose: Pose,
                      camera: Camera, radius: float | np.ndarray = 0.05,
                      occlusions: tuple[Occlusion, ...] = ()) -> Embedding2D:
    """The embedding of a drawing that shows ``pose`` exactly, from ``camera``.

    Args:
        skeleton: The full skeleton.
        solving: Its solving skeleton.
        pose: The pose drawn.
        camera: The view.
        radius: Body radius at each joint, world units (scalar or ``(J,)``).
        occlusions: Occlusions to record.

    Returns:
        The embedding (no contours: cues that need them are absent).
    """
    state = skeleton.forward(pose)
    n_j = solving.n_joints
    X = np.zeros((n_j, 3))
    X[solving.head_joint] = state.heads[solving.bones]
    X[solving.tail_joint] = state.tails[solving.bones]
    px = camera.project(X)
    center = X.mean(axis=0)
    scale = camera.pixels_per_unit(float(camera.depth(center[None])[0]))
    radius_px = np.broadcast_to(np.asarray(radius, float), (n_j,)) * scale
    m = solving.n_bones
    return Embedding2D(
        solving=solving, joints2d=px, joint_visible=np.ones(n_j, bool),
        joint_radius=radius_px.copy(), bone_segments=((),) * m,
        bone_segment_sides=((),) * m, occlusions=tuple(occlusions), contours=(),
        contour_normals=(), coverage=1.0, e_match=0.0,
    )
