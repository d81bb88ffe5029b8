"""Benchmark of the 3D step of gesture-drawing posing (Gesture3D Section 7).

Three tables:

1. **Lifting alone** on the sample humanoid and quadruped: the 2D embedding is the exact
   projection of a known pose (with the occlusions a perfect contour analysis would see),
   so the numbers measure the 3D solve, not the 2D fit.
2. **The whole Pose** (traced contours of a known pose, the 2D fit, the 3D solve with the
   choice of left/right labels, ``DepthOptions.limb_labels``) on the sample humanoid and
   quadruped, timed as the operator runs it.

The camera of each drawing is framed on the posed character (all of it in the frame).
Tables 1 and 2 cover the mild example poses (``HUMANOID_POSES``, ``QUADRUPED_POSES``:
mostly one limb changed, so the bind pose is a strong baseline) and the humanoid's poses
far from the bind pose (``HUMANOID_FAR_POSES``: run, lunge, throw, arms crossed, sit),
with the error of leaving the bind pose beside the result's.
3. **CMU poses** retargeted onto a real character (``../shared/eval-assets``, skipped when
   absent), lifting alone as in table 1.

Metrics: mean 3D joint error after aligning the root joint, in % of the character's
height; the correct depth-order rate, the fraction of joint pairs more than 5% of the
height apart in depth whose order (which is nearer the camera) the result gets right; the
depth-sign rate, the fraction of links whose depth change (tail minus head) is more than a
fifth of their length in the truth that the result turns the same way by more than a tenth
(a link left in the view plane counts as wrong); for drawings, how many of the depth orders
detected from the contours hold in the truth (right / wrong, pairs at equal depth within
1% of the height not counted); and wall times. Targets (issue): the whole Pose under 5 s
for a 20-joint humanoid on 2 cores (the paper: 1-3 minutes) and a mean 3D error under 8%
of the height on clean drawings.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

HUMANOID_VIEWS = {"front": (0.0, -1.0, 0.0), "oblique": (0.5, -1.0, 0.2)}
QUADRUPED_VIEWS = {"side": (1.0, 0.0, 0.0), "oblique": (1.0, -0.6, 0.2)}


def metrics(solving, skeleton, truth_pose, joints3d: np.ndarray, camera
            ) -> tuple[float, float, float]:
    """Mean joint error (% of height, root aligned), depth-order and depth-sign rates.

    See the module docstring for the definitions.
    """
    from gesture_pose.core.gesture.depth.evaluation import (
        depth_sign_rate,
        joints_of,
        pose_error,
    )

    truth = joints_of(solving, skeleton, truth_pose)
    err = pose_error(truth, joints3d, skeleton, camera)
    return (err.mean_error, err.depth_order,
            depth_sign_rate(solving, truth, joints3d, camera))


def order_agreement(result, solving, skeleton, truth_pose, camera) -> tuple[int, int]:
    """How many of the result's depth-order constraints hold / fail in the truth.

    Pairs within 1% of the height of equal depth are not counted.
    """
    from gesture_pose.core.gesture.depth.evaluation import joints_of

    truth = joints_of(solving, skeleton, truth_pose)
    height = float(np.ptp(np.concatenate([skeleton.rest_heads, skeleton.rest_tails]),
                          axis=0).max())
    gaps = np.array([c.gap(camera.depth(truth)) for c in result.ordering])
    return int(np.sum(gaps > 0.01 * height)), int(np.sum(gaps < -0.01 * height))


def _scene(kind: str, direction, ortho: bool = False):
    """A sample character and a camera; returns the armature and the core camera."""
    import bpy

    from gesture_pose.blender.read_view import camera_from_object
    from sample_scenes import builders

    bpy.ops.wm.read_factory_settings(use_empty=True)
    arm, _ = builders.build_humanoid() if kind == "humanoid" else builders.build_quadruped()
    cam_obj = builders.add_camera(arm, direction=direction, ortho=ortho)
    return arm, camera_from_object(cam_obj, bpy.context.scene)


def _posed_camera(arm, truth, direction):
    """Replace the scene camera by one framed on the posed character; the core camera.

    The camera of :func:`_scene` frames the bind pose: raised hands left the frame (the
    throw and the wave seen obliquely), so their traced drawings were cut. This one frames
    the posed character's deformed mesh (every joint inside the frame, with the default
    margin of 1.15).
    """
    import bpy

    from gesture_pose.blender.read_mesh import read_skinned_meshes
    from gesture_pose.blender.read_view import camera_from_object
    from sample_scenes import builders

    scene = bpy.context.scene
    if scene.camera is not None:
        bpy.data.objects.remove(scene.camera)
    points = read_skinned_meshes(arm, truth.skeleton).deformed_vertices
    return camera_from_object(builders.add_camera(points, direction=direction), scene)


def demo_rotations(arm) -> dict:
    """A humanoid pose with cues in and out of the view plane.

    The right arm waves, the left forearm points at a front camera and the left knee is
    raised towards it.
    """
    from sample_scenes import builders

    bone = arm.data.bones["forearm.L"]
    d = np.array(bone.tail_local - bone.head_local)
    axis = np.cross(d / np.linalg.norm(d), [0.0, -1.0, 0.0])
    rot = dict(builders.HUMANOID_POSES["wave"])
    rot.update({"forearm.L": (tuple(axis), 70.0), "thigh.L": ((1.0, 0.0, 0.0), -50.0),
                "shin.L": ((1.0, 0.0, 0.0), 60.0)})
    return rot


def _truth(arm, kind: str, pose_name: str):
    """Read the bind pose, pose the character (leaving it posed) and read the truth."""
    import bpy

    from gesture_pose.blender.read_armature import read_armature
    from sample_scenes import builders

    bind = read_armature(arm)
    poses = ({**builders.HUMANOID_POSES, **builders.HUMANOID_FAR_POSES} if kind == "humanoid"
             else builders.QUADRUPED_POSES)
    builders.apply_rotations(arm, demo_rotations(arm) if pose_name == "demo"
                             else poses[pose_name])
    bpy.context.view_layer.update()
    truth = read_armature(arm)
    return bind, truth


def lifting_table(quick: bool) -> tuple[str, list[str], list[list]]:
    """Table 1: the 3D solve on exact embeddings of the sample characters' poses."""
    from gesture_pose.core.gesture.depth import joints_of, solve_pose3d
    from gesture_pose.core.gesture.depth.synthetic import project_embedding
    from gesture_pose.core.gesture.solving import solving_skeleton
    from sample_scenes import builders

    far_names = set(builders.HUMANOID_FAR_POSES)
    rows = []
    cases = [("humanoid", p, v) for p in builders.HUMANOID_POSES for v in HUMANOID_VIEWS]
    cases += [("quadruped", p, v) for p in builders.QUADRUPED_POSES for v in QUADRUPED_VIEWS]
    far = [("humanoid", p, v) for p in builders.HUMANOID_FAR_POSES for v in HUMANOID_VIEWS]
    cases = cases[:2] + far[:2] if quick else cases + far
    for kind, pose_name, view in cases:
        views = HUMANOID_VIEWS if kind == "humanoid" else QUADRUPED_VIEWS
        arm, cam = _scene(kind, views[view])
        bind, truth = _truth(arm, kind, pose_name)
        cam = _posed_camera(arm, truth, views[view])
        solving = solving_skeleton(bind.skeleton)
        emb = project_embedding(bind.skeleton, solving, truth.pose, cam, 0.06, "auto")
        t0 = time.perf_counter()
        res = solve_pose3d(bind.skeleton, emb, cam, bind.pose)
        seconds = time.perf_counter() - t0
        err, rate, signs = metrics(solving, bind.skeleton, truth.pose, res.joints3d, cam)
        still = joints_of(solving, bind.skeleton, bind.pose)
        bind_err = metrics(solving, bind.skeleton, truth.pose, still, cam)[0]
        rows.append([kind, pose_name, view, solving.n_joints, err, bind_err, rate, signs,
                     seconds, res.iterations, len(res.ordering)])
    means = []
    for name, sel in (("mean mild poses", [r for r in rows if r[1] not in far_names]),
                      ("mean far poses", [r for r in rows if r[1] in far_names]),
                      ("mean", rows)):
        if sel and (name == "mean" or len(sel) < len(rows)):
            means.append([name, "", "", ""] + [float(np.nanmean([r[i] for r in sel]))
                                               for i in range(4, 9)] + ["", ""])
    return ("Gesture3D lifting on exact 2D embeddings (sample characters)",
            ["character", "pose", "view", "joints", "3D error % height",
             "bind pose error % height", "depth order ok", "depth signs ok", "3D time s",
             "SQP its", "order cons."], [*rows, *means])


