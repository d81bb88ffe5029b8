"""Problem builders: rest data from a posed start, LBS and black-box problems agree."""

from __future__ import annotations

import numpy as np

from gesture_pose.core.abstraction.curves import CurveLayout
from gesture_pose.core.abstraction.parameters import ParameterSpace
from gesture_pose.core.abstraction.problem import (
    build_blackbox_problem,
    build_lbs_problem,
    lbs_mismatch,
    rest_from_posed,
)
from gesture_pose.core.abstraction.rig import lbs_weighted_rest, pose_bones, skin
from gesture_pose.core.abstraction.solver import SolveOptions, solve_abstraction
from gesture_pose.core.stroke import Stroke
from tests.core.fixtures import front_camera, tree_skeleton
from tests.core.test_abstraction_solver import bone_error_deg, in_plane_pose, tube_mesh


def _scene():
    skel = tree_skeleton()
    verts, _, weights = tube_mesh(skel)
    start = in_plane_pose(skel, np.array([0.05, 0.1, -0.2, 0.3, 0.2, -0.1]))
    target = in_plane_pose(skel, np.array([0.0, -0.15, 0.3, -0.3, -0.2, 0.35]))
    # Abstraction: three polylines through the left arm, the right arm and the neck.
    rng = np.random.default_rng(0)
    chains = [("arm.L", "fore.L"), ("arm.R", "fore.R"), ("neck",)]
    pts, w, off = [], [], [0]
    for chain in chains:
        for name in chain:
            b = skel.index(name)
            s = np.linspace(0, 1, 7)[:, None]
            s = s if name == chain[-1] else s[:-1]
            pts.append(skel.rest_heads[b] + s * (skel.rest_tails[b] - skel.rest_heads[b])
                       + rng.normal(scale=0.01, size=(len(s), 3)))
            wb = np.zeros((len(s), 6))
            wb[:, b] = 1.0
            w.append(wb)
        off.append(sum(len(p) for p in pts))
    rest_pts, weights_pts = np.concatenate(pts), np.concatenate(w)
    layout = CurveLayout(("L", "R", "neck"), np.array(off))
    y = lbs_weighted_rest(rest_pts, weights_pts)
    return skel, verts, weights, start, target, rest_pts, weights_pts, y, layout


def test_rest_from_posed_inverts_skinning() -> None:
    skel, verts, weights, start, *_ = _scene()
    posed = skin(pose_bones(skel, start), lbs_weighted_rest(verts, weights))
    np.testing.assert_allclose(rest_from_posed(skel, start, posed, weights), verts, atol=1e-10)
    assert lbs_mismatch(skel, start, verts, weights, posed) < 1e-10
    assert lbs_mismatch(skel, start, verts, weights, posed + [0, 0, 0.01]) > 0.009


def test_lbs_and_black_box_problems_reach_the_same_pose() -> None:
    skel, verts, weights, start, target, rest_pts, weights_pts, y, layout = _scene()
    cam = front_camera()
    now = skin(pose_bones(skel, start), y)
    want = cam.project(skin(pose_bones(skel, target), y))
    strokes = [Stroke(want[layout.curve(i)]) for i in range(3)]
    space = ParameterSpace.from_masks(skel.parents, np.ones(6, bool))
    y_mesh = lbs_weighted_rest(verts, weights)
    deformed = skin(pose_bones(skel, start), y_mesh)
    lbs = build_lbs_problem(skel, start, space, cam, strokes, now, weights_pts, layout, verts,
                            deformed, weights, k=80, budget=60)
    # The root carries no curve but must turn: let the bones above the drawn ones move.
    options = SolveOptions(moved_bones="DRAWN_AND_PARENTS")
    res_lbs = solve_abstraction(lbs, options)

    def raw(pose):
        posed = pose_bones(skel, pose)
        return skin(posed, y), skin(posed, y_mesh)

    box = build_blackbox_problem(skel.names, start, space, cam, strokes, raw, layout, deformed,
                                 weights, k=80, budget=60, step=1e-6, skeleton=skel,
                                 curve_weights=weights_pts)
    res_box = solve_abstraction(box, options)
    assert res_lbs.initial_residual_px > 10
    assert res_lbs.residual_px < 0.5 and res_box.residual_px < 0.5
    assert bone_error_deg(skel, res_lbs.pose, res_box.pose) < 1.0
    assert bone_error_deg(skel, res_lbs.pose, target) < 3.0
