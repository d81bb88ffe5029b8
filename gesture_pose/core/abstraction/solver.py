"""The ICP loop: alternate correspondences and bounded Gauss-Newton updates (Hahn et al. 2015).

Each iteration (Sec. 4):

1. evaluate the rig and its Jacobians ``J_x`` (abstraction points) and ``J_z``
   (representative vertices) at the current pose;
2. recompute correspondences between the projected abstraction and the strokes;
3. build the quadratic model of ``E_match + W_pose + W_plane + W_dist`` (Eqs. 3, 8-11) and
   solve the update as a bounded QP (or, with ``bounded=False``, the paper's unconstrained
   Gauss-Newton system);
4. apply the update with a backtracking line search on the true energy.

The loop stops when the energy decrease falls below ``tolerance`` (relative), the step
vanishes, or after ``max_iterations``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from ..camera import Camera
from ..exceptions import InputError
from ..skeleton import Skeleton
from ..stroke import Stroke
from ..threads import single_thread_blas
from .checks import end_on_message
from .coarsening import Coarsening
from .correspondences import (
    BY_PROXIMITY,
    CLOSEST,
    IN_ORDER,
    IN_ORDER_CLOSEST,
    Correspondences,
    build_correspondences,
)
from .curves import CurveLayout
from .energies import (
    LAMBDA_DIST,
    LAMBDA_PLANE,
    LAMBDA_POSE,
    QuadraticModel,
    full_regularizer_value,
    match_term,
    pair_distances,
    pose_metric,
    pose_term,
    regularizer_terms,
)
from .inputs import MOVE_DRAWN, end_on_names, prepare_phase
from .parameters import ParameterSpace, RigPose
from .qp import StepLimits, project_to_limits, solve_bounded_step, solve_step_unbounded


class RigModel(Protocol):
    """What the solver needs from a rig (analytic LBS or black-box finite differences)."""

    space: ParameterSpace

    def evaluate(self, pose: RigPose) -> tuple[np.ndarray, np.ndarray]:
        """Abstraction points ``(m, 3)`` and representative vertices ``(k, 3)``."""

    def jacobians(self, pose: RigPose) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(x, z, J_x (m, 3, P), J_z (k, 3, P))``."""


@dataclass(frozen=True)
class SolveOptions:
    """Solver settings; the defaults are the paper's.

    Attributes:
        correspondence: ``"IN_ORDER"``, ``"CLOSEST"`` or ``"IN_ORDER_CLOSEST"`` (in order,
            then closest point from its result).
        assignment: Strokes to curves by ``"ORDER"`` or ``"PROXIMITY"``.
        lambda_pose: Weight of ``W_pose`` (Eq. 8).
        lambda_plane: Weight of ``W_plane`` (Eq. 9).
        lambda_dist: Weight of ``W_dist`` (Eq. 10).
        max_iterations: ICP iterations at most.
        tolerance: Stop when the relative energy decrease is below this.
        residual_tolerance_px: Stop when the RMS matching distance is below this (pixels).
        stall_iterations: Stop when the RMS matching distance improved by less than 1 %
            (and 0.005 px) over this many iterations.
        bounded: Solve updates as bounded QPs (False: the paper's unbounded update).
        limits: Scale bounds, IK limits and trust box of the bounded update.
        line_search_steps: Step halvings tried when the energy does not decrease.
        damping_decay: After each iteration the weight of ``W_pose`` is scaled by this
            factor, down to ``min_damping`` times the paper's weight (a continuation: the
            early iterations stay near the pose before the drawing, the last ones match the
            drawing). 1 keeps the paper's weight throughout (a regularized, biased fit).
        min_damping: Smallest scale of ``W_pose``; the stopping tests (other than the
            residual tolerance) apply once it is reached.
        moved_bones: ``"DRAWN"``: only the bones the matched points are weighted on (and
            those between them) move; ``"DRAWN_AND_LIMB"``: also the bones above them up
            to the first branching bone (upper arm and shoulder for a forearm);
            ``"DRAWN_AND_PARENTS"``: every bone whose rotation moves a matched point (the
            spine for an arm). Other bones are kept exactly.
    """

    correspondence: str = IN_ORDER
    assignment: str = BY_PROXIMITY
    lambda_pose: float = LAMBDA_POSE
    lambda_plane: float = LAMBDA_PLANE
    lambda_dist: float = LAMBDA_DIST
    max_iterations: int = 50
    tolerance: float = 1e-4
    residual_tolerance_px: float = 0.02
    stall_iterations: int = 4
    bounded: bool = True
    limits: StepLimits = field(default_factory=StepLimits)
    line_search_steps: int = 8
    damping_decay: float = 0.1
    min_damping: float = 1e-4
    moved_bones: str = MOVE_DRAWN

    def lambdas(self, damping: float = 1.0) -> tuple[float, float, float]:
        """``(lambda_pose, lambda_plane, lambda_dist)`` with ``W_pose`` scaled by ``damping``."""
        return (self.lambda_pose * damping, self.lambda_plane, self.lambda_dist)


