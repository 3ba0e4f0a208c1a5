"""Explain the velocity tasks' fidelity gaps with raw MuJoCo runs (no task code in between).

    python benchmarks/fidelity/diagnose.py [--tasks AntVelocity,...] [--seeds 0,1,2]
        [--steps 1000] [--out FILE.jsonl]

For each task: (1) the compiled models: the reference's XML under MuJoCo 2.3.3 against ours
under MuJoCo 4, every numeric mjModel array compared (visual-only fields skipped); (2) one-step
errors of raw mj_step between the two simulators, as-is and with one suspected cause switched
off on both sides or put back on ours (`EXPERIMENTS`); (3) the chaos baseline: the reference
simulator against itself with its initial qvel perturbed by 1e-12, open loop, and our simulator
against the reference open loop: the first control step at which qpos or qvel differ by more
than 1e-3. If the reference diverges from itself about as soon as ours diverges from it, the
open-loop gap is chaos, not model error.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from compare import reference_python, reference_rollout  # noqa: E402

XML = {"AntVelocity": "ant.xml", "HalfCheetahVelocity": "half_cheetah.xml",
       "SwimmerVelocity": "swimmer.xml", "HopperVelocity": "hopper.xml",
       "Walker2dVelocity": "walker2d.xml"}
# name: (overrides on the reference side, overrides on our side)
EXPERIMENTS = {
    "as_is": ({}, {}),
    # gymnasium's own margins under MuJoCo 4 (our XMLs halve them; see velocity.py)
    "unhalved_margins": ({}, {"geom_margin*": 2.0}),
    # the Euler integrator on both sides: removes MuJoCo 4.0's RK4 change for free joints
    "euler_both": ({"opt.integrator": 0}, {"opt.integrator": 0}),
}
SKIP = ("tex_", "mat_", "vis", "light_", "cam_", "name", "mesh", "skin", "hfield", "text",
        "tuple", "key", "plugin", "buffer", "signature", "paths", "bvh_", "narena", "nstack",
        "ntex", "nbuffer", "geom_rgba", "site_rgba", "geom_matid", "geom_group",
        "body_sameframe", "geom_sameframe", "geom_aabb", "eq_data", "opt_apirate",
        "opt_collision", "opt_mpr_", "body_bvhadr", "body_bvhnum", "nbvh", "body_margin")


def model_diff(task: str, python: Path) -> list:
    import mujoco

    from r2pac_jax.envs.velocity import ASSETS
    from r2pac_jax.tasks import get_task

    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "model.npz"
        subprocess.run([str(python), str(HERE / "reference_rollout.py"), "--model",
                        get_task(task).gym_id, str(out)], check=True, capture_output=True)
        with np.load(out) as z:
            ref = {k: z[k] for k in z.files}
    ours = mujoco.MjModel.from_xml_path(str(ASSETS / XML[task]))
    diffs = []
    for k, r in ref.items():
        if k in ("xml_path", "mujoco_version") or k.startswith(SKIP):
            continue
        try:
            o = np.asarray(getattr(ours.opt, k[4:]) if k.startswith("opt_") else getattr(ours, k))
        except AttributeError:
            continue  # fields MuJoCo 4 dropped (listed in SKIP when they matter)
        if o.shape != r.shape or not np.allclose(o.astype(float), r.astype(float),
                                                 rtol=1e-12, atol=0):
            diffs.append(f"{k}: ref {r.ravel()[:6].tolist()} ours {o.ravel()[:6].tolist()}")
    return diffs


def raw(python: str, xml: str, states: dict, fs: int, mode: str, overrides: dict) -> dict:
    with tempfile.TemporaryDirectory() as d:
        inp, out = Path(d) / "in.npz", Path(d) / "out.npz"
        np.savez(inp, **states)
        subprocess.run([python, str(HERE / "raw_step.py"), xml, str(inp), str(out), str(fs),
                        mode, json.dumps(overrides)], check=True, capture_output=True)
        with np.load(out) as z:
            return {k: z[k] for k in z.files}


def first_over(a: dict, b: dict, tol: float = 1e-3):
    d = np.maximum(np.abs(a["qpos"] - b["qpos"]).max(1), np.abs(a["qvel"] - b["qvel"]).max(1))
    over = np.nonzero(d > tol)[0]
    return int(over[0]) + 1 if over.size else None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", default=",".join(XML))
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    from r2pac_jax.envs.velocity import ASSETS, ROBOTS
    from r2pac_jax.tasks import get_task

    python = reference_python()
    ref_site = next((python.parent.parent / "lib").glob("python*/site-packages"))
    ref_assets = ref_site / "gymnasium" / "envs" / "mujoco" / "assets"

    def emit(row):
        line = json.dumps(row)
        print(line, flush=True)
        if args.out:
            with open(args.out, "a") as f:
                f.write(line + "\n")

    for task in args.tasks.split(","):
        emit(dict(task=task, kind="model_diff", diffs=model_diff(task, python)))
        fs = ROBOTS[task].frame_skip
        ref_xml, our_xml = str(ref_assets / XML[task]), str(ASSETS / XML[task])
        for seed in (int(s) for s in args.seeds.split(",")):
            ref = reference_rollout(get_task(task).gym_id, seed, args.steps, python)
            states = dict(qpos=ref["pre"]["qpos"], qvel=ref["pre"]["qvel"],
                          actions=ref["actions"])
            for name, (ref_over, our_over) in EXPERIMENTS.items():
                a = raw(str(python), ref_xml, states, fs, "one_step", ref_over)
                b = raw(sys.executable, our_xml, states, fs, "one_step", our_over)
                emit(dict(task=task, seed=seed, kind="raw_one_step", experiment=name,
                          max_err_qpos=float(np.abs(a["qpos"] - b["qpos"]).max()),
                          max_err_qvel=float(np.abs(a["qvel"] - b["qvel"]).max()),
                          max_err_xpos=float(np.abs(a["xpos"] - b["xpos"]).max())))
            ref_open = raw(str(python), ref_xml, states, fs, "open_loop", {})
            bumped = dict(states, qvel=states["qvel"].copy())
            bumped["qvel"][0] += 1e-12
            ref_bumped = raw(str(python), ref_xml, bumped, fs, "open_loop", {})
            ours_open = raw(sys.executable, our_xml, states, fs, "open_loop", {})
            emit(dict(task=task, seed=seed, kind="chaos",
                      ref_self_check=float(np.abs(ref_open["qvel"] - ref["qvel"]).max()),
                      ref_vs_ref_perturbed_1e12=first_over(ref_open, ref_bumped),
                      ours_vs_ref=first_over(ref_open, ours_open)))


if __name__ == "__main__":
    main()
