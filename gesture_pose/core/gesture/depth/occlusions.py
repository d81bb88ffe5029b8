"""Occlusions and T-junctions read from a drawing's contours (Gesture3D Section 7, Eq. 8).

Where one body part passes in front of another, the outline of the part behind stops at
the outline of the part in front, which goes on: the drawing has a T-junction whose stem
is the hidden part's contour and whose top is the occluder's. The detection works on the
2D embedding (:class:`..types.Embedding2D`) alone:

1. **Junctions.** A contour end (not joined to another stroke by a Gestalt bridge) that
   stops within ``tolerance`` resampling steps of another contour's interior (at least
   ``interior`` steps from that contour's ends) is the stem of a T; the nearest point of
   the other contour is the junction point ``q``. A contour may also end on itself (an
   outline that folds back), away from its own end.
2. **Parts.** Every contour sample gets a solving bone: the bone the 2D fit matched it to
   (the embedding's correspondences) or else the drawn bone whose tube of the fitted radii
   passes nearest it (``|distance to the axis - radius|`` below ``reach`` times the
   radius). The stem's bone is the most common label of the stem's samples within one
   resampling step of its end (the end sample itself lies on the top's outline and is
   skipped), the top's bone that of the top's samples on either side of ``q``, each
   weighted by the inverse of its distance to ``q`` plus a quarter step (ours: the
   sample at ``q`` decides between single samples of different bones around it). A stem
   ending on an outline of its own bone (a hand's outline folding on itself) gives no
   order: before, the stem's bone was left out of the top's vote, and the one sample of
   another bone nearby made a T (the sample humanoid's hand pointing at the viewer read
   behind its upper arm: its whole Pose 5.7 % of the height off, 3.2 without it).
3. **Order.** Between bones at least ``min_parts`` parent-child steps apart whose drawn
   tubes overlap (an inter-part occlusion: one part passes over the other) the stem's bone
   is behind the top's at ``q``, with the tube depths of Eq. 8
   (:func:`.ordering.occlusion_constraint`). Between two bones that share a joint (an
   intra-part T-junction) the stem bone turns away: its far joint is deeper than the
   shared one. A pair found in front of each other both ways gives no order.
4. **Roots** (ours, :func:`root_junctions`). Outlines of a part that stop, at the part's
   root, on the outline of the body it hangs from (an arm pulled back behind the torso):
   the part turns away from the viewer, as the stem of an intra-part T-junction.

The defaults were chosen on traced contours of known poses of the sample characters
(whole 2D fit, 18 drawings): junction ends within half a resampling step of a contour at
least one step inside it, parts at least two steps apart whose tubes overlap. The
occlusions kept were right for 17 of the 21 bone pairs whose true depths differ clearly
(the rest lie at nearly equal depth); with looser settings, or the 2D fit's joints off by
tens of pixels, bones are misattributed and the rate drops to about 60%.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..types import Embedding2D, Occlusion


@dataclass(frozen=True)
class Junction:
    """A contour end stopping on another contour: the stem and top of a T.

    Attributes:
        stem_contour: Index of the contour that ends (the hidden part's outline).
        stem_end: Which end of it: 0 its first sample, 1 its last.
        top_contour: Index of the contour it ends on (the occluder's outline).
        point: The junction point ``q`` on the top contour, pixels, shape ``(2,)``.
        gap: Distance from the stem's end to ``q``, pixels.
        stem_bone: Solving bone of the stem near its end, -1 if unknown.
        top_bone: Solving bone of the top at ``q``, -1 if unknown.
    """

    stem_contour: int
    stem_end: int
    top_contour: int
    point: np.ndarray
    gap: float
    stem_bone: int = -1
    top_bone: int = -1


def _segments(contours: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                    np.ndarray, np.ndarray]:
    """All polyline segments of the contours.

    Returns:
        ``(a, b, contour, arc, length)``: segment starts and ends ``(S, 2)``, the contour of
        each ``(S,)``, the arc length at each start ``(S,)`` and each contour's length
        ``(C,)``, pixels.
    """
    a = np.concatenate([c[:-1] for c in contours])
    b = np.concatenate([c[1:] for c in contours])
    owner = np.concatenate([np.full(len(c) - 1, k) for k, c in enumerate(contours)])
    seg = np.linalg.norm(b - a, axis=1)
    starts = np.cumsum([0] + [len(c) - 1 for c in contours])
    total = np.r_[0.0, np.cumsum(seg)]
    arc = total[:-1] - total[starts[owner]]
    length = total[starts[1:]] - total[starts[:-1]]
    return a, b, owner, arc, length


def find_junctions(contours: tuple[np.ndarray, ...], epsilon: float,
                   bridges: np.ndarray | None = None, tolerance: float = 0.5,
                   interior: float = 1.0, min_angle: float = np.radians(10.0)
                   ) -> list[Junction]:
    """Contour ends that stop on another contour's interior (stems of T-junctions).

    Args:
        contours: Polylines, each ``(k, 2)`` pixels (at least 2 samples to count).
        epsilon: Resampling step of the drawing, pixels.
        bridges: Gestalt bridges ``(stroke_a, end_a, stroke_b, end_b)``, ``(b, 4)``: bridged
            ends continue another stroke and are no stems.
        tolerance: Largest distance from the end to the top contour, in steps.
        interior: Smallest arc length from ``q`` to the top contour's ends, in steps.
        min_angle: Smallest angle between the stem's last segment and the top there,
            radians (a stem running along the top is a continuation, not a T).

    Returns:
        The junctions (bones not yet attributed), at most one per contour end.
    """
    idx = [k for k, c in enumerate(contours) if len(c) >= 2]
    if len(idx) < 1:
        return []
    polys = [np.asarray(contours[k], float) for k in idx]
    a, b, owner, arc, length = _segments(polys)
    ab = b - a
    seg = np.linalg.norm(ab, axis=1)
    bridged = set()
    if bridges is not None and len(bridges):
        br = np.asarray(bridges, int).reshape(-1, 4)
        bridged = {(int(r[0]), int(r[1])) for r in br} | {(int(r[2]), int(r[3])) for r in br}
    # Every end with the sample before it: (contour position in idx, end flag).
    ends = [(i, e) for i in range(len(polys)) for e in (0, 1)
            if (idx[i], e) not in bridged]
    if not ends:
        return []
    P = np.array([polys[i][0] if e == 0 else polys[i][-1] for i, e in ends])
    prev = np.array([polys[i][1] if e == 0 else polys[i][-2] for i, e in ends])
    own = np.array([i for i, _ in ends])
    own_arc = np.array([0.0 if e == 0 else length[i] for i, e in ends])
    # Closest point of every segment to every end, (E, S).
    t = np.clip(np.einsum("esk,sk->es", P[:, None] - a[None], ab)
                / np.maximum(seg**2, 1e-12), 0.0, 1.0)
    Q = a[None] + t[..., None] * ab[None]
    dist = np.linalg.norm(Q - P[:, None], axis=2)
    s_arc = arc[None] + t * seg[None]
    inner = np.minimum(s_arc, length[owner][None] - s_arc)
    same = owner[None] == own[:, None]
    # On its own contour only far (along the contour) from the end itself.
    dist = np.where(same & (np.abs(s_arc - own_arc[:, None]) < 3.0 * epsilon), np.inf, dist)
    dist = np.where(inner < interior * epsilon, np.inf, dist)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(ends))
    d = dist[rows, best]
    tangent = P - prev
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    top_dir = ab[best] / np.maximum(seg[best], 1e-12)[:, None]
    crossing = np.abs(np.sum(tangent * top_dir, axis=1)) <= np.cos(min_angle)
    keep = (d <= tolerance * epsilon) & crossing
    return [Junction(idx[own[k]], ends[k][1], idx[owner[best[k]]], Q[k, best[k]].copy(),
                     float(d[k])) for k in np.flatnonzero(keep)]


def _tube_distance(points: np.ndarray, heads: np.ndarray, tails: np.ndarray,
                   r_head: np.ndarray, r_tail: np.ndarray) -> np.ndarray:
    """``|distance to each bone's axis - its radius there| / radius``, shape ``(n, m)``."""
    ab = tails - heads
    t = np.clip(np.einsum("nmk,mk->nm", points[:, None] - heads[None], ab)
                / np.maximum(np.sum(ab * ab, axis=1), 1e-12), 0.0, 1.0)
    foot = heads[None] + t[..., None] * ab[None]
    d = np.linalg.norm(points[:, None] - foot, axis=2)
    r = np.maximum((1.0 - t) * r_head[None] + t * r_tail[None], 1e-6)
    return np.abs(d - r) / r


def sample_bones(embedding: Embedding2D, reach: float = 0.5) -> tuple[np.ndarray, ...]:
    """The solving bone of every contour sample, -1 where none fits.

    Samples the 2D fit matched to a bone keep it; the others take the bone whose drawn
    tube (axis between its joints, radii of its joints) passes nearest, when that is
    within ``reach`` radii.

    Args:
        embedding: The 2D embedding (contours, correspondences, joints and radii).
        reach: Largest ``|distance to the axis - radius| / radius`` of a geometric label.

    Returns:
        One label array ``(k,)`` per contour.
    """
    s = embedding.solving
    contours = [np.asarray(c, float).reshape(-1, 2) for c in embedding.contours]
    if not contours:
        return ()
    pts = np.concatenate(contours)
    labels = np.full(len(pts), -1)
    if len(pts) and s.n_bones:
        j, r = embedding.joints2d, embedding.joint_radius
        rel = _tube_distance(pts, j[s.head_joint], j[s.tail_joint], r[s.head_joint],
                             r[s.tail_joint])
        nearest = np.argmin(rel, axis=1)
        labels = np.where(rel[np.arange(len(pts)), nearest] <= reach, nearest, -1)
    matched = [(np.asarray(p, float).reshape(-1, 2), bone)
               for bone, pieces in enumerate(embedding.bone_segments) for p in pieces]
    if matched:
        mp = np.concatenate([p for p, _ in matched])
        mb = np.concatenate([np.full(len(p), bone) for p, bone in matched])
        # Matched pieces are samples of the contours themselves: look them up exactly.
        key = {tuple(x): k for k, x in enumerate(map(tuple, pts))}
        hit = np.array([key.get(tuple(x), -1) for x in mp])
        labels[hit[hit >= 0]] = mb[hit >= 0]
    splits = np.cumsum([len(c) for c in contours])[:-1]
    return tuple(np.split(labels, splits))


def _majority(labels: np.ndarray, weights: np.ndarray | None = None) -> int:
    """The non-negative label with the largest total weight (-1 when there is none).

    Ties go to the smallest label.

    Args:
        labels: Labels, shape ``(k,)``; -1 is none.
        weights: Weight of each label, shape ``(k,)``; None counts each once.
    """
    keep = labels >= 0
    if not np.any(keep):
        return -1
    w = np.ones(len(labels)) if weights is None else np.asarray(weights, float)
    values, inverse = np.unique(labels[keep], return_inverse=True)
    return int(values[np.argmax(np.bincount(inverse, weights=w[keep]))])


def attribute(junctions: list[Junction], embedding: Embedding2D,
              labels: tuple[np.ndarray, ...]) -> list[Junction]:
    """Give each junction its stem and top bones (see the module docstring).

    Args:
        junctions: Junctions from :func:`find_junctions` on ``embedding.contours``.
        embedding: The 2D embedding.
        labels: Per-sample bones from :func:`sample_bones`.

    Returns:
        The junctions with ``stem_bone`` and ``top_bone`` set (-1 where unknown).
    """
    eps = embedding.epsilon if embedding.epsilon > 0 else 2.0
    out = []
    for jn in junctions:
        stem = np.asarray(embedding.contours[jn.stem_contour], float)
        lab = labels[jn.stem_contour]
        if jn.stem_end == 1:
            stem, lab = stem[::-1], lab[::-1]
        arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(stem, axis=0), axis=1))]
        near = (arc <= max(eps, arc[1] if len(arc) > 1 else 0.0) + 1e-9)
        near[0] = len(stem) <= 1
        stem_bone = _majority(lab[near])
        top = np.asarray(embedding.contours[jn.top_contour], float)
        top_lab = labels[jn.top_contour]
        d = np.linalg.norm(top - jn.point, axis=1)
        around = d <= max(eps, float(np.partition(d, min(1, len(d) - 1))[min(1, len(d) - 1)]))
        # Nearer samples weigh more: the bone whose outline passes at q decides, not a tie
        # between single samples a step away (which went to the lowest bone index).
        top_bone = _majority(top_lab[around], 1.0 / (d[around] + 0.25 * eps))
        if top_bone == stem_bone:
            top_bone = -1  # a part's outline ending on its own outline: no order
        out.append(Junction(jn.stem_contour, jn.stem_end, jn.top_contour, jn.point, jn.gap,
                            stem_bone, top_bone))
    return out


