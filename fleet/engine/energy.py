"""Energy: each robot's battery, the chargers, and the charging policy's decisions.

With a ``[battery]`` table every robot carries a battery (`fleet.scenario.BatteryConfig`). At
each of a robot's ticks `Energy.tick` books the step just taken: ``drive_wh_per_m`` per metre
driven, ``print_w`` over the time its job printed in the step and ``idle_w`` over the whole
step; a robot standing at its charger gains ``charge_w`` over the step (up to the capacity).
A battery that runs flat strands its robot: it is braked where it is for the rest of the run
(`RobotState.faulted`, so nothing asks it to move or gives it jobs), its jobs are handed back
and ``stranded`` is counted; a charging policy should never let that happen.

Then the charging policy (a ``fleet.charging`` plugin, `fleet.plugins.ChargingPolicy`) is asked
about the robot: a robot that should charge takes no new job (`Dispatch.off_duty`) and, once it
has none, reserves its charger (one robot per charger) and drives there as it would drive home
(`RobotState.charger_at`, the goal `fleet.engine.makeway.MakeWay.goal_of` gives a robot without
a job); at rest on it, it charges (`RobotState.charging`) until the policy lets it leave or, if
the policy lets it work meanwhile, a job is given to it. ``charge_start`` and ``charge_end``
(and ``stranded``) go to events.csv with the charger as the station.

Nothing here draws random numbers, and a scenario without ``[battery]`` builds no `Energy`: its
runs are bit-identical to those of a build without batteries.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import simpy

from fleet.engine.dispatch import Dispatch
from fleet.engine.motion import RobotState, at_rest_near
from fleet.engine.recorder import Recorder, write_rows
from fleet.errors import ScenarioError
from fleet.floor import Floor
from fleet.plugins import BatteryStatus, Charger, ChargingPolicy
from fleet.plugins.robot import brake_input
from fleet.scenario import BatteryConfig

__all__ = ["Energy", "Cell", "CHARGER_REACH_M", "BATTERY_SAMPLE_S", "BATTERY_CSV"]

log = logging.getLogger("fleet.engine")

#: A robot at rest this close (m) to its charger stands at it and charges.
CHARGER_REACH_M = 0.25
#: battery.csv keeps each robot's charge at least this often (s), and at every change of state.
BATTERY_SAMPLE_S = 10.0
#: The run file of charge levels the replay reads.
BATTERY_CSV = "battery.csv"


@dataclass(slots=True)
class Cell:
    """One robot's battery and what it went through."""

    level_wh: float
    min_wh: float
    used_wh: float = 0.0
    charged_wh: float = 0.0
    driven_m: float = 0.0
    printing_s: float = 0.0
    charging_s: float = 0.0
    charges: int = 0
    stranded_s: float | None = None
    #: The charger the policy sent it to (it takes no new job), reserved once it has no job.
    due: str | None = None
    reserved: bool = False
    since_s: float = 0.0
    last_x: float = 0.0
    last_y: float = 0.0
    sampled_s: float = -math.inf


