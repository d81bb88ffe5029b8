"""Stroke sampling and feature extraction (Mahmudi et al. 2016, Section 5, Eqs. 1-3).

The stroke is sampled once per pixel of arc length. Walking down the chain, the guess for
the next joint lies one projected segment length further along the stroke; Eq. 2 moves it
to the point of highest curvature in a window of half-width ``||P x_{i+1} - P x_i|| / 3``
around the guess (a drawn elbow or knee), and after the bone is aligned Eq. 3 renormalizes
the arc-length position to the stroke point nearest where the joint actually projects.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from dataclasses import dataclass, replace

import numpy as np

from ..stroke import Stroke


@dataclass(frozen=True)
class SampledStroke:
    """A stroke sampled at a fixed pixel step, with curvature.

    Attributes:
        params: Arc lengths of the samples, shape ``(m,)``, pixels.
        points: Sample positions, shape ``(m, 2)``, pixels.
        curvature: Unsigned curvature at the samples, shape ``(m,)``, 1/pixels.
        step: Sampling step, pixels.
        length: Arc length of the last sample, pixels.
        peaks: Indices of the curvature's local maxima (plateaus included), ascending.
        curvature_sum: Prefix sums of the curvature, shape ``(m + 1,)``.
    """

    params: np.ndarray
    points: np.ndarray
    curvature: np.ndarray
    step: float
    length: float
    peaks: tuple[int, ...]
    curvature_sum: np.ndarray

    def __post_init__(self) -> None:
        """Keep the samples as Python floats too, for :meth:`at_xy`."""
        object.__setattr__(self, "_xy", self.points.tolist())

    @classmethod
    def from_stroke(cls, stroke: Stroke, step: float) -> SampledStroke:
        """Sample ``stroke`` every ``step`` pixels of arc length (``length``: its end)."""
        s = stroke.sample_params(step)
        kappa = np.abs(stroke.curvature(s))
        inner = np.flatnonzero((kappa[1:-1] >= kappa[:-2]) & (kappa[1:-1] >= kappa[2:])) + 1
        return cls(s, stroke.evaluate(s), kappa, float(s[1] - s[0]), float(s[-1]),
                   tuple(inner.tolist()), np.concatenate([[0.0], np.cumsum(kappa)]))

    def shifted(self, offset: np.ndarray) -> SampledStroke:
        """The same samples translated by ``offset`` pixels (shape ``(2,)``)."""
        return replace(self, points=self.points + np.asarray(offset, dtype=float))

    def at_xy(self, s: float) -> tuple[float, float]:
        """Point ``(x, y)`` at arc length ``s``, pixels, on Python floats.

        Linear between the evenly spaced samples.
        """
        u = min(max(s, 0.0), self.length) / self.step
        i = min(int(u), len(self._xy) - 2)
        f = u - i
        (x0, y0), (x1, y1) = self._xy[i], self._xy[i + 1]
        return x0 + (x1 - x0) * f, y0 + (y1 - y0) * f

    def window(self, lo: float, hi: float) -> slice:
        """Sample indices whose arc lengths lie in ``[lo, hi]`` (samples are evenly spaced)."""
        last = len(self.params)
        i0 = min(max(math.ceil(lo / self.step - 1e-9), 0), last - 1)
        i1 = min(max(math.floor(hi / self.step + 1e-9) + 1, 0), last)
        return slice(i0, max(i1, i0 + 1))


def feature_param(
    sampled: SampledStroke, guess: float, half_window: float, min_curvature: float
) -> float | None:
    """Eq. 2: the highest-curvature sample near ``guess``.

    Args:
        sampled: The sampled stroke.
        guess: Arc-length guess ``v'_i`` for the joint, pixels.
        half_window: Half-width of the search window, pixels
            (``||P x_{i+1} - P x_i|| / 3``).
        min_curvature: A sample only counts as a feature above this |curvature| and above
            twice the window's mean, so straight strokes keep the arc-length guess.

    Returns:
        Arc length of the feature point, or None when the window holds none (the caller
        keeps the arc-length guess).
    """
    lo, hi = guess - half_window, guess + half_window
    if hi >= sampled.length or lo <= 0.0:
        # Windows reaching a stroke end are cut symmetrically so the end is not a feature.
        reach = min(guess, sampled.length - guess)
        lo, hi = guess - reach, guess + reach
    idx = sampled.window(lo, hi)
    i0, i1 = idx.start, idx.stop
    if i1 - i0 < 3:
        return None
    # The window's maximum is at one of its ends or at a local maximum inside it; the
    # mean comes from prefix sums. Plain Python: this runs once per joint.
    kappa = sampled.curvature
    best = i0 if kappa[i0] >= kappa[i1 - 1] else i1 - 1
    peaks = sampled.peaks
    for p in peaks[bisect_left(peaks, i0 + 1):bisect_left(peaks, i1 - 1)]:
        if kappa[p] > kappa[best] or (kappa[p] == kappa[best] and p < best):
            best = p
    mean = float(sampled.curvature_sum[i1] - sampled.curvature_sum[i0]) / (i1 - i0)
    if kappa[best] < max(min_curvature, 2.0 * mean):
        return None
    return float(sampled.params[best])


def renormalize_param(
    sampled: SampledStroke, landed: np.ndarray, around: float, half_window: float
) -> float:
    """Eq. 3: arc length of the stroke sample nearest the landed joint, near ``around``.

    Args:
        sampled: The sampled stroke.
        landed: Projection of the aligned joint, pixels, shape ``(2,)``.
        around: Arc length of the joint's feature point ``u'_i``.
        half_window: Search half-width in pixels.

    Returns:
        The renormalized arc length.
    """
    idx = sampled.window(around - half_window, around + half_window)
    rel = sampled.points[idx] - landed
    return float(sampled.params[idx.start + int(np.argmin(np.einsum("ij,ij->i", rel, rel)))])
