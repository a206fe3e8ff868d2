"""The fleet: contract-net job exchange, job accounting, agents in worker processes, faults.

Everything runs the real engine over real sockets: worker processes are spawned interpreters
talking ipc://, the distributed commands are real `fleet` processes talking tcp://.
"""

import multiprocessing
import os
import signal
import socket
import subprocess
import sys
from dataclasses import replace
from functools import cache

import pytest

from fleet.engine import World
from fleet.engine.agents import (
    build_controllers,
    parse_robot_selection,
    robot_specs,
    scenario_fingerprint,
    serve_agent,
    split_robots,
)
from fleet.errors import ScenarioError
from fleet.scenario import (
    REPO_ROOT,
    BusConfig,
    JobsConfig,
    PluginChoice,
    ScriptedJob,
    load_scenario,
)

FLEET = REPO_ROOT / "scenarios" / "fleet.toml"


def fleet_scenario(**override):
    """The shipped fleet scenario, shortened; keyword overrides as for `Scenario.override`."""
    return load_scenario(FLEET).override(**override)


def scripted(*stations: str, at: float = 0.0) -> JobsConfig:
    return JobsConfig(mode="scripted", scripted=tuple(ScriptedJob(at, s) for s in stations))


def check_accounting(summary: dict) -> None:
    jobs = summary["jobs"]
    assert jobs["accounted"] is True
    assert jobs["released"] == jobs["completed"] + jobs["failed"] + jobs["in_progress"]


# -- the auction ------------------------------------------------------------------------------


def test_auction_awards_every_job_from_bids_and_accounts_for_all():
    sc = replace(
        fleet_scenario(robots=4, duration=240.0),
        jobs=scripted("cnc_1_in", "qc_lab_in", "furnace_in", "paint_booth_in"),
    )
    world = World(sc)
    result = world.run()
    s = result.summary
    check_accounting(s)
    assert s["dispatcher"] == "auction"
    assert s["jobs"]["completed"] == 4
    assert s["engine"]["announcements"] >= 4
    assert s["engine"]["bids"] >= 4 * 4  # every robot bid for every first announcement
    # Each job went to a different robot: all idle at the start, one win per robot per round.
    assert len({rec.robot for rec in result.jobs}) == 4
    assert s["violations"]["collision"] == 0


def test_auction_prefers_the_robot_that_delivers_first():
    # One job next to depot_b: a robot starting there wins it, not one from depot_a.
    sc = replace(fleet_scenario(robots=2, duration=120.0), jobs=scripted("paint_booth_in"))
    world = World(sc)
    homes = {rid: r.home for rid, r in world.robots.items()}
    job_xy = world.floor.station("paint_booth_in")
    result = world.run()
    winner = result.jobs[0].robot
    nearest = min(homes, key=lambda r: world.planner.travel_time(homes[r], (job_xy.x, job_xy.y)))
    assert winner == nearest


def test_busy_robot_queues_a_job_it_wins():
    # One robot, two jobs: it wins the first, bids for the second while busy and queues it.
    sc = replace(fleet_scenario(robots=1, duration=400.0), jobs=scripted("cnc_1_in", "qc_lab_in"))
    result = World(sc).run()
    check_accounting(result.summary)
    assert result.summary["jobs"]["completed"] == 2
    first, second = sorted(result.jobs, key=lambda r: r.job.id)
    assert second.assigned_s < first.delivered_s  # won while the first was still under way
    assert second.delivered_s > first.delivered_s


def test_jobs_nobody_can_win_stay_in_progress_and_are_reannounced():
    sc = replace(
        fleet_scenario(robots=1, duration=10.0),
        jobs=scripted("cnc_1_in", "qc_lab_in", "furnace_in"),
    )
    result = World(sc).run()
    s = result.summary
    check_accounting(s)
    # One robot can hold one job and queue one; the third waits, announced every few seconds.
    assert s["jobs"]["in_progress"] == 3
    assert s["jobs"]["unassigned"] == 1
    assert s["engine"]["announcements"] > 3


# -- agents outside the engine ------------------------------------------------------------------


