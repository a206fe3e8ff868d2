"""Built-in plugins of mambot-fleet, importable as ``fleet_plugins``.

Each sub-package is an ordinary plugin, registered through the same entry points a third
party's would use (see ``pyproject.toml``):

- ``fleet_plugins.follower``: `PathFollower`, the baseline controller (``fleet.controllers``
  name ``follower``): tracks the path layer's exact reference, no optimisation.
- ``fleet_plugins.greedy``: `GreedyDispatcher` (``fleet.dispatchers`` name ``greedy``): oldest
  open job to the nearest idle robot.

Nothing here is imported by the core: the engine finds these through `fleet.plugins.discover`.
"""

__all__: list[str] = []
