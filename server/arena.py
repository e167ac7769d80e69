"""The in-process arena: one RMUA battle, stepped decision by decision.

:class:`Arena` wires the parts together and owns nothing else: the PyBullet world
(:mod:`~neuronsmae.server.sim.world`), the chassis model (:mod:`~neuronsmae.server.sim.chassis`),
the referee (:mod:`~neuronsmae.server.sim.referee`), and the task layer (actions, perception,
observations, bots, planner under :mod:`neuronsmae.server.task`). Its public methods are the
:class:`~neuronsmae.protocol.interface.ArenaAPI` contract shared with the remote client.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from neuronsmae.protocol.actions import used_agents
from neuronsmae.protocol.defaults import DEFAULT_SEED
from neuronsmae.protocol.env_info import EnvInfo
from neuronsmae.protocol.errors import ClosedError, InvalidOptionError, ResetNeededError
from neuronsmae.protocol.interface import ArenaAPI, inherit_docstrings
from neuronsmae.server.config import ArenaConfig
from neuronsmae.server.contexts import EpisodeContext, check_seed, parse_contexts
from neuronsmae.server.render import render_scene
from neuronsmae.server.sim import field as F
from neuronsmae.server.sim.chassis import Chassis, ChassisParams
from neuronsmae.server.sim.referee import BLUE, RED, Referee, StepTally
from neuronsmae.server.sim.spawn import corner_poses, random_poses
from neuronsmae.server.sim.stepper import Stepper
from neuronsmae.server.sim.world import World
from neuronsmae.server.sim.zones import Zones
from neuronsmae.server.task import observations as O
from neuronsmae.server.task import perception as P
from neuronsmae.server.task.actions import KIND_GOAL, ActionDecoder, Intent, n_actions
from neuronsmae.server.task.bots import BotView, make_bot
from neuronsmae.server.task.control import Orders
from neuronsmae.server.task.planner import Planner

CONTROL_EVERY = 5
"""Physics steps between controller updates (0.1 s): the planner's velocity command and the
auto-turn are recomputed this often and held in between, like the released build's 0.1 s
discrete decisions."""


_NO_CANDS = np.zeros((0, 1, 1, 2))
"""Stands for the candidate points in an observation layout without them."""


@inherit_docstrings
class Arena(ArenaAPI):
    """One battle on the RMUA field, simulated in this process.

    ``Arena(seed=1234, action_space="abstract", n_blue=2, n_red=2, mode="cooperative", ...)``;
    every option is a field of :class:`~neuronsmae.server.config.ArenaConfig` and is listed
    in ``docs/options.md``. Each arena owns its own RNG (seeded by ``seed``) and its own
    PyBullet client, so several arenas in one process never interfere.
    """

    def __init__(self, seed: int = DEFAULT_SEED, **options: Any) -> None:
        self.seed = check_seed(seed, InvalidOptionError)
        self.config = cfg = ArenaConfig.from_options(options)
        self.rng = np.random.default_rng(self.seed)
        self.n_blue, self.n_red = cfg.n_blue, cfg.n_red
        self.n = cfg.n_blue + cfg.n_red
        self.team = np.array([BLUE] * cfg.n_blue + [RED] * cfg.n_red)
        self.mates_of = [self._mates(i) for i in range(self.n)]
        self.enemies_of = [np.flatnonzero(self.team != self.team[i]) for i in range(self.n)]
        self.agents = self._controlled(cfg.mode)
        # Per-robot index tables used every decision, built once.
        self.team_robots = {t: np.flatnonzero(self.team == t) for t in (BLUE, RED)}
        self._span = {BLUE: (0, self.n_blue), RED: (self.n_blue, self.n)}
        self._agent_list = self.agents.tolist()
        self._agent_team = self.team[self.agents].tolist()
        self._order = [
            np.concatenate([self.mates_of[i], self.enemies_of[i]]) for i in range(self.n)
        ]
        self._others = [self._order[i][1:] for i in range(self.n)]
        self._enemy_table = P.enemy_table(self.enemies_of)
        self._agent_order = np.array([self._order[i] for i in self.agents]).reshape(
            len(self.agents), self.n
        )
        self._wanted_mask = np.zeros(self.n, dtype=bool)
        # The agents' shared observation layout (see _perceive): its vector part's size, and
        # the sight of every enemy under full observability.
        first = int(self.agents[0]) if len(self.agents) else 0
        n_team, n_enemy = len(self.mates_of[first]), len(self.enemies_of[first])
        self._seen_all = np.ones((len(self.agents), n_enemy), dtype=bool)
        self._vec_size = O.obs_size(n_team, n_enemy, cfg.k, cfg.with_candidates, True, False)
        self.world = World(self.n, gui=cfg.gui, n_blue=cfg.n_blue)
        self.chassis = Chassis(self.n)
        self.referee = Referee(
            cfg.n_blue,
            cfg.n_red,
            self.rng,
            cfg.hit_mode == "sampled",
            by_damage=cfg.time_limit_winner == "damage",
        )
        self.stepper = Stepper(self.world, self.chassis, self.referee)
        self.planner = Planner(resolution=cfg.planner_resolution)
        self.zones = Zones(self.rng, cfg.n_blue, self.n) if cfg.zones else None
        self._max_bullets = F.START_BULLETS + (
            Zones.ammo_capacity(cfg.episode_steps) if cfg.zones else 0.0
        )
        self.decoder = ActionDecoder(cfg.action_space, cfg.n_red, cfg.k, cfg.clip_actions)
        self.poses = np.zeros((self.n, 3))
        self.t = 0
        self.done = True
        self._episodes = 0
        self._closed = False
        self._obs: list[np.ndarray] = []
        self.context = EpisodeContext()
        self.targets = np.zeros(self.n, dtype=np.int64)
        self.cmd = np.zeros((self.n, 3))
        self.bots: dict[int, Any] = {BLUE: None, RED: None}
        self._used: list[bool] | None = None
        """Whose actions this episode uses (None: every agent's); a bot's team's are not."""

    # --- construction helpers -----------------------------------------------------------
    def _mates(self, i: int) -> np.ndarray:
        same = np.flatnonzero(self.team == self.team[i])
        return np.concatenate([[i], same[same != i]]).astype(int)

    def _controlled(self, mode: str) -> np.ndarray:
        return {
            "cooperative": np.arange(self.n_blue),
            "competitive": np.arange(self.n),
            "bots": np.arange(0),
        }[mode]

    # --- ArenaAPI -------------------------------------------------------------------------
    def reset(
        self, contexts: Mapping[str, Any] | None = None, seed: int | None = None
    ) -> list[np.ndarray]:
        self._need_open("reset()")
        self.context = ctx = parse_contexts(contexts)
        if seed is not None:
            self.rng = np.random.default_rng(check_seed(seed))
            self.referee.rng = self.rng
        cfg = self.config
        if cfg.spawn == "random":
            self.poses = random_poses(self.n, self.rng)
        else:
            self.poses = corner_poses(self.n_blue, self.n_red, self.rng)
        self.world.build(self.poses)
        params = [
            ChassisParams(**(ctx.blue_dynamics if self.team[i] == BLUE else ctx.red_dynamics))
            for i in range(self.n)
        ]
        self.chassis.reset(params)
        max_hp = np.where(self.team == RED, ctx.opponent_hp, float(F.START_HP))
        self.referee.reset(max_hp, ctx.coef, self._max_bullets)
        if self.zones is not None:
            self.zones.rng = self.rng
            self.zones.reset()
        # Competitive mode hands one team to a bot for an episode when told (``bot_team``).
        bot_team = ctx.bot_team if cfg.mode == "competitive" else "none"
        self.bots = {
            BLUE: make_bot(cfg.blue_level, self.rng)
            if cfg.mode == "bots" or bot_team == "blue"
            else None,
            RED: make_bot(ctx.level, self.rng)
            if cfg.mode in ("cooperative", "bots") or bot_team == "red"
            else None,
        }
        self._wanted_mask = self._wanted()
        self._used = used_agents([self.agent_name(i) for i in self.agents], cfg.mode, bot_team)
        self.t = 0
        self.done = False
        self._episodes += 1
        self.targets = np.array([self._nearest_enemy(i) for i in range(self.n)])
        self.cmd = np.zeros((self.n, 3))
        self._perceive()
        return self.get_obs()

    def step(
        self, actions: Sequence[Any]
    ) -> tuple[list[np.ndarray], list[float], bool, dict[str, Any]]:
        self._need_open("step()")
        if self.done:
            raise ResetNeededError(
                "step() called before reset() or after the episode ended; call reset() first"
            )
        checked = self.check_actions(actions)
        intents = self._intents(checked)
        orders = Orders(intents, self._plan(intents))
        tally = StepTally.zero()
        cfg = self.config
        if self.zones is None:  # the whole decision in the stepper, one numba call per step
            self.t = self.stepper.run(
                self.poses, self.cmd, self.targets, orders, self.t, cfg.episode_steps,
                cfg.period, CONTROL_EVERY, tally,
            )  # fmt: skip
            self.done = self.referee.check_end(self.t, cfg.episode_steps)
        else:
            for k in range(cfg.period):
                if k % CONTROL_EVERY == 0:  # velocity commands, held until the next update
                    orders.apply(self.poses, self.referee.alive, self.cmd)
                self._physics_step(tally)
                if self.done:
                    break
        team_r, parts = self.referee.team_rewards(tally, self.config.reward == "dense")
        self._perceive()
        team_reward = team_r.tolist()
        rewards = [team_reward[team] for team in self._agent_team]
        info = self.referee.info() | {
            "t": self.t,
            "components": parts,
            "team_reward": team_reward,
            "targets": self.targets.tolist(),
            "contacts": self.world.contacts(),
        }
        if self.zones is not None:
            info |= self.zones.info()
        return self.get_obs(), rewards, self.done, info

    def get_obs(self) -> list[np.ndarray]:
        self._need_episode("get_obs()")
        return [o.copy() for o in self._obs]

    def get_state(self) -> np.ndarray:
        self._need_episode("get_state()")
        ref = self.referee
        return O.global_state(
            O.norm_pose(self.poses),
            O.norm_hp(ref.hp, ref.max_hp),
            O.norm_bullets(ref.bullets, ref.max_bullets),
            O.norm_time(self.t, self.config.episode_steps),
        )

    def get_avail_actions(self) -> list[np.ndarray]:
        self._need_episode("get_avail_actions()")  # no candidate goals before a reset
        alive = self.referee.alive
        return [
            self.decoder.mask(
                bool(alive[i]), alive[self.enemies_of[i]], self.valid[i, : len(self.enemies_of[i])]
            )
            for i in self.agents
        ]

    def get_env_info(self) -> dict[str, Any]:
        return self.env_info().to_dict()

    def env_info(self) -> EnvInfo:
        """:meth:`get_env_info` as the typed :class:`~neuronsmae.protocol.EnvInfo` (which
        checks that the layout it computes is the one this arena's observations have)."""
        cfg = self.config
        # Agents are blue robots, or (competitive, equal teams) any robot: one layout fits all.
        n_team, n_enemy = self.n_blue, self.n_red
        return EnvInfo(
            n_agents=len(self.agents),
            n_enemies=n_enemy,
            n_actions=n_actions(cfg.action_space, n_enemy, cfg.k),
            obs_shape=O.obs_size(
                n_team, n_enemy, cfg.k, cfg.with_candidates, cfg.vector_obs, cfg.lidar
            ),
            state_shape=O.state_size(self.n),
            episode_limit=-(-cfg.episode_steps // cfg.period),
            action_space=cfg.action_space,
            agents=tuple(self.agent_name(i) for i in self.agents),
            decision_steps=cfg.period,
            mode=cfg.mode,
            team_size=n_team,
            k=cfg.k,
            candidate_obs=cfg.with_candidates,
            vector_obs=cfg.vector_obs,
            lidar_beams=F.LIDAR_BEAMS if cfg.lidar else 0,
        )

    def render(self) -> np.ndarray:
        self._need_episode("render()")
        return render_scene(self)

    def close(self) -> None:
        self.world.close()
        self.done = True
        self._closed = True

    # --- checks ---------------------------------------------------------------------------
    def check_actions(self, actions: Sequence[Any]) -> list[Any]:
        """Validate a joint action without stepping: the per-agent actions as ``step`` will
        use them, or ``InvalidActionError`` naming the agent and the bound. ``VecArena``
        checks every arena's row this way before it steps any arena. In competitive mode
        the actions of the team a bot drives this episode (``bot_team``) are ignored, so
        they are not checked (only counted)."""
        return self.decoder.validate(actions, len(self.agents), self._used)

    def _need_open(self, what: str) -> None:
        """After ``close()`` the simulation is gone: a typed error, not PyBullet's "Not
        connected to physics server" or the last episode's stale observations."""
        if self._closed:
            raise ClosedError(f"{what} on a closed arena; make a new Arena")

    def _need_episode(self, what: str) -> None:
        """Before the first reset there is no scene (no poses, candidate points or
        observations), and after ``close()`` none either: a typed error, not an arbitrary
        value."""
        self._need_open(what)
        if self._episodes == 0:
            raise ResetNeededError(f"{what} needs an episode: call reset() first")

    # --- scenes ---------------------------------------------------------------------------
    def place(self, poses: np.ndarray, bullets: Sequence[float] | None = None) -> list[np.ndarray]:
        """Teleport every robot to ``poses`` (N, 3) mid-episode and return fresh observations.

        For constructed scenes (tests, tutorials, curriculum starts): wheel states and HP are
        kept, velocities zeroed; ``bullets`` optionally overrides each robot's ammunition.
        """
        self._need_open("place()")
        if self.done:
            raise ResetNeededError("place() needs a running episode: call reset() first")
        poses = np.asarray(poses, dtype=np.float64).reshape(self.n, 3)
        for i in range(self.n):
            self.world.place(i, *poses[i])
        self.poses[:] = poses
        if bullets is not None:
            self.referee.bullets[:] = np.asarray(bullets, dtype=np.float64)
        self.targets[:] = [self._nearest_enemy(i) for i in range(self.n)]
        self._perceive()
        return self.get_obs()

    # --- helpers --------------------------------------------------------------------------
    def agent_name(self, i: int) -> str:
        """``blue_0``, ``red_1``, ... for robot ``i``."""
        team = "blue" if self.team[i] == BLUE else "red"
        return f"{team}_{i if team == 'blue' else i - self.n_blue}"

    def _nearest_enemy(self, i: int) -> int:
        enemies = self.enemies_of[i]
        live = enemies[self.referee.alive[enemies]]
        if live.size == 0:
            return int(enemies[0])
        d = np.hypot(*(self.poses[live, :2] - self.poses[i, :2]).T)
        return int(live[np.argmin(d)])

    def _wanted(self) -> np.ndarray:
        """Robots whose candidate points are needed: observed abstract agents and bots."""
        wanted = np.zeros(self.n, dtype=bool)
        if self.config.with_candidates or self.config.action_space == "abstract":
            wanted[self.agents] = True
        for team, bot in self.bots.items():
            if bot is not None:
                wanted[self.team == team] = True
        return wanted

    def _perceive(self) -> None:
        """Candidate points, sight and observations for the decision about to be taken."""
        cfg, ref = self.config, self.referee
        self.cands, self.valid = P.all_candidates(
            self.poses, ref.alive, self.enemies_of, cfg.k, self._wanted_mask, self._enemy_table
        )
        agents, vec = self.agents, None
        if len(agents) == 0:  # "bots" mode: nobody observes
            self._obs = []
            return
        # Agents share one layout (competitive needs equal teams); sight and candidates are
        # as wide as the largest team: a 3 v 2 blue agent has 2 enemies.
        ne = len(self.enemies_of[agents[0]])
        if cfg.observability == "partial":
            seen = P.sight(
                self.poses,
                ref.alive,
                self.targets,
                self.enemies_of,
                np.deg2rad(cfg.camera_hfov_deg),
                True,
            )[agents, :ne]
        else:  # P.sight's answer under full observability: every enemy is seen
            seen = self._seen_all
        if cfg.vector_obs:
            vec = np.empty((len(agents), self._vec_size), dtype=np.float32)
            O.vector_obs_kernel(
                self._agent_order,
                len(self.mates_of[agents[0]]),
                self.poses,
                agents,
                self.cands if cfg.with_candidates else _NO_CANDS,
                O.norm_time(self.t, cfg.episode_steps),
                ref.hp,
                ref.max_hp,
                ref.bullets,
                ref.max_bullets,
                seen,
                cfg.unseen_value,
                vec,
            )
        if not cfg.lidar:
            self._obs = list(vec)  # type: ignore[arg-type]
            return
        obs = []
        for a, i in enumerate(self.agents):
            scan = P.lidar(self.poses, i, cfg.lidar_range).astype(np.float32)
            obs.append(scan if vec is None else np.concatenate([vec[a], scan]))
        self._obs = obs

    def _intents(self, actions: list[Any]) -> list[Intent]:
        """Per-robot intents from the agents' actions and the bots' choices."""
        ref, enemies_of, cands = self.referee, self.enemies_of, self.cands
        live = ref.alive.tolist()
        decode = self.decoder.decode
        intents: list[Any] = [None] * self.n
        for a, i in zip(actions, self._agent_list, strict=True):
            intents[i] = decode(a, enemies_of[i], cands[i])
        for team, bot in self.bots.items():
            if bot is None:
                continue
            lo, hi = self._span[team]  # a team's robots are consecutive
            if not any(live[lo:hi]):
                continue
            view = BotView(
                self.team_robots[team],
                enemies_of[lo],
                self.poses,
                ref.hp,
                ref.max_hp,
                ref.alive,
                cands[lo:hi].copy(),
                self.valid[lo:hi].copy(),
            )
            for r, (e, c) in zip(range(lo, hi), bot.act(view), strict=True):
                intents[r] = Intent(int(enemies_of[r][e]), KIND_GOAL, goal=cands[r, e, c])
        targets = self.targets
        for i, intent in enumerate(intents):
            if not live[intent.target]:
                intent.target = self._nearest_enemy(i)
            targets[i] = intent.target
        return intents

    def _plan(self, intents: list[Intent]) -> list[np.ndarray | None]:
        xy = self.poses[:, :2]
        paths: list[np.ndarray | None] = []
        for i, intent in enumerate(intents):
            if intent.kind == KIND_GOAL and self.referee.alive[i]:
                others = xy[self._others[i]]  # team-mates, then enemies
                paths.append(self.planner.plan(xy[i], intent.goal, others))
            else:
                paths.append(None)
        return paths

    def _physics_step(self, tally: StepTally) -> None:
        ref = self.referee
        cmd, targets = self.cmd, self.targets
        if self.zones is not None:
            self.zones.update(self.t, self.poses, ref.alive, ref.hp, ref.max_hp, ref.bullets)
            cmd = np.where(self.zones.frozen(self.t)[:, None], 0.0, cmd)
            targets = np.where(self.zones.silenced(self.t), -1, targets)
        if self.stepper.step(self.poses, cmd, targets, tally):  # someone was destroyed
            for i in np.flatnonzero(~ref.alive):
                self.chassis.stop(int(i))  # idempotent for robots destroyed earlier
                self.cmd[i] = 0.0
        self.t += 1
        self.done = ref.check_end(self.t, self.config.episode_steps)
