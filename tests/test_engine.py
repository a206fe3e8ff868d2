"""The engine end to end on a small floor: jobs flow, events are logged, runs are reproducible."""

from dataclasses import replace
from pathlib import Path

import pytest

from fleet.engine import World
from fleet.errors import PluginError, ScenarioError
from fleet.scenario import JobsConfig, PluginChoice, ScriptedJob, load_scenario

MAP = """
[floor]
name = "test hall"
boundary = [[0, 0], [30, 0], [30, 16], [0, 16]]
default_v_max = 1.0
clearance = 0.4

[[obstacles]]
name = "press"
polygon = [[10, 4], [16, 4], [16, 9], [13, 12], [10, 9]]

[[zones]]
name = "press_buffer"
around = "press"
margin = 1.5
v_max = 0.4

[[stations]]
name = "depot"
at = [2, 2]
kind = "depot"

[[stations]]
name = "east"
at = [27, 8]

[[stations]]
name = "north"
at = [13, 14.5]
"""


@pytest.fixture
def scenario_file(tmp_path: Path) -> Path:
    (tmp_path / "hall.toml").write_text(MAP)
    path = tmp_path / "hall_run.toml"
    path.write_text(
        '[scenario]\nmap = "hall.toml"\nduration_s = 240\nseed = 3\n'
        "[robots]\ncount = 3\nperiod_s = 0.25\n"
        '[jobs]\nrate_per_h = 120\nstations = ["east", "north"]\n'
    )
    return path


def test_jobs_are_released_assigned_started_and_delivered(scenario_file):
    world = World(load_scenario(scenario_file))
    result = world.run()
    s = result.summary
    assert s["jobs"]["released"] > 0
    assert 0 < s["jobs"]["completed"] <= s["jobs"]["released"]
    # No sensing radius here: robots ignore each other (tests/test_fleet.py covers fleets that
    # keep clear), so only the floor rules are asserted; collisions are counted honestly.
    assert s["violations"]["obstacle"] == 0 and s["violations"]["speed_zone"] == 0
    events = world.recorder.events
    for rec in result.jobs:
        if rec.delivered_s is None:
            continue
        mine = [(e.event, e.t) for e in events if e.job == rec.job.id]
        assert [name for name, _ in mine] == [
            "released",
            "assigned",
            "started",
            "arrived",
            "delivered",
        ]
        times = [t for _, t in mine]
        assert times == sorted(times)
        # Nothing to print: delivered as soon as it arrived.
        assert times[-2] == times[-1] == rec.delivered_s == rec.arrived_s
        robot = world.robots[rec.robot]
        # Delivered where the job said, by the robot it was assigned to.
        delivered = next(e for e in events if e.job == rec.job.id and e.event == "delivered")
        assert delivered.robot == rec.robot == robot.id
    assert sum(p["jobs_completed"] for p in s["per_robot"]) == s["jobs"]["completed"]


def test_poisson_jobs_stop_at_release_until_and_the_fleet_works_off_the_rest(scenario_file):
    text = scenario_file.read_text()
    scenario_file.write_text(text.replace("[jobs]\n", "[jobs]\nrelease_until_s = 60\n"))
    batch = World(load_scenario(scenario_file)).run()
    scenario_file.write_text(text)
    stream = World(load_scenario(scenario_file)).run()
    released = [(rec.job.id, rec.job.released_s) for rec in batch.jobs]
    # The same jobs as the endless stream's up to 60 s, and none after.
    assert released and all(t <= 60.0 for _, t in released)
    assert released == [(rec.job.id, rec.job.released_s) for rec in stream.jobs][: len(released)]
    assert len(stream.jobs) > len(released)
    # 180 s with nothing new: every job of the batch is delivered.
    assert batch.summary["jobs"]["completed"] == len(released)


def test_same_seed_same_digest_other_seed_other_digest(scenario_file):
    sc = load_scenario(scenario_file)
    first = World(sc).run().summary
    again = World(sc).run().summary
    other = World(sc.override(seed=4)).run().summary
    assert first["digest"] == again["digest"]
    assert first["jobs"] == again["jobs"]
    assert other["digest"] != first["digest"]


