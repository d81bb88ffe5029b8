"""Pose genes and forward kinematics vectorized over a whole population.

A pose is a gene vector ``x = [t (3), omega (3), g_1, ..., g_m]``: the root's world
translation ``t`` (world units), its world rotation ``G = exp(omega)`` applied on top of
the base pose, and the rotation genes of every :class:`~.figure.GeneGroup`. With the base
local rotations ``Q0`` the local rotation of a bone ``b`` in a group of ``k`` bones is
``Q_b = Q0_b exp(B_b g / k)`` and the root's is ``Q_r = C^T G C Q0_r`` (``C`` the root's
parent carry, fixed). Jacobians are analytic: a gene turning bone ``b`` about the world
axis ``w`` moves every point ``p`` below ``b`` by ``w x (p - head_b)``, with
``w = F_b J_r(phi) B_b e / k`` (``J_r`` the right Jacobian of the exponential map).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..skeleton import Pose, Skeleton
from .figure import CharacterFigure

N_ROOT_GENES = 6


def _position(bones: np.ndarray, bone: int) -> int:
    """Position of ``bone`` in ``bones`` ``(k,)``, or -1."""
    at = np.flatnonzero(bones == bone)
    return int(at[0]) if at.size else -1


def _coefficients(phi: np.ndarray, third: bool = True):
    """``theta^2``, ``sin(t)/t``, ``(1 - cos t)/t^2``, ``(t - sin t)/t^3`` (series near 0).

    Args:
        phi: Rotation vectors, shape ``(..., 3)``.
        third: Also compute ``(t - sin t)/t^3`` (None otherwise).

    Returns:
        Four arrays of shape ``(...)`` (the last None unless ``third``).
    """
    t2 = np.sum(phi * phi, axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-4
    safe = np.where(small, 1.0, t)
    sin = np.sin(safe)
    s = np.where(small, 1.0 - t2 / 6.0, sin / safe)
    c = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    if not third:
        return t2, s, c, None
    d = np.where(small, 1.0 / 6.0 - t2 / 120.0, (safe - sin) / safe**3)
    return t2, s, c, d


def _frames_times(F: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Frames ``(P, k, 3, 3)`` times vectors ``(k, 3)``: ``(P, k, 3)``.

    The three products summed as ``(F_0 w_0 + F_2 w_2) + F_1 w_1``, elementwise: every
    row gets the same arithmetic whatever the row count (so two row chunks give one
    call's bits). It is also the association numpy's ``einsum("pnij,nj->pni")`` uses
    here (its two-lane accumulation), which the forward pass called before: the same
    poses to the bit on this machine, twice as fast on a population.
    """
    return (F[..., 0] * w[:, None, 0] + F[..., 2] * w[:, None, 2]) + F[..., 1] * w[:, None, 1]


def _identity_skew_outer(phi: np.ndarray, alpha: np.ndarray, beta: np.ndarray,
                         gamma: np.ndarray) -> np.ndarray:
    """``alpha I + beta K + gamma phi phi^T`` (``K`` the cross-product matrix of ``phi``).

    Assembled entry by entry on ``(...)`` arrays instead of broadcasting ``(..., 3, 3)``
    products (4-5 times faster over a population), with the same floating-point
    operations per entry, so the result is bit-identical to the matrix expression.

    Args:
        phi: Rotation vectors, shape ``(..., 3)``.
        alpha: Identity coefficients, shape ``(...)``.
        beta: Cross-product coefficients, shape ``(...)``.
        gamma: Outer-product coefficients, shape ``(...)``.

    Returns:
        Matrices, shape ``(..., 3, 3)``.
    """
    x, y, z = phi[..., 0], phi[..., 1], phi[..., 2]
    bx, by, bz = beta * x, beta * y, beta * z
    gxy, gxz, gyz = gamma * (x * y), gamma * (x * z), gamma * (y * z)
    out = np.empty(phi.shape[:-1] + (3, 3))
    out[..., 0, 0] = alpha + gamma * (x * x)
    out[..., 1, 1] = alpha + gamma * (y * y)
    out[..., 2, 2] = alpha + gamma * (z * z)
    out[..., 0, 1], out[..., 1, 0] = -bz + gxy, bz + gxy
    out[..., 0, 2], out[..., 2, 0] = by + gxz, -by + gxz
    out[..., 1, 2], out[..., 2, 1] = -bx + gyz, bx + gyz
    return out


