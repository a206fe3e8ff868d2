"""Map files: what a valid file reads as, and an error naming file, field and value for each
kind of mistake."""

from __future__ import annotations

from pathlib import Path

import pytest
from shapely.geometry import box

from fleet.errors import MapError
from fleet.floor import load_floor, load_spec

FLOOR = """\
[floor]
name = "Test hall"
rect = [0, 0, 20, 10]
default_v_max = 1.0
clearance = 0.5
"""

MACHINE = """
[[obstacles]]
name = "cnc_1"
rect = [8, 4, 12, 6]
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "hall.toml"
    path.write_text(text)
    return path


def test_a_full_map_reads_as_written(tmp_path):
    path = write(
        tmp_path,
        FLOOR.replace("rect = [0, 0, 20, 10]", "boundary = [[0, 0], [20, 0], [20, 10], [0, 10]]")
        + 'description = "d"\n'
        + MACHINE
        + """
[[zones]]
name = "slow"
around = "cnc_1"
margin = 1.0
v_max = [0.4, 0.3]

[[zones]]
name = "lane"
polygon = [[0, 0], [4, 0], [4, 3]]
v_max = 0.8

[[stations]]
name = "depot"
at = [1, 1]
kind = "depot"

[[stations]]
name = "drop"
at = [15, 5]

[[rough_areas]]
name = "duct"
rect = [14, 0, 14.5, 10]
severity = 0.5

