"""Ranking depth interpretations: foreshortening, joint comfort and depth flips."""

from __future__ import annotations

import dataclasses

import numpy as np

from gesture_pose.core.camera import Camera
from gesture_pose.core.skeleton import Pose
from gesture_pose.core.stick.capsules import bone_masses, capsules_from_mesh
from gesture_pose.core.stick.figure import humanoid_figure
from gesture_pose.core.stick.genetic import GAConfig
from gesture_pose.core.stick.graph import StickFigure
from gesture_pose.core.stick.kinematics import PoseModel
from gesture_pose.core.stick.lifting import depth_flips, limb_flips
from gesture_pose.core.stick.objective import EnvPin, StickObjective, Weights
from gesture_pose.core.stick.ranking import foreshortening, plausibility
from gesture_pose.core.stick.solve import StickInput, _pivot_on_pins, solve_stick
from tests.core.test_stick_figure import humanoid_skeleton

CAMERA = Camera.look_at([0.0, -4.5, 1.0], [0.0, 0.0, 1.0], width=1000, height=800)


def _pose(model: PoseModel, degrees: dict[str, list[float]]) -> np.ndarray:
    """Gene vector with the named groups' genes set (degrees), the rest at rest."""
    x = np.zeros(model.n_genes)
    for name, values in degrees.items():
        x[model.genes_of(name)] = np.radians(values)
    return x


def _drawn(model: PoseModel, x: np.ndarray) -> tuple[StickFigure, np.ndarray]:
    """The stick figure of a pose seen by CAMERA (hands and feet left out) and its joints."""
    fig = model.figure
    heads, tails, _ = model.forward(x[None])
    joints = fig.joint_positions(heads, tails)[0]
    pts = CAMERA.project(joints)
    present = ~fig.optional
    pts[~present] = np.nan
    return StickFigure(fig.joint_names, pts, present, fig.joint_parents,
                       np.zeros((0, 2))), joints


def _objective(model: PoseModel, stick: StickFigure) -> StickObjective:
    caps = capsules_from_mesh(model.skeleton)
    return StickObjective(model=model, camera=CAMERA, stick=stick, height=1.8,
                          masses=bone_masses(model.skeleton, caps), capsules=caps,
                          env_capsules=np.zeros(len(caps.bones), bool))


def _model() -> PoseModel:
    sk = humanoid_skeleton()
    return PoseModel(sk, humanoid_figure(sk), Pose.identity(sk.n_bones))


def _out_of_plane(joints: np.ndarray, a: int, b: int) -> float:
    """Angle (degrees) between the edge a-b and the view plane at its midpoint."""
    v = joints[b] - joints[a]
    ray = 0.5 * (joints[a] + joints[b]) - CAMERA.location
    return float(np.degrees(np.arcsin(abs(v @ ray) / np.linalg.norm(v) /
                                      np.linalg.norm(ray))))


def test_foreshortening_is_zero_for_the_drawn_pose_and_grows_out_of_the_view_plane():
    model = _model()
    fig = model.figure
    _, joints = _drawn(model, _pose(model, {"upper_arm.L": [0, 0, 60], "forearm.L": [40]}))
    # Lay the left forearm in the view plane (drawn at full length), then turn it out of
    # the plane about the elbow keeping its drawn direction: the projection shortens by
    # cos(angle), which the drawing does not show.
    e, w = fig.joint("elbow.L"), fig.joint("wrist.L")
    ray = joints[e] - CAMERA.location
    ray /= np.linalg.norm(ray)
    v = joints[w] - joints[e]
    across = v - ray * (v @ ray)
    across /= np.linalg.norm(across)
    poses = []
    for deg in (0.0, 20.0, 40.0):
        t = np.radians(deg)
        moved = joints.copy()
        moved[w] = joints[e] + np.linalg.norm(v) * (np.cos(t) * across - np.sin(t) * ray)
        poses.append(moved)
    pts = CAMERA.project(poses[0])
    present = ~fig.optional
    pts[~present] = np.nan
    stick = StickFigure(fig.joint_names, pts, present, fig.joint_parents, np.zeros((0, 2)))
    out = foreshortening(_objective(model, stick), np.array(poses))
    assert out[0] < 1e-3 < out[1] < out[2]
    # About (1 - cos 40 deg)^2 for the forearm (it also comes nearer the eye).
    assert 0.5 < out[2] / (1 - np.cos(np.radians(40.0))) ** 2 < 1.5


