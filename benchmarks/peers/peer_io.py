"""What every peer script shares: reading one of our DSRL-format files. Imported by the peers,
which run in their own side virtualenvs (their directory is on sys.path as scripts)."""
from __future__ import annotations

import numpy as np

KEYS = ("observations", "next_observations", "actions", "rewards", "costs", "terminals",
        "timeouts")


def read_dsrl(path, dtype=None) -> dict:
    """The file's seven DSRL arrays as numpy, each cast to `dtype` when given."""
    import h5py

    with h5py.File(path, "r") as f:
        return {k: np.asarray(f[k]) if dtype is None else np.asarray(f[k]).astype(dtype)
                for k in KEYS}
