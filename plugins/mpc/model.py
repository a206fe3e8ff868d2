"""The trip's mixed-integer MPC: the Pyomo formulation, and how each step reaches HiGHS.

The formulation, for horizon steps k = 0..N with step dt:

- double integrator ``p[k+1] = p[k] + dt v[k]``, ``v[k+1] = v[k] + dt u[k]``, ``|u| <= a_max``;
  p[0], v[0] fixed to the measured state (their bounds);
- for each step k = 1..N-1 one binary z[k, j] per region j of the trip's set S (sum 1):
  ``z = 1 => A_j p[k] <= b_j, A_j p[k+1] <= b_j, |v[k]| <= v_max_j`` (the whole step in one
  convex region, so the segment is free and within the region's limit), written with Big-M
  rows whose M is tight per row over the trip box; plus the midpoint cut on faces next to a
  slower region; step 0 is already fixed by the measured state;
- print caps and the robot's limit as bounds on v[k]; ``v[N] = 0`` (the plan ends at rest, so
  the shifted plan is always a feasible fallback);
- cost: the 1-norm tracking of the reference (position and velocity, weights Q) plus input
  effort (weight R), via epigraph variables: a MILP that HiGHS solves.

Per step only bounds change: p, v (measured state, caps, reachable boxes), z (corridor: a 0
upper bound switches a region off for a step) and the right-hand sides of the tracking rows
(the reference). Rows keeping clear of other robots (`separation`) change in number every
step; they are added for one solve only. Two ways to a solve (`Interface`):

- "direct" (default): no Pyomo model; each step's MILP is written as arrays (`bounded`) with
  only the binaries the corridor leaves open and the rows the step's reachable box can break,
  M tight over that box: the same feasible set, a model whose size does not grow with the trip,
  and no model to build per trip (Pyomo took 0.25-0.4 s per trip at 40 robots);
- "pyomo": the trip's Pyomo model above, built once per trip in Pyomo's persistent interface
  (mutable Params, ``update_parameters``): the reference path, and the check that both agree.

Every direct solve runs in a new HiGHS object, so that its result depends on its inputs only. A
reused object completes a MIP start against its lifetime clock: once a trip's solves have added
up to ``time_limit_s``, HiGHS silently drops starts it has to complete, and when that happens
depends on the wall clock (two runs of the same fleet diverged there; docs/mpc.md,
"Reproducible solves").
"""

from __future__ import annotations

import enum
import logging
import time
from dataclasses import dataclass

import highspy
import numpy as np
import pyomo.environ as pyo
from pyomo.contrib.solver.solvers.highs import Highs as PersistentHighs

from fleet.highs import SolverError, configure, new_highs, solve, solver_log
from fleet.plugins import SolverOutcome, gate_released
from fleet_plugins.mpc.bounded import Layout, StepMILP, TripFaces, build_step
from fleet_plugins.mpc.separation import SLACK_COST, Separation
from fleet_plugins.mpc.trip import MIDPOINT_MARGIN, Trip

__all__ = [
    "Interface",
    "TripModel",
    "StepData",
    "Solution",
    "HIGHS_OPTIONS",
    "DEFAULT_MAX_NODES",
    "run_outcome",
]

log = logging.getLogger("fleet.mpc")

#: HiGHS options for these small MILPs (measured in docs/mpc-study.md): the sub-MIP
#: heuristics and restarts cost up to a second on a 300-row MILP and never pay off here;
#: the tight feasibility tolerance keeps Big-M leakage (M * 1e-6) far below the checker's 1e-6 m.
#: Light presolve (``presolve_mode`` 2): the bounded step MILPs (`bounded`) leave it little to
#: do, and the full one cost a third of the hardest solves' time on case study 3 (p95 CPU 36 ->
#: 22 ms, the same optimal costs; docs/performance.md).
HIGHS_OPTIONS: dict[str, object] = {
    "presolve_mode": 2,
    "mip_heuristic_run_rins": False,
    "mip_heuristic_run_rens": False,
    "mip_heuristic_run_root_reduced_cost": False,
    "mip_heuristic_run_feasibility_jump": False,
    "mip_allow_restart": False,
    "mip_feasibility_tolerance": 1e-9,
}

