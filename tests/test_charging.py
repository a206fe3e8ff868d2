"""Batteries, chargers and charging policies: energy bookkeeping on real runs, robots that charge
and go back to work, a robot that runs flat, the scenario's checks and the plugin contract."""

from __future__ import annotations

import csv
import json
import math
import re
import sys
import textwrap
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fleet.plugins.discovery as plugins_module
from fleet.engine import World
from fleet.errors import ScenarioError
from fleet.plugins import CHARGING_GROUP, BatteryStatus, ChargingPolicy, load_charging_policy
from fleet.plugins.testing import ConformanceError, check_charging_policy
from fleet.scenario import REPO_ROOT, load_scenario
from fleet.study.sweep import kpi_values
from fleet_plugins.charging import OpportunityCharging, ThresholdCharging

SHOP = (REPO_ROOT / "maps" / "shop_floor.toml").as_posix()


def scripted(tmp_path: Path, battery: str, charging: str, jobs: str, duration: float = 900.0):
    """A one-robot scenario on the shop floor starting at depot_a (6 m from charger_a)."""
    path = tmp_path / "run.toml"
    path.write_text(
        textwrap.dedent(
            f"""
            [scenario]
            map = "{SHOP}"
            duration_s = {duration}
            [robots]
            count = 1
            start = ["depot_a"]
            [jobs]
            mode = "scripted"
            [battery]
            {battery}
            [charging]
            {charging}
            """
        )
        + textwrap.dedent(jobs)
    )
    return load_scenario(path)


def events(world: World, robot: str = "r01") -> list[tuple[float, str, str]]:
    return [(e.t, e.event, e.job) for e in world.recorder.events if e.robot == robot]


def first(evs: list[tuple[float, str, str]], name: str) -> float:
    return next(t for t, e, _ in evs if e == name)


JOB_AT_20 = """
[[jobs.scripted]]
at_s = 20
station = "cnc_1_in"
print = [{ kind = "infill", start_s = 0, end_s = 60 }]
"""


def test_energy_used_is_per_metre_times_distance_plus_draws_times_their_hours() -> None:
    scenario = load_scenario(
        REPO_ROOT / "scenarios" / "charging.toml",
        {"scenario.duration_s": 1500.0, "robots.count": 2, "jobs.rate_per_h": 12.0},
    )
    world = World(scenario)
    summary = world.run().summary
    assert world.energy is not None
    battery = scenario.battery
    assert battery is not None
    per_robot = {p["id"]: p for p in summary["per_robot"]}
    assert summary["jobs"]["handed_back"] == 0
    printed = 0.0
    for rid, cell in world.energy.cells.items():
        track = world.recorder.trajectories[rid]
        end = track.t[-1]
        printing = sum(
            min(rec.print_end_s, end) - rec.print_start_s
            for rec in world.jobs
            if rec.robot == rid and rec.print_start_s is not None and rec.print_end_s is not None
        )
        printed += printing
        distance = per_robot[rid]["distance_m"]
        want = (
            battery.drive_wh_per_m * distance
            + battery.print_w * printing / 3600.0
            + battery.idle_w * end / 3600.0
        )
        assert cell.used_wh == pytest.approx(want, rel=1e-6, abs=1e-6)
        assert cell.driven_m == pytest.approx(distance, abs=1e-6)
        # What is left is what there was, less what was used, plus what the chargers gave.
        start = battery.capacity_wh * battery.initial_share
        assert cell.level_wh == pytest.approx(start - cell.used_wh + cell.charged_wh, abs=1e-9)
        mine = summary["battery"]["per_robot"][rid]
        assert mine["energy_used_wh"] == pytest.approx(want, rel=1e-6, abs=1e-5)
        assert 0.0 <= mine["min_charge_share"] <= mine["charge_end_share"] <= 1.0
    assert printed > 600.0  # the run printed and drove: the test could fail
    assert summary["battery"]["stranded"] == 0
    assert summary["violations"] == {k: 0 for k in summary["violations"]}


