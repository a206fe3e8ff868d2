"""A follower among other robots: whether it may go on, and its way round deadlocked blockers.

`Guard.may_go` applies rules 1 and 2 of `PathFollower` to each tracking command (the stopping
check against every neighbour, yielding to higher-priority plans); `Guard.route` and
`Guard.detour_planner` apply rule 3 (plan round the blockers in sight, a `Detour` built once per
set of blockers); `Guard.keeps_going` keeps a robot at rest from setting off only to brake.
The pieces themselves are in `fleet_plugins.follower.yielding`.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import shapely
from shapely.geometry import LineString

from fleet.floor import BOUNDARY_BAND
from fleet.plugins import Command, Observation, RobotSpec
from fleet.plugins.robot import clip, neighbour_stray
from fleet_plugins.follower.track import Track
from fleet_plugins.follower.yielding import (
    Detour,
    Forecast,
    behind,
    bounds,
    braking_path,
    must_yield,
    stops_clear,
    unseen_step,
)

if TYPE_CHECKING:
    from fleet.floor import Floor
    from fleet.paths import PathPlanner

__all__ = ["Guard", "MOVED_M"]

#: Speed (m/s) over a limit below which rounding is forgiven (the safety checker's).
_SPEED_TOL = 1e-6

#: A blocker that moved further than this (m) since a detour round it found no way is looked
#: at again where it stands now.
MOVED_M = 0.1
#: Ticks ahead a robot at rest checks, before it sets off, that it could drive on.
SET_OFF_TICKS = 1


class Guard:
    """One robot's conduct towards the others.

    Parameters
    ----------
    spec:
        The robot.
    floor:
        The floor it plans on; detours cut the blockers out of it.
    margin_m:
        Gap (m) kept between footprints on top of the sum of the radii.
    yield_s:
        How far (s) beyond its braking horizon the robot looks at higher-priority plans.
    hold_steps:
        How many periods the spot where the robot would stop must stay clear.
    """

    def __init__(
        self, spec: RobotSpec, floor: Floor, margin_m: float, yield_s: float, hold_steps: int
    ) -> None:
        self.spec = spec
        self.floor = floor
        self.margin_m = margin_m
        self.yield_s = yield_s
        self.hold_steps = hold_steps
        self.detour: Detour | None = None
        self._blockers: list[tuple[str, float, float, float]] = []
        #: Whether the detour is one kept with no blockers named (`route`).
        self._kept = False
        #: Each region's per-axis limit, and the floor's slowest per axis (`stops_within_limits`).
        self._limits = np.array([r.v_max for r in floor.regions], dtype=float).reshape(-1, 2)
        self._slowest = self._limits.min(axis=0, initial=np.inf)

    # -- rules 1 and 2 ----------------------------------------------------------------------------
    def braking_after(self, obs: Observation, cmd: Command) -> list[tuple[float, float, float]]:
        """Full braking after `cmd`: the next state is fixed but for this command's velocity,
        and from there the robot brakes along its line of travel (`braking_path`)."""
        dt, a_max = self.spec.period, self.spec.a_max
        vx, vy = obs.vx + dt * clip(cmd.ax, a_max), obs.vy + dt * clip(cmd.ay, a_max)
        return braking_path(obs.t + dt, obs.x + dt * obs.vx, obs.y + dt * obs.vy, vx, vy, dt, a_max)

    def may_go(
        self, obs: Observation, track: Track, stop: list[tuple[float, float, float]], cap: float
    ) -> bool:
        """Whether the robot may send the tracking command of `track` planned at speed `cap`,
        after which it would brake along `stop` (`braking_after`; rules 1 and 2 of
        `PathFollower`); if not, it must hold."""
        spec = self.spec
        dt, a_max = spec.period, spec.a_max
        top = min(cap, spec.v_max)
        speed = min(max(abs(obs.vx), abs(obs.vy)), top)
        # The braking horizon from the top speed, plus the time to get there: the window
        # then ends at the same spot while the robot speeds up, so a robot that set off
        # never sees a conflict it could not see at rest (no creeping start-stop-start).
        own = track.ahead(obs, dt, (2.0 * top - speed) / a_max + self.yield_s)
        forecasts = [
            _braking_only(f) if f.has_plan and behind(own, f) else f
            for f in (Forecast.of(n, obs.t, dt, a_max, spec.v_max) for n in obs.neighbours)
        ]
        # Where it would stop must stay clear a while too: stopping right in the way of a
        # robot about to pass is no stop in time.
        t_stop, x_stop, y_stop = stop[-1]
        held = [(t_stop + i * dt, x_stop, y_stop) for i in range(1, self.hold_steps + 1)]
        # Routed round: waiting for them would undo the detour.
        blockers = set(obs.blockers) if self.detour is None else set(self.detour.key)
        higher = [
            f
            for f in forecasts
            if f.priority > obs.priority and f.has_plan and f.robot not in blockers
        ]
        if higher:
            box = bounds(own)
            for f in higher:
                if must_yield(own, f, spec.radius + f.radius + self.margin_m, box):
                    return False
        now = (obs.t, obs.x, obs.y)
        # Round lower-priority blockers the detour keeps what it could (less than the gap when
        # they were stuck close): hold it to that. Higher ones go first (they route round this
        # one): the robot only moves away from them while that close.
        gaps = None
        if self.detour is not None:
            gaps = {
                f.robot: min(
                    spec.radius + f.radius + self.margin_m, self.detour.clearance[f.robot] - 1e-3
                )
                for f in forecasts
                if f.robot in self.detour.clearance and f.priority < obs.priority
            }
        return stops_clear(stop + held, forecasts, spec.radius, self.margin_m, now, gaps)

    def keeps_going(
        self, obs: Observation, track: Track, cmd: Command, cap: float, gain: float
    ) -> bool:
        """Whether a robot about to set off from rest with `cmd` may, as far as it sees now,
        also drive on for the next `SET_OFF_TICKS` ticks (`may_go` ahead, each neighbour one
        step on at its velocity: that step is fixed, its next velocity is not known and kept).

        Without it a robot held at speed by rule 1 crept: it set off, was held one tick later
        (its braking path had grown), braked, dropped its reference and planned again from a
        few centimetres on, every third tick. Staying at rest with the reference kept is always
        allowed; the real check still runs at every tick.
        """
        dt, a_max = self.spec.period, self.spec.a_max
        nxt = obs
        for _ in range(SET_OFF_TICKS):
            seen = tuple(replace(n, x=n.x + dt * n.vx, y=n.y + dt * n.vy) for n in nxt.neighbours)
            nxt = replace(
                nxt,
                neighbours=seen,
                tick=nxt.tick + 1,
                t=nxt.t + dt,
                x=nxt.x + dt * nxt.vx,
                y=nxt.y + dt * nxt.vy,
                vx=nxt.vx + dt * clip(cmd.ax, a_max),
                vy=nxt.vy + dt * clip(cmd.ay, a_max),
            )
            cmd = track.command(nxt, dt=dt, a_max=a_max, gain=gain, steps=1, stride=1)
            if not self.may_go(nxt, track, self.braking_after(nxt, cmd), cap):
                return False
        return True

    def stops_inside(self, obs: Observation, stop: list[tuple[float, float, float]]) -> bool:
        """Whether braking along `stop` (`braking_after` a command) keeps the robot in the
        floor's free space. Checked before every tracking command, so braking (the robot's
        answer to everything else) can never carry it into a wall: the brake it may need next
        tick was checked this tick. Tracking alone keeps to the reference, but a brake from
        the speed of a bend's approach ran 3 cm into a wall in the floor fuzz."""
        points = [(obs.x, obs.y)] + [(x, y) for _, x, y in stop]
        if all(p == points[0] for p in points):
            return True
        return bool(self.floor.free_space_tolerant.covers(LineString(points)))

    def stops_within_limits(self, obs: Observation, stop: list[tuple[float, float, float]]) -> bool:
        """Whether braking along `stop` (`braking_after` a command) keeps to the speed limit of
        every region it enters: per axis, no step of it faster than the limit of a region whose
        core it reaches (`Floor.region_cores`, as the safety checker judges). Checked with
        `stops_inside`, for the same reason: a robot a neighbour held on a path that skirted a
        slow zone at a bend braked straight on, into the zone at 0.61 m/s where 0.33 was the
        limit (fuzz s31-0360). Steps slower than the floor's slowest limit are not measured."""
        pts = np.array([(obs.x, obs.y)] + [(x, y) for _, x, y in stop])
        speed = np.abs(np.diff(pts, axis=0)) / self.spec.period
        fast = np.flatnonzero(np.any(speed > self._slowest + _SPEED_TOL, axis=1))
        if not len(fast):
            return True
        lines = shapely.linestrings(np.stack([pts[:-1][fast], pts[1:][fast]], axis=1))
        line_i, reg_i = self.floor.tree.query(lines, predicate="intersects")
        hit = shapely.intersects(lines[line_i], self.floor.region_cores(BOUNDARY_BAND)[reg_i])
        return not np.any(speed[fast][line_i[hit]] > self._limits[reg_i[hit]] + _SPEED_TOL)

    # -- rule 3 -----------------------------------------------------------------------------------
    def route(
        self, obs: Observation, keep: bool = False, face_off: tuple[str, ...] = ()
    ) -> Detour | None:
        """The detour round this observation's blockers (those in sight), None without any.

        With `keep` (the robot drives a reference planned on the current detour) and no
        blockers named any more, the detour is kept while each of its blockers is in sight
        within `MOVED_M` of where it stood: the deadlock watch stops naming them once the
        robot has gained a little on its goal, long before it is past them, and dropping the
        detour then braked it and sent it back onto the normal route, against the same
        blocker, to wait a whole deadlock period again (fuzz s21-0312: a robot let out of a
        ring of seven parked robots gained 0.2 to 0.3 m per deadlock period, for 100 s).

        Without blockers named, `face_off` (robots at rest in its way, `in_the_way`) are
        routed round as blockers are."""
        named = obs.blockers or face_off
        if not named:
            if not (keep and self.detour is not None and self._in_place(obs)):
                self.detour = None
            self._kept = self.detour is not None
            return self.detour
        if self._kept:
            # Named again after it was kept: built anew round them where they stand now.
            self.detour, self._kept = None, False
        seen = {n.robot: n for n in obs.neighbours}
        blockers = [
            (n.robot, n.x, n.y, n.radius)
            for name in sorted(set(named))
            if (n := seen.get(name)) is not None
        ]
        if not blockers:
            self.detour = None
            return None
        key = tuple(b[0] for b in blockers)
        if self.detour is None or self.detour.key != key:
            # Once per set of blockers: cutting them out of the floor and building a planner
            # take about 0.15 to 0.25 s on the shop floor.
            self._blockers = blockers
            self.detour = self._build_detour(obs)
        return self.detour

    def in_the_way(
        self, obs: Observation, track: Track, cap: float, goal: tuple[float, float]
    ) -> tuple[str, ...]:
        """The lower-priority neighbours at rest, with no plan to move, within the gap
        (both radii, the margin and `neighbour_stray`) of the robot's way over the window it
        yields over (`may_go`), but not of its goal (there it waits its turn)."""
        spec = self.spec
        dt, a_max = spec.period, spec.a_max
        own = track.ahead(obs, dt, 2.0 * min(cap, spec.v_max) / a_max + self.yield_s)
        found = []
        for n in obs.neighbours:
            if n.priority >= obs.priority or max(abs(n.vx), abs(n.vy)) > 1e-9:
                continue
            if any(math.hypot(x - n.x, y - n.y) > MOVED_M for _, x, y in n.plan):
                continue  # about to leave
            gap = spec.radius + n.radius + self.margin_m + neighbour_stray(n, spec)
            if math.hypot(goal[0] - n.x, goal[1] - n.y) <= gap:
                continue
            if any(math.hypot(x - n.x, y - n.y) <= gap for _, x, y in own):
                found.append(n.robot)
        return tuple(sorted(found))

    def where(self, obs: Observation, names: tuple[str, ...]) -> dict[str, tuple[float, float]]:
        """Where each of the neighbours `names` in sight stands."""
        return {n.robot: (n.x, n.y) for n in obs.neighbours if n.robot in names}

    def same_places(
        self, obs: Observation, names: tuple[str, ...], places: dict[str, tuple[float, float]]
    ) -> bool:
        """Whether each of `names` stands within `MOVED_M` of its place in `places`."""
        now = self.where(obs, names)
        return all(
            name in places and name in now and math.dist(now[name], places[name]) <= MOVED_M
            for name in names
        )

    def in_place(self, obs: Observation, names: tuple[str, ...]) -> bool:
        """Whether each of `names` (robots routed round) is in sight within `MOVED_M` of where
        it stood when the current detour was built (no detour round them: True)."""
        if self.detour is None or self.detour.key != names:
            return True
        return self._in_place(obs)

    def _in_place(self, obs: Observation) -> bool:
        """Whether every blocker of the current detour is in sight within `MOVED_M` of where
        it stood when the detour was built."""
        places = {name: (x, y) for name, x, y, _ in self._blockers}
        return self.same_places(obs, tuple(places), places)

    def blockers_moved(self, obs: Observation) -> bool:
        """Whether a blocker of the current detour now stands more than `MOVED_M` from where
        it stood when the detour was built: a detour that found no way may find one now (the
        blocker stepped aside), and the robot must look again instead of holding for good."""
        if self.detour is None:
            return False
        seen = {n.robot: n for n in obs.neighbours}
        for name, x, y, _ in self._blockers:
            n = seen.get(name)
            if n is not None and math.hypot(n.x - x, n.y - y) > MOVED_M:
                return True
        return False

    def rebuild(self, obs: Observation) -> Detour | None:
        """The detour built anew round the blockers where they stand now."""
        self.detour = None
        return self.route(obs)

    def detour_planner(self, obs: Observation, cap: float) -> PathPlanner | None:
        """The detour's planner at speed `cap`, rebuilt if the robot stands in a blocker's
        obstacle (it came closer than the margin since the detour was built)."""
        detour = self.detour
        assert detour is not None
        floor = detour.floor
        if floor is not None and not floor.is_free(obs.x, obs.y):
            detour = self.detour = self._build_detour(obs)
        return detour.planner(min(cap, self.spec.v_max))

    def _build_detour(self, obs: Observation) -> Detour:
        spec = self.spec
        # Past the gap by the drift a parked robot is granted (`Forecast`), so that the
        # stopping check lets the robot drive the detour past a blocker that sends no plan.
        names = {b[0] for b in self._blockers}
        drift = max(
            [neighbour_stray(n, spec) for n in obs.neighbours if n.robot in names],
            default=unseen_step(spec.period, spec.a_max, spec.v_max),
        )
        return Detour.build(
            self.floor,
            self._blockers,
            spec.radius,
            self.margin_m + drift,
            (obs.x, obs.y),
            spec.a_max,
        )


def _braking_only(f: Forecast) -> Forecast:
    """`f`, the forecast of a neighbour behind the robot (`behind`), cut to its braking from
    now. Such a neighbour follows the robot and keeps its own braking clear of the robot's
    forecast (rule 1; the lead covers this tick), so where its plan would take it is not the
    robot's to keep clear of, and braking for it would only stop the robot in its way.
    Counting that plan held robots in a row for good: the one ahead could not stop where the
    plan of the one behind would pass, the one behind could not come closer, and all set off
    again in the same tick only to brake (fuzz s21-0998, s21-0827: 2 cm/s for 100 s)."""
    return replace(f, samples=f.brake, box=bounds(f.brake))
