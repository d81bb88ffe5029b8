"""Residuals, Jacobians and a trust-region least-squares solve for a batch of poses.

The short refinements of the solve (the candidates' Gauss-Newton refinements, the limb
flips' in :func:`.solve._flip_descent`, the suggestions' polish) refine several poses
independently for a few iterations each. One evaluation of one pose is about 200 small
numpy calls (the forward pass, the capsule pairs, the environment grid, the Jacobian,
scipy's SVD): the time is Python overhead, not arithmetic. Here the residuals (Eqs. 4-11
as square roots, the order of :meth:`.StickObjective.residuals`) and their Jacobian are
computed for ``K`` poses at once, arrays with a leading ``K`` axis, and
:func:`refine_batch` runs scipy's trust-region reflective method (``least_squares``,
``method="trf"``, the exact subproblem solver: Branch, Coleman and Li 1999; More and
Sorensen's step) on all of them together, each pose with its own radius, damping,
acceptance and stopping: the overhead is paid once per iteration for the whole batch.
The iterates are scipy's to rounding (the subproblem is solved from the eigenvalues of
``J^T J`` instead of the singular values of ``J``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .capsules import axis_samples, pair_closest
from .kinematics import N_ROOT_GENES
from .objective import StickObjective, project_jacobian
from .refine import PENETRATION_ROWS, RefineResult, refine, refine_least_squares


@dataclass
class BatchEvaluation:
    """Residuals of ``K`` poses and, on demand, their Jacobians.

    The rows are the smooth ones of :meth:`.StickObjective.residuals` (the same order),
    then each pose's nonzero capsule penetrations (Eq. 11; body pairs then environment
    samples, in their order), zero-padded to the batch's largest count: the squared norm,
    ``J^T J`` and ``J^T r`` are those of the full residual vector (a zero penetration has
    a zero Jacobian row).

    Attributes:
        residuals: Packed residuals, shape ``(K, S + p)``.
        cost: Energies ``|r|^2``, shape ``(K,)``.
        jacobian: ``sel (k,) -> (k, S + p, G)``: the packed Jacobian of the poses
            ``sel``.
        rows: The rows :func:`.refine.refine_least_squares` gives scipy (the smooth
            ones, :data:`.refine.PENETRATION_ROWS` penetration slots and the folded row).
    """

    residuals: np.ndarray
    cost: np.ndarray
    jacobian: Callable[[np.ndarray], np.ndarray]
    rows: int


def evaluate_batch(objective: StickObjective, X: np.ndarray, collision: bool = True
                   ) -> BatchEvaluation:
    """Residuals of ``K`` gene vectors, their Jacobian deferred.

    :meth:`.StickObjective.residuals_deferred` with a leading batch axis (without the
    foreshortening rows: :func:`refine_batch` refines one pose at a time when they are
    weighted).

    Args:
        objective: The energy.
        X: Gene vectors, shape ``(K, G)``.
        collision: Include Eq. 11's penetration rows.

    Returns:
        The packed residuals and their Jacobian.
    """
    ob, model = objective, objective.model
    fig, w = model.figure, ob.weights
    X = np.asarray(X, float)
    K, G = X.shape
    state = model._forward(X)
    heads, tails = state[0], state[1]
    bones, at_tail = fig.joint_bones, fig.joint_at_tail
    joints = fig.joint_positions(heads, tails)
    q, Jq = project_jacobian(ob.camera, joints)
    a, b = ob._edges[:, 0], ob._edges[:, 1]
    u = q[:, b] - q[:, a]
    n = np.maximum(np.linalg.norm(u, axis=-1), 1e-9)
    uh = u / n[..., None]
    present = ob.stick.present
    off = (q[:, present] - ob.stick.points[present]) / ob._px_scale
    sp, spp = np.sqrt(w.projection), np.sqrt(w.projection * w.position)
    rs = [sp * (uh - ob._dirs).reshape(K, -1), spp * off.reshape(K, -1)]
    sb = np.sqrt(w.balance) / ob.height
    balance = len(ob._poly) > 0
    if balance:
        m = ob._mass_share
        com = np.einsum("n,knd->kd", m, 0.5 * (heads + tails))
        feet = ob._feet(joints) if ob.footprints else None
        c2 = com @ ob._ground
        o, closest = ob._support_offset_closest(c2, feet)
        rs.append(sb * o)
    sa = np.sqrt(w.attachment) / ob.height
    for pin in ob.env_pins:
        rs.append(sa * ((joints[:, pin.joint] - pin.target) @ pin.normal)[:, None])
    for pin in ob.limb_pins:
        rs.append(sa * (joints[:, pin.joint] - pin.target(joints)))
    if w.comfort > 0:
        rs.append(ob.comfort_residuals(X))
    smooth = np.concatenate(rs, axis=1)
    S = smooth.shape[1]

    c = np.sqrt(w.collision) / (0.05 * ob.height)
    caps = ob.capsules
    pairs = bool(collision and len(caps.pairs))
    env = bool(collision and ob.grid is not None and np.any(ob.env_capsules))
    pens = []
    if collision:
        start, end = caps.segments(heads, tails)
    if pairs:
        s_, t_, d = pair_closest(caps, start, end)
        pen_pairs = np.maximum(ob._pair_reach - d, 0.0)  # (K, q)
        pens.append(pen_pairs)
    if env:
        cc, radii = ob._env_on, ob._env_radii
        sm = axis_samples(5)
        pts = start[:, cc, None] * (1 - sm)[:, None] + end[:, cc, None] * sm[:, None]
        d_env, gd = ob.grid.sample(pts, limit=1.001 * radii.max())
        pen_env = np.maximum(radii[:, None] - d_env, 0.0)  # (K, c, 5)
        pens.append(pen_env.reshape(K, -1))
    pen = np.concatenate(pens, axis=1) if pens else np.zeros((K, 0))
    hit = pen > 0
    count = hit.sum(1)
    width = int(count.max(initial=0))
    rows, cols = np.nonzero(hit)  # row-major: each pose's penetrations in order
    slot = np.arange(rows.size) - np.concatenate([[0], np.cumsum(count)[:-1]])[rows]
    packed = np.zeros((K, S + width))
    packed[:, :S] = smooth
    packed[rows, S + slot] = c * pen[rows, cols]
    cost = np.einsum("kr,kr->k", packed, packed)
    n_pairs = len(caps.pairs) if pairs else 0
    derivatives: list = []

    def jacobian(sel: np.ndarray) -> np.ndarray:
        sel = np.asarray(sel, int)
        k = sel.size
        sub = tuple(s[sel] for s in state)
        Jh, Jt = model.jacobians_at(X[sel], sub)
        Jj = np.where(at_tail[:, None, None], Jt[:, bones], Jh[:, bones])  # (k, J, 3, G)
        dq = np.einsum("kjcd,kjdg->kjcg", Jq[sel], Jj)
        uh_, n_ = uh[sel], n[sel]
        Pm = (np.eye(2) - uh_[..., :, None] * uh_[..., None, :]) / n_[..., None, None]
        js = [sp * np.einsum("keij,kejg->keig", Pm, dq[:, b] - dq[:, a]).reshape(k, -1, G),
              spp * dq[:, present].reshape(k, -1, G) / ob._px_scale]
        if balance:
            if not derivatives:  # for the whole batch, once
                derivatives.append(ob._support_offset_derivatives(c2, o, closest))
            dc, df = derivatives[0]
            dcom = np.einsum("n,kndg->kdg", m, 0.5 * (Jh + Jt))
            jb = dc[sel] @ ob._ground.T @ dcom
            for f_, f in enumerate(ob.footprints):  # the soles turn with the feet
                jb = jb + df[sel, f_] @ ob._ground.T @ (Jj[:, f.tip] - Jj[:, f.joint])
            js.append(sb * jb)
        for pin in ob.env_pins:
            js.append(sa * np.einsum("d,kdg->kg", pin.normal, Jj[:, pin.joint])[:, None])
        for pin in ob.limb_pins:
            js.append(sa * (Jj[:, pin.joint] - pin.target(Jj, axis=1)))
        if w.comfort > 0:
            js.append(np.broadcast_to(ob._comfort_jacobian, (k,) + ob._comfort_jacobian.shape))
        out = np.zeros((k, S + width, G))
        out[:, :S] = np.concatenate(js, axis=1)
        # The penetration rows of the poses ``sel``, at their packed slots.
        pos = np.full(K, -1)
        pos[sel] = np.arange(k)
        mine = pos[rows] >= 0
        kr, kc, ks = pos[rows[mine]], cols[mine], S + slot[mine]
        if kr.size:
            J0, J1 = caps.segment_jacobians(np.moveaxis(Jh, 0, 1), np.moveaxis(Jt, 0, 1))
            # (c, k, 3, G) each: capsule first, as segment_jacobians indexes it.
            on_p = kc < n_pairs
            if np.any(on_p):
                i, p_ = kr[on_p], kc[on_p]
                kk = sel[i]
                ca, cb = caps.pairs[p_, 0], caps.pairs[p_, 1]
                s1, t1 = s_[kk, p_][:, None], t_[kk, p_][:, None]
                p0, p1 = start[kk, ca], end[kk, ca]
                q0, q1 = start[kk, cb], end[kk, cb]
                diff = p0 + s1 * (p1 - p0) - q0 - t1 * (q1 - q0)
                un = diff / np.maximum(d[kk, p_], 1e-12)[:, None]
                dd = ((1 - s1)[..., None] * J0[ca, i] + s1[..., None] * J1[ca, i] -
                      (1 - t1)[..., None] * J0[cb, i] - t1[..., None] * J1[cb, i])
                out[i, ks[on_p]] = -c * np.einsum("qd,qdg->qg", un, dd)
            on_e = ~on_p
            if np.any(on_e):
                i, e_ = kr[on_e], kc[on_e] - n_pairs
                kk = sel[i]
                ci, mi = e_ // 5, e_ % 5
                dp = ((1 - sm[mi])[:, None, None] * J0[cc[ci], i] +
                      sm[mi][:, None, None] * J1[cc[ci], i])
                out[i, ks[on_e]] = -c * np.einsum("kd,kdg->kg", gd[kk, ci, mi], dp)
        return out

    rows_scipy = S + min(PENETRATION_ROWS, pen.shape[1]) + 1
    return BatchEvaluation(packed, cost, jacobian, rows_scipy)


# -- trust-region reflective, batched ------------------------------------------------------

def _to_bound(x: np.ndarray, s: np.ndarray, lo: np.ndarray, hi: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Largest ``t`` with ``x + t s`` in the box, and the genes whose bound it meets.

    Args:
        x: Points, shape ``(k, G)``.
        s: Directions, shape ``(k, G)``.
        lo: Lower bounds, shape ``(G,)``.
        hi: Upper bounds, shape ``(G,)``.

    Returns:
        ``(t (k,), hits (k, G))``: ``hits`` the sign of ``s`` on the genes reaching their
        bound at ``t``, 0 elsewhere.
    """
    nz = s != 0
    safe = np.where(nz, s, 1.0)
    with np.errstate(over="ignore"):  # a tiny step component: that bound is never met
        steps = np.where(nz, np.maximum((lo - x) / safe, (hi - x) / safe), np.inf)
    t = steps.min(1)
    return t, (steps == t[:, None]) * np.sign(s).astype(int)


