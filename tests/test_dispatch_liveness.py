"""Dispatch-level liveness (issue 16): a job queued behind a busy robot is offered again when
another robot frees up, and (not yet: an expected failure) a station is not kept by the robot
already standing on it while other robots hold jobs waiting for it. Real follower runs on small
open floors."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleet.engine import World
from fleet.scenario import load_scenario

FLOOR = """\
[floor]
name = "open hall"
rect = [0, 0, 32, 12]
default_v_max = 1.0
clearance = 0.4
{stations}
"""

SCENARIO = """\
[scenario]
name = "{name}"
map = "floor.toml"
duration_s = {duration}
seed = 1
arrival_tolerance_m = 0.05
sensing_radius_m = 6.0
deadlock_after_s = {deadlock_after}

[robots]
count = {count}
start = {start}
v_max = 1.0
a_max = 0.5
radius = 0.4
period_s = 0.25
return_home = true

[controller]
name = "follower"

[dispatcher]
name = "{dispatcher}"

[jobs]
mode = "scripted"
{jobs}
"""


def stations(**where: tuple[float, float]) -> str:
    return "\n".join(
        f'[[stations]]\nname = "{name}"\nat = [{x}, {y}]\n'
        + ('kind = "depot"\n' if name.startswith("home") else "")
        for name, (x, y) in where.items()
    )


def run(tmp_path: Path, floor: str, deadlock_after: float = 30, **fields: object) -> World:
    (tmp_path / "floor.toml").write_text(FLOOR.format(stations=floor), encoding="utf-8")
    text = SCENARIO.format(deadlock_after=deadlock_after, **fields)
    (tmp_path / "scen.toml").write_text(text, encoding="utf-8")
    world = World(load_scenario(tmp_path / "scen.toml"))
    world.run()
    return world


def events(world: World, kind: str, job: str | None = None) -> list[tuple[float, str, str]]:
    return [
        (e.t, e.job, e.robot)
        for e in world.recorder.events
        if e.event == kind and (job is None or e.job == job)
    ]


def test_a_job_queued_behind_a_busy_robot_goes_to_a_robot_freed_meanwhile(tmp_path):
    # r01 heads for x on its way to d; its bid for j00003 (to s3, next to x) counts only the
    # trip to x, so it wins j00003 behind its own job. r02 delivers j00002 soon after and
    # stands idle while r01 still drives to d and back: j00003 is offered again, r02 wins it.
    world = run(
        tmp_path,
        stations(homea=(14, 3), homeb=(24, 9), x=(16, 3), d=(3, 3), s3=(17, 6), e=(28, 9)),
        name="queued behind a busy robot",
        duration=90,
        count=2,
        start='["homea", "homeb"]',
        dispatcher="auction",
        jobs="""
[[jobs.scripted]]
at_s = 0
station = "d"
via = ["x"]

[[jobs.scripted]]
at_s = 0
station = "e"

[[jobs.scripted]]
at_s = 1
station = "s3"
""",
    )
    jobs = {rec.job.id: rec for rec in world.jobs}
    assert events(world, "assigned", "j00003")[0][2] == "r01"  # queued behind its job first
    assert jobs["j00003"].robot == "r02"
    assert jobs["j00003"].delivered_s is not None
    # Delivered about when r01 reaches d, some 14 m (over 15 s) from s3: it did not wait
    # behind r01's job.
    assert jobs["j00003"].delivered_s < jobs["j00001"].delivered_s + 5.0
    assert all(rec.delivered_s is not None for rec in world.jobs)
    assert [robot for _, _, robot in events(world, "reoffered", "j00003")] == ["r01"]


def test_a_job_queued_behind_a_stalled_robot_goes_to_an_idle_one(tmp_path):
    # r01 prints standing on g for 60 s; r03 brings j00002 to g and waits beside it. Its bid
    # for j00003 (to h, next to g) does not know it must wait, so it wins j00003 behind its
    # own job while r02, idle far off, bids more. r02 was idle when j00003 was queued, so only
    # r03 stalling (no progress for a deadlock period) sends j00003 to it. (Here r01 steps
    # aside soon after, so r02 is no faster: on the fuzz floors it is, see docs/fleet.md.)
    print_ = '[[jobs.scripted.print]]\nkind = "contour"\nstart_s = 0.0\nend_s = 60.0\n'
    world = run(
        tmp_path,
        stations(homea=(11, 6), homeb=(2, 10), homec=(15, 9), g=(15, 6), h=(15, 2)),
        name="queued behind a stalled robot",
        deadlock_after=10,
        duration=90,
        count=3,
        start='["homea", "homeb", "homec"]',
        dispatcher="auction",
        jobs=f"""
[[jobs.scripted]]
at_s = 0
station = "g"

{print_}
[[jobs.scripted]]
at_s = 0.5
station = "g"

[[jobs.scripted]]
at_s = 1
station = "h"
""",
    )
    jobs = {rec.job.id: rec for rec in world.jobs}
    assert jobs["j00001"].robot == "r01" and jobs["j00002"].robot == "r03"
    assert events(world, "assigned", "j00003")[0][2] == "r03"  # queued behind its job first
    # Offered again when r03 is found stalled, while it still waits for g, and r02 wins it.
    (stalled, _, _), *_ = events(world, "deadlock", "j00002")
    assert [(t, robot) for t, _, robot in events(world, "reoffered", "j00003")] == [
        (stalled, "r03")
    ]
    assert stalled < jobs["j00002"].delivered_s
    assert jobs["j00003"].robot == "r02" and jobs["j00003"].delivered_s is not None


@pytest.mark.xfail(
    strict=True,
    reason="station starvation (fuzz s21-0366): the robot on a station takes the next job "
    "there and prints standing on it while a robot ready to deliver waits beside it; "
    "dispatch-level turn rules measured worse on the fuzz (docs/fleet.md, known limit)",
)
def test_the_robot_served_at_a_station_does_not_take_its_next_job_ahead_of_one_waiting(tmp_path):
    # r01 reaches g first and prints there; r02, holding an older job to g, waits beside it
    # with its print done at 12.25 s. A new job to g comes each time r01 delivers, and r01,
    # nearest, takes each one and prints on g again while r02 waits (until 79 s here).
    print_ = '[[jobs.scripted.print]]\nkind = "contour"\nstart_s = 0.0\nend_s = 12.0\n'
    jobs = "".join(
        f'\n[[jobs.scripted]]\nat_s = {t}\nstation = "g"\n\n{print_}'
        for t in (0, 0, 12.5, 25, 37.5, 50, 62.5)
    )
    world = run(
        tmp_path,
        stations(homea=(12, 6), homeb=(15, 10), g=(15, 6)),
        name="one station, two robots",
        duration=120,
        count=2,
        start='["homea", "homeb"]',
        dispatcher="greedy",
        jobs=jobs,
    )
    jobs_ = {rec.job.id: rec for rec in world.jobs}
    assert jobs_["j00001"].robot == "r01" and jobs_["j00002"].robot == "r02"
    # r02's print ends at 12.25 s: it delivers as soon as r01 has left g.
    assert jobs_["j00002"].delivered_s is not None and jobs_["j00002"].delivered_s < 20.0
    # And the robots take turns at g: neither takes two jobs in a row while the other waits.
    assert {rec.robot for rec in world.jobs if rec.job.id in ("j00003", "j00004")} == {
        "r01",
        "r02",
    }
    assert all(rec.delivered_s is not None for rec in world.jobs)
