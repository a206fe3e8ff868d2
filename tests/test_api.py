"""The Python API (fleet.api, docs/api.md): real runs and sweeps, typed tables, scenarios made
in code checked as files are, nothing printed on stdout, and the example notebook as written."""

import contextlib
import io
import json
import re
import runpy
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

import fleet
import fleet.api
from fleet.errors import FleetError, InputError, ScenarioError
from fleet.scenario import REPO_ROOT, Scenario
from fleet.study.sweep import StudyError, load_study
from tests.test_study import BASE, MAP

EXAMPLE = REPO_ROOT / "docs" / "examples" / "notebook_study.py"


@pytest.fixture(scope="module")
def hall(tmp_path_factory) -> Path:
    """The scenario file of test_study's hall: deliveries only, a busy rate."""
    folder = tmp_path_factory.mktemp("hall")
    (folder / "hall.toml").write_text(MAP)
    (folder / "base.toml").write_text(BASE)
    return folder / "base.toml"


@pytest.fixture(scope="module")
def result(hall) -> fleet.RunResult:
    return fleet.run(fleet.load_scenario(hall, {"scenario.duration_s": 120}))


# -- tables -------------------------------------------------------------------------------------
def test_every_csv_of_the_run_directory_is_a_table_with_typed_columns(result):
    on_disk = sorted(p.stem for p in result.out_dir.glob("*.csv"))
    assert list(result.table_names) == on_disk
    assert {"events", "jobs", "trajectories"} <= set(on_disk)
    assert result.summary == json.loads((result.out_dir / "summary.json").read_text())
    for name in result.table_names:
        table = result.table(name)
        header = (result.out_dir / f"{name}.csv").read_text().splitlines()[0].split(",")
        assert list(table) == header
        assert len({len(column) for column in table.values()}) <= 1, name
        assert result.rows(name) == [
            dict(zip(table, row, strict=True)) for row in zip(*table.values(), strict=True)
        ]
    jobs = result.table("jobs")
    assert len(jobs["id"]) == result.summary["jobs"]["released"] > 0
    done = result.summary["jobs"]["completed"]
    assert repr(result).startswith(f"RunResult('base': {done} of {len(jobs['id'])} jobs")
    assert all(isinstance(v, str) for v in jobs["id"])
    assert all(isinstance(v, float) for v in jobs["released_s"])
    # A job not delivered by the end has no delivery time: None, not "" or NaN.
    delivered = [v for v in jobs["delivered_s"] if v is not None]
    assert len(delivered) == result.summary["jobs"]["completed"]
    assert all(isinstance(v, float) for v in delivered)
    traj = result.table("trajectories")
    assert all(type(v) is int for v in traj["region"])
    assert all(isinstance(v, float) for v in traj["x"])
    assert set(traj["robot"]) == {"r01", "r02", "r03"}


def test_a_table_is_a_fresh_copy_and_an_unknown_one_names_the_tables_there_are(result):
    result.table("jobs")["id"].clear()
    assert result.table("jobs")["id"]
    with pytest.raises(fleet.TableNotFound, match=r"no table 'nope'.*events, jobs") as caught:
        result.table("nope")
    assert isinstance(caught.value, KeyError) and isinstance(caught.value, FleetError)
    assert "nope" not in result.tables and "jobs" in result.tables and "jobs.csv" in result.tables
    assert result.path("jobs.csv") == result.out_dir / "jobs.csv"


def test_a_table_the_recorder_learns_to_write_is_read_without_a_list(result, tmp_path):
    # Other CSVs (attempts, states, wip...) are tables by being in the run directory.
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "summary.json").write_text((result.out_dir / "summary.json").read_text())
    (run_dir / "future.csv").write_text(
        "t,wip,share,busy,robot,note\n0,1,0.5,true,r01,\n1.5,2,1,false,,x\n3,10,1e-3,TRUE,r02,7\n"
    )
    opened = fleet.open_run(run_dir)
    assert opened.table_names == ("future",)
    assert opened.table("future") == {
        "t": [0.0, 1.5, 3.0],  # a column with one fraction is all floats
        "wip": [1, 2, 10],
        "share": [0.5, 1.0, 0.001],
        "busy": [True, False, True],
        "robot": ["r01", None, "r02"],
        "note": [None, "x", "7"],  # text with a number in it stays text
    }
    assert opened.scenario is None and opened.summary == result.summary
    with pytest.raises(InputError, match="not a run directory"):
        fleet.open_run(tmp_path)
    (run_dir / "bad.csv").write_text("a,b\n1\n")
    with pytest.raises(FleetError, match=r"bad.csv: line 2 has 1 fields, the header 2"):
        opened.table("bad")


