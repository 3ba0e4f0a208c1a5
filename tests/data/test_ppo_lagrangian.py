"""The learned-behaviour data source (DSRL's recipe): GAE, the PID multiplier, the schedule, the
resumable generation on both rollout paths (JAX scan on ReachAvoid, C MuJoCo on a velocity task),
its files and its errors."""
import json
import os

import chex
import h5py
import jax.numpy as jnp
import numpy as np
import pytest

from r2pac_jax.data import factory
from r2pac_jax.data.dsrl import DatasetError
from r2pac_jax.data.factory import collect
from r2pac_jax.data.factory import ppo_lagrangian as pl
from r2pac_jax.io import DirectoryBusy
from r2pac_jax.tasks import get_task

RA = dict(trajectories=12, env_steps=16 * 80 * 4, ppo=dict(num_envs=16, rollout_len=80,
                                                           hidden=(16,), minibatches=2, epochs=2),
          checkpoint_every=1, progress=False, log=lambda m: None)
# Hopper falls within tens of steps under a random policy: episodes cross update boundaries
HOP = dict(trajectories=6, env_steps=2 * 60 * 3, ppo=dict(num_envs=2, rollout_len=60,
                                                          hidden=(16,), minibatches=2, epochs=1),
           checkpoint_every=1, progress=False, log=lambda m: None)


def _col(x):
    return jnp.asarray(x, jnp.float32)[:, None]  # [T] -> [T, N=1]


def test_gae_bootstraps_a_time_limit_but_not_a_terminal():
    r, v, nv = _col([1, 1, 1]), _col([0, 0, 0]), _col([5, 5, 5])
    # the episode is cut by the time limit after step 3: its next value still counts
    adv, tgt = pl.gae(r, v, nv, _col([0, 0, 0]), _col([0, 0, 1]), gamma=0.5, lam=1.0)
    chex.assert_trees_all_close(adv[:, 0], jnp.array([6.125, 5.25, 3.5]))
    chex.assert_trees_all_close(tgt, adv + v)
    # a true terminal at step 3: no bootstrap there
    adv, _ = pl.gae(r, v, nv, _col([0, 0, 1]), _col([0, 0, 1]), gamma=0.5, lam=1.0)
    chex.assert_trees_all_close(adv[:, 0], jnp.array([5.5, 4.0, 1.0]))
    # an episode boundary after step 1 stops the recursion there
    adv, _ = pl.gae(r, v, nv, _col([1, 0, 0]), _col([1, 0, 0]), gamma=0.5, lam=1.0)
    chex.assert_trees_all_close(adv[0, 0], jnp.array(1.0))


def test_pid_multiplier_as_dsrl():
    gains = (0.05, 0.005, 0.1)
    st, lam = pl.pid_multiplier((0.0, 0.0), 30.0, 10.0, gains)  # error 20, rising by 20
    assert st == (20.0, 20.0) and lam == pytest.approx(0.05 * 20 + 0.005 * 20 + 0.1 * 20)
    st, lam = pl.pid_multiplier(st, 15.0, 10.0, gains)  # error 5, falling: no derivative term
    assert st == (25.0, 5.0) and lam == pytest.approx(0.05 * 5 + 0.005 * 25)
    st, lam = pl.pid_multiplier(st, 0.0, 10.0, gains)  # below the limit: integral unwinds
    assert st == (15.0, -10.0) and lam == pytest.approx(0.005 * 15)
    st, lam = pl.pid_multiplier((0.0, 0.0), 0.0, 10.0, gains)
    assert lam == 0.0 and st[0] == 0.0


