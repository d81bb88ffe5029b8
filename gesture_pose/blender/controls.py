"""Posing constrained bones through the controls their constraints follow (ours).

A rig whose foot copies the rotation of an IK control, or whose shin ends an IK chain
aimed at that control, ignores keys on the foot and the leg: Blender evaluates the
constraints after the keyed pose. :func:`.constraints.plan_redirects` finds such bones
and their controls; :func:`pose_controls` moves the controls so that Blender's own
evaluation gives the solved pose back (the control's world rotation for a copied
rotation, the IK target at the solved chain's end, the pole turned with the chain), and
then checks it does, bone by bone.

All matrices here are in the armature's pose space (Blender's ``pose_bone.matrix``: the
armature object's own axes and units); the solved pose is turned into it through the
object's world matrix.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ..core.exceptions import InputError
from ..core.rotations import rotation_between
from ..core.skeleton import Pose
from .constraints import Redirects
from .read_armature import ArmatureData

#: Largest distance of a bone's head from its solved place, fraction of the rig's size.
HEAD_TOLERANCE = 0.005
#: Largest angle between a bone's evaluated and solved rotation, degrees.
ANGLE_TOLERANCE = 1.0
#: A bone below a moved control or chain turned by more than this (degrees) from its
#: solved rotation is given it again (float32 pose matrices carry about 0.01 degree).
FOLLOW_TOLERANCE = 0.05


class _Solved:
    """The solved pose's bones in pose space: rotations (Blender's bone frames) and heads."""

    def __init__(self, arm_obj: bpy.types.Object, data: ArmatureData, pose: Pose) -> None:
        state = data.skeleton.forward(pose)
        world = np.asarray(data.matrix_world, float)
        rot_o = world[:3, :3] / data.object_scale
        frames = state.frames
        if data.frame_change is not None:  # joint-skeleton frames back to the bones'
            frames = frames @ np.swapaxes(data.frame_change, 1, 2)
        self.rotations = np.einsum("ji,njk->nik", rot_o, frames)
        inverse = np.linalg.inv(world)
        self.heads = state.heads @ inverse[:3, :3].T + inverse[:3, 3]
        self.index = {n: i for i, n in enumerate(data.skeleton.names)}
        self.lengths = {b.name: b.length for b in arm_obj.data.bones}

    def rotation(self, name: str) -> np.ndarray:
        return self.rotations[self.index[name]]

    def head(self, name: str) -> np.ndarray:
        return self.heads[self.index[name]]

    def tail(self, name: str) -> np.ndarray:
        return self.head(name) + self.rotation(name)[:, 1] * self.lengths[name]


def rig_size(arm_obj: bpy.types.Object) -> float:
    """The largest extent of the armature's rest bones, heads and tails (its units)."""
    rest = np.array([[*b.head_local, *b.tail_local] for b in arm_obj.data.bones])
    return float(np.ptp(rest.reshape(-1, 3), axis=0).max())


def _evaluated(arm_obj: bpy.types.Object, name: str) -> np.ndarray:
    """The bone's evaluated pose matrix, ``(4, 4)`` (constraints included)."""
    return np.array(arm_obj.pose.bones[name].matrix, dtype=float)


def _frame(points: np.ndarray) -> np.ndarray | None:
    """An orthonormal frame of a chain: its root-to-end axis and the bend's direction.

    Args:
        points: The chain's joints, root first, end last, ``(k, 3)``.

    Returns:
        Columns (axis, bend, axis x bend), ``(3, 3)``; None when the chain is straight.
    """
    axis = points[-1] - points[0]
    size = float(np.linalg.norm(axis))
    if size < 1e-9:
        return None
    axis = axis / size
    off = points - points[0]
    off = off - np.outer(off @ axis, axis)
    k = int(np.argmax(np.linalg.norm(off, axis=1)))
    if np.linalg.norm(off[k]) < 1e-3 * size:
        return None
    bend = off[k] / np.linalg.norm(off[k])
    return np.column_stack([axis, bend, np.cross(axis, bend)])


