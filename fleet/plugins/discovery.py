"""Discovery: the controllers, dispatchers and charging policies registered through entry points.

A plugin is a class registered under an entry-point group in its distribution's
``pyproject.toml``; the built-in ones in ``plugins/`` register exactly the same way::

    [project.entry-points."fleet.controllers"]
    my_controller = "my_package.module:MyController"

    [project.entry-points."fleet.dispatchers"]
    my_dispatcher = "my_package.module:MyDispatcher"

    [project.entry-points."fleet.charging"]
    my_policy = "my_package.module:MyChargingPolicy"

The class is instantiated with the keyword options from the scenario
(``[controller.options]`` / ``[dispatcher.options]`` / ``[charging.options]``).
"""

from __future__ import annotations

import importlib
import importlib.metadata
import sys
import threading
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from fleet.errors import PluginError
from fleet.plugins.charging import CHARGING_GROUP, ChargingPolicy
from fleet.plugins.contracts import CONTROLLER_GROUP, DISPATCHER_GROUP, Controller, Dispatcher

__all__ = [
    "PluginWarning",
    "PluginInfo",
    "discover",
    "load_controller",
    "load_dispatcher",
    "load_charging_policy",
]

# Each kind: its entry-point group, the base class a plugin must subclass, and the one method it
# must implement. Validation checks exactly these, so the error can name the broken one.
_KINDS: dict[str, tuple[str, type, str]] = {
    "controller": (CONTROLLER_GROUP, Controller, "compute"),
    "dispatcher": (DISPATCHER_GROUP, Dispatcher, "assign"),
    "charging": (CHARGING_GROUP, ChargingPolicy, "go_charge"),
}

# Per-process cache of `discover()`: kind -> plugins in entry-point order. None until first use.
_CACHE: dict[str, tuple[PluginInfo, ...]] | None = None
#: Held while the entry points are read (reentrant: a plugin's import may ask for plugins).
_CACHE_LOCK = threading.RLock()


class PluginWarning(UserWarning):
    """A registered plugin is broken (or shadowed) and was skipped; the message says why."""


@dataclass(frozen=True)
class PluginInfo:
    """One registered plugin as discovery found it, usable or not.

    Attributes
    ----------
    name:
        Entry-point name: what a scenario writes in ``[controller] name = ...``.
    kind:
        ``"controller"``, ``"dispatcher"`` or ``"charging"`` (a charging policy).
    group:
        The entry-point group it was registered under (`CONTROLLER_GROUP`, `DISPATCHER_GROUP`).
    value:
        The entry point's target, ``"module:Class"``.
    distribution, version:
        The installed distribution that registered it (None if unknown).
    origin:
        The file the class lives in (None when it could not be imported).
    factory:
        The validated plugin class; None when the plugin is broken.
    error:
        Why the plugin cannot be used (import error, wrong base class, abstract method,
        shadowed by an earlier plugin of the same name); None when it is usable.
    """

    name: str
    kind: str
    group: str
    value: str
    distribution: str | None = None
    version: str | None = None
    origin: str | None = None
    factory: type | None = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        """Whether the plugin loaded and passed validation."""
        return self.factory is not None and self.error is None

    def describe(self) -> str:
        """``name (group = module:Class from dist version)``, for messages and listings."""
        source = f" from {self.distribution} {self.version}" if self.distribution else ""
        return f"{self.kind} plugin {self.name!r} ({self.group} = {self.value}{source})"


def discover(kind: str | None = None, *, refresh: bool = False) -> list[PluginInfo]:
    """Every registered plugin (of `kind`, or of every kind), usable or broken.

    The entry points are read, imported and validated once per process; pass ``refresh=True``
    to read them again (after installing a plugin at runtime, or in tests). A broken plugin is
    listed with its `PluginInfo.error` and reported once per read with a `PluginWarning`; it
    never stops the others from loading. When two plugins of one kind share a name, the first
    found on ``sys.path`` wins and the other is listed as shadowed.

    Parameters
    ----------
    kind:
        ``"controller"``, ``"dispatcher"``, ``"charging"`` or None for every kind.
    refresh:
        Read the entry points again instead of using the per-process cache.

    Returns
    -------
    list[PluginInfo]
        Sorted by kind, then name (a winner before the plugins it shadows).

    Raises
    ------
    ValueError
        If `kind` is not one of the allowed values.
    """
    global _CACHE
    if kind is not None and kind not in _KINDS:
        raise ValueError(f"plugin kind {kind!r} is unknown; allowed: {', '.join(_KINDS)} or None")
    cache = _CACHE
    if cache is None or refresh:
        with _CACHE_LOCK:
            # Threads (a Dask worker's, say) may all find no cache: one reads, the others
            # wait and take its result. The registry is published whole, in one assignment,
            # so no thread ever sees one partly filled.
            cache = _CACHE
            if cache is None or refresh:
                # A plugin installed since the last read may live in a directory whose
                # listing the import system has cached.
                importlib.invalidate_caches()
                fresh = {}
                for k in _KINDS:  # a plain loop so the warnings' stacklevel points at our caller
                    fresh[k] = _scan(k)
                _CACHE = cache = fresh
    kinds = [kind] if kind is not None else sorted(_KINDS)
    # sorted() is stable, so among equal names the winner (found first) stays first.
    return [info for k in kinds for info in sorted(cache[k], key=lambda i: i.name)]