@dataclass(frozen=True)
class AbstractionProblem:
    """Everything one solve needs, built before solving.

    Attributes:
        rig: The rig model.
        names: Bone names (for labels).
        camera: The view the strokes were drawn in.
        layout: Curves of the rig's abstraction points.
        strokes: Target strokes in pixels, oldest first.
        coarse: Representative vertices of the regularizers.
        start: Pose before the solve.
        stroke_labels: Names of the strokes for messages (e.g. ``"stroke 6 of 6 in layer
            'Lines'"``); ``"stroke i"`` when empty.
        skeleton: The skeleton, for the end-on check of black-box rigs (an
            :class:`LbsRig` has its own).
        point_weights: Bone weights of the abstraction points, ``(m, n)``, for the
            choice of moving bones and the end-on check (an :class:`LbsRig`'s own weights
            when None; without either, every bone whose rotation moves a matched point
            moves).
    """

    rig: RigModel
    names: tuple[str, ...]
    camera: Camera
    layout: CurveLayout
    strokes: tuple[Stroke, ...]
    coarse: Coarsening
    start: RigPose
    stroke_labels: tuple[str, ...] = ()
    skeleton: Skeleton | None = None
    point_weights: np.ndarray | None = None

    def __post_init__(self) -> None:
        """Check that there is something to match."""
        if len(self.strokes) == 0:
            raise InputError("There is no target stroke: draw the new pose first.")


@dataclass(frozen=True)
class SolveResult:
    """Result and diagnostics of a solve.

    Attributes:
        pose: The optimized pose.
        iterations: ICP iterations run.
        converged: Whether the tolerance was reached.
        residual_px: Final RMS matching distance, pixels.
        initial_residual_px: RMS matching distance before the solve, pixels.
        energies: Total energy after each iteration (world units squared).
        residuals_px: RMS matching distance after each iteration, pixels.
        seconds: Wall time of the solve.
        iteration_seconds: Wall time of each iteration.
        qp_iterations: OSQP iterations over all updates.
        active_bounds: Bounds active at the last update (scales, IK limits).
        pairs: ``(curve, stroke)`` pairs matched.
        warnings: Human-readable notes.
        frozen: Bones left as they were because no matched abstraction point depends on
            them (see :func:`.checks.constrained_bones`).
    """

    pose: RigPose
    iterations: int
    converged: bool
    residual_px: float
    initial_residual_px: float
    energies: tuple[float, ...]
    residuals_px: tuple[float, ...]
    seconds: float
    iteration_seconds: tuple[float, ...]
    qp_iterations: int
    active_bounds: tuple[str, ...]
    pairs: tuple[tuple[int, int], ...]
    warnings: tuple[str, ...] = ()
    frozen: tuple[str, ...] = ()


def _stalled(residuals: list[float], window: int) -> bool:
    """Whether the RMS residual stopped improving over the last ``window`` iterations."""
    if len(residuals) <= window:
        return False
    before = residuals[-1 - window]
    return before - min(residuals[-window:]) < 0.01 * before + 0.005


def _rms_px(camera: Camera, x: np.ndarray, corr: Correspondences) -> float:
    """Weighted RMS distance between projected correspondences and targets, pixels."""
    res = corr.residuals(camera.project(x))
    return float(np.sqrt(corr.weights @ np.sum(res * res, axis=1)))


def _objective(camera: Camera, x: np.ndarray, z_new: np.ndarray,
               corr: Correspondences, coarse: Coarsening, z_start: np.ndarray, rest_d: np.ndarray,
               lambdas: tuple[float, float, float], ppu: float,
               w_pose: float) -> tuple[float, float]:
    """True energy (with the current correspondences) and RMS residual in pixels."""
    rms = _rms_px(camera, x, corr)
    reg = full_regularizer_value(camera, z_new, coarse, z_start, rest_d, lambdas)
    return rms**2 / ppu**2 + sum(reg.values()) + w_pose, rms


def solve_abstraction(problem: AbstractionProblem,
                      options: SolveOptions | None = None) -> SolveResult:
    """Pose the rig so that its abstraction's projection matches the strokes.

    With ``correspondence="IN_ORDER_CLOSEST"`` an in-order solve is followed by a
    closest-point solve from its result (for curves that stretch, where in-order pairs
    slide); the result then reports the iterations and time of both and the residual of
    the second.

    Args:
        problem: The problem (see :class:`AbstractionProblem`).
        options: Settings (the paper's defaults when None).

    Returns:
        The optimized pose and diagnostics.

    Raises:
        InputError: Bad input (e.g. abstraction behind the view).
        SolverError: An update QP could not be solved.
    """
    opt = SolveOptions() if options is None else options
    with single_thread_blas():  # BLAS's thread hand-offs cost more than these small solves
        if opt.correspondence != IN_ORDER_CLOSEST:
            return _solve_phase(problem, opt)
        first = _solve_phase(problem, replace(opt, correspondence=IN_ORDER))
        second = _solve_phase(replace(problem, start=first.pose),
                              replace(opt, correspondence=CLOSEST))
    return replace(
        second, iterations=first.iterations + second.iterations,
        initial_residual_px=first.initial_residual_px,
        energies=first.energies + second.energies,
        residuals_px=first.residuals_px + second.residuals_px,
        seconds=first.seconds + second.seconds,
        iteration_seconds=first.iteration_seconds + second.iteration_seconds,
        qp_iterations=first.qp_iterations + second.qp_iterations,
        warnings=tuple(dict.fromkeys(first.warnings + second.warnings)))


