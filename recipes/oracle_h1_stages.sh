#!/usr/bin/env bash
# The H1 oracle committed as checkpoints/oracle_h1.pt, trained from scratch in six stages
# (docs/history/results-sessions-1-12.md runs 4-9). Each stage resumes the previous stage's checkpoint (networks, optimiser,
# rng, env state) under new settings and stops at the env-step count where the next one took
# over. About 99 min of training on 2 CPU cores, 14.99M env steps, seed 0.
#
#   bash recipes/oracle_h1_stages.sh [output root, default outputs/oracle_h1_stages]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-outputs/oracle_h1_stages}
PY=${PYTHON:-python}
COMMON=(env.num_envs=256 env.categories=[randommix] env.variants=4 model.layers=[256,128,64] model.init_std=0.5
        checkpoint.every=10 logger.backend=csv)

source recipes/stages.sh  # stage <n> <total env steps> <overrides...>

# 1 (run 4): balance first: slow command, large alive bonus, fall penalty
stage 1 2703360 env.levels=[0] env.cmd_speed=0.3 "env.reward_overrides={alive: 10.0, termination: -100.0}"
# 2 (run 5): walk: faster command, smaller alive bonus
stage 2 8540160 env.levels=[0] env.cmd_speed=0.5 "env.reward_overrides={alive: 4.0, termination: -100.0}"
# 3 (run 6): worlds restart on levels 0-1; entropy bonus 0.01 -> 0.001 (the action std had doubled)
stage 3 9584640 "env.levels=[0,1]" env.cmd_speed=0.5 "env.reward_overrides={alive: 4.0, termination: -100.0}" \
    ppo.entropy_coeff=0.001 checkpoint.keep_curriculum=false
# 4 (run 7): curriculum off: levels 0 and 1 in equal shares (the curriculum had sent level 1 back to 0)
stage 4 10813440 "env.levels=[0,1]" env.curriculum=false env.cmd_speed=0.5 \
    "env.reward_overrides={alive: 4.0, termination: -100.0}" ppo.entropy_coeff=0.001 checkpoint.keep_curriculum=false
# 5 (run 8): action std capped at 0.5 (it was 1.03)
stage 5 13824000 "env.levels=[0,1]" env.curriculum=false env.cmd_speed=0.5 \
    "env.reward_overrides={alive: 4.0, termination: -100.0}" ppo.entropy_coeff=0.001 model.max_std=0.5
# 6 (run 9): desired KL 0.01 -> 0.02 (the adaptive learning rate sat at 1e-5 - 5e-5)
stage 6 14991360 "env.levels=[0,1]" env.curriculum=false env.cmd_speed=0.5 \
    "env.reward_overrides={alive: 4.0, termination: -100.0}" ppo.entropy_coeff=0.001 model.max_std=0.5 \
    ppo.desired_kl=0.02

"$PY" recipes/export_policy.py "$OUT/stage6/last.pt" "$OUT/oracle_h1.pt"
