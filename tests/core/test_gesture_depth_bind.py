"""The bind pose and the rig in the 3D lifting: E_b (links drawn as the bind pose shows
them keep their bind vectors, ours), IK limits and the natural bend deciding depth sides."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gesture_pose.core.gesture.depth import DepthOptions, energies, solve_pose3d
from gesture_pose.core.gesture.depth.synthetic import project_embedding, solving_skeleton
from gesture_pose.core.gesture.embedding import posed_joints
from gesture_pose.core.gesture.types import Embedding2D
from gesture_pose.core.rotations import exp_map, log_map
from gesture_pose.core.skeleton import Pose, Skeleton
from tests.core.fixtures import bone_skeleton, frame_along, front_camera, turned_about_x

FORWARD = np.array([0.0, 1.0, 0.0])  # front_camera's depth axis


def _turned_tree() -> Skeleton:
    """The fixtures' Y-shaped tree with the right forearm pointing half towards the viewer
    in the bind pose (depth slope -0.6)."""
    heads = np.array([[0, 0, 0], [0, 0, 1], [0.1, 0, 1], [0.6, 0, 1.0], [-0.1, 0, 1.05],
                      [-0.6, 0, 1.05]], float)
    tails = np.array([[0, 0, 1], [0, 0, 1.5], [0.6, 0, 1], [1.1, 0, 1.0], [-0.6, 0, 1.05],
                      [-1.0, -0.3, 1.05]], float)
    return bone_skeleton(("root", "neck", "arm.L", "fore.L", "arm.R", "fore.R"),
                         [-1, 0, 0, 2, 0, 4], heads, tails,
                         [False, True, False, True, False, True], roll_step=0.2)


def _raised_left_arm(sk: Skeleton) -> Pose:
    """Bind pose with the left arm swung 60 degrees up in the view plane."""
    pose = Pose.identity(sk.n_bones)
    rot = sk.aim_local(2, np.array([0.5, 0.0, np.sqrt(3.0) / 2.0]), sk.forward(pose),
                       pose.rotations[2])
    return pose.with_rotations(np.array([2]), rot[None])


def test_bind_agreement_is_one_for_the_bind_drawing_and_falls_with_the_gap():
    sk = _turned_tree()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    emb = project_embedding(sk, s, _raised_left_arm(sk), cam)
    a = s.joint_parent[s.joint_parent >= 0]
    b = np.flatnonzero(s.joint_parent >= 0)
    frame = energies.view_frame(cam, s.rest_joints.mean(axis=0))
    links = s.rest_joints[b] - s.rest_joints[a]
    g = energies.bind_agreement(emb.joints2d, a, b, links, frame, 1.5, 0.025)
    moved = np.isin(b, [s.tail_joint[2], s.tail_joint[3]])  # the raised arm's links
    np.testing.assert_allclose(g[~moved], 1.0, atol=1e-9)
    assert np.all(g[moved] < 1e-6)
    # One joint 0.0375 (one sigma times the height 1.5) off: exp(-1/2) on its link.
    shifted = emb.joints2d.copy()
    shifted[s.tail_joint[5], 0] += 0.0375 * frame.scale
    g2 = energies.bind_agreement(shifted, a, b, links, frame, 1.5, 0.025)
    k = int(np.flatnonzero(b == s.tail_joint[5])[0])
    assert abs(g2[k] - np.exp(-0.5)) < 1e-9


def test_an_untouched_limb_keeps_its_bind_depth_under_2d_noise():
    sk = _turned_tree()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    truth = _raised_left_arm(sk)
    emb = project_embedding(sk, s, truth, cam)
    # The 2D fit placed the right forearm's tip 3 cm (4 px) short along the forearm: its
    # drawn length says "more foreshortened than in the bind pose".
    joints = emb.joints2d.copy()
    tip, elbow = s.tail_joint[5], s.head_joint[5]
    along = joints[tip] - joints[elbow]
    joints[tip] -= 0.03 * cam.pixels_per_unit(6.0) * along / np.linalg.norm(along)
    noisy = Embedding2D(s, joints, emb.joint_visible, emb.joint_radius, emb.bone_segments,
                        emb.bone_segment_sides, emb.occlusions, (), (), 1.0, 0.0)
    tj = posed_joints(s, sk, truth)

    def solve(opts: DepthOptions) -> tuple[float, float]:
        X = solve_pose3d(sk, noisy, cam, options=opts).joints3d
        err = float(np.linalg.norm(X - X[0] + tj[0] - tj, axis=1).mean())
        return float((X[tip] - X[elbow]) @ FORWARD), err

    bind_depth = float((tj[tip] - tj[elbow]) @ FORWARD)  # -0.3
    kept, err = solve(DepthOptions())
    drifted, err_paper = solve(DepthOptions(bind_weight=0.0))
    # Measured: depth -0.3065 with E_b, -0.3152 without (E_v already holds most of it on
    # this small tree); mean joint error 2.9 mm against 5.4 mm. With E_v weighted 0.3
    # against E_c (DepthOptions.foreshortening_weight; it holds less of it): -0.3108 with
    # E_b, -0.3296 without, 1.8 mm against 5.7 mm (limit 0.01 -> 0.015).
    assert abs(kept - bind_depth) < 0.015
    assert abs(drifted - bind_depth) > 2.0 * abs(kept - bind_depth)
    assert err < 0.7 * err_paper


def _hinge_chain() -> Skeleton:
    """A leg with a foot hanging from a vertical chain of four bones (down the image in a
    front view), its knee bent 6 degrees at rest (forward, as a knee)."""
    from tests.core.fixtures import chain_skeleton

    top = [[0.0, 0.0, 3.0 - 0.5 * i] for i in range(5)]
    sk = chain_skeleton(np.array([*top, [0.0, -0.05, 0.5], [0.0, 0.0, 0.0],
                                  [0.0, -0.15, 0.0]]), np.zeros(7))
    # A limb's bones carry a side in their names (the natural bend is for limbs only).
    return replace(sk, names=("b0", "b1", "b2", "b3", "thigh.L", "shin.L", "foot.L"))


def _flexed_leg(sk: Skeleton) -> Pose:
    """Hip (bone 4) flexed 40 degrees towards the viewer, knee (bone 5) 100 degrees the way
    it bends at rest, both about the world x axis: the shin goes 60 degrees away from the
    viewer, drawn at half its length."""
    return turned_about_x(sk, Pose.identity(sk.n_bones), ((4, -40.0), (5, 100.0)))


@pytest.mark.parametrize("limit", ["ik", "natural"])
def test_the_rig_decides_the_side_of_a_bent_joint(limit):
    sk = _hinge_chain()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    pose = _flexed_leg(sk)
    emb = project_embedding(sk, s, pose, cam)
    tj = posed_joints(s, sk, pose)
    knee, ankle = s.head_joint[5], s.tail_joint[5]
    truth_dz = float((tj[ankle] - tj[knee]) @ FORWARD)
    assert truth_dz > 0.4  # away from the viewer
    limits = None
    if limit == "ik":
        # The knee flexes one way only: about its local x axis, with the truth's sign.
        flex = log_map(pose.rotations[5][None])[0]
        limits = np.full((sk.n_bones, 3, 2), np.nan)
        limits[5] = [[0.0, np.pi] if flex[0] > 0 else [-np.pi, 0.0], [-0.1, 0.1],
                     [-0.1, 0.1]]
        opts = DepthOptions(natural_bend=False)
    else:
        opts = DepthOptions()
    # Towards the viewer without the rig's word (neither limits nor the rest bend).
    plain = solve_pose3d(sk, emb, cam, options=DepthOptions(natural_bend=False))
    res = solve_pose3d(sk, emb, cam, ik_limits=limits, options=opts)
    got = float((res.joints3d[ankle] - res.joints3d[knee]) @ FORWARD)
    assert (plain.joints3d[ankle] - plain.joints3d[knee]) @ FORWARD < -0.3
    assert got == pytest.approx(truth_dz, abs=0.05)
    if limits is not None:
        assert log_map(res.pose.rotations[5][None])[0][0] * flex[0] > 0


def test_depth_orders_the_solve_cannot_meet_are_dropped():
    from gesture_pose.core.gesture.types import Occlusion
    from tests.core.fixtures import tree_skeleton

    sk = tree_skeleton()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    drawn = _raised_left_arm(sk)  # not the bind pose: its orders are read (see below)
    state = sk.forward(drawn)
    mid = {k: cam.project(0.5 * (state.heads[k:k + 1] + state.tails[k:k + 1]))[0]
           for k in range(6)}
    # The drawing says both: the left forearm in front of the left upper arm, and behind.
    cycle = tuple(Occlusion(front_bone=f, back_bone=b, point2d=mid[3], front_radius=6.0,
                            back_radius=6.0) for f, b in ((2, 3), (3, 2)))
    emb = project_embedding(sk, s, drawn, cam, occlusions=cycle)
    forced = solve_pose3d(sk, emb, cam, options=DepthOptions(drop_unmet_orders=False))
    res = solve_pose3d(sk, emb, cam)
    assert len(forced.ordering) == 2
    assert not np.all(forced.ordering_satisfied)
    kept = {c.label for c in res.ordering}
    dropped = {c.label for c in forced.ordering} - kept
    assert dropped and any("contradicted the drawing" in w for w in res.warnings)
    assert np.all(res.ordering_satisfied)
    assert any("not met" in w for w in forced.warnings)
    # Without them the drawing (the raised arm in the view plane) is met. (On the
    # benchmark's quadruped drawn from the side, two orders read from the contours put a
    # front leg both behind and in front of the other: forcing them swung the legs 60
    # degrees out of the view plane, 4.9% of the height off against 1.3% without.)
    tj = posed_joints(s, sk, drawn)
    assert np.linalg.norm(res.joints3d - tj, axis=1).max() < 1e-3


def test_orders_between_parts_drawn_as_at_bind_keep_the_bind_order():
    from gesture_pose.core.gesture.depth.ordering import drawn_as_bind, ordering_constraints
    from gesture_pose.core.gesture.types import Occlusion

    sk = _turned_tree()  # the right forearm points half towards the viewer at bind
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    # A misread: the right forearm's tip behind the neck (the bind pose has it 0.3 in
    # front of the neck's plane).
    point = cam.project(np.array([[-0.9, 0.0, 1.05]]))[0]
    occ = (Occlusion(front_bone=1, back_bone=5, point2d=point, front_radius=8.0,
                     back_radius=8.0),)
    a = s.joint_parent[s.joint_parent >= 0]
    b = np.flatnonzero(s.joint_parent >= 0)
    frame = energies.view_frame(cam, s.rest_joints.mean(axis=0))
    links = s.rest_joints[b] - s.rest_joints[a]
    for pose in (Pose.identity(6), _raised_left_arm(sk)):
        emb = project_embedding(sk, s, pose, cam, occlusions=occ)
        agreement = np.ones(s.n_joints)
        agreement[b] = energies.bind_agreement(emb.joints2d, a, b, links, frame, 1.5, 0.025)
        order = ordering_constraints(emb, frame.scale)
        # The path between the neck and the right forearm (root, right arm) is drawn as
        # at bind either way: the raised left arm is not on it.
        assert drawn_as_bind(order, s.joint_parent, agreement).tolist() == [True]
        res = solve_pose3d(sk, emb, cam)
        assert res.ordering == ()
        tj = posed_joints(s, sk, pose)
        assert float(np.abs((res.joints3d - tj) @ FORWARD).max()) < 0.01
        # With E_b off the order is enforced: the forearm leaves its bind depth.
        forced = solve_pose3d(sk, emb, cam, options=DepthOptions(bind_weight=0.0))
        assert len(forced.ordering) == 1 and np.all(forced.ordering_satisfied)
        assert float(np.abs((forced.joints3d - tj) @ FORWARD).max()) > 0.05
    # A change drawn on the path (the right upper arm raised) reads the order again.
    raised = Pose.identity(6)
    rot = sk.aim_local(4, np.array([-0.5, 0.0, np.sqrt(3.0) / 2.0]), sk.forward(raised),
                       raised.rotations[4])
    raised = raised.with_rotations(np.array([4]), rot[None])
    res = solve_pose3d(sk, project_embedding(sk, s, raised, cam, occlusions=occ), cam)
    assert len(res.ordering) == 1 and np.all(res.ordering_satisfied)


def test_an_order_the_bind_pose_meets_asks_no_more_than_its_gap_of_parts_drawn_as_at_bind():
    sk = _turned_tree()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    # The right forearm's tip in front of the neck, as at bind, but with tubes so thick
    # (100 px, 0.375 units) that Eq. 8's margin (0.375: the point is 0.9 from the neck's
    # axis, on the forearm's) exceeds the bind pose's gap there (0.225).
    from gesture_pose.core.gesture.types import Occlusion

    point = cam.project(np.array([[-0.9, 0.0, 1.05]]))[0]
    occ = (Occlusion(front_bone=5, back_bone=1, point2d=point, front_radius=100.0,
                     back_radius=100.0),)
    emb = project_embedding(sk, s, Pose.identity(6), cam, occlusions=occ)
    forced = solve_pose3d(sk, emb, cam, options=DepthOptions(bind_weight=0.0))
    res = solve_pose3d(sk, emb, cam)
    tj = posed_joints(s, sk, Pose.identity(6))
    bind_gap = res.ordering[0].gap(cam.depth(tj))
    assert 0.0 < bind_gap < forced.ordering[0].margin - 0.1
    assert res.ordering[0].margin == pytest.approx(bind_gap)
    assert np.all(res.ordering_satisfied)
    assert float(np.abs((res.joints3d - tj) @ FORWARD).max()) < 0.01
    assert float(np.abs((forced.joints3d - tj) @ FORWARD).max()) > 0.05


def test_natural_bend_holds_on_the_joint_skeleton_of_a_token_rig():
    """An imported rig (token bones, nothing connected) read as its joint skeleton bends
    its knee the rest pose's way, as the rig with tails does."""
    from gesture_pose.core.joint_skeleton import joint_skeleton, to_joint_pose

    sk = _hinge_chain()
    rng = np.random.default_rng(3)
    frames = np.stack([frame_along(d, 0.0) for d in rng.normal(size=(sk.n_bones, 3))])
    token = replace(sk, rest_tails=sk.rest_heads + 0.01 * frames[:, :, 1], rest_frames=frames,
                    connected=np.zeros(sk.n_bones, bool))
    # The foot's skin (what the reader passes for end bones): points forward to the toe.
    vertices = sk.rest_heads[6] + np.linspace(0.02, 0.15, 10)[:, None] * [0.0, -1.0, 0.0]
    weights = np.zeros((10, sk.n_bones))
    weights[:, 6] = 1.0
    joint = joint_skeleton(token, vertices, weights)
    cam = front_camera(ortho=True)
    results = {}
    for name, skel in (("tails", sk), ("joints", joint.skeleton)):
        pose = _flexed_leg(skel)
        s = solving_skeleton(skel)
        res = solve_pose3d(skel, project_embedding(skel, s, pose, cam), cam,
                           to_joint_pose(Pose.identity(skel.n_bones), joint.frame_change)
                           if name == "joints" else None)
        knee, ankle = s.head_joint[5], s.tail_joint[5]
        results[name] = float((res.joints3d[ankle] - res.joints3d[knee]) @ FORWARD)
    assert results["tails"] > 0.4
    assert results["joints"] == pytest.approx(results["tails"], abs=0.05)


