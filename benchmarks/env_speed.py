"""Environment speed: env-steps/s of our backends against the original simulator, MJX compile
times, and the fidelity cost of the MJX model simplifications.

    python benchmarks/env_speed.py stepping  --tasks T1,T2 --backends mujoco,mjx,jax \
                                             --batches 20,100,500 --policies none,r2pac
    python benchmarks/env_speed.py protocol  --tasks T1,T2 --policies none,r2pac
    python benchmarks/env_speed.py reference --tasks T1,T2 [--episodes 20] [--workers 2]
    python benchmarks/env_speed.py policy    --tasks T1,T2            # R2PAC act() at batch 1
    python benchmarks/env_speed.py compile   --tasks T1,T2            # MJX, plain vs simplified
    python benchmarks/env_speed.py table     FILE.jsonl               # markdown for RESULTS.md

Every measurement prints one JSON line (and appends it to `--out FILE` when given).

stepping  B parallel episodes stepped S control steps (after a warm-up that compiles); an
          episode that ends is reset (as the original's loop does), resets inside the timing.
          C MuJoCo (`physics="mujoco"`): the env's `step_batch` in a Python loop; MJX and pure
          JAX: one jitted `lax.scan` over steps of the vmapped step. Policy "none": uniform
          random actions (drawn before the loop for C MuJoCo, inside the program for JAX);
          "r2pac": the quick-preset R2PAC policy (CFG flow 3x128, 16 candidates x 32 Euler
          steps, critic selection; random initial parameters), jitted, called every step on
          the batch.
protocol  DSRL's evaluation: 20 episodes in parallel, each to its end (at most 1000 steps), with
          the library's own `LaneEvaluator` (what training uses); env-steps = sum of lengths,
          resets included; timed after one full warm-up call (compilation left out).
reference the original (Safety-Gymnasium 0.4.0, MuJoCo 2.3.3) in its own virtualenv
          ($R2PAC_SG_VENV or .venv-safety-gymnasium), as a subprocess timing its own loop
          (benchmarks/env_speed_reference.py): N sequential episodes (DSRL's protocol) and
          gymnasium's AsyncVectorEnv with K worker processes.
policy    seconds per call of the R2PAC policy on one observation: with it, the original's
          "policy included" rate is derived as 1 / (1 / rate + t_policy) (the original's venv
          has no JAX, so the policy cannot run inside its loop).
compile   MJX: lowering + XLA compile time of the batched reset and step programs (B = 20) with
          the model as written (plain) and as the task simplifies it for MJX (`mjx_model`), and
          the max |obs difference| against C MuJoCo over 100 steps from the same states and
          actions, for both.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from r2pac_jax.envs.base import pow2_bucket, put_rows, take_rows
from r2pac_jax.machine import record
from r2pac_jax.tasks import get_task, list_tasks

ROOT = Path(__file__).resolve().parent.parent
VELOCITY = ["AntVelocity", "HalfCheetahVelocity", "SwimmerVelocity", "HopperVelocity",
            "Walker2dVelocity"]
NAVIGATION = ["CarGoal1", "CarGoal2", "CarButton1", "CarButton2", "CarPush1", "CarPush2",
              "PointGoal1", "PointGoal2", "PointButton1", "PointButton2", "PointPush1",
              "PointPush2"]
GROUPS = {"velocity": VELOCITY, "navigation": NAVIGATION,
          "core-nav": ["CarGoal1", "CarGoal2", "CarButton1", "CarPush1", "PointGoal1"]}


def emit(rec: dict, out: str | None):
    rec = dict(rec, **record())
    line = json.dumps(rec)
    print(line, flush=True)
    if out:
        with open(out, "a") as f:  # one whole line per write: a reader never sees half a record
            f.write(line + "\n")


# ---------------------------------------------------------------------------------------------
# Policies


def r2pac_policy(task):
    """The quick-preset R2PAC policy with random initial parameters: (act, params)."""
    from r2pac_jax.agents import make_agent
    from r2pac_jax.config import default_hparams, make_config

    cfg = make_config(task, "r2pac", "quick")
    agent = make_agent(cfg, task.obs_dim, task.act_dim)
    hp = default_hparams(cfg)
    pp = agent.policy_params(agent.init(jax.random.PRNGKey(0), hp), hp)
    desc = (f"R2PAC quick ({cfg.actor}, {len(cfg.hidden_dims)}x{cfg.hidden_dims[0]}, "
            f"{cfg.num_candidates} candidates x {cfg.flow_steps} Euler steps, h={cfg.chunk_len})")
    return agent.act, pp, desc


def random_policy(task):
    def act(params, obs, key):
        return jax.random.uniform(key, (obs.shape[0], task.act_dim), minval=-1.0, maxval=1.0)

    return act, {}, "uniform random"


def get_policy(task, kind):
    return r2pac_policy(task) if kind == "r2pac" else random_policy(task)


# ---------------------------------------------------------------------------------------------
# Stepping throughput


def _physics_for(task, backend):
    return "jax" if task.family == "demo" else backend


def _serves(task, backend) -> bool:
    """Whether `backend` simulates `task` (pure JAX: the demo; bullet: the Bullet tasks)."""
    if task.family == "demo":
        return backend == "jax"
    if task.family == "bullet":  # pybullet, or the MuJoCo re-creations
        return backend in ("bullet", "mujoco", "mjx")
    return backend in ("mujoco", "mjx")


def step_c_mujoco(task, batch, policy, steps, warmup=3, physics="mujoco"):
    """C MuJoCo (or pybullet, `physics="bullet"`): `step_batch` in a Python loop; ended
    episodes are reset (only those lanes; for C MuJoCo in power-of-two buckets so that the
    jitted reset functions compile once per bucket; pybullet resets exactly the ended lanes,
    since each reset takes a simulation of its own)."""
    env = task.make_env(physics=physics)
    bucket = pow2_bucket if physics == "mujoco" else (lambda n: n)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    state = env.reset_batch(keys)
    if physics == "mujoco" and (steps + warmup >= task.episode_len
                                or task.family != "navigation"):
        # compile the reset buckets up front (up to 64 lanes ending in one step; more would
        # compile inside the timing: not seen with these batches)
        for b in range(int(np.log2(min(pow2_bucket(batch), 64))) + 1):
            env.reset_batch(jax.random.split(jax.random.PRNGKey(1), 1 << b))
    rng = np.random.default_rng(0)
    if policy == "none":
        acts = rng.uniform(-1, 1, (steps + warmup, batch, task.act_dim)).astype(np.float32)
        get = lambda t, s: acts[t]  # noqa: E731
        desc = "uniform random (pre-drawn)"
    else:
        act, pp, desc = get_policy(task, policy)
        act = jax.jit(act)
        pkeys = jax.random.split(jax.random.PRNGKey(1), steps + warmup)
        get = lambda t, s: np.asarray(act(pp, jnp.asarray(s.obs), pkeys[t]))  # noqa: E731
    resets = 0

    def advance(t, state):
        nonlocal resets
        state = env.step_batch(state, get(t, state))
        done = np.asarray(state.terminated) | np.asarray(state.truncated)
        if done.any():
            idx = np.flatnonzero(done)
            resets += len(idx)
            k = jax.random.split(jax.random.PRNGKey(1000 + t), bucket(len(idx)))
            fresh = take_rows(env.reset_batch(k), np.arange(len(idx)))  # the bucket's first
            state = put_rows(state, idx, fresh)
        return state

    for t in range(warmup):  # compiles the jitted task functions (and policy) at this batch
        state = advance(t, state)
    resets = 0
    t0 = time.perf_counter()
    for t in range(warmup, warmup + steps):
        state = advance(t, state)
    np.asarray(state.obs)
    wall = time.perf_counter() - t0
    return dict(wall_s=wall, env_steps=batch * steps, policy_desc=desc, resets=resets)


def step_jax(task, backend, batch, policy, steps, env=None):
    """JAX env (MJX, pure JAX): one jitted scan of the vmapped step; when an episode ends, the
    batch's reset is computed (lax.cond on any) and merged into the ended lanes."""
    env = env or task.make_env(physics=_physics_for(task, backend))
    act, pp, desc = get_policy(task, policy)
    v_reset = jax.vmap(env.reset)

    def run(state, key):
        def body(s, k):
            k_act, k_reset = jax.random.split(k)
            s = jax.vmap(env.step)(s, act(pp, s.obs, k_act))
            done = s.terminated | s.truncated

            def reset_ended(s):
                fresh = v_reset(jax.random.split(k_reset, batch))
                pick = lambda f, o: jnp.where(  # noqa: E731
                    done.reshape(done.shape + (1,) * (f.ndim - 1)), f, o)
                return jax.tree_util.tree_map(pick, fresh, s)

            s = jax.lax.cond(done.any(), reset_ended, lambda s: s, s)
            return s, done.sum()

        s, n_done = jax.lax.scan(body, state, jax.random.split(key, steps))
        return s, n_done.sum()

    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    t0 = time.perf_counter()
    reset = jax.jit(v_reset).lower(keys).compile()
    state = reset(keys)
    prog = jax.jit(run).lower(state, jax.random.PRNGKey(1)).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(prog(state, jax.random.PRNGKey(2))[0].obs)  # warm-up
    walls = []
    for r in range(2):
        t0 = time.perf_counter()
        s, n_done = prog(state, jax.random.PRNGKey(3 + r))
        jax.block_until_ready(s.obs)
        walls.append(time.perf_counter() - t0)
    return dict(wall_s=min(walls), env_steps=batch * steps, policy_desc=desc,
                compile_s=compile_s, resets=int(n_done))


