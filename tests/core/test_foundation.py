"""Rotations, skeleton forward kinematics, camera and stroke basics."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core import rotations as rot
from gesture_pose.core.camera import Camera
from gesture_pose.core.exceptions import InputError
from gesture_pose.core.skeleton import Pose
from gesture_pose.core.stroke import Stroke

from .fixtures import chain_skeleton, front_camera, tree_skeleton

RNG = np.random.default_rng(7)


def random_rotations(n: int) -> np.ndarray:
    return rot.exp_map(RNG.normal(size=(n, 3)))


def test_exp_log_roundtrip_and_quaternions() -> None:
    w = RNG.normal(size=(50, 3))
    w *= (np.pi * 0.95 * RNG.random(50) / np.linalg.norm(w, axis=1))[:, None]
    r = rot.exp_map(w)
    np.testing.assert_allclose(r @ np.swapaxes(r, 1, 2), np.tile(np.eye(3), (50, 1, 1)),
                               atol=1e-12)
    np.testing.assert_allclose(rot.log_map(r), w, atol=1e-9)
    np.testing.assert_allclose(rot.quat_to_matrix(rot.matrix_to_quat(r)), r, atol=1e-12)


def test_rotation_between_handles_opposite_directions() -> None:
    a = np.array([[0, 1, 0], [1, 0, 0], [0, 0, 1.0]])
    b = np.array([[0, -1, 0], [0, 1, 0], [0, 0, 1.0]])
    r = rot.rotation_between(a, b)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", r, a), b, atol=1e-12)


def test_swing_twist_recomposes() -> None:
    r = random_rotations(20)
    y = np.array([0.0, 1.0, 0.0])
    swing, twist = rot.swing_twist(r, y)
    np.testing.assert_allclose(swing @ rot.exp_map(y * twist[:, None]), r, atol=1e-12)
    # The swing has no component about y: it is the smallest rotation y -> r y.
    np.testing.assert_allclose(swing, rot.rotation_between(y, r[:, :, 1]), atol=1e-9)


def test_forward_rest_pose_reproduces_rest() -> None:
    sk = tree_skeleton()
    st = sk.forward(Pose.identity(sk.n_bones))
    np.testing.assert_allclose(st.heads, sk.rest_heads, atol=1e-12)
    np.testing.assert_allclose(st.tails, sk.rest_tails, atol=1e-12)
    np.testing.assert_allclose(st.frames, sk.rest_frames, atol=1e-12)


def test_forward_keeps_lengths_and_offsets() -> None:
    sk = tree_skeleton()
    pose = Pose(random_rotations(sk.n_bones), np.zeros((sk.n_bones, 3)))
    st = sk.forward(pose)
    np.testing.assert_allclose(np.linalg.norm(st.tails - st.heads, axis=1), sk.lengths,
                               atol=1e-12)
    # Unconnected child keeps its rest offset from the parent's head, rigidly.
    off_rest = np.linalg.norm(sk.rest_heads[2] - sk.rest_heads[0])
    np.testing.assert_allclose(np.linalg.norm(st.heads[2] - st.heads[0]), off_rest, atol=1e-12)
    # Connected child sits on the parent's tail.
    np.testing.assert_allclose(st.heads[3], st.tails[2], atol=1e-12)


@pytest.mark.parametrize("path", ["_forward_levels", "_forward_floats"])
@pytest.mark.parametrize("inherit_arm", [True, False])
def test_forward_matches_recursive_definition(inherit_arm: bool, path: str) -> None:
    """Both forward-kinematics paths (per depth, and bone by bone for chains)."""
    sk = tree_skeleton()
    inherit = sk.inherit_rotation.copy()
    inherit[2] = inherit_arm  # arm.L, which has a child
    sk = type(sk)(sk.names, sk.parents, sk.rest_heads, sk.rest_tails, sk.rest_frames,
                  inherit, sk.connected, sk.deform)
    q = random_rotations(sk.n_bones)
    t = RNG.normal(size=(sk.n_bones, 3)) * 0.1
    rel_rot, rel_off = sk.rest_relative
    st = getattr(sk, path)(q, rel_off + np.einsum("nij,nj->ni", rel_rot, t))
    whole = sk.forward(Pose(q, t))
    np.testing.assert_allclose(whole.frames, st.frames, atol=1e-12)
    np.testing.assert_allclose(whole.tails, st.tails, atol=1e-12)
    R, r = sk.rest_frames, sk.rest_heads
    for i in range(sk.n_bones):
        p = sk.parents[i]
        if p < 0:
            np.testing.assert_allclose(st.frames[i], R[i] @ q[i], atol=1e-12)
            np.testing.assert_allclose(st.heads[i], r[i] + R[i] @ t[i], atol=1e-12)
        else:
            carry = st.frames[p] @ R[p].T
            frame = carry @ R[i] @ q[i] if sk.inherit_rotation[i] else R[i] @ q[i]
            np.testing.assert_allclose(st.frames[i], frame, atol=1e-12)
            expected = st.heads[p] + carry @ (r[i] - r[p] + R[i] @ t[i])
            np.testing.assert_allclose(st.heads[i], expected, atol=1e-12)


def test_aim_local_points_bone_and_keeps_twist() -> None:
    sk = chain_skeleton(np.array([[0, 0, 0], [0, 0, 1], [0.5, 0, 1.5], [1, 0, 1.5]], float))
    pose = Pose(random_rotations(sk.n_bones), np.zeros((sk.n_bones, 3)))
    st = sk.forward(pose)
    target = np.array([0.3, -0.4, 0.8])
    q = sk.aim_local(1, target, st, pose.rotations[1])
    new = sk.forward(pose.with_rotations([1], q[None]))
    np.testing.assert_allclose(new.frames[1][:, 1], target / np.linalg.norm(target), atol=1e-12)
    twist_before = sk.twist_angles(pose)[1]
    twist_after = sk.twist_angles(pose.with_rotations([1], q[None]))[1]
    assert twist_after == pytest.approx(twist_before, abs=1e-9)


def test_skeleton_rejects_bad_input() -> None:
    sk = tree_skeleton()
    with pytest.raises(InputError, match="parents before children"):
        type(sk)(sk.names, sk.parents[::-1].copy(), sk.rest_heads, sk.rest_tails,
                 sk.rest_frames, sk.inherit_rotation, sk.connected, sk.deform)
    heads = sk.rest_heads.copy()
    heads[1, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        type(sk)(sk.names, sk.parents, heads, sk.rest_tails, sk.rest_frames,
                 sk.inherit_rotation, sk.connected, sk.deform)
    with pytest.raises(InputError, match="no bone named 'tail'"):
        sk.index("tail")


@pytest.mark.parametrize("ortho", [False, True])
def test_camera_project_unproject_roundtrip(ortho: bool) -> None:
    cam = front_camera(ortho)
    pts = RNG.normal(size=(30, 3)) * 0.5 + [0, 0, 0.8]
    px = cam.project(pts)
    back = cam.unproject_at_depth(px, cam.depth(pts))
    np.testing.assert_allclose(back, pts, atol=1e-9)
    origins, dirs = cam.rays(px)
    # Each point lies on its ray.
    rel = pts - origins
    np.testing.assert_allclose(np.linalg.norm(np.cross(rel, dirs), axis=1), 0, atol=1e-9)
    # The target projects to the image centre.
    np.testing.assert_allclose(cam.project(np.array([[0, 0, 0.8]])), [[400, 300]], atol=1e-9)


def test_camera_scale_and_orientation() -> None:
    cam = front_camera(ortho=True)
    assert cam.pixels_per_unit(6.0) == pytest.approx(800 / 3.0)
    # World +x is to the right, +z up in a front view looking along +y.
    p = cam.project(np.array([[0, 0, 0.8], [1, 0, 0.8], [0, 0, 1.8]]))
    assert p[1, 0] > p[0, 0] and p[2, 1] > p[0, 1]
    np.testing.assert_allclose(cam.forward, [0, 1, 0], atol=1e-12)
    with pytest.raises(InputError, match="parallel"):
        Camera.look_at([0, 0, 5], [0, 0, 0], up=[0, 0, 1])


def test_stroke_arclength_resample_and_curvature() -> None:
    theta = np.linspace(0, np.pi, 400)
    circle = np.stack([50 * np.cos(theta), 50 * np.sin(theta)], 1)
    s = Stroke(circle)
    assert s.length == pytest.approx(50 * np.pi, rel=1e-4)
    pts = s.resample(2.0)
    gaps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    assert gaps.max() - gaps.min() < 0.02
    k = s.curvature(np.linspace(5, s.length - 5, 20))
    np.testing.assert_allclose(k, 1 / 50, rtol=2e-3)
    assert s.closest_param(np.array([0.0, 60.0])) == pytest.approx(s.length / 2, abs=1.0)


def test_stroke_rejects_bad_points() -> None:
    with pytest.raises(InputError, match="single point"):
        Stroke(np.array([[1.0, 1.0], [1.0, 1.0]]))
    with pytest.raises(InputError, match="NaN"):
        Stroke(np.array([[1.0, 1.0], [np.nan, 2.0]]))
    with pytest.raises(InputError, match=r"shape \(n, 2\)"):
        Stroke(np.zeros((3, 3)))


def test_distance_to_polyline_exact_on_a_square() -> None:
    from gesture_pose.core.stroke import distance_to_polyline

    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    pts = np.array([[5, -3], [12, 5], [5, 5], [-4, 13], [10, 10]], float)
    np.testing.assert_allclose(distance_to_polyline(pts, square), [3, 2, 5, 5, 0], atol=1e-12)


def test_distance_to_polyline_tree_path_matches_every_segment() -> None:
    from gesture_pose.core.stroke import (
        _BRUTE_FORCE_PAIRS,
        _segment_distance,
        distance_to_polyline,
    )

    rng = np.random.default_rng(4)
    for _ in range(40):
        n = int(rng.integers(120, 400))
        # Mixed segment lengths: dense runs and long straight spans.
        steps = rng.normal(0.0, 1.0, (n, 2)) * rng.choice([0.5, 40.0], (n, 1), p=[0.9, 0.1])
        line = np.cumsum(steps, axis=0)
        pts = rng.uniform(line.min(0) - 30, line.max(0) + 30, (int(rng.integers(40, 120)), 2))
        assert len(pts) * (n - 1) > _BRUTE_FORCE_PAIRS
        every = _segment_distance(pts[:, None], line[None, :-1], line[None, 1:]).min(axis=1)
        np.testing.assert_allclose(distance_to_polyline(pts, line), every, atol=1e-9)


def test_camera_survives_a_pickle_round_trip() -> None:
    import pickle

    cam = front_camera()
    fresh = pickle.loads(pickle.dumps(cam))
    cam.project(np.zeros((1, 3)))  # fills the cached matrices of the original
    again = pickle.loads(pickle.dumps(cam))
    pix = np.array([[10.0, 20.0]])
    for c in (fresh, again):
        np.testing.assert_allclose(c.full_matrix, cam.full_matrix)
        np.testing.assert_allclose(c.rays(pix)[1], cam.rays(pix)[1])
