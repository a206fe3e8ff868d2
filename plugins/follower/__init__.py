"""The path follower: the baseline controller, tracking the path layer's exact reference.

Registered as ``follower`` under the ``fleet.controllers`` entry-point group. Scenario options::

    [controller]
    name = "follower"
    options = { gain = 0.5 }   # position feedback per period, in [0, 1]
"""

from fleet_plugins.follower.controller import PathFollower

__all__ = ["PathFollower"]
