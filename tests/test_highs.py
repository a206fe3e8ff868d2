"""HiGHS configured in one place (fleet.highs): one thread count for the process, no banner on
stdout, and every failure raised or counted with HiGHS's own message.

HiGHS's scheduler and its banner belong to the process, so the tests that depend on what ran
first run in a fresh interpreter of their own.
"""

import logging
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import highspy
import numpy as np
import pytest

from fleet import highs
from fleet.plugins import SolverOutcome
from fleet_plugins.mpc.model import run_outcome

ROOT = Path(__file__).resolve().parent.parent


def fresh_python(code: str) -> subprocess.CompletedProcess[str]:
    """Run `code` in a new interpreter (a process whose HiGHS has never solved)."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )


def tiny_milp(h: highspy.Highs) -> None:
    """max x + y, x + y <= 1.5, x integer in [0, 1], y in [0, 1]."""
    h.addVars(2, np.zeros(2), np.ones(2))
    h.changeColsIntegrality(1, np.array([0], dtype=np.int32), np.array([1], dtype=np.uint8))
    h.changeColsCost(2, np.arange(2, dtype=np.int32), np.array([-1.0, -1.0]))
    h.addRows(
        1,
        np.array([-highspy.kHighsInf]),
        np.array([1.5]),
        2,
        np.array([0], dtype=np.int32),
        np.arange(2, dtype=np.int32),
        np.ones(2),
    )


def option(h: highspy.Highs, name: str) -> object:
    got = h.getOptionValue(name)  # (status, value) in highspy 1.16, the value before
    return got[1] if isinstance(got, tuple) else got


def test_every_object_asks_for_the_process_wide_thread_count():
    h = highs.new_highs({"time_limit": 5.0})
    assert option(h, "threads") == highs.THREADS
    assert option(h, "time_limit") == 5.0
    assert option(h, "log_to_console") is False


def test_a_solve_is_optimal_and_its_log_is_kept_off_the_console():
    h = highs.new_highs()
    tiny_milp(h)
    result = highs.solve(h, "tiny MILP")
    assert result.status == highspy.HighsModelStatus.kOptimal
    assert result.has_solution
    assert h.getInfo().objective_function_value == pytest.approx(-1.5)
    # HiGHS logged into the object's SolverLog rather than onto stdout.
    assert highs.solver_log(h).lines


def test_an_unknown_option_is_refused_with_highs_own_message(caplog):
    with (
        caplog.at_level(logging.WARNING, logger="fleet.highs"),
        pytest.raises(highs.SolverError, match=r"bogus_option = 1: .*unknown"),
    ):
        highs.new_highs({"bogus_option": 1})
    assert "bogus_option" in caplog.text


@pytest.mark.parametrize("name", ["threads", "output_flag", "log_to_console"])
def test_process_wide_options_are_set_here_only(name):
    with pytest.raises(ValueError, match=name):
        highs.new_highs({name: 2})


def test_a_time_limit_is_an_outcome_not_an_error(caplog):
    h = highs.new_highs({"time_limit": 0.0})
    tiny_milp(h)
    with caplog.at_level(logging.INFO):
        outcome = run_outcome(h, "tiny MILP")
    assert outcome is SolverOutcome.TIME_LIMIT
    assert "Time limit reached" in caplog.text
    assert "determinism may be lost" in caplog.text


def test_only_fleet_highs_sets_up_highs_objects():
    """One place: no other module makes a HiGHS object or sets a process-wide option."""
    offenders = []
    for path in [*ROOT.glob("fleet/**/*.py"), *ROOT.glob("plugins/**/*.py")]:
        if path == ROOT / "fleet" / "highs.py":
            continue
        text = path.read_text()
        for pattern in (r"highspy\.Highs\(\)", r"\"threads\"", r"\"output_flag\""):
            if re.search(pattern, text):
                offenders.append(f"{path.relative_to(ROOT)}: {pattern}")
    assert offenders == []


def test_no_banner_reaches_stdout_whoever_makes_the_first_object():
    # Pyomo's persistent interface makes its own highspy.Highs(): that must stay quiet too.
    done = fresh_python(
        """
        import fleet.highs
        import highspy
        raw = highspy.Highs()
        mine = fleet.highs.new_highs()
        print("done")
        """
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout == "done\n"


def test_a_scheduler_set_up_elsewhere_fails_loudly_with_highs_message():
    """A solve that cannot get its thread count is an error naming the cause, never a quiet
    'no solution' (the lower bound used to come out 'not tight' this way)."""
    done = fresh_python(
        """
        import highspy
        import numpy as np
        from fleet import highs
        from fleet.floor import Floor, FloorSpec
        from fleet.study.lowerbound import min_time_lower_bound
        from shapely.geometry import box

        # Someone else's first solve sets the process's scheduler up with 2 threads.
        other = highspy.Highs()
        other.setOptionValue("output_flag", False)
        other.setOptionValue("threads", 2)
        other.addVars(1, np.zeros(1), np.ones(1))
        other.run()

        h = highs.new_highs()
        h.addVars(1, np.zeros(1), np.ones(1))
        try:
            highs.solve(h, "probe")
        except highs.SolverError as e:
            print("solve:", e)
        floor = Floor.from_regions(
            FloorSpec("f.toml", "f", box(0, 0, 10, 10), (1.0, 1.0)),
            [(box(0, 0, 10, 10), (1.0, 1.0), None)],
        )
        try:
            b = min_time_lower_bound(floor, (1, 1), (9, 9), v_max=1.0, a_max=0.5, dt=1.0)
            print("bound:", b.steps, b.tight)
        except highs.SolverError as e:
            print("bound error:", e)
        """
    )
    assert done.returncode == 0, done.stderr
    assert re.search(r"solve: HiGHS failed on probe: .*scheduler", done.stdout)
    assert re.search(r"bound error: .*lower bound MILP.*scheduler", done.stdout), done.stdout
    assert "Running HiGHS" not in done.stdout


def test_the_bound_is_tight_after_an_mpc_run_in_the_same_process():
    """The reported defect: an MPC run first, then the lower bound, in one process."""
    done = fresh_python(
        """
        from fleet.engine import World
        from fleet.study.lowerbound import min_time_lower_bound
        from fleet.scenario import REPO_ROOT, load_scenario

        scenario = load_scenario(REPO_ROOT / "scenarios" / "paper_case3_s1.toml")
        world = World(scenario)
        summary = world.run().summary
        assert summary["solver"]["steps"] > 0
        robot = next(iter(world.robots.values()))
        # A short trip on the same floor keeps the bound's MILPs small.
        x, y = robot.home
        b = min_time_lower_bound(world.floor, (x, y), (x + 4.0, y), v_max=robot.spec.v_max,
                                 a_max=robot.spec.a_max, dt=robot.spec.period)
        print("tight" if b.tight else "not tight", b.steps)
        """
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("tight"), done.stdout + done.stderr


@pytest.mark.parametrize("workers", [0, 1])
def test_fleet_run_prints_no_solver_banner(tmp_path, workers):
    """An MPC run, in this process and in an agent process: stdout is the CLI's alone."""
    done = subprocess.run(
        [sys.executable, "-m", "fleet", "run", "scenarios/paper_case3_s1.toml", "--quiet",
         "--no-figures", "--duration", "20", "--workers", str(workers), "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=300, cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "HiGHS" not in done.stdout + done.stderr
    summary = (tmp_path / "summary.json").read_text()
    assert '"steps": ' in summary  # the MPC did solve
