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
from .kinematics import PoseModel


def _lifted_groups(model: PoseModel, stick: StickFigure) -> list[tuple[int, int, int, float]]:
    """``(group index, first gene, drawn end joint, length)`` of liftable limb groups."""
    sk, fig = model.skeleton, model.figure
    rest = fig.rest_joints(sk)
    out = []
    for gi, (grp, genes) in enumerate(zip(fig.groups, model.group_genes, strict=True)):
        if len(grp.bones) == 1:
            b = int(grp.bones[0])
            hit = np.flatnonzero(np.linalg.norm(rest - sk.rest_tails[b], axis=1) < 1e-6)
            hit = [j for j in hit if stick.present[j]]
            if hit:
                length = float(np.linalg.norm(rest[hit[0]] - sk.rest_heads[b]))
                out.append((gi, int(genes[0]), int(hit[0]), length))
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
    n = len(sel)
    bits = (np.arange(n)[:, None] >> np.arange(len(groups))[None]) & 1
    bits = bits[rng.permutation(n)].astype(bool)
    pop[sel] = _lift(model, pop[sel], bounds, stick, camera, groups, bits)
    return pop


def depth_flips(model: PoseModel, x: np.ndarray, bounds: np.ndarray, stick: StickFigure,
                camera: Camera, max_bones: int = 10) -> np.ndarray:
    """Every near/far choice of the limb bones of one pose: its depth interpretations.

    The root, spine and head of ``x`` are kept; each liftable limb bone (upper arm,
    forearm, thigh, shin, and hand or foot when drawn) is aimed, root-most first, at the
    near or the far point where the eye ray through its drawn end meets the sphere of its
    length around its posed start.

    Args:
        model: Genes -> bones.
        x: The pose, shape ``(G,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        stick: The drawing.
        camera: The view it was drawn in.
        max_bones: Bones whose choice varies (the first ones in the figure's group order);
            the others keep the side of the sphere they have in ``x``.

    Returns:
        ``2^k`` gene vectors, shape ``(2^k, G)``, ``k = min(max_bones, liftable bones)``;
        row ``i`` takes the far point for bone ``j`` when bit ``j`` of ``i`` is set.
    """
    groups = _lifted_groups(model, stick)
    if not groups:
        return np.asarray(x, float)[None].copy()
    k = min(max_bones, len(groups))
    far_now = _far_sides(model, x, stick, camera, groups)
    n = 2**k
    bits = np.broadcast_to(far_now, (n, len(groups))).copy()
    bits[:, :k] = ((np.arange(n)[:, None] >> np.arange(k)[None]) & 1).astype(bool)
    X = np.repeat(np.asarray(x, float)[None], n, 0)
    return _lift(model, X, bounds, stick, camera, groups, bits)


def _far_sides(model: PoseModel, x: np.ndarray, stick: StickFigure, camera: Camera,
               groups: list) -> np.ndarray:
    """Whether each lifted bone of pose ``x`` ends on the far side, ``(len(groups),)``.

    Far: its end lies beyond the closest approach of the eye ray through its drawn end
    to its posed start.
    """
    heads, tails, _ = model.forward(np.asarray(x, float)[None])
    _, d = camera.rays(stick.points[[j for _, _, j, _ in groups]])
    bones = [int(model.figure.groups[gi].bones[0]) for gi, *_ in groups]
    return np.einsum("kd,kd->k", tails[0, bones] - heads[0, bones], d) > 0


