"""The task's shape as one typed object: sizes, the observation and state layouts, actions.

``ArenaAPI.get_env_info()`` returns a plain dict, which is what travels on the wire (msgpack
map) and what SMAC-style code expects. :class:`EnvInfo` is that dict parsed once
(:meth:`EnvInfo.from_dict`), checked for consistency, and extended with the layouts the dict
implies: which columns of an observation hold which robot's pose, which candidate point,
the time, HP, bullets and LiDAR (:class:`ObsLayout`), and the same for the global state
(:class:`StateLayout`). Clients and trainers read positions from it instead of writing
column numbers down, so the layout is written in one place: here (the server sizes and
fills its observations from :class:`ObsLayout` too, ``server/task/observations.py``).

The observation of an agent whose team has ``a`` robots (itself included) facing ``e``
enemies, every value in [−1, 1] (``docs/options.md``, ``docs/reference.md``)::

    [poses 3·(a+e)] [candidate points 2·k·e] [time 1] [HP a+e] [bullets a+e] [LiDAR]

Robots are numbered in the observation's order: 0 is the agent itself, then its team-mates,
then the enemies. The first four blocks (the "vector" part) are absent with
``vector_obs=False``; candidate points are absent unless ``candidate_obs``; LiDAR is present
when ``lidar_beams > 0``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from neuronsmae.protocol.errors import EnvInfoError

V_MAX = 2.0
"""Bound of a continuous action's ``vx`` and ``vy`` (m/s): each lies in [−V_MAX, V_MAX]
(paper: 2)."""
W_MAX = 1.75
"""Bound of a continuous action's ``omega`` (rad/s): it lies in [−W_MAX, W_MAX] (paper:
1.75)."""
FIELD_HALF = (4.04, 2.24)
"""Half the field's interior along x and y (m): an observation's position is its offset from
the centre divided by these, ``x → (x − 4.04) / 4.04`` (``docs/reference.md``)."""
MOTION_HIGH = (V_MAX, V_MAX, W_MAX)
"""Upper bounds of a continuous action's ``(vx, vy, omega)``; the lower ones are their
negatives."""
ACTION_SPACES = ("abstract", "discrete", "continuous")
ARENA_OPTIONS = frozenset(
    {
        "action_space", "n_blue", "n_red", "mode", "blue_level", "decision_steps",
        "episode_steps", "k", "candidate_obs", "observability", "unseen_value",
        "camera_hfov_deg", "vector_obs", "lidar", "lidar_range", "reward", "spawn", "zones",
        "gui", "hit_mode", "time_limit_winner", "clip_actions", "planner_resolution",
    }
)  # fmt: skip
"""The arena options (``Arena(seed, **options)``, docs/options.md); a test keeps this equal
to the server's ``ArenaConfig`` fields, so a client or a trainer can refuse an unknown option
without importing the server or launching one."""
MODES = ("cooperative", "competitive", "bots")


@dataclass(frozen=True)
class ObsLayout:
    """Where each block of one agent's observation lies (see the module docstring).

    Block properties are slices (empty when the block is absent); the per-robot methods give
    single column indices and raise :class:`EnvInfoError` for a block that is absent.
    """

    team_size: int
    """Robots on the agent's team, itself included (``a``)."""
    n_enemies: int
    """Enemy robots (``e``)."""
    k: int
    """Candidate points per enemy in the observation (0: none)."""
    vector: bool
    """Whether the poses, candidate points, time, HP and bullets are present."""
    lidar_beams: int
    """LiDAR ranges at the end (0: none)."""

    @property
    def n_robots(self) -> int:
        return self.team_size + self.n_enemies

    @property
    def poses(self) -> slice:
        """``(x, y, yaw)`` of every robot in observation order: 3 columns each."""
        return slice(0, 3 * self.n_robots if self.vector else 0)

    @property
    def candidates(self) -> slice:
        """``(x, y)`` of the ``k`` candidate points of each enemy in turn."""
        start = self.poses.stop
        return slice(start, start + (2 * self.k * self.n_enemies if self.vector else 0))

    @property
    def time(self) -> slice:
        """The elapsed time: one column."""
        start = self.candidates.stop
        return slice(start, start + (1 if self.vector else 0))

    @property
    def hp(self) -> slice:
        """HP of every robot in observation order."""
        start = self.time.stop
        return slice(start, start + (self.n_robots if self.vector else 0))

    @property
    def bullets(self) -> slice:
        """Bullets of every robot in observation order."""
        start = self.hp.stop
        return slice(start, start + (self.n_robots if self.vector else 0))

    @property
    def lidar(self) -> slice:
        """The LiDAR ranges, beam −135° first."""
        return slice(self.bullets.stop, self.bullets.stop + self.lidar_beams)

    @property
    def size(self) -> int:
        """Length of the observation."""
        return self.lidar.stop

    def enemy(self, j: int) -> int:
        """Observation-order index of enemy ``j``."""
        return self.team_size + self._index(j, self.n_enemies, "enemy")

    def pose(self, robot: int) -> tuple[int, int, int]:
        """Columns of robot ``robot``'s ``x, y, yaw``."""
        c = self.poses.start + 3 * self._robot(robot)
        return c, c + 1, c + 2

    def point(self, j: int, q: int) -> tuple[int, int]:
        """Columns of ``x, y`` of candidate point ``q`` of enemy ``j``."""
        if self.candidates.stop == self.candidates.start:
            raise EnvInfoError("this observation holds no candidate points")
        c = self.candidates.start + 2 * (
            self.k * self._index(j, self.n_enemies, "enemy") + self._index(q, self.k, "point")
        )
        return c, c + 1

    def hp_of(self, robot: int) -> int:
        """Column of robot ``robot``'s HP."""
        return self.hp.start + self._robot(robot)

    def bullets_of(self, robot: int) -> int:
        """Column of robot ``robot``'s bullets."""
        return self.bullets.start + self._robot(robot)

    def xy_columns(self) -> list[int]:
        """Every position column (robots' and candidate points' x and y), ascending."""
        if not self.vector:
            return []
        robots = [c for r in range(self.n_robots) for c in self.pose(r)[:2]]
        return robots + list(range(self.candidates.start, self.candidates.stop))

    def yaw_columns(self) -> list[int]:
        """Every yaw column, one per robot."""
        return [self.pose(r)[2] for r in range(self.n_robots)] if self.vector else []

    def _robot(self, robot: int) -> int:
        if not self.vector:
            raise EnvInfoError("this observation holds no poses, HP or bullets (vector_obs off)")
        return self._index(robot, self.n_robots, "robot")

    @staticmethod
    def _index(i: int, n: int, what: str) -> int:
        if not 0 <= i < n:
            raise EnvInfoError(f"{what} {i} is out of range; valid: 0..{n - 1}")
        return i