def test_a_low_robot_charges_first_then_takes_the_job_and_delivers_it(tmp_path: Path) -> None:
    scenario = scripted(
        tmp_path,
        "capacity_wh = 10.0\ninitial_share = 0.35\ncharge_w = 100.0\nidle_w = 5.0",
        'name = "threshold"\noptions = { threshold = 0.4, target = 0.9 }',
        JOB_AT_20,
    )
    world = World(scenario)
    summary = world.run().summary
    evs = events(world)
    went, start, end = first(evs, "charge_go"), first(evs, "charge_start"), first(evs, "charge_end")
    assigned, delivered = first(evs, "assigned"), first(evs, "delivered")
    assert went == 0.0 < start < 20.0 < end <= assigned < delivered
    robot = world.robots["r01"]
    assert not robot.charging and robot.charger_at is None
    cell = world.energy.cells["r01"]  # type: ignore[union-attr]
    # Charged to the target (at most one step of draw below it), at the charger's rate.
    assert summary["battery"]["per_robot"]["r01"]["charges"] == 1
    assert cell.charged_wh == pytest.approx(100.0 * (end - start) / 3600.0, rel=1e-9)
    assert summary["battery"]["charging_s"] == pytest.approx(end - start)
    # The per-robot state shares (fleet.engine.activity) count the same time as charging.
    shares = summary["states"]["robots"]["r01"]
    assert shares["charging"]["seconds"] == pytest.approx(end - start)
    assert summary["jobs"]["completed"] == 1 and summary["battery"]["stranded"] == 0
    # A study's results.csv carries the battery KPIs.
    kpis = kpi_values(json.loads(json.dumps(summary)))
    assert kpis["charging_share"] == pytest.approx((end - start) / summary["sim_time_s"], abs=1e-6)
    assert kpis["min_charge_share"] < 0.4 and kpis["stranded"] == 0 and kpis["handbacks"] == 0
    world.write(tmp_path / "out")
    rows = list(csv.DictReader((tmp_path / "out" / "battery.csv").open()))
    assert {r["state"] for r in rows} >= {"to_charger", "charging", "working"}


def test_an_opportunity_charger_leaves_at_once_for_a_job(tmp_path: Path) -> None:
    scenario = scripted(
        tmp_path,
        "capacity_wh = 100.0\ninitial_share = 0.7\ncharge_w = 100.0",
        'name = "opportunity"\noptions = { radius_m = 10.0 }',
        JOB_AT_20,
    )
    world = World(scenario)
    world.run()
    evs = events(world)
    start, end, assigned = (first(evs, e) for e in ("charge_start", "charge_end", "assigned"))
    # It charged until the job came, and left at once.
    assert start < 20.0 == assigned == end
    # Idle again after the delivery, next to the charger: it charges again.
    delivered = first(evs, "delivered")
    assert any(e == "charge_start" and t > delivered for t, e, _ in evs)


def test_a_robot_that_runs_flat_is_stranded_braked_and_hands_its_job_back(tmp_path: Path) -> None:
    scenario = scripted(
        tmp_path,
        "capacity_wh = 1.0\ninitial_share = 0.5\nprint_w = 60.0",
        'name = "threshold"\noptions = { threshold = 0.0, target = 0.5 }',  # never charges
        JOB_AT_20,
    )
    world = World(scenario)
    summary = world.run().summary
    evs = events(world)
    stranded = first(evs, "stranded")
    assert 20.0 < stranded < 60.0  # 0.5 Wh at 60 W lasts 30 s
    assert first(evs, "handed_back") == stranded
    assert summary["battery"]["stranded"] == 1 and summary["jobs"]["completed"] == 0
    robot = world.robots["r01"]
    assert robot.faulted and robot.vx == robot.vy == 0.0 and robot.plan == ()
    track = world.recorder.trajectories["r01"]
    after = [i for i, t in enumerate(track.t) if t > stranded + 10.0]
    assert {(track.x[i], track.y[i]) for i in after} == {(robot.x, robot.y)}
    assert summary["violations"] == {k: 0 for k in summary["violations"]}


def test_a_scenario_without_battery_has_no_energy_and_no_battery_figures() -> None:
    scenario = load_scenario(REPO_ROOT / "scenarios" / "default.toml").override(duration=30.0)
    world = World(scenario)
    summary = world.run().summary
    assert world.energy is None and scenario.battery is None and "battery" not in summary


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("battery.capacity_wh", 0, "positive"),
        ("battery.initial_share", 1.5, "share"),
        ("battery.drive_wh_per_m", -1, ">= 0"),
        ("battery.charge_w", "fast", "type"),
    ],
)
def test_bad_battery_values_name_the_field_and_value(key: str, value: object, words: str) -> None:
    with pytest.raises(ScenarioError, match=words) as info:
        load_scenario(REPO_ROOT / "scenarios" / "charging.toml", {key: value})
    assert info.value.field == key and info.value.value == value


def test_a_battery_on_a_map_without_chargers_is_refused(tmp_path: Path) -> None:
    scenario = load_scenario(
        REPO_ROOT / "scenarios" / "charging.toml",
        {"scenario.map": str(REPO_ROOT / "maps" / "paper_case3.toml"), "robots.start": ["start"]},
    )
    with pytest.raises(ScenarioError, match="no charger"):
        World(scenario)


