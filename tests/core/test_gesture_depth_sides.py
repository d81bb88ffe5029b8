"""The start's depth sides of the legs (the front the pelvis carries, ours)."""

from __future__ import annotations

import numpy as np

from gesture_pose.core.gesture.depth import DepthOptions, energies, solve_pose3d, start, twist
from gesture_pose.core.gesture.depth.synthetic import project_embedding, solving_skeleton
from gesture_pose.core.gesture.embedding import posed_joints
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.skeleton import Pose, Skeleton
from tests.core.fixtures import frame_along, front_camera, turned_about_x

FORWARD = np.array([0.0, 1.0, 0.0])  # front_camera's depth axis (away from the viewer)


def _legged_figure() -> Skeleton:
    """A short pelvis link pointing up (as the Adventurer's joint skeleton has it), a
    spine above it and two legs hanging from hip joints beside its head. The figure faces
    the front camera (its left leg at +x)."""
    heads = np.array([[0, 0, 1.0], [0, 0, 1.15], [0.15, 0, 1.0], [-0.15, 0, 1.0],
                      [0.15, 0, 0.55], [-0.15, 0, 0.55]], float)
    tails = np.array([[0, 0, 1.15], [0, 0, 1.7], [0.15, 0, 0.55], [-0.15, 0, 0.55],
                      [0.15, 0, 0.1], [-0.15, 0, 0.1]], float)
    frames = np.stack([frame_along(t - h, 0.1 * i)
                       for i, (h, t) in enumerate(zip(heads, tails, strict=True))])
    return Skeleton(names=("hips", "spine", "thigh.L", "thigh.R", "shin.L", "shin.R"),
                    parents=np.array([-1, 0, 0, 0, 2, 3]), rest_heads=heads,
                    rest_tails=tails, rest_frames=frames,
                    inherit_rotation=np.ones(6, bool),
                    connected=np.array([False, True, False, False, True, True]),
                    deform=np.ones(6, bool))


def _arabesque(sk: Skeleton) -> Pose:
    """Folded forward by 120 degrees at the hips (towards the viewer), the right leg
    standing straight, the left one stretched back and down: 70 degrees from the vertical,
    away from the viewer (drawn at a third of its length), 50 degrees of hip flexion from
    the pelvis."""
    return turned_about_x(sk, Pose.identity(sk.n_bones),
                          ((0, 120.0), (2, -50.0), (3, -120.0)))


def test_the_legs_are_the_limbs_below_the_hips():
    s = solving_skeleton(_legged_figure())
    legs = start.limbs_below_first_pairs(s)
    sk = _legged_figure()
    assert {sk.names[b] for b, leg in zip(s.bones, legs, strict=True) if leg} == {
        "thigh.L", "thigh.R", "shin.L", "shin.R"}


def test_a_leg_stretched_back_under_a_body_folded_forward_starts_behind_it():
    """The character's front (towards the viewer) would put the foreshortened left leg in
    front; the pelvis, folded past the vertical, carries that front down and away, and
    the leg is there, behind the body."""
    sk = _legged_figure()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    pose = _arabesque(sk)
    emb = project_embedding(sk, s, pose, cam)
    truth = posed_joints(s, sk, pose)
    hip, knee = s.head_joint[2], s.tail_joint[2]
    assert s.bones[2] == 2  # thigh.L
    truth_dz = float((truth[knee] - truth[hip]) @ FORWARD)
    assert truth_dz > 0.4  # 0.42: away from the viewer
    res = solve_pose3d(sk, emb, cam)
    bind_front = solve_pose3d(sk, emb, cam, options=DepthOptions(pelvis_front=0.0))
    got = float((res.joints3d[knee] - res.joints3d[hip]) @ FORWARD)
    before = float((bind_front.joints3d[knee] - bind_front.joints3d[hip]) @ FORWARD)
    assert before < -0.3  # towards the viewer: the bind pose's front
    assert abs(got - truth_dz) < 0.03
    # Both legs come back (every leg joint within 1 mm; 85 cm and 1.7 m off at the left
    # knee and ankle with the bind pose's front). The spine's tail is 4.6 cm off either
    # way: its side is not the legs' rule's.
    off = np.linalg.norm(res.joints3d - res.joints3d[0] - truth + truth[0], axis=1)
    leg_joints = np.r_[s.head_joint[2:], s.tail_joint[2:]]
    assert off[leg_joints].max() < 1e-3


def _figure_with_arms() -> Skeleton:
    """A pelvis, a spine, legs (thigh, shin, foot) from hip joints beside the pelvis's
    head and arms (upper arm, forearm, hand) from shoulder joints beside the spine's
    tail, facing the front camera. Knees and elbows are bent 6 degrees at rest, as
    they bend: the shins back, the forearms forward (towards the viewer, -y)."""
    back, fwd = np.array([0.0, 0.05, 0.0]), np.array([0.0, -0.05, 0.0])
    heads, tails, parents, names, connected = [], [], [], [], []

    def add(name, head, tail, parent, conn):
        names.append(name)
        heads.append(np.asarray(head, float))
        tails.append(np.asarray(tail, float))
        parents.append(parent)
        connected.append(conn)
        return len(names) - 1

    pelvis = add("hips", [0, 0, 1.0], [0, 0, 1.15], -1, False)
    spine = add("spine", [0, 0, 1.15], [0, 0, 1.6], pelvis, True)
    for side, x in (("L", 0.15), ("R", -0.15)):
        thigh = add(f"thigh.{side}", [x, 0, 1.0], [x, 0, 0.55], pelvis, False)
        shin = add(f"shin.{side}", [x, 0, 0.55], np.array([x, 0, 0.1]) + back, thigh, True)
        add(f"foot.{side}", np.array([x, 0, 0.1]) + back, np.array([x, -0.15, 0.05]),
            shin, True)
        upper = add(f"upper_arm.{side}", [1.2 * x, 0, 1.55], [3.2 * x, 0, 1.55], spine,
                    False)
        fore = add(f"forearm.{side}", [3.2 * x, 0, 1.55],
                   np.array([5.2 * x, 0, 1.55]) + fwd, upper, True)
        add(f"hand.{side}", np.array([5.2 * x, 0, 1.55]) + fwd,
            np.array([6.0 * x, 0, 1.55]) + fwd, fore, True)
    heads, tails = np.array(heads), np.array(tails)
    frames = np.stack([frame_along(t - h, 0.1 * i)
                       for i, (h, t) in enumerate(zip(heads, tails, strict=True))])
    n = len(names)
    return Skeleton(names=tuple(names), parents=np.array(parents), rest_heads=heads,
                    rest_tails=tails, rest_frames=frames, inherit_rotation=np.ones(n, bool),
                    connected=np.array(connected), deform=np.ones(n, bool))


