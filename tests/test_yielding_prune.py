"""The follower's checks pass over neighbours out of reach (`prune`) with the same answers.

`stops_clear` and `must_yield` skip a neighbour whose forecast's bounding box lies further than
the gap from the robot's path; these tests compare them, on random robots, paths and plans
(hypothesis), with the same checks made sample by sample (``prune=False``), including cases a
hair either side of the gap.
"""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.plugins import Neighbour
from fleet_plugins.follower.yielding import (
    Forecast,
    bounds,
    braking_path,
    must_yield,
    stops_clear,
)

DT, A_MAX, RADIUS, MARGIN = 0.25, 0.5, 0.4, 0.1
GAP = 2 * RADIUS + MARGIN

coord = st.floats(-4.0, 4.0, allow_nan=False)
speed = st.floats(-1.0, 1.0, allow_nan=False)


@st.composite
def neighbours(draw: st.DrawFn, t: float) -> Neighbour:
    x, y, vx, vy = draw(coord), draw(coord), draw(speed), draw(speed)
    plan: tuple[tuple[float, float, float], ...] = ()
    if draw(st.booleans()):
        n = draw(st.integers(1, 8))
        times = sorted(draw(st.lists(st.floats(t - 1.0, t + 6.0), min_size=n, max_size=n)))
        plan = tuple((ts, draw(coord), draw(coord)) for ts in times)
    return Neighbour(
        draw(st.sampled_from(["a", "b", "c", "d"])),
        x,
        y,
        vx,
        vy,
        draw(st.sampled_from([0.3, 0.4, 0.5])),
        draw(st.integers(0, 5)),
        plan,
    )


@st.composite
def situations(draw: st.DrawFn):
    t = draw(st.floats(0.0, 100.0))
    x, y, vx, vy = draw(coord), draw(coord), draw(speed), draw(speed)
    stop = braking_path(t + DT, x + DT * vx, y + DT * vy, vx, vy, DT, A_MAX)
    hold = draw(st.integers(0, 8))
    path = stop + [(stop[-1][0] + i * DT, stop[-1][1], stop[-1][2]) for i in range(1, hold + 1)]
    found = draw(st.lists(neighbours(t), max_size=6))
    forecasts = [Forecast.of(n, t, DT, A_MAX) for n in found]
    return t, (t, x, y), path, forecasts


@settings(max_examples=400, deadline=None)
@given(situations(), st.booleans(), st.floats(0.0, 1.0))
def test_stops_clear_pruned_gives_the_same_answer(case, with_gaps: bool, cut: float) -> None:
    _, now, path, forecasts = case
    gaps = {f.robot: GAP * cut for f in forecasts[:2]} if with_gaps else None
    fast = stops_clear(path, forecasts, RADIUS, MARGIN, now, gaps)
    slow = stops_clear(path, forecasts, RADIUS, MARGIN, now, gaps, prune=False)
    assert fast == slow
    for f in forecasts:  # one at a time too, so every neighbour's answer is compared
        assert stops_clear(path, [f], RADIUS, MARGIN, now) == stops_clear(
            path, [f], RADIUS, MARGIN, now, prune=False
        )


@settings(max_examples=400, deadline=None)
@given(situations(), st.integers(1, 30), st.floats(0.1, 2.0))
def test_must_yield_pruned_gives_the_same_answer(case, steps: int, gap: float) -> None:
    t, (_, x, y), _, forecasts = case
    own = [(t + i * DT, x + 0.2 * i, y - 0.1 * i) for i in range(steps)]
    for f in forecasts:
        slow = must_yield(own, f, gap, prune=False)
        assert must_yield(own, f, gap) == slow
        assert must_yield(own, f, gap, bounds(own)) == slow


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_forecast_bounds_hold_every_point_it_names(data: st.DataObject) -> None:
    t = data.draw(st.floats(0.0, 100.0))
    f = Forecast.of(data.draw(neighbours(t)), t, DT, A_MAX)
    x0, y0, x1, y1 = f.bounds()
    assert (x0, y0, x1, y1) == Forecast(**{**_fields(f), "box": None}).bounds()
    for s in data.draw(st.lists(st.floats(t - 2.0, t + 10.0), min_size=1, max_size=10)):
        px, py = f.at(s)
        # Within the box but for the interpolation's rounding (which `_SURE_M` covers).
        assert x0 - 1e-12 <= px <= x1 + 1e-12 and y0 - 1e-12 <= py <= y1 + 1e-12
        # The nearest point from a corner's far side is no nearer than the box lets it be.
        qx, qy = x1 + 1.0, y1 + 2.0
        assert f.distance(s, qx, qy) >= (1.0 if f.has_plan else 1.0 - f.slack) - 1e-9


def test_a_neighbour_a_hair_beyond_the_gap_is_clear_and_a_hair_within_is_not() -> None:
    # A robot parked (a plan that stays) east of a robot that brakes towards it.
    path = braking_path(0.25, 0.25, 0.0, 1.0, 0.0, DT, A_MAX)
    end = path[-1][1]
    need = GAP + math.sqrt(2.0) * A_MAX * DT * DT  # the gap and a parked robot's lead
    for off, clear in ((1e-5, True), (1e-7, True), (-1e-7, False)):
        parked = Forecast.of(
            Neighbour("r2", end + need + off, 0.0, 0.0, 0.0, plan=((0.0, end + need + off, 0.0),)),
            0.0,
            DT,
            A_MAX,
        )
        for prune in (True, False):
            assert (
                stops_clear(path, [parked], RADIUS, MARGIN, (0.0, 0.0, 0.0), prune=prune) is clear
            )


def _fields(f: Forecast) -> dict:
    return {name: getattr(f, name) for name in f.__slots__}


def test_bounds_of_a_plan_without_samples_in_reach() -> None:
    # A plan far away: pruned without sampling it, and the same answer as sampling it.
    own = [(0.25 * i, 0.25 * i, 0.0) for i in range(17)]
    far = Forecast.of(Neighbour("h", 50.0, 50.0, 0, 1, plan=((4.0, 50.0, 60.0),)), 0.0, DT, A_MAX)
    assert math.isclose(far.bounds()[1], 50.0)
    assert not must_yield(own, far, GAP) and not must_yield(own, far, GAP, prune=False)
