"""The whole gesture Pose on a real imported character (``../shared/eval-assets``).

The Quaternius Adventurer is a glTF import: its bones have token lengths, so the add-on
reads it as its joint skeleton (``gesture_pose/core/joint_skeleton.py``). For a selection
of the 40 CMU poses keyed on it, the posed character's visible contours are traced
(``trace_contours``, as the Gesture3D paper validated itself), the character is put back in
its bind pose, and the Pose operator's function (``pose_from_drawing``: 2D fit, 3D solve,
write) runs on the real armature; the result is read back from Blender.

Metrics, per drawing:

- 2D fit error: mean distance of the fitted joints from the true joints' projections, %
  of their projected height;
- 3D error: mean joint error after aligning the root joint, % of the character's height
  (``core/gesture/depth/evaluation.py``), and the same for leaving the bind pose
  (baseline: what doing nothing scores);
- depth signs: among links whose depth change (tail minus head) is more than a fifth of
  their length in the truth, the share the result turns the same way by more than a tenth;
- coverage of the drawing by the fit, and the seconds of the whole Pose.

Skipped when the eval assets are absent.
"""

from __future__ import annotations

import numpy as np

from bench.eval_assets import ADVENTURER, load_adventurer, posed_drawings

HEADERS = ["frame", "view", "joints", "2D error %h", "3D error %h", "bind pose %h",
           "depth signs ok", "coverage %", "Pose s"]

#: Views, as directions from the character toward the camera (it faces +Y).
VIEWS = {"front": (0.0, 1.0, 0.0), "3/4": (0.6, 1.0, 0.15)}


def _pose_row(arm, camera, view: str, k: int, truth, traced) -> list:
    """Pose the bind-posed character from one traced drawing; one table row."""
    import bpy

    from gesture_pose.blender.operators.fit_drawing import bind_pose
    from gesture_pose.blender.operators.pose_drawing import pose_from_drawing
    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.core.gesture.depth.evaluation import (
        depth_sign_rate,
        joints_of,
        pose_error,
    )
    from sample_scenes import builders

    builders.reset_pose(arm)
    bpy.context.view_layer.update()
    sketch = builders.add_grease_pencil("Sketch", list(traced.world(camera)))
    bind = read_armature(arm)
    rep = pose_from_drawing(arm, sketch, camera, insert_keys=False, show_fit=False)
    bpy.context.view_layer.update()
    bpy.data.objects.remove(sketch)
    solving = rep.embedding.solving
    sk = bind.skeleton
    true3d = joints_of(solving, sk, truth.pose)
    got3d = joints_of(solving, sk, read_armature(arm).pose)
    true2d = camera.project(true3d)
    fit2d = np.linalg.norm(rep.embedding.joints2d - true2d, axis=1).mean()
    err = pose_error(true3d, got3d, sk, camera).mean_error
    still = pose_error(true3d, joints_of(solving, sk, bind_pose(bind)), sk, camera).mean_error
    return [k, view, solving.n_joints, float(100.0 * fit2d / np.ptp(true2d[:, 1])), err, still,
            depth_sign_rate(solving, true3d, got3d, camera), 100.0 * rep.embedding.coverage,
            rep.seconds]


def pose_table(quick: bool) -> tuple[str, list[str], list[list]] | None:
    """The whole Pose on CMU poses of the Adventurer (None without the assets)."""
    if not ADVENTURER.exists():
        return None
    scene, arm, rest, _ = load_adventurer()
    # Every 4th pose from the front, every 8th from three-quarters (about 2 minutes).
    plan = {"front": (1, 21)} if quick else {"front": tuple(range(1, 41, 4)),
                                             "3/4": tuple(range(1, 41, 8))}
    views = tuple(plan)
    rows = []
    for view, frames in plan.items():
        anim = arm.animation_data
        action, slot = anim.action, anim.action_slot
        drawings = posed_drawings(scene, arm, frames, VIEWS[view])
        anim.action = None  # the bind pose must stay when frames change
        for k, truth, _, camera, traced in drawings:
            rows.append(_pose_row(arm, camera, view, k, truth, traced))
        anim.action = action
        anim.action_slot = slot
    for view in views:
        sel = [r for r in rows if r[1] == view]
        rows.append([f"mean {view}", "", sel[0][2]] + [float(np.nanmean([r[c] for r in sel]))
                                                      for c in range(3, 9)])
    height = float(np.ptp(rest.skeleton.rest_heads[:, 2]))
    return (f"Whole gesture Pose of traced CMU poses on the imported Adventurer (glTF, token "
            f"bones read as joints; {height:.2f} m)", HEADERS, rows)


def run(quick: bool) -> list[tuple[str, list[str], list[list]]]:
    """The table, when bpy and the eval assets are present."""
    try:
        import bpy  # noqa: F401
    except ImportError:
        return []
    table = pose_table(quick)
    return [] if table is None else [table]