def test_dsrl_schedule_and_its_errors():
    s = pl.CostSchedule(180.0, 5.0, 4_000_000, 20_000_000)  # CarGoal2: epochs 400 -> 2000
    assert s.limit(0) == 180.0 and s.limit(4_000_000) == 180.0
    assert s.limit(12_000_000) == pytest.approx(92.5)
    assert s.limit(20_000_000) == pytest.approx(5.0) and s.limit(22_000_000) == pytest.approx(5.0)
    rising = pl.CostSchedule(5.0, 100.0, 0, 10)  # Bullet tasks raise it
    assert rising.limit(5) == pytest.approx(52.5)
    with pytest.raises(DatasetError, match="limits must be > 0"):
        pl.CostSchedule(0.0, 5.0, 0, 10)
    with pytest.raises(DatasetError, match="start_step < end_step"):
        pl.CostSchedule(10.0, 5.0, 10, 10)
    t = get_task("CarGoal2")
    full = collect.make_spec(t)
    assert (full.env_steps, full.trajectories, full.cost_cap) == (22_000_000, 4105, 200.0)
    assert (full.schedule.start_step, full.schedule.end_step) == (4_000_000, 20_000_000)
    assert full.steps_per_update == 10_000 and full.updates == 2200
    half = collect.make_spec(t, env_steps=11_000_000)  # a smaller budget scales the schedule
    assert (half.schedule.start_step, half.schedule.end_step) == (2_000_000, 10_000_000)
    with pytest.raises(DatasetError, match="minibatches"):
        collect.make_spec(t, ppo=dict(num_envs=3, rollout_len=7, minibatches=4))
    ball = collect.make_spec(get_task("BallCircle"))  # DSRL's rising Bullet schedule
    assert (ball.physics, ball.env_steps, ball.cost_cap, ball.trajectories) == (
        "bullet", 10_000_000, 80.0, 886)
    assert ball.schedule.limit(0) == 5.0 and ball.schedule.limit(10_000_000) == 200.0
    assert ball.steps_per_update == 10_000 and ball.ppo.rollout_len == 200
    with pytest.raises(DatasetError, match="made on the original's engine"):
        collect.make_spec(get_task("BallCircle"), physics="mjx")  # MuJoCo: evaluation only


def _arrays(path):
    with h5py.File(path, "r") as f:
        return {k: np.asarray(f[k]) for k in f.keys()}


# BallRun: pybullet's simulations live outside the state; a resumed generation rebuilds them
# (rollouts of 60 steps: episodes of 100 cross the update boundaries, so they are replayed)
BALL = dict(trajectories=4, env_steps=2 * 60 * 5, ppo=dict(num_envs=2, rollout_len=60,
                                                           hidden=(16,), minibatches=2, epochs=1),
            checkpoint_every=1, progress=False, log=lambda m: None)


@pytest.mark.parametrize("name,kw", [("ReachAvoid", dict(RA, env_steps=16 * 80 * 5,
                                                          checkpoint_every=2)),
                                     ("HopperVelocity", HOP),
                                     # slow: the bullet revive is tested in test_bullet.py
                                     pytest.param("BallRun", BALL, marks=pytest.mark.slow)])
