"""The quadratic refinement of the MPC: the paper's cost for the MILP's region sequence, as a QP.

Everything runs on the conformance floor with real HiGHS solves: the trip from the depot around
the press into the slow corner, the trip's MILP (`TripModel`) for the region sequence, then
`refine_quadratic` for the same step data.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cache

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from fleet.engine.safety import check_steps
from fleet.floor import Floor
from fleet.highs import new_highs
from fleet.paths import PathPlanner, Reference
from fleet.plugins import SolverOutcome
from fleet.plugins.testing import CONFORMANCE_SPEC, conformance_floor
from fleet_plugins.mpc import refine
from fleet_plugins.mpc.model import Interface, Solution, StepData, TripModel
from fleet_plugins.mpc.refine import quadratic_cost, refine_quadratic
from fleet_plugins.mpc.trip import MIDPOINT_MARGIN, Trip, reach_boxes

SPEC = CONFORMANCE_SPEC
DT, A_MAX, V_ROBOT = SPEC.period, SPEC.a_max, SPEC.v_max
N = 12
PAPER = (1.0, 1.0, 1.0)  # Q = R = I
NO_EFFORT = (1.0, 1.0, 0.0)  # tracking only: an exactly trackable reference costs 0
ROW_TOL = 1e-7  # HiGHS's primal feasibility tolerance (m, m/s)
# HiGHS regularises the QP's Hessian (1e-7), so its optimum is that far from exact.
PLAN_TOL = 1e-5


@dataclass(frozen=True)
class Setup:
    floor: Floor
    reference: Reference
    trip: Trip
    milp: dict[tuple[float, float, float], TripModel]


@cache
def setup() -> Setup:
    floor = conformance_floor()
    ref = PathPlanner(floor, V_ROBOT, A_MAX).reference((2.0, 5.0), (17.0, 1.5), dt=DT)
    trip = Trip.build(floor, ref)
    milp = {
        w: TripModel(trip, N, DT, A_MAX, V_ROBOT, w, Interface.DIRECT, 10.0)
        for w in (PAPER, NO_EFFORT)
    }
    return Setup(floor, ref, trip, milp)


def step_data(i: int, p0: np.ndarray, v0: np.ndarray, free_end: bool = False) -> StepData:
    """The controller's step data (no caps, every trip region open) at reference sample i."""
    s = setup()
    k = np.arange(N + 1)[:, None]
    bound = np.full((N + 1, 2), V_ROBOT)
    if not free_end:
        bound[N] = 0.0
    bound = np.maximum(bound, np.abs(v0)[None, :] - k * A_MAX * DT)
    p_lo, p_hi = reach_boxes(p0, v0, bound, DT, A_MAX)
    xlo, ylo, xhi, yhi = s.trip.box
    p_lo[1:] = np.maximum(p_lo[1:], [xlo, ylo])
    p_hi[1:] = np.minimum(p_hi[1:], [xhi, yhi])
    p_hi[1:] = np.maximum(p_hi[1:], p_lo[1:])
    v_lo, v_hi = -bound.copy(), bound.copy()
    v_lo[0] = v_hi[0] = v0
    idx = np.minimum(i + np.arange(N + 1), s.reference.steps)
    z_ub = np.ones((N - 1, len(s.trip.regions)))
    ref = s.reference
    return StepData(p_lo, p_hi, v_lo, v_hi, z_ub, ref.positions[idx], ref.velocities[idx])


def on_reference(i: int, free_end: bool = False) -> StepData:
    ref = setup().reference
    return step_data(i, ref.positions[i], ref.velocities[i], free_end)


def qp(data: StepData, regions: np.ndarray, weights=PAPER, **kw) -> Solution:
    return refine_quadratic(
        setup().trip, data, regions, N=N, dt=DT, a_max=A_MAX, v_robot=V_ROBOT,
        weights=weights, time_limit_s=kw.pop("time_limit_s", 10.0), **kw,
    )  # fmt: skip


def l1_tracking(sol: Solution, data: StepData) -> float:
    assert sol.p is not None and sol.v is not None
    return float(
        np.abs(sol.p[1:] - data.p_ref[1:]).sum() + np.abs(sol.v[1:] - data.v_ref[1:]).sum()
    )


