"""The discrete-event engine: the World (SimPy), jobs, and the recorder of run directories."""

from fleet.engine.jobs import JobRecord, JobSource
from fleet.engine.recorder import Recorder
from fleet.engine.world import RobotState, RunResult, World

__all__ = ["World", "RobotState", "RunResult", "JobRecord", "JobSource", "Recorder"]