def _away_forearm_tree() -> Skeleton:
    """:func:`_turned_tree` with the right forearm pointing away from the viewer at bind
    (depth slope +0.6)."""
    base = _turned_tree()
    tails = base.rest_tails.copy()
    tails[5] = [-1.0, 0.3, 1.05]
    return replace(base, rest_tails=tails, rest_frames=np.stack(
        [frame_along(t - h, 0.2 * i) for i, (h, t) in enumerate(zip(base.rest_heads, tails,
                                                                     strict=True))]))


def test_a_limb_drawn_moved_keeps_the_start_side_against_its_bind_depth():
    """A forearm that points away from the viewer at bind, drawn turned 60 degrees down in
    the image (a reach seen obliquely): the start puts it on the character's front, and
    E_v's reference keeps it there instead of pulling it back to the bind side."""
    sk = _away_forearm_tree()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    truth = Pose.identity(6)
    rot = sk.aim_local(5, np.array([-0.2, -0.3, -0.2 * np.sqrt(3.0)]), sk.forward(truth),
                       truth.rotations[5])
    truth = truth.with_rotations(np.array([5]), rot[None])
    emb = project_embedding(sk, s, truth, cam)
    tj = posed_joints(s, sk, truth)
    tip, elbow = s.tail_joint[5], s.head_joint[5]
    assert (tj[tip] - tj[elbow]) @ FORWARD == pytest.approx(-0.3)
    depth = {}
    for sides in (True, False):
        X = solve_pose3d(sk, emb, cam, options=DepthOptions(start_sides=sides)).joints3d
        depth[sides] = float((X[tip] - X[elbow]) @ FORWARD)
    # Measured: -0.295 with the start's side, +0.295 with the bind pose's signed depth
    # change as E_v's reference (pulled back across the view plane, mirrored).
    assert depth[True] == pytest.approx(-0.3, abs=0.02)
    assert depth[False] > 0.2


