"""`make demo`: pose the sample humanoid headless and write the results under ``out/``.

Opens ``sample_scenes/humanoid.blend``, renders the character before, runs Pose Stroke on
every example stroke of its "Sketch" object, renders it after, and writes:

- ``out/humanoid_posed.blend``: the posed, keyed scene;
- ``out/line_of_action_before_after.png``: the two renders side by side;
- a summary on stdout (bones posed, distances, timings).
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
    gesture_pose.register()
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


def main() -> None:
    """Run every demo and print what it did."""
    OUT.mkdir(exist_ok=True)
    t0 = time.perf_counter()
    line_of_action_demo()
    print(f"Demo finished in {time.perf_counter() - t0:.1f} s; results in {OUT}/")


if __name__ == "__main__":
    main()
