"""Eqs. 4-11: the objective's analytic gradient against finite differences, capsules."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import least_squares

from gesture_pose.core.camera import Camera
from gesture_pose.core.skeleton import Pose
from gesture_pose.core.stick.capsules import (
    Capsules,
    body_collision,
    bone_masses,
    capsules_from_mesh,
    pair_closest,
    segment_closest,
)
from gesture_pose.core.stick.environment import Environment, distance_grid
from gesture_pose.core.stick.figure import humanoid_figure
from gesture_pose.core.stick.finish import settle_unseen_feet
from gesture_pose.core.stick.graph import StickFigure
from gesture_pose.core.stick.kinematics import PoseModel
from gesture_pose.core.stick.objective import (
    EnvPin,
    Footprint,
    LimbPin,
    StickObjective,
    Weights,
    _hull,
    hull_offset,
    polygon_offset,
    project_jacobian,
)
from gesture_pose.core.stick.pins import foot_extents
from gesture_pose.core.stick.refine import PackedRows, refine, refine_least_squares
from tests.core.test_stick_figure import humanoid_skeleton


def box(lo, hi):
    """Triangles of an axis-aligned box (outward normals)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                  for z in (lo[2], hi[2])])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
             (1, 5, 7, 3)]
    tris = [(a, b, c) for a, b, c, d in quads] + [(a, c, d) for a, b, c, d in quads]
    return v, np.array(tris)


def chair_env():
    """A floor and a chair seat (a 45 cm high box) behind the character."""
    fv = np.array([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0.0]])
    ft = np.array([[0, 1, 2], [0, 2, 3]])
    sv, st = box([-0.25, -0.05, 0.40], [0.25, 0.45, 0.45])
    return Environment(np.concatenate([fv, sv]), np.concatenate([ft, st + 4]),
                       np.r_[0, 0, np.ones(len(st), int)], ("floor", "chair"))


def problem(rng, with_grid=True):
    sk = humanoid_skeleton()
    fig = humanoid_figure(sk)
    model = PoseModel(sk, fig, Pose.identity(sk.n_bones))
    cam = Camera.look_at([1.5, -4.0, 1.2], [0, 0, 0.9], width=800, height=600)
    truth = rng.normal(scale=0.3, size=model.n_genes)
    heads, tails, _ = model.forward(truth[None])
    joints = fig.joint_positions(heads, tails)[0]
    pts = cam.project(joints) + rng.normal(scale=3.0, size=(fig.n_joints, 2))
    present = ~fig.optional
    pts[~present] = np.nan
    stick = StickFigure(fig.joint_names, pts, present, fig.joint_parents, np.zeros((0, 2)))
    caps = capsules_from_mesh(sk)
    env = chair_env()
    grid = distance_grid(env, [0, 0, 0.8], 1.2, 0.05) if with_grid else None
    obj = StickObjective(
        model=model, camera=cam, stick=stick, height=1.8, masses=bone_masses(sk, caps),
        capsules=caps, env_capsules=np.ones(len(caps.bones), bool), grid=grid,
        support=np.array([[0.1, -0.1, 0], [-0.1, -0.1, 0], [0, 0.3, 0.45]]),
        env_pins=(EnvPin(fig.joint("ankle.L"), np.array([0.1, 0, 0.09]),
                         np.array([0, 0, 1.0])),),
        limb_pins=(LimbPin(fig.joint("wrist.R"), (fig.joint("knee.L"), fig.joint("ankle.L")),
                           0.3),))
    return obj, truth


def test_gradient_matches_finite_differences():
    rng = np.random.default_rng(11)
    obj, truth = problem(rng)
    for trial in range(3):
        x = truth + rng.normal(scale=0.4, size=truth.size)
        x[:3] = rng.normal(scale=0.2, size=3) + [0, 0, -0.3 * trial]  # sink into the seat
        f, g = obj.value_and_grad(x)
        h = 1e-6
        X = np.concatenate([x + h * np.eye(x.size), x - h * np.eye(x.size)])
        E, terms = obj.evaluate(X)
        num = (E[: x.size] - E[x.size:]) / (2 * h)
        assert np.allclose(num, g, rtol=1e-4, atol=1e-6 * max(1.0, abs(f))), trial
        assert np.isclose(obj.evaluate(x[None])[0][0], f)
    # The collision term was active in at least the sunken trials.
    assert terms["collision"].max() > 0


