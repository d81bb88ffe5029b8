"""Line-of-action stroke posing (Mahmudi et al. 2016) on tiny hand-built skeletons."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.camera import Camera
from gesture_pose.core.exceptions import InputError
from gesture_pose.core.line_of_action import PlaneMode, StrokeOptions, Tracking, pose_from_stroke
from gesture_pose.core.line_of_action.alignment import ViewOps, circle_of, place_joint
from gesture_pose.core.line_of_action.chain import PlanKind
from gesture_pose.core.line_of_action.features import SampledStroke, feature_param
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.skeleton import Pose
from gesture_pose.core.stroke import Stroke, distance_to_polyline

from .fixtures import chain_skeleton, front_camera, tree_skeleton

VERTICAL = np.array([[0, 0, 0], [0, 0, 0.5], [0, 0, 1.0], [0, 0, 1.5]], float)


def polyline(*corners: np.ndarray, step: float = 1.0) -> np.ndarray:
    """Densely sampled polyline through ``corners`` (pixels)."""
    pts = [np.asarray(corners[0], float)]
    for a, b in zip(corners[:-1], corners[1:], strict=True):
        n = max(int(np.linalg.norm(np.subtract(b, a)) / step), 1)
        t = np.linspace(0, 1, n + 1)[1:, None]
        pts.extend(np.asarray(a) + t * (np.asarray(b) - np.asarray(a)))
    return np.array(pts)


def joints(sk, state) -> np.ndarray:
    return np.vstack([state.heads, state.tails[-1:]])


# --- Eq. 4: the sphere-plane circle and the line-circle placement -------------------------

def test_circle_of_sphere_and_depth_plane() -> None:
    view = ViewOps.from_camera(front_camera(ortho=True))
    parent = np.array([0.0, 0.0, 0.0])
    centre, radius = circle_of(view, parent, 1.0, float(view.depth(parent)) + 0.6)
    np.testing.assert_allclose(centre, [0.0, 0.6, 0.0], atol=1e-12)
    assert radius == pytest.approx(0.8, abs=1e-12)
    # A plane beyond the sphere gives the nearest sphere point and a zero radius.
    centre, radius = circle_of(view, parent, 1.0, float(view.depth(parent)) + 2.0)
    np.testing.assert_allclose(centre, [0.0, 1.0, 0.0], atol=1e-12)
    assert radius == 0.0


def test_place_joint_lands_on_circle_towards_target() -> None:
    cam = front_camera(ortho=True)
    view = ViewOps.from_camera(cam)
    parent = np.array([0.0, 0.0, 0.8])
    current = np.array([0.0, 0.6, 0.8 + 0.8])  # depth +0.6 behind the parent, length 1
    target = cam.project(np.array([[1.0, 0.0, 0.8]]))[0]  # straight to the right
    placed = place_joint(view, parent, current, 1.0, target, float(view.depth(current)), 0.03)
    np.testing.assert_allclose(placed.position, [0.8, 0.6, 0.8], atol=1e-9)
    assert placed.circle_radius == pytest.approx(0.8)
    # Plane posing: the bone ends orthogonal to the view, full length on screen.
    placed = place_joint(view, parent, current, 1.0, target, float(view.depth(parent)), 0.03)
    np.testing.assert_allclose(placed.position, [1.0, 0.0, 0.8], atol=1e-9)


def test_place_joint_skips_bone_along_view_axis() -> None:
    view = ViewOps.from_camera(front_camera(ortho=True))
    parent = np.array([0.0, 0.0, 0.8])
    current = np.array([0.0, 1.0, 0.8])
    placed = place_joint(view, parent, current, 1.0, np.array([500.0, 300.0]),
                         float(view.depth(current)), 0.03)
    assert placed.skipped
    np.testing.assert_array_equal(placed.position, current)


# --- Whole strokes ------------------------------------------------------------------------

@pytest.mark.parametrize("ortho", [False, True])
def test_lengths_and_depths_kept_and_joints_on_stroke(ortho: bool) -> None:
    sk = chain_skeleton(VERTICAL)
    cam = front_camera(ortho)
    rng = np.random.default_rng(3)
    pose = Pose(exp_map(rng.normal(size=(3, 3)) * 0.4), np.zeros((3, 3)))
    state = sk.forward(pose)
    p0 = cam.project(state.heads[:1])[0]
    # A smooth stroke (no drawn corner): joints land where the stroke crosses their circles.
    theta = np.linspace(0.0, 0.9 * np.pi, 500)[:, None]
    stroke = Stroke(p0 + 150.0 * np.hstack([1.0 - np.cos(theta), np.sin(theta)]))
    res = pose_from_stroke(sk, pose, cam, stroke)
    new = sk.forward(res.pose)
    np.testing.assert_allclose(np.linalg.norm(new.tails - new.heads, axis=1), sk.lengths,
                               atol=1e-9)
    np.testing.assert_allclose(cam.depth(joints(sk, new)), cam.depth(joints(sk, state)),
                               atol=1e-9)
    assert res.chain == ("b0", "b1", "b2")
    dist = distance_to_polyline(cam.project(joints(sk, new))[1:], stroke.points)
    assert dist.max() < 0.05


def test_plane_posing_makes_bones_orthogonal_to_view() -> None:
    sk = chain_skeleton(VERTICAL)
    cam = front_camera(ortho=True)
    pose = Pose(exp_map(np.array([[0.5, 0.0, 0.2], [0.4, 0.1, 0.0], [-0.3, 0.0, 0.3]])),
                np.zeros((3, 3)))
    state = sk.forward(pose)
    p0 = cam.project(state.heads[:1])[0]
    stroke = Stroke(polyline(p0, p0 + [0, 300], p0 + [150, 450]))
    res = pose_from_stroke(sk, pose, cam, stroke, StrokeOptions(mode=PlaneMode.PLANE))
    new = sk.forward(res.pose)
    dirs = new.tails - new.heads
    np.testing.assert_allclose(dirs @ cam.forward, 0.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), sk.lengths, atol=1e-9)


def test_twist_is_preserved_across_strokes_and_views() -> None:
    sk = chain_skeleton(VERTICAL)
    twist = np.array([0.7, -0.4, 1.1])
    pose = Pose(exp_map(np.array([0.0, 1.0, 0.0]) * twist[:, None]), np.zeros((3, 3)))
    side = Camera.look_at([6.0, 0.0, 0.8], [0.0, 0.0, 0.8], width=800, height=600)
    high = Camera.look_at([-3.0, -4.0, 4.0], [0.0, 0.0, 0.8], width=800, height=600,
                          ortho_scale=3.0)
    for cam in (front_camera(), side, high):
        p0 = cam.project(sk.forward(pose).heads[:1])[0]
        stroke = Stroke(polyline(p0, p0 + [140, 40], p0 + [200, 200]))
        pose = pose_from_stroke(sk, pose, cam, stroke).pose
    np.testing.assert_allclose(sk.twist_angles(pose), twist, atol=1e-9)


def test_start_joint_must_be_near_the_stroke() -> None:
    sk = chain_skeleton(VERTICAL)
    cam = front_camera()
    far = Stroke(polyline([5, 5], [50, 5]))
    with pytest.raises(InputError, match=r"farther than the pick radius of 40 px"):
        pose_from_stroke(sk, Pose.identity(3), cam, far)


def test_stroke_from_a_leaf_tail_is_refused() -> None:
    sk = chain_skeleton(VERTICAL)
    cam = front_camera()
    tip = cam.project(sk.rest_tails[-1:])[0]
    with pytest.raises(InputError, match="end of bone 'b2'"):
        pose_from_stroke(sk, Pose.identity(3), cam, Stroke(polyline(tip, tip + [80, 0])))


def test_chain_along_view_axis_is_refused() -> None:
    pts = np.array([[0, 0, 0.8], [0, 0.5, 0.8], [0, 1.0, 0.8]], float)  # pointing at +y
    sk = chain_skeleton(pts)
    cam = front_camera()
    p0 = cam.project(pts[:1])[0]
    with pytest.raises(InputError, match="along the view axis"):
        pose_from_stroke(sk, Pose.identity(2), cam, Stroke(polyline(p0, p0 + [100, 0])))


def test_too_short_stroke_is_refused() -> None:
    sk = chain_skeleton(VERTICAL)
    p0 = front_camera().project(sk.rest_heads[:1])[0]
    with pytest.raises(InputError, match="only 3.0 px long"):
        pose_from_stroke(sk, Pose.identity(3), front_camera(), Stroke(polyline(p0, p0 + [3, 0])))


# --- Branches, Forward / Over-Root plans ------------------------------------------------

@pytest.mark.parametrize(("turn", "expected"), [((1.0, 0.0), "arm.L"), ((0.0, 1.0), "neck"),
                                                ((-1.0, 0.0), "arm.R")])
def test_branch_choice_takes_smallest_rotation(turn, expected) -> None:
    # Up along the root, then right, up or left: the child whose own rotation is smallest
    # continues the chain (the neck is the first child, so "first" would not pass).
    sk = tree_skeleton()
    cam = front_camera(ortho=True)
    ppu = cam.pixels_per_unit(6.0)
    root = cam.project(sk.rest_heads[:1])[0]
    top = root + [0.0, ppu]
    stroke = Stroke(polyline(root, top, top + np.array(turn) * 0.45 * ppu))
    res = pose_from_stroke(sk, Pose.identity(6), cam, stroke)
    assert res.chain[:2] == ("root", expected)


def test_stroke_along_one_arm_poses_only_that_arm() -> None:
    sk = tree_skeleton()
    cam = front_camera()
    start = cam.project(sk.rest_heads[2:3])[0]  # arm.L's head (unconnected from root)
    res = pose_from_stroke(sk, Pose.identity(6), cam,
                           Stroke(polyline(start, start + [80, 40], start + [150, 120])))
    assert res.chain == ("arm.L", "fore.L")
    assert set(np.flatnonzero(np.any(res.pose.rotations != np.eye(3), axis=(1, 2)))) == {2, 3}


def test_direction_bone_restricts_the_branch() -> None:
    sk = tree_skeleton()
    cam = front_camera()
    root = cam.project(sk.rest_heads[:1])[0]
    res = pose_from_stroke(sk, Pose.identity(6), cam, Stroke(polyline(root, root + [0, 260])),
                           StrokeOptions(direction_bone="fore.R"))
    assert res.chain[:2] == ("root", "arm.R")


def test_reversed_stroke_from_lower_end() -> None:
    sk = chain_skeleton(VERTICAL)
    cam = front_camera()
    tip = cam.project(sk.rest_tails[-1:])[0]
    base = cam.project(sk.rest_heads[:1])[0]
    # Drawn from the tip down to the base, bulging right.
    stroke = Stroke(polyline(tip, tip + [120, -140], base))
    res = pose_from_stroke(sk, Pose.identity(3), cam, stroke,
                           StrokeOptions(start_bone="b2", end_bone="b0"))
    assert res.plan is PlanKind.REVERSED
    assert res.chain == ("b0", "b1", "b2")


def test_over_root_splits_begin_middle_end() -> None:
    sk = tree_skeleton()
    cam = front_camera(ortho=True)
    # Target: both arms raised in the view plane, forearms bent outwards.
    target = Pose.identity(6)
    for arm, fore, sign in ((2, 3, 1.0), (4, 5, -1.0)):
        st = sk.forward(target)
        q = sk.aim_local(arm, np.array([0.3 * sign, 0.0, 1.0]), st, target.rotations[arm])
        target = target.with_rotations([arm], q[None])
        st = sk.forward(target)
        q = sk.aim_local(fore, np.array([sign, 0.0, 0.4]), st, target.rotations[fore])
        target = target.with_rotations([fore], q[None])
    st = sk.forward(target)
    path = np.array([st.tails[3], st.heads[3], st.heads[2], st.heads[4], st.heads[5],
                     st.tails[5]])
    stroke = Stroke(polyline(*cam.project(path), step=0.5))
    res = pose_from_stroke(sk, Pose.identity(6), cam, stroke,
                           StrokeOptions(start_bone="fore.L", end_bone="fore.R"))
    assert res.plan is PlanKind.OVER_ROOT
    # Begin part reversed (posed from the ancestor outwards), then the end part.
    assert res.chain == ("arm.L", "fore.L", "arm.R", "fore.R")
    new = sk.forward(res.pose)
    np.testing.assert_allclose(new.tails[2:], st.tails[2:], atol=2e-3)
    np.testing.assert_array_equal(res.pose.rotations[:2], np.tile(np.eye(3), (2, 1, 1)))


def test_shape_tracking_scales_stroke_to_chain() -> None:
    # An L drawn twice the chain's size. Position tracking follows the drawn positions: both
    # bones lie along the L's first leg. Shape tracking scales the L to the chain: the
    # second bone turns the corner.
    sk = chain_skeleton(np.array([[0, 0, 0], [0, 0, 0.5], [0, 0, 1.0]], float))
    cam = front_camera(ortho=True)
    ppu = cam.pixels_per_unit(6.0)
    p0 = cam.project(sk.rest_heads[:1])[0]
    corner = p0 + [1.0 * ppu, 0.0]
    stroke = Stroke(polyline(p0, corner, corner + [0.0, 1.0 * ppu]))

    def bone_dirs(tracking: Tracking) -> np.ndarray:
        res = pose_from_stroke(sk, Pose.identity(2), cam, stroke,
                               StrokeOptions(tracking=tracking))
        st = sk.forward(res.pose)
        d = st.tails - st.heads
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    np.testing.assert_allclose(bone_dirs(Tracking.POSITION), [[1, 0, 0], [1, 0, 0]], atol=1e-3)
    np.testing.assert_allclose(bone_dirs(Tracking.SHAPE), [[1, 0, 0], [0, 0, 1]], atol=2e-2)


# --- Feature extraction (Eqs. 2-3) ------------------------------------------------------

def test_feature_points_snap_to_zigzag_corners() -> None:
    corners = np.array([[0, 0], [100, 0], [100, 100], [200, 100]], float)
    sampled = SampledStroke.from_stroke(Stroke(polyline(*corners, step=0.5)), 1.0)
    # Guesses 20 px off each corner, window 100/3 px: the corners are found exactly.
    assert feature_param(sampled, 80.0, 100 / 3, 0.02) == pytest.approx(100.0, abs=1.0)
    assert feature_param(sampled, 215.0, 100 / 3, 0.02) == pytest.approx(200.0, abs=1.0)
    # On the straight middle of a segment nothing counts as a feature.
    assert feature_param(sampled, 150.0, 100 / 3, 0.02) is None


def test_features_beat_uniform_baseline_on_a_curved_stroke() -> None:
    sk = chain_skeleton(VERTICAL)
    cam = front_camera(ortho=True)
    p0 = cam.project(sk.rest_heads[:1])[0]
    radius = 0.9 * cam.pixels_per_unit(6.0)
    theta = np.linspace(0.0, 0.8 * np.pi, 600)
    arc = p0 + radius * np.stack([1.0 - np.cos(theta), np.sin(theta)], 1)
    stroke = Stroke(arc)
    feat = pose_from_stroke(sk, Pose.identity(3), cam, stroke)
    base = pose_from_stroke(sk, Pose.identity(3), cam, stroke,
                            StrokeOptions(feature_extraction=False))
    assert feat.mean_distance < 1e-3
    assert base.mean_distance > 0.5


def bent_arm():
    """A 0.6 m + 0.4 m vertical two-bone arm, an orthographic front camera, the arm's base
    in pixels and the camera's pixels per metre."""
    sk = chain_skeleton(np.array([[0, 0, 0], [0, 0, 0.6], [0, 0, 1.0]], float))
    cam = front_camera(ortho=True)
    return sk, cam, cam.project(sk.rest_heads[:1])[0], cam.pixels_per_unit(6.0)


