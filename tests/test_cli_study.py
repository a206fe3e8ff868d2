"""The study and picture commands as a user runs them: `fleet sweep`, `report`, `plot`, `replay`
and `plugins`, through `fleet.cli.main` in-process and as the installed console script, on small
real runs of the shipped throughput scenario (printed parts, one robot, a minute or two)."""

import csv
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fleet.cli import main
from fleet.scenario import REPO_ROOT

SCENARIO = REPO_ROOT / "scenarios" / "throughput.toml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

#: Two strategies, one robot, two seeds: four cells of 90 simulated seconds. Jobs come often
#: enough that each seed releases some (the seed only draws arrivals: without jobs, seeds agree).
TINY_GRID = """robots = [1]
rate_per_h = [120]
controller = [
    "qsp_speed",
    { label = "fixed 0.4 m/s", name = "fixed_speed", options = { speed = 0.4 } },
]
"""

#: An MPC horizon shorter than braking suits no robot: the second cell fails building its World.
FAILING_GRID = """robots = [1]
controller = ["follower", { label = "short horizon", name = "mpc", options = { horizon = 3 } }]
"""


def write_study(
    folder: Path, grid: str, *, name: str = "tiny", seeds: str = "[1, 2]", duration: int = 90
) -> Path:
    """A study of the shipped throughput scenario with `grid` as its [grid] table."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.toml"
    path.write_text(
        f'[study]\nname = "{name}"\nscenario = "{SCENARIO.as_posix()}"\nseeds = {seeds}\n'
        f"duration_s = {duration}\n\n[grid]\n{grid}",
        encoding="utf-8",
    )
    return path


def unwrap(text: str) -> str:
    """Printed text as one line.

    Off a terminal the CLI no longer wraps (tests/test_cli_conventions.py checks that); joining
    the lines lets these tests read several printed lines as one sentence.
    """
    return "".join(text.splitlines())


def read_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def written(out: str) -> list[Path]:
    """The paths of the ``wrote PATH`` lines of `fleet report` and `fleet plot`, in order."""
    return [Path(p.strip()) for p in re.findall(r"wrote (.+?)(?=wrote |$)", unwrap(out))]


def is_png(path: Path) -> bool:
    return path.is_file() and path.read_bytes()[:8] == PNG_MAGIC and path.stat().st_size > 1000


def exit_status(argv: list[str]) -> int | str | None:
    """`main`'s status, also when argparse refuses the arguments by raising SystemExit."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


def plain_env() -> dict[str, str]:
    """This environment without settings that would make rich colour or widen its output."""
    return {k: v for k, v in os.environ.items() if k not in ("FORCE_COLOR", "COLUMNS")}


