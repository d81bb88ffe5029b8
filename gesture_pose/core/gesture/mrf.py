"""Exact minimization of the tree-structured matching energy (Gesture3D Eq. 4).

The energy over joint labels ``x`` (one candidate per joint) is::

    E(x) = sum_j U_j(x_j) + sum_{j non-root} P_j(x_parent(j), x_j)
           + sum_{j with a triplet} T_j(x_grandparent(j), x_parent(j), x_j)

Triplet factors couple three consecutive joints, so dynamic programming runs over *edges*:
for each non-root joint ``j`` with parent ``p``, the table ``S_j[a, b]`` is the best energy
of ``j``'s subtree given ``x_p = a`` and ``x_j = b``::

    S_j[a, b] = P_j[a, b] + U_j[b] + sum_{c child of j} min_k (S_c[b, k] + T_c[a, b, k])

(``T_c`` is zero when ``c`` has no triplet). Every step is a vectorized numpy reduction;
the cost is ``O(sum K_p K_j K_c)`` over triplets.

:class:`MatchProblem` holds the data of ``E_match`` for one drawing and solving skeleton;
:func:`build_energy` turns candidate sets into the factor tables, and :func:`joint_energy`
evaluates the same energy for joints at arbitrary positions (consistency, refinement).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..exceptions import InputError
from .candidates import JointCandidates
from .costs import (
    CostParams,
    bone_costs,
    circle_alignment,
    direction_cost,
    pair_cost,
    pair_rows,
    rigid_cost,
    triplet_cost,
    unary_from_aligned,
)
from .preprocess import Drawing
from .types import SolvingSkeleton


@dataclass(frozen=True)
class TreeEnergy:
    """Factor tables of a tree-structured energy.

    Attributes:
        parent: Parent of each node, -1 for roots; parents have smaller indices, ``(J,)``.
        unary: Per node, ``(K_j,)``.
        pairwise: Per node, ``(K_parent, K_j)`` or None for roots.
        triplet: Per node, ``(K_grandparent, K_parent, K_j)`` or None.
        keys: Per node, a hashable key of everything its pairwise and triplet tables are
            computed from (:func:`build_energy`'s cache keys), or None: :func:`solve_tree`'s
            memo then hashes these small keys instead of the tables' bytes.
    """

    parent: np.ndarray
    unary: tuple[np.ndarray, ...]
    pairwise: tuple[np.ndarray | None, ...]
    triplet: tuple[np.ndarray | None, ...]
    keys: tuple | None = None

    def __post_init__(self) -> None:
        """Check that the tables fit the tree."""
        par = np.asarray(self.parent, dtype=int)
        if np.any(par >= np.arange(len(par))):
            raise InputError("Tree nodes must be ordered parents before children.")
        for j, p in enumerate(par):
            k = len(self.unary[j])
            if p >= 0:
                pw = self.pairwise[j]
                if pw is None or pw.shape != (len(self.unary[p]), k):
                    raise InputError(f"Pairwise table of node {j} has the wrong shape.")
                tr = self.triplet[j]
                if tr is not None:
                    g = par[p]
                    if g < 0 or tr.shape != (len(self.unary[g]), len(self.unary[p]), k):
                        raise InputError(f"Triplet table of node {j} has the wrong shape.")

    def evaluate(self, labels: np.ndarray) -> float:
        """Energy of one labelling ``(J,)``."""
        par = self.parent
        total = 0.0
        for j, x in enumerate(labels):
            total += self.unary[j][x]
            p = par[j]
            if p >= 0:
                total += self.pairwise[j][labels[p], x]
                if self.triplet[j] is not None:
                    total += self.triplet[j][labels[par[p]], labels[p], x]
        return float(total)


def solve_tree(energy: TreeEnergy, memo: dict | None = None) -> tuple[np.ndarray, float]:
    """Exact minimizer of a tree energy with pairwise and triplet factors.

    Args:
        energy: The factor tables.
        memo: Subtree tables of earlier solves, keyed by a hash of the subtree's factors:
            a re-solve with a few candidate sets changed (the terminal enumeration of
            Section 5.4) recomputes only the tables of the subtrees holding them.

    Returns:
        ``(labels (J,), minimum energy)``.
    """
    par = np.asarray(energy.parent, dtype=int)
    n = len(par)
    children = [np.flatnonzero(par == j) for j in range(n)]
    table: list[np.ndarray | None] = [None] * n
    arg: dict[int, np.ndarray] = {}
    sig: list[int] = [0] * n
    for j in range(n - 1, -1, -1):
        p = par[j]
        if memo is not None:
            parts = [energy.unary[j]]
            if energy.keys is None:
                parts += [energy.pairwise[j], energy.triplet[j]]
            sig[j] = hash((j, *(None if a is None else (a.shape, a.tobytes()) for a in parts),
                           None if energy.keys is None else energy.keys[j],
                           *(sig[c] for c in children[j])))
            hit = memo.get(sig[j])
            if hit is not None:
                table[j] = hit[0]
                arg.update(hit[1])
                continue
        kp = 1 if p < 0 else len(energy.unary[p])
        acc = np.broadcast_to(energy.unary[j][None, :], (kp, len(energy.unary[j]))).copy()
        if p >= 0:
            acc += energy.pairwise[j]
        for c in children[j]:
            s_c = table[c]
            tr = energy.triplet[c]
            if tr is None:
                best = np.argmin(s_c, axis=1)
                acc += s_c[np.arange(len(s_c)), best][None, :]
                arg[c] = np.broadcast_to(best[None, :], acc.shape)
            else:
                full = tr + s_c[None, :, :]
                best = np.argmin(full, axis=2)
                acc += np.take_along_axis(full, best[..., None], axis=2)[..., 0]
                arg[c] = best
        table[j] = acc
        if memo is not None:
            memo[sig[j]] = (acc, {c: arg[c] for c in children[j]})
    labels = -np.ones(n, dtype=int)
    total = 0.0
    for j in range(n):
        p = par[j]
        if p < 0:
            labels[j] = int(np.argmin(table[j][0]))
            total += float(table[j][0, labels[j]])
            continue
    for j in range(n):
        for c in children[j]:
            a = labels[par[j]] if par[j] >= 0 else 0
            labels[c] = int(arg[c][a, labels[j]])
    return labels, total


def min_marginals(energy: TreeEnergy) -> list[np.ndarray]:
    """Min-marginals of a tree energy with pairwise factors only (min-sum BP, two passes).

    ``M_j[b]`` is the lowest energy of any labelling with ``x_j = b`` (over the tree that
    holds ``j``; other trees of a forest add a constant). Upward messages are those of
    :func:`solve_tree`; the downward message to ``j`` is
    ``D_j[b] = min_a (P_j[a, b] + U_p[a] + D_p[a] + sum_{c != j child of p} m_c[a])``.

    Args:
        energy: Factor tables without triplets.

    Returns:
        ``M_j`` per node, ``(K_j,)`` each.

    Raises:
        InputError: The energy has triplet factors.
    """
    if any(t is not None for t in energy.triplet):
        raise InputError("Min-marginals are computed for pairwise trees only.")
    par = np.asarray(energy.parent, dtype=int)
    n = len(par)
    below = [np.array(u, float) for u in energy.unary]  # U_j + messages from children
    up: list[np.ndarray | None] = [None] * n
    for j in range(n - 1, -1, -1):
        p = par[j]
        if p >= 0:
            up[j] = np.min(energy.pairwise[j] + below[j][None, :], axis=1)
            below[p] = below[p] + up[j]
    down = [np.zeros(len(u)) for u in energy.unary]
    for j in range(n):
        p = par[j]
        if p >= 0:
            rest = below[p] + down[p] - up[j]
            down[j] = np.min(energy.pairwise[j] + rest[:, None], axis=0)
    return [below[j] + down[j] for j in range(n)]


@dataclass(frozen=True)
class MatchProblem:
    """Data of the 2D matching energy.

    Attributes:
        drawing: The preprocessed drawing.
        solving: The solving skeleton.
        link_length: Expected drawn length of each joint's link to its parent (bone length
            or rigid offset times the view scale), pixels, ``(J,)``; 0 for roots.
        rest_angle: Angle between a joint's link and its parent's link in the view at the
            current pose (in 3D at rest without ``view_angles``), radians, ``(J,)``; NaN
            where there is no triplet.
        terminal: Terminal joints, ``(J,)`` bool.
        params: Cost parameters.
        link_offset: Offset of each joint from its parent in the view at the current pose,
            pixels, ``(J, 2)`` (used by rigid links).
        blocked: Contour samples each solving bone may not claim, ``(m, N)`` bool, or None
            (set by the consistency step to resolve overlaps).
        reference: The joints in the view at the current pose, pixels, ``(J, 2)``.
        interior: Joints at the end of an interior bone (a clavicle inside the torso's
            outline, see :func:`interior_joints`), ``(J,)`` bool, or None.
        near_scale: Largest view scale each joint's link can have through a perspective
            camera over the character's scale (``pixels_per_unit`` of
            :func:`make_problem`), ``(J,)`` (1 for orthographic views), or None.
    """

    drawing: Drawing
    solving: SolvingSkeleton
    link_length: np.ndarray
    rest_angle: np.ndarray
    terminal: np.ndarray
    params: CostParams
    link_offset: np.ndarray
    blocked: np.ndarray | None = None
    reference: np.ndarray | None = None
    interior: np.ndarray | None = None
    near_scale: np.ndarray | None = None

    @property
    def rigid(self) -> np.ndarray:
        """Joints of reduced degrees of freedom, ``(J,)`` bool.

        They are placed from their parent by the offset in the view: rigid links (hip and
        shoulder heads) and interior bones' tails.
        """
        return rigid_joints(self.solving, self.interior)

    @property
    def scored(self) -> np.ndarray:
        """Joints whose unary term counts in ``E_match``, ``(J,)`` bool: all but the rigid.

        See :func:`joint_energy`.
        """
        return ~self.rigid

    def bone_blocked(self, j: int) -> np.ndarray | None:
        """Blocked samples of the bone linking joint ``j`` to its parent (None if free)."""
        b = self.solving.joint_link_bone[j]
        if self.blocked is None or b < 0:
            return None
        return self.blocked[b]

    def free_lengths(self, j: int) -> tuple[float, float] | None:
        """Drawn lengths of joint ``j``'s bone that cost nothing in ``Cl``, pixels.

        With ``view_lengths`` the range runs between the bone's length seen in the view at
        the current pose and its full length (:func:`~.costs.length_cost`); None without
        (Eq. 2 as in the paper).
        """
        if not self.params.view_lengths:
            return None
        full, seen = float(self.link_length[j]), float(np.linalg.norm(self.link_offset[j]))
        return min(full, seen), max(full, seen)

    def nearest_length(self, j: int) -> float | None:
        """Joint ``j``'s bone at the nearest depth it can come to, pixels, or None.

        Up to it a bone drawn too long pays ``Cl`` with the lenient sigma
        (``perspective_lengths``, :func:`~.costs.length_cost`); None for an orthographic
        view or without ``perspective_lengths``.
        """
        if not self.params.perspective_lengths or self.near_scale is None:
            return None
        return float(self.link_length[j] * self.near_scale[j])

    def has_triplet(self, j: int) -> bool:
        """Whether joint ``j`` closes a triplet (two consecutive bone links)."""
        return bool(np.isfinite(self.rest_angle[j]))


def rigid_joints(solving: SolvingSkeleton, interior: np.ndarray | None = None) -> np.ndarray:
    """Joints placed from their parent by the offset in the view, ``(J,)`` bool.

    Rigid links (hip and shoulder heads: unconnected heads of bones) and, when given, the
    tails of interior bones (:func:`interior_joints`).

    Args:
        solving: The solving skeleton.
        interior: Interior bones' tails, ``(J,)`` bool, or None.
    """
    out = (solving.joint_link_bone < 0) & (solving.joint_parent >= 0)
    return out if interior is None else out | interior


def rigid_descendants(parent: np.ndarray, rigid: np.ndarray, joint: int) -> np.ndarray:
    """``joint`` and the ``rigid`` joints reached from it down the tree, ``joint`` first.

    Args:
        parent: Parent of each joint, -1 for roots, ``(J,)``.
        rigid: Joints the walk may collect and pass through, ``(J,)`` bool.
        joint: Where the walk starts.

    Returns:
        Joint indices in the order of the walk (breadth first), ``(k,)`` int.
    """
    group = [int(joint)]
    k = 0
    while k < len(group):
        group += [int(c) for c in np.flatnonzero((parent == group[k]) & rigid)]
        k += 1
    return np.asarray(group, int)


def interior_joints(solving: SolvingSkeleton, radius: np.ndarray) -> np.ndarray:
    """Tails of interior bones: bones with no contour of their own (Section 6).

    A bone hanging from a rigid offset (a clavicle from the chest, through the shoulder's
    head) whose tail's circle overlaps the circle of the joint the offset starts from lies
    inside that part's outline: nothing in the drawing locates it, so it moves with the
    rigid neighbourhood (a thigh hanging from the pelvis ends far outside it and stays free).

    Args:
        solving: The solving skeleton.
        radius: Largest radius of each joint, world units, ``(J,)``.

    Returns:
        ``(J,)`` bool.
    """
    par, link, rest = solving.joint_parent, solving.joint_link_bone, solving.rest_joints
    out = np.zeros(solving.n_joints, bool)
    for j in range(solving.n_joints):
        p = par[j]
        if link[j] < 0 or p < 0 or link[p] >= 0 or par[p] < 0:
            continue
        g = par[p]
        out[j] = np.linalg.norm(rest[j] - rest[g]) < radius[g] + radius[j]
    return out


def make_problem(drawing: Drawing, solving: SolvingSkeleton, pixels_per_unit: float,
                 reference: np.ndarray, params: CostParams | None = None,
                 near_scale: np.ndarray | None = None) -> MatchProblem:
    """Expected lengths and bind angles of the joint tree, scaled to the drawing.

    Args:
        drawing: The preprocessed drawing.
        solving: The solving skeleton.
        pixels_per_unit: View scale at the character.
        reference: Joints in the view at the current pose, pixels, ``(J, 2)``.
        params: Cost parameters.
        near_scale: Largest view scale of each joint's link over ``pixels_per_unit``,
            ``(J,)`` (see :func:`~.embedding.near_scales`), or None.
    """
    params = params or CostParams()
    par = solving.joint_parent
    rest = solving.rest_joints
    n = solving.n_joints
    length = np.zeros(n)
    has = par >= 0
    length[has] = np.linalg.norm(rest[has] - rest[par[has]], axis=1) * pixels_per_unit
    angle = np.full(n, np.nan)
    for j in np.flatnonzero(has):
        p = par[j]
        if solving.joint_link_bone[j] >= 0 and par[p] >= 0 and solving.joint_link_bone[p] >= 0:
            frame = reference if params.view_angles else rest
            d1, d2 = frame[p] - frame[par[p]], frame[j] - frame[p]
            c = d1 @ d2 / max(np.linalg.norm(d1) * np.linalg.norm(d2), 1e-12)
            angle[j] = float(np.arccos(np.clip(c, -1.0, 1.0)))
    offset = np.zeros((n, 2))
    offset[has] = reference[has] - reference[par[has]]
    return MatchProblem(drawing, solving, length, angle, solving.terminal, params, offset,
                        reference=np.asarray(reference, float),
                        near_scale=None if near_scale is None else np.asarray(near_scale,
                                                                                float))


def root_reach(solving: SolvingSkeleton) -> np.ndarray:
    """Distance of each joint from the root along the skeleton at rest, world units, ``(J,)``.

    The sum of the links (bones and rigid offsets) on the way from the root: however the
    character is posed, the joint stays within this distance of the root. Joints are
    numbered parents first (:func:`~.solving.build_solving_skeleton`).
    """
    par, rest = solving.joint_parent, solving.rest_joints
    reach = np.zeros(solving.n_joints)
    for j in np.flatnonzero(par >= 0):
        reach[j] = reach[par[j]] + float(np.linalg.norm(rest[j] - rest[par[j]]))
    return reach


def link_table(problem: MatchProblem, j: int, a: JointCandidates,
               b: JointCandidates, stations: int = 8) -> np.ndarray:
    """Pairwise table between parent candidates ``a`` and joint ``j``'s candidates ``b``."""
    return link_cost(problem, j, a.positions, a.radii, a.group, a.side, b.positions, b.radii,
                     b.group, b.side, stations)


