"""Scenario files: defaults, relative map paths, and a clear error for each bad input."""

import math
import re
from dataclasses import replace
from pathlib import Path

import pytest

from fleet.errors import ScenarioError
from fleet.scenario import REPO_ROOT, Scenario, load_scenario, parse_scenario


@pytest.fixture
def write(tmp_path: Path):
    (tmp_path / "floor.toml").write_text("# any file will do for the scenario loader\n")

    def _write(text: str) -> Path:
        path = tmp_path / "s.toml"
        path.write_text('[scenario]\nmap = "floor.toml"\n' + text)
        return path

    return _write


def test_the_file_defaults_are_the_config_defaults(write):
    # ScenarioFile (what a file may omit) and the frozen Scenario (what code may omit) state
    # their defaults each; a file that omits everything reads as a Scenario that does.
    path = write("")
    assert load_scenario(path) == Scenario(
        name="s", source=str(path), map=(path.parent / "floor.toml").resolve()
    )


def test_minimal_scenario_gets_defaults(write):
    sc = load_scenario(write(""))
    assert sc.name == "s"
    assert sc.map == (write("").parent / "floor.toml").resolve()
    assert (sc.controller.name, sc.dispatcher.name, sc.jobs.mode) == (
        "follower",
        "greedy",
        "poisson",
    )
    assert len(sc.robots) == 1
    assert sc.robots[0].count == 4 and sc.robots[0].period_s == 0.25


def test_full_scenario(write):
    sc = load_scenario(
        write(
            'duration_s = 120\nseed = 7\n[robots]\ncount = 3\nstart = ["a"]\n'
            '[controller]\nname = "follower"\noptions = { gain = 0.3 }\n'
            '[jobs]\nmode = "scripted"\n[[jobs.scripted]]\nat_s = 5\nstation = "b"\n'
            '[bus]\naddress = "tcp://127.0.0.1:5555"\n'
        )
    )
    assert sc.seed == 7 and sc.duration_s == 120.0 and sc.robots[0].start == ("a",)
    assert sc.controller.options == {"gain": 0.3}
    assert sc.jobs.scripted[0].station == "b" and sc.jobs.scripted[0].at_s == 5.0
    assert sc.bus_address == "tcp://127.0.0.1:5555"


@pytest.mark.parametrize(
    ("text", "field", "value", "rule"),
    [
        ("colour = 'red'\n", "scenario.colour", "'red'", "unknown key"),
        ("[robots]\ncount = 0\n", "robots.count", "0", "positive whole number"),
        ("[robots]\ncount = 2.5\n", "robots.count", "2.5", "must be of type int"),
        ("[robots]\na_max = -1\n", "robots.a_max", "-1", "positive number"),
        ("[robots]\nperiod_s = true\n", "robots.period_s", "True", "must be of type"),
        ("seed = -3\n", "scenario.seed", "-3", "whole number >= 0"),
        ("[jobs]\nmode = 'batch'\n", "jobs.mode", "'batch'", "'poisson' or 'scripted'"),
        ("[jobs]\nmode = 'scripted'\n", "jobs.scripted", "[]", "at least one job"),
        ("[[jobs.scripted]]\nstation = 'x'\n", "jobs.scripted[0].at_s", "None", "is required"),
        ("[bus]\naddress = 'udp://x'\n", "bus.address", "'udp://x'", "inproc://"),
        ("[controller]\nname = 'x'\nopts = {}\n", "controller.opts", "{}", "unknown key"),
        ("[print]\ncaps = { glaze = 0.2 }\n", "print.caps.glaze", "0.2", "unknown task kind"),
        ("[print]\ncaps = { infill = 0 }\n", "print.caps.infill", "0", "positive number"),
        (
            "[[jobs.scripted]]\nat_s = 0\nstation = 'x'\n"
            "print = [{ kind = 'glaze', start_s = 0, end_s = 1 }]\n",
            "jobs.scripted[0].print[0].kind",
            "'glaze'",
            "unknown task kind",
        ),
        (
            "[[jobs.scripted]]\nat_s = 0\nstation = 'x'\n"
            "print = [{ kind = 'infill', start_s = 5, end_s = 5 }]\n",
            "jobs.scripted[0].print[0].end_s",
            "5.0",
            "must be after start_s",
        ),
        (
            "[[jobs.scripted]]\nat_s = 0\nstation = 'x'\nprint = ["
            "{ kind = 'infill', start_s = 0, end_s = 10 },"
            "{ kind = 'contour', start_s = 9, end_s = 12 }]\n",
            "jobs.scripted[0].print[1].start_s",
            "9.0",
            "in order and not overlap",
        ),
        (
            "[[jobs.scripted]]\nat_s = 0\nstation = 'x'\nprint = [{ kind = 'infill' }]\n",
            "jobs.scripted[0].print[0].start_s",
            "None",
            "is required",
        ),
        ("[robots]\nv_max = inf\n", "robots.v_max", "inf", "finite number"),
        ("[print]\ncaps = 'fast'\n", "print.caps", "'fast'", 'or "quality"'),
        ("[print]\ncaps = 3\n", "print.caps", "3", "must be of type str or dict"),
        (
            "[quality]\ntolerance_mm = { infill = 0.1, support = -1 }\n",
            "quality.tolerance_mm.support",
            "-1",
            "positive number",
        ),
        ("[jobs]\nstations = ['a', 3]\n", "jobs.stations[1]", "3", "must be of type str"),
        ("[jobs]\nmax_handbacks = -1\n", "jobs.max_handbacks", "-1", "whole number >= 0"),
        (
            "[[jobs.scripted]]\nat_s = 0\nstation = 'x'\ndue_s = nan\n",
            "jobs.scripted[0].due_s",
            "nan",
            "finite number",
        ),
        ("[bus]\ntimeout_s = 2\nlost_after_s = 3\n", "bus.lost_after_s", "3.0", "must not exceed"),
    ],
)
def test_bad_values_name_file_field_and_value(write, text, field, value, rule):
    path = write(text)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    message = str(err.value)
    assert str(path) in message
    assert f"{field} = {value}" in message
    assert rule in message


