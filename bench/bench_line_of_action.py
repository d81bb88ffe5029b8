"""Line-of-action stroke posing: speed per chain length, accuracy, operator round trip.

- Solve time: chains of 3 to 45 joints in the view plane, strokes drawn through the
  projected joints of random known poses; median time per stroke and per joint.
- Accuracy: the same strokes with drawing noise (control points jittered by a percentage
  of the chain's projected length); mean distance of the posed joints' projections to the
  stroke and to the true joints, as % of the chain's projected length, with feature
  extraction and with the uniform arc-length baseline.
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


def drawn_stroke(pixels: np.ndarray, noise_px: float, rng: np.random.Generator) -> Stroke:
    """A smooth stroke through (jittered) control points, sampled every pixel."""
    pts = pixels + rng.normal(0.0, noise_px, pixels.shape) * (noise_px > 0)
    pts[0] = pixels[0]
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


def accuracy_table(quick: bool) -> tuple[str, list[str], list[list]]:
    """Accuracy with feature extraction and with the uniform baseline under noise."""
    rng = np.random.default_rng(2)
    cam = camera()
    rows = []
    for joints in (3, 5, 10, 45):
        for noise_pct in (0.0, 1.0, 3.0):
            acc = {True: [], False: []}
            for _ in range(8 if quick else 60):
                sk, target = _case(joints - 1, rng)
                px = cam.project(target)
                length_px = float(np.sum(np.linalg.norm(np.diff(px, axis=0), axis=1)))
                stroke = drawn_stroke(px, noise_pct / 100 * length_px, rng)
                for feat in (True, False):
                    res = pose_from_stroke(sk, Pose.identity(sk.n_bones), cam, stroke,
                                           StrokeOptions(feature_extraction=feat))
                    st = sk.forward(res.pose)
                    got = cam.project(np.vstack([st.heads, st.tails[-1:]]))[1:]
                    to_stroke = distance_to_polyline(got, stroke.points).mean()
                    to_truth = np.linalg.norm(got - px[1:], axis=1).mean()
                    acc[feat].append((to_stroke / length_px, to_truth / length_px))
            f, b = np.mean(acc[True], axis=0) * 100, np.mean(acc[False], axis=0) * 100
            rows.append([joints, noise_pct, float(f[0]), float(b[0]), float(f[1]), float(b[1])])
    return ("Line of action: accuracy, % of the chain's projected length",
            ["joints", "noise %", "to stroke (features)", "to stroke (uniform)",
             "to true joints (features)", "to true joints (uniform)"], rows)


def round_trip_table(quick: bool) -> tuple[str, list[str], list[list]]:
    """The operator's full round trip on the sample humanoid's left arm."""
    try:
        import bpy
    except ImportError:
        return ("Line of action: operator round trip", ["note"], [["bpy not installed"]])
    import gesture_pose
    from sample_scenes import builders

    bpy.ops.wm.read_factory_settings(use_empty=True)
    gesture_pose.register()
    try:
        arm, _ = builders.build_humanoid()
        cam = builders.add_camera(arm)
        stroke = builders.chain_stroke(arm, cam, ["upper_arm.L", "forearm.L", "hand.L",
                                                  "fingers.L"],
                                       builders.HUMANOID_POSES["raise_left_arm"])
        gp = builders.add_grease_pencil("Sketch", [stroke])
        times = []
        for frame in range(1, (6 if quick else 21) + 1):
            bpy.context.scene.frame_set(frame)
            builders.reset_pose(arm)
            t0 = time.perf_counter()
            bpy.ops.gesture_pose.pose_stroke(armature=arm.name, sketch=gp.name)
            times.append((time.perf_counter() - t0) * 1e3)
        n_bones = len(arm.data.bones)
    finally:
        gesture_pose.unregister()
    return ("Line of action: Pose Stroke operator round trip (read, solve, key)",
            ["rig", "bones", "runs", "median ms", "max ms"],
            [["sample humanoid, left arm", n_bones, len(times), float(np.median(times[1:])),
              float(np.max(times[1:]))]])


def run(quick: bool) -> list[tuple[str, list[str], list[list]]]:
    """All line-of-action tables."""
    return [timing_table(quick), accuracy_table(quick), round_trip_table(quick)]
