"""Correspondences between projected abstraction curves and drawn strokes (Hahn et al. 2015).

Two procedures give, for the matching energy of Eq. 3, pairs of (a blend of projected
abstraction points, a target pixel):

- **in-order**: both curves are parametrized by normalized arc length in their drawing
  direction, so abstraction point ``i`` at fraction ``u_i`` of its projected curve is paired
  with the stroke point at fraction ``u_i`` of the stroke;
- **closest point**: each abstraction point is paired with the closest point of the stroke,
  and each stroke sample with the closest point of the projected curve (both directions, so
  a curve cannot shrink onto part of a stroke).

Strokes are assigned to curves by drawing order (i-th stroke to i-th curve) or by proximity
(an optimal assignment on the mean symmetric distance).

All correspondences are rows ``sum_i C[q, i] pi(x_i) - T[q]`` with a sparse ``C``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from ..exceptions import InputError
from ..stroke import Stroke
from .curves import CurveLayout, polyline_arclength

IN_ORDER = "IN_ORDER"
CLOSEST = "CLOSEST"
#: In-order ICP followed by closest-point ICP (see :func:`.solver.solve_abstraction`).
IN_ORDER_CLOSEST = "IN_ORDER_CLOSEST"
BY_ORDER = "ORDER"
BY_PROXIMITY = "PROXIMITY"
#: Sampling step of strokes for the assignment costs, pixels.
ASSIGNMENT_STEP = 4.0


@dataclass(frozen=True)
class Correspondences:
    """Matching rows of Eq. 3.

    Attributes:
        blend: Sparse ``C``, shape ``(q, m)``: each row blends projected abstraction points.
        targets: Target pixels ``T``, shape ``(q, 2)``.
        weights: Row weights, shape ``(q,)`` (summing to 1).
        pairs: ``(curve, stroke)`` index pairs that were matched.
        selects: When every row of ``C`` picks one point with weight 1 (in-order rows),
            the point of each row, ``(q,)`` (a faster path than the sparse product);
            else None.
    """

    blend: sparse.csr_matrix
    targets: np.ndarray
    weights: np.ndarray
    pairs: tuple[tuple[int, int], ...]
    selects: np.ndarray | None = None

    def residuals(self, pixels: np.ndarray) -> np.ndarray:
        """Pixel residuals ``C pi(x) - T`` for projected points ``(m, 2)``, shape ``(q, 2)``."""
        if self.selects is not None:
            return pixels[self.selects] - self.targets
        return np.asarray(self.blend @ pixels) - self.targets


def _closest_on_polyline(queries: np.ndarray, poly: np.ndarray, candidates: int = 3,
                         tree: cKDTree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of a polyline to queries.

    Only the segments next to the ``candidates`` nearest polyline vertices of each query
    are tested (a KD-tree query), which finds the exact closest point unless a farther
    vertex has a much longer segment passing closer; for the densely sampled strokes and
    curves here that does not happen.

    Args:
        queries: Points, shape ``(q, 2)``.
        poly: Polyline, shape ``(k, 2)``, ``k >= 2``.
        candidates: Nearest vertices whose adjacent segments are tested.
        tree: KD-tree of ``poly`` (built here when None).

    Returns:
        ``(segment (q,), fraction (q,))``: the closest point is
        ``poly[seg] + frac (poly[seg + 1] - poly[seg])``.
    """
    n_seg = len(poly) - 1
    k = min(candidates, len(poly))
    _, near = (cKDTree(poly) if tree is None else tree).query(queries, k=k)
    near = near.reshape(len(queries), k)
    segs = np.clip(np.concatenate([near - 1, near], axis=1), 0, n_seg - 1)  # (q, 2k)
    a, ab = poly[segs], poly[segs + 1] - poly[segs]
    denom = np.maximum(np.sum(ab * ab, axis=2), 1e-18)
    t = np.clip(np.sum((queries[:, None, :] - a) * ab, axis=2) / denom, 0.0, 1.0)
    d2 = np.sum((a + t[..., None] * ab - queries[:, None, :]) ** 2, axis=2)
    best = np.argmin(d2, axis=1)
    rows = np.arange(len(queries))
    return segs[rows, best], t[rows, best]


