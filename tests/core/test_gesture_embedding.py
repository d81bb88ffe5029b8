"""The 2D embedding on tiny hand-made drawings with exact expectations."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from gesture_pose.core.camera import Camera
from gesture_pose.core.exceptions import InputError
from gesture_pose.core.gesture import embedding, solving
from gesture_pose.core.gesture.candidates import JointCandidates, contour_candidates
from gesture_pose.core.gesture.consistency import assign_contours
from gesture_pose.core.gesture.costs import unary_cost
from gesture_pose.core.gesture.embedding import GestureParams, fit_drawing, posed_joints
from gesture_pose.core.gesture.mrf import interior_joints, joint_energy, make_problem
from gesture_pose.core.gesture.preprocess import preprocess
from gesture_pose.core.gesture.radii import discrete_radii, fit_sphere, joint_radii
from gesture_pose.core.gesture.refine import rigid_groups
from gesture_pose.core.gesture.solving import solving_skeleton
from gesture_pose.core.skeleton import Pose
from gesture_pose.core.stroke import Stroke

from .fixtures import chain_skeleton, front_camera, tree_skeleton
from .test_gesture_fixtures import bent_arm_outline, capsule_vertices

R = 0.1125  # limb radius, metres (30 px in the orthographic front camera)


def _arm_case():
    cam = front_camera(ortho=True)  # 800 px for 3 m: 266.7 px per metre
    s, e, w = np.array([-0.8, 0, 0.8]), np.array([0.1, 0, 0.8]), np.array([0.7, 0, 0.8])
    skel = chain_skeleton(np.stack([s, e, w]))
    outline = bent_arm_outline(s[[0, 2]], e[[0, 2]], 0.6, R)
    pixels = cam.project(np.stack([outline[:, 0], np.zeros(len(outline)), outline[:, 1]], 1))
    verts = capsule_vertices(np.stack([s, e, w]), R)
    truth = cam.project(np.stack([s, e, e + [0, 0, 0.6]]))
    return cam, skel, pixels, verts, truth


def test_bent_arm_puts_the_elbow_at_the_arc_centre_inside_the_arm():
    cam, skel, pixels, verts, truth = _arm_case()
    emb = fit_drawing([Stroke(pixels)], skel, Pose.identity(2), verts, cam)
    elbow = emb.joint_index("b0 tail")
    eps = emb.epsilon
    # Within one resampling step (the naturalness prior pulls a little towards straight).
    assert np.linalg.norm(emb.joints2d[elbow] - truth[1]) < eps
    # Shoulder and wrist at their caps' centres.
    assert np.linalg.norm(emb.joints2d[emb.joint_index("b0 head")] - truth[0]) < eps
    assert np.linalg.norm(emb.joints2d[emb.joint_index("b1 tail")] - truth[2]) < eps
    # The elbow comes from the contours, on the arc's concave side (inside the arm).
    assert emb.joint_visible[elbow]
    assert emb.joint_radius[elbow] == pytest.approx(30.0, abs=eps)
    outer_arc = pixels[30:54]
    to_centre = truth[1] - outer_arc
    to_elbow = emb.joints2d[elbow] - outer_arc
    assert np.all(np.einsum("nd,nd->n", to_centre, to_elbow) > 0)
    assert emb.coverage > 0.85
    assert all(len(segs) > 0 for segs in emb.bone_segments)
    assert set(emb.timings) >= {"preprocess", "candidates", "mrf", "consistency", "refine"}


def test_refinement_from_the_pose_is_kept_only_when_it_fits_better(monkeypatch):
    """_refine_both keeps the walk from the pose with no more overlapping parts and either
    a lower energy at no less coverage, or ``coverage_gain`` more coverage at most
    ``symmetric_tolerance`` more energy (refine and the contour assignment faked)."""
    n = 3
    reference = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    conf = JointCandidates(reference + 5.0, np.full(n, 4.0), np.zeros(n, int),
                           -np.ones(n, int), -np.ones(n, int), np.zeros(n),
                           -np.ones((n, 48), int))
    calls = []

    def run(case):
        # case: (energy, overlaps, coverage) of the discrete walk and of the pose's walk
        def fake_refine(problem, start, ref, params):
            from_pose = bool(np.array_equal(start.positions, ref))
            calls.append(from_pose)
            return start, {"energy_after": case[from_pose][0]}

        def fake_assign(problem, placed):
            got = case[bool(np.array_equal(placed.positions, reference))]
            return SimpleNamespace(overlaps=[(0, 1)] * got[1], coverage=got[2])

        monkeypatch.setattr(embedding, "refine", fake_refine)
        monkeypatch.setattr(embedding, "assign_contours", fake_assign)
        out, info = embedding._refine_both(None, conf, reference, GestureParams())
        from_pose = bool(np.array_equal(out.positions, reference))
        assert info["pose_start"] == int(from_pose)
        return from_pose

    discrete = (5.0, 1, 0.80)
    assert run((discrete, (4.0, 1, 0.80)))          # lower energy, as good otherwise
    assert run((discrete, (4.0, 0, 0.90)))          # better on every count
    assert not run((discrete, (5.0, 1, 0.80)))      # no lower energy
    assert not run((discrete, (4.0, 1, 0.79)))      # less coverage (a limb left behind)
    assert not run((discrete, (4.0, 2, 0.95)))      # more overlapping parts
    assert run((discrete, (5.4, 1, 0.83)))          # 3% more coverage for 0.4 more energy
    assert run((discrete, (5.4, 0, 0.83)))          # the same with fewer overlaps
    assert not run((discrete, (5.4, 1, 0.81)))      # 1% more coverage: not enough
    assert not run((discrete, (5.6, 1, 0.90)))      # coverage bought with 0.6 more energy
    assert not run((discrete, (5.4, 2, 0.90)))      # more overlapping parts
    calls.clear()
    out, info = embedding._refine_both(None, conf, reference,
                                       replace(GestureParams(), bind_start=False))
    assert calls == [False] and info["pose_start"] == 0


def test_fit_is_deterministic():
    cam, skel, pixels, verts, _ = _arm_case()
    a = fit_drawing([Stroke(pixels)], skel, Pose.identity(2), verts, cam)
    b = fit_drawing([Stroke(pixels)], skel, Pose.identity(2), verts, cam)
    np.testing.assert_array_equal(a.joints2d, b.joints2d)


def test_tiny_drawing_and_missing_mesh_are_input_errors():
    cam, skel, pixels, verts, _ = _arm_case()
    small = (pixels - pixels.mean(0)) * 0.05 + pixels.mean(0)
    with pytest.raises(InputError, match="far smaller"):
        fit_drawing([Stroke(small)], skel, Pose.identity(2), verts, cam)
    with pytest.raises(InputError, match="mesh"):
        fit_drawing([Stroke(pixels)], skel, Pose.identity(2), np.zeros((0, 3)), cam)


def test_drawing_beside_the_character_is_an_input_error():
    cam, skel, pixels, verts, _ = _arm_case()
    size = np.ptp(pixels, axis=0)
    beside = pixels + [2.0 * size[0], 0.0]  # the same outline, drawn next to the arm
    with pytest.raises(InputError, match="beside the character"):
        fit_drawing([Stroke(beside)], skel, Pose.identity(2), verts, cam)
    # Shifted by a fraction of its size it still overlaps the character: fitted.
    near = fit_drawing([Stroke(pixels + 0.2 * size)], skel, Pose.identity(2), verts, cam)
    assert np.all(np.isfinite(near.joints2d))


def test_solving_skeleton_joints_and_exclusion():
    skel = tree_skeleton()
    sol = solving_skeleton(skel)
    # Connected children share their parent's tail joint; unconnected heads are new joints
    # linked rigidly (-1) to the nearer joint of the parent.
    assert sol.head_joint[1] == sol.tail_joint[0]
    arm = list(skel.names).index("arm.L")
    k = int(np.flatnonzero(sol.bones == arm)[0])
    assert sol.head_joint[k] != sol.tail_joint[0]
    assert sol.joint_link_bone[sol.head_joint[k]] == -1
    assert sol.joint_parent[sol.head_joint[k]] == sol.tail_joint[0]
    assert np.all(sol.joint_parent < np.arange(sol.n_joints))
    # A bone shorter than 2 steps (2% of the rest diagonal) is left out and its parent's
    # tail is no longer terminal.
    pts = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 2.02]])
    chain = chain_skeleton(pts)
    sol = solving_skeleton(chain)
    assert sol.bones.tolist() == [0, 1] and sol.excluded.tolist() == [2]
    assert sol.extends[sol.tail_joint[1]] and not sol.terminal[sol.tail_joint[1]]
    # It still ends its limb in the drawing (a hand that fingers continue): Section 5.4's
    # enumeration places it.
    assert sol.limb_ends[sol.tail_joint[1]] and not sol.limb_ends[sol.tail_joint[0]]
    assert sol.limb_ends[sol.head_joint[0]]  # the root, with a single child
    # The "Gesture" collection overrides the choice.
    sol = solving_skeleton(chain, override=np.array([True, False, False]))
    assert sol.bones.tolist() == [0]
    with pytest.raises(InputError, match="Gesture"):
        solving_skeleton(chain, override=np.zeros(3, bool))


def test_bones_moving_no_skin_are_not_solved():
    """A glTF importer marks every joint deforming: an IK pole target (a leaf no vertex is
    weighted to) is left out, a spine bone without weights of its own but carrying skinned
    bones below it stays, and without any weights nothing changes."""
    skel = tree_skeleton()  # root, neck, arm.L, fore.L, arm.R, fore.R
    weighted = np.array([False, True, True, True, False, True])
    sol = solving_skeleton(skel, weighted=weighted)
    assert sol.bones.tolist() == [0, 1, 2, 3, 4, 5]  # arm.R carries fore.R's skin
    weighted[5] = False  # the right arm moves no skin: a pole target and its child
    sol = solving_skeleton(skel, weighted=weighted)
    assert sol.bones.tolist() == [0, 1, 2, 3]
    np.testing.assert_array_equal(solving.skinned_subtrees(skel, weighted),
                                  [True, True, True, True, False, False])
    assert solving_skeleton(skel, weighted=np.zeros(6, bool)).bones.tolist() == list(range(6))
    # Through the fit: its skin weights decide.
    cam, arm, pixels, verts, _ = _arm_case()
    weights = np.zeros((len(verts), 2))
    weights[:, 0] = 1.0  # all skin on the first bone: the second is a helper
    emb = fit_drawing([Stroke(pixels)], arm, Pose.identity(2), verts, cam, weights)
    assert emb.solving.bones.tolist() == [0]


def test_sphere_fit_and_capsule_radii():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(200, 3))
    pts = 0.7 * pts / np.linalg.norm(pts, axis=1, keepdims=True) + [1, 2, 3]
    centre, radius = fit_sphere(pts)
    np.testing.assert_allclose(centre, [1, 2, 3], atol=1e-9)
    assert radius == pytest.approx(0.7)
    pts3 = np.array([[0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    skel = chain_skeleton(pts3)
    sol = solving_skeleton(skel)
    r_min, r_max = joint_radii(sol, skel, capsule_vertices(pts3, 0.1, 2000))
    np.testing.assert_allclose(r_min, 0.1, rtol=0.1)
    inner = ~sol.terminal
    np.testing.assert_allclose(r_max[inner], 0.1, rtol=0.1)
    # The end cap's sphere may widen the terminal joint's range, never past 1.5x.
    assert np.all((r_max[sol.terminal] >= 0.095) & (r_max[sol.terminal] <= 0.15))


def test_discrete_radii_step_epsilon():
    np.testing.assert_allclose(discrete_radii(10, 31, 10), [10, 20, 30])
    np.testing.assert_allclose(discrete_radii(10, 11, 10), [10.5])
    np.testing.assert_allclose(discrete_radii(10, 15, 10), [10, 15])
    assert len(discrete_radii(1, 100, 1, max_count=4)) == 4


def test_interior_bones_join_the_rigid_neighbourhood():
    """A bone hanging from a rigid offset whose tail's circle overlaps the circle of the joint
    the offset starts from (a clavicle inside the chest) is rigid; a longer one is free."""
    sol = solving_skeleton(tree_skeleton())
    chest = sol.tail_joint[0]
    heads = [sol.head_joint[k] for k in (2, 4)]  # arm.L and arm.R heads, rigid offsets
    tails = [sol.tail_joint[k] for k in (2, 4)]  # 0.6 from the chest joint
    assert all(sol.joint_link_bone[h] == -1 and sol.joint_parent[h] == chest for h in heads)
    radius = np.full(sol.n_joints, 0.2)
    assert not interior_joints(sol, radius).any()
    radius[chest] = 0.45  # 0.45 + 0.2 > 0.6: both arm tails lie inside the chest's circle
    inside = interior_joints(sol, radius)
    assert np.flatnonzero(inside).tolist() == sorted(tails)
    cam = front_camera(ortho=True)
    stroke = Stroke(np.array([[100.0, 100.0], [700.0, 500.0]]))
    problem = make_problem(preprocess([stroke]), sol, 100.0, cam.project(sol.rest_joints))
    assert np.flatnonzero(problem.rigid).tolist() == sorted(heads)
    problem = replace(problem, interior=inside)
    assert np.flatnonzero(problem.rigid).tolist() == sorted(heads + tails)
    groups = rigid_groups(problem)
    assert len(groups) == 1 and sorted(groups[0].tolist()) == sorted([chest, *heads, *tails])


def test_near_scales_follow_the_distance_from_the_root():
    """Through a perspective camera 6 m away, a joint 1 m along the skeleton from the root
    can come to 5 m: its link may look up to 6/5 as long; at the root nothing changes, and
    an orthographic view never scales."""
    from gesture_pose.core.gesture.embedding import near_scales

    sol = solving_skeleton(chain_skeleton(np.array([[0.0, 0, 0.8], [0.5, 0, 0.8],
                                                    [1.0, 0, 0.8]])))
    world = sol.rest_joints
    cam = front_camera()
    ppu = cam.pixels_per_unit(6.0)
    scale = near_scales(cam, sol, world, ppu)
    reach = np.linalg.norm(world - world[0], axis=1)
    np.testing.assert_allclose(scale, 6.0 / (6.0 - reach), rtol=1e-6)
    assert scale.max() > 1.19
    ortho = front_camera(ortho=True)
    np.testing.assert_allclose(near_scales(ortho, sol, world, ortho.pixels_per_unit(6.0)),
                               1.0)
    # A second tree (a prop) 1 m nearer is measured from its own root.
    from dataclasses import replace as dc_replace
    two = dc_replace(sol, joint_parent=np.array([-1, 0, -1]))
    moved = world + np.array([[0, 0, 0], [0, 0, 0], [0, -1.0, 0]])
    got = near_scales(cam, two, moved, ppu)
    np.testing.assert_allclose(got[2], 6.0 / 5.0, rtol=1e-6)


def test_rigid_joints_have_no_unary_term():
    """E_match scores rigid joints (hip and shoulder heads) as the search does: placed by
    rigidity, without a unary term, even where their circle touches a line."""
    sol = solving_skeleton(tree_skeleton())
    cam = front_camera(ortho=True)
    ref = cam.project(sol.rest_joints)
    head = int(sol.head_joint[2])  # arm.L's head, a rigid offset from the chest
    r = 12.0
    line = Stroke(np.array([ref[head] + [-300.0, -r], ref[head] + [300.0, -r]]))
    problem = make_problem(preprocess([line]), sol, 100.0, ref)
    assert problem.rigid[head] and not problem.scored[head] and problem.scored.sum() > 0
    n = sol.n_joints

    def unary(j: int) -> float:
        return float(unary_cost(problem.drawing, ref[j:j + 1], np.array([r]),
                                bool(problem.terminal[j]), problem.params)[0][0])

    assert 0.0 < unary(head) < 1.0  # tangent to the line: counted, it would pay this
    _, aligned = unary_cost(problem.drawing, ref, np.full(n, r), False, problem.params)
    conf = JointCandidates(ref, np.full(n, r), np.zeros(n, int), -np.ones(n, int),
                           -np.ones(n, int), np.zeros(n), aligned)
    terms = joint_energy(problem, conf)[1]
    scored = np.flatnonzero(problem.scored)
    assert terms["unary"] == pytest.approx(sum(unary(int(j)) for j in scored))


def test_coverage_moves_offer_limb_ends_the_contours_left_unexplained():
    """With the wrist placed halfway up the forearm, the hand's end cap is unexplained:
    the wrist's sites are there, none where it already is (Section 5.4, our order)."""
    cam, skel, pixels, _, truth = _arm_case()
    d = preprocess([Stroke(pixels)])
    sol = solving_skeleton(skel)
    ppu = cam.pixels_per_unit(6.0)
    problem = make_problem(d, sol, ppu, cam.project(sol.rest_joints))
    params = GestureParams()
    r = R * ppu
    contour = [contour_candidates(d, np.array([r]), bool(problem.terminal[j]), problem.params,
                                  params.pool_candidates) for j in range(sol.n_joints)]
    wrist = sol.joint_bones.index("b1 tail")
    placed = truth.copy()
    placed[wrist] = 0.5 * (truth[1] + truth[2])
    n = sol.n_joints
    conf = JointCandidates(placed, np.full(n, r), np.zeros(n, int), -np.ones(n, int),
                           -np.ones(n, int), np.zeros(n), -np.ones((n, 48), int))
    assign = assign_contours(problem, conf)
    assert assign.coverage < 0.85
    ends = np.flatnonzero(sol.limb_ends & (sol.joint_parent >= 0))
    assert sol.limb_ends[0] and 0 not in ends  # the root, a limb end, is not moved
    sites = embedding._coverage_sites(problem, assign, ends, contour, conf, params)
    eps = d.epsilon
    moved = [s for j, s in sites if j == wrist]
    assert 1 <= len(moved) <= params.coverage_sites
    assert min(np.linalg.norm(s.positions[0] - truth[2]) for s in moved) < 1.5 * eps
    for j, s in sites:
        assert np.linalg.norm(s.positions[0] - placed[j]) > 1.5 * eps
        assert np.count_nonzero(~assign.covered[s.aligned[0][s.aligned[0] >= 0]]) >= 2
        # Never the root (the shoulder, a limb end of this chain: offered the hand's cap it
        # would reverse the arm), and within reach of the parent as placed.
        k = int(sol.joint_parent[j])
        assert k >= 0
        assert np.linalg.norm(s.positions[0] - placed[k]) <= (
            1.2 * problem.link_length[j] + 2 * eps)
    # The moves place the wrist on the cap (the DP re-solved with it there) and explain
    # the drawing: the constraints are met.
    out, solves = embedding._coverage_moves(problem, problem, ends, contour, contour, conf,
                                            assign, params, {})
    assert solves >= 1
    assert np.linalg.norm(out.positions[wrist] - truth[2]) < 1.5 * eps
    got = assign_contours(problem, out)
    assert got.coverage >= params.min_coverage and not got.overlaps


