"""Stick figure -> 3D poses: the whole pipeline of Lin et al. (2012), Sections 4.1-4.3.

1. Match the drawing to the character's stick joints (:mod:`.graph`).
2. Place the root: the sit location along the pelvis' eye ray (Section 4.1.2) when the
   environment offers a seat, otherwise the depth at which the drawing has the
   character's size (or the depth of the pinned contacts).
3. Normalize the drawing (Section 4.1.3).
4. Genetic search over the pose genes (population 1024), the depth interpretations of
   the best individuals, a local search flipping one limb at a time in depth (only with
   environment pins or a seat; a flipped limb whose end is pinned turns about that end,
   the body moving along the eye ray), then L-BFGS-B refinement of several distinct good
   candidates with the collision energy (Eq. 11).
5. Per suggestion: hands and feet resting on the environment are turned to a
   collision-free orientation and pinned joints are placed exactly on their targets.

Deterministic for a given seed.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
from ..exceptions import InputError, SolverError
from ..rotations import exp_map, log_map, normalize, rotation_between
from ..skeleton import Pose, Skeleton
from .batch import refine_batch, refine_lbfgsb_batch
from .capsules import Capsules, bone_masses, capsules_from_mesh
from .environment import UP_ANGLE, Environment, Seat, distance_grid, find_seat
from .figure import CharacterFigure, character_figure, spine_joint
from .finish import finish_pose, settle_unseen_feet
from .genetic import GAConfig, genetic_search
from .graph import SNAP_RADIUS, StickFigure, stick_figure_from_strokes
from .kinematics import PoseModel
from .lifting import depth_flips, lift_population, limb_flips
from .normalize import drawing_scale, normalize_figure
from .objective import EnvPin, Footprint, StickObjective, Weights
from .pins import (
    EnvPinSpec,
    LimbPinSpec,
    foot_extents,
    pin_offsets,
    resolve_pins,
    standing_joints,
)
from .ranking import RankWeights, plausibility
from .refine import RefineResult
from .threads import in_background, row_threads, single_thread_blas, split_rows

#: A candidate whose energy after the short refinement exceeds ``HOPELESS_RATIO`` times
#: the best one's plus ``HOPELESS_MARGIN`` is not refined further.
HOPELESS_RATIO = 10.0
HOPELESS_MARGIN = 0.05
#: Suggestions differ by at least one joint this far apart, as a fraction of the height.
DISTINCT = 0.04
#: A pinned standing foot supports the balance term (Eqs. 7-8) over this share of its
#: sole's extent about the ankle (heel to toe tip, measured on the mesh): the heel to
#: about the middle of the foot. 0 supports at the ankle alone (until this round). CMU
#: pinned, first suggestion at three seed sets: 10.84 / 10.95 / 11.73 % -> 10.31 /
#: 10.42 / 10.55 at 0.5; at the whole sole (1.0) 11.41 / 10.65 at the first two.
SOLE_SHARE = 0.5
#: Half-width of the root's box (fraction of the height) with neither seat nor pins.
FREE_ROOT_RANGE = 0.15
#: The same for a horizontal body (a quadruped): its legs, nearer or farther than its
#: root, make the depth read from the drawing's scale less certain.
FREE_ROOT_RANGE_HORIZONTAL = 0.3


def _upright(figure: CharacterFigure, skeleton: Skeleton) -> bool:
    """Whether the body's main axis (root to :func:`spine_joint`) is across its facing."""
    rest = figure.rest_joints(skeleton)
    spine = normalize(rest[spine_joint(figure)] - rest[0])
    return bool(abs(spine @ figure.forward) < 0.7)
#: Distinct individuals of the genetic search refined before their depth flips are tried.
GA_SEEDS = 3
#: Refined individuals whose depth flips are tried.
FLIPPED_SEEDS = 2
#: Root gene change (radians and world units) below which a spine-mirrored seed is the
#: seed itself and is not tried: a turn of the root below about 3 degrees, i.e. a spine
#: within about 1.4 degrees of the plane across the eye ray through its top (mirroring a
#: spine at angle phi to that plane turns it by 2 phi).
MIRROR_MIN = 0.05
#: Depth interpretations whose collisions are checked (the most plausible without them).
SCREENED = 64
#: Candidates refined beyond the number of suggestions.
EXTRA_CANDIDATES = 3
#: Residual evaluations of the short (Gauss-Newton) refinement of each candidate.
SHORT_EVALUATIONS = 10
#: The limb-flip move (:func:`_flip_descent`): most rounds, residual evaluations refining
#: each flipped candidate, and the fraction of the best score a flip must gain to count
#: (flips 1-4 % more plausible than a sitting pose were as often wrong as right).
FLIP_ROUNDS = 4
FLIP_EVALUATIONS = 10
FLIP_MARGIN = 0.1


