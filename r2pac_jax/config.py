"""Configuration: one frozen dataclass, the presets and the algorithm variants.

Per-task values (quantile alpha, penalty C, chunk length h, reward and cost scale) come from the
task registry (`tasks.py`, the paper's Table 4); the presets give everything else (Table 3 for
`paper`; small nets and few steps for `quick`). Variants are config values that switch small
pure pieces of the agent, never separate training loops.
"""
from __future__ import annotations

import dataclasses
import json
from typing import Any, NamedTuple, Optional

import jax.numpy as jnp

from r2pac_jax.tasks import TaskSpec, get_task


class ConfigError(ValueError):
    pass


@dataclasses.dataclass(frozen=True)
class Config:
    task: str
    algo: str = "r2pac"
    preset: str = "quick"
    # optimisation
    steps: int = 20_000  # per phase (critic phase, then policy phase) for two_phase
    batch_size: int = 256
    lr: float = 3e-4
    hidden_dims: tuple = (128, 128, 128)
    actor_hidden_dims: tuple = (128, 128, 128)  # the AWR Gaussian actor: a 3-layer MLP
    layer_norm: bool = False
    schedule: str = "two_phase"  # two_phase | joint
    # IQL critics
    discount: float = 0.99
    expectile: float = 0.9
    polyak: float = 0.005
    num_critics: int = 2
    chunk_len: int = 5
    reward_scale: float = 1.0
    cost_scale: float = 1.0
    # safety threshold and penalty
    quantile_alpha: float = 0.9
    penalty_c: float = 1.0
    penalty_mode: str = "absorbing"  # absorbing: target -C/(1-g); direct: target -C
    threshold_source: str = "dataset"  # dataset | batch
    threshold_every: int = 1000  # also the block: steps per compiled scan, metrics per block
    threshold_subset: int = 65536
    # policy
    guidance_scale: float = 2.0
    cfg_dropout: float = 0.1
    flow_steps: int = 32
    num_candidates: int = 16
    selection: str = "min_qc"  # min_qc | safe_then_reward | first
    awr_temperature: float = 6.0
    awr_clip: float = 100.0
    time_embed_dim: int = 16
    # variant switches (set by `algo`, see ALGOS)
    actor: str = "cfg_flow"  # cfg_flow | awr_flow | bc_flow | awr_gaussian | bc_gaussian
    reward_penalty: bool = True  # False: "w/o Vbar_r" (unpenalised V_r in safe states)
    unsafe_branch: bool = True  # False: "w/o V_c" (reward advantage labels everywhere)
    cost_critic: str = "discounted"  # discounted | hj (feasibility, Eq. 42)
    data_filter: str = "all"  # all | safe (BC-safe: episodes with cost <= kappa)
    train_critics: bool = True
    # run
    seeds: int = 3
    eval_every: int = 5_000
    eval_episodes: int = 20
    checkpoint_every: int = 5_000

    # ---- derived -------------------------------------------------------------------------
    @property
    def phases(self) -> tuple[str, ...]:
        if not self.train_critics:
            return ("actor",)
        return ("critic", "actor") if self.schedule == "two_phase" else ("joint",)

    @property
    def total_steps(self) -> int:
        return self.steps * len(self.phases)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True)

    @staticmethod
    def from_dict(d: dict) -> "Config":
        d = dict(d)
        for k in ("hidden_dims", "actor_hidden_dims"):
            if k in d:
                d[k] = tuple(d[k])
        return Config(**d)


# The algorithms of the paper's ablations and the first baselines, as config overrides.
ALGOS: dict[str, dict[str, Any]] = {
    "r2pac": {},
    "r2pac-no-penalty": {"reward_penalty": False},
    "r2pac-no-vc": {"unsafe_branch": False},
    "r2pac-awr": {"actor": "awr_gaussian"},
    "r2pac-awr-flow": {"actor": "awr_flow"},
    "r2pac-hj": {"cost_critic": "hj"},
    "bc-all": {"actor": "bc_flow", "train_critics": False, "selection": "first"},
    "bc-safe": {"actor": "bc_flow", "train_critics": False, "selection": "first",
                "data_filter": "safe"},
}

PRESETS: dict[str, dict[str, Any]] = {
    # Table 3 of the paper.
    "paper": dict(steps=600_000, batch_size=1024, hidden_dims=(512, 512, 512, 512),
                  actor_hidden_dims=(512, 512, 512), flow_steps=32, num_candidates=16,
                  eval_every=50_000, checkpoint_every=50_000, threshold_every=1000),
    # Small nets and few steps: minutes on a 2-core CPU.
    # 3x128 runs ~160 critic steps/s on 2 cores (3x256: ~77; benchmarks/RESULTS.md).
    "quick": dict(steps=20_000, batch_size=256, hidden_dims=(128, 128, 128),
                  actor_hidden_dims=(128, 128, 128), flow_steps=32, num_candidates=16,
                  eval_every=5_000, checkpoint_every=5_000, threshold_every=500,
                  threshold_subset=16384),
}

