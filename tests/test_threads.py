"""Robots' steps in threads (``[bus] threads``): the plugin gate, the threaded responder, and
runs whose digests do not depend on the thread count (issue 17)."""

from __future__ import annotations

import logging
import subprocess
import sys
import threading
from dataclasses import replace

import highspy
import numpy as np
import pytest

from fleet.bus import AGENT_STATS, AgentHost
from fleet.bus.responder import Responder
from fleet.engine import World
from fleet.errors import ScenarioError
from fleet.highs import new_highs
from fleet.plugins import (
    Announcement,
    Command,
    Controller,
    ControlStatus,
    Observation,
    SolverOutcome,
    gate_released,
    in_gate,
)
from fleet.plugins import gate as gate_module
from fleet.scenario import REPO_ROOT, load_scenario
from fleet_plugins.mpc.model import run_outcome
from tests.test_fleet import check_accounting, fleet_scenario, mpc_fleet_run, mpc_fleet_scenario
from tests.test_pipeline import write_scenario

# Generous: a wait ends as soon as the other thread arrives; only a held gate waits this long.
WAIT_S = 10.0


def with_threads(scenario, threads: int):
    return replace(scenario, bus=replace(scenario.bus, threads=threads))


# -- the gate -------------------------------------------------------------------------------------


def test_the_gate_is_held_inside_in_gate_and_let_go_only_inside_gate_released():
    seen = []

    def step() -> str:
        seen.append(gate_module._GATE.locked())
        with gate_released():
            seen.append(gate_module._GATE.locked())
        seen.append(gate_module._GATE.locked())
        return "done"

    assert in_gate(step) == "done"
    assert seen == [True, False, True]
    assert not gate_module._GATE.locked()
    # Outside a host's threads, letting go is a no-op: a step computed in turn takes no lock.
    with gate_released():
        assert not gate_module._GATE.locked()


def test_the_gate_is_let_go_after_a_step_that_raises():
    def boom() -> None:
        raise RuntimeError("plugin bug")

    with pytest.raises(RuntimeError, match="plugin bug"):
        in_gate(boom)
    assert not gate_module._GATE.locked()


def tiny_milp() -> highspy.Highs:
    """max x + y, x + 2y <= 4, 3x + y <= 6, x, y integer in [0, 10]."""
    h = new_highs()
    h.addVars(2, np.zeros(2), np.full(2, 10.0))
    h.changeColsCost(2, np.arange(2, dtype=np.int32), np.array([-1.0, -1.0]))
    h.changeColsIntegrality(
        2, np.arange(2, dtype=np.int32), np.array([highspy.HighsVarType.kInteger] * 2)
    )
    h.addRows(
        2,
        np.full(2, -highspy.kHighsInf),
        np.array([4.0, 6.0]),
        4,
        np.array([0, 2], dtype=np.int32),
        np.array([0, 1, 0, 1], dtype=np.int32),
        np.array([1.0, 2.0, 3.0, 1.0]),
    )
    return h


class MeetsInSolve(Controller):
    """Solves a tiny MILP through the MPC's `run_outcome`; while HiGHS runs (its first log
    line), says so and waits for the other robot's solve to be running too."""

    def __init__(self, here: threading.Event, there: threading.Event) -> None:
        super().__init__()
        self.here, self.there = here, there
        self.met: bool | None = None

    def compute(self, obs: Observation) -> Command:
        h = tiny_milp()

        def on_log(*_: object) -> None:
            if self.met is None:
                self.here.set()
                self.met = self.there.wait(WAIT_S)

        h.cbLogging.subscribe(on_log)
        assert run_outcome(h, "gate test") is SolverOutcome.OPTIMAL
        return Command(0.0, 0.0, ControlStatus.OK)


def test_two_robots_solves_run_at_once_on_a_host_with_threads():
    # Each robot waits inside its HiGHS run for the other's run to start: only if a run lets
    # go of the gate can the other robot's step get that far (held, the first would wait out
    # WAIT_S alone and the second would start after it).
    a, b = threading.Event(), threading.Event()
    controllers = {"r01": MeetsInSolve(a, b), "r02": MeetsInSolve(b, a)}
    stats = dict.fromkeys(AGENT_STATS, 0)
    responder = Responder("t", controllers, stats, logging.getLogger("test"), threads=2)
    try:
        obs = [Observation(r, 1, 0.25, 0.0, 0.0, 0.0, 0.0) for r in controllers]
        commands, _, _ = responder.answer(1, obs, [], frozenset(controllers), lambda: None)
    finally:
        responder.close()
    assert sorted(commands) == ["r01", "r02"] and stats["controller_errors"] == 0
    assert [c.met for c in controllers.values()] == [True, True]


# -- the responder --------------------------------------------------------------------------------


class Mixed(Controller):
    """Accelerates by its robot's x; raises for robot r03; bids x + the job's x."""

    def __init__(self) -> None:
        super().__init__()
        self.gated: list[bool] = []

    def compute(self, obs: Observation) -> Command:
        self.gated.append(gate_module._GATE.locked())
        if obs.robot == "r03":
            raise RuntimeError("r03's plugin bug")
        status = ControlStatus.BLOCKED if obs.robot == "r02" else ControlStatus.OK
        return Command(obs.x, -obs.x, status)

    def bid(self, obs: Observation, job: Announcement) -> float | None:
        return obs.x + job.x


