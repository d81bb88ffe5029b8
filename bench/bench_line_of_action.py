"""Line-of-action stroke posing: speed per chain length, accuracy, operator round trip.

- Solve time: chains of 3 to 45 joints in the view plane, strokes drawn through the
  projected joints of random known poses; median time per stroke and per joint.
- Accuracy: smooth strokes and strokes with drawn corners (segments stretched at random),
  with drawing noise; the 2D bone-direction error against the drawn pose and the joints'
  distance to the stroke, for feature extraction with and without the ray-circle crossing
  and for the uniform arc-length baseline.
- Round trip: the Pose Stroke operator on the sample humanoid's arm (read, solve, key).
"""

from __future__ import annotations

import time

import numpy as np
from scipy.interpolate import CubicSpline

from gesture_pose.core.camera import Camera
from gesture_pose.core.line_of_action import StrokeOptions, pose_from_stroke
from gesture_pose.core.rotations import exp_map, rotation_between
from gesture_pose.core.skeleton import Pose, Skeleton
from gesture_pose.core.stroke import Stroke, distance_to_polyline

CHAIN_HEIGHT = 1.6  # metres


def planar_chain(n_bones: int, rng: np.random.Generator, spread: float) -> np.ndarray:
    """Joint positions of a chain in the x-z plane with random bends, ``(n + 1, 3)``."""
    angles = np.cumsum(rng.normal(0.0, spread, n_bones))
    seg = np.stack([np.sin(angles), np.zeros(n_bones), np.cos(angles)], 1)
    return np.vstack([[0.0, 0.0, 0.0], np.cumsum(seg * CHAIN_HEIGHT / n_bones, axis=0)])


def chain_skeleton(points: np.ndarray, rng: np.random.Generator) -> Skeleton:
    """A connected chain through ``points`` with random rolls."""
    n = len(points) - 1
    y = np.array([0.0, 1.0, 0.0])
    dirs = np.diff(points, axis=0)
    frames = rotation_between(np.tile(y, (n, 1)), dirs)
    frames = exp_map(dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
                     * rng.uniform(-np.pi, np.pi, (n, 1))) @ frames
    return Skeleton(tuple(f"b{i}" for i in range(n)), np.arange(n) - 1, points[:-1].copy(),
                    points[1:].copy(), frames, np.ones(n, bool),
                    np.r_[False, np.ones(n - 1, bool)], np.ones(n, bool))


def drawn_stroke(pixels: np.ndarray, noise_px: float, rng: np.random.Generator,
                 corners: bool = False) -> Stroke:
    """A stroke through (jittered) control points, sampled every pixel.

    Smooth strokes are a cubic spline through the points. Corner strokes are the polyline
    through them with every drawn segment stretched by a random factor in [0.75, 1.25]:
    the corners are where the artist put them, not where the bone lengths say.
    """
    pts = pixels + rng.normal(0.0, noise_px, pixels.shape) * (noise_px > 0)
    pts[0] = pixels[0]
    if corners:
        seg = np.diff(pts, axis=0) * rng.uniform(0.75, 1.25, (len(pts) - 1, 1))
        pts = pts[0] + np.vstack([[0.0, 0.0], np.cumsum(seg, axis=0)])
        dense = [pts[:1]]
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            n = max(int(np.linalg.norm(b - a)), 1)
            dense.append(a + np.linspace(0, 1, n + 1)[1:, None] * (b - a))
        return Stroke(np.vstack(dense))
    t = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    spline = CubicSpline(t, pts, axis=0)
    return Stroke(spline(np.linspace(0.0, t[-1], int(t[-1]) + 2)))


def camera() -> Camera:
    """A front perspective camera 960x960 looking along +y at the chain."""
    return Camera.look_at([0.0, -5.0, 0.8], [0.0, 0.0, 0.8], width=960, height=960,
                          fov=np.radians(40.0))


def _case(n_bones: int, rng: np.random.Generator):
    rest = planar_chain(n_bones, rng, 0.3 / np.sqrt(n_bones))
    sk = chain_skeleton(rest, rng)
    target = planar_chain(n_bones, rng, 1.2 / np.sqrt(n_bones))
    target = target - target[0] + rest[0]
    # Same bone lengths: rebuild the target from the rest lengths along the target angles.
    dirs = np.diff(target, axis=0)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    target = np.vstack([rest[:1], rest[0] + np.cumsum(dirs * sk.lengths[:, None], axis=0)])
    return sk, target


