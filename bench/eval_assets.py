"""The ``../shared/eval-assets`` files the benchmarks read (skipped when absent).

Not a benchmark itself (``bench/run.py`` runs only ``bench_*.py``).
"""

from __future__ import annotations

from pathlib import Path

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