def test_resumed_generation_equals_an_uninterrupted_one(name, kw, tmp_path):
    task = get_task(name)
    full = collect.generate_learned(task, tmp_path / "full.hdf5", **kw)
    part = tmp_path / "part.hdf5"
    episodes = tmp_path / "part.hdf5.partial" / "episodes"
    if kw["checkpoint_every"] == 2:  # killed between checkpoints: after update 3 of 5
        # first killed before its first checkpoint: the next run starts afresh, its log too
        assert collect.generate_learned(task, part, stop_after=1, **kw) is None
        assert not (tmp_path / "part.hdf5.partial" / "state.pkl").exists()
        assert collect.generate_learned(task, part, stop_after=3, **kw) is None
        n_after_3 = len(list(episodes.glob("ep-*.npz")))
        assert collect.generate_learned(task, part, stop_after=0, **kw) is None  # resume only
        assert len(list(episodes.glob("ep-*.npz"))) < n_after_3  # update 3's episodes went
    else:
        assert collect.generate_learned(task, part, stop_after=1, **kw) is None  # killed
        assert (tmp_path / "part.hdf5.partial" / "state.pkl").exists() and not part.exists()
        assert collect.generate_learned(task, part, stop_after=1, **kw) is None  # and again
    assert collect.generate_learned(task, part, **kw) == part
    a, b = _arrays(full), _arrays(part)
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    card = json.loads(factory.card_path(part).read_text())
    assert card["data_version"] == 2 and card["source"] == "ppo-lagrangian"
    # the physics library's version, so a regenerated file can be matched to its card
    import mujoco
    assert card["versions"]["mujoco"] == mujoco.__version__
    # and the machine: XLA's CPU numerics follow the CPUs it may use
    assert card["machine"]["cpus"] == len(os.sched_getaffinity(0))
    assert card["machine"]["cpu"] and card["machine"]["arch"]
    assert card["budget_below_dsrl"] and card["trajectories"] <= kw["trajectories"]
    assert card["generation"]["updates"] == kw["env_steps"] // (
        kw["ppo"]["num_envs"] * kw["ppo"]["rollout_len"])
    log = [json.loads(ln) for ln in part.with_suffix(".log.jsonl").read_text().splitlines()]
    assert [r["update"] for r in log] == list(range(1, card["generation"]["updates"] + 1))
    # where each update's time went (profiling only): the parts lie within the update's wall;
    # the simulator's share where Python steps it (C MuJoCo, pybullet), not for a JAX env; each
    # checkpoint's time in the row after it
    python_stepped = not task.make_env(physics=collect.make_spec(task).physics).is_jax
    every = kw["checkpoint_every"]
    full_log = [json.loads(ln) for ln in (tmp_path / "full.log.jsonl").read_text().splitlines()]
    for r in full_log:
        wall = (r["env_steps"] / r["update"]) / r["steps_per_s"]
        assert 0 < r["t_rollout"] + r["t_pool"] + r["t_update"] <= wall + 1e-3
        assert ("t_physics" in r) == python_stepped
        assert r.get("t_physics", 0.0) <= r["t_rollout"]
        assert ("t_checkpoint_before" in r) == (r["update"] > 1 and (r["update"] - 1) % every == 0)
    assert part.with_suffix(".training.png").exists() and part.with_suffix(".png").exists()
    assert not (tmp_path / "part.hdf5.partial").exists()  # cleaned up once the file exists
    # episodes are whole: each ends in a terminal or a timeout, and costs respect the cap
    ends = np.flatnonzero(a["terminals"] | a["timeouts"])
    assert ends[-1] == a["rewards"].size - 1
    starts = np.concatenate([[0], ends[:-1] + 1])
    assert np.all(np.add.reduceat(a["costs"], starts) <= task.collection.cost_cap)
    if name == "HopperVelocity":  # terminals (falls) seen, next_obs continues obs within episodes
        assert a["terminals"].any()
        inner = np.setdiff1d(np.arange(a["rewards"].size - 1), ends)
        np.testing.assert_array_equal(a["next_observations"][inner], a["observations"][inner + 1])


def test_an_update_row_is_checked_against_the_expected_log(tmp_path):
    """The check itself (the generation below runs it after each row and on resume): wall-clock
    fields aside, a differing row names its update and values; updates past the log pass."""
    task = get_task("ReachAvoid")
    spec = collect.make_spec(task, RA["trajectories"], RA["env_steps"], ppo=RA["ppo"])
    rows = [dict(update=1, multiplier=0.0, episode_return=1.5, steps_per_s=10.0)]
    gen = collect.Generation(task, spec, tmp_path / "p", expected=(rows, "pin.log.jsonl.gz"))
    gen._check_row(dict(rows[0], steps_per_s=99.0, t_rollout=3.0))  # timings only: agrees
    gen._check_row(dict(update=2, multiplier=5.0))  # past the expected log: nothing to match
    with pytest.raises(collect.LogMismatch, match=r"ReachAvoid: update 1 of the generation differs "
                                                  r"from pin.log.jsonl.gz \(episode_return 1.25 "
                                                  r"here, 1.5 expected\)"):
        gen._check_row(dict(rows[0], episode_return=1.25))
    collect.Generation(task, spec, tmp_path / "q")._check_row(dict(update=1))  # no log: no check


