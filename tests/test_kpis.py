"""KPIs over time and per robot (issue 18, part 2): state shares that sum to the measured window
for every robot (faults included), the queue and WIP series, waits and lead times, the warm-up
left out of the KPIs, and MSER-5's warm-up suggestion, on real runs and on series with a known
transient."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fleet.cli import main
from fleet.engine import World
from fleet.engine.activity import STATES
from fleet.engine.kpis import queue_wip, time_mean
from fleet.engine.warmup import grid_means, mser5, suggest_warmup
from fleet.errors import ScenarioError
from fleet.printing import PrintTask
from fleet.scenario import REPO_ROOT, JobsConfig, ScriptedJob, check_warmup, load_scenario
from fleet.study.warmup import warmup_lines
from fleet.view.kpi_figures import STATES_PNG, WIP_PNG, save_kpi_figures

FLEET = REPO_ROOT / "scenarios" / "fleet.toml"
DEFAULT = REPO_ROOT / "scenarios" / "default.toml"
STATIONS = ("cnc_1_in", "furnace_in", "qc_lab_in", "paint_booth_in")


def printing_scenario(warmup_s: float = 0.0, duration: float = 600.0):
    """Three robots printing 90 s parts on the way to stations, a job every 30 s."""
    jobs = tuple(
        ScriptedJob(30.0 * i, STATIONS[i % len(STATIONS)], tasks=(PrintTask("infill", 0, 90),))
        for i in range(16)
    )
    sc = load_scenario(DEFAULT).override(robots=3, duration=duration)
    return replace(sc, jobs=JobsConfig(mode="scripted", scripted=jobs), warmup_s=warmup_s)


def check_states_sum(summary: dict, window: float) -> None:
    """Every robot's state seconds sum to the measured window; the fleet shares to 1."""
    states = summary["states"]
    assert states["to_s"] - states["from_s"] == pytest.approx(window)
    for robot, secs in states["robots"].items():
        assert set(secs) == set(STATES)
        total = sum(s["seconds"] for s in secs.values())
        assert total == pytest.approx(window, abs=1e-5), robot
        assert sum(s["share"] for s in secs.values()) == pytest.approx(1.0, abs=1e-5), robot
    assert sum(states["shares"].values()) == pytest.approx(1.0, abs=1e-5)


@pytest.fixture(scope="module")
def printed(tmp_path_factory) -> tuple[World, dict, Path]:
    world = World(printing_scenario())
    summary = world.run().summary
    out = tmp_path_factory.mktemp("runs") / "printed"
    world.write(out)
    return world, summary, out


