#!/usr/bin/env bash
# The GPU measurements of benchmarks/RESULTS.md, batched into few long calls on a lent machine.
#
#   bash benchmarks/gpu_session.sh SECTION OUTDIR      SECTION: train | env | alpha_h | quality_bar | ppolag | bullet_env | gen_speed | table | efficiency
#
# The GPU machine has jax/flax/optax/orbax/chex/h5py but no mujoco and no network: carry the
# cp312 wheels in .whl/ (see benchmarks/RESULTS.md, "GPU figures") and they are installed
# first. Every step has its own time limit so one slow step cannot take the others with it;
# each step appends JSON lines to OUTDIR as it finishes.
set -u
section=${1:?section: train | env | alpha_h | quality_bar | ppolag | bullet_env | gen_speed | table | efficiency}
out=${2:?output directory}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
if ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
nvidia-smi -L
python3 -c "import jax, flax, optax, orbax.checkpoint, chex; print('jax', jax.__version__, 'flax', flax.__version__, jax.devices())"

step() {  # step LIMIT_S NAME CMD...: run CMD, appending stdout to OUTDIR/NAME.jsonl
  local limit=$1 name=$2; shift 2
  echo "=== $name: $*"
  local t0=$SECONDS
  timeout "$limit" "$@" | tee -a "$out/$name.jsonl"
  echo "=== $name: rc ${PIPESTATUS[0]} after $((SECONDS - t0)) s"
}

