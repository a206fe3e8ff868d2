"""The safety checker judges trajectories by the project's step semantics."""

import numpy as np
import pytest
from shapely.geometry import box

from fleet.engine.safety import SafetyChecker, check_collisions, check_steps
from fleet.floor import Floor, FloorSpec
from fleet.plugins.robot import DoubleIntegrator, brake_input


@pytest.fixture
def hall() -> Floor:
    """10 x 4 m: fast left part, an obstacle 4..6 x 0..2, a 0.4 m/s zone at x >= 7."""
    spec = FloorSpec("hall.toml", "hall", box(0, 0, 10, 4), (1.0, 1.0))
    pieces = [
        (box(0, 0, 4, 4), (1.0, 1.0), None),
        (box(4, 2, 6, 4), (1.0, 1.0), None),
        (box(6, 0, 7, 4), (1.0, 1.0), None),
        (box(7, 0, 10, 4), (0.4, 0.4), "slow"),
    ]
    return Floor.from_regions(spec, pieces)


def steps(points, dt=1.0):
    """Samples along `points` with the velocity that moves each step to the next point."""
    xy = np.asarray(points, dtype=float)
    v = np.zeros_like(xy)
    v[:-1] = np.diff(xy, axis=0) / dt
    return np.arange(len(xy)) * dt, xy, v


def test_clean_trajectory_has_no_violations(hall):
    t, xy, v = steps(
        [(1, 1), (2, 1.5), (3, 2.5), (4, 3), (5, 3), (6, 3), (6.5, 2.5), (6.9, 2.5), (7.2, 2.5)]
    )
    assert check_steps(hall, t, xy, v, "r1") == []


def test_step_through_obstacle_is_counted_even_with_both_ends_free(hall):
    t, xy, v = steps([(3.5, 1), (6.5, 1)], dt=3.0)
    found = check_steps(hall, t, xy, v, "r1")
    assert [f.kind for f in found] == ["obstacle"]
    assert "crosses an obstacle for 2 m" in found[0].detail


def test_position_inside_obstacle_is_counted(hall):
    t, xy, v = steps([(5, 1), (5, 1)])
    kinds = [f.kind for f in check_steps(hall, t, xy, v, "r1")]
    assert kinds == ["obstacle", "obstacle"]


def test_straddling_into_a_slow_zone_too_fast_is_a_speed_violation(hall):
    # Ends inside the slow zone at 0.8 m/s: the part of the step inside it was too fast.
    t, xy, v = steps([(6.5, 3), (7.3, 3)])
    found = check_steps(hall, t, xy, v, "r1")
    assert [f.kind for f in found] == ["speed_zone"]
    assert "over limit (0.4, 0.4)" in found[0].detail


def test_touching_the_slow_zone_boundary_is_allowed(hall):
    t, xy, v = steps([(6.2, 3), (7.0, 3), (7.4, 3)])
    assert check_steps(hall, t, xy, v, "r1") == []


def test_rounding_on_a_boundary_is_forgiven_but_real_entry_is_not(hall):
    # Leaving the slow zone (x >= 7) at 0.8 m/s nearly parallel to its edge, starting 5e-10 m
    # inside it: the step overlaps the zone for 2e-6 m of length but only 5e-10 m deep.
    t, xy, v = steps([(7.0 + 5e-10, 3.0), (7.0 - 1e-4, 3.4)], dt=0.5)
    assert v[0, 1] == pytest.approx(0.8)
    assert check_steps(hall, t, xy, v, "r1") == []
    # The same step starting 1 mm inside the zone really drives through it too fast.
    t, xy, v = steps([(7.001, 3.0), (7.0 - 2e-4, 3.8)])
    assert [f.kind for f in check_steps(hall, t, xy, v, "r1")] == ["speed_zone"]


def test_a_step_along_a_shared_boundary_obeys_both_sides(hall):
    t, xy, v = steps([(7.0, 0.5), (7.0, 1.2)])  # on the line x = 7, at 0.7 m/s
    assert [f.kind for f in check_steps(hall, t, xy, v, "r1")] == ["speed_zone"]
    t, xy, v = steps([(7.0, 0.5), (7.0, 0.9)])  # 0.4 m/s is fine on both sides
    assert check_steps(hall, t, xy, v, "r1") == []


def test_per_axis_limit(hall):
    # 0.39 m/s on each axis (0.55 m/s overall) is within a per-axis 0.4 m/s box.
    t, xy, v = steps([(8, 1), (8.39, 1.39)])
    assert check_steps(hall, t, xy, v, "r1") == []
    t, xy, v = steps([(8, 1), (8.41, 1.0)])
    assert [f.kind for f in check_steps(hall, t, xy, v, "r1")] == ["speed_zone"]


