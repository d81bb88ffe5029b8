"""Matching costs of the 2D embedding (Gesture3D Section 5.2-5.3, Eq. 2-4).

All costs are functions of positions so the discrete solver (candidate tables) and the
continuous refinement (moved joints) share them.

- Unary ``C(i, P)``: a joint's circle of radius ``r`` centred at ``P`` is sampled; a circle
  sample is *aligned* when a contour sample lies within ``min(epsilon, r / 2)`` with normals
  within ``alpha = 15`` degrees. ``C = 1 - f / f_ref`` with ``f`` the aligned fraction and
  ``f_ref`` the fraction an ideal fit reaches (two tangent arcs of ``2 alpha`` for a joint
  inside a limb, a half circle plus those arcs for a terminal joint). Terminal joints need
  ``f >= 15%``; circles that a contour cuts through are unreliable; both cost 1.
- Pairwise ``E(i, j) = 1 - (1 - Cl)(1 - Ccf)(1 - Wc Cc)`` per bone with the length term
  ``Cl`` (Eq. 2, ``sigma`` = 4% of the diagonal, ``sigma / 3`` when the drawn bone is
  longer than the bone), contour conformity ``Ccf`` and consistency ``Cc``, ``Wc = 0.9``.
- Triplet naturalness ``Cn`` on consecutive bones with ``sigma_a = pi / 3`` when the three
  joints come from the same contour, else ``pi / 6``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .preprocess import Drawing


@dataclass(frozen=True)
class CostParams:
    """Cost parameters (the paper's values are the defaults).

    Attributes:
        alpha: Normal tolerance of aligned circle samples, radians.
        terminal_min_fraction: Matched circle fraction a terminal joint needs.
        circle_samples: Samples per joint circle.
        sigma_length: Length-term sigma as a fraction of the drawing diagonal.
        w_consistency: Weight ``Wc`` of the consistency term.
        sigma_angle_shared: ``sigma_a`` when the three joints share a contour, radians.
        sigma_angle: ``sigma_a`` otherwise, radians.
        conform_angle: Largest angle between a conforming contour sample and its bone.
        rigid_sigma: Length sigma of rigid offsets (unconnected heads), fraction of diagonal.
    """

    alpha: float = np.radians(15.0)
    terminal_min_fraction: float = 0.15
    circle_samples: int = 48
    sigma_length: float = 0.04
    w_consistency: float = 0.9
    sigma_angle_shared: float = np.pi / 3
    sigma_angle: float = np.pi / 6
    conform_angle: float = np.radians(30.0)
    rigid_sigma: float = 0.02


def circle_alignment(drawing: Drawing, centres: np.ndarray, radii: np.ndarray,
                     params: CostParams = CostParams()) -> np.ndarray:
    """Aligned contour sample of every circle sample, or -1.

    Args:
        drawing: The preprocessed drawing.
        centres: Circle centres, pixels, ``(K, 2)``.
        radii: Circle radii, pixels, ``(K,)``.
        params: Cost parameters.

    Returns:
        Sample indices, shape ``(K, M)`` int, -1 where nothing aligns.
    """
    m = params.circle_samples
    ang = np.linspace(0.0, 2 * np.pi, m, endpoint=False)
    u = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    centres = np.asarray(centres, float).reshape(-1, 2)
    radii = np.broadcast_to(np.asarray(radii, float), (len(centres),))
    tol = np.minimum(drawing.epsilon, radii / 2.0)
    q = centres[:, None, :] + radii[:, None, None] * u[None]
    dist, idx = drawing.tree.query(q.reshape(-1, 2), k=3, distance_upper_bound=float(tol.max()))
    dist = dist.reshape(len(centres), m, 3)
    idx = idx.reshape(len(centres), m, 3)
    found = dist <= tol[:, None, None]
    safe = np.where(found, idx, 0)
    cos = np.abs(np.einsum("kmsd,md->kms", drawing.normals[safe], u))
    ok = found & (cos > np.cos(params.alpha))
    first = np.argmax(ok, axis=2)
    hit = ok.any(axis=2)
    chosen = np.take_along_axis(safe, first[..., None], axis=2)[..., 0]
    return np.where(hit, chosen, -1)


def unary_cost(drawing: Drawing, centres: np.ndarray, radii: np.ndarray, terminal: bool,
               params: CostParams = CostParams()) -> tuple[np.ndarray, np.ndarray]:
    """Unary cost ``C(i, P)`` of circles (see the module docstring).

    Args:
        drawing: The preprocessed drawing.
        centres: Circle centres, pixels, ``(K, 2)``.
        radii: Radii, pixels, ``(K,)``.
        terminal: Whether the joint is terminal (no child joint).
        params: Cost parameters.

    Returns:
        ``(cost (K,), aligned (K, M))`` with ``aligned`` from :func:`circle_alignment`.
    """
    aligned = circle_alignment(drawing, centres, radii, params)
    frac = (aligned >= 0).mean(axis=1)
    a = params.alpha
    f_ref = (np.pi + 2 * a) / (2 * np.pi) if terminal else 2 * a / np.pi
    cost = 1.0 - np.clip(frac / f_ref, 0.0, 1.0)
    if terminal:
        cost = np.where(frac < params.terminal_min_fraction, 1.0, cost)
    radii = np.broadcast_to(np.asarray(radii, float), (len(cost),))
    nearest = drawing.tree.query(np.asarray(centres, float).reshape(-1, 2), k=1)[0]
    cut = nearest < radii - np.minimum(drawing.epsilon, radii / 2.0)
    return np.where(cut, 1.0, cost), aligned


def length_cost(dist: np.ndarray, length: float, sigma: float) -> np.ndarray:
    """Length term ``Cl`` (Eq. 2): Gaussian misfit, three times stricter when too long.

    Args:
        dist: Drawn bone lengths, pixels, any shape.
        length: Expected bone length, pixels.
        sigma: Standard deviation, pixels.
    """
    s = np.where(dist > length, sigma / 3.0, sigma)
    return 1.0 - np.exp(-((dist - length) ** 2) / (2.0 * s**2))


def _local_samples(drawing: Drawing, pa: np.ndarray, pb: np.ndarray, reach: float) -> np.ndarray:
    """Indices of contour samples within ``reach`` of the box around all endpoints."""
    lo = np.minimum(pa.min(axis=0), pb.min(axis=0)) - reach
    hi = np.maximum(pa.max(axis=0), pb.max(axis=0)) + reach
    inside = np.all((drawing.points >= lo) & (drawing.points <= hi), axis=1)
    return np.flatnonzero(inside)


def bone_frame(drawing: Drawing, pa: np.ndarray, pb: np.ndarray, idx: np.ndarray):
    """Axis parameter ``t`` and signed offset ``h`` of samples ``idx`` for all bone pairs.

    Returns:
        ``(t, h, dist, u)``: ``t, h`` of shape ``(Ka, Kb, n)``, ``dist (Ka, Kb)``, unit axes
        ``u (Ka, Kb, 2)``. ``h > 0`` left of the bone (head to tail).
    """
    d = pb[None, :, :] - pa[:, None, :]
    dist = np.linalg.norm(d, axis=2)
    u = d / np.maximum(dist, 1e-9)[..., None]
    rel = drawing.points[idx][None, None, :, :] - pa[:, None, None, :]
    t = np.einsum("abnd,abd->abn", rel, u) / np.maximum(dist, 1e-9)[..., None]
    h = u[..., None, 0] * rel[..., 1] - u[..., None, 1] * rel[..., 0]
    return t, h, dist, u


def pair_cost(drawing: Drawing, pa: np.ndarray, ra: np.ndarray, ga: np.ndarray,
              sa: np.ndarray, pb: np.ndarray, rb: np.ndarray, gb: np.ndarray, sb: np.ndarray,
              length: float, params: CostParams = CostParams()) -> np.ndarray:
    """Pairwise bone cost ``E(i, j) = 1 - (1 - Cl)(1 - Ccf)(1 - Wc Cc)``.

    Args:
        drawing: The preprocessed drawing.
        pa: Head joint positions, pixels, ``(Ka, 2)``.
        ra: Their radii, pixels, ``(Ka,)``.
        ga: Contour of their originating samples (-1 for grid), ``(Ka,)``.
        sa: Side of their originating contour (+1, -1, 0 grid), ``(Ka,)``.
        pb: Tail joint positions, pixels, ``(Kb, 2)``.
        rb: Their radii, pixels, ``(Kb,)``.
        gb: Contour of their originating samples, ``(Kb,)``.
        sb: Side of their originating contour, ``(Kb,)``.
        length: Expected drawn length (bind length times the view scale), pixels.
        params: Cost parameters.

    Returns:
        Costs, shape ``(Ka, Kb)``.
    """
    pa, pb = np.asarray(pa, float).reshape(-1, 2), np.asarray(pb, float).reshape(-1, 2)
    eps = drawing.epsilon
    reach = 1.5 * max(float(np.max(ra)), float(np.max(rb))) + eps
    idx = _local_samples(drawing, pa, pb, reach)
    dist = np.linalg.norm(pb[None] - pa[:, None], axis=2)
    cl = length_cost(dist, length, params.sigma_length * drawing.diagonal)
    if idx.size == 0:
        ccf = np.ones_like(dist)
        cc = np.zeros_like(dist)
    else:
        t, h, dist, u = bone_frame(drawing, pa, pb, idx)
        r_t = (1.0 - t) * ra[:, None, None] + t * rb[None, :, None]
        along = np.abs(np.einsum("nd,abd->abn", drawing.normals[idx], u))
        conform = ((t >= 0) & (t <= 1) & (np.abs(np.abs(h) - r_t) < np.maximum(eps, 0.5 * r_t))
                   & (along < np.sin(params.conform_angle)))
        need = np.maximum(dist / eps, 1.0)
        left = np.minimum((conform & (h > 0)).sum(axis=2) / need, 1.0)
        right = np.minimum((conform & (h < 0)).sum(axis=2) / need, 1.0)
        ccf = 1.0 - 0.5 * (left + right)
        grp = drawing.group[idx]
        own = (grp[None, None, :] == ga[:, None, None]) | (grp[None, None, :] == gb[None, :, None])
        cross = (t > 0.05) & (t < 0.95) & (np.abs(h) < 0.5 * eps) & own
        cc = cross.any(axis=2).astype(float)
    same = (ga[:, None] == gb[None, :]) & (ga[:, None] >= 0)
    opposite = same & (sa[:, None] * sb[None, :] < 0)
    cc = np.maximum(cc, opposite.astype(float))
    return 1.0 - (1.0 - cl) * (1.0 - ccf) * (1.0 - params.w_consistency * cc)


def rigid_cost(drawing: Drawing, pa: np.ndarray, pb: np.ndarray, length: float,
               params: CostParams = CostParams()) -> np.ndarray:
    """Cost of a rigid offset link (an unconnected head): its length term only, ``(Ka, Kb)``."""
    dist = np.linalg.norm(np.asarray(pb, float)[None] - np.asarray(pa, float)[:, None], axis=2)
    sigma = params.rigid_sigma * drawing.diagonal
    return 1.0 - np.exp(-((dist - length) ** 2) / (2.0 * sigma**2))


def triplet_cost(pa: np.ndarray, pb: np.ndarray, pc: np.ndarray, shared: np.ndarray,
                 rest_angle: float, params: CostParams = CostParams()) -> np.ndarray:
    """Naturalness ``Cn`` of consecutive bones ``a -> b -> c``, shape ``(Ka, Kb, Kc)``.

    The turning angle at ``b`` is compared with the bind pose's angle between the bones;
    ``sigma_a`` is wider where the three joints come from the same contour (``shared``).

    Args:
        pa: First joint positions, pixels, ``(Ka, 2)``.
        pb: Middle joint positions, pixels, ``(Kb, 2)``.
        pc: Last joint positions, pixels, ``(Kc, 2)``.
        shared: Whether the three joints share an originating contour, ``(Ka, Kb, Kc)``.
        rest_angle: Angle between the two bones in the bind pose, radians.
        params: Cost parameters.
    """
    d1 = pb[None, :, :] - pa[:, None, :]
    d2 = pc[None, :, :] - pb[:, None, :]
    n1 = np.linalg.norm(d1, axis=2)
    n2 = np.linalg.norm(d2, axis=2)
    cos = np.einsum("abd,bcd->abc", d1, d2) / np.maximum(n1[:, :, None] * n2[None], 1e-9)
    ang = np.arccos(np.clip(cos, -1.0, 1.0))
    sigma = np.where(shared, params.sigma_angle_shared, params.sigma_angle)
    return 1.0 - np.exp(-((ang - rest_angle) ** 2) / (2.0 * sigma**2))
