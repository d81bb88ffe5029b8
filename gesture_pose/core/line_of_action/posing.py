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

from ..rotations3 import M3, between, mtv, mul, mv, swap_swing
from ..skeleton import PoseState, Skeleton
from .alignment import (
    StrokeRays,
    ViewOps,
    joint_plane_depth,
    place_point,
    stroke_circle_crossing,
)
from .chain import next_candidates
from .features import SampledStroke, feature_param, renormalize_param
from .options import PlaneMode, StrokeOptions, Tracking


def _unit(x: float, y: float, z: float) -> list[float]:
    n = math.sqrt(x * x + y * y + z * z)
    return [x / n, y / n, z / n]


@dataclass(frozen=True)
class _Tables:
    """Per-skeleton constants of one solve, as Python lists (see :class:`ChainState`)."""

    parents: list[int]
    inherit: list[bool]
    rel_rot: list[M3]
    rest_frames: list[M3]
    lengths: list[float]
    offsets: list[list[float]]


@dataclass
class ChainState:
    """Working copy of the pose while one stroke is applied, on Python floats.

    The walk down a chain only ever needs the bone it is posing and that bone's children,
    and their parents are final by then; so a bone's world state is recomputed from its
    parent by one forward-kinematics step when it is reached (:meth:`refresh`), instead of
    rotating whole subtrees after every joint. Bones off the walked chain may hold stale
    world data; the local rotations are always current.

    The per-joint work is a few dozen 3-vector and 3x3 operations, where numpy's per-call
    overhead would dominate: the state is kept as nested lists (rows are replaced, never
    edited in place, so a shallow copy is an independent copy) and exposed as arrays.

    Attributes:
        skeleton: The skeleton.
        translations: Local translations, shape ``(n, 3)``.
        q: Local rotations, ``n`` nested 3x3 lists.
        h: World heads, ``n`` lists of three floats.
        t: World tails, ``n`` lists of three floats.
        f: World frames, ``n`` nested 3x3 lists.
        tables: The skeleton's constants; ``offsets`` holds each head in its parent's
            posed frame, ``R_p^T (r_i - r_p + R_i t_i)`` (world point for roots).
    """

    skeleton: Skeleton
    translations: np.ndarray
    q: list[M3]
    h: list[list[float]]
    t: list[list[float]]
    f: list[M3]
    tables: _Tables

    @classmethod
    def from_state(cls, skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray,
                   state: PoseState) -> ChainState:
        """Copy a pose and its forward kinematics."""
        rel_rot, rel_off = skeleton.rest_relative
        offsets = rel_off + np.einsum("nij,nj->ni", rel_rot, translations)
        rel_rot_lists, rest_lists = skeleton.rest_relative_lists
        tables = _Tables(skeleton.parents.tolist(), skeleton.inherit_rotation.tolist(),
                         rel_rot_lists, rest_lists, skeleton.lengths.tolist(),
                         offsets.tolist())
        return cls(skeleton, translations, rotations.tolist(), state.heads.tolist(),
                   state.tails.tolist(), state.frames.tolist(), tables)

    @property
    def rotations(self) -> np.ndarray:
        """Local rotations, shape ``(n, 3, 3)``."""
        return np.array(self.q)

    @property
    def heads(self) -> np.ndarray:
        """World heads, shape ``(n, 3)``."""
        return np.array(self.h)

    @property
    def tails(self) -> np.ndarray:
        """World tails, shape ``(n, 3)``."""
        return np.array(self.t)

    @property
    def frames(self) -> np.ndarray:
        """World frames, shape ``(n, 3, 3)``."""
        return np.array(self.f)

    def copy(self) -> ChainState:
        """An independent copy (for dry runs)."""
        return ChainState(self.skeleton, self.translations, list(self.q), list(self.h),
                          list(self.t), list(self.f), self.tables)

    def carry(self, bone: int) -> M3:
        """``C`` with ``F = C Q`` for ``bone`` (its parent's frame must be current)."""
        tb = self.tables
        p = tb.parents[bone]
        if p < 0:
            return tb.rel_rot[bone]
        if not tb.inherit[bone]:
            return tb.rest_frames[bone]
        return mul(self.f[p], tb.rel_rot[bone])

    def refresh_head(self, bone: int) -> None:
        """Recompute ``bone``'s world head from its (current) parent."""
        off = self.tables.offsets[bone]
        p = self.tables.parents[bone]
        if p < 0:
            self.h[bone] = off
            return
        (x, y, z), (dx, dy, dz) = self.h[p], mv(self.f[p], off)
        self.h[bone] = [x + dx, y + dy, z + dz]

    def refresh(self, bone: int) -> None:
        """Recompute ``bone``'s world head, tail and frame from its (current) parent."""
        self.refresh_head(bone)
        self.set_rotation(bone, self.q[bone])

    def set_rotation(self, bone: int, local: M3) -> None:
        """Set a bone's local rotation and its world frame and tail (head unchanged)."""
        self.q[bone] = local
        frame = mul(self.carry(bone), local)
        self.f[bone] = frame
        length = self.tables.lengths[bone]
        x, y, z = self.h[bone]
        self.t[bone] = [x + frame[0][1] * length, y + frame[1][1] * length,
                        z + frame[2][1] * length]

    def segment_point(self, bone: int, local: list[float]) -> list[float]:
        """World position of a point given in ``bone``'s frame relative to its head."""
        (x, y, z), (dx, dy, dz) = self.h[bone], mv(self.f[bone], local)
        return [x + dx, y + dy, z + dz]

    def local_offset(self, bone: int, point: list[float]) -> list[float]:
        """``point`` in ``bone``'s frame relative to its head (inverse of the above)."""
        x, y, z = self.h[bone]
        px, py, pz = point
        return mtv(self.f[bone], (px - x, py - y, pz - z))


