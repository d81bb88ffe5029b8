"""Which pose bones a key cannot move: bones posed by constraints or drivers.

Blender evaluates a pose bone's constraints after its own transform, and drivers overwrite
the driven channel at every evaluation. A rotation written and keyed on a bone that a Copy
Transforms constraint or an IK chain poses therefore does not show, and the solvers would
have posed the character for nothing (a generated Rigify rig's deform bones, ``DEF-*``,
all copy its controls). :func:`overrides` reads, for each bone, what would take over its
rotation and its location, so that :func:`check_writable` refuses to write there and says
what to change instead, unless :func:`plan_redirects` finds the control such a bone
follows (a copied rotation, an IK chain's target and pole), which
:func:`.controls.pose_controls` then poses in its place.

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
    out, seen = [], 0
    while bone is not None and (count == 0 or seen < count):
        # A bone locked for IK on every axis is not turned by the chain: its keys show.
        if c.type != "IK" or not (bone.lock_ik_x and bone.lock_ik_y and bone.lock_ik_z):
            out.append(bone.name)
        seen += 1
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
        bone = bone.replace('\\"', '"').replace("\\\\", "\\")  # RNA path escapes
        out[(bone, prop)] = f"a driver on its {prop}"
    return out


def _takers(arm_obj: bpy.types.Object, names: Sequence[str]
            ) -> tuple[dict[str, list], dict[str, list]]:
    """Everything that takes over each named bone's rotation and location.

    Returns:
        ``(rotation, location)``: per name, a list of ``(reason, owner pose bone,
        constraint)`` (owner and constraint None for a driver), in evaluation order.
    """
    from .write_pose import rotation_channel

    rotation: dict[str, list] = {n: [] for n in names}
    location: dict[str, list] = {n: [] for n in names}
    for pb in arm_obj.pose.bones:
        for c in pb.constraints:
            if not _counts(c):
                continue
            if c.type in _CHAINS:
                why = f"the {c.type.replace('_', ' ')} constraint '{c.name}' on '{pb.name}'"
                for name in _chain(pb, c):
                    if name in rotation:
                        rotation[name].append((why, pb, c))
                continue
            rot, loc = _channels(c)
            if pb.name in rotation and rot:
                rotation[pb.name].append((f"its constraint '{c.name}'", pb, c))
            if pb.name in location and loc:
                location[pb.name].append((f"its constraint '{c.name}'", pb, c))
    for (bone, prop), reason in _driven(arm_obj).items():
        pb = arm_obj.pose.bones.get(bone)
        if pb is None or bone not in rotation:
            continue
        if prop == rotation_channel(pb.rotation_mode):
            rotation[bone].append((reason, None, None))
        if prop == "location":
            location[bone].append((reason, None, None))
    return rotation, location


def overrides(arm_obj: bpy.types.Object, names: Sequence[str]) -> Overrides:
    """What takes over the rotation and location of each named pose bone.

    Args:
        arm_obj: The armature object.
        names: Bone names, in the order wanted.

    Returns:
        The reasons per bone (the first that takes it over; empty strings where keys
        show).
    """
    rotation, location = _takers(arm_obj, names)
    return Overrides(tuple(rotation[n][0][0] if rotation[n] else "" for n in names),
                     tuple(location[n][0][0] if location[n] else "" for n in names))


@dataclass(frozen=True)
class IkChain:
    """An IK chain posed by moving its target (and its pole) to the solved pose.

    Attributes:
        bone: The bone carrying the IK constraint.
        chain: The bones it poses, that bone first when ``use_tail``, upwards.
        use_tail: Whether the chain ends at the bone's tail (else at its head).
        target: The target bone (in the same armature; the chain's end goes to its
            head).
        pole: The pole target bone, or ``""``.
    """

    bone: str
    chain: tuple[str, ...]
    use_tail: bool
    target: str
    pole: str


@dataclass(frozen=True)
class Redirects:
    """Controls through which constrained bones are posed (ours).

    Attributes:
        copies: ``{owner: (source, whole)}``: the owner copies the source bone's world
            rotation (a Copy Rotation on every axis, or with ``whole`` a Copy
            Transforms: also its head), mixed by Replace in world space at full
            influence; the source is given the owner's solved rotation.
        chains: IK chains whose targets are moved to the solved chain's end.
    """

    copies: dict[str, tuple[str, bool]]
    chains: tuple[IkChain, ...]

    @property
    def handled(self) -> set[str]:
        """The constrained bones these controls pose."""
        return set(self.copies) | {n for c in self.chains for n in c.chain}

    @property
    def controls(self) -> set[str]:
        """The bones written in their place."""
        return ({s for s, _ in self.copies.values()} | {c.target for c in self.chains}
                | {c.pole for c in self.chains if c.pole})


def _own_bone(arm_obj, obj, sub: str) -> str:
    """``sub`` when ``obj`` is this armature and it has that bone, else ``""``."""
    return sub if obj == arm_obj and sub and sub in arm_obj.pose.bones else ""


def _copy_source(arm_obj, c) -> tuple[str, bool] | None:
    """The bone a Copy Rotation/Transforms constraint gives its owner's rotation of."""
    if c.type not in ("COPY_ROTATION", "COPY_TRANSFORMS") or c.influence < 1.0:
        return None
    if c.mix_mode != "REPLACE" or c.owner_space != "WORLD" or c.target_space != "WORLD":
        return None
    if c.type == "COPY_ROTATION" and not (c.use_x and c.use_y and c.use_z) or any(
            getattr(c, f"invert_{a}", False) for a in "xyz"):
        return None
    source = _own_bone(arm_obj, c.target, c.subtarget)
    return (source, c.type == "COPY_TRANSFORMS") if source else None


