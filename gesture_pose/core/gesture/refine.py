"""2D refinement of the embedding (Gesture3D Section 6).

The discrete solution puts joints on candidate positions only. Each joint then takes a
local random walk: trial moves around it (Gaussian, epsilon / 2) are kept when they lower
the part of ``E_match`` touching the joint, keep the joint on the same side of every nearby
contour and create no new inconsistency (the consistency term of its bones may not grow).
Limb ends (a joint with its few descendants: an elbow with the wrist and the hand) also
walk as a whole, so a limb drawn shorter or longer than where the search left it can slide
along its outline without first stretching one bone. The step is halved each time a
sweep lowers the energy by less than a small amount, down to epsilon / 8.
Joints with reduced degrees of freedom, the pelvis and the shoulders, whose joints are tied
by rigid offsets, are snapped to the nearest 2D rigid transform of their bind-pose
neighbourhood (one ICP step, a 2D Kabsch fit) unless that raises their energy by more than
a small slack (a 2D rigid motion cannot follow the foreshortening of a turned torso). This
repeats until the walk converges at its smallest step. The walk uses a fixed seed, so a
given input always gives the same result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .candidates import JointCandidates
from .costs import (
    triplet_cost,
    unary_cost,
    unary_from_aligned,
)
from .mrf import MatchProblem, joint_energy, link_costs, rigid_descendants


@dataclass(frozen=True)
class RefineParams:
    """Refinement parameters.

    Attributes:
        iterations: Maximum sweeps over the joints.
        trials: Trial moves per joint and sweep.
        step: Standard deviation of a trial move, in epsilons.
        min_step: The walk's step is halved after a sweep that lowers the energy by less
            than ``converged``, down to this (epsilons); the walk ends after such a sweep at
            this step.
        converged: Energy decrease of a sweep below which the walk has converged at its
            step.
        seed: Random seed.
        snap_rigid: Snap the rigid neighbourhoods (pelvis, shoulders).
        group_trials: Trial moves of a rigid neighbourhood per sweep.
        group_turn: Standard deviation of a rigid neighbourhood's trial turn, degrees.
        snap_slack: A snap is kept unless it raises the group's energy by more than this
            (infinite: always, as in the paper). A group's rigid joints do not walk on
            their own: the group walks as a whole.
        chain_trials: Trial moves per sweep of each limb end moved as a whole (a joint
            with all its descendants, see :func:`limb_chains`); 0 disables them.
        chain_size: Most joints of such a limb end.
    """

    iterations: int = 12
    trials: int = 24
    step: float = 0.5
    min_step: float = 0.125
    converged: float = 0.05
    seed: int = 0
    snap_rigid: bool = True
    group_trials: int = 6
    group_turn: float = 3.0
    snap_slack: float = float("inf")
    chain_trials: int = 8
    chain_size: int = 3


def limb_chains(problem: MatchProblem, size: int) -> list[np.ndarray]:
    """Free joints with their descendants, when those are free and at most ``size`` joints.

    On a humanoid: an elbow with the wrist and the hand's tail, a wrist with the hand's
    tail, a knee with the ankle and the foot's tail, the neck with the head. Each list
    starts with its top joint, parents before children.
    """
    s = problem.solving
    rigid = problem.rigid
    out = []
    for j in np.flatnonzero(~rigid & (s.joint_parent >= 0)):
        sub = [int(j)]
        k = 0
        while k < len(sub) and len(sub) <= size:
            sub += [int(c) for c in np.flatnonzero(s.joint_parent == sub[k])]
            k += 1
        if 2 <= len(sub) <= size and not rigid[sub].any():
            out.append(np.array(sub))
    return out


def _conf_link(problem: MatchProblem, conf: JointCandidates, j: int, pa: np.ndarray,
               pb: np.ndarray) -> tuple:
    """Joint ``j``'s link with the configuration's labels, positions moved.

    Args:
        problem: The matching problem.
        conf: The configuration's labels (radii, groups, sides).
        j: The joint whose link to its parent is costed.
        pa: Parent positions, pixels, ``(Ka, 2)``.
        pb: Joint ``j``'s positions, pixels, ``(Kb, 2)``.

    Returns:
        The arguments of :func:`~.mrf.link_cost` after ``problem`` (see
        :func:`~.mrf.link_costs`), for a ``(Ka, Kb)`` table.
    """
    p = problem.solving.joint_parent[j]
    return (j, pa, conf.radii[[p]], conf.group[[p]], conf.side[[p]], pb,
            conf.radii[[j]], conf.group[[j]], conf.side[[j]])


def _per_trial(table: np.ndarray, t: int) -> np.ndarray:
    """The entries of a cost table where every moved joint takes the same trial, ``(t,)``.

    Each axis of ``table`` has length ``t`` (a joint moved by the trials) or 1 (a joint
    that stays).
    """
    index = tuple(np.arange(t) if n == t else np.zeros(t, int) for n in table.shape)
    return table[index]


def _same_side(problem: MatchProblem, old: np.ndarray, trial: np.ndarray,
               reach: float) -> np.ndarray:
    """Trials on the same side as ``old`` of every contour sample within ``reach``, ``(T,)``."""
    d = problem.drawing
    near = d.tree.query_ball_point(old, reach)
    if not near:
        return np.ones(len(trial), bool)
    near = np.asarray(near)
    side_old = np.sign(np.einsum("nd,nd->n", old[None] - d.points[near], d.normals[near]))
    side_new = np.sign(np.einsum("tnd,nd->tn", trial[:, None] - d.points[near][None],
                                 d.normals[near]))
    return np.all(side_new * side_old[None] >= 0, axis=1)


def with_positions(conf: JointCandidates, positions: np.ndarray) -> JointCandidates:
    """``conf``'s labels (radii, sides, origins, groups, unaries) at ``positions`` ``(J, 2)``."""
    return JointCandidates(positions, conf.radii, conf.side, conf.origin, conf.group,
                           conf.unary, conf.aligned)