@dataclass(frozen=True)
class StickInput:
    """Everything one solve needs.

    Attributes:
        skeleton: Rest skeleton (world space).
        camera: The view the figure was drawn in.
        strokes: Drawn strokes in pixels, each ``(n_i, 2)`` (ignored when ``stick`` given).
        stick: An already matched (e.g. edited) drawing, or None.
        environment: Meshes to sit on and avoid, or None.
        mesh_vertices: Rest skin vertices ``(V, 3)`` (capsules, masses), or None.
        mesh_weights: Skin weights ``(V, n)``, or None.
        ik_limits: Rig IK limits ``(n, 3, 2)`` (NaN = unlimited), or None.
        roles: Humanoid roles the rig gives outright, ``{role: bone name}``
            (:func:`.figure.find_humanoid_bones`), or None.
        base_pose: Pose of the bones the solver does not move (rest when None).
        env_pins: Joints pinned to surfaces.
        limb_pins: Joints pinned to the body.
        seed: Random seed.
        n_suggestions: Distinct solutions to return.
        snap_radius: Node snapping radius, pixels.
        facing: ``"front"`` or ``"back"``: which way the character faces the viewer. The
            left/right sign test labels drawn strokes by it, and the search's initial roots
            face that way (the option decides, whatever the labels: Swap Sides exchanges
            limbs, it does not turn the body).
        use_contact: Use a drawn contact dot rather than the pelvis for the sit location.
        ga: Genetic search settings.
        weights: Objective weights.
        refine_iterations: L-BFGS-B iterations for each suggestion's final refinement.
        polish_evaluations: Gauss-Newton residual evaluations that follow them (0: none).
        rank: Weights of the plausibility score that orders the suggestions.
        threads: Threads evaluating the large populations (1 or 2: two fixed chunks of
            rows, one in a worker thread; :func:`.threads.split_rows`). The results are
            the same either way.
    """

    skeleton: Skeleton
    camera: Camera
    strokes: tuple[np.ndarray, ...] = ()
    stick: StickFigure | None = None
    environment: Environment | None = None
    mesh_vertices: np.ndarray | None = None
    mesh_weights: np.ndarray | None = None
    ik_limits: np.ndarray | None = None
    roles: Mapping[str, str] | None = None
    base_pose: Pose | None = None
    env_pins: tuple[EnvPinSpec, ...] = ()
    limb_pins: tuple[LimbPinSpec, ...] = ()
    seed: int = 0
    n_suggestions: int = 3
    snap_radius: float = SNAP_RADIUS
    facing: str = "front"
    use_contact: bool = False
    ga: GAConfig = field(default_factory=GAConfig)
    weights: Weights = field(default_factory=Weights)
    refine_iterations: int = 10
    polish_evaluations: int = 20
    rank: RankWeights = field(default_factory=RankWeights)
    threads: int = 2


@dataclass(frozen=True)
class Suggestion:
    """One solution.

    Attributes:
        pose: Local rotations and translations of every bone.
        genes: Gene vector, shape ``(G,)``.
        energy: Objective value.
        score: Plausibility score (:mod:`.ranking`) of the refined pose before the pins
            were placed exactly; suggestions are sorted by it.
        terms: Unweighted energy terms and the ranking's foreshortening.
        joints: World stick joint positions, shape ``(J, 3)``.
        pin_residuals: Distance of each pinned joint from its target, the environment
            pins then the body pins (a point on a limb), world units, ``(k,)``.
    """

    pose: Pose
    genes: np.ndarray
    energy: float
    score: float
    terms: dict
    joints: np.ndarray
    pin_residuals: np.ndarray


@dataclass(frozen=True)
class StickResult:
    """Suggestions (best first) and diagnostics.

    Attributes:
        suggestions: Distinct solutions, best first.
        stick: The matched, normalized drawing.
        figure: The character's stick model.
        seat: The sit location, or None (standing, lying...).
        root_estimate: Initial root position, shape ``(3,)``.
        scale_factor: Normalization factor applied to the drawing.
        generations: Genetic generations run.
        refine_iterations: L-BFGS-B iterations per refined candidate.
        timings: Seconds per stage.
        warnings: Things the user should know (ambiguous sides, unreachable pins).
    """

    suggestions: tuple[Suggestion, ...]
    stick: StickFigure
    figure: CharacterFigure
    seat: Seat | None
    root_estimate: np.ndarray
    scale_factor: float
    generations: int
    refine_iterations: tuple[int, ...]
    timings: dict
    warnings: tuple[str, ...]


def _moving_pairs(model: PoseModel, caps: Capsules) -> Capsules:
    """The capsules with only the self-collision pairs whose relative pose can change.

    Two capsules move relative to each other only when a bone the genes turn lies on one
    side of the path between them (two fingers of one hand, both carried by the hand, keep
    their rest distance: if they do not overlap at rest they never will).
    """
    sk = model.skeleton
    moved = np.zeros(sk.n_bones, bool)
    moved[model.figure.root_bone] = True
    for grp in model.figure.groups:
        moved[grp.bones] = True
    turned = np.zeros((len(caps.bones), sk.n_bones), bool)
    for k, b in enumerate(caps.bones):
        chain = [a for a in sk.ancestors(int(b)) if moved[a]]
        turned[k, chain] = True
    if len(caps.pairs) == 0:
        return caps
    varies = np.any(turned[caps.pairs[:, 0]] != turned[caps.pairs[:, 1]], axis=1)
    return dataclasses.replace(caps, pairs=caps.pairs[varies])