def detect_junctions(embedding: Embedding2D, tolerance: float = 0.5,
                     interior: float = 1.0, min_angle: float = np.radians(10.0),
                     reach: float = 0.5, found: list[Junction] | None = None
                     ) -> list[Junction]:
    """T-junctions of the drawing's contours with the bones on either side.

    Args:
        embedding: The 2D embedding with its contours and correspondences.
        tolerance: See :func:`find_junctions` (resampling steps).
        interior: See :func:`find_junctions` (resampling steps).
        min_angle: See :func:`find_junctions` (radians).
        reach: See :func:`sample_bones`.
        found: The junctions :func:`find_junctions` finds on ``embedding.contours`` with
            these parameters, when the caller has them already.

    Returns:
        Junctions whose stem and top bones are known and differ.
    """
    if found is None:
        eps = embedding.epsilon if embedding.epsilon > 0 else 2.0
        found = find_junctions(embedding.contours, eps, embedding.bridges, tolerance,
                               interior, min_angle)
    if not found:
        return []
    done = attribute(found, embedding, sample_bones(embedding, reach))
    return [j for j in done if j.stem_bone >= 0 and j.top_bone >= 0
            and j.stem_bone != j.top_bone]


@dataclass(frozen=True)
class RootJunction:
    """A part whose outline stops on the outline of the body it hangs from, at its root.

    Attributes:
        bone: Solving bone whose outline stops (the stem's part, ``B``).
        occluder: Its ancestor whose outline goes on past ``B``'s root (``A``).
        point: The first junction point ``q`` read, pixels, shape ``(2,)``.
        count: How many contour ends read it.
    """

    bone: int
    occluder: int
    point: np.ndarray
    count: int = 1