def answer_with(threads: int) -> tuple[tuple, dict, list[list[bool]]]:
    robots = [f"r{i:02d}" for i in range(1, 7)]
    controllers = {r: Mixed() for r in robots}
    stats = dict.fromkeys(AGENT_STATS, 0)
    responder = Responder("t", controllers, stats, logging.getLogger("test"), threads=threads)
    obs = [
        Observation(r, 4, 1.0, float(i), 0.0, 0.0, 0.0, job="j1" if r == "r02" else None)
        for i, r in enumerate(robots)
    ]
    # r09 is not hosted and r01 appears twice: both are refused, not computed.
    obs += [Observation("r09", 4, 1.0, 0.0, 0.0, 0.0, 0.0), obs[0]]
    jobs = [Announcement("j7", 10.0, 0.0, 0.0, 0.0), Announcement("j8", 20.0, 0.0, 0.0, 0.0)]
    try:
        out = responder.answer(4, obs, jobs, frozenset(robots), lambda: None)
    finally:
        responder.close()
    return out, stats, [c.gated for c in controllers.values()]


def test_a_host_with_threads_answers_exactly_as_one_without():
    one, stats_one, gated_one = answer_with(1)
    three, stats_three, gated_three = answer_with(3)
    assert three == one and stats_three == stats_one
    commands, bids, handbacks = three
    assert list(commands) == [f"r{i:02d}" for i in range(1, 7)]  # in the observations' order
    assert commands["r03"]["status"] == ControlStatus.ERROR.value
    assert stats_three["controller_errors"] == 1 and stats_three["unknown_robots"] == 2
    # Every robot but r03 (its bid is asked too: only its step raised) bids x + the job's x.
    assert [(b.robot, b.job, b.estimate_s) for b in bids][:4] == [
        ("r01", "j7", 10.0),
        ("r01", "j8", 20.0),
        ("r02", "j7", 11.0),
        ("r02", "j8", 21.0),
    ]
    assert len(bids) == 12
    assert [(h.robot, h.job) for h in handbacks] == [("r02", "j1")]
    # Each robot computed once; in threads, inside the gate; in turn, without it.
    assert gated_three == [[True]] * 6 and gated_one == [[False]] * 6


# -- runs -----------------------------------------------------------------------------------------


def test_mpc_robots_give_the_same_digest_with_any_number_of_threads():
    # The fleet of tests/test_fleet.py (six MPC robots keeping clear of each other, 120 s,
    # solving every tick): in this process with 3 threads, and on 2 workers with 2 threads each.
    base = mpc_fleet_run(0).summary
    for workers, threads in ((0, 3), (2, 2)):
        s = World(with_threads(mpc_fleet_scenario(), threads), workers=workers).run().summary
        assert set(s["solver"]["termination"]) == {"optimal"}
        assert s["digest"] == base["digest"], (workers, threads)
        assert s["solver"]["steps"] == base["solver"]["steps"] > 100
        check_accounting(s)


def test_followers_give_the_same_digest_with_threads_in_a_worker():
    sc = fleet_scenario(robots=6, duration=90.0)
    summaries = [World(with_threads(sc, t), workers=w).run().summary for w, t in ((0, 1), (1, 3))]
    assert len({s["digest"] for s in summaries}) == 1
    assert summaries[0]["jobs"]["completed"] >= 1  # not vacuous: the robots worked


# -- the option -----------------------------------------------------------------------------------


def test_threads_default_to_1_and_are_read_from_the_bus_table(tmp_path):
    assert load_scenario(REPO_ROOT / "scenarios" / "fleet.toml").bus.threads == 1
    assert load_scenario(write_scenario(tmp_path, "threads = 4\n")).bus.threads == 4


@pytest.mark.parametrize("value", ["0", "-2", "1.5", '"two"'])
def test_a_bad_thread_count_is_refused_naming_the_file_field_and_value(tmp_path, value):
    path = write_scenario(tmp_path, f"threads = {value}\n")
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    said = str(err.value)
    assert str(path) in said and "bus.threads" in said and value.strip('"') in said


@pytest.mark.parametrize(
    "command", [["run"], ["agent", "--connect", "tcp://127.0.0.1:5555"]], ids=["run", "agent"]
)
def test_fleet_run_and_agent_refuse_a_bad_threads_option_by_name(command):
    done = subprocess.run(
        [sys.executable, "-m", "fleet", *command, "--threads", "0"],
        capture_output=True,
        text=True,
        cwd=REPO_ROOT,
    )
    assert done.returncode == 2 and done.stdout == ""
    assert "--threads" in done.stderr and "'0'" in done.stderr
    assert "Traceback" not in done.stderr


def test_an_agent_host_refuses_a_thread_count_that_is_not_a_whole_number_above_0():
    for bad in (0, True, 1.0):
        with pytest.raises(ValueError, match=r"threads = .*must be an integer >= 1"):
            AgentHost("inproc://nowhere", {}, threads=bad)