def test_robot_ids_shares_and_selection_follow_the_scenario():
    sc = fleet_scenario(robots=5)
    assert list(robot_specs(sc)) == ["r01", "r02", "r03", "r04", "r05"]
    assert split_robots(list(robot_specs(sc)), 2) == [["r01", "r02", "r03"], ["r04", "r05"]]
    assert parse_robot_selection(sc, None, "2/2") == ["r04", "r05"]
    assert parse_robot_selection(sc, "r02,r05", None) == ["r02", "r05"]
    with pytest.raises(ScenarioError, match=r"--only.*r09"):
        parse_robot_selection(sc, "r02,r09", None)
    with pytest.raises(ScenarioError, match=r"--share.*3/2"):
        parse_robot_selection(sc, None, "3/2")
    controllers = build_controllers(sc, World(sc).floor, ["r02"])
    assert list(controllers) == ["r02"] and controllers["r02"].context.robot == "r02"


def test_fingerprint_changes_with_what_agents_must_agree_on():
    sc = fleet_scenario(robots=4)
    assert scenario_fingerprint(sc) == scenario_fingerprint(fleet_scenario(robots=4))
    assert scenario_fingerprint(sc) != scenario_fingerprint(fleet_scenario(robots=5))
    assert scenario_fingerprint(sc) != scenario_fingerprint(sc.override(controller="fixed_speed"))
    # The seed and duration are the engine's business only.
    assert scenario_fingerprint(sc) == scenario_fingerprint(sc.override(seed=9, duration=5.0))


def test_same_seed_same_digest_with_0_1_and_2_workers():
    sc = fleet_scenario(robots=6, duration=90.0)
    summaries = [World(sc, workers=w).run().summary for w in (0, 1, 2)]
    digests = {s["digest"] for s in summaries}
    assert len(digests) == 1, [s["digest"] for s in summaries]
    for s in summaries:
        check_accounting(s)
        assert s["faults"]["agents_lost"] == 0
        assert s["engine"]["bus_timeouts"] == 0
    # Not vacuous: the robots worked.
    assert summaries[0]["jobs"]["completed"] >= 1


def mpc_fleet_scenario():
    """Six MPC robots on the shipped fleet scenario for 120 s, solving every tick
    (``reuse_ticks = 0``: every plan depends on the others', and tests/test_mpc_reuse.py
    compares its reusing fleet with this one)."""
    base = fleet_scenario(robots=6, duration=120.0, controller="mpc")
    return replace(base, controller=PluginChoice("mpc", {"reuse_ticks": 0}))


@cache
def mpc_fleet_run(workers: int):
    """`mpc_fleet_scenario` with `workers` worker processes, run once per session: the tests
    here and tests/test_mpc_reuse.py read the same run."""
    return World(mpc_fleet_scenario(), workers=workers).run()


def test_mpc_robots_that_keep_clear_of_each_other_give_the_same_digest_with_0_and_2_workers():
    # The MPC's separation constraints make every robot's solve depend on the others' plans:
    # any solve that depends on timing (HiGHS's clock, message order) shows here. 120 s hold
    # 447 solves, and parting the plans the workers see parts the digests (checked by sending
    # every neighbour's plan as empty over the bus).
    results = [mpc_fleet_run(w) for w in (0, 2)]
    summaries = [r.summary for r in results]
    for s in summaries:
        # Every solve ran to optimality: none was cut short by the wall clock (which would
        # make the digests differ for a reason this test is not about).
        assert set(s["solver"]["termination"]) == {"optimal"}
    assert summaries[0]["digest"] == summaries[1]["digest"]
    for result, s in zip(results, summaries, strict=True):
        assert s["violations"] == {
            "obstacle": 0,
            "speed_zone": 0,
            "print_speed": 0,
            "collision": 0,
        }, result.safety.examples
        check_accounting(s)
    assert summaries[0]["jobs"]["completed"] >= 1 and summaries[0]["solver"]["steps"] > 100


