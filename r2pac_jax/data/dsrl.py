"""DSRL's HDF5 dataset format: read and validate, write atomically, find files on disk.

A file holds one row per transition under the keys of `KEYS`. Episodes end where
`terminals | timeouts`. Every problem found raises `DatasetError` naming the file, the key and
the fix.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Optional

import numpy as np

from r2pac_jax.errors import R2pacError
from r2pac_jax.io import atomic_path

FLOAT_KEYS = ("observations", "next_observations", "actions", "rewards", "costs")
FLAG_KEYS = ("terminals", "timeouts")
KEYS = FLOAT_KEYS + FLAG_KEYS
ACTION_BOUND = 1.0 + 1e-4  # DSRL stores the clipped actions sent to the env


class DatasetError(R2pacError, ValueError):
    """A dataset file is missing, unreadable or inconsistent."""


class LogMismatch(DatasetError):
    """A generation's log parts from the log of the file it was to make again
    (`data make --expect-log`, exit 3)."""


@dataclasses.dataclass
class Dataset:
    """Transitions in numpy arrays; shapes [N, obs_dim], [N, act_dim] and [N]."""

    observations: np.ndarray
    next_observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    costs: np.ndarray
    terminals: np.ndarray  # bool
    timeouts: np.ndarray  # bool
    source: str = "<memory>"

    @property
    def size(self) -> int:
        return int(self.rewards.shape[0])

    @property
    def obs_dim(self) -> int:
        return int(self.observations.shape[1])

    @property
    def act_dim(self) -> int:
        return int(self.actions.shape[1])

    def episode_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Start and end (inclusive) index of every episode, each [E]."""
        ends = np.flatnonzero(self.terminals | self.timeouts)
        starts = np.concatenate([[0], ends[:-1] + 1])
        return starts, ends

    def episode_sums(self) -> tuple[np.ndarray, np.ndarray]:
        """Undiscounted return and cost of every episode, each [E]."""
        starts, _ = self.episode_bounds()
        return np.add.reduceat(self.rewards, starts), np.add.reduceat(self.costs, starts)

    def as_dict(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in KEYS}

    def digest(self) -> str:
        """sha256 of the arrays' contents (what a resumed run checks it trains on again)."""
        import hashlib

        h = hashlib.sha256()
        for k in KEYS:
            # the array's own buffer, the bytes tobytes() would copy (1.5 GB for the largest file)
            h.update(memoryview(np.ascontiguousarray(getattr(self, k))).cast("B"))
        return h.hexdigest()


def _fail(path, key, problem, fix) -> DatasetError:
    where = f"{path}" + (f", key '{key}'" if key else "")
    return DatasetError(f"{where}: {problem}. Fix: {fix}")


def validate(arrays: dict, path: str = "<memory>", obs_dim: Optional[int] = None,
             act_dim: Optional[int] = None, task_name: str = "") -> Dataset:
    """Check keys, shapes, dtypes, finiteness and episode structure; return a `Dataset`."""
    regen = (f"regenerate it with `python -m r2pac_jax.data make --task {task_name}`"
             if task_name else "regenerate the file in DSRL's format")
    missing = [k for k in KEYS if k not in arrays]
    if missing:
        raise _fail(path, missing[0], f"missing key(s) {missing}; a DSRL file holds {list(KEYS)}",
                    regen)
    out = {}
    n = None
    for k in KEYS:
        a = np.asarray(arrays[k])
        if k in ("observations", "next_observations", "actions"):
            if a.ndim != 2:
                raise _fail(path, k, f"expected a 2-D array [N, dim], got shape {a.shape}", regen)
        else:
            if a.ndim == 2 and a.shape[1] == 1:
                a = a[:, 0]  # DSRL sometimes stores (N, 1)
            if a.ndim != 1:
                raise _fail(path, k, f"expected shape [N] or [N, 1], got {a.shape}", regen)
        if n is None:
            n = a.shape[0]
        elif a.shape[0] != n:
            raise _fail(path, k, f"has {a.shape[0]} rows but 'observations' has {n}",
                        "every key must hold one row per transition; " + regen)
        if k in FLOAT_KEYS:
            if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
                raise _fail(path, k, f"dtype {a.dtype} is not numeric", regen)
            a = a.astype(np.float32, copy=False)  # a float32 file is not copied
            bad = _rows_not_finite(a.reshape(n, -1))
            if bad.size:
                raise _fail(path, k, f"{bad.size} rows hold NaN or inf (first at row {bad[0]})",
                            "drop or repair those transitions; " + regen)
        else:
            if a.dtype != np.bool_:
                if not (np.issubdtype(a.dtype, np.number) and np.isin(a, (0, 1)).all()):
                    raise _fail(path, k, f"flags must be bool or 0/1, got dtype {a.dtype} with "
                                f"values {np.unique(a)[:5]}", regen)
                a = a.astype(bool)
        out[k] = a
    if n == 0:
        raise _fail(path, "observations", "the dataset is empty", regen)
    if out["next_observations"].shape != out["observations"].shape:
        raise _fail(path, "next_observations", f"shape {out['next_observations'].shape} differs "
                    f"from observations {out['observations'].shape}", regen)
    if obs_dim is not None and out["observations"].shape[1] != obs_dim:
        raise _fail(path, "observations", f"has {out['observations'].shape[1]} columns but task "
                    f"{task_name or '?'} has observations of size {obs_dim}",
                    "the file belongs to another task: pass the matching --task or --dataset")
    if act_dim is not None and out["actions"].shape[1] != act_dim:
        raise _fail(path, "actions", f"has {out['actions'].shape[1]} columns but task "
                    f"{task_name or '?'} has actions of size {act_dim}",
                    "the file belongs to another task: pass the matching --task or --dataset")
    neg = np.flatnonzero(out["costs"] < 0)
    if neg.size:
        first = ", ".join(f"row {i}: {out['costs'][i]:g}" for i in neg[:3])
        raise _fail(path, "costs", f"{neg.size} rows hold negative costs ({first}); DSRL's costs "
                    "are >= 0, and a safety limit on the episode cost (<= kappa) means nothing "
                    "otherwise", "store each step's constraint violation as a cost >= 0 (a "
                    "signed or shaped signal belongs in the rewards); " + regen)
    amax = float(np.abs(out["actions"]).max())
    if amax > ACTION_BOUND:
        raise _fail(path, "actions", f"values reach {amax:.3g}, outside the action box [-1, 1]",
                    "store the clipped actions that were sent to the environment")
    ends = out["terminals"] | out["timeouts"]
    if not ends[-1]:
        raise _fail(path, "timeouts", "the last transition ends no episode (neither terminal nor "
                    "timeout)", "flag the final transition of every episode, or drop the "
                    "incomplete last episode")
    # Inside an episode, each next observation is the following observation.
    bad = _unfollowed_rows(out["observations"], out["next_observations"], ends)
    if bad.size:
        raise _fail(path, "terminals/timeouts",
                    f"{bad.size} transitions are not followed by their next observation but "
                    f"no episode end is flagged there (first at row {bad[0]})",
                    "flag episode ends with terminals or timeouts so that episodes are "
                    "contiguous runs of rows")
    return Dataset(**out, source=str(path))


