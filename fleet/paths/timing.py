"""Timing: a `Reference` along a path that the discrete double integrator tracks exactly.

The reference samples the paper's double integrator (``p[k+1] = p[k] + dt*v[k]``) from rest at
the path's start to rest at its goal. Every corner and every speed-limit change falls exactly on
a sample (very short stretches are merged into their slower neighbour, which is conservative),
and a HiGHS LP picks the speeds, so the reference meets the project's step semantics exactly:
each step's chord stays in the free space, every axis of ``v[k]`` respects the lowest limit of
every region the chord overlaps with positive length, and ``|v[k+1] - v[k]| <= a_max*dt`` per
axis. Every reference checks itself against those rules before it is returned.
"""

from __future__ import annotations

__all__ = ["Timing"]

import math
from dataclasses import dataclass, replace

import highspy
import numpy as np

from fleet.errors import FleetError
from fleet.highs import SolverError, new_highs, solve
from fleet.paths.limits import OVERLAP_TOL, SpeedLimits, speed_along
from fleet.paths.results import Path, Reference, make_reference

#: Tolerance of the self-check every reference passes before it is returned.
CHECK_TOL = 1e-9
#: Relative tightening of the LP's bounds, so the solver's own tolerance can never show.
LP_MARGIN = 1e-7
#: Above this many steps the speed LP's second phase (calmest speeds) is skipped.
CALM_MAX_STEPS = 4000
#: Rounds of adding steps to pieces the speed LP cannot cover before stopping at every corner.
MAX_ROUNDS = 8
#: Rounds of slowing pieces whose steps break their own chord's limit (`Timing._tightened`).
MAX_TIGHTENINGS = 8
#: m: in the speed LP's first phase a piece shorter than this weighs as one this long. A robot
#: 45 nm inside a slower zone made a piece that short, weighing 2e6 against 0.006 for the
#: longest, and HiGHS failed on the scaling (fuzz s21-0052, follower: 200 failed ticks).
COVER_MIN_M = 1e-4