def assert_obeys_the_fixed_regions(sol: Solution, data: StepData, regions: np.ndarray) -> None:
    """Every row of the QP, checked on the plan with the floor's own geometry."""
    s = setup()
    assert sol.p is not None and sol.v is not None and sol.u is not None
    p, v, u = sol.p, sol.v, sol.u
    assert p.shape == v.shape == (N + 1, 2) and u.shape == (N, 2)
    np.testing.assert_array_equal(sol.regions, regions)
    # The measured state, the dynamics and the input bound.
    np.testing.assert_allclose(p[0], data.p_lo[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(v[0], data.v_lo[0], rtol=0, atol=1e-12)
    # The dynamics are rows of the QP too: they hold to HiGHS's feasibility tolerance (the
    # example at step 43 misses by 1.4e-8 m).
    np.testing.assert_allclose(p[1:], p[:-1] + DT * v[:-1], rtol=0, atol=ROW_TOL)
    np.testing.assert_allclose(v[1:], v[:-1] + DT * u, rtol=0, atol=ROW_TOL)
    assert np.all(np.abs(u) <= A_MAX)
    # The step's bounds (reachable boxes, speed bounds, rest at the end).
    assert np.all(p >= data.p_lo - ROW_TOL) and np.all(p <= data.p_hi + ROW_TOL)
    assert np.all(v >= data.v_lo - ROW_TOL) and np.all(v <= data.v_hi + ROW_TOL)
    # Steps 1..N-1: both ends in the step's region, within its limit, midpoint off slow faces.
    for k in range(1, N):
        j = int(regions[k - 1])
        region = s.floor.regions[s.trip.regions[j]]
        assert np.all(region.A @ p[k] <= region.b + ROW_TOL), (k, p[k])
        assert np.all(region.A @ p[k + 1] <= region.b + ROW_TOL), (k, p[k + 1])
        assert np.all(np.abs(v[k]) <= np.asarray(region.v_max) + ROW_TOL), (k, v[k])
        for f in s.trip.faces:
            if f.region == j and f.slower_side:
                mid = np.dot(f.a, p[k] + p[k + 1]) / 2
                assert mid <= f.b - MIDPOINT_MARGIN + ROW_TOL, (k, mid, f)
    # And the project's safety checker agrees on those steps.
    t = DT * np.arange(N + 1)
    assert check_steps(s.floor, t[1:], p[1:], v[1:]) == []


# --- the QP's plan obeys the fixed regions ---------------------------------------------------


@settings(max_examples=20, deadline=None)
@example(i=43, dx=0.0, dy=0.0, free_end=True)  # found by a random run, not the derandomized one
@given(
    i=st.integers(0, 90),
    dx=st.floats(-0.4, 0.4),
    dy=st.floats(-0.4, 0.4),
    free_end=st.booleans(),
)
def test_the_plan_keeps_every_row_of_the_fixed_regions_and_beats_the_milp_plan(
    i: int, dx: float, dy: float, free_end: bool
) -> None:
    s = setup()
    i = min(i, s.reference.steps)
    p0 = s.reference.positions[i] + [dx, dy]
    data = step_data(i, p0, s.reference.velocities[i], free_end)
    milp = s.milp[PAPER].solve(data)
    assume(milp.outcome is SolverOutcome.OPTIMAL)  # an offset start may sit in the press
    assert milp.regions is not None

    sol = qp(data, milp.regions)

    assert sol.outcome is SolverOutcome.OPTIMAL
    assert_obeys_the_fixed_regions(sol, data, milp.regions)
    # The MILP's plan is feasible for the QP, so the QP's optimum can only be cheaper.
    assert sol.p is not None and sol.v is not None and sol.u is not None
    assert milp.p is not None and milp.v is not None and milp.u is not None
    ours = quadratic_cost(sol.p, sol.v, sol.u, data, PAPER)
    assert ours <= quadratic_cost(milp.p, milp.v, milp.u, data, PAPER) + 1e-9


# --- against the MILP ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("i", "free_end"),
    [(28, True), (60, True), (80, False)],
    ids=["north-corridor-free-end", "slow-zone-free-end", "final-approach-to-rest"],
)
def test_an_exactly_trackable_reference_gives_the_milps_plan(i: int, free_end: bool) -> None:
    data = on_reference(i, free_end)
    milp = setup().milp[NO_EFFORT].solve(data)
    assert milp.outcome is SolverOutcome.OPTIMAL and milp.regions is not None
    assert l1_tracking(milp, data) <= 1e-9  # the premise: the MILP tracks exactly

    sol = qp(data, milp.regions, NO_EFFORT)

    assert sol.outcome is SolverOutcome.OPTIMAL
    assert sol.p is not None and sol.v is not None and sol.u is not None
    assert quadratic_cost(sol.p, sol.v, sol.u, data, NO_EFFORT) <= 1e-9
    np.testing.assert_allclose(sol.p, milp.p, rtol=0, atol=PLAN_TOL)
    np.testing.assert_allclose(sol.v, milp.v, rtol=0, atol=PLAN_TOL)
    np.testing.assert_allclose(sol.u, milp.u, rtol=0, atol=PLAN_TOL / DT**2)


def test_where_the_plans_differ_the_qp_has_the_lower_quadratic_cost() -> None:
    # Entering the north corridor: the region changes within the horizon, the plan must stop at
    # its end while the reference keeps going, and R = I: the 1-norm and 2-norm optima differ.
    data = on_reference(40)
    milp = setup().milp[PAPER].solve(data)
    assert milp.outcome is SolverOutcome.OPTIMAL and milp.regions is not None
    assert len(set(milp.regions.tolist())) == 2

    highs = new_highs()
    sol = qp(data, milp.regions, highs=highs)

    assert sol.outcome is SolverOutcome.OPTIMAL
    assert_obeys_the_fixed_regions(sol, data, milp.regions)
    assert sol.p is not None and sol.v is not None and sol.u is not None
    assert milp.p is not None and milp.v is not None and milp.u is not None
    theirs = quadratic_cost(milp.p, milp.v, milp.u, data, PAPER)
    ours = quadratic_cost(sol.p, sol.v, sol.u, data, PAPER)
    assert ours < 0.95 * theirs
    # HiGHS's objective is the paper's cost itself.
    assert highs.getInfo().objective_function_value == pytest.approx(ours, rel=1e-9)
    assert np.abs(sol.u - milp.u).max() > 1e-2


def straight_reference(data: StepData, p0: tuple[float, float], v: tuple[float, float]) -> None:
    """Make `data` track a straight line from p0 at constant velocity v (never stopping)."""
    k = np.arange(N + 1)[:, None]
    data.p_ref[:] = np.asarray(p0) + DT * k * np.asarray(v)
    data.v_ref[:] = v


def test_a_step_never_runs_along_a_face_next_to_a_slower_region() -> None:
    # The gate's face x = 14 borders the 0.4 m/s corner; a reference running along it at
    # 1 m/s would be bound by the corner's limit, so the midpoint cut keeps each step's
    # midpoint 1e-5 m inside the gate.
    s = setup()
    gate = s.trip.regions.index(s.floor.locate(13.0, 2.0))
    cut = [f for f in s.trip.faces if f.region == gate and f.slower_side]
    assert [(f.a, f.b) for f in cut] == [((1.0, 0.0), 14.0)]
    data = step_data(0, np.array([14.0, 0.5]), np.array([0.0, 1.0]))
    straight_reference(data, (14.0, 0.5), (0.0, 1.0))
    regions = np.full(N - 1, gate)

    sol = qp(data, regions)

    assert sol.outcome is SolverOutcome.OPTIMAL
    assert_obeys_the_fixed_regions(sol, data, regions)
    assert sol.p is not None
    mid_x = (sol.p[1:N, 0] + sol.p[2:, 0]) / 2
    assert mid_x.max() == pytest.approx(14.0 - MIDPOINT_MARGIN, abs=1e-8)  # the cut binds


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["east", "west"])
def test_a_zone_limit_holds_a_faster_reference_back(sign: float) -> None:
    s = setup()
    corner = s.trip.regions.index(s.floor.locate(17.0, 1.5))
    assert s.trip.v_max[corner].tolist() == [0.4, 0.4]
    start = (17.0 - 2.0 * sign, 2.0)
    data = step_data(0, np.array(start), np.array([0.4 * sign, 0.0]))
    straight_reference(data, start, (1.0 * sign, 0.0))
    regions = np.full(N - 1, corner)

    sol = qp(data, regions)

    assert sol.outcome is SolverOutcome.OPTIMAL
    assert_obeys_the_fixed_regions(sol, data, regions)
    assert sol.v is not None
    assert np.abs(sol.v[1:N]).max() == pytest.approx(0.4, abs=1e-7)  # the limit binds


