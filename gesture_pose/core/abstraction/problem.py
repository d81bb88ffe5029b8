"""Assemble abstraction and draw-over problems from rig, mesh and stroke data.

These builders do the set-up of Hahn et al. 2015 once per solve: rest data of the rigged
abstraction points (the inverse of the current skinning, so any current pose works),
arc-length resampling of the curves, k-means coarsening of the mesh (Eq. 12), and the rig
model (analytic LBS, Eq. 13, or a black-box evaluator with finite differences).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..camera import Camera
from ..exceptions import InputError
from ..skeleton import Skeleton
from ..stroke import Stroke
from .blackbox import FiniteDifferenceRig
from .checks import TINY_FRACTION
from .coarsening import DEFAULT_K, Coarsening, coarsen
from .curves import DEFAULT_POINT_BUDGET, CurveLayout, resample_rigged, resampling_matrix
from .drawover import SurfaceCurve, project_onto_mesh
from .parameters import ParameterSpace, RigPose
from .rig import LbsRig, lbs_weighted_rest, pose_bones
from .solver import AbstractionProblem


def rest_from_posed(skeleton: Skeleton, pose: RigPose, points: np.ndarray,
                    weights: np.ndarray) -> np.ndarray:
    """Rest positions of skinned points seen at ``pose``: ``zbar = (sum_j w_j G_j)^-1 x``.

    Args:
        skeleton: The rest skeleton.
        pose: The pose the points were read at.
        points: Posed world positions, shape ``(m, 3)``.
        weights: Normalized bone weights, shape ``(m, n)``.

    Returns:
        Rest positions, shape ``(m, 3)``.
    """
    blend = np.einsum("mn,nij->mij", weights, pose_bones(skeleton, pose).skinning)
    homo = np.concatenate([points, np.ones((len(points), 1))], axis=1)
    return np.linalg.solve(blend, homo[:, :, None])[:, :3, 0]


def lbs_mismatch(skeleton: Skeleton, pose: RigPose, rest: np.ndarray, weights: np.ndarray,
                 deformed: np.ndarray) -> float:
    """Largest distance between LBS of ``rest`` at ``pose`` and the rig's ``deformed`` vertices.

    A large value means the rig is not plain LBS (constraints, drivers, shape keys): use the
    black-box path.
    """
    weighted = weights.sum(axis=1) > 0
    if not np.any(weighted):
        return 0.0
    y = lbs_weighted_rest(rest[weighted], weights[weighted])
    skinned = np.einsum("nij,mnj->mi", pose_bones(skeleton, pose).skinning[:, :3, :], y)
    return float(np.linalg.norm(skinned - deformed[weighted], axis=1).max())


def _representatives(deformed: np.ndarray, weights: np.ndarray, k: int
                     ) -> tuple[Coarsening, np.ndarray]:
    """k-means representatives of the weighted mesh vertices (Eq. 12).

    Args:
        deformed: Mesh vertices at the current pose, ``(V, 3)``.
        weights: Their bone weights, ``(V, n)``; unweighted vertices are left out.
        k: Number of representatives.

    Returns:
        ``(coarsening, vertex index of each representative (k,))``.

    Raises:
        InputError: No vertex has bone weights.
    """
    weighted = np.flatnonzero(weights.sum(axis=1) > 0)
    if weighted.size == 0:
        raise InputError("The character's mesh has no bone weights: skin it to the armature.")
    coarse = coarsen(deformed[weighted], k=k, weights=weights[weighted])
    return coarse, weighted[coarse.indices]


def build_lbs_problem(skeleton: Skeleton, start: RigPose, space: ParameterSpace,
                      camera: Camera, strokes: Sequence[Stroke], curve_points: np.ndarray,
                      curve_weights: np.ndarray, layout: CurveLayout, mesh_rest: np.ndarray,
                      mesh_deformed: np.ndarray, mesh_weights: np.ndarray, k: int = DEFAULT_K,
                      budget: int = DEFAULT_POINT_BUDGET,
                      stroke_labels: Sequence[str] = ()) -> AbstractionProblem:
    """An abstraction problem on the analytic LBS rig.

    Args:
        skeleton: The rest skeleton.
        start: The current pose.
        space: Free parameters.
        camera: The view the strokes were drawn in.
        strokes: Target strokes (pixels), oldest first.
        curve_points: Raw abstraction points at the current pose, ``(m_raw, 3)`` world.
        curve_weights: Their bone weights, ``(m_raw, n)``.
        layout: Curves of the raw points.
        mesh_rest: Mesh rest vertices, ``(V, 3)`` world.
        mesh_deformed: Mesh vertices at the current pose, ``(V, 3)``.
        mesh_weights: Mesh bone weights, ``(V, n)`` (unweighted rows are skipped).
        k: Representative vertices (Eq. 12).
        budget: Abstraction points after resampling.
        stroke_labels: Names of the strokes for messages.

    Returns:
        The problem.
    """
    w = np.asarray(curve_weights, dtype=float)
    if np.any(w.sum(axis=1) <= 1e-12):
        raise InputError("Some abstraction points have no bone weights: add vertex groups, "
                         "parent the abstraction to a bone, or use the black-box path.")
    w = w / w.sum(axis=1, keepdims=True)
    rest = rest_from_posed(skeleton, start, np.asarray(curve_points, float), w)
    mat, new_layout = resampling_matrix(curve_points, layout, budget)
    y_abs = resample_rigged(lbs_weighted_rest(rest, w), mat)
    coarse, rep_idx = _representatives(mesh_deformed, mesh_weights, k)
    y_rep = lbs_weighted_rest(mesh_rest[rep_idx], mesh_weights[rep_idx])
    rig = LbsRig(skeleton, space, y_abs, y_rep)
    return AbstractionProblem(rig, skeleton.names, camera, new_layout, tuple(strokes), coarse,
                              start, tuple(stroke_labels))


def build_blackbox_problem(names: tuple[str, ...], start: RigPose, space: ParameterSpace,
                           camera: Camera, strokes: Sequence[Stroke],
                           evaluate_raw: Callable[[RigPose], tuple[np.ndarray, np.ndarray]],
                           layout: CurveLayout, mesh_deformed: np.ndarray,
                           mesh_weights: np.ndarray | None = None, k: int = DEFAULT_K,
                           budget: int = DEFAULT_POINT_BUDGET,
                           step: float = 1e-4, skeleton: Skeleton | None = None,
                           curve_weights: np.ndarray | None = None,
                           stroke_labels: Sequence[str] = ()) -> AbstractionProblem:
    """An abstraction problem on a black-box rig (finite differences).

    Args:
        names: Bone names.
        start: The current pose.
        space: Free parameters.
        camera: The view.
        strokes: Target strokes (pixels).
        evaluate_raw: ``pose -> (raw abstraction points (m_raw, 3), all mesh vertices
            (V, 3))`` evaluated by the host application.
        layout: Curves of the raw points.
        mesh_deformed: Mesh vertices at ``start``, ``(V, 3)``.
        mesh_weights: Mesh bone weights ``(V, n)`` to skip unweighted vertices (all used
            when None).
        k: Representative vertices.
        budget: Abstraction points after resampling.
        step: Finite-difference step.
        skeleton: The skeleton (for the end-on check), optional.
        curve_weights: Bone weights of the raw points ``(m_raw, n)``, optional: with them
            only the bones drawn on move (see :data:`.inputs.MOVE_DRAWN`), without them
            every bone whose parameters move a matched point.
        stroke_labels: Names of the strokes for messages.

    Returns:
        The problem.
    """
    weights = np.ones((len(mesh_deformed), 1)) if mesh_weights is None else mesh_weights
    coarse, rep_idx = _representatives(mesh_deformed, weights, k)
    raw0, _ = evaluate_raw(start)
    mat, new_layout = resampling_matrix(raw0, layout, budget)

    def evaluator(pose: RigPose) -> tuple[np.ndarray, np.ndarray]:
        """Resampled abstraction points ``(m, 3)`` and representatives ``(k, 3)``."""
        raw, verts = evaluate_raw(pose)
        return np.asarray(mat @ raw), np.asarray(verts)[rep_idx]

    rig = FiniteDifferenceRig(space, evaluator, step=step)
    point_weights = None
    if curve_weights is not None:
        w = np.asarray(curve_weights, dtype=float)
        point_weights = np.asarray(mat @ (w / np.maximum(w.sum(axis=1, keepdims=True),
                                                         1e-12)))
    return AbstractionProblem(rig, names, camera, new_layout, tuple(strokes), coarse, start,
                              tuple(stroke_labels), skeleton, point_weights)


def drawover_curve(source: Stroke, camera: Camera, mesh_deformed: np.ndarray,
                   triangles: np.ndarray, mesh_weights: np.ndarray) -> SurfaceCurve:
    """Project the source stroke onto the weighted part of the deformed mesh.

    Raises:
        InputError: The stroke is not over a skinned part of the character.
    """
    weighted = mesh_weights.sum(axis=1) > 0
    tris = np.asarray(triangles, dtype=int)
    tris = tris[np.all(weighted[tris], axis=1)]
    if len(tris) == 0:
        raise InputError("The character's mesh has no skinned triangles.")
    return project_onto_mesh(source.points, camera, mesh_deformed, tris)


def build_drawover_problem(skeleton: Skeleton, start: RigPose, space: ParameterSpace,
                           camera: Camera, source: Stroke, target: Stroke,
                           mesh_rest: np.ndarray, mesh_deformed: np.ndarray,
                           triangles: np.ndarray, mesh_weights: np.ndarray,
                           k: int = DEFAULT_K, stroke_labels: Sequence[str] = ()
                           ) -> tuple[AbstractionProblem, SurfaceCurve]:
    """A draw-over problem: the source stroke on the mesh is the abstraction, ``target`` its goal.

    A target far from the character is refused by the solver (see
    :func:`.checks.check_strokes_near`).

    Args:
        skeleton: The rest skeleton.
        start: The current pose.
        space: Free parameters.
        camera: The view of both strokes.
        source: Stroke drawn over the part to move (pixels).
        target: Where it should go (pixels).
        mesh_rest: Mesh rest vertices, ``(V, 3)`` world.
        mesh_deformed: Mesh vertices at the current pose, ``(V, 3)``.
        triangles: Mesh triangles, ``(T, 3)`` vertex indices.
        mesh_weights: Mesh bone weights, ``(V, n)``.
        k: Representative vertices (Eq. 12).
        stroke_labels: Name of the target stroke for messages.

    Returns:
        ``(problem, surface_curve)``; the curve gives the source's points at any pose.

    Raises:
        InputError: The source is not over the skinned mesh, or is so short in the view
            (a dot, or a part seen end-on) that it says nothing about what to move.
    """
    weighted = mesh_weights.sum(axis=1) > 0
    seen = camera.project(mesh_deformed[weighted]) if np.any(weighted) else np.zeros((0, 2))
    size = float(np.max(np.ptp(seen, axis=0))) if len(seen) else 0.0
    if source.length < TINY_FRACTION * size:
        raise InputError(f"The source stroke is only {source.length:.1f} px long in this "
                         f"view (the character is {size:.0f} px): draw it along the part to "
                         "move, in a view where that part is seen from the side.")
    curve = drawover_curve(source, camera, mesh_deformed, triangles, mesh_weights)
    if curve.kept.size < 2:
        raise InputError("The source stroke barely touches the character: draw it over the "
                         "part to move.")
    y_mesh = np.zeros(mesh_weights.shape + (4,))
    y_mesh[weighted] = lbs_weighted_rest(mesh_rest[weighted], mesh_weights[weighted])
    coarse, rep_idx = _representatives(mesh_deformed, mesh_weights, k)
    rig = LbsRig(skeleton, space, curve.rigged_rest(y_mesh), y_mesh[rep_idx])
    layout = CurveLayout(("draw-over",), np.array([0, curve.kept.size]))
    return AbstractionProblem(rig, skeleton.names, camera, layout, (target,), coarse,
                              start, tuple(stroke_labels)), curve
