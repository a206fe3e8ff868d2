"""Print schedules and cap schedules: placing tasks on the clock and caps per step."""

import math

import numpy as np
import pytest

from fleet.engine.safety import check_print_speed
from fleet.printing import PAPER_CAPS, CapSchedule, PrintSchedule, PrintTask


def paper_schedule() -> PrintSchedule:
    """Case study 3's task sequence (steps 0-20 support, 21-50 infill, 51-80 contour, ...)."""
    bounds = [0, 21, 51, 81, 101, 131, 151, 181, 251]
    kinds = ["support", "infill", "contour", "infill", "support", "contour", "infill", "support"]
    tasks = tuple(
        PrintTask(k, float(a), float(b))
        for k, a, b in zip(kinds, bounds[:-1], bounds[1:], strict=True)
    )
    return PrintSchedule(tasks, PAPER_CAPS)


def test_step_caps_follow_the_papers_steps():
    caps = paper_schedule().caps_from(0.0).step_caps(0.0, 1.0, 252)
    assert caps[0] == caps[20] == 0.7
    assert caps[21] == caps[50] == 0.5
    assert caps[51] == caps[80] == 0.3
    assert caps[81] == 0.5 and caps[130] == 0.7 and caps[131] == 0.3 and caps[250] == 0.7
    assert math.isinf(caps[251])


def test_a_step_straddling_a_change_gets_the_tighter_cap():
    caps = paper_schedule().caps_from(0.0)
    assert caps.cap_over(50.5, 51.5) == 0.3
    # Half-second steps that end exactly on a change are not bound by the next task.
    assert list(caps.step_caps(50.0, 0.5, 3)) == [0.5, 0.5, 0.3]


def test_the_schedule_moves_with_the_print_start_and_windows_crop():
    caps = paper_schedule().caps_from(1000.0)
    assert caps.cap_over(0.0, 1000.0) == math.inf
    assert caps.cap_over(1051.0, 1052.0) == 0.3
    window = caps.window(1015.0, 1030.0)
    assert window.pieces == ((1015.0, 1021.0, 0.7), (1021.0, 1030.0, 0.5))


def test_bad_schedules_are_refused():
    with pytest.raises(ValueError, match="must be after"):
        PrintSchedule((PrintTask("infill", 5.0, 5.0),), PAPER_CAPS)
    with pytest.raises(ValueError, match="in order"):
        PrintSchedule((PrintTask("infill", 0.0, 5.0), PrintTask("contour", 4.0, 6.0)), PAPER_CAPS)
    with pytest.raises(ValueError, match="non-overlapping"):
        CapSchedule(((0.0, 2.0, 0.5), (1.0, 3.0, 0.3)))


def test_print_speed_checker_judges_each_step_against_overlapping_caps():
    caps = CapSchedule(((2.0, 4.0, 0.3),))
    t = np.arange(7, dtype=float)
    v = np.array([[1.0, 0], [0.3, 0], [0.3, 0], [0.3, 0], [0.6, 0], [0.6, 0], [0, 0]])
    xy = np.cumsum(np.vstack([[0, 0], v[:-1]]), axis=0)
    assert check_print_speed(t, xy, v, caps) == []
    v[1, 0] = 0.31  # step [1, 2) ends where the cap starts: still free
    assert check_print_speed(t, xy, v, caps) == []
    v[3, 0] = 0.31  # step [3, 4) lies inside the cap
    found = check_print_speed(t, xy, v, caps, "r1")
    assert [(f.kind, f.t, f.robot) for f in found] == [("print_speed", 3.0, "r1")]
    assert "0.31" in found[0].detail and "0.3" in found[0].detail
