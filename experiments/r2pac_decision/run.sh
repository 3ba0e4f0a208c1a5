#!/usr/bin/env bash
# PROTOCOL.md's runs, each cell resumable (a killed cell continues with --resume; a finished one
# is skipped):
#   nice -n 5 bash experiments/r2pac_decision/run.sh decide > runs/r2pac_decision.log 2>&1
#   nice -n 5 bash experiments/r2pac_decision/run.sh confirm WINNER >> runs/r2pac_decision.log 2>&1
# then: python experiments/r2pac_decision/decide.py
#   bash experiments/r2pac_decision/run.sh keep   # finished cells' results into the repo
# A cell kept in experiments/r2pac_decision/cells (committed) is never run again: a machine and
# its runs/ folder may not outlive a session, the repo does.
# TASKS="BallRun DroneRun" runs only those decision tasks (their order kept as given), so that two
# lanes on two cores each make their own files and cells without touching the other's.
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT="${OUT:-runs/r2pac_decision}"
KEPT="experiments/r2pac_decision/cells"
DECISION="HalfCheetahVelocity Walker2dVelocity HopperVelocity BallRun DroneRun CarGoal2 PointGoal2"
CONFIRM="$DECISION AntVelocity BallCircle CarButton1 PointButton1"
only() {  # the tasks of list $1 that TASKS names (all of them where TASKS is unset)
  [ -z "${TASKS:-}" ] && { echo "$1"; return; }
  local t out=""
  for t in $TASKS; do
    case " $1 " in *" $t "*) out="$out $t" ;;
      *) echo "TASKS: $t is not one of this stage's tasks ($1)" >&2; return 2 ;; esac
  done
  echo "$out"
}
left_out() {  # the task is in left_out.json (decide.py's record of tasks left out)
  grep -q "\"$1\"" experiments/r2pac_decision/left_out.json 2>/dev/null
}
left_out_of_confirmation() {  # ... or in the confirmation's own record
  left_out "$1" || grep -q "\"$1\"" experiments/r2pac_decision/left_out_confirmation.json 2>/dev/null
}
sets_of() {
  case "$1" in
    0) echo "" ;;
    a) echo "--set critic_layer_norm=true" ;;
    b) echo "--set vc_nonneg=true" ;;
    c) echo "--set critic_layer_norm=true --set vc_nonneg=true" ;;
    *) echo "unknown candidate $1" >&2; exit 2 ;;
  esac
}
cell() {  # task, candidate, seed offset, seeds label
  local t="$1" c="$2" off="$3" label="$4" f dir
  dir="$OUT/$label/$t/$c"
  if [ -f "$dir/results.json" ] || [ -f "$KEPT/$label/$t/$c/results.json" ]; then
    echo "== $label $t $c: finished earlier"; return
  fi
  f="$(python experiments/r2pac_decision/decide.py --file "$t")" \
    || { echo "!! $t: no pinned file"; return; }
  f="$(printf '%s\n' "$f" | tail -n 1)"  # the path is the last line, whatever else printed
  [ -f "$f" ] || { echo "!! $t: no pinned file ($f)"; return; }
  echo "== $label $t $c $(date -u +%FT%TZ)"
  local resume=""
  [ -f "$dir/config.json" ] && resume="--resume"
  # shellcheck disable=SC2046
  python -m r2pac_jax.train --task "$t" --dataset "$f" --seeds 3 --seed-offset "$off" \
    --baselines none --eval-episodes 20 --no-progress --out "$dir" $resume $(sets_of "$c") \
    || echo "!! $label $t $c failed"
}
case "${1:-decide}" in
  decide)
    tasks="$(only "$DECISION")" || exit 2
    for t in $tasks; do
      if left_out "$t"; then
        echo "== $t: left out of the decision (left_out.json)"; continue
      fi
      for c in 0 a b c; do cell "$t" "$c" 0 seeds0-2; done
    done ;;
  confirm)
    w="${2:?confirm needs the winning candidate id}"
    tasks="$(only "$CONFIRM")" || exit 2
    for t in $tasks; do
      if left_out_of_confirmation "$t"; then
        echo "== $t: left out of the confirmation (left_out*.json)"; continue
      fi
      for c in 0 "$w"; do cell "$t" "$c" 3 seeds3-5; done
    done ;;
  rerun)  # a kept baseline cell (candidate 0) whose run left with its machine, trained again
    # into $OUT-rerun for writeup.py --selection (its policy) and its training log; same
    # command, seeds and file, so its scores must equal the kept ones (said, never overwritten)
    tasks="$(only "$DECISION")" || exit 2
    for t in $tasks; do
      left_out "$t" && continue
      k="$KEPT/seeds0-2/$t/0"; d="$OUT/seeds0-2/$t/0"
      [ -f "$k/results.json" ] || { echo "== rerun $t: no kept baseline cell"; continue; }
      [ -d "$d/policy" ] && { echo "== rerun $t: its run is here ($d)"; continue; }
      OUT="$OUT-rerun" KEPT=/nonexistent cell "$t" 0 0 seeds0-2
      python - "$k/results.json" "$OUT-rerun/seeds0-2/$t/0/results.json" <<'PY'
import json, sys
a, b = (json.load(open(f)) for f in sys.argv[1:])
key = ("normalized_reward", "normalized_cost")
same = all(a[k]["per_seed"] == b[k]["per_seed"] for k in key)
print(("== rerun equal to the kept cell: " if same else "!! rerun differs from the kept cell: ")
      + "; ".join(f"{k} {a[k]['per_seed']} / {b[k]['per_seed']}" for k in key))
PY
    done ;;
  keep)  # each finished cell's results, config and logs (the write-up's training diagnostics:
    # writeup.py); its checkpoints stay in runs/
    for f in "$OUT"/*/*/*/results.json; do
      [ -f "$f" ] || continue
      d="$(dirname "$f")"; k="$KEPT/${d#"$OUT"/}"
      mkdir -p "$k" && cp "$d/config.json" "$k/" || continue
      for j in eval.jsonl metrics.jsonl; do [ -f "$d/$j" ] && cp "$d/$j" "$k/"; done
      cp "$d/results.json" "$k/" && echo "kept $k"  # last: it marks the cell kept
    done ;;
  *) echo "usage: run.sh decide | confirm WINNER | rerun | keep" >&2; exit 2 ;;
esac
