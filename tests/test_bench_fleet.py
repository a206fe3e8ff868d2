"""The fleet sweep (scripts/bench_fleet.py): its own contact check, exact between samples, what
became of each deadlock (robots with a job and robots heading home apart), and its command
line."""

import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from fleet.engine.recorder import Event, Trajectory
from tests.scripts import REPO_ROOT, load_script


def world(paths: dict[str, list[tuple[float, float]]], radius: float = 0.4) -> SimpleNamespace:
    trajectories = {}
    for robot, points in paths.items():
        tr = Trajectory()
        for k, (x, y) in enumerate(points):
            tr.append(0.25 * k, x, y, 0.0, 0.0)
        trajectories[robot] = tr
    spec = SimpleNamespace(radius=radius)
    return SimpleNamespace(
        robots={r: SimpleNamespace(spec=spec) for r in paths},
        recorder=SimpleNamespace(trajectories=trajectories),
    )


def test_robots_that_pass_through_each_other_between_samples_are_caught() -> None:
    bench = load_script("bench_fleet")
    # Head-on at 4 m/s each: 2 m apart at one sample, 2 m apart (swapped) at the next.
    w = world(
        {
            "r1": [(0.0, 0.0), (0.0, 0.0), (2.0, 0.0)],
            "r2": [(3.0, 0.0), (2.0, 0.0), (0.0, 0.0)],
            "r3": [(9.0, 9.0)] * 3,
        }
    )
    gap, a, b, t = bench.closest_approach(w)
    assert (a, b) == ("r1", "r2")
    assert gap == pytest.approx(-0.8)  # centres met: the radii overlap entirely
    assert t == pytest.approx(0.375)


def test_robots_that_stay_apart_give_their_least_distance_less_the_radii() -> None:
    bench = load_script("bench_fleet")
    w = world({"r1": [(0.0, 0.0), (1.0, 0.0)], "r2": [(0.0, 1.5), (1.0, 1.0)]})
    gap, a, b, t = bench.closest_approach(w)
    assert gap == pytest.approx(1.0 - 0.8) and t == pytest.approx(0.25)


def test_deadlock_fates_are_told_apart_for_robots_with_a_job_and_robots_heading_home() -> None:
    bench = load_script("bench_fleet")
    # r1 (a job) gets to its goal; heading home, r2 comes 1 m closer to its home, r3 never
    # moves, and r4 ends at another home than the one it headed for (traded on the way). Each
    # was reported in deadlock at t = 0.25 s.
    w = world(
        {
            "r1": [(0.0, 0.0), (0.0, 0.0), (1.0, 0.0), (2.0, 0.0)],
            "r2": [(5.0, 0.0), (5.0, 0.0), (6.0, 0.0), (6.0, 0.0)],
            "r3": [(9.0, 9.0)] * 4,
            "r4": [(3.0, 3.0), (3.0, 3.0), (3.0, 2.0), (3.0, 2.0)],
        }
    )
    homes = {"r1": (0.0, 0.0), "r2": (8.0, 0.0), "r3": (0.0, 9.0), "r4": (3.0, 2.0)}
    w.robots = {r: SimpleNamespace(home=home) for r, home in homes.items()}
    w.scenario = SimpleNamespace(arrival_tolerance_m=0.05)
    w.recorder.events = [
        Event(0.25, "deadlock", "j1", "r1"),
        Event(0.25, "deadlock", "", "r2"),
        Event(0.25, "deadlock", "", "r3"),
        Event(0.25, "deadlock", "", "r4"),
        Event(0.75, "arrived", "j1", "r1", "st1"),
    ]
    goals = {
        (0.25, "r1"): (2.0, 0.0),
        (0.25, "r2"): (8.0, 0.0),
        (0.25, "r3"): (0.0, 9.0),
        (0.25, "r4"): (3.0, 6.0),  # its home then
    }
    fate = bench.deadlock_outcomes(w, goals)
    assert [fate[k] for k in bench.FATES] == [2, 1, 0, 1]
    assert fate["with a job"] == {"reached": 1, "progressed": 0, "handed back": 0, "none": 0}
    assert fate["heading home"] == {"reached": 1, "progressed": 1, "handed back": 0, "none": 1}


def test_robots_short_of_home_are_those_idle_robots_off_their_home() -> None:
    bench = load_script("bench_fleet")

    def robot(x: float, job: object = None, return_home: bool = True) -> SimpleNamespace:
        return SimpleNamespace(x=x, y=0.0, home=(0.0, 0.0), job=job, return_home=return_home)

    robots = {
        "home": robot(0.04),  # within the arrival tolerance
        "away": robot(1.0),
        "busy": robot(3.0, job="j1"),  # on a job: not heading home
        "stays": robot(2.0, return_home=False),
    }
    events = [Event(10.0, "delivered", "j0", "busy"), Event(4.0, "delivered", "j2", "away")]
    w = SimpleNamespace(
        robots=robots,
        scenario=SimpleNamespace(arrival_tolerance_m=0.05),
        recorder=SimpleNamespace(events=events),
    )
    assert bench.short_of_home(w) == (1, 10.0)
    w.recorder.events = []
    assert bench.short_of_home(w) == (1, None)


def test_the_best_fixed_split_parts_robots_that_work_in_the_same_rounds() -> None:
    bench = load_script("bench_fleet")
    robots = ["r01", "r02", "r03", "r04"]
    # r01 and r02 work in round 0, r03 and r04 in round 1: together on one worker, each round
    # waits for both (4 in all); parted, for one (2 in all).
    work = np.array([[1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0]])
    shares = bench.best_fixed_split(work, robots, ["r01", "r02"])
    assert sorted(shares[0] + shares[1]) == robots
    for pair in (("r01", "r02"), ("r03", "r04")):
        assert len(set(pair) & set(shares[0])) == 1, shares


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--sweep", "2", "--duration", "-5"], "--duration: '-5': must be a number > 0"),
        (["--sweep", "0"], "--sweep: '0': must be a whole number >= 1"),
        (["--rate", "nan"], "--rate: 'nan': must be a number > 0"),
        (["--workers", "1", "-1"], "--workers: '-1': must be a whole number >= 0"),
        (["--robots", "two"], "--robots: 'two': must be a whole number >= 1"),
        (["--threads", "1", "0"], "--threads: '0': must be a whole number >= 1"),
    ],
)
def test_a_bad_count_or_time_is_refused_by_name_before_anything_runs(
    args: list[str], named: str
) -> None:
    script = REPO_ROOT / "scripts" / "bench_fleet.py"
    done = subprocess.run(
        [sys.executable, str(script), *args], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 2, done.stderr
    assert named in done.stderr and "Traceback" not in done.stderr
    assert done.stdout == ""
