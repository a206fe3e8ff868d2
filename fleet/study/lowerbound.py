"""Minimum-time lower bound of a trip: no robot that obeys the floor's rules can arrive sooner.

Offline yardstick for controllers (issue 3: "report arrival / lower bound"). The rules are the
ones the safety checker judges, on the paper's discrete double integrator
``p[k+1] = p[k] + dt*v[k]``, ``v[k+1] = v[k] + dt*u[k]``, ``|u| <= a_max`` per axis:

- step k moves on the segment ``p[k] -> p[k+1]``, which stays in the free space (the union of
  the floor's convex regions);
- ``|v[k]|`` per axis is at most the limit of every region the segment enters, the robot's
  ``v_max``, and the print cap active during ``[t_k, t_k + dt)``;
- the robot starts at rest at `start` at `t0` and arrives when it is at rest (v = 0) within
  `tolerance` of `goal` per axis.

The bound comes from a relaxation of these rules, solved as a time-indexed MILP with HiGHS: for
a number of steps T, binaries ``z[s, j]`` place each sample in one region j (Big-M on the
region's H-representation, each M tight over that sample's reach box), and each step's velocity
must respect the limit of the region its start sample and its end sample lie in. What happens
between samples (a segment cutting an obstacle's corner or a slow zone) is dropped, so every
real trajectory is a solution of the relaxation and the smallest feasible T is a lower bound.
Optionally (`interior_points`) points inside each step must lie in a region too, whose limit
binds the step: still valid, tighter against hopping over thin zones, much slower. Binaries are
pruned by reach: region j can hold sample k only if it meets the box reachable from the start
in k steps and from which the goal is reachable in T - k steps (per axis, `envelope`).

Why the endpoint rule is valid. The first stretch of a moving segment lies in some region whose
closure holds ``p[k]``, and the segment is bound by it; likewise its last stretch and
``p[k+1]``. When the regions' per-axis limits are totally ordered (every pair comparable, true
of isotropic limits) one binary per sample suffices: place ``p[k]`` in the faster of the region
the step before ends in and the region the step after starts in; both steps are then bound by
at least that region's limit. Otherwise each step gets its own start and end binaries (twice as
many), which is valid for any limits.

Search over T. A closed-form bound comes first: per axis, the 1-D double integrator with the
fastest limit anywhere on the floor, the robot's limit and the caps (`envelope`). Every
T below it is infeasible without a solve. From there T grows (1, 2, 4, ... steps at a time)
until a MILP is not proven infeasible, then bisection closes the gap; feasibility is monotone
in T because a robot at rest at the goal may stay there. A MILP that hits its time limit
counts as "not proven infeasible", so the bound is always (largest T proven infeasible) + 1.

Limits of the claim: the checker forgives rounding (a step dipping less than 1e-6 m into a
region is not bound by it); the relaxation allows 1e-6 m and 1e-6 m/s of slack, which covers
rounding on samples but not a step that runs within 1e-6 m inside a slow region's edge for a
long stretch before entering a faster region (the checker binds it by the faster one only).
HiGHS proves infeasibility up to its own tolerances (set to 1e-9).
"""

from __future__ import annotations

__all__ = ["LowerBound", "min_time_lower_bound", "envelope"]

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import highspy
import numpy as np
import shapely

from fleet.errors import NoPathError
from fleet.floor.compiled import Floor
from fleet.highs import new_highs, solve
from fleet.printing import CapSchedule

log = logging.getLogger("fleet.study.lowerbound")

#: Slack (m) on region membership: the safety checker forgives this much rounding.
POSITION_SLACK = 1e-6
#: Slack (m/s) on speed limits, as the checker's `SPEED_TOL`.
SPEED_SLACK = 1e-6


@dataclass(frozen=True)
class LowerBound:
    """A proven lower bound on the arrival time of one trip.

    Attributes
    ----------
    steps:
        Arrival step lower bound: no rule-abiding trajectory is at rest within the tolerance of
        the goal before sample ``steps`` (arrival time ``t0 + steps*dt``).
    seconds:
        ``steps * dt``.
    tight:
        Whether the relaxation has a solution with exactly `steps` steps (so no better bound is
        possible from this relaxation); False when that MILP timed out.
    solves:
        MILPs solved (T below the closed-form bound need none).
    solve_s:
        Total wall time (s) of those MILPs, building included.
    trajectory:
        ``(steps + 1, 4)`` array of ``[px, py, vx, vy]`` of the relaxation's solution when
        `tight`, else None. It obeys the dynamics and the endpoint rules, not necessarily the
        free-space rule between samples.
    """

    steps: int
    seconds: float
    tight: bool
    solves: int
    solve_s: float
    trajectory: np.ndarray | None


