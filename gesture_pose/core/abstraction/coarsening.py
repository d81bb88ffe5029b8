"""k-means coarsening of the mesh for the regularizers (Hahn et al. 2015, Eq. 12).

The regularizers sum over mesh vertices. To make their cost independent of the mesh
resolution, the vertices are clustered with k-means (``k = 200`` by default) and each cluster
is replaced by one representative vertex (the member closest to the centroid) weighted by
the cluster's size::

    sum_v f(z_v)  ~=  sum_c m_c f(z_rep(c))                                 (Eq. 12)

With ``k`` equal to the vertex count every vertex represents itself with mass 1 and the
coarsened sums are the full ones. ``W_dist`` uses pairs of neighbouring representatives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.spatial import cKDTree

from ..exceptions import InputError

#: Representative vertices of the paper.
DEFAULT_K = 200
#: Vertices the k-means++ seeding looks at (a random subset of larger meshes).
_SEED_SAMPLE = 1500
#: Neighbouring representatives per representative in ``W_dist``.
DEFAULT_NEIGHBOURS = 6


@dataclass(frozen=True)
class Coarsening:
    """Representative vertices of a mesh.

    Attributes:
        indices: Vertex index of each representative, shape ``(k,)``.
        masses: Number of vertices each one stands for, shape ``(k,)`` (sums to ``V``).
        pairs: Neighbouring representatives for ``W_dist``, shape ``(e, 2)`` (indices into
            the representatives).
        pair_masses: Weight of each pair, the mean mass of its ends, shape ``(e,)``.
        labels: Cluster of every vertex, shape ``(V,)``.
    """

    indices: np.ndarray
    masses: np.ndarray
    pairs: np.ndarray
    pair_masses: np.ndarray
    labels: np.ndarray

    @property
    def n_vertices(self) -> int:
        """Number of vertices of the full mesh."""
        return len(self.labels)


def neighbour_pairs(points: np.ndarray, neighbours: int = DEFAULT_NEIGHBOURS) -> np.ndarray:
    """Unique undirected pairs of each point with its nearest neighbours, shape ``(e, 2)``."""
    k = min(neighbours + 1, len(points))
    if k < 2:
        return np.zeros((0, 2), dtype=int)
    _, nn = cKDTree(points).query(points, k=k)
    a = np.repeat(np.arange(len(points)), k - 1)
    b = nn[:, 1:].ravel()
    pairs = np.sort(np.stack([a, b], axis=1), axis=1)
    return np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)


def coarsen(vertices: np.ndarray, k: int = DEFAULT_K, neighbours: int = DEFAULT_NEIGHBOURS,
            seed: int = 0, weights: np.ndarray | None = None,
            min_similarity: float = 0.95) -> Coarsening:
    """Cluster mesh vertices and pick one representative per cluster (Eq. 12).

    Args:
        vertices: Vertex positions, shape ``(V, 3)`` (the rest or current pose).
        k: Number of clusters; ``k >= V`` keeps every vertex.
        neighbours: Neighbours per representative for ``W_dist``.
        seed: Seed of the k-means initialization (deterministic results).
        weights: Bone weights of the vertices ``(V, n)``; when given, ``W_dist`` pairs are
            kept only between representatives moved by the same bones (cosine similarity
            of their weights at least ``min_similarity``), so that a hand resting near a
            thigh is not tied to it.
        min_similarity: Threshold of that similarity.

    Returns:
        The coarsening.

    Raises:
        InputError: No vertices or ``k < 1``.
    """
    v = np.asarray(vertices, dtype=float)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise InputError(f"Expected mesh vertices of shape (V, 3), got {v.shape}: the "
                         "character needs a skinned mesh.")
    if k < 1:
        raise InputError(f"The number of representative vertices must be positive, got {k}.")
    if k >= len(v):
        idx = np.arange(len(v))
        masses = np.ones(len(v))
        labels = idx.copy()
    else:
        rng = np.random.default_rng(seed)
        sample = v if len(v) <= _SEED_SAMPLE else v[rng.choice(len(v), _SEED_SAMPLE, False)]
        seeds, _ = kmeans2(sample, k, minit="++", seed=rng, iter=1)
        centroids, labels = kmeans2(v, seeds, minit="matrix", iter=10)
        used = np.unique(labels)
        d = np.linalg.norm(v - centroids[labels], axis=1)
        order = np.lexsort((d, labels))
        first = order[np.r_[True, labels[order][1:] != labels[order][:-1]]]
        idx = first
        masses = np.bincount(labels, minlength=len(centroids))[used].astype(float)
        remap = np.full(len(centroids), -1)
        remap[used] = np.arange(len(used))
        labels = remap[labels]
    pairs = neighbour_pairs(v[idx], neighbours)
    if weights is not None and len(pairs):
        w = np.asarray(weights, dtype=float)[idx]
        w = w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12)
        pairs = pairs[np.sum(w[pairs[:, 0]] * w[pairs[:, 1]], axis=1) >= min_similarity]
    pair_masses = 0.5 * (masses[pairs[:, 0]] + masses[pairs[:, 1]]) if len(pairs) else np.zeros(0)
    return Coarsening(idx, masses, pairs, pair_masses, labels)