def rigid_groups(problem: MatchProblem) -> list[np.ndarray]:
    """Rigid neighbourhoods: a free joint and the rigid joints hanging from it, ``(k,)``.

    Rigid joints (see :attr:`MatchProblem.rigid`: hip and shoulder heads, interior bones'
    tails such as a clavicle's) are collected down the tree, so a chest's group holds the
    shoulder heads and the clavicle tails.
    """
    rigid = problem.rigid
    groups = (rigid_descendants(problem.solving.joint_parent, rigid, int(p))
              for p in np.flatnonzero(~rigid))
    return [g for g in groups if len(g) > 1]


def kabsch_2d(template: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``template`` moved by the rigid 2D transform closest to ``target`` (least squares).

    Args:
        template: Points, ``(k, 2)``.
        target: Points, ``(k, 2)``.

    Returns:
        Transformed template, ``(k, 2)``.
    """
    a = template - template.mean(axis=0)
    b = target - target.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    rot = (u @ vt).T
    if np.linalg.det(rot) < 0:
        vt[-1] *= -1
        rot = (u @ vt).T
    return a @ rot.T + target.mean(axis=0)


def _walk_group(problem: MatchProblem, conf: JointCandidates, pos: np.ndarray,
                grp: np.ndarray, rng: np.random.Generator, params: RefineParams,
                step: float | None = None) -> np.ndarray:
    """One random-walk step of a rigid neighbourhood moved as a whole.

    Trials turn the group about its centroid (``group_turn`` degrees, Gaussian) and move
    it (``step`` epsilons, Gaussian); the best trial lowering the energy of the group's
    factors, with its free joint staying on the same side of the nearby contours, is kept.

    Returns:
        The new positions ``(J, 2)``, or ``pos`` itself when no trial is better.
    """
    eps = problem.drawing.epsilon
    n = params.group_trials
    ang = np.radians(rng.normal(0.0, params.group_turn, n))
    step = params.step if step is None else step
    ang = ang * step / params.step
    shift = rng.normal(0.0, step * eps, (n, 2))
    centre = pos[grp].mean(axis=0)
    rel = pos[grp] - centre
    cos, sin = np.cos(ang)[:, None], np.sin(ang)[:, None]
    moved = np.stack([cos * rel[:, 0] - sin * rel[:, 1], sin * rel[:, 0] + cos * rel[:, 1]],
                     axis=2) + centre + shift[:, None]
    ok = _same_side(problem, pos[grp[0]], moved[:, 0], 2.0 * conf.radii[grp[0]] + eps)
    if not ok.any():
        return pos
    trials = np.concatenate([pos[grp][None], moved[ok]])
    energy = _set_energy(problem, conf, pos, grp, trials)
    energy = np.where(np.isfinite(energy), energy, np.inf)
    k = int(np.argmin(energy[1:]))
    if energy[1 + k] >= energy[0] - 1e-6:
        return pos
    out = pos.copy()
    out[grp] = trials[1 + k]
    return out


def _set_energy(problem: MatchProblem, conf: JointCandidates, pos: np.ndarray,
                idx: np.ndarray, moved: np.ndarray) -> np.ndarray:
    """``E_match`` of the factors touching joints ``idx`` for each placement of them, ``(T,)``.

    The factors of :func:`~.mrf.joint_energy` with ``joints=idx`` (the unaries of
    ``idx`` but its rigid joints', every link and triplet with a joint in ``idx``),
    evaluated for all trials at once; the other joints stay at ``pos``.

    Args:
        problem: The matching problem.
        conf: The configuration's labels (radii, groups, sides).
        pos: Current joint positions, pixels, ``(J, 2)``.
        idx: The moved joints, ``(k,)``.
        moved: Their positions in each trial, pixels, ``(T, k, 2)``.

    Returns:
        The energy of each trial, ``(T,)``.
    """
    s, d, prm = problem.solving, problem.drawing, problem.params
    par = s.joint_parent
    t = len(moved)
    slot = {int(k): i for i, k in enumerate(idx)}

    def at(k: int) -> np.ndarray:
        return moved[:, slot[k]] if k in slot else pos[k][None]

    total = np.zeros(t)
    scored = problem.scored
    for k in slot:
        if not scored[k]:
            continue  # placed by rigidity: no unary (see mrf.joint_energy)
        aligned = unary_cost(d, at(k), np.full(t, conf.radii[k]), bool(problem.terminal[k]),
                             prm)[1]
        total += unary_from_aligned(aligned, bool(problem.terminal[k]), prm,
                                    problem.bone_blocked(k))
    linked = [int(j) for j in np.flatnonzero(par >= 0) if j in slot or par[j] in slot]
    tables = dict(zip(linked, link_costs(problem, [
        _conf_link(problem, conf, j, at(int(par[j])), at(j)) for j in linked]), strict=True))
    for j in np.flatnonzero(par >= 0):
        p = int(par[j])
        g = int(par[p])
        if j in slot or p in slot:
            total += _per_trial(tables[int(j)], t)
        if problem.has_triplet(j) and (j in slot or p in slot or g in slot):
            ga, gb, gc = conf.group[g], conf.group[p], conf.group[j]
            shared = bool(ga == gb == gc and gc >= 0)
            table = triplet_cost(at(g), at(p), at(int(j)), np.array(shared),
                                 float(problem.rest_angle[j]), prm)
            total += _per_trial(table, t)
    return total


def refine(problem: MatchProblem, conf: JointCandidates, template: np.ndarray,
           params: RefineParams | None = None) -> tuple[JointCandidates, dict]:
    """Local random walk and rigid snapping to convergence.

    Args:
        problem: The matching problem.
        conf: One placement per joint (the discrete solution).
        template: The character's joints in the view at the current pose, pixels, ``(J, 2)``.
        params: Refinement parameters.

    Returns:
        ``(refined configuration, diagnostics)`` with ``"sweeps"``, ``"moves"``,
        ``"energy_before"`` and ``"energy_after"``.
    """
    params = params or RefineParams()
    rng = np.random.default_rng(params.seed)
    eps = problem.drawing.epsilon
    before = joint_energy(problem, conf)[0]
    pos = conf.positions.copy()
    moves, sweeps = 0, 0
    groups = rigid_groups(problem) if params.snap_rigid else []
    roots = {int(g[0]): g for g in groups}
    chains = limb_chains(problem, params.chain_size) if params.chain_trials else []
    step = params.step
    for sweep in range(1, params.iterations + 1):
        sweeps = sweep
        moved, gain = 0, 0.0
        for j in range(len(pos)):
            if params.snap_rigid and problem.rigid[j]:
                continue  # moves with its rigid neighbourhood
            if j in roots:
                new = _walk_group(problem, conf, pos, roots[j], rng, params, step)
                moved += int(new is not pos)
                pos = new
                continue
            trial = pos[j] + rng.normal(0.0, step * eps, (params.trials, 2))
            trial = np.concatenate([pos[j:j + 1], trial])
            ok = _same_side(problem, pos[j], trial, 2.0 * conf.radii[j] + eps)
            energy = _set_energy(problem, conf, pos, np.array([j]), trial[:, None])
            energy = np.where(ok, energy, np.inf)
            k = int(np.argmin(energy))
            if k > 0 and energy[k] < energy[0] - 1e-6:
                pos = pos.copy()
                pos[j] = trial[k]
                moved += 1
                gain += energy[0] - energy[k]
        for chain in chains:
            shift = np.concatenate([np.zeros((1, 2)),
                                    rng.normal(0.0, step * eps, (params.chain_trials, 2))])
            top = int(chain[0])
            ok = _same_side(problem, pos[top], pos[top] + shift, 2.0 * conf.radii[top] + eps)
            # A translation leaves the chain's inner triplets as they are: the energies
            # differ by exactly the factors it changes.
            moved_chain = pos[chain][None] + shift[:, None]
            energy = np.where(ok, _set_energy(problem, conf, pos, chain, moved_chain), np.inf)
            k = int(np.argmin(energy))
            if k > 0 and energy[k] < energy[0] - 1e-6:
                pos = pos.copy()
                pos[chain] += shift[k]
                moved += 1
                gain += energy[0] - energy[k]
        for grp in groups:
            trial_pos = pos.copy()
            trial_pos[grp] = kabsch_2d(template[grp], pos[grp])
            if np.allclose(trial_pos, pos, atol=1e-3):
                continue
            if params.snap_slack != np.inf:
                old, new = _set_energy(problem, conf, pos, grp,
                                       np.stack([pos[grp], trial_pos[grp]]))
                if new > old + params.snap_slack:
                    continue
            pos = trial_pos
        moves += moved
        if moved == 0 or gain < params.converged:
            if step <= params.min_step:
                break
            step = max(0.5 * step, params.min_step)
    out = JointCandidates(pos, conf.radii, conf.side, conf.origin, conf.group, conf.unary,
                          conf.aligned)
    after = joint_energy(problem, out)[0]
    return out, {"sweeps": sweeps, "moves": moves, "energy_before": before,
                 "energy_after": after}
