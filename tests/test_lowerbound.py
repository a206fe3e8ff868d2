"""Minimum-time lower bounds: exact on open floors, larger with zones, caps and obstacles, and
never above the arrival of a trajectory that obeys the rules."""

import math

import numpy as np
import pytest
import shapely
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from shapely.geometry import box

from fleet.engine.safety import check_steps
from fleet.errors import NoPathError
from fleet.floor import Floor, FloorSpec
from fleet.paths import PathPlanner
from fleet.printing import CapSchedule
from fleet.study.lowerbound import LowerBound, envelope, min_time_lower_bound

FAST = (1.0, 1.0)
TOL = 0.05


def floor_of(name: str, pieces, bounds) -> Floor:
    spec = FloorSpec(f"{name}.toml", name, box(*bounds), FAST)
    return Floor.from_regions(spec, pieces)


def rest_to_rest(distance: float, v_max: float, a_max: float, dt: float) -> int:
    """Fewest steps of the 1-D discrete double integrator from rest to rest over `distance`.

    The fastest profile accelerates at a_max until v_max and brakes as late as it can:
    ``v[k] = min(v_max, k*a*dt, (T-k)*a*dt)`` for k < T, covering ``dt * sum(v)``.
    """
    T = 0
    while True:
        covered = dt * sum(min(v_max, k * a_max * dt, (T - k) * a_max * dt) for k in range(T))
        if covered >= distance:
            return T
        T += 1


def straight_line(start, goal, v_max=1.0, a_max=0.5, dt=1.0) -> int:
    """Per-axis rest-to-rest bound (axes are independent) ignoring everything on the floor."""
    return max(
        rest_to_rest(abs(g - s) - TOL, v_max, a_max, dt) for s, g in zip(start, goal, strict=True)
    )


def bound(floor, start, goal, **kw) -> LowerBound:
    kw = {"v_max": 1.0, "a_max": 0.5, "dt": 1.0, **kw}
    return min_time_lower_bound(floor, start, goal, **kw)


def reference_steps(floor, start, goal, v_max=1.0, a_max=0.5, dt=1.0) -> int:
    """Arrival step of the path layer's reference: a trajectory that obeys every rule."""
    ref = PathPlanner(floor, v_max, a_max).reference(start, goal, dt)
    assert check_steps(floor, np.arange(ref.steps + 1) * dt, ref.positions, ref.velocities) == []
    return ref.steps


def assert_obeys_dynamics(lb: LowerBound, start, goal, v_max, a_max, dt) -> None:
    tr = lb.trajectory
    assert tr is not None and tr.shape == (lb.steps + 1, 4)
    p, v = tr[:, :2], tr[:, 2:]
    assert np.allclose(p[0], start) and np.allclose(v[0], 0) and np.allclose(v[-1], 0, atol=1e-6)
    assert np.allclose(p[1:], p[:-1] + dt * v[:-1], atol=1e-6)
    assert np.all(np.abs(np.diff(v, axis=0)) <= a_max * dt + 1e-6)
    assert np.all(np.abs(v) <= v_max + 1e-5)
    assert np.all(np.abs(p[-1] - goal) <= TOL + 1e-6)


# -- open floor: the bound is the double integrator's own minimum --------------------------------
OPEN = floor_of("open", [(box(0, 0, 30, 12), FAST, None)], (0, 0, 30, 12))


@settings(max_examples=12, deadline=None)
@given(
    start=st.tuples(st.integers(0, 300), st.integers(0, 120)),
    goal=st.tuples(st.integers(0, 300), st.integers(0, 120)),
    v_max=st.sampled_from([1.0, 0.6]),
    a_max=st.sampled_from([0.5, 0.3]),
    dt=st.sampled_from([1.0, 0.5]),
)
def test_on_an_open_floor_the_bound_is_the_1d_minimum_time_of_the_slower_axis(
    start, goal, v_max, a_max, dt
):
    start = (start[0] / 10, start[1] / 10)
    goal = (goal[0] / 10, goal[1] / 10)
    distances = [abs(g - s) - TOL for s, g in zip(start, goal, strict=True)]
    want = [
        max(rest_to_rest(d + shift, v_max, a_max, dt) for d in distances) for shift in (-1e-4, 1e-4)
    ]
    assume(want[0] == want[1])  # a tie within rounding could fall either way
    lb = bound(OPEN, start, goal, v_max=v_max, a_max=a_max, dt=dt)
    assert lb.steps == want[0]
    assert lb.seconds == pytest.approx(want[0] * dt)
    assert lb.tight
    assert_obeys_dynamics(lb, start, goal, v_max, a_max, dt)