def pose_table(quick: bool) -> tuple[str, list[str], list[list]]:
    """Table 2: the whole Pose (trace, 2D fit, 3D solve, write) on traced contours."""
    import bpy

    from gesture_pose.blender.operators.pose_drawing import pose_from_drawing
    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.blender.read_mesh import read_skinned_meshes
    from gesture_pose.core.gesture.embedding import posed_joints
    from gesture_pose.core.gesture.trace import trace_contours
    from sample_scenes import builders

    cases = [("humanoid", "raise_left_arm", "front"), ("humanoid", "wave", "front"),
             ("humanoid", "kick_right_leg", "front"), ("humanoid", "step", "front"),
             ("humanoid", "demo", "front"), ("quadruped", "paw_forward", "side"),
             ("quadruped", "tail_up", "side")]
    cases += [("humanoid", p, "oblique") for p in ("raise_left_arm", "wave", "kick_right_leg",
                                                   "step", "crouch", "reach")]
    cases += [("quadruped", p, "oblique") for p in ("paw_forward", "tail_up")]
    # Poses far from the bind pose (several limbs, in and out of the view plane), where
    # leaving the bind pose is far off.
    far = [("humanoid", p, v) for p in builders.HUMANOID_FAR_POSES for v in HUMANOID_VIEWS]
    cases = cases[:1] + far[:1] if quick else cases + far
    far_names = set(builders.HUMANOID_FAR_POSES)
    rows = []
    for kind, pose_name, view in cases:
        views = HUMANOID_VIEWS if kind == "humanoid" else QUADRUPED_VIEWS
        arm, cam = _scene(kind, views[view])
        bind, truth = _truth(arm, kind, pose_name)
        cam = _posed_camera(arm, truth, views[view])
        meshes = read_skinned_meshes(arm, truth.skeleton)
        traced = trace_contours(meshes.deformed_vertices, meshes.triangles, cam)
        builders.reset_pose(arm)
        bpy.context.view_layer.update()
        sketch = builders.add_grease_pencil("Sketch", list(traced.world(cam)))
        rep = pose_from_drawing(arm, sketch, cam, insert_keys=False, show_fit=False)
        bpy.context.view_layer.update()
        solving = rep.embedding.solving
        got = posed_joints(solving, bind.skeleton, read_armature(arm).pose)
        err, rate, signs = metrics(solving, bind.skeleton, truth.pose, got, cam)
        # Baseline: the error of leaving the character in its bind pose (doing nothing).
        still = posed_joints(solving, bind.skeleton, bind.pose)
        bind_err = metrics(solving, bind.skeleton, truth.pose, still, cam)[0]
        right, wrong = order_agreement(rep.result, solving, bind.skeleton, truth.pose, cam)
        fit_px = float(np.linalg.norm(rep.embedding.joints2d - cam.project(
            posed_joints(solving, bind.skeleton, truth.pose)), axis=1).mean())
        rows.append([kind, pose_name, view, solving.n_joints, rep.embedding.coverage, fit_px,
                     err, bind_err, rate, signs, f"{right}/{wrong}", rep.timings["fit"],
                     rep.timings["solve3d"], rep.seconds])
    means = []
    mild = [r for r in rows if r[1] not in far_names]
    far_rows = [r for r in rows if r[1] in far_names]
    for name, sel in (("mean mild, front/side", [r for r in mild if r[2] != "oblique"]),
                      ("mean mild, oblique", [r for r in mild if r[2] == "oblique"]),
                      ("mean mild poses", mild),
                      ("mean far poses", far_rows),
                      ("mean", rows)):
        if not sel or (name != "mean" and len(sel) == len(rows)):
            continue
        counts = np.array([[int(x) for x in r[10].split("/")] for r in sel]).sum(axis=0)
        means.append([name, "", "", ""] + [float(np.nanmean([r[i] for r in sel]))
                                           for i in range(4, 10)]
                     + [f"{counts[0]}/{counts[1]}"]
                     + [float(np.mean([r[i] for r in sel])) for i in range(11, 14)])
    return ("Gesture3D whole Pose on traced contours (2D fit + 3D solve)",
            ["character", "pose", "view", "joints", "coverage", "2D joint error px",
             "3D error % height", "bind pose error % height", "depth order ok",
             "depth signs ok", "orders right/wrong", "fit s", "3D s", "Pose s"],
            [*rows, *means])


