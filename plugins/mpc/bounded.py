"""One control step's MILP, bounded to what the step can reach, as HiGHS arrays (no Pyomo).

The trip's model (`model.TripModel`, the Pyomo formulation) has a binary for every region of the
trip at every step and Big-M rows for every face of every region, with M over the whole trip's
bounding box: its size grows with the trip (up to 4,000 rows on the shop floor), and each
step's corridor switches all but a handful of binaries off with a zero bound. This module
writes the same step's MILP with only what that step can use:

- binaries only for the (step, region) pairs the corridor leaves open (``StepData.z_ub``);
- a face row only where the face can be crossed inside the step's reachable box, with M tight
  over that box (``max a . p - b`` over the box of p[k]), not over the trip's box;
- the midpoint cut alike: kept only where the box can break it, with M tight over the box;
- the zone speed as one row per step, axis and sign, ``s v[k] <= sum_j min(v_j, vb) z[k, j]``
  (vb the step's own speed bound): exact when one region is on, and the convex combination of
  the limits for a fractional z, tighter than one Big-M row per region; only where an open
  region is slower than vb.

Each row left out holds at every point of the box (and every speed within the bounds), so the
feasible set of (p, v, u) is the same as the trip model's and so is the optimal cost; only the
relaxation is tighter (fewer branch-and-bound nodes). The model's size no longer depends on the
trip's length: it is fixed by the horizon and the corridor. Columns are laid out as in `Layout`
(the "full" layout of the trip model's columns, for warm starts and solutions); the MILP holds
its fixed columns and then the open binaries only.
"""

from __future__ import annotations

from dataclasses import dataclass

import highspy
import numpy as np

from fleet_plugins.mpc.trip import MIDPOINT_MARGIN, Trip

__all__ = ["Layout", "StepMILP", "TripFaces", "build_step"]

_INF = highspy.kHighsInf
_ROWWISE = int(highspy.MatrixFormat.kRowwise)
_MINIMIZE = int(highspy.ObjSense.kMinimize)
#: A row whose Big-M over the box is at most this is never needed there (as in `trip`).
_NEEDED = 1e-9
#: Below this a zone's limit counts as the step's own speed bound (as in the trip model).
_SAME_SPEED = 1e-12


@dataclass(frozen=True)
class Layout:
    """Column positions of one trip's "full" layout: p, v, u, the tracking epigraphs, and one
    binary per (step 1..N-1, region of the trip's set S)."""

    N: int
    S: int

    @property
    def p(self) -> np.ndarray:
        return np.arange(2 * (self.N + 1), dtype=np.int32)

    @property
    def v(self) -> np.ndarray:
        return 2 * (self.N + 1) + self.p

    @property
    def u(self) -> np.ndarray:
        return np.arange(4 * (self.N + 1), 4 * (self.N + 1) + 2 * self.N, dtype=np.int32)

    @property
    def ep(self) -> np.ndarray:
        return self.u + 2 * self.N

    @property
    def ev(self) -> np.ndarray:
        return self.u + 4 * self.N

    @property
    def eu(self) -> np.ndarray:
        return self.u + 6 * self.N

    @property
    def fixed(self) -> int:
        """Columns before the binaries."""
        return 4 * (self.N + 1) + 8 * self.N

    @property
    def z(self) -> np.ndarray:
        return np.arange(self.fixed, self.fixed + (self.N - 1) * self.S, dtype=np.int32)

    @property
    def columns(self) -> int:
        return self.fixed + (self.N - 1) * self.S