def timing_table(quick: bool) -> tuple[str, list[str], list[list]]:
    """Median solve time per stroke and per joint against chain length."""
    rng = np.random.default_rng(1)
    cam = camera()
    rows = []
    for joints in (3, 5, 10, 20, 30, 45):
        times, n_cases = [], 5 if quick else 30
        for _ in range(n_cases):
            sk, target = _case(joints - 1, rng)
            stroke = drawn_stroke(cam.project(target), 0.0, rng)
            pose = Pose.identity(sk.n_bones)
            pose_from_stroke(sk, pose, cam, stroke)  # warm
            reps = []
            for _ in range(3 if quick else 7):
                t0 = time.perf_counter()
                pose_from_stroke(sk, pose, cam, stroke)
                reps.append(time.perf_counter() - t0)
            times.append(min(reps))
        ms = np.array(times) * 1e3
        rows.append([joints, n_cases, float(np.median(ms)), float(np.median(ms) / joints),
                     float(np.percentile(ms, 90))])
    return ("Line of action: solve time per stroke (perspective camera, 960 px)",
            ["joints", "strokes", "median ms/stroke", "median ms/joint", "p90 ms/stroke"],
            rows)


METHODS = {
    "features + crossing": StrokeOptions(),
    "features only": StrokeOptions(stroke_crossing=False),
    "uniform": StrokeOptions(feature_extraction=False),
}


