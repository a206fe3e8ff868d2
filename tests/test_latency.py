"""Compute latency (``[scenario] latency``, ``--latency``): a command takes effect after its
latency, the step's input is the time-weighted mean of the inputs in force, newer commands
supersede older pending ones, and the summary reports what the commands waited."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest

import fleet.engine.agents as agents_module
from fleet.cli import main
from fleet.engine import World
from fleet.errors import ScenarioError
from fleet.plugins import Command, Controller, SolveReport, SolverOutcome
from fleet.plugins.robot import clip
from fleet.scenario import Latency, Scenario, load_scenario

from .test_engine import MAP, print_scenario

OPEN_HALL = """
[floor]
name = "open hall"
rect = [0, 0, 40, 40]
default_v_max = 1.0

[[stations]]
name = "depot"
at = [20, 20]
kind = "depot"

[[stations]]
name = "far"
at = [35, 35]
"""

DT = 0.25
A_MAX = 0.5
#: Open-loop inputs by tick, cycled; some beyond a_max to show they are clipped before blending.
INPUTS = [(0.4, -0.3), (0.8, 0.1), (-0.2, 0.5), (0.0, -0.6), (0.3, 0.2), (-0.5, -0.1)]


class Scripted(Controller):
    """Sends `script(tick)` whatever it observes, and keeps what it sent as ``(t, ax, ay)``."""

    def __init__(self, script: Callable[[int], Command]) -> None:
        self.script = script
        self.sent: list[tuple[float, float, float]] = []

    def compute(self, obs):  # type: ignore[no-untyped-def]
        cmd = self.script(obs.tick)
        self.sent.append((obs.t, cmd.ax, cmd.ay))
        return cmd


def open_loop(tick: int) -> Command:
    # Out and back: the second half of each 48-tick cycle mirrors the first.
    ax, ay = INPUTS[tick % len(INPUTS)]
    sign = 1.0 if tick % 48 < 24 else -1.0
    return Command(sign * ax, sign * ay)


@pytest.fixture
def one_robot(tmp_path: Path) -> Scenario:
    """One robot at rest in an empty hall; its one job is released after the run ends."""
    (tmp_path / "open.toml").write_text(OPEN_HALL)
    path = tmp_path / "one.toml"
    path.write_text(
        '[scenario]\nmap = "open.toml"\nduration_s = 12\n'
        f"[robots]\ncount = 1\nperiod_s = {DT}\na_max = {A_MAX}\nreturn_home = false\n"
        '[jobs]\nmode = "scripted"\n[[jobs.scripted]]\nat_s = 1000\nstation = "far"\n'
    )
    return load_scenario(path)


def run_scripted(
    monkeypatch: pytest.MonkeyPatch,
    scenario: Scenario,
    script: Callable[[int], Command],
    latency: Latency,
) -> tuple[World, Scripted]:
    controller = Scripted(script)
    monkeypatch.setattr(agents_module, "load_controller", lambda name, options: controller)
    world = World(replace(scenario, latency=latency))
    world.run()
    return world, controller


@pytest.fixture
def hall(tmp_path: Path) -> Scenario:
    """Three followers delivering jobs on the engine tests' hall for 40 s."""
    (tmp_path / "hall.toml").write_text(MAP)
    path = tmp_path / "hall_run.toml"
    path.write_text(
        '[scenario]\nmap = "hall.toml"\nduration_s = 40\nseed = 3\nsensing_radius_m = 6\n'
        '[robots]\ncount = 3\nperiod_s = 0.25\n[jobs]\nrate_per_h = 360\nstations = ["east"]\n'
    )
    return load_scenario(path)


# --- reproducibility --------------------------------------------------------------------------


def test_no_latency_fixed_zero_and_measured_without_reports_move_robots_alike(hall):
    digests = {
        str(latency): World(replace(hall, latency=latency)).run().summary["digest"]
        for latency in (None, 0.0, "measured")  # the follower reports no solves: instant
    }
    assert len(set(digests.values())) == 1, digests


