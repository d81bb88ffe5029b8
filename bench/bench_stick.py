"""Benchmark of stick-figure posing in an environment (Lin et al. 2012, ground-truth test).

Stick figures are made by projecting known poses through a camera (1.5 px noise on the
sample scene, none on the CMU poses; hands and feet left out), then reconstructed.

1. **Sample scene** (the humanoid with a chair, stool, table and floor): sitting on the
   chair, standing, leaning on the table and lying on the floor; feet (and, lying, the
   pelvis) pinned to the floor and, leaning, the wrists to the table, where the eye ray
   through the drawn joint meets them.
2. **CMU poses** retargeted onto the Adventurer (``../shared/eval-assets``, skipped when
   absent), no environment and no pins.

Metrics: mean 3D error over the drawn joints, in % of the character's height, of the first
suggestion and of the best of the suggestions (single-view depth is ambiguous; the user
steps through suggestions), absolute and after aligning the pelvis; time per solve
(wall, the machine's 2 cores being shared) with the genetic search and the refinement.
The paper reports 7.8 cm on a 170 cm character (4.6 %) and 1-2 s per solve with a GPU;
the targets are under 3 % and under 1 s.
"""

from __future__ import annotations

import numpy as np

from bench.eval_assets import ADVENTURER, load_adventurer

HEADERS = ["case", "solves", "first %h", "best %h", "best %h (pelvis aligned)",
           "median s", "GA s", "refine s"]


def _errors(result, truth: np.ndarray, drawn: np.ndarray, height: float):
    """First, best and best pelvis-aligned errors (% height) of a result."""
    errs, aligned = [], []
    for s in result.suggestions:
        d = s.joints[drawn] - truth[drawn]
        errs.append(np.linalg.norm(d, axis=1).mean())
        aligned.append(np.linalg.norm(d - (s.joints[0] - truth[0]), axis=1).mean())
    return (100 * errs[0] / height, 100 * min(errs) / height, 100 * min(aligned) / height)


def _row(case: str, stats: list) -> list:
    a = np.array([s[:3] for s in stats])
    t = np.array([s[3:] for s in stats])
    return [case, len(stats), float(a[:, 0].mean()), float(a[:, 1].mean()),
            float(a[:, 2].mean()), float(np.median(t[:, 0])), float(np.median(t[:, 1])),
            float(np.median(t[:, 2]))]


def _inputs(arm, sketch, cam_obj, env_coll: str | None, pinned: tuple[str, ...]):
    """Read the scene like Pose Stick Figure does; returns the StickInput pieces."""
    import bpy

    from gesture_pose.blender.read_mesh import read_skinned_meshes
    from gesture_pose.blender.stick_io import (
        base_pose,
        environment_objects,
        read_environment,
        read_stick_scene,
    )
    from gesture_pose.core.stick.pins import EnvPinSpec, pin_candidates

    ctx = bpy.context
    ctx.scene.camera = cam_obj
    st = read_stick_scene(ctx, arm, sketch)
    mesh = read_skinned_meshes(arm, st.armature.skeleton)
    env = None
    if env_coll is not None:
        env = read_environment(environment_objects(ctx, arm, env_coll),
                               ctx.evaluated_depsgraph_get())
    pins = []
    if env is not None:
        for j in pinned:
            hit = pin_candidates(env, st.camera, st.stick.points[st.figure.joint(j)])[0]
            pins.append(EnvPinSpec(j, hit.point, hit.normal, "Floor"))
    base, _ = base_pose(st.armature, st.figure)
    return st, mesh, env, tuple(pins), base


