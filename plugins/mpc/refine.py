"""The paper's quadratic cost for a fixed region sequence: a small convex QP solved by HiGHS.

HiGHS cannot solve the paper's MIQP (quadratic cost with binaries), so the trip model
(`model.TripModel`) solves a MILP with the 1-norm of the same terms. This module takes the
region sequence that MILP chose and solves the paper's cost exactly for it: with every step's
region fixed, the Big-M union collapses to that region's rows and the problem is a convex QP,

    minimise   sum_{k=1..N} q_p |p[k] - p_ref[k]|^2 + q_v |v[k] - v_ref[k]|^2
             + sum_{k=0..N-1} r |u[k]|^2
    subject to p[k+1] = p[k] + dt v[k],  v[k+1] = v[k] + dt u[k],  |u[k]| <= a_max,
               the step's p, v bounds (`StepData`: measured state, caps, reachable boxes),
               for k = 1..N-1 and j = regions[k-1]:
               A_j p[k] <= b_j,  A_j p[k+1] <= b_j,  |v[k]| <= v_max_j per axis,
               a.(p[k] + p[k+1]) <= 2 (b - MIDPOINT_MARGIN) on faces next to a slower region.

Every MILP solution is feasible here (same rows for its own regions), so the QP's plan never
has a higher quadratic cost than the MILP's plan.

How it is put to HiGHS, and why. HiGHS's only QP solver (1.15) is an active-set method that
ends some degenerate solves in "solve error" (it claims optimality, but its point misses a row
by about the midpoint margin; cf. ERGO-Code/HiGHS#2973). Measured on the 305 MILP solutions of
case study 3 (s1 + s2): p, v, u as columns with the dynamics as equality rows failed 120 of
them; u as the only columns (p, v condensed) failed 34. Here the columns are the *positions*
p[2..N]: p[0], p[1] follow from the measured state, v and u are first and second differences,
every row has at most four entries, the reachable boxes and axis-aligned faces are column
bounds, and a fixed end velocity (``v[N] = 0``) fixes p[N+1] (no equality rows at all).
That failed 3 of 305; a failed solve is retried once with the columns measured from the
reference (``p - p_ref``), which HiGHS solves along a different path (that variant alone
failed 2, none of the same 3): 0 of 305 failed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import highspy
import numpy as np

from fleet.highs import configure, new_highs
from fleet.plugins import SolverOutcome
from fleet_plugins.mpc.model import Solution, StepData, run_outcome
from fleet_plugins.mpc.separation import Separation
from fleet_plugins.mpc.trip import MIDPOINT_MARGIN, Trip

__all__ = ["refine_milp", "refine_quadratic", "quadratic_cost"]

_ROWWISE = int(highspy.MatrixFormat.kRowwise)
_TRIANGULAR = int(highspy.HessianFormat.kTriangular)
_MINIMIZE = int(highspy.ObjSense.kMinimize)
_INF = highspy.kHighsInf
#: Below this a zone's limit counts as the robot's own (as in the MILP's speed rows).
_SAME_SPEED = 1e-12
#: A row no column enters is left out when it holds within this.
_CONSTANT_TOL = 1e-9


def refine_milp(
    milp: Solution,
    trip: Trip,
    data: StepData,
    separation: Separation | None,
    *,
    N: int,
    dt: float,
    a_max: float,
    v_robot: float,
    weights: tuple[float, float, float],
    time_limit_s: float,
    highs: highspy.Highs,
) -> tuple[Solution, bool]:
    """The paper's quadratic cost for the regions of a usable MILP solution, and whether the
    QP was optimal; if it was not, the MILP's own solution (its time counting both solves).

    With other robots about, the sides of their squares the MILP chose are fixed too: each
    is a bound on one coordinate of one point, so the QP keeps clear of them as well. A QP
    stopped by the wall-clock guard gives an unusable ``TIME_LIMIT`` solution instead of the
    MILP's (the step falls back). The other arguments are `refine_quadratic`'s.
    """
    assert milp.regions is not None
    if separation is not None and milp.separation is not None:
        assert milp.p is not None
        p_lo, p_hi = separation.bounds(milp.separation, data.p_lo, data.p_hi, milp.p)
        data = StepData(p_lo, p_hi, data.v_lo, data.v_hi, data.z_ub, data.p_ref, data.v_ref)
    qp = refine_quadratic(
        trip,
        data,
        milp.regions,
        N=N,
        dt=dt,
        a_max=a_max,
        v_robot=v_robot,
        weights=weights,
        time_limit_s=time_limit_s,
        highs=highs,
    )
    if qp.outcome is SolverOutcome.TIME_LIMIT:
        # Whether the QP finished depended on the machine's speed, so the step must not
        # depend on it either: it falls back like a MILP stopped by the clock (and is counted
        # in the summary's ``solver.time_limit_hits``).
        return Solution(SolverOutcome.TIME_LIMIT, milp.solver_s + qp.solver_s), False
    if qp.outcome is not SolverOutcome.OPTIMAL:
        milp.solver_s += qp.solver_s
        return milp, False
    # The report keeps the MILP's outcome (the command comes from a usable plan either way)
    # and counts both solves' time.
    refined = Solution(
        milp.outcome,
        milp.solver_s + qp.solver_s,
        p=qp.p,
        v=qp.v,
        u=qp.u,
        regions=milp.regions,
        separation=milp.separation,
    )
    return refined, True


def refine_quadratic(
    trip: Trip,
    data: StepData,
    regions: np.ndarray,
    *,
    N: int,
    dt: float,
    a_max: float,
    v_robot: float,
    weights: tuple[float, float, float],
    time_limit_s: float,
    highs: highspy.Highs | None = None,
) -> Solution:
    """Solve the paper's quadratic-cost MPC with each step's region fixed to `regions`.

    Parameters
    ----------
    trip:
        The trip whose faces and zone limits the regions refer to.
    data:
        This step's bounds and reference window (the same object the MILP was solved with);
        p[0] and v[0] must be fixed (lower bound = upper bound: the measured state).
    regions:
        ``(N-1,)`` positions in ``trip.regions``: the region of steps 1..N-1 (usually the
        MILP solution's ``regions``).
    N, dt, a_max, v_robot:
        Horizon, step (s), per-axis input bound (m/s^2), the robot's per-axis speed limit (m/s).
    weights:
        ``(q_p, q_v, r)``: the paper's ``Q = q_p I`` (position), ``q_v I`` (velocity) and
        ``R = r I`` (input), all >= 0.
    time_limit_s:
        Wall-clock limit of HiGHS for this call (both tries together).
    highs:
        A HiGHS object of its own for these QPs, reused from call to call to save its
        construction (`fleet.highs.new_highs`); its model and its ``time_limit`` are replaced
        on every call. Never pass the trip model's ``TripModel.highs`` (that would replace the
        MILP). A new one is made when None.

    Returns
    -------
    Solution
        ``outcome`` (`SolverOutcome`), ``solver_s`` (wall time of HiGHS ``run()``, summed over
        the tries) and, when the outcome is usable, the plan ``p``, ``v`` (``(N+1, 2)``),
        ``u`` (``(N, 2)``; clipped to ``a_max``, which it meets within HiGHS's feasibility
        tolerance of 1e-7) and ``regions`` (the given ones). An impossible region sequence
        gives ``INFEASIBLE``.

    Raises
    ------
    ValueError
        `N` < 2, `regions` is not ``N-1`` positions in ``trip.regions``, or p[0], v[0] are
        not fixed in `data`.
    """
    if isinstance(N, bool) or not isinstance(N, int) or N < 2:
        raise ValueError(f"refine_quadratic: N = {N!r}, must be an integer >= 2")
    regions = np.asarray(regions)
    n_regions = len(trip.regions)
    if (
        regions.shape != (N - 1,)
        or not np.issubdtype(regions.dtype, np.integer)
        or np.any(regions < 0)
        or np.any(regions >= n_regions)
    ):
        raise ValueError(
            f"refine_quadratic: regions = {regions!r}: must be {N - 1} integer positions "
            f"in the trip's {n_regions} regions (0..{n_regions - 1})"
        )
    if np.any(data.p_lo[0] != data.p_hi[0]) or np.any(data.v_lo[0] != data.v_hi[0]):
        raise ValueError(
            f"refine_quadratic: p[0] in [{data.p_lo[0]}, {data.p_hi[0]}], v[0] in "
            f"[{data.v_lo[0]}, {data.v_hi[0]}]: must be fixed to the measured state"
        )
    if highs is None:
        highs = new_highs()
    problem = _Problem.of(trip, data, regions, N, float(dt), float(a_max), v_robot)

    solver_s = 0.0
    outcome = SolverOutcome.ERROR
    for origin in (None, data.p_ref):  # the second try only after a solve error
        qp = _build(problem, data, weights, origin)
        # The QP solver checks its time limit against the object's lifetime clock
        # (getRunTime(), which no clear() resets), not per run(): add the time used so far.
        left = max(float(time_limit_s) - solver_s, 0.0)
        configure(highs, {"time_limit": highs.getRunTime() + left})
        qp.pass_to(highs)
        t0 = time.perf_counter()
        outcome = run_outcome(highs, "MPC quadratic refinement")
        solver_s += time.perf_counter() - t0
        if outcome is not SolverOutcome.ERROR or solver_s >= time_limit_s:
            break
    if not outcome.usable:
        return Solution(outcome, solver_s)
    x = np.asarray(highs.getSolution().col_value)
    q = qp.C + qp.S @ x  # p[0..N+1]
    v = np.diff(q, axis=0) / problem.dt
    u = np.diff(v, axis=0)[:N] / problem.dt
    return Solution(
        outcome,
        solver_s,
        p=q[: N + 1],
        v=v,
        u=np.clip(u, -problem.a_max, problem.a_max),
        regions=regions.copy(),
    )


def quadratic_cost(
    p: np.ndarray,
    v: np.ndarray,
    u: np.ndarray,
    data: StepData,
    weights: tuple[float, float, float],
) -> float:
    """The paper's cost of a plan: ``sum q_p |p-p_ref|^2 + q_v |v-v_ref|^2`` over k = 1..N,
    plus ``r |u|^2`` over k = 0..N-1 (to compare the MILP's plan with the QP's)."""
    q_p, q_v, r = weights
    dp = p[1:] - data.p_ref[1 : len(p)]
    dv = v[1:] - data.v_ref[1 : len(v)]
    return float(q_p * np.sum(dp * dp) + q_v * np.sum(dv * dv) + r * np.sum(u * u))


@dataclass(frozen=True)
class _Problem:
    """One call's data that does not depend on how the columns are measured."""

    N: int
    dt: float
    a_max: float
    p0: np.ndarray
    v0: np.ndarray
    v_lo: np.ndarray  # (N+1, 2) with the fixed regions' zone limits
    v_hi: np.ndarray
    end_speed: np.ndarray | None  # v[N] when fixed (then p[N+1] is not a column)
    p_lo: np.ndarray  # (N+1, 2)
    p_hi: np.ndarray
    faces: np.ndarray  # (F, 2): point index m, face index f, for the rows a_f.p[m] <= b_f
    cuts: np.ndarray  # (C, 2): step k, face f, for a_f.(p[k] + p[k+1]) <= 2(b_f - margin)
    face_a: np.ndarray  # (all faces, 2)
    face_b: np.ndarray

    @classmethod
    def of(
        cls,
        trip: Trip,
        data: StepData,
        regions: np.ndarray,
        N: int,
        dt: float,
        a_max: float,
        v_robot: float,
    ) -> _Problem:
        v_lo = np.array(data.v_lo[: N + 1], dtype=float)
        v_hi = np.array(data.v_hi[: N + 1], dtype=float)
        zone = trip.v_max[regions]  # (N-1, 2), the limits of steps 1..N-1
        slower = zone < v_robot - _SAME_SPEED
        v_lo[1:N] = np.where(slower, np.maximum(v_lo[1:N], -zone), v_lo[1:N])
        v_hi[1:N] = np.where(slower, np.minimum(v_hi[1:N], zone), v_hi[1:N])
        end_speed = None
        if np.all(v_lo[N] == v_hi[N]):
            end_speed = v_lo[N].copy()
            # |u[N-1]| <= a_max with u[N-1] = (v[N] - v[N-1]) / dt is a bound on v[N-1].
            v_lo[N - 1] = np.maximum(v_lo[N - 1], end_speed - a_max * dt)
            v_hi[N - 1] = np.minimum(v_hi[N - 1], end_speed + a_max * dt)

        faces = trip.faces
        n_faces = len(faces)
        f_region = np.fromiter((f.region for f in faces), dtype=np.int64, count=n_faces)
        f_cut = np.fromiter((f.slower_side for f in faces), dtype=bool, count=n_faces)
        steps, fs = np.nonzero(f_region[None, :] == regions[:, None])
        k = steps + 1  # the region of step k is regions[k-1]
        # Both ends of each step; two steps in one region share a point: one row is enough.
        ends = np.unique(np.concatenate([k, k + 1]) * max(n_faces, 1) + np.concatenate([fs, fs]))
        face_rows = np.stack(np.divmod(ends, max(n_faces, 1)), axis=1)
        cut = f_cut[fs]
        return cls(
            N=N,
            dt=dt,
            a_max=a_max,
            p0=np.asarray(data.p_lo[0], dtype=float),
            v0=np.asarray(data.v_lo[0], dtype=float),
            v_lo=v_lo,
            v_hi=v_hi,
            end_speed=end_speed,
            p_lo=np.asarray(data.p_lo[: N + 1], dtype=float),
            p_hi=np.asarray(data.p_hi[: N + 1], dtype=float),
            faces=face_rows,
            cuts=np.stack([k[cut], fs[cut]], axis=1),
            face_a=np.array([f.a for f in faces], dtype=float).reshape(n_faces, 2),
            face_b=np.fromiter((f.b for f in faces), dtype=float, count=n_faces),
        )