@pytest.mark.slow  # two generations' compilations (python -m pytest -m slow)
def test_an_expected_log_stops_a_generation_at_its_first_differing_update(tmp_path):
    """A machine that does not make a pinned file again is told an update in, not hours later
    by the digest: the generation stops at the first row that differs from the file's log
    (wall-clock fields aside), on resume too, and keeps its partial state."""
    import gzip
    import pickle

    task = get_task("ReachAvoid")
    part, partial = tmp_path / "part.hdf5", tmp_path / "part.hdf5.partial"
    assert collect.generate_learned(task, part, stop_after=1, **RA) is None
    row1 = collect.read_log(partial / "log.jsonl")[0]

    def expected(name, rows):
        path = tmp_path / name
        with gzip.open(path, "wt") as f:  # as results_v2 archives it
            f.writelines(json.dumps(r) + "\n" for r in rows)
        return path

    # update 1 agrees although its timings differ; update 2 cannot be row 1 again
    slower = dict(row1, steps_per_s=row1["steps_per_s"] / 2, t_rollout=row1["t_rollout"] + 1)
    at2 = expected("at2.log.jsonl.gz", [slower, dict(row1, update=2)])
    with pytest.raises(collect.LogMismatch, match=r"update 2 of the generation differs from "
                                                  r".*at2.log.jsonl.gz \(.* expected"):
        collect.generate_learned(task, part, expect_log=at2, **RA)
    with open(partial / "state.pkl", "rb") as f:
        assert pickle.load(f)["update"] == 1  # stopped before update 2's checkpoint
    assert not part.exists()
    # the rows made before are checked on resume, before any new update is made (update 2's
    # row, past the checkpoint, was dropped by the resume)
    at1 = expected("at1.log.jsonl.gz", [dict(row1, multiplier=row1["multiplier"] + 1.0)])
    with pytest.raises(collect.LogMismatch, match=r"update 1 of .*multiplier"):
        collect.generate_learned(task, part, expect_log=at1, **RA)
    assert [r["update"] for r in collect.read_log(partial / "log.jsonl")] == [1]


def test_log_difference_leaves_out_wall_clock_fields_and_keys_one_side_lacks(tmp_path):
    new = dict(update=2, multiplier=0.5, log_std=-0.5, steps_per_s=10.0, t_rollout=1.0)
    old = dict(update=2, multiplier=0.5, steps_per_s=99.0)  # an older generator: no log_std
    assert collect.log_difference(new, old) == {}
    assert collect.log_difference(dict(new, multiplier=0.25), old) == {"multiplier": (0.25, 0.5)}
    with pytest.raises(DatasetError, match="no generation log .*results_v2/TASK archives them"):
        collect.read_log(tmp_path / "missing.log.jsonl.gz")


def test_generation_refuses_changes_a_second_writer_and_force_discards(tmp_path, monkeypatch):
    task = get_task("ReachAvoid")
    path = tmp_path / "g.hdf5"
    assert collect.generate_learned(task, path, stop_after=1, **RA) is None
    other = dict(RA, trajectories=13)
    with pytest.raises(DatasetError, match="other settings .*trajectories: 12 -> 13"):
        collect.generate_learned(task, path, **other)
    from r2pac_jax.io import lock_directory

    held = lock_directory(tmp_path / "g.hdf5.partial")
    try:
        with pytest.raises(DirectoryBusy):
            collect.generate_learned(task, path, **RA)
    finally:
        held.close()
    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path / "cache"))
    p = factory.dataset_path(task, 0, 12, "ppo-lagrangian", RA["env_steps"])
    assert p.name == f"ReachAvoid-generated-ppolag-v2-s0-n12-b{RA['env_steps']}.hdf5"
    kw = {k: v for k, v in RA.items() if k not in ("trajectories", "env_steps", "progress")}
    assert factory.generate_dataset(task, 12, 0, source="ppo-lagrangian",
                                    env_steps=RA["env_steps"], stop_after=1, **kw) is None
    state = p.parent / f"{p.name}.partial" / "state.pkl"
    assert state.exists()
    # --force with other settings: the old partial state is discarded, not refused
    kw2 = dict(kw, ppo=dict(RA["ppo"], epochs=1))
    assert factory.generate_dataset(task, 12, 0, source="ppo-lagrangian",
                                    env_steps=RA["env_steps"], force=True, stop_after=1,
                                    **kw2) is None
    spec = json.loads((p.parent / f"{p.name}.partial" / "spec.json").read_text())
    assert spec["ppo"]["epochs"] == 1
    assert factory.find_cached(task) is None  # train's automatic lookup takes scripted files


