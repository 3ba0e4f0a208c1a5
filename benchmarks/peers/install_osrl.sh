#!/usr/bin/env bash
# OSRL (osrl-lib 0.1.0, PyTorch CPU) in a side virtualenv: a peer to measure against, never a
# dependency of the project. Usage: bash benchmarks/peers/install_osrl.sh [DIR] (default
# ../osrl-venv/venv). The wheel ships osrl/algorithms and osrl/common only; its imports also need
# tensorboard and wandb (run it with WANDB_MODE=disabled).
set -euo pipefail
DIR="${1:-$(dirname "$0")/../../../osrl-venv/venv}"
python3 -m venv "$DIR"
# shellcheck disable=SC1091
source "$DIR/bin/activate"
pip install -q torch==2.13.0   # takes the machine's local CPU build
pip install -q --no-deps osrl-lib==0.1.0 fast-safe-rl==0.1.0 dsrl==0.1.0 pyrallis==0.3.1
pip install -q numpy h5py pyyaml tqdm scipy gymnasium typing-inspect tensorboard wandb
# CDT's Pareto augmentation (osrl/common/dataset.py) needs oapackage
pip install -q oapackage
WANDB_MODE=disabled python -c "import osrl.algorithms, osrl.common, torch; print('OSRL ready:', torch.__version__)"
