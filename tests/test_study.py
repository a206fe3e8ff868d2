"""Parameter sweeps end to end: real runs on a process pool and on Dask, resume, failed cells,
and a clear error for each bad study file."""

import csv
import json
import multiprocessing
import os
import shutil
import signal
import socket
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from fleet.engine import World
from fleet.errors import FleetError
from fleet.scenario import REPO_ROOT, load_scenario
from fleet.study.sweep import (
    KPI_COLUMNS,
    CellStatus,
    StudyError,
    dask_executor,
    load_study,
    run_study,
)

MAP = """
[floor]
name = "test hall"
boundary = [[0, 0], [30, 0], [30, 16], [0, 16]]
default_v_max = 1.0
clearance = 0.4

[[obstacles]]
name = "press"
polygon = [[10, 4], [16, 4], [16, 9], [13, 12], [10, 9]]

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

#: Deliveries only (no G-code to analyse) and a busy hour's rate, so a minute has jobs.
BASE = """
[scenario]
map = "hall.toml"
duration_s = 600
seed = 9
[robots]
count = 3
[jobs]
rate_per_h = 360
stations = ["east", "north"]
"""


def write_study(folder: Path, body: str, name: str = "study.toml") -> Path:
    """A study over ``base.toml`` (written next to it with its map) in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "hall.toml").write_text(MAP)
    if not (folder / "base.toml").exists():
        (folder / "base.toml").write_text(BASE)
    path = folder / name
    path.write_text(body)
    return path


TINY = '[study]\nscenario = "base.toml"\nseeds = [1, 2]\nduration_s = 60\n[grid]\nrobots = [1, 2]\n'