def test_collisions_count_episodes_not_samples():
    t = np.array([0, 0, 1, 1, 2, 2, 3, 3], dtype=float)
    idx = np.array([0, 1] * 4)
    xy = np.array(
        [[0, 0], [5, 0], [0, 0], [0.5, 0], [0, 0], [0.6, 0], [0, 0], [0.5, 0]], dtype=float
    )
    found = check_collisions(t, idx, xy, [0.4, 0.4], ["a", "b"])
    assert [f.t for f in found] == [1.0]  # one contact episode from t=1 to t=3
    xy[5] = [5, 0]  # separate at t=2: two episodes
    assert [f.t for f in check_collisions(t, idx, xy, [0.4, 0.4], ["a", "b"])] == [1.0, 3.0]


def test_robots_that_pass_through_each_other_between_samples_collide():
    # Head-on along one line at 1.25 m/s each with 0.5 s periods: every sample of one falls
    # midway between two of the other's (0.625 m apart at each sample: radii 0.3 + 0.3 clear).
    t = np.arange(6) * 0.5
    a = np.column_stack([1.25 * t, np.zeros(6)])
    b = np.column_stack([5.625 - 1.25 * t, np.zeros(6)])
    assert np.min(np.hypot(*(a - b).T)) > 0.6
    found = check_collisions(np.r_[t, t], np.repeat([0, 1], 6), np.vstack([a, b]), [0.3] * 2, "ab")
    assert len(found) == 1 and found[0].t == pytest.approx(2.25)
    assert found[0].detail == "a and b 0.000 m apart"
    assert (found[0].x, found[0].y) == (pytest.approx(2.8125), 0.0)


def test_robots_with_different_periods_are_compared_between_their_samples():
    # a samples every 0.5 s, b every 0.3 s: they share only t = 0, 1.5, 3.0, when they are far
    # apart (6, 1.5 and 9 m), and cross at t = 1.2 at x = 3 (2.5 m/s each, head-on).
    ta, tb = np.arange(7) * 0.5, np.arange(11) * 0.3
    a = np.column_stack([2.5 * ta, np.zeros(7)])
    b = np.column_stack([6.0 - 2.5 * tb, np.zeros(11)])
    common = np.intersect1d(ta, tb)
    assert np.all(np.abs(2.5 * common - (6.0 - 2.5 * common)) > 0.8)
    t, idx, xy = np.r_[ta, tb], np.r_[np.zeros(7), np.ones(11)], np.vstack([a, b])
    found = check_collisions(t, idx, xy, [0.4, 0.4], ["a", "b"])
    assert len(found) == 1 and found[0].t == pytest.approx(1.2)
    assert found[0].x == pytest.approx(3.0) and "0.000 m apart" in found[0].detail
    # b 1 m off a's line: they pass 1 m apart, clear of 0.8 m.
    xy[7:, 1] = 1.0
    assert check_collisions(t, idx, xy, [0.4, 0.4], ["a", "b"]) == []
    # Tracks that do not overlap in time are never compared.
    assert check_collisions(np.r_[ta, tb + 10], idx, np.zeros((18, 2)), [0.4] * 2, "ab") == []


def test_checker_counts_per_kind(hall):
    tr = {"a": steps([(3.5, 1), (6.5, 1)], dt=3.0), "b": steps([(3.5, 1.5), (3.5, 1.5)])}
    report = SafetyChecker(hall).check(tr, {"a": 0.4, "b": 0.4})
    assert report.counts == {"obstacle": 1, "speed_zone": 0, "print_speed": 0, "collision": 1}


def test_double_integrator_matches_the_paper_matrices():
    model = DoubleIntegrator(dt=0.5, a_max=1.0)
    state = np.array([1.0, 2.0, 0.3, -0.2])
    u = np.array([0.4, 2.0])  # 2.0 is clipped to the bound 1.0
    expected = model.A @ state + model.B @ np.clip(u, -1, 1)
    assert model.step(*state, *u) == pytest.approx(tuple(expected), abs=1e-15)
    # Braking keeps the direction of travel: both axes scaled by the same factor.
    ax, ay = brake_input(0.2, -3.0, 0.5, 1.0)
    assert (ax, ay) == (pytest.approx(-0.2 / 0.5 / 6), pytest.approx(1.0))
    assert brake_input(0.1, 0.05, 0.5, 1.0) == (pytest.approx(-0.2), pytest.approx(-0.1))
