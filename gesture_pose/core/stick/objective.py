"""The reconstruction objective of Lin et al. (2012), Eqs. 4-11, for a whole population.

``E = w_p E_proj + w_b E_bal + w_a E_att (+ w_c E_col in refinement)`` with the paper's
weights 1.0, 0.5 and 5.0:

- ``E_proj`` (Eqs. 4-6): for every drawn stick edge, the squared difference between the
  unit direction of the projected 3D edge and the drawn one, plus ``w = 0.1`` times the
  squared distance (in units of the mean drawn edge length) between every projected joint
  and its drawn node.
- ``E_bal`` (Eqs. 7-8): squared ground-plane distance (in units of the character's
  height) from the centre of mass (bone masses from the mesh volume around each bone) to
  the support polygon, the convex hull of the environment contacts and of the soles of
  the pinned standing feet (:class:`Footprint`: heel to toe along each posed foot, so
  that two feet support an area and one foot a segment, not a point); zero inside.
- ``E_att`` (Eqs. 9-10): a joint pinned to a limb stays at its parameter along the limb
  (Eq. 9); a joint pinned to the environment stays on the contact plane (Eq. 10).
- ``E_col`` (Eq. 11): squared capsule penetrations, body against body and against the
  environment's distance grid, in units of 5 % of the height.
- ``E_com`` (joint comfort, our addition, weight 0.002): per gene group (a shoulder, an
  elbow, the spine...) the mean of ``((g - g_0) / h)^2`` over its rotation genes, ``g_0``
  the rest pose clipped into the range of motion and ``h`` the range's half-width (or the
  group's own ``comfort`` unit: a non-humanoid's defaults keep that of a +-90 degree
  ball). It is
  too weak to move a pose off the drawing (a 30-degree turn costs what a 1-degree error
  of one drawn edge does) but decides between depth interpretations that fit the drawing
  equally well and fixes the rotations the drawing does not see (twists along bones).
- ``E_fs`` (foreshortening the drawing does not show, our addition, off by default): per drawn
  edge ``((l_proj - min(l_drawn, l_full)) / l_full)^2``, ``l_proj`` the projected length
  of the posed edge, ``l_drawn`` the drawn one and ``l_full`` the projection of the
  whole edge at its depth were it in the view plane. Eqs. 4-6 weigh directions and
  (with ``w = 0.1``) positions, which barely constrain lengths: a bone drawn at full
  length must lie in the view plane, a bone drawn short must turn out of it as much.
  Weighted 0.1 or 0.5 in refinement it made the sample scenes' sitting, standing and
  lying reconstructions worse (it fights the 1.5 px noise of every drawn length), so by
  default it only ranks the suggestions (:mod:`.ranking`).

Every term returns its gradient with respect to the bones' heads and tails; chained with
:meth:`.kinematics.PoseModel.jacobian` this gives the analytic gene gradient.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ..camera import Camera
from .capsules import Capsules, axis_samples, body_collision, pair_closest
from .environment import DistanceGrid
from .graph import StickFigure
from .kinematics import N_ROOT_GENES, PoseModel


@dataclass(frozen=True)
class EnvPin:
    """A joint attached to the environment.

    Attributes:
        joint: Stick joint index.
        target: Contact point the joint is placed on at the end, shape ``(3,)``.
        normal: Unit normal of the contact plane, shape ``(3,)``.
        stands: The joint stands on the short chain below it (an ankle on its foot): its
            height above the surface follows that chain's orientation (see
            :func:`~gesture_pose.core.stick.finish.finish_pose`).
    """

    joint: int
    target: np.ndarray
    normal: np.ndarray
    stands: bool = False


@dataclass(frozen=True)
class Footprint:
    """The sole of a pinned standing foot, a support area of the balance term (Eqs. 7-8).

    On the ground plane it is the segment from ``heel`` to ``toe`` (world units, the
    heel negative) along the posed foot's direction on the ground (the ankle to its toe
    joint), about the ankle's support point: the finish stands the foot flat, its yaw
    kept.

    Attributes:
        joint: The standing stick joint (an ankle).
        tip: Its child stick joint (the toe).
        point: The ankle's support point on the surface, shape ``(3,)``.
        heel: Extent behind the ankle (negative), world units.
        toe: Extent ahead of it, world units.
    """

    joint: int
    tip: int
    point: np.ndarray
    heel: float
    toe: float


@dataclass(frozen=True)
class LimbPin:
    """A joint attached to a point of a stick edge of the body (Eq. 9).

    Attributes:
        joint: Stick joint index.
        limb: Joint indices ``(a, b)`` of the stick edge.
        s: Parameter along the edge, 0 at ``a`` and 1 at ``b``.
    """

    joint: int
    limb: tuple[int, int]
    s: float

    def target(self, joints: np.ndarray, axis: int = -2) -> np.ndarray:
        """The point of the edge the joint is attached to (Eq. 9): ``(1 - s) a + s b``.

        The one place the pin's target is computed: the attachment energy, its
        residuals and their Jacobian, the finish and the residual reports call it.

        Args:
            joints: Stick joint positions (world units) or their Jacobians, indexed by
                joint along ``axis``: ``(J, 3)``, ``(P, J, 3)``, or ``(J, 3, G)`` with
                ``axis=0``.
            axis: The joint axis of ``joints``.

        Returns:
            ``joints`` without its joint axis: ``(3,)``, ``(P, 3)`` or ``(3, G)``.
        """
        a, b = self.limb
        return (1 - self.s) * np.take(joints, a, axis) + self.s * np.take(joints, b, axis)


@dataclass(frozen=True)
class Weights:
    """Term weights (the paper's: projection 1.0, balance 0.5, attachment 5.0).

    ``collision`` weighs Eq. 11 in refinement, ``position`` is Eq. 5's ``w``,
    ``comfort`` and ``foreshortening`` weigh our two additions (0 turns them off).
    """

    projection: float = 1.0
    balance: float = 0.5
    attachment: float = 5.0
    collision: float = 5.0
    position: float = 0.1
    comfort: float = 0.002
    foreshortening: float = 0.0


def project_jacobian(camera: Camera, points: np.ndarray, jacobian: bool = True
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """Pixels of world points and the projection's Jacobian.

    Args:
        camera: The view.
        points: World points, shape ``(..., 3)``.
        jacobian: Also compute the Jacobian (None otherwise).

    Returns:
        ``(pixels (..., 2), d pixels / d points (..., 2, 3))``.
    """
    M = camera.full_matrix
    clip = points @ M[:, :3].T + M[:, 3]
    w = clip[..., 3:4]
    size = np.array([camera.width, camera.height], float) / 2.0
    px = (clip[..., :2] / w + 1.0) * size
    if not jacobian:
        return px, None
    J = (M[None, :2, :3] * w[..., None] - clip[..., :2, None] * M[3, :3]) / (w[..., None] ** 2)
    return px, J * size[:, None]


def _hull(points2d: np.ndarray) -> np.ndarray:
    """Support polygon vertices (counter-clockwise), ``(k, 2)``; points or a segment too."""
    pts = np.unique(np.round(points2d, 9), axis=0)
    if len(pts) >= 3:
        try:
            return pts[ConvexHull(pts).vertices]
        except QhullError:
            pass
    if len(pts) >= 2:
        d = pts - pts.mean(0)
        axis = np.linalg.svd(d)[2][0]
        proj = d @ axis
        return pts[[np.argmin(proj), np.argmax(proj)]]
    return pts


@functools.lru_cache(maxsize=16)
def _hull_indices(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs ``(i, j)`` of ``k`` points (``i < j``) and the fan triangles ``(0, a, b)``."""
    i, j = np.triu_indices(k, 1)
    a, b = np.triu_indices(k - 1, 1)
    return i, j, np.stack([np.zeros_like(a), a + 1, b + 1], 1)


def hull_offset(q: np.ndarray, points: np.ndarray, closest: bool = False
                ) -> np.ndarray | tuple[np.ndarray, ...]:
    """Vector from the closest point of the convex hull of ``points`` to ``q``; zero inside.

    Per individual: the hull of a few points (the support polygon with posed
    footprints). Outside the hull its closest point lies on a hull edge, a segment
    between two of the points, and every such segment lies in the hull: the offset is
    the shortest one to any segment between two points. ``q`` is inside when it is in a
    triangle of the first point and two others (the ray from the first point through an
    inside ``q`` leaves the hull through an edge between two points).

    Args:
        q: Points, shape ``(P, 2)``.
        points: Hull points per individual, shape ``(P, k, 2)``.
        closest: Also return where the closest point is.

    Returns:
        Offsets, shape ``(P, 2)``; with ``closest``, also the closest segment's ends
        ``i, j`` ``(P,)`` (indices into the points), its parameter ``t`` ``(P,)`` (the
        closest point is ``(1 - t) p_i + t p_j``) and whether ``q`` is inside ``(P,)``.
    """
    k = points.shape[1]
    if k == 1:
        zero = np.zeros(len(q), int)
        off = q - points[:, 0]
        return (off, zero, zero, np.zeros(len(q)), np.zeros(len(q), bool)) if closest else off
    i, j, tri = _hull_indices(k)
    a, d = points[:, i], points[:, j] - points[:, i]
    t = np.clip(np.einsum("psd,psd->ps", q[:, None] - a, d) /
                np.maximum(np.einsum("psd,psd->ps", d, d), 1e-18), 0, 1)
    off = q[:, None] - a - t[..., None] * d
    best = np.argmin(np.einsum("psd,psd->ps", off, off), axis=1)
    out = off[np.arange(len(q)), best]
    inside = np.zeros(len(q), bool)
    if k >= 3:
        p0, p1, p2 = points[:, :1], points[:, tri[:, 1]], points[:, tri[:, 2]]

        def cross(u, v):
            return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

        qq = q[:, None]
        c0, c1, c2 = cross(p1 - p0, qq - p0), cross(p2 - p1, qq - p1), cross(p0 - p2, qq - p2)
        tri_in = (((c0 >= 0) & (c1 >= 0) & (c2 >= 0)) | ((c0 <= 0) & (c1 <= 0) & (c2 <= 0)))
        tri_in &= np.abs(cross(p1 - p0, p2 - p0)) > 1e-18
        inside = np.any(tri_in, axis=1)
        out[inside] = 0.0
    if closest:
        return out, i[best], j[best], t[np.arange(len(q)), best], inside
    return out


def polygon_offset(q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Vector from the closest point of a convex polygon to ``q``; zero inside.

    Args:
        q: Points, shape ``(P, 2)``.
        poly: Counter-clockwise polygon (or segment/point), shape ``(k, 2)``.

    Returns:
        Offsets, shape ``(P, 2)``.
    """
    a = poly
    b = np.roll(poly, -1, axis=0)
    d = b - a
    t = np.clip(np.einsum("pkd,kd->pk", q[:, None] - a[None], d) /
                np.maximum((d * d).sum(1), 1e-18), 0, 1)
    closest = a[None] + t[..., None] * d[None]
    off = q[:, None] - closest
    k = np.argmin((off**2).sum(-1), axis=1)
    out = off[np.arange(len(q)), k]
    if len(poly) >= 3:
        cross = d[None, :, 0] * (q[:, None, 1] - a[None, :, 1]) - d[None, :, 1] * (
            q[:, None, 0] - a[None, :, 0])
        inside = np.all(cross >= 0, axis=1)
        out[inside] = 0.0
    return out


@dataclass(frozen=True)
class StickObjective:
    """Everything the energy of a pose depends on.

    Attributes:
        model: Genes -> bones.
        camera: The view the figure was drawn in.
        stick: The matched drawing (target joint pixels).
        height: Character height, world units (length unit of the energies).
        masses: Bone masses (any unit), shape ``(n,)``.
        capsules: Body capsules.
        env_capsules: Capsules checked against the environment, shape ``(c,)`` bool.
        grid: Environment distance grid, or None.
        support: Contact points forming the support polygon, shape ``(k, 3)``.
        env_pins: Joints pinned to the environment.
        limb_pins: Joints pinned to the body.
        weights: Term weights.
        up: World up, shape ``(3,)``.
        footprints: Soles of pinned standing feet, supporting the centre of mass with
            ``support`` (the hull of both).
    """

    model: PoseModel
    camera: Camera
    stick: StickFigure
    height: float
    masses: np.ndarray
    capsules: Capsules
    env_capsules: np.ndarray
    grid: DistanceGrid | None = None
    support: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    env_pins: tuple[EnvPin, ...] = ()
    limb_pins: tuple[LimbPin, ...] = ()
    weights: Weights = field(default_factory=Weights)
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    footprints: tuple[Footprint, ...] = ()
    _edges: np.ndarray = field(init=False, repr=False)
    _dirs: np.ndarray = field(init=False, repr=False)
    _px_scale: float = field(init=False, repr=False)
    _ground: np.ndarray = field(init=False, repr=False)
    _poly: np.ndarray = field(init=False, repr=False)
    _drawn_len: np.ndarray = field(init=False, repr=False)
    _ppu1: float = field(init=False, repr=False)
    _comfort_ref: np.ndarray = field(init=False, repr=False)
    _comfort_scale: np.ndarray = field(init=False, repr=False)
    _rigid_mass: tuple = field(init=False, repr=False)
    _mass_share: np.ndarray = field(init=False, repr=False)
    _pair_reach: np.ndarray = field(init=False, repr=False)
    _env_on: np.ndarray = field(init=False, repr=False)
    _env_radii: np.ndarray = field(init=False, repr=False)
    _comfort_jacobian: np.ndarray = field(init=False, repr=False)
    _soles: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        """Cache drawn edges, the pixel scale, the support polygon and comfort constants."""
        edges = self.stick.drawn_edges()
        vec = self.stick.points[edges[:, 1]] - self.stick.points[edges[:, 0]]
        lengths = np.linalg.norm(vec, axis=1)
        object.__setattr__(self, "_edges", edges)
        object.__setattr__(self, "_dirs", vec / np.maximum(lengths, 1e-9)[:, None])
        object.__setattr__(self, "_px_scale", float(max(lengths.mean(), 1.0)))
        object.__setattr__(self, "_drawn_len", lengths)
        object.__setattr__(self, "_ppu1", float(self.camera.pixels_per_unit(1.0)))
        up = np.asarray(self.up, float)
        ground = np.linalg.svd(np.eye(3) - np.outer(up, up))[0][:, :2]
        object.__setattr__(self, "_ground", ground)
        sup = np.asarray(self.support, float).reshape(-1, 3)
        object.__setattr__(self, "_poly", _hull(sup @ ground) if len(sup) else np.zeros((0, 2)))
        groups = self.model.figure.groups
        m = np.array([g.bounds.shape[0] for g in groups], int)
        b = np.concatenate([g.bounds for g in groups]).reshape(-1, 2)
        half = np.concatenate([0.5 * (g.bounds[:, 1] - g.bounds[:, 0]) if g.comfort is None
                               else g.comfort for g in groups])
        half = np.maximum(half, 1e-6)
        object.__setattr__(self, "_comfort_ref", np.clip(0.0, b[:, 0], b[:, 1]))
        # sqrt(w / m) / h: each group counts once, whatever its number of genes.
        object.__setattr__(self, "_comfort_scale",
                           np.sqrt(self.weights.comfort / np.repeat(m, m)) / half)
        # Per-solve constants of the residuals: bone mass shares, the radii sums of the
        # capsule pairs, the capsules checked against the environment and their radii,
        # the comfort rows' (constant) Jacobian.
        w = self.masses / self.masses.sum()
        object.__setattr__(self, "_mass_share", w)
        caps = self.capsules
        object.__setattr__(self, "_pair_reach", caps.radii[caps.pairs[:, 0]] +
                           caps.radii[caps.pairs[:, 1]])
        on = np.flatnonzero(self.env_capsules)
        object.__setattr__(self, "_env_on", on)
        object.__setattr__(self, "_env_radii", caps.radii[on])
        G = self.model.n_genes
        # The soles' support points on the ground and extents (heel, toe), (f, 2) each.
        object.__setattr__(self, "_soles", (
            np.array([f.point for f in self.footprints]).reshape(-1, 3) @ ground,
            np.array([[f.heel, f.toe] for f in self.footprints]).reshape(-1, 2)))
        object.__setattr__(self, "_comfort_jacobian",
                           np.eye(G)[N_ROOT_GENES:] * self._comfort_scale[:, None])
        # The centre of mass without posing the rigid bones (fingers): the chain bones'
        # masses and, per chain bone, what its rigid bones add.
        chain = np.zeros(len(w), bool)
        chain[self.model.chain_bones] = True
        object.__setattr__(self, "_rigid_mass",
                           (np.flatnonzero(chain), w[chain], *self.model.rigid_moments(w)))

    # -- terms ---------------------------------------------------------------------------

    def _projection(self, joints, grad):
        q, Jq = project_jacobian(self.camera, joints, grad)
        a, b = self._edges[:, 0], self._edges[:, 1]
        u = q[:, b] - q[:, a]
        n = np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-9)
        uh = u / n
        diff = uh - self._dirs
        e_dir = np.sum(diff**2, axis=(1, 2))
        present = self.stick.present
        off = (q[:, present] - self.stick.points[present]) / self._px_scale
        e_pos = np.sum(off**2, axis=(1, 2))
        energy = e_dir + self.weights.position * e_pos
        if not grad:
            return energy, None
        gu = 2.0 * (diff - uh * np.sum(diff * uh, -1, keepdims=True)) / n
        gq = np.zeros_like(q)
        np.add.at(gq, (slice(None), b), gu)
        np.add.at(gq, (slice(None), a), -gu)
        gq[:, present] += 2.0 * self.weights.position * off / self._px_scale
        return energy, np.einsum("pjk,pjkd->pjd", gq, Jq)

    def _centre_of_mass(self, heads: np.ndarray, tails: np.ndarray,
                        frames: np.ndarray | None) -> np.ndarray:
        """Centre of mass ``(P, 3)`` of posed bones (Eqs. 7-8).

        With ``frames`` ``(P, n, 3, 3)`` the rigid bones' heads and tails are not read
        (:meth:`.PoseModel.forward` with ``rigid`` False): their masses move with their
        chain ancestors' frames (:meth:`.PoseModel.rigid_moments`). The same centre, to
        rounding.
        """
        if frames is None:
            m = self._mass_share
            return np.einsum("n,pnd->pd", m, 0.5 * (heads + tails))
        chain, w, anchors, W, v = self._rigid_mass
        com = np.einsum("n,pnd->pd", w, 0.5 * (heads[:, chain] + tails[:, chain]))
        return (com + np.einsum("a,pad->pd", W, heads[:, anchors]) +
                np.einsum("paij,aj->pi", frames[:, anchors], v))

    def _feet(self, joints: np.ndarray) -> np.ndarray:
        """The footprints' posed directions on the ground (ankle to toe), ``(P, f, 2)``.

        Args:
            joints: Posed stick joints, shape ``(P, J, 3)``.
        """
        tip = [f.tip for f in self.footprints]
        ankle = [f.joint for f in self.footprints]
        return (joints[:, tip] - joints[:, ankle]) @ self._ground

    def support_offset(self, c2: np.ndarray, feet: np.ndarray | None = None) -> np.ndarray:
        """Offset ``(P, 2)`` of the centre of mass on the ground from the support (Eq. 8).

        Args:
            c2: Centres of mass on the ground plane, shape ``(P, 2)``.
            feet: The footprints' directions on the ground (:meth:`_feet`), ``(P, f, 2)``.

        Returns:
            The vector from the support area's closest point, zero inside it: the hull of
            the contacts (``support``) and, per pinned standing foot, its sole from heel
            to toe along its direction.
        """
        if not self.footprints or feet is None:
            return polygon_offset(c2, self._poly)
        return hull_offset(c2, self._support_points(feet)[0])

    def _support_points(self, feet: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The support's points on the ground: the contacts' polygon, then each sole's ends.

        Args:
            feet: The footprints' directions on the ground (:meth:`_feet`), ``(P, f, 2)``.

        Returns:
            ``(points (P, k0 + 2 f, 2), u (P, f, 2), n (P, f, 1), ext (f, 2))``: the
            contacts' ``k0`` polygon points followed by each foot's heel and toe; the
            feet's unit directions (0 for a foot without one) and lengths; the soles'
            extents (heel, toe) along them, world units.
        """
        base, ext = self._soles  # (f, 2) each
        n = np.linalg.norm(feet, axis=-1, keepdims=True)
        u = np.where(n > 1e-9, feet / np.maximum(n, 1e-9), 0.0)
        soles = base[None, :, None] + ext[None, :, :, None] * u[:, :, None]  # (P, f, 2, 2)
        P = len(feet)
        pts = np.concatenate([np.broadcast_to(self._poly, (P,) + self._poly.shape),
                              soles.reshape(P, -1, 2)], axis=1)
        return pts, u, n, ext

    def _support_offset_jacobian(self, c2: np.ndarray, feet: np.ndarray | None
                                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """:meth:`support_offset` and its derivatives.

        Outside the support the offset is ``q - (1 - t) a - t b`` to the closest segment
        ``a b`` (of length ``m^0.5``, direction ``d = b - a``): with ``t`` inside (0, 1)
        its derivatives are ``N = I - d d^T / m`` in ``q``, ``-(1 - t) N + d off^T / m``
        in ``a`` and ``-t N - d off^T / m`` in ``b``; at an end, ``I`` and ``-I``. A sole's
        ends move with its foot's unit direction ``u = v / |v|`` (``du/dv = (I - u u^T) /
        |v|``).

        Returns:
            ``(off (P, 2), d off / d c2 (P, 2, 2), d off / d feet (P, f, 2, 2) or None)``.
        """
        off, closest = self._support_offset_closest(c2, feet)
        return (off, *self._support_offset_derivatives(c2, off, closest))

    def _support_offset_closest(self, c2: np.ndarray, feet: np.ndarray | None
                                ) -> tuple[np.ndarray, tuple | None]:
        """:meth:`support_offset` and where its closest point is (None without soles).

        The first half of :meth:`_support_offset_jacobian`: a trial point of the
        trust-region solve needs the offset, not its derivatives
        (:meth:`_support_offset_derivatives`).
        """
        if not self.footprints or feet is None:
            return polygon_offset(c2, self._poly), None
        pts, u, n, ext = self._support_points(feet)
        off, i, j, t, inside = hull_offset(c2, pts, closest=True)
        return off, (pts, u, n, ext, i, j, t, inside)

    def _support_offset_derivatives(self, c2: np.ndarray, off: np.ndarray,
                                    closest: tuple | None
                                    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The derivatives of :meth:`_support_offset_jacobian` from its first half.

        Args:
            c2: Centres of mass on the ground plane, shape ``(P, 2)``.
            off: Their offsets, shape ``(P, 2)``.
            closest: :meth:`_support_offset_closest`'s second item.

        Returns:
            ``(d off / d c2 (P, 2, 2), d off / d feet (P, f, 2, 2) or None)``.
        """
        P = len(c2)
        eye = np.eye(2)
        if closest is None:
            h = 1e-7  # piecewise linear: differences are exact away from the corners
            o = polygon_offset(np.concatenate([c2 + [h, 0.0], c2 + [0.0, h]]), self._poly)
            return np.stack([o[:P] - off, o[P:] - off], axis=2) / h, None
        nf = len(self.footprints)
        pts, u, n, ext, i, j, t, inside = closest
        k0 = len(self._poly)
        rows = np.arange(P)
        d = pts[rows, j] - pts[rows, i]
        m = np.maximum(np.einsum("pd,pd->p", d, d), 1e-18)
        N = eye - d[:, :, None] * d[:, None, :] / m[:, None, None]
        on = ((t > 0) & (t < 1))[:, None, None]
        dq = np.where(on, N, eye)
        dq[inside] = 0.0
        dod = d[:, :, None] * off[:, None, :] / m[:, None, None]
        da = np.where(on, -(1 - t)[:, None, None] * N + dod, np.where(t[:, None, None] <= 0,
                                                                      -eye, 0.0))
        db = np.where(on, -t[:, None, None] * N - dod, np.where(t[:, None, None] >= 1,
                                                               -eye, 0.0))
        da[inside] = 0.0
        db[inside] = 0.0
        du = (eye - u[..., :, None] * u[..., None, :]) / np.maximum(n, 1e-9)[..., None]
        du = np.where(n[..., None] > 1e-9, du, 0.0)  # (P, f, 2, 2)
        df = np.zeros((P, nf, 2, 2))
        for end, dend in ((i, da), (j, db)):
            s_ = end - k0  # sole point index: foot s_ // 2, heel or toe s_ % 2
            sole = s_ >= 0
            if np.any(sole):
                r, f, e = rows[sole], s_[sole] // 2, ext[s_[sole] // 2, s_[sole] % 2]
                df[r, f] += e[:, None, None] * dend[sole] @ du[r, f]
        return dq, df

    def _balance(self, heads, tails, grad, frames=None, joints=None):
        P = heads.shape[0]
        if len(self._poly) == 0:
            return np.zeros(P), None, None
        m = self._mass_share
        com = self._centre_of_mass(heads, tails, frames)
        feet = self._feet(joints) if self.footprints and joints is not None else None
        if not grad or feet is None:
            off = self.support_offset(com @ self._ground, feet)
            energy = np.sum(off**2, 1) / self.height**2
            if not grad:
                return energy, None, None
            gc = (2.0 * off / self.height**2) @ self._ground.T  # d |off|^2 / d q = 2 off
            return energy, 0.5 * m[None, :, None] * gc[:, None, :], None
        off, dc, df = self._support_offset_jacobian(com @ self._ground, feet)
        energy = np.sum(off**2, 1) / self.height**2
        go = 2.0 * off / self.height**2
        gc = np.einsum("pi,pij->pj", go, dc) @ self._ground.T
        g = 0.5 * m[None, :, None] * gc[:, None, :]
        gj = None
        if df is not None:  # the soles turn with the feet
            gf = np.einsum("pi,pfij->pfj", go, df) @ self._ground.T  # (P, f, 3)
            gj = np.zeros_like(joints)
            np.add.at(gj, (slice(None), [f.tip for f in self.footprints]), gf)
            np.add.at(gj, (slice(None), [f.joint for f in self.footprints]), -gf)
        return energy, g, gj

    def _attachment(self, joints, grad):
        energy = np.zeros(joints.shape[0])
        g = np.zeros_like(joints) if grad else None
        h2 = self.height**2
        for pin in self.env_pins:
            dist = (joints[:, pin.joint] - pin.target) @ pin.normal
            energy += dist**2 / h2
            if grad:
                g[:, pin.joint] += 2.0 * dist[:, None] * pin.normal / h2
        for pin in self.limb_pins:
            a, b = pin.limb
            d = joints[:, pin.joint] - pin.target(joints)
            energy += np.sum(d**2, 1) / h2
            if grad:
                g[:, pin.joint] += 2 * d / h2
                g[:, a] -= 2 * (1 - pin.s) * d / h2
                g[:, b] -= 2 * pin.s * d / h2
        return energy, g

    def _collision(self, heads, tails, grad, body: bool = True, samples: int = 5):
        scale = (0.05 * self.height) ** 2
        if body:
            e_body, gh, gt = body_collision(self.capsules, heads, tails, grad)
        else:
            e_body, gh, gt = np.zeros(heads.shape[0]), None, None
        energy = e_body
        if self.grid is not None and np.any(self.env_capsules):
            on = self.env_capsules
            radii = self.capsules.radii[on]
            start, end = self.capsules.segments(heads, tails)
            u = axis_samples(samples)
            pts = start[:, on, None] * (1 - u)[:, None] + end[:, on, None] * u[:, None]
            d, gd = self.grid.sample(pts, limit=1.001 * radii.max())
            pen = np.maximum(radii[None, :, None] - d, 0.0)
            energy = energy + np.sum(pen**2, axis=(1, 2))
            if grad:
                gp = -2.0 * pen[..., None] * gd
                g0, g1 = np.zeros_like(start), np.zeros_like(end)
                g0[:, on] = np.einsum("pcmd,m->pcd", gp, 1 - u)
                g1[:, on] = np.einsum("pcmd,m->pcd", gp, u)
                eh, et = self.capsules.scatter(g0, g1, heads.shape[-2])
                gh, gt = gh + eh, gt + et
        if grad:
            return energy / scale, gh / scale, gt / scale
        return energy / scale, None, None

    def _full_length(self, joints: np.ndarray) -> tuple[np.ndarray, ...]:
        """``l_full`` of every drawn edge ``(..., E)``.

        Returns:
            ``(l_full, edge vectors, 3D lengths, midpoint depths or None)``.
        """
        a, b = self._edges[:, 0], self._edges[:, 1]
        v = joints[..., b, :] - joints[..., a, :]
        length = np.maximum(np.linalg.norm(v, axis=-1), 1e-12)
        if not self.camera.is_perspective:
            return length * self._ppu1, v, length, None
        depth = np.maximum(self.camera.depth(0.5 * (joints[..., a, :] + joints[..., b, :])),
                           1e-6)
        return length * self._ppu1 / depth, v, length, depth

    def foreshortening_residuals(self, joints: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Unweighted ``(l_proj - min(l_drawn, l_full)) / l_full`` per drawn edge.

        Args:
            joints: World stick joints, shape ``(..., J, 3)``.
            q: Their pixels, shape ``(..., J, 2)``.

        Returns:
            Residuals, shape ``(..., E)``.
        """
        a, b = self._edges[:, 0], self._edges[:, 1]
        lp = np.linalg.norm(q[..., b, :] - q[..., a, :], axis=-1)
        lf = self._full_length(joints)[0]
        return (lp - np.minimum(self._drawn_len, lf)) / lf

    def _foreshortening_jacobian(self, joints, Jj, q, dq) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`foreshortening_residuals` of one pose and their Jacobian.

        Args:
            joints: Stick joints, shape ``(J, 3)``.
            Jj: Their Jacobian, shape ``(J, 3, G)``.
            q: Their pixels, shape ``(J, 2)``.
            dq: The pixels' Jacobian, shape ``(J, 2, G)``.

        Returns:
            ``(r (E,), dr/dx (E, G))``.
        """
        a, b = self._edges[:, 0], self._edges[:, 1]
        u = q[b] - q[a]
        lp = np.maximum(np.linalg.norm(u, axis=-1), 1e-12)
        dlp = np.einsum("ek,ekg->eg", u / lp[:, None], dq[b] - dq[a])
        lf, v, length, depth = self._full_length(joints)
        dlen = np.einsum("ed,edg->eg", v / length[:, None], Jj[b] - Jj[a])
        if depth is None:
            dlf = self._ppu1 * dlen
        else:
            view_z = self.camera.view_matrix[2, :3]
            ddepth = -np.einsum("d,edg->eg", view_z, 0.5 * (Jj[a] + Jj[b]))
            dlf = (self._ppu1 / depth)[:, None] * dlen - (lf / depth)[:, None] * ddepth
        short = self._drawn_len < lf
        target = np.where(short, self._drawn_len, lf)
        dtarget = np.where(short[:, None], 0.0, dlf)
        r = (lp - target) / lf
        return r, (dlp - dtarget) / lf[:, None] - (r / lf)[:, None] * dlf

    def comfort_residuals(self, genes: np.ndarray) -> np.ndarray:
        """Weighted comfort residuals ``(P, G - 6)``: ``sqrt(w / m) (g - g_0) / h``.

        Their squares sum to ``w_com E_com``; their Jacobian is the constant diagonal
        ``sqrt(w / m) / h`` on the rotation genes.
        """
        x = np.atleast_2d(genes)[:, N_ROOT_GENES:]
        return (x - self._comfort_ref) * self._comfort_scale

    # -- public ----------------------------------------------------------------------------

    def energies(self, heads: np.ndarray, tails: np.ndarray, collision: bool = True,
                 grad: bool = False, frames: np.ndarray | None = None
                 ) -> tuple[np.ndarray, dict, np.ndarray | None, np.ndarray | None]:
        """Weighted total energy of posed bones.

        Args:
            heads: Posed heads, shape ``(P, n, 3)``.
            tails: Posed tails, shape ``(P, n, 3)``.
            collision: Include Eq. 11.
            grad: Also return the gradients with respect to heads and tails.
            frames: Posed frames ``(P, n, 3, 3)`` when the rigid bones were not posed
                (``collision`` False only; see :meth:`_centre_of_mass`), else None.

        Returns:
            ``(E (P,), {term: (P,)}, dE/dheads (P, n, 3), dE/dtails (P, n, 3))``.
        """
        fig = self.model.figure
        joints = fig.joint_positions(heads, tails)
        w = self.weights
        e_p, gj_p = self._projection(joints, grad)
        e_b, g_b, gj_b = self._balance(heads, tails, grad, frames, joints)
        e_a, gj_a = self._attachment(joints, grad)
        terms = {"projection": e_p, "balance": e_b, "attachment": e_a}
        total = w.projection * e_p + w.balance * e_b + w.attachment * e_a
        if collision == "environment":
            # The genetic search's cheap check: environment only, three samples per bone.
            e_c, _, _ = self._collision(heads, tails, False, body=False, samples=3)
            terms["collision"] = e_c
            total = total + w.collision * e_c
            collision = False
        elif collision:
            e_c, gh_c, gt_c = self._collision(heads, tails, grad)
            terms["collision"] = e_c
            total = total + w.collision * e_c
        if not grad:
            return total, terms, None, None
        gj = w.projection * gj_p + w.attachment * gj_a
        if gj_b is not None:
            gj = gj + w.balance * gj_b
        gh, gt = np.zeros_like(heads), np.zeros_like(tails)
        tail_mask = fig.joint_at_tail
        np.add.at(gt, (slice(None), fig.joint_bones[tail_mask]), gj[:, tail_mask])
        np.add.at(gh, (slice(None), fig.joint_bones[~tail_mask]), gj[:, ~tail_mask])
        if g_b is not None:
            gh += w.balance * g_b
            gt += w.balance * g_b
        if collision:
            gh += w.collision * gh_c
            gt += w.collision * gt_c
        return total, terms, gh, gt

    def residuals(self, genes: np.ndarray, collision: bool = True) -> np.ndarray:
        """Weighted residuals ``r`` of a population with ``sum(r**2) == E`` per individual.

        Every term is a sum of squares (Eqs. 4-11), so the energy is ``|r|^2`` with
        ``r`` the square roots of the weights times: the projected direction differences
        and joint offsets (Eqs. 4-6), the centre of mass' offset from the support polygon
        (Eqs. 7-8), the pin distances (Eqs. 9-10) and the capsule penetrations (Eq. 11).

        Args:
            genes: Gene vectors, shape ``(P, G)``.
            collision: Include Eq. 11.

        Returns:
            Residuals, shape ``(P, R)``.
        """
        heads, tails, _ = self.model.forward(genes)
        fig, w = self.model.figure, self.weights
        P = heads.shape[0]
        joints = fig.joint_positions(heads, tails)
        q, _ = project_jacobian(self.camera, joints, jacobian=False)
        a, b = self._edges[:, 0], self._edges[:, 1]
        u = q[:, b] - q[:, a]
        uh = u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-9)
        present = self.stick.present
        off = (q[:, present] - self.stick.points[present]) / self._px_scale
        out = [np.sqrt(w.projection) * (uh - self._dirs).reshape(P, -1),
               np.sqrt(w.projection * w.position) * off.reshape(P, -1)]
        if len(self._poly):
            m = self._mass_share
            com = np.einsum("n,pnd->pd", m, 0.5 * (heads + tails))
            bal = self.support_offset(com @ self._ground,
                                      self._feet(joints) if self.footprints else None)
            out.append(np.sqrt(w.balance) * bal / self.height)
        for pin in self.env_pins:
            dist = (joints[:, pin.joint] - pin.target) @ pin.normal
            out.append(np.sqrt(w.attachment) * dist[:, None] / self.height)
        for pin in self.limb_pins:
            d = joints[:, pin.joint] - pin.target(joints)
            out.append(np.sqrt(w.attachment) * d / self.height)
        if w.comfort > 0:
            out.append(self.comfort_residuals(genes))
        if w.foreshortening > 0:
            out.append(np.sqrt(w.foreshortening) * self.foreshortening_residuals(joints, q))
        if collision:
            c = np.sqrt(w.collision) / (0.05 * self.height)
            caps = self.capsules
            start, end = caps.segments(heads, tails)
            if len(caps.pairs):
                ca, cb = caps.pairs[:, 0], caps.pairs[:, 1]
                _, _, d = pair_closest(caps, start, end)
                rr = caps.radii[ca] + caps.radii[cb]
                out.append(c * np.maximum(rr - d, 0.0))
            if self.grid is not None and np.any(self.env_capsules):
                on = self.env_capsules
                radii = caps.radii[on]
                s = axis_samples(5)
                pts = start[:, on, None] * (1 - s)[:, None] + end[:, on, None] * s[:, None]
                d, _ = self.grid.sample(pts, limit=1.001 * radii.max())
                out.append(c * np.maximum(radii[None, :, None] - d, 0.0).reshape(P, -1))
        return np.concatenate(out, axis=1)

    def smooth_residual_count(self, n_genes: int) -> int:
        """How many of :meth:`residuals`' rows come before the capsule penetrations.

        Those rows (Eqs. 4-10, comfort, foreshortening) keep their derivative everywhere;
        a penetration row (Eq. 11) is zero, with a zero Jacobian row, wherever its
        capsules do not overlap.

        Args:
            n_genes: Length of the gene vector.
        """
        e, p = len(self._edges), int(np.sum(self.stick.present))
        n = 2 * e + 2 * p + (2 if len(self._poly) else 0) + len(self.env_pins)
        n += 3 * len(self.limb_pins)
        n += n_genes - N_ROOT_GENES if self.weights.comfort > 0 else 0
        return n + (e if self.weights.foreshortening > 0 else 0)

    def residuals_and_jacobian(self, x: np.ndarray, collision: bool = True
                               ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`residuals` of one gene vector ``(G,)`` and their analytic Jacobian.

        Chains each residual's derivative with respect to joints, bone ends or the
        centre of mass with :meth:`.kinematics.PoseModel.jacobian`; capsule penetrations
        are differentiated at fixed closest points (Danskin), like the energy's gradient.

        Returns:
            ``(r (R,), dr/dx (R, G))``, ``r`` in the order of :meth:`residuals`.
        """
        r, jacobian = self.residuals_deferred(x, collision)
        return r, jacobian()

    def residuals_deferred(self, x: np.ndarray, collision: bool = True
                           ) -> tuple[np.ndarray, Callable[[], np.ndarray]]:
        """:meth:`residuals_and_jacobian` with the Jacobian computed only when asked for.

        A trust-region step that is rejected needs the residuals at its trial point, not
        their Jacobian. Both come from the same operations as in
        :meth:`residuals_and_jacobian` (bit-identical).

        Args:
            x: Gene vector, shape ``(G,)``.
            collision: Include Eq. 11's penetration rows.

        Returns:
            ``(r (R,), jacobian)``: ``jacobian()`` returns ``dr/dx (R, G)``.
        """
        fig, w = self.model.figure, self.weights
        state = self.model.posed(x)
        heads, tails = state[0], state[1]
        G = x.size
        bones, at_tail = fig.joint_bones, fig.joint_at_tail
        joints = np.where(at_tail[:, None], tails[bones], heads[bones])
        q, Jq = project_jacobian(self.camera, joints)
        a, b = self._edges[:, 0], self._edges[:, 1]
        u = q[b] - q[a]
        n = np.maximum(np.linalg.norm(u, axis=-1), 1e-9)
        uh = u / n[:, None]
        present = self.stick.present
        off = (q[present] - self.stick.points[present]) / self._px_scale
        sp, spp = np.sqrt(w.projection), np.sqrt(w.projection * w.position)
        rs = [sp * (uh - self._dirs).ravel(), spp * off.ravel()]
        sb = np.sqrt(w.balance) / self.height
        if len(self._poly):
            m = self._mass_share
            com = m @ (0.5 * (heads + tails))
            feet = self._feet(joints[None]) if self.footprints else None
            c2 = (com @ self._ground)[None]
            o, closest = self._support_offset_closest(c2, feet)
            rs.append(sb * o[0])
        sa = np.sqrt(w.attachment) / self.height
        for pin in self.env_pins:
            rs.append(sa * np.atleast_1d((joints[pin.joint] - pin.target) @ pin.normal))
        for pin in self.limb_pins:
            rs.append(sa * (joints[pin.joint] - pin.target(joints)))
        if w.comfort > 0:
            rs.append(self.comfort_residuals(x)[0])
        done: list[tuple[np.ndarray, ...]] = []

        def joint_jacobians() -> tuple[np.ndarray, ...]:
            """Heads', tails', stick joints' and their images' Jacobians, computed once."""
            if not done:
                Jh, Jt = self.model.jacobian_at(x, state)
                Jj = np.where(at_tail[:, None, None], Jt[bones], Jh[bones])  # (J, 3, G)
                done.append((Jh, Jt, Jj, np.einsum("jkd,jdg->jkg", Jq, Jj)))
            return done[0]

        if w.foreshortening > 0:
            # Its residuals and Jacobian come together (cheap: a few edges).
            _, _, Jj, dq = joint_jacobians()
            rf, jf = self._foreshortening_jacobian(joints, Jj, q, dq)
            rs.append(np.sqrt(w.foreshortening) * rf)
        c = np.sqrt(w.collision) / (0.05 * self.height)
        caps = self.capsules
        pairs = collision and len(caps.pairs)
        env = collision and self.grid is not None and np.any(self.env_capsules)
        if collision:
            start, end = caps.segments(heads, tails)
        if pairs:
            ca, cb = caps.pairs[:, 0], caps.pairs[:, 1]
            s_, t_, d = pair_closest(caps, start, end)
            pen_pairs = np.maximum(self._pair_reach - d, 0.0)
            rs.append(c * pen_pairs)
        if env:
            cc, radii = self._env_on, self._env_radii
            sm = axis_samples(5)
            pts = start[cc, None] * (1 - sm)[:, None] + end[cc, None] * sm[:, None]
            d_env, gd = self.grid.sample(pts, limit=1.001 * radii.max())
            pen_env = np.maximum(radii[:, None] - d_env, 0.0)
            rs.append(c * pen_env.ravel())

        def jacobian() -> np.ndarray:
            Jh_, Jt_, Jj_, dq_ = joint_jacobians()
            P = (np.eye(2) - uh[:, :, None] * uh[:, None, :]) / n[:, None, None]
            js = [sp * np.einsum("eij,ejg->eig", P, dq_[b] - dq_[a]).reshape(-1, G),
                  spp * dq_[present].reshape(-1, G) / self._px_scale]
            if len(self._poly):
                dc, df = self._support_offset_derivatives(c2, o, closest)
                dcom = np.einsum("n,ndg->dg", m, 0.5 * (Jh_ + Jt_))
                jb = dc[0] @ self._ground.T @ dcom
                for k, f in enumerate(self.footprints):  # the soles turn with the feet
                    jb = jb + df[0, k] @ self._ground.T @ (Jj_[f.tip] - Jj_[f.joint])
                js.append(sb * jb)
            for pin in self.env_pins:
                js.append(sa * (pin.normal @ Jj_[pin.joint])[None])
            for pin in self.limb_pins:
                js.append(sa * (Jj_[pin.joint] - pin.target(Jj_, axis=0)))
            if w.comfort > 0:
                js.append(self._comfort_jacobian)
            if w.foreshortening > 0:
                js.append(np.sqrt(w.foreshortening) * jf)
            if collision:
                J0, J1 = caps.segment_jacobians(Jh_, Jt_)
            if pairs:
                jac = np.zeros((len(pen_pairs), G))
                on = np.flatnonzero(pen_pairs > 0)
                if on.size:
                    s1, t1 = s_[on, None], t_[on, None]
                    a_, b_ = ca[on], cb[on]
                    p0, p1, q0, q1 = start[a_], end[a_], start[b_], end[b_]
                    diff = p0 + s1 * (p1 - p0) - q0 - t1 * (q1 - q0)
                    un = diff / np.maximum(d[on], 1e-12)[:, None]
                    dd = ((1 - s1)[..., None] * J0[a_] + s1[..., None] * J1[a_] -
                          (1 - t1)[..., None] * J0[b_] - t1[..., None] * J1[b_])
                    jac[on] = -np.einsum("qd,qdg->qg", un, dd)
                js.append(c * jac)
            if env:
                jac = np.zeros(pen_env.shape + (G,))
                ci, mi = np.nonzero(pen_env > 0)
                if ci.size:
                    dp = ((1 - sm[mi])[:, None, None] * J0[cc[ci]] +
                          sm[mi][:, None, None] * J1[cc[ci]])
                    jac[ci, mi] = -np.einsum("kd,kdg->kg", gd[ci, mi], dp)
                js.append(c * jac.reshape(-1, G))
            return np.concatenate(js, axis=0)

        return np.concatenate(rs), jacobian

    def pose(self, genes: np.ndarray, collision: bool) -> tuple[np.ndarray, ...]:
        """A population posed as :meth:`evaluate` reads it, ``(P, G)``.

        Returns:
            Heads and tails ``(P, n, 3)``, with every bone when collisions are scored;
            without them (``collision`` False) the rigid bones (fingers) are left out and
            the frames come too (:meth:`.PoseModel.forward` with ``rigid`` False).
        """
        if collision is False:
            return self.model.forward(genes, rigid=False)
        return self.model.forward(genes)[:2]

    def evaluate(self, genes: np.ndarray, collision: bool = True,
                 posed: tuple[np.ndarray, ...] | None = None
                 ) -> tuple[np.ndarray, dict]:
        """Energies of a population, ``(P, G) -> ((P,), {term: (P,)})``.

        ``posed``: the population's heads and tails ``(P, n, 3)`` when the caller has
        already posed it (:meth:`.PoseModel.forward`), or heads, tails and frames posed
        without the rigid bones (``rigid`` False, ``collision`` False only), else None.
        Without collisions the rigid bones (fingers) are not posed: only the centre of
        mass reads them (:meth:`_centre_of_mass`).
        """
        if posed is None:
            posed = self.pose(genes, collision)
        heads, tails = posed[:2]
        frames = posed[2] if len(posed) > 2 else None
        total, terms, _, _ = self.energies(heads, tails, collision, frames=frames)
        if self.weights.comfort > 0:
            c = np.sum(self.comfort_residuals(genes) ** 2, 1)
            terms["comfort"] = c / self.weights.comfort
            total = total + c
        if self.weights.foreshortening > 0:
            joints = self.model.figure.joint_positions(heads, tails)
            q, _ = project_jacobian(self.camera, joints, jacobian=False)
            f = np.sum(self.foreshortening_residuals(joints, q) ** 2, -1)
            terms["foreshortening"] = f
            total = total + self.weights.foreshortening * f
        return total, terms

    def value_and_grad(self, x: np.ndarray, collision: bool = True
                       ) -> tuple[float, np.ndarray]:
        """Energy and analytic gradient of one gene vector ``(G,)``."""
        heads, tails, Jh, Jt = self.model.jacobian(x)
        total, _, gh, gt = self.energies(heads[None], tails[None], collision, grad=True)
        g = np.einsum("nd,ndg->g", gh[0], Jh) + np.einsum("nd,ndg->g", gt[0], Jt)
        total = float(total[0])
        if self.weights.comfort > 0:
            r = self.comfort_residuals(x)[0]
            total += float(r @ r)
            g[N_ROOT_GENES:] += 2.0 * r * self._comfort_scale
        if self.weights.foreshortening > 0:
            fig = self.model.figure
            joints = fig.joint_positions(heads, tails)
            Jj = np.where(fig.joint_at_tail[:, None, None], Jt[fig.joint_bones],
                          Jh[fig.joint_bones])
            q, Jq = project_jacobian(self.camera, joints)
            rf, jf = self._foreshortening_jacobian(joints, Jj, q,
                                                   np.einsum("jkd,jdg->jkg", Jq, Jj))
            total += self.weights.foreshortening * float(rf @ rf)
            g += 2.0 * self.weights.foreshortening * (rf @ jf)
        return total, g
