"""Joint skeletons of token-bone rigs (core/joint_skeleton.py): detection, segments, poses."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.joint_skeleton import (
    from_joint_pose,
    has_token_bones,
    joint_skeleton,
    principal_children,
    remap_axis_settings,
    to_joint_pose,
)
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.skeleton import Pose, Skeleton
from tests.core.fixtures import chain_skeleton, frame_along, tree_skeleton

#: A small figure: root at the floor, hips, spine, chest, neck, head; a left/right pair of
#: arms off the chest and of legs off the hips (heads in world units).
NAMES = ("Root", "Hips", "Spine", "Chest", "Neck", "Head", "Arm.L", "Hand.L", "Arm.R",
         "Hand.R", "Leg.L", "Foot.L", "Leg.R", "Foot.R")
PARENTS = np.array([-1, 0, 1, 2, 3, 4, 3, 6, 3, 8, 1, 10, 1, 12])
HEADS = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 1.1], [0, 0, 1.4], [0, 0, 1.6],
                  [0, 0, 1.7], [0.2, 0, 1.55], [0.7, 0, 1.55], [-0.2, 0, 1.55],
                  [-0.7, 0, 1.55], [0.1, 0, 0.95], [0.1, 0, 0.5], [-0.1, 0, 0.95],
                  [-0.1, 0, 0.5]], float)


def token_figure(seed: int = 0) -> Skeleton:
    """:data:`HEADS` with 1 cm bones pointing in random directions, none connected."""
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(len(NAMES), 3))
    frames = np.stack([frame_along(d, r) for d, r in zip(dirs, rng.uniform(-3, 3, len(NAMES)),
                                                         strict=True)])
    n = len(NAMES)
    return Skeleton(NAMES, PARENTS, HEADS, HEADS + 0.01 * frames[:, :, 1], frames,
                    np.ones(n, bool), np.zeros(n, bool), np.ones(n, bool))


def random_pose(n: int, seed: int) -> Pose:
    """Random local rotations (up to about 1.2 rad) and translations (up to 5 cm)."""
    rng = np.random.default_rng(seed)
    return Pose(exp_map(rng.uniform(-0.7, 0.7, (n, 3))), rng.uniform(-0.05, 0.05, (n, 3)))


def test_token_rig_detected_and_proper_rigs_not():
    assert has_token_bones(token_figure())
    assert not has_token_bones(chain_skeleton(np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0]])))
    assert not has_token_bones(tree_skeleton())
    # Proper tails but nothing connected (a glTF rig whose importer found the children):
    # still read as it is.
    sk = token_figure()
    proper = Skeleton(sk.names, sk.parents, sk.rest_heads, joint_skeleton(sk).skeleton.rest_tails,
                      joint_skeleton(sk).skeleton.rest_frames, sk.inherit_rotation,
                      sk.connected, sk.deform)
    assert not has_token_bones(proper)


def test_principal_children_follow_the_chain_not_the_pairs():
    got = principal_children(token_figure())
    name = {n: i for i, n in enumerate(NAMES)}
    expect = {"Root": "Hips", "Hips": "Spine", "Spine": "Chest", "Chest": "Neck",
              "Neck": "Head", "Arm.L": "Hand.L", "Leg.R": "Foot.R"}
    for bone, child in expect.items():
        assert got[name[bone]] == name[child], bone
    for end in ("Head", "Hand.L", "Hand.R", "Foot.L", "Foot.R"):
        assert got[name[end]] == -1


def test_pairs_without_side_names_are_told_by_their_shape():
    """The Khronos fox names its arms b_RightUpperArm_06 and b_LeftUpperArm_09."""
    sk = token_figure()
    names = tuple(n.replace("Arm.L", "ArmA_06").replace("Arm.R", "ArmB_09") for n in NAMES)
    renamed = Skeleton(names, sk.parents, sk.rest_heads, sk.rest_tails, sk.rest_frames,
                       sk.inherit_rotation, sk.connected, sk.deform)
    np.testing.assert_array_equal(principal_children(renamed), principal_children(sk))
    # Without the shape test the longer arm chain would win over the neck.
    assert principal_children(renamed)[3] == 4


def test_joint_skeleton_runs_head_to_child_head_and_ends_on_the_mesh():
    sk = token_figure()
    rng = np.random.default_rng(3)
    # A head of mesh: a ball of radius 0.1 centred 0.12 above the head joint.
    ball = rng.normal(size=(200, 3))
    ball = HEADS[5] + [0, 0, 0.12] + 0.1 * ball / np.linalg.norm(ball, axis=1)[:, None]
    weights = np.zeros((200, len(NAMES)))
    weights[:, 5] = 1.0
    js = joint_skeleton(sk, ball, weights)
    j = js.skeleton
    np.testing.assert_array_equal(j.rest_heads, sk.rest_heads)
    name = {n: i for i, n in enumerate(NAMES)}
    np.testing.assert_allclose(j.rest_tails[name["Chest"]], HEADS[name["Neck"]], atol=1e-12)
    np.testing.assert_allclose(j.rest_tails[name["Arm.L"]], HEADS[name["Hand.L"]], atol=1e-12)
    # The head runs up through its ball: centre direction, reaching near its top.
    head_dir = j.rest_tails[5] - j.rest_heads[5]
    assert np.degrees(np.arccos(head_dir[2] / np.linalg.norm(head_dir))) < 5.0
    assert 0.17 < np.linalg.norm(head_dir) < 0.23
    # Without mesh, an end bone continues its parent, half as long.
    np.testing.assert_allclose(j.rest_tails[name["Foot.L"]], [0.1, 0, 0.5 - 0.225], atol=1e-12)
    # New frames: orthonormal, +Y along the segment, the smallest turn from the old frame.
    f = j.rest_frames
    np.testing.assert_allclose(np.swapaxes(f, 1, 2) @ f, np.tile(np.eye(3), (len(NAMES), 1, 1)),
                               atol=1e-12)
    seg = (j.rest_tails - j.rest_heads) / j.lengths[:, None]
    np.testing.assert_allclose(f[:, :, 1], seg, atol=1e-12)
    np.testing.assert_allclose(sk.rest_frames @ js.frame_change, f, atol=1e-12)
    # Only the head moves vertices here: the other bones stop deforming.
    assert j.deform.tolist() == [n == "Head" for n in NAMES]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_conjugated_pose_gives_the_same_world_bones(seed):
    sk = token_figure(seed)
    js = joint_skeleton(sk)
    pose = random_pose(sk.n_bones, seed + 10)
    real = sk.forward(pose)
    joint = js.skeleton.forward(to_joint_pose(pose, js.frame_change))
    np.testing.assert_allclose(joint.heads, real.heads, atol=1e-12)
    np.testing.assert_allclose(joint.frames, real.frames @ js.frame_change, atol=1e-12)
    back = from_joint_pose(to_joint_pose(pose, js.frame_change), js.frame_change)
    np.testing.assert_allclose(back.rotations, pose.rotations, atol=1e-12)
    np.testing.assert_allclose(back.translations, pose.translations, atol=1e-12)


def test_conjugation_holds_for_bones_that_do_not_inherit_rotation():
    sk = token_figure()
    free = np.zeros(sk.n_bones, bool)
    free[[3, 7]] = True
    sk = Skeleton(sk.names, sk.parents, sk.rest_heads, sk.rest_tails, sk.rest_frames, ~free,
                  sk.connected, sk.deform)
    js = joint_skeleton(sk)
    pose = random_pose(sk.n_bones, 4)
    real = sk.forward(pose)
    joint = js.skeleton.forward(to_joint_pose(pose, js.frame_change))
    np.testing.assert_allclose(joint.heads, real.heads, atol=1e-12)
    np.testing.assert_allclose(joint.frames, real.frames @ js.frame_change, atol=1e-12)


def test_axis_settings_follow_a_permutation_and_are_dropped_otherwise():
    swap = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # C: x -> -y ...
    change = np.stack([swap, exp_map(np.array([0.3, 0.2, 0.0])), np.eye(3)])
    lock = np.array([[True, False, False], [True, False, False], [False, False, False]])
    limits = np.full((3, 3, 2), np.nan)
    limits[0, 1] = [-0.5, 1.0]
    new_lock, new_limits, dropped = remap_axis_settings(lock, limits, change)
    # C^T e_x = e_y, C^T e_y = -e_x: the x lock moves to y, the y limits to x, negated.
    assert new_lock[0].tolist() == [False, True, False]
    np.testing.assert_allclose(new_limits[0, 0], [-1.0, 0.5])
    assert np.isnan(new_limits[0, 1:]).all()
    assert dropped.tolist() == [False, True, False]
    assert not new_lock[1].any()
    # Check the mapping on a rotation: locking real x means Q' has no rotation about C^T x.
    q = exp_map(np.array([0.0, 0.4, 0.0]))  # about real y: allowed
    qp = swap.T @ q @ swap
    axis = np.array([qp[2, 1] - qp[1, 2], qp[0, 2] - qp[2, 0], qp[1, 0] - qp[0, 1]])
    assert abs(axis[1]) < 1e-12 and abs(axis[0]) > 0.1


def test_principal_children_are_connected_in_the_joint_skeleton():
    """Connected as a rig with tails would be: the chain's next bone, not a side branch."""
    joint = joint_skeleton(token_figure()).skeleton
    connected = {n for n, c in zip(joint.names, joint.connected, strict=True) if c}
    assert connected == {"Hips", "Spine", "Chest", "Neck", "Head", "Hand.L", "Hand.R",
                         "Foot.L", "Foot.R"}
    tails = joint.rest_tails[joint.parents[joint.connected]]
    np.testing.assert_allclose(joint.rest_heads[joint.connected], tails, atol=1e-12)