def link_cost(problem: MatchProblem, j: int, pa: np.ndarray, ra: np.ndarray, ga: np.ndarray,
              sa: np.ndarray, pb: np.ndarray, rb: np.ndarray, gb: np.ndarray, sb: np.ndarray,
              stations: int = 8) -> np.ndarray:
    """Cost of joint ``j``'s link for parent placements ``a`` and placements ``b``, ``(Ka, Kb)``.

    A rigid offset (an unconnected head) pays :func:`~.costs.rigid_cost`; a bone pays the
    direction prior and ``E(i, j)`` (:func:`~.costs.pair_cost`).

    Args:
        problem: The matching problem.
        j: The joint whose link to its parent is costed.
        pa: Parent positions, pixels, ``(Ka, 2)``.
        ra: Their radii, pixels, ``(Ka,)`` or ``(1,)``.
        ga: Their contour groups (-1 for grid), ``(Ka,)`` or ``(1,)``.
        sa: Their contour sides, ``(Ka,)`` or ``(1,)``.
        pb: The joint's positions, pixels, ``(Kb, 2)``.
        rb: Their radii, pixels, ``(Kb,)`` or ``(1,)``.
        gb: Their contour groups, ``(Kb,)`` or ``(1,)``.
        sb: Their contour sides, ``(Kb,)`` or ``(1,)``.
        stations: Outline samples per bone.

    Returns:
        Costs, ``(Ka, Kb)``.
    """
    if problem.solving.joint_link_bone[j] < 0:
        return rigid_cost(problem.drawing, pa, pb, problem.link_offset[j], problem.params,
                          problem.link_length[j])
    prior = direction_cost(pa, pb, problem.link_offset[j], problem.params)
    return prior + pair_cost(problem.drawing, pa, ra, ga, sa, pb, rb, gb, sb,
                             problem.link_length[j], problem.params, stations=stations,
                             blocked=problem.bone_blocked(j), free=problem.free_lengths(j),
                             nearest=problem.nearest_length(j))


