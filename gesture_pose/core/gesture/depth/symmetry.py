"""Symmetric limbs and depth flips (Gesture3D Section 7, post-process and ambiguities).

- :func:`symmetrize`: left/right limbs whose solved 3D shapes are already nearly mirror
  images (every bone within ``max_angle`` of its mirrored partner) are made exactly
  symmetric about the spine plane. The plane's normal is the rest left-right axis carried
  by the posed rotation of the limbs' common ancestor; it passes through the midpoint of
  the two limbs' root joints.
- :func:`flip_depth`: mirror a chain's depth about the view plane through its root joint,
  the choice the drawing cannot make (a foreshortened limb pointing towards or away from
  the viewer projects to the same strokes).

Both aim bones with :meth:`Skeleton.aim_local`, so bone lengths stay exact and twists
about the bones are kept.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ...rotations import normalize
from ...skeleton import Pose, Skeleton
from ..solving import mirror_name


def mirror_pairs(names: tuple[str, ...], bones: np.ndarray) -> np.ndarray:
    """Left/right bone pairs among ``bones`` (full-skeleton indices), shape ``(k, 2)``."""
    chosen = {names[b]: int(b) for b in bones}
    pairs = [(b, chosen[mirror_name(n)]) for n, b in chosen.items()
             if mirror_name(n) in chosen and b < chosen[mirror_name(n)]]
    return np.asarray(pairs, dtype=int).reshape(-1, 2)


def _reflect(v: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Reflect vectors ``(..., 3)`` across the plane with unit ``normal`` through 0."""
    return v - 2.0 * (v @ normal)[..., None] * normal


def _common_ancestor(skeleton: Skeleton, a: int, b: int) -> int:
    """Lowest common ancestor of bones ``a`` and ``b``, -1 if in different trees."""
    up = set(skeleton.ancestors(a))
    return next((k for k in skeleton.ancestors(b) if k in up), -1)


def _limb_roots(skeleton: Skeleton, pairs: np.ndarray) -> list[np.ndarray]:
    """Group pairs into limbs: sets of pairs whose left bones form one connected subtree."""
    left = {int(p[0]): i for i, p in enumerate(pairs)}
    groups: dict[int, list[int]] = {}
    for lb, i in left.items():
        top = lb
        while skeleton.parents[top] >= 0 and int(skeleton.parents[top]) in left:
            top = int(skeleton.parents[top])
        groups.setdefault(top, []).append(i)
    return [pairs[sorted(g, key=lambda i: pairs[i][0])] for g in groups.values()]


def symmetrize(skeleton: Skeleton, pose: Pose, pairs: np.ndarray,
               max_angle: float = np.radians(10.0),
               accept: Callable[[Pose], bool] | None = None) -> tuple[Pose, list[str]]:
    """Make nearly mirror-symmetric left/right limbs exactly symmetric.

    Args:
        skeleton: The full skeleton (rest pose assumed left/right symmetric).
        pose: The solved pose.
        pairs: Left/right bone pairs (full indices), shape ``(k, 2)``.
        max_angle: Largest angle between a bone and its mirrored partner, radians.
        accept: Called with the pose after each limb pair is made symmetric; the change is
            kept only when it returns True (e.g. no depth-order constraint broken).

    Returns:
        ``(pose, names)``: the new pose and the names of the left bones made symmetric.
    """
    done: list[str] = []
    for limb in _limb_roots(skeleton, pairs):
        state = skeleton.forward(pose)
        top_l, top_r = int(limb[0, 0]), int(limb[0, 1])
        anc = _common_ancestor(skeleton, top_l, top_r)
        rest_axis = normalize(skeleton.rest_heads[limb[:, 0]] - skeleton.rest_heads[limb[:, 1]]
                              ).mean(axis=0)
        carry = (state.frames[anc] @ skeleton.rest_frames[anc].T) if anc >= 0 else np.eye(3)
        normal = normalize(carry @ rest_axis)
        center = 0.5 * (state.heads[top_l] + state.heads[top_r])
        if abs((state.heads[top_l] - center) @ normal) < 1e-9:
            continue
        dl = normalize(state.tails[limb[:, 0]] - state.heads[limb[:, 0]])
        dr = _reflect(normalize(state.tails[limb[:, 1]] - state.heads[limb[:, 1]]), normal)
        angle = np.arccos(np.clip(np.sum(dl * dr, axis=1), -1.0, 1.0))
        if angle.max() > max_angle:
            continue
        target = normalize(dl + dr)
        before = pose
        for (bl, br), d in zip(limb, target, strict=True):
            for bone, direction in ((bl, d), (br, _reflect(d, normal))):
                state = skeleton.forward(pose)
                rot = skeleton.aim_local(int(bone), direction, state, pose.rotations[bone])
                pose = pose.with_rotations(np.array([bone]), rot[None])
        if accept is not None and not accept(pose):
            pose = before
            continue
        done.extend(skeleton.names[b] for b in limb[:, 0])
    return pose, done


def flip_depth(skeleton: Skeleton, pose: Pose, chain: np.ndarray, forward: np.ndarray
               ) -> Pose:
    """Mirror the depth of a chain of bones about the view plane through its root joint.

    Args:
        skeleton: The full skeleton.
        pose: Current pose.
        chain: Full-skeleton bone indices, parents first; the first one's head is the
            root joint, shape ``(k,)``.
        forward: Unit view direction (orthographic), shape ``(3,)``.

    Returns:
        The pose with every bone of the chain re-aimed along its depth-mirrored direction.
    """
    forward = normalize(np.asarray(forward, dtype=float))
    state = skeleton.forward(pose)
    chain = np.asarray(chain, dtype=int)
    targets = _reflect(state.tails[chain] - state.heads[chain], forward)
    for bone, d in zip(chain, targets, strict=True):
        state = skeleton.forward(pose)
        rot = skeleton.aim_local(int(bone), d, state, pose.rotations[bone])
        pose = pose.with_rotations(np.array([bone]), rot[None])
    return pose
