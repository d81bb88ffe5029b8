"""Pairwise bone cost of the 2D embedding (Gesture3D Section 5.2, consistency term Cc)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gesture_pose.core.gesture.costs import (
    CostParams,
    bone_costs,
    crossing_room,
    crossing_stations,
    exposed_weight,
    length_cost,
    pair_cost,
    pair_rows,
    rigid_cost,
)
from gesture_pose.core.gesture.preprocess import preprocess
from gesture_pose.core.stroke import Stroke

from .test_gesture_fixtures import arc, segment

R = 30.0  # limb radius, pixels: the balls' outlines cross the axis at t = 0.1 and 0.9


def _limb(cut_at: float | None) -> list[Stroke]:
    """A straight limb from (100, 300) to (400, 300), outlined at radius R, with a drawn
    joint ball at each end (circles of radius R around the joints, as traced from a mesh
    made of parts) and optionally a line across the limb at x = ``cut_at``."""
    head, tail = np.array([100.0, 300.0]), np.array([400.0, 300.0])
    strokes = [segment(head + [0, R], tail + [0, R], 60),
               segment(head - [0, R], tail - [0, R], 60),
               arc(head, R, 0.0, 2 * np.pi, 32), arc(tail, R, 0.0, 2 * np.pi, 32)]
    if cut_at is not None:
        strokes.append(segment([cut_at, 300 - R], [cut_at, 300 + R], 8))
    return [Stroke(s) for s in strokes]


def _cost(strokes: list[Stroke]) -> float:
    d = preprocess(strokes)
    # The joints come from their balls' contours (group of the ball strokes).
    head_group = d.group[d.tree.query([100.0 + R, 300.0])[1]]
    tail_group = d.group[d.tree.query([400.0 - R, 300.0])[1]]
    params = CostParams(w_direction=0.0)
    cost = pair_cost(d, np.array([[100.0, 300.0]]), np.array([R]), np.array([head_group]),
                     np.array([-1]), np.array([[400.0, 300.0]]), np.array([R]),
                     np.array([tail_group]), np.array([-1]), 300.0, params)
    return float(cost[0, 0])


def test_a_bone_crossing_only_its_joint_balls_is_consistent():
    # The axis crosses each ball's outline inside that joint's circle: the outline of the
    # joint itself, not the bone leaving its shape. Length and conformity are exact.
    assert _cost(_limb(None)) < 0.05


def test_a_contour_of_its_joints_crossed_between_the_circles_is_inconsistent():
    # A line of the tail ball's own contour group across the middle of the limb: Cc = 1,
    # so E = 1 - (1 - Cl)(1 - Ccf)(1 - Wc) >= Wc = 0.9.
    strokes = _limb(None)
    ball = strokes[3].points
    # Join the cut to the tail ball so it belongs to the same contour group.
    cut = np.concatenate([segment([250.0, 300 - R], [250.0, 300 + R], 8),
                          segment([250.0, 300 + R], ball[0], 20)])
    strokes[3] = Stroke(np.concatenate([cut, ball]))
    assert _cost(strokes) >= 0.9


def test_an_outline_along_a_thin_bone_is_not_a_crossing():
    """A part thinner than a resampling step (a hand seen edge-on) has its outline within
    half a step of its bone's axis all along: near, but running along the axis, so not
    crossed. The same outline turned across the axis is a crossing."""
    head, tail = np.array([100.0, 300.0]), np.array([400.0, 300.0])
    frame = [Stroke(segment([50.0, 100.0], [450.0, 120.0], 40)),  # set the drawing's size
             Stroke(segment([50.0, 500.0], [450.0, 480.0], 40))]
    loop = np.concatenate([segment(head + [0, 3], tail + [0, 3], 60),
                           segment(tail - [0, 3], head - [0, 3], 60)])
    d = preprocess([Stroke(loop), *frame])
    assert 3.0 < 0.5 * d.epsilon
    g = d.group[d.tree.query(head + [150.0, 3.0])[1]]
    params = CostParams(w_direction=0.0, sigma_length=10.0)

    def cost(drawing) -> float:
        return float(pair_cost(drawing, head[None], np.array([3.0]), np.array([g]),
                               np.array([1]), tail[None], np.array([3.0]), np.array([g]),
                               np.array([1]), 300.0, params)[0, 0])

    along = cost(d)
    assert along < 0.9
    # A line of the same contour across the axis between the joints makes Cc = 1.
    cross = np.concatenate([loop, segment(head - [0, 3], [250.0, 280.0], 30),
                            segment([250.0, 280.0], [250.0, 320.0], 8)])
    crossed = preprocess([Stroke(cross), *frame])
    g2 = crossed.group[crossed.tree.query(head + [150.0, 3.0])[1]]
    assert g2 == crossed.group[crossed.tree.query([250.0, 300.0])[1]]
    assert float(pair_cost(crossed, head[None], np.array([3.0]), np.array([g2]),
                           np.array([1]), tail[None], np.array([3.0]), np.array([g2]),
                           np.array([1]), 300.0, params)[0, 0]) >= 0.9


def test_crossing_stations_stay_between_the_joint_circles():
    t = crossing_stations(np.array([[300.0]]), np.array([35.0]), np.array([50.0]), 10.0)
    assert t.shape == (1, 1, 9)
    np.testing.assert_allclose(t[0, 0, [0, -1]], [45.0 / 300.0, 1.0 - 60.0 / 300.0])
    assert np.all(np.diff(t[0, 0]) > 0)
    # A bone shorter than its circles is probed at its middle only.
    short = crossing_stations(np.array([[30.0]]), np.array([20.0]), np.array([20.0]), 10.0)
    np.testing.assert_allclose(short, 0.5)


def test_rigid_offsets_in_the_view_or_by_length_only():
    d = preprocess(_limb(None))
    pa = np.array([[200.0, 300.0]])
    offset = np.array([30.0, 0.0])
    turned = pa + [[0.0, 30.0]]  # the offset's length, turned by 90 degrees
    view = CostParams()
    paper = CostParams(view_offsets=False)
    # Our prior compares the 2D layout: the turned offset costs, the bind one does not.
    assert rigid_cost(d, pa, pa + offset, offset, view)[0, 0] < 1e-9
    assert rigid_cost(d, pa, turned, offset, view)[0, 0] > 0.5
    # The paper's length term sees only the length (here the bind length of the offset).
    assert rigid_cost(d, pa, turned, offset, paper, 30.0)[0, 0] < 1e-9
    assert rigid_cost(d, pa, pa + [[60.0, 0.0]], offset, paper, 30.0)[0, 0] > 0.5


def test_naturalness_reference_angle_from_the_view_or_the_rest_pose():
    from gesture_pose.core.gesture.mrf import make_problem
    from gesture_pose.core.gesture.solving import solving_skeleton

    from .fixtures import chain_skeleton

    # A chain bent by 90 degrees at rest, seen in a view that shows it straight.
    rest = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 1.0]])
    solving = solving_skeleton(chain_skeleton(rest), min_bone_epsilons=0.0)
    seen = np.array([[100.0, 300.0], [200.0, 300.0], [300.0, 300.0]])
    d = preprocess(_limb(None))
    tail = solving.joint_bones.index("b1 tail")
    in_view = make_problem(d, solving, 100.0, seen, CostParams())
    at_rest = make_problem(d, solving, 100.0, seen, CostParams(view_angles=False))
    assert in_view.rest_angle[tail] < 1e-6
    np.testing.assert_allclose(at_rest.rest_angle[tail], np.pi / 2)


def test_length_term_accepts_the_range_between_view_and_full_length():
    """Eq. 2 measures the drawn length against the bone's length (sigma / 3 when longer);
    with ``view_lengths`` a bone foreshortened in the view costs nothing anywhere between
    its length seen in the view and its full length."""
    drawn = np.array([20.0, 40.0, 45.0, 50.0, 56.0])
    paper = length_cost(drawn, 50.0, 10.0)
    assert paper[3] == 0.0 and np.all(paper[[0, 1, 2, 4]] > 0.0)
    np.testing.assert_allclose(paper[4], 1.0 - np.exp(-36.0 / (2.0 * (10.0 / 3.0) ** 2)))
    view = length_cost(drawn, 50.0, 10.0, free=(40.0, 50.0))
    np.testing.assert_allclose(view[1:4], 0.0)
    # Shorter than the view length: the paper's Gaussian from the view length; longer than
    # the full length: unchanged.
    np.testing.assert_allclose(view[0], length_cost(np.array(20.0), 40.0, 10.0))
    np.testing.assert_allclose(view[4], paper[4])
    # A range above the bone length (nearer than the mean depth) widens it upwards, and the
    # stricter side starts at its top.
    near = length_cost(np.array([52.0, 56.0]), 50.0, 10.0, free=(50.0, 53.0))
    np.testing.assert_allclose(near, [0.0, 1.0 - np.exp(-9.0 / (2.0 * (10.0 / 3.0) ** 2))])


def test_length_term_is_lenient_up_to_the_nearest_depth():
    """Through a perspective camera a bone drawn longer than its length, up to its length at
    the nearest depth it can reach, pays the lenient sigma; beyond, the strict sigma / 3 on
    the rest of the excess (the cost stays continuous and grows with the length)."""
    drawn = np.array([50.0, 55.0, 60.0, 63.0, 70.0])
    cost = length_cost(drawn, 50.0, 10.0, nearest=60.0)
    np.testing.assert_allclose(cost[:3], 1.0 - np.exp(-0.5 * np.array([0.0, 0.5, 1.0]) ** 2))
    np.testing.assert_allclose(cost[3], 1.0 - np.exp(-0.5 * (1.0 + 0.9) ** 2))
    assert np.all(np.diff(cost) > 0.0)
    paper = length_cost(drawn, 50.0, 10.0)
    assert np.all(cost[1:] < paper[1:])
    # Shorter drawings are unchanged by it.
    np.testing.assert_allclose(length_cost(np.array([30.0]), 50.0, 10.0, nearest=60.0),
                               length_cost(np.array([30.0]), 50.0, 10.0))


def test_foreshortening_scales_the_short_side_with_the_bone():
    """A bone turned out of the view plane is drawn at cos(theta) of its length: with
    ``foreshortening`` the short side's sigma becomes that share of the bone's length
    beyond ``foreshortening_from`` sigmas of shortfall, so a long bone drawn at a third of
    its length no longer costs 1, while a small shortfall costs what the paper's sigma
    says (the long side keeps the strict sigma / 3). On by default: half the bone's length
    beyond one sigma (``foreshortening`` 0; the paper's Eq. 2)."""
    assert (CostParams().foreshortening, CostParams().foreshortening_from) == (0.5, 1.0)
    drawn = np.array([95.0, 31.0, 100.0, 105.0])
    paper = length_cost(drawn, 100.0, 10.0)
    scaled = length_cost(drawn, 100.0, 10.0, short_sigma=50.0, knee=0.5)
    np.testing.assert_allclose(scaled[0], paper[0])  # 5 px short: within half a sigma
    np.testing.assert_allclose(scaled[1], 1.0 - np.exp(-0.5 * (0.5 + 64.0 / 50.0) ** 2))
    assert scaled[1] < 0.81 and paper[1] > 0.99
    np.testing.assert_allclose(scaled[2:], paper[2:])
    # From the start (knee 0): the share alone.
    np.testing.assert_allclose(length_cost(drawn[1:2], 100.0, 10.0, short_sigma=50.0),
                               1.0 - np.exp(-0.5 * (69.0 / 50.0) ** 2))
    # In the pairwise cost: the limb's 300 px bone expected at 600 px (drawn at half its
    # length) pays Cl with the paper's sigma (4% of the diagonal, 15 px here) for half a
    # sigma of its shortfall and with half its length for the rest.
    d = preprocess(_limb(None))
    sigma = CostParams().sigma_length * d.diagonal

    def cost(length: float, params: CostParams) -> float:
        return float(pair_cost(d, np.array([[100.0, 300.0]]), np.array([R]), np.array([-1]),
                               np.array([0]), np.array([[400.0, 300.0]]), np.array([R]),
                               np.array([-1]), np.array([0]), length, params)[0, 0])

    paper = CostParams(w_direction=0.0, foreshortening=0.0, exposed_conformity=False)
    base = cost(300.0, paper)  # the data terms alone (Cl = 0)
    ours = CostParams(w_direction=0.0, foreshortening=0.5, foreshortening_from=0.5,
                      exposed_conformity=False)
    z = 0.5 + (300.0 - 0.5 * sigma) / 300.0
    cl = 1.0 - np.exp(-0.5 * z**2)
    np.testing.assert_allclose(cost(600.0, ours), 1.0 - (1.0 - cl) * (1.0 - base))
    assert cost(600.0, paper) > 0.999
    # Drawn at its length, the conformity of the side it shows is the paper's.
    assert cost(300.0, replace(ours, exposed_conformity=True)) == base
    # A shortfall within half a sigma costs what it costs in the paper.
    np.testing.assert_allclose(cost(300.0 + 0.4 * sigma, ours),
                               cost(300.0 + 0.4 * sigma, paper))


def test_conformity_counts_only_the_side_a_bone_shows():
    """``exposed_conformity``: the conformity term ``Ccf`` is discounted by the share of the
    stretch between the joint circles (at the bone's length) that a bone no longer shows,
    beyond ``exposed_from`` sigmas of slack. A bone drawn at its length pays the whole
    ``Ccf``; one foreshortened into its joints' circles (thighs pointing at the viewer)
    pays only the slack's share; a bone whose stretch is within the slack (a hand) always
    pays all of it. On by default (False: the paper's ``Ccf``)."""
    assert CostParams().exposed_conformity
    ra, rb = np.array([20.0]), np.array([15.0])
    # 150 px thigh: 150 - 35 = 115 px of stretch, 10 px of slack.
    drawn = np.array([150.0, 200.0, 140.0, 87.5, 50.0, 30.0, 20.0])
    w = np.array([exposed_weight(np.array([[x]]), 150.0, ra, rb, 10.0)[0, 0] for x in drawn])
    np.testing.assert_allclose(w, [1.0, 1.0, 1.0, 62.5 / 115.0, 25.0 / 115.0, 5.0 / 115.0,
                                   0.0])
    # A hand (30 px, radii 10 and 8): 12 px of stretch, within a 15 px slack.
    assert exposed_weight(np.array([[18.0]]), 30.0, np.array([10.0]), np.array([8.0]),
                          15.0)[0, 0] == 1.0
    # In the pairwise cost: the hand-made limb (radius 30) with no outline drawn, seen at
    # 60 px (its circles touching) when its length is 300 px: Cl and the slack's share of
    # the paper's Ccf (1, nothing drawn) are left.
    d = preprocess([Stroke(segment([0.0, 0.0], [500.0, 500.0], 40))])
    sigma = CostParams().sigma_length * d.diagonal

    def cost(params: CostParams) -> float:
        return float(pair_cost(d, np.array([[100.0, 300.0]]), np.array([R]), np.array([-1]),
                               np.array([0]), np.array([[160.0, 300.0]]), np.array([R]),
                               np.array([-1]), np.array([0]), 300.0, params)[0, 0])

    ours = CostParams(w_direction=0.0, exposed_conformity=True, foreshortening=0.5,
                      foreshortening_from=0.5)
    cl = length_cost(np.array(60.0), 300.0, sigma, short_sigma=max(sigma, 0.5 * 300.0),
                     knee=0.5)
    share = ours.exposed_from * sigma / (300.0 - 2 * R)
    np.testing.assert_allclose(cost(ours), 1.0 - (1.0 - cl) * (1.0 - share))
    assert cost(ours) < cost(replace(ours, exposed_conformity=False))
    paper_ccf = cost(CostParams(w_direction=0.0, sigma_length=1e6, exposed_conformity=False))
    assert paper_ccf > 0.99  # nothing drawn along it: the paper's Ccf is 1
    assert cost(replace(ours, exposed_conformity=False)) > 0.99


def test_problem_gives_the_view_length_only_with_view_lengths():
    from gesture_pose.core.gesture.mrf import make_problem
    from gesture_pose.core.gesture.solving import solving_skeleton

    from .fixtures import chain_skeleton

    # A chain whose second bone points at the viewer half-way: seen at half its length.
    sol = solving_skeleton(chain_skeleton(np.array([[0.0, 0, 0], [1.0, 0, 0],
                                                    [1.5, -np.sqrt(0.75), 0]])))
    view = np.array([[0.0, 0.0], [100.0, 0.0], [150.0, 0.0]])
    d = preprocess(_limb(None))
    problem = make_problem(d, sol, 100.0, view)
    tail = sol.tail_joint[1]
    np.testing.assert_allclose(problem.link_length[tail], 100.0)
    np.testing.assert_allclose(problem.free_lengths(tail), (50.0, 100.0))
    paper = make_problem(d, sol, 100.0, view, CostParams(view_lengths=False))
    assert paper.free_lengths(tail) is None
    # Through a perspective camera the bone may come nearer: up to its length at that
    # depth, a longer drawing pays the lenient sigma (orthographic: no near scale).
    assert problem.nearest_length(tail) is None
    near = make_problem(d, sol, 100.0, view, near_scale=np.array([1.0, 1.1, 1.2]))
    np.testing.assert_allclose(near.nearest_length(tail), 120.0)
    off = make_problem(d, sol, 100.0, view, CostParams(perspective_lengths=False),
                       np.full(3, 1.2))
    assert off.nearest_length(tail) is None


def test_a_bone_without_room_between_its_circles_is_not_tested_for_crossings():
    """A hand (34 px, joint radii 11 and 9) a step of about 17 px long on each side has
    no stretch of axis a step beyond both circles: its probe falls on the drawn wrist
    ball's outline, a contour of its own head joint that every correct placement
    crosses. ``crossing_room`` leaves such a bone out of the crossing test."""
    head, tail = np.array([300.0, 300.0]), np.array([334.0, 300.0])
    frame = [Stroke(segment([0.0, 0.0], [600.0, 0.0], 40)),  # a 600 x 600 drawing
             Stroke(segment([0.0, 600.0], [600.0, 600.0], 40))]
    ball = Stroke(arc(head, 13.0, 0.0, 2 * np.pi, 32))
    tip = Stroke(arc(tail, 9.0, -np.pi / 2, np.pi / 2, 16))
    outline = [Stroke(segment(head + [0, s * 10.0], tail + [0, s * 9.0], 12))
               for s in (1.0, -1.0)]
    d = preprocess([ball, tip, *outline, *frame])
    assert 15.0 < d.epsilon < 20.0
    g_head = d.group[d.tree.query(head + [13.0, 0.0])[1]]  # the ball, where the axis crosses it
    g_tail = d.group[d.tree.query(tail + [9.0, 0.0])[1]]

    def cost(room: bool, expected: float = 34.0) -> float:
        params = CostParams(w_direction=0.0, crossing_room=room, sigma_length=1.0)
        return float(pair_cost(d, head[None], np.array([11.0]), np.array([g_head]),
                               np.array([1]), tail[None], np.array([9.0]),
                               np.array([g_tail]), np.array([1]), expected, params)[0, 0])

    assert cost(False) >= 0.9  # the ball's outline, 4 px from the middle probe, is "crossed"
    assert cost(True) < 0.5
    room = crossing_room(np.array([[34.0], [70.0]]).T, np.array([11.0]), np.array([9.0]),
                         d.epsilon)
    np.testing.assert_array_equal(room, [[False, True]])


def test_a_bone_drawn_short_is_still_tested_for_crossings():
    """A bone expected 70 px long, with room for the crossing test, drawn 52 px long
    across a line of its head joint's contour: the room is measured at the expected
    length, so drawing it short does not escape Cc (the length term is made lenient to
    isolate Cc). Without the line, its head's ball (14 px from the probe) is not crossed."""
    head, tail = np.array([300.0, 300.0]), np.array([352.0, 300.0])
    frame = [Stroke(segment([0.0, 0.0], [600.0, 0.0], 40)),
             Stroke(segment([0.0, 600.0], [600.0, 600.0], 40))]
    ball = arc(head, 13.0, 0.0, 2 * np.pi, 32)
    cut = np.concatenate([segment([327.0, 285.0], [327.0, 315.0], 8),
                          segment([327.0, 315.0], ball[0], 12)])
    outline = [Stroke(segment(head + [0, s * 10.0], tail + [0, s * 9.0], 12))
               for s in (1.0, -1.0)]

    def cost(strokes, room: bool) -> float:
        d = preprocess([*strokes, *outline, *frame])
        g = d.group[d.tree.query(head + [13.0, 0.0])[1]]
        params = CostParams(w_direction=0.0, crossing_room=room, sigma_length=1.0)
        return float(pair_cost(d, head[None], np.array([11.0]), np.array([g]),
                               np.array([1]), tail[None], np.array([9.0]), np.array([-1]),
                               np.array([0]), 70.0, params)[0, 0])

    crossed = [Stroke(np.concatenate([cut, ball]))]
    assert cost(crossed, True) >= 0.9
    assert cost([Stroke(ball)], True) < 0.5
    # Measured at the drawn length (52 < 11 + 9 + 2 steps) the bone would escape.
    assert not crossing_room(np.array([[52.0]]), np.array([11.0]), np.array([9.0]), 17.0)


def test_bone_costs_of_a_tables_rows_are_the_table_exactly():
    # The refinement and the energy evaluations cost many bones' placement pairs in one
    # bone_costs call (each row with its bone's length, free range, nearest length and
    # blocked samples); the search costs tables with pair_cost, which computes only the
    # pairs whose length term is below 1. Both must give the same values, bit for bit.
    d = preprocess(_limb(250.0))
    rng = np.random.default_rng(3)
    pa, pb = rng.uniform([50, 230], [450, 370], (17, 2)), rng.uniform([50, 230], [450, 370],
                                                                        (23, 2))
    ra, rb = rng.uniform(10, 40, 17), rng.uniform(10, 40, 23)
    ga, gb = rng.integers(-1, d.group.max() + 1, 17), rng.integers(-1, d.group.max() + 1, 23)
    sa, sb = rng.choice([-1, 0, 1], 17), rng.choice([-1, 0, 1], 23)
    blocked = rng.random(d.n_samples) < 0.2
    # (length, blocked, free range, nearest length) of two bones.
    bones = [(300.0, blocked, (250.0, 320.0), 340.0), (120.0, None, None, None)]
    rows = pair_rows(pa, ra, ga, sa, pb, rb, gb, sb)
    n = len(rows[0])
    for params in (CostParams(), CostParams(transverse_crossings=False, crossing_room=False,
                                            exposed_conformity=False, foreshortening=0.0)):
        tables = [pair_cost(d, pa, ra, ga, sa, pb, rb, gb, sb, length, params, blocked=blk,
                            free=free, nearest=near) for length, blk, free, near in bones]
        got = bone_costs(d, *(np.concatenate([r, r]) for r in rows),
                         np.repeat([300.0, 120.0], n), params, 8,
                         np.repeat(np.stack([blocked, np.zeros_like(blocked)]), n, axis=0),
                         np.repeat([(250.0, 320.0), (120.0, 120.0)], n, axis=0),
                         np.repeat([340.0, np.nan], n))
        expected = np.concatenate([t.ravel() for t in tables])
        np.testing.assert_array_equal(got, expected)
        assert 0 < np.mean(expected == 1.0) < 1  # pruned pairs and costed ones


def _torso_with_creases() -> list[Stroke]:
    """A torso's two sides (x = 100 and 300) and a crease meeting each at y = 200 at 45
    degrees from inside (a thigh's crease meeting the outline at the hip), drawn a few
    pixels past the outline, as traced lines overshoot."""
    return [Stroke(segment([100.0, 0.0], [100.0, 400.0], 80)),
            Stroke(segment([300.0, 0.0], [300.0, 400.0], 80)),
            Stroke(segment([96.0, 196.0], [160.0, 260.0], 30)),
            Stroke(segment([304.0, 196.0], [240.0, 260.0], 30))]


def _link_cost(d, head, tail, radius: float, length: float, oriented: bool) -> float:
    params = CostParams(w_direction=0.0, exposed_conformity=False,
                        oriented_conformity=oriented)
    none, zero = -np.ones(1, int), np.zeros(1, int)
    return float(pair_cost(d, np.array([head], float), np.array([radius]), none, zero,
                           np.array([tail], float), np.array([radius]), none, zero, length,
                           params)[0, 0])


def test_a_crease_meeting_the_outline_does_not_hide_it_from_a_link_inside_its_circles():
    # The pelvis link of the test view's step: 40 px between joints of radius 100 (their
    # circles overlap), its checkpoints on the torso's sides. At the crease's junction the
    # distance field gives the checkpoint to the crease, 45 degrees off the bone: the
    # paper's Ccf fails it there on both sides (1 of 8 stations each, 0.125).
    d = preprocess(_torso_with_creases())
    head, tail = (200.0, 177.5), (200.0, 217.5)  # a station at y = 200 on each side
    assert _link_cost(d, head, tail, 100.0, 40.0, oriented=False) == 0.125
    # With oriented_conformity the outline, as near as the crease, counts.
    assert _link_cost(d, head, tail, 100.0, 40.0, oriented=True) == 0.0
    # A link whose circles leave room between them (a limb) keeps the paper's Ccf: a line
    # meeting a limb's outline can mark its joint (a knee's outline on a foreshortened leg).
    for head, tail, radius, length in (((130.0, 120.0), (130.0, 280.0), 30.0, 160.0),
                                       ((200.0, 160.0), (200.0, 240.0), 30.0, 80.0)):
        assert (_link_cost(d, head, tail, radius, length, oriented=True)
                == _link_cost(d, head, tail, radius, length, oriented=False))

