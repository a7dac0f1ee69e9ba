"""Backend-neutral RL algorithms (returns, networks, normalization, gradient statistics) in plain torch."""
