"""Benchmark of sketch-abstraction posing (Hahn et al. 2015): time against rig and mesh size.

A synthetic character (a tree of bone chains, a tube mesh skinned to it, a stick-figure
abstraction resampled to about 400 points) is posed from strokes drawn from a known pose's
abstraction. Reported over N identical solves (the machine is shared, so both the fastest
and the median are given, and the table titles give the load average when it ran): time per
solve, median time per ICP iteration, iterations, final RMS residual in pixels and the pose
error (largest angle between solved and true bone directions, in the image and in 3D). The
paper reports 260-370 ms per solve (C++ in Maya) for a rig of about 90 parameters; the target
here is under 100 ms per solve.
"""

from __future__ import annotations

import os
import time

import numpy as np

from gesture_pose.core.abstraction import (
    FiniteDifferenceRig,
    ParameterSpace,
    RigPose,
    SolveOptions,
    build_lbs_problem,
    lbs_weighted_rest,
    pose_bones,
    skin,
    solve_abstraction,
)
from gesture_pose.core.abstraction.curves import CurveLayout
from gesture_pose.core.abstraction.solver import AbstractionProblem
from gesture_pose.core.camera import Camera
from gesture_pose.core.rotations import exp_map, rotation_between
from gesture_pose.core.skeleton import Skeleton
from gesture_pose.core.stroke import Stroke


def character(bones: int) -> tuple[Skeleton, list[list[int]]]:
    """A root with ``bones - 1`` bones in 6 chains spread in the x-z plane."""
    per, extra = divmod(bones - 1, 6)
    heads, tails, parents, chains = [[0, 0, 0.9]], [[0, 0, 1.1]], [-1], []
    for c in range(6):
        ang = np.radians(90 + 60 * c)
        d = np.array([np.cos(ang), 0.0, np.sin(ang)])
        start = np.array(tails[0]) if c < 3 else np.array(heads[0])
        chain, parent = [], 0
        for _ in range(per + (1 if c < extra else 0)):
            heads.append(start.tolist())
            start = start + 0.12 * d
            tails.append(start.tolist())
            parents.append(parent)
            parent = len(heads) - 1
            chain.append(parent)
        chains.append(chain)
    h, t = np.array(heads), np.array(tails)
    frames = rotation_between(np.array([0.0, 1.0, 0.0]), t - h)
    n = len(h)
    skel = Skeleton(tuple(f"b{i}" for i in range(n)), np.array(parents), h, t, frames,
                    np.ones(n, bool), np.r_[False, np.ones(n - 1, bool)], np.ones(n, bool))
    return skel, chains