def test_an_enumerated_solution_is_accepted_by_the_constraints_or_its_gains():
    params = GestureParams()  # min coverage 0.85, penalty 10, gain 0.02, tolerance 0.5

    def got(overlaps: int, coverage: float):
        return SimpleNamespace(overlaps=[(0, 1)] * overlaps, coverage=coverage)

    old = (got(1, 0.70), 5.0)
    assert embedding._accepts((got(0, 0.86), 9.0), old, params)      # meets both
    assert embedding._accepts((got(0, 0.70), 9.0), old, params)      # 9 < 5 + 10
    assert not embedding._accepts((got(0, 0.60), 9.0), old, params)  # lost coverage
    assert embedding._accepts((got(1, 0.75), 5.4), old, params)      # covers more
    assert not embedding._accepts((got(1, 0.75), 5.6), old, params)  # for too much
    # Coverage and energy trade at 0.5 per 0.02 (0.25 per percent of the drawing).
    assert embedding._accepts((got(1, 0.71), 5.2), old, params)      # 1% for 0.2
    assert not embedding._accepts((got(1, 0.71), 5.3), old, params)  # 1% for 0.3
    assert not embedding._accepts((got(1, 0.75), 5.0 + 0.51), old, params)  # capped
    assert not embedding._accepts((got(1, 0.70), 5.0), old, params)  # no gain at all
    assert embedding._accepts((got(1, 0.69), 4.7), old, params)      # 1% less for 0.3 less
    assert not embedding._accepts((got(1, 0.69), 4.8), old, params)  # 1% less for 0.2 less


