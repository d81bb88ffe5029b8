"""The ``../shared/eval-assets`` files the benchmarks read (skipped when absent).

Not a benchmark itself (``bench/run.py`` runs only ``bench_*.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "eval-assets"
ADVENTURER = ASSETS / "humanoid_quaternius_adventurer" / "Adventurer_cmu40poses.glb"


def load_adventurer():
    """Open the Adventurer (40 CMU poses on frames 1-40) in an empty scene.

    Returns:
        ``(scene, armature object, its ArmatureData read in the rest position, the meshes
        it deforms)``; the armature is left in the pose position. Its bones have token
        lengths, so the ArmatureData is the joint skeleton (``core/joint_skeleton.py``):
        each bone from its head to its principal child's head, the pose in those frames.
    """
    import bpy

    from gesture_pose.blender.read_armature import read_armature

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=str(ADVENTURER))
    scene = bpy.context.scene
    arm = next(o for o in scene.objects if o.type == "ARMATURE")
    arm.data.pose_position = "REST"
    bpy.context.view_layer.update()
    rest = read_armature(arm)
    arm.data.pose_position = "POSE"
    meshes = [o for o in scene.objects if o.type == "MESH" and o.find_armature() == arm]
    return scene, arm, rest, meshes


#: Bones of the Adventurer whose heads are the joints a drawing shows.
MAJOR = ("Hips", "Abdomen", "Torso", "Chest", "Neck", "Head", "UpperLeg.L", "LowerLeg.L",
         "Foot.L", "UpperLeg.R", "LowerLeg.R", "Foot.R", "Shoulder.L", "UpperArm.L",
         "LowerArm.L", "Hand.L", "Shoulder.R", "UpperArm.R", "LowerArm.R", "Hand.R")


def head_skeleton(skeleton, heads_rest: np.ndarray):
    """A skeleton through the heads of the :data:`MAJOR` bones of an imported glTF rig.

    One bone from each major bone's nearest major ancestor's head to its own head: the
    skeleton the benchmarks used before ``read_armature`` read token-bone rigs as joint
    skeletons, kept so that their tables stay comparable (it has no hand, foot or head
    end bones and skips the neck and shoulders). The first of them (the lower spine) is
    the root; the other bones leaving the hips hang off it. ``skeleton`` may be the joint
    skeleton or the raw one: only names, parents and heads are used.

    Returns:
        ``(skeleton, ends)``: the head skeleton and, per bone, the full-skeleton indices of
        its start and end bones, shape ``(m, 2)``.
    """
    from gesture_pose.core.rotations import rotation_between
    from gesture_pose.core.skeleton import Skeleton

    major = [skeleton.index(n) for n in MAJOR]
    anc = {}
    for b in major:
        up = [a for a in skeleton.ancestors(b)[1:] if a in major]
        anc[b] = up[0] if up else -1
    order = [b for b in major if anc[b] >= 0]
    order.sort(key=lambda b: len(skeleton.ancestors(b)))
    seg = {b: k for k, b in enumerate(order)}
    ends = np.array([[anc[b], b] for b in order])
    h, t = heads_rest[ends[:, 0]], heads_rest[ends[:, 1]]
    parents = np.array([seg.get(anc[b], -1) for b in order])
    parents[1:][parents[1:] < 0] = 0
    frames = rotation_between(np.array([0.0, 1.0, 0.0]), t - h)
    n = len(order)
    connected = np.array([p >= 0 and ends[p, 1] == ends[k, 0] for k, p in enumerate(parents)])
    names = tuple(skeleton.names[b] for b in order)
    return Skeleton(names, parents, h, t, frames, np.ones(n, bool), connected,
                    np.ones(n, bool)), ends


def pose_through(skel, ends: np.ndarray, heads_posed: np.ndarray):
    """The pose of a head skeleton whose joints are the given posed heads."""
    from gesture_pose.core.skeleton import Pose

    pose = Pose.identity(skel.n_bones)
    for k in range(skel.n_bones):
        state = skel.forward(pose)
        d = heads_posed[ends[k, 1]] - heads_posed[ends[k, 0]]
        pose = pose.with_rotations(np.array([k]), skel.aim_local(k, d, state,
                                                                  pose.rotations[k])[None])
    return pose
