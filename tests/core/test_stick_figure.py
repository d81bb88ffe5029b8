"""The humanoid stick model and the population forward kinematics with its Jacobian.

Also provides :func:`humanoid_skeleton`, a 24-bone core skeleton shaped like the sample
humanoid, for the other stick tests.
"""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.exceptions import InputError
from gesture_pose.core.skeleton import Pose, Skeleton
from gesture_pose.core.stick.figure import bone_side, find_humanoid_bones, humanoid_figure
from gesture_pose.core.stick.kinematics import PoseModel, _frames_times, right_jacobian
from tests.core.fixtures import chain_skeleton, frame_along


def _skeleton(rows: list[tuple[str, str | None, tuple, tuple]], connected: bool) -> Skeleton:
    """A skeleton from ``(name, parent or None, head, tail)`` rows listed parents first."""
    order = {r[0]: i for i, r in enumerate(rows)}
    heads = np.array([r[2] for r in rows], float)
    tails = np.array([r[3] for r in rows], float)
    n = len(rows)
    frames = np.stack([frame_along(t - h, 0.1 * i)
                       for i, (h, t) in enumerate(zip(heads, tails, strict=True))])
    return Skeleton(
        names=tuple(r[0] for r in rows),
        parents=np.array([order[r[1]] if r[1] else -1 for r in rows]),
        rest_heads=heads, rest_tails=tails, rest_frames=frames,
        inherit_rotation=np.ones(n, bool), connected=np.full(n, connected),
        deform=np.ones(n, bool))


def humanoid_skeleton() -> Skeleton:
    """A 1.8 m humanoid facing -Y (left is +X), arms in an A-pose, parents first."""
    bones: list[tuple[str, str | None, tuple, tuple]] = [
        ("pelvis", None, (0, 0, 0.93), (0, -0.01, 1.04)),
        ("spine", "pelvis", (0, -0.01, 1.04), (0, 0, 1.16)),
        ("spine.001", "spine", (0, 0, 1.16), (0, 0.01, 1.28)),
        ("chest", "spine.001", (0, 0.01, 1.28), (0, 0, 1.45)),
        ("neck", "chest", (0, 0, 1.45), (0, -0.01, 1.56)),
        ("head", "neck", (0, -0.01, 1.56), (0, -0.02, 1.72)),
    ]
    c, s = np.cos(np.radians(40)), np.sin(np.radians(40))
    for side, sx in (("L", 1.0), ("R", -1.0)):
        sh = np.array([0.18 * sx, 0.01, 1.43])
        el = sh + [0.29 * c * sx, 0.025, -0.29 * s]
        wr = el + [0.26 * c * sx, -0.03, -0.26 * s]
        kn = wr + [0.09 * c * sx, -0.005, -0.09 * s]
        hip, knee, ank = (0.10 * sx, 0, 0.93), (0.11 * sx, -0.025, 0.51), (0.12 * sx, 0.02, 0.09)
        ball = (0.125 * sx, -0.10, 0.025)
        bones += [
            (f"shoulder.{side}", "chest", (0.03 * sx, 0, 1.42), tuple(sh)),
            (f"upper_arm.{side}", f"shoulder.{side}", tuple(sh), tuple(el)),
            (f"forearm.{side}", f"upper_arm.{side}", tuple(el), tuple(wr)),
            (f"hand.{side}", f"forearm.{side}", tuple(wr), tuple(kn)),
            (f"thigh.{side}", "pelvis", hip, knee),
            (f"shin.{side}", f"thigh.{side}", knee, ank),
            (f"foot.{side}", f"shin.{side}", ank, ball),
        ]
    return _skeleton(bones, connected=False)


def test_side_markers():
    # The sides names.side_of reads (shared with the gesture mode).
    for name, side in [("upper_arm.L", "L"), ("thigh_R", "R"), ("LeftForeArm", "L"),
                       ("RightUpLeg", "R"), ("l_hand", "L"), ("Hips", ""), ("Neck1", ""),
                       ("leg_joint_R_1", "R"), ("Bip01 L Thigh", "L"),
                       ("DEF-thigh.L.001", "L"), ("L_Thigh", "L"), ("Root", ""),
                       ("Lid", ""), ("mixamorig:LeftUpLeg", "L")]:
        assert bone_side(name) == side, name