def test_a_blocking_resolve_buys_coverage_at_the_consistency_rate():
    # resolve_rate: 0.25 of E_match per percent, at least 0.5 (on by default).
    params = GestureParams()
    old = (14, 0.811, 7.49)
    # The 2D bench's tail_up under oriented_conformity: 10 pairs fewer and 6.5% more
    # coverage for 2.84 more energy, which a 2% jump alone used to buy.
    assert not embedding._resolves((4, 0.876, 10.33), old, params)
    assert embedding._resolves((4, 0.876, 7.49 + 1.6), old, params)   # 6.5% for 1.6
    assert embedding._resolves((4, 0.811, 7.49 + 0.5), old, params)   # the tolerance
    assert not embedding._resolves((14, 0.9, 7.6), old, params)       # not lower at all
    off = GestureParams(resolve_rate=False)
    assert embedding._resolves((4, 0.876, 10.33), old, off)  # any, for 2%


def test_the_second_seed_wins_on_energy_net_of_coverage_not_on_the_penalty():
    params = GestureParams()

    def got(overlaps: int, coverage: float):
        return SimpleNamespace(overlaps=[(0, 1)] * overlaps, coverage=coverage)

    # The 3D bench's oblique reach: the arm recovered, 2 pairs fewer, 6.9% more coverage
    # for 0.8 more E_match (5.91 - 25 * 0.845 < 5.10 - 25 * 0.776).
    assert embedding._seed_accepts((got(0, 0.845), 5.906), (got(2, 0.776), 5.101), params)
    # The 2D bench's step at 3/4: constraints met, 4 pairs fewer, but 2.8 more E_match
    # for 4.6% more coverage: the leg moved off its contour is refused.
    assert not embedding._seed_accepts((got(0, 0.858), 5.944), (got(4, 0.812), 3.136),
                                       params)
    # Never more overlapping pairs.
    assert not embedding._seed_accepts((got(3, 0.9), 3.0), (got(2, 0.8), 5.0), params)


