"""Line-of-action stroke posing, end to end (Mahmudi et al. 2016).

``pose_from_stroke`` matches a stroke to a chain (Section 4), builds the intermediate
representation (Forward or Over-Root posing, the begin part reversed, Eq. 1 translation
onto the start joint and, for shape tracking, scaling to the chain's projected length),
extracts features and aligns the joints (Sections 5-6, Eqs. 2-4), then restores pinned
bones with a prioritized IK.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
from ..exceptions import InputError
from ..skeleton import Pose, Skeleton
from ..stroke import Stroke, distance_to_polyline
from .alignment import ViewOps
from .chain import ChainPlan, PlanKind, plan_chain
from .features import SampledStroke
from .options import StrokeOptions, Tracking
from .pins import PinReport, restore_pins
from .posing import ChainState, PartOutcome, PartSpec, pose_part

MIN_STROKE_PIXELS = 5.0


@dataclass(frozen=True)
class StrokePoseResult:
    """A posed skeleton and what it took.

    Attributes:
        pose: The new pose (every bone; only ``changed`` bones differ from the input).
        changed: Indices of bones whose local rotation changed, shape ``(c,)``.
        chain: Posed bones in posing order.
        plan: FORWARD, REVERSED or OVER_ROOT.
        targets: Target pixel of every posed joint, shape ``(k, 2)``.
        landed: Where those joints project after posing, shape ``(k, 2)``.
        skipped: Names of bones left alone because they lie along the view axis.
        mean_distance: Mean distance in pixels from the posed joints' projections to the
            drawn stroke.
        pins: Report of the pinned-bone restoration.
        timings: Seconds per stage.
        warnings: Messages for the user.
    """

    pose: Pose
    changed: np.ndarray
    chain: tuple[str, ...]
    plan: PlanKind
    targets: np.ndarray
    landed: np.ndarray
    skipped: tuple[str, ...]
    mean_distance: float
    pins: PinReport
    timings: dict[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()


def _path_points(cs: ChainState, bones: tuple[int, ...]) -> np.ndarray:
    """Joint positions along a fixed downward chain, shape ``(k + 1, 3)``."""
    return np.array([cs.h[b] for b in bones] + [cs.t[bones[-1]]])


def _projected_length(view: ViewOps, points: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(view.project(points), axis=0), axis=1)))


def _pieces(stroke: Stroke, plan: ChainPlan, view: ViewOps, cs: ChainState) -> list[Stroke]:
    """Split the stroke over the plan's parts (Over-Root: begin, middle, end)."""
    if plan.kind is PlanKind.FORWARD:
        return [stroke]
    if plan.kind is PlanKind.REVERSED:
        return [stroke.reversed()]
    begin, end = plan.parts
    lb = _projected_length(view, _path_points(cs, begin.fixed_bones))
    le = _projected_length(view, _path_points(cs, end.fixed_bones))
    ends = view.project(np.array([cs.h[begin.fixed_bones[0]], cs.h[end.fixed_bones[0]]]))
    lm = float(np.linalg.norm(ends[0] - ends[1]))
    total = lb + lm + le
    if total < 1e-9:
        raise InputError("The chain between the start and end bones is invisible in this view.")
    s1 = stroke.length * lb / total
    s2 = stroke.length * (lb + lm) / total
    return [stroke.sub_stroke(0.0, s1).reversed(), stroke.sub_stroke(s2, stroke.length)]


def _prepare(piece: Stroke, start_px: np.ndarray, chain_px_length: float | None,
             step: float) -> SampledStroke:
    """Eq. 1: the piece sampled and translated onto its start joint (scaled for shape).

    A translation leaves arc lengths and curvature as they are, so the samples are shifted
    rather than a new spline built; scaling needs the spline of the scaled stroke.
    """
    offset = np.asarray(start_px) - piece.points[0]
    if chain_px_length is None:
        return SampledStroke.from_stroke(piece, step).shifted(offset)
    scale = chain_px_length / max(piece.length, 1e-9)
    return SampledStroke.from_stroke(piece.transformed(scale=scale, offset=offset), step)


def _run_part(skeleton: Skeleton, view: ViewOps, cs: ChainState, piece: Stroke, part,
              plan: ChainPlan, options: StrokeOptions) -> PartOutcome:
    """Translate (and scale) the piece, then pose its chain."""
    shape = options.tracking is Tracking.SHAPE
    spec = PartSpec(part.start_candidates, part.fixed_bones, plan.direction_path, not shape)
    start_px = view.project(np.array(cs.h[part.start_candidates[0]]))
    bones = part.fixed_bones
    if shape and bones is None:
        # The chain must be known before the stroke is scaled to its length: find it by
        # a dry run on a copy, which chooses branches exactly as the real pass would.
        trial = cs.copy()
        sampled = _prepare(piece, start_px, None, options.sample_step)
        bones = pose_part(skeleton, view, sampled, trial, spec, options).bones
        spec = PartSpec(bones[:1], bones, plan.direction_path, False)
    length = _projected_length(view, _path_points(cs, bones)) if shape else None
    sampled = _prepare(piece, start_px, length, options.sample_step)
    return pose_part(skeleton, view, sampled, cs, spec, options)


