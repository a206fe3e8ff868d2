"""Print strategies for throughput studies: print first, fixed speed, the QSP rule; advisory
caps and caps from the quality model; what the run directory records of plans and tasks."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from fleet.errors import PluginError, ScenarioError
from fleet.plugins import load_controller
from fleet.printing.quality import default_model
from fleet.scenario import load_scenario
from tests.test_print_jobs import run, track_scenario

TWO_TASKS = (
    'print = [{ kind = "contour", start_s = 0, end_s = 20 },'
    ' { kind = "support", start_s = 20, end_s = 60 }]\n'
)
PAPER_CAPS = "[print]\ncaps = { contour = 0.3, infill = 0.5, support = 0.7 }\n"


def controller(name: str, options: str = "") -> str:
    table = f"[controller]\nname = {name!r}\n"
    return table + (f"[controller.options]\n{options}\n" if options else "")


def samples(world, robot: str = "r01"):
    t, xy, v = world.recorder.trajectories[robot].arrays()
    return t, xy, np.abs(v).max(axis=1)


def test_print_first_stands_while_the_print_lasts_then_drives_at_full_speed(tmp_path):
    body = 'print = [{ kind = "contour", start_s = 0, end_s = 30 }]\n'
    path = track_scenario(tmp_path, body, extra=controller("print_first") + PAPER_CAPS)
    world, result = run(path)
    t, xy, speed = samples(world)
    printing = t < 30.0 - 1e-9
    assert speed[printing].max() == 0.0
    assert np.allclose(xy[printing], xy[0])
    # Then the trip at the robot's own limit (1 m/s), no print cap left to respect.
    assert speed[~printing].max() == pytest.approx(1.0, abs=0.02)
    rec = result.jobs[0]
    assert rec.delivered_s is not None and rec.delivered_s > 30.0 + 18.0
    assert rec.quality.outcome == "good"  # printed standing: the QSP's error at rest
    assert rec.quality.error_mm == pytest.approx(default_model().profile("contour").error(0.0))


def test_fixed_speed_ignores_advisory_caps_and_its_parts_are_judged(tmp_path):
    body = 'print = [{ kind = "contour", start_s = 0, end_s = 100 }]\n'
    advice = PAPER_CAPS + "enforce = false\n"
    path = track_scenario(tmp_path, body, extra=controller("fixed_speed", "speed = 0.4") + advice)
    world, result = run(path)
    _, _, speed = samples(world)
    assert speed.max() == pytest.approx(0.4, abs=0.01)  # above the contour's 0.3 advice
    assert speed.max() <= 0.4 + 1e-9
    s = result.summary
    assert s["print_caps"] == {
        "caps": {"contour": 0.3, "infill": 0.5, "support": 0.7},
        "enforced": False,
    }
    assert s["violations"]["print_speed"] == 0  # advice is not a limit
    assert result.jobs[0].quality.outcome == "defective"  # 0.4 m/s spoils a 0.05 mm contour


def test_fixed_speed_breaks_enforced_caps_and_the_checker_says_so(tmp_path):
    body = 'print = [{ kind = "contour", start_s = 0, end_s = 100 }]\n'
    path = track_scenario(
        tmp_path, body, extra=controller("fixed_speed", "speed = 0.4") + PAPER_CAPS
    )
    _, result = run(path)
    assert result.summary["print_caps"]["enforced"] is True
    assert result.summary["violations"]["print_speed"] > 0


def test_qsp_rule_drives_each_task_at_its_own_cap_where_the_follower_waits(tmp_path):
    # Support (0.7 m/s) first, then a contour (0.3 m/s) from 30 s.
    tasks = (
        'print = [{ kind = "support", start_s = 0, end_s = 30 },'
        ' { kind = "contour", start_s = 30, end_s = 60 }]\n'
    )
    speeds = {}
    for name in ("follower", "qsp_speed"):
        path = track_scenario(tmp_path, tasks, extra=controller(name) + PAPER_CAPS, bump=False)
        world, result = run(path)
        assert result.summary["violations"]["print_speed"] == 0, result.safety.examples
        t, _, speed = samples(world)
        speeds[name] = (t, speed)
    t, speed = speeds["qsp_speed"]
    assert speed[t < 25.0].max() == pytest.approx(0.7, abs=0.01)
    assert speed[t >= 30.0].max() <= 0.3 + 1e-9
    # The follower plans at the tightest cap of its whole look-ahead minute: the contour's.
    t, speed = speeds["follower"]
    assert speed.max() <= 0.3 + 1e-9


def test_qsp_rule_crosses_rough_floor_slowly(tmp_path):
    body = 'print = [{ kind = "support", start_s = 0, end_s = 100 }]\n'
    path = track_scenario(tmp_path, body, extra=controller("qsp_speed") + PAPER_CAPS)
    world, result = run(path)
    t, xy, speed = samples(world)
    on_bump = (xy[:, 0] > 9.95 + 1e-6) & (xy[:, 0] < 10.05 - 1e-6)
    assert on_bump.any()
    assert speed[on_bump].max() <= 0.2 + 1e-9
    assert speed.max() == pytest.approx(0.7, abs=0.01)  # elsewhere at the support cap
    assert result.jobs[0].quality.outcome == "good"


def test_print_caps_from_the_quality_model(tmp_path):
    extra = (
        '[print]\ncaps = "quality"\n'
        "[quality]\ntolerance_mm = { contour = 0.05, infill = 0.08, support = 0.1 }\n"
    )
    scenario = load_scenario(track_scenario(tmp_path, TWO_TASKS, extra=extra))
    model = default_model()
    assert set(scenario.print_caps) == {"contour", "infill", "support"}  # travel, other: none
    for kind, tol in (("contour", 0.05), ("infill", 0.08), ("support", 0.1)):
        assert scenario.print_caps[kind] == pytest.approx(model.profile(kind).max_speed(tol))
        assert model.profile(kind).error(scenario.print_caps[kind]) == pytest.approx(tol)
    assert scenario.enforce_print_caps is True


@pytest.mark.parametrize(
    ("extra", "field", "value"),
    [
        ('[print]\ncaps = "qsp"\n', "print.caps", "qsp"),
        ("[print]\nenforce = 1\n", "print.enforce", "1"),
    ],
)
def test_bad_print_cap_settings_are_named(tmp_path, extra, field, value):
    path = track_scenario(tmp_path, TWO_TASKS, extra=extra)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert str(path) in str(err.value) and field in str(err.value) and value in str(err.value)


@pytest.mark.parametrize(
    ("name", "options", "words"),
    [
        ("fixed_speed", {"speed": -0.2}, "speed = -0.2: must be a positive number"),
        ("fixed_speed", {}, "speed"),
        ("follower", {"caps": "sometimes"}, "caps = 'sometimes': must be one of"),
        ("follower", {"print_first": "yes"}, "print_first = 'yes': must be true or false"),
        ("qsp_speed", {"rough_v_max": math.inf}, "rough_v_max = inf: must be a positive"),
    ],
)
def test_strategy_options_are_checked(name, options, words):
    with pytest.raises(PluginError, match=words.replace("(", r"\(")):
        load_controller(name, options)


def test_run_directory_records_print_tasks_and_planned_horizons(tmp_path):
    path = track_scenario(tmp_path, TWO_TASKS, extra=PAPER_CAPS, bump=False)
    world, result = run(path)
    out = tmp_path / "out"
    world.write(out)
    tasks = list(csv.DictReader((out / "tasks.csv").open()))
    start = result.jobs[0].print_start_s
    assert [(r["kind"], float(r["start_s"]), float(r["end_s"])) for r in tasks] == [
        ("contour", pytest.approx(start), pytest.approx(start + 20.0)),
        ("support", pytest.approx(start + 20.0), pytest.approx(start + 60.0)),
    ]
    plans = list(csv.DictReader((out / "plans.csv").open()))
    assert plans and {r["robot"] for r in plans} == {"r01"}
    sent = sorted({float(r["t_sent"]) for r in plans})
    assert min(np.diff(sent)) >= 1.0 - 1e-9  # at most one kept per second
    for when in sent:
        times = [float(r["t"]) for r in plans if float(r["t_sent"]) == when]
        assert len(times) <= 2 or min(np.diff(times[:-1])) >= 0.5 - 1e-9
    # A plan's samples start where it was sent and lie on the robot's later path.
    t, xy, _ = samples(world)
    for row in plans:
        assert float(row["t"]) >= float(row["t_sent"]) - 1e-9
        assert 1.0 - 1e-6 <= float(row["x"]) <= 19.0 + 1e-6
