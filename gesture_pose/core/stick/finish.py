"""Finishing a refined pose (Section 4.3): hands and feet, then attachment enforcement.

A hand or foot resting on the environment is turned, over a grid of its joint's range of
motion, to the orientation with the least penetration of the environment (and the least
energy); a foot standing on it is turned sole down, flat on the surface. Then every
pinned joint is placed exactly on its target by a bounded least-squares solve on the
genes of the limb above it (and the root's translation for environment pins; the spine
as well when a limb pin is out of the arm's reach, and the whole body, its environment
pins held, when it is out of the spine's too).
"""

from __future__ import annotations

import numpy as np

from ..rotations import exp_map, log_map, rotation_between
from .kinematics import N_ROOT_GENES, PoseModel
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
    if _stands_upright(model, heads, tails, pin)[0]:  # a shin standing on its foot
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


def _stands_upright(model: PoseModel, heads: np.ndarray, tails: np.ndarray,
                    pin: EnvPin) -> np.ndarray:
    """Whether the chain above a standing pin (a shin) is within 60 degrees of its normal.

    Args:
        model: Genes -> bones.
        heads: Bone heads, shape ``(P, n, 3)``.
        tails: Bone tails, shape ``(P, n, 3)``.
        pin: The pin.

    Returns:
        Shape ``(P,)`` bool.
    """
    parent = model.skeleton.parents[int(model.figure.joint_bones[pin.joint])]
    if parent < 0:
        return np.zeros(len(heads), bool)
    d = tails[:, parent] - heads[:, parent]
    return np.abs(d @ pin.normal) > 0.5 * np.linalg.norm(d, axis=-1)


def _sole_tilt(model: PoseModel, frames: np.ndarray, pin: EnvPin) -> np.ndarray:
    """``1 - cos`` of the angle between a standing end bone's sole normal and the pin's.

    The sole faces down at rest: its normal is the character's up carried by the end
    bone (the foot at an ankle). Zero when the foot stands flat on the surface.

    Args:
        model: Genes -> bones.
        frames: Posed bone frames, shape ``(P, n, 3, 3)``.
        pin: The pin (its joint starts the end bone).

    Returns:
        Shape ``(P,)``, in ``[0, 2]``.
    """
    b = int(model.figure.joint_bones[pin.joint])
    local = model.skeleton.rest_frames[b].T @ model.figure.up
    return 1.0 - (frames[:, b] @ local) @ pin.normal


def _flatten(objective: StickObjective, x: np.ndarray, bounds: np.ndarray, pin: EnvPin,
             genes: np.ndarray) -> np.ndarray:
    """The end bone's genes that put its sole flat on the pin's surface.

    The smallest world turn ``R`` taking the sole normal onto the surface's (the turn
    about the normal, which the sole does not fix, stays as it is) becomes the local
    rotation ``exp(B g') = exp(B g) F^T R F`` (``F`` the bone's posed frame), clipped to
    the bounds. Its genes do not move the pinned joint at the bone's head.
    """
    model = objective.model
    b = int(model.figure.joint_bones[pin.joint])
    group = next(g for g, idx in zip(model.figure.groups, model.group_genes, strict=True)
                 if np.array_equal(idx, genes))
    if group.bases.shape[-1] != 3 or len(group.bones) != 1:
        return x
    B = group.bases[0]
    _, _, frames = model.forward(x[None])
    F = frames[0, b]
    sole = F @ (model.skeleton.rest_frames[b].T @ model.figure.up)
    R = rotation_between(sole, pin.normal)
    phi = log_map(exp_map(B @ x[genes]) @ F.T @ R @ F)
    out = x.copy()
    out[genes] = np.clip(B.T @ phi, bounds[genes, 0], bounds[genes, 1])
    return out


