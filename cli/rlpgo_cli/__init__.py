"""Command-line tools of rlpgo_gtsam: rlpgo-compare (and, with the agent, rlpgo-init)."""
