"""Quality-speed profiles, vibration and print-quality prediction (`fleet.printing.quality`)."""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import box

from fleet.errors import CalibrationError
from fleet.floor.mapfile import load_spec
from fleet.floor.spec import RoughArea
from fleet.printing import PAPER_CAPS, PrintTask
from fleet.printing.quality import (
    DEFAULT_TOLERANCES,
    QSP,
    Outcome,
    QualityModel,
    TaskProfile,
    Vibration,
    check_runs,
    default_model,
    fit_qsp,
    fit_vibration,
    load_calibration,
)

REPO = Path(__file__).resolve().parents[1]
BUMP = RoughArea("bump", box(0.95, -0.6, 1.05, 0.6), 1.0)


def drive(xs0: float, speed: float, dt: float, n: int, t0: float = 0.0):
    """Samples of a robot driving along +x at constant `speed` from x = `xs0`."""
    t = t0 + dt * np.arange(n)
    xy = np.column_stack([xs0 + speed * (t - t0), np.zeros(n)])
    v = np.column_stack([np.full(n, speed), np.zeros(n)])
    return t, xy, v


def write(tmp_path: Path, text: str, name: str = "cal.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# -- fitting ----------------------------------------------------------------------------------
def test_fit_matches_a_least_squares_line_worked_by_hand():
    # |errors| = 1, 3, 2, 5 at v = 0..3: mean v 1.5, mean |e| 2.75;
    # Sxy = (-1.5)(-1.75) + (-0.5)(0.25) + (0.5)(-0.75) + (1.5)(2.25) = 5.5; Sxx = 5
    # a = 5.5 / 5 = 1.1; b = 2.75 - 1.1 * 1.5 = 1.1. Signs are dropped before fitting.
    line = fit_qsp([0.0, 1.0, 2.0, 3.0], [1.0, -3.0, 2.0, 5.0])
    assert line.a == pytest.approx(1.1)
    assert line.b == pytest.approx(1.1)


def test_fit_needs_two_distinct_speeds():
    with pytest.raises(ValueError, match="2 distinct speeds"):
        fit_qsp([0.2, 0.2], [0.01, 0.02])


def test_table1_fit_per_axis():
    profile = default_model().profile("all")
    # Height by hand: Sxx = 2 (0.25 + 0.09 + 0.01 + 0.01 + 0.09 + 0.25) = 1.4; the pairs of
    # |height| per speed sum to 0.03, 0.06, 0.13, 0.12, 0.15, 0.31, so
    # Sxy = -0.5(0.03) - 0.3(0.06) - 0.1(0.13) + 0.1(0.12) + 0.3(0.15) + 0.5(0.31) = 0.166;
    # a = 0.166 / 1.4; b = 0.80 / 12 - a * 0.5.
    assert profile.lines["height"].a == pytest.approx(0.166 / 1.4)
    assert profile.lines["height"].b == pytest.approx(0.80 / 12 - 0.5 * 0.166 / 1.4)
    assert profile.lines["width"].a == pytest.approx(0.0336, abs=5e-5)
    assert profile.lines["width"].b == pytest.approx(0.0107, abs=5e-5)
    assert profile.lines["depth"].a == pytest.approx(-0.0079, abs=5e-5)
    assert profile.lines["depth"].b == pytest.approx(0.0364, abs=5e-5)
    # The height line sets the cap: (0.05 - b) / a.
    assert profile.max_speed(0.05) == pytest.approx(0.359, abs=5e-4)
    # The profile is the largest axis: depth at rest, height when fast.
    assert profile.error(0.0) == pytest.approx(profile.lines["depth"].b)
    assert profile.worst_axis(0.0) == "depth" and profile.worst_axis(1.0) == "height"


def test_every_kind_uses_the_all_profile_when_table1_has_no_task_column():
    model = default_model()
    caps = model.caps()
    assert caps["contour"] == caps["infill"] == caps["support"] == pytest.approx(0.3594, abs=1e-4)
    assert math.isinf(caps["travel"])  # travel has no tolerance


# -- max speed and tolerances -----------------------------------------------------------------
def test_max_speed_edge_cases():
    assert QSP(0.1, 0.01).max_speed(0.05) == pytest.approx(0.4)
    assert QSP(0.1, 0.05).max_speed(0.05) == 0.0  # exactly at tolerance at rest
    assert QSP(0.1, 0.06).max_speed(0.05) == 0.0  # standing still is already too poor
    assert math.isinf(QSP(0.0, 0.01).max_speed(0.05))  # flat: never exceeded
    assert math.isinf(QSP(-0.1, 0.01).max_speed(0.05))  # falling: never exceeded
    assert QSP(-0.1, 0.06).max_speed(0.05) == 0.0  # falling, but too poor at rest
    assert math.isinf(QSP(0.1, 0.01).max_speed(math.inf))
    with pytest.raises(ValueError, match="tolerance"):
        QSP(0.1, 0.01).max_speed(-0.01)
    # A profile caps at its tightest line, and at 0 when any line is too poor at rest.
    profile = TaskProfile({"x": QSP(0.1, 0.01), "y": QSP(0.2, 0.0), "z": QSP(-1.0, 0.02)})
    assert profile.max_speed(0.05) == pytest.approx(0.25)
    assert TaskProfile({"x": QSP(0.1, 0.0), "y": QSP(-1, 0.06)}).max_speed(0.05) == 0.0


def test_tolerance_implied_by_the_papers_caps():
    model = default_model()
    height = model.profile("all").lines["height"]
    implied = model.implied_tolerances(PAPER_CAPS)
    assert implied["contour"] == pytest.approx(height.a * 0.3 + height.b)
    assert implied["contour"] == pytest.approx(0.0430, abs=5e-5)
    assert implied["infill"] == pytest.approx(0.0667, abs=5e-5)
    assert implied["support"] == pytest.approx(0.0904, abs=5e-5)
    # Those tolerances give the paper's caps back.
    caps = model.caps(implied)
    for kind, cap in PAPER_CAPS.items():
        assert caps[kind] == pytest.approx(cap)


@settings(max_examples=60, deadline=None)
@given(
    a=st.floats(1e-3, 1.0),
    b=st.floats(0.0, 0.05),
    cap=st.floats(0.0, 2.0),
)
def test_caps_and_implied_tolerances_are_inverse(a, b, cap):
    line = QSP(a, b)
    assert line.max_speed(float(line.error(cap))) == pytest.approx(cap, abs=1e-9)


# -- vibration --------------------------------------------------------------------------------
def test_kick_grows_exponentially_with_speed_and_scales_with_severity():
    vib = Vibration(coef_mm=0.001, rate_per_mps=10.0, failure_mm=1.0)
    assert vib.kick(0.5) == pytest.approx(0.001 * math.exp(5.0))
    assert vib.kick(0.5, severity=0.3) == pytest.approx(0.3 * 0.001 * math.exp(5.0))
    assert vib.kick(0.0) == pytest.approx(0.001)


def test_table2_vibration_fit():
    model = default_model()
    vib = model.vibration
    assert vib.rate_per_mps == pytest.approx(11.42, abs=0.01)
    assert vib.coef_mm == pytest.approx(7.32e-4, rel=1e-3)
    assert vib.failure_mm == pytest.approx(2.19, abs=0.01)
    # Between the largest error a part survived (0.71 mm) and the smallest fatal kick (0.8 m/s).
    assert 0.71 < vib.failure_mm < vib.kick(0.8)


def test_the_model_reproduces_every_table2_outcome_with_the_mean_metric():
    checks = {c.run: c for c in check_runs(default_model())}
    expected = {"pass": "good", "defect": "defective", "fail": "failed"}
    for c in checks.values():
        assert c.predicted == expected[c.outcome], c.run
    # The varying strategy drives 0.8 m/s on flat floor: its top speed alone would fail it.
    assert checks["varying"].mean_speed == pytest.approx(318 / 1200)
    assert checks["varying"].predicted_max == Outcome.DEFECTIVE


def test_vibration_fit_without_failed_runs_never_fails(tmp_path):
    runs = write(
        tmp_path,
        "run,speed_mps,crossing_mps,distance_m,turn_rad,print_s,outcome\n"
        "a,0.2,0.2,100,,1000,pass\nb,0.6,0.6,300,,1000,defect\n",
        "runs.csv",
    )
    errors = write(tmp_path, "run,sample,axis,error_mm\na,1,x,0.02\nb,1,x,-0.5\n", "err.csv")
    flat = TaskProfile({"x": QSP(0.0, 0.01)})
    vib = fit_vibration(runs, errors, flat)
    # Two points: ln(0.01) at 0.2 and ln(0.49) at 0.6, so k = ln(49) / 0.4.
    assert vib.rate_per_mps == pytest.approx(math.log(49) / 0.4)
    assert vib.kick(0.2) == pytest.approx(0.01)
    assert math.isinf(vib.failure_mm)


# -- prediction -------------------------------------------------------------------------------
def test_a_ten_cm_bump_jumped_over_in_one_step_is_still_crossed():
    t, xy, v = drive(0.1, 1.0, 0.25, 8)  # x = 0.1, 0.35, 0.6, 0.85, 1.1, ...
    assert not np.any((xy[:, 0] >= 0.95) & (xy[:, 0] <= 1.05))  # no sample on the bump
    pred = default_model().predict([PrintTask("infill", 0.0, 1.75)], t, xy, v, [BUMP])
    assert len(pred.crossings) == 1
    c = pred.crossings[0]
    assert (c.area, c.start_s, c.end_s, c.speed) == ("bump", 0.75, 1.0, 1.0)
    assert c.kick_mm == pytest.approx(default_model().vibration.kick(1.0))


def test_consecutive_segments_on_an_area_make_one_crossing_at_their_top_speed():
    slow = RoughArea("slow", box(0.5, -1.0, 1.5, 1.0), 0.3)
    t = np.arange(6) * 0.5
    x = np.array([0.0, 0.4, 0.7, 1.0, 1.6, 2.0])
    v = np.column_stack([np.diff(x, append=2.4) / 0.5, np.zeros(6)])
    pred = default_model().predict(
        [PrintTask("support", 0.0, 3.0)], t, np.column_stack([x, np.zeros(6)]), v, [slow]
    )
    # Segments 1 (0.4->0.7), 2 (0.7->1.0) and 3 (1.0->1.6) touch the area: one crossing.
    assert len(pred.crossings) == 1
    c = pred.crossings[0]
    assert (c.start_s, c.end_s) == (0.5, 2.0)
    assert c.speed == pytest.approx(1.2)  # segment 3: 0.6 m in 0.5 s
    assert c.kick_mm == pytest.approx(default_model().vibration.kick(1.2, 0.3))


def test_mean_speed_counts_standing_still_and_max_does_not():
    # 0.4 m/s for 10 s, then standing still for 10 s; samples every 0.5 s.
    t = np.arange(41) * 0.5
    speed = np.where(t < 10.0, 0.4, 0.0)
    v = np.column_stack([speed, np.zeros_like(t)])
    xy = np.column_stack([np.cumsum(np.concatenate([[0.0], speed[:-1] * 0.5])), np.zeros_like(t)])
    task = [PrintTask("contour", 0.0, 20.0)]
    mean = default_model().predict(task, t, xy, v)
    assert mean.tasks[0].speed == pytest.approx(0.2)
    assert mean.tasks[0].qsp_mm == pytest.approx(default_model().profile("contour").error(0.2))
    model_max = QualityModel(
        default_model().profiles, vibration=default_model().vibration, speed_metric="max"
    )
    assert model_max.predict(task, t, xy, v).tasks[0].speed == pytest.approx(0.4)
    # A task ending mid-sample weighs the sample by the part it covers: [9.75, 10.5) holds
    # 0.4 for 0.25 s and 0 for 0.5 s.
    part = default_model().predict([PrintTask("contour", 9.75, 10.5)], t, xy, v)
    assert part.tasks[0].speed == pytest.approx(0.4 * 0.25 / 0.75)


def test_a_bump_crossed_too_fast_spoils_the_print_and_slowly_passes():
    model = default_model()
    areas = load_spec(REPO / "maps" / "bump_track.toml").rough_areas
    bump_1 = next(a for a in areas if a.name == "bump_1")
    results = {}
    for speed in (0.2, 0.6, 0.8):
        dt = 0.25
        n = int(round(2.0 / (speed * dt))) + 1  # x from 0 to 2 m across bump_1 and bump_2
        t, xy, v = drive(0.0, speed, dt, n)
        results[speed] = model.predict([PrintTask("infill", 0.0, float(t[-1]))], t, xy, v, [bump_1])
    assert results[0.2].outcome == Outcome.GOOD and results[0.2].passed
    assert results[0.6].outcome == Outcome.DEFECTIVE and not results[0.6].passed
    assert results[0.8].outcome == Outcome.FAILED and not results[0.8].passed
    assert results[0.6].tasks[0].vibration_mm == pytest.approx(model.vibration.kick(0.6))
    assert results[0.2].error_mm == pytest.approx(
        model.profile("infill").error(0.2) + model.vibration.kick(0.2)
    )


def test_the_same_path_judged_by_task_and_only_within_the_print():
    model = default_model()
    # 0.3 m/s (within the 0.359 m/s cap): the segments from t = 3.0 to 3.5 enter the bump;
    # the next one only starts on its edge (touching is not crossing).
    t, xy, v = drive(0.0, 0.3, 0.25, 21)
    tasks = [PrintTask("support", 0.0, 2.5), PrintTask("contour", 2.5, 5.0)]
    pred = model.predict(tasks, t, xy, v, [BUMP])
    support, contour = pred.tasks
    assert support.vibration_mm == 0.0 and support.passed
    assert [(c.start_s, c.end_s) for c in pred.crossings] == [(3.0, 3.5)]
    assert contour.vibration_mm == pytest.approx(model.vibration.kick(0.3))
    assert not contour.passed and pred.outcome == Outcome.DEFECTIVE
    assert pred.error_mm == contour.error_mm
    # Printing ends before the bump: the crossing is not part of the print.
    early = model.predict([PrintTask("contour", 0.0, 2.5)], t, xy, v, [BUMP])
    assert early.crossings == () and early.passed
    # Nozzle travel has no tolerance, but a fatal crossing during travel still fails the print.
    t, xy, v = drive(0.0, 1.0, 0.25, 9)
    travel = model.predict([PrintTask("travel", 0.0, 2.0)], t, xy, v, [BUMP])
    assert travel.tasks[0].tolerance_mm == math.inf
    assert travel.outcome == Outcome.FAILED


def test_a_print_without_tasks_passes():
    t, xy, v = drive(0.0, 1.0, 0.25, 9)
    pred = default_model().predict([], t, xy, v, [BUMP])
    assert pred.passed and pred.outcome == "good" and pred.error_mm == 0.0
    assert pred.tasks == () and pred.crossings == ()


def test_bad_samples_and_options_are_refused():
    t, xy, v = drive(0.0, 1.0, 0.25, 9)
    with pytest.raises(ValueError, match=r"\(9, 2\)"):
        default_model().predict([PrintTask("infill", 0.0, 1.0)], t, xy[:5], v)
    with pytest.raises(ValueError, match="must not be before"):
        default_model().predict([PrintTask("infill", 1.0, 0.5)], t, xy, v)
    with pytest.raises(ValueError, match="speed_metric"):
        QualityModel(default_model().profiles, speed_metric="median")
    with pytest.raises(ValueError, match="'contour'"):
        QualityModel(default_model().profiles, {"contour": -0.1})


# -- calibration files ------------------------------------------------------------------------
def test_user_calibration_per_task_and_axis_with_all_as_fallback(tmp_path):
    path = write(
        tmp_path,
        "task,axis,speed_mps,error_mm\n"
        "contour,x,0,0.01\ncontour,x,1,0.11\n"
        "contour,y,0,0.03\ncontour,y,1,0.03\n"
        "all,,0,0.0\nall,,1,-0.05\n",
    )
    profiles = load_calibration(path)
    assert set(profiles) == {"contour", "all"}
    model = QualityModel.from_csv(path, tolerances={"contour": 0.06})
    contour = model.profile("contour")
    assert contour.error(0.0) == pytest.approx(0.03)  # y is the larger line at rest
    assert contour.error(1.0) == pytest.approx(0.11)  # x when fast
    assert model.caps()["contour"] == pytest.approx(0.5)  # (0.06 - 0.01) / 0.1
    assert model.profile("infill") is model.profiles["all"]
    assert model.caps()["infill"] == pytest.approx(1.0)  # 0.05 mm default at 0.05 mm per m/s
    assert model.tolerance("infill") == DEFAULT_TOLERANCES["infill"] == 0.05


@pytest.mark.parametrize(
    ("text", "field", "value", "rule"),
    [
        ("speed,error_mm\n0,0.1\n", "header (row 1)", "['speed', 'error_mm']", "speed_mps"),
        ("speed_mps,error_mm,colour\n0,1,red\n", "header (row 1)", "colour", "allowed"),
        ("speed_mps,error_mm\n0,0.1\nfast,0.2\n", "row 3 column speed_mps", "'fast'", "m/s"),
        ("speed_mps,error_mm\n0,0.1\n0.2,\n", "row 3 column error_mm", "''", "mm"),
        ("speed_mps,error_mm\n-0.2,0.1\n0.2,0.1\n", "row 2 column speed_mps", "'-0.2'", ">= 0"),
        ("speed_mps,error_mm\n0,nan\n0.2,0.1\n", "row 2 column error_mm", "'nan'", "mm"),
        ("task,speed_mps,error_mm\nwall,0,0.1\n", "row 2 column task", "'wall'", "contour"),
        (
            "axis,speed_mps,error_mm\nx,0,0.1\nx,0.2,0.1\ny,0.2,0.1\ny,0.2,0.3\n",
            "(task all, axis y: rows 4, 5)",
            "[0.2]",
            "2 or more distinct speeds",
        ),
        ("speed_mps,error_mm\n", "(file)", "", "no rows"),
    ],
)
def test_bad_calibration_files_name_file_row_column_and_value(tmp_path, text, field, value, rule):
    path = write(tmp_path, text)
    with pytest.raises(CalibrationError) as err:
        load_calibration(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ")
    assert field in err.value.field
    assert value in message
    assert rule in err.value.rule


def test_a_missing_calibration_file_is_named(tmp_path):
    path = tmp_path / "nope.csv"
    with pytest.raises(CalibrationError, match="no such file") as err:
        QualityModel.from_csv(path)
    assert err.value.source == str(path) and err.value.field == "(file)"


def test_bad_vibration_files_are_named(tmp_path):
    header = "run,speed_mps,crossing_mps,distance_m,turn_rad,print_s,outcome\n"
    runs = write(tmp_path, header + "a,0.2,0.2,100,,1000,pass\nb,0.9,0.9,,,1000,crashed\n", "r.csv")
    errors = write(tmp_path, "run,sample,axis,error_mm\na,1,x,0.02\n", "e.csv")
    with pytest.raises(CalibrationError, match="row 3 column outcome = 'crashed'"):
        fit_vibration(runs, errors, default_model().profile("all"))
    runs = write(tmp_path, header + "a,0.2,0.2,100,,1000,pass\nb,0.9,0.9,,,1000,fail\n", "r.csv")
    errors = write(tmp_path, "run,sample,axis,error_mm\na,1,x,0.02\nb,1,x,0.5\n", "e.csv")
    with pytest.raises(CalibrationError, match="row 3 column run = 'b': is a failed run"):
        fit_vibration(runs, errors, default_model().profile("all"))
    errors = write(tmp_path, "run,sample,axis,error_mm\na,1,x,0.02\n", "e.csv")
    with pytest.raises(CalibrationError, match="column crossing_mps"):
        fit_vibration(runs, errors, TaskProfile({"x": QSP(0.0, 0.0)}))


# -- the script -------------------------------------------------------------------------------
def test_paper_case1_script_prints_the_fits_and_draws_the_profile(tmp_path):
    out = tmp_path / "case1"
    done = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "paper_case1.py"), "--out", str(out)],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    assert "0.1186" in done.stdout and "0.359" in done.stdout
    assert "varying" in done.stdout
    png = out / "qsp.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    fit = (out / "table2_fit.csv").read_text().splitlines()
    assert fit[0].startswith("run,paper_outcome") and len(fit) == 7