@dataclass(frozen=True)
class StepMILP:
    """One step's MILP in HiGHS's arrays, and where its binaries sit in the full layout."""

    layout: Layout
    z_full: np.ndarray  # full-layout column of each open binary, in the MILP's order
    col_cost: np.ndarray
    col_lower: np.ndarray
    col_upper: np.ndarray
    integrality: np.ndarray
    row_lower: np.ndarray
    row_upper: np.ndarray
    start: np.ndarray
    index: np.ndarray
    value: np.ndarray

    @property
    def columns(self) -> int:
        return len(self.col_cost)

    @property
    def rows(self) -> int:
        return len(self.row_lower)

    def pass_to(self, h: highspy.Highs) -> None:
        """Load this MILP into `h` (replacing whatever it held)."""
        status = h.passModel(
            self.columns,
            self.rows,
            len(self.value),
            _ROWWISE,
            _MINIMIZE,
            0.0,
            self.col_cost,
            self.col_lower,
            self.col_upper,
            self.row_lower,
            self.row_upper,
            self.start,
            self.index,
            self.value,
            self.integrality,
        )
        if status == highspy.HighsStatus.kError:
            raise RuntimeError("HiGHS refused the MPC step's MILP")

    def reduce(self, full: np.ndarray) -> np.ndarray:
        """A full-layout column vector (a warm start) in this MILP's columns."""
        return np.concatenate([full[: self.layout.fixed], full[self.z_full]])

    def expand(self, col: np.ndarray) -> np.ndarray:
        """This MILP's column values in the full layout (closed binaries at 0)."""
        full = np.zeros(self.layout.columns)
        fixed = self.layout.fixed
        full[:fixed] = col[:fixed]
        full[self.z_full] = col[fixed : self.columns]
        return full


@dataclass(frozen=True)
class TripFaces:
    """The trip's faces as arrays, grouped by region (positions in S)."""

    region: np.ndarray  # (F,)
    a: np.ndarray  # (F, 2)
    b: np.ndarray  # (F,)
    slower: np.ndarray  # (F,) bool
    first: np.ndarray  # (S,) first face of each region in this order
    count: np.ndarray  # (S,)

    @classmethod
    def of(cls, trip: Trip) -> TripFaces:
        faces = sorted(trip.faces, key=lambda f: f.region)
        S = len(trip.regions)
        region = np.array([f.region for f in faces], dtype=np.int64)
        count = np.bincount(region, minlength=S)
        return cls(
            region=region,
            a=np.array([f.a for f in faces], dtype=float).reshape(-1, 2),
            b=np.array([f.b for f in faces], dtype=float),
            slower=np.array([f.slower_side for f in faces], dtype=bool),
            first=np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64),
            count=count,
        )