def test_coverage_moves_keep_the_best_solve_the_rule_accepts(monkeypatch):
    """Each round ranks only the solves _accepts takes: a better-ranked solve it refuses
    (more coverage bought with much more energy) does not end the moves."""
    n = 2
    conf = JointCandidates(np.zeros((n, 2)), np.ones(n), np.zeros(n, int), -np.ones(n, int),
                           -np.ones(n, int), np.zeros(n), -np.ones((n, 48), int))
    site = {k: replace(conf.take(np.array([0])), positions=np.array([[float(k), 0.0]]))
            for k in (1, 2)}
    # site 1: coverage 0.80 for 9.0 more energy (refused); site 2: 0.75 for 0.2 (taken)
    outcome = {1: (0.80, 10.0), 2: (0.75, 1.2)}

    def fake_sites(problem, assign, terminals, contour, cur, params):
        return [] if cur.positions[1, 0] else [(1, site[1]), (1, site[2])]

    def fake_solve(problem, fine, contour, placed, params, cache, memo):
        pos = conf.positions.copy()
        pos[1] = placed[1].positions[0]
        return replace(conf, positions=pos), 0.0

    def fake_assign(problem, c):
        cov = outcome[int(c.positions[1, 0])][0] if c.positions[1, 0] else 0.70
        return SimpleNamespace(overlaps=[], coverage=cov, covered=np.zeros(1, bool))

    def fake_energy(problem, c, joints=None):
        return (outcome[int(c.positions[1, 0])][1] if c.positions[1, 0] else 1.0), {}

    monkeypatch.setattr(embedding, "_coverage_sites", fake_sites)
    monkeypatch.setattr(embedding, "_solve_placed", fake_solve)
    monkeypatch.setattr(embedding, "assign_contours", fake_assign)
    monkeypatch.setattr(embedding, "joint_energy", fake_energy)
    start = fake_assign(None, conf)
    out, solves = embedding._coverage_moves(None, None, np.array([1]), [], [], conf, start,
                                            GestureParams(), {})
    assert solves == 2 and out.positions[1, 0] == 2.0


