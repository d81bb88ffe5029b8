"""Pins (Section 3.3): joints attached to the environment or to the body.

A joint is pinned to the environment by casting the eye ray through its drawn node; every
surface the ray meets is a candidate (the floor or a table under the hand) and the user
picks one. The joint is then kept on that contact plane (Eq. 10) and finally placed on the
contact point, lifted along the normal by the body's thickness there (the sole under an
ankle, the palm under a wrist). A joint pinned to a limb keeps its parameter along the
limb's stick edge (Eq. 9), measured in the drawing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..exceptions import InputError
from ..skeleton import Skeleton
from .capsules import Capsules
from .environment import Environment, Hit, surfaces_under_ray
from .figure import CharacterFigure
from .graph import StickFigure
from .objective import EnvPin, LimbPin


@dataclass(frozen=True)
class EnvPinSpec:
    """A joint pinned to a surface, as stored on the scene.

    Attributes:
        joint: Stick joint name (``"ankle.L"``, ...).
        point: Contact point on the surface, shape ``(3,)``.
        normal: Surface normal at the contact, shape ``(3,)``.
        object_name: Mesh the surface belongs to (for display).
    """

    joint: str
    point: np.ndarray
    normal: np.ndarray
    object_name: str = ""


@dataclass(frozen=True)
class LimbPinSpec:
    """A joint pinned to a stick edge of the body.

    ``"wrist.L"`` on ``("knee.R", "ankle.R")`` at ``s = 0.1`` puts a hand on the knee.
    """

    joint: str
    limb: tuple[str, str]
    s: float


def pin_candidates(env: Environment, camera: Camera, pixel: np.ndarray,
                   max_gap: float = 0.15, far: float = 20.0) -> list[Hit]:
    """Surfaces under a drawn node, nearest first; the user chooses among several.

    Every surface the eye ray through ``pixel`` meets is a candidate, and so is every
    up-facing surface it passes less than ``max_gap`` above (a hand drawn at the far edge
    of a table, the ray then missing the table top behind it).
    """
    origins, dirs = camera.rays(np.asarray(pixel, float).reshape(1, 2))
    o, d = origins[0], dirs[0]
    hits = env.raycast(o, d)
    below = surfaces_under_ray(env, o, d, (0.0, max_gap), 0.0, far, step=0.03)
    seen = {h.triangle for h in hits}
    extra = []
    for h in below:  # one candidate per surface: the first point along the ray
        if h.triangle not in seen:
            seen.add(h.triangle)
            extra.append(h)
    return sorted(hits + extra, key=lambda h: h.distance)


def limb_parameter(stick: StickFigure, joint: str, limb: tuple[str, str]) -> float:
    """Parameter in ``[0, 1]`` of the drawn node ``joint`` along the drawn edge ``limb``."""
    names = stick.joint_names
    for n in (joint, *limb):
        if n not in names or not stick.present[names.index(n)]:
            raise InputError(f"Cannot pin to '{n}': that joint is not in the drawing.")
    p = stick.points[names.index(joint)]
    a, b = stick.points[names.index(limb[0])], stick.points[names.index(limb[1])]
    d = b - a
    return float(np.clip((p - a) @ d / max(d @ d, 1e-12), 0.0, 1.0))


def pin_offsets(figure: CharacterFigure, skeleton: Skeleton, caps: Capsules,
                vertices: np.ndarray | None = None,
                weights: np.ndarray | None = None) -> np.ndarray:
    """Distance from each stick joint to the skin it rests on, world units, ``(J,)``.

    For a joint starting a short end chain that the character stands on at rest (an ankle
    over its foot: bones below it shorter than 15 % of the height and reaching the lowest
    rest point) it is the rest height of the joint above that chain's lowest skin point;
    otherwise (a wrist over a hand laid flat, a pelvis lying on the floor, a knee on a
    bench, a head top) it is the capsule radius of the joint's bone or its parent,
    whichever is larger.
    """
    return _offsets(figure, skeleton, caps, vertices, weights)[0]


def standing_joints(figure: CharacterFigure, skeleton: Skeleton, caps: Capsules,
                    vertices: np.ndarray | None = None,
                    weights: np.ndarray | None = None) -> np.ndarray:
    """Joints whose :func:`pin_offsets` is the rest height over the chain below, ``(J,)``."""
    return _offsets(figure, skeleton, caps, vertices, weights)[1]


def _offsets(figure: CharacterFigure, skeleton: Skeleton, caps: Capsules,
             vertices: np.ndarray | None, weights: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Offsets ``(J,)`` of :func:`pin_offsets` and which joints stand, ``(J,)``."""
    up = figure.up
    stands = np.zeros(figure.n_joints, bool)
    radius = np.zeros(skeleton.n_bones)
    radius[caps.bones] = caps.radii
    out = np.zeros(figure.n_joints)
    pts = np.concatenate([skeleton.rest_heads, skeleton.rest_tails])
    height = float(np.ptp(pts @ up))
    floor = float(np.min(pts @ up - np.concatenate([radius, radius])))
    if vertices is not None and len(vertices):
        floor = float(np.min(vertices @ up))
    for j in range(figure.n_joints):
        b = int(figure.joint_bones[j])
        p = (skeleton.rest_tails if figure.joint_at_tail[j] else skeleton.rest_heads)[b]
        par = skeleton.parents[b]
        r = max(radius[b], radius[par] if par >= 0 and not figure.joint_at_tail[j] else 0.0)
        below = skeleton.descendants(b) if not figure.joint_at_tail[j] else np.array([b])
        if figure.joint_at_tail[j] or skeleton.lengths[below].sum() > 0.15 * height:
            out[j] = r
            continue
        low = None
        if vertices is not None and weights is not None and len(vertices):
            own = np.isin(np.argmax(weights, 1), below)
            low = float(np.min(vertices[own] @ up)) if np.any(own) else None
        if low is None:
            ends = np.concatenate([skeleton.rest_heads[below], skeleton.rest_tails[below]])
            rr = np.concatenate([radius[below], radius[below]])
            low = float(np.min(ends @ up - rr))
        if low > floor + 0.02 * height:  # not what it stands on: lay it flat
            out[j] = r
            continue
        out[j] = max(float(p @ up) - low, r)
        stands[j] = True
    return out, stands


