"""The geometry of a two-objective search (ilcforce/tune/front.py) on hand-computed cases: which
trials form the front, the area it dominates, when a search has stopped improving, and which front
points are re-evaluated on held-out seeds."""

from __future__ import annotations

import pytest

from ilcforce.tune.front import converged, hypervolume, pareto_indices, spread
from ilcforce.tune.objectives import HV_REFERENCE


def test_pareto_indices_keeps_the_non_dominated_ordered_by_the_first_objective():
    points = [(3.0, 1.0), (2.0, 3.0), (1.0, 3.0), (2.0, 2.0), (1.0, 3.0), (4.0, 4.0)]
    # (2, 3) is dominated by (2, 2) and (1, 3); (4, 4) by all; the second (1, 3) equals the first
    assert pareto_indices(points) == [2, 3, 0]
    assert pareto_indices([]) == []
    assert pareto_indices([(5.0, 5.0)]) == [0]
    # equal in the first objective: only the better second one is on the front
    assert pareto_indices([(1.0, 2.0), (1.0, 1.0)]) == [1]
    # equal in the second objective: only the better first one
    assert pareto_indices([(2.0, 1.0), (1.0, 1.0)]) == [1]


@pytest.mark.parametrize("points, area", [
    ([], 0.0),
    ([(0.0, 0.0)], 1.0),
    ([(0.5, 0.5)], 0.25),
    ([(0.0, 0.5), (0.5, 0.0)], 0.75),  # [0, 1] x [0.5, 1] and [0.5, 1] x [0, 0.5]
    ([(0.0, 0.5), (0.5, 0.0), (0.6, 0.6)], 0.75),  # a dominated point adds nothing
    ([(0.5, 0.0), (0.0, 0.5), (0.0, 0.5)], 0.75),  # nor does order or a repeated point
    ([(0.5, 0.5), (2.0, -1.0), (-1.0, 1.0), (1.0, 0.0)], 0.25),  # beyond or on the reference: nothing
    ([(-1.0, -1.0)], 4.0),  # below zero is fine: the area is up to the reference
    ([(0.25, 0.75), (0.5, 0.5), (0.75, 0.25)], 0.75 * 0.25 + 0.5 * 0.25 + 0.25 * 0.25),
])
def test_hypervolume_of_hand_computed_fronts(points, area):
    assert hypervolume(points, (1.0, 1.0)) == pytest.approx(area)


def test_hypervolume_only_grows_as_points_are_added():
    points = [(0.9, 0.1), (0.2, 0.8), (0.5, 0.5), (0.4, 0.45), (0.95, 0.95), (0.1, 0.95)]
    volumes = [hypervolume(points[:n], HV_REFERENCE) for n in range(len(points) + 1)]
    assert volumes == sorted(volumes) and volumes[0] == 0.0


def test_a_search_whose_front_stopped_growing_converges():
    improving = [(1.0 - 0.1 * n, 1.0 - 0.1 * n) for n in range(1, 5)]  # each dominates the one before
    history = [*improving, *[(0.9, 0.9)] * 8, None, None, None, None]  # then 12 trials that add nothing
    done, gain = converged(history, (1.0, 1.0), 0.01)
    assert done and gain == 0.0


def test_a_search_whose_front_still_grows_does_not_converge():
    history = [(1.0 - 0.05 * n, 1.0 - 0.05 * n) for n in range(1, 17)]  # every trial better than all before
    done, gain = converged(history, (1.0, 1.0), 0.01)
    # its last quarter (4 trials) took the dominated square from 0.6^2 to 0.8^2
    assert not done and gain == pytest.approx((0.8 ** 2 - 0.6 ** 2) / 0.8 ** 2)
    # and a gain just under stop_gain converges, just over does not
    assert converged(history, (1.0, 1.0), gain * 1.001)[0] and not converged(history, (1.0, 1.0), gain * 0.999)[0]


def test_a_search_with_no_feasible_trial_has_nothing_to_improve():
    # an empty front (every trial infeasible or failed) has nothing left to improve: converged, gain 0, so
    # a method with no stable gains stops at its first budget (e8ed17d; the report says its front is empty)
    for n in (1, 4, 40):
        assert converged([None] * n, (1.0, 1.0), 0.01) == (True, 0.0)
    # points beyond the reference count as none
    assert converged([(2.0, 2.0)] * 8, (1.0, 1.0), 0.99) == (True, 0.0)
    # the first feasible point in the last quarter is all the gain there is: not converged
    assert converged([None] * 7 + [(0.5, 0.5)], (1.0, 1.0), 0.5) == (False, 1.0)


def test_the_last_quarter_is_at_least_one_trial():
    # two trials: the last quarter is the last one; it added all the volume there is
    assert converged([None, (0.5, 0.5)], (1.0, 1.0), 0.01) == (False, 1.0)
    assert converged([(0.5, 0.5), None], (1.0, 1.0), 0.01) == (True, 0.0)


@pytest.mark.parametrize("size", range(1, 15))
@pytest.mark.parametrize("most", [2, 3, 6])
def test_spread_keeps_both_ends_and_at_most_most(size, most):
    front = [100 + 3 * i for i in range(size)]  # indices of trials, ordered along the front
    picked = spread(front, most)
    assert len(picked) == min(size, most)
    assert picked[0] == front[0] and picked[-1] == front[-1]  # both ends
    assert picked == sorted(picked) and set(picked) <= set(front)  # ordered along it, from it


def test_spread_is_even():
    assert spread(list(range(10)), 4) == [0, 3, 6, 9]
    assert spread(list(range(7)), 3) == [0, 3, 6]
    assert spread([5, 1, 9], 6) == [5, 1, 9]  # a short front whole, in its order
