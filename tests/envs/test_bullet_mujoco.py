"""The MuJoCo re-creations of the Bullet tasks (`--physics mujoco` / `mjx`): models built from
pybullet's own numbers, the rules' view of MuJoCo's state, resets, the measured gap to the
original's engine staying where benchmarks/FIDELITY.md puts it, and bad input."""
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from r2pac_jax.envs.base import BackendUnavailableError
from r2pac_jax.envs.bullet import make_env, mjcf
from r2pac_jax.envs.bullet.mujoco_env import euler_from_quat, quat_from_euler
from r2pac_jax.tasks import get_task

pb = pytest.importorskip("pybullet")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks" / "fidelity_bullet"))
import mujoco_gap  # noqa: E402


def _pybullet_bodies(robot_name):
    """[(mass, sorted diag inertia)] of the original's moving links with mass, as loaded."""
    from r2pac_jax.envs.bullet.robots import ROBOTS

    c = pb.connect(pb.DIRECT)
    try:
        body = ROBOTS[robot_name].load(pb, c)
        out = []
        for j in range(-1, pb.getNumJoints(body, physicsClientId=c)):
            mass, _, inertia = pb.getDynamicsInfo(body, j, physicsClientId=c)[:3]
            if mass > 1e-3:
                out.append((mass, tuple(sorted(inertia))))
        return sorted(out)
    finally:
        pb.disconnect(c)


@pytest.mark.parametrize("task", ["BallRun", "AntRun", "DroneRun"])
def test_models_carry_pybullets_masses_and_inertias(task):
    """Every massive link of the original has a MuJoCo body (or a welded pair of them, which
    pybullet splits into a massless joint link and a fixed child) with its mass and inertia."""
    m = make_env(get_task(task), "mujoco").mj_model
    ours = sorted((float(m.body_mass[b]), tuple(sorted(m.body_inertia[b])))
                  for b in range(1, m.nbody) if m.body_mass[b] > 1e-3)
    theirs = _pybullet_bodies(get_task(task).name.replace("Run", ""))
    assert len(ours) == len(theirs)
    for (ma, ia), (mb, ib) in zip(ours, theirs):
        assert ma == pytest.approx(mb, rel=1e-6)
        np.testing.assert_allclose(ia, ib, rtol=1e-6)


def test_euler_helpers_match_pybullet():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        rpy = np.asarray(euler_from_quat(jnp.asarray(q)))
        np.testing.assert_allclose(rpy, pb.getEulerFromQuaternion(q), atol=2e-6)
        np.testing.assert_allclose(np.asarray(quat_from_euler(jnp.asarray(rpy))),
                                   pb.getQuaternionFromEuler(rpy), atol=2e-6)


@pytest.mark.parametrize("task", ["BallCircle", "DroneRun"])
def test_reset_starts_where_the_bullet_backend_starts(task):
    """The same keys give the same sampled start on both engines (the shared reset law); after
    the settling step the robot is at rest on the ground in both."""
    keys = jax.random.split(jax.random.PRNGKey(7), 3)
    a = make_env(get_task(task), "bullet").reset_batch(keys)
    b = make_env(get_task(task), "mujoco").reset_batch(keys)
    np.testing.assert_allclose(b.obs[:, :2], a.obs[:, :2], atol=1e-4)  # 0.1 xy
    assert (b.t == 0).all() and (b.reward == 0).all() and (b.cost == 0).all()


def test_same_keys_same_episodes():
    env = make_env(get_task("AntRun"), "mujoco")
    keys = jax.random.split(jax.random.PRNGKey(1), 2)
    acts = np.random.default_rng(0).uniform(-1, 1, (5, 2, 8)).astype(np.float32)
    runs = []
    for _ in range(2):
        s = env.reset_batch(keys)
        for a in acts:
            s = env.step_batch(s, a)
        runs.append((s.obs, s.reward))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])


# the gap measured by mujoco_gap.py (benchmarks/FIDELITY.md), with headroom: one step from the
# original's states, median over states of the largest observation / reward difference
GAP = {"BallRun": (0.01, 0.05), "DroneRun": (0.02, 0.01), "AntRun": (0.2, 0.15),
       "CarRun": (0.08, 0.06)}


@pytest.mark.parametrize("task", sorted(GAP))
def test_one_step_gap_stays_where_measured(task):
    r = mujoco_gap.one_step(task, episodes=2, seed=0)
    obs, reward = GAP[task]
    assert r["obs_median"] < obs and r["reward_median"] < reward, r
    assert r["cost_disagree"] < 0.02, r


def test_car_model_carries_pybullets_numbers():
    """The Car's chassis and wheels carry pybullet's masses and inertias; the differentials'
    parts become point masses, so the total mass is the original's."""
    m = make_env(get_task("CarRun"), "mujoco").mj_model
    theirs = _pybullet_bodies("Car")
    assert m.body_subtreemass[1] == pytest.approx(sum(ma for ma, _ in theirs), rel=1e-9)
    chassis = int(m.body("robot").id)
    ma, ia = float(m.body_mass[chassis]), sorted(m.body_inertia[chassis])
    assert any(ma == pytest.approx(mb) and np.allclose(ia, ib, rtol=1e-9) for mb, ib in theirs)
    for name in ("rear_left", "rear_right", "front_left", "front_right"):
        b = int(m.body(name).id)
        assert m.body_mass[b] == pytest.approx(0.34055)
        np.testing.assert_allclose(sorted(m.body_inertia[b]), sorted(mjcf.CAR_WHEEL["inertia"]))


def test_bad_physics():
    with pytest.raises(BackendUnavailableError, match="auto, bullet, mjx or mujoco"):
        make_env(get_task("BallRun"), "brax")
    assert all(mjcf.has_model(r) for r in ("Ball", "Car", "Drone", "Ant"))


