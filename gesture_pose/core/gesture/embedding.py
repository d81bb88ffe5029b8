"""Top level of the 2D skeletal embedding (Gesture3D Sections 4-6).

:func:`fit_drawing` runs the whole pipeline: preprocessing, solving skeleton, joint radii,
candidates, the exact tree MRF (twice: a coarse occlusion grid first, then a fine grid at
epsilon around the first answer), global consistency with terminal enumeration and
symmetric permutations, and the 2D refinement.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..camera import Camera
from ..exceptions import InputError
from ..skeleton import Pose, Skeleton
from ..stroke import Stroke
from .candidates import JointCandidates, best, consolidate, contour_candidates, grid_candidates
from .consistency import (
    assign_contours,
    block_overlaps,
    first_consistent,
    permute,
    symmetric_limbs,
    terminal_order,
    twist_score,
)
from .costs import CostParams, unary_cost
from .depth.energies import view_frame
from .depth.start import REST_UP, front_direction, half_turn, rig_up, view_roll
from .mrf import (
    MatchProblem,
    build_energy,
    configuration,
    interior_joints,
    joint_energy,
    make_problem,
    min_marginals,
    root_reach,
    solve_tree,
)
from .preprocess import PreprocessParams, preprocess
from .radii import discrete_radii, joint_radii
from .refine import RefineParams, limb_chains, refine, with_positions
from .solving import solving_skeleton
from .types import Embedding2D, SolvingSkeleton


@dataclass(frozen=True)
class GestureParams:
    """Parameters of the 2D embedding (the paper's values are the defaults).

    Attributes:
        preprocess: Resampling and Gestalt-bridge parameters.
        costs: Cost parameters.
        refine: Refinement parameters.
        min_bone_epsilons: Shortest solving bone, in resampling steps.
        max_candidates: Contour candidates per joint in the fine pass.
        pool_candidates: Contour candidates per joint kept after consolidation.
        coarse_candidates: Contour candidates per joint in the coarse pass.
        coarse_cell: Consolidation cell of the coarse pass, epsilons.
        coarse_stations: Outline samples per bone in the coarse pass's conformity term.
        coarse_grid: Grid points of the coarse occlusion grid.
        fine_reach: Radius around the coarse answer searched by the fine pass, epsilons.
        fine_grid_reach: Half-width of the fine grid around the coarse answer, epsilons.
        alternatives: Next-best coarse placements per joint (by min-marginal) added to the
            fine pass with their neighbourhoods (0: the fine pass searches only around the
            coarse answer).
        alternative_spread: Least distance between those placements, epsilons.
        alternative_neighbours: Contour candidates kept around each of them.
        rigid_search: Rigidly attached joints (hips, shoulders) are searched only at their
            parent's candidates moved by the offset (Section 6's reduced degrees of
            freedom during the search, not only in the refinement).
        rigid_turns: Extra turns of those offsets searched, degrees.
        max_radii: Most candidate radii per joint.
        min_coverage: Coverage the consistency step requires.
        overlap_penalty: Penalty per overlapping pair of bones or joints.
        max_terminal_rounds: Overlap-resolving re-solves of the consistency step.
        extra_terminal_rounds: Re-solves continuing them when they end with overlaps
            left, a second seed for the rest of the search (ours, see
            :func:`_blocking_rounds`); 0 stops at ``max_terminal_rounds``.
        reseed_overlaps: Overlapping pairs the final result must keep before the search is
            finished again from the solution after those extra re-solves.
        resolve_rate: A blocking re-solve that explains more of the drawing may cost at
            most ``symmetric_tolerance`` per ``coverage_gain`` more energy (the rate of
            :func:`_accepts`; ours, see :func:`_resolves`); False: any energy once it
            explains ``coverage_gain`` more. On by default, with
            ``CostParams.oriented_conformity``, whose costs made the 2D bench's quadruped
            with its tail up take such a re-solve (docs/gesture.md).
        terminal_sites: Sites per terminal joint in the paper's enumeration of terminal
            assignments (Section 5.4).
        coverage_moves: Rounds of moving limb ends onto unexplained contours in place of
            that enumeration (ours, see :func:`_coverage_moves`); 0 enumerates as the
            paper does.
        coverage_sites: Sites tried per limb end and round in those moves.
        max_terminal_assignments: Most assignments solved by that enumeration (its cap).
        coverage_gain: Coverage gain for which an enumerated solution that still misses
            the constraints replaces the current one.
        symmetric_tolerance: Energy slack within which symmetric permutations compete.
        min_drawing_ratio: Smallest drawing diagonal relative to the character's.
        bind_start: Refine also from the character's current pose seen in the view (ours,
            see :func:`_refine_both`).
        limb_resolves: Sweeps re-solving each limb with the rest of the solution held
            (ours, see :func:`_limb_resolves`); 0 skips them.
        limb_candidates: Contour placements per joint in those re-solves.
        limb_grid: Grid points across the reach of a joint in those re-solves (their
            occlusion candidates).
        refined_resolves: Sweeps of the limb re-solves again after the refinement, each
            kept re-solve refined once more (ours, see :func:`_resolve_refined`); 0 skips
            them. One by default, with the foreshortened-bone costs
            (``CostParams.foreshortening``, ``CostParams.exposed_conformity``).
    """

    preprocess: PreprocessParams = field(default_factory=PreprocessParams)
    costs: CostParams = field(default_factory=CostParams)
    refine: RefineParams = field(default_factory=RefineParams)
    min_bone_epsilons: float = 2.0
    max_candidates: int = 40
    pool_candidates: int = 400
    coarse_candidates: int = 120
    coarse_cell: float = 1.5
    coarse_stations: int = 4
    coarse_grid: int = 40
    fine_reach: float = 5.0
    fine_grid_reach: float = 2.0
    alternatives: int = 0
    alternative_spread: float = 3.0
    alternative_neighbours: int = 4
    rigid_search: bool = True
    rigid_turns: tuple[float, ...] = ()
    max_radii: int = 3
    min_coverage: float = 0.85
    overlap_penalty: float = 10.0
    max_terminal_rounds: int = 3
    extra_terminal_rounds: int = 3
    reseed_overlaps: int = 2
    resolve_rate: bool = True
    terminal_sites: int = 4
    coverage_moves: int = 3
    coverage_sites: int = 2
    max_terminal_assignments: int = 8
    coverage_gain: float = 0.02
    symmetric_tolerance: float = 0.5
    min_drawing_ratio: float = 0.25
    bind_start: bool = True
    limb_resolves: int = 1
    limb_candidates: int = 32
    limb_grid: float = 2.5
    refined_resolves: int = 1


def posed_joints(solving: SolvingSkeleton, skeleton: Skeleton, pose: Pose) -> np.ndarray:
    """World positions of the joints in ``pose``, shape ``(J, 3)``."""
    state = skeleton.forward(pose)
    out = np.empty((solving.n_joints, 3))
    out[solving.tail_joint] = state.tails[solving.bones]
    heads = solving.bones
    out[solving.head_joint] = state.heads[heads]
    return out


def near_scales(camera: Camera, solving: SolvingSkeleton, world: np.ndarray,
                pixels_per_unit: float) -> np.ndarray:
    """Largest view scale of each joint's link over the character's scale, ``(J,)``.

    A joint stays within its distance along the skeleton from its root
    (:func:`~.mrf.root_reach`), so its link can come no nearer than the root's depth less
    that distance (and no nearer than half the character's depth): through a perspective
    camera it can look that much longer. 1 for orthographic cameras.

    Args:
        camera: The view.
        solving: The solving skeleton.
        world: Its joints at the current pose, world units, ``(J, 3)``.
        pixels_per_unit: The character's view scale (at its mean depth).
    """
    depth = camera.depth(world)
    par = solving.joint_parent
    top = np.arange(len(par))  # each joint's root (a prop can be a separate tree)
    for j in np.flatnonzero(par >= 0):  # parents are numbered first
        top[j] = top[par[j]]
    nearest = np.maximum(depth[top] - root_reach(solving), 0.5 * float(np.mean(depth)))
    scale = np.array([camera.pixels_per_unit(float(z)) for z in nearest])
    return np.maximum(scale / pixels_per_unit, 1.0)


def _near(cands: JointCandidates, centre: np.ndarray, reach: float, count: int
          ) -> JointCandidates:
    """The ``count`` cheapest candidates within ``reach`` of ``centre``.

    Equal costs (many placements fit the contours perfectly) are broken by the distance to
    ``centre``, so the kept set is the neighbourhood of the coarse answer rather than
    whichever contour samples come first.
    """
    dist = np.linalg.norm(cands.positions - centre, axis=1)
    sel = np.flatnonzero(dist <= reach)
    order = sel[np.lexsort((dist[sel], np.round(cands.unary[sel], 6)))][:count]
    return cands.take(np.sort(order))


def _alternatives(coarse: JointCandidates, marginal: np.ndarray, contour: JointCandidates,
                  answer: np.ndarray, eps: float, params) -> list[JointCandidates]:
    """A joint's next-best coarse placements and their neighbourhoods, for the fine pass.

    The coarse pass has no naturalness triplets, so its single answer can fold a limb onto
    one contour while the right placement comes a close second. Its min-marginals rank
    every coarse placement by the best whole-skeleton labelling through it; the
    ``alternatives`` best placements at least ``alternative_spread`` epsilons apart (and
    from the answer, which the fine pass searches anyway) are kept with up to
    ``alternative_neighbours`` contour candidates within a coarse cell of each, so the
    fine pass (with triplets) chooses among them exactly.

    Args:
        coarse: The joint's coarse candidates, ``K``.
        marginal: Their min-marginals, ``(K,)``.
        contour: The joint's contour candidates (the pool).
        answer: The coarse answer, pixels, ``(2,)``.
        eps: Resampling step, pixels.
        params: Embedding parameters.

    Returns:
        Candidate sets to add to the fine pass.
    """
    spread = params.alternative_spread * eps
    kept = [np.asarray(answer, float)]
    out = []
    for k in np.argsort(marginal, kind="stable"):
        if len(out) >= params.alternatives:
            break
        pos = coarse.positions[k]
        if min(np.linalg.norm(pos - q) for q in kept) < spread:
            continue
        kept.append(pos)
        near = _near(contour, pos, params.coarse_cell * eps, params.alternative_neighbours)
        out.append(JointCandidates.concat([coarse.take(np.array([k])), near]))
    return out


def _unique(cands: JointCandidates) -> JointCandidates:
    """The candidates with distinct (position, radius), first occurrence kept."""
    key = np.c_[cands.positions, cands.radii]
    _, first = np.unique(key, axis=0, return_index=True)
    return cands.take(np.sort(first))


def _two_pass(problem, contour: list[JointCandidates], mid_r: np.ndarray, params,
              cache: dict | None = None,
              restrict: dict[int, np.ndarray] | None = None
              ) -> tuple[list[JointCandidates], np.ndarray, float]:
    """Coarse DP (many candidates, pairwise factors) then fine DP with triplets.

    Args:
        problem: The matching problem.
        contour: Contour candidates of every joint.
        mid_r: Middle radius of every joint (for grid candidates), pixels, ``(J,)``.
        params: Embedding parameters.
        cache: Pairwise tables of earlier solves.
        restrict: Joints forced near a position (terminal enumeration): only their contour
            candidates within 1.5 epsilon of it, no grid.

    Returns:
        ``(fine candidate sets, labels, energy)``.
    """
    d = problem.drawing
    eps = d.epsilon
    restrict = restrict or {}
    contour = [_near(c, restrict[j], 1.5 * eps, len(c)) if j in restrict else c
               for j, c in enumerate(contour)]
    area = float(np.prod(np.maximum(d.bbox[1] - d.bbox[0], eps)))
    spacing = max(eps, np.sqrt(area / params.coarse_grid))
    coarse = []
    for j, c in enumerate(contour):
        pool = best(consolidate(c, params.coarse_cell * eps), params.coarse_candidates)
        grid = grid_candidates(d, spacing, mid_r[j], params=params.costs)
        grid = grid.take(np.zeros(0, int)) if j in restrict and len(pool) else grid
        coarse.append(JointCandidates.concat([pool, grid]))
    coarse = _with_rigid(problem, coarse, params.rigid_turns, params.rigid_search)
    # Coarse candidates are up to a cell off: widen the length tolerances accordingly.
    slack = params.coarse_cell * eps / d.diagonal
    loose = replace(problem.params,
                    sigma_length=float(np.hypot(problem.params.sigma_length, 2 * slack)),
                    rigid_sigma=float(np.hypot(problem.params.rigid_sigma, 2 * slack)))
    coarse_energy = build_energy(replace(problem, params=loose), coarse, triplets=False,
                                 stations=params.coarse_stations, cache=cache)
    labels, _ = solve_tree(coarse_energy)
    first = configuration(coarse, labels)
    marginals = min_marginals(coarse_energy) if params.alternatives else None
    reach = params.fine_grid_reach * eps
    fine = []
    for j, c in enumerate(contour):
        near = _near(c, first.positions[j], params.fine_reach * eps, params.max_candidates)
        grid = grid_candidates(d, eps, mid_r[j], first.positions[j], reach, params.costs)
        grid = grid.take(np.zeros(0, int)) if j in restrict and len(near) else grid
        parts = [near, grid]
        if marginals is not None and j not in restrict:
            parts += _alternatives(coarse[j], marginals[j], c, first.positions[j], eps, params)
        fine.append(_unique(JointCandidates.concat(parts)))
    fine = _with_rigid(problem, fine, params.rigid_turns, params.rigid_search)
    labels, energy = solve_tree(build_energy(problem, fine, cache=cache))
    return fine, labels, energy


def _enumerate_terminals(problem, base, contour: list[JointCandidates],
                         fine: list[JointCandidates], conf: JointCandidates, params,
                         cache: dict) -> tuple[JointCandidates, int]:
    """Section 5.4's enumeration of terminal assignments, when the solution breaks a constraint.

    The terminals are the limb ends (:attr:`~.types.SolvingSkeleton.limb_ends`: hands and
    feet too when fingers and toes continue them), roots excepted. With ``coverage_moves``
    (ours, the default) they are moved onto the contours the solution leaves unexplained
    (:func:`_coverage_moves`). Without, as in the paper: each terminal's sites are its
    contour candidates consolidated at 3 epsilon within reach of its parent as placed
    now, the ``terminal_sites`` cheapest. Assignments (one site per terminal) are solved in
    increasing unary cost, those whose sites claim contour samples held by a non-adjacent
    part last (:func:`terminal_order`), up to ``max_terminal_assignments``, stopping at the
    first meeting non-overlap and coverage (:func:`first_consistent`). A solve is the fine
    DP over the candidate sets of the current solution with the terminals restricted to
    their sites; subtrees without a terminal keep their DP tables (``solve_tree``'s memo).
    The best solve replaces the current solution by :func:`_accepts` (energies without
    the samples blocking gave up, as :func:`_resolves` compares them).

    Returns:
        ``(configuration, number of solves)``.
    """
    d = problem.drawing
    eps = d.epsilon
    assign = assign_contours(base, conf)
    # Roots stay: a chain's first joint offered its far end's cap would reverse the chain.
    terminals = np.flatnonzero(problem.solving.limb_ends & (problem.solving.joint_parent >= 0))
    if (not assign.overlaps and assign.coverage >= params.min_coverage) or terminals.size == 0:
        return conf, 0
    if params.coverage_moves:
        return _coverage_moves(problem, base, terminals, contour, fine, conf, assign, params,
                               cache)
    costs, violates, sites = [], [], []
    for j in terminals:
        cand = _within_reach(problem, consolidate(contour[j], 3 * eps), conf, int(j))
        cand = cand.take(np.argsort(cand.unary, kind="stable")[:params.terminal_sites])
        held = _held_by_others(base, assign, int(j), d.n_samples)
        claims = [np.unique(a[a >= 0]) for a in cand.aligned]
        violates.append(np.array([held[c].sum() >= 2 for c in claims], dtype=bool))
        costs.append(cand.unary)
        sites.append(cand)
    order = terminal_order(costs, violates, params.max_terminal_assignments)
    memo: dict = {}

    def solve(assignment: np.ndarray):
        placed = {int(j): sites[t].take(np.array([assignment[t]]))
                  for t, j in enumerate(terminals)}
        new, e = _solve_placed(problem, fine, contour, placed, params, cache, memo)
        got = assign_contours(base, new)
        return len(got.overlaps), got.coverage, e, new

    index, result, count = first_consistent(order, solve, params.min_coverage)
    if result is None:
        return conf, count
    got = assign_contours(base, result)
    old = (assign, joint_energy(base, conf)[0])
    return (result if _accepts((got, joint_energy(base, result)[0]), old, params)
            else conf), count


def _within_reach(problem, cand: JointCandidates, conf: JointCandidates, j: int
                  ) -> JointCandidates:
    """Candidates of joint ``j`` (not a root) within reach of its parent as placed.

    Reach: 1.2 link lengths and two steps.
    """
    p = problem.solving.joint_parent[j]
    reach = 1.2 * problem.link_length[j] + 2 * problem.drawing.epsilon
    return cand.take(np.flatnonzero(
        np.linalg.norm(cand.positions - conf.positions[p], axis=1) <= reach))


def _solve_placed(problem, fine: list[JointCandidates], contour: list[JointCandidates],
                  placed: dict[int, JointCandidates], params, cache: dict, memo: dict
                  ) -> tuple[JointCandidates, float]:
    """The fine DP with joints restricted to a site each: ``(configuration, energy)``.

    A placed joint keeps its site and its contour candidates within 1.5 epsilon of it;
    every other joint keeps its fine candidate set.
    """
    eps = problem.drawing.epsilon
    sets = list(fine)
    for j, site in placed.items():
        near = _near(contour[j], site.positions[0], 1.5 * eps, params.max_candidates)
        sets[j] = _unique(JointCandidates.concat([site, near]))
    sets = _with_rigid(problem, sets, params.rigid_turns, params.rigid_search)
    labels, e = solve_tree(build_energy(problem, sets, cache=cache), memo)
    return configuration(sets, labels), e


def _accepts(new: tuple, old: tuple, params) -> bool:
    """Whether an enumerated solution replaces the current one (Section 5.4).

    Both are ``(Assignment, E_match)``. It does when it meets the constraints (no overlap,
    ``min_coverage``); when it does not (traced drawings rarely reach 85% coverage: face
    and hand details), coverage is traded for energy at one rate, ``symmetric_tolerance``
    per ``coverage_gain`` (0.25 of E_match per percent of the drawing; ours): it replaces
    the current one with a lower energy counting ``overlap_penalty`` per overlap and that
    rate per unit of coverage lost (at no more than ``coverage_gain`` less coverage), or
    with as many overlaps and more coverage for at most that rate times the gain in
    energy, and never more than ``symmetric_tolerance`` (coverage bought with a much worse
    fit is not kept; measured on crouching figures, where it moved the head and the arms).
    A rate rather than a threshold: a foot put back on its drawn shoe for 0.6% more
    coverage at 0.007 more energy is kept (the test view's step), and losing that coverage
    again for free is not.
    """
    (got, e_new), (was, e_old) = new, old
    if not got.overlaps and got.coverage >= params.min_coverage:
        return True
    pen = params.overlap_penalty
    rate = params.symmetric_tolerance / params.coverage_gain
    gain = got.coverage - was.coverage
    fewer = (e_new + pen * len(got.overlaps) + rate * max(-gain, 0.0)
             < e_old + pen * len(was.overlaps) and gain >= -params.coverage_gain)
    covers = (len(got.overlaps) == len(was.overlaps) and gain > 0.0
              and e_new <= e_old + min(params.symmetric_tolerance, rate * gain))
    return fewer or covers


def _seed_accepts(new: tuple, old: tuple, params) -> bool:
    """Whether the result from the extra blocking rounds replaces the first (ours).

    Both are ``(Assignment, E_match)`` of final results. It must have no more
    overlapping pairs and a lower ``E_match`` net of coverage at the consistency step's
    rate (``symmetric_tolerance`` per ``coverage_gain``, as :func:`_accepts`), the
    overlap penalty not counted, even when it meets Section 5.4's constraints: the extra
    rounds exist to resolve overlaps, and a limb moved off its drawn contour onto another
    part's line resolves them too (the 2D bench's step seen at 3/4, legs that overlap in
    the view: 4 pairs fewer, coverage 0.819 -> 0.858, for 2.9 more ``E_match`` and its
    front leg 72% of the height off), which the penalty of 10 per pair would pay for.
    """
    (got, e_new), (was, e_old) = new, old
    rate = params.symmetric_tolerance / params.coverage_gain
    return (len(got.overlaps) <= len(was.overlaps)
            and e_new - rate * got.coverage < e_old - rate * was.coverage)


def _limb_chains(problem) -> list[np.ndarray]:
    """The longest free chains of :func:`~.refine.limb_chains` (none inside another)."""
    chains = limb_chains(problem, 3)
    return [c for c in chains
            if not any(len(o) > len(c) and set(c) <= set(o) for o in chains)]


def _limb_sets(problem, contour: list[JointCandidates], mid_r: np.ndarray,
               conf: JointCandidates, chain: np.ndarray, params) -> list[JointCandidates]:
    """Candidate sets with ``chain`` free and every other joint at its placement.

    A chain joint gets its current placement, its contour placements within
    ``fine_reach`` epsilons of it (consolidated at the coarse cell, up to half of
    ``limb_candidates``), the cheapest contour placement of each cell of half the grid's
    spacing (up to ``limb_candidates``: spread over the reach, not crowded where many
    placements fit equally well; the cheapest by distance from the chain's parent left a
    hand's cap out for the elbow's outer arc) and a grid of ``limb_grid`` points across
    the reach (occlusion candidates), all within reach of the chain's parent (its links'
    lengths, 1.2 times, and two steps, along the chain). Every rigid joint of the skeleton
    (a hip or shoulder head, a clavicle's tail) may stay where it is or move to its offset
    from its parent's candidates (a clavicle's tail from its head's offset placement, not
    from the head as placed): the search's rigid offsets are soft, and with only the
    offsets (the first version) the re-solve could not keep the solution as it was.
    """
    eps = problem.drawing.epsilon
    par = problem.solving.joint_parent
    top = int(chain[0])
    anchor = conf.positions[par[top]]
    sets = [conf.take(np.array([j])) for j in range(problem.solving.n_joints)]
    reaches = {int(par[top]): 2 * eps}
    cell = params.coarse_cell * eps
    for j in chain:
        reach = reaches[int(par[j])] + 1.2 * problem.link_length[j]
        reaches[int(j)] = reach
        spacing = max(2 * cell, reach / params.limb_grid)
        pool = contour[j].take(np.flatnonzero(
            np.linalg.norm(contour[j].positions - anchor, axis=1) <= reach))
        near = best(consolidate(pool, max(cell, 0.5 * spacing)), params.limb_candidates)
        here = _near(consolidate(pool, cell), conf.positions[j], params.fine_reach * eps,
                     params.limb_candidates // 2)
        grid = grid_candidates(problem.drawing, spacing, mid_r[j], anchor, reach,
                               problem.params)
        grid = grid.take(np.flatnonzero(np.linalg.norm(grid.positions - anchor, axis=1)
                                        <= reach))
        sets[j] = _unique(JointCandidates.concat([sets[j], here, near, grid]))
    # Rigid joints may stay where they are or sit at their offsets from their parents'
    # candidates (the search's offsets are soft: a chest's shoulders can lie a little off
    # it, and an arm fits again only from the shoulder put back).
    moved = _with_rigid(problem, sets, params.rigid_turns, params.rigid_search)
    for j in np.flatnonzero(problem.rigid):
        sets[j] = _unique(JointCandidates.concat([sets[j], moved[j]]))
    return sets


def _limb_resolves(problem, base, contour: list[JointCandidates], mid_r: np.ndarray,
                   conf: JointCandidates, params, cache: dict) -> tuple[JointCandidates, int]:
    """Re-solve each limb exactly with the rest of the solution held (ours).

    The fine DP searches only near the coarse answer, and the coarse pass has no
    naturalness triplets: a limb it folds onto one contour (a raised forearm laid back
    along the upper arm: the raised arm seen obliquely, 11.7% of the height off at its
    worst joint, 3.8 after) stays folded when the right placement was never a fine
    candidate. Here each free chain (:func:`_limb_chains`: elbow, wrist and hand; knee,
    ankle and foot; neck and head) is solved by the DP with triplets over wide candidate
    sets (:func:`_limb_sets`) while every other free joint keeps its placement (rigid
    joints may also snap to their offsets), and replaces the solution by
    :func:`_limb_accepts`. The chains are swept ``limb_resolves`` times (a second sweep
    changed none of the 48 drawings measured in docs/gesture.md).

    Returns:
        ``(configuration, number of re-solves kept)``.
    """
    kept = 0
    got = assign_contours(base, conf)
    e_cur = joint_energy(base, conf)[0]
    for _ in range(params.limb_resolves):
        changed = False
        for chain in _limb_chains(problem):
            sets = _limb_sets(problem, contour, mid_r, conf, chain, params)
            labels, _ = solve_tree(build_energy(problem, sets, cache=cache))
            new = configuration(sets, labels)
            a, e = assign_contours(base, new), joint_energy(base, new)[0]
            if _limb_accepts((a, e), (got, e_cur), params):
                conf, got, e_cur, changed = new, a, e, True
                kept += 1
        if not changed:
            break
    return conf, kept


def _resolve_refined(problem, base, contour: list[JointCandidates], mid_r: np.ndarray,
                     conf: JointCandidates, reference: np.ndarray, params,
                     cache: dict) -> tuple[JointCandidates, dict | None]:
    """The limb re-solves run again from the refined solution, then Section 6's walk (ours).

    The re-solves before the refinement start from the discrete placements, a step
    apart; the walk then moves the rest of the body (a rigid group, a neighbouring
    chain) and a limb whose better placement was a near tie before can win after it (the
    token rig's raised hand in ``tests/blender/test_imported_rigs.py``, folded 13 of its
    33 px: E_match 4.72 against 4.68 with the arm the proper rig's fit found). Each chain
    is re-solved as in :func:`_limb_resolves` (``refined_resolves`` sweeps) with the
    current, refined placements among its candidates; when any is kept the result is
    refined again and replaces the solution by :func:`_limb_accepts` (a lower ``E_match``
    counting the overlap penalty, at no less coverage).

    Args:
        problem: The matching problem the refinement used.
        base: The problem without blocked samples (energies and assignments).
        contour: Contour candidates per joint.
        mid_r: Middle radius per joint, pixels, ``(J,)``.
        conf: The refined solution.
        reference: The character's joints in the view at the current pose, ``(J, 2)``.
        params: Embedding parameters.
        cache: The search's cost cache.

    Returns:
        ``(solution kept, the second walk's diagnostics or None when it is not kept)``.
    """
    sub = replace(params, limb_resolves=params.refined_resolves)
    new, kept = _limb_resolves(problem, base, contour, mid_r, conf, sub, cache)
    if not kept:
        return conf, None
    new, info = refine(problem, new, reference, params.refine)
    old = (assign_contours(base, conf), joint_energy(base, conf)[0])
    if _limb_accepts((assign_contours(base, new), joint_energy(base, new)[0]), old, params):
        return new, info
    return conf, None


def _limb_accepts(new: tuple, old: tuple, params) -> bool:
    """Whether a limb's re-solve replaces the solution; both are ``(Assignment, E_match)``.

    Its ``E_match`` counting ``overlap_penalty`` per overlapping pair (as the consistency
    step counts them) must be lower, at no less coverage, or at most ``coverage_gain``
    less when it has fewer overlapping pairs. Requiring a lower ``E_match`` without the
    penalty and no more overlaps kept fewer re-solves (the humanoid's reach seen at 3/4,
    its arm laid across the body with two overlaps: 41% of the height off against 24%).
    """
    (got, e_new), (was, e_old) = new, old
    pen = params.overlap_penalty
    if e_new + pen * len(got.overlaps) >= e_old + pen * len(was.overlaps) - 1e-9:
        return False
    slack = params.coverage_gain if len(got.overlaps) < len(was.overlaps) else 0.0
    return got.coverage >= was.coverage - slack


def _coverage_moves(problem, base, terminals: np.ndarray, contour: list[JointCandidates],
                    fine: list[JointCandidates], conf: JointCandidates, assign, params,
                    cache: dict) -> tuple[JointCandidates, int]:
    """Move limb ends, one at a time, onto the contours the solution leaves unexplained.

    Ours, in place of the paper's order by unary cost: with the hands and feet among the
    terminals (fingers and toes continue them) its assignments differ mostly in sites
    that explain nothing new. Each round tries every terminal at each of its
    :func:`_coverage_sites` (the other terminals free, those moved in earlier rounds kept
    at their sites), solves the fine DP, and keeps the best by (overlaps, coverage,
    E_match) of the solves :func:`_accepts` takes; rounds stop when it takes none, when
    the constraints are met, or after ``coverage_moves`` rounds. The DP runs on the
    current problem (with the samples blocking gave up); acceptance compares ``E_match``
    without them, as the blocking rounds do (:func:`_resolves`). On the test view's kick
    (not among the Blender test's poses) the kicked ankle and foot, drawn longer than their
    bones through the perspective, were left 7-9% of the height short; moved onto the
    foot's own outline every joint of the leg lands within 4% (the drawing's worst joint,
    a clavicle's tail, 4.02%).

    Returns:
        ``(configuration, number of solves)``.
    """
    memo: dict = {}
    placed: dict[int, JointCandidates] = {}
    cur, got, e_cur, count = conf, assign, joint_energy(base, conf)[0], 0
    for _ in range(params.coverage_moves):
        best = None
        for j, site in _coverage_sites(base, got, terminals, contour, cur, params):
            trial = {**placed, j: site}
            new, _ = _solve_placed(problem, fine, contour, trial, params, cache, memo)
            a, e = assign_contours(base, new), joint_energy(base, new)[0]
            count += 1
            key = (len(a.overlaps), -a.coverage, e)
            if _accepts((a, e), (got, e_cur), params) and (best is None or key < best[0]):
                best = (key, new, a, e, trial)
        if best is None:
            break
        _, cur, got, e_cur, placed = best
        if not got.overlaps and got.coverage >= params.min_coverage:
            break
    return cur, count


def _coverage_sites(problem, assign, terminals: np.ndarray, contour: list[JointCandidates],
                    conf: JointCandidates, params) -> list[tuple[int, JointCandidates]]:
    """Sites of each limb end that claim unexplained contour samples.

    A terminal's contour candidates, consolidated at a step, within reach of its parent
    as placed and more than 1.5 steps from where it is; kept when their circle is aligned
    with at least two uncovered samples, the ``coverage_sites`` claiming the most (the
    cheaper first among equals).

    Returns:
        ``(joint, site)`` pairs, each site a single candidate.
    """
    eps = problem.drawing.epsilon
    uncovered = ~assign.covered
    out = []
    for j in terminals:
        cand = _within_reach(problem, consolidate(contour[j], eps), conf, int(j))
        if not len(cand):
            continue
        away = np.linalg.norm(cand.positions - conf.positions[j], axis=1) > 1.5 * eps
        gain = np.array([np.count_nonzero(uncovered[np.unique(a[a >= 0])])
                         for a in cand.aligned])
        keep = np.flatnonzero(away & (gain >= 2))
        keep = keep[np.lexsort((cand.unary[keep], -gain[keep]))][:params.coverage_sites]
        out += [(int(j), cand.take(np.array([k]))) for k in keep]
    return out


def _held_by_others(problem, assign, j: int, n_samples: int) -> np.ndarray:
    """Contour samples claimed by bones and joints not adjacent to joint ``j``, ``(N,)``."""
    s = problem.solving
    held = np.zeros(n_samples, dtype=bool)
    for b in range(s.n_bones):
        if j not in (s.head_joint[b], s.tail_joint[b]):
            held[assign.bone_left[b]] = True
            held[assign.bone_right[b]] = True
    near = {j, int(s.joint_parent[j]), *np.flatnonzero(s.joint_parent == j).tolist()}
    for k, samples in enumerate(assign.joint_samples):
        if k not in near:
            held[samples] = True
    return held


def _resolves(new: tuple[int, float, float], old: tuple[int, float, float], params) -> bool:
    """Whether an overlap-blocking re-solve replaces the best solution so far.

    Both are ``(overlaps, coverage, energy)`` with the energy of the unblocked problem.
    Blocking helps when a part was folded onto another part's contour, which leaves some
    of the drawing unexplained: the re-solve must lower the energy counting
    ``overlap_penalty`` per overlap, and either explain ``coverage_gain`` more of the
    drawing or cost at most ``symmetric_tolerance`` more energy. Limbs that really overlap
    in the view (the legs of a step seen at 3/4) share contours however they are placed;
    blocking then only moves a correct limb to a worse fit, which this rejects. With
    ``resolve_rate`` the coverage is bought at the consistency step's rate instead
    (:func:`_accepts`: ``symmetric_tolerance`` per ``coverage_gain``, at least
    ``symmetric_tolerance``): a 2% jump in coverage no longer buys any energy (the 2D
    bench's quadruped with its tail up took a re-solve 2.8 higher without the penalty
    for 6.5% more coverage, 10 pairs fewer, and ended with a front paw 51% off).
    """
    pen = params.overlap_penalty
    if new[2] + pen * new[0] >= old[2] + pen * old[0]:
        return False
    if not params.resolve_rate:
        return (new[1] >= old[1] + params.coverage_gain
                or new[2] <= old[2] + params.symmetric_tolerance)
    rate = params.symmetric_tolerance / params.coverage_gain
    return new[2] <= old[2] + max(params.symmetric_tolerance, rate * (new[1] - old[1]))


def _with_rigid(problem, cands: list[JointCandidates], turns: tuple[float, ...] = (),
                snap: bool = True) -> list[JointCandidates]:
    """Candidates of the rigidly attached joints from their parent's, by the offset.

    A hip or shoulder head sits at a fixed offset from the pelvis or chest (a joint of
    reduced degrees of freedom, Section 6). Its candidates are its parent's moved by the
    offset seen in the view, also turned by each angle of ``turns`` (degrees) for a torso
    that turns in the drawing. With ``snap`` these are its only candidates, so the search
    itself keeps the rigid neighbourhood (a shoulder cannot leave the chest for a hand's
    contour, reversing the arm chain); otherwise they are added to its own.
    """
    s, d = problem.solving, problem.drawing
    out = list(cands)
    for j in range(s.n_joints):
        p = s.joint_parent[j]
        if not problem.rigid[j]:
            continue
        off = problem.link_offset[j]
        rads = np.radians(np.r_[0.0, np.asarray(turns, float)])
        rot = np.stack([np.cos(rads) * off[0] - np.sin(rads) * off[1],
                        np.sin(rads) * off[0] + np.cos(rads) * off[1]], axis=1)
        moved = (out[p].positions[None] + rot[:, None]).reshape(-1, 2)
        r = np.full(len(moved), float(np.median(cands[j].radii)))
        _, aligned = unary_cost(d, moved, r, bool(problem.terminal[j]), problem.params)
        # Placed by rigidity, not by the contours: no unary cost.
        cost = np.zeros(len(moved))
        side = np.zeros(len(moved), int)
        shifted = JointCandidates(moved, r, side, -np.ones(len(moved), int),
                                  -np.ones(len(moved), int), cost, aligned)
        out[j] = shifted if snap else JointCandidates.concat([cands[j], shifted])
    return out


#: How far (as a fraction of the character's projected diagonal) a drawing's bounding box
#: may lie beside the character's before it is refused as not drawn over it.
FAR_MARGIN = 0.1


def _check_over_character(bbox: np.ndarray, reference: np.ndarray, char_diag: float) -> None:
    """Refuse a drawing whose bounding box misses the character's projected joints.

    Args:
        bbox: The drawing's ``[[xmin, ymin], [xmax, ymax]]``, pixels.
        reference: The character's joints in the view, pixels, ``(J, 2)``.
        char_diag: Their bounding-box diagonal, pixels.

    Raises:
        InputError: The two boxes are apart by more than :data:`FAR_MARGIN` of the diagonal.
    """
    lo, hi = reference.min(axis=0), reference.max(axis=0)
    gap = np.maximum(np.maximum(bbox[0] - hi, lo - bbox[1]), 0.0)
    if float(np.hypot(*gap)) > FAR_MARGIN * char_diag:
        raise InputError(
            f"The drawing lies {float(np.hypot(*gap)):.0f} px beside the character in the "
            "view: draw over the character (or frame it so the drawing covers it).")


def turned_half_round(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Points turned 180 degrees about the rig's up axis through their centroid (ours).

    The character turned round where it stands: seen through a level camera its image is
    mirrored left to right, each joint keeping its label, so its left limbs show where
    the right ones did.

    Args:
        points: World positions, ``(J, 3)``.
        up: The axis, world axes, ``(3,)`` (any length).

    Returns:
        The turned positions, world units, ``(J, 3)``.
    """
    return _turned_about_centroid(points, half_turn(up))


def _turned_about_centroid(points: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Points ``(J, 3)`` turned by ``rotation`` ``(3, 3)`` about their centroid."""
    pts = np.asarray(points, float)
    centre = pts.mean(axis=0)
    return centre + (pts - centre) @ rotation.T


FACINGS = ("auto", "front", "back", "turned")


def facing_turn(facing: str, solving: SolvingSkeleton, joints: np.ndarray, camera: Camera,
                object_up: np.ndarray | None = None, min_slope: float = 0.3
                ) -> tuple[np.ndarray | None, str | None]:
    """The turn the fit's reference needs for the side the drawing shows (ours).

    The character's front is ``depth.start.front_direction``'s (the hips' or shoulders'
    left-to-right vector crossed with the rig's up). It shows its front when that points
    towards the eye by more than ``min_slope`` (17 degrees out of the view plane), its
    back when away by as much. ``"back"`` turns a character that shows its front,
    ``"front"`` one that shows its back; ``"auto"`` never turns, ``"turned"`` always (the
    character turned half round about its up: in a side view, a profile facing the other
    way). In between (a side view) and for a rig without left/right pairs, front and back
    are not told: no turn, and a note says so.

    Args:
        facing: One of :data:`FACINGS`.
        solving: The solving skeleton.
        joints: Its joints at the current pose, world units, ``(J, 3)``.
        camera: The view.
        object_up: The armature object's z axis (None: world +Z); gives the rig's up
            (``depth.start.rig_up``).
        min_slope: Smallest share of the front along the line of sight that shows a side.

    Returns:
        ``(up, note)``: the rig's up to turn the reference about (:func:`turned_half_round`)
        or None for no turn, and a note for the user or None.

    Raises:
        InputError: An unknown ``facing``.
    """
    if facing not in FACINGS:
        raise InputError(f"Facing must be one of {', '.join(FACINGS)}, not {facing!r}.")
    if facing == "auto":
        return None, None
    up = REST_UP if object_up is None else rig_up(solving, np.asarray(object_up, float))
    if facing == "turned":
        return up, None
    pts = np.asarray(joints, float)
    frame = view_frame(camera, pts.mean(axis=0))
    front = front_direction(solving, pts, frame, up)
    slope = 0.0 if front is None else float(front @ frame.forward)
    if abs(slope) <= min_slope:
        why = "has no left/right limbs" if front is None else "is seen from the side"
        return None, (f"Facing {facing.capitalize()} was not used: the character {why}, "
                      "so the fit reads the drawing as seen (Turned Round turns it).")
    shows_back = slope > 0.0
    return (up if shows_back == (facing == "front") else None), None


def rolled_in_view(points: np.ndarray, camera: Camera, body_up: str) -> np.ndarray:
    """Points rolled in the image plane so that the character's up points ``body_up`` (ours).

    The turn is about the camera's viewing direction through the points' centroid (the
    axis the 3D step rolls its bind pose about, ``depth.start.rolled_bind``), so every
    point keeps its depth: for an orthographic view the image turns exactly about the
    centroid's, for a perspective one to first order in the points' spread and their
    offset from the view's axis over their distance from the eye. A character standing
    in the bind pose is shown lying on its side (``"left"``: its head on the image's
    left) or upside down (``"down"``), as a handstand or a cartwheel is drawn.

    Args:
        points: World positions, ``(J, 3)``.
        camera: The view.
        body_up: One of ``depth.start.BODY_UPS``.

    Returns:
        The rolled positions, world units, ``(J, 3)``.

    Raises:
        InputError: An unknown ``body_up``.
    """
    return _turned_about_centroid(points, view_roll(camera.forward, body_up))


def fit_solving_skeleton(skeleton: Skeleton, weights: np.ndarray | None = None,
                         override: np.ndarray | None = None,
                         params: GestureParams | None = None) -> SolvingSkeleton:
    """The solving skeleton :func:`fit_drawing` builds when it is not given one.

    Args:
        skeleton: The character's skeleton.
        weights: Skin weights ``(V, n_bones)`` or None: bones moving no skin are left out
            (``solving.select_bones``).
        override: Bones of the "Gesture" collection, ``(n,)`` bool, or None.
        params: Parameters (``min_bone_epsilons``; defaults: the paper's).

    Returns:
        The solving skeleton.
    """
    params = params or GestureParams()
    weighted = None if weights is None else np.asarray(weights).sum(axis=0) > 0.0
    return solving_skeleton(skeleton, override, params.min_bone_epsilons, weighted)


def fit_drawing(strokes: list[Stroke], skeleton: Skeleton, pose: Pose, vertices: np.ndarray,
                camera: Camera, weights: np.ndarray | None = None,
                params: GestureParams | None = None, override: np.ndarray | None = None,
                solving: SolvingSkeleton | None = None, facing: str = "auto",
                object_up: np.ndarray | None = None, body_up: str = "up") -> Embedding2D:
    """Embed the solving skeleton in a gesture drawing.

    Args:
        strokes: The drawing's contour strokes, pixels.
        skeleton: The character's skeleton (rest pose, world space).
        pose: Its current pose: sets the view scale and the left/right reference.
        vertices: Rest mesh vertices in world space, ``(V, 3)``.
        camera: The view the drawing was made in.
        weights: Skin weights ``(V, n_bones)`` or None (distance-based regions); bones
            moving no skin are not solved (``solving.select_bones``).
        params: Parameters (defaults: the paper's).
        override: Bones of the "Gesture" collection, ``(n,)`` bool, or None.
        solving: A prebuilt solving skeleton (overrides ``override``; default
            :func:`fit_solving_skeleton`).
        facing: Which side of the character the drawing shows: ``"auto"`` (the side
            ``pose`` shows in this view), ``"front"``, ``"back"`` or ``"turned"`` (see
            :func:`facing_turn`). When it is not the side ``pose`` shows, the fit's
            left/right reference and bind-pose priors are read from ``pose`` turned half
            round (:func:`turned_half_round`).
        object_up: The armature object's z axis, world axes, ``(3,)``: tells the rig's up
            (``depth.start.rig_up``; None: world +Z) for ``facing``.
        body_up: Which way the character's up points in the drawing, one of
            ``depth.start.BODY_UPS``: ``"up"`` (as it stands), ``"left"``, ``"right"`` (lying)
            or ``"down"`` (upside down). Other than ``"up"``, the reference and priors
            are read from ``pose`` rolled in the image plane (:func:`rolled_in_view`),
            after ``facing``'s turn.

    Returns:
        The embedding with its diagnostics.

    Raises:
        InputError: No strokes, a drawing far smaller than the character or beside it, no
            mesh, an unknown ``facing`` or ``body_up``.
    """
    params = params or GestureParams()
    timings: dict[str, float] = {}
    warnings: list[str] = []
    t0 = time.perf_counter()
    drawing = preprocess(list(strokes), params.preprocess)
    solving = solving or fit_solving_skeleton(skeleton, weights, override, params)
    world = posed_joints(solving, skeleton, pose)
    turn, note = facing_turn(facing, solving, world, camera, object_up)
    if turn is not None:
        world = turned_half_round(world, turn)
    world = rolled_in_view(world, camera, body_up)
    if note:
        warnings.append(note)
    reference = camera.project(world)
    if not np.all(np.isfinite(reference)):
        raise InputError("The character is behind the view: frame it before fitting.")
    char_diag = float(np.linalg.norm(reference.max(axis=0) - reference.min(axis=0)))
    if drawing.diagonal < params.min_drawing_ratio * char_diag:
        raise InputError(
            f"The drawing ({drawing.diagonal:.0f} px across) is far smaller than the "
            f"character in the view ({char_diag:.0f} px): draw over the whole character.")
    _check_over_character(drawing.bbox, reference, char_diag)
    ppu = camera.pixels_per_unit(float(np.mean(camera.depth(world))))
    timings["preprocess"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    r_min, r_max = joint_radii(solving, skeleton, vertices, weights)
    problem = make_problem(drawing, solving, ppu, reference, params.costs,
                           near_scales(camera, solving, world, ppu))
    if params.rigid_search:
        problem = replace(problem, interior=interior_joints(solving, r_max))
    eps = drawing.epsilon
    terminal = problem.terminal
    contour = [contour_candidates(drawing, discrete_radii(r_min[j] * ppu, r_max[j] * ppu, eps,
                                                          params.max_radii),
                                  bool(terminal[j]), params.costs, params.pool_candidates)
               for j in range(solving.n_joints)]
    mid_r = 0.5 * (r_min + r_max) * ppu
    timings["candidates"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    cache: dict = {}
    cands, labels, _ = _two_pass(problem, contour, mid_r, params, cache)
    timings["mrf"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    seeds, rounds = _blocking_rounds(problem, contour, mid_r, configuration(cands, labels),
                                     cands, params, cache)
    timings["consistency"] = time.perf_counter() - t0
    best = _finish(seeds[0], problem, contour, mid_r, reference, params, cache, timings)
    if len(seeds) > 1 and len(best[0][0].overlaps) >= params.reseed_overlaps:
        got = _finish(seeds[1], problem, contour, mid_r, reference, params, cache, timings)
        if _seed_accepts(got[0], best[0], params):
            best = got
    _, problem, conf, mask, refine_info, n_bad = best
    if n_bad:
        warnings.append(f"{n_bad} pairs of body parts claim the same contour.")
    return replace(_result(problem, conf, refine_info, timings, warnings, rounds, mask),
                   body_up=body_up)


def _blocking_rounds(base, contour: list[JointCandidates], mid_r: np.ndarray,
                    conf: JointCandidates, fine_sets: list[JointCandidates], params,
                    cache: dict) -> tuple[list[tuple], int]:
    """Section 5.4's overlap blocking: re-solves with the samples each loser gives up.

    Each round blocks, for the part of every overlapping pair that yields
    (:func:`~.consistency.block_overlaps`), the samples the other claims (added to the
    earlier rounds' blocks) and solves the two passes again; the best solution so far is
    kept by :func:`_resolves`. Rounds stop when the solution meets the constraints, has
    no overlap, blocking adds nothing new, or after ``max_terminal_rounds``. When that cap
    ends them with overlaps left, ``extra_terminal_rounds`` more rounds continue the same
    blocking (ours): which round recovers a limb laid on another part's contour depends on
    small differences of the costs (the 3D bench's reach seen obliquely, its left arm
    folded onto the legs after three rounds and recovered in the fourth), so the best
    solution after the extra rounds is a second seed for the rest of the consistency step
    and the refinement, and the caller keeps the better result (:func:`_seed_accepts` on
    the final results: no more overlapping pairs, and a lower energy net of coverage).

    Args:
        base: The matching problem without blocked samples.
        contour: Contour candidates per joint.
        mid_r: Middle radius per joint, pixels, ``(J,)``.
        conf: The first pass's solution.
        fine_sets: Its fine candidate sets.
        params: Embedding parameters.
        cache: The search's cost cache.

    Returns:
        ``(seeds, rounds made)``; each seed ``(configuration, problem with its blocked
        samples, fine candidate sets)``, the one after ``max_terminal_rounds`` first.
    """
    blocked = np.zeros((base.solving.n_bones, base.drawing.n_samples), dtype=bool)
    problem, best_sol, seeds, rounds = base, None, [], 0
    last = params.max_terminal_rounds + params.extra_terminal_rounds
    for rounds in range(last + 1):
        assign = assign_contours(base, conf)
        n_bad = len(assign.overlaps)
        key = (n_bad, assign.coverage, joint_energy(base, conf)[0])
        if best_sol is None or _resolves(key, best_sol[0], params):
            best_sol = (key, (conf, problem, fine_sets))
        if rounds == params.max_terminal_rounds:
            seeds.append(best_sol[1])
        if n_bad == 0 or rounds == last:
            break
        grown = blocked | block_overlaps(base, assign)
        if np.array_equal(grown, blocked):
            break  # the same problem again would give the same answer
        blocked = grown
        problem = replace(base, blocked=blocked.copy())
        fine_sets, labels, _ = _two_pass(problem, contour, mid_r, params, cache)
        conf = configuration(fine_sets, labels)
    if not seeds or seeds[-1] is not best_sol[1]:
        seeds.append(best_sol[1])
    return seeds, rounds


def _finish(seed: tuple, base, contour: list[JointCandidates], mid_r: np.ndarray,
            reference: np.ndarray, params, cache: dict, timings: dict) -> tuple:
    """The consistency step after blocking, then the refinement, from one seed.

    Terminal moves or enumeration (:func:`_enumerate_terminals`), limb re-solves
    (:func:`_limb_resolves`), the symmetric permutations, Section 6's walks
    (:func:`_refine_both`) and the refined re-solves (:func:`_resolve_refined`).

    Args:
        seed: ``(configuration, problem with its blocked samples, fine candidate sets)``.
        base: The matching problem without blocked samples.
        contour: Contour candidates per joint.
        mid_r: Middle radius per joint, pixels, ``(J,)``.
        reference: The character's joints in the view at the current pose, ``(J, 2)``.
        params: Embedding parameters.
        cache: The search's cost cache.
        timings: Seconds per stage, added to (``"consistency"``, ``"refine"``).

    Returns:
        ``((Assignment, E_match) of the result, problem, configuration, permutation
        mask, refinement diagnostics, overlapping pairs after the limb re-solves)``.
    """
    t0 = time.perf_counter()
    conf, problem, fine_sets = seed
    conf, trials = _enumerate_terminals(problem, base, contour, fine_sets, conf, params, cache)
    conf, resolved = _limb_resolves(problem, base, contour, mid_r, conf, params, cache)
    n_bad = len(assign_contours(base, conf).overlaps)
    limbs = symmetric_limbs(problem)
    options = []
    # Symmetric permutations compete on the paper's energy: the direction prior (our
    # addition) is measured against the bind pose's left/right layout, the very thing the
    # twist score decides.
    plain = replace(base, params=replace(base.params, w_direction=0.0))
    for mask in range(2 ** len(limbs)):
        perm = permute(conf, limbs, mask)
        e = joint_energy(plain, perm)[0]
        options.append((e, twist_score(problem, perm.positions, reference), mask, perm))
    e_min = min(o[0] for o in options)
    close = [o for o in options if o[0] <= e_min + params.symmetric_tolerance]
    _, _, mask, conf = min(close, key=lambda o: (o[1], o[0], o[2]))
    if mask:
        problem = base
    timings["consistency"] = timings.get("consistency", 0.0) + time.perf_counter() - t0

    t0 = time.perf_counter()
    conf, refine_info = _refine_both(problem, conf, reference, params)
    if refine_info["pose_start"]:
        mask = 0  # the pose's start carries no permutation of the limbs
    refine_info["refined_resolves"] = 0
    if params.refined_resolves:
        conf, again = _resolve_refined(problem, base, contour, mid_r, conf, reference, params,
                                       cache)
        if again is not None:
            refine_info.update(again, refined_resolves=1)
    timings["refine"] = timings.get("refine", 0.0) + time.perf_counter() - t0
    refine_info["terminal_trials"] = trials
    refine_info["limb_resolves"] = resolved
    scored = (assign_contours(base, conf), joint_energy(base, conf)[0])
    return scored, problem, conf, mask, refine_info, n_bad


def _refine_both(problem: MatchProblem, conf: JointCandidates, reference: np.ndarray,
                 params: GestureParams) -> tuple[JointCandidates, dict]:
    """Section 6's refinement from the discrete solution and, with ``bind_start``, from the pose.

    The second start puts every joint where the character's current pose has it in the view,
    with the discrete solution's radii and contour labels. A drawing that leaves most of the
    character as it is lies near that pose, which the discrete candidates (a step apart) can
    miss by a fraction of a step: the walk from them then stops in a neighbouring minimum
    (the test view's rest pose when this came in: the chest 20 px high, E_match 7.90 against
    4.67 from the pose). The pose's result is kept when it has no more overlapping parts
    and either the lower E_match at no less coverage, or ``coverage_gain`` more coverage at
    most ``symmetric_tolerance`` more E_match (the consistency step's rule for coverage
    bought with energy, :func:`_accepts`; Section 5.4's constraints come first): a limb
    left at its bind place where the drawing moved it can lower the energy while leaving
    the drawn limb's contours unexplained. Without the second branch, the 2D bench
    quadruped's rest drawing under ``foreshortening`` and ``exposed_conformity`` kept the
    discrete walk (E_match 6.44, 3 overlapping pairs, coverage 0.877, the hidden far hind
    leg folded) over the pose's (6.47, 2 pairs, 0.913; docs/gesture.md). Both walks
    minimize the same energy, direction prior included (which the pose's start begins
    with at zero); the labels of a joint (its contour origin, side and visibility) stay the
    discrete solution's, as they do for every joint the walk moves.

    Args:
        problem: The matching problem.
        conf: The discrete solution (after the consistency step).
        reference: The character's joints in the view at the current pose, pixels,
            ``(J, 2)``.
        params: Embedding parameters.

    Returns:
        ``(configuration, diagnostics)`` as :func:`~.refine.refine` for the walk kept
        (its ``"energy_before"`` is that walk's start), with ``"pose_start"``: 1 when
        the result comes from the pose, else 0.
    """
    out, info = refine(problem, conf, reference, params.refine)
    info["pose_start"] = 0
    if not params.bind_start:
        return out, info
    at_pose = with_positions(conf, np.asarray(reference, float).copy())
    alt, alt_info = refine(problem, at_pose, reference, params.refine)
    got, alt_got = assign_contours(problem, out), assign_contours(problem, alt)
    e_alt, e_out = alt_info["energy_after"], info["energy_after"]
    lower = e_alt < e_out and alt_got.coverage >= got.coverage
    covers = (alt_got.coverage > got.coverage + params.coverage_gain
              and e_alt <= e_out + params.symmetric_tolerance)
    if len(alt_got.overlaps) > len(got.overlaps) or not (lower or covers):
        return out, info
    alt_info["pose_start"] = 1
    return alt, alt_info


def _runs(samples: np.ndarray, drawing) -> tuple[np.ndarray, ...]:
    """Split sorted sample indices into runs that are consecutive along the contour."""
    if samples.size == 0:
        return ()
    samples = np.sort(samples)
    breaks = np.flatnonzero(drawing.next[samples[:-1]] != samples[1:]) + 1
    return tuple(drawing.points[run] for run in np.split(samples, breaks) if len(run) >= 2)


def _result(problem, conf: JointCandidates, refine_info: dict, timings: dict,
            warnings: list[str], rounds: int, mask: int) -> Embedding2D:
    """Assemble the :class:`Embedding2D` of a final configuration."""
    d, s = problem.drawing, problem.solving
    assign = assign_contours(problem, conf)
    energy, terms = joint_energy(problem, conf)
    terms = dict(terms)
    terms["overlap"] = problem_penalty = len(assign.overlaps) * 10.0
    terms.update(refine_info)
    terms["terminal_rounds"] = rounds
    terms["symmetric_permutation"] = mask
    segs, sides = [], []
    for b in range(s.n_bones):
        left, right = _runs(assign.bone_left[b], d), _runs(assign.bone_right[b], d)
        segs.append(left + right)
        sides.append((1,) * len(left) + (-1,) * len(right))
    contours = tuple(d.points[d.offsets[k]:d.offsets[k + 1]] for k in range(len(d.offsets) - 1))
    normals = tuple(d.normals[d.offsets[k]:d.offsets[k + 1]] for k in range(len(d.offsets) - 1))
    visible = conf.origin >= 0
    if not visible.all():
        hidden = [s.joint_bones[j] for j in np.flatnonzero(~visible)]
        warnings.append(f"Joints placed without contour evidence (hidden, or set by a rigid "
                        f"offset): {', '.join(hidden)}.")
    timings["total"] = sum(timings.values())
    return Embedding2D(
        solving=s, joints2d=conf.positions.copy(), joint_visible=visible,
        joint_radius=conf.radii.copy(), bone_segments=tuple(segs),
        bone_segment_sides=tuple(sides), occlusions=(), contours=contours,
        contour_normals=normals, coverage=assign.coverage,
        e_match=float(energy + problem_penalty), terms=terms, timings=dict(timings),
        joint_side=conf.side.copy(), joint_segments=tuple(d.points[a]
                                                          for a in assign.joint_samples),
        bridges=d.bridges.copy(), epsilon=d.epsilon, warnings=tuple(warnings))
