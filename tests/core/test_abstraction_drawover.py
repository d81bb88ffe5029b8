"""Draw-over: strokes projected onto the deformed mesh and carried by the skinning."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.abstraction.coarsening import coarsen
from gesture_pose.core.abstraction.curves import CurveLayout
from gesture_pose.core.abstraction.drawover import project_onto_mesh, ray_triangle
from gesture_pose.core.abstraction.parameters import ParameterSpace, RigPose
from gesture_pose.core.abstraction.rig import LbsRig, lbs_weighted_rest, pose_bones, skin
from gesture_pose.core.abstraction.solver import (
    AbstractionProblem,
    SolveOptions,
    solve_abstraction,
)
from gesture_pose.core.exceptions import InputError
from gesture_pose.core.stroke import Stroke
from tests.core.fixtures import front_camera, tree_skeleton
from tests.core.test_abstraction_solver import in_plane_pose, tube_mesh


def test_ray_triangle_hits_and_barycentrics() -> None:
    v0, v1, v2 = (np.array([[0.0, 0, 0], [0, 2, 0]]), np.array([[1.0, 0, 0], [1, 2, 0]]),
                  np.array([[0.0, 1, 0], [0, 3, 0]]))
    origins = np.array([[0.25, 0.25, 1.0], [0.9, 0.9, 1.0], [0.2, 2.2, -1.0]])
    dirs = np.array([[0.0, 0, -1], [0, 0, -1], [0, 0, 1]])
    tri, dist, bary = ray_triangle(origins, dirs, v0, v1, v2)
    np.testing.assert_array_equal(tri, [0, -1, 1])
    np.testing.assert_allclose(dist[[0, 2]], [1.0, 1.0])
    np.testing.assert_allclose(bary[0], [0.5, 0.25, 0.25])
    np.testing.assert_allclose(bary[2], [0.6, 0.2, 0.2])


def test_projected_stroke_lies_on_the_mesh_and_follows_skinning() -> None:
    skel = tree_skeleton()
    cam = front_camera()
    verts, tris, weights = tube_mesh(skel, rings=6, segments=12)
    fore = skel.index("fore.L")
    along = skel.rest_heads[fore] + np.linspace(0.1, 0.9, 20)[:, None] * (
        skel.rest_tails[fore] - skel.rest_heads[fore])
    px = cam.project(along)
    curve = project_onto_mesh(px, cam, verts, tris)
    assert curve.kept.size == 20
    pts = curve.points(verts)
    np.testing.assert_allclose(cam.project(pts), px, atol=1e-6)
    y = curve.rigged_rest(lbs_weighted_rest(verts, weights))
    posed = pose_bones(skel, in_plane_pose(skel, np.array([0, 0, 0.3, 0.5, 0, 0])))
    moved_verts = skin(posed, lbs_weighted_rest(verts, weights))
    np.testing.assert_allclose(skin(posed, y), curve.points(moved_verts), atol=1e-12)
    with pytest.raises(InputError, match="not over the character"):
        project_onto_mesh(np.array([[5.0, 5.0], [6.0, 6.0]]), cam, verts, tris)


def test_drawover_moves_the_limb_onto_the_target_stroke() -> None:
    skel = tree_skeleton()
    cam = front_camera()
    verts, tris, weights = tube_mesh(skel, rings=6, segments=12)
    y_all = lbs_weighted_rest(verts, weights)
    fore = skel.index("fore.L")
    src = skel.rest_heads[fore] + np.linspace(0.1, 0.95, 30)[:, None] * (
        skel.rest_tails[fore] - skel.rest_heads[fore])
    curve = project_onto_mesh(cam.project(src), cam, verts, tris)
    target_pose = in_plane_pose(skel, np.array([0, 0, 0.25, 0.6, 0, 0]))
    target_px = cam.project(curve.points(skin(pose_bones(skel, target_pose), y_all)))
    space = ParameterSpace.from_masks(skel.parents, np.ones(6, bool))
    coarse = coarsen(verts, k=100)
    rig = LbsRig(skel, space, curve.rigged_rest(y_all), y_all[coarse.indices])
    start = RigPose(np.tile(np.eye(3), (6, 1, 1)), np.ones(6), np.zeros((6, 3)))
    problem = AbstractionProblem(rig, skel.names, cam,
                                 CurveLayout(("drawover",), np.array([0, curve.kept.size])),
                                 (Stroke(target_px),), coarse, start)
    result = solve_abstraction(problem, SolveOptions(moved_bones="DRAWN_AND_LIMB"))
    assert result.initial_residual_px > 15.0
    assert result.residual_px < 0.5
    moved = skin(pose_bones(skel, result.pose), curve.rigged_rest(y_all))
    np.testing.assert_allclose(cam.project(moved), target_px, atol=1.5)
    # The forearm's limb (the upper arm) follows; the rest of the body is kept exactly.
    assert set(result.frozen) == {"root", "neck", "arm.R", "fore.R"}
    for name in result.frozen:
        np.testing.assert_array_equal(result.pose.rotations[skel.index(name)], np.eye(3))
