#!/usr/bin/env bash
# Where a generation update's time goes, task by task, at each task's own recipe (issue 53 item
# 3): time_learned.py --recipe for a few updates (the first, compiling, left out), one JSON line
# per task into OUT. Run it with every background job paused: the rates are the machine's own.
#   bash experiments/data_factory/profile_generation.sh OUT.jsonl [TASK ...]
set -uo pipefail
cd "$(dirname "$0")/../.."
out="${1:?usage: profile_generation.sh OUT.jsonl [TASK ...]}"; shift
tasks="${*:-AntCircle DroneCircle AntRun CarCircle CarGoal2 PointGoal2 CarPush2 CarRun CarPush1 CarButton2 Walker2dVelocity PointPush1 PointPush2 PointButton2 HopperVelocity}"
for t in $tasks; do
  python experiments/data_factory/time_learned.py --task "$t" --recipe --updates "${UPDATES:-4}" \
    2>/dev/null | tail -n 1 >> "$out" || echo "!! $t failed" >&2
  tail -n 1 "$out"
done
