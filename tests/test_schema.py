"""`fleet schema`: the JSON Schema of scenario and map files describes every file we ship.

A real JSON Schema validator (`jsonschema`, Draft 2020-12, what msgspec writes) accepts every
shipped file against the printed schema and refuses files with unknown keys or values out of
range, as an editor would; msgspec accepts every shipped file against the structure the schema
is printed from; and the printed schema names every key those files use, at every level, with
the help an editor shows.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import jsonschema
import msgspec
import pytest

from fleet.cli import main
from fleet.floor import MapFile
from fleet.scenario import REPO_ROOT, ScenarioFile

FILES = {
    "scenario": (ScenarioFile, sorted((REPO_ROOT / "scenarios").glob("*.toml"))),
    "map": (MapFile, sorted((REPO_ROOT / "maps").glob("*.toml"))),
}


def printed_schema(kind: str, capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    assert main(["schema", kind]) == 0
    return json.loads(capsys.readouterr().out)


def unnamed_keys(schema: dict[str, Any], node: dict[str, Any], value: Any, at: str) -> list[str]:
    """The keys in `value` (TOML as parsed) that the schema `node` does not name."""
    if "$ref" in node:
        node = schema["$defs"][node["$ref"].removeprefix("#/$defs/")]
    for branch in node.get("anyOf", ()):
        fits = {dict: "object", list: "array"}.get(type(value)) == branch.get("type")
        if fits or "$ref" in branch and isinstance(value, dict):
            return unnamed_keys(schema, branch, value, at)
    if isinstance(value, list) and isinstance(node.get("items"), dict):  # not a tuple's
        return [
            k
            for i, v in enumerate(value)
            for k in unnamed_keys(schema, node["items"], v, f"{at}[{i}]")
        ]
    if not isinstance(value, dict) or "properties" not in node:
        return []
    missing = [f"{at}.{key}" for key in value if key not in node["properties"]]
    for key, inner in value.items():
        if key in node["properties"]:
            missing += unnamed_keys(schema, node["properties"][key], inner, f"{at}.{key}")
    return missing


@pytest.mark.parametrize("kind", list(FILES))
def test_the_schema_describes_every_shipped_file(kind, capsys):
    structure, files = FILES[kind]
    schema = printed_schema(kind, capsys)
    root = schema["$defs"][structure.__name__]
    assert set(root["properties"]) == {f.encode_name for f in msgspec.structs.fields(structure)}
    assert root["additionalProperties"] is False  # unknown keys are errors, in editors too
    assert files
    for path in files:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
        msgspec.convert(raw, structure)  # the structure accepts the file as written
        assert unnamed_keys(schema, schema, raw, path.name) == []


@pytest.mark.parametrize("kind", list(FILES))
def test_a_json_schema_validator_accepts_every_shipped_file(kind, capsys):
    schema = printed_schema(kind, capsys)
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    for path in FILES[kind][1]:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
        assert [e.message for e in validator.iter_errors(raw)] == [], path.name


def test_a_json_schema_validator_refuses_what_fleet_refuses(capsys):
    validator = jsonschema.Draft202012Validator(printed_schema("scenario", capsys))
    base = tomllib.loads((REPO_ROOT / "scenarios" / "default.toml").read_text(encoding="utf-8"))
    assert validator.is_valid(base)
    assert not validator.is_valid({**base, "robotz": {"count": 2}})  # unknown key
    robots = base["robots"] if isinstance(base["robots"], dict) else base["robots"][0]
    assert not validator.is_valid({**base, "robots": {**robots, "period_s": 0}})  # out of range
    assert not validator.is_valid({**base, "robots": {**robots, "count": "two"}})  # wrong type


def test_the_schema_carries_the_help_and_ranges_an_editor_shows(capsys):
    robots = printed_schema("scenario", capsys)["$defs"]["RobotsTable"]["properties"]
    assert robots["period_s"]["description"] == "Control period (s)."
    assert robots["period_s"]["exclusiveMinimum"] == 0 and robots["period_s"]["default"] == 0.25
    zones = printed_schema("map", capsys)["$defs"]["ZoneEntry"]
    assert zones["required"] == ["name", "v_max"]
    assert "speed limit" in zones["properties"]["v_max"]["description"]


def test_out_writes_the_schema_to_a_file(tmp_path: Path, capsys):
    out = tmp_path / "map.schema.json"
    assert main(["schema", "map", "--out", str(out)]) == 0
    assert str(out) in capsys.readouterr().out
    assert json.loads(out.read_text()) == msgspec.json.schema(MapFile)


def test_out_in_a_missing_folder_is_an_error_not_a_traceback(tmp_path: Path, capsys):
    out = tmp_path / "no-such-folder" / "scenario.schema.json"
    assert main(["schema", "scenario", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "--out" in err and "no-such-folder" in err and "Traceback" not in err
    assert not out.exists()
