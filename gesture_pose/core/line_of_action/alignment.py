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


@dataclass(frozen=True)
class ViewOps:
    """Fast single-point camera operations with the matrices inverted once.

    Attributes:
        full: World to clip matrix, shape ``(4, 4)``.
        inverse: Its inverse, shape ``(4, 4)``.
        size: ``(width, height)`` in pixels, shape ``(2,)``.
        forward: Unit view direction, shape ``(3,)``.
        depth_row: Row of the view matrix giving ``-depth``, shape ``(4,)``.
    """

    full: np.ndarray
    inverse: np.ndarray
    size: np.ndarray
    forward: np.ndarray
    depth_row: np.ndarray

    @classmethod
    def from_camera(cls, camera: Camera) -> ViewOps:
        """Precompute the matrices of ``camera``."""
        full = camera.full_matrix
        return cls(full, np.linalg.inv(full), np.array([camera.width, camera.height], float),
                   camera.forward, camera.view_matrix[2].copy())

    def project(self, p: np.ndarray) -> np.ndarray:
        """Pixels of world points, ``(..., 3) -> (..., 2)``."""
        clip = p @ self.full[:, :3].T + self.full[:, 3]
        return (clip[..., :2] / clip[..., 3:4] + 1.0) * 0.5 * self.size

    def depth(self, p: np.ndarray) -> np.ndarray:
        """View depth of world points, ``(..., 3) -> (...)``."""
        return -(p @ self.depth_row[:3] + self.depth_row[3])

    def rays(self, px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rays through many pixels: origins and unit directions, ``(m, 3)`` each."""
        ndc = np.asarray(px, float) / self.size * 2.0 - 1.0
        ones = np.ones((len(ndc), 1))
        near = np.hstack([ndc, -ones, ones]) @ self.inverse.T
        far = np.hstack([ndc, 0.0 * ones, ones]) @ self.inverse.T
        near, far = near[:, :3] / near[:, 3:], far[:, :3] / far[:, 3:]
        d = far - near
        return near, d / np.linalg.norm(d, axis=1, keepdims=True)

    def ray(self, px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World ray ``(origin, unit direction)`` through pixel ``px`` (shape ``(2,)``)."""
        ndc = px / self.size * 2.0 - 1.0
        near = self.inverse @ np.array([ndc[0], ndc[1], -1.0, 1.0])
        far = self.inverse @ np.array([ndc[0], ndc[1], 0.0, 1.0])
        near, far = near[:3] / near[3], far[:3] / far[3]
        d = far - near
        return near, d / math.sqrt(float(d @ d))


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
    r = view.depth_row
    h = plane_depth + float(r[0] * parent[0] + r[1] * parent[1] + r[2] * parent[2] + r[3])
    h = max(-length, min(length, h))
    centre = parent + h * view.forward
    return centre, math.sqrt(max(length * length - h * h, 0.0))


@dataclass(frozen=True)
class StrokeRays:
    """The rays through a sampled stroke, with what every crossing test needs.

    Attributes:
        params: Arc lengths of the samples, shape ``(m,)``.
        origins: Ray origins, shape ``(m, 3)``.
        directions: Unit ray directions, shape ``(m, 3)``.
        origin_depth: View depth of each origin, shape ``(m,)``.
        rate: Depth gained per unit along each ray, shape ``(m,)``.
    """

    params: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    origin_depth: np.ndarray
    rate: np.ndarray

    @classmethod
    def through(cls, view: ViewOps, params: np.ndarray, pixels: np.ndarray) -> StrokeRays:
        """Rays through stroke samples ``pixels`` (shape ``(m, 2)``) at arc lengths ``params``."""
        origins, directions = view.rays(pixels)
        return cls(params, origins, directions, view.depth(origins), directions @ view.forward)


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
    centre, radius = circle_of(view, parent, length, plane_depth)
    params = rays.params
    i0 = int(np.searchsorted(params, s_from))
    i1 = int(np.searchsorted(params, s_near + (s_near - s_from) + 4.0)) + 1
    if i1 - i0 < 2:
        return None
    t = (plane_depth - rays.origin_depth[i0:i1]) / rays.rate[i0:i1]
    rel = rays.origins[i0:i1] - centre + t[:, None] * rays.directions[i0:i1]
    f = np.sqrt(np.einsum("ij,ij->i", rel, rel)) - radius
    cross = np.flatnonzero(np.sign(f[:-1]) * np.sign(f[1:]) <= 0)
    if cross.size == 0:
        return None
    s0, s1 = params[i0:][cross], params[i0:][cross + 1]
    f0, f1 = f[cross], f[cross + 1]
    w = np.where(np.abs(f0 - f1) > 1e-15, f0 / np.where(f0 == f1, 1.0, f0 - f1), 0.0)
    roots = s0 + w * (s1 - s0)
    return float(roots[int(np.argmin(np.abs(roots - s_near)))])


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
    centre, radius = circle_of(view, parent, length, plane_depth)
    if radius < min_radius_ratio * length:
        return Placement(current.copy(), radius, True)
    origin, direction = view.ray(np.asarray(target_px, float))
    rate = float(direction @ view.forward)
    t = (plane_depth - float(view.depth(origin))) / rate
    hit = origin + t * direction
    radial = hit - centre
    norm = math.sqrt(float(radial @ radial))
    if norm < 1e-12 * max(length, 1.0):
        return Placement(current.copy(), radius, False)
    return Placement(centre + radial * (radius / norm), radius, False)


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
        return float(view.depth(parent))
    _, radius = circle_of(view, parent, length, original_depth)
    if radius >= min_radius_ratio * length:
        return float(original_depth)
    return float(view.depth(current))
