"""The recurrent soft actor-critic agent of RL-PGO: networks, replay, training, checkpoints."""
