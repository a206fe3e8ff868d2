"""Run figures: drawn from a real run directory, with the limit line the paper's figure shows."""

import os
import shutil
import struct
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_hex

from fleet.engine import World
from fleet.errors import InputError
from fleet.floor import load_floor
from fleet.scenario import JobsConfig, ScriptedJob, default_scenario
from fleet.view.figures import (
    KIND_COLOURS,
    PrintCap,
    TaskSpan,
    Track,
    gantt_figure,
    load_caps,
    load_jobs,
    load_run,
    load_tasks,
    save_run_figures,
    speed_figure,
    step_limits,
    trajectory_figure,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CAPS_HEADER = "robot,job,kind,start_s,end_s,cap\n"
TASKS_HEADER = "robot,job,kind,start_s,end_s\n"


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


def test_save_run_figures_writes_all_pngs_loading_the_map_named_in_the_summary(run_dir):
    paths = save_run_figures(run_dir)
    assert paths == [run_dir / "trajectory.png", run_dir / "speed.png", run_dir / "gantt.png"]
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


def test_the_speed_axis_ends_where_the_run_ends(run_dir):
    # A print task cut off by the end of the run leaves a cap past it in caps.csv.
    (run_dir / "caps.csv").write_text(CAPS_HEADER + "r01,j1,contour,50,95,0.3\n")
    run = load_run(run_dir)
    assert run.t_end == 60.0
    for fig in (speed_figure(run.tracks, run.caps, t_end=run.t_end), speed_figure(run.tracks)):
        for ax in fig.axes:
            assert ax.get_xlim() == (0.0, pytest.approx(60.0, abs=0.25))


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


# -- the Gantt chart --------------------------------------------------------------------------
def bars(ax) -> dict[str, object]:
    return {p.get_gid(): p for p in ax.patches if (p.get_gid() or "").startswith("task:")}


def test_gantt_draws_each_task_in_its_robots_row_in_its_kinds_colour(run_dir):
    (run_dir / "tasks.csv").write_text(
        TASKS_HEADER
        + "r01,j00001,contour,0.5,9.5\n"
        + "r01,j00001,travel,9.5,10\n"
        + "r02,j00002,infill,2,2.2\n"
    )
    run = load_run(run_dir)
    fig = gantt_figure(run.tasks, run.events, run.jobs, robots=list(run.tracks), t_end=60.0)
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_yticklabels()] == ["r01", "r02", "r03"]
    drawn = bars(ax)
    assert set(drawn) == {
        "task:r01:j00001:contour",
        "task:r01:j00001:travel",
        "task:r02:j00002:infill",
    }
    contour = drawn["task:r01:j00001:contour"]
    assert (contour.get_x(), contour.get_width()) == pytest.approx((0.5, 9.0))
    assert contour.get_y() + contour.get_height() / 2 == pytest.approx(0.0)  # row of r01
    infill = drawn["task:r02:j00002:infill"]
    assert infill.get_y() + infill.get_height() / 2 == pytest.approx(1.0)  # row of r02
    assert to_hex(infill.get_facecolor()) == KIND_COLOURS["infill"]
    assert ax.get_xlim() == (0.0, 60.0)
    legend = [x.get_text() for x in fig.legends[0].get_texts()]
    assert {"print: contour", "print: travel", "print: infill", "delivered"} <= set(legend)
    assert "print: support" not in legend


def test_gantt_labels_jobs_only_where_they_fit(run_dir):
    (run_dir / "tasks.csv").write_text(
        TASKS_HEADER + "r01,j00001,contour,0,50\nr02,j00002,infill,2,2.3\n"
    )
    run = load_run(run_dir)
    ax = gantt_figure(run.tasks, run.events, robots=list(run.tracks), t_end=60.0).axes[0]
    labels = {t.get_gid(): t for t in ax.texts if (t.get_gid() or "").startswith("label:")}
    assert labels["label:j00001"].get_visible() and labels["label:j00001"].get_text() == "j00001"
    assert not labels["label:j00002"].get_visible()  # 0.3 s of a 60 s axis: no room


