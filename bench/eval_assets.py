"""The ``../shared/eval-assets`` files the benchmarks read (skipped when absent).

Not a benchmark itself (``bench/run.py`` runs only ``bench_*.py``).

The Adventurer's 40 CMU poses are corrected on loading (``correct_zero_length_torso``):
the asset aims its ``Torso`` bone along the BVH segment ``Spine1 -> Neck``, which in the
files with MotionBuilder joint names (clips 01, 08, 09, 49, 55; 26 of the 40) has zero
length (``Neck`` sits on ``Spine1``), so those torsos point along rounding noise. There the
``Torso`` is re-aimed along ``Spine1 -> Neck1``, the mocap's upper trunk.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from gesture_pose.core.rotations import exp_map, matrix_to_quat, orthonormalize, rotation_between

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "eval-assets"
ADVENTURER = ASSETS / "humanoid_quaternius_adventurer" / "Adventurer_cmu40poses.glb"
MOCAP = ASSETS / "mocap_cmu_poses"
#: Characters with their own animation clips (no CMU poses), by name.
CLIP_RIGS = {
    "Wizard": ASSETS / "humanoid_quaternius_wizard" / "Wizard.glb",
    "Robot": ASSETS / "humanoid_quaternius_robot" / "robot.glb",
    "raylib girl": ASSETS / "humanoid_girl_raylib" / "girl.glb",
}

#: The bone the asset aims along a zero-length segment, and the mapped bone whose first
#: joint ends the real segment (the bone map's ``Neck`` starts at ``Neck1``).
_TORSO, _NECK = "Torso", "Neck"
#: A segment shorter than this fraction of the mocap's hips-to-head distance is degenerate
#: (the zero offsets are 1e-6 units against about 10 for the trunk).
_DEGENERATE = 1e-3


def bvh_joint_positions(text: str) -> dict[str, np.ndarray]:
    """World positions of a BVH file's joints in its first motion frame.

    Each joint's local transform is its ``OFFSET`` (replaced component-wise by its position
    channels, if any) and its rotation channels composed in the declared order, in degrees
    (``R = R_first @ R_second @ R_third`` on column vectors): the convention of Blender's
    BVH importer, whose joint heads this matches to 1e-5 units on the CMU pose files.

    Args:
        text: The BVH file's text.

    Returns:
        ``{joint name: (3,) position in the BVH's units and axes}``; an ``End Site`` is named
        ``"<its joint>_end"``.
    """
    tokens = text.split()
    joints: list[tuple[str, int, np.ndarray, list[str]]] = []
    stack: list[int] = []
    name = ""
    i = 0
    while tokens[i] != "MOTION":
        tok = tokens[i]
        if tok in ("ROOT", "JOINT"):
            name, i = tokens[i + 1], i + 2
        elif tok == "End":
            name, i = joints[stack[-1]][0] + "_end", i + 2
        elif tok == "{":
            joints.append((name, stack[-1] if stack else -1, np.zeros(3), []))
            stack.append(len(joints) - 1)
            i += 1
        elif tok == "}":
            stack.pop()
            i += 1
        elif tok == "OFFSET":
            joints[stack[-1]][2][:] = [float(x) for x in tokens[i + 1:i + 4]]
            i += 4
        elif tok == "CHANNELS":
            n = int(tokens[i + 1])
            joints[stack[-1]][3].extend(tokens[i + 2:i + 2 + n])
            i += 2 + n
        else:
            i += 1
    # MOTION Frames: n Frame Time: t, then the first frame's values.
    values = iter(float(x) for x in tokens[i + 6:])
    positions: list[np.ndarray] = []
    rotations: list[np.ndarray] = []
    out = {}
    for name, parent, offset, channels in joints:
        t, r = offset.copy(), np.eye(3)
        for ch in channels:
            axis = "XYZ".index(ch[0].upper())
            v = next(values)
            if ch.lower().endswith("position"):
                t[axis] = v
            else:
                r = r @ exp_map(np.radians(v) * np.eye(3)[axis])
        if parent >= 0:
            t, r = positions[parent] + rotations[parent] @ t, rotations[parent] @ r
        positions.append(t)
        rotations.append(r)
        out[name] = t
    return out


def kabsch_rotation(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The rotation best taking directions ``src`` onto ``dst`` (least squares, Kabsch).

    Args:
        src: Unit directions, shape ``(n, 3)``.
        dst: Unit directions, shape ``(n, 3)``.

    Returns:
        The proper rotation ``R`` minimising ``sum |R src_i - dst_i|^2``, shape ``(3, 3)``:
        the rotation nearest ``sum dst_i src_i^T`` (``orthonormalize``).
    """
    return orthonormalize(np.asarray(dst, float).T @ np.asarray(src, float))


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two vectors ``(3,)``, degrees (``atan2``: exact near 0 and 180)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b))))