def test_projection_jacobian():
    cam = Camera.look_at([1.5, -4.0, 1.2], [0, 0, 0.9])
    p = np.array([[0.2, 0.3, 1.1], [-0.4, 0.1, 0.2]])
    q, J = project_jacobian(cam, p)
    assert np.allclose(q, cam.project(p))
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        assert np.allclose((cam.project(p + d) - cam.project(p - d)) / (2 * h), J[:, :, k],
                           atol=1e-4)


def test_ground_truth_has_low_energy():
    rng = np.random.default_rng(5)
    obj, truth = problem(rng, with_grid=False)
    e_true, terms = obj.evaluate(truth[None], collision=False)
    e_rand, _ = obj.evaluate(rng.normal(scale=0.6, size=(50, truth.size)), collision=False)
    assert terms["projection"][0] < np.min(e_rand)


def test_segment_distance_against_brute_force():
    rng = np.random.default_rng(2)
    p0, p1, q0, q1 = rng.normal(size=(4, 60, 3))
    q1[:20] = q0[:20] + 1e-3 * (p1[:20] - p0[:20])  # nearly degenerate segments
    off = np.cross(p1[20:40] - p0[20:40], rng.normal(size=(20, 3)))
    off /= np.linalg.norm(off, axis=1, keepdims=True)
    q0[20:40], q1[20:40] = p0[20:40] + off, p1[20:40] + off  # parallel, 1 apart
    s, t, d = segment_closest(p0, p1, q0, q1)
    u = np.linspace(0, 1, 201)
    a = p0[:, None] + u[None, :, None] * (p1 - p0)[:, None]
    b = q0[:, None] + u[None, :, None] * (q1 - q0)[:, None]
    brute = np.linalg.norm(a[:, :, None] - b[:, None], axis=-1).min(axis=(1, 2))
    assert np.all(d <= brute + 1e-9)
    assert np.allclose(d, brute, atol=1e-2)
    assert np.all((s >= 0) & (s <= 1) & (t >= 0) & (t <= 1))
    assert np.allclose(d[20:40], 1.0)


def test_body_collision_counts_only_overlaps():
    sk = humanoid_skeleton()
    caps = capsules_from_mesh(sk)
    heads, tails = sk.rest_heads[None], sk.rest_tails[None]
    e, _, _ = body_collision(caps, heads, tails)
    assert e[0] == 0.0
    # Move the left hand onto the right thigh: they now overlap.
    h, t = heads.copy(), tails.copy()
    hand, thigh = sk.index("hand.L"), sk.index("thigh.R")
    shift = 0.5 * (sk.rest_heads[thigh] + sk.rest_tails[thigh]) - sk.rest_heads[hand]
    h[0, hand] += shift
    t[0, hand] += shift
    e, _, _ = body_collision(caps, h, t)
    i = list(caps.bones).index(hand)
    j = list(caps.bones).index(thigh)
    expected = (caps.radii[i] + caps.radii[j]) ** 2  # axes cross: distance 0
    assert np.isclose(e[0], expected, rtol=1e-6)


def test_pair_closest_is_segment_closest_where_capsules_can_touch():
    # Random capsules crowded into a small box: some pairs overlap, most do not.
    rng = np.random.default_rng(5)
    c, P = 30, 4
    start = rng.uniform(-0.5, 0.5, size=(P, c, 3))
    end = start + rng.normal(scale=0.15, size=(P, c, 3))
    end[:, :3] = start[:, :3]  # spheres (axes of no length)
    ii, jj = np.triu_indices(c, 1)
    caps = Capsules(np.arange(c), rng.uniform(0.02, 0.08, c), np.stack([ii, jj], 1))
    s, t, d = pair_closest(caps, start, end)
    s0, t0, d0 = segment_closest(start[:, ii], end[:, ii], start[:, jj], end[:, jj])
    rr = caps.radii[ii] + caps.radii[jj]
    near = np.isfinite(d)
    # Bit-identical where computed; left out only where the capsules are apart.
    assert np.array_equal(s[near], s0[near]) and np.array_equal(t[near], t0[near])
    assert np.array_equal(d[near], d0[near])
    assert np.all(d0[~near] > rr[None].repeat(P, 0)[~near])
    assert 0 < near.sum() < 0.5 * near.size
    pen = np.maximum(rr - d, 0.0)
    assert np.array_equal(pen, np.maximum(rr - d0, 0.0)) and np.any(pen > 0)


