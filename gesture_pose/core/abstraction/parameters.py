"""Rig parameters p of the abstraction solver and their increments (Hahn et al. 2015, Sec. 4).

The parameters are chosen per bone: a rotation (exponential map about the bone's current
local rotation, 3 values), a uniform scale (1 value) and, for root bones, a translation in the
bone's rest axes (3 values, world units). Increments are applied as::

    Q_b <- Q_b exp([omega_b]_x),    s_b <- s_b + sigma_b,    t_b <- t_b + tau_b

so the Jacobians of :mod:`.rig` are those of the current pose, re-linearized at every
Gauss-Newton step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..exceptions import InputError
from ..rotations import exp_map, log_map
from ..skeleton import Pose


@dataclass(frozen=True)
class RigPose:
    """The full state of the rig as the abstraction solver sees it.

    Attributes:
        rotations: Local rotations ``Q``, shape ``(n, 3, 3)``.
        scales: Local uniform scales ``s``, shape ``(n,)``.
        translations: Local translations ``t`` in world units, rest-bone axes, ``(n, 3)``.
    """

    rotations: np.ndarray
    scales: np.ndarray
    translations: np.ndarray

    @classmethod
    def from_pose(cls, pose: Pose, scales: np.ndarray | None = None) -> RigPose:
        """Wrap a core :class:`Pose` (scales default to 1)."""
        n = len(pose.rotations)
        s = np.ones(n) if scales is None else np.asarray(scales, dtype=float)
        return cls(np.asarray(pose.rotations, float), s, np.asarray(pose.translations, float))

    def to_pose(self) -> Pose:
        """The rotations and translations as a core :class:`Pose` (scales dropped)."""
        return Pose(self.rotations.copy(), self.translations.copy())


@dataclass(frozen=True)
class ParameterSpace:
    """Which parameters are free, and their column layout in ``p``.

    Columns are ``[omega of rotation_bones (3 each), sigma of scale_bones (1 each),
    tau of translation_bones (3 each)]``.

    Attributes:
        n_bones: Number of bones of the skeleton.
        rotation_bones: Bones with a free rotation, shape ``(r,)``.
        scale_bones: Bones with a free uniform scale, shape ``(s,)``.
        translation_bones: Root bones with a free translation, shape ``(t,)``.
    """

    n_bones: int
    rotation_bones: np.ndarray
    scale_bones: np.ndarray
    translation_bones: np.ndarray

    @classmethod
    def from_masks(cls, parents: np.ndarray, rotation: np.ndarray,
                   scale: np.ndarray | None = None,
                   translation: np.ndarray | None = None) -> ParameterSpace:
        """Build the space from per-bone masks.

        Args:
            parents: Parent index per bone, shape ``(n,)``.
            rotation: Bones whose rotation is free, shape ``(n,)`` bool.
            scale: Bones whose scale is free, shape ``(n,)`` bool (none when None).
            translation: Bones whose translation is free, shape ``(n,)`` bool; only roots
                may translate (none when None).

        Raises:
            InputError: No free parameter, or a translated bone that is not a root.
        """
        n = len(parents)
        masks = []
        for m in (rotation, scale, translation):
            m = np.zeros(n, bool) if m is None else np.asarray(m, dtype=bool)
            if m.shape != (n,):
                raise InputError(f"Parameter masks must have shape ({n},), got {m.shape}.")
            masks.append(np.flatnonzero(m))
        if np.any(np.asarray(parents)[masks[2]] >= 0):
            raise InputError("Only root bones can have a free translation: untick "
                             "translation or pick the root.")
        space = cls(n, *masks)
        if space.n_params == 0:
            raise InputError("No rig parameter is free: enable rotations, scales or the root "
                             "translation, or unpin some bones.")
        return space

    @property
    def n_params(self) -> int:
        """Number of free parameters ``P``."""
        return 3 * self.rotation_bones.size + self.scale_bones.size \
            + 3 * self.translation_bones.size

    @property
    def scale_columns(self) -> np.ndarray:
        """Columns of the scale increments, shape ``(s,)``."""
        start = 3 * self.rotation_bones.size
        return np.arange(start, start + self.scale_bones.size)

    @property
    def column_bones(self) -> np.ndarray:
        """The bone of every column of ``p``, shape ``(P,)``."""
        return np.concatenate([np.repeat(self.rotation_bones, 3), self.scale_bones,
                               np.repeat(self.translation_bones, 3)]).astype(int)

    def restrict(self, bones: np.ndarray) -> tuple[ParameterSpace, np.ndarray]:
        """The parameters of ``bones`` only.

        Args:
            bones: Bone indices to keep free, ``(b,)``.

        Returns:
            ``(space, columns)``: the smaller space and, for each of its columns, the
            column of ``self`` it comes from (same order), ``(P',)``.
        """
        keep = np.zeros(self.n_bones, dtype=bool)
        keep[np.asarray(bones, dtype=int)] = True
        rb, sb, tb = self.rotation_bones, self.scale_bones, self.translation_bones
        sub = ParameterSpace(self.n_bones, rb[keep[rb]], sb[keep[sb]], tb[keep[tb]])
        return sub, np.flatnonzero(keep[self.column_bones])

    def split(self, dp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Split ``dp`` (shape ``(P,)``) into ``omega (r, 3)``, ``sigma (s,)``, ``tau (t, 3)``."""
        dp = np.asarray(dp, dtype=float)
        if dp.shape != (self.n_params,):
            raise InputError(f"Expected {self.n_params} parameters, got shape {dp.shape}.")
        r, s = 3 * self.rotation_bones.size, self.scale_bones.size
        return dp[:r].reshape(-1, 3), dp[r:r + s], dp[r + s:].reshape(-1, 3)

    def step(self, pose: RigPose, dp: np.ndarray) -> RigPose:
        """Apply the increment ``dp`` (shape ``(P,)``) to ``pose``."""
        omega, sigma, tau = self.split(dp)
        rot = pose.rotations.copy()
        rot[self.rotation_bones] = rot[self.rotation_bones] @ exp_map(omega)
        scales = pose.scales.copy()
        scales[self.scale_bones] += sigma
        trans = pose.translations.copy()
        trans[self.translation_bones] += tau
        return RigPose(rot, scales, trans)

    def deviation(self, start: RigPose, pose: RigPose) -> np.ndarray:
        """Parameters of ``pose`` relative to ``start`` in increment coordinates, ``(P,)``.

        Rotations: ``log(Q_start^T Q)`` (the increment that leads from ``start`` to ``pose``);
        scales and translations: differences.
        """
        rb, sb, tb = self.rotation_bones, self.scale_bones, self.translation_bones
        rel = np.swapaxes(start.rotations[rb], 1, 2) @ pose.rotations[rb]
        return np.concatenate([log_map(rel).ravel(), pose.scales[sb] - start.scales[sb],
                               (pose.translations[tb] - start.translations[tb]).ravel()])

    def describe(self, names: tuple[str, ...], column: int) -> str:
        """A readable name of parameter ``column`` (e.g. ``"forearm.L rot y"``)."""
        r, s = 3 * self.rotation_bones.size, self.scale_bones.size
        if column < r:
            return f"{names[self.rotation_bones[column // 3]]} rot {'xyz'[column % 3]}"
        if column < r + s:
            return f"{names[self.scale_bones[column - r]]} scale"
        c = column - r - s
        return f"{names[self.translation_bones[c // 3]]} loc {'xyz'[c % 3]}"
