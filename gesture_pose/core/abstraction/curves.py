"""Abstraction curves: polylines of rigged points and their arc-length resampling.

An abstraction is a list of curves, each a polyline of rigged points (the vertices of a curve
object, a Grease Pencil stroke or a chain of mesh edges that deform with the armature). The
solver works on curves resampled to equal arc-length spacing; since skinning is linear in
the rigged points, a resampled point is the same blend of two raw points at every pose, so
resampling is a fixed sparse matrix applied to the raw points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ..exceptions import InputError

#: Default number of abstraction points over all curves (the issue's benchmark size).
DEFAULT_POINT_BUDGET = 400
#: Fewest points a resampled curve keeps.
MIN_CURVE_POINTS = 8


@dataclass(frozen=True)
class CurveLayout:
    """Where each curve's points are in a stacked point array.

    Attributes:
        names: Curve names, shape ``(c,)``.
        offsets: Curve ``i`` spans points ``offsets[i]:offsets[i + 1]``, shape ``(c + 1,)``.
    """

    names: tuple[str, ...]
    offsets: np.ndarray

    def __post_init__(self) -> None:
        """Check that every curve has at least two points."""
        off = np.asarray(self.offsets, dtype=int)
        if off.shape != (len(self.names) + 1,) or off[0] != 0:
            raise InputError("Curve offsets must start at 0 and have one entry per curve + 1.")
        if len(self.names) == 0:
            raise InputError("The abstraction has no curves: add curves to the "
                             "'Sketch Abstraction' collection or pick an abstraction.")
        if np.any(np.diff(off) < 2):
            short = self.names[int(np.flatnonzero(np.diff(off) < 2)[0])]
            raise InputError(f"Abstraction curve '{short}' has fewer than two points.")
        object.__setattr__(self, "offsets", off)

    @property
    def n_curves(self) -> int:
        """Number of curves."""
        return len(self.names)

    @property
    def n_points(self) -> int:
        """Total number of points."""
        return int(self.offsets[-1])

    def curve(self, i: int) -> slice:
        """Slice of curve ``i``'s points."""
        return slice(int(self.offsets[i]), int(self.offsets[i + 1]))


def polyline_arclength(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length along a polyline, shape ``(n, d) -> (n,)``."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def resampling_matrix(points: np.ndarray, layout: CurveLayout,
                      budget: int = DEFAULT_POINT_BUDGET) -> tuple[sparse.csr_matrix, CurveLayout]:
    """Equal arc-length resampling of every curve as a sparse blend of its raw points.

    The budget is shared among curves in proportion to their lengths (at least
    :data:`MIN_CURVE_POINTS` each). When the raw points are fewer than the budget they are
    all kept as well (merged in arc-length order), so the resampled polyline keeps every
    corner and its arc length equals the raw one (in-order correspondences stay exact).

    Args:
        points: Raw points at the current pose, shape ``(m_raw, 3)``.
        layout: Curves of the raw points.
        budget: Total number of points wanted.

    Returns:
        ``(S, new_layout)``: ``S`` of shape ``(m, m_raw)`` with two entries per row (weights
        summing to 1), and the layout of the resampled points.

    Raises:
        InputError: A curve has zero length.
    """
    pts = np.asarray(points, dtype=float)
    lengths = np.array([polyline_arclength(pts[layout.curve(i)])[-1]
                        for i in range(layout.n_curves)])
    if np.any(lengths <= 1e-12):
        bad = layout.names[int(np.flatnonzero(lengths <= 1e-12)[0])]
        raise InputError(f"Abstraction curve '{bad}' has zero length.")
    counts = np.maximum(np.round(budget * lengths / lengths.sum()).astype(int), MIN_CURVE_POINTS)
    rows, cols, vals = [], [], []
    start = 0
    for i, count in enumerate(counts):
        sl = layout.curve(i)
        s = polyline_arclength(pts[sl])
        keep_raw = layout.n_points <= budget
        u = np.linspace(0.0, s[-1], max(count - len(s), 2) if keep_raw else count)
        if keep_raw:
            u = np.unique(np.concatenate([u, s]))
            u = u[np.concatenate([[True], np.diff(u) > 1e-9 * s[-1]])]
            count = len(u)
        seg = np.clip(np.searchsorted(s, u, side="right") - 1, 0, len(s) - 2)
        frac = np.clip((u - s[seg]) / np.maximum(s[seg + 1] - s[seg], 1e-15), 0.0, 1.0)
        r = np.arange(start, start + count)
        rows += [r, r]
        cols += [sl.start + seg, sl.start + seg + 1]
        vals += [1.0 - frac, frac]
        start += count
        counts[i] = count
    mat = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                            shape=(start, layout.n_points))
    return mat, CurveLayout(layout.names, np.concatenate([[0], np.cumsum(counts)]))


def resample_rigged(weighted_rest: np.ndarray, matrix: sparse.csr_matrix) -> np.ndarray:
    """Apply a resampling matrix to rigged points ``Y``: ``(m_raw, n, 4) -> (m, n, 4)``."""
    flat = np.asarray(weighted_rest).reshape(len(weighted_rest), -1)
    return np.asarray(matrix @ flat).reshape((matrix.shape[0],) + weighted_rest.shape[1:])
