"""Global consistency of an embedding (Gesture3D Section 5.4).

The tree MRF cannot see two constraints that span the whole drawing:

- *non-overlap*: contour samples on the same side of two disjoint bones (bones sharing no
  joint), or aligned with two non-adjacent joints, mean two body parts claim one line;
  each such pair costs ``overlap_penalty`` (10), except left/right counterparts the view
  superimposes (:func:`stacked_counterparts`, ours);
- *coverage*: at least 85% of the drawn contour samples must be explained by some bone or
  joint.

Terminal joints (the limb ends) decide most of both, so their assignments are enumerated
in increasing unary cost, violators of the non-overlap constraint last, stopping at the
first solution meeting both (:func:`terminal_order`, :func:`first_consistent`; by default
the embedding moves them onto unexplained contours instead, see
``embedding._coverage_moves``). Left/right limbs are then permuted (each symmetric limb
pair swapped or not); among permutations of (nearly) equal energy the least twisted, most
front-facing one wins: the one whose left/right order agrees with the character's current
pose seen in the view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .candidates import JointCandidates
from .costs import bone_frame, circle_alignment
from .mrf import MatchProblem
from .solving import symmetric_joint_pairs


@dataclass(frozen=True)
class Assignment:
    """Contour samples matched to bones and joints.

    Attributes:
        bone_left: Per solving bone, samples conforming on its left, list of ``(k,)`` int.
        bone_right: Per solving bone, samples conforming on its right.
        joint_samples: Per joint, samples its circle is aligned with.
        covered: Samples matched to anything, ``(N,)`` bool.
        coverage: Fraction of covered samples.
        overlaps: Pairs of solving bones (or joints, as ``-1 - j``) that claim the same
            same-side samples, list of ``(a, b)``.
    """

    bone_left: list[np.ndarray]
    bone_right: list[np.ndarray]
    joint_samples: list[np.ndarray]
    covered: np.ndarray
    coverage: float
    overlaps: list[tuple[int, int]]


def assign_contours(problem: MatchProblem, conf: JointCandidates) -> Assignment:
    """Match contour samples to the bones and joints of a configuration.

    A sample conforms to a bone when it projects inside the bone, lies at the interpolated
    joint radius (within ``max(epsilon, r / 2)``) and runs along the bone (within
    ``conform_angle``), as in the conformity term ``Ccf``.

    Args:
        problem: The matching problem.
        conf: One placement per joint.

    Returns:
        The assignment with coverage and overlaps.
    """
    d, s = problem.drawing, problem.solving
    eps = d.epsilon
    idx = np.arange(d.n_samples)
    left, right = [], []
    for b in range(s.n_bones):
        ha, ta = s.head_joint[b], s.tail_joint[b]
        t, h, _, u = bone_frame(d, conf.positions[ha:ha + 1], conf.positions[ta:ta + 1], idx)
        t, h, u = t[0, 0], h[0, 0], u[0, 0]
        r_t = (1 - t) * conf.radii[ha] + t * conf.radii[ta]
        along = np.abs(d.normals @ u)
        ok = ((t >= 0) & (t <= 1) & (np.abs(np.abs(h) - r_t) < np.maximum(eps, 0.5 * r_t))
              & (along < np.sin(problem.params.conform_angle)))
        left.append(np.flatnonzero(ok & (h > 0)))
        right.append(np.flatnonzero(ok & (h < 0)))
    aligned = circle_alignment(d, conf.positions, conf.radii, problem.params)
    joint_samples = [np.unique(a[a >= 0]) for a in aligned]
    covered = np.zeros(d.n_samples, bool)
    for arr in left + right + joint_samples:
        covered[arr] = True
    overlaps = _overlaps(problem, left, right, joint_samples)
    return Assignment(left, right, joint_samples, covered, float(covered.mean()), overlaps)


def stacked_counterparts(problem: MatchProblem) -> np.ndarray:
    """Left/right joint pairs the view superimposes at the current pose, ``(p, 2)`` int.

    A pair whose joints lie within ``CostParams.stacked_counterparts`` epsilons of each
    other in the character's current pose seen in the view (a quadruped's left and right
    legs seen from the side, one behind the other) is drawn on the same lines: its bones
    and joints may share contour samples without counting as an overlap (ours; the paper
    counts every pair of disjoint bones). Without it a side view's legs, which overlap
    however they are placed, were pushed onto the other legs' outlines by the overlap
    penalty (the 3D bench's quadruped with its tail up, seen from the side: a front leg
    fitted to the hind legs, 94 px mean error; with it 17 px).

    Args:
        problem: The matching problem (its ``reference``: the current pose in the view).

    Returns:
        Joint index pairs ``(lower index, its counterpart)``, ``(p, 2)`` int; none
        without a reference, without left/right pairs or with the option at 0.
    """
    pairs = symmetric_joint_pairs(problem.solving)
    limit = problem.params.stacked_counterparts * problem.drawing.epsilon
    if problem.reference is None or len(pairs) == 0 or limit <= 0:
        return np.zeros((0, 2), int)
    ref = np.asarray(problem.reference, float)
    gap = np.linalg.norm(ref[pairs[:, 0]] - ref[pairs[:, 1]], axis=1)
    return pairs[gap < limit]


def _overlaps(problem: MatchProblem, left: list[np.ndarray], right: list[np.ndarray],
              joints: list[np.ndarray], min_shared: int = 2) -> list[tuple[int, int]]:
    """Disjoint bones (and non-adjacent joints) sharing same-side samples."""
    s = problem.solving
    n_s = problem.drawing.n_samples
    ends = np.stack([s.head_joint, s.tail_joint], axis=1)
    m = s.n_bones
    # Membership matrices, (m, N) for each side.
    member_l = np.zeros((m, n_s), bool)
    member_r = np.zeros((m, n_s), bool)
    for b in range(m):
        member_l[b, left[b]] = True
        member_r[b, right[b]] = True
    shared = member_l.astype(int) @ member_l.T.astype(int)
    shared += member_r.astype(int) @ member_r.T.astype(int)
    touching = (ends[:, None, :, None] == ends[None, :, None, :]).any(axis=(2, 3))
    # Bones meeting at a rigid offset (pelvis and thighs) are neighbours too.
    par = s.joint_parent
    rigid_pairs = {(j, par[j]) for j in range(s.n_joints) if s.joint_link_bone[j] < 0}
    for j, p in rigid_pairs:
        at_j = (ends == j).any(axis=1)
        at_p = (ends == p).any(axis=1)
        touching |= at_j[:, None] & at_p[None, :]
        touching |= at_p[:, None] & at_j[None, :]
    bad = (shared >= min_shared) & ~touching
    stacked = stacked_counterparts(problem)
    partner = dict(zip(stacked[:, 0].tolist(), stacked[:, 1].tolist(), strict=True))
    partner.update(zip(stacked[:, 1].tolist(), stacked[:, 0].tolist(), strict=True))
    tail = np.asarray(s.tail_joint)
    for b in range(m):
        if int(tail[b]) in partner:
            other = np.flatnonzero(tail == partner[int(tail[b])])
            bad[b, other] = bad[other, b] = False
    out = [(int(a), int(b)) for a, b in zip(*np.nonzero(np.triu(bad, 1)), strict=True)]
    n_j = s.n_joints
    member_j = np.zeros((n_j, n_s), bool)
    for j in range(n_j):
        member_j[j, joints[j]] = True
    shared_j = member_j.astype(int) @ member_j.T.astype(int)
    adjacent = np.eye(n_j, dtype=bool)
    has = par >= 0
    adjacent[np.flatnonzero(has), par[has]] = True
    adjacent[par[has], np.flatnonzero(has)] = True
    bad_j = (shared_j >= min_shared) & ~adjacent
    bad_j[stacked[:, 0], stacked[:, 1]] = bad_j[stacked[:, 1], stacked[:, 0]] = False
    out += [(-1 - int(a), -1 - int(b))
            for a, b in zip(*np.nonzero(np.triu(bad_j, 1)), strict=True)]
    return out


def block_overlaps(problem: MatchProblem, assign: Assignment) -> np.ndarray:
    """Samples each bone may no longer claim, resolving the overlaps of ``assign``.

    Of two overlapping bones (or joints) the one whose middle lies farther from the shared
    samples in the view at the current pose yields (the later one in the skeleton when
    there is no reference): it may not use the other's samples, so the next solve moves it
    to other contours.

    Returns:
        Blocked samples per solving bone, ``(m, N)`` bool.
    """
    s = problem.solving
    blocked = np.zeros((s.n_bones, problem.drawing.n_samples), dtype=bool)

    def claim(x: int) -> tuple[int, np.ndarray]:
        if x >= 0:
            return x, np.concatenate([assign.bone_left[x], assign.bone_right[x]])
        j = -1 - x
        link = s.joint_link_bone[j]
        bone = link if link >= 0 else int(np.flatnonzero(s.head_joint == j)[0])
        return bone, assign.joint_samples[j]

    ref = problem.reference

    def distance(bone: int, samples: np.ndarray) -> float:
        if ref is None or samples.size == 0:
            return float(bone)
        mid = 0.5 * (ref[s.head_joint[bone]] + ref[s.tail_joint[bone]])
        return float(np.linalg.norm(problem.drawing.points[samples].mean(axis=0) - mid))

    for a, b in assign.overlaps:
        (bone_a, samples_a), (bone_b, samples_b) = claim(a), claim(b)
        shared = np.intersect1d(samples_a, samples_b)
        a_loses = distance(bone_a, shared) > distance(bone_b, shared)
        loser, winner_samples = (bone_a, samples_b) if a_loses else (bone_b, samples_a)
        blocked[loser, winner_samples] = True
    return blocked


def symmetric_limbs(problem: MatchProblem) -> list[np.ndarray]:
    """Left/right limb pairs as arrays of joint pairs, each ``(k, 2)`` int.

    A limb starts at a symmetric joint whose parent is not symmetric and collects the
    symmetric joints below it.
    """
    s = problem.solving
    pairs = symmetric_joint_pairs(s)
    if len(pairs) == 0:
        return []
    partner = -np.ones(s.n_joints, int)
    partner[pairs[:, 0]], partner[pairs[:, 1]] = pairs[:, 1], pairs[:, 0]
    limb_of = -np.ones(s.n_joints, int)
    limbs: list[list[tuple[int, int]]] = []
    for a, b in pairs:
        p = s.joint_parent[a]
        if p >= 0 and partner[p] >= 0 and limb_of[p] >= 0:
            limb_of[a] = limb_of[p]
        else:
            limb_of[a] = len(limbs)
            limbs.append([])
        limbs[limb_of[a]].append((int(a), int(b)))
    return [np.array(limb, dtype=int) for limb in limbs]


def twist_score(problem: MatchProblem, positions: np.ndarray, reference: np.ndarray) -> int:
    """Symmetric joint pairs whose left/right order disagrees with ``reference``.

    The order of a pair is the side of the body axis (root joint to the centroid) the left
    joint lies on; ``reference`` is the character's current pose projected in the view.

    Args:
        problem: The matching problem.
        positions: Joint positions, pixels, ``(J, 2)``.
        reference: Reference joint positions, pixels, ``(J, 2)``.
    """
    pairs = symmetric_joint_pairs(problem.solving)
    if len(pairs) == 0:
        return 0

    def order(p: np.ndarray) -> np.ndarray:
        axis = p.mean(axis=0) - p[0]
        axis = axis / max(np.linalg.norm(axis), 1e-9)
        d = p[pairs[:, 0]] - p[pairs[:, 1]]
        return np.sign(axis[0] * d[:, 1] - axis[1] * d[:, 0])

    return int(np.sum(order(positions) * order(reference) < 0))


def permute(conf: JointCandidates, limbs: list[np.ndarray], mask: int) -> JointCandidates:
    """Swap the placements of the limbs whose bit is set in ``mask``."""
    order = np.arange(len(conf))
    for k, limb in enumerate(limbs):
        if mask >> k & 1:
            order[limb[:, 0]], order[limb[:, 1]] = limb[:, 1], limb[:, 0]
    return conf.take(order)


def terminal_order(costs: list[np.ndarray], violates: list[np.ndarray],
                   limit: int) -> np.ndarray:
    """Terminal assignments in increasing unary cost, non-overlap violators last (Sec. 5.4).

    An assignment gives every terminal joint one of its sites. Assignments are ranked by
    the sum of their sites' unary costs; those with a site that violates the non-overlap
    constraint (its circle claims contour samples another, non-adjacent part holds) come
    after all the others, in the same order among themselves. Ties keep the sites' order.

    Args:
        costs: Per terminal joint, the unary cost of each of its sites, ``(S_t,)``.
        violates: Per terminal joint, whether each site violates non-overlap, ``(S_t,)``.
        limit: Most assignments returned (the enumeration's cap).

    Returns:
        Site indices, shape ``(n, T)`` int with ``n <= limit`` (``(1, 0)`` without
        terminals: the empty assignment).
    """
    if not costs:
        return np.zeros((1, 0), dtype=int)
    grids = np.meshgrid(*[np.arange(len(c)) for c in costs], indexing="ij")
    idx = np.stack([g.ravel() for g in grids], axis=1)
    if idx.size == 0:
        return np.zeros((0, len(costs)), dtype=int)
    total = sum(np.asarray(c, float)[idx[:, t]] for t, c in enumerate(costs))
    bad = np.zeros(len(idx), dtype=bool)
    for t, v in enumerate(violates):
        bad |= np.asarray(v, bool)[idx[:, t]]
    order = np.lexsort((np.arange(len(idx)), np.round(total, 9), bad))
    return idx[order[:limit]]


def first_consistent(order: np.ndarray, solve, min_coverage: float):
    """Solve the assignments in order, stopping at the first meeting the constraints.

    Args:
        order: Assignments, ``(n, T)`` (see :func:`terminal_order`).
        solve: ``solve(assignment) -> (overlaps, coverage, energy, result)``.
        min_coverage: Coverage the constraints require.

    Returns:
        ``(index of the chosen assignment, its result, solves made)``: the first with no
        overlap and enough coverage, else the best by (overlaps, -coverage, energy); index
        -1 and result None when ``order`` is empty.
    """
    best_key, best = None, (-1, None)
    for n, assignment in enumerate(order, start=1):
        overlaps, coverage, energy, result = solve(assignment)
        if overlaps == 0 and coverage >= min_coverage:
            return n - 1, result, n
        key = (overlaps, -coverage, energy)
        if best_key is None or key < best_key:
            best_key, best = key, (n - 1, result)
    return best[0], best[1], len(order)