def polyline_at(stroke: Stroke, s: np.ndarray) -> np.ndarray:
    """Points of the drawn polyline (linear between samples) at arc lengths ``s``, ``(q, 2)``.

    The drawn samples are used as they are (no spline), so sharp corners stay sharp.
    """
    arc = stroke.arclength
    s = np.clip(np.asarray(s, dtype=float), 0.0, arc[-1])
    return np.stack([np.interp(s, arc, stroke.points[:, d]) for d in range(2)], axis=1)


def assignment_cost(curve: np.ndarray, stroke_pts: np.ndarray,
                    trees: tuple[cKDTree | None, cKDTree | None] = (None, None)) -> float:
    """Cost of matching a stroke to a curve: shape distance plus end-point distance, pixels.

    The shape distance is the mean distance from every point of each polyline to the
    nearest point of the other (both densely sampled, so nearest points stand for nearest
    segments). It alone prefers a long curve that happens to pass near a redrawn limb (a
    torso outline near a raised arm); a limb is redrawn from where it is attached, so the
    mean distance between the two curves' end points (in either drawing direction) is
    added.

    Args:
        curve: Projected curve, ``(m, 2)`` pixels.
        stroke_pts: Stroke samples, ``(s, 2)`` pixels.
        trees: KD-trees of ``(curve, stroke_pts)`` when already built.
    """
    curve_tree = cKDTree(curve) if trees[0] is None else trees[0]
    stroke_tree = cKDTree(stroke_pts) if trees[1] is None else trees[1]
    shape = 0.5 * (float(stroke_tree.query(curve)[0].mean())
                   + float(curve_tree.query(stroke_pts)[0].mean()))
    ends = (curve[0], curve[-1])
    same = 0.5 * (np.linalg.norm(ends[0] - stroke_pts[0]) + np.linalg.norm(ends[1]
                                                                           - stroke_pts[-1]))
    flipped = 0.5 * (np.linalg.norm(ends[0] - stroke_pts[-1]) + np.linalg.norm(
        ends[1] - stroke_pts[0]))
    return shape + float(min(same, flipped))


def assign_strokes(curves_2d: list[np.ndarray], strokes: list[Stroke],
                   mode: str = BY_PROXIMITY) -> tuple[tuple[int, int], ...]:
    """Assign strokes to abstraction curves.

    With ``"PROXIMITY"`` the assignment minimizes the summed :func:`assignment_cost` (an
    optimal assignment, so two strokes never share a curve). Strokes far from the
    character are refused before (see :func:`.checks.check_strokes_near`).

    Args:
        curves_2d: Projected curves, each ``(m_i, 2)`` pixels.
        strokes: Drawn strokes, oldest first.
        mode: ``"ORDER"`` (stroke ``i`` to curve ``i``) or ``"PROXIMITY"``.

    Returns:
        ``(curve, stroke)`` pairs, as many as ``min(len(curves), len(strokes))``.

    Raises:
        InputError: No stroke or an unknown mode.
    """
    if not strokes:
        raise InputError("There is no stroke to pose from: draw strokes in the sketch object.")
    k = min(len(curves_2d), len(strokes))
    if mode == BY_ORDER:
        return tuple((i, i) for i in range(k))
    if mode != BY_PROXIMITY:
        raise InputError(f"Unknown stroke assignment '{mode}': use ORDER or PROXIMITY.")
    cost = np.empty((len(curves_2d), len(strokes)))
    curve_trees = [cKDTree(c) for c in curves_2d]
    for j, stroke in enumerate(strokes):
        pts = polyline_at(stroke, stroke.sample_params(ASSIGNMENT_STEP))
        tree = cKDTree(pts)
        for i, curve in enumerate(curves_2d):
            cost[i, j] = assignment_cost(curve, pts, (curve_trees[i], tree))
    rows, cols = linear_sum_assignment(cost)
    return tuple(sorted((int(r), int(c)) for r, c in zip(rows, cols, strict=True)))


