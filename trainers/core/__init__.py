"""The learning core: torch only, no Ray and no run configuration.

The agent networks (:mod:`.agent`: PyMARL's GRU and the released code's MLP), the mixers
by name (:mod:`.mixers`: none for IQL, VDN, QMIX), the one Q-learner (:mod:`.learner`), the
replays of whole episodes and of single transitions (:mod:`.buffer`), the agents' derived
inputs (:mod:`.features`), the task's symmetries and the point order they keep
(:mod:`.symmetry`, :mod:`.point_order`), a policy and a team acting greedily with it
(:mod:`.acting`), and the checkpoint format (:mod:`.checkpoint`).
"""