def _folded_arm(params: GestureParams) -> SimpleNamespace:
    """The arm case with its forearm laid back along the upper arm (the wrist at 0.3 of
    the upper arm, as the coarse pass or a refinement can leave it): the matching problem
    at the drawn pose, single-radius contour candidates, and ``conf_at(positions)``."""
    cam, skel, pixels, _, truth = _arm_case()
    d = preprocess([Stroke(pixels)])
    sol = solving_skeleton(skel)
    ppu = cam.pixels_per_unit(6.0)
    problem = make_problem(d, sol, ppu, truth)
    r = R * ppu
    contour = [contour_candidates(d, np.array([r]), bool(problem.terminal[j]), problem.params,
                                  params.pool_candidates) for j in range(sol.n_joints)]
    wrist = sol.joint_bones.index("b1 tail")
    n = sol.n_joints

    def conf_at(pos):
        return JointCandidates(pos, np.full(n, r), np.zeros(n, int), -np.ones(n, int),
                               -np.ones(n, int), np.zeros(n), -np.ones((n, 48), int))

    folded = truth.copy()
    folded[wrist] = truth[0] + 0.3 * (truth[1] - truth[0])
    return SimpleNamespace(d=d, problem=problem, contour=contour, mid_r=np.full(n, r),
                           conf_at=conf_at, truth=truth, folded=folded, wrist=wrist,
                           elbow=sol.joint_bones.index("b0 tail"))


