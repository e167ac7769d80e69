"""What each dynamics context does to the robot, one key at a time.

    python -m bench.bench_dynamics

For each of the ten dynamics keys (``DYNAMICS_KEYS``: Friction_coeff, KP, KI, KD, VK1, M,
Wheel_I, vx_dt, vy_dt, vw_dt) and each of a few values spanning its useful range (the
default among them), the others at their defaults, one blue robot of a continuous-action
arena — the simulator users get: chassis model, PyBullet body, 0.02 s physics steps — is
given three step commands from rest, each held for ``HOLD`` s and then dropped to zero for
``HOLD`` s:

* forward 2 m/s: the settled speed (mean over the last ``TAIL`` s of the hold), the time to
  63 % of it (``t63``, from the command, so it includes any delay), the time to 5 % (``lag``,
  the command delay as seen in the response) and the stopping distance once the command drops
  to zero (``stop``: the farthest it goes from there, delay included; ``back``: how far it
  then comes back, when the wheels overshoot through zero);
* lateral (left) 2 m/s: the same four;
* yaw 1.75 rad/s (the paper's limit): settled turn rate, ``t63`` and ``lag``.

The robot's speed at each physics step is its displacement over that step (the body moves
at the chassis model's mean velocity for the step), placed at the step's midpoint; crossing
times are interpolated between those points (and 0 at the command's start), so they
resolve about a physics step (0.02 s), no finer. After every step the robot is put back at its start
pose (``Arena.place`` keeps the wheel states, and the chassis sets the body's velocity
before every step), so a run of any length stays in open floor and never touches anything.
Nobody has bullets, so nothing is shot. Deterministic: no random draw reaches the result.
Prints a Markdown table and writes bench/out/dynamics.json (docs/data/dynamics.json is a
copy).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from bench.common import Distinct, machine, table, write_json
from neuronsmae.server import Arena
from neuronsmae.server.contexts import DYNAMICS_KEYS

DT = 0.02
"""Physics step (s)."""
HOLD = 6.0
"""Seconds each command is held, then seconds of zero command after it: seven time constants
at the slowest setting measured (VK1 = 0.0375, 0.83 s)."""
TAIL = 0.5
"""The settled value is the mean over the last this many seconds of the hold."""
SETTLED_TOLERANCE = 0.002
"""``steady`` is true when the last two ``TAIL`` windows of the hold differ by less than this
fraction of the command."""
SPEED = 2.0
"""Linear step command (m/s): the continuous action's limit."""
TURN = 1.75
"""Yaw-rate step command (rad/s): the continuous action's limit."""
START = np.array([(5.0, 1.7, 0.0), (7.5, 4.0, np.pi)])
"""The measured robot on open floor (B4 ends at y 1.13, B7 starts at y 2.15), facing +x;
the other robot parked in a corner, out of the way."""

VALUES: dict[str, tuple[float, ...]] = {
    "Friction_coeff": (0.0, 0.1, 0.5, 1.0, 2.0),
    "KP": (2.0, 4.0, 8.0, 32.0, 128.0),
    "KI": (0.0, 0.001, 0.01, 0.1, 1.0),
    "KD": (0.0, 2.0, 20.0, 100.0, 200.0),
    "VK1": (0.0375, 0.1, 0.375, 1.0, 3.0),
    "M": (1.0, 3.4, 10.0, 30.0, 100.0),
    "Wheel_I": (0.003, 0.0125, 0.025, 0.05, 0.1),
    "vx_dt": (0.0, 0.04, 0.1, 0.2, 0.5),
    "vy_dt": (0.0, 0.04, 0.1, 0.2, 0.5),
    "vw_dt": (0.0, 0.04, 0.1, 0.2, 0.5),
}
"""The values measured per key; each tuple holds the key's default."""

TESTS: dict[str, tuple[tuple[float, float, float], int]] = {
    "fwd": ((SPEED, 0.0, 0.0), 0),
    "lat": ((0.0, SPEED, 0.0), 1),
    "turn": ((0.0, 0.0, TURN), 2),
}
"""Name → (body command (forward, left, ω), the axis of the response measured)."""


def _crossing(t: np.ndarray, v: np.ndarray, level: float) -> float:
    """First time ``v`` reaches ``level`` (same sign), linearly interpolated; nan if never."""
    above = np.flatnonzero(v * np.sign(level) >= abs(level))
    if above.size == 0:
        return float("nan")
    k = int(above[0])
    if k == 0:
        return float(t[0])
    return float(t[k - 1] + (level - v[k - 1]) / (v[k] - v[k - 1]) * (t[k] - t[k - 1]))


