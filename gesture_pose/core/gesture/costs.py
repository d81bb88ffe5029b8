"""Matching costs of the 2D embedding (Gesture3D Section 5.2-5.3, Eq. 2-4).

All costs are functions of positions so the discrete solver (candidate tables) and the
continuous refinement (moved joints) share them.

- Unary ``C(i, P)``: a joint's circle of radius ``r`` centred at ``P`` is sampled; a circle
  sample is *aligned* when a contour sample lies within ``min(epsilon, r / 2)`` with normals
  within ``alpha = 15`` degrees. ``C = 1 - f / f_ref`` with ``f`` the aligned fraction and
  ``f_ref`` the fraction an ideal fit reaches (two tangent arcs of ``2 alpha`` for a joint
  inside a limb, a half circle plus those arcs for a terminal joint). Terminal joints need
  ``f >= 15%`` (else cost 1). Lines crossing a joint's circle are allowed: traced and drawn
  figures have interior lines at joints (a hand over a hip, a junction of parts).
- Pairwise ``E(i, j) = 1 - (1 - Cl)(1 - Ccf)(1 - Wc Cc)`` per bone with the length term
  ``Cl`` (Eq. 2, ``sigma`` = 4% of the diagonal, ``sigma / 3`` when the drawn bone is
  longer than the bone; optionally, on the short side, at least a share of the bone's
  length), contour conformity ``Ccf`` (optionally only for the side a foreshortened bone
  still shows) and consistency ``Cc``, ``Wc = 0.9``.
- Triplet naturalness ``Cn`` on consecutive bones with ``sigma_a = pi / 3`` when the three
  joints come from the same contour, else ``pi / 6``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .preprocess import Drawing


@dataclass(frozen=True)
class CostParams:
    """Cost parameters (the paper's values are the defaults).

    Attributes:
        alpha: Normal tolerance of aligned circle samples, radians.
        terminal_min_fraction: Matched circle fraction a terminal joint needs.
        circle_samples: Samples per joint circle.
        sigma_length: Length-term sigma as a fraction of the drawing diagonal.
        w_consistency: Weight ``Wc`` of the consistency term.
        sigma_angle_shared: ``sigma_a`` when the three joints share a contour, radians.
        sigma_angle: ``sigma_a`` otherwise, radians.
        conform_angle: Largest angle between a conforming contour sample and its bone.
        rigid_sigma: Sigma of rigid offsets (unconnected heads), fraction of the diagonal.
        w_direction: Weight of the direction prior (see :func:`direction_cost`); not in the
            paper (0 gives the paper's energy).
        view_offsets: Compare rigid offsets (hips, shoulders) as 2D vectors with the bind
            pose seen in the view (not in the paper); False compares only their length,
            with the length term ``Cl``.
        view_angles: Measure the naturalness ``Cn`` against the angle between the bones in
            the bind pose seen in the view (not in the paper); False uses their 3D angle in
            the bind pose.
        view_lengths: A bone foreshortened in the bind pose seen in the view (a foot
            pointing at the viewer) may be drawn at any length between its length in the
            view and its full length at no cost in ``Cl`` (not in the paper); False
            measures the drawn length against the full length only (Eq. 2).
        perspective_lengths: Through a perspective camera a bone nearer than the
            character's depth looks longer than its length at that depth: drawn longer, up
            to its length at the nearest depth it can reach (the root's depth less the
            bone's distance from the root along the skeleton), it pays ``Cl`` with
            ``sigma`` instead of the strict ``sigma / 3`` (not in the paper).
        transverse_crossings: The consistency term ``Cc`` counts a contour near the bone's
            axis as crossed only where it runs across the axis (ours); False counts any
            contour of the end joints within half a step of the axis.
        crossing_room: The consistency term's crossing test applies only to bones whose
            two joint circles, each widened by a step, leave room between them at the
            larger of the drawn and the expected length (ours; a bone drawn short cannot
            escape the test); False tests the others too, at the middle of the overlap of
            their widened circles, within a step of their joints' own outlines (see
            :func:`crossing_room`).
        stacked_counterparts: Left/right counterparts whose joints lie within this many
            epsilons of each other in the current pose seen in the view may share contour
            samples without an overlap (ours, see
            :func:`~.consistency.stacked_counterparts`); 0 gives the paper's non-overlap.
        foreshortening: Eq. 2's sigma for a bone drawn shorter than its length is at least
            this share of the bone's expected length beyond ``foreshortening_from``
            (ours; 0 gives the paper's sigma, a share of the drawing's diagonal, for every
            bone). A bone turned out of the view plane by ``theta`` is drawn at
            ``cos(theta)`` of its length, so how much shorter it can look grows with the
            bone: thighs pointing at the viewer, drawn at 31% of their length, pay the
            paper's ``Cl`` of 1.00 (0.76 at 0.5 from half a sigma). On by default (0.5
            from 1 sigma, with ``exposed_conformity``; docs/gesture.md).
        foreshortening_from: Shortfall, in the paper's sigmas, up to which the paper's sigma
            holds before the share above takes over: a bone drawn at full length keeps
            the paper's hold on its joints (with the share alone from the start, a bent
            arm's elbow slid 9.5 px along its upper arm, docs/gesture.md).
        exposed_conformity: ``Ccf`` is weighted by the share of its exposed stretch (between
            the two joint circles) a bone still shows (ours, :func:`exposed_weight`): a bone
            foreshortened into its joints' circles has no side to conform; False gives
            the paper's ``Ccf`` for every bone. On by default: with ``foreshortening``
            0.5 from 1 sigma and ``GestureParams.refined_resolves`` it fits the test
            view's crouch (every joint within 4%) and improves the humanoid means; the 2D
            bench quadruped's means are a little worse (docs/gesture.md); alone it leaves
            the crouch as it is.
        exposed_from: Exposed stretch, in the paper's sigmas, a bone may lack before its
            ``Ccf`` is discounted; bones whose expected exposed stretch is shorter never
            are.
        oriented_conformity: A link whose two joint circles overlap at its expected
            length (the pelvis, the spine's links, the neck: inside the torso) conforms at
            a checkpoint also when ink running along it (within ``conform_angle``) lies as
            near as the nearest ink of any direction, within half a cell of the distance
            field (ours, :func:`pair_cost`); False gives the paper's ``Ccf`` from the
            nearest ink only. On by default, with ``GestureParams.resolve_rate``: it fits
            the test view's step (its pelvis group 4.002 -> 2.08 % of the height, every
            joint of the five test drawings within 4%) and lowers the 2D bench's means
            of the sample characters; it moves other drawings through the search both
            ways, and the whole Pose's mean rose (docs/gesture.md).
    """

    alpha: float = np.radians(15.0)
    terminal_min_fraction: float = 0.15
    circle_samples: int = 48
    sigma_length: float = 0.04
    w_consistency: float = 0.9
    sigma_angle_shared: float = np.pi / 3
    sigma_angle: float = np.pi / 6
    conform_angle: float = np.radians(30.0)
    rigid_sigma: float = 0.03
    w_direction: float = 0.75
    view_offsets: bool = True
    view_angles: bool = True
    view_lengths: bool = True
    perspective_lengths: bool = True
    transverse_crossings: bool = True
    crossing_room: bool = True
    stacked_counterparts: float = 1.5
    foreshortening: float = 0.5
    foreshortening_from: float = 1.0
    exposed_conformity: bool = True
    exposed_from: float = 1.5
    oriented_conformity: bool = True


@lru_cache(maxsize=8)
def _unit_circle(m: int) -> np.ndarray:
    """``m`` unit vectors at even angles from 0, ``(m, 2)``, read-only (computed once)."""
    ang = np.linspace(0.0, 2 * np.pi, m, endpoint=False)
    u = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    u.flags.writeable = False
    return u


@lru_cache(maxsize=8)
def _unit_steps(count: int) -> np.ndarray:
    """``count`` even parameters from 0 to 1, ``(count,)``, read-only (computed once)."""
    s = np.linspace(0.0, 1.0, count)
    s.flags.writeable = False
    return s


def _norms(x: np.ndarray, axis: int) -> np.ndarray:
    """``np.linalg.norm(x, axis=axis)`` of a real array without its wrapper's overhead.

    The same values: the square root of the sum of the squares along ``axis``.
    """
    return np.sqrt(np.add.reduce(x * x, axis=axis))


def _rows(x, k: int, dtype=None) -> np.ndarray:
    """``x`` as an array of ``k`` rows: itself when it has them, else broadcast."""
    x = np.asarray(x, dtype)
    return x if x.shape == (k,) else np.broadcast_to(x, (k,))


def circle_alignment(drawing: Drawing, centres: np.ndarray, radii: np.ndarray,
                     params: CostParams | None = None) -> np.ndarray:
    """Aligned contour sample of every circle sample, or -1.

    A circle sample is aligned when the contours pass within ``min(epsilon, r / 2)`` of it
    (read from the drawing's distance field) and the nearest contour sample's normal is
    within ``alpha`` of the circle's normal.

    Args:
        drawing: The preprocessed drawing.
        centres: Circle centres, pixels, ``(K, 2)``.
        radii: Circle radii, pixels, ``(K,)``.
        params: Cost parameters.

    Returns:
        Sample indices, shape ``(K, M)`` int, -1 where nothing aligns.
    """
    params = params or CostParams()
    u = _unit_circle(params.circle_samples)
    centres = np.asarray(centres, float).reshape(-1, 2)
    radii = np.broadcast_to(np.asarray(radii, float), (len(centres),))
    tol = np.minimum(drawing.epsilon, radii / 2.0)
    x = centres[:, 0, None] + radii[:, None] * u[:, 0]
    y = centres[:, 1, None] + radii[:, None] * u[:, 1]
    dist, owner = drawing.lookup_xy(x, y)
    cos = np.abs(drawing.normals[owner, 0] * u[:, 0] + drawing.normals[owner, 1] * u[:, 1])
    ok = (dist <= tol[:, None]) & (cos > np.cos(params.alpha))
    return np.where(ok, owner, -1)


def unary_cost(drawing: Drawing, centres: np.ndarray, radii: np.ndarray, terminal: bool,
               params: CostParams | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Unary cost ``C(i, P)`` of circles (see the module docstring).

    Args:
        drawing: The preprocessed drawing.
        centres: Circle centres, pixels, ``(K, 2)``.
        radii: Radii, pixels, ``(K,)``.
        terminal: Whether the joint is terminal (no child joint).
        params: Cost parameters.

    Returns:
        ``(cost (K,), aligned (K, M))`` with ``aligned`` from :func:`circle_alignment`.
    """
    params = params or CostParams()
    aligned = circle_alignment(drawing, centres, radii, params)
    return unary_from_aligned(aligned, terminal, params), aligned


def unary_from_aligned(aligned: np.ndarray, terminal: bool, params: CostParams | None = None,
                       blocked: np.ndarray | None = None) -> np.ndarray:
    """Unary cost from the aligned samples of circles, ``(K, M) -> (K,)``.

    Args:
        aligned: Aligned contour sample per circle sample or -1, ``(K, M)``.
        terminal: Whether the joint is terminal.
        params: Cost parameters.
        blocked: Contour samples this joint may not use (claimed by another part), ``(N,)``.
    """
    params = params or CostParams()
    ok = aligned >= 0
    if blocked is not None:
        ok &= ~blocked[np.maximum(aligned, 0)]
    frac = np.count_nonzero(ok, axis=1) / ok.shape[1]  # the mean, exactly (0/1 sums)
    a = params.alpha
    f_ref = (np.pi + 2 * a) / (2 * np.pi) if terminal else 2 * a / np.pi
    cost = 1.0 - np.minimum(np.maximum(frac / f_ref, 0.0), 1.0)
    if terminal:
        cost = np.where(frac < params.terminal_min_fraction, 1.0, cost)
    return cost


def length_cost(dist: np.ndarray, length: float, sigma: float,
                free: tuple[float, float] | None = None,
                nearest: float | None = None, short_sigma: float | None = None,
                knee: float = 0.0) -> np.ndarray:
    """Length term ``Cl`` (Eq. 2): Gaussian misfit, three times stricter when too long.

    Args:
        dist: Drawn bone lengths, pixels, any shape.
        length: Expected bone length, pixels.
        sigma: Standard deviation, pixels.
        free: Drawn lengths ``(shortest, longest)`` that cost nothing, pixels (see
            ``view_lengths``); the misfit is measured from the nearer end of that range,
            widened to include ``length``. None: only ``length`` (Eq. 2 as in the paper).
        nearest: The bone's length at the nearest depth it can come to through a
            perspective camera, pixels (see ``perspective_lengths``): a drawn length above
            the range is measured with ``sigma`` up to this length and with
            ``sigma / 3`` beyond it. None: ``sigma / 3`` from the top of the range.
        short_sigma: Standard deviation below the range beyond ``knee`` sigmas (a
            foreshortened bone), pixels (see ``foreshortening``); None: ``sigma``.
        knee: Shortfall in units of ``sigma`` up to which ``sigma`` holds when
            ``short_sigma`` is given (see ``foreshortening_from``).

    Returns:
        ``Cl`` in ``[0, 1)``, the shape of ``dist``.
    """
    lo, hi, lenient = _length_range(length, free, nearest)
    return _length_term(np.asarray(dist, float), lo, hi, lenient, sigma, short_sigma, knee)


def _length_range(length, free, nearest) -> tuple:
    """:func:`length_cost`'s free range ``(lo, hi)`` and its lenient stretch above it.

    For one bone (``length`` a scalar, ``free`` ``(2,)`` or None, ``nearest`` a scalar or
    None) or row by row (``length`` ``(L,)``, ``free`` ``(L, 2)``, ``nearest`` ``(L,)``
    with NaN where a row has none): the same values either way.
    """
    lo = hi = np.asarray(length, float)
    if free is not None:
        free = np.asarray(free, float)
        lo, hi = np.minimum(lo, free[..., 0]), np.maximum(hi, free[..., 1])
    if nearest is None:
        return lo, hi, 0.0
    nearest = np.asarray(nearest, float)
    return lo, hi, np.where(np.isnan(nearest), 0.0, np.maximum(nearest - hi, 0.0))


def _length_term(dist: np.ndarray, lo, hi, lenient, sigma: float, short_sigma, knee: float
                 ) -> np.ndarray:
    """:func:`length_cost` element by element.

    ``lo``, ``hi``, ``lenient`` and ``short_sigma`` are scalars or arrays broadcast with
    ``dist``.
    """
    deficit = np.maximum(lo - dist, 0.0)
    if short_sigma is None:
        short = deficit / sigma
    else:
        near = np.minimum(deficit, knee * sigma)
        short = near / sigma + (deficit - near) / short_sigma
    over = np.maximum(dist - hi, 0.0)
    near = np.minimum(over, lenient)
    over = (near + 3.0 * (over - near)) / sigma
    return 1.0 - np.exp(-0.5 * (short + over) ** 2)


def pair_cost(drawing: Drawing, pa: np.ndarray, ra: np.ndarray, ga: np.ndarray,
              sa: np.ndarray, pb: np.ndarray, rb: np.ndarray, gb: np.ndarray, sb: np.ndarray,
              length: float, params: CostParams | None = None,
              stations: int = 8, blocked: np.ndarray | None = None,
              free: tuple[float, float] | None = None,
              nearest: float | None = None) -> np.ndarray:
    """Pairwise bone cost ``E(i, j) = 1 - (1 - Cl)(1 - Ccf)(1 - Wc Cc)``.

    ``Cl`` is Eq. 2 (:func:`length_cost`) with ``sigma`` = ``sigma_length`` of the
    diagonal (below the accepted range and beyond ``foreshortening_from`` sigmas:
    ``foreshortening`` times ``length`` if larger).

    ``Ccf`` samples the bone's two outlines (offset by the interpolated joint radius) at
    ``stations`` positions; a station conforms when a contour runs there (within
    ``max(epsilon, r / 2)``) along the bone (within ``conform_angle``), and
    ``Ccf = 1 - (left + right) / 2`` with the conforming fractions per side, times
    :func:`exposed_weight` with ``exposed_conformity``; with ``oriented_conformity`` a
    link inside its joints' circles takes ties at junctions for the ink along it
    (:func:`tied_along`). ``Cc`` is 1 when
    the bone's axis crosses a contour its end joints come from between the two joint
    circles (see :func:`crossing_stations`; the contour must run across the axis there,
    not along it), or when both end joints
    come from the same contour but lie on opposite sides of it.

    Args:
        drawing: The preprocessed drawing.
        pa: Head joint positions, pixels, ``(Ka, 2)``.
        ra: Their radii, pixels, ``(Ka,)``.
        ga: Contour of their originating samples (-1 for grid), ``(Ka,)``.
        sa: Side of their originating contour (+1, -1, 0 grid), ``(Ka,)``.
        pb: Tail joint positions, pixels, ``(Kb, 2)``.
        rb: Their radii, pixels, ``(Kb,)``.
        gb: Contour of their originating samples, ``(Kb,)``.
        sb: Side of their originating contour, ``(Kb,)``.
        length: Expected drawn length (bind length times the view scale), pixels.
        params: Cost parameters.
        stations: Samples along the bone per outline.
        blocked: Contour samples claimed by other body parts, which do not count for this
            bone's conformity (the non-overlap constraint), ``(N,)`` bool.
        free: Drawn lengths ``(shortest, longest)`` the length term accepts at no cost,
            pixels (see :func:`length_cost`); None: only ``length``.
        nearest: The bone's length at its nearest depth, pixels (see :func:`length_cost`).

    Returns:
        Costs, shape ``(Ka, Kb)``.
    """
    params = params or CostParams()
    pa, pb = np.asarray(pa, float).reshape(-1, 2), np.asarray(pb, float).reshape(-1, 2)
    ka, kb = len(pa), len(pb)
    ra, rb = _rows(ra, ka, float), _rows(rb, kb, float)
    ga, sa, gb, sb = _rows(ga, ka), _rows(sa, ka), _rows(gb, kb), _rows(sb, kb)
    d = pb[None, :, :] - pa[:, None, :]
    dist = _norms(d, 2)
    sigma = params.sigma_length * drawing.diagonal
    cl = length_cost(dist, length, sigma, free, nearest,
                     max(sigma, params.foreshortening * length), params.foreshortening_from)
    out = np.ones((ka, kb))
    # E = 1 - (1 - Cl)(...)(...) is exactly 1 where Cl is (a length far off): only the
    # other pairs ("live", flat indices) need the conformity and consistency terms, which
    # are computed on them alone, element by element as on the whole table.
    live = np.flatnonzero(cl != 1.0)
    if live.size == 0:
        return out
    ia, ib = np.divmod(live, kb)
    out.ravel()[live] = _live_costs(drawing, pa[ia], ra[ia], ga[ia], sa[ia], rb[ib], gb[ib],
                                    sb[ib], d.reshape(-1, 2)[live], dist.ravel()[live],
                                    cl.ravel()[live], length, params, stations, blocked)
    return out


def bone_costs(drawing: Drawing, pa: np.ndarray, ra: np.ndarray, ga: np.ndarray,
               sa: np.ndarray, pb: np.ndarray, rb: np.ndarray, gb: np.ndarray, sb: np.ndarray,
               length: np.ndarray, params: CostParams | None = None, stations: int = 8,
               blocked: np.ndarray | None = None, free: np.ndarray | None = None,
               nearest: np.ndarray | None = None) -> np.ndarray:
    """:func:`pair_cost` of ``L`` bones at one placement pair each, in one call, ``(L,)``.

    Row ``i`` is ``pair_cost`` of the head ``pa[i]`` and the tail ``pb[i]`` with that bone's
    ``length[i]``, ``free[i]``, ``nearest[i]`` and ``blocked[i]``: the same value, element
    by element, for many bones (or placements) at once.

    Args:
        drawing: The preprocessed drawing.
        pa: Head positions, pixels, ``(L, 2)``.
        ra: Their radii, pixels, ``(L,)``.
        ga: Their contour groups (-1 for grid), ``(L,)``.
        sa: Their contour sides, ``(L,)``.
        pb: Tail positions, pixels, ``(L, 2)``.
        rb: Their radii, pixels, ``(L,)``.
        gb: Their contour groups, ``(L,)``.
        sb: Their contour sides, ``(L,)``.
        length: Expected drawn lengths, pixels, ``(L,)``.
        params: Cost parameters.
        stations: Samples along the bone per outline.
        blocked: Contour samples that do not count for each row's conformity, ``(L, N)``
            bool, or None.
        free: Each row's free lengths ``(shortest, longest)``, pixels, ``(L, 2)`` (a row
            without: its ``length`` twice), or None: none for all.
        nearest: Each row's length at its nearest depth, pixels, ``(L,)`` (NaN: none), or
            None: none for all.

    Returns:
        Costs, ``(L,)``.
    """
    params = params or CostParams()
    pa, pb = np.asarray(pa, float).reshape(-1, 2), np.asarray(pb, float).reshape(-1, 2)
    n = len(pa)
    length = np.asarray(length, float)
    sigma = params.sigma_length * drawing.diagonal
    lo, hi, lenient = _length_range(
        length, None if free is None else np.asarray(free, float).reshape(-1, 2), nearest)
    short = np.maximum(sigma, params.foreshortening * length)
    d = pb - pa
    dist = _norms(d, 1)
    cl = _length_term(dist, lo, hi, lenient, sigma, short, params.foreshortening_from)
    out = np.ones(n)
    live = np.flatnonzero(cl != 1.0)
    if live.size:
        ga, sa, gb, sb = (np.asarray(x)[live] for x in (ga, sa, gb, sb))
        out[live] = _live_costs(drawing, pa[live], np.asarray(ra, float)[live], ga, sa,
                                np.asarray(rb, float)[live], gb, sb, d[live], dist[live],
                                cl[live], length[live], params, stations,
                                None if blocked is None else blocked[live])
    return out


def pair_rows(pa: np.ndarray, ra: np.ndarray, ga: np.ndarray, sa: np.ndarray,
              pb: np.ndarray, rb: np.ndarray, gb: np.ndarray, sb: np.ndarray) -> tuple:
    """The ``Ka x Kb`` placement pairs of a :func:`pair_cost` table as rows (row-major).

    Returns:
        ``(pa, ra, ga, sa, pb, rb, gb, sb)`` of ``Ka * Kb`` rows each, for
        :func:`bone_costs`.
    """
    pa, pb = np.asarray(pa, float).reshape(-1, 2), np.asarray(pb, float).reshape(-1, 2)
    ka, kb = len(pa), len(pb)
    row = np.arange(ka * kb)
    ia, ib = row // kb, row % kb
    return (pa[ia], *(_gather(x, ka, ia) for x in (np.asarray(ra, float), ga, sa)),
            pb[ib], *(_gather(x, kb, ib) for x in (np.asarray(rb, float), gb, sb)))


def _gather(x, k: int, index: np.ndarray) -> np.ndarray:
    """``x`` broadcast to ``(k,)``, at ``index``."""
    x = np.asarray(x).reshape(-1)
    if len(x) == k:
        return x[index]
    if len(x) != 1:
        raise ValueError(f"expected {k} values or one, got {len(x)}")
    return x[index * 0]


def _live_costs(drawing: Drawing, pa: np.ndarray, ra: np.ndarray, ga: np.ndarray,
                sa: np.ndarray, rb: np.ndarray, gb: np.ndarray, sb: np.ndarray, d: np.ndarray,
                dist: np.ndarray, cl: np.ndarray, length, params: CostParams, stations: int,
                blocked: np.ndarray | None) -> np.ndarray:
    """:func:`pair_cost` of ``L`` placement pairs (rows) whose length term ``cl`` is below 1.

    Args:
        drawing: The preprocessed drawing.
        pa: Head positions, pixels, ``(L, 2)``.
        ra: Their radii, pixels, ``(L,)``.
        ga: Their contour groups (-1 for grid), ``(L,)``.
        sa: Their contour sides, ``(L,)``.
        rb: Tail radii, pixels, ``(L,)``.
        gb: Their contour groups, ``(L,)``.
        sb: Their contour sides, ``(L,)``.
        d: Bone vectors (tail less head), pixels, ``(L, 2)``.
        dist: Their lengths, pixels, ``(L,)``.
        cl: Their length terms, ``(L,)``.
        length: Expected drawn length, pixels, a scalar or ``(L,)``.
        params: Cost parameters.
        stations: Samples along the bone per outline.
        blocked: Samples that do not count, ``(N,)`` or per row ``(L, N)`` bool, or None.

    Returns:
        ``E`` per row, ``(L,)``.
    """
    eps = drawing.epsilon
    u = d / np.maximum(dist, 1e-9)[:, None]
    weight = 1.0
    if params.exposed_conformity:
        sigma = params.sigma_length * drawing.diagonal
        weight = _exposed(dist, length, ra + rb, params.exposed_from * sigma)
    inside = None
    if params.oriented_conformity:
        inside = np.asarray(length) < ra + rb  # joint circles overlapping at full length
    cover = _conformity(drawing, pa, ra, rb, d, u, stations, params, blocked, inside)
    ccf = weight * (1.0 - 0.5 * (cover[0] + cover[1]))
    scale = (1.0 - cl) * (1.0 - ccf)
    opposite = (ga == gb) & (ga >= 0) & (sa * sb < 0)
    cc = opposite.astype(float)
    # Cc matters where the rest of E is not 0 and the pair is not already inconsistent
    # (opposite sides of one contour); the crossing test needs room on the axis and a
    # contour of an end joint (none for two grid placements).
    test = (scale != 0.0) & ~opposite & ((ga >= 0) | (gb >= 0))
    if params.crossing_room:
        test &= _room(np.maximum(dist, length), ra + rb, eps)
    t = np.flatnonzero(test)
    cc[t[_crossed(drawing, pa[t], ra[t], rb[t], ga[t], gb[t], d[t], dist[t], u[t],
                  params)]] = 1.0
    return 1.0 - scale * (1.0 - params.w_consistency * cc)


def _conformity(drawing: Drawing, pa: np.ndarray, ra: np.ndarray, rb: np.ndarray,
                d: np.ndarray, u: np.ndarray, stations: int, params: CostParams,
                blocked: np.ndarray | None, inside: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Conforming fraction of each outline of ``L`` bones (:func:`pair_cost`'s ``Ccf``).

    Args:
        drawing: The preprocessed drawing.
        pa: Head positions, pixels, ``(L, 2)``.
        ra: Head radii, pixels, ``(L,)``.
        rb: Tail radii, pixels, ``(L,)``.
        d: Bone vectors (tail less head), pixels, ``(L, 2)``.
        u: Their unit directions, ``(L, 2)``.
        stations: Samples along the bone per outline.
        params: Cost parameters.
        blocked: Contour samples that do not count, ``(N,)`` bool (or per bone ``(L, N)``),
            or None.
        inside: Bones whose stations take ties for the ink along them
            (:func:`tied_along`, ``oriented_conformity``), ``(L,)`` bool, or None.

    Returns:
        ``(left, right)`` fractions of conforming stations, each ``(L,)``.
    """
    eps = drawing.epsilon
    ux, uy = u[:, 0, None], u[:, 1, None]
    nx, ny = drawing.normals[:, 0], drawing.normals[:, 1]
    t = (np.arange(stations) + 0.5) / stations
    ax, ay = pa[:, 0, None] + t * d[:, 0, None], pa[:, 1, None] + t * d[:, 1, None]
    r_t = (1.0 - t)[None, :] * ra[:, None] + t[None, :] * rb[:, None]
    tol = np.maximum(eps, 0.5 * r_t)
    sin_max = np.sin(params.conform_angle)
    # The outlines at +-r_t across the axis: ax -+ r_t uy, ay +- r_t ux (exactly the
    # products with a signed r_t).
    wx, wy = r_t * uy, r_t * ux
    cover = []
    for x, y in ((ax - wx, ay + wy), (ax + wx, ay - wy)):
        dq, owner = drawing.lookup_xy(x, y)
        near = np.flatnonzero(dq <= tol)
        o, row = owner.ravel()[near], near // stations
        ok = np.abs(nx[o] * ux[row, 0] + ny[o] * uy[row, 0]) < sin_max
        if inside is not None and inside.any():
            tie = np.flatnonzero(inside[row])
            k, rt = near[tie], row[tie]
            ok[tie], o[tie] = tied_along(drawing, x.ravel()[k], y.ravel()[k], ux[rt, 0],
                                         uy[rt, 0], dq.ravel()[k], tol.ravel()[k],
                                         params.conform_angle)
        if blocked is not None:
            ok &= ~(blocked[o] if blocked.ndim == 1 else blocked[row, o])
        cover.append(np.bincount(row[ok], minlength=len(u)) / stations)
    return cover[0], cover[1]


def _crossed(drawing: Drawing, pa: np.ndarray, ra: np.ndarray, rb: np.ndarray,
             ga: np.ndarray, gb: np.ndarray, d: np.ndarray, dist: np.ndarray, u: np.ndarray,
             params: CostParams) -> np.ndarray:
    """Bones whose axis crosses a contour of an end joint (:func:`pair_cost`'s ``Cc``).

    Args:
        drawing: The preprocessed drawing.
        pa: Head positions, pixels, ``(L, 2)``.
        ra: Head radii, pixels, ``(L,)``.
        rb: Tail radii, pixels, ``(L,)``.
        ga: Head contour groups, ``(L,)``.
        gb: Tail contour groups, ``(L,)``.
        d: Bone vectors, pixels, ``(L, 2)``.
        dist: Their lengths, pixels, ``(L,)``.
        u: Their unit directions, ``(L, 2)``.
        params: Cost parameters.

    Returns:
        ``(L,)`` bool.
    """
    eps = drawing.epsilon
    ta = _axis_stations(dist, ra, rb, eps)
    qx, qy = pa[:, 0, None] + ta * d[:, 0, None], pa[:, 1, None] + ta * d[:, 1, None]
    dq, owner = drawing.lookup_xy(qx, qy)
    near = np.flatnonzero(dq < 0.5 * eps)
    o, row = owner.ravel()[near], near // ta.shape[1]
    grp = drawing.group[o]
    keep = (grp == ga[row]) | (grp == gb[row])
    near, o, row = near[keep], o[keep], row[keep]
    if params.transverse_crossings:
        # The contour must run across the axis: its tangent line at the nearest sample
        # meets the axis within a step of the station. An outline running along the axis
        # (a part thinner than a step, such as a hand seen edge-on) is near but not crossed.
        mx, my = drawing.normals[o, 0], drawing.normals[o, 1]
        pts = drawing.points[o]
        off = np.abs((qx.ravel()[near] - pts[:, 0]) * mx + (qy.ravel()[near] - pts[:, 1]) * my)
        row = row[off < eps * np.abs(mx * u[row, 0] + my * u[row, 1])]
    out = np.zeros(len(u), bool)
    out[row] = True
    return out


def tied_along(drawing: Drawing, x: np.ndarray, y: np.ndarray, ux: np.ndarray,
               uy: np.ndarray, nearest: np.ndarray, tol: np.ndarray, max_angle: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Checkpoints with ink running along a direction as near as ``nearest`` (ours).

    The distance field gives a checkpoint to the nearest contour sample; where two lines
    meet (a crease meeting an outline) both are equally near and the field's choice
    between them is arbitrary. The test view's step, a thigh's crease meeting the torso's
    outline, gave the pelvis link's checkpoints on that outline to the crease, 33-50
    degrees off the bone, and the link paid ``Ccf`` 0.31 at its true place. Here the ink
    within ``max_angle`` of the bone (:meth:`~.preprocess.Drawing.lookup_along_xy`)
    counts when it lies within half a field cell of ``nearest`` and within ``tol``.

    Args:
        drawing: The preprocessed drawing.
        x: Checkpoint x coordinates, pixels, any shape.
        y: Checkpoint y coordinates, pixels, the shape of ``x``.
        ux: Bone direction x components, broadcastable to ``x``.
        uy: Bone direction y components, broadcastable to ``x``.
        nearest: Distance of the nearest ink of any direction, pixels, shaped like ``x``.
        tol: Conformity tolerance, pixels, broadcastable to ``x``.
        max_angle: Largest angle between the ink and the bone, radians.

    Returns:
        ``(conforms, sample)``: bool and the contour sample along the bone, each shaped
        like ``x`` (the caller discounts blocked samples).
    """
    dist, owner = drawing.lookup_along_xy(x, y, ux, uy, max_angle)
    nx, ny = drawing.normals[owner, 0], drawing.normals[owner, 1]
    ok = ((dist <= np.minimum(tol, nearest + 0.5 * drawing.field_cell))
          & (np.abs(nx * ux + ny * uy) < np.sin(max_angle)))
    return ok, owner


def exposed_weight(dist: np.ndarray, length: float, ra: np.ndarray, rb: np.ndarray,
                   slack: float) -> np.ndarray:
    """Share of the conformity term ``Ccf`` a bone pays for the side it shows (ours).

    Inside a joint's circle the drawn outline runs around the joint, not along the bone:
    only the stretch of the axis between the two circles has sides to conform. A bone
    turned towards the viewer is drawn short, its joint circles close in, and that stretch
    shrinks or vanishes (the test view's crouch: thighs drawn at a third of their length,
    their circles overlapping); the paper's ``Ccf`` still asks for its whole outline and
    costs such a bone 0.7-0.75 at its true place. The discount is the share of the bone's
    exposed stretch (``full``: the larger of its drawn and expected lengths less both
    radii) that is missing beyond ``slack``: the weight is
    ``(dist - ra - rb + slack) / full``, clipped to ``[0, 1]``. A bone drawn at its length,
    or within ``slack`` of it, pays the whole ``Ccf``; each pixel missing beyond pays
    ``1 / full`` less, the share of the outline it no longer shows, and a bone collapsed
    into its joints' circles still pays ``slack / full`` of it. Bones whose exposed stretch
    is no longer than ``slack`` (hands, feet, clavicles, the spine's links inside the
    torso) always pay the whole ``Ccf``: on them a few pixels of shortening would buy a
    large discount (with no slack, the raised hand of the test view slid 6% of the height
    up its forearm). The first version ramped the weight from 1 to 0 over ``full - slack``
    only, so a bone whose stretch was a little longer than the slack lost its whole
    ``Ccf`` over a few pixels (the 2D bench quadruped's hind thigh, 76 px: all of it
    between 41 and 31 px drawn); docs/gesture.md.

    Args:
        dist: Drawn bone lengths, pixels, ``(Ka, Kb)``.
        length: Expected drawn length, pixels.
        ra: Head radii, pixels, ``(Ka,)``.
        rb: Tail radii, pixels, ``(Kb,)``.
        slack: Exposed stretch a bone may lack at no discount, pixels.

    Returns:
        Weights in ``[0, 1]``, ``(Ka, Kb)``.
    """
    return _exposed(dist, length, ra[:, None] + rb[None, :], slack)


def _exposed(dist: np.ndarray, length, radii: np.ndarray, slack: float) -> np.ndarray:
    """:func:`exposed_weight` element by element, ``radii`` the two radii's sums."""
    full = np.maximum(dist, length) - radii
    room = full > slack
    share = (dist - radii + slack) / np.where(room, full, 1.0)
    return np.where(room, np.clip(share, 0.0, 1.0), 1.0)


def crossing_room(dist: np.ndarray, ra: np.ndarray, rb: np.ndarray, eps: float) -> np.ndarray:
    """Whether a bone's axis has room for the crossing test between its joint circles.

    :func:`crossing_stations` probes the axis one step beyond each joint's circle. A bone
    shorter than its two radii plus two steps has no such stretch: its probe falls within
    a step of a joint's own outline (a drawn wrist ball, the rounded end of a hand), which
    every correct placement crosses. On the test view's reach, the hand (34 px, joint
    radii 11 and 9 px, a step of 17 px) paid ``Cc`` at its true place for its wrist's
    ball (its pair cost 0.93 instead of 0.26), and the fit drew the wrist and the hand's
    tip up the forearm instead (the tip 8.3% of the figure's height off).

    :func:`pair_cost` passes the larger of the drawn and the expected length, so a
    placement cannot escape the test by drawing the bone shorter (48 drawings, mean / p90
    / max %h: 3.62 / 8.84 / 16.53 with the drawn length, 3.55 / 8.57 / 15.81 with it).
    The trade-off: the probes stay on the drawn bone, so a bone drawn much shorter than
    its length (a hand pointing at the viewer) is probed near its joints' own outlines
    again and can pay ``Cc`` for a drawn joint ball.

    Args:
        dist: Bone lengths, pixels, ``(Ka, Kb)``.
        ra: Head radii, pixels, ``(Ka,)``.
        rb: Tail radii, pixels, ``(Kb,)``.
        eps: Resampling step, pixels.

    Returns:
        ``(Ka, Kb)`` bool.
    """
    return _room(dist, ra[:, None] + rb[None, :], eps)


def _room(dist: np.ndarray, radii: np.ndarray, eps: float) -> np.ndarray:
    """:func:`crossing_room` element by element, ``radii`` the two radii's sums."""
    return dist > radii + 2.0 * eps


def crossing_stations(dist: np.ndarray, ra: np.ndarray, rb: np.ndarray, eps: float,
                      count: int = 9) -> np.ndarray:
    """Axis parameters where the consistency term ``Cc`` looks for crossed contours.

    The bone's axis is probed between its two joint circles, one resampling step beyond
    each (the crossing test's tolerance is half a step): inside a joint's circle the
    contour that crosses the axis is that joint's own outline (the rounded end of a limb
    part, or a drawn joint ball), which a correct placement always crosses; only a contour
    crossed between the circles means the bone leaves its shape.

    Args:
        dist: Drawn bone lengths, pixels, ``(Ka, Kb)``.
        ra: Head radii, pixels, ``(Ka,)``.
        rb: Tail radii, pixels, ``(Kb,)``.
        eps: Resampling step, pixels.
        count: Stations per bone.

    Returns:
        Parameters in ``[0, 1]`` (kept within ``[0.1, 0.9]``), shape ``(Ka, Kb, count)``;
        a bone without room between its widened circles gets every station at the middle
        of their overlap (:func:`crossing_room` leaves it out of the test unless its
        expected length has room).
    """
    return _axis_stations(dist, ra[:, None], rb[None, :], eps, count)


def _axis_stations(dist: np.ndarray, ra: np.ndarray, rb: np.ndarray, eps: float,
                   count: int = 9) -> np.ndarray:
    """:func:`crossing_stations` element by element: ``dist``, ``ra``, ``rb`` broadcast.

    Returns:
        Parameters, the broadcast shape with a last axis of ``count``.
    """
    length = np.maximum(dist, 1e-9)
    # np.clip's values with two ufunc calls each (clip's wrapper costs more on small tables).
    lo = np.minimum(np.maximum((ra + eps) / length, 0.1), 0.9)
    hi = np.minimum(np.maximum(1.0 - (rb + eps) / length, 0.1), 0.9)
    short = hi < lo  # no room between the circles: the middle of the gap between them
    mid = 0.5 * (lo + hi)
    lo, hi = np.where(short, mid, lo), np.where(short, mid, hi)
    return lo[..., None] + (hi - lo)[..., None] * _unit_steps(count)


def bone_frame(drawing: Drawing, pa: np.ndarray, pb: np.ndarray, idx: np.ndarray):
    """Axis parameter ``t`` and signed offset ``h`` of samples ``idx`` for all bone pairs.

    Returns:
        ``(t, h, dist, u)``: ``t, h`` of shape ``(Ka, Kb, n)``, ``dist (Ka, Kb)``, unit axes
        ``u (Ka, Kb, 2)``. ``h > 0`` left of the bone (head to tail).
    """
    d = pb[None, :, :] - pa[:, None, :]
    dist = np.linalg.norm(d, axis=2)
    u = d / np.maximum(dist, 1e-9)[..., None]
    rel = drawing.points[idx][None, None, :, :] - pa[:, None, None, :]
    t = np.einsum("abnd,abd->abn", rel, u) / np.maximum(dist, 1e-9)[..., None]
    h = u[..., None, 0] * rel[..., 1] - u[..., None, 1] * rel[..., 0]
    return t, h, dist, u


def rigid_cost(drawing: Drawing, pa: np.ndarray, pb: np.ndarray, offset: np.ndarray,
               params: CostParams | None = None, length: float | None = None) -> np.ndarray:
    """Cost of a rigid offset link (an unconnected head such as a hip), ``(Ka, Kb)``.

    With ``view_offsets`` (our addition) the drawn offset ``pb - pa`` is compared with the
    offset seen in the view at the character's current pose (a 2D rigid prior: hips and
    shoulders keep their layout); otherwise only its length is, with the length term
    ``Cl`` (Eq. 2) at ``length``.

    Args:
        drawing: The preprocessed drawing.
        pa: Parent joint positions, pixels, ``(Ka, 2)``.
        pb: Joint positions, pixels, ``(Kb, 2)``.
        offset: Expected offset, pixels, ``(2,)``.
        params: Cost parameters.
        length: Expected length of the offset, pixels (default: that of ``offset``).
    """
    params = params or CostParams()
    if not params.view_offsets:
        dist = np.linalg.norm(np.asarray(pb, float)[None] - np.asarray(pa, float)[:, None],
                              axis=2)
        length = float(np.linalg.norm(offset)) if length is None else length
        return length_cost(dist, length, params.sigma_length * drawing.diagonal)
    diff = np.asarray(pb, float)[None] - np.asarray(pa, float)[:, None] - offset
    sigma = params.rigid_sigma * drawing.diagonal
    return 1.0 - np.exp(-np.einsum("abd,abd->ab", diff, diff) / (2.0 * sigma**2))


def direction_cost(pa: np.ndarray, pb: np.ndarray, reference: np.ndarray,
                   params: CostParams | None = None) -> np.ndarray:
    """Weak prior keeping a bone's drawn direction near its direction in the view.

    ``w_direction (1 - cos theta) / 2`` with ``theta`` the angle between the drawn bone
    and the bone at the character's current pose seen in the same view. Not part of the
    paper: it breaks the ties of the matching energy between symmetric or reversed
    placements (a leg drawn in the arm's place) that the paper resolves by enumeration.

    Args:
        pa: Head positions, pixels, ``(Ka, 2)``.
        pb: Tail positions, pixels, ``(Kb, 2)``.
        reference: The bone's offset in the view, pixels, ``(2,)``.
        params: Cost parameters.

    Returns:
        Costs, shape ``(Ka, Kb)``.
    """
    params = params or CostParams()
    d = np.asarray(pb, float)[None] - np.asarray(pa, float)[:, None]
    ref = np.asarray(reference, float)
    norm = _norms(d, 2) * max(float(np.linalg.norm(ref)), 1e-9)
    cos = np.where(norm > 1e-9, d @ ref / np.maximum(norm, 1e-9), 1.0)
    return params.w_direction * 0.5 * (1.0 - cos)


def triplet_cost(pa: np.ndarray, pb: np.ndarray, pc: np.ndarray, shared: np.ndarray,
                 rest_angle: float, params: CostParams | None = None) -> np.ndarray:
    """Naturalness ``Cn`` of consecutive bones ``a -> b -> c``, shape ``(Ka, Kb, Kc)``.

    The turning angle at ``b`` is compared with the angle between the bones in the view at
    the character's current pose;
    ``sigma_a`` is wider where the three joints come from the same contour (``shared``).

    Args:
        pa: First joint positions, pixels, ``(Ka, 2)``.
        pb: Middle joint positions, pixels, ``(Kb, 2)``.
        pc: Last joint positions, pixels, ``(Kc, 2)``.
        shared: Whether the three joints share an originating contour, ``(Ka, Kb, Kc)``.
        rest_angle: Angle between the two bones in the view at the current pose, radians.
        params: Cost parameters.
    """
    params = params or CostParams()
    d1 = pb[None, :, :] - pa[:, None, :]
    d2 = pc[None, :, :] - pb[:, None, :]
    n1 = _norms(d1, 2)
    n2 = _norms(d2, 2)
    cos = np.einsum("abd,bcd->abc", d1, d2) / np.maximum(n1[:, :, None] * n2[None], 1e-9)
    ang = np.arccos(np.minimum(np.maximum(cos, -1.0), 1.0))
    sigma = np.where(shared, params.sigma_angle_shared, params.sigma_angle)
    return 1.0 - np.exp(-((ang - rest_angle) ** 2) / (2.0 * sigma**2))
