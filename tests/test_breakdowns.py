"""Breakdowns (issue 18, part 4): robots fail at random and are repaired where they stopped.

Real runs of the engine: failure times come from the seed through streams of their own (the same
with agents in worker processes, the same for a robot whatever the rest of the fleet, and no job
arrival moves when breakdowns are switched on); availability is 1 - repair time / run length; a
breakdown mid-print hands the job back with the reason "breakdown" and scraps the part; a broken
robot stands still until repaired; and `[breakdowns]` is read and refused as other tables are.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from fleet.cli import main
from fleet.engine import World
from fleet.engine.breakdowns import draw
from fleet.errors import ScenarioError
from fleet.printing import PrintTask
from fleet.scenario import (
    REPO_ROOT,
    BreakdownsConfig,
    JobsConfig,
    RobotsConfig,
    ScriptedJob,
    load_scenario,
)
from fleet.view.figures import load_tracks
from fleet.view.replay import write_replay
from tests.test_replay import (
    CHROMIUM,
    WINDOWS,
    finish,
    page_data,
    page_view,
    position,
    probe,
    probed,
    rgb,
    screenshot,
)

HALL = Path(__file__).resolve().parent / "cases" / "same_station" / "scen.toml"
DEFAULT = REPO_ROOT / "scenarios" / "default.toml"


def events(world: World, *kinds: str) -> list[tuple[float, str, str, str, str]]:
    return [
        (e.t, e.event, e.job, e.robot, e.station)
        for e in world.recorder.events
        if not kinds or e.event in kinds
    ]


def default_run(duration: float, breakdowns: BreakdownsConfig | None, **kw) -> World:
    sc = load_scenario(DEFAULT).override(duration=duration, **kw)
    world = World(replace(sc, breakdowns=breakdowns))
    world.run()
    return world


def spans(world: World, robot: str) -> list[tuple[float, float]]:
    """(breakdown, repaired) times of `robot` from its events; a repair under way ends at the
    end of the run."""
    out: list[tuple[float, float]] = []
    for t, kind, _, rid, _ in events(world, "breakdown", "repaired"):
        if rid != robot:
            continue
        if kind == "breakdown":
            out.append((t, math.nan))
        else:
            out[-1] = (out[-1][0], t)
    end = float(world.env.now)
    return [(a, end if math.isnan(b) else b) for a, b in out]


# -- the scenario table --------------------------------------------------------------------------
def write_scenario(tmp_path: Path, table: str) -> Path:
    """The hall scenario with `table` added, written into `tmp_path`."""
    text = HALL.read_text(encoding="utf-8")
    text = text.replace('map = "floor.toml"', f'map = "{HALL.parent / "floor.toml"}"')
    path = tmp_path / "scen.toml"
    path.write_text(text + "\n" + table, encoding="utf-8")
    return path


def test_a_scenario_without_the_table_has_no_breakdowns():
    assert load_scenario(HALL).breakdowns is None


def test_the_table_is_read_with_its_defaults(tmp_path):
    sc = load_scenario(write_scenario(tmp_path, "[breakdowns]\nmtbf_s = 3600\nmttr_s = 300\n"))
    b = sc.breakdowns
    assert b == BreakdownsConfig(3600.0, 300.0, "exponential", "exponential", 0.5, ())
    assert b.for_group(0) == (3600.0, 300.0)


def test_groups_override_the_table_one_per_robot_group(tmp_path):
    text = HALL.read_text(encoding="utf-8")
    text = text.replace('map = "floor.toml"', f'map = "{HALL.parent / "floor.toml"}"')
    text = text.replace("[robots]\ncount = 3", "[[robots]]\ncount = 1")
    text = text.replace("return_home = true\n", "return_home = true\n\n[[robots]]\ncount = 2\n", 1)
    path = tmp_path / "groups.toml"
    path.write_text(
        text + '\n[breakdowns]\nmtbf_s = 600\nmttr_s = 60\nrepairs = "lognormal"\n'
        "groups = [{}, { mtbf_s = 0, mttr_s = 5 }]\n",
        encoding="utf-8",
    )
    b = load_scenario(path).breakdowns
    assert b is not None and b.repairs == "lognormal"
    assert b.for_group(0) == (600.0, 60.0)
    assert b.for_group(1) == (0.0, 5.0)
    path.write_text(text + "\n[breakdowns]\nmtbf_s = 600\nmttr_s = 60\ngroups = [{}]\n")
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.field == "breakdowns.groups"
    assert "one entry per robot group (2)" in str(err.value)


@pytest.mark.parametrize(
    ("table", "field", "words"),
    [
        ("mtbf_s = 600\nmttr_s = 0", "breakdowns.mttr_s", "positive number"),
        ("mtbf_s = -1\nmttr_s = 60", "breakdowns.mtbf_s", ">= 0"),
        ("mttr_s = 60", "breakdowns.mtbf_s", "is required"),
        ('mtbf_s = 600\nmttr_s = 60\nrepairs = "weibull"', "breakdowns.repairs", "lognormal"),
        ("mtbf_s = 600\nmttr_s = 60\nmtbf = 3", "breakdowns.mtbf", "unknown key"),
    ],
)
def test_bad_values_are_refused_naming_file_field_and_value(tmp_path, table, field, words):
    path = write_scenario(tmp_path, "[breakdowns]\n" + table + "\n")
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.field == field
    assert str(path) in str(err.value) and words in str(err.value)


def test_draws_have_the_means_asked_for():
    rng = np.random.default_rng(0)
    for kind in ("exponential", "lognormal"):
        x = np.array([draw(rng, 120.0, kind, 0.5) for _ in range(20000)])
        assert abs(x.mean() - 120.0) < 0.03 * 120.0, kind
    x = np.array([draw(rng, 120.0, "lognormal", 0.5) for _ in range(20000)])
    assert abs(x.std() / x.mean() - 0.5) < 0.05
    assert draw(rng, 7.0, "fixed") == 7.0


# -- real runs -----------------------------------------------------------------------------------
RANDOM = BreakdownsConfig(mtbf_s=200.0, mttr_s=60.0)


def test_failure_times_come_from_the_seed_alone():
    # 300 s: 7 breakdowns with seed 1, 10 with seed 2.
    a = default_run(300.0, RANDOM)
    b = default_run(300.0, RANDOM)
    c = default_run(300.0, RANDOM, seed=2)
    times = events(a, "breakdown", "repaired")
    assert len(events(a, "breakdown")) >= 3  # not vacuous
    assert [(t, k, r) for t, k, _, r, _ in times] == [
        (t, k, r) for t, k, _, r, _ in events(b, "breakdown", "repaired")
    ]
    assert [t for t, *_ in times] != [t for t, *_ in events(c, "breakdown", "repaired")]


def test_a_robots_failure_times_do_not_depend_on_the_rest_of_the_fleet():
    # Each robot draws from streams of its own: r01 and r02 fail and are repaired at the same
    # times in a fleet of two as in a fleet of four.
    # 300 s: r01 breaks down three times, r02 once.
    small = default_run(300.0, RANDOM, robots=2)
    large = default_run(300.0, RANDOM, robots=4)
    for robot in ("r01", "r02"):
        assert spans(small, robot) == spans(large, robot)
        assert spans(small, robot)


def test_switching_breakdowns_on_moves_no_job_arrival():
    # 600 s hold the same three releases (386, 413 and 545 s) as 900 s did.
    off = default_run(600.0, None)
    on = default_run(600.0, BreakdownsConfig(mtbf_s=120.0, mttr_s=60.0))
    released = events(off, "released")
    assert len(released) >= 2
    assert events(on, "released") == released
    assert events(on, "breakdown")
    # And a table that breaks nothing down runs bit-identically to no table.
    zero = default_run(600.0, BreakdownsConfig(mtbf_s=0.0, mttr_s=60.0))
    assert zero.result.summary["digest"] == off.result.summary["digest"]
    assert zero.result.summary["breakdowns"]["breakdowns"] == 0


def test_failure_times_are_the_same_with_agents_in_worker_processes():
    sc = load_scenario(HALL).override(duration=120.0)
    sc = replace(sc, breakdowns=BreakdownsConfig(mtbf_s=30.0, mttr_s=20.0))
    here, there = World(sc), World(sc, workers=2)
    here.run()
    there.run()
    assert events(here, "breakdown", "repaired")
    assert events(here) == events(there)
    assert here.result.summary["digest"] == there.result.summary["digest"]


def test_availability_is_one_minus_repair_time_over_the_run_length():
    world = default_run(450.0, BreakdownsConfig(mtbf_s=150.0, mttr_s=90.0))  # 16 breakdowns
    s = world.result.summary["breakdowns"]
    length = world.env.now
    assert s["breakdowns"] >= 6
    down_total = 0.0
    for entry in s["per_robot"]:
        down = sum(b - a for a, b in spans(world, entry["id"]))
        down_total += down
        assert entry["repair_s"] == pytest.approx(down, abs=1e-5)
        assert entry["availability"] == pytest.approx(1.0 - down / length, abs=1e-6)
        assert entry["breakdowns"] == len(spans(world, entry["id"]))
    assert s["availability"] == pytest.approx(1.0 - down_total / (6 * length), abs=1e-6)
    assert s["availability"] < 1.0


def test_fixed_times_give_the_availability_they_imply():
    # Fail 100 s after the start or a repair, repaired in 50 s: down 100-150 and 250-300 of 400.
    world = default_run(
        400.0, BreakdownsConfig(mtbf_s=100.0, mttr_s=50.0, failures="fixed", repairs="fixed")
    )
    s = world.result.summary["breakdowns"]
    assert s["breakdowns"] == 6 * 2 and s["repaired"] == 12
    assert s["mean_repair_s"] == pytest.approx(50.0)
    assert all(e["availability"] == pytest.approx(0.75) for e in s["per_robot"])


def print_world(
    breakdowns: BreakdownsConfig, duration: float = 400.0, max_handbacks: int = 3
) -> World:
    """Two robots at one depot; one job printing for 60 s on its way to the goal."""
    sc = load_scenario(HALL).override(duration=duration)
    job = ScriptedJob(0.0, "goal", tasks=(PrintTask("contour", 0.0, 60.0),))
    sc = replace(
        sc,
        robots=(
            RobotsConfig(count=1, start=("depot_a",)),
            RobotsConfig(count=1, start=("depot_a",)),
        ),
        jobs=JobsConfig(mode="scripted", scripted=(job,), max_handbacks=max_handbacks),
        print_caps={"contour": 0.3},
        breakdowns=breakdowns,
    )
    world = World(sc)
    world.run()
    return world


def test_a_breakdown_mid_print_hands_the_job_back_and_scraps_the_part():
    # r01 breaks down 20 s into the run (it took the job at 0), r02 never does.
    b = BreakdownsConfig(
        mtbf_s=20.0,
        mttr_s=100.0,
        failures="fixed",
        repairs="fixed",
        groups=((None, None), (0.0, None)),
    )
    world = print_world(b)
    first = events(world, "assigned")[0]
    assert first[:2] == (0.0, "assigned") and first[3] == "r01"
    assert events(world, "breakdown")[0] == (20.0, "breakdown", first[2], "r01", "")
    handed = events(world, "handed_back")
    assert handed == [(20.0, "handed_back", first[2], "r01", "breakdown")]
    # The part is printed anew by r02 and delivered; the 20 s printed on r01 are scrapped.
    rec = world.jobs[0]
    assert rec.robot == "r02" and rec.delivered_s is not None
    assert rec.print_start_s is not None and rec.print_start_s >= 20.0
    s = world.result.summary
    assert s["breakdowns"]["jobs_handed_back"] == 1
    assert s["breakdowns"]["print_scrapped_s"] == pytest.approx(20.0, abs=0.3)
    assert s["jobs"]["accounted"] and s["violations"]["collision"] == 0


def test_a_broken_robot_brakes_to_rest_and_stands_still_until_repaired():
    b = BreakdownsConfig(
        mtbf_s=20.0,
        mttr_s=100.0,
        failures="fixed",
        repairs="fixed",
        groups=((None, None), (0.0, None)),
    )
    world = print_world(b)
    tr = world.recorder.trajectories["r01"]
    t = np.asarray(tr.t)
    x, y = np.asarray(tr.x), np.asarray(tr.y)
    vx, vy = np.asarray(tr.vx), np.asarray(tr.vy)
    assert np.hypot(vx[t <= 20.0], vy[t <= 20.0]).max() > 0.1  # it was on its way
    # Braking at a_max from at most 0.3 m/s per axis takes under a second (plus a tick).
    still = (t >= 21.5) & (t < 120.0)
    assert still.sum() > 300
    assert np.all(np.hypot(vx[still], vy[still]) < 1e-9)
    assert np.ptp(x[still]) < 1e-9 and np.ptp(y[still]) < 1e-9
    # After the repair it drives home.
    after = t > 121.0
    assert np.hypot(vx[after], vy[after]).max() > 0.1
    assert events(world, "repaired")[0] == (120.0, "repaired", "", "r01", "")


def test_the_cli_shows_availability_and_the_summary_holds_it(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(
        [
            "run",
            str(HALL),
            "--duration",
            "120",
            "--no-figures",
            "--set",
            "breakdowns.mtbf_s=30",
            "--set",
            "breakdowns.mttr_s=20",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "availability / breakdowns / repair" in text
    assert "jobs handed back by breakdowns" in text
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    with (out / "events.csv").open(encoding="utf-8") as fh:
        kinds = {row["event"] for row in csv.DictReader(fh)}
    assert {"breakdown", "repaired"} <= kinds
    assert summary["breakdowns"]["configured"] is True
    assert 0.0 < summary["breakdowns"]["availability"] < 1.0


def test_hand_backs_by_breakdowns_do_not_make_a_job_fail():
    # Both robots break down every 15 s in service: the 60 s print is handed back again and
    # again, never given up (a breakdown is no fault of the job's), even with max_handbacks 0.
    b = BreakdownsConfig(mtbf_s=15.0, mttr_s=5.0, failures="fixed", repairs="fixed")
    world = print_world(b, duration=120.0, max_handbacks=0)
    rec = world.jobs[0]
    assert rec.handbacks >= 3
    assert rec.failed_s is None and not events(world, "failed")
    assert {e[4] for e in events(world, "handed_back")} == {"breakdown"}
    assert world.result.summary["jobs"]["accounted"]


def test_the_replay_marks_a_broken_down_robot(tmp_path):

    b = BreakdownsConfig(
        mtbf_s=20.0,
        mttr_s=100.0,
        failures="fixed",
        repairs="fixed",
        groups=((None, None), (0.0, None)),
    )
    world = print_world(b, duration=160.0)
    run = tmp_path / "run"
    world.write(run)
    page = write_replay(run)
    robots = {r["id"]: r for r in page_data(page)["robots"]}
    assert robots["r01"]["broken"] == [[20.0, 120.0], [140.0, None]]
    assert robots["r02"]["broken"] == []
    if CHROMIUM is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium)")
    procs = [
        screenshot(probed(page, f"at{t}.html"), t, tmp_path / f"shot{t}", WINDOWS[0])
        for t in (60.0, 130.0)
    ]
    (dom, shot), (dom_after, _) = (
        finish(p, tmp_path / f"shot{t}") for p, t in zip(procs, (60.0, 130.0), strict=True)
    )
    assert "broken down (repaired at 120 s)" in dom
    assert "broken down" not in dom_after.split('id="robots"')[1].split("</ul>")[0]
    view, (left, top) = page_view(probe(dom))
    x, y = np.array(view.pixel(*position(load_tracks(run / "trajectories.csv")["r01"], 60.0)))
    centre = imread(shot)[int(y + top), int(x + left), :3]
    assert np.abs(centre - rgb("#7b3294")).max() < 0.1, centre  # the purple cross over its disk


def test_time_broken_down_is_the_faulted_share_of_the_robot_states():
    # The per-robot state shares (fleet.engine.activity) count a broken-down robot as faulted,
    # step by step: their faulted seconds are its repair time, to within a control period per
    # breakdown (each one starts and ends between two ticks).
    world = default_run(600.0, BreakdownsConfig(mtbf_s=150.0, mttr_s=90.0))
    s = world.result.summary
    period = 0.25
    for entry in s["breakdowns"]["per_robot"]:
        states = s["states"]["robots"][entry["id"]]
        slack = period * max(1, entry["breakdowns"]) + 1e-9
        assert abs(states["faulted"]["seconds"] - entry["repair_s"]) < slack
        assert sum(v["seconds"] for v in states.values()) == pytest.approx(600.0)
    assert s["breakdowns"]["repair_s"] > 300.0  # not vacuous
