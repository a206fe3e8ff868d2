"""The pipelined lockstep (``[bus] lockstep = "pipelined"``): commands answer the next tick's
observation, the engine steps the world while the agents compute.

Real runs throughout: the engine, real HiGHS solves, worker processes over ipc://.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fleet.bus import AgentHost, Exchange
from fleet.engine import World
from fleet.errors import ScenarioError
from fleet.plugins import Command, Controller, ControlStatus, Observation
from fleet.scenario import REPO_ROOT, PluginChoice, load_scenario
from tests.test_fleet import check_accounting, fleet_scenario

NO_VIOLATIONS = {"obstacle": 0, "speed_zone": 0, "print_speed": 0, "collision": 0}


def pipelined(scenario):
    return replace(scenario, bus=replace(scenario.bus, lockstep="pipelined"))


def busy_fleet(robots: int, duration: float, controller: str = "follower"):
    """scenarios/fleet.toml with `robots` robots and a job every 30 s per robot."""
    sc = fleet_scenario(robots=robots, duration=duration, controller=controller)
    return replace(sc, jobs=replace(sc.jobs, rate_per_h=120.0 * robots))


# -- the option ---------------------------------------------------------------------------------


def write_scenario(tmp_path: Path, bus: str, scenario: str = "") -> Path:
    text = (REPO_ROOT / "scenarios" / "fleet.toml").read_text()
    text = text.replace('map = "../maps/', f'map = "{REPO_ROOT}/maps/')
    text = text.replace("[scenario]\n", f"[scenario]\n{scenario}")
    text = text.replace("[bus]\n", f"[bus]\n{bus}")
    path = tmp_path / "fleet.toml"
    path.write_text(text)
    tomllib.loads(text)  # the test's own edit is valid TOML
    return path


def test_the_lockstep_is_strict_unless_the_scenario_asks_for_pipelined(tmp_path):
    assert load_scenario(REPO_ROOT / "scenarios" / "fleet.toml").bus.lockstep == "strict"
    sc = load_scenario(write_scenario(tmp_path, 'lockstep = "pipelined"\n'))
    assert sc.bus.lockstep == "pipelined"


def test_a_bad_lockstep_is_refused_naming_the_file_field_and_value(tmp_path):
    path = write_scenario(tmp_path, 'lockstep = "eager"\n')
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert str(path) in str(err.value) and "bus.lockstep" in str(err.value)
    assert "eager" in str(err.value)


def test_a_pipelined_lockstep_refuses_a_compute_latency(tmp_path):
    path = write_scenario(tmp_path, 'lockstep = "pipelined"\n', "latency = 0.1\n")
    with pytest.raises(ScenarioError, match=r"scenario\.latency.*0\.1.*pipelined"):
        load_scenario(path)
    sc = load_scenario(write_scenario(tmp_path, 'lockstep = "pipelined"\n'))
    with pytest.raises(ScenarioError, match=r"--latency.*measured.*pipelined"):
        sc.override(latency="measured")
    with pytest.raises(ScenarioError, match=r"scenario\.latency"):
        World(replace(sc, latency=0.25, duration_s=1.0))  # set in code


# -- the exchange's two halves -----------------------------------------------------------------


class Echo(Controller):
    """Answers ``ax = tick`` so a test can tell which observation a command answers."""

    def compute(self, obs: Observation) -> Command:
        return Command(float(obs.tick), 0.0, ControlStatus.OK)


def test_send_and_collect_make_one_round_and_must_alternate():
    with Exchange() as exchange:
        host = AgentHost(exchange.address, {"r1": Echo(), "r2": Echo()}, name="local")
        exchange.add_local(host)
        exchange.wait_for_agents(["r1", "r2"], 5.0)
        with pytest.raises(ValueError, match="no round to collect"):
            exchange.collect()
        obs = [Observation(r, 3, 0.75, 0.0, 0.0, 0.0, 0.0) for r in ("r2", "r1")]
        exchange.send(1, 0.75, obs)
        assert exchange.outstanding
        with pytest.raises(ValueError, match="tick 1 was sent and not collected"):
            exchange.send(2, 1.0, obs)
        assert exchange.collect() == {"r1": Command(3.0, 0.0), "r2": Command(3.0, 0.0)}
        assert not exchange.outstanding
        assert exchange.round(2, 1.0, obs[:1]) == {"r2": Command(3.0, 0.0)}
        assert exchange.stats["rounds"] == 2 and exchange.stats["commands_missing"] == 0


# -- what the controllers see ---------------------------------------------------------------------


def test_each_command_answers_the_state_the_robot_has_when_it_takes_effect():
    sc = pipelined(busy_fleet(4, 60.0))
    world = World(sc)
    assert world.host is not None
    seen: dict[str, list[Observation]] = {}
    answers: dict[tuple[str, float], Command] = {}
    for rid, controller in world.host.controllers.items():

        def compute(obs, rid=rid, inner=controller.compute):
            seen.setdefault(rid, []).append(obs)
            cmd = inner(obs)
            answers[(rid, obs.t)] = cmd
            return cmd

        controller.compute = compute  # type: ignore[method-assign]
    s = world.run().summary
    assert s["violations"] == NO_VIOLATIONS and s["jobs"]["completed"] >= 2
    period = sc.robots[0].period_s
    checked = 0
    for rid, observations in seen.items():
        t, xy, v = world.recorder.trajectories[rid].arrays()
        # The first observation is of tick 1: the robots stand still at tick 0 (brakes).
        assert observations[0].tick == 1 and observations[0].t == pytest.approx(period)
        for obs in observations:
            k = int(round(obs.t / period))
            if k >= len(t):
                continue  # the run ended before this tick
            # The prediction was exact: the robot stood there, at that speed, at that tick.
            assert t[k] == pytest.approx(obs.t)
            assert (obs.x, obs.y) == (xy[k, 0], xy[k, 1])
            assert (obs.vx, obs.vy) == (v[k, 0], v[k, 1])
            assert obs.tick == k
        # And the answer drove the step from there: the next velocity is that command's.
        a = sc.robots[0].a_max
        for obs in observations:
            k = int(round(obs.t / period))
            cmd = answers[(rid, obs.t)]
            if k + 1 < len(t) and (cmd.ax, cmd.ay) != (0.0, 0.0):
                checked += 1
                assert v[k + 1, 0] == pytest.approx(obs.vx + period * np.clip(cmd.ax, -a, a))
                assert v[k + 1, 1] == pytest.approx(obs.vy + period * np.clip(cmd.ay, -a, a))
    assert checked > 100


def test_print_caps_and_speed_zones_hold_with_the_mpc_pipelined():
    # Case study 3 with its print caps (scenario 2): the command in force when a cap starts
    # was computed knowing the cap, one tick ahead.
    # 300 s: the part (printed from the first tick) is done at 251 s, after the paper's 250.
    sc = replace(load_scenario(REPO_ROOT / "scenarios" / "paper_case3_s2.toml"), duration_s=300)
    strict = World(sc).run()
    assert strict.summary["jobs"]["completed"] == 1
    result = World(pipelined(sc)).run()
    s = result.summary
    assert s["violations"] == NO_VIOLATIONS, result.safety.examples
    assert s["jobs"]["completed"] == 1
    assert s["digest"] != strict.summary["digest"]  # the mode changed the run
    # One tick of actuation latency (1 s here) costs the trip about that, not more.
    late = result.jobs[0].arrived_s - strict.jobs[0].arrived_s
    assert 0.0 <= late <= 2.0 * sc.robots[0].period_s, late


# -- same run in one process or three -----------------------------------------------------------


def test_pipelined_followers_give_the_same_run_with_0_2_and_4_workers():
    # 4 workers on 2 cores: the system then evens out each round (docs/fleet.md). One worker
    # would take the path two take (every robot's command over ipc://, collected per round),
    # with all robots in one share; test_fleet.py runs one worker, strict.
    sc = pipelined(busy_fleet(6, 90.0))
    summaries = [World(sc, workers=w).run().summary for w in (0, 2, 4)]
    assert len({s["digest"] for s in summaries}) == 1, [s["digest"] for s in summaries]
    for s in summaries:
        check_accounting(s)
        assert s["lockstep"] == "pipelined"
        assert s["violations"] == NO_VIOLATIONS
        assert s["faults"]["agents_lost"] == 0 and s["engine"]["bus_timeouts"] == 0
    assert summaries[0]["jobs"]["completed"] >= 3
    strict = World(busy_fleet(6, 90.0)).run().summary
    assert strict["lockstep"] == "strict" and strict["digest"] != summaries[0]["digest"]


def test_pipelined_mpc_robots_keep_clear_and_give_the_same_run_with_0_and_2_workers():
    # In this process and in two worker processes (one worker takes the path of two, with
    # every robot in one share; the followers' test above runs 4).
    sc = pipelined(busy_fleet(6, 60.0, "mpc"))
    # Every tick solves (reuse_ticks = 0): each solve depends on the plans the workers passed.
    sc = replace(sc, controller=PluginChoice("mpc", {**sc.controller.options, "reuse_ticks": 0}))
    results = [World(sc, workers=w).run() for w in (0, 2)]
    summaries = [r.summary for r in results]
    for result, s in zip(results, summaries, strict=True):
        # No solve stopped at a limit (the wall-clock guard, "time_limit", would part the
        # digests for another reason; the node limit: "feasible", "no_solution"); an infeasible
        # step falls back, by itself.
        assert set(s["solver"]["termination"]) <= {"optimal", "infeasible"}
        assert s["violations"] == NO_VIOLATIONS, result.safety.examples
        assert s["engine"]["bus_timeouts"] == 0
        check_accounting(s)
    assert len({s["digest"] for s in summaries}) == 1, [s["digest"] for s in summaries]
    assert summaries[0]["jobs"]["completed"] >= 1 and summaries[0]["solver"]["steps"] > 300
