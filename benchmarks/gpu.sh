#!/usr/bin/env bash
# agentax on a GPU beside this machine's CPU, in under 10 minutes: PPO on CartPole-v1 with 1, 64 and
# 1,024 seeds, PQN on Breakout-MinAtar and SAC on Pendulum-v1 with 8 seeds, each the whole
# `agentax train` command on the default device (the GPU: no flag) and on the CPU (benchmarks/gpu.py).
#
#   benchmarks/gpu.sh [WHEELS]
#
# Needs Python with JAX and its CUDA plugin installed (`pip install "jax[cuda12]"`, the jax version of
# requirements.lock). WHEELS: a folder of agentax's other dependencies as wheels (on a machine with the
# internet: `pip download -d WHEELS -r requirements.lock gymnax==1.0.1 --no-deps`), installed from it
# with no index; without it, agentax and its dependencies must be importable already.
# AGENTAX_GPU_SCALE=0.1 runs a tenth of the steps.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
if [ $# -ge 1 ]; then
	"$PYTHON" -m pip install --quiet --no-index --find-links "$1" -e .
	"$PYTHON" -m pip install --quiet --no-index --find-links "$1" --no-deps gymnax==1.0.1
fi
"$PYTHON" -c "import agentax, gymnax" || { echo "gpu.sh: agentax or gymnax is not importable: give WHEELS" >&2; exit 2; }
exec timeout 600 "$PYTHON" benchmarks/gpu.py