def aimed_rotation(cs: ChainState, bone: int, seg_end: list[float],
                   new_end: tuple[float, float, float]) -> tuple[M3, float]:
    """Local rotation of ``bone`` moving its segment end to ``new_end``, and the angle moved.

    The rotation is computed directly, not compounded: for a segment along the bone
    (connected child or tail) it is the swing taking y to the new direction times the old
    twist, so the twist about the bone is preserved; for an offset child it is the smallest
    rotation of the segment.

    Args:
        cs: Working pose.
        bone: Bone index.
        seg_end: Current world end of the bone's segment (three floats).
        new_end: Desired world end (three floats).

    Returns:
        ``(local rotation (3x3 nested list), angle in radians)``.
    """
    hx, hy, hz = cs.h[bone]
    frame, q = cs.f[bone], cs.q[bone]
    cur = _unit(seg_end[0] - hx, seg_end[1] - hy, seg_end[2] - hz)
    new = _unit(new_end[0] - hx, new_end[1] - hy, new_end[2] - hz)
    angle = math.acos(max(-1.0, min(1.0, cur[0] * new[0] + cur[1] * new[1] + cur[2] * new[2])))
    target_local = mtv(cs.carry(bone), new)
    if frame[0][1] * cur[0] + frame[1][1] * cur[1] + frame[2][1] * cur[2] > 1.0 - 1e-9:
        return swap_swing(q, target_local), angle  # the segment runs along the bone's y
    delta, _ = between(mv(q, mtv(frame, cur)), target_local)
    return mul(delta, q), angle


