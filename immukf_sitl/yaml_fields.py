"""One reader for the mappings of a YAML file: typed fields, one-line errors naming the field.

Scenario files (:mod:`immukf_sitl.scenario`) and campaign files
(:mod:`immukf_sitl.experiments.campaign`) read their mappings through :class:`YamlFields`, so a
user gets the same kind of message from either: ``file: where.field: expected ..., got ...``,
``file: field: required field is missing`` or ``file: field: unknown field (expected one of
...)``. The error class is the caller's (a :class:`~immukf_sitl.errors.UserError`), so the
command line prints it as one line.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from immukf_sitl.errors import UserError

__all__ = ["YamlFields"]


class YamlFields:
    """Reads one mapping of ``path`` (at ``where``), naming ``file: field`` in every error.

    Parameters
    ----------
    path : str
        The file, as the user named it.
    where : str
        Dotted position of this mapping in the file ("" at the top level).
    data : Any
        What the file holds there; anything but a mapping is an error.
    error : type of UserError
        The exception raised for every problem.
    """

    def __init__(
        self, path: str, where: str, data: Any, error: type[UserError] = UserError
    ) -> None:
        self.path, self.where, self.error = path, where, error
        if not isinstance(data, Mapping):
            self.fail("", "a mapping", data)
        self.data = dict(data)
        self.used: set[str] = set()

    def name(self, key: str) -> str:
        """Dotted name of ``key`` in the file."""
        return f"{self.where}.{key}" if self.where else key

    def fail(self, key: str, expected: str, got: Any) -> None:
        """Raise the one-line error: ``key`` held ``got`` where ``expected`` was wanted."""
        where = self.name(key) if key else (self.where or "top level")
        raise self.error(f"{self.path}: {where}: expected {expected}, got {got!r}")

    def has(self, key: str) -> bool:
        """Whether the mapping holds ``key``."""
        return key in self.data

    def raw(self, key: str, default: Any = ...) -> Any:
        """The value of ``key`` as the file holds it (``default`` if absent; none: required)."""
        self.used.add(key)
        if key not in self.data:
            if default is ...:
                raise self.error(f"{self.path}: {self.name(key)}: required field is missing")
            return default
        return self.data[key]

    def number(
        self,
        key: str,
        default: Any = ...,
        *,
        lo: float = -math.inf,
        hi: float = math.inf,
        lo_open: bool = False,
    ) -> float:
        """A finite number within ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""
        value = self.raw(key, default)
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
        ):
            self.fail(key, "a number", value)
        ok = (value > lo if lo_open else value >= lo) and value <= hi
        if not ok:
            bound = f"> {lo}" if lo_open else f">= {lo}"
            rng = bound if hi == math.inf else f"{bound} and <= {hi}"
            self.fail(key, f"a number {rng}", value)
        return float(value)

    def integer(self, key: str, default: Any = ..., *, lo: int = 0) -> int:
        """An integer of at least ``lo``."""
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < lo:
            self.fail(key, "a non-negative integer" if lo == 0 else f"an integer >= {lo}", value)
        return int(value)

    def string(self, key: str, default: Any = ...) -> str:
        """A non-empty string."""
        value = self.raw(key, default)
        if not isinstance(value, str) or not value.strip():
            self.fail(key, "a non-empty string", value)
        return value

    def boolean(self, key: str, default: Any = ...) -> bool:
        """``true`` or ``false``."""
        value = self.raw(key, default)
        if not isinstance(value, bool):
            self.fail(key, "true or false", value)
        return value

    def vector3(self, key: str, default: Any = ...) -> tuple[float, float, float]:
        """A list of three numbers."""
        value = self.raw(key, default)
        if (
            not isinstance(value, list | tuple)
            or len(value) != 3
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        ):
            self.fail(key, "a list of 3 numbers", value)
        return (float(value[0]), float(value[1]), float(value[2]))

    def child(self, key: str, default: Any = ...) -> YamlFields:
        """The mapping at ``key``, read the same way."""
        return YamlFields(self.path, self.name(key), self.raw(key, default), self.error)

    def done(self) -> None:
        """Refuse any field that was never read: a misspelt key must not vanish."""
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise self.error(
                f"{self.path}: {self.name(unknown[0])}: unknown field "
                f"(expected one of {', '.join(sorted(self.used))})"
            )