@pytest.mark.parametrize("rename", [
    lambda n, s: f"Bip01 {s} {n}" if s else f"Bip01 {n}",  # 3ds Max Biped
    lambda n, s: f"DEF-{n}.{s}.001" if s else f"DEF-{n}",  # Rigify duplicates
    lambda n, s: f"{s}_{n}" if s else n,
    lambda n, s: f"mixamorig:{dict(L='Left', R='Right')[s]}{n}" if s else f"mixamorig:{n}",
])
def test_humanoid_roles_in_other_naming_conventions(rename):
    base = humanoid_skeleton()
    words = {"pelvis": "Hips", "upper_arm": "UpperArm", "forearm": "ForeArm", "thigh": "UpLeg",
             "shin": "Leg"}

    def new(name):
        stem, _, side = name.partition(".")
        side = side if side in ("L", "R") else ""
        stem = words.get(stem, stem.replace(".", "").capitalize())
        return rename(stem, side) if name != "spine.001" else rename("Spine1", "")

    names = tuple(new(n) for n in base.names)
    assert len(set(names)) == len(names)
    sk = Skeleton(names=names, parents=base.parents, rest_heads=base.rest_heads,
                  rest_tails=base.rest_tails, rest_frames=base.rest_frames,
                  inherit_rotation=base.inherit_rotation, connected=base.connected,
                  deform=base.deform)
    found = find_humanoid_bones(sk)
    expected = find_humanoid_bones(base)
    assert {r: base.names[i] for r, i in found.items()} == {
        r: base.names[i] for r, i in expected.items()}


def test_humanoid_roles_by_name():
    sk = humanoid_skeleton()
    b = find_humanoid_bones(sk)
    assert sk.names[b["pelvis"]] == "pelvis"
    assert sk.names[b["forearm.R"]] == "forearm.R"
    assert sk.names[b["shin.L"]] == "shin.L"
    fig = humanoid_figure(sk)
    assert np.allclose(fig.forward, [0.0, -1.0, 0.0], atol=0.05)
    heads, tails = sk.rest_heads, sk.rest_tails
    pos = fig.joint_positions(heads, tails)
    assert np.allclose(pos[fig.joint("elbow.L")], heads[sk.index("forearm.L")])
    assert np.allclose(pos[fig.joint("head")], tails[sk.index("head")])
    assert fig.edges().shape == (14, 2)
    spine = next(g for g in fig.groups if g.name == "spine")
    assert [sk.names[i] for i in spine.bones] == ["spine", "spine.001", "chest"]


def test_not_a_humanoid_says_what_is_missing():
    sk = chain_skeleton(np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2.0]]))
    with pytest.raises(InputError, match="not recognised as a humanoid"):
        find_humanoid_bones(sk)


def test_hinges_flex_the_right_way():
    sk = humanoid_skeleton()
    fig = humanoid_figure(sk)
    model = PoseModel(sk, fig, Pose.identity(sk.n_bones))
    x = np.zeros(model.n_genes)
    x[model.genes_of("shin.L")] = np.radians(90)
    heads, tails, _ = model.forward(x[None])
    ank = heads[0, sk.index("foot.L")]
    knee = heads[0, sk.index("shin.L")]
    # A flexed knee sends the ankle behind the knee (+Y, the character faces -Y).
    assert ank[1] - knee[1] > 0.35


def test_population_fk_matches_skeleton_forward():
    sk = humanoid_skeleton()
    model = PoseModel(sk, humanoid_figure(sk), Pose.identity(sk.n_bones))
    rng = np.random.default_rng(3)
    x = rng.normal(scale=0.4, size=(5, model.n_genes))
    heads, tails, _ = model.forward(x)
    for p in range(5):
        state = sk.forward(model.to_pose(x[p]))
        assert np.allclose(state.heads, heads[p], atol=1e-12)
        assert np.allclose(state.tails, tails[p], atol=1e-12)
    assert np.allclose(heads[:, sk.index("pelvis")], sk.rest_heads[0] + x[:, :3])


