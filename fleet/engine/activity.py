"""Per-robot state accounting: how long each robot spent in each state, step by step.

Every control step ``[t, t + period)`` of every robot is given exactly one state, decided at
its tick once the step's command is known (`Activity.step`); a state lasts until the robot's
next tick with another state, and the last one until the run's end. So the seconds of a
robot's states sum to the measured window, ``[warmup_s, end)`` (the whole run without a
warm-up), for every robot. The states, first match wins:

``faulted``
    Its agent is lost or gone (`RobotState.faulted`) or it broke down (`RobotState.broken`).
``charging``
    Standing at a charger taking charge (`RobotState.charging`).
``printing_driving``
    A print is under way (`JobRecord.printing`) and the robot moves: its speed on an axis is
    above `REST_SPEED` at the tick, the step's input changes it by more than that, or it is
    turning on the spot.
``printing_at_rest``
    A print is under way and the robot does not move (at its destination, or held on the way:
    the print goes on either way, so printing counts before being held).
``blocked``
    Blocked or waiting: not printing, it has work (a job, `RobotState.goal`, or a trip to a
    charger, `RobotState.charger_at`) and is held. That is: it is stepping aside for another robot
    (`RobotState.aside`, moving there or waiting there), or it stands still farther than the
    arrival tolerance from its goal. A robot stalled in a deadlock, waiting for a way through,
    or waiting at rest short of its goal is here.
``driving_empty``
    It moves and prints nothing: to a job's station before (or after) its print, home, aside...
``idle``
    It stands still with no work: no job, wherever it stands. An idle robot waiting where it
    stepped aside, or held short of home, is idle too: it holds up nothing of its own, and
    counting it as blocked would hide the fleet's spare capacity (in a 12-robot run on
    scenarios/fleet.toml that was 16% of the robots' time).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from fleet.engine.motion import REST_SPEED, RobotState

__all__ = ["STATES", "Activity", "robot_state"]

#: The states, in the order tables and figures show them.
STATES = (
    "idle",
    "driving_empty",
    "printing_driving",
    "printing_at_rest",
    "blocked",
    "faulted",
    "charging",
)


def robot_state(robot: RobotState, t: float, tol: float) -> str:
    """The state of `robot` over its step from `t`, with its command for the step applied
    (`robot.ax`, `robot.ay`); `tol` is the arrival tolerance (m). See the module docstring."""
    if robot.faulted or robot.broken:
        return "faulted"
    if robot.charging:
        return "charging"
    reach = max(abs(robot.ax), abs(robot.ay)) * robot.spec.period
    moving = (
        max(abs(robot.vx), abs(robot.vy)) > REST_SPEED
        or reach > REST_SPEED
        or t < robot.turning_until - 1e-9
    )
    job = robot.job
    if job is not None and job.printing(t):
        return "printing_driving" if moving else "printing_at_rest"
    goal = robot.goal or robot.charger_at
    if goal is not None and robot.aside is not None:
        return "blocked"
    if moving:
        return "driving_empty"
    if goal is not None and math.hypot(goal[0] - robot.x, goal[1] - robot.y) > tol:
        return "blocked"
    return "idle"


class Activity:
    """Seconds each robot spent in each state over the measured window ``[start_s, end)``.

    Parameters
    ----------
    robots:
        The run's robots (each starts ``idle`` at t = 0, until its first tick says otherwise).
    tol:
        The arrival tolerance (m): at rest closer than this to its goal, a robot is there.
    start_s:
        The warm-up (`Scenario.warmup_s`): time before it is not counted.
    """

    def __init__(self, robots: Mapping[str, RobotState], tol: float, start_s: float = 0.0):
        self.tol = tol
        self.start_s = start_s
        self._state = dict.fromkeys(robots, "idle")
        self._since = dict.fromkeys(robots, 0.0)
        self._seconds = {rid: dict.fromkeys(STATES, 0.0) for rid in robots}

    def step(self, robot: RobotState, t: float) -> None:
        """Account `robot`'s step from `t` (its command for the step applied)."""
        state = robot_state(robot, t, self.tol)
        rid = robot.id
        if state != self._state[rid]:
            self._count(rid, t)
            self._state[rid], self._since[rid] = state, t

    def _count(self, rid: str, t: float) -> None:
        """Add the current state's time from its start (or the warm-up's end) to `t`."""
        since = max(self._since[rid], self.start_s)
        if t > since:
            self._seconds[rid][self._state[rid]] += t - since

    def seconds(self, end: float) -> dict[str, dict[str, float]]:
        """Per robot, the seconds in each state over ``[start_s, end)``: they sum to ``end -
        start_s`` for every robot (0 when the run ended before the warm-up did)."""
        out = {}
        for rid, secs in self._seconds.items():
            secs = dict(secs)
            since = max(self._since[rid], self.start_s)
            if end > since:
                secs[self._state[rid]] += end - since
            out[rid] = secs
        return out

    def summary(self, end: float) -> dict[str, object]:
        """summary.json's ``states`` object: the window, the fleet-wide share of each state
        (of all robots' time), and each robot's seconds and shares."""
        window = max(end - self.start_s, 0.0)
        per_robot = self.seconds(end)
        total = window * len(per_robot)
        fleet = {s: sum(r[s] for r in per_robot.values()) for s in STATES}
        return {
            "from_s": self.start_s,
            "to_s": end,
            "shares": {s: round(v / total, 6) if total > 0 else 0.0 for s, v in fleet.items()},
            "robots": {
                rid: {
                    s: {"seconds": round(v, 6), "share": round(v / window, 6) if window else 0.0}
                    for s, v in secs.items()
                }
                for rid, secs in per_robot.items()
            },
        }

    def rows(self, end: float) -> list[tuple[str, str, str, str]]:
        """``states.csv`` rows: robot, state, seconds, share (of the measured window)."""
        window = max(end - self.start_s, 0.0)
        return [
            (rid, s, f"{v:.6f}", f"{v / window:.6f}" if window else "0")
            for rid, secs in self.seconds(end).items()
            for s, v in secs.items()
        ]
