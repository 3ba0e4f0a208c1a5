"""ReachAvoid's data source: the scripted behaviour mix of envs/reach_avoid.py."""
from __future__ import annotations

import jax
import numpy as np

from r2pac_jax.data.factory.batch import keep_valid_steps
from r2pac_jax.envs import reach_avoid as ra

DEFAULT_TRAJECTORIES = 600


def generate(n_trajectories: int, seed: int, progress=None) -> dict:
    """Roll out `n_trajectories` behaviours; DSRL arrays with only the real (pre-end) steps."""
    env = ra.ReachAvoidEnv()

    @jax.jit
    def one_batch(keys):
        def single(k):
            kb, kr = jax.random.split(k)
            return ra.rollout_behaviour(env, ra.sample_behaviour(kb), kr)
        return jax.vmap(single)(keys)

    keys = jax.random.split(jax.random.PRNGKey(seed), n_trajectories)
    parts = []
    batch = 200
    for i in range(0, n_trajectories, batch):
        parts.append(keep_valid_steps(one_batch(keys[i:i + batch])))
        if progress is not None:
            progress(min(batch, n_trajectories - i))
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return out


SOURCE = dict(name="scripted waypoint controllers (risk, speed and noise knobs)",
              generate=generate, default_trajectories=DEFAULT_TRAJECTORIES)