def resolve_pins(figure: CharacterFigure, stick: StickFigure,
                 env_specs: tuple[EnvPinSpec, ...], limb_specs: tuple[LimbPinSpec, ...],
                 offsets: np.ndarray, camera: Camera | None = None,
                 standing: np.ndarray | None = None
                 ) -> tuple[tuple[EnvPin, ...], tuple[LimbPin, ...]]:
    """Turn stored pins into objective pins (joint indices, lifted targets).

    The target of a joint pinned to a surface lies on the contact plane lifted by the
    joint's offset; when the joint is drawn and ``camera`` is given, it is where the eye
    ray through the drawn joint meets that lifted plane, so that the placed joint still
    projects onto the drawing. ``standing`` (``(J,)``, from :func:`standing_joints`)
    marks the joints whose height above the surface the finish adapts to the orientation
    of the chain below them.

    Raises:
        InputError: A pin names a joint the character does not have.
    """
    def index(name):
        if name not in figure.joint_names:
            raise InputError(f"Pinned joint '{name}' is not a stick joint; use one of "
                             f"{list(figure.joint_names)}.")
        return figure.joint(name)

    env = []
    for spec in env_specs:
        j = index(spec.joint)
        n = np.asarray(spec.normal, float)
        n = n / max(np.linalg.norm(n), 1e-12)
        target = np.asarray(spec.point, float) + n * offsets[j]
        if camera is not None and stick.present[j]:
            o, d = camera.rays(stick.points[j][None])
            rate = float(d[0] @ n)
            if abs(rate) > 1e-6:
                t = float((target - o[0]) @ n) / rate
                if t > 0:
                    target = o[0] + t * d[0]
        env.append(EnvPin(j, target, n, bool(standing is not None and standing[j])))
    limbs = tuple(LimbPin(index(s.joint), (index(s.limb[0]), index(s.limb[1])), float(s.s))
                  for s in limb_specs)
    return tuple(env), limbs


def foot_extents(figure: CharacterFigure, skeleton: Skeleton, caps: Capsules,
                 joint: int, vertices: np.ndarray | None = None,
                 weights: np.ndarray | None = None) -> tuple[int, float, float] | None:
    """The footprint of the short chain a standing joint stands on (a foot at an ankle).

    Measured at rest along the chain's direction on the ground (the joint to its child
    stick joint, the toe, projected on the ground plane): the skin of the chain's bones
    reaches from ``heel`` (negative: behind the joint) to ``toe`` (ahead of it). The
    balance term (Eqs. 7-8) supports the centre of mass over the hull of these heel-to-toe
    segments, not over the ankles alone.

    Args:
        figure: The character's stick model.
        skeleton: Its skeleton.
        caps: Body capsules (without a mesh, the chain's capsules give the extent).
        joint: The standing joint (an ankle).
        vertices: Rest mesh vertices ``(V, 3)``, or None.
        weights: Their bone weights ``(V, n)``, or None.

    Returns:
        ``(toe joint, heel, toe)`` (world units along the foot's ground direction), or
        None when the joint has no child stick joint or no extent on the ground.
    """
    kids = np.flatnonzero(figure.joint_parents == joint)
    if kids.size == 0:
        return None
    up = figure.up
    tip = int(kids[0])
    rest = figure.rest_joints(skeleton)
    v = rest[tip] - rest[joint]
    v = v - up * (v @ up)
    if np.linalg.norm(v) < 1e-9:
        return None
    f = v / np.linalg.norm(v)
    below = skeleton.descendants(int(figure.joint_bones[joint]))
    s = None
    if vertices is not None and weights is not None and len(vertices):
        own = np.isin(np.argmax(weights, 1), below)
        if np.any(own):
            s = (vertices[own] - rest[joint]) @ f
    if s is None:
        radius = np.zeros(skeleton.n_bones)
        radius[caps.bones] = caps.radii
        ends = np.concatenate([skeleton.rest_heads[below], skeleton.rest_tails[below]])
        rr = np.concatenate([radius[below], radius[below]])
        along = (ends - rest[joint]) @ f
        s = np.concatenate([along - rr, along + rr])
    heel, toe = float(min(s.min(), 0.0)), float(max(s.max(), 0.0))
    return (tip, heel, toe) if toe - heel > 1e-6 else None
