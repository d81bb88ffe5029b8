"""What one solve phase settles before iterating: checked strokes, matches, moving bones.

:func:`prepare_phase` runs the checks of :mod:`.checks` on the start of a solve (strokes far
from the character are refused, curves seen end-on are refused or reported), assigns the
strokes to curves, and restricts the rig to the bones the drawing constrains (Sec. 4 of
Hahn et al. 2015 regularizes the other bones with ``W_pose``; here they are kept exactly,
so they are neither changed nor keyed).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..exceptions import InputError
from .checks import (
    TINY_FRACTION,
    check_strokes_near,
    constrained_bones,
    drawn_bones,
    end_on_bones,
    end_on_message,
    limb_bones,
)
from .correspondences import assign_strokes
from .curves import CurveLayout, polyline_arclength
from .parameters import RigPose
from .rig import pose_bones

if TYPE_CHECKING:
    from .solver import AbstractionProblem, SolveOptions

#: Only the bones drawn on (and between them) move.
MOVE_DRAWN = "DRAWN"
#: Also their limb: the bones above them up to the first bone with several children.
MOVE_DRAWN_AND_LIMB = "DRAWN_AND_LIMB"
#: Also the bones above them (every bone whose rotation moves a matched point).
MOVE_DRAWN_AND_PARENTS = "DRAWN_AND_PARENTS"


@dataclass(frozen=True)
class PhaseInput:
    """The settled input of a solve phase.

    Attributes:
        pairs: ``(curve, stroke)`` pairs.
        rows: Abstraction points of the matched curves, ``(q,)``.
        rig: The rig restricted to the moving bones.
        frozen: Names of the free bones kept as they were.
        jacobians: ``(x, z, J_x, J_z)`` at the start, columns of the moving bones.
        warnings: Notes (bones seen end-on).
    """

    pairs: tuple[tuple[int, int], ...]
    rows: np.ndarray
    rig: Any
    frozen: tuple[str, ...]
    jacobians: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    warnings: tuple[str, ...]


def matched_rows(layout: CurveLayout, pairs: tuple[tuple[int, int], ...]) -> np.ndarray:
    """Indices of the abstraction points on the matched curves, ``(q,)``."""
    return np.concatenate([np.arange(layout.offsets[c], layout.offsets[c + 1])
                           for c, _ in pairs])


def bone_view(problem: AbstractionProblem):
    """``(skeleton, point weights (m, n))`` of the problem when known, else None."""
    skel = problem.skeleton if problem.skeleton is not None else getattr(
        problem.rig, "skeleton", None)
    weights = problem.point_weights
    if weights is None and hasattr(problem.rig, "abstraction_rest"):
        weights = problem.rig.abstraction_rest[:, :, 3]
    return None if skel is None or weights is None else (skel, np.asarray(weights, float))


def end_on_names(problem: AbstractionProblem, pose: RigPose, rows: np.ndarray) -> list[str]:
    """Names of the matched points' dominant bones that point along the view axis."""
    view = bone_view(problem)
    if view is None:
        return []
    skel, weights = view
    posed = pose_bones(skel, pose)
    tails = posed.heads + posed.world[:, :3, 1] * skel.lengths[:, None]
    drawn = np.unique(np.argmax(weights[rows], axis=1))
    drawn = drawn[skel.lengths[drawn] > 1e-9]
    return [skel.names[b] for b in end_on_bones(problem.camera, posed.heads, tails, drawn)]


def _moving_bones(problem: AbstractionProblem, jac_matched: np.ndarray, space, rows,
                  mode: str) -> np.ndarray:
    """Bones whose parameters stay free (see :data:`MOVE_DRAWN`)."""
    modes = (MOVE_DRAWN, MOVE_DRAWN_AND_LIMB, MOVE_DRAWN_AND_PARENTS)
    if mode not in modes:
        raise InputError(f"Unknown bone choice '{mode}': use one of {', '.join(modes)}.")
    seen = constrained_bones(jac_matched, space)
    view = bone_view(problem)
    if mode != MOVE_DRAWN_AND_PARENTS and view is not None:
        drawn = drawn_bones(view[1][rows], view[0].parents)
        if mode == MOVE_DRAWN_AND_LIMB:
            drawn = limb_bones(drawn, view[0].parents)
        seen = np.intersect1d(seen, drawn)
    return seen


def prepare_phase(problem: AbstractionProblem, pose: RigPose, x: np.ndarray, z: np.ndarray,
                  opt: SolveOptions) -> PhaseInput:
    """Check the input at the start pose, assign strokes and pick the moving bones.

    Args:
        problem: The problem.
        pose: The start pose (inside its limits).
        x: Abstraction points at ``pose``, ``(m, 3)``.
        z: Representative vertices at ``pose``, ``(k, 3)``.
        opt: Solver settings (assignment, which bones move).

    Raises:
        InputError: A stroke is far from the character, the matched curves project to
            almost nothing, or no moving bone is left.
    """
    cam, layout, rig = problem.camera, problem.layout, problem.rig
    px = cam.project(x)
    size = check_strokes_near(np.concatenate([px, cam.project(z)]), problem.strokes,
                              problem.stroke_labels)
    curves = [px[layout.curve(i)] for i in range(layout.n_curves)]
    pairs = assign_strokes(curves, list(problem.strokes), opt.assignment)
    if max(polyline_arclength(curves[c])[-1] for c, _ in pairs) < TINY_FRACTION * size:
        raise InputError("The abstraction curves matched to the strokes project to almost "
                         "nothing in this view (they point at you): turn the view so the "
                         "part to pose is seen from the side. Nothing was changed.")
    rows = matched_rows(layout, pairs)
    names = end_on_names(problem, pose, rows)
    warnings = (end_on_message(names, after=False),) if names else ()
    space = rig.space
    jac = rig.jacobians(pose)
    moving = _moving_bones(problem, jac[2][rows], space, rows, opt.moved_bones)
    if moving.size == 0:
        raise InputError("The strokes only match curves of bones that cannot move (pinned "
                         "or not free): unpin them or free their parameters.")
    frozen = tuple(problem.names[b] for b in np.setdiff1d(space.column_bones, moving))
    if frozen:
        space, cols = space.restrict(moving)
        rig = rig.with_space(space)
        jac = (jac[0], jac[1], jac[2][..., cols], jac[3][..., cols])
    return PhaseInput(pairs, rows, rig, frozen, jac, warnings)