def link_costs(problem: MatchProblem, links: list[tuple], stations: int = 8
               ) -> list[np.ndarray]:
    """:func:`link_cost` of several links, their pair costs evaluated in one call.

    Small tables (the refinement's trials, one configuration's energy) cost mostly the
    overhead of numpy's calls: their bones' rows go through one
    :func:`~.costs.bone_costs`, which gives the same values as separate
    :func:`~.costs.pair_cost` tables.

    Args:
        problem: The matching problem.
        links: Per link the arguments of :func:`link_cost` after ``problem``:
            ``(j, pa, ra, ga, sa, pb, rb, gb, sb)``.
        stations: Outline samples per bone.

    Returns:
        Per link its table, ``(Ka, Kb)``.
    """
    out: list = [None] * len(links)
    bones = []
    for i, (j, pa, ra, ga, sa, pb, rb, gb, sb) in enumerate(links):
        if problem.solving.joint_link_bone[j] < 0:
            out[i] = rigid_cost(problem.drawing, pa, pb, problem.link_offset[j],
                                problem.params, problem.link_length[j])
            continue
        out[i] = direction_cost(pa, pb, problem.link_offset[j], problem.params)
        bones.append((i, j, pair_rows(pa, ra, ga, sa, pb, rb, gb, sb)))
    if not bones:
        return out
    counts = [len(rows[0]) for _, _, rows in bones]
    columns = [np.concatenate([rows[k] for _, _, rows in bones]) for k in range(8)]
    blocked = None
    if any(problem.bone_blocked(j) is not None for _, j, _ in bones):
        none = np.zeros(problem.drawing.n_samples, bool)
        blocked = np.repeat(np.stack([none if problem.bone_blocked(j) is None
                                      else problem.bone_blocked(j) for _, j, _ in bones]),
                            counts, axis=0)
    lengths = [problem.link_length[j] for _, j, _ in bones]
    free = [problem.free_lengths(j) for _, j, _ in bones]
    nearest = [problem.nearest_length(j) for _, j, _ in bones]
    costs = bone_costs(problem.drawing, *columns, np.repeat(lengths, counts), problem.params,
                       stations, blocked,
                       np.repeat([(x, x) if f is None else f
                                  for x, f in zip(lengths, free, strict=True)], counts, axis=0),
                       np.repeat([np.nan if x is None else x for x in nearest], counts))
    start = 0
    for (i, _, _), n in zip(bones, counts, strict=True):
        out[i] = out[i] + costs[start:start + n].reshape(out[i].shape)
        start += n
    return out


