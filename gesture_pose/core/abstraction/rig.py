"""Linear blend skinning of rigged points with analytic Jacobians (Hahn et al. 2015, Eq. 13).

Every rigged point (a point of an abstraction curve, a representative mesh vertex) is stored
as per-bone homogeneous rest vectors ``Y_vj = sum_k c_vk w_kj [zbar_k; 1]`` so that its
position is linear in the bones' skinning matrices::

    x_v(p) = sum_j G_j(p) Y_vj,      G_j = A_j Bw_j^-1              (Eq. 13)

with ``A_j`` the posed world transform of bone ``j`` (a similarity: rotation, uniform scale,
translation) and ``Bw_j = [R_j | r_j]`` its rest transform in world space. A plain skinned
vertex has ``Y_vj = w_vj [zbar_v; 1]``; a point at barycentric coordinates on a triangle (the
draw-over abstraction) blends the three vertices' vectors.

Derivatives (parameters are increments about the current pose, see :mod:`.parameters`): for a
rotation ``omega_b`` of bone ``b`` about its local axis ``k`` every point moved by the
subtree of ``b`` turns about the posed joint ``h_b`` around the world axis ``a = F_b e_k``::

    dx_v / d omega_bk = a x (Ysub_vb - Wsub_vb h_b)
    dx_v / d s_b      = (Ysub_vb - Wsub_vb h_b) / s_b
    dx_v / d tau_b    = Wsub_vb R_b

where ``Ysub_vb`` sums ``G_j Y_vj`` and ``Wsub_vb`` the weights over the bones ``j`` in the
subtree of ``b``. A bone ``c`` below ``b`` that does not inherit rotation keeps its
orientation when ``b`` turns: only its head moves, so ``c`` and its subtree translate by the
motion of ``h_c``. With ``Rsub`` summing over the bones reached from ``b`` through inheriting
bones only, and ``c`` running over the topmost non-inheriting bones below ``b``::

    rel_vb = Rsub_vb - Wsub_vb h_b + sum_c Wsub_vc h_c
    dx_v / d omega_bk = a x rel_vb,        dx_v / d s_b = rel_vb / s_b
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..exceptions import InputError
from ..skeleton import Skeleton
from .parameters import ParameterSpace, RigPose


def rest_matrices(skeleton: Skeleton) -> np.ndarray:
    """World rest transforms ``Bw = [R | r]`` of every bone, shape ``(n, 4, 4)``."""
    n = skeleton.n_bones
    out = np.tile(np.eye(4), (n, 1, 1))
    out[:, :3, :3] = skeleton.rest_frames
    out[:, :3, 3] = skeleton.rest_heads
    return out


def rigid_inverse(m: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``[R | t]``: ``[R^T | -R^T t]``, shape ``(..., 4, 4)``."""
    out = np.zeros_like(m)
    rt = np.swapaxes(m[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, m[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _skew_columns(frames: np.ndarray) -> np.ndarray:
    """Cross-product matrices of every frame column, laid out for :func:`point_jacobian`.

    Args:
        frames: Rotation frames ``F``, shape ``(r, 3, 3)``; column ``k`` is the world axis
            ``a_k`` of local axis ``k``.

    Returns:
        ``S``, shape ``(r, 3, 9)``, with ``S[r, e, 3 d + k] = [a_k]_x[d, e]``, so that
        ``(v @ S[r])[3 d + k] = (a_k x v)_d``.
    """
    a = np.swapaxes(frames, 1, 2)  # (r, k, xyz)
    zero = np.zeros(a.shape[:2])
    skew = np.stack([np.stack([zero, -a[..., 2], a[..., 1]], -1),
                     np.stack([a[..., 2], zero, -a[..., 0]], -1),
                     np.stack([-a[..., 1], a[..., 0], zero], -1)], -2)  # (r, k, d, e)
    return np.transpose(skew, (0, 3, 2, 1)).reshape(len(frames), 3, 9)


def descendant_matrix(skeleton: Skeleton) -> np.ndarray:
    """``D[j, b] = 1`` when bone ``j`` is ``b`` or below it, shape ``(n, n)`` float."""
    n = skeleton.n_bones
    d = np.eye(n)
    for j in range(n):  # parents first: a bone's column set is its parent's plus itself
        p = skeleton.parents[j]
        if p >= 0:
            d[j] += d[p]
    return d


def inheritance_matrices(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray | None]:
    """``(T, K)`` of :class:`RigTables` (``K`` None when every bone inherits rotation)."""
    n = skeleton.n_bones
    inherit = np.asarray(skeleton.inherit_rotation, dtype=bool)
    turning = np.eye(n)
    carried = np.zeros((n, n))
    for j in range(n):  # parents first
        p = skeleton.parents[j]
        if p < 0:
            continue
        if inherit[j]:
            turning[j] += turning[p]
        else:
            carried[j] = turning[p]
    return turning, (carried if np.any(~inherit[skeleton.parents >= 0]) else None)


def _levels(parents: np.ndarray) -> list[np.ndarray]:
    """Bone indices per depth in the tree (roots first), for level-wise kinematics."""
    depth = np.zeros(len(parents), dtype=int)
    for i, p in enumerate(parents):
        depth[i] = 0 if p < 0 else depth[p] + 1
    return [np.flatnonzero(depth == d) for d in range(depth.max() + 1)]


@dataclass(frozen=True)
class PosedBones:
    """Posed bone transforms.

    Attributes:
        world: Posed world transforms ``A``, shape ``(n, 4, 4)`` (similarities).
        skinning: Skinning matrices ``G = A Bw^-1``, shape ``(n, 4, 4)``.
        frames: Posed rotation frames ``F`` (scale removed), shape ``(n, 3, 3)``.
        heads: Posed heads ``h``, shape ``(n, 3)``, world units.
        scales: Accumulated uniform scale of every bone, shape ``(n,)``.
    """

    world: np.ndarray
    skinning: np.ndarray
    frames: np.ndarray
    heads: np.ndarray
    scales: np.ndarray


@dataclass(frozen=True)
class RigTables:
    """Pose-independent tables of a skeleton, computed once per solve.

    Attributes:
        rest: Rest transforms ``Bw``, ``(n, 4, 4)``.
        rest_inv: Their inverses, ``(n, 4, 4)``.
        levels: Bone indices per tree depth.
        descendants: :func:`descendant_matrix`, ``(n, n)``.
        turning: ``T[j, b] = 1`` when bone ``j`` turns with ``b`` (``j`` is ``b`` or below
            it with only inheriting bones on the way), ``(n, n)``.
        carried: ``K[c, b] = 1`` when ``c`` is a topmost non-inheriting bone below ``b``
            (it translates with ``b`` without turning), ``(n, n)``; None when every bone
            inherits rotation.
    """

    rest: np.ndarray
    rest_inv: np.ndarray
    levels: tuple[np.ndarray, ...]
    descendants: np.ndarray
    turning: np.ndarray
    carried: np.ndarray | None

    @classmethod
    def of(cls, skeleton: Skeleton) -> RigTables:
        """Compute the tables of ``skeleton``."""
        rest = rest_matrices(skeleton)
        turning, carried = inheritance_matrices(skeleton)
        return cls(rest, rigid_inverse(rest), tuple(_levels(skeleton.parents)),
                   descendant_matrix(skeleton), turning, carried)


def pose_bones(skeleton: Skeleton, pose: RigPose, tables: RigTables | None = None
               ) -> PosedBones:
    """Forward kinematics with per-bone uniform scale (Blender's full scale inheritance).

    ``A_i = A_p Bw_p^-1 Bw_i M_i`` with ``M_i = [s_i Q_i | t_i]`` (``A_i = Bw_i M_i`` for roots);
    bones that do not inherit rotation keep ``R_i s_i Q_i`` as their linear part.

    Args:
        skeleton: The rest skeleton.
        pose: Local rotations, scales and translations.
        tables: Precomputed tables of ``skeleton`` (computed here when None).

    Returns:
        The posed transforms.
    """
    n = skeleton.n_bones
    tables = RigTables.of(skeleton) if tables is None else tables
    rest = tables.rest
    local = np.tile(np.eye(4), (n, 1, 1))
    local[:, :3, :3] = pose.rotations * pose.scales[:, None, None]
    local[:, :3, 3] = pose.translations
    rest_local = rest @ local
    world = np.empty((n, 4, 4))
    parents = skeleton.parents
    rest_inv = tables.rest_inv
    for level in tables.levels:
        p = parents[level]
        roots, kids, kp = level[p < 0], level[p >= 0], p[p >= 0]
        world[roots] = rest_local[roots]
        if kids.size:
            world[kids] = world[kp] @ rest_inv[kp] @ rest_local[kids]
            keep = ~skeleton.inherit_rotation[kids]
            if np.any(keep):
                world[kids[keep], :3, :3] = rest_local[kids[keep], :3, :3]
    scales = np.cbrt(np.linalg.det(world[:, :3, :3]))
    frames = world[:, :3, :3] / scales[:, None, None]
    return PosedBones(world, world @ rest_inv, frames, world[:, :3, 3].copy(), scales)


def lbs_weighted_rest(rest_points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per-bone homogeneous rest vectors of plain skinned points.

    Args:
        rest_points: Rest positions in world space, shape ``(m, 3)``.
        weights: Skinning weights, shape ``(m, n)`` (rows are normalized here; rows
            summing to zero raise).

    Returns:
        ``Y``, shape ``(m, n, 4)``.

    Raises:
        InputError: A point has no weight on any bone.
    """
    w = np.asarray(weights, dtype=float)
    total = w.sum(axis=1, keepdims=True)
    if np.any(total <= 1e-12):
        bad = int(np.flatnonzero(total[:, 0] <= 1e-12)[0])
        raise InputError(f"Rigged point {bad} has no bone weights: give every abstraction "
                         "vertex a vertex group of a deforming bone, or parent it to a bone.")
    w = w / total
    homo = np.concatenate([np.asarray(rest_points, float), np.ones((len(w), 1))], axis=1)
    return w[:, :, None] * homo[:, None, :]


def skin(posed: PosedBones, weighted_rest: np.ndarray) -> np.ndarray:
    """Posed positions ``x_v = sum_j G_j Y_vj`` (Eq. 13), shape ``(m, 3)``."""
    m, n = weighted_rest.shape[:2]
    stacked = np.swapaxes(posed.skinning[:, :3, :], 1, 2).reshape(n * 4, 3)
    return weighted_rest.reshape(m, n * 4) @ stacked


@dataclass(frozen=True)
class LbsRig:
    """An LBS rig evaluating abstraction points and representative vertices.

    Attributes:
        skeleton: The rest skeleton.
        space: Which parameters are free.
        abstraction_rest: ``Y`` of the abstraction points, shape ``(m, n, 4)``.
        representative_rest: ``Y`` of the representative mesh vertices, shape ``(k, n, 4)``.
    """

    skeleton: Skeleton
    space: ParameterSpace
    abstraction_rest: np.ndarray
    representative_rest: np.ndarray
    tables: RigTables = field(init=False, repr=False, compare=False)
    subtree_weights: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False,
                                                           compare=False)

    def __post_init__(self) -> None:
        """Precompute the skeleton's tables and the points' subtree weights ``Wsub``."""
        tables = RigTables.of(self.skeleton)
        object.__setattr__(self, "tables", tables)
        object.__setattr__(self, "subtree_weights", tuple(
            np.ascontiguousarray(y[:, :, 3]) @ tables.descendants
            for y in (self.abstraction_rest, self.representative_rest)))

    def with_space(self, space: ParameterSpace) -> LbsRig:
        """The same rig with other free parameters (e.g. the bones a drawing constrains)."""
        return replace(self, space=space)

    def evaluate(self, pose: RigPose) -> tuple[np.ndarray, np.ndarray]:
        """Abstraction points ``(m, 3)`` and representative vertices ``(k, 3)`` at ``pose``."""
        posed = pose_bones(self.skeleton, pose, self.tables)
        return skin(posed, self.abstraction_rest), skin(posed, self.representative_rest)

    def jacobians(self, pose: RigPose) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Positions and analytic Jacobians ``J_x`` and ``J_z`` at ``pose``.

        Returns:
            ``(x (m, 3), z (k, 3), J_x (m, 3, P), J_z (k, 3, P))``.
        """
        posed = pose_bones(self.skeleton, pose, self.tables)
        out = []
        for rest, wsub in zip((self.abstraction_rest, self.representative_rest),
                              self.subtree_weights, strict=True):
            out.append(skin(posed, rest))
            out.append(point_jacobian(posed, rest, self.space, pose, self.tables, wsub))
        return out[0], out[2], out[1], out[3]


def point_jacobian(posed: PosedBones, weighted_rest: np.ndarray, space: ParameterSpace,
                   pose: RigPose, tables: RigTables,
                   subtree_weights: np.ndarray | None = None) -> np.ndarray:
    """Analytic Jacobian of skinned points with respect to the free parameters.

    Args:
        posed: Posed bones at ``pose``.
        weighted_rest: ``Y``, shape ``(m, n, 4)``.
        space: The free parameters.
        pose: The current pose (for the scales).
        tables: The skeleton's :class:`RigTables`.
        subtree_weights: ``Wsub = W D``, shape ``(m, n)`` (pose-independent; computed here
            when None).

    Returns:
        ``J``, shape ``(m, 3, P)``, world units per radian / per unit scale / per unit;
        columns in the order of ``space``.
    """
    m, n = weighted_rest.shape[:2]
    # Bone-major layout (n, m, 3) so that every product is one BLAS call.
    per_bone = np.swapaxes(weighted_rest, 0, 1) @ np.swapaxes(posed.skinning[:, :3, :], 1, 2)
    wsub = (np.ascontiguousarray(weighted_rest[:, :, 3]) @ tables.descendants
            if subtree_weights is None else subtree_weights)  # (m, n)
    at_heads = wsub.T[:, :, None] * posed.heads[:, None, :]  # Wsub_vb h_b, (n, m, 3)
    rel = (tables.turning.T @ per_bone.reshape(n, m * 3)).reshape(n, m, 3) - at_heads
    if tables.carried is not None:  # non-inheriting bones below b translate with h_c
        rel += (tables.carried.T @ at_heads.reshape(n, m * 3)).reshape(n, m, 3)
    blocks = []
    rb = space.rotation_bones
    if rb.size:
        # a x rel = [a]_x rel: one batched product per rotating bone, (r, m, 3) @ (r, 3, 9).
        skew = _skew_columns(posed.frames[rb])  # (r, e, d * 3 + k)
        jr = np.transpose((rel[rb] @ skew).reshape(rb.size, m, 3, 3), (1, 2, 0, 3))
        blocks.append(jr.reshape(m, 3, 3 * rb.size))
    sb = space.scale_bones
    if sb.size:
        blocks.append(np.transpose(rel[sb], (1, 2, 0)) / pose.scales[sb][None, None, :])
    tb = space.translation_bones
    if tb.size:
        rot = posed.world[tb, :3, :3] / posed.scales[tb, None, None]
        rest_axes = np.einsum("bij,bjk->bik", rot, pose.rotations[tb].transpose(0, 2, 1))
        jt = wsub[:, tb, None, None] * rest_axes[None]  # (m, t, xyz, k)
        blocks.append(np.transpose(jt, (0, 2, 1, 3)).reshape(m, 3, -1))
    if not blocks:
        return np.zeros((m, 3, 0))
    return blocks[0] if len(blocks) == 1 else np.concatenate(blocks, axis=2)
