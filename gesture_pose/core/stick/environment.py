"""The environment as triangle meshes: ray casts, seats (Section 4.1.2) and a distance grid.

All geometry is world space with ``up`` the world's up axis. Ray casts use the
Moller-Trumbore test vectorized over all triangles. A *seat* is found by casting the eye
ray through the drawn pelvis (or contact dot): hits on surfaces facing up (normal within
30 degrees of up) whose height above the floor below them lies within 0.5-1.5 seated
hip heights (the knee height of the character: sitting, the hips are at knee height)
are candidates; the nearest is grown into a flat region of connected up-facing
triangles, and Eq. 3's centerness (distance to the region boundary over its maximum)
picks a central spot near the hit that leaves the body collision-free.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..exceptions import InputError
from ..rotations import normalize
from .genetic import row_hash

UP_ANGLE = np.radians(30.0)
#: Voxel edge (world units) of the distance grid's test for points near no surface.
VOXEL = 0.1
SEAT_RANGE = (0.5, 1.5)


@dataclass(frozen=True)
class Hit:
    """One ray hit.

    Attributes:
        distance: Distance along the ray, world units.
        point: Hit point, shape ``(3,)``.
        normal: Unit face normal facing the ray's origin, shape ``(3,)``.
        triangle: Triangle index.
        object_index: Index of the mesh the triangle belongs to.
    """

    distance: float
    point: np.ndarray
    normal: np.ndarray
    triangle: int
    object_index: int


@dataclass(frozen=True)
class Environment:
    """Static triangle meshes around the character.

    Attributes:
        vertices: World vertices, shape ``(V, 3)``.
        triangles: Vertex indices, shape ``(T, 3)``.
        object_ids: Mesh index of each triangle, shape ``(T,)``.
        object_names: Mesh names.
        up: World up, shape ``(3,)``.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    object_ids: np.ndarray
    object_names: tuple[str, ...] = ()
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    def __post_init__(self) -> None:
        """Validate shapes."""
        v = np.asarray(self.vertices, float).reshape(-1, 3)
        t = np.asarray(self.triangles, int).reshape(-1, 3)
        if len(t) and (t.min() < 0 or t.max() >= len(v)):
            raise InputError("Environment triangles index missing vertices.")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "triangles", t)
        object.__setattr__(self, "object_ids", np.asarray(self.object_ids, int).reshape(-1))

    @property
    def corners(self) -> np.ndarray:
        """Triangle corners, shape ``(T, 3, 3)``."""
        return self.vertices[self.triangles]

    @property
    def normals(self) -> np.ndarray:
        """Unit triangle normals (right-hand winding), shape ``(T, 3)``."""
        c = self.corners
        return normalize(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]))

    def raycast(self, origin: np.ndarray, direction: np.ndarray) -> list[Hit]:
        """All hits of one ray, nearest first (Moller-Trumbore over every triangle).

        Args:
            origin: Ray origin, shape ``(3,)``.
            direction: Ray direction, shape ``(3,)``.

        Returns:
            Hits sorted by distance (both triangle sides count).
        """
        if len(self.triangles) == 0:
            return []
        o, d = np.asarray(origin, float), normalize(np.asarray(direction, float))
        c = self.corners
        e1, e2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
        pv = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pv)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = o - c[:, 0]
        u = np.einsum("ij,ij->i", tv, pv) * inv
        qv = np.cross(tv, e1)
        v = (qv @ d) * inv
        t = np.einsum("ij,ij->i", e2, qv) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
        idx = np.flatnonzero(hit)
        idx = idx[np.argsort(t[idx])]
        n = self.normals[idx]
        n = np.where((n @ d)[:, None] > 0, -n, n)
        return [Hit(float(t[i]), o + t[i] * d, n[k], int(i), int(self.object_ids[i]))
                for k, i in enumerate(idx)]

    def height_above_floor(self, point: np.ndarray) -> float:
        """Height of ``point`` above the lowest surface below it (or the lowest vertex)."""
        up = self.up
        below = [h for h in self.raycast(np.asarray(point) - up * 1e-4, -up)
                 if h.normal @ up > np.cos(UP_ANGLE)]
        base = (below[-1].point @ up if below else float(np.min(self.vertices @ up)))
        return float(np.asarray(point) @ up - base)


def _voxel_keys(cells: np.ndarray) -> np.ndarray:
    """One integer per voxel index triple ``(m, 3) -> (m,)`` (indices within +-2^20)."""
    c = cells.astype(np.int64) + (1 << 20)
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]


