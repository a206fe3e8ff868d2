"""The HTML replay: a self-contained page that a real headless Chromium draws as recorded."""

import csv
import html
import itertools
import json
import os
import re
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from matplotlib.image import imread

from fleet.engine import World
from fleet.errors import InputError
from fleet.printing import PrintTask
from fleet.scenario import JobsConfig, ScriptedJob, load_scenario
from fleet.view.figures import load_jobs, load_run, load_tracks
from fleet.view.replay import (
    REPLAY_HTML,
    VIEW_MARGIN_PX,
    View,
    load_plans,
    page_part,
    replay_html,
    robot_colour,
    simplify,
    view_transform,
    write_replay,
)

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
#: What the scripted jobs print, seconds after each print starts: every kind, one uncapped.
TASKS = (
    PrintTask("support", 0.0, 20.0),
    PrintTask("contour", 20.0, 50.0),
    PrintTask("travel", 50.0, 60.0),
    PrintTask("infill", 60.0, 90.0),
)
PLAN_HORIZON_S = 5.0
#: The window sizes the page must fit: the smallest it promises and a common desktop.
WINDOWS = ((1280, 720), (1920, 1080))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A real run directory of the default scenario: 2 robots, 120 s, one scripted job each.

    plans.csv and tasks.csv are written here from what the run recorded (a plan every second
    while a robot moves: the next 5 s of its own trajectory; every scripted task on the clock),
    so the test does not depend on which controller sends plans.
    """
    scenario = load_scenario("scenarios/default.toml").override(duration=120, robots=2)
    jobs = (ScriptedJob(0.0, "cnc_1_in", tasks=TASKS), ScriptedJob(0.0, "furnace_in", tasks=TASKS))
    world = World(replace(scenario, jobs=JobsConfig(mode="scripted", scripted=jobs)))
    world.run()
    out = tmp_path_factory.mktemp("replay") / "run"
    world.write(out)
    write_tasks(out)
    write_plans(out)
    return out


def write_tasks(run: Path) -> None:
    with open(run / "tasks.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["robot", "job", "kind", "start_s", "end_s"])
        for job in load_jobs(run / "jobs.csv"):
            assert job.robot and job.started_s is not None, "every scripted job must start"
            stop = job.delivered_s if job.delivered_s is not None else np.inf
            for task in TASKS:
                start, end = job.started_s + task.start_s, min(job.started_s + task.end_s, stop)
                if end > start:
                    w.writerow([job.robot, job.id, task.kind, f"{start:.6f}", f"{end:.6f}"])


def write_plans(run: Path) -> None:
    tracks = load_tracks(run / "trajectories.csv")
    with open(run / "plans.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_sent", "robot", "k", "t", "x", "y"])
        for rid, tr in tracks.items():
            for i in range(0, len(tr.t), 4):
                if not np.any(tr.v[i]):
                    continue
                ahead = np.flatnonzero((tr.t >= tr.t[i]) & (tr.t <= tr.t[i] + PLAN_HORIZON_S))
                for k, j in enumerate(ahead[::4]):
                    w.writerow([f"{tr.t[i]:.3f}", rid, k, tr.t[j], tr.xy[j, 0], tr.xy[j, 1]])


@pytest.fixture
def run_dir(recorded: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(recorded, out)
    return out


def page_data(path: Path) -> dict:
    return page_data_text(path.read_text(encoding="utf-8"))


def page_data_text(text: str) -> dict:
    m = re.search(r'<script type="application/json" id="replay-data">(.*?)</script>', text, re.S)
    assert m, "the page embeds its data as application/json"
    return json.loads(m.group(1))


def position(track, t: float) -> tuple[float, float]:
    return float(np.interp(t, track.t, track.xy[:, 0])), float(
        np.interp(t, track.t, track.xy[:, 1])
    )


def rgb(hex_colour: str) -> np.ndarray:
    return np.array([int(hex_colour[i : i + 2], 16) / 255 for i in (1, 3, 5)])


# -- the page ---------------------------------------------------------------------------------
def test_the_page_fetches_nothing_and_embeds_its_data_as_json(run_dir):
    path = write_replay(run_dir)
    assert path == run_dir / REPLAY_HTML
    text = path.read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text and "//cdn" not in text
    assert not re.search(r"\b(src|href)\s*=", text), "no external (or any) resource reference"
    assert text.count("<script") == 2 and "<link" not in text

    data = page_data(path)
    run = load_run(run_dir)
    assert [r["id"] for r in data["robots"]] == ["r01", "r02"]
    assert len({r["colour"] for r in data["robots"]}) == 2
    assert [r["radius"] for r in data["robots"]] == [0.4, 0.4]  # the map's footprint radius
    assert data["t0"] == 0.0 and data["t1"] == 120.0
    assert data["bounds"] == list(run.floor.bounds) and data["margin"] == VIEW_MARGIN_PX
    assert {j["id"] for j in data["jobs"]} == {j.id for j in run.jobs}
    assert {j["station"] for j in data["jobs"]} == {"cnc_1_in", "furnace_in"}
    # tasks.csv wins over caps.csv: the uncapped travel task is there.
    assert "travel" in {k[2] for r in data["robots"] for k in r["tasks"]}
    plans = load_plans(run_dir / "plans.csv")
    assert [len(r["plans"]["sent"]) for r in data["robots"]] == [len(plans[r]) for r in plans]
    assert len(data["floor"]["zones"]) == 3 and len(data["floor"]["stations"]) == 11  # 2 chargers


def test_embedded_samples_interpolate_to_every_recorded_sample(run_dir):
    data = page_data(write_replay(run_dir))
    tracks = load_tracks(run_dir / "trajectories.csv")
    for robot in data["robots"]:
        track = tracks[robot["id"]]
        assert len(robot["t"]) < len(track.t) / 4  # thinned: the file stays small
        x = np.interp(track.t, robot["t"], robot["x"])
        y = np.interp(track.t, robot["t"], robot["y"])
        err = np.hypot(x - track.xy[:, 0], y - track.xy[:, 1])
        assert err.max() <= 0.01 + 1e-3  # tolerance plus the mm rounding


def test_a_run_dir_without_plans_or_tasks_still_replays(run_dir, tmp_path):
    (run_dir / "plans.csv").unlink()
    (run_dir / "tasks.csv").unlink()
    out = write_replay(run_dir, tmp_path / "elsewhere" / "r.html")
    assert out == tmp_path / "elsewhere" / "r.html" and out.is_file()
    data = page_data(out)
    assert all(r["plans"] == {"sent": [], "pts": []} for r in data["robots"])
    kinds = {k[2] for r in data["robots"] for k in r["tasks"]}
    assert kinds == {"support", "contour", "infill"}  # caps.csv: the capped kinds only


def test_a_bad_plan_row_names_file_line_and_column(run_dir):
    with open(run_dir / "plans.csv", "a") as fh:
        fh.write("3.000,r01,0,3.000,east,1\n")
    with pytest.raises(InputError, match=r"plans\.csv: line \d+, x = 'east': must be a number"):
        write_replay(run_dir)


def test_the_view_fits_the_floor_at_its_aspect_inside_the_margin():
    wide = view_transform((0.0, 0.0, 80.0, 50.0))
    assert (wide.scale, wide.width, wide.height) == (12.0, 1000, 640)
    assert wide.pixel(0.0, 50.0) == (20.0, 20.0)  # top-left corner of the floor
    assert wide.pixel(80.0, 0.0) == (980.0, 620.0)
    tall = view_transform((-5.0, 10.0, 5.0, 110.0))
    assert tall.scale == pytest.approx(6.6) and tall.height == 700 and tall.width == 106
    assert tall.pixel(-5.0, 110.0) == pytest.approx((20.0, 20.0))
    with pytest.raises(ValueError, match="bounds"):
        view_transform((0.0, 0.0, 0.0, 10.0))


def test_robot_colours_are_distinct_for_a_large_fleet():
    colours = [robot_colour(i) for i in range(24)]
    assert len(set(colours)) == 24
    assert all(re.fullmatch(r"#[0-9a-f]{6}", c) for c in colours)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(0.0, 2.0), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)),
        min_size=1,
        max_size=12,
    ),
    st.sampled_from([0.0, 0.001, 0.01, 0.1]),
)
def test_simplify_keeps_linear_interpolation_within_the_tolerance(pieces, tolerance):
    # A piecewise-constant-velocity trajectory sampled at 0.25 s, as the engine records.
    t, xy = [0.0], [np.zeros(2)]
    for duration, vx, vy in pieces:
        for _ in range(int(duration / 0.25)):
            t.append(t[-1] + 0.25)
            xy.append(xy[-1] + 0.25 * np.array([vx, vy]))
    t, xy = np.array(t), np.array(xy)
    keep = simplify(t, xy, tolerance)
    assert keep[0] == 0 and keep[-1] == len(t) - 1 and np.all(np.diff(keep) > 0)
    x = np.interp(t, t[keep], xy[keep, 0])
    y = np.interp(t, t[keep], xy[keep, 1])
    assert np.hypot(x - xy[:, 0], y - xy[:, 1]).max() <= tolerance + 1e-9


def test_simplify_needs_two_samples_for_rest_and_for_constant_velocity():
    t = np.arange(0.0, 100.0, 0.25)
    assert simplify(t, np.zeros((len(t), 2))).tolist() == [0, len(t) - 1]
    assert simplify(t, np.column_stack([0.3 * t, -0.2 * t])).tolist() == [0, len(t) - 1]


def test_the_page_parts_are_shipped_files_that_cannot_end_their_element():
    # They are package data (pyproject's package-data; tests/test_architecture.py checks every
    # data file ships) and inlined as they are: a closing tag inside would end the page's
    # <style> or <script> early.
    assert "</style" not in page_part("replay.css").lower()
    assert "</script" not in page_part("replay.js").lower()
    template = page_part("replay.html")
    assert all(f"@{slot}@" in template for slot in ("TITLE", "CSS", "SCRIPT", "DATA"))


def test_text_put_into_the_page_is_never_read_as_a_slot(run_dir):
    run = load_run(run_dir)
    data = page_data(write_replay(run_dir))
    data["title"] = "@CSS@ </script><b>"
    text = replay_html(data)
    assert text.count("<style>") == 1 and text.count("</script>") == 2
    assert "<title>replay: @CSS@ &lt;/script&gt;&lt;b&gt;</title>" in text
    assert page_data_text(text)["title"] == "@CSS@ </script><b>" and run.title != data["title"]


# -- the page in a real browser ---------------------------------------------------------------
def screenshot(page: Path, t: float, work: Path, size: tuple[int, int]) -> subprocess.Popen:
    """Start headless Chromium on ``page#t=<t>``; it writes ``shot.png`` and prints the DOM."""
    work.mkdir()
    cmd = [
        str(CHROMIUM),
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={work / 'profile'}",
        "--force-device-scale-factor=1",
        "--hide-scrollbars",
        # Headless Chromium keeps 143 px of a window for browser bars it does not draw, so a page
        # would be laid out for 1280x577 and shot at 1280x720. Full screen (kiosk) on a screen
        # the window's size makes the page's viewport exactly the screenshot.
        "--kiosk",
        f"--screen-info={{{size[0]}x{size[1]}}}",
        f"--window-size={size[0]},{size[1]}",
        "--virtual-time-budget=3000",
        "--dump-dom",
        f"--screenshot={work / 'shot.png'}",
        f"{page.resolve().as_uri()}#t={t:g}",
    ]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


