"""The exception tree: every error the project raises on purpose derives from `FleetError`.

Errors on user input (`InputError` and its subclasses) always name the file, the field and the
bad value, and say what is allowed, so a user can fix the file without reading our code.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "FleetError",
    "InputError",
    "MapError",
    "ScenarioError",
    "GcodeError",
    "CalibrationError",
    "NoPathError",
    "MessageError",
    "PluginError",
]


class FleetError(Exception):
    """Root of every error mambot-fleet raises on purpose."""


class InputError(FleetError):
    """A value in a user's file is wrong.

    Parameters
    ----------
    source:
        The file (or other origin) the value came from.
    field:
        Dotted path of the field inside the file, e.g. ``obstacles[2].polygon``.
    value:
        The offending value, quoted in the message.
    rule:
        What is allowed, phrased so the user knows what to write instead.
    """

    def __init__(self, source: str, field: str, value: Any, rule: str) -> None:
        self.source = str(source)
        self.field = field
        self.value = value
        self.rule = rule
        super().__init__(f"{self.source}: {field} = {_show(value)}: {rule}")


class MapError(InputError):
    """A floor map file is malformed or describes an impossible floor."""


class ScenarioError(InputError):
    """A scenario file (or a CLI option overriding it) is malformed."""


class GcodeError(InputError):
    """A G-code file is not G-code, is truncated, has no extrusion or holds a bad value.

    `field` names the place in the file, e.g. ``line 1234`` or ``(file)``.
    """


class CalibrationError(InputError):
    """A quality calibration file (CSV) is malformed or cannot be fitted."""


class NoPathError(FleetError):
    """No collision-free path joins the start to the goal on this floor."""

    def __init__(self, start: tuple[float, float], goal: tuple[float, float], reason: str) -> None:
        self.start = start
        self.goal = goal
        super().__init__(f"no path from {_point(start)} to {_point(goal)}: {reason}")


class MessageError(FleetError):
    """A bus message is malformed, of an unknown schema version, or unexpected."""


class PluginError(FleetError):
    """A plugin cannot be loaded or does not meet its contract."""


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 200 else text[:197] + "..."


def _point(p: tuple[float, float]) -> str:
    return f"({p[0]:g}, {p[1]:g})"