@pytest.fixture(autouse=True)
def plain_console(monkeypatch):
    for name in ("FORCE_COLOR", "COLUMNS"):
        monkeypatch.delenv(name, raising=False)


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """The tiny study swept once by the installed console script, as a user would."""
    exe = shutil.which("fleet", path=str(Path(sys.executable).parent))
    assert exe, "the console script `fleet` is installed next to the interpreter"
    folder = tmp_path_factory.mktemp("swept")
    study = write_study(folder, TINY_GRID)
    out = folder / "out"
    proc = subprocess.run(
        [exe, "sweep", str(study), "--out", str(out), "--jobs", "2"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=folder,
        env=plain_env(),
    )
    return study, out, proc


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A run directory from `fleet run ... --no-figures`: the files, no pictures yet."""
    out = tmp_path_factory.mktemp("run") / "R"
    status = main(
        [
            "run",
            str(SCENARIO),
            "--robots",
            "1",
            "--duration",
            "60",
            "--out",
            str(out),
            "--quiet",
            "--no-figures",
        ]
    )
    assert status == 0
    return out


# -- fleet sweep ----------------------------------------------------------------------------------
def test_sweep_runs_every_cell_and_says_where_the_results_are(swept):
    study, out, proc = swept
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    text = unwrap(proc.stdout)
    assert f"tiny: 4 cells (2 seeds) on local processes into {out}" in text
    results = out.resolve() / "results.csv"
    assert "4 ok, 0 failed (0 of these cells reused from an earlier sweep)" in text
    assert f"results: {results}" in text
    assert f"next: fleet report {out}" in text
    assert "failed:" not in text

    rows = read_rows(results)
    assert [(r["controller"], r["seed"], r["status"]) for r in rows] == [
        ("qsp_speed", "1", "ok"),
        ("qsp_speed", "2", "ok"),
        ("fixed 0.4 m/s", "1", "ok"),
        ("fixed 0.4 m/s", "2", "ok"),
    ]
    for row in rows:
        summary = json.loads((out / row["run_dir"] / "summary.json").read_text())
        assert summary["sim_time_s"] == 90.0 and summary["robots"] == 1
        assert summary["digest"] == row["digest"]
    # Two seeds of one strategy are two different runs.
    assert rows[0]["digest"] != rows[1]["digest"]


def test_sweeping_again_reuses_every_cell_and_says_so(swept, capsys):
    study, out, proc = swept
    assert proc.returncode == 0, proc.stderr
    cells = sorted((out / "cells").iterdir())
    before = {c.name: (c / "summary.json").stat().st_mtime_ns for c in cells}
    rows = read_rows(out / "results.csv")

    assert main(["sweep", str(study), "--out", str(out)]) == 0
    text = unwrap(capsys.readouterr().out)
    assert "4 ok, 0 failed (4 of these cells reused from an earlier sweep)" in text
    assert {c.name: (c / "summary.json").stat().st_mtime_ns for c in cells} == before
    assert read_rows(out / "results.csv") == rows


def test_a_quiet_sweep_prints_nothing_when_every_cell_is_ok(swept, capsys):
    study, out, proc = swept
    assert proc.returncode == 0, proc.stderr
    assert main(["sweep", str(study), "--out", str(out), "--quiet"]) == 0
    assert capsys.readouterr() == ("", "")


def test_a_failing_cell_exits_1_prints_its_error_and_the_others_run(tmp_path, capsys):
    study = write_study(tmp_path, FAILING_GRID, name="failing", seeds="[1]", duration=60)
    out = tmp_path / "out"
    assert main(["sweep", str(study), "--out", str(out), "-j", "2"]) == 1
    rows = read_rows(out / "results.csv")
    assert [(r["controller"], r["status"]) for r in rows] == [
        ("follower", "ok"),
        ("short horizon", "failed"),
    ]
    bad = rows[1]["cell"]
    captured = capsys.readouterr()
    text, errors = unwrap(captured.out), unwrap(captured.err)
    assert (
        f"cell {bad} (robots=1, controller=short horizon, seed 1) failed: PluginError: " in errors
    )
    assert "horizon 3" in errors and "shorter than braking" in errors
    assert "1 ok, 1 failed (0 of these cells reused from an earlier sweep)" in text

    # --keep-failed: the failure stays as recorded, nothing runs again, the exit is still 1.
    error_txt = out / rows[1]["run_dir"] / "error.txt"
    stamp = error_txt.stat().st_mtime_ns
    record = (out / rows[1]["run_dir"] / "cell.json").read_text()
    assert main(["sweep", str(study), "--out", str(out), "--keep-failed"]) == 1
    captured = capsys.readouterr()
    text, errors = unwrap(captured.out), unwrap(captured.err)
    assert "1 ok, 1 failed (2 of these cells reused from an earlier sweep)" in text
    kept = (
        f"cell {bad} (robots=1, controller=short horizon, seed 1) failed "
        "(kept from an earlier sweep)"
    )
    assert kept in errors
    assert "PluginError" in errors
    assert error_txt.stat().st_mtime_ns == stamp
    assert (out / rows[1]["run_dir"] / "cell.json").read_text() == record
    assert read_rows(out / "results.csv") == rows

    # The report of a study with a failure lists it and still draws the ok runs.
    assert main(["report", str(out)]) == 0
    report = (out / "report.md").read_text()
    failed_section = report.split("## Failed runs", 1)[1].split("##", 1)[0]
    assert bad in failed_section and "PluginError" in failed_section
    assert rows[0]["cell"] not in failed_section


@pytest.mark.parametrize(
    ("grid", "study_line", "where", "rule"),
    [
        ("robots = [2, 0]\n", "", "grid.robots[1] = 0", "must be a positive whole number"),
        (
            'controller = ["qsp_speed", "qsp_sped"]\n',
            "",
            "grid.controller[1] = 'qsp_sped'",
            "no controller plugin named 'qsp_sped'",
        ),
        ("robots = [1]\n", "seed = 3\n", "study.seed = 3", "unknown key"),
    ],
)
def test_a_bad_study_file_exits_1_naming_the_file_the_field_and_the_value(
    tmp_path, capsys, grid, study_line, where, rule
):
    study = write_study(tmp_path, grid)
    if study_line:
        study.write_text(study.read_text().replace("[study]\n", "[study]\n" + study_line))
    out = tmp_path / "out"
    assert main(["sweep", str(study), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert f"error: {study}: {where}: " in captured.err and rule in captured.err
    assert "Traceback" not in captured.err
    assert not out.exists()  # refused before anything ran


def test_a_missing_study_file_exits_1_naming_it(tmp_path, capsys):
    missing = tmp_path / "nope.toml"
    assert main(["sweep", str(missing)]) == 1
    err = capsys.readouterr().err
    assert f"{missing}: (file) = '{missing}': no such study file" in err


# -- fleet report ---------------------------------------------------------------------------------
def test_report_writes_the_markdown_and_figures_and_lists_them(swept, tmp_path, capsys):
    study, out, proc = swept
    assert proc.returncode == 0, proc.stderr
    names = ["report.md", "throughput.png", "lead_time.png", "defects.png"]

    elsewhere = tmp_path / "report"
    assert main(["report", str(out), "--out", str(elsewhere)]) == 0
    assert written(capsys.readouterr().out) == [elsewhere / n for n in names]
    assert all(is_png(elsewhere / n) for n in names[1:])
    report = (elsewhere / "report.md").read_text()
    assert report.startswith("# Study report: tiny")
    assert "qsp_speed" in report and "fixed 0.4 m/s" in report
    assert "4 ok, 0 failed" in report
    assert not (out / "report.md").exists()  # --out was honoured

    assert main(["report", str(out)]) == 0
    assert written(capsys.readouterr().out) == [out / n for n in names]
    assert (out / "report.md").read_text() == report


#: Two strategies, one robot, five seeds of plain deliveries (no prints), ten cells of five
#: simulated minutes: each seed's arrivals give both strategies the same jobs (common random
#: numbers) and the faster one delivers more of them.
PAIR_GRID = """robots = [1]
rate_per_h = [60]
"jobs.parts" = [[]]
controller = [
    "qsp_speed",
    { label = "fixed 0.2 m/s", name = "fixed_speed", options = { speed = 0.2 } },
]
"""


@pytest.fixture(scope="module")
def paired(tmp_path_factory):
    """A 2-arm, 5-seed study of real runs, swept in-process on two workers."""
    folder = tmp_path_factory.mktemp("paired")
    study = write_study(folder, PAIR_GRID, name="pair", seeds="5", duration=300)
    out = folder / "out"
    assert main(["sweep", str(study), "--out", str(out), "-j", "2", "--quiet"]) == 0
    return out


def test_report_of_a_two_arm_five_seed_study_prints_paired_intervals(paired, capsys):
    from scipy import stats as scipy_stats

    rows = read_rows(paired / "results.csv")
    good = {(r["controller"], int(r["seed"])): float(r["throughput_good_per_h"]) for r in rows}
    arms = {c: [good[(c, s)] for s in range(1, 6)] for c in ("qsp_speed", "fixed 0.2 m/s")}
    (lead, va), (other, vb) = sorted(arms.items(), key=lambda kv: -sum(kv[1]))
    assert va != vb  # the strategies differ on these runs
    ci = scipy_stats.ttest_rel(va, vb).confidence_interval(0.95)
    interval = f"{(ci.low + ci.high) / 2:+.2f} ± {(ci.high - ci.low) / 2:.2f}"
    method = "95 % CI, paired t on 5 common seeds, df 4"

    assert main(["report", str(paired)]) == 0
    text = unwrap(capsys.readouterr().out)
    separated = "separated" if ci.low > 0 else "not separated"
    line = f"robots=1, rate_per_h=60: {lead} − {other} = {interval} good parts/h ({method}), "
    assert line + separated in text
    assert "wider than 5 % of the mean" in text
    report = (paired / "report.md").read_text()
    assert f"| 60 | {lead} − {other} | {interval} |" in report and method in report
    # The engine gives common random numbers: each seed releases the same jobs in both arms.
    assert "the released jobs (id, part, release time) are the same in all 5 pairs" in report

    assert main(["report", str(paired), "--json", "--half-width", "100%"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["method"] == f"{method} (1 difference)"
    (diff,) = data["differences"]
    assert (diff["leader"], diff["series"], diff["method"], diff["df"]) == (
        lead, other, "paired t", 4
    )  # fmt: skip
    assert (diff["low"], diff["high"]) == pytest.approx((ci.low, ci.high), rel=1e-9)
    assert data["half_width_target"] == "100 % of the mean"


def test_report_refuses_a_bad_half_width_naming_it(paired, capsys):
    assert main(["report", str(paired), "--half-width", "tight"]) == 1
    err = capsys.readouterr().err
    assert "--half-width" in err and "'tight'" in err and "share of the mean (5%)" in err


@pytest.mark.parametrize("kind", ["empty", "missing"])
def test_report_on_a_directory_without_a_study_exits_1_naming_it(tmp_path, capsys, kind):
    folder = tmp_path / kind
    if kind == "empty":
        folder.mkdir()
    assert main(["report", str(folder)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert f"error: {folder / 'results.csv'}: (file) = 'missing': " in captured.err
    assert "`fleet sweep`" in captured.err and "Traceback" not in captured.err
    assert not (folder / "report.md").exists()


# -- fleet plot and fleet replay ------------------------------------------------------------------
def test_plot_draws_trajectory_speed_and_gantt_of_a_run(run_dir, capsys):
    names = ("trajectory.png", "speed.png", "gantt.png", "states.png", "wip.png")
    pictures = [run_dir / n for n in names]
    assert not any(p.exists() for p in pictures)  # --no-figures left them to `fleet plot`
    assert main(["plot", str(run_dir)]) == 0
    assert written(capsys.readouterr().out) == pictures
    assert all(is_png(p) for p in pictures)


def test_a_sweep_cell_is_a_run_directory_plot_and_replay_read(swept, capsys):
    study, out, proc = swept
    assert proc.returncode == 0, proc.stderr
    cell = out / read_rows(out / "results.csv")[0]["run_dir"]
    assert main(["plot", str(cell)]) == 0
    assert [p.name for p in written(capsys.readouterr().out)] == [
        "trajectory.png",
        "speed.png",
        "gantt.png",
        "states.png",
        "wip.png",
    ]
    assert main(["replay", str(cell)]) == 0
    assert (cell / "replay.html").is_file()


def test_replay_writes_one_page_into_the_run_dir_or_where_asked(run_dir, tmp_path, capsys):
    assert main(["replay", str(run_dir)]) == 0
    page = run_dir / "replay.html"
    assert f"wrote {page} (open it in a browser" in unwrap(capsys.readouterr().out)
    html = page.read_text()
    assert html.lstrip().lower().startswith("<!doctype html")

    there = tmp_path / "pages" / "run.html"  # folders made as needed
    assert main(["replay", str(run_dir), "--out", str(there)]) == 0
    assert f"wrote {there} " in unwrap(capsys.readouterr().out)
    assert there.read_text() == html


@pytest.mark.parametrize("command", ["plot", "replay"])
def test_plot_and_replay_of_a_missing_run_dir_exit_1_naming_it(tmp_path, capsys, command):
    missing = tmp_path / "no_such_run"
    assert main([command, str(missing)]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and "Traceback" not in captured.err
    assert f"error: {missing / 'trajectories.csv'}: (file) = 'missing': " in captured.err
    assert "`fleet run`" in captured.err
    assert not missing.exists()


# -- fleet plugins --------------------------------------------------------------------------------
def test_plugins_lists_the_print_strategies_as_working_controllers(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    for name in ("follower", "fixed_speed", "qsp_speed", "print_first", "mpc"):
        assert re.search(rf"│ controller +│ {name} +│.*│ ok +│", out), name
    assert re.search(r"│ dispatcher +│ greedy +│.*│ ok +│", out)


# -- user mistakes get a message, not a traceback -------------------------------------------------
@pytest.mark.parametrize("option", ["--jobs", "--workers"])
def test_jobs_below_one_is_a_usage_error(tmp_path, capsys, option):
    study = write_study(tmp_path, TINY_GRID)
    argv = ["sweep", str(study), "--out", str(tmp_path / "out"), option, "0"]
    assert exit_status(argv) == 2
    assert f"{option}: '0': must be a whole number >= 1" in capsys.readouterr().err


def test_sweep_workers_is_the_old_name_of_jobs_and_warns(swept, capsys):
    # --workers means agent processes on `fleet run`; on `fleet sweep` it is now --jobs.
    study, out, proc = swept
    assert proc.returncode == 0, proc.stderr
    assert main(["sweep", str(study), "--out", str(out), "--workers", "2"]) == 0
    captured = capsys.readouterr()
    assert "fleet sweep --workers is now --jobs (-j)" in unwrap(captured.err)
    assert "4 ok, 0 failed (4 of these cells reused" in unwrap(captured.out)


def test_replay_out_naming_a_directory_writes_the_page_into_it(run_dir, tmp_path, capsys):
    assert main(["replay", str(run_dir), "--out", str(tmp_path)]) == 0
    assert (tmp_path / "replay.html").is_file()
    assert str(tmp_path / "replay.html") in capsys.readouterr().out


def test_report_out_naming_a_file_is_refused_with_a_message(swept, tmp_path, capsys):
    study, out, proc = swept
    assert proc.returncode == 0, proc.stderr
    taken = tmp_path / "taken"
    taken.write_text("")
    assert main(["report", str(out), "--out", str(taken)]) == 1
    assert str(taken) in capsys.readouterr().err


def test_sweep_out_naming_a_file_is_refused_with_a_message(tmp_path, capsys):
    study = write_study(tmp_path, TINY_GRID)
    taken = tmp_path / "taken"
    taken.write_text("")
    assert main(["sweep", str(study), "--out", str(taken)]) == 1
    assert str(taken) in capsys.readouterr().err


def test_a_long_path_is_printed_on_one_line(run_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("COLUMNS", "80")  # a pipe or a CI log
    page = tmp_path / ("long_folder_name_" * 5) / "replay.html"
    assert main(["replay", str(run_dir), "--out", str(page)]) == 0
    assert any(line.startswith(f"wrote {page}") for line in capsys.readouterr().out.splitlines())
