#!/usr/bin/env bash
# The learned-behaviour data (data v2) of every MuJoCo task at DSRL's size and budget, one task
# after another, each resumable: rerun this script after a kill or a session's end and every
# task continues from its last checkpoint (finished files are skipped). Then the data checks.
#
#   nice -n 10 bash experiments/data_factory/make_learned.sh [TASK ...] > runs/make_learned.log 2>&1
#
# BUDGET_HOURS=H: each task's RL budget cut to what is expected to finish in H hours on the
# 2-core CPU (a machine that does not outlive the session loses a partial generation; the file's
# name and card record the smaller budget). Unset: DSRL's budgets.
#
# Order (the data issue): the six Car tasks and the paper's three velocity tasks first, the
# quickest first within them (estimates in GENERATION.md), then the rest, then the eight Bullet
# tasks (pybullet through --physics bullet, quickest first; AntCircle's 54M steps last).
set -uo pipefail
cd "$(dirname "$0")/../.."
TASKS=("$@")
if [ ${#TASKS[@]} -eq 0 ]; then
  TASKS=(CarGoal1 HalfCheetahVelocity SwimmerVelocity CarButton1 AntVelocity CarButton2 CarPush1
         CarPush2 CarGoal2 PointGoal1 PointButton1 HopperVelocity PointButton2 PointPush2
         PointPush1 Walker2dVelocity PointGoal2 BallRun BallCircle DroneRun CarRun DroneCircle
         CarCircle AntRun AntCircle)
fi
for t in "${TASKS[@]}"; do
  echo "== $t $(date -u +%FT%TZ)"
  # DSRL's budget, or with BUDGET_HOURS the largest expected to finish in that time (next_tasks.py)
  read -r budget f < <(python experiments/data_factory/next_tasks.py --plan "$t" \
                         ${BUDGET_HOURS:+--hours "$BUDGET_HOURS"}) || { echo "!! $t: no plan"; continue; }
  python -m r2pac_jax.data make --task "$t" --source ppo-lagrangian --budget "$budget" \
    || echo "!! $t failed ($?)"
  if [ -f "$f" ] && [ ! -f "$f.checks.json" ]; then
    echo "== checks $t $(date -u +%FT%TZ)"
    python -m r2pac_jax.data check "$f" | tail -1
  fi
done
echo "== done $(date -u +%FT%TZ)"