def _edge_spans(model: PoseModel, lengths: np.ndarray, samples: int = 256
                ) -> tuple[np.ndarray, np.ndarray]:
    """Rigid and longest lengths of the stick edges, each ``(J,)`` by the child joint.

    The pelvis-knee edge stretches (the hip joint is off the edge). An edge is rigid when
    its length stays within 0.1 % over random poses in the genes' ranges (deterministic).
    Only rigid edges tell the drawing's scale: foreshortening can only shorten them. The
    longest length over the same poses (at least the rest one) bounds an edge's
    projection (Section 4.1.3's normalization).

    Returns:
        ``(rigid, longest)``: rigid lengths, infinite for the edges that stretch, and the
        longest lengths.
    """
    b = model.bounds(np.zeros(3), 0.0)
    u = np.random.default_rng(0).random((samples, b.shape[0]))
    heads, tails, _ = model.forward(b[:, 0] + u * (b[:, 1] - b[:, 0]), rigid=False)
    joints = model.figure.joint_positions(heads, tails)
    fig = model.figure
    child = np.flatnonzero(fig.joint_parents >= 0)
    d = np.linalg.norm(joints[:, child] - joints[:, fig.joint_parents[child]], axis=-1)
    out = np.full(fig.n_joints, np.inf)
    rigid = np.ptp(d, axis=0) <= 1e-3 * np.maximum(lengths[child], 1e-9)
    out[child[rigid]] = lengths[child[rigid]]
    longest = lengths.copy()
    longest[child] = np.maximum(lengths[child], d.max(0))
    return out, longest


def _nearest_scales(camera: Camera, root: np.ndarray, figure: CharacterFigure,
                    lengths: np.ndarray) -> np.ndarray:
    """Largest image scale of the edge ending at each joint, pixels per unit, ``(J,)``.

    An edge can come no nearer the eye than the root's depth less the length of the
    stick path from the root to its end (Section 4.1.3's maximum projection, with the
    root at its estimated depth); at most 4 times the root's scale.
    """
    z = float(camera.depth(root[None])[0])
    ppu = camera.pixels_per_unit(z)
    if not camera.is_perspective:
        return np.full(figure.n_joints, ppu)
    reach = np.zeros(figure.n_joints)
    for j in range(1, figure.n_joints):  # parents first
        reach[j] = reach[figure.joint_parents[j]] + lengths[j]
    return ppu * z / np.maximum(z - reach, 0.25 * z)


def _free_of_environment(figure: CharacterFigure, skeleton: Skeleton, caps: Capsules,
                         env_pins: tuple[EnvPin, ...], height: float) -> np.ndarray:
    """Capsules checked against the environment (Eq. 11), shape ``(c,)`` bool.

    A joint pinned to a surface rests on it with the part below it: the short end chain
    under an ankle or a wrist (the foot, the hand; less than 15 % of the height) is left
    out. A pinned joint with a long chain below it (a pelvis lying on the floor) leaves
    out its own bone only: the limbs it carries still may not pass through the floor.
    """
    out = np.ones(len(caps.bones), bool)
    for p in env_pins:
        if figure.joint_at_tail[p.joint]:
            continue
        b = int(figure.joint_bones[p.joint])
        below = skeleton.descendants(b)
        if skeleton.lengths[below].sum() > 0.15 * height:
            below = np.array([b])
        out &= ~np.isin(caps.bones, below)
    return out


def _depth_for_scale(camera: Camera, ppu: float, pixel: np.ndarray) -> float:
    """View depth at which the image scale is ``ppu`` pixels per unit."""
    if not camera.is_perspective:
        return float(camera.depth(camera.rays(pixel[None])[0])[0] + 5.0)
    d0 = 5.0
    return d0 * camera.pixels_per_unit(d0) / ppu


def _pinned_root_depth(camera: Camera, pixel: np.ndarray, env_pins: tuple[EnvPin, ...],
                       pelvis: int, up: np.ndarray) -> float:
    """View depth of the root when joints are pinned to the environment.

    With the pelvis among them (a body lying on them) it is their mean depth. Otherwise,
    when some pins rest on up-facing surfaces (the support of Eqs. 7-8), the pelvis is
    taken above them: the point of its eye ray
    nearest the vertical line through their centroid. Only when no pin faces up (or the
    eye ray is vertical) does the root take the pins' mean depth. A body standing on
    its feet seen from above has its pelvis nearer the eye than its feet: on the 40 CMU
    drawings the pins' mean depth put it 0.31 m (median) behind its true depth, the
    vertical line 0.13 m.

    Args:
        camera: The view.
        pixel: The drawn pelvis, shape ``(2,)``.
        env_pins: The environment pins (targets resolved).
        pelvis: The pelvis' stick joint index.
        up: World up, shape ``(3,)``.

    Returns:
        The depth, world units along the view axis.
    """
    targets = np.array([p.target for p in env_pins])
    if any(p.joint == pelvis for p in env_pins):
        return float(np.mean(camera.depth(targets)))
    standing = [p.target for p in env_pins if p.normal @ up > np.cos(UP_ANGLE)]
    o, r = (a[0] for a in camera.rays(pixel[None]))
    r_flat = r - up * (r @ up)
    if standing and r_flat @ r_flat > 1e-6:
        w = o - np.mean(standing, axis=0)
        t = -((w - up * (w @ up)) @ r_flat) / (r_flat @ r_flat)
        if t > 0.0:
            return float(camera.depth((o + t * r)[None])[0])
    return float(np.mean(camera.depth(targets)))


