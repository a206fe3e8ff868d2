"""`MPCController`: the paper's mixed-integer MPC, tracking the path layer's reference.

Per control tick: take the measured state, pick the reference window and the corridor of
regions each horizon step may use (`horizon`) and the robots to keep clear of (`neighbours`),
update the trip's model (`model.TripModel`), solve it with HiGHS (refined by `refine` for the
quadratic cost) and apply the first input, or fall back (`recover`). The trip model is built
once per reference and updated in place; a new goal, or a fallback, starts a new trip. The
controller keeps what lasts from tick to tick (the trip, the last plan, the counts of
benchmarks) and its options (`options` checks them).
"""

from __future__ import annotations

import math
import time
from typing import Any

import highspy
import numpy as np

from fleet.errors import NoPathError
from fleet.highs import new_highs
from fleet.plugins import (
    Command,
    Controller,
    ControllerContext,
    ControlStatus,
    Observation,
    SolveReport,
    SolverOutcome,
)
from fleet_plugins.mpc.crowd import solve_clear
from fleet_plugins.mpc.fallback import brake, park, plan_points, shifted, stays_put
from fleet_plugins.mpc.horizon import PROGRESS_WINDOW, into_regions, region_bounds, step_data
from fleet_plugins.mpc.model import Solution, StepData, TripModel
from fleet_plugins.mpc.neighbours import (
    brake_runs_into,
    must_hold,
    robots_to_avoid,
)
from fleet_plugins.mpc.options import (
    DEFAULT_MAX_NODES,
    check_horizon,
    check_options,
    default_reuse_ticks,
)
from fleet_plugins.mpc.recover import fall_back, stop
from fleet_plugins.mpc.refine import refine_milp
from fleet_plugins.mpc.reuse import RepeatWatch, on_plan, reusable_among, within_caps
from fleet_plugins.mpc.separation import Obstacle, Separation, spans
from fleet_plugins.mpc.start import StartGate
from fleet_plugins.mpc.trip import Trip

__all__ = ["MPCController"]

#: A robot at rest (to this per-axis speed, m/s) this close (m) to its goal holds without a
#: solve: the optimum there is to stay.
PARKED_SPEED = 1e-6
PARKED_DISTANCE = 1e-3


def parked(obs: Observation, goal: tuple[float, float], radius: float) -> bool:
    """At rest (to `PARKED_SPEED`) within `PARKED_DISTANCE` of the goal, with no robot closer
    than contact (then a solve may move it away)."""
    if max(abs(obs.vx), abs(obs.vy)) > PARKED_SPEED:
        return False
    if math.hypot(goal[0] - obs.x, goal[1] - obs.y) > PARKED_DISTANCE:
        return False
    return all(math.hypot(n.x - obs.x, n.y - obs.y) > radius + n.radius for n in obs.neighbours)