def test_the_rest_bend_decides_the_knees_and_leaves_the_elbows_to_the_other_cues():
    """The left knee and elbow flexed 70 degrees out of the view plane (the shin back,
    the forearm forward, as they bend at rest): the rest bend decides the shin's side,
    not the forearm's unless ``arms`` (the arm's roll at the shoulder is unknown)."""
    sk = _figure_with_arms()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    idx = {sk.names[b]: k for k, b in enumerate(s.bones)}
    bone = {n: i for i, n in enumerate(sk.names)}
    # Knee about the world x axis (shin back, away from the viewer); elbow about the
    # vertical (forearm forward, towards the viewer), each by 70 degrees.
    pose = turned_about_x(sk, Pose.identity(sk.n_bones), ((bone["shin.L"], 70.0),))
    state = sk.forward(pose)
    world = exp_map(np.array([0.0, 0.0, np.radians(-70.0)]))
    frame = state.frames[bone["forearm.L"]]
    rot = sk.local_rotation_for_frame(bone["forearm.L"], world @ frame, state)
    pose = pose.with_rotations(np.array([bone["forearm.L"]]), rot[None])
    emb = project_embedding(sk, s, pose, cam)
    truth = posed_joints(s, sk, pose)
    sides = {}
    for name in ("shin.L", "forearm.L"):
        k = idx[name]
        sides[name] = float(np.sign((truth[s.tail_joint[k]] - truth[s.head_joint[k]])
                                    @ FORWARD))
    assert sides == {"shin.L": 1.0, "forearm.L": -1.0}  # away / towards the viewer
    jmap = twist.joint_map(sk, s)
    view = energies.view_frame(cam, s.rest_joints.mean(axis=0))
    bind = Pose.identity(sk.n_bones)
    fixed = np.ones(jmap.n_bones, bool)
    fixed[[idx["shin.L"], idx["forearm.L"]]] = False  # their parents stay at bind
    wrong = np.ones(jmap.n_bones)
    wrong[idx["shin.L"]], wrong[idx["forearm.L"]] = -1.0, 1.0
    legs = start.hinge_signs(sk, jmap, view, emb, bind, wrong, fixed)
    both = start.hinge_signs(sk, jmap, view, emb, bind, wrong, fixed, arms=True)
    assert legs[idx["shin.L"]] == sides["shin.L"]
    assert legs[idx["forearm.L"]] == wrong[idx["forearm.L"]]  # left to the other cues
    assert both[idx["forearm.L"]] == sides["forearm.L"]


def test_a_limb_swung_towards_the_viewer_keeps_part_of_its_drawn_depth():
    """The left arm swung 45 degrees towards the viewer through a perspective camera
    (upper arm and forearm drawn at 76% and 70% of their lengths at the character's
    scale, E_v's weights 0.70 and 0.49 against the drawing's average): measured from the
    bind pose's depth change (0 for the arm at bind), E_v pulls the arm back towards the
    view plane; with a share of the depth the start lifted it by, less."""
    sk = _figure_with_arms()
    s = solving_skeleton(sk)
    cam = front_camera()  # perspective
    bone = {n: i for i, n in enumerate(sk.names)}
    pose = Pose.identity(sk.n_bones)
    state = sk.forward(pose)
    world = exp_map(np.array([0.0, 0.0, np.radians(-45.0)]))
    arm = bone["upper_arm.L"]
    rot = sk.local_rotation_for_frame(arm, world @ state.frames[arm], state)
    pose = pose.with_rotations(np.array([arm]), rot[None])
    emb = project_embedding(sk, s, pose, cam)
    truth = posed_joints(s, sk, pose)
    k = list(s.bones).index(bone["hand.L"])
    tip = s.tail_joint[k]
    assert (truth[tip] - truth[s.head_joint[list(s.bones).index(arm)]]) @ FORWARD < -0.5

    def errors(share: float) -> tuple[float, float]:
        X = solve_pose3d(sk, emb, cam, options=DepthOptions(lifted_reference=share)).joints3d
        X = X - X[0] + truth[0]
        return (float(np.linalg.norm(X - truth, axis=1).mean()),
                abs(float((X[tip] - truth[tip]) @ FORWARD)))

    # Measured (mean joint error m, hand tip's depth error m): share 0: 0.084, 0.63;
    # 0.3 (the default): 0.056, 0.40; 1: 0.027, 0.20.
    mean0, tip0 = errors(0.0)
    mean, tip_err = errors(DepthOptions().lifted_reference)
    assert mean < 0.75 * mean0
    assert tip_err < 0.75 * tip0
    assert errors(1.0)[0] < 0.5 * mean0
