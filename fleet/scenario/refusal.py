"""Restating msgspec's refusal of a scenario value as a `ScenarioError`: file, field, value, rule.

msgspec says where a value broke the structure (``... - at `$.robots[1].period_s```) but not
the value, and in its own words. `refusal` follows that path through the raw TOML tables and the
declared types side by side, so it can quote the value as written and say what the declared
type allows: a rule the type carries (``Meta(extra={"rule": ...})``, see `fleet.scenario.spec`),
the alternatives of a `Literal`, or msgspec's words in ours.
"""

from __future__ import annotations

import re
import sys
import types
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import msgspec

from fleet.errors import ScenarioError

__all__ = ["convert"]

# "<what> - at `$.a[0].b`", or for a dict's key "<what> - at `key` in `$.a`"; no path at `$`.
_MESSAGE = re.compile(r"(?P<what>.*?)(?: - at `(?P<at>[^`]*)`(?: in `(?P<key_of>[^`]*)`)?)?")
_STEP = re.compile(r"\.(\w+)|\[(\d+|\.\.\.)\]")
_FIELD = re.compile(r"Object (?P<kind>contains unknown|missing required) field `(?P<name>\w+)`")
_TYPES = re.compile(r"Expected `(?P<expected>[^`]+)`, got `\w+`")
_BOUND = re.compile(r"Expected `(?P<type>int|float)` (?P<op>[<>]=?) (?P<bound>\S+)")

#: How the rules name msgspec's types (as the scenario reader always has: Python's names).
_TYPE_NAMES = {"float": "int or float", "array": "list", "object": "dict"}


def convert(value: Any, declared: Any, source: str, where: str = "") -> Any:
    """`value` converted to the `declared` type, or a `ScenarioError` naming `source`.

    `where` is the field `value` sits at (empty for a whole file): errors name fields below it.
    """
    try:
        return msgspec.convert(value, declared)
    except msgspec.ValidationError as exc:
        raise refusal(str(exc), value, declared, source, where) from None


def refusal(message: str, value: Any, declared: Any, source: str, where: str) -> ScenarioError:
    """The `ScenarioError` msgspec's `message` about converting `value` to `declared` means."""
    match = _MESSAGE.fullmatch(message)
    assert match is not None  # every message matches: its location is optional
    what, at, key_of = match["what"], match["at"] or "$", match["key_of"]
    steps = [name or index for name, index in _STEP.findall(key_of or at)]
    if key_of:
        steps.append("...")  # the bad key of the dict at `key_of`
    field = where
    for step in steps:
        bare = _bare(_member(declared, value))
        if step == "...":
            key, declared = _bad_entry(bare, value)
            field, value = f"{field}.{key}", value[key]
        elif step.isdigit():
            index = int(step)
            items = get_args(bare)
            declared = items[index] if get_origin(bare) is tuple else items[0]
            field, value = f"{field}[{index}]", value[index]
        else:
            declared = _fields(bare)[step]
            field, value = f"{field}.{step}" if field else step, value[step]

    known = _FIELD.fullmatch(what)
    if known is None:
        return ScenarioError(source, field, value, _rule(what, declared, value))
    name = known["name"]
    inner = f"{field}.{name}" if field else name
    if known["kind"] == "missing required":
        return ScenarioError(source, inner, None, "is required")
    allowed = ", ".join(sorted(_fields(_bare(_member(declared, value)))))
    return ScenarioError(source, inner, value[name], f"unknown key (allowed here: {allowed})")


def _rule(what: str, declared: Any, value: Any) -> str:
    """What `declared` allows, for a `value` msgspec refused with `what`."""
    member = _member(declared, value)
    for type_ in (declared, member):  # a union's own rule judges the value whole
        if get_origin(type_) is Annotated:
            for meta in type_.__metadata__:
                if isinstance(meta, msgspec.Meta) and meta.extra and "rule" in meta.extra:
                    return meta.extra["rule"]
    if what.startswith("Invalid enum value"):
        return "must be " + " or ".join(repr(v) for v in get_args(_bare(member)))
    if expected := _TYPES.fullmatch(what):
        names = [_TYPE_NAMES.get(t, t) for t in expected["expected"].split(" | ") if t != "null"]
        return f"must be of type {' or '.join(names)}"
    if bound := _BOUND.fullmatch(what):
        number = "whole number" if bound["type"] == "int" else "number"
        op, limit = bound["op"], float(bound["bound"])
        if abs(limit) == sys.float_info.max:
            return "must be a finite number"
        # msgspec states an int's "> 0" as ">= 1".
        if (op, limit) == (">", 0) or (number == "whole number" and (op, limit) == (">=", 1)):
            return f"must be a positive {number}"
        return f"must be a {number} {op} {limit:g}"
    return what


def _bare(declared: Any) -> Any:
    """`declared` without its `Annotated` metadata."""
    return get_args(declared)[0] if get_origin(declared) is Annotated else declared


def _member(declared: Any, value: Any) -> Any:
    """The member of the union `declared` that a TOML value like `value` is meant for.

    A table goes to a struct or a dict, an array to a list or a tuple, a string to a `Literal`
    or a str, a number to a number: the member whose shape fits, whatever else is wrong with
    the value. Not a union, or no member fits: `declared` itself.
    """
    if get_origin(_bare(declared)) not in (Union, types.UnionType):
        return declared
    return next((m for m in get_args(_bare(declared)) if _fits(m, value)), declared)


def _fits(declared: Any, value: Any) -> bool:
    bare = _bare(declared)
    origin = get_origin(bare) or bare
    if origin is Literal:
        shapes: tuple[type, ...] = tuple({type(v) for v in get_args(bare)})
    elif isinstance(origin, type) and issubclass(origin, msgspec.Struct):
        shapes = (dict,)
    elif origin in (list, tuple):
        shapes = (list,)
    elif origin is float:
        shapes = (int, float)
    else:
        shapes = (origin,) if isinstance(origin, type) else ()
    # TOML's true and false are Python ints too; they are never numbers here.
    return isinstance(value, shapes) and (bool in shapes or not isinstance(value, bool))


def _fields(struct: type[msgspec.Struct]) -> dict[str, Any]:
    """A struct's declared types by the keys the file uses."""
    return {f.encode_name: f.type for f in msgspec.structs.fields(struct)}


def _bad_entry(declared: Any, table: dict[str, Any]) -> tuple[str, Any]:
    """The first key of `table` whose key or value `declared` (a dict type) refuses, and the
    type that refuses it (the key's or the value's)."""
    key_type, value_type = get_args(declared)
    for key, item in table.items():
        for type_, part in ((key_type, key), (value_type, item)):
            try:
                msgspec.convert(part, type_)
            except msgspec.ValidationError:
                return key, type_
    raise AssertionError("msgspec refused an entry that every check accepts")