def test_state_shares_sum_to_the_run_for_every_robot_and_printing_shows(printed):
    _, s, out = printed
    check_states_sum(s, 600.0)
    shares = s["states"]["shares"]
    # The robots printed, drove and (with jobs every 30 s for three robots) waited at home too.
    assert shares["printing_driving"] > 0 and shares["printing_at_rest"] > 0
    assert shares["driving_empty"] > 0
    assert shares["faulted"] == 0 and shares["charging"] == 0
    # states.csv holds the same seconds.
    with open(out / "states.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(STATES) * 3
    for row in rows:
        want = s["states"]["robots"][row["robot"]][row["state"]]["seconds"]
        assert float(row["seconds"]) == pytest.approx(want, abs=1e-5)


def test_printing_time_matches_the_print_tasks(printed):
    world, s, _ = printed
    # Every print under way is printing time of its robot, and nothing else is: the seconds in
    # the two printing states are the print tasks' time, to a control period per print.
    printing = sum(
        r[k]["seconds"] for r in s["states"]["robots"].values() for k in STATES if "printing" in k
    )
    prints = [
        min(rec.print_end_s, 600.0) - rec.print_start_s
        for rec in world.jobs
        if rec.print_start_s is not None and rec.print_start_s < 600.0
    ]
    assert printing == pytest.approx(sum(prints), abs=0.25 * len(prints) + 1e-6)


def test_queue_and_wip_follow_the_events_and_end_where_the_summary_does(printed):
    world, s, out = printed
    series = queue_wip(world.recorder.events)
    assert series[0][0] == 0.0  # the values after t = 0's events (jobs released at 0)
    times = [t for t, _, _ in series]
    assert times == sorted(times) and len(set(times)) == len(times)
    assert all(0 <= q <= w for _, q, w in series)
    _, queue, wip = series[-1]
    assert queue == s["jobs"]["unassigned"]
    assert wip == s["jobs"]["in_progress"]
    assert s["wip_max"] == max(w for _, _, w in series)
    with open(out / "wip.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(float(r["t"]), int(r["queue"]), int(r["wip"])) for r in rows] == [
        (pytest.approx(t, abs=1e-6), q, w) for t, q, w in series
    ]


def test_waits_and_lead_times_are_those_of_the_jobs(printed):
    world, s, _ = printed
    leads = [rec.lead_time_s for rec in world.jobs if rec.delivered_s is not None]
    assert s["lead_time_s"]["n"] == len(leads) > 0
    assert s["lead_time_s"]["p50"] == pytest.approx(np.percentile(leads, 50), abs=1e-5)
    assert s["lead_time_s"]["p95"] == pytest.approx(np.percentile(leads, 95), abs=1e-5)
    assert s["mean_lead_time_s"] == pytest.approx(s["lead_time_s"]["mean"], abs=1e-5)
    waits = s["assign_wait_s"]
    assigned = {e.job for e in world.recorder.events if e.event == "assigned"}
    assert waits["n"] == len(assigned)
    # Three robots for a job every 30 s of 90 s prints: jobs wait, and no wait is negative.
    assert 0 < waits["p50"] <= waits["p95"] <= waits["max"]


def test_a_warm_up_leaves_the_start_out_of_the_kpis_and_changes_no_behaviour(printed):
    world0, s0, _ = printed
    world = World(printing_scenario(warmup_s=150.0))
    s = world.run().summary
    assert s["digest"] == s0["digest"]  # the warm-up only changes what is measured
    assert s["warmup_s"] == 150.0
    check_states_sum(s, 450.0)
    delivered = [rec.delivered_s for rec in world.jobs if rec.delivered_s is not None]
    late = [t for t in delivered if t >= 150.0]
    assert len(late) < len(delivered)  # some deliveries fell in the warm-up
    assert s["throughput_per_h"] == pytest.approx(len(late) / 450.0 * 3600.0, abs=1e-5)
    assert s["lead_time_s"]["n"] == len(late)
    assert s["jobs"]["completed"] == s0["jobs"]["completed"]  # the counts stay whole-run
    # Each robot's seconds after the warm-up are its whole-run seconds less those of the same
    # run stopped at the warm-up's end (the same steps up to then).
    first = World(printing_scenario(duration=150.0)).run().summary["states"]["robots"]
    for robot, secs in s["states"]["robots"].items():
        whole = s0["states"]["robots"][robot]
        for state in STATES:
            assert secs[state]["seconds"] == pytest.approx(
                whole[state]["seconds"] - first[robot][state]["seconds"], abs=1e-5
            )
    wip = queue_wip(world.recorder.events)
    t, w = [r[0] for r in wip], [r[2] for r in wip]
    assert s["wip_mean"] == pytest.approx(time_mean(t, w, 150.0, 600.0), abs=1e-5)


def test_shares_sum_to_the_run_with_faulted_robots_and_hand_backs(tmp_path):
    sc = replace(
        load_scenario(FLEET).override(robots=6, duration=300.0),
        jobs=JobsConfig(mode="scripted", scripted=tuple(ScriptedJob(40.0, s) for s in STATIONS)),
    )
    world = World(sc)
    closed: dict[str, float] = {}

    def progress(now: float) -> None:
        # The agent hosting every robot says BYE while robots hold jobs: all are orphaned.
        if now >= 45.0 and "t" not in closed and any(r.job for r in world.robots.values()):
            world.host.close()
            closed["t"] = now

    s = world.run(progress).summary
    assert s["faults"]["robots_orphaned"] == 6
    assert s["jobs"]["handed_back"] >= 1
    check_states_sum(s, 300.0)
    for secs in s["states"]["robots"].values():
        # Faulted from the round after the BYE to the end (ticks every 0.25 s).
        assert 300.0 - closed["t"] - 1.0 <= secs["faulted"]["seconds"] <= 300.0 - closed["t"]
    world.write(tmp_path / "run")
    _, queue, wip = queue_wip(world.recorder.events)[-1]
    assert (queue, wip) == (s["jobs"]["unassigned"], s["jobs"]["in_progress"]) == (4, 4)
    paths = save_kpi_figures(tmp_path / "run")
    assert [p.name for p in paths] == [STATES_PNG, WIP_PNG]
    assert all(p.stat().st_size > 10_000 for p in paths)


# -- MSER-5 -----------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_mser5_finds_the_end_of_a_ramp(seed):
    # WIP decaying linearly from 20 to 5 over 300 s, then noise around 5, over 3000 s.
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 3000.0, 1.0)
    v = 5.0 + 15.0 * np.clip(1.0 - t / 300.0, 0.0, None) + rng.normal(0.0, 1.0, t.size)
    suggested, at_limit = suggest_warmup(t, v, 3000.0)
    assert 200.0 <= suggested <= 450.0 and not at_limit


@pytest.mark.parametrize("seed", range(6))
def test_mser5_cuts_little_from_a_stationary_series(seed):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 3000.0, 1.0)
    suggested, _ = suggest_warmup(t, 5.0 + rng.normal(0.0, 1.0, t.size), 3000.0)
    assert suggested <= 300.0


def test_mser5_batches_and_searches_the_first_half_only():
    assert mser5([1.0] * 9) == 0  # one batch: nothing to compare
    # A step at observation 40 of 100: cut there (a multiple of 5).
    assert mser5([10.0] * 40 + [0.0, 1.0] * 30) == 40
    # A series that trends all along: the cut stops at half the batches, flagged as the limit.
    rising = np.arange(100.0)
    assert mser5(rising) == 50
    assert suggest_warmup(np.arange(100.0), rising, 100.0, cells=100) == (50.0, True)


