"""The mixed-integer MPC controller plugin (`mpc`): Pyomo model, HiGHS solver."""

from fleet_plugins.mpc.controller import MPCController

__all__ = ["MPCController"]
