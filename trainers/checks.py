"""Checks every configuration of the trainers shares: the error a bad setting raises and
the rules that test a frozen dataclass's fields (types, choices, ranges).

A config object checks itself in ``__post_init__`` with these, so a setting is refused the
same way whether it came from the command line, a file or Python.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import os
import types
import typing
from collections.abc import Iterable
from typing import Any

import numpy as np


class ConfigError(ValueError):
    """An unknown key, a value of the wrong type, or a value out of range."""


def check_choice(name: str, value: Any, valid: Iterable[Any]) -> None:
    """Raise :class:`ConfigError` unless ``value`` is one of ``valid`` (listed)."""
    valid = list(valid)
    if value not in valid:
        raise ConfigError(f"{name}={value!r} is not valid; valid: {', '.join(map(str, valid))}")


def check_positive(owner: object, *names: str) -> None:
    """Raise :class:`ConfigError` unless every named integer field is ≥ 1."""
    for name in names:
        if getattr(owner, name) < 1:
            raise ConfigError(f"{name} must be ≥ 1, got {getattr(owner, name)}")


def check_finite(owner: object) -> None:
    """Raise :class:`ConfigError` unless every float field of ``owner`` is a finite number
    (NaN or infinity in a learning rate or a budget would pass every range check)."""
    for f in dataclasses.fields(owner):  # type: ignore[arg-type]
        value = getattr(owner, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{f.name} must be a finite number, got {value}")


_WRONG = object()


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def check_types(owner: object) -> None:
    """Raise :class:`ConfigError` unless every field of ``owner`` holds its annotated type.

    A config built directly (``TrainConfig(episodes=4.5)``, ``dataclasses.replace``) is
    checked as :func:`~neuronsmae.trainers.run.config.make_config` checks its layers: an int
    field takes a whole Python or NumPy number, a float field any real number (stored as a
    float), a str field a path too (stored as a str), a bool field only a bool.
    """
    for f in dataclasses.fields(owner):  # type: ignore[arg-type]
        kind, value = _hints(type(owner))[f.name], getattr(owner, f.name)
        if isinstance(kind, types.UnionType):
            if value is None and type(None) in typing.get_args(kind):
                continue
            kind = next(a for a in typing.get_args(kind) if a is not type(None))
        typed = _typed(value, kind)
        if typed is _WRONG:
            name = getattr(kind, "__name__", str(kind))
            got = f"{value!r:.80} ({type(value).__name__})"
            raise ConfigError(f"{f.name} expects {name}, got {got}")
        if typed is not value:
            object.__setattr__(owner, f.name, typed)


def _typed(value: Any, kind: Any) -> Any:
    """``value`` as a ``kind`` field holds it, or ``_WRONG``."""
    if kind is bool:
        return bool(value) if isinstance(value, (bool, np.bool_)) else _WRONG
    if isinstance(value, (bool, np.bool_)):
        return _WRONG  # not a number, nor a name
    if kind is int:
        if isinstance(value, numbers.Integral):
            return int(value)
        whole = isinstance(value, numbers.Real) and float(value).is_integer()
        return int(value) if whole else _WRONG
    if kind is float:
        return float(value) if isinstance(value, numbers.Real) else _WRONG
    if kind is str:
        if isinstance(value, str):
            return value
        return os.fspath(value) if isinstance(value, os.PathLike) else _WRONG
    if isinstance(kind, type) and dataclasses.is_dataclass(kind):
        return value if isinstance(value, kind) else _WRONG
    return value  # other annotations are checked by the field's own rule
