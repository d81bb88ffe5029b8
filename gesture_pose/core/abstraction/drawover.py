"""Draw-over abstractions: a stroke projected onto the deformed mesh (Hahn et al. 2015, Sec. 6).

Without an authored abstraction, the first stroke drawn over the character becomes one: a
ray through each stroke point hits the deformed mesh, and the hit is stored as barycentric
coordinates on its triangle. The point then moves with the skinning of the three vertices,
``x = sum_k b_k z_k(p)``, so its rigged rest vectors are ``Y_j = sum_k b_k w_kj [zbar_k; 1]``
(see :mod:`.rig`). The next stroke is its target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ..camera import Camera
from ..exceptions import InputError

#: Rays tested against all triangles at once, per chunk (memory bound).
_CHUNK = 64


def ray_triangle(origins: np.ndarray, directions: np.ndarray, v0: np.ndarray, v1: np.ndarray,
                 v2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First hit of every ray with a set of triangles (Moller-Trumbore, vectorized).

    Args:
        origins: Ray origins, shape ``(r, 3)``.
        directions: Ray directions, shape ``(r, 3)``.
        v0: First corners, shape ``(t, 3)``.
        v1: Second corners, shape ``(t, 3)``.
        v2: Third corners, shape ``(t, 3)``.

    Returns:
        ``(triangle (r,), distance (r,), barycentric (r, 3))``; ``triangle`` is -1 (and
        the distance infinite) where the ray misses every triangle.
    """
    e1, e2 = v1 - v0, v2 - v0
    tri = np.full(len(origins), -1)
    dist = np.full(len(origins), np.inf)
    bary = np.zeros((len(origins), 3))
    for a in range(0, len(origins), _CHUNK):
        o, d = origins[a:a + _CHUNK], directions[a:a + _CHUNK]
        pvec = np.cross(d[:, None, :], e2[None])
        det = np.einsum("td,rtd->rt", e1, pvec)
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tvec = o[:, None, :] - v0[None]
        u = np.einsum("rtd,rtd->rt", tvec, pvec) * inv
        qvec = np.cross(tvec, e1[None])
        v = np.einsum("rd,rtd->rt", d, qvec) * inv
        t = np.einsum("td,rtd->rt", e2, qvec) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        t = np.where(hit, t, np.inf)
        best = np.argmin(t, axis=1)
        rows = np.arange(len(o))
        found = np.isfinite(t[rows, best])
        tri[a:a + _CHUNK] = np.where(found, best, -1)
        dist[a:a + _CHUNK] = t[rows, best]
        bu, bv = u[rows, best], v[rows, best]
        bary[a:a + _CHUNK] = np.where(found[:, None], np.stack([1 - bu - bv, bu, bv], 1), 0.0)
    return tri, dist, bary


@dataclass(frozen=True)
class SurfaceCurve:
    """A stroke projected onto the mesh.

    Attributes:
        triangles: Hit triangle of every kept stroke point, shape ``(q,)``.
        barycentric: Barycentric coordinates on it, shape ``(q, 3)``.
        blend: Sparse ``(q, V)`` matrix giving the points from mesh vertices.
        kept: Indices of the stroke points that hit the mesh, shape ``(q,)``.
    """

    triangles: np.ndarray
    barycentric: np.ndarray
    blend: sparse.csr_matrix
    kept: np.ndarray

    def points(self, vertices: np.ndarray) -> np.ndarray:
        """The curve's points on a mesh with these vertices ``(V, 3)``, shape ``(q, 3)``."""
        return np.asarray(self.blend @ vertices)

    def rigged_rest(self, weighted_rest: np.ndarray) -> np.ndarray:
        """Rigged rest vectors of the points from the vertices' ``Y (V, n, 4)``, ``(q, n, 4)``."""
        flat = weighted_rest.reshape(len(weighted_rest), -1)
        return np.asarray(self.blend @ flat).reshape((len(self.kept),) + weighted_rest.shape[1:])


def project_onto_mesh(pixels: np.ndarray, camera: Camera, vertices: np.ndarray,
                      triangles: np.ndarray, min_hits: int = 2) -> SurfaceCurve:
    """Project a drawn stroke onto the deformed mesh, one ray per stroke point.

    Args:
        pixels: Stroke points, shape ``(s, 2)`` pixels.
        camera: The view it was drawn in.
        vertices: Deformed mesh vertices, shape ``(V, 3)`` world.
        triangles: Vertex indices of the triangles, shape ``(T, 3)``.
        min_hits: Fewest points that must hit the mesh.

    Returns:
        The surface curve (points that missed the mesh are dropped).

    Raises:
        InputError: Fewer than ``min_hits`` stroke points are over the character.
    """
    tris = np.asarray(triangles, dtype=int)
    origins, dirs = camera.rays(np.asarray(pixels, dtype=float))
    v = np.asarray(vertices, dtype=float)
    tri, _, bary = ray_triangle(origins, dirs, v[tris[:, 0]], v[tris[:, 1]], v[tris[:, 2]])
    kept = np.flatnonzero(tri >= 0)
    if kept.size < min_hits:
        raise InputError("The source stroke is not over the character: draw the first "
                         "stroke on the character's body.")
    rows = np.repeat(np.arange(kept.size), 3)
    cols = tris[tri[kept]].ravel()
    blend = sparse.csr_matrix((bary[kept].ravel(), (rows, cols)), shape=(kept.size, len(v)))
    return SurfaceCurve(tri[kept], bary[kept], blend, kept)