def finish(proc: subprocess.Popen, work: Path) -> tuple[str, Path]:
    """The DOM Chromium printed and the screenshot it wrote (its path printed for a reader)."""
    try:
        dom, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()
    shot = work / "shot.png"
    assert shot.is_file(), f"chromium wrote no screenshot (exit {proc.returncode})"
    print(f"screenshot: {shot}")
    return dom, shot


#: Appended to a page under test: once the page has settled, what it reports and what the
#: browser measured go into a hidden <pre id="probe"> as JSON, for --dump-dom to print.
PROBE = """<script>
setTimeout(function () {
  const box = (id) => {
    const r = document.getElementById(id).getBoundingClientRect();
    return [r.left, r.top, r.right, r.bottom];
  };
  const root = document.documentElement;
  const out = {
    inner: [innerWidth, innerHeight], scroll: [root.scrollWidth, root.scrollHeight],
    canvas: box("floor"), side: box("side"), controls: box("controls"),
    view: replayView(), labels: replayLabels(), scaleBar: replayScaleBar(), t: replayTime(),
  };
  const pre = document.createElement("pre");
  pre.id = "probe"; pre.hidden = true; pre.textContent = JSON.stringify(out);
  document.body.append(pre);
}, 500);
</script>
</body>"""


def probed(page: Path, name: str, extra: str = "") -> Path:
    """A copy of `page` that runs `extra` (a script element) and then reports (`PROBE`)."""
    out = page.with_name(name)
    out.write_text(page.read_text(encoding="utf-8").replace("</body>", extra + PROBE))
    return out


