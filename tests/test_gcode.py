"""G-code analysis: real slicer files become timed, classified, merged print tasks."""

from __future__ import annotations

import doctest
import json
import logging
import math
import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import fleet.printing.gcode.analysis
from fleet.cli import main
from fleet.errors import GcodeError
from fleet.printing import PAPER_CAPS, TASK_KINDS, PrintSchedule
from fleet.printing.gcode import FEATURE_KINDS, STRICTNESS, GcodeTask, analyze
from fleet.printing.gcode.parse import EXTRUDE, OTHER, TRAVEL, read_program
from fleet.printing.gcode.tasks import merge
from fleet.scenario import REPO_ROOT

PARTS = REPO_ROOT / "parts"
PRISM = PARTS / "prism_40x20x2.gcode"
T_PRUSA = PARTS / "t_overhang_support.gcode"
CUBE = PARTS / "cube_30_gyroid20.gcode"
T_CURA = PARTS / "t_overhang_cura.gcode"
FIXTURES = [PRISM, T_PRUSA, CUBE, T_CURA]
RANK = {k: i for i, k in enumerate(STRICTNESS)}

_cache: dict[Path, fleet.printing.gcode.GcodeAnalysis] = {}


def analysis(path: Path) -> fleet.printing.gcode.GcodeAnalysis:
    """Each fixture is analysed once per test session (the analysis is pure)."""
    if path not in _cache:
        _cache[path] = analyze(path)
    return _cache[path]


def write(tmp_path: Path, text: str, name: str = "part.gcode") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# --- real fixtures ------------------------------------------------------------------------------


@pytest.mark.parametrize("path", FIXTURES, ids=lambda p: p.stem)
def test_time_agrees_with_the_slicers_own_estimate(path: Path) -> None:
    a = analysis(path)
    assert a.slicer_estimate_s is not None
    assert 0.9 <= a.total_s / a.slicer_estimate_s <= 1.1
    assert a.estimate_ratio == pytest.approx(a.total_s / a.slicer_estimate_s)


@pytest.mark.parametrize("path", FIXTURES, ids=lambda p: p.stem)
def test_tasks_are_contiguous_long_enough_and_cover_the_print(path: Path) -> None:
    a = analysis(path)
    assert a.tasks[0].start_s == 0.0
    assert a.tasks[-1].end_s == pytest.approx(a.total_s)
    assert sum(a.by_kind_s.values()) == pytest.approx(a.total_s)
    for before, after in zip(a.tasks, a.tasks[1:], strict=False):
        assert after.start_s == before.end_s
        assert after.kind != before.kind
        assert after.layer >= before.layer
    assert all(t.duration_s >= a.min_task_s for t in a.tasks) or len(a.tasks) == 1
    assert {t.kind for t in a.tasks} <= set(TASK_KINDS)
    schedule = PrintSchedule(a.print_tasks(), PAPER_CAPS)
    assert schedule.duration_s == pytest.approx(a.total_s)


def test_prism_is_the_papers_twenty_minute_part() -> None:
    a = analysis(PRISM)
    assert a.slicer == "PrusaSlicer 2.5.0"
    assert a.layers == 182  # 0.2 mm, then 0.22 mm layers to 40 mm
    assert 18 * 60 <= a.slicer_estimate_s <= 23 * 60
    assert a.by_kind_s["support"] == 0.0
    # A 2 mm wall is all perimeters: outer ones are contour, inner ones infill.
    assert a.by_kind_s["contour"] > 0.3 * a.total_s
    assert a.by_kind_s["infill"] > 0.3 * a.total_s
    # No stretch of it lasts 10 s, so the whole print runs under the contour cap.
    assert [t.kind for t in a.tasks] == ["contour"]


@pytest.mark.parametrize("path", [T_PRUSA, T_CURA], ids=lambda p: p.stem)
def test_overhanging_t_prints_support(path: Path) -> None:
    a = analysis(path)
    assert a.by_kind_s["support"] > 0.2 * a.total_s
    assert a.by_kind_s["contour"] > 0.05 * a.total_s


