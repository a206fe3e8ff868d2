"""Scenario files: which floor, which fleet, which plugins, which jobs, for how long.

`spec` describes the file's structure (``fleet schema scenario`` prints it as JSON Schema) and
words what it refuses; `reader` checks a file against it and builds a frozen `Scenario`
(re-exported here).
This room imports `fleet.errors` and `fleet.printing`; everything downstream reads a `Scenario`,
never the file.
"""

from fleet.scenario.reader import (
    REPO_ROOT,
    BatteryConfig,
    BreakdownsConfig,
    BusConfig,
    JobsConfig,
    Latency,
    PluginChoice,
    QualityConfig,
    RobotsConfig,
    Scenario,
    ScriptedJob,
    check_fleet,
    check_lockstep,
    check_warmup,
    default_scenario,
    load_scenario,
    parse_latency,
    parse_scenario,
    parse_with_settings,
    sensing_needed,
)
from fleet.scenario.spec import ScenarioFile

__all__ = [
    "RobotsConfig",
    "PluginChoice",
    "ScriptedJob",
    "JobsConfig",
    "BusConfig",
    "BatteryConfig",
    "QualityConfig",
    "BreakdownsConfig",
    "Scenario",
    "Latency",
    "parse_latency",
    "check_fleet",
    "sensing_needed",
    "check_lockstep",
    "check_warmup",
    "load_scenario",
    "parse_scenario",
    "parse_with_settings",
    "default_scenario",
    "REPO_ROOT",
    "ScenarioFile",
]