def tube_mesh(skel: Skeleton, vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Tubes around the bones with about ``vertices`` vertices: ``(V, 3)``, weights ``(V, n)``."""
    n = skel.n_bones
    segments = max(int(np.sqrt(vertices / n / 1.5)), 4)
    rings = max(int(vertices / n / segments), 2)
    ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    s = np.linspace(0, 1, rings)
    pts, wts = [], []
    for b in range(n):
        f = skel.rest_frames[b]
        ring = 0.04 * (np.cos(ang)[:, None] * f[:, 0] + np.sin(ang)[:, None] * f[:, 2])
        line = skel.rest_heads[b] + s[:, None] * (skel.rest_tails[b] - skel.rest_heads[b])
        pts.append((line[:, None] + ring[None]).reshape(-1, 3))
        w = np.zeros((rings * segments, n))
        blend = np.repeat(np.clip(1.5 - 3 * s, 0, 1) * 0.5, segments)
        p = skel.parents[b]
        w[:, b] = 1.0 - (blend if p >= 0 else 0)
        if p >= 0:
            w[:, p] = blend
        wts.append(w)
    return np.concatenate(pts), np.concatenate(wts)


def stick(skel: Skeleton, chains: list[list[int]]) -> tuple[np.ndarray, np.ndarray, CurveLayout]:
    """Raw stick-figure points (8 per bone), weights and layout, one curve per chain.

    The first chain (upwards from the root's tail) starts with the root bone, so every
    bone carries abstraction points.
    """
    pts, wts, offsets = [], [], [0]
    for chain in [[0] + list(chains[0])] + list(chains[1:]):
        for k, b in enumerate(chain):
            s = np.linspace(0, 1, 9)[:-1] if k < len(chain) - 1 else np.linspace(0, 1, 9)
            pts.append(skel.rest_heads[b] + s[:, None] * (skel.rest_tails[b]
                                                         - skel.rest_heads[b]))
            w = np.zeros((len(s), skel.n_bones))
            w[:, b] = 1.0
            wts.append(w)
        offsets.append(sum(len(p) for p in pts))
    return (np.concatenate(pts), np.concatenate(wts),
            CurveLayout(tuple(f"c{i}" for i in range(len(chains))), np.array(offsets)))


def _case(bones: int, vertices: int, k: int, seed: int = 0, black_box: bool = False,
          repeats: int = 3) -> list:
    """One table row: ``repeats`` identical solves of a character posed from its strokes.

    Args:
        bones: Bones of the character (3 rotation parameters each).
        vertices: About this many mesh vertices.
        k: Representative vertices (Eq. 12).
        seed: Seed of the known pose.
        black_box: Differentiate the rig by finite differences instead.
        repeats: Identical solves (the fastest and the median are reported).

    Returns:
        The row, in the order of :data:`HEADERS`.
    """
    skel, chains = character(bones)
    cam = Camera.look_at([0, -6, 1.0], [0, 0, 1.0], width=960, height=960)
    verts, weights = tube_mesh(skel, vertices)
    pts, w, layout = stick(skel, chains)
    n = skel.n_bones
    rng = np.random.default_rng(seed)
    ang = rng.uniform(-0.35, 0.35, n)
    world = ang[:, None] * np.array([0.0, 1.0, 0.0])
    target = RigPose(exp_map(np.einsum("nji,nj->ni", skel.rest_frames, world)), np.ones(n),
                     np.zeros((n, 3)))
    want = skin(pose_bones(skel, target), lbs_weighted_rest(pts, w))
    px = cam.project(want)
    strokes = [Stroke(px[layout.curve(i)]) for i in range(layout.n_curves)]
    start = RigPose(np.tile(np.eye(3), (n, 1, 1)), np.ones(n), np.zeros((n, 3)))
    space = ParameterSpace.from_masks(skel.parents, np.ones(n, bool))
    t0 = time.perf_counter()
    problem = build_lbs_problem(skel, start, space, cam, strokes, pts, w, layout, verts, verts,
                                weights, k=k, budget=400)
    setup = time.perf_counter() - t0
    if black_box:
        rig = FiniteDifferenceRig(space, problem.rig.evaluate, step=1e-6)
        problem = AbstractionProblem(rig, problem.names, cam, problem.layout, problem.strokes,
                                     problem.coarse, start)
    # The machine is shared: report the fastest and the median of identical solves.
    results = [solve_abstraction(problem, SolveOptions()) for _ in range(repeats)]
    result = min(results, key=lambda r: r.seconds)
    median = float(np.median([r.seconds for r in results]))
    got, true = pose_bones(skel, result.pose), pose_bones(skel, target)
    cos3 = np.sum(got.frames[:, :, 1] * true.frames[:, :, 1], axis=1)
    err3 = float(np.degrees(np.arccos(np.clip(cos3, -1, 1))).max())
    d_got = cam.project(got.heads + 0.1 * got.frames[:, :, 1]) - cam.project(got.heads)
    d_true = cam.project(true.heads + 0.1 * true.frames[:, :, 1]) - cam.project(true.heads)
    cos2 = np.sum(d_got * d_true, 1) / np.linalg.norm(d_got, axis=1) / np.linalg.norm(
        d_true, axis=1)
    err2 = float(np.degrees(np.arccos(np.clip(cos2, -1, 1))).max())
    per_it = float(np.median(result.iteration_seconds))
    return [bones, space.n_params, len(verts), len(problem.coarse.indices),
            problem.layout.n_points, setup * 1e3, result.seconds * 1e3, median * 1e3,
            per_it * 1e3, result.iterations, result.initial_residual_px, result.residual_px,
            err2, err3]


HEADERS = ["bones", "params", "vertices", "representatives", "abstraction pts", "setup ms",
           "best solve ms", "median solve ms", "ms / iteration", "iterations", "initial px",
           "final px", "image err deg", "3D err deg"]


def run(quick: bool) -> list[tuple[str, list[str], list[list]]]:
    """Tables: mesh resolution sweep, rig size sweep, and the coarsening/black-box contrast."""
    reps = 2 if quick else 7
    load = f", load {os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else ""
    sizes = (1800, 7000) if quick else (1800, 7000, 28000)
    mesh_rows = [_case(31, v, 200, repeats=reps) for v in sizes]
    rigs = (13, 31) if quick else (13, 31, 61)
    rig_rows = [_case(b, 7000, 200, repeats=reps) for b in rigs]
    contrast = [_case(31, 7000, 200, repeats=reps)[:-1] + ["k-means k=200 (default)"]]
    if not quick:
        contrast.append(_case(31, 7000, 7000, repeats=3)[:-1] + ["no coarsening (k=V)"])
        contrast.append(_case(31, 1800, 200, black_box=True, repeats=3)[:-1]
                        + ["finite-difference rig (black box)"])
    return [
        (f"Abstraction posing: time against mesh resolution (31 bones, 93 parameters, "
         f"{reps} solves{load})", HEADERS, mesh_rows),
        (f"Abstraction posing: time against rig size (7,000 vertices{load})", HEADERS,
         rig_rows),
        (f"Abstraction posing: coarsening and rig paths{load}", HEADERS[:-1] + ["path"],
         contrast),
    ]


if __name__ == "__main__":
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run import format_table

    for table in run("--quick" in sys.argv):
        print(format_table(*table))
