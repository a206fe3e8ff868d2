"""The run's summary (summary.json) and the rows of the CSVs the recorder writes.

`check_safety` judges the recorded trajectories; `summarise` turns the robots, the jobs and
what the recorder collected into summary.json's object, with the job accounting, the quality,
solver and latency statistics and the hand-backs; `task_rows`, `cap_rows`, `job_rows` and
`attempt_rows` are the rows of tasks.csv, caps.csv, jobs.csv and attempts.csv (the output
contract is in `fleet.engine.recorder`).
"""

from __future__ import annotations

import logging
from collections import defaultdict
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from fleet.engine.activity import Activity
from fleet.engine.jobs import JobRecord
from fleet.engine.kpis import job_kpis
from fleet.engine.motion import EFFECT_EPS_S, RobotState
from fleet.engine.recorder import Recorder
from fleet.engine.safety import SafetyChecker, SafetyReport
from fleet.floor import Floor
from fleet.plugins import SolveReport, SolverOutcome
from fleet.printing import CapSchedule
from fleet.scenario import Latency, Scenario

__all__ = [
    "check_safety",
    "summarise",
    "task_rows",
    "cap_rows",
    "job_rows",
    "attempt_rows",
    "handback_summary",
    "quality_summary",
    "solver_summary",
    "latency_summary",
]

log = logging.getLogger("fleet.engine")


def check_safety(
    floor: Floor, robots: Mapping[str, RobotState], recorder: Recorder, enforce_caps: bool
) -> SafetyReport:
    """Judge every recorded step: obstacles, speed zones, collisions and (when they are
    enforced) the print caps each robot was under."""
    trajectories = {rid: tr.arrays() for rid, tr in recorder.trajectories.items()}
    radii = {rid: r.spec.radius for rid, r in robots.items()}
    # Caps that are only advice (`[print] enforce = false`) are not limits to check.
    caps = {rid: r.caps() if enforce_caps else CapSchedule() for rid, r in robots.items()}
    return SafetyChecker(floor).check(trajectories, radii, caps)