@pytest.mark.parametrize("lockstep", ["strict", "pipelined"])
def test_a_killed_worker_is_a_fault_its_jobs_move_on_and_a_restarted_agent_rejoins(lockstep):
    # Pipelined, the orphans brake from the tick after their last command, and a rejoined
    # robot's first command answers its state braked to rest.
    sc = replace(
        fleet_scenario(robots=4, duration=150.0),
        jobs=scripted("cnc_1_in", "qc_lab_in", "furnace_in", "paint_booth_in"),
        # 3 s of silence (the default): at 1 s a live worker on a loaded machine may be lost too.
        bus=BusConfig(timeout_s=5.0, lost_after_s=3.0, lockstep=lockstep),
    )
    world = World(sc, workers=2)
    victim = world.workers.processes[0]
    orphans = world.workers.shares[victim.name]
    done: dict[str, object] = {}

    def progress(now: float) -> None:
        if now >= 20.0 and "killed" not in done:
            done["held"] = sum(
                len(world.robots[r].queue) + (world.robots[r].job is not None) for r in orphans
            )
            os.kill(victim.pid, signal.SIGKILL)
            victim.join()
            done["killed"] = now
        if now >= 50.0 and "restarted" not in done:
            p = multiprocessing.get_context("spawn").Process(
                target=serve_agent,
                args=(sc, world.exchange.address, orphans),
                kwargs={"name": "restarted", "idle_timeout_s": 60.0},
            )
            p.start()
            done["restarted"] = p
            # Simulated time runs much faster than a process starts: hold the clock until the
            # new agent has said HELLO, as a long run would simply go on while it does.
            world.exchange.wait_for_agents(orphans, 60.0)

    result = world.run(progress)
    restarted = done["restarted"]
    restarted.join(30)
    s = result.summary
    check_accounting(s)
    assert s["faults"]["agents_lost"] == 1
    assert s["faults"]["robots_orphaned"] == len(orphans)
    assert s["faults"]["robots_rejoined"] == len(orphans)
    # The orphans' jobs were handed back and done by someone: nothing lost.
    assert done["held"] >= 1
    assert s["jobs"]["handed_back"] == done["held"]
    assert s["jobs"]["completed"] == 4
    assert s["violations"]["collision"] == 0
    events = world.recorder.events
    assert sum(1 for e in events if e.event == "fault") == len(orphans)
    assert sum(1 for e in events if e.event == "rejoined") == len(orphans)
    assert restarted.exitcode == 0


# -- the commands ----------------------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def fleet_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "fleet.cli", *args]


