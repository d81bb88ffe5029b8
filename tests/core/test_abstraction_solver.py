"""ICP posing from abstractions: self-recovery, bounded scales, IK limits, black-box rigs."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.abstraction.blackbox import FiniteDifferenceRig
from gesture_pose.core.abstraction.coarsening import coarsen
from gesture_pose.core.abstraction.curves import CurveLayout, resample_rigged, resampling_matrix
from gesture_pose.core.abstraction.parameters import ParameterSpace, RigPose
from gesture_pose.core.abstraction.qp import StepLimits
from gesture_pose.core.abstraction.rig import LbsRig, lbs_weighted_rest, pose_bones, skin
from gesture_pose.core.abstraction.solver import (
    AbstractionProblem,
    SolveOptions,
    solve_abstraction,
)
from gesture_pose.core.rotations import exp_map, log_map, normalize
from gesture_pose.core.stroke import Stroke
from tests.core.fixtures import chain_skeleton, front_camera, tree_skeleton


def tube_mesh(skel, rings: int = 6, segments: int = 8, radius: float = 0.06):
    """Closed-ish tubes around every bone: vertices ``(V, 3)``, triangles, weights ``(V, n)``."""
    verts, tris, weights = [], [], []
    n = skel.n_bones
    for b in range(n):
        h, t, f = skel.rest_heads[b], skel.rest_tails[b], skel.rest_frames[b]
        base = sum(len(v) for v in verts)
        ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
        ring = radius * (np.cos(ang)[:, None] * f[:, 0] + np.sin(ang)[:, None] * f[:, 2])
        s = np.linspace(0.0, 1.0, rings)
        pts = (h + s[:, None] * (t - h))[:, None, :] + ring[None]
        verts.append(pts.reshape(-1, 3))
        w = np.zeros((rings * segments, n))
        w[:, b] = 1.0
        p = skel.parents[b]
        if p >= 0:
            w[:segments, b] = 0.5
            w[:segments, p] = 0.5
        weights.append(w)
        for r in range(rings - 1):
            for k in range(segments):
                a0 = base + r * segments + k
                a1 = base + r * segments + (k + 1) % segments
                tris += [[a0, a1, a0 + segments], [a1, a1 + segments, a0 + segments]]
    return np.concatenate(verts), np.array(tris), np.concatenate(weights)


def stick_abstraction(skel, per_bone: int = 12):
    """One straight curve per bone, rigidly attached: ``(Y (m, n, 4), layout)``."""
    pts, w, offsets = [], [], [0]
    for b in range(skel.n_bones):
        s = np.linspace(0.0, 1.0, per_bone)[:, None]
        pts.append(skel.rest_heads[b] + s * (skel.rest_tails[b] - skel.rest_heads[b]))
        wb = np.zeros((per_bone, skel.n_bones))
        wb[:, b] = 1.0
        w.append(wb)
        offsets.append(offsets[-1] + per_bone)
    layout = CurveLayout(skel.names, np.array(offsets))
    return lbs_weighted_rest(np.concatenate(pts), np.concatenate(w)), layout


def make_problem(skel, target: RigPose, space: ParameterSpace, noise: float = 0.0,
                 seed: int = 0, start: RigPose | None = None, reverse: tuple[int, ...] = ()):
    """A problem whose strokes are the projected abstraction of ``target``."""
    cam = front_camera()
    y_abs, layout = stick_abstraction(skel)
    verts, _, weights = tube_mesh(skel)
    coarse = coarsen(verts, k=60)
    y_rep = lbs_weighted_rest(verts[coarse.indices], weights[coarse.indices])
    rig = LbsRig(skel, space, y_abs, y_rep)
    px = cam.project(skin(pose_bones(skel, target), y_abs))
    rng = np.random.default_rng(seed)
    strokes = []
    for i in range(layout.n_curves):
        pts = px[layout.curve(i)] + rng.normal(scale=noise, size=(len(px[layout.curve(i)]), 2))
        strokes.append(Stroke(pts[::-1] if i in reverse else pts))
    n = skel.n_bones
    start = start or RigPose(np.tile(np.eye(3), (n, 1, 1)), np.ones(n), np.zeros((n, 3)))
    return AbstractionProblem(rig, skel.names, cam, layout, tuple(strokes), coarse, start)


def in_plane_pose(skel, angles: np.ndarray) -> RigPose:
    """Local rotations turning each bone by ``angles`` about the world y (view) axis."""
    world = angles[:, None] * np.array([0.0, 1.0, 0.0])
    local = np.einsum("nji,nj->ni", skel.rest_frames, world)
    n = skel.n_bones
    return RigPose(exp_map(local), np.ones(n), np.zeros((n, 3)))


def rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Largest angle between corresponding rotations, degrees."""
    return float(np.degrees(np.linalg.norm(log_map(np.swapaxes(a, 1, 2) @ b), axis=1).max()))


