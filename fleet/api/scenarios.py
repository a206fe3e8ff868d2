"""Scenarios for code: read from a file, built from a dict, changed by dotted key.

Every way goes through the scenario reader (`fleet.scenario.parse_scenario`), so a scenario made
in code is checked exactly as a file is, and a bad value raises `ScenarioError` naming where it
came from, the field and the value.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fleet.errors import FleetError
from fleet.scenario import Scenario, parse_scenario, parse_with_settings
from fleet.scenario import load_scenario as _load_scenario

__all__ = ["OVERRIDES", "load_scenario", "scenario_from_dict", "change", "as_toml"]

#: How errors name the `overrides` of these functions.
OVERRIDES = "overrides"


def load_scenario(path: str | Path, overrides: Mapping[str, Any] | None = None) -> Scenario:
    """Read and validate a scenario file, with `overrides` written over it.

    Parameters
    ----------
    path:
        The scenario TOML; paths in it are relative to its folder.
    overrides:
        Values by dotted key, as ``fleet run --set`` takes them: ``{"robots.count": 6,
        "scenario.seed": 3, "controller.options.gain": 0.5}``. File names among them
        (``scenario.map``, ``parts.<name>``, ``quality.calibration``) are relative to the
        current directory.

    Raises
    ------
    ScenarioError
        Naming the file, or ``overrides`` when an override is what is wrong, with the key and
        the value.
    """
    return _load_scenario(path, as_toml(overrides), settings_source=OVERRIDES)


def scenario_from_dict(
    tables: Mapping[str, Any],
    *,
    folder: str | Path = ".",
    name: str = "scenario",
    source: str = "scenario_from_dict",
) -> Scenario:
    """A scenario from its tables as a dict, laid out as the file's (``{"scenario": {"map":
    ...}, "robots": {"count": 4}, ...}``; `fleet.scenario.ScenarioFile` describes them).

    Parameters
    ----------
    tables:
        The scenario's tables; left unchanged.
    folder:
        What relative paths in `tables` (map, parts, calibration) are relative to.
    name:
        The scenario's name when ``tables["scenario"]`` has none.
    source:
        How errors name where the tables came from.

    Raises
    ------
    ScenarioError
        Naming `source`, the field and the value.
    """
    return parse_scenario(as_toml(tables), Path(folder) / f"{name}.toml", source=source)


def change(scenario: Scenario, overrides: Mapping[str, Any]) -> Scenario:
    """A copy of `scenario` with `overrides` written over its tables by dotted key and checked
    again, as `load_scenario`'s are: ``change(s, {"robots.count": 6, "scenario.seed": 3})``.

    Raises
    ------
    ScenarioError
        Naming ``overrides``, the key and the value, when an override is wrong.
    FleetError
        If `scenario` has no tables to change (built field by field), or was changed with
        `dataclasses.replace` or `Scenario.override` after it was read, which a change of its
        tables would quietly undo.
    """
    if not scenario.tables or scenario.origin is None:
        raise FleetError(
            f"scenario {scenario.name!r} was built field by field and has no tables to change: "
            "make it with load_scenario or scenario_from_dict, or change it with "
            "dataclasses.replace"
        )
    tables = dict(scenario.tables)
    if parse_scenario(tables, scenario.origin, source=scenario.source) != scenario:
        raise FleetError(
            f"scenario {scenario.name!r} was changed after it was read (dataclasses.replace or "
            "Scenario.override), and change() works on the tables it was read from, so it would "
            "undo that: make every change with change() or the overrides of load_scenario"
        )
    return parse_with_settings(
        tables,
        scenario.origin,
        as_toml(overrides),
        source=scenario.source,
        settings_source=OVERRIDES,
    )


def as_toml(value: Any) -> Any:
    """`value` as a TOML file would give it: paths as text, tuples as lists, mappings as
    dicts (a copy; `value` is left as it is), so ``{"map": Path(...)}`` reads as the file's."""
    if isinstance(value, Mapping):
        return {str(k): as_toml(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [as_toml(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value
