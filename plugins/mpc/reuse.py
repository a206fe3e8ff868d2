"""Solving less: follow the previous plan, one step on, while nothing has happened.

A solve at tick k+1 re-plans what the solve at tick k already planned, with one more step at
the end. While the robot is on its plan, the print caps allow the plan's speeds and no other
robot can come near it, the shifted plan meets every constraint the new solve would impose:
the floor's regions and zone limits (the same points, in the same regions), the caps (checked
here against this tick's caps), the end at rest (its last point repeated, at rest), and the
other robots (checked here with the margin, see `clear_of_all`). So the controller follows it
for up to ``reuse_ticks`` ticks and solves again on an event: a deviation from the plan, new
caps the plan breaks, a robot within reach, a new trip, or the plan's age. A robot held for a
lower one (`neighbours.must_hold`) follows its plan only while braking a tick later would still
keep clear too (`brake_keeps_clear`): held, braking is its only other move.
"""

from __future__ import annotations

import numpy as np

from fleet.plugins import Observation, RobotSpec
from fleet.printing import CapSchedule
from fleet_plugins.mpc.model import Solution
from fleet_plugins.mpc.neighbours import brake_after, closest_approach, outranks, paths_of
from fleet_plugins.mpc.separation import at_rest, predict

#: The measured state must match the previous plan within this (m, m/s) to reuse that plan.
PLAN_MATCH = 1e-6

__all__ = [
    "PLAN_MATCH",
    "within_caps",
    "clear_of_all",
    "brake_keeps_clear",
    "reusable_among",
    "on_plan",
    "RepeatWatch",
]

#: Tolerance (m/s) of the cap check (the solves' feasibility tolerance is 1e-9).
_CAP_TOL = 1e-9


def within_caps(obs: Observation, spec: RobotSpec, v: np.ndarray) -> bool:
    """Whether the plan's velocities ``v`` (steps 0..N) keep the robot's limit and this tick's
    print caps at every step 1..N (step 0 is the measured state)."""
    n = len(v)
    caps = CapSchedule(obs.speed_caps).step_caps(obs.t, spec.period, n)
    bound = np.minimum(spec.v_max, caps)
    return bool(np.all(np.abs(v[1:]) <= bound[1:, None] + _CAP_TOL))


def clear_of_all(obs: Observation, spec: RobotSpec, p: np.ndarray, margin: float) -> bool:
    """Whether every robot in `obs.neighbours` stays out of reach of plan `p` (steps 0..N) over
    the whole horizon, whatever it does of what a solve assumes: carry on with its plan or
    brake along its line of travel.

    Sound and cheap, step by step: over each step k -> k+1 the plan's segment lies in the box of
    its two ends, and the neighbour (on its plan or braking) in the box of its four predicted
    points at k and k+1. Those two boxes must lie ``r_i + r_j + margin`` apart along one axis
    (to `PLAN_MATCH`: a robot a solve stopped at the margin waits there), so the two centres are
    that far apart along it at every instant of the step: the separation rows of a solve hold
    with their margin, whichever robot would have yielded.
    """
    dt, N = spec.period, len(p) - 1
    lo = np.minimum(p[:-1], p[1:])  # (N, 2): the plan's box over each step
    hi = np.maximum(p[:-1], p[1:])
    for n in obs.neighbours:
        centres = predict(n, obs.t, dt, N)
        a_max = n.limits(spec).a_max  # it brakes by its own bound (a fleet may mix robots)
        stop = brake_after(obs.t, (n.x, n.y), (n.vx, n.vy), dt, a_max, N)
        ends = np.stack([centres[:-1], centres[1:], stop[:-1], stop[1:]])  # (4, N, 2)
        # (A plan kept to the margin by a solve sits on it to rounding: 0.8999999999999986 m.)
        half = spec.radius + float(n.radius) + margin - PLAN_MATCH
        apart = (ends.min(axis=0) >= hi + half) | (ends.max(axis=0) <= lo - half)
        if not apart.any(axis=1).all():
            return False
    return True


