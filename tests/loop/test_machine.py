"""The machine record that a dataset card and every benchmark line carry."""
import json
import os

import jax

from r2pac_jax.machine import describe, record
from conftest import load_script


def test_describe_counts_the_cores_this_process_may_use():
    d = describe()
    assert set(d) == {"cpu", "cpu_model", "isa", "cpus", "arch", "libc"}
    assert d["cpus"] == len(os.sched_getaffinity(0))
    assert d["cpu"] and d["arch"]
    with open("/proc/cpuinfo") as f:  # the first CPU's flags, as far as the record names them
        flags = set(next(ln for ln in f if ln.startswith("flags")).split(":", 1)[1].split())
    assert d["isa"] == [x for x in ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl",
                                    "avx512_bf16", "amx_tile") if x in flags]
    assert d["cpu_model"].startswith("family ") and d["libc"].startswith("glibc")


def test_record_adds_what_a_timing_hangs_on():
    r = record()
    assert {k: r[k] for k in describe()} == describe()
    assert r["jax"] == jax.__version__ and r["backend"] == jax.default_backend()
    assert len(r["date"]) == len("2026-12-06 05:45") and r["load_avg"] >= 0


def test_benchmark_lines_carry_the_record(tmp_path, capsys):
    env_speed = load_script("benchmarks/env_speed.py")
    out = tmp_path / "speed.jsonl"
    env_speed.emit(dict(task="ReachAvoid", steps_per_s=1.0), str(out))
    line = json.loads(out.read_text())
    assert line["steps_per_s"] == 1.0 and line["cpu"] == describe()["cpu"]
    assert json.loads(capsys.readouterr().out) == line