def test_rigid_fingers_are_posed_exactly_like_the_chain():
    """Bones no gene turns below a hand (finger chains, one not inheriting its parent's
    rotation, a base pose that bends and shifts them) are posed from constants after the
    chain; heads, tails and frames still match the skeleton's own forward kinematics."""
    core = humanoid_skeleton()
    rows = [(core.names[i], core.names[core.parents[i]] if core.parents[i] >= 0 else None,
             tuple(core.rest_heads[i]), tuple(core.rest_tails[i])) for i in range(core.n_bones)]
    for side, sx in (("L", 1.0), ("R", -1.0)):
        h = core.rest_tails[core.index(f"hand.{side}")]
        parent = f"hand.{side}"
        for k in range(3):
            head = h + np.array([0.02 * sx * k, -0.01 * k, -0.025 * k])
            rows.append((f"finger{k}.{side}", parent, tuple(head),
                         tuple(head + [0.01 * sx, -0.005, -0.025])))
            parent = f"finger{k}.{side}"
    sk = _skeleton(rows, connected=False)
    inherit = np.ones(sk.n_bones, bool)
    inherit[sk.index("finger2.R")] = False
    sk = Skeleton(names=sk.names, parents=sk.parents, rest_heads=sk.rest_heads,
                  rest_tails=sk.rest_tails, rest_frames=sk.rest_frames,
                  inherit_rotation=inherit, connected=sk.connected, deform=sk.deform)
    rng = np.random.default_rng(11)
    from gesture_pose.core.rotations import exp_map
    base = Pose(exp_map(rng.normal(scale=0.3, size=(sk.n_bones, 3))),
                rng.normal(scale=0.01, size=(sk.n_bones, 3)))
    model = PoseModel(sk, humanoid_figure(sk), base)
    fingers = [sk.index(f"finger{k}.{s}") for k in range(3) for s in "LR"]
    rigid = np.setdiff1d(np.arange(sk.n_bones), model._chain)
    # The left fingers are rigid; the right chain up to the non-inheriting bone is not.
    assert {sk.index(f"finger{k}.L") for k in range(3)} <= set(rigid.tolist())
    assert sk.index("finger2.R") in model._chain and sk.index("finger1.R") in model._chain
    x = rng.normal(scale=0.4, size=(6, model.n_genes))
    heads, tails, frames = model.forward(x)
    for p in range(len(x)):
        state = sk.forward(model.to_pose(x[p]))
        assert np.allclose(state.heads, heads[p], atol=1e-12)
        assert np.allclose(state.tails, tails[p], atol=1e-12)
        assert np.allclose(state.frames[fingers], frames[p, fingers], atol=1e-12)
    # Without the rigid bones (the stick joints and the lifted bones only): the chain is
    # the same to the last bit, the rigid bones are left out (NaN).
    h2, t2, f2 = model.forward(x, rigid=False)
    chain = model._chain
    assert np.array_equal(h2[:, chain], heads[:, chain])
    assert np.array_equal(t2[:, chain], tails[:, chain])
    assert np.array_equal(f2[:, chain], frames[:, chain])
    assert np.isnan(h2[:, rigid]).all() and np.isnan(f2[:, rigid]).all()
    fig = model.figure
    assert np.array_equal(fig.joint_positions(h2, t2), fig.joint_positions(heads, tails))
    *_, Q = model.forward_rotations(x, rigid=False)
    assert np.array_equal(Q, model.local_rotations(x)[0])
    # Only some bones' local rotations (the lifted bones'; the root's; a bone no gene
    # turns): the same bits as those rows.
    some = np.array([fig.groups[-1].bones[0], fig.root_bone, fingers[0],
                     fig.groups[0].bones[0]])
    *_, Qs = model.forward_rotations(x, rigid=False, bones=some)
    assert Qs.shape == (len(x), len(some), 3, 3)
    assert np.array_equal(Qs, Q[:, some])
    # What the rigid bones add to a weighted sum of midpoints (the centre of mass) follows
    # from their chain ancestors' frames alone.
    w = np.random.default_rng(3).random(sk.n_bones)
    anchors, W, v = model.rigid_moments(w)
    assert anchors.tolist() == [sk.index("hand.L")]  # the right fingers are on the chain
    mid = 0.5 * (heads + tails)
    want = np.einsum("n,pnd->pd", w[rigid], mid[:, rigid])
    got = np.einsum("a,pad->pd", W, h2[:, anchors]) + np.einsum("paij,aj->pi",
                                                                f2[:, anchors], v)
    assert np.allclose(got, want, atol=1e-13)


def test_frames_times_vectors_row_by_row():
    """The forward pass' frames times vectors: the product, each row the same bits alone."""
    rng = np.random.default_rng(4)
    for k in (1, 2, 3):
        frames = rng.normal(size=(300, 7, 3, 3))[:, [4, 1, 6][:k]]  # a gathered copy
        w = rng.normal(size=(k, 3))
        got = _frames_times(frames, w)
        assert np.allclose(got, np.einsum("pnij,nj->pni", frames, w), rtol=0, atol=1e-14)
        for rows in (slice(0, 1), slice(7, 70), slice(64, 300)):
            assert np.array_equal(_frames_times(frames[rows], w), got[rows])