def test_a_shin_below_a_thigh_at_the_viewer_bends_in_the_knees_plane():
    """Crouching seen obliquely: the thigh points at the viewer, so both depth sides of the
    shin bend the knee the natural way; the side nearer the knee's plane of flexion is the
    knee's (the other turns the shin sideways)."""
    from gesture_pose.core.camera import Camera
    from gesture_pose.core.gesture.depth import start, twist

    sk = _hinge_chain()
    s = solving_skeleton(sk)
    cam = Camera.look_at([3.0, -6.0, 0.8], [0.0, 0.0, 0.8], width=800, height=600,
                         ortho_scale=3.0)
    # The hip flexed at the viewer, the knee bent.
    pose = turned_about_x(sk, Pose.identity(sk.n_bones), ((4, -75.0), (5, 120.0)))
    emb = project_embedding(sk, s, pose, cam)
    tj = posed_joints(s, sk, pose)
    knee, ankle = s.head_joint[5], s.tail_joint[5]
    truth = float(np.sign(cam.depth(tj[[ankle]])[0] - cam.depth(tj[[knee]])[0]))
    jmap = twist.joint_map(sk, s)
    frame = energies.view_frame(cam, s.rest_joints.mean(axis=0))
    bind = Pose.identity(sk.n_bones)
    # The thigh on its true side (towards the viewer), the shin starting the other way.
    signs = np.full(jmap.n_bones, -truth)
    signs[4] = -1.0
    fixed = np.zeros(jmap.n_bones, bool)
    fixed[:4] = True
    got = start.hinge_signs(sk, jmap, frame, emb, bind, signs, fixed)
    undecided = start.hinge_signs(sk, jmap, frame, emb, bind, signs, fixed, min_off=np.inf)
    assert got[5] == truth
    assert undecided[5] == -truth  # the bend's sense alone does not decide here