@dataclass(frozen=True)
class _Qp:
    """The QP in HiGHS's terms, and how its columns x give the points: ``p = C + S x``."""

    C: np.ndarray  # (N+2, 2): p[0..N+1] at x = 0
    S: np.ndarray  # (N+2, 2, n)
    col_lo: np.ndarray
    col_hi: np.ndarray
    A: np.ndarray  # dense (rows, n); rows have at most four entries
    row_lo: np.ndarray
    row_hi: np.ndarray
    cost: np.ndarray
    offset: float
    H: np.ndarray  # dense (n, n)

    def pass_to(self, highs: highspy.Highs) -> None:
        n = len(self.col_lo)
        rows, cols = np.nonzero(self.A)
        a_start = np.searchsorted(rows, np.arange(len(self.A))).astype(np.int32)
        h_cols, h_rows = np.nonzero(np.tril(self.H).T)  # lower triangle, column by column
        q_start = np.searchsorted(h_cols, np.arange(n + 1)).astype(np.int32)
        highs.passModel(
            n,
            len(self.A),
            len(rows),
            len(h_rows),
            _ROWWISE,
            _TRIANGULAR,
            _MINIMIZE,
            self.offset,
            self.cost,
            self.col_lo,
            self.col_hi,
            self.row_lo,
            self.row_hi,
            a_start,
            cols.astype(np.int32),
            self.A[rows, cols],
            q_start,
            h_rows.astype(np.int32),
            self.H[h_rows, h_cols],
            np.zeros(n, dtype=np.int32),
        )


