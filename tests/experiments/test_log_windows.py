"""log_windows.py: windowed means of a generation's training log."""
import gzip
import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "experiments" / "data_factory" / "log_windows.py"


def test_windows_average_the_updates_that_finished_episodes(tmp_path):
    rows = [dict(update=u, env_steps=u * 100_000, cost_limit=100.0 - u, episode_return=float(u),
                 episode_cost=10.0 * u, multiplier=0.5, finished=int(u != 2),
                 steps_per_s=1000.0 * u) for u in range(1, 6)]
    log = tmp_path / "x.log.jsonl.gz"
    with gzip.open(log, "wt") as f:
        f.writelines(json.dumps(r) + "\n" for r in rows)
    out = subprocess.run([sys.executable, str(SCRIPT), str(log), "--every", "0.5"],
                         capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[0] == "5 updates; env steps/s mean 3000, 5th-95th 1200-4800"
    # the window 0.25M +-0.25M holds updates 1-5; update 2 finished no episode and is left out:
    # limits 99, 97, 96, 95 -> 96.75; returns 1, 3, 4, 5 -> 3.25
    limit, ret, cost, mult = map(float, out[2].split()[1:])
    assert (limit, ret, cost, mult) == (96.8, 3.25, 32.5, 0.5)
