"""Per-episode reset contexts for training, and the fixed ones for evaluation.

A training run plays each episode with contexts drawn from a *spec* (the ``contexts``
config key, ``--contexts`` on the command line): one entry per context key, separated by
``;``, each either

* ``key=value`` — fixed (``coef=0.5``; ``level`` takes a bot name or a released number);
* ``key=v1,v2,...`` — one of the listed values, uniformly (``coef=0.5,0.7,1,1.4,1.7,2``, the
  released scripts' randomisation of the damage coefficient);
* ``key=lo..hi`` — a number uniformly in ``[lo, hi]`` (``Friction_coeff=0.3..0.7``).

Keys are those of docs/contexts.md (dynamics keys for blue, ``opponent.<key>`` for red,
``coef``, ``opponent_hp``, ``opponent_speed``, ``level``); the arena checks them and their
ranges (:meth:`ContextSpec.extremes` lets a run check them all before it starts).

Episode ``k``'s draw depends only on the run seed and ``k``, like its reset seed: the
episodes of a resumed run draw exactly what an uninterrupted run would have, with no state
to checkpoint beyond the spec itself (saved in the run's config). Evaluation contexts are
fixed specs (no sets, no ranges), so every evaluation meets the same task.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from neuronsmae.protocol.levels import level_from_arg

CHOICE_SEP, RANGE_SEP, ENTRY_SEP = ",", "..", ";"
_STREAM = 0xC0_47E7
"""Third word of an episode's draw seed, so context draws never share a stream with the
trainer's other random numbers."""


class ContextSpecError(ValueError):
    """A contexts spec that does not parse: the message names the entry and the syntax."""


@dataclass(frozen=True)
class Entry:
    """One key of a spec: a fixed value, a set of choices, or a range."""

    key: str
    choices: tuple[Any, ...] = ()
    """The values to pick from uniformly (one value: fixed)."""
    low: float | None = None
    high: float | None = None
    """A range ``[low, high]`` to draw from uniformly (when ``choices`` is empty)."""

    def draw(self, rng: np.random.Generator) -> Any:
        if self.choices:
            return self.choices[int(rng.integers(len(self.choices)))]
        assert self.low is not None and self.high is not None
        return float(rng.uniform(self.low, self.high))

    def values(self) -> tuple[Any, ...]:
        """Every value a draw can give at the edges (the choices, or both ends)."""
        return self.choices or (self.low, self.high)


def _value(key: str, text: str) -> Any:
    text = text.strip()
    if key == "level":
        return level_from_arg(text)
    try:
        number = float(text)
    except ValueError:
        raise ContextSpecError(f"contexts: {key}={text!r} is not a number") from None
    if not math.isfinite(number):
        raise ContextSpecError(f"contexts: {key}={text!r} is not a finite number")
    return number


@dataclass(frozen=True)
class ContextSpec:
    """Parsed ``contexts`` spec; :meth:`sample` draws one episode's contexts."""

    entries: tuple[Entry, ...] = ()

    @classmethod
    def parse(cls, text: str) -> ContextSpec:
        """Parse ``"key=v;key=v1,v2;key=lo..hi"`` (empty: no contexts)."""
        entries: list[Entry] = []
        for part in filter(None, (p.strip() for p in text.split(ENTRY_SEP))):
            key, sep, rhs = (x.strip() for x in part.partition("="))
            if not sep or not key or not rhs:
                raise ContextSpecError(
                    f"contexts: {part!r} is not key=value, key=v1,v2,... or key=lo..hi"
                )
            if any(e.key == key for e in entries):
                raise ContextSpecError(f"contexts: {key!r} is given twice")
            if RANGE_SEP in rhs and key != "level":
                lo, hi = (_value(key, x) for x in rhs.split(RANGE_SEP, 1))
                if lo > hi:
                    raise ContextSpecError(f"contexts: {key}={rhs} has low > high")
                entries.append(Entry(key, low=lo, high=hi))
            else:
                values = tuple(_value(key, x) for x in rhs.split(CHOICE_SEP))
                entries.append(Entry(key, choices=values))
        return cls(tuple(entries))

    @property
    def fixed(self) -> bool:
        """Whether every key has one value (what evaluation contexts must be)."""
        return all(len(e.choices) == 1 for e in self.entries)

    def updated(self, other: ContextSpec) -> ContextSpec:
        """This spec with ``other``'s entries added, ``other`` winning on shared keys."""
        keys = {e.key for e in other.entries}
        return ContextSpec((*(e for e in self.entries if e.key not in keys), *other.entries))

    def sample(self, seed: int, k: int) -> dict[str, Any]:
        """Episode ``k``'s contexts for a run seeded ``seed``: the same for the same pair."""
        if not self.entries:
            return {}
        rng = np.random.default_rng([seed, k, _STREAM])
        return {e.key: e.draw(rng) for e in self.entries}

    def value(self) -> dict[str, Any]:
        """The contexts of a fixed spec; ``ContextSpecError`` if any key varies."""
        if not self.fixed:
            varying = [e.key for e in self.entries if len(e.choices) != 1]
            raise ContextSpecError(f"evaluation contexts must be fixed; {varying} vary")
        return {e.key: e.choices[0] for e in self.entries}

    def extremes(self) -> list[dict[str, Any]]:
        """Contexts that between them use every listed value and both ends of every range,
        so that checking these with the arena checks every draw's values."""
        width = max((len(e.values()) for e in self.entries), default=0)
        return [
            {e.key: e.values()[min(i, len(e.values()) - 1)] for e in self.entries}
            for i in range(width)
        ]


def merge(*layers: Mapping[str, Any]) -> dict[str, Any]:
    """Later layers' keys win (the run's opponent, then a spec's draws)."""
    out: dict[str, Any] = {}
    for layer in layers:
        out.update(layer)
    return out