def summarise(
    scenario: Scenario,
    floor: Floor,
    robots: Mapping[str, RobotState],
    jobs: list[JobRecord],
    recorder: Recorder,
    safety: SafetyReport,
    *,
    now: float,
    wall_time_s: float,
    bus_rounds: int,
    bus_stats: Mapping[str, int],
    activity: Activity | None = None,
) -> dict[str, Any]:
    """summary.json's object for a run that ended at `now` after `wall_time_s` seconds of
    wall time (see `fleet.engine.recorder` for its keys); `activity` adds the robots' states."""
    completed = [rec for rec in jobs if rec.delivered_s is not None]
    failed = [rec for rec in jobs if rec.failed_s is not None]
    # No job may be lost: every released job is delivered, given up, held by a robot
    # (current or queued) or open for the dispatcher, and exactly one of these. Counted from
    # the robots' side, so a job that fell between them shows.
    held = [rec for r in robots.values() for rec in (r.job, *r.queue) if rec is not None]
    waiting = [rec for rec in jobs if rec.open]
    in_progress = held + waiting
    states = [id(rec) for rec in (*completed, *failed, *in_progress)]
    accounted = len(states) == len(set(states)) == len(jobs)
    if not accounted:
        log.error(
            "job accounting broken: %d released != %d completed + %d failed + %d in progress",
            len(jobs),
            len(completed),
            len(failed),
            len(in_progress),
        )
    good = [rec for rec in completed if rec.quality is None or rec.quality.passed]
    # The KPIs leave out the warm-up: deliveries from `warmup_s` on, over the time since.
    start, end = scenario.warmup_s, min(now, scenario.duration_s)
    measured = [rec for rec in completed if rec.delivered_s >= start]
    measured_good = [rec for rec in measured if rec.quality is None or rec.quality.passed]
    late = sum(
        1
        for rec in jobs
        if rec.late
        or (rec.delivered_s is None and rec.job.due_s is not None and now > rec.job.due_s)
    )
    lead = [rec.lead_time_s for rec in measured]
    per_robot = [
        {
            "id": rid,
            "distance_m": round(recorder.trajectories[rid].distance(), 6),
            "jobs_completed": r.jobs_completed,
            "turned_rad": round(r.turned_rad, 6),
            "radius_m": r.spec.radius,
            "goal_commands": r.goal_commands,
            "goal_errors": r.goal_errors,
        }
        for rid, r in robots.items()
    ]
    # A run stopped early (Ctrl-C) is judged over the time it ran.
    hours = max(end - start, 0.0) / 3600.0
    summary = {
        "scenario": scenario.name,
        "scenario_file": scenario.source,
        "map": str(floor.source),
        "seed": scenario.seed,
        "controller": scenario.controller.name,
        "dispatcher": scenario.dispatcher.name,
        # "strict" or "pipelined" ([bus] lockstep): pipelined commands take effect a tick later.
        "lockstep": scenario.bus.lockstep,
        "robots": len(robots),
        "sim_time_s": now,
        # False when the run was stopped before scenario.duration_s (interrupted).
        "complete": now >= scenario.duration_s,
        "wall_time_s": round(wall_time_s, 3),
        "jobs": {
            "released": len(jobs),
            "completed": len(completed),
            # Given up after too many hand-backs (`[jobs] max_handbacks`), and the rest:
            # released == completed + failed + in_progress, checked in `accounted`.
            "failed": len(failed),
            "in_progress": len(in_progress),
            "accounted": accounted,
            "handed_back": sum(rec.handbacks for rec in jobs),
            # Every robot's try at a job (`attempt_rows`): delivered, handed back or under way.
            "attempts": sum(len(rec.all_attempts()) for rec in jobs),
            "assigned_open": sum(1 for rec in jobs if rec.robot and rec.delivered_s is None),
            "unassigned": sum(1 for rec in jobs if rec.open),
            # Delivered parts that passed the quality prediction (jobs with nothing to
            # print count as good), delivered parts that did not, and jobs delivered after
            # their due time or still out when it passed.
            "good": len(good),
            "defective": len(completed) - len(good),
            "late": late,
        },
        "throughput_per_h": round(len(measured) / hours, 6) if hours > 0 else 0.0,
        "throughput_good_per_h": round(len(measured_good) / hours, 6) if hours > 0 else 0.0,
        "mean_lead_time_s": round(float(np.mean(lead)), 6) if lead else None,
        "distance_m": round(sum(p["distance_m"] for p in per_robot), 6),
        "violations": dict(safety.counts),
        "faults": dict(recorder.faults),
        "handbacks": handback_summary(jobs),
        # Robots the deadlock watch found stalled (also the engine's ``deadlocks``); .get:
        # reading the defaultdict must not add the key to the engine's counters.
        "deadlocks": int(recorder.stats.get("deadlocks", 0)),
        "print_caps": {
            "caps": dict(sorted(scenario.print_caps.items())),
            "enforced": scenario.enforce_print_caps,
        },
        "quality": quality_summary(jobs),
        "solver": solver_summary(recorder.solves, recorder.stats),
        "latency": latency_summary(scenario.latency, robots.values()),
        "per_robot": per_robot,
        "stuck_robots": stuck_robots(robots),
        "engine": {
            "bus_rounds": bus_rounds,
            "robot_steps": sum(r.tick for r in robots.values()),
            **{k: int(v) for k, v in sorted(recorder.stats.items())},
            **{f"bus_{k}": int(v) for k, v in sorted(bus_stats.items())},
        },
        "digest": recorder.digest(),
    }
    summary["warmup_s"] = start
    summary.update(job_kpis(jobs, recorder.events, start, end))
    if activity is not None:
        summary["states"] = activity.summary(end)
    if scenario.jobs.mode == "scripted":
        # Point-to-point runs: when each robot reached the destination of its last trip
        # (a print may keep it there longer); None while a trip it was given is still open.
        last: dict[str, float | None] = dict.fromkeys(robots)
        arrived = [rec for rec in jobs if rec.arrived_s is not None]
        for rec in arrived:
            last[rec.robot] = max(last[rec.robot] or 0.0, rec.arrived_s)
        for rec in jobs:
            if rec.robot is not None and rec.arrived_s is None:
                last[rec.robot] = None
        summary["arrivals"] = last
    return summary