def test_not_enough_disk_is_refused_with_the_size(tmp_path, monkeypatch):
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10, 10, 1000))
    with pytest.raises(DatasetError, match=r"GiB free, generating 4105 CarGoal2 trajectories "
                                           r"needs about [0-9.]+ GiB"):
        collect.check_disk(get_task("CarGoal2"), collect.make_spec(get_task("CarGoal2")),
                           tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10, 0, 10 * 2**40))
    monkeypatch.setattr(collect, "_available_memory", lambda: 2**20)
    with pytest.raises(DatasetError, match=r"GiB of memory available, assembling 4105 CarGoal2 "
                                           r"trajectories needs about [0-9.]+ GiB"):
        collect.check_disk(get_task("CarGoal2"), collect.make_spec(get_task("CarGoal2")),
                           tmp_path)


def test_data_cli_errors(tmp_path, monkeypatch, capsys):
    from r2pac_jax.data.__main__ import main

    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path))
    with pytest.raises(SystemExit):
        main(["make", "--task", "ReachAvoid", "--source", "sac"])
    assert "invalid choice: 'sac'" in capsys.readouterr().err
    import dataclasses

    from r2pac_jax import tasks as registry

    # a registered task without an environment (constants only) has no source of either kind
    monkeypatch.setitem(registry.TASKS, "CarRun",
                        dataclasses.replace(get_task("CarRun"), env_factory=None))
    assert main(["make", "--task", "CarRun", "--source", "ppo-lagrangian"]) == 2
    assert "no data source for task 'CarRun'" in capsys.readouterr().err
    assert main(["make", "--task", "CarGoal2", "--source", "ppo-lagrangian", "--budget", "0"]) \
        == 2
    assert "--budget must be >= 1, got 0" in capsys.readouterr().err
    assert not list(tmp_path.glob("CarGoal2-*"))  # refused before any lock or partial state
    # the same refusal from Python, before any lock file
    from r2pac_jax.data.factory import FactoryError, generate_dataset

    for kw, fragment in ((dict(env_steps=-5), "--budget must be >= 1, got -5"),
                         (dict(checkpoint_every=0), "--checkpoint-every must be >= 1, got 0")):
        with pytest.raises(FactoryError, match=fragment):
            generate_dataset(get_task("CarGoal2"), source="ppo-lagrangian", **kw)
    assert not list(tmp_path.glob("CarGoal2-*"))
    # recipe values to try: KEY=VALUE, known keys, valid values, all before any lock file
    for bad, fragment in ((["stagger_starts"], "--ppo takes KEY=VALUE items, got 'stagger_starts'"),
                          (["lr_actor=1e-4"], "no recipe value 'lr_actor'"),
                          (["stagger_starts=2"], "stagger_starts must be true or false")):
        assert main(["make", "--task", "SwimmerVelocity", "--ppo", *bad]) == 2
        assert fragment in capsys.readouterr().err
    assert not list(tmp_path.glob("SwimmerVelocity-*"))
    # the log of a file to make again: missing, or asked of a source that keeps none
    assert main(["make", "--task", "CarGoal2", "--expect-log", str(tmp_path / "no.log.jsonl")]) \
        == 2
    assert "no generation log" in capsys.readouterr().err
    assert main(["make", "--task", "ReachAvoid", "--source", "scripted", "--expect-log",
                 str(tmp_path / "no.log.jsonl")]) == 2
    assert "--expect-log applies to a ppo-lagrangian generation" in capsys.readouterr().err
    assert main(["make", "--task", "CarGoal2", "--stop-after", "0"]) == 2
    assert "--stop-after must be >= 1, got 0" in capsys.readouterr().err
    assert not list(tmp_path.glob("CarGoal2-*")) and not list(tmp_path.glob("ReachAvoid-*"))


