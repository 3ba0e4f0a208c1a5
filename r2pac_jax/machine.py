"""What machine a figure or a file came from, said one way everywhere: a generated dataset's
card and every benchmark record carry these fields, so two of them can be compared."""
from __future__ import annotations

import os
import platform
import time


# the instruction sets a float result may hang on (XLA, numpy and C libraries pick code paths
# by them at run time)
ISA_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl", "avx512_bf16", "amx_tile")


def describe() -> dict:
    """{cpu: model name, cpu_model: "family F model M" (one name covers CPUs of several
    generations), isa: ISA_FLAGS present, cpus: CPUs this process may run on, arch, libc}: what
    a regeneration's numerics and a speed figure may hang on besides the software versions (a
    pinned Walker2dVelocity file did not regenerate on another "AMD EPYC")."""
    cpu = platform.processor() or None
    fields: dict = {}
    try:
        with open("/proc/cpuinfo") as f:
            for ln in f:
                if not ln.strip():
                    break  # the first CPU's block is enough
                k, _, v = ln.partition(":")
                fields.setdefault(k.strip(), v.strip())
    except OSError:  # not Linux
        pass
    cpu = fields.get("model name", cpu)
    family, model = fields.get("cpu family"), fields.get("model")
    flags = set(fields.get("flags", "").split())
    # The affinity mask, not os.cpu_count(): a container or `taskset` may give fewer cores.
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    libc = " ".join(platform.libc_ver()).strip() or None
    return dict(cpu=cpu, cpu_model=f"family {family} model {model}" if family else None,
                isa=[f for f in ISA_FLAGS if f in flags], cpus=cpus, arch=platform.machine(),
                libc=libc)


def training_device() -> dict:
    """{backend: "cpu" | "gpu" | "tpu", device_kind: e.g. "NVIDIA H100 80GB HBM3" or "cpu",
    devices: how many}: what trained a run (a table names rows trained on another kind)."""
    import jax

    d = jax.devices()
    return dict(backend=jax.default_backend(), device_kind=d[0].device_kind, devices=len(d))


def record() -> dict:
    """describe() plus what a timing also hangs on: {cpu, cpu_model, isa, cpus, arch, libc, jax,
    backend, device, date ("YYYY-MM-DD HH:MM"), load_avg (1-minute load when measured; None off
    Unix)}."""
    import jax

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return dict(describe(), jax=jax.__version__, backend=jax.default_backend(),
                device=str(jax.devices()[0]), date=time.strftime("%Y-%m-%d %H:%M"),
                load_avg=load)
