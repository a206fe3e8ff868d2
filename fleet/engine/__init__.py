"""The discrete-event engine: the World (SimPy), jobs, agents, safety checks and the recorder.

`world` is the loop and the wiring; `jobs` the job lifecycle; `agents` the robot agents'
processes; `safety` judges every step; `recorder` writes the run directory. The engine may
import every room below it (floor, paths, printing, scenario, plugins, bus), never study or view.
"""

from fleet.engine.jobs import JobRecord, JobSource
from fleet.engine.motion import RobotState
from fleet.engine.recorder import Recorder
from fleet.engine.world import RunResult, World

__all__ = ["World", "RobotState", "RunResult", "JobRecord", "JobSource", "Recorder"]
