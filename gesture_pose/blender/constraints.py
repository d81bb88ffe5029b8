"""Which pose bones a key cannot move: bones posed by constraints or drivers.

Blender evaluates a pose bone's constraints after its own transform, and drivers overwrite
the driven channel at every evaluation. A rotation written and keyed on a bone that a Copy
Transforms constraint or an IK chain poses therefore does not show, and the solvers would
have posed the character for nothing (a generated Rigify rig's deform bones, ``DEF-*``,
all copy its controls). :func:`overrides` reads, for each bone, what would take over its
rotation and its location, so that :func:`check_writable` refuses to write there and says
what to change instead.

What counts: a constraint that is enabled, valid (Blender can evaluate it: its targets
exist) and has a non-zero influence, of a kind that replaces the channel (Copy Rotation
and Copy Transforms mixed by Replace, Damped Track, Track To, Stretch To, IK chains...).
Constraints that combine with the bone's own transform (Child Of, Armature, Action, the
Add, Before and After mixes, Copy Location with an offset) let keys show, and the
abstraction mode's black-box path solves through them; limit constraints, Floor, Copy
Scale and Maintain Volume only bound or scale the bone. None of these count, nor does a
targetless IK constraint (Blender's interactive Auto IK, which holds the chain as posed).
An IK constraint takes over its chain: ``chain_count`` bones from its own bone (from the
bone's parent when ``use_tail`` is off), every ancestor when the count is 0. A driver counts
on the rotation channel of the bone's rotation mode, or on its location.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import bpy

from ..core.exceptions import InputError

#: Constraint types that replace both the rotation and the location of their bone.
_WHOLE = frozenset({"CAMERA_SOLVER", "OBJECT_SOLVER", "FOLLOW_TRACK", "TRANSFORM_CACHE"})
#: Constraint types that replace the rotation only (aiming ones, a stretch to a target).
_ROTATION = frozenset({"DAMPED_TRACK", "LOCKED_TRACK", "TRACK_TO", "STRETCH_TO"})
#: Constraint types that replace the location only.
_LOCATION = frozenset({"CLAMP_TO"})
#: Constraint types that take over a chain of bones ending at their own.
_CHAINS = frozenset({"IK", "SPLINE_IK"})
#: How many bones an error message names before "and N more".
_NAMED = 3


@dataclass(frozen=True)
class Overrides:
    """What takes over each bone's channels, in the order of the names read.

    Attributes:
        rotation: For each bone, what poses its rotation (``"its constraint 'Copy
            Transforms'"``), or ``""`` when a written rotation shows.
        location: Likewise for its location.
    """

    rotation: tuple[str, ...]
    location: tuple[str, ...]


def _counts(c: bpy.types.Constraint) -> bool:
    """Whether Blender evaluates the constraint with some effect."""
    enabled = getattr(c, "enabled", not getattr(c, "mute", False))
    return bool(enabled and c.is_valid and c.influence > 0.0)


def _channels(c: bpy.types.Constraint) -> tuple[bool, bool]:
    """``(rotation, location)``: which channels of its own bone a constraint replaces.

    Constraints that combine with the bone's own transform (Child Of, Armature and Action
    act as parents or offsets; Copy Rotation or Copy Transforms mixed in by Add, Before or
    After; Copy Location with an offset) let the keyed channels show and do not count.
    """
    kind = c.type
    if kind in _WHOLE:
        return True, True
    if kind in _ROTATION:
        return True, False
    if kind in _LOCATION:
        return False, True
    if kind == "COPY_TRANSFORMS":
        return (c.mix_mode == "REPLACE",) * 2
    if kind == "COPY_ROTATION":
        return c.mix_mode == "REPLACE" and any((c.use_x, c.use_y, c.use_z)), False
    if kind == "COPY_LOCATION":
        return False, not c.use_offset and any((c.use_x, c.use_y, c.use_z))
    if kind == "TRANSFORM":
        return (c.map_to == "ROTATION" and c.mix_mode_rot == "REPLACE",
                c.map_to == "LOCATION" and c.mix_mode == "REPLACE")
    if kind == "SHRINKWRAP":
        return bool(getattr(c, "use_track_normal", False)), True
    return False, False


def _chain(pose_bone: bpy.types.PoseBone, c: bpy.types.Constraint) -> list[str]:
    """Names of the bones an IK or Spline IK constraint poses (its chain)."""
    if c.type == "IK" and c.target is None:  # targetless (Auto IK): holds the chain
        return []
    bone = pose_bone if c.type == "SPLINE_IK" or c.use_tail else pose_bone.parent
    count = int(c.chain_count)
    out = []
    while bone is not None and (count == 0 or len(out) < count):
        out.append(bone.name)
        bone = bone.parent
    return out


def _driven(arm_obj: bpy.types.Object) -> dict[tuple[str, str], str]:
    """``{(bone, property): reason}`` for the enabled, valid drivers on pose-bone channels."""
    anim = arm_obj.animation_data
    out = {}
    for fc in anim.drivers if anim is not None else ():
        path = fc.data_path
        if (fc.mute or fc.driver is None or not fc.driver.is_valid
                or not path.startswith('pose.bones["') or '"].' not in path):
            continue
        bone, prop = path[len('pose.bones["'):].split('"].', 1)
        out[(bone, prop)] = f"a driver on its {prop}"
    return out


def overrides(arm_obj: bpy.types.Object, names: Sequence[str]) -> Overrides:
    """What takes over the rotation and location of each named pose bone.

    Args:
        arm_obj: The armature object.
        names: Bone names, in the order wanted.

    Returns:
        The reasons per bone (empty strings where keys show).
    """
    from .write_pose import rotation_channel

    rotation = {n: "" for n in names}
    location = dict(rotation)
    for pb in arm_obj.pose.bones:
        for c in pb.constraints:
            if not _counts(c):
                continue
            if c.type in _CHAINS:
                for name in _chain(pb, c):
                    if name in rotation and not rotation[name]:
                        rotation[name] = (f"the {c.type.replace('_', ' ')} constraint "
                                          f"'{c.name}' on '{pb.name}'")
                continue
            rot, loc = _channels(c)
            if pb.name in rotation and rot and not rotation[pb.name]:
                rotation[pb.name] = f"its constraint '{c.name}'"
            if pb.name in location and loc and not location[pb.name]:
                location[pb.name] = f"its constraint '{c.name}'"
    for (bone, prop), reason in _driven(arm_obj).items():
        pb = arm_obj.pose.bones.get(bone)
        if pb is None or bone not in rotation:
            continue
        if prop == rotation_channel(pb.rotation_mode) and not rotation[bone]:
            rotation[bone] = reason
        if prop == "location" and not location[bone]:
            location[bone] = reason
    return Overrides(tuple(rotation[n] for n in names), tuple(location[n] for n in names))


def check_writable(arm_obj: bpy.types.Object, rotations: Sequence[str],
                   locations: Sequence[str] = (), pin_hint: bool = False) -> None:
    """Refuse to write channels that constraints or drivers take over.

    Args:
        arm_obj: The armature object.
        rotations: Bones whose rotation is about to be written.
        locations: Bones whose location is about to be written.
        pin_hint: Also suggest the ``Pinned`` bone collection (the modes that leave
            pinned bones alone).

    Raises:
        InputError: Some of those channels would not show; names the bones, what poses
            them and what to do. Nothing has been written.
    """
    names = list(dict.fromkeys([*rotations, *locations]))
    if not names:
        return
    found = overrides(arm_obj, names)
    at = {n: i for i, n in enumerate(names)}
    blocked = [(n, found.rotation[at[n]]) for n in rotations if found.rotation[at[n]]]
    blocked += [(n, f"{found.location[at[n]]}, on its location") for n in locations
                if found.location[at[n]] and n not in dict(blocked)]
    if not blocked:
        return
    listed = ", ".join(f"'{n}' ({why})" for n, why in blocked[:_NAMED])
    more = f" and {len(blocked) - _NAMED} more bones" if len(blocked) > _NAMED else ""
    rigify = ""
    if arm_obj.data.get("rig_id") is not None:
        rigify = (f"'{arm_obj.name}' is a generated Rigify rig: its DEF- and ORG- bones "
                  "follow its controls, which Gesture Pose does not pose yet. ")
    pinned = (", or put them in the 'Pinned' bone collection to pose the rest"
              if pin_hint else "")
    verb = "is" if len(blocked) == 1 else "are"
    raise InputError(
        f"{rigify}Nothing was written: {listed}{more} {verb} posed by constraints or drivers, "
        f"so keys on them would not show. Mute those constraints or drivers (or set their "
        f"influence to 0) to pose these bones here{pinned}.")