def test_body_collision_gradient_is_the_all_pairs_one():
    """The pruned pairs add nothing: energy and gradient equal the all-pairs formula."""
    rng = np.random.default_rng(6)
    n, P = 24, 3
    heads = rng.uniform(-0.4, 0.4, size=(P, n, 3))
    tails = heads + rng.normal(scale=0.2, size=(P, n, 3))
    ii, jj = np.triu_indices(n, 1)
    caps = Capsules(np.arange(n), rng.uniform(0.03, 0.07, n), np.stack([ii, jj], 1))
    e, gh, gt = body_collision(caps, heads, tails, grad=True)
    # The formula on all pairs, as body_collision computed it before the pruning.
    p0, p1, q0, q1 = heads[:, ii], tails[:, ii], heads[:, jj], tails[:, jj]
    s, t, d = segment_closest(p0, p1, q0, q1)
    pen = np.maximum(caps.radii[ii] + caps.radii[jj] - d, 0.0)
    assert np.array_equal(e, np.sum(pen**2, axis=1)) and np.all(e > 0)
    diff = p0 + s[..., None] * (p1 - p0) - q0 - t[..., None] * (q1 - q0)
    g = (-2.0 * pen)[..., None] * (diff / np.maximum(d, 1e-12)[..., None])
    rh, rt = np.zeros_like(heads), np.zeros_like(tails)
    for arr, idx, coef in ((rh, ii, 1 - s), (rt, ii, s), (rh, jj, -(1 - t)), (rt, jj, -t)):
        np.add.at(arr, (slice(None), idx), coef[..., None] * g)
    assert np.array_equal(gh, rh) and np.array_equal(gt, rt)


def test_capsule_radii_from_a_cylinder_mesh():
    sk = humanoid_skeleton()
    i = sk.index("shin.L")
    a, b = sk.rest_heads[i], sk.rest_tails[i]
    axis = (b - a) / np.linalg.norm(b - a)
    ortho = np.cross(axis, [1, 0, 0])
    ortho /= np.linalg.norm(ortho)
    other = np.cross(axis, ortho)
    ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    ts = np.linspace(0.1, 0.9, 10)
    verts = np.array([a + tt * (b - a) + 0.06 * (np.cos(q) * ortho + np.sin(q) * other)
                      for tt in ts for q in ang])
    w = np.zeros((len(verts), sk.n_bones))
    w[:, i] = 1.0
    caps = capsules_from_mesh(sk, verts, w)
    assert caps.bones.tolist() == [i]
    assert np.isclose(caps.radii[0], 0.06)


def test_polygon_offset_inside_and_outside():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    q = np.array([[0.5, 0.5], [2.0, 0.5], [-1.0, -1.0]])
    off = polygon_offset(q, square)
    assert np.allclose(off, [[0, 0], [1, 0], [-1, -1]])
    seg = np.array([[0, 0], [2, 0.0]])
    assert np.allclose(polygon_offset(np.array([[1.0, 0.5]]), seg), [[0, 0.5]])


def test_hull_offset_is_the_polygon_offset_of_the_hull():
    rng = np.random.default_rng(5)
    for k in (1, 2, 3, 5):
        pts = rng.normal(size=(k, 2))
        q = rng.normal(scale=1.5, size=(200, 2))
        want = polygon_offset(q, _hull(pts))
        got = hull_offset(q, np.broadcast_to(pts, (len(q), k, 2)))
        assert np.allclose(got, want, atol=1e-12), k
    assert np.any(np.all(got == 0, axis=1)) and np.any(np.any(got != 0, axis=1))


def footprint_problem(rng):
    """:func:`problem` with both ankles' soles (heel to toe) supporting the body."""
    obj, truth = problem(rng)
    fig = obj.model.figure
    feet = []
    for side in ("L", "R"):
        j = fig.joint(f"ankle.{side}")
        tip = int(np.flatnonzero(fig.joint_parents == j)[0])
        feet.append(Footprint(j, tip, np.array([0.2 if side == "L" else -0.2, -0.4, 0.0]),
                              -0.05, 0.25))
    return dataclasses.replace(obj, support=np.array([[0.2, -0.4, 0], [-0.2, -0.4, 0]]),
                               footprints=tuple(feet)), truth


