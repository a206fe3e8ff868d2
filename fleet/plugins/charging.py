"""The charging-policy contract: when a robot goes to charge, when it leaves, whether it works.

A scenario with a ``[battery]`` table gives every robot a battery and runs a charging policy
(``[charging] name = ...``), a plugin found through the ``fleet.charging`` entry-point group as
controllers and dispatchers are. The engine asks it about each robot at each of the robot's
control ticks, with a `BatteryStatus`: the robot's charge, whether it has a job, the time and
every charger with its occupant. The policy answers three questions:

- `ChargingPolicy.go_charge`: go to charge now? A charger's name, or None. Asked while the
  robot is neither at nor heading for a charger. Answered while the robot has a job, the robot
  goes once the job is delivered and takes no new job meanwhile.
- `ChargingPolicy.leave`: leave the charger now? Asked while the robot is heading for or
  standing at a charger without a job.
- `ChargingPolicy.takes_jobs`: may the dispatcher give the robot a job while it is heading for
  or standing at a charger? A job given ends the charge.

The policy runs in the engine's process (like dispatchers, unlike controllers): it decides on
what only the engine holds (every robot's charge, which charger is taken), and its answers
must agree across robots (one robot per charger) within one instant.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

__all__ = ["CHARGING_GROUP", "Charger", "BatteryStatus", "ChargingPolicy"]

CHARGING_GROUP = "fleet.charging"


@dataclass(frozen=True, slots=True)
class Charger:
    """A charging station of the floor (a map station of kind ``"charger"``).

    `occupant` is the robot standing at it or heading for it (one robot per charger); None when
    it is free.
    """

    name: str
    x: float
    y: float
    occupant: str | None = None


@dataclass(frozen=True, slots=True)
class BatteryStatus:
    """A robot's battery as the charging policy sees it at time `t` (s).

    Attributes
    ----------
    charge:
        State of charge, the share of `capacity_wh` left (0 to 1).
    has_job:
        It has a job (current or queued).
    charger:
        The charger it is heading for or standing at (None: neither).
    charging:
        It stands at `charger` taking charge.
    chargers:
        Every charger of the floor with its occupant, in map order.
    drive_wh_per_m, print_w, idle_w:
        The battery's draw (Wh per metre driven, W while printing, W at all times), so a policy
        can judge what a trip or a print costs.
    charge_w:
        The rate at which a charger fills the battery (W, i.e. Wh per hour).
    """

    robot: str
    t: float
    x: float
    y: float
    charge: float
    capacity_wh: float
    has_job: bool
    charger: str | None
    charging: bool
    chargers: tuple[Charger, ...]
    drive_wh_per_m: float = 0.0
    print_w: float = 0.0
    idle_w: float = 0.0
    charge_w: float = 0.0


class ChargingPolicy(ABC):
    """Base class of charging-policy plugins.

    Override `go_charge` and `leave` (required) and `takes_jobs` (default: no jobs while heading
    for or at a charger). Answers must be deterministic given the statuses so far. An answer
    naming a charger that is unknown or taken by another robot is ignored (and counted in
    summary.json ``engine.charger_refused``).
    """

    #: Short name shown by ``fleet plugins``; defaults to the entry-point name.
    name: ClassVar[str] = ""

    def __init__(self, **options: Any) -> None:
        if options:
            raise TypeError(f"{type(self).__name__} takes no options, got {sorted(options)}")

    @abstractmethod
    def go_charge(self, status: BatteryStatus) -> str | None:
        """The charger `status.robot` should go to now (after its job, if it has one), or
        None to carry on."""

    @abstractmethod
    def leave(self, status: BatteryStatus) -> bool:
        """Whether the robot heading for or standing at `status.charger` should leave it now."""

    def takes_jobs(self, status: BatteryStatus) -> bool:
        """Whether the dispatcher may give the robot a job while it heads for or stands at
        `status.charger` (a job given ends the charge)."""
        return False