def _ik_chain(arm_obj, pb, c) -> IkChain | None:
    """The chain of an IK constraint that its target bone can pose, or None."""
    if c.type != "IK" or c.influence < 1.0 or c.use_rotation:
        return None
    target = _own_bone(arm_obj, c.target, c.subtarget)
    pole = _own_bone(arm_obj, c.pole_target, c.pole_subtarget)
    if not target or (c.pole_target is not None and not pole):
        return None
    return IkChain(pb.name, tuple(_chain(pb, c)), bool(c.use_tail), target, pole)


def _locked(pb: bpy.types.PoseBone, rotation: bool, location: bool) -> bool:
    """Whether a lock stops writing the rotation or location a control needs."""
    w = (pb.lock_rotations_4d and pb.rotation_mode in ("QUATERNION", "AXIS_ANGLE")
         and pb.lock_rotation_w)
    return bool((rotation and (any(pb.lock_rotation) or w))
                or (location and any(pb.lock_location)))


def _touched(arm_obj: bpy.types.Object, names: Sequence[str], changed: set[str]) -> bool:
    """Whether any of the bones, or a bone above them, is written."""
    for name in names:
        bone = arm_obj.data.bones[name]
        if name in changed or any(p.name in changed for p in bone.parent_recursive):
            return True
    return False


