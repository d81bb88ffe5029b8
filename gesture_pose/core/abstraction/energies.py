"""Matching energy and regularizers as Gauss-Newton quadratic models (Hahn et al. 2015).

Around the current pose every term is a sum of weighted squared residuals
``sum_q w_q |r_q + J_q dp|^2`` with the rig linearized in the subspace of the parameters
(Eqs. 5-6, 11: ``x(p + dp) ~ x + J_x dp``, ``z(p + dp) ~ z + J_z dp``). Units: pixel
residuals are divided by the image scale ``ppu`` (pixels per world unit at the character's
depth) so that every term is in squared world units and the paper's weights apply:

- ``E_match`` (Eq. 3): mean squared distance between the projected abstraction
  correspondences and their stroke targets.
- ``W_pose`` (Eq. 8, lambda 0.5): squared change of every parameter since the start of the
  solve, each weighted by how much mesh it moves (the diagonal of ``J_z^T M J_z`` over the
  representative vertices, so radians become world units): the new pose stays near the
  one before the drawing, and parameters the drawing does not see stay where they were
  (no coupling, so an unconstrained hand is not bent back to keep still). The solver lowers
  its weight over the iterations (see :mod:`.solver`) so reachable drawings are matched.
- ``W_plane`` (Eq. 9, lambda 0.01): mean squared displacement along the view axis since the
  start of the solve (depth cannot be seen in a drawing, so poses that keep the mesh in
  its view planes are preferred among those matching the strokes equally well).
- ``W_dist`` (Eq. 10, lambda 0.001): mean squared change of the distances between
  neighbouring representative vertices relative to the pose before the solve (against
  stretching by scales).

Vertex sums use the representatives and masses of :mod:`.coarsening` (Eq. 12).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ..camera import Camera
from ..rotations import normalize
from .coarsening import Coarsening
from .correspondences import Correspondences

LAMBDA_POSE = 0.5
LAMBDA_PLANE = 0.01
LAMBDA_DIST = 0.001


@dataclass(frozen=True)
class QuadraticModel:
    """``E(dp) ~ E0 + 2 g^T dp + dp^T H dp`` summed over terms.

    Attributes:
        hessian: ``H``, shape ``(P, P)``.
        gradient: ``g``, shape ``(P,)``.
        energies: Value of each term at ``dp = 0`` (world units squared).
    """

    hessian: np.ndarray
    gradient: np.ndarray
    energies: dict

    @property
    def energy(self) -> float:
        """Total energy at ``dp = 0``."""
        return float(sum(self.energies.values()))

    def predicted(self, dp: np.ndarray) -> float:
        """Model energy at ``dp``."""
        return self.energy + 2.0 * float(self.gradient @ dp) + float(dp @ self.hessian @ dp)


def projection_jacobian(camera: Camera, points: np.ndarray) -> np.ndarray:
    """Derivative of :meth:`Camera.project` with respect to world points.

    Args:
        camera: The view.
        points: World points, shape ``(m, 3)``.

    Returns:
        ``d pixels / d point``, shape ``(m, 2, 3)``, pixels per world unit.
    """
    full = camera.full_matrix
    clip = points @ full[:3, :3].T + full[:3, 3]
    w = points @ full[3, :3] + full[3, 3]
    xy = clip[:, :2]
    jac = (full[None, :2, :3] * w[:, None, None] - xy[:, :, None] * full[None, 3:4, :3])
    jac /= (w**2)[:, None, None]
    return jac * (0.5 * np.array([camera.width, camera.height]))[None, :, None]


def _quadratic(res: np.ndarray, jac: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                          float]:
    """``H, g, E`` of ``sum_q w_q |res_q + jac_q dp|^2`` for ``res (q, d)``, ``jac (q, d, P)``."""
    sw = np.sqrt(w)
    flat = (jac * sw[:, None, None]).reshape(-1, jac.shape[2])
    rw = (res * sw[:, None]).ravel()
    return flat.T @ flat, rw @ flat, float(rw @ rw)


def match_term(camera: Camera, x: np.ndarray, jac_x: np.ndarray, corr: Correspondences,
               ppu: float) -> tuple[np.ndarray, np.ndarray, float]:
    """``E_match`` of Eq. 3 linearized: ``(H, g, E)``.

    Args:
        camera: The view the strokes were drawn in.
        x: Abstraction points, shape ``(m, 3)``.
        jac_x: ``J_x``, shape ``(m, 3, P)``.
        corr: Correspondences at the current pose.
        ppu: Pixels per world unit used to express residuals in world units.
    """
    jpix = projection_jacobian(camera, x) @ jac_x  # (m, 2, P), batched products
    res = corr.residuals(camera.project(x)) / ppu
    m, _, p = jpix.shape
    if corr.selects is not None:  # rows pick single points (in-order): no blending
        jrows = jpix[corr.selects] / ppu
    else:
        jrows = np.asarray(corr.blend @ jpix.reshape(m, 2 * p)).reshape(-1, 2, p) / ppu
    return _quadratic(res, jrows, corr.weights)


def regularizer_terms(camera: Camera, z: np.ndarray, jac_z: np.ndarray, coarse: Coarsening,
                      z_start: np.ndarray, rest_distances: np.ndarray,
                      lambdas: tuple[float, float, float]
                      ) -> tuple[np.ndarray, np.ndarray, dict]:
    """``W_pose`` metric, ``W_plane`` and ``W_dist`` (Eqs. 8-10) on representative vertices.

    Args:
        camera: The view (for the view rays of ``W_plane``).
        z: Representative vertices at the current pose, shape ``(k, 3)``.
        jac_z: ``J_z``, shape ``(k, 3, P)``.
        coarse: Masses and neighbour pairs of the representatives.
        z_start: Representative vertices before the solve, shape ``(k, 3)``.
        rest_distances: Pair distances before the solve, shape ``(e,)``.
        lambdas: ``(lambda_pose, lambda_plane, lambda_dist)`` (``lambda_pose`` unused here).

    Returns:
        ``(H, g, energies)`` of ``W_plane`` and ``W_dist`` at ``dp = 0`` (``W_pose`` is
        :func:`pose_term`).
    """
    _, lam_plane, lam_dist = lambdas
    total = coarse.masses.sum()
    p = jac_z.shape[2]
    h = np.zeros((p, p))
    g = np.zeros(p)
    jdepth = (camera.forward @ jac_z)[:, None, :]  # (k, 1, P)
    depth = ((z - z_start) @ camera.forward)[:, None]
    hd, gd, ed = _quadratic(depth, jdepth, lam_plane * coarse.masses / total)
    h += hd
    g += gd
    energies = {"W_plane": ed, "W_dist": 0.0}
    if len(coarse.pairs) and lam_dist > 0:
        a, b = coarse.pairs[:, 0], coarse.pairs[:, 1]
        diff = z[a] - z[b]
        dist = np.linalg.norm(diff, axis=1)
        u = normalize(diff)
        # d |z_a - z_b| = u . (J_a - J_b) dp as one sparse product over the pairs.
        e = len(a)
        rows = np.repeat(np.arange(e), 6)
        cols = np.concatenate([3 * a[:, None] + np.arange(3), 3 * b[:, None]
                               + np.arange(3)], axis=1).ravel()
        vals = np.concatenate([u, -u], axis=1).ravel()
        diff_op = sparse.csr_matrix((vals, (rows, cols)), shape=(e, 3 * len(z)))
        jd = np.asarray(diff_op @ jac_z.reshape(3 * len(z), p))[:, None, :]
        w = lam_dist * coarse.pair_masses / coarse.pair_masses.sum()
        hw, gw, ew = _quadratic((dist - rest_distances)[:, None], jd, w)
        h += hw
        g += gw
        energies["W_dist"] = ew
    return h, g, energies


def pose_metric(jac_z: np.ndarray, coarse: Coarsening) -> np.ndarray:
    """Mesh motion per unit of each parameter: ``diag(J_z^T M J_z) / sum(M)``, ``(P,)``.

    Args:
        jac_z: ``J_z`` of the representatives, shape ``(k, 3, P)``.
        coarse: Their masses (Eq. 12).

    Returns:
        World units squared per squared parameter unit (floored so no entry is zero).
    """
    m = coarse.masses / coarse.masses.sum()
    diag = np.einsum("k,kdp->p", m, jac_z * jac_z)
    return np.maximum(diag, 1e-6 * max(float(diag.max(initial=0.0)), 1e-12))


def pose_term(metric: np.ndarray, deviation: np.ndarray, lam: float
              ) -> tuple[np.ndarray, np.ndarray, float]:
    """``W_pose`` of Eq. 8: ``lam sum_i D_i (e_i + dp_i)^2``.

    Args:
        metric: ``D`` from :func:`pose_metric`, shape ``(P,)``.
        deviation: Parameters' change since the start ``e``, shape ``(P,)``.
        lam: Weight.

    Returns:
        ``(H, g, E)`` at ``dp = 0``.
    """
    w = lam * metric
    return np.diag(w), w * deviation, float(w @ deviation**2)


def pair_distances(z: np.ndarray, coarse: Coarsening) -> np.ndarray:
    """Distances between the representative pairs, shape ``(e,)``."""
    if len(coarse.pairs) == 0:
        return np.zeros(0)
    return np.linalg.norm(z[coarse.pairs[:, 0]] - z[coarse.pairs[:, 1]], axis=1)


def full_regularizer_value(camera: Camera, z1: np.ndarray, coarse: Coarsening,
                           z_start: np.ndarray, rest_distances: np.ndarray,
                           lambdas: tuple[float, float, float]) -> dict:
    """Exact (not linearized) ``W_plane`` and ``W_dist`` with representatives at ``z1``.

    Returns:
        ``{"W_plane", "W_dist"}`` in world units squared.
    """
    _, lam_plane, lam_dist = lambdas
    m = coarse.masses / coarse.masses.sum()
    depth = (z1 - z_start) @ camera.forward
    out = {"W_plane": lam_plane * float(m @ depth**2), "W_dist": 0.0}
    if len(coarse.pairs):
        w = coarse.pair_masses / coarse.pair_masses.sum()
        out["W_dist"] = lam_dist * float(w @ (pair_distances(z1, coarse) - rest_distances) ** 2)
    return out