def _initial_population(model: PoseModel, bounds: np.ndarray, n: int, stick: StickFigure,
                        camera: Camera, root_center: np.ndarray, facing: str,
                        rng: np.random.Generator) -> np.ndarray:
    """Random individuals whose root orientation agrees with the drawn spine."""
    fig, sk = model.figure, model.skeleton
    G = bounds.shape[0]
    pop = bounds[:, 0] + rng.random((n, G)) * (bounds[:, 1] - bounds[:, 0])
    pop[:, :3] = root_center + rng.normal(scale=0.05, size=(n, 3))
    rest = fig.rest_joints(sk)
    top = spine_joint(fig)
    spine_rest = normalize(rest[top] - rest[0])
    upright = _upright(fig, sk)
    if not upright:
        # A horizontal body's legs, nearer or farther than its root, bias the depth read
        # from the drawing's scale: spread the roots along the eye ray over the box.
        o, ray = camera.rays(stick.points[:1])
        half = 0.5 * float(np.min(bounds[:3, 1] - bounds[:3, 0]))
        pop[:, :3] += ray[0] * rng.uniform(-half, half, size=(n, 1))
    s2 = stick.points[top] - stick.points[0]
    s2 = s2 / max(np.linalg.norm(s2), 1e-9)
    V = camera.view_matrix[:3, :3]
    right, up, back = V[0], V[1], V[2]
    # The spine's depth: an upright body's is mostly in the view plane; a horizontal one
    # (a quadruped's) points anywhere up to 75 degrees out of it.
    z = (rng.normal(scale=0.6, size=n) if upright
         else np.tan(rng.uniform(-1.3, 1.3, size=n)))
    d = normalize(s2[0] * right + s2[1] * up + z[:, None] * back)
    G0 = rotation_between(spine_rest, d)
    # The roll about the spine: the front faces the viewer or, for a body whose spine
    # runs along its facing (a quadruped), its back stays up in the view.
    if upright:
        fwd = G0 @ fig.forward
        want = back if facing == "front" else -back  # towards the viewer
    else:
        fwd, want = G0 @ fig.up, up
    want = normalize(want - d * (d @ want)[:, None])
    fwd = normalize(fwd - d * np.sum(fwd * d, 1)[:, None])
    psi = np.arctan2(np.sum(np.cross(fwd, want) * d, 1), np.sum(fwd * want, 1))
    psi += rng.normal(scale=0.5, size=n)
    wild = rng.random(n) < 0.2
    psi[wild] = rng.uniform(-np.pi, np.pi, wild.sum())
    R = exp_map(d * psi[:, None]) @ G0
    pop[:, 3:6] = log_map(R)
    pop = np.clip(pop, bounds[:, 0], bounds[:, 1])
    return lift_population(model, pop, bounds, stick, camera, rng)


def _spine_flipped(model: PoseModel, x: np.ndarray, bounds: np.ndarray, camera: Camera
                   ) -> np.ndarray | None:
    """``x`` with its main axis' depth mirrored: the body bent the other way along the eye.

    The eye ray ``o + t r`` through the spine joint ``s`` meets the sphere about the
    pelvis ``p`` of radius ``|s - p|`` twice: at ``s`` and at its depth mirror ``s'``,
    ``t' = -2 r . (o - p) - t_s`` (the two roots of the sphere's quadratic sum to
    ``-2 r . (o - p)``). The root turns (about the pelvis) by the smallest rotation taking
    ``s - p`` to ``s' - p``: the spine joint projects exactly where it did, under
    perspective too, on the other side of the sphere along its ray. (Mirroring about the
    pelvis' eye ray instead, ``d - 2 (d . r) r``, is exact only for an orthographic view:
    on two CMU drawings of bodies bent 40-80 degrees out of the view plane it moved the
    neck 41 and 53 pixels.) A spine across its top's eye ray mirrors onto
    itself: when the root genes move by no more than :data:`MIRROR_MIN` there is no other
    pose, and None is returned instead of a copy of ``x``.

    Args:
        model: Genes -> bones.
        x: The pose, shape ``(G,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        camera: The view.

    Returns:
        The flipped genes, shape ``(G,)``, or None.
    """
    fig = model.figure
    heads, tails, _ = model.forward(np.asarray(x, float)[None])
    joints = fig.joint_positions(heads, tails)[0]
    top = joints[spine_joint(fig)]
    o, r = (a[0] for a in camera.rays(camera.project(top[None])))
    # The spine joint's eye ray meets the sphere about the pelvis at the joint and at its
    # mirror: the roots of |o + t r - pelvis|^2 = |top - pelvis|^2 sum to -2 r.(o - pelvis).
    t = -2.0 * (r @ (o - joints[0])) - (top - o) @ r
    d = normalize(top - joints[0])
    turn = rotation_between(d, normalize(o + t * r - joints[0]))
    out = np.array(x, float)
    out[3:6] = log_map(turn @ exp_map(out[3:6]))
    out = np.clip(out, bounds[:, 0], bounds[:, 1])
    return out if np.linalg.norm(out[:6] - np.asarray(x, float)[:6]) > MIRROR_MIN else None


def _distinct(joints: np.ndarray, order: np.ndarray, k: int, min_dist: float,
              reduce=np.max) -> list[int]:
    """Greedy pick of up to ``k`` indices, in ``order``, of poses that differ.

    Two poses differ when ``reduce`` (max: some joint, a single forearm flipped in depth;
    mean: the whole body) of their joint distances exceeds ``min_dist``.
    """
    chosen: list[int] = []
    for i in order:
        if all(reduce(np.linalg.norm(joints[i] - joints[c], axis=1)) > min_dist
               for c in chosen):
            chosen.append(int(i))
        if len(chosen) == k:
            break
    return chosen


