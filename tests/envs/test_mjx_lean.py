"""The compile-lean MJX step (RK4 as one rolled scan) and reset pass, on a tiny model: they must
compute what MuJoCo computes (C MuJoCo for the default suite; MJX's own step under `slow`)."""
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from r2pac_jax.envs import mjx_lean

# A free body with a damped, actuated hinge child: exercises the quaternion integration of a free
# joint, hinge kinematics and the RK4 sums; no contacts, so that MJX compiles it quickly.
XML = """
<mujoco>
  <option integrator="RK4" timestep="0.01"><flag contact="disable"/></option>
  <worldbody>
    <body pos="0 0 1">
      <freejoint/>
      <geom type="capsule" size="0.05" fromto="0 0 0 0.3 0 0"/>
      <body pos="0.3 0 0">
        <joint name="h" type="hinge" axis="0 1 0" damping="0.5"/>
        <geom type="capsule" size="0.04" fromto="0 0 0 0 0 -0.3"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="h" gear="2"/></actuator>
</mujoco>"""
QVEL = np.array([0.1, -0.2, 0.3, 1.0, -0.5, 0.7, 2.0])
STEPS = 20


def _start():
    m = mujoco.MjModel.from_xml_string(XML)
    mx = mjx.put_model(m)
    d = mjx.make_data(mx).replace(qvel=jnp.asarray(QVEL, jnp.float32),
                                  ctrl=jnp.array([0.7], jnp.float32))
    return m, mx, d


def _run(mx, d, step):
    return jax.jit(lambda d: jax.lax.fori_loop(0, STEPS, lambda _, d: step(mx, d), d))(d)


def test_rolled_rk4_matches_c_mujoco():
    m, mx, d = _start()
    out = _run(mx, d, mjx_lean.step)
    dc = mujoco.MjData(m)
    dc.qvel[:], dc.ctrl[:] = QVEL, 0.7
    mujoco.mj_step(m, dc, nstep=STEPS)
    # float32 MJX against float64 C MuJoCo: agreement to rounding
    np.testing.assert_allclose(np.asarray(out.qpos), dc.qpos, atol=2e-5)
    np.testing.assert_allclose(np.asarray(out.qvel), dc.qvel, atol=2e-5)
    # derived fields as mj_step leaves them (the last Runge-Kutta stage's kinematics)
    np.testing.assert_allclose(np.asarray(out.xpos), dc.xpos, atol=2e-5)
    assert float(out.time) == pytest.approx(STEPS * 0.01, abs=1e-5)


def test_reset_pass_runs_only_what_the_view_needs():
    m, mx, d = _start()
    d = d.replace(qpos=d.qpos.at[3:7].set(jnp.array([2.0, 0.0, 0.0, 0.0])))  # unnormalised
    assert mjx_lean.reset_pass(mx, d, ("qpos", "qvel")) is d  # state fields: nothing to run
    kin = jax.jit(lambda d: mjx_lean.reset_pass(mx, d, ("qpos", "xpos")))(d)
    dc = mujoco.MjData(m)
    mujoco.mj_kinematics(m, dc)
    np.testing.assert_allclose(np.asarray(kin.xpos), dc.xpos, atol=1e-6)
    np.testing.assert_allclose(np.asarray(kin.qpos[3:7]), [1, 0, 0, 0])  # normalised, as MJX's
    assert float(jnp.abs(kin.qacc).max()) == 0.0  # no dynamics were run


@pytest.mark.slow
def test_rolled_rk4_matches_mjx_step():
    """Against MJX's own (unrolled) RK4: the same arithmetic, so equal to float rounding."""
    _, mx, d = _start()
    a, b = _run(mx, d, mjx_lean.step), _run(mx, d, mjx.step)
    for f in ("qpos", "qvel", "xpos", "qacc_warmstart"):
        np.testing.assert_allclose(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)),
                                   atol=1e-6, err_msg=f)
    # a non-RK4 model falls through to mjx.step
    m = mujoco.MjModel.from_xml_string(XML.replace('integrator="RK4"', 'integrator="Euler"'))
    mx = mjx.put_model(m)
    e1, e2 = _run(mx, d, mjx_lean.step), _run(mx, d, mjx.step)
    np.testing.assert_array_equal(np.asarray(e1.qpos), np.asarray(e2.qpos))
