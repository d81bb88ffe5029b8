"""Benchmark of stick-figure posing in an environment (Lin et al. 2012, ground-truth test).

Stick figures are made by projecting known poses through a camera (1.5 px noise on the
sample scene, none on the CMU poses; hands and feet left out), then reconstructed.

1. **Sample scene** (the humanoid with a chair, stool, table and floor): sitting on the
   chair, standing, leaning on the table and lying on the floor; feet (and, lying, the
   pelvis) pinned to the floor and, leaning, the wrists to the table, where the eye ray
   through the drawn joint meets them.
2. **CMU poses** retargeted onto the Adventurer (``../shared/eval-assets``, skipped when
   absent), the paper's test: a floor under the posed character (at its lowest skin
   point) and the drawn joints that touch it pinned to it as a user pins them (the eye
   ray through the drawn joint; joints whose height above the floor, less the height
   their pin gives them, is within :data:`CONTACT` of the lowest one's). The full run
   also solves every pose with no environment and no pins (the root's depth then
   follows the drawing's scale only).

Metrics: mean 3D error over the drawn joints, in % of the character's height, of the first
suggestion and of the best of the suggestions (single-view depth is ambiguous; the user
steps through suggestions), absolute and after aligning the pelvis; time per solve on
:data:`THREADS` threads (``StickInput.threads``): CPU (the process's, both threads, BLAS
being single-threaded meanwhile) and wall (the machine's 2 cores being shared), with the
genetic search's and the refinement's wall time.
The paper reports 7.8 cm on a 170 cm character (4.6 %) and 1-2 s per solve with a GPU;
the targets are under 3 % and under 1 s.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from bench.eval_assets import ADVENTURER, load_adventurer

HEADERS = ["case", "solves", "first %h", "best %h", "best %h (pelvis aligned)",
           "threads", "median CPU s", "median s", "GA s", "refine s"]
#: Threads per solve (``StickInput.threads``: 2, the default, or 1).
THREADS = 2


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
            float(a[:, 2].mean()), THREADS, *(float(v) for v in np.median(t, axis=0))]


def _solve_timed(inp):
    """``solve_stick(inp)`` and its CPU time (seconds of the process: both solve threads)."""
    from gesture_pose.core.stick.solve import solve_stick

    t0 = time.process_time()
    res = solve_stick(dataclasses.replace(inp, threads=THREADS))
    return res, time.process_time() - t0


def _times(res, cpu: float) -> tuple[float, ...]:
    """CPU seconds, then wall seconds of the solve, the genetic search, the refinement."""
    return (cpu, res.timings["total"], res.timings["genetic"], res.timings["refine"])


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

    from gesture_pose.core.stick.solve import StickInput
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
            res, cpu = _solve_timed(StickInput(
                st.armature.skeleton, st.camera, stick=st.stick, environment=env,
                mesh_vertices=mesh.rest_vertices, mesh_weights=mesh.weights,
                base_pose=base, env_pins=pins, seed=seed))
            stats.append(_errors(res, truth, st.stick.present, 1.8) + _times(res, cpu))
        rows.append(_row(pose, stats))
    return ("Stick figures on the sample scene (pinned to the floor, 1.5 px noise)", HEADERS,
            rows)


#: Joints whose height above the floor is within this of the lowest one's touch it
#: (metres; over the height their pin would give them).
CONTACT = 0.05


def _floor(z: float, half: float = 10.0):
    """A 5 cm thick floor slab whose top is at height ``z`` (world units)."""
    from gesture_pose.core.stick.environment import Environment

    v = np.array([(x, y, h) for x in (-half, half) for y in (-half, half)
                  for h in (z - 0.05, z)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return Environment(v, np.array(tris), np.zeros(len(tris), int), ("Floor",))


def contact_pins(env, cam, figure, stick, truth: np.ndarray, offsets: np.ndarray,
                 floor: float, contact: float = CONTACT) -> tuple:
    """Pins of the drawn joints that touch the floor in the truth pose, as a user pins them.

    A joint touches when its height above the floor, less the height its pin lifts it by
    (``offsets``: an ankle's standing height, a wrist's radius), is within ``contact`` of
    the lowest such clearance; it is pinned where the eye ray through its drawn node meets
    the floor (:func:`~gesture_pose.core.stick.pins.pin_candidates`).
    """
    from gesture_pose.core.stick.pins import EnvPinSpec, pin_candidates

    clear = truth @ figure.up - floor - offsets
    clear[~stick.present] = np.inf
    touch = np.flatnonzero(clear <= clear.min() + contact)
    pins = []
    for j in touch:
        hit = pin_candidates(env, cam, stick.points[j])[0]
        pins.append(EnvPinSpec(figure.joint_names[j], hit.point, hit.normal, "Floor"))
    return tuple(pins)


def view_facing(figure, truth: np.ndarray, forward: np.ndarray, camera) -> str:
    """The Facing an animator gives a posed character: ``"front"`` or ``"back"``.

    Front when the character's front (its posed ``forward``), taken across its spine (the
    pelvis to the spine joint of ``truth``), turns towards the eye: the way the search's
    initial roots face for that option.

    Args:
        figure: The character's stick model.
        truth: Posed stick joints, shape ``(J, 3)``.
        forward: The posed root's facing direction, shape ``(3,)``.
        camera: The view.
    """
    from gesture_pose.core.stick.figure import spine_joint

    spine = truth[spine_joint(figure)] - truth[0]
    spine = spine / np.linalg.norm(spine)
    eye = -camera.rays(camera.project(truth[:1]))[1][0]
    across = forward - spine * (forward @ spine)
    towards = eye - spine * (eye @ spine)
    return "front" if across @ towards >= 0.0 else "back"


def cmu_cases(quick: bool):
    """The CMU poses on the Adventurer, drawn from the front-right, one per frame.

    Yields:
        ``(frame, StickInput with a floor under the character and its contact joints
        pinned, the same without environment and pins, truth joints (J, 3), drawn joints
        (J,) bool, height)``.
    """
    import bpy

    from gesture_pose.blender.read_armature import read_armature
    from gesture_pose.blender.read_mesh import read_skinned_meshes
    from gesture_pose.blender.read_view import camera_from_object
    from gesture_pose.core.stick.capsules import capsules_from_mesh
    from gesture_pose.core.stick.figure import humanoid_figure
    from gesture_pose.core.stick.graph import StickFigure
    from gesture_pose.core.stick.pins import pin_offsets
    from gesture_pose.core.stick.solve import StickInput
    from sample_scenes import builders

    scene, arm, rest, meshes = load_adventurer()
    sk = rest.skeleton
    fig = humanoid_figure(sk)
    height = float(np.ptp(np.concatenate([sk.rest_heads, sk.rest_tails])[:, 2]))
    # Drawn from the front-right of the character (the Adventurer faces +Y).
    side = np.cross(fig.forward, fig.up)
    view = fig.forward + 0.4 * side + 0.25 * fig.up
    cam_obj = builders.add_camera(meshes[0] if meshes else arm, direction=tuple(view))
    mesh = read_skinned_meshes(arm, sk)
    offsets = pin_offsets(fig, sk, capsules_from_mesh(sk, mesh.rest_vertices, mesh.weights),
                          mesh.rest_vertices, mesh.weights)
    frames = range(1, 41, 13) if quick else range(1, 41)
    for k in frames:
        scene.frame_set(k)
        bpy.context.view_layer.update()
        data = read_armature(arm)
        state = sk.forward(data.pose)
        truth = fig.joint_positions(state.heads, state.tails)
        # The floor under the posed character (the CMU root height is not carried).
        floor = float(np.min(read_skinned_meshes(arm, sk).deformed_vertices @ fig.up))
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
        env = _floor(floor)
        pins = contact_pins(env, cam, fig, stick, truth, offsets, floor)
        # The stick figure carries the true left/right labels; the Facing option is the
        # one an animator gives (the labels do not turn the body).
        r = fig.root_bone
        forward = state.frames[r] @ sk.rest_frames[r].T @ fig.forward
        free = StickInput(sk, cam, stick=stick, mesh_vertices=mesh.rest_vertices,
                          mesh_weights=mesh.weights, seed=k,
                          facing=view_facing(fig, truth, forward, cam))
        pinned = dataclasses.replace(free, environment=env, env_pins=pins)
        yield k, pinned, free, truth, present, height


def cmu_table(quick: bool) -> tuple[str, list[str], list[list]] | None:
    """Table 2: CMU poses on the Adventurer, floor and contact pins (and none, full run)."""
    if not ADVENTURER.exists():
        return None
    rows = {"floor, contacts pinned": [], "no environment, no pins": []}
    height = 0.0
    for _, pinned, free, truth, present, height in cmu_cases(quick):
        for case, inp in zip(rows, (pinned, free), strict=True):
            if quick and inp is free:
                continue
            res, cpu = _solve_timed(inp)
            rows[case].append(_errors(res, truth, present, height) + _times(res, cpu))
    return (f"CMU poses on the Adventurer ({height:.2f} m)", HEADERS,
            [_row(case, stats) for case, stats in rows.items() if stats])


def run(quick: bool) -> list[tuple[str, list[str], list[list]]]:
    """Both tables (the CMU one only when the eval assets are present)."""
    tables = [sample_table(quick)]
    cmu = cmu_table(quick)
    if cmu is not None:
        tables.append(cmu)
    return tables