def test_right_jacobian_against_finite_differences():
    rng = np.random.default_rng(0)
    from gesture_pose.core.rotations import exp_map, log_map
    for phi in [rng.normal(size=3), np.array([1e-8, 0, 0]), rng.normal(size=3) * 2.5]:
        R = exp_map(phi)
        for k in range(3):
            d = np.zeros(3)
            d[k] = 1e-6
            num = log_map(R.T @ exp_map(phi + d)) / 1e-6
            assert np.allclose(num, right_jacobian(phi)[:, k], atol=1e-5)


def test_pose_jacobian_against_finite_differences():
    sk = humanoid_skeleton()
    model = PoseModel(sk, humanoid_figure(sk), Pose.identity(sk.n_bones))
    rng = np.random.default_rng(7)
    x = rng.normal(scale=0.5, size=model.n_genes)
    heads, tails, Jh, Jt = model.jacobian(x)
    h = 1e-6
    X = np.concatenate([x + h * np.eye(x.size), x - h * np.eye(x.size)])
    H, T, _ = model.forward(X)
    num_h = (H[: x.size] - H[x.size:]) / (2 * h)
    num_t = (T[: x.size] - T[x.size:]) / (2 * h)
    assert np.allclose(np.transpose(num_h, (1, 2, 0)), Jh, atol=1e-6)
    assert np.allclose(np.transpose(num_t, (1, 2, 0)), Jt, atol=1e-6)


def quadruped_skeleton() -> Skeleton:
    """A 27-bone quadruped shaped like the sample one (facing -Y, left +X), parents first.

    Spine hips - spine - spine.001 - chest, neck - neck.001 - head off the chest, a 6-bone
    tail off the hips, front legs upper_arm - forearm - front_paw, hind legs thigh - shin -
    hind_foot - hind_paw.
    """
    spine = [(0, 0.45, 0.80), (0, 0.25, 0.83), (0, 0.05, 0.84), (0, -0.15, 0.83),
             (0, -0.35, 0.82)]
    neck = [(0, -0.35, 0.82), (0, -0.45, 0.95), (0, -0.52, 1.08), (0, -0.78, 1.02)]
    tail = [(0.0, 0.45 + 0.12 * i, 0.80 + 0.05 * i - 0.012 * i * i) for i in range(7)]
    rows: list[tuple[str, str | None, tuple, tuple]] = []

    def chain(names, pts, parent):
        for k, name in enumerate(names):
            rows.append((name, parent if k == 0 else names[k - 1], pts[k], pts[k + 1]))

    chain(["hips", "spine", "spine.001", "chest"], spine, None)
    chain(["neck", "neck.001", "head"], neck, "chest")
    chain([f"tail.{i:03d}" for i in range(6)], tail, "hips")
    for side, sx in (("L", 1.0), ("R", -1.0)):
        front = [(0.11 * sx, -0.28, 0.76), (0.12 * sx, -0.22, 0.45), (0.12 * sx, -0.26, 0.08),
                 (0.12 * sx, -0.36, 0.02)]
        hind = [(0.11 * sx, 0.42, 0.76), (0.12 * sx, 0.30, 0.48), (0.12 * sx, 0.42, 0.22),
                (0.12 * sx, 0.38, 0.05), (0.12 * sx, 0.30, 0.02)]
        chain([f"upper_arm.{side}", f"forearm.{side}", f"front_paw.{side}"], front, "chest")
        chain([f"thigh.{side}", f"shin.{side}", f"hind_foot.{side}", f"hind_paw.{side}"],
              hind, "hips")
    return _skeleton(rows, connected=True)


def _knee_angle(heads, tails, sk, upper, lower) -> float:
    """Angle (degrees) between two bones' directions."""
    a = tails[sk.index(upper)] - heads[sk.index(upper)]
    b = tails[sk.index(lower)] - heads[sk.index(lower)]
    return float(np.degrees(np.arccos(a @ b / np.linalg.norm(a) / np.linalg.norm(b))))


