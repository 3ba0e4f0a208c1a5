"""Metrics in plain files (JSONL) and TensorBoard, resumable without duplicated rows."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Optional

from r2pac_jax.io import atomic_write_text


def _rows(f: Path) -> list[dict]:
    """The rows of a JSONL file; a line cut short by a failed write (only the last can be) is
    dropped."""
    out = []
    for ln in f.read_text().splitlines():
        if ln.strip():
            try:
                out.append(json.loads(ln))
            except json.JSONDecodeError:
                continue
    return out


class MetricsLog:
    """Appends one JSON object per line to `DIR/NAME.jsonl`; mirrors scalars to TensorBoard.

    resume_step: rows with a step beyond it (written after the checkpoint a resumed run starts
    from) are dropped, so a resumed run's files equal an uninterrupted run's.
    """

    def __init__(self, directory, resume_step: Optional[int] = None,
                 tensorboard: Optional[bool] = None):
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        if resume_step is not None:
            for f in self.dir.glob("*.jsonl"):
                keep = [json.dumps(r, sort_keys=True) for r in _rows(f)
                        if r.get("step", 0) <= resume_step]
                atomic_write_text(f, "".join(k + "\n" for k in keep))
        self._tb = None
        if tensorboard is None:  # default: on, unless R2PAC_NO_TENSORBOARD=1
            tensorboard = os.environ.get("R2PAC_NO_TENSORBOARD") != "1"
        if tensorboard:
            try:
                from tensorboardX import SummaryWriter

                kw = {"purge_step": resume_step + 1} if resume_step is not None else {}
                self._tb = SummaryWriter(str(self.dir / "tb"), **kw)
            except ImportError:  # pragma: no cover - tensorboardX is a dependency
                self._tb = None

    def write(self, name: str, row: dict, tb_prefix: Optional[str] = None) -> None:
        from r2pac_jax.io import writing

        path = self.dir / f"{name}.jsonl"
        with writing(path, "the log", "rows written so far are kept"):
            with open(path, "a") as f:
                f.write(json.dumps(row, sort_keys=True) + "\n")
        if self._tb is not None and "step" in row:
            prefix = tb_prefix or name
            for k, v in row.items():
                if k != "step" and isinstance(v, (int, float)) and not isinstance(v, bool):
                    self._tb.add_scalar(f"{prefix}/{k}", v, row["step"])

    def read(self, name: str) -> list[dict]:
        f = self.dir / f"{name}.jsonl"
        if not f.exists():
            return []
        return _rows(f)

    def close(self) -> None:
        if self._tb is not None:
            self._tb.flush()
            self._tb.close()