def test_a_joint_slid_along_a_straight_spine_is_put_back_where_the_bind_pose_has_it():
    from gesture_pose.core.gesture.depth.regularity import spine_chain, spine_runs

    sk = _hinge_chain()  # a vertical chain of four unsided bones, then a leg
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    emb = project_embedding(sk, s, Pose.identity(sk.n_bones), cam)
    chain = spine_chain(s)
    assert [s.joint_bones[j] for j in chain] == ["b0 head", "b0 tail", "b1 tail", "b2 tail",
                                                 "b3 tail"]
    frame = energies.view_frame(cam, s.rest_joints.mean(axis=0))
    # The 2D fit slid the second inner joint 40% of a link down the straight run: its
    # links read 1.4 and 0.6 of their lengths.
    slid = emb.joints2d.copy()
    step = slid[chain[3]] - slid[chain[2]]
    slid[chain[2]] += 0.4 * step
    np.testing.assert_allclose(spine_runs(s, slid, s.rest_joints, frame), emb.joints2d,
                               atol=1e-9)
    # (On the benchmark's traced drawings, cached 2D fits of 3e58fb0's parent: the oblique
    # raised arm, whose pelvis link was drawn at 40% of its length and the chest above it at
    # 162%, 5.34 -> 3.92 % of the height; the 25 drawings 7.80 -> 7.65 on average.)
    # A straight spine whose last link is drawn at half its length, none too long: a bone
    # turned towards the viewer, kept as drawn.
    short = emb.joints2d.copy()
    below = ~np.isin(np.arange(s.n_joints), chain[:4])
    short[below] -= 0.5 * (short[chain[4]] - short[chain[3]])
    np.testing.assert_array_equal(spine_runs(s, short, s.rest_joints, frame), short)
    # A spine drawn bent (its third link turned 30 degrees in the image) is two runs: the
    # bend stays as drawn, a joint slid inside the first run is put back.
    bent = emb.joints2d.copy()
    rot = np.array([[np.cos(0.52), -np.sin(0.52)], [np.sin(0.52), np.cos(0.52)]])
    below = np.isin(np.arange(s.n_joints), chain[3:]) | ~np.isin(np.arange(s.n_joints), chain)
    bent[below] = bent[chain[2]] + (bent[below] - bent[chain[2]]) @ rot.T
    bent[chain[1]] += 0.3 * (bent[chain[2]] - bent[chain[1]])
    out = spine_runs(s, bent, s.rest_joints, frame)
    np.testing.assert_allclose(out[chain[1]], emb.joints2d[chain[1]], atol=1e-9)
    np.testing.assert_allclose(np.delete(out, chain[1], axis=0),
                               np.delete(bent, chain[1], axis=0), atol=1e-12)
    # The first run drawn within its lengths but unlike: its second link at half its
    # length under the first at its full length, a 60-degree bend in depth at the joint
    # between them inside a spine drawn straight. Kept by default; respaced when the links'
    # foreshortening may differ by at most 0.3 (ours, ``DepthOptions.spine_run_spread``):
    # the joint goes to the middle of the run, as in the bind pose's image.
    unlike = emb.joints2d.copy()
    unlike[below] = unlike[chain[2]] + (unlike[below] - unlike[chain[2]]) @ rot.T
    shift = 0.5 * (unlike[chain[2]] - unlike[chain[1]])
    unlike[below | (np.arange(s.n_joints) == chain[2])] -= shift
    np.testing.assert_array_equal(spine_runs(s, unlike, s.rest_joints, frame), unlike)
    out = spine_runs(s, unlike, s.rest_joints, frame, max_spread=0.3)
    np.testing.assert_allclose(out[chain[1]], 0.5 * (unlike[chain[0]] + unlike[chain[2]]),
                               atol=1e-12)
    np.testing.assert_array_equal(np.delete(out, chain[1], axis=0),
                                  np.delete(unlike, chain[1], axis=0))
    # A run ending at the body's axis' free end (the head's tip) keeps an unlike last
    # link at any spread: a head nods far in depth at the neck.
    np.testing.assert_array_equal(spine_runs(s, short, s.rest_joints, frame, max_spread=0.3),
                                  short)