def _joint(joints: dict[str, np.ndarray], name: str, aliases: dict[str, str]) -> np.ndarray:
    """A bone-map joint in a BVH, through the map's 3ds Max aliases.

    Args:
        joints: ``bvh_joint_positions`` of the file.
        name: The map's (MotionBuilder) joint name; ``"X_end(tail)"`` is ``X``'s end site.
        aliases: The map's ``cmu_3dsmax_aliases`` (left side; the right likewise).

    Returns:
        The joint's position, ``(3,)``.
    """
    name = name.removesuffix("(tail)")
    if name in joints:
        return joints[name]
    if name.startswith("Right"):
        left = aliases.get("Left" + name[len("Right"):], "")
        alias = ("Right" + left[len("Left"):] if left.startswith("Left")
                 else "R" + left[1:] if left else "")
    else:
        alias = aliases.get(name, "")
    if alias in joints:
        return joints[alias]
    raise KeyError(f"joint {name!r} not in the BVH")


def correct_zero_length_torso(scene, arm) -> list[dict]:
    """Re-aim the ``Torso`` of the poses whose BVH ``Spine1 -> Neck`` has zero length.

    For each frame ``k`` (CMU pose ``k - 1`` of ``poses.json``) the rotation from the BVH's
    world to the armature's space is fitted (``kabsch_rotation``) on the directions of the
    mapped bones other than ``Torso``: each bone's Y axis against its BVH segment, what the
    asset's retargeting aimed (the fit's residual is below 0.001 degree on all 40 poses,
    and on the 14 with a real ``Torso`` segment the asset's ``Torso`` lies on the fitted
    segment as closely). Where the ``Torso``'s segment is degenerate, it turns by
    the smallest rotation onto the fitted image of ``Spine1 -> Neck1`` (the first joint of
    the map's ``Neck`` bone); the mapped bones keep their orientations in the armature's
    space and the unmapped ones (``Chest``, the shoulders) their local rotations, so they
    follow the ``Torso``. The changed rotations are written into the action's keyframes, so
    ``scene.frame_set(k)`` gives the corrected pose. Other frames are left bit-identical.

    Args:
        scene: The scene holding the Adventurer.
        arm: The armature object, its action ``cmu_poses`` assigned.

    Returns:
        One dict per frame: ``frame``, ``file``, ``fit_residual_deg`` (largest angle between
        a mapped bone and its fitted BVH segment), ``torso_deg`` (the asset's ``Torso``
        against its fitted segment: the check on poses left as they are), ``corrected``
        and ``torso_turn_deg``.
        Empty (and a note on stderr) when the BVH files are absent.
    """
    import bpy
    from bpy_extras.anim_utils import action_get_channelbag_for_slot

    if not (MOCAP / "poses.json").exists():
        print(f"eval_assets: {MOCAP} absent, the Adventurer's poses are not corrected",
              file=sys.stderr)
        return []
    bonemap = json.loads((MOCAP / "bonemap_cmu_to_quaternius.json").read_text())
    pairs, aliases = bonemap["map"], bonemap["cmu_3dsmax_aliases"]
    poses = json.loads((MOCAP / "poses.json").read_text())
    anim = arm.animation_data
    fcurves = action_get_channelbag_for_slot(anim.action, anim.action_slot).fcurves
    bones = arm.pose.bones
    mapped = [b for b in pairs if b != _TORSO]
    current = scene.frame_current
    report = []
    for k, pose in enumerate(poses, start=1):
        joints = bvh_joint_positions((MOCAP / pose["file"]).read_text())
        scene.frame_set(k)
        world = {b.name: np.array(b.matrix) for b in bones}  # armature space, (4, 4)
        seg = {b: _joint(joints, pairs[b][1], aliases) - _joint(joints, pairs[b][0], aliases)
               for b in pairs}
        src = np.array([seg[b] / np.linalg.norm(seg[b]) for b in mapped])
        dst = np.array([world[b][:3, 1] / np.linalg.norm(world[b][:3, 1]) for b in mapped])
        rot = kabsch_rotation(src, dst)
        row = {"frame": k, "file": pose["file"],
               "fit_residual_deg": max(_angle(rot @ s, d) for s, d in zip(src, dst, strict=True)),
               "torso_deg": _angle(rot @ seg[_TORSO], world[_TORSO][:3, 1]),
               "corrected": False, "torso_turn_deg": 0.0}
        report.append(row)
        span = np.linalg.norm(_joint(joints, "Head", aliases) - _joint(joints, "Hips", aliases))
        if np.linalg.norm(seg[_TORSO]) >= _DEGENERATE * span:
            continue
        real = _joint(joints, pairs[_NECK][0], aliases) - _joint(joints, pairs[_TORSO][0],
                                                                  aliases)
        turn = rotation_between(world[_TORSO][:3, 1], rot @ real)
        row["corrected"], row["torso_turn_deg"] = True, _angle(world[_TORSO][:3, 1], rot @ real)
        # New armature-space rotations of the Torso's subtree: the Torso turned, mapped bones
        # as they were, unmapped ones rigid on their parent. ``turned``: the bones turning
        # with the Torso; a mapped bone on one of them gets a new local rotation (a key).
        new = {_TORSO: turn @ world[_TORSO][:3, :3]}
        keys, turned = {_TORSO: new[_TORSO]}, {_TORSO}
        queue = list(bones[_TORSO].children)
        while queue:  # parents before children
            b = queue.pop(0)
            queue.extend(b.children)
            par = b.parent.name
            if b.name in pairs:
                new[b.name] = world[b.name][:3, :3]
                if par in turned:
                    keys[b.name] = new[b.name]
            else:
                new[b.name] = new[par] @ world[par][:3, :3].T @ world[b.name][:3, :3]
                if par in turned:
                    turned.add(b.name)
        for name, target in keys.items():
            b = bones[name]
            rest = np.array(b.bone.matrix_local)[:3, :3]
            rest_rel = np.array(b.parent.bone.matrix_local)[:3, :3].T @ rest
            parent = new.get(b.parent.name, world[b.parent.name][:3, :3])
            basis = rest_rel.T @ parent.T @ target
            _write_quaternion(fcurves, name, k, basis)
    scene.frame_set(current)
    bpy.context.view_layer.update()
    return report


