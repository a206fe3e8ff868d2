"""`MPCController`: the paper's mixed-integer MPC, tracking the path layer's reference.

Per control tick: take the measured state, pick the reference window and the corridor of
regions each horizon step may use, update the trip's model (`model.TripModel`), solve it with
HiGHS and apply the first input. The trip model is built once per reference and updated in
place; a new goal, or a fallback, starts a new trip.
"""

from __future__ import annotations

import math
import numbers
import time
from typing import Any

import highspy
import numpy as np

from fleet.errors import NoPathError
from fleet.highs import new_highs
from fleet.paths import Reference
from fleet.plugins import (
    CAP_LOOKAHEAD_S,
    Command,
    Controller,
    ControllerContext,
    ControlStatus,
    Neighbour,
    Observation,
    SolveReport,
    SolverOutcome,
)
from fleet.plugins.robot import DoubleIntegrator, brake_input
from fleet.printing import CapSchedule
from fleet_plugins.mpc.model import Interface, Solution, StepData, TripModel
from fleet_plugins.mpc.refine import refine_quadratic
from fleet_plugins.mpc.separation import (
    Obstacle,
    Separation,
    at_rest,
    build_separation,
    predict,
    reaches,
    spans,
)
from fleet_plugins.mpc.trip import Trip, reach_boxes

__all__ = ["MPCController"]

#: Per-axis speed (m/s) below which the robot counts as at rest.
REST_SPEED = 1e-9
#: A robot at rest (to this per-axis speed, m/s) this close (m) to its goal holds without a
#: solve: the optimum there is to stay.
PARKED_SPEED = 1e-6
PARKED_DISTANCE = 1e-3
#: The measured state must match the previous plan within this (m, m/s) to reuse that plan.
PLAN_MATCH = 1e-6
#: How far ahead (samples) the progress search along the reference looks.
PROGRESS_WINDOW = 8
#: The cost options: the 1-norm MILP, or that MILP's regions refined by the paper's quadratic cost.
COSTS = ("l1", "quadratic")