def test_the_envelope_is_the_fastest_profile_from_rest_to_rest():
    w = envelope(8, np.full(8, 1.0), 0.5, 1.0)
    assert w.tolist() == [0.0, 0.5, 1.0, 1.0, 1.0, 1.0, 1.0, 0.5, 0.0]


def test_a_trip_already_at_the_goal_takes_no_steps():
    lb = bound(OPEN, (5, 5), (5.03, 4.98))
    assert lb.steps == 0 and lb.tight


# -- slow zones, caps, obstacles ----------------------------------------------------------------
def corridor(zone_v: float) -> Floor:
    """40 x 10 m; the band 15 <= x <= 25 allows `zone_v` per axis."""
    return floor_of(
        "corridor",
        [
            (box(0, 0, 15, 10), FAST, None),
            (box(15, 0, 25, 10), (zone_v, zone_v), "band" if zone_v != 1.0 else None),
            (box(25, 0, 40, 10), FAST, None),
        ],
        (0, 0, 40, 10),
    )


def test_a_slow_zone_across_the_way_makes_the_bound_larger():
    start, goal = (2.0, 5.0), (38.0, 5.0)
    plain = bound(corridor(1.0), start, goal)
    assert plain.steps == straight_line(start, goal)
    slowed = bound(corridor(0.3), start, goal)
    # Every metre of x in the band is covered by steps with a sample in the band (steps are too
    # short to hop 10 m), so at 0.3 m/s; the other 25.95 m take at least 1 s each.
    assert slowed.steps >= math.ceil(10 / 0.3 + 25.95)
    assert slowed.steps <= reference_steps(corridor(0.3), start, goal)


def test_print_caps_make_the_bound_larger():
    start, goal = (1.0, 1.0), (25.0, 6.0)
    plain = bound(OPEN, start, goal)
    capped_all = bound(OPEN, start, goal, caps=CapSchedule.from_pieces([(0, 1000, 0.3)]))
    assert capped_all.steps == straight_line(start, goal, v_max=0.3)
    capped_part = bound(OPEN, start, goal, caps=CapSchedule.from_pieces([(5, 15, 0.3)]))
    assert plain.steps < capped_part.steps < capped_all.steps
    # The same cap later on the clock, after the trip would be over, costs nothing.
    late = bound(OPEN, start, goal, caps=CapSchedule.from_pieces([(5, 15, 0.3)]), t0=100.0)
    assert late.steps == plain.steps


def test_the_trajectory_found_honours_the_caps():
    caps = CapSchedule.from_pieces([(5, 15, 0.3)])
    lb = bound(OPEN, (1.0, 1.0), (25.0, 6.0), caps=caps)
    step_caps = caps.step_caps(0.0, 1.0, lb.steps + 1)
    assert np.all(np.abs(lb.trajectory[:, 2:]) <= step_caps[:, None] + 1e-5)


def wall() -> Floor:
    """30 x 20 m with a machine at 10..20 x 0..15 in the way."""
    return floor_of(
        "wall",
        [
            (box(0, 0, 10, 20), FAST, None),
            (box(10, 15, 20, 20), FAST, None),
            (box(20, 0, 30, 20), FAST, None),
        ],
        (0, 0, 30, 20),
    )


def test_an_obstacle_between_start_and_goal_makes_the_bound_larger_than_the_straight_line():
    start, goal = (2.0, 2.0), (28.0, 2.0)
    lb = bound(wall(), start, goal)
    assert lb.steps > straight_line(start, goal)
    assert lb.steps <= reference_steps(wall(), start, goal)
    assert lb.tight
    # No sample inside the machine (up to the 1e-6 m the safety checker forgives).
    samples = shapely.points(lb.trajectory[:, :2])
    assert np.all(shapely.dwithin(wall().free_space, samples, 2e-6))
    assert not np.any(shapely.within(samples, box(10 + 1e-5, 0, 20 - 1e-5, 15 - 1e-5)))


