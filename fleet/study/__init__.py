"""Studies: many runs and what they say together.

`sweep` (a grid of scenario cells over seeds, content-addressed and resumable, on any
`concurrent.futures` executor), `report` (statistics across seeds, figures, ``report.md``),
`lowerbound` (the minimum-time lower bound of a trip, the yardstick for controllers). This room
sits above the engine: it may import the scenario, the plugins, the engine and the view.
Import the module you need (``from fleet.study.sweep import run_study``).
"""
