"""The bounded Gauss-Newton update as a quadratic program (bounds the paper lacked).

Each update minimizes the quadratic model of :mod:`.energies`,
``min_dp 1/2 dp^T (2H) dp + (2g)^T dp``, subject to linear bounds ``l <= A dp <= u``:

- scales stay in ``[min_scale, max_scale]`` (0.1 by default), so a limb can never be
  inverted by a negative scale (the paper's Figure 7);
- IK limits of the pose bones hold on the rotation-vector components ``theta`` of the local
  rotation ``Q exp(omega)``: ``theta(omega) ~ theta_0 + J_r^-1(theta_0) omega`` (right
  Jacobian of the logarithm); locked axes get equal bounds;
- a trust box limits one step (rotations in radians, translations in world units) so the
  linearization stays valid.

The problem is built by :func:`build_step_qp` and solved by :func:`solve_step_qp` with OSQP;
a failed solve raises :class:`SolverError` with its status and residuals.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import osqp
from scipy import sparse
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from ..exceptions import SolverError
from ..rotations import exp_map, log_map, skew
from .energies import QuadraticModel
from .parameters import ParameterSpace, RigPose

_INF = 1e30


@dataclass(frozen=True)
class StepLimits:
    """Bounds of one update.

    Attributes:
        min_scale: Smallest allowed bone scale.
        max_scale: Largest allowed bone scale.
        ik_limits: ``[min, max]`` per local axis in radians, ``(n, 3, 2)``, NaN = free.
        max_rotation_step: Trust box of rotation increments, radians.
        max_scale_step: Trust box of scale increments.
        max_translation_step: Trust box of translation increments, world units.
    """

    min_scale: float = 0.1
    max_scale: float = 10.0
    ik_limits: np.ndarray | None = None
    max_rotation_step: float = 0.5
    max_scale_step: float = 0.5
    max_translation_step: float = 0.25


@dataclass(frozen=True)
class StepQP:
    """An inspectable update problem ``min 1/2 x^T P x + q^T x, l <= A x <= u``.

    Attributes:
        P: Hessian, sparse ``(P, P)``.
        q: Linear term, ``(P,)``.
        A: Constraint matrix, sparse ``(c, P)``.
        lower: ``l``, ``(c,)``.
        upper: ``u``, ``(c,)``.
        labels: What each constraint row bounds.
    """

    P: sparse.csc_matrix
    q: np.ndarray
    A: sparse.csc_matrix
    lower: np.ndarray
    upper: np.ndarray
    labels: tuple[str, ...]


@dataclass(frozen=True)
class StepSolution:
    """Solution of one update.

    Attributes:
        dp: The increment, ``(P,)``.
        iterations: OSQP iterations.
        status: OSQP status text.
        primal_residual: OSQP primal residual.
        dual_residual: OSQP dual residual.
        active: Labels of the constraint rows at a bound (excluding the trust box).
        seconds: Solve time.
    """

    dp: np.ndarray
    iterations: int
    status: str
    primal_residual: float
    dual_residual: float
    active: tuple[str, ...]
    seconds: float


def inverse_right_jacobian(theta: np.ndarray) -> np.ndarray:
    """``J_r^-1(theta) = d log(exp(theta) exp(w)) / dw`` at ``w = 0``, shape ``(..., 3, 3)``."""
    t = np.linalg.norm(theta, axis=-1)[..., None, None]
    k = skew(theta)
    small = t < 1e-6
    ts = np.where(small, 1.0, t)
    coef = np.where(small, 1.0 / 12.0,
                    1.0 / ts**2 - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(np.minimum(ts, 3.14))))
    return np.eye(3) + 0.5 * k + coef * (k @ k)


#: Relative weight of the small ridge on the increments (see :func:`parameter_ridge`).
RIDGE = 1e-6


def parameter_ridge(hessian: np.ndarray) -> np.ndarray:
    """A tiny ridge ``RIDGE * max(diag H) * I`` on the increments, shape ``(P, P)``.

    Parameters that move nothing the energy sees (e.g. finger bones with no representative
    vertex and no abstraction point) would otherwise get arbitrary increments from solver
    round-off; the ridge keeps them still without biasing the others.
    """
    n = len(hessian)
    scale = float(np.max(np.diag(hessian))) if n else 0.0
    return (RIDGE * max(scale, 1e-12)) * np.eye(n)


def project_to_limits(pose: RigPose, space: ParameterSpace, limits: StepLimits) -> RigPose:
    """Clamp scales and the limited rotation-vector components of ``pose`` exactly."""
    scales = pose.scales.copy()
    sb = space.scale_bones
    scales[sb] = np.clip(scales[sb], limits.min_scale, limits.max_scale)
    rot = pose.rotations.copy()
    if limits.ik_limits is not None:
        rb = space.rotation_bones
        lim = limits.ik_limits[rb]
        limited = np.any(np.isfinite(lim[:, :, 0]), axis=1)
        if np.any(limited):
            theta = log_map(rot[rb[limited]])
            lo = np.where(np.isfinite(lim[limited, :, 0]), lim[limited, :, 0], -np.inf)
            hi = np.where(np.isfinite(lim[limited, :, 1]), lim[limited, :, 1], np.inf)
            rot[rb[limited]] = exp_map(np.clip(theta, lo, hi))
    return RigPose(rot, scales, pose.translations.copy())


@dataclass(frozen=True)
class StepBounds:
    """The bounds of one update as dense rows ``lower <= rows dp <= upper``.

    The first ``P`` rows are the trust box (the identity), then the scale rows, then the
    IK-limit rows.

    Attributes:
        rows: ``(c, P)``; only the scale and IK rows are stored, the trust box is implied.
        lower: ``(P + c,)``.
        upper: ``(P + c,)``.
        scale_bones: Bones of the scale rows, ``(s,)``.
        limit_rows: ``(bone position in rotation_bones, axis)`` of the IK rows, ``(l, 2)``.
    """

    rows: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    scale_bones: np.ndarray
    limit_rows: np.ndarray

    def satisfied(self, dp: np.ndarray, slack: float = 1e-12) -> bool:
        """Whether ``dp`` (``(P,)``) meets every bound (up to a relative ``slack``)."""
        ax = np.concatenate([dp, self.rows @ dp])
        tol = slack * np.maximum(1.0, np.abs(ax))
        return bool(np.all(ax >= self.lower - tol) and np.all(ax <= self.upper + tol))


def step_bounds(space: ParameterSpace, pose: RigPose, limits: StepLimits) -> StepBounds:
    """Trust box, scale bounds and linearized IK limits of an update at ``pose``.

    Args:
        space: The free parameters.
        pose: The current pose (inside its limits).
        limits: Bounds.
    """
    n = space.n_params
    rb, sb, tb = space.rotation_bones, space.scale_bones, space.translation_bones
    step = np.concatenate([np.full(3 * rb.size, limits.max_rotation_step),
                           np.full(sb.size, limits.max_scale_step),
                           np.full(3 * tb.size, limits.max_translation_step)])
    rows, lower, upper = [np.zeros((0, n))], [-step], [step]
    if sb.size:
        scale_rows = np.zeros((sb.size, n))
        scale_rows[np.arange(sb.size), space.scale_columns] = 1.0
        rows.append(scale_rows)
        lower.append(limits.min_scale - pose.scales[sb])
        upper.append(limits.max_scale - pose.scales[sb])
    limit_rows = np.zeros((0, 2), dtype=int)
    if limits.ik_limits is not None and rb.size:
        lim = limits.ik_limits[rb]
        bone, axis = np.nonzero(np.isfinite(lim[:, :, 0]))
        if bone.size:
            theta = log_map(pose.rotations[rb[np.unique(bone)]])
            theta_all = np.zeros((rb.size, 3))
            theta_all[np.unique(bone)] = theta
            jinv = inverse_right_jacobian(theta_all[bone])  # (l, 3, 3)
            ik_rows = np.zeros((bone.size, n))
            ik_rows[np.arange(bone.size)[:, None], 3 * bone[:, None] + np.arange(3)] = \
                jinv[np.arange(bone.size), axis, :]
            rows.append(ik_rows)
            lower.append(np.minimum(lim[bone, axis, 0] - theta_all[bone, axis], 0.0))
            upper.append(np.maximum(lim[bone, axis, 1] - theta_all[bone, axis], 0.0))
            limit_rows = np.stack([bone, axis], axis=1)
    return StepBounds(np.concatenate(rows), np.concatenate(lower), np.concatenate(upper),
                      sb.copy(), limit_rows)


def build_step_qp(model: QuadraticModel, space: ParameterSpace, pose: RigPose,
                  limits: StepLimits, names: tuple[str, ...],
                  bounds: StepBounds | None = None) -> StepQP:
    """Build the bounded update problem at ``pose``.

    Args:
        model: Quadratic model of the energy.
        space: The free parameters.
        pose: The current pose (inside its limits).
        limits: Bounds.
        names: Bone names, for the row labels.
        bounds: :func:`step_bounds` when already computed.

    Returns:
        The QP.
    """
    n = space.n_params
    b = step_bounds(space, pose, limits) if bounds is None else bounds
    labels = [f"step {space.describe(names, c)}" for c in range(n)]
    labels += [f"scale {names[j]}" for j in b.scale_bones]
    labels += [f"limit {names[space.rotation_bones[j]]} {'xyz'[a]}" for j, a in b.limit_rows]
    hess = 2.0 * (model.hessian + parameter_ridge(model.hessian))
    a = sparse.vstack([sparse.identity(n, format="csr"), sparse.csr_matrix(b.rows)],
                      format="csc")
    return StepQP(sparse.csc_matrix(np.triu(hess)), 2.0 * model.gradient, a, b.lower,
                  b.upper, tuple(labels))


def solve_bounded_step(model: QuadraticModel, space: ParameterSpace, pose: RigPose,
                       limits: StepLimits, names: tuple[str, ...]) -> StepSolution:
    """The bounded update: the Gauss-Newton step when it meets every bound, else the QP.

    The unconstrained minimizer (a Cholesky solve of the dense Hessian) is tried first;
    the sparse QP of :func:`build_step_qp` is only built and handed to OSQP when that step
    leaves the trust box, the scale bounds or the IK limits.

    Raises:
        SolverError: OSQP did not solve the problem.
    """
    t0 = time.perf_counter()
    bounds = step_bounds(space, pose, limits)
    hess = model.hessian + parameter_ridge(model.hessian)
    x = _spd_solve(hess, -model.gradient)
    if x is not None and np.all(np.isfinite(x)) and bounds.satisfied(x):
        return StepSolution(x, 0, "unconstrained", 0.0, 0.0, (), time.perf_counter() - t0)
    if len(bounds.limit_rows) == 0:  # only bounds on single parameters: a box QP
        n = space.n_params
        lo, hi = bounds.lower[:n].copy(), bounds.upper[:n].copy()
        cols = space.scale_columns
        lo[cols] = np.maximum(lo[cols], bounds.lower[n:])
        hi[cols] = np.minimum(hi[cols], bounds.upper[n:])
        boxed = box_qp(hess, model.gradient, lo, hi)
        if boxed is not None:
            x, iterations = boxed
            qp = build_step_qp(model, space, pose, limits, names, bounds)
            return StepSolution(x, iterations, "box active set", 0.0, 0.0, _active(qp, x),
                                time.perf_counter() - t0)
    return solve_step_qp(build_step_qp(model, space, pose, limits, names, bounds))


def box_qp(hessian: np.ndarray, gradient: np.ndarray, lower: np.ndarray, upper: np.ndarray,
           max_iter: int = 50) -> tuple[np.ndarray, int] | None:
    """``min dp^T H dp + 2 g^T dp`` subject to ``lower <= dp <= upper``, by active sets.

    Each round solves the free parameters with the others at their bounds (a Cholesky
    solve), fixes the ones that leave their box, and frees the fixed ones whose gradient
    points inside (the KKT conditions). Small dense problems (a few hundred parameters)
    take a few rounds, far fewer operations than an ADMM solver.

    Args:
        hessian: ``H``, symmetric positive definite, ``(P, P)``.
        gradient: ``g``, ``(P,)``.
        lower: ``(P,)`` (``lower <= 0 <= upper``).
        upper: ``(P,)``.
        max_iter: Rounds at most.

    Returns:
        ``(dp, rounds)``, or None when it did not settle (the caller uses OSQP).
    """
    n = len(gradient)
    at_lo, at_hi = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    x = np.zeros(n)
    scale = max(float(np.abs(gradient).max(initial=0.0)), 1e-300)
    for rounds in range(1, max_iter + 1):
        free = ~(at_lo | at_hi)
        x[at_lo], x[at_hi] = lower[at_lo], upper[at_hi]
        if np.any(free):
            rhs = -(gradient[free] + hessian[np.ix_(free, ~free)] @ x[~free])
            sol = _spd_solve(hessian[np.ix_(free, free)], rhs)
            if sol is None:
                return None
            x[free] = sol
        tol = 1e-12 * np.maximum(1.0, np.abs(x))
        low, high = free & (x < lower - tol), free & (x > upper + tol)
        if np.any(low | high):
            at_lo |= low
            at_hi |= high
            continue
        grad = hessian @ x + gradient
        release = (at_lo & (grad < -1e-10 * scale)) | (at_hi & (grad > 1e-10 * scale))
        if not np.any(release):
            return np.clip(x, lower, upper), rounds
        at_lo &= ~release
        at_hi &= ~release
    return None


def _active(qp: StepQP, x: np.ndarray) -> tuple[str, ...]:
    """Labels of the non-trust-box rows at a bound for ``x``."""
    ax = qp.A @ x
    gap = 1e-6 * np.maximum(1.0, np.abs(ax))
    at_bound = (ax <= qp.lower + gap) | (ax >= qp.upper - gap)
    return tuple(lab for lab, a in zip(qp.labels, at_bound, strict=True)
                 if a and not lab.startswith("step "))


def solve_step_qp(qp: StepQP, tolerance: float = 1e-7, max_iter: int = 10000) -> StepSolution:
    """Solve the update problem: directly when no bound is hit, else with OSQP.

    The unconstrained minimizer ``-P^-1 q`` is tried first (a Cholesky solve); when it
    satisfies every bound it is the QP's solution. Otherwise OSQP solves the problem with
    ``P`` and ``q`` scaled to unit largest curvature, so its tolerances are relative.

    Raises:
        SolverError: OSQP did not solve the problem (status and residuals in ``details``).
    """
    t0 = time.perf_counter()
    x = _spd_solve((qp.P + sparse.triu(qp.P, k=1).T).toarray(), -qp.q)
    if x is not None and np.all(np.isfinite(x)):
        ax = qp.A @ x
        slack = 1e-12 * np.maximum(1.0, np.abs(ax))
        if np.all(ax >= qp.lower - slack) and np.all(ax <= qp.upper + slack):
            return StepSolution(x, 0, "unconstrained", 0.0, 0.0, _active(qp, x),
                                time.perf_counter() - t0)
    scale = 1.0 / max(float(qp.P.diagonal().max()), 1e-300)
    solver = osqp.OSQP()
    solver.setup(qp.P * scale, qp.q * scale, qp.A, np.maximum(qp.lower, -_INF),
                 np.minimum(qp.upper, _INF), verbose=False, eps_abs=tolerance,
                 eps_rel=tolerance, max_iter=max_iter, polishing=False)
    res = solver.solve(raise_error=False)
    status = str(res.info.status)
    details = {"status": status, "iterations": int(res.info.iter),
               "primal_residual": float(res.info.prim_res),
               "dual_residual": float(res.info.dual_res)}
    if res.x is None or not np.all(np.isfinite(res.x)) or "solved" not in status:
        raise SolverError(f"The bounded update failed (OSQP status '{status}').", details)
    x = np.asarray(res.x, float)
    return StepSolution(x, details["iterations"], status, details["primal_residual"],
                        details["dual_residual"], _active(qp, x), time.perf_counter() - t0)


def _spd_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """``a^-1 b`` by Cholesky for a symmetric positive definite ``a``; None if it is not.

    (SciPy's Cholesky is used: for these small systems it is ~50x faster than
    ``numpy.linalg.solve`` on a busy machine.)
    """
    try:
        return cho_solve(cho_factor(a, check_finite=False), b, check_finite=False)
    except LinAlgError:
        return None


def solve_step_unbounded(model: QuadraticModel) -> np.ndarray:
    """The paper's unconstrained Gauss-Newton update ``H dp = -g``, shape ``(P,)``."""
    hess = model.hessian + parameter_ridge(model.hessian)
    x = _spd_solve(hess, -model.gradient)
    return np.linalg.lstsq(hess, -model.gradient, rcond=None)[0] if x is None else x