def test_a_fixed_latency_is_reproducible_and_changes_the_motion(hall):
    none = World(hall).run().summary
    first, second = (World(replace(hall, latency=0.1)).run().summary for _ in range(2))
    assert first["digest"] == second["digest"] != none["digest"]
    assert none["latency"] == {
        "mode": "none",
        "commands": 0,
        "median_ms": None,
        "p95_ms": None,
        "max_ms": None,
        "late": 0,
        "instant": 0,
    }
    lat = first["latency"]
    assert lat["mode"] == "fixed" and lat["commands"] == first["engine"]["robot_steps"]
    assert lat["median_ms"] == lat["p95_ms"] == lat["max_ms"] == 100.0 and lat["late"] == 0


# --- the blend, by hand ----------------------------------------------------------------------


def test_a_latency_within_the_period_blends_the_old_and_new_input(monkeypatch, one_robot):
    latency = 0.1
    world, controller = run_scripted(monkeypatch, one_robot, open_loop, latency)
    tr = world.recorder.trajectories["r01"]
    assert len(controller.sent) == len(tr.vx) == 48  # ticks at 0, 0.25, ..., 11.75 s
    # Over [t_k, t_k + dt) the previous input holds for `latency`, this tick's for the rest.
    vx = vy = 0.0
    prev = (0.0, 0.0)
    for k, (t, ax, ay) in enumerate(controller.sent[:-1]):
        assert t == pytest.approx(k * DT)
        now = (clip(ax, A_MAX), clip(ay, A_MAX))
        vx += DT * (latency * prev[0] + (DT - latency) * now[0]) / DT
        vy += DT * (latency * prev[1] + (DT - latency) * now[1]) / DT
        assert (tr.vx[k + 1], tr.vy[k + 1]) == pytest.approx((vx, vy), abs=1e-12), k
        prev = now
    # The clipped inputs (0.8 -> 0.5, -0.6 -> -0.5) were really exercised.
    assert any(abs(ax) > A_MAX for _, ax, _ in controller.sent)
    s = world.result.summary["latency"]
    assert s["mode"] == "fixed" and s["commands"] == 48 and s["late"] == 0


def test_a_latency_of_two_periods_delays_the_response_by_two_ticks(monkeypatch, one_robot):
    prompt, _ = run_scripted(monkeypatch, one_robot, open_loop, None)
    late, _ = run_scripted(monkeypatch, one_robot, open_loop, 2 * DT)
    a, b = prompt.recorder.trajectories["r01"], late.recorder.trajectories["r01"]
    for column in ("x", "y", "vx", "vy"):
        now, delayed = getattr(a, column), getattr(b, column)
        assert delayed[:3] == [now[0]] * 3  # nothing happens for two steps
        assert delayed[2:] == pytest.approx(now[:-2], abs=1e-12), column
    s = late.result.summary["latency"]
    assert s["median_ms"] == s["max_ms"] == 500.0
    assert s["late"] == s["commands"] == 48  # every command missed its own step


def test_a_newer_command_taking_effect_first_supersedes_an_older_one(monkeypatch, one_robot):
    """Measured mode with chosen step times: tick 0's 0.5 m/s^2 would take effect at 0.6 s,
    but tick 1's -0.3 takes effect at 0.3 s, so the 0.5 never applies."""

    def script(tick: int) -> Command:
        ax, step = {0: (0.5, 0.6), 1: (-0.3, 0.05)}.get(tick, (0.1, 0.6))
        return Command(ax, 0.0, solve=SolveReport(SolverOutcome.OPTIMAL, step / 2, step))

    world, _ = run_scripted(monkeypatch, one_robot, script, "measured")
    vx = world.recorder.trajectories["r01"].vx
    expected = [
        0.0,
        0.0,  # [0, 0.25): nothing in force yet
        -0.06,  # [0.25, 0.5): 0 for 0.05 s, then -0.3 (tick 1, at 0.3 s) for 0.2 s
        -0.135,  # [0.5, 0.75): -0.3 throughout (tick 0's 0.5 at 0.6 s was superseded)
        -0.21,
        -0.225,  # [1, 1.25): -0.3 for 0.1 s, then tick 2's 0.1 (at 1.1 s) for 0.15 s
        -0.2,
    ]
    assert vx[: len(expected)] == pytest.approx(expected, abs=1e-12)
    s = world.result.summary["latency"]
    assert s["mode"] == "measured" and s["max_ms"] == 600.0
    assert s["late"] == s["commands"] - 1  # all but tick 1's 0.05 s


