"""Preprocessing of gesture drawings: resampling step, Gestalt bridges, normals."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.exceptions import InputError
from gesture_pose.core.gesture.preprocess import find_bridges, preprocess
from gesture_pose.core.stroke import Stroke


def _line(a, b, n=20) -> Stroke:
    return Stroke(np.linspace(a, b, n))


def test_epsilon_is_two_percent_of_the_diagonal():
    d = preprocess([_line([0, 0], [300, 0]), _line([0, 400], [300, 400])])
    assert d.diagonal == pytest.approx(500.0)
    assert d.epsilon == pytest.approx(10.0)
    steps = np.linalg.norm(np.diff(d.stroke_samples(0), axis=0), axis=1)
    np.testing.assert_allclose(steps, 10.0, atol=1e-6)


def test_bridge_across_a_collinear_gap_in_every_pairing():
    a = _line([0, 0], [100, 0])
    b = _line([130, 0], [250, 0])
    np.testing.assert_array_equal(find_bridges([a, b], 5.0), [[0, 1, 1, 0]])
    # The second stroke drawn backwards: its end meets the first stroke's end.
    np.testing.assert_array_equal(find_bridges([a, b.reversed()], 5.0), [[0, 1, 1, 1]])
    np.testing.assert_array_equal(find_bridges([a.reversed(), b], 5.0), [[0, 0, 1, 0]])


def test_no_bridge_across_a_corner_or_a_long_gap():
    a = _line([0, 0], [100, 0])
    corner = _line([110, 10], [110, 120])
    assert len(find_bridges([a, corner], 5.0)) == 0
    far = _line([300, 0], [400, 0])
    assert len(find_bridges([a, far], 5.0)) == 0


def test_bridged_strokes_share_a_contour_and_orientation():
    a = _line([0, 0], [100, 0])
    b = _line([250, 0], [130, 0])  # drawn the other way
    d = preprocess([a, b, _line([0, 200], [250, 200])])
    g = [int(d.group[d.stroke == k][0]) for k in range(3)]
    assert g[0] == g[1] != g[2]
    # Normals agree along the bridged contour despite the reversed drawing direction.
    np.testing.assert_allclose(d.normals[d.stroke == 0].mean(0), d.normals[d.stroke == 1].mean(0))
    end_a = d.offsets[1] - 1
    assert d.next[end_a] in np.flatnonzero(d.stroke == 1)


def test_circle_normals_point_inward_with_curvature_one_over_radius():
    t = np.linspace(0, 2 * np.pi, 200)
    circle = Stroke(np.stack([100 * np.cos(t), 100 * np.sin(t)], 1) + 300)
    d = preprocess([circle])
    inward = (300 - d.points) / np.linalg.norm(300 - d.points, axis=1, keepdims=True)
    assert np.min(np.einsum("nd,nd->n", d.normals, inward)) > 0.99
    np.testing.assert_allclose(d.curvature[5:-5], 0.01, rtol=0.02)


def test_distance_field_measures_distance_to_ink():
    d = preprocess([_line([0, 0], [200, 0])])
    dist, owner = d.lookup(np.array([[100.0, 30.0], [0.0, 0.0]]))
    np.testing.assert_allclose(dist, [30.0, 0.0], atol=d.field_cell)
    assert abs(d.points[owner[0], 0] - 100.0) <= d.epsilon


def test_distance_field_is_infinite_outside_and_agrees_with_the_kd_tree():
    d = preprocess([_line([0, 0], [200, 0]), _line([0, 60], [150, 120])])
    rng = np.random.default_rng(0)
    pts = rng.uniform([-150, -150], [350, 270], (500, 2))
    dist, owner = d.lookup(pts)
    # The field read directly, cell by cell (rounding to the nearest cell centre).
    g = np.floor((pts - d.field_origin) / d.field_cell + 0.5).astype(int)
    h, w = d.field_dist.shape
    inside = (g[:, 0] >= 0) & (g[:, 0] < w) & (g[:, 1] >= 0) & (g[:, 1] < h)
    assert 0 < inside.sum() < len(pts)  # some probes fall outside the field
    np.testing.assert_array_equal(dist[inside], d.field_dist[g[inside, 1], g[inside, 0]])
    np.testing.assert_array_equal(owner[inside], d.field_owner[g[inside, 1], g[inside, 0]])
    assert np.all(np.isinf(dist[~inside]))
    x_dist, _ = d.lookup_xy(pts[:, 0], pts[:, 1])
    np.testing.assert_array_equal(x_dist, dist)
    # Inside: the distance to the ink (the samples' polylines, up to a cell), which is at
    # most the distance to the nearest sample and at least that less half a step.
    nearest = d.tree.query(pts[inside])[0]
    assert np.all(dist[inside] <= nearest + d.field_cell)
    assert np.all(dist[inside] >= nearest - 0.5 * d.epsilon - d.field_cell)


def test_lookup_along_a_direction_ignores_ink_running_across_it():
    # A vertical line at x = 0 and a horizontal one at y = 100 ending 20 px from it.
    d = preprocess([_line([0, 0], [0, 200]), _line([20, 100], [200, 100])])
    probe = np.array([[30.0, 110.0], [30.0, 50.0]])
    dist, owner = d.lookup(probe)
    np.testing.assert_allclose(dist[0], 10.0, atol=d.field_cell)  # the horizontal line
    assert abs(d.normals[owner[0], 1]) > 0.99
    up = np.zeros(2), np.ones(2)  # along the vertical line: only its ink counts
    dist, owner = d.lookup_along_xy(probe[:, 0], probe[:, 1], *up, np.radians(30.0))
    np.testing.assert_allclose(dist, 30.0, atol=d.field_cell)
    assert np.all(np.abs(d.points[owner, 0]) < 1e-9)
    across = np.ones(2), np.zeros(2)  # along the horizontal line
    dist, owner = d.lookup_along_xy(probe[:, 0], probe[:, 1], *across, np.radians(30.0))
    np.testing.assert_allclose(dist, [10.0, 50.0], atol=d.field_cell)
    assert np.all(np.abs(d.points[owner, 1] - 100.0) < 1e-9)
    far = d.lookup_along_xy(np.array([1e6]), np.array([0.0]), np.ones(1), np.zeros(1), 0.5)
    assert np.isinf(far[0][0])


def test_empty_drawing_is_an_input_error():
    with pytest.raises(InputError, match="no strokes"):
        preprocess([])