@pytest.mark.parametrize("transport", ["ipc", "tcp"])
def test_same_run_over_ipc_and_tcp_as_over_inproc(scenario_file, tmp_path, transport):
    sc = replace(load_scenario(scenario_file), duration_s=120.0)
    address = f"ipc://{tmp_path}/bus" if transport == "ipc" else "tcp://127.0.0.1:*"
    world = World(replace(sc, bus_address=address))
    assert world.exchange.address.startswith(f"{transport}://")
    over_socket = world.run().summary
    in_process = World(sc).run().summary
    assert over_socket["digest"] == in_process["digest"]
    assert over_socket["engine"]["bus_rounds"] == in_process["engine"]["bus_rounds"] > 0


def test_scripted_jobs_arrive_in_order(scenario_file):
    sc = load_scenario(scenario_file)
    sc = replace(
        sc,
        jobs=JobsConfig(
            mode="scripted", scripted=(ScriptedJob(10.0, "north"), ScriptedJob(0.0, "east"))
        ),
    )
    world = World(sc)
    world.run()
    released = [(e.t, e.job) for e in world.recorder.events if e.event == "released"]
    assert released == [(0.0, "j00001"), (10.0, "j00002")]
    delivered = {e.job: e.station for e in world.recorder.events if e.event == "delivered"}
    assert delivered == {"j00001": "east", "j00002": "north"}


def test_scripted_jobs_at_one_time_after_an_earlier_one_are_released_without_a_crash(
    scenario_file,
):
    # Fuzz s73-0109 (MPC): jobs at 1.4, 6.2 and 6.2 s. The clock reached 1.4 + (6.2 - 1.4) =
    # 6.200000000000001 s, so the third job's wait was -8.9e-16 s: SimPy's "Negative delay"
    # ended the run at its start.
    sc = load_scenario(scenario_file)
    times = (1.4, 6.2, 6.2, 6.5)
    jobs = tuple(ScriptedJob(t, "east" if i % 2 else "north") for i, t in enumerate(times))
    world = World(replace(sc, jobs=JobsConfig(mode="scripted", scripted=jobs)))
    world.run()
    released = [(e.t, e.job) for e in world.recorder.events if e.event == "released"]
    assert released == [(t, f"j{i:05d}") for i, t in enumerate(times, start=1)]
    delivered = [e.job for e in world.recorder.events if e.event == "delivered"]
    assert sorted(delivered) == [f"j{i:05d}" for i in range(1, 5)]


def test_robot_steps_follow_each_period(scenario_file):
    sc = load_scenario(scenario_file)
    world = World(replace(sc, duration_s=10.0))
    world.run()
    for tr in world.recorder.trajectories.values():
        assert tr.t[:3] == [0.0, 0.25, 0.5]
        assert len(tr.t) == 40  # ticks at 0, 0.25, ..., 9.75


def test_groups_tick_at_their_own_periods(scenario_file):
    sc = load_scenario(scenario_file)
    fast = replace(sc.robots[0], count=2, period_s=0.25)
    slow = replace(sc.robots[0], count=1, period_s=1.0, v_max=0.5, start=("north",))
    # The slow robot waits nearest to "east", so the greedy dispatcher sends it there.
    jobs = JobsConfig(mode="scripted", scripted=(ScriptedJob(0.0, "east"),))
    world = World(replace(sc, robots=(fast, slow), duration_s=120.0, jobs=jobs))
    result = world.run()
    periods = {rid: r.spec.period for rid, r in world.robots.items()}
    assert periods == {"r01": 0.25, "r02": 0.25, "r03": 1.0}
    for rid, tr in world.recorder.trajectories.items():
        assert len(tr.t) == round(120.0 / periods[rid])
    # The slow group's robot never exceeds its own speed limit.
    t, xy, v = world.recorder.trajectories["r03"].arrays()
    assert world.recorder.trajectories["r03"].distance() > 10.0
    assert 0.3 < abs(v).max() <= 0.5 + 1e-9
    assert result.summary["violations"]["obstacle"] == 0
    assert result.summary["violations"]["speed_zone"] == 0
    assert world.planner_for(world.robots["r03"].spec) is not world.planner


