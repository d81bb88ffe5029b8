"""Stroke-to-chain matching (Mahmudi et al. 2016, Section 4).

A *chain* is a sequence of bones ``b_0 .. b_{k-1}``, each the parent of the next, with
joints ``J_0 = head(b_0)``, ``J_i = head(b_i)`` and ``J_k = tail(b_{k-1})``. Segment ``i``
(``J_i -> J_{i+1}``) is rigid in bone ``b_i``'s frame, so rotating ``b_i`` about ``J_i``
places ``J_{i+1}``; for unconnected children the segment is the offset to the child's head.

A *plan* splits a user's stroke over one or more chains: Forward Posing (one downward
chain), a reversed Forward Posing (the stroke drawn from the lower end), or Over-Root
posing through a common ancestor, in begin / middle / end parts with the begin part
reversed.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from ..camera import Camera
from ..exceptions import InputError
from ..skeleton import PoseState, Skeleton
from .options import StrokeOptions

_COINCIDE = 1e-6


class PlanKind(StrEnum):
    """How a stroke maps onto the skeleton."""

    FORWARD = "FORWARD"
    REVERSED = "REVERSED"
    OVER_ROOT = "OVER_ROOT"


@dataclass(frozen=True)
class ChainPart:
    """One downward chain and the share of the stroke it follows.

    Attributes:
        start_candidates: Bones that may start the chain (several at a branch point).
        fixed_bones: The chain's bones when fully determined, else None (chosen while
            posing, at branches by the smallest rotation).
        end_bone: Bone the chain stops at, or -1 to continue to a leaf.
        reversed_stroke: Whether this part follows its piece of the stroke backwards.
    """

    start_candidates: tuple[int, ...]
    fixed_bones: tuple[int, ...] | None
    end_bone: int
    reversed_stroke: bool


@dataclass(frozen=True)
class ChainPlan:
    """The parts a stroke is split into.

    Attributes:
        kind: FORWARD, REVERSED or OVER_ROOT.
        parts: Chains in stroke order (for OVER_ROOT: begin, end).
        ancestor: Common ancestor bone of an Over-Root plan, else -1.
        direction_path: Bones that must be on the chain (from a direction bone).
    """

    kind: PlanKind
    parts: tuple[ChainPart, ...]
    ancestor: int = -1
    direction_path: frozenset[int] = frozenset()


def segment_end(skeleton: Skeleton, state: PoseState, bone: int, child: int) -> np.ndarray:
    """World end of ``bone``'s segment: ``child``'s head, or the bone's tail if ``child < 0``."""
    return state.tails[bone] if child < 0 else state.heads[child]


def pick_start(
    skeleton: Skeleton, state: PoseState, camera: Camera, point: np.ndarray, radius: float
) -> tuple[int, ...]:
    """Bones starting at the joint whose projection is nearest ``point``.

    Args:
        skeleton: The skeleton.
        state: Its current forward kinematics.
        camera: The view the stroke was drawn in.
        point: The stroke's first point in pixels, shape ``(2,)``.
        radius: Pick radius in pixels.

    Returns:
        The bones whose heads sit on the picked joint (several at a branch point).

    Raises:
        InputError: No joint within ``radius``, or the joint has no bone below it.
    """
    n = skeleton.n_bones
    joints = np.concatenate([state.heads, state.tails])
    px = camera.project(joints)
    dist = np.linalg.norm(px - np.asarray(point, float), axis=1)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    best = int(np.argmin(dist))
    if not dist[best] <= radius:
        name = skeleton.names[best % n]
        end = "head" if best < n else "tail"
        raise InputError(
            f"The stroke starts {dist[best]:.0f} px from the nearest joint ({end} of "
            f"'{name}'), farther than the pick radius of {radius:.0f} px: start the stroke "
            "on a joint of the character, or set a start bone."
        )
    scale = float(np.max(np.ptp(joints, axis=0)))
    where = joints[best]
    near = np.linalg.norm(state.heads - where, axis=1) <= _COINCIDE * max(scale, 1.0)
    starts = tuple(np.flatnonzero(near).tolist())
    if not starts:
        raise InputError(
            f"The stroke starts at the end of bone '{skeleton.names[best - n]}', which has no "
            "bone below it: start the stroke at the joint above the part you want to pose."
        )
    return starts