def test_bad_policy_options_name_the_plugin_and_option() -> None:
    with pytest.raises(Exception, match="target"):
        load_charging_policy("threshold", {"threshold": 0.5, "target": 0.4})
    with pytest.raises(Exception, match="below"):
        load_charging_policy("opportunity", {"below": 0.99, "full": 0.98})


# --- the plugin contract ----------------------------------------------------------------------


@pytest.mark.parametrize("factory", [ThresholdCharging, OpportunityCharging])
def test_the_builtin_policies_pass_the_conformance_kit(factory: type[ChargingPolicy]) -> None:
    check_charging_policy(factory)


class NeverCharges(ChargingPolicy):
    def go_charge(self, status: BatteryStatus) -> str | None:
        return None

    def leave(self, status: BatteryStatus) -> bool:
        return True


class MadeUpCharger(NeverCharges):
    def go_charge(self, status: BatteryStatus) -> str | None:
        return "the moon"


class StaysForever(ChargingPolicy):
    def go_charge(self, status: BatteryStatus) -> str | None:
        return status.chargers[0].name

    def leave(self, status: BatteryStatus) -> bool:
        return False


@pytest.mark.parametrize(
    ("policy", "rule"),
    [(NeverCharges, "no-flat-battery"), (MadeUpCharger, "known-charger"), (StaysForever, "full")],
)
def test_the_kit_fails_a_bad_policy_naming_the_rule(policy: type, rule: str) -> None:
    with pytest.raises(ConformanceError, match=rule) as info:
        check_charging_policy(policy)
    assert info.value.rule.startswith(rule)


THIRD_PARTY = '''
from fleet.plugins import ChargingPolicy


class EagerCharging(ChargingPolicy):
    """Go to the nearest charger whenever idle below `below`; leave when full."""

    def __init__(self, below: float = 0.99) -> None:
        super().__init__()
        self.below = below

    def go_charge(self, status):
        if status.has_job or status.charge >= self.below:
            return None
        free = [c for c in status.chargers if c.occupant in (None, status.robot)]
        far = lambda c: (c.x - status.x) ** 2 + (c.y - status.y) ** 2
        return min(free or status.chargers, key=far).name

    def leave(self, status):
        return status.charge >= 1.0

    def takes_jobs(self, status):
        return True
'''


def test_a_third_party_policy_registered_through_entry_points_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    module = f"acme_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{module}.py").write_text(THIRD_PARTY)
    info = tmp_path / "acme_charging-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-charging\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{CHARGING_GROUP}]\neager = {module}:EagerCharging\n")
    monkeypatch.setattr(sys, "path", [*sys.path, str(tmp_path)])
    monkeypatch.setattr(plugins_module, "_CACHE", None)
    found = {i.name: i for i in plugins_module.discover("charging", refresh=True)}
    assert found["eager"].ok and found["eager"].distribution == "acme-charging"
    assert {"threshold", "opportunity"} <= set(found)
    policy = load_charging_policy("eager", {"below": 0.9})
    check_charging_policy(type(policy), options={"below": 0.9})
    scenario = scripted(
        tmp_path,
        "capacity_wh = 100.0\ninitial_share = 0.5\ncharge_w = 100.0",
        'name = "eager"\noptions = { below = 0.9 }',
        JOB_AT_20,
        duration=300.0,
    )
    world = World(scenario)
    summary = world.run().summary
    evs = events(world)
    assert first(evs, "charge_start") < 20.0 == first(evs, "assigned") == first(evs, "charge_end")
    assert summary["battery"]["policy"] == "eager"
    assert math.isclose(sum(1 for _, e, _ in evs if e == "delivered"), 1)


# --- the replay ---------------------------------------------------------------------------------


def test_the_replay_shows_each_robots_charge_and_when_it_charges(tmp_path: Path) -> None:
    from fleet.view.replay import write_replay
    from tests.test_replay import CHROMIUM, finish, screenshot

    scenario = scripted(
        tmp_path,
        "capacity_wh = 10.0\ninitial_share = 0.35\ncharge_w = 100.0",
        'name = "threshold"\noptions = { threshold = 0.4, target = 0.9 }',
        JOB_AT_20,
        duration=400.0,
    )
    world = World(scenario)
    world.run()
    run = tmp_path / "run"
    world.write(run)
    page = write_replay(run)
    text = page.read_text(encoding="utf-8")
    assert '"battery":{"t":[' in text
    if CHROMIUM is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium)")
    start = first(events(world), "charge_start")
    work = tmp_path / "shot"
    dom, _ = finish(screenshot(page, start + 60.0, work, (1280, 720)), work)
    shown = re.search(r"r01: <span[^>]*>([^<]*)</span>", dom)
    assert shown, dom[-2000:]
    # 35 % at the start, less the trip, plus 60 s at 100 W of a 10 Wh battery: about 50 %.
    m = re.fullmatch(r"idle \[battery (\d+) %, charging\]", shown.group(1))
    assert m and 45 <= int(m.group(1)) <= 55, shown.group(1)


