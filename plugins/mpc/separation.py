"""Keeping clear of other robots: Big-M boxes round their predicted positions along the horizon.

Another robot j is predicted from its latest plan (`fleet.plugins.Neighbour.plan`, ``(t, x, y)``
samples): its centre c_jk at step k's time is the plan interpolated there (the observed position
before the first sample, the last sample after the end; no plan: where it is now). The robot's
plan must stay outside the square of half-width ``d = r_i + r_j + margin`` round c_jk: along
one axis the two centres are at least d apart, so the discs (centres at least d apart) never
touch. The outside of a square is the union of four half-planes, so each group of steps gets
one binary per side ("this side holds"), at least one of which must be on.

As with the floor's regions (`model`), a binary covers whole steps: the side it picks holds at
every point of its group, p[k] against c_jk for k = first..last, and consecutive groups share
their end point. Between samples both robots move (nearly) in straight lines, so their
difference does too, and a half-plane that holds at both ends of a step holds all along it: no
tunnelling through each other between samples. Groups grow along the horizon (`spans`).

Rows, for the side ``s * p[axis] >= s * c[axis] + d`` (s = +1 or -1) at point e:

    s * p[e, axis] - M * b + slack >= s * c[e, axis] + d - M,    0 <= slack <= margin

with M = ``s * c + d - min(s * p)`` over the box where p[e] can be (tight per row, as the
region rows). The margin is soft: `slack` (one per robot and group, cost `SLACK_COST` per
metre) lets a plan into the margin only where it cannot keep out of it (a neighbour whose plan
moved by a few centimetres since the robot planned its fixed next position), never into contact
(``r_i + r_j``, hard), unless the robots are already that close (then the whole square is
soft, so that the plan gets away). A robot inside the hard square but not in contact (off on
a diagonal: the square is larger than the disc there) gets a fifth side instead, across the
line between the two: the plan keeps at least ``r_i + r_j`` along it (`build_separation`).
Few binaries: a group gets none when one side provably holds at all its points over the
boxes where they can be, and a side that cannot hold there gets none.

Everything here is numpy; `model.TripModel.solve` appends the rows to the trip's HiGHS model
for one solve and removes them again.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fleet.plugins import Neighbour

__all__ = [
    "Separation",
    "Obstacle",
    "predict",
    "at_rest",
    "reaches",
    "build_separation",
    "spans",
    "SLACK_COST",
    "SPAN_S",
]

#: Cost (per metre, per robot and step) of a plan entering the soft margin: far above what a
#: detour of the same length costs in tracking (weights ~1 per metre and step).
SLACK_COST = 1e3
#: A robot whose predicted positions stay within this (m) of where it is counts as at rest.
REST_M = 1e-3
#: Tolerance (m) of the "holds" and "possible" tests (HiGHS's feasibility tolerance is 1e-9).
_TOL = 1e-9
#: How long (s) the first group of steps that share one side lasts; each second group lasts this
#: much longer than the previous pair (0.5, 0.5, 1, 1, 1.5, 1.5, ... s; at least one step).
SPAN_S = 0.5
#: The four sides of a square: (axis, sign) for ``sign * p[axis] >= sign * c[axis] + d``.
SIDES: tuple[tuple[int, int], ...] = ((0, 1), (0, -1), (1, 1), (1, -1))
#: The side index of the fifth side, across the line between two robots (`build_separation`).
ACROSS = len(SIDES)


@dataclass(frozen=True)
class Obstacle:
    """Another robot as the plan must avoid it: a box round its predicted centre at each step.

    `centres` and `half` are ``(N+1, 2)``: the box's centre and per-axis half-widths at steps
    0..N. For a robot predicted at one point that is d on both axes (`square`); a robot that
    may be anywhere between two predictions gets the box round both. The outer `margin` of
    each half-width is soft; the rest (at least the sum of the two radii) is hard.
    """

    robot: str
    centres: np.ndarray
    half: np.ndarray
    margin: float
    #: ``(N+1, 2)``: half-widths of the box the other robot's centre may be in (zero for a
    #: robot predicted at one point); `half` is this plus ``r_i + r_j + margin``.
    core: np.ndarray | None = None

    @classmethod
    def square(cls, robot: str, centres: np.ndarray, half: float, margin: float) -> Obstacle:
        """The square of half-width `half` round each of `centres`."""
        return cls(robot, centres, np.full(centres.shape, float(half)), margin)

    @classmethod
    def between(
        cls, robot: str, one: np.ndarray, other: np.ndarray, half: float, margin: float
    ) -> Obstacle:
        """The box holding the squares of half-width `half` round both `one[k]` and
        `other[k]`, at each step k (a robot that either carries on or stops)."""
        core = np.abs(one - other) / 2
        return cls(robot, (one + other) / 2, half + core, margin, core)

    def spread(self) -> np.ndarray:
        """`core`, zeros when not given."""
        return np.zeros_like(self.half) if self.core is None else self.core


def predict(neighbour: Neighbour, t0: float, dt: float, steps: int) -> np.ndarray:
    """Where `neighbour` is predicted at ``t0 + k dt``, k = 0..`steps`: ``(steps+1, 2)``.

    Its plan interpolated linearly; before the plan's first sample, between the observed
    position (at `t0`) and that sample; after its last sample, the last sample (a plan ends at
    rest); with no plan, the observed position throughout (the contract: assume it stays put).
    """
    here = np.array([neighbour.x, neighbour.y], dtype=float)
    if not neighbour.plan:
        return np.tile(here, (steps + 1, 1))
    plan = np.asarray(neighbour.plan, dtype=float).reshape(-1, 3)
    plan = plan[np.argsort(plan[:, 0], kind="stable")]
    if plan[0, 0] > t0 + 1e-9:
        plan = np.vstack([[t0, *here], plan])
    times = t0 + dt * np.arange(steps + 1)
    return np.column_stack(
        [np.interp(times, plan[:, 0], plan[:, 1]), np.interp(times, plan[:, 0], plan[:, 2])]
    )


def at_rest(centres: np.ndarray) -> bool:
    """Whether predicted `centres` stay where they start (a robot parked for the horizon)."""
    return float(np.max(np.abs(centres - centres[0]))) <= REST_M


def reaches(obstacle: Obstacle, p_lo: np.ndarray, p_hi: np.ndarray) -> bool:
    """Whether the plan could come closer than d to `obstacle` at some step 1..N.

    `p_lo`, `p_hi` (``(N+1, 2)``) bound where the plan can be at each step (reachable boxes).
    """
    c, h = obstacle.centres, obstacle.half
    apart = (p_lo[1:] >= c[1:] + h[1:] - _TOL) | (p_hi[1:] <= c[1:] - h[1:] + _TOL)
    return bool(np.any(~apart.any(axis=1)))


@dataclass(frozen=True)
class Separation:
    """The separation rows of one solve, in HiGHS's terms.

    Columns appended after the trip model's own: the binaries (one per step, robot and side
    that can hold), then one slack per group (a group = one robot at one step). Rows: one per
    (binary, end) that can fail, then one ``sum of the group's binaries >= 1`` per group.
    Points are numbered ``2 * k + axis`` (the trip model maps them to its p columns).
    """

    obstacles: tuple[Obstacle, ...]
    #: Per group: the obstacle's index and the first and last points it covers.
    group_obstacle: np.ndarray
    group_first: np.ndarray
    group_last: np.ndarray
    #: Per group: the slack's upper bound (the margin; all of d for a robot already too close).
    group_slack: np.ndarray
    #: Per binary: its group and side (index into `SIDES`, or `ACROSS`).
    binary_group: np.ndarray
    binary_side: np.ndarray
    #: Per side row: the point ``2 e + axis`` and its coefficient (the sign; a component of
    #: the normal on an `ACROSS` row, whose other point ``2 e + 1`` and coefficient are in
    #: `row_point2` and `row_coef2`, -1 and 0 on other rows), its binary, its M and its
    #: lower bound.
    row_point: np.ndarray
    row_coef: np.ndarray
    row_point2: np.ndarray
    row_coef2: np.ndarray
    row_binary: np.ndarray
    row_big_m: np.ndarray
    row_lo: np.ndarray
    #: A step at which no side can hold: the plan cannot keep clear (the problem is infeasible).
    infeasible: bool
    #: Per obstacle: the unit normal of its `ACROSS` side, zero when it has none.
    normals: np.ndarray

    @property
    def binaries(self) -> int:
        """Binaries this solve adds."""
        return len(self.binary_group)

    @property
    def groups(self) -> int:
        """(Robot, step) pairs this solve constrains (one slack column each)."""
        return len(self.group_first)

    def start(self, p: np.ndarray) -> np.ndarray:
        """Values of the added columns for plan `p` (``(N+1, 2)``), for a MIP start.

        Each group takes the side on which `p` keeps farthest out at both ends, and the slack
        it needs (a plan that enters the hard part gives an infeasible start: HiGHS drops it).
        """
        values = np.zeros(self.binaries + self.groups)
        if not self.groups:
            return values
        best = np.full(self.groups, -np.inf)
        pick = np.full(self.groups, -1)
        for b in range(self.binaries):
            g = int(self.binary_group[b])
            j = int(self.group_obstacle[g])
            ends = range(int(self.group_first[g]), int(self.group_last[g]) + 1)
            gap = min(self._clearance(j, int(self.binary_side[b]), e, p[e]) for e in ends)
            if gap > best[g]:
                best[g], pick[g] = gap, b
        for g in range(self.groups):
            if pick[g] >= 0:
                values[pick[g]] = 1.0
                values[self.binaries + g] = min(max(-best[g], 0.0), self.group_slack[g])
        return values

    def _clearance(self, j: int, side: int, e: int, q: np.ndarray) -> float:
        """How far point `q` (at point e) is beyond `side` of obstacle j's box, its margin
        included (negative inside)."""
        ob = self.obstacles[j]
        if side == ACROSS:
            n, core = self.normals[j], ob.spread()[e]
            reach = float(ob.half[e, 0] - core[0] + np.abs(n) @ core)
            return float(n @ (q - ob.centres[e])) - reach
        axis, sign = SIDES[side]
        return float(sign * (q[axis] - ob.centres[e, axis]) - ob.half[e, axis])

    def bounds(
        self,
        values: np.ndarray,
        p_lo: np.ndarray,
        p_hi: np.ndarray,
        p: np.ndarray,
        first: int = 2,
    ) -> tuple[np.ndarray, np.ndarray]:
        """`p_lo`, `p_hi` narrowed to the sides a solution `values` (plan `p`) chose, from
        step `first` on.

        With the sides fixed, each is a bound on one coordinate (``s p >= s c + d - slack``):
        the quadratic refinement keeps to them through its column bounds. An `ACROSS` side
        is no bound on one coordinate: each point keeps within half its surplus over the side
        of where `p` has it, along each axis, which keeps the side.
        """
        lo, hi = p_lo.copy(), p_hi.copy()
        on = np.flatnonzero(values[: self.binaries] > 0.5)
        for b in on:
            g = int(self.binary_group[b])
            j = int(self.group_obstacle[g])
            ob = self.obstacles[j]
            ends = range(int(self.group_first[g]), int(self.group_last[g]) + 1)
            slack = float(values[self.binaries + g])
            if int(self.binary_side[b]) == ACROSS:
                n = self.normals[j]
                for e in ends:
                    if e < first:
                        continue
                    surplus = max(self._clearance(j, ACROSS, e, p[e]) + slack, 0.0)
                    for axis in (0, 1):
                        if n[axis] == 0.0:
                            continue
                        give = surplus / (2.0 * abs(n[axis]))
                        if n[axis] > 0:
                            lo[e, axis] = min(max(lo[e, axis], p[e, axis] - give), hi[e, axis])
                        else:
                            hi[e, axis] = max(min(hi[e, axis], p[e, axis] + give), lo[e, axis])
                continue
            axis, sign = SIDES[int(self.binary_side[b])]
            for e in ends:
                if e < first:
                    continue
                reach = ob.half[e, axis] - slack
                if sign > 0:
                    lo[e, axis] = min(max(lo[e, axis], ob.centres[e, axis] + reach), hi[e, axis])
                else:
                    hi[e, axis] = max(min(hi[e, axis], ob.centres[e, axis] - reach), lo[e, axis])
        return lo, hi


def spans(n_steps: int, dt: float) -> list[tuple[int, int]]:
    """Groups of points ``(first, last)`` that keep to one side, covering points 1..`n_steps`.

    Consecutive groups share a point (the side switches there, so that point holds both). They
    grow along the horizon (`SPAN_S`): fine where the plan is about to be carried out, coarse
    where it will be planned again anyway. One side for several steps is stricter than one per
    step (a group's points keep to one half-plane), but each group costs up to four binaries
    and HiGHS's time grows with them: on a crossing, one group per step took 2-3 times as long.
    """
    out: list[tuple[int, int]] = []
    k, length_s = 1, SPAN_S
    while k < n_steps:
        size = max(1, round(length_s / dt))
        out.append((k, min(k + size, n_steps)))
        k += size
        if len(out) % 2 == 0:
            length_s += SPAN_S
    return out


def build_separation(
    obstacles: Sequence[Obstacle],
    p_lo: np.ndarray,
    p_hi: np.ndarray,
    spans: Sequence[tuple[int, int]] | None = None,
    *,
    across: bool = True,
) -> Separation:
    """The rows keeping the plan clear of `obstacles` from point 1 to point N.

    `p_lo`, `p_hi` (``(N+1, 2)``) bound where each p[k] can be; they give each row its M and
    decide which groups and sides need a binary at all. `spans` are the groups of points that
    keep to one side (default: each step k, points k and k+1, for k = 1..N-1). p[1] is fixed
    by the measured state (lower = upper bound): a side it breaks cannot be chosen for the
    first group, unless it breaks the hard part of all four. Then, if the robots are in
    contact, that robot's whole square is soft, so the plan gets away from it as fast as it
    can; if not (p[1] is off on a diagonal, where the square reaches beyond the disc), the
    robot gets an `ACROSS` side, the half-plane through p[1] across the line from the box its
    centre may be in: any plan point at least ``r_i + r_j`` beyond it is out of contact, and
    p[1] is. (Softening the whole square there let a plan into contact: 80 MPC robots on the
    fleet scenario, 0.798 m apart, radii 0.4.) Without `across`, such a robot's square is
    soft too: one side across is stricter than the disc (a robot sliding round the other
    cannot keep to it), so a solve it makes infeasible is tried again so
    (`crowd.solve_clear`) rather than braking, which may run into the other robot.
    """
    n_steps = len(p_lo) - 1
    g_ob: list[int] = []
    g_first: list[int] = []
    g_last: list[int] = []
    g_soft: list[float] = []
    b_group: list[int] = []
    b_side: list[int] = []
    rows: list[tuple[int, float, int, float, int, float, float]] = []
    normals = np.zeros((len(obstacles), 2))
    infeasible = False
    fixed = n_steps >= 1 and bool(np.all(p_lo[1] == p_hi[1]))
    for j, ob in enumerate(obstacles):
        c, h = ob.centres, ob.half
        # Per point e and side s: the least and greatest value of the side's left-hand side
        # (s * p[axis], or n . p across), and the threshold.
        low = np.empty((n_steps + 1, len(SIDES) + 1))
        high = np.empty_like(low)
        thr = np.full_like(low, np.inf)
        for s, (axis, sign) in enumerate(SIDES):
            if sign > 0:
                low[:, s], high[:, s] = p_lo[:, axis], p_hi[:, axis]
            else:
                low[:, s], high[:, s] = -p_hi[:, axis], -p_lo[:, axis]
            thr[:, s] = sign * c[:, axis] + h[:, axis]
        low[:, ACROSS] = high[:, ACROSS] = -np.inf  # (no such side unless set below)
        soft = ob.margin
        if fixed and np.all(np.abs(p_lo[1] - c[1]) < h[1] - ob.margin - _TOL):
            n = _across(p_lo[1], ob) if across else None
            if n is None:
                # In contact at the fixed p[1]: no plan keeps the hard part, so all of the
                # square is soft: the plan gets out as fast as it can instead of giving up
                # (an infeasible solve only brakes).
                soft = float(np.max(h))
            else:
                normals[j] = n
                core = ob.spread()
                low[:, ACROSS] = np.minimum(p_lo * n, p_hi * n).sum(axis=1)
                high[:, ACROSS] = np.maximum(p_lo * n, p_hi * n).sum(axis=1)
                thr[:, ACROSS] = c @ n + h[:, 0] - core[:, 0] + core @ np.abs(n)
        holds = low >= thr - _TOL  # the side holds wherever p[e] can be
        possible = high >= thr - soft - _TOL  # the side can hold (its hard part)
        if spans is None:
            spans = [(k, k + 1) for k in range(1, n_steps)]
        for k, last in spans:
            ends = tuple(range(k, last + 1))
            if np.any(holds[list(ends)].all(axis=0)):
                continue  # one side holds at every end, whatever the plan: nothing to decide
            sides = np.flatnonzero(possible[list(ends)].all(axis=0))
            if len(sides) == 0:
                infeasible = True
                continue
            g = len(g_first)
            g_ob.append(j)
            g_soft.append(soft)
            g_first.append(ends[0])
            g_last.append(ends[-1])
            for s in sides:
                b = len(b_group)
                b_group.append(g)
                b_side.append(int(s))
                for e in ends:
                    if holds[e, s]:
                        continue
                    big_m = float(thr[e, s] - low[e, s])
                    if s == ACROSS:
                        first_term = (2 * e, float(normals[j, 0]))
                        second_term = (2 * e + 1, float(normals[j, 1]))
                    else:
                        axis, sign = SIDES[int(s)]
                        first_term, second_term = (2 * e + axis, float(sign)), (-1, 0.0)
                    lo = float(thr[e, s]) - big_m
                    rows.append((*first_term, b, big_m, *second_term, lo))
    arr = np.array(rows, dtype=float).reshape(-1, 7)
    return Separation(
        obstacles=tuple(obstacles),
        group_obstacle=np.array(g_ob, dtype=np.int64),
        group_first=np.array(g_first, dtype=np.int64),
        group_last=np.array(g_last, dtype=np.int64),
        group_slack=np.array(g_soft, dtype=float),
        binary_group=np.array(b_group, dtype=np.int64),
        binary_side=np.array(b_side, dtype=np.int64),
        row_point=arr[:, 0].astype(np.int64),
        row_coef=arr[:, 1],
        row_point2=arr[:, 4].astype(np.int64),
        row_coef2=arr[:, 5],
        row_binary=arr[:, 2].astype(np.int64),
        row_big_m=arr[:, 3],
        row_lo=arr[:, 6],
        infeasible=infeasible,
        normals=normals,
    )


def _across(q: np.ndarray, ob: Obstacle) -> np.ndarray | None:
    """The unit normal, pointing to `q` (p[1]), of the `ACROSS` side of `ob` at point 1 (the
    other robot's centre may be anywhere in its core box; contact is a distance, not a box):
    None if `q` is in contact, closer than ``r_i + r_j`` to that box."""
    core = ob.spread()[1]
    contact = float(ob.half[1, 0] - ob.margin - core[0])
    off = q - ob.centres[1]
    out = np.maximum(np.abs(off) - core, 0.0)
    gap = float(np.hypot(out[0], out[1]))
    if gap < contact - _TOL or gap == 0.0:
        return None
    return np.sign(off) * out / gap