def test_cube_is_mostly_infill() -> None:
    a = analysis(CUBE)
    assert a.by_kind_s["infill"] > 0.6 * a.total_s
    assert a.by_kind_s["support"] == 0.0
    assert a.layers == 100
    assert "infill" in {t.kind for t in a.tasks} and "contour" in {t.kind for t in a.tasks}


def test_cura_fixture_is_read_as_cura() -> None:
    a = analysis(T_CURA)
    assert a.slicer == "Cura 4.13.0"
    assert a.layers == 125
    # CuraEngine from the command line leaves ";TIME:6666"; its last ;TIME_ELAPSED is used.
    assert a.slicer_estimate_s == pytest.approx(2248.247847)


def test_features_of_a_real_file_take_their_table_kind() -> None:
    program = read_program(T_PRUSA)
    names = {n.lower() for n in program.features}
    assert {"external perimeter", "perimeter", "support material", "internal infill"} <= names
    assert all(n in FEATURE_KINDS for n in names)
    assert FEATURE_KINDS["external perimeter"] == "contour"
    assert FEATURE_KINDS["support material interface"] == "support"
    assert FEATURE_KINDS["wall-inner"] == "infill"
    assert FEATURE_KINDS["skirt/brim"] == "other"
    assert set(FEATURE_KINDS.values()) <= set(TASK_KINDS) - {"travel"}


def test_override_merges_over_the_table_case_insensitively() -> None:
    base = analysis(T_PRUSA)
    a = analyze(
        T_PRUSA,
        classification={"support MATERIAL": "contour", "Support material interface": "contour"},
    )
    assert a.by_kind_s["support"] == 0.0
    assert a.by_kind_s["contour"] == pytest.approx(
        base.by_kind_s["contour"] + base.by_kind_s["support"]
    )
    assert a.total_s == pytest.approx(base.total_s)
    assert FEATURE_KINDS["support material"] == "support"  # the default table is untouched


def test_override_to_an_unknown_kind_is_refused() -> None:
    with pytest.raises(GcodeError, match=r"classification\['Gap fill'\] = 'fast'.*contour"):
        analyze(PRISM, classification={"Gap fill": "fast"})


def test_min_task_zero_keeps_every_segment() -> None:
    a = analyze(PRISM, min_task_s=0)
    assert len(a.tasks) > 1000
    assert a.by_kind_s == analysis(PRISM).by_kind_s


def test_unknown_features_warn_once_and_count_as_other(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    text = PRISM.read_text()
    text = text.replace(";TYPE:Perimeter", ";TYPE:Fancy wall").replace(
        ";TYPE:Skirt/Brim", ";TYPE:Mystery"
    )
    with caplog.at_level(logging.WARNING, logger="fleet.printing.gcode"):
        a = analyze(write(tmp_path, text))
    records = [r for r in caplog.records if r.name == "fleet.printing.gcode"]
    assert len(records) == 1
    assert "'Fancy wall'" in records[0].message and "'Mystery'" in records[0].message
    assert a.warnings == (records[0].message,)
    assert a.by_kind_s["infill"] == 0.0
    assert a.by_kind_s["other"] > analysis(PRISM).by_kind_s["infill"]


# --- bad input ----------------------------------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "absent.gcode"
    with pytest.raises(GcodeError, match=r"absent\.gcode: \(file\) = .*must exist"):
        analyze(path)


def test_binary_file(tmp_path: Path) -> None:
    path = tmp_path / "part.gcode"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 10)
    with pytest.raises(GcodeError, match=r"part\.gcode: \(file\) = .*binary, not G-code"):
        analyze(path)


def test_binary_gcode_is_named(tmp_path: Path) -> None:
    path = tmp_path / "part.bgcode"
    path.write_bytes(b"GCDE\x01\x00\x00\x00" + b"\x00" * 64)
    with pytest.raises(GcodeError, match=r"\(file\) = 'GCDE'.*export plain-text G-code"):
        analyze(path)


def test_text_that_is_not_gcode(tmp_path: Path) -> None:
    path = write(tmp_path, "# notes\n\nThe prism is 40 mm high.\nPrint it slowly.\n", "notes.txt")
    with pytest.raises(GcodeError, match=r"notes\.txt: line 1 = '# notes': not G-code"):
        analyze(path)


