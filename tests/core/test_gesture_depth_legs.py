"""The legs' and arms' joint ranges choosing between mirror images (ours, depth.plausibility)."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.gesture.depth import DepthOptions, plausibility, solve_pose3d
from gesture_pose.core.gesture.depth.synthetic import project_embedding, solving_skeleton
from gesture_pose.core.gesture.embedding import posed_joints
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.skeleton import Pose
from tests.core.fixtures import bone_skeleton, front_camera, turned_about_x
from tests.core.test_gesture_depth_sides import FORWARD, _figure_with_arms, _legged_figure

FRONT = np.array([0.0, -1.0, 0.0])  # the legged figure faces the front camera
DOWN = np.array([0.0, 0.0, -1.0])


def _rest(foot: np.ndarray | None = None) -> plausibility.LegRest:
    """A leg hanging straight down from an upright pelvis facing -y."""
    return plausibility.LegRest(DOWN, FRONT, foot)


def test_a_knee_bent_forwards_is_outside_the_hips_range():
    """The thigh straight down, the shin 60 degrees back (flexed): within every range.
    Its mirror image about the view plane (60 degrees forward) needs the hip turned 180
    degrees about the thigh: 2 asin(sin 60 sin 67.5) = 106 degrees from what the range
    allows, plus a tenth of 180 sin 60."""
    shin = np.array([0.0, np.sin(np.radians(60)), -np.cos(np.radians(60))])
    flexed = plausibility.leg_cost(DOWN, shin, None, _rest())
    mirrored = plausibility.leg_cost(DOWN, shin * [1, -1, 1], None, _rest())
    assert flexed == pytest.approx(0.0, abs=1e-9)
    expected = 2 * np.degrees(np.arcsin(np.sin(np.radians(60)) * np.sin(np.radians(67.5))))
    assert mirrored == pytest.approx(expected + 18.0 * np.sin(np.radians(60)))
    # A straight leg has no knee front: any twist is within range.
    assert plausibility.leg_cost(DOWN, DOWN, None, _rest()) == pytest.approx(0.0)


def test_the_hip_extends_30_degrees_and_the_foot_keeps_its_angle():
    """A straight thigh 50 degrees back costs the 20 beyond the hip's extension, 50
    degrees forward nothing; a foot pointing back from a shin whose rest foot points
    forward costs the 120 beyond the ankle's 60 (180 from its rest angle)."""
    back = np.array([0.0, np.sin(np.radians(50)), -np.cos(np.radians(50))])
    assert plausibility.leg_cost(back, back, None, _rest()) == pytest.approx(20.0)
    assert plausibility.leg_cost(back * [1, -1, 1], back * [1, -1, 1], None,
                                 _rest()) == pytest.approx(0.0)
    foot = np.array([0.0, 1.0, 0.0])  # the rest foot along the shin's front
    assert plausibility.leg_cost(DOWN, DOWN, FRONT, _rest(foot)) == pytest.approx(0.0)
    assert plausibility.leg_cost(DOWN, DOWN, -FRONT, _rest(foot)) == pytest.approx(120.0)


