"""Which left/right labels of a 2D embedding the 3D pose supports: the joints' ranges (ours).

An outline does not say which of two symmetric limbs is which: the 2D fit (Gesture3D
Section 5.4) takes the left/right permutation that is least twisted and most
front-facing, a guess. Relabelling symmetric limbs keeps every drawn position, so the
drawing's conformity E_c (Eq. 5) and foreshortening E_v (Eqs. 6-7) stay comparable
across labellings; what tells them apart in 3D is whether the lifted body can take the
pose: a knee bent the wrong way, an elbow bent backwards beyond the shoulder's rotation,
a pelvis turned half round against the chest.

:func:`label_alternatives` forms the relabellings (each limb pair exchanged whole, which
turns its root, or below its upper bone, thigh or upper arm, which crosses or uncrosses
the two limbs), :func:`relabel` applies one to an embedding, and :func:`choose_labels`
lifts each (:func:`.solve3d.solve_pose3d`) and keeps the 2D fit's labels unless an
alternative whose drawing energy does not rise is clearly more plausible
(:func:`pose_cost`: the legs' and arms' ranges of :mod:`.plausibility`, and the twist
between pelvis and chest).

Between labellings the ranges do not tell apart (both within them, or alike out of
them) the one that draws more links as the bind pose shows them is kept
(:func:`bind_links`, E_b's agreement): most drawings change a few limbs and leave the rest
as they are. This is Section 5.4's least twisted permutation read per link on the lifted
labels: the 2D fit reads it as the image's left/right order against the bind pose's, which
a limb swung across its partner in an oblique view reverses (the sample quadruped's front
paw lifted forward, seen from its left and front, was fitted with its front legs crossed
below the shoulders, both moved, whose 3D lift is as plausible as the truth's).

What the ranges cannot decide: the facing. A body seen from its back and labelled as
facing the viewer lifts to the depth mirror image of the truth with left and right
exchanged, a reflection of a body that is itself a body, with the same joint angles:
exactly as plausible. Only perspective (slightly) and depth orders tell the two apart;
the drawing energies do not either (with E_b, the bind pose's pull, on for the fitted
labels and off for a body read as turned round, the turned reading fits better on 36 of
the Adventurer's 40 front drawings, right or wrong). Every pair exchanged at once is
therefore left out by default (``LabelLimits.facing``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import numpy as np

from ...camera import Camera
from ...exceptions import SolverError
from ...skeleton import Pose, Skeleton
from ..consistency import symmetric_limbs
from ..types import Embedding2D, SolvingSkeleton
from . import energies, ordering, plausibility, start
from .solve3d import DepthOptions, Pose3DResult, rest_front, solve_pose3d


@dataclass(frozen=True)
class LabelLimits:
    """Thresholds of the choice between labellings.

    Attributes:
        margin: Smallest plausibility gain, degrees of :func:`pose_cost`, for an
            alternative to replace the 2D fit's labels (the legs' and arms' own margin,
            :class:`.plausibility.LegLimits`).
        energy_rise: Largest relative rise of the drawing energy (E_c plus the weighted
            E_v) over the 2D fit's labels' for an alternative to be considered. 0: the
            relabelled drawing must be fitted at least as well. At 0.1 the 25 traced
            drawings of the sample characters lost 0.07 % of the height (the front run
            10.7 -> 12.5: its fitted legs, 289 degrees out of range, read crossed) for
            no gain on the Adventurer.
        torso_twist: Largest turn between the pelvis's and the chest's fronts about the
            spine that costs nothing, degrees (the spine's axial rotation).
        facing: Also compare every pair exchanged at once (the other facing). Off: the
            ranges cannot tell it (module docstring); on the Adventurer's 40 front
            drawings they chose it in 5, on the sample drawings in 2, one of them wrong
            (the front run, 10.7 -> 25.9 % of the height).
        bind_links: Between labellings the ranges do not tell apart (costs within
            ``margin`` of each other), prefer one that draws at least this many more
            links as the bind pose shows them (:func:`bind_links`, E_b's agreement summed):
            Section 5.4's least twisted permutation, read per link against the bind
            pose's image instead of by the left/right order (module docstring). None:
            the 2D fit's labels stay unless the ranges choose.
        tie_rise: Largest relative rise of the whole energy (E_c, E_v and E_b, as each
            solve minimized it) over the 2D fit's labels' for such a tie to take an
            alternative (ours). The energies of labellings the ranges do not tell
            apart differ by the 2D fit's noise: the quadruped's paw lifted in an oblique
            view, fitted with the front legs crossed, lifts with the truth's labels at
            0.352 against 0.335 for the crossed ones (5% higher; 0.80 against 4.59 % of
            the height). At 0.1 the 25 traced drawings of ``make bench``, fitted with
            the 2D options of the round before (``oriented_conformity`` off), moved in
            one drawing (the oblique sit, 11.23 -> 11.85, both labellings far off); at
            0 the alternative must fit at least as well.
    """

    margin: float = 15.0
    energy_rise: float = 0.0
    torso_twist: float = 60.0
    facing: bool = False
    bind_links: float | None = 0.2
    tie_rise: float = 0.1


@dataclass(frozen=True)
class LabelChoice:
    """The labelling chosen and why.

    Attributes:
        result: The 3D solve of the chosen labelling.
        embedding: The embedding with the chosen labels.
        chosen: Index of the chosen alternative (0: the 2D fit's labels).
        names: Name of each alternative considered (``"as fitted"``, the first pair's
            bones for a pair exchanged whole, ``"thigh.L/thigh.R"``; for one exchanged
            below its upper bone, the first exchanged pair's bones and ``" below"``,
            ``"thigh.L/thigh.R below"``; ``"all pairs"`` with ``LabelLimits.facing``).
        swaps: Joint pairs each alternative exchanges, each ``(k, 2)`` int.
        costs: :func:`pose_cost` of each alternative's solved pose, degrees, ``(n,)``;
            NaN for those not solved (a rig without left/right pairs, a solve that
            raised :class:`SolverError`, or, the fitted labels' pose within ``margin``
            of plausible, one drawing fewer than ``LabelLimits.bind_links`` more links
            as at bind than the fitted labels).
        energies: Drawing energy (E_c plus the weighted E_v) of each, ``(n,)`` (NaN
            where not solved).
        seconds: Wall time of the choice (the fitted labels' solve included unless it
            was given), seconds.
        links: :func:`bind_links` of each alternative, links, ``(n,)`` (empty for a rig
            without left/right pairs).
    """

    result: Pose3DResult
    embedding: Embedding2D
    chosen: int
    names: tuple[str, ...]
    swaps: tuple[np.ndarray, ...]
    costs: np.ndarray
    energies: np.ndarray
    seconds: float
    links: np.ndarray = field(default_factory=lambda: np.zeros(0))


def limb_uppers(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray,
                up: np.ndarray) -> np.ndarray:
    """The solving bones two limbs cross below: thighs and upper arms, ``(k,)`` int.

    The thighs of :func:`.plausibility.leg_chains` and the upper arms of
    :func:`.plausibility.arm_chains`: an arm hung from a clavicle crosses at the elbow.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        up: The rig's rest up, world axes, unit, ``(3,)``.

    Returns:
        Solving-bone indices.
    """
    legs = [c[0] for c in plausibility.leg_chains(skeleton, solving, bones, up)]
    arms = [c[0] for c in plausibility.arm_chains(skeleton, solving, bones, up)]
    return np.array(legs + arms, dtype=int)


def label_alternatives(solving: SolvingSkeleton, facing: bool = False,
                       uppers: np.ndarray | None = None) -> list[tuple[str, np.ndarray]]:
    """The relabellings to compare: each limb pair alone, whole or below its upper bone.

    The limb pairs are :func:`..consistency.symmetric_limbs`' (a limb from the first
    symmetric joint below the body's axis, e.g. a hip head, down to its end). A whole
    pair exchanged turns that pair's root (a pelvis drawn facing the other way); the pair
    below its upper bone (the knees, ankles and toes, the hips kept; the elbows and
    hands, the shoulders kept) reads two limbs drawn crossed as uncrossed, or the
    reverse. A rig with a single limb pair (two legs and no arms) has no whole exchange
    but with ``facing``: that is every pair at once.

    Args:
        solving: The solving skeleton.
        facing: Also every pair at once (``"all pairs"``: the character seen from its
            other side), which the joints' ranges cannot tell from the 2D fit's labels
            (see the module docstring).
        uppers: Solving bones whose tails a limb's exchange below starts at
            (:func:`limb_uppers`). None, or a limb without one of them: the limb's
            first bone (the thigh, or an arm's clavicle where the rig has one).

    Returns:
        ``[(name, joint pairs to exchange (k, 2) int)]``, the 2D fit's labels first
        (no pairs); empty pairs only there.
    """
    limbs = symmetric_limbs(SimpleNamespace(solving=solving))
    out = [("as fitted", np.zeros((0, 2), int))]
    if not limbs:
        return out
    if facing:
        out.append(("all pairs", np.concatenate(limbs)))
    parent = np.asarray(solving.joint_parent)
    ends = set() if uppers is None else {int(solving.tail_joint[int(k)]) for k in uppers}
    for limb in limbs:
        a, b = (solving.joint_bones[int(j)].rpartition(" ")[0] for j in limb[0])
        if len(limbs) > 1:
            out.append((f"{a}/{b}", limb))
        first = [int(j) for j in limb[1:, 0] if int(j) in ends][:1] or (
            [int(limb[1, 0])] if len(limb) > 1 else [])
        if first:
            # The limbs below their upper bones: two limbs drawn crossed, or uncrossed.
            below = limb[[first[0] in ordering.ancestors(parent, int(j)) for j in limb[:, 0]]]
            c, d = (solving.joint_bones[int(j)].rpartition(" ")[0] for j in below[0])
            out.append((f"{c}/{d} below", below))
    return out


def relabel(embedding: Embedding2D, pairs: np.ndarray) -> Embedding2D:
    """The embedding with the joints of ``pairs`` exchanged (same drawn positions).

    Every joint-indexed field moves with its label (position, visibility, radius, side,
    matched samples); so do the bones ending at exchanged joints (their matched contour
    pieces) and the occlusions between them.

    Args:
        embedding: The 2D embedding.
        pairs: Joint pairs to exchange, ``(k, 2)`` int.

    Returns:
        The relabelled embedding.
    """
    s = embedding.solving
    pairs = np.asarray(pairs, int).reshape(-1, 2)
    perm = np.arange(s.n_joints)
    perm[pairs[:, 0]], perm[pairs[:, 1]] = pairs[:, 1], pairs[:, 0]
    tails = np.asarray(s.tail_joint)
    bone_of = np.full(s.n_joints, -1)
    bone_of[tails] = np.arange(s.n_bones)
    bperm = bone_of[perm[tails]]
    bperm = np.where(bperm >= 0, bperm, np.arange(s.n_bones))

    def joints(field):
        return field[perm] if len(field) == s.n_joints else field

    return replace(
        embedding,
        joints2d=embedding.joints2d[perm],
        joint_visible=joints(np.asarray(embedding.joint_visible)),
        joint_radius=joints(np.asarray(embedding.joint_radius)),
        joint_side=joints(np.asarray(embedding.joint_side)),
        joint_segments=(tuple(embedding.joint_segments[int(j)] for j in perm)
                        if len(embedding.joint_segments) == s.n_joints
                        else embedding.joint_segments),
        bone_segments=tuple(embedding.bone_segments[int(k)] for k in bperm),
        bone_segment_sides=tuple(embedding.bone_segment_sides[int(k)] for k in bperm),
        occlusions=tuple(replace(o, front_bone=int(bperm[o.front_bone]),
                                 back_bone=int(bperm[o.back_bone]))
                         for o in embedding.occlusions),
    )


def _torso_chain(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray,
                 up: np.ndarray) -> tuple[int, int] | None:
    """Full-skeleton ``(pelvis, chest)``: the legs' parent and the arms' chest, or None."""
    legs = plausibility.leg_chains(skeleton, solving, bones, up)
    arms = plausibility.arm_chains(skeleton, solving, bones, up)
    if not legs or not arms:
        return None
    pelvis = int(skeleton.parents[int(bones[legs[0][0]])])
    chest = int(arms[0][2])
    return None if pelvis < 0 or pelvis == chest else (pelvis, chest)


def torso_twist(skeleton: Skeleton, pose: Pose, torso: tuple[int, int], front: np.ndarray,
                up: np.ndarray) -> float:
    """Turn between the pelvis's and the chest's fronts about the chest's up, degrees.

    Args:
        skeleton: The full skeleton.
        pose: The pose.
        torso: Full-skeleton ``(pelvis, chest)``.
        front: The character's front in the rest pose, unit, ``(3,)``.
        up: The rig's rest up, unit, ``(3,)``.

    Returns:
        The angle in ``[0, 180]`` (0 when either front lies along the chest's up).
    """
    state = skeleton.forward(pose)
    carry = [state.frames[b] @ skeleton.rest_frames[b].T for b in torso]
    axis = carry[1] @ up
    fronts = [c @ front for c in carry]
    flat = [f - float(f @ axis) * axis for f in fronts]
    norms = [float(np.linalg.norm(f)) for f in flat]
    if min(norms) < 1e-6:
        return 0.0
    cos = float(flat[0] @ flat[1]) / (norms[0] * norms[1])
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def pose_cost(skeleton: Skeleton, solving: SolvingSkeleton, bones: np.ndarray, pose: Pose,
              front: np.ndarray, up: np.ndarray, limits: LabelLimits = LabelLimits()
              ) -> float:
    """How far a pose lies outside the body's joint ranges, degrees (ours).

    The sum of :func:`.plausibility.leg_cost` over the legs and
    :func:`.plausibility.arm_cost` over the arms, each read on its solved pelvis or chest,
    and the twist between pelvis and chest beyond ``limits.torso_twist``.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton.
        bones: Full-skeleton index of each solving bone, ``(m,)``.
        pose: The pose to score.
        front: The character's front in the rest pose, unit, world axes, ``(3,)``.
        up: The rig's rest up, unit, ``(3,)``.
        limits: The torso's range.

    Returns:
        The cost, degrees (0 within every range).
    """
    cost = float(np.sum(plausibility.leg_costs(skeleton, solving, bones, pose, front, up)))
    cost += float(np.sum(plausibility.arm_costs(skeleton, solving, bones, pose, front, up)))
    torso = _torso_chain(skeleton, solving, bones, up)
    if torso is not None:
        cost += max(0.0, torso_twist(skeleton, pose, torso, front, up) - limits.torso_twist)
    return cost


def _rolled_rest(embedding: Embedding2D, frame: energies.ViewFrame,
                 body_up: str | None = None) -> np.ndarray:
    """The solving skeleton's rest joints rolled as the body is drawn, ``(J, 3)``.

    Turned about the origin by ``body_up``'s roll (default ``Embedding2D.body_up``;
    :func:`.start.view_roll`): the link vectors and left/right pairs the label choice
    reads, as the 3D step's rolled bind pose (:func:`.start.rolled_bind`) shows them.
    """
    rest = np.asarray(embedding.solving.rest_joints, float)
    return rest @ start.view_roll(frame.forward, body_up or embedding.body_up).T


def bind_links(embedding: Embedding2D, frame: energies.ViewFrame,
               options: DepthOptions, body_up: str | None = None) -> float:
    """How many links the embedding draws as the bind pose shows them (ours).

    The sum over the joint tree's links of E_b's agreement
    (:func:`.energies.bind_agreement`, ``DepthOptions.bind_sigma``): 1 for a link drawn
    exactly as in the bind pose seen in the view (rolled as the body is drawn,
    ``Embedding2D.body_up``), falling off with the image distance between the two link
    vectors.

    Args:
        embedding: The 2D embedding.
        frame: The view frame (:func:`.solve3d.rest_front`).
        options: 3D parameters (``bind_sigma``).
        body_up: The Body Up the 3D step applies (:func:`.start.applied_body_up`;
            default ``Embedding2D.body_up``).

    Returns:
        The summed agreement, links, in ``[0, L]``.
    """
    s = embedding.solving
    a, b = energies.joint_links(np.asarray(s.joint_parent))
    rest = _rolled_rest(embedding, frame, body_up)
    height = float(np.ptp(rest, axis=0).max())
    return float(energies.bind_agreement(embedding.joints2d, a, b, rest[b] - rest[a], frame,
                                         height, options.bind_sigma).sum())


def choose_labels(skeleton: Skeleton, embedding: Embedding2D, camera: Camera,
                  pose: Pose | None = None, *, options: DepthOptions | None = None,
                  limits: LabelLimits = LabelLimits(), fitted: Pose3DResult | None = None,
                  **solve_kwargs) -> LabelChoice:
    """Lift the embedding under each labelling and keep the most plausible (ours).

    Each alternative of :func:`label_alternatives` is solved
    (:func:`.solve3d.solve_pose3d` with ``options`` and ``solve_kwargs``) and scored by
    :func:`pose_cost`. The 2D fit's labels are kept unless an alternative whose drawing
    energy is at most ``limits.energy_rise`` above theirs costs at least
    ``limits.margin`` less; of those, the least costly. Failing that, an alternative
    whose whole energy (E_c, E_v and E_b, as its solve minimized them) rises by at most
    ``limits.tie_rise``, whose cost is within ``limits.margin`` of the fitted labels'
    and which draws at least ``limits.bind_links`` more links as the bind pose shows
    them (:func:`bind_links`) is taken, the one drawing most (ours). When
    the fitted labels' pose costs less than ``limits.margin`` only the alternatives
    drawing that much more as at bind are solved. An alternative that reverses the
    drawn facing (:func:`.start.drawn_facing`: the hips exchanged whole) is not solved
    unless ``limits.facing``: it is the other facing for the whole figure. Nor is one
    that draws more links longer than ``DepthOptions.max_drawn_ratio`` of their bones
    than the fitted labels do: E_c weighs such links a tenth (a misplaced joint), which
    would lower its energy for drawing worse.

    Args:
        skeleton: The full skeleton.
        embedding: The 2D embedding as fitted.
        camera: The view.
        pose: Current pose (:func:`.solve3d.solve_pose3d`).
        options: 3D parameters.
        limits: The choice's thresholds.
        fitted: The solve of the fitted labels, when already done.
        **solve_kwargs: ``lock_rotation``, ``ik_limits``, ``pinned``, ``limit_axes``.

    Returns:
        The choice, with every alternative's cost and energy (NaN where not solved).

    Raises:
        SolverError: The fitted labels' solve failed (an alternative's failure only
            leaves it out).
    """
    opts = options or DepthOptions()
    s = embedding.solving
    t0 = time.perf_counter()
    frame, up, front = rest_front(embedding, camera, opts)
    alternatives = label_alternatives(
        s, limits.facing, limb_uppers(skeleton, s, np.asarray(s.bones), up))
    names = tuple(n for n, _ in alternatives)
    swaps = tuple(p for _, p in alternatives)
    base = fitted or solve_pose3d(skeleton, embedding, camera, pose, options=opts,
                                  **solve_kwargs)
    costs = np.full(len(alternatives), np.nan)
    energy = np.full(len(alternatives), np.nan)
    energy[0] = base.e_conformity + base.e_foreshortening
    if front is None:  # no left/right pairs: nothing to relabel
        return LabelChoice(base, embedding, 0, names, swaps, costs, energy,
                           time.perf_counter() - t0)
    costs[0] = pose_cost(skeleton, s, base.bones, base.pose, front, up, limits)
    embeddings = [embedding] + [relabel(embedding, p) for p in swaps[1:]]
    # The bind pose as the 3D step rolls it (upright when a pinned root holds the body).
    body_up = start.applied_body_up(s, embedding.body_up, solve_kwargs.get("pinned"))
    agree = np.array([bind_links(e, frame, opts, body_up) for e in embeddings])
    # The facing (every pair at once) is the 2D fit's front-facing choice, not a limb's
    # crossing: the agreement does not re-choose it.
    gains = (agree >= agree[0] + limits.bind_links if limits.bind_links is not None
             else np.zeros(len(agree), bool)) & (np.array(names) != "all pairs")
    # A relabelling that turns the drawn facing round (the hips exchanged whole reverse
    # the image order :func:`.start.drawn_facing` reads) is the facing in disguise, which
    # the ranges cannot tell either (module docstring): it is left out as "all pairs" is.
    # ``admitted``: the labellings these two rules let be solved (the fitted first).
    admitted = np.ones(len(embeddings), bool)
    if opts.read_facing and not limits.facing:
        rest = _rolled_rest(embedding, frame, body_up)
        facing = np.array([start.drawn_facing(s, e.joints2d, rest, frame, body_up=body_up)
                           for e in embeddings])
        admitted = facing == facing[0]
    # A labelling that draws more links longer than their bones can be drawn
    # (``DepthOptions.max_drawn_ratio``, E_c's sign of a misplaced joint, Eq. 5) than the
    # fitted labels is no reading of the drawing: E_c weighs those links a tenth, which
    # lowers its energy, not its error (ours).
    a, b = energies.joint_links(np.asarray(s.joint_parent))
    rest = np.asarray(s.rest_joints, float)
    lengths = np.linalg.norm(rest[b] - rest[a], axis=1)
    too_long = np.array([int(np.sum(energies.foreshortening_ratios(
        e.joints2d, a, b, lengths, frame.scale) > opts.max_drawn_ratio)) for e in embeddings])
    admitted &= too_long <= too_long[0]
    gains &= admitted
    plausible = costs[0] < limits.margin
    if plausible and not np.any(gains):
        # No labelling can cost ``margin`` less (costs are never negative), none draws
        # more as at bind: the others are not solved.
        return LabelChoice(base, embedding, 0, names, swaps, costs, energy,
                           time.perf_counter() - t0, agree)
    results = [base]
    # Joints a T-junction read from the drawing turned (an enforced order) keep their
    # labels: the drawing decided that limb (ours).
    turned = ordering.turned_joints(base.ordering)
    for k, pairs in enumerate(swaps[1:], start=1):
        emb = embeddings[k]
        if (np.isin(np.asarray(pairs), turned).any() or (plausible and not gains[k])
                or not admitted[k]):
            results.append(base)
            continue
        try:
            res = solve_pose3d(skeleton, emb, camera, pose, options=opts, **solve_kwargs)
        except SolverError:
            # An alternative is optional: one no QP solves is left out (NaN), the
            # Pose goes on with the others.
            results.append(base)
            continue
        results.append(res)
        energy[k] = res.e_conformity + res.e_foreshortening
        costs[k] = pose_cost(skeleton, s, res.bones, res.pose, front, up, limits)
    fits = energy <= (1.0 + limits.energy_rise) * energy[0] + 1e-12
    ok = fits & (costs <= costs[0] - limits.margin)
    chosen = int(np.argmin(np.where(ok, costs, np.inf))) if np.any(ok) else 0
    # Between labellings the ranges do not tell apart, the drawing's fit is the whole
    # energy each solve minimized, E_b included: the labelling drawing more links as at
    # bind has E_b pull them there, which raises its E_c + E_v (ours; the quadruped's
    # paw lifted in an oblique view: 0.276 against 0.254 with one 2D fit, 0.300 against
    # 0.304 with another, the truth's labels both times). Within ``tie_rise`` the
    # energies are the 2D fit's noise, not a reading of the drawing.
    whole = energy + np.array([r.e_bind for r in results])
    tie = (whole <= (1.0 + limits.tie_rise) * whole[0] + 1e-12) & gains & (
        np.abs(costs - costs[0]) < limits.margin)
    if not np.any(ok) and np.any(tie):
        # The ranges do not tell the labellings apart: the one that leaves more of the
        # drawing as the bind pose shows it (Section 5.4's least twisted permutation,
        # per link; ours).
        chosen = int(np.argmax(np.where(tie, agree, -np.inf)))
    return LabelChoice(results[chosen], embeddings[chosen], chosen, names, swaps, costs,
                       energy, time.perf_counter() - t0, agree)
