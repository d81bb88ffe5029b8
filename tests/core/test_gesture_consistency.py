"""Global consistency: contour assignment, coverage, overlaps and who yields."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gesture_pose.core.gesture.candidates import JointCandidates
from gesture_pose.core.gesture.consistency import (
    assign_contours,
    block_overlaps,
    stacked_counterparts,
)
from gesture_pose.core.gesture.costs import CostParams
from gesture_pose.core.gesture.mrf import make_problem
from gesture_pose.core.gesture.preprocess import preprocess
from gesture_pose.core.gesture.solving import solving_skeleton
from gesture_pose.core.stroke import Stroke

from .fixtures import chain_skeleton


def _conf(points: np.ndarray, radius: float) -> JointCandidates:
    n = len(points)
    return JointCandidates(np.asarray(points, float), np.full(n, radius), np.zeros(n, int),
                           -np.ones(n, int), -np.ones(n, int), np.zeros(n),
                           -np.ones((n, 48), int))


def test_folded_chain_overlaps_and_the_farther_bone_yields():
    # A limb outline: two parallel lines 40 px apart, 200 px long.
    top = Stroke(np.linspace([100.0, 320.0], [300.0, 320.0], 40))
    bottom = Stroke(np.linspace([100.0, 280.0], [300.0, 280.0], 40))
    drawing = preprocess([top, bottom])
    skel = chain_skeleton(np.array([[0, 0, 0], [1.0, 0, 0], [0.1, 0, 0], [0.9, 0, 0]]))
    solving = solving_skeleton(skel)
    assert solving.n_bones == 3
    # The bind pose seen in the view: bone 0 lies on the limb, bone 2 far below it.
    reference = np.array([[100.0, 300.0], [300.0, 300.0], [120.0, 100.0], [280.0, 100.0]])
    problem = make_problem(drawing, solving, 200.0, reference)
    # Folded placement: bone 0 and bone 2 (disjoint) both along the limb.
    conf = _conf([[100.0, 300.0], [300.0, 300.0], [110.0, 300.0], [290.0, 300.0]], 20.0)
    assign = assign_contours(problem, conf)
    assert (0, 2) in assign.overlaps
    # Both outlines are explained: bone 0 holds samples on its left and right.
    assert len(assign.bone_left[0]) > 10 and len(assign.bone_right[0]) > 10
    assert assign.coverage > 0.9
    blocked = block_overlaps(problem, assign)
    assert not blocked[0].any()
    shared = np.intersect1d(np.r_[assign.bone_left[0], assign.bone_right[0]],
                            np.r_[assign.bone_left[2], assign.bone_right[2]])
    assert shared.size > 10 and blocked[2, shared].all()


def test_straight_chain_has_no_overlap():
    top = Stroke(np.linspace([100.0, 320.0], [500.0, 320.0], 60))
    bottom = Stroke(np.linspace([100.0, 280.0], [500.0, 280.0], 60))
    drawing = preprocess([top, bottom])
    skel = chain_skeleton(np.array([[0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]]))
    solving = solving_skeleton(skel)
    reference = np.array([[100.0, 300.0], [300.0, 300.0], [500.0, 300.0]])
    problem = make_problem(drawing, solving, 200.0, reference)
    assign = assign_contours(problem, _conf(reference, 20.0))
    assert assign.overlaps == []
    assert assign.coverage > 0.9


def test_counterparts_the_view_superimposes_may_share_contours():
    """Left and right legs one behind the other in the view (a side view) are drawn on the
    same lines: they do not count as an overlap; drawn apart at bind, or with the option
    off (the paper's non-overlap), the same folded placement does."""
    top = Stroke(np.linspace([100.0, 320.0], [300.0, 320.0], 40))
    bottom = Stroke(np.linspace([100.0, 280.0], [300.0, 280.0], 40))
    drawing = preprocess([top, bottom])
    skel = chain_skeleton(np.array([[0, 0, 0], [1.0, 0, 0], [0.1, 0, 0], [0.9, 0, 0]]))
    skel = replace(skel, names=("leg.L", "body", "leg.R"))
    solving = solving_skeleton(skel)
    conf = _conf([[100.0, 300.0], [300.0, 300.0], [110.0, 300.0], [290.0, 300.0]], 20.0)
    apart = np.array([[100.0, 300.0], [300.0, 300.0], [120.0, 100.0], [280.0, 100.0]])
    stacked = np.array([[100.0, 300.0], [300.0, 300.0], [120.0, 300.0], [302.0, 300.0]])
    for reference, params, overlap in ((stacked, CostParams(), False),
                                       (apart, CostParams(), True),
                                       (stacked, CostParams(stacked_counterparts=0.0), True)):
        problem = make_problem(drawing, solving, 200.0, reference, params)
        pairs = stacked_counterparts(problem)
        assert len(pairs) == (0 if overlap else 1)
        assert ((0, 2) in assign_contours(problem, conf).overlaps) == overlap
