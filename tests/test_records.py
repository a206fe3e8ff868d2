"""Complete records (issue 18): every attempt at a job, handed back or not, is in attempts.csv,
tasks.csv, caps.csv, the figures and the replay, with the print time it scrapped and why; the
summary and the KPI table count hand-backs by reason, scrapped print time, deadlocks and faults.

Real runs: a controller that declares its robot blocked hands jobs back over the bus, a
breakdown-like hand-back goes through `Dispatch.hand_back` as any engine part would call it, and
a killed worker process is a real agent fault.
"""

from __future__ import annotations

import csv
import html
import json
import os
import re
import signal
from collections import Counter
from dataclasses import replace
from pathlib import Path

import pytest
from rich.console import Console

from fleet.cli import _kpi_table
from fleet.engine import World
from fleet.errors import InputError
from fleet.plugins import Command, ControlStatus
from fleet.printing import PrintTask
from fleet.scenario import REPO_ROOT, BusConfig, JobsConfig, ScriptedJob, load_scenario
from fleet.view.figures import gantt_figure, load_attempts, load_run, speed_figure
from fleet.view.replay import replay_data, write_replay
from fleet_plugins.follower import PathFollower
from tests.test_replay import (
    chromium,  # noqa: F401  (the fixture)
    finish,
    screenshot,
)

FLEET = REPO_ROOT / "scenarios" / "fleet.toml"
CAPS = {"contour": 0.3, "infill": 0.5}
#: What each job prints: 80 s, the travel task uncapped.
TASKS = (
    PrintTask("contour", 0.0, 30.0),
    PrintTask("infill", 30.0, 70.0),
    PrintTask("travel", 70.0, 80.0),
)
BLOCKED_AFTER_S = 15.0
BREAKDOWN_AT_S = 50.0


class BlockedAfterAWhile(PathFollower):
    """The follower, except that robot r01 declares itself blocked 15 s into each of the first
    two jobs it is given (its print by then under way): the engine takes the job back."""

    def compute(self, obs):
        if self.context.robot == "r01" and obs.job is not None:
            seen = self.__dict__.setdefault("_seen", {})
            since = seen.setdefault(obs.job, obs.t)
            if len(seen) <= 2 and obs.t - since >= BLOCKED_AFTER_S:
                return Command(0.0, 0.0, ControlStatus.BLOCKED)
        return super().compute(obs)


def scripted(*jobs: tuple[float, str]) -> tuple[ScriptedJob, ...]:
    return tuple(ScriptedJob(at, station, tasks=TASKS) for at, station in jobs)