def test_drawn_corner_decides_the_bone_direction() -> None:
    # The elbow is drawn at 0.5 of a 0.6 m upper arm: Eq. 2 finds the corner, and Eq. 4
    # points the upper arm at it (the joint cannot reach it exactly), instead of landing
    # the joint where the stroke's second leg crosses its circle.
    sk, cam, p0, ppu = bent_arm()
    corner = p0 + [0.5 * ppu, 0.0]
    stroke = Stroke(polyline(p0, corner, corner + [0.0, 0.6 * ppu]))
    res = pose_from_stroke(sk, Pose.identity(2), cam, stroke)
    upper = sk.forward(res.pose).tails[0] - sk.rest_heads[0]
    assert np.degrees(np.arccos(upper[0] / np.linalg.norm(upper))) < 1.0
    no_features = pose_from_stroke(sk, Pose.identity(2), cam, stroke,
                                   StrokeOptions(feature_min_curvature=1e9))
    upper = sk.forward(no_features.pose).tails[0] - sk.rest_heads[0]
    assert np.degrees(np.arccos(upper[0] / np.linalg.norm(upper))) > 20.0


def test_bent_limb_elbow_lands_on_the_drawn_corner() -> None:
    sk, cam, p0, ppu = bent_arm()
    elbow = p0 + [0.6 * ppu, 0]
    stroke = Stroke(polyline(p0, elbow, elbow + [0, 0.5 * ppu]))
    res = pose_from_stroke(sk, Pose.identity(2), cam, stroke)
    # Within the spline's rounding of a sharp drawn corner (sub-pixel).
    np.testing.assert_allclose(res.landed[0], elbow, atol=0.75)
    assert res.mean_distance < 0.5