[metadata]
author = "test"
""",
    )
    spec = load_spec(path)
    assert spec.source == str(path) and spec.name == "Test hall" and spec.description == "d"
    assert spec.boundary.equals(box(0, 0, 20, 10))
    assert spec.default_v_max == (1.0, 1.0) and spec.clearance == 0.5
    assert [o.name for o in spec.obstacles] == ["cnc_1"]
    assert spec.zones[0].polygon.equals(box(7, 3, 13, 7)) and spec.zones[0].v_max == (0.4, 0.3)
    assert spec.zones[1].polygon.area == pytest.approx(6.0)
    assert [(s.name, s.x, s.y, s.kind) for s in spec.stations] == [
        ("depot", 1.0, 1.0, "depot"),
        ("drop", 15.0, 5.0, "delivery"),
    ]
    assert spec.rough_areas[0].severity == 0.5
    assert spec.metadata == {"author": "test"}
    floor = load_floor(path)
    assert floor.v_max_at(7.2, 5) == (0.4, 0.3)


def test_missing_file(tmp_path):
    path = tmp_path / "nope.toml"
    with pytest.raises(MapError) as info:
        load_spec(path)
    assert info.value.field == "(file)" and str(path) in str(info.value)


def test_toml_syntax_error_gives_the_line(tmp_path):
    path = write(tmp_path, FLOOR + "\n[[obstacles]]\nname = cnc_1\n")
    with pytest.raises(MapError) as info:
        load_spec(path)
    err = info.value
    assert err.source == str(path)
    assert err.field == "(TOML syntax, line 8)"
    assert "'name = cnc_1'" in str(err) and "not valid TOML" in str(err)


# Each case: text of the map, the field the error must name, the value it must quote (as the
# message shows it, i.e. its repr), and a fragment of the rule.
BAD = {
    "unknown top-level key": (
        FLOOR + "[machines]\nx = 1\n",
        "machines",
        "{'x': 1}",
        "allowed keys: floor, obstacles, zones",
    ),
    "unknown floor key": (
        FLOOR + "speed = 2\n",
        "floor.speed",
        "2",
        "allowed keys: name, description, boundary, rect, default_v_max, clearance",
    ),
    "unknown obstacle key (typo)": (
        FLOOR + MACHINE + "hieght = 2\n",
        "obstacles[0] (cnc_1).hieght",
        "2",
        "allowed keys: name, polygon, rect",
    ),
    "missing floor section": (
        '[[obstacles]]\nname = "a"\nrect = [0, 0, 1, 1]\n',
        "floor",
        "<missing>",
        "required",
    ),
    "missing floor name": (
        FLOOR.replace('name = "Test hall"\n', ""),
        "floor.name",
        "<missing>",
        "required",
    ),
    "missing default speed": (
        FLOOR.replace("default_v_max = 1.0\n", ""),
        "floor.default_v_max",
        "<missing>",
        "required",
    ),
    "missing boundary": (
        FLOOR.replace("rect = [0, 0, 20, 10]\n", ""),
        "floor.boundary",
        "<missing>",
        "or rect = [xmin, ymin, xmax, ymax]",
    ),
    "boundary and rect": (
        FLOOR + "boundary = [[0, 0], [1, 0], [1, 1]]\n",
        "floor.rect",
        "[0, 0, 20, 10]",
        "exactly one of boundary or rect",
    ),
    "missing obstacle name": (
        FLOOR + "\n[[obstacles]]\nrect = [1, 1, 2, 2]\n",
        "obstacles[0].name",
        "<missing>",
        "required",
    ),
    "missing zone speed": (
        FLOOR + MACHINE + '[[zones]]\nname = "z"\nrect = [1, 1, 2, 2]\n',
        "zones[0] (z).v_max",
        "<missing>",
        "required",
    ),
    "missing obstacle shape": (
        FLOOR + '[[obstacles]]\nname = "a"\n',
        "obstacles[0] (a).polygon",
        "<missing>",
        "or rect",
    ),
    "name of wrong type": (
        FLOOR.replace('"Test hall"', "3"),
        "floor.name",
        "3",
        "must be a string",
    ),
    "clearance of wrong type": (
        FLOOR.replace("clearance = 0.5", 'clearance = "big"'),
        "floor.clearance",
        "'big'",
        "must be a number",
    ),
    "boolean speed": (
        FLOOR.replace("default_v_max = 1.0", "default_v_max = true"),
        "floor.default_v_max",
        "True",
        "speed > 0",
    ),
    "obstacles as a table": (
        FLOOR + '[obstacles]\nname = "a"\n',
        "obstacles",
        "{'name': 'a'}",
        "write each entry as [[obstacles]]",
    ),
    "polygon with two vertices": (
        FLOOR + '[[obstacles]]\nname = "a"\npolygon = [[1, 1], [2, 2]]\n',
        "obstacles[0] (a).polygon",
        "[[1, 1], [2, 2]]",
        "at least 3 vertices, got 2",
    ),
    "vertex that is not a pair": (
        FLOOR + '[[obstacles]]\nname = "a"\npolygon = [[1, 1], [2, 2, 3], [1, 2]]\n',
        "obstacles[0] (a).polygon[1]",
        "[2, 2, 3]",
        "[x, y]",
    ),
    "non-finite coordinate": (
        FLOOR + '[[obstacles]]\nname = "a"\npolygon = [[1, 1], [nan, 2], [1, 2]]\n',
        "obstacles[0] (a).polygon[1][0]",
        "nan",
        "finite",
    ),
    "coordinate beyond what geometry can take": (
        FLOOR + '[[obstacles]]\nname = "a"\nrect = [1, 1, 1e308, 2]\n',
        "obstacles[0] (a).rect[2]",
        "1e+308",
        "within ±1,000,000",
    ),
    "infinite rect": (
        FLOOR + '[[obstacles]]\nname = "a"\nrect = [1, 1, inf, 2]\n',
        "obstacles[0] (a).rect[2]",
        "inf",
        "finite",
    ),
    "inverted rect": (
        FLOOR + '[[obstacles]]\nname = "a"\nrect = [3, 1, 2, 2]\n',
        "obstacles[0] (a).rect",
        "[3, 1, 2, 2]",
        "xmin < xmax",
    ),
    "self-intersecting polygon": (
        FLOOR + '[[obstacles]]\nname = "bow"\npolygon = [[1, 1], [3, 3], [3, 1], [1, 3]]\n',
        "obstacles[0] (bow).polygon",
        "[[1, 1], [3, 3], [3, 1], [1, 3]]",
        "cross or touch at (2, 2)",
    ),
    "zero-area polygon": (
        FLOOR + '[[obstacles]]\nname = "flat"\npolygon = [[1, 1], [2, 2], [3, 3]]\n',
        "obstacles[0] (flat).polygon",
        "[[1, 1], [2, 2], [3, 3]]",
        "zero area",
    ),
    "obstacle partly outside": (
        FLOOR + '[[obstacles]]\nname = "a"\nrect = [18, 4, 22, 6]\n',
        "obstacles[0] (a).rect",
        "[18, 4, 22, 6]",
        "partly outside the floor boundary (4 m^2 outside",
    ),
    "zone outside": (
        FLOOR + '[[zones]]\nname = "z"\nrect = [30, 4, 32, 6]\nv_max = 0.4\n',
        "zones[0] (z).rect",
        "[30, 4, 32, 6]",
        "lies outside the floor boundary",
    ),
    "zone polygon partly outside": (
        FLOOR + '[[zones]]\nname = "z"\npolygon = [[-1, 1], [3, 1], [3, 3]]\nv_max = 0.4\n',
        "zones[0] (z).polygon",
        "[[-1, 1], [3, 1], [3, 3]]",
        "partly outside",
    ),
    "rough area partly outside": (
        FLOOR + '[[rough_areas]]\nname = "r"\nrect = [5, 9, 6, 11]\nseverity = 1\n',
        "rough_areas[0] (r).rect",
        "[5, 9, 6, 11]",
        "partly outside",
    ),
    "zero speed": (
        FLOOR.replace("default_v_max = 1.0", "default_v_max = 0"),
        "floor.default_v_max",
        "0",
        "speed > 0",
    ),
    "negative axis speed": (
        FLOOR + '[[zones]]\nname = "z"\nrect = [1, 1, 2, 2]\nv_max = [0.5, -0.1]\n',
        "zones[0] (z).v_max",
        "[0.5, -0.1]",
        "speed > 0",
    ),
    "three speeds": (
        FLOOR + '[[zones]]\nname = "z"\nrect = [1, 1, 2, 2]\nv_max = [1, 1, 1]\n',
        "zones[0] (z).v_max",
        "[1, 1, 1]",
        "[vx, vy]",
    ),
    "negative clearance": (
        FLOOR.replace("clearance = 0.5", "clearance = -0.1"),
        "floor.clearance",
        "-0.1",
        ">= 0",
    ),
    "negative severity": (
        FLOOR + '[[rough_areas]]\nname = "r"\nrect = [5, 5, 6, 6]\nseverity = -1\n',
        "rough_areas[0] (r).severity",
        "-1",
        ">= 0",
    ),
    "station outside the floor": (
        FLOOR + '[[stations]]\nname = "s"\nat = [25, 5]\n',
        "stations[0] (s).at",
        "[25.0, 5.0]",
        "outside the floor",
    ),
    "station inside an obstacle": (
        FLOOR + MACHINE + '[[stations]]\nname = "s"\nat = [10, 5]\n',
        "stations[0] (s).at",
        "[10.0, 5.0]",
        "inside obstacle 'cnc_1' (obstacles[0] (cnc_1))",
    ),
    "station within clearance of an obstacle": (
        FLOOR + MACHINE + '[[stations]]\nname = "s"\nat = [12.3, 5]\n',
        "stations[0] (s).at",
        "[12.3, 5.0]",
        "0.3 m from obstacle 'cnc_1'",
    ),
    "station within clearance of the wall": (
        FLOOR + '[[stations]]\nname = "s"\nat = [0.2, 5]\n',
        "stations[0] (s).at",
        "[0.2, 5.0]",
        "0.2 m from the floor boundary",
    ),
    "station that is not a point": (
        FLOOR + '[[stations]]\nname = "s"\nat = 5\n',
        "stations[0] (s).at",
        "5",
        "[x, y]",
    ),
    "duplicate name across kinds": (
        FLOOR + MACHINE + '[[stations]]\nname = "cnc_1"\nat = [1, 1]\n',
        "stations[0].name",
        "'cnc_1'",
        "already used by obstacles[0] (cnc_1)",
    ),
    "around naming nothing": (
        FLOOR + MACHINE + '[[zones]]\nname = "z"\naround = "cnc_9"\nmargin = 1\nv_max = 0.4\n',
        "zones[0] (z).around",
        "'cnc_9'",
        "names no obstacle or zone (known: cnc_1)",
    ),
    "around naming a station": (
        FLOOR
        + '[[stations]]\nname = "s"\nat = [1, 1]\n'
        + '[[zones]]\nname = "z"\naround = "s"\nmargin = 1\nv_max = 0.4\n',
        "zones[0] (z).around",
        "'s'",
        "'s' is stations[0] (s)",
    ),
    "zones around each other": (
        FLOOR
        + '[[zones]]\nname = "a"\naround = "b"\nmargin = 1\nv_max = 0.4\n'
        + '[[zones]]\nname = "b"\naround = "a"\nmargin = 1\nv_max = 0.8\n',
        "zones[1] (b).around",
        "'a'",
        "cycle: a -> b -> a",
    ),
    "around with a polygon too": (
        FLOOR + MACHINE + '[[zones]]\nname = "z"\naround = "cnc_1"\nmargin = 1\n'
        "rect = [1, 1, 2, 2]\nv_max = 0.4\n",
        "zones[0] (z).rect",
        "[1, 1, 2, 2]",
        "exactly one of polygon, rect or around",
    ),
    "around without margin": (
        FLOOR + MACHINE + '[[zones]]\nname = "z"\naround = "cnc_1"\nv_max = 0.4\n',
        "zones[0] (z).margin",
        "<missing>",
        "required with around",
    ),
    "margin without around": (
        FLOOR + '[[zones]]\nname = "z"\nrect = [1, 1, 2, 2]\nmargin = 1\nv_max = 0.4\n',
        "zones[0] (z).margin",
        "1",
        "only allowed with around",
    ),
    "non-positive margin": (
        FLOOR + MACHINE + '[[zones]]\nname = "z"\naround = "cnc_1"\nmargin = 0\nv_max = 0.4\n',
        "zones[0] (z).margin",
        "0",
        "> 0",
    ),
    "floor not a table": ("floor = 3\n", "floor", "3", "write it as [floor]"),
    "entry name of wrong type": (
        FLOOR + "[[obstacles]]\nname = 3\nrect = [1, 1, 2, 2]\n",
        "obstacles[0].name",
        "3",
        "must be a string",
    ),
    "speed axis that is not a number": (
        FLOOR + '[[zones]]\nname = "z"\nrect = [1, 1, 2, 2]\nv_max = [0.5, "fast"]\n',
        "zones[0] (z).v_max",
        "[0.5, 'fast']",
        "[vx, vy]",
    ),
    "empty name": (
        FLOOR + '[[stations]]\nname = " "\nat = [1, 1]\n',
        "stations[0].name",
        "' '",
        "not be empty",
    ),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_map_names_file_field_and_value(tmp_path, case):
    text, field, shown, rule = BAD[case]
    path = write(tmp_path, text)
    with pytest.raises(MapError) as info:
        load_spec(path)
    err = info.value
    message = str(err)
    assert err.source == str(path)
    assert err.field == field, message
    assert message.startswith(f"{path}: {field} = {shown}: "), message
    assert rule in err.rule, message


def test_station_in_the_mitred_corner_of_a_grown_machine_fails_at_load_floor(tmp_path):
    # 0.5 m from both edges of the corner (so load_spec accepts it) but inside the mitred
    # grown machine, whose corner reaches 0.71 m out along the diagonal.
    path = write(tmp_path, FLOOR + MACHINE + '[[stations]]\nname = "s"\nat = [7.6, 3.6]\n')
    load_spec(path)
    with pytest.raises(MapError) as info:
        load_floor(path)
    assert info.value.field == "stations[0] (s).at"
    assert str(info.value).startswith(f"{path}: stations[0] (s).at = [7.6, 3.6]: ")
    assert "obstacle 'cnc_1' grown by clearance 0.5 m" in str(info.value)