@dataclass(frozen=True)
class DistanceGrid:
    """Distance to the environment's surfaces: nearest of dense surface samples.

    Attributes:
        samples: Surface points at most ``spacing`` apart, shape ``(m, 3)``.
        spacing: Sample spacing, world units (the distance error is below half of it).
        max_distance: Distances are clamped to this (only penetrations matter).
    """

    samples: np.ndarray
    spacing: float
    max_distance: float = 0.3
    _tree: cKDTree | None = field(init=False, repr=False, compare=False)
    _near: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Build the k-d tree."""
        # Sliding-midpoint splits without node compaction build 2-3 times faster than
        # the median ones and answer the (exact) nearest-sample queries as fast.
        tree = (cKDTree(self.samples, balanced_tree=False, compact_nodes=False)
                if len(self.samples) else None)
        object.__setattr__(self, "_tree", tree)
        object.__setattr__(self, "_near", {})

    def _near_voxels(self, reach: int) -> np.ndarray:
        """Sorted keys of the voxels (edge ``VOXEL``) within ``reach`` voxels of a sample."""
        if reach not in self._near:
            cells = np.floor(self.samples / VOXEL).astype(np.int64)
            _, first = np.unique(_voxel_keys(cells), return_index=True)
            near = cells[first]
            # The cube of shifts is separable: dilate along one axis at a time.
            for axis in range(3):
                shifts = np.zeros((2 * reach + 1, 3), np.int64)
                shifts[:, axis] = np.arange(-reach, reach + 1)
                near = (near[:, None] + shifts[None]).reshape(-1, 3)
                _, first = np.unique(_voxel_keys(near), return_index=True)
                near = near[first]
            self._near[reach] = _voxel_keys(near)
        return self._near[reach]

    def sample(self, points: np.ndarray, limit: float | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """Distance and its gradient at points.

        Args:
            points: World points, shape ``(..., 3)``.
            limit: Only distances below this are looked up (points whose voxel is farther
                from every sample's skip the k-d search; penetration tests only need
                distances under the largest radius).

        Returns:
            ``(distance (...), gradient (..., 3))``; ``max_distance`` and zero gradient
            where no surface is closer than ``min(limit, max_distance)``.
        """
        p = np.asarray(points, float)
        flat = p.reshape(-1, 3)
        d = np.full(len(flat), self.max_distance)
        grad = np.zeros_like(flat)
        if self._tree is None:
            return d.reshape(p.shape[:-1]), grad.reshape(p.shape)
        bound = self.max_distance if limit is None else min(limit, self.max_distance)
        near_voxels = self._near_voxels(int(np.ceil(bound / VOXEL)))
        keys = _voxel_keys(np.floor(flat / VOXEL))
        pos = np.minimum(np.searchsorted(near_voxels, keys), len(near_voxels) - 1)
        ask = np.flatnonzero(near_voxels[pos] == keys)
        if ask.size:
            dq, idx = self._tree.query(flat[ask], distance_upper_bound=bound, workers=1)
            hit = np.isfinite(dq)
            rows = ask[hit]
            d[rows] = dq[hit]
            diff = flat[rows] - self.samples[idx[hit]]
            grad[rows] = diff / np.maximum(dq[hit], 1e-12)[:, None]
        return d.reshape(p.shape[:-1]), grad.reshape(p.shape)


def _clip_subdivide(tris: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_edge: float
                    ) -> np.ndarray:
    """Triangles ``(t, 3, 3)`` split in four until no edge exceeds ``max_edge``.

    Pieces whose bounding box misses the box ``[lo, hi]`` are dropped on the way.
    """
    out = []
    while len(tris):
        tris = tris[np.all(tris.max(1) >= lo, 1) & np.all(tris.min(1) <= hi, 1)]
        edges = np.linalg.norm(tris - np.roll(tris, 1, axis=1), axis=-1).max(1)
        small = edges <= max_edge
        out.append(tris[small])
        a, b, c = (tris[~small][:, i] for i in range(3))
        ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
        tris = np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc),
                                                         (ca, bc, c), (ab, bc, ca))])
    return np.concatenate(out) if out else np.zeros((0, 3, 3))


def _in_box(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Whether points ``(m, 3)`` lie in the box ``[lo, hi]``, ``(m,)`` bool.

    Compared coordinate by coordinate: on the grid's few hundred thousand samples this is
    three times faster than reducing an ``(m, 3)`` comparison along its short axis.
    """
    inside = (points[:, 0] >= lo[0]) & (points[:, 0] <= hi[0])
    for k in (1, 2):
        inside &= (points[:, k] >= lo[k]) & (points[:, k] <= hi[k])
    return inside