def cmu_table(quick: bool) -> tuple[str, list[str], list[list]] | None:
    """Table 3: lifting exact embeddings of CMU poses retargeted onto the Adventurer.

    The character is read as the add-on reads it (the joint skeleton of its token glTF
    bones) and seen from the front (it faces +Y).
    """
    from bench.eval_assets import ADVENTURER, load_adventurer

    if not ADVENTURER.exists():
        return None
    import bpy

    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.blender.read_view import camera_from_object
    from gesture_pose.core.gesture.depth import solve_pose3d
    from gesture_pose.core.gesture.depth.synthetic import project_embedding
    from gesture_pose.core.gesture.solving import solving_skeleton
    from sample_scenes import builders

    scene, arm, full, meshes = load_adventurer()
    skel = full.skeleton
    cam_obj = builders.add_camera(meshes[0] if meshes else arm, direction=(0.0, 1.0, 0.0))
    cam = camera_from_object(cam_obj, scene)
    names = json.loads((ADVENTURER.parent / "Adventurer_cmu40poses_report.json").read_text())
    solving = solving_skeleton(skel)
    height = float(np.ptp(np.concatenate([skel.rest_heads, skel.rest_tails]), axis=0).max())
    frames = range(1, 41, 13) if quick else range(1, 41)
    rows = []
    for k in frames:
        scene.frame_set(k)
        bpy.context.view_layer.update()
        truth = read_armature(arm).pose
        emb = project_embedding(skel, solving, truth, cam, 0.035 * height, "auto")
        t0 = time.perf_counter()
        res = solve_pose3d(skel, emb, cam)
        seconds = time.perf_counter() - t0
        err, rate, signs = metrics(solving, skel, truth, res.joints3d, cam)
        rows.append([k, str(names[k - 1][0]).removesuffix(".bvh"), solving.n_joints, err,
                     rate, signs, seconds])
    rows.append(["mean", "", "", float(np.mean([r[3] for r in rows])),
                 float(np.nanmean([r[4] for r in rows])), float(np.nanmean([r[5] for r in rows])),
                 float(np.mean([r[6] for r in rows]))])
    rows.append(["median", "", "", float(np.median([r[3] for r in rows[:-1]])), "", "", ""])
    return ("Gesture3D lifting of CMU poses on the Quaternius Adventurer (exact 2D "
            "embeddings of the solving joints, front view)",
            ["frame", "CMU pose", "joints", "3D error % height", "depth order ok",
             "depth signs ok", "3D s"], rows)


