"""Options of line-of-action stroke posing (Mahmudi et al. 2016)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from ..exceptions import InputError


class PlaneMode(StrEnum):
    """Where each joint may move (Section 6, Eq. 4).

    DEFAULT keeps every joint's view depth: the joint moves on the circle where the sphere
    of the bone's length around its parent joint meets the view-parallel plane through the
    joint. PLANE moves that plane to the parent joint, so the posed bone lies orthogonal to
    the view direction (no foreshortening).
    """

    DEFAULT = "DEFAULT"
    PLANE = "PLANE"


class Tracking(StrEnum):
    """What of the stroke the chain follows.

    POSITION places each joint on the ray through its feature point of the drawn stroke, so
    the projected joints land on the stroke itself. SHAPE scales the stroke to the chain's
    projected length and follows the stroke's direction between consecutive feature points,
    starting from where the previous joint really landed: the chain takes the stroke's shape
    even where a joint cannot reach the stroke.
    """

    POSITION = "POSITION"
    SHAPE = "SHAPE"


@dataclass(frozen=True)
class StrokeOptions:
    """Options of one stroke-posing solve.

    Attributes:
        mode: Depth handling (DEFAULT keeps depths, PLANE makes bones view-orthogonal).
        tracking: POSITION or SHAPE tracking.
        start_bone: Bone whose head starts the chain (default: the joint nearest the stroke's
            first point).
        direction_bone: A bone the chain must pass through (chooses the branch).
        end_bone: Last bone of the chain; with ``start_bone`` it may lie in another branch
            (Over-Root posing through the common ancestor).
        pick_radius: Largest distance in pixels from the stroke's first point to the start
            joint's projection.
        feature_extraction: Use the curvature features of Eqs. 2-3; False gives the uniform
            arc-length baseline (Guay et al. 2013 style).
        stroke_crossing: Where Eq. 2 finds no drawn corner, place the joint where the rays
            through the stroke cross its circle (nearest the arc-length guess), so joints
            land on smooth strokes exactly; a refinement beyond the paper, which places
            the joint at the circle point nearest the guess's ray (position tracking
            with feature extraction only).
        sample_step: Stroke sampling step in pixels ("one sample per pixel").
        feature_min_curvature: Smallest |curvature| (1/pixels) that counts as a feature.
        view_axis_tolerance: Bones whose depth-keeping circle is smaller than this fraction
            of their length point along the view axis and are skipped.
        pin_iterations: Iterations of the prioritized IK that restores pinned bones.
    """

    mode: PlaneMode = PlaneMode.DEFAULT
    tracking: Tracking = Tracking.POSITION
    start_bone: str | None = None
    direction_bone: str | None = None
    end_bone: str | None = None
    pick_radius: float = 40.0
    feature_extraction: bool = True
    stroke_crossing: bool = True
    sample_step: float = 1.0
    feature_min_curvature: float = 0.02
    view_axis_tolerance: float = 0.03
    pin_iterations: int = 60

    def __post_init__(self) -> None:
        """Coerce enum strings and check ranges."""
        try:
            object.__setattr__(self, "mode", PlaneMode(self.mode))
            object.__setattr__(self, "tracking", Tracking(self.tracking))
        except ValueError as err:
            raise InputError(f"Unknown stroke option: {err}.") from None
        if not self.pick_radius > 0:
            raise InputError("pick_radius must be a positive number of pixels.")
        if not self.sample_step > 0:
            raise InputError("sample_step must be a positive number of pixels.")
        if self.end_bone is not None and self.start_bone is None:
            raise InputError("An end bone needs a start bone: set start_bone as well.")
