"""What a plugin sees: the contracts it implements, the robot model, discovery, the kit.

`contracts` (observations, commands, jobs, bids and the `Controller` and `Dispatcher` bases),
`robot` (the double integrator every controller plans for), `bidding` (a robot's default bid),
`charging` (the charging-policy contract: `ChargingPolicy`, `BatteryStatus`, `Charger`),
`discovery` (entry points), `gate` (controller steps in threads: `in_gate`,
`gate_released`). The conformance kit, `fleet.plugins.testing`, is a room of its own above the
bus: import it by name. This room imports only `fleet.errors`, and `fleet.paths` and
`fleet.floor` for type names.
"""

from fleet.plugins.charging import CHARGING_GROUP, BatteryStatus, Charger, ChargingPolicy
from fleet.plugins.contracts import (
    CAP_LOOKAHEAD_S,
    CONTROLLER_GROUP,
    DISPATCHER_GROUP,
    Announcement,
    Assignment,
    Bid,
    Command,
    Controller,
    ControllerContext,
    ControlStatus,
    DispatchContext,
    Dispatcher,
    Handback,
    Job,
    Neighbour,
    Observation,
    RobotSpec,
    RobotStatus,
    SolveReport,
    SolverOutcome,
)
from fleet.plugins.discovery import (
    PluginInfo,
    PluginWarning,
    discover,
    load_charging_policy,
    load_controller,
    load_dispatcher,
)
from fleet.plugins.gate import gate_released, in_gate

__all__ = [
    "CONTROLLER_GROUP",
    "DISPATCHER_GROUP",
    "CAP_LOOKAHEAD_S",
    "ControlStatus",
    "SolverOutcome",
    "SolveReport",
    "RobotSpec",
    "Neighbour",
    "Observation",
    "Command",
    "ControllerContext",
    "Controller",
    "Job",
    "RobotStatus",
    "Assignment",
    "DispatchContext",
    "Dispatcher",
    "Announcement",
    "Bid",
    "Handback",
    "PluginWarning",
    "PluginInfo",
    "discover",
    "load_controller",
    "load_dispatcher",
    "load_charging_policy",
    "CHARGING_GROUP",
    "BatteryStatus",
    "Charger",
    "ChargingPolicy",
    "in_gate",
    "gate_released",
]