def probe(dom: str) -> dict:
    m = re.search(r'<pre id="probe" hidden="">(.*?)</pre>', dom, re.S)
    assert m, "the page ran the probe (a script error stops it)"
    return json.loads(html.unescape(m.group(1)))


def page_view(report: dict) -> tuple[View, tuple[int, int]]:
    """The map the page reported, and where its canvas sits in the window (px)."""
    v = report["view"]
    return View(v["scale"], v["x0"], v["y0"], v["width"], v["height"]), (v["left"], v["top"])


def overlap(a: dict, b: dict) -> bool:
    return (
        a["x"] < b["x"] + b["w"]
        and b["x"] < a["x"] + a["w"]
        and a["y"] < b["y"] + b["h"]
        and b["y"] < a["y"] + a["h"]
    )


def pick_times(tracks, robots) -> tuple[float, float]:
    """Two times >= 12 s apart, off the 0.25 s sample grid, at which every robot is moving and
    the robots are far apart."""

    def good(t: float) -> bool:
        moving = all(
            np.hypot(*tracks[r].v[np.searchsorted(tracks[r].t, t) - 1]) > 0.2 for r in robots
        )
        a, b = (np.array(position(tracks[r], t)) for r in robots)
        return moving and np.hypot(*(a - b)) > 10.0

    candidates = [t for t in np.arange(1.1, 118.0, 0.7) if good(t)]
    assert candidates, "the fixture's robots must drive at the same time"
    first = candidates[0]
    later = [t for t in candidates if t >= first + 12.0]
    assert later, "the fixture's robots must drive for more than 12 s"
    return float(first), float(later[0])