def pose_from_stroke(skeleton: Skeleton, pose: Pose, camera: Camera, stroke: Stroke,
                     options: StrokeOptions | None = None,
                     pinned: np.ndarray | None = None) -> StrokePoseResult:
    """Pose the chain a stroke was drawn along.

    Args:
        skeleton: The character's skeleton (world space).
        pose: Its current pose.
        camera: The view the stroke was drawn in.
        stroke: The stroke, pixels.
        options: Posing options (defaults: depth-keeping, position tracking, features on).
        pinned: Boolean mask of pinned bones, shape ``(n,)``.

    Returns:
        The new pose with diagnostics.

    Raises:
        InputError: Stroke too short, no joint near its start, unknown bones, or a chain
            that lies entirely along the view axis.
    """
    options = options or StrokeOptions()
    t0 = time.perf_counter()
    if stroke.length < MIN_STROKE_PIXELS:
        raise InputError(f"The stroke is only {stroke.length:.1f} px long: draw a longer "
                         "stroke along the part to pose.")
    state = skeleton.forward(pose)
    view = ViewOps.from_camera(camera)
    plan = plan_chain(skeleton, state, camera, stroke.points[0], options)
    cs = ChainState.from_state(skeleton, pose.rotations, pose.translations, state)
    pieces = _pieces(stroke, plan, view, cs)
    t1 = time.perf_counter()
    outcomes = [_run_part(skeleton, view, cs, piece, part, plan, options)
                for piece, part in zip(pieces, plan.parts, strict=True)]
    t2 = time.perf_counter()
    chain = tuple(b for o in outcomes for b in o.bones)
    skipped = tuple(skeleton.names[b] for o in outcomes for b in o.skipped)
    if chain and len(skipped) == len(chain):
        raise InputError(
            f"The chain from '{skeleton.names[chain[0]]}' points along the view axis, so the "
            "stroke cannot orient it: rotate the view, or use plane posing.")
    new_pose = Pose(cs.rotations, pose.translations.copy())
    pin_report = PinReport((), 0, 0.0, 0.0)
    if pinned is not None and np.any(pinned):
        new_pose, pin_report = restore_pins(skeleton, pose, new_pose, np.asarray(chain, int),
                                            np.asarray(pinned, bool), options.pin_iterations)
    t3 = time.perf_counter()
    landed = (_landed(skeleton, new_pose, view, outcomes) if pin_report.pinned
              else np.concatenate([o.landed for o in outcomes]))
    mean_distance = float(np.mean(distance_to_polyline(landed, stroke.points))) if len(
        landed) else 0.0
    diff = np.abs(new_pose.rotations - pose.rotations).max(axis=(1, 2))
    warnings = _warnings(skeleton, outcomes, pin_report, mean_distance)
    return StrokePoseResult(
        pose=new_pose, changed=np.flatnonzero(diff > 1e-12), chain=tuple(
            skeleton.names[b] for b in chain), plan=plan.kind,
        targets=np.concatenate([o.targets for o in outcomes]), landed=landed,
        skipped=skipped, mean_distance=mean_distance, pins=pin_report,
        timings={"match": t1 - t0, "align": t2 - t1, "pins": t3 - t2,
                 "total": time.perf_counter() - t0},
        warnings=warnings,
    )


def _landed(skeleton: Skeleton, pose: Pose, view: ViewOps,
            outcomes: list[PartOutcome]) -> np.ndarray:
    """Projections of every posed segment end in the final pose, shape ``(k, 2)``."""
    state = skeleton.forward(pose)
    ends = [state.tails[b] if c < 0 else state.heads[c]
            for o in outcomes for b, c in zip(o.bones, o.ends, strict=True)]
    return view.project(np.array(ends).reshape(-1, 3))


FAR_FROM_STROKE_PX = 10.0


def _warnings(skeleton: Skeleton, outcomes: list[PartOutcome], pins: PinReport,
              mean_distance: float) -> tuple[str, ...]:
    """Messages about what the solve could not do exactly."""
    names = skeleton.names
    out = []
    skipped = [names[b] for o in outcomes for b in o.skipped]
    if skipped:
        out.append(f"Skipped bones along the view axis: {', '.join(skipped)}.")
    moved = [names[b] for o in outcomes for b in o.depth_moved]
    if moved:
        out.append(f"The joints below {', '.join(moved)} could not keep their depth (their "
                   "parent moved too far towards or away from the view); they kept their "
                   "current depth instead.")
    if pins.pinned and not pins.held:
        held = ", ".join(names[b] for b in pins.pinned)
        out.append(f"Pinned bones ({held}) could not be held exactly: off by "
                   f"{pins.residual:.3g} units. Draw a stroke they can follow, or unpin them.")
    if mean_distance > FAR_FROM_STROKE_PX:
        why = ("the pinned bones (" + ", ".join(names[b] for b in pins.pinned)
               + ") hold the chain back" if pins.pinned else "the bones cannot follow it "
               "(they keep their lengths and depth). Try View Plane, or check the start and "
               "end bones")
        out.append(f"The posed joints are {mean_distance:.0f} px from the stroke on average: "
                   f"{why}.")
    return tuple(out)