def _leaving(contour: np.ndarray, end: int, step: float) -> np.ndarray:
    """Unit direction in which a contour leaves its end ``end`` (0 first, 1 last sample).

    Measured to the first sample at least ``step`` pixels along it (else its other end).
    """
    pts = np.asarray(contour, float)
    if end == 1:
        pts = pts[::-1]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
    k = min(int(np.searchsorted(arc, step)), len(pts) - 1)
    d = pts[k] - pts[0]
    return d / max(float(np.linalg.norm(d)), 1e-12)


def root_junctions(embedding: Embedding2D, junctions: list[Junction], reach: float = 0.5,
                   head_reach: float = 1.5, min_count: int = 2,
                   max_turn: float = np.radians(45.0)) -> list[RootJunction]:
    """T-junctions at the root of a part, on the outline of the body it hangs from (ours).

    An arm pulled back behind the torso, seen from the front, is drawn with the torso's
    outline running on past the arm's root and the arm's outlines ending on it; an arm
    in front shows the reverse. Eq. 8 at such a junction asks little: ``q`` lies at the
    arm's root, whose depth is its head joint's, so the arm's direction is left free.
    What the junction says about that direction is the paper's intra-part T-junction
    reading: the part whose outline stops turns away from the viewer at the junction.

    A junction (:func:`find_junctions`) counts when ``q`` lies within ``head_reach``
    drawn radii of the head joint of a bone ``B`` with a parent, the stem leaves ``q``
    along ``B``'s drawn axis (within ``max_turn``), and the top contour at ``q`` is the
    outline of an ancestor ``A`` of ``B`` that shares no joint with it (the drawn tube of ``A``
    passes within ``reach`` radii of ``q``, as in :func:`sample_bones`). Bones are read
    from the fitted joints and radii alone: near a root the 2D fit's correspondences
    give the top contour to the part hanging there as often as to the body.

    Args:
        embedding: The 2D embedding.
        junctions: Junctions from :func:`find_junctions` on ``embedding.contours``.
        reach: Largest ``|distance to A's axis - its radius| / radius`` at ``q``.
        head_reach: Largest distance from ``q`` to ``B``'s head joint over its radius
            (the outline stops at about one radius from the axis).
        min_count: Fewest contour ends that must read a pair (the part's outlines both
            stopping there): one alone is as often wrong as right on the benchmark's
            traced drawings.
        max_turn: Largest angle between the stem's direction from ``q`` and ``B``'s
            drawn axis, radians.

    Returns:
        One :class:`RootJunction` per ``(B, A)`` pair read at least ``min_count`` times.
    """
    s = embedding.solving
    j, r = embedding.joints2d, embedding.joint_radius
    eps = embedding.epsilon if embedding.epsilon > 0 else 2.0
    parent = np.asarray(s.parent, int)
    heads, tails = np.asarray(s.head_joint, int), np.asarray(s.tail_joint, int)
    axis = j[tails] - j[heads]
    axis = axis / np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
    out: dict[tuple[int, int], RootJunction] = {}
    for jn in junctions:
        q = np.asarray(jn.point, float)
        near = np.linalg.norm(j[heads] - q, axis=1) / np.maximum(r[heads], 1e-9)
        near[parent < 0] = np.inf
        bone = int(np.argmin(near))
        if near[bone] > head_reach:
            continue
        leave = _leaving(embedding.contours[jn.stem_contour], jn.stem_end, eps)
        if float(leave @ axis[bone]) < np.cos(max_turn):
            continue
        up = []
        a = int(parent[bone])
        while a >= 0:
            if heads[bone] not in (heads[a], tails[a]):
                up.append(a)
            a = int(parent[a])
        if not up:
            continue
        up = np.array(up)
        rel = _tube_distance(q[None], j[heads[up]], j[tails[up]], r[heads[up]],
                             r[tails[up]])[0]
        k = int(np.argmin(rel))
        if rel[k] <= reach:
            key = (bone, int(up[k]))
            n = out[key].count + 1 if key in out else 1
            first = out[key].point if key in out else q.copy()
            out[key] = RootJunction(bone, int(up[k]), first, n)
    return [r for r in out.values() if r.count >= min_count]