class MPCController(Controller):
    """Mixed-integer MPC over the floor's convex regions, solved by HiGHS.

    The paper's formulation: double integrator, zone speed limits as a Big-M union over the
    regions (M tight per row), time-varying print caps per horizon step, input bounds, horizon
    `horizon` with the robot's control period as step. HiGHS cannot solve the paper's
    quadratic cost with binaries (MIQP), so the cost is the 1-norm of the same terms (a MILP,
    measured as the fastest and first-arriving choice; docs/mpc.md compares the candidates).
    ``cost = "quadratic"`` then solves the paper's quadratic cost exactly for the regions that
    MILP chose (a convex QP, `refine.refine_quadratic`) and applies its input when it is optimal.

    The reference is the path layer's time-parameterised trajectory to the goal (tracking only the
    goal stalls in front of obstacles). While the robot keeps pace, step k tracks reference sample
    ``index(t) + k``; when it falls behind (print caps slow it down) the window follows its
    progress along the path instead, one sample ahead, so the reference never runs away.

    Each step k = 1..N-1 may only use the regions of the reference chords around its expected
    progress (±`corridor` chords) plus the region the previous plan used there, and only those
    whose bounding box meets the reachable box of the step: a handful of binaries per solve.

    Other robots (`Observation.neighbours`, with ``avoid_robots``): each whose predicted square
    (its plan and braking path) can come within reach of the plan adds binaries for the four sides
    of the square of half-width ``r_i + r_j + separation_margin_m`` round its predicted centre, one
    of which must hold over each group of steps (`separation`; the margin is soft, contact is not).
    With ``respect_priority``, a robot keeps clear of higher robots, and of lower ones only when
    parked or close; held by a close moving lower one it follows its plan or brakes, and at rest it
    shows its start a tick early (`neighbours`, `start`). The nearest ``max_neighbours`` robots are
    constrained, then any other the plan runs into (`crowd`).

    A solve with no usable solution (node limit without incumbent, the wall-clock guard,
    infeasible, solver error) falls back (`recover.fall_back`) to the previous plan one step on if
    the robot is on it and it keeps clear of the neighbours, else to braking (`fallback.brake`); a
    new trip follows, as after a plan that keeps it at rest off its goal with no robot about
    that moves (`fallback.stays_put`). With no goal, or no path to it, it brakes, or follows its
    plan where braking would leave the floor or a zone's limit (`recover.stop`). Each solved
    tick's command carries a `SolveReport`.

    Parameters
    ----------
    horizon:
        N, the number of steps (the paper: 25).
    q_position, q_velocity, r_input:
        Cost weights (the paper: Q = R = I).
    corridor:
        Reference chords either side of the expected progress whose regions a step may use.
    corridor_steps:
        The steps (1, 2, ...) that get the whole corridor; later ones only the chords from the
        reference's to the expected progress: their binaries cost the most search.
    max_nodes:
        Branch-and-bound nodes per solve (HiGHS ``mip_max_nodes``): the solve's stopping
        rule, which depends on the inputs only, so the same seed gives the same run however
        loaded the machine is. A solve stopped by it applies its incumbent (``feasible``) or
        falls back (``no_solution``). The default is far above any solve measured
        (docs/mpc.md, "Deterministic stopping").
    time_limit_s:
        Wall-clock guard per solve (s), a last resort far above any normal solve: a solve it
        stops falls back (what HiGHS had found depends on the machine's speed), is logged as
        a warning and counted in the summary (``solver.time_limit_hits``).
    warm_start:
        Offer HiGHS the shifted previous plan as a starting solution (``interface = "direct"``
        only: Pyomo's persistent HiGHS interface has no warm start).
    cost:
        ``"l1"`` (default) or ``"quadratic"`` (the MILP, then the QP with its regions fixed).
    interface:
        ``"direct"`` (default): each step's MILP bounded to what the step can reach, written
        straight into HiGHS (`bounded`); ``"pyomo"``: the trip's Pyomo model, mutable Params
        through Pyomo's persistent update (slower, the same optimal costs).
    avoid_robots:
        Keep clear of the other robots in the observation (their plans); False ignores them.
    separation_margin_m:
        Clearance (m) kept between two robots' discs on top of the sum of their radii (soft:
        a plan enters it only where it cannot keep out).
    max_neighbours:
        The solve keeps clear of this many robots (the nearest that need it), and of any other
        one its plan then runs into (solved again with those added).
    respect_priority:
        Yield to higher-priority robots and keep course for lower ones unless they are parked
        or close (see above); False keeps clear of every robot in reach.
    reuse_ticks:
        Follow the previous plan, one step on, for up to this many ticks without a solve while
        the robot is on it, it keeps this tick's print caps and no other robot can come within
        reach of it (`reuse`); any of those events, or the age, brings a solve; such a tick's
        command carries no `SolveReport`. None (default): 4, or ``horizon - 1`` if that is
        less (`options.default_reuse_ticks`). 0: solve every tick.
    """

    name = "mpc"

    def __init__(
        self,
        horizon: int = 25,
        q_position: float = 1.0,
        q_velocity: float = 1.0,
        r_input: float = 1.0,
        corridor: int = 1,
        corridor_steps: int = 6,
        time_limit_s: float = 10.0,
        max_nodes: int = DEFAULT_MAX_NODES,
        warm_start: bool = True,
        interface: str = "direct",
        cost: str = "l1",
        avoid_robots: bool = True,
        separation_margin_m: float = 0.1,
        max_neighbours: int = 3,
        respect_priority: bool = True,
        reuse_ticks: int | None = None,
    ) -> None:
        super().__init__()
        if reuse_ticks is None and isinstance(horizon, int) and not isinstance(horizon, bool):
            reuse_ticks = default_reuse_ticks(horizon)
        self.interface = check_options(
            horizon=horizon,
            q_position=q_position,
            q_velocity=q_velocity,
            r_input=r_input,
            corridor=corridor,
            corridor_steps=corridor_steps,
            time_limit_s=time_limit_s,
            max_nodes=max_nodes,
            warm_start=warm_start,
            interface=interface,
            cost=cost,
            avoid_robots=avoid_robots,
            separation_margin_m=separation_margin_m,
            max_neighbours=max_neighbours,
            respect_priority=respect_priority,
            reuse_ticks=reuse_ticks,
        )
        self.cost = cost
        self.horizon = horizon
        self.weights = (float(q_position), float(q_velocity), float(r_input))
        self.corridor = corridor
        self.corridor_steps = corridor_steps
        self.time_limit_s = float(time_limit_s)
        self.max_nodes = max_nodes
        self.warm_start = warm_start
        self.avoid_robots = avoid_robots
        self.separation_margin_m = float(separation_margin_m)
        self.max_neighbours = max_neighbours
        self.respect_priority = respect_priority
        self.reuse_ticks = reuse_ticks
        self._clear()

    def __repr__(self) -> str:
        return (
            f"MPCController(horizon={self.horizon}, weights={self.weights}, "
            f"corridor={self.corridor}, corridor_steps={self.corridor_steps}, "
            f"time_limit_s={self.time_limit_s}, "
            f"max_nodes={self.max_nodes}, warm_start={self.warm_start}, "
            f"interface={self.interface.value!r}, cost={self.cost!r}, "
            f"avoid_robots={self.avoid_robots}, separation_margin_m={self.separation_margin_m}, "
            f"max_neighbours={self.max_neighbours}, respect_priority={self.respect_priority}, "
            f"reuse_ticks={self.reuse_ticks})"
        )

    def reset(self, context: ControllerContext) -> None:
        """Keep the context; check the horizon against the robot and the cap look-ahead."""
        super().reset(context)
        check_horizon(self.horizon, context.spec)
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
        self._reused = 0  # ticks the latest solved plan has been followed without a solve
        self._repeats = RepeatWatch()
        self._go = StartGate(self.respect_priority and self.avoid_robots, self.separation_margin_m)
        #: Ticks that followed the previous plan instead of solving (`reuse_ticks`).
        self.reuses = 0
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
            self._goal = self._trip = self._model = None
            return self._stop(obs, ControlStatus.IDLE)
        goal = (float(obs.goal[0]), float(obs.goal[1]))
        if parked(obs, goal, spec.radius):
            return park(obs, spec, self.horizon)  # at rest on the goal: staying is optimal
        if (goal != self._goal or self._model is None) and not self._new_trip(obs, goal):
            return self._stop(obs, ControlStatus.FALLBACK)
        assert self._trip is not None and self._model is not None
        hold = self.respect_priority and self.avoid_robots
        hold = hold and must_hold(obs, spec, self.horizon, self.separation_margin_m)
        if self._reusable(obs, hold):
            return self._reuse(obs)
        # A close lower robot relies on this one's plan or braking path: no solve, unless that
        # runs into a robot standing still (held too, it may not give way) or off the floor.
        if hold and not brake_runs_into(obs, spec, self.horizon, self.context.floor):
            self._last = None
            return brake(obs, spec, self.horizon, ControlStatus.OK, self.context.floor)
        # A state met again in this trip: a cycle of reused plans; solve every tick from now.
        self._reused = self.reuse_ticks if self._repeats.solved_from(obs, self._trip) else 0
        obs = into_regions(obs, self.context.floor, self._trip)  # a hair outside: at the edge
        data, warm = self._step_data(obs)
        solution, separation = self._solve(obs, data, warm)
        if solution.outcome is SolverOutcome.INFEASIBLE:
            # The corridor assumed the plan keeps pace with the reference; open it back to the
            # robot's own progress and try once more before falling back.
            first = solution.solver_s
            data, warm = self._step_data(obs, wide=True)
            solution, separation = self._solve(obs, data, warm)
            solution.solver_s += first
        if self.cost == "quadratic" and solution.outcome.usable:
            solution = self._refine(solution, data, separation)
        report = SolveReport(solution.outcome, solution.solver_s, time.perf_counter() - started)
        if solution.outcome.usable:
            assert solution.p is not None and solution.u is not None
            self._last, self._last_t, self._last_model = solution, obs.t, self._model
            if stays_put(obs, solution.p, goal, spec.radius, self._trip.reference.positions[0]):
                self._model = None  # a trap nothing else ends: a new trip from here
            cmd = self._go.command(obs, spec, solution.p, solution.u[0], report)  # (`start`)
            self._repeats.waited(obs, cmd.ax, cmd.ay, spec.period)  # standing: no cycle
            return cmd
        return self._fallback(obs, report)

    def _reusable(self, obs: Observation, hold: bool = False) -> bool:
        """Whether the previous plan, one step on, may be followed instead of a solve (with
        `hold`, as many ticks as it keeps clear: `neighbours.must_hold`)."""
        last = self._last
        if self._reused >= self.reuse_ticks and not hold:
            return False
        if last is None or self._last_model is not self._model:
            return False
        if not self._on_plan(obs):
            return False
        assert last.p is not None and last.v is not None
        spec = self.context.spec
        if not within_caps(obs, spec, np.vstack([last.v[1:], np.zeros((1, 2))])):
            return False
        if not obs.neighbours or not self.avoid_robots:
            return True
        # Held, it may only brake next tick: its brake must keep clear too.
        return reusable_among(obs, spec, last, self.separation_margin_m, hold)

    def _reuse(self, obs: Observation) -> Command:
        """Follow the previous plan one step on (no solve, no `SolveReport`)."""
        assert self._last is not None and self._trip is not None
        self._last, self._last_t = shifted(self._last), obs.t
        # Keep the progress along the reference current, as a solve's step data does (its
        # search looks only `PROGRESS_WINDOW` samples ahead of the last one).
        here = np.array([obs.x, obs.y])
        self._progress = self._trip.progress_in_sight(here, self._progress, PROGRESS_WINDOW)[0]
        self._reused += 1
        self.reuses += 1
        last = self._last
        assert last.p is not None and last.u is not None
        self._go.shown(obs.t, last.p)
        plan = plan_points(obs.t, last.p, self.context.spec.period)
        return Command(float(last.u[0, 0]), float(last.u[0, 1]), ControlStatus.OK, plan)

    def _refine(self, milp: Solution, data: StepData, separation: Separation | None) -> Solution:
        """The paper's quadratic cost for the MILP's regions; the MILP's plan if that fails."""
        spec = self.context.spec
        if self._qp_highs is None:
            self._qp_highs = new_highs()  # its own object: each refinement replaces its model
        assert self._trip is not None
        solution, optimal = refine_milp(
            milp,
            self._trip,
            data,
            separation,
            N=self.horizon,
            dt=spec.period,
            a_max=spec.a_max,
            v_robot=spec.v_max,
            weights=self.weights,
            time_limit_s=self.time_limit_s,
            highs=self._qp_highs,
        )
        if not optimal:
            self.qp_failures += 1
        return solution

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
            self.max_nodes,
        )
        self._goal, self._failed, self._progress = goal, None, 0
        self.trips += 1
        return True

    def _step_data(
        self, obs: Observation, wide: bool = False
    ) -> tuple[StepData, np.ndarray | None]:
        """Bounds, corridor and reference window for this tick (and a warm start, if any).

        `wide` opens every step's corridor back to the robot's own progress (`horizon`).
        """
        trip, model = self._trip, self._model
        assert trip is not None and model is not None
        # The last plan's regions are positions in its own trip's S: only reuse them there.
        on_plan = self._on_plan(obs) and self._last_model is model
        data, self._progress = step_data(
            obs,
            self.context.spec,
            trip,
            horizon=self.horizon,
            corridor=self.corridor,
            corridor_steps=self.corridor_steps,
            progress=self._progress,
            last=self._last if on_plan else None,
            wide=wide,
        )
        self.binaries.append(int(data.z_ub.sum()))
        warm = None
        if self.warm_start and on_plan:
            assert self._last is not None
            warm = model.shifted_columns(self._last, data)
        return data, warm

    # -- other robots ---------------------------------------------------------------------------
    def _solve(
        self, obs: Observation, data: StepData, warm: np.ndarray | None
    ) -> tuple[Solution, Separation | None]:
        """This tick's MILP kept clear of the robots that need it (`neighbours.robots_to_avoid`):
        the nearest `max_neighbours`, and any other the plan runs into (`crowd.solve_clear`)."""
        assert self._model is not None and self._trip is not None
        spec = self.context.spec
        nearest: list[Obstacle] = []
        p_lo = p_hi = None
        if self.avoid_robots and obs.neighbours and self.max_neighbours > 0:
            p_lo, p_hi = region_bounds(self._trip, self.horizon, data)
            nearest = robots_to_avoid(
                obs,
                spec,
                self.horizon,
                p_lo,
                p_hi,
                margin=self.separation_margin_m,
                respect_priority=self.respect_priority,
            )
        groups = spans(self.horizon, spec.period)
        solution, separation, chosen = solve_clear(
            self._model, data, warm, nearest, self.max_neighbours, p_lo, p_hi, groups
        )
        self.separation_binaries.append(0 if separation is None else separation.binaries)
        self.separation_robots.append(tuple(ob.robot for ob in chosen))
        return solution, separation

    def _on_plan(self, obs: Observation) -> bool:
        """Whether the robot is where the last usable plan said (`reuse.on_plan`)."""
        return on_plan(obs, self._last, self._last_t, self.context.spec.period)

    # -- fallbacks ------------------------------------------------------------------------------
    def _fallback(self, obs: Observation, report: SolveReport) -> Command:
        """The shifted previous plan or braking (`recover.fall_back`); then a new trip."""
        ctx, here, self._model = self.context, self._on_plan(obs), None  # (a new trip next tick)
        command, self._last = fall_back(
            obs, ctx.spec, self.horizon, ctx.floor, self._last, here, self.avoid_robots, report
        )
        self._last_t = obs.t if self._last is not None else self._last_t
        return command

    def _stop(self, obs: Observation, status: ControlStatus) -> Command:
        """Brake, or follow the previous plan where braking leaves the floor (`recover.stop`)."""
        ctx, here, avoid, last = self.context, self._on_plan(obs), self.avoid_robots, self._last
        cmd, self._last = stop(obs, ctx.spec, self.horizon, ctx.floor, last, here, status, avoid)
        self._last_t = obs.t if self._last is not None else self._last_t
        return cmd
