"""mambot-fleet: a discrete-event simulator for fleets of mobile additive-manufacturing robots.

The rooms, in the direction a run flows (docs/architecture.md): `fleet.scenario` (scenario
files), `fleet.floor` (map files -> convex regions in H-representation), `fleet.printing`
(G-code, print tasks and caps, quality), `fleet.paths` (reference paths and trajectories),
`fleet.plugins` (the contracts controllers and dispatchers implement, and their discovery),
`fleet.bus` (ZeroMQ messages between the engine and robot agents), `fleet.engine` (the SimPy
World), `fleet.view` (figures, replay) and `fleet.study` (sweeps, reports). `fleet.errors`,
`fleet.highs` and `fleet.cli` stand on their own.
"""

__version__ = "0.1.0"
