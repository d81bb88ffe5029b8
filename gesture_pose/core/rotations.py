"""Vectorized rotation helpers on numpy arrays.

All functions accept leading batch dimensions. Rotation matrices act on column vectors.
Quaternions are ``(w, x, y, z)`` as in Blender.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def normalize(v: np.ndarray, axis: int = -1) -> np.ndarray:
    """Return ``v`` scaled to unit length along ``axis`` (zero vectors stay zero).

    Args:
        v: Array of vectors, shape ``(..., k)``.
        axis: Axis holding the vector components.

    Returns:
        Array of the same shape.
    """
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return np.where(n > _EPS, v / np.maximum(n, _EPS), 0.0)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]_x`` with ``[v]_x w = v x w``.

    Args:
        v: Vectors, shape ``(..., 3)``.

    Returns:
        Matrices, shape ``(..., 3, 3)``.
    """
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2
    )


def exp_map(omega: np.ndarray) -> np.ndarray:
    """Rotation matrices from rotation vectors (Rodrigues' formula).

    Args:
        omega: Rotation vectors (axis times angle in radians), shape ``(..., 3)``.

    Returns:
        Rotation matrices, shape ``(..., 3, 3)``.
    """
    omega = np.asarray(omega, dtype=float)
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    k = skew(omega)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    eye = np.broadcast_to(np.eye(3), k.shape)
    return eye + a * k + b * (k @ k)


def log_map(r: np.ndarray) -> np.ndarray:
    """Rotation vectors from rotation matrices (inverse of :func:`exp_map`).

    Args:
        r: Rotation matrices, shape ``(..., 3, 3)``.

    Returns:
        Rotation vectors, shape ``(..., 3)``, angle in ``[0, pi]``.
    """
    return quat_to_rotvec(matrix_to_quat(r))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors from quaternions ``(w, x, y, z)``.

    Args:
        q: Quaternions, shape ``(..., 4)`` (need not be unit length).

    Returns:
        Rotation vectors, shape ``(..., 3)``.
    """
    q = normalize(np.asarray(q, dtype=float))
    q = np.where(q[..., :1] < 0.0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-12), 2.0)
    return q[..., 1:] * scale[..., None]


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(w, x, y, z)`` from rotation matrices (Shepperd's method).

    Args:
        r: Rotation matrices, shape ``(..., 3, 3)``.

    Returns:
        Quaternions with ``w >= 0``, shape ``(..., 4)``.
    """
    r = np.asarray(r, dtype=float)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack(
        [
            np.stack([1 + tr, r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                      r[..., 1, 0] - r[..., 0, 1]], -1),
            np.stack([r[..., 2, 1] - r[..., 1, 2], 1 + m00 - m11 - m22,
                      r[..., 0, 1] + r[..., 1, 0], r[..., 0, 2] + r[..., 2, 0]], -1),
            np.stack([r[..., 0, 2] - r[..., 2, 0], r[..., 0, 1] + r[..., 1, 0],
                      1 - m00 + m11 - m22, r[..., 1, 2] + r[..., 2, 1]], -1),
            np.stack([r[..., 1, 0] - r[..., 0, 1], r[..., 0, 2] + r[..., 2, 0],
                      r[..., 1, 2] + r[..., 2, 1], 1 - m00 - m11 + m22], -1),
        ],
        -2,
    )
    diag = np.stack([tr, m00, m11, m22], -1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    q = normalize(q)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices from quaternions ``(w, x, y, z)``.

    Args:
        q: Quaternions, shape ``(..., 4)`` (normalized here).

    Returns:
        Rotation matrices, shape ``(..., 3, 3)``.
    """
    w, x, y, z = np.moveaxis(normalize(np.asarray(q, dtype=float)), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotations taking directions ``a`` to directions ``b``.

    For opposite directions the rotation is a half turn about an axis orthogonal to ``a``.

    Args:
        a: Source directions, shape ``(..., 3)``.
        b: Target directions, shape ``(..., 3)``.

    Returns:
        Rotation matrices ``R`` with ``R a/|a| = b/|b|``, shape ``(..., 3, 3)``.
    """
    a = normalize(np.asarray(a, dtype=float))
    b = normalize(np.asarray(b, dtype=float))
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=-1)
    c = np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)
    angle = np.arctan2(s, c)
    # Antiparallel: pick any axis orthogonal to a.
    helper = np.where(np.abs(a[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    ortho = normalize(np.cross(a, helper))
    axis = np.where((s < 1e-9)[..., None], ortho, axis / np.maximum(s, 1e-300)[..., None])
    return exp_map(axis * angle[..., None])


def swing_twist(r: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split rotations into ``R = swing @ twist`` with ``twist`` about ``axis``.

    Args:
        r: Rotation matrices, shape ``(..., 3, 3)``.
        axis: Unit twist axes in the frame ``r`` acts on, shape ``(..., 3)``.

    Returns:
        ``(swing, twist_angle)``: swing matrices ``(..., 3, 3)`` (no component about
        ``axis``) and signed twist angles about ``axis`` in radians ``(...)``.
    """
    q = matrix_to_quat(r)
    axis = normalize(np.asarray(axis, dtype=float))
    proj = np.sum(q[..., 1:] * axis, axis=-1)
    twist_angle = 2.0 * np.arctan2(proj, q[..., 0])
    twist_angle = (twist_angle + np.pi) % (2.0 * np.pi) - np.pi
    twist = exp_map(axis * twist_angle[..., None])
    swing = r @ np.swapaxes(twist, -1, -2)
    return swing, twist_angle


def orthonormalize(r: np.ndarray) -> np.ndarray:
    """Nearest rotation matrices (polar decomposition via SVD).

    Args:
        r: Matrices, shape ``(..., 3, 3)``.

    Returns:
        Proper rotation matrices, shape ``(..., 3, 3)``.
    """
    u, _, vt = np.linalg.svd(np.asarray(r, dtype=float))
    d = np.sign(np.linalg.det(u @ vt))
    u = u * np.concatenate([np.ones(d.shape + (2,)), d[..., None]], -1)[..., None, :]
    return u @ vt