# --- invariants on random batteries ---------------------------------------------------------


@settings(
    max_examples=6, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    seed=st.integers(1, 1000),
    policy=st.sampled_from(["threshold", "opportunity"]),
    capacity=st.floats(8.0, 40.0),
    initial=st.floats(0.2, 1.0),
)
def test_batteries_keep_the_fleet_safe_and_every_charger_to_one_robot(
    seed: int, policy: str, capacity: float, initial: float
) -> None:
    scenario = load_scenario(
        REPO_ROOT / "scenarios" / "charging.toml",
        {
            "scenario.seed": seed,
            "scenario.duration_s": 900.0,
            "robots.count": 3,
            "jobs.rate_per_h": 20.0,
            "battery.capacity_wh": capacity,
            "battery.initial_share": initial,
            "battery.charge_w": 400.0,
            "charging.name": policy,
            "charging.options": {},
        },
    )
    world = World(scenario)
    result = world.run()
    s = result.summary
    assert s["violations"] == {k: 0 for k in s["violations"]}, result.safety.examples
    assert s["jobs"]["accounted"]
    # A charger serves one robot at a time: its charge_start/charge_end intervals never overlap.
    holder: dict[str, str | None] = {}
    for e in world.recorder.events:
        if e.event == "charge_start":
            assert holder.get(e.station) is None, (e.t, e.station, holder)
            holder[e.station] = e.robot
        elif e.event == "charge_end":
            assert holder.get(e.station) == e.robot, (e.t, e.station, holder)
            holder[e.station] = None
    occupants = [o for o in world.energy.occupant.values() if o is not None]  # type: ignore[union-attr]
    assert len(occupants) == len(set(occupants))
    battery = s["battery"]
    assert battery["stranded"] == sum(e.event == "stranded" for e in world.recorder.events)
    start = capacity * initial
    for cell in world.energy.cells.values():  # type: ignore[union-attr]
        assert 0.0 <= cell.level_wh <= capacity + 1e-9
        assert cell.level_wh == pytest.approx(
            max(start - cell.used_wh + cell.charged_wh, 0.0), abs=1e-6
        )


def test_fleet_run_shows_charging_in_its_key_figures_and_lists_the_policies(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from fleet.cli import main

    scenario = REPO_ROOT / "scenarios" / "charging.toml"
    args = ["run", str(scenario), "--duration", "240", "--out", str(tmp_path / "run")]
    assert main([*args, "--no-figures", "--set", "battery.initial_share=0.2"]) == 0
    printed = capsys.readouterr().out
    # Every robot starts below the threshold and drives to a charger; two charge at once.
    figures = re.search(
        r"charging time \(fleet\) / charges\s*│\s*([\d.]+) h \((\d+)%\) / (\d+)", printed
    )
    assert figures and float(figures[1]) > 0 and int(figures[3]) == 2, printed
    assert re.search(r"lowest charge / robots stranded\s*│\s*\d+% / 0", printed)
    assert (tmp_path / "run" / "battery.csv").is_file()
    assert main(["plugins"]) == 0
    listed = capsys.readouterr().out
    assert "threshold" in listed and "opportunity" in listed and "charging" in listed


def test_the_study_sweeps_the_charging_policy_as_a_plugin_axis(tmp_path: Path) -> None:
    from fleet.study.sweep import StudyError, load_study

    study = load_study(REPO_ROOT / "studies" / "charging.toml")
    assert [a.name for a in study.axes] == ["charging"]
    assert [v.label for v in study.axes[0].values] == ["threshold", "opportunity"]
    assert len(study.cells) == 10
    names = {c.raw["charging"]["name"] for c in study.cells}
    assert names == {"threshold", "opportunity"}
    bad = tmp_path / "bad.toml"
    bad.write_text(
        f'[study]\nscenario = "{(REPO_ROOT / "scenarios" / "charging.toml").as_posix()}"\n'
        '[grid]\ncharging = [{ name = "threshold", options = { target = 2 } }]\n'
    )
    with pytest.raises(StudyError, match=r"grid\.charging\[0\].*target"):
        load_study(bad)