#: Branch-and-bound nodes per solve by default (HiGHS ``mip_max_nodes``, the controller's
#: ``max_nodes``): the deterministic stopping rule, above what normal solves need (of some
#: 19,000 solves measured on case 3 and the 20- and 40-robot fleet, p99.9 25 nodes, the most
#: 101; docs/mpc.md, "Deterministic stopping"), so they are untouched.
DEFAULT_MAX_NODES = 200


class Interface(enum.Enum):
    """How per-step data reaches HiGHS."""

    DIRECT = "direct"
    """Each step's bounded MILP written straight into HiGHS as arrays (`bounded`; fast)."""
    PYOMO = "pyomo"
    """The trip's Pyomo model: mutable Params and the persistent interface's own update (the
    reference path)."""


@dataclass
class StepData:
    """Everything that changes from one control step to the next (numpy arrays)."""

    p_lo: np.ndarray  # (N+1, 2)
    p_hi: np.ndarray
    v_lo: np.ndarray  # (N+1, 2)
    v_hi: np.ndarray
    z_ub: np.ndarray  # (N-1, |S|) 0/1, rows = steps 1..N-1
    p_ref: np.ndarray  # (N+1, 2)
    v_ref: np.ndarray  # (N+1, 2)


@dataclass
class Solution:
    """One solve: outcome, times and (when usable) the plan."""

    outcome: SolverOutcome
    solver_s: float
    p: np.ndarray | None = None  # (N+1, 2)
    v: np.ndarray | None = None
    u: np.ndarray | None = None  # (N, 2)
    regions: np.ndarray | None = None  # (N-1,) position in S used at steps 1..N-1
    columns: np.ndarray | None = None  # the raw column values (for warm starts)
    #: The separation columns' values (binaries, then slacks) when the solve had any.
    separation: np.ndarray | None = None
    #: Branch-and-bound nodes HiGHS explored (0: the MIP start or the root settled it).
    nodes: int = 0
    #: The plan's cost (the model's objective), when usable: the comparable figure of two
    #: solves, whose plans may differ where the cost has several optima.
    objective: float | None = None