def limb_flips(model: PoseModel, x: np.ndarray, bounds: np.ndarray, stick: StickFigure,
               camera: Camera) -> np.ndarray:
    """The depth interpretations one limb away from pose ``x``: a local move.

    Each liftable bone is aimed at the other side of the sphere of its length together
    with the lifted bones it carries: a whole arm or leg about its shoulder or hip, or a
    forearm or a shin alone about its elbow or knee. The flipped bones are aimed as in
    :func:`depth_flips` (whose full enumeration includes these, but re-aims every limb
    and is screened before it is refined), within their joint ranges; every other gene
    keeps its value. A whole limb turns to the other side of the eye ray, its ball
    joint's limits possibly stopping it short. A forearm or shin alone only turns its
    hinge, in the plane the parent's kept twist gives it: when that plane and the
    hinge's range hold the flipped direction its end gets there, otherwise the hinge
    stops at its limit and the move is a nudge that the solver's short refinement
    (``solve._flip_descent``, 10 evaluations) carries on. On the ranking test's pose
    the right wrist moves 0.178 of the 0.185 m the flip asks in depth; the left wrist
    0.046 of 0.463 m and the left ankle 0.029 of 0.745 m, 98 and 113 pixels off their
    drawn points.

    Args:
        model: Genes -> bones.
        x: The pose, shape ``(G,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        stick: The drawing.
        camera: The view it was drawn in.

    Returns:
        One gene vector per liftable bone, shape ``(k, G)`` (``(0, G)`` when none).
    """
    x = np.asarray(x, float)
    groups = _lifted_groups(model, stick)
    if not groups:
        return np.zeros((0, x.size))
    sk = model.skeleton
    bones = [int(model.figure.groups[gi].bones[0]) for gi, *_ in groups]
    far = _far_sides(model, x, stick, camera, groups)
    out = []
    for b in bones:
        # Bone b and the lifted bones below it are aimed again, the others not touched.
        sel = [i for i, c in enumerate(bones) if b in sk.ancestors(c)]
        out.append(_lift(model, x[None], bounds, stick, camera, [groups[i] for i in sel],
                         ~far[sel][None])[0])
    return np.array(out)