@pytest.mark.parametrize("bend", [0.0, 20.0, 50.0, 70.0])
def test_a_foot_at_its_rest_angle_costs_nothing_on_a_rig_with_bent_knees(bend):
    """A leg whose knee is bent at rest (a quadruped's hind leg), its foot pointing
    forward and down: at rest, and with the whole leg swung 40 degrees forward at the
    hip, the foot is at its rest angle to the shin's front, so it costs nothing even with
    an ankle range of 0. The rest encoding read the shin's front across the thigh rather
    than the shin for knees bent 15 degrees or more (here 1.0, 1.0 and 4.8 degrees at a
    rest bend of 20, 50 and 70)."""
    b = np.radians(bend)
    knee = np.array([0.2, 0.0, 0.5])
    ankle = knee + 0.45 * np.array([0.0, np.sin(b), -np.cos(b)])
    heads = np.array([[0, 0, 1.0], [0, 0, 1.15], [0.2, 0, 1.0], [-0.2, 0, 1.0], knee,
                      knee * [-1, 1, 1], ankle, ankle * [-1, 1, 1]], float)
    toe = np.array([0.0, -0.15, -0.08])
    tails = np.array([[0, 0, 1.15], [0, 0, 1.7], knee, knee * [-1, 1, 1], ankle,
                      ankle * [-1, 1, 1], ankle + toe, ankle * [-1, 1, 1] + toe], float)
    sk = bone_skeleton(("hips", "spine", "thigh.L", "thigh.R", "shin.L", "shin.R", "foot.L",
                        "foot.R"), [-1, 0, 0, 0, 2, 3, 4, 5], heads, tails,
                       [False, True, False, False, True, True, True, True], roll_step=0.1)
    s = solving_skeleton(sk)
    bones = np.asarray(s.bones)
    chains = plausibility.leg_chains(sk, s, bones, np.array([0.0, 0.0, 1.0]))
    assert len(chains) == 2 and all(len(c) == 3 for c in chains)
    strict = plausibility.LegLimits(ankle=0.0)
    for pose in (Pose.identity(sk.n_bones),
                 turned_about_x(sk, Pose.identity(sk.n_bones), ((2, -40.0), (3, -40.0)))):
        state = sk.forward(pose)
        for chain in chains:
            rest = plausibility._leg_rest(sk, chain, bones, np.eye(3), FRONT)
            v = [state.tails[bones[k]] - state.heads[bones[k]] for k in chain]
            assert plausibility.leg_cost(*v, rest, strict) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("ortho", [True, False])
def test_a_knee_bent_back_on_a_rig_with_straight_legs_is_solved_flexed(ortho):
    """The legged figure's legs are straight at rest, so no rest bend decides its knees
    and the start puts a foreshortened shin towards the character's front (the viewer):
    the left knee bent 60 degrees back was solved bent 60 degrees forward (0.39 m the
    wrong way, 0.78 m off at the ankle; 0.81 through the perspective camera). On the
    solved pose that knee is outside the hip's range, its mirror image within it: the
    second solve, started there, gives the truth."""
    sk = _legged_figure()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=ortho)
    pose = turned_about_x(sk, Pose.identity(sk.n_bones), ((4, 60.0),))
    emb = project_embedding(sk, s, pose, cam)
    truth = posed_joints(s, sk, pose)
    k = list(s.bones).index(4)
    knee, ankle = s.head_joint[k], s.tail_joint[k]
    depth = float((truth[ankle] - truth[knee]) @ FORWARD)
    assert depth == pytest.approx(0.45 * np.sin(np.radians(60)))  # away from the viewer

    def solve(options: DepthOptions) -> tuple[float, float, tuple[str, ...]]:
        res = solve_pose3d(sk, emb, cam, options=options)
        off = np.linalg.norm(res.joints3d - res.joints3d[0] - truth + truth[0], axis=1)
        return (float((res.joints3d[ankle] - res.joints3d[knee]) @ FORWARD),
                float(off.max()), res.resided)

    old, old_off, old_resided = solve(DepthOptions(leg_limits=False))
    new, new_off, resided = solve(DepthOptions())
    assert old < -0.35 and old_off > 0.75 and old_resided == ()
    assert new == pytest.approx(depth, abs=1e-3)
    assert new_off < 1e-3
    assert resided == ("shin.L",)
    # A bone the rig gives IK limits keeps the side the start chose with them (here
    # limits that allow both sides, so the start's default stays).
    limits = np.full((sk.n_bones, 3, 2), np.nan)
    limits[4] = [[-np.pi, np.pi]] * 3
    res = solve_pose3d(sk, emb, cam, ik_limits=limits)
    assert res.resided == ()
    assert float((res.joints3d[ankle] - res.joints3d[knee]) @ FORWARD) < -0.35


