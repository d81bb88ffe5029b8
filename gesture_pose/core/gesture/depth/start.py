"""The start of the 3D solve: the bind pose lifted to the drawing (Gesture3D Section 7).

A drawn link fixes how much a bone leaves the view plane, ``sqrt(l^2 - l_2d^2)``, not to
which side. The start aims every solving bone at its drawn direction, lifted by that
amount, on the bind pose's side when the bone clearly has one (depth slope above 0.3)
and is drawn within 45 degrees of its bind direction and near its bind image, else
towards the character's front (its ``.L`` side is its own left), or towards the viewer
when the front is not clear (a side view); the thighs take that front as their pelvis
carries it (:func:`pelvis_front_sides`), and a bone drawn as its parents carry it from
the bind pose takes its bind side (:func:`carried_sides`); the rig's limits and the rest
bend of the knees (of elbows too on request) decide the bones at those joints
(:func:`hinge_signs`); then sides that break depth-order constraints are flipped
greedily. When the drawing shows the character turned around (its left and right hips or
shoulders swapped in the image, :func:`drawn_facing`), the bind pose's sides and its
front are reversed and the bones are aimed from the bind pose turned half round
(:func:`turned_bind`). Through a perspective camera each tail is put on its pixel's view
ray (:func:`side_directions`).

Starting lifted matters: from a flat pose the linearized projection cannot shorten a bone
(the depth direction is a saddle), so the SQP alone would never leave the view plane.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ...exceptions import InputError
from ...names import side_of
from ...rotations import exp_map, log_map
from ...skeleton import Pose, PoseState, Skeleton
from ..solving import symmetric_joint_pairs
from ..types import Embedding2D, SolvingSkeleton
from . import twist
from .energies import ViewFrame
from .ordering import OrderingConstraint, ancestors, violations
from .regularity import spine_chain


def _first_pairs(solving: SolvingSkeleton) -> np.ndarray:
    """The left/right joint pairs nearest the root (hips, shoulders), shape ``(p, 2)``."""
    pairs = symmetric_joint_pairs(solving)
    if not len(pairs):
        return pairs
    jp = np.asarray(solving.joint_parent)
    depth = np.zeros(len(jp), int)
    for j in range(len(jp)):
        k = j
        while jp[k] >= 0:
            k, depth[j] = jp[k], depth[j] + 1
    level = depth[pairs].max(axis=1)
    return pairs[level == level.min()]


#: The default rest up, world axes: Blender's +Z, the rig's own up when it stands in the
#: world at rest. The rest joints are world positions: an armature object turned to lay
#: its rig down turns that up with it (:func:`rig_up`, ``DepthOptions(rest_up=)``).
REST_UP = np.array([0.0, 0.0, 1.0])


def rig_up(solving: SolvingSkeleton, object_up: np.ndarray) -> np.ndarray:
    """The rig's rest up, world axes: Blender's +Z or its armature object's z axis (ours).

    The rest joints are world positions. A rig modelled standing whose object is turned
    to lie at rest carries its up with the object's z axis; an imported rig (FBX, glTF)
    whose armature data is Y-up stands with its object turned 90 degrees about x, its
    object's z axis level (the Adventurer's points along world +Y). Of the two, the one
    the limbs below the left/right pairs nearest the root (:func:`_first_pairs`: legs)
    hang down along, from those joints to their limbs' ends, by at least 0.7 of their
    hang and more than along the other; +Z when they lie within 6 degrees of each other
    or the limbs decide neither (a bust's arms held out sideways).

    Args:
        solving: The solving skeleton.
        object_up: The armature object's z axis, world axes, ``(3,)`` (any length).

    Returns:
        The unit up, world axes, ``(3,)``.
    """
    obj = np.asarray(object_up, float)
    obj = obj / max(float(np.linalg.norm(obj)), 1e-12)
    if float(obj @ REST_UP) > 0.994:  # within 6 degrees
        return REST_UP.copy()
    pairs = _first_pairs(solving)
    if not len(pairs):
        return REST_UP.copy()
    jp = np.asarray(solving.joint_parent)
    rest = np.asarray(solving.rest_joints, float)
    has_child = np.zeros(len(jp), bool)
    has_child[jp[jp >= 0]] = True
    hang = np.zeros(3)
    for j in pairs.ravel():
        ends = [k for k in np.flatnonzero(~has_child) if int(j) in ancestors(jp, int(k))]
        if ends:
            hang += rest[int(j)] - rest[ends].mean(axis=0)
    size = float(np.linalg.norm(hang))
    if size > 1e-12 and float(hang @ obj) >= max(0.7 * size, float(hang @ REST_UP)):
        return obj
    return REST_UP.copy()


def body_axis(solving: SolvingSkeleton, up: np.ndarray = REST_UP) -> np.ndarray:
    """The joints of the body's axis, root end first, shape ``(k,)`` (ours).

    The root's unsided chain up to the head (:func:`.regularity.spine_chain`), without a
    floor root: a root link from the floor the feet stand on up to the pelvis (an FBX or
    Unreal rig's ``root`` bone) would put the axis' middle at half the height, below the
    hips. The root joint is on that floor when the paired limbs reach down to its height
    (their lowest joint within a tenth of the rig's height along ``up`` of it); the axis
    then starts at the first of its joints a limb's top pair (:func:`leg_pairs`) hangs
    from. A bust's root, the torso's bottom, is not on such a floor: its arms, hanging
    from the chest, do not reach down to it.

    Args:
        solving: The solving skeleton.
        up: The rig's rest up, world axes, ``(3,)``.

    Returns:
        Joint indices along the axis, ``(k,)`` int.
    """
    chain = spine_chain(solving, through_branches=True)
    pairs = _top_pairs(solving)
    if not len(pairs) or len(chain) < 2:
        return chain
    height = np.asarray(solving.rest_joints, float) @ np.asarray(up, float)
    tenth = 0.1 * float(height.max() - height.min())
    reach = float(height[symmetric_joint_pairs(solving)].min())  # the limbs' lowest
    if abs(reach - float(height[chain[0]])) > tenth:
        return chain  # the limbs do not reach the root: it is the body's own
    jp = np.asarray(solving.joint_parent)
    position = {int(j): i for i, j in enumerate(chain)}
    hung = [position[j] for j in (_hanging_joint(jp, int(a), position) for a in pairs[:, 0])
            if j is not None]
    return chain[min(hung):] if hung else chain


def _top_pairs(solving: SolvingSkeleton) -> np.ndarray:
    """The limbs' top left/right pairs (hips, shoulders, not knees), shape ``(p, 2)``.

    A top pair's joints have parent joints in no pair.
    """
    pairs = symmetric_joint_pairs(solving)
    if not len(pairs):
        return pairs
    jp = np.asarray(solving.joint_parent)
    paired = set(int(j) for j in pairs.ravel())
    top = np.array([int(jp[a]) not in paired and int(jp[b]) not in paired for a, b in pairs],
                   dtype=bool)
    return pairs[top]


def _hanging_joint(joint_parent: np.ndarray, joint: int, chain: dict[int, int]) -> int | None:
    """The nearest ancestor of ``joint`` among the keys of ``chain`` (None: no such)."""
    k = int(joint_parent[joint])
    while k >= 0 and k not in chain:
        k = int(joint_parent[k])
    return k if k >= 0 else None


def leg_pairs(solving: SolvingSkeleton, up: np.ndarray = REST_UP) -> np.ndarray:
    """The left/right joint pairs the legs hang from (hips), shape ``(p, 2)`` (ours).

    The limbs' top pairs (a pair whose joints' parent joint is in no pair: hips,
    shoulders, not knees or elbows) that lie at or below the middle of the body's axis
    (the root's unsided chain up to the head, a floor root left out: :func:`body_axis`)
    along the rig's rest ``up``, and of those the ones nearest the root. Tree depth alone
    would take the arms of a bust (a rig whose only pairs hang from the chest) for legs.

    Args:
        solving: The solving skeleton.
        up: The rig's rest up, world axes, ``(3,)``.

    Returns:
        Joint pairs, ``(p, 2)`` int; none on a rig whose paired limbs all hang from the
        upper half of its axis (a bust) or whose sided bones form no pairs.
    """
    pairs = _top_pairs(solving)
    if not len(pairs):
        return pairs
    jp = np.asarray(solving.joint_parent)
    height = np.asarray(solving.rest_joints, float) @ np.asarray(up, float)
    axis = height[body_axis(solving, up)]
    pairs = pairs[height[pairs].max(axis=1) <= 0.5 * (axis.min() + axis.max()) + 1e-9]
    if not len(pairs):
        return pairs
    depth = np.array([len(ancestors(jp, int(j))) for j in pairs[:, 0]])
    return pairs[depth == depth.min()]


def front_direction(solving: SolvingSkeleton, rest_joints: np.ndarray, frame: ViewFrame,
                    up: np.ndarray | None = None) -> np.ndarray | None:
    """The way the bind pose faces, ``(left - right) x up``, as a unit vector.

    A rig's ``.L`` side is the character's own left: with the first joint of each of the
    left/right pairs nearest the root (:func:`_first_pairs`) on the left, the character
    faces ``(left - right) x up``. With the view's up (the default) that is the front
    only for a level camera; the character's own is the rig's rest up (its armature
    object's z axis, :data:`REST_UP` unrotated): a humanoid's chest, a quadruped's head.

    Args:
        solving: The solving skeleton.
        rest_joints: Bind-pose joints, world units, shape ``(J, 3)``.
        frame: The view.
        up: The up axis, world axes, ``(3,)`` (None: the view's up). When the pairs lie
            within 6 degrees of it, the view's up is used instead.

    Returns:
        The unit facing direction, world axes, ``(3,)``; None when the rig has no
        left/right pairs or they lie along both axes.
    """
    pairs = _first_pairs(solving)
    if not len(pairs):
        return None
    sides = [side_of(solving.joint_bones[i].rpartition(" ")[0]) for i, _ in pairs]
    left = np.array([1.0 if side == "L" else -1.0 for side in sides])
    across = np.sum(left[:, None] * (rest_joints[pairs[:, 0]] - rest_joints[pairs[:, 1]]),
                    axis=0)
    if up is not None:
        up = np.asarray(up, float)
        front = np.cross(across, up)
        norm = float(np.linalg.norm(front))
        if norm > 0.1 * float(np.linalg.norm(across) * np.linalg.norm(up)):  # 6 degrees
            return front / norm
    front = np.cross(across, frame.up)
    norm = float(np.linalg.norm(front))
    return front / norm if norm > 1e-12 else None


def bind_front(solving: SolvingSkeleton, rest_joints: np.ndarray, frame: ViewFrame,
               min_slope: float = 0.3) -> float:
    """Which way the bind pose faces along the view: -1 towards the viewer, +1 away, 0 unclear.

    The facing direction is :func:`front_direction`'s; the answer is 0 when it is within
    ``asin(min_slope)`` of the view plane (a side view) or the rig has no left/right
    pairs.

    Args:
        solving: The solving skeleton.
        rest_joints: Bind-pose joints, world units, shape ``(J, 3)``.
        frame: The view.
        min_slope: Smallest depth component of the unit facing direction.

    Returns:
        The sign of the facing direction's depth, or 0.
    """
    front = front_direction(solving, rest_joints, frame)
    if front is None:
        return 0.0
    slope = float(front @ frame.forward)
    return float(np.sign(slope)) if abs(slope) >= min_slope else 0.0


def drawn_facing(solving: SolvingSkeleton, joints2d: np.ndarray, rest_joints: np.ndarray,
                 frame: ViewFrame, min_agreement: float = 0.5, min_width: float = 0.3,
                 body_up: str = "up") -> float:
    """Whether the drawing shows the character turned around from its bind pose (-1) or not.

    A character turned half-way round about its up axis shows its left side where the
    bind pose shows its right: the order of its left/right joint pairs across the body in
    the image is reversed. Across the body is the image's x axis, rolled as the body is
    drawn (``body_up``, :func:`view_roll`; ours). Only the pairs nearest the root (hips,
    shoulders) are read, as hands and feet cross freely, and only when the bind pose
    shows them apart (their difference across at least ``min_width`` of their distance;
    not in a side view). Each pair votes with its drawn difference across times the bind
    pose's; a reversal needs the votes to agree on at least ``min_agreement`` of their
    total weight.

    Args:
        solving: The solving skeleton.
        joints2d: Drawn joints, pixels, shape ``(J, 2)``.
        rest_joints: Bind-pose joints, world units, shape ``(J, 3)``: rolled as drawn
            (:func:`rolled_bind`) when ``body_up`` is not ``"up"``.
        frame: The view.
        min_agreement: Smallest ``|sum| / sum(|votes|)`` to read a reversal.
        min_width: Smallest bind difference across of a voting pair over its distance.
        body_up: Which way the body's up points in the drawing (:data:`BODY_UPS`).

    Returns:
        -1.0 when the drawing shows the character turned around, else 1.0.
    """
    pairs = _first_pairs(solving)
    if not len(pairs):
        return 1.0
    across = view_roll(frame.forward, body_up) @ np.asarray(frame.right, float)
    turn = np.radians(BODY_UPS[body_up])
    across_px = np.array([np.cos(turn), np.sin(turn)])  # ``across`` in the image
    rest = rest_joints[pairs[:, 0]] - rest_joints[pairs[:, 1]]
    bind = rest @ across
    wide = np.abs(bind) >= min_width * np.maximum(np.linalg.norm(rest, axis=1), 1e-12)
    drawn = (joints2d[pairs[:, 0]] - joints2d[pairs[:, 1]]) @ across_px / frame.scale
    votes = (drawn * bind)[wide]
    total = float(np.sum(np.abs(votes)))
    if total <= 0.0 or float(np.sum(votes)) >= -min_agreement * total:
        return 1.0
    return -1.0


def near_bind_direction(drawn: np.ndarray, rest: np.ndarray, frame: ViewFrame,
                        max_angle: float = np.radians(45.0)) -> np.ndarray:
    """Whether each link is drawn within ``max_angle`` of its bind direction in the image.

    Args:
        drawn: Drawn link vectors, pixels, shape ``(k, 2)``.
        rest: Bind-pose link vectors, world units, shape ``(k, 3)``.
        frame: The view.
        max_angle: Largest angle, radians.

    Returns:
        Shape ``(k,)`` bool.
    """
    rest2 = np.stack([rest @ frame.right, rest @ frame.up], axis=1)
    cos = np.sum(drawn * rest2, axis=1) / np.maximum(
        np.linalg.norm(drawn, axis=1) * np.linalg.norm(rest2, axis=1), 1e-12)
    return cos >= np.cos(max_angle)


def _drawn_link(skeleton: Skeleton, embedding: Embedding2D, frame: ViewFrame, k: int,
                bone: int) -> tuple[np.ndarray, float]:
    """Solving bone ``k``'s drawn 2D vector and the depth change its length leaves.

    Returns:
        ``(drawn (2,), depth)``: the drawn vector in view units (right, up) and
        ``sqrt(l^2 - |drawn|^2)`` (0 for a bone drawn at or beyond its length).
    """
    s = embedding.solving
    drawn = (embedding.joints2d[s.tail_joint[k]] - embedding.joints2d[s.head_joint[k]]) \
        / frame.scale
    return drawn, float(np.sqrt(max(skeleton.lengths[bone] ** 2 - drawn @ drawn, 0.0)))


def _direction(frame: ViewFrame, drawn: np.ndarray, depth: float) -> np.ndarray:
    """The 3D vector drawn as ``drawn`` (view units) with ``depth`` along the view."""
    return drawn[0] * frame.right + drawn[1] * frame.up + depth * frame.forward


def side_directions(skeleton: Skeleton, embedding: Embedding2D, frame: ViewFrame, k: int,
                    bone: int, head: np.ndarray) -> tuple[np.ndarray, float]:
    """The two 3D vectors solving bone ``k`` may have as drawn: away from and towards the viewer.

    Orthographic (``frame.camera`` None): the drawn vector lifted by
    ``+-sqrt(l^2 - |drawn|^2)`` along the view. With a perspective camera (ours) the tail
    is put on its pixel's view ray at the bone's length from the head (a ray-sphere
    intersection, the farther and the nearer point), the ray shifted by the head's own
    offset from its pixel's ray (the start's joints are not exactly where they are
    drawn). A ray that passes farther than the bone's length gives its closest point on
    both sides.

    Args:
        skeleton: The full skeleton.
        embedding: The 2D embedding.
        frame: The view.
        k: Solving bone index.
        bone: Its full-skeleton index.
        head: The bone's head in the pose being aimed, world units, ``(3,)``.

    Returns:
        ``(sides, lift)``: the away and towards vectors, ``(2, 3)``, and half their
        difference along the view (the depth change the drawing leaves), world units.
    """
    camera = frame.camera
    if camera is None:
        drawn, depth = _drawn_link(skeleton, embedding, frame, k, bone)
        return np.stack([_direction(frame, drawn, depth), _direction(frame, drawn, -depth)]), depth
    s = embedding.solving
    pixels = embedding.joints2d[[s.head_joint[k], s.tail_joint[k]]]
    head = np.asarray(head, float)
    shift = head - camera.unproject_at_depth(pixels[:1], camera.depth(head[None]))[0]
    origins, dirs = camera.rays(pixels[1:])
    q, u = origins[0] + shift - head, dirs[0]
    uq = float(u @ q)
    root = float(np.sqrt(max(uq * uq - q @ q + skeleton.lengths[bone] ** 2, 0.0)))
    sides = q[None] + np.array([[-uq + root], [-uq - root]]) * u[None]
    return sides, root * float(u @ frame.forward)


def lifted_pose(skeleton: Skeleton, jmap: twist.JointMap, frame: ViewFrame,
                embedding: Embedding2D, bind: Pose, signs: np.ndarray, fixed: np.ndarray
                ) -> Pose:
    """The bind pose with each solving bone aimed at its drawn direction, lifted.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        frame: The view.
        embedding: The 2D embedding.
        bind: The bind pose.
        signs: Depth side of each solving bone (+1 away from the viewer), ``(m,)``.
        fixed: Solving bones left at their bind rotation, ``(m,)`` bool.

    Returns:
        The lifted pose.
    """
    return _aim_in_order(skeleton, jmap, frame, embedding, bind, signs, fixed)[0]


#: ``decide(k, bone, sides, depth, state, pose)``: the side of solving bone ``k`` (full
#: skeleton index ``bone``, whose two drawn 3D vectors, away from and towards the viewer,
#: are ``sides`` with ``depth`` out of the view plane, :func:`side_directions`) in
#: ``pose`` (its parents aimed, forward ``state``), or None to keep it.
Decide = Callable[[int, int, np.ndarray, float, PoseState, Pose], "float | None"]


def _aim_in_order(skeleton: Skeleton, jmap: twist.JointMap, frame: ViewFrame,
                  embedding: Embedding2D, bind: Pose, signs: np.ndarray, fixed: np.ndarray,
                  decide: Decide | None = None) -> tuple[Pose, np.ndarray]:
    """Aim the solving bones at their drawn directions, parents first, from the bind pose.

    Each bone not ``fixed`` is aimed on its depth side; ``decide`` may first choose that
    side, seeing the pose its parents were aimed to.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        frame: The view.
        embedding: The 2D embedding.
        bind: The bind pose.
        signs: Depth side of each solving bone so far (+1 away from the viewer), ``(m,)``.
        fixed: Solving bones left at their bind rotation, ``(m,)`` bool.
        decide: Chooses sides on the way (None: ``signs`` as given).

    Returns:
        ``(pose, signs)``: the lifted pose and the sides, ``(m,)``.
    """
    signs = np.asarray(signs, float).copy()
    pose = bind
    for k, bone in enumerate(jmap.bones):
        if fixed[k]:
            continue
        bone = int(bone)
        state = skeleton.forward(pose)
        sides, depth = side_directions(skeleton, embedding, frame, k, bone,
                                       state.heads[bone])
        if decide is not None:
            side = decide(k, bone, sides, depth, state, pose)
            if side is not None:
                signs[k] = side
        direction = sides[0] if signs[k] > 0 else sides[1] if signs[k] < 0 \
            else sides.mean(axis=0)
        if np.linalg.norm(direction) < 1e-9 * skeleton.lengths[bone]:
            continue
        rot = skeleton.aim_local(bone, direction, state, pose.rotations[bone])
        pose = pose.with_rotations(np.array([bone]), rot[None])
    return pose, signs


def applied_body_up(solving: SolvingSkeleton, body_up: str, pinned: np.ndarray | None
                    ) -> str:
    """The Body Up the 3D step applies (ours).

    ``body_up``, or ``"up"`` when a pinned solving root (a solving bone without solving
    ancestors, ``SolvingSkeleton.parent``) keeps the whole body at its bind rotation.

    Args:
        solving: The solving skeleton.
        body_up: The drawing's Body Up (:data:`BODY_UPS`).
        pinned: Bones that keep their bind rotation, ``(n,)`` bool (full skeleton), or
            None.

    Returns:
        The Body Up the bind pose is rolled by.
    """
    if body_up == "up" or pinned is None:
        return body_up
    held = np.asarray(pinned, bool)[solving.bones] & (np.asarray(solving.parent) < 0)
    return "up" if held.any() else body_up


def _turned_rigidly(skeleton: Skeleton, bones: np.ndarray, parent: np.ndarray, bind: Pose,
                    rotation: np.ndarray, fixed: np.ndarray | None) -> Pose:
    """The pose with each solving root's subtree turned rigidly about the root's head (ours).

    The roots (solving bones without solving ancestors) not ``fixed`` turn, and with each
    the solving bones below it: every one not ``fixed`` takes the world frame ``rotation``
    times its frame in ``bind``, parents first (:meth:`Skeleton.local_rotation_for_frame`
    on the pose as turned so far). A bone that inherits its parent's rotation keeps its
    local rotation; one that does not is turned itself. ``fixed`` bones keep their local
    rotations, and a fixed root keeps the solving bones below it as they are.

    Args:
        skeleton: The full skeleton.
        bones: Full-skeleton index of each solving bone, parents first, ``(m,)``.
        parent: Nearest solving ancestor of each, among ``bones``, -1 for a root, ``(m,)``
            (``SolvingSkeleton.parent``, ``twist.JointMap.solving_parent``).
        bind: The pose to turn.
        rotation: The turn, world axes, ``(3, 3)``.
        fixed: Solving bones left at their local rotation, ``(m,)`` bool (optional).

    Returns:
        The turned pose.
    """
    bones = np.asarray(bones, int)
    keep = np.zeros(len(bones), bool) if fixed is None else np.asarray(fixed, bool)
    turning = np.zeros(len(bones), bool)
    for k, p in enumerate(parent):
        turning[k] = not keep[k] if p < 0 else turning[p]
    target = rotation @ skeleton.forward(bind).frames[bones]
    pose = bind
    for k in np.flatnonzero(turning & ~keep):
        rot = skeleton.local_rotation_for_frame(int(bones[k]), target[k],
                                                skeleton.forward(pose))
        pose = pose.with_rotations(bones[k:k + 1], rot[None])
    return pose


def turned_bind(skeleton: Skeleton, jmap: twist.JointMap, frame: ViewFrame, bind: Pose,
                fixed: np.ndarray, body_up: str = "up") -> Pose:
    """The bind pose turned half round about the body's up axis in the view (ours).

    For a character drawn turned around (:func:`drawn_facing`), the solving skeleton is
    turned rigidly (:func:`_turned_rigidly`, ``fixed`` bones keeping their local
    rotations) by 180 degrees about the view's up axis (rolled to ``body_up`` for a body
    drawn lying or upside down, :func:`view_roll`) through its roots' heads before the
    bones are aimed: aiming keeps a bone's twist (:meth:`Skeleton.aim_local`), so from
    the unturned bind pose the SQP had to turn the whole body round itself, through the
    depth of every limb.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        frame: The view.
        bind: The bind pose.
        fixed: Solving bones left at their bind rotation, ``(m,)`` bool.
        body_up: Which way the body's up points in the drawing (:data:`BODY_UPS`).

    Returns:
        The turned pose.
    """
    up = view_roll(frame.forward, body_up) @ np.asarray(frame.up, float)
    return _turned_rigidly(skeleton, jmap.bones, jmap.solving_parent, bind, half_turn(up),
                           fixed)


def half_turn(axis: np.ndarray) -> np.ndarray:
    """The rotation by 180 degrees about ``axis`` (any length), ``2 a a^T - I``, ``(3, 3)``."""
    a = np.asarray(axis, float)
    return 2.0 * np.outer(a, a) / float(a @ a) - np.eye(3)


#: Which way the character's up points in the drawing, and the quarter turns (degrees,
#: anticlockwise as the viewer sees the image) that roll its up from the image's up there.
BODY_UPS = {"up": 0.0, "left": 90.0, "down": 180.0, "right": -90.0}


def view_roll(forward: np.ndarray, body_up: str) -> np.ndarray:
    """The rotation that rolls the image's up to ``body_up`` about the line of sight (ours).

    Args:
        forward: The viewing direction, world axes, ``(3,)`` (any length).
        body_up: One of :data:`BODY_UPS`.

    Returns:
        The rotation matrix, world axes, ``(3, 3)``: about ``-forward`` (towards the
        viewer), so anticlockwise as the viewer sees it.

    Raises:
        InputError: An unknown ``body_up``.
    """
    if body_up not in BODY_UPS:
        raise InputError(f"Body Up must be one of {', '.join(BODY_UPS)}, not {body_up!r}.")
    axis = -np.asarray(forward, float) / np.linalg.norm(forward)
    return exp_map(np.radians(BODY_UPS[body_up]) * axis)


def rolled_bind(skeleton: Skeleton, solving: SolvingSkeleton, forward: np.ndarray,
                bind: Pose, body_up: str, fixed: np.ndarray | None = None) -> Pose:
    """The bind pose rolled about the line of sight as the drawing shows the body (ours).

    For a character drawn lying or upside down (``Embedding2D.body_up``), the solving
    skeleton is rolled rigidly about the viewing direction through its roots' heads
    (:func:`view_roll`, :func:`_turned_rigidly`; ``fixed`` bones keep their local
    rotations), so that the start, the bind-pose priors and the side rules read a bind
    pose drawn the way the drawing shows it; from the upright bind pose the SQP had to
    turn the whole body over through its linearization. Several roots each turn about
    their own heads, which stay where they are.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton (its bones and their solving parents).
        forward: The viewing direction, world axes, ``(3,)``.
        bind: The bind pose.
        body_up: One of :data:`BODY_UPS`.
        fixed: Solving bones left at their bind rotation, ``(m,)`` bool (optional).

    Returns:
        The rolled pose (``bind`` itself for ``"up"``).
    """
    roll = view_roll(forward, body_up)
    if body_up == "up":
        return bind
    return _turned_rigidly(skeleton, solving.bones, solving.parent, bind, roll, fixed)


def _within(rotvec: np.ndarray, limits: np.ndarray, tol: float = 1e-3) -> bool:
    """Whether a local rotation vector lies inside IK limits ``(3, 2)`` (NaN: no limit)."""
    lo, hi = limits[:, 0], limits[:, 1]
    lim = np.isfinite(lo) & np.isfinite(hi)
    return bool(np.all((rotvec[lim] >= lo[lim] - tol) & (rotvec[lim] <= hi[lim] + tol)))


def carried_sides(skeleton: Skeleton, jmap: twist.JointMap, frame: ViewFrame,
                  embedding: Embedding2D, bind: Pose, signs: np.ndarray, fixed: np.ndarray,
                  open_: np.ndarray, max_angle: float = np.radians(10.0),
                  min_lift: float = 0.1) -> np.ndarray:
    """Depth sides of bones drawn as their parents carry them (ours).

    A bone whose parents turned while its own joint did not (a forearm following its
    raised upper arm) is drawn along its bind direction carried by the parents' start
    rotations. When exactly one of its two depth sides lies within ``max_angle`` of that
    direction, that side is the bone's: its bind side relative to its parent, which the
    default guess (the character's front) would otherwise replace. Bones are aimed in
    order, parents first, as in :func:`lifted_pose`. Only bones in ``open_`` that leave
    the view plane by at least ``min_lift`` of their length are decided.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        frame: The view.
        embedding: The 2D embedding.
        bind: The bind pose.
        signs: Depth side of each solving bone so far (+1 away from the viewer), ``(m,)``.
        fixed: Solving bones left at their bind rotation, ``(m,)`` bool.
        open_: Solving bones whose side is still a guess, ``(m,)`` bool.
        max_angle: Largest angle between a side and the carried bind direction, radians.
        min_lift: Smallest depth change over length of a decided bone.

    Returns:
        The sides, ``(m,)``.
    """
    def decide(k: int, bone: int, sides: np.ndarray, depth: float, state: PoseState,
               pose: Pose) -> float | None:
        length = skeleton.lengths[bone]
        if not (open_[k] and depth >= min_lift * length):
            return None
        carried = state.tails[bone] - state.heads[bone]
        cos = [float(c @ carried) / max(float(np.linalg.norm(c) * np.linalg.norm(carried)),
                                         1e-12) for c in sides]
        near = [c >= np.cos(max_angle) for c in cos]
        if near[0] == near[1]:
            return None
        return 1.0 if near[0] else -1.0

    return _aim_in_order(skeleton, jmap, frame, embedding, bind, signs, fixed, decide)[1]


def thigh_bones(solving: SolvingSkeleton, up: np.ndarray = REST_UP) -> np.ndarray:
    """Solving bones whose head is a joint the legs hang from (:func:`leg_pairs`): thighs.

    Args:
        solving: The solving skeleton.
        up: The rig's rest up, world axes, ``(3,)``.

    Returns:
        ``(m,)`` bool over the solving bones.
    """
    return np.isin(np.asarray(solving.head_joint), leg_pairs(solving, up).ravel())


def leg_bones(solving: SolvingSkeleton, up: np.ndarray = REST_UP) -> np.ndarray:
    """Solving bones of the legs: the thighs (:func:`thigh_bones`) and every bone below.

    A humanoid's or a quadruped's hind legs (thighs, shins, feet); none on a bust
    (:func:`leg_pairs`).

    Args:
        solving: The solving skeleton.
        up: The rig's rest up, world axes, ``(3,)``.

    Returns:
        ``(m,)`` bool over the solving bones.
    """
    parent = np.asarray(solving.parent)
    out = thigh_bones(solving, up)
    for k in range(len(out)):  # parents come before their children
        if parent[k] >= 0 and out[parent[k]]:
            out[k] = True
    return out


def pelvis_front_sides(skeleton: Skeleton, jmap: twist.JointMap, frame: ViewFrame,
                       embedding: Embedding2D, bind: Pose, signs: np.ndarray,
                       fixed: np.ndarray, open_: np.ndarray, front: np.ndarray,
                       min_slope: float = 0.3, min_lift: float = 0.1,
                       max_turn: float = np.radians(150.0)) -> np.ndarray:
    """Depth sides of thighs from the front their pelvis carries (ours).

    The default side of a lifted bone is the character's front (:func:`start_pose`), the
    bind pose's facing. A body bent far forward or back turns its pelvis with it, and a
    thigh drawn foreshortened is then in front of the pelvis (hip flexion, up to 120
    degrees) far more often than behind it (hip extension, 10-30 degrees): a body bent
    forward with a leg stretched back points that leg away from the viewer whom its
    front faces. Each bone in ``open_`` (the thighs, :func:`thigh_bones`: their parent
    is the pelvis) takes the side towards ``front`` as its parent's start rotation
    carries it (the parent aimed first, as in :func:`lifted_pose`), when that carried
    front leaves the view plane by at least ``min_slope`` (else it keeps its side). Not
    for the bones below: a knee bends backwards, so the front a thigh carries says
    nothing of its shin's side (a thigh raised past 90 degrees carries it down and
    away, with a shin pointing at the viewer), nor of a foot's under its shin. Only bones
    that leave the view plane by at least ``min_lift`` of their length are decided.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        frame: The view.
        embedding: The 2D embedding.
        bind: The bind pose the bones are aimed from (turned half round for a character
            drawn turned around, :func:`turned_bind`).
        signs: Depth side of each solving bone so far (+1 away from the viewer), ``(m,)``.
        fixed: Solving bones left at their bind rotation, ``(m,)`` bool.
        open_: Solving bones whose side this decides, ``(m,)`` bool.
        front: The character's front in ``bind``'s rest frames, world axes, ``(3,)``
            (:func:`front_direction` with the rig's rest up; reversed for a character
            drawn turned around when ``bind`` is not turned).
        min_slope: Smallest depth component of the carried unit front.
        min_lift: Smallest depth change over length of a decided bone.
        max_turn: Largest angle between the parent's direction in ``bind`` and in the
            start for its carried front to count, radians: a bone aimed nearly backwards
            turns about an axis its aim does not fix (a figure drawn upside down).

    Returns:
        The sides, ``(m,)``.
    """
    solving = set(int(b) for b in jmap.bones)
    front = np.asarray(front, float)
    bind_state = skeleton.forward(bind)

    def decide(k: int, bone: int, sides: np.ndarray, depth: float, state: PoseState,
               pose: Pose) -> float | None:
        parent = int(skeleton.parents[bone])
        if not open_[k] or parent not in solving or depth < min_lift * skeleton.lengths[bone]:
            return None
        before = bind_state.tails[parent] - bind_state.heads[parent]
        now = state.tails[parent] - state.heads[parent]
        cos = float(before @ now) / max(float(np.linalg.norm(before) * np.linalg.norm(now)),
                                        1e-12)
        if cos < np.cos(max_turn):
            return None  # aimed nearly backwards: the aim's axis, hence the front, is a guess
        carried = state.frames[parent] @ skeleton.rest_frames[parent].T @ front
        slope = float(carried @ frame.forward)
        if abs(slope) < min_slope:
            return None
        return 1.0 if slope > 0 else -1.0

    return _aim_in_order(skeleton, jmap, frame, embedding, bind, signs, fixed, decide)[1]


def hinge_signs(skeleton: Skeleton, jmap: twist.JointMap, frame: ViewFrame,
                embedding: Embedding2D, bind: Pose, signs: np.ndarray, fixed: np.ndarray,
                ik_limits: np.ndarray | None = None, natural_bend: bool = True,
                min_bend: float = np.radians(3.0), min_lift: float = 0.1,
                limit_axes: np.ndarray | None = None, min_off: float = 0.15,
                arms: bool = False, up: np.ndarray = REST_UP,
                held: np.ndarray | None = None) -> np.ndarray:
    """Depth sides of bones at a joint the rig restricts or bends (knees, elbows).

    A drawn bone's two depth sides bend its joint with its parent in opposite senses. With
    IK limits on the bone, the side whose local rotation (aimed from the bind pose as in
    :func:`lifted_pose`) stays within them is taken when the other does not. Otherwise,
    with ``natural_bend``, the middle bone of a limb (a ``.L``/``.R`` name, connected to
    its parent, with a solving child: a shin, a forearm) bent against its parent at rest
    (by at least ``min_bend``: a knee slightly forward, an elbow slightly back) bends the
    same way as at rest: the side whose bend axis ``u_parent x u_bone`` agrees with the rest bend
    axis carried along by the parent's rotation. When both sides do (the parent points
    along the view: a thigh at the viewer), the side nearer the hinge's plane of flexion
    (smaller ``|u_bone . axis|``, by at least ``min_off``) is taken: the other turns the
    bone sideways out of that plane. The two sides are compared as mirror images about
    the view plane through the bone's head (ours): through a perspective camera the two
    intersections of :func:`side_directions` are moved towards the viewer together by a
    tilted view ray, and both bends looked natural (CMU poses on the Adventurer 7.32 ->
    7.30 % of the height, the 25 traced drawings with cached 2D fits 7.86 -> 7.78, the
    sample characters' exact embeddings unchanged at 4.11). When neither test decides a
    knee (the middle bone of a limb hanging from the hips, :func:`leg_pairs`), the side
    that bends it more is taken instead of the default (ours; CMU 7.30 -> 7.30, sample
    characters 4.11 -> 4.06, traced 7.78 -> 7.73). Not for elbows: there it
    turned the oblique throw's forearm, pointing at the viewer, away. Only bones that
    leave the view plane by at least ``min_lift`` of their length are decided; the others
    keep ``signs``. The rest bend decides only the legs' middle bones (:func:`leg_bones`;
    none on a bust, whose pairs all hang from the upper half of its axis; every limb's
    on a rig whose sided bones form no pairs) unless ``arms`` (ours): the start aims the upper arm
    keeping its bind twist, and the shoulder turns the arm about its own axis far more
    than the hip turns the thigh, so the elbow's carried hinge axis says little. On the
    40 CMU poses the elbows' rest bend picked the right side for 6 of the 32 clearly
    turned forearms it decided, the knees' for 21 of 25.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        frame: The view.
        embedding: The 2D embedding.
        bind: The bind pose.
        signs: Depth side of each solving bone so far (+1 away from the viewer), ``(m,)``.
        fixed: Solving bones left at their bind rotation, ``(m,)`` bool.
        ik_limits: IK limits ``[min, max]`` per local axis, radians, ``(n, 3, 2)``, NaN
            when unlimited (optional).
        natural_bend: Use the rest bend where IK limits do not decide.
        min_bend: Smallest rest bend angle of a natural hinge, radians.
        min_lift: Smallest depth change over length of a decided bone.
        limit_axes: The local axes ``ik_limits`` refer to, as columns, ``(n, 3, 3)`` (None:
            the bones' own axes; see :func:`~.rig.rig_rows`).
        min_off: Smallest difference of the two sides' ``|cos|`` to the hinge axis that
            decides between two natural bends.
        arms: Use the rest bend of the other limbs' middle bones (elbows) too.
        up: The rig's rest up, world axes, ``(3,)``, which tells the legs
            (:func:`leg_pairs`).
        held: Solving bones whose sides are not decided here, ``(m,)`` bool (ours: the
            sides :func:`start_pose` is given, ``forced``); None: none.

    Returns:
        The sides, ``(m,)``.
    """
    s = embedding.solving
    solving = set(int(b) for b in jmap.bones)
    rest_dir = skeleton.rest_tails - skeleton.rest_heads
    rest_dir = rest_dir / np.maximum(np.linalg.norm(rest_dir, axis=1, keepdims=True), 1e-12)
    # Natural hinges: the middle bones of limbs (a side in the name, connected to the
    # parent, a solving child below): knees, elbows, not the spine, tails or hands.
    has_child = np.zeros(jmap.n_bones, bool)
    has_child[np.asarray(s.parent)[np.asarray(s.parent) >= 0]] = True
    hinge = np.array([bool(skeleton.connected[b]) and has_child[k]
                      and side_of(skeleton.names[b]) is not None
                      for k, b in enumerate(jmap.bones)])

    if not arms and len(symmetric_joint_pairs(s)):
        hinge &= leg_bones(s, up)
    index = {int(b): i for i, b in enumerate(jmap.bones)}
    hips = set(int(j) for j in leg_pairs(s, up).ravel())

    def decide(k: int, bone: int, sides: np.ndarray, depth: float, state: PoseState,
               pose: Pose) -> float | None:
        parent = int(skeleton.parents[bone])
        if depth < min_lift * skeleton.lengths[bone] or parent not in solving or (
                held is not None and held[k]):
            return None
        cands = list(sides)
        if ik_limits is not None and np.any(np.isfinite(ik_limits[bone])):
            rotvecs = log_map(np.stack([skeleton.aim_local(bone, c, state, pose.rotations[bone])
                                        for c in cands]))
            if limit_axes is not None:
                rotvecs = rotvecs @ limit_axes[bone]
            ok = [_within(r, ik_limits[bone]) for r in rotvecs]
            if ok[0] != ok[1]:
                return 1.0 if ok[0] else -1.0
        axis = np.cross(rest_dir[parent], rest_dir[bone])
        if not (natural_bend and hinge[k] and np.linalg.norm(axis) >= np.sin(min_bend)):
            return None
        # The two sides as mirror images about the view plane through the head (the same
        # length and image direction, opposite depths): through a perspective camera both
        # ray intersections lie nearer the viewer when the ray is tilted, which would make
        # both bends look alike, and they differ sideways too.
        mid = 0.5 * (sides[0] + sides[1])
        mid = mid - float(mid @ frame.forward) * frame.forward
        lift = float(0.5 * (sides[0] - sides[1]) @ frame.forward) * frame.forward
        cands = [mid + lift, mid - lift]
        world = state.frames[parent] @ skeleton.rest_frames[parent].T
        u = state.tails[parent] - state.heads[parent]
        hinge_axis = world @ axis
        score = [float(np.cross(u, c) @ hinge_axis) for c in cands]
        if score[0] * score[1] < 0:
            return 1.0 if score[0] > 0 else -1.0
        if min(score) > 0.0:
            # Both sides bend the natural way (the parent points along the view): the one
            # nearer the hinge's plane of flexion.
            off = [abs(float(c @ hinge_axis)) / max(float(np.linalg.norm(c)
                   * np.linalg.norm(hinge_axis)), 1e-12) for c in cands]
            if abs(off[0] - off[1]) >= min_off:
                return 1.0 if off[0] < off[1] else -1.0
            if int(s.head_joint[index[parent]]) in hips:
                # A knee: the more bent side, the larger angle from the thigh (its cosine,
                # not the score's sine, which falls again past 90 degrees).
                cos = [float(u @ c) / max(float(np.linalg.norm(c)), 1e-12) for c in cands]
                return 1.0 if cos[0] < cos[1] else -1.0
        return None

    return _aim_in_order(skeleton, jmap, frame, embedding, bind, signs, fixed, decide)[1]


def start_pose(skeleton: Skeleton, jmap: twist.JointMap, frame: ViewFrame,
               order: list[OrderingConstraint], embedding: Embedding2D, bind: Pose,
               toward_viewer: bool = True, pinned: np.ndarray | None = None,
               facing: float = 1.0, bind_turn: float = np.radians(45.0),
               keep: np.ndarray | None = None, ik_limits: np.ndarray | None = None,
               natural_bend: bool = False, limit_axes: np.ndarray | None = None,
               agreement: np.ndarray | None = None, min_agreement: float = 0.1,
               carried_turn: float = 0.0, turn: bool = False,
               pelvis_front: float = 0.0, arm_bend: bool = False,
               rest_up: np.ndarray | None = None, forced: np.ndarray | None = None
               ) -> tuple[Pose, np.ndarray]:
    """The lifted start pose and the depth side of each solving bone.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        frame: The view.
        order: Depth-order constraints the sides should satisfy.
        embedding: The 2D embedding.
        bind: The bind pose.
        toward_viewer: Default side of a bone the bind pose does not decide.
        pinned: Bones kept at their bind rotation, ``(n,)`` bool (full skeleton).
        facing: -1 when the drawing shows the character turned around
            (:func:`drawn_facing`): the bind pose's sides and the default are reversed.
        bind_turn: Largest angle between a bone's drawn direction and its bind direction
            in the image for the bind pose's side to be kept, radians.
        keep: Solving bones drawn as the bind pose shows them, left at their bind rotation
            (not lifted) in the start, ``(m,)`` bool (optional).
        ik_limits: IK limits per bone, ``(n, 3, 2)`` radians, NaN when unlimited: they
            decide the side of a bone when only one side stays within them
            (:func:`hinge_signs`).
        natural_bend: Bones bent against their parents at rest bend the same way
            (:func:`hinge_signs`) where IK limits do not decide.
        limit_axes: The local axes ``ik_limits`` refer to (:func:`hinge_signs`).
        agreement: How well each solving bone is drawn as the bind pose shows it,
            :func:`.energies.bind_agreement` of its link, ``(m,)`` (optional).
        min_agreement: Smallest ``agreement`` for the bind pose's side to be kept: a bone
            drawn far from its bind image has moved, and its bind side says little.
        carried_turn: Bones drawn within this angle of their bind direction carried by
            their parents keep that side (:func:`carried_sides`), radians; 0 leaves them
            to the default.
        turn: For a character drawn turned around, aim the bones from the bind pose
            turned half round (:func:`turned_bind`).
        pelvis_front: The thighs (:func:`thigh_bones`) whose side is still a guess take
            the character's front (with ``rest_up``) as their pelvis carries it
            when it leaves the view plane by at least this much
            (:func:`pelvis_front_sides`); 0 leaves them to the default.
        arm_bend: With ``natural_bend``, the elbows bend as at rest too, not only the
            knees (:func:`hinge_signs` ``arms``).
        rest_up: The rig's rest up, world axes, ``(3,)``: its armature object's z axis
            (the rest joints are world positions); None for :data:`REST_UP`. It gives the
            character's front for ``pelvis_front`` and tells the legs (:func:`leg_pairs`).
        forced: Depth sides that replace the rules' where non-zero, ``(m,)`` (ours: the
            mirror images of the legs' and arms' sides with which a first solve broke the
            joints' ranges, :func:`.plausibility.leg_sides` and
            :func:`.plausibility.arm_sides`); such bones are lifted even when drawn as at
            bind (``keep``), pinned ones excepted; the rules and the greedy flips leave
            them, and the rules read their children against them.

    Returns:
        ``(pose, signs)``: the start pose and the sides, ``(m,)``.
    """
    jm, f = jmap, frame
    up = REST_UP if rest_up is None else np.asarray(rest_up, float)
    up = up / max(float(np.linalg.norm(up)), 1e-12)
    fixed = (np.zeros(jm.n_bones, bool) if pinned is None
             else np.asarray(pinned, bool)[jm.bones])
    if keep is not None:
        fixed = fixed | np.asarray(keep, bool)
    state = skeleton.forward(bind)
    bind_slope = ((state.tails[jm.bones] - state.heads[jm.bones]) @ f.forward) \
        / skeleton.lengths[jm.bones]
    front = bind_front(embedding.solving, embedding.solving.rest_joints, f)
    default = facing * front if front != 0.0 else (-1.0 if toward_viewer else 1.0)
    # The bind pose's side is kept only for bones drawn near their bind direction: a bone
    # turned far in the image (a tail curled over the back) has left that side behind.
    sk = embedding.solving
    drawn = embedding.joints2d[sk.tail_joint] - embedding.joints2d[sk.head_joint]
    near = near_bind_direction(drawn, state.tails[jm.bones] - state.heads[jm.bones], f,
                               bind_turn)
    kept = (np.abs(bind_slope) > 0.3) & near
    if agreement is not None:
        kept &= np.asarray(agreement, float) >= min_agreement
    signs = np.where(kept, facing * np.sign(bind_slope), default)
    chosen = np.zeros(jm.n_bones, bool)
    if forced is not None:
        # Before the rules, which leave these sides alone, so that a child's hinge or
        # carried side is read against its parent's forced side.
        chosen = np.asarray(forced, float) != 0.0
        if pinned is not None:
            chosen &= ~np.asarray(pinned, bool)[jm.bones]
        signs[chosen] = np.asarray(forced, float)[chosen]
        fixed = fixed & ~chosen
    turned = facing < 0 and turn
    if turned:
        bind = turned_bind(skeleton, jm, f, bind, fixed, embedding.body_up)
    facing_dir = front_direction(sk, sk.rest_joints, f, up) if pelvis_front > 0.0 else None
    if facing_dir is not None:
        # The turned bind pose carries the front round with it; the unturned one does not.
        signs = pelvis_front_sides(skeleton, jm, f, embedding, bind, signs, fixed,
                                   ~kept & thigh_bones(sk, up) & ~chosen,
                                   facing_dir if turned else facing * facing_dir,
                                   pelvis_front)
    if carried_turn > 0.0:
        signs = carried_sides(skeleton, jm, f, embedding, bind, signs, fixed,
                              ~kept & ~chosen, carried_turn)
    if natural_bend or (ik_limits is not None and np.any(np.isfinite(ik_limits))):
        signs = hinge_signs(skeleton, jm, f, embedding, bind, signs, fixed, ik_limits,
                            natural_bend, limit_axes=limit_axes, arms=arm_bend, up=up,
                            held=chosen)
    pose = lifted_pose(skeleton, jm, f, embedding, bind, signs, fixed)
    if not order:
        return pose, signs

    # Greedy flips on a linear model of the depths: flipping bone k moves every joint below
    # its tail by -2 s_k m_k along the view (rigid offsets turning with it are ignored
    # here; the SQP enforces the constraints exactly).
    X, _ = twist.joint_positions(skeleton, jm, pose)
    depth = f.depth(X)
    s = embedding.solving
    drawn = np.linalg.norm(embedding.joints2d[s.tail_joint] - embedding.joints2d[s.head_joint],
                           axis=1) / f.scale
    lengths = skeleton.lengths[jm.bones]
    lift = np.sqrt(np.maximum(lengths**2 - drawn**2, 0.0))
    lifted = np.flatnonzero((drawn < 0.98 * lengths) & ~fixed & ~chosen)
    shift = jm.moves[:, lifted].astype(float) * lift[lifted]

    def badness(d: np.ndarray) -> float:
        return float(np.sum(violations(order, d)))

    current, flipped = badness(depth), False
    for _ in range(len(lifted)):
        if current <= 1e-12:
            break
        trials = depth[:, None] - 2.0 * signs[lifted] * shift
        scores = np.array([badness(trials[:, i]) for i in range(len(lifted))])
        if not len(scores) or scores.min() >= current - 1e-12:
            break
        i = int(np.argmin(scores))
        signs[lifted[i]] = -signs[lifted[i]]
        depth, current, flipped = trials[:, i], scores[i], True
    if flipped:
        pose = lifted_pose(skeleton, jm, f, embedding, bind, signs, fixed)
    return pose, signs
