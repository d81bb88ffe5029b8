"""Which depth sides of a leg or an arm a body can take: joint-limit plausibility (ours).

A drawn link fixes how far a bone leaves the view plane, not to which side (Gesture3D
Section 7); the start picks each foreshortened bone's side by rules (:mod:`.start`), and
the solve ends on the side it starts on. A leg's sides are not free, though: the knee is
a hinge that flexes one way only, the hip rotates the thigh about its own axis by about 45
degrees either way and extends it behind the pelvis by about 30, and the ankle holds the
foot near the shin's front. Mirroring one bone of a drawn leg about the view plane keeps
the drawing and usually breaks one of these. This module scores the 2, 4 or 8 mirror
combinations of a solved leg's bones (thigh, shin, foot) against those ranges, on
the pose the first solve reached, whose pelvis is read from the drawn hips (the start's
pelvis keeps its bind twist and faced 44-128 degrees off on 16 of the 40 CMU poses, the
solved one within 15 on 31), and returns the sides of the most plausible one when it
is clearly more plausible than the solved one.

The ranges are anatomical, read in the rig's own terms: the front is the character's
(:func:`.start.front_direction`), carried by the solved pelvis; a straight rest leg's
thigh hangs along the carried rest direction; the foot keeps its rest angle to the shin.

The arms (:func:`arm_sides`): the shoulder rotates the upper arm about its axis by
about 90 degrees either way, so the elbow's plane says less than the knee's; only an
upper arm whose solved elbow bends beyond that range is mirrored (the start's upper
arms have no cue but the character's front).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...names import side_of
from ...rotations import rotation_between
from ...skeleton import Pose, Skeleton
from ..types import SolvingSkeleton
from . import start


@dataclass(frozen=True)
class LegLimits:
    """Joint ranges of a leg, degrees, and the decision thresholds.

    Attributes:
        hip_twist: Largest rotation of the thigh about its own axis away from the front
            its pelvis carries (the knee's plane of flexion), degrees.
        hip_extension: Largest swing of the thigh behind its carried rest direction, in
            the pelvis's plane of flexion, degrees.
        ankle: Largest angle between the foot and its rest direction relative to the
            shin's front, degrees.
        twist_share: Weight of the twist itself, within the range (degrees times the
            sine of the knee's bend), which tells apart combinations all within range.
        margin: Smallest cost difference, degrees, for a combination to replace the
            solved one.
        thigh_tolerance: A thigh keeps its solved side when some combination that keeps
            it costs at most this much, degrees: the thigh's side has the most support
            (the pelvis's front, :func:`.start.pelvis_front_sides`).
    """

    hip_twist: float = 45.0
    hip_extension: float = 30.0
    ankle: float = 60.0
    twist_share: float = 0.1
    margin: float = 15.0
    thigh_tolerance: float = 10.0


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two vectors, degrees."""
    cos = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-12)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _swing(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """The smallest rotation taking direction ``a`` to ``b``, ``(3, 3)``.

    None within 8 degrees of opposite directions, where the rotation's axis is a guess.
    """
    c = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-12)
    return None if c < -0.99 else rotation_between(a, b)


def _unit_perp(v: np.ndarray, axis: np.ndarray) -> np.ndarray | None:
    """The unit component of ``v`` orthogonal to the unit ``axis`` (None: along it)."""
    p = v - float(v @ axis) * axis
    n = float(np.linalg.norm(p))
    return p / n if n > 1e-9 * max(float(np.linalg.norm(v)), 1e-12) else None


def _mirrored(v: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """``v`` mirrored about the view plane (unit view direction ``forward``), ``(3,)``.

    The mirror image projects where ``v`` does (orthographically), at the other depth.
    """
    return v - 2.0 * float(v @ forward) * forward


def _depth_side(v: np.ndarray, forward: np.ndarray) -> float:
    """+1 when ``v`` goes away from the viewer along ``forward``, else -1."""
    return 1.0 if float(v @ forward) > 0 else -1.0


def _shin_front(thigh: np.ndarray, shin: np.ndarray, front: np.ndarray | None
                ) -> np.ndarray | None:
    """The shin's front, where the ankle's rest angle is measured from, unit, ``(3,)``.

    The knee's front (``-(shin ⟂ thigh)``, where a flexed shin goes) when the knee is bent
    by 15 degrees or more, else ``front``, carried onto the shin by the knee's flexion (the
    smallest rotation taking the thigh to the shin) and made orthogonal to the shin; None
    when undefined (no ``front`` for a straight knee, the shin turned right round, or the
    carried front along the shin).

    Args:
        thigh: Thigh vector, world units, ``(3,)``.
        shin: Shin vector, ``(3,)``.
        front: The front of a straight leg, ``(3,)`` (any length; its part along the
            thigh is ignored), or None.

    Returns:
        The unit shin front orthogonal to ``shin``, ``(3,)``, or None.
    """
    knee = _unit_perp(-shin, thigh / np.linalg.norm(thigh))
    ahead = knee if knee is not None and _angle(thigh, shin) >= 15.0 else front
    carry = _swing(thigh, shin)
    if ahead is None or carry is None:
        return None
    return _unit_perp(carry @ ahead, shin / np.linalg.norm(shin))


def _extension_cost(limb: np.ndarray, down: np.ndarray, front: np.ndarray,
                    limit: float) -> float:
    """How far a limb's first bone swings behind its rest direction beyond ``limit``, degrees.

    The hip's and the shoulder's extension: the swing of ``limb`` behind ``down`` (away
    from ``front``) in the plane of ``down`` and ``front``, less ``limit``, weighted by the
    share of ``limb`` in that plane (a bone held sideways, out of that plane, extends
    little).

    Args:
        limb: The thigh's or upper arm's vector, world units, ``(3,)``.
        down: Its rest direction carried by the pelvis or chest, ``(3,)`` (any length).
        front: The character's front carried likewise, ``(3,)`` (its part along ``down``
            is ignored).
        limit: Largest extension that costs nothing, degrees.

    Returns:
        The cost, degrees (0 within range, or when ``front`` lies along ``down``).
    """
    d = down / np.linalg.norm(down)
    ahead = _unit_perp(front, d)
    if ahead is None:
        return 0.0
    a, b = float(limb @ ahead), float(limb @ d)
    extension = float(np.degrees(np.arctan2(-a, b)))
    share = float(np.hypot(a, b) / np.linalg.norm(limb))
    return max(0.0, extension - limit) * share


def _twist(expected: np.ndarray, flexion: np.ndarray, axis: np.ndarray) -> float:
    """The signed turn from ``expected`` to ``flexion`` about ``axis``, degrees.

    How far a hinge's plane of flexion is turned about its parent bone (the thigh's or
    the upper arm's rotation about its own axis), in ``[-180, 180]``.

    Args:
        expected: The direction of flexion with no rotation, unit, orthogonal to
            ``axis``, ``(3,)``.
        flexion: The direction the child bone flexes towards, unit, orthogonal to
            ``axis``, ``(3,)``.
        axis: The parent bone's unit direction, ``(3,)``.

    Returns:
        The angle, degrees, positive counterclockwise about ``axis``.
    """
    return float(np.degrees(np.arctan2(np.cross(expected, flexion) @ axis, expected @ flexion)))


def _beyond_twist(twist: float, limit: float, bend: float) -> float:
    """How far a child bone lies from the nearest direction a twist range allows, degrees.

    A child bone bent by ``bend`` from its parent's axis, its plane of flexion turned
    about that axis by ``twist``, lies on the cone of half-angle ``bend`` about the axis;
    the nearest direction within the range is on that cone too, turned by the excess
    ``|twist| - limit`` less, at the chord angle ``2 asin(sin(bend) sin(excess / 2))``.

    Args:
        twist: The turn of the plane of flexion (:func:`_twist`), degrees.
        limit: Largest ``|twist|`` that costs nothing, degrees.
        bend: Angle between the parent bone and the child, radians.

    Returns:
        The angle, degrees (0 within the range or for a straight joint).
    """
    excess = np.radians(max(abs(twist) - limit, 0.0))
    return float(np.degrees(2.0 * np.arcsin(min(1.0, np.sin(bend) * np.sin(excess / 2)))))


@dataclass(frozen=True)
class LegRest:
    """A leg's rest geometry in its pelvis's frame, carried to the solved pelvis.

    Attributes:
        thigh: The thigh's rest direction carried by the solved pelvis, ``(3,)``.
        front: The character's front carried by the solved pelvis, unit, ``(3,)``.
        foot: The foot's rest direction in the shin's rest frame (along the shin, along
            its front, across), unit, ``(3,)``; None without a foot.
    """

    thigh: np.ndarray
    front: np.ndarray
    foot: np.ndarray | None


def leg_cost(thigh: np.ndarray, shin: np.ndarray, foot: np.ndarray | None, rest: LegRest,
             limits: LegLimits = LegLimits()) -> float:
    """How far a leg's bone directions lie outside its joints' ranges, degrees.

    The hip: the thigh's swing behind its carried rest direction beyond
    ``hip_extension`` (in the plane of that direction and the carried front, weighted by
    the thigh's share in that plane). The knee: the knee's front (``-(shin ⟂ thigh)``,
    where a flexed shin goes) against the carried front swung onto the thigh (zero hip
    rotation); beyond ``hip_twist`` the shin is ``2 asin(sin(bend) sin(excess / 2))`` from
    the nearest direction the hip's rotation allows, plus ``twist_share`` of the twist
    times ``sin(bend)``. The ankle: the foot against its rest direction in the shin's frame
    (the shin's front the knee's flexion carries) beyond ``ankle``.

    Args:
        thigh: Thigh vector, world units, ``(3,)``.
        shin: Shin vector, ``(3,)``.
        foot: Foot vector, ``(3,)`` (None: not scored).
        rest: The leg's carried rest geometry.
        limits: The ranges.

    Returns:
        The cost, degrees (0 within every range and straight).
    """
    cost = _extension_cost(thigh, rest.thigh, rest.front, limits.hip_extension)
    swing = _swing(rest.thigh, thigh)
    if swing is None:
        return cost  # the thigh turned right round: its swing's axis is a guess
    t = thigh / np.linalg.norm(thigh)
    expected = _unit_perp(swing @ rest.front, t)
    knee = _unit_perp(-shin, t)
    bend = np.radians(_angle(thigh, shin))
    if expected is not None and knee is not None:
        twist = _twist(expected, knee, t)
        cost += _beyond_twist(twist, limits.hip_twist, bend)
        cost += limits.twist_share * abs(twist) * float(np.sin(bend))
    if foot is not None and rest.foot is not None:
        f = _shin_front(thigh, shin, expected)
        if f is not None:
            s = shin / np.linalg.norm(shin)
            want = rest.foot[0] * s + rest.foot[1] * f + rest.foot[2] * np.cross(s, f)
            cost += max(0.0, _angle(foot, want) - limits.ankle)
    return cost


def leg_chains(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray,
               up: np.ndarray) -> list[tuple[int, ...]]:
    """The legs' solving bones, thigh first: ``(thigh, shin)`` or ``(thigh, shin, foot)``.

    The thighs are :func:`.start.thigh_bones`; each next bone is the only solving child
    connected to the previous one.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        up: The rig's rest up, world axes, ``(3,)``.

    Returns:
        One tuple of solving-bone indices per leg.
    """
    parent = np.asarray(solving.parent)

    def child(k: int) -> int | None:
        kids = [c for c in np.flatnonzero(parent == k) if skeleton.connected[int(bones[c])]]
        return int(kids[0]) if len(kids) == 1 else None

    chains = []
    for thigh in np.flatnonzero(start.thigh_bones(solving, up)):
        shin = child(int(thigh))
        if shin is None:
            continue
        foot = child(shin)
        chains.append((int(thigh), shin) if foot is None else (int(thigh), shin, foot))
    return chains


def _leg_rest(skeleton: Skeleton, chain: tuple[int, ...], bones: np.ndarray,
              carry: np.ndarray, front: np.ndarray) -> LegRest:
    """The leg's rest geometry carried by the pelvis's world rotation ``carry``."""
    rest = skeleton.rest_tails - skeleton.rest_heads
    thigh, shin = rest[int(bones[chain[0]])], rest[int(bones[chain[1]])]
    foot = None
    if len(chain) > 2:
        s = shin / np.linalg.norm(shin)
        # The shin's front as leg_cost reads it on a posed leg (at rest, the rest pose's
        # foot costs nothing).
        ahead = _shin_front(thigh, shin, front)
        if ahead is not None:
            f = rest[int(bones[chain[2]])]
            f = f / np.linalg.norm(f)
            foot = np.array([f @ s, f @ ahead, f @ np.cross(s, ahead)])
    return LegRest(carry @ thigh, carry @ front, foot)


def _posed_legs(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray,
                pose: Pose, front: np.ndarray, up: np.ndarray):
    """Each leg of :func:`leg_chains` as posed, for :func:`leg_sides` and :func:`leg_costs`.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        pose: The pose.
        front: The character's front in the rest pose, unit, world axes, ``(3,)``.
        up: The rig's rest up, world axes, ``(3,)``.

    Yields:
        ``(chain, rest, vectors)``: the leg's solving bones, its :class:`LegRest` carried
        by its posed pelvis (None for a leg hanging from a root bone) and its bones' posed
        head-to-tail vectors, each ``(3,)``.
    """
    state = skeleton.forward(pose)
    front = np.asarray(front, float)
    for chain in leg_chains(skeleton, solving, bones, up):
        full = [int(bones[k]) for k in chain]
        vectors = [state.tails[b] - state.heads[b] for b in full]
        pelvis = int(skeleton.parents[full[0]])
        if pelvis < 0:
            yield chain, None, vectors
            continue
        carry = state.frames[pelvis] @ skeleton.rest_frames[pelvis].T
        yield chain, _leg_rest(skeleton, chain, bones, carry, front), vectors


def _mirrorable(chain: tuple[int, ...], vectors: list[np.ndarray], movable: np.ndarray,
                forward: np.ndarray, min_slope: float) -> list[bool]:
    """Which of a limb's bones :func:`leg_sides` and :func:`arm_sides` may mirror.

    A bone may be mirrored about the view plane when it is ``movable`` and leaves that
    plane by at least ``min_slope`` of its length.

    Args:
        chain: The limb's solving bones, ``(k,)``.
        vectors: Their posed head-to-tail vectors, world units, each ``(3,)``.
        movable: Solving bones whose side may change, ``(m,)`` bool.
        forward: The unit view direction, ``(3,)``.
        min_slope: Smallest depth change over length of a bone that may be mirrored.

    Returns:
        One flag per bone of ``chain``.
    """
    return [bool(movable[k]) and abs(float(v @ forward)) >= min_slope * np.linalg.norm(v)
            for k, v in zip(chain, vectors, strict=True)]


def leg_sides(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray,
              forward: np.ndarray, pose: Pose, front: np.ndarray, up: np.ndarray,
              movable: np.ndarray, limits: LegLimits = LegLimits(),
              min_slope: float = 0.1) -> np.ndarray:
    """Depth sides for the legs whose solved sides break their joints' ranges (ours).

    Each leg's ``movable`` bones leaving the view plane by at least ``min_slope`` of their
    length in ``pose`` may be mirrored about the view plane through their heads, which
    keeps the drawing (orthographically); bones drawn as at bind too (a foot drawn
    end-on looks the same pointing at the viewer, as at bind, or away). Of those
    combinations the one of least :func:`leg_cost` is taken, keeping the thigh's side when
    a combination that keeps it costs at most ``thigh_tolerance``, ties to the fewest
    mirrored bones, when it costs at least ``margin`` less than the solved one.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        forward: The view direction (depth grows along it), ``(3,)``.
        pose: The solved pose.
        front: The character's front in the rest pose, unit, world axes, ``(3,)``
            (:func:`.start.front_direction`).
        up: The rig's rest up, world axes, ``(3,)``.
        movable: Solving bones whose side may change (not pinned), ``(m,)`` bool.
        limits: The ranges and thresholds.
        min_slope: Smallest depth change over length of a bone that may be mirrored.

    Returns:
        The new depth side of each solving bone (+1 away from the viewer, -1 towards), 0
        where unchanged, ``(m,)``.
    """
    forward = np.asarray(forward, float) / np.linalg.norm(forward)
    sides = np.zeros(len(bones))
    for chain, rest, vectors in _posed_legs(skeleton, solving, bones, pose, front, up):
        if rest is None:
            continue
        free = _mirrorable(chain, vectors, movable, forward, min_slope)
        options = []
        for mask in range(1 << len(chain)):
            bits = [(mask >> i) & 1 == 1 for i in range(len(chain))]
            if any(b and not f for b, f in zip(bits, free, strict=True)):
                continue
            v = [_mirrored(x, forward) if b else x for x, b in zip(vectors, bits, strict=True)]
            cost = leg_cost(v[0], v[1], v[2] if len(v) > 2 else None, rest, limits)
            options.append((cost, sum(bits), bits, v))
        solved = options[0][0]  # mask 0: as solved
        keep_thigh = [o for o in options if not o[2][0]]
        pool = keep_thigh if min(o[0] for o in keep_thigh) <= limits.thigh_tolerance \
            else options
        cost, _, bits, v = min(pool, key=lambda o: (round(o[0], 6), o[1]))
        if cost <= solved - limits.margin:
            for k, b, x in zip(chain, bits, v, strict=True):
                if b:
                    sides[k] = _depth_side(x, forward)
    return sides


@dataclass(frozen=True)
class ArmLimits:
    """The elbow's plane against the shoulder's rotation, degrees, and the threshold.

    Attributes:
        humeral_twist: Largest turn of the elbow's plane of flexion about the upper arm
            away from the one the chest's front gives it (the humerus's rotation: about
            90 degrees either way from the arm hanging with the elbow flexing forward),
            degrees.
        shoulder_extension: Largest swing of the upper arm behind the chest's down, in
            the chest's plane of flexion (the shoulder's extension, about 60 degrees),
            degrees.
        margin: Smallest cost difference, degrees, for a combination to replace the
            solved one.
    """

    humeral_twist: float = 100.0
    shoulder_extension: float = 60.0
    margin: float = 15.0


def arm_cost(upper: np.ndarray, forearm: np.ndarray, down: np.ndarray, front: np.ndarray,
             limits: ArmLimits = ArmLimits()) -> float:
    """How far an arm lies outside the shoulder's extension and rotation, degrees.

    The shoulder: the upper arm's swing behind ``down`` beyond ``shoulder_extension``, in
    the plane of ``down`` and the chest's front, weighted by the arm's share in that plane
    (as the hip's extension in :func:`leg_cost`). Without it an upper arm drawn end-on
    with the forearm hanging below was mirrored to point straight back (90 degrees of
    extension), where the elbow's plane is within range.

    The elbow flexes the forearm towards the front of the upper arm. Hanging down, the
    arm's front is the chest's; raised, the front the smallest swing from ``down`` to the
    upper arm carries (no rotation of the humerus). The forearm's direction away from the
    upper arm's axis, turned about it from that front by more than ``humeral_twist``, is
    ``2 asin(sin(bend) sin(excess / 2))`` from what the rotation allows.

    Args:
        upper: Upper-arm vector, world units, ``(3,)``.
        forearm: Forearm vector, ``(3,)``.
        down: The chest's down (the rig's rest down carried by the chest), ``(3,)``.
        front: The chest's front (the character's front carried by the chest), ``(3,)``.
        limits: The range.

    Returns:
        The cost, degrees.
    """
    cost = _extension_cost(upper, down, front, limits.shoulder_extension)
    swing = _swing(down, upper)
    if swing is None:
        return cost  # the arm straight up: the swing's axis is a guess
    t = upper / np.linalg.norm(upper)
    expected = _unit_perp(swing @ front, t)
    elbow = _unit_perp(forearm, t)
    if expected is None or elbow is None:
        return cost
    twist = _twist(expected, elbow, t)
    bend = np.radians(_angle(upper, forearm))
    return cost + _beyond_twist(twist, limits.humeral_twist, bend)


def arm_chains(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray,
               up: np.ndarray) -> list[tuple[int, int, int]]:
    """The arms' ``(upper arm, forearm, chest)``: solving bones, the chest a full-skeleton one.

    An arm ends in a sided end bone (a hand) whose parent (the forearm) and grandparent
    (the upper arm) are sided, connected solving bones, outside the legs
    (:func:`.start.leg_bones`); its chest is the upper arm's first unsided ancestor. Only
    on an upright rig: its body's axis (:func:`.start.body_axis`) spans more along ``up``
    than across (a quadruped's front legs are not arms).

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        up: The rig's rest up, world axes, unit, ``(3,)``.

    Returns:
        One tuple per arm.
    """
    parent = np.asarray(solving.parent)
    axis = np.asarray(solving.rest_joints, float)[start.body_axis(solving, up)]
    span = axis.max(axis=0) - axis.min(axis=0)
    along = abs(float(span @ up))
    if along <= float(np.linalg.norm(span - along * np.sign(span @ up) * up)):
        return []
    legs = start.leg_bones(solving, up)
    chains = []
    for end in range(len(bones)):
        if np.any(parent == end) or legs[end] or parent[end] < 0 or parent[parent[end]] < 0:
            continue
        fore = int(parent[end])
        upper = int(parent[fore])
        full = [int(bones[k]) for k in (upper, fore, end)]
        if any(side_of(skeleton.names[b]) is None for b in full) or not (
                skeleton.connected[full[1]] and skeleton.connected[full[2]]):
            continue
        chest = int(skeleton.parents[full[0]])
        while chest >= 0 and side_of(skeleton.names[chest]) is not None:
            chest = int(skeleton.parents[chest])
        if chest >= 0:
            chains.append((upper, fore, chest))
    return chains


def _posed_arms(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray,
                pose: Pose, front: np.ndarray, up: np.ndarray):
    """Each arm of :func:`arm_chains` as posed, for :func:`arm_sides` and :func:`arm_costs`.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        pose: The pose.
        front: The character's front in the rest pose, unit, world axes, ``(3,)``.
        up: The rig's rest up, world axes, unit, ``(3,)``.

    Yields:
        ``((upper, fore), down, ahead, vectors)``: the arm's solving bones, the rest down
        and front carried by its posed chest, each ``(3,)``, and the upper arm's and
        forearm's posed head-to-tail vectors.
    """
    state = skeleton.forward(pose)
    up, front = np.asarray(up, float), np.asarray(front, float)
    for upper, fore, chest in arm_chains(skeleton, solving, bones, up):
        carry = state.frames[chest] @ skeleton.rest_frames[chest].T
        vectors = [state.tails[int(bones[k])] - state.heads[int(bones[k])]
                   for k in (upper, fore)]
        yield (upper, fore), carry @ -up, carry @ front, vectors


def arm_sides(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray,
              forward: np.ndarray, pose: Pose, front: np.ndarray, up: np.ndarray,
              movable: np.ndarray, limits: ArmLimits = ArmLimits(),
              min_slope: float = 0.1) -> np.ndarray:
    """Depth sides for the upper arms whose solved elbows break the shoulder's rotation.

    As :func:`leg_sides` for each arm (:func:`arm_chains`), its combinations scored by
    :func:`arm_cost` on the solved chest; only those that mirror the upper arm (the
    forearm with it or not): the start's forearm sides are mostly right (61 of the 68
    clearly turned ones on the CMU poses), its upper arms' a guess (the character's
    front; 28 of 54).

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        forward: The view direction (depth grows along it), ``(3,)``.
        pose: The solved pose.
        front: The character's front in the rest pose, unit, world axes, ``(3,)``.
        up: The rig's rest up, world axes, unit, ``(3,)``.
        movable: Solving bones whose side may change (not pinned), ``(m,)`` bool.
        limits: The range and threshold.
        min_slope: Smallest depth change over length of a bone that may be mirrored.

    Returns:
        The new depth side of each solving bone (+1 away from the viewer), 0 where
        unchanged, ``(m,)``.
    """
    forward = np.asarray(forward, float) / np.linalg.norm(forward)
    sides = np.zeros(len(bones))
    for (upper, fore), down, ahead, vectors in _posed_arms(skeleton, solving, bones, pose,
                                                          front, up):
        free = _mirrorable((upper, fore), vectors, movable, forward, min_slope)
        if not free[0]:
            continue
        solved = arm_cost(vectors[0], vectors[1], down, ahead, limits)
        options = []
        for fore_too in (False, True) if free[1] else (False,):
            v = [_mirrored(x, forward) if b else x
                 for x, b in zip(vectors, (True, fore_too), strict=True)]
            options.append((arm_cost(v[0], v[1], down, ahead, limits), fore_too, v))
        cost, fore_too, v = min(options, key=lambda o: (round(o[0], 6), o[1]))
        if cost <= solved - limits.margin:
            for k, x in zip((upper, fore) if fore_too else (upper,), v, strict=False):
                sides[k] = _depth_side(x, forward)
    return sides


def leg_costs(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray, pose: Pose,
              front: np.ndarray, up: np.ndarray, limits: LegLimits = LegLimits()
              ) -> np.ndarray:
    """:func:`leg_cost` of each leg as posed (:func:`leg_chains`), degrees, ``(legs,)``.

    The same reading as :func:`leg_sides` without mirroring: each leg's rest carried by
    its solved pelvis.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        pose: The pose to score.
        front: The character's front in the rest pose, unit, world axes, ``(3,)``.
        up: The rig's rest up, world axes, ``(3,)``.
        limits: The ranges.

    Returns:
        One cost per leg (a leg hanging from a root bone scores 0).
    """
    return np.array([0.0 if rest is None else
                     leg_cost(v[0], v[1], v[2] if len(v) > 2 else None, rest, limits)
                     for _, rest, v in _posed_legs(skeleton, solving, bones, pose, front, up)],
                    dtype=float)


def arm_costs(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray, pose: Pose,
              front: np.ndarray, up: np.ndarray, limits: ArmLimits = ArmLimits()
              ) -> np.ndarray:
    """:func:`arm_cost` of each arm as posed (:func:`arm_chains`), degrees, ``(arms,)``.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        pose: The pose to score.
        front: The character's front in the rest pose, unit, world axes, ``(3,)``.
        up: The rig's rest up, world axes, unit, ``(3,)``.
        limits: The range.

    Returns:
        One cost per arm.
    """
    return np.array([arm_cost(v[0], v[1], down, ahead, limits)
                     for _, down, ahead, v in _posed_arms(skeleton, solving, bones, pose,
                                                          front, up)], dtype=float)