class _Outcome(Enum):
    """What one MILP over a fixed number of steps proved."""

    INFEASIBLE = "infeasible"
    """No trajectory of the relaxation arrives in this many steps: a proof."""
    FEASIBLE = "feasible"
    """The relaxation has a trajectory arriving in this many steps."""
    UNKNOWN = "unknown"
    """The time limit ran out (or HiGHS gave up) before either was shown."""


def envelope(T: int, limit: np.ndarray, a_max: float, dt: float) -> np.ndarray:
    """Largest speed each step of a T-step trip can have, on one axis.

    Parameters
    ----------
    T:
        Number of steps; the trip starts at rest at sample 0 and ends at rest at sample T.
    limit:
        ``(T,)`` speed limit of each step (robot, floor, cap; ``inf`` for none).
    a_max, dt:
        Acceleration bound and period.

    Returns
    -------
    numpy.ndarray
        ``(T + 1,)`` speeds ``w`` with ``w[0] = w[T] = 0``: the pointwise largest
        ``|v[k]|`` of any velocity sequence that meets the limits and changes by at most
        ``a_max*dt`` per step. The sequence ``w`` itself meets them, so ``dt * w[:T].sum()`` is
        the farthest the robot can travel along the axis in T steps.
    """
    dv = a_max * dt
    w = np.empty(T + 1)
    w[0] = 0.0
    for k in range(1, T):
        w[k] = min(limit[k], w[k - 1] + dv)
    w[T] = 0.0
    for k in range(T - 1, -1, -1):
        w[k] = min(w[k], w[k + 1] + dv)
    return w


def min_time_lower_bound(
    floor: Floor,
    start: Sequence[float],
    goal: Sequence[float],
    *,
    v_max: float,
    a_max: float,
    dt: float,
    caps: CapSchedule | None = None,
    t0: float = 0.0,
    tolerance: float = 0.05,
    time_limit_s: float = 60.0,
    interior_points: int = 0,
) -> LowerBound:
    """A valid lower bound on the arrival time of a trip from `start` to `goal` on `floor`.

    Parameters
    ----------
    floor:
        The compiled floor (free space = union of its regions, each with per-axis limits).
    start, goal:
        Points (x, y) in m; the robot is at rest at `start` at time `t0`.
    v_max:
        The robot's per-axis speed limit (m/s).
    a_max:
        Per-axis acceleration bound (m/s^2).
    dt:
        Period (s) of the double integrator.
    caps:
        Print caps on the simulation clock (per-axis, m/s), or None for none.
    t0:
        Time (s) of sample 0, which places the caps.
    tolerance:
        Per-axis distance (m) from the goal that counts as arrived.
    time_limit_s:
        Wall-time limit (s) of each MILP; one that runs out proves nothing, which can only
        make the bound weaker (`LowerBound.tight` is then False).
    interior_points:
        Points inside each step (evenly spaced) that must also lie in a region whose limit
        binds the step: a valid tightening against steps that hop over a thin slow zone or
        cut a corner, at a steep price in binaries (on case study 3, 1 point made each MILP 4-8x
        slower, 3 points 15-30x, and neither raised the bound).

    Returns
    -------
    LowerBound
        Every trajectory obeying the rules in the module docstring arrives no earlier than
        ``t0 + bound.seconds``.

    Raises
    ------
    ValueError
        If `start` or `goal` lies outside the free space, or a parameter is out of range.
    NoPathError
        If `start` and `goal` lie in different connected parts of the free space.
    fleet.highs.SolverError
        If HiGHS fails on a MILP (an option refused, a model error), with HiGHS's message: no
        bound is better than a silently weakened one.
    """
    for name, value in (("v_max", v_max), ("a_max", a_max), ("dt", dt)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} = {value!r}: must be a positive finite number")
    if not (math.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"tolerance = {tolerance!r}: must be a finite number >= 0 (metres)")
    if not time_limit_s > 0:
        raise ValueError(f"time_limit_s = {time_limit_s!r}: must be positive (seconds)")
    if not (isinstance(interior_points, int) and interior_points >= 0):
        raise ValueError(f"interior_points = {interior_points!r}: must be an integer >= 0")
    p0 = _point(floor, "start", start)
    pg = _point(floor, "goal", goal)
    # Some T is feasible when the free space joins start and goal, so the search below ends.
    parts = list(getattr(floor.free_space, "geoms", [floor.free_space]))
    near = [
        min(range(len(parts)), key=lambda i: parts[i].distance(shapely.points(*p)))
        for p in (p0, pg)
    ]
    if near[0] != near[1]:
        raise NoPathError(
            (float(p0[0]), float(p0[1])),
            (float(pg[0]), float(pg[1])),
            "they lie in different connected parts of the free space",
        )
    trip = _Trip(
        floor, p0, pg, v_max, a_max, dt, caps or CapSchedule(), t0, tolerance, interior_points
    )

    # Closed form: every T below `lo + 1` has an empty reach box somewhere.
    T = 0
    while trip.boxes(T) is None:
        T += 1
    lo = T - 1  # largest T known infeasible
    solves, solve_s = 0, 0.0
    found: dict[int, np.ndarray] = {}

    def attempt(T: int) -> _Outcome:
        nonlocal solves, solve_s
        tic = time.perf_counter()
        outcome, traj = trip.solve(T, time_limit_s)
        solve_s += time.perf_counter() - tic
        solves += 1
        if traj is not None:
            found[T] = traj
        return outcome

    # Grow T until a MILP is not proven infeasible ...
    jump = 1
    while attempt(T) is _Outcome.INFEASIBLE:
        lo = T
        T += jump
        jump *= 2
    # ... then bisect between the largest infeasible T and the first one that was not.
    hi = T
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if attempt(mid) is _Outcome.INFEASIBLE:
            lo = mid
        else:
            hi = mid
    steps = lo + 1
    traj = found.get(steps)
    return LowerBound(steps, steps * dt, traj is not None, solves, solve_s, traj)