@dataclass(frozen=True)
class StateLayout:
    """The global state: ``(x, y, yaw, HP, bullets)`` of every robot, blue team first (in
    cooperative mode the agents' team), then the time."""

    n_blue: int
    """Robots on the blue team."""
    n_red: int
    """Robots on the red team."""
    PER_ROBOT: ClassVar[int] = 5
    """Columns per robot."""

    @property
    def n_robots(self) -> int:
        return self.n_blue + self.n_red

    @property
    def size(self) -> int:
        """Length of the state."""
        return self.PER_ROBOT * self.n_robots + 1

    @property
    def time(self) -> int:
        """Column of the elapsed time (the last one)."""
        return self.size - 1

    def robot(self, r: int) -> slice:
        """The five columns of robot ``r`` (blue robots ``0..n_blue-1``, then red)."""
        ObsLayout._index(r, self.n_robots, "robot")
        return slice(self.PER_ROBOT * r, self.PER_ROBOT * (r + 1))

    def pose(self, r: int) -> tuple[int, int, int]:
        """Columns of robot ``r``'s ``x, y, yaw``."""
        c = self.robot(r).start
        return c, c + 1, c + 2

    def hp_of(self, r: int) -> int:
        return self.robot(r).start + 3

    def bullets_of(self, r: int) -> int:
        return self.robot(r).start + 4

    def xy_columns(self) -> list[int]:
        """Every position column, ascending."""
        return [c for r in range(self.n_robots) for c in self.pose(r)[:2]]

    def yaw_columns(self) -> list[int]:
        return [self.pose(r)[2] for r in range(self.n_robots)]


