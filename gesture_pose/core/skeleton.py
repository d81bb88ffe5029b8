"""Skeletons, poses and vectorized forward kinematics.

Rest data is in world space with the armature object's transform baked in; only uniform
object scale is supported. For bone ``i`` with parent ``p``, rest frames ``R`` (columns are
the bone's x, y, z axes, y from head to tail), rest heads ``r``, local rotations ``Q`` and
local translations ``t`` (world units, in the bone's rest axes), the posed world frame and
head are (Blender's pose-matrix recursion)::

    F_i = F_p R_p^T R_i Q_i                       (F_i = R_i Q_i for roots)
    h_i = h_p + F_p R_p^T (r_i - r_p + R_i t_i)   (h_i = r_i + R_i t_i for roots)
    tail_i = h_i + length_i * F_i[:, 1]

Bones whose ``inherit_rotation`` is False take ``F_i = R_i Q_i`` but still follow the
parent's head motion.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .exceptions import InputError
from .rotations import normalize, swing_twist
from .rotations3 import mul, mv, reswing


@dataclass(frozen=True)
class Pose:
    """Local transforms of every bone relative to its rest frame.

    Attributes:
        rotations: Local rotations ``Q``, shape ``(n, 3, 3)``.
        translations: Local translations ``t`` in world units, in rest-bone axes, ``(n, 3)``.
    """

    rotations: np.ndarray
    translations: np.ndarray

    @classmethod
    def identity(cls, n: int) -> Pose:
        """The rest pose of ``n`` bones."""
        return cls(np.tile(np.eye(3), (n, 1, 1)), np.zeros((n, 3)))

    def with_rotations(self, indices: np.ndarray, rotations: np.ndarray) -> Pose:
        """Return a copy with the rotations of ``indices`` replaced.

        Args:
            indices: Bone indices, shape ``(k,)``.
            rotations: New local rotations, shape ``(k, 3, 3)``.
        """
        rot = self.rotations.copy()
        rot[np.asarray(indices, dtype=int)] = rotations
        return Pose(rot, self.translations.copy())


@dataclass(frozen=True)
class PoseState:
    """World-space result of forward kinematics.

    Attributes:
        heads: Bone heads, shape ``(n, 3)``.
        tails: Bone tails, shape ``(n, 3)``.
        frames: Posed world frames ``F``, shape ``(n, 3, 3)``.
    """

    heads: np.ndarray
    tails: np.ndarray
    frames: np.ndarray


@dataclass(frozen=True)
class Skeleton:
    """A bone hierarchy with its rest pose in world space.

    Attributes:
        names: Bone names, parents before children.
        parents: Parent index per bone, -1 for roots, shape ``(n,)``.
        rest_heads: Rest heads, shape ``(n, 3)``, world units.
        rest_tails: Rest tails, shape ``(n, 3)``, world units.
        rest_frames: Rest frames ``R`` (orthonormal, columns x, y, z), shape ``(n, 3, 3)``.
        inherit_rotation: Whether each bone inherits its parent's rotation, shape ``(n,)``.
        connected: Whether each bone's head sits on its parent's tail, shape ``(n,)``.
        deform: Whether each bone deforms a mesh, shape ``(n,)``.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    rest_heads: np.ndarray
    rest_tails: np.ndarray
    rest_frames: np.ndarray
    inherit_rotation: np.ndarray
    connected: np.ndarray
    deform: np.ndarray
    _levels: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)
    _ancestry: np.ndarray = field(init=False, repr=False, compare=False)
    _fk: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Validate shapes and parent order, then cache the per-depth bone groups."""
        n = len(self.names)
        for attr, shape in (
            ("parents", (n,)),
            ("rest_heads", (n, 3)),
            ("rest_tails", (n, 3)),
            ("rest_frames", (n, 3, 3)),
            ("inherit_rotation", (n,)),
            ("connected", (n,)),
            ("deform", (n,)),
        ):
            value = np.asarray(getattr(self, attr))
            if value.shape != shape:
                raise InputError(f"Skeleton.{attr} must have shape {shape}, got {value.shape}.")
        if n == 0:
            raise InputError("The armature has no bones.")
        for attr in ("rest_heads", "rest_tails", "rest_frames"):
            if not np.all(np.isfinite(getattr(self, attr))):
                raise InputError(f"Skeleton.{attr} contains NaN or infinite values.")
        parents = np.asarray(self.parents, dtype=int)
        if np.any(parents >= np.arange(n)):
            raise InputError("Skeleton bones must be ordered parents before children.")
        depth = np.zeros(n, dtype=int)
        for i in range(n):
            depth[i] = 0 if parents[i] < 0 else depth[parents[i]] + 1
        levels = tuple(np.flatnonzero(depth == d) for d in range(depth.max() + 1))
        ancestry = np.eye(n, dtype=bool)  # ancestry[i, j]: j is i or an ancestor of i
        for level in levels[1:]:
            ancestry[level] |= ancestry[parents[level]]
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "_levels", levels)
        object.__setattr__(self, "_ancestry", ancestry)
        object.__setattr__(self, "_fk", self._forward_tables())

    def _forward_tables(self) -> tuple:
        """Constant parts of forward kinematics, computed once.

        Returns:
            ``(rel_rot (n, 3, 3), rel_off (n, 3), steps, lengths (n,), children, order)``
            where ``rel_rot_i = R_p^T R_i`` and ``rel_off_i = R_p^T (r_i - r_p)`` (``R_i``
            and ``r_i`` for roots), ``steps`` holds ``(children, parents, children that do
            not inherit rotation)`` per tree depth, and ``order`` is ``((bone, parent,
            free), ...)`` parents first, with ``rel_rot`` and the rest frames as nested
            lists, for :meth:`_forward_floats`.
        """
        rest = np.asarray(self.rest_frames, dtype=float)
        heads = np.asarray(self.rest_heads, dtype=float)
        p = self.parents
        has_parent = p >= 0
        par_rest = np.where(has_parent[:, None, None], rest[np.maximum(p, 0)], np.eye(3))
        par_head = np.where(has_parent[:, None], heads[np.maximum(p, 0)], 0.0)
        rel_rot = np.swapaxes(par_rest, 1, 2) @ rest
        rel_off = np.einsum("nji,nj->ni", par_rest, heads - par_head)
        free = has_parent & ~np.asarray(self.inherit_rotation, bool)
        steps = []
        for level in self._levels:
            kids = level[has_parent[level]]
            if kids.size:
                steps.append((kids, p[kids], kids[free[kids]]))
        lengths = np.linalg.norm(np.asarray(self.rest_tails, float) - heads, axis=1)
        kids = tuple(np.flatnonzero(p == i) for i in range(len(p)))
        order = [(i, -1, False) for i in np.flatnonzero(~has_parent).tolist()]
        for k, par, _ in steps:
            order += [(i, j, bool(free[i])) for i, j in zip(k.tolist(), par.tolist(),
                                                             strict=True)]
        floats = (tuple(order), rel_rot.tolist(), rest.tolist())
        return rel_rot, rel_off, tuple(steps), lengths, kids, floats

    @property
    def rest_relative(self) -> tuple[np.ndarray, np.ndarray]:
        """Rest rotation and head offset of each bone in its parent's rest frame.

        Returns:
            ``(R_p^T R_i (n, 3, 3), R_p^T (r_i - r_p) (n, 3))``; ``R_i`` and ``r_i`` for
            roots. Read-only views: do not modify.
        """
        return self._fk[0], self._fk[1]

    @property
    def rest_relative_lists(self) -> tuple[list, list]:
        """:attr:`rest_relative`'s rotations and the rest frames as nested Python lists.

        For the per-bone loops on floats; computed once. Do not modify.

        Returns:
            ``(R_p^T R_i, R_i)``, ``n`` nested 3x3 lists each.
        """
        return self._fk[5][1], self._fk[5][2]

    @property
    def n_bones(self) -> int:
        """Number of bones."""
        return len(self.names)

    @property
    def lengths(self) -> np.ndarray:
        """Bone lengths, shape ``(n,)``, world units."""
        return self._fk[3].copy()

    def index(self, name: str) -> int:
        """Index of the bone called ``name``.

        Raises:
            InputError: No bone has that name.
        """
        try:
            return self.names.index(name)
        except ValueError:
            raise InputError(f"The armature has no bone named '{name}'.") from None

    def children(self, i: int) -> np.ndarray:
        """Indices of the direct children of bone ``i``, shape ``(k,)`` (do not modify)."""
        return self._fk[4][i]

    def ancestors(self, i: int) -> list[int]:
        """Bone ``i`` and its ancestors, from ``i`` up to its root."""
        out = [i]
        while self.parents[out[-1]] >= 0:
            out.append(int(self.parents[out[-1]]))
        return out

    def descendants(self, i: int) -> np.ndarray:
        """Bone ``i`` and every bone below it, in skeleton order, shape ``(k,)``."""
        return np.flatnonzero(self._ancestry[:, i])

    def forward(self, pose: Pose) -> PoseState:
        """Forward kinematics: per tree depth, or bone by bone for long chains.

        Args:
            pose: Local rotations and translations of every bone.

        Returns:
            World-space heads, tails and frames.
        """
        rel_rot, rel_off, steps = self._fk[:3]
        q = np.asarray(pose.rotations, dtype=float)
        offsets = rel_off + np.einsum("nij,nj->ni", rel_rot, np.asarray(pose.translations,
                                                                        dtype=float))
        if 3 * len(steps) > self.n_bones:  # long chains: numpy's per-depth calls dominate
            return self._forward_floats(q, offsets)
        return self._forward_levels(q, offsets)

    def _forward_levels(self, q: np.ndarray, offsets: np.ndarray) -> PoseState:
        """:meth:`forward` vectorized over the bones of each tree depth.

        Args:
            q: Local rotations, shape ``(n, 3, 3)``.
            offsets: Heads in their parents' posed frames (world for roots), ``(n, 3)``.

        Returns:
            World-space heads, tails and frames.
        """
        rel_rot, steps = self._fk[0], self._fk[2]
        # einsum, not matmul: numpy hands batched 3x3 products to BLAS, whose thread pool
        # makes each per-depth call slow on a busy machine.
        frames = np.einsum("nij,njk->nik", rel_rot, q)  # final for roots: R_i Q_i
        heads = offsets.copy()  # final for roots: r_i + R_i t_i
        for kids, pars, free in steps:
            heads[kids] = heads[pars] + np.einsum("nij,nj->ni", frames[pars], offsets[kids])
            frames[kids] = np.einsum("nij,njk->nik", frames[pars], frames[kids])
            if free.size:
                frames[free] = self.rest_frames[free] @ q[free]
        tails = heads + frames[:, :, 1] * self._fk[3][:, None]
        return PoseState(heads, tails, frames)

    def _forward_floats(self, q: np.ndarray, offsets: np.ndarray) -> PoseState:
        """:meth:`forward` bone by bone on Python floats.

        For skeletons with few bones per tree depth (chains), where numpy's per-depth calls
        cost more than the arithmetic.

        Args:
            q: Local rotations, shape ``(n, 3, 3)``.
            offsets: Heads in their parents' posed frames (world for roots), ``(n, 3)``.

        Returns:
            World-space heads, tails and frames.
        """
        order, rel_rot, rest = self._fk[5]
        ql, off = q.tolist(), offsets.tolist()
        frames: list = [None] * len(ql)
        heads: list = [None] * len(ql)
        for i, p, free in order:
            if p < 0:
                frames[i], heads[i] = mul(rel_rot[i], ql[i]), off[i]
                continue
            frames[i] = mul(rest[i] if free else mul(frames[p], rel_rot[i]), ql[i])
            (x, y, z), (dx, dy, dz) = heads[p], mv(frames[p], off[i])
            heads[i] = [x + dx, y + dy, z + dz]
        f, h = np.array(frames), np.array(heads)
        return PoseState(h, h + f[:, :, 1] * self._fk[3][:, None], f)

    def parent_carry(self, i: int, state: PoseState) -> np.ndarray:
        """The rotation ``C`` with ``F_i = C Q_i`` for bone ``i`` in ``state``.

        Args:
            i: Bone index.
            state: Forward kinematics of the current pose (only the parent is used).

        Returns:
            Rotation matrix, shape ``(3, 3)``.
        """
        p = self.parents[i]
        if p < 0 or not self.inherit_rotation[i]:
            return self.rest_frames[i]
        return state.frames[p] @ self.rest_frames[p].T @ self.rest_frames[i]

    def local_rotation_for_frame(self, i: int, frame: np.ndarray, state: PoseState) -> np.ndarray:
        """Local rotation ``Q_i`` that gives bone ``i`` the world frame ``frame``.

        Args:
            i: Bone index.
            frame: Desired world frame of bone ``i``, shape ``(3, 3)``.
            state: Forward kinematics of a pose holding the desired parent frame.

        Returns:
            Local rotation, shape ``(3, 3)``.
        """
        return self.parent_carry(i, state).T @ frame

    def aim_local(
        self, i: int, direction: np.ndarray, state: PoseState, current: np.ndarray
    ) -> np.ndarray:
        """Local rotation pointing bone ``i`` along ``direction`` with its twist kept.

        The local rotation is written as ``Q = S T`` (swing-twist about the bone's y axis).
        The new rotation is computed directly, not compounded: ``S`` is the smallest
        rotation taking y to the target direction expressed in the parent-carried frame,
        and ``T`` is the twist of ``current``, so the twist about the bone survives any
        number of strokes and views.

        Args:
            i: Bone index.
            direction: Desired world direction of the bone (any length > 0), shape ``(3,)``.
            state: Forward kinematics of a pose holding the desired parent frame.
            current: The bone's current local rotation, shape ``(3, 3)``.

        Returns:
            Local rotation ``Q_i``, shape ``(3, 3)``.
        """
        local_dir = self.parent_carry(i, state).T @ normalize(np.asarray(direction, float))
        return reswing(np.asarray(current, float), local_dir)

    def twist_angles(self, pose: Pose) -> np.ndarray:
        """Twist of every local rotation about the bone's own y axis, radians, ``(n,)``."""
        return swing_twist(pose.rotations, np.array([0.0, 1.0, 0.0]))[1]