def test_an_impossible_region_sequence_is_infeasible_and_the_highs_object_stays_usable() -> None:
    s = setup()
    highs = new_highs()
    start = on_reference(0)  # at rest at the depot, region 0
    slow = int(np.argmin(s.trip.v_max[:, 0]))
    far = np.full(N - 1, slow)  # the slow corner, 12 m away, for the next 3 s

    sol = qp(start, far, highs=highs)

    assert sol.outcome is SolverOutcome.INFEASIBLE
    assert sol.p is None and sol.u is None
    # The same object then solves a feasible QP.
    milp = s.milp[PAPER].solve(start)
    assert milp.regions is not None
    again = qp(start, milp.regions, highs=highs)
    assert again.outcome is SolverOutcome.OPTIMAL
    assert_obeys_the_fixed_regions(again, start, milp.regions)


def test_a_reused_highs_object_gets_the_time_limit_per_call() -> None:
    # HiGHS's QP solver measures time_limit on the object's lifetime clock; without the
    # correction every call after the first 0.05 s of solving would stop at the limit.
    data = on_reference(40)
    milp = setup().milp[PAPER].solve(data)
    assert milp.regions is not None
    highs = new_highs()
    outcomes = []
    while highs.getRunTime() < 0.15 and len(outcomes) < 2000:
        outcomes.append(qp(data, milp.regions, highs=highs, time_limit_s=0.05).outcome)
    assert highs.getRunTime() >= 0.15
    assert set(outcomes) == {SolverOutcome.OPTIMAL}