# --- Pins: prioritized IK -----------------------------------------------------------------

def test_pinned_bone_keeps_world_position() -> None:
    pts = np.array([[0, 0, 0], [0.3, 0, 0.4], [0, 0, 0.8], [0.3, 0, 1.2], [0.3, 0, 1.7]], float)
    sk = chain_skeleton(pts)
    cam = front_camera(ortho=True)
    p0 = cam.project(sk.rest_heads[:1])[0]
    pinned = np.array([False, False, False, True])
    stroke = Stroke(polyline(p0, p0 + [200, 60], p0 + [260, 300]))
    free = pose_from_stroke(sk, Pose.identity(4), cam, stroke)
    res = pose_from_stroke(sk, Pose.identity(4), cam, stroke, pinned=pinned)
    before, after = sk.forward(Pose.identity(4)), sk.forward(res.pose)
    assert res.pins.pinned == (3,) and res.pins.held
    assert res.warnings == (f"The posed joints are {res.mean_distance:.0f} px from the stroke "
                            "on average: the pinned bones (b3) hold the chain back.",)
    np.testing.assert_allclose(after.heads[3], before.heads[3], atol=1e-9)
    np.testing.assert_allclose(after.tails[3], before.tails[3], atol=1e-9)
    np.testing.assert_allclose(after.frames[3], before.frames[3], atol=1e-9)
    assert res.pins.drawn_error > 0.01  # the pin pulled the chain off the drawn pose
    np.testing.assert_allclose(np.linalg.norm(after.tails - after.heads, axis=1), sk.lengths,
                               atol=1e-9)
    # Without the pin the stroke would have moved it far.
    assert np.linalg.norm(sk.forward(free.pose).heads[3] - before.heads[3]) > 0.3


