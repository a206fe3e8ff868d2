"""The recorder: turns what happened in a run into the run directory.

During the run it keeps every sample, event, planned horizon, count and solve report; after it,
`fleet.engine.summary` makes summary.json's object and the CSV rows from them, and the recorder
writes the files.

Output contract (extend it, never break it):

- ``summary.json``: scenario, map, seed, controller, dispatcher, robots, sim_time_s,
  complete (false when the run was stopped before its duration, e.g. by Ctrl-C), wall_time_s,
  jobs {released, completed, good, defective, late, ...}, throughput_per_h, throughput_good_per_h,
  mean_lead_time_s, distance_m, violations {obstacle, speed_zone, print_speed, collision},
  quality {prints, outcomes {good, defective, failed}, max_error_mm},
  solver {steps, median_ms, p95_ms, max_ms, fallbacks, termination {outcome: count},
  time_limit_hits, ...}
  (solve statistics reported by optimising controllers), per_robot [{id, distance_m,
  jobs_completed, turned_rad, radius_m, goal_commands, goal_errors (commands sent while it had
  somewhere to go, and how many were errors)}], stuck_robots [{robot, reason}] (robots whose
  every such command was an error: they could never move; `fleet run` exits 1), digest (sha256
  of the trajectories: the same seed gives the same digest), handbacks {count, by_reason
  {reason: count}, scrapped_print_s, scrapped_parts} (attempts handed back, as in
  attempts.csv), deadlocks (robots the deadlock watch found stalled), faults {agents_lost,
  agents_left, robots_orphaned, robots_rejoined}, jobs.attempts; for scripted (point-to-point)
  runs also arrivals {robot: when it reached the destination of its last trip, s, or null};
  breakdowns {configured, mtbf_s, mttr_s, availability, breakdowns, repaired, repair_s,
  mean_repair_s, jobs_handed_back, print_scrapped_s, per_robot [{id, availability, breakdowns,
  repair_s, jobs_handed_back}]} (`fleet.engine.breakdowns`; over the whole run, warm-up
  included; availability 1 without breakdowns).
  KPIs over time (`fleet.engine.kpis`, `fleet.engine.activity`): warmup_s (the scenario's;
  throughput_per_h, throughput_good_per_h, mean_lead_time_s and everything below leave out
  [0, warmup_s); the jobs counts cover the whole run), assign_wait_s and lead_time_s {n, mean,
  p50, p95, max} (release to first assignment, counted when the assignment is at or after
  warmup_s; release to delivery, counted when the delivery is), queue_mean, wip_mean
  (time-weighted over [warmup_s, end)), queue_max, wip_max (over the run),
  suggested_warmup_s and suggested_warmup_at_limit (MSER-5 on the WIP, `fleet.engine.warmup`),
  states {from_s, to_s, shares {state: fleet-wide share}, robots {id: {state: {seconds,
  share}}}} with the states idle, driving_empty, printing_driving, printing_at_rest, blocked,
  faulted, charging: each robot's seconds sum to to_s - from_s (the run's length less the
  warm-up).
- ``trajectories.csv``: t, robot, x, y, vx, vy, region, v_zone (one row per robot per tick).
- ``events.csv``: t, event, job, robot, station (released, assigned, started, turn, passed,
  arrived, delivered, and deadlock, make_way, handed_back, reoffered, failed, fault, rejoined,
  breakdown, repaired; with ``[battery]`` also charge_go, charge_start, charge_end, stranded,
  with the charger as the station).
- ``jobs.csv``: id, part, robot, released_s, started_s, finished_s, delivered_s,
  predicted_error_mm, passed, due_s, outcome: one row per job (empty: not happened, or nothing
  printed); started/finished are the print's start and end (for a job with nothing to print,
  started is when the robot set off). summary quality counts every print judged, delivered or
  not; jobs.good/defective count delivered jobs only.
- ``caps.csv``: robot, job, kind, start_s, end_s, cap, attempt: the print-task speed caps each
  robot was under (absolute seconds; written when any job prints), in every attempt at a job.
- ``tasks.csv``: robot, job, kind, start_s, end_s, attempt: every print task, capped or not, on
  the clock, in every attempt at a job (``attempt`` as in attempts.csv), cut where the attempt
  ended: a handed-back attempt's tasks end at the hand-back.
- ``attempts.csv``: job, attempt, robot, assigned_s, started_s, print_start_s, ended_s, result,
  reason, printed_s, scrapped_s: one row per robot's try at a job (attempt 1, 2... of that
  job), from its assignment to how it ended: result delivered, handed_back (with the reason
  given to the hand-back: blocked, its agent lost or gone, a breakdown...), failed (handed
  back once too often: the job is given up) or unfinished (under way at the run's end, ended_s
  empty); printed_s is the print time done in the attempt, scrapped_s that of a handed-back
  attempt (its part is scrapped; the next attempt prints anew).
- ``plans.csv``: t_sent, robot, k, t, x, y: the planned horizons controllers sent (sample k of
  the plan sent at t_sent; a plan holds until the robot's next), at most one per robot per
  second, samples at least half a second apart.
- ``violations.csv``: the first violations in full, when there are any.
- ``states.csv``: robot, state, seconds, share: each robot's time in each state over
  [warmup_s, end) (summary.json ``states``; defined in `fleet.engine.activity`).
- ``wip.csv``: t, queue, wip: jobs released and not assigned, and released and neither
  delivered nor failed, from t = 0 and at every time either changes (`fleet.engine.kpis`).
- ``battery.csv`` (with ``[battery]``): t, robot, charge (share of capacity), state (working,
  to_charger, charging, stranded), at least every 10 s per robot and at every change of state;
  summary.json then has ``battery`` (`fleet.engine.energy.Energy.summary`).
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fleet.floor import Floor
from fleet.plugins import SolveReport

__all__ = [
    "Event",
    "Recorder",
    "Trajectory",
    "PLAN_RECORD_S",
    "PLAN_SAMPLE_S",
    "RUN_FILES",
    "ATTEMPT_COLUMNS",
    "JOB_COLUMNS",
    "write_rows",
]

#: Every file a run writes into its run directory (caps.csv and violations.csv only when
#: needed; states.csv and wip.csv come from `fleet.engine.kpis`, written by `World.write`;
#: battery.csv, with ``[battery]``, from `fleet.engine.energy`).
RUN_FILES = (
    "summary.json",
    "trajectories.csv",
    "events.csv",
    "jobs.csv",
    "tasks.csv",
    "plans.csv",
    "caps.csv",
    "attempts.csv",
    "violations.csv",
    "states.csv",
    "wip.csv",
    "battery.csv",
)

#: Shortest time (s) between two planned horizons the recorder keeps for one robot.
PLAN_RECORD_S = 1.0
#: Shortest time (s) between two samples of a kept plan (its first and last are always kept).
PLAN_SAMPLE_S = 0.5


@dataclass(frozen=True, slots=True)
class Event:
    t: float
    event: str  # released, assigned, started, delivered
    job: str
    robot: str = ""
    station: str = ""


@dataclass
class Trajectory:
    """One robot's samples, appended tick by tick (lists: cheaper than growing arrays)."""

    t: list[float] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)
    vx: list[float] = field(default_factory=list)
    vy: list[float] = field(default_factory=list)

    def append(self, t: float, x: float, y: float, vx: float, vy: float) -> None:
        self.t.append(t)
        self.x.append(x)
        self.y.append(y)
        self.vx.append(vx)
        self.vy.append(vy)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t, xy, v) as float arrays."""
        return (
            np.asarray(self.t, dtype=float),
            np.column_stack([self.x, self.y]).astype(float).reshape(-1, 2),
            np.column_stack([self.vx, self.vy]).astype(float).reshape(-1, 2),
        )

    def distance(self) -> float:
        if len(self.x) < 2:
            return 0.0
        return float(np.sum(np.hypot(np.diff(self.x), np.diff(self.y))))


class Recorder:
    """Collects samples, events, counts and solve reports during a run; writes the run
    directory afterwards."""

    def __init__(self, robots: list[str]) -> None:
        self.trajectories: dict[str, Trajectory] = {r: Trajectory() for r in robots}
        self.events: list[Event] = []
        #: Planned horizons as sent: (t_sent, robot, ((t, x, y), ...)), at most one per robot
        #: per `PLAN_RECORD_S`.
        self.plans: list[tuple[float, str, tuple[tuple[float, float, float], ...]]] = []
        self._plan_kept: dict[str, float] = {}
        #: What the engine counted (commands missing or clipped, bids, deadlocks, hand-backs...):
        #: summary.json's ``engine`` object.
        self.stats: dict[str, int] = defaultdict(int)
        #: The solve reports controllers attached to their commands, in the order they came.
        self.solves: list[SolveReport] = []
        #: Faults seen on the bus: agents lost or gone, robots orphaned, agents that rejoined.
        self.faults: dict[str, int] = dict.fromkeys(
            ("agents_lost", "agents_left", "robots_orphaned", "robots_rejoined"), 0
        )

    def sample(self, robot: str, t: float, x: float, y: float, vx: float, vy: float) -> None:
        self.trajectories[robot].append(t, x, y, vx, vy)

    def event(self, t: float, event: str, job: str, robot: str = "", station: str = "") -> None:
        self.events.append(Event(t, event, job, robot, station))

    def plan(self, robot: str, t: float, samples: tuple[tuple[float, float, float], ...]) -> None:
        """Keep a robot's planned horizon sent at `t`, unless one was kept less than
        `PLAN_RECORD_S` ago (an MPC sends one every tick; the replay needs about one a second)."""
        if t - self._plan_kept.get(robot, -math.inf) >= PLAN_RECORD_S - 1e-9:
            self._plan_kept[robot] = t
            # An MPC horizon has a sample per period: a few per second are enough to draw it.
            kept, last = [samples[0]], samples[0][0]
            for s in samples[1:-1]:
                if s[0] - last >= PLAN_SAMPLE_S - 1e-9:
                    kept.append(s)
                    last = s[0]
            if len(samples) > 1:
                kept.append(samples[-1])
            self.plans.append((t, robot, tuple(kept)))

    def digest(self) -> str:
        """sha256 over every robot's exact samples, robots in name order."""
        h = hashlib.sha256()
        for robot in sorted(self.trajectories):
            tr = self.trajectories[robot]
            h.update(robot.encode())
            for column in (tr.t, tr.x, tr.y, tr.vx, tr.vy):
                h.update(np.asarray(column, dtype="<f8").tobytes())
        return h.hexdigest()

    # -- writing ------------------------------------------------------------------------------
    def write(
        self,
        out_dir: Path,
        summary: dict[str, Any],
        floor: Floor,
        violations: list,
        caps: list[tuple] | None = None,
        jobs: list[dict[str, Any]] | None = None,
        tasks: list[tuple] | None = None,
        attempts: list[dict[str, Any]] | None = None,
    ) -> None:
        """Write the run directory; `caps` rows are (robot, job, kind, start_s, end_s, cap,
        attempt), `jobs` rows are `summary.job_rows` dicts, `tasks` rows (robot, job, kind,
        start_s, end_s, attempt) every print task on the clock, `attempts` rows
        `summary.attempt_rows` dicts (attempts.csv, written when given). Rows without their
        attempt (the columns before it only) are the first attempt's. ``plans.csv`` holds the
        kept planned horizons."""
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "summary.json").write_text(
            json.dumps(summary, indent=2) + "\n", encoding="utf-8"
        )
        self._write_trajectories(out_dir / "trajectories.csv", floor)
        with open(out_dir / "events.csv", "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["t", "event", "job", "robot", "station"])
            for e in self.events:
                w.writerow([f"{e.t:.6f}", e.event, e.job, e.robot, e.station])
        if jobs is not None:
            _write_jobs(out_dir / "jobs.csv", jobs)
        if attempts is not None:
            _write_dicts(out_dir / "attempts.csv", ATTEMPT_COLUMNS, attempts)
        write_rows(
            out_dir / "tasks.csv",
            ("robot", "job", "kind", "start_s", "end_s", "attempt"),
            [
                (r, j, k, f"{a:.6f}", f"{b:.6f}", n)
                for r, j, k, a, b, n in map(_numbered(5), tasks or ())
            ],
        )
        write_rows(
            out_dir / "plans.csv",
            ("t_sent", "robot", "k", "t", "x", "y"),
            [
                (f"{sent:.3f}", robot, k, f"{t:.3f}", f"{x:.4f}", f"{y:.4f}")
                for sent, robot, samples in self.plans
                for k, (t, x, y) in enumerate(samples)
            ],
        )
        cpath = out_dir / "caps.csv"
        if caps:
            with open(cpath, "w", newline="", encoding="utf-8") as fh:
                w = csv.writer(fh)
                w.writerow(["robot", "job", "kind", "start_s", "end_s", "cap", "attempt"])
                for robot, job, kind, start, end, cap, n in map(_numbered(6), caps):
                    w.writerow([robot, job, kind, f"{start:.6f}", f"{end:.6f}", f"{cap:g}", n])
        elif cpath.exists():
            cpath.unlink()
        vpath = out_dir / "violations.csv"
        if violations:
            with open(vpath, "w", newline="", encoding="utf-8") as fh:
                w = csv.writer(fh)
                w.writerow(["t", "kind", "robot", "x", "y", "detail"])
                for v in violations:
                    w.writerow(
                        [f"{v.t:.6f}", v.kind, v.robot, f"{v.x:.6f}", f"{v.y:.6f}", v.detail]
                    )
        elif vpath.exists():
            vpath.unlink()

    def _write_trajectories(self, path: Path, floor: Floor) -> None:
        speed = np.array([min(r.v_max) for r in floor.regions] + [0.0])
        with open(path, "w", newline="", encoding="utf-8") as fh:
            fh.write("t,robot,x,y,vx,vy,region,v_zone\n")
            for robot in sorted(self.trajectories):
                t, xy, v = self.trajectories[robot].arrays()
                if len(t) == 0:
                    continue
                region = floor.locate_many(xy)
                v_zone = speed[region]  # index -1 (outside) picks the trailing 0.0
                fh.writelines(
                    f"{t[i]:.3f},{robot},{xy[i, 0]:.6f},{xy[i, 1]:.6f},{v[i, 0]:.6f},"
                    f"{v[i, 1]:.6f},{region[i]},{v_zone[i]:g}\n"
                    for i in range(len(t))
                )


#: Columns of attempts.csv, in order (rows: `fleet.engine.summary.attempt_rows`).
ATTEMPT_COLUMNS = (
    "job",
    "attempt",
    "robot",
    "assigned_s",
    "started_s",
    "print_start_s",
    "ended_s",
    "result",
    "reason",
    "printed_s",
    "scrapped_s",
)

#: Columns of jobs.csv, in order (the issue's list first, then extras).
JOB_COLUMNS = (
    "id",
    "part",
    "robot",
    "released_s",
    "started_s",
    "finished_s",
    "delivered_s",
    "predicted_error_mm",
    "passed",
    "due_s",
    "outcome",
)


def write_rows(path: Path, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
    """A CSV file at `path` with `header` and `rows`."""
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def _numbered(width: int) -> Callable[[tuple], tuple]:
    """A row of `width` cells and its attempt: given, or 1 for a row without one."""
    return lambda row: tuple(row) if len(row) > width else (*row, 1)


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6f}"
    return str(value)


def _write_dicts(path: Path, columns: tuple[str, ...], rows: list[dict[str, Any]]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for row in rows:
            w.writerow([_cell(row[c]) for c in columns])


def _write_jobs(path: Path, rows: list[dict[str, Any]]) -> None:
    _write_dicts(path, JOB_COLUMNS, rows)