@dataclass(frozen=True)
class Trial:
    """Where one bone's segment would go.

    Attributes:
        rotation: New local rotation (3x3 nested list), or None when the bone is skipped
            (view axis).
        angle: Rotation magnitude, radians.
        param: Arc length of the joint's point on the stroke, pixels.
        target: Target pixel ``(x, y)``.
        projected: Projected segment length, pixels.
        depth_kept: False when the joint could not keep its depth (its parent moved too far
            in depth) and kept its current one instead.
        on_stroke: The joint lands exactly on the stroke at ``param`` (a ray-circle
            crossing), so Eq. 3's search would return ``param`` itself.
    """

    rotation: M3 | None
    angle: float
    param: float
    target: tuple[float, float]
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
        self.head_depth = view.depth(cs.heads).tolist()
        self.tail_depth = view.depth(cs.tails).tolist()
        self.crossing = (options.feature_extraction and options.stroke_crossing
                         and not self.shape)
        if self.crossing:
            self.rays = StrokeRays.through(view, sampled.params, sampled.points)
        fx, fy, _ = view.forward.tolist()  # right = forward x z, or forward x y when level
        rx, ry, rz = fy, -fx, 0.0
        if math.hypot(rx, ry) < 1e-6:
            fz = float(view.forward[2])
            rx, ry, rz = -fz, 0.0, fx
        self.right = _unit(rx, ry, rz)

    def projected_length(self, start: list[float], end: list[float]) -> float:
        """Pixels the segment covers now, or would cover orthogonal to the view (plane)."""
        sx, sy, sz = start
        ex, ey, ez = end
        if self.plane:
            length = math.sqrt((ex - sx) ** 2 + (ey - sy) ** 2 + (ez - sz) ** 2)
            rx, ry, rz = self.right
            ex, ey, ez = sx + rx * length, sy + ry * length, sz + rz * length
        x0, y0 = self.view.project_point(sx, sy, sz)
        x1, y1 = self.view.project_point(ex, ey, ez)
        return math.hypot(x1 - x0, y1 - y0)

    def target(self, s_prev: float, lp: float,
               landed_prev: tuple[float, float]) -> tuple[float, tuple[float, float], bool]:
        """Eq. 2 for a segment projecting to ``lp`` px: arc length, target pixel, feature?"""
        guess = min(s_prev + lp, self.sampled.length)
        s, feature = guess, False
        if self.opt.feature_extraction:
            found = feature_param(self.sampled, guess, lp / 3.0, self.opt.feature_min_curvature)
            if found is not None:
                s, feature = found, True
        x, y = self.sampled.at_xy(s)
        if self.shape:
            x0, y0 = self.sampled.at_xy(s_prev)
            return s, (landed_prev[0] + x - x0, landed_prev[1] + y - y0), feature
        return s, (x, y), feature

    def try_bone(self, bone: int, seg_end: list[float], end_child: int, s_prev: float,
                 landed_prev: tuple[float, float]) -> Trial:
        """Placement of one bone's segment (Eqs. 2 and 4).

        ``end_child`` is the child whose head ends the segment, or -1 for the bone's tail.
        """
        head = self.cs.h[bone]
        dx, dy, dz = seg_end[0] - head[0], seg_end[1] - head[1], seg_end[2] - head[2]
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        if length < 1e-12:
            return Trial(None, 0.0, s_prev, landed_prev, 0.0)
        original = self.tail_depth[bone] if end_child < 0 else self.head_depth[end_child]
        tolerance = self.opt.view_axis_tolerance
        depth = joint_plane_depth(self.view, head, seg_end, length, original, self.plane,
                                  tolerance)
        kept = self.plane or depth == original
        lp = self.projected_length(head, seg_end)
        s, tgt, feature = self.target(s_prev, lp, landed_prev)
        on_stroke = False
        if self.crossing and not feature:
            root = stroke_circle_crossing(self.view, self.rays, head, length, depth, s_prev, s)
            if root is not None and abs(root - s) <= max(lp, 2.0 * self.sampled.step):
                s, tgt, on_stroke = root, self.sampled.at_xy(root), True
        position, _ = place_point(self.view, head, length, seg_end, tgt[0], tgt[1], depth,
                                  tolerance)
        if position is None:
            return Trial(None, 0.0, s, tgt, lp, kept)
        rot, angle = aimed_rotation(self.cs, bone, seg_end, position)
        return Trial(rot, angle, s, tgt, lp, kept, on_stroke)


