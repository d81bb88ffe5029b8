"""Quasi-Newton refinement (Section 4.3): bounded L-BFGS-B on the full objective.

The genetic search ends near good minima; refinement polishes several distinct ones with
the analytic gradient, collision energy (Eq. 11) included.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, minimize

from .objective import StickObjective


@dataclass(frozen=True)
class RefineResult:
    """One refined pose.

    Attributes:
        x: Genes, shape ``(G,)``.
        energy: Final energy.
        iterations: L-BFGS-B iterations.
        evaluations: Objective evaluations.
        seconds: Wall time.
        message: scipy's status message.
    """

    x: np.ndarray
    energy: float
    iterations: int
    evaluations: int
    seconds: float
    message: str


def refine(objective: StickObjective, x0: np.ndarray, bounds: np.ndarray,
           max_iterations: int = 80, collision: bool = True) -> RefineResult:
    """Minimize the objective from ``x0`` with L-BFGS-B inside ``bounds``.

    Args:
        objective: The energy.
        x0: Start genes, shape ``(G,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        max_iterations: Iteration limit.
        collision: Include Eq. 11.

    Returns:
        The refined genes and diagnostics.
    """
    t0 = time.perf_counter()
    res = minimize(lambda x: objective.value_and_grad(x, collision), np.clip(x0, *bounds.T),
                   jac=True, method="L-BFGS-B", bounds=bounds,
                   options={"maxiter": max_iterations, "maxfun": 2 * max_iterations + 5,
                            "maxcor": 15, "ftol": 1e-10,
                            "gtol": 1e-7})
    return RefineResult(res.x, float(res.fun), int(res.nit), int(res.nfev),
                        time.perf_counter() - t0, str(res.message))


#: Capsule penetration rows (Eq. 11) given to the trust-region solve: the overlapping
#: pairs and samples, at most this many (the rest folded into one row).
PENETRATION_ROWS = 128


@dataclass(frozen=True)
class PackedRows:
    """The rows of a residual vector the trust-region solve sees (fixed count).

    Every smooth row, then the nonzero penetration rows (up to ``k``, zero-padded), then
    one row ``sqrt(sum r_i^2)`` over the penetrations beyond ``k`` (the largest ``k`` are
    kept). The inactive penetrations are zero with zero Jacobian rows: leaving them out
    keeps ``|r|^2``, ``J^T J`` and ``J^T r`` (the Gauss-Newton model) while the solve's
    SVD works on about 200 rows instead of about 1,100 on the Adventurer. Beyond ``k``
    overlapping rows the folded ones keep ``|r|^2`` and ``J^T r``, their share of
    ``J^T J`` becoming the rank-one term of their norm's gradient (not reached on the
    benches: over the 52 CMU and sample solves at most 71 penetration rows were nonzero,
    the median 1).

    Attributes:
        smooth: Smooth rows (:meth:`.StickObjective.smooth_residual_count`).
        keep: Penetration rows kept, ascending, shape ``(<= k,)``.
        fold: Penetration rows folded into the last row, shape ``(f,)``.
        k: Penetration slots.
    """

    smooth: int
    keep: np.ndarray
    fold: np.ndarray
    k: int

    @classmethod
    def of(cls, r: np.ndarray, smooth: int, k: int) -> PackedRows:
        """The packing of residuals ``r`` ``(R,)`` whose first ``smooth`` rows are smooth."""
        pen = np.flatnonzero(r[smooth:]) + smooth
        if pen.size <= k:
            return cls(smooth, pen, pen[:0], k)
        order = np.argsort(-np.abs(r[pen]), kind="stable")
        return cls(smooth, np.sort(pen[order[:k]]), pen[order[k:]], k)

    def residuals(self, r: np.ndarray) -> np.ndarray:
        """Packed residuals, shape ``(smooth + k + 1,)``, with the same squared norm."""
        out = np.zeros(self.smooth + self.k + 1)
        out[:self.smooth] = r[:self.smooth]
        out[self.smooth:self.smooth + self.keep.size] = r[self.keep]
        out[-1] = np.sqrt(r[self.fold] @ r[self.fold])
        return out

    def jacobian(self, r: np.ndarray, J: np.ndarray) -> np.ndarray:
        """Packed Jacobian ``(smooth + k + 1, G)`` of the residuals ``r`` ``(R,)``."""
        out = np.zeros((self.smooth + self.k + 1, J.shape[1]))
        out[:self.smooth] = J[:self.smooth]
        out[self.smooth:self.smooth + self.keep.size] = J[self.keep]
        if self.fold.size:
            rf = r[self.fold]
            out[-1] = rf @ J[self.fold] / np.sqrt(rf @ rf)
        return out


def refine_least_squares(objective: StickObjective, x0: np.ndarray, bounds: np.ndarray,
                         max_iterations: int = 30, collision: bool = True) -> RefineResult:
    """Minimize the objective from ``x0`` as bounded nonlinear least squares.

    The energy is ``|r(x)|^2`` (:meth:`.StickObjective.residuals`), so a trust-region
    Gauss-Newton method (scipy's ``trf``) with the analytic residual Jacobian
    (:meth:`.StickObjective.residuals_deferred`) converges in far fewer evaluations
    than L-BFGS-B on the same energy. The solve sees the smooth rows and the capsule
    penetrations that are not zero (:class:`PackedRows`).

    Args:
        objective: The energy.
        x0: Start genes, shape ``(G,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        max_iterations: Limit on residual evaluations.
        collision: Include Eq. 11.

    Returns:
        The refined genes and diagnostics (``iterations`` counts Jacobians).
    """
    t0 = time.perf_counter()
    lo, hi = bounds[:, 0], bounds[:, 1]
    count = [0, 0]
    cache: dict = {}
    smooth = objective.smooth_residual_count(x0.size)

    def evaluated(x):
        # The Jacobian is computed only when asked for: a rejected trial point needs
        # the residuals only.
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            r, jacobian = objective.residuals_deferred(x, collision)
            packing = PackedRows.of(r, smooth, min(PENETRATION_ROWS, r.size - smooth))
            cache[key] = [packing.residuals(r), r, packing, jacobian, None]
        return cache[key]

    def fun(x):
        count[0] += 1
        return evaluated(x)[0]

    def jac(x):
        count[1] += 1
        entry = evaluated(x)
        if entry[4] is None:
            entry[4] = entry[2].jacobian(entry[1], entry[3]())
        return entry[4]

    res = least_squares(fun, np.clip(x0, lo, hi), jac=jac, bounds=(lo, hi), method="trf",
                        max_nfev=max_iterations, xtol=1e-8, ftol=1e-6, gtol=1e-8)
    energy = float(np.sum(res.fun**2))
    return RefineResult(res.x, energy, count[1], count[0], time.perf_counter() - t0,
                        str(res.message))


def place_joints(objective: StickObjective, x0: np.ndarray, bounds: np.ndarray,
                 joints: np.ndarray, targets: np.ndarray, genes: np.ndarray,
                 tol: float = 1e-9, max_evaluations: int = 60
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Move ``genes`` so that stick ``joints`` land exactly on ``targets``.

    This is the attachment enforcement: a bounded least-squares solve from ``x0``, by
    projected Gauss-Newton (a few Jacobians when the targets are within reach), finished
    by scipy's trust-region methods when that stalls against the bounds.

    Args:
        objective: Provides the pose model.
        x0: Start genes, shape ``(G,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        joints: Stick joint indices, shape ``(k,)``.
        targets: Target positions, shape ``(k, 3)``.
        genes: Indices of the genes allowed to move, shape ``(m,)``.
        tol: Stop once every coordinate of every joint is this close (world units).
        max_evaluations: Limit on residual evaluations of each method.

    Returns:
        ``(x, residuals (k,))``: new genes and the remaining distances (world units).
    """
    model = objective.model
    fig = model.figure
    bones, at_tail = fig.joint_bones[joints], fig.joint_at_tail[joints]

    cache: dict = {}

    def points(x):
        key = x.tobytes()
        if key not in cache:
            heads, tails, Jh, Jt = model.jacobian(x)
            p = np.where(at_tail[:, None], tails[bones], heads[bones])
            J = np.where(at_tail[:, None, None], Jt[bones], Jh[bones])
            everything = np.where(fig.joint_at_tail[:, None, None], Jt[fig.joint_bones],
                                  Jh[fig.joint_bones])
            cache.clear()
            cache[key] = (p, J, everything)
        return cache[key]

    def full(z):
        x = x0.copy()
        x[genes] = z
        return x

    def fun_plain(z):
        return (points(full(z))[0] - targets).ravel()

    def fun(z):
        r = fun_plain(z)
        if np.max(np.abs(r)) < tol:  # on target: stop (least_squares has no such test)
            raise _OnTargetError(z.copy())
        return r

    def jac(z):
        return points(full(z))[1][..., genes].reshape(-1, genes.size)

    lo, hi = bounds[genes, 0], bounds[genes, 1]
    def metric(z):
        J = points(full(z))[2][..., genes].reshape(-1, genes.size)
        return J.T @ J

    z = _projected_gauss_newton(lambda z: (fun_plain(z), jac(z), metric(z)),
                                np.clip(x0[genes], lo, hi), lo, hi, tol, max_evaluations)
    if np.max(np.abs(fun_plain(z))) >= tol:
        # The trust-region reflective method moves the genes least; where it crawls
        # (bounds nearly active) the dogleg method finishes from where it stopped.
        for method in ("trf", "dogbox"):
            try:
                res = least_squares(fun, z, jac=jac, bounds=(lo, hi), method=method,
                                    xtol=1e-12, ftol=1e-14, gtol=1e-12,
                                    max_nfev=max_evaluations)
                z = res.x
            except _OnTargetError as hit:
                z = hit.z
                break
    x = full(z)
    return x, np.linalg.norm(points(x)[0] - targets, axis=1)


def _projected_gauss_newton(fun_jac, z: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                            tol: float, max_evaluations: int) -> np.ndarray:
    """Damped Gauss-Newton on ``|r(z)|^2`` inside ``[lo, hi]``, moving the body least.

    Each step solves ``(J^T J + lambda (M + mu I)) dz = -J^T r`` with ``M = K^T K``, ``K``
    the Jacobian of every stick joint: with small ``lambda`` this is the step that meets
    the linearized targets while moving the joints least. Genes at a bound that the step
    would push out are held; ``lambda`` grows when a step does not lower the residual.

    Args:
        fun_jac: ``z -> (r (k,), dr/dz (k, m), M (m, m))``.
        z: Start, shape ``(m,)`` (inside the bounds).
        lo: Lower bounds, shape ``(m,)``.
        hi: Upper bounds, shape ``(m,)``.
        tol: Stop once every residual is below this.
        max_evaluations: Limit on ``fun_jac`` calls.

    Returns:
        The last accepted ``z``.
    """
    r, J, M = fun_jac(z)
    cost = float(r @ r)
    lam = 1e-6
    for _ in range(max_evaluations - 1):
        if np.max(np.abs(r)) < tol:
            break
        g = J.T @ r
        held = ((z <= lo) & (g > 0)) | ((z >= hi) & (g < 0))
        free = np.flatnonzero(~held)
        if free.size == 0:
            break
        Jf = J[:, free]
        H = Jf.T @ Jf
        Mf = M[np.ix_(free, free)]
        Mf = Mf + 1e-3 * (np.trace(Mf) / free.size + 1e-12) * np.eye(free.size)
        step = np.zeros_like(z)
        step[free] = -np.linalg.solve(H + lam * np.trace(H) / np.trace(Mf) * Mf, g[free])
        zn = np.clip(z + step, lo, hi)
        rn, Jn, Mn = fun_jac(zn)
        cn = float(rn @ rn)
        if cn < cost:
            z, r, J, M, cost = zn, rn, Jn, Mn, cn
            lam = max(lam / 10.0, 1e-12)
        else:
            lam *= 10.0
            if lam > 1e6:
                break
    return z


class _OnTargetError(Exception):
    """Raised inside :func:`place_joints` once every joint is within ``tol``."""

    def __init__(self, z: np.ndarray) -> None:
        super().__init__("on target")
        self.z = z