def test_a_limb_drawn_near_its_bind_direction_but_moved_takes_the_default_side():
    """The forearm of the previous test turned only 30 degrees down in the image: within
    45 degrees of its bind direction, but 0.2 units from its bind image, so it has moved
    and its bind side (away) is not kept; the character's front (towards the viewer) is."""
    sk = _away_forearm_tree()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    truth = Pose.identity(6)
    rot = sk.aim_local(5, np.array([-0.2 * np.sqrt(3.0), -0.3, -0.2]), sk.forward(truth),
                       truth.rotations[5])
    truth = truth.with_rotations(np.array([5]), rot[None])
    emb = project_embedding(sk, s, truth, cam)
    tip, elbow = s.tail_joint[5], s.head_joint[5]
    depth = {}
    for side in (0.1, 0.0):
        X = solve_pose3d(sk, emb, cam, options=DepthOptions(bind_side=side)).joints3d
        depth[side] = float((X[tip] - X[elbow]) @ FORWARD)
    # Measured: -0.30 (the truth) against +0.30 keeping the bind side.
    assert depth[0.1] == pytest.approx(-0.3, abs=0.02)
    assert depth[0.0] > 0.2


def _turned_about_world(sk: Skeleton, pose: Pose, bone: int, axis: np.ndarray,
                        degrees: float) -> Pose:
    """``pose`` with ``bone`` turned ``degrees`` about the world ``axis`` (children follow)."""
    frame = sk.forward(pose).frames[bone]
    world = exp_map(np.radians(degrees) * np.asarray(axis, float))
    return pose.with_rotations(np.array([bone]),
                               (frame.T @ world @ frame @ pose.rotations[bone])[None])


@pytest.mark.parametrize("degrees", [30.0, 60.0])
def test_a_forearm_carried_by_its_raised_arm_keeps_its_bind_depth(degrees):
    """The whole right arm raised in the view plane: the forearm turns with it and still
    points away from the viewer (+0.3). The start takes the side its raised arm carries
    it to (``carried_turn``), not the default guess (the character's front) that E_v's
    reference would then keep; pinned, the start does not lift it and E_v keeps the
    signed bind reference."""
    sk = _away_forearm_tree()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    truth = _turned_about_world(sk, Pose.identity(6), 4, FORWARD, degrees)
    emb = project_embedding(sk, s, truth, cam)
    tj = posed_joints(s, sk, truth)
    tip, elbow = s.tail_joint[5], s.head_joint[5]
    assert (tj[tip] - tj[elbow]) @ FORWARD == pytest.approx(0.3)
    pinned = np.zeros(6, bool)
    pinned[5] = True

    def solve(pins: np.ndarray | None, opts: DepthOptions) -> tuple[float, float]:
        X = solve_pose3d(sk, emb, cam, pinned=pins, options=opts).joints3d
        err = np.linalg.norm(X - X[0] + tj[0] - tj, axis=1)
        return float((X[tip] - X[elbow]) @ FORWARD), float(err.max())

    # Measured at 8461247: depth -0.295 / -0.298 (30 / 60 degrees) and largest joint
    # error 0.60 free; pinned -0.299 / +0.081, 0.60 / 0.45. Now (as with start_sides
    # off) 0.295 to 0.301, errors 0.002 to 0.022.
    for pins in (None, pinned):
        depth, err = solve(pins, DepthOptions())
        assert depth == pytest.approx(0.3, abs=0.01)
        assert err < 0.03
    # The start's carried side is what decides the free forearm (the default otherwise).
    depth, err = solve(None, DepthOptions(carried_turn=0.0))
    assert depth < -0.2
    assert err > 0.5