def _quadratic(B: np.ndarray, g: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``s^T B s / 2 + g^T s`` per pose: ``B`` ``(k, G, G)``, ``g`` and ``s`` ``(k, G)``."""
    return 0.5 * np.einsum("kg,kgh,kh->k", s, B, s) + np.einsum("kg,kg->k", g, s)


def _minimize_1d(a: np.ndarray, b: np.ndarray, c: np.ndarray, lo: np.ndarray,
                 hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum of ``a t^2 + b t + c`` over ``[lo, hi]`` per pose (all ``(k,)``).

    Returns:
        ``(t (k,), value (k,))``.
    """
    cand = [lo, hi]
    inside = a != 0
    ext = np.where(inside, -0.5 * b / np.where(inside, a, 1.0), lo)
    ext = np.where(inside & (lo < ext) & (ext < hi), ext, lo)
    cand.append(ext)
    t = np.stack(cand, 1)
    y = t * (a[:, None] * t + b[:, None]) + c[:, None]
    i = np.argmin(y, 1)
    rows = np.arange(len(a))
    return t[rows, i], y[rows, i]


def _trust_region_step(mu: np.ndarray, V: np.ndarray, g: np.ndarray, delta: np.ndarray,
                       alpha: np.ndarray, rows: int, rtol: float = 0.01, max_iter: int = 10
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Minimizer of ``p^T B p / 2 + g^T p`` with ``|p| <= delta`` per pose.

    scipy's ``solve_lsq_trust_region`` (More and Sorensen's Newton iteration on
    ``|p(alpha)| - delta``, ``p(alpha) = -(B + alpha I)^-1 g``, safeguarded, to within
    ``rtol`` of the radius, then scaled onto it) with ``B = J^T J = V diag(s^2) V^T``
    from its eigen-decomposition instead of the SVD of ``J``. The Gauss-Newton step when
    ``J`` has full rank and the step is inside.

    Args:
        mu: Eigenvalues of the model Hessians ``B``, ascending, shape ``(k, G)``.
        V: Their eigenvectors (columns), shape ``(k, G, G)``.
        g: Gradients ``J^T r``, shape ``(k, G)``.
        delta: Radii, shape ``(k,)``.
        alpha: Previous damping per pose, NaN for none, shape ``(k,)``.
        rows: Rows of ``J`` (the rank test's tolerance, ``eps * rows * s_max``).
        rtol: Relative tolerance on the step's length.
        max_iter: Newton iterations.

    Returns:
        ``(steps (k, G), alpha (k,))``.
    """
    s = np.sqrt(np.maximum(mu, 0.0))  # ascending
    s2 = s**2
    suf = np.einsum("kgi,kg->ki", V, g)
    full = s[:, 0] > np.finfo(float).eps * rows * s[:, -1]
    safe = np.where(full[:, None], s2, 1.0)
    gn = -np.einsum("kgi,ki->kg", V, suf / safe)
    inside = full & (np.linalg.norm(gn, axis=1) <= delta)

    def phi(a_):
        den = s2 + a_[:, None]
        den = np.where(den > 0, den, np.finfo(float).tiny)
        norm = np.sqrt(np.sum((suf / den) ** 2, 1))
        return norm - delta, -np.sum(suf**2 / den**3, 1) / np.maximum(norm, 1e-300)

    upper = np.linalg.norm(suf, axis=1) / delta
    p0, d0 = phi(np.zeros(len(g)))
    lower = np.where(full, -p0 / np.where(d0 != 0, d0, -1.0), 0.0)
    restart = np.isnan(alpha) | (~full & (alpha == 0))
    a = np.where(restart, np.maximum(0.001 * upper, np.sqrt(np.maximum(lower * upper, 0))),
                 alpha)
    done = inside.copy()
    for _ in range(max_iter):
        if done.all():
            break
        out = (a < lower) | (a > upper)
        a = np.where(~done & out, np.maximum(0.001 * upper,
                                             np.sqrt(np.maximum(lower * upper, 0))), a)
        f, fp = phi(a)
        upper = np.where(~done & (f < 0), a, upper)
        ratio = f / np.where(fp != 0, fp, -1.0)
        lower = np.where(done, lower, np.maximum(lower, a - ratio))
        a = np.where(done, a, a - (f + delta) * ratio / delta)
        done |= np.abs(f) < rtol * delta
    a = np.where(inside, 0.0, a)
    den = s2 + a[:, None]
    p = -np.einsum("kgi,ki->kg", V, suf / np.where(den > 0, den, np.finfo(float).tiny))
    norm = np.linalg.norm(p, axis=1)
    p = np.where(inside[:, None], gn, p * (delta / np.where(norm > 0, norm, 1.0))[:, None])
    return p, a


def _select_step(x, B, g_h, p, p_h, d, delta, lo, hi, theta):
    """Scipy's ``select_step`` (trust-region reflective) for a batch.

    Of the trust-region step ``p`` (stepped back by ``theta`` from a bound it crosses),
    its reflection off that bound and the anti-gradient step, the one with the lowest
    model value. Arrays ``(k, G)``; ``B`` ``(k, G, G)`` the model in the scaled genes
    (``p = d p_h``), ``delta`` and ``theta`` ``(k,)``.

    Returns:
        ``(step (k, G), scaled step (k, G), predicted decrease (k,))``.
    """
    k = len(x)
    ok = np.all((x + p >= lo) & (x + p <= hi), 1)
    p_value = _quadratic(B, g_h, p_h)
    if ok.all():  # every step inside the box: taken as it is
        return p, p_h, -p_value
    p_stride, hits = _to_bound(x, p, lo, hi)
    p_stride = np.where(ok, 1.0, p_stride)
    r_h = np.where(hits != 0, -p_h, p_h)
    r = d * r_h
    pb, pb_h = p * p_stride[:, None], p_h * p_stride[:, None]
    # Along the reflection: up to the trust region's sphere or the box.
    aa = np.einsum("kg,kg->k", r_h, r_h)
    bb = np.einsum("kg,kg->k", pb_h, r_h)
    cc = np.einsum("kg,kg->k", pb_h, pb_h) - delta**2
    disc = np.sqrt(np.maximum(bb**2 - aa * cc, 0.0))
    q = -(bb + np.copysign(disc, bb))
    safe_a = np.where(aa > 0, aa, 1.0)
    safe_q = np.where(q != 0, q, 1.0)
    to_tr = np.where(aa > 0, np.maximum(q / safe_a, cc / safe_q), 0.0)
    to_bound, _ = _to_bound(x + pb, r, lo, hi)
    r_stride = np.minimum(to_bound, to_tr)
    pos = r_stride > 0
    safe_rs = np.where(pos, r_stride, 1.0)
    r_lo = np.where(pos, (1 - theta) * p_stride / safe_rs, 0.0)
    r_hi = np.where(pos, np.where(r_stride == to_bound, theta * to_bound, to_tr), -1.0)
    usable = ~ok & (r_lo <= r_hi)
    Br = np.einsum("kgh,kh->kg", B, r_h)
    a1 = 0.5 * np.einsum("kg,kg->k", r_h, Br)
    b1 = np.einsum("kg,kg->k", g_h, r_h) + np.einsum("kg,kg->k", pb_h, Br)
    c1 = _quadratic(B, g_h, pb_h)
    t_r, r_value = _minimize_1d(a1, b1, c1, np.where(usable, r_lo, 0.0),
                                np.where(usable, r_hi, 0.0))
    r_value = np.where(usable, r_value, np.inf)
    r_h = pb_h + t_r[:, None] * r_h
    # The trust-region step, stepped back inside.
    pt, pt_h = pb * np.where(ok, 1.0, theta)[:, None], pb_h * np.where(ok, 1.0, theta)[:, None]
    pt_value = np.where(ok, p_value, _quadratic(B, g_h, pt_h))
    # The anti-gradient step.
    ag_h = -g_h
    ag = d * ag_h
    gn = np.linalg.norm(ag_h, axis=1)
    to_tr_g = delta / np.where(gn > 0, gn, 1.0)
    to_bound_g, _ = _to_bound(x, ag, lo, hi)
    stride = np.where(to_bound_g < to_tr_g, theta * to_bound_g, to_tr_g)
    Bag = np.einsum("kgh,kh->kg", B, ag_h)
    a2 = 0.5 * np.einsum("kg,kg->k", ag_h, Bag)
    b2 = np.einsum("kg,kg->k", g_h, ag_h)
    t_g, ag_value = _minimize_1d(a2, b2, np.zeros(k), np.zeros(k), stride)
    ag_value = np.where(ok, np.inf, ag_value)
    use_p = ok | ((pt_value < r_value) & (pt_value < ag_value))
    use_r = ~use_p & (r_value < pt_value) & (r_value < ag_value)
    step = np.where(use_p[:, None], pt, np.where(use_r[:, None], d * r_h, ag * t_g[:, None]))
    step_h = np.where(use_p[:, None], pt_h, np.where(use_r[:, None], r_h,
                                                       ag_h * t_g[:, None]))
    value = np.where(use_p, pt_value, np.where(use_r, r_value, ag_value))
    return step, step_h, -value


def _strictly_feasible(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, rstep: float = 0.0
                       ) -> np.ndarray:
    """Genes on (or within ``rstep`` of) a bound moved inside it.

    scipy's ``make_strictly_feasible``: by ``rstep`` times the bound's magnitude (at
    least 1), or, with ``rstep`` 0, to the next float inside.

    Args:
        x: Genes, shape ``(k, G)``.
        lo: Lower bounds, shape ``(G,)``.
        hi: Upper bounds, shape ``(G,)``.
        rstep: Relative step.

    Returns:
        The moved genes, shape ``(k, G)``.
    """
    with np.errstate(under="ignore"):
        if rstep == 0:
            lower, upper = x <= lo, x >= hi
            inside_lo, inside_hi = np.nextafter(lo, hi), np.nextafter(hi, lo)
        else:
            d_lo, d_hi = x - lo, hi - x
            lower = d_lo <= np.minimum(d_hi, rstep * np.maximum(1, np.abs(lo)))
            upper = ~lower & (d_hi <= np.minimum(d_lo, rstep * np.maximum(1, np.abs(hi))))
            inside_lo = lo + rstep * np.maximum(1, np.abs(lo))
            inside_hi = hi - rstep * np.maximum(1, np.abs(hi))
        out = np.where(lower, inside_lo, np.where(upper, inside_hi, x))
    tight = (out < lo) | (out > hi)
    return np.where(tight, 0.5 * (lo + hi), out)


def _coleman_li(x: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Coleman and Li's scaling ``v`` and its derivative sign ``dv``, each ``(k, G)``.

    ``v`` is the distance to the bound the descent direction ``-g`` heads for (1 where
    that bound is infinite), ``dv`` the sign of its derivative.
    """
    up = (g < 0) & np.isfinite(hi)
    down = (g > 0) & np.isfinite(lo)
    v = np.where(up, hi - x, np.where(down, x - lo, 1.0))
    dv = np.where(up, -1.0, np.where(down, 1.0, 0.0))
    return v, dv


def refine_batch(objective: StickObjective, X0: np.ndarray, bounds: np.ndarray,
                 max_evaluations: int = 10, collision: bool = True, ftol: float = 1e-6,
                 xtol: float = 1e-8, gtol: float = 1e-8) -> list[RefineResult]:
    """:func:`.refine.refine_least_squares` of ``K`` poses at once.

    Bounded nonlinear least squares on ``|r(x)|^2`` by scipy's trust-region reflective
    iteration, batched. Per pose and iteration: Coleman and Li's scaling ``v`` (the
    distance to the bound the descent heads for) gives the scaled genes
    ``x = sqrt(v) x_h``; the trust-region step of the model ``J_h^T J_h + diag(g dv)``
    (:func:`_trust_region_step`); of it (stepped back from a bound it crosses), its
    reflection off that bound and the anti-gradient step, the lowest model value
    (:func:`_select_step`); the trial point kept when it lowers the energy; the radius
    set from the ratio of the actual to the predicted decrease. The trial points of all
    the poses still running are evaluated together (:func:`evaluate_batch`), Jacobians
    only at accepted points. Each pose stops on its own: its budget of
    ``max_evaluations`` residual evaluations (the first included, as scipy's
    ``max_nfev``), or scipy's ``ftol``, ``xtol`` and ``gtol`` tests.

    Args:
        objective: The energy.
        X0: Start genes, shape ``(K, G)`` (clipped into the bounds).
        bounds: Gene bounds, shape ``(G, 2)``, lower strictly below upper.
        max_evaluations: Residual evaluations per pose.
        collision: Include Eq. 11.
        ftol: Stop when a step lowers the energy by less than this fraction (with a
            ratio above 0.25).
        xtol: Stop when a step is shorter than this, relative to ``|x|``.
        gtol: Stop when the scaled gradient's largest entry is below this.

    Returns:
        One :class:`.refine.RefineResult` per pose (``iterations`` counts Jacobians,
        ``seconds`` is the batch's wall time divided among the poses). With the
        foreshortening term weighted (not batched) the poses are refined one by one by
        :func:`.refine.refine_least_squares`.
    """
    t0 = time.perf_counter()
    X0 = np.atleast_2d(np.asarray(X0, float))
    K, G = X0.shape
    if K == 0:
        return []
    if objective.weights.foreshortening > 0:
        return [refine_least_squares(objective, x, bounds, max_evaluations, collision)
                for x in X0]
    lo, hi = bounds[:, 0], bounds[:, 1]
    x = _strictly_feasible(np.clip(X0, lo, hi), lo, hi, 1e-10)
    ev = evaluate_batch(objective, x, collision)
    cost = 0.5 * ev.cost
    H = np.zeros((K, G, G))
    g = np.zeros((K, G))

    def normal(ev_, which, into):
        J = ev_.jacobian(which)
        H[into] = np.swapaxes(J, 1, 2) @ J
        g[into] = np.einsum("krg,kr->kg", J, ev_.residuals[which])

    everyone = np.arange(K)
    normal(ev, everyone, everyone)
    v, _ = _coleman_li(x, g, lo, hi)
    delta = np.linalg.norm(x / np.sqrt(v), axis=1)
    delta = np.where(delta == 0, 1.0, delta)
    active = np.isfinite(cost)
    n_eval = np.ones(K, int)
    n_jac = np.ones(K, int)
    status = np.array(["evaluation budget"] * K, dtype=object)
    alpha = np.full(K, np.nan)
    ev_rows = ev.rows
    # The model's eigen-decomposition per pose, kept while its point is: a rejected step
    # is retried with a smaller radius on the same model (scipy's inner loop).
    mu, V = np.zeros((K, G)), np.zeros((K, G, G))
    known = np.zeros(K, bool)
    while True:
        v, dv = _coleman_li(x, g, lo, hi)
        g_norm = np.max(np.abs(g * v), 1)
        small = active & (g_norm < gtol)
        status[small] = "gtol"
        active &= ~small & (n_eval < max_evaluations)
        idx = np.flatnonzero(active)
        if not idx.size:
            break
        xa, ga, Ha = x[idx], g[idx], H[idx]
        d = np.sqrt(v[idx])
        diag_h = ga * dv[idx]
        g_h = d * ga
        B = d[:, :, None] * Ha * d[:, None, :] + diag_h[:, :, None] * np.eye(G)
        theta = np.maximum(0.995, 1 - g_norm[idx])
        new = ~known[idx]
        if new.any():
            mu[idx[new]], V[idx[new]] = np.linalg.eigh(B[new])
            known[idx[new]] = True
        p_h, alpha[idx] = _trust_region_step(mu[idx], V[idx], g_h, delta[idx], alpha[idx],
                                             ev_rows)
        step, step_h, pred = _select_step(xa, B, g_h, d * p_h, p_h, d, delta[idx], lo, hi,
                                          theta)
        xt = _strictly_feasible(xa + step, lo, hi)
        et = evaluate_batch(objective, xt, collision)
        n_eval[idx] += 1
        c_new = 0.5 * et.cost
        finite = np.isfinite(c_new)
        actual = np.where(finite, cost[idx] - c_new, -np.inf)
        h_norm = np.linalg.norm(step_h, axis=1)
        ratio = np.where(pred > 0, actual / np.where(pred > 0, pred, 1.0),
                         np.where((pred == 0) & (actual == 0), 1.0, 0.0))
        new_delta = np.where(ratio < 0.25, 0.25 * h_norm,
                             np.where((ratio > 0.75) & (h_norm > 0.95 * delta[idx]),
                                      2.0 * delta[idx], delta[idx]))
        delta_new = np.where(finite, new_delta, 0.25 * h_norm)
        # The damping follows the radius on a rejected step (scipy's warm start).
        rej = ~(actual > 0)
        alpha[idx[rej]] *= delta[idx[rej]] / np.where(delta_new[rej] > 0, delta_new[rej], 1.0)
        delta[idx] = delta_new
        s_norm = np.linalg.norm(step, axis=1)
        f_ok = finite & (actual < ftol * cost[idx]) & (ratio > 0.25)
        x_ok = finite & (s_norm < xtol * (xtol + np.linalg.norm(xa, axis=1)))
        stop = f_ok | x_ok
        status[idx[f_ok]] = "ftol"
        status[idx[x_ok & ~f_ok]] = "xtol"
        acc = np.flatnonzero(actual > 0)
        if acc.size:
            ka = idx[acc]
            x[ka] = xt[acc]
            cost[ka] = c_new[acc]
            known[ka] = False
            need = ~stop[acc] & (n_eval[ka] < max_evaluations)
            if np.any(need):
                normal(et, acc[need], ka[need])
                n_jac[ka[need]] += 1
        active[idx[stop]] = False
    seconds = (time.perf_counter() - t0) / K
    return [RefineResult(x[k].copy(), float(2.0 * cost[k]), int(n_jac[k]), int(n_eval[k]),
                         seconds, str(status[k])) for k in range(K)]


# -- L-BFGS-B, several poses in lockstep -----------------------------------------------------

def values_and_grads(objective: StickObjective, X: np.ndarray, collision: bool = True
                     ) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`.StickObjective.value_and_grad` of ``K`` gene vectors at once.

    Args:
        objective: The energy (foreshortening not weighted).
        X: Gene vectors, shape ``(K, G)``.
        collision: Include Eq. 11.

    Returns:
        ``(energies (K,), gradients (K, G))``.
    """
    X = np.asarray(X, float)
    state = objective.model._forward(X)
    heads, tails = state[0], state[1]
    Jh, Jt = objective.model.jacobians_at(X, state)
    total, _, gh, gt = objective.energies(heads, tails, collision, grad=True)
    g = np.einsum("knd,kndg->kg", gh, Jh) + np.einsum("knd,kndg->kg", gt, Jt)
    if objective.weights.comfort > 0:
        r = objective.comfort_residuals(X)
        total = total + np.sum(r * r, 1)
        g[:, N_ROOT_GENES:] += 2.0 * r * objective._comfort_scale
    return total, g


#: The reverse-communication routine of scipy's L-BFGS-B this module drives (scipy 1.15+).
SETULB = "setulb(m,x,l,u,nbd,f,g,factr,pgtol,wa,iwa,task,lsave,isave,dsave,maxls,ln_task)"


def _setulb() -> Callable | None:
    """Scipy's ``_lbfgsb.setulb`` when it is the routine :data:`SETULB` describes."""
    try:
        from scipy.optimize import _lbfgsb
    except ImportError:  # pragma: no cover - another scipy
        return None
    routine = getattr(_lbfgsb, "setulb", None)
    doc = (getattr(routine, "__doc__", "") or "").strip()
    return routine if doc.startswith(SETULB) else None


def refine_lbfgsb_batch(objective: StickObjective, X0: np.ndarray, bounds: np.ndarray,
                        max_iterations: int = 80, collision: bool = True
                        ) -> list[RefineResult]:
    """:func:`.refine.refine` (bounded L-BFGS-B) of ``K`` poses in lockstep.

    scipy's L-BFGS-B (``minimize(method="L-BFGS-B")`` with the options of
    :func:`.refine.refine`) asks for the energy and its gradient by reverse
    communication (``_lbfgsb.setulb``): here one instance per pose is driven as scipy's
    driver drives it (its iteration and evaluation limits, an evaluation at a point
    already evaluated answered from memory), and the points the instances ask for are
    evaluated together (:func:`values_and_grads`). The iterates are scipy's to rounding.
    When scipy's private routine is not the one expected, or the foreshortening term is
    weighted, the poses are refined one by one by :func:`.refine.refine`.

    Args:
        objective: The energy.
        X0: Start genes, shape ``(K, G)`` (clipped into the bounds).
        bounds: Gene bounds, shape ``(G, 2)``.
        max_iterations: L-BFGS-B iterations per pose.
        collision: Include Eq. 11.

    Returns:
        One :class:`.refine.RefineResult` per pose (``seconds`` the batch's wall time
        divided among the poses).
    """
    t0 = time.perf_counter()
    X0 = np.atleast_2d(np.asarray(X0, float))
    K, n = X0.shape
    setulb = _setulb()
    if K == 0:
        return []
    if setulb is None or objective.weights.foreshortening > 0:
        return [refine(objective, x, bounds, max_iterations, collision) for x in X0]
    m, maxls = 15, 20  # refine's maxcor; scipy's default line-search limit
    factr, pgtol = 1e-10 / np.finfo(float).eps, 1e-7
    maxfun = 2 * max_iterations + 5
    lo = np.where(np.isinf(bounds[:, 0]), 0.0, bounds[:, 0]).astype(np.float64)
    hi = np.where(np.isinf(bounds[:, 1]), 0.0, bounds[:, 1]).astype(np.float64)
    fin_lo, fin_hi = np.isfinite(bounds[:, 0]), np.isfinite(bounds[:, 1])
    nbd = np.select([fin_lo & fin_hi, fin_lo, fin_hi], [2, 1, 3], 0).astype(np.int32)
    X = np.clip(X0, bounds[:, 0], bounds[:, 1])
    f0, g0 = values_and_grads(objective, X, collision)
    runs = []
    for k in range(K):
        runs.append({
            "x": np.array(X[k], dtype=np.float64), "f": np.array(0.0), "g": np.zeros(n),
            "wa": np.zeros(2 * m * n + 5 * n + 11 * m * m + 8 * m),
            "iwa": np.zeros(3 * n, np.int32), "task": np.zeros(2, np.int32),
            "ln_task": np.zeros(2, np.int32), "lsave": np.zeros(4, np.int32),
            "isave": np.zeros(44, np.int32), "dsave": np.zeros(29),
            "nit": 0, "nfev": 1, "seen": X[k].copy(), "fg": (float(f0[k]), g0[k].copy()),
            "done": False})
    while True:
        asking = []
        for r in runs:
            while not r["done"]:
                r["g"] = r["g"].astype(np.float64)
                setulb(m, r["x"], lo, hi, nbd, r["f"], r["g"], factr, pgtol, r["wa"],
                       r["iwa"], r["task"], r["lsave"], r["isave"], r["dsave"], maxls,
                       r["ln_task"])
                task = r["task"]
                if task[0] == 3:  # wants f and g at x
                    if np.array_equal(r["x"], r["seen"]):
                        r["f"], r["g"] = r["fg"][0], r["fg"][1].copy()
                        continue
                    asking.append(r)
                    break
                if task[0] == 1:  # a new iteration
                    r["nit"] += 1
                    if r["nit"] >= max_iterations:
                        task[0], task[1] = 5, 504
                    elif r["nfev"] > maxfun:
                        task[0], task[1] = 5, 502
                    continue
                r["done"] = True
        if not asking:
            break
        f, g = values_and_grads(objective, np.array([r["x"] for r in asking]),
                                collision)
        for r, fk, gk in zip(asking, f, g, strict=True):
            r["nfev"] += 1
            r["seen"] = r["x"].copy()
            r["fg"] = (float(fk), gk.copy())
            r["f"], r["g"] = r["fg"][0], gk.copy()
    seconds = (time.perf_counter() - t0) / K
    return [RefineResult(r["x"].copy(), float(r["f"]), r["nit"], r["nfev"], seconds,
                         f"task {int(r['task'][0])}: {int(r['task'][1])}") for r in runs]
