"""2D strokes as arc-length parametrized curves.

A stroke is the polyline a user drew, in pixels. Following Mahmudi et al. 2016 (Section 3)
it is reparametrized by arc length with a piecewise cubic Hermite spline whose tangents are
central differences of the samples (a Catmull-Rom-like choice that keeps curvature smooth),
so it can be resampled at a fixed pixel step and differentiated for tangents and curvature.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicHermiteSpline
from scipy.spatial import cKDTree

from .exceptions import InputError

MIN_POINTS = 2


def _dedupe(points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Drop consecutive points closer than ``tol`` pixels, shape ``(n, 2) -> (m, 2)``."""
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(points, axis=0), axis=1) > tol
    return points[keep]


@dataclass(frozen=True)
class Stroke:
    """A drawn 2D curve.

    Attributes:
        points: The drawn samples in pixels, shape ``(n, 2)``, consecutive duplicates removed.
    """

    points: np.ndarray
    _arclen: np.ndarray = field(init=False, repr=False, compare=False)
    _spline: CubicHermiteSpline | None = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Validate the samples and build the arc-length spline."""
        pts = np.asarray(self.points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise InputError(f"A stroke needs points of shape (n, 2), got {pts.shape}.")
        if not np.all(np.isfinite(pts)):
            raise InputError("The stroke has NaN or infinite points (is it behind the view?).")
        pts = _dedupe(pts)
        if len(pts) < MIN_POINTS:
            raise InputError("The stroke is a single point: draw a longer stroke.")
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "_arclen", s)
        tangents = np.gradient(pts, s, axis=0) if len(s) > 2 else np.diff(pts, axis=0) / s[1]
        tangents = np.broadcast_to(tangents, pts.shape)
        object.__setattr__(self, "_spline", CubicHermiteSpline(s, pts, tangents, axis=0))

    @property
    def length(self) -> float:
        """Arc length in pixels."""
        return float(self._arclen[-1])

    @property
    def arclength(self) -> np.ndarray:
        """Arc length at each drawn sample, shape ``(n,)``."""
        return self._arclen

    def evaluate(self, s: np.ndarray, nu: int = 0) -> np.ndarray:
        """Positions (or derivatives) at arc lengths ``s``.

        Args:
            s: Arc lengths in pixels, shape ``(m,)``; clipped to ``[0, length]``.
            nu: Derivative order (0 position, 1 tangent, 2 second derivative).

        Returns:
            Array of shape ``(m, 2)``.
        """
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.length)
        return self._spline(s, nu)

    def sample_params(self, step: float) -> np.ndarray:
        """Arc lengths spaced ``step`` pixels apart from 0 to the end, shape ``(m,)``."""
        if not step > 0:
            raise InputError(f"The resampling step must be positive, got {step}.")
        count = max(int(np.ceil(self.length / step)), 1)
        return np.linspace(0.0, self.length, count + 1)

    def resample(self, step: float) -> np.ndarray:
        """Points at (nearly) equal arc-length spacing ``step`` in pixels, shape ``(m, 2)``."""
        return self.evaluate(self.sample_params(step))

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """Signed curvature ``(x'y'' - y'x'') / |c'|^3`` in 1/pixels at ``s``, shape ``(m,)``."""
        d1 = self.evaluate(s, 1)
        d2 = self.evaluate(s, 2)
        speed = np.maximum(np.linalg.norm(d1, axis=1), 1e-12)
        return (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / speed**3

    def tangent(self, s: np.ndarray) -> np.ndarray:
        """Unit tangents at ``s``, shape ``(m, 2)``."""
        d1 = self.evaluate(s, 1)
        return d1 / np.maximum(np.linalg.norm(d1, axis=1, keepdims=True), 1e-12)

    def closest_param(self, point: np.ndarray, s_min: float = 0.0, s_max: float | None = None,
                      step: float = 1.0) -> float:
        """Arc length of the stroke point nearest ``point`` within ``[s_min, s_max]``.

        Args:
            point: Query point in pixels, shape ``(2,)``.
            s_min: Start of the searched arc-length interval.
            s_max: End of the interval (default: the stroke's end).
            step: Sampling step of the search, pixels.

        Returns:
            Arc length in pixels.
        """
        hi = self.length if s_max is None else min(s_max, self.length)
        lo = min(max(s_min, 0.0), hi)
        s = np.linspace(lo, hi, max(int(np.ceil((hi - lo) / step)), 1) + 1)
        d = np.linalg.norm(self.evaluate(s) - np.asarray(point, dtype=float), axis=1)
        return float(s[np.argmin(d)])

    def reversed(self) -> Stroke:
        """The same curve drawn the other way."""
        return Stroke(self.points[::-1].copy())

    def transformed(self, scale: float = 1.0, offset: np.ndarray | None = None,
                    pivot: np.ndarray | None = None) -> Stroke:
        """The stroke scaled about ``pivot`` (default: its first point) and translated."""
        piv = self.points[0] if pivot is None else np.asarray(pivot, dtype=float)
        off = np.zeros(2) if offset is None else np.asarray(offset, dtype=float)
        return Stroke((self.points - piv) * scale + piv + off)

    def sub_stroke(self, s0: float, s1: float, step: float = 1.0) -> Stroke:
        """The piece between arc lengths ``s0 < s1``, sampled every ``step`` pixels."""
        if s1 - s0 <= 1e-9:
            raise InputError("Cannot take an empty piece of a stroke.")
        count = max(int(np.ceil((s1 - s0) / step)), 1)
        return Stroke(self.evaluate(np.linspace(s0, s1, count + 1)))


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points to segments, all of shape ``(..., 2)``; returns ``(...)``.

    x and y are kept apart: no reductions over a 2-axis.
    """
    bx, by = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    px, py = p[..., 0] - a[..., 0], p[..., 1] - a[..., 1]
    t = np.clip((px * bx + py * by) / np.maximum(bx * bx + by * by, 1e-300), 0.0, 1.0)
    dx, dy = px - t * bx, py - t * by
    return np.sqrt(dx * dx + dy * dy)


# Below this many point-segment pairs the brute-force distance is cheaper than the tree.
_BRUTE_FORCE_PAIRS = 4096


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest point of a polyline.

    Exact. Small inputs are compared against every segment; larger ones use a k-d tree
    over the vertices: the segments next to a point's nearest vertex give an upper bound
    ``u`` on its distance, and a segment of length at most ``L`` can only be nearer than
    ``u`` if one of its ends lies within ``u + L / 2``, so only those segments are tested.

    Args:
        points: Query points in pixels, shape ``(m, 2)``.
        polyline: Polyline vertices in pixels, shape ``(n, 2)``, ``n >= 2``.

    Returns:
        Distances in pixels, shape ``(m,)``.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    v = np.asarray(polyline, dtype=float)
    a, b = v[:-1], v[1:]
    n_seg = len(a)
    if len(p) * n_seg <= _BRUTE_FORCE_PAIRS:
        return _segment_distance(p[:, None], a[None], b[None]).min(axis=1)
    tree = cKDTree(v)
    _, nearest = tree.query(p)
    adjacent = np.clip(np.stack([nearest - 1, nearest], axis=1), 0, n_seg - 1)
    bound = _segment_distance(p[:, None], a[adjacent], b[adjacent]).min(axis=1)
    seg = b - a
    half = 0.5 * float(np.sqrt(np.max(seg[:, 0] ** 2 + seg[:, 1] ** 2)))
    near = tree.query_ball_point(p, bound + half + 1e-9)
    counts = np.fromiter(map(len, near), dtype=int, count=len(p))
    vertices = np.concatenate(near).astype(int)
    owner = np.repeat(np.arange(len(p)), counts)
    segs = np.clip(np.concatenate([vertices - 1, vertices]), 0, n_seg - 1)
    owner = np.concatenate([owner, owner])
    out = bound.copy()
    np.minimum.at(out, owner, _segment_distance(p[owner], a[segs], b[segs]))
    return out
