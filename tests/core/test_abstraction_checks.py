"""Input checks: far strokes refused, undrawn bones kept, end-on bones reported."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gesture_pose.core.abstraction.checks import (
    check_strokes_near,
    drawn_bones,
    projected_length_ratio,
)
from gesture_pose.core.abstraction.correspondences import assign_strokes
from gesture_pose.core.abstraction.parameters import ParameterSpace, RigPose
from gesture_pose.core.abstraction.problem import build_drawover_problem
from gesture_pose.core.abstraction.rig import pose_bones
from gesture_pose.core.abstraction.solver import SolveOptions, solve_abstraction
from gesture_pose.core.exceptions import InputError
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.stroke import Stroke
from tests.core.fixtures import front_camera, tree_skeleton
from tests.core.test_abstraction_solver import in_plane_pose, make_problem, tube_mesh


def _one_arm_problem(**kwargs):
    """Strokes of every bone at the rest pose except ``fore.L``, redrawn bent."""
    skel = tree_skeleton()
    target = in_plane_pose(skel, np.array([0.0, 0.0, 0.0, 0.6, 0.0, 0.0]))
    space = ParameterSpace.from_masks(skel.parents, np.ones(6, bool))
    full = make_problem(skel, target, space, **kwargs)
    fore = skel.index("fore.L")
    return skel, target, replace(full, strokes=(full.strokes[fore],))


def test_far_stroke_is_refused_by_name() -> None:
    box = np.array([[0.0, 0.0], [100.0, 200.0]])
    near = Stroke(np.array([[110.0, 50.0], [150.0, 80.0]]))  # 10 px outside the box
    far = Stroke(np.array([[400.0, 50.0], [450.0, 80.0]]))
    assert check_strokes_near(box, [near]) == 200.0
    with pytest.raises(InputError, match=r"the newest \(300 px away\)"):
        check_strokes_near(box, [near, far], labels=("old", "the newest"))


def test_solver_refuses_a_far_stroke_before_changing_anything() -> None:
    skel, _, problem = _one_arm_problem()
    moved = Stroke(problem.strokes[0].points + [0.0, 2000.0])
    with pytest.raises(InputError, match="far from the character"):
        solve_abstraction(replace(problem, strokes=(moved,)))


def test_drawn_bones_include_those_between_but_not_above() -> None:
    parents = np.array([-1, 0, 1, 2, 3, 0])  # a chain 0-1-2-3-4 and a side bone 5
    w = np.zeros((2, 6))
    w[0, 2] = 1.0
    w[1, 4] = 0.5  # a point half on bone 4 and half on bone 5 draws neither
    w[1, 5] = 0.5
    w[0, 3] = 0.0
    np.testing.assert_array_equal(drawn_bones(w, parents), [2])
    w[1, 4] = 0.6
    np.testing.assert_array_equal(drawn_bones(w, parents), [2, 3, 4])


def test_undrawn_bones_are_kept_exactly() -> None:
    skel, target, problem = _one_arm_problem()
    result = solve_abstraction(problem)
    assert result.residual_px < 0.1
    assert set(result.frozen) == {"root", "neck", "arm.L", "arm.R", "fore.R"}
    for name in result.frozen:
        np.testing.assert_array_equal(result.pose.rotations[skel.index(name)], np.eye(3))
    fore = skel.index("fore.L")
    np.testing.assert_allclose(pose_bones(skel, result.pose).frames[fore][:, 1],
                               pose_bones(skel, target).frames[fore][:, 1], atol=1e-3)
    # The paper's behaviour: the bones above may move too (held back by W_pose only).
    loose = solve_abstraction(problem, SolveOptions(moved_bones="DRAWN_AND_PARENTS"))
    assert set(loose.frozen) == {"neck", "arm.R", "fore.R"}


def test_proximity_prefers_the_curve_the_stroke_starts_from() -> None:
    # A long "torso" curve passes near the redrawn arm; the arm's own curve starts where
    # the stroke starts.
    torso = np.stack([np.zeros(50), np.linspace(0.0, 300.0, 50)], axis=1)
    arm = np.stack([np.linspace(0.0, 150.0, 20), np.full(20, 200.0)], axis=1)
    raised = Stroke(np.stack([np.linspace(0.0, 60.0, 20), np.linspace(200.0, 340.0, 20)],
                             axis=1))
    assert assign_strokes([torso, arm], [raised]) == ((1, 0),)


def test_end_on_bone_is_reported() -> None:
    skel = tree_skeleton()
    cam = front_camera()
    n = skel.n_bones
    heads = skel.rest_heads
    to_eye = cam.location - heads
    tails = heads + 0.5 * to_eye / np.linalg.norm(to_eye, axis=1, keepdims=True)
    assert np.all(projected_length_ratio(cam, heads, heads + [0.5, 0, 0]) > 0.98)
    np.testing.assert_allclose(projected_length_ratio(cam, heads, tails), 0.0, atol=1e-9)
    # fore.L turned to point at the camera at the target: its stroke is a dot.
    world = np.zeros((n, 3))
    axis = np.cross(skel.rest_frames[3][:, 1], [0.0, -1.0, 0.0])
    world[3] = 0.5 * np.pi * axis / np.linalg.norm(axis)
    local = np.einsum("nji,nj->ni", skel.rest_frames, world)
    start = RigPose(exp_map(local), np.ones(n), np.zeros((n, 3)))
    target = in_plane_pose(skel, np.array([0.0, 0.0, 0.0, 0.5, 0.0, 0.0]))
    space = ParameterSpace.from_masks(skel.parents, np.ones(6, bool))
    problem = make_problem(skel, target, space, start=start)
    result = solve_abstraction(problem)
    assert any("fore.L points almost along the view axis" in w for w in result.warnings)


def test_drawover_source_that_projects_to_a_dot_is_refused() -> None:
    skel = tree_skeleton()
    cam = front_camera()
    verts, tris, weights = tube_mesh(skel, rings=6, segments=12)
    centre = cam.project(skel.rest_heads[3:4] + [0.2, 0.0, 0.0])[0]
    dot = Stroke(centre + np.array([[0.0, 0.0], [0.5, 0.2]]))
    target = Stroke(centre + np.array([[0.0, 0.0], [0.0, 80.0]]))
    n = skel.n_bones
    start = RigPose(np.tile(np.eye(3), (n, 1, 1)), np.ones(n), np.zeros((n, 3)))
    space = ParameterSpace.from_masks(skel.parents, np.ones(n, bool))
    with pytest.raises(InputError, match="source stroke is only"):
        build_drawover_problem(skel, start, space, cam, dot, target, verts, verts, tris,
                               weights)
