"""The built-in charging policies (``fleet.charging`` entry points), used with ``[battery]``.

- ``threshold`` (`ThresholdCharging`): below `threshold` of its capacity a robot finishes its
  job, drives to the nearest free charger and charges to `target`, taking no jobs meanwhile.
- ``opportunity`` (`OpportunityCharging`): an idle robot below `below` near a free charger
  charges there until it is given a job (or `full`); below `safety` it charges as
  ``threshold`` does.

Scenario options::

    [charging]
    name = "threshold"
    options = { threshold = 0.3, target = 0.9 }
"""

from fleet_plugins.charging.policies import OpportunityCharging, ThresholdCharging, nearest_free

__all__ = ["ThresholdCharging", "OpportunityCharging", "nearest_free"]
