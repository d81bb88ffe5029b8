"""Section 5.4's enumeration of terminal assignments on small hand-made cases."""

from __future__ import annotations

import numpy as np

from gesture_pose.core.gesture.consistency import first_consistent, terminal_order


def test_assignments_by_unary_cost_with_violators_last():
    costs = [np.array([0.3, 0.0, 0.5]), np.array([0.2, 0.1])]
    violates = [np.array([False, True, False]), np.array([False, False])]
    order = terminal_order(costs, violates, limit=10)
    # Sums: site 1 of the first terminal is cheapest but violates non-overlap, so the
    # four assignments without it come first, by increasing total cost.
    assert order.tolist() == [[0, 1], [0, 0], [2, 1], [2, 0], [1, 1], [1, 0]]
    assert terminal_order(costs, violates, limit=3).tolist() == [[0, 1], [0, 0], [2, 1]]
    assert terminal_order([], [], limit=5).shape == (1, 0)


def test_enumeration_stops_at_the_first_assignment_meeting_the_constraints():
    order = np.array([[0], [1], [2], [3]])
    # (overlaps, coverage, energy) per assignment: the second has an overlap, the third is
    # the first with none and enough coverage; the fourth (also valid, lower energy) is
    # never solved.
    outcomes = {0: (0, 0.80, 1.0), 1: (1, 0.95, 0.5), 2: (0, 0.90, 3.0), 3: (0, 0.99, 0.1)}
    solved = []

    def solve(assignment):
        solved.append(int(assignment[0]))
        o, c, e = outcomes[int(assignment[0])]
        return o, c, e, f"result {assignment[0]}"

    index, result, count = first_consistent(order, solve, min_coverage=0.85)
    assert (index, result, count) == (2, "result 2", 3)
    assert solved == [0, 1, 2]
    # None meets them: the best by (overlaps, -coverage, energy) after trying all.
    outcomes[2] = (2, 0.99, 0.0)
    outcomes[3] = (0, 0.70, 0.0)
    solved.clear()
    index, result, count = first_consistent(order, solve, min_coverage=0.85)
    assert (index, result, count) == (0, "result 0", 4)
    assert first_consistent(np.zeros((0, 1), int), solve, 0.85) == (-1, None, 0)
