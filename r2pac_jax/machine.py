"""What machine a figure or a file came from, said one way everywhere: a generated dataset's
card and every benchmark record carry these fields, so two of them can be compared."""
from __future__ import annotations

import os
import platform
import time


def describe() -> dict:
    """{cpu: model name, cpus: CPUs this process may run on, arch}: what a regeneration's
    numerics and a speed figure may hang on besides the software versions."""
    cpu = platform.processor() or None
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")),
                       cpu)
    except OSError:  # not Linux
        pass
    # The affinity mask, not os.cpu_count(): a container or `taskset` may give fewer cores.
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return dict(cpu=cpu, cpus=cpus, arch=platform.machine())


def training_device() -> dict:
    """{backend: "cpu" | "gpu" | "tpu", device_kind: e.g. "NVIDIA H100 80GB HBM3" or "cpu",
    devices: how many}: what trained a run (a table names rows trained on another kind)."""
    import jax

    d = jax.devices()
    return dict(backend=jax.default_backend(), device_kind=d[0].device_kind, devices=len(d))


def record() -> dict:
    """describe() plus what a timing also hangs on: {cpu, cpus, arch, jax, backend, device,
    date ("YYYY-MM-DD HH:MM"), load_avg (1-minute load when measured; None off Unix)}."""
    import jax

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return dict(describe(), jax=jax.__version__, backend=jax.default_backend(),
                device=str(jax.devices()[0]), date=time.strftime("%Y-%m-%d %H:%M"),
                load_avg=load)