def run(quick: bool) -> list[tuple[str, list[str], list[list]]]:
    """All tables (the Blender-based ones are skipped when bpy is missing)."""
    try:
        import bpy  # noqa: F401
    except ImportError:
        return []
    tables = [lifting_table(quick), pose_table(quick)]
    cmu = cmu_table(quick)
    if cmu is not None:
        tables.append(cmu)
    return tables


def _render(path: Path) -> np.ndarray:
    """Render the scene camera with Workbench to ``path``; RGBA pixels ``(h, w, 4)``."""
    import bpy

    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(path), check_existing=False)
    px = np.empty(img.size[0] * img.size[1] * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    shape = (img.size[1], img.size[0], 4)
    bpy.data.images.remove(img)
    return px.reshape(shape)


def _save_row(images: list[np.ndarray], path: Path) -> None:
    """Write renders next to each other (white separators) as one PNG."""
    import bpy

    gap = np.ones((images[0].shape[0], 8, 4), dtype=np.float32)
    parts = [p for img in images for p in (img, gap)][:-1]
    row = np.concatenate(parts, axis=1)
    img = bpy.data.images.new(path.stem, row.shape[1], row.shape[0], alpha=True)
    img.pixels.foreach_set(row.ravel())
    img.filepath_raw = str(path)
    img.file_format = "PNG"
    img.save()
    bpy.data.images.remove(img)


def _picture_scene(out_dir: Path):
    """A fresh scene for the pictures, ``(armature, scene)``.

    The add-on registered, the sample humanoid with a camera from the front, a light;
    ``out_dir`` created.
    """
    import bpy

    import gesture_pose
    from sample_scenes import builders

    out_dir.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if not hasattr(bpy.types.Scene, "gesture_pose"):  # once per process
        gesture_pose.register()
    arm, _ = _scene("humanoid", HUMANOID_VIEWS["front"])
    builders.add_light()
    return arm, bpy.context.scene


def pictures(out_dir: Path, pose_name: str = "demo") -> list[Path]:
    """Render the documentation pictures of the 3D step headless (Workbench, 400 px).

    ``gesture3d_before_after.png``: front view of the bind pose under the traced drawing of
    a known pose, and of the result of the whole Pose, through a camera framed on the posed
    character (:func:`_posed_camera`, as in :func:`pose_table`; the side camera is framed
    on the bind pose). ``gesture3d_depth.png``: side views
    of the known pose, of the lifting of its exact embedding, and of the whole Pose. Poses
    other than ``demo`` add their name to the file names.
    """
    import bpy

    from gesture_pose.blender.operators.pose_drawing import pose_from_drawing
    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.blender.write_pose import apply_pose
    from gesture_pose.core.gesture.depth import solve_pose3d
    from gesture_pose.core.gesture.depth.synthetic import project_embedding
    from gesture_pose.core.gesture.embedding import posed_joints
    from gesture_pose.core.gesture.solving import solving_skeleton
    from sample_scenes import builders

    arm, scene = _picture_scene(out_dir)
    bind_framed = scene.camera
    side = builders.add_camera(arm, direction=(1.0, 0.0, 0.0), resolution=(400, 400),
                               name="Side")
    scene.camera = bind_framed  # the scene camera _posed_camera replaces, not the side one
    bind, truth = _truth(arm, "humanoid", pose_name)
    # Framed on the posed character, as in the bench's table: a raised hand stays in the
    # picture and in the drawing (the bind pose's frame cut the waving hand's outline).
    cam = _posed_camera(arm, truth, HUMANOID_VIEWS["front"])
    front = scene.camera
    scene.render.resolution_x = scene.render.resolution_y = 400

    def shot(camera_obj, name: str) -> np.ndarray:
        scene.camera = camera_obj
        bpy.context.view_layer.update()
        return _render(out_dir / f"_{name}.png")

    truth_side = shot(side, "truth_side")
    # Half a unit in front of the contours along their view rays: drawn over the character.
    sketch = builders.sketch_over(arm, truth.skeleton, cam)
    before = shot(front, "before")
    rep = pose_from_drawing(arm, sketch, cam, insert_keys=False, show_fit=False)
    sketch.hide_render = False
    after = shot(front, "after")
    sketch.hide_render = True
    whole_side = shot(side, "whole_side")
    solving = solving_skeleton(bind.skeleton)
    emb = project_embedding(bind.skeleton, solving, truth.pose, cam, 0.06, "auto")
    res = solve_pose3d(bind.skeleton, emb, cam, bind.pose)
    apply_pose(arm, read_armature(arm), res.pose, insert_keys=False)
    lifted_side = shot(side, "lifted_side")
    for tmp in out_dir.glob("_*.png"):
        tmp.unlink()
    suffix = "" if pose_name == "demo" else f"_{pose_name}"
    paths = [out_dir / f"gesture3d_before_after{suffix}.png",
             out_dir / f"gesture3d_depth{suffix}.png"]
    _save_row([before, after], paths[0])
    _save_row([truth_side, lifted_side, whole_side], paths[1])
    whole = posed_joints(solving, bind.skeleton, rep.result.pose)
    errors = [metrics(solving, bind.skeleton, truth.pose, joints, cam)[0]
              for joints in (whole, res.joints3d,
                             posed_joints(solving, bind.skeleton, bind.pose))]
    print(f"whole Pose {rep.seconds:.1f} s, coverage {rep.embedding.coverage:.2f}; 3D error "
          "(% of the height): whole Pose {:.2f}, exact embedding {:.2f}, bind pose "
          "{:.2f}".format(*errors))
    return paths


def body_up_pictures(out_dir: Path) -> Path:
    """Render ``gesture3d_body_up.png``: a handstand drawn, posed read Up and with Body Up.

    The sample humanoid raising its left arm, its root rolled 180 degrees about the front
    camera's line of sight (upside down), traced through a camera framed on it; three
    front renders: the bind pose under the drawing, the whole Pose with the default Body
    Up (*Up*) and with *Down* (Workbench, 400 px each).
    """
    import bpy

    from gesture_pose.blender.operators.pose_drawing import pose_from_drawing
    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.core.gesture.embedding import posed_joints
    from gesture_pose.core.gesture.solving import solving_skeleton
    from sample_scenes import builders

    arm, scene = _picture_scene(out_dir)
    bind = read_armature(arm)
    builders.apply_rotations(arm, {**builders.HUMANOID_POSES["raise_left_arm"],
                                   arm.data.bones[0].name: ((0.0, -1.0, 0.0), 180.0)})
    bpy.context.view_layer.update()
    truth = read_armature(arm)
    cam = _posed_camera(arm, truth, HUMANOID_VIEWS["front"])
    scene.render.resolution_x = scene.render.resolution_y = 400
    sketch = builders.sketch_over(arm, truth.skeleton, cam)
    shots, errors = [_render(out_dir / "_before.png")], []
    solving = solving_skeleton(bind.skeleton)
    for body_up in ("up", "down"):
        rep = pose_from_drawing(arm, sketch, cam, insert_keys=False, show_fit=False,
                                body_up=body_up)
        bpy.context.view_layer.update()
        shots.append(_render(out_dir / f"_{body_up}.png"))
        whole = posed_joints(solving, bind.skeleton, rep.result.pose)
        errors.append(metrics(solving, bind.skeleton, truth.pose, whole, cam)[0])
    for tmp in out_dir.glob("_*.png"):
        tmp.unlink()
    path = out_dir / "gesture3d_body_up.png"
    _save_row(shots, path)
    print("handstand, 3D error (% of the height): Body Up Up {:.2f}, Down {:.2f}".format(
        *errors))
    return path


if __name__ == "__main__":
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] \
        / "docs" / "img"
    for name in sys.argv[2:] or ["demo"]:
        print(*([body_up_pictures(target)] if name == "body_up" else pictures(target, name)),
              sep="\n")