def finish_pose(objective: StickObjective, x: np.ndarray, bounds: np.ndarray,
                env_pins: tuple[EnvPin, ...], limb_pins: tuple[LimbPin, ...]
                ) -> tuple[np.ndarray, tuple[EnvPin, ...]]:
    """Collision-free hands and feet on the environment, then pins placed exactly.

    A foot standing on the surface it is pinned to (its shin within 60 degrees of the
    normal) is turned sole down, flat on it (grid search, then least squares), again
    after the pins are placed; other hands and feet take the grid orientation with the
    least penetration of the environment.

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
        heads, tails, frames = model.forward(X)
        b = np.array(sorted(set(model.skeleton.descendants(int(fig.joint_bones[pin.joint])))))
        caps = objective.capsules
        sel = np.isin(caps.bones, b)
        standing = pin.stands and bool(_stands_upright(model, heads[:1], tails[:1], pin)[0])
        e, _ = objective.evaluate(X, collision=False, posed=(heads, tails))
        if standing:
            # A foot standing on the surface: sole down and flat (its pin puts the ankle
            # at its standing height, so the flat sole touches). The capsules, coarser
            # than the skin, would read a flat foot as sunk into the floor.
            score = e + 50.0 * _sole_tilt(model, frames, pin)
        else:
            pen = np.zeros(len(X))
            if np.any(sel):
                u = np.linspace(0, 1, 5)
                start, end = caps.segments(heads, tails)
                pts = start[:, sel, None] * (1 - u)[:, None] + end[:, sel, None] * u[:, None]
                d, _ = objective.grid.sample(pts, limit=1.001 * caps.radii[sel].max())
                pen = np.sum(np.maximum(caps.radii[sel][None, :, None] - d, 0) ** 2, (1, 2))
            score = e + 100.0 * pen / (0.05 * objective.height) ** 2
        score += 1e-3 * np.sum((grid - x[genes]) ** 2, 1)
        x = X[int(np.argmin(score))]
        if standing:
            x = _flatten(objective, x, bounds, pin, genes)
    env_pins = tuple(_lie_on_chain(objective, x, p) if p.stands else p for p in env_pins)
    # Attachment enforcement: pinned joints exactly on their targets (the limbs and,
    # when several limbs are pinned, the root's translation move).
    if env_pins:
        genes = np.unique(np.concatenate([_chain_genes(model, p.joint) for p in env_pins] +
                                         [np.arange(3)]))
        x, _ = place_joints(objective, x, bounds, np.array([p.joint for p in env_pins]),
                            np.array([p.target for p in env_pins]), genes)
        # Placing the ankles turned the shins: the standing feet flat again (their genes
        # do not move the ankles).
        heads, tails, _ = model.forward(x[None])
        for pin in env_pins:
            genes_end = _end_group_genes(model, pin.joint)
            if (pin.stands and genes_end.size and objective.grid is not None
                    and _stands_upright(model, heads, tails, pin)[0]):
                x = _flatten(objective, x, bounds, pin, genes_end)
    for pin in limb_pins:
        heads, tails, _ = model.forward(x[None])
        J = fig.joint_positions(heads, tails)[0]
        target = pin.target(J)
        genes = _chain_genes(model, pin.joint)
        if genes.size:
            x, res = place_joints(objective, x, bounds, np.array([pin.joint]), target[None],
                                  genes)
            if res.max() > 1e-6:  # out of the limb's reach: bend the spine too
                genes = np.union1d(genes, _spine_genes(model))
                heads, tails, _ = model.forward(x[None])
                J = fig.joint_positions(heads, tails)[0]
                target = pin.target(J)
                x, res = place_joints(objective, x, bounds, np.array([pin.joint]),
                                      target[None], genes)
            if res.max() > 1e-6 and env_pins:
                x = _reach_with_body(objective, x, bounds, pin, env_pins, genes)
    return x, env_pins


def _reach_with_body(objective: StickObjective, x: np.ndarray, bounds: np.ndarray,
                     pin: LimbPin, env_pins: tuple[EnvPin, ...], genes: np.ndarray,
                     rounds: int = 40) -> np.ndarray:
    """A limb pin out of reach of the limb and the spine: the whole body turns as well.

    The root's rotation and translation and the limbs of the environment pins join
    ``genes``; the environment-pinned joints stay on their targets while the limb-pinned
    joint goes to its point on the limb, which moves with the body (re-aimed for up to
    ``rounds`` rounds). A pin still out of reach after them shows in the suggestion's
    ``pin_residuals`` and the solve's warning.

    Args:
        objective: The stick objective.
        x: Genes, ``(G,)``.
        bounds: Gene bounds, ``(G, 2)``.
        pin: The body pin.
        env_pins: The environment pins, kept on their targets.
        genes: Genes already free for this pin.
        rounds: Most re-aims of the pin's target as the limb moves.

    Returns:
        The genes, ``(G,)``.
    """
    model = objective.model
    fig = model.figure
    joints = np.array([pin.joint] + [p.joint for p in env_pins])
    more = np.unique(np.concatenate([genes, np.arange(N_ROOT_GENES)] +
                                    [_chain_genes(model, p.joint) for p in env_pins]))
    for _ in range(rounds):
        heads, tails, _ = model.forward(x[None])
        J = fig.joint_positions(heads, tails)[0]
        target = pin.target(J)
        x, res = place_joints(objective, x, bounds, joints,
                              np.array([target] + [p.target for p in env_pins]), more)
        heads, tails, _ = model.forward(x[None])
        J = fig.joint_positions(heads, tails)[0]
        if np.linalg.norm(J[pin.joint] - pin.target(J)) < 1e-6:
            break
    return x


#: Steps of :func:`settle_unseen_feet`'s scan from the natural heading to the solved one.
SETTLE_STEPS = 10


def settle_unseen_feet(objective: StickObjective, x: np.ndarray, bounds: np.ndarray,
                       env_pins: tuple[EnvPin, ...]) -> np.ndarray:
    """Turn each unseen standing foot back towards its natural heading while no energy is paid.

    A pinned standing foot whose tip the drawing omits is turned only by the balance term
    (its sole, Eqs. 7-8) and the weak comfort term, so the search leaves it turned past
    what the support needs. Its natural heading on the ground is its rest direction
    carried by the shin's frame (the knee's plane, which the drawing constrains). The foot
    turns about the pin's normal through the ankle (it stays flat; no drawn joint moves)
    by ``(1 - t)`` of the angle to that heading, ``t`` from 0 to 1 in ``SETTLE_STEPS``
    steps: the first whose total energy (:meth:`.StickObjective.evaluate`) is not above
    the solved pose's is kept (``t = 1``, the solved pose, always is).

    Args:
        objective: The objective with its footprints.
        x: Finished gene vector, shape ``(G,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        env_pins: The environment pins (their normals).

    Returns:
        The gene vector, shape ``(G,)``.
    """
    model = objective.model
    fig, sk = model.figure, model.skeleton
    rest = fig.rest_joints(sk)
    y = np.array(x, float)
    base = None
    for fp in objective.footprints:
        pin = next((p for p in env_pins if p.joint == fp.joint), None)
        bone = int(fig.joint_bones[fp.joint])
        shin = int(sk.parents[bone])
        if objective.stick.present[fp.tip] or pin is None or shin < 0:
            continue
        gi = next((i for i, g in enumerate(fig.groups)
                   if len(g.bones) == 1 and g.bones[0] == bone and g.bases.shape[-1] == 3),
                  None)
        if gi is None:
            continue
        genes, B = model.group_genes[gi], fig.groups[gi].bases[0]
        _, _, frames = model.forward(y[None])
        F, n = frames[0, bone], pin.normal
        foot = F @ (sk.rest_frames[bone].T @ (rest[fp.tip] - rest[fp.joint]))
        natural = frames[0, shin] @ (sk.rest_frames[shin].T @ (rest[fp.tip] - rest[fp.joint]))
        foot, natural = foot - n * (foot @ n), natural - n * (natural @ n)
        if min(np.linalg.norm(foot), np.linalg.norm(natural)) < 1e-9:
            continue
        angle = np.arctan2(np.cross(foot, natural) @ n, foot @ natural)
        cands = []
        for t in np.linspace(0.0, 1.0, SETTLE_STEPS + 1)[:-1]:
            R = exp_map(n * (1.0 - t) * angle)
            g = B.T @ log_map(exp_map(B @ y[genes]) @ F.T @ R @ F)
            if np.all((g >= bounds[genes, 0]) & (g <= bounds[genes, 1])):
                z = y.copy()
                z[genes] = g
                cands.append(z)
        if not cands:
            continue
        if base is None:
            base = objective.evaluate(y[None])[0][0]
        e = objective.evaluate(np.array(cands))[0]
        ok = np.flatnonzero(e <= base + 1e-12 * max(abs(base), 1.0))  # rounding
        if ok.size:
            y, base = cands[ok[0]], e[ok[0]]
    return y