def _build(
    pb: _Problem,
    data: StepData,
    weights: tuple[float, float, float],
    origin: np.ndarray | None,
) -> _Qp:
    """The QP with columns ``p[2..M] - origin[2..M]`` (M = N, or N+1 if v[N] is free)."""
    N, dt = pb.N, pb.dt
    last = N if pb.end_speed is not None else N + 1
    n_points = last - 1
    n = 2 * n_points
    # Points p[0..N+1] = C + S x; the axes do not mix.
    S = np.zeros((N + 2, 2, n))
    S[2 : last + 1] = np.eye(n).reshape(n_points, 2, n)
    C = np.zeros((N + 2, 2))
    C[0] = pb.p0
    C[1] = pb.p0 + dt * pb.v0
    if pb.end_speed is not None:
        S[N + 1] = S[N]
        C[N + 1] = dt * pb.end_speed
    col_lo = np.full(n, -_INF)
    col_hi = np.full(n, _INF)
    col_lo[: 2 * (N - 1)] = pb.p_lo[2:].ravel()
    col_hi[: 2 * (N - 1)] = pb.p_hi[2:].ravel()
    if origin is not None:
        # (p[N+1], a column when v[N] is free, is measured from origin[N].)
        shift = np.ravel(np.vstack([origin, origin[-1:]])[2 : last + 1])
        C = C + S @ shift
        col_lo, col_hi = col_lo - shift, col_hi - shift
    # v[k] = (p[k+1] - p[k]) / dt for k = 0..N; u[k] = (v[k+1] - v[k]) / dt for k = 0..N-1.
    VS, VC = np.diff(S, axis=0) / dt, np.diff(C, axis=0) / dt
    US, UC = np.diff(VS, axis=0)[:N] / dt, np.diff(VC, axis=0)[:N] / dt

    blocks: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    v_steps = slice(1, N if pb.end_speed is not None else N + 1)  # v[N] fixed: no row
    blocks.append((VS[v_steps], VC[v_steps], pb.v_lo[v_steps], pb.v_hi[v_steps]))
    u_steps = slice(0, N - 1 if pb.end_speed is not None else N)  # u[N-1]: a bound on v[N-1]
    a = np.full_like(UC[u_steps], pb.a_max)
    blocks.append((US[u_steps], UC[u_steps], -a, a))
    A = np.vstack([M.reshape(-1, n) for M, _, _, _ in blocks])
    const = np.concatenate([c.ravel() for _, c, _, _ in blocks])
    lo = np.concatenate([b.ravel() for _, _, b, _ in blocks]) - const
    hi = np.concatenate([b.ravel() for _, _, _, b in blocks]) - const
    # Faces a.p[m] <= b and midpoint cuts a.(p[k] + p[k+1]) <= 2(b - margin).
    m, f = pb.faces[:, 0], pb.faces[:, 1]
    k, g = pb.cuts[:, 0], pb.cuts[:, 1]
    fa, ga = pb.face_a[f], pb.face_a[g]
    face_rows = np.einsum("ra,ran->rn", fa, S[m])
    face_hi = pb.face_b[f] - np.einsum("ra,ra->r", fa, C[m])
    cut_rows = np.einsum("ra,ran->rn", ga, S[k] + S[k + 1])
    cut_hi = 2.0 * (pb.face_b[g] - MIDPOINT_MARGIN) - np.einsum("ra,ra->r", ga, C[k] + C[k + 1])
    A = np.vstack([A, face_rows, cut_rows])
    lo = np.concatenate([lo, np.full(len(face_hi) + len(cut_hi), -_INF)])
    hi = np.concatenate([hi, face_hi, cut_hi])
    A, lo, hi, col_lo, col_hi = _rows_to_bounds(A, lo, hi, col_lo, col_hi)

    q_p, q_v, r = (float(w) for w in weights)
    Mp, ep = S[1 : N + 1].reshape(-1, n), (C[1 : N + 1] - data.p_ref[1 : N + 1]).ravel()
    Mv, ev = VS[1 : N + 1].reshape(-1, n), (VC[1 : N + 1] - data.v_ref[1 : N + 1]).ravel()
    Mu, eu = US.reshape(-1, n), UC.ravel()
    return _Qp(
        C=C,
        S=S,
        col_lo=col_lo,
        col_hi=col_hi,
        A=A,
        row_lo=lo,
        row_hi=hi,
        cost=2.0 * (q_p * Mp.T @ ep + q_v * Mv.T @ ev + r * Mu.T @ eu),
        offset=q_p * float(ep @ ep) + q_v * float(ev @ ev) + r * float(eu @ eu),
        H=2.0 * (q_p * Mp.T @ Mp + q_v * Mv.T @ Mv + r * Mu.T @ Mu),
    )


def _rows_to_bounds(
    A: np.ndarray, lo: np.ndarray, hi: np.ndarray, col_lo: np.ndarray, col_hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows with one entry become column bounds; rows with none are left out if they hold.

    (A row with none that fails stays: HiGHS then reports the QP infeasible.)
    """
    nnz = np.count_nonzero(A, axis=1)
    col_lo, col_hi = col_lo.copy(), col_hi.copy()
    for i in np.flatnonzero(nnz == 1):
        j = int(np.flatnonzero(A[i])[0])
        a = A[i, j]
        low, high = (lo[i] / a, hi[i] / a) if a > 0 else (hi[i] / a, lo[i] / a)
        col_lo[j] = max(col_lo[j], low)
        col_hi[j] = min(col_hi[j], high)
    holds = (lo <= _CONSTANT_TOL) & (hi >= -_CONSTANT_TOL)
    keep = (nnz > 1) | ((nnz == 0) & ~holds)
    return A[keep], lo[keep], hi[keep], col_lo, col_hi
