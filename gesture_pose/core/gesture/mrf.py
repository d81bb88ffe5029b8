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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..exceptions import InputError


@dataclass(frozen=True)
class TreeEnergy:
    """Factor tables of a tree-structured energy.

    Attributes:
        parent: Parent of each node, -1 for roots; parents have smaller indices, ``(J,)``.
        unary: Per node, ``(K_j,)``.
        pairwise: Per node, ``(K_parent, K_j)`` or None for roots.
        triplet: Per node, ``(K_grandparent, K_parent, K_j)`` or None.
    """

    parent: np.ndarray
    unary: tuple[np.ndarray, ...]
    pairwise: tuple[np.ndarray | None, ...]
    triplet: tuple[np.ndarray | None, ...]

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


def solve_tree(energy: TreeEnergy) -> tuple[np.ndarray, float]:
    """Exact minimizer of a tree energy with pairwise and triplet factors.

    Args:
        energy: The factor tables.

    Returns:
        ``(labels (J,), minimum energy)``.
    """
    par = np.asarray(energy.parent, dtype=int)
    n = len(par)
    children = [np.flatnonzero(par == j) for j in range(n)]
    table: list[np.ndarray | None] = [None] * n
    arg: dict[int, np.ndarray] = {}
    for j in range(n - 1, -1, -1):
        p = par[j]
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
            table[c] = None
        table[j] = acc
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
