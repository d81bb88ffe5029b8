"""k-means coarsening (Eq. 12): exact at k = V, close at k << V, independent of resolution."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from gesture_pose.core.abstraction.coarsening import coarsen, neighbour_pairs
from gesture_pose.core.abstraction.energies import pair_distances, pose_metric, regularizer_terms
from gesture_pose.core.abstraction.parameters import ParameterSpace, RigPose
from gesture_pose.core.abstraction.rig import (
    RigTables,
    lbs_weighted_rest,
    point_jacobian,
    pose_bones,
)
from gesture_pose.core.rotations import exp_map
from tests.core.fixtures import front_camera, tree_skeleton
from tests.core.test_abstraction_solver import tube_mesh

LAMBDAS = (0.5, 0.01, 0.001)


def _mesh_jacobian(rings: int, segments: int):
    skel = tree_skeleton()
    verts, _, weights = tube_mesh(skel, rings=rings, segments=segments)
    space = ParameterSpace.from_masks(skel.parents, np.ones(6, bool), np.ones(6, bool))
    rng = np.random.default_rng(7)
    pose = RigPose(exp_map(rng.normal(scale=0.3, size=(6, 3))), np.ones(6), np.zeros((6, 3)))
    posed = pose_bones(skel, pose)
    y = lbs_weighted_rest(verts, weights)
    jac = point_jacobian(posed, y, space, pose, RigTables.of(skel))
    z = np.einsum("nij,mnj->mi", posed.skinning[:, :3, :], y)
    return z, jac, space


def _full_reference(z, jac, z_start, dp):
    """``W_plane`` and ``W_pose``'s metric written directly as sums over every vertex."""
    cam = front_camera()
    v = len(z)
    depth = (z + jac @ dp - z_start) @ cam.forward
    w_plane = LAMBDAS[1] / v * np.sum(depth**2)
    metric = np.array([np.sum(jac[:, :, c] ** 2) for c in range(jac.shape[2])]) / v
    return w_plane, metric


def _full_dist_reference(z, jac, z_start, dp, neighbours: int = 6) -> float:
    """``W_dist`` (Eq. 10, linearized in ``dp``) over every vertex's nearest neighbours."""
    _, nn = cKDTree(z).query(z, k=neighbours + 1)
    pairs = {tuple(sorted((i, int(j)))) for i in range(len(z)) for j in nn[i, 1:] if j != i}
    total = 0.0
    for a, b in pairs:
        diff = z[a] - z[b]
        d = np.linalg.norm(diff)
        moved = d + (diff / d) @ ((jac[a] - jac[b]) @ dp)
        total += (moved - np.linalg.norm(z_start[a] - z_start[b])) ** 2
    return LAMBDAS[2] * total / len(pairs)


def test_coarsened_regularizers_equal_full_when_k_is_vertex_count() -> None:
    z, jac, space = _mesh_jacobian(rings=4, segments=6)
    coarse = coarsen(z, k=len(z))
    assert len(coarse.indices) == len(z) and np.all(coarse.masses == 1)
    rng = np.random.default_rng(1)
    z_start = z - 0.01 * rng.normal(size=z.shape)
    h, g, e = regularizer_terms(front_camera(), z, jac, coarse, z_start,
                                pair_distances(z_start, coarse), LAMBDAS)
    assert e["W_dist"] > 0.0
    for _ in range(3):
        dp = rng.normal(scale=0.05, size=space.n_params)
        model = sum(e.values()) + 2 * g @ dp + dp @ h @ dp
        w_plane, metric = _full_reference(z, jac, z_start, dp)
        w_dist = _full_dist_reference(z, jac, z_start, dp)
        assert w_dist > 1e-3 * w_plane
        np.testing.assert_allclose(model, w_plane + w_dist, rtol=1e-10)
    np.testing.assert_allclose(pose_metric(jac, coarse), metric, rtol=1e-10)


def test_coarse_regularizer_approximates_full_and_ignores_resolution() -> None:
    shapes = []
    for rings, segments in ((8, 12), (24, 32)):
        z, jac, space = _mesh_jacobian(rings, segments)
        coarse = coarsen(z, k=200)
        assert len(coarse.indices) <= 200 and coarse.masses.sum() == len(z)
        rng = np.random.default_rng(2)
        dp = rng.normal(scale=0.05, size=space.n_params)
        zr, jr = z[coarse.indices], jac[coarse.indices]
        h, _, _ = regularizer_terms(front_camera(), zr, jr, coarse, zr,
                                    np.zeros(len(coarse.pairs)), (0.0, LAMBDAS[1], 0.0))
        w_plane, metric = _full_reference(z, jac, z, dp)
        np.testing.assert_allclose(dp @ h @ dp, w_plane, rtol=0.1)
        np.testing.assert_allclose(pose_metric(jr, coarse), metric, rtol=0.1)
        shapes.append(h.shape)
    assert shapes[0] == shapes[1]  # same problem size at 576 and 4608 vertices


def test_neighbour_pairs_are_unique_and_undirected() -> None:
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [10, 0, 0]])
    pairs = neighbour_pairs(pts, neighbours=1)
    np.testing.assert_array_equal(pairs, [[0, 1], [1, 2], [2, 3]])


def test_dist_pairs_only_join_vertices_moved_by_the_same_bones() -> None:
    # Two touching clusters of points driven by different bones.
    rng = np.random.default_rng(3)
    a = rng.normal(scale=0.01, size=(30, 3))
    b = rng.normal(scale=0.01, size=(30, 3)) + [0.03, 0, 0]
    w = np.zeros((60, 2))
    w[:30, 0] = 1.0
    w[30:, 1] = 1.0
    loose = coarsen(np.concatenate([a, b]), k=60)
    tied = coarsen(np.concatenate([a, b]), k=60, weights=w)
    side = lambda c: (c.indices[c.pairs] >= 30)  # noqa: E731
    assert np.any(side(loose)[:, 0] != side(loose)[:, 1])
    assert len(tied.pairs) > 0 and np.all(side(tied)[:, 0] == side(tied)[:, 1])