@pytest.mark.xfail(strict=True, reason="drawn as a forward reach would be; the start's "
                   "default (the front) wins on the benchmark")
def test_an_upper_arm_raised_in_the_body_plane_seen_obliquely_stays_in_it():
    """The core test humanoid seen from its front left (view direction (0.5, -1, 0.2)),
    its far (right) upper arm raised 45 degrees sideways in the body's plane: drawn as
    foreshortened as at bind, on the same (far) side.

    Expected failure: the drawing is also that of the arm reaching forward (45 degrees
    from its bind direction on the far side, 79 on the near side; the benchmark's oblique
    reach is the reverse, 82 against 47), nothing in it decides, and the start takes the
    character's front, which E_v's reference keeps (``start_sides``). Leaving default
    sides to the signed bind reference passes this test but, on the benchmark's exact
    embeddings where the front is right for 65 of 73 such links and the bind side for
    36, costs mild 3.52 -> 3.96 and far 6.17 -> 7.29 % of the height."""
    from gesture_pose.core.camera import Camera
    from tests.core.test_stick_figure import humanoid_skeleton

    sk = humanoid_skeleton()
    s = solving_skeleton(sk)
    pts = np.concatenate([sk.rest_heads, sk.rest_tails])
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    view = np.array([0.5, -1.0, 0.2]) / np.linalg.norm([0.5, -1.0, 0.2])
    cam = Camera.look_at(centre + 6.0 * view, centre, width=800, height=800,
                         ortho_scale=2.4)
    truth = _turned_about_world(sk, Pose.identity(sk.n_bones), sk.index("upper_arm.R"),
                                np.array([0.0, 1.0, 0.0]), 45.0)
    emb = project_embedding(sk, s, truth, cam)
    tj = posed_joints(s, sk, truth)
    height = float(np.ptp(pts, axis=0).max())
    X = solve_pose3d(sk, emb, cam).joints3d
    err = np.linalg.norm(X - X[0] + tj[0] - tj, axis=1) / height * 100.0
    # Measured (% of the height): 2.82 mean / 28.0 largest (the wrist 0.48 m off); 0.35 /
    # 2.4 with start_sides off.
    assert err.mean() < 0.6
    assert err.max() < 4.0


def _figure_with_a_head() -> Skeleton:
    """A trunk (hips, spine, chest up the z axis), a neck and head above the chest, and an
    arm on each side from shoulders 0.1 m either side of the chest's tail."""
    heads = np.array([[0, 0, 0], [0, 0, 0.3], [0, 0, 0.6], [0, 0, 0.9], [0, 0, 1.0],
                      [0.1, 0, 0.9], [-0.1, 0, 0.9]], float)
    tails = np.array([[0, 0, 0.3], [0, 0, 0.6], [0, 0, 0.9], [0, 0, 1.0], [0, 0, 1.25],
                      [0.6, 0, 0.9], [-0.6, 0, 0.9]], float)
    frames = np.stack([frame_along(t - h) for h, t in zip(heads, tails, strict=True)])
    return Skeleton(("hips", "spine", "chest", "neck", "head", "arm.L", "arm.R"),
                    np.array([-1, 0, 1, 2, 3, 2, 2]), heads, tails, frames, np.ones(7, bool),
                    np.array([False, True, True, True, True, False, False]), np.ones(7, bool))


