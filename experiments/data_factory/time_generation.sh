#!/usr/bin/env bash
# Time `python -m r2pac_jax.data make` per task on a fresh cache and summarise each card.
#   R2PAC_DATA_DIR=/tmp/r2pac_gen bash experiments/data_factory/time_generation.sh CarGoal2 ...
# Output: one line per task (wall seconds, load averages before/after, card summary).
set -u
: "${R2PAC_DATA_DIR:?set R2PAC_DATA_DIR to a scratch directory}"
export R2PAC_DATA_DIR
for task in "$@"; do
  before=$(cut -d' ' -f1-3 /proc/loadavg)
  start=$(date +%s.%N)
  python -m r2pac_jax.data make --task "$task" --source scripted > "$R2PAC_DATA_DIR/$task.log" 2>&1
  rc=$?
  end=$(date +%s.%N)
  after=$(cut -d' ' -f1-3 /proc/loadavg)
  card=$(ls "$R2PAC_DATA_DIR"/"$task"-generated-s0-n*.json 2>/dev/null | head -1)
  summary=$(python - "$card" <<'PY'
import json, sys
try:
    c = json.load(open(sys.argv[1]))
except Exception as e:  # no card: the make failed
    print(f"no card ({e})"); sys.exit()
print(f"n={c['trajectories']} generated={(c.get('thinning') or {}).get('generated')} "
      f"safe={c['safe_trajectories']} unsafe={c['unsafe_trajectories']} "
      f"return=[{c['return_range'][0]:.2f}, {c['return_range'][1]:.2f}] "
      f"norm_return=[{c['normalised_return_range'][0]:.2f}, {c['normalised_return_range'][1]:.2f}] "
      f"cost=[{c['cost_range'][0]:.0f}, {c['cost_range'][1]:.0f}]")
PY
)
  printf '%s rc=%s wall=%.0fs load_before=(%s) load_after=(%s) %s\n' "$task" "$rc" \
    "$(echo "$end - $start" | bc)" "$before" "$after" "$summary"
done
