"""The same-direction rule and the symmetrization on a rig that is one chain of bones
without left/right sides in their names (a snake, a tail)."""

from __future__ import annotations

import numpy as np

from gesture_pose.core.gesture.depth import DepthOptions, solve_pose3d, symmetry
from gesture_pose.core.gesture.depth.regularity import axial_joints, parallel_pairs
from gesture_pose.core.gesture.depth.synthetic import project_embedding, solving_skeleton
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.skeleton import Pose
from tests.core.fixtures import chain_skeleton, front_camera


def _snake():
    """Five straight links along x (names b0..b4, no side), turned as a whole 40 degrees
    about the vertical, its tip away from the viewer (+y): drawn straight, every link
    at cos 40 = 0.77 of its length, the same-direction rule's very case. (Lifted, it
    stays near the view plane: E_v reads a drawing foreshortened evenly throughout as
    drawn at a smaller scale, Eqs. 6-7, not as turned.)"""
    sk = chain_skeleton(np.array([[-1.0 + 0.4 * i, 0.0, 0.8] for i in range(6)]))
    world = exp_map(np.array([0.0, 0.0, np.radians(40.0)]))
    rot = np.tile(np.eye(3), (sk.n_bones, 1, 1))
    rot[0] = sk.rest_frames[0].T @ world @ sk.rest_frames[0]
    return sk, Pose(rot, np.zeros((sk.n_bones, 3)))


def test_nothing_is_paired_or_mirrored_on_an_unsided_single_chain():
    sk, pose = _snake()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    emb = project_embedding(sk, s, pose, cam)
    # The whole chain is the body's axis (no branch point ends it) ...
    assert axial_joints(s).all()
    # ... though the drawing has the rule's pairs: every inner joint joins two links drawn
    # in line, equally foreshortened, straight at bind.
    ratio = np.ones(s.n_joints)
    ratio[1:] = np.cos(np.radians(40.0))
    triples = parallel_pairs(s.joint_parent, emb.joints2d, np.radians(10.0), ratio, 0.1,
                             s.rest_joints)
    assert sorted(triples[:, 1].tolist()) == [1, 2, 3, 4]
    assert symmetry.mirror_pairs(sk.names, np.asarray(s.bones)).size == 0
    res = solve_pose3d(sk, emb, cam)
    assert res.equalities == ()
    assert res.symmetric == ()
    # The rule on the spine too (spine_parallel) pairs them: it is the axis that skips it.
    on_axis = solve_pose3d(sk, emb, cam, options=DepthOptions(spine_parallel=True))
    assert on_axis.equalities == tuple(f"straight at b{i} tail" for i in range(4))