# --- the MPC, as measured --------------------------------------------------------------------


def test_measured_latency_of_the_mpc_is_reported_and_its_violations_counted(tmp_path):
    sc = replace(load_scenario(print_scenario(tmp_path, "mpc")), duration_s=20.0)
    s = World(replace(sc, latency="measured")).run().summary
    lat = s["latency"]
    assert lat["mode"] == "measured"
    # Every command with a solve report waited for its step; the rest (the MPC holding a
    # parked robot, idle robots braking) applied at once.
    assert lat["commands"] == s["solver"]["steps"] > 0
    assert lat["commands"] + lat["instant"] == s["engine"]["robot_steps"]
    assert lat["median_ms"] >= s["solver"]["step_median_ms"] * 0.999  # the step time itself
    assert 0 < lat["median_ms"] <= lat["p95_ms"] <= lat["max_ms"]
    # (Violations are not asserted to be zero: a slow solve may cost one, which is counted.)


# --- settings and errors -----------------------------------------------------------------------


def scenario_with(tmp_path: Path, line: str) -> Path:
    (tmp_path / "hall.toml").write_text(MAP)
    path = tmp_path / "lat.toml"
    path.write_text(f'[scenario]\nmap = "hall.toml"\n{line}\n')
    return path


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("", None),
        ('latency = "none"', None),
        ('latency = "measured"', "measured"),
        ("latency = 0", 0.0),
        ("latency = 0.12", 0.12),
    ],
)
def test_the_latency_setting_is_read_from_the_file(tmp_path, line, expected):
    assert load_scenario(scenario_with(tmp_path, line)).latency == expected


@pytest.mark.parametrize(
    ("line", "shown"),
    [
        ('latency = "fast"', "'fast'"),
        ('latency = "0.1"', "'0.1'"),  # a number in the file is written as a number
        ("latency = -0.1", "-0.1"),
        ("latency = nan", "nan"),
        ("latency = true", "True"),
        ("latency = [0.1]", "[0.1]"),
    ],
)
def test_a_bad_latency_in_the_file_names_file_field_value_and_what_is_allowed(
    tmp_path, line, shown
):
    path = scenario_with(tmp_path, line)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.field == "scenario.latency" and err.value.source == str(path)
    message = str(err.value)
    assert f"scenario.latency = {shown}" in message
    assert '"none"' in message and '"measured"' in message and "seconds >= 0" in message


def test_a_bad_latency_in_a_scenario_built_in_code_is_refused_by_the_world(hall):
    with pytest.raises(ScenarioError, match=r"scenario\.latency.*'fast'.*measured"):
        World(replace(hall, latency="fast"))  # type: ignore[arg-type]


def test_the_command_line_overrides_the_file(tmp_path):
    sc = load_scenario(scenario_with(tmp_path, 'latency = "measured"'))
    assert sc.override(latency="0.25").latency == 0.25
    assert sc.override(latency="none").latency is None
    assert sc.override().latency == "measured"
    with pytest.raises(ScenarioError, match=r"command line: --latency = 'soon': must be \"none\""):
        sc.override(latency="soon")
    with pytest.raises(ScenarioError, match="--latency = '-1'"):
        sc.override(latency="-1")


def test_fleet_run_takes_latency_and_reports_it(tmp_path, capsys):
    path = scenario_with(tmp_path, "duration_s = 10\n[robots]\ncount = 1")
    out = tmp_path / "run"
    argv = ["run", str(path), "--out", str(out), "--no-figures", "--latency", "0.3"]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["latency"]["mode"] == "fixed" and summary["latency"]["max_ms"] == 300.0
    assert "commands later than their period" in capsys.readouterr().out
    assert main([*argv[:-1], "eventually"]) == 1
    err = capsys.readouterr().err
    assert "--latency = 'eventually'" in err and "measured" in err