def test_tables_load_into_pandas_in_one_line(result):
    pd = pytest.importorskip("pandas")
    frame = pd.DataFrame(result.table("jobs"))
    assert list(frame.columns) == list(result.table("jobs"))
    assert frame["released_s"].dtype == float


# -- scenarios made in code ---------------------------------------------------------------------
def test_overrides_and_changes_are_checked_as_a_file_is_and_name_key_and_value(hall):
    base = fleet.load_scenario(hall)
    six = fleet.change(base, {"robots.count": 6, "scenario.seed": 3})
    assert (six.robots[0].count, six.seed) == (6, 3)
    assert six == fleet.load_scenario(hall, {"robots.count": 6, "scenario.seed": 3})
    assert fleet.change(six, {"robots.count": 2}).seed == 3  # changes add up
    assert base.robots[0].count == 3  # the original is left as it was
    cases = [
        ({"robots.count": 0}, "robots.count = 0"),
        ({"robots.cuont": 2}, "robots.cuont = 2: unknown key"),
        ({"jobs.rate_per_h": "fast"}, "jobs.rate_per_h = 'fast'"),
        ({"scenario.seed.x": 1}, "scenario.seed.x = 1: scenario.seed is not a table"),
    ]
    for overrides, message in cases:
        for attempt in (lambda o=overrides: fleet.change(base, o),
                        lambda o=overrides: fleet.load_scenario(hall, o)):  # fmt: skip
            with pytest.raises(ScenarioError) as caught:
                attempt()
            assert str(caught.value).startswith(f"overrides: {message}"), caught.value


def test_change_refuses_what_it_would_silently_undo(hall):
    base = fleet.load_scenario(hall)
    with pytest.raises(FleetError, match="changed after it was read"):
        fleet.change(replace(base, duration_s=5.0), {"robots.count": 2})
    by_field = Scenario(name="x", source="<code>", map=base.map)
    with pytest.raises(FleetError, match="built field by field"):
        fleet.change(by_field, {"robots.count": 2})


def test_a_scenario_built_from_a_dict_is_the_file_it_would_be(hall):
    tables = {
        "scenario": {"map": "hall.toml", "duration_s": 600, "seed": 9},
        "robots": {"count": 3},
        "jobs": {"rate_per_h": 360, "stations": ["east", "north"]},
    }
    built = fleet.scenario_from_dict(tables, folder=hall.parent, name="base")
    assert built == replace(fleet.load_scenario(hall), source="scenario_from_dict")
    # Python's paths and tuples read as the file's text and lists.
    pythonic = {**tables, "scenario": {**tables["scenario"], "map": hall.parent / "hall.toml"}}
    pythonic["jobs"] = {**tables["jobs"], "stations": ("east", "north")}
    assert fleet.scenario_from_dict(pythonic, name="base") == built
    assert fleet.change(built, {"scenario.map": hall.parent / "hall.toml"}) == built
    assert tables["robots"] == {"count": 3}  # left unchanged
    assert fleet.change(built, {"robots.count": 1}).robots[0].count == 1
    with pytest.raises(ScenarioError, match=r"^scenario_from_dict: scenario.map = 'nope.toml'"):
        fleet.scenario_from_dict({"scenario": {"map": "nope.toml"}}, folder=hall.parent)
    with pytest.raises(ScenarioError, match=r"^mine: robots.count = 'six'"):
        fleet.scenario_from_dict(
            {**tables, "robots": {"count": "six"}}, folder=hall.parent, source="mine"
        )