def triplet_table(problem: MatchProblem, j: int, g: JointCandidates, p: JointCandidates,
                  c: JointCandidates) -> np.ndarray:
    """Naturalness table of grandparent, parent and joint ``j`` candidates."""
    gg, gp, gc = g.group[:, None, None], p.group[None, :, None], c.group[None, None, :]
    shared = (gg == gp) & (gp == gc) & (gc >= 0)
    return triplet_cost(g.positions, p.positions, c.positions, shared,
                        float(problem.rest_angle[j]), problem.params)


def build_energy(problem: MatchProblem, cands: list[JointCandidates],
                 triplets: bool = True, stations: int = 8,
                 cache: dict | None = None) -> TreeEnergy:
    """Factor tables of ``E_match`` over the candidate sets (Eq. 4).

    Args:
        problem: The matching problem.
        cands: Candidates of every joint.
        triplets: Include the naturalness triplets (the coarse pass leaves them out).
        stations: Outline samples per bone in the conformity term.
        cache: Pairwise and triplet tables of earlier calls, keyed by their inputs (the
            consistency step re-solves with a few bones changed).
    """
    par = problem.solving.joint_parent
    unary = tuple(c.unary if problem.bone_blocked(j) is None else
                  np.maximum(c.unary, unary_from_aligned(c.aligned, bool(problem.terminal[j]),
                                                         problem.params, problem.bone_blocked(j)))
                  for j, c in enumerate(cands))
    pair, trip, keys = [], [], []
    for j in range(problem.solving.n_joints):
        p = par[j]
        pair_key = trip_key = None
        if p < 0:
            pair.append(None)
        else:
            blk = problem.bone_blocked(j)
            # Everything the link cost reads: positions, radii, contour groups and sides.
            key = (j, stations, *(getattr(cands[k], f).tobytes() for k in (p, j)
                                  for f in ("positions", "radii", "group", "side")),
                   None if blk is None else np.packbits(blk).tobytes(), problem.params)
            table = None if cache is None else cache.get(key)
            if table is None:
                table = link_table(problem, j, cands[p], cands[j], stations)
                if cache is not None:
                    cache[key] = table
            pair.append(table)
            pair_key = key
        tr = None
        if triplets and p >= 0 and problem.has_triplet(j):
            g = par[p]
            key = ("triplet", j, *(x.tobytes() for k in (g, p, j)
                                   for x in (cands[k].positions, cands[k].group)),
                   problem.params)
            tr = None if cache is None else cache.get(key)
            if tr is None:
                tr = triplet_table(problem, j, cands[g], cands[p], cands[j])
                if cache is not None:
                    cache[key] = tr
            trip_key = key
        trip.append(tr)
        keys.append((pair_key, trip_key))
    return TreeEnergy(par, unary, tuple(pair), tuple(trip), tuple(keys))


