"""The memory a run needs against what the machine has, checked before anything is allocated.

The need is XLA's own: each phase's block is compiled for abstract inputs (shapes only, from
`jax.eval_shape`), and its memory analysis gives the bytes of its arguments, outputs and
temporaries. Nothing of the run is allocated for it, and the compiled block is the one the run
then calls (jit finds it in its cache), so the check costs no extra compilation.

What is available: on an accelerator, the device's limit less what is in use; on a CPU, the
kernel's MemAvailable, capped by the memory cgroup's limit less its usage (a container's or a
batch job's limit is what an allocation actually meets).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Optional

import jax
import jax.numpy as jnp

from r2pac_jax.config import ConfigError

# A need above this share of what is available is warned about: the estimate is XLA's buffers,
# and what training actually adds to the process's memory measured 1.04x it for r2pac and 1.49x
# for bc-all-mlp (benchmarks/RESULTS.md, "The memory check's estimate").
WARN_SHARE = 0.6


class MemoryShortfall(ConfigError):
    """The requested lanes, batch and networks need more memory than is available."""


@dataclasses.dataclass
class Need:
    """Bytes one compiled block needs beyond what is already allocated."""

    state: int  # the training state of all lanes (held throughout)
    step: int  # the block's outputs and temporaries, less what aliases its inputs
    lanes: int

    @property
    def total(self) -> int:
        return self.state + self.step


def gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 / 10 else f"{n / 2**20:.0f} MiB"


def tree_bytes(tree) -> int:
    return int(sum(x.size * jnp.dtype(x.dtype).itemsize for x in jax.tree_util.tree_leaves(tree)))


def block_need(init, blocks: dict, hp, data, lanes: int) -> Need:
    """The need of the largest of `blocks` ({phase: jitted lane-vmapped block}) for `lanes`
    lanes. `init(keys[L], hp) -> state` and the blocks are `loop.compiled`'s; `data` is the
    (already resident) data view, which is not counted."""
    keys = jax.ShapeDtypeStruct((lanes, 2), jnp.uint32)
    state = jax.eval_shape(init, keys, hp)
    state_bytes = tree_bytes(state)
    step = 0
    for block in blocks.values():
        ma = block.lower(state, hp, data).compile().memory_analysis()
        if ma is None:  # a backend without the analysis: the state alone, twice (in and out)
            step = max(step, state_bytes)
            continue
        step = max(step, int(ma.output_size_in_bytes + ma.temp_size_in_bytes
                             - ma.alias_size_in_bytes))
    return Need(state=state_bytes, step=step, lanes=lanes)


def _read_int(path: Path) -> Optional[int]:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _cgroup_dirs() -> list[Path]:
    """This process's memory cgroup directories (v2, then v1), most specific first."""
    root = Path("/sys/fs/cgroup")
    out = []
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        lines = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _, controllers, rel = parts
        rel = rel.lstrip("/")
        if controllers == "":  # v2
            out.append(root / rel)
        elif "memory" in controllers.split(","):  # v1
            out.append(root / "memory" / rel)
    out += [root, root / "memory"]
    return [d for d in out if d.is_dir()]


def cgroup_remaining() -> Optional[tuple[int, int]]:
    """(limit, bytes still allowed) of this process's memory cgroup, or None without a limit.
    Reclaimable page cache (inactive files) counts as allowed."""
    for d in _cgroup_dirs():
        limit = _read_int(d / "memory.max") or _read_int(d / "memory.limit_in_bytes")
        if limit is not None:
            limit = min(limit, _hierarchical_limit(d) or limit)
        if limit is None or limit >= 2**60:  # 'max' or v1's 'unlimited' (a huge number)
            continue
        used = _read_int(d / "memory.current") or _read_int(d / "memory.usage_in_bytes") or 0
        inactive = 0
        try:
            for line in (d / "memory.stat").read_text().splitlines():
                k, _, v = line.partition(" ")
                if k in ("inactive_file", "total_inactive_file"):
                    inactive = int(v)
                    break
        except (OSError, ValueError):
            pass
        return limit, max(0, limit - used + inactive)
    return None


def _hierarchical_limit(d: Path) -> Optional[int]:
    """cgroup v1: the lowest limit on the way to the root (a parent's limit binds a child)."""
    try:
        for line in (d / "memory.stat").read_text().splitlines():
            k, _, v = line.partition(" ")
            if k == "hierarchical_memory_limit" and v.isdigit():
                return int(v)
    except OSError:
        pass
    return None


def mem_available() -> Optional[int]:
    """The kernel's MemAvailable in bytes, or None where /proc/meminfo is absent."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def available() -> tuple[Optional[int], str]:
    """(bytes this process may still allocate where training runs, where that figure comes
    from); (None, why) when it cannot be told."""
    dev = jax.local_devices()[0]
    if dev.platform != "cpu":
        stats = dev.memory_stats() or {}
        if "bytes_limit" in stats:
            n = len(jax.local_devices())
            free = stats["bytes_limit"] - stats.get("bytes_in_use", 0)
            return free * n, f"{n} x {dev.device_kind} memory"
        return None, f"{dev.device_kind} reports no memory limit"
    host = mem_available()
    cg = cgroup_remaining()
    if cg is not None and (host is None or cg[1] < host):
        return cg[1], f"the memory cgroup's limit of {gib(cg[0])} less its usage"
    if host is None:
        return None, "neither /proc/meminfo nor a cgroup limit is readable"
    return host, "MemAvailable of /proc/meminfo"


def check_fits(need: Need, what: str, fix: str, log=print,
               have: Optional[tuple[Optional[int], str]] = None) -> None:
    """Refuse (MemoryShortfall) when `need` exceeds what is available, warn when it is close.
    `what` names the run ('CarGoal2 r2pac'), `fix` the options that shrink it."""
    free, source = have or available()
    if free is None:
        log(f"note: memory not checked ({source}); {what} needs about {gib(need.total)}")
        return
    per_lane = need.total / max(need.lanes, 1)
    detail = (f"{what}: {need.lanes} lanes need about {gib(need.total)} (state "
              f"{gib(need.state)}, a training block's outputs and temporaries {gib(need.step)}; "
              f"about {gib(per_lane)} a lane) against {gib(free)} available ({source})")
    if need.total > free:
        fits = free * need.lanes // need.total
        raise MemoryShortfall(f"{detail}; nothing was allocated. Fix: {fix} (about {fits} "
                              "lanes fit), or run on a machine with more memory")
    if need.total > WARN_SHARE * free:
        log(f"warning: {detail}: close to the limit; evaluation and other processes need "
            "memory too")


def check_lanes_fit(init, blocks: dict, hp, data, lanes: int, what: str, batch_size: int,
                    log=print) -> None:
    """Refuse, before anything is allocated, `lanes` lanes of a run that do not fit in memory
    (`block_need`, `check_fits`); R2PAC_MEMORY_CHECK=off skips it."""
    import os

    if os.environ.get("R2PAC_MEMORY_CHECK", "on").lower() in ("off", "0", "false"):
        return
    check_fits(block_need(init, blocks, hp, data, lanes), what,
               "fewer lanes (--seeds, or fewer cells in a sweep) or a smaller batch "
               f"(--set batch_size=..., now {batch_size})", log=log)
