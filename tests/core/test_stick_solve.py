"""GA operators' statistics and end-to-end reconstruction on the core humanoid."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from gesture_pose.core.camera import Camera
from gesture_pose.core.exceptions import InputError
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.skeleton import Pose
from gesture_pose.core.stick.capsules import capsules_from_mesh
from gesture_pose.core.stick.edit import drag_node
from gesture_pose.core.stick.environment import find_seat
from gesture_pose.core.stick.figure import humanoid_figure
from gesture_pose.core.stick.genetic import (
    GAConfig,
    gaussian_mutation,
    genetic_search,
    merge,
    row_hash,
    sbx,
)
from gesture_pose.core.stick.graph import StickFigure
from gesture_pose.core.stick.kinematics import PoseModel
from gesture_pose.core.stick.normalize import normalize_figure
from gesture_pose.core.stick.objective import EnvPin
from gesture_pose.core.stick.pins import EnvPinSpec, pin_offsets
from gesture_pose.core.stick.solve import (
    StickInput,
    _initial_population,
    _pinned_root_depth,
    _spine_flipped,
    solve_stick,
)
from gesture_pose.core.stick.threads import in_background, row_threads, split_rows
from tests.core.test_stick_figure import humanoid_skeleton
from tests.core.test_stick_objective import chair_env


def test_sbx_children_keep_the_parents_mean_and_spread_with_eta():
    rng = np.random.default_rng(0)
    n, g = 20000, 8
    a, b = rng.uniform(-1, 1, (n, g)), rng.uniform(-1, 1, (n, g))
    bounds = np.tile([-10.0, 10.0], (g, 1))
    c1, c2 = sbx(a, b, bounds, rng, eta=10.0, gene_fraction=0.5, probability=0.7)
    assert np.allclose(c1 + c2, a + b)  # SBX preserves the mean of each pair
    changed = ~np.isclose(c1, a)
    # 0.7 of the pairs, half of their genes.
    assert abs(changed.mean() - 0.35) < 0.01
    pairs = changed.any(1).mean()
    assert abs(pairs - 0.7 * (1 - 0.5**g)) < 0.01
    spread = np.abs(c1 - c2)[changed] / np.abs(a - b)[changed]
    _, _, = sbx(a, b, bounds, rng, eta=2.0)
    c1w, c2w = sbx(a, b, bounds, np.random.default_rng(1), eta=2.0, probability=1.0,
                   gene_fraction=1.0)
    wide = np.abs(c1w - c2w) / np.abs(a - b)
    assert np.median(spread) < np.median(wide)  # larger eta: children nearer the parents
    assert abs(np.median(spread) - 1.0) < 0.05  # beta's median is 1


def test_gaussian_mutation_rate_and_scale():
    rng = np.random.default_rng(3)
    x = np.zeros((5000, 10))
    bounds = np.tile([-5.0, 5.0], (10, 1))
    y = gaussian_mutation(x, bounds, rng, rate=0.1, scale=0.1)
    hit = y != 0
    assert abs(hit.mean() - 0.1) < 0.01
    assert abs(y[hit].std() - 1.0) < 0.05  # 0.1 of the range 10
    clipped = gaussian_mutation(x, np.tile([-0.01, 0.01], (10, 1)), rng, 1.0, 10.0)
    assert np.all(np.abs(clipped) <= 0.01)


def test_merge_keeps_the_best_distinct_individuals():
    rng = np.random.default_rng(4)
    pop = rng.random((300, 12))
    pop[200:] = pop[:100] + 1e-7  # near-copies of the first 100 (same 0.1 % cell or next)
    energies = rng.random(300)
    spans = np.ones(12)
    kept, e = merge(pop, energies, 250, spans)
    key = np.round(kept / 1e-3).astype(np.int64)
    assert len(np.unique(key, axis=0)) == len(kept)  # no two kept rows share a cell
    assert np.all(np.diff(e) >= 0) and e[0] == energies.min()
    # The row-wise reference: the same rows as sorting whole rows would keep.
    order = np.argsort(energies, kind="stable")
    ref_key = np.round(pop[order] / 1e-3).astype(np.int64)
    _, first = np.unique(ref_key, axis=0, return_index=True)
    assert np.array_equal(kept, pop[order[np.sort(first)][:250]])
    assert len(np.unique(row_hash(ref_key))) == len(np.unique(ref_key, axis=0))


def test_genetic_search_minimizes_a_shifted_sphere_deterministically():
    def run(seed):
        rng = np.random.default_rng(seed)
        bounds = np.tile([-3.0, 3.0], (6, 1))
        init = rng.uniform(-3, 3, (256, 6))
        return genetic_search(lambda X: np.sum((X - 1.2) ** 2, 1), bounds, init, rng,
                              GAConfig(population=256, max_generations=60, patience=10))
    a, b = run(5), run(5)
    assert np.array_equal(a.population, b.population)
    assert a.energies[0] < 1e-2
    assert np.all(np.diff(a.history) <= 1e-15)  # elitist merge never loses the best


def _stand_problem(noise=0.0, seed=0):
    sk = humanoid_skeleton()
    fig = humanoid_figure(sk)
    model = PoseModel(sk, fig, Pose.identity(sk.n_bones))
    x = np.zeros(model.n_genes)
    for name, val in {"upper_arm.L": [30, 0, 0], "forearm.L": [50], "upper_arm.R": [-20, 0, 20],
                      "thigh.L": [-20, 0, 0], "shin.L": [25]}.items():
        x[model.genes_of(name)] = np.radians(val)
    x[:3] = [0.0, -1.0, 0.0]
    heads, tails, _ = model.forward(x[None])
    joints = fig.joint_positions(heads, tails)[0]
    cam = Camera.look_at([2.0, -4.5, 1.4], [0, -0.3, 0.8], width=1000, height=800)
    pts = cam.project(joints) + np.random.default_rng(seed).normal(scale=noise, size=(15, 2))
    present = ~fig.optional
    pts[~present] = np.nan
    stick = StickFigure(fig.joint_names, pts, present, fig.joint_parents, np.zeros((0, 2)))
    offs = pin_offsets(fig, sk, capsules_from_mesh(sk))
    pins = tuple(EnvPinSpec(a, joints[fig.joint(a)] - [0, 0, offs[fig.joint(a)]],
                            np.array([0, 0, 1.0]), "floor") for a in ("ankle.L", "ankle.R"))
    return sk, fig, cam, stick, pins, joints


def test_reconstructs_a_standing_pose_with_feet_pinned():
    sk, fig, cam, stick, pins, truth = _stand_problem()
    inp = StickInput(sk, cam, stick=stick, environment=chair_env(), env_pins=pins, seed=3,
                     n_suggestions=2, ga=GAConfig(population=384, max_generations=10),
                     refine_iterations=100)
    res = solve_stick(inp)
    body = [fig.joint(n) for n in ("pelvis", "neck", "head", "knee.L", "ankle.L", "knee.R",
                                   "ankle.R")]
    best = res.suggestions[0]
    # Pinned legs and the torso are recovered (the arms' depth is ambiguous in one view:
    # the suggestions hold the alternatives).
    assert np.linalg.norm(best.joints[body] - truth[body], axis=1).mean() < 0.05
    errors = [np.linalg.norm(s.joints - truth, axis=1)[stick.present].mean()
              for s in res.suggestions]
    assert min(errors) < 0.15
    for s in res.suggestions:
        assert np.all(s.pin_residuals < 1e-6)
    assert len(res.suggestions) >= 2
    assert [s.score for s in res.suggestions] == sorted(s.score for s in res.suggestions)
    again = solve_stick(inp)
    assert np.array_equal(again.suggestions[0].genes, res.suggestions[0].genes)


def test_pinned_root_starts_above_the_standing_contacts():
    # A camera looking down (from 1.4 m at a point 0.8 m high) at a standing figure: its
    # pelvis is nearer the eye than its pinned ankles.
    sk, fig, cam, stick, pins, truth = _stand_problem()
    up = np.array([0.0, 0.0, 1.0])
    env = tuple(EnvPin(fig.joint(p.joint), p.point, p.normal) for p in pins)
    pelvis = fig.joint("pelvis")
    z = _pinned_root_depth(cam, stick.points[pelvis], env, pelvis, up)
    mean_depth = float(np.mean(cam.depth(np.array([p.target for p in env]))))
    true_depth = float(cam.depth(truth[pelvis][None])[0])
    assert z < mean_depth - 0.05
    assert abs(z - true_depth) < 0.5 * abs(mean_depth - true_depth)
    # The point on the pelvis' eye ray at that depth is straight above the contacts'
    # centroid (horizontally): the support of the balance term.
    root = cam.unproject_at_depth(stick.points[pelvis][None], z)[0]
    centre = np.mean([p.target for p in env], axis=0)
    off = root - centre
    ray = cam.rays(stick.points[pelvis][None])[1][0]
    flat = ray - up * (ray @ up)
    assert abs((off - up * (off @ up)) @ flat) < 1e-9
    # Lying (the pelvis pinned too) keeps the pins' mean depth; so does a contact that
    # does not face up (a hand on a wall).
    lying = env + (EnvPin(pelvis, truth[pelvis] - [0, 0, 0.1], up),)
    assert _pinned_root_depth(cam, stick.points[pelvis], lying, pelvis, up) == (
        pytest.approx(float(np.mean(cam.depth(np.array([p.target for p in lying]))))))
    wall = (EnvPin(fig.joint("wrist.R"), truth[fig.joint("wrist.R")], np.array([1.0, 0, 0])),)
    assert _pinned_root_depth(cam, stick.points[pelvis], wall, pelvis, up) == (
        pytest.approx(float(cam.depth(wall[0].target[None])[0])))


def test_initial_roots_face_the_way_the_facing_option_says(monkeypatch):
    # The Facing option decides which way the search's roots face, whatever the labels:
    # arms swapped (crossed) or both pairs swapped do not turn the body.
    sk, fig, cam, stick, _, truth = _stand_problem()
    import gesture_pose.core.stick.solve as solve_module

    seen = []

    def spy(*args):
        seen.append(args[6])
        raise StopIteration

    monkeypatch.setattr(solve_module, "_initial_population", spy)
    for facing in ("front", "back"):
        for labels in (stick.swapped("arms"), stick.swapped("arms").swapped("legs")):
            with pytest.raises(StopIteration):
                solve_stick(StickInput(sk, cam, stick=labels, facing=facing))
    assert seen == ["front", "front", "back", "back"]
    monkeypatch.undo()
    model = PoseModel(sk, fig, Pose.identity(sk.n_bones))
    bounds = model.bounds(np.zeros(3), 0.5)
    eye = -cam.rays(cam.project(truth[:1]))[1][0]
    for facing, sign in (("front", 1.0), ("back", -1.0)):
        for labels in (stick, stick.swapped("arms"), stick.swapped("arms").swapped("legs")):
            pop = _initial_population(model, bounds, 200, labels, cam, np.zeros(3), facing,
                                      np.random.default_rng(0))
            forward = exp_map(pop[:, 3:6]) @ fig.forward  # (P, 3)
            towards = np.mean(sign * forward @ eye > 0.0)
            assert towards > 0.75, (facing, towards)


def test_facing_must_be_front_or_back():
    sk, fig, cam, stick, pins, truth = _stand_problem()
    with pytest.raises(InputError, match="Facing"):
        solve_stick(StickInput(sk, cam, stick=stick, facing="left"))


def test_spine_flip_mirrors_the_body_bend_along_the_eye_ray():
    sk, fig, cam, stick, pins, truth = _stand_problem()
    model = PoseModel(sk, fig, Pose.identity(sk.n_bones))
    bounds = model.bounds(np.zeros(3), 2.0)
    x = np.zeros(model.n_genes)
    x[:3] = [0.0, -1.0, 0.0]
    x[model.genes_of("spine")] = np.radians([35.0, 0.0, 0.0])  # bent over, towards the eye
    flipped = _spine_flipped(model, x, bounds, cam)
    before = fig.joint_positions(*model.forward(x[None])[:2])[0]
    after = fig.joint_positions(*model.forward(flipped[None])[:2])[0]
    neck = fig.joint("neck")
    o, ray = (a[0] for a in cam.rays(cam.project(before[neck][None])))
    d0, d1 = before[neck] - before[0], after[neck] - after[0]
    # Same pelvis; the spine joint moves along its own eye ray to the other point where
    # the ray meets the sphere about the pelvis: the same pixel under perspective (the
    # mirror about the pelvis' eye ray moved it 16 pixels here), as far from the pelvis,
    # behind it along the ray where it was in front. The spine's own bend is kept.
    assert np.allclose(after[0], before[0])
    assert np.linalg.norm(cam.project(after[neck][None]) - cam.project(before[neck][None])
                          ) < 1e-6
    assert np.linalg.norm(d1) == pytest.approx(np.linalg.norm(d0), abs=1e-9)
    assert d0 @ ray < -0.1 and d1 @ ray > 0.1
    assert (after[neck] - o) @ ray > (before[neck] - o) @ ray + 0.2
    assert np.array_equal(flipped[6:], x[6:])


def test_spine_in_the_view_plane_has_no_mirror():
    # A spine across the eye ray through its top (the neck) mirrors onto itself: no
    # second seed (its depth flips would repeat the first's); tilted 5 degrees out of
    # that plane it has one, turned by twice the tilt.
    sk = humanoid_skeleton()
    fig = humanoid_figure(sk)
    model = PoseModel(sk, fig, Pose.identity(sk.n_bones))
    bounds = model.bounds(np.zeros(3), 2.0)
    x = np.zeros(model.n_genes)
    joints = fig.joint_positions(*model.forward(x[None])[:2])[0]
    neck = joints[fig.joint("neck")]
    d = neck - joints[0]
    d /= np.linalg.norm(d)
    across = np.cross(d, [1.0, 0.0, 0.0])
    for tilt, mirrored in ((0.0, False), (5.0, True)):
        t = np.radians(tilt)
        eye = neck - 4.0 * (np.cos(t) * across + np.sin(t) * d)
        cam = Camera.look_at(eye.tolist(), neck.tolist(), width=1000, height=800)
        flipped = _spine_flipped(model, x, bounds, cam)
        assert (flipped is not None) == mirrored, tilt
    assert np.degrees(np.linalg.norm(flipped[3:6])) == pytest.approx(10.0, abs=0.1)


def test_pinned_feet_stand_flat_on_the_floor():
    # Both ankles pinned to the floor: each foot ends sole down and flat on it, its lowest
    # skin (capsules) on the pin's contact plane, neither sunk nor tilted up.
    sk, fig, cam, stick, pins, _ = _stand_problem(noise=1.0, seed=1)
    res = solve_stick(StickInput(sk, cam, stick=stick, environment=chair_env(),
                                 env_pins=pins, seed=1, n_suggestions=2,
                                 ga=GAConfig(population=384, max_generations=8)))
    model = PoseModel(sk, fig, Pose.identity(sk.n_bones))
    caps = capsules_from_mesh(sk)
    up = np.array([0.0, 0.0, 1.0])

    def lowest(heads, tails, side):
        chain = np.isin(caps.bones, sk.descendants(sk.index(f"foot.{side}")))
        start, end = caps.segments(heads, tails)
        return float(np.min(np.minimum(start[0, chain] @ up, end[0, chain] @ up) -
                            caps.radii[chain]))

    for s in res.suggestions:
        heads, tails, frames = model.forward(s.genes[None])
        for side in "LR":
            foot = sk.index(f"foot.{side}")
            sole_up = frames[0, foot] @ sk.rest_frames[foot].T @ up
            assert np.degrees(np.arccos(min(sole_up @ up, 1.0))) < 0.5
            contact = pins[0 if side == "L" else 1].point @ up
            assert abs(lowest(heads, tails, side) - contact) < 2e-3
        assert np.all(s.pin_residuals < 1e-6)


def test_seat_found_behind_the_drawn_hips():
    env = chair_env()
    cam = Camera.look_at([2.0, -4.5, 1.4], [0, -0.3, 0.8], width=1000, height=800)
    hips = np.array([0.0, 0.2, 0.45 + 0.06])
    o, d = cam.rays(cam.project(hips[None]))
    seat = find_seat(env, o[0], d[0], seated_hip_height=0.5, hip_radius=0.06,
                     near=1.0, far=8.0)
    assert seat is not None and env.object_names[seat.object_index] == "chair"
    assert np.isclose(seat.point[2], 0.45)
    assert np.linalg.norm(seat.point[:2] - hips[:2]) < 0.15
    assert seat.centerness > 0.5
    # A seat too high for the character (knee height 0.2 m) is not a seat.
    assert find_seat(env, o[0], d[0], 0.2, 0.06, near=1.0, far=8.0) is None


def test_normalization_scales_overlong_drawings():
    sk, fig, cam, stick, _, _ = _stand_problem()
    lengths = np.full(fig.n_joints, 0.1)
    scaled, factor = normalize_figure(stick, lengths, pixels_per_unit=100.0, tolerance=1.0)
    e = scaled.drawn_edges()
    drawn = np.linalg.norm(scaled.points[e[:, 1]] - scaled.points[e[:, 0]], axis=1)
    assert factor < 1 and np.isclose(drawn.max(), 10.0)
    assert np.allclose(scaled.points[0], stick.points[0])
    same, one = normalize_figure(stick, np.full(fig.n_joints, 10.0), 100.0)
    assert one == 1.0 and same is stick


def test_drag_local_and_global():
    sk, fig, cam, stick, _, _ = _stand_problem()
    wrist = fig.joint("wrist.L")
    local = drag_node(stick, wrist, stick.points[wrist] + [5.0, 0.0], global_radius=30.0)
    moved = np.flatnonzero(np.any(np.abs(local.points - stick.points) > 1e-9, axis=1))
    assert moved.tolist() == [wrist]
    far = stick.points[wrist] + [80.0, 60.0]
    glob = drag_node(stick, wrist, far, global_radius=30.0)
    assert np.allclose(glob.points[wrist], far, atol=1e-6)
    # The chain above moves (not the pelvis), the other limbs follow rigidly.
    assert np.allclose(glob.points[fig.joint("pelvis")], stick.points[fig.joint("pelvis")])
    assert not np.allclose(glob.points[fig.joint("elbow.L")], stick.points[fig.joint("elbow.L")])
    shift = glob.points[fig.joint("neck")] - stick.points[fig.joint("neck")]
    assert np.allclose(glob.points[fig.joint("head")] - stick.points[fig.joint("head")], shift)


def test_non_humanoid_solve_reprojects_onto_the_drawing():
    from gesture_pose.core.stick.figure import character_figure
    from tests.core.test_stick_graph import _animal
    sk = _animal()
    fig, _ = character_figure(sk)
    model = PoseModel(sk, fig, Pose.identity(sk.n_bones))
    x = np.zeros(model.n_genes)
    x[6:] = np.random.default_rng(4).uniform(-0.3, 0.3, model.n_genes - 6)
    heads, tails, _ = model.forward(x[None])
    truth = fig.joint_positions(heads, tails)[0]
    cam = Camera.look_at([3.0, -2.5, 1.2], [0, -0.4, 0.7], width=800, height=600)
    px = cam.project(truth)
    stick = StickFigure(fig.joint_names, px, np.ones(fig.n_joints, bool), fig.joint_parents,
                        np.zeros((0, 2)))
    res = solve_stick(StickInput(sk, cam, stick=stick, seed=2, n_suggestions=2,
                                 ga=GAConfig(population=256, max_generations=8),
                                 refine_iterations=60))
    assert any("topology" in w for w in res.warnings)
    best = res.suggestions[0]
    assert np.abs(cam.project(best.joints) - px).max() < 3.0  # pixels
    # Bones keep their lengths (edges drawn from the head of their bone).
    e = fig.edges()
    rest = fig.joint_positions(sk.rest_heads, sk.rest_tails)
    e = e[np.linalg.norm(rest[e[:, 0]] - sk.rest_heads[fig.joint_bones[e[:, 1]]], axis=1)
          < 1e-9]
    assert len(e) >= 8
    got = np.linalg.norm(best.joints[e[:, 1]] - best.joints[e[:, 0]], axis=1)
    assert np.allclose(got, np.linalg.norm(truth[e[:, 1]] - truth[e[:, 0]], axis=1))


def test_limb_pin_is_placed_exactly():
    from gesture_pose.core.stick.pins import LimbPinSpec
    sk, fig, cam, stick, pins, _ = _stand_problem()
    limb = LimbPinSpec("wrist.R", ("pelvis", "knee.R"), 0.6)
    res = solve_stick(StickInput(sk, cam, stick=stick, environment=chair_env(), env_pins=pins,
                                 limb_pins=(limb,), seed=1, n_suggestions=1,
                                 ga=GAConfig(population=256, max_generations=6),
                                 refine_iterations=40))
    j = res.suggestions[0].joints
    target = 0.4 * j[fig.joint("pelvis")] + 0.6 * j[fig.joint("knee.R")]
    assert np.linalg.norm(j[fig.joint("wrist.R")] - target) < 1e-6
    # The residuals cover the body pin too (after the environment pins).
    assert len(res.suggestions[0].pin_residuals) == len(pins) + 1
    assert np.all(res.suggestions[0].pin_residuals < 1e-6)


def test_contact_dot_chooses_the_seat():
    sk, fig, cam, stick, _, _ = _stand_problem()
    env = chair_env()
    seat_px = cam.project(np.array([[0.0, 0.15, 0.45 + 0.06]]))
    dotted = StickFigure(stick.joint_names, stick.points, stick.present, stick.parents,
                         seat_px)
    small = GAConfig(population=128, max_generations=3)
    with_dot = solve_stick(StickInput(sk, cam, stick=dotted, environment=env, seed=0,
                                      use_contact=True, n_suggestions=1, ga=small,
                                      refine_iterations=10))
    without = solve_stick(StickInput(sk, cam, stick=dotted, environment=env, seed=0,
                                     n_suggestions=1, ga=small, refine_iterations=10))
    assert with_dot.seat is not None
    assert env.object_names[with_dot.seat.object_index] == "chair"
    assert without.seat is None  # the drawn pelvis is over the floor in front of the chair


def test_limb_flips_run_only_when_pins_or_a_seat_fix_the_depth(monkeypatch):
    # Without environment pins or a seat nothing fixes the body's depth and the more
    # plausible flips slid it along the eye ray: the limb-flip search is skipped.
    import gesture_pose.core.stick.solve as solve_module
    calls = []
    original = solve_module._flip_descent

    def counted(*args, **kwargs):
        calls.append(len(args[1]))
        return original(*args, **kwargs)

    monkeypatch.setattr(solve_module, "_flip_descent", counted)
    sk, fig, cam, stick, pins, _ = _stand_problem()
    env = chair_env()
    seat_px = cam.project(np.array([[0.0, 0.15, 0.45 + 0.06]]))
    dotted = StickFigure(stick.joint_names, stick.points, stick.present, stick.parents,
                         seat_px)
    small = dict(seed=0, n_suggestions=1, ga=GAConfig(population=128, max_generations=3),
                 refine_iterations=10)
    runs = {"free": StickInput(sk, cam, stick=stick, environment=env, **small),
            "pinned": StickInput(sk, cam, stick=stick, environment=env, env_pins=pins,
                                 **small),
            "seated": StickInput(sk, cam, stick=dotted, environment=env, use_contact=True,
                                 **small)}
    seen = {}
    for name, inp in runs.items():
        calls.clear()
        res = solve_stick(inp)
        seen[name] = (len(calls), res.seat is not None)
        assert all(n > 0 for n in calls)  # given the refined candidates
    assert seen == {"free": (0, False), "pinned": (1, False), "seated": (1, True)}


def test_two_threads_give_the_same_suggestions_as_one():
    # The genetic search's populations in two fixed chunks of rows (one in the worker
    # thread) and the distance grid built meanwhile: bit-identical results.
    sk, fig, cam, stick, pins, _ = _stand_problem(noise=1.0, seed=2)
    inp = StickInput(sk, cam, stick=stick, environment=chair_env(), env_pins=pins, seed=2,
                     n_suggestions=2, ga=GAConfig(population=384, max_generations=6))
    one = solve_stick(dataclasses.replace(inp, threads=1))
    two = solve_stick(inp)
    assert inp.threads == 2
    assert len(one.suggestions) == len(two.suggestions)
    for a, b in zip(one.suggestions, two.suggestions, strict=True):
        assert np.array_equal(a.genes, b.genes)
        assert np.array_equal(a.joints, b.joints)
        assert a.score == b.score


def test_split_rows_joins_two_fixed_chunks():
    seen = []

    def fn(x, y):
        seen.append((len(x), threading.get_ident()))
        # Nested splits run in the chunk's own thread.
        inner = split_rows(lambda z: z * 2.0, x)
        return inner + y, {"sum": np.sum(x, 1)}

    x = np.arange(300 * 4, dtype=float).reshape(300, 4)
    y = np.ones((300, 4))
    assert split_rows(fn, x, y)[0].shape == (300, 4) and len(seen) == 1  # one thread
    seen.clear()
    with row_threads(2):
        out, terms = split_rows(fn, x, y)
        assert sorted(n for n, _ in seen) == [128, 172]  # cut at a multiple of 64
        assert len({t for _, t in seen}) == 2
        assert np.array_equal(out, 2.0 * x + 1.0)
        assert np.array_equal(terms["sum"], np.sum(x, 1))
        assert split_rows(lambda z: z + 1.0, x[:10])[0, 0] == 1.0  # few rows: one call
        with pytest.raises(ZeroDivisionError):  # raised in the worker's chunk
            split_rows(lambda z: z if len(z) > 150 else 1 // 0, x)
        task = in_background(lambda a: a.sum(), x)
        assert task.result() == x.sum()
    with pytest.raises(ValueError):
        with row_threads(3):
            pass