def plan_redirects(arm_obj: bpy.types.Object, allowed: Sequence[str],
                   changed: Sequence[str] = (), pinned: Sequence[str] = ()) -> Redirects:
    """The constrained bones among ``allowed`` that controls can pose (ours).

    A bone is posed through a control when exactly one thing takes its rotation over
    and that is a Copy Rotation or Copy Transforms constraint copying another bone's
    world rotation whole (Replace, world spaces, full influence: a foot following its IK
    control), or an IK constraint at full influence (without rotation matching, with
    Blender's standard solver, not iTaSC) whose target, and pole if any, are bones of
    the armature: the target is moved to the solved chain's end and the pole turned
    with the chain, so that Blender's IK gives the solved chain back. Every bone of such
    a chain must be ``allowed`` to change. The controls must be controls: bones that
    deform nothing (a deforming bone such as the head is part of the character, which
    the write must not move unasked), whose deforming descendants may all change, which
    nothing takes over, which are not pinned, not written themselves (``changed``) and
    not locked on a channel they need (a copied rotation, an IK target's or pole's
    location).

    Not on a generated Rigify rig (``rig_id`` on its armature): its deform bones copy
    its tweak controls, and keys on those would fight its FK and IK controls.

    Args:
        arm_obj: The armature object.
        allowed: Bones the write may change (a chain moves as a whole).
        changed: Bones whose channels are written (never moved as controls): a chain or
            a copying bone is posed through its control only when it, or a bone above
            it, is among them (an IK leg the write does not touch keeps the pose its
            controls give it, not the pose its stale channels would).
        pinned: Bones the solvers leave alone (never moved as controls either).

    Returns:
        The redirects; bones not covered keep their refusal (:func:`check_writable`).
    """
    if arm_obj.data.get("rig_id") is not None:
        # A generated Rigify rig: its deform bones copy tweak controls, which animators
        # use as offsets over its FK and IK controls; keys there would fight those.
        return Redirects({}, ())
    # What takes over each bone, read once (the allowed bones, the controls, the chains).
    rotation, location = _takers(arm_obj, [pb.name for pb in arm_obj.pose.bones])
    allowed_set, changed_set, pinned_set = set(allowed), set(changed), set(pinned)
    copies: dict[str, tuple[str, bool]] = {}
    chains: dict[str, IkChain] = {}
    itasc = arm_obj.pose.ik_solver == "ITASC"
    for name in allowed:
        if len(rotation[name]) != 1 or rotation[name][0][2] is None:
            continue
        _, owner, c = rotation[name][0]
        if c.type == "IK":
            chain = None if itasc else _ik_chain(arm_obj, owner, c)
            if (chain is not None and set(chain.chain) <= allowed_set
                    and _touched(arm_obj, chain.chain, changed_set)):
                chains[chain.bone] = chain
        else:
            source = _copy_source(arm_obj, c)
            if source is not None and _touched(arm_obj, [name], changed_set):
                copies[name] = source
    needs: dict[str, tuple[bool, bool]] = {}  # control: (rotation, location) written
    for source, whole in copies.values():
        needs[source] = (True, whole)
    for ch in chains.values():
        needs[ch.target] = (needs.get(ch.target, (False, False))[0], True)
        if ch.pole:
            needs[ch.pole] = (False, True)
    bones, pbs = arm_obj.data.bones, arm_obj.pose.bones
    busy = {n for n, (rot, loc) in needs.items()
            if rotation[n] or location[n] or n in changed_set or n in pinned_set
            or bones[n].use_deform or _locked(pbs[n], rot, loc)
            or any(d.use_deform and d.name not in allowed_set
                   for d in bones[n].children_recursive)}
    copies = {o: s for o, s in copies.items() if s[0] not in busy}
    kept = tuple(c for c in chains.values() if c.target not in busy and c.pole not in busy
                 and all(len(rotation[n]) == 1 for n in c.chain))
    return Redirects(copies, kept)


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
    named = {n for n, _ in blocked}
    blocked += [(n, f"{found.location[at[n]]}, on its location") for n in locations
                if found.location[at[n]] and n not in named]
    if not blocked:
        return
    listed = ", ".join(f"'{n}' ({why})" for n, why in blocked[:_NAMED])
    more = f" and {len(blocked) - _NAMED} more bones" if len(blocked) > _NAMED else ""
    rigify = ""
    if arm_obj.data.get("rig_id") is not None:
        rigify = (f"'{arm_obj.name}' is a generated Rigify rig: its DEF- and ORG- bones "
                  "follow its controls (Gesture Pose reads a Rigify rig that has its ORG- "
                  "bones as its metarig's bones and poses it through its FK controls). ")
    pinned = (", or put them in the 'Pinned' bone collection to pose the rest"
              if pin_hint else "")
    verb = "is" if len(blocked) == 1 else "are"
    raise InputError(
        f"{rigify}Nothing was written: {listed}{more} {verb} posed by constraints or drivers, "
        f"so keys on them would not show. Mute those constraints or drivers (or set their "
        f"influence to 0) to pose these bones here{pinned}.")
