"""What a run shows and writes as it goes: one metrics row per lane and block, one evaluation
row per lane (JSONL and TensorBoard, `metrics_log.py`), and the progress bar (steps/s, ETA, the
phase, the agent's progress metrics and the last evaluation's scores)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from r2pac_jax.io import sigint_deferred
from r2pac_jax.metrics_log import MetricsLog


class RunProgress:
    """Logs of the run in `out` (rows past `resume_step` dropped) and, with `bar`, a progress
    bar over `total` steps starting at `initial`."""

    def __init__(self, out: Path, lanes, block_steps: int, progress_metrics: dict,
                 resume_step: int, bar: bool, total: int, initial: int, desc: str):
        self.lanes, self.block_steps, self.progress_metrics = lanes, block_steps, progress_metrics
        self.logs = MetricsLog(out, resume_step=resume_step)
        self.bar = None
        if bar:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, unit="step", dynamic_ncols=True,
                            desc=desc, smoothing=0.1)

    def block(self, metrics: dict, step: int, phase: str, dt: float) -> None:
        """One metrics row per lane; a block's rows are logged whole (Ctrl-C waits)."""
        with sigint_deferred():
            for lane in range(self.lanes.size):
                row = {k: float(v[lane]) for k, v in metrics.items()}
                row.update(step=step, phase=phase, lane=lane, seed=self.lanes.seeds[lane],
                           steps_per_s=self.block_steps / dt)
                self.logs.write("metrics", row, tb_prefix=f"train/lane{lane}")

    def evaluation(self, res: dict, step: int) -> None:
        for lane in range(self.lanes.size):
            self.logs.write("eval", dict(
                step=step, lane=lane, seed=self.lanes.seeds[lane],
                normalized_reward=float(res["normalized_reward"][lane]),
                normalized_cost=float(res["normalized_cost"][lane]),
                mean_return=float(res["returns"][lane].mean()),
                mean_cost=float(res["costs"][lane].mean()),
                mean_length=float(res["mean_length"][lane]),
                terminal_share=float(res["terminal_share"][lane]),
                **{k: float(v[lane]) for k, v in res["diagnostics"].items()}),
                tb_prefix=f"eval/lane{lane}")

    def show(self, phase: str, metrics: dict, last_eval: Optional[dict]) -> None:
        if self.bar is None:
            return
        post = {"phase": phase}
        for label, name in self.progress_metrics.items():
            if name in metrics:
                post[label] = f"{float(np.mean(metrics[name])):.3g}"
        if last_eval is not None:
            post["rew"] = f"{float(np.mean(last_eval['normalized_reward'])):.2f}"
            post["cost"] = f"{float(np.mean(last_eval['normalized_cost'])):.2f}"
        self.bar.set_postfix(post, refresh=False)
        self.bar.update(self.block_steps)

    def close_bar(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def close(self) -> None:
        self.close_bar()
        self.logs.close()
