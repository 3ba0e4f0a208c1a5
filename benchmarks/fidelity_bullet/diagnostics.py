"""The diagnostic figures behind the MuJoCo re-creations' design notes (mjcf.py, FIDELITY.md) and
the bullet backend's machine-independence fix (tasks.py, robots.py).

    python benchmarks/fidelity_bullet/diagnostics.py

Prints:
- how often numpy's arctan2 differs from the C library's (math.atan2) on this machine's numpy
  build (10,000 random arguments): the reason the bullet backend uses math.atan2;
- the Car's joint speeds in the original's engine after 30 steps of full throttle: the
  differential's side gears against what its gear constraints ask (opposite speeds), the front
  ring against its motor's 40 rad/s target;
- the height at which a lifting Drone's ground contact ends in the original's engine (DroneRun,
  a gentle climb): the contact distance the MuJoCo adapter uses;
- MJX's plane-cylinder distance for a Drone rotor disc well above the plane, against C MuJoCo's:
  why the rotor discs do not collide in the MuJoCo models.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from r2pac_jax.envs.bullet import make_env  # noqa: E402
from r2pac_jax.tasks import get_task  # noqa: E402


def arctan2_mismatch(n: int = 10_000) -> float:
    rng = np.random.default_rng(0)
    y, x = rng.normal(size=(2, n))
    return float(np.mean([np.arctan2(a, b) != math.atan2(a, b) for a, b in zip(y, x)]))


def car_gears(steps: int = 30) -> dict:
    env = make_env(get_task("CarRun"), "bullet")
    s = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 1))
    for _ in range(steps):
        s = env.step_batch(s, np.array([[1.0, 0.0]], np.float32))
    w = env._worlds[int(s.physics["world"][0])]
    v = {j: w.pb.getJointState(w.body, j, physicsClientId=w.cid)[1] for j in (8, 11, 13, 15)}
    return dict(rear_ring=v[8], rear_side_a=v[11], rear_side_b=v[13], front_ring=v[15])


def drone_liftoff() -> tuple:
    """(last height above rest with a ground contact, first without) in DroneRun's climb."""
    env = make_env(get_task("DroneRun"), "bullet")
    s = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), 1))
    rest = float(s.physics["pos"][0][2])
    rng = np.random.default_rng(0)
    last_on = None
    for _ in range(40):
        s = env.step_batch(s, rng.uniform(-1, 1, (1, 4)).astype(np.float32))
        h = float(s.physics["pos"][0][2]) - rest
        if s.physics["ground"][0][0]:
            last_on = h
        elif last_on is not None:
            return last_on, h
    return last_on, None


def mjx_rotor_distance() -> tuple:
    """(C MuJoCo's, MJX's) smallest contact distance of a rotor disc, 18.5 cm above the plane,
    with the rotors colliding (the models' rotors do not)."""
    import mujoco
    from mujoco import mjx

    from r2pac_jax.envs.bullet import mjcf, tasks

    task = tasks.make_task(get_task("DroneRun"))
    xml = mjcf.model_xml(task).replace('contype="0"/></body>', 'contype="1"/></body>')
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:] = [0.0089, -0.0075, 0.17, 1, 0, 0, 0, -0.0153, -0.0621, -0.0975, -0.0417]
    mujoco.mj_forward(m, d)
    rotor = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"rotor_{i}") for i in range(4)]
    c_min = min([d.contact.dist[i] for i in range(d.ncon)
                 if {d.contact.geom1[i], d.contact.geom2[i]} & set(rotor)] or [np.inf])
    dd = jax.jit(mjx.forward)(mjx.put_model(m), mjx.put_data(m, d))
    c = dd._impl.contact if hasattr(dd, "_impl") else dd.contact
    geoms, dist = np.asarray(c.geom), np.asarray(c.dist)
    mjx_min = min(float(x) for g, x in zip(geoms, dist) if set(g.tolist()) & set(rotor))
    return float(c_min), mjx_min


def main():
    print(f"numpy arctan2 != math.atan2 for {100 * arctan2_mismatch():.1f}% of arguments")
    g = car_gears()
    print("Car after 1 s of full throttle (rad/s): " + ", ".join(f"{k} {v:.1f}"
                                                                 for k, v in g.items()))
    on, off = drone_liftoff()
    print(f"Drone ground contact reported at {1000 * on:.2f} mm above rest, gone at "
          f"{1000 * off:.2f} mm" if off is not None else "Drone did not lift off")
    c, j = mjx_rotor_distance()
    print(f"rotor disc contact distance: C MuJoCo {c:.4f} (no contact if inf), MJX {j:.4f} m")


if __name__ == "__main__":
    main()