CHOICES = {
    "schedule": ("two_phase", "joint"),
    "penalty_mode": ("absorbing", "direct"),
    "threshold_source": ("dataset", "batch"),
    "selection": ("min_qc", "safe_then_reward", "first"),
    "actor": ("cfg_flow", "awr_flow", "bc_flow", "awr_gaussian", "bc_gaussian"),
    "cost_critic": ("discounted", "hj"),
    "data_filter": ("all", "safe"),
}


def resolve_preset(preset: str) -> tuple[str, str]:
    """`auto` -> `paper` on an accelerator, `quick` on a CPU. Returns (preset, reason)."""
    if preset == "auto":
        import jax

        backend = jax.default_backend()
        chosen = "quick" if backend == "cpu" else "paper"
        return chosen, f"--preset auto chose '{chosen}' (JAX backend: {backend})"
    if preset not in PRESETS:
        raise ConfigError(f"unknown preset {preset!r}; choose auto, {', '.join(PRESETS)}")
    return preset, f"preset '{preset}'"


def make_config(task: str | TaskSpec, algo: str = "r2pac", preset: str = "quick",
                overrides: Optional[dict] = None) -> Config:
    """Task values, then the preset, then the algo's switches, then explicit overrides."""
    spec = task if isinstance(task, TaskSpec) else get_task(task)
    if algo not in ALGOS:
        raise ConfigError(f"unknown algo {algo!r}; choose one of {', '.join(ALGOS)}")
    preset, _ = resolve_preset(preset)
    values: dict[str, Any] = dict(
        task=spec.name, algo=algo, preset=preset, chunk_len=spec.chunk_len,
        quantile_alpha=spec.quantile_alpha, penalty_c=spec.penalty_c,
        reward_scale=spec.reward_scale, cost_scale=spec.cost_scale,
    )
    values.update(PRESETS[preset])
    values.update(ALGOS[algo])
    for k, v in (overrides or {}).items():
        if v is None:
            continue
        if k not in {f.name for f in dataclasses.fields(Config)}:
            raise ConfigError(f"unknown config key {k!r}; known keys: "
                              f"{', '.join(f.name for f in dataclasses.fields(Config))}")
        values[k] = v
    cfg = Config.from_dict(values)
    validate_config(cfg, spec)
    return cfg


def validate_config(cfg: Config, spec: Optional[TaskSpec] = None) -> None:
    """Raise ConfigError naming the bad value and what would be valid."""
    for k, choices in CHOICES.items():
        if getattr(cfg, k) not in choices:
            raise ConfigError(f"{k}={getattr(cfg, k)!r} is not one of {choices}")
    check_hparams(cfg.quantile_alpha, cfg.penalty_c, cfg.guidance_scale)
    if not 0.0 < cfg.expectile < 1.0:
        raise ConfigError(f"expectile must be in (0, 1), got {cfg.expectile}")
    if not 0.0 < cfg.discount < 1.0:
        raise ConfigError(f"discount must be in (0, 1), got {cfg.discount}")
    if cfg.chunk_len < 1:
        raise ConfigError(f"chunk_len must be >= 1, got {cfg.chunk_len}")
    if spec is not None and cfg.chunk_len > spec.episode_len:
        raise ConfigError(f"chunk_len {cfg.chunk_len} is longer than an episode of {spec.name} "
                          f"({spec.episode_len} steps); choose --chunk-len <= {spec.episode_len}")
    for k in ("steps", "batch_size", "flow_steps", "num_candidates", "seeds", "threshold_every",
              "eval_every", "checkpoint_every", "threshold_subset", "num_critics"):
        if getattr(cfg, k) < 1:
            raise ConfigError(f"{k} must be >= 1, got {getattr(cfg, k)}")
    if cfg.eval_episodes < 0:
        raise ConfigError(f"eval_episodes must be >= 0, got {cfg.eval_episodes}")
    for k in ("steps", "eval_every", "checkpoint_every"):
        if getattr(cfg, k) % cfg.threshold_every:
            raise ConfigError(f"{k}={getattr(cfg, k)} must be a multiple of threshold_every="
                              f"{cfg.threshold_every} (the compiled block)")


def check_hparams(alpha, penalty_c, guidance_scale) -> None:
    """The scalar hyperparameters a sweep may vary (also checked per grid cell)."""
    import numpy as np

    a = np.asarray(alpha, dtype=float)
    if not np.all((a > 0.0) & (a < 1.0)):
        raise ConfigError(f"quantile_alpha must lie in (0, 1), got {alpha}")
    if not np.all(np.asarray(penalty_c, dtype=float) >= 0.0):
        raise ConfigError(f"penalty_c must be >= 0, got {penalty_c}")
    if not np.all(np.asarray(guidance_scale, dtype=float) >= 0.0):
        raise ConfigError(f"guidance_scale must be >= 0, got {guidance_scale}")


class HParams(NamedTuple):
    """Scalars that may differ between vmapped lanes of one compiled program."""

    quantile_alpha: jnp.ndarray
    penalty_c: jnp.ndarray
    guidance_scale: jnp.ndarray

    @staticmethod
    def from_config(cfg: Config) -> "HParams":
        return HParams(jnp.float32(cfg.quantile_alpha), jnp.float32(cfg.penalty_c),
                       jnp.float32(cfg.guidance_scale))


HPARAM_KEYS = HParams._fields
