"""The visible occluding contour tracer and the drawing perturbation."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.camera import Camera
from gesture_pose.core.exceptions import InputError
from gesture_pose.core.gesture.trace import (
    Perturbation,
    TracedContours,
    occluding_edges,
    perturb,
    trace_contours,
)

from .test_gesture_fixtures import uv_sphere


def _camera() -> Camera:
    # Orthographic, 4 m wide on 800 px: 200 px per metre, looking along +y.
    return Camera.look_at([0, -10, 0], [0, 0, 0], width=800, height=600, ortho_scale=4.0)


def test_sphere_silhouette_is_a_circle_of_the_projected_radius():
    verts, tris = uv_sphere([0.0, 0.0, 0.0], 1.0)
    cam = _camera()
    traced = trace_contours(verts, tris, cam)
    pts = np.concatenate(traced.pixels)
    centre = cam.project(np.zeros((1, 3)))[0]
    dist = np.linalg.norm(pts - centre, axis=1)
    np.testing.assert_allclose(dist, 200.0, rtol=0.02)
    # The whole outline is traced: points all around the circle.
    ang = np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0])
    assert np.histogram(ang, bins=12, range=(-np.pi, np.pi))[0].min() > 0
    world = traced.world(cam)
    np.testing.assert_allclose(cam.project(np.concatenate(world)), pts, atol=1e-6)


def test_occluded_contour_is_hidden():
    front_v, front_t = uv_sphere([0.0, -1.5, 0.0], 0.6)
    back_v, back_t = uv_sphere([0.5, 1.0, 0.0], 0.8)
    verts = np.concatenate([front_v, back_v])
    tris = np.concatenate([front_t, back_t + len(front_v)])
    cam = _camera()
    traced = trace_contours(verts, tris, cam)
    pts = np.concatenate(traced.pixels)
    c_front = cam.project(np.array([[0.0, -1.5, 0.0]]))[0]
    c_back = cam.project(np.array([[0.5, 1.0, 0.0]]))[0]
    d_front = np.linalg.norm(pts - c_front, axis=1)
    d_back = np.linalg.norm(pts - c_back, axis=1)
    # No traced point lies inside the front sphere's disk (up to the last vertex of a
    # visible edge, one mesh edge of about 21 px)...
    assert np.all(d_front > 120.0 - 21.0)
    assert np.sum(d_front < 120.0 * 0.97) <= 2
    # ...and the back sphere's outline is traced where it is not covered.
    on_back = np.abs(d_back - 160.0) < 4.0
    assert on_back.sum() > 20
    assert np.all(d_front[on_back] > 120.0 - 21.0)
    # Its edges form front/back-facing boundaries only along silhouettes.
    assert len(occluding_edges(front_v, front_t, cam)) == 48


def test_perturbation_is_deterministic_and_bounded():
    t = np.linspace(0, 2 * np.pi, 400)
    circle = np.stack([300 + 100 * np.cos(t), 300 + 100 * np.sin(t)], 1)
    clean = TracedContours((circle,), (np.full(400, 5.0),))
    params = Perturbation(gap_probability=1.0, scale_error=0.05, seed=3)
    a, b = perturb(clean, params), perturb(clean, params)
    assert len(a.pixels) == 2  # the gap cut the stroke in two
    for p, q in zip(a.pixels, b.pixels, strict=True):
        np.testing.assert_array_equal(p, q)
    centre = circle.mean(0)
    r = np.linalg.norm(np.concatenate(a.pixels) - centre, axis=1)
    diag = np.linalg.norm(np.ptp(circle, axis=0))
    bound = 100 * 1.05 + (params.noise + params.overshoot) * diag * 1.05 + 1e-6
    assert r.max() <= bound and r.min() >= 100 * 0.95 - params.noise * diag * 1.05 - 1e-6


def test_empty_mesh_is_an_input_error():
    with pytest.raises(InputError):
        trace_contours(np.zeros((3, 3)), np.zeros((0, 3), int), _camera())


def test_split_vertices_trace_like_the_welded_mesh():
    """Imported meshes split vertices along UV seams: the seams are not contours."""
    verts, tris = uv_sphere([0.0, 0.0, 0.0], 1.0)
    cam = _camera()
    # Every triangle gets its own three vertices (the worst seam splitting).
    split_v = verts[tris].reshape(-1, 3)
    split_t = np.arange(len(split_v)).reshape(-1, 3)
    assert len(occluding_edges(split_v, split_t, cam)) == 3 * len(tris)  # all boundary
    assert len(occluding_edges(split_v, split_t, cam, 1e-9)) == len(
        occluding_edges(verts, tris, cam))
    traced = trace_contours(split_v, split_t, cam)
    pts = np.concatenate(traced.pixels)
    centre = cam.project(np.zeros((1, 3)))[0]
    np.testing.assert_allclose(np.linalg.norm(pts - centre, axis=1), 200.0, rtol=0.02)
    whole = np.concatenate(trace_contours(verts, tris, cam).pixels)
    assert abs(len(pts) - len(whole)) <= 2
