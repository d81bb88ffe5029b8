"""Editing the drawn stick figure (Section 4.2).

Dragging a node a little moves only that node (local editing). Dragging it farther than
``global_radius`` pixels deforms the whole chain from the root (pelvis) to the node with a
Laplacian solve that keeps the chain's shape: the chain's interior nodes keep their
Laplacian coordinates ``delta_i = x_i - (x_{i-1} + x_{i+1}) / 2`` in the least-squares
sense while the root stays and the node goes where it was dragged; every part hanging off
the chain (the dragged node's children included) follows its attachment rigidly.
"""

from __future__ import annotations

import numpy as np

from ..exceptions import InputError
from .graph import StickFigure

#: Drags longer than this (pixels) are global.
GLOBAL_RADIUS = 40.0


def _chain(parents: np.ndarray, node: int) -> list[int]:
    """Joints from the root down to ``node``."""
    out = [node]
    while parents[out[-1]] >= 0:
        out.append(int(parents[out[-1]]))
    return out[::-1]


def laplacian_chain(points: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Move the last point of a polyline to ``target`` keeping the first and the shape.

    Args:
        points: Chain points, first fixed, shape ``(k, 2)``.
        target: New position of the last point, shape ``(2,)``.

    Returns:
        New chain points, shape ``(k, 2)``.
    """
    k = len(points)
    new = points.astype(float).copy()
    new[-1] = target
    if k <= 2:
        return new
    L = np.zeros((k - 2, k))
    rows = np.arange(k - 2)
    L[rows, rows] = -0.5
    L[rows, rows + 1] = 1.0
    L[rows, rows + 2] = -0.5
    delta = L @ points
    free = np.arange(1, k - 1)
    rhs = delta - L[:, [0, k - 1]] @ new[[0, k - 1]]
    new[free] = np.linalg.lstsq(L[:, free], rhs, rcond=None)[0]
    return new


def drag_node(stick: StickFigure, node: int, position: np.ndarray,
              global_radius: float = GLOBAL_RADIUS) -> StickFigure:
    """Drag one drawn joint.

    Args:
        stick: The drawing.
        node: Index of the dragged joint.
        position: Where it was dropped, pixels, shape ``(2,)``.
        global_radius: Drags longer than this (pixels) deform the chain from the root.

    Returns:
        The edited drawing.

    Raises:
        InputError: The joint is not drawn.
    """
    if not stick.present[node]:
        raise InputError(f"Joint '{stick.joint_names[node]}' is not in the drawing.")
    pos = np.asarray(position, float)
    pts = stick.points.copy()
    old = stick.points[node]
    if np.linalg.norm(pos - old) <= global_radius or stick.parents[node] < 0:
        pts[node] = pos
        return stick.with_points(pts)
    chain = _chain(stick.parents, node)
    pts[chain] = laplacian_chain(stick.points[chain], pos)
    moved = pts - stick.points
    on_chain = np.zeros(len(pts), bool)
    on_chain[chain] = True
    for j in range(len(pts)):  # joints are parents first
        if on_chain[j] or stick.parents[j] < 0:
            continue
        p = stick.parents[j]
        shift = moved[p]
        moved[j] = shift
        pts[j] = stick.points[j] + shift
    return stick.with_points(pts)