# Rows per block of the checks below: whole-array checks made temporaries of several GB on the
# largest file (CarPush2 at DSRL's size, 3 GB; blocks took 1.3 GiB off `train`'s 9.3 GiB peak).
_CHECK_BLOCK = 1 << 16


def _rows_not_finite(a: np.ndarray) -> np.ndarray:
    """Indices of the rows of a[N, d] holding NaN or inf, in order."""
    bad = [s + np.flatnonzero(~np.isfinite(a[s:s + _CHECK_BLOCK]).all(axis=1))
           for s in range(0, a.shape[0], _CHECK_BLOCK)]
    return np.concatenate(bad) if bad else np.zeros(0, np.int64)


def _unfollowed_rows(obs: np.ndarray, next_obs: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Indices i < N-1 not ending an episode (ends[i] False) whose next_obs[i] differs from
    obs[i+1] beyond 1e-4 (1 + max|obs[i+1]|), in order; obs, next_obs [N, d], ends [N] bool."""
    bad = []
    for s in range(0, obs.shape[0] - 1, _CHECK_BLOCK):
        inside = s + np.flatnonzero(~ends[s:min(s + _CHECK_BLOCK, obs.shape[0] - 1)])
        following = obs[inside + 1]
        gap = np.abs(next_obs[inside] - following).max(axis=1)
        scale = 1e-4 * (1.0 + np.abs(following).max(axis=1))
        bad.append(inside[gap > scale])
    return np.concatenate(bad) if bad else np.zeros(0, np.int64)


def load_dsrl(path, obs_dim: Optional[int] = None, act_dim: Optional[int] = None,
              task_name: str = "") -> Dataset:
    """Read and validate a DSRL HDF5 file."""
    import h5py

    path = Path(path).expanduser()
    if not path.exists():
        raise DatasetError(f"{path}: no such file. Fix: pass an existing --dataset path, or drop "
                           "--dataset to use DSRL's directory or generated data")
    if path.is_dir():
        raise DatasetError(f"{path} is a directory. Fix: pass the dataset's .hdf5 file itself "
                           "(for example one of the files in it)")
    try:
        with h5py.File(path, "r") as f:
            arrays = {k: f[k][()] for k in KEYS if k in f}
    except OSError as e:
        raise DatasetError(f"{path}: cannot be read as HDF5 ({e}). Fix: the file is damaged or "
                           "not HDF5; download or generate it again") from e
    return validate(arrays, str(path), obs_dim, act_dim, task_name)


def write_dsrl(path, data, attrs: Optional[dict] = None) -> Path:
    """Write a dataset in DSRL's format (float32 gzip, bool flags), atomically.

    `data` is a `Dataset` or a dict of arrays; it is validated first, so a written file always
    reads back. The file appears complete or not at all.
    """
    import h5py

    path = Path(path).expanduser()
    ds = data if isinstance(data, Dataset) else validate(data, str(path))
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            for k, v in ds.as_dict().items():
                f.create_dataset(k, data=v, compression="gzip")
            for k, v in (attrs or {}).items():
                f.attrs[k] = v
    return path


def dsrl_dirs() -> list[Path]:
    """Where DSRL keeps its files: $DSRL_DATASET_DIR, else ~/.dsrl/datasets."""
    env = os.environ.get("DSRL_DATASET_DIR")
    return [Path(env).expanduser()] if env else [Path("~/.dsrl/datasets").expanduser()]


def find_dsrl_file(task) -> Optional[Path]:
    """A DSRL file `{GymId}-{cmax}-{ntraj}.hdf5` for the task, or None.

    Where several exist, the one with DSRL's trajectory count for the task is preferred.
    """
    if not task.gym_id:
        return None
    found = []
    for d in dsrl_dirs():
        if d.is_dir():
            found += sorted(d.glob(f"{task.gym_id}-*-*.hdf5"))
    if not found:
        return None
    want = task.dsrl_trajectories
    for p in found:
        if want is not None and p.stem.endswith(f"-{want}"):
            return p
    return found[0]