def test_serve_and_two_agents_over_tcp_give_the_same_run_as_one_process(tmp_path):
    port = free_port()
    common = [str(FLEET), "--robots", "4"]
    serve = subprocess.Popen(
        fleet_cmd(
            "serve",
            *common,
            "--duration",
            "40",
            "--bind",
            f"tcp://127.0.0.1:{port}",
            "--out",
            str(tmp_path / "served"),
            "--quiet",
            "--no-figures",
            "--wait",
            "60",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    agents = [
        subprocess.Popen(
            fleet_cmd("agent", *common, "--connect", f"tcp://127.0.0.1:{port}", "--share", share),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for share in ("1/2", "2/2")
    ]
    out, err = serve.communicate(timeout=240)
    assert serve.returncode == 0, err
    for a in agents:
        a_out, a_err = a.communicate(timeout=60)
        assert a.returncode == 0, a_err
        assert "run finished" in a_out
    import json

    served = json.loads((tmp_path / "served" / "summary.json").read_text())
    local = World(fleet_scenario(robots=4, duration=40.0)).run().summary
    assert served["digest"] == local["digest"]


def test_curve_keys_let_an_authorised_agent_in_and_refuse_a_stranger(tmp_path):
    keys = tmp_path / "keys"
    authorized = tmp_path / "authorized"
    keys.mkdir(mode=0o700)  # as `fleet keys` makes it: the three below then run at once
    makers = [
        subprocess.Popen(
            fleet_cmd("keys", str(keys), "--name", name),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name in ("engine", "agent", "stranger")
    ]
    for maker in makers:
        _, err = maker.communicate(timeout=120)
        assert maker.returncode == 0, err
    authorized.mkdir()
    (authorized / "agent.key").write_bytes((keys / "agent.key").read_bytes())
    common = [str(FLEET), "--robots", "2"]

    def serve(wait: str, address: str, out: str) -> subprocess.Popen:
        return subprocess.Popen(
            fleet_cmd(
                "serve",
                *common,
                "--duration",
                "20",
                "--bind",
                address,
                "--key",
                str(keys / "engine.key_secret"),
                "--authorized",
                str(authorized),
                "--out",
                str(tmp_path / out),
                "--quiet",
                "--no-figures",
                "--wait",
                wait,
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    def agent(name: str, address: str) -> subprocess.Popen:
        return subprocess.Popen(
            fleet_cmd(
                "agent",
                *common,
                "--wait",
                "8",
                "--connect",
                address,
                "--key",
                str(keys / f"{name}.key_secret"),
                "--server-key",
                str(keys / "engine.key"),
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    # Two engines with the same keys on ports of their own, at once (the stranger's mostly
    # waits): one with a stranger for agent, one with the authorised agent.
    ports = {free_port()}
    while len(ports) < 2:  # neither engine has bound yet: ask until the two differ
        ports.add(free_port())
    closed, open_ = (f"tcp://127.0.0.1:{port}" for port in sorted(ports))
    engine, stranger = serve("4", closed, "refused"), agent("stranger", closed)
    friendly, friend = serve("60", open_, "served"), agent("agent", open_)
    # A stranger's key is refused: the engine never hears it, logs the refusal, gives up.
    _, err = engine.communicate(timeout=120)
    _, stranger_err = stranger.communicate(timeout=60)
    assert engine.returncode == 1
    assert "refused" in err.lower() and "no agent hosts robots" in err
    # ... and the stranger gives up with an error instead of waiting for ever.
    assert stranger.returncode == 1
    assert "no answer from an engine" in stranger_err
    # The authorised agent is let in and the run completes.
    _, err = friendly.communicate(timeout=180)
    out, agent_err = friend.communicate(timeout=60)
    assert friendly.returncode == 0, err
    assert friend.returncode == 0, agent_err
    assert "run finished" in out


@pytest.mark.parametrize(
    ("scenario", "override"),
    [
        ("fleet.toml", {"duration": 600.0}),
        ("default.toml", {"duration": 1200.0}),
    ],
    ids=["fleet-follower", "default"],  # the MPC fleet: see the digest test above
)
def test_shipped_fleet_scenarios_keep_robots_apart(scenario, override):
    sc = load_scenario(REPO_ROOT / "scenarios" / scenario).override(**override)
    result = World(sc).run()
    s = result.summary
    assert s["violations"] == {"obstacle": 0, "speed_zone": 0, "print_speed": 0, "collision": 0}, (
        result.safety.examples
    )
    check_accounting(s)
    # Not vacuous: robots took jobs and drove (the default's prints outlast 20 minutes).
    assert s["jobs"]["released"] >= 1 and s["distance_m"] > 50.0


def test_an_agent_with_another_scenario_is_refused_and_says_so(tmp_path):
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    engine = subprocess.Popen(
        fleet_cmd(
            "serve",
            str(FLEET),
            "--robots",
            "2",
            "--duration",
            "5",
            "--bind",
            address,
            "--out",
            str(tmp_path / "run"),
            "--quiet",
            "--no-figures",
            "--wait",
            "5",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    # Three robots against the engine's two: another scenario, refused by its fingerprint.
    agent = subprocess.run(
        fleet_cmd(
            "agent",
            str(FLEET),
            "--robots",
            "3",
            "--only",
            "r01",
            "--connect",
            address,
            "--wait",
            "20",
        ),
        capture_output=True,
        text=True,
        timeout=120,
    )
    engine.communicate(timeout=120)
    assert agent.returncode == 1
    assert "refused robots" in agent.stderr and "scenario differs" in agent.stderr


def test_bad_controller_options_fail_at_once_with_workers():
    from fleet.errors import PluginError

    sc = replace(
        fleet_scenario(robots=2),
        controller=replace(fleet_scenario().controller, options={"gain": -1.0}),
    )
    with pytest.raises(PluginError, match=r"fleet.toml: \[controller\].*gain"):
        World(sc, workers=1)


def test_a_world_given_its_floor_keeps_its_agents_in_process():
    sc = fleet_scenario(robots=2)
    floor = World(sc).floor
    with pytest.raises(ValueError, match="workers=0"):
        World(sc, floor, workers=1)


def test_a_blocked_robot_hands_its_job_back_and_another_robot_delivers_it(monkeypatch):
    import fleet.engine.agents as agents_module
    from fleet.plugins import Command, ControlStatus
    from fleet_plugins.follower import PathFollower

    class Stuck(PathFollower):
        def compute(self, obs):
            if obs.job is not None and self.context.robot == "r01":
                return Command(0.0, 0.0, ControlStatus.BLOCKED)
            return super().compute(obs)

    monkeypatch.setattr(agents_module, "load_controller", lambda name, options: Stuck())
    for dispatcher in ("auction", "greedy"):
        sc = replace(
            fleet_scenario(robots=2, duration=200.0, dispatcher=dispatcher),
            jobs=scripted("cnc_1_in"),  # r01 starts at depot_a, nearer: the natural pick
        )
        result = World(sc).run()
        s = result.summary
        check_accounting(s)
        (rec,) = result.jobs
        assert rec.handbacks == 1 and rec.handed_back_by == {"r01"}, dispatcher
        assert rec.robot == "r02" and s["jobs"]["completed"] == 1, dispatcher