def radius_at(embedding: Embedding2D, bone: int, q: np.ndarray) -> float:
    """Drawn radius of a bone at point ``q``, interpolated between its joints, pixels."""
    s = embedding.solving
    h, t = embedding.joints2d[s.head_joint[bone]], embedding.joints2d[s.tail_joint[bone]]
    ab = t - h
    u = float(np.clip((q - h) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0))
    r = embedding.joint_radius
    return float((1.0 - u) * r[s.head_joint[bone]] + u * r[s.tail_joint[bone]])


def bone_steps(parent: np.ndarray) -> np.ndarray:
    """Number of parent-child steps between every pair of bones of a forest, ``(m, m)``.

    Bones of different trees are ``m`` steps apart.
    """
    parent = np.asarray(parent, int)
    m = len(parent)
    depth = np.zeros(m, int)
    anc = np.full((m, m), -1)  # anc[k, i]: ancestor of k at i steps up
    for k in range(m):
        path = [k]
        while parent[path[-1]] >= 0:
            path.append(int(parent[path[-1]]))
        depth[k] = len(path) - 1
        anc[k, :len(path)] = path
    steps = np.full((m, m), m, dtype=int)
    for i in range(m):
        up_i = {int(b): n for n, b in enumerate(anc[i]) if b >= 0}
        for j in range(m):
            for n, b in enumerate(anc[j]):
                if b >= 0 and int(b) in up_i:
                    steps[i, j] = n + up_i[int(b)]
                    break
    return steps