def test_limb_resolves_unfold_a_limb_the_search_left_folded():
    """A forearm laid back along the upper arm (the wrist at the shoulder's side, as the
    coarse pass can leave it) is re-solved with the shoulder held: the elbow and the wrist
    go to the arc's centre and the cap; a solution already there is left as it is. The
    character's current pose is the drawn one (the naturalness term's reference angle is
    the drawn bend; against the straight bind pose a forearm shrunk onto the elbow scores
    lower than the drawn one, 1.46 against 1.52, with these single radii)."""
    params = GestureParams()
    case = _folded_arm(params)
    d, problem, contour, mid_r = case.d, case.problem, case.contour, case.mid_r
    conf_at, truth, folded = case.conf_at, case.truth, case.folded
    elbow, wrist = case.elbow, case.wrist
    out, kept = embedding._limb_resolves(problem, problem, contour, mid_r, conf_at(folded),
                                         params, {})
    assert kept == 1
    eps = d.epsilon
    assert np.linalg.norm(out.positions[elbow] - truth[1]) < 1.5 * eps
    assert np.linalg.norm(out.positions[wrist] - truth[2]) < 1.5 * eps
    assert np.array_equal(out.positions[0], folded[0])  # the rest of the solution is held
    assert joint_energy(problem, out)[0] < joint_energy(problem, conf_at(folded))[0]
    # From the re-solved limb nothing better is found: nothing changes.
    again, kept = embedding._limb_resolves(problem, problem, contour, mid_r, out, params, {})
    assert kept == 0 and np.array_equal(again.positions, out.positions)
    # Off, the folded limb stays.
    off = replace(params, limb_resolves=0)
    same, kept = embedding._limb_resolves(problem, problem, contour, mid_r, conf_at(folded),
                                          off, {})
    assert kept == 0 and np.array_equal(same.positions, folded)


def test_limb_resolves_after_the_refinement_keep_only_a_better_walk():
    """``refined_resolves``: the limb re-solves run again from the refined solution and,
    when one is kept, the walk refines the result again; it replaces the solution only
    with a lower energy at no less coverage. From a folded forearm (as a refinement can
    leave it) the arm unfolds; from the unfolded arm nothing changes; off, nothing runs."""
    params = GestureParams(refined_resolves=1)
    case = _folded_arm(params)
    d, problem, contour, mid_r = case.d, case.problem, case.contour, case.mid_r
    conf_at, truth, folded = case.conf_at, case.truth, case.folded
    elbow, wrist = case.elbow, case.wrist
    out, info = embedding._resolve_refined(problem, problem, contour, mid_r, conf_at(folded),
                                           truth, params, {})
    assert info is not None and info["energy_after"] <= info["energy_before"]
    eps = d.epsilon
    assert np.linalg.norm(out.positions[elbow] - truth[1]) < 1.5 * eps
    assert np.linalg.norm(out.positions[wrist] - truth[2]) < 1.5 * eps
    assert joint_energy(problem, out)[0] < joint_energy(problem, conf_at(folded))[0]
    again, info = embedding._resolve_refined(problem, problem, contour, mid_r, out, truth,
                                             params, {})
    assert info is None and np.array_equal(again.positions, out.positions)
    off = replace(params, refined_resolves=0)
    same, info = embedding._resolve_refined(problem, problem, contour, mid_r,
                                            conf_at(folded), truth, off, {})
    assert info is None and np.array_equal(same.positions, folded)