def test_unknown_station_in_scenario_is_a_clear_error(scenario_file):
    sc = load_scenario(scenario_file)
    with pytest.raises(ScenarioError, match=r"jobs.stations\[0\] = 'west'"):
        World(replace(sc, jobs=JobsConfig(stations=("west",))))
    with pytest.raises(ScenarioError, match=r"robots.start\[0\] = 'garage'"):
        World(replace(sc, robots=(replace(sc.robots[0], start=("garage",)),)))


def test_unknown_plugin_is_a_clear_error(scenario_file):
    from fleet.errors import PluginError

    sc = load_scenario(scenario_file)
    with pytest.raises(PluginError, match="nonesuch"):
        World(replace(sc, controller=PluginChoice("nonesuch")))


def test_a_controller_that_raises_costs_its_robot_a_brake_not_the_run(
    scenario_file, monkeypatch, caplog
):
    import fleet.engine.agents as agents_module
    from fleet_plugins.follower import PathFollower

    class Flaky(PathFollower):
        """The follower, except that it raises on every 10th tick of robot r01."""

        def compute(self, obs):
            if self.context.robot == "r01" and obs.tick % 10 == 9:
                raise RuntimeError("sensor glitch")
            return super().compute(obs)

    monkeypatch.setattr(agents_module, "load_controller", lambda name, options: Flaky())
    sc = replace(load_scenario(scenario_file), duration_s=60.0)
    result = World(sc).run()
    engine = result.summary["engine"]
    assert engine["commands_error"] == 24  # ticks 9, 19, ..., 239 of r01
    assert result.summary["violations"]["obstacle"] == 0
    assert result.summary["violations"]["speed_zone"] == 0
    glitches = [r for r in caplog.records if "sensor glitch" in r.getMessage()]
    assert len(glitches) == 1  # logged once per robot, not once per tick


def test_a_station_no_robot_can_reach_is_refused_before_the_run(tmp_path):
    # A wall splits the hall: the depot is west of it, "island" east of it.
    (tmp_path / "split.toml").write_text(
        '[floor]\nname = "split"\nrect = [0, 0, 20, 10]\ndefault_v_max = 1.0\n'
        '[[obstacles]]\nname = "wall"\nrect = [9, 0, 10, 10]\n'
        '[[stations]]\nname = "depot"\nat = [2, 5]\nkind = "depot"\n'
        '[[stations]]\nname = "west"\nat = [6, 5]\n'
        '[[stations]]\nname = "island"\nat = [15, 5]\n'
    )
    path = tmp_path / "split_run.toml"
    path.write_text('[scenario]\nmap = "split.toml"\n[robots]\ncount = 1\n')
    with pytest.raises(ScenarioError, match=r"jobs.stations = 'island': .* cannot be reached"):
        World(load_scenario(path))
    west_only = replace(load_scenario(path), jobs=JobsConfig(stations=("west",)))
    assert World(west_only).run().summary["violations"]["obstacle"] == 0


def test_a_world_runs_once(scenario_file):
    from fleet.errors import FleetError

    world = World(replace(load_scenario(scenario_file), duration_s=5.0))
    world.run()
    with pytest.raises(FleetError, match="already run"):
        world.run()


def test_a_fleet_that_cannot_see_itself_is_warned_about_once_a_seeing_one_is_not(
    scenario_file, caplog
):
    blind = replace(load_scenario(scenario_file), duration_s=1.0)  # 3 robots, sensing 0
    with caplog.at_level("WARNING", logger="fleet.engine"):
        World(blind)
        World(replace(blind, sensing_radius_m=6.0))
        World(replace(blind, robots=(replace(blind.robots[0], count=1),)))
    warned = [r.getMessage() for r in caplog.records if "cannot see each other" in r.getMessage()]
    assert warned == [
        f"{scenario_file}: 3 robots with sensing_radius_m = 0 cannot see each other: nothing "
        "keeps them apart (collisions are counted, not avoided)"
    ]


