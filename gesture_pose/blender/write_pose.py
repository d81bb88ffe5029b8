"""Write core local rotations back to pose bones, in each bone's rotation mode, and key them.

Only bones whose rotation changed are touched, and only their rotation channel is keyed
(plus ``location`` for the bones asked for), at one frame; a limb rigged with IK is also
posed through its controls, whose changed channels are keyed too (``controls.py``).
Values stay continuous with the current ones: quaternions keep the hemisphere of the
current value, Euler angles use Blender's compatible-Euler conversion and axis-angle
keeps the side of the current axis.

For a rig read as its joint skeleton (``ArmatureData.frame_change`` set: an imported rig
with token bones) the pose is in the joint skeleton's frames and is conjugated back to the
real bones' local frames (``Q = C Q' C^T``, ``t = C t'``) before anything is written.
"""

from __future__ import annotations

from collections.abc import Sequence

import bpy
import numpy as np
from mathutils import Matrix, Vector

from ..core.exceptions import InputError
from ..core.joint_skeleton import from_joint_pose
from ..core.skeleton import Pose
from .constraints import check_writable, plan_redirects
from .controls import pose_controls
from .read_armature import ArmatureData

_MODE_CHANNEL = {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle"}


def rotation_channel(mode: str) -> str:
    """The pose-bone property holding the rotation in ``mode`` (e.g. ``'rotation_euler'``)."""
    return _MODE_CHANNEL.get(mode, "rotation_euler")


def _indices(data: ArmatureData, bones: Sequence[int | str] | None) -> list[int]:
    n = data.skeleton.n_bones
    if bones is None:
        return list(range(n))
    out = [data.skeleton.index(b) if isinstance(b, str) else int(b) for b in bones]
    bad = [i for i in out if not 0 <= i < n]
    if bad:
        raise InputError(f"Bone indices {bad} are out of range for {n} bones.")
    return out


def _check_pose(data: ArmatureData, pose: Pose) -> None:
    n = data.skeleton.n_bones
    rot, trans = np.asarray(pose.rotations), np.asarray(pose.translations)
    if rot.shape != (n, 3, 3) or trans.shape != (n, 3):
        raise InputError(f"The pose has {rot.shape[0]} bones but the armature "
                         f"'{data.object_name}' has {n}: read the armature again.")
    if not (np.all(np.isfinite(rot)) and np.all(np.isfinite(trans))):
        raise InputError("The computed pose has NaN values; nothing was written.")


def blender_pose(data: ArmatureData, pose: Pose) -> Pose:
    """A pose of ``data``'s skeleton in the pose bones' own local frames.

    Args:
        data: The armature as read.
        pose: Local rotations and translations in ``data.skeleton``'s frames.

    Returns:
        ``pose`` itself for rigs read as they are; for joint skeletons the real bones'
        ``Q = C Q' C^T`` and ``t = C t'``.
    """
    if data.frame_change is None:
        return pose
    return from_joint_pose(pose, data.frame_change)


def set_rotation(pb: bpy.types.PoseBone, rotation: np.ndarray) -> str:
    """Assign a local rotation to a pose bone in its rotation mode, continuously.

    Args:
        pb: The pose bone.
        rotation: Local rotation matrix (``matrix_basis`` rotation), shape ``(3, 3)``.

    Returns:
        The name of the channel written.
    """
    quat = Matrix(np.asarray(rotation, dtype=float).tolist()).to_quaternion()
    mode = pb.rotation_mode
    if mode == "QUATERNION":
        if quat.dot(pb.rotation_quaternion) < 0.0:
            quat.negate()
        pb.rotation_quaternion = quat
    elif mode == "AXIS_ANGLE":
        axis, angle = quat.to_axis_angle()
        if axis.dot(Vector(pb.rotation_axis_angle[1:])) < 0.0:
            axis, angle = -axis, -angle
        pb.rotation_axis_angle = (angle, *axis)
    else:
        pb.rotation_euler = quat.to_euler(mode, pb.rotation_euler)
    return rotation_channel(mode)


def apply_pose(arm_obj: bpy.types.Object, data: ArmatureData, new_pose: Pose,
               bones: Sequence[int | str] | None = None, insert_keys: bool = True,
               frame: float | None = None, location_bones: Sequence[int | str] = (),
               tol: float = 1e-6, pin_hint: bool = False, redirect: bool = True
               ) -> list[str]:
    """Write the changed local rotations (and chosen locations) of a pose to the armature.

    Args:
        arm_obj: The armature object ``data`` was read from.
        data: The armature as read before solving (its pose is the "unchanged" reference).
        new_pose: Local rotations and translations in skeleton order, in the frames of
            ``data.skeleton`` (converted to the pose bones' frames here).
        bones: Bones (indices or names) allowed to change; all when None.
        insert_keys: Key the written channels.
        frame: Frame of the keys (the scene's current frame when None).
        location_bones: Bones whose location is also written and keyed from
            ``new_pose.translations`` (world units, divided by the object scale).
        tol: Bones whose rotation matrix entries change by at most ``tol`` are skipped
            (unless a moved control turned them: :func:`.controls.pose_controls`).
        pin_hint: The refusal of constrained bones also suggests the ``Pinned`` bone
            collection (for the modes whose solvers leave pinned bones alone: Pose and
            the abstraction operators; Pose Stroke keeps them in place by turning them).
        redirect: Pose constrained bones through their controls (below). False for a
            solve that already went through Blender's evaluation, constraints included
            (the abstraction tools' black-box path): its result is what Blender shows.

    Returns:
        Names of the bones written, in skeleton order: those whose channels changed,
        with the controls moved for constrained bones and the bones below them given
        their solved pose again. For a generated Rigify rig (``data.rigify``), the
        controls and the limbs' ``IK_FK`` holders written, in the armature's bone order
        (:func:`_apply_rigify`).

    Bones whose rotation a constraint takes over are posed through the control it
    follows when there is one (:func:`.constraints.plan_redirects`: a copied rotation,
    an IK chain's target and pole; :func:`.controls.pose_controls` checks Blender's
    evaluation gives the solved pose back); the controls are keyed too, and so are the
    bones' own channels, which then hold the pose shown (the next read starts from it,
    and Blender's IK starts from it).

    Raises:
        InputError: The pose does not match the armature or has NaN values, or a channel
            to write is posed by a constraint or driver that no control poses
            (:func:`.constraints.check_writable`), or the controls do not give the
            solved pose back; nothing is written (what was set is put back).
    """
    _check_pose(data, new_pose)
    selected = _indices(data, bones)
    with_location = set(_indices(data, location_bones))
    frame = bpy.context.scene.frame_current if frame is None else frame
    solved = new_pose
    old, new_pose = blender_pose(data, data.pose), blender_pose(data, new_pose)
    diff = np.abs(np.asarray(new_pose.rotations) - old.rotations).max(axis=(1, 2))
    old_t, new_t = old.translations, np.asarray(new_pose.translations, dtype=float)
    moved = np.abs(new_t - old_t).max(axis=1) > tol
    names = data.skeleton.names
    order = sorted(set(selected) | with_location)
    gone = [names[i] for i in order if arm_obj.pose.bones.get(names[i]) is None]
    if gone:  # checked before anything is written
        raise InputError(f"Bone '{gone[0]}' no longer exists in '{arm_obj.name}': read the "
                         "armature again.")
    rotating = [names[i] for i in selected if diff[i] > tol]
    allowed = [names[i] for i in selected]
    relocated = [names[i] for i in sorted(with_location) if moved[i]]
    if data.rigify is not None:
        return _apply_rigify(arm_obj, data, solved, allowed, rotating, relocated,
                             insert_keys, frame)
    plan = plan_redirects(arm_obj, allowed if redirect else [], rotating + relocated,
                          [names[i] for i in np.flatnonzero(data.pinned)])
    handled = plan.handled
    check_writable(arm_obj, [n for n in rotating if n not in handled], relocated, pin_hint)
    saved = _channel_values(arm_obj, [names[i] for i in order] + sorted(plan.controls))
    channels: dict[str, list[str]] = {}
    try:
        for i in order:  # a chain's and a copying bone's own channels too
            name = names[i]
            pb = arm_obj.pose.bones[name]
            if i in selected and diff[i] > tol:
                channels.setdefault(name, []).append(set_rotation(pb, new_pose.rotations[i]))
            if i in with_location and moved[i]:
                pb.location = new_t[i] / data.object_scale
                channels.setdefault(name, []).append("location")
        if plan.copies or plan.chains:
            for name, written in pose_controls(arm_obj, data, solved, plan,
                                               allowed).items():
                if written:  # a control already in place is not written
                    have = channels.setdefault(name, [])
                    have.extend(c for c in written if c not in have)
    except Exception:  # a failed check, or anything else half-way: put it back
        _restore(arm_obj, saved)
        raise
    if insert_keys:
        _key_channels(arm_obj, channels, frame)
    position = {n: i for i, n in enumerate(names)}
    return sorted(channels, key=lambda n: position.get(n, len(names)))


def _key_channels(arm_obj: bpy.types.Object, channels: dict[str, list[str]],
                  frame: float) -> None:
    """Key every written channel (``{bone: channels}``) at ``frame``."""
    for name, written in channels.items():
        for channel in written:
            arm_obj.pose.bones[name].keyframe_insert(channel, frame=frame, group=name)


def _apply_rigify(arm_obj: bpy.types.Object, data: ArmatureData, solved: Pose,
                  allowed: list[str], rotating: list[str], relocated: list[str],
                  insert_keys: bool, frame: float) -> list[str]:
    """:func:`apply_pose` on a generated Rigify rig: through its controls (``rigify.py``).

    The bones outside ``allowed`` keep the rotations they have and the root keeps its
    place unless it is ``relocated`` (the controls are then moved so that they do: a
    spine control turns the hips about the spine's middle). A limb switched from IK to
    FK has its ``IK_FK`` keyed at the frame only (:func:`_key_switch`); a switch that
    would change other frames is refused (:func:`_check_switches`). A control channel
    that is locked (``lock_rotation``, ``lock_location``, ``lock_scale``) is never
    changed: the write is refused instead.
    """
    from .rigify import IK_FK, ROTATION_TOLERANCE, pose_rig, switching

    if not rotating and not relocated:
        return []
    rig = data.rigify
    old, new = np.asarray(data.pose.rotations), np.asarray(solved.rotations)
    index = {n: i for i, n in enumerate(data.skeleton.names)}
    # Solver noise does not switch a limb: only turns the controls would make count.
    turn = np.degrees(2 * np.arcsin(np.minimum(
        np.linalg.norm(new - old, axis=(1, 2)) / np.sqrt(8.0), 1.0)))
    rotating = [n for n in rotating if turn[index[n]] > ROTATION_TOLERANCE / 4]
    names = data.skeleton.names
    keep = np.array([n not in set(allowed) for n in names])
    rotations = np.where(keep[:, None, None], data.pose.rotations, solved.rotations)
    translations = np.array(data.pose.translations, dtype=float)
    for name in relocated:
        translations[names.index(name)] = np.asarray(solved.translations)[names.index(name)]
    effective = Pose(rotations, translations)
    switched = switching(arm_obj, data, rotating)
    fk_frames = _check_switches(arm_obj, switched, insert_keys, frame)
    # The FK controls of a switched limb as the frames it shows FK on have them.
    held = {c: _held_values(arm_obj, c, fk_frames[h]) for n, h in rig.switches.items()
            if fk_frames.get(h) and (c := rig.controls.get(n))}
    holders = sorted(set(rig.switches.values()))
    writable = sorted({*rig.controls.values(), *holders}
                      | {p.name for c in rig.controls.values()
                         for p in arm_obj.data.bones[c].parent_recursive})
    saved = _channel_values(arm_obj, writable)
    switches = {h: arm_obj.pose.bones[h].get(IK_FK) for h in holders}
    try:
        channels = pose_rig(arm_obj, data, effective, rotating, switched)
        _check_locks(arm_obj, saved, channels)
    except Exception:
        for holder, value in switches.items():
            if value is not None:
                arm_obj.pose.bones[holder][IK_FK] = value
        arm_obj.update_tag()
        _restore(arm_obj, saved)
        raise
    if insert_keys:
        _key_channels(arm_obj, channels, frame)
        for holder in switched:
            _key_switch(arm_obj, holder, IK_FK, float(switches[holder] or 0.0), frame)
        for name, values in held.items():
            _hold(arm_obj, name, values, channels.get(name, []))
    for holder in switched:
        channels.setdefault(holder, []).append(f'["{IK_FK}"]')
    order = {b.name: i for i, b in enumerate(arm_obj.data.bones)}
    return sorted(channels, key=order.get)


def _switch_curve(arm_obj: bpy.types.Object, holder: str):
    """The F-curve of a limb's ``IK_FK`` in the armature's action slot, or None."""
    from .rigify import IK_FK

    bag = _channelbag(arm_obj)
    path = f'pose.bones["{bpy.utils.escape_identifier(holder)}"]["{IK_FK}"]'
    return next((c for c in bag.fcurves if c.data_path == path), None) if bag else None


def _check_switches(arm_obj: bpy.types.Object, holders: list[str], insert_keys: bool,
                    frame: float) -> dict[str, list[float]]:
    """Refuse a switch from IK to FK that would change other frames.

    Keyed, the switch holds at ``frame`` only (:func:`_key_switch`); that needs the limb
    in IK (``IK_FK`` 0) at the frame. Frames an earlier write switched to FK (``IK_FK``
    keyed 1, every frame showing FK keyed so) keep their FK pose: the FK channels keyed
    here are also keyed there with the values they have (:func:`_hold`). A blend from
    IK to FK, or FK held over frames without keys, is the animator's. Unkeyed, the
    switch would hold on every frame of an animated rig (its action or NLA strips).

    Returns:
        ``{holder: the keyed frames showing FK}``.
    """
    from .rigify import IK_FK

    anim = arm_obj.animation_data
    animated = anim is not None and (
        any(len(t.strips) for t in anim.nla_tracks)
        or (anim.action is not None and _channelbag(arm_obj) is not None
            and len(_channelbag(arm_obj).fcurves) > 0))
    out = {}
    for holder in holders:
        curve = _switch_curve(arm_obj, holder)
        if not insert_keys and (animated or curve is not None):
            raise InputError(
                f"Nothing was written: the pose switches '{holder}' from IK to FK, which "
                "unkeyed would show on every frame; turn Insert Keys on (the switch is "
                "then keyed at this frame only) or switch the limb yourself.")
        if curve is None:
            alone, ok = [], float(arm_obj.pose.bones[holder].get(IK_FK, 0.0)) <= 1e-6
        else:
            keys = {k.co[0]: k.co[1] for k in curve.keyframe_points}
            alone = sorted(g for g, v in keys.items() if v > 1e-6)
            # FK only on keyed frames, whole (1), every other frame around them and
            # around this one in IK (0): no FK frame is interpolated between keys.
            ok = (all(abs(keys[g] - 1.0) <= 1e-6 for g in alone)
                  and curve.evaluate(frame) <= 1e-6
                  and all(curve.evaluate(g) <= 1e-6 or g in keys
                          for g in {frame - 1, frame + 1,
                                    *(g + d for g in alone for d in (-1, 1))}))
        if not ok:
            raise InputError(
                f"Nothing was written: the IK/FK switch of '{holder}' is animated or "
                f"blends IK and FK (FK held between keys, or part-way, around frame "
                f"{frame:g} or elsewhere); switch the limb to FK at this frame yourself "
                "(Rigify's IK/FK panel), or pose it on a frame where it is in FK.")
        out[holder] = alone
    return out


def _held_values(arm_obj: bpy.types.Object, name: str, frames: list[float]) -> dict:
    """``{(channel, frame): values}`` of a control's channels at the given frames."""
    pb = arm_obj.pose.bones[name]
    bag = _channelbag(arm_obj)
    out = {}
    for channel in (rotation_channel(pb.rotation_mode), "location", "scale"):
        path = f'pose.bones["{bpy.utils.escape_identifier(name)}"].{channel}'
        curves = {c.array_index: c for c in (bag.fcurves if bag else ())
                  if c.data_path == path}
        now = list(getattr(pb, channel))
        for g in frames:
            out[(channel, g)] = [curves[i].evaluate(g) if i in curves else now[i]
                                 for i in range(len(now))]
    return out


def _hold(arm_obj: bpy.types.Object, name: str, values: dict, written: list[str]) -> None:
    """Key a written control's channels where the limb shows FK alone, as they were.

    At the frames of :func:`_held_values` that have no key on the channel yet.
    """
    pb = arm_obj.pose.bones[name]
    for (channel, g), old in values.items():
        if channel not in written or g in keyed_frames(arm_obj, name, channel):
            continue
        now = list(getattr(pb, channel))
        setattr(pb, channel, old)
        pb.keyframe_insert(channel, frame=g, group=name)
        setattr(pb, channel, now)


def _channelbag(arm_obj: bpy.types.Object):
    """The channelbag of the armature's action slot, or None."""
    from bpy_extras.anim_utils import action_get_channelbag_for_slot

    anim = arm_obj.animation_data
    if anim is None or anim.action is None:
        return None
    return action_get_channelbag_for_slot(anim.action, anim.action_slot)


def _check_locks(arm_obj: bpy.types.Object, saved: dict, channels: dict) -> None:
    """Raise when a written control changed a locked component of a channel."""
    for name, written in channels.items():
        pb = arm_obj.pose.bones[name]
        locks = {"location": tuple(pb.lock_location), "scale": tuple(pb.lock_scale),
                 "rotation_euler": tuple(pb.lock_rotation),
                 "rotation_quaternion": (pb.lock_rotations_4d and pb.lock_rotation_w,
                                         *pb.lock_rotation),
                 "rotation_axis_angle": (pb.lock_rotations_4d and pb.lock_rotation_w,
                                         *pb.lock_rotation)}
        for channel in written:
            if channel not in locks:
                continue
            moved = np.abs(np.array(getattr(pb, channel)) - saved[name][channel]) > 1e-6
            if np.any(moved & np.array(locks[channel], bool)):
                raise InputError(
                    f"Nothing was written: the pose needs the control '{name}' of "
                    f"'{arm_obj.name}' to change its locked {channel.replace('_', ' ')}; "
                    "unlock it to pose these bones.")


def _key_switch(arm_obj: bpy.types.Object, holder: str, prop: str, old: float,
                frame: float) -> None:
    """Key a limb's IK/FK switch at ``frame`` only.

    :func:`_check_switches` made sure the switch is flat around the frame. The key at
    the frame is constant; so is a key of the old value added at the frame before
    (holding it up to this frame); one added at the frame after keeps the interpolation
    of the segment it splits (the curve is flat there, so its shape does not change).
    Keys already at those frames are left as they are.
    """
    pb = arm_obj.pose.bones[holder]
    curve = _switch_curve(arm_obj, holder)
    keyed = {k.co[0] for k in curve.keyframe_points} if curve is not None else set()
    after = curve.evaluate(frame + 1) if curve is not None else old
    before = curve.evaluate(frame - 1) if curve is not None else old
    value = pb[prop]
    pb.keyframe_insert(f'["{prop}"]', frame=frame, group=holder)
    added = []
    for f, v in ((frame - 1, before), (frame + 1, after)):
        if f not in keyed:
            pb[prop] = v
            pb.keyframe_insert(f'["{prop}"]', frame=f, group=holder)
            added.append(f)
    pb[prop] = value
    curve = _switch_curve(arm_obj, holder)
    for k in curve.keyframe_points:
        if k.co[0] == frame or (k.co[0] == frame - 1 and frame - 1 in added):
            k.interpolation = "CONSTANT"
    arm_obj.update_tag()


def _channel_values(arm_obj: bpy.types.Object, names: Sequence[str]) -> dict:
    """Every rotation channel, location and scale of the named pose bones, as they are."""
    out = {}
    for name in dict.fromkeys(names):
        pb = arm_obj.pose.bones[name]
        out[name] = {c: tuple(getattr(pb, c)) for c in ("rotation_quaternion", "rotation_euler",
                                                       "rotation_axis_angle", "location",
                                                       "scale")}
    return out


def _restore(arm_obj: bpy.types.Object, saved: dict) -> None:
    """Put back what :func:`_channel_values` read."""
    for name, values in saved.items():
        pb = arm_obj.pose.bones[name]
        for channel, value in values.items():
            setattr(pb, channel, value)
    bpy.context.view_layer.update()


def keyed_frames(arm_obj: bpy.types.Object, bone_name: str, channel: str) -> list[float]:
    """Frames at which a pose-bone channel has keys in the object's current action slot.

    Args:
        arm_obj: The armature object.
        bone_name: Pose bone name.
        channel: Property name, e.g. ``'rotation_quaternion'`` or ``'location'``, or a
            custom property's path (``'["IK_FK"]'``).

    Returns:
        Sorted distinct key frames over all components of the channel.
    """
    from bpy_extras.anim_utils import action_get_channelbag_for_slot

    anim = arm_obj.animation_data
    if anim is None or anim.action is None:
        return []
    bag = action_get_channelbag_for_slot(anim.action, anim.action_slot)
    if bag is None:
        return []
    dot = "" if channel.startswith("[") else "."  # a custom property: '["IK_FK"]'
    path = f'pose.bones["{bpy.utils.escape_identifier(bone_name)}"]{dot}{channel}'
    frames: set[float] = set()
    for fcurve in bag.fcurves:
        if fcurve.data_path == path and len(fcurve.keyframe_points):
            co = np.empty(2 * len(fcurve.keyframe_points))
            fcurve.keyframe_points.foreach_get("co", co)
            frames.update(co[0::2].tolist())
    return sorted(frames)
