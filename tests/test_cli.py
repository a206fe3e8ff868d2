"""The `fleet` command line, as a user calls it."""

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fleet.cli import main
from fleet.scenario import REPO_ROOT

from .test_engine import MAP

SUMMARY_KEYS = {
    "scenario",
    "map",
    "seed",
    "controller",
    "dispatcher",
    "robots",
    "sim_time_s",
    "wall_time_s",
    "jobs",
    "throughput_per_h",
    "throughput_good_per_h",
    "quality",
    "mean_lead_time_s",
    "distance_m",
    "violations",
    "per_robot",
    "digest",
}


@pytest.fixture
def scenario(tmp_path: Path) -> Path:
    (tmp_path / "hall.toml").write_text(MAP)
    path = tmp_path / "smoke.toml"
    path.write_text(
        '[scenario]\nmap = "hall.toml"\nduration_s = 90\n[robots]\ncount = 2\n'
        "[jobs]\nrate_per_h = 200\n"
    )
    return path


def test_run_writes_the_run_directory(scenario, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(scenario), "--out", str(out), "--seed", "5", "--robots", "3"]) == 0
    printed = capsys.readouterr().out
    assert "Key figures" in printed and "throughput" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary) >= SUMMARY_KEYS
    assert summary["seed"] == 5 and summary["robots"] == 3
    assert set(summary["jobs"]) >= {"released", "completed", "good", "defective", "late"}
    assert set(summary["violations"]) == {"obstacle", "speed_zone", "print_speed", "collision"}
    assert [p["id"] for p in summary["per_robot"]] == ["r01", "r02", "r03"]
    with open(out / "trajectories.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["t", "robot", "x", "y", "vx", "vy", "region", "v_zone"]
    assert len(rows) == 3 * 90 * 4  # 3 robots, 90 s at 4 ticks per second
    assert all(int(r["region"]) >= 0 for r in rows)
    events = (out / "events.csv").read_text().splitlines()
    assert events[0] == "t,event,job,robot,station"
    with open(out / "jobs.csv") as fh:
        jobs = list(csv.DictReader(fh))
    assert len(jobs) == summary["jobs"]["released"]
    assert list(jobs[0])[:9] == [
        "id",
        "part",
        "robot",
        "released_s",
        "started_s",
        "finished_s",
        "delivered_s",
        "predicted_error_mm",
        "passed",
    ]
    # Plain deliveries: nothing printed, nothing judged, every delivered job counts as good.
    delivered = [j for j in jobs if j["delivered_s"]]
    assert len(delivered) == summary["jobs"]["completed"] == summary["jobs"]["good"]
    assert all(j["part"] == "" and j["passed"] == "" for j in jobs)


def test_bad_scenario_exits_1_with_the_message(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[scenario]\nmap = "nowhere.toml"\n')
    assert main(["run", str(bad)]) == 1
    assert "scenario.map = 'nowhere.toml'" in capsys.readouterr().err


def test_bad_map_message_is_printed_whole(tmp_path, capsys):
    bad = tmp_path / "bad_map.toml"
    bad.write_text('[floor]\nname = "x"\nrect = [0, 0, 9, 9]\ndefault_v_max = 1.0\ncolour = 1\n')
    assert main(["map", str(bad)]) == 1
    err = capsys.readouterr().err
    # Square brackets in the message survive the terminal markup, on one line.
    assert f"{bad}: floor.colour = 1: unknown key in [floor]; allowed keys:" in err


def test_plugins_lists_the_built_ins(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    assert "follower" in out and "greedy" in out and "mambot-fleet" in out


def test_map_describes_a_shipped_map(capsys):
    assert main(["map", str(REPO_ROOT / "maps" / "shop_floor.toml")]) == 0
    assert "convex regions" in capsys.readouterr().out


def test_console_script_smoke(scenario, tmp_path):
    exe = shutil.which("fleet", path=str(Path(sys.executable).parent))
    assert exe, "the console script `fleet` is installed next to the interpreter"
    out = tmp_path / "cli_run"
    proc = subprocess.run(
        [exe, "run", str(scenario), "--out", str(out), "--quiet", "--duration", "20"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads((out / "summary.json").read_text())["sim_time_s"] == 20.0
