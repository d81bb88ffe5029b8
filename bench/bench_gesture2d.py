"""Gesture3D part 1: accuracy and speed of the 2D skeletal embedding.

Drawings are the traced visible contours of posed characters (how Gesture3D validated
itself), clean and perturbed like a hand drawing (smooth noise, overshoot, gaps, a 4%
scale error). Each drawing is fitted from the character's bind pose; the fitted joints are
compared with the true joints projected in the same view:

- mean and 90th-percentile joint error in % of the figure's projected height;
- left/right swaps: symmetric joint pairs fitted the wrong way round;
- coverage of the drawn contours, and seconds per drawing.

Characters: the sample humanoid (named poses, front and three-quarter views) and
quadruped; with ``../shared/eval-assets`` present, CMU poses on the Quaternius Adventurer.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

if __name__ == "__main__":  # run as a script (the docs pictures): the repository root
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.eval_assets import ADVENTURER, load_adventurer, posed_drawings  # noqa: E402

HEADERS = ["character", "pose", "view", "drawing", "joints", "mean err %", "p90 err %",
           "either facing %", "L/R swaps", "coverage %", "s"]


def swaps(solving, fitted: np.ndarray, truth: np.ndarray) -> int:
    """Symmetric joint pairs whose fitted positions match the truth better swapped."""
    from gesture_pose.core.gesture.solving import symmetric_joint_pairs

    pairs = symmetric_joint_pairs(solving)
    if len(pairs) == 0:
        return 0
    a, b = pairs[:, 0], pairs[:, 1]
    straight = (np.linalg.norm(fitted[a] - truth[a], axis=1)
                + np.linalg.norm(fitted[b] - truth[b], axis=1))
    crossed = (np.linalg.norm(fitted[a] - truth[b], axis=1)
               + np.linalg.norm(fitted[b] - truth[a], axis=1))
    return int(np.sum(crossed < 0.5 * straight))


def errors(solving, fitted: np.ndarray, truth: np.ndarray) -> list[float]:
    """Mean and 90th-percentile joint error, and the mean for either facing, % of height.

    "Either facing" is the smaller mean error of the fit as labelled and of the fit with
    every symmetric joint pair exchanged: an outline drawing does not tell a character
    seen from the front from one seen from the back, which the fit resolves as facing
    the viewer (Section 5.4's front-facing choice).

    Args:
        solving: The solving skeleton.
        fitted: Fitted joints, pixels, ``(J, 2)``.
        truth: True joints in the view, pixels, ``(J, 2)``.

    Returns:
        ``[mean, 90th percentile, either-facing mean]``, % of the truth's height.
    """
    from gesture_pose.core.gesture.solving import symmetric_joint_pairs

    height = np.ptp(truth[:, 1])
    err = np.linalg.norm(fitted - truth, axis=1) / height * 100.0
    perm = np.arange(len(truth))
    pairs = symmetric_joint_pairs(solving)
    if len(pairs):
        perm[pairs[:, 0]], perm[pairs[:, 1]] = pairs[:, 1], pairs[:, 0]
    mirrored = np.linalg.norm(fitted - truth[perm], axis=1) / height * 100.0
    return [float(err.mean()), float(np.percentile(err, 90)),
            float(min(err.mean(), mirrored.mean()))]


def measure(arm, camera, traced, label: list) -> list:
    """Fit one traced drawing and return a table row."""
    from gesture_pose.blender.operators.fit_drawing import bind_pose
    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.blender.read_mesh import read_skinned_meshes
    from gesture_pose.core.gesture.embedding import fit_drawing, posed_joints
    from gesture_pose.core.stroke import Stroke

    data = read_armature(arm)
    bind = bind_pose(data)
    meshes = read_skinned_meshes(arm, data.skeleton, state=data.skeleton.forward(bind))
    strokes = [Stroke(p) for p in traced.pixels]
    t0 = time.perf_counter()
    emb = fit_drawing(strokes, data.skeleton, bind, meshes.rest_vertices, camera,
                      meshes.weights, override=data.gesture_override)
    seconds = time.perf_counter() - t0
    truth = camera.project(posed_joints(emb.solving, data.skeleton, data.pose))
    return _row(label, emb, truth, seconds)


def _row(label: list, emb, truth: np.ndarray, seconds: float) -> list:
    """A table row (:data:`HEADERS`) for a fit against the true joints in the view."""
    return [*label, emb.solving.n_joints, *errors(emb.solving, emb.joints2d, truth),
            swaps(emb.solving, emb.joints2d, truth), 100.0 * emb.coverage, seconds]


def _drawings(arm, camera):
    """Clean and perturbed traced drawings of the character as posed now."""
    from gesture_pose.blender.operators.fit_drawing import trace_character
    from gesture_pose.core.gesture.trace import Perturbation, perturb

    clean = trace_character(arm, camera)
    return [("clean", clean), ("perturbed", perturb(clean, Perturbation(seed=1)))]


def sample_rows(quick: bool) -> list[list]:
    """Rows for the sample humanoid and quadruped."""
    import bpy

    from gesture_pose.blender.read_view import camera_from_object
    from sample_scenes import builders

    cases = [("humanoid", p, v) for p in ("rest", "wave", "step", "reach", "crouch",
                                          "raise_left_arm", "kick_right_leg")
             for v in ("front", "3/4")]
    cases += [("quadruped", p, "side") for p in ("rest", "tail_up", "paw_forward")]
    if quick:
        cases = [("humanoid", "step", "front")]
    views = {"front": (0.0, -1.0, 0.0), "3/4": (0.6, -1.0, 0.15), "side": (1.0, -0.25, 0.1)}
    rows = []
    for kind, pose, view in cases:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        if kind == "humanoid":
            arm, _ = builders.build_humanoid()
            builders.pose_humanoid(arm, pose)
        else:
            arm, _ = builders.build_quadruped()
            if pose != "rest":
                builders.apply_rotations(arm, builders.QUADRUPED_POSES[pose])
        cam = builders.add_camera(arm, direction=views[view], resolution=(800, 800),
                                  margin=1.4)
        bpy.context.view_layer.update()
        camera = camera_from_object(cam, bpy.context.scene)
        for drawing, traced in _drawings(arm, camera):
            rows.append(measure(arm, camera, traced, [kind, pose, view, drawing]))
    return rows


def adventurer_rows(quick: bool) -> list[list]:
    """Rows for CMU poses on the Quaternius Adventurer (skipped when assets are absent).

    The character is read as the add-on reads it: its glTF bones have token lengths, so the
    reader gives the joint skeleton (each bone from its head to its principal child's head,
    ``core/joint_skeleton.py``); the bind pose is its rest pose. Seen from the front (it
    faces +Y), the camera framed on each posed character (the CMU poses move and turn the
    body, so a camera framed on the rest pose cut off feet and raised hands). Each clean
    drawing is fitted again with the Facing and Body Up an animator gives
    (``bench_gesture_assets.view_facing`` and ``view_body_up``).
    """
    if not ADVENTURER.exists():
        return []

    from bench.bench_gesture_assets import view_body_up, view_facing
    from gesture_pose.blender.operators.fit_drawing import bind_pose
    from gesture_pose.core.gesture.embedding import fit_drawing, posed_joints
    from gesture_pose.core.gesture.solving import solving_skeleton
    from gesture_pose.core.gesture.trace import Perturbation, perturb
    from gesture_pose.core.stroke import Stroke

    scene, arm, rest, _ = load_adventurer()
    rows = []
    up = np.asarray(arm.matrix_world)[:3, 2]
    solving, bind = solving_skeleton(rest.skeleton), bind_pose(rest)
    for k, data, md, camera, clean in posed_drawings(scene, arm,
                                                     (1,) if quick else range(1, 41, 4),
                                                     (0.0, 1.0, 0.0)):
        facing = view_facing(solving, rest.skeleton, data.pose, camera, up)
        body_up = view_body_up(solving, rest.skeleton, data.pose, bind, camera, up)
        for drawing, traced, side, roll in (
                ("clean", clean, "auto", "up"),
                ("perturbed", perturb(clean, Perturbation(seed=1)), "auto", "up"),
                ("clean, Facing and Body Up given", clean, facing, body_up)):
            t0 = time.perf_counter()
            emb = fit_drawing([Stroke(p) for p in traced.pixels], rest.skeleton,
                              bind, md.rest_vertices, camera, md.weights,
                              facing=side, object_up=up, body_up=roll)
            seconds = time.perf_counter() - t0
            truth = camera.project(posed_joints(emb.solving, data.skeleton, data.pose))
            rows.append(_row(["adventurer", f"cmu {k}", "front", drawing], emb, truth,
                             seconds))
    return rows


def _summary(rows: list[list]) -> list[list]:
    """Mean over rows per character and drawing kind."""
    out = []
    keys = sorted({(r[0], r[3]) for r in rows if isinstance(r[5], float)})
    for kind, drawing in keys:
        sel = [r for r in rows if r[0] == kind and r[3] == drawing and isinstance(r[5], float)]
        out.append([kind, "all", "", drawing, sel[0][4],
                    *[float(np.mean([r[c] for r in sel])) for c in (5, 6, 7)],
                    int(sum(r[8] for r in sel)), float(np.mean([r[9] for r in sel])),
                    float(np.mean([r[10] for r in sel]))])
    return out


def run(quick: bool) -> list[tuple[str, list[str], list[list]]]:
    """The per-drawing table and its summary (empty without bpy)."""
    try:
        import bpy  # noqa: F401
    except ImportError:
        return []
    rows = sample_rows(quick) + adventurer_rows(quick)
    return [("Gesture3D 2D embedding of traced drawings (joint error in % of the projected "
             "height)", HEADERS, rows),
            ("Gesture3D 2D embedding: means per character and drawing", HEADERS,
             _summary(rows))]


def render_doc_images(out_dir: Path, pose: str = "kick_right_leg", size: int = 480) -> list[Path]:
    """Render the docs pictures headless with Workbench on the sample humanoid.

    First the traced drawing over the character, then the drawing with the fitted skeleton.

    Args:
        out_dir: Folder for ``gesture_input.png`` and ``gesture_fit.png``.
        pose: Named humanoid pose.
        size: Image width and height, pixels.

    Returns:
        The written files.
    """
    import bpy

    from gesture_pose.blender.operators import fit_drawing as op
    from gesture_pose.blender.read_view import camera_from_object
    from sample_scenes import builders

    bpy.ops.wm.read_factory_settings(use_empty=True)
    arm, mesh = builders.build_humanoid()
    builders.pose_humanoid(arm, pose)
    cam = builders.add_camera(arm, direction=(0.35, -1.0, 0.1), resolution=(size, size))
    bpy.context.view_layer.update()
    camera = camera_from_object(cam, bpy.context.scene)
    traced = op.trace_character(arm, camera)
    sketch = op.write_traced("Drawing", traced, camera)
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.image_settings.file_format = "PNG"
    scene.render.film_transparent = False
    scene.world = scene.world or bpy.data.worlds.new("World")
    scene.world.color = (1.0, 1.0, 1.0)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    scene.render.filepath = str(out_dir / "gesture_input.png")
    bpy.ops.render.render(write_still=True)
    written.append(out_dir / "gesture_input.png")
    emb, _ = op.fit_scene_drawing(arm, sketch, camera)
    depth = float(np.mean(camera.depth(np.concatenate(traced.world(camera)))))
    op.draw_fit(sketch, emb, camera, depth - 0.3)
    mesh.hide_render = True
    scene.render.filepath = str(out_dir / "gesture_fit.png")
    bpy.ops.render.render(write_still=True)
    written.append(out_dir / "gesture_fit.png")
    return written


if __name__ == "__main__":
    for path in render_doc_images(Path(__file__).resolve().parents[1] / "docs" / "img"):
        print(path)
