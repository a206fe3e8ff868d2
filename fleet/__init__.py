"""mambot-fleet: a discrete-event simulator for fleets of mobile additive-manufacturing robots.

The rooms, in the direction a run flows (docs/architecture.md): `fleet.scenario` (scenario
files), `fleet.floor` (map files -> convex regions in H-representation), `fleet.printing`
(G-code, print tasks and caps, quality), `fleet.paths` (reference paths and trajectories),
`fleet.plugins` (the contracts controllers and dispatchers implement, and their discovery),
`fleet.bus` (ZeroMQ messages between the engine and robot agents), `fleet.engine` (the SimPy
World), `fleet.view` (figures, replay) and `fleet.study` (sweeps, reports). `fleet.errors`,
`fleet.highs` and `fleet.cli` stand on their own. `fleet.api` is the Python API for notebooks
(docs/api.md); its names are this package's too (``fleet.run``, ``fleet.load_scenario``, ...),
imported on first use so that ``import fleet`` and the command line stay quick.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # for type checkers and editors; at run time `__getattr__` imports them
    from fleet.api import RunResult as RunResult
    from fleet.api import SweepResults as SweepResults
    from fleet.api import TableNotFound as TableNotFound
    from fleet.api import change as change
    from fleet.api import load_scenario as load_scenario
    from fleet.api import open_run as open_run
    from fleet.api import read_table as read_table
    from fleet.api import run as run
    from fleet.api import scenario_from_dict as scenario_from_dict
    from fleet.api import sweep as sweep

__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    # `fleet.api`'s names (its __all__) are this package's too, imported on first use.
    if not name.startswith("__"):
        import fleet.api

        if name in fleet.api.__all__:
            return getattr(fleet.api, name)
    raise AttributeError(f"module 'fleet' has no attribute {name!r}")