def test_gantt_marks_deliveries_and_the_time_each_job_was_in_hand(run_dir):
    run = load_run(run_dir)
    delivered = {e.job: e.t for e in run.events if e.event == "delivered"}
    assigned = {e.job: e.t for e in run.events if e.event == "assigned"}
    assert delivered, "the fixture's jobs are delivered"
    ax = gantt_figure(run.tasks, run.events, robots=list(run.tracks)).axes[0]
    (marks,) = [ln for ln in ax.get_lines() if ln.get_gid() == "delivered"]
    assert sorted(marks.get_xdata()) == sorted(delivered.values())
    held = {p.get_gid(): p for p in ax.patches if (p.get_gid() or "").startswith("held:")}
    for job, t in delivered.items():
        band = held[f"held:{job}"]
        assert (band.get_x(), band.get_x() + band.get_width()) == pytest.approx((assigned[job], t))


def test_defective_parts_get_red_labels(run_dir):
    (run_dir / "tasks.csv").write_text(TASKS_HEADER + "r01,j00001,contour,0,50\n")
    (run_dir / "jobs.csv").write_text(
        "id,robot,released_s,started_s,finished_s,delivered_s,outcome,passed\n"
        "j00001,r01,0,0,50,50,defective,false\n"
    )
    run = load_run(run_dir)
    assert run.jobs[0].passed is False and run.jobs[0].outcome == "defective"
    ax = gantt_figure(run.tasks, run.events, run.jobs).axes[0]
    (label,) = [t for t in ax.texts if t.get_gid() == "label:j00001"]
    assert to_hex(label.get_color()) == "#b00000"


def test_tasks_come_from_tasks_csv_else_from_caps_csv(run_dir):
    assert load_tasks(run_dir) == ()
    (run_dir / "caps.csv").write_text(CAPS_HEADER + "r01,j1,contour,10,20,0.3\n")
    from_caps = (TaskSpan("r01", "j1", "contour", 10.0, 20.0),)
    assert load_tasks(run_dir) == from_caps
    (run_dir / "tasks.csv").write_text(TASKS_HEADER)  # a header only: nothing recorded there
    assert load_tasks(run_dir) == from_caps
    (run_dir / "tasks.csv").write_text(TASKS_HEADER + "r01,j1,travel,20,25\nr01,j1,contour,10,20\n")
    assert [t.kind for t in load_tasks(run_dir)] == ["contour", "travel"]  # by start
    (run_dir / "tasks.csv").write_text(TASKS_HEADER + "r01,j1,travel,25,20\n")
    with pytest.raises(InputError, match=r"tasks\.csv: line 2, end_s = '20': must be after"):
        load_tasks(run_dir)


def test_a_bad_jobs_file_names_line_and_value(run_dir):
    path = run_dir / "jobs.csv"
    path.write_text("id,robot,released_s,started_s,finished_s,delivered_s,outcome\nj1,r01,0,,,x,\n")
    with pytest.raises(InputError, match=r"jobs\.csv: line 2, delivered_s = 'x': must be a number"):
        load_jobs(path)


def test_figures_are_drawn_without_a_display_or_pyplot(run_dir):
    # A GUI backend and no display: any use of pyplot would fail or show in sys.modules.
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MPLBACKEND"] = "TkAgg"
    code = (
        "import sys; from fleet.view.figures import save_run_figures; "
        f"paths = save_run_figures({str(run_dir)!r}); "
        "assert 'matplotlib.pyplot' not in sys.modules, 'pyplot was imported'; "
        "print(*(p.name for p in paths))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["trajectory.png", "speed.png", "gantt.png"]
    width, height = png_size(run_dir / "gantt.png")
    assert width >= 800 and height >= 300