def test_comments_only(tmp_path: Path) -> None:
    with pytest.raises(GcodeError, match=r"\(file\) = '2 lines': .*no G or M command"):
        analyze(write(tmp_path, "; one\n; two\n"))


def test_truncated_prusaslicer_file(tmp_path: Path) -> None:
    lines = PRISM.read_text().split("\n")
    path = write(tmp_path, "\n".join(lines[: len(lines) // 2]) + "\n")
    with pytest.raises(
        GcodeError,
        match=r"\(file\) = '\d+ lines': the file looks truncated: PrusaSlicer 2\.5\.0 "
        r"ends its files with '; prusaslicer_config = end'",
    ):
        analyze(path)


def test_truncated_cura_file(tmp_path: Path) -> None:
    text = T_CURA.read_text().replace(";End of Gcode", "")
    with pytest.raises(GcodeError, match=r"truncated: Cura 4\.13\.0 ends its files with "):
        analyze(write(tmp_path, text))


def test_last_line_cut_mid_command(tmp_path: Path) -> None:
    text = "G90\nM82\nG92 E0\nG1 X10 Y10 F3000\nG1 X20 Y10 E1.5\nG1 X20 Y"
    with pytest.raises(GcodeError, match=r"line 6 = 'G1 X20 Y': .*truncated.*cut mid-command"):
        analyze(write(tmp_path, text))


def test_bad_number_names_the_line(tmp_path: Path) -> None:
    lines = PRISM.read_text().split("\n")
    k = next(i for i, ln in enumerate(lines) if ln.startswith("G1 X") and i > 500)
    lines[k] = "G1 X1..2 Y105 E0.5"
    with pytest.raises(GcodeError, match=rf"line {k + 1} = 'G1 X1\.\.2 Y105 E0\.5': each word"):
        analyze(write(tmp_path, "\n".join(lines)))


def test_no_extrusion(tmp_path: Path) -> None:
    text = "G28\nG90\nG1 Z5 F600\nG1 X10 Y10 F3000\nG1 X50 Y10\nG1 E-1\n"
    with pytest.raises(GcodeError, match=r"\(file\) = '4 moves': the file extrudes nothing"):
        analyze(write(tmp_path, text))


def test_bad_min_task(tmp_path: Path) -> None:
    with pytest.raises(GcodeError, match=r"min_task_s = -1.0: a finite number"):
        analyze(PRISM, min_task_s=-1.0)


# --- parsing and timing on hand-written G-code --------------------------------------------------

LIMITS = "M201 X1000 Y1000 Z200 E5000\nM203 X200 Y200 Z12 E120\nM204 P1000 R1000 T1000\n"
JERK = "M205 X10 Y10 Z0.4 E5\n"


def test_a_single_move_is_a_trapezoid(tmp_path: Path) -> None:
    # From rest, 100 mm at 100 mm/s with a = 1000 and jerk 10: start and end at the safe
    # speed 10 mm/s, ramps of (100^2 - 10^2) / 2000 = 4.95 mm taking 0.09 s each.
    a = analyze(write(tmp_path, LIMITS + JERK + "G92 E0\nG1 X100 E5 F6000\n"))
    assert a.total_s == pytest.approx(2 * 0.09 + (100 - 2 * 4.95) / 100)
    assert a.by_kind_s["infill"] == 0.0 and a.by_kind_s["other"] == pytest.approx(a.total_s)


def test_a_straight_junction_keeps_speed_and_a_reversal_stops(tmp_path: Path) -> None:
    one = analyze(write(tmp_path, LIMITS + JERK + "G1 X100 E5 F6000\n", "a.gcode")).total_s
    two = analyze(write(tmp_path, LIMITS + JERK + "G1 X50 E2.5 F6000\nG1 X100 E5\n", "b.gcode"))
    assert two.total_s == pytest.approx(one)
    back = analyze(write(tmp_path, LIMITS + JERK + "G1 X50 E2.5 F6000\nG1 X0 E5\n", "c.gcode"))
    # 50 mm each way, each from and to the safe speed: ramps 4.95 mm, 0.09 s.
    assert back.total_s == pytest.approx(2 * (2 * 0.09 + (50 - 2 * 4.95) / 100))


def test_junction_deviation_slows_corners_not_straights(tmp_path: Path) -> None:
    jd = LIMITS + "M205 J0.02 E5\n"
    straight = analyze(write(tmp_path, jd + "G1 X50 E2.5 F6000\nG1 X100 E5\n", "s.gcode"))
    corner = analyze(write(tmp_path, jd + "G1 X50 E2.5 F6000\nG1 X50 Y50 E5\n", "c.gcode"))
    assert corner.total_s > straight.total_s
    # Through a right angle: v = sqrt(a J s / (1 - s)), s = sin(45 deg).
    s = math.sin(math.pi / 4)
    v = math.sqrt(1000 * 0.02 * s / (1 - s))
    assert 5 < v < 10
    ramp = (100**2 - v**2) / 2000
    expected = 2 * ((100 - 10) / 1000 + (100 - v) / 1000 + (50 - 4.95 - ramp) / 100)
    assert corner.total_s == pytest.approx(expected)


def test_feedrate_is_capped_by_m203(tmp_path: Path) -> None:
    fast = analyze(write(tmp_path, LIMITS + JERK + "G1 X1000 E5 F60000\n", "f.gcode"))
    # 1000 mm/s asked, 200 mm/s allowed.
    assert fast.total_s == pytest.approx(2 * 0.19 + (1000 - 2 * 19.95) / 200)


def test_dwell_counts_and_heating_does_not(tmp_path: Path) -> None:
    base = LIMITS + JERK + "G1 X100 E5 F6000\n"
    plain = analyze(write(tmp_path, base, "p.gcode")).total_s
    waits = analyze(write(tmp_path, "M190 S60\nM109 S215\n" + base + "G4 P500\nG4 S2\n", "w.gcode"))
    assert waits.total_s == pytest.approx(plain + 2.5)


def test_modes_positions_and_arcs(tmp_path: Path) -> None:
    text = (
        "G21\nG90\nM83\n"
        "G1 X10 Y0 F600\n"  # travel
        "G3 X0 Y10 I-10 J0 E1\n"  # quarter circle, counter-clockwise
        "G2 X10 Y0 I0 J-10 E1\n"  # back clockwise: the quarter again
        "G2 X10 Y0 I-5 J0 E1\n"  # same start and end: a full circle of radius 5
        "G1 E-0.8\nG1 E0.8\n"  # retract, unretract: other
        "G91\nG1 X5 E0.2\nG90\nM82\nG92 E0\nG1 X20 E0.5\n"  # relative, then absolute after G92
        "G1 Z0.4\n"  # Z alone: other
        "G1X25Y0E1\n"  # words without spaces
        "N7 G1 X30 E1.5*71\n"  # line number and checksum
        "G20\nG1 X1.2 E1.6\nG21\n"  # inches: 1.2 in = 30.48 mm
        "G1 X29 E1.5\n"  # E decreases while moving: travel, not extrusion
    )
    p = read_program(write(tmp_path, text))
    assert p.motion.tolist() == [
        TRAVEL, EXTRUDE, EXTRUDE, EXTRUDE, OTHER, OTHER, EXTRUDE, EXTRUDE, OTHER, EXTRUDE,
        EXTRUDE, EXTRUDE, TRAVEL,
    ]  # fmt: skip
    assert p.length[1] == pytest.approx(math.pi * 5)
    assert p.length[2] == pytest.approx(math.pi * 5)
    assert p.length[3] == pytest.approx(2 * math.pi * 5)
    assert p.delta[6].tolist() == pytest.approx([5, 0, 0, 0.2])
    assert p.delta[7].tolist() == pytest.approx([5, 0, 0, 0.5])
    assert p.delta[10].tolist() == pytest.approx([5, 0, 0, 0.5])
    assert p.delta[11].tolist() == pytest.approx([0.48, 0, 0, 1.6 * 25.4 - 1.5])  # E in inches too


def test_windows_line_ends_and_a_byte_order_mark_read_the_same(tmp_path: Path) -> None:
    path = tmp_path / "crlf.gcode"
    path.write_bytes(b"\xef\xbb\xbf" + PRISM.read_bytes().replace(b"\n", b"\r\n"))
    a, b = analyze(path), analysis(PRISM)
    assert (a.total_s, a.layers, a.slicer_estimate_s) == (b.total_s, b.layers, b.slicer_estimate_s)
    assert a.by_kind_s == b.by_kind_s


def test_layers_from_z_when_the_file_has_no_layer_comments(tmp_path: Path) -> None:
    text = "G92 E0\n" + "".join(
        f"G1 Z{z:.1f} F600\nG1 X10 Y0 E{z:.1f}\nG1 X0 Y0\n" for z in (0.2, 0.4, 0.6)
    )
    a = analyze(write(tmp_path, text), min_task_s=0)
    assert a.layers == 3
    assert a.slicer is None and a.slicer_estimate_s is None and a.estimate_ratio is None


def test_cura_time_header_by_hand(tmp_path: Path) -> None:
    # Hand-written in Cura's format (header, ;LAYER:n, ;TYPE:), without ;TIME_ELAPSED.
    text = (
        ";FLAVOR:Marlin\n;TIME:42\n;Generated with Cura_SteamEngine 5.0.0\nM82\nG92 E0\n"
        ";LAYER:0\n;TYPE:WALL-OUTER\nG1 F1200 X10 Y0 Z0.2 E1\n;TYPE:SKIN\nG1 X10 Y10 E2\n"
        ";LAYER:1\n;TYPE:WALL-INNER\nG0 F3000 Z0.4\nG1 X0 Y10 E3\n;End of Gcode\n"
    )
    a = analyze(write(tmp_path, text), min_task_s=0)
    assert a.slicer == "Cura 5.0.0"
    assert a.slicer_estimate_s == 42
    assert a.layers == 2
    assert [t.kind for t in a.tasks] == ["contour", "infill", "other", "infill"]
    assert [t.layer for t in a.tasks] == [0, 0, 1, 1]


# --- merging ------------------------------------------------------------------------------------


def tasks_of(*spec: tuple[str, float]) -> list[GcodeTask]:
    out, t = [], 0.0
    for i, (kind, d) in enumerate(spec):
        out.append(GcodeTask(kind, t, t + d, i))
        t += d
    return out


def shape(tasks: tuple[GcodeTask, ...]) -> list[tuple[str, float, float]]:
    return [(t.kind, round(t.start_s, 9), round(t.end_s, 9)) for t in tasks]


def test_a_run_of_short_segments_takes_its_strictest_kind() -> None:
    got = merge(tasks_of(("infill", 20), ("contour", 2), ("travel", 1), ("support", 3),
                         ("infill", 30)), 5)  # fmt: skip
    assert shape(got) == [("infill", 0, 20), ("contour", 20, 26), ("infill", 26, 56)]
    assert [t.layer for t in got] == [0, 1, 4]


def test_a_still_short_run_joins_the_neighbour_it_tightens_least() -> None:
    # Joining the 100 s infill would tighten 100 s, joining the 50 s support only 50 s.
    got = merge(tasks_of(("infill", 100), ("contour", 2), ("support", 50)), 5)
    assert shape(got) == [("infill", 0, 100), ("contour", 100, 152)]
    # An equal kind tightens nothing; a stricter neighbour would tighten the short run.
    got = merge(tasks_of(("contour", 30), ("infill", 3), ("infill", 40)), 5)
    assert shape(got) == [("contour", 0, 30), ("infill", 30, 73)]


def test_ties_go_to_the_earlier_neighbour_and_equal_kinds_coalesce() -> None:
    # Both neighbours are stricter than the travel: each would tighten its 1 s.
    got = merge(tasks_of(("infill", 20), ("travel", 1), ("support", 30)), 5)
    assert shape(got) == [("infill", 0, 21), ("support", 21, 51)]
    got = merge(tasks_of(("infill", 20), ("travel", 1), ("infill", 30)), 5)
    assert shape(got) == [("infill", 0, 51)]
    got = merge(tasks_of(("support", 20), ("travel", 1), ("support", 30), ("other", 1)), 5)
    assert shape(got) == [("support", 0, 52)]


def test_a_print_shorter_than_the_minimum_is_one_task() -> None:
    assert shape(merge(tasks_of(("infill", 2), ("contour", 1)), 10)) == [("contour", 0, 3)]
    assert merge([], 10) == ()


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from(TASK_KINDS), st.floats(0.01, 60.0)), min_size=1, max_size=40
    ),
    st.floats(0.0, 30.0),
)
def test_merging_never_loosens_a_cap(spec: list[tuple[str, float]], min_task: float) -> None:
    parts = tasks_of(*spec)
    got = merge(parts, min_task)
    assert got[0].start_s == 0.0 and got[-1].end_s == parts[-1].end_s
    for a, b in zip(got, got[1:], strict=False):
        assert a.end_s == b.start_s and a.kind != b.kind
    assert len(got) == 1 or all(t.duration_s >= min_task for t in got)
    for seg in parts:  # every moment runs under a cap at least as strict as its own
        mid = (seg.start_s + seg.end_s) / 2
        task = next(t for t in got if t.start_s <= mid < t.end_s)
        assert RANK[task.kind] <= RANK[seg.kind]


