"""Generated Rigify rigs: read as their metarig's bones, posed through the FK controls.

A generated Rigify rig (``rig_id`` on its armature data) has no bone an animator keys
that is also the character's bone: the deform bones (``DEF-``) copy tweak controls and
stretch to the next, the limbs' ``DEF-`` bones are split into segments, and the
original bones (``ORG-``) copy the FK or IK controls. The solvers need one bone per
metarig bone, posed as Blender shows it, so the rig is read as its **reading bones**:

- the ``ORG-`` bone when it copies a control (limbs, hands, feet, toes, shoulders and
  head: an exact copy of ``upper_arm_fk.L``, ``head``);
- a control spanning a chain of ``ORG-`` bones that follow mechanism bones (the neck
  control over the two neck bones, whose middle joint lies on the line from neck to
  head; each finger's FK control);
- the ``DEF-`` bone with the ``ORG-`` bone's rest head and tail when the ``ORG-`` bone
  copies nothing (the spine, whose ``ORG-`` bones hang from its tweaks, not from each
  other; palms, pelvis sides, the face);
- otherwise the ``ORG-`` bone.

Their parents are the metarig's (the nearest reading bone above in Blender's parents,
or, where the chain goes through the torso's controls, the bone whose rest tail is the
head). Their pose is read from Blender's evaluation (``pose_bone.matrix``), not from
their channels.

Each reading bone is written through the control that turns it: the FK control its
``ORG-`` bone copies (``upper_arm_fk.L``), the spine's FK control (``spine_fk.002``),
the neck, head and finger controls. A limb in IK (its ``IK_FK`` property below 1) that
the write changes is switched to FK at the frame written. Controls are turned in their
own hierarchy's order (the spine's FK controls hang from the torso's middle outwards),
each by the turn its bone still needs, until Blender's evaluation gives the solved
rotations back.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

#: Armature-data property that marks a generated Rigify rig.
RIG_ID = "rig_id"
#: The limb property switching between IK (0) and FK (1).
IK_FK = "IK_FK"
_PREFIXES = ("ORG-", "DEF-", "MCH-", "VIS_", "WGT-")


@dataclass(frozen=True)
class RigifyMap:
    """How a generated Rigify rig is read and written.

    Attributes:
        reading: The reading bones (Blender names), one per metarig bone read.
        parents: The reading parent of each, ``-1`` for the root, shape ``(n,)``.
        deform: Whether the metarig bone deforms (has ``DEF-`` bones), shape ``(n,)``.
        controls: ``{reading bone: control}``: the bone whose rotation turns it (the
            reading bone itself for a control read directly, such as the neck).
        switches: ``{reading bone: pose bone}`` holding the ``IK_FK`` property of its
            limb, for bones of limbs that have one.
        groups: ``{vertex group: reading bone}``: the ``DEF-`` bones (split segments
            included) that deform with each reading bone.
        axis_only: Reading bones whose twist is the rig's: they stretch to the next
            bone and copy the rotation of a tweak that another control carries (the
            middle of the spine, whose twist follows the hips' and chest's controls);
            only their direction is posed.
        orgs: ``{ORG- bone: reading bone}``.
        partial: Reading bones without a control whose ``ORG-`` bone copies a control
            part-way (palms .02 and .03 follow the palm control at a third and two
            thirds): they follow the rig.
    """

    reading: tuple[str, ...]
    parents: np.ndarray
    deform: np.ndarray
    controls: dict[str, str]
    switches: dict[str, str]
    groups: dict[str, str]
    axis_only: frozenset[str] = frozenset()
    orgs: dict[str, str] = field(default_factory=dict)
    partial: frozenset[str] = frozenset()

    @property
    def roles(self) -> dict[str, str]:
        """Humanoid roles the metarig's names do not give (``{role: reading bone}``).

        The spine's first bone (the root) is the pelvis; the bone the ``head`` control
        poses is the head.
        """
        out = {}
        roots = [n for n, p in zip(self.reading, self.parents, strict=True) if p < 0]
        if roots:
            out["pelvis"] = roots[0]
        head = next((r for r, c in self.controls.items() if c == "head"), None)
        if head is not None:
            out["head"] = head
        return out

    def reading_of(self, name: str) -> str:
        """The reading bone a bone of the rig stands for, ``name`` itself otherwise.

        A control (``upper_arm_fk.L``, ``upper_arm_ik.L``, the limb's
        ``upper_arm_parent.L``), an ``ORG-`` bone or a ``DEF-`` segment: what an animator
        selects to name a limb.
        """
        if name in self.reading:
            return name
        by_control = {c: r for r, c in self.controls.items()}
        if name in by_control:
            return by_control[name]
        found = self.orgs.get(name) or self.groups.get(name)
        if found:
            return found
        stem, dot, side = name.rpartition(".")
        if side not in ("L", "R"):
            stem, dot, side = name, "", ""
        for tag in ("_ik_target", "_fk", "_ik", "_parent", "_master"):
            if stem.endswith(tag):  # f_index.01_master.L -> ORG-f_index.01.L
                found = self.orgs.get(f"ORG-{stem[: -len(tag)]}{dot}{side}")
                return self.reading_of(found) if found else name
        if name == "torso":  # the figure's master control: its root
            return self.roles.get("pelvis", name)
        return name


def is_rigify(arm_obj: bpy.types.Object) -> bool:
    """Whether the armature is a generated Rigify rig (``rig_id`` and ``ORG-`` bones)."""
    return (arm_obj is not None and arm_obj.type == "ARMATURE"
            and arm_obj.data.get(RIG_ID) is not None
            and any(b.name.startswith("ORG-") for b in arm_obj.data.bones))


def _is_control(name: str) -> bool:
    """Whether a bone is one an animator poses (not ``MCH-``, ``DEF-``, ``ORG-``, tweaks)."""
    return not name.startswith(_PREFIXES) and "tweak" not in name


def _same_rest(a: bpy.types.Bone, b: bpy.types.Bone, tol: float) -> bool:
    return ((a.head_local - b.head_local).length < tol
            and (a.tail_local - b.tail_local).length < tol)


def _exact_source(pb: bpy.types.PoseBone, holders: dict[str, str]) -> str:
    """The control a pose bone copies whole, or ``""``.

    Its first Copy Transforms, at full influence, from a control; every later
    constraint is the limb's IK copy (driven by ``IK_FK``), scales it only or has no
    influence. A palm copying its control at a third and turned by a Copy Rotation has
    none.
    """
    found = ""
    for c in pb.constraints:
        if not found:
            if (c.type != "COPY_TRANSFORMS" or c.target != pb.id_data or c.influence < 1.0
                    or not _is_control(c.subtarget)):
                return ""
            found = c.subtarget
        elif (c.influence > 0.0 and pb.name not in holders
              and c.type not in ("COPY_SCALE", "LIMIT_SCALE")):
            return ""
    return found


def _copy_sources(pb: bpy.types.PoseBone) -> list[str]:
    """The bones the Copy Transforms constraints of a pose bone copy, in stack order."""
    return [c.subtarget for c in pb.constraints
            if c.type == "COPY_TRANSFORMS" and c.subtarget and c.target == pb.id_data
            and c.subtarget in pb.id_data.pose.bones]


def _switch_holders(arm_obj: bpy.types.Object) -> dict[str, str]:
    """``{ORG bone: pose bone holding IK_FK}`` from the drivers on ORG constraints."""
    out = {}
    anim = arm_obj.animation_data
    for fc in anim.drivers if anim is not None else ():
        path = fc.data_path
        if not path.startswith('pose.bones["ORG-') or ".constraints[" not in path:
            continue
        owner = path[len('pose.bones["'):].split('"]', 1)[0]
        for var in fc.driver.variables:
            target = var.targets[0].data_path if len(var.targets) else ""
            if target.startswith('pose.bones["') and target.endswith(f'["{IK_FK}"]'):
                out[owner] = target[len('pose.bones["'):].split('"]', 1)[0]
    return out


def _spanning_control(arm_obj, org: bpy.types.Bone, tol: float) -> tuple[str, list[str]]:
    """A control spanning ``org`` and the single-child chain of ``ORG-`` bones below it.

    Returns:
        The control from ``org``'s head to the tail of ``org`` or of a bone of that
        chain, and the bones it spans; ``("", [])`` if there is none.
    """
    chain = [org]
    while True:
        kids = [c for c in chain[-1].children if c.name.startswith("ORG-")]
        if len(kids) != 1 or (kids[0].head_local - chain[-1].tail_local).length > tol:
            break
        chain.append(kids[0])
    for bone in arm_obj.data.bones:
        if not _is_control(bone.name) or (bone.head_local - org.head_local).length > tol:
            continue
        for k in range(len(chain), 0, -1):
            if (bone.tail_local - chain[k - 1].tail_local).length < tol:
                return bone.name, [b.name for b in chain[:k]]
    return "", []


def _fk_name(base: str) -> str:
    """``spine.002`` -> ``spine_fk.002``; ``upper_arm.L`` -> ``upper_arm_fk.L``."""
    stem, dot, rest = base.partition(".")
    return f"{stem}_fk{dot}{rest}"


def rigify_map(arm_obj: bpy.types.Object) -> RigifyMap | None:
    """The reading bones and controls of a generated Rigify rig, or None for other rigs.

    Args:
        arm_obj: An armature object.

    Returns:
        The map (see the module docstring), bones in Blender's order; None when the
        armature is not a generated Rigify rig.
    """
    if not is_rigify(arm_obj):
        return None
    from .controls import rig_size

    bones, pbs = arm_obj.data.bones, arm_obj.pose.bones
    tol = 1e-4 * rig_size(arm_obj)
    holders = _switch_holders(arm_obj)
    reading: dict[str, str] = {}  # ORG bone -> reading bone
    controls: dict[str, str] = {}
    absorbed: set[str] = set()
    for org in (b for b in bones if b.name.startswith("ORG-")):
        if org.name in absorbed:
            continue
        base = org.name[4:]
        sources = _copy_sources(pbs[org.name])
        deform = bones.get(f"DEF-{base}")
        same = deform is not None and _same_rest(deform, org, tol)
        exact = _exact_source(pbs[org.name], holders)
        if exact and exact not in controls.values():  # FK limbs, shoulders, the head
            # The ORG- bone is the control's exact copy (a DEF- foot stretches to the
            # toe, which can twist it; a heel hangs from the ORG- foot).
            reading[org.name], controls[org.name] = org.name, exact
            continue
        span, covered = _spanning_control(arm_obj, org, tol) if sources else ("", [])
        if span and span not in controls.values():  # bones under one control: the neck
            for name in covered:
                reading[name] = span
            absorbed.update(covered)
            controls[span] = span
            continue
        read = deform.name if same else org.name  # the spine; unconstrained bones
        reading[org.name] = read
        if _fk_name(base) in pbs and _fk_name(base) not in controls.values():
            controls[read] = _fk_name(base)
        elif not pbs[read].constraints and not sources:  # pelvis sides: their own keys
            controls[read] = read
    return _assemble(arm_obj, reading, controls, holders, tol)


def _assemble(arm_obj, reading: dict[str, str], controls: dict[str, str],
              holders: dict[str, str], tol: float) -> RigifyMap:
    """The map from the ORG -> reading assignment: parents, deform flags, groups."""
    bones = arm_obj.data.bones
    names = tuple(dict.fromkeys(reading.values()))
    position = {n: i for i, n in enumerate(names)}
    orgs_of: dict[str, list[str]] = {}
    for org, read in reading.items():
        orgs_of.setdefault(read, []).append(org)
    groups = _deform_groups(bones, reading)
    owner = {**groups, **reading, **{n: n for n in names}}  # any bone -> its reading bone
    parents = np.full(len(names), -1)
    for i, name in enumerate(names):
        first = bones[orgs_of[name][0]]
        up = first.parent
        while up is not None and owner.get(up.name, name) == name:
            up = up.parent
        if up is not None:  # a palm hangs from the hand's deform bone
            parents[i] = position[owner[up.name]]
            continue
        tails = [o for o, r in reading.items()
                 if r != name and (bones[o].tail_local - first.head_local).length < tol]
        parents[i] = position[reading[tails[0]]] if tails else -1
    deform = np.zeros(len(names), bool)
    deform[[position[r] for r in groups.values()]] = True
    switches = {reading[o]: h for o, h in holders.items() if o in reading}
    pbs = arm_obj.pose.bones
    partial = frozenset(r for o, r in reading.items() if r not in controls
                        and any(c.type in ("COPY_TRANSFORMS", "COPY_ROTATION")
                                and c.influence > 0.0 for c in pbs[o].constraints))
    return RigifyMap(names, parents, deform, controls, switches, groups,
                     _axis_only(arm_obj, names, controls), dict(reading), partial)


def _deform_groups(bones, reading: dict[str, str]) -> dict[str, str]:
    """``{DEF- bone: reading bone}`` for the deforming ``DEF-`` bones.

    Split segments (``DEF-upper_arm.L.001``) go with the bone they split.
    """
    groups = {}
    for b in bones:
        if b.name.startswith("DEF-") and b.use_deform:
            base = b.name[4:]
            org = f"ORG-{base}"
            while org not in reading and "." in base:  # a split segment: upper_arm.L.001
                base = base.rsplit(".", 1)[0]
                org = f"ORG-{base}"
            if org in reading:
                groups[b.name] = reading[org]
    return groups


def _axis_only(arm_obj, names: tuple[str, ...], controls: dict[str, str]) -> frozenset:
    """The reading bones whose twist their control does not set (see ``RigifyMap``).

    A bone that stretches to the next takes its twist from the bone it copies; following
    that bone's parents (and, from an ``ORG-`` bone, the control it copies) up to the
    first control tells whether its own control sets the twist, unless a bone on the
    way blends in another (the spine's ``MCH-pivot``).
    """
    out = set()
    pbs = arm_obj.pose.bones
    for name in names:
        pb = pbs[name]
        sources = _copy_sources(pb)
        if not sources or not any(c.type == "STRETCH_TO" for c in pb.constraints):
            continue
        bone, mixed = arm_obj.data.bones[sources[0]], False
        while bone is not None and not _is_control(bone.name):
            copied = _copy_sources(pbs[bone.name]) if bone.name.startswith("ORG-") else []
            mixed |= not copied and len(pbs[bone.name].constraints) > 0  # a blend
            bone = arm_obj.data.bones[copied[0]] if copied else bone.parent
        if mixed or bone is None or bone.name != controls.get(name):
            out.add(name)
    return frozenset(out)


def _rigid(matrix: np.ndarray) -> np.ndarray:
    """A pose or rest matrix without its scale (columns normalized), ``(..., 4, 4)``."""
    out = np.array(matrix, dtype=float)
    out[..., :3, :3] /= np.linalg.norm(out[..., :3, :3], axis=-2, keepdims=True)
    return out


def reading_pose(arm_obj: bpy.types.Object, names: tuple[str, ...], parents: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations and translations of the reading bones as Blender evaluates them.

    With the rigid rest matrices ``B`` and evaluated pose matrices ``P`` (armature
    space, scale dropped), the local transform in the core's recursion
    ``P_i = P_p B_p^-1 B_i M_i`` is ``M_i = B_i^-1 B_p P_p^-1 P_i``.

    Args:
        arm_obj: The rig (its evaluation current).
        names: Reading bones, parents first.
        parents: Their reading parents, shape ``(n,)``.

    Returns:
        ``(rotations (n, 3, 3), translations (n, 3))``, translations in armature units.
    """
    rest = _rigid(np.array([np.array(arm_obj.data.bones[n].matrix_local) for n in names]))
    posed = _rigid(np.array([np.array(arm_obj.pose.bones[n].matrix) for n in names]))
    local = np.empty_like(posed)
    for i, p in enumerate(parents):
        if p < 0:
            local[i] = np.linalg.inv(rest[i]) @ posed[i]
        else:
            local[i] = (np.linalg.inv(rest[i]) @ rest[p] @ np.linalg.inv(posed[p])
                        @ posed[i])
    return local[:, :3, :3], local[:, :3, 3]


#: Largest angle (degrees) between a reading bone's evaluated and solved rotation.
ROTATION_TOLERANCE = 0.05
#: Passes over the controls (each turns every control by what its bone still needs).
PASSES = 6


def _top_control(arm_obj: bpy.types.Object, name: str) -> str:
    """The highest control above ``name`` (the torso over the spine's FK controls)."""
    top, bone = name, arm_obj.data.bones[name].parent
    while bone is not None:
        if _is_control(bone.name) and bone.parent is not None:
            top = bone.name
        bone = bone.parent
    return top


def _following(arm_obj: bpy.types.Object, data) -> set[str]:
    """The reading bones that follow the rig, neither written nor compared.

    The limbs left in IK, with the bones below them, follow their IK controls (a
    planted foot stays planted when the hips turn); bones that copy a control part-way
    (palms between the hand and the palm control) follow both; bones that are their own
    control and locked on every axis (Rigify locks its heels and pelvis sides) follow
    theirs.
    """
    rig: RigifyMap = data.rigify
    names, parents = data.skeleton.names, data.skeleton.parents
    out = {n for n, h in rig.switches.items()
           if float(arm_obj.pose.bones[h].get(IK_FK, 1.0)) < 1.0}
    out |= rig.partial
    for i, name in enumerate(names):  # parents first: the bones below them
        if parents[i] >= 0 and names[parents[i]] in out:
            out.add(name)
    # A locked bone turns with its parent as the solvers turn it: the bones below it
    # are posed as usual.
    return out | {n for n in names if rig.controls.get(n) == n
                  and all(arm_obj.pose.bones[n].lock_rotation)}


def switching(arm_obj: bpy.types.Object, data, changed: list[str]) -> list[str]:
    """The ``IK_FK`` holders a write of ``changed`` switches from IK to FK."""
    return [h for h in _limbs_of(data, changed)
            if float(arm_obj.pose.bones[h].get(IK_FK, 1.0)) < 1.0]


def _limbs_of(data, changed: list[str]) -> list[str]:
    """The ``IK_FK`` holders of the limbs holding a changed bone or a bone above it.

    A finger below a hand in IK is posed from where the IK puts the hand only once the
    arm is in FK (the solved pose places it from the hand the solver saw).
    """
    rig: RigifyMap = data.rigify
    names, parents = data.skeleton.names, data.skeleton.parents
    out = []
    for name in changed:
        i = data.skeleton.index(name)
        while i >= 0:
            holder = rig.switches.get(names[i])
            if holder is not None and holder not in out:
                out.append(holder)
            i = parents[i]
    return out


def pose_rig(arm_obj: bpy.types.Object, data, pose, changed: list[str],
             switch: list[str]) -> dict[str, list[str]]:
    """Pose a generated Rigify rig's reading bones through its controls.

    Every reading bone with a control is brought to its solved rotation (those the
    write leaves alone to the rotation they have: a spine control also carries bones
    below it), the root's head to its solved place through the highest control above
    it (the torso); limbs in IK holding a ``changed`` bone, or one above a changed bone
    (a hand above a finger), are switched to FK first, and limbs left in IK (with the
    bones below them) follow their IK controls (a planted foot stays planted when the
    hips turn). The caller restores the channels on an error.

    Args:
        arm_obj: The rig.
        data: Its :class:`~.read_armature.ArmatureData` (``data.rigify`` set).
        pose: The solved pose of the reading bones.
        changed: Reading bones whose rotation the write changes.
        switch: The ``IK_FK`` holders to switch to FK (:func:`switching` of
            ``changed``).

    Returns:
        ``{control: channels written}``.

    Raises:
        InputError: A changed bone has no control, or Blender's evaluation does not
            give the solved pose back.
    """
    from ..core.exceptions import InputError
    from ..core.rotations import rotation_between
    from .controls import (
        HEAD_TOLERANCE,
        _angle,
        _evaluated,
        _set_pose_matrix,
        _Solved,
        rig_size,
    )

    rig: RigifyMap = data.rigify
    locked = [n for n in changed if rig.controls.get(n, n) == n
              and all(arm_obj.pose.bones[n].lock_rotation)]
    if locked:
        raise InputError(f"Nothing was written: the pose turns {locked[:5]}, locked in the "
                         f"Rigify rig '{arm_obj.name}' (Rigify locks its DEF- and ORG- "
                         "bones): pose a chain of bones with controls, or unlock them.")
    bare = [n for n in changed if n not in rig.controls]
    if bare:
        raise InputError(f"Nothing was written: {bare[:5]} of the Rigify rig "
                         f"'{arm_obj.name}' have no control that poses them; put them in "
                         "the 'Pinned' bone collection (or lock their rotation) to pose "
                         "the rest.")
    written: dict[str, list[str]] = {}

    def note(name, channels):
        have = written.setdefault(name, [])
        have.extend(c for c in channels if c not in have)

    for holder in switch:
        # Rigify's own IK -> FK snap first: the FK controls take the limb as its IK
        # shows it, stretch included (the IK stretches or squashes the chain).
        limb = [n for n in data.skeleton.names if rig.switches.get(n) == holder]
        shown = {n: _evaluated(arm_obj, n) for n in limb}
        arm_obj.pose.bones[holder][IK_FK] = 1.0
        arm_obj.update_tag()
        bpy.context.view_layer.update()
        for name in limb:  # parents first
            note(rig.controls[name], _set_pose_matrix(arm_obj, rig.controls[name],
                                                      shown[name], True, True, True))
    arm_obj.update_tag()
    bpy.context.view_layer.update()
    solved = _Solved(arm_obj, data, pose)

    names = data.skeleton.names
    root = names[0]
    top = _top_control(arm_obj, rig.controls.get(root, root))

    def carry() -> bool:  # the figure's root to its place: the highest control moves it
        gap = solved.head(root) - _evaluated(arm_obj, root)[:3, 3]
        if np.linalg.norm(gap) <= 1e-6:
            return False
        matrix = _evaluated(arm_obj, top)
        matrix[:3, 3] += gap
        note(top, _set_pose_matrix(arm_obj, top, matrix, False, True))
        return True

    depth = {n: len(arm_obj.data.bones[c].parent_recursive) for n, c in rig.controls.items()}
    following = _following(arm_obj, data)
    order = sorted((n for n in names if n in rig.controls and n not in following),
                   key=lambda n: (depth[n], names.index(n)))
    for _ in range(PASSES):
        turned = False
        for name in order:
            got = _evaluated(arm_obj, name)
            axis = name in rig.axis_only
            if _angle(got, solved.rotation(name), axis) <= ROTATION_TOLERANCE / 4:
                continue
            current = got[:3, :3] / np.linalg.norm(got[:3, :3], axis=0)
            delta = (rotation_between(current[:, 1], solved.rotation(name)[:, 1]) if axis
                     else solved.rotation(name) @ current.T)
            control = rig.controls[name]
            matrix = _evaluated(arm_obj, control)
            matrix[:3, :3] = delta @ matrix[:3, :3]
            note(control, _set_pose_matrix(arm_obj, control, matrix, True, False))
            turned = True
        turned = carry() or turned  # the spine's controls turn about its middle
        if not turned:
            break
    size = rig_size(arm_obj)
    for name in (n for n in names if n not in following):
        got = _evaluated(arm_obj, name)
        angle = _angle(got, solved.rotation(name), name in rig.axis_only)
        off = float(np.linalg.norm(got[:3, 3] - solved.head(name)))
        if angle > ROTATION_TOLERANCE or off > HEAD_TOLERANCE * size:
            raise InputError(
                f"'{name}' of the Rigify rig '{arm_obj.name}' could not be posed through "
                f"its control '{rig.controls.get(name, name)}': Blender evaluates it "
                f"{angle:.2f} degrees and {100 * off / size:.2f}% of the rig's size from "
                "the solved pose. Nothing was written.")
    return {n: c for n, c in written.items() if c}