@pytest.mark.parametrize("ortho", [True, False])
def test_a_resided_thigh_takes_its_knee_along_when_ik_limits_decide_it(ortho):
    """The body folded 120 degrees towards the viewer, the left thigh 30 degrees back
    from it (away) and the knee bent 30 degrees; the knees are hinges (IK limits: flexion
    about the figure's x axis only). The start, with the bind pose's front, puts the thigh
    in front; the hip's range mirrors it, and the second start must choose the shin's
    side, which the knee's limits decide, against the thigh's new side. Chosen against the
    old one, the shin started flexed the wrong way round (mean joint error 0.09 m through
    either camera); now 0.01."""
    sk = _legged_figure()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=ortho)
    pose = turned_about_x(sk, Pose.identity(sk.n_bones),
                          ((0, 120.0), (2, -30.0), (4, 30.0), (3, -120.0)))
    emb = project_embedding(sk, s, pose, cam)
    truth = posed_joints(s, sk, pose)
    axes = np.tile(np.eye(3), (sk.n_bones, 1, 1))
    limits = np.full((sk.n_bones, 3, 2), np.nan)
    for b in (4, 5):  # the shins: their local axes with the figure's x first
        x = sk.rest_frames[b].T @ np.array([1.0, 0.0, 0.0])
        y = sk.rest_frames[b].T @ np.array([0.0, 1.0, 0.0])
        axes[b] = np.stack([x, y, np.cross(x, y)], axis=1)
        limits[b] = [[0.0, 2.6], [-np.pi, np.pi], [-np.pi, np.pi]]

    def solve(leg_limits: bool):
        res = solve_pose3d(sk, emb, cam, ik_limits=limits, limit_axes=axes,
                           options=DepthOptions(pelvis_front=0.0, leg_limits=leg_limits))
        return res, float(np.linalg.norm(res.joints3d - res.joints3d[0] - truth + truth[0],
                                          axis=1).mean())

    old, old_off = solve(False)
    new, new_off = solve(True)
    assert old.resided == () and old_off > 0.2
    assert new.resided == ("thigh.L",)
    assert new_off < 0.02


def test_the_second_solve_is_dropped_when_the_drawing_energy_rises():
    """The straight-legged figure's knee bent back, as above: the ranges' second solve
    is kept only if its drawing energy (E_c plus E_v) is at most ``leg_energy_rise``
    above the first's. With a negative allowance it never is: the result is the first
    solve's, nothing re-sided."""
    sk = _legged_figure()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    pose = turned_about_x(sk, Pose.identity(sk.n_bones), ((4, 60.0),))
    emb = project_embedding(sk, s, pose, cam)
    first = solve_pose3d(sk, emb, cam, options=DepthOptions(leg_limits=False))
    kept = solve_pose3d(sk, emb, cam)
    assert kept.resided == ("shin.L",)
    assert kept.e_conformity + kept.e_foreshortening <= 1.1 * (
        first.e_conformity + first.e_foreshortening)
    dropped = solve_pose3d(sk, emb, cam, options=DepthOptions(leg_energy_rise=-1.0))
    assert dropped.resided == ()
    np.testing.assert_allclose(dropped.joints3d, first.joints3d, atol=1e-9)


def test_a_plausible_solve_is_left_as_it_is():
    """On the truth itself (both knees bent back, the left thigh raised 10 degrees
    forward) no combination of mirror images is more plausible by the margin: no side
    changes. With the left shin mirrored (the knee bent 60 degrees forward) only that
    shin is put back, away from the viewer."""
    sk = _legged_figure()
    s = solving_skeleton(sk)
    pose = turned_about_x(sk, Pose.identity(sk.n_bones),
                          ((2, -10.0), (4, 80.0), (5, 30.0)))
    movable = np.ones(len(s.bones), bool)
    sides = plausibility.leg_sides(sk, s, np.asarray(s.bones), FORWARD, pose, FRONT,
                                   np.array([0.0, 0.0, 1.0]), movable)
    np.testing.assert_array_equal(sides, 0.0)
    mirrored = turned_about_x(sk, pose, ((4, -140.0),))
    sides = plausibility.leg_sides(sk, s, np.asarray(s.bones), FORWARD, mirrored, FRONT,
                                   np.array([0.0, 0.0, 1.0]), movable)
    k = list(s.bones).index(4)
    assert sides[k] == 1.0
    assert np.count_nonzero(sides) == 1