def test_limb_drawn_at_full_length_comes_out_in_the_view_plane_with_foreshortening_on():
    # By default the foreshortening term only ranks the suggestions; with the default
    # weights this forearm comes out 16 degrees off the plane (the comfort term prefers
    # a less twisted upper arm). Weighted into refinement, it holds the drawn length.
    model = _model()
    fig = model.figure
    # The left arm twisted so that the elbow bends across the view: both of its bones
    # lie in the view plane and are drawn at full length.
    x = _pose(model, {"upper_arm.L": [10, -80, 0], "forearm.L": [30]})
    stick, truth = _drawn(model, x)
    e, w, n = fig.joint("elbow.L"), fig.joint("wrist.L"), fig.joint("neck")
    assert _out_of_plane(truth, n, e) < 2.0 and _out_of_plane(truth, e, w) < 2.0
    res = solve_stick(StickInput(model.skeleton, CAMERA, stick=stick, seed=1,
                                 n_suggestions=2,
                                 ga=GAConfig(population=256, max_generations=6),
                                 weights=Weights(foreshortening=0.5)))
    best = res.suggestions[0].joints
    # 10 degrees out of the plane shorten a bone's projection by 1.5 % (1 pixel here).
    assert _out_of_plane(best, n, e) < 10.0 and _out_of_plane(best, e, w) < 10.0
    assert np.linalg.norm((best[w] - best[n]) - (truth[w] - truth[n])) < 0.05


def test_depth_flip_against_the_joint_limits_ranks_below_the_drawn_pose():
    model = _model()
    fig = model.figure
    # Forearm bent forward towards the viewer: its depth flip needs the elbow bent
    # backwards, beyond the hinge's range (or the upper arm twisted far from rest).
    x = _pose(model, {"upper_arm.L": [40, 0, 20], "forearm.L": [70]})
    stick, truth = _drawn(model, x)
    obj = _objective(model, stick)
    bounds = model.bounds(np.zeros(3), 0.3)
    flips = depth_flips(model, x, bounds, stick, CAMERA)
    assert len(flips) == 2 ** 8  # near or far end of the eight limb bones
    heads, tails, _ = model.forward(flips)
    joints = fig.joint_positions(heads, tails)
    score, terms = plausibility(obj, flips)
    drawn = int(np.argmin(np.linalg.norm(joints - truth, axis=-1).max(1)))
    assert np.abs(joints[drawn] - truth).max() < 1e-3  # the drawn pose is one of them
    assert np.argmin(score) == drawn
    # Flip the left forearm alone (bit 1: the lifted groups are upper arm, forearm,
    # thigh, shin per side): its hinge cannot bend the other way, so the flip either
    # leaves the drawing or twists the upper arm out of comfort.
    flip = drawn ^ 2
    w = fig.joint("wrist.L")
    assert np.linalg.norm(joints[flip, w] - truth[w]) > 0.1
    assert score[flip] > score[drawn] + 1e-3
    assert (terms["projection"][flip] > terms["projection"][drawn] + 1e-3 or
            terms["comfort"][flip] > terms["comfort"][drawn] + 0.1)


