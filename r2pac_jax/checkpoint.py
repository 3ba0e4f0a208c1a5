"""Orbax checkpoints of the whole training state (all lanes), written atomically.

Orbax writes each step into a temporary directory and renames it when complete, so a run
killed mid-write leaves the previous checkpoint intact; `latest_step` sees only finished ones.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import jax

from r2pac_jax.config import ConfigError
from r2pac_jax.errors import R2pacError


class CheckpointUnreadable(ConfigError):
    """No checkpoint of a run reads back (each one's reason is in the message)."""


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 160 else text[:157] + "..."


# Orbax's array chunks carry no checksum of their own: bytes damaged on disk in one of them
# restore silently as other numbers. Each checkpoint therefore records the sha256 of its files
# when it is written, and a restore compares them first (checkpoints of earlier releases,
# without the record, are restored unchecked).
DIGEST = "r2pac_sha256.json"


def _file_digests(step_dir: Path) -> dict[str, str]:
    import hashlib

    out = {}
    for p in sorted(step_dir.rglob("*")):
        if p.is_file() and p.name != DIGEST:
            h = hashlib.sha256()
            with open(p, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
            out[str(p.relative_to(step_dir))] = h.hexdigest()
    return out


def write_digest(step_dir: Path) -> None:
    from r2pac_jax.io import atomic_write_json

    atomic_write_json(step_dir / DIGEST, _file_digests(step_dir))


def check_digest(step_dir: Path) -> None:
    """Raise CheckpointDamaged when a file of the checkpoint differs from its record."""
    import json

    record = step_dir / DIGEST
    if not record.is_file():
        return
    try:
        want = json.loads(record.read_text())
    except ValueError:
        raise CheckpointDamaged(f"its checksum record {record} is damaged") from None
    have = _file_digests(step_dir)
    bad = sorted(k for k in want if have.get(k) != want[k])
    if bad:
        what = "missing or changed" if any(k not in have for k in bad) else "changed"
        raise CheckpointDamaged(f"{len(bad)} of its files {what} on disk since it was written "
                                f"(sha256 differs: {', '.join(bad[:2])})")


class CheckpointDamaged(R2pacError, ValueError):
    """A checkpoint's files differ from the checksums recorded when it was written."""


class Checkpointer:
    def __init__(self, directory, max_to_keep: int = 2):
        import orbax.checkpoint as ocp

        from r2pac_jax.io import writing

        self._ocp = ocp
        self.directory = Path(directory).absolute()
        opts = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True,
                                            enable_async_checkpointing=False)
        with writing(self.directory, "the checkpoint directory"):
            self._mgr = ocp.CheckpointManager(self.directory, options=opts)

    def save(self, step: int, state: Any, meta: dict) -> None:
        from r2pac_jax.io import writing

        ocp = self._ocp
        last = self.latest_step()
        kept = (f"the last complete checkpoint, step {last}, is kept" if last is not None
                else "no earlier checkpoint exists")
        import logging

        absl = logging.getLogger("absl")
        level = absl.level
        # orbax logs a failed write's whole traceback before raising it; the raised error is
        # reported (as one line when it is a write failure, in full otherwise)
        absl.setLevel(logging.CRITICAL)
        try:
            with writing(self.directory / str(step), "the checkpoint", kept):
                self._mgr.save(step, args=ocp.args.Composite(
                    state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)),
                    force=True)
                self._mgr.wait_until_finished()
                write_digest(self.directory / str(step))
        finally:
            absl.setLevel(level)

    def latest_step(self) -> Optional[int]:
        return self._mgr.latest_step()

    def all_steps(self) -> list[int]:
        """The finished checkpoints' steps, newest first."""
        return sorted(self._mgr.all_steps(), reverse=True)

    def restore_newest_readable(self, like: Any, log=print) -> tuple[int, Any, dict]:
        """(step, state, meta) of the newest checkpoint that reads back into `like`.

        A newer one that does not (bytes damaged on disk: tensorstore's CRC error, a truncated
        file) is moved to `checkpoints-damaged/STEP` beside this directory, so that training can
        write that step again while nothing on disk is deleted, and `log` says which and why.
        If none reads back, nothing is moved and CheckpointUnreadable names each failure."""
        failures = []
        for step in self.all_steps():
            try:
                state, meta = self.restore(step, like)
            except Exception as e:  # noqa: BLE001 - every reason is reported; none is hidden
                failures.append((step, _one_line(e)))
                continue
            for bad, why in failures:
                dest = self.quarantine(bad)
                log(f"warning: checkpoint step {bad} does not read back ({why}); skipped and "
                    f"moved to {dest}; resuming from step {step}")
            return step, state, meta
        listed = "; ".join(f"step {s}: {why}" for s, why in failures)
        raise CheckpointUnreadable(
            f"--resume: no checkpoint in {self.directory} reads back ({listed}); nothing was "
            "changed. Start the run again into another --out (or move the checkpoints away "
            "and rerun without --resume)")

    def save_blocks(self, step: int, state: Any, blocks_done: int, diverged: dict) -> None:
        """A training run's checkpoint: the state and where the run stands (blocks done, its
        diverged lanes)."""
        self.save(step, state, {"blocks_done": blocks_done, "step": step,
                                "diverged": {str(k): v for k, v in diverged.items()}})

    def resume_blocks(self, like: Any, log=print) -> Optional[tuple[int, Any, int, dict]]:
        """(step, state, blocks done, diverged lanes) of the newest readable `save_blocks`
        checkpoint, or None where there is none."""
        if self.latest_step() is None:
            return None
        step, state, meta = self.restore_newest_readable(like, log=log)
        diverged = {int(k): v for k, v in meta.get("diverged", {}).items()}
        return step, state, int(meta["blocks_done"]), diverged

    def quarantine(self, step: int) -> Path:
        """Move checkpoint `step` out of orbax's sight (it would refuse to save that step again)."""
        import os

        dest_dir = self.directory.parent / f"{self.directory.name}-damaged"
        dest_dir.mkdir(parents=True, exist_ok=True)
        dest = dest_dir / str(step)
        n = 1
        while dest.exists():  # an earlier quarantine of the same step is kept too
            dest = dest_dir / f"{step}.{n}"
            n += 1
        os.replace(self.directory / str(step), dest)
        self._mgr.reload()
        return dest

    def restore(self, step: int, like: Any) -> tuple[Any, dict]:
        """Restore `step` into the structure (shapes, dtypes) of `like`."""
        ocp = self._ocp
        check_digest(self.directory / str(step))
        abstract = jax.tree_util.tree_map(ocp.utils.to_shape_dtype_struct, like)
        out = self._mgr.restore(step, args=ocp.args.Composite(
            state=ocp.args.StandardRestore(abstract), meta=ocp.args.JsonRestore()))
        return out["state"], dict(out["meta"])

    def close(self) -> None:
        self._mgr.close()