case $section in
  train)
    step 150 train_speed python3 benchmarks/train_speed.py --presets quick --seeds 1,4,16 \
      --blocks 3 --block-steps 1000
    step 200 train_speed python3 benchmarks/train_speed.py --presets paper --seeds 1,4 \
      --blocks 3 --block-steps 200
    step 100 sweep_speed python3 benchmarks/sweep_speed.py --cells 4 --seeds 1 --steps 1000
    step 150 sweep_speed python3 benchmarks/sweep_speed.py --cells 8 --seeds 3 --steps 2000
    ;;
  env)
    step 330 env_speed python3 benchmarks/env_speed.py stepping \
      --tasks HalfCheetahVelocity,AntVelocity,CarGoal2 --backends mjx --batches 1024,8192 \
      --steps 100 --no-fidelity
    step 200 env_speed python3 benchmarks/env_speed.py protocol \
      --tasks HalfCheetahVelocity,CarGoal2 --backends mjx --episodes 1024 --policies none,r2pac
    ;;
  alpha_h)
    step 560 alpha_h python3 -m r2pac_jax.sweep sweeps/alpha_h.toml --out /tmp/alpha_h
    python3 -m r2pac_jax.sweep report /tmp/alpha_h
    cp /tmp/alpha_h/*.csv /tmp/alpha_h/*.md /tmp/alpha_h/*.png "$out"/ 2>/dev/null
    ls -la /tmp/alpha_h
    ;;
  quality_bar)  # issue 5's table for the tasks in $TASKS (comma-separated), C MuJoCo evaluation
    step 560 quality_bar python3 experiments/data_factory/quality_bar.py --tasks "${TASKS:?}" \
      --out /tmp/quality_bar --physics mujoco
    python3 experiments/data_factory/quality_bar.py --tasks "$TASKS" --out /tmp/quality_bar \
      --report-only > "$out/quality_bar.md"
    (cd /tmp/quality_bar && tar czf "$out/quality_bar_runs.tar.gz" */*/results.json */*/config.json)
    ;;
  ppolag)  # issue 5's DSRL-recipe source on MJX for the tasks in $TASKS; cards and plots back
    export R2PAC_DATA_DIR=/tmp/ppolag
    for t in ${TASKS//,/ }; do
      step 560 ppolag python3 -m r2pac_jax.data make --task "$t" --source ppo-lagrangian \
        --physics mjx
    done
    cp /tmp/ppolag/*.json /tmp/ppolag/*.png "$out"/ 2>/dev/null
    ;;
  bullet_env)  # issue 14: the Bullet tasks' MJX re-creations at large batch, policy excluded and in
    step 270 env_speed python3 benchmarks/env_speed.py stepping \
      --tasks BallRun,DroneRun,AntRun,BallCircle,DroneCircle,CarRun,AntCircle,CarCircle \
      --backends mjx --batches 4096 --steps 20 --no-fidelity
    step 90 env_speed python3 benchmarks/env_speed.py protocol --tasks BallRun,AntRun \
      --backends mjx --episodes 1024 --policies none,r2pac
    ;;
  gen_speed)  # issue 17: the learned-behaviour generation (rollout + PPO update) on MJX, large batch
    step 150 gen_speed python3 experiments/data_factory/time_learned.py \
      --task HalfCheetahVelocity --physics mjx --envs 1024,4096 --rollout-len 100 --updates 3
    ;;
  table)  # issue 15: Table 1 cells, one process per entry of $ALGOS side by side, on $TASKS. An
    # entry is ALGO or ALGO:PRESET:STEPS (PRESET default $PRESET or quick; STEPS per phase, default
    # $STEPS or the preset's); 3 seeds, 20 episodes, C MuJoCo evaluation as on the CPU. The data
    # come from $R2PAC_DATA_DIR (carry the pinned files). Finished cells come back in one archive.
    export XLA_PYTHON_CLIENT_PREALLOCATE=false  # the processes share the GPU
    for e in ${ALGOS//,/ }; do
      IFS=: read -r a p n <<< "$e"
      p=${p:-${PRESET:-quick}} n=${n:-${STEPS:-}}
      tag=${e//:/_}  # one output folder per entry, named as it is written
      (t0=$SECONDS; timeout "${LIMIT:-480}" python3 -m r2pac_jax.table --tasks "${TASKS:?}" \
        --algos "$a" --seeds 3 --episodes 20 --preset "$p" ${n:+--steps "$n"} --physics mujoco \
        --out "/tmp/table_$tag" --no-progress > "$out/table_$tag.log" 2>&1
       echo "=== table $e: rc $? after $((SECONDS - t0)) s") &
    done
    wait
    (cd /tmp && tar czf "$out/table_cells.tar.gz" table_*/manifest.json table_*/*/*/results.json \
      table_*/*/*/config.json table_*/*/*/eval.jsonl table_*/*/*/metrics.jsonl)
    ;;
  efficiency)  # issue 56: FLOP efficiency at the paper preset, 1 and 4 lanes, default and bf16;
    # then the Table-1 GPU-hour estimate from the measured 4-lane rates. EFF_PRESET=quick BLOCKS=1
    # rehearse it on the CPU.
    p=${EFF_PRESET:-paper}
    step 230 efficiency python3 benchmarks/efficiency.py --presets "$p" --lanes 1,4 \
      --algos r2pac,cpq,fisor --blocks "${BLOCKS:-3}"
    step 150 efficiency python3 benchmarks/efficiency.py --presets "$p" --lanes 1,4 \
      --algos r2pac,cpq,fisor --blocks "${BLOCKS:-3}" --set matmul_precision=bf16
    step 160 efficiency python3 benchmarks/efficiency.py --presets "$p" --lanes 4 \
      --algos bc-all-mlp,coptidice,cdt,trebi --blocks "${BLOCKS:-3}"
    python3 benchmarks/efficiency.py --table "$out/efficiency.jsonl" > "$out/efficiency.md"
    # the paper's text lies beside the repository, which the GPU machine may not have: then run
    # gpu_hours.py on the returned efficiency.jsonl at home
    paper=${PAPER:-../shared/paper/r2pac-paper.txt}
    if [ -f "$paper" ]; then
      for prec in default bf16; do
        python3 benchmarks/gpu_hours.py "$out/efficiency.jsonl" --precision $prec \
          --paper "$paper" --out "$out/gpu_hours_$prec.md"
      done
    else echo "=== no $paper here: python benchmarks/gpu_hours.py OUT/efficiency.jsonl at home"; fi
    ;;
  *) echo "unknown section $section (train | env | alpha_h | quality_bar | ppolag | bullet_env | gen_speed | table | efficiency)"; exit 2 ;;
esac
