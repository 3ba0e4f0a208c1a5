"""Lanes: the seeds x hyperparameter cells that one compiled program trains side by side.

Each lane has a seed and values of its algorithm's vmappable scalars (`HPARAMS` of its module,
e.g. R2PAC's alpha, C and guidance scale); everything else is shared by all lanes. The loop
vmaps `init` and the blocks over the lane axis, and spreads that axis over local devices.
"""
from __future__ import annotations

import dataclasses
from typing import Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.config import Config, ConfigError, check_hparams


@dataclasses.dataclass
class Lanes:
    seeds: list[int]  # per lane
    cells: list[int]  # per lane: index into `cell_hparams`
    cell_hparams: list[dict]  # per cell: {name: value} of the algorithm's HPARAMS
    hp: dict  # {name: [L] float32}

    @property
    def size(self) -> int:
        return len(self.seeds)

    @staticmethod
    def build(cfg: Config, seeds: Sequence[int], cells: Optional[Sequence[dict]] = None) -> "Lanes":
        from r2pac_jax.agents import algo_module

        names = algo_module(cfg.algo).HPARAMS
        base = {k: float(getattr(cfg, k)) for k in names}
        cells = [dict(c) for c in (cells or [{}])]
        full = []
        for c in cells:
            unknown = set(c) - set(base)
            if unknown:
                raise ConfigError(f"cannot vary {sorted(unknown)} across lanes of {cfg.algo}; "
                                  f"its vmappable hyperparameters are {list(names)}")
            merged = {k: float(c.get(k, base[k])) for k in names}
            check_hparams(cfg.algo, merged)
            full.append(merged)
        lane_seeds = [s for _ in full for s in seeds]
        lane_cells = [i for i in range(len(full)) for _ in seeds]
        hp = {k: jnp.asarray([full[c][k] for c in lane_cells], jnp.float32) for k in names}
        return Lanes(list(lane_seeds), lane_cells, full, hp)

    def init_keys(self) -> jax.Array:
        """[L] PRNG keys: PRNGKey(seed) of each lane."""
        return jnp.stack([jax.random.PRNGKey(s) for s in self.seeds])

    def broadcast(self, tree):
        """A pytree of one lane's values -> the same with a leading [L] axis."""
        return jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (self.size,) + jnp.shape(x)),
                                      tree)


def place(tree, lanes: int):
    """Spread the lane axis over the local devices when it divides evenly (jax.sharding);
    XLA then partitions the vmapped program along lanes. A no-op on one device."""
    devices = jax.local_devices()
    if len(devices) < 2 or lanes % len(devices):
        return tree
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    sharding = NamedSharding(Mesh(np.array(devices), ("lanes",)), PartitionSpec("lanes"))
    return jax.device_put(tree, sharding)
