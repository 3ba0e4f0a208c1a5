"""Raw MuJoCo stepping for the fidelity diagnosis; runs under either interpreter (the reference
virtualenv's MuJoCo 2.3.3 or ours, MuJoCo 4), with no task code in between.

    PY raw_step.py XML IN.npz OUT.npz FRAME_SKIP MODE [OVERRIDES_JSON]

IN.npz holds qpos [T, nq], qvel [T, nv], actions [T, A]. MODE `one_step`: from each (qpos[t],
qvel[t]) apply actions[t] for FRAME_SKIP substeps; `open_loop`: from (qpos[0], qvel[0]) apply
the whole action sequence. OUT.npz: qpos, qvel, xpos (as mj_step leaves them) per control step.
OVERRIDES_JSON changes the compiled model first, e.g. '{"opt.integrator": 0}' (Euler) or
'{"geom_margin": 0.0}', or '{"geom_margin*": 2}' (scale), so that a suspected cause of a
difference can be switched off on both sides.
"""
import json
import sys
import warnings

warnings.filterwarnings("ignore")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402


def main():
    xml, inp, out, fs, mode = sys.argv[1:6]
    fs = int(fs)
    overrides = json.loads(sys.argv[6]) if len(sys.argv) > 6 else {}
    m = mujoco.MjModel.from_xml_path(xml)
    for k, v in overrides.items():
        if k.startswith("opt."):
            setattr(m.opt, k[4:], v)
        elif k.endswith("*"):
            getattr(m, k[:-1])[:] *= v
        else:
            getattr(m, k)[:] = v
    d = mujoco.MjData(m)
    with np.load(inp) as z:
        qpos, qvel, actions = z["qpos"], z["qvel"], z["actions"]
    rec = {"qpos": [], "qvel": [], "xpos": []}
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = qpos[0], qvel[0]
    mujoco.mj_forward(m, d)
    for t in range(actions.shape[0]):
        if mode == "one_step":
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:] = qpos[t], qvel[t]
            mujoco.mj_forward(m, d)
        d.ctrl[:] = actions[t]
        mujoco.mj_step(m, d, nstep=fs)
        for k in rec:
            rec[k].append(np.array(getattr(d, k)))
    np.savez(out, mujoco_version=np.array(mujoco.__version__),
             **{k: np.asarray(v) for k, v in rec.items()})


if __name__ == "__main__":
    main()
