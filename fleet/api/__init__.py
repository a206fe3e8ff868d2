"""The Python API for notebooks and scripts: load, build or change a scenario, run it, read its
tables, run a study (docs/api.md).

``import fleet`` gives the same names (`fleet.run`, `fleet.load_scenario`, ...), imported on
first use. Tables come as typed columns ``{column: [value, ...]}``, which
``pandas.DataFrame`` takes as they are; pandas is not needed. Nothing is printed on stdout: a
progress bar, when asked for, goes to stderr, and warnings (a run whose job accounting broke)
to the ``fleet`` logger. The API calls what the command line calls: `runs.simulate` runs a
World for ``fleet run`` too, and `sweep` is ``fleet sweep``'s `fleet.study.sweep.run_study`.
"""

from fleet.api.runs import RunResult, open_run, run
from fleet.api.scenarios import change, load_scenario, scenario_from_dict
from fleet.api.sweeps import SweepResults, sweep
from fleet.api.tables import TableNotFound, read_table

__all__ = [
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
