"""Visible occluding contours of a posed mesh: test drawings for the gesture mode.

Gesture3D validated itself on projected contours of posed models; so do the tests and the
benchmark here. The tracer is pure numpy:

1. *Occluding edges*: mesh edges where a front-facing and a back-facing triangle meet
   (the silhouette and the interior contours where one part folds in front of another),
   plus open boundary edges. Imported meshes (glTF) split their vertices along UV and
   normal seams; pairs of boundary edges at the same place are such a seam and count as
   one edge between their two triangles, or every seam would be traced.
2. *Visibility*: a z-buffer of all triangles, rasterized by splatting a barycentric lattice
   finer than half a pixel; an edge point is visible when no surface lies more than a small
   depth tolerance in front of it.
3. *Chaining*: visible edges are linked at shared vertices into polylines, lightly smoothed
   in the image and short pieces are dropped.

:func:`perturb` imitates a human drawing: smooth normal noise, overshoot at the ends, gaps
and a global scale error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..exceptions import InputError


@dataclass(frozen=True)
class TraceParams:
    """Tracer parameters.

    Attributes:
        depth_tolerance: Depth slack of the visibility test, fraction of the mesh's
            bounding-box diagonal.
        min_length: Shortest kept polyline, fraction of the traced drawing's diagonal.
        smooth_iterations: Laplacian smoothing passes on each polyline (ends fixed).
        splat_step: Lattice step of the z-buffer splatting, pixels.
        weld: Boundary edges whose ends are closer than this fraction of the mesh's
            bounding-box diagonal to another's are a seam (0: every boundary is traced).
    """

    depth_tolerance: float = 0.02
    min_length: float = 0.02
    smooth_iterations: int = 2
    splat_step: float = 0.5
    weld: float = 1e-6


@dataclass(frozen=True)
class Perturbation:
    """How a traced drawing is roughened (all lengths are fractions of its diagonal).

    Attributes:
        noise: Amplitude of the smooth normal noise.
        wavelength: Wavelength of the noise.
        overshoot: Extension of each stroke beyond its ends.
        gap_probability: Chance that a stroke is cut by a gap.
        gap: Length of a gap.
        scale_error: Relative error of the drawing's overall scale.
        seed: Random seed.
    """

    noise: float = 0.004
    wavelength: float = 0.15
    overshoot: float = 0.01
    gap_probability: float = 0.3
    gap: float = 0.015
    scale_error: float = 0.04
    seed: int = 0


@dataclass(frozen=True)
class TracedContours:
    """Traced contour polylines.

    Attributes:
        pixels: Polylines in pixels, each ``(k, 2)``.
        depths: View depth of every point, each ``(k,)``, world units.
    """

    pixels: tuple[np.ndarray, ...]
    depths: tuple[np.ndarray, ...]

    def world(self, camera: Camera) -> tuple[np.ndarray, ...]:
        """The polylines in world space (each point at its depth), each ``(k, 3)``."""
        return tuple(camera.unproject_at_depth(p, d) for p, d in zip(self.pixels, self.depths,
                                                                      strict=True))


def _place_ids(vertices: np.ndarray, tolerance: float) -> np.ndarray:
    """One id per place: vertices within ``tolerance`` (on a grid) share it, ``(V,)``."""
    keys = np.round(np.asarray(vertices, float) / max(tolerance, 1e-300)).astype(np.int64)
    return np.unique(keys, axis=0, return_inverse=True)[1].ravel()


def occluding_edges(vertices: np.ndarray, triangles: np.ndarray, camera: Camera,
                    weld: float = 0.0) -> np.ndarray:
    """Edges between front- and back-facing triangles, and boundary edges, ``(e, 2)``.

    Args:
        vertices: Vertices, ``(V, 3)``.
        triangles: Triangles, ``(T, 3)`` int.
        camera: The view.
        weld: Boundary edges whose ends lie within this distance (world units) of another
            boundary edge's ends are a seam (imported meshes split their vertices along UV
            and normal seams): the pair is one edge between its two triangles, an occluding
            edge only when one faces the camera. 0 keeps every boundary edge.

    Returns:
        Vertex index pairs of the occluding edges.
    """
    v = vertices[triangles]
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    view = camera.view_directions(v.mean(axis=1))
    front = np.einsum("td,td->t", normals, view) < 0
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    faces = np.tile(np.arange(len(triangles)), 3)
    edges = np.sort(edges, axis=1)
    uniq, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    n_front = np.bincount(inverse, weights=front[faces].astype(float), minlength=len(uniq))
    contour = ((counts == 2) & (n_front == 1)) | (counts == 1)
    boundary = np.flatnonzero(counts == 1)
    if weld <= 0 or boundary.size == 0:
        return uniq[contour]
    place = _place_ids(vertices, weld)
    ends = place[uniq[boundary]]
    _, group, size = np.unique(np.sort(ends, axis=1), axis=0, return_inverse=True,
                               return_counts=True)
    group = group.ravel()
    seam = size[group] == 2
    fronts = np.bincount(group, weights=n_front[boundary], minlength=len(size))
    first = np.zeros(len(boundary), bool)
    first[np.unique(group, return_index=True)[1]] = True
    contour[boundary[seam]] = (fronts[group[seam]] == 1) & first[seam]
    # Seam vertices take one index per place so that contours chain across seams.
    rep = np.arange(len(vertices))
    seam_v = np.unique(uniq[boundary[seam]])
    _, pick = np.unique(place[seam_v], return_index=True)
    lookup = dict(zip(place[seam_v[pick]].tolist(), seam_v[pick].tolist(), strict=True))
    rep[seam_v] = [lookup[k] for k in place[seam_v].tolist()]
    return rep[uniq[contour]]


def zbuffer(pixels: np.ndarray, depth: np.ndarray, triangles: np.ndarray, width: int,
            height: int, step: float = 0.5) -> np.ndarray:
    """Nearest depth per pixel by splatting a barycentric lattice of every triangle.

    Args:
        pixels: Projected vertices, ``(V, 2)``.
        depth: Vertex view depths, ``(V,)``.
        triangles: Triangles, ``(T, 3)`` int.
        width: Image width, pixels.
        height: Image height, pixels.
        step: Lattice step, pixels.

    Returns:
        Depth image, ``(height, width)``, ``inf`` where nothing is drawn.
    """
    zbuf = np.full((height, width), np.inf)
    p = pixels[triangles]
    ok = np.all(np.isfinite(p), axis=(1, 2))
    p, z = p[ok], depth[triangles[ok]]
    span = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).max(axis=1)
    subdiv = np.clip(np.ceil(span / step), 1, 400).astype(int)
    for k in np.unique(subdiv):
        sel = subdiv == k
        i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        keep = i + j <= k
        bary = np.stack([i[keep], j[keep], k - i[keep] - j[keep]], axis=1) / k
        pts = np.einsum("lc,tcd->tld", bary, p[sel]).reshape(-1, 2)
        dep = np.einsum("lc,tc->tl", bary, z[sel]).ravel()
        ix, iy = np.floor(pts[:, 0]).astype(int), np.floor(pts[:, 1]).astype(int)
        inside = (ix >= 0) & (ix < width) & (iy >= 0) & (iy < height)
        np.minimum.at(zbuf, (iy[inside], ix[inside]), dep[inside])
    return zbuf


def _chains(edges: np.ndarray) -> list[list[int]]:
    """Link edges sharing vertices into vertex chains (open or closed)."""
    adjacency: dict[int, list[int]] = {}
    for a, b in edges:
        adjacency.setdefault(int(a), []).append(int(b))
        adjacency.setdefault(int(b), []).append(int(a))
    used: set[tuple[int, int]] = set()
    chains = []
    starts = [v for v, nb in adjacency.items() if len(nb) != 2] + list(adjacency)
    for s in starts:
        for nxt in adjacency[s]:
            if (min(s, nxt), max(s, nxt)) in used:
                continue
            chain, prev, cur = [s], s, nxt
            used.add((min(s, nxt), max(s, nxt)))
            while True:
                chain.append(cur)
                if len(adjacency[cur]) != 2:
                    break
                a, b = adjacency[cur]
                step = b if a == prev else a
                key = (min(cur, step), max(cur, step))
                if key in used:
                    break
                used.add(key)
                prev, cur = cur, step
            chains.append(chain)
    return chains


def _smooth(points: np.ndarray, iterations: int) -> np.ndarray:
    """Laplacian smoothing with fixed ends, ``(k, d) -> (k, d)``."""
    out = points.copy()
    for _ in range(iterations):
        out[1:-1] = 0.25 * out[:-2] + 0.5 * out[1:-1] + 0.25 * out[2:]
    return out


def trace_contours(vertices: np.ndarray, triangles: np.ndarray, camera: Camera,
                   params: TraceParams | None = None) -> TracedContours:
    """Visible occluding contours of a mesh seen by ``camera``.

    Args:
        vertices: Posed (deformed) vertices in world space, ``(V, 3)``.
        triangles: Triangles, ``(T, 3)`` int.
        camera: The view.
        params: Tracer parameters.

    Returns:
        The visible contour polylines in pixels with their depths.

    Raises:
        InputError: No triangles, or nothing visible.
    """
    params = params or TraceParams()
    vertices = np.asarray(vertices, float)
    triangles = np.asarray(triangles, int)
    if triangles.ndim != 2 or triangles.shape[1] != 3 or len(triangles) == 0:
        raise InputError("The mesh has no triangles to trace.")
    px = camera.project(vertices)
    dep = camera.depth(vertices)
    zbuf = zbuffer(px, dep, triangles, camera.width, camera.height, params.splat_step)
    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    tol = params.depth_tolerance * diag
    edges = occluding_edges(vertices, triangles, camera, params.weld * diag)
    mid_px = 0.5 * (px[edges[:, 0]] + px[edges[:, 1]])
    mid_z = 0.5 * (dep[edges[:, 0]] + dep[edges[:, 1]])
    ix = np.clip(np.floor(mid_px[:, 0]).astype(int), 0, camera.width - 1)
    iy = np.clip(np.floor(mid_px[:, 1]).astype(int), 0, camera.height - 1)
    inside = np.all(np.isfinite(mid_px), axis=1) & (mid_px[:, 0] >= 0) & (mid_px[:, 1] >= 0)
    inside &= (mid_px[:, 0] < camera.width) & (mid_px[:, 1] < camera.height)
    visible = inside & (mid_z <= zbuf[iy, ix] + tol)
    chains = _chains(edges[visible])
    if not chains:
        raise InputError("No contour of the mesh is visible in this view: frame the character.")
    polys = [(_smooth(px[c], params.smooth_iterations), dep[c]) for c in chains]
    allpts = np.concatenate([p for p, _ in polys])
    size = float(np.linalg.norm(allpts.max(axis=0) - allpts.min(axis=0)))
    keep = [(p, d) for p, d in polys
            if np.linalg.norm(np.diff(p, axis=0), axis=1).sum() >= params.min_length * size]
    return TracedContours(tuple(p for p, _ in keep), tuple(d for _, d in keep))


def perturb(traced: TracedContours, params: Perturbation | None = None) -> TracedContours:
    """A hand-drawn-looking copy of traced contours (deterministic for a seed).

    Args:
        traced: Clean contours.
        params: Perturbation sizes.

    Returns:
        Perturbed contours (strokes cut by gaps become two strokes).
    """
    params = params or Perturbation()
    rng = np.random.default_rng(params.seed)
    allpts = np.concatenate(traced.pixels)
    centre = allpts.mean(axis=0)
    diag = float(np.linalg.norm(allpts.max(axis=0) - allpts.min(axis=0)))
    scale = 1.0 + params.scale_error * rng.choice([-1.0, 1.0])
    out_p, out_d = [], []
    for pts, dep in zip(traced.pixels, traced.depths, strict=True):
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        tan = np.gradient(pts, axis=0)
        tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-9)
        nrm = np.stack([-tan[:, 1], tan[:, 0]], axis=1)
        k = 2 * np.pi / (params.wavelength * diag)
        phase = rng.uniform(0, 2 * np.pi, 2)
        wobble = params.noise * diag * (0.7 * np.sin(k * s + phase[0])
                                        + 0.3 * np.sin(2.3 * k * s + phase[1]))
        p = pts + wobble[:, None] * nrm
        ext = params.overshoot * diag
        p = np.concatenate([p[:1] - ext * tan[:1], p, p[-1:] + ext * tan[-1:]])
        d = np.concatenate([dep[:1], dep, dep[-1:]])
        p = (p - centre) * scale + centre
        if rng.random() < params.gap_probability and s[-1] > 4 * params.gap * diag:
            cut = rng.uniform(0.25, 0.75) * s[-1]
            s_ext = np.concatenate([[-ext], s, [s[-1] + ext]])
            a = s_ext < cut - 0.5 * params.gap * diag
            b = s_ext > cut + 0.5 * params.gap * diag
            pieces = [(p[a], d[a]), (p[b], d[b])]
        else:
            pieces = [(p, d)]
        for pp, dd in pieces:
            if len(pp) >= 2:
                out_p.append(pp)
                out_d.append(dd)
    return TracedContours(tuple(out_p), tuple(out_d))