@dataclass(frozen=True)
class EnvInfo:
    """``get_env_info()`` as a typed object: sizes, names and the layouts they imply."""

    n_agents: int
    """Agents the caller controls (0 in ``bots`` mode)."""
    n_enemies: int
    """Enemies each agent faces."""
    n_actions: int
    """Flat discrete choices per agent (for continuous actions: the target enemies)."""
    obs_shape: int
    """Length of one agent's observation."""
    state_shape: int
    """Length of the global state."""
    episode_limit: int
    """Decisions per episode at most."""
    action_space: str
    """``abstract``, ``discrete`` or ``continuous``."""
    agents: tuple[str, ...]
    """Names of the agents in their order, e.g. ``("blue_0", "blue_1")``."""
    decision_steps: int
    """Physics steps (0.02 s each) per decision."""
    mode: str
    """``cooperative``, ``competitive`` or ``bots``."""
    team_size: int
    """Robots on an agent's team, itself included (the blue team's size)."""
    k: int
    """Candidate points per enemy (the abstract actions' points; the paper's 4)."""
    candidate_obs: bool
    """Whether the candidate points are part of the observation."""
    vector_obs: bool
    """Whether the observation holds poses, time, HP and bullets (else LiDAR only)."""
    lidar_beams: int
    """LiDAR ranges at the end of the observation (0: none; 61 with ``lidar=True``)."""
    obs: ObsLayout = field(init=False, repr=False, compare=False)
    """Where each block of an observation lies (from the fields above)."""
    state: StateLayout = field(init=False, repr=False, compare=False)
    """Where each robot's values lie in the global state."""

    def __post_init__(self) -> None:
        for name in ("action_space", "mode"):
            valid = ACTION_SPACES if name == "action_space" else MODES
            if getattr(self, name) not in valid:
                raise EnvInfoError(f"{name}={getattr(self, name)!r}; valid: {', '.join(valid)}")
        sizes = (self.n_enemies, self.team_size, self.n_actions, self.episode_limit, self.k)
        if min(*sizes, self.decision_steps) < 1 or min(self.n_agents, self.lidar_beams) < 0:
            raise EnvInfoError(f"sizes must be ≥ 1 (n_agents, lidar_beams ≥ 0): {self}")
        if len(self.agents) != self.n_agents:
            raise EnvInfoError(f"{self.n_agents} agents but {len(self.agents)} names")
        k = self.k if self.candidate_obs and self.vector_obs else 0
        layout = ObsLayout(self.team_size, self.n_enemies, k, self.vector_obs, self.lidar_beams)
        object.__setattr__(self, "obs", layout)
        object.__setattr__(self, "state", StateLayout(self.team_size, self.n_enemies))
        per_enemy = {"abstract": self.k, "continuous": 1}.get(self.action_space)
        checks = {
            "obs_shape": (self.obs_shape, layout.size),
            "state_shape": (self.state_shape, self.state.size),
            "n_actions": (self.n_actions, self.n_enemies * (per_enemy or self.actions_per_enemy)),
        }
        for name, (got, expected) in checks.items():
            if got != expected:
                raise EnvInfoError(f"{name}={got} does not fit the layout, which gives {expected}")

    @property
    def continuous(self) -> bool:
        return self.action_space == "continuous"

    @property
    def motion_bounds(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Lower and upper bounds of a continuous action's ``(vx, vy, omega)``; its fourth
        value, the target, is an enemy index in ``[0, n_enemies)``."""
        return tuple(-v for v in MOTION_HIGH), MOTION_HIGH

    @property
    def actions_per_enemy(self) -> int:
        """Choices per target enemy: ``k`` points (abstract), 5 moves (discrete), 1."""
        return self.n_actions // self.n_enemies

    def action(self, enemy: int, choice: int) -> int:
        """The flat action that targets ``enemy`` with ``choice`` (its point or move)."""
        ObsLayout._index(enemy, self.n_enemies, "enemy")
        return enemy * self.actions_per_enemy + ObsLayout._index(
            choice, self.actions_per_enemy, "choice"
        )

    def split(self, action: int) -> tuple[int, int]:
        """``(enemy, choice)`` of a flat action: the inverse of :meth:`action`."""
        return divmod(ObsLayout._index(action, self.n_actions, "action"), self.actions_per_enemy)

    def to_dict(self) -> dict[str, Any]:
        """The wire form: the keys of :data:`WIRE_KEYS`, plain values."""
        out = {key: getattr(self, key) for key in WIRE_KEYS}
        out["agents"] = list(self.agents)
        return out

    @classmethod
    def from_dict(cls, info: Mapping[str, Any]) -> EnvInfo:
        """Parse ``get_env_info()``'s dict; raise :class:`EnvInfoError` naming any missing or
        mistyped key (keys this version does not know are ignored)."""
        if not isinstance(info, Mapping):
            raise EnvInfoError(f"env info must be a mapping, got {type(info).__name__}")
        missing = [key for key in WIRE_KEYS if key not in info]
        if missing:
            raise EnvInfoError(
                f"env info lacks {', '.join(missing)}; it needs {', '.join(WIRE_KEYS)}"
            )
        values = {key: _typed(key, info[key], kind) for key, kind in WIRE_KEYS.items()}
        return cls(**values)


WIRE_KEYS: dict[str, type] = {
    "n_actions": int,
    "n_agents": int,
    "state_shape": int,
    "obs_shape": int,
    "episode_limit": int,
    "action_space": str,
    "agents": tuple,
    "n_enemies": int,
    "decision_steps": int,
    "mode": str,
    "team_size": int,
    "k": int,
    "candidate_obs": bool,
    "vector_obs": bool,
    "lidar_beams": int,
}
"""The keys of the wire dict and their types, in the order the arena has always sent the
first ten."""


def _typed(key: str, value: Any, kind: type) -> Any:
    if kind is tuple:
        if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
            return tuple(value)
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif isinstance(value, kind):
        return value
    expected = "a list of str" if kind is tuple else kind.__name__
    raise EnvInfoError(f"env info {key}={value!r} must be {expected}")
