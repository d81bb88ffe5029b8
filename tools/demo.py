"""`make demo`: pose the sample humanoid headless and write the results under ``out/``.

1. Line of action: opens ``sample_scenes/humanoid.blend``, renders the character, runs
   Pose Stroke on every example stroke of its "Sketch" object and renders it again.
2. Gesture drawing: builds the humanoid in code, poses it in a known pose that is not the
   bind pose, traces its visible contours as the drawing, puts the character back in its
   bind pose, runs the whole Pose (2D fit and 3D depth) and measures the 3D error.

Writes ``out/humanoid_posed.blend``, ``out/line_of_action_before_after.png``,
``out/gesture_posed.blend``, ``out/gesture_before_after.png``, and prints what it did.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import bpy  # noqa: E402

import gesture_pose  # noqa: E402
from gesture_pose.blender.read_armature import read_armature  # noqa: E402

OUT = ROOT / "out"
RENDER_PERCENT = 50


def ensure_registered() -> None:
    """Register the extension once per process (registration survives a factory reset)."""
    try:
        bpy.ops.gesture_pose.pose_stroke.get_rna_type()
    except KeyError:
        gesture_pose.register()


def render(path: Path) -> np.ndarray:
    """Render the scene camera with Workbench to ``path``; return RGBA pixels ``(h, w, 4)``."""
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_percentage = RENDER_PERCENT
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(path), check_existing=False)
    w, h = img.size
    px = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)


def save_side_by_side(left: np.ndarray, right: np.ndarray, path: Path) -> None:
    """Write two renders next to each other, with a thin separator, as a PNG."""
    gap = np.ones((left.shape[0], 6, 4), dtype=np.float32)
    both = np.concatenate([left, gap, right], axis=1)
    h, w = both.shape[:2]
    img = bpy.data.images.new("before_after", w, h, alpha=True)
    img.pixels.foreach_set(both.ravel())
    img.filepath_raw = str(path)
    img.file_format = "PNG"
    img.save()
    bpy.data.images.remove(img)


def pose_all_strokes(arm: bpy.types.Object, sketch: bpy.types.Object) -> float:
    """Run Pose Stroke on every stroke; return the wall time in milliseconds."""
    t0 = time.perf_counter()
    with bpy.context.temp_override(active_object=arm, object=arm):
        result = bpy.ops.gesture_pose.pose_stroke(armature=arm.name, sketch=sketch.name,
                                                  all_strokes=True)
    if result != {"FINISHED"}:
        raise SystemExit(f"Pose Stroke did not finish: {result}")
    return (time.perf_counter() - t0) * 1e3


def line_of_action_demo() -> None:
    """Pose the sample humanoid from its example line-of-action strokes."""
    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_scenes" / "humanoid.blend"))
    ensure_registered()
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    sketch = bpy.data.objects["Sketch"]
    before = read_armature(arm).pose.rotations
    img_before = render(OUT / "line_of_action_before.png")
    ms = pose_all_strokes(arm, sketch)
    data = read_armature(arm)
    moved = np.abs(data.pose.rotations - before).max(axis=(1, 2)) > 1e-7
    img_after = render(OUT / "line_of_action_after.png")
    save_side_by_side(img_before, img_after, OUT / "line_of_action_before_after.png")
    bpy.ops.wm.save_as_mainfile(filepath=str(OUT / "humanoid_posed.blend"), copy=True)
    names = [n for n, m in zip(data.names, moved, strict=True) if m]
    print(f"Line of action: posed {len(names)} bones of '{arm.name}' from "
          f"{sum(1 for _ in _strokes(sketch))} strokes in {ms:.1f} ms: {', '.join(names)}")
    print(f"  wrote {OUT / 'humanoid_posed.blend'} and "
          f"{OUT / 'line_of_action_before_after.png'}")


def _strokes(sketch: bpy.types.Object):
    from gesture_pose.blender.read_strokes import read_sketch

    return read_sketch(sketch)


GESTURE_POSE = "kick_right_leg"


def gesture_demo() -> None:
    """Whole Pose from the traced contours of a known pose of the sample humanoid."""
    from gesture_pose.blender.operators.pose_drawing import pose_from_drawing
    from gesture_pose.blender.read_view import camera_from_object
    from gesture_pose.core.gesture.depth.evaluation import joints_of, pose_error
    from sample_scenes import builders

    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    arm, _ = builders.build_humanoid()
    cam_obj = builders.add_camera(arm, resolution=(960, 960))
    builders.add_light()
    camera = camera_from_object(cam_obj, bpy.context.scene)
    bind = read_armature(arm)
    builders.pose_humanoid(arm, GESTURE_POSE)
    bpy.context.view_layer.update()
    truth = read_armature(arm)
    # Drawn a little in front of the character, along the same view rays.
    sketch = builders.sketch_over(arm, truth.skeleton, camera, radius=0.004)
    img_before = render(OUT / "gesture_before.png")
    rep = pose_from_drawing(arm, sketch, camera, insert_keys=True, show_fit=False)
    img_after = render(OUT / "gesture_after.png")
    save_side_by_side(img_before, img_after, OUT / "gesture_before_after.png")
    bpy.ops.wm.save_as_mainfile(filepath=str(OUT / "gesture_posed.blend"), copy=True)
    solving = rep.embedding.solving
    err = pose_error(joints_of(solving, bind.skeleton, truth.pose), rep.result.joints3d,
                     bind.skeleton, camera)
    n_strokes = len(sketch.data.layers["Lines"].frames[0].drawing.strokes)
    print(f"Gesture drawing: traced '{GESTURE_POSE}' into {n_strokes} strokes; Pose keyed "
          f"{len(rep.written)} bones in {rep.seconds:.1f} s (fit {rep.timings['fit']:.1f} s, "
          f"3D {rep.timings['solve3d']:.2f} s), coverage {100 * rep.embedding.coverage:.0f}%")
    print(f"  3D joint error to the known pose: mean {err.mean_error:.1f}% of the height "
          f"(max {err.max_error:.1f}%), depth order right for {100 * err.depth_order:.0f}% "
          "of joint pairs")
    print(f"  wrote {OUT / 'gesture_posed.blend'} and {OUT / 'gesture_before_after.png'}")


def main() -> None:
    """Run every demo and print what it did."""
    OUT.mkdir(exist_ok=True)
    t0 = time.perf_counter()
    line_of_action_demo()
    gesture_demo()
    print(f"Demo finished in {time.perf_counter() - t0:.1f} s; results in {OUT}/")


if __name__ == "__main__":
    main()