def test_interior_points_stop_steps_hopping_over_a_thin_slow_strip():
    floor = floor_of(
        "strip",
        [
            (box(0, 0, 9.8, 4), FAST, None),
            (box(9.8, 0, 10.2, 4), (0.05, 0.05), "strip"),
            (box(10.2, 0, 20, 4), FAST, None),
        ],
        (0, 0, 20, 4),
    )
    start, goal = (1.0, 2.0), (19.0, 2.0)
    hopping = bound(floor, start, goal)
    assert hopping.steps == straight_line(start, goal)  # samples only: the strip is jumped
    strict = bound(floor, start, goal, interior_points=3)
    assert strict.steps > hopping.steps
    assert strict.steps <= reference_steps(floor, start, goal)


# -- never above a real arrival -----------------------------------------------------------------
def crossing() -> Floor:
    """A plus-shaped junction whose arms have incomparable per-axis limits."""
    return floor_of(
        "crossing",
        [
            (box(0, 8, 8, 12), (1.0, 0.3), "west"),
            (box(8, 8, 12, 12), FAST, None),
            (box(12, 8, 20, 12), (1.0, 0.3), "east"),
            (box(8, 0, 12, 8), (0.3, 1.0), "south"),
            (box(8, 12, 12, 20), (0.3, 1.0), "north"),
        ],
        (0, 0, 20, 20),
    )


@settings(max_examples=10, deadline=None)
@given(
    which=st.sampled_from(["wall", "corridor", "crossing"]),
    s=st.tuples(st.floats(0.05, 0.95), st.floats(0.05, 0.95)),
    g=st.tuples(st.floats(0.05, 0.95), st.floats(0.05, 0.95)),
)
def test_the_bound_never_exceeds_the_arrival_of_a_trajectory_that_obeys_the_rules(which, s, g):
    floor = {"wall": wall, "corridor": lambda: corridor(0.4), "crossing": crossing}[which]()
    regions = floor.regions
    # Start and goal in two of the floor's regions, picked by the drawn fractions.
    a = regions[int(s[0] * len(regions))].polygon.bounds
    b = regions[int(g[0] * len(regions))].polygon.bounds
    start = (a[0] + s[1] * (a[2] - a[0]), a[1] + s[0] * (a[3] - a[1]))
    goal = (b[0] + g[1] * (b[2] - b[0]), b[1] + g[0] * (b[3] - b[1]))
    lb = bound(floor, start, goal)
    assert lb.steps <= reference_steps(floor, start, goal)
    if lb.tight:
        assert_obeys_dynamics(lb, start, goal, 1.0, 0.5, 1.0)


# -- bad input ----------------------------------------------------------------------------------
def test_a_start_outside_the_free_space_is_refused_naming_the_point():
    with pytest.raises(ValueError, match=r"start = \(15, 5\) is outside the free space"):
        bound(wall(), (15, 5), (28, 2))


def test_a_goal_outside_the_floor_is_refused_naming_the_point():
    with pytest.raises(ValueError, match=r"goal = \(31, 2\) is outside the free space"):
        bound(wall(), (2, 2), (31, 2))


@pytest.mark.parametrize(
    ("kw", "field"),
    [({"v_max": 0.0}, "v_max"), ({"dt": -1.0}, "dt"), ({"tolerance": -0.1}, "tolerance")],
)
def test_bad_parameters_are_refused_by_name(kw, field):
    with pytest.raises(ValueError, match=field):
        bound(OPEN, (1, 1), (5, 5), **kw)


def test_a_goal_in_another_part_of_the_free_space_has_no_path():
    split = floor_of(
        "split", [(box(0, 0, 4, 4), FAST, None), (box(6, 0, 10, 4), FAST, None)], (0, 0, 10, 4)
    )
    with pytest.raises(NoPathError):
        bound(split, (1, 1), (8, 1))