def test_a_trial_recipe_file_is_named_as_such_and_never_found_as_the_recipe_file(tmp_path,
                                                                                  monkeypatch):
    from r2pac_jax.data import factory

    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path))
    t = get_task("SwimmerVelocity")
    recipe = factory.learned_path(t)
    trial = factory.dataset_path(t, 0, t.collection.trajectories, "ppo-lagrangian",
                                 trial={"stagger_starts": True})
    assert trial.name == recipe.name.replace(".hdf5", "-ppo-stagger_starts_true.hdf5")
    for p in (trial, factory.card_path(trial)):
        p.write_text("{}")
    assert factory.find_learned(t) is None  # a trial stands in for no recipe file
    for p in (recipe, factory.card_path(recipe)):
        p.write_text("{}")
    assert factory.find_learned(t) == recipe
    # a trial's values reach the generator beside the caller's own recipe values
    from r2pac_jax.data.factory import collect

    seen = {}
    monkeypatch.setattr(collect, "generate_learned",
                        lambda task, path, *a, **kw: seen.update(path=path, **kw))
    factory.generate_dataset(t, source="ppo-lagrangian", ppo={"num_envs": 7},
                             trial={"stagger_starts": True}, force=True)
    assert seen["path"].name == trial.name
    assert seen["ppo"] == {"num_envs": 7, "stagger_starts": True}


@pytest.mark.slow
def test_generation_on_mjx():
    """The MJX path (minutes to compile on a CPU): a velocity task through the jitted rollout."""
    import tempfile
    from pathlib import Path

    task = get_task("HopperVelocity")
    d = Path(tempfile.mkdtemp())
    kw = dict(HOP, physics="mjx", trajectories=1, env_steps=2 * 40 * 2,
              ppo=dict(num_envs=2, rollout_len=40, hidden=(16,), minibatches=1, epochs=1))
    p = collect.generate_learned(task, d / "hop.hdf5", **kw)
    card = json.loads(factory.card_path(p).read_text())
    assert card["physics"] == "mjx" and card["generation"]["updates"] == 2


def test_train_prefers_learned_data_and_warns_on_scripted(tmp_path, monkeypatch):
    from r2pac_jax.data import load_task_dataset
    from r2pac_jax.data.dsrl import validate, write_dsrl

    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("DSRL_DATASET_DIR", str(tmp_path / "none"))
    task = get_task("HopperVelocity")
    rng = np.random.default_rng(0)
    n = 20
    obs = rng.normal(size=(n + 1, task.obs_dim)).astype(np.float32)
    arrays = dict(observations=obs[:-1], next_observations=obs[1:],
                  actions=np.zeros((n, task.act_dim), np.float32),
                  rewards=np.ones(n, np.float32), costs=np.zeros(n, np.float32),
                  terminals=np.zeros(n, bool), timeouts=np.arange(n) == n - 1)
    ds = validate(arrays, "x")
    scripted = factory.dataset_path(task, 0, factory.default_trajectories(task))
    write_dsrl(scripted, ds)
    factory.card_path(scripted).write_text("{}")
    said = []
    got = load_task_dataset(task, announce=said.append)
    assert got.source == str(scripted)
    assert any("warning: " in m and "scripted (data v1)" in m and "--source ppo-lagrangian" in m
               for m in said)
    learned = factory.dataset_path(task, 0, task.collection.trajectories, "ppo-lagrangian")
    assert learned.name == "HopperVelocity-generated-ppolag-v2-s0-n2240.hdf5"
    write_dsrl(learned, ds)
    factory.card_path(learned).write_text("{}")
    said.clear()
    assert load_task_dataset(task, announce=said.append).source == str(learned)
    assert not any("warning" in m for m in said)


def test_a_fresh_machine_makes_learned_data_with_its_eta(tmp_path, monkeypatch, capfd):
    """No data at all for a MuJoCo task: train's loader starts the learned generation (here at a
    tiny registered budget), says how long DSRL's size takes and how to resume, then runs the
    fast checks on the file."""
    import dataclasses

    from r2pac_jax import tasks
    from r2pac_jax.data import load_task_dataset
    from r2pac_jax.data.checks import checks_path

    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("DSRL_DATASET_DIR", str(tmp_path / "none"))
    hop = get_task("HopperVelocity")
    tiny = dataclasses.replace(hop.collection, epochs=2, epoch_start=0, epoch_end=1,
                               steps_per_epoch=400, trajectories=8,
                               ppo=(("num_envs", 4), ("rollout_len", 100), ("hidden", (16,)),
                                    ("minibatches", 2), ("epochs", 1)))
    monkeypatch.setitem(tasks.TASKS, "HopperVelocity", dataclasses.replace(hop, collection=tiny))
    task = get_task("HopperVelocity")
    said = []
    capfd.readouterr()
    ds = load_task_dataset(task, announce=said.append, progress=False)
    assert "PPO-Lagrangian" not in capfd.readouterr().err  # --no-progress: no generation bar
    assert "generating DSRL's learned-behaviour data (8 trajectories from 800 env steps" in said[0]
    assert "rerun the same command to continue" in said[0] and "--source ppo-lagrangian" in said[0]
    assert ds.source.endswith("HopperVelocity-generated-ppolag-v2-s0-n8.hdf5")
    assert checks_path(ds.source).exists() and "coverage checks" in said[-1]
    said.clear()
    assert load_task_dataset(task, announce=said.append).source == ds.source  # found next time