def _flip_descent(objective: StickObjective, candidates: list[RefineResult],
                  score: np.ndarray, bounds: np.ndarray, rank: RankWeights, apart: float
                  ) -> tuple[list[RefineResult], np.ndarray]:
    """Flip the most plausible candidate's limbs in depth, one at a time: a local search.

    The genetic search and the depth flips of :mod:`.lifting` reach most depth
    interpretations, but a flipped limb scores badly until it is refined (its hand in the
    floor, its twist far from comfort) and the enumeration is screened before refinement:
    a lying figure kept a forearm or a whole arm on the wrong side of the eye ray (the
    sample scene at some seeds, 5-10 % of the height off). Each round flips, in the best
    candidate, each limb and each limb's end bone (:func:`.lifting.limb_flips`), refines
    the flips (:data:`FLIP_EVALUATIONS` Gauss-Newton evaluations) and keeps those more
    plausible than the best by more than :data:`FLIP_MARGIN` of its score; the next round
    starts from the new best. A flip within ``apart`` of a candidate already refined (a
    bone drawn at full length has its near and far ends together; a bone flipped back)
    is not refined. A flip that moves a pinned joint off its pin is first moved back
    along the eye ray (:func:`_pivot_on_pins`: the limb turned about its pinned end).
    :func:`solve_stick` runs it only with environment pins or a seat,
    which fix the body's depth (without them the flips slid the body along the eye ray).

    Args:
        objective: The energy.
        candidates: Refined candidates.
        score: Their plausibility (:func:`.ranking.plausibility`), shape ``(n,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        rank: Weights of the plausibility score.
        apart: Smallest largest-joint distance (world units) from every candidate.

    Returns:
        The candidates with the kept flips appended, and their scores.
    """
    model, fig = objective.model, objective.model.figure
    candidates, score = list(candidates), np.asarray(score, float)
    for _ in range(FLIP_ROUNDS):
        top = int(np.argmin(score))
        flips = limb_flips(model, candidates[top].x, bounds, objective.stick,
                           objective.camera)
        flips = _pivot_on_pins(objective, candidates[top].x, flips, bounds)
        xs = np.array([r.x for r in candidates])
        heads, tails, _ = model.forward(np.vstack([xs, flips]), rigid=False)
        joints = fig.joint_positions(heads, tails)
        gap = np.linalg.norm(joints[len(xs):, None] - joints[None, :len(xs)], axis=-1)
        new = flips[gap.max(-1).min(-1) > apart]
        if not len(new):
            break
        moved = refine_batch(objective, new, bounds, max_evaluations=FLIP_EVALUATIONS)
        s_moved, _ = plausibility(objective, np.array([r.x for r in moved]), rank)
        better = np.flatnonzero(s_moved < (1.0 - FLIP_MARGIN) * score[top])
        if not len(better):
            break
        candidates += [moved[i] for i in better]
        score = np.concatenate([score, s_moved[better]])
    return candidates, score


def _pivot_on_pins(objective: StickObjective, x: np.ndarray, flips: np.ndarray,
                   bounds: np.ndarray) -> np.ndarray:
    """Depth flips of pinned limbs moved along the pelvis' eye ray back onto their pins.

    A limb flipped in depth about its shoulder or hip (:func:`.lifting.limb_flips`, and
    the near/far choices of :func:`.lifting.depth_flips`) moves its end to the other side
    of the sphere of its length. When that end is pinned to the environment (Eq. 10: an
    ankle on the floor, a hand on it) the flip leaves its pin by about twice the limb's
    depth and scores badly however it is refined, while the same limb flipped about its
    pinned end keeps it: the body then moves along the eye ray instead, each joint
    staying on its drawn ray to first order. The root of such a flip is translated along
    the eye ray ``r`` through the posed pelvis of ``x`` by the least-squares shift
    ``t = mean_k (target_k - p_k) . r`` over the pinned joints ``p_k`` the flip moved
    (world units; the pelvis projects where it did). Flips that move no pinned joint are
    returned as they are, and nothing moves when the root joint (the pelvis) is pinned
    itself (lying; seated, the hips on the seat): its pin fixes the body's depth.

    Args:
        objective: The energy (its pins, model and camera).
        x: The pose the flips were made from, shape ``(G,)``.
        flips: Flipped poses, shape ``(k, G)``.
        bounds: Gene bounds, shape ``(G, 2)`` (the root's translation stays in its box).

    Returns:
        The flips, shape ``(k, G)``, those that moved a pinned joint shifted.
    """
    pins = objective.env_pins
    if not len(flips) or not pins or any(p.joint == 0 for p in pins):  # 0: the root joint
        return flips
    model, cam = objective.model, objective.camera
    fig = model.figure
    heads, tails, _ = model.forward(np.vstack([x[None], flips]), rigid=False)
    joints = fig.joint_positions(heads, tails)
    r = normalize(joints[0, 0] - cam.rays(cam.project(joints[0, :1]))[0][0])
    idx = np.array([p.joint for p in pins])
    targets = np.array([p.target for p in pins])
    moved = np.linalg.norm(joints[1:, idx] - joints[0, idx], axis=-1) > 1e-6
    gap = (targets[None] - joints[1:, idx]) @ r
    t = np.sum(np.where(moved, gap, 0.0), 1) / np.maximum(moved.sum(1), 1)
    out = flips.copy()
    out[:, :3] = np.clip(out[:, :3] + t[:, None] * r, bounds[:3, 0], bounds[:3, 1])
    return out


