"""The start's depth sides of the legs (the front the pelvis carries, ours)."""

from __future__ import annotations

import numpy as np

from gesture_pose.core.gesture.depth import DepthOptions, solve_pose3d, start
from gesture_pose.core.gesture.depth.synthetic import project_embedding, solving_skeleton
from gesture_pose.core.gesture.embedding import posed_joints
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