def test_a_solve_error_is_retried_once_with_the_same_plan(monkeypatch) -> None:
    data = on_reference(40)
    milp = setup().milp[PAPER].solve(data)
    assert milp.regions is not None
    first = qp(data, milp.regions)
    calls = []
    real = refine.run_outcome

    def fail_first(highs, what):
        calls.append(1)
        return SolverOutcome.ERROR if len(calls) == 1 else real(highs, what)

    monkeypatch.setattr(refine, "run_outcome", fail_first)
    second = qp(data, milp.regions)

    assert len(calls) == 2
    assert second.outcome is SolverOutcome.OPTIMAL
    assert second.p is not None and first.p is not None
    np.testing.assert_allclose(second.p, first.p, rtol=0, atol=PLAN_TOL)
    np.testing.assert_allclose(second.u, first.u, rtol=0, atol=PLAN_TOL / DT**2)

    monkeypatch.setattr(refine, "run_outcome", lambda highs, what: SolverOutcome.ERROR)
    assert qp(data, milp.regions).outcome is SolverOutcome.ERROR


@pytest.mark.parametrize(
    "regions",
    [np.zeros(N - 2, dtype=int), np.full(N - 1, 4), np.full(N - 1, -1), np.zeros(N - 1)],
    ids=["too-short", "past-the-trip", "negative", "not-integer"],
)
def test_a_bad_region_sequence_is_refused(regions: np.ndarray) -> None:
    with pytest.raises(ValueError, match="regions = .* 11 integer positions in the trip's 4"):
        qp(on_reference(0), regions)


def test_a_free_measured_state_is_refused() -> None:
    data = on_reference(0)
    loose = replace(data, p_hi=data.p_hi.copy())
    loose.p_hi[0] += 1.0
    with pytest.raises(ValueError, match="must be fixed to the measured state"):
        qp(loose, np.zeros(N - 1, dtype=int))
