"""Tiny hand-built skeletons and cameras shared by the core tests."""

from __future__ import annotations

import numpy as np

from gesture_pose.core.camera import Camera
from gesture_pose.core.rotations import exp_map, rotation_between
from gesture_pose.core.skeleton import Pose, Skeleton


def frame_along(direction: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """A rest frame whose y axis is ``direction``, rolled by ``roll`` radians."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    base = rotation_between(np.array([0.0, 1.0, 0.0]), d)
    return exp_map(d * roll) @ base


def chain_skeleton(points: np.ndarray, rolls: np.ndarray | None = None) -> Skeleton:
    """A single connected chain of bones through ``points`` (shape ``(k+1, 3)``)."""
    pts = np.asarray(points, float)
    n = len(pts) - 1
    rolls = np.linspace(0.3, -0.7, n) if rolls is None else rolls
    frames = np.stack([frame_along(pts[i + 1] - pts[i], rolls[i]) for i in range(n)])
    return Skeleton(
        names=tuple(f"b{i}" for i in range(n)),
        parents=np.arange(n) - 1,
        rest_heads=pts[:-1].copy(),
        rest_tails=pts[1:].copy(),
        rest_frames=frames,
        inherit_rotation=np.ones(n, bool),
        connected=np.r_[False, np.ones(n - 1, bool)],
        deform=np.ones(n, bool),
    )


def bone_skeleton(names: tuple[str, ...], parents, heads, tails, connected,
                  roll_step: float = 0.0) -> Skeleton:
    """A deforming skeleton from bone heads and tails (``(n, 3)`` each, metres); bone ``i``
    is rolled by ``i * roll_step`` radians about itself."""
    heads, tails = np.asarray(heads, float), np.asarray(tails, float)
    frames = np.stack([frame_along(t - h, roll_step * i)
                       for i, (h, t) in enumerate(zip(heads, tails, strict=True))])
    n = len(heads)
    return Skeleton(names=tuple(names), parents=np.asarray(parents), rest_heads=heads,
                    rest_tails=tails, rest_frames=frames, inherit_rotation=np.ones(n, bool),
                    connected=np.asarray(connected, bool), deform=np.ones(n, bool))


def tree_skeleton() -> Skeleton:
    """A small Y-shaped tree: root, then two branches of two bones, one unconnected."""
    heads = np.array([[0, 0, 0], [0, 0, 1], [0.1, 0, 1], [0.6, 0, 1.0], [-0.1, 0, 1.05],
                      [-0.6, 0, 1.05]], float)
    tails = np.array([[0, 0, 1], [0, 0, 1.5], [0.6, 0, 1], [1.1, 0, 1.0], [-0.6, 0, 1.05],
                      [-1.2, 0, 1.05]], float)
    parents = np.array([-1, 0, 0, 2, 0, 4])
    pairs = enumerate(zip(heads, tails, strict=True))
    frames = np.stack([frame_along(t - h, 0.2 * i) for i, (h, t) in pairs])
    return Skeleton(
        names=("root", "neck", "arm.L", "fore.L", "arm.R", "fore.R"),
        parents=parents,
        rest_heads=heads,
        rest_tails=tails,
        rest_frames=frames,
        inherit_rotation=np.ones(6, bool),
        connected=np.array([False, True, False, True, False, True]),
        deform=np.ones(6, bool),
    )


def front_camera(ortho: bool = False) -> Camera:
    """A camera 6 m in front (-y) of the origin looking along +y, 800x600 pixels."""
    return Camera.look_at(
        [0.0, -6.0, 0.8], [0.0, 0.0, 0.8], width=800, height=600,
        ortho_scale=3.0 if ortho else None,
    )


def turned_about_x(skeleton: Skeleton, pose: Pose, turns) -> Pose:
    """``pose`` with bones turned in world space about the x axis, one after the other.

    Args:
        skeleton: The skeleton.
        pose: The starting pose.
        turns: ``(bone, degrees)`` pairs, applied in order (a parent before its child).

    Returns:
        The new pose.
    """
    for bone, angle in turns:
        state = skeleton.forward(pose)
        world = exp_map(np.array([np.radians(angle), 0.0, 0.0]))
        frame = state.frames[bone]
        pose = pose.with_rotations(np.array([bone]),
                                   (frame.T @ world @ frame @ pose.rotations[bone])[None])
    return pose