def test_foot_extents_reach_from_behind_the_ankle_to_the_toe():
    sk = humanoid_skeleton()
    fig = humanoid_figure(sk)
    caps = capsules_from_mesh(sk)
    ankle = fig.joint("ankle.L")
    tip, heel, toe = foot_extents(fig, sk, caps, ankle)
    rest = fig.joint_positions(sk.rest_heads[None], sk.rest_tails[None])[0]
    foot = rest[tip] - rest[ankle]
    assert fig.joint_parents[tip] == ankle
    assert heel < 0 < toe
    assert np.linalg.norm(foot[:2]) <= toe < np.linalg.norm(foot[:2]) + 0.1
    assert foot_extents(fig, sk, caps, fig.joint("hand.L")) is None  # no child joint


def test_footprints_support_along_the_posed_feet_with_exact_derivatives():
    rng = np.random.default_rng(3)
    obj, truth = footprint_problem(rng)
    plain = dataclasses.replace(obj, footprints=())
    X = truth + rng.normal(scale=0.4, size=(6, truth.size))
    X[:, :3] = rng.normal(scale=0.2, size=(6, 3))
    e_fp, t_fp = obj.evaluate(X, collision=False)
    e_pl, t_pl = plain.evaluate(X, collision=False)
    # The soles only add support area: never more balance energy, less where the centre
    # of mass is off the ankles' segment towards the toes.
    assert np.all(t_fp["balance"] <= t_pl["balance"] + 1e-15)
    assert np.any(t_fp["balance"] < 0.9 * t_pl["balance"])
    assert np.all(t_fp["balance"] > 0)  # the test's poses stand off the soles too
    assert np.allclose(np.sum(obj.residuals(X) ** 2, 1), obj.evaluate(X)[0], rtol=1e-12)
    h = 1e-6
    for x in X[:3]:
        f, g = obj.value_and_grad(x, collision=False)
        E, _ = obj.evaluate(np.concatenate([x + h * np.eye(x.size), x - h * np.eye(x.size)]),
                            collision=False)
        num = (E[: x.size] - E[x.size:]) / (2 * h)
        assert np.allclose(num, g, rtol=1e-4, atol=1e-6 * max(1.0, abs(f)))
        r1, J = obj.residuals_and_jacobian(x, collision=False)
        R = obj.residuals(np.concatenate([x + h * np.eye(x.size), x - h * np.eye(x.size)]),
                          collision=False)
        num = ((R[: x.size] - R[x.size:]) / (2 * h)).T
        assert np.allclose(num, J, rtol=1e-4, atol=1e-5)


def test_unseen_feet_turn_back_without_paying_energy():
    rng = np.random.default_rng(5)
    obj, truth = footprint_problem(rng)
    model, fig, sk = obj.model, obj.model.figure, obj.model.skeleton
    up = np.array([0.0, 0.0, 1.0])
    pins = tuple(EnvPin(f.joint, f.point, up, stands=True) for f in obj.footprints)
    bounds = model.bounds(np.zeros(3), 0.5)
    rest = fig.joint_positions(sk.rest_heads[None], sk.rest_tails[None])[0]

    def headings(v):
        """Per foot: its heading's angle on the ground from the shin's natural one."""
        _, _, fr = model.forward(v[None])
        out = []
        for f in obj.footprints:
            foot = sk.index(f"foot.{fig.joint_names[f.joint][-1]}")
            r = rest[f.tip] - rest[f.joint]
            a = (fr[0, foot] @ sk.rest_frames[foot].T @ r)[:2]
            b = (fr[0, sk.parents[foot]] @ sk.rest_frames[sk.parents[foot]].T @ r)[:2]
            out.append(abs(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b)))
        return np.array(out)

    x = truth.copy()
    for side in ("L", "R"):  # both feet turned far about the shin
        gi = next(i for i, g in enumerate(fig.groups) if g.name == f"foot.{side}")
        x[model.group_genes[gi][2]] = 0.45
    y = settle_unseen_feet(obj, x, bounds, pins)
    e_x, e_y = obj.evaluate(np.stack([x, y]))[0]
    assert e_y <= e_x + 1e-12
    assert np.all(headings(y) <= headings(x) + 1e-9)
    assert np.any(headings(y) < headings(x) - 0.1)
    jx, jy = (fig.joint_positions(*model.forward(v[None])[:2])[0] for v in (x, y))
    drawn = obj.stick.present
    assert np.allclose(jx[drawn], jy[drawn], atol=1e-12)  # the turn moves no drawn joint
    _, _, fx = model.forward(x[None])
    _, _, fy = model.forward(y[None])
    for f in obj.footprints:  # turned about the pin's normal: the sole's tilt is kept
        b = fig.joint_bones[f.joint]
        sole = sk.rest_frames[b].T @ up
        assert np.isclose((fx[0, b] @ sole) @ up, (fy[0, b] @ sole) @ up, atol=1e-9)
    # A drawn toe keeps its foot as solved.
    seen = dataclasses.replace(obj, stick=dataclasses.replace(
        obj.stick, present=np.ones_like(drawn), points=np.nan_to_num(obj.stick.points)))
    assert np.array_equal(settle_unseen_feet(seen, x, bounds, pins), x)