def test_a_limb_re_solve_is_kept_for_a_lower_penalized_energy_at_no_less_coverage():
    params = GestureParams()  # overlap_penalty 10, coverage_gain 0.02

    def sol(n_overlaps, coverage, energy):
        return SimpleNamespace(overlaps=[(0, 1)] * n_overlaps, coverage=coverage), energy

    assert embedding._limb_accepts(sol(0, 0.80, 4.0), sol(0, 0.80, 4.5), params)
    assert not embedding._limb_accepts(sol(0, 0.80, 4.5), sol(0, 0.80, 4.5), params)
    # Less coverage for a lower energy is not taken (a limb left off its drawn contours).
    assert not embedding._limb_accepts(sol(0, 0.79, 4.0), sol(0, 0.80, 4.5), params)
    # One overlap fewer pays for more E_match, and for a little coverage, not for much.
    assert embedding._limb_accepts(sol(1, 0.79, 9.0), sol(2, 0.80, 4.5), params)
    assert not embedding._limb_accepts(sol(1, 0.75, 9.0), sol(2, 0.80, 4.5), params)
    assert not embedding._limb_accepts(sol(1, 0.80, 15.0), sol(2, 0.80, 4.5), params)


def test_limb_re_solve_sets_hold_the_rest_and_offer_rigid_joints_their_offsets():
    """Outside the chain every joint keeps its placement; a rigid joint (the unconnected
    arm heads of the Y-shaped tree) is offered its current placement and its offset from
    its parent, so the re-solve can keep the solution as it is or snap the rigid part."""
    cam, _, pixels, _, _ = _arm_case()
    d = preprocess([Stroke(pixels)])
    sol = solving_skeleton(tree_skeleton())
    ppu = cam.pixels_per_unit(6.0)
    reference = cam.project(sol.rest_joints)
    problem = make_problem(d, sol, ppu, reference)
    params = GestureParams()
    n = sol.n_joints
    contour = [contour_candidates(d, np.array([20.0]), bool(problem.terminal[j]),
                                  problem.params, params.pool_candidates) for j in range(n)]
    placed = reference + 5.0  # the whole tree shifted, with a rigid head a bit off
    rigid = np.flatnonzero(problem.rigid)
    assert rigid.size == 2
    placed[rigid[0]] += [3.0, -2.0]
    conf = JointCandidates(placed, np.full(n, 20.0), np.zeros(n, int), -np.ones(n, int),
                           -np.ones(n, int), np.zeros(n), -np.ones((n, 48), int))
    chain = embedding._limb_chains(problem)[0]
    sets = embedding._limb_sets(problem, contour, np.full(n, 20.0), conf, chain, params)
    for j in range(n):
        if j in chain:
            assert len(sets[j]) > 5 and np.allclose(sets[j].positions[0], placed[j])
        elif problem.rigid[j]:
            snapped = placed[sol.joint_parent[j]] + problem.link_offset[j]
            got = sets[j].positions
            assert np.any(np.all(np.isclose(got, placed[j]), axis=1))
            assert np.any(np.all(np.isclose(got, snapped), axis=1))
        else:
            assert len(sets[j]) == 1 and np.allclose(sets[j].positions[0], placed[j])


def test_a_character_turned_half_round_shows_its_image_mirrored():
    skel = tree_skeleton()
    solving = solving_skeleton(skel)
    cam = front_camera(ortho=True)
    world = posed_joints(solving, skel, Pose.identity(skel.n_bones))
    turned = embedding.turned_half_round(world, np.array([0.0, 0.0, 2.0]))
    seen, seen_turned = cam.project(world), cam.project(turned)
    mid = seen[:, 0].mean()
    np.testing.assert_allclose(seen_turned[:, 0], 2.0 * mid - seen[:, 0], atol=1e-6)
    np.testing.assert_allclose(seen_turned[:, 1], seen[:, 1], atol=1e-6)
    np.testing.assert_allclose(turned[:, 2], world[:, 2])  # still standing on its feet


def _turns(solving, joints, cam) -> dict:
    return {f: embedding.facing_turn(f, solving, joints, cam)[0] is not None
            for f in embedding.FACINGS}


