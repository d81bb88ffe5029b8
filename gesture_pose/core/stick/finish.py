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
    genes, start = [], 6
    for g in fig.groups:
        m = g.bounds.shape[0]
        if g.name not in ("spine", "head") and any(int(x) in above for x in g.bones):
            genes += range(start, start + m)
        start += m
    return np.array(genes, int)


def _spine_genes(model: PoseModel) -> np.ndarray:
    """Genes of the spine group (empty when there is none)."""
    start = 6
    for g in model.figure.groups:
        m = g.bounds.shape[0]
        if g.name == "spine":
            return np.arange(start, start + m)
        start += m
    return np.zeros(0, int)


def _end_group_genes(model: PoseModel, joint: int) -> np.ndarray:
    """Genes of the group of the bone starting at a stick joint (foot at an ankle)."""
    fig, start = model.figure, 6
    b = int(fig.joint_bones[joint])
    for g in fig.groups:
        m = g.bounds.shape[0]
        if not fig.joint_at_tail[joint] and b in g.bones:
            return np.arange(start, start + m)
        start += m
    return np.zeros(0, int)


def finish_pose(objective: StickObjective, x: np.ndarray, bounds: np.ndarray,
                env_pins: tuple[EnvPin, ...], limb_pins: tuple[LimbPin, ...]) -> np.ndarray:
    """Collision-free hands and feet on the environment, then pins placed exactly.

    Args:
        objective: The energy (its model, capsules and distance function are used).
        x: Refined genes, shape ``(G,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        env_pins: Joints pinned to the environment.
        limb_pins: Joints pinned to limbs.

    Returns:
        Final genes, shape ``(G,)``.
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
    return x