def test_a_chest_joint_slid_up_the_neck_is_put_back_and_the_head_stays_upright():
    """The 2D fit drew the chest's tail (where neck and arms branch) 6 cm up the straight
    neck, with its rigid neighbourhood (the shoulder heads), as its rigid groups move:
    chest drawn at 120% of its length, neck at 40%. The run goes on through the branch
    point to the head, so the joint is put back with the shoulders and the upright
    figure is read upright; respacing only up to the chest (the first branch point), the
    neck was read as turned 56 degrees out of the view plane."""
    from gesture_pose.core.gesture.depth.regularity import (
        rigid_followers,
        spine_chain,
        spine_runs,
    )

    sk = _figure_with_a_head()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    emb = project_embedding(sk, s, Pose.identity(sk.n_bones), cam)
    names = [s.joint_bones[j] for j in spine_chain(s, through_branches=True)]
    assert names == ["hips head", "hips tail", "spine tail", "chest tail", "neck tail",
                     "head tail"]
    assert [s.joint_bones[j] for j in spine_chain(s)] == names[:4]
    chest, neck = s.joint_bones.index("chest tail"), s.joint_bones.index("neck tail")
    frame = energies.view_frame(cam, s.rest_joints.mean(axis=0))
    group = [chest, *rigid_followers(s, chest, emb.joint_radius / frame.scale)]
    assert sorted(s.joint_bones[j] for j in group) == ["arm.L head", "arm.R head",
                                                       "chest tail"]
    slid = emb.joints2d.copy()
    slid[group] += 0.6 * (slid[neck] - slid[chest])
    np.testing.assert_allclose(spine_runs(s, slid, s.rest_joints, frame), emb.joints2d,
                               atol=1e-9)
    moved = replace(emb, joints2d=slid)
    tilt, error = {}, {}
    truth = s.rest_joints - s.rest_joints[0]
    for runs in (DepthOptions().spine_runs, 0.0):
        X = solve_pose3d(sk, moved, cam, options=DepthOptions(spine_runs=runs)).joints3d
        tilt[runs] = float(np.degrees(np.arcsin(min(abs((X[neck] - X[chest]) @ FORWARD)
                                                    / 0.1, 1.0))))
        error[runs] = np.linalg.norm(X - X[0] - truth, axis=1)
    # Measured: 0.0 degrees and 0.0 cm at every joint with the run through the branch
    # and the shoulders moved with the chest (moving the chest alone left them 16 px
    # off: 1.0 cm mean, 5.2 at an arm's tail); 56 degrees without respacing, as with the
    # run stopped at the chest (the slid joint ends that run), 1.9 / 9.4 cm.
    assert tilt[DepthOptions().spine_runs] < 2.0
    assert error[DepthOptions().spine_runs].max() < 0.005
    assert tilt[0.0] > 45.0
    assert error[0.0].max() > 0.05


def test_only_enforced_orders_can_veto_the_symmetrization():
    """The symmetrization keeps a pose only if it breaks no depth order the solve meets;
    an unenforced (soft) order is reported, not forced, so one the solve happens to meet
    does not veto it (before, every order counted)."""
    from gesture_pose.core.gesture.depth import twist
    from gesture_pose.core.gesture.depth.ordering import OrderingConstraint
    from gesture_pose.core.gesture.depth.solve3d import _keeps_enforced_orders

    sk = _figure_with_a_head()
    s = solving_skeleton(sk)
    jm = twist.joint_map(sk, s)
    frame = energies.view_frame(front_camera(ortho=True), s.rest_joints.mean(axis=0))
    left, right = s.joint_bones.index("arm.L tail"), s.joint_bones.index("arm.R tail")
    solved = Pose.identity(sk.n_bones).with_rotations(np.array([5]),
                                                      exp_map(np.array([[0.0, 0.0, 0.6]])))
    X, _ = twist.joint_positions(sk, jm, solved)
    gap = float(frame.depth(X)[left] - frame.depth(X)[right])
    assert abs(gap) > 0.1  # the turned arm's hand is out of the other's depth
    back, front = (left, right) if gap > 0 else (right, left)
    order = OrderingConstraint("occlusion", "hands", np.array([back]), np.ones(1),
                               np.array([front]), np.ones(1), 0.5 * abs(gap))
    # The symmetric candidate (both arms in the bind pose, hands at one depth) breaks it.
    candidate = Pose.identity(sk.n_bones)
    keeps = _keeps_enforced_orders(sk, jm, frame, [replace(order, soft=True)], solved, 1e-6)
    assert keeps(candidate)
    keeps = _keeps_enforced_orders(sk, jm, frame, [order], solved, 1e-6)
    assert not keeps(candidate)


def _figure_with_clavicles() -> Skeleton:
    """:func:`_figure_with_a_head` with a clavicle on each side: unconnected bones from
    3 cm beside the chest's tail to 15 cm beside it, the arms connected to their tails."""
    heads = np.array([[0, 0, 0], [0, 0, 0.3], [0, 0, 0.6], [0, 0, 0.9], [0, 0, 1.0],
                      [0.03, 0, 0.9], [-0.03, 0, 0.9], [0.15, 0, 0.9], [-0.15, 0, 0.9]],
                     float)
    tails = np.array([[0, 0, 0.3], [0, 0, 0.6], [0, 0, 0.9], [0, 0, 1.0], [0, 0, 1.25],
                      [0.15, 0, 0.9], [-0.15, 0, 0.9], [0.6, 0, 0.9], [-0.6, 0, 0.9]],
                     float)
    frames = np.stack([frame_along(t - h) for h, t in zip(heads, tails, strict=True)])
    return Skeleton(("hips", "spine", "chest", "neck", "head", "clavicle.L", "clavicle.R",
                     "arm.L", "arm.R"), np.array([-1, 0, 1, 2, 3, 2, 2, 5, 6]), heads,
                    tails, frames, np.ones(9, bool),
                    np.array([False, True, True, True, True, False, False, True, True]),
                    np.ones(9, bool))


def _clavicle_case():
    """The figure with clavicles, seen from the front: ``(skeleton, solving, camera,
    embedding, view frame, chest tail, neck tail, radii)``, the radii (world units) making
    the clavicles' tails interior to the chest (0.15 m against 0.05 elsewhere)."""
    sk = _figure_with_clavicles()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    emb = project_embedding(sk, s, Pose.identity(sk.n_bones), cam)
    frame = energies.view_frame(cam, s.rest_joints.mean(axis=0))
    chest, neck = s.joint_bones.index("chest tail"), s.joint_bones.index("neck tail")
    radius = np.full(s.n_joints, 0.05)
    radius[chest] = 0.15
    return sk, s, cam, emb, frame, chest, neck, radius


