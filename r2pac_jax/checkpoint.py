"""Orbax checkpoints of the whole training state (all lanes), written atomically.

Orbax writes each step into a temporary directory and renames it when complete, so a run
killed mid-write leaves the previous checkpoint intact; `latest_step` sees only finished ones.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import jax


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
        finally:
            absl.setLevel(level)

    def latest_step(self) -> Optional[int]:
        return self._mgr.latest_step()

    def restore(self, step: int, like: Any) -> tuple[Any, dict]:
        """Restore `step` into the structure (shapes, dtypes) of `like`."""
        ocp = self._ocp
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

    from r2pac_jax.config import default_hparams

    hp = default_hparams(agent.cfg)
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
