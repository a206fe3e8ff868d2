"""`ThresholdCharging` and `OpportunityCharging`: the built-in charging policies."""

from __future__ import annotations

import math

from fleet.plugins import BatteryStatus, Charger, ChargingPolicy

__all__ = ["ThresholdCharging", "OpportunityCharging", "nearest_free"]


def _share(name: str, value: object) -> float:
    """`value` as a share of the capacity in [0, 1], or ValueError naming the option."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 <= value <= 1:
        raise ValueError(f"option {name} = {value!r}: must be a share of the capacity, 0 to 1")
    return float(value)


def nearest_free(status: BatteryStatus, within_m: float = math.inf) -> Charger | None:
    """The charger nearest to the robot (straight line) that is free or already its own,
    within `within_m`; ties go to the first in map order. None: there is none."""
    best: Charger | None = None
    best_d = within_m
    for c in status.chargers:
        if c.occupant not in (None, status.robot):
            continue
        d = math.hypot(c.x - status.x, c.y - status.y)
        if d <= best_d and (best is None or d < best_d):
            best, best_d = c, d
    return best


def _nearest(status: BatteryStatus) -> Charger | None:
    """The nearest charger, free or not (to wait for when every one is taken)."""
    return min(
        status.chargers, key=lambda c: math.hypot(c.x - status.x, c.y - status.y), default=None
    )


class ThresholdCharging(ChargingPolicy):
    """Charge when low: below `threshold` (a share of the capacity) the robot finishes its job,
    drives to the nearest free charger (or waits for the nearest one when all are taken) and
    charges to `target`; it takes no jobs from the moment it is low until it leaves."""

    name = "threshold"

    def __init__(self, threshold: float = 0.3, target: float = 0.9) -> None:
        super().__init__()
        self.threshold = _share("threshold", threshold)
        self.target = _share("target", target)
        if self.target <= self.threshold:
            raise ValueError(f"option target = {target!r}: must be above threshold = {threshold!r}")

    def go_charge(self, status: BatteryStatus) -> str | None:
        if status.charge >= self.threshold:
            return None
        charger = nearest_free(status) or _nearest(status)
        return None if charger is None else charger.name

    def leave(self, status: BatteryStatus) -> bool:
        return status.charge >= self.target


class OpportunityCharging(ChargingPolicy):
    """Charge whenever idle near a free charger: an idle robot below `below` within `radius_m`
    (straight line) of a free charger goes there and charges until it is given a job or reaches
    `full` (`below` < `full`, so a robot that just left does not turn back at once). Below
    `safety` it charges as `ThresholdCharging` does (after its job, to `target`, no jobs
    meanwhile), so it never runs flat waiting for an opportunity."""

    name = "opportunity"

    def __init__(
        self,
        radius_m: float = 15.0,
        safety: float = 0.25,
        target: float = 0.6,
        below: float = 0.9,
        full: float = 0.98,
    ) -> None:
        super().__init__()
        if isinstance(radius_m, bool) or not isinstance(radius_m, int | float) or radius_m < 0:
            raise ValueError(f"option radius_m = {radius_m!r}: must be a distance >= 0 (m)")
        self.radius_m = float(radius_m)
        self.safety = _share("safety", safety)
        self.target = _share("target", target)
        self.below = _share("below", below)
        self.full = _share("full", full)
        if not (self.safety < self.target <= self.full and self.below < self.full):
            raise ValueError(
                f"options safety = {safety!r}, target = {target!r}, below = {below!r}, "
                f"full = {full!r}: must keep safety < target <= full and below < full"
            )
        #: Robots that fell below `safety` and charge to `target` before they work again.
        self._low: set[str] = set()

    def go_charge(self, status: BatteryStatus) -> str | None:
        if status.charge < self.safety:
            self._low.add(status.robot)
            charger = nearest_free(status) or _nearest(status)
            return None if charger is None else charger.name
        if status.has_job or status.charge >= self.below:
            return None
        charger = nearest_free(status, self.radius_m)
        return None if charger is None else charger.name

    def leave(self, status: BatteryStatus) -> bool:
        return status.charge >= self.full

    def takes_jobs(self, status: BatteryStatus) -> bool:
        # Low robots charge to the target first; the others work as soon as a job comes.
        if status.robot in self._low and status.charge >= self.target:
            self._low.discard(status.robot)
        return status.robot not in self._low
