"""Reading YAML fields with errors that name the dotted key and the valid choices.

:class:`FieldReader` is the base of the scene reader
(:class:`calib_oed.scene.reader.SceneReader`) and of the ``cell:`` and
``feasibility:`` blocks (:mod:`calib_oed.scene.cell`): every value it returns
is checked and converted to SI with the file's units.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from calib_oed.exceptions import SceneError


class FieldReader:
    """Validates the parsed YAML key by key; errors name the dotted key."""

    def __init__(self, source: str | None):
        self.source = source
        self.length = self.angle = 1.0  # [m] and [rad] per file unit
        self.units = {"length": "m", "angle": "rad"}

    def fail(self, key: str | None, message: str) -> SceneError:
        return SceneError(message, key=key, source=self.source)

    def mapping(self, value, key, required, optional=()) -> dict:
        where = f"{key}." if key else ""
        if not isinstance(value, Mapping):
            raise self.fail(key, f"expected a mapping with keys {_keys(required, optional)}, "
                            f"got {value!r}")
        valid = (*required, *optional)
        for k in value:
            if k not in valid:
                raise self.fail(f"{where}{k}", f"unknown key; valid keys of {_at(key)} are: "
                                f"{', '.join(valid)}")
        for k in required:
            if k not in value:
                raise self.fail(f"{where}{k}", f"missing required key; {_at(key)} requires: "
                                f"{', '.join(required)}")
        return dict(value)

    def free_mapping(self, value, key) -> dict:
        if not isinstance(value, Mapping):
            raise self.fail(key, f"expected a mapping {{joint name: value}}, got {value!r}")
        return dict(value)

    def number(self, value, key, scale=1.0, positive=False, nonnegative=False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            hint = ""
            if isinstance(value, str) and _parses_as_float(value):
                hint = " (YAML reads a number like 1e-5 as text: write 1.0e-5)"
            raise self.fail(key, f"expected a number, got {value!r}{hint}")
        if not math.isfinite(value):
            raise self.fail(key, f"expected a finite number, got {value!r}")
        if positive and value <= 0:
            raise self.fail(key, f"expected a number > 0, got {value!r}")
        if nonnegative and value < 0:
            raise self.fail(key, f"expected a number >= 0, got {value!r}")
        return float(value) * scale

    def vector(self, value, key, n, scale=1.0, what=None) -> np.ndarray:
        """A list of ``n`` finite numbers times ``scale``; ``what`` explains the entries."""
        why = f" ({what})" if what else ""
        if not isinstance(value, list):
            raise self.fail(key, f"expected a list of {n} numbers{why}, got {value!r}")
        if len(value) != n:
            raise self.fail(key, f"expected {n} values{why}, got {len(value)}: {value!r}")
        return np.array([self.number(v, f"{key}[{i}]", scale) for i, v in enumerate(value)])

    def vector3_or_scalar(self, value, key, scale) -> np.ndarray:
        """A number > 0 for all three axes, or a list of three."""
        if not isinstance(value, list):
            return np.full(3, self.number(value, key, scale, positive=True))
        if len(value) != 3:
            raise self.fail(key, f"expected a number or 3 values, got {len(value)}: {value!r}")
        return np.array([self.number(v, f"{key}[{i}]", scale, positive=True)
                         for i, v in enumerate(value)])

    def string(self, value, key, choices=None) -> str:
        if choices is not None and (not isinstance(value, str) or value not in choices):
            raise self.fail(key, f"expected one of {', '.join(choices)}, got {value!r}")
        if not isinstance(value, str) or not value:
            raise self.fail(key, f"expected a non-empty string, got {value!r}")
        return value

    def integer(self, value, key, minimum=0) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise self.fail(key, f"expected an integer >= {minimum}, got {value!r}")
        return value

    def named_list(self, value, key, fields, what, optional=()) -> list[dict]:
        if not isinstance(value, list) or not value:
            raise self.fail(key, f"expected a non-empty list of {what}s, got {value!r}")
        items, seen = [], set()
        for i, item in enumerate(value):
            item = self.mapping(item, f"{key}[{i}]", fields, optional)
            name = self.string(item["name"], f"{key}[{i}].name")
            if name in seen:
                raise self.fail(f"{key}[{i}].name", f"duplicate {what} name {name!r}")
            seen.add(name)
            items.append(item)
        return items


def _keys(required, optional) -> str:
    return ", ".join([*required, *(f"{k} (optional)" for k in optional)]) or "(none fixed)"


def _at(key: str | None) -> str:
    return repr(key) if key else "the top level"


def _parses_as_float(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False
