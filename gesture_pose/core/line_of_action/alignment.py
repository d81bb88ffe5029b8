"""Joint alignment (Mahmudi et al. 2016, Section 6, Eq. 4).

Joint ``x_{i+1}`` must stay at distance ``l`` (the bone's length) from the already placed
joint ``x_i``: a sphere. Keeping its view depth puts it on a view-parallel plane; the two
meet in a circle (Eq. 4). The ray through the joint's feature point meets that plane in one
point, and the joint goes to the circle point nearest it (the line-circle intersection when
the ray passes through the circle, the closest point otherwise). Plane posing moves the
plane to ``x_i`` so the bone ends orthogonal to the view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import Camera


def _xyz(p: np.ndarray | list[float] | tuple[float, ...]) -> tuple[float, float, float]:
    """A world point as three floats (numpy arrays are converted, sequences kept)."""
    x, y, z = p.tolist() if isinstance(p, np.ndarray) else p
    return x, y, z


@dataclass(frozen=True)
class ViewOps:
    """A camera with float fast paths for the single points of the per-joint loop.

    Array operations are the camera's own; one-point projections, depths and rays run on
    Python floats from matrices inverted once, since numpy's per-call overhead would
    dominate them.

    Attributes:
        camera: The view.
        forward: Unit view direction, shape ``(3,)``.
    """

    camera: Camera
    forward: np.ndarray

    def __post_init__(self) -> None:
        """Keep Python-float copies of the matrices."""
        full = self.camera.full_matrix
        object.__setattr__(self, "_m", [full[i].tolist() for i in (0, 1, 3)])
        object.__setattr__(self, "_inv", self.camera.inverse_full_matrix.tolist())
        object.__setattr__(self, "_fwd", self.forward.tolist())
        object.__setattr__(self, "_dr", self.camera.view_matrix[2].tolist())
        object.__setattr__(self, "_size", [float(self.camera.width), float(self.camera.height)])

    @classmethod
    def from_camera(cls, camera: Camera) -> ViewOps:
        """Precompute the float matrices of ``camera``."""
        return cls(camera, camera.forward)

    def project(self, p: np.ndarray) -> np.ndarray:
        """Pixels of world points, ``(n, 3) -> (n, 2)`` (see :meth:`Camera.project`)."""
        return self.camera.project(p)

    def depth(self, p: np.ndarray) -> np.ndarray:
        """View depth of world points, ``(n, 3) -> (n,)`` (see :meth:`Camera.depth`)."""
        return self.camera.depth(p)

    def project_point(self, x: float, y: float, z: float) -> tuple[float, float]:
        """Pixel of one world point given as floats."""
        (a0, a1, a2, a3), (b0, b1, b2, b3), (c0, c1, c2, c3) = self._m
        w = c0 * x + c1 * y + c2 * z + c3
        width, height = self._size
        return ((a0 * x + a1 * y + a2 * z + a3) / w + 1.0) * 0.5 * width, \
            ((b0 * x + b1 * y + b2 * z + b3) / w + 1.0) * 0.5 * height

    def depth_point(self, x: float, y: float, z: float) -> float:
        """View depth of one world point given as floats."""
        r0, r1, r2, r3 = self._dr
        return -(r0 * x + r1 * y + r2 * z + r3)

    def ray_point(self, px: float, py: float) -> tuple[tuple[float, float, float],
                                                       tuple[float, float, float]]:
        """World ray (origin on the near plane, unit direction) through one pixel."""
        width, height = self._size
        u, v = px / width * 2.0 - 1.0, py / height * 2.0 - 1.0
        near, far = [], []
        for a, b, c, d in self._inv:
            base = a * u + b * v + d
            near.append(base - c)
            far.append(base)
        o = (near[0] / near[3], near[1] / near[3], near[2] / near[3])
        f = (far[0] / far[3], far[1] / far[3], far[2] / far[3])
        dx, dy, dz = f[0] - o[0], f[1] - o[1], f[2] - o[2]
        n = math.sqrt(dx * dx + dy * dy + dz * dz)
        return o, (dx / n, dy / n, dz / n)


@dataclass(frozen=True)
class Placement:
    """Where a joint goes.

    Attributes:
        position: New world position of ``x_{i+1}``, shape ``(3,)``.
        circle_radius: Radius of the sphere-plane circle, world units.
        skipped: True when the circle degenerates (bone along the view axis).
    """

    position: np.ndarray
    circle_radius: float
    skipped: bool


def _circle(view: ViewOps, parent: tuple[float, float, float], length: float,
            plane_depth: float) -> tuple[tuple[float, float, float], float]:
    """:func:`circle_of` on floats."""
    h = plane_depth - view.depth_point(*parent)
    h = max(-length, min(length, h))
    fx, fy, fz = view._fwd
    centre = (parent[0] + h * fx, parent[1] + h * fy, parent[2] + h * fz)
    return centre, math.sqrt(max(length * length - h * h, 0.0))


def circle_of(
    view: ViewOps, parent: np.ndarray, length: float, plane_depth: float
) -> tuple[np.ndarray, float]:
    """Eq. 4: the circle where the sphere ``|x - parent| = length`` meets a depth plane.

    Args:
        view: Camera operations.
        parent: Sphere centre ``x_i``, shape ``(3,)``.
        length: Sphere radius (segment length), world units.
        plane_depth: View depth of the plane.

    Returns:
        ``(centre, radius)``; the radius is 0 when the plane misses the sphere, and the
        centre is then the sphere point nearest the plane.
    """
    centre, radius = _circle(view, _xyz(parent), length,
                             plane_depth)
    return np.array(centre), radius


@dataclass(frozen=True)
class StrokeRays:
    """The rays through a sampled stroke, reduced to what the crossing test needs.

    The point at view depth ``D`` on the ray through sample ``k`` is ``q_k(D) = A_k + D B_k``,
    so ``|q_k(D) - c|^2`` is linear in the per-ray terms ``(|A|^2, A.B, |B|^2, A, B)``.

    Attributes:
        params: Arc lengths of the samples, shape ``(m,)``.
        coeffs: The per-ray terms, shape ``(m, 9)``.
    """

    params: np.ndarray
    coeffs: np.ndarray

    @classmethod
    def through(cls, view: ViewOps, params: np.ndarray, pixels: np.ndarray) -> StrokeRays:
        """Rays through stroke samples ``pixels`` (shape ``(m, 2)``) at arc lengths ``params``."""
        origins, directions = view.camera.rays(pixels)
        depth, rate = view.depth(origins), directions @ view.forward
        b = directions / rate[:, None]
        a = origins - depth[:, None] * b
        coeffs = np.column_stack([np.einsum("ij,ij->i", a, a), np.einsum("ij,ij->i", a, b),
                                  np.einsum("ij,ij->i", b, b), a, b])
        return cls(params, coeffs)


def stroke_circle_crossing(
    view: ViewOps, rays: StrokeRays, parent: np.ndarray, length: float, plane_depth: float,
    s_from: float, s_near: float,
) -> float | None:
    """Arc length where the stroke's rays cross the joint's circle, nearest ``s_near``.

    The rays through the stroke samples meet the circle's plane along a curve; a crossing
    of that curve with the circle (Eq. 4) is a placement whose projection lies exactly on
    the stroke with the bone rigid and the depth kept.

    Args:
        view: Camera operations.
        rays: The rays through the stroke's samples.
        parent: Placed joint ``x_i``, shape ``(3,)``.
        length: Segment length.
        plane_depth: View depth of the joint's plane.
        s_from: Only samples at or after this arc length are searched.
        s_near: Preferred arc length (the feature point); the search ends as far beyond
            it as ``s_from`` lies before it.

    Returns:
        The arc length of the crossing (linearly interpolated), or None if the stroke
        does not cross the circle after ``s_from``.
    """
    centre, radius = _circle(view, _xyz(parent), length,
                             plane_depth)
    params = rays.params
    step = float(params[1] - params[0])
    i0 = max(math.ceil(s_from / step - 1e-9), 0)
    i1 = min(math.floor((2.0 * s_near - s_from + 4.0) / step) + 2, len(params))
    if i1 - i0 < 2:
        return None
    # |q(D) - c|^2 - r^2 for every ray at once, as one product with the precomputed terms.
    d = plane_depth
    cx, cy, cz = centre
    w = np.array([1.0, 2.0 * d, d * d, -2.0 * cx, -2.0 * cy, -2.0 * cz, -2.0 * d * cx,
                  -2.0 * d * cy, -2.0 * d * cz])
    f = np.einsum("ij,j->i", rays.coeffs[i0:i1], w) + (cx * cx + cy * cy + cz * cz
                                                       - radius * radius)
    inside = f < 0.0
    cross = np.flatnonzero(inside[:-1] != inside[1:])
    if cross.size == 0:
        return None
    best, best_gap = None, math.inf
    for k in cross.tolist():  # a stroke crosses a circle a handful of times at most
        f0, f1 = float(f[k]), float(f[k + 1])
        root = float(params[i0 + k]) + step * f0 / (f0 - f1)
        if abs(root - s_near) < best_gap:
            best, best_gap = root, abs(root - s_near)
    return best


def place_joint(
    view: ViewOps, parent: np.ndarray, current: np.ndarray, length: float, target_px: np.ndarray,
    plane_depth: float, min_radius_ratio: float,
) -> Placement:
    """Align one joint to its target pixel (Eq. 4 and the line-circle intersection).

    Args:
        view: Camera operations.
        parent: Placed joint ``x_i``, shape ``(3,)``.
        current: Current position of ``x_{i+1}``, shape ``(3,)``.
        length: Segment length ``|x_{i+1} - x_i|``, world units.
        target_px: Feature point in pixels, shape ``(2,)``.
        plane_depth: View depth the joint should keep (see :func:`joint_plane_depth`).
        min_radius_ratio: Circles smaller than this fraction of ``length`` mean the bone
            lies along the view axis: the joint is left where it is.

    Returns:
        The placement.
    """
    position, radius = place_point(view, _xyz(parent), length, _xyz(current),
                                   *np.asarray(target_px, float).tolist(), plane_depth,
                                   min_radius_ratio)
    if position is None:
        return Placement(np.array(current, float), radius, True)
    return Placement(np.array(position), radius, False)


def place_point(
    view: ViewOps, parent: tuple[float, float, float], length: float,
    current: tuple[float, float, float], tx: float, ty: float, plane_depth: float,
    min_radius_ratio: float,
) -> tuple[tuple[float, float, float] | None, float]:
    """:func:`place_joint` on floats: ``(position or None when skipped, circle radius)``."""
    (cx, cy, cz), radius = _circle(view, parent, length, plane_depth)
    if radius < min_radius_ratio * length:
        return None, radius
    (ox, oy, oz), (dx, dy, dz) = view.ray_point(tx, ty)
    fx, fy, fz = view._fwd
    t = (plane_depth - view.depth_point(ox, oy, oz)) / (dx * fx + dy * fy + dz * fz)
    rx, ry, rz = ox + t * dx - cx, oy + t * dy - cy, oz + t * dz - cz
    norm = math.sqrt(rx * rx + ry * ry + rz * rz)
    if norm < 1e-12 * max(length, 1.0):
        return current, radius
    k = radius / norm
    return (cx + rx * k, cy + ry * k, cz + rz * k), radius


def joint_plane_depth(
    view: ViewOps, parent: np.ndarray, current: np.ndarray, length: float,
    original_depth: float, plane_posing: bool, min_radius_ratio: float,
) -> float:
    """The view depth a joint is placed at.

    Default posing keeps the joint's depth from before the stroke. When the parent has
    moved so far in depth that this plane leaves too small a circle, the joint keeps the
    depth it has now instead (always reachable: the joint lies on the sphere). Plane
    posing uses the parent's depth.

    Args:
        view: Camera operations.
        parent: Placed joint ``x_i``, shape ``(3,)``.
        current: Current ``x_{i+1}``, shape ``(3,)``.
        length: Segment length.
        original_depth: Depth of ``x_{i+1}`` before the stroke.
        plane_posing: Use the plane through the parent.
        min_radius_ratio: Smallest acceptable circle radius as a fraction of ``length``.

    Returns:
        The plane's view depth.
    """
    if plane_posing:
        return view.depth_point(*_xyz(parent))
    _, radius = _circle(view, _xyz(parent), length,
                        float(original_depth))
    if radius >= min_radius_ratio * length:
        return float(original_depth)
    return view.depth_point(*_xyz(current))