class TripModel:
    """One trip's MPC: per step, the bounded MILP (direct interface), or the trip's Pyomo
    model and its persistent HiGHS instance (pyomo interface).

    Parameters
    ----------
    trip:
        The trip's regions and faces.
    horizon:
        N, the number of steps.
    dt, a_max, v_robot:
        Step (s), per-axis input bound (m/s^2), the robot's per-axis speed limit (m/s).
    weights:
        ``(q_position, q_velocity, r_input)`` of the 1-norm cost.
    interface:
        How per-step data reaches HiGHS.
    time_limit_s:
        Wall-clock guard per solve (a last resort: its hit is `SolverOutcome.TIME_LIMIT`).
    max_nodes:
        Branch-and-bound nodes per solve (HiGHS ``mip_max_nodes``): the deterministic
        stopping rule; a solve stopped by it is ``FEASIBLE`` (its incumbent) or
        ``NO_SOLUTION``.
    """

    def __init__(
        self,
        trip: Trip,
        horizon: int,
        dt: float,
        a_max: float,
        v_robot: float,
        weights: tuple[float, float, float],
        interface: Interface,
        time_limit_s: float,
        max_nodes: int = DEFAULT_MAX_NODES,
    ) -> None:
        self.trip = trip
        self.N = horizon
        self.interface = interface
        self.time_limit_s = time_limit_s
        self.max_nodes = max_nodes
        self._dims = (dt, a_max, weights)
        if interface is Interface.DIRECT:
            # Each solve builds its own bounded MILP (`bounded`): no Pyomo model at all.
            self._faces = TripFaces.of(trip)
            self._index_layout(Layout(horizon, len(trip.regions)))
            return
        self.model = _build(trip, horizon, dt, a_max, v_robot, weights)
        self.solver = PersistentHighs()
        self.solver.config.timer = None
        self.solver.set_instance(self.model)
        #: The persistent interface's HiGHS object (solved in only by the "pyomo" interface).
        self.highs: highspy.Highs = self.solver._solver_model
        configure(self.highs, self._options())
        self._index()
        cfg = self.solver.config.auto_updates
        # Only Params change between solves; skip the structural scans.
        for name in (
            "check_for_new_or_removed_constraints",
            "check_for_new_or_removed_vars",
            "check_for_new_or_removed_params",
            "check_for_new_objective",
            "update_constraints",
            "update_vars",
            "update_named_expressions",
            "update_objective",
        ):
            setattr(cfg, name, False)
        cfg.update_parameters = True

    @property
    def dt(self) -> float:
        """The control period (s) the model was built for."""
        return self._dims[0]

    @property
    def a_max(self) -> float:
        """The robot's acceleration bound per axis (m/s^2) the model was built for."""
        return self._dims[1]

    def _options(self) -> dict[str, object]:
        return dict(
            HIGHS_OPTIONS, time_limit=float(self.time_limit_s), mip_max_nodes=int(self.max_nodes)
        )

    @property
    def binaries(self) -> int:
        """Columns z of the whole trip model (most are switched off per step)."""
        return len(self._z_cols)

    # -- index maps ----------------------------------------------------------------------------
    def _index_layout(self, layout: Layout) -> None:
        """Column positions of the direct interface: the full layout of `bounded`."""
        self._p_cols, self._v_cols, self._u_cols = layout.p, layout.v, layout.u
        self._z_cols = layout.z
        self._ep_cols, self._ev_cols, self._eu_cols = layout.ep, layout.ev, layout.eu
        self._n_cols = layout.columns

    def _index(self) -> None:
        """Column and row positions the persistent interface assigned."""
        m = self.model
        var_map = self.solver._pyomo_var_to_solver_var_map
        con_map = self.solver._pyomo_con_to_solver_con_map
        N, S = self.N, len(self.trip.regions)

        def cols(var, keys) -> np.ndarray:
            return np.array([var_map[id(var[key])] for key in keys], dtype=np.int32)

        pk = [(k, a) for k in range(N + 1) for a in (0, 1)]
        self._p_cols = cols(m.p, pk)
        self._v_cols = cols(m.v, pk)
        self._u_cols = cols(m.u, [(k, a) for k in range(N) for a in (0, 1)])
        self._z_keys = [(k, j) for k in range(1, N) for j in range(S)]
        self._z_cols = cols(m.z, self._z_keys)
        self._ep_cols = cols(m.ep, [(k, a) for k in range(1, N + 1) for a in (0, 1)])
        self._ev_cols = cols(m.ev, [(k, a) for k in range(1, N + 1) for a in (0, 1)])
        self._eu_cols = cols(m.eu, [(k, a) for k in range(N) for a in (0, 1)])
        ka = [(k, a) for k in range(1, N + 1) for a in (0, 1)]
        self._rows_p_up = np.array([con_map[m.track_p_up[key]] for key in ka], dtype=np.int32)
        self._rows_p_dn = np.array([con_map[m.track_p_dn[key]] for key in ka], dtype=np.int32)
        self._rows_v_up = np.array([con_map[m.track_v_up[key]] for key in ka], dtype=np.int32)
        self._rows_v_dn = np.array([con_map[m.track_v_dn[key]] for key in ka], dtype=np.int32)
        self._n_cols = self.highs.getNumCol()

    # -- per step -------------------------------------------------------------------------------
    def solve(
        self,
        data: StepData,
        warm: np.ndarray | None = None,
        separation: Separation | None = None,
    ) -> Solution:
        """Push `data` into the model, solve, and read the plan.

        `separation` (rows keeping clear of other robots, `separation.build_separation`) is
        added for this solve only, in both interfaces (it is not part of the Pyomo model: its
        size changes every step). A separation no plan can meet is reported `INFEASIBLE`
        without asking HiGHS.

        The direct interface solves in a new HiGHS object (see the module); the "pyomo"
        interface in the persistent one, with its previous solution cleared first (else
        HiGHS starts from it, as long as the lifetime clock allows, see the module).
        """
        if separation is not None and separation.infeasible:
            return Solution(SolverOutcome.INFEASIBLE, 0.0)
        extra = separation is not None and separation.groups > 0
        if self.interface is Interface.DIRECT:
            dt, a_max, weights = self._dims
            milp = build_step(
                self.trip, self._faces, self.N, dt, a_max, weights,
                data.p_lo, data.p_hi, data.v_lo, data.v_hi, data.z_ub, data.p_ref, data.v_ref,
            )  # fmt: skip
            h = new_highs(self._options())
            milp.pass_to(h)
            if warm is not None:
                warm = milp.reduce(warm)
            if extra:
                assert separation is not None
                self._append(h, separation)
                if warm is not None:
                    p = warm[self._p_cols].reshape(self.N + 1, 2)
                    warm = np.concatenate([warm, separation.start(p)])
            if warm is not None:
                _warm_start(h, warm)
            t0 = time.perf_counter()
            outcome = run_outcome(h, "MPC step")
            return self._read(h, outcome, time.perf_counter() - t0, milp)
        h = self.highs
        h.clearSolver()
        added = self._append(h, separation) if extra and separation is not None else None
        try:
            self._write_params(data)
            before = h.getRunTime()
            opts = self.solver.config
            opts.load_solutions = False
            opts.raise_exception_on_nonoptimal_result = False
            opts.time_limit = self.time_limit_s
            opts.solver_options = {k: v for k, v in self._options().items() if k != "time_limit"}
            solver_log(h).clear()
            self.solver.solve(self.model)
            outcome = outcome_of(h, h.getModelStatus(), "MPC step (pyomo)")
            return self._read(h, outcome, h.getRunTime() - before)
        finally:
            if added is not None:
                _remove(h, *added)

    def _append(self, h: highspy.Highs, sep: Separation) -> tuple[int, int, int, int]:
        """Add `sep`'s binaries, slacks and rows after the model's own columns and rows in
        `h`; returns where they went (first column, columns, first row, rows)."""
        n_bin, n_grp = sep.binaries, sep.groups
        base = h.getNumCol()
        n_new = n_bin + n_grp
        costs = np.concatenate([np.zeros(n_bin), np.full(n_grp, SLACK_COST)])
        empty_i = np.zeros(0, dtype=np.int32)
        h.addCols(
            n_new,
            costs,
            np.zeros(n_new),
            np.concatenate([np.ones(n_bin), sep.group_slack]),
            0,
            np.zeros(n_new, dtype=np.int32),
            empty_i,
            np.zeros(0),
        )
        binaries = np.arange(base, base + n_bin, dtype=np.int32)
        h.changeColsIntegrality(
            n_bin, binaries, np.full(n_bin, int(highspy.HighsVarType.kInteger), dtype=np.uint8)
        )
        # Side rows: s p[e, axis] - M b + slack >= s c + d - M (three entries each; four on a
        # row across the line between two robots, n . p[e] - M b + slack >= ...).
        n_side = len(sep.row_lo)
        p_col = self._p_cols[sep.row_point]
        b_col = binaries[sep.row_binary]
        slack_col = base + n_bin + sep.binary_group[sep.row_binary]
        two = sep.row_point2 >= 0
        p2_col = self._p_cols[np.where(two, sep.row_point2, 0)]
        entries = np.column_stack([p_col, b_col, slack_col, p2_col]).astype(np.int32)
        values = np.column_stack([sep.row_coef, -sep.row_big_m, np.ones(n_side), sep.row_coef2])
        used = np.column_stack([np.ones((n_side, 3), dtype=bool), two])
        side_idx, side_val = entries[used], values[used]  # (row-major: row by row)
        side_starts = np.concatenate([[0], np.cumsum(3 + two)])[:n_side]
        # Group rows: one of the group's sides holds.
        order = np.argsort(sep.binary_group, kind="stable")
        sizes = np.bincount(sep.binary_group, minlength=n_grp)
        group_idx = binaries[order]
        starts = np.concatenate(
            [side_starts, len(side_idx) + np.concatenate([[0], np.cumsum(sizes)[:-1]])]
        ).astype(np.int32)
        index = np.concatenate([side_idx, group_idx]).astype(np.int32)
        value = np.concatenate([side_val, np.ones(n_bin)])
        lower = np.concatenate([sep.row_lo, np.ones(n_grp)])
        n_rows = n_side + n_grp
        h.addRows(
            n_rows, lower, np.full(n_rows, highspy.kHighsInf), len(index), starts, index, value
        )
        return base, n_new, h.getNumRow() - n_rows, n_rows

    def _write_params(self, d: StepData) -> None:
        m = self.model
        N, S = self.N, len(self.trip.regions)
        for k in range(N + 1):
            for a in (0, 1):
                m.p_lo[k, a] = float(d.p_lo[k, a])
                m.p_hi[k, a] = float(d.p_hi[k, a])
                m.v_lo[k, a] = float(d.v_lo[k, a])
                m.v_hi[k, a] = float(d.v_hi[k, a])
                m.p_ref[k, a] = float(d.p_ref[k, a])
                m.v_ref[k, a] = float(d.v_ref[k, a])
        for k in range(1, N):
            for j in range(S):
                m.z_ub[k, j] = float(d.z_ub[k - 1, j])

    def _read(
        self,
        h: highspy.Highs,
        outcome: SolverOutcome,
        solver_s: float,
        milp: StepMILP | None = None,
    ) -> Solution:
        """The plan in `h` (`milp`: the bounded MILP it holds, else the trip model)."""
        nodes = int(h.getInfo().mip_node_count)
        if not outcome.usable:
            return Solution(outcome, solver_s, nodes=nodes)
        raw = np.asarray(h.getSolution().col_value)
        own = milp.columns if milp is not None else self._n_cols
        col = milp.expand(raw) if milp is not None else raw[:own]
        N = self.N
        z = col[self._z_cols].reshape(N - 1, len(self.trip.regions))
        return Solution(
            outcome,
            solver_s,
            p=col[self._p_cols].reshape(N + 1, 2),
            v=col[self._v_cols].reshape(N + 1, 2),
            u=col[self._u_cols].reshape(N, 2),
            regions=np.argmax(z, axis=1),
            columns=col,
            separation=raw[own:].copy() if len(raw) > own else None,
            nodes=nodes,
            objective=float(h.getInfo().objective_function_value),
        )

    def shifted_columns(self, sol: Solution, data: StepData) -> np.ndarray:
        """The previous solution moved one step on (plus rest at its end) as a MIP start."""
        assert sol.p is not None and sol.v is not None and sol.u is not None
        assert sol.regions is not None
        N, S = self.N, len(self.trip.regions)
        p = np.vstack([sol.p[1:], sol.p[-1:]])
        v = np.vstack([sol.v[1:], np.zeros((1, 2))])
        u = np.vstack([sol.u[1:], np.zeros((1, 2))])
        regions = np.concatenate([sol.regions[1:], sol.regions[-1:]])
        z = np.zeros((N - 1, S))
        z[np.arange(N - 1), regions] = 1.0
        col = np.zeros(self._n_cols)
        col[self._p_cols] = p.ravel()
        col[self._v_cols] = v.ravel()
        col[self._u_cols] = u.ravel()
        col[self._z_cols] = z.ravel()
        col[self._ep_cols] = np.abs(p[1:] - data.p_ref[1:]).ravel()
        col[self._ev_cols] = np.abs(v[1:] - data.v_ref[1:]).ravel()
        col[self._eu_cols] = np.abs(u).ravel()
        return col


