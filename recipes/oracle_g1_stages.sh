#!/usr/bin/env bash
# A G1 oracle from scratch in three resumed stages: the H1 schedule (recipes/oracle_h1_stages.sh)
# condensed with what the H1 stages taught (docs/history/results-sessions-1-12.md, runs 4-9): the action std capped at 0.5
# and entropy 0.001 from the start, then levels 0-1 in equal shares. ~78 min on 2 CPU cores,
# 9.83M env steps, seed 0 (docs/history/results-sessions-1-12.md, "G1 oracle"). Committed as checkpoints/oracle_g1.pt.
#
#   bash recipes/oracle_g1_stages.sh [output root, default outputs/oracle_g1_stages]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-outputs/oracle_g1_stages}
PY=${PYTHON:-python}
COMMON=(env.robot=g1 env.num_envs=256 env.categories=[randommix] env.variants=4 model.layers=[256,128,64]
        model.init_std=0.5 model.max_std=0.5 ppo.entropy_coeff=0.001 checkpoint.every=10 logger.backend=csv)

source recipes/stages.sh  # stage <n> <total env steps> <overrides...>

# 1: balance first: slow command, large alive bonus, fall penalty
stage 1 2703360 env.levels=[0] env.cmd_speed=0.3 "env.reward_overrides={alive: 10.0, termination: -100.0}"
# 2: walk: faster command, smaller alive bonus
stage 2 8540160 env.levels=[0] env.cmd_speed=0.5 "env.reward_overrides={alive: 4.0, termination: -100.0}"
# 3: levels 0 and 1 in equal shares, worlds restart there; desired KL 0.02
stage 3 9830400 "env.levels=[0,1]" env.curriculum=false env.cmd_speed=0.5 \
    "env.reward_overrides={alive: 4.0, termination: -100.0}" checkpoint.keep_curriculum=false ppo.desired_kl=0.02

"$PY" recipes/export_policy.py "$OUT/stage3/last.pt" "$OUT/oracle_g1.pt"
