"""The discrete-event engine: the World (SimPy), its collaborators, agents, safety and recorder.

`world` is the SimPy loop and the wiring; each collaborator it builds has one job, and gets what
it needs passed in: `placement` (start spots, reachability checks), `motion` (the robots' state,
delayed inputs, turning in place), `jobs` (job records and where jobs come from), `lifecycle`
(release, print start, arrival, delivery, judging), `dispatch` (assignments, auctions,
hand-backs), `sensing` (observations, neighbours and their plans, priorities, deadlock watch),
`makeway` and `queueing` (robots stepping aside, and waiting their turn short of a station),
`homes` (a robot held up on its way home trading homes with a parked one),
`rounds` (the bus round), `breakdowns` (robots failing and repaired). `agents` runs the robot
agents' processes; `safety` judges every step; `recorder` keeps what happened and writes the
run directory, `summary` makes summary.json and the CSV rows from it. The engine may import
every room below it (floor, paths, printing, scenario, plugins, bus), never study or view.
"""

from fleet.engine.jobs import JobRecord, JobSource
from fleet.engine.motion import RobotState
from fleet.engine.recorder import Recorder
from fleet.engine.world import RunResult, World

__all__ = ["World", "RobotState", "RunResult", "JobRecord", "JobSource", "Recorder"]