def fast_exp(phi: np.ndarray) -> np.ndarray:
    """Rodrigues' formula ``I + s K + c K^2`` with ``K^2 = phi phi^T - theta^2 I``.

    Args:
        phi: Rotation vectors, shape ``(..., 3)`` (radians).

    Returns:
        Rotation matrices, shape ``(..., 3, 3)``.
    """
    phi = np.asarray(phi, float)
    t2, s, c, _ = _coefficients(phi, third=False)
    return _identity_skew_outer(phi, 1.0 - c * t2, s, c)


def right_jacobian(phi: np.ndarray) -> np.ndarray:
    """Right Jacobian of SO(3)'s exponential map, ``(..., 3) -> (..., 3, 3)``.

    ``d exp(phi) = exp(phi) [J_r(phi) d phi]_x``, ``J_r = I - c K + d K^2``.
    """
    phi = np.asarray(phi, float)
    t2, _, c, d = _coefficients(phi)
    return _identity_skew_outer(phi, 1.0 - d * t2, -c, d)


@dataclass(frozen=True)
class PoseModel:
    """Genes -> bone transforms for one character.

    Attributes:
        skeleton: Rest skeleton.
        figure: Stick model with the gene groups.
        base: Base pose (bones outside the groups keep its rotations), ``Pose``.
        group_genes: Gene indices of each of the figure's groups, in group order (the
            first :data:`N_ROOT_GENES` genes are the root's).
    """

    skeleton: Skeleton
    figure: CharacterFigure
    base: Pose
    group_genes: tuple[np.ndarray, ...] = field(init=False, repr=False)
    _e_bone: np.ndarray = field(init=False, repr=False)
    _e_genes: np.ndarray = field(init=False, repr=False)
    _e_basis: np.ndarray = field(init=False, repr=False)
    _e_valid: np.ndarray = field(init=False, repr=False)
    _gene_bone: np.ndarray = field(init=False, repr=False)
    _gene_col: np.ndarray = field(init=False, repr=False)
    _gene_index: np.ndarray = field(init=False, repr=False)
    _desc: np.ndarray = field(init=False, repr=False)
    _root_carry: np.ndarray = field(init=False, repr=False)
    _root_hcarry: np.ndarray = field(init=False, repr=False)
    _level_data: tuple = field(init=False, repr=False)
    _tables: dict = field(init=False, repr=False, compare=False)
    _chain: np.ndarray = field(init=False, repr=False)
    _e_base: np.ndarray = field(init=False, repr=False)
    _rigid: tuple = field(init=False, repr=False)
    _root_right: np.ndarray = field(init=False, repr=False)
    _joints_on_chain: bool = field(init=False, repr=False)

    def __post_init__(self) -> None:
        """Flatten the groups into per-(bone, gene) entries and cache descendant masks."""
        sk, fig = self.skeleton, self.figure
        sizes = [grp.bounds.shape[0] for grp in fig.groups]
        ends = N_ROOT_GENES + np.cumsum(sizes, dtype=int)
        object.__setattr__(self, "group_genes", tuple(
            np.arange(e - m, e) for e, m in zip(ends.tolist(), sizes, strict=True)))
        bone, col, gene = [], [], []
        for grp, genes in zip(fig.groups, self.group_genes, strict=True):
            for j, b in enumerate(grp.bones):
                for c, g in enumerate(genes.tolist()):
                    bone.append((int(b), j, grp))
                    col.append(c)
                    gene.append(g)
        entries = [(int(b), grp, genes)
                   for grp, genes in zip(fig.groups, self.group_genes, strict=True)
                   for b in grp.bones]
        e_bone = np.array([b for b, _, _ in entries], int)
        e_genes = np.zeros((len(entries), 3), int)
        e_basis = np.zeros((len(entries), 3, 3))
        e_ncol = np.zeros(len(entries), int)
        for e, (b, grp, genes) in enumerate(entries):
            j = int(np.flatnonzero(grp.bones == b)[0])
            m = grp.bounds.shape[0]
            e_genes[e, :m] = genes
            e_basis[e, :, :m] = grp.bases[j] / len(grp.bones)
            e_ncol[e] = m
        object.__setattr__(self, "_e_bone", e_bone)
        object.__setattr__(self, "_e_genes", e_genes)
        object.__setattr__(self, "_e_basis", e_basis)
        object.__setattr__(self, "_e_valid", np.arange(3)[None] < e_ncol[:, None])
        object.__setattr__(self, "_gene_bone", np.array([b for b, _, _ in bone], int))
        object.__setattr__(self, "_gene_col", np.array(col, int))
        object.__setattr__(self, "_gene_index", np.array(gene, int))
        desc = np.zeros((sk.n_bones, sk.n_bones), bool)
        for i in range(sk.n_bones):
            desc[i, sk.descendants(i)] = True
        object.__setattr__(self, "_desc", desc)
        moved = np.unique(np.concatenate([e_bone, [fig.root_bone]]))
        object.__setattr__(self, "_e_base", self.base.rotations[e_bone])
        object.__setattr__(self, "_tables", {})
        base_local = sk.rest_frames @ self.base.rotations
        base_offset = np.einsum("nij,nj->ni", sk.rest_frames, self.base.translations)
        # The chain: the bones the genes turn, the bones that do not inherit their
        # parent's rotation, their ancestors and the bones nothing turns. The others
        # (fingers below a hand) are rigid: their local frames and offsets are always the
        # base pose's, so they are posed after the chain from constants.
        inherit_all = np.asarray(sk.inherit_rotation, bool)
        turned = np.zeros(sk.n_bones, bool)
        turned[moved] = True
        under = turned.copy()  # turned or below a turned bone
        for level in sk._levels:
            par = sk.parents[level]
            has = par >= 0
            under[level[has]] |= under[par[has]]
        chain = ~under | turned | (under & ~inherit_all)
        for b in np.flatnonzero(chain & under).tolist():
            chain[sk.ancestors(b)] = True
        chain_idx = np.flatnonzero(chain)
        state = sk.forward(self.base)
        r = fig.root_bone
        object.__setattr__(self, "_root_carry", sk.parent_carry(r, state))
        p = sk.parents[r]
        hc = np.eye(3) if p < 0 else state.frames[p] @ sk.rest_frames[p].T
        object.__setattr__(self, "_root_hcarry", hc)
        object.__setattr__(self, "_root_right", self._root_carry @ self.base.rotations[r])
        object.__setattr__(self, "_chain", chain_idx)
        object.__setattr__(self, "_joints_on_chain", bool(np.all(chain[fig.joint_bones])))
        object.__setattr__(self, "_level_data", self._factored_levels(
            chain, base_local, base_offset, e_bone))
        # The rigid bones, level by level (parents first): a rigid bone's frame is its
        # parent's times a constant, its head its parent's plus the parent's frame times a
        # constant vector.
        rigid = []
        for level in sk._levels:
            ki = level[~chain[level]]
            if ki.size:
                kp = sk.parents[ki]
                rest_t = np.swapaxes(sk.rest_frames[kp], 1, 2)
                rel = (sk.rest_heads[ki] - sk.rest_heads[kp]) + base_offset[ki]
                rigid.append((ki, kp, rest_t @ base_local[ki],
                              np.einsum("nij,nj->ni", rest_t, rel)))
        object.__setattr__(self, "_rigid", tuple(rigid))

    def _factored_levels(self, chain: np.ndarray, base_local: np.ndarray,
                         base_offset: np.ndarray, e_bone: np.ndarray) -> tuple:
        """Per tree depth, the constants of the chain bones' posed frames and heads.

        A chain bone ``b`` of parent ``p`` (rest frames ``R``) has the local frame
        ``L_b = R_b Q_b`` and is posed as ``F_b = F_p R_p^T L_b`` (``L_b`` alone when it
        does not inherit its parent's rotation, or has no parent) and ``h_b = h_p + F_p
        R_p^T (rel_b + o_b)``. ``Q_b`` is the base rotation, ``Q0_b E_b`` for a group bone
        (``E_b = exp(B_b g / k)``) or ``C^T G C Q0_r`` for the root, so ``F_b = F_p K_b``
        with the constant ``K_b = R_p^T R_b Q0_b``, ``R_p^T R_b Q0_b`` then times ``E_b``,
        or ``R_p^T R_r C^T`` then times ``G C Q0_r``: two 3x3 products per individual
        and turned bone instead of four (the same pose, to rounding).

        Returns:
            Per level ``(roots, children (k,), parents (k,), K (k, 3, 3), w (k, 3), the
            children not inheriting (positions, or None), the group bones' positions (None
            when all are) and entries, the root's position or -1)``; ``roots`` is None or,
            for the level's parentless chain bones, ``(bones (r,), K (r, 3, 3), heads (r,
            3), the group bones' positions and entries, the root's position or -1)``.
        """
        sk, fig = self.skeleton, self.figure
        rest, n = sk.rest_frames, sk.n_bones
        inherit = np.asarray(sk.inherit_rotation, bool)
        r = fig.root_bone
        entry = np.full(n, -1)
        entry[e_bone] = np.arange(e_bone.size)  # a bone in two groups: the last
        entry[r] = -1  # the root's own formula wins
        C = self._root_carry
        left = base_local.copy()  # the factor of L_b left of its per-individual part
        left[e_bone] = rest[e_bone] @ self.base.rotations[e_bone]
        left[r] = rest[r] @ C.T
        levels = []
        for level in sk._levels:
            level = level[chain[level]]
            if not level.size:
                continue
            par = sk.parents[level]
            ri, ci, cp = level[par < 0], level[par >= 0], par[par >= 0]
            rest_t = np.swapaxes(rest[cp], 1, 2)
            K = rest_t @ left[ci]
            out = ~inherit[ci]
            K[out] = left[ci][out]
            w = np.einsum("nij,nj->ni", rest_t,
                          (sk.rest_heads[ci] - sk.rest_heads[cp]) + base_offset[ci])
            roots = None
            if ri.size:
                rpos = np.flatnonzero(entry[ri] >= 0)
                roots = (ri, left[ri], sk.rest_heads[ri] + base_offset[ri], rpos,
                         entry[ri][rpos], _position(ri, r))
            pos = np.flatnonzero(entry[ci] >= 0)
            levels.append((roots, ci, cp, K, w, np.flatnonzero(out) if out.any() else None,
                           None if pos.size == ci.size else pos, entry[ci][pos],
                           _position(ci, r)))
        return tuple(levels)

    @property
    def chain_bones(self) -> np.ndarray:
        """The bones posed per individual (the others are rigid), ascending, ``(c,)``."""
        return self._chain

    def rigid_moments(self, weights: np.ndarray) -> tuple[np.ndarray, ...]:
        """What the rigid bones add to a weighted sum of bone midpoints, per chain bone.

        A rigid bone (below the chain, turned by no gene: a finger) keeps its place in the
        frame of its nearest chain ancestor ``a``, so the rigid bones under ``a`` add
        ``W_a head_a + F_a v_a`` to ``sum_n w_n (head_n + tail_n) / 2`` (the centre of
        mass of Eqs. 7-8 with ``w`` the bone masses), ``F_a`` the posed frame of ``a``.

        Args:
            weights: Per-bone weights, shape ``(n,)``.

        Returns:
            ``(anchors (A,), W (A,), v (A, 3))``: the chain bones carrying rigid bones,
            their rigid bones' total weight and weighted midpoint offsets in their frames.
        """
        sk = self.skeleton
        on_chain = np.zeros(sk.n_bones, bool)
        on_chain[self._chain] = True
        heads, tails, frames = (a[0] for a in self.forward(np.zeros((1, self.n_genes))))
        anchor = {}
        for k in np.flatnonzero(~on_chain).tolist():
            a = k
            while not on_chain[a]:
                a = int(sk.parents[a])
            anchor.setdefault(a, []).append(k)
        anchors = np.array(sorted(anchor), int)
        W = np.array([weights[anchor[a]].sum() for a in anchors.tolist()])
        # The frames' inverse, not their transpose: rest frames read from float32 data
        # are orthonormal to about 1e-7 only.
        v = np.array([np.linalg.solve(frames[a], weights[anchor[a]] @ (
            0.5 * (heads[anchor[a]] + tails[anchor[a]]) - heads[a]))
            for a in anchors.tolist()]).reshape(-1, 3)
        return anchors, W, v

    def genes_of(self, name: str) -> np.ndarray:
        """Gene indices of the group called ``name`` (empty when there is none)."""
        for grp, genes in zip(self.figure.groups, self.group_genes, strict=True):
            if grp.name == name:
                return genes
        return np.zeros(0, int)

    @property
    def n_genes(self) -> int:
        """Length of the gene vector."""
        return N_ROOT_GENES + sum(g.size for g in self.group_genes)

    def bounds(self, root_center: np.ndarray, root_range: float) -> np.ndarray:
        """Gene bounds, shape ``(G, 2)``: the root within ``root_range`` of ``root_center``.

        Args:
            root_center: World offset of the root from its base position, shape ``(3,)``.
            root_range: Half-width of the translation box, world units.
        """
        c = np.asarray(root_center, float)
        rows = [np.stack([c - root_range, c + root_range], 1),
                np.tile([-np.pi, np.pi], (3, 1))]
        rows += [g.bounds for g in self.figure.groups]
        return np.concatenate(rows)

    def local_rotations(self, genes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local rotations and the exp-map arguments of the group bones.

        Args:
            genes: Gene vectors, shape ``(P, G)``.

        Returns:
            ``(Q, phi)``: local rotations ``(P, n, 3, 3)`` and per group bone the rotation
            vectors ``phi = B g / k`` in group order, ``(P, n_entries, 3)``.
        """
        phi, E = self._exponentials(np.atleast_2d(genes))
        return self._rotations(E), phi

    def _exponentials(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The group bones' rotation vectors and the turns of the group bones and the root.

        Args:
            x: Gene vectors, shape ``(P, G)``.

        Returns:
            ``(phi (P, entries, 3), E (P, entries + 1, 3, 3))``: ``E`` holds ``exp(phi)``
            per group bone entry, then the root's turn ``G`` (the last row).
        """
        g = np.where(self._e_valid, x[:, self._e_genes], 0.0)
        phi = np.einsum("eij,pej->pei", self._e_basis, g)
        # One exponential call for the group bones and the root's turn (the last row).
        return phi, fast_exp(np.concatenate([phi, x[:, None, 3:6]], axis=1))

    def _rotations(self, E: np.ndarray, bones: np.ndarray | None = None) -> np.ndarray:
        """Local rotations ``(P, n, 3, 3)`` from :meth:`_exponentials`' ``E``.

        With ``bones`` ``(k,)``, only theirs ``(P, k, 3, 3)`` (the same products, the
        same bits).
        """
        base = self.base.rotations
        if bones is not None:
            bones = np.asarray(bones, int)
            # The entry a bone takes its rotation from: its last (as the scatter below).
            last = np.full(self.skeleton.n_bones, -1)
            last[self._e_bone] = np.arange(self._e_bone.size)
            ent = last[bones]
            Q = np.broadcast_to(base[bones], (E.shape[0], bones.size, 3, 3)).copy()
            on = np.flatnonzero(ent >= 0)
            if on.size:
                Q[:, on] = self._e_base[ent[on]] @ E[:, ent[on]]
            root = np.flatnonzero(bones == self.figure.root_bone)
            if root.size:
                C = self._root_carry
                Q[:, root] = (C.T @ E[:, -1] @ C @ base[self.figure.root_bone])[:, None]
            return Q
        Q = np.broadcast_to(base, (E.shape[0],) + base.shape).copy()
        Q[:, self._e_bone] = self._e_base @ E[:, :-1]
        C = self._root_carry
        G = E[:, -1]
        r = self.figure.root_bone
        Q[:, r] = C.T @ G @ C @ base[r]
        return Q

    def forward(self, genes: np.ndarray, rigid: bool = True
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Posed heads, tails and frames of every bone for a population.

        Args:
            genes: Gene vectors, shape ``(P, G)``.
            rigid: Also pose the bones below the chain that no gene turns (fingers below
                a hand). Without them (for the stick joints, the gene groups' bones) their
                entries are NaN and the others are the same to the last bit; a figure
                with a stick joint on such a bone always poses them.

        Returns:
            ``(heads (P, n, 3), tails (P, n, 3), frames (P, n, 3, 3))`` in world space.
        """
        heads, tails, frames, _ = self._forward(genes, rigid=rigid)
        return heads, tails, frames

    def forward_rotations(self, genes: np.ndarray, rigid: bool = True,
                          bones: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`forward` plus the local rotations ``(P, n, 3, 3)`` it computed.

        Args:
            genes: Gene vectors, shape ``(P, G)``.
            rigid: As :meth:`forward`.
            bones: Only these bones' local rotations, ``(P, k, 3, 3)`` (the same values
                as those rows of every bone's), or None for every bone.

        Returns:
            ``(heads, tails, frames, Q)`` (:meth:`forward`, :meth:`local_rotations`).
        """
        heads, tails, frames, _, Q = self._forward(genes, rotations=True, rigid=rigid,
                                                   bones=bones)
        return heads, tails, frames, Q

    def _forward(self, genes: np.ndarray, rotations: bool = False, rigid: bool = True,
                 bones: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        """:meth:`forward` plus the group bones' rotation vectors ``(P, entries, 3)``.

        The chain bones (``_chain``) are posed level by level, each frame its parent's
        times a constant and, for a turned bone, times its exponential (see
        :meth:`_factored_levels`), then (``rigid``) the rigid ones (fingers below a hand),
        each its parent's frame times a constant. With ``rotations`` the local rotations
        ``(P, n, 3, 3)`` (of ``bones`` only, ``(P, k, 3, 3)``, when given) follow as a
        fifth item.
        """
        sk = self.skeleton
        x = np.atleast_2d(genes)
        P, n = x.shape[0], sk.n_bones
        rigid = rigid or not self._joints_on_chain
        phi, E = self._exponentials(x)
        turn = E[:, -1] @ self._root_right  # G C Q0_r
        r = self.figure.root_bone
        rest = sk.rest_frames
        t_root = self.base.translations[r] + x[:, :3] @ self._root_hcarry @ rest[r]
        off_r = np.einsum("ij,pj->pi", rest[r], t_root)
        frames = np.empty((P, n, 3, 3))
        heads = np.empty((P, n, 3))
        if not rigid and self._rigid:
            # One contiguous fill: faster than scattering NaN into the rigid bones alone.
            frames.fill(np.nan)
            heads.fill(np.nan)
        for roots, ci, cp, K, w, out, pos, ent, at in self._level_data:
            if roots is not None:
                ri, K0, h0, rpos, rent, rat = roots
                F = np.broadcast_to(K0, (P,) + K0.shape).copy()
                if rpos.size:
                    F[:, rpos] = K0[rpos] @ E[:, rent]
                if rat >= 0:
                    F[:, rat] = K0[rat] @ turn
                frames[:, ri] = F
                heads[:, ri] = h0
                if rat >= 0:
                    heads[:, r] = sk.rest_heads[r] + off_r
            if ci.size:
                Fp = frames[:, cp]
                T = Fp @ K
                if out is not None:
                    T[:, out] = K[out]
                if pos is None:  # every child is a group bone
                    T = T @ E[:, ent]
                elif pos.size:
                    T[:, pos] = T[:, pos] @ E[:, ent]
                if at >= 0:
                    T[:, at] = T[:, at] @ turn
                frames[:, ci] = T
                heads[:, ci] = heads[:, cp] + _frames_times(Fp, w)
                if at >= 0:
                    p = cp[at]
                    rel = (sk.rest_heads[r] - sk.rest_heads[p]) + off_r
                    heads[:, r] = heads[:, p] + np.einsum("pij,pj->pi", Fp[:, at],
                                                          rel @ rest[p])
        for ki, kp, K, w in self._rigid if rigid else ():
            Fp = frames[:, kp]
            frames[:, ki] = Fp @ K
            heads[:, ki] = heads[:, kp] + _frames_times(Fp, w)
        tails = heads + frames[..., 1] * sk.lengths[:, None]
        if rotations:
            return heads, tails, frames, phi, self._rotations(E, bones)
        return heads, tails, frames, phi

    def jacobian(self, genes: np.ndarray) -> tuple[np.ndarray, ...]:
        """Heads, tails and their analytic Jacobians for one gene vector.

        Args:
            genes: Gene vector, shape ``(G,)``.

        Returns:
            ``(heads (n, 3), tails (n, 3), J_heads (n, 3, G), J_tails (n, 3, G))``.
        """
        x = np.asarray(genes, float)
        state = self.posed(x)
        Jh, Jt = self.jacobian_at(x, state)
        return state[0], state[1], Jh, Jt

    def posed(self, genes: np.ndarray) -> tuple[np.ndarray, ...]:
        """The forward pass of one gene vector that :meth:`jacobian_at` continues.

        Args:
            genes: Gene vector, shape ``(G,)``.

        Returns:
            ``(heads (n, 3), tails (n, 3), frames (n, 3, 3), phi (entries, 3))``.
        """
        return tuple(a[0] for a in self._forward(np.asarray(genes, float)[None]))

    def jacobian_at(self, genes: np.ndarray, state: tuple[np.ndarray, ...]
                    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`jacobian`'s Jacobians from a forward pass already made (:meth:`posed`).

        Args:
            genes: Gene vector, shape ``(G,)``.
            state: ``posed(genes)``.

        Returns:
            ``(J_heads (n, 3, G), J_tails (n, 3, G))``.
        """
        x = np.asarray(genes, float)[None]
        Jh, Jt = self.jacobians_at(x, tuple(a[None] for a in state))
        return Jh[0], Jt[0]

    def jacobians_at(self, X: np.ndarray, state: tuple[np.ndarray, ...]
                     ) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians of the posed heads and tails of ``K`` gene vectors at once.

        A gene turning bone ``b`` about the world axis ``w`` moves every point ``p``
        below it by ``w x (p - head_b)``; the root's position genes move every point.

        Args:
            X: Gene vectors, shape ``(K, G)``.
            state: Their forward pass (:meth:`_forward`): heads, tails ``(K, n, 3)``,
                frames ``(K, n, 3, 3)``, rotation vectors ``(K, E, 3)``.

        Returns:
            ``(J_heads (K, n, 3, G), J_tails (K, n, 3, G))``, world units per gene unit.
        """
        heads, tails, frames, phi = state
        K, G = X.shape
        n = self.skeleton.n_bones
        # World axis of every (bone, gene) entry, in group order.
        jr = right_jacobian(np.concatenate([phi, X[:, None, 3:6]], axis=1))  # root's last
        w = frames[:, self._e_bone] @ jr[:, :-1] @ self._e_basis  # (K, E, 3, 3): genes
        axes = np.swapaxes(w, -1, -2)[:, self._e_valid]  # (K, V, 3)
        # Root: dG = [J_l e_k]_x G with J_l = J_r^T, so the axes are the rows of J_r.
        all_axes = np.concatenate([jr[:, -1], axes], axis=1)  # (K, A, 3)
        entry, centre, point, ranks = self._jacobian_tables(G)
        # Moving ``p`` by a turn about ``w`` through ``c``: w x (p - c), only for the
        # (entry, point) pairs the entry moves (a third of them), summed per (gene, point)
        # in entry order (as a product with the entries' one-hot gene matrix sums them).
        a = all_axes[:, entry]
        d = np.concatenate([heads, tails], axis=1)[:, point] - heads[:, centre]
        mov = np.stack([a[..., 1] * d[..., 2] - a[..., 2] * d[..., 1],
                        a[..., 2] * d[..., 0] - a[..., 0] * d[..., 2],
                        a[..., 0] * d[..., 1] - a[..., 1] * d[..., 0]], -1)
        J = np.zeros((K, G * 2 * n, 3))
        target, pairs = ranks[0]
        J[:, target] = mov[:, pairs]
        for target, pairs in ranks[1:]:
            J[:, target] += mov[:, pairs]
        J = J.reshape(K, G, 2 * n, 3)
        J[:, :3] = np.eye(3)[:, None, :]
        J = np.transpose(J, (0, 2, 3, 1))
        return J[:, :n], J[:, n:]

    def _jacobian_tables(self, n_genes: int) -> tuple[np.ndarray, ...]:
        """Constants of :meth:`jacobians_at` (computed once per gene count).

        The rotation-gene entries (the root's three first, then ``_gene_bone``'s) each
        turn one bone and move the heads and tails below it; their moves are summed per
        (gene, head or tail).

        Returns:
            ``(entry, centre, point, ranks)``: per moved (entry, point) pair the entry
            ``(M,)``, the bone it turns about ``(M,)`` and the point (a head ``i`` or the
            tail ``n + i``, ``(M,)``); per rank ``k`` (the ``k``-th entry, ascending, of
            a gene moving a point) the flat indices ``gene * 2n + point`` and the pairs.
        """
        if n_genes not in self._tables:
            r = self.figure.root_bone
            n = self.skeleton.n_bones
            bone = np.concatenate([[r, r, r], self._gene_bone])
            gene = np.concatenate([[3, 4, 5], self._gene_index])
            entry, point = np.nonzero(np.tile(self._desc[bone], (1, 2)))
            flat = gene[entry] * 2 * n + point
            order = np.argsort(flat, kind="stable")  # entries ascending per target
            flat = flat[order]
            first = np.r_[True, flat[1:] != flat[:-1]]
            rank = np.arange(flat.size) - np.maximum.accumulate(
                np.where(first, np.arange(flat.size), 0))
            ranks = tuple((flat[rank == k], order[rank == k])
                          for k in range(int(rank.max(initial=0)) + 1))
            self._tables[n_genes] = (entry, bone[entry], point, ranks)
        return self._tables[n_genes]

    def to_pose(self, genes: np.ndarray) -> Pose:
        """The :class:`Pose` of one gene vector (shape ``(G,)``)."""
        x = np.asarray(genes, float)
        Q, _ = self.local_rotations(x[None])
        t = self.base.translations.copy()
        r = self.figure.root_bone
        t[r] += x[:3] @ self._root_hcarry @ self.skeleton.rest_frames[r]
        return Pose(Q[0], t)
