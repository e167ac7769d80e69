"""The checks of a joint action, shared by the arena, the vector server and the clients.

The in-process ``Arena`` validates every step with :func:`check_joint`; ``RM`` and the
client faces refuse what cannot be sent as a joint action with :func:`check_sequence`
before anything goes on the wire; a ``VecRM`` over several servers runs :func:`check_joint`
on every arena's row before it sends any, so no server is left to refuse a request the
others would carry out. One function per rule keeps all of them giving the same answer.

What is checked follows what is used: an action the arena will not use this step is not
checked (the team a bot drives, ``bot_team``; see :func:`check_joint`'s ``used``), just as a
vector ignores the rows of arenas that do not step (``VecArenaAPI.step``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence, Set
from typing import Any

import numpy as np

from neuronsmae.protocol.env_info import V_MAX, W_MAX
from neuronsmae.protocol.errors import InvalidActionError

CONTINUOUS_NOOP = (0.0, 0.0, 0.0, 0)
"""What an unused continuous action stands for (stand still, aim at the first enemy)."""
_MOTION = (("vx", V_MAX), ("vy", V_MAX), ("omega", W_MAX))


def is_sequence(values: Any) -> bool:
    """Whether ``values`` can be a sequence of per-agent (or per-arena) entries: not a
    mapping (iterating it would read its keys), a set (no order), a string or bytes (its
    characters), a scalar, a 0-d array or tensor, or None."""
    if isinstance(values, (str, bytes, bytearray, Mapping, Set)):
        return False
    return hasattr(values, "__len__") and getattr(values, "ndim", 1) != 0


def check_sequence(actions: Any, n_agents: int, what: str = "actions") -> None:
    """``InvalidActionError`` naming ``what`` and the count that is valid when
    ``actions`` is not a sequence (:func:`is_sequence`); the count itself is checked by
    :func:`check_joint`."""
    if not is_sequence(actions):
        raise InvalidActionError(
            f"{what} must be a sequence of {n_agents} per-agent actions (a list, tuple or "
            f"array in agent order), got {actions!r:.80} ({type(actions).__name__})"
        )


def action_index(agent: int, action: Any, size: int) -> int:
    """One abstract or discrete action as an int in ``[0, size)``: an integer (Python or
    NumPy, or a 0-d array of one), or a whole float; never a bool."""
    if isinstance(action, np.ndarray) and action.shape == ():
        action = action.item()
    if isinstance(action, (bool, np.bool_)) or not isinstance(action, (int, np.integer)):
        if isinstance(action, (float, np.floating)) and float(action).is_integer():
            action = int(action)
        else:
            raise InvalidActionError(
                f"agent {agent}: action must be an integer in [0, {size - 1}], got {action!r:.80}"
            )
    if not 0 <= int(action) < size:
        raise InvalidActionError(
            f"agent {agent}: action {int(action)} is out of range; valid: [0, {size - 1}]"
        )
    return int(action)


def is_number(value: Any) -> bool:
    """A real number: a Python or NumPy int or float, or a 0-d array (or tensor) of one;
    never a bool, a string or bytes, which NumPy would convert."""
    if isinstance(value, (bool, np.bool_, str, bytes, bytearray)):
        return False
    if isinstance(value, (int, float, np.integer, np.floating)):
        return True
    try:
        arr = np.asarray(value)
    except Exception:
        return False
    return arr.shape == () and arr.dtype.kind in "iuf"


def holds_numbers(action: Any) -> bool:
    """Whether ``action`` holds real numbers only: a list or tuple of :func:`is_number`
    entries, or an array(-like) whose dtype is integer or float (strings, bytes, bools and
    objects would pass through NumPy's float conversion otherwise)."""
    if isinstance(action, (list, tuple)):
        return all(is_number(v) for v in action)
    try:
        return np.asarray(action).dtype.kind in "iuf"
    except Exception:
        return False


def _numbers(agent: int, action: Any) -> list[float]:
    """A continuous action's 4 entries as floats, refusing anything that is not 4 real
    numbers (strings, bytes and bools included, which NumPy would convert)."""
    what = f"agent {agent}: continuous action must be 4 numbers (vx, vy, omega, target), got "
    if isinstance(action, (list, tuple)):
        if len(action) != 4:
            raise InvalidActionError(
                f"agent {agent}: continuous action must have shape (4,) (vx, vy, omega, "
                f"target), got {len(action)} entries: {action!r:.80}"
            )
        if not all(is_number(v) for v in action):
            raise InvalidActionError(f"{what}{action!r:.80}")
        return [float(v) for v in action]
    try:  # an array or array-like (a tensor): its dtype says whether it holds numbers
        arr = np.asarray(action)
    except Exception:
        raise InvalidActionError(f"{what}{type(action).__name__} {action!r:.80}") from None
    if arr.dtype.kind not in "iuf":
        raise InvalidActionError(f"{what}an array of dtype {arr.dtype}: {action!r:.80}")
    if arr.shape != (4,):
        raise InvalidActionError(
            f"agent {agent}: continuous action must have shape (4,) (vx, vy, omega, target), "
            f"got shape {arr.shape}"
        )
    return [float(v) for v in arr.tolist()]


def continuous_action(agent: int, action: Any, n_enemy: int, clip: bool) -> tuple[Any, ...]:
    """One continuous action ``(vx, vy, omega, target)``: 4 finite real numbers, the motion
    within its bounds (or clipped to them when ``clip``), the target an integer in
    ``[0, n_enemy)``. Clipping applies to the motion commands only: the target names an
    enemy, and a target that names none is refused whatever ``clip`` says."""
    values = _numbers(agent, action)
    if not all(math.isfinite(v) for v in values):
        raise InvalidActionError(f"agent {agent}: action has NaN or infinite values: {values}")
    motion = []
    for (name, bound), v in zip(_MOTION, values[:3], strict=True):
        if not -bound <= v <= bound:
            if not clip:
                raise InvalidActionError(
                    f"agent {agent}: {name}={v} is outside [{-bound}, {bound}] "
                    "(or build the arena with clip_actions=True)"
                )
            v = min(max(v, -bound), bound)
        motion.append(v)
    target = values[3]
    if not target.is_integer() or not 0 <= target < n_enemy:
        raise InvalidActionError(
            f"agent {agent}: target={target} must be an integer in [0, {n_enemy - 1}] "
            "(clip_actions clips the motion, never the target)"
        )
    return (*motion, int(target))


def check_joint(
    actions: Any,
    n_agents: int,
    space: str,
    n_actions: int,
    n_enemy: int,
    clip: bool = False,
    used: Sequence[bool] | None = None,
) -> list[Any]:
    """A joint action as the arena uses it, or ``InvalidActionError`` naming the agent.

    ``space`` is the arena's ``action_space``, ``n_actions`` its flat discrete size and
    ``n_enemy`` the targets of a continuous action. ``used`` (one bool per agent; None: all)
    says whose actions the arena uses this step: the others (a bot-driven team's) may be
    anything and stand for a no-op, but the count is always ``n_agents``."""
    check_sequence(actions, n_agents)
    if len(actions) != n_agents:
        raise InvalidActionError(f"expected {n_agents} actions (one per agent), got {len(actions)}")
    out: list[Any] = []
    for i, a in enumerate(actions):
        if used is not None and not used[i]:
            out.append(CONTINUOUS_NOOP if space == "continuous" else 0)
        elif space == "continuous":
            out.append(continuous_action(i, a, n_enemy, clip))
        else:
            out.append(action_index(i, a, n_actions))
    return out


def used_agents(agents: Sequence[str], mode: str, bot_team: str) -> list[bool] | None:
    """Whose actions an arena uses in an episode with context ``bot_team`` (None: all):
    in competitive mode the team a bot drives is not the caller's. ``agents`` are the
    agent names of ``get_env_info()`` (``blue_0``, ..., ``red_0``, ...)."""
    if mode != "competitive" or bot_team not in ("red", "blue"):
        return None
    return [not name.startswith(bot_team + "_") for name in agents]