@pytest.fixture
def chromium() -> str:
    if CHROMIUM is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is not installed (CI is set: the replay must be tested there)")
        pytest.skip("chromium is not installed (Debian: apt-get install chromium)")
    return CHROMIUM


@pytest.fixture(scope="module")
def crowded(tmp_path_factory) -> Path:
    """The replay of scenarios/fleet.toml's first 20 s: 12 robots, 6 parked at each depot."""
    world = World(load_scenario("scenarios/fleet.toml").override(duration=20, robots=12))
    world.run()
    out = tmp_path_factory.mktemp("crowded") / "run"
    world.write(out)
    return write_replay(out)


@pytest.mark.parametrize("size", WINDOWS, ids=lambda s: f"{s[0]}x{s[1]}")
def test_the_page_fits_the_window_with_the_whole_floor_a_scale_bar_and_apart_labels(
    chromium, crowded, tmp_path, size
):
    data = page_data(crowded)
    work = tmp_path / "shot"
    dom, shot = finish(screenshot(probed(crowded, f"probe{size[0]}.html"), 0.0, work, size), work)
    image = imread(shot)
    assert image.shape[:2] == (size[1], size[0])  # the screenshot is the window
    report = probe(dom)
    width, height = size
    assert report["inner"] == [width, height]
    assert report["scroll"][0] <= width and report["scroll"][1] <= height, "the page scrolls"

    def inside(box, outer) -> bool:
        return (
            outer[0] <= box[0] and outer[1] <= box[1] and box[2] <= outer[2] and box[3] <= outer[3]
        )

    window = (0, 0, width, height)
    for part in ("canvas", "side", "controls"):
        assert inside(report[part], window), (part, report[part])
    assert report["side"][2] - report["side"][0] >= 300 and report["side"][0] >= report["canvas"][2]
    assert report["controls"][1] >= report["canvas"][3]  # below the floor, not over it

    # The page's map is view_transform for the area it had, and its canvas is where it says.
    view, (left, top) = page_view(report)
    area = report["view"]["area"]
    assert view == view_transform(data["bounds"], width=area[0], height=area[1])
    assert report["canvas"] == [left, top, left + view.width, top + view.height]
    assert view.width >= 0.7 * (width - (report["side"][2] - report["side"][0]))  # it grew
    xmin, ymin, xmax, ymax = data["bounds"]
    (fx0, fy0), (fx1, fy1) = view.pixel(xmin, ymax), view.pixel(xmax, ymin)
    assert 0 <= fx0 < fx1 <= view.width and 0 <= fy0 < fy1 <= view.height  # the whole floor

    bar = report["scaleBar"]
    assert bar["metres"] in {1, 2, 5, 10, 20, 50} and bar["text"] == f"{bar['metres']:g} m"
    assert bar["px"] == pytest.approx(bar["metres"] * view.scale) and 30 <= bar["px"] <= 160
    assert (
        bar["x"] >= 0 and bar["x"] + bar["w"] <= view.width and bar["y"] + bar["h"] <= view.height
    )
    row = int(top + bar["y"] + bar["h"] / 2 + 3)  # the bar's line, drawn dark on white
    line = image[row, int(left + bar["x"] + 8) : int(left + bar["x"] + 4 + bar["px"]), :3]
    assert line.max() < 0.35, "a dark scale bar where the page says"

    labels = report["labels"]
    for a, b in itertools.combinations(labels, 2):
        assert not overlap(a, b), (a, b)
    for a in labels:
        assert a["x"] >= 0 and a["x"] + a["w"] <= view.width and a["y"] >= 0
        assert a["y"] + a["h"] <= view.height and not overlap(a, {**bar, "w": bar["w"]})
    robots = [r for a in labels if a["kind"] == "robot" for r in a["robots"]]
    assert sorted(robots) == sorted(r["id"] for r in data["robots"])  # each named once
    assert 2 <= sum(a["kind"] == "robot" for a in labels) < 12  # parked robots share a label
    assert {a["station"] for a in labels if a["kind"] == "station"} == {
        s["name"] for s in data["floor"]["stations"]
    }