def _frame(e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    """Rotations with columns ``e1``, ``e2`` (made orthogonal) and ``e1 x e2``, ``(n, 3, 3)``."""
    e1 = e1 / np.maximum(np.linalg.norm(e1, axis=-1, keepdims=True), 1e-12)
    e2 = e2 - e1 * np.sum(e1 * e2, -1, keepdims=True)
    e2 = e2 / np.maximum(np.linalg.norm(e2, axis=-1, keepdims=True), 1e-12)
    return np.stack([e1, e2, np.cross(e1, e2)], -1)


def _lift(model: PoseModel, X: np.ndarray, bounds: np.ndarray, stick: StickFigure,
          camera: Camera, groups: list, bits: np.ndarray) -> np.ndarray:
    """Aim each lifted group of ``X`` (``(n, G)``) at its near or far point (``bits``).

    A ball joint whose child is a lifted hinge (shoulder, hip) also takes the twist that
    puts the hinge's axis across the plane of its two lifted bones, flexing the right
    way, so that the hinge can reach its own target.
    """
    X = X.copy()
    sk, fig = model.skeleton, model.figure
    y = np.array([0.0, 1.0, 0.0])
    depth, hinge_child = {}, {}
    bone_of = [int(fig.groups[gi].bones[0]) for gi, *_ in groups]
    for k, b in enumerate(bone_of):
        depth[k] = sum(b2 in sk.ancestors(b)[1:] for b2 in bone_of)
        kids = [c for c, b2 in enumerate(bone_of) if sk.parents[b2] == b and
                fig.groups[groups[c][0]].bounds.shape[0] == 1]
        if kids and fig.groups[groups[k][0]].bounds.shape[0] == 3:
            hinge_child[k] = kids[0]
    rays = camera.rays(stick.points[[j for _, _, j, _ in groups]])
    for tier in sorted(set(depth.values())):
        # Only the gene groups' bones are read: the fingers below a hand are not posed.
        tier_bones = [b for k, b in enumerate(bone_of) if depth[k] == tier]
        heads, _, frames, Q = model.forward_rotations(X, rigid=False, bones=tier_bones)
        for k, (gi, start, _, length) in enumerate(groups):
            if depth[k] != tier:
                continue
            grp = fig.groups[gi]
            b = bone_of[k]
            m = grp.bounds.shape[0]
            o, d = rays[0][k][None], rays[1][k][None]
            target = _ray_sphere(o, d, heads[:, b], length, bits[:, k])
            # F_b = C Q0 E with E = exp(B g): the new E must turn y towards the target
            # expressed in C Q0 = F_b E^T.
            E = (np.swapaxes(model.base.rotations[b], 0, 1)[None] @
                 Q[:, tier_bones.index(b)])
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
                if k in hinge_child:
                    c = hinge_child[k]
                    R = _twisted(model, groups, c, b, frames, base, heads[:, b], target,
                                 rays, bits[:, c], R, B, bounds[start:start + m],
                                 bounds[groups[c][1]])
                g = log_map(R) @ B
            X[:, start:start + m] = np.clip(g, bounds[start:start + m, 0],
                                            bounds[start:start + m, 1])
    return X


def _twisted(model: PoseModel, groups: list, c: int, b: int, frames: np.ndarray,
             base: np.ndarray, head: np.ndarray, target: np.ndarray, rays: tuple,
             far: np.ndarray, smallest: np.ndarray, basis: np.ndarray,
             ball_bounds: np.ndarray, hinge_bounds: np.ndarray) -> np.ndarray:
    """Rotations ``E`` (``(n, 3, 3)``) of ball bone ``b`` aiming it at ``target``.

    The twist puts the axis of its lifted hinge child (lifted group ``c``, its end on the
    near or ``far`` side) normal to the plane of the two bones, so that turning the hinge
    moves the child towards its own target. A hinge that can also straighten past its
    rest bend (``hinge_bounds`` ``(2,)`` below 0, a quadruped's knee) has two normals:
    each individual takes the one whose ball genes (``basis`` ``(3, m)``, ``ball_bounds``
    ``(m, 2)``) and hinge angle leave their ranges least (a ball of little twist cannot
    turn the hinge's axis round). Where the
    bones are aligned (no plane) the smallest rotation ``smallest`` is kept.
    """
    gi, _, _, length = groups[c]
    sk = model.skeleton
    cb = int(model.figure.groups[gi].bones[0])
    axis_c = model.figure.groups[gi].bases[0][:, 0]
    # The child's hinge axis in b's posed frame (unchanged when b turns), then in world.
    F_b = frames[:, b]
    ell = np.einsum("pji,pjk,k->pi", F_b, frames[:, cb], axis_c)
    end = _ray_sphere(rays[0][c][None], rays[1][c][None], target, length, far)
    u, v = target - head, end - target
    n = np.cross(u, v)
    ok = np.linalg.norm(n, axis=1) > 1e-6 * np.linalg.norm(u, axis=1) * np.maximum(
        np.linalg.norm(v, axis=1), 1e-12)
    want = np.einsum("pji,pj->pi", base, u)
    y = np.broadcast_to([0.0, 1.0, 0.0], want.shape)
    # Bend of the drawn pair, and the hinge's rest bend about its own axis.
    bend = np.arctan2(np.linalg.norm(n, axis=1), np.sum(u * v, 1))
    d1 = sk.rest_tails[b] - sk.rest_heads[b]
    d2 = sk.rest_tails[cb] - sk.rest_heads[cb]
    a = sk.rest_frames[cb] @ axis_c
    rest = np.arctan2(np.cross(d1, d2) @ a, d1 @ d2)
    best, cost = smallest, np.full(len(want), np.inf)
    # A hinge that only flexes from its rest (a humanoid's elbow or knee) takes the first.
    for sign in (1.0, -1.0) if hinge_bounds[0] < 0.0 else (1.0,):
        n_base = np.einsum("pji,pj->pi", base, sign * n)
        R = _frame(want, n_base) @ np.swapaxes(_frame(y, ell), 1, 2)
        g = log_map(R) @ basis
        theta = sign * bend - rest
        out = (np.sum(np.abs(g - np.clip(g, ball_bounds[:, 0], ball_bounds[:, 1])), 1)
               + np.abs(theta - np.clip(theta, hinge_bounds[0], hinge_bounds[1])))
        better = out < cost - 1e-9
        best = np.where(better[:, None, None], R, best)
        cost = np.where(better, out, cost)
    return np.where(ok[:, None, None], best, smallest)
