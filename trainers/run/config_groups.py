"""The groups of the training configuration: learner, evaluation and cluster settings.

Each group is a frozen dataclass with one docstring per field (``neuronsmae-train
--help-config`` prints them) and checks its own values; :class:`~.config.TrainConfig`
nests one of each. Keys are addressed as ``learner.lr`` or, when the name is unique across
groups, as the bare ``lr`` (:mod:`neuronsmae.trainers.run.config`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from neuronsmae.protocol.env_info import EnvInfo
from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.messages import MAX_SEED
from neuronsmae.protocol.transport import check_locator
from neuronsmae.trainers.checks import (
    ConfigError,
    check_choice,
    check_finite,
    check_positive,
    check_types,
)
from neuronsmae.trainers.core.buffer import PREFETCH
from neuronsmae.trainers.core.features import FEATURES, HEADS, POINT_FEATURES
from neuronsmae.trainers.core.learner import DeviceError, check_device_name
from neuronsmae.trainers.core.symmetry import GENERATORS, parse_generators
from neuronsmae.trainers.play.task import Q_ACTION_SPACES
from neuronsmae.trainers.run.contexts import ContextSpec, ContextSpecError

SERVER_PLACEMENTS = ("local", "actors")
"""``remote``: where each worker's server runs (see ``trainers/run/placement.py``)."""


TEST_SEED_OFFSET = 10_000_000
"""The final test's seeds start this far above ``eval_seed``, clear of any validation seed."""
MAX_WIDTH = 4096
"""Widest layer a learner's network may have (the paper's widest is 128; 4096 already makes a
GRU of 100 million weights)."""


WIN_RULES = {"referee": "win_rate", "released": "released_win_rate"}
"""``eval.win_rule`` → the evaluation figure it names."""


def parse_resources(text: str) -> dict[str, float]:
    """``"sampler=1,big_node=0.5"`` → ``{"sampler": 1.0, "big_node": 0.5}`` ("" → {}).

    Only custom resources: CPUs are ``worker_cpus``, and Ray owns the built-in names.
    """
    out: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, amount = (x.strip() for x in item.partition("="))
        try:
            value = float(amount) if sep else 1.0
        except ValueError:
            raise ConfigError(f"resource {item!r}: expected name=amount") from None
        reserved = name in ("CPU", "GPU", "memory", "object_store_memory")
        if not name or reserved or not math.isfinite(value) or value <= 0:
            raise ConfigError(f"resource {item!r}: expected a custom name and an amount > 0")
        out[name] = value
    return out


