"""One quadratic program of the SQP loop: build it (inspectable), then solve it with OSQP.

Each iteration of the 3D lifting linearizes the joint positions in the twists,
``x(delta) ~ x0 + G delta`` (:mod:`.twist`), and minimizes over ``delta``::

    alpha * sum_terms sum_i w_i (M (x0 + G delta) - t)_i^2   (E_c, E_v, spline; Eqs. 5-7)
    + kappa * ||G delta||^2 + eps ||delta||^2                (stabilizer, Eq. 9)

subject to ``lo <= A (x0 + G delta) <= hi`` (depth ordering, same-direction and contact
constraints) and ``lo <= D delta <= hi`` (locked axes, IK limits, pinned bones). ``kappa``
is one over the summed squared link lengths, so the stabilizer is the mean squared joint
displacement relative to the skeleton's size and ``alpha`` (paper: 200) weighs the drawing
against it, scale free. With
``soften=True`` every joint-space constraint row gets a free slack variable ``s`` with
penalty ``rho s^2`` so that the problem is always feasible; the slacks tell which
constraints the drawing makes contradictory.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import osqp
import scipy.sparse as sp

from ...exceptions import SolverError
from .energies import LinearTerm


@dataclass(frozen=True)
class LinearConstraint:
    """Rows ``lower <= matrix @ v <= upper`` on joint positions or on twists.

    Attributes:
        matrix: Shape ``(r, n)`` with ``n = 3J`` (joint positions) or ``3m`` (twists).
        lower: Shape ``(r,)``; ``-inf`` for none.
        upper: Shape ``(r,)``; ``+inf`` for none.
        labels: One label per row (e.g. ``"occlusion forearm.L>spine"``).
    """

    matrix: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    labels: tuple[str, ...]

    @property
    def n_rows(self) -> int:
        """Number of rows ``r``."""
        return len(self.labels)

    def violation(self, v: np.ndarray) -> np.ndarray:
        """How far each row is outside its bounds at ``v`` (0 when satisfied), ``(r,)``."""
        y = self.matrix @ np.ravel(v)
        return np.maximum(self.lower - y, 0.0) + np.maximum(y - self.upper, 0.0)


@dataclass(frozen=True)
class QPProblem:
    """``min 1/2 z^T P z + q^T z  s.t.  l <= A z <= u`` over ``z = [delta; slacks]``.

    Attributes:
        P: Upper-triangular sparse cost matrix, shape ``(n, n)``.
        q: Linear cost, shape ``(n,)``.
        A: Sparse constraint matrix, shape ``(r, n)``.
        l: Lower bounds, shape ``(r,)``.
        u: Upper bounds, shape ``(r,)``.
        labels: Label of each constraint row.
        n_twist: Number of twist variables ``3m``.
        n_slack: Number of slack variables (0 unless softened).
        constant: Cost at ``z = 0`` (the energy before the step).
    """

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    l: np.ndarray  # noqa: E741
    u: np.ndarray
    labels: tuple[str, ...]
    n_twist: int
    n_slack: int
    constant: float


@dataclass(frozen=True)
class QPResult:
    """The solution of one :class:`QPProblem`.

    Attributes:
        status: OSQP's status (``"solved"``, ``"solved inaccurate"``, or ``"maximum
            iterations reached"`` with a feasible iterate).
        delta: Twists, shape ``(m, 3)``, radians.
        slacks: Slack values, shape ``(n_slack,)``.
        objective: Optimal QP cost including the constant: ``alpha`` times the predicted
            drawing energy plus the stabilizer.
        iterations: OSQP iterations.
        primal_residual: OSQP primal residual.
        dual_residual: OSQP dual residual.
        solve_time: Seconds spent in OSQP.
        active: Labels of inequality rows at a bound with a non-zero multiplier.
    """

    status: str
    delta: np.ndarray
    slacks: np.ndarray
    objective: float
    iterations: int
    primal_residual: float
    dual_residual: float
    solve_time: float
    active: tuple[str, ...]


def build_qp(terms: list[LinearTerm], constraints: list[LinearConstraint],
             dof: list[LinearConstraint], x0: np.ndarray, G: np.ndarray, *, alpha: float,
             kappa: float, soften: bool = False, rho: float = 1e7,
             eps: float = 1e-2) -> QPProblem:
    """Assemble the QP of one SQP step.

    Args:
        terms: Least-squares terms on joint positions.
        constraints: Constraints on joint positions (linearized through ``G``).
        dof: Constraints directly on the twists.
        x0: Current joint positions, flattened, shape ``(3J,)``.
        G: Position Jacobian, shape ``(3J, 3m)``.
        alpha: Weight of the drawing terms against the stabilizer (paper: 200).
        kappa: Stabilizer normalization (one over summed squared link lengths).
        soften: Add penalized slacks to the joint-space constraints.
        rho: Slack penalty.
        eps: Small Tikhonov weight on the twists (twists about a leaf bone's own axis move
            no joint).

    Returns:
        The problem.
    """
    n_tw = G.shape[1]
    H = 2.0 * (kappa * (G.T @ G) + eps * np.eye(n_tw))
    g = np.zeros(n_tw)
    constant = 0.0
    for term in terms:
        MG = term.matrix @ G
        r0 = term.matrix @ x0 - term.target
        w = alpha * term.weight
        H += 2.0 * MG.T @ (w[:, None] * MG)
        g += 2.0 * MG.T @ (w * r0)
        constant += float(np.sum(w * r0 * r0))
    rows, lo, hi, labels = [], [], [], []
    for c in constraints:
        y0 = c.matrix @ x0
        rows.append(c.matrix @ G)
        lo.append(c.lower - y0)
        hi.append(c.upper - y0)
        labels.extend(c.labels)
    n_soft = sum(len(r) for r in rows) if soften else 0
    for c in dof:
        rows.append(c.matrix)
        lo.append(c.lower)
        hi.append(c.upper)
        labels.extend(c.labels)
    A = np.vstack(rows) if rows else np.zeros((0, n_tw))
    if n_soft:
        slack_cols = np.zeros((A.shape[0], n_soft))
        slack_cols[np.arange(n_soft), np.arange(n_soft)] = 1.0
        A = np.hstack([A, slack_cols])
        H = np.block([[H, np.zeros((n_tw, n_soft))],
                      [np.zeros((n_soft, n_tw)), 2.0 * rho * np.eye(n_soft)]])
        g = np.concatenate([g, np.zeros(n_soft)])
    return QPProblem(
        P=sp.csc_matrix(np.triu(0.5 * (H + H.T))),
        q=g,
        A=sp.csc_matrix(A),
        l=np.concatenate(lo) if lo else np.zeros(0),
        u=np.concatenate(hi) if hi else np.zeros(0),
        labels=tuple(labels),
        n_twist=n_tw,
        n_slack=n_soft,
        constant=constant,
    )


def solve_qp(problem: QPProblem, *, eps_abs: float = 1e-6, eps_rel: float = 1e-6,
             max_iter: int = 10000, feasibility: float = 1e-5) -> QPResult:
    """Solve a :class:`QPProblem` with OSQP.

    An iterate that reached the iteration limit is accepted when it is feasible within
    ``feasibility`` (a step of the SQP loop need not be optimal, only feasible: the next
    iteration continues from it).

    Args:
        problem: The QP.
        eps_abs: OSQP absolute tolerance.
        eps_rel: OSQP relative tolerance.
        max_iter: OSQP iteration limit.
        feasibility: Largest primal residual accepted at the iteration limit.

    Returns:
        The solution.

    Raises:
        SolverError: OSQP did not solve the problem; ``details`` holds its status and
            residuals.
    """
    solver = osqp.OSQP()
    solver.setup(problem.P, problem.q, problem.A, problem.l, problem.u, verbose=False,
                 eps_abs=eps_abs, eps_rel=eps_rel, max_iter=max_iter, polishing=False,
                 scaled_termination=False)
    start = time.perf_counter()
    res = solver.solve(raise_error=False)
    elapsed = time.perf_counter() - start
    status = str(res.info.status)
    ok = res.info.status_val in (int(osqp.SolverStatus.OSQP_SOLVED),
                                 int(osqp.SolverStatus.OSQP_SOLVED_INACCURATE))
    ok |= (res.info.status_val == int(osqp.SolverStatus.OSQP_MAX_ITER_REACHED)
           and res.info.prim_res <= feasibility)
    if not ok or res.x is None or not np.all(np.isfinite(res.x)):
        raise SolverError(
            f"The depth QP was not solved (OSQP status '{status}').",
            {"status": status, "primal_residual": float(res.info.prim_res),
             "dual_residual": float(res.info.dual_res), "iterations": int(res.info.iter)},
        )
    z = np.asarray(res.x, dtype=float)
    y = np.asarray(res.y, dtype=float)
    Az = problem.A @ z
    tol = 1e-6 * (1.0 + np.abs(Az))
    at_bound = (np.abs(Az - problem.l) < tol) | (np.abs(Az - problem.u) < tol)
    inequality = problem.u - problem.l > 1e-12
    active = tuple(lab for lab, on in zip(problem.labels, at_bound & inequality
                                          & (np.abs(y) > 1e-9), strict=True) if on)
    return QPResult(
        status=status,
        delta=z[:problem.n_twist].reshape(-1, 3),
        slacks=z[problem.n_twist:],
        objective=float(res.info.obj_val) + problem.constant,
        iterations=int(res.info.iter),
        primal_residual=float(res.info.prim_res),
        dual_residual=float(res.info.dual_res),
        solve_time=elapsed,
        active=active,
    )
