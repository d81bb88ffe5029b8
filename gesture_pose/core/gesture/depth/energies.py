"""Conformity and foreshortening energies of the 3D lifting (Gesture3D Section 7).

Every term here is a weighted linear least-squares residual of the flattened joint
positions ``x = vec(X)`` (``X`` of shape ``(J, 3)``, world units, row-major)::

    E = sum_i weight_i * (M x - target)_i^2

so the solver only needs its matrix, target and weights (:class:`LinearTerm`). The view is
orthographic as in the paper: a joint's image is ``scale * (right . X, up . X)`` plus a
constant and its depth is ``forward . X``. For a perspective camera, ``scale`` is the
camera's pixels per world unit at the character's depth (:func:`view_frame`).

The links are the edges of the solving skeleton's joint tree (bones and the rigid offsets
of unconnected bones); ``lengths`` are their rest lengths, which the twist parametrization
keeps exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import trim_mean

from ...camera import Camera
from ...exceptions import InputError


@dataclass(frozen=True)
class ViewFrame:
    """The orthographic view the drawing is interpreted in.

    Attributes:
        right: World direction of the image x axis, shape ``(3,)``.
        up: World direction of the image y axis, shape ``(3,)``.
        forward: World direction away from the viewer (depth grows along it), ``(3,)``.
        scale: Pixels per world unit at the character's depth.
        camera: The perspective camera, when the solve reads the drawing through its view
            rays (ours; None: orthographic at ``scale`` throughout).
    """

    right: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    scale: float
    camera: Camera | None = None

    def depth(self, X: np.ndarray) -> np.ndarray:
        """Depth of points along ``forward`` (up to a constant), shape ``(n,)``."""
        return np.asarray(X, dtype=float) @ self.forward


@dataclass(frozen=True)
class LinearTerm:
    """A weighted least-squares term ``sum_i w_i ((M x) - t)_i^2`` of the joint positions.

    Attributes:
        name: Term name (``"conformity"``, ``"foreshortening"``, ``"spline"``).
        matrix: ``M``, shape ``(r, 3J)``.
        target: ``t``, shape ``(r,)``.
        weight: ``w`` per row, shape ``(r,)``.
    """

    name: str
    matrix: np.ndarray
    target: np.ndarray
    weight: np.ndarray

    def value(self, X: np.ndarray) -> float:
        """Energy at joint positions ``X`` of shape ``(J, 3)``."""
        r = self.matrix @ np.ravel(X) - self.target
        return float(np.sum(self.weight * r * r))


def view_frame(camera: Camera, center: np.ndarray, perspective: bool = False) -> ViewFrame:
    """The orthographic approximation of ``camera`` around the world point ``center``.

    Args:
        camera: The view the drawing was made in.
        center: A point at the character's depth, shape ``(3,)`` (e.g. the rest joints'
            centroid).
        perspective: Keep a perspective camera in the frame (``ViewFrame.camera``) for
            the parts of the solve that read the drawing through its view rays.

    Returns:
        The view frame; for a perspective camera the scale is the one at ``center``.
    """
    view = camera.view_matrix
    center = np.asarray(center, dtype=float)
    scale = camera.pixels_per_unit(float(camera.depth(center[None])[0]))
    return ViewFrame(view[0, :3].copy(), view[1, :3].copy(), camera.forward, scale,
                     camera if perspective and camera.is_perspective else None)


def joint_links(joint_parent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges of a joint tree.

    Args:
        joint_parent: Parent joint of each joint, -1 for roots, shape ``(J,)``.

    Returns:
        ``(a, b)``: parent and child joint of every link, each ``(L,)``.
    """
    b = np.flatnonzero(np.asarray(joint_parent) >= 0)
    return np.asarray(joint_parent)[b], b


def _difference_rows(a: np.ndarray, b: np.ndarray, axis: np.ndarray, n_joints: int
                     ) -> np.ndarray:
    """Rows ``axis . (X_b - X_a)`` for each link, shape ``(L, 3J)``."""
    rows = np.zeros((len(a), n_joints, 3))
    idx = np.arange(len(a))
    rows[idx, b] += axis
    rows[idx, a] -= axis
    return rows.reshape(len(a), 3 * n_joints)


