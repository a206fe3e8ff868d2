"""A run directory's tables, typed: every CSV it holds, by name, read on first use.

The tables are whatever the run directory holds (``jobs.csv`` is the table ``"jobs"``), not a
list kept here, so a table the recorder learns to write is a table here too. Each is returned as
columns, ``{column: [value, ...]}``, which ``pandas.DataFrame`` takes as it is. A column is typed
as a whole: whole numbers as `int`, other numbers as `float`, ``true``/``false`` as `bool`, else
`str`; an empty field is None.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from fleet.errors import FleetError

__all__ = ["TableNotFound", "Tables", "read_table", "rows_of"]

_INT = re.compile(r"[+-]?\d+")
_FLOAT = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|[+-]?(inf|nan)", re.IGNORECASE)
_BOOL = {"true": True, "false": False}


class TableNotFound(FleetError, KeyError):
    """No table of that name in the run directory; the message lists the ones there are."""

    def __str__(self) -> str:  # KeyError would quote the message like a key
        return str(self.args[0])


def read_table(path: str | Path) -> dict[str, list[Any]]:
    """The CSV file `path` as typed columns (see the module): ``{column: [value, ...]}``.

    Raises
    ------
    FleetError
        If a line has more or fewer fields than the header, or two columns share a name.
    """
    path = Path(path)
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            return {}
        if len(set(header)) != len(header):
            raise FleetError(f"{path}: the header names a column twice: {header}")
        columns: list[list[str]] = [[] for _ in header]
        for row in reader:
            if not row:
                continue
            if len(row) != len(header):
                raise FleetError(
                    f"{path}: line {reader.line_num} has {len(row)} fields, the header "
                    f"{len(header)}"
                )
            for column, value in zip(columns, row, strict=True):
                column.append(value)
    return {name: _typed(values) for name, values in zip(header, columns, strict=True)}


def _typed(values: list[str]) -> list[Any]:
    """One column's values, all of the one type every non-empty value fits."""
    present = [v for v in values if v != ""]
    if present and all(_INT.fullmatch(v) for v in present):
        convert: Any = int
    elif present and all(_FLOAT.fullmatch(v) for v in present):
        convert = float
    elif present and all(v.lower() in _BOOL for v in present):
        convert = lambda v: _BOOL[v.lower()]  # noqa: E731
    else:
        convert = str
    return [None if v == "" else convert(v) for v in values]


def rows_of(columns: Mapping[str, list[Any]]) -> list[dict[str, Any]]:
    """Typed columns as one dict per row (``pandas.DataFrame`` takes either form)."""
    names = list(columns)
    return [dict(zip(names, values, strict=True)) for values in zip(*columns.values(), strict=True)]


class Tables(Mapping[str, dict[str, list[Any]]]):
    """The CSV tables of one folder by name (the file name without ``.csv``), read on first
    use and kept; each access returns a fresh copy of the columns, free to change."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self._read: dict[str, dict[str, list[Any]]] = {}

    def names(self) -> tuple[str, ...]:
        """The tables there are, sorted."""
        return tuple(sorted(p.stem for p in self.folder.glob("*.csv") if p.is_file()))

    def path(self, name: str) -> Path:
        """The CSV file of table `name` (``"jobs"`` or ``"jobs.csv"``)."""
        stem = name.removesuffix(".csv")
        path = self.folder / f"{stem}.csv"
        if not path.is_file():
            there = ", ".join(self.names()) or "none"
            raise TableNotFound(
                f"{self.folder}: no table {name!r} (the tables there: {there}; a run writes "
                "caps and violations only when it has some)"
            )
        return path

    def __getitem__(self, name: str) -> dict[str, list[Any]]:
        path = self.path(name)
        if path.stem not in self._read:
            self._read[path.stem] = read_table(path)
        return {column: list(values) for column, values in self._read[path.stem].items()}

    def __contains__(self, name: object) -> bool:
        if not isinstance(name, str):
            return False
        return (self.folder / f"{name.removesuffix('.csv')}.csv").is_file()

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())

    def __repr__(self) -> str:
        return f"Tables({str(self.folder)!r}: {', '.join(self.names())})"