def build_step(
    trip: Trip,
    faces: TripFaces,
    N: int,
    dt: float,
    a_max: float,
    weights: tuple[float, float, float],
    p_lo: np.ndarray,
    p_hi: np.ndarray,
    v_lo: np.ndarray,
    v_hi: np.ndarray,
    z_ub: np.ndarray,
    p_ref: np.ndarray,
    v_ref: np.ndarray,
) -> StepMILP:
    """The step's MILP (see the module) for the bounds and reference of `StepData`."""
    S = len(trip.regions)
    L = Layout(N, S)
    P, V, U, EP, EV, EU = L.p, L.v, L.u, L.ep, L.ev, L.eu
    steps, regions = np.nonzero(z_ub > 0.5)  # steps - 1 (0..N-2), positions in S
    n_z = len(steps)
    z_col = L.fixed + np.arange(n_z)
    rows = _Rows()

    # Dynamics: p[k+1] - p[k] - dt v[k] = 0, v[k+1] - v[k] - dt u[k] = 0.
    k2 = np.arange(2 * N)  # (k, axis) pairs, k = 0..N-1
    rows.add(np.column_stack([P[k2 + 2], P[k2], V[k2]]), [1.0, -1.0, -dt], 0.0, 0.0)
    rows.add(np.column_stack([V[k2 + 2], V[k2], U[k2]]), [1.0, -1.0, -dt], 0.0, 0.0)
    # One open region per step 1..N-1 (a step with none left open: an empty row, infeasible).
    rows.add_groups(steps, N - 1, z_col)

    # Face rows a . p[k + end] + M z <= b + M, M over the box of p[k + end].
    if n_z:
        per = faces.count[regions]
        pair = np.repeat(np.arange(n_z), per)
        within = np.arange(len(pair)) - np.repeat(np.cumsum(per) - per, per)
        f = faces.first[regions][pair] + within
        a, b = faces.a[f], faces.b[f]
        k = steps[pair] + 1
        a_max_of = _max_over_box(a, p_lo, p_hi)
        for end in (0, 1):
            m = a_max_of(k + end) - b
            keep = m > _NEEDED
            kk = k[keep] + end
            rows.add(
                np.column_stack([P[2 * kk], P[2 * kk + 1], z_col[pair[keep]]]),
                np.column_stack([a[keep, 0], a[keep, 1], m[keep]]),
                -_INF,
                b[keep] + m[keep],
            )
        # Midpoint cut on faces next to a slower region: a . (p[k] + p[k+1]) <= 2 (b - margin).
        cut = faces.slower[f]
        rhs = 2.0 * (b - MIDPOINT_MARGIN)
        big = a_max_of(k) + a_max_of(k + 1) - rhs
        keep = cut & (big > _NEEDED)
        kk = k[keep]
        ak = a[keep]
        rows.add(
            np.column_stack(
                [P[2 * kk], P[2 * kk + 1], P[2 * kk + 2], P[2 * kk + 3], z_col[pair[keep]]]
            ),
            np.column_stack([ak[:, 0], ak[:, 1], ak[:, 0], ak[:, 1], big[keep]]),
            -_INF,
            rhs[keep] + big[keep],
        )
        # Zone speed, per step and axis: s v[k, axis] <= sum_j min(v_j, vb) z[k, j], vb the
        # step's own bound on s v: exact for one region on (the rows sum to 1), and the convex
        # combination of the limits for a fractional z (tighter than one Big-M row per region).
        k = steps + 1
        for axis in (0, 1):
            vj = trip.v_max[regions, axis]
            for sign, bound in ((1.0, v_hi[k, axis]), (-1.0, -v_lo[k, axis])):
                limit = np.minimum(vj, bound)
                slow = limit < bound - _SAME_SPEED
                # Rows only for steps where an open region is slower than the step's bound.
                needed = np.zeros(N + 1, dtype=bool)
                needed[k[slow]] = True
                on = needed[k]
                steps_on = np.flatnonzero(needed)
                if len(steps_on) == 0:
                    continue
                row_of = np.searchsorted(steps_on, k[on])
                rows.add_sparse(
                    np.concatenate([np.arange(len(steps_on)), row_of]),
                    np.concatenate([V[2 * steps_on + axis], z_col[on]]),
                    np.concatenate([np.full(len(steps_on), sign), -limit[on]]),
                    len(steps_on),
                    -_INF,
                    0.0,
                )

    # 1-norm tracking epigraph (k = 1..N) and input effort (k = 0..N-1).
    ke = np.arange(2, 2 * (N + 1))  # (k, axis), k = 1..N
    pr, vr = p_ref[1:].ravel(), v_ref[1:].ravel()
    e = np.arange(2 * N)
    rows.add(np.column_stack([P[ke], EP[e]]), [1.0, -1.0], -_INF, pr)
    rows.add(np.column_stack([P[ke], EP[e]]), [-1.0, -1.0], -_INF, -pr)
    rows.add(np.column_stack([V[ke], EV[e]]), [1.0, -1.0], -_INF, vr)
    rows.add(np.column_stack([V[ke], EV[e]]), [-1.0, -1.0], -_INF, -vr)
    rows.add(np.column_stack([U[e], EU[e]]), [1.0, -1.0], -_INF, 0.0)
    rows.add(np.column_stack([U[e], EU[e]]), [-1.0, -1.0], -_INF, 0.0)

    qp, qv, r = weights
    n_col = L.fixed + n_z
    cost = np.zeros(n_col)
    cost[EP], cost[EV], cost[EU] = qp, qv, r
    lower = np.concatenate(
        [p_lo[: N + 1].ravel(), v_lo.ravel(), np.full(2 * N, -a_max), np.zeros(6 * N + n_z)]
    )
    upper = np.concatenate(
        [p_hi[: N + 1].ravel(), v_hi.ravel(), np.full(2 * N, a_max), np.full(6 * N, _INF)]
        + [np.ones(n_z)]
    )
    integrality = np.zeros(n_col, dtype=np.int32)
    integrality[L.fixed :] = 1
    start, index, value, row_lo, row_hi = rows.arrays()
    return StepMILP(
        layout=L,
        z_full=(L.fixed + steps * S + regions).astype(np.int64),
        col_cost=cost,
        col_lower=lower,
        col_upper=upper,
        integrality=integrality,
        row_lower=row_lo,
        row_upper=row_hi,
        start=start,
        index=index,
        value=value,
    )


