"""Seeding the genetic search by lifting the drawing (the two depths of each limb).

Seen through the eye, a limb bone of known length starting at a known 3D joint can only
end where the eye ray through its drawn end meets the sphere of that length around the
joint: at a near or a far point (or, when the drawn bone is too long, closest to the
ray). Choosing near or far for every limb bone enumerates the classic depth ambiguities
of single-view reconstruction; with ten limb bones the 2^10 choices fill a population of
1024. Each individual aims its limb bones, root-most first, at its chosen points: ball
joints take the smallest rotation, hinges the best angle about their axis, both clipped
to the ranges of motion.
"""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..rotations import log_map, rotation_between
from .graph import StickFigure
from .kinematics import N_ROOT_GENES, PoseModel


def _lifted_groups(model: PoseModel, stick: StickFigure) -> list[tuple[int, int, int, float]]:
    """``(group index, first gene, drawn end joint, length)`` of liftable limb groups."""
    sk, fig = model.skeleton, model.figure
    rest = fig.joint_positions(sk.rest_heads, sk.rest_tails)
    out, start = [], N_ROOT_GENES
    for gi, grp in enumerate(fig.groups):
        m = grp.bounds.shape[0]
        if len(grp.bones) == 1:
            b = int(grp.bones[0])
            hit = np.flatnonzero(np.linalg.norm(rest - sk.rest_tails[b], axis=1) < 1e-6)
            hit = [j for j in hit if stick.present[j]]
            if hit:
                length = float(np.linalg.norm(rest[hit[0]] - sk.rest_heads[b]))
                out.append((gi, start, int(hit[0]), length))
        start += m
    return out


def _ray_sphere(origins, dirs, centers, radius, far):
    """Near or far intersection of rays with spheres (closest ray point when missed)."""
    oc = origins - centers
    b = np.sum(oc * dirs, -1)
    c = np.sum(oc * oc, -1) - radius**2
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0.0))
    t = np.where(far, -b + root, -b - root)
    t = np.where(disc < 0, -b, t)
    return origins + dirs * t[..., None]


def lift_population(model: PoseModel, pop: np.ndarray, bounds: np.ndarray,
                    stick: StickFigure, camera: Camera, rng: np.random.Generator,
                    fraction: float = 0.8) -> np.ndarray:
    """Aim the limb bones of a fraction of the population at lifted drawn joints.

    Args:
        model: Genes -> bones.
        pop: Individuals (root and spine already set), shape ``(N, G)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        stick: The drawing.
        camera: The view it was drawn in.
        rng: Random generator.
        fraction: Share of individuals lifted (the rest stay random).

    Returns:
        The new population, shape ``(N, G)``.
    """
    pop = pop.copy()
    groups = _lifted_groups(model, stick)
    if not groups:
        return pop
    sel = np.flatnonzero(rng.random(len(pop)) < fraction)
    X = pop[sel]
    n = len(sel)
    bits = (np.arange(n)[:, None] >> np.arange(len(groups))[None]) & 1
    bits = bits[rng.permutation(n)].astype(bool)
    sk, fig = model.skeleton, model.figure
    y = np.array([0.0, 1.0, 0.0])
    depth = {}
    for k, (gi, _, _, _) in enumerate(groups):
        b = int(fig.groups[gi].bones[0])
        depth[k] = sum(int(fig.groups[g2].bones[0]) in sk.ancestors(b)[1:]
                       for g2, *_ in groups)
    for tier in sorted(set(depth.values())):
        heads, _, frames = model.forward(X)
        Q, _ = model.local_rotations(X)
        for k, (gi, start, joint, length) in enumerate(groups):
            if depth[k] != tier:
                continue
            grp = fig.groups[gi]
            b = int(grp.bones[0])
            m = grp.bounds.shape[0]
            o, d = camera.rays(stick.points[joint][None])
            target = _ray_sphere(o, d, heads[:, b], length, bits[:, k])
            # F_b = C Q0 E with E = exp(B g): the new E must turn y towards the target
            # expressed in C Q0 = F_b E^T.
            E = np.swapaxes(model.base.rotations[b], 0, 1)[None] @ Q[:, b]
            base = frames[:, b] @ np.swapaxes(E, 1, 2)
            want = np.einsum("pji,pj->pi", base, target - heads[:, b])
            B = grp.bases[0]
            if m == 1:
                a = B[:, 0]
                yp = y - a * (a @ y)
                theta = np.arctan2(want @ np.cross(a, yp), want @ yp)
                g = theta[:, None]
            else:
                R = rotation_between(np.broadcast_to(y, want.shape), want)
                g = log_map(R) @ B
            X[:, start:start + m] = np.clip(g, bounds[start:start + m, 0],
                                            bounds[start:start + m, 1])
    pop[sel] = X
    return pop