def ray_rows(camera: Camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear residuals that vanish when each point lies on the view ray of its pixel.

    With ``v = V X + v0`` the view-space point and ``c = P [v, 1]`` its clip coordinates,
    the point projects onto image coordinate ``n_i`` (normalized, ``2 p_i / size_i - 1``)
    when ``c_i - n_i c_3 = 0``, which is linear in ``X``. Divided by ``P_ii`` the residual
    is the point's lateral distance from the ray at its own depth, world units: a pixel
    off at view depth ``z`` is ``1 / scale(z)`` world units off. For an orthographic
    camera ``c_3 = 1`` and the residual is ``right . X - p_x / scale`` up to a constant.

    Args:
        camera: The view.
        pixels: Drawn points, pixels, shape ``(J, 2)``.

    Returns:
        ``(A, k)``: the residual of point ``j`` along image axis ``i`` is
        ``A[j, i] . X_j + k[j, i]``; shapes ``(J, 2, 3)`` and ``(J, 2)``.
    """
    P, V = camera.projection_matrix, camera.view_matrix
    size = np.array([camera.width, camera.height], dtype=float)
    n = 2.0 * np.asarray(pixels, dtype=float) / size - 1.0  # (J, 2)
    rows = P[None, :2, :] - n[:, :, None] * P[3][None, None, :]  # (J, 2, 4)
    rows = rows / np.array([P[0, 0], P[1, 1]])[None, :, None]
    A = rows[:, :, :3] @ V[:3, :3]
    k = rows[:, :, :3] @ V[:3, 3] + rows[:, :, 3]
    return A, k


def conformity_term(frame: ViewFrame, joints2d: np.ndarray, a: np.ndarray, b: np.ndarray,
                    lengths: np.ndarray, n_joints: int,
                    confidence: np.ndarray | None = None,
                    camera: Camera | None = None) -> LinearTerm:
    """E_c (Eq. 5): the projected 3D links match the drawn 2D links, slope and length.

    ``E_c = sum_ab w_ab || P (X_b - X_a) - (p_b - p_a) / scale ||^2`` with ``P`` the image
    axes and ``w_ab = 1 / l_ab^2``.

    With a perspective ``camera`` (ours) each link's residual is instead the difference of
    its two joints' distances from their view rays (:func:`ray_rows`):
    ``(A_b X_b + k_b) - (A_a X_a + k_a)``. At one depth ``z`` this is the orthographic
    residual at ``scale(z)``; a link reaching towards the camera is measured at its
    joints' own depths, and the image offset of a link seen off the view's axis as it
    moves in depth (parallax) is the drawing's, not read as a turn or a length.

    Args:
        frame: The view.
        joints2d: Drawn joints, pixels, shape ``(J, 2)``.
        a: Parent joint of each link, shape ``(L,)``.
        b: Child joint of each link, shape ``(L,)``.
        lengths: Rest 3D length of each link, world units, shape ``(L,)``.
        n_joints: ``J``.
        confidence: Extra factor on each link's weight, shape ``(L,)`` (default 1).
        camera: The drawing's view, for the perspective residuals (None or orthographic:
            the orthographic ones at ``frame.scale``).

    Returns:
        The term, ``2L`` rows.
    """
    if camera is not None and camera.is_perspective:
        A, k = ray_rows(camera, joints2d)
        rows = np.zeros((2, len(a), n_joints, 3))
        idx = np.arange(len(a))
        for i in range(2):
            rows[i, idx, b] += A[b, i]
            rows[i, idx, a] -= A[a, i]
        matrix = rows.reshape(2 * len(a), 3 * n_joints)
        target = np.concatenate([k[a, 0] - k[b, 0], k[a, 1] - k[b, 1]])
    else:
        drawn = (joints2d[b] - joints2d[a]) / frame.scale
        matrix = np.concatenate([_difference_rows(a, b, frame.right, n_joints),
                                 _difference_rows(a, b, frame.up, n_joints)])
        target = np.concatenate([drawn[:, 0], drawn[:, 1]])
    w = 1.0 / np.maximum(lengths, 1e-9) ** 2
    if confidence is not None:
        w = w * np.asarray(confidence, dtype=float)
    return LinearTerm("conformity", matrix, target, np.concatenate([w, w]))


def foreshortening_ratios(joints2d: np.ndarray, a: np.ndarray, b: np.ndarray,
                          lengths: np.ndarray, scale: float) -> np.ndarray:
    """Drawn length over full 3D length of each link, ``(L,)`` (1 = in the view plane)."""
    drawn = np.linalg.norm(joints2d[b] - joints2d[a], axis=1) / scale
    return drawn / np.maximum(lengths, 1e-9)


def foreshortening_weights(ratios: np.ndarray, sigma_f: float = 0.2,
                           free_ratio: float = 0.6, trim: float = 0.1) -> np.ndarray:
    """Weights of E_v (Eq. 6) from each link's foreshortening relative to the average.

    With ``rho = f / mean(f)``: links drawn at least as long as the average keep weight 1
    (their depth should not change), shorter ones get ``exp(-(1 - rho)^2 / (2 sigma_f^2))``
    and links with ``rho < free_ratio`` are deliberately foreshortened and free (weight 0).

    The average is trimmed (ours): the fraction ``trim`` of the links at each end of the
    ratios is left out, so that one link the 2D fit got badly wrong (a short rigid offset
    drawn at many times its length) does not make every other link look foreshortened.

    Args:
        ratios: Foreshortening ``f`` per link, shape ``(L,)``.
        sigma_f: Width of the fall-off (paper: 0.2).
        free_ratio: Relative foreshortening below which a link is free (paper: 0.6).
        trim: Fraction of links left out at each end of the average (0: the plain mean).

    Returns:
        Weights in ``[0, 1]``, shape ``(L,)``.
    """
    ratios = np.asarray(ratios, dtype=float)
    mean = float(trim_mean(ratios, trim)) if ratios.size else 1.0
    if mean <= 1e-9:
        raise InputError("Every bone of the drawing has zero length: redraw the figure.")
    rho = ratios / mean
    w = np.exp(-np.maximum(1.0 - rho, 0.0) ** 2 / (2.0 * sigma_f**2))
    return np.where(rho < free_ratio, 0.0, w)


def foreshortening_term(frame: ViewFrame, a: np.ndarray, b: np.ndarray, lengths: np.ndarray,
                        weights: np.ndarray, n_joints: int,
                        bind_depth: np.ndarray | None = None) -> LinearTerm:
    """E_v (Eq. 7): penalize depth change along links that the drawing shows unshortened.

    ``E_v = sum_ab v_ab (d_b - d_a - e_ab)^2 / l_ab^2`` with ``d = forward . X``, ``v_ab``
    from :func:`foreshortening_weights` and ``e_ab`` the link's depth change in the bind
    pose (0 in the paper, which assumes a bind pose in the view plane; with ``e`` a link
    the drawing shows as usual keeps the depth it has in the bind pose, e.g. feet pointing
    at a front view).

    Args:
        frame: The view.
        a: Parent joint of each link, shape ``(L,)``.
        b: Child joint of each link, shape ``(L,)``.
        lengths: Rest 3D lengths, world units, shape ``(L,)``.
        weights: ``v_ab``, shape ``(L,)``.
        n_joints: ``J``.
        bind_depth: ``e_ab``, world units, shape ``(L,)``; zeros when None.

    Returns:
        The term, ``L`` rows.
    """
    matrix = _difference_rows(a, b, frame.forward, n_joints)
    w = np.asarray(weights, dtype=float) / np.maximum(lengths, 1e-9) ** 2
    target = np.zeros(len(a)) if bind_depth is None else np.asarray(bind_depth, float)
    return LinearTerm("foreshortening", matrix, target, w)


def bind_agreement(joints2d: np.ndarray, a: np.ndarray, b: np.ndarray,
                   rest_links: np.ndarray, frame: ViewFrame, height: float,
                   sigma: float) -> np.ndarray:
    """How well each drawn link agrees with the bind pose's link seen in the view.

    ``g = exp(-|p_b - p_a - scale P r|^2 / (2 (sigma height scale)^2))`` with ``r`` the
    link's bind vector and ``P`` the image axes: 1 for a link drawn exactly as the bind
    pose shows it, falling off with the image distance between the two link vectors
    measured in character heights (the 2D fit places joints a few % of the height off,
    so the fall-off is absolute, not relative to the link's length).

    Args:
        joints2d: Drawn joints, pixels, shape ``(J, 2)``.
        a: Parent joint of each link, shape ``(L,)``.
        b: Child joint of each link, shape ``(L,)``.
        rest_links: Bind-pose link vectors ``X_b - X_a``, world units, shape ``(L, 3)``.
        frame: The view.
        height: The character's height, world units.
        sigma: Fall-off, fraction of the height.

    Returns:
        Agreement in ``(0, 1]``, shape ``(L,)``.
    """
    drawn = (joints2d[b] - joints2d[a]) / frame.scale
    bind = np.stack([rest_links @ frame.right, rest_links @ frame.up], axis=1)
    gap = np.linalg.norm(drawn - bind, axis=1) / max(sigma * height, 1e-12)
    return np.exp(-0.5 * gap**2)


def bind_term(a: np.ndarray, b: np.ndarray, rest_links: np.ndarray, lengths: np.ndarray,
              weights: np.ndarray, n_joints: int) -> LinearTerm:
    """E_b (ours): links the drawing shows as in the bind pose keep their bind 3D vector.

    ``E_b = sum_ab g_ab |X_b - X_a - r_ab|^2 / l_ab^2`` with ``r_ab`` the bind link vector
    and ``g_ab`` the weight (:func:`bind_agreement` times a factor). This is the
    stabilizer of Eq. 9 measured from the bind pose instead of the previous iterate, and
    only where the drawing agrees with it: a limb the drawing leaves as it is keeps its
    depth (the drawing cannot show it, so the bind pose is the best guess), while links
    drawn differently are free of it. It acts on the whole vector, not only on the depth:
    near the bind pose it also evens out the 2D fit's misplaced joints (on the benchmark's
    traced drawings the depth-only version gave 5.36% of the height against 4.85%).

    Args:
        a: Parent joint of each link, shape ``(L,)``.
        b: Child joint of each link, shape ``(L,)``.
        rest_links: Target link vectors, world units, shape ``(L, 3)``.
        lengths: Rest 3D lengths, world units, shape ``(L,)``.
        weights: ``g_ab``, shape ``(L,)``.
        n_joints: ``J``.

    Returns:
        The term, ``3L`` rows (x, y and z of every link).
    """
    eye = np.eye(3)
    matrix = np.concatenate([_difference_rows(a, b, e, n_joints) for e in eye])
    w = np.asarray(weights, dtype=float) / np.maximum(lengths, 1e-9) ** 2
    return LinearTerm("bind", matrix, np.asarray(rest_links, float).T.ravel(), np.tile(w, 3))
