"""2D refinement of the embedding (Gesture3D Section 6): limb ends moved as a whole."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gesture_pose.core.gesture.candidates import JointCandidates
from gesture_pose.core.gesture.mrf import interior_joints, joint_energy, make_problem
from gesture_pose.core.gesture.preprocess import preprocess
from gesture_pose.core.gesture.refine import (
    RefineParams,
    _set_energy,
    limb_chains,
    refine,
    rigid_groups,
    with_positions,
)
from gesture_pose.core.gesture.solving import solving_skeleton
from gesture_pose.core.stroke import Stroke

from .fixtures import chain_skeleton, front_camera, tree_skeleton
from .test_gesture_fixtures import bent_arm_outline

R = 0.1125  # limb radius, metres (30 px in the orthographic front camera)


def _arm():
    """The bent two-bone arm outline, its problem and the true joints as a configuration."""
    cam = front_camera(ortho=True)
    s, e, w = np.array([-0.8, 0, 0.8]), np.array([0.1, 0, 0.8]), np.array([0.7, 0, 0.8])
    skel = chain_skeleton(np.stack([s, e, w]))
    outline = bent_arm_outline(s[[0, 2]], e[[0, 2]], 0.6, R)
    pixels = cam.project(np.stack([outline[:, 0], np.zeros(len(outline)), outline[:, 1]], 1))
    solving = solving_skeleton(skel)
    truth = cam.project(np.stack([s, e, e + [0, 0, 0.6]]))
    problem = make_problem(preprocess([Stroke(pixels)]), solving,
                           cam.pixels_per_unit(float(cam.depth(e[None])[0])),
                           cam.project(solving.rest_joints))
    n = solving.n_joints
    conf = JointCandidates(truth.copy(), np.full(n, 30.0), np.zeros(n, int), -np.ones(n, int),
                           -np.ones(n, int), np.zeros(n), -np.ones((n, 48), int))
    return problem, conf


def test_limb_chains_are_free_joints_with_their_descendants():
    problem, _ = _arm()
    ends = limb_chains(problem, 3)
    names = problem.solving.joint_bones
    # The elbow carries the wrist; the wrist alone and the root are not limb ends.
    assert [[names[j] for j in e] for e in ends] == [["b0 tail", "b1 tail"]]
    assert limb_chains(problem, 1) == []


def test_chain_energy_is_the_change_of_the_whole_energy():
    """Translating a limb end changes its factors' energy (what the refinement compares
    for a chain) exactly as much as the whole energy."""
    problem, conf = _arm()
    chain = limb_chains(problem, 3)[0]
    shift = np.array([[0.0, 0.0], [6.0, -4.0], [-15.0, 2.0], [3.0, 20.0]])
    chained = _set_energy(problem, conf, conf.positions, chain,
                          conf.positions[chain][None] + shift[:, None])
    whole = []
    for d in shift:
        pos = conf.positions.copy()
        pos[chain] += d
        moved = JointCandidates(pos, conf.radii, conf.side, conf.origin, conf.group,
                                conf.unary, conf.aligned)
        whole.append(joint_energy(problem, moved)[0])
    np.testing.assert_allclose(chained - chained[0], np.array(whole) - whole[0], atol=1e-9)
    assert np.ptp(chained) > 0.1  # the shifts do change the energy


def _tree_problem():
    """The Y-shaped tree with a wide root (its shoulders join its rigid group), rough
    outlines, and every joint labelled with contour 0 and a random side."""
    solving = solving_skeleton(tree_skeleton())
    cam = front_camera(ortho=True)
    ref = cam.project(solving.rest_joints)
    t = np.linspace(0.0, 1.0, 60)[:, None]
    strokes = [Stroke(ref[0] + (ref.max(0) - ref[0]) * t + [0, 30]),
               Stroke(ref.min(0) + (ref[0] - ref.min(0)) * t - [0, 30]),
               Stroke(ref[[1, 2, 3]] + [0, 25]), Stroke(ref[[1, 4, 5]] - [0, 25])]
    drawing = preprocess(strokes)
    problem = make_problem(drawing, solving, cam.pixels_per_unit(6.0), ref)
    radius = np.full(solving.n_joints, 0.2)
    radius[solving.tail_joint[0]] = 0.45
    problem = replace(problem, interior=interior_joints(solving, radius))
    rng = np.random.default_rng(1)
    n = solving.n_joints
    samples = rng.integers(0, drawing.n_samples, n)
    # Every joint from one contour: the triplets share it (sigma_a = pi/3).
    conf = JointCandidates(ref + rng.normal(0, 3, ref.shape), np.full(n, 20.0),
                           rng.choice([-1, 1], n), samples, np.zeros(n, int),
                           np.zeros(n), -np.ones((n, 48), int))
    return problem, conf


def test_set_energy_sums_the_factors_touching_the_moved_joints():
    """All trials at once equal joint_energy of each moved configuration on those joints:
    single joints (a grandparent alone: the triplets it starts), pairs, the whole arm, and
    the rigid groups of a tree whose joints carry contour labels (shared-contour triplets,
    rigid links)."""
    rng = np.random.default_rng(3)
    arm, arm_conf = _arm()
    tree, tree_conf = _tree_problem()
    groups = rigid_groups(tree)
    assert any(len(g) > 1 for g in groups)
    cases = [(arm, arm_conf, np.array(i)) for i in ([0], [1], [0, 1], [1, 2], [0, 1, 2])]
    cases += [(tree, tree_conf, g) for g in groups]
    for problem, conf, idx in cases:
        trials = conf.positions[idx][None] + rng.normal(0.0, 8.0, (5, len(idx), 2))
        trials[0] = conf.positions[idx]
        got = _set_energy(problem, conf, conf.positions, idx, trials)
        want = []
        for t in trials:
            pos = conf.positions.copy()
            pos[idx] = t
            want.append(joint_energy(problem, with_positions(conf, pos), idx)[0])
        np.testing.assert_allclose(got, want, atol=1e-9)
        assert np.ptp(got) > 0.01  # the trials do change the energy


def test_refinement_of_a_displaced_limb_end_regains_the_energy():
    """Elbow and wrist pushed off the drawn arm together: the walk (single joints and the
    limb end as a whole, step halved as it converges) gets back at least to the energy
    of the true joints, deterministically."""
    problem, conf = _arm()
    eps = problem.drawing.epsilon
    chain = limb_chains(problem, 3)[0]
    params = RefineParams(chain_trials=8, min_step=0.125, converged=0.05, trials=24,
                          iterations=12)
    truth = joint_energy(problem, conf)[0]
    for dy in (eps, -eps):
        start = conf.positions.copy()
        start[chain] += [0.0, dy]
        moved = JointCandidates(start, conf.radii, conf.side, conf.origin, conf.group,
                                conf.unary, conf.aligned)
        out, info = refine(problem, moved, problem.reference, params)
        assert info["energy_before"] > truth + 0.1
        assert info["energy_after"] <= truth
        assert np.all(np.linalg.norm(out.positions - conf.positions, axis=1) < eps)
        again, _ = refine(problem, moved, problem.reference, params)
        np.testing.assert_array_equal(out.positions, again.positions)


def test_the_search_and_the_refinement_score_the_same_energy():
    """The DP's tables (rigid joints placed by their parent, no unary) and E_match as the
    refinement computes it agree on any labelling, and the rigid joints' circles do touch
    lines (counting them would change the energy)."""
    from gesture_pose.core.gesture import embedding
    from gesture_pose.core.gesture.candidates import contour_candidates
    from gesture_pose.core.gesture.costs import unary_cost
    from gesture_pose.core.gesture.mrf import build_energy, configuration

    problem, _ = _tree_problem()
    rigid = np.flatnonzero(problem.rigid)
    assert len(rigid) >= 2 and not problem.scored[rigid].any()
    sets = [contour_candidates(problem.drawing, np.array([20.0]), bool(problem.terminal[j]),
                               problem.params, 30) for j in range(problem.solving.n_joints)]
    sets = embedding._with_rigid(problem, sets)
    energy = build_energy(problem, sets)
    rng = np.random.default_rng(5)
    touching = 0.0
    for _ in range(6):
        labels = np.array([rng.integers(len(c)) for c in sets])
        conf = configuration(sets, labels)
        assert energy.evaluate(labels) == pytest.approx(joint_energy(problem, conf)[0])
        cost, _ = unary_cost(problem.drawing, conf.positions[rigid], conf.radii[rigid],
                             False, problem.params)
        touching = max(touching, float(np.sum(1.0 - cost)))
        for j in rigid:
            trial = conf.positions[j] + rng.normal(0.0, 6.0, (4, 2))
            got = _set_energy(problem, conf, conf.positions, np.array([j]), trial[:, None])
            want = [joint_energy(problem, with_positions(conf, np.where(
                np.arange(len(labels))[:, None] == j, t, conf.positions)), [j])[0]
                for t in trial]
            np.testing.assert_allclose(got, want, atol=1e-9)
    assert touching > 0.1
