"""Building blocks of the 3D lifting: twists, energies, ordering, QP, symmetry."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.exceptions import SolverError
from gesture_pose.core.gesture.depth import (
    DepthOptions,
    energies,
    occlusions,
    ordering,
    qp,
    regularity,
    solve_pose3d,
    symmetry,
    twist,
)
from gesture_pose.core.gesture.depth.synthetic import project_embedding, solving_skeleton
from gesture_pose.core.gesture.embedding import posed_joints
from gesture_pose.core.gesture.types import Embedding2D
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.skeleton import Pose, Skeleton
from tests.core.fixtures import chain_skeleton, frame_along, front_camera, tree_skeleton

FORWARD = np.array([0.0, 1.0, 0.0])


def _random_pose(seed: int, n: int = 6, scale: float = 0.6) -> Pose:
    rng = np.random.default_rng(seed)
    return Pose(exp_map(rng.normal(scale=scale, size=(n, 3))), np.zeros((n, 3)))


def test_position_jacobian_matches_finite_differences():
    sk = tree_skeleton()
    solving = solving_skeleton(sk)
    jm = twist.joint_map(sk, solving)
    pose = _random_pose(1)
    X, state = twist.joint_positions(sk, jm, pose)
    np.testing.assert_allclose(X, posed_joints(solving, sk, pose), atol=1e-12)
    G = twist.position_jacobian(jm, X, state)
    h = 1e-6
    numeric = np.zeros_like(G)
    for i in range(G.shape[1]):
        d = np.zeros(G.shape[1])
        d[i] = h
        Xp, _ = twist.joint_positions(sk, jm, twist.apply_twists(sk, jm, pose, state,
                                                                 d.reshape(-1, 3)))
        d[i] = -h
        Xm, _ = twist.joint_positions(sk, jm, twist.apply_twists(sk, jm, pose, state,
                                                                 d.reshape(-1, 3)))
        numeric[:, i] = (Xp - Xm).ravel() / (2 * h)
    np.testing.assert_allclose(G, numeric, atol=1e-7)
    # A twist about the root's head moves every joint but the root's own head.
    assert jm.moves[:, 0].sum() == solving.n_joints - 1


def test_large_twists_keep_lengths_and_orthonormality():
    sk = tree_skeleton()
    solving = solving_skeleton(sk)
    jm = twist.joint_map(sk, solving)
    pose = _random_pose(2)
    rng = np.random.default_rng(5)
    for _ in range(200):
        _, state = twist.joint_positions(sk, jm, pose)
        pose = twist.apply_twists(sk, jm, pose, state, rng.normal(scale=0.3, size=(6, 3)))
    state = sk.forward(pose)
    np.testing.assert_allclose(np.linalg.norm(state.tails - state.heads, axis=1), sk.lengths,
                               atol=1e-12)
    np.testing.assert_allclose(pose.rotations @ np.swapaxes(pose.rotations, 1, 2),
                               np.broadcast_to(np.eye(3), (6, 3, 3)), atol=1e-12)


def test_foreshortening_weights_follow_eq6():
    ratios = np.array([1.2, 1.2, 1.0, 0.9, 0.5])
    w = energies.foreshortening_weights(ratios, sigma_f=0.2, free_ratio=0.6)
    mean = ratios.mean()
    assert w[0] == 1.0 and w[2] == 1.0  # at least as long as the average
    assert w[3] == pytest.approx(np.exp(-(1 - 0.9 / mean) ** 2 / 0.08))
    assert 0.5 / mean < 0.6 and w[4] == 0.0  # deliberately foreshortened: free
    # One link drawn at 16 times its length (a 2D fit error) among twenty: the trimmed
    # average ignores it and the unforeshortened links keep their weight.
    many = np.r_[np.full(19, 0.95), 16.0]
    assert np.all(energies.foreshortening_weights(many)[:19] == 1.0)
    assert np.all(energies.foreshortening_weights(many, trim=0.0)[:19] == 0.0)


def test_conformity_is_zero_for_the_drawn_pose_and_matches_its_definition():
    sk = tree_skeleton()
    cam = front_camera(ortho=True)
    solving = solving_skeleton(sk)
    pose = _random_pose(4)
    emb = project_embedding(sk, solving, pose, cam)
    frame = energies.view_frame(cam, solving.rest_joints.mean(axis=0))
    a, b = energies.joint_links(solving.joint_parent)
    lengths = np.linalg.norm(solving.rest_joints[b] - solving.rest_joints[a], axis=1)
    term = energies.conformity_term(frame, emb.joints2d, a, b, lengths, solving.n_joints)
    X = posed_joints(solving, sk, pose)
    assert term.value(X) < 1e-20
    Y = X + np.random.default_rng(0).normal(scale=0.05, size=X.shape)
    d = Y[b] - Y[a]
    drawn = (emb.joints2d[b] - emb.joints2d[a]) / frame.scale
    proj = np.stack([d @ frame.right, d @ frame.up], 1)
    expected = np.sum(np.sum((proj - drawn) ** 2, axis=1) / lengths**2)
    assert term.value(Y) == pytest.approx(expected, rel=1e-12)
    # A link's confidence scales its weight (hidden joints are guesses).
    conf = np.linspace(0.1, 1.0, len(a))
    scaled = energies.conformity_term(frame, emb.joints2d, a, b, lengths, solving.n_joints,
                                      conf)
    per_link = np.sum((proj - drawn) ** 2, axis=1) / lengths**2
    assert scaled.value(Y) == pytest.approx(np.sum(conf * per_link), rel=1e-12)


def _embedding_with_pieces(base: Embedding2D, pieces: dict[int, list[np.ndarray]],
                           contours: list[np.ndarray]) -> Embedding2D:
    segs = tuple(tuple(pieces.get(b, [])) for b in range(base.solving.n_bones))
    sides = tuple(tuple(1 for _ in s) for s in segs)
    return Embedding2D(base.solving, base.joints2d, base.joint_visible, base.joint_radius,
                       segs, sides, (), tuple(contours), tuple(contours), 1.0, 0.0,
                       epsilon=2.0)


def _t_drawing() -> tuple[Embedding2D, np.ndarray, np.ndarray]:
    """The tree skeleton's rest embedding, a T's top (a horizontal line) and its stem (a
    vertical stroke ending on the top's interior)."""
    sk = tree_skeleton()
    solving = solving_skeleton(sk)
    base = project_embedding(sk, solving, Pose.identity(6), front_camera(ortho=True))
    top = np.stack([np.linspace(400, 500, 51), np.full(51, 300.0)], 1)
    stem = np.stack([np.full(21, 450.0), np.linspace(260, 300, 21)], 1)
    return base, top, stem


def test_t_junction_detection_from_contours():
    base, top, stem = _t_drawing()
    solving = base.solving
    # Upper arm outline: the T's top; forearm outline: its stem; the torso outline ends
    # on nothing.
    free = np.stack([np.full(21, 380.0), np.linspace(100, 200, 21)], 1)
    emb = _embedding_with_pieces(base, {2: [top], 3: [stem], 0: [free]}, [top, stem, free])
    found = occlusions.detect_junctions(emb)
    assert [(j.stem_bone, j.top_bone) for j in found] == [(3, 2)]
    np.testing.assert_allclose(found[0].point, [450.0, 300.0])
    names = ("r", "n", "a", "f", "b", "g")
    # Intra-part T-junctions are off by default (unreliable on traced drawings).
    assert ordering.ordering_constraints(emb, scale=200.0, names=names) == []
    cons = ordering.ordering_constraints(emb, scale=200.0, names=names, t_junctions=True)
    assert len(cons) == 1 and cons[0].kind == "t_junction"
    # fore.L shares its head joint with arm.L's tail: its tail must be deeper.
    assert cons[0].back.tolist() == [solving.tail_joint[3]]
    assert cons[0].front.tolist() == [solving.tail_joint[2]]


def test_eq8_margin_uses_radii_at_the_occluding_point():
    sk = tree_skeleton()
    cam = front_camera(ortho=True)
    solving = solving_skeleton(sk)
    emb = project_embedding(sk, solving, Pose.identity(6), cam)
    h, t = emb.joints2d[solving.head_joint[2]], emb.joints2d[solving.tail_joint[2]]
    on_axis = 0.5 * (h + t)
    from gesture_pose.core.gesture.types import Occlusion

    c = ordering.occlusion_constraint(emb, Occlusion(2, 0, on_axis, 10.0, 30.0), scale=100.0)
    # On arm.L's axis (e = 0) the occluder is 10 px deep; the torso axis is 0.35 * 200 px
    # away, beyond its 30 px radius (h = 0).
    assert c.margin == pytest.approx(0.1)
    np.testing.assert_allclose(c.front_w, [0.5, 0.5])


def test_qp_respects_every_ordering_inequality():
    sk = tree_skeleton()
    solving = solving_skeleton(sk)
    jm = twist.joint_map(sk, solving)
    pose = _random_pose(8, scale=0.3)
    X, state = twist.joint_positions(sk, jm, pose)
    G = twist.position_jacobian(jm, X, state)
    # Pull every joint towards the viewer, but demand an order between three pairs.
    pull = energies.LinearTerm("pull", np.kron(np.eye(len(X)), FORWARD[None]),
                               X @ FORWARD - 0.5, np.ones(len(X)))
    cons = [ordering.OrderingConstraint("occlusion", f"c{i}", np.array([b]), np.ones(1),
                                        np.array([f]), np.ones(1), 0.05)
            for i, (b, f) in enumerate([(5, 4), (8, 2), (4, 7)])]
    rows = ordering.ordering_rows(cons, FORWARD, len(X))
    problem = qp.build_qp([pull], [rows], [], X.ravel(), G, alpha=200.0, kappa=1.0)
    sol = qp.solve_qp(problem)
    linear = rows.matrix @ (X.ravel() + G @ sol.delta.ravel())
    assert np.all(linear >= rows.lower - 1e-6)
    assert len(sol.active) >= 1  # the pull makes at least one order binding
    unconstrained = qp.solve_qp(qp.build_qp([pull], [], [], X.ravel(), G, alpha=200.0,
                                            kappa=1.0))
    free_linear = rows.matrix @ (X.ravel() + G @ unconstrained.delta.ravel())
    assert np.any(free_linear < rows.lower - 1e-3)  # the constraints mattered


def test_infeasible_qp_raises_solver_error_with_status():
    sk = tree_skeleton()
    solving = solving_skeleton(sk)
    jm = twist.joint_map(sk, solving)
    X, state = twist.joint_positions(sk, jm, Pose.identity(6))
    G = twist.position_jacobian(jm, X, state)
    both = [ordering.OrderingConstraint("occlusion", name, np.array([b]), np.ones(1),
                                        np.array([f]), np.ones(1), 0.1)
            for name, b, f in (("ahead", 5, 8), ("behind", 8, 5))]
    rows = ordering.ordering_rows(both, FORWARD, len(X))
    with pytest.raises(SolverError) as err:
        qp.solve_qp(qp.build_qp([], [rows], [], X.ravel(), G, alpha=200.0, kappa=1.0))
    assert "infeasible" in err.value.details["status"]
    soft = qp.solve_qp(qp.build_qp([], [rows], [], X.ravel(), G, alpha=200.0, kappa=1.0,
                                   soften=True))
    assert soft.slacks.size == 2 and np.abs(soft.slacks).max() > 0.05


def test_parallel_pairs_need_the_same_foreshortening():
    jp = np.array([-1, 0, 1, 2])
    pts = np.array([[0.0, 0.0], [0.0, 10.0], [0.5, 20.0], [10.0, 25.0]])
    triples = regularity.parallel_pairs(jp, pts, np.radians(10.0))
    assert triples.tolist() == [[0, 1, 2]]
    ratios = np.array([1.0, 1.0, 0.5, 1.0])
    assert regularity.parallel_pairs(jp, pts, np.radians(10.0), ratios).size == 0


def test_flip_depth_mirrors_a_chain_about_its_root_view_plane():
    sk = tree_skeleton()
    cam = front_camera(ortho=True)
    pose = _random_pose(9)
    flipped = symmetry.flip_depth(sk, pose, np.array([2, 3]), FORWARD)
    before, after = sk.forward(pose), sk.forward(flipped)
    root = before.heads[2]
    for pts0, pts1 in ((before.tails[[2, 3]], after.tails[[2, 3]]),):
        np.testing.assert_allclose((pts1 - root) @ FORWARD, -(pts0 - root) @ FORWARD,
                                   atol=1e-9)
        np.testing.assert_allclose(cam.project(pts1), cam.project(pts0), atol=1e-6)
    np.testing.assert_allclose(after.tails[[0, 1, 4, 5]], before.tails[[0, 1, 4, 5]])
    np.testing.assert_allclose(np.linalg.norm(after.tails - after.heads, axis=1), sk.lengths)


def _symmetric_tree() -> Skeleton:
    heads = np.array([[0, 0, 0], [0.1, 0, 1], [0.6, 0, 1], [-0.1, 0, 1], [-0.6, 0, 1]], float)
    tails = np.array([[0, 0, 1], [0.6, 0, 1], [1.1, 0, 1], [-0.6, 0, 1], [-1.1, 0, 1]], float)
    frames = np.stack([frame_along(t - h) for h, t in zip(heads, tails, strict=True)])
    return Skeleton(("root", "arm.L", "fore.L", "arm.R", "fore.R"), np.array([-1, 0, 1, 0, 3]),
                    heads, tails, frames, np.ones(5, bool),
                    np.array([False, False, True, False, True]), np.ones(5, bool))


def test_symmetrize_makes_near_mirror_limbs_exact():
    sk = _symmetric_tree()
    # Mirror-image arms (about the x = 0 plane) but for a 5 degree wobble of fore.R.
    pose = Pose.identity(5)
    state = sk.forward(pose)
    left = exp_map(np.array([0.0, 0.0, 0.4]))
    mirror = np.diag([-1.0, 1.0, 1.0])
    right = mirror @ left @ mirror
    for bone, rot in ((1, left), (3, right)):
        state = sk.forward(pose)
        pose = pose.with_rotations(np.array([bone]), (state.frames[bone].T @ rot
                                                      @ state.frames[bone])[None])
    state = sk.forward(pose)
    wobble = state.frames[4].T @ exp_map(np.array([0.0, 0.0, np.radians(5.0)])) @ \
        state.frames[4]
    pose = pose.with_rotations(np.array([4]), wobble[None])
    pairs = symmetry.mirror_pairs(sk.names, np.arange(5))
    assert sorted(map(tuple, pairs.tolist())) == [(1, 3), (2, 4)]
    out, names = symmetry.symmetrize(sk, pose, pairs, np.radians(10.0))
    assert sorted(names) == ["arm.L", "fore.L"]
    st = sk.forward(out)
    center = 0.5 * (st.heads[1] + st.heads[3])
    for lb, rb in ((1, 3), (2, 4)):
        dl = st.tails[lb] - st.heads[lb]
        dr = st.tails[rb] - st.heads[rb]
        np.testing.assert_allclose(dl, mirror @ dr, atol=1e-9)
    assert abs(center[0]) < 1e-9
    # Beyond the threshold nothing changes.
    same, none = symmetry.symmetrize(sk, pose, pairs, np.radians(2.0))
    assert none == [] and np.allclose(same.rotations, pose.rotations)


def test_contacts_keep_touching_joints_at_one_depth():
    pts = np.stack([np.zeros(5), np.zeros(5), np.linspace(0.0, 1.6, 5)], 1)
    sk = chain_skeleton(pts)
    cam = front_camera(ortho=True)
    solving = solving_skeleton(sk)
    # Fold the chain into a square loop in the view plane, the last bone tilted 70 degrees
    # towards the viewer: its tip is drawn next to the base but lies 0.38 m in front.
    tilt = np.radians(70.0)
    dirs = [[0, 0, 1], [1, 0, 0], [0, 0, -1], [-np.cos(tilt), -np.sin(tilt), 0]]
    pose = Pose.identity(4)
    for k, d in enumerate(dirs):
        state = sk.forward(pose)
        pose = pose.with_rotations(np.array([k]), sk.aim_local(
            k, np.array(d, float), state, pose.rotations[k])[None])
    emb = project_embedding(sk, solving, pose, cam, radius=0.14)
    tip, base = solving.tail_joint[3], solving.head_joint[0]
    assert [base, tip] in regularity.contact_pairs(emb).tolist()
    reach = (emb.joint_radius[tip] + emb.joint_radius[base]) / cam.pixels_per_unit(6.0)
    res = solve_pose3d(sk, emb, cam, options=DepthOptions(use_contacts=True))
    gap = abs((res.joints3d[tip] - res.joints3d[base]) @ FORWARD)
    assert gap <= reach + 1e-6
    free = solve_pose3d(sk, emb, cam, options=DepthOptions(use_contacts=False))
    assert abs((free.joints3d[tip] - free.joints3d[base]) @ FORWARD) > reach + 0.05
    # Circles where one covers most of the other are an occlusion, not a contact.
    covering = project_embedding(sk, solving, pose, cam, radius=0.3)
    assert [base, tip] not in regularity.contact_pairs(covering).tolist()


def test_spline_term_is_zero_on_quadratic_depths_only():
    pts = np.stack([np.zeros(6), np.zeros(6), np.linspace(0.0, 2.0, 6)], 1)
    sk = chain_skeleton(pts)
    cam = front_camera(ortho=True)
    solving = solving_skeleton(sk)
    emb = project_embedding(sk, solving, Pose.identity(5), cam, radius=0.05)
    frame = energies.view_frame(cam, pts.mean(axis=0))
    term = regularity.spline_term(emb, solving.rest_joints, frame)
    assert len(term.target) == 6  # every joint of the straight drawn limb is attracted
    t = np.linspace(0.0, 1.0, 6)
    X = solving.rest_joints.copy()
    X[:, 1] = 0.3 * t**2 - 0.1 * t  # quadratic depth profile
    assert term.value(X) < 1e-20
    X[3, 1] += 0.05  # a kink
    assert term.value(X) > 1e-4
    free = np.zeros(solving.n_joints, bool)
    free[3] = True  # a deliberately foreshortened link splits the limb into short runs
    split = regularity.spline_term(emb, solving.rest_joints, frame, free=free)
    assert len(split.target) == 0


def test_pose_error_aligns_the_root_and_counts_depth_order():
    from gesture_pose.core.gesture.depth import pose_error

    sk = tree_skeleton()
    cam = front_camera(ortho=True)
    truth = np.array([[0.0, 0.0, 0.0], [0.0, 0.5, 1.0], [1.0, -0.5, 1.0]])
    shifted = truth + np.array([3.0, 2.0, 1.0])  # same pose elsewhere
    err = pose_error(truth, shifted, sk, cam)
    assert err.mean_error == pytest.approx(0.0, abs=1e-12)
    assert err.depth_order == 1.0
    assert err.height == pytest.approx(2.3)  # x extent of the tree's rest bones
    flipped = truth * np.array([1.0, -1.0, 1.0])  # every depth mirrored
    err = pose_error(truth, flipped, sk, cam)
    assert err.depth_order == 0.0
    assert err.max_error == pytest.approx(100.0 * 1.0 / 2.3)
    assert err.mean_error == pytest.approx(100.0 * (0 + 1.0 + 1.0) / 3 / 2.3)


def test_junctions_between_parts_apart_in_the_drawing_are_not_occlusions():
    base, top, stem = _t_drawing()
    # An arm.R outline stopping across an arm.L outline: the two arms are drawn on either
    # side of the body (their tubes do not overlap), so this is not read as an occlusion.
    emb = _embedding_with_pieces(base, {2: [top], 4: [stem]}, [top, stem])
    assert [(j.stem_bone, j.top_bone) for j in occlusions.detect_junctions(emb)] == [(4, 2)]
    assert occlusions.tubes_overlap(emb, 4, 2) > 1.0
    assert ordering.ordering_constraints(emb, scale=200.0) == []
    cons = ordering.ordering_constraints(emb, scale=200.0, overlap=np.inf)
    assert len(cons) == 1 and cons[0].kind == "occlusion"
    solving = base.solving
    assert set(cons[0].back.tolist()) <= {solving.head_joint[4], solving.tail_joint[4]}
    # Bones two steps apart are not enough with min_parts=3.
    assert ordering.ordering_constraints(emb, scale=200.0, overlap=np.inf, min_parts=3) == []
    # Evidence both ways cancels out: an arm.L outline also stops across the arm.R one.
    other = np.stack([np.linspace(420, 450, 16), np.full(16, 280.0)], 1)
    emb2 = _embedding_with_pieces(base, {2: [top, other], 4: [stem]}, [top, stem, other])
    found = {(j.stem_bone, j.top_bone) for j in occlusions.detect_junctions(emb2)}
    assert found == {(4, 2), (2, 4)}
    assert ordering.ordering_constraints(emb2, scale=200.0, overlap=np.inf) == []
