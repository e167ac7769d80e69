"""Named layers of configuration keys applied before a config file (``--preset NAME``).

A preset is a plain mapping of full config keys to values, checked like any layer by
:func:`~neuronsmae.trainers.run.config.make_config`; ``--set`` and the config file still
override it.
"""

from __future__ import annotations

from typing import Any

from neuronsmae.trainers.checks import ConfigError

PRESETS: dict[str, dict[str, Any]] = {
    "paper": {
        # the agent: the released MLP on the observation alone (network/qmix_net.py myRNN)
        "learner.agent_net": "mlp",
        "learner.agent_hidden": 128,
        "learner.features": "raw",
        "learner.head": "flat",
        "learner.last_action_input": False,
        "learner.agent_id_input": False,
        # QMIX: one-layer weight hypernetworks, embedding 32, agent 0's observation as state
        "learner.mixer_embed": 32,
        "learner.hypernet_layers": 1,
        "learner.mixer_state": "agent0_obs",
        # replay: 200,000 transitions, batches of 2,000 drawn uniformly from the first update
        "learner.replay": "transitions",
        "learner.buffer_size": 200_000,
        "learner.batch_size": 2000,
        "learner.learning_starts": 0,
        "learner.augment": "none",
        # updates: max(20, 2·⌊stored / 2,000⌋) per iteration; one-step targets, max over all
        # actions of the target network, copied at the first update of every 5th iteration
        "learner.updates_per_round": 20,
        "learner.updates_per_stored_batch": 2,
        "learner.td_lambda": 0.0,
        "learner.double_q": False,
        "learner.target_update_interval": 5,
        "learner.target_update_unit": "rounds",
        # all-ones action masks in acting and in targets; destroyed robots trained as living
        "learner.action_masks": "ones",
        "learner.mask_destroyed": False,
        # Adam 5e-4, γ 0.99, gradient-norm clip 10 (common/arguments.py)
        "learner.lr": 5e-4,
        "learner.gamma": 0.99,
        "learner.grad_clip": 10.0,
        # ε 0.2 → 0.05 per episode over 600 episodes on each of 20 workers
        "learner.eps_start": 0.2,
        "learner.eps_end": 0.05,
        "learner.eps_anneal_episodes": 12_000,
        "learner.eps_schedule": "iterations",
        # the loop: iterations of 20 episodes, then their updates; 1,500 iterations
        "sync": True,
        "iteration_episodes": 20,
        "episodes": 30_000,
        "max_minutes": 0.0,
        "envs_per_worker": 10,
        # contexts: trained at coef 0.5 (the build's μ 0.5 for the learning team)
        "contexts": "Friction_coeff=0.5;coef=0.5",
        # evaluation: every 50 iterations 200 greedy episodes at coef 1.5, the released win
        # rule; the final test at coef 1.5 and, beside it, at coef 1.0
        "eval.eval_contexts": "Friction_coeff=0.5;coef=1.5",
        "eval.extra_test_contexts": "coef=1.0",
        "eval.eval_every": 1000,
        "eval.eval_episodes": 200,
        "eval.final_eval_episodes": 200,
        "eval.win_rule": "released",
        "eval.keep_best": False,
    },
}
"""Named layers applied before the config file.

``paper`` is the paper's experiment as its authors ran it: their released training code
(github:DRL-CASIA/NeuronsMAE at 6026fdf; docs/reference.md, "The authors' training as
released"). Where the released code and the paper's text differ, the released code is
followed and the line says so. Fact by fact, with the file it comes from:

* agent: an MLP, observation → 128 → 128 → actions with ReLU (network/qmix_net.py, class
  ``myRNN``, which has no recurrence), fed the observation alone (no last action, no agent
  id; policy/*.py ``_get_inputs``), shared by the agents. The paper says "hidden 128";
  this project's GRU reading of it is gone from the preset.
* QMIX: one-layer weight hypernetworks (common/arguments.py ``two_hyper_layers=False``),
  mixing embedding 32, and the mixer's state is agent 0's observation (RmCooAbsEnv.py
  ``get_state`` returns ``[obs[0]]``); b2's hypernetwork is two layers, b1's one.
* replay: 200,000 transitions; each update draws 2,000 uniformly with replacement, or all
  that are stored while fewer (common/replay_buffer.py, runner.py).
* updates: after each iteration, ``max(20, 2·⌊stored transitions / 2,000⌋)``: 20 at
  first, 200 once the buffer is full (runner.py), about 270,000 in a run; learning starts
  with the first iteration.
* targets: one-step, the target network's max over all actions (no double Q), copied at
  the first update of every 5th iteration counted from 0 (runner.py ``eps %
  target_update_cycle``; policy/*.py ``train_step == 0 and target_update``). The paper's
  "every 5 iterations" agrees.
* masks: all ones in acting and in the targets (RmCooAbsEnv.py, common/rollout.py); a
  destroyed robot's Q enters the mixer and IQL's loss like a living one's, and IQL's
  per-agent targets use the team reward and the episode's end (policy/iql.py).
* Adam 5e-4, γ 0.99, gradient-norm clip 10 (common/arguments.py, as the paper states).
* ε: 0.2 → 0.05 linearly per episode over 600 episodes counted on each of the 20 workers
  (common/arguments.py ``anneal_steps``, common/rollout.py), i.e. one step per iteration:
  the first iteration plays 0.19975, the 600th (12,000 episodes) 0.05.
* loop: an iteration is 20 episodes (the 20 workers' one each, here played by however
  many workers there are), then its updates; 30,000 episodes are 1,500 iterations (the
  released ``n_eps`` 1,501 make 30,020; the last one, 0.07 % of the budget, is left out).
* contexts: training at coef 0.5 (``coef_tr``) for the bots' damage, with the released
  build's μ 0.5 for the learning team (its default for blue; this arena's default is 0.1).
  The ``--dr_coef`` variant is ``--set contexts="Friction_coeff=0.5;coef=0.5,0.7,1,1.4,1.7,2"``.
* evaluation: every 50 iterations (1,000 episodes; the released code also tests after
  iteration 0) 200 greedy episodes at coef 1.5 (``coef_ts``) with the released win rule:
  a win is agent 0's reward at the last step above 13 (``eval.win_rule``); the referee's
  win/draw/loss are recorded beside it. The final weights are tested on 200 held-out
  episodes at coef 1.5 and, as a second column, at coef 1.0; no best-of selection.

Left to the build and decided here (docs/results.md, "The paper's experiment"): the arena
carries out every in-range action the all-ones masks let through as it does any (a
destroyed robot's is ignored, a destroyed enemy is replaced by the nearest live one, a
missing candidate point keeps the robot in place); the build's observation quirks — a
time value stuck at −1 and y normalised with the x centre — are not reproduced (the time
is observed as the paper's table lists it; the shifted y is an affine change that the
MLP's first layer absorbs). The arenas per worker (10) only set how an iteration's 20
episodes are played on two workers, in one wave."""


def preset(name: str) -> dict[str, Any]:
    """The preset layer called ``name``; raise listing the valid ones."""
    try:
        return dict(PRESETS[name])
    except KeyError:
        raise ConfigError(f"unknown preset {name!r}; valid: {', '.join(sorted(PRESETS))}") from None