@pytest.mark.parametrize("kind", ["a folder", "not UTF-8"])
def test_an_unreadable_scenario_file_is_an_error_naming_it(tmp_path, kind):
    path = tmp_path / "s.toml"
    if kind == "a folder":
        path.mkdir()
    else:
        path.write_bytes(b"\xff\xfe[scenario]\n")
    with pytest.raises(ScenarioError, match=r"s\.toml: \(file\) = .*cannot read the scenario file"):
        load_scenario(path)


def test_robot_groups_with_their_own_periods(write):
    sc = load_scenario(
        write(
            "[[robots]]\ncount = 2\nperiod_s = 0.5\n"
            "[[robots]]\ncount = 3\nv_max = 0.6\nstart = ['b']\n"
        )
    )
    assert [(g.count, g.period_s, g.v_max) for g in sc.robots] == [(2, 0.5, 1.0), (3, 0.25, 0.6)]
    with pytest.raises(ScenarioError, match=r"--robots = 4: .* defines 2 robot groups"):
        sc.override(robots=4)
    with pytest.raises(ScenarioError, match=r"robots\[1\].period_s = 0"):
        load_scenario(write("[[robots]]\ncount = 1\n[[robots]]\nperiod_s = 0\n"))
    with pytest.raises(ScenarioError, match=r"robots\[0\].speed = 2"):
        load_scenario(write("[[robots]]\nspeed = 2\n"))


def test_a_scenario_checked_for_someone_else_names_their_source(write):
    # As `fleet.study.sweep` checks a study cell: the file's tables, the cell's values, and
    # errors that name the cell.
    path = write("")
    raw = {"scenario": {"map": "floor.toml"}, "robots": [{"count": 2}, {"count": 0}]}
    with pytest.raises(ScenarioError, match=r"^study.toml cell 3: robots\[1\].count = 0: "):
        parse_scenario(raw, path, source="study.toml cell 3")