def test_a_scripted_run_only_needs_its_own_stations_reachable(tmp_path):
    (tmp_path / "split.toml").write_text(
        '[floor]\nname = "split"\nrect = [0, 0, 20, 10]\ndefault_v_max = 1.0\n'
        '[[obstacles]]\nname = "wall"\nrect = [9, 0, 10, 10]\n'
        '[[stations]]\nname = "depot"\nat = [2, 5]\nkind = "depot"\n'
        '[[stations]]\nname = "west"\nat = [6, 5]\n'
        '[[stations]]\nname = "island"\nat = [15, 5]\n'
    )
    path = tmp_path / "run.toml"
    path.write_text(
        '[scenario]\nmap = "split.toml"\n[robots]\ncount = 1\n[jobs]\nmode = "scripted"\n'
        '[[jobs.scripted]]\nat_s = 0\nstation = "west"\n'
        '[[jobs.scripted]]\nat_s = 5\nstation = "island"\n'
    )
    with pytest.raises(ScenarioError, match=r"jobs.scripted\[1\].station = 'island'"):
        World(load_scenario(path))
    path.write_text(path.read_text().replace('"island"', '"west"'))
    assert World(load_scenario(path)).run().summary["jobs"]["completed"] == 2


class _Raising:
    def assign(self, jobs, robots, context):
        raise RuntimeError("dispatcher bug")


class _Sloppy:
    """Returns plain tuples and assigns a robot that is busy."""

    def assign(self, jobs, robots, context):
        from fleet.plugins import Assignment

        busy = [r.robot for r in robots if not r.idle]
        out = [(jobs[0].id, robots[0].robot)]
        if busy:
            out.append(Assignment(jobs[0].id, busy[0]))
        return out


@pytest.mark.parametrize("dispatcher", [_Raising, _Sloppy])
def test_a_faulty_dispatcher_never_crashes_the_run(scenario_file, monkeypatch, dispatcher):
    import fleet.engine.world as world_module

    monkeypatch.setattr(world_module, "load_dispatcher", lambda name, options: dispatcher())
    sc = replace(load_scenario(scenario_file), duration_s=120.0)
    result = World(sc).run()
    engine = result.summary["engine"]
    assert result.summary["jobs"]["released"] > 0
    assert result.summary["jobs"]["completed"] == 0  # nothing valid was ever assigned
    key = "dispatcher_errors" if dispatcher is _Raising else "assignments_rejected"
    assert engine[key] > 0


def test_the_engine_keeps_each_robots_latest_plan(scenario_file):
    sc = replace(load_scenario(scenario_file), duration_s=30.0)
    world = World(sc)
    world.run()
    moved = [r for r in world.robots.values() if world.recorder.trajectories[r.id].distance() > 1]
    assert moved
    for robot in moved:
        times = [p[0] for p in robot.plan]
        assert len(times) > 1 and times == sorted(times)
        assert times[0] in world.recorder.trajectories[robot.id].t  # sent at one of its ticks


def test_bad_plugin_options_name_the_scenario_file(scenario_file):
    from fleet.errors import PluginError

    sc = replace(load_scenario(scenario_file), controller=PluginChoice("follower", {"gain": 5}))
    with pytest.raises(PluginError) as err:
        World(sc)
    message = str(err.value)
    assert message.startswith(f"{scenario_file}: [controller] name = 'follower'")
    assert "gain = 5" in message


def print_scenario(tmp_path: Path, controller: str) -> Path:
    """One robot from the depot to 'east' (25 m away), printing an infill task capped at 0.2
    m/s between 8 s and 20 s after the job starts."""
    (tmp_path / "hall.toml").write_text(MAP)
    path = tmp_path / f"print_{controller}.toml"
    path.write_text(
        '[scenario]\nmap = "hall.toml"\nduration_s = 90\n'
        "[robots]\ncount = 1\nperiod_s = 0.5\nreturn_home = false\n"
        f'[controller]\nname = "{controller}"\n'
        + ("[controller.options]\nhorizon = 12\n" if controller == "mpc" else "")
        + "[print]\ncaps = { infill = 0.2 }\n"
        '[jobs]\nmode = "scripted"\n[[jobs.scripted]]\nat_s = 0\nstation = "east"\n'
        'print = [{ kind = "support", start_s = 0, end_s = 8 },'
        ' { kind = "infill", start_s = 8, end_s = 20 }]\n'
    )
    return path


