"""Replay the reference's rollouts in our environments and measure the step-by-step errors.

    python benchmarks/fidelity/compare.py [--tasks AntVelocity,...] [--steps 100,1000]
        [--seeds 0,1,2] [--physics mujoco,mjx] [--x64] [--ref-python PATH] [--out FILE.jsonl]
    python benchmarks/fidelity/compare.py --episodes 50 [--tasks ...] [--out FILE.jsonl]

For every task and seed, `reference_rollout.py` runs in the reference virtualenv (env var
R2PAC_SG_VENV, default .venv-safety-gymnasium; build it with
../shared/reference/install-safety-gymnasium.sh) for max(steps) steps of seeded uniform-random
actions, stepping on through terminal states (so every horizon is compared in full; the terminal
flags are compared step by step). Our side then measures, per backend, two things:

* open loop: start from the reference's state after reset, apply the same actions, compare
  observation, reward, cost, terminal flag, qpos and qvel at every step. Errors here combine
  model differences with chaotic growth of round-off (contact-rich robots amplify 1e-14 into
  O(1) within a few hundred steps).
* one step: put our env in the reference's exact state before step t (qpos, qvel and any other
  field our task reads, e.g. Ant's torso xpos; MJX also gets the solver warm start), apply
  action t, compare with the reference after step t. This isolates the model/integrator error
  of a single control step from the chaos.

`--episodes N` instead compares statistics, which is what DSRL's scores are made of: N whole
episodes of a uniform-random policy (the same action sequences on both sides, from the same
start states; each side ends its episodes by its own terminal rule), the mean return, cost and
length with their standard errors, on the C-MuJoCo backend.

Prints one JSON line per (task, backend, mode, horizon): the maximum absolute error of each
quantity over seeds and steps, how many steps' cost / terminal flags disagree, and (open loop)
the first step at which the observation error exceeds 1e-3. `--x64` runs MJX in float64.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
QUANTITIES = ("obs", "reward", "cost", "qpos", "qvel")


def reference_python() -> Path:
    venv = Path(os.environ.get("R2PAC_SG_VENV", ".venv-safety-gymnasium"))
    return venv / "bin" / "python"


def reference_rollout(gym_id: str, seed: int, steps: int, python: Path) -> dict:
    """The reference's record (see reference_rollout.py), with the start state prepended to
    the per-step state arrays: `pre[k][t]` is the state before step t."""
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "ref.npz"
        subprocess.run([str(python), str(HERE / "reference_rollout.py"), gym_id, str(seed),
                        str(steps), str(out), "--through-terminal"], check=True,
                       capture_output=True, timeout=900)
        with np.load(out) as z:
            ref = {k: z[k] for k in z.files}
    ref["pre"] = {
        "qpos": np.concatenate([ref["qpos0"][None], ref["qpos"][:-1]]),
        "qvel": np.concatenate([ref["qvel0"][None], ref["qvel"][:-1]]),
        "xpos": np.concatenate([ref["body_xpos0"][None], ref["body_xpos"][:-1]]),
        "qacc_warmstart": np.concatenate([ref["warmstart0"][None], ref["warmstart"][:-1]]),
    }
    return ref


class Replayer:
    """Our env for one task and backend; compiled functions are reused across seeds."""

    def __init__(self, task_name: str, physics: str):
        import jax

        from r2pac_jax.tasks import get_task

        self.physics = physics
        self.env = get_task(task_name).make_env(physics=physics)
        self.fields = self.env.task.view_fields
        if physics == "mjx":
            env = self.env
            def body(s, a):
                s = env.step(s, a)
                return s, self._record(s)

            self._scan = jax.jit(lambda s, a: jax.lax.scan(body, s, a)[1])
            self._vstep = jax.jit(jax.vmap(lambda s, a: self._record(env.step(s, a))))
            self._vforward = jax.jit(jax.vmap(self._mjx_state))

    @staticmethod
    def _record(s):
        return dict(obs=s.obs, reward=s.reward, cost=s.cost, terminated=s.terminated,
                    qpos=s.physics.qpos, qvel=s.physics.qvel)

    def _mjx_state(self, key, pre):
        """An MJX EnvState at the reference's state `pre` (dict of mjData fields)."""
        from mujoco import mjx

        st = self.env.reset(key)
        data = st.physics.replace(qpos=pre["qpos"], qvel=pre["qvel"])
        data = mjx.forward(self.env.model, data)
        # fields as the reference's last mj_step left them (e.g. Ant's xpos); the warm start too
        data = data.replace(**{k: v for k, v in pre.items() if k not in ("qpos", "qvel")})
        view = {f: getattr(data, f) for f in self.fields}
        return st.replace(obs=self.env.task.observe(view, st.info).astype(st.obs.dtype),
                          physics=data)

    def _mujoco_state(self, pre: dict, n: int):
        """A C-MuJoCo EnvState (batch n) at the reference's states `pre`."""
        import jax

        env = self.env
        st = env.reset_batch(jax.random.split(jax.random.PRNGKey(0), n))
        states = env.states_from_qpos_qvel(pre["qpos"], pre["qvel"])
        st = env.reset_to(states, st.info, st.key)
        # view fields as the reference's last mj_step left them (e.g. Ant's xpos)
        physics = dict(st.physics, **{f: pre[f] for f in self.fields if f in pre})
        return st.replace(physics=physics)

    def _pre_arrays(self, pre: dict, idx):
        import jax.numpy as jnp

        keep = set(self.fields) | {"qpos", "qvel"}
        if self.physics == "mjx":
            keep.add("qacc_warmstart")
        dtype = jnp.zeros(()).dtype  # float32, or float64 under --x64
        return {k: jnp.asarray(v[idx], dtype) for k, v in pre.items() if k in keep}

    def open_loop(self, ref: dict) -> dict:
        import jax
        import jax.numpy as jnp

        pre, acts = ref["pre"], ref["actions"]
        if self.physics == "mjx":
            st = self._vforward(jax.random.split(jax.random.PRNGKey(0), 1),
                                self._pre_arrays(pre, slice(0, 1)))
            st = jax.tree_util.tree_map(lambda x: x[0], st)
            out = self._scan(st, jnp.asarray(acts, jnp.zeros(()).dtype))
            return {k: np.asarray(v) for k, v in out.items()}
        st = self._mujoco_state({k: v[:1] for k, v in pre.items()}, 1)
        rec = {k: [] for k in ("obs", "reward", "cost", "terminated", "qpos", "qvel")}
        for t in range(acts.shape[0]):
            st = self.env.step_batch(st, acts[t][None])
            for k, v in (("obs", st.obs), ("reward", st.reward), ("cost", st.cost),
                         ("terminated", st.terminated), ("qpos", st.physics["qpos"]),
                         ("qvel", st.physics["qvel"])):
                rec[k].append(np.asarray(v[0]))
        return {k: np.asarray(v) for k, v in rec.items()}

    def one_step(self, ref: dict) -> dict:
        import jax
        import jax.numpy as jnp

        pre, acts = ref["pre"], ref["actions"]
        T = acts.shape[0]
        if self.physics == "mjx":
            st = self._vforward(jax.random.split(jax.random.PRNGKey(0), T),
                                self._pre_arrays(pre, slice(None)))
            out = self._vstep(st, jnp.asarray(acts, jnp.zeros(()).dtype))
            return {k: np.asarray(v) for k, v in out.items()}
        st = self.env.step_batch(self._mujoco_state(pre, T), acts)
        return dict(obs=st.obs, reward=st.reward, cost=st.cost, terminated=st.terminated,
                    qpos=st.physics["qpos"], qvel=st.physics["qvel"])


