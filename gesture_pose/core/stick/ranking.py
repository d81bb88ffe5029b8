"""Ranking depth interpretations: the plausibility score of a pose that fits the drawing.

One view leaves every limb's depth ambiguous: a bone can point towards the viewer or
away from it and project onto the same drawn line. The drawing terms of Eqs. 4-6 barely
tell such flips apart (they reproject equally well), so suggestions are ordered by

``S = E + w_f F``

- ``E``: the objective (:class:`.objective.StickObjective`): projection, balance,
  attachment, collision (Eqs. 4-11) and joint comfort. A flip that sends a limb through
  the body or the seat, the centre of mass off the support polygon, or a joint towards
  the end of its range of motion (an arm thrown behind the back, a head turned far away)
  ranks below one that does not.
- ``F`` (foreshortening the drawing does not show): for every drawn stick edge,
  ``((l_proj - min(l_drawn, l_full)) / l_full)^2`` with ``l_proj`` the projected length
  of the posed 3D edge, ``l_drawn`` the drawn one and ``l_full`` the projection of the
  whole edge at its depth if it lay in the view plane. A bone drawn at full length must
  lie in the view plane; a bone drawn short must turn out of it by just as much. Eqs. 4-6
  weigh directions and (with ``w = 0.1``) positions only, so lengths are otherwise barely
  constrained.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .objective import StickObjective, project_jacobian


@dataclass(frozen=True)
class RankWeights:
    """Weight of the foreshortening term (the energy's weight is 1).

    Attributes:
        foreshortening: Weight of ``F`` (dimensionless, squared length fractions).
        balance: Extra weight of the balance term (Eqs. 7-8) on top of the energy's.
    """

    foreshortening: float = 0.05
    balance: float = 5.0


def foreshortening(objective: StickObjective, joints: np.ndarray) -> np.ndarray:
    """Foreshortening the drawing does not show, ``F``, for posed stick joints.

    Args:
        objective: Provides the camera and the drawing.
        joints: World stick joints, shape ``(P, J, 3)``.

    Returns:
        ``F`` per individual, shape ``(P,)``: the sum over drawn edges of
        ``((l_proj - min(l_drawn, l_full)) / l_full)^2``.
    """
    q, _ = project_jacobian(objective.camera, joints, jacobian=False)
    return np.sum(objective.foreshortening_residuals(joints, q) ** 2, axis=-1)


def plausibility(objective: StickObjective, genes: np.ndarray,
                 weights: RankWeights = RankWeights(), collision: bool = True
                 ) -> tuple[np.ndarray, dict]:
    """The ranking score ``S = E + w_f F`` of a population (lower ranks first).

    Args:
        objective: The energy (Eqs. 4-11 and joint comfort).
        genes: Gene vectors, shape ``(P, G)``.
        weights: Weight of ``F``.
        collision: Include the collision energy (Eq. 11) in ``E``.

    Returns:
        ``(S (P,), terms)``: the energy's terms (:meth:`.StickObjective.evaluate`) plus
        ``"energy"`` and ``"foreshortening"``, each ``(P,)``.
    """
    x = np.atleast_2d(genes)
    posed = objective.pose(x, collision)  # posed once: evaluate reads it too
    heads, tails = posed[:2]
    energy, terms = objective.evaluate(x, collision, posed=posed)
    f = foreshortening(objective, objective.model.figure.joint_positions(heads, tails))
    score = energy + weights.foreshortening * f + weights.balance * terms["balance"]
    return score, {**terms, "energy": energy, "foreshortening": f}