def test_budget_too_small_for_the_last_limit_warns_before_starting(tmp_path):
    from r2pac_jax.data.factory import collect
    from r2pac_jax.tasks import get_task

    t = get_task("ReachAvoid")
    assert collect.schedule_warning(t, collect.make_spec(t)) is None  # DSRL-style budget
    lines = []
    out = collect.generate_learned(t, tmp_path / "ra.hdf5", env_steps=50_000, stop_after=0,
                                   log=lines.append, progress=False)
    assert out is None  # stopped before the first update: nothing made
    warn = [ln for ln in lines if ln.startswith("warning: ")]
    assert len(warn) == 1 and "leaves 1,080 steps under it" in warn[0] and "--budget" in warn[0]


def test_unknown_recipe_value_names_the_key():
    from r2pac_jax.data.dsrl import DatasetError
    from r2pac_jax.data.factory import collect
    from r2pac_jax.tasks import get_task

    with pytest.raises(DatasetError, match=r"no recipe value 'lr_actor'; known: clip, "):
        collect.make_spec(get_task("CarGoal1"), ppo={"lr_actor": 1e-4})


def test_mean_squash_recipe_value():
    """The unsquashed mean (a per-task recipe value) reaches past the action bounds where the
    tanh saturates; the default stays DSRL's and is left out of spec.json and the card, so
    every earlier generation resumes and every pinned card reads the same."""
    import jax
    import jax.numpy as jnp

    from r2pac_jax.data.dsrl import DatasetError
    from r2pac_jax.data.factory import collect
    from r2pac_jax.data.factory import ppo_lagrangian as pl
    from r2pac_jax.tasks import get_task

    t = get_task("SwimmerVelocity")
    assert "mean_squash" not in collect.make_spec(t).to_dict()["ppo"]
    spec = collect.make_spec(t, ppo={"mean_squash": "none"})
    assert spec.to_dict()["ppo"]["mean_squash"] == "none"
    with pytest.raises(DatasetError, match="mean_squash must be one of tanh, none"):
        collect.make_spec(t, ppo={"mean_squash": "softsign"})
    obs = 50.0 * jnp.ones((4, t.obs_dim))
    for squash, beyond in (("tanh", False), ("none", True)):
        actor = pl.Actor(t.act_dim, (8,), -0.5, squash)
        params = actor.init(jax.random.PRNGKey(0), obs[0])
        # a saturating policy: every bias at 3 (the output's pre-activation about 3)
        params = jax.tree_util.tree_map_with_path(
            lambda path, x: jnp.full_like(x, 3.0) if "bias" in jax.tree_util.keystr(path) else x,
            params)
        mean, _ = actor.apply(params, obs)
        assert bool((jnp.abs(mean) > 1.0).any()) == beyond


