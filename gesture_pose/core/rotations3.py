"""Single 3x3 rotations on Python floats.

The per-joint loops (line-of-action posing, ``Skeleton.aim_local``) work on one bone at a
time; numpy's per-call overhead would dominate there, and numpy hands even 3x3 products to
BLAS, whose thread pool makes each call several times slower on a busy machine. Inputs and
outputs are numpy arrays; the arithmetic is on floats.
"""

from __future__ import annotations

import math

import numpy as np

_Y = np.array([0.0, 1.0, 0.0])


def rotation_between3(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Smallest rotation taking unit vector ``a`` to unit vector ``b``, and its angle.

    Written on Python floats: this runs once or twice per joint and numpy's per-call
    overhead on 3-vectors would dominate the solve.

    Args:
        a: Unit vector, shape ``(3,)``.
        b: Unit vector, shape ``(3,)``.

    Returns:
        ``(R (3, 3), angle in radians)`` with ``R a = b`` (Rodrigues:
        ``R = cos t I + sin t [k]_x + (1 - cos t) k k^T``).
    """
    ax, ay, az = a.tolist()
    bx, by, bz = b.tolist()
    kx, ky, kz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    s = math.sqrt(kx * kx + ky * ky + kz * kz)
    c = max(-1.0, min(1.0, ax * bx + ay * by + az * bz))
    angle = math.atan2(s, c)
    if s < 1e-12:
        if c > 0.0:
            return np.eye(3), 0.0
        kx, ky, kz = (0.0, -az, ay) if abs(ax) < 0.9 else (az, 0.0, -ax)
        s = math.sqrt(kx * kx + ky * ky + kz * kz)
    kx, ky, kz = kx / s, ky / s, kz / s
    sn, cs = math.sin(angle), math.cos(angle)
    t = 1.0 - cs
    return np.array([
        [cs + t * kx * kx, t * kx * ky - sn * kz, t * kx * kz + sn * ky],
        [t * kx * ky + sn * kz, cs + t * ky * ky, t * ky * kz - sn * kx],
        [t * kx * kz - sn * ky, t * ky * kz + sn * kx, cs + t * kz * kz],
    ]), angle


def mm3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for ``(3, 3)`` matrices on Python floats.

    numpy hands even 3x3 products to BLAS, whose thread pool makes each call several times
    slower on a busy machine; the per-joint loop stays clear of it.
    """
    return np.array(_mul(a.tolist(), b.tolist()))


def _mul(a: list, b: list) -> list[list[float]]:
    """``a @ b`` for 3x3 nested lists, written out."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return [
        [a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21,
         a00 * b02 + a01 * b12 + a02 * b22],
        [a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21,
         a10 * b02 + a11 * b12 + a12 * b22],
        [a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21,
         a20 * b02 + a21 * b12 + a22 * b22]]


def _mul_bt(a: list, b: list) -> list[list[float]]:
    """``a @ b.T`` for 3x3 nested lists, written out."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return [
        [a00 * b00 + a01 * b01 + a02 * b02, a00 * b10 + a01 * b11 + a02 * b12,
         a00 * b20 + a01 * b21 + a02 * b22],
        [a10 * b00 + a11 * b01 + a12 * b02, a10 * b10 + a11 * b11 + a12 * b12,
         a10 * b20 + a11 * b21 + a12 * b22],
        [a20 * b00 + a21 * b01 + a22 * b02, a20 * b10 + a21 * b11 + a22 * b12,
         a20 * b20 + a21 * b21 + a22 * b22]]


def mv3(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``a @ v`` for a ``(3, 3)`` matrix and a 3-vector on Python floats (see :func:`mm3`)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a.tolist()
    x, y, z = v.tolist()
    return np.array([a00 * x + a01 * y + a02 * z, a10 * x + a11 * y + a12 * z,
                     a20 * x + a21 * y + a22 * z])


def _swing_from_y(v: list[float]) -> list[list[float]] | None:
    """Smallest rotation taking y to the unit vector ``v``, as nested lists.

    With ``K = [y x v]_x``: ``R = I + K + K^2 / (1 + v_y)``, written out. None when ``v`` is
    (nearly) ``-y``, where the swing's axis is undefined.
    """
    a, c, b = v
    if c < -1.0 + 1e-9:
        return None
    k = 1.0 / (1.0 + c)
    return [[1.0 - a * a * k, a, -a * b * k], [-a, c, -b], [-a * b * k, b, 1.0 - b * b * k]]


def reswing(q: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``S_new T``: ``q = S T`` (swing-twist about y) with its swing replaced.

    ``S_new`` takes y to the unit vector ``target``; the twist ``T = S^T q`` is kept. One
    pass on Python floats (this runs once per joint).

    Args:
        q: Local rotation, shape ``(3, 3)``.
        target: Unit direction of the bone in its parent-carried frame, shape ``(3,)``.

    Returns:
        Local rotation, shape ``(3, 3)``.
    """
    ql = q.tolist()
    yx, yy, yz = ql[0][1], ql[1][1], ql[2][1]
    m = math.sqrt(yx * yx + yy * yy + yz * yz)
    s_old = _swing_from_y([yx / m, yy / m, yz / m])
    tx, ty, tz = target.tolist()
    n = math.sqrt(tx * tx + ty * ty + tz * tz)  # exactly unit, or the error would compound
    s_new = _swing_from_y([tx / n, ty / n, tz / n])
    if s_old is None or s_new is None:
        return mm3(rotation_between3(_Y, target)[0], twist_about_y(q))
    return np.array(_mul(_mul_bt(s_new, s_old), ql))  # S_new S_old^T q


def twist_about_y(q: np.ndarray) -> np.ndarray:
    """Twist factor ``T`` of ``q = S T`` (swing-twist about the bone's y axis), ``(3, 3)``."""
    swing, _ = rotation_between3(_Y, q[:, 1])
    return mm3(swing.T, q)