def in_order_rows(curve: np.ndarray, stroke: Stroke) -> tuple[np.ndarray, np.ndarray]:
    """In-order targets: normalized arc length on the projected curve mapped onto the stroke.

    Args:
        curve: Projected (resampled) abstraction curve, shape ``(m, 2)`` pixels.
        stroke: Its stroke.

    Returns:
        ``(point_indices (m,), targets (m, 2))``, indices local to the curve.
    """
    s = polyline_arclength(curve)
    u = s / max(s[-1], 1e-12)
    return np.arange(len(curve)), polyline_at(stroke, u * stroke.length)


def closest_rows(curve: np.ndarray, stroke: Stroke, step: float = 2.0
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Closest-point rows in both directions.

    Args:
        curve: Projected abstraction curve, shape ``(m, 2)`` pixels.
        stroke: Its stroke.
        step: Sampling step of the stroke, pixels.

    Returns:
        ``(rows, cols, vals, targets, m, k)``: the local blend's entries (``m`` rows of
        curve-to-stroke pairs, each one curve point with weight 1, then ``k`` rows of
        stroke-to-curve pairs, each blending the two ends of a curve segment; ``rows`` and
        ``vals`` of shape ``(m + 2k,)``), the targets ``(m + k, 2)`` pixels (closest stroke
        points, then the ``k`` stroke samples), and ``m`` and ``k``.
    """
    poly = polyline_at(stroke, stroke.sample_params(step))
    m = len(curve)
    seg, t = _closest_on_polyline(curve, poly)
    fwd_targets = poly[seg] + t[:, None] * (poly[seg + 1] - poly[seg])
    seg_b, t_b = _closest_on_polyline(poly, curve)
    k = len(poly)
    rows = np.concatenate([np.arange(m), m + np.arange(k), m + np.arange(k)])
    cols = np.concatenate([np.arange(m), seg_b, seg_b + 1])
    vals = np.concatenate([np.ones(m), 1.0 - t_b, t_b])
    return rows, cols, vals, np.concatenate([fwd_targets, poly]), m, k


def build_correspondences(pixels: np.ndarray, layout: CurveLayout, strokes: list[Stroke],
                          pairs: tuple[tuple[int, int], ...],
                          procedure: str = IN_ORDER) -> Correspondences:
    """Correspondences of every matched (curve, stroke) pair at the current pose.

    Each matched curve gets the same total weight; within the closest-point procedure the
    two directions share it equally.

    Args:
        pixels: Projected abstraction points, shape ``(m, 2)``.
        layout: Curves of the points.
        strokes: Drawn strokes.
        pairs: ``(curve, stroke)`` pairs from :func:`assign_strokes`.
        procedure: ``"IN_ORDER"`` or ``"CLOSEST"``.

    Returns:
        The correspondences.
    """
    if procedure not in (IN_ORDER, CLOSEST):
        raise InputError(f"Unknown correspondence procedure '{procedure}': use IN_ORDER or "
                         "CLOSEST.")
    if not np.all(np.isfinite(pixels)):
        raise InputError("Part of the abstraction is behind the view: move the view back.")
    rows, cols, vals, targets, weights = [], [], [], [], []
    start = 0
    share = 1.0 / len(pairs)
    for c, s in pairs:
        sl = layout.curve(c)
        curve = pixels[sl]
        if procedure == IN_ORDER:
            idx, tgt = in_order_rows(curve, strokes[s])
            r, cc, v = idx, idx, np.ones(len(idx))
            w = np.full(len(idx), share / len(idx))
        else:
            r, cc, v, tgt, m, k = closest_rows(curve, strokes[s])
            w = np.concatenate([np.full(m, 0.5 * share / m), np.full(k, 0.5 * share / k)])
        rows.append(r + start)
        cols.append(cc + sl.start)
        vals.append(v)
        targets.append(tgt)
        weights.append(w)
        start += len(tgt)
    cols_all = np.concatenate(cols)
    blend = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), cols_all)),
                              shape=(start, len(pixels)))
    selects = cols_all if procedure == IN_ORDER else None
    return Correspondences(blend, np.concatenate(targets), np.concatenate(weights), pairs,
                           selects)
