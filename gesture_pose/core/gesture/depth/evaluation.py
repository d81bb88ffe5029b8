"""How far a solved 3D pose is from a known one (tests, benchmarks, the demo).

Two measures, both after moving the solved joints so that the first joint (the root)
coincides with the truth's, since the drawing fixes neither the character's place along
the view nor, for a root without translation, its place in the image:

- the mean joint error in % of the character's height (the largest extent of its rest
  bones);
- the correct depth-order rate: among joint pairs more than ``min_gap`` of the height apart
  in depth in the truth, the fraction whose order (which is nearer the camera) the result
  gets right.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...camera import Camera
from ...skeleton import Pose, Skeleton
from ..types import SolvingSkeleton


@dataclass(frozen=True)
class PoseError:
    """Distance between a solved and a known pose.

    Attributes:
        mean_error: Mean joint distance after aligning the root, % of the height.
        max_error: Largest joint distance after aligning the root, % of the height.
        depth_order: Correct depth-order rate in ``[0, 1]`` (NaN without deep pairs).
        height: The character's height, world units.
    """

    mean_error: float
    max_error: float
    depth_order: float
    height: float


def joints_of(solving: SolvingSkeleton, skeleton: Skeleton, pose: Pose) -> np.ndarray:
    """World joints of the solving skeleton in ``pose``, shape ``(J, 3)``."""
    state = skeleton.forward(pose)
    out = np.empty((solving.n_joints, 3))
    out[solving.head_joint] = state.heads[solving.bones]
    out[solving.tail_joint] = state.tails[solving.bones]
    return out


def pose_error(truth: np.ndarray, solved: np.ndarray, skeleton: Skeleton, camera: Camera,
               min_gap: float = 0.05) -> PoseError:
    """Compare solved joints with the known ones.

    Args:
        truth: Known joints, shape ``(J, 3)``, world units.
        solved: Solved joints in the same order, shape ``(J, 3)``.
        skeleton: The skeleton (its rest extent is the height).
        camera: The view (depth axis).
        min_gap: Smallest depth difference of a counted pair, fraction of the height.

    Returns:
        The errors.
    """
    truth, solved = np.asarray(truth, float), np.asarray(solved, float)
    aligned = solved - solved[0] + truth[0]
    pts = np.concatenate([skeleton.rest_heads, skeleton.rest_tails])
    height = float(np.ptp(pts, axis=0).max())
    dist = np.linalg.norm(aligned - truth, axis=1) / height * 100.0
    dt, ds = camera.depth(truth), camera.depth(aligned)
    gap_t = dt[:, None] - dt[None]
    gap_s = ds[:, None] - ds[None]
    pairs = np.triu(np.abs(gap_t) > min_gap * height, 1)
    rate = (float(np.mean(np.sign(gap_t[pairs]) == np.sign(gap_s[pairs]))) if pairs.any()
            else float("nan"))
    return PoseError(float(dist.mean()), float(dist.max()), rate, height)


def depth_sign_rate(solving: SolvingSkeleton, truth: np.ndarray, got: np.ndarray,
                    camera: Camera, clear: float = 0.2, moved: float = 0.1) -> float:
    """Share of the clearly turned links whose depth change the result gets right.

    A link counts when its true depth change along the view (tail minus head, over its
    rest length) exceeds ``clear``; the result gets it right when it turns the link the
    same way by more than ``moved`` (a link left in the view plane counts as wrong).

    Args:
        solving: The solving skeleton.
        truth: True joints, world units, ``(J, 3)``.
        got: Result joints, world units, ``(J, 3)``.
        camera: The view.
        clear: Smallest true depth change of a counted link, fraction of its length.
        moved: Smallest depth change of the result's link, fraction of its length.

    Returns:
        The rate in ``[0, 1]``, NaN without such links.
    """
    child = np.flatnonzero(solving.joint_parent >= 0)
    par = solving.joint_parent[child]
    length = np.maximum(np.linalg.norm(solving.rest_joints[child] - solving.rest_joints[par],
                                       axis=1), 1e-9)
    d_truth = camera.forward @ (truth[child] - truth[par]).T / length
    d_got = camera.forward @ (got[child] - got[par]).T / length
    sel = np.abs(d_truth) > clear
    if not sel.any():
        return float("nan")
    return float(np.mean(np.sign(d_got[sel]) * (np.abs(d_got[sel]) > moved)
                         == np.sign(d_truth[sel])))