def load_controller(name: str, options: Mapping[str, Any] | None = None) -> Controller:
    """Instantiate the controller plugin registered as `name` with keyword `options`.

    Raises
    ------
    PluginError
        If no usable controller is registered as `name` (the message lists the available
        ones), if the plugin is broken (the message says why), or if its constructor rejects
        the options (the message names the plugin and the options).
    """
    return _load("controller", name, options)  # type: ignore[return-value]


def load_dispatcher(name: str, options: Mapping[str, Any] | None = None) -> Dispatcher:
    """Instantiate the dispatcher plugin registered as `name` with keyword `options`.

    Raises
    ------
    PluginError
        As for `load_controller`.
    """
    return _load("dispatcher", name, options)  # type: ignore[return-value]


def load_charging_policy(name: str, options: Mapping[str, Any] | None = None) -> ChargingPolicy:
    """Instantiate the charging-policy plugin registered as `name` with keyword `options`.

    Raises
    ------
    PluginError
        As for `load_controller`.
    """
    return _load("charging", name, options)  # type: ignore[return-value]


def _load(kind: str, name: str, options: Mapping[str, Any] | None) -> Any:
    found = [info for info in discover(kind) if info.name == name]
    usable = [info for info in found if info.ok]
    if not usable:
        group = _KINDS[kind][0]
        if found:
            raise PluginError(f"{found[0].describe()} cannot be used: {found[0].error}")
        available = ", ".join(sorted({i.name for i in discover(kind) if i.ok})) or "none"
        raise PluginError(
            f"no {kind} plugin named {name!r} is registered under entry-point group {group!r}; "
            f"available: {available}"
        )
    info = usable[0]
    assert info.factory is not None
    opts = dict(options or {})
    try:
        return info.factory(**opts)
    except (TypeError, ValueError) as exc:
        # Options come from a user's scenario: say which plugin and which options, and pass on
        # the constructor's own words (they name the bad keyword or value).
        raise PluginError(
            f"{info.describe()} rejected options {opts!r}: {exc}; "
            f"see the plugin's documentation for the options it accepts"
        ) from exc


def _scan(kind: str) -> tuple[PluginInfo, ...]:
    """Read, import and validate every entry point of `kind`, warning about broken ones."""
    group = _KINDS[kind][0]
    found: list[PluginInfo] = []
    winners: dict[str, PluginInfo] = {}
    for ep in importlib.metadata.entry_points(group=group):
        dist = getattr(ep, "dist", None)
        base = PluginInfo(
            name=ep.name,
            kind=kind,
            group=group,
            value=ep.value,
            distribution=dist.name if dist is not None else None,
            version=dist.version if dist is not None else None,
        )
        first = winners.get(ep.name)
        if first is not None:
            if (first.value, first.distribution) == (base.value, base.distribution):
                continue  # the same distribution seen twice on sys.path: not a conflict
            info = replace(
                base,
                error=f"name already taken by {first.describe()}, which wins (found first on "
                f"sys.path); rename one of the entry points to use both",
            )
        else:
            info = _validate(base, ep)
            if info.ok:
                winners[ep.name] = info
        if info.error is not None:
            warnings.warn(f"skipping {info.describe()}: {info.error}", PluginWarning, stacklevel=3)
        found.append(info)
    return tuple(found)


def _validate(info: PluginInfo, ep: importlib.metadata.EntryPoint) -> PluginInfo:
    """Import the entry point and check it against its kind's contract."""
    _group, base_class, method = _KINDS[info.kind]
    contract = f"fleet.plugins.{base_class.__qualname__}"  # the name plugin authors import
    try:
        obj = ep.load()
    except Exception as exc:  # any failure inside a third party's import is that plugin's fault
        module = sys.modules.get(ep.module)
        return replace(
            info,
            origin=getattr(module, "__file__", None),
            error=f"cannot import {ep.value!r}: {type(exc).__name__}: {exc}",
        )
    info = replace(info, origin=_origin(obj, ep))
    if not isinstance(obj, type) or not issubclass(obj, base_class):
        return replace(
            info,
            error=f"{ep.value!r} is {_describe_object(obj)}, not a subclass of {contract}",
        )
    if not callable(getattr(obj, method, None)):
        return replace(info, error=f"{ep.value!r} has no callable method {method!r}")
    abstract = sorted(getattr(obj, "__abstractmethods__", ()))
    if abstract:
        return replace(
            info,
            error=f"{ep.value!r} does not implement the abstract method(s) "
            f"{', '.join(abstract)} of {contract}",
        )
    return replace(info, factory=obj)


def _origin(obj: object, ep: importlib.metadata.EntryPoint) -> str | None:
    """The file defining `obj` (falling back to the entry point's module)."""
    module = sys.modules.get(getattr(obj, "__module__", None) or ep.module)
    module = module or sys.modules.get(ep.module)
    path = getattr(module, "__file__", None)
    return str(path) if path else None


def _describe_object(obj: object) -> str:
    if isinstance(obj, type):
        return f"the class {obj.__module__}.{obj.__qualname__}"
    return f"a {type(obj).__name__} object"
