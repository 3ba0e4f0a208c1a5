#!/usr/bin/env bash
# The runs of PROTOCOL.md (issue 56): R2PAC quick, seeds 0-2, per task and matmul precision.
#   OUT=runs/precision bash experiments/precision/run.sh      (a killed run continues)
set -u
out=${OUT:-runs/precision}
# highest last: on the CPU it is bit-identical to default (tests/loop/test_precision.py)
for mode in ${MODES:-default bf16 highest}; do
  for task in ${TASKS:-ReachAvoid HalfCheetahVelocity}; do
    dir=$out/$task/$mode
    if [ -f "$dir/results.json" ]; then echo "== kept $task $mode"; continue; fi
    resume=""; [ -f "$dir/config.json" ] && resume="--resume"
    echo "== $task $mode $(date -u +%FT%TZ)"
    python -m r2pac_jax.train --task "$task" --algo r2pac --preset quick --seeds 3 \
      --baselines none --set matmul_precision="$mode" --out "$dir" --no-progress $resume \
      || echo "!! $task $mode failed"
  done
done