def stuck_robots(robots: Mapping[str, RobotState]) -> list[dict[str, str]]:
    """The robots that had somewhere to go but never got a command other than an error: such
    a robot can never move, and `fleet run` fails the run for it."""
    return [
        {
            "robot": rid,
            "reason": f"every one of its {r.goal_errors} commands while it had somewhere to go "
            "was an error (its controller failed, or no command came)",
        }
        for rid, r in robots.items()
        if r.goal_commands > 0 and r.goal_errors == r.goal_commands
    ]


def task_rows(jobs: Iterable[JobRecord]) -> list[tuple[str, str, str, float, float, int]]:
    """Every print task that started, in every attempt at a job: (robot, job, kind, start_s,
    end_s, attempt) rows on the clock, cut where the attempt ended (delivered or handed back)."""
    return [
        (a.robot, a.job, kind, start, end, a.number)
        for rec in jobs
        for a in rec.all_attempts()
        for kind, start, end in a.tasks
    ]


def cap_rows(
    tasks: Iterable[tuple[str, str, str, float, float, int]], caps: Mapping[str, float]
) -> list[tuple[str, str, str, float, float, float, int]]:
    """Every print cap a robot was under: (robot, job, kind, start_s, end_s, cap, attempt) rows,
    from the `task_rows` of the run."""
    return [(*row[:5], caps[row[2]], row[5]) for row in tasks if row[2] in caps]


def attempt_rows(jobs: Iterable[JobRecord], now: float) -> list[dict[str, Any]]:
    """One row per attempt at a job for ``attempts.csv`` (None: not happened), jobs in release
    order and each job's attempts in order; ``printed_s`` is the print time done by `now`."""
    return [
        {
            "job": a.job,
            "attempt": a.number,
            "robot": a.robot,
            "assigned_s": a.assigned_s,
            "started_s": a.started_s,
            "print_start_s": a.print_start_s,
            "ended_s": a.ended_s,
            "result": a.result,
            "reason": a.reason,
            "printed_s": a.printed_s(now),
            "scrapped_s": a.scrapped_s,
        }
        for rec in jobs
        for a in rec.all_attempts()
    ]


def handback_summary(jobs: Iterable[JobRecord]) -> dict[str, Any]:
    """summary.json's ``handbacks`` object: attempts handed back, by reason, and the print time
    and the parts they scrapped."""
    ended = [a for rec in jobs for a in rec.attempts]
    by_reason: dict[str, int] = defaultdict(int)
    for a in ended:
        by_reason[a.reason or ""] += 1
    return {
        "count": len(ended),
        "by_reason": dict(sorted(by_reason.items())),
        "scrapped_print_s": round(float(sum(a.scrapped_s for a in ended)), 6),
        "scrapped_parts": sum(1 for a in ended if a.scrapped_s > 0),
    }