def test_labels_never_overlap_however_crowded_the_floor(chromium, crowded, tmp_path):
    # 40 robots scattered over a 12 x 8 m corner: most labels cannot go where they would like.
    data = page_data(crowded)
    rng = np.random.default_rng(3)
    robots = []
    for i in range(40):
        x, y = rng.uniform([1.0, 1.0], [13.0, 9.0])
        robots.append({**data["robots"][0], "id": f"x{i:02d}", "colour": robot_colour(i),
                       "t": [0.0], "x": [round(x, 3)], "y": [round(y, 3)]})  # fmt: skip
    data["robots"] = robots
    page = tmp_path / "scattered.html"
    page.write_text(replay_html(data), encoding="utf-8")
    work = tmp_path / "shot"
    dom, _ = finish(screenshot(probed(page, "probe.html"), 0.0, work, WINDOWS[0]), work)
    report = probe(dom)
    view, _ = page_view(report)
    labels = [a for a in report["labels"] if a["kind"] == "robot"]
    assert len(labels) >= 5
    for a, b in itertools.combinations(report["labels"], 2):
        assert not overlap(a, b), (a, b)
    assert all(a["x"] >= 0 and a["x"] + a["w"] <= view.width for a in labels)
    named = [r for a in labels for r in a["robots"]]
    assert len(named) == len(set(named))  # no robot is named twice