@pytest.mark.parametrize("ortho", [True, False])
def test_a_foot_drawn_end_on_as_at_bind_is_turned_with_its_leg(ortho):
    """The figure with arms and feet, its left thigh 20 degrees back and the knee flexed
    120 more (the heel up behind it): the foot, which points at the viewer at bind, now
    points away, drawn end-on as short as at bind and within 2.5% of the height of its
    bind image, so the start keeps it at bind (side 0). On the solved leg it turns the
    ankle 180 degrees from its rest angle; its mirror image is within range, and the
    second solve lifts it there (largest joint error 0.61 m with the ranges off, 0.58
    through the perspective camera; 0.23 and 0.20 now, the rest from the thigh's side,
    which no range decides)."""
    sk = _figure_with_arms()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=ortho)
    names = list(sk.names)
    pose = turned_about_x(sk, Pose.identity(sk.n_bones),
                          ((names.index("thigh.L"), 20.0), (names.index("shin.L"), 120.0)))
    emb = project_embedding(sk, s, pose, cam)
    truth = posed_joints(s, sk, pose)
    k = list(s.bones).index(names.index("foot.L"))
    heel, toe = s.head_joint[k], s.tail_joint[k]
    depth = float((truth[toe] - truth[heel]) @ FORWARD)
    assert depth > 0.18  # 0.185: away from the viewer

    def solve(options: DepthOptions):
        res = solve_pose3d(sk, emb, cam, options=options)
        off = np.linalg.norm(res.joints3d - res.joints3d[0] - truth + truth[0], axis=1)
        return res, float((res.joints3d[toe] - res.joints3d[heel]) @ FORWARD), float(off.max())

    old, old_depth, old_off = solve(DepthOptions(leg_limits=False))
    assert old.depth_sides[k] == 0.0  # kept at bind
    assert old_depth < -0.18 and old_off > 0.55
    new, new_depth, new_off = solve(DepthOptions())
    assert "foot.L" in new.resided
    assert new.depth_sides[k] == 1.0
    assert new_depth == pytest.approx(depth, abs=0.005)
    assert new_off < 0.25


def _turned(sk, pose: Pose, bone: int, axis, degrees: float) -> Pose:
    """``pose`` with ``bone`` turned ``degrees`` about the world ``axis`` (children follow)."""
    frame = sk.forward(pose).frames[bone]
    carried = frame @ pose.rotations[bone].T  # the frame the parent carries
    world = exp_map(np.radians(degrees) * np.asarray(axis, float))
    return pose.with_rotations(np.array([bone]),
                               (carried.T @ world @ carried @ pose.rotations[bone])[None])


def test_an_elbow_bent_backwards_is_outside_the_shoulders_rotation():
    """The arm hanging from an upright chest facing -y: a forearm flexed 80 degrees
    forward is within range; flexed backwards (the elbow's plane 180 degrees from the
    front), 2 asin(sin 80 sin 40) = 78 degrees from what a rotation of 100 allows."""
    upper = DOWN
    ahead = np.array([0.0, -np.sin(np.radians(80)), -np.cos(np.radians(80))])
    assert plausibility.arm_cost(upper, ahead, DOWN, FRONT) == pytest.approx(0.0)
    back = ahead * [1, -1, 1]
    expected = 2 * np.degrees(np.arcsin(np.sin(np.radians(80)) * np.sin(np.radians(40))))
    assert plausibility.arm_cost(upper, back, DOWN, FRONT) == pytest.approx(expected)


def test_an_upper_arm_swung_far_back_is_outside_the_shoulders_extension():
    """The shoulder extends about 60 degrees: a straight arm swung 60 degrees back from
    the chest's down, or raised forward or sideways, is within range; swung straight back
    (horizontal, 90 degrees) it costs the 30 beyond, and 75 degrees back and 45 out to
    the side the excess in the plane of flexion times the arm's share in that plane."""
    for upper in ([0.0, np.sin(np.radians(60)), -np.cos(np.radians(60))],  # 60 back
                  [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]):  # forward, sideways
        u = np.array(upper)
        assert plausibility.arm_cost(u, u, DOWN, FRONT) == pytest.approx(0.0, abs=1e-9)
    back = np.array([0.0, 1.0, 0.0])
    assert plausibility.arm_cost(back, back, DOWN, FRONT) == pytest.approx(30.0)
    c = np.cos(np.radians(45))
    side = np.array([c, c * np.sin(np.radians(75)), -c * np.cos(np.radians(75))])
    assert plausibility.arm_cost(side, side, DOWN, FRONT) == pytest.approx(15.0 * c)


def test_the_arms_hang_from_the_chest_and_the_legs_are_not_arms():
    sk = _figure_with_arms()
    s = solving_skeleton(sk)
    chains = plausibility.arm_chains(sk, s, np.asarray(s.bones), np.array([0.0, 0.0, 1.0]))
    assert {(sk.names[s.bones[u]], sk.names[s.bones[f]], sk.names[c])
            for u, f, c in chains} == {("upper_arm.L", "forearm.L", "spine"),
                                       ("upper_arm.R", "forearm.R", "spine")}


