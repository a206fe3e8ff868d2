"""The study report: figures and Markdown from a study directory of real runs.

The study directory is made the way `fleet sweep` lays it out (study.json, results.csv, one run
directory per cell under cells/) from real, short runs of the default scenario; synthetic
results.csv files cover the verdicts, missing axes and malformed input.
"""

import csv
import json
import math
import multiprocessing
import re
import shutil
import statistics
import struct
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import pytest
from matplotlib.container import BarContainer
from scipy import stats as scipy_stats

from fleet.engine import World
from fleet.errors import InputError, PluginError
from fleet.scenario import PluginChoice, default_scenario
from fleet.study.report import (
    HalfWidth,
    Verdict,
    compare,
    load_study,
    mean_ci,
    summarise,
    t_quantile,
    throughput_figure,
    write_report,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
KPI = (
    "jobs_released",
    "jobs_completed",
    "jobs_good",
    "jobs_defective",
    "jobs_late",
    "throughput_per_h",
    "throughput_good_per_h",
    "mean_lead_time_s",
    "distance_m",
    "violations_obstacle",
    "violations_speed_zone",
    "violations_print_speed",
    "violations_collision",
    "solver_median_ms",
    "solver_fallbacks",
    "digest",
)
# Two-sided 95 % t quantiles from a printed table, for the independent recomputation.
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 30: 2.042}


