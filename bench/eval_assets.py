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
    from gesture_pose.blender.read_view import camera_from_object
    from gesture_pose.core.gesture.trace import trace_contours
    from sample_scenes import builders

    out = []
    for k in frames:
        scene.frame_set(k)
        bpy.context.view_layer.update()
        data = read_armature(arm)
        md = read_skinned_meshes(arm, data.skeleton)
        cam = builders.add_camera(md.deformed_vertices, direction=direction,
                                  resolution=(800, 800), margin=1.4, name=f"Camera {k}")
        camera = camera_from_object(cam, scene)
        cam_data = cam.data
        bpy.data.objects.remove(cam)
        bpy.data.cameras.remove(cam_data)
        out.append((k, data, md, camera,
                    trace_contours(md.deformed_vertices, md.triangles, camera)))
    return out