def _write_quaternion(fcurves, bone: str, frame: int, basis: np.ndarray) -> None:
    """Overwrite a bone's rotation-quaternion keys at a frame (same hemisphere as before).

    Args:
        fcurves: The action's F-curves for the armature.
        bone: Pose bone name.
        frame: The keyed frame.
        basis: The bone's new local rotation, ``(3, 3)``.
    """
    path = f'pose.bones["{bone}"].rotation_quaternion'
    curves = [fcurves.find(path, index=i) for i in range(4)]
    points = [next(p for p in c.keyframe_points if p.co[0] == frame) for c in curves]
    q = matrix_to_quat(basis)
    if float(np.dot(q, [p.co[1] for p in points])) < 0.0:
        q = -q
    for c, p, v in zip(curves, points, q, strict=True):
        for attr in ("co", "handle_left", "handle_right"):
            getattr(p, attr)[1] = float(v)
        c.update()


def load_adventurer(corrected: bool = True):
    """Open the Adventurer (40 CMU poses on frames 1-40) in an empty scene.

    Args:
        corrected: Re-aim the torsos the asset aimed along zero-length BVH segments
            (``correct_zero_length_torso``; skipped when the BVH files are absent).

    Returns:
        ``(scene, armature object, its ArmatureData read in the rest position, the meshes
        it deforms)``; the armature is left in the pose position, last evaluated in the
        rest one (the meshes are at rest until a frame is set). Its bones have token
        lengths, so the ArmatureData is the joint skeleton (``core/joint_skeleton.py``):
        each bone from its head to its principal child's head, the pose in those frames.
    """
    import bpy

    from gesture_pose.blender.read_armature import read_armature

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=str(ADVENTURER))
    scene = bpy.context.scene
    arm = next(o for o in scene.objects if o.type == "ARMATURE")
    if corrected:
        correct_zero_length_torso(scene, arm)
    # Last evaluated in the rest position: the benches frame their cameras on the meshes as
    # they are on return.
    arm.data.pose_position = "REST"
    bpy.context.view_layer.update()
    rest = read_armature(arm)
    arm.data.pose_position = "POSE"
    meshes = [o for o in scene.objects if o.type == "MESH" and o.find_armature() == arm]
    return scene, arm, rest, meshes