def write_study(out: Path, axes: dict[str, list[str]], seeds: list[int], rows: list[dict]) -> Path:
    """study.json and results.csv in the layout `fleet sweep` (fleet.study.sweep) writes; rows hold
    `cell`, `seed`, one key per axis, `status`, optionally `error`, `run_dir` and KPI values."""
    out.mkdir(parents=True, exist_ok=True)
    cells = {
        r["cell"]: {"index": i, "seed": r["seed"], "params": {a: r[a] for a in axes}}
        for i, r in enumerate(rows)
    }
    (out / "study.json").write_text(
        json.dumps(
            {
                "name": out.name,
                "file": "study.toml",
                "axes": [{"name": a, "labels": labels} for a, labels in axes.items()],
                "seeds": seeds,
                "cells": cells,
            }
        )
    )
    columns = ["cell", "index", "seed", *axes, "status", "error", "wall_s", "run_dir", *KPI]
    with open(out / "results.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, columns)
        w.writeheader()
        for i, r in enumerate(rows):
            w.writerow({c: r.get(c, "") for c in columns} | {"index": i})
    return out


def flatten(summary: dict) -> dict:
    """The KPI columns of results.csv from a real summary.json."""
    row = {f"jobs_{k}": summary["jobs"][k] for k in ("released", "completed", "good", "defective")}
    row["jobs_late"] = summary["jobs"]["late"]
    for k in ("throughput_per_h", "throughput_good_per_h", "mean_lead_time_s", "distance_m"):
        row[k] = "" if summary[k] is None else summary[k]
    for k, v in summary["violations"].items():
        row[f"violations_{k}"] = v
    row["solver_median_ms"] = summary["solver"]["median_ms"] or ""
    row["solver_fallbacks"] = summary["solver"]["fallbacks"]
    row["digest"] = summary["digest"]
    return row


SERIES = ("follower, jobs.parts=prism", "follower, jobs.parts=bracket")


def run_cell(cell: str, seed: int, part: str, rate: str, out: Path) -> dict:
    """One real run of the default scenario on 2 robots for 40 simulated minutes, every job
    printing `part` (the prism takes ~20 min, the bracket ~31 min), written to cells/<cell>."""
    base = default_scenario().override(robots=2, duration=2400, seed=seed)
    scenario = replace(base, jobs=replace(base.jobs, rate_per_h=float(rate), parts=(part,)))
    world = World(scenario)
    result = world.run()
    world.write(out / "cells" / cell)
    params = {"controller": "follower", "jobs.parts": part, "rate_per_h": rate, "robots": "2"}
    return {"cell": cell, "seed": seed, "status": "ok", "run_dir": f"cells/{cell}"} | (
        params | {"wall_s": result.summary["wall_time_s"]} | flatten(result.summary)
    )


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    """A real study: prints of the prism or the bracket x 6 and 12 jobs/h x seeds 1, 2 (eight
    runs on two processes), plus a controller variant whose options the plugin rejects (two
    real failed cells) and a failed row of an ok grid point (as a crashed worker leaves it)."""
    out = tmp_path_factory.mktemp("study") / "demo"
    grid = [(part, rate, seed) for part in ("prism", "bracket") for rate in ("6", "12")
            for seed in (1, 2)]  # fmt: skip
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [
            pool.submit(run_cell, f"c{i:03d}", seed, part, rate, out)
            for i, (part, rate, seed) in enumerate(grid)
        ]
        rows = [f.result() for f in futures]
    for rate in ("6", "12"):
        bad = replace(default_scenario(), controller=PluginChoice("follower", {"gain": 5}))
        with pytest.raises(PluginError) as err:
            World(bad)
        rows.append(
            {"cell": f"c{len(rows):03d}", "seed": 1, "controller": "follower g5"}
            | {"jobs.parts": "prism", "rate_per_h": rate, "robots": "2", "status": "failed"}
            | {"error": f"PluginError: {err.value}"}
        )
    rows.append(
        {"cell": "c999", "seed": 3, "controller": "follower", "jobs.parts": "prism"}
        | {"rate_per_h": "6", "robots": "2", "status": "failed"}
        | {"error": "BrokenProcessPool: worker | died"}
    )
    axes = {
        "controller": ["follower", "follower g5"],
        "jobs.parts": ["prism", "bracket"],
        "rate_per_h": ["6", "12"],
        "robots": ["2"],
    }
    return write_study(out, axes, [1, 2, 3], rows)


@pytest.fixture(scope="module")
def report(study: Path, tmp_path_factory):
    return write_report(study, tmp_path_factory.mktemp("report"))


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, f"{path} is not a PNG"
    return struct.unpack(">II", data[16:24])  # IHDR width, height


def table_rows(markdown: str, section: str) -> list[list[str]]:
    """Body rows of the Markdown tables in `section` (``## section`` up to the next ``## ``)."""
    body = markdown.split(f"## {section}\n", 1)[1].split("\n## ", 1)[0]
    rows = [ln for ln in body.splitlines() if ln.startswith("|") and not ln.startswith("|---")]
    return [[c.strip() for c in re.split(r"(?<!\\)\|", ln)[1:-1]] for ln in rows]


# -- statistics (tests/test_stats.py checks them against scipy) ---------------------------------
def test_mean_ci_is_the_student_t_interval_and_none_for_one_value():
    c = mean_ci([1.0, 2.0, 3.0])
    assert c.mean == 2.0 and c.n == 3
    assert c.half_width == pytest.approx(4.303 / math.sqrt(3), abs=1e-3)
    assert t_quantile(2) == pytest.approx(T975[2], abs=5e-4)
    one = mean_ci([5.0])
    assert one.half_width is None and one.low == one.high == 5.0
    with pytest.raises(ValueError):
        mean_ci([])


def test_compare_says_clear_only_when_every_paired_difference_is_above_zero():
    a = {1: 10.0, 2: 11.0, 3: 9.0}
    assert compare({"b": {1: 7.0, 2: 8.1, 3: 5.8}, "a": a}).verdict is Verdict.CLEAR
    # c has the lowest mean but differences to the leader that reach 0: not clearly ahead.
    c = {1: 2.0, 2: 14.0, 3: 3.0}
    got = compare({"a": a, "b": {1: 7.0, 2: 8.1, 3: 5.8}, "c": c})
    assert (got.leader, got.runner_up, got.verdict) == ("a", "b", Verdict.TIE)
    assert got.differences["b"].low > 0 and got.differences["c"].low <= 0


# -- the report of real runs ------------------------------------------------------------------
def test_writes_three_pngs_and_the_report_into_out_dir(report):
    names = [p.name for p in report.paths]
    assert names == ["report.md", "throughput.png", "lead_time.png", "defects.png"]
    for path in report.figures:
        width, height = png_size(path)
        assert width >= 600 and height >= 500
        assert path.stat().st_size > 15_000  # something drawn, not an empty canvas
    assert report.report.read_text(encoding="utf-8") == report.markdown
    for name in ("throughput.png", "lead_time.png", "defects.png"):
        assert f"]({name})" in report.markdown  # linked relative to report.md


def good_parts_by_setting(study: Path) -> dict[tuple[str, str], dict[int, float]]:
    """(rate, series) -> seed -> good parts/h of the ok runs, read straight from results.csv."""
    groups = defaultdict(dict)
    with open(study / "results.csv", newline="") as fh:
        for r in csv.DictReader(fh):
            if r["status"] == "ok":
                key = (r["rate_per_h"], f"{r['controller']}, jobs.parts={r['jobs.parts']}")
                groups[key][int(r["seed"])] = float(r["throughput_good_per_h"])
    return groups


def parse_interval(text: str) -> tuple[float, float, float, int]:
    """(mean, low, high, n) of a table cell, ``m ± h (n=k)`` or, cut at 0, ``m [lo, hi] (n=k)``."""
    m = re.fullmatch(r"(-?[\d.]+) ± ([\d.]+) \(n=(\d+)\)", text)
    if m:
        return float(m[1]), float(m[1]) - float(m[2]), float(m[1]) + float(m[2]), int(m[3])
    m = re.fullmatch(r"(-?[\d.]+) \[(-?[\d.]+), (-?[\d.]+)\] \(n=(\d+)\)", text)
    assert m, text
    return float(m[1]), float(m[2]), float(m[3]), int(m[4])


def test_good_parts_table_equals_means_and_intervals_recomputed_from_results_csv(study, report):
    groups = good_parts_by_setting(study)
    rows = table_rows(report.markdown, "Good parts per hour")
    header, body = rows[0], rows[1:]
    assert header == ["rate_per_h", *SERIES, "highest mean"]
    assert [r[0] for r in body] == ["6", "12"]
    for r in body:
        for col, series in enumerate(SERIES, 1):
            values = list(groups[(r[0], series)].values())
            mean, low, high, n = parse_interval(r[col])
            assert mean == pytest.approx(statistics.mean(values), abs=0.006)
            hw = T975[len(values) - 1] * statistics.stdev(values) / math.sqrt(len(values))
            # Cut at 0: good parts per hour cannot be negative.
            assert low == pytest.approx(max(0.0, mean - hw), abs=0.006)
            assert high == pytest.approx(mean + hw, abs=0.006)
            assert n == len(values) == 2


def test_the_leader_column_agrees_with_paired_differences_recomputed_from_results_csv(
    study, report
):
    groups = good_parts_by_setting(study)
    checked = 0
    for row in table_rows(report.markdown, "Good parts per hour")[1:]:
        arms = {series: groups[(row[0], series)] for series in SERIES}
        (a, va), (b, vb) = sorted(arms.items(), key=lambda kv: -statistics.mean(kv[1].values()))
        assert sorted(va) == sorted(vb) == [1, 2]  # the same seeds: paired
        d = [va[seed] - vb[seed] for seed in (1, 2)]
        low = statistics.mean(d) - T975[1] * statistics.stdev(d) / math.sqrt(2)
        if math.isclose(statistics.mean(va.values()), statistics.mean(vb.values())):
            assert row[-1] == f"none: {SERIES[0]} and {SERIES[1]} have equal means"
        elif low > 0.01:
            assert row[-1] == f"**{a}**, clearly ahead of {b}"
        elif low < -0.01:
            assert row[-1] == f"{a}; tie with {b} (difference's interval reaches 0)"
        else:
            continue  # within rounding of zero: either verdict is defensible
        checked += 1
    assert checked >= 1
    comparisons = table_rows(report.markdown, "Comparisons")
    assert comparisons[0] == [
        "rate_per_h", "leader − series", "difference (good parts/h)", "separated", "method"
    ]  # fmt: skip
    for r in comparisons[1:]:
        assert r[4] == "95 % CI, paired t on 2 common seeds, df 1"


def test_failed_runs_are_listed_with_their_errors_and_left_out(report):
    failed = table_rows(report.markdown, "Failed runs")
    assert [r[0] for r in failed[1:]] == ["c008", "c009", "c999"]
    assert failed[1][3].startswith("PluginError") and "gain = 5" in failed[1][3]
    assert failed[3][3] == "BrokenProcessPool: worker \\| died"  # pipe escaped for the table
    assert report.summary.series == SERIES  # the g5 variant never ran
    assert "11 runs in" in report.markdown and "8 ok, 3 failed" in report.markdown


def test_defect_rates_and_lead_time_medians_come_from_the_jobs_files(study, report):
    bad, judged, leads = defaultdict(int), defaultdict(int), defaultdict(list)
    for cid, meta in json.loads((study / "study.json").read_text())["cells"].items():
        path = study / "cells" / cid / "jobs.csv"
        if not path.is_file():
            continue
        p = meta["params"]
        key = (p["rate_per_h"], f"{p['controller']}, jobs.parts={p['jobs.parts']}")
        with open(path, newline="") as fh:
            for r in csv.DictReader(fh):
                if r["outcome"]:
                    judged[key] += 1
                    bad[key] += r["outcome"] != "good"
                if r["delivered_s"]:
                    leads[key].append(float(r["delivered_s"]) - float(r["released_s"]))
    assert sum(judged.values()) >= 4  # the runs are long enough to judge parts
    defects = {r[0]: r[1:] for r in table_rows(report.markdown, "Defect rates")[1:]}
    medians = {r[0]: r[1:] for r in table_rows(report.markdown, "Lead times")[1:]}
    for rate in ("6", "12"):
        for col, series in enumerate(SERIES):
            key = (rate, series)
            if judged[key]:
                expected = f"{100 * bad[key] / judged[key]:.0f} % ({bad[key]}/{judged[key]})"
            else:
                expected = "– (0 judged)"
            assert defects[rate][col] == expected
            if leads[key]:
                expected = f"{statistics.median(leads[key]):.0f} s (n={len(leads[key])})"
            else:
                expected = "– (n=0)"
            assert medians[rate][col] == expected


def test_violations_are_summed_over_ok_runs(study, report):
    total = 0
    with open(study / "results.csv", newline="") as fh:
        for r in csv.DictReader(fh):
            if r["status"] == "ok":
                total += sum(int(r[f"violations_{k}"]) for k in ("obstacle", "speed_zone"))
                total += sum(int(r[f"violations_{k}"]) for k in ("print_speed", "collision"))
    section = report.markdown.split("## Safety violations\n", 1)[1].split("\n## ", 1)[0]
    if total:
        assert f"{total} violation(s)" in section
    else:
        assert "None: all 8 ok runs have zero violations" in section


def test_the_report_goes_into_the_study_dir_by_default(study, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(study, copy)
    result = write_report(copy)
    assert result.out_dir == copy and (copy / "report.md").is_file()
    assert (copy / "throughput.png").is_file()


# -- synthetic studies: verdicts, missing axes ------------------------------------------------
def ok_row(cell: str, seed: int, good: float, **params) -> dict:
    violations = {f"violations_{k}": 0 for k in ("obstacle", "speed_zone", "print_speed")}
    return {"cell": cell, "seed": seed, "status": "ok", "throughput_good_per_h": good} | (
        violations | {"violations_collision": 0} | params
    )


def test_verdicts_per_fleet_size_and_rate(tmp_path):
    """A clearly ahead at 2 robots and 6/h, a tie at 2 robots and 12/h, one seed at 4 robots."""
    values = {
        ("2", "6"): {"A": [5.0, 5.2, 5.1], "B": [3.0, 3.1, 2.9]},
        ("2", "12"): {"A": [6.0, 9.0, 7.0], "B": [7.0, 6.5, 7.2]},
        ("4", "6"): {"A": [4.0], "B": [5.0]},
    }
    rows = []
    for (robots, rate), by_c in values.items():
        for c, goods in by_c.items():
            for seed, g in enumerate(goods, 1):
                p = {"controller": c, "rate_per_h": rate, "robots": robots}
                rows.append(ok_row(f"c{len(rows):03d}", seed, g, **p))
    axes = {"controller": ["A", "B"], "rate_per_h": ["6", "12"], "robots": ["2", "4"]}
    result = write_report(write_study(tmp_path / "s", axes, [1, 2, 3], rows))
    verdicts = {(r.panel, r.x): (r.leader, r.verdict) for r in result.summary.rankings}
    assert verdicts == {
        ("2", "6"): ("A", Verdict.CLEAR),
        ("2", "12"): ("A", Verdict.TIE),
        ("4", "6"): ("B", Verdict.NO_INTERVAL),
    }
    md = result.markdown
    assert "### robots = 2" in md and "### robots = 4" in md
    assert "**A**, clearly ahead of B" in md
    assert "A; tie with B (difference's interval reaches 0)" in md
    assert "A has the highest mean in 2 of 3 setting(s), clearly ahead in 1." in md
    assert "None: all" in md  # no violations
    assert "have no `jobs.csv`" in md  # synthetic rows have no run directories
    assert all(png_size(p)[0] > 0 for p in result.figures)


def test_without_a_rate_axis_throughput_is_a_bar_per_controller(tmp_path):
    rows = [
        ok_row("c0", 1, 3.0, controller="A"),
        ok_row("c1", 2, 4.0, controller="A"),
        ok_row("c2", 1, 6.0, controller="B"),
    ]
    summary = summarise(
        load_study(write_study(tmp_path / "s", {"controller": ["A", "B"]}, [1, 2], rows))
    )
    (ax,) = throughput_figure(summary).axes
    bars = [c for c in ax.containers if isinstance(c, BarContainer)]
    assert sorted(b.patches[0].get_height() for b in bars) == [3.5, 6.0]
    assert not [ln for ln in ax.get_lines() if ln.get_gid() == "offered"]


def test_without_a_controller_axis_other_axes_name_the_series(tmp_path):
    axes = {"rate_per_h": ["6", "12"], "quality.tolerance_mm": ["0.05", "0.08"]}
    rows = [
        ok_row(f"c{i}", 1, float(i), rate_per_h=r, **{"quality.tolerance_mm": t})
        for i, (r, t) in enumerate([("6", "0.05"), ("6", "0.08"), ("12", "0.05"), ("12", "0.08")])
    ]
    summary = summarise(load_study(write_study(tmp_path / "s", axes, [1], rows)))
    assert summary.series == ("quality.tolerance_mm=0.05", "quality.tolerance_mm=0.08")
    assert summary.xs == ("6", "12") and summary.x_values == (6.0, 12.0)
    (ax,) = throughput_figure(summary).axes
    (offered,) = [ln for ln in ax.get_lines() if ln.get_gid() == "offered"]
    assert list(offered.get_ydata()) == [6.0, 12.0]


# -- errors -----------------------------------------------------------------------------------
def test_a_dir_without_results_csv_is_named(tmp_path):
    with pytest.raises(InputError, match=r"results\.csv.*missing.*fleet sweep"):
        write_report(tmp_path)


def test_a_study_with_no_ok_run_is_refused(tmp_path):
    rows = [{"cell": "c0", "seed": 1, "controller": "A", "status": "failed", "error": "boom"}]
    path = write_study(tmp_path / "s", {"controller": ["A"]}, [1], rows)
    with pytest.raises(InputError, match="none ok") as err:
        write_report(path)
    assert err.value.source == str(path / "results.csv")


def test_a_missing_column_is_named(tmp_path):
    path = write_study(
        tmp_path / "s", {"controller": ["A"]}, [1], [ok_row("c0", 1, 1.0, controller="A")]
    )
    text = (path / "results.csv").read_text().replace("throughput_good_per_h", "good")
    (path / "results.csv").write_text(text)
    with pytest.raises(InputError, match="lacks column.*throughput_good_per_h") as err:
        load_study(path)
    assert err.value.field == "header"


def test_a_value_that_is_not_a_number_is_named_with_line_and_column(tmp_path):
    rows = [ok_row("c0", 1, 1.0, controller="A"), ok_row("c1", 2, "lots", controller="A")]
    path = write_study(tmp_path / "s", {"controller": ["A"]}, [1, 2], rows)
    with pytest.raises(InputError) as err:
        load_study(path)
    assert err.value.field == "line 3, throughput_good_per_h" and err.value.value == "lots"
    assert str(path / "results.csv") in str(err.value)


def test_a_bad_status_and_an_axis_column_missing_are_refused(tmp_path):
    rows = [ok_row("c0", 1, 1.0, controller="A") | {"status": "done"}]
    path = write_study(tmp_path / "s", {"controller": ["A"]}, [1], rows)
    with pytest.raises(InputError, match='must be "ok" or "failed"'):
        load_study(path)
    meta = json.loads((path / "study.json").read_text())
    meta["axes"].append({"name": "robots", "labels": ["2"]})
    (path / "study.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="axis column.*robots"):
        load_study(path)


def test_a_malformed_jobs_file_is_named_with_line_and_column(tmp_path):
    rows = [ok_row("c0", 1, 1.0, controller="A") | {"run_dir": "cells/c0"}]
    path = write_study(tmp_path / "s", {"controller": ["A"]}, [1], rows)
    (path / "cells" / "c0").mkdir(parents=True)
    (path / "cells" / "c0" / "jobs.csv").write_text(
        "id,released_s,delivered_s,outcome\nj1,10,50,good\nj2,20,soon,good\n"
    )
    with pytest.raises(InputError) as err:
        write_report(path)
    assert err.value.field == "line 3, delivered_s" and err.value.value == "soon"


def test_cells_of_study_json_without_a_result_are_named_as_not_run(tmp_path):
    path = write_study(
        tmp_path / "s", {"controller": ["A"]}, [1], [ok_row("c0", 1, 2.0, controller="A")]
    )
    meta = json.loads((path / "study.json").read_text())
    meta["cells"]["c1"] = {"index": 1, "seed": 2, "params": {"controller": "A"}}
    meta["axes"] = {"controller": ["A"]}  # the other layout: axis name -> labels
    (path / "study.json").write_text(json.dumps(meta))
    md = write_report(path).markdown
    assert "1 cell(s) listed in `study.json` have no row in `results.csv` (not run yet): c1." in md
    assert "Study file: `study.toml`." in md


# -- paired comparisons on a 2-arm, 5-seed study ----------------------------------------------
# Good parts per hour of two controllers on seeds 1..5: the seeds' spread is shared (common
# random numbers), B trails A by about one part per hour on every seed.
PAIR_A = {1: 12.0, 2: 18.0, 3: 9.0, 4: 15.0, 5: 21.0}
PAIR_B = {1: 11.0, 2: 16.5, 3: 8.0, 4: 14.2, 5: 19.6}


def pair_study(path: Path, a: dict, b: dict, *, failed: tuple = ()) -> Path:
    rows = []
    for name, values in (("A", a), ("B", b)):
        for seed, good in values.items():
            rows.append(ok_row(f"c{len(rows):03d}", seed, good, controller=name))
    for name, seed in failed:
        rows.append({"cell": f"c{len(rows):03d}", "seed": seed, "controller": name}
                    | {"status": "failed", "error": "RuntimeError: lost"})  # fmt: skip
    seeds = sorted({*a, *b})
    return write_study(path, {"controller": ["A", "B"]}, seeds, rows)


def test_a_two_arm_five_seed_study_prints_paired_intervals_that_scipy_confirms(tmp_path):
    result = write_report(pair_study(tmp_path / "s", PAIR_A, PAIR_B))
    seeds = sorted(PAIR_A)
    res = scipy_stats.ttest_rel([PAIR_A[s] for s in seeds], [PAIR_B[s] for s in seeds])
    ci = res.confidence_interval(0.95)
    (row,) = table_rows(result.markdown, "Comparisons")[1:]
    mean, half = (ci.low + ci.high) / 2, (ci.high - ci.low) / 2
    assert row == [
        "all runs",
        "A − B",
        f"{mean:+.2f} ± {half:.2f}",
        "yes",
        "95 % CI, paired t on 5 common seeds, df 4",
    ]
    assert "Method: 95 % CI, paired t on 5 common seeds, df 4 (1 difference)." in result.markdown
    assert "Every comparison is paired" in result.markdown
    (ranking,) = result.summary.rankings
    assert ranking.verdict is Verdict.CLEAR
    d = ranking.differences["B"]
    assert (d.low, d.high) == pytest.approx((ci.low, ci.high), rel=1e-12) and d.df == res.df
    # The arms' own intervals overlap: only the pairing separates them.
    a, b = (result.summary.throughput[(None, s, None)] for s in ("A", "B"))
    assert a.low < b.high


def test_a_failed_run_breaks_the_pairing_and_welch_is_named(tmp_path):
    b = {s: v for s, v in PAIR_B.items() if s != 4}
    result = write_report(pair_study(tmp_path / "s", PAIR_A, b, failed=(("B", 4),)))
    res = scipy_stats.ttest_ind(list(PAIR_A.values()), list(b.values()), equal_var=False)
    ci = res.confidence_interval(0.95)
    (row,) = table_rows(result.markdown, "Comparisons")[1:]
    method = f"95 % CI, Welch t (seeds differ: 4 in one arm only; n 5 and 4), df {res.df:.1f}"
    mean, half = (ci.low + ci.high) / 2, (ci.high - ci.low) / 2
    assert row == ["all runs", "A − B", f"{mean:+.2f} ± {half:.2f}", "no", method]
    assert "1 of 1 comparisons are not paired: their series' ok seeds differ." in result.markdown
    assert "unknown: seeds differ (run the missing seeds to pair)" in result.markdown


def test_one_seed_gives_no_interval_and_says_so(tmp_path):
    result = write_report(pair_study(tmp_path / "s", {1: 3.0}, {1: 2.0}))
    md = result.markdown
    assert "| all runs | 3.00 (n=1) | 2.00 (n=1) |" in md
    assert "no interval: 1 seed in one arm" in md
    assert "One seed: no interval and no spread to estimate how many seeds are needed" in md
    assert "A; no interval (one seed) to compare with B" in md


def smallest_n(sd: float, h: float) -> int:
    """The fewest seeds whose 95 % t interval is at most h wide, counting up."""
    n = 2
    while scipy_stats.t.ppf(0.975, n - 1) * sd / math.sqrt(n) > h:
        n += 1
    return n


def test_the_replications_section_says_which_intervals_need_how_many_seeds(tmp_path):
    path = pair_study(tmp_path / "s", PAIR_A, PAIR_B)
    result = write_report(path)
    md = result.markdown
    rows = {r[1]: r for r in table_rows(md, "Replications")[1:]}
    seeds = sorted(PAIR_A)
    d = [PAIR_A[s] - PAIR_B[s] for s in seeds]
    target_a = 0.05 * statistics.mean(PAIR_A.values())
    target_b = 0.05 * statistics.mean(PAIR_B.values())
    # 5 % of the mean: each arm's spread across seeds needs many seeds...
    need_a = smallest_n(statistics.stdev(PAIR_A.values()), target_a)
    need_b = smallest_n(statistics.stdev(PAIR_B.values()), target_b)
    hw_a = T975[4] * statistics.stdev(PAIR_A.values()) / math.sqrt(5)
    assert rows["A"] == ["all runs", "A", "5", f"{hw_a:.2f}", f"{target_a:.2f}", str(need_a)]
    assert rows["B"][-1] == str(need_b)
    assert "2 of 3 intervals are wider than the target:" in md
    assert f"To meet the target: {max(need_a, need_b)} for every mean" in md
    # ...while the paired difference (target: 5 % of the leader's mean) already meets it.
    assert "A − B" not in rows
    advice = {a.series: a for a in result.summary.advice}
    assert advice["A − B"].enough and advice["A − B"].target == pytest.approx(target_a)
    assert advice["A − B"].needed == smallest_n(statistics.stdev(d), target_a) <= 5
    # An absolute target of 0.2 good parts/h: the difference now needs more seeds too.
    summary = write_report(path, tmp_path / "abs", half_width=HalfWidth(0.2, False)).summary
    verdicts = {a.series: (a.enough, a.needed) for a in summary.advice}
    need_d = smallest_n(statistics.stdev(d), 0.2)
    assert verdicts["A − B"] == (False, need_d) and need_d > 5
    assert verdicts["A"] == (False, smallest_n(statistics.stdev(PAIR_A.values()), 0.2))
    text = (tmp_path / "abs" / "report.md").read_text()
    assert "Target half-width: 0.2 good parts/h" in text
    assert f"To meet the target: {need_d} seeds for every difference to the leader" in text


def test_half_width_parses_a_share_or_good_parts_per_hour():
    assert HalfWidth.parse("5%") == HalfWidth(0.05, True)
    assert HalfWidth.parse(" 0.5 ") == HalfWidth(0.5, False)
    assert HalfWidth.parse("5%").of(20.0) == pytest.approx(1.0)
    for bad in ("", "five", "0", "-1%", "nan", "%"):
        with pytest.raises(ValueError, match="positive number"):
            HalfWidth.parse(bad)


def test_the_throughput_figure_cuts_error_bars_at_zero(tmp_path):
    summary = summarise(load_study(pair_study(tmp_path / "s", {1: 0.0, 2: 0.0, 3: 3.0},
                                              {1: 0.0, 2: 1.0, 3: 0.0})))  # fmt: skip
    (ax,) = throughput_figure(summary).axes
    bars = [c for c in ax.containers if isinstance(c, BarContainer)]
    assert bars
    lows = [
        seg[0][1] for line in ax.collections for seg in line.get_segments()
    ]  # error-bar segments: (x, low) to (x, high)
    assert min(lows) == 0.0  # the t interval would reach below zero


def test_every_panels_error_bars_fit_under_the_shared_top(tmp_path):
    """The second panel's interval reaches higher than anything in the first."""
    rows = [
        ok_row(f"c{i}", seed, good, controller="A", rate_per_h=rate, robots=robots)
        for i, (robots, rate, seed, good) in enumerate(
            [("2", "3", 1, 3.0), ("2", "3", 2, 3.0), ("2", "6", 1, 3.0), ("2", "6", 2, 3.2)]
            + [("4", "3", 1, 3.0), ("4", "3", 2, 3.1), ("4", "6", 1, 5.0), ("4", "6", 2, 6.0)]
        )
    ]
    axes = {"controller": ["A"], "rate_per_h": ["3", "6"], "robots": ["2", "4"]}
    summary = summarise(load_study(write_study(tmp_path / "s", axes, [1, 2], rows)))
    highs = [
        seg[1][1]
        for ax in throughput_figure(summary).axes
        for line in ax.collections
        for seg in line.get_segments()
    ]
    assert max(highs) > 6.0  # two seeds: a wide t interval, above every mean
    for ax in throughput_figure(summary).axes:
        assert ax.get_ylim()[0] == 0.0 and ax.get_ylim()[1] >= max(highs)


def test_released_jobs_are_compared_seed_by_seed_for_common_random_numbers(tmp_path):
    a, b = {1: 4.0, 2: 6.0}, {1: 3.0, 2: 5.5}
    path = pair_study(tmp_path / "s", a, b)
    with open(path / "results.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    header = "id,part,released_s,delivered_s,outcome\n"
    for r in rows:
        # Seed 2 of B released its second job later than seed 2 of A: not the same arrivals.
        late = r["controller"] == "B" and r["seed"] == "2"
        jobs = f"j1,prism,10.0,900.0,good\nj2,prism,{'75.5' if late else '70.0'},,\n"
        (path / "cells" / r["cell"]).mkdir(parents=True)
        (path / "cells" / r["cell"] / "jobs.csv").write_text(header + jobs)
    summary = write_report(path).summary
    assert summary.arrivals_checked == 2
    assert summary.arrivals_differ == ("all runs: A and B, seed 2",)
    assert "the released jobs differ in 1 of 2 pairs of runs (all runs: A and B, seed 2)" in (
        (path / "report.md").read_text()
    )
