#!/usr/bin/env bash
# PROTOCOL.md's runs, each cell resumable (a killed cell continues with --resume; a finished one
# is skipped):
#   nice -n 5 bash experiments/r2pac_decision/run.sh decide > runs/r2pac_decision.log 2>&1
#   nice -n 5 bash experiments/r2pac_decision/run.sh confirm WINNER >> runs/r2pac_decision.log 2>&1
# then: python experiments/r2pac_decision/decide.py
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT="${OUT:-runs/r2pac_decision}"
DECISION="HalfCheetahVelocity Walker2dVelocity HopperVelocity BallRun DroneRun CarGoal2 PointGoal2"
CONFIRM="$DECISION AntVelocity BallCircle CarButton1 PointButton1"
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
  if [ -f "$dir/results.json" ]; then echo "== $label $t $c: finished earlier"; return; fi
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
    for t in $DECISION; do for c in 0 a b c; do cell "$t" "$c" 0 seeds0-2; done; done ;;
  confirm)
    w="${2:?confirm needs the winning candidate id}"
    for t in $CONFIRM; do for c in 0 "$w"; do cell "$t" "$c" 3 seeds3-5; done; done ;;
  *) echo "usage: run.sh decide | confirm WINNER" >&2; exit 2 ;;
esac
