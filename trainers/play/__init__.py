"""Playing episodes with policies: workers, opponents, evaluation, matches and leagues.

The rollout worker that plays episodes on a vector of arenas (:mod:`.rollout`), red's
policies on it (:mod:`.opponents`), the task the arenas are made with (:mod:`.task`), the
opponent pool and its δ-uniform draw (:mod:`.pool`), greedy evaluation of checkpoints
(:mod:`.evaluate`), checkpoints as match players (:mod:`.policies`, the ``qlearner`` entry
point), ``neuronsmae-match`` (:mod:`.match`) and ``neuronsmae-league`` (:mod:`.league`).
Depends on :mod:`neuronsmae.trainers.core`, never on the training run.
"""