class MPCController(Controller):
    """Mixed-integer MPC over the floor's convex regions, solved by HiGHS through Pyomo.

    The paper's formulation: double integrator, zone speed limits as a Big-M union over the
    regions (M tight per row), time-varying print caps per horizon step, input bounds, horizon
    `horizon` with the robot's control period as step. HiGHS cannot solve the paper's
    quadratic cost with binaries (MIQP), so the cost is the 1-norm of the same terms (a MILP,
    measured as the fastest and first-arriving choice; docs/mpc.md compares the candidates).
    ``cost = "quadratic"`` then solves the paper's quadratic cost exactly for the regions that
    MILP chose (a convex QP, `refine.refine_quadratic`) and applies its input when it is optimal.

    The reference is the path layer's time-parameterised trajectory to the goal (tracking only
    the goal stalls in front of obstacles). While the robot keeps pace, step k tracks reference
    sample ``index(t) + k``; when it falls behind (print caps slow it down) the window follows
    its progress along the path instead, one sample ahead, so the reference never runs away.

    Each step k = 1..N-1 may only use the regions of the reference chords around its expected
    progress (±`corridor` chords) plus the region the previous plan used there, and only those
    whose bounding box meets the reachable box of the step: a handful of binaries per solve.

    Other robots (`Observation.neighbours`, with ``avoid_robots``): each one whose predicted
    square can come within reach of the plan adds binaries for the four sides of the square of
    half-width ``r_i + r_j + separation_margin_m`` round its predicted centre (its plan
    interpolated at each step's time), one of which must hold over each group of steps
    (`separation`). The margin is soft (a heavy cost), contact is not. With
    ``respect_priority``, a robot keeps clear of the robots that outrank it (higher priority;
    on a tie, the smaller robot id) wherever they can come within reach, and of the robots it
    outranks only when they are parked for the whole horizon or close (closer than two robots
    at full speed need to stop, plus a step each); a close one may carry on or stop to let it
    pass, so it keeps clear of the box round both. The higher one thus keeps its course, and
    the lower one has a plan to avoid that does not move away as it yields (when both yield,
    both swerve alike and meet again: measured head-on). At most ``max_neighbours`` robots,
    the nearest, are constrained.

    When a solve gives no usable solution (time limit without incumbent, infeasible, solver
    error) the controller falls back: the previous plan shifted by one step if the robot is on
    it and it keeps clear of every neighbour's predicted position (it ends at rest, so it stays
    safe to its end), else braking along the line of travel (with neighbours about, the
    command's plan is then the braking path, so that they avoid it). It then plans a new trip.
    Every command carries a `SolveReport`.

    Parameters
    ----------
    horizon:
        N, the number of steps (the paper: 25).
    q_position, q_velocity, r_input:
        Cost weights (the paper: Q = R = I).
    corridor:
        Reference chords either side of the expected progress whose regions a step may use.
    time_limit_s:
        Wall-clock limit per solve (s); a solve stopped with an incumbent uses it.
    warm_start:
        Offer HiGHS the shifted previous plan as a starting solution (``interface = "direct"``
        only: Pyomo's persistent HiGHS interface has no warm start).
    cost:
        ``"l1"`` (default) or ``"quadratic"`` (the MILP, then the QP with its regions fixed).
    interface:
        ``"direct"`` (default): per-step bounds written into the persistent HiGHS object by
        index; ``"pyomo"``: mutable Params through Pyomo's persistent update (slower, same model).
    avoid_robots:
        Keep clear of the other robots in the observation (their plans); False ignores them.
    separation_margin_m:
        Clearance (m) kept between two robots' discs on top of the sum of their radii (soft:
        a plan enters it only where it cannot keep out).
    max_neighbours:
        At most this many robots (the nearest that need it) are kept clear of per solve.
    respect_priority:
        Yield to higher-priority robots and keep course for lower ones unless they are parked
        or close (see above); False keeps clear of every robot in reach.
    """

    name = "mpc"

    def __init__(
        self,
        horizon: int = 25,
        q_position: float = 1.0,
        q_velocity: float = 1.0,
        r_input: float = 1.0,
        corridor: int = 1,
        time_limit_s: float = 1.0,
        warm_start: bool = True,
        interface: str = "direct",
        cost: str = "l1",
        avoid_robots: bool = True,
        separation_margin_m: float = 0.1,
        max_neighbours: int = 3,
        respect_priority: bool = True,
    ) -> None:
        super().__init__()
        if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 2:
            raise ValueError(f"MPCController option horizon = {horizon!r}: must be an integer >= 2")
        for label, w in (
            ("q_position", q_position),
            ("q_velocity", q_velocity),
            ("r_input", r_input),
        ):
            if not _non_negative(w):
                raise ValueError(f"MPCController option {label} = {w!r}: must be a number >= 0")
        if isinstance(corridor, bool) or not isinstance(corridor, int) or corridor < 0:
            raise ValueError(
                f"MPCController option corridor = {corridor!r}: must be an integer >= 0"
            )
        if not _non_negative(time_limit_s) or time_limit_s == 0:
            raise ValueError(
                f"MPCController option time_limit_s = {time_limit_s!r}: must be a number > 0"
            )
        for label, flag in (
            ("warm_start", warm_start),
            ("avoid_robots", avoid_robots),
            ("respect_priority", respect_priority),
        ):
            if not isinstance(flag, bool):
                raise ValueError(f"MPCController option {label} = {flag!r}: must be a bool")
        if not _non_negative(separation_margin_m):
            raise ValueError(
                f"MPCController option separation_margin_m = {separation_margin_m!r}: "
                "must be a number >= 0"
            )
        if (
            isinstance(max_neighbours, bool)
            or not isinstance(max_neighbours, int)
            or max_neighbours < 0
        ):
            raise ValueError(
                f"MPCController option max_neighbours = {max_neighbours!r}: must be an integer >= 0"
            )
        try:
            self.interface = Interface(interface)
        except ValueError:
            allowed = ", ".join(repr(i.value) for i in Interface)
            raise ValueError(
                f"MPCController option interface = {interface!r}: must be one of {allowed}"
            ) from None
        if cost not in COSTS:
            allowed = ", ".join(repr(c) for c in COSTS)
            raise ValueError(f"MPCController option cost = {cost!r}: must be one of {allowed}")
        self.cost = cost
        self.horizon = horizon
        self.weights = (float(q_position), float(q_velocity), float(r_input))
        self.corridor = corridor
        self.time_limit_s = float(time_limit_s)
        self.warm_start = warm_start
        self.avoid_robots = avoid_robots
        self.separation_margin_m = float(separation_margin_m)
        self.max_neighbours = max_neighbours
        self.respect_priority = respect_priority
        self._clear()

    def __repr__(self) -> str:
        return (
            f"MPCController(horizon={self.horizon}, weights={self.weights}, "
            f"corridor={self.corridor}, time_limit_s={self.time_limit_s}, "
            f"warm_start={self.warm_start}, interface={self.interface.value!r}, "
            f"cost={self.cost!r}, avoid_robots={self.avoid_robots}, "
            f"separation_margin_m={self.separation_margin_m}, "
            f"max_neighbours={self.max_neighbours}, respect_priority={self.respect_priority})"
        )

    def reset(self, context: ControllerContext) -> None:
        """Keep the context; check the horizon against the robot and the cap look-ahead."""
        super().reset(context)
        spec = context.spec
        span = self.horizon * spec.period
        stop = spec.v_max / spec.a_max
        if span < stop - 1e-9:
            # Every plan ends at rest: a horizon shorter than braking from full speed never
            # lets the robot reach it, and a much shorter one never lets it start.
            raise ValueError(
                f"MPCController horizon {self.horizon} x period {spec.period:g} s = {span:g} s "
                f"is shorter than braking from full speed ({spec.v_max:g} / {spec.a_max:g} = "
                f"{stop:g} s); use horizon >= {math.ceil(stop / spec.period - 1e-9)}"
            )
        if span > CAP_LOOKAHEAD_S:
            raise ValueError(
                f"MPCController horizon {self.horizon} x period {context.spec.period:g} s = "
                f"{span:g} s reaches past the {CAP_LOOKAHEAD_S:g} s of print caps an "
                "observation carries; shorten the horizon"
            )
        self._clear()

    def _clear(self) -> None:
        self._goal: tuple[float, float] | None = None
        self._trip: Trip | None = None
        self._model: TripModel | None = None
        self._last: Solution | None = None  # the latest usable solution (or its shifted copy)
        self._last_model: TripModel | None = None  # the model `_last` came from
        self._last_t = math.nan
        self._progress = 0
        self._failed: tuple[Any, ...] | None = None
        #: Trips built so far (a new goal or a fallback starts one).
        self.trips = 0
        #: Binaries switched on (corridor size) in each solve so far, for benchmarks.
        self.binaries: list[int] = []
        #: Separation binaries added in each solve so far (0: no robot within reach).
        self.separation_binaries: list[int] = []
        #: Robots kept clear of in each solve so far.
        self.separation_robots: list[tuple[str, ...]] = []
        #: Quadratic refinements that were not optimal (their MILP input was applied instead).
        self.qp_failures = 0
        self._qp_highs: highspy.Highs | None = None

    # -- the control law ------------------------------------------------------------------------
    def compute(self, obs: Observation) -> Command:
        """The first input of this tick's optimal plan (or a safe fallback)."""
        started = time.perf_counter()
        spec = self.context.spec
        if obs.goal is None:
            self._goal = self._trip = self._model = self._last = None
            return self._brake(obs, ControlStatus.IDLE)
        goal = (float(obs.goal[0]), float(obs.goal[1]))
        if self._parked(obs, goal):
            # At rest on the goal the optimum is to stay: skip the solve. Others see a robot
            # parked for the whole horizon (and keep clear of it as such).
            # (A speed left from the solver's tolerances is cancelled within the step.)
            dt = spec.period
            end = obs.t + self.horizon * dt
            plan = ((obs.t, obs.x, obs.y), (end, obs.x + dt * obs.vx, obs.y + dt * obs.vy))
            return Command(-obs.vx / dt + 0.0, -obs.vy / dt + 0.0, ControlStatus.OK, plan)
        if (goal != self._goal or self._model is None) and not self._new_trip(obs, goal):
            return self._brake(obs, ControlStatus.FALLBACK)
        assert self._trip is not None and self._model is not None
        data, warm = self._step_data(obs)
        separation = self._separation(obs, data)
        solution = self._model.solve(data, warm, separation)
        if solution.outcome is SolverOutcome.INFEASIBLE:
            # The corridor assumed the plan keeps pace with the reference; open it back to the
            # robot's own progress and try once more before falling back.
            first = solution.solver_s
            data, warm = self._step_data(obs, wide=True)
            separation = self._separation(obs, data)
            solution = self._model.solve(data, warm, separation)
            solution.solver_s += first
        if self.cost == "quadratic" and solution.outcome.usable:
            solution = self._refine(solution, data, separation)
        step_s = time.perf_counter() - started
        report = SolveReport(solution.outcome, solution.solver_s, step_s)
        if solution.outcome.usable:
            assert solution.p is not None and solution.u is not None
            self._last, self._last_t, self._last_model = solution, obs.t, self._model
            dt = spec.period
            plan = tuple(
                (obs.t + k * dt, float(solution.p[k, 0]), float(solution.p[k, 1]))
                for k in range(len(solution.p))
            )
            u = solution.u[0]
            return Command(float(u[0]), float(u[1]), ControlStatus.OK, plan, report)
        return self._fallback(obs, report)

    def _parked(self, obs: Observation, goal: tuple[float, float]) -> bool:
        """At rest (to `PARKED_SPEED`) within `PARKED_DISTANCE` of the goal, with no robot closer
        than contact (then a solve may move it away)."""
        if max(abs(obs.vx), abs(obs.vy)) > PARKED_SPEED:
            return False
        if math.hypot(goal[0] - obs.x, goal[1] - obs.y) > PARKED_DISTANCE:
            return False
        r = self.context.spec.radius
        return all(math.hypot(n.x - obs.x, n.y - obs.y) > r + n.radius for n in obs.neighbours)

    def _refine(self, milp: Solution, data: StepData, separation: Separation | None) -> Solution:
        """The paper's quadratic cost for the MILP's regions; the MILP's plan if that fails.

        With other robots about, the sides of their squares the MILP chose are fixed too: each
        is a bound on one coordinate of one point, so the QP keeps clear of them as well.
        """
        assert milp.regions is not None
        spec = self.context.spec
        if separation is not None and milp.separation is not None:
            p_lo, p_hi = separation.bounds(milp.separation, data.p_lo, data.p_hi)
            data = StepData(p_lo, p_hi, data.v_lo, data.v_hi, data.z_ub, data.p_ref, data.v_ref)
        if self._qp_highs is None:
            self._qp_highs = new_highs()  # its own object: each refinement replaces its model
        assert self._trip is not None
        qp = refine_quadratic(
            self._trip,
            data,
            milp.regions,
            N=self.horizon,
            dt=spec.period,
            a_max=spec.a_max,
            v_robot=spec.v_max,
            weights=self.weights,
            time_limit_s=self.time_limit_s,
            highs=self._qp_highs,
        )
        if qp.outcome is not SolverOutcome.OPTIMAL:
            self.qp_failures += 1
            milp.solver_s += qp.solver_s
            return milp
        # The report keeps the MILP's outcome (the command comes from a usable plan either way)
        # and counts both solves' time.
        return Solution(
            milp.outcome,
            milp.solver_s + qp.solver_s,
            p=qp.p,
            v=qp.v,
            u=qp.u,
            regions=milp.regions,
            separation=milp.separation,
        )

    def _new_trip(self, obs: Observation, goal: tuple[float, float]) -> bool:
        """Plan a reference from here to `goal` and build its model; False if there is no path."""
        spec = self.context.spec
        attempt = (goal, obs.x, obs.y)
        if self._failed == attempt:
            return False
        try:
            ref = self.context.planner.reference(
                start=(obs.x, obs.y), goal=goal, dt=spec.period, t0=obs.t
            )
        except NoPathError:
            self._failed = attempt
            return False
        self._trip = Trip.build(self.context.floor, ref)
        self._model = TripModel(
            self._trip,
            self.horizon,
            spec.period,
            spec.a_max,
            spec.v_max,
            self.weights,
            self.interface,
            self.time_limit_s,
        )
        self._goal, self._failed, self._progress = goal, None, 0
        self.trips += 1
        return True

    def _step_data(
        self, obs: Observation, wide: bool = False
    ) -> tuple[StepData, np.ndarray | None]:
        """Bounds, corridor and reference window for this tick (and a warm start, if any).

        `wide` opens every step's corridor back to the robot's own progress, for when the plan
        cannot keep pace with the reference window (the retry after an infeasible solve).
        """
        spec = self.context.spec
        trip, model = self._trip, self._model
        assert trip is not None and model is not None
        N, dt, a = self.horizon, spec.period, spec.a_max
        ref = trip.reference
        last_index = ref.steps
        p0 = np.array([obs.x, obs.y])
        v0 = np.array([obs.vx, obs.vy])

        # Speed bounds per step: robot limit and print caps, never below what braking at full
        # deceleration reaches (a cap that starts too soon is then missed by the least possible,
        # instead of making the problem infeasible).
        caps = CapSchedule(obs.speed_caps).step_caps(obs.t, dt, N + 1)
        bound = np.minimum(spec.v_max, caps)[:, None].repeat(2, axis=1)
        bound[N] = 0.0  # end at rest
        braking = np.abs(v0)[None, :] - np.arange(N + 1)[:, None] * a * dt
        bound = np.maximum(bound, braking)
        p_lo, p_hi = reach_boxes(p0, v0, bound, dt, a)
        xlo, ylo, xhi, yhi = trip.box
        p_lo[1:] = np.maximum(p_lo[1:], [xlo, ylo])
        p_hi[1:] = np.minimum(p_hi[1:], [xhi, yhi])
        p_hi[1:] = np.maximum(p_hi[1:], p_lo[1:])  # empty box: leave it to HiGHS to say so
        v_lo, v_hi = -bound.copy(), bound.copy()
        v_lo[0] = v_hi[0] = v0

        # Where along the reference: on time, the timed sample; behind, just past the progress.
        self._progress = int(trip.progress(p0[None, :], self._progress, PROGRESS_WINDOW)[0])
        timed = ref.index(obs.t)
        base = min(max(timed, self._progress), self._progress + 1)
        p_ref, v_ref, at = _reference_window(ref, base, np.minimum(spec.v_max, caps), dt)
        # The chord each step's reference starts on, and the last chord it reaches: step k
        # runs along the reference from at[k] to at[k+1].
        chord = np.minimum(np.floor(at).astype(int), last_index)
        chord_end = np.maximum(np.ceil(at[1:]).astype(int) - 1, chord[:-1])

        # Corridor: chords around both where the reference is and where the last plan expected
        # the robot to be, plus the region the last plan used (so the shifted plan stays open).
        # (The last plan's regions are positions in its own trip's S: only reuse them there.)
        on_plan = self._on_plan(obs) and self._last_model is model
        expected = chord
        if on_plan:
            assert self._last is not None and self._last.p is not None
            shifted = np.vstack([self._last.p[1:], self._last.p[-1:]])
            expected = trip.progress(shifted, self._progress, N + PROGRESS_WINDOW)
        z_ub = np.zeros((N - 1, len(trip.regions)))
        w = self.corridor
        for k in range(1, N):
            lo = min(expected[k], chord[k]) - w
            if wide:
                lo = min(lo, self._progress - w)
            hi = max(expected[k + 1], chord_end[k]) + w
            allowed = set(trip.corridor(lo, hi))
            if on_plan:
                assert self._last is not None and self._last.regions is not None
                allowed.add(int(self._last.regions[min(k, N - 2)]))
            for j in allowed:
                z_ub[k - 1, j] = 1.0
            # Keep only regions whose box meets where the step can be.
            lo_box = np.minimum(p_lo[k], p_lo[k + 1])
            hi_box = np.maximum(p_hi[k], p_hi[k + 1])
            rb = trip.region_boxes
            outside = (
                (rb[:, 0] > hi_box[0] + 1e-9)
                | (rb[:, 2] < lo_box[0] - 1e-9)
                | (rb[:, 1] > hi_box[1] + 1e-9)
                | (rb[:, 3] < lo_box[1] - 1e-9)
            )
            z_ub[k - 1, outside] = 0.0
        data = StepData(p_lo, p_hi, v_lo, v_hi, z_ub, p_ref, v_ref)
        self.binaries.append(int(z_ub.sum()))
        warm = None
        if self.warm_start and on_plan:
            assert self._last is not None
            warm = model.shifted_columns(self._last, data)
        return data, warm

    # -- other robots ---------------------------------------------------------------------------
    def _separation(self, obs: Observation, data: StepData) -> Separation | None:
        """The rows keeping this solve's plan clear of the robots that need it (None: none).

        A robot needs it when its square can come within reach of the plan (the reachable
        boxes, narrowed to the regions each step may use) and, with `respect_priority`, it
        outranks this one or is parked or close (see the class). The nearest `max_neighbours`
        of those are kept.
        """
        if not self.avoid_robots or not obs.neighbours or self.max_neighbours == 0:
            self.separation_binaries.append(0)
            self.separation_robots.append(())
            return None
        spec = self.context.spec
        N, dt = self.horizon, spec.period
        p_lo, p_hi = self._region_bounds(data)
        # Within this, two robots at full speed could not stop before they met.
        near = spec.v_max**2 / spec.a_max + 2.0 * spec.v_max * dt
        margin = self.separation_margin_m
        picked: list[tuple[float, str, Obstacle]] = []
        for n in obs.neighbours:
            centres = predict(n, obs.t, dt, N)
            half = spec.radius + float(n.radius) + margin
            distance = math.hypot(n.x - obs.x, n.y - obs.y)
            ob = Obstacle.square(n.robot, centres, half, margin)
            if self.respect_priority and _outranks(obs, n) and not at_rest(centres):
                if distance >= half + near:
                    continue  # it yields to this robot; this one keeps its course
                # Close by: it may carry on with its plan or stop to let this one pass (it
                # changes its plan as this one's changes): keep clear of both.
                stop = np.array(_braking_path(obs.t, n.x, n.y, n.vx, n.vy, dt, spec.a_max, N))
                stop = np.vstack([stop[:, 1:], np.repeat(stop[-1:, 1:], N + 1 - len(stop), 0)])
                ob = Obstacle.between(n.robot, centres, stop, half, margin)
            if not reaches(ob, p_lo, p_hi):
                continue
            picked.append((distance, n.robot, ob))
        picked.sort(key=lambda item: (item[0], item[1]))
        chosen = tuple(ob for _, _, ob in picked[: self.max_neighbours])
        if not chosen:
            self.separation_binaries.append(0)
            self.separation_robots.append(())
            return None
        separation = build_separation(chosen, p_lo, p_hi, spans(N, dt))
        self.separation_binaries.append(separation.binaries)
        self.separation_robots.append(tuple(ob.robot for ob in chosen))
        return separation

    def _region_bounds(self, data: StepData) -> tuple[np.ndarray, np.ndarray]:
        """Where each p[k] can be: the reachable box within the boxes of the regions its
        steps may use (p[k] lies in the region of step k-1 and of step k)."""
        assert self._trip is not None
        boxes = self._trip.region_boxes
        N = self.horizon
        allowed = data.z_ub > 0.5  # (N-1, |S|), steps 1..N-1
        inf = np.inf
        lo_s = np.where(allowed[:, :, None], boxes[None, :, :2], inf).min(axis=1)  # (N-1, 2)
        hi_s = np.where(allowed[:, :, None], boxes[None, :, 2:], -inf).max(axis=1)
        none = ~allowed.any(axis=1)  # no region open (the solve is infeasible): no narrowing
        lo_s[none], hi_s[none] = -inf, inf
        lo = np.full((N + 1, 2), -inf)
        hi = np.full((N + 1, 2), inf)
        # Point k is an end of steps k-1 and k (for k - 1 >= 1 and k <= N - 1).
        lo[1:N] = np.maximum(lo[1:N], lo_s)
        hi[1:N] = np.minimum(hi[1:N], hi_s)
        lo[2 : N + 1] = np.maximum(lo[2 : N + 1], lo_s)
        hi[2 : N + 1] = np.minimum(hi[2 : N + 1], hi_s)
        p_lo = np.maximum(data.p_lo, lo)
        p_hi = np.minimum(data.p_hi, hi)
        p_hi = np.maximum(p_hi, p_lo)  # an empty box: left for HiGHS to find infeasible
        return p_lo, p_hi

    def _clear_of_neighbours(self, obs: Observation, p: np.ndarray) -> bool:
        """Whether plan `p` (steps 0..N from now) keeps every neighbour's predicted disc out
        of its own at steps 1..N (a fallback plan is checked before it is followed)."""
        if not self.avoid_robots:
            return True
        spec = self.context.spec
        for n in obs.neighbours:
            centres = predict(n, obs.t, spec.period, len(p) - 1)
            gap = np.hypot(*(p[1:] - centres[1:]).T)
            if np.any(gap < spec.radius + float(n.radius) - 1e-9):
                return False
        return True

    def _on_plan(self, obs: Observation) -> bool:
        """Whether the robot is where the last usable plan said it would be now."""
        last = self._last
        if last is None or last.p is None or last.v is None:
            return False
        if abs(obs.t - self._last_t - self.context.spec.period) > 1e-9:
            return False
        return (
            max(abs(last.p[1, 0] - obs.x), abs(last.p[1, 1] - obs.y)) <= PLAN_MATCH
            and max(abs(last.v[1, 0] - obs.vx), abs(last.v[1, 1] - obs.vy)) <= PLAN_MATCH
        )

    # -- fallbacks ------------------------------------------------------------------------------
    def _fallback(self, obs: Observation, report: SolveReport) -> Command:
        """The shifted previous plan if the robot is on it and it keeps clear of the other
        robots, else braking; then a new trip."""
        on_plan = self._on_plan(obs)
        self._model = None  # plan a new trip next tick
        if on_plan and obs.neighbours:
            assert self._last is not None and self._last.p is not None
            shifted_p = np.vstack([self._last.p[1:], self._last.p[-1:]])
            on_plan = self._clear_of_neighbours(obs, shifted_p)
        if on_plan:
            last = self._last
            assert last is not None and last.p is not None and last.v is not None
            assert last.u is not None and last.regions is not None
            # Move the stored plan one step on, so a run of fallbacks walks down it to rest.
            shifted = Solution(
                last.outcome,
                last.solver_s,
                p=np.vstack([last.p[1:], last.p[-1:]]),
                v=np.vstack([last.v[1:], np.zeros((1, 2))]),
                u=np.vstack([last.u[1:], np.zeros((1, 2))]),
                regions=np.concatenate([last.regions[1:], last.regions[-1:]]),
            )
            self._last, self._last_t = shifted, obs.t
            u = last.u[1]
            dt = self.context.spec.period
            plan = tuple(
                (obs.t + k * dt, float(shifted.p[k, 0]), float(shifted.p[k, 1]))
                for k in range(len(shifted.p))
            )
            return Command(float(u[0]), float(u[1]), ControlStatus.FALLBACK, plan, report)
        self._last = None
        cmd = self._brake(obs, ControlStatus.FALLBACK)
        return Command(cmd.ax, cmd.ay, cmd.status, cmd.plan, report)

    def _brake(self, obs: Observation, status: ControlStatus) -> Command:
        """Brake along the line of travel; with other robots about, the braking path is the
        plan (else they would keep avoiding the last plan, which runs on past the stop)."""
        if abs(obs.vx) <= REST_SPEED and abs(obs.vy) <= REST_SPEED:
            return Command(0.0, 0.0, status)
        spec = self.context.spec
        ax, ay = brake_input(obs.vx, obs.vy, spec.period, spec.a_max)
        plan: tuple[tuple[float, float, float], ...] = ()
        if obs.neighbours:
            plan = _braking_path(
                obs.t, obs.x, obs.y, obs.vx, obs.vy, spec.period, spec.a_max, self.horizon
            )
        return Command(ax, ay, status, plan)