def test_assemble_fills_the_file_episode_by_episode_as_a_concatenation_would(tmp_path):
    """The pool's episodes, in index order, into arrays of the final size (one copy in memory);
    a pool record whose length disagrees with its episode file is refused."""
    rng = np.random.default_rng(0)
    (tmp_path / "episodes").mkdir()
    pool, eps = [], []
    for i, n in enumerate((5, 3, 7)):
        ep = dict(observations=rng.normal(size=(n, 3)).astype(np.float32),
                  next_observations=rng.normal(size=(n, 3)).astype(np.float32),
                  actions=rng.normal(size=(n, 2)).astype(np.float32),
                  rewards=rng.normal(size=n).astype(np.float32),
                  costs=rng.normal(size=n).astype(np.float32),
                  terminals=np.arange(n) == n - 1, timeouts=np.zeros(n, bool))
        np.savez(tmp_path / "episodes" / f"ep-{i:07d}.npz", **ep)
        pool.append((i, float(i), 0.0, n))
        eps.append(ep)
    gen = collect.Generation.__new__(collect.Generation)  # assemble reads spec and dir only
    gen.spec = collect.make_spec(get_task("ReachAvoid"), trajectories=10, env_steps=16 * 80 * 4)
    gen.dir = tmp_path
    arrays, info = gen.assemble(pool[::-1])  # the pool's order does not matter: index order
    assert info["kept"] == 3
    for k in collect.EPISODE_KEYS:
        want = np.concatenate([e[k] for e in eps])
        assert arrays[k].dtype == (bool if k in ("terminals", "timeouts") else np.float32)
        np.testing.assert_array_equal(arrays[k], want, err_msg=k)
    with pytest.raises(DatasetError, match="episode 1 holds 3 steps, its pool record 4"):
        gen.assemble([pool[0], (1, 1.0, 0.0, 4), pool[2]])


# the phase-locked contrast (the default, every pin's) is slow: the default suite is near 10 min
@pytest.mark.parametrize("stagger", [pytest.param(False, marks=pytest.mark.slow), True])
def test_stagger_starts_spreads_episode_phases_and_keeps_only_whole_episodes(stagger, tmp_path):
    """stagger_starts (a recipe value, default off and left out of the card): env j's first
    episode starts at step j x 1000 / 4, so from then on one episode ends in every update of 250
    steps instead of all four in one update of four; the shortened first ones are not pooled."""
    import pickle

    from r2pac_jax.data.dsrl import DatasetError
    from r2pac_jax.data.factory import collect

    t = get_task("SwimmerVelocity")  # 1,000-step episodes without terminals, C MuJoCo
    assert "stagger_starts" not in collect.make_spec(t).to_dict()["ppo"]
    with pytest.raises(DatasetError, match="stagger_starts must be true or false"):
        collect.make_spec(t, ppo={"stagger_starts": "yes"})
    ppo = dict(num_envs=4, rollout_len=250, hidden=(8,), minibatches=2, epochs=1,
               stagger_starts=stagger)
    spec = collect.make_spec(t, trajectories=50, env_steps=8 * 1000, ppo=ppo, physics="mujoco",
                             checkpoint_every=1)
    assert spec.to_dict()["ppo"].get("stagger_starts", False) is stagger
    gen = collect.Generation(t, spec, tmp_path / "g", log=lambda m: None, progress=False)
    gen.dir.mkdir(parents=True)
    (gen.dir / "episodes").mkdir()
    res = gen.run()  # all 8 updates
    assert res["updates"] == 8 and res["finished_episodes"] == (5 if stagger else 8)
    log = [json.loads(ln) for ln in (gen.dir / "log.jsonl").read_text().splitlines()]
    finished = [r["finished"] for r in log]
    if stagger:  # envs 3, 2, 1 cut short in updates 1-3 (not counted), then one a update
        assert finished == [0, 0, 0, 1, 1, 1, 1, 1]
    else:  # all four together, every fourth update
        assert finished == [0, 0, 0, 4, 0, 0, 0, 4]
    state = pickle.loads((gen.dir / "state.pkl").read_bytes())
    lengths = [e[3] for e in state["pool"]]
    assert lengths and all(n == t.episode_len for n in lengths)  # whole episodes only
    assert len(lengths) <= sum(finished)


def test_make_command_reads_back_the_budget_dataset_path_writes(tmp_path, monkeypatch):
    """The inverse of the file's name: a file at another budget is made again at that budget,
    one at DSRL's with none named."""
    monkeypatch.setenv("R2PAC_DATA_DIR", str(tmp_path))
    t = get_task("CarGoal2")
    cut = factory.dataset_path(t, 0, 4105, "ppo-lagrangian", 5_000_000).name
    full = factory.learned_path(t).name
    assert factory.budget_in_name(cut) == 5_000_000 and factory.budget_in_name(full) is None
    assert factory.make_command("CarGoal2", cut) == [
        "-m", "r2pac_jax.data", "make", "--task", "CarGoal2", "--source", "ppo-lagrangian",
        "--budget", "5000000"]
    assert "--budget" not in factory.make_command("CarGoal2", full)