def read(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def kpi_text(summary: dict) -> str:
    console = Console(record=True, width=120, color_system=None)
    _kpi_table(console, summary)
    return console.export_text()


@pytest.fixture(scope="module")
def handed_back(tmp_path_factory) -> tuple[World, dict, Path]:
    """Three robots, four printing jobs: r01 hands back as blocked (a job it was given twice
    fails: max_handbacks = 1), r02 breaks down at 50 s, and the run ends with a print under way.
    """
    import fleet.engine.agents as agents_module

    mp = pytest.MonkeyPatch()
    mp.setattr(agents_module, "load_controller", lambda name, options: BlockedAfterAWhile())
    try:
        sc = load_scenario(FLEET).override(robots=3, duration=110.0, dispatcher="greedy")
        sc = replace(
            sc,
            print_caps=CAPS,
            jobs=JobsConfig(
                mode="scripted",
                max_handbacks=1,
                scripted=scripted(
                    (0.0, "cnc_1_in"), (0.0, "qc_lab_in"), (5.0, "furnace_in"), (40.0, "press_1_in")
                ),
            ),
        )
        world = World(sc)
        broke: dict[str, tuple[float, str]] = {}

        def breakdown(now: float) -> None:
            # What a breakdown does to the job of the robot it stops (issue 18, part 4).
            robot = world.robots["r02"]
            if now >= BREAKDOWN_AT_S and not broke and robot.job is not None:
                broke["r02"] = (now, robot.job.job.id)
                world.dispatch.hand_back(robot, robot.job, "breakdown")

        result = world.run(breakdown)
    finally:
        mp.undo()
    out = tmp_path_factory.mktemp("records") / "run"
    world.write(out)
    assert broke, "r02 held a job at the breakdown"
    return world, result.summary, out


def test_every_attempt_is_in_attempts_csv_with_how_it_ended(handed_back):
    world, summary, out = handed_back
    rows = read(out / "attempts.csv")
    assert len(rows) == summary["jobs"]["attempts"]
    assert len(rows) == sum(len(rec.all_attempts()) for rec in world.jobs)
    # Every assignment the engine made is an attempt, in order per job.
    assigned = [(e.job, e.robot, e.t) for e in world.recorder.events if e.event == "assigned"]
    assert sorted((r["job"], r["robot"], r["assigned_s"]) for r in rows) == sorted(
        (j, r, f"{t:.6f}") for j, r, t in assigned
    )
    for job in {r["job"] for r in rows}:
        numbers = [int(r["attempt"]) for r in rows if r["job"] == job]
        assert numbers == list(range(1, len(numbers) + 1)), job
    results = Counter(r["result"] for r in rows)
    assert set(results) == {"delivered", "handed_back", "failed", "unfinished"}, results
    # Each hand-back event is an attempt that ended then, by that robot, for that reason.
    events = [e for e in world.recorder.events if e.event == "handed_back"]
    ended = [r for r in rows if r["result"] in ("handed_back", "failed")]
    assert sorted((e.job, e.robot, e.station) for e in events) == sorted(
        (r["job"], r["robot"], r["reason"]) for r in ended
    )
    assert {r["reason"] for r in ended} == {"handed back: blocked", "breakdown"}
    for r in rows:
        if r["result"] == "unfinished":
            assert r["ended_s"] == "" and r["reason"] == ""
        else:
            assert float(r["ended_s"]) >= float(r["assigned_s"])
        if r["result"] in ("delivered", "unfinished"):
            assert float(r["scrapped_s"]) == 0.0
    failed = {r["job"] for r in rows if r["result"] == "failed"}
    assert failed == {rec.job.id for rec in world.jobs if rec.failed_s is not None}
    assert summary["jobs"]["failed"] == len(failed)


def test_tasks_and_caps_hold_every_attempt_cropped_where_it_ended(handed_back):
    world, summary, out = handed_back
    attempts = {(r["job"], int(r["attempt"])): r for r in read(out / "attempts.csv")}
    tasks = read(out / "tasks.csv")
    caps = read(out / "caps.csv")
    printed: Counter = Counter()
    for t in tasks:
        a = attempts[(t["job"], int(t["attempt"]))]
        assert t["robot"] == a["robot"]
        start, end = float(t["start_s"]), float(t["end_s"])
        assert start >= float(a["print_start_s"]) - 1e-9
        if a["ended_s"]:
            assert end <= float(a["ended_s"]) + 1e-9  # cropped at the hand-back or delivery
        # An unfinished print's plan goes on past the run's end: count what was done by then.
        printed[(t["job"], int(t["attempt"]))] += max(0.0, min(end, summary["sim_time_s"]) - start)
    # Each attempt's printed time is what its tasks say; every attempt that printed has tasks.
    for key, a in attempts.items():
        assert float(a["printed_s"]) == pytest.approx(printed.get(key, 0.0), abs=1e-5), key
    scrapped_keys = {k for k, a in attempts.items() if a["result"] in ("handed_back", "failed")}
    assert any(printed[k] > 0 for k in scrapped_keys), "a handed-back attempt printed"
    # caps.csv: exactly the capped tasks, attempt for attempt.
    capped = [
        (t["robot"], t["job"], t["kind"], t["start_s"], t["end_s"], t["attempt"]) for t in tasks
    ]
    assert sorted(
        (c["robot"], c["job"], c["kind"], c["start_s"], c["end_s"], c["attempt"]) for c in caps
    ) == sorted(row for row in capped if row[2] in CAPS)
    for c in caps:
        assert float(c["cap"]) == CAPS[c["kind"]]
    # The caps the safety checker judged each robot by include the scrapped attempts' caps.
    for c in caps:
        mid = (float(c["start_s"]) + float(c["end_s"])) / 2
        judged = world.robots[c["robot"]].caps().pieces
        assert any(a <= mid < b and cap == float(c["cap"]) for a, b, cap in judged), c


def test_scrapped_print_time_is_what_the_tasks_say_and_the_summary_counts_it(handed_back):
    world, summary, out = handed_back
    attempts = {(r["job"], r["attempt"]): r for r in read(out / "attempts.csv")}
    scrapped_tasks = sum(
        float(t["end_s"]) - float(t["start_s"])
        for t in read(out / "tasks.csv")
        if attempts[(t["job"], t["attempt"])]["result"] in ("handed_back", "failed")
    )
    hb = summary["handbacks"]
    assert scrapped_tasks > 2 * BLOCKED_AFTER_S  # r01 twice, r02 for its breakdown
    assert hb["scrapped_print_s"] == pytest.approx(scrapped_tasks, abs=1e-5)
    assert hb["scrapped_print_s"] == pytest.approx(
        sum(float(a["scrapped_s"]) for a in attempts.values()), abs=1e-5
    )
    ended = [a for a in attempts.values() if a["result"] in ("handed_back", "failed")]
    assert hb["count"] == len(ended) == summary["jobs"]["handed_back"]
    assert hb["by_reason"] == dict(Counter(a["reason"] for a in ended))
    assert hb["scrapped_parts"] == sum(1 for a in ended if float(a["scrapped_s"]) > 0)
    assert summary["deadlocks"] == world.stats.get("deadlocks", 0)
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["handbacks"] == hb and on_disk["deadlocks"] == summary["deadlocks"]


def test_the_kpi_table_shows_hand_backs_scrapped_time_deadlocks_and_faults(handed_back):
    _, summary, _ = handed_back
    text = kpi_text(summary)
    hb = summary["handbacks"]
    assert hb["count"] >= 4 and len(hb["by_reason"]) == 2
    lines = {line.split("│")[1].strip(): line.split("│")[2].strip() for line in kpi_rows(text)}
    assert lines["hand-backs / scrapped print"] == f"{hb['count']} / {hb['scrapped_print_s']:.1f} s"
    for reason, n in hb["by_reason"].items():
        assert lines[f"hand-backs: {reason}"] == str(n)
    assert lines["deadlocks"] == str(summary["deadlocks"])
    assert lines["faults: agents lost / left"] == "0 / 0"
    assert lines["faults: robots orphaned / rejoined"] == "0 / 0"


def kpi_rows(text: str) -> list[str]:
    """The table's body rows (``│ figure │ value │``)."""
    return [line for line in text.splitlines() if line.count("│") == 3]


def test_the_figures_draw_scrapped_attempts_apart_and_mark_each_hand_back(handed_back):
    _, _, out = handed_back
    run = load_run(out)
    attempts = load_attempts(out / "attempts.csv")
    assert run.attempts == attempts and len(attempts) == len(read(out / "attempts.csv"))
    scrapped = {(a.job, a.attempt) for a in attempts if a.scrapped}
    assert {(t.job, t.attempt) for t in run.tasks if t.scrapped} == {
        (t.job, t.attempt) for t in run.tasks if (t.job, t.attempt) in scrapped
    }
    assert any(t.scrapped for t in run.tasks) and any(not t.scrapped for t in run.tasks)
    ax = gantt_figure(
        run.tasks, run.events, run.jobs, robots=list(run.tracks), attempts=run.attempts
    ).axes[0]
    gids = [p.get_gid() or "" for p in ax.patches]
    assert sorted(g for g in gids if g.startswith("scrapped:")) == sorted(
        f"scrapped:{t.robot}:{t.job}:{t.kind}:{t.attempt}" for t in run.tasks if t.scrapped
    )
    assert sorted(g for g in gids if g.startswith("task:")) == sorted(
        f"task:{t.robot}:{t.job}:{t.kind}" for t in run.tasks if not t.scrapped
    )
    # One band per attempt, each in its own robot's row.
    bands = [p for p in ax.patches if (p.get_gid() or "").startswith("held:")]
    assert len(bands) == len(attempts)
    rows = {rid: i for i, rid in enumerate(run.tracks)}
    for a in attempts:
        gid = f"held:{a.job}" if a.attempt == 1 else f"held:{a.job}:{a.attempt}"
        (band,) = [p for p in bands if p.get_gid() == gid]
        assert band.get_x() == pytest.approx(a.assigned_s)
        assert band.get_y() + band.get_height() / 2 == pytest.approx(rows[a.robot])
    (marks,) = [ln for ln in ax.get_lines() if ln.get_gid() == "handed_back"]
    ended = sorted(a.ended_s for a in attempts if a.scrapped)
    assert list(marks.get_xdata()) == pytest.approx(ended)
    fig = speed_figure(run.tracks, run.caps, attempts=run.attempts)
    lines = {ln.get_gid() for a in fig.axes for ln in a.get_lines()}
    assert {f"handed_back:{a.job}:{a.attempt}" for a in attempts if a.scrapped} <= lines
    hatched = {p.get_gid() for a in fig.axes for p in a.patches if p.get_gid()}
    assert {
        f"scrapped:{c.job}:{c.kind}:{c.attempt}" for c in run.caps if c.scrapped
    } == hatched and hatched


def test_the_replay_data_holds_every_attempt_and_its_scrapped_prints(handed_back):
    _, _, out = handed_back
    data = replay_data(load_run(out))
    rows = read(out / "attempts.csv")
    assert [(a["job"], a["attempt"], a["robot"], a["result"]) for a in data["attempts"]] == [
        (r["job"], int(r["attempt"]), r["robot"], r["result"]) for r in rows
    ]
    for a, r in zip(data["attempts"], rows, strict=True):
        assert a["scrapped"] == (r["result"] in ("handed_back", "failed"))
        assert a["reason"] == (r["reason"] or None)
    shown = {
        (robot["id"], task[3], task[4], task[5])
        for robot in data["robots"]
        for task in robot["tasks"]
    }
    by_key = {(a["job"], a["attempt"]): a for a in data["attempts"]}
    assert shown == {
        (t["robot"], t["job"], int(t["attempt"]), by_key[(t["job"], int(t["attempt"]))]["scrapped"])
        for t in read(out / "tasks.csv")
    }


def test_the_replay_shows_a_hand_back_where_and_when_it_happened(
    handed_back,
    chromium,  # noqa: F811  (the fixture imported above)
    tmp_path,
):
    _, _, out = handed_back
    page = write_replay(out)
    hb = next(a for a in load_attempts(out / "attempts.csv") if a.reason == "breakdown")
    report = """<script>setTimeout(function () {
      const pre = document.createElement("pre"); pre.id = "states"; pre.hidden = true;
      pre.textContent = JSON.stringify({states: replayStates(), marks: replayHandbacks()});
      document.body.append(pre);
    }, 400);</script></body>"""
    probed = page.with_name("states.html")
    probed.write_text(page.read_text(encoding="utf-8").replace("</body>", report))
    at = hb.ended_s + 0.5
    dom, _ = finish(screenshot(probed, at, tmp_path / "shot", (1280, 720)), tmp_path / "shot")
    m = re.search(r'<pre id="states" hidden="">(.*?)</pre>', dom, re.S)
    assert m, "the page ran the report (a script error stops it)"
    seen = json.loads(html.unescape(m.group(1)))
    marks = [(k["robot"], k["job"], k["attempt"]) for k in seen["marks"]]
    assert (hb.robot, hb.job, hb.attempt) in marks
    job_state = seen["states"]["jobs"][hb.job]
    robot_state = seen["states"]["robots"][hb.robot]
    # Taken again at once (a breakdown sets no hold) or open: either way the page says so.
    assert job_state == "handed back (breakdown)" or job_state.startswith("assigned (attempt 2")
    assert robot_state["key"] in ("handed_back", "to", "printing")


def test_a_killed_worker_hands_its_robots_jobs_back_and_every_record_shows_it(tmp_path):
    sc = replace(
        load_scenario(FLEET).override(robots=4, duration=150.0),
        print_caps=CAPS,
        jobs=JobsConfig(
            mode="scripted",
            scripted=scripted(
                (0.0, "cnc_1_in"), (0.0, "qc_lab_in"), (0.0, "furnace_in"), (0.0, "paint_booth_in")
            ),
        ),
        # The default 3 s of silence: at 1 s a live worker on a loaded 2-core machine was
        # taken for lost too (2 agents lost, not 1).
        bus=BusConfig(timeout_s=5.0, lost_after_s=3.0),
    )
    world = World(sc, workers=2)
    victim = world.workers.processes[0]
    orphans = world.workers.shares[victim.name]
    done: dict[str, object] = {}

    def kill(now: float) -> None:
        if now >= 20.0 and "killed" not in done:
            done["held"] = sum(
                len(world.robots[r].queue) + (world.robots[r].job is not None) for r in orphans
            )
            os.kill(victim.pid, signal.SIGKILL)
            victim.join()
            done["killed"] = now

    summary = world.run(kill).summary
    world.write(tmp_path / "run")
    out = tmp_path / "run"
    assert summary["faults"]["agents_lost"] == 1
    assert summary["faults"]["robots_orphaned"] == len(orphans)
    rows = read(out / "attempts.csv")
    lost = [r for r in rows if r["result"] in ("handed_back", "failed")]
    assert len(lost) == done["held"] >= 1
    assert {r["robot"] for r in lost} <= set(orphans)
    assert all(r["reason"].startswith("agent ") and r["reason"].endswith(" lost") for r in lost)
    # Their prints (20 s of each, started at once) are scrapped and in tasks.csv and caps.csv.
    keys = {(r["job"], r["attempt"]) for r in lost}
    tasks = [t for t in read(out / "tasks.csv") if (t["job"], t["attempt"]) in keys]
    scrapped = sum(float(t["end_s"]) - float(t["start_s"]) for t in tasks)
    assert summary["handbacks"]["scrapped_print_s"] == pytest.approx(scrapped, abs=1e-5)
    assert scrapped > 0 and all(float(t["end_s"]) <= done["killed"] + 5.0 for t in tasks)
    assert {(c["job"], c["attempt"]) for c in read(out / "caps.csv")} >= keys
    # The jobs went on with other robots: a later attempt by a robot that kept its agent.
    for job, n in keys:
        later = [r for r in rows if r["job"] == job and int(r["attempt"]) > int(n)]
        assert later and later[0]["robot"] not in orphans, job
    lines = {
        row.split("│")[1].strip(): row.split("│")[2].strip() for row in kpi_rows(kpi_text(summary))
    }
    assert lines["faults: agents lost / left"] == "1 / 0"
    assert lines["faults: robots orphaned / rejoined"] == f"{len(orphans)} / 0"
    reasons = summary["handbacks"]["by_reason"]
    assert sum(reasons.values()) == len(lost)
    for reason, n in reasons.items():
        assert lines[f"hand-backs: {reason}"] == str(n)
    # Other robots finished what the orphans left.
    assert summary["jobs"]["completed"] + summary["jobs"]["in_progress"] == 4


def test_a_bad_attempt_cell_is_named_and_old_files_without_attempts_still_load(tmp_path):
    (tmp_path / "tasks.csv").write_text(
        "robot,job,kind,start_s,end_s,attempt\nr01,j1,contour,0,10,zero\n"
    )
    with pytest.raises(InputError, match=r"tasks.csv.*line 2, attempt.*zero.*whole number"):
        load_run_tasks(tmp_path)
    (tmp_path / "tasks.csv").write_text("robot,job,kind,start_s,end_s\nr01,j1,contour,0,10\n")
    (task,) = load_run_tasks(tmp_path)
    assert (task.attempt, task.scrapped) == (1, False)
    (tmp_path / "attempts.csv").write_text(
        "job,attempt,robot,assigned_s,ended_s,result\nj1,1,r01,0,10,handed_back\n"
    )
    (task,) = load_run_tasks(tmp_path)
    assert task.scrapped
    assert load_attempts(tmp_path / "attempts.csv")[0].ended_s == 10.0


def load_run_tasks(run_dir: Path):
    from fleet.view.figures import load_tasks

    return load_tasks(run_dir)