@pytest.mark.slow
# control steps compared: the Car's wheel contacts and the Ant's feet amplify float32's
# rounding (MJX) against float64's (C MuJoCo) to visible differences after ~5 steps
@pytest.mark.parametrize("task,steps", [("BallRun", 10), ("DroneRun", 10), ("CarRun", 4)])
def test_mjx_matches_c_mujoco(task, steps):
    """The MJX backend runs the same model as C MuJoCo (float32 against float64)."""
    mjx_env, c_env = make_env(get_task(task), "mjx"), make_env(get_task(task), "mujoco")
    keys = jax.random.split(jax.random.PRNGKey(3), 4)
    s, s2 = mjx_env.reset_batch(keys), c_env.reset_batch(keys)
    rng = np.random.default_rng(0)
    for _ in range(steps):
        a = rng.uniform(-1, 1, (4, mjx_env.act_dim)).astype(np.float32)
        s, s2 = mjx_env.step_batch(s, jnp.asarray(a)), c_env.step_batch(s2, a)
    np.testing.assert_allclose(np.asarray(s.obs), s2.obs, atol=1e-3)
    np.testing.assert_allclose(np.asarray(s.reward), s2.reward, atol=1e-3)


def _mjx_contact_slots(xml: str) -> int:
    import mujoco
    from mujoco import mjx

    m = mujoco.MjModel.from_xml_string(xml)
    return int(mjx.put_data(m, mujoco.MjData(m))._impl.ncon)


@pytest.mark.parametrize("robot", ["Ball", "Car", "Drone", "Ant"])
def test_circle_worlds_cap_mjx_contact_slots(robot):
    """MJX's static contact slots: the Run world's count is what RUN_CONTACTS says, and the
    Circle world carries that plus WALL_SLOTS instead of one set per robot geom x wall."""
    run = mjcf.model_xml(mjcf_task(f"{robot}Run"))
    circle = mjcf.model_xml(mjcf_task(f"{robot}Circle"))
    assert "max_contact_points" not in run
    assert _mjx_contact_slots(run) == mjcf.RUN_CONTACTS[robot]
    assert _mjx_contact_slots(circle) == mjcf.CIRCLE_CONTACTS[robot]
    uncapped = mjcf.model_xml(mjcf_task(f"{robot}Circle"), contact_slots=None)
    assert "max_contact_points" not in uncapped
    assert _mjx_contact_slots(uncapped) > 2 * mjcf.CIRCLE_CONTACTS[robot]
    # a cap caps: never more slots than the world has contacts to fill
    capped_run = mjcf.model_xml(mjcf_task(f"{robot}Run"), contact_slots=np.int64(2))
    assert _mjx_contact_slots(capped_run) == min(2, mjcf.RUN_CONTACTS[robot])


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, "none", np.array([3])])
def test_model_xml_refuses_a_bad_contact_cap(bad):
    with pytest.raises(ValueError, match="contact_slots"):
        mjcf.model_xml(mjcf_task("BallCircle"), contact_slots=bad)


def mjcf_task(name):
    from r2pac_jax.envs.bullet.tasks import make_task

    return make_task(get_task(name))


def _ball_into_a_corner(slots: int) -> float:
    """BallCircle's ball pushed into a corner of the octagon until the floor and both walls hold
    it: the largest |qpos| gap over 1 s between MJX with `slots` contact slots and C MuJoCo,
    which ignores the cap and holds every contact."""
    import mujoco
    from mujoco import mjx

    m = mjcf.load_model(mjcf_task("BallCircle"), contact_slots=slots)
    d = mujoco.MjData(m)
    corner = np.array([np.cos(np.pi / 8), np.sin(np.pi / 8)])  # between the walls at 0 and 45 deg
    d.qpos[:3] = [*(11.6 * corner), 0.5]  # the ball's centre meets both walls 12.34 m out
    d.qvel[:2] = 2.0 * corner
    ball = m.geom_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "ball")]
    d.xfrc_applied[ball, :2] = 3.5 * corner  # the Ball's full push, into the corner
    mujoco.mj_forward(m, d)
    mx, dx = mjx.put_model(m), mjx.put_data(m, d)
    step = jax.jit(lambda d: mjx.step(mx, d))
    gap, most = 0.0, 0
    for _ in range(60):
        mujoco.mj_step(m, d)
        dx = step(dx)
        most = max(most, d.ncon)  # margin 0: every listed contact is active
        gap = max(gap, float(np.max(np.abs(np.asarray(dx.qpos[:3]) - d.qpos[:3]))))
    assert most == 3 and np.linalg.norm(d.qpos[:2]) < 12.4  # floor and both walls at once
    return gap


@pytest.mark.slow
def test_capped_mjx_contacts_hold_a_ball_in_a_corner():
    """The Ball's 3 slots are enough for its worst case, and one fewer would not be."""
    assert mjcf.CIRCLE_CONTACTS["Ball"] == 3
    # measured: 1.8e-6 with 3 slots (what every slot gives), 1.9e-3 with 2, 0.15 with 1
    assert _ball_into_a_corner(3) < 1e-4
    assert _ball_into_a_corner(2) > 5e-4


def test_contact_cap_benchmark_refuses_a_world_without_a_cap(tmp_path):
    import subprocess
    import sys

    script = Path(__file__).resolve().parents[2] / "benchmarks" / "mjx_contact_cap.py"
    r = subprocess.run([sys.executable, str(script), "--tasks", "BallRun",
                        "--out", str(tmp_path / "x.jsonl")], capture_output=True, text=True)
    assert r.returncode != 0
    assert "BallRun: its model has no contact cap (only the Circle worlds do)" in r.stderr
    assert not (tmp_path / "x.jsonl").exists()
