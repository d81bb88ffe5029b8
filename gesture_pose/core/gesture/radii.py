"""Joint radii measured on the mesh (Gesture3D Section 5).

A joint's circle in the drawing is the outline of the body around it. For every joint the
mesh region around it is gathered (vertices skinned to the bones meeting at the joint, in a
slab across the joint's bone, or by distance when there are no weights). The half-extents
of a bone-aligned PCA box of that region give the minimum and maximum radius, widened at end
caps by a least-squares sphere fit of the cap;
the candidate radii in the drawing are sampled between them at step epsilon.
"""

from __future__ import annotations

import numpy as np

from ..exceptions import InputError
from ..skeleton import Skeleton
from .types import SolvingSkeleton


def fit_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic least-squares sphere through points.

    Solves ``|x|^2 = 2 c . x + k`` for centre ``c`` and ``k = r^2 - |c|^2``.

    Args:
        points: Points, shape ``(n, 3)``, ``n >= 4``.

    Returns:
        ``(centre (3,), radius)``.
    """
    a = np.concatenate([2.0 * points, np.ones((len(points), 1))], axis=1)
    b = np.einsum("ij,ij->i", points, points)
    sol = np.linalg.lstsq(a, b, rcond=None)[0]
    c = sol[:3]
    return c, float(np.sqrt(max(sol[3] + c @ c, 0.0)))


def _joint_axis(solving: SolvingSkeleton, skeleton: Skeleton, j: int) -> tuple[np.ndarray, float]:
    """Unit axis and length of the bone that best describes joint ``j``'s cross-section."""
    link = solving.joint_link_bone[j]
    if link < 0:
        kids = np.flatnonzero(solving.head_joint == j)
        link = int(kids[0]) if kids.size else int(np.flatnonzero(solving.tail_joint ==
                                                                solving.joint_parent[j])[0])
    b = solving.bones[link]
    d = skeleton.rest_tails[b] - skeleton.rest_heads[b]
    length = float(np.linalg.norm(d))
    return d / length, length


def joint_radii(solving: SolvingSkeleton, skeleton: Skeleton, vertices: np.ndarray,
                weights: np.ndarray | None = None, slab: float = 0.25,
                percentile: float = 95.0) -> tuple[np.ndarray, np.ndarray]:
    """Minimum and maximum radius of every joint, world units.

    Args:
        solving: The solving skeleton.
        skeleton: The full skeleton (rest pose; ``vertices`` are rest vertices).
        vertices: Rest mesh vertices in world space, shape ``(V, 3)``.
        weights: Skin weights per full-skeleton bone, ``(V, n_bones)``, or None.
        slab: Half-thickness of the region across the joint, fraction of the bone length.
        percentile: Percentile of the box half-extents (robust to stray vertices).

    Returns:
        ``(r_min, r_max)``, each ``(J,)``.

    Raises:
        InputError: No mesh vertices.
    """
    verts = np.asarray(vertices, dtype=float)
    if verts.ndim != 2 or verts.shape[1] != 3 or len(verts) < 4:
        raise InputError("No skinned mesh to measure the joint radii: parent a mesh to the "
                         "armature with an Armature modifier.")
    n_j = solving.n_joints
    r_min, r_max = np.zeros(n_j), np.zeros(n_j)
    if weights is not None:
        weights = np.asarray(weights, dtype=float)
        # Excluded bones (fingers, toes) count for their nearest solving ancestor.
        owner = np.arange(skeleton.n_bones)
        in_solving = np.zeros(skeleton.n_bones, bool)
        in_solving[solving.bones] = True
        for b in range(skeleton.n_bones):
            a = b
            while a >= 0 and not in_solving[a]:
                a = skeleton.parents[a]
            owner[b] = a
        folded = np.zeros_like(weights)
        valid = owner >= 0
        np.add.at(folded.T, owner[valid], weights[:, valid].T)
        weights = folded
    for j in range(n_j):
        centre = solving.rest_joints[j]
        axis, length = _joint_axis(solving, skeleton, j)
        rel = verts - centre
        t = rel @ axis
        perp = rel - t[:, None] * axis
        dist = np.linalg.norm(perp, axis=1)
        region = np.abs(t) < slab * length
        if weights is not None:
            link = solving.joint_link_bone[j]
            adj = (np.array([link]) if link >= 0 else np.flatnonzero(solving.head_joint == j))
            w = weights[:, solving.bones[adj]].sum(axis=1)
            region &= w > 0.3
        region &= dist < 1.5 * length
        if region.sum() < 4:
            region = np.zeros(len(verts), bool)
            region[np.argsort(np.linalg.norm(rel, axis=1))[:16]] = True
        p2 = np.stack([perp[region] @ _ortho(axis)[0], perp[region] @ _ortho(axis)[1]], 1)
        cov = p2.T @ p2 / len(p2)
        _, vecs = np.linalg.eigh(cov)
        half = np.percentile(np.abs(p2 @ vecs), percentile, axis=0)
        r_min[j], r_max[j] = half.min(), half.max()
        if solving.terminal[j]:
            # At an end cap the region is a dome: its sphere bounds the drawn cap.
            r_sphere = fit_sphere(verts[region])[1]
            r_max[j] = max(r_max[j], float(np.clip(r_sphere, half.min(), 1.5 * half.max())))
    return r_min, r_max


def _ortho(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane perpendicular to ``axis`` (3,)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def discrete_radii(r_min: float, r_max: float, epsilon: float, max_count: int = 4) -> np.ndarray:
    """Candidate radii from ``r_min`` to ``r_max`` at step ``epsilon`` (pixels).

    Args:
        r_min: Minimum radius, pixels.
        r_max: Maximum radius, pixels.
        epsilon: Step, pixels.
        max_count: At most this many radii (evenly spread when the range is wider).

    Returns:
        Radii, shape ``(k,)``, ``1 <= k <= max_count``; when the range is narrower than a
        step, its two ends if they differ by more than a quarter step, else its middle.
    """
    r_min = max(float(r_min), 0.5 * epsilon)
    r_max = max(float(r_max), r_min)
    count = int(np.floor((r_max - r_min) / epsilon)) + 1
    if count == 1:
        # Narrower than a step: both extremes when they differ noticeably (a flat hand).
        if r_max - r_min > 0.25 * epsilon and max_count >= 2:
            return np.array([r_min, r_max])
        return np.array([0.5 * (r_min + r_max)])
    if count > max_count:
        return np.linspace(r_min, r_max, max_count)
    return r_min + epsilon * np.arange(count)