def _solve_phase(problem: AbstractionProblem, opt: SolveOptions) -> SolveResult:
    """One ICP solve with one correspondence procedure (see :func:`solve_abstraction`)."""
    t_start = time.perf_counter()
    rig, cam, layout, coarse = problem.rig, problem.camera, problem.layout, problem.coarse
    space = rig.space
    pose = project_to_limits(problem.start, space, opt.limits) if opt.bounded else problem.start
    x, z = rig.evaluate(pose)
    depth = float(np.mean(cam.depth(x)))
    if depth <= 0 and cam.is_perspective:
        raise InputError("The abstraction is behind the view: look at the character.")
    setup = prepare_phase(problem, pose, x, z, opt)
    pairs, rows, rig, cached = setup.pairs, setup.rows, setup.rig, setup.jacobians
    space, warnings = rig.space, list(setup.warnings)
    ppu = cam.pixels_per_unit(max(depth, 1e-6))
    z_start, rest_d = z, pair_distances(z, coarse)
    strokes = list(problem.strokes)
    corr0 = build_correspondences(cam.project(x), layout, strokes, pairs, opt.correspondence)
    initial = _rms_px(cam, x, corr0)
    energies, times, residuals = [], [], []
    qp_iters, active, converged = 0, (), False
    it, damping = 0, 1.0
    best = (np.inf, pose)
    while it < opt.max_iterations:
        it += 1
        t_it = time.perf_counter()
        x, z, jx, jz = rig.jacobians(pose) if cached is None else cached
        cached = None
        corr = build_correspondences(cam.project(x), layout, strokes, pairs, opt.correspondence)
        now = _rms_px(cam, x, corr)
        if now < best[0]:
            best = (now, pose)
        hm, gm, em = match_term(cam, x, jx, corr, ppu)
        lambdas = opt.lambdas(damping)
        hr, gr, er = regularizer_terms(cam, z, jz, coarse, z_start, rest_d, lambdas)
        metric = pose_metric(jz, coarse)
        hp, gp, ep = pose_term(metric, space.deviation(problem.start, pose), lambdas[0])
        model = QuadraticModel(hm + hr + hp, gm + gr + gp, {"E_match": em, "W_pose": ep, **er})
        energy = model.energy
        if opt.bounded:
            sol = solve_bounded_step(model, space, pose, opt.limits, problem.names)
            dp, active = sol.dp, sol.active
            qp_iters += sol.iterations
        else:
            dp = solve_step_unbounded(model)
        alpha, accepted = 1.0, None
        for _ in range(opt.line_search_steps):
            cand = space.step(pose, alpha * dp)
            if opt.bounded:
                cand = project_to_limits(cand, space, opt.limits)
            xc, zc = rig.evaluate(cand)
            dev = space.deviation(problem.start, cand)
            e_c, rms = _objective(cam, xc, zc, corr, coarse, z_start, rest_d, lambdas, ppu,
                                  float(lambdas[0] * metric @ dev**2))
            if np.isfinite(e_c) and e_c <= energy:
                accepted = (cand, e_c, rms)
                break
            alpha *= 0.5
        times.append(time.perf_counter() - t_it)
        at_floor = damping <= opt.min_damping
        damping = max(opt.min_damping, damping * opt.damping_decay)
        if accepted is None:
            energies.append(energy)
            if at_floor:
                converged = True
                break
            continue
        pose, new_energy, rms = accepted
        residuals.append(rms)
        energies.append(new_energy)
        if rms < opt.residual_tolerance_px or (at_floor and (
                energy - new_energy <= opt.tolerance * max(energy, 1e-300)
                or alpha * np.abs(dp).max() < 1e-9
                or _stalled(residuals, opt.stall_iterations))):
            converged = True
            break
    x, _ = rig.evaluate(pose)
    final = build_correspondences(cam.project(x), layout, strokes, pairs, opt.correspondence)
    if best[0] < _rms_px(cam, x, final):  # ICP can drift once correspondences slide
        pose = best[1]
        x, _ = rig.evaluate(pose)
        final = build_correspondences(cam.project(x), layout, strokes, pairs,
                                      opt.correspondence)
    if (names := end_on_names(problem, pose, rows)) and not warnings:
        warnings.append(end_on_message(names, after=True))
    if len(strokes) > layout.n_curves:
        warnings.append(f"{len(strokes) - layout.n_curves} stroke(s) had no curve to match.")
    if not converged:
        warnings.append(f"Stopped after {it} iterations before converging.")
    return SolveResult(pose, it, converged, _rms_px(cam, x, final), initial, tuple(energies),
                       tuple(residuals), time.perf_counter() - t_start, tuple(times),
                       qp_iters, tuple(active), pairs, tuple(warnings), setup.frozen)