def test_missing_map_file(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('[scenario]\nmap = "nowhere.toml"\n')
    with pytest.raises(ScenarioError, match=r"scenario.map = 'nowhere.toml': no such map file"):
        load_scenario(path)


def test_syntax_error_is_reported_with_the_file(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text("[scenario\n")
    with pytest.raises(ScenarioError, match=r"s.toml: \(syntax\)"):
        load_scenario(path)


def test_command_line_overrides_are_validated(write):
    sc = load_scenario(write(""))
    assert sc.override(robots=9, seed=3, duration=60).robots[0].count == 9
    with pytest.raises(ScenarioError, match=r"command line: --robots = -1"):
        sc.override(robots=-1)
    with pytest.raises(ScenarioError, match=r"--map = 'missing.toml': no such map file"):
        sc.override(map="missing.toml")


def test_shipped_scenarios_load():
    for path in sorted((REPO_ROOT / "scenarios").glob("*.toml")):
        assert load_scenario(path).map.is_file()


def test_print_caps_and_tasks_make_a_schedule(write):
    sc = load_scenario(
        write(
            "[print]\ncaps = { contour = 0.3, infill = 0.5 }\n"
            "[jobs]\nmode = 'scripted'\n[[jobs.scripted]]\nat_s = 0\nstation = 'x'\nprint = ["
            "{ kind = 'infill', start_s = 0, end_s = 10 },"
            "{ kind = 'support', start_s = 10, end_s = 20 },"
            "{ kind = 'contour', start_s = 20, end_s = 30 }]\n"
        )
    )
    schedule = sc.print_schedule(sc.jobs.scripted[0])
    assert schedule is not None and schedule.duration_s == 30.0
    # Support has no cap in this scenario: only the capped tasks become pieces.
    assert schedule.caps_from(100.0).pieces == ((100.0, 110.0, 0.5), (120.0, 130.0, 0.3))


# --- rules across fields (check_fleet) ---------------------------------------------------------


def _fleet(**group):
    from dataclasses import replace

    from fleet.scenario import REPO_ROOT, load_scenario

    sc = load_scenario(REPO_ROOT / "scenarios" / "fleet.toml")
    return replace(sc, robots=(replace(sc.robots[0], **group),))


def test_robots_that_could_cross_unseen_in_one_period_are_refused_by_name() -> None:
    from fleet.scenario import check_fleet

    with pytest.raises(ScenarioError) as err:
        check_fleet(_fleet(period_s=1.0))  # 1 m per period, radius 0.4
    assert err.value.field == "robots.period_s" and err.value.value == 1.0
    assert "period_s <= 0.8" in str(err.value)
    # exactly the diameter: allowed (seeing far enough for it: 8.15 m)
    check_fleet(replace(_fleet(period_s=0.8), sensing_radius_m=8.2))
    check_fleet(_fleet(period_s=1.0, v_max=0.5))  # slower robots may plan less often
    check_fleet(_fleet(period_s=1.0, count=1))  # alone (the paper's case 3 runs at 1 s)


def test_a_robot_wider_than_the_maps_clearance_is_refused() -> None:
    from fleet.engine import World
    from fleet.scenario import check_fleet

    with pytest.raises(ScenarioError) as err:
        check_fleet(_fleet(radius=0.5), clearance=0.4)
    assert err.value.field == "robots.radius" and "floor.clearance (0.4 m)" in str(err.value)
    check_fleet(_fleet(radius=0.4), clearance=0.4)
    check_fleet(_fleet(radius=0.5), clearance=0.0)  # a map of point robots (the paper's)
    with pytest.raises(ScenarioError, match="robots.radius"):
        World(_fleet(radius=0.45))  # the shop floor's clearance is 0.4


def test_robots_that_see_each_other_too_late_to_stop_are_refused() -> None:
    from fleet.scenario import check_fleet, sensing_needed

    # 2 * 0.4 + sqrt(2) * (1**2 / 0.5 + 4 * 1 * 0.25) = 5.043 m: the diagonal counts (v_max
    # bounds each axis); the rule before it, 2 * 0.4 + 1**2 / 0.5 + 2 * 1 * 0.25 = 3.3 m, let
    # MPC robots on diagonals see each other too late (tests/test_mpc_contact.py)
    group = _fleet().robots[0]
    assert sensing_needed(group, group) == pytest.approx(0.8 + math.sqrt(2) * 3.0)
    with pytest.raises(ScenarioError) as err:
        check_fleet(replace(_fleet(), sensing_radius_m=5.0))
    assert err.value.field == "scenario.sensing_radius_m" and err.value.value == 5.0
    assert err.value.source.endswith("fleet.toml") and "at least 5.05 m for robots" in str(
        err.value
    )
    check_fleet(replace(_fleet(), sensing_radius_m=5.05))
    check_fleet(_fleet())  # the shipped fleet scenario sets 6 m
    check_fleet(replace(_fleet(count=1), sensing_radius_m=1.0))  # alone
    check_fleet(replace(_fleet(), sensing_radius_m=0.0))  # blind: robots ignore each other
    # The MPC property test's robots (radius 0.3, 0.5 s periods) need 6.26 m.
    mpc = replace(group, radius=0.3, period_s=0.5)
    assert sensing_needed(mpc, mpc) == pytest.approx(6.2569, abs=1e-4)


def test_two_groups_must_see_far_enough_for_each_pair() -> None:
    from fleet.scenario import check_fleet, sensing_needed

    sc = _fleet()
    quick, coarse = replace(sc.robots[0], count=1), replace(sc.robots[0], count=1, period_s=0.5)
    both = replace(sc, robots=(quick, coarse))
    # Each group alone asks 5.04 m and 6.46 m; together 0.8 + sqrt(2) * (1.5 + 2) = 5.75 m.
    assert sensing_needed(quick, coarse) == pytest.approx(0.8 + math.sqrt(2) * 3.5)
    with pytest.raises(ScenarioError) as err:
        check_fleet(replace(both, sensing_radius_m=6.0))
    assert err.value.field == "scenario.sensing_radius_m"
    assert "6.46 m for robots[1]" in str(err.value)
    check_fleet(replace(both, sensing_radius_m=6.46))


def test_a_scenario_file_that_sees_too_little_is_refused_naming_the_file(tmp_path: Path) -> None:
    from fleet.engine import World
    from fleet.scenario import load_scenario

    text = (REPO_ROOT / "scenarios" / "fleet.toml").read_text()
    text = text.replace("sensing_radius_m = 6.0", "sensing_radius_m = 4.5", 1)
    shop = (REPO_ROOT / "maps" / "shop_floor.toml").as_posix()
    text = re.sub(r'map = "[^"]+"', f'map = "{shop}"', text, count=1)
    path = tmp_path / "short_sight.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as err:
        World(load_scenario(path))
    assert (err.value.source, err.value.field, err.value.value) == (
        str(path),
        "scenario.sensing_radius_m",
        4.5,
    )
    assert f"{path}: scenario.sensing_radius_m = 4.5" in str(err.value)