# --- CLI and docs -------------------------------------------------------------------------------


def test_cli_json(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["gcode", str(T_PRUSA), "--json", "--min-task", "20", "--classify", "Gap fill=contour"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"file", "total_s", "by_kind_s", "tasks", "slicer", "layers", "slicer_estimate_s",
            "warnings"} <= out.keys()  # fmt: skip
    assert set(out["by_kind_s"]) == set(TASK_KINDS)
    assert out["tasks"] and all(
        set(t) == {"kind", "start_s", "end_s", "layer"} for t in out["tasks"]
    )
    assert all(t["end_s"] - t["start_s"] >= 20 for t in out["tasks"])
    assert out["total_s"] == pytest.approx(analysis(T_PRUSA).total_s)


def test_cli_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["gcode", str(PRISM)]) == 0
    out = capsys.readouterr().out
    assert "PrusaSlicer 2.5.0" in out and "total" in out and "ours / slicer = 0.99" in out
    assert "1 tasks of at least 10 s" in out


def test_cli_errors_exit_1(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["gcode", str(PRISM), "--classify", "Gap fill"]) == 1
    assert "--classify = 'Gap fill': write NAME=KIND" in capsys.readouterr().err
    assert main(["gcode", str(PRISM), "--classify", "Gap fill=fast"]) == 1
    assert "'fast'" in capsys.readouterr().err


