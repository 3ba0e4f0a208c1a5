"""MJX physics of the Bullet Circle worlds with and without the contact cap, in one run.

    python benchmarks/mjx_contact_cap.py [--tasks BallCircle,DroneCircle,CarCircle,AntCircle]
        [--batch 100] [--substeps 20] [--out benchmarks/results/mjx_contact_cap.jsonl]

The Circle worlds cap MJX's static contact slots (`mjcf.CIRCLE_CONTACTS`, MJX's
`max_contact_points`) instead of carrying one set per robot geom x wall plane. This times
`mjx.step` (one physics sub-step, no task code, no policy) vmapped over `--batch` copies of the
model's initial state under random controls, `--substeps` sub-steps per jitted call, median of 3
calls after a compile-and-run call, for the model as built ("capped") and the same model with
the cap removed ("uncapped"); one JSON line per (task, variant), with env_speed.py's machine
fields, is printed and appended to --out.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from env_speed import emit  # noqa: E402


def physics_rate(xml: str, batch: int, substeps: int) -> dict:
    import mujoco
    from mujoco import mjx

    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    mx, dx = mjx.put_model(m), mjx.put_data(m, d)
    ctrl = jax.random.uniform(jax.random.PRNGKey(0), (batch, substeps, m.nu), minval=-1, maxval=1)
    d0 = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), dx)

    def roll(d, c):
        return jax.lax.scan(lambda d, u: (mjx.step(mx, d.replace(ctrl=u)), None), d, c)[0]

    f = jax.jit(jax.vmap(roll))
    t0 = time.perf_counter()
    jax.block_until_ready(f(d0, ctrl).qpos)
    first = time.perf_counter() - t0
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(f(d0, ctrl).qpos)
        times.append(time.perf_counter() - t0)
    return dict(contact_slots=int(dx._impl.ncon), compile_and_run_s=round(first, 2),
                substeps_per_s=round(batch * substeps / float(np.median(times)), 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tasks", default="BallCircle,DroneCircle,CarCircle,AntCircle")
    ap.add_argument("--batch", type=int, default=100)
    ap.add_argument("--substeps", type=int, default=20)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/mjx_contact_cap.jsonl"))
    args = ap.parse_args()
    from r2pac_jax.envs.bullet import mjcf
    from r2pac_jax.envs.bullet.tasks import make_task
    from r2pac_jax.tasks import get_task

    args.out.parent.mkdir(parents=True, exist_ok=True)
    for name in args.tasks.split(","):
        task = make_task(get_task(name))
        if mjcf.world_contact_slots(task) is None:
            raise SystemExit(f"{name}: its model has no contact cap (only the Circle worlds do)")
        capped, uncapped = mjcf.model_xml(task), mjcf.model_xml(task, contact_slots=None)
        for variant, xml in (("uncapped", uncapped), ("capped", capped)):
            emit(dict(kind="mjx_contact_cap", task=name, variant=variant, batch=args.batch,
                      substeps=args.substeps, **physics_rate(xml, args.batch, args.substeps)),
                 str(args.out))


if __name__ == "__main__":
    main()
