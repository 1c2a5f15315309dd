"""Command-line tools of rlpgo_gtsam.

- ``rlpgo-init``: write an initial guess for a g2o pose graph.
- ``rlpgo-compare``: initial guesses side by side, each refined by the same GTSAM solver.
- ``rlpgo-generate``: write one of the paper's synthetic lawn-mower graphs.
- ``rlpgo-train``: train a recurrent SAC agent on a preset's generated graphs.
- ``rlpgo-eval``: a trained agent against random actions and the edge-balancing rule.
- ``rlpgo-example``: the pose graphs of GTSAM's example data; with a name, one's path.

Each command parses options, calls the library and prints; errors become one
``Error: <message>`` line and a non-zero exit (``rlpgo_cli.errors``), and every output goes
through ``rlpgo_cli.output``.
"""
