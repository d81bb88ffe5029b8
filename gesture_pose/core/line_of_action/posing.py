"""Posing one downward chain along its piece of the stroke (Sections 5-6).

Walks the chain from its first joint: Eq. 2 picks each joint's feature point, Eq. 4 places
the joint, the bone's local rotation is computed directly from the new direction with its
twist kept (everything below follows through forward kinematics), and Eq. 3 renormalizes
the arc length. At a branch the child whose rotation has the smallest magnitude continues
the chain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..rotations3 import mm3, mv3, reswing, rotation_between3
from ..skeleton import PoseState, Skeleton
from .alignment import (
    StrokeRays,
    ViewOps,
    joint_plane_depth,
    place_joint,
    stroke_circle_crossing,
)
from .chain import next_candidates
from .features import SampledStroke, feature_param, renormalize_param
from .options import PlaneMode, StrokeOptions, Tracking


def _unit(v: np.ndarray) -> np.ndarray:
    x, y, z = v.tolist()
    n = math.sqrt(x * x + y * y + z * z)
    return np.array([x / n, y / n, z / n])


@dataclass
class ChainState:
    """Working copy of the pose while one stroke is applied.

    The walk down a chain only ever needs the bone it is posing and that bone's children,
    and their parents are final by then; so a bone's world state is recomputed from its
    parent by one forward-kinematics step when it is reached (:meth:`refresh`), instead of
    rotating whole subtrees after every joint. Bones off the walked chain may hold stale
    world data; the local rotations are always current.

    Attributes:
        skeleton: The skeleton.
        rotations: Local rotations, shape ``(n, 3, 3)``.
        translations: Local translations, shape ``(n, 3)``.
        heads: World heads, shape ``(n, 3)``.
        tails: World tails, shape ``(n, 3)``.
        frames: World frames, shape ``(n, 3, 3)``.
        lengths: Bone lengths, shape ``(n,)``.
        offsets: Each head in its parent's posed frame, ``R_p^T (r_i - r_p + R_i t_i)``
            (world point for roots), shape ``(n, 3)``.
    """

    skeleton: Skeleton
    rotations: np.ndarray
    translations: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    frames: np.ndarray
    lengths: np.ndarray
    offsets: np.ndarray

    @classmethod
    def from_state(cls, skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray,
                   state: PoseState) -> ChainState:
        """Copy a pose and its forward kinematics."""
        rel_rot, rel_off = skeleton.rest_relative
        offsets = rel_off + np.einsum("nij,nj->ni", rel_rot, translations)
        return cls(skeleton, rotations.copy(), translations, state.heads.copy(),
                   state.tails.copy(), state.frames.copy(), skeleton.lengths, offsets)

    def copy(self) -> ChainState:
        """An independent copy (for dry runs)."""
        return ChainState(self.skeleton, self.rotations.copy(), self.translations,
                          self.heads.copy(), self.tails.copy(), self.frames.copy(),
                          self.lengths, self.offsets)

    def carry(self, bone: int) -> np.ndarray:
        """``C`` with ``F = C Q`` for ``bone`` (its parent's frame must be current)."""
        sk = self.skeleton
        rel_rot = sk.rest_relative[0][bone]
        p = sk.parents[bone]
        if p < 0 or not sk.inherit_rotation[bone]:
            return sk.rest_frames[bone] if p >= 0 else rel_rot
        return mm3(self.frames[p], rel_rot)

    def refresh_head(self, bone: int) -> None:
        """Recompute ``bone``'s world head from its (current) parent."""
        off = self.offsets[bone]
        p = self.skeleton.parents[bone]
        self.heads[bone] = off if p < 0 else self.heads[p] + mv3(self.frames[p], off)

    def refresh(self, bone: int) -> None:
        """Recompute ``bone``'s world head, tail and frame from its (current) parent."""
        self.refresh_head(bone)
        self.set_rotation(bone, self.rotations[bone])

    def set_rotation(self, bone: int, local: np.ndarray) -> None:
        """Set a bone's local rotation and its world frame and tail (head unchanged)."""
        self.rotations[bone] = local
        frame = mm3(self.carry(bone), local)
        self.frames[bone] = frame
        self.tails[bone] = self.heads[bone] + frame[:, 1] * self.lengths[bone]


def aimed_rotation(cs: ChainState, bone: int, seg_end: np.ndarray,
                   new_end: np.ndarray) -> tuple[np.ndarray, float]:
    """Local rotation of ``bone`` moving its segment end to ``new_end``, and the angle moved.

    The rotation is computed directly, not compounded: for a segment along the bone
    (connected child or tail) it is the swing taking y to the new direction times the old
    twist, so the twist about the bone is preserved; for an offset child it is the smallest
    rotation of the segment.

    Args:
        cs: Working pose.
        bone: Bone index.
        seg_end: Current world end of the bone's segment, shape ``(3,)``.
        new_end: Desired world end, shape ``(3,)``.

    Returns:
        ``(local rotation (3, 3), angle in radians)``.
    """
    head = cs.heads[bone]
    frame, q = cs.frames[bone], cs.rotations[bone]
    carry = cs.carry(bone)
    cur_dir = _unit(seg_end - head)
    new_dir = _unit(new_end - head)
    angle = math.acos(max(-1.0, min(1.0, float(cur_dir @ new_dir))))
    target_local = mv3(carry.T, new_dir)
    if float(frame[:, 1] @ cur_dir) > 1.0 - 1e-9:  # the segment runs along the bone's y
        return reswing(q, target_local), angle
    delta, _ = rotation_between3(mv3(q, mv3(frame.T, cur_dir)), target_local)
    return mm3(delta, q), angle


@dataclass(frozen=True)
class Trial:
    """Where one bone's segment would go.

    Attributes:
        rotation: New local rotation, or None when the bone is skipped (view axis).
        angle: Rotation magnitude, radians.
        param: Arc length of the joint's point on the stroke, pixels.
        target: Target pixel, shape ``(2,)``.
        projected: Projected segment length, pixels.
        depth_kept: False when the joint could not keep its depth (its parent moved too far
            in depth) and kept its current one instead.
        on_stroke: The joint lands exactly on the stroke at ``param`` (a ray-circle
            crossing), so Eq. 3's search would return ``param`` itself.
    """

    rotation: np.ndarray | None
    angle: float
    param: float
    target: np.ndarray
    projected: float
    depth_kept: bool = True
    on_stroke: bool = False


@dataclass(frozen=True)
class PartOutcome:
    """What posing one chain did.

    Attributes:
        bones: Chain bones in order.
        targets: Target pixel of each segment end, shape ``(k, 2)``.
        landed: Projection of each posed segment end, shape ``(k, 2)``.
        skipped: Bones left alone because they lie along the view axis.
        angles: Rotation magnitude applied to each bone, radians, shape ``(k,)``.
        ends: For each bone, the child whose head ends its segment, or -1 for its tail.
        depth_moved: Bones whose end joint could not keep its depth.
    """

    bones: tuple[int, ...]
    targets: np.ndarray
    landed: np.ndarray
    skipped: tuple[int, ...]
    angles: np.ndarray
    ends: tuple[int, ...] = ()
    depth_moved: tuple[int, ...] = ()


@dataclass(frozen=True)
class PartSpec:
    """Inputs of :func:`pose_part` besides the working pose.

    Attributes:
        start_candidates: Bones that may start the chain.
        fixed_bones: Predetermined chain, or None to choose at branches.
        direction_path: Bones the chain must follow where it can.
        stop_when_exhausted: End the chain when the stroke runs out (position tracking).
    """

    start_candidates: tuple[int, ...]
    fixed_bones: tuple[int, ...] | None
    direction_path: frozenset[int]
    stop_when_exhausted: bool


class _Walker:
    """One pass down a chain; holds the per-pass constants."""

    def __init__(self, skeleton: Skeleton, view: ViewOps, sampled: SampledStroke,
                 options: StrokeOptions, cs: ChainState) -> None:
        self.sk, self.view, self.sampled, self.opt, self.cs = (
            skeleton, view, sampled, options, cs)
        self.plane = options.mode is PlaneMode.PLANE
        self.shape = options.tracking is Tracking.SHAPE
        self.head_depth = view.depth(cs.heads)
        self.tail_depth = view.depth(cs.tails)
        self.crossing = (options.feature_extraction and options.stroke_crossing
                         and not self.shape)
        if self.crossing:
            self.rays = StrokeRays.through(view, sampled.params, sampled.points)
        right = np.cross(view.forward, [0.0, 0.0, 1.0])
        if np.linalg.norm(right) < 1e-6:
            right = np.cross(view.forward, [0.0, 1.0, 0.0])
        self.right = right / np.linalg.norm(right)
        self.right_floats = self.right.tolist()

    def projected_length(self, start: np.ndarray, end: np.ndarray) -> float:
        """Pixels the segment covers now, or would cover orthogonal to the view (plane)."""
        sx, sy, sz = start.tolist()
        ex, ey, ez = end.tolist()
        if self.plane:
            length = math.sqrt((ex - sx) ** 2 + (ey - sy) ** 2 + (ez - sz) ** 2)
            rx, ry, rz = self.right_floats
            ex, ey, ez = sx + rx * length, sy + ry * length, sz + rz * length
        x0, y0 = self.view.project_point(sx, sy, sz)
        x1, y1 = self.view.project_point(ex, ey, ez)
        return math.hypot(x1 - x0, y1 - y0)

    def target(self, s_prev: float, lp: float,
               landed_prev: np.ndarray) -> tuple[float, np.ndarray, bool]:
        """Eq. 2 for a segment projecting to ``lp`` px: arc length, target pixel, feature?"""
        guess = min(s_prev + lp, self.sampled.length)
        s, feature = guess, False
        if self.opt.feature_extraction:
            found = feature_param(self.sampled, guess, lp / 3.0, self.opt.feature_min_curvature)
            if found is not None:
                s, feature = found, True
        if self.shape:
            return s, landed_prev + self.sampled.at(s) - self.sampled.at(s_prev), feature
        return s, self.sampled.at(s), feature

    def try_bone(self, bone: int, seg_end: np.ndarray, end_child: int, s_prev: float,
                 landed_prev: np.ndarray) -> Trial:
        """Placement of one bone's segment (Eqs. 2 and 4).

        ``end_child`` is the child whose head ends the segment, or -1 for the bone's tail.
        """
        head = self.cs.heads[bone]
        dx, dy, dz = (seg_end - head).tolist()
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        if length < 1e-12:
            return Trial(None, 0.0, s_prev, landed_prev, 0.0)
        original = self.tail_depth[bone] if end_child < 0 else self.head_depth[end_child]
        depth = joint_plane_depth(self.view, head, seg_end, length, original, self.plane,
                                  self.opt.view_axis_tolerance)
        kept = self.plane or depth == original
        lp = self.projected_length(head, seg_end)
        s, tgt, feature = self.target(s_prev, lp, landed_prev)
        on_stroke = False
        if self.crossing and not feature:
            root = stroke_circle_crossing(self.view, self.rays, head, length, depth, s_prev, s)
            if root is not None and abs(root - s) <= max(lp, 2.0 * self.sampled.step):
                s, tgt, on_stroke = root, self.sampled.at(root), True
        placed = place_joint(self.view, head, seg_end, length, tgt, depth,
                             self.opt.view_axis_tolerance)
        if placed.skipped:
            return Trial(None, 0.0, s, tgt, lp, kept)
        rot, angle = aimed_rotation(self.cs, bone, seg_end, placed.position)
        return Trial(rot, angle, s, tgt, lp, kept, on_stroke)


def _segment_ends(skeleton: Skeleton, cs: ChainState, bone: int,
                  kids: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Group candidate children by head position: ``[(end point, children), ...]``."""
    if kids.size == 0:
        return [(cs.tails[bone], kids)]
    groups: list[tuple[np.ndarray, np.ndarray]] = []
    span = cs.tails[bone] - cs.heads[bone]
    tol2 = (1e-6 * max(math.sqrt(float(span @ span)), 1e-9)) ** 2
    for k in kids:
        for gi, (p, members) in enumerate(groups):
            gap = cs.heads[k] - p
            if float(gap @ gap) <= tol2:
                groups[gi] = (p, np.append(members, k))
                break
        else:
            groups.append((cs.heads[k].copy(), np.array([k])))
    return groups


def pose_part(skeleton: Skeleton, view: ViewOps, sampled: SampledStroke, cs: ChainState,
              spec: PartSpec, options: StrokeOptions) -> PartOutcome:
    """Pose one chain along a (prepared) stroke piece, updating ``cs`` in place.

    Args:
        skeleton: The skeleton.
        view: Camera operations.
        sampled: The stroke piece, starting on the chain's first joint (Eq. 1).
        cs: Working pose, modified in place.
        spec: Chain candidates and stopping rule.
        options: Posing options.

    Returns:
        What was posed.
    """
    walker = _Walker(skeleton, view, sampled, options, cs)
    fixed = spec.fixed_bones
    candidates = np.asarray(fixed[:1] if fixed else spec.start_candidates, dtype=int)
    s_prev, landed_prev = 0.0, sampled.at(0.0)
    bones, targets, landed, skipped, angles = [], [], [], [], []
    seg_ends: list[int] = []
    depth_moved: list[int] = []
    while candidates.size:
        for c in candidates.tolist():
            cs.refresh(c)  # their parent is final now
        bone = _choose(skeleton, walker, candidates, s_prev, landed_prev)
        pos = len(bones)
        if fixed is not None:
            kids = np.asarray(fixed[pos + 1:pos + 2], dtype=int)
        else:
            kids = next_candidates(skeleton, bone, spec.direction_path)
        for k in kids.tolist():
            cs.refresh_head(k)  # where the segment ends before the bone turns
        ends = _segment_ends(skeleton, cs, bone, kids)
        trials = [walker.try_bone(bone, end, int(m[0]) if m.size else -1, s_prev, landed_prev)
                  for end, m in ends]
        best = _choose_branch(walker, bone, ends, trials) if len(ends) > 1 else 0
        trial = trials[best]
        end, members = ends[best]
        if spec.stop_when_exhausted and fixed is None and pos > 0:
            if sampled.length - s_prev < 0.5 * trial.projected:
                break
        offset_local = mv3(cs.frames[bone].T, end - cs.heads[bone])
        if trial.rotation is None:
            skipped.append(bone)
        else:
            cs.set_rotation(bone, trial.rotation)
        if not trial.depth_kept:
            depth_moved.append(bone)
        new_end = cs.heads[bone] + mv3(cs.frames[bone], offset_local)
        land = np.array(view.project_point(*new_end.tolist()))
        s = trial.param
        if (options.tracking is Tracking.POSITION and options.feature_extraction
                and not trial.on_stroke):
            s = renormalize_param(sampled, land, s, max(trial.projected / 3.0,
                                                        2.0 * sampled.step))
        bones.append(bone)
        seg_ends.append(int(members[0]) if members.size else -1)
        targets.append(trial.target)
        landed.append(land)
        angles.append(trial.angle if trial.rotation is not None else 0.0)
        s_prev, landed_prev = s, land
        candidates = members
        if fixed is not None and pos + 1 >= len(fixed):
            break
    return PartOutcome(tuple(bones), np.array(targets).reshape(-1, 2),
                       np.array(landed).reshape(-1, 2), tuple(skipped), np.array(angles),
                       tuple(seg_ends), tuple(depth_moved))


def _choose_branch(walker: _Walker, bone: int, ends: list[tuple[np.ndarray, np.ndarray]],
                   trials: list[Trial]) -> int:
    """At a branch whose children start at different points, the group to continue into.

    Each choice is tried on a copy: the bone turns towards that child's head, then the
    child's own alignment is computed; the child needing the smallest rotation wins (the
    parent's rotations differ little, since the children's heads are close).

    Returns:
        Index into ``ends``.
    """
    cs = walker.cs
    costs = []
    for (end, members), trial in zip(ends, trials, strict=True):
        if trial.rotation is None or members.size == 0:
            costs.append(np.inf if trial.rotation is None else trial.angle)
            continue
        trial_cs = cs.copy()
        offset = trial_cs.frames[bone].T @ (end - trial_cs.heads[bone])
        trial_cs.set_rotation(bone, trial.rotation)
        landed = walker.view.project(trial_cs.heads[bone] + trial_cs.frames[bone] @ offset)
        walker.cs = trial_cs
        try:
            for m in members.tolist():
                trial_cs.refresh(m)
            child = [walker.try_bone(m, trial_cs.tails[m], -1, trial.param, landed)
                     for m in members.tolist()]
        finally:
            walker.cs = cs
        costs.append(min(t.angle if t.rotation is not None else np.inf for t in child))
    return int(np.argmin(costs)) if np.isfinite(np.min(costs)) else 0


def _choose(skeleton: Skeleton, walker: _Walker, candidates: np.ndarray, s_prev: float,
            landed_prev: np.ndarray) -> int:
    """The candidate bone whose own alignment needs the smallest rotation."""
    if candidates.size == 1:
        return int(candidates[0])
    cs = walker.cs
    angles = []
    for c in candidates:
        trial = walker.try_bone(int(c), cs.tails[c], -1, s_prev, landed_prev)
        angles.append(trial.angle if trial.rotation is not None else np.inf)
    return int(candidates[int(np.argmin(angles))])
