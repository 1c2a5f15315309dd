"""The RL-PGO agent (Kourtzanidis & Saeedi): a recurrent soft actor-critic that rotates the
two orientations of each edge as it walks the graph.

:mod:`~rlpgo_gtsam.rl.episode` (the walk, numpy only), :mod:`~rlpgo_gtsam.rl.env` (the
gymnasium environment), :mod:`~rlpgo_gtsam.rl.agent` (networks, SAC, checkpoints: torch),
:mod:`~rlpgo_gtsam.rl.train`, :mod:`~rlpgo_gtsam.rl.evaluation`,
:mod:`~rlpgo_gtsam.rl.initializer` (``RLInitializer``, the ``rl`` method) and
:mod:`~rlpgo_gtsam.rl.models` (shipped models by name). Importing this package loads
neither torch nor gymnasium; the modules that need them load them.
"""