def test_grid_means_are_time_weighted():
    # 1 over [0, 1), 3 over [1, 4): cells of 2 s average 2 then 3.
    assert grid_means([0.0, 1.0], [1.0, 3.0], 4.0, cells=2).tolist() == [2.0, 3.0]
    assert time_mean([0.0, 1.0], [1.0, 3.0], 0.0, 4.0) == 2.5
    assert time_mean([0.0, 1.0], [1.0, 3.0], 2.0, 4.0) == 3.0


def test_on_a_real_run_mser5_cuts_where_a_backlog_has_cleared():
    # Six robots start with 30 jobs waiting, then get one every 30 s (less than they can do):
    # the WIP falls from 30 to a few jobs, then stays there. MSER-5 cuts once the backlog has
    # cleared, not long after the WIP settled, in a whole number of batches of 5 cells of 1.5 s.
    backlog = tuple(ScriptedJob(0.0, STATIONS[(i + 1) % 4]) for i in range(30))
    steady = tuple(ScriptedJob(30.0 * k, STATIONS[(3 * k + 1) % 4]) for k in range(1, 50))
    sc = replace(
        load_scenario(FLEET).override(robots=6, duration=1500.0),
        jobs=JobsConfig(mode="scripted", scripted=backlog + steady),
    )
    world = World(sc)
    s = world.run().summary
    series = queue_wip(world.recorder.events)
    cleared = next(t for t, queue, _ in series if t > 0 and queue == 0)
    settled = next(t for t, _, wip in series if t > 0 and wip <= 3)
    assert cleared <= s["suggested_warmup_s"] <= settled + 200.0
    assert s["suggested_warmup_at_limit"] is False
    batches = s["suggested_warmup_s"] / (5 * 1500.0 / 1000)
    assert math.isclose(batches, round(batches), abs_tol=1e-6)


# -- the option and the command line ----------------------------------------------------------


@pytest.mark.parametrize(
    ("value", "rule"),
    [("600", "must be less than the run's duration_s"), ("-1", "number >= 0")],
)
def test_a_bad_warm_up_is_an_error_naming_file_field_and_value(tmp_path, value, rule):
    (tmp_path / "floor.toml").write_text("# the scenario loader only needs the file\n")
    path = tmp_path / "warm.toml"
    path.write_text(f'[scenario]\nmap = "floor.toml"\nduration_s = 600\nwarmup_s = {value}\n')
    with pytest.raises(ScenarioError, match=rf"warm\.toml: scenario\.warmup_s = {value}.*{rule}"):
        load_scenario(path)


def test_a_run_shortened_below_its_warm_up_is_refused():
    sc = replace(load_scenario(DEFAULT), warmup_s=300.0)
    check_warmup(sc)
    short = sc.override(duration=200.0)
    with pytest.raises(ScenarioError, match=r"scenario\.warmup_s = 300\.0: must be less than"):
        check_warmup(short)
    with pytest.raises(ScenarioError, match=r"warmup_s = 300\.0"):
        World(short)


def test_fleet_run_shows_the_kpis_over_time(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(
        [
            "run",
            str(FLEET),
            "--robots",
            "4",
            "--duration",
            "240",
            "--set",
            "scenario.warmup_s=60",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    for row in (
        "wait for assignment mean / p50 / p95",
        "lead time p50 / p95",
        "queue / WIP mean",
        "robots' time idle / driving empty / blocked",
        "warm-up left out of the KPIs",
        "warm-up suggested (MSER-5, WIP)",
    ):
        assert row in text
    s = json.loads((out / "summary.json").read_text())
    assert s["warmup_s"] == 60.0
    assert (out / STATES_PNG).is_file() and (out / WIP_PNG).is_file()
    # --force clears the new files as the run's own.
    assert main(["run", str(FLEET), "--duration", "60", "--out", str(out), "--force"]) == 0


def test_the_study_report_gathers_the_runs_warm_up_suggestions(printed, tmp_path):
    _, s0, out0 = printed
    world = World(load_scenario(FLEET).override(robots=4, duration=600.0))
    s1 = world.run().summary
    world.write(tmp_path / "fleet")
    lines = warmup_lines([out0, tmp_path / "fleet", None, tmp_path / "absent"])
    text = "\n".join(lines)
    assert lines[1] == "## Warm-up"
    got = [s0["suggested_warmup_s"], s1["suggested_warmup_s"]]
    assert f"{np.median(got):.0f} s (median) to {max(got):.0f} s (largest) over 2 runs" in text
    limited = s0["suggested_warmup_at_limit"] + s1["suggested_warmup_at_limit"]
    assert ("run longer" in text) is (limited > 0)
    assert warmup_lines([tmp_path / "absent"]) == []