def test_a_slid_chest_is_put_back_with_the_clavicles_the_fit_moved_with_it():
    """The 2D fit moves a chest with its rigid neighbourhood: the clavicles' heads (rigid
    offsets) and their tails, interior bones inside the torso's outline (their circles
    overlap the chest's). Respacing the spine run puts the chest back with all four, and
    only those: the arms' tails, placed on their own contours, stay."""
    from gesture_pose.core.gesture.depth.regularity import rigid_followers, spine_runs

    sk, s, cam, emb, frame, chest, neck, radius = _clavicle_case()
    group = rigid_followers(s, chest, radius)
    assert sorted(s.joint_bones[j] for j in group) == [
        "clavicle.L head", "clavicle.L tail", "clavicle.R head", "clavicle.R tail"]
    # With small radii the clavicles' tails are free joints (the fit places them).
    assert sorted(s.joint_bones[j] for j in rigid_followers(s, chest, radius / 3)) == [
        "clavicle.L head", "clavicle.R head"]
    slid = emb.joints2d.copy()
    slid[[chest, *group]] += 0.6 * (slid[neck] - slid[chest])
    back = spine_runs(s, slid, s.rest_joints, frame, radius=radius * frame.scale)
    np.testing.assert_allclose(back, emb.joints2d, atol=1e-9)
    # Without the radii the clavicles' tails are left where the slide put them.
    back = spine_runs(s, slid, s.rest_joints, frame)
    off = np.linalg.norm(back - emb.joints2d, axis=1)
    tails = [s.joint_bones.index("clavicle.L tail"), s.joint_bones.index("clavicle.R tail")]
    assert off[tails].min() > 10.0 and np.delete(off, tails).max() < 1e-9


def test_joints_below_an_axis_joint_follow_it_once():
    """A disconnected short chest hangs from the spine's tail by a rigid offset and lies
    on the body's axis, with the arms' heads hanging from its tail: respacing moves each
    axis joint itself, and the arms' heads follow only the chest's tail (before, they were
    moved once for the spine's tail too and ended 35 px off)."""
    from gesture_pose.core.gesture.depth.regularity import rigid_followers, spine_runs

    heads = np.array([[0, 0, 0], [0, 0, 0.3], [0, 0, 0.62], [0, 0, 0.72], [0, 0, 0.85],
                      [0.1, 0, 0.72], [-0.1, 0, 0.72]], float)
    tails = np.array([[0, 0, 0.3], [0, 0, 0.6], [0, 0, 0.72], [0, 0, 0.85], [0, 0, 1.1],
                      [0.6, 0, 0.72], [-0.6, 0, 0.72]], float)
    frames = np.stack([frame_along(t - h) for h, t in zip(heads, tails, strict=True)])
    sk = Skeleton(("hips", "spine", "chest", "neck", "head", "arm.L", "arm.R"),
                  np.array([-1, 0, 1, 2, 3, 2, 2]), heads, tails, frames, np.ones(7, bool),
                  np.array([False, True, False, True, True, False, False]), np.ones(7, bool))
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    emb = project_embedding(sk, s, Pose.identity(sk.n_bones), cam)
    frame = energies.view_frame(cam, s.rest_joints.mean(axis=0))
    radius = np.full(s.n_joints, 0.1)
    names = s.joint_bones
    spine, chest, neck = (names.index(n) for n in ("spine tail", "chest tail", "neck tail"))
    group = [spine, *rigid_followers(s, spine, radius)]
    assert chest in group  # the fit's rigid group runs through the chest to the arms
    slid = emb.joints2d.copy()
    slid[group] += 0.5 * (slid[neck] - slid[chest])  # slid up the neck, as the fit does
    back = spine_runs(s, slid, s.rest_joints, frame, radius=radius * frame.scale)
    arms = [names.index("arm.L head"), names.index("arm.R head")]
    np.testing.assert_allclose(back[arms] - back[chest], emb.joints2d[arms]
                               - emb.joints2d[chest], atol=1e-6)


def test_the_pose_puts_a_slid_chest_back_with_the_clavicles_by_the_drawn_radii():
    """solve_pose3d respaces the spine with the embedding's joint radii: the clavicles'
    tails, interior by those radii, come back with the chest the fit slid up the neck and
    the lifted figure is the bind pose (with radii too small for them to be interior
    they stay where the slide put them, and the lifted figure is off by more than 2 cm;
    so is it when solve_pose3d does not pass the radii on)."""
    from gesture_pose.core.gesture.depth.regularity import rigid_followers

    sk, s, cam, emb, frame, chest, neck, radius = _clavicle_case()
    group = [chest, *rigid_followers(s, chest, radius)]
    assert len(group) == 5  # the chest, the clavicles' heads and tails
    slid = emb.joints2d.copy()
    slid[group] += 0.6 * (slid[neck] - slid[chest])
    truth = s.rest_joints - s.rest_joints[0]
    error = {}
    for scale in (frame.scale, None):
        drawn = radius * scale if scale else np.full(s.n_joints, 1e-3)
        moved = replace(emb, joints2d=slid, joint_radius=drawn)
        X = solve_pose3d(sk, moved, cam).joints3d
        error[scale is not None] = np.linalg.norm(X - X[0] - truth, axis=1)
    assert error[True].max() < 0.005
    assert error[False].max() > 0.02
