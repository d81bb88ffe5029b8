"""Single 3x3 rotations on Python floats.

The per-joint loops (line-of-action posing, ``Skeleton.aim_local``) work on one bone at a
time; numpy's per-call overhead would dominate there, and numpy hands even 3x3 products to
BLAS, whose thread pool makes each call several times slower on a busy machine.

The routines work on nested Python lists (``M3``: three rows of three floats; ``V3``:
three floats), for loops that keep their whole state in floats; :func:`reswing` wraps
:func:`swap_swing` for numpy arrays.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

M3 = list[list[float]]
V3 = Sequence[float]

_IDENTITY: M3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
_Y_AXIS = (0.0, 1.0, 0.0)


def mul(a: M3, b: M3) -> M3:
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


def transpose(a: M3) -> M3:
    """``a.T`` for a 3x3 nested list."""
    return [[a[0][0], a[1][0], a[2][0]], [a[0][1], a[1][1], a[2][1]],
            [a[0][2], a[1][2], a[2][2]]]


def mv(a: M3, v: V3) -> list[float]:
    """``a @ v`` for a 3x3 nested list and three floats."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    x, y, z = v
    return [a00 * x + a01 * y + a02 * z, a10 * x + a11 * y + a12 * z,
            a20 * x + a21 * y + a22 * z]


def mtv(a: M3, v: V3) -> list[float]:
    """``a.T @ v`` for a 3x3 nested list and three floats."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    x, y, z = v
    return [a00 * x + a10 * y + a20 * z, a01 * x + a11 * y + a21 * z,
            a02 * x + a12 * y + a22 * z]


def between(a: V3, b: V3) -> tuple[M3, float]:
    """Smallest rotation taking unit vector ``a`` to unit vector ``b``, and its angle.

    Rodrigues: ``R = cos t I + sin t [k]_x + (1 - cos t) k k^T``; opposite vectors turn
    about an axis orthogonal to ``a``.
    """
    ax, ay, az = a
    bx, by, bz = b
    kx, ky, kz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    s = math.sqrt(kx * kx + ky * ky + kz * kz)
    c = max(-1.0, min(1.0, ax * bx + ay * by + az * bz))
    angle = math.atan2(s, c)
    if s < 1e-12:
        if c > 0.0:
            return [row[:] for row in _IDENTITY], 0.0
        kx, ky, kz = (0.0, -az, ay) if abs(ax) < 0.9 else (az, 0.0, -ax)
        s = math.sqrt(kx * kx + ky * ky + kz * kz)
    kx, ky, kz = kx / s, ky / s, kz / s
    sn, cs = math.sin(angle), math.cos(angle)
    t = 1.0 - cs
    return [
        [cs + t * kx * kx, t * kx * ky - sn * kz, t * kx * kz + sn * ky],
        [t * kx * ky + sn * kz, cs + t * ky * ky, t * ky * kz - sn * kx],
        [t * kx * kz - sn * ky, t * ky * kz + sn * kx, cs + t * kz * kz],
    ], angle


def _swing_from_y(v: V3) -> M3 | None:
    """Smallest rotation taking y to the unit vector ``v``, as nested lists.

    With ``K = [y x v]_x``: ``R = I + K + K^2 / (1 + v_y)``, written out. None when ``v`` is
    (nearly) ``-y``, where the swing's axis is undefined.
    """
    a, c, b = v
    if c < -1.0 + 1e-9:
        return None
    k = 1.0 / (1.0 + c)
    return [[1.0 - a * a * k, a, -a * b * k], [-a, c, -b], [-a * b * k, b, 1.0 - b * b * k]]


def twist(q: M3) -> M3:
    """Twist factor ``T`` of ``q = S T`` (swing-twist about the bone's y axis)."""
    swing, _ = between(_Y_AXIS, [q[0][1], q[1][1], q[2][1]])
    return mul(transpose(swing), q)


def swap_swing(q: M3, target: V3) -> M3:
    """``S_new T``: ``q = S T`` (swing-twist about y) with its swing replaced.

    ``S_new`` takes y to the unit vector ``target``; the twist ``T = S^T q`` is kept.

    Args:
        q: Local rotation.
        target: Unit direction of the bone in its parent-carried frame.

    Returns:
        The local rotation.
    """
    yx, yy, yz = q[0][1], q[1][1], q[2][1]
    m = math.sqrt(yx * yx + yy * yy + yz * yz)
    s_old = _swing_from_y([yx / m, yy / m, yz / m])
    tx, ty, tz = target
    n = math.sqrt(tx * tx + ty * ty + tz * tz)  # exactly unit, or the error would compound
    unit = [tx / n, ty / n, tz / n]
    s_new = _swing_from_y(unit)
    if s_old is None or s_new is None:
        return mul(between(_Y_AXIS, unit)[0], twist(q))
    return mul(mul(s_new, transpose(s_old)), q)  # S_new S_old^T q


def reswing(q: np.ndarray, target: np.ndarray) -> np.ndarray:
    """:func:`swap_swing` on numpy arrays: ``q`` is ``(3, 3)``, ``target`` ``(3,)``."""
    return np.array(swap_swing(q.tolist(), target.tolist()))