def errors(ref: dict, ours: dict, horizon: int) -> dict:
    """Per-quantity max |ours - ref| over the first `horizon` steps, and flag disagreements."""
    n = min(horizon, ref["actions"].shape[0])
    res = dict(steps=int(n))
    for k in QUANTITIES:
        d = np.abs(np.asarray(ours[k][:n], np.float64) - np.asarray(ref[k][:n], np.float64))
        res[f"max_err_{k}"] = float(np.max(d))
    res["cost_disagree"] = int(np.sum(np.asarray(ours["cost"][:n]) != ref["cost"][:n]))
    res["terminated_disagree"] = int(np.sum(np.asarray(ours["terminated"][:n]).astype(bool)
                                            != ref["terminated"][:n].astype(bool)))
    dobs = np.abs(np.asarray(ours["obs"][:n], np.float64) - ref["obs"][:n]).max(axis=1)
    over = np.nonzero(dobs > 1e-3)[0]
    res["first_obs_err_over_1e-3"] = int(over[0]) + 1 if over.size else None
    ref_term = np.nonzero(ref["terminated"][:n])[0]
    res["ref_first_terminal"] = int(ref_term[0]) + 1 if ref_term.size else None
    return res


def summarise(per: list, **row) -> dict:
    row["steps"] = [p["steps"] for p in per]
    for k in per[0]:
        if k.startswith("max_err"):
            row[k] = max(p[k] for p in per)
    for k in ("cost_disagree", "terminated_disagree"):
        row[k] = sum(p[k] for p in per)
    for k in ("first_obs_err_over_1e-3", "ref_first_terminal"):
        row[k] = [p[k] for p in per]
    return row