def tubes_overlap(embedding: Embedding2D, a: int, b: int, samples: int = 11) -> float:
    """Closest approach of two bones' drawn axes over the sum of their radii there.

    Below 1 the two tubes overlap in the drawing, as two parts one in front of the other
    must.

    Args:
        embedding: The 2D embedding.
        a: A solving bone.
        b: Another solving bone.
        samples: Points sampled along each axis.

    Returns:
        The smallest ``distance / (r_a + r_b)`` over the samples.
    """
    s, j, r = embedding.solving, embedding.joints2d, embedding.joint_radius
    t = np.linspace(0.0, 1.0, samples)[:, None]
    best = np.inf
    for p, q in ((a, b), (b, a)):
        pts = j[s.head_joint[p]] + t * (j[s.tail_joint[p]] - j[s.head_joint[p]])
        rp = (1.0 - t[:, 0]) * r[s.head_joint[p]] + t[:, 0] * r[s.tail_joint[p]]
        h, e = j[s.head_joint[q]], j[s.tail_joint[q]]
        u = np.clip((pts - h) @ (e - h) / max(float((e - h) @ (e - h)), 1e-12), 0.0, 1.0)
        d = np.linalg.norm(pts - (h + u[:, None] * (e - h)), axis=1)
        rq = (1.0 - u) * r[s.head_joint[q]] + u * r[s.tail_joint[q]]
        best = min(best, float(np.min(d / np.maximum(rp + rq, 1e-9))))
    return best


