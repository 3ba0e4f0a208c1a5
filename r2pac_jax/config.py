"""Configuration of a run: the generic part every algorithm shares, and its algorithm's own part.

`Config` holds what the training loop, the data view, evaluation and checkpoints need (task,
steps, batch, chunk length, seeds, periods); `Config.agent` is the algorithm's own frozen
dataclass, defined beside the algorithm in `agents/<module>.py` with its presets and variants.
Users see one flat namespace of keys (`--set quantile_alpha=0.8`, sweep files, `make_config`
overrides); `cfg.quantile_alpha` reads through to `cfg.agent`.

Values are resolved in this order: defaults, the task's values (the paper's Table 4), the preset
(generic, then the algorithm's), the algorithm variant's switches, explicit overrides.
"""
from __future__ import annotations

import dataclasses
import json
from typing import Any, Optional

from r2pac_jax.agents import algo_module, algo_names
from r2pac_jax.errors import ConfigError
from r2pac_jax.ranges import check_range
from r2pac_jax.tasks import TaskSpec, get_task

__all__ = ["Config", "ConfigError", "check_range", "make_config", "validate_config",
           "field_types", "default_hparams", "check_hparams", "resolve_preset", "switch_keys",
           "refuse_user_key", "GENERIC_KEYS", "RUN_IDENTITY", "PRESETS"]


@dataclasses.dataclass(frozen=True)
class Config:
    task: str
    algo: str = "r2pac"
    preset: str = "quick"
    # optimisation loop
    steps: int = 20_000  # per phase (R2PAC's two_phase schedule has two)
    batch_size: int = 256
    block_steps: int = 1000  # the block: steps per compiled scan, metrics (R2PAC: its threshold)
    # per block; named threshold_every before 2026-12-07 (RENAMED)
    # data view
    chunk_len: int = 5
    discount: float = 0.99
    reward_scale: float = 1.0
    cost_scale: float = 1.0
    data_filter: str = "all"  # all | safe (episodes with cost <= kappa)
    # run
    seeds: int = 3
    eval_every: int = 5_000
    eval_episodes: int = 20
    checkpoint_every: int = 5_000
    # the networks' matmuls: default | highest | bf16 (precision.py); losses and Adam stay f32
    matmul_precision: str = "default"
    agent: Any = None  # the algorithm's config (agents/<module>.py)

    def __getattr__(self, name: str):
        # the flat view: cfg.quantile_alpha is cfg.agent.quantile_alpha
        agent = self.__dict__.get("agent")
        if not name.startswith("__") and agent is not None and name in _names(type(agent)):
            return getattr(agent, name)
        raise AttributeError(f"{type(self).__name__} of {self.__dict__.get('algo')!r} has no "
                             f"key {name!r}")

    # ---- derived -------------------------------------------------------------------------
    @property
    def phases(self) -> tuple[str, ...]:
        return algo_module(self.algo).phases(self.agent)

    @property
    def total_steps(self) -> int:
        return self.steps * len(self.phases)

    def flat(self) -> dict:
        """Every key of the flat namespace with its value (generic and the algorithm's)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "agent"}
        out.update(dataclasses.asdict(self.agent))
        return out

    def replace(self, **values) -> "Config":
        """A copy with flat-namespace keys changed (generic or the algorithm's), validated."""
        gen = {k: v for k, v in values.items() if k in GENERIC_KEYS}
        own = {k: v for k, v in values.items() if k not in GENERIC_KEYS}
        unknown = set(own) - _names(type(self.agent))
        if unknown:
            raise ConfigError(f"{self.algo} has no config key(s) {sorted(unknown)}; its keys: "
                              f"{', '.join(sorted(field_types(self.algo)))}")
        new = dataclasses.replace(self, agent=dataclasses.replace(self.agent, **own), **gen)
        validate_config(new)
        return new

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True)

    @staticmethod
    def from_dict(d: dict) -> "Config":
        """From `to_json`'s layout, or the flat layout of runs made before the agent protocol."""
        d = {RENAMED.get(k, k): v for k, v in d.items()}  # a run's config.json of an older name
        cls = algo_module(d.get("algo", "r2pac")).CONFIG
        own = d.pop("agent", None)
        if own is None:  # flat: the algorithm's keys sit beside the generic ones
            own = {k: d[k] for k in _names(cls) if k in d}
        own = {k: tuple(v) if isinstance(v, list) else v for k, v in own.items()
               if k in _names(cls)}
        gen = {k: v for k, v in d.items() if k in GENERIC_KEYS}
        return Config(**gen, agent=cls(**own))


def _names(cls) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


GENERIC_KEYS = _names(Config) - {"agent"}
# Keys renamed since runs were first written: config.json files keep the old name (read as the
# new one by `Config.from_dict`); a user who writes the old name is told the new one.
RENAMED = {"threshold_every": "block_steps"}
# Set by the command line's own arguments (or the sweep file's axes), never by --set.
RUN_IDENTITY = ("task", "algo", "preset")

# Generic preset values; each algorithm adds its own (agents/<module>.py: PRESETS).
PRESETS: dict[str, dict[str, Any]] = {
    # Table 3 of the paper.
    "paper": dict(steps=600_000, batch_size=1024, eval_every=50_000, checkpoint_every=50_000,
                  block_steps=1000),
    # Few steps: minutes on a 2-core CPU.
    "quick": dict(steps=20_000, batch_size=256, eval_every=5_000, checkpoint_every=5_000,
                  block_steps=500),
}

CHOICES = {"data_filter": ("all", "safe"), "matmul_precision": ("default", "highest", "bf16")}


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