def test_facing_turns_the_reference_only_when_the_drawing_shows_the_other_side():
    skel = tree_skeleton()  # its left (.L) on +x: it faces -y, the front camera
    solving = solving_skeleton(skel)
    cam = front_camera()
    world = posed_joints(solving, skel, Pose.identity(skel.n_bones))
    assert _turns(solving, world, cam) == {"auto": False, "front": False, "back": True,
                                           "turned": True}
    up, note = embedding.facing_turn("back", solving, world, cam)
    np.testing.assert_allclose(up, [0.0, 0.0, 1.0])
    assert note is None
    away = embedding.turned_half_round(world, up)  # now it shows its back
    assert _turns(solving, away, cam) == {"auto": False, "front": True, "back": False,
                                          "turned": True}
    with pytest.raises(InputError, match="Facing must be one of auto, front, back, turned"):
        embedding.facing_turn("behind", solving, world, cam)


def test_facing_is_not_used_in_a_side_view_or_without_left_and_right():
    skel = tree_skeleton()
    solving = solving_skeleton(skel)
    world = posed_joints(solving, skel, Pose.identity(skel.n_bones))
    side = Camera.look_at([6.0, -1.0, 0.8], [0.0, 0.0, 0.8], width=800, height=600)
    for facing in ("front", "back"):
        up, note = embedding.facing_turn(facing, solving, world, side)
        assert up is None
        assert note.startswith(f"Facing {facing.capitalize()} was not used: the character "
                               "is seen from the side")
    up, note = embedding.facing_turn("turned", solving, world, side)  # a profile turned
    np.testing.assert_allclose(up, [0.0, 0.0, 1.0])
    assert note is None
    cam, arm, pixels, verts, _ = _arm_case()
    chain = solving_skeleton(arm)
    up, note = embedding.facing_turn("back", chain, posed_joints(chain, arm, Pose.identity(2)),
                                     cam)
    assert up is None and "has no left/right limbs" in note
    emb = fit_drawing([Stroke(pixels)], arm, Pose.identity(2), verts, cam, facing="back")
    assert any("Facing Back was not used" in w for w in emb.warnings)


@pytest.mark.parametrize("ortho", [True, False])
def test_rolling_in_view_points_the_body_up_where_the_drawing_shows_it(ortho):
    skel = tree_skeleton()  # its root bone stands along +Z: up in the front view
    solving = solving_skeleton(skel)
    cam = front_camera(ortho=ortho)
    world = posed_joints(solving, skel, Pose.identity(skel.n_bones))
    head, tail = solving.head_joint[0], solving.tail_joint[0]
    expected = {"up": [0.0, 1.0], "left": [-1.0, 0.0], "down": [0.0, -1.0],
                "right": [1.0, 0.0]}  # pixels have y up
    for body_up, direction in expected.items():
        rolled = embedding.rolled_in_view(world, cam, body_up)
        seen = cam.project(rolled)
        up = seen[tail] - seen[head]
        np.testing.assert_allclose(up / np.linalg.norm(up), direction, atol=1e-3)
        np.testing.assert_allclose(cam.depth(rolled), cam.depth(world), atol=1e-9)
        np.testing.assert_allclose(rolled.mean(axis=0), world.mean(axis=0), atol=1e-9)
        lengths = np.linalg.norm(rolled[tail] - rolled[head])
        assert lengths == pytest.approx(np.linalg.norm(world[tail] - world[head]))
    with pytest.raises(InputError, match="Body Up must be one of up, left, down, right"):
        embedding.rolled_in_view(world, cam, "sideways")


def test_a_drawing_of_a_limb_upside_down_is_fitted_with_body_up_down():
    """The two-bone arm drawn turned half round in the image: as seen, the fit's priors
    read it upright; with Body Up "down" its joints land on the drawn ones."""
    cam, arm, pixels, verts, truth = _arm_case()
    solving = solving_skeleton(arm)
    world = posed_joints(solving, arm, Pose.identity(2))
    centre = cam.project(world).mean(axis=0)
    turned = 2.0 * centre - np.asarray(pixels, float)  # the drawing turned 180 degrees
    drawn = 2.0 * centre - np.asarray(truth, float)
    errors = {}
    for body_up in ("up", "down"):
        emb = fit_drawing([Stroke(turned)], arm, Pose.identity(2), verts, cam,
                          body_up=body_up)
        errors[body_up] = float(np.linalg.norm(emb.joints2d - drawn, axis=1).max())
    # Measured: the worst joint 292 px off as seen (the chain read backwards), 4.7 px.
    assert errors["down"] < 10.0 and errors["up"] > 100.0, errors
    with pytest.raises(InputError, match="Body Up must be one of"):
        fit_drawing([Stroke(turned)], arm, Pose.identity(2), verts, cam, body_up="over")
