"""Finishing a refined pose (Section 4.3): hands and feet, then attachment enforcement.

A hand or foot resting on the environment is turned, over a grid of its joint's range of
motion, to the orientation with the least penetration of the environment (and the least
energy). Then every pinned joint is placed exactly on its target by a bounded least-squares
solve on the genes of the limb above it (and the root's translation for environment pins;
the spine as well when a limb pin is out of the arm's reach).
"""

from __future__ import annotations

import numpy as np

from .kinematics import PoseModel
from .objective import EnvPin, LimbPin, StickObjective
from .refine import place_joints


def _chain_genes(model: PoseModel, joint: int) -> np.ndarray:
    """Genes of the limb groups above a stick joint (spine and root excluded)."""
    fig, sk = model.figure, model.skeleton
    b = int(fig.joint_bones[joint])
    above = set(sk.ancestors(b)) if fig.joint_at_tail[joint] else set(sk.ancestors(b)[1:])
    picked = [genes for g, genes in zip(fig.groups, model.group_genes, strict=True)
              if g.name not in ("spine", "head") and any(int(x) in above for x in g.bones)]
    return np.concatenate(picked) if picked else np.zeros(0, int)


def _spine_genes(model: PoseModel) -> np.ndarray:
    """Genes of the spine group (empty when there is none)."""
    return model.genes_of("spine")


def _end_group_genes(model: PoseModel, joint: int) -> np.ndarray:
    """Genes of the group of the bone starting at a stick joint (foot at an ankle)."""
    fig = model.figure
    b = int(fig.joint_bones[joint])
    if not fig.joint_at_tail[joint]:
        for g, genes in zip(fig.groups, model.group_genes, strict=True):
            if b in g.bones:
                return genes
    return np.zeros(0, int)


def _clearance(objective: StickObjective, heads: np.ndarray, tails: np.ndarray, joint: int,
               normal: np.ndarray) -> np.ndarray:
    """Height of a joint above the lowest skin around and below it, along ``normal``.

    The skin is the capsules of the joint's bone, its descendants and its parent (an
    ankle over the shin, the foot and the toes).

    Args:
        objective: The energy (its model and capsules are used).
        heads: Bone heads, shape ``(P, n, 3)``.
        tails: Bone tails, shape ``(P, n, 3)``.
        joint: Stick joint index.
        normal: Surface normal, shape ``(3,)``.

    Returns:
        Clearances in world units, shape ``(P,)`` (NaN when the chain has no capsule).
    """
    fig, caps = objective.model.figure, objective.capsules
    b = int(fig.joint_bones[joint])
    sk = objective.model.skeleton
    sel = np.isin(caps.bones, np.union1d(sk.descendants(b), [sk.parents[b]]))
    if not np.any(sel):
        return np.full(len(heads), np.nan)
    start, end = caps.segments(heads, tails)
    low = np.minimum(start[:, sel] @ normal, end[:, sel] @ normal) - caps.radii[sel]
    return fig.joint_positions(heads, tails)[:, joint] @ normal - low.min(1)


def _lie_on_chain(objective: StickObjective, x: np.ndarray, pin: EnvPin) -> EnvPin:
    """The pin's target lifted by the change of the joint's clearance since rest (Eq. 10).

    An ankle's target is lifted by its standing height above the sole. A leg lying along
    the surface (its shin more than 60 degrees from the normal) rests on the back of the
    shin and the heel, which hold the ankle at another height: the target moves along the
    normal by the clearance over the shin and the chain below it in the pose ``x`` minus
    that clearance at rest (standing on the surface), then back onto the eye ray through
    the drawn joint. A shin standing on its foot keeps the standing height.
    """
    model = objective.model
    sk = model.skeleton
    heads, tails, _ = model.forward(x[None])
    n = pin.normal
    parent = sk.parents[int(model.figure.joint_bones[pin.joint])]
    if parent >= 0:
        d = tails[0, parent] - heads[0, parent]
        if abs(d @ n) > 0.5 * np.linalg.norm(d):  # a shin standing on its foot
            return pin
    now = _clearance(objective, heads, tails, pin.joint, n)[0]
    rest = _clearance(objective, sk.rest_heads[None], sk.rest_tails[None], pin.joint,
                      model.figure.up)[0]
    if not np.isfinite(now - rest) or abs(now - rest) < 1e-6:
        return pin

    target = pin.target + n * (now - rest)
    stick, camera = objective.stick, objective.camera
    if stick.present[pin.joint]:
        o, d = camera.rays(stick.points[pin.joint][None])
        rate = float(d[0] @ n)
        t = float((target - o[0]) @ n) / rate if abs(rate) > 1e-6 else -1.0
        if t > 0:
            target = o[0] + t * d[0]
    return EnvPin(pin.joint, target, n, pin.stands)