def _direction_error(got: np.ndarray, truth: np.ndarray) -> float:
    """Mean angle in degrees between projected bone directions, ``(k + 1, 2)`` joints each."""
    a, b = np.diff(got, axis=0), np.diff(truth, axis=0)
    cos = np.sum(a * b, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    return float(np.degrees(np.mean(np.arccos(np.clip(cos, -1.0, 1.0)))))


def accuracy_table(quick: bool) -> tuple[str, list[str], list[list]]:
    """Accuracy of each method on smooth and corner strokes, with drawing noise."""
    rng = np.random.default_rng(2)
    cam = camera()
    rows = []
    for style in ("smooth", "corners"):
        for joints in (3, 5, 10, 45):
            for noise_pct in (0.0, 0.5, 2.0):
                err = {m: [] for m in METHODS}
                dist = {m: [] for m in METHODS}
                for _ in range(4 if quick else 30):
                    sk, target = _case(joints - 1, rng)
                    px = cam.project(target)
                    length_px = float(np.sum(np.linalg.norm(np.diff(px, axis=0), axis=1)))
                    stroke = drawn_stroke(px, noise_pct / 100 * length_px, rng,
                                          corners=style == "corners")
                    for name, opts in METHODS.items():
                        res = pose_from_stroke(sk, Pose.identity(sk.n_bones), cam, stroke,
                                               opts)
                        st = sk.forward(res.pose)
                        got = cam.project(np.vstack([st.heads, st.tails[-1:]]))
                        err[name].append(_direction_error(got, px))
                        dist[name].append(distance_to_polyline(got[1:], stroke.points).mean()
                                          / length_px * 100)
                rows.append([style, joints, noise_pct]
                            + [float(np.mean(err[m])) for m in METHODS]
                            + [float(np.mean(dist[m])) for m in METHODS])
    heads = [f"{m} (deg)" for m in METHODS] + [f"{m} (% to stroke)" for m in METHODS]
    return ("Line of action: accuracy. Mean 2D bone-direction error against the drawn pose "
            "(degrees) and joint distance to the stroke (% of the chain's projected length); "
            "corner strokes have each drawn segment stretched by 0.75-1.25",
            ["stroke", "joints", "noise %", *heads], rows)


def _round_trips(arm, gp, runs: int) -> list[float]:
    """Milliseconds of Pose Stroke at successive frames, the rig rested before each."""
    import bpy

    from sample_scenes import builders

    times = []
    for frame in range(1, runs + 1):
        bpy.context.scene.frame_set(frame)
        builders.reset_pose(arm)
        t0 = time.perf_counter()
        done = bpy.ops.gesture_pose.pose_stroke(armature=arm.name, sketch=gp.name)
        times.append((time.perf_counter() - t0) * 1e3)
        if done != {"FINISHED"}:  # a refusal's time is not a round trip's
            raise RuntimeError(f"Pose Stroke on '{arm.name}' did not finish: {done}")
    return times[1:]


def _rigify_human(full: bool):
    """Rigify's human (fingers, face) or basic human generated headless (None without)."""
    import addon_utils
    import bpy

    addon_utils.enable("rigify", default_set=True)
    try:
        import rigify
    except ImportError:
        return None
    rigify.register_rig_parameters()
    if full:
        bpy.ops.object.armature_human_metarig_add()
    else:
        bpy.ops.object.armature_basic_human_metarig_add()
    bpy.ops.pose.rigify_generate()
    return bpy.context.active_object


def _rigify_arm_stroke(rig, cam) -> np.ndarray:
    """A stroke where the Rigify rig's left arm goes when raised (its reading bones)."""
    from gesture_pose.blender.read_armature import read_armature

    data = read_armature(rig)
    rot = np.array(data.pose.rotations)
    chain = ["ORG-upper_arm.L", "ORG-forearm.L", "ORG-hand.L"]
    rot[data.skeleton.index(chain[0])] = exp_map(np.array([0.0, -0.9, 0.0]))
    rot[data.skeleton.index(chain[1])] = exp_map(np.array([0.5, 0.0, 0.0]))
    state = data.skeleton.forward(Pose(rot, data.pose.translations))
    idx = [data.skeleton.index(n) for n in chain]
    joints = np.concatenate([state.heads[idx], state.tails[idx[-1:]]])
    t = np.linspace(0.0, 1.0, 12)[:, None]
    return np.concatenate([a + t * (b - a) for a, b in zip(joints[:-1], joints[1:],
                                                           strict=True)])


def round_trip_table(quick: bool) -> tuple[str, list[str], list[list]]:
    """The operator's full round trip on the sample humanoid's left arm.

    Also on a generated Rigify human's (the full metarig, or the basic one for a quick
    run): its FK controls written, the arm switched from IK at each frame.
    """
    try:
        import bpy
    except ImportError:
        return ("Line of action: operator round trip", ["note"], [["bpy not installed"]])
    import gesture_pose
    from sample_scenes import builders

    runs = 6 if quick else 21
    rows = []
    bpy.ops.wm.read_factory_settings(use_empty=True)
    gesture_pose.register()
    try:
        arm, _ = builders.build_humanoid()
        cam = builders.add_camera(arm)
        stroke = builders.chain_stroke(arm, cam, ["upper_arm.L", "forearm.L", "hand.L",
                                                  "fingers.L"],
                                       builders.HUMANOID_POSES["raise_left_arm"])
        gp = builders.add_grease_pencil("Sketch", [stroke])
        times = _round_trips(arm, gp, runs)
        rows.append(["sample humanoid, left arm", len(arm.data.bones), len(times),
                     float(np.median(times)), float(np.max(times))])
        bpy.ops.wm.read_factory_settings(use_empty=True)
        rig = _rigify_human(full=not quick)
        if rig is not None:
            cam = builders.add_camera(rig)
            gp = builders.add_grease_pencil("Sketch", [_rigify_arm_stroke(rig, cam)])
            times = _round_trips(rig, gp, runs)
            kind = "basic human" if quick else "human"
            rows.append([f"Rigify {kind} (generated), left arm", len(rig.data.bones),
                         len(times), float(np.median(times)), float(np.max(times))])
    finally:
        gesture_pose.unregister()
        import addon_utils

        addon_utils.disable("rigify", default_set=True)
    return ("Line of action: Pose Stroke operator round trip (read, solve, key)",
            ["rig", "bones", "runs", "median ms", "max ms"], rows)


def run(quick: bool) -> list[tuple[str, list[str], list[list]]]:
    """All line-of-action tables."""
    return [timing_table(quick), accuracy_table(quick), round_trip_table(quick)]