def _refine_short(objective: StickObjective, X: np.ndarray, bounds: np.ndarray
                  ) -> list[RefineResult]:
    """A few Gauss-Newton steps of each candidate ``(K, G)``, together.

    Enough to settle each in its basin (:func:`.batch.refine_batch`).
    """
    return refine_batch(objective, X, bounds, max_evaluations=SHORT_EVALUATIONS)


def _refine_long(objective: StickObjective, X: np.ndarray, bounds: np.ndarray,
                 inp: StickInput) -> list[RefineResult]:
    """L-BFGS-B of each pose ``(K, G)``, then Gauss-Newton polishing; the lower of the two.

    Both refine the poses together (:func:`.batch.refine_lbfgsb_batch`,
    :func:`.batch.refine_batch`).
    """
    lb = refine_lbfgsb_batch(objective, X, bounds, max_iterations=inp.refine_iterations)
    if inp.polish_evaluations <= 0 or not lb:
        return lb
    polished = refine_batch(objective, np.array([r.x for r in lb]), bounds,
                            max_evaluations=inp.polish_evaluations)
    return [p if p.energy < r.energy else r for r, p in zip(lb, polished, strict=True)]


def solve_stick(inp: StickInput) -> StickResult:
    """Pose the character from a drawn stick figure (BLAS single-threaded meanwhile).

    Args:
        inp: The problem.

    Returns:
        Distinct suggestions, best first, with diagnostics.

    Raises:
        InputError: The drawing does not match the character, or bad pins.
        SolverError: No finite solution was found.
    """
    with single_thread_blas(), row_threads(inp.threads):
        return _solve(inp)