def junction_occlusions(embedding: Embedding2D, junctions: list[Junction],
                        min_parts: int = 2, overlap: float = 1.0
                        ) -> tuple[list[Occlusion], list[tuple[int, int]]]:
    """Sort attributed junctions into inter-part occlusions and intra-part T-junctions.

    Args:
        embedding: The 2D embedding.
        junctions: Junctions with their bones (:func:`detect_junctions`).
        min_parts: Fewest parent-child steps between the bones of an occlusion.
        overlap: Largest :func:`tubes_overlap` of an occlusion's bones.

    Returns:
        ``(occlusions, t_junctions)``: one :class:`Occlusion` per (front, back) bone pair
        (the stem's bone behind the top's, radii at ``q``), and ``(stem, top)`` bone pairs
        sharing a joint. Pairs seen both ways are left out.
    """
    s = embedding.solving
    steps = bone_steps(s.parent)
    pairs = {(j.stem_bone, j.top_bone) for j in junctions}
    occ: dict[tuple[int, int], Occlusion] = {}
    tees: list[tuple[int, int]] = []
    for j in junctions:
        stem, top = j.stem_bone, j.top_bone
        if stem < 0 or top < 0:
            continue  # no part on one side (:func:`attribute`'s -1)
        if (top, stem) in pairs:
            continue  # contradictory evidence
        shared = {int(s.head_joint[stem]), int(s.tail_joint[stem])} & {
            int(s.head_joint[top]), int(s.tail_joint[top])}
        if shared and steps[stem, top] == 1:
            if (stem, top) not in tees:
                tees.append((stem, top))
        elif (steps[stem, top] >= min_parts and (top, stem) not in occ
              and tubes_overlap(embedding, stem, top) <= overlap):
            occ[(top, stem)] = Occlusion(top, stem, j.point, radius_at(embedding, top, j.point),
                                         radius_at(embedding, stem, j.point))
    return list(occ.values()), tees