def _segment_ends(cs: ChainState, bone: int,
                  kids: np.ndarray) -> list[tuple[list[float], list[int]]]:
    """Group candidate children by head position: ``[(end point, children), ...]``."""
    if kids.size == 0:
        return [(cs.t[bone], [])]
    groups: list[tuple[list[float], list[int]]] = []
    (hx, hy, hz), (tx, ty, tz) = cs.h[bone], cs.t[bone]
    tol2 = (1e-6 * max(math.sqrt((tx - hx) ** 2 + (ty - hy) ** 2 + (tz - hz) ** 2),
                       1e-9)) ** 2
    for k in kids.tolist():
        kx, ky, kz = cs.h[k]
        for p, members in groups:
            if (kx - p[0]) ** 2 + (ky - p[1]) ** 2 + (kz - p[2]) ** 2 <= tol2:
                members.append(k)
                break
        else:
            groups.append((cs.h[k], [k]))
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
    candidates = list(fixed[:1] if fixed else spec.start_candidates)
    s_prev, landed_prev = 0.0, sampled.at_xy(0.0)
    renormalize = options.tracking is Tracking.POSITION and options.feature_extraction
    bones, targets, landed, skipped, angles = [], [], [], [], []
    seg_ends: list[int] = []
    depth_moved: list[int] = []
    while candidates:
        for c in candidates:
            cs.refresh(c)  # their parent is final now
        bone = _choose(walker, candidates, s_prev, landed_prev)
        pos = len(bones)
        if fixed is not None:
            kids = np.asarray(fixed[pos + 1:pos + 2], dtype=int)
        else:
            kids = next_candidates(skeleton, bone, spec.direction_path)
        for k in kids.tolist():
            cs.refresh_head(k)  # where the segment ends before the bone turns
        ends = _segment_ends(cs, bone, kids)
        trials = [walker.try_bone(bone, end, m[0] if m else -1, s_prev, landed_prev)
                  for end, m in ends]
        best = _choose_branch(walker, bone, ends, trials) if len(ends) > 1 else 0
        trial = trials[best]
        end, members = ends[best]
        if spec.stop_when_exhausted and fixed is None and pos > 0:
            if sampled.length - s_prev < 0.5 * trial.projected:
                break
        offset_local = cs.local_offset(bone, end)
        if trial.rotation is None:
            skipped.append(bone)
        else:
            cs.set_rotation(bone, trial.rotation)
        if not trial.depth_kept:
            depth_moved.append(bone)
        land = view.project_point(*cs.segment_point(bone, offset_local))
        s = trial.param
        if renormalize and not trial.on_stroke:
            s = renormalize_param(sampled, np.array(land), s,
                                  max(trial.projected / 3.0, 2.0 * sampled.step))
        bones.append(bone)
        seg_ends.append(members[0] if members else -1)
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


def _choose_branch(walker: _Walker, bone: int, ends: list[tuple[list[float], list[int]]],
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
        if trial.rotation is None or not members:
            costs.append(math.inf if trial.rotation is None else trial.angle)
            continue
        trial_cs = cs.copy()
        offset = trial_cs.local_offset(bone, end)
        trial_cs.set_rotation(bone, trial.rotation)
        landed = walker.view.project_point(*trial_cs.segment_point(bone, offset))
        walker.cs = trial_cs
        try:
            for m in members:
                trial_cs.refresh(m)
            child = [walker.try_bone(m, trial_cs.t[m], -1, trial.param, landed)
                     for m in members]
        finally:
            walker.cs = cs
        costs.append(min(t.angle if t.rotation is not None else math.inf for t in child))
    return int(np.argmin(costs)) if math.isfinite(min(costs)) else 0


def _choose(walker: _Walker, candidates: list[int], s_prev: float,
            landed_prev: tuple[float, float]) -> int:
    """The candidate bone whose own alignment needs the smallest rotation."""
    if len(candidates) == 1:
        return candidates[0]
    cs = walker.cs
    angles = []
    for c in candidates:
        trial = walker.try_bone(c, cs.t[c], -1, s_prev, landed_prev)
        angles.append(trial.angle if trial.rotation is not None else math.inf)
    return candidates[int(np.argmin(angles))]