def run_outcome(h: highspy.Highs, what: str) -> SolverOutcome:
    """Run `h`, the controller's own object, and map how it ended to a `SolverOutcome`.

    A failed run is ``ERROR``, logged with HiGHS's own message (`fleet.highs.solve`); every
    other status that is not optimal is logged at info level by `outcome_of`. On an agent host
    with threads the run lets go of the gate (`fleet.plugins.gate`): `h` is no one else's, and
    HiGHS keeps a scheduler per calling thread, so other robots' steps go on meanwhile.
    """
    try:
        with gate_released():
            result = solve(h, what)
    except SolverError:
        return SolverOutcome.ERROR
    return outcome_of(h, result.status, what)


def outcome_of(h: highspy.Highs, status: highspy.HighsModelStatus, what: str) -> SolverOutcome:
    """The `SolverOutcome` of a run of `h` that ended with model `status`.

    "Unbounded or infeasible" (a presolve verdict) counts as infeasible: every plan's feasible
    set is bounded, since each of its points lies in a region. A work limit (nodes, iterations)
    ends with the incumbent, if any (``FEASIBLE``, else ``NO_SOLUTION``): where it stops depends
    on the inputs only. The wall-clock limit is ``TIME_LIMIT``, logged as a warning: where it
    stops depends on the machine's speed, so its incumbent is not used.
    """
    S = highspy.HighsModelStatus
    if status == S.kOptimal:
        return SolverOutcome.OPTIMAL
    message = h.modelStatusToString(status)
    if status in (S.kInfeasible, S.kUnboundedOrInfeasible):
        log.info("%s: HiGHS: %s", what, message)
        return SolverOutcome.INFEASIBLE
    if status == S.kTimeLimit:
        log.warning(
            "%s: HiGHS: %s (the wall-clock guard, time_limit_s): where it stopped depends on "
            "the machine's speed, so determinism may be lost (the run may not be reproducible); "
            "its incumbent is not used",
            what,
            message,
        )
        return SolverOutcome.TIME_LIMIT
    if status in (S.kIterationLimit, S.kSolutionLimit, S.kInterrupt):
        log.info("%s: HiGHS: %s", what, message)
        has_solution = h.getInfo().primal_solution_status == 2  # kSolutionStatusFeasible
        return SolverOutcome.FEASIBLE if has_solution else SolverOutcome.NO_SOLUTION
    log.warning("%s: HiGHS: %s: %s", what, message, solver_log(h).problems())
    return SolverOutcome.ERROR


