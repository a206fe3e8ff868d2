"""The path follower: the baseline controller, tracking the path layer's exact reference.

Registered under the ``fleet.controllers`` entry-point group as ``follower`` and as three
print strategies built on it, for throughput studies::

    [controller]
    name = "follower"
    options = { gain = 0.5 }   # position feedback per period, in [0, 1]; also speed (m/s),
                               # caps ("window", "ahead", "ignore"), print_first (bool),
                               # margin_m (gap kept to other robots, m), yield_s (s)

    name = "fixed_speed", options = { speed = 0.2 }  # print while driving at one speed
    name = "qsp_speed"                               # each print task at its own cap
    name = "print_first"                             # print standing, then drive
"""

from fleet_plugins.follower.controller import FixedSpeed, PathFollower, PrintFirst, QSPSpeed

__all__ = ["PathFollower", "FixedSpeed", "QSPSpeed", "PrintFirst"]
