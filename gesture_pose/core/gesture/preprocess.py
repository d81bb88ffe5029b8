"""Drawing preprocessing (Gesture3D Section 4): resampling, Gestalt bridges, normals.

Every stroke is resampled at ``epsilon``, 2% of the drawing's bounding-box diagonal. Two
stroke ends are *Gestalt-continuous* when the straight bridge joining them leaves both ends
within 18 degrees of their outgoing tangents (all four end pairings of two strokes are
tried); such strokes are treated as one contour. Normals are the strokes' left normals,
flipped per stroke so that they agree along bridged contours.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from ..exceptions import InputError
from ..stroke import Stroke


@dataclass(frozen=True)
class PreprocessParams:
    """Parameters of the preprocessing (the paper's values are the defaults).

    Attributes:
        epsilon_fraction: Resampling step as a fraction of the bounding-box diagonal.
        bridge_angle: Maximum angle between an end's tangent and the bridge, radians.
        bridge_max_gap: Longest bridge, in units of ``epsilon``.
    """

    epsilon_fraction: float = 0.02
    bridge_angle: float = np.radians(18.0)
    bridge_max_gap: float = 8.0


@dataclass(frozen=True)
class Drawing:
    """A preprocessed drawing: all contour samples in one set of arrays.

    Attributes:
        points: Contour samples, pixels, shape ``(N, 2)``.
        tangents: Unit tangents in the (oriented) contour direction, ``(N, 2)``.
        normals: Unit left normals of the oriented tangents, ``(N, 2)``.
        curvature: Signed curvature, 1/pixels, ``(N,)``.
        stroke: Index of the stroke of each sample, ``(N,)``.
        group: Contour index of each sample (strokes joined by bridges share it), ``(N,)``.
        prev: Previous sample along the contour (across bridges) or -1, ``(N,)``.
        next: Next sample along the contour or -1, ``(N,)``.
        offsets: Start of each stroke's samples, ``(n_strokes + 1,)``.
        bridges: ``(stroke_a, end_a, stroke_b, end_b)`` rows, ends 0 start / 1 end, ``(b, 4)``.
        epsilon: Sampling step, pixels.
        diagonal: Bounding-box diagonal, pixels.
        bbox: ``[[xmin, ymin], [xmax, ymax]]``, pixels.
        tree: KD-tree over ``points``.
        field_origin: Pixel position of the distance field's first cell, ``(2,)``.
        field_cell: Cell size of the distance field, pixels (epsilon / 4).
        field_dist: Distance to the nearest contour (bridges included), pixels, ``(H, W)``.
        field_owner: Contour sample owning the nearest contour point, ``(H, W)`` int.
    """

    points: np.ndarray
    tangents: np.ndarray
    normals: np.ndarray
    curvature: np.ndarray
    stroke: np.ndarray
    group: np.ndarray
    prev: np.ndarray
    next: np.ndarray
    offsets: np.ndarray
    bridges: np.ndarray
    epsilon: float
    diagonal: float
    bbox: np.ndarray
    tree: cKDTree
    field_origin: np.ndarray
    field_cell: float
    field_dist: np.ndarray
    field_owner: np.ndarray

    @property
    def n_samples(self) -> int:
        """Number of contour samples ``N``."""
        return len(self.points)

    def lookup(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance to the contours and nearest contour sample at pixel positions.

        Args:
            points: Pixel positions, shape ``(..., 2)``.

        Returns:
            ``(distance (...), sample (...))``; points outside the field get distance
            ``inf`` and a sample index that means nothing (every caller masks them by
            distance).
        """
        points = np.asarray(points, float)
        return self.lookup_xy(points[..., 0], points[..., 1])

    def lookup_xy(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`lookup` with the coordinates apart.

        Points outside the field read a sentinel cell of a border one cell wide around the
        field (distance ``inf``, the owner of the field's last cell): cell indices are
        clipped to the border, so one gather serves every point.

        Args:
            x: Pixel x coordinates, any shape.
            y: Pixel y coordinates, the same shape.

        Returns:
            ``(distance, sample)`` as :meth:`lookup`, shaped like ``x``.
        """
        h, w = self.field_dist.shape
        ix = self._cell(x, 0, w)
        iy = self._cell(y, 1, h)
        # Row-major index into the bordered (h + 2, w + 2) field: (iy + 1)(w + 2) + ix + 1.
        iy *= w + 2
        iy += ix
        iy += w + 3
        dist, owner = self._bordered_field
        return dist[iy], owner[iy]

    def _cell(self, coord: np.ndarray, axis: int, size: int) -> np.ndarray:
        """Nearest field cell of pixel coordinates along ``axis``, clipped to ``[-1, size]``.

        ``floor((coord - origin) / cell + 0.5)`` computed in place; -1 and ``size`` are the
        border (a NaN or an overflow casts to the smallest integer, the border too).
        """
        f = np.subtract(coord, self.field_origin[axis], out=np.empty(np.shape(coord)))
        f /= self.field_cell
        f += 0.5
        np.floor(f, out=f)
        i = f.astype(np.int64)
        np.maximum(i, -1, out=i)
        return np.minimum(i, size, out=i)

    @cached_property
    def _bordered_field(self) -> tuple[np.ndarray, np.ndarray]:
        """The distance field and its owners with a sentinel border, flattened.

        The border (one cell around the field) has distance ``inf`` and the owner of the
        field's last cell.
        """
        h, w = self.field_dist.shape
        dist = np.full((h + 2, w + 2), np.inf)
        dist[1:-1, 1:-1] = self.field_dist
        owner = np.full((h + 2, w + 2), self.field_owner.ravel()[-1],
                        dtype=self.field_owner.dtype)
        owner[1:-1, 1:-1] = self.field_owner
        return dist.ravel(), owner.ravel()

    def lookup_along_xy(self, x: np.ndarray, y: np.ndarray, ux: np.ndarray, uy: np.ndarray,
                        max_angle: float) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`lookup_xy` among the contour samples running along a direction only.

        The distance and the nearest sample of the ink whose tangent lies within
        ``max_angle`` of the direction ``(ux, uy)`` (either way along it); ink of any other
        direction is ignored, so a crease meeting an outline does not hide the outline.
        The directions are rounded to :data:`ORIENTATION_BINS` bins over 180 degrees (each
        bin's field holds the ink within ``max_angle`` of its centre,
        :func:`oriented_fields`): a sample up to half a bin beyond ``max_angle`` can be
        found, one up to half a bin within it missed.

        Args:
            x: Pixel x coordinates, any shape.
            y: Pixel y coordinates, the same shape.
            ux: Unit direction x components, broadcastable to ``x``.
            uy: Unit direction y components, broadcastable to ``x``.
            max_angle: Largest angle between the ink's tangent and the direction, radians.

        Returns:
            ``(distance, sample)`` as :meth:`lookup`, shaped like ``x``.
        """
        dist, owner = self._oriented_field(float(max_angle))
        h, w = self.field_dist.shape
        angle = np.mod(np.arctan2(uy, ux), np.pi)
        k = np.rint(angle / (np.pi / ORIENTATION_BINS)).astype(np.int64) % ORIENTATION_BINS
        ix, iy = self._cell(x, 0, w), self._cell(y, 1, h)
        inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        flat = np.where(inside, k * (h * w) + iy * w + ix, ORIENTATION_BINS * h * w)
        return dist[flat], owner[flat]

    def _oriented_field(self, max_angle: float) -> tuple[np.ndarray, np.ndarray]:
        """Flattened fields of :func:`oriented_fields` (a sentinel cell last), cached."""
        cache = self._oriented_cache
        if max_angle not in cache:
            dist, owner = oriented_fields(self.points, self.next, self.tangents,
                                          self.field_origin, self.field_cell,
                                          self.field_dist.shape, self.epsilon, max_angle)
            cache[max_angle] = (np.append(dist.ravel(), np.float32(np.inf)),
                                np.append(owner.ravel(), owner.ravel()[-1]))
        return cache[max_angle]

    @cached_property
    def _oriented_cache(self) -> dict:
        """The fields of :meth:`_oriented_field` built so far, by ``max_angle``."""
        return {}

    def stroke_samples(self, k: int) -> np.ndarray:
        """Samples of stroke ``k``, shape ``(n_k, 2)``."""
        return self.points[self.offsets[k]:self.offsets[k + 1]]


def _end_frames(strokes: list[Stroke]) -> tuple[np.ndarray, np.ndarray]:
    """Positions and outward unit tangents of both ends of every stroke.

    Returns:
        ``(positions, outward)``, each ``(n_strokes, 2, 2)``: ``[k, 0]`` the start,
        ``[k, 1]`` the end.
    """
    pos = np.stack([[s.points[0], s.points[-1]] for s in strokes])
    out = np.stack([[-s.tangent(np.array([0.0]))[0], s.tangent(np.array([s.length]))[0]]
                    for s in strokes])
    return pos, out


def find_bridges(strokes: list[Stroke], epsilon: float,
                 params: PreprocessParams = PreprocessParams()) -> np.ndarray:
    """Gestalt-continuous stroke ends: bridges whose tangents agree (Section 4).

    Both outgoing end tangents must make an angle below ``bridge_angle`` with the bridge
    (for touching ends: with each other). Each end keeps its shortest valid bridge and
    bridges are mutual, so every end joins at most one other end.

    Args:
        strokes: The drawing's strokes, pixels.
        epsilon: Sampling step, pixels.
        params: Angle and gap limits.

    Returns:
        Rows ``(stroke_a, end_a, stroke_b, end_b)`` with ``a < b``, shape ``(b, 4)`` int.
    """
    if len(strokes) == 0:
        return np.zeros((0, 4), dtype=int)
    pos, out = _end_frames(strokes)
    p, o = pos.reshape(-1, 2), out.reshape(-1, 2)
    n = len(p)
    gap = p[None, :, :] - p[:, None, :]
    dist = np.linalg.norm(gap, axis=2)
    unit = gap / np.maximum(dist, 1e-12)[..., None]
    cos_max = np.cos(params.bridge_angle)
    touching = dist < 1e-3 * epsilon
    ok_a = np.einsum("id,ijd->ij", o, unit) > cos_max
    ok_b = np.einsum("jd,ijd->ij", o, -unit) > cos_max
    parallel = np.einsum("id,jd->ij", o, -o) > cos_max
    valid = np.where(touching, parallel, ok_a & ok_b) & (dist <= params.bridge_max_gap * epsilon)
    same_stroke = (np.arange(n)[:, None] // 2) == (np.arange(n)[None, :] // 2)
    short = np.array([s.length for s in strokes]).repeat(2) < 3 * epsilon
    valid &= ~(same_stroke & short[:, None])
    np.fill_diagonal(valid, False)
    cost = np.where(valid, dist, np.inf)
    best = np.argmin(cost, axis=1)
    has = np.isfinite(cost[np.arange(n), best])
    mutual = has & (best[best] == np.arange(n)) & (np.arange(n) < best)
    a = np.flatnonzero(mutual)
    b = best[a]
    return np.stack([a // 2, a % 2, b // 2, b % 2], axis=1).astype(int)


def _orient_groups(n_strokes: int, bridges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contour index and direction sign (+1 / -1) of every stroke, from the bridges.

    A bridge joining an end to a start keeps both directions; end-end or start-start
    bridges mean one stroke runs the other way.
    """
    group = np.arange(n_strokes)
    sign = np.ones(n_strokes, dtype=int)
    adjacency: list[list[tuple[int, int]]] = [[] for _ in range(n_strokes)]
    for sa, ea, sb, eb in bridges:
        flip = -1 if ea == eb else 1
        adjacency[sa].append((sb, flip))
        adjacency[sb].append((sa, flip))
    seen = np.zeros(n_strokes, dtype=bool)
    for start in range(n_strokes):
        if seen[start]:
            continue
        seen[start] = True
        stack = [start]
        while stack:
            k = stack.pop()
            for other, flip in adjacency[k]:
                if not seen[other]:
                    seen[other] = True
                    group[other] = group[start]
                    sign[other] = sign[k] * flip
                    stack.append(other)
    return np.unique(group, return_inverse=True)[1], sign


def preprocess(strokes: list[Stroke], params: PreprocessParams = PreprocessParams()) -> Drawing:
    """Resample the strokes at epsilon, find bridges, orient contours, compute normals.

    Args:
        strokes: The drawing's strokes in pixels.
        params: Preprocessing parameters.

    Returns:
        The preprocessed drawing.

    Raises:
        InputError: No strokes, or a drawing with no extent.
    """
    strokes = [s for s in strokes if s.length > 0]
    if not strokes:
        raise InputError("The drawing has no strokes: draw the character's contours first.")
    allpts = np.concatenate([s.points for s in strokes])
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    diagonal = float(np.linalg.norm(hi - lo))
    if diagonal < 1.0:
        raise InputError("The drawing is smaller than a pixel: draw larger strokes.")
    eps = params.epsilon_fraction * diagonal
    bridges = find_bridges(strokes, eps, params)
    group_of_stroke, sign = _orient_groups(len(strokes), bridges)
    pts, tan, curv = [], [], []
    for k, s in enumerate(strokes):
        t = s.sample_params(eps)
        pts.append(s.evaluate(t))
        tan.append(s.tangent(t) * sign[k])
        curv.append(s.curvature(t) * sign[k])
    counts = np.array([len(p) for p in pts])
    offsets = np.concatenate([[0], np.cumsum(counts)])
    points, tangents = np.concatenate(pts), np.concatenate(tan)
    normals = np.stack([-tangents[:, 1], tangents[:, 0]], axis=1)
    stroke = np.repeat(np.arange(len(strokes)), counts)
    idx = np.arange(len(points))
    prev = np.where(idx == offsets[stroke], -1, idx - 1)
    nxt = np.where(idx == offsets[stroke + 1] - 1, -1, idx + 1)
    for sa, ea, sb, eb in bridges:
        ia = offsets[sa] if ea == 0 else offsets[sa + 1] - 1
        ib = offsets[sb] if eb == 0 else offsets[sb + 1] - 1
        # Link along the oriented direction: the end whose oriented tangent points out.
        a_is_tail = (ea == 1) == (sign[sa] > 0)
        first, second = (ia, ib) if a_is_tail else (ib, ia)
        nxt[first], prev[second] = second, first
    origin, cell, dist, owner = distance_field(points, nxt, np.stack([lo, hi]), eps)
    return Drawing(points, tangents, normals, np.concatenate(curv), stroke,
                   group_of_stroke[stroke], prev, nxt, offsets, bridges, eps, diagonal,
                   np.stack([lo, hi]), cKDTree(points), origin, cell, dist, owner)


def distance_field(points: np.ndarray, nxt: np.ndarray, bbox: np.ndarray, epsilon: float,
                   margin: float = 0.3) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Distance transform of the contours on a grid of step epsilon / 4.

    Gaps closed by bridges up to two steps long count as ink; longer bridges do not.

    Args:
        points: Contour samples, ``(N, 2)``.
        nxt: Next sample along the contour or -1, ``(N,)``.
        bbox: Drawing bounding box, ``(2, 2)``.
        epsilon: Sampling step, pixels.
        margin: Grid margin around the box, fraction of the box diagonal.

    Returns:
        ``(origin (2,), cell, distance (H, W) pixels, owner sample (H, W))``.
    """
    cell = epsilon / 4.0
    pad = margin * float(np.linalg.norm(bbox[1] - bbox[0]))
    origin = bbox[0] - pad
    shape = np.ceil((bbox[1] - bbox[0] + 2 * pad) / cell).astype(int) + 1
    dense, owner_of = _ink(points, nxt, epsilon, cell)
    g = np.floor((dense - origin) / cell + 0.5).astype(int)
    dist, owner = _nearest_ink(g, owner_of, (shape[1], shape[0]))
    return origin, cell, dist * cell, owner


def _nearest_ink(g: np.ndarray, owner_of: np.ndarray, shape: tuple[int, int]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Distance (in cells) from every cell to the nearest inked cell, and that ink's sample.

    Args:
        g: Inked cells ``(x, y)``, ``(D, 2)`` int.
        owner_of: The sample owning each, ``(D,)`` int.
        shape: Grid shape ``(H, W)``.

    Returns:
        ``(distance (H, W) cells, owner sample (H, W) int)``.
    """
    mask = np.ones(shape, bool)
    owner = np.zeros(shape, int)
    mask[g[:, 1], g[:, 0]] = False
    owner[g[:, 1], g[:, 0]] = owner_of
    dist, (iy, ix) = distance_transform_edt(mask, return_indices=True)
    return dist, owner[iy, ix]


def _ink(points: np.ndarray, nxt: np.ndarray, epsilon: float, cell: float
         ) -> tuple[np.ndarray, np.ndarray]:
    """The contours as dense points (half a cell apart) and the sample owning each.

    Gaps closed by bridges up to two steps long count as ink; longer bridges do not.

    Returns:
        ``(points (D, 2) pixels, owner sample (D,) int)``.
    """
    src = np.flatnonzero(nxt >= 0)
    seg = points[nxt[src]] - points[src]
    # Bridges longer than two steps are links, not ink: keep them out of the field.
    short = np.linalg.norm(seg, axis=1) <= 2.0 * epsilon
    src, seg = src[short], seg[short]
    count = np.maximum(np.ceil(np.linalg.norm(seg, axis=1) / (0.5 * cell)).astype(int), 1)
    rep = np.repeat(np.arange(len(src)), count)
    frac = (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)) / count[rep]
    dense = np.concatenate([points, points[src][rep] + frac[:, None] * seg[rep]])
    owner_of = np.concatenate([np.arange(len(points)),
                               np.where(frac < 0.5, src[rep], nxt[src][rep])])
    return dense, owner_of


#: Direction bins over 180 degrees of :func:`oriented_fields` (5 degrees each).
ORIENTATION_BINS = 36


def oriented_fields(points: np.ndarray, nxt: np.ndarray, tangents: np.ndarray,
                    origin: np.ndarray, cell: float, shape: tuple[int, int], epsilon: float,
                    max_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Distance fields of the ink running along each of :data:`ORIENTATION_BINS` directions.

    Field ``k`` is :func:`distance_field`'s over only the ink whose owner sample's tangent
    lies within ``max_angle`` of the direction ``k * 180 / ORIENTATION_BINS`` degrees
    (either way along it), on the same grid (``origin``, ``cell``, ``shape``).

    Args:
        points: Contour samples, ``(N, 2)``.
        nxt: Next sample along the contour or -1, ``(N,)``.
        tangents: Unit tangents of the samples, ``(N, 2)``.
        origin: Pixel position of the grid's first cell, ``(2,)``.
        cell: Grid step, pixels.
        shape: Grid shape ``(H, W)``.
        epsilon: Sampling step, pixels.
        max_angle: Largest angle between the ink and a bin's direction, radians.

    Returns:
        ``(distance (B, H, W) float32 pixels, owner sample (B, H, W) int32)``; infinite
        distance in a bin no ink runs along.
    """
    dense, owner_of = _ink(points, nxt, epsilon, cell)
    g = np.floor((dense - origin) / cell + 0.5).astype(int)
    bins = np.arange(ORIENTATION_BINS) * (np.pi / ORIENTATION_BINS)
    axes = np.stack([np.cos(bins), np.sin(bins)], axis=1)
    along = np.abs(tangents[owner_of] @ axes.T) >= np.cos(max_angle)  # (D, B)
    dist = np.full((ORIENTATION_BINS, *shape), np.inf, np.float32)
    owner = np.zeros((ORIENTATION_BINS, *shape), np.int32)
    for k in range(ORIENTATION_BINS):
        sel = along[:, k]
        if not sel.any():
            continue
        d, own = _nearest_ink(g[sel], owner_of[sel], shape)
        dist[k], owner[k] = d * cell, own
    return dist, owner