def bone_error_deg(skel, a: RigPose, b: RigPose) -> float:
    """Largest angle between posed bone directions, degrees (twist is invisible to strokes)."""
    fa, fb = pose_bones(skel, a).frames[:, :, 1], pose_bones(skel, b).frames[:, :, 1]
    return float(np.degrees(np.arccos(np.clip(np.sum(fa * fb, axis=1), -1, 1))).max())


@pytest.mark.parametrize("procedure", ["IN_ORDER", "CLOSEST"])
def test_pose_recovered_from_own_abstraction(procedure: str) -> None:
    skel = tree_skeleton()
    target = in_plane_pose(skel, np.array([0.15, -0.3, 0.35, -0.4, -0.25, 0.3]))
    space = ParameterSpace.from_masks(skel.parents, np.ones(6, bool))
    problem = make_problem(skel, target, space)
    result = solve_abstraction(problem, SolveOptions(correspondence=procedure))
    assert result.initial_residual_px > 20.0
    assert result.residual_px < 0.1
    assert bone_error_deg(skel, result.pose, target) < 0.5
    assert result.iterations >= 2


def test_noisy_strokes_recover_pose_approximately() -> None:
    skel = tree_skeleton()
    target = in_plane_pose(skel, np.array([0.1, 0.2, -0.35, 0.5, 0.3, -0.45]))
    space = ParameterSpace.from_masks(skel.parents, np.ones(6, bool))
    problem = make_problem(skel, target, space, noise=1.0, seed=5)
    result = solve_abstraction(problem)
    assert result.residual_px < 1.5
    # Depth is not observable under noise: compare the joints as drawn (pixels).
    cam = problem.camera
    got, want = pose_bones(skel, result.pose), pose_bones(skel, target)
    err = np.linalg.norm(cam.project(got.heads) - cam.project(want.heads), axis=1)
    tails = [h + f[:, :, 1] * length[:, None] for h, f, length in
             ((got.heads, got.frames, skel.lengths), (want.heads, want.frames, skel.lengths))]
    err_t = np.linalg.norm(cam.project(tails[0]) - cam.project(tails[1]), axis=1)
    assert max(err.max(), err_t.max()) < 1.5


def _inversion_problem():
    """A chain whose last bone is drawn pointing (almost) backwards."""
    skel = chain_skeleton(np.array([[0, 0, 0.0], [0, 0, 0.6], [0, 0, 1.1], [0, 0, 1.5]]))
    n = skel.n_bones
    ang = np.radians(175.0)
    target = in_plane_pose(skel, np.array([0.0, 0.0, ang]))
    space = ParameterSpace.from_masks(skel.parents, np.ones(n, bool), np.ones(n, bool))
    return skel, target, make_problem(skel, target, space)


def test_unbounded_update_inverts_limb_but_bounded_keeps_scales_positive() -> None:
    skel, target, problem = _inversion_problem()
    loose = solve_abstraction(problem, SolveOptions(bounded=False))
    assert loose.pose.scales.min() < 0.0  # the paper's Figure 7: a limb turned inside out
    tight = solve_abstraction(problem)
    assert tight.pose.scales.min() >= 0.1 - 1e-9
    posed = pose_bones(skel, tight.pose)
    wanted = pose_bones(skel, target)
    cos = normalize(posed.frames[2][:, 1]) @ normalize(wanted.frames[2][:, 1])
    assert cos > 0.95
    assert tight.residual_px < 2.0