def test_quadruped_gets_ranges_from_its_rig():
    from gesture_pose.core.stick.figure import (
        CHAIN_BEND,
        bone_chains,
        chain_kind,
        character_figure,
    )
    sk = quadruped_skeleton()
    fig, humanoid = character_figure(sk)
    assert not humanoid
    use = np.ones(sk.n_bones, bool)
    kinds = {}
    for c in bone_chains(sk, use, sk.index("hips")):
        below = any(c[-1] in sk.ancestors(k)[1:] for k in range(sk.n_bones))
        kinds[sk.names[c[0]]] = (chain_kind(sk, c, below, np.array([0, 0, 1.0]), 0.02, 1.06),
                                 len(c))
    assert kinds == {"spine": ("trunk", 3), "neck": ("neck", 3), "tail.000": ("tail", 6),
                     "upper_arm.L": ("leg", 3), "upper_arm.R": ("leg", 3),
                     "thigh.L": ("leg", 4), "thigh.R": ("leg", 4)}
    groups = {g.name: g for g in fig.groups}
    lateral = np.array([1.0, 0.0, 0.0])
    # Knees, hocks and the front elbows are hinges about the lateral axis (the sagittal
    # plane's normal), flexing 140 degrees the way they bend at rest and 20 the other.
    for name in ("forearm.L", "shin.R", "hind_foot.L"):
        g = groups[name]
        assert g.bounds.shape == (1, 2)
        world_axis = sk.rest_frames[g.bones[0]] @ g.bases[0][:, 0]
        assert abs(world_axis @ lateral) > 0.99
        assert np.allclose(np.degrees(g.bounds[0]), [-20.0, 140.0])
    # Shoulders and hips swing in the sagittal plane more than they spread or twist.
    hip = np.degrees(groups["thigh.L"].bounds)
    assert hip[0, 1] == 100.0 and np.all(np.abs(hip[1:]) <= 45.0)
    # Spine, neck and tail: a chain's segments share its total bend.
    for name, kind, k in (("spine.001", "trunk", 3), ("neck.001", "neck", 3),
                          ("tail.003", "tail", 6)):
        b = np.degrees(groups[name].bounds)
        assert np.isclose(b[0, 1] * k, CHAIN_BEND[kind][0])
        assert np.isclose(b[1, 1] * k, CHAIN_BEND[kind][1])
    total = sum(np.degrees(groups[f"tail.{i:03d}"].bounds[0, 1]) for i in range(6))
    assert np.isclose(total, 180.0)
    # The comfort prior keeps the unit of the old +-90 degree balls (it does not pull a
    # 30-degree segment range harder towards rest).
    assert np.allclose(np.degrees(groups["tail.003"].comfort), [90.0, 45.0, 90.0])
    assert np.allclose(np.degrees(groups["shin.L"].comfort), [90.0])
    # A positive angle flexes: the hind knee at its upper limit bends further than at rest,
    # at its lower one it straightens a little only (20 degrees).
    model = PoseModel(sk, fig, Pose.identity(sk.n_bones))
    lo, hi = model.bounds(sk.rest_heads[0], 0.1).T
    j = 6 + sum(g.bounds.shape[0] for g in fig.groups[:[g.name for g in fig.groups]
                                                      .index("shin.L")])
    rest = _knee_angle(sk.rest_heads, sk.rest_tails, sk, "thigh.L", "shin.L")
    bent = []
    for value in (lo[j], hi[j]):
        x = np.zeros(model.n_genes)
        x[j] = value
        heads, tails, _ = model.forward(x[None])
        bent.append(_knee_angle(heads[0], tails[0], sk, "thigh.L", "shin.L"))
    assert bent[1] > rest + 100.0
    assert abs(bent[0] - rest) < 21.0


def test_ik_limits_take_precedence_over_default_ranges():
    from gesture_pose.core.stick.figure import character_figure
    for sk in (quadruped_skeleton(), humanoid_skeleton()):
        limits = np.full((sk.n_bones, 3, 2), np.nan)
        b = sk.index("shin.L")
        limits[b, 0] = np.radians([-10.0, 95.0])
        limits[b, 2] = np.radians([-5.0, 5.0])
        fig, _ = character_figure(sk, limits)
        g = next(g for g in fig.groups if g.name == "shin.L")
        assert np.allclose(g.bases[0], np.eye(3)) and g.comfort is None
        assert np.allclose(np.degrees(g.bounds), [[-10.0, 95.0], [-120.0, 120.0], [-5, 5]])
        other = next(g for g in fig.groups if g.name == "shin.R")
        assert other.bounds.shape == (1, 2)  # unlimited bones keep their default hinge
