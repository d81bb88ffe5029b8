"""Hand-built gesture drawings and meshes shared by the gesture-mode tests (no tests here)."""

from __future__ import annotations

import numpy as np


def arc(centre, radius: float, a0: float, a1: float, n: int = 24) -> np.ndarray:
    """Points on a circular arc from ``a0`` to ``a1`` degrees, ``(n, 2)``."""
    t = np.radians(np.linspace(a0, a1, n))
    return np.stack([centre[0] + radius * np.cos(t), centre[1] + radius * np.sin(t)], 1)


def segment(a, b, n: int = 30) -> np.ndarray:
    """Points on a straight segment, ``(n, 2)``."""
    return np.linspace(np.asarray(a, float), np.asarray(b, float), n)


def bent_arm_outline(shoulder, elbow, wrist_up: float, r: float) -> np.ndarray:
    """Closed outline (x, z) of an arm along +x bent 90 degrees up at the elbow.

    Args:
        shoulder: Shoulder centre ``(x, z)``.
        elbow: Elbow centre ``(x, z)`` (same z as the shoulder).
        wrist_up: Forearm length (the wrist is above the elbow).
        r: Limb radius.
    """
    s, e = np.asarray(shoulder, float), np.asarray(elbow, float)
    w = e + [0.0, wrist_up]
    return np.concatenate([
        segment([s[0], e[1] - r], [e[0], e[1] - r]),
        arc(e, r, -90, 0),                       # the elbow's outer arc
        segment([e[0] + r, e[1]], [w[0] + r, w[1]]),
        arc(w, r, 0, 180),                       # the hand's cap
        segment([w[0] - r, w[1]], [e[0] - r, e[1] + r]),
        segment([e[0] - r, e[1] + r], [s[0], s[1] + r]),
        arc(s, r, 90, 270),                      # the shoulder's cap
    ])


def capsule_vertices(points: np.ndarray, radius: float, per_bone: int = 400,
                     seed: int = 0) -> np.ndarray:
    """Random surface points of capsules around a chain of 3D points, ``(V, 3)``."""
    rng = np.random.default_rng(seed)
    out = []
    for a, b in zip(points[:-1], points[1:], strict=True):
        d = b - a
        u = d / np.linalg.norm(d)
        v = np.cross(u, [0.0, 1.0, 0.0] if abs(u[1]) < 0.9 else [1.0, 0.0, 0.0])
        v /= np.linalg.norm(v)
        w = np.cross(u, v)
        t, ang = rng.random(per_bone), rng.random(per_bone) * 2 * np.pi
        out.append(a + t[:, None] * d + radius * (np.cos(ang)[:, None] * v
                                                  + np.sin(ang)[:, None] * w))
    for p in points:
        s = rng.normal(size=(per_bone // 2, 3))
        out.append(p + radius * s / np.linalg.norm(s, axis=1, keepdims=True))
    return np.concatenate(out)


def uv_sphere(centre, radius: float, rings: int = 24, segments: int = 48
              ) -> tuple[np.ndarray, np.ndarray]:
    """A closed UV sphere: vertices ``(V, 3)`` and outward-wound triangles ``(T, 3)``."""
    phi = np.linspace(0, np.pi, rings + 1)[1:-1]
    theta = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    p, t = np.meshgrid(phi, theta, indexing="ij")
    ring = np.stack([np.sin(p) * np.cos(t), np.sin(p) * np.sin(t), np.cos(p)], -1).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]]) * radius + np.asarray(centre)
    tris = []
    top, bottom = 0, len(verts) - 1
    idx = lambda i, j: 1 + i * segments + (j % segments)  # noqa: E731
    for j in range(segments):
        tris.append([top, idx(0, j), idx(0, j + 1)])
        tris.append([bottom, idx(rings - 2, j + 1), idx(rings - 2, j)])
    for i in range(rings - 2):
        for j in range(segments):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j), idx(i + 1, j + 1)
            tris += [[a, c, b], [b, c, d]]
    return verts, np.array(tris)