def _framed_contours(scene, md, direction) -> tuple:
    """A camera framed on the posed character and its traced contours.

    The camera (800x800 pixels, margin 1.4) frames the skinned meshes ``md`` as posed;
    its object is removed once read (the core camera stands alone).

    Args:
        scene: The scene.
        md: The posed character's ``SkinnedMeshes``.
        direction: From the character towards the camera, ``(3,)``.

    Returns:
        ``(Camera, TracedContours)``.
    """
    import bpy

    from gesture_pose.blender.read_view import camera_from_object
    from gesture_pose.core.gesture.trace import trace_contours
    from sample_scenes import builders

    cam = builders.add_camera(md.deformed_vertices, direction=direction,
                              resolution=(800, 800), margin=1.4, name="Framed camera")
    camera = camera_from_object(cam, scene)
    cam_data = cam.data
    bpy.data.objects.remove(cam)
    bpy.data.cameras.remove(cam_data)
    return camera, trace_contours(md.deformed_vertices, md.triangles, camera)


def posed_drawings(scene, arm, frames, direction) -> list:
    """Each frame's pose read back, its skinned meshes, a camera framed on it, its contours.

    Each pose is seen through its own camera, framed on the posed character (its deformed
    mesh, margin 1.4, 800x800 pixels): the CMU poses move and turn the body, and a camera
    framed on the rest pose cut off feet and raised hands. The camera object is removed
    once read (the core camera stands alone).

    Args:
        scene: The scene.
        arm: The armature object, in the pose position.
        frames: Frames to read (frame k = CMU pose k).
        direction: From the character towards the camera, ``(3,)``.

    Returns:
        ``[(frame, ArmatureData, SkinnedMeshes, Camera, TracedContours)]``.
    """
    import bpy

    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.blender.read_mesh import read_skinned_meshes

    out = []
    for k in frames:
        scene.frame_set(k)
        bpy.context.view_layer.update()
        data = read_armature(arm)
        md = read_skinned_meshes(arm, data.skeleton)
        out.append((k, data, md, *_framed_contours(scene, md, direction)))
    return out


def load_rig(path: Path):
    """Open a glTF character in an empty scene; ``(scene, armature object)``.

    The armature is left without an action (its bind pose).
    """
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=str(path))
    scene = bpy.context.scene
    arm = next(o for o in scene.objects if o.type == "ARMATURE")
    if arm.animation_data is not None:
        arm.animation_data.action = None
    return scene, arm


def clip_drawings(scene, arm, direction, skip: tuple[str, ...] = ("Idle",)) -> list:
    """The middle frame of each of the armature's clips, traced; the armature left at rest.

    Each clip (action) whose name contains none of ``skip`` is assigned in turn, its
    middle frame read, and the posed character traced through a camera framed on it (as
    :func:`posed_drawings`).

    Args:
        scene: The scene.
        arm: The armature object.
        direction: From the character towards the camera, ``(3,)``.
        skip: Parts of the names of clips left out (idle loops stay near the bind pose).

    Returns:
        ``[(label "clip@frame", ArmatureData, Camera, TracedContours)]``, by clip name.
    """
    import bpy

    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.blender.read_mesh import read_skinned_meshes

    anim = arm.animation_data or arm.animation_data_create()
    out = []
    for action in sorted(bpy.data.actions, key=lambda a: a.name):
        if any(word in action.name for word in skip):
            continue
        anim.action = action
        if anim.action_slot is None and len(action.slots):
            anim.action_slot = action.slots[0]
        start, end = action.frame_range
        k = int(round(0.5 * (start + end)))
        scene.frame_set(k)
        bpy.context.view_layer.update()
        data = read_armature(arm)
        md = read_skinned_meshes(arm, data.skeleton)
        label = action.name.rpartition("|")[2]
        out.append((f"{label}@{k}", data, *_framed_contours(scene, md, direction)))
    anim.action = None
    return out