class Timing:
    """References along the paths of one floor for one robot.

    Parameters
    ----------
    limits:
        The floor's speed limits for the robot.
    a_max:
        The robot's per-axis acceleration bound (m/s^2).
    """

    def __init__(self, limits: SpeedLimits, a_max: float) -> None:
        self.a_max = a_max
        self._limits = limits

    def reference(self, path: Path, dt: float) -> Reference:
        """A reference from rest at the start of `path` to rest at its goal, sampled every `dt`.

        Sample 0 is at time 0. The LP's step counts start from a trapezoidal profile and grow
        where it cannot cover a piece; after `MAX_ROUNDS` rounds the robot stops at every piece
        boundary, which is always feasible.

        Raises
        ------
        FleetError
            If no safe timing was found, or the reference fails its self-check (both bugs).
        """
        pieces = self._pieces(path, dt)
        if not pieces:
            z = np.zeros((1, 2))
            return make_reference(dt, path.waypoints[:1].copy(), z, path)
        for _ in range(MAX_TIGHTENINGS):
            counts, sigma = self._timed(pieces, dt, path)
            ref = self._assemble(pieces, counts, sigma, dt, path)
            slower = self._tightened(pieces, counts, ref)
            if slower is None:
                break
            pieces = slower
        self._verify(ref)
        return ref

    def _timed(self, pieces: list[_Piece], dt: float, path: Path) -> tuple[list[int], np.ndarray]:
        """Steps per piece and the speed of every moving step."""
        counts = self._step_counts(pieces, dt)
        for _ in range(MAX_ROUNDS):
            sigma, short = self._solve_speeds(pieces, counts, dt)
            if sigma is not None:
                return counts, sigma
            # Pieces the LP could not cover in their steps get more steps (never fewer, so the
            # reachable coverage only grows); the stop-and-go counts end the search for sure.
            counts = [
                n + max(1, math.ceil(gap / (p.speed * dt))) if gap > 0 else n
                for n, gap, p in zip(counts, short, pieces, strict=True)
            ]
        counts = self._stop_and_go_counts(pieces, dt)
        sigma, _ = self._solve_speeds(pieces, counts, dt)
        if sigma is None:  # pragma: no cover - the stop-and-go counts are always feasible
            start, goal = (tuple(path.waypoints[i].tolist()) for i in (0, -1))
            raise FleetError(
                f"no safe timing found from {start} to {goal} with dt={dt} (HiGHS found "
                "the speed LP infeasible); please report this with the floor map"
            )
        return counts, sigma

    def _tightened(
        self, pieces: list[_Piece], counts: list[int], ref: Reference
    ) -> list[_Piece] | None:
        """The pieces with lower speeds where a step of `ref` breaks its own chord's limit, or
        None if none does.

        A piece's limit comes from its whole leg, but a step's limit from its own chord, and
        the two can differ where a slower region's edge grazes the leg at a corner: the overlap
        there is rounding (under `OVERLAP_TOL` for the leg, over it for a shorter chord whose
        direction differs in the last digits). Such a piece is driven at the chord's limit.
        Speeds only go down, to one of the floor's finitely many limits, so this ends.
        """
        p, v = ref.positions, ref.velocities
        lim, _ = self._limits.of_segments(p[:-1], p[1:])
        over = (np.abs(v[:-1]) - lim).max(axis=1) > 0.0
        if not over.any():
            return None
        piece_of = np.repeat(np.arange(len(pieces)), counts)  # steps 1.. (step 0 is at rest)
        out = list(pieces)
        changed = False
        for k in np.flatnonzero(over):
            if k == 0 or k > len(piece_of):
                continue  # pragma: no cover - the rest steps have v = 0
            j = int(piece_of[k - 1])
            speed = speed_along(lim[k], out[j].u)
            if speed < out[j].speed:
                out[j] = replace(out[j], speed=speed)
                changed = True
        return out if changed else None

    def _pieces(self, path: Path, dt: float) -> list[_Piece]:
        """Straight pieces of constant limit: split at corners and where the limit changes."""
        pieces: list[_Piece] = []
        wp = path.waypoints
        # A leg too short to overlap any region (judged as a point) is folded into the next, or
        # the last into the one before, so the samples start and end exactly at the path's ends
        # (fuzz s41-0045: a 1 nm first leg gave no piece, and the reference began 1 nm off its
        # start, failing the self-check on 194 of the follower's commands).
        a = wp[0]
        for b in wp[1:]:
            d = b - a
            L = math.hypot(d[0], d[1])
            if L <= OVERLAP_TOL:
                continue
            parts = self._limits.stretches(a, b)
            if parts is None:  # pragma: no cover - paths are checked when planned
                raise FleetError(f"path leg {a} -> {b} leaves the free space (bug)")
            if not parts:
                continue
            u = d / L
            spans = _merge_spans([[s0, s1, lim] for s0, s1, lim in parts], u, dt)
            accel = self.a_max / float(np.abs(u).max())
            for s0, s1, lim in spans:
                p0 = a if s0 == 0.0 else a + d * (s0 / L)
                p1 = b if s1 == L else a + d * (s1 / L)
                pieces.append(_Piece(p0, p1, u, s1 - s0, speed_along(lim, u), accel))
            a = b
        if pieces and not np.array_equal(pieces[-1].p1, wp[-1]):
            last = pieces[-1]
            pieces[-1] = replace(last, p1=wp[-1], length=math.dist(last.p0, wp[-1]))
        return pieces

    def _step_counts(self, pieces: list[_Piece], dt: float) -> list[int]:
        """Steps per piece from a continuous forward/backward trapezoidal profile.

        Speeds and accelerations are shrunk like the LP's bounds, and a piece cannot be faster
        than one step over its whole length, so a piece driven at its limit gets the step it
        needs for the LP's margin.
        """
        J = len(pieces)
        shrink = 1.0 - 2 * LP_MARGIN
        cap = [min(p.speed * shrink, p.length / dt) for p in pieces]
        accel = [p.accel * shrink for p in pieces]
        junction = [0.0] * (J + 1)
        for j in range(1, J):
            turn = float(np.abs(pieces[j].u - pieces[j - 1].u).max())
            corner = self.a_max * dt * shrink / turn if turn > 0 else math.inf
            junction[j] = min(cap[j - 1], cap[j], corner)
        for j in range(J):
            reach = math.sqrt(junction[j] ** 2 + 2 * accel[j] * pieces[j].length)
            junction[j + 1] = min(junction[j + 1], reach)
        for j in reversed(range(J)):
            reach = math.sqrt(junction[j + 1] ** 2 + 2 * accel[j] * pieces[j].length)
            junction[j] = min(junction[j], reach)
        counts = []
        for j, p in enumerate(pieces):
            T = _trapezoid(p.length, junction[j], junction[j + 1], cap[j], accel[j])
            counts.append(max(1, math.ceil(T / dt - 1e-9)))
        return counts

    def _stop_and_go_counts(self, pieces: list[_Piece], dt: float) -> list[int]:
        """Steps per piece if the robot (nearly) stops at every piece boundary.

        Each piece starts and ends at a speed whose every axis is at most ``a_max*dt/2``, so any
        two pieces meet within the acceleration bound; the fewest steps that can cover the piece
        that way always give a feasible LP.
        """
        counts = []
        shrink = 1.0 - 2 * LP_MARGIN
        for p in pieces:
            edge = 0.5 * self.a_max * dt / float(np.abs(p.u).max()) * shrink
            top = p.speed * shrink
            step = p.accel * dt * shrink
            need = p.length / dt
            n = 1
            while True:
                i = np.arange(n)
                if np.minimum(top, edge + step * np.minimum(i, n - 1 - i)).sum() >= need:
                    break
                n = n + 1 if n < 64 else int(n * 1.25)
            counts.append(n)
        return counts

    def _solve_speeds(
        self, pieces: list[_Piece], counts: list[int], dt: float
    ) -> tuple[np.ndarray | None, list[float]]:
        """Along-piece speed of every moving step, from HiGHS.

        Constraints: speeds within each piece's limit, per-axis acceleration within
        ``a_max*dt`` between consecutive steps (also across corners), the first step reachable
        from rest and the last one able to stop, and each piece's steps covering at most its
        length. Phase 1 maximises the coverage; if every piece is covered, phase 2 fixes the
        coverage and minimises the total variation of the speeds (the calmest profile), warm
        started from phase 1.

        Returns
        -------
        sigma, short:
            The speeds, or None when some piece cannot be covered in its steps; `short` is the
            length (m) each piece lacks (all zero on success).
        """
        M = sum(counts)
        J = len(pieces)
        shrink = 1.0 - LP_MARGIN
        adt = self.a_max * dt * shrink
        piece_of = np.repeat(np.arange(J), counts)
        ub = np.array([pieces[j].speed for j in piece_of]) * shrink
        ub[0] = min(ub[0], adt / float(np.abs(pieces[0].u).max()))
        ub[-1] = min(ub[-1], adt / float(np.abs(pieces[-1].u).max()))
        n_tv = M - 1
        nvar = M + n_tv
        inf = highspy.kHighsInf
        target = np.array([p.length / dt for p in pieces])

        rows_lo, rows_hi, starts, index, value = _rows(pieces, counts, piece_of, dt, adt)
        h = new_highs({"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10})
        h.addVars(nvar, np.zeros(nvar), np.concatenate([ub, np.full(n_tv, inf)]))
        cols = np.arange(nvar, dtype=np.int32)
        # Phase 1: cover as much of every piece as the steps allow (relative to its length, so
        # a long piece cannot buy coverage with a short one's; one shorter than `COVER_MIN_M`
        # weighs as if that long, or its weight alone breaks HiGHS's scaling).
        weight = 1.0 / np.maximum(target, COVER_MIN_M / dt)
        h.changeColsCost(nvar, cols, np.concatenate([-weight[piece_of], np.zeros(n_tv)]))
        h.addRows(len(rows_lo), rows_lo, rows_hi, len(index), starts, index, value)
        # A failed run raises SolverError (HiGHS's message): no timing can come from this LP.
        if solve(h, "reference timing LP").status != highspy.HighsModelStatus.kOptimal:
            return None, [p.length for p in pieces]  # pragma: no cover - x = 0 is feasible
        x = np.asarray(h.getSolution().col_value[:M], dtype=float)
        covered = np.bincount(piece_of, weights=x, minlength=J)
        short = np.maximum(target - covered, 0.0) * dt
        if np.any(short > 1e-9 * np.maximum(1.0, target * dt)):
            return None, [float(s) if s > 1e-9 else 0.0 for s in short]

        # Phase 2: exact coverage, calmest speeds. Only a refinement (phase 1 is already a
        # feasible timing) and it grows about with the square of the steps, so long, finely
        # sampled trips skip it.
        if M <= CALM_MAX_STEPS:
            h.changeRowsBounds(J, np.arange(J, dtype=np.int32), target, target)
            h.changeColsCost(nvar, cols, np.concatenate([np.zeros(M), np.ones(n_tv)]))
            try:
                calm = solve(h, "reference calming LP").status == highspy.HighsModelStatus.kOptimal
            except SolverError:  # logged; phase 1's timing stands
                calm = False
            if calm:
                x = np.asarray(h.getSolution().col_value[:M], dtype=float)
        sigma = np.clip(x, 0.0, ub)
        # Cover each piece exactly (removes the solver's last rounding in the sums).
        covered = np.bincount(piece_of, weights=sigma, minlength=J)
        if np.any(covered <= 0):
            return None, [p.length if c <= 0 else 0.0 for p, c in zip(pieces, covered, strict=True)]
        sigma *= (target / covered)[piece_of]
        return sigma, [0.0] * J

    def _assemble(
        self, pieces: list[_Piece], counts: list[int], sigma: np.ndarray, dt: float, path: Path
    ) -> Reference:
        """The samples: from rest at the first piece's start, each piece in its steps at `sigma`."""
        K = sum(counts) + 1
        pos = np.zeros((K + 1, 2))
        vel = np.zeros((K + 1, 2))
        pos[0] = pos[1] = pieces[0].p0
        k = 1
        for piece, n in zip(pieces, counts, strict=True):
            # Place the samples by their cumulative share of the piece, not by adding steps up:
            # summing thousands of small steps would pile the rounding onto the last one.
            share = np.cumsum(sigma[k - 1 : k - 1 + n])
            pos[k + 1 : k + 1 + n] = piece.p0 + np.outer(share / share[-1], piece.p1 - piece.p0)
            pos[k + n] = piece.p1
            vel[k : k + n] = (pos[k + 1 : k + 1 + n] - pos[k : k + n]) / dt
            k += n
        return make_reference(dt, pos, vel, path)

    def _verify(self, ref: Reference) -> None:
        """Raise FleetError unless `ref` meets the step semantics to `CHECK_TOL`."""
        p, v, dt = ref.positions, ref.velocities, ref.dt
        wp = ref.path.waypoints
        problems = []
        if np.abs(p[0] - wp[0]).max() > CHECK_TOL or np.abs(p[-1] - wp[-1]).max() > CHECK_TOL:
            problems.append("does not start at the start and end at the goal")
        if np.abs(v[0]).max() > 0 or np.abs(v[-1]).max() > 0:
            problems.append("does not start and end at rest")
        drift = np.abs(p[1:] - p[:-1] - dt * v[:-1]).max()
        if drift > CHECK_TOL:
            problems.append(f"breaks p[k+1] = p[k] + dt*v[k] by {drift:.3g} m")
        dv = np.abs(np.diff(v, axis=0)).max()
        if dv > self.a_max * dt + CHECK_TOL:
            problems.append(f"changes velocity by {dv:.6g} m/s in one step (> a_max*dt)")
        lim, ok = self._limits.of_segments(p[:-1], p[1:])
        if not ok.all():
            k = int(np.flatnonzero(~ok)[0])
            problems.append(f"step {k} from {p[k]} to {p[k + 1]} leaves the free space")
        over = np.abs(v[:-1]) - lim
        if over.max() > CHECK_TOL:
            k = int(np.argmax(over.max(axis=1)))
            problems.append(f"step {k} at |v| = {np.abs(v[k])} exceeds its limit {lim[k]}")
        if problems:
            raise FleetError(
                "the reference failed its safety self-check (a bug; please report it with the "
                "floor map): " + "; ".join(problems)
            )


@dataclass(frozen=True, eq=False)
class _Piece:
    """A straight stretch of a path with one speed limit; samples land on both its ends."""

    p0: np.ndarray
    p1: np.ndarray
    u: np.ndarray  # unit direction
    length: float
    speed: float  # highest speed along u within the per-axis limit
    accel: float  # highest acceleration along u within the per-axis bound


def _rows(
    pieces: list[_Piece], counts: list[int], piece_of: np.ndarray, dt: float, adt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The speed LP's rows (lower and upper bounds, and the entries row by row, as HiGHS takes
    them): per piece its coverage; per pair of consecutive steps the acceleration row (one per
    moving axis where two pieces meet) and the two rows of the total variation.

    Built with numpy: the LP runs once per plan and a row-by-row Python loop cost as much as
    the solve. Columns 0..M-1 are the step speeds, M.. the total variation's.
    """
    M, J = int(sum(counts)), len(pieces)
    n_tv = M - 1
    shrink = 1.0 - LP_MARGIN
    inf = highspy.kHighsInf
    target = np.array([p.length / dt for p in pieces])
    i = np.arange(n_tv)
    a, b = piece_of[:-1], piece_of[1:]
    same = a == b
    step = np.array([p.accel for p in pieces]) * dt * shrink
    u = np.array([p.u for p in pieces], dtype=float).reshape(J, 2)
    ua, ub = u[a], u[b]
    moving = (ua != 0.0) | (ub != 0.0)
    # Up to four rows per pair, in this order: acceleration (along the piece, or the x axis
    # where pieces meet), acceleration on the y axis (where pieces meet), TV below, TV above.
    used = np.empty((n_tv, 4), dtype=bool)
    used[:, 0] = same | moving[:, 0]
    used[:, 1] = ~same & moving[:, 1]
    used[:, 2:] = True
    lo = np.empty((n_tv, 4))
    hi = np.empty((n_tv, 4))
    lo[:, 0] = np.where(same, -step[a], -adt)
    hi[:, 0] = np.where(same, step[a], adt)
    lo[:, 1], hi[:, 1] = -adt, adt
    lo[:, 2], hi[:, 2] = -inf, 0.0
    lo[:, 3], hi[:, 3] = 0.0, inf
    width = np.array([2, 2, 3, 3])
    cols = np.empty((n_tv, 4, 3), dtype=np.int32)
    vals = np.empty((n_tv, 4, 3))
    cols[:, :, 0], cols[:, :, 1], cols[:, :, 2] = i[:, None], i[:, None] + 1, M + i[:, None]
    vals[:, 0, 0] = np.where(same, -1.0, -ua[:, 0])
    vals[:, 0, 1] = np.where(same, 1.0, ub[:, 0])
    vals[:, 1, 0], vals[:, 1, 1] = -ua[:, 1], ub[:, 1]
    vals[:, 2:, 0], vals[:, 2:, 1] = -1.0, 1.0
    vals[:, 2, 2], vals[:, 3, 2] = -1.0, 1.0
    taken = used[:, :, None] & (np.arange(3) < width[:, None])[None, :, :]
    sizes = np.concatenate(
        [np.asarray(counts, dtype=np.int64), np.broadcast_to(width, used.shape)[used]]
    )
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32)
    index = np.concatenate([np.arange(M, dtype=np.int32), cols[taken]])
    value = np.concatenate([np.ones(M), vals[taken]])
    rows_lo = np.concatenate([np.zeros(J), lo[used]])
    rows_hi = np.concatenate([target, hi[used]])
    return rows_lo, rows_hi, starts, index, value


def _merge_spans(spans: list[list], u: np.ndarray, dt: float) -> list[list]:
    """Join collinear stretches ``[from_m, to_m, limit]`` where a sample is not worth it.

    Two neighbours join when that costs nothing (the same speed along `u` before and after),
    and a stretch shorter than one step at its own speed joins its slower neighbour: otherwise a
    sample would have to land on both its ends, forcing a slowdown for nothing.
    """
    spans = [list(s) for s in spans]
    changed = True
    while changed and len(spans) > 1:
        changed = False
        for k in range(len(spans) - 1):
            a, b = spans[k], spans[k + 1]
            both = np.minimum(a[2], b[2])
            fastest = max(speed_along(a[2], u), speed_along(b[2], u))
            if speed_along(both, u) >= fastest * (1 - 1e-12):
                spans[k : k + 2] = [[a[0], b[1], both]]
                changed = True
                break
        if changed:
            continue
        for k, (s0, s1, lim) in enumerate(spans):
            speed = speed_along(lim, u)
            if s1 - s0 >= speed * dt:
                continue
            m = min(
                (m for m in (k - 1, k + 1) if 0 <= m < len(spans)),
                key=lambda m: speed_along(spans[m][2], u),
            )
            if speed_along(spans[m][2], u) > speed:
                continue
            lo, hi = min(k, m), max(k, m)
            spans[lo : hi + 1] = [[spans[lo][0], spans[hi][1], np.minimum(lim, spans[m][2])]]
            changed = True
            break
    return spans


def _trapezoid(length: float, entry: float, exit_: float, top: float, accel: float) -> float:
    """Time to drive `length` from speed `entry` to `exit_` with speed <= `top`, |acc| <= accel."""
    peak = math.sqrt(accel * length + 0.5 * (entry**2 + exit_**2))
    if peak <= top:
        return max((2 * peak - entry - exit_) / accel, 0.0)
    ramps = (top**2 - entry**2 + top**2 - exit_**2) / (2 * accel)
    return (2 * top - entry - exit_) / accel + max(length - ramps, 0.0) / top