@pytest.mark.parametrize("ortho", [True, False])
def test_an_arm_swung_back_with_the_elbow_flexed_forward_is_solved_behind(ortho):
    """The figure's right arm hanging 60 degrees back from the vertical (away from the
    viewer), the forearm flexed 80 degrees forward (towards the viewer). The start puts
    the upper arm, which no cue decides, towards the character's front: the elbow then
    bends backwards, which the shoulder's rotation cannot give it; its mirror image is
    the truth's (largest joint error 0.52 m with the ranges off, 0.48 through the
    perspective camera; 0.10 and 0.07 now, the forearm's depth short by half)."""
    sk = _figure_with_arms()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=ortho)
    names = list(sk.names)
    upper, fore = names.index("upper_arm.R"), names.index("forearm.R")
    pose = _turned(sk, Pose.identity(sk.n_bones), upper, [0.0, 1.0, 0.0], -90.0)  # down
    pose = _turned(sk, pose, upper, [1.0, 0.0, 0.0], 60.0)  # back
    pose = _turned(sk, pose, fore, [1.0, 0.0, 0.0], -80.0)  # flexed forward
    emb = project_embedding(sk, s, pose, cam)
    truth = posed_joints(s, sk, pose)
    k = list(s.bones).index(upper)
    shoulder, elbow = s.head_joint[k], s.tail_joint[k]
    depth = float((truth[elbow] - truth[shoulder]) @ FORWARD)
    assert depth == pytest.approx(0.3 * np.sin(np.radians(60)), abs=1e-3)

    def solve(options: DepthOptions):
        res = solve_pose3d(sk, emb, cam, options=options)
        off = np.linalg.norm(res.joints3d - res.joints3d[0] - truth + truth[0], axis=1)
        return res, float((res.joints3d[elbow] - res.joints3d[shoulder]) @ FORWARD), \
            float(off.max())

    _, old_depth, old_off = solve(DepthOptions(arm_limits=False))
    assert old_depth < -0.2 and old_off > 0.45
    new, new_depth, new_off = solve(DepthOptions())
    assert new.resided == ("upper_arm.R",)
    assert new_depth == pytest.approx(depth, abs=0.01)
    assert new_off < 0.11


def test_a_mirrored_arm_the_second_solve_leaves_implausible_is_not_kept(monkeypatch):
    """The arm swung back with the elbow flexed forward (above): the first solve has the
    upper arm in front and the elbow bent backwards (55 degrees out of range). With the
    ranges' choice rigged to mirror the forearm alone, the second solve bends the elbow
    further out of range (72 degrees): not more plausible by the margin, so the first
    solve is kept, whatever the drawing energy says (``leg_energy_rise`` lifted here)."""
    from gesture_pose.core.gesture.depth import solve3d

    sk = _figure_with_arms()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    names = list(sk.names)
    upper, fore = names.index("upper_arm.R"), names.index("forearm.R")
    pose = _turned(sk, Pose.identity(sk.n_bones), upper, [0.0, 1.0, 0.0], -90.0)
    pose = _turned(sk, pose, upper, [1.0, 0.0, 0.0], 60.0)
    pose = _turned(sk, pose, fore, [1.0, 0.0, 0.0], -80.0)
    emb = project_embedding(sk, s, pose, cam)
    opts = DepthOptions(leg_energy_rise=100.0)
    first = solve_pose3d(sk, emb, cam, options=DepthOptions(arm_limits=False))
    assert solve_pose3d(sk, emb, cam, options=opts).resided == ("upper_arm.R",)
    k = list(s.bones).index(fore)

    def forearm_only(*args, **kwargs):
        out = np.zeros(len(args[2]))
        out[k] = 1.0  # the forearm away from the viewer: flexed further backwards
        return out

    monkeypatch.setattr(solve3d.plausibility, "arm_sides", forearm_only)
    res = solve_pose3d(sk, emb, cam, options=opts)
    assert res.resided == ()
    np.testing.assert_allclose(res.joints3d, first.joints3d, atol=1e-9)