class Energy:
    """Keeps every robot's battery, asks the charging policy, sends robots to the chargers."""

    def __init__(
        self,
        env: simpy.Environment,
        battery: BatteryConfig,
        source: str,
        floor: Floor,
        robots: Mapping[str, RobotState],
        recorder: Recorder,
        dispatch: Dispatch,
        policy: ChargingPolicy,
        policy_name: str,
    ) -> None:
        self.env = env
        self.battery = battery
        self.robots = robots
        self.recorder = recorder
        self.dispatch = dispatch
        self.policy = policy
        self.policy_name = policy_name
        self.chargers = {s.name: (s.x, s.y) for s in floor.spec.stations if s.kind == "charger"}
        if not self.chargers:
            raise ScenarioError(
                source,
                "battery",
                "[battery]",
                f'the map {floor.source} has no charger: add stations of kind = "charger"',
            )
        #: The robot holding each charger (heading for it or standing at it), None: free.
        self.occupant: dict[str, str | None] = dict.fromkeys(self.chargers)
        start = battery.capacity_wh * battery.initial_share
        self.cells = {rid: Cell(start, start, last_x=r.x, last_y=r.y) for rid, r in robots.items()}
        #: (t, robot, charge share, state) rows of battery.csv.
        self.samples: list[tuple[float, str, float, str]] = []

    # -- each tick ------------------------------------------------------------------------------
    def tick(self, robot: RobotState) -> None:
        """Book the step `robot` just took, then let the policy decide (at its tick)."""
        cell = self.cells[robot.id]
        t = self.env.now
        if robot.tick > 0:
            self._book(robot, cell, t)
        if cell.stranded_s is None:
            if cell.level_wh <= 0.0:
                self._strand(robot, cell, t)
            else:
                self._decide(robot, cell, t)
        if t >= cell.sampled_s + BATTERY_SAMPLE_S - 1e-9:
            self._sample(robot, cell, t)

    def hold(self, robot: RobotState) -> None:
        """After the bus round: a robot given a job at its charger leaves it now (the policy let
        it work); a stranded robot brakes, whatever its controller commanded, and shows no plan
        (its neighbours take it to stay where it is)."""
        cell = self.cells[robot.id]
        if cell.reserved and robot.job is not None:
            self._release(robot, cell, self.env.now, "job")
        if cell.stranded_s is not None:
            spec = robot.spec
            robot.ax, robot.ay = brake_input(robot.vx, robot.vy, spec.period, spec.a_max)
            robot.plan = robot.thinned_plan = ()

    def _book(self, robot: RobotState, cell: Cell, t: float) -> None:
        b = self.battery
        dt = robot.spec.period
        step_m = math.hypot(robot.x - cell.last_x, robot.y - cell.last_y)
        cell.last_x, cell.last_y = robot.x, robot.y
        printing = 0.0
        rec = robot.job
        if rec is not None and rec.print_start_s is not None and rec.print_end_s is not None:
            printing = max(0.0, min(t, rec.print_end_s) - max(t - dt, rec.print_start_s))
        used = b.drive_wh_per_m * step_m + (b.print_w * printing + b.idle_w * dt) / 3600.0
        gained = 0.0
        if robot.charging and robot.job is None:  # a job given ends the charge at once
            gained = min(b.charge_w * dt / 3600.0, b.capacity_wh - cell.level_wh + used)
            cell.charging_s += dt
        cell.driven_m += step_m
        cell.printing_s += printing
        cell.used_wh += used
        cell.charged_wh += gained
        cell.level_wh = max(cell.level_wh - used + gained, 0.0)
        cell.min_wh = min(cell.min_wh, cell.level_wh)

    # -- the policy -----------------------------------------------------------------------------
    def status(self, robot: RobotState) -> BatteryStatus:
        """`robot`'s battery as the charging policy sees it now."""
        b = self.battery
        cell = self.cells[robot.id]
        return BatteryStatus(
            robot=robot.id,
            t=self.env.now,
            x=robot.x,
            y=robot.y,
            charge=cell.level_wh / b.capacity_wh,
            capacity_wh=b.capacity_wh,
            has_job=robot.job is not None or bool(robot.queue),
            charger=cell.due if cell.reserved else None,
            charging=robot.charging,
            chargers=tuple(
                Charger(n, x, y, self.occupant[n]) for n, (x, y) in self.chargers.items()
            ),
            drive_wh_per_m=b.drive_wh_per_m,
            print_w=b.print_w,
            idle_w=b.idle_w,
            charge_w=b.charge_w,
        )

    def _decide(self, robot: RobotState, cell: Cell, t: float) -> None:
        if cell.reserved:
            if robot.job is not None:
                self._release(robot, cell, t, "job")  # the policy let it work: a job came
                return
            status = self.status(robot)
            if self.policy.leave(status):
                self._release(robot, cell, t, "done")
                return
            self._set_off_duty(robot, not self.policy.takes_jobs(status))
            target = self.chargers[cell.due]  # type: ignore[index]
            if robot.charging and math.hypot(robot.x - target[0], robot.y - target[1]) > (
                CHARGER_REACH_M
            ):
                robot.charging = False  # moved off (making way): the charge pauses
                self.recorder.event(t, "charge_end", "", robot.id, cell.due or "")
                self._sample(robot, cell, t)
            if not robot.charging and at_rest_near(robot, target, CHARGER_REACH_M):
                robot.charging = True
                cell.charges += 1
                self.recorder.event(t, "charge_start", "", robot.id, cell.due or "")
                self._sample(robot, cell, t)
            return
        choice = self.policy.go_charge(self.status(robot))
        if choice is not None and choice not in self.chargers:
            self.recorder.stats["charger_refused"] += 1
            log.warning("charging policy named no charger of the map: %r; ignored", choice)
            choice = None
        cell.due = choice
        self._set_off_duty(robot, choice is not None)
        if choice is None or robot.job is not None or robot.queue:
            return  # carry on, or finish the job first
        if self.occupant[choice] not in (None, robot.id):
            return  # taken: wait for it (or another) off duty
        self.occupant[choice] = robot.id
        cell.reserved, cell.since_s = True, t
        robot.charger_at = self.chargers[choice]
        self.recorder.event(t, "charge_go", "", robot.id, choice)

    def _release(self, robot: RobotState, cell: Cell, t: float, why: str) -> None:
        """Free `robot`'s charger: it leaves (done charging, or a job came)."""
        name = cell.due or ""
        if robot.charging:
            self.recorder.event(t, "charge_end", "", robot.id, name)
        self.occupant[name] = None
        robot.charging = False
        robot.charger_at = None
        cell.due, cell.reserved = None, False
        self._set_off_duty(robot, False)
        self._sample(robot, cell, t)
        if why == "done":
            self.dispatch.request()  # back on duty: it may take a waiting job

    def _set_off_duty(self, robot: RobotState, off: bool) -> None:
        """Keep `robot` from new jobs (or give it back to the dispatcher)."""
        if off:
            self.dispatch.off_duty.add(robot.id)
        elif robot.id in self.dispatch.off_duty:
            self.dispatch.off_duty.discard(robot.id)
            self.dispatch.request()

    def _strand(self, robot: RobotState, cell: Cell, t: float) -> None:
        """The battery is flat: brake the robot for good and hand its jobs back."""
        cell.stranded_s = t
        if cell.reserved:
            self._release(robot, cell, t, "stranded")
        robot.faulted = True
        robot.plan = robot.thinned_plan = ()
        self.recorder.stats["stranded"] += 1
        self.recorder.event(t, "stranded", "", robot.id)
        log.warning("t = %.2f s: robot %s ran out of charge and is stranded", t, robot.id)
        for rec in [*robot.queue, *([robot.job] if robot.job else [])]:
            self.dispatch.hand_back(robot, rec, "battery empty")
        self._sample(robot, cell, t)

    def _sample(self, robot: RobotState, cell: Cell, t: float) -> None:
        state = (
            "stranded"
            if cell.stranded_s is not None
            else "charging"
            if robot.charging
            else "to_charger"
            if cell.reserved
            else "working"
        )
        share = cell.level_wh / self.battery.capacity_wh
        self.samples.append((t, robot.id, round(share, 6), state))
        cell.sampled_s = t

    # -- the end --------------------------------------------------------------------------------
    def summary(self, now: float) -> dict[str, Any]:
        """summary.json's ``battery`` object: the fleet's figures and each robot's."""
        b = self.battery
        robots = {
            rid: {
                "energy_used_wh": round(c.used_wh, 6),
                "energy_charged_wh": round(c.charged_wh, 6),
                "charge_end_share": round(c.level_wh / b.capacity_wh, 6),
                "min_charge_share": round(c.min_wh / b.capacity_wh, 6),
                "charging_s": round(c.charging_s, 6),
                "charges": c.charges,
                "driven_m": round(c.driven_m, 6),
                "printing_s": round(c.printing_s, 6),
                "stranded_s": c.stranded_s,
            }
            for rid, c in self.cells.items()
        }
        cells = self.cells.values()
        return {
            "policy": self.policy_name,
            "capacity_wh": b.capacity_wh,
            "chargers": len(self.chargers),
            "charging_s": round(sum(c.charging_s for c in cells), 6),
            "charging_share": round(sum(c.charging_s for c in cells) / (now * len(self.cells)), 6)
            if now > 0
            else 0.0,
            "energy_used_wh": round(sum(c.used_wh for c in cells), 6),
            "min_charge_share": round(min(c.min_wh for c in cells) / b.capacity_wh, 6),
            "charges": sum(c.charges for c in cells),
            "stranded": sum(c.stranded_s is not None for c in cells),
            "per_robot": robots,
        }

    def write(self, out: Path) -> None:
        """Write battery.csv: t, robot, charge (share of capacity), state."""
        rows = ((f"{t:.3f}", rid, f"{share:.6f}", state) for t, rid, share, state in self.samples)
        write_rows(Path(out) / BATTERY_CSV, ("t", "robot", "charge", "state"), rows)