def sample_table(quick: bool) -> tuple[str, list[str], list[list]]:
    """Table 1: the sample scene's poses, three noise seeds each."""
    import bpy

    from gesture_pose.core.stick.solve import StickInput, solve_stick
    from sample_scenes import stick_builders as sb

    rows = []
    poses = ["sit"] if quick else ["sit", "stand", "lean", "lie"]
    seeds = [0] if quick else [0, 1, 2]
    for pose in poses:
        stats = []
        for seed in seeds:
            bpy.ops.wm.read_factory_settings(use_empty=True)
            sc = sb.build_stick_scene(pose, noise_px=1.5, seed=seed)
            arm = sc["armature"]
            sb.pose_stick_humanoid(arm, pose)
            truth_d = sb.stick_joints(arm)
            sb.pose_stick_humanoid(arm, "rest")
            st, mesh, env, pins, base = _inputs(arm, sc["sketch"], sc["camera"],
                                                "Environment",
                                                sb.STICK_PINS[pose])
            truth = np.array([truth_d[n] for n in st.figure.joint_names])
            res = solve_stick(StickInput(
                st.armature.skeleton, st.camera, stick=st.stick, environment=env,
                mesh_vertices=mesh.rest_vertices, mesh_weights=mesh.weights,
                base_pose=base, env_pins=pins, seed=seed))
            stats.append(_errors(res, truth, st.stick.present, 1.8) +
                         (res.timings["total"], res.timings["genetic"],
                          res.timings["refine"]))
        rows.append(_row(pose, stats))
    return ("Stick figures on the sample scene (pinned to the floor, 1.5 px noise)", HEADERS,
            rows)


def cmu_table(quick: bool) -> tuple[str, list[str], list[list]] | None:
    """Table 2: CMU poses on the Adventurer, drawn from the front-right."""
    if not ADVENTURER.exists():
        return None
    import bpy

    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.blender.read_view import camera_from_object
    from gesture_pose.core.stick.figure import humanoid_figure
    from gesture_pose.core.stick.solve import StickInput, solve_stick
    from sample_scenes import builders

    scene, arm, rest, meshes = load_adventurer()
    sk = rest.skeleton
    fig = humanoid_figure(sk)
    height = float(np.ptp(np.concatenate([sk.rest_heads, sk.rest_tails])[:, 2]))
    # Drawn from the front-right of the character (the Adventurer faces +Y).
    side = np.cross(fig.forward, fig.up)
    view = fig.forward + 0.4 * side + 0.25 * fig.up
    cam_obj = builders.add_camera(meshes[0] if meshes else arm, direction=tuple(view))
    from gesture_pose.blender.read_mesh import read_skinned_meshes
    mesh = read_skinned_meshes(arm, sk)
    frames = range(1, 41, 13) if quick else range(1, 41)
    stats = []
    from gesture_pose.core.stick.graph import StickFigure
    for k in frames:
        scene.frame_set(k)
        bpy.context.view_layer.update()
        data = read_armature(arm)
        state = sk.forward(data.pose)
        truth = fig.joint_positions(state.heads, state.tails)
        # Frame the posed character: the camera follows the pelvis.
        cam_obj.location = (np.array(cam_obj.location) - np.array(
            cam_obj.get("_target", truth[0])) + truth[0]).tolist()
        cam_obj["_target"] = truth[0].tolist()
        bpy.context.view_layer.update()
        cam = camera_from_object(cam_obj, scene)
        pts = cam.project(truth)
        present = ~fig.optional
        pts[~present] = np.nan
        stick = StickFigure(fig.joint_names, pts, present, fig.joint_parents,
                            np.zeros((0, 2)))
        res = solve_stick(StickInput(sk, cam, stick=stick, mesh_vertices=mesh.rest_vertices,
                                     mesh_weights=mesh.weights, seed=k))
        stats.append(_errors(res, truth, present, height) +
                     (res.timings["total"], res.timings["genetic"], res.timings["refine"]))
    return (f"CMU poses on the Adventurer ({height:.2f} m, no environment, no pins)", HEADERS,
            [_row("cmu", stats)])


def run(quick: bool) -> list[tuple[str, list[str], list[list]]]:
    """Both tables (the CMU one only when the eval assets are present)."""
    tables = [sample_table(quick)]
    cmu = cmu_table(quick)
    if cmu is not None:
        tables.append(cmu)
    return tables
