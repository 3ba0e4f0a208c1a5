"""The task registry and its families: one record per task, simulators imported only when an
environment is made."""
import subprocess
import sys

import pytest

from r2pac_jax import tasks
from r2pac_jax.tasks import bullet, demo, navigation, velocity


def test_each_family_registers_its_own_tasks_once():
    fams = {"demo": demo, "navigation": navigation, "velocity": velocity, "bullet": bullet}
    counts = {f: 0 for f in fams}
    for t in tasks.TASKS.values():
        assert t.env_factory is fams[t.family].make_env, t.name
        counts[t.family] += 1
    assert counts == {"demo": 1, "navigation": 12, "velocity": 5, "bullet": 8}
    # a task with DSRL's recipe keeps its trajectory count from it
    assert all(t.dsrl_trajectories == t.collection.trajectories for t in tasks.TASKS.values())
    with pytest.raises(ValueError, match="already registered"):
        tasks.register(tasks.get_task("BallRun"))


def test_reading_the_tasks_imports_no_simulator():
    code = ("import sys, r2pac_jax.tasks as t; t.get_task('CarGoal2').obs_dim; "
            "print(sorted(m for m in ('mujoco', 'pybullet', 'mujoco.mjx') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "[]", out.stderr[-2000:]


def test_a_factory_given_as_module_function_is_imported_on_first_use(monkeypatch):
    monkeypatch.setitem(tasks.TASKS, "ReachAvoid", tasks.get_task("ReachAvoid"))
    tasks.set_env_factory("ReachAvoid", "r2pac_jax.envs.reach_avoid:make_env")
    env = tasks.get_task("ReachAvoid").make_env()
    assert tasks.get_task("ReachAvoid").env_factory.target == "r2pac_jax.envs.reach_avoid:make_env"
    assert env is not None