def job_rows(jobs: Iterable[JobRecord], now: float) -> list[dict[str, Any]]:
    """One row per job for ``jobs.csv`` (None: not happened, or not printed)."""
    rows = []
    for rec in jobs:
        q = rec.quality
        rows.append(
            {
                "id": rec.job.id,
                "part": rec.job.part,
                "robot": rec.robot,
                "released_s": rec.job.released_s,
                "started_s": rec.print_start_s if rec.print_start_s is not None else rec.started_s,
                "finished_s": rec.print_end_s
                if rec.print_end_s is not None and rec.printing_done(now)
                else None,
                "delivered_s": rec.delivered_s,
                "due_s": rec.job.due_s,
                "predicted_error_mm": None if q is None else q.error_mm,
                "passed": None if q is None else q.passed,
                "outcome": None if q is None else q.outcome,
            }
        )
    return rows


def quality_summary(jobs: Iterable[JobRecord]) -> dict[str, Any]:
    """Outcomes of the prints judged so far and the largest predicted error."""
    judged = [rec.quality for rec in jobs if rec.quality is not None]
    outcomes: dict[str, int] = defaultdict(int)
    for q in judged:
        outcomes[q.outcome] += 1
    return {
        "prints": len(judged),
        "outcomes": dict(sorted(outcomes.items())),
        "max_error_mm": round(max(q.error_mm for q in judged), 6) if judged else None,
    }


def solver_summary(solves: list[SolveReport], stats: Mapping[str, int]) -> dict[str, Any]:
    """Statistics of the `SolveReport`s controllers attached to their commands."""
    outcomes: dict[str, int] = defaultdict(int)
    for s in solves:
        outcomes[s.outcome.value] += 1
    out: dict[str, Any] = {
        "steps": len(solves),
        "median_ms": None,
        "p95_ms": None,
        "max_ms": None,
        "fallbacks": int(stats.get("commands_fallback", 0)),
        "termination": dict(sorted(outcomes.items())),
        # Solves stopped by the wall clock: while this is 0 the run is reproducible.
        "time_limit_hits": outcomes.get(SolverOutcome.TIME_LIMIT.value, 0),
    }
    if solves:
        solver = np.array([s.solver_s for s in solves]) * 1e3
        step = np.array([s.step_s for s in solves]) * 1e3
        out.update(_spread_ms(solver))
        out.update(
            step_median_ms=round(float(np.median(step)), 3),
            step_p95_ms=round(float(np.percentile(step, 95)), 3),
            # The modelling layer's overhead: whole controller step over solver time.
            overhead_ratio=round(float(step.sum() / max(solver.sum(), 1e-12)), 3),
        )
    return out


def _spread_ms(ms: np.ndarray) -> dict[str, float]:
    """``median_ms``, ``p95_ms`` and ``max_ms`` of times in ms, as summary.json writes them."""
    return {
        "median_ms": round(float(np.median(ms)), 3),
        "p95_ms": round(float(np.percentile(ms, 95)), 3),
        "max_ms": round(float(ms.max()), 3),
    }


def latency_summary(mode: Latency, robots: Iterable[RobotState]) -> dict[str, Any]:
    """The ``latency`` object of summary.json: the mode and, over the controllers' commands
    that waited (every one with a fixed latency; those with a solve report when measured), how
    many, the median, p95 and largest latency, and how many were `late` (a latency of at least
    the robot's period: the command missed its own step); `instant` counts the commands a
    measured run applied at once (no solve report). The keys are the same in every mode."""
    robots = list(robots)
    out: dict[str, Any] = {
        "mode": "none" if mode is None else "measured" if mode == "measured" else "fixed",
        "commands": 0,
        "median_ms": None,
        "p95_ms": None,
        "max_ms": None,
        "late": 0,
        "instant": sum(r.instant for r in robots),
    }
    per_robot = [
        (np.frombuffer(r.latencies, dtype=float), r.spec.period) for r in robots if r.latencies
    ]
    if mode is None or not per_robot:
        return out
    ms = np.concatenate([s for s, _ in per_robot]) * 1e3
    out.update(_spread_ms(ms))
    out.update(
        commands=int(ms.size),
        late=sum(int(np.count_nonzero(s >= period - EFFECT_EPS_S)) for s, period in per_robot),
    )
    return out
