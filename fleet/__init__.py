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

if TYPE_CHECKING:
    from fleet.api import (
        RunResult,
        SweepResults,
        TableNotFound,
        change,
        load_scenario,
        open_run,
        read_table,
        run,
        scenario_from_dict,
        sweep,
    )

__version__ = "0.1.0"

#: `fleet.api`'s names are offered here too (all but the version).
__all__ = [
    "__version__",
    "load_scenario",
    "scenario_from_dict",
    "change",
    "run",
    "open_run",
    "RunResult",
    "sweep",
    "SweepResults",
    "read_table",
    "TableNotFound",
]


def __getattr__(name: str) -> Any:
    if name in __all__ and name != "__version__":
        import fleet.api

        return getattr(fleet.api, name)
    raise AttributeError(f"module 'fleet' has no attribute {name!r}")
