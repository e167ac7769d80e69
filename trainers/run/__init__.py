"""The training run: its configuration, the Ray sampling workers and the loop.

:class:`~.config.TrainConfig` and its groups (:mod:`.config`, :mod:`.config_groups`,
per-episode contexts in :mod:`.contexts`), the sampler and its placement on a Ray cluster
(:mod:`.sampler`, :mod:`.placement`), the loop (:mod:`.train`), self-play's bookkeeping
(:mod:`.competition`), records and plots (:mod:`.records`, :mod:`.plot`), the checkpoint,
replay and best weights (:mod:`.saving`), stopping on a signal (:mod:`.interrupt`),
``neuronsmae-train`` (:mod:`.cli`) and the experiments kept off by default
(:mod:`.experimental`). The top of the dependency order: it uses
:mod:`neuronsmae.trainers.core` and :mod:`neuronsmae.trainers.play`.
"""