def _warm_start(h: highspy.Highs, columns: np.ndarray) -> None:
    sol = highspy.HighsSolution()
    sol.col_value = columns.tolist()
    sol.value_valid = True
    h.setSolution(sol)


def _remove(h: highspy.Highs, first_col: int, n_cols: int, first_row: int, n_rows: int) -> None:
    """Take a solve's separation columns and rows out of `h` again."""
    h.deleteRows(n_rows, np.arange(first_row, first_row + n_rows, dtype=np.int32))
    h.deleteCols(n_cols, np.arange(first_col, first_col + n_cols, dtype=np.int32))


def _build(
    trip: Trip,
    N: int,
    dt: float,
    a_max: float,
    v_robot: float,
    weights: tuple[float, float, float],
) -> pyo.ConcreteModel:
    """The trip's Pyomo model: variables, Big-M region rows, tracking epigraph, cost."""
    m = pyo.ConcreteModel(name="mambot_mpc")
    S = len(trip.regions)
    m.K = pyo.RangeSet(0, N)
    m.U = pyo.RangeSet(0, N - 1)
    m.KS = pyo.RangeSet(1, N - 1)  # steps with a region choice
    m.KE = pyo.RangeSet(1, N)  # states in the cost
    m.AX = pyo.Set(initialize=[0, 1])
    m.S = pyo.RangeSet(0, S - 1)
    mutable = {"mutable": True, "initialize": 0.0}
    m.p_lo = pyo.Param(m.K, m.AX, **mutable)
    m.p_hi = pyo.Param(m.K, m.AX, **mutable)
    m.v_lo = pyo.Param(m.K, m.AX, **mutable)
    m.v_hi = pyo.Param(m.K, m.AX, **mutable)
    m.p_ref = pyo.Param(m.K, m.AX, **mutable)
    m.v_ref = pyo.Param(m.K, m.AX, **mutable)
    m.z_ub = pyo.Param(m.KS, m.S, mutable=True, initialize=1.0)

    m.p = pyo.Var(m.K, m.AX, bounds=lambda m, k, a: (m.p_lo[k, a], m.p_hi[k, a]))
    m.v = pyo.Var(m.K, m.AX, bounds=lambda m, k, a: (m.v_lo[k, a], m.v_hi[k, a]))
    m.u = pyo.Var(m.U, m.AX, bounds=(-a_max, a_max))
    m.z = pyo.Var(m.KS, m.S, domain=pyo.Binary, bounds=lambda m, k, j: (0, m.z_ub[k, j]))
    m.ep = pyo.Var(m.KE, m.AX, domain=pyo.NonNegativeReals)
    m.ev = pyo.Var(m.KE, m.AX, domain=pyo.NonNegativeReals)
    m.eu = pyo.Var(m.U, m.AX, domain=pyo.NonNegativeReals)

    m.move = pyo.Constraint(
        m.U, m.AX, rule=lambda m, k, a: m.p[k + 1, a] == m.p[k, a] + dt * m.v[k, a]
    )
    m.accelerate = pyo.Constraint(
        m.U, m.AX, rule=lambda m, k, a: m.v[k + 1, a] == m.v[k, a] + dt * m.u[k, a]
    )
    m.one_region = pyo.Constraint(m.KS, rule=lambda m, k: sum(m.z[k, j] for j in m.S) == 1)

    # Big-M rows: a . p + M z <= b + M (z = 1: a . p <= b; z = 0: implied by the trip box).
    faces = list(enumerate(trip.faces))
    m.F = pyo.Set(initialize=[n for n, f in faces if f.big_m > 1e-9])

    def face_rule(m, k, n, end):
        f = trip.faces[n]
        p = (m.p[k + end, 0], m.p[k + end, 1])
        return f.a[0] * p[0] + f.a[1] * p[1] + f.big_m * m.z[k, f.region] <= f.b + f.big_m

    m.inside = pyo.Constraint(m.KS, m.F, [0, 1], rule=face_rule)
    cut_faces = [n for n, f in faces if f.slower_side]
    m.FC = pyo.Set(initialize=cut_faces)

    def midpoint_rule(m, k, n):
        f = trip.faces[n]
        # The step's midpoint MIDPOINT_MARGIN inside the face: M over the box for p + q.
        big = 2.0 * (max(f.big_m, 0.0) + MIDPOINT_MARGIN)
        s = sum(f.a[a] * (m.p[k, a] + m.p[k + 1, a]) for a in (0, 1))
        return s + big * m.z[k, f.region] <= 2.0 * (f.b - MIDPOINT_MARGIN) + big

    m.midpoint = pyo.Constraint(m.KS, m.FC, rule=midpoint_rule)

    # Region speed limits: |v[k]| <= v_j + (v_robot - v_j)(1 - z), only where v_j < v_robot.
    slow = [(j, a) for j in range(S) for a in (0, 1) if trip.v_max[j, a] < v_robot - 1e-12]
    m.SV = pyo.Set(initialize=slow, dimen=2)

    def speed_rule(m, k, j, a, sign):
        gap = v_robot - float(trip.v_max[j, a])
        return sign * m.v[k, a] + gap * m.z[k, j] <= v_robot

    m.zone_speed = pyo.Constraint(m.KS, m.SV, [1, -1], rule=speed_rule)

    # 1-norm tracking epigraph; the reference sits in the rows' right-hand sides.
    m.track_p_up = pyo.Constraint(
        m.KE, m.AX, rule=lambda m, k, a: m.p[k, a] - m.ep[k, a] <= m.p_ref[k, a]
    )
    m.track_p_dn = pyo.Constraint(
        m.KE, m.AX, rule=lambda m, k, a: -m.p[k, a] - m.ep[k, a] <= -m.p_ref[k, a]
    )
    m.track_v_up = pyo.Constraint(
        m.KE, m.AX, rule=lambda m, k, a: m.v[k, a] - m.ev[k, a] <= m.v_ref[k, a]
    )
    m.track_v_dn = pyo.Constraint(
        m.KE, m.AX, rule=lambda m, k, a: -m.v[k, a] - m.ev[k, a] <= -m.v_ref[k, a]
    )
    m.effort_up = pyo.Constraint(m.U, m.AX, rule=lambda m, k, a: m.u[k, a] <= m.eu[k, a])
    m.effort_dn = pyo.Constraint(m.U, m.AX, rule=lambda m, k, a: -m.u[k, a] <= m.eu[k, a])
    qp, qv, r = weights
    m.cost = pyo.Objective(
        expr=qp * pyo.quicksum(m.ep[k, a] for k in m.KE for a in m.AX)
        + qv * pyo.quicksum(m.ev[k, a] for k in m.KE for a in m.AX)
        + r * pyo.quicksum(m.eu[k, a] for k in m.U for a in m.AX),
        sense=pyo.minimize,
    )
    return m