def surface_samples(env: Environment, spacing: float, lo: np.ndarray,
                    hi: np.ndarray, max_edge: float = 0.2) -> np.ndarray:
    """Points covering the triangles inside a box, at most ``spacing`` apart, ``(m, 3)``.

    Large triangles (a floor) are first split into pieces of at most ``max_edge`` and
    the pieces outside the box dropped; each piece is then covered by the lattice
    ``t0 + (i e1 + j e2) / k``, ``i + j <= k``, ``t0`` the corner facing the longest edge
    and ``k`` the smallest that keeps the steps along ``e1`` and ``e2`` within
    ``spacing / sqrt(2)``.
    """
    tris = _clip_subdivide(env.corners, np.asarray(lo, float), np.asarray(hi, float),
                           max_edge)
    if len(tris) == 0:
        return np.zeros((0, 3))
    # Start each lattice at the corner facing the longest edge: its two shorter edges
    # then set the lattice step.
    opposite = np.linalg.norm(np.roll(tris, 1, axis=1) - np.roll(tris, 2, axis=1),
                              axis=-1).argmax(1)
    tris = tris[np.arange(len(tris))[:, None], (opposite[:, None] + np.arange(3)) % 3]
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    longest = np.maximum(np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1))
    # Steps of spacing / sqrt(2): no surface point is more than spacing / 2 from a sample.
    ks = np.maximum(np.ceil(np.sqrt(2.0) * longest / spacing).astype(int), 1)
    out = []
    for k in np.unique(ks):
        sel = ks == k
        a, b = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        m = a + b <= k
        w = np.stack([a[m], b[m]], 1) / k  # (L, 2)
        pts = (tris[sel, 0, None] + w[None, :, :1] * e1[sel, None] +
               w[None, :, 1:] * e2[sel, None]).reshape(-1, 3)
        out.append(pts[_in_box(pts, lo - spacing, hi + spacing)])
    return np.concatenate(out)


def distance_grid(env: Environment, center: np.ndarray, half_size: float,
                  spacing: float = 0.02, max_distance: float = 0.2) -> DistanceGrid:
    """Distance to the environment's surfaces inside a cube around ``center``.

    Args:
        env: The environment.
        center: Cube centre, shape ``(3,)``.
        half_size: Half the cube's edge, world units.
        spacing: Surface sample spacing, world units.
        max_distance: Distances are clamped to this.

    Returns:
        The distance function.
    """
    lo = np.asarray(center, float) - half_size
    hi = np.asarray(center, float) + half_size
    samples = surface_samples(env, spacing, lo, hi)
    samples = samples[_in_box(samples, lo, hi)]
    cells = np.floor(samples / (0.5 * spacing))
    # One integer per half-spacing cell: packed indices (exact) while they fit, else hashed.
    fits = len(cells) == 0 or float(np.abs(cells).max()) < (1 << 20) - 1
    key = _voxel_keys(cells) if fits else row_hash(cells.astype(np.int64))
    _, first = np.unique(key, return_index=True)
    return DistanceGrid(samples[np.sort(first)], spacing, max_distance)


def _region(env: Environment, tri: int, height_tol: float = 0.03,
            max_radius: float = 1.5) -> np.ndarray:
    """Connected up-facing triangles at the height of ``tri`` (region growing), ``(k,)``."""
    up = env.up
    n = env.normals
    c = env.corners
    h = c.mean(1) @ up
    flat = (np.abs(n @ up) > np.cos(UP_ANGLE)) & (np.abs(h - h[tri]) < height_tol)
    flat &= np.linalg.norm(c.mean(1) - c[tri].mean(0), axis=1) < max_radius
    cand = np.flatnonzero(flat)
    # Triangles sharing a vertex position are neighbours.
    key = np.round(env.vertices[env.triangles[cand]].reshape(-1, 3) / 1e-5).astype(np.int64)
    _, vid = np.unique(key, axis=0, return_inverse=True)
    vid = vid.reshape(-1, 3)
    rows = np.repeat(np.arange(len(cand)), 3)
    m = coo_matrix((np.ones(rows.size), (rows, vid.ravel())))
    adj = (m @ m.T).tocoo()
    _, lab = connected_components(adj, directed=False)
    return cand[lab == lab[np.flatnonzero(cand == tri)[0]]]


