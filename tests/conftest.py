import atexit
import importlib.util
import os
import shutil
import tempfile
from pathlib import Path

os.environ.setdefault("R2PAC_NO_TENSORBOARD", "1")
# Tests never touch the user's dataset caches (a CLI test that makes data would otherwise leave
# it in ~/.cache): one throwaway cache per test session, inherited by subprocesses.
_CACHE = tempfile.mkdtemp(prefix="r2pac-test-cache-")
atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)
os.environ["R2PAC_DATA_DIR"] = os.path.join(_CACHE, "gen")
os.environ["DSRL_DATASET_DIR"] = os.path.join(_CACHE, "dsrl")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
# One XLA compilation cache per test run, shared by the xdist workers and the subprocesses the
# tests start (they inherit the environment): the same tiny programs compile once per run, not
# once per process. The first process to import this makes it (and removes it at exit); a run
# starts cold, so the suite's time is a fresh machine's.
if "R2PAC_TEST_XLA_CACHE" not in os.environ:
    os.environ["R2PAC_TEST_XLA_CACHE"] = tempfile.mkdtemp(prefix="r2pac-test-xla-")
    atexit.register(shutil.rmtree, os.environ["R2PAC_TEST_XLA_CACHE"], ignore_errors=True)
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.environ["R2PAC_TEST_XLA_CACHE"])
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from r2pac_jax.config import make_config  # noqa: E402

TINY = dict(steps=20, batch_size=32, hidden_dims=(16, 16), actor_hidden_dims=(16, 16),
            block_steps=10, eval_every=10, checkpoint_every=10, flow_steps=4,
            num_candidates=4, threshold_subset=256, eval_episodes=2, seeds=2,
            # the OSRL-ported baselines' networks
            a_hidden_dims=(16, 16), c_hidden_dims=(16, 16), vae_hidden=16,
            critic_hidden_dims=(16, 16), actor_hidden=16, actor_blocks=1, critic_batch=16,
            # CDT's transformer
            embedding_dim=16, num_heads=2, num_layers=1,
            # TREBI's U-Net and planner (at least 2 channels in each of GroupNorm's 8 groups:
            # with one, a conv's bias is cancelled exactly and Adam amplifies its noise)
            horizon=4, unet_dim=16, unet_mults=(1, 4), diffusion_steps=3, plans=2)


ROOT = Path(__file__).resolve().parents[1]


def load_script(relpath: str, name: str | None = None):
    """A script outside the package (benchmarks/, experiments/) as a fresh module object.

    `relpath` is relative to the repository root; each call executes the file anew, so a test
    that monkeypatches module globals cannot leak into another test's copy."""
    path = ROOT / relpath
    spec = importlib.util.spec_from_file_location(name or path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def tiny_config(algo="r2pac", task="ReachAvoid", **kw):
    """Tiny networks and few steps; TINY's keys that `algo` does not have are left out."""
    from r2pac_jax.config import field_types

    keys = field_types(algo)
    over = {k: v for k, v in TINY.items() if k in keys}
    over.update(kw)
    return make_config(task, algo, "quick", over)


@pytest.fixture
def data_dir(tmp_path, monkeypatch):
    """Isolated dataset caches for tests."""
    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path / "gen"))
    monkeypatch.setenv("DSRL_DATASET_DIR", str(tmp_path / "dsrl"))
    return tmp_path


def toy_arrays(episodes=((4, "timeout"), (3, "terminal")), obs_dim=3, act_dim=2, seed=0):
    """A small DSRL-format dataset with consistent episodes (next_obs[t] == obs[t+1] inside)."""
    rng = np.random.default_rng(seed)
    parts = {k: [] for k in ("observations", "next_observations", "actions", "rewards", "costs",
                             "terminals", "timeouts")}
    for length, end in episodes:
        obs = rng.normal(size=(length + 1, obs_dim)).astype(np.float32)
        parts["observations"].append(obs[:-1])
        parts["next_observations"].append(obs[1:])
        parts["actions"].append(rng.uniform(-1, 1, (length, act_dim)).astype(np.float32))
        parts["rewards"].append(rng.normal(size=length).astype(np.float32))
        parts["costs"].append((rng.uniform(size=length) < 0.3).astype(np.float32))
        term = np.zeros(length, bool)
        tout = np.zeros(length, bool)
        (term if end == "terminal" else tout)[-1] = True
        parts["terminals"].append(term)
        parts["timeouts"].append(tout)
    return {k: np.concatenate(v) for k, v in parts.items()}


def random_action_arrays(env, n: int, seed: int = 0) -> dict:
    """DSRL-format arrays of `n` whole episodes of uniform random actions in a batched Python-loop
    env (reset_batch / step_batch), episode-major ([n * episode_len, ...])."""
    rng = np.random.default_rng(seed)
    st = env.reset_batch(jax.random.split(jax.random.PRNGKey(seed), n))
    parts = {k: [] for k in ("observations", "next_observations", "actions", "rewards", "costs",
                             "terminals", "timeouts")}
    for _ in range(env.episode_len):
        a = rng.uniform(-1, 1, (n, env.act_dim)).astype(np.float32)
        nxt = env.step_batch(st, a)
        for k, v in (("observations", st.obs), ("next_observations", nxt.obs), ("actions", a),
                     ("rewards", nxt.reward), ("costs", nxt.cost),
                     ("terminals", nxt.terminated), ("timeouts", nxt.truncated)):
            parts[k].append(np.asarray(v))
        st = nxt
    # [T, n, ...] -> episode-major [n * T, ...]
    return {k: np.stack(v, 1).reshape((n * env.episode_len,) + np.shape(v[0])[1:])
            for k, v in parts.items()}


@pytest.fixture(scope="session")
def reach_avoid_data(tmp_path_factory):
    """A small generated ReachAvoid dataset (60 trajectories), shared across tests."""
    from r2pac_jax.data.dsrl import validate
    from r2pac_jax.data.factory import reach_avoid

    arrays = reach_avoid.generate(60, seed=0)
    return validate(arrays, "reach_avoid_test")


# The tiny r2pac run of the CLI's bad-input and fault tests: TINY's values as --set options.
TINY_ARGV = ["--set", "steps=20", "--set", "batch_size=32", "--set", "hidden_dims=16,16",
             "--set", "block_steps=10", "--set", "checkpoint_every=10", "--set",
             "flow_steps=4", "--set", "num_candidates=4", "--set", "threshold_subset=256",
             "--set", "actor_hidden_dims=16,16", "--eval-episodes", "2", "--eval-every", "10",
             "--seeds", "2", "--no-progress"]


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory, reach_avoid_data):
    """A finished tiny r2pac run on ReachAvoid (2 seeds, 20 + 20 steps, checkpoints at 30 and 40
    kept) and its dataset file, made once per test process: {"d": file, "run": dir}. Tests copy
    it before changing anything in it."""
    from r2pac_jax.data.dsrl import write_dsrl
    from r2pac_jax.train import main

    t = tmp_path_factory.mktemp("tiny_run")
    d = t / "ra.hdf5"
    write_dsrl(d, reach_avoid_data, attrs={"task": "ReachAvoid"})
    run = t / "run"
    assert main(["--task", "ReachAvoid", "--dataset", str(d), "--out", str(run), "--baselines",
                 "none"] + TINY_ARGV) == 0
    return dict(t=t, d=d, run=run)