def test_long_chain_stays_rigid_and_orthonormal() -> None:
    # 45 joints: rounding in the rigid subtree updates must not compound along the chain.
    rng = np.random.default_rng(11)
    angles = np.cumsum(rng.normal(0.0, 0.08, 44))
    seg = np.stack([np.sin(angles), np.zeros(44), np.cos(angles)], 1) * (1.6 / 44)
    sk = chain_skeleton(np.vstack([[0, 0, 0], np.cumsum(seg, axis=0)]),
                        rolls=rng.uniform(-np.pi, np.pi, 44))
    cam = front_camera()
    p0 = cam.project(sk.rest_heads[:1])[0]
    theta = np.linspace(0, 1.5 * np.pi, 800)
    stroke = Stroke(p0 + 120 * np.stack([1 - np.cos(theta), np.sin(theta)], 1)
                    + np.stack([theta * 20, theta * 30], 1))
    res = pose_from_stroke(sk, Pose.identity(44), cam, stroke)
    q = res.pose.rotations
    np.testing.assert_allclose(np.swapaxes(q, 1, 2) @ q, np.tile(np.eye(3), (44, 1, 1)),
                               atol=1e-12)
    new = sk.forward(res.pose)
    np.testing.assert_allclose(np.linalg.norm(new.tails - new.heads, axis=1), sk.lengths,
                               atol=1e-9)
    assert len(res.chain) > 30 and res.mean_distance < 0.5


def test_direction_bone_outside_the_drawn_part_is_refused() -> None:
    sk = tree_skeleton()
    cam = front_camera()
    start = cam.project(sk.rest_heads[2:3])[0]  # arm.L
    with pytest.raises(InputError, match="direction bone 'fore.R' is not below"):
        pose_from_stroke(sk, Pose.identity(6), cam, Stroke(polyline(start, start + [90, 30])),
                         StrokeOptions(direction_bone="fore.R"))
