"""The MPC controller's options, checked: a bad one raises ValueError naming it and its rule.

`check_options` checks what the constructor is given; `check_horizon` checks the horizon
against the robot it is reset for (long enough to brake, short enough for the print caps an
observation carries).
"""

from __future__ import annotations

import math
import numbers

from fleet.plugins import CAP_LOOKAHEAD_S, RobotSpec
from fleet_plugins.mpc.model import DEFAULT_MAX_NODES, Interface

__all__ = [
    "COSTS",
    "DEFAULT_MAX_NODES",
    "DEFAULT_REUSE_TICKS",
    "check_options",
    "check_horizon",
    "default_reuse_ticks",
]

#: The cost options: the 1-norm MILP, or that MILP's regions refined by the paper's quadratic cost.
COSTS = ("l1", "quadratic")

#: Ticks a plan is followed without a solve unless told (``reuse_ticks``): on the 40-robot fleet
#: it halves the CPU with 0 contacts, and case 3 and the MPC fuzz are as safe as with 0
#: (docs/mpc.md, "Solving less").
DEFAULT_REUSE_TICKS = 4


def default_reuse_ticks(horizon: int) -> int:
    """``reuse_ticks`` when it is not given: `DEFAULT_REUSE_TICKS`, kept below the horizon (a
    plan followed for `horizon` ticks has run out)."""
    return max(0, min(DEFAULT_REUSE_TICKS, horizon - 1))


def check_options(
    *,
    horizon: object,
    q_position: object,
    q_velocity: object,
    r_input: object,
    corridor: object,
    corridor_steps: object,
    time_limit_s: object,
    warm_start: object,
    interface: object,
    cost: object,
    avoid_robots: object,
    separation_margin_m: object,
    max_neighbours: object,
    respect_priority: object,
    reuse_ticks: object = DEFAULT_REUSE_TICKS,
    max_nodes: object = DEFAULT_MAX_NODES,
) -> Interface:
    """Raise ValueError for the first of `MPCController`'s options that breaks its rule;
    return the `Interface` that `interface` names."""
    if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 2:
        raise ValueError(f"MPCController option horizon = {horizon!r}: must be an integer >= 2")
    for label, w in (
        ("q_position", q_position),
        ("q_velocity", q_velocity),
        ("r_input", r_input),
    ):
        if not _non_negative(w):
            raise ValueError(f"MPCController option {label} = {w!r}: must be a number >= 0")
    for label, count in (("corridor", corridor), ("corridor_steps", corridor_steps)):
        if isinstance(count, bool) or not isinstance(count, int) or count < 0:
            raise ValueError(f"MPCController option {label} = {count!r}: must be an integer >= 0")
    if not _non_negative(time_limit_s) or time_limit_s == 0:
        raise ValueError(
            f"MPCController option time_limit_s = {time_limit_s!r}: must be a number > 0"
        )
    if (
        isinstance(max_nodes, bool)
        or not isinstance(max_nodes, int)
        or not 1 <= max_nodes <= _HIGHS_INT_MAX
    ):
        # 0 nodes stops every solve before its root: the robot would never move.
        raise ValueError(
            f"MPCController option max_nodes = {max_nodes!r}: must be an integer from 1 to "
            f"{_HIGHS_INT_MAX}"
        )
    for label, flag in (
        ("warm_start", warm_start),
        ("avoid_robots", avoid_robots),
        ("respect_priority", respect_priority),
    ):
        if not isinstance(flag, bool):
            raise ValueError(f"MPCController option {label} = {flag!r}: must be a bool")
    if not _non_negative(separation_margin_m):
        raise ValueError(
            f"MPCController option separation_margin_m = {separation_margin_m!r}: "
            "must be a number >= 0"
        )
    if (
        isinstance(max_neighbours, bool)
        or not isinstance(max_neighbours, int)
        or max_neighbours < 0
    ):
        raise ValueError(
            f"MPCController option max_neighbours = {max_neighbours!r}: must be an integer >= 0"
        )
    if (
        isinstance(reuse_ticks, bool)
        or not isinstance(reuse_ticks, int)
        or not 0 <= reuse_ticks < horizon
    ):
        # A plan followed for `horizon` ticks has run out: the robot would stand still.
        raise ValueError(
            f"MPCController option reuse_ticks = {reuse_ticks!r}: must be an integer >= 0 "
            f"and below the horizon ({horizon})"
        )
    try:
        checked = Interface(interface)
    except ValueError:
        allowed = ", ".join(repr(i.value) for i in Interface)
        raise ValueError(
            f"MPCController option interface = {interface!r}: must be one of {allowed}"
        ) from None
    if cost not in COSTS:
        allowed = ", ".join(repr(c) for c in COSTS)
        raise ValueError(f"MPCController option cost = {cost!r}: must be one of {allowed}")
    return checked


def check_horizon(horizon: int, spec: RobotSpec) -> None:
    """Raise ValueError if `horizon` steps of the robot's period are shorter than braking
    from full speed, or reach past the print caps an observation carries."""
    span = horizon * spec.period
    stop = spec.v_max / spec.a_max
    if span < stop - 1e-9:
        # Every plan ends at rest: a horizon shorter than braking from full speed never
        # lets the robot reach it, and a much shorter one never lets it start.
        raise ValueError(
            f"MPCController horizon {horizon} x period {spec.period:g} s = {span:g} s "
            f"is shorter than braking from full speed ({spec.v_max:g} / {spec.a_max:g} = "
            f"{stop:g} s); use horizon >= {math.ceil(stop / spec.period - 1e-9)}"
        )
    if span > CAP_LOOKAHEAD_S:
        raise ValueError(
            f"MPCController horizon {horizon} x period {spec.period:g} s = "
            f"{span:g} s reaches past the {CAP_LOOKAHEAD_S:g} s of print caps an "
            "observation carries; shorten the horizon"
        )


#: The largest value of a HiGHS integer option.
_HIGHS_INT_MAX = 2**31 - 1


def _non_negative(x: object) -> bool:
    return (
        not isinstance(x, bool)
        and isinstance(x, numbers.Real)
        and math.isfinite(float(x))
        and float(x) >= 0
    )