def test_distance_grid_on_a_plane():
    env = chair_env()
    grid = distance_grid(env, [1.0, -1.0, 0.5], 0.5, 0.05)
    pts = np.array([[1.0, -1.0, 0.12], [0.8, -1.2, 0.17]])
    d, g = grid.sample(pts)
    assert np.allclose(d, pts[:, 2], atol=0.01)
    assert np.allclose(grid.sample(np.array([[1.0, -1.0, 0.6]]))[0], 0.2)  # clamped
    assert np.allclose(g, [[0, 0, 1], [0, 0, 1]], atol=0.1)


def test_distance_grid_samples_are_distinct_and_exact_far_from_the_origin():
    # 40 km out the half-spacing cell indices no longer fit the packed key (2^20): the
    # deduplication falls back to hashing and must still keep distinct, covering samples.
    for offset in (0.0, 40000.0):
        v, t = box([offset - 0.5, -0.5, -0.05], [offset + 0.5, 0.5, 0.0])
        env = Environment(v, t, np.zeros(len(t), int), ("Floor",))
        grid = distance_grid(env, [offset, 0.0, 0.0], 0.3, 0.05)
        cells = np.floor(grid.samples / 0.025)
        assert len(np.unique(cells, axis=0)) == len(grid.samples) > 100
        d, _ = grid.sample(np.array([[offset + 0.1, 0.05, 0.07]]))
        assert abs(d[0] - 0.07) < 0.025


def test_residuals_square_to_the_energy_and_jacobian_matches_finite_differences():
    rng = np.random.default_rng(11)
    obj, truth = problem(rng)
    X = truth + rng.normal(scale=0.4, size=(4, truth.size))
    X[:, 2] -= 0.3  # sink into the seat: collision residuals are active
    e, terms = obj.evaluate(X)
    r = obj.residuals(X)
    assert terms["collision"].max() > 0
    assert np.allclose(np.sum(r**2, 1), e, rtol=1e-12, atol=1e-12)
    for x in X[:2]:
        r1, J = obj.residuals_and_jacobian(x)
        assert np.allclose(r1, obj.residuals(x[None])[0], atol=1e-14)
        h = 1e-6
        num = (obj.residuals(x + h * np.eye(x.size)) - obj.residuals(x - h * np.eye(x.size)))
        num = (num / (2 * h)).T
        # Environment penetrations use the nearest surface sample (piecewise): compare the
        # rows that are smooth, i.e. everything but the environment samples.
        smooth = r1.size - int(np.sum(obj.env_capsules)) * 5
        assert np.allclose(num[:smooth], J[:smooth], rtol=1e-4, atol=1e-5)