def _turn(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """The rotation taking the chain ``old`` to ``new`` (both ``(k, 3)``, root first).

    Its root-to-end axis and bend onto the new ones; for a straight chain, the smallest
    turn of the axis.
    """
    f_old, f_new = _frame(old), _frame(new)
    if f_old is not None and f_new is not None:
        return f_new @ f_old.T
    return rotation_between(old[-1] - old[0], new[-1] - new[0])


def _targets(arm_obj: bpy.types.Object, solved: _Solved, plan: Redirects
             ) -> dict[str, tuple[np.ndarray | None, np.ndarray | None]]:
    """``{control: (pose-space rotation or None, head or None)}`` to give each control."""
    out: dict[str, tuple[np.ndarray | None, np.ndarray | None]] = {}
    for owner, (source, whole) in plan.copies.items():
        out[source] = (solved.rotation(owner), solved.head(owner) if whole else None)
    for ch in plan.chains:
        end = solved.tail(ch.bone) if ch.use_tail else solved.head(ch.bone)
        rotation = out.get(ch.target, (None, None))[0]
        if rotation is None:
            rotation = _evaluated(arm_obj, ch.target)[:3, :3]
            rotation = rotation / np.linalg.norm(rotation, axis=0)
        out[ch.target] = (rotation, end)  # Blender's IK aims at the target's head
        if ch.pole:
            bones = list(reversed(ch.chain))
            old_end = _evaluated(arm_obj, ch.bone)
            old_end = (old_end[:3, 3] + old_end[:3, 1] * arm_obj.data.bones[ch.bone].length
                       if ch.use_tail else old_end[:3, 3])
            old = np.array([_evaluated(arm_obj, n)[:3, 3] for n in bones] + [old_end])
            new = np.array([solved.head(n) for n in bones] + [end])
            turn = _turn(old, new)
            pole = _evaluated(arm_obj, ch.pole)[:3, 3]
            out[ch.pole] = (None, new[0] + turn @ (pole - old[0]))  # its head (IK aims at it)
    return out


def _set_pose_matrix(arm_obj: bpy.types.Object, name: str, matrix: np.ndarray,
                     rotation: bool, location: bool, scale: bool = False) -> list[str]:
    """Give a bone a pose-space matrix through its own channels, continuously.

    The local transform is Blender's (``convert_space`` from the pose to the bone's
    local space, its parent as evaluated); the rotation goes through
    :func:`.write_pose.set_rotation` (the current quaternion's side, compatible Euler
    angles), not through ``pose_bone.matrix``, which keeps neither. With ``scale``
    the matrix's scale is written too (a Rigify FK control snapped to a squashed IK
    limb).

    Returns:
        The channels whose values changed.
    """
    from .write_pose import rotation_channel, set_rotation

    pb = arm_obj.pose.bones[name]
    local = np.array(arm_obj.convert_space(pose_bone=pb, matrix=Matrix(matrix.tolist()),
                                           from_space="POSE", to_space="LOCAL"))
    channels = []
    if rotation:
        channel = rotation_channel(pb.rotation_mode)
        before = np.array(getattr(pb, channel))
        set_rotation(pb, local[:3, :3] / np.linalg.norm(local[:3, :3], axis=0))
        if np.abs(np.array(getattr(pb, channel)) - before).max() > 1e-6:
            channels.append(channel)
    if location:
        before = np.array(pb.location)
        pb.location = local[:3, 3]
        if np.abs(np.array(pb.location) - before).max() > 1e-6:
            channels.append("location")
    size = np.linalg.norm(local[:3, :3], axis=0)
    if scale and np.abs(size - np.array(pb.scale)).max() > 1e-6:
        pb.scale = size
        channels.append("scale")
    bpy.context.view_layer.update()
    return channels


def pose_controls(arm_obj: bpy.types.Object, data: ArmatureData, pose: Pose,
                  plan: Redirects, allowed: list[str]) -> dict[str, list[str]]:
    """Move the controls of ``plan`` so that Blender evaluates the solved pose.

    Every allowed bone's own channels must already hold the solved pose (a chain's
    bones too: Blender's IK starts from them, and the next read sees the pose shown).
    Each control is then given its pose matrix, parents first; the bones that follow
    (:func:`followers`: allowed, unconstrained, below a chain, a copying bone or a
    control), which the rig's twist of a chain may have turned, are given their solved
    pose again; and the bones the plan poses and those that follow are compared with the
    solved pose (:func:`_check`).

    Args:
        arm_obj: The armature object.
        data: The armature as read.
        pose: The solved pose in ``data.skeleton``'s frames.
        plan: What to move (:func:`.constraints.plan_redirects`).
        allowed: The bones the write may change.

    Returns:
        ``{bone: channels written}``: the controls, and the allowed bones given their
        solved pose again.

    Raises:
        InputError: Blender's evaluation does not give the solved pose back (a control
            moved but a bone ends elsewhere); the caller restores what was written.
    """
    bpy.context.view_layer.update()
    solved = _Solved(arm_obj, data, pose)
    written: dict[str, list[str]] = {}
    targets = _targets(arm_obj, solved, plan)
    order = {b.name: i for i, b in enumerate(arm_obj.data.bones)}
    for name in sorted(targets, key=lambda n: (len(arm_obj.data.bones[n].parent_recursive),
                                               order[n])):
        rotation, head = targets[name]
        matrix = _evaluated(arm_obj, name)
        if rotation is not None:
            matrix[:3, :3] = rotation * np.linalg.norm(matrix[:3, :3], axis=0)
        if head is not None:
            matrix[:3, 3] = head
        written[name] = _set_pose_matrix(arm_obj, name, matrix, rotation is not None,
                                         head is not None)
    following = followers(arm_obj, plan, allowed, solved.index)
    for name in following:
        got = _evaluated(arm_obj, name)
        if _angle(got, solved.rotation(name)) > FOLLOW_TOLERANCE:  # a chain's twist
            matrix = got.copy()
            matrix[:3, :3] = solved.rotation(name) * np.linalg.norm(got[:3, :3], axis=0)
            changed = _set_pose_matrix(arm_obj, name, matrix, True, False)
            if changed:
                written[name] = changed
    _check(arm_obj, solved, plan, following)
    return written


def followers(arm_obj: bpy.types.Object, plan: Redirects, allowed: list[str],
              index: dict[str, int]) -> list[str]:
    """The allowed bones that hang below the bones and controls the plan moves.

    Only bones without constraints of their own (a constrained bone follows its
    constraint, which the write does not model), parents first.
    """
    moved = plan.handled | plan.controls
    out = []
    for name in set(allowed) - moved:
        bone = arm_obj.data.bones[name]
        if not arm_obj.pose.bones[name].constraints and any(
                p.name in moved for p in bone.parent_recursive):
            out.append(name)
    return sorted(out, key=index.get)


def _angle(matrix: np.ndarray, rotation: np.ndarray, axis_only: bool = False) -> float:
    """Degrees between a pose matrix's rotation (or its y axis) and a rotation's.

    From the chord, ``2 asin(|a - b| / 2)`` (``|A - B|_F / sqrt(8)`` for whole
    rotations), which float32 pose matrices leave accurate near zero, unlike the
    arccos of a trace.
    """
    rot = matrix[:3, :3] / np.linalg.norm(matrix[:3, :3], axis=0)
    chord = (float(np.linalg.norm(rot[:, 1] - rotation[:, 1])) / 2.0 if axis_only
             else float(np.linalg.norm(rot - rotation)) / np.sqrt(8.0))
    return float(np.degrees(2.0 * np.arcsin(min(chord, 1.0))))


def _check(arm_obj: bpy.types.Object, solved: _Solved, plan: Redirects,
           following: list[str]) -> None:
    """Raise when a bone the plan poses, or one below, is evaluated off its solved pose.

    A bone of an IK chain must have its solved head and direction: the twist of a
    chain's bones about their own axes is the rig's (the pole's plane and the knee's
    bend), not the drawing's. A bone copying its control, and ``following`` (the bones
    :func:`followers` gives: a toe), their head and whole rotation. Other bones are the
    free rig's, written as before.
    """
    size = rig_size(arm_obj)
    chained = {n: ch.target for ch in plan.chains for n in ch.chain}
    for name in sorted(plan.handled, key=solved.index.get) + following:
        got = _evaluated(arm_obj, name)
        angle = _angle(got, solved.rotation(name), axis_only=name in chained)
        gap = float(np.linalg.norm(got[:3, 3] - solved.head(name)))
        if angle > ANGLE_TOLERANCE or gap > HEAD_TOLERANCE * size:
            if name in chained:
                how = f"could not be posed through the IK target '{chained[name]}'"
            elif name in plan.copies:
                how = f"could not be posed through its control '{plan.copies[name][0]}'"
            else:
                how = "did not follow the controls moved for the bones above it"
            raise InputError(
                f"'{name}' {how}: Blender evaluates it {angle:.1f} degrees and "
                f"{100 * gap / size:.1f}% of the rig's size from the solved pose. Nothing "
                "was written; mute the constraints of the leg or arm (or set their "
                "influence to 0) to pose its bones themselves.")