@dataclass(frozen=True)
class LearnerConfig:
    """The algorithm's hyper-parameters: optimiser, exploration, networks, replay."""

    lr: float = 5e-4
    """Adam learning rate, > 0 (paper: 5e-4)."""
    gamma: float = 0.99
    """Discount in [0, 1] (paper: 0.99)."""
    eps_start: float = 0.2
    """Initial exploration ε in [0, 1] (paper: 0.2)."""
    eps_end: float = 0.05
    """Final exploration ε in [0, 1] (paper: 0.05)."""
    eps_anneal_episodes: int = 1500
    """Training episodes over which ε falls linearly from eps_start to eps_end, ≥ 0 (0: ε
    is eps_end from the first episode)."""
    target_update_interval: int = 100
    """Updates (or rounds, see ``target_update_unit``) between hard target refreshes, ≥ 1.
    100 updates are every 50 episodes at the default 2 updates per episode; the paper's
    "every 5 iterations" of 20 workers is 100 episodes."""
    grad_clip: float = 10.0
    """Largest gradient norm of an update, > 0; larger ones are scaled down to it (paper: 10)."""
    agent_hidden: int = 128
    """Width of the shared agent network's hidden layers (the GRU's, or each of the MLP's
    two), in [1, 4096] (paper: 128)."""
    mixer_embed: int = 32
    """QMIX mixing-layer width, in [1, 4096] (paper: 32)."""
    hypernet_hidden: int = 64
    """QMIX hypernetwork hidden width, in [1, 4096]."""
    td_lambda: float = 0.3
    """λ of the TD(λ) targets in [0, 1] (0: the paper's one-step targets; PyMARL2 uses 0.6).
    λ > 0 carries a win's +20 back over many steps per update; a smaller λ carries fewer
    of the ε-greedy actions' consequences into the targets."""
    double_q: bool = True
    """Pick the next action with the online network, value it with the target network."""
    features: str = "auto"
    """Agent inputs: raw (the paper's: the observation as given), relative (plus geometry
    derived from it, see trainers/core/features.py) or auto: relative when the observation
    holds the poses and candidate points, else raw (``resolve_learner``)."""
    head: str = "auto"
    """Q head: flat (the paper's: a linear output per action), points (adds one small MLP
    that scores each action from its enemy's and point's features; needs 'relative' and
    abstract actions) or auto: points where it fits, else flat."""
    augment: str = "auto"
    """Replay each sampled episode under a random symmetry of the task, so the learner sees
    every scene in all its equivalent forms: 'none', a comma list of enemies (swap the
    enemy slots), field (turn the scene half a turn about the field's centre) and allies
    (swap the agents), see trainers/core/symmetry.py, or auto: every one the task has (all
    three on the default 2 v 2; ``resolve_learner``). The paper: none."""
    last_action_input: bool = True
    """Give the agent network its one-hot last action."""
    agent_id_input: bool = True
    """Give the agent network its one-hot agent index."""
    buffer_size: int = 5000
    """Replay capacity, ≥ 1, in episodes (in transitions with ``replay='transitions'``;
    the released code's is 200,000). A run refuses a buffer larger than the memory its
    machine has available, naming the size of one item for its task."""
    batch_size: int = 32
    """Episodes per gradient update (transitions with ``replay='transitions'``; the
    released code's 2,000, or all that are stored while fewer), in [1, buffer_size]."""
    learning_starts: int = 64
    """Episodes (or transitions) in the buffer before learning begins, in [0,
    buffer_size]."""
    train_every: int = 1
    """Asynchronous mode: episodes collected between training rounds, ≥ 1."""
    updates_per_round: int = 2
    """Gradient updates per training round (per iteration in synchronous mode), ≥ 1; with
    ``updates_per_stored_batch`` the least a round makes."""
    updates_per_stored_batch: int = 0
    """≥ 0. A round makes ``max(updates_per_round, updates_per_stored_batch ×
    ⌊stored / batch_size⌋)`` updates, so the work per round grows as the replay fills
    (0: ``updates_per_round`` always). The released code's is 2 with 20 per round:
    ``max(20, 2·⌊stored transitions / 2,000⌋)``, 20 at first and 200 once 200,000 are
    stored (runner.py)."""
    agent_net: str = "gru"
    """The shared agent network: gru (Linear, ReLU, GRU, Linear: PyMARL's recurrent agent,
    trained on whole episodes) or mlp (observation → agent_hidden → agent_hidden → actions
    with ReLU and no recurrence: the released code's, network/qmix_net.py's ``myRNN``)."""
    replay: str = "episodes"
    """What the replay stores and a batch holds: episodes (whole, padded; PyMARL's) or
    transitions (single decisions drawn uniformly with replacement: the released code's,
    common/replay_buffer.py; needs ``agent_net='mlp'``)."""
    target_update_unit: str = "updates"
    """What ``target_update_interval`` counts: updates, or rounds (the targets are copied
    at the first update of every ``target_update_interval``-th round, counted from 0: the
    released code copies them at the first update of every 5th iteration)."""
    action_masks: str = "env"
    """env: the agents act, and their targets maximise, within the environment's available
    actions; ones: every action is open in acting and in targets (the released code's
    all-ones masks, RmCooAbsEnv.py and common/rollout.py). The arena carries out any action
    in range: a destroyed robot's is ignored, one naming a destroyed enemy aims at the
    nearest live one, and a candidate slot the enemy has no point for holds the robot's own
    position, so it stays (docs/options.md, "Actions")."""
    mask_destroyed: bool = True
    """A destroyed robot's Q is zeroed in the mixer's input and dropped from IQL's loss,
    and IQL ends its return at its destruction; False: it is trained like a living one's
    to the episode's end (the released code)."""
    mixer_state: str = "state"
    """What QMIX's hypernetworks read: state (the environment's global state) or
    agent0_obs (agent 0's observation: the released ``get_state`` returns ``[obs[0]]``)."""
    hypernet_layers: int = 2
    """Layers of QMIX's weight hypernetworks, 1 or 2 (PyMARL's ``hypernet_layers``; the
    released code's ``two_hyper_layers=False`` is 1). The bias hypernetworks are one layer
    for b1 and two for b2 either way."""
    replay_ratio: float = 0.0
    """Learning decoupled from sampling when > 0: the learner trains in a thread of its own
    while the workers go on sampling, at this many updates per stored episode (counted
    once ``learning_starts`` are stored), kept within ``replay_tolerance`` by pausing the
    faster side (trainers/run/decoupled.py; asynchronous loop, ``target_update_unit``
    updates). 0: the learner trains inline, ``updates_per_round`` updates every
    ``train_every`` episodes (a ratio of 2 per episode by default). The paper: 0."""
    replay_tolerance: float = 0.1
    """How far the decoupled learner may run ahead of, or fall behind, ``replay_ratio``, as a
    fraction of the updates due, in (0, 1] (at least one episode's worth)."""
    device: str = "auto"
    """Where the learner runs: auto (CUDA when torch sees a CUDA device, else the CPU), cpu,
    cuda or cuda:N. The networks, targets, optimiser and batches live there; acting weights
    go to the workers and checkpoints to disk on the CPU, so a checkpoint written on one
    device loads on the other. A CUDA device this machine lacks stops the run before
    anything starts. (The released code's ``--cuda``; the paper is silent.)"""
    prefetch: str = "auto"
    """Where the next batch is drawn, augmented and sent to the device: on (in a background
    thread while the current update trains), off (inline, before each update) or auto (in
    the background when the learner leaves a core for it: on CUDA, or with fewer intra-op
    threads than the process has cores; inline otherwise, where the thread would only take
    a core from the update's own threads). The same batches either way."""
    eps_schedule: str = "episodes"
    """How ε falls from eps_start to eps_end: episodes (linearly with the run's episode
    count over ``eps_anneal_episodes``) or iterations (needs ``sync`` and
    ``iteration_episodes``: ε steps once per iteration, all its episodes sharing it,
    as each of the released code's 20 workers steps it before each of its own episodes:
    iteration i, from 0, plays ``max(eps_end, eps_start − (i + 1)·Δ)`` with Δ = (eps_start −
    eps_end) · iteration_episodes / eps_anneal_episodes; 600 per worker is 12,000 episodes
    of the run)."""

    def __post_init__(self) -> None:
        check_types(self)
        check_choice("agent_net", self.agent_net, ("gru", "mlp"))
        check_choice("replay", self.replay, ("episodes", "transitions"))
        check_choice("prefetch", self.prefetch, PREFETCH)
        check_choice("target_update_unit", self.target_update_unit, ("updates", "rounds"))
        check_choice("action_masks", self.action_masks, ("env", "ones"))
        check_choice("mixer_state", self.mixer_state, ("state", "agent0_obs"))
        check_choice("hypernet_layers", self.hypernet_layers, (1, 2))
        check_choice("eps_schedule", self.eps_schedule, ("episodes", "iterations"))
        try:
            check_device_name(self.device)
        except DeviceError as err:
            raise ConfigError(str(err)) from None
        if self.replay == "transitions" and self.agent_net != "mlp":
            raise ConfigError(
                f"replay='transitions' needs agent_net='mlp' (a recurrent agent learns from "
                f"whole episodes), got agent_net={self.agent_net!r}"
            )
        if self.replay_ratio < 0 or not 0 < self.replay_tolerance <= 1:
            raise ConfigError(
                f"replay_ratio must be ≥ 0 and replay_tolerance in (0, 1], got "
                f"{self.replay_ratio} and {self.replay_tolerance}"
            )
        if self.replay_ratio > 0 and self.target_update_unit != "updates":
            raise ConfigError(
                "replay_ratio > 0 (a decoupled learner has no rounds) needs "
                f"target_update_unit='updates', got {self.target_update_unit!r}"
            )
        if self.updates_per_stored_batch < 0:
            raise ConfigError(
                f"updates_per_stored_batch must be ≥ 0, got {self.updates_per_stored_batch}"
            )
        check_choice("features", self.features, (*FEATURES, "auto"))
        check_choice("head", self.head, (*HEADS, "auto"))
        if self.head == "points" and self.features not in (*POINT_FEATURES, "auto"):
            raise ConfigError(
                f"head='points' needs features in {POINT_FEATURES}, got {self.features!r}"
            )
        try:
            if self.augment != "auto":
                parse_generators(self.augment)
        except ValueError as err:
            raise ConfigError(f"{err} (or 'auto')") from None
        check_positive(
            self, "batch_size", "buffer_size", "train_every", "updates_per_round",
            "target_update_interval", "agent_hidden", "mixer_embed", "hypernet_hidden",
        )  # fmt: skip
        check_finite(self)
        for name in ("eps_anneal_episodes", "learning_starts"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must be ≥ 0, got {getattr(self, name)}")
        for name in ("agent_hidden", "mixer_embed", "hypernet_hidden"):
            if getattr(self, name) > MAX_WIDTH:
                raise ConfigError(f"{name} must be in [1, {MAX_WIDTH}], got {getattr(self, name)}")
        if self.batch_size > self.buffer_size:
            raise ConfigError(
                f"batch_size must be in [1, buffer_size={self.buffer_size}], got {self.batch_size}"
            )
        if self.learning_starts > self.buffer_size:  # the buffer would never hold that many
            raise ConfigError(
                f"learning_starts must be in [0, buffer_size={self.buffer_size}], got "
                f"{self.learning_starts}"
            )
        for name in ("lr", "grad_clip"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("eps_start", "eps_end", "gamma", "td_lambda"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"{name} must lie in [0, 1], got {getattr(self, name)}")

    def updates_in_round(self, stored: int) -> int:
        """Gradient updates in a round with ``stored`` items in the replay: ``max(
        updates_per_round, updates_per_stored_batch × ⌊stored / batch_size⌋)``."""
        grown = self.updates_per_stored_batch * (stored // self.batch_size)
        return max(self.updates_per_round, grown)

    def refreshes_targets(self, round_index: int) -> bool:
        """Whether round ``round_index`` (from 0) copies the targets after its first update
        (``target_update_unit='rounds'``; by updates the learner counts them itself)."""
        unit_rounds = self.target_update_unit == "rounds"
        return unit_rounds and round_index % self.target_update_interval == 0


@dataclass(frozen=True)
class EvalConfig:
    """Greedy evaluations, model selection and checkpoints."""

    eval_every: int = 500
    """Training episodes between greedy evaluations (0 disables them until the end)."""
    eval_episodes: int = 50
    """Greedy episodes per evaluation, on held-out seeds, ≥ 1."""
    final_eval_episodes: int = 200
    """Greedy episodes of the final evaluation at the end of the run, ≥ 1 (the paper's
    200; a win rate near 0.9 is then known to about ±0.04 at 95 %)."""
    eval_seed: int = 1_000_000_000
    """First held-out seed; training episodes use seeds below it. Periodic evaluations
    (validation) use ``eval_seed + k``; the final evaluation (test) uses
    ``eval_seed + 10,000,000 + k`` (``TEST_SEED_OFFSET``), so the figures reported at the
    end never come from the seeds that chose the best weights."""
    keep_best: bool = True
    """Keep the weights of the best periodic evaluation, write them to ``best.pt`` and
    evaluate them on the test seeds at the end beside the final weights (model selection
    on validation seeds, as is usual when reporting greedy win rates). Equal readings go to
    the later weights, which trained longer."""
    checkpoint_every: int = 1000
    """Training episodes between checkpoints, ≥ 1 (one is always written at the end)."""
    save_replay: bool = True
    """Save the replay with each checkpoint (``replay.npz`` in the run directory: the
    stored items, up to the buffer's size on disk, e.g. about 170 MB for the paper preset's
    200,000 transitions), so that ``--resume`` continues with the replay the run had;
    without it a resumed run refills its replay from empty."""
    eval_contexts: str = ""
    """The fixed reset contexts of every evaluation beyond the run's ``level``, as
    ``key=value`` entries separated by ``;`` (no sets or ranges: every evaluation meets the
    same task). Empty: the defaults (coef 1)."""
    extra_test_contexts: str = ""
    """More fixed context sets for the final test only, separated by ``|`` (each with the
    syntax of ``eval_contexts``, whose keys it overrides); each is played on the same test
    seeds and reported beside the main test. The paper's evaluation at coef 1.5 is
    ``coef=1.5``."""
    win_rule: str = "referee"
    """Which win rate is the run's figure (the one printed, and the one ``keep_best``
    selects by): referee (the referee's outcome: a wipe-out, or more HP at the time limit)
    or released (the released code's rule: agent 0's reward at the last decision above 13,
    common/rollout.py). Every evaluation records both (``win_rate`` and
    ``released_win_rate``)."""

    def __post_init__(self) -> None:
        check_types(self)
        check_choice("win_rule", self.win_rule, WIN_RULES)
        check_positive(self, "eval_episodes", "final_eval_episodes", "checkpoint_every")
        for name, spec in self.context_specs().items():
            if not spec.fixed:
                raise ConfigError(f"{name} must be fixed contexts (key=value entries only)")
        if self.eval_every < 0:
            raise ConfigError(f"eval_every must be ≥ 0, got {self.eval_every}")
        top = MAX_SEED - TEST_SEED_OFFSET - max(self.eval_episodes, self.final_eval_episodes)
        if not 1 <= self.eval_seed <= top:
            raise ConfigError(
                f"eval_seed must be in [1, {top}] (the test seeds run to eval_seed + "
                f"{TEST_SEED_OFFSET} + final_eval_episodes, and a seed is at most {MAX_SEED}), "
                f"got {self.eval_seed}"
            )

    def context_specs(self) -> dict[str, ContextSpec]:
        """Every evaluation context set by name: ``"main"`` (``eval_contexts``), then each
        extra test set under its own text (its keys override ``eval_contexts``')."""
        try:
            main = ContextSpec.parse(self.eval_contexts)
            out = {"main": main}
            extra = self.extra_test_contexts
            for text in [t.strip() for t in extra.split("|")] if extra.strip() else []:
                if not text or text in out:
                    raise ConfigError(
                        f"extra_test_contexts {extra!r}: every '|'-separated set must be "
                        f"given once and not be empty, got {text!r}"
                    )
                out[text] = main.updated(ContextSpec.parse(text))
        except ContextSpecError as err:
            raise ConfigError(str(err)) from None
        return out


@dataclass(frozen=True)
class ClusterConfig:
    """Where sampling runs: the Ray cluster, worker placement and the remote servers."""

    address: str = ""
    """Ray cluster to join (ray.init address); empty always starts a new local Ray."""
    worker_cpus: float = 0.5
    """CPUs Ray reserves per worker, > 0 (fractions let workers share a core with the
    learner)."""
    base_port: int = 0
    """env=remote: 0 (the default) gives every worker a private server on a free port, so
    runs never collide; a port P makes worker i use the server on P + i (a fleet started
    with ``neuronsmae-fleet --base-port P --arenas envs_per_worker --time-scale 0``;
    without ``--time-scale 0`` a fleet is paced at 100x), launching one there if none answers."""
    max_worker_failures: int = 5
    """Consecutive failures after which a worker is given up instead of restarted, ≥ 1."""
    groups: int = 1
    """env=remote: groups a worker's arenas are split into, in [1, envs_per_worker], stepped
    in turn (the server steps one group while the worker chooses the other's actions). More
    than one pays only where each worker and its server have a core of their own
    (docs/benchmarks.md, "Sampling")."""
    servers_per_worker: int = 1
    """env=remote with private servers (base_port 0, servers local): vector servers each
    worker launches, in [1, envs_per_worker], holding consecutive shares of its arenas and
    stepped side by side, so one worker's arenas can use several cores. More than one pays
    where a worker has more than its own core; where every core is taken one server per
    worker costs the least CPU (docs/benchmarks.md, "Sampling")."""
    worker_resources: str = ""
    """Custom Ray resources each worker also requires, "name=amount[,...]" (e.g. "sampler=1"
    puts workers only on nodes started with --resources '{"sampler": N}', N per node)."""
    servers: str = "local"
    """env=remote: local (each worker launches its server on its own node, loopback only)
    or actors (a Ray actor per worker runs its server on a node Ray picks, reached by node
    IP)."""
    server_resources: str = ""
    """servers=actors: custom Ray resources each server actor requires, like
    worker_resources."""
    router: str = ""
    """env=remote: reach server base_port + i through this Zenoh router (tcp/host:7447)
    instead; the servers run outside Ray (neuronsmae-fleet --router). See deploy/README.md."""

    def __post_init__(self) -> None:
        check_types(self)
        check_choice("servers", self.servers, SERVER_PLACEMENTS)
        parse_resources(self.worker_resources)
        parse_resources(self.server_resources)
        check_positive(self, "max_worker_failures")
        check_positive(self, "groups", "servers_per_worker")
        if self.servers_per_worker > 1 and (
            self.base_port or self.servers != "local" or self.router
        ):
            raise ConfigError(
                "cluster.servers_per_worker > 1 needs private servers (cluster.base_port=0, "
                f"cluster.servers=local, no cluster.router); got base_port={self.base_port}, "
                f"servers={self.servers!r}, router={self.router!r}"
            )
        if not 0 <= self.base_port < 65536:
            raise ConfigError(
                f"base_port must be 0 (private servers) or a port, got {self.base_port}"
            )
        if self.router:
            try:
                check_locator(self.router, "cluster.router")
            except InvalidOptionError as exc:
                raise ConfigError(str(exc)) from None
        check_finite(self)
        if self.worker_cpus <= 0:
            raise ConfigError(f"worker_cpus must be > 0, got {self.worker_cpus}")


def _auto_generators(info: EnvInfo, observability: str, spawn: str) -> str:
    """Every symmetry the task has (trainers/core/symmetry.py): none in competitive mode (a
    policy on red reads robots by index), none with LiDAR; ``field`` needs random spawns
    (corners are not turned into each other), full observability (a half turn would
    negate the unseen padding) and, with abstract actions, the candidate points in the
    observation (to list them again in the environment's order); ``enemies`` two enemies,
    ``allies`` two agents."""
    ok = (
        info.mode == "cooperative"
        and info.obs.vector
        and not info.obs.lidar_beams
        and info.action_space in Q_ACTION_SPACES
    )
    if not ok:
        return "none"
    wanted = {
        "enemies": info.n_enemies == 2,
        "field": spawn == "random"
        and observability == "full"
        and (info.action_space != "abstract" or info.obs.k > 0),
        "allies": info.n_agents == 2,
    }
    chosen = [name for name in GENERATORS if wanted[name]]
    return ",".join(chosen) or "none"


def resolve_learner(
    learner: LearnerConfig, info: EnvInfo, observability: str, spawn: str
) -> LearnerConfig:
    """``learner`` with each ``auto`` setting made concrete for the task ``info`` (the
    learning team's view):

    * ``features``: relative when the observation holds poses and candidate points, else raw;
    * ``head``: points with relative features and abstract actions, else flat;
    * ``augment``: every symmetry the task has (see :func:`_auto_generators`).

    Explicit settings are kept; ``augment`` with ``field`` under partial observability or
    corner spawns is refused (not a symmetry of that task).
    """
    features = learner.features
    if features == "auto":
        features = "relative" if info.obs.vector and info.obs.k > 0 else "raw"
    head = learner.head
    if head == "auto":
        head = "points" if features == "relative" and info.action_space == "abstract" else "flat"
    augment = learner.augment
    if augment == "auto":
        augment = _auto_generators(info, observability, spawn)
    elif "field" in parse_generators(augment) and (observability, spawn) != ("full", "random"):
        raise ConfigError(
            f"augment={augment!r}: the half turn ('field') is a symmetry of the task only with "
            f"full observability and random spawns, got observability={observability!r}, "
            f"spawn={spawn!r}; use augment='auto' or leave out field"
        )
    return dataclasses.replace(learner, features=features, head=head, augment=augment)
