"""Scenario files: which floor, which fleet, which plugins, which jobs, for how long.

`reader` parses and checks a scenario TOML file into a frozen `Scenario` (re-exported here).
This room imports `fleet.errors` and `fleet.printing`; everything downstream reads a `Scenario`,
never the file.
"""

from fleet.scenario.reader import (
    REPO_ROOT,
    BusConfig,
    JobsConfig,
    Latency,
    PluginChoice,
    QualityConfig,
    RobotsConfig,
    Scenario,
    ScriptedJob,
    default_scenario,
    load_scenario,
    parse_latency,
    parse_scenario,
)

__all__ = [
    "RobotsConfig",
    "PluginChoice",
    "ScriptedJob",
    "JobsConfig",
    "BusConfig",
    "QualityConfig",
    "Scenario",
    "Latency",
    "parse_latency",
    "load_scenario",
    "parse_scenario",
    "default_scenario",
    "REPO_ROOT",
]
