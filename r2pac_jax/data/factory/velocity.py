"""Scripted behaviour source for the velocity tasks: periodic gaits of graded speed.

DSRL's velocity datasets come from Lagrangian RL agents (annealed cost limit) whose finished
trajectories were kept. That recipe is NOT implemented here: on this 2-core CPU the C-MuJoCo
batch backend runs roughly 1e3 (Ant) to 1e4 (HalfCheetah, Swimmer) environment steps per
second, while such agents train on millions of steps. The source here is the default on CPU
and on GPU: a central-pattern gait per robot, found once by a cross-entropy search
(`experiments/data_factory/gait_search.py`, parameters in GAITS), played with per-trajectory
knobs so that the trajectories spread over the cost/return plane:

    a_j(t) = clip(b_j + m A_j sin(2 pi (f g) t + phi_j) + (K obs)_j + noise, -1, 1)

- SPEED: the amplitude multiplier m and frequency multiplier g rise together with a speed
  level (`_levels`); each gait draws its levels from its own range;
- SEGMENTS: half of the trajectories switch (gait, level) at a random step, so that episode
  costs (steps above the velocity limit) take values between the extremes;
- NOISE: Gaussian action noise, std in [0, 0.3];
- K: a linear feedback on the observation, only for the robots that fall over without one
  (Hopper, Walker2d).

How well this covers the plane differs by robot (figures in GENERATION.md): HalfCheetah's
gait spans slow-and-safe to faster than DSRL's best (like DSRL's data); Swimmer's x velocity
swings within every stroke, so only its slowest swimmers are safe; Hopper and Walker2d fall
within a few hundred steps (short, low-return episodes; costs from speed spikes); Ant's open-loop
gaits drift in heading and stay under its velocity limit, with costs only from a violent gait's
speed spikes. The last three need the RL recipe (or closed-loop controllers) to match DSRL.

Episodes run batched on the C MuJoCo backend; trajectory i's randomness comes from
(seed, i) only, so the same seed gives the same arrays and a smaller n gives a prefix.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from r2pac_jax.data.factory.batch import episode_keys, in_equal_batches, record_episodes

VELOCITY_TASKS = ("AntVelocity", "HalfCheetahVelocity", "SwimmerVelocity", "HopperVelocity",
                  "Walker2dVelocity")

# Gaits found by experiments/data_factory/gait_search.py (commands in GENERATION.md):
# params = (f, A[J], phi[J], b[J]) (+ K [J * obs_dim], row-major, when "feedback"); `levels`:
# the range of speed levels drawn for it (level 1 = the gait as found; see _levels).
# A task with several gaits (a fast one and one found with a cost penalty) draws one per
# trajectory segment.
GAITS: dict = {
    "HalfCheetahVelocity": [
        # 4.58 m/s over 200 steps (--iters 40 --pop 128 --elite 12 --fmax 6); the speed rises
        # with the level up to ~0.8 (R ~3200), faster levels flip the robot
        dict(levels=(0.1, 0.85), params=[
            4.3919, 0.8313, 1.0, 0.9751, 0.9453, 1.0, 0.8605, 3.9931, 0.0544, 3.358, 5.9233,
            5.9997, 6.1102, 0.2535, 0.1301, 0.2588, -0.1627, -0.1599, -0.3552])],
    "SwimmerVelocity": [
        # 0.296 m/s in steady state: a grid over (f, phase lag, amplitude) after the search
        # plateaued at 0.175 m/s; amplitude 3 makes clipped, square-ish waves. The swimmer's
        # x velocity swings widely within a stroke, so only the lowest levels stay safe.
        dict(levels=(0.0, 1.0), level_power=2.0, params=[0.4, 3.0, 3.0, 0.0, 6.2, 0.0, 0.0]),
        # the same gait held to its slowest levels: the safe (and slow) swimmers
        dict(levels=(0.0, 0.06), params=[0.4, 3.0, 3.0, 0.0, 6.2, 0.0, 0.0])],
    "HopperVelocity": [
        # 0.379 m/s over 400 steps without falling (--iters 25 --pop 96 --elite 10
        # --horizon 400 --fmax 3 --feedback 0.5)
        dict(feedback=True, levels=(0.0, 1.0), params=[
            2.5921, 0.3665, 0.2819, 0.1587, 3.3728, 3.6786, 5.3195, 0.4125, 0.3635, 0.123,
            -0.3091, -0.5, 0.0014, 0.2787, -0.2211, -0.0898, 0.5, -0.353, -0.4015, 0.4527,
            -0.0779, -0.0617, -0.3806, 0.0903, 0.3661, -0.059, 0.3352, 0.4765, -0.2697, -0.4483,
            -0.1424, 0.3449, 0.0871, -0.4318, 0.2262, 0.1026, -0.4322, -0.2239, 0.3829, -0.2146,
            -0.0289, -0.3705, -0.1915]),
        # 0.20 (speed - 3 x fraction of steps with cost) over 400 steps (same with
        # --penalty 3): the slower, safer hop
        dict(feedback=True, levels=(0.0, 1.0), params=[
            3.0, 0.8477, 0.4017, 0.4966, 2.9336, 1.5084, 0.5846, 0.1754, 0.0905, 0.1455,
            -0.2155, 0.2204, 0.2415, -0.2243, -0.0097, 0.1215, -0.3081, -0.1437, -0.4487,
            -0.2366, 0.2326, 0.4122, 0.3026, -0.4085, -0.0661, 0.4668, -0.2947, -0.0198, -0.3917,
            0.5, -0.5, 0.0685, -0.036, -0.4371, 0.398, 0.0571, -0.2371, -0.3759, -0.1456,
            -0.3386, -0.401, 0.2552, -0.4772])],
    "Walker2dVelocity": [
        # 0.43 m/s over 400 steps without falling (--iters 30 --pop 96 --elite 10 --horizon
        # 400 --fmax 3 --feedback 0.5)
        dict(feedback=True, levels=(0.0, 1.0), params=[
            0.6645, 0.1014, 0.2919, 0.972, 0.8065, 0.1153, 0.7577, 0.5663, 2.973, 1.1806,
            1.7751, 5.9266, 1.3315, -0.0095, 0.2443, 0.4122, 0.3155, -0.2933, 0.2686, 0.3637,
            -0.5, -0.263, -0.3276, -0.5, 0.41, -0.3903, 0.351, -0.1004, 0.152, -0.3856, -0.3705,
            -0.0502, -0.1051, -0.323, -0.2199, 0.2842, 0.5, 0.3171, -0.4408, -0.294, -0.3509,
            -0.1963, 0.1471, 0.483, 0.0931, -0.1084, -0.1833, 0.2949, -0.2755, 0.1159, -0.2702,
            0.3894, -0.1092, 0.4675, -0.365, 0.3664, -0.1084, 0.123, 0.4444, -0.2713, -0.0969,
            0.2235, 0.1806, -0.3954, 0.4278, -0.0325, -0.4694, -0.2878, -0.1161, 0.2152, 0.141,
            -0.2396, -0.2163, -0.2996, 0.3226, 0.5, 0.4307, 0.2808, -0.0071, -0.1683, 0.043,
            -0.0981, 0.3162, 0.4749, 0.0144, 0.0946, 0.0576, 0.0988, -0.3533, 0.5, 0.4643,
            -0.0342, -0.3831, -0.1566, 0.2414, 0.353, 0.1352, -0.1227, -0.3264, 0.1141, 0.4367,
            0.0731, -0.4338, 0.0968, 0.1617, -0.5, -0.4799, -0.0939, 0.081, -0.1903, 0.4059,
            -0.2987, 0.1799, -0.4398, -0.4205, 0.1998, 0.1696, 0.0526, -0.0847, 0.386,
            -0.4278])],
    "AntVelocity": [
        # 1.15 m/s over 300 steps (--iters 40 --pop 64 --elite 8 --horizon 300 --fmax 6
        # --amax 1.5); over 1000 steps the heading drifts and forward progress fades: returns
        # stay near the healthy reward minus the control cost (about 100-600)
        dict(levels=(0.1, 1.0), params=[
            5.1997, 0.4162, 1.0344, 1.0023, 0.6084, 0.8141, 0.0589, 1.0984, 0.9099, 0.7024,
            5.4423, 1.9376, 2.3954, 4.8808, 3.7918, 3.8691, 4.7283, 0.1701, -0.2285, 0.2848,
            -0.1938, -0.0406, 0.3583, 0.3129, 0.4732]),
        # 1.81 m/s over 150 steps (--horizon 150 --fmax 6 --amax 3 from an earlier best): a
        # violent gait whose speed spikes cross the limit (cost 3-50) and that often flips
        dict(levels=(0.5, 1.0), params=[
            3.7084, 0.0, 1.6276, 0.0, 0.5167, 1.838, 1.9124, 0.5639, 0.3637, 1.3644, 3.443,
            1.7135, 1.0326, 2.8514, 2.5121, 3.2042, 4.4045, 0.4296, -0.2606, 0.3957, -0.0305,
            0.4263, 0.1526, 0.2652, 0.0928])],
}

# Default sizes (OVERSAMPLE x this many episodes are simulated, then density-thinned): about
# 10 minutes or less per task on the 2-core CPU, measured in GENERATION.md.
DEFAULT_TRAJECTORIES = {"AntVelocity": 300, "HalfCheetahVelocity": 1000, "SwimmerVelocity": 1000,
                        "HopperVelocity": 1000, "Walker2dVelocity": 1000}
OVERSAMPLE = 2
BATCH = 200
NOISE_MAX = 0.3


def _levels(level):
    """Amplitude and frequency multipliers for speed levels in [0, 1]."""
    return level, 0.5 + 0.5 * level


class Plan:
    """Per-trajectory knobs for a batch: two segments (gait, speed level) split at `switch`
    (T for the half of the trajectories that keep one), a phase offset, the action noise."""

    def __init__(self, seed: int, first: int, n: int, task: str, T: int, act_dim: int):
        gaits = GAITS[task]
        self.gait = np.empty((n, 2), int)
        self.level = np.empty((n, 2))
        self.switch = np.empty(n, int)
        self.phase = np.empty(n)
        self.noise = np.empty((n, T, act_dim), np.float32)
        for i in range(n):
            rng = np.random.default_rng([seed, first + i])
            self.gait[i] = rng.integers(0, len(gaits), 2)
            for k in range(2):
                g = gaits[self.gait[i, k]]
                lo, hi = g["levels"]
                self.level[i, k] = lo + (hi - lo) * rng.uniform() ** g.get("level_power", 1.0)
            self.switch[i] = T if rng.uniform() < 0.5 else rng.integers(T // 10, T - T // 10)
            self.phase[i] = rng.uniform(0, 2 * np.pi)
            std = NOISE_MAX * rng.uniform() ** 2
            self.noise[i] = (std * rng.normal(size=(T, act_dim))).astype(np.float32)

    def at(self, t: int):
        """Gait index [n] and speed level [n] at step t."""
        seg = (t >= self.switch).astype(int)
        rows = np.arange(len(seg))
        return self.gait[rows, seg], self.level[rows, seg]


def gait_actions(params: np.ndarray, t: float, level: np.ndarray, phase: np.ndarray,
                 obs: np.ndarray, act_dim: int, feedback: bool) -> np.ndarray:
    """Actions [n, J] at time t (s) for speed levels [n], phase offsets [n], obs [n, obs_dim]."""
    J = act_dim
    f = params[0]
    amp, phi, bias = (params[1 + i * J:1 + (i + 1) * J] for i in range(3))
    m, g = _levels(level)
    a = bias[None] + m[:, None] * amp[None] * np.sin(
        2 * np.pi * f * g[:, None] * t + phi[None] + phase[:, None])
    if feedback:
        K = params[1 + 3 * J:].reshape(J, -1)
        a = a + obs @ K.T
    return a


def rollout(env, task: str, seed: int, first: int, n: int, progress=None,
            progress_scale: float = 1.0, steps=None, plan: Optional[Plan] = None) -> dict:
    """Trajectories first .. first + n - 1 of (task, seed): DSRL arrays of the real steps.

    `steps` cuts the episodes short and `plan` replaces the drawn knobs (tests)."""
    gaits = GAITS[task]
    params = [np.asarray(g["params"], np.float64) for g in gaits]
    T = env.episode_len if steps is None else steps
    J = env.act_dim
    dt = env.task.dt
    plan = Plan(seed, first, n, task, T, J) if plan is None else plan
    state = env.reset_batch(episode_keys(seed, first, n))

    def act(t, state):
        obs = np.asarray(state.obs)
        which, level = plan.at(t)
        a = np.zeros((n, J))
        for k, g in enumerate(gaits):
            fb = g.get("feedback", False)
            # feedback gaits were found starting in phase: no random offset for them
            phase = plan.phase * 0.0 if fb else plan.phase
            a = np.where((which == k)[:, None], gait_actions(
                params[k], t * dt, level, phase, obs, J, fb), a)
        a = np.clip(a + plan.noise[:, t], -1.0, 1.0).astype(np.float32)
        return a

    return record_episodes(env, state, act, T, progress, progress_scale)


def make_generate(task: str):
    def generate(n_trajectories: int, seed: int, progress=None) -> dict:
        """`n_trajectories` gait episodes of `task` (DSRL arrays); `progress` is called with
        counts of requested trajectories (generated / OVERSAMPLE), as the factory's bar."""
        from r2pac_jax.tasks import get_task

        env = get_task(task).make_env(physics="mujoco")
        return in_equal_batches(n_trajectories, BATCH, lambda first, size: rollout(
            env, task, seed, first, size, progress, 1.0 / OVERSAMPLE))

    return generate


def source(task: str) -> dict:
    return dict(name="scripted periodic gaits of graded speed (speed level, level switch, "
                     "noise), density-thinned",
                generate=make_generate(task), default_trajectories=DEFAULT_TRAJECTORIES[task],
                oversample=OVERSAMPLE)


SOURCES = {name: source(name) for name in VELOCITY_TASKS if name in GAITS}
