"""The batched residuals and trust-region refinement of the stick solver (:mod:`.batch`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gesture_pose.core.stick.batch import (
    evaluate_batch,
    refine_batch,
    refine_lbfgsb_batch,
    values_and_grads,
)
from gesture_pose.core.stick.objective import Weights
from gesture_pose.core.stick.refine import refine, refine_least_squares
from tests.core.test_stick_objective import footprint_problem, problem


@pytest.mark.parametrize("make", [problem, footprint_problem])
@pytest.mark.parametrize("collision", [True, False])
def test_batch_residuals_give_the_single_pose_gauss_newton_model(make, collision):
    # The packed rows (smooth ones, then each pose's nonzero penetrations) keep |r|^2,
    # J^T J and J^T r of the full residual vector, pose by pose, for any subset asked.
    rng = np.random.default_rng(11)
    obj, truth = make(rng)
    X = truth + rng.normal(scale=0.4, size=(6, truth.size))
    X[:, 2] -= 0.3  # into the seat: penetration rows are active on poses 2 and 5
    ev = evaluate_batch(obj, X, collision)
    sel = np.array([5, 0, 2])
    J = ev.jacobian(sel)
    hits = 0
    for i, k in enumerate(sel):
        r1, J1 = obj.residuals_and_jacobian(X[k], collision)
        hits += int(np.sum(r1[obj.smooth_residual_count(truth.size):] > 0))
        assert np.isclose(ev.cost[k], r1 @ r1, rtol=1e-12)
        H1 = J1.T @ J1
        assert np.allclose(J[i].T @ J[i], H1, rtol=1e-10, atol=1e-10 * np.abs(H1).max())
        g1 = J1.T @ r1
        assert np.allclose(J[i].T @ ev.residuals[k], g1, rtol=1e-10,
                           atol=1e-10 * np.abs(g1).max())
    assert hits > 0 or not collision


def test_batch_refinement_is_scipys_trust_region_solve():
    # The batch follows scipy's trf iterates (to rounding) for every pose at once, starts
    # on a bound included.
    rng = np.random.default_rng(3)
    obj, truth = problem(rng, with_grid=False)
    bounds = obj.model.bounds(np.zeros(3), 0.5)
    X0 = np.clip(truth + rng.normal(scale=0.1, size=(4, truth.size)), *bounds.T)
    X0[1, 8] = bounds[8, 1]  # a gene on its bound
    out = refine_batch(obj, X0, bounds, max_evaluations=6)
    for x0, b in zip(X0, out, strict=True):
        s = refine_least_squares(obj, x0, bounds, max_iterations=6)
        assert b.evaluations == s.evaluations <= 6
        assert np.allclose(b.x, s.x, atol=1e-8)
        assert np.isclose(b.energy, s.energy, rtol=1e-8)


def test_batch_refinement_lowers_the_energy_inside_the_bounds():
    rng = np.random.default_rng(4)
    obj, truth = problem(rng)
    bounds = obj.model.bounds(np.zeros(3), 0.5)
    X0 = truth + rng.normal(scale=0.5, size=(6, truth.size))
    X0[:, 2] -= 0.3
    X0[0] = bounds[:, 1] + 1.0  # outside: clipped first
    e0 = obj.evaluate(np.clip(X0, *bounds.T))[0]
    out = refine_batch(obj, X0, bounds, max_evaluations=10)
    X = np.array([r.x for r in out])
    assert np.all((X >= bounds[:, 0]) & (X <= bounds[:, 1]))
    e = np.array([r.energy for r in out])
    assert np.allclose(e, obj.evaluate(X)[0], rtol=1e-12)
    assert np.all(e <= e0) and np.all(e < 0.8 * e0)
    assert all(r.evaluations <= 10 for r in out)
    # Each pose is refined on its own: the same alone as in the batch.
    alone = refine_batch(obj, X0[3:4], bounds, max_evaluations=10)[0]
    assert np.allclose(alone.x, out[3].x, atol=1e-10)
    assert refine_batch(obj, X0[:0], bounds) == []


def test_batch_energies_and_gradients_are_the_single_pose_ones():
    rng = np.random.default_rng(6)
    obj, truth = footprint_problem(rng)
    X = truth + rng.normal(scale=0.4, size=(4, truth.size))
    X[:, 2] -= 0.3
    for collision in (True, False):
        e, g = values_and_grads(obj, X, collision)
        for x, ek, gk in zip(X, e, g, strict=True):
            e1, g1 = obj.value_and_grad(x, collision)
            assert np.isclose(ek, e1, rtol=1e-12)
            assert np.allclose(gk, g1, rtol=1e-10, atol=1e-10 * np.abs(g1).max())


def test_lockstep_lbfgsb_is_scipys():
    # Driving one L-BFGS-B instance per pose, their points evaluated together, gives
    # scipy's iterates (to rounding) within the same iteration and evaluation limits.
    rng = np.random.default_rng(7)
    obj, truth = problem(rng, with_grid=False)
    bounds = obj.model.bounds(np.zeros(3), 0.5)
    X0 = np.clip(truth + rng.normal(scale=0.1, size=(3, truth.size)), *bounds.T)
    X0[2, 8] = bounds[8, 0]
    out = refine_lbfgsb_batch(obj, X0, bounds, max_iterations=5)
    for x0, b in zip(X0, out, strict=True):
        s = refine(obj, x0, bounds, max_iterations=5)
        assert (b.iterations, b.evaluations) == (s.iterations, s.evaluations)
        assert np.allclose(b.x, s.x, atol=1e-7)
        assert np.isclose(b.energy, s.energy, rtol=1e-9)
        assert np.all((b.x >= bounds[:, 0]) & (b.x <= bounds[:, 1]))
        assert b.energy < obj.evaluate(x0[None])[0][0]
    assert refine_lbfgsb_batch(obj, X0[:0], bounds) == []


def test_weighted_foreshortening_is_refined_one_pose_at_a_time():
    # The foreshortening rows are not batched: with them weighted the poses are refined
    # by the single-pose solvers, unchanged.
    rng = np.random.default_rng(8)
    obj, truth = problem(rng, with_grid=False)
    obj = dataclasses.replace(obj, weights=Weights(foreshortening=0.5))
    bounds = obj.model.bounds(np.zeros(3), 0.5)
    X0 = np.clip(truth + rng.normal(scale=0.1, size=(2, truth.size)), *bounds.T)
    for x0, b, c in zip(X0, refine_batch(obj, X0, bounds, 6),
                        refine_lbfgsb_batch(obj, X0, bounds, 4), strict=True):
        assert np.array_equal(b.x, refine_least_squares(obj, x0, bounds, 6).x)
        assert np.array_equal(c.x, refine(obj, x0, bounds, 4).x)


def test_lockstep_lbfgsb_uses_the_pinned_scipys_routine_or_falls_back(monkeypatch):
    # With the pinned scipy the lockstep path is the one taken (its private routine has
    # the signature the driver expects); with another scipy whose routine differs, the
    # poses are refined one by one by scipy's public L-BFGS-B, with the same results.
    from gesture_pose.core.stick import batch

    assert batch._setulb() is not None
    rng = np.random.default_rng(9)
    obj, truth = problem(rng, with_grid=False)
    bounds = obj.model.bounds(np.zeros(3), 0.5)
    X0 = np.clip(truth + rng.normal(scale=0.1, size=(2, truth.size)), *bounds.T)
    monkeypatch.setattr(batch, "_setulb", lambda: None)
    for x0, b in zip(X0, batch.refine_lbfgsb_batch(obj, X0, bounds, 4), strict=True):
        s = refine(obj, x0, bounds, 4)
        assert np.array_equal(b.x, s.x) and b.message == s.message