# -- running ------------------------------------------------------------------------------------
def test_run_writes_where_asked_refuses_an_earlier_run_and_reports_progress(hall, tmp_path):
    scenario = fleet.load_scenario(hall, {"scenario.duration_s": 30, "robots.count": 1})
    seen: list[float] = []
    out = tmp_path / "run"
    first = fleet.run(scenario, out, progress=seen.append)
    assert first.out_dir == out and (out / "jobs.csv").is_file() and first.complete
    assert first.problems == [] and first.scenario is scenario
    assert seen and seen == sorted(seen) and seen[-1] <= 30.0
    with pytest.raises(InputError, match=r"fleet.api.run: out_dir = .*force=True"):
        fleet.run(scenario, out)
    again = fleet.run(scenario, out, force=True)
    assert again.summary["digest"] == first.summary["digest"]
    (out / "mine.txt").write_text("keep me")
    with pytest.raises(InputError, match="holds files no run writes"):
        fleet.run(scenario, out, force=True)
    assert (out / "mine.txt").read_text() == "keep me"


def test_a_temporary_run_directory_goes_with_its_result(hall):
    result = fleet.run(str(hall))  # a file name is read as load_scenario reads it
    folder = result.out_dir
    assert folder.is_dir() and result.scenario.name == "base"
    del result
    import gc

    gc.collect()
    assert not folder.exists()


