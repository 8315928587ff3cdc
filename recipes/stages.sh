# Shared by the staged oracle scripts (oracle_h1_stages.sh, oracle_h1_gait_stages.sh,
# oracle_g1_stages.sh); source it after setting OUT (output root), PY (python) and COMMON
# (overrides every stage shares).
#
#   stage <n> <total env steps> <overrides...>
# runs recipes/oracle_ppo.py into $OUT/stage<n>, resuming $OUT/stage<n-1>/last.pt when n > 1, or
# $OUT/stage<n>/last.pt when that exists (an interrupted stage goes on where it stopped; a finished
# one has nothing left to train). Run the script again after an interruption.
# FROM_STAGE=k (environment) skips the stages before k (their checkpoints must exist).
stage() {
  local n=$1 total=$2
  shift 2
  if [ "$n" -lt "${FROM_STAGE:-1}" ]; then return 0; fi
  local resume=()
  if [ -f "$OUT/stage$n/last.pt" ]; then resume=(checkpoint.resume="$OUT/stage$n/last.pt")
  elif [ "$n" -gt 1 ]; then resume=(checkpoint.resume="$OUT/stage$((n - 1))/last.pt"); fi
  "$PY" recipes/oracle_ppo.py "${COMMON[@]}" collector.total_frames="$total" checkpoint.dir="$OUT/stage$n" \
      "${resume[@]}" "$@"
}