def response(arena: Arena, contexts: dict[str, float], test: str) -> dict[str, float]:
    """One step test (a key of :data:`TESTS`) on ``arena`` reset with ``contexts``."""
    cmd, axis = TESTS[test]
    arena.reset(contexts)
    arena.place(START, bullets=[0, 0])
    hold = round(HOLD / DT)
    still = np.zeros(4)
    go = np.array([*cmd, 0.0])
    v = np.empty(2 * hold)
    heading = START[0, 2]
    for k in range(2 * hold):
        arena.step([go if k < hold else still, still])
        d = arena.poses[0] - START[0]
        if axis == 2:
            v[k] = np.angle(np.exp(1j * d[2])) / DT
        else:  # displacement in the start pose's body frame
            fwd = d[0] * np.cos(heading) + d[1] * np.sin(heading)
            left = -d[0] * np.sin(heading) + d[1] * np.cos(heading)
            v[k] = (fwd, left)[axis] / DT
        arena.place(START, bullets=[0, 0])
    # Each step's mean speed at the step's midpoint, after 0 at the command's start.
    t = np.concatenate([[0.0], (np.arange(hold) + 0.5) * DT])
    rise = np.concatenate([[0.0], v[:hold]])
    tail = round(TAIL / DT)
    settled = float(v[hold - tail : hold].mean())
    before = float(v[hold - 2 * tail : hold - tail].mean())
    travel = np.cumsum(v[hold:]) * DT * np.sign(cmd[axis])  # along the command, from its drop
    return {
        "settled": settled,
        "steady": bool(abs(settled - before) < SETTLED_TOLERANCE * abs(cmd[axis])),
        "t63": _crossing(t, rise, 0.63 * settled),
        "lag": _crossing(t, rise, 0.05 * cmd[axis]),
        "stop": float(travel.max(initial=0.0)),
        "back": float(travel.max(initial=0.0) - travel[-1]),
        "residual": float(v[-1]),
    }


def measure(key: str, value: float, arena: Arena | None = None) -> dict[str, Any]:
    """The robot's response with dynamics context ``key`` = ``value`` (others at defaults).

    Returns ``{"key", "value", "fwd_settled", "fwd_steady", "fwd_t63", "fwd_lag", "fwd_stop",
    "fwd_back", "fwd_residual", "lat_…", "turn_…"}``: the settled speed (m/s; rad/s for
    turn) and whether it was steady (:data:`SETTLED_TOLERANCE`), the times ``t63`` and
    ``lag`` (s), ``stop``, the farthest the robot goes after the command drops to zero (m;
    rad for turn), ``back``, how far it then comes back (an overshoot through zero), and
    ``residual``, the speed left at the end (≈ 0 when it came to rest). ``arena``: reuse one
    from :func:`make_arena`.
    """
    own = arena is None
    if arena is None:
        arena = make_arena()
    row: dict[str, Any] = {"key": key, "value": value}
    try:
        for test in TESTS:
            for name, x in response(arena, {key: value}, test).items():
                row[f"{test}_{name}"] = x
    finally:
        if own:
            arena.close()
    return row


def make_arena() -> Arena:
    """A 1 v 1 continuous arena stepping one physics step per decision, driven by the caller."""
    return Arena(
        seed=0,
        action_space="continuous",
        mode="competitive",
        n_blue=1,
        n_red=1,
        decision_steps=1,
        episode_steps=100_000,
    )


COLUMNS = [
    "key",
    "value",
    "fwd_settled",
    "fwd_t63",
    "fwd_lag",
    "fwd_stop",
    "fwd_back",
    "lat_settled",
    "lat_lag",
    "lat_stop",
    "turn_settled",
    "turn_t63",
    "turn_lag",
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--keys", nargs="+", action=Distinct, default=list(VALUES), choices=list(VALUES)
    )
    args = parser.parse_args()
    defaults = {k.name: k.default for k in DYNAMICS_KEYS}
    assert set(VALUES) == set(defaults)
    start = time.perf_counter()
    arena = make_arena()
    try:
        rows = [measure(key, v, arena) for key in args.keys for v in VALUES[key]]
    finally:
        arena.close()
    wall = time.perf_counter() - start
    print(table(rows, COLUMNS))
    print(f"\n{len(rows)} settings in {wall:.1f} s")
    path = write_json(
        "dynamics",
        {
            "command": "python -m bench.bench_dynamics",
            "machine": machine(),
            "wall_seconds": wall,
            "defaults": defaults,
            "hold_seconds": HOLD,
            "tail_seconds": TAIL,
            "commands": {"fwd": SPEED, "lat": SPEED, "turn": TURN},
            "rows": rows,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
