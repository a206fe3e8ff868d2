"""The greedy dispatcher: oldest open job first, each to the nearest idle robot.

Registered as ``greedy`` under the ``fleet.dispatchers`` entry-point group. Scenario options::

    [dispatcher]
    name = "greedy"
    options = { metric = "travel_time" }   # or "euclidean" (the default)
"""

from fleet_plugins.greedy.dispatcher import METRICS, GreedyDispatcher

__all__ = ["GreedyDispatcher", "METRICS"]