def test_ik_limits_hold_and_are_reported() -> None:
    skel = tree_skeleton()
    target = in_plane_pose(skel, np.array([0.0, 0.0, 0.0, 0.8, 0.0, 0.0]))
    space = ParameterSpace.from_masks(skel.parents, np.ones(6, bool))
    limits = np.full((6, 3, 2), np.nan)
    limits[3] = [[-0.3, 0.3]] * 3
    problem = make_problem(skel, target, space)
    free = solve_abstraction(problem)
    assert np.abs(log_map(free.pose.rotations[3])).max() > 0.5
    bounded = solve_abstraction(problem, SolveOptions(limits=StepLimits(ik_limits=limits)))
    assert np.abs(log_map(bounded.pose.rotations[3])).max() <= 0.3 + 1e-6
    assert any(lab.startswith("limit fore.L") for lab in bounded.active_bounds)


def test_black_box_rig_matches_analytic_rig() -> None:
    skel = tree_skeleton()
    target = in_plane_pose(skel, np.array([0.1, -0.2, 0.3, -0.3, -0.2, 0.25]))
    space = ParameterSpace.from_masks(skel.parents, np.ones(6, bool))
    problem = make_problem(skel, target, space)
    black = FiniteDifferenceRig(space, problem.rig.evaluate, step=1e-6)
    x, z, jx, jz = problem.rig.jacobians(problem.start)
    _, _, fx, fz = black.jacobians(problem.start)
    np.testing.assert_allclose(fx, jx, atol=1e-4)
    boxed = AbstractionProblem(black, skel.names, problem.camera, problem.layout,
                               problem.strokes, problem.coarse, problem.start)
    result = solve_abstraction(boxed)
    assert result.residual_px < 0.15
    assert bone_error_deg(skel, result.pose, target) < 1.0
    assert black.counter[0] > space.n_params


def test_resampling_is_exact_under_skinning() -> None:
    skel = tree_skeleton()
    y, layout = stick_abstraction(skel, per_bone=5)
    mat, new = resampling_matrix(np.einsum("mnj->mj", y)[:, :3], layout, budget=90)
    assert 60 <= new.n_points <= 96 and new.n_curves == 6
    yr = resample_rigged(y, mat)
    posed = pose_bones(skel, in_plane_pose(skel, np.linspace(-0.5, 0.5, 6)))
    np.testing.assert_allclose(skin(posed, yr), mat @ skin(posed, y), atol=1e-12)


def test_closest_point_on_polyline_matches_brute_force() -> None:
    from gesture_pose.core.abstraction.correspondences import _closest_on_polyline

    rng = np.random.default_rng(11)
    t = np.linspace(0, 3 * np.pi, 80)
    poly = np.stack([60 * t, 80 * np.sin(t)], axis=1)
    queries = rng.uniform([-20, -120], [600, 120], size=(300, 2))
    seg, frac = _closest_on_polyline(queries, poly)
    got = poly[seg] + frac[:, None] * (poly[seg + 1] - poly[seg])
    dense = np.concatenate([np.linspace(poly[i], poly[i + 1], 200) for i in range(79)])
    brute = np.linalg.norm(queries[:, None] - dense[None], axis=2).min(axis=1)
    np.testing.assert_allclose(np.linalg.norm(got - queries, axis=1), brute, atol=0.05)


def test_box_qp_matches_osqp() -> None:
    from scipy import sparse

    from gesture_pose.core.abstraction.qp import StepQP, box_qp, solve_step_qp

    rng = np.random.default_rng(8)
    a = rng.normal(size=(40, 12))
    hess = a.T @ a + 0.1 * np.eye(12)
    grad = 5.0 * rng.normal(size=12)
    lo, hi = -np.full(12, 0.3), np.full(12, 0.2)
    x, rounds = box_qp(hess, grad, lo, hi)
    assert rounds >= 2 and np.any(np.isclose(x, lo) | np.isclose(x, hi))
    qp = StepQP(sparse.csc_matrix(np.triu(2 * hess)), 2 * grad,
                sparse.identity(12, format="csc"), lo, hi, tuple(str(i) for i in range(12)))
    np.testing.assert_allclose(x, solve_step_qp(qp, tolerance=1e-10).dp, atol=1e-6)