def _flipped_depth(model: PoseModel, x: np.ndarray, group: str, end: int,
                   stick: StickFigure) -> float:
    """Depth change the flip of ``group`` asks of joint ``end``: the far intersection.

    The eye ray through the drawn ``end`` meets the sphere about the bone's posed head
    (radius: its distance to ``end``) twice, once at the posed end; the flip aims at the
    other intersection.
    """
    fig = model.figure
    heads, tails, _ = model.forward(x[None])
    joints = fig.joint_positions(heads, tails)[0]
    c = heads[0, int(fig.groups[[g.name for g in fig.groups].index(group)].bones[0])]
    o, d = CAMERA.rays(stick.points[[end]])
    oc = o[0] - c
    b = oc @ d[0]
    disc = max(b * b - oc @ oc + np.sum((joints[end] - c) ** 2), 0.0)
    pts = o[0] + np.array([-b - np.sqrt(disc), -b + np.sqrt(disc)])[:, None] * d[0]
    dz = CAMERA.depth(pts) - CAMERA.depth(joints[end][None])[0]
    return float(dz[np.argmax(np.abs(dz))])


def test_limb_flips_turn_one_limb_or_its_end_in_depth_and_keep_the_rest():
    model = _model()
    fig = model.figure
    names = [g.name for g in fig.groups]
    # Both arms and the left leg bent out of the view plane; the right leg straight.
    x = _pose(model, {"upper_arm.L": [40, 0, 20], "forearm.L": [70],
                      "upper_arm.R": [-30, 10, 0], "forearm.R": [50],
                      "thigh.L": [50, 0, 0], "shin.L": [60]})
    stick, truth = _drawn(model, x)
    bounds = model.bounds(np.zeros(3), 0.3)
    flips = limb_flips(model, x, bounds, stick, CAMERA)
    # Per limb (upper arm, forearm, thigh, shin per side): the whole limb, its end bone.
    assert flips.shape == (8, model.n_genes)
    heads, tails, _ = model.forward(flips)
    joints = fig.joint_positions(heads, tails)
    moved = np.linalg.norm(joints - truth, axis=-1) > 1e-9  # (8, J)
    rows = {0: ("upper_arm.L", "elbow.L"), 1: ("forearm.L", "wrist.L"),
            2: ("thigh.L", "knee.L"), 3: ("shin.L", "ankle.L"),
            4: ("upper_arm.R", "elbow.R"), 5: ("forearm.R", "wrist.R")}
    for row, (group, end) in rows.items():
        bone = fig.groups[names.index(group)].bones[0]
        below = set(model.skeleton.descendants(int(bone)))
        # Only the flipped bone's genes and those of the bones it carries change...
        changed = {g.name for g in fig.groups
                   if np.any(flips[row, model.genes_of(g.name)] != x[model.genes_of(g.name)])}
        assert group in changed and all(int(fig.groups[names.index(c)].bones[0]) in below
                                        for c in changed), (group, changed)
        assert np.array_equal(flips[row, :6], x[:6])
        assert all(int(fig.joint_bones[j]) in below for j in np.flatnonzero(moved[row]))
        # ... and its end moves in depth towards the other side of the eye ray, never
        # beyond the flipped point.
        e = fig.joint(end)
        want = _flipped_depth(model, x, group, e, stick)
        dz = CAMERA.depth(joints[row, e][None])[0] - CAMERA.depth(truth[e][None])[0]
        assert abs(want) > 0.15 and 0.0 < dz / want < 1.0 + 1e-6, (group, dz, want)
        if row % 2 == 0:
            # A whole limb turns to the other side: the ball's range (the twist at its
            # limit) stops it short, but beyond half-way (0.18 of 0.29 m, 0.42 of 0.65,
            # 0.30 of 0.34).
            assert dz / want > 0.5, (group, dz, want)
        else:
            # A forearm or shin alone: only its hinge turns, in the plane the parent's
            # kept twist gives it. The right forearm's plane holds the flipped direction
            # and its wrist gets there (0.178 of 0.185 m); the left forearm and shin
            # would have to bend backwards, so the hinge straightens against its limit
            # and the end moves a few centimetres (0.046 of 0.463 m, 0.029 of 0.745): a
            # nudge the refinement carries on.
            assert changed == {group}
            g = flips[row, model.genes_of(group)]
            lo, hi = bounds[model.genes_of(group)].T
            reached = abs(dz - want) < 0.01
            at_limit = bool(np.all(np.isclose(g, lo) | np.isclose(g, hi)))
            assert reached != at_limit, (group, dz, want, g)
            assert reached == (group == "forearm.R")
    # The forearm's flip keeps the elbow where it was; the whole arm's moves it.
    assert not moved[1, fig.joint("elbow.L")] and moved[0, fig.joint("elbow.L")]


