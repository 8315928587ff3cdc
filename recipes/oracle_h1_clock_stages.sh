#!/usr/bin/env bash
# Runs 12 and 13 (docs/history/results-sessions-1-12.md): the schedule that taught H1 to walk (recipes/oracle_h1_stages.sh,
# runs 4-9: entropy bonus 0.01 and an uncapped action std while it learns to walk) with a 0.8 s
# gait clock in the observation (env.gait_period) and only positive gait terms from the first
# step: feet whose contacts follow the clock (gait_contact, 2) and legs that follow its swing
# reference (gait_joint_ref, 4). No clearance or slip penalty: run 11 (the G1 schedule with the
# std capped at 0.5 from the start, and those penalties) kept standing. Stages 3-6 of the
# original schedule are merged into one. Seed 0, 2 CPU cores.
#
# FEEDFORWARD (default 0) is env.gait_feedforward: the gain of the clock's swing reference added
# to the PD targets, so that the legs step by themselves and the policy learns a residual.
# Run 12 is FEEDFORWARD=0 (stopped in stage 2: it shuffled like run 5, the gait terms at their
# standing values); run 13 is FEEDFORWARD=1.
#
#   bash recipes/oracle_h1_clock_stages.sh [output root, default outputs/oracle_h1_clock]
#   FEEDFORWARD=1 bash recipes/oracle_h1_clock_stages.sh outputs/oracle_h1_feedforward   # run 13
#   FROM_STAGE=2 bash recipes/oracle_h1_clock_stages.sh   # stage 1 done: go on from its checkpoint
#
# STAGE3_CURRICULUM=1 (default 0) keeps the terrain curriculum on in stage 3: the worlds go on from
# the levels stage 2's curriculum left them on (up to level 4), with desired KL 0.01 instead of
# 0.02. Run 14 is run 13's stages 1-2 followed by such a stage 3:
#   mkdir -p outputs/oracle_h1_run14 && ln -s ../oracle_h1_feedforward/stage1 ../oracle_h1_feedforward/stage2 outputs/oracle_h1_run14/
#   FEEDFORWARD=1 STAGE3_CURRICULUM=1 FROM_STAGE=3 bash recipes/oracle_h1_clock_stages.sh outputs/oracle_h1_run14
#
# ROBOT (default h1) is env.robot: ROBOT=g1 runs the same schedule on G1 (G1 run 2 in docs/history/results-sessions-1-12.md):
#   ROBOT=g1 FEEDFORWARD=1 STAGE3_CURRICULUM=1 bash recipes/oracle_h1_clock_stages.sh outputs/oracle_g1_run2
#
# AMPLITUDE (default 0.25) is env.gait_amplitude, the swing reference's fold in rad. The feedforward
# alone lifts H1's foot 5.4 cm at 0.25 and G1's 4.3 cm; G1 run 3 tries 0.45 (10.3 cm) to reach level 1
# (G1 run 3 in docs/history/results-sessions-1-12.md):
#   ROBOT=g1 AMPLITUDE=0.45 FEEDFORWARD=1 STAGE3_CURRICULUM=1 bash recipes/oracle_h1_clock_stages.sh outputs/oracle_g1_run3
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-outputs/oracle_h1_clock}
PY=${PYTHON:-python}
ROBOT=${ROBOT:-h1}
COMMON=(env.robot="$ROBOT" env.num_envs=256 env.categories=[randommix] env.variants=4 model.layers=[256,128,64] model.init_std=0.5
        checkpoint.every=10 logger.backend=csv env.gait_period=0.8 env.gait_feedforward="${FEEDFORWARD:-0}"
        env.gait_amplitude="${AMPLITUDE:-0.25}")
# after each stage's reward_overrides (which replaces the whole dict)
GAIT=(+env.reward_overrides.gait_contact=2.0 +env.reward_overrides.gait_joint_ref=4.0)

source recipes/stages.sh  # stage <n> <total env steps> <overrides...>

# 1: balance first: slow command, large alive bonus, fall penalty
stage 1 2703360 env.levels=[0] env.cmd_speed=0.3 "env.reward_overrides={alive: 10.0, termination: -100.0}" "${GAIT[@]}"
# 2: walk: faster command, smaller alive bonus
stage 2 8540160 env.levels=[0] env.cmd_speed=0.5 "env.reward_overrides={alive: 4.0, termination: -100.0}" "${GAIT[@]}"
# 3: levels 0 and 1 in equal shares, worlds restart there; entropy 0.001, std capped at 0.5, desired KL 0.02
if [ "${STAGE3_CURRICULUM:-0}" = 1 ]; then
  LEVELS3=(env.curriculum=true checkpoint.keep_curriculum=true ppo.desired_kl=0.01)
else
  LEVELS3=("env.levels=[0,1]" env.curriculum=false checkpoint.keep_curriculum=false ppo.desired_kl=0.02)
fi
stage 3 14991360 "${LEVELS3[@]}" env.cmd_speed=0.5 "env.reward_overrides={alive: 4.0, termination: -100.0}" \
    ppo.entropy_coeff=0.001 model.max_std=0.5 "${GAIT[@]}"

"$PY" recipes/export_policy.py "$OUT/stage3/last.pt" "$OUT/oracle_$ROBOT.pt"