def _path_up(skeleton: Skeleton, bone: int, stop: int) -> list[int]:
    """Bones from ``bone`` up to (excluding) ``stop``."""
    out = []
    while bone != stop and bone >= 0:
        out.append(bone)
        bone = int(skeleton.parents[bone])
    return out


def _lowest_common_ancestor(skeleton: Skeleton, a: int, b: int) -> int:
    up_a = skeleton.ancestors(a)
    for bone in skeleton.ancestors(b):
        if bone in up_a:
            return bone
    return -1


def plan_chain(
    skeleton: Skeleton, state: PoseState, camera: Camera, first_point: np.ndarray,
    options: StrokeOptions,
) -> ChainPlan:
    """Decide which chain(s) a stroke poses (Section 4).

    Args:
        skeleton: The skeleton.
        state: Its current forward kinematics.
        camera: The view.
        first_point: The stroke's first point in pixels, shape ``(2,)``.
        options: Start, direction and end bones and the pick radius.

    Returns:
        The plan.

    Raises:
        InputError: Unknown bones, no joint near the stroke start, or bones in separate
            trees.
    """
    direction_path: frozenset[int] = frozenset()
    if options.direction_bone is not None:
        direction_path = frozenset(skeleton.ancestors(skeleton.index(options.direction_bone)))
    if options.start_bone is None:
        starts = pick_start(skeleton, state, camera, first_point, options.pick_radius)
        _check_direction(skeleton, starts, options.direction_bone)
        part = ChainPart(starts, None, -1, False)
        return ChainPlan(PlanKind.FORWARD, (part,), -1, direction_path)
    start = skeleton.index(options.start_bone)
    if options.end_bone is None:
        _check_direction(skeleton, (start,), options.direction_bone)
        return ChainPlan(PlanKind.FORWARD, (ChainPart((start,), None, -1, False),), -1,
                         direction_path)
    end = skeleton.index(options.end_bone)
    if start in skeleton.ancestors(end):
        bones = tuple(reversed(_path_up(skeleton, end, int(skeleton.parents[start]))))
        return ChainPlan(PlanKind.FORWARD, (ChainPart((start,), bones, end, False),))
    if end in skeleton.ancestors(start):
        bones = tuple(reversed(_path_up(skeleton, start, int(skeleton.parents[end]))))
        return ChainPlan(PlanKind.REVERSED, (ChainPart((end,), bones, start, True),))
    ancestor = _lowest_common_ancestor(skeleton, start, end)
    if ancestor < 0:
        raise InputError(
            f"Bones '{options.start_bone}' and '{options.end_bone}' are in separate trees of "
            "the armature: one stroke can only pose connected bones."
        )
    begin = tuple(reversed(_path_up(skeleton, start, ancestor)))
    finish = tuple(reversed(_path_up(skeleton, end, ancestor)))
    parts = (
        ChainPart((begin[0],), begin, begin[-1], True),
        ChainPart((finish[0],), finish, finish[-1], False),
    )
    return ChainPlan(PlanKind.OVER_ROOT, parts, ancestor)


def _check_direction(skeleton: Skeleton, starts: tuple[int, ...], direction: str | None) -> None:
    """Refuse a direction bone that no chain from ``starts`` can reach."""
    if direction is None:
        return
    below = skeleton.ancestors(skeleton.index(direction))
    if not any(s in below for s in starts):
        names = ", ".join(f"'{skeleton.names[s]}'" for s in starts)
        raise InputError(f"The direction bone '{direction}' is not below the joint the stroke "
                         f"starts at (bones {names}): pick a bone in the part you are drawing, "
                         "or clear the direction bone.")


def next_candidates(
    skeleton: Skeleton, bone: int, direction_path: frozenset[int]
) -> np.ndarray:
    """Children that may continue a chain after ``bone``, restricted to ``direction_path``.

    Returns:
        Child bone indices, shape ``(k,)`` (empty at a leaf).
    """
    kids = skeleton.children(bone)
    if direction_path:
        on_path = [k for k in kids if k in direction_path]
        if on_path:
            return np.asarray(on_path, dtype=int)
    return kids