def test_flips_of_a_pinned_limb_pivot_on_its_pin():
    model = _model()
    fig = model.figure
    # The left leg (its ankle pinned) and the left arm bent out of the view plane.
    x = _pose(model, {"upper_arm.L": [40, 0, 20], "forearm.L": [70],
                      "thigh.L": [30, 10, 0], "shin.L": [20]})
    stick, truth = _drawn(model, x)
    a, p = fig.joint("ankle.L"), fig.joint("pelvis")
    pin = EnvPin(a, truth[a].copy(), np.array([0.0, 0.0, 1.0]))
    obj = dataclasses.replace(_objective(model, stick), env_pins=(pin,))
    bounds = model.bounds(np.zeros(3), 1.0)
    flips = limb_flips(model, x, bounds, stick, CAMERA)
    out = _pivot_on_pins(obj, x, flips, bounds)
    before = fig.joint_positions(*model.forward(flips)[:2])
    after = fig.joint_positions(*model.forward(out)[:2])
    # The whole leg's flip (row 2) brings the ankle 0.72 m nearer the eye than its pin;
    # moved back along the pelvis' eye ray (0.73 m) the ankle is at its pin's depth to a
    # millimetre (its sideways offset, where the hip's limits stopped the flip short of
    # the ankle's eye ray, stays), the pelvis still on its drawn point.
    depth = CAMERA.depth(np.array([before[2, a], after[2, a], truth[a]]))
    assert depth[2] - depth[0] > 0.7
    assert abs(depth[1] - depth[2]) < 0.002
    assert np.linalg.norm(CAMERA.project(after[2, p][None]) - stick.points[p]) < 1e-6
    assert not np.array_equal(out[2, :3], x[:3]) and np.array_equal(out[2, 3:], flips[2, 3:])
    # Flips that leave the pinned joint where it is (the arms) are not moved.
    still = np.linalg.norm(before[:, a] - truth[a], axis=1) < 1e-9
    assert still[[0, 1, 4, 5]].all() and np.array_equal(out[still], flips[still])
    # With the pelvis pinned too (lying, seated) its pin fixes the depth: nothing moves.
    lying = dataclasses.replace(obj, env_pins=(pin, EnvPin(p, truth[p].copy(), pin.normal)))
    assert np.array_equal(_pivot_on_pins(lying, x, flips, bounds), flips)


def test_foreshortening_term_in_the_objective_matches_finite_differences():
    from tests.core.test_stick_objective import problem
    rng = np.random.default_rng(7)
    obj, truth = problem(rng, with_grid=False)
    obj = dataclasses.replace(obj, weights=Weights(foreshortening=0.5))
    x = truth + rng.normal(scale=0.2, size=truth.size)
    f, g = obj.value_and_grad(x)
    e, terms = obj.evaluate(x[None])
    assert np.isclose(f, e[0]) and terms["foreshortening"][0] > 0
    assert np.isclose(np.sum(obj.residuals(x[None]) ** 2), f, rtol=1e-12)
    h = 1e-6
    X = np.concatenate([x + h * np.eye(x.size), x - h * np.eye(x.size)])
    E, _ = obj.evaluate(X)
    assert np.allclose((E[:x.size] - E[x.size:]) / (2 * h), g, rtol=1e-4, atol=1e-6)
    r, J = obj.residuals_and_jacobian(x)
    num = ((obj.residuals(x + h * np.eye(x.size)) - obj.residuals(x - h * np.eye(x.size)))
           / (2 * h)).T
    assert np.allclose(num, J, rtol=1e-4, atol=1e-5)
