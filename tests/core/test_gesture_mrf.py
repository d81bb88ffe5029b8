"""The tree DP with pairwise and triplet factors equals brute force on small trees."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from gesture_pose.core.exceptions import InputError
from gesture_pose.core.gesture.mrf import TreeEnergy, min_marginals, solve_tree


def _random_energy(parent: list[int], sizes: list[int], seed: int,
                   triplets: bool = True) -> TreeEnergy:
    rng = np.random.default_rng(seed)
    par = np.array(parent)
    unary = tuple(rng.random(k) for k in sizes)
    pair = tuple(None if p < 0 else rng.random((sizes[p], sizes[j])) for j, p in enumerate(par))
    trip = []
    for j, p in enumerate(par):
        if triplets and p >= 0 and par[p] >= 0:
            trip.append(rng.random((sizes[par[p]], sizes[p], sizes[j])))
        else:
            trip.append(None)
    return TreeEnergy(par, unary, pair, tuple(trip))


def _brute(energy: TreeEnergy) -> tuple[np.ndarray, float]:
    best, arg = np.inf, None
    for labels in itertools.product(*[range(len(u)) for u in energy.unary]):
        e = energy.evaluate(np.array(labels))
        if e < best:
            best, arg = e, np.array(labels)
    return arg, best


@pytest.mark.parametrize("parent,sizes", [
    ([-1, 0, 1, 2], [3, 4, 2, 3]),            # chain: triplets on nodes 2 and 3
    ([-1, 0, 0, 1, 2, 1], [2, 3, 3, 2, 3, 2]),  # branching at the root and below
    ([-1, 0, 1, 1, 1, -1, 5], [3, 2, 3, 2, 2, 3, 2]),  # a forest, a 3-way branch
])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dp_equals_brute_force(parent, sizes, seed):
    energy = _random_energy(parent, sizes, seed)
    labels, value = solve_tree(energy)
    ref_labels, ref_value = _brute(energy)
    assert value == pytest.approx(ref_value, abs=1e-12)
    assert energy.evaluate(labels) == pytest.approx(ref_value, abs=1e-12)
    np.testing.assert_array_equal(labels, ref_labels)


def test_dp_without_triplets_and_single_node():
    energy = _random_energy([-1, 0, 0, 2], [4, 3, 2, 3], seed=7, triplets=False)
    labels, value = solve_tree(energy)
    assert value == pytest.approx(_brute(energy)[1])
    single = TreeEnergy(np.array([-1]), (np.array([0.5, 0.2, 0.9]),), (None,), (None,))
    assert solve_tree(single)[0].tolist() == [1]


def test_wrong_table_shape_is_rejected():
    with pytest.raises(InputError):
        TreeEnergy(np.array([-1, 0]), (np.zeros(2), np.zeros(3)), (None, np.zeros((3, 3))),
                   (None, None))


@pytest.mark.parametrize("parent,sizes", [
    ([-1, 0, 1, 2], [3, 4, 2, 3]),
    ([-1, 0, 0, 1, 2, 1], [2, 3, 3, 2, 3, 2]),
    ([-1, 0, 1, 1, 1, -1, 5], [3, 2, 3, 2, 2, 3, 2]),
])
def test_min_marginals_equal_brute_force(parent, sizes):
    energy = _random_energy(parent, sizes, seed=5, triplets=False)
    got = min_marginals(energy)
    par = np.array(parent)
    tree = np.zeros(len(par), int)  # the root of each node's tree
    for j, p in enumerate(par):
        tree[j] = j if p < 0 else tree[p]
    for j in range(len(par)):
        same = np.flatnonzero(tree == tree[j])
        for b in range(sizes[j]):
            best = np.inf
            for labels in itertools.product(*[range(sizes[k]) for k in same]):
                lab = dict(zip(same.tolist(), labels, strict=True))
                if lab[j] != b:
                    continue
                e = sum(energy.unary[k][lab[k]] for k in same)
                e += sum(energy.pairwise[k][lab[par[k]], lab[k]] for k in same if par[k] >= 0)
                best = min(best, e)
            assert got[j][b] == pytest.approx(best, abs=1e-12)


def test_min_marginals_refuse_triplets():
    with pytest.raises(InputError):
        min_marginals(_random_energy([-1, 0, 1], [2, 2, 2], seed=0))


def test_memo_reuses_unchanged_subtrees_and_stays_exact():
    energy = _random_energy([-1, 0, 1, 1, 3, 0], [3, 2, 3, 2, 3, 2], seed=11)
    memo: dict = {}
    first = solve_tree(energy, memo)
    assert len(memo) == 6
    # Change the candidates of node 4 (a leaf under 3): only 4, 3, 1 and the root change.
    unary = list(energy.unary)
    unary[4] = unary[4] + np.array([5.0, 0.0, 5.0])
    changed = TreeEnergy(energy.parent, tuple(unary), energy.pairwise, energy.triplet)
    labels, value = solve_tree(changed, memo)
    assert len(memo) == 6 + 4
    assert value == pytest.approx(_brute(changed)[1], abs=1e-12)
    assert changed.evaluate(labels) == pytest.approx(value, abs=1e-12)
    assert solve_tree(energy, memo)[1] == pytest.approx(first[1])