def finish_pose(objective: StickObjective, x: np.ndarray, bounds: np.ndarray,
                env_pins: tuple[EnvPin, ...], limb_pins: tuple[LimbPin, ...]
                ) -> tuple[np.ndarray, tuple[EnvPin, ...]]:
    """Collision-free hands and feet on the environment, then pins placed exactly.

    A joint that stands on the chain below it (``EnvPin.stands``, an ankle) on a limb
    lying along the surface has its target lifted by its clearance in the pose (Eq. 10
    on the part that touches: a leg lying on the back of its shin and heel holds the
    ankle lower than a standing foot).

    Args:
        objective: The energy (its model, capsules and distance function are used).
        x: Refined genes, shape ``(G,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        env_pins: Joints pinned to the environment.
        limb_pins: Joints pinned to limbs.

    Returns:
        Final genes, shape ``(G,)``, and the environment pins with the targets they were
        placed on.
    """
    model = objective.model
    fig = model.figure
    x = x.copy()
    # Orientation search for the end bones resting on the environment (foot at an ankle).
    for pin in env_pins:
        genes = _end_group_genes(model, pin.joint)
        if genes.size == 0 or objective.grid is None:
            continue
        lo, hi = bounds[genes, 0], bounds[genes, 1]
        axes = [np.linspace(lo[k], hi[k], 5) for k in range(genes.size)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, genes.size)
        X = np.repeat(x[None], len(grid), 0)
        X[:, genes] = grid
        heads, tails, _ = model.forward(X)
        b = np.array(sorted(set(model.skeleton.descendants(int(fig.joint_bones[pin.joint])))))
        caps = objective.capsules
        sel = np.isin(caps.bones, b)
        pen = np.zeros(len(X))
        if np.any(sel):
            u = np.linspace(0, 1, 5)
            start, end = caps.segments(heads, tails)
            pts = start[:, sel, None] * (1 - u)[:, None] + end[:, sel, None] * u[:, None]
            d, _ = objective.grid.sample(pts, limit=1.001 * caps.radii[sel].max())
            pen = np.sum(np.maximum(caps.radii[sel][None, :, None] - d, 0) ** 2, (1, 2))
        e, _ = objective.evaluate(X, collision=False)
        score = e + 100.0 * pen / (0.05 * objective.height) ** 2
        score += 1e-3 * np.sum((grid - x[genes]) ** 2, 1)
        x = X[int(np.argmin(score))]
    env_pins = tuple(_lie_on_chain(objective, x, p) if p.stands else p for p in env_pins)
    # Attachment enforcement: pinned joints exactly on their targets (the limbs and,
    # when several limbs are pinned, the root's translation move).
    if env_pins:
        genes = np.unique(np.concatenate([_chain_genes(model, p.joint) for p in env_pins] +
                                         [np.arange(3)]))
        x, _ = place_joints(objective, x, bounds, np.array([p.joint for p in env_pins]),
                            np.array([p.target for p in env_pins]), genes)
    for pin in limb_pins:
        heads, tails, _ = model.forward(x[None])
        J = fig.joint_positions(heads, tails)[0]
        a, b = pin.limb
        target = (1 - pin.s) * J[a] + pin.s * J[b]
        genes = _chain_genes(model, pin.joint)
        if genes.size:
            x, res = place_joints(objective, x, bounds, np.array([pin.joint]), target[None],
                                  genes)
            if res.max() > 1e-6:  # out of the limb's reach: bend the spine too
                genes = np.union1d(genes, _spine_genes(model))
                heads, tails, _ = model.forward(x[None])
                J = fig.joint_positions(heads, tails)[0]
                target = (1 - pin.s) * J[a] + pin.s * J[b]
                x, _ = place_joints(objective, x, bounds, np.array([pin.joint]),
                                    target[None], genes)
    return x, env_pins
