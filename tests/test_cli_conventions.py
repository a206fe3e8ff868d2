"""The command line's habits, as a user meets them: --version, --json, --set, fresh run
directories, Ctrl-C that saves what ran, plain output off a terminal, and `fleet keys` that keeps
secrets out of the repository."""

import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fleet import __version__
from fleet.cli import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, main
from fleet.scenario import REPO_ROOT

THROUGHPUT = REPO_ROOT / "scenarios" / "throughput.toml"
#: One robot for two simulated minutes of the throughput scenario: well under a second.
SMALL = [str(THROUGHPUT), "--robots", "1", "--duration", "120", "--no-figures"]


def fleet_exe() -> str:
    exe = shutil.which("fleet", path=str(Path(sys.executable).parent))
    assert exe, "the console script `fleet` is installed next to the interpreter"
    return exe


def plain_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("FORCE_COLOR", "COLUMNS")}
    return env | extra


def sigint_default() -> None:
    """In a child, before it runs: Ctrl-C's default. A test suite started as a shell's
    background job has SIGINT ignored, its children inherit that, and a Python started that way
    keeps ignoring it, so the signal these tests send would be lost."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture(autouse=True)
def plain_console(monkeypatch):
    for name in ("FORCE_COLOR", "COLUMNS"):
        monkeypatch.delenv(name, raising=False)


def test_version(capsys):
    assert main(["--version"]) == EXIT_OK
    assert capsys.readouterr().out.strip() == f"mambot-fleet {__version__}"


def test_help_documents_the_exit_status(capsys):
    assert main(["run", "--help"]) == EXIT_OK
    text = " ".join(capsys.readouterr().out.split())
    assert "exit status: 0 done; 1 bad input or a failed run; 2 usage" in text
    assert "130 interrupted" in text


# -- --json ----------------------------------------------------------------------------------------
def test_run_json_is_all_that_reaches_stdout(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.run(
        [fleet_exe(), "run", *SMALL, "--out", str(out), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
        env=plain_env(),
    )
    assert proc.returncode == EXIT_OK, proc.stderr
    data = json.loads(proc.stdout)  # nothing but the JSON
    assert data["run_dir"] == str(out) and data["complete"] is True
    assert data["summary"] == json.loads((out / "summary.json").read_text())
    assert data["summary"]["robots"] == 1 and data["summary"]["sim_time_s"] == 120.0
    assert "Key figures" not in proc.stdout + proc.stderr
    assert "throughput: 1 robots on" in proc.stderr  # the human line went to stderr


def test_sweep_and_report_json(tmp_path, capsys):
    study = tmp_path / "tiny.toml"
    study.write_text(
        f'[study]\nscenario = "{THROUGHPUT.as_posix()}"\nseeds = 1\nduration_s = 60\n\n'
        '[grid]\nrobots = [1]\ncontroller = ["qsp_speed", "print_first"]\n'
    )
    out = tmp_path / "study"
    assert main(["sweep", str(study), "--out", str(out), "-j", "1", "--json"]) == EXIT_OK
    captured = capsys.readouterr()
    swept = json.loads(captured.out)
    assert (swept["cells"], swept["ok"], swept["failed"], swept["complete"]) == (2, 2, 0, True)
    assert [r["params"]["controller"] for r in swept["records"]] == ["qsp_speed", "print_first"]
    assert swept["results"][0] == str(out.resolve() / "results.csv")
    assert json.loads((out / "study.json").read_text())["complete"] is True

    assert main(["report", str(out), "--json"]) == EXIT_OK
    reported = json.loads(capsys.readouterr().out)
    assert reported["report"] == str(out / "report.md") and (out / "report.md").is_file()
    assert reported["runs"] == 2 and reported["failed"] == 0 and reported["not_run"] == []
    series = {row["series"]: row for row in reported["throughput_good_per_h"]}
    assert set(series) == {"qsp_speed", "print_first"}
    assert all(row["n"] == 1 and row["low"] == row["mean"] for row in series.values())


# -- --set -----------------------------------------------------------------------------------------
def test_set_writes_typed_values_over_the_scenario(tmp_path):
    out = tmp_path / "run"
    argv = [
        "run",
        str(THROUGHPUT),
        "--set",
        "robots.count=2",
        "--set",
        "scenario.duration_s=30",
        "--set",
        "controller.name=fixed_speed",
        "--set",
        "controller.options.speed=0.3",
        "--quiet",
        "--no-figures",
        "--out",
        str(out),
    ]
    assert main(argv) == EXIT_OK
    summary = json.loads((out / "summary.json").read_text())
    assert summary["robots"] == 2 and summary["sim_time_s"] == 30.0
    assert summary["controller"] == "fixed_speed"


def test_a_bad_set_names_the_key_and_the_value(tmp_path, capsys):
    argv = ["run", str(THROUGHPUT), "--set", "robots.count=0", "--out", str(tmp_path / "r")]
    assert main(argv) == EXIT_FAILED
    assert capsys.readouterr().err == (
        "error: --set: robots.count = 0: must be a positive whole number\n"
    )
    argv[3] = "jobs.rate_per_h=fast"
    assert main(argv) == EXIT_FAILED
    assert (
        "--set: jobs.rate_per_h = 'fast': must be of type int or float" in capsys.readouterr().err
    )
    assert not (tmp_path / "r").exists()


# -- a run directory is written fresh --------------------------------------------------------------
def test_a_used_run_directory_is_refused_unless_forced(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", *SMALL[:-1], "--out", str(out), "--quiet"]) == EXIT_OK
    assert (out / "speed.png").is_file()
    before = (out / "summary.json").read_text()

    assert main(["run", *SMALL, "--out", str(out), "--quiet", "--seed", "2"]) == EXIT_FAILED
    err = capsys.readouterr().err
    assert f"--out = '{out}': already holds files" in err and "--force" in err
    assert (out / "summary.json").read_text() == before  # untouched

    # --force clears the earlier run: no figure of it survives a run without figures.
    assert main(["run", *SMALL, "--out", str(out), "--quiet", "--seed", "2", "--force"]) == 0
    assert not (out / "speed.png").exists()
    assert json.loads((out / "summary.json").read_text())["seed"] == 2


def test_the_default_run_directory_is_replaced_by_the_next_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["run", *SMALL[:-1], "--quiet"]) == EXIT_OK
    out = tmp_path / "runs" / "throughput-seed1"
    assert (out / "speed.png").is_file()
    assert main(["run", *SMALL, "--quiet", "--duration", "60"]) == EXIT_OK
    assert not (out / "speed.png").exists()
    assert json.loads((out / "summary.json").read_text())["sim_time_s"] == 60.0


def test_force_never_empties_a_folder_that_is_not_a_run(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("mine")
    argv = ["run", *SMALL, "--out", str(tmp_path), "--quiet", "--force"]
    assert main(argv) == EXIT_FAILED
    assert "holds files no run writes (notes.txt)" in capsys.readouterr().err
    assert (tmp_path / "notes.txt").read_text() == "mine"


# -- Ctrl-C ----------------------------------------------------------------------------------------
def test_a_world_asked_to_stop_ends_between_steps_and_says_so():
    from fleet.engine import World
    from fleet.scenario import load_scenario

    scenario = load_scenario(THROUGHPUT).override(robots=2, duration=120)
    whole = World(scenario).run()
    # Asking (and never stopping) leaves the run as it was: the same samples, the same digest.
    asked = World(scenario).run(stop=lambda: False)
    assert asked.summary["digest"] == whole.summary["digest"]
    assert whole.summary["complete"] is True and asked.summary["complete"] is True

    world = World(scenario)
    stopped = world.run(stop=lambda: world.env.now >= 30.0).summary
    assert stopped["complete"] is False and stopped["sim_time_s"] == 30.0
    assert max(world.recorder.trajectories["r01"].t) <= 30.0


def test_ctrl_c_stops_a_run_and_saves_it_marked_incomplete(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [fleet_exe(), "run", "--duration", "3600", "--out", str(out), "--no-figures"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=plain_env(),
        cwd=REPO_ROOT,
        preexec_fn=sigint_default,
    )
    assert proc.stdout is not None
    assert "robots on" in proc.stdout.readline()  # the World is built and running
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == EXIT_INTERRUPTED, stderr
    assert "Traceback" not in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and 0 < summary["sim_time_s"] < 3600
    assert f"error: interrupted at {summary['sim_time_s']:g} s of 3600 s: {out}" in stderr
    assert "Key figures" in stdout  # what ran is still reported
    rows = (out / "trajectories.csv").read_text().splitlines()
    assert float(rows[-1].split(",")[0]) <= summary["sim_time_s"]


def test_ctrl_c_stops_a_sweep_which_resumes_where_it_stopped(tmp_path, capsys):
    study = tmp_path / "six.toml"
    study.write_text(
        f'[study]\nscenario = "{THROUGHPUT.as_posix()}"\nseeds = 6\nduration_s = 900\n\n'
        "[grid]\nrobots = [1]\nrate_per_h = [60]\n"
    )
    out = tmp_path / "study"
    proc = subprocess.Popen(
        [fleet_exe(), "sweep", str(study), "--out", str(out), "-j", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=plain_env(),
        preexec_fn=sigint_default,
    )
    results = out / "results.csv"
    deadline = time.monotonic() + 120
    while not (results.is_file() and len(results.read_text().splitlines()) >= 2):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_INTERRUPTED, stderr
    assert "Traceback" not in stderr
    finished = len(results.read_text().splitlines()) - 1
    assert 1 <= finished < 6
    assert json.loads((out / "study.json").read_text())["complete"] is False
    assert f"interrupted: {finished} of 6 cells have a record" in stderr

    assert main(["sweep", str(study), "--out", str(out), "-j", "2"]) == EXIT_OK
    text = "".join(capsys.readouterr().out.splitlines())
    assert f"6 ok, 0 failed ({finished} of these cells reused from an earlier sweep)" in text
    assert json.loads((out / "study.json").read_text())["complete"] is True


# -- plain output off a terminal -------------------------------------------------------------------
def test_output_off_a_terminal_is_plain_and_unwrapped(tmp_path):
    deep = tmp_path / ("a_rather_long_folder_name_" * 4) / "run"
    proc = subprocess.run(
        [fleet_exe(), "run", *SMALL, "--out", str(deep)],
        capture_output=True,
        text=True,
        timeout=120,
        env=plain_env(COLUMNS="80"),  # what a CI log or a pipe reports
    )
    assert proc.returncode == EXIT_OK, proc.stderr
    assert "\x1b[" not in proc.stdout + proc.stderr  # no colour, no cursor moves
    assert "simulating" not in proc.stdout + proc.stderr  # no progress bar
    assert f"run directory: {deep}\n" in proc.stdout  # one line, however long
    assert (
        "throughput: 1 robots on Shop floor (100 regions), qsp_speed + greedy, 120 s"
        in (proc.stdout.splitlines()[0])
    )


# -- keys ------------------------------------------------------------------------------------------
def test_keys_go_to_the_user_config_folder_owner_only(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(REPO_ROOT)  # where a user types it: no folder given, nothing lands here
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    assert main(["keys", "--name", "engine"]) == EXIT_OK
    home = tmp_path / "config" / "mambot-fleet" / "keys"
    assert f"secret key: {home / 'engine.key_secret'}" in capsys.readouterr().out
    assert stat.S_IMODE(home.stat().st_mode) == 0o700
    assert stat.S_IMODE((home / "engine.key_secret").stat().st_mode) == 0o600
    assert (home / "engine.key").is_file()
    assert not (REPO_ROOT / "engine.key_secret").exists()


def test_keys_refuse_a_git_work_tree_unless_forced(tmp_path, capsys):
    (tmp_path / ".git").mkdir()
    inside = tmp_path / "keys"
    assert main(["keys", str(inside)]) == EXIT_FAILED
    err = capsys.readouterr().err
    assert f"DIRECTORY = '{inside}': lies in the git work tree {tmp_path}" in err
    assert not inside.exists()
    assert main(["keys", str(inside), "--force"]) == EXIT_OK
    assert stat.S_IMODE((inside / "fleet.key_secret").stat().st_mode) == 0o600


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
@pytest.mark.parametrize(
    "path", ["keys/engine.key_secret", "keys/engine.key", "a/agent.key_secret"]
)
def test_key_files_in_the_repository_are_git_ignored(path):
    if not (REPO_ROOT / ".git").exists():
        pytest.skip("not a git work tree")
    proc = subprocess.run(["git", "check-ignore", "-q", path], cwd=REPO_ROOT)
    assert proc.returncode == 0, f"{path} is not ignored by .gitignore"


def test_controller_options_set_with_another_controller_reach_it(tmp_path, capsys):
    """``--controller X --set controller.options.*`` configures X (they were once dropped, and
    fixed_speed, which needs its speed, was refused without it)."""
    argv = ["run", str(THROUGHPUT), "--controller", "fixed_speed", "--quiet", "--no-figures"]
    argv += ["--set", "scenario.duration_s=30", "--set", "controller.options.speed=-1"]
    assert main([*argv, "--out", str(tmp_path / "bad")]) == EXIT_FAILED
    assert "option speed = -1: must be a positive number" in capsys.readouterr().err
    argv[-1] = "controller.options.speed=0.2"
    assert main([*argv, "--out", str(tmp_path / "run")]) == EXIT_OK
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["controller"] == "fixed_speed"