def test_deferred_jacobians_belong_to_their_own_points():
    # The refinement asks for a Jacobian only at accepted points, after other trial
    # points were evaluated: each deferred Jacobian must be its own point's, with and
    # without collisions and foreshortening.
    rng = np.random.default_rng(12)
    obj, truth = problem(rng)
    X = truth + rng.normal(scale=0.4, size=(2, truth.size))
    X[:, 2] -= 0.3
    for o in (obj, dataclasses.replace(obj, weights=Weights(foreshortening=0.5))):
        for collision in (True, False):
            first, second = (o.residuals_deferred(x, collision) for x in X)
            for x, (r, jacobian) in zip(X[::-1], (second, first), strict=True):
                r_all, J_all = o.residuals_and_jacobian(x, collision)
                assert np.array_equal(r, r_all) and np.array_equal(jacobian(), J_all)
                assert np.allclose(r, o.residuals(x[None], collision)[0], atol=1e-14)
            h = 1e-6
            x = X[1]
            num = (o.residuals(x + h * np.eye(x.size), collision) -
                   o.residuals(x - h * np.eye(x.size), collision)).T / (2 * h)
            J = second[1]()
            smooth = J.shape[0] - (int(np.sum(o.env_capsules)) * 5 if collision else 0)
            assert np.allclose(num[:smooth], J[:smooth], rtol=1e-4, atol=1e-5)


def test_distance_limit_keeps_penetrations():
    rng = np.random.default_rng(2)
    grid = distance_grid(chair_env(), [0, 0, 0.8], 1.2, 0.05)
    pts = rng.uniform([-0.5, -0.5, 0.0], [0.5, 0.6, 0.6], size=(400, 3))
    d0, g0 = grid.sample(pts)
    d1, g1 = grid.sample(pts, limit=0.08)
    near = d0 < 0.08
    assert near.sum() > 20 and (~near).sum() > 20
    assert np.array_equal(d0[near], d1[near]) and np.array_equal(g0[near], g1[near])
    assert np.all(d1[~near] >= 0.08)


def test_least_squares_refinement_converges_faster_than_lbfgs():
    rng = np.random.default_rng(3)
    obj, truth = problem(rng, with_grid=False)
    bounds = obj.model.bounds(np.zeros(3), 0.5)
    x0 = np.clip(truth + rng.normal(scale=0.05, size=truth.size), *bounds.T)
    e0 = obj.evaluate(x0[None])[0][0]
    gn = refine_least_squares(obj, x0, bounds, max_iterations=30)
    lb = refine(obj, x0, bounds, max_iterations=60)  # about twice the evaluations
    assert gn.evaluations <= 30 and np.all((gn.x >= bounds[:, 0]) & (gn.x <= bounds[:, 1]))
    assert np.isclose(gn.energy, obj.evaluate(gn.x[None])[0][0])
    # The pins disagree with the drawing, so the minimum is well above zero (about 1.14).
    assert gn.energy < 0.6 * e0
    assert gn.energy < lb.energy - 0.02
    longer = refine_least_squares(obj, gn.x, bounds, max_iterations=60)
    assert gn.energy - longer.energy < 1e-3 * gn.energy  # already converged


def test_packed_rows_keep_the_gauss_newton_model():
    # The trust-region solve sees the smooth rows and the nonzero penetrations: |r|^2,
    # J^T J and J^T r are those of all rows; beyond k penetrations the smallest fold into
    # one row, the norm of theirs, with the norm's gradient as its Jacobian.
    rng = np.random.default_rng(5)
    smooth, n_pen, G = 7, 40, 5
    A = rng.normal(size=(smooth + n_pen, G))
    c = rng.normal(size=smooth + n_pen)
    c[smooth + 1::3] += 4.0  # some penetrations larger than the others
    x0 = rng.normal(size=G)
    r = A @ x0 + c
    off = smooth + np.flatnonzero(rng.random(n_pen) < 0.6)  # capsules apart: zero rows
    A[off], c[off] = 0.0, 0.0
    r, J = A @ x0 + c, A
    active = n_pen - off.size
    pk = PackedRows.of(r, smooth, active + 3)
    rp, Jp = pk.residuals(r), pk.jacobian(r, J)
    assert rp.shape == (smooth + active + 4,) and Jp.shape == (rp.size, G)
    assert pk.fold.size == 0 and rp[-1] == 0.0
    assert np.isclose(rp @ rp, r @ r, rtol=1e-14)
    assert np.allclose(Jp.T @ Jp, J.T @ J, rtol=1e-13) and np.allclose(Jp.T @ rp, J.T @ r)
    k = active - 4
    pk = PackedRows.of(r, smooth, k)
    rp, Jp = pk.residuals(r), pk.jacobian(r, J)
    assert pk.keep.size == k and pk.fold.size == 4
    assert np.all(np.abs(r[pk.fold]).max() <= np.abs(r[pk.keep]).min())
    assert np.isclose(rp @ rp, r @ r, rtol=1e-14)
    h = 1e-6
    num = [(np.linalg.norm((A @ (x0 + h * e) + c)[pk.fold]) -
            np.linalg.norm((A @ (x0 - h * e) + c)[pk.fold])) / (2 * h) for e in np.eye(G)]
    assert np.allclose(Jp[-1], num, atol=1e-7)