def read_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny sweep (2 grid points x 2 seeds) run once on a pool of 2 processes."""
    folder = tmp_path_factory.mktemp("tiny")
    study = load_study(write_study(folder, TINY))
    calls = []
    result = run_study(
        study, folder / "out", workers=2, progress=lambda r, d, t: calls.append((r, d, t))
    )
    return study, result, calls


def test_a_tiny_sweep_runs_every_cell_on_processes(tiny):
    study, result, calls = tiny
    assert (result.ok, result.failed, result.skipped) == (4, 0, 0)
    assert [(r["params"]["robots"], r["seed"]) for r in result.records] == [
        ("1", 1),
        ("1", 2),
        ("2", 1),
        ("2", 2),
    ]
    assert all(r["status"] == CellStatus.OK and r["error"] is None for r in result.records)
    assert sorted(d for _, d, _ in calls) == [1, 2, 3, 4] and {t for *_, t in calls} == {4}

    rows = read_rows(result.results_path)
    with open(result.results_path, encoding="utf-8") as fh:
        assert tuple(next(csv.reader(fh))) == study.columns
    assert [(row["index"], row["robots"], row["seed"]) for row in rows] == [
        ("0", "1", "1"),
        ("1", "1", "2"),
        ("2", "2", "1"),
        ("3", "2", "2"),
    ]
    for row in rows:
        assert row["status"] == "ok" and row["error"] == ""
        # Empty only where the summary says null: no job delivered yet, no solver in use, no
        # [battery] table.
        battery = {"charging_share", "min_charge_share", "stranded"}
        maybe = {"mean_lead_time_s", "solver_median_ms", *battery}
        assert all(row[name] != "" for name, _ in KPI_COLUMNS if name not in maybe)
        assert row["solver_median_ms"] == "" and row["charging_share"] == ""
        assert len(row["digest"]) == 64
        summary = json.loads((result.out_dir / row["run_dir"] / "summary.json").read_text())
        assert summary["robots"] == int(row["robots"]) and summary["seed"] == int(row["seed"])
        assert summary["sim_time_s"] == 60.0
        assert summary["digest"] == row["digest"]
        assert (result.out_dir / row["run_dir"] / "trajectories.csv").is_file()
    assert sum(int(row["jobs_released"]) for row in rows) > 0

    study_json = json.loads((result.out_dir / "study.json").read_text())
    assert study_json["axes"] == [
        {"name": "robots", "target": "robots.count", "labels": ["1", "2"]}
    ]
    assert list(study_json["cells"]) == [c.id for c in study.cells]


def test_a_cell_gives_the_same_digest_as_running_its_scenario_directly(tiny):
    study, result, _ = tiny
    sc = load_scenario(study.scenario).override(robots=2, seed=2, duration=60)
    direct = World(sc).run().summary["digest"]
    assert result.records[3]["kpis"]["digest"] == direct


def test_resume_runs_only_the_cells_without_a_finished_result(tiny):
    study, result, _ = tiny
    out = result.out_dir

    def mtimes():
        return {
            c.id: (out / "cells" / c.id / "summary.json").stat().st_mtime_ns for c in study.cells
        }

    before = mtimes()
    calls = []
    again = run_study(study, out, workers=2, progress=lambda r, d, t: calls.append(r))
    assert (again.ok, again.failed, again.skipped) == (4, 0, 4)
    assert [r["skipped"] for r in calls] == [True] * 4
    assert mtimes() == before
    assert read_rows(again.results_path) == read_rows(result.results_path)

    gone = study.cells[1].id
    shutil.rmtree(out / "cells" / gone)
    third = run_study(study, out, workers=2)
    assert (third.ok, third.skipped) == (4, 3)
    assert [r["skipped"] for r in third.records] == [True, False, True, True]
    after = mtimes()
    assert after[gone] != before[gone]
    assert {k: v for k, v in after.items() if k != gone} == {
        k: v for k, v in before.items() if k != gone
    }
    assert third.records[1]["kpis"]["digest"] == result.records[1]["kpis"]["digest"]
    assert len(read_rows(third.results_path)) == 4


def test_cell_ids_follow_the_scenario_content(tmp_path):
    study = load_study(write_study(tmp_path, TINY))
    ids = [c.id for c in study.cells]
    assert len(set(ids)) == 4
    assert [c.id for c in load_study(tmp_path / "study.toml").cells] == ids

    # More seeds: the cells already there keep their ids (their results are reused).
    more = load_study(
        write_study(tmp_path, TINY.replace("seeds = [1, 2]", "seeds = [1, 2, 3]"), "more.toml")
    )
    assert {c.id for c in more.cells} > set(ids)

    # A changed base scenario or map file: every cell is a new one.
    (tmp_path / "base.toml").write_text(BASE.replace("count = 3", "count = 3\nradius = 0.35"))
    assert not {c.id for c in load_study(tmp_path / "study.toml").cells} & set(ids)
    (tmp_path / "base.toml").write_text(BASE)
    assert [c.id for c in load_study(tmp_path / "study.toml").cells] == ids
    (tmp_path / "hall.toml").write_text(MAP.replace("[13, 14.5]", "[13, 14.4]"))
    assert not {c.id for c in load_study(tmp_path / "study.toml").cells} & set(ids)


def test_map_values_are_relative_to_the_study_file(tmp_path):
    write_study(tmp_path, "")
    (tmp_path / "maps").mkdir()
    (tmp_path / "maps" / "wide.toml").write_text(
        MAP.replace("[30, 0], [30, 16]", "[32, 0], [32, 16]")
    )
    path = write_study(
        tmp_path / "studies",
        '[study]\nscenario = "../base.toml"\n[grid]\nmap = ["../maps/wide.toml"]\n',
    )
    study = load_study(path)
    assert study.seeds == (1,)
    assert study.cells[0].params == {"map": "../maps/wide.toml"}
    assert study.cells[0].raw["scenario"]["map"] == str((tmp_path / "maps" / "wide.toml").resolve())


def test_a_failing_cell_is_recorded_and_the_others_run(tmp_path):
    path = write_study(
        tmp_path,
        '[study]\nscenario = "base.toml"\nseeds = [1]\nduration_s = 30\n[grid]\n'
        'controller = ["follower", { label = "short horizon", name = "mpc", '
        "options = { horizon = 3 } }]\n",
    )
    study = load_study(path)  # options are the plugin's to judge: only a run finds them bad
    assert [c.params["controller"] for c in study.cells] == ["follower", "short horizon"]
    result = run_study(study, tmp_path / "out", workers=2)
    assert (result.ok, result.failed) == (1, 1)
    good, bad = result.records
    assert good["status"] == "ok" and bad["status"] == "failed"
    assert bad["error"].startswith("PluginError: ") and "horizon 3" in bad["error"]
    assert all(v is None for v in bad["kpis"].values())
    error_txt = result.out_dir / bad["run_dir"] / "error.txt"
    assert "Traceback" in error_txt.read_text() and "PluginError" in error_txt.read_text()
    rows = read_rows(result.results_path)
    assert [(r["controller"], r["status"]) for r in rows] == [
        ("follower", "ok"),
        ("short horizon", "failed"),
    ]
    assert rows[1]["error"] == bad["error"] and rows[1]["digest"] == ""
    assert rows[0]["digest"] != ""

    # Kept as they are on request; retried by default (and failing again).
    stamp = error_txt.stat().st_mtime_ns
    kept = run_study(study, tmp_path / "out", retry_failed=False)
    assert (kept.ok, kept.failed, kept.skipped) == (1, 1, 2)
    assert error_txt.stat().st_mtime_ns == stamp
    retried = run_study(study, tmp_path / "out", workers=1)
    assert (retried.ok, retried.failed, retried.skipped) == (1, 1, 1)
    assert error_txt.stat().st_mtime_ns != stamp


def run_on_dask(distributed, study, out: Path, *, processes: bool, threads: int):
    """`study` on a local Dask cluster of one worker with `threads` threads."""
    with (
        distributed.LocalCluster(
            n_workers=1, processes=processes, threads_per_worker=threads, dashboard_address=None
        ) as cluster,
        dask_executor(cluster.scheduler_address) as executor,
    ):
        return run_study(study, out, executor=executor)


def test_the_dask_path_gives_the_same_results_as_the_process_pool(tiny, tmp_path):
    distributed = pytest.importorskip("distributed")
    study, pool_result, _ = tiny
    # The same scenarios as the tiny sweep's seed-1 cells, so the same content-addressed ids.
    folder = pool_result.out_dir.parent
    path = write_study(folder, TINY.replace("seeds = [1, 2]", "seeds = [1]"), "dask.toml")
    subset = load_study(path)
    by_id = {r["cell"]: r for r in pool_result.records}
    assert {c.id for c in subset.cells} <= set(by_id)

    result = run_on_dask(distributed, subset, tmp_path / "out", processes=False, threads=1)
    assert (result.ok, result.failed, result.skipped) == (2, 0, 0)
    for record in result.records:
        assert record["kpis"]["digest"] == by_id[record["cell"]]["kpis"]["digest"]
        assert (result.out_dir / record["run_dir"] / "summary.json").is_file()


def test_no_dask_scheduler_is_a_clear_error():
    pytest.importorskip("distributed")
    with socket.socket() as s:  # a port nobody listens on once closed
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    with (
        pytest.raises(FleetError, match=f"Dask scheduler at '{address}'"),
        dask_executor(address, timeout_s=1),
    ):
        pass


@pytest.mark.parametrize(
    ("body", "field", "value", "rule"),
    [
        ('[study]\nscenario = "base.toml"\nseed = [1]\n', "study.seed", [1], "unknown key"),
        ('[study]\nscenario = "base.toml"\n[grid]\nrobots = []\n', "grid.robots", [], "at least"),
        (
            '[study]\nscenario = "base.toml"\n[grid]\n'
            'controller = ["mpc", { name = "follower", options = { gain = 5 } }]\n',
            "grid.controller[1]",
            {"name": "follower", "options": {"gain": 5}},
            "gain = 5: must be a number in [0, 1]",
        ),
        (
            '[study]\nscenario = "base.toml"\n[grid]\ncontroller = ["follower", "folower"]\n',
            "grid.controller[1]",
            "folower",
            "no controller plugin named 'folower'",
        ),
        (
            '[study]\nscenario = "base.toml"\n[grid]\n'
            'controller = ["mpc", { name = "follower", label = "mpc" }]\n',
            "grid.controller[1]",
            {"name": "follower", "label": "mpc"},
            "same label 'mpc'",
        ),
        (
            '[study]\nscenario = "base.toml"\n[grid]\nrobots = [2, 0]\n',
            "grid.robots[1]",
            0,
            "robots.count = 0: must be a positive whole number",
        ),
        (
            '[study]\nscenario = "base.toml"\n[grid]\n"jobs.rate_per_hour" = [6]\n',
            'grid."jobs.rate_per_hour"[0]',
            6,
            "unknown key",
        ),
        (
            '[study]\nscenario = "base.toml"\n[grid]\nrobots = [1]\n"robots.count" = [2]\n',
            'grid."robots.count"',
            [2],
            "axis 'robots' also sets",
        ),
        ('[study]\nscenario = "base.toml"\nseeds = [1, 1]\n', "study.seeds[1]", 1, "twice"),
        ('[study]\nscenario = "nope.toml"\n', "study.scenario", "nope.toml", "no such file"),
        ('[study]\nscenario = "base.toml"\n[grids]\n', "grids", {}, "unknown key"),
    ],
)
def test_bad_study_files_name_the_file_the_field_and_the_value(tmp_path, body, field, value, rule):
    path = write_study(tmp_path, body)
    with pytest.raises(StudyError) as err:
        load_study(path)
    assert (err.value.source, err.value.field, err.value.value) == (str(path), field, value)
    assert rule in str(err.value)
    assert str(err.value).startswith(f"{path}: {field} = ")


def test_a_plugin_the_base_scenario_names_must_exist(tmp_path):
    write_study(tmp_path, "")
    (tmp_path / "base.toml").write_text(BASE + '[dispatcher]\nname = "greedyy"\n')
    path = write_study(tmp_path, '[study]\nscenario = "base.toml"\n[grid]\nrobots = [1, 2]\n')
    with pytest.raises(StudyError, match="study.scenario = 'base.toml': no dispatcher plugin"):
        load_study(path)


def test_cells_an_executor_cannot_run_are_recorded_as_failed(tmp_path):
    study = load_study(write_study(tmp_path, TINY))
    closed = ProcessPoolExecutor(max_workers=1)
    closed.shutdown()
    result = run_study(study, tmp_path / "out", executor=closed)
    assert (result.ok, result.failed) == (0, 4)
    for record in result.records:
        assert record["error"].startswith("RuntimeError: cannot schedule new futures")
        cell_dir = result.out_dir / record["run_dir"]
        assert json.loads((cell_dir / "cell.json").read_text())["status"] == "failed"
        assert "RuntimeError" in (cell_dir / "error.txt").read_text()
    assert [r["status"] for r in read_rows(result.results_path)] == ["failed"] * 4


def test_a_worker_killed_mid_sweep_costs_no_cell(tmp_path):
    # A dead worker breaks the whole process pool; the cells it took down with it run again
    # in a fresh pool instead of being recorded as failed.
    study = load_study(write_study(tmp_path, TINY))
    killed = []

    def kill_a_worker(record, done, total):
        if not killed:
            victim = multiprocessing.active_children()[0]
            os.kill(victim.pid, signal.SIGKILL)
            killed.append(victim.pid)

    result = run_study(study, tmp_path / "out", workers=2, progress=kill_a_worker)
    assert killed
    assert (result.ok, result.failed) == (4, 0)
    assert [r["status"] for r in read_rows(result.results_path)] == ["ok"] * 4


def test_a_dask_worker_with_two_threads_finishes_every_cell(tmp_path):
    # Dask's default workers run cells in threads: each cell loads plugins (a registry read
    # from several threads at once; it used to fail cells with KeyError) and solves with
    # HiGHS, whose scheduler is one per process. Same digests as on a process pool.
    distributed = pytest.importorskip("distributed")
    body = TINY.replace("seeds = [1, 2]", "seeds = [1]") + 'controller = ["follower", "mpc"]\n'
    study = load_study(write_study(tmp_path, body))
    pool = run_study(study, tmp_path / "pool", workers=2)
    result = run_on_dask(distributed, study, tmp_path / "dask", processes=True, threads=2)
    assert (result.ok, result.failed, result.skipped) == (4, 0, 0)
    digests = {r["cell"]: r["kpis"]["digest"] for r in pool.records}
    solves = 0
    for record in result.records:
        assert record["kpis"]["digest"] == digests[record["cell"]]
        summary = json.loads((result.out_dir / record["run_dir"] / "summary.json").read_text())
        solves += summary.get("solver", {}).get("steps", 0)
    assert solves > 0  # the MPC cells did solve in the worker's threads


def test_an_unreadable_study_or_base_scenario_is_an_error_naming_it(tmp_path):
    folder = tmp_path / "s.toml"
    folder.mkdir()
    with pytest.raises(StudyError, match=r"s\.toml: \(file\) = .*cannot read the study file"):
        load_study(folder)
    (tmp_path / "base.toml").write_bytes(b"\xff\xfe[scenario]\n")
    study = tmp_path / "study.toml"
    study.write_text("[study]\nscenario = 'base.toml'\n", encoding="utf-8")
    with pytest.raises(StudyError, match=r"study\.scenario = 'base\.toml': cannot read"):
        load_study(study)


SHIPPED_STUDIES = sorted((REPO_ROOT / "studies").glob("*.toml"))


@pytest.mark.parametrize("path", SHIPPED_STUDIES, ids=lambda p: p.name)
def test_every_shipped_study_loads_and_runs_every_arm_on_the_same_seeds(path):
    """Common random numbers need every grid point on the same seeds (`fleet report` pairs them)."""
    study = load_study(path)
    seeds_of: dict[tuple, list[int]] = {}
    for cell in study.cells:
        seeds_of.setdefault(tuple(sorted(cell.params.items())), []).append(cell.seed)
    assert len(seeds_of) > 1
    assert all(seeds == list(study.seeds) for seeds in seeds_of.values())
