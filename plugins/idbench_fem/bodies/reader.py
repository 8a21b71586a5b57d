"""Reading the tables of a body TOML: checked values, one-line errors.

:class:`TableReader` reads the numbers, vectors, keys, choices and region
selectors of one table, raising ``ValueError`` naming the file, the table,
the bad value and what is allowed; :func:`table` takes a sub-table.
"""

from __future__ import annotations

import math
from typing import Any

from idbench_fem.bodies.regions import SELECTORS, Region

Vec = tuple[float, float, float]


class TableReader:
    """Values of one table of a TOML file, checked, with one-line errors.

    Parameters
    ----------
    source
        The file (for messages).
    where
        The table being read, e.g. ``"[material]"`` (for messages).
    """

    def __init__(self, source: str, where: str) -> None:
        self.source, self.where = source, where

    def error(self, text: str) -> ValueError:
        """A ValueError prefixed by the file and the table."""
        return ValueError(f"{self.source}: {self.where} {text}")

    def number(self, key: str, value: Any, positive: bool = False) -> float:
        """``value`` as a finite float (> 0 if ``positive``)."""
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if not ok or not math.isfinite(value) or (positive and value <= 0):
            need = "a number > 0" if positive else "a finite number"
            raise self.error(f"{key} = {value!r}: need {need}")
        return float(value)

    def vector(self, key: str, value: Any) -> Vec:
        """``value`` as three finite floats [x, y, z]."""
        if not isinstance(value, list | tuple) or len(value) != 3:
            raise self.error(f"{key} = {value!r}: need three numbers [x, y, z]")
        x, y, z = (self.number(key, v) for v in value)
        return (x, y, z)

    def keys(self, table: dict[str, Any], allowed: tuple[str, ...]) -> None:
        """Raise the error for the first key of ``table`` not in ``allowed``."""
        extra = sorted(set(table) - set(allowed))
        if extra:
            raise self.error(
                f"has unknown key {extra[0]!r}; allowed: {', '.join(allowed)}"
            )

    def region(self, key: str, value: Any) -> Region:
        """``value`` as a :class:`Region`: a name, or a table with one selector."""
        if isinstance(value, str):
            if not value:
                raise self.error(f"{key} = '': need a region name")
            return Region(name=value)
        if (
            not isinstance(value, dict)
            or len(value) != 1
            or (next(iter(value)) not in SELECTORS)
        ):
            raise self.error(
                f"{key} = {value!r}: need a region name or a table with exactly "
                f"one of {', '.join(SELECTORS)}"
            )
        ((kind, spec),) = value.items()
        return self._selector(f"{key}.{kind}", kind, spec)

    def _selector(self, key: str, kind: str, spec: Any) -> Region:
        if kind == "name":
            return self.region(key, spec)
        if kind == "slab":
            ok = isinstance(spec, dict) and set(spec) == {"index", "count"}
            index, count = (spec.get("index"), spec.get("count")) if ok else (0, 0)
            if not ok or not all(
                isinstance(v, int) and not isinstance(v, bool) for v in (index, count)
            ) or not 0 <= index < count:
                raise self.error(
                    f"{key} = {spec!r}: need a table with whole numbers index and "
                    "count, 0 <= index < count"
                )
            return Region(slab=(index, count))
        fields = {
            "box": ("lower", "upper"),
            "sphere": ("centre", "radius"),
            "half_space": ("point", "normal"),
            "patch": ("point", "radius"),
        }[kind]
        if not isinstance(spec, dict) or set(spec) != set(fields):
            raise self.error(
                f"{key} = {spec!r}: need a table with {' and '.join(fields)}"
            )
        a = self.vector(f"{key}.{fields[0]}", spec[fields[0]])
        if fields[1] == "radius":
            return Region(
                **{kind: (a, self.number(f"{key}.radius", spec["radius"], True))}
            )
        b = self.vector(f"{key}.{fields[1]}", spec[fields[1]])
        if kind == "box" and not all(lo < hi for lo, hi in zip(a, b, strict=True)):
            raise self.error(f"{key} = {spec!r}: need lower < upper in x, y and z")
        if kind == "half_space" and not any(b):
            raise self.error(f"{key}.normal = {list(b)}: need a non-zero normal")
        return Region(**{kind: (a, b)})

    def choice(self, key: str, value: Any, allowed: tuple[str, ...]) -> str:
        """``value`` if it is one of ``allowed``."""
        if value not in allowed:
            raise self.error(f"{key} = {value!r}: allowed are {', '.join(allowed)}")
        return str(value)


def table(raw: dict[str, Any], key: str, source: str) -> dict[str, Any]:
    """The sub-table ``raw[key]`` (empty if absent); a ValueError if not a table."""
    value = raw.get(key, {})
    if not isinstance(value, dict):
        raise ValueError(f"{source}: [{key}] must be a table, got {value!r}")
    return value