def test_packed_refinement_ends_where_the_full_one_does():
    # The same Gauss-Newton model: from a pose sunk into the seat (penetrations active),
    # the refinement through the packed rows reaches the full rows' energy.
    rng = np.random.default_rng(11)
    obj, truth = problem(rng)
    bounds = obj.model.bounds(np.zeros(3), 0.5)
    x0 = np.clip(truth + rng.normal(scale=0.1, size=truth.size), *bounds.T)
    x0[2] -= 0.5
    full = least_squares(lambda x: obj.residuals_and_jacobian(x)[0], x0,
                         jac=lambda x: obj.residuals_and_jacobian(x)[1],
                         bounds=tuple(bounds.T), method="trf", max_nfev=30, xtol=1e-8,
                         ftol=1e-6, gtol=1e-8)
    r0, _ = obj.residuals_and_jacobian(x0)
    assert np.count_nonzero(r0[obj.smooth_residual_count(x0.size):]) >= 3
    packed = refine_least_squares(obj, x0, bounds, max_iterations=30)
    assert np.isclose(packed.energy, obj.evaluate(packed.x[None])[0][0], rtol=1e-12)
    assert abs(packed.energy - 2 * full.cost) < 1e-4 * packed.energy


def test_smooth_residual_count_is_where_penetrations_start():
    rng = np.random.default_rng(4)
    obj, truth = problem(rng)
    for o in (obj, dataclasses.replace(obj, weights=Weights(foreshortening=0.5, comfort=0.0))):
        assert o.smooth_residual_count(truth.size) == o.residuals(truth[None], False).shape[1]


def test_a_lying_leg_lowers_its_ankle_pin_to_the_shin_and_heel():
    from gesture_pose.core.stick.finish import _clearance, _lie_on_chain

    obj, _ = problem(np.random.default_rng(2))
    model, fig, sk = obj.model, obj.model.figure, obj.model.skeleton
    ankle = fig.joint("ankle.L")
    pin = EnvPin(ankle, np.array([0.1, 0.0, 0.09]), np.array([0.0, 0.0, 1.0]), True)
    # Standing (rest): the shin stands on its foot, the standing height is kept.
    assert _lie_on_chain(obj, np.zeros(model.n_genes), pin) is pin
    # Lying on the back: the shin lies along the floor and holds the ankle lower.
    x = np.zeros(model.n_genes)
    x[3] = -np.pi / 2
    heads, tails, _ = model.forward(x[None])
    shin = tails[0, sk.index("shin.L")] - heads[0, sk.index("shin.L")]
    assert abs(shin[2]) < 0.2 * np.linalg.norm(shin)  # within 12 degrees of the floor
    now = _clearance(obj, heads, tails, ankle, pin.normal)[0]
    rest = _clearance(obj, sk.rest_heads[None], sk.rest_tails[None], ankle, pin.normal)[0]
    foot = sk.index("foot.L")
    assert np.isclose(rest, sk.rest_heads[foot, 2] - min(
        (np.minimum(s[:, 2], e[:, 2]) - obj.capsules.radii)[np.isin(
            obj.capsules.bones, [foot, sk.index("shin.L")])].min()
        for s, e in [obj.capsules.segments(sk.rest_heads, sk.rest_tails)]))
    assert now < rest - 0.02
    moved = _lie_on_chain(obj, x, pin)
    assert moved.stands and np.allclose(moved.normal, pin.normal)
    assert np.isclose(moved.target[2] - pin.target[2], now - rest)
    # Still on the eye ray through the drawn ankle.
    assert np.allclose(obj.camera.project(moved.target[None])[0], obj.stick.points[ankle],
                       atol=1e-6)