def test_a_job_released_at_t_is_observed_at_t_with_its_print_caps(tmp_path):
    world = World(load_scenario(print_scenario(tmp_path, "follower")))
    seen = []
    host = world.host
    original = host.controllers["r01"].compute

    def spy(obs):
        seen.append(obs)
        return original(obs)

    host.controllers["r01"].compute = spy
    world.run()
    first = seen[0]
    assert first.t == 0.0 and first.goal is not None  # not one period late
    # Only the capped task travels, cropped to the look-ahead window; speed_cap is this step's.
    assert first.speed_caps == ((8.0, 20.0, 0.2),) and first.speed_cap is None
    during = next(o for o in seen if o.t == 10.0)
    assert during.speed_caps == ((10.0, 20.0, 0.2),) and during.speed_cap == 0.2
    after = next(o for o in seen if o.t == 20.0)
    assert after.speed_caps == () and after.speed_cap is None


def test_the_follower_honours_print_caps_ahead_and_caps_are_written(tmp_path):
    # The capped task starts 8 s into the print, while the follower would be driving at full
    # speed: it must plan at the cap that is coming, not only the one in force.
    world = World(load_scenario(print_scenario(tmp_path, "follower")))
    result = world.run()
    assert all(n == 0 for n in result.summary["violations"].values())
    assert result.summary["jobs"]["completed"] == 1
    world.recorder.write(tmp_path / "run", result.summary, world.floor, [], world.cap_rows())
    rows = (tmp_path / "run" / "caps.csv").read_text().splitlines()
    assert rows == [
        "robot,job,kind,start_s,end_s,cap,attempt",
        "r01,j00001,infill,8.000000,20.000000,0.2,1",
    ]


def test_the_mpc_honours_print_caps_and_reports_its_solves(tmp_path):
    world = World(load_scenario(print_scenario(tmp_path, "mpc")))
    s = world.run().summary
    assert all(n == 0 for n in s["violations"].values()), s["violations"]
    arrival = s["arrivals"]["r01"]
    assert arrival is not None and arrival > 20.0
    solver = s["solver"]
    assert solver["steps"] == len(world.solves) > 0 and solver["fallbacks"] == 0
    assert solver["termination"] == {"optimal": solver["steps"]}
    assert 0 < solver["median_ms"] <= solver["p95_ms"] <= solver["max_ms"]
    assert solver["overhead_ratio"] >= 1.0


def test_runs_without_solvers_or_scripts_report_accordingly(scenario_file):
    s = World(replace(load_scenario(scenario_file), duration_s=20.0)).run().summary
    assert s["solver"]["steps"] == 0 and s["solver"]["median_ms"] is None
    assert "arrivals" not in s  # Poisson jobs: not a point-to-point run


def test_a_print_given_to_a_moving_robot_starts_once_it_could_have_braked(tmp_path):
    # Job 2 reaches the robot while it drives back home at speed: its capped task must not
    # start before braking could meet the cap, so the MPC meets it; the open job's robot has
    # no arrival yet.
    path = print_scenario(tmp_path, "mpc")
    text = path.read_text().replace("return_home = false", "return_home = true")
    text = text.replace("duration_s = 90", "duration_s = 70")
    text += (
        '[[jobs.scripted]]\nat_s = 45\nstation = "north"\n'
        'print = [{ kind = "infill", start_s = 0, end_s = 30 }]\n'
    )
    path.write_text(text)
    world = World(load_scenario(path))
    s = world.run().summary
    second = world.jobs[1]
    robot = world.robots["r01"]
    assert second.assigned_s == 45.0 and second.print_start_s is not None
    assert second.print_start_s > 45.0  # it was moving when the job came
    assert all(n == 0 for n in s["violations"].values()), s["violations"]
    assert robot.job is second and s["arrivals"] == {"r01": None}


def test_controller_options_that_do_not_suit_the_robot_name_the_scenario(tmp_path):
    path = print_scenario(tmp_path, "mpc")
    path.write_text(path.read_text().replace("horizon = 12", "horizon = 3"))
    with pytest.raises(
        PluginError, match=r"print_mpc.toml: \[controller\] name = 'mpc'.*horizon 3"
    ):
        World(load_scenario(path))