def _outranks(obs: Observation, other: Neighbour) -> bool:
    """Whether the robot of `obs` goes before `other`: higher priority, or on a tie (an engine
    that sets none) the smaller robot id."""
    if obs.priority != other.priority:
        return obs.priority > other.priority
    return obs.robot < other.robot


def _braking_path(
    t: float, x: float, y: float, vx: float, vy: float, dt: float, a_max: float, steps: int
) -> tuple[tuple[float, float, float], ...]:
    """Samples ``(t, x, y)`` of braking along the line of travel until at rest (at most
    `steps` periods; a neighbour is assumed to brake as hard as this robot can)."""
    robot = DoubleIntegrator(dt, a_max)
    out = [(t, x, y)]
    for k in range(1, steps + 1):
        ax, ay = brake_input(vx, vy, dt, a_max)
        x, y, vx, vy = robot.step(x, y, vx, vy, ax, ay)
        out.append((t + k * dt, x, y))
        if abs(vx) <= REST_SPEED and abs(vy) <= REST_SPEED:
            break
    return tuple(out)


def _non_negative(x: object) -> bool:
    return (
        not isinstance(x, bool)
        and isinstance(x, numbers.Real)
        and math.isfinite(float(x))
        and float(x) >= 0
    )


def _reference_window(
    ref: Reference, base: int, speed: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference for horizon steps 0..N, starting at sample `base`, slowed to `speed`.

    Where the reference is faster (per axis) than step k's allowed speed (a print cap), it is
    retimed: it advances only the fraction ``speed / |v_ref|`` of a sample per step, along the
    same chords, with its velocity scaled alike. Without caps this is samples ``base + k``.
    Returns positions and velocities ``(N+1, 2)`` and the fractional sample index of each step.
    """
    last = ref.steps
    pos, vel = ref.positions, ref.velocities
    n = len(speed)
    p_ref = np.empty((n, 2))
    v_ref = np.empty((n, 2))
    at = np.empty(n)
    s = float(base)
    for k in range(n):
        s = min(s, float(last))
        i = int(s)
        frac = s - i
        fastest = max(abs(vel[i, 0]), abs(vel[i, 1]))
        scale = 1.0 if fastest <= speed[k] or fastest < 1e-12 else speed[k] / fastest
        # Along chord i: p[i] + frac * dt * v[i] (the chord is the step p[i] -> p[i+1]).
        p_ref[k] = pos[i] + frac * dt * vel[i]
        v_ref[k] = vel[i] * scale
        at[k] = s
        s += scale
    return p_ref, v_ref, at
