"""r2pac-jax: R2PAC (Region-Based Reward Penalty over Action Chunks) for offline safe RL in JAX."""
from __future__ import annotations

__version__ = "0.1.0"


def load_policy(run_dir, lane: int = 0):
    """A jitted `act(obs, key) -> action` from a finished training run directory.

    obs is [obs_dim] or [B, obs_dim]; `lane` picks the seed (and grid cell) of the run.
    """
    from r2pac_jax.policy import load_policy as _load

    return _load(run_dir, lane)