def switch_keys() -> dict[str, list[str]]:
    """Keys that algorithm variants set (e.g. reward_penalty for r2pac-no-penalty) -> the
    `--algo` names that set them: users choose these with --algo, never with --set."""
    out: dict[str, list[str]] = {}
    for name in algo_names():
        for k in algo_module(name).VARIANTS[name]:
            out.setdefault(k, []).append(name)
    return out


def refuse_user_key(key: str, where: str) -> None:
    """ConfigError for keys a user sets elsewhere (the run's identity, seeds, variant switches)
    or no longer under that name."""
    if key in RENAMED:
        raise ConfigError(f"{where} {key}=...: {key} is now called {RENAMED[key]}; write "
                          f"{RENAMED[key]}=... instead")
    if key in RUN_IDENTITY:
        raise ConfigError(f"{where} {key}=...: {key} is chosen with --{key}, not here")
    if key == "seeds":
        raise ConfigError(f"{where} seeds=...: the number of seeds is chosen with --seeds N "
                          "(sweep files: `seeds = N` at the top level)")
    sw = switch_keys()
    if key in sw:
        raise ConfigError(f"{where} {key}=...: {key} is an algorithm switch; choose the variant "
                          f"with --algo ({', '.join(sw[key])})")


def field_types(algo: str) -> dict[str, type]:
    """Every key `algo` accepts (generic and its own) -> the type of its default."""
    cls = algo_module(algo).CONFIG
    gen = Config(task="x")
    out = {k: type(getattr(gen, k)) for k in GENERIC_KEYS}
    own = cls()
    out.update({f.name: type(getattr(own, f.name)) for f in dataclasses.fields(cls)})
    return out


def make_config(task: str | TaskSpec, algo: str = "r2pac", preset: str = "quick",
                overrides: Optional[dict] = None) -> Config:
    """Task values, then the presets, then the algorithm's switches, then explicit overrides."""
    spec = task if isinstance(task, TaskSpec) else get_task(task)
    mod = algo_module(algo)
    preset, _ = resolve_preset(preset)
    types = field_types(algo)
    values: dict[str, Any] = dict(task=spec.name, algo=algo, preset=preset,
                                  chunk_len=spec.chunk_len, reward_scale=spec.reward_scale,
                                  cost_scale=spec.cost_scale)
    values.update(mod.task_values(spec))
    values.update(PRESETS[preset])
    own_preset = mod.PRESETS.get(preset, {})
    values.update(own_preset(spec) if callable(own_preset) else own_preset)
    values.update(mod.VARIANTS[algo])
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    for k, v in given.items():
        if k in RUN_IDENTITY:
            raise ConfigError(f"{k} cannot be overridden ({k}={v!r}); choose it with --{k}")
        if k in RENAMED:
            refuse_user_key(k, "config key")
        if k not in types:
            raise ConfigError(f"unknown config key {k!r} for {algo}; known keys: "
                              f"{', '.join(sorted(types))}")
        pinned = mod.FIXED.get(k)
        if pinned is not None and v != pinned:
            raise ConfigError(f"{algo} {mod.FIXED_WHY.get(k, 'pins this key')} ({k} is fixed "
                              f"at {pinned!r}); {k}={v!r} does not apply to it: drop the option")
        values[k] = v
    values.update(mod.FIXED)
    gen = {k: v for k, v in values.items() if k in GENERIC_KEYS}
    own = {k: v for k, v in values.items() if k not in GENERIC_KEYS}
    cfg = Config(**gen, agent=mod.CONFIG(**own))
    validate_config(cfg, spec)
    return cfg


def validate_config(cfg: Config, spec: Optional[TaskSpec] = None) -> None:
    """Raise ConfigError naming the bad value and what would be valid."""
    spec = spec or get_task(cfg.task)
    for k, choices in CHOICES.items():
        if getattr(cfg, k) not in choices:
            raise ConfigError(f"{k}={getattr(cfg, k)!r} is not one of {choices}")
    check_range("discount", cfg.discount, 0, 1, low_open=True, high_open=True)
    if cfg.chunk_len < 1:
        raise ConfigError(f"chunk_len must be >= 1, got {cfg.chunk_len}")
    if cfg.chunk_len > spec.episode_len:
        raise ConfigError(f"chunk_len {cfg.chunk_len} is longer than an episode of {spec.name} "
                          f"({spec.episode_len} steps); choose --chunk-len <= {spec.episode_len}")
    for k in ("steps", "batch_size", "seeds", "block_steps", "eval_every", "checkpoint_every"):
        if getattr(cfg, k) < 1:
            raise ConfigError(f"{k} must be >= 1, got {getattr(cfg, k)}")
    for k in ("reward_scale", "cost_scale"):
        check_range(k, getattr(cfg, k), 0, low_open=True)
    if cfg.eval_episodes < 0:
        raise ConfigError(f"eval_episodes must be >= 0, got {cfg.eval_episodes}")
    for k in ("steps", "eval_every", "checkpoint_every"):
        if getattr(cfg, k) % cfg.block_steps:
            raise ConfigError(f"{k}={getattr(cfg, k)} must be a multiple of block_steps="
                              f"{cfg.block_steps} (the compiled block)")
    algo_module(cfg.algo).validate(cfg.agent)


def default_hparams(cfg: Config) -> dict:
    """The vmappable scalars of cfg's algorithm at their configured values: {name: f32 []}.

    These may differ between the lanes of one compiled program (see `lanes.Lanes`)."""
    import jax.numpy as jnp

    return {k: jnp.float32(getattr(cfg, k)) for k in algo_module(cfg.algo).HPARAMS}


def check_hparams(algo: str, values: dict) -> None:
    """Check per-lane values of the vmappable scalars (each grid cell is checked too)."""
    algo_module(algo).check_hparams(values)
