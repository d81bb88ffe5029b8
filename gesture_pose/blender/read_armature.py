"""Read an armature object into a core :class:`Skeleton` and :class:`Pose`, in bulk.

Blender's pose recursion in armature space is
``P_i = P_p B_p^-1 B_i M_i`` with ``B`` the bones' rest matrices (``bone.matrix_local``) and
``M`` the local transforms (``pose_bone.matrix_basis``). With the object's world matrix
``W = [s R_o | T]`` (uniform scale ``s`` only) the world rest frames are ``R_i = R_o B_i``,
the world rest heads ``r_i = W b_i`` and the local translations ``t_i = s m_i``; the core's
``Skeleton.forward`` then reproduces ``W P_i`` exactly (see ``core/skeleton.py``).

Imported rigs whose bones have token lengths (glTF has no tails; see
``core/joint_skeleton.py``) are read as their joint skeleton: each bone from its head to
its principal child's head, rest frames ``R_i C_i``, and the pose conjugated into those
frames (``Q' = C^T Q C``). ``ArmatureData.frame_change`` holds ``C`` so that
``write_pose`` writes the real bones' local rotations back.
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ..core.exceptions import InputError
from ..core.joint_skeleton import (
    has_token_bones,
    joint_skeleton,
    remap_axis_settings,
    to_joint_pose,
)
from ..core.rotations import orthonormalize
from ..core.skeleton import Pose, Skeleton
from .rigify import RigifyMap, reading_pose, rigify_map

#: Pose-bone custom property that pins a bone (the solvers leave it alone).
PINNED_PROPERTY = "gesture_pose_pinned"
#: Bone collection whose bones are pinned.
PINNED_COLLECTION = "Pinned"
#: Bone collection that restricts the gesture mode to its bones.
GESTURE_COLLECTION = "Gesture"

_AXES = ("x", "y", "z")


@dataclass(frozen=True)
class ArmatureData:
    """Everything the solvers need from one armature, read once.

    Arrays follow the skeleton's bone order (parents first), not Blender's.

    Attributes:
        object_name: Name of the armature object.
        skeleton: Rest skeleton in world space.
        pose: Current local rotations and translations (world units).
        rotation_modes: Each pose bone's ``rotation_mode`` (``'QUATERNION'``, ``'XYZ'``, ...,
            ``'AXIS_ANGLE'``).
        pinned: Bones the solvers must not rotate, shape ``(n,)`` bool.
        gesture_override: Bones in the "Gesture" bone collection, shape ``(n,)`` bool, or
            None when the armature has no such collection.
        lock_rotation: Per-axis rotation locks (``pose_bone.lock_rotation``), ``(n, 3)`` bool.
        ik_limits: IK limits ``[min, max]`` per local axis x, y, z in radians, ``(n, 3, 2)``;
            NaN where the axis is not limited.
        object_scale: The object's uniform world scale ``s``.
        matrix_world: The object's world matrix, shape ``(4, 4)``.
        frame_change: For a rig read as its joint skeleton (token bones), the constant
            rotations ``C_i`` from each real bone's rest frame to the skeleton's
            (``R'_i = R_i C_i``), ``(n, 3, 3)``; None when the bones are read as they are.
            ``pose`` is then in the joint skeleton's frames (``Q' = C^T Q C``).
        warnings: Notes about the read (e.g. rotation locks that could not be kept).
        rig_lock_rotation: For a rig read as its joint skeleton, its rotation locks on the
            real bones' axes (:meth:`axis_settings`); None otherwise.
        rig_ik_limits: Likewise its IK limits on the real bones' axes.
        rigify: For a generated Rigify rig, how it is read and written (its skeleton is
            then its reading bones, its pose Blender's evaluation; ``rigify.py``); None
            otherwise.
    """

    object_name: str
    skeleton: Skeleton
    pose: Pose
    rotation_modes: tuple[str, ...]
    pinned: np.ndarray
    gesture_override: np.ndarray | None
    lock_rotation: np.ndarray
    ik_limits: np.ndarray
    object_scale: float
    matrix_world: np.ndarray
    frame_change: np.ndarray | None = None
    warnings: tuple[str, ...] = ()
    rig_lock_rotation: np.ndarray | None = None
    rig_ik_limits: np.ndarray | None = None
    rigify: RigifyMap | None = None

    @property
    def roles(self) -> dict[str, str] | None:
        """Humanoid roles the rig gives outright, or None (found by name).

        A Rigify rig's pelvis and head (:attr:`.rigify.RigifyMap.roles`).
        """
        return self.rigify.roles if self.rigify is not None else None

    def axis_settings(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Locks and IK limits with the axes they are about, for solvers that take axes.

        Returns:
            ``(lock (n, 3), ik_limits (n, 3, 2), axes (n, 3, 3) or None)``: on an imported
            rig read as its joint skeleton, the rig's own settings (every bone's, also
            those ``lock_rotation`` drops) with the real bones' axes in the skeleton's
            frames (columns ``C_i^T e_k``); else ``lock_rotation`` and ``ik_limits`` on the
            bones' own axes.
        """
        if self.frame_change is None:
            return self.lock_rotation, self.ik_limits, None
        return (self.rig_lock_rotation, self.rig_ik_limits,
                np.swapaxes(self.frame_change, 1, 2))

    @property
    def names(self) -> tuple[str, ...]:
        """Bone names in skeleton order."""
        return self.skeleton.names


def _bulk(collection, attr: str, width: int, dtype=np.float64) -> np.ndarray:
    """``collection.foreach_get(attr)`` into an array of shape ``(len, width)``."""
    out = np.empty(len(collection) * width, dtype=dtype)
    collection.foreach_get(attr, out)
    return out.reshape(len(collection), width)


def _matrices(collection, attr: str) -> np.ndarray:
    """4x4 matrix property of every item, shape ``(len, 4, 4)`` (row-major, as numpy)."""
    # foreach_get flattens mathutils matrices column by column: transpose back.
    return np.swapaxes(_bulk(collection, attr, 16).reshape(-1, 4, 4), 1, 2)


def object_similarity(matrix_world: np.ndarray, name: str) -> tuple[np.ndarray, float]:
    """Split a world matrix into a rotation and a uniform scale.

    Args:
        matrix_world: Object world matrix, shape ``(4, 4)``.
        name: Object name, for messages.

    Returns:
        ``(R_o, s)``: rotation ``(3, 3)`` and uniform scale.

    Raises:
        InputError: NaN values, non-uniform scale, shear or mirroring.
    """
    if not np.all(np.isfinite(matrix_world)):
        raise InputError(f"'{name}' has a NaN or infinite transform: reset its transform.")
    a = matrix_world[:3, :3]
    norms = np.linalg.norm(a, axis=0)
    s = float(norms.mean())
    if s < 1e-12:
        raise InputError(f"'{name}' has zero scale: set its scale to a positive value.")
    gram = a.T @ a / s**2
    if np.abs(gram - np.eye(3)).max() > 1e-4:
        raise InputError(
            f"'{name}' has a non-uniform scale {np.round(norms, 4).tolist()} (or shear): "
            "apply the scale (Ctrl+A > Scale) or give it the same scale on all axes."
        )
    if np.linalg.det(a) < 0:
        raise InputError(f"'{name}' is mirrored (negative scale): apply or undo the mirroring.")
    return a / s, s


def _parents_first(parent_names: list[str | None], names: list[str]) -> np.ndarray:
    """Permutation putting parents before children (stable by tree depth), shape ``(n,)``."""
    index = {name: i for i, name in enumerate(names)}
    parents = [index[p] if p is not None else -1 for p in parent_names]
    depth = [-1] * len(names)
    for i in range(len(names)):
        path, j = [], i
        while j >= 0 and depth[j] < 0:
            path.append(j)
            j = parents[j]
        d = depth[j] if j >= 0 else -1
        for k in reversed(path):
            d += 1
            depth[k] = d
    return np.argsort(np.asarray(depth), kind="stable")


def _collection_mask(arm, name: str, names: tuple[str, ...]) -> np.ndarray | None:
    """Bones in the bone collection ``name`` (any nesting level), or None if absent."""
    colls = [c for c in arm.collections_all if c.name == name]
    if not colls:
        return None
    members = {b.name for c in colls for b in c.bones}
    return np.array([n in members for n in names], dtype=bool)


def _ik_limits(pose_bones) -> np.ndarray:
    """IK limits of every pose bone, ``(n, 3, 2)`` radians, NaN where unlimited."""
    out = np.full((len(pose_bones), 3, 2), np.nan)
    for k, ax in enumerate(_AXES):
        used = _bulk(pose_bones, f"use_ik_limit_{ax}", 1, bool)[:, 0]
        lo = _bulk(pose_bones, f"ik_min_{ax}", 1)[:, 0]
        hi = _bulk(pose_bones, f"ik_max_{ax}", 1)[:, 0]
        out[used, k, 0], out[used, k, 1] = lo[used], hi[used]
    return out


def read_armature(arm_obj: bpy.types.Object, joints: bool = True) -> ArmatureData:
    """Read the rest skeleton, current pose and per-bone settings of an armature object.

    Args:
        arm_obj: An object of type ``'ARMATURE'``.
        joints: Read a rig whose bones have token lengths (an imported glTF rig) as its
            joint skeleton (see the module docstring); False reads the bones as they are.

    Returns:
        The armature's data, bones ordered parents first.

    Raises:
        InputError: Not an armature, no bones, non-uniform scale, zero-length bones or NaN
            matrices.
    """
    if arm_obj is None or arm_obj.type != "ARMATURE":
        article = "an" if arm_obj is not None and arm_obj.type[0] in "AEIOU" else "a"
        kind = "nothing" if arm_obj is None else f"{article} {arm_obj.type.lower()} object"
        raise InputError(f"Expected an armature object, got {kind}: select the armature.")
    arm = arm_obj.data
    bones, pose_bones = arm.bones, arm_obj.pose.bones
    if len(bones) == 0:
        raise InputError(f"Armature '{arm_obj.name}' has no bones: add bones first.")
    world = np.array(arm_obj.matrix_world, dtype=float)
    rot_o, scale = object_similarity(world, arm_obj.name)

    rigify = rigify_map(arm_obj)
    if rigify is not None:
        return _read_rigify(arm_obj, rigify, world, rot_o, scale)
    blender_names = [b.name for b in bones]
    order = _parents_first([b.parent.name if b.parent else None for b in bones], blender_names)
    names = tuple(blender_names[i] for i in order)
    position = {name: i for i, name in enumerate(names)}
    parents = np.array([position[bones[n].parent.name] if bones[n].parent else -1
                        for n in names], dtype=int)

    heads_w, tails_w, rest_frames = _world_rest(
        arm_obj.name, names, _matrices(bones, "matrix_local")[order],
        _bulk(bones, "head_local", 3)[order], _bulk(bones, "tail_local", 3)[order], world,
        rot_o, ("fix or recreate the affected bones in Edit Mode.",
                "give them a length in Edit Mode."))

    inherit = _bulk(bones, "use_inherit_rotation", 1, bool)[order, 0]
    connected = _bulk(bones, "use_connect", 1, bool)[order, 0]
    deform = _bulk(bones, "use_deform", 1, bool)[order, 0]
    skeleton = Skeleton(names, parents, heads_w, tails_w, rest_frames, inherit, connected,
                        deform)

    pb_index = {pb.name: i for i, pb in enumerate(pose_bones)}
    pb_order = np.array([pb_index[n] for n in names])
    basis = _matrices(pose_bones, "matrix_basis")[pb_order]
    if not np.all(np.isfinite(basis)):
        raise InputError(f"Armature '{arm_obj.name}' has NaN pose values: clear the pose "
                         "(Alt+R, Alt+G) of the affected bones.")
    pose = Pose(orthonormalize(basis[:, :3, :3]), basis[:, :3, 3] * scale)

    ordered_pbs = [pose_bones[n] for n in names]
    modes = tuple(pb.rotation_mode for pb in ordered_pbs)
    pinned = np.array([bool(pb.get(PINNED_PROPERTY, False)) for pb in ordered_pbs], bool)
    pinned_coll = _collection_mask(arm, PINNED_COLLECTION, names)
    if pinned_coll is not None:
        pinned |= pinned_coll
    lock = _bulk(pose_bones, "lock_rotation", 3, bool)[pb_order]
    limits = _ik_limits(pose_bones)[pb_order]
    change, warnings, rig_lock, rig_limits = None, (), None, None
    if joints and has_token_bones(skeleton):
        rig_lock, rig_limits = lock, limits
        skeleton, pose, change, lock, limits, warnings = _as_joints(arm_obj, skeleton, pose,
                                                                    lock, limits)
    return ArmatureData(
        object_name=arm_obj.name,
        skeleton=skeleton,
        pose=pose,
        rotation_modes=modes,
        pinned=pinned,
        gesture_override=_collection_mask(arm, GESTURE_COLLECTION, names),
        lock_rotation=lock,
        ik_limits=limits,
        object_scale=scale,
        matrix_world=world,
        frame_change=change,
        warnings=warnings,
        rig_lock_rotation=rig_lock,
        rig_ik_limits=rig_limits,
    )


def _as_joints(arm_obj: bpy.types.Object, skeleton: Skeleton, pose: Pose, lock: np.ndarray,
               limits: np.ndarray) -> tuple:
    """The joint skeleton of a token-bone rig, with its pose and axis settings.

    End bones follow their skinned mesh (rest vertices and weights read here).

    Returns:
        ``(skeleton, pose, frame_change (n, 3, 3), lock (n, 3), ik_limits (n, 3, 2),
        warnings)``.
    """
    from .read_mesh import rest_skin

    skin = rest_skin(arm_obj, skeleton)
    joint = joint_skeleton(skeleton, *(skin if skin is not None else (None, None)))
    lock, limits, dropped = remap_axis_settings(lock, limits, joint.frame_change)
    warnings = ()
    if dropped.any():
        warnings = (f"Bones {[skeleton.names[i] for i in np.flatnonzero(dropped)][:5]} of "
                    f"'{arm_obj.name}' are read head to child; their rotation locks and IK "
                    "limits do not fall on its axes: Pose (gesture drawings) keeps them, "
                    "the other modes ignore them.",)
    return (joint.skeleton, to_joint_pose(pose, joint.frame_change), joint.frame_change,
            lock, limits, warnings)


def _world_rest(arm_name: str, names, local: np.ndarray, heads: np.ndarray,
                tails: np.ndarray, world: np.ndarray, rot_o: np.ndarray,
                fixes: tuple[str, str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World rest heads, tails and frames of bones, checked.

    Args:
        arm_name: The armature object's name, for messages.
        names: The bones' names.
        local: Their ``matrix_local``, ``(n, 4, 4)``.
        heads: Their rest heads, armature space, ``(n, 3)``.
        tails: Their rest tails, armature space, ``(n, 3)``.
        world: The object's world matrix, ``(4, 4)``.
        rot_o: Its rotation, ``(3, 3)``.
        fixes: What to do about NaN data and about zero-length bones.

    Returns:
        ``(heads (n, 3), tails (n, 3), frames (n, 3, 3))`` in world space.

    Raises:
        InputError: NaN bone data or zero-length bones.
    """
    if not (np.all(np.isfinite(local)) and np.all(np.isfinite(heads))
            and np.all(np.isfinite(tails))):
        raise InputError(f"Armature '{arm_name}' has NaN bone data: {fixes[0]}")
    heads_w = heads @ world[:3, :3].T + world[:3, 3]
    tails_w = tails @ world[:3, :3].T + world[:3, 3]
    short = np.linalg.norm(tails_w - heads_w, axis=1) < 1e-9
    if np.any(short):
        raise InputError(f"Zero-length bones {[names[i] for i in np.flatnonzero(short)]} in "
                         f"'{arm_name}': {fixes[1]}")
    return heads_w, tails_w, rot_o @ orthonormalize(local[:, :3, :3])


def _in_collection(arm_obj: bpy.types.Object, group: str, names: tuple[str, ...],
                     controls: tuple[str, ...]) -> np.ndarray | None:
    """Bones in the bone collection ``group``, themselves or through their control.

    Returns:
        Shape ``(n,)`` bool, or None when the armature has no such collection.
    """
    own = _collection_mask(arm_obj.data, group, names)
    if own is None:
        return None
    return own | _collection_mask(arm_obj.data, group, controls)


def _read_rigify(arm_obj: bpy.types.Object, rigify: RigifyMap, world: np.ndarray,
                 rot_o: np.ndarray, scale: float) -> ArmatureData:
    """A generated Rigify rig read as its reading bones (``rigify.py``).

    The pose is Blender's evaluation of those bones; pins and the Gesture collection are
    read from each bone's control as well as the bone itself (animators pin the
    controls they see), rotation locks from the bones that are their own control; the
    rig's IK limits are its IK chains', not these bones', so none are read.
    """
    names_all = rigify.reading
    parent_names = [names_all[p] if p >= 0 else None for p in rigify.parents]
    order = _parents_first(parent_names, list(names_all))
    names = tuple(names_all[i] for i in order)
    position = {n: i for i, n in enumerate(names)}
    parents = np.array([position[parent_names[i]] if parent_names[i] else -1
                        for i in order], dtype=int)
    bones, pose_bones = arm_obj.data.bones, arm_obj.pose.bones
    again = "generate the Rigify rig again from its metarig."
    heads, tails, frames = _world_rest(
        arm_obj.name, names, np.array([np.array(bones[n].matrix_local) for n in names]),
        np.array([bones[n].head_local for n in names]),
        np.array([bones[n].tail_local for n in names]), world, rot_o, (again, again))
    connected = np.array([p >= 0 and np.allclose(heads[i], tails[p], atol=1e-6)
                          for i, p in enumerate(parents)], bool)
    skeleton = Skeleton(names, parents, heads, tails, frames, np.ones(len(names), bool),
                        connected, rigify.deform[order])
    bpy.context.view_layer.update()
    rotations, translations = reading_pose(arm_obj, names, parents)
    if not (np.all(np.isfinite(rotations)) and np.all(np.isfinite(translations))):
        raise InputError(f"Armature '{arm_obj.name}' has NaN pose values: clear the pose "
                         "(Alt+R, Alt+G) of its controls.")
    pose = Pose(orthonormalize(rotations), translations * scale)
    controls = [rigify.controls.get(n, n) for n in names]
    pinned = np.array([bool(pose_bones[n].get(PINNED_PROPERTY, False)
                            or pose_bones[c].get(PINNED_PROPERTY, False))
                       for n, c in zip(names, controls, strict=True)], bool)
    in_pinned = _in_collection(arm_obj, PINNED_COLLECTION, names, tuple(controls))
    if in_pinned is not None:
        pinned |= in_pinned
    # A control's channels may turn about another parent than the reading bone's (the
    # head's follows the torso): only a bone that is its own control gives the solvers
    # its locks; the write refuses to change a locked control channel.
    lock = np.array([tuple(pose_bones[n].lock_rotation) if c == n else (False,) * 3
                     for n, c in zip(names, controls, strict=True)], bool)
    return ArmatureData(
        object_name=arm_obj.name,
        skeleton=skeleton,
        pose=pose,
        rotation_modes=tuple(pose_bones[c].rotation_mode for c in controls),
        pinned=pinned,
        gesture_override=_in_collection(arm_obj, GESTURE_COLLECTION, names,
                                          tuple(controls)),
        lock_rotation=lock,
        ik_limits=np.full((len(names), 3, 2), np.nan),
        object_scale=scale,
        matrix_world=world,
        rigify=rigify,
    )
