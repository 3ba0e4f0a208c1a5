"""Why MJX and C MuJoCo disagree on Ant at contacts (evidence for benchmarks/FIDELITY.md).

    python benchmarks/fidelity/mjx_contact_frames.py [--seed 0] [--steps 29]

Raw one-step comparison, MJX in float64 against C MuJoCo 4 (same MuJoCo release), from the
original's Ant states (reference_rollout.py), both with the Euler integrator so that RK4
differences are out of the picture: once with the model's pyramidal friction cone, once with the
elliptic cone. Then, at the first contact where the two disagree, the contact frames of both and
the capsule's axis: MJX's plane-capsule collider aligns the first tangent with the capsule axis
projected on the plane only when that projection has norm >= 0.5 (capsule less than 60 degrees
from the plane), C MuJoCo whenever it is nonzero. The pyramidal cone is not invariant under
rotations of the tangent frame (the elliptic cone is), so steep capsules get different friction.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from mujoco import mjx  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from compare import reference_python, reference_rollout  # noqa: E402

from r2pac_jax.envs.velocity import ASSETS  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=29)
    args = ap.parse_args()
    ref = reference_rollout("SafetyAntVelocityGymnasium-v1", args.seed, args.steps,
                            reference_python())
    pre, acts = ref["pre"], ref["actions"]
    for cone in ("pyramidal", "elliptic"):
        m = mujoco.MjModel.from_xml_path(str(ASSETS / "ant.xml"))
        m.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
        m.opt.cone = getattr(mujoco.mjtCone, f"mjCONE_{cone.upper()}")
        mm, d = mjx.put_model(m), mujoco.MjData(m)
        step5 = jax.jit(lambda mm, x: jax.lax.fori_loop(0, 5, lambda i, y: mjx.step(mm, y), x))
        fwd = jax.jit(mjx.forward)
        errs, shown = [], cone == "elliptic"
        for t in range(acts.shape[0]):
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:], d.ctrl[:] = pre["qpos"][t], pre["qvel"][t], acts[t]
            x0 = mjx.make_data(mm).replace(qpos=d.qpos.copy(), qvel=d.qvel.copy(),
                                           ctrl=d.ctrl.copy())
            if not shown:  # substep by substep, to find the first contact that differs
                x = x0
                for _ in range(5):
                    mujoco.mj_forward(m, d)
                    f = fwd(mm, x)
                    if np.abs(np.asarray(f.qacc) - d.qacc).max() > 1e-6 and d.ncon:
                        c = d.contact[0]
                        i = int(np.argmin(np.abs(np.asarray(f._impl.contact.dist) - c.dist)))
                        axis = d.geom_xmat[c.geom2].reshape(3, 3)[:, 2]
                        proj = axis - c.frame[:3] * axis.dot(c.frame[:3])
                        print(f"step {t}: contact geoms {c.geom1}-{c.geom2}, capsule axis "
                              f"{np.round(axis, 4).tolist()}, |projection on the plane| "
                              f"{np.linalg.norm(proj):.3f}")
                        print("  C MuJoCo tangent 1:", np.round(c.frame[3:6], 4).tolist())
                        print("  MJX      tangent 1:",
                              np.round(np.asarray(f._impl.contact.frame)[i][1], 4).tolist())
                        shown = True
                        break
                    mujoco.mj_step(m, d)
                    x = mjx.make_data(mm).replace(qpos=d.qpos.copy(), qvel=d.qvel.copy(),
                                                  ctrl=d.ctrl.copy())
                mujoco.mj_resetData(m, d)
                d.qpos[:], d.qvel[:], d.ctrl[:] = pre["qpos"][t], pre["qvel"][t], acts[t]
            mujoco.mj_step(m, d, nstep=5)
            errs.append(np.abs(np.asarray(step5(mm, x0).qvel) - d.qvel).max())
        print(f"{cone} cone, Euler: MJX-f64 vs C MuJoCo one-step qvel error over "
              f"{len(errs)} steps: max {max(errs):.1e}, median {np.median(errs):.1e}",
              flush=True)


if __name__ == "__main__":
    main()