def _max_over_box(a: np.ndarray, p_lo: np.ndarray, p_hi: np.ndarray):
    """``k -> max of a[i] . p over the box of p[k[i]]`` for the rows of `a`."""

    def at(k: np.ndarray) -> np.ndarray:
        x = np.where(a[:, 0] > 0, p_hi[k, 0], p_lo[k, 0])
        y = np.where(a[:, 1] > 0, p_hi[k, 1], p_lo[k, 1])
        return a[:, 0] * x + a[:, 1] * y

    return at


class _Rows:
    """Rows collected in blocks, then one row-wise matrix (zero entries dropped)."""

    def __init__(self) -> None:
        self.idx: list[np.ndarray] = []
        self.val: list[np.ndarray] = []
        self.row: list[np.ndarray] = []
        self.lo: list[np.ndarray] = []
        self.hi: list[np.ndarray] = []
        self.n = 0

    def add(self, idx: np.ndarray, val, lo, hi) -> None:
        """Rows of equal width: `idx` (n, w), `val` (n, w) or (w,); bounds scalars or (n,)."""
        n, w = idx.shape
        if n == 0:
            return
        val = np.broadcast_to(np.asarray(val, dtype=float), (n, w))
        self.idx.append(idx.ravel())
        self.val.append(val.ravel())
        self.row.append(np.repeat(np.arange(self.n, self.n + n), w))
        self.lo.append(np.broadcast_to(np.asarray(lo, dtype=float), (n,)))
        self.hi.append(np.broadcast_to(np.asarray(hi, dtype=float), (n,)))
        self.n += n

    def add_groups(self, group: np.ndarray, n_groups: int, col: np.ndarray) -> None:
        """One row ``sum of the group's columns == 1`` per group 0..n_groups-1."""
        self.idx.append(col)
        self.val.append(np.ones(len(col)))
        self.row.append(self.n + group)
        self.lo.append(np.ones(n_groups))
        self.hi.append(np.ones(n_groups))
        self.n += n_groups

    def add_sparse(self, row: np.ndarray, idx: np.ndarray, val: np.ndarray, n: int, lo, hi) -> None:
        """`n` rows given by entries (row 0..n-1, column, value); bounds scalars or (n,)."""
        self.idx.append(idx)
        self.val.append(val)
        self.row.append(self.n + row)
        self.lo.append(np.broadcast_to(np.asarray(lo, dtype=float), (n,)))
        self.hi.append(np.broadcast_to(np.asarray(hi, dtype=float), (n,)))
        self.n += n

    def arrays(self) -> tuple[np.ndarray, ...]:
        row = np.concatenate(self.row)
        idx = np.concatenate(self.idx)
        val = np.concatenate(self.val)
        nz = val != 0.0
        row, idx, val = row[nz], idx[nz], val[nz]
        order = np.argsort(row, kind="stable")
        counts = np.bincount(row, minlength=self.n)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
        return (
            start,
            idx[order].astype(np.int32),
            val[order],
            np.concatenate(self.lo),
            np.concatenate(self.hi),
        )
