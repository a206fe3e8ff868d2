"""Run figures: drawn from a real run directory, with the limit line the paper's figure shows."""

import shutil
import struct
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fleet.engine import World
from fleet.errors import InputError
from fleet.floor import load_floor
from fleet.plots import (
    PrintCap,
    Track,
    load_caps,
    load_run,
    save_run_figures,
    speed_figure,
    step_limits,
    trajectory_figure,
)
from fleet.scenario import JobsConfig, ScriptedJob, default_scenario

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CAPS_HEADER = "robot,job,kind,start_s,end_s,cap\n"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A run directory written the way `fleet run` writes it: 3 robots, 60 s, 2 jobs."""
    scenario = default_scenario().override(robots=3, duration=60)
    # Scripted jobs at t = 0 so that robots drive (Poisson jobs may not come within 60 s).
    jobs = (ScriptedJob(0.0, "cnc_1_in"), ScriptedJob(0.0, "furnace_in"))
    scenario = replace(scenario, jobs=JobsConfig(mode="scripted", scripted=jobs))
    world = World(scenario)
    result = world.run()
    out = tmp_path_factory.mktemp("runs") / "run"
    world.recorder.write(out, result.summary, world.floor, result.safety.examples)
    return out


@pytest.fixture
def run_dir(recorded: Path, tmp_path: Path) -> Path:
    """A private copy of the recorded run, without caps.csv, that a test may change."""
    out = tmp_path / "run"
    shutil.copytree(recorded, out)
    (out / "caps.csv").unlink(missing_ok=True)
    return out


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, f"{path} is not a PNG"
    return struct.unpack(">II", data[16:24])  # IHDR width, height


def line(ax, gid: str):
    (found,) = [ln for ln in ax.get_lines() if ln.get_gid() == gid]
    return found


def test_save_run_figures_writes_both_pngs_loading_the_map_named_in_the_summary(run_dir):
    paths = save_run_figures(run_dir)
    assert paths == [run_dir / "trajectory.png", run_dir / "speed.png"]
    for path in paths:
        width, height = png_size(path)
        assert width >= 800 and height >= 400
        assert path.stat().st_size > 20_000  # a drawn figure, not an empty canvas


def test_a_floor_passed_in_needs_no_summary(run_dir):
    floor = load_floor(load_run(run_dir).summary["map"])
    (run_dir / "summary.json").unlink()
    paths = save_run_figures(run_dir, floor)
    assert all(png_size(p)[0] > 0 for p in paths)


def test_without_a_floor_a_missing_summary_is_named(run_dir):
    (run_dir / "summary.json").unlink()
    with pytest.raises(InputError, match=r"summary\.json"):
        save_run_figures(run_dir)


def test_a_run_dir_without_trajectories_names_the_missing_file(run_dir):
    (run_dir / "trajectories.csv").unlink()
    with pytest.raises(InputError, match=r"trajectories\.csv.*missing"):
        save_run_figures(run_dir)
    assert not (run_dir / "trajectory.png").exists()


def test_one_speed_panel_per_robot_up_to_the_limit(run_dir):
    run = load_run(run_dir)
    assert list(run.tracks) == ["r01", "r02", "r03"]
    few = speed_figure(run.tracks, run.caps, robots=2)
    assert [ax.get_title(loc="left") for ax in few.axes] == ["r01", "r02"]
    assert "first 2 of 3 robots" in few.get_suptitle()
    every = speed_figure(run.tracks, run.caps, robots=6)
    assert [ax.get_title(loc="left") for ax in every.axes] == ["r01", "r02", "r03"]


def test_velocity_steps_are_the_recorded_samples(run_dir):
    run = load_run(run_dir)
    ax = speed_figure(run.tracks).axes[0]
    track = run.tracks["r01"]
    assert np.abs(track.v).max() > 0.3  # the robot drove
    np.testing.assert_array_equal(line(ax, "vx").get_ydata(), track.v[:, 0])
    np.testing.assert_array_equal(line(ax, "vy").get_ydata(), track.v[:, 1])
    assert line(ax, "vx").get_drawstyle() == "steps-post"


def test_a_print_cap_lowers_the_limit_line_only_while_the_task_runs(run_dir):
    (run_dir / "caps.csv").write_text(CAPS_HEADER + "r01,j1,contour,10,20,0.3\n")
    run = load_run(run_dir)
    assert run.caps == (PrintCap("r01", "j1", "contour", 10.0, 20.0, 0.3),)
    fig = speed_figure(run.tracks, run.caps)
    t = run.tracks["r01"].t
    upper = line(fig.axes[0], "limit+").get_ydata()
    lower = line(fig.axes[0], "limit-").get_ydata()
    assert upper.min() == pytest.approx(0.3)
    np.testing.assert_array_equal(lower, -upper)
    during = (t >= 10) & (t < 20)
    assert np.all(upper[during] == pytest.approx(0.3))
    # Outside the task only zone limits hold, and every zone on this floor allows >= 0.4 m/s.
    assert np.all(upper[:-1][t[1:] <= 10] >= 0.4)
    assert np.all(upper[t >= 20] >= 0.4)
    # The other robots print nothing: their limit never falls below the slowest zone.
    assert line(fig.axes[1], "limit+").get_ydata().min() >= 0.4
    legend = [x.get_text() for x in fig.legends[0].get_texts()]
    assert "print: contour" in legend


def test_missing_or_empty_caps_mean_no_print_tasks(run_dir):
    assert load_caps(run_dir / "caps.csv") == ()
    without = load_run(run_dir)
    (run_dir / "caps.csv").write_text(CAPS_HEADER)
    assert load_run(run_dir).caps == ()
    upper = line(speed_figure(without.tracks, without.caps).axes[0], "limit+").get_ydata()
    zone = without.tracks["r01"].v_zone
    np.testing.assert_array_equal(upper[:-1], np.minimum(zone[:-1], zone[1:]))
    assert save_run_figures(run_dir)[1].is_file()


def test_a_bad_cap_names_file_line_and_value(run_dir):
    (run_dir / "caps.csv").write_text(CAPS_HEADER + "r01,j1,contour,10,20,fast\n")
    with pytest.raises(InputError, match=r"caps\.csv: line 2, cap = 'fast': must be a number"):
        load_run(run_dir)
    (run_dir / "caps.csv").write_text(CAPS_HEADER + "r01,j1,contour,20,10,0.3\n")
    with pytest.raises(InputError, match=r"line 2, end_s = '10': must be after start_s 20"):
        load_run(run_dir)


def test_a_trajectories_file_without_a_column_is_refused(run_dir):
    path = run_dir / "trajectories.csv"
    path.write_text("t,robot,x,y\n0,r01,1,2\n")
    with pytest.raises(InputError, match=r"trajectories\.csv: header .*lacks vx, vy, region"):
        load_run(run_dir)


def test_trajectory_figure_draws_each_path_and_drops_robot_entries_when_crowded(run_dir):
    run = load_run(run_dir)
    fig = trajectory_figure(run.floor, run.tracks)
    ax = fig.axes[0]
    for rid, track in run.tracks.items():
        path = line(ax, f"path:{rid}")
        np.testing.assert_array_equal(path.get_xdata(), track.xy[:, 0])
        np.testing.assert_array_equal(path.get_ydata(), track.xy[:, 1])
    labels = [x.get_text() for x in fig.legends[0].get_texts()]
    assert {"r01", "r02", "r03", "0.4 m/s", "0.8 m/s", "obstacle"} <= set(labels)
    crowded = trajectory_figure(run.floor, run.tracks, robots=2)
    labels = [x.get_text() for x in crowded.legends[0].get_texts()]
    assert "r01" not in labels and "paths (3)" in labels
    assert line(crowded.axes[0], "path:r01").get_linewidth() < 1.0


def make_track(t, v_zone) -> Track:
    n = len(t)
    return Track(
        "r01",
        np.asarray(t, dtype=float),
        np.zeros((n, 2)),
        np.zeros((n, 2)),
        np.zeros(n, dtype=np.int64),
        np.asarray(v_zone, dtype=float),
    )


def test_step_limits_bind_a_step_by_both_zones_and_by_caps_overlapping_it():
    track = make_track([0, 1, 2, 3, 4], [1.0, 0.4, 1.0, 1.0, 0.8])
    # Steps straddling a boundary take the slower side.
    np.testing.assert_array_equal(step_limits(track), [0.4, 0.4, 1.0, 0.8])
    caps = [
        PrintCap("r01", "j", "infill", 2.5, 2.75, 0.5),  # inside step 2 only
        PrintCap("r01", "j", "contour", 3.0, 4.0, 0.3),  # exactly step 3: not step 2
        PrintCap("r02", "j", "contour", 0.0, 4.0, 0.1),  # another robot's task
        PrintCap("r01", "j", "travel", 0.0, 1.0, float("inf")),  # no cap
    ]
    np.testing.assert_array_equal(step_limits(track, caps), [0.4, 0.4, 0.5, 0.3])
    assert step_limits(make_track([0.0], [1.0])).shape == (0,)
