"""Normalization of the drawn stick figure (Section 4.1.3).

A bone of length ``L`` at view depth ``z`` projects to at most ``L * s(z)`` pixels
(``s`` the image scale at that depth). A drawn edge longer than this cannot be matched by
any 3D pose, so the whole figure is scaled about its pelvis node until every drawn edge
fits.
"""

from __future__ import annotations

import numpy as np

from .graph import StickFigure


def drawing_scale(stick: StickFigure, lengths_3d: np.ndarray, quantile: float = 1.0) -> float:
    """Pixels per world unit suggested by the drawing: the largest drawn/3D edge ratio.

    Foreshortening only shortens edges, so the largest ratio (``quantile`` 1) is the
    least foreshortened edge's.

    Args:
        stick: The drawing.
        lengths_3d: 3D length of every stick edge ``(parent, child)`` of the figure,
            indexed by the child joint, shape ``(J,)``.
        quantile: Quantile of the ratios.

    Returns:
        Pixels per world unit.
    """
    e = stick.drawn_edges()
    drawn = np.linalg.norm(stick.points[e[:, 1]] - stick.points[e[:, 0]], axis=1)
    return float(np.quantile(drawn / np.maximum(lengths_3d[e[:, 1]], 1e-9), quantile))


def normalize_figure(stick: StickFigure, lengths_3d: np.ndarray,
                     pixels_per_unit: float | np.ndarray, root: int = 0,
                     tolerance: float = 1.15) -> tuple[StickFigure, float]:
    """Scale the figure so that no drawn edge is longer than its largest projection.

    Args:
        stick: The drawing.
        lengths_3d: 3D edge lengths indexed by the child joint, shape ``(J,)``.
        pixels_per_unit: Image scale at the figure's depth, or per joint ``(J,)`` the
            largest scale an edge ending there can have (at the nearest depth it can reach:
            a head bent towards the eye projects larger than the pelvis' depth allows).
        root: Joint kept fixed (the pelvis).
        tolerance: Edges up to this many times their largest projection are accepted
            (the depth the scale is read at is itself an estimate).

    Returns:
        ``(stick, factor)``: the (possibly) scaled drawing and the factor (1 when nothing
        was too long).
    """
    e = stick.drawn_edges()
    drawn = np.linalg.norm(stick.points[e[:, 1]] - stick.points[e[:, 0]], axis=1)
    ppu = np.broadcast_to(np.asarray(pixels_per_unit, float), (stick.points.shape[0],))
    limit = lengths_3d[e[:, 1]] * ppu[e[:, 1]] * tolerance
    factor = float(min(1.0, np.min(limit / np.maximum(drawn, 1e-9))))
    if factor >= 1.0:
        return stick, 1.0
    center = stick.points[root]
    return stick.with_points(center + (stick.points - center) * factor), factor
