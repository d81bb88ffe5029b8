"""LBS rig model (Eq. 13): analytic Jacobians J_x and J_z against finite differences."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gesture_pose.core.abstraction.parameters import ParameterSpace, RigPose
from gesture_pose.core.abstraction.rig import LbsRig, lbs_weighted_rest, pose_bones
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.skeleton import Pose
from tests.core.fixtures import tree_skeleton


def _random_setup(seed: int, keep_rotation: tuple[int, ...] = ()):
    """A random pose and rig; bones in ``keep_rotation`` do not inherit rotation."""
    rng = np.random.default_rng(seed)
    skel = tree_skeleton()
    if keep_rotation:
        inherit = skel.inherit_rotation.copy()
        inherit[list(keep_rotation)] = False
        skel = replace(skel, inherit_rotation=inherit)
    n = skel.n_bones
    pose = RigPose(exp_map(rng.normal(scale=0.4, size=(n, 3))), rng.uniform(0.7, 1.4, n),
                   rng.normal(scale=0.05, size=(n, 3)))
    pts = rng.uniform([-1.2, -0.2, 0.0], [1.2, 0.2, 1.5], size=(40, 3))
    w = rng.uniform(size=(40, n)) * (rng.uniform(size=(40, n)) < 0.5)
    w[:, 0] += 0.05
    reps = rng.uniform([-1.0, -0.2, 0.2], [1.0, 0.2, 1.4], size=(15, 3))
    wr = rng.uniform(size=(15, n)) + 0.01
    space = ParameterSpace.from_masks(skel.parents, np.ones(n, bool), np.ones(n, bool),
                                      skel.parents < 0)
    rig = LbsRig(skel, space, lbs_weighted_rest(pts, w), lbs_weighted_rest(reps, wr))
    return rig, pose


@pytest.mark.parametrize(("seed", "keep_rotation"), [(0, ()), (1, ()), (2, ()), (3, (3,)),
                                                     (4, (2, 5)), (5, (2, 3))])
def test_jacobians_match_finite_differences(seed: int, keep_rotation: tuple[int, ...]) -> None:
    rig, pose = _random_setup(seed, keep_rotation)
    x, z, jx, jz = rig.jacobians(pose)
    eps = 1e-6
    fx = np.empty_like(jx)
    fz = np.empty_like(jz)
    for c in range(rig.space.n_params):
        e = np.zeros(rig.space.n_params)
        e[c] = eps
        xp, zp = rig.evaluate(rig.space.step(pose, e))
        xm, zm = rig.evaluate(rig.space.step(pose, -e))
        fx[:, :, c] = (xp - xm) / (2 * eps)
        fz[:, :, c] = (zp - zm) / (2 * eps)
    assert rig.space.n_params == 6 * 3 + 6 + 3
    assert np.abs(jx).max() > 0.1
    np.testing.assert_allclose(jx, fx, atol=1e-6)
    np.testing.assert_allclose(jz, fz, atol=1e-6)
    np.testing.assert_allclose(rig.evaluate(pose)[0], x)


def test_unit_scale_forward_matches_core_skeleton() -> None:
    rng = np.random.default_rng(3)
    skel = tree_skeleton()
    rot = exp_map(rng.normal(scale=0.5, size=(6, 3)))
    trans = rng.normal(scale=0.1, size=(6, 3))
    state = skel.forward(Pose(rot, trans))
    posed = pose_bones(skel, RigPose(rot, np.ones(6), trans))
    np.testing.assert_allclose(posed.heads, state.heads, atol=1e-12)
    np.testing.assert_allclose(posed.frames, state.frames, atol=1e-12)


def test_rest_pose_skins_to_rest_points() -> None:
    skel = tree_skeleton()
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(10, 3))
    y = lbs_weighted_rest(pts, rng.uniform(size=(10, 6)))
    posed = pose_bones(skel, RigPose(np.tile(np.eye(3), (6, 1, 1)), np.ones(6), np.zeros((6, 3))))
    from gesture_pose.core.abstraction.rig import skin
    np.testing.assert_allclose(skin(posed, y), pts, atol=1e-12)