def save_policy(directory, step: int, pp: Any, meta: dict) -> None:
    """The final policy parameters of every lane ([L, ...] leaves): what `load_policy` reads.

    A resumed finished run already saved this very policy at `step`, and keeps it."""
    pol = Checkpointer(directory, max_to_keep=1)
    try:
        if pol.latest_step() != step:
            pol.save(step, pp, meta)
    finally:
        pol.close()


def policy_like(agent, lanes: int):
    """Shapes and dtypes of `lanes` lanes' policy parameters (the restore target)."""
    import jax.numpy as jnp

    from r2pac_jax.agents import algo_module

    # shapes only: any value of the per-lane scalars will do
    hp = {k: jnp.float32(0) for k in algo_module(agent.cfg.algo).HPARAMS}
    hp_l = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (lanes,)), hp)
    return jax.eval_shape(lambda k: jax.vmap(agent.policy_params)(
        jax.vmap(agent.init)(k, hp_l), hp_l), jnp.zeros((lanes, 2), jnp.uint32))


def restore_policy(directory, agent, lanes: int) -> Any:
    """The saved policy parameters of a finished run ([L, ...] leaves)."""
    pol = Checkpointer(directory, max_to_keep=1)
    try:
        step = pol.latest_step()
        if step is None:
            raise FileNotFoundError(f"{directory} holds no saved policy (it is written when "
                                    "training ends)")
        pp, _ = pol.restore(step, policy_like(agent, lanes))
    finally:
        pol.close()
    return pp