def test_the_browser_draws_each_robot_where_the_trajectory_says(chromium, run_dir, tmp_path):
    page = write_replay(run_dir)
    data = page_data(page)
    tracks = load_tracks(run_dir / "trajectories.csv")
    robots = [r["id"] for r in data["robots"]]
    colours = {r["id"]: rgb(r["colour"]) for r in data["robots"]}
    times = pick_times(tracks, robots)

    # The first page seeks by its URL's hash at load; the second opens at the first time and is
    # then sent to the second by `window.replaySeek`, as a script would.
    seeking = f"<script>window.replaySeek({times[1]!r});</script>\n"
    procs = [
        screenshot(probed(page, "at.html"), times[0], tmp_path / "at0", WINDOWS[0]),
        screenshot(probed(page, "seeking.html", seeking), times[0], tmp_path / "at1", WINDOWS[0]),
    ]
    shots, doms, views = [], [], []
    for i, proc in enumerate(procs):
        dom, shot = finish(proc, tmp_path / f"at{i}")
        shots.append(imread(shot)[..., :3])
        doms.append(dom)
        views.append(page_view(probe(dom)))
    assert views[0] == views[1]  # one window size, one map
    view, (left, top) = views[0]

    def where(robot: str, t: float) -> np.ndarray:
        return np.array(view.pixel(*position(tracks[robot], t))) + (left, top)

    def pixel(image: np.ndarray, robot: str, t: float) -> np.ndarray:
        x, y = where(robot, t)
        return image[int(y), int(x)]

    for image, dom, t, other in zip(shots, doms, times, times[::-1], strict=True):
        assert f"t = {t:.2f} s" in dom  # the page seeked to the hash's time
        for robot in robots:
            here = pixel(image, robot, t)
            assert np.abs(here - colours[robot]).max() < 0.06, (robot, t, here)
            # Where the robot is at the other time, no robot is drawn now.
            there = pixel(image, robot, other)
            assert all(np.abs(there - c).max() > 0.1 for c in colours.values()), (robot, t)
    for robot in robots:  # the robot's disk moved with the slider
        a, b = where(robot, times[0]), where(robot, times[1])
        assert np.hypot(*(a - b)) > 3 * data["robots"][0]["radius"] * view.scale


def test_play_runs_the_clock_at_the_chosen_speed(chromium, run_dir, tmp_path):
    page = write_replay(run_dir)
    playing = page.with_name("playing.html")
    script = (
        '<script>document.getElementById("speed").value = "10";'
        'document.getElementById("play").click();</script>\n</body>'
    )
    playing.write_text(page.read_text(encoding="utf-8").replace("</body>", script))
    dom, _ = finish(screenshot(playing, 10.0, tmp_path / "play", WINDOWS[0]), tmp_path / "play")
    shown = re.search(r'<span id="time">t = ([0-9.]+) s', dom)
    assert shown, "the page shows the time"
    # Chromium's virtual time budget is 3 s: at 10x the clock runs on by about 30 s.
    assert 30.0 < float(shown.group(1)) < 50.0
    assert re.search(r'<button id="play"[^>]*>Pause<', dom)