def reference_episodes(gym_id: str, n: int, seed: int, python: Path) -> dict:
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "eps.npz"
        subprocess.run([str(python), str(HERE / "reference_rollout.py"), "--episodes", str(n),
                        gym_id, str(seed), str(out)], check=True, capture_output=True,
                       timeout=3600)
        with np.load(out) as z:
            return {k: z[k] for k in z.files}


def our_episodes(task_name: str, ref: dict) -> dict:
    """The reference's episodes replayed open loop in our C-MuJoCo env, all in one batch."""
    rep = Replayer(task_name, "mujoco")
    n, T = ref["actions"].shape[:2]
    pre = {"qpos": ref["qpos0"], "qvel": ref["qvel0"], "xpos": ref["body_xpos0"]}
    st = rep._mujoco_state(pre, n)
    ret, cost = np.zeros(n), np.zeros(n)
    length, alive = np.zeros(n, np.int64), np.ones(n, bool)
    for t in range(T):
        st = rep.env.step_batch(st, ref["actions"][:, t])
        ret += np.where(alive, st.reward, 0.0)
        cost += np.where(alive, st.cost, 0.0)
        length += alive
        alive &= ~np.asarray(st.terminated | st.truncated)
        if not alive.any():
            break
    return dict(returns=ret, costs=cost, lengths=length)


def episode_stats(task_name: str, ref: dict, ours: dict) -> dict:
    from r2pac_jax.tasks import get_task

    spec = get_task(task_name)
    row = dict(task=task_name, physics="mujoco", mode="episodes",
               episodes=int(ref["returns"].shape[0]))
    for k in ("returns", "costs", "lengths"):
        a, b = np.asarray(ref[k], np.float64), np.asarray(ours[k], np.float64)
        se = lambda x: float(x.std(ddof=1) / np.sqrt(x.size))  # noqa: E731
        row[k] = dict(ref_mean=float(a.mean()), ref_se=se(a), ours_mean=float(b.mean()),
                      ours_se=se(b), diff_over_se=float((b.mean() - a.mean()) /
                                                        max(np.hypot(se(a), se(b)), 1e-12)))
    row["normalized_reward_diff"] = (row["returns"]["ours_mean"] - row["returns"]["ref_mean"]
                                     ) / (spec.r_max - spec.r_min)
    row["normalized_cost_diff"] = (row["costs"]["ours_mean"] - row["costs"]["ref_mean"]
                                   ) / spec.kappa
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", default="AntVelocity,HalfCheetahVelocity,SwimmerVelocity,"
                                       "HopperVelocity,Walker2dVelocity")
    ap.add_argument("--steps", default="100,1000")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--physics", default="mujoco")
    ap.add_argument("--x64", action="store_true", help="run MJX in float64")
    ap.add_argument("--ref-python", default=None)
    ap.add_argument("--out", default=None, help="also append the JSON lines to this file")
    ap.add_argument("--episodes", type=int, default=0,
                    help="compare N whole random-policy episodes' statistics instead")
    args = ap.parse_args()
    if args.x64:
        import jax

        jax.config.update("jax_enable_x64", True)
    from r2pac_jax.tasks import get_task

    python = Path(args.ref_python) if args.ref_python else reference_python()
    if not python.exists():
        sys.exit(f"reference python {python} not found: build the reference virtualenv with "
                 "../shared/reference/install-safety-gymnasium.sh and set R2PAC_SG_VENV")
    horizons = [int(h) for h in args.steps.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    if args.episodes:
        for name in args.tasks.split(","):
            ref = reference_episodes(get_task(name).gym_id, args.episodes, 1000, python)
            line = json.dumps(episode_stats(name, ref, our_episodes(name, ref)))
            print(line, flush=True)
            if args.out:
                with open(args.out, "a") as f:
                    f.write(line + "\n")
        return
    for name in args.tasks.split(","):
        refs = [reference_rollout(get_task(name).gym_id, s, max(horizons), python)
                for s in seeds]
        for physics in args.physics.split(","):
            rep = Replayer(name, physics)
            label = physics + ("-f64" if physics == "mjx" and args.x64 else "")
            for mode, fn in (("open_loop", rep.open_loop), ("one_step", rep.one_step)):
                ours = [fn(r) for r in refs]
                for h in horizons:
                    row = summarise([errors(r, o, h) for r, o in zip(refs, ours)], task=name,
                                    physics=label, mode=mode, horizon=h, seeds=args.seeds)
                    line = json.dumps(row)
                    print(line, flush=True)
                    if args.out:
                        with open(args.out, "a") as f:
                            f.write(line + "\n")


if __name__ == "__main__":
    main()