def _point(floor: Floor, name: str, value: Sequence[float]) -> np.ndarray:
    p = np.asarray(value, dtype=float).reshape(-1)
    if p.shape != (2,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name} = {value!r}: must be a point (x, y) of two finite numbers")
    if floor.locate(float(p[0]), float(p[1])) is None:
        raise ValueError(
            f"{name} = ({p[0]:g}, {p[1]:g}) is outside the free space of floor {floor.name!r} "
            f"({floor.source}); {name} must lie in one of its regions"
        )
    return p


class _Trip:
    """One trip's data, and the relaxation's MILP for any number of steps."""

    def __init__(
        self,
        floor: Floor,
        start: np.ndarray,
        goal: np.ndarray,
        v_max: float,
        a_max: float,
        dt: float,
        caps: CapSchedule,
        t0: float,
        tolerance: float,
        interior: int = 0,
    ) -> None:
        self.floor = floor
        self.interior = interior
        self.start, self.goal = start, goal
        self.v_max, self.a_max, self.dt = v_max, a_max, dt
        self.caps, self.t0, self.tol = caps, t0, tolerance
        # Region limits clipped to the robot's: what a step in the region may really do.
        self.limits = np.minimum(np.array([r.v_max for r in floor.regions], dtype=float), v_max)
        self.ordered = _totally_ordered(self.limits)
        x0, y0, x1, y1 = shapely.total_bounds(np.array([r.polygon for r in floor.regions]))
        self.extent = np.array([[x0, y0], [x1, y1]]) + np.array([[-1.0], [1.0]]) * POSITION_SLACK
        self.A = [r.A for r in floor.regions]
        self.b = [r.b for r in floor.regions]

    def speed_limits(self, T: int) -> np.ndarray:
        """``(T, 2)`` per-axis limit of each step from the robot, the fastest region, the caps."""
        caps = self.caps.step_caps(self.t0, self.dt, T) if T else np.zeros(0)
        top = self.limits.max(axis=0)
        return np.minimum(np.minimum(top[None, :], caps[:, None]), self.v_max) + SPEED_SLACK

    def boxes(self, T: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Reach boxes ``(T+1, 2, 2)`` [k, lo/hi, axis] and speed bounds ``(T+1, 2)``.

        None when some box is empty, which proves that T steps cannot reach the goal.
        """
        limit = self.speed_limits(T)
        w = np.column_stack(
            [envelope(T, limit[:, a], self.a_max, self.dt) for a in (0, 1)]
        )  # (T+1, 2)
        reach = self.dt * np.vstack([np.zeros((1, 2)), np.cumsum(w[:-1], axis=0)])  # forward
        back = reach[-1][None, :] - reach  # travel still possible from sample k to rest
        lo = np.maximum.reduce(
            [
                self.start - reach,
                self.goal - self.tol - back,
                np.broadcast_to(self.extent[0], w.shape),
            ]
        )
        hi = np.minimum.reduce(
            [
                self.start + reach,
                self.goal + self.tol + back,
                np.broadcast_to(self.extent[1], w.shape),
            ]
        )
        if np.any(lo > hi + 1e-12):
            return None
        return np.stack([lo, np.maximum(lo, hi)], axis=1), w

    def solve(self, T: int, time_limit_s: float) -> tuple[_Outcome, np.ndarray | None]:
        """Whether the relaxation can arrive in exactly T steps (and a trajectory if so)."""
        got = self.boxes(T)
        if got is None:
            return _Outcome.INFEASIBLE, None
        box, w = got
        model = _Model()
        # Columns: p[k] at 2k, v[k] at 2(T+1) + 2k.
        P = 2 * (T + 1)
        lo = np.concatenate([box[:, 0, :].ravel(), -w.ravel()])
        hi = np.concatenate([box[:, 1, :].ravel(), w.ravel()])
        lo[0:2] = hi[0:2] = self.start
        model.cols(lo, hi)
        dv = self.a_max * self.dt
        for k in range(T):
            for a in (0, 1):
                p, pn, v, vn = 2 * k + a, 2 * (k + 1) + a, P + 2 * k + a, P + 2 * (k + 1) + a
                model.row(0.0, 0.0, [p, pn, v], [-1.0, 1.0, -self.dt])
                model.row(-dv, dv, [v, vn], [-1.0, 1.0])
        # Slots: (sample k, fraction f of step k, steps bound): the point p[k] + f*dt*v[k] lies
        # in the region chosen, and that region's limit binds the steps listed.
        if self.ordered:
            slots = [(k, 0.0, [k - 1, k] if k < T else [k - 1]) for k in range(1, T + 1)]
        else:
            slots = [(k, 0.0, [k]) for k in range(1, T)] + [(k + 1, 0.0, [k]) for k in range(T)]
        # Interior points of each moving step (both ends of the step are samples already).
        n = self.interior
        slots += [(k, i / (n + 1), [k]) for k in range(1, T) for i in range(1, n + 1)]
        for k, f, steps in slots:
            if f == 0.0:
                hull = box[k]
            else:
                # The point lies between p[k] and p[k+1]: in the hull of their boxes.
                hull = np.stack(
                    [np.minimum(box[k, 0], box[k + 1, 0]), np.maximum(box[k, 1], box[k + 1, 1])]
                )
            self._slot(model, hull, w, P, k, f, steps)
        outcome, x = model.solve(time_limit_s, f"lower bound MILP, {T} steps")
        if x is None:
            return outcome, None
        traj = np.column_stack([x[:P:2], x[1:P:2], x[P : 2 * P : 2], x[P + 1 : 2 * P : 2]])
        return outcome, traj

    def _slot(
        self,
        model: _Model,
        box: np.ndarray,
        w: np.ndarray,
        P: int,
        k: int,
        f: float,
        steps: list[int],
    ) -> None:
        """Binaries placing the point ``p[k] + f*dt*v[k]`` (inside `box`) in one region, its
        Big-M rows and the speed rows that region's limit puts on `steps`."""
        (x0, y0), (x1, y1) = box
        e = POSITION_SLACK
        where = shapely.box(x0, y0, x1, y1)
        cand = sorted(
            int(j)
            for j in self.floor.tree.query(where.buffer(e, join_style="mitre"))
            if self.floor.regions[int(j)].polygon.distance(where) <= e
        )
        if not cand:
            # No region meets the box: the point has nowhere to be.
            model.infeasible = True
            return
        z0 = model.binaries(len(cand))
        zs = list(range(z0, z0 + len(cand)))
        model.row(1.0, 1.0, zs, [1.0] * len(cand))
        px, py, vx, vy = 2 * k, 2 * k + 1, P + 2 * k, P + 2 * k + 1
        c = f * self.dt
        for z, j in zip(zs, cand, strict=True):
            A, b = self.A[j], self.b[j]
            # M: how far A q - b can exceed 0 anywhere in the box (a row with M <= 0 is idle).
            M = np.maximum(A[:, 0] * x0, A[:, 0] * x1) + np.maximum(A[:, 1] * y0, A[:, 1] * y1) - b
            for i in np.flatnonzero(e < M):
                ax, ay = float(A[i, 0]), float(A[i, 1])
                cols, vals = ([px, py, z], [ax, ay, float(M[i])])
                if c:
                    cols += [vx, vy]
                    vals += [c * ax, c * ay]
                model.row(-math.inf, float(b[i] + M[i] + e), cols, vals)
        for m in steps:
            for a in (0, 1):
                ub = w[m, a]
                caps = np.minimum(self.limits[cand, a] + SPEED_SLACK, ub)
                if np.all(caps >= ub):
                    continue
                v = P + 2 * m + a
                model.row(-math.inf, 0.0, [v, *zs], [1.0, *(-caps)])
                model.row(-math.inf, 0.0, [v, *zs], [-1.0, *(-caps)])


def _totally_ordered(limits: np.ndarray) -> bool:
    """Whether every pair of per-axis limits is comparable (one at most the other per axis)."""
    u = np.unique(limits, axis=0)
    le = np.all(u[:, None, :] <= u[None, :, :], axis=2)
    return bool(np.all(le | le.T))


class _Model:
    """A MILP in HiGHS's row-wise form, built with plain lists (fast enough offline)."""

    def __init__(self) -> None:
        self.lo: list[np.ndarray] = []
        self.hi: list[np.ndarray] = []
        self.n = 0
        self.integer: list[int] = []
        self.row_lo: list[float] = []
        self.row_hi: list[float] = []
        self.starts: list[int] = []
        self.index: list[int] = []
        self.value: list[float] = []
        self.infeasible = False

    def cols(self, lo: np.ndarray, hi: np.ndarray) -> int:
        self.lo.append(np.asarray(lo, dtype=float))
        self.hi.append(np.asarray(hi, dtype=float))
        first = self.n
        self.n += len(lo)
        return first

    def binaries(self, n: int) -> int:
        first = self.cols(np.zeros(n), np.ones(n))
        self.integer.extend(range(first, first + n))
        return first

    def row(self, lo: float, hi: float, index: Sequence[int], value: Sequence[float]) -> None:
        self.starts.append(len(self.index))
        self.row_lo.append(lo)
        self.row_hi.append(hi)
        self.index.extend(index)
        self.value.extend(value)

    def solve(self, time_limit_s: float, what: str) -> tuple[_Outcome, np.ndarray | None]:
        if self.infeasible:
            return _Outcome.INFEASIBLE, None
        inf = highspy.kHighsInf
        h = new_highs({**_OPTIONS, "time_limit": float(time_limit_s)})
        lo = np.concatenate(self.lo)
        hi = np.concatenate(self.hi)
        h.addVars(self.n, lo, hi)
        integer = np.asarray(self.integer, dtype=np.int32)
        h.changeColsIntegrality(
            len(integer), integer, np.full(len(integer), highspy.HighsVarType.kInteger)
        )
        row_lo = np.asarray(self.row_lo)
        row_hi = np.asarray(self.row_hi)
        row_lo[np.isneginf(row_lo)] = -inf
        row_hi[np.isposinf(row_hi)] = inf
        h.addRows(
            len(row_lo),
            row_lo,
            row_hi,
            len(self.index),
            np.asarray(self.starts, dtype=np.int32),
            np.asarray(self.index, dtype=np.int32),
            np.asarray(self.value, dtype=float),
        )
        # A failed run (option refused, model error) raises SolverError with HiGHS's message:
        # taking it for "unknown" would quietly weaken the bound.
        result = solve(h, what)
        if result.status == highspy.HighsModelStatus.kInfeasible:
            return _Outcome.INFEASIBLE, None
        if result.status == highspy.HighsModelStatus.kOptimal or result.has_solution:
            return _Outcome.FEASIBLE, np.asarray(h.getSolution().col_value, dtype=float)
        log.info("%s: HiGHS: %s", what, h.modelStatusToString(result.status))
        return _Outcome.UNKNOWN, None


#: HiGHS options for the feasibility MILPs (zero objective: the first solution is optimal).
_OPTIONS: dict[str, object] = {
    "mip_feasibility_tolerance": 1e-9,
    "primal_feasibility_tolerance": 1e-9,
}
