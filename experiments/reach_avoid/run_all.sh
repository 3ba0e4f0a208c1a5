#!/usr/bin/env bash
# The ReachAvoid experiment of the core issue: every algorithm over 3 seeds, the alpha x h grid
# (sweeps/alpha_h.toml, the paper's Figures 4-5), the alpha x penalty sensitivity sweeps, and
# re-evaluation of each trained run under the three candidate-selection rules.
# The small sensitivity sweeps run before the long alpha x h grid (about 3 h on 2 cores).
# Resumable: rerunning skips finished runs and cells (each run continues from its checkpoint).
#   bash experiments/reach_avoid/run_all.sh [OUT_DIR]     (default runs/reach_avoid)
# Then: python experiments/reach_avoid/summarise.py OUT_DIR
set -euo pipefail
OUT="${1:-runs/reach_avoid}"
PY="${PYTHON:-python}"
mkdir -p "$OUT"
for algo in r2pac bc-all bc-safe r2pac-no-penalty r2pac-no-vc r2pac-awr r2pac-awr-flow r2pac-hj; do
  if [ ! -f "$OUT/$algo/results.json" ]; then
    resume=""; [ -d "$OUT/$algo/checkpoints" ] && resume="--resume"
    "$PY" -m r2pac_jax.train --task ReachAvoid --algo "$algo" --preset quick --seeds 3 \
      --baselines none --out "$OUT/$algo" --no-progress $resume
  fi
done
"$PY" -m r2pac_jax.sweep experiments/reach_avoid/sensitivity_absorbing.toml --out "$OUT/sweep_absorbing" --no-progress
"$PY" -m r2pac_jax.sweep experiments/reach_avoid/sensitivity_direct.toml --out "$OUT/sweep_direct" --no-progress
"$PY" -m r2pac_jax.sweep sweeps/alpha_h.toml --out "$OUT/sweep_alpha_h" --no-progress
"$PY" experiments/reach_avoid/summarise.py "$OUT"