def configuration(cands: list[JointCandidates], labels: np.ndarray) -> JointCandidates:
    """One candidate per joint as a single candidate set (joint order), ``K = J``."""
    picks = [c.take(np.array([k])) for c, k in zip(cands, labels, strict=True)]
    return JointCandidates.concat(picks)


def joint_energy(problem: MatchProblem, conf: JointCandidates,
                 joints: np.ndarray | None = None) -> tuple[float, dict]:
    """``E_match`` of the factors touching ``joints`` (all factors when None).

    Rigid joints (:attr:`MatchProblem.rigid`) have no unary term: they are placed by
    their parent and the offset, not by the contours, as in the search, whose rigid
    candidates cost nothing (``embedding._with_rigid``). The refinement scores them the
    same way; when it counted their circles, it moved a torso's rigid group to make
    joints inside the body (hip and shoulder heads, a clavicle's tail) touch some line,
    which the search had not asked for. One exception, measured and kept: in the search's
    re-solves after blocking (:func:`build_energy` with ``blocked``), a rigid joint at the
    end of a bone (a clavicle's tail) pays the unary of its circle's unblocked samples;
    without it 48 drawings went from 3.62 / 8.84 to 3.98 / 9.68 %h (mean / p90). With
    ``rigid_search`` off the search also keeps a rigid joint's own contour candidates,
    whose unaries count there.

    Args:
        problem: The matching problem.
        conf: One placement per joint (see :func:`configuration`).
        joints: Joints whose factors are summed, or None for the whole energy.

    Returns:
        ``(energy, terms)`` with terms ``"unary"``, ``"pairwise"``, ``"triplet"``.
    """
    s = problem.solving
    par = s.joint_parent
    n = s.n_joints
    sel = np.ones(n, bool) if joints is None else np.isin(np.arange(n), joints)
    terms = {"unary": 0.0, "pairwise": 0.0, "triplet": 0.0}
    scored = np.flatnonzero(sel & problem.scored)
    # Every circle in one call (row by row the same values as one circle per call).
    aligned = circle_alignment(problem.drawing, conf.positions[scored], conf.radii[scored],
                               problem.params)
    for row, j in enumerate(scored):
        cost = unary_from_aligned(aligned[row:row + 1], bool(problem.terminal[j]),
                                  problem.params, problem.bone_blocked(j))
        terms["unary"] += float(cost[0])
    one = [conf.take(np.array([j])) for j in range(n)]
    linked = [j for j in range(n) if par[j] >= 0 and (sel[j] or sel[par[j]])]
    tables = dict(zip(linked, link_costs(problem, [
        (j, *(getattr(one[k], f) for k in (par[j], j)
              for f in ("positions", "radii", "group", "side"))) for j in linked]),
        strict=True))
    for j in range(n):
        p = par[j]
        if p < 0:
            continue
        g = par[p]
        if sel[j] or sel[p]:
            terms["pairwise"] += float(tables[j][0, 0])
        if problem.has_triplet(j) and (sel[j] or sel[p] or sel[g]):
            terms["triplet"] += float(triplet_table(problem, j, one[g], one[p], one[j])[0, 0, 0])
    return sum(terms.values()), terms