def test_the_old_map_option_still_classifies_with_a_warning(capsys: pytest.CaptureFixture[str]):
    # --map names a floor map on every other command; here it became --classify.
    assert main(["gcode", str(T_PRUSA), "--json", "--map", "Gap fill=contour"]) == 0
    captured = capsys.readouterr()
    assert "--map is now --classify" in captured.err
    assert main(["gcode", str(T_PRUSA), "--json", "--classify", "Gap fill=contour"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(captured.out)


@pytest.mark.parametrize(
    ("text", "line"),
    [
        ("# A README\n\nNotes on the build.\n* a list item\n", "line 1"),
        ("G1 X1 E1\n*12 a bare checksum\nG1 X2 E2\n", None),
        ("G1 X1 E1\nN12\nN13 *7\nG1 X2 E2\n", None),
    ],
)
def test_text_that_is_not_quite_gcode_is_read_or_refused_by_line(tmp_path, text, line):
    # The first crashed with IndexError (a line starting with "*", after a line starting with
    # "N" passed for a line number).
    path = tmp_path / "odd.gcode"
    path.write_text(text)
    if line is None:
        assert analysis(path).total_s > 0
    else:
        with pytest.raises(GcodeError, match=rf"odd\.gcode: {line} = "):
            analysis(path)


def test_docstring_examples_run() -> None:
    result = doctest.testmod(fleet.printing.gcode.analysis)
    assert result.attempted > 0 and result.failed == 0


def test_docs_table_is_the_code_table() -> None:
    text = (REPO_ROOT / "docs" / "gcode.md").read_text()
    rows = re.findall(r"^\| `([^`]+)` \| (\w+) \|", text, flags=re.M)
    assert {name.lower(): kind for name, kind in rows} == dict(FEATURE_KINDS)
