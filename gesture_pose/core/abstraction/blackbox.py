"""Black-box rigs: Jacobians by finite differences of any rig evaluation (Hahn et al. 2015).

The paper supports arbitrary rigs by evaluating them as black boxes. Here a rig is any
callable mapping a :class:`RigPose` to the abstraction points and representative vertices
(e.g. Blender evaluating constraints, drivers and shape keys); ``J_x`` and ``J_z`` are forward
differences with one evaluation per free parameter, so it is slower than :class:`LbsRig`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..exceptions import InputError
from .parameters import ParameterSpace, RigPose

#: Default finite-difference step (radians, scale units, world units).
DEFAULT_STEP = 1e-4

Evaluator = Callable[[RigPose], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class FiniteDifferenceRig:
    """A rig evaluated as a black box.

    Attributes:
        space: The free parameters.
        evaluator: ``pose -> (abstraction points (m, 3), representative vertices (k, 3))``.
        step: Forward-difference step.
        counter: Number of evaluations so far (one-element list, for diagnostics).
    """

    space: ParameterSpace
    evaluator: Evaluator
    step: float = DEFAULT_STEP
    counter: list = field(default_factory=lambda: [0])

    def with_space(self, space: ParameterSpace) -> FiniteDifferenceRig:
        """The same rig (sharing the evaluation counter) with other free parameters."""
        return replace(self, space=space)

    def evaluate(self, pose: RigPose) -> tuple[np.ndarray, np.ndarray]:
        """Abstraction points ``(m, 3)`` and representative vertices ``(k, 3)``."""
        self.counter[0] += 1
        x, z = self.evaluator(pose)
        x, z = np.asarray(x, dtype=float), np.asarray(z, dtype=float)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(z))):
            raise InputError("The rig evaluated to NaN or infinite positions: check its "
                             "constraints and drivers.")
        return x, z

    def jacobians(self, pose: RigPose) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(x, z, J_x (m, 3, P), J_z (k, 3, P))`` by forward differences."""
        x, z = self.evaluate(pose)
        n = self.space.n_params
        jx = np.empty(x.shape + (n,))
        jz = np.empty(z.shape + (n,))
        for c in range(n):
            e = np.zeros(n)
            e[c] = self.step
            xp, zp = self.evaluate(self.space.step(pose, e))
            jx[..., c] = (xp - x) / self.step
            jz[..., c] = (zp - z) / self.step
        return x, z, jx, jz
