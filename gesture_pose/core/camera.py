"""Pinhole and orthographic cameras: projection to pixels and rays back into the scene.

The matrices are Blender's: ``view_matrix`` maps world to view space (the camera looks
down its -z axis) and ``projection_matrix`` maps view space to clip space, as
``RegionView3D.window_matrix`` or ``Camera.calc_matrix_camera``. Pixels have their origin
at the bottom-left corner of the region, x to the right and y up.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .exceptions import InputError
from .rotations import normalize


@dataclass(frozen=True)
class Camera:
    """A view of the scene.

    Attributes:
        view_matrix: World to view transform, shape ``(4, 4)``.
        projection_matrix: View to clip transform, shape ``(4, 4)``.
        width: Region width in pixels.
        height: Region height in pixels.
        is_perspective: False for orthographic views.
    """

    view_matrix: np.ndarray
    projection_matrix: np.ndarray
    width: int
    height: int
    is_perspective: bool

    def __post_init__(self) -> None:
        """Check shapes and finiteness."""
        for attr in ("view_matrix", "projection_matrix"):
            m = np.asarray(getattr(self, attr), dtype=float)
            if m.shape != (4, 4) or not np.all(np.isfinite(m)):
                raise InputError(f"Camera.{attr} must be a finite 4x4 matrix.")
            object.__setattr__(self, attr, m)
        if self.width <= 0 or self.height <= 0:
            raise InputError("The view has no area (width or height is zero).")

    @classmethod
    def look_at(
        cls,
        eye: np.ndarray,
        target: np.ndarray,
        up: np.ndarray = (0.0, 0.0, 1.0),
        *,
        width: int = 800,
        height: int = 600,
        fov: float = np.radians(40.0),
        ortho_scale: float | None = None,
        clip: tuple[float, float] = (0.1, 100.0),
    ) -> Camera:
        """A camera at ``eye`` looking at ``target`` (Blender's conventions).

        Args:
            eye: Camera position, shape ``(3,)``.
            target: Point looked at, shape ``(3,)``.
            up: Approximate world up, shape ``(3,)``.
            width: Image width in pixels.
            height: Image height in pixels.
            fov: Horizontal field of view in radians (perspective).
            ortho_scale: Visible width in world units; orthographic when given.
            clip: Near and far clip distances.

        Returns:
            The camera.
        """
        eye, target = np.asarray(eye, float), np.asarray(target, float)
        back = normalize(eye - target)
        right = normalize(np.cross(np.asarray(up, float), back))
        if np.linalg.norm(right) < 0.5:
            raise InputError("The camera's up vector is parallel to its view direction.")
        cam_up = np.cross(back, right)
        view = np.eye(4)
        view[:3, :3] = np.stack([right, cam_up, back])
        view[:3, 3] = -view[:3, :3] @ eye
        n, f = clip
        aspect = width / height
        proj = np.zeros((4, 4))
        if ortho_scale is None:
            sx = 1.0 / np.tan(fov / 2.0)
            proj[0, 0], proj[1, 1] = sx, sx * aspect
            proj[2, 2], proj[2, 3] = (f + n) / (n - f), 2 * f * n / (n - f)
            proj[3, 2] = -1.0
        else:
            proj[0, 0], proj[1, 1] = 2.0 / ortho_scale, 2.0 * aspect / ortho_scale
            proj[2, 2], proj[2, 3] = -2.0 / (f - n), -(f + n) / (f - n)
            proj[3, 3] = 1.0
        return cls(view, proj, width, height, ortho_scale is None)

    # Cached (in the instance's __dict__, which a frozen dataclass still has): the
    # per-stroke solvers project and unproject many times with one camera.
    @cached_property
    def full_matrix(self) -> np.ndarray:
        """World to clip transform ``P V``, shape ``(4, 4)``."""
        return self.projection_matrix @ self.view_matrix

    @cached_property
    def inverse_full_matrix(self) -> np.ndarray:
        """Clip to world transform ``(P V)^-1``, shape ``(4, 4)``.

        Raises:
            InputError: The projection is singular.
        """
        try:
            return np.linalg.inv(self.full_matrix)
        except np.linalg.LinAlgError:
            raise InputError("The view's projection cannot be inverted.") from None

    @property
    def location(self) -> np.ndarray:
        """Eye position in world space, shape ``(3,)`` (meaningful for perspective)."""
        return np.linalg.inv(self.view_matrix)[:3, 3]

    @property
    def forward(self) -> np.ndarray:
        """Unit world direction the camera looks along, shape ``(3,)``."""
        return -normalize(self.view_matrix[2, :3])

    def _clip(self, points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points, dtype=float)
        if pts.shape[-1] != 3:
            raise InputError(f"Expected points of shape (n, 3), got {pts.shape}.")
        homo = np.concatenate([pts, np.ones(pts.shape[:-1] + (1,))], -1)
        return homo @ self.full_matrix.T

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project world points to pixels.

        Args:
            points: World points, shape ``(n, 3)``.

        Returns:
            Pixel coordinates, shape ``(n, 2)``. Points behind a perspective camera
            give non-finite values.
        """
        clip = self._clip(points)
        w = clip[..., 3:4]
        with np.errstate(divide="ignore", invalid="ignore"):
            ndc = np.where(w > 1e-12, clip[..., :2] / w, np.nan)
        return (ndc + 1.0) * 0.5 * np.array([self.width, self.height], dtype=float)

    def depth(self, points: np.ndarray) -> np.ndarray:
        """Distance of world points along the view axis, shape ``(n,)``."""
        pts = np.asarray(points, dtype=float)
        return -(pts @ self.view_matrix[2, :3] + self.view_matrix[2, 3])

    def _unproject_ndc(self, ndc: np.ndarray) -> np.ndarray:
        homo = np.concatenate([ndc, np.ones(ndc.shape[:-1] + (1,))], -1)
        world = homo @ self.inverse_full_matrix.T
        return world[..., :3] / world[..., 3:4]

    def rays(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rays through pixels.

        Args:
            pixels: Pixel coordinates, shape ``(n, 2)``.

        Returns:
            ``(origins, directions)``, each ``(n, 3)``: origins on the near plane and
            unit directions pointing into the scene.
        """
        px = np.asarray(pixels, dtype=float)
        ndc = px / np.array([self.width, self.height], dtype=float) * 2.0 - 1.0
        near = self._unproject_ndc(np.concatenate([ndc, -np.ones(ndc.shape[:-1] + (1,))], -1))
        far = self._unproject_ndc(np.concatenate([ndc, np.zeros(ndc.shape[:-1] + (1,))], -1))
        return near, normalize(far - near)

    def view_directions(self, points: np.ndarray) -> np.ndarray:
        """Unit directions from the eye towards world points, shape ``(n, 3)``."""
        pts = np.asarray(points, dtype=float)
        if not self.is_perspective:
            return np.broadcast_to(self.forward, pts.shape).copy()
        return normalize(pts - self.location)

    def unproject_at_depth(self, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """World points at a given view depth that project onto ``pixels``.

        Args:
            pixels: Pixel coordinates, shape ``(n, 2)``.
            depth: View depths (see :meth:`depth`), shape ``(n,)`` or scalar.

        Returns:
            World points, shape ``(n, 3)``.
        """
        origins, dirs = self.rays(pixels)
        d0 = self.depth(origins)
        rate = dirs @ self.forward
        t = (np.asarray(depth, dtype=float) - d0) / rate
        return origins + dirs * t[..., None]

    def pixels_per_unit(self, depth: float) -> float:
        """Image scale at a view depth: pixels per world unit for a view-parallel segment.

        Args:
            depth: View depth in world units (ignored for orthographic cameras).

        Returns:
            Scale in pixels per world unit.
        """
        a = self.unproject_at_depth(np.array([[0.0, 0.0], [1.0, 0.0]]), depth)
        return 1.0 / float(np.linalg.norm(a[1] - a[0]))
