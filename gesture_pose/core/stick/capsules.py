"""Per-bone capsules sized from the skinned mesh, and their collision energies (Eq. 11).

Every bone with skinned vertices becomes a capsule: its posed segment head-tail and a
radius, the median distance from the bone's segment of the rest vertices it dominates.
A bone that stops well short of its children (rigs imported from glTF give every bone a
token length) has its segment run from its head to the head of the child along which its
vertices spread instead, so that a shin is a capsule from knee to ankle, not a 37 cm
sphere at the knee.
Body collisions are checked between non-adjacent capsules (no shared joint, more than
two bones apart in the hierarchy); environment collisions sample each capsule's axis
against a distance grid of the environment (see :mod:`.environment`). The penalty is
the squared penetration depth, ``E = sum max(0, r_a + r_b - d_ab)^2``, with its gradient
with respect to the segment end points (Danskin: the closest-point parameters stay fixed).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..skeleton import Skeleton


@dataclass(frozen=True)
class Capsules:
    """Capsules of the body.

    Attributes:
        bones: Bone of each capsule, shape ``(c,)``; its head starts the capsule.
        radii: Radii in world units, shape ``(c,)``.
        pairs: Non-adjacent capsule pairs checked for self-collision, shape ``(q, 2)``.
        ends: Where each capsule ends, as an index into the bones' heads and tails stacked
            (``(2n, 3)``: ``b`` is bone ``b``'s head, ``n + b`` its tail), shape ``(c,)``;
            None: each bone's own tail.
    """

    bones: np.ndarray
    radii: np.ndarray
    pairs: np.ndarray
    ends: np.ndarray | None = None

    def end_index(self, n_bones: int) -> np.ndarray:
        """Index of each capsule's end in the stacked heads and tails, ``(c,)``."""
        return n_bones + self.bones if self.ends is None else self.ends

    def segments(self, heads: np.ndarray, tails: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Capsule axes' starts and ends ``(..., c, 3)`` from heads and tails ``(..., n, 3)``."""
        both = np.concatenate([heads, tails], axis=-2)
        return both[..., self.bones, :], both[..., self.end_index(heads.shape[-2]), :]

    def segment_jacobians(self, jh: np.ndarray, jt: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians of the capsule ends ``(c, 3, G)`` twice from the bones' ``(n, 3, G)``."""
        both = np.concatenate([jh, jt], axis=0)
        return both[self.bones], both[self.end_index(jh.shape[0])]

    def scatter(self, g_start: np.ndarray, g_end: np.ndarray, n_bones: int
                ) -> tuple[np.ndarray, np.ndarray]:
        """Gradients on capsule ends ``(P, c, 3)`` -> on bone heads and tails ``(P, n, 3)``."""
        both = np.zeros((g_start.shape[0], 2 * n_bones, 3))
        np.add.at(both, (slice(None), self.bones), g_start)
        np.add.at(both, (slice(None), self.end_index(n_bones)), g_end)
        return both[:, :n_bones], both[:, n_bones:]


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points to segments, broadcasting ``(..., 3)`` arrays to ``(...)``."""
    d = b - a
    t = np.clip(np.sum((p - a) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-18), 0.0, 1.0)
    return np.linalg.norm(p - a - t[..., None] * d, axis=-1)


def segment_closest(p0, p1, q0, q1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points between segments ``p0p1`` and ``q0q1`` (all ``(..., 3)``).

    Returns:
        ``(s, t, dist)``: parameters along each segment in ``[0, 1]`` and the distance,
        each of shape ``(...)``.
    """
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.maximum(np.sum(d1 * d1, -1), 1e-18)
    e = np.maximum(np.sum(d2 * d2, -1), 1e-18)
    b, c, f = np.sum(d1 * d2, -1), np.sum(d1 * r, -1), np.sum(d2 * r, -1)
    den = a * e - b * b
    s = np.where(den > 1e-12 * a * e, np.clip((b * f - c * e) / np.maximum(den, 1e-30), 0, 1),
                 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0, np.clip(-c / a, 0, 1), np.where(t > 1, np.clip((b - c) / a, 0, 1), s))
    t = np.clip(t, 0, 1)
    diff = p0 + s[..., None] * d1 - q0 - t[..., None] * d2
    return s, t, np.linalg.norm(diff, axis=-1)


#: Slack (world units) of :func:`pair_closest`'s bounding-sphere test: a pair is left out
#: only when its spheres are apart by more than this, far above the rounding of the test.
SPHERE_SLACK = 1e-6


def pair_closest(caps: Capsules, start: np.ndarray, end: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`segment_closest` of every capsule pair, computed only where they can touch.

    Each capsule lies in the sphere about its axis' midpoint of radius half its axis plus
    its own radius; a pair whose spheres are apart (by more than :data:`SPHERE_SLACK`)
    does not overlap, its penetration ``max(0, r_a + r_b - d)`` is zero and its distance
    is not needed. Those pairs get ``s = t = 0`` and ``d = inf``; the others the values
    :func:`segment_closest` gives them on all pairs (the same operations element by
    element, so the penetrations, energies and gradients are bit-identical). On the
    Adventurer most of its 822 pairs are apart in any pose.

    Args:
        caps: The capsules (``pairs`` ``(q, 2)``).
        start: Capsule axes' starts, shape ``(..., c, 3)``.
        end: Their ends, shape ``(..., c, 3)``.

    Returns:
        ``(s, t, d)``, each of shape ``(..., q)``.
    """
    a, b = caps.pairs[:, 0], caps.pairs[:, 1]
    mid = 0.5 * (start + end)
    reach = 0.5 * np.linalg.norm(end - start, axis=-1) + caps.radii
    gap = mid[..., a, :] - mid[..., b, :]
    near = (np.sqrt(np.sum(gap * gap, -1)) <= reach[..., a] + reach[..., b] + SPHERE_SLACK)
    # Laid out pair-major as segment_closest lays out (..., q) from start[:, a]: sums of
    # the penetrations over the pairs then add in the same order (the same bits).
    shape = near.shape
    s, t = np.zeros(shape, order="F"), np.zeros(shape, order="F")
    d = np.full(shape, np.inf, order="F")
    idx = np.nonzero(near)
    if idx[-1].size:
        lead = idx[:-1]
        pa, pb = a[idx[-1]], b[idx[-1]]
        s[idx], t[idx], d[idx] = segment_closest(start[lead + (pa,)], end[lead + (pa,)],
                                                 start[lead + (pb,)], end[lead + (pb,)])
    return s, t, d


def capsules_from_mesh(skeleton: Skeleton, vertices: np.ndarray | None = None,
                       weights: np.ndarray | None = None,
                       default_ratio: float = 0.12) -> Capsules:
    """Size one capsule per bone from the rest mesh.

    Args:
        skeleton: Rest skeleton.
        vertices: Rest vertices in world space, shape ``(V, 3)``, or None.
        weights: Skin weights, shape ``(V, n)``, or None.
        default_ratio: Radius as a fraction of the bone length when there is no mesh.

    Returns:
        The capsules (bones without vertices are left out when a mesh is given).
    """
    n = skeleton.n_bones
    if vertices is None or weights is None or len(vertices) == 0:
        bones = np.flatnonzero(skeleton.deform) if np.any(skeleton.deform) else np.arange(n)
        radii = default_ratio * skeleton.lengths[bones]
        ends = n + bones
    else:
        owner = np.argmax(weights, axis=1)
        strong = weights[np.arange(len(owner)), owner] > 0.3
        bones, radii, ends = [], [], []
        for i in range(n):
            sel = vertices[(owner == i) & strong]
            if len(sel) < 4:
                continue
            end = _segment_end(skeleton, i, sel)
            tip = skeleton.rest_tails[i] if end >= n else skeleton.rest_heads[end]
            d = point_segment_distance(sel, skeleton.rest_heads[i], tip)
            bones.append(i)
            radii.append(float(np.median(d)))
            ends.append(end)
        bones, radii, ends = np.array(bones, int), np.array(radii), np.array(ends, int)
    return Capsules(bones, radii, _non_adjacent(skeleton, bones), ends)


def _segment_end(skeleton: Skeleton, bone: int, vertices: np.ndarray,
                 short: float = 0.5) -> int:
    """End of a bone's capsule: ``n + bone`` (its tail) or a child's index (its head).

    A child's head is used when the bone is shorter than ``short`` times the distance to
    it; the child is the one lying best along the bone's own direction (a token-length
    chest bone of an imported rig points at its neck, not at a shoulder), or along the
    principal axis of the bone's vertices when the bone has no length.
    """
    n, head = skeleton.n_bones, skeleton.rest_heads[bone]
    kids = np.flatnonzero(skeleton.parents == bone)
    if kids.size == 0:
        return n + bone
    to_kid = skeleton.rest_heads[kids] - head
    dist = np.linalg.norm(to_kid, axis=1)
    axis = skeleton.rest_tails[bone] - head
    if np.linalg.norm(axis) > 1e-9:
        k = int(np.argmax(to_kid @ axis / np.maximum(dist, 1e-12)))
    else:
        centred = vertices - vertices.mean(0)
        axis = np.linalg.svd(centred, full_matrices=False)[2][0]
        k = int(np.argmax(np.abs(to_kid @ axis) / np.maximum(dist, 1e-12)))
    if skeleton.lengths[bone] >= short * dist[k] or dist[k] < 1e-9:
        return n + bone
    return int(kids[k])


def _non_adjacent(skeleton: Skeleton, bones: np.ndarray) -> np.ndarray:
    """Capsule pairs more than two bones apart in the hierarchy, shape ``(q, 2)``."""
    n = skeleton.n_bones
    adj = np.eye(n, dtype=bool)
    par = skeleton.parents
    for i in range(n):
        if par[i] >= 0:
            adj[i, par[i]] = adj[par[i], i] = True
    near = (adj.astype(int) @ adj.astype(int) @ adj.astype(int)) > 0
    c = len(bones)
    ii, jj = np.triu_indices(c, 1)
    keep = ~near[bones[ii], bones[jj]]
    return np.stack([ii[keep], jj[keep]], 1).reshape(-1, 2)


def body_collision(caps: Capsules, heads: np.ndarray, tails: np.ndarray,
                   grad: bool = False) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Self-collision energy ``sum max(0, r_a + r_b - d_ab)^2`` (Eq. 11, body part).

    Args:
        caps: The capsules.
        heads: Posed heads, shape ``(P, n, 3)``.
        tails: Posed tails, shape ``(P, n, 3)``.
        grad: Also return the gradients with respect to heads and tails.

    Returns:
        ``(E (P,), dE/dheads (P, n, 3) or None, dE/dtails (P, n, 3) or None)``.
    """
    if len(caps.pairs) == 0:
        z = np.zeros(heads.shape[0])
        return z, (np.zeros_like(heads) if grad else None), (np.zeros_like(tails) if grad
                                                             else None)
    a, b = caps.pairs[:, 0], caps.pairs[:, 1]
    start, end = caps.segments(heads, tails)
    s, t, d = pair_closest(caps, start, end)
    pen = np.maximum(caps.radii[a] + caps.radii[b] - d, 0.0)
    energy = np.sum(pen**2, axis=1)
    if not grad:
        return energy, None, None
    g0, g1 = np.zeros_like(start), np.zeros_like(end)
    # Only the overlapping pairs push: the others would add zeros (the sums of the
    # overlapping ones keep their order, so the gradient is the same to the last bit).
    pi, qi = np.nonzero(pen > 0.0)
    if qi.size:
        a, b, s, t, d, pen = a[qi], b[qi], s[pi, qi], t[pi, qi], d[pi, qi], pen[pi, qi]
        p0, p1, q0, q1 = start[pi, a], end[pi, a], start[pi, b], end[pi, b]
        diff = p0 + s[..., None] * (p1 - p0) - q0 - t[..., None] * (q1 - q0)
        u = diff / np.maximum(d, 1e-12)[..., None]
        g = (-2.0 * pen)[..., None] * u  # dE/d(closest point on a)
        for arr, idx, coef in ((g0, a, (1 - s)), (g1, a, s), (g0, b, -(1 - t)),
                               (g1, b, -t)):
            np.add.at(arr, (pi, idx), coef[..., None] * g)
    return (energy,) + caps.scatter(g0, g1, heads.shape[-2])


@functools.lru_cache(maxsize=8)
def axis_samples(n_samples: int) -> np.ndarray:
    """Sample parameters along a capsule axis, ``(m,)`` in ``[0, 1]`` (cached, read-only)."""
    u = np.linspace(0.0, 1.0, n_samples)
    u.flags.writeable = False
    return u


def bone_masses(skeleton: Skeleton, caps: Capsules, density: float = 1000.0) -> np.ndarray:
    """Bone masses from the capsule volumes ``pi r^2 L + 4/3 pi r^3`` (kg), ``(n,)``.

    Bones without a capsule weigh nothing.
    """
    m = np.zeros(skeleton.n_bones)
    r, length = caps.radii, skeleton.lengths[caps.bones]
    m[caps.bones] = density * (np.pi * r**2 * length + 4.0 / 3.0 * np.pi * r**3)
    return m