def brake_keeps_clear(
    obs: Observation, spec: RobotSpec, p: np.ndarray, v: np.ndarray, margin: float
) -> bool:
    """Whether braking along the line of travel from the next state of plan `p`, `v` (steps
    0..N from now) keeps ``r_i + r_j + margin`` (to `PLAN_MATCH`), between the samples too,
    from every neighbour at rest and from every moving one that outranks this robot, whether
    it follows its plan, brakes now or brakes a tick later (both robots a tick on, as
    `neighbours.close` judges).

    A held robot (`neighbours.must_hold`) only follows its plan or brakes; where that brake
    runs into a higher robot it solves (`brake_runs_into`), a tick late. Three MPC robots to
    one station (tests/test_mpc_reuse.py): r02, held for r03, followed its plan and braked a
    tick later, while r01, which outranks it and was held too, drove on a tick along its plan:
    r02's brake then ran into r01's (0.742 m, radii 0.4) and its solves from there were
    infeasible (2 fallbacks)."""
    dt, N = spec.period, len(p) - 1
    mine = np.vstack([p[:1], brake_after(obs.t + dt, p[1], v[1], dt, spec.a_max, N - 1)])
    for n in obs.neighbours:
        centres = predict(n, obs.t, dt, N)
        if not at_rest(centres) and outranks(obs, n):
            continue  # a lower robot keeps clear of this one
        paths = [centres] if at_rest(centres) else paths_of(obs, n, spec, N)
        half = spec.radius + float(n.radius) + margin - PLAN_MATCH
        if min(closest_approach(mine, q) for q in paths) < half:
            return False
    return True


def reusable_among(
    obs: Observation, spec: RobotSpec, last: Solution, margin: float, hold: bool
) -> bool:
    """Whether `last`, one step on, keeps clear of the neighbours for a reuse (`clear_of_all`)
    and, the robot being held, its brake a tick later too (`brake_keeps_clear`)."""
    assert last.p is not None and last.v is not None
    p = np.vstack([last.p[1:], last.p[-1:]])
    if not clear_of_all(obs, spec, p, margin):
        return False
    v = np.vstack([last.v[1:], np.zeros((1, 2))])
    return not hold or brake_keeps_clear(obs, spec, p, v, margin)


def on_plan(obs: Observation, last: Solution | None, last_t: float, dt: float) -> bool:
    """Whether the robot is where the last usable plan `last`, made at `last_t` one period
    `dt` ago, said it would be now (to `PLAN_MATCH`)."""
    if last is None or last.p is None or last.v is None:
        return False
    if abs(obs.t - last_t - dt) > 1e-9:
        return False
    return (
        max(abs(last.p[1, 0] - obs.x), abs(last.p[1, 1] - obs.y)) <= PLAN_MATCH
        and max(abs(last.v[1, 0] - obs.vx), abs(last.v[1, 1] - obs.vy)) <= PLAN_MATCH
    )


class RepeatWatch:
    """Whether a trip's solves have started from the same state twice: a plan that brings the
    robot back to where a solve started, followed without a solve, is solved alike from there,
    for good. In fuzz case s21-0613 an MPC robot held 0.2 m short of a corner went back and
    forth on such a 5-tick plan (4 reused ticks, one solve) for the last 100 s, too little
    motion to count as progress and too much to count as stuck; solving every tick, it was
    reported and let through. Once a state repeats, the trip solves every tick.

    A solve after which the robot stands where it stood (`waited`: at rest, kept at rest by its
    plan or by the start gate, `start`) is no cycle but a robot waiting, and its state is not
    kept. Counted, a robot at rest whose plan was shown a tick late (the gate) solved from the
    same state at the next tick, and from then on every tick of its trip: on a 40-robot fleet
    run (`scripts/bench_fleet.py --sweep 40`) 1,109 of 5,059 solves were such robots at rest
    solving plans at rest, 18 % of the run's CPU time."""

    #: Solve states remembered (cycles up to this many solves long are caught).
    KEEP = 8

    def __init__(self) -> None:
        self._trip: object = None
        self._states: list[tuple[float, float, float, float]] = []
        self.repeated = False

    def solved_from(self, obs: Observation, trip: object) -> bool:
        """Note a solve from `obs`'s state in `trip`; whether some solve of the trip has
        started from a state within `PLAN_MATCH` of another's."""
        if trip is not self._trip:
            self._trip, self._states, self.repeated = trip, [], False
        state = (obs.x, obs.y, obs.vx, obs.vy)
        close = (max(abs(a - b) for a, b in zip(state, s, strict=True)) for s in self._states)
        if any(d <= PLAN_MATCH for d in close):
            self.repeated = True
        self._states = [*self._states[-(self.KEEP - 1) :], state]
        return self.repeated

    def waited(self, obs: Observation, ax: float, ay: float, dt: float) -> None:
        """Forget the state of the solve just noted (`solved_from`) if the robot, at rest, stays
        at rest over this tick (its input `ax`, `ay` over period `dt`): a wait, not a move."""
        still = max(abs(obs.vx + dt * ax), abs(obs.vy + dt * ay), abs(obs.vx), abs(obs.vy))
        if self._states and still <= PLAN_MATCH:
            self._states.pop()