def _solve(inp: StickInput) -> StickResult:
    """The body of :func:`solve_stick` (same arguments, result and errors)."""
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    if inp.facing not in ("front", "back"):
        raise InputError(f"Facing must be 'front' or 'back', not {inp.facing!r}.")
    sk, cam = inp.skeleton, inp.camera
    figure, humanoid = character_figure(sk, inp.ik_limits, inp.roles)
    lengths = figure.edge_lengths(sk)
    stick = inp.stick or stick_figure_from_strokes(inp.strokes, figure, inp.snap_radius,
                                                   inp.facing, lengths)
    warnings = [f"Left and right {p} look alike from this view: use Swap Sides if they are "
                "wrong." for p in stick.ambiguous_sides]
    if not humanoid:
        warnings.append("The character is not a recognised humanoid: its stick figure was "
                        "matched by topology (one line per bone).")
    base = inp.base_pose or Pose.identity(sk.n_bones)
    model = PoseModel(sk, figure, base)
    caps = _moving_pairs(model, capsules_from_mesh(sk, inp.mesh_vertices, inp.mesh_weights))
    offsets = pin_offsets(figure, sk, caps, inp.mesh_vertices, inp.mesh_weights)
    standing = standing_joints(figure, sk, caps, inp.mesh_vertices, inp.mesh_weights)
    env_pins, limb_pins = resolve_pins(figure, stick, inp.env_pins, inp.limb_pins, offsets,
                                       cam, standing)
    up = figure.up
    height = float(np.ptp(np.concatenate([sk.rest_heads, sk.rest_tails]) @ up))
    rest_joints = figure.rest_joints(sk)
    pelvis_j = 0
    base_root = sk.forward(base).heads[figure.root_bone]
    timings["setup"] = time.perf_counter() - t_start

    # Root placement: seat, pinned contacts or drawing scale.
    t0 = time.perf_counter()
    env = inp.environment
    seat = None
    radius = np.zeros(sk.n_bones)
    radius[caps.bones] = caps.radii
    hip_r = float(max(radius[sk.children(figure.root_bone)].max(initial=0.0),
                      radius[figure.root_bone]))
    low = float(np.min(np.concatenate([sk.rest_heads, sk.rest_tails]) @ up))
    knee_h = (float(rest_joints[figure.joint("knee.L")] @ up) - low if humanoid
              else 0.5 * float(rest_joints[0] @ up - low))
    seat_pixel = stick.points[pelvis_j]
    if inp.use_contact and len(stick.contacts):
        seat_pixel = stick.contacts[0]
    rigid, longest = _edge_spans(model, lengths)
    drawn = stick.drawn_edges()[:, 1]
    ppu = drawing_scale(stick, rigid if np.isfinite(rigid[drawn]).any() else lengths)
    depth_guess = _depth_for_scale(cam, ppu, stick.points[pelvis_j])
    root_range = 0.3 * height
    grid, grid_task = None, None
    # Distances are looked up to beyond the thickest capsule (a capsule thicker than the
    # grid's reach would read as always penetrating).
    reach = max(0.2, 1.1 * float(caps.radii.max(initial=0.0)))
    if env is not None and len(env.triangles):
        o, d = cam.rays(seat_pixel[None])
        probe = cam.unproject_at_depth(stick.points[pelvis_j][None], depth_guess)[0]
        dist = float(np.linalg.norm(probe - o[0]))
        # The distance grid (for a collision-free spot on the seat) only once a seat is
        # found: standing or lying, it is built around the root instead.
        if find_seat(env, o[0], d[0], knee_h, hip_r, None, near=0.5 * dist, far=1.6 * dist):
            grid = distance_grid(env, probe, 0.75 * height, max_distance=reach)
            seat = find_seat(env, o[0], d[0], knee_h, hip_r, grid, near=0.5 * dist,
                             far=1.6 * dist)
    if seat is not None:
        root = seat.point + up * hip_r
        root_range = 0.12 * height
    else:
        depth = depth_guess
        if env_pins:
            depth = _pinned_root_depth(cam, stick.points[pelvis_j], env_pins, pelvis_j, up)
        else:
            # Nothing else fixes the depth (a nearer figure with more foreshortened limbs
            # reprojects as well): keep the root near the drawing's scale.
            root_range = (FREE_ROOT_RANGE if _upright(figure, sk)
                          else FREE_ROOT_RANGE_HORIZONTAL) * height
        root = cam.unproject_at_depth(stick.points[pelvis_j][None], depth)[0]
        if env is not None and len(env.triangles):
            # Built in the worker thread (threads 2) while the genetic search runs: its
            # energy leaves collisions out.
            grid_task = in_background(lambda c: distance_grid(env, c, 0.75 * height,
                                                              max_distance=reach), root)
    stick, factor = normalize_figure(stick, longest,
                                     _nearest_scales(cam, root, figure, longest), pelvis_j)
    if factor < 1.0:
        warnings.append(f"The drawing was scaled by {factor:.2f}: some bones were drawn "
                        "longer than the character's.")
        # The pins' targets lie on the eye rays through the drawn joints: follow them.
        env_pins, limb_pins = resolve_pins(figure, stick, inp.env_pins, inp.limb_pins,
                                           offsets, cam, standing)
    support = [p.target - p.normal * offsets[p.joint] for p in env_pins
               if p.normal @ up > np.cos(UP_ANGLE)]
    # A pinned standing foot supports over its sole along the posed foot, not at its
    # ankle alone (a lying body, its pelvis pinned, does not stand on its feet).
    footprints = []
    if SOLE_SHARE > 0 and not any(p.joint == pelvis_j for p in env_pins):
        for p in env_pins:
            ext = (foot_extents(figure, sk, caps, p.joint, inp.mesh_vertices,
                                inp.mesh_weights)
                   if p.stands and p.normal @ up > np.cos(UP_ANGLE) else None)
            if ext is not None:
                footprints.append(Footprint(
                    p.joint, ext[0], p.target - p.normal * offsets[p.joint],
                    SOLE_SHARE * ext[1], SOLE_SHARE * ext[2]))
    if seat is not None:
        side = normalize(np.cross(up, figure.forward))
        support += [seat.point + side * hip_r, seat.point - side * hip_r]
    env_caps = _free_of_environment(figure, sk, caps, env_pins, height)
    # Seated, the hips rest on the seat's plane (Eq. 10 on the pelvis; free to slide).
    seat_pin = () if seat is None else (EnvPin(pelvis_j, root, up.copy()),)
    # A body whose pelvis the user pinned to a surface lies or rests on it: its balance
    # over the pinned contacts does not rank its interpretations.
    rank = inp.rank
    if any(p.joint == pelvis_j for p in env_pins):
        rank = dataclasses.replace(rank, balance=0.0)
    objective = StickObjective(
        model=model, camera=cam, stick=stick, height=height,
        masses=bone_masses(sk, caps), capsules=caps, env_capsules=env_caps, grid=grid,
        support=np.array(support).reshape(-1, 3), env_pins=env_pins + seat_pin,
        limb_pins=limb_pins, weights=inp.weights, up=up, footprints=tuple(footprints))
    bounds = model.bounds(root - base_root, root_range)
    timings["placement"] = time.perf_counter() - t0

    # Genetic search, then refinement of distinct candidates.
    t0 = time.perf_counter()
    rng = np.random.default_rng(inp.seed)
    init = _initial_population(model, bounds, inp.ga.population, stick, cam,
                               root - base_root, inp.facing, rng)
    ga = genetic_search(
        lambda X: split_rows(lambda Y: objective.evaluate(Y, collision=False)[0], X),
        bounds, init, rng, inp.ga)
    if grid_task is not None:
        objective = dataclasses.replace(objective, grid=grid_task.result())
    timings["genetic"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    # Distinct good individuals of the GA (different basins), shortly refined.
    heads, tails, _ = model.forward(ga.population[:256], rigid=False)
    joints = figure.joint_positions(heads, tails)
    picks = _distinct(joints, np.arange(len(joints)), GA_SEEDS, 0.08 * height, np.mean)
    first = _refine_short(objective, ga.population[picks], bounds)
    # Every depth interpretation (near or far end of each limb bone) of the best ones,
    # ranked by plausibility (:mod:`.ranking`) with the refined ones.
    tops = np.argsort([r.energy for r in first], kind="stable")[:FLIPPED_SEEDS]
    # Each also with its spine's depth mirrored: the search samples spines near the view
    # plane, and a body bent towards the eye or away from it has a twin bent the other way.
    # A spine in the view plane mirrors onto itself: its flips would repeat the seed's.
    # A flip that moves a pinned joint off its pin is moved back along the eye ray
    # (the limb flipped about its pinned end: CMU pinned 11.66 -> 10.97 % first).
    starts = [first[i].x for i in tops]
    mirrored = [_spine_flipped(model, x, bounds, cam) for x in starts]
    starts += [f for f in mirrored if f is not None]
    pool = np.concatenate([[r.x for r in first]] +
                          [_pivot_on_pins(objective, x, depth_flips(model, x, bounds, stick,
                                                                    cam), bounds)
                           for x in starts])
    # Collisions (the costly term) only for the most plausible without them.
    cheap, _ = plausibility(objective, pool, rank, collision=False)
    screened = np.argsort(cheap, kind="stable")[:SCREENED]
    pool = pool[screened]
    score, _ = plausibility(objective, pool, rank)
    heads, tails, _ = model.forward(pool, rigid=False)
    joints = figure.joint_positions(heads, tails)
    picks = _distinct(joints, np.argsort(score, kind="stable"),
                      inp.n_suggestions + EXTRA_CANDIDATES, DISTINCT * height)
    # The refined seeds (the pool's first rows) are not refined again.
    again = [i for i in picks if screened[i] >= len(first)]
    short = dict(zip(again, _refine_short(objective, pool[again], bounds), strict=True))
    second = [first[screened[i]] if screened[i] < len(first) else short[i] for i in picks]
    xs = np.array([r.x for r in second])
    score, _ = plausibility(objective, xs, rank)
    # A local move the genetic search lacks: the most plausible candidate with one limb
    # (or its end bone) flipped in depth, refined before it is compared. Only when the
    # environment fixes the body's depth (pins, a seat): without them nothing does, and
    # the more plausible flips slid the body along the eye ray (CMU without pins: first
    # suggestion 21.4 -> 23.0 % and 21.6 -> 22.2 at two seed sets, pelvis-aligned 11.4 ->
    # 11.6 and 12.3 -> 12.0).
    if env_pins or seat is not None:
        second, score = _flip_descent(objective, second, score, bounds, rank,
                                      DISTINCT * height)
        xs = np.array([r.x for r in second])
    order = np.argsort(score, kind="stable")
    heads, tails, _ = model.forward(xs[order])
    joints = figure.joint_positions(heads, tails)
    best = [order[k] for k in _distinct(joints, np.arange(len(order)), inp.n_suggestions,
                                         DISTINCT * height)]
    # The long refinement (quasi-Newton, then Gauss-Newton) of each suggestion; a
    # candidate far above the best (a limb through the body or the seat) stays an
    # alternative as it is.
    s_best = min(score[i] for i in best)
    hopeless = [score[i] > HOPELESS_RATIO * s_best + HOPELESS_MARGIN for i in best]
    longs = iter(_refine_long(objective, np.array([second[i].x for i, h in
                                                   zip(best, hopeless, strict=True) if not h]
                                                  ).reshape(-1, bounds.shape[0]), bounds, inp))
    refined = [second[i] if h else next(longs) for i, h in zip(best, hopeless, strict=True)]
    timings["refine"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    # Ranked by the refined poses' plausibility: enforcing the pins afterwards spreads
    # the targets' own errors (an ankle lying lower than standing) over every suggestion.
    xs = np.array([r.x for r in refined])
    score, _ = plausibility(objective, xs, rank)
    order = np.argsort(score, kind="stable")
    heads, tails, _ = model.forward(xs[order])
    joints = figure.joint_positions(heads, tails)
    keep = order[_distinct(joints, np.arange(len(xs)), inp.n_suggestions, DISTINCT * height)]
    suggestions = []
    for i in keep:
        xf, pins_f = finish_pose(objective, xs[i], bounds, env_pins, limb_pins)
        xf = settle_unseen_feet(objective, xf, bounds, pins_f)
        suggestions.append(_suggestion(objective, xf, pins_f, float(score[i]), rank))
    if not suggestions or not np.isfinite(suggestions[0].energy):
        raise SolverError("The stick figure solver found no finite solution.",
                          {"generations": ga.generations})
    worst = max(float(np.max(s.pin_residuals, initial=0.0)) for s in suggestions[:1])
    if worst > 0.01:
        warnings.append(f"A pinned joint is {worst * 100:.0f} cm from its target: it is out "
                        "of reach of the drawn pose.")
    timings["finish"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    return StickResult(tuple(suggestions), stick, figure, seat, root, factor, ga.generations,
                       tuple(r.iterations for r in first + second + refined), timings,
                       tuple(warnings))


def _suggestion(objective: StickObjective, x: np.ndarray, env_pins, score: float,
                weights: RankWeights) -> Suggestion:
    """A finished pose with its energy, ranking score, terms and pin residuals."""
    model = objective.model
    heads, tails, _ = model.forward(x[None])
    e, terms = objective.evaluate(x[None])
    _, rank_terms = plausibility(objective, x[None], weights)
    joints = model.figure.joint_positions(heads, tails)[0]
    res = np.array([np.linalg.norm(joints[p.joint] - p.target) for p in env_pins]
                   + [np.linalg.norm(joints[p.joint] - p.target(joints))
                      for p in objective.limb_pins])
    terms = {k: float(v[0]) for k, v in terms.items()}
    terms["foreshortening"] = float(rank_terms["foreshortening"][0])
    return Suggestion(model.to_pose(x), x, float(e[0]), score, terms, joints, res)
