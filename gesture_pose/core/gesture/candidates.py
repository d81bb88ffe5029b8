"""Candidate joint locations (Gesture3D Section 5.1).

Visible joints sit at a radius from the contour: every contour sample proposes the two
tangential placements ``x +/- r n`` for each candidate radius ``r`` of the joint. Joints
hidden behind other parts get candidates on a regular grid at step epsilon. Placements
that land close together (they pile up near curvature extrema, where neighbouring samples'
normals converge) are consolidated into the cheapest one per epsilon cell, and each joint
keeps its best ``max_candidates`` placements for the MRF.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .costs import CostParams, unary_cost
from .preprocess import Drawing


@dataclass(frozen=True)
class JointCandidates:
    """The candidate placements of one joint.

    Attributes:
        positions: Centres, pixels, ``(K, 2)``.
        radii: Circle radii, pixels, ``(K,)``.
        side: +1 left of the originating contour, -1 right, 0 grid, ``(K,)`` int.
        origin: Originating contour sample, -1 for grid placements, ``(K,)`` int.
        group: Contour of the originating sample, -1 for grid placements, ``(K,)`` int.
        unary: Unary cost ``C(i, P)``, ``(K,)``.
        aligned: Aligned contour sample of each circle sample or -1, ``(K, M)`` int.
    """

    positions: np.ndarray
    radii: np.ndarray
    side: np.ndarray
    origin: np.ndarray
    group: np.ndarray
    unary: np.ndarray
    aligned: np.ndarray

    def __len__(self) -> int:
        """Number of candidates ``K``."""
        return len(self.positions)

    def take(self, idx: np.ndarray) -> JointCandidates:
        """The candidates at ``idx`` (in that order)."""
        return JointCandidates(*(getattr(self, f)[idx] for f in _FIELDS))

    @staticmethod
    def concat(parts: list[JointCandidates]) -> JointCandidates:
        """All candidates of ``parts``, in order."""
        return JointCandidates(*(np.concatenate([getattr(p, f) for p in parts]) for f in _FIELDS))


_FIELDS = ("positions", "radii", "side", "origin", "group", "unary", "aligned")


def consolidate(cands: JointCandidates, cell: float) -> JointCandidates:
    """Keep the cheapest candidate of every ``cell``-sized square (ties: first index)."""
    if len(cands) == 0:
        return cands
    key = np.floor(cands.positions / cell).astype(np.int64)
    order = np.lexsort((np.arange(len(cands)), cands.unary, key[:, 1], key[:, 0]))
    k = key[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = np.any(k[1:] != k[:-1], axis=1)
    return cands.take(np.sort(order[first]))


def best(cands: JointCandidates, count: int) -> JointCandidates:
    """The ``count`` cheapest candidates (stable order)."""
    if len(cands) <= count:
        return cands
    order = np.argsort(cands.unary, kind="stable")[:count]
    return cands.take(np.sort(order))


def contour_candidates(drawing: Drawing, radii: np.ndarray, terminal: bool,
                       params: CostParams | None = None, max_candidates: int = 48,
                       max_cost: float = 0.95) -> JointCandidates:
    """Tangential placements on both sides of every contour sample at every radius.

    Args:
        drawing: The preprocessed drawing.
        radii: Candidate radii of the joint, pixels, ``(R,)``.
        terminal: Whether the joint is terminal.
        params: Cost parameters.
        max_candidates: Candidates kept after consolidation.
        max_cost: Placements costing more are dropped (the grid stands for them).

    Returns:
        The joint's contour candidates.
    """
    params = params or CostParams()
    n = drawing.n_samples
    radii = np.asarray(radii, dtype=float)
    side = np.array([1, -1])
    # Shape (2 sides, R radii, N samples).
    pos = (drawing.points[None, None] + side[:, None, None, None] * radii[None, :, None, None]
           * drawing.normals[None, None])
    r = np.broadcast_to(radii[None, :, None], (2, len(radii), n))
    s = np.broadcast_to(side[:, None, None], (2, len(radii), n))
    o = np.broadcast_to(np.arange(n)[None, None], (2, len(radii), n))
    pos, r, s, o = pos.reshape(-1, 2), r.ravel(), s.ravel(), o.ravel()
    cost, aligned = unary_cost(drawing, pos, r, terminal, params)
    cands = JointCandidates(pos, r, s, o, drawing.group[o], cost, aligned)
    cands = cands.take(np.flatnonzero(cost <= max_cost))
    return best(consolidate(cands, drawing.epsilon), max_candidates)


def grid_candidates(drawing: Drawing, spacing: float, radius: float,
                    centre: np.ndarray | None = None, reach: float | None = None,
                    params: CostParams | None = None) -> JointCandidates:
    """Occlusion candidates on a regular grid (unary cost 1).

    Args:
        drawing: The preprocessed drawing.
        spacing: Grid step, pixels (epsilon in the paper).
        radius: Radius given to the grid placements, pixels.
        centre: Centre of a local grid, pixels, ``(2,)``; None covers the drawing.
        reach: Half-width of a local grid, pixels.
        params: Cost parameters (for the shape of ``aligned``).

    Returns:
        Grid candidates.
    """
    params = params or CostParams()
    if centre is None:
        lo, hi = drawing.bbox[0], drawing.bbox[1]
    else:
        lo, hi = np.asarray(centre) - reach, np.asarray(centre) + reach
    xs = np.arange(lo[0], hi[0] + 0.5 * spacing, spacing)
    ys = np.arange(lo[1], hi[1] + 0.5 * spacing, spacing)
    pos = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    k = len(pos)
    return JointCandidates(pos, np.full(k, float(radius)), np.zeros(k, int), -np.ones(k, int),
                           -np.ones(k, int), np.ones(k),
                           -np.ones((k, params.circle_samples), int))