def cmd_stepping(args):
    for name in args.tasks:
        task = get_task(name)
        for backend in args.backends:
            if not _serves(task, backend):
                continue
            for batch in args.batches:
                for policy in args.policies:
                    steps = args.steps or _default_steps(task, backend, batch, policy)
                    if backend in ("mujoco", "bullet"):
                        r = step_c_mujoco(task, batch, policy, steps, physics=backend)
                    else:
                        r = step_jax(task, backend, batch, policy, steps)
                    emit(dict(kind="stepping", task=task.name, backend=backend, batch=batch,
                              policy=policy, steps=steps, autoreset=True,
                              steps_per_s=r["env_steps"] / r["wall_s"], **r), args.out)


def _default_steps(task, backend, batch, policy):
    """Enough control steps for a stable figure without spending minutes per row."""
    if backend == "jax":  # ReachAvoid: the policy dominates (16 x 2 flows x 32 steps per obs)
        return 200 if policy == "none" else int(np.clip(2000 // batch, 5, 100))
    if backend == "mjx":
        return 20 if policy == "none" else 10
    per = 4000 if task.family in ("velocity", "bullet") else 1500
    if policy == "r2pac":
        per //= 4
    return int(np.clip(per * 20 // batch, 10, 400))


# ---------------------------------------------------------------------------------------------
# DSRL protocol through the library's evaluator


def cmd_protocol(args):
    from r2pac_jax.evaluate import LaneEvaluator

    for name in args.tasks:
        task = get_task(name)
        for backend in args.backends:
            physics = _physics_for(task, backend)
            if not _serves(task, backend):
                continue
            for policy in args.policies:
                act, pp, desc = get_policy(task, policy)
                env = task.make_env(physics=physics)
                ev = LaneEvaluator(act, task, args.episodes, env=env)
                lane = jax.tree_util.tree_map(lambda x: jnp.asarray(x)[None], pp)
                keys = jax.random.PRNGKey(0)[None]
                t0 = time.perf_counter()
                # compile + one run (a Python-loop env steps only the running episodes, in
                # power-of-two buckets: a full run compiles the buckets its episodes reach)
                ev(lane, keys)
                warm_s = time.perf_counter() - t0
                t0 = time.perf_counter()
                out = ev(lane, jax.random.PRNGKey(1)[None])
                wall = time.perf_counter() - t0
                n = int(out["lengths"].sum())
                emit(dict(kind="protocol", task=task.name, backend=backend,
                          batch=args.episodes, policy=policy, policy_desc=desc, wall_s=wall,
                          env_steps=n, steps_per_s=n / wall, warmup_s=warm_s,
                          mean_length=float(out["lengths"].mean())), args.out)


# ---------------------------------------------------------------------------------------------
# The original simulator


def reference_python(family: str = "navigation") -> str:
    if family == "bullet":
        venv = Path(os.environ.get("R2PAC_BSG_VENV", ROOT / ".venv-bullet-safety-gym"))
        how = "../shared/reference/install-bullet-safety-gym.sh or set R2PAC_BSG_VENV"
    else:
        venv = Path(os.environ.get("R2PAC_SG_VENV", ROOT / ".venv-safety-gymnasium"))
        how = "../shared/reference/install-safety-gymnasium.sh or set R2PAC_SG_VENV"
    py = venv / "bin" / "python"
    if not py.exists():
        raise SystemExit(f"reference virtualenv not found at {venv}: build it with {how}")
    return str(py)


def cmd_reference(args):
    script = str(Path(__file__).with_name("env_speed_reference.py"))
    for name in args.tasks:
        task = get_task(name)
        if task.gym_id is None:
            continue
        py = reference_python(task.family)
        runs = [["--mode", "seq", "--episodes",
                 str(args.episodes or (3 if task.family == "navigation" else 20))]]
        if args.workers > 1:
            steps = 2000 if task.family == "velocity" else 300
            runs.append(["--mode", "async", "--workers", str(args.workers), "--steps",
                         str(steps)])
        for extra in runs:
            p = subprocess.run([py, script, task.gym_id, *extra], capture_output=True, text=True)
            if p.returncode:
                raise SystemExit(f"reference run failed for {task.gym_id}:\n{p.stderr[-3000:]}")
            r = json.loads(p.stdout.strip().splitlines()[-1])
            r["stepping_steps_per_s"] = (r["env_steps"] / (r["wall_s"] - r["reset_s"])
                                         if "reset_s" in r else None)
            emit(dict(kind="reference", task=task.name, backend="original", policy="none",
                      **r), args.out)


def cmd_policy(args):
    for name in args.tasks:
        task = get_task(name)
        act, pp, desc = r2pac_policy(task)
        act = jax.jit(act)
        obs = jnp.zeros((1, task.obs_dim))
        keys = jax.random.split(jax.random.PRNGKey(0), args.calls + 3)
        for k in keys[:3]:
            np.asarray(act(pp, obs, k))
        times = []
        for k in keys[3:]:
            t0 = time.perf_counter()
            np.asarray(act(pp, obs, k))
            times.append(time.perf_counter() - t0)
        emit(dict(kind="policy", task=task.name, batch=1, policy_desc=desc,
                  s_per_call=float(np.median(times))), args.out)


# ---------------------------------------------------------------------------------------------
# MJX compile time and the simplification's fidelity cost


@contextlib.contextmanager
def plain_mjx():
    """Trace MJX envs with MJX's own `mjx.step` and a full forward pass at reset (what
    `r2pac_jax.envs.mjx_lean` replaces), and without the task's `mjx_model` simplification."""
    from mujoco import mjx

    from r2pac_jax.envs import mjx_lean
    from r2pac_jax.envs.physics import MjTask

    saved = (mjx_lean.step, mjx_lean.reset_pass)
    mjx_lean.step = lambda m, d: mjx.step(m, d)
    mjx_lean.reset_pass = lambda m, d, fields: mjx.forward(m, d)
    hooks = {}
    try:
        from r2pac_jax.envs.velocity import VelocityTask

        if VelocityTask.mjx_model is not MjTask.mjx_model:
            hooks[VelocityTask] = VelocityTask.mjx_model
            VelocityTask.mjx_model = MjTask.mjx_model
        yield
    finally:
        mjx_lean.step, mjx_lean.reset_pass = saved
        for cls, fn in hooks.items():
            cls.mjx_model = fn


def _obs_gap(task, reset, step, B=20, steps=100):
    """Max |obs_MJX - obs_C| over `steps` steps from the same initial states (same reset keys)
    and actions, with the compiled MJX programs of `_compile_mjx`; and the MJX observations."""
    c = task.make_env(physics="mujoco")
    keys = jax.random.split(jax.random.PRNGKey(42), B)
    sc, sm = c.reset_batch(keys), reset(keys)
    acts = np.random.default_rng(0).uniform(-1, 1, (steps, B, task.act_dim)).astype(np.float32)
    gaps, obs_m = [np.abs(np.asarray(sm.obs) - sc.obs).max(axis=-1)], [np.asarray(sm.obs)]
    alive, gap_alive = np.ones(B, bool), float(gaps[0].max())
    for t in range(steps):
        sc, sm = c.step_batch(sc, acts[t]), step(sm, jnp.asarray(acts[t]))
        obs_m.append(np.asarray(sm.obs))
        gaps.append(np.abs(obs_m[-1] - sc.obs).max(axis=-1))
        if alive.any():  # episodes not yet ended in C MuJoCo (before chaos after a fall)
            gap_alive = max(gap_alive, float(gaps[-1][alive].max()))
        alive &= ~np.asarray(sc.terminated)
    g = np.max(gaps, axis=-1)
    return dict(obs_gap_10=float(g[:11].max()), obs_gap_100=float(g.max()),
                obs_gap_until_done=gap_alive), np.stack(obs_m)


def _compile_mjx(task, B=20):
    """Build, lower and compile the batched reset and step programs; time each part."""
    env = task.make_env(physics="mjx")
    keys = jax.random.split(jax.random.PRNGKey(0), B)
    t0 = time.perf_counter()
    lo = jax.jit(jax.vmap(env.reset)).lower(keys)
    t1 = time.perf_counter()
    reset = lo.compile()
    t2 = time.perf_counter()
    s = reset(keys)
    a = jnp.zeros((B, task.act_dim))
    jax.block_until_ready(s.obs)
    t2b = time.perf_counter()
    lo = jax.jit(jax.vmap(env.step)).lower(s, a)
    t3 = time.perf_counter()
    step = lo.compile()
    t4 = time.perf_counter()
    s = step(s, a)
    jax.block_until_ready(s.obs)
    t5 = time.perf_counter()
    for _ in range(5):
        s = step(s, a)
    jax.block_until_ready(s.obs)
    sps = 5 * B / (time.perf_counter() - t5)
    m = env.mj_model
    return reset, step, dict(reset_lower_s=t1 - t0, reset_compile_s=t2 - t1, step_lower_s=t3 - t2b,
                     step_compile_s=t4 - t3, total_s=(t2 - t0) + (t4 - t2b),
                     step_steps_per_s_b20=sps, integrator=int(m.opt.integrator),
                     solver=int(m.opt.solver), iterations=int(m.opt.iterations),
                     ls_iterations=int(m.opt.ls_iterations))


def cmd_compile(args):
    """MJX compile times, MJX's own step/reset ("plain") vs ours ("lean": mjx_lean + the
    task's mjx_model), and each one's obs gap to C MuJoCo (and to each other)."""
    for name in args.tasks:
        task = get_task(name)
        obs = {}
        for variant in ("plain", "lean"):
            ctx = plain_mjx() if variant == "plain" else contextlib.nullcontext()
            with ctx:
                reset, step, rec = _compile_mjx(task)
                if not args.no_fidelity:
                    gap, obs[variant] = _obs_gap(task, reset, step)
                    rec.update(gap)
            emit(dict(kind="compile", task=task.name, variant=variant, **rec), args.out)
        if len(obs) == 2:
            d = np.abs(obs["plain"] - obs["lean"]).max(axis=(1, 2))
            emit(dict(kind="compile_agreement", task=task.name, lean_vs_plain_step1=float(d[1]),
                      lean_vs_plain_10=float(d[:11].max()),
                      lean_vs_plain_100=float(d.max())), args.out)


# ---------------------------------------------------------------------------------------------
# Table


def cmd_table(args):
    """Markdown tables from JSON lines; a later record replaces an earlier one with the same
    key (re-runs)."""
    last = {}
    for f in args.files:
        for line in open(f):
            if line.strip():
                r = json.loads(line)
                key = (r["kind"], r.get("task"), r.get("backend"), r.get("batch"),
                       r.get("policy"), r.get("mode"), r.get("variant"))
                last[key] = r
    recs = list(last.values())
    ref = {}
    for r in recs:
        if r["kind"] == "reference":
            ref.setdefault(r["task"], {})[r["mode"]] = r
    pol1 = {r["task"]: r["s_per_call"] for r in recs if r["kind"] == "policy"}

    def orig(task, policy):
        """The original's best rate (sequential or async workers); with the policy, derived."""
        if task not in ref:
            return None, ""
        best = max(ref[task].values(), key=lambda r: r["steps_per_s"])
        rate = best["steps_per_s"]
        how = "seq" if best["mode"] == "seq" else f"async x{best['batch']}"
        if policy == "r2pac":
            if task not in pol1:
                return None, ""
            rate = 1.0 / (1.0 / rate + pol1[task] / best["batch"])
            how += " + policy"
        return rate, how

    order = {t: i for i, t in enumerate(["ReachAvoid"] + VELOCITY + NAVIGATION)}
    rows = sorted((r for r in recs if r["kind"] in ("stepping", "protocol")),
                  key=lambda r: (order.get(r["task"], 99), r["backend"], r["kind"] != "protocol",
                                 r["policy"], r["batch"]))
    print("| task | backend | measure | batch | policy | env-steps/s | original env-steps/s "
          "(how) | ratio | load |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        o, how = orig(r["task"], r["policy"])
        ratio = f"{r['steps_per_s'] / o:.2f}x" if o else "n/a"
        pol = "excl." if r["policy"] == "none" else "incl."
        print(f"| {r['task']} | {r['backend']} | {r['kind']} | {r['batch']} | {pol} | "
              f"{r['steps_per_s']:,.0f} | {f'{o:,.0f} ({how})' if o else 'n/a'} | {ratio} | "
              f"{r.get('load_avg', float('nan')):.1f} |")
    print("\n| task | original seq (incl. resets) | seq, stepping only | async x2 | "
          "R2PAC policy s/call (batch 1) |")
    print("|---|---|---|---|---|")
    for t in sorted(ref, key=lambda t: order.get(t, 99)):
        seq, asy = ref[t].get("seq", {}), ref[t].get("async", {})
        print(f"| {t} | {seq.get('steps_per_s', float('nan')):,.0f} | "
              f"{seq.get('stepping_steps_per_s') or float('nan'):,.0f} | "
              f"{asy.get('steps_per_s', float('nan')):,.0f} | "
              f"{pol1.get(t, float('nan')) * 1e3:.1f} ms |")
    comp = [r for r in recs if r["kind"] == "compile"]
    if comp:
        print("\n| task | MJX step/reset | reset: lower + compile s | step: lower + compile s | "
              "total s | step env-steps/s (B=20) | max abs obs gap to C MuJoCo: 10 steps / 100 "
              "steps / 100 steps before the episode ends |")
        print("|---|---|---|---|---|---|---|")
        for r in sorted(comp, key=lambda r: (order.get(r["task"], 99), r["variant"] != "plain")):
            gap = (f"{r['obs_gap_10']:.1e} / {r['obs_gap_100']:.1e} / "
                   f"{r['obs_gap_until_done']:.1e}" if "obs_gap_100" in r else "-")
            print(f"| {r['task']} | {r['variant']} | "
                  f"{r['reset_lower_s']:.1f} + {r['reset_compile_s']:.1f} | "
                  f"{r['step_lower_s']:.1f} + {r['step_compile_s']:.1f} | {r['total_s']:.1f} | "
                  f"{r['step_steps_per_s_b20']:,.0f} | {gap} |")
    agree = [r for r in recs if r["kind"] == "compile_agreement"]
    for r in agree:
        print(f"\n{r['task']}: lean vs plain MJX max abs obs difference: step 1 "
              f"{r['lean_vs_plain_step1']:.1e}, 10 steps {r['lean_vs_plain_10']:.1e}, "
              f"100 steps {r['lean_vs_plain_100']:.1e}")


def _tasks(spec: str) -> list[str]:
    out = []
    for part in spec.split(","):
        out += GROUPS.get(part, [part])
    known = set(list_tasks())
    bad = [t for t in out if get_task(t).name not in known]
    if bad:
        raise SystemExit(f"unknown tasks {bad}")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cmd", choices=["stepping", "protocol", "reference", "policy", "compile",
                                    "table"])
    ap.add_argument("files", nargs="*", help="(table) JSON-lines files")
    ap.add_argument("--tasks", default="velocity,core-nav")
    ap.add_argument("--backends", default="mujoco")
    ap.add_argument("--batches", default="20")
    ap.add_argument("--policies", default="none")
    ap.add_argument("--steps", type=int, default=0, help="control steps (0: per-row default)")
    ap.add_argument("--episodes", type=int, default=0,
                    help="protocol: parallel episodes (default 20); reference: sequential "
                         "episodes (default 20 velocity, 3 navigation)")
    ap.add_argument("--workers", type=int, default=2, help="reference: AsyncVectorEnv workers")
    ap.add_argument("--calls", type=int, default=50)
    ap.add_argument("--no-fidelity", action="store_true")
    ap.add_argument("--out", default=None, help="append the JSON lines to this file")
    args = ap.parse_args(argv)
    if args.cmd == "table":
        return cmd_table(args)
    args.tasks = _tasks(args.tasks)
    args.backends = args.backends.split(",")
    args.batches = [int(b) for b in args.batches.split(",")]
    args.policies = args.policies.split(",")
    if args.cmd == "protocol":
        args.episodes = args.episodes or 20
    dict(stepping=cmd_stepping, protocol=cmd_protocol, reference=cmd_reference,
         policy=cmd_policy, compile=cmd_compile)[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