def centerness(env: Environment, region: np.ndarray, spacing: float = 0.02
               ) -> tuple[np.ndarray, np.ndarray]:
    """Sample points of a flat region and their centerness (Eq. 3).

    The centerness of a point is its distance to the region's boundary divided by the
    largest such distance, 1 at the most central point and 0 on the boundary.

    Returns:
        ``(points (m, 3), centerness (m,))``.
    """
    up = env.up
    tris = env.triangles[region]
    corners = env.vertices[tris]
    lo, hi = corners.reshape(-1, 3).min(0), corners.reshape(-1, 3).max(0)
    # Boundary edges: used by one region triangle only.
    key = np.round(env.vertices / 1e-5).astype(np.int64)
    _, vid = np.unique(key, axis=0, return_inverse=True)
    e = np.sort(vid[tris][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges_xyz = corners[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2, 3)
    _, inv, cnt = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    border = edges_xyz[cnt[inv.ravel()] == 1]
    axes = [np.arange(lo[k], hi[k] + spacing, spacing) if hi[k] - lo[k] > 1e-6
            else np.array([lo[k]]) for k in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    # Keep points above a region triangle (barycentric test in the ground plane).
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    basis = np.linalg.svd(np.eye(3) - np.outer(up, up))[0][:, :2]
    P2, A, B, C = pts @ basis, a @ basis, b @ basis, c @ basis
    v0, v1 = B - A, C - A
    den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    rel = P2[:, None] - A[None]
    s = (rel[..., 0] * v1[:, 1] - rel[..., 1] * v1[:, 0]) / np.where(den == 0, 1, den)
    t = (v0[:, 0] * rel[..., 1] - v0[:, 1] * rel[..., 0]) / np.where(den == 0, 1, den)
    inside = (s >= -1e-9) & (t >= -1e-9) & (s + t <= 1 + 1e-9)
    keep = inside.any(1)
    tri_of = np.argmax(inside, 1)[keep]
    pts = pts[keep]
    # Lift onto the triangles' plane.
    nrm = env.normals[region][tri_of]
    pts = pts - up * (np.einsum("ij,ij->i", pts - a[tri_of], nrm) / (nrm @ up))[:, None]
    if len(pts) == 0:
        return corners.mean(1), np.zeros(len(region))
    from .capsules import point_segment_distance
    d = point_segment_distance(pts[:, None], border[None, :, 0], border[None, :, 1]).min(1)
    return pts, d / max(d.max(), 1e-12)


@dataclass(frozen=True)
class Seat:
    """Where the character sits.

    Attributes:
        point: Chosen spot on the seat, shape ``(3,)``.
        hit: Where the eye ray met the seat, shape ``(3,)``.
        normal: Seat normal, shape ``(3,)``.
        object_index: Mesh of the seat.
        centerness: Eq. 3 at the chosen spot.
        region: Triangles of the seat region, shape ``(k,)``.
    """

    point: np.ndarray
    hit: np.ndarray
    normal: np.ndarray
    object_index: int
    centerness: float
    region: np.ndarray


def _surface_below(env: Environment, points: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The highest up-facing triangle below each point (a vertical ray cast down).

    Args:
        env: The environment.
        points: World points, shape ``(m, 3)``.

    Returns:
        ``(point index (k,), triangle (k,), height above it (k,))`` for the points that
        have an up-facing triangle (normal within 30 degrees of up or down) below them.
    """
    up = env.up
    flat = np.flatnonzero(np.abs(env.normals @ up) >= np.cos(UP_ANGLE))
    if flat.size == 0:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0)
    c = env.corners[flat]
    basis = np.linalg.svd(np.eye(3) - np.outer(up, up))[0][:, :2]
    a, b, cc = c[:, 0] @ basis, c[:, 1] @ basis, c[:, 2] @ basis  # (f, 2)
    v0, v1 = b - a, cc - a
    den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    ok = np.abs(den) > 1e-18
    den = np.where(ok, den, 1.0)
    rel = (points @ basis)[:, None] - a[None]  # (m, f, 2)
    s = (rel[..., 0] * v1[:, 1] - rel[..., 1] * v1[:, 0]) / den
    t = (v0[:, 0] * rel[..., 1] - v0[:, 1] * rel[..., 0]) / den
    inside = ok & (s >= 0) & (t >= 0) & (s + t <= 1)
    h = c @ up  # corner heights (f, 3)
    surf = (1 - s - t) * h[:, 0] + s * h[:, 1] + t * h[:, 2]
    above = (points @ up)[:, None] - surf
    cand = inside & (above > 1e-9)
    gap = np.where(cand, above, np.inf)
    j = np.argmin(gap, axis=1)
    k = np.flatnonzero(np.isfinite(gap[np.arange(len(points)), j]))
    return k, flat[j[k]], gap[k, j[k]]


def surfaces_under_ray(env: Environment, origin: np.ndarray, direction: np.ndarray,
                       gap: tuple[float, float], near: float, far: float,
                       step: float = 0.02) -> list[Hit]:
    """Up-facing surfaces the eye ray meets or passes just above, nearest first.

    The eye ray meets a seat (or table) itself when the joint is drawn over it; when the
    surface is hidden behind the drawn joint (hips at the back of a seat seen from the
    front, a hand at the far edge of a table), the point of the ray lying ``gap`` above an
    up-facing surface is used instead (its hit is the surface point below it).

    Args:
        env: The environment.
        origin: Ray origin, shape ``(3,)``.
        direction: Unit ray direction, shape ``(3,)``.
        gap: Allowed height ``(min, max)`` of the ray above the surface, world units.
        near: Start of the searched part of the ray.
        far: End of the searched part of the ray.
        step: Ray-marching step, world units.

    Returns:
        Hits sorted by distance along the ray.
    """
    up = env.up
    out = []
    for hit in env.raycast(origin, direction):
        if near <= hit.distance <= far and hit.normal @ up >= np.cos(UP_ANGLE):
            out.append((hit.distance, hit))
    ts = np.arange(near, min(far, 50.0), step)
    if ts.size and len(env.triangles):
        pts = origin + ts[:, None] * direction
        k, tri, height = _surface_below(env, pts)
        ok = (gap[0] <= height) & (height <= gap[1])
        for i, t, h in zip(k[ok], tri[ok], height[ok], strict=True):
            below = pts[i] - up * h
            out.append((float(ts[i]), Hit(float(ts[i]), below, up.copy(), int(t),
                                   int(env.object_ids[t]))))
    out.sort(key=lambda item: item[0])
    return [h for _, h in out]


def find_seat(env: Environment, origin: np.ndarray, direction: np.ndarray,
              seated_hip_height: float, hip_radius: float,
              grid: DistanceGrid | None = None, seat_range=SEAT_RANGE,
              sigma: float = 0.15, near: float = 0.0, far: float = 50.0) -> Seat | None:
    """Sit location along an eye ray (Section 4.1.2).

    Args:
        env: The environment.
        origin: Eye ray origin, shape ``(3,)``.
        direction: Eye ray direction, shape ``(3,)``.
        seated_hip_height: The character's knee height (hip height when seated), world
            units; seats must be ``seat_range`` times this above the floor.
        hip_radius: Clearance the hips need above the seat and around them.
        grid: Distance grid used to reject spots where the hips would collide.
        seat_range: Allowed seat heights in units of ``seated_hip_height``.
        sigma: Distance scale (world units) trading closeness to the hit for centerness.
        near: Start of the searched part of the ray, world units from ``origin``.
        far: End of the searched part of the ray.

    Returns:
        The seat, or None when the ray meets no suitable surface.
    """
    up = env.up
    o, d = np.asarray(origin, float), normalize(np.asarray(direction, float))
    lo, hi = seat_range
    for hit in surfaces_under_ray(env, o, d, (0.5 * hip_radius, 1.5 * hip_radius), near, far):
        height = env.height_above_floor(hit.point + up * 1e-3)
        if not lo * seated_hip_height <= height <= hi * seated_hip_height:
            continue
        region = _region(env, hit.triangle)
        pts, cent = centerness(env, region)
        score = cent * np.exp(-np.sum((pts - hit.point) ** 2, 1) / (2 * sigma**2))
        order = np.argsort(-score)
        best = order[0]
        if grid is not None:
            hips = pts[order] + up * (hip_radius * 1.05)
            free = grid.sample(hips)[0] >= hip_radius * 0.95
            if np.any(free):
                best = order[np.argmax(free)]
        return Seat(pts[best], hit.point, hit.normal, hit.object_index, float(cent[best]),
                    region)
    return None