def test_the_api_prints_nothing_on_stdout(hall):
    # A fresh process: HiGHS's banner and logging are set up once per process.
    code = (
        "import fleet\n"
        f"r = fleet.run(fleet.load_scenario({str(hall)!r}, {{'scenario.duration_s': 30}}))\n"
        "assert r.table('jobs')\n"
        # The MPC solves through pyomo and HiGHS, whose banners would go to stdout.
        f"m = fleet.load_scenario({str(hall)!r}, {{'scenario.duration_s': 30, "
        "'robots.count': 1, 'controller.name': 'mpc', 'jobs.rate_per_h': 3600})\n"
        "assert fleet.run(m).summary['solver']['steps'] > 0\n"
        f"fleet.sweep(fleet.load_scenario({str(hall)!r}), grid={{'robots': [1]}}, "
        "duration_s=10, jobs=0)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""
    assert "Traceback" not in proc.stderr


def test_the_package_offers_the_api_names_on_first_use():
    assert fleet.run is fleet.api.run and fleet.SweepResults is fleet.api.SweepResults
    assert all(getattr(fleet, name) is getattr(fleet.api, name) for name in fleet.api.__all__)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        fleet.nope  # noqa: B018


# -- sweeps -------------------------------------------------------------------------------------
STUDY = """
[study]
scenario = "base.toml"
seeds = [1, 2]
duration_s = 60
[grid]
robots = [1, 2]
"""


def test_a_sweep_gives_typed_rows_and_every_cells_tables(hall, tmp_path):
    (hall.parent / "study.toml").write_text(STUDY)
    done = fleet.sweep(hall.parent / "study.toml", tmp_path / "study", jobs=1)
    assert (done.ok, done.failed) == (4, 0)
    rows = done.rows
    assert [(r["robots"], r["seed"]) for r in rows] == [(1, 1), (1, 2), (2, 1), (2, 2)]
    for row in rows:
        assert row["status"] == "ok" and isinstance(row["jobs_released"], int)
        assert isinstance(row["throughput_per_h"], float)
        run = done.run(row["cell"])
        assert run.summary["jobs"]["released"] == row["jobs_released"]
        assert run.summary["robots"] == row["robots"]
    assert repr(done).startswith("SweepResults('study': 4 cells, 4 ok, 0 failed")
    results = done.table()
    assert list(results) == list(rows[0]) and results["robots"] == [1, 1, 2, 2]
    jobs = done.table("jobs")
    assert list(jobs)[:3] == ["cell", "seed", "robots"]
    assert len(jobs["id"]) == sum(r["jobs_released"] for r in rows)
    for cell in done.rows:
        mine = [i for i, c in enumerate(jobs["cell"]) if c == cell["cell"]]
        assert [jobs["id"][i] for i in mine] == done.run(cell["index"]).table("jobs")["id"]
    with pytest.raises(FleetError, match="no cell 'nope'"):
        done.run("nope")
    report = done.report(tmp_path / "report")
    assert report.report.is_file() and "robots" in report.markdown


def test_sweeping_a_scenario_in_code_is_sweeping_the_same_study_file(hall, tmp_path):
    (hall.parent / "study.toml").write_text(STUDY)
    from_file = load_study(hall.parent / "study.toml")
    base = fleet.load_scenario(hall)
    in_code = fleet.sweep(
        base, tmp_path / "s", grid={"robots": [1, 2]}, seeds=[1, 2], duration_s=60, jobs=0
    )
    # The same cells (content addresses), so the file's sweep resumes the code's.
    assert [c.id for c in in_code.study.cells] == [c.id for c in from_file.cells]
    resumed = fleet.sweep(from_file, tmp_path / "s", jobs=0)
    assert all(r["skipped"] for r in resumed.sweep.records)
    assert resumed.rows == in_code.rows
    with pytest.raises(StudyError, match=r"^sweep\(base\): grid.robots\[1\] = 0: .*robots.count"):
        fleet.sweep(base, grid={"robots": [1, 0]})
    with pytest.raises(TypeError, match="go with a Scenario"):
        fleet.sweep(from_file, grid={"robots": [1]})


# -- the example --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def example() -> tuple[dict, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        namespace = runpy.run_path(str(EXAMPLE), run_name="__main__")
    return namespace, out.getvalue()


def test_the_example_notebook_runs_and_its_figures_follow_from_its_tables(example):
    ns, printed = example
    result, study = ns["result"], ns["study"]
    assert result.summary["robots"] == 4 and result.scenario.seed == 3
    jobs = result.table("jobs")
    expected = sorted(
        d - r for r, d in zip(jobs["released_s"], jobs["delivered_s"], strict=True) if d
    )
    assert (
        sorted(ns["lead_times"]) == expected
        and len(expected) == result.summary["jobs"]["completed"]
    )
    assert (study.ok, study.failed) == (4, 0)
    for n, mean in ns["mean_throughput"].items():
        cells = [r["throughput_per_h"] for r in study.rows if r["robots"] == n]
        assert len(cells) == 2 and mean == pytest.approx(sum(cells) / 2)
    assert set(ns["p50_lead"]) == {2, 4}
    assert "refused: overrides: robots.count = 0" in printed


def test_docs_api_shows_the_examples_real_output(example):
    text = (REPO_ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- output of notebook_study.py -->\n```text\n(.*?)```", text, re.S)
    assert block is not None, "docs/api.md lost the example's output block"
    if "pandas" in sys.modules:
        pytest.skip("with pandas installed the example also prints a data frame")
    shown, printed = block[1].splitlines(), example[1].splitlines()
    assert len(shown) == len(printed)
    for want, got in zip(shown, printed, strict=True):
        if want.startswith("tables: "):
            # Tables the recorder learns to write join the list without changing the page.
            assert set(want[8:].split(", ")) <= set(got[8:].split(", ")), got
        else:
            assert want == got


def test_progress_is_a_bar_on_stderr_or_a_callable_and_never_on_stdout(hall, capfd):
    scenario = fleet.load_scenario(hall, {"scenario.duration_s": 20, "robots.count": 1})
    assert fleet.run(scenario, progress=True).complete
    cells: list[tuple[str, int, int]] = []
    fleet.sweep(
        scenario,
        grid={"robots": [1]},
        seeds=2,
        jobs=0,
        progress=lambda record, done, total: cells.append((record["status"], done, total)),
    )
    assert cells == [("ok", 1, 2), ("ok", 2, 2)]
    fleet.sweep(scenario, grid={"robots": [1]}, jobs=0, progress=True)
    assert capfd.readouterr().out == ""
    with pytest.raises(TypeError, match="progress = 'yes'"):
        fleet.run(scenario, progress="yes")


def test_an_interrupted_sweep_keeps_the_cells_that_finished_and_resumes(hall, tmp_path):
    from fleet.study.sweep import SweepInterrupted

    scenario = fleet.load_scenario(hall, {"scenario.duration_s": 20})

    def stop_after_one(record, done, total):
        raise KeyboardInterrupt  # as Ctrl-C or a notebook's stop button would, mid-sweep

    with pytest.raises(SweepInterrupted) as caught:
        fleet.sweep(scenario, tmp_path, grid={"robots": [1, 2]}, jobs=0, progress=stop_after_one)
    kept = caught.value.results
    assert kept.ok == 1 and not kept.sweep.complete
    assert kept.run(kept.rows[0]["cell"]).summary["robots"] == 1
    resumed = fleet.sweep(scenario, tmp_path, grid={"robots": [1, 2]}, jobs=0)
    assert resumed.ok == 2 and [r["skipped"] for r in resumed.sweep.records] == [True, False]
