#!/usr/bin/env bash
# An H1 oracle from scratch with a gait clock (docs/history/results-sessions-1-12.md, run 11): the G1 schedule
# (recipes/oracle_g1_stages.sh) plus, from the first step, a 0.8 s gait clock in the observation
# (env.gait_period), a reward for feet whose contacts follow it (gait_contact), a swing-foot
# clearance target (feet_clearance) and a slip penalty (feet_slip); from stage 2 on, a reward for
# legs that follow the clock's swing reference (gait_joint_ref). Seed 0, 2 CPU cores.
#
# Not a recipe that works yet: run 11 stopped 2.71M steps into stage 2 with the robot still
# standing (no stepping in phase). Stage 1 took 23 min; stages 2-3 below are the planned rest.
#
#   bash recipes/oracle_h1_gait_stages.sh [output root, default outputs/oracle_h1_gait]
#   FROM_STAGE=2 bash recipes/oracle_h1_gait_stages.sh   # stage 1 done: go on from its checkpoint
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-outputs/oracle_h1_gait}
PY=${PYTHON:-python}
COMMON=(env.num_envs=256 env.categories=[randommix] env.variants=4 model.layers=[256,128,64]
        model.init_std=0.5 model.max_std=0.5 ppo.entropy_coeff=0.001 checkpoint.every=10 logger.backend=csv
        env.gait_period=0.8)
# after each stage's reward_overrides (which replaces the whole dict). Stage 1 rewards the clock's
# contact pattern (weight 2) and penalises low swings (-100) and slipping feet. From stage 2 on the
# legs are also rewarded for following the clock's swing reference (gait_joint_ref, 8) and the
# clearance penalty is -20: with the contact term alone (at 2 or 5) the stage-1 policy kept
# standing (docs/history/results-sessions-1-12.md, run 11).
GAIT1=(+env.reward_overrides.gait_contact=2.0 +env.reward_overrides.feet_clearance=-100.0
       +env.reward_overrides.feet_slip=-1.0)
GAIT=(+env.reward_overrides.gait_contact=2.0 +env.reward_overrides.gait_joint_ref=8.0
      +env.reward_overrides.feet_clearance=-20.0 +env.reward_overrides.feet_slip=-1.0)

source recipes/stages.sh  # stage <n> <total env steps> <overrides...>

# 1: balance first: slow command, large alive bonus, fall penalty
stage 1 2703360 env.levels=[0] env.cmd_speed=0.3 "env.reward_overrides={alive: 10.0, termination: -100.0}" "${GAIT1[@]}"
# 2: walk: faster command, smaller alive bonus
stage 2 7004160 env.levels=[0] env.cmd_speed=0.5 "env.reward_overrides={alive: 4.0, termination: -100.0}" "${GAIT[@]}"
# 3: levels 0 and 1 in equal shares, worlds restart there; desired KL 0.02
stage 3 11999232 "env.levels=[0,1]" env.curriculum=false env.cmd_speed=0.5 \
    "env.reward_overrides={alive: 4.0, termination: -100.0}" checkpoint.keep_curriculum=false ppo.desired_kl=0.02 \
    "${GAIT[@]}"

"$PY" recipes/export_policy.py "$OUT/stage3/last.pt" "$OUT/oracle_h1_gait.pt"
