#!/usr/bin/env bash
# One task's whole v2 chain, each step resumable, so a session can start it first and leave it:
#   1. the learned-behaviour file at DSRL's size and its data checks (make_learned.sh);
#   2. the file's card, plots, checks and gzipped training log copied into results_v2/TASK
#      (committed);
#   3. the quality bar v2 (quality_bar.py --data v2, archived into results_v2) and its report;
#   4. Table 1's cells for ALGOS (python -m r2pac_jax.table) in TABLE_OUT, the quality bar's
#      r2pac and bc-all-mlp runs reused (same configuration, seeds and file: the table checks
#      each one's identity before reading it back); the cells' results and configs, manifest and
#      table then go into the committed experiments/table1/cpu-quick.
#
#   nice -n 5 bash experiments/data_factory/task_pipeline.sh TASK [TASK ...] > runs/pipeline.log 2>&1
#
# Environment: QB_OUT (runs/quality_bar_v2), TABLE_OUT (runs/table1), ALGOS (Table 1's columns,
# default bc-all-mlp,cpq,coptidice,r2pac: the quickest on a CPU; add bcq-lag,cdt,fisor where the
# session has the hours: `python -m r2pac_jax.table ... --estimate`), TABLE_COLUMNS (the committed
# table's columns, default all eight: bc-all-mlp,cpq,coptidice,bcq-lag,cdt,trebi,fisor,r2pac;
# a column left out drops its cells from table.md), SKIP_TABLE=1 to stop after 3,
# BUDGET_HOURS=H to fit each task's RL budget to H hours (make_learned.sh; recorded in the card).
# A killed pipeline restarts where it stopped: finished files, runs and cells are skipped.
set -uo pipefail
cd "$(dirname "$0")/../.."
QB_OUT="${QB_OUT:-runs/quality_bar_v2}"
TABLE_OUT="${TABLE_OUT:-runs/table1}"
ALGOS="${ALGOS:-bc-all-mlp,cpq,coptidice,r2pac}"
TABLE_COLUMNS="${TABLE_COLUMNS:-bc-all-mlp,cpq,coptidice,bcq-lag,cdt,trebi,fisor,r2pac}"  # the committed table's
ARCHIVE=experiments/data_factory/results_v2
TABLE_KEEP=experiments/table1/cpu-quick  # the committed CPU table (results and configs only)
for t in "$@"; do
  echo "== $t: data $(date -u +%FT%TZ)"
  bash experiments/data_factory/make_learned.sh "$t" || { echo "!! $t: data failed"; continue; }
  read -r _ f < <(python experiments/data_factory/next_tasks.py --plan "$t" \
                   ${BUDGET_HOURS:+--hours "$BUDGET_HOURS"})
  if [ ! -f "$f" ] || [ ! -f "$f.checks.json" ]; then
    echo "!! $t: no file or no checks at $f"; continue
  fi
  stem="${f%.hdf5}"
  mkdir -p "$ARCHIVE/$t"
  for x in "$f.checks.json" "$stem.json" "$stem.png" "$stem.training.png"; do
    [ -f "$x" ] && cp "$x" "$ARCHIVE/$t/"
  done
  # the training log (return, cost, limit, multiplier per update), compressed: a later machine
  # can check that it regenerates the same updates before spending hours on a whole file
  [ -f "$stem.log.jsonl" ] && gzip -9nc "$stem.log.jsonl" > "$ARCHIVE/$t/$(basename "$stem").log.jsonl.gz"
  echo "== $t: quality bar $(date -u +%FT%TZ)"
  python experiments/data_factory/quality_bar.py --tasks "$t" --data v2 --out "$QB_OUT" \
    --archive "$ARCHIVE" || { echo "!! $t: quality bar failed"; continue; }
  python experiments/data_factory/quality_bar.py --report-only --out "$ARCHIVE" | tail -3
  if [ "${SKIP_TABLE:-0}" = 1 ]; then continue; fi
  echo "== $t: Table 1 cells ($ALGOS) $(date -u +%FT%TZ)"
  for a in r2pac bc-all-mlp; do  # the quality bar's runs are these cells
    if [ -f "$QB_OUT/$t/$a/results.json" ] && [ ! -e "$TABLE_OUT/$t/$a" ]; then
      mkdir -p "$TABLE_OUT/$t" && cp -r "$QB_OUT/$t/$a" "$TABLE_OUT/$t/$a"
    fi
  done
  # the committed table's cells and tasks join TABLE_OUT first (its own runs win), so every
  # earlier task keeps its row
  python -m r2pac_jax.table --tasks "$t" --algos "$ALGOS" --seeds 3 --episodes 20 \
    --out "$TABLE_OUT" --merge-from "$TABLE_KEEP" --no-progress || echo "!! $t: table failed"
  # back into the committed table, finished cells only (a failed or partial table keeps the
  # cells it finished), each as its results and config; the manifest is merged, not copied,
  # so a chain running beside this one keeps its task; then the committed table, every column
  # that has cells (bcq-lag's made apart included)
  python -m r2pac_jax.table --table-only --algos "$TABLE_COLUMNS" --seeds 3 --episodes 20 \
    --out "$TABLE_KEEP" --merge-from "$TABLE_OUT" --results-only --no-progress | tail -2 \
    || echo "!! $t: table-only failed"
done
echo "== pipeline done $(date -u +%FT%TZ)"
