#!/usr/bin/env bash
# Runs one mlnseq stage for `make reproduce`: prints its one-line summary (plus any warning or note)
# with the time it took, appends the full output to stages.log and a timing row to timings.tsv in
# RUNS_DIR (read by `mlnseq report`). On failure the full output is shown. With MLNSEQ_STAGE_SERVER set
# (`make reproduce` sets it), the stage runs in scripts/stage_server.py's preloaded process.
# usage: scripts/timed_stage.sh RUNS_DIR MLNSEQ STAGE [ARGS...]
set -uo pipefail
runs_dir=$1 mlnseq=$2 stage=$3
shift 3
mkdir -p "$runs_dir"
output=$(mktemp)
trap 'rm -f "$output"' EXIT
runner=("$mlnseq")
if [ -n "${MLNSEQ_STAGE_SERVER:-}" ]; then
  runner=("$(dirname "$mlnseq")/python" "$(dirname "$0")/stage_server.py" run "$MLNSEQ_STAGE_SERVER" "$mlnseq")
fi
started=$(date +%s.%N)
COLUMNS=1000 "${runner[@]}" "$stage" "$@" >"$output" 2>&1
status=$?
seconds=$(awk -v a="$started" -v b="$(date +%s.%N)" 'BEGIN { printf "%.2f", b - a }')
{
  flock 9
  printf '== %s %s (exit %s, %s s)\n' "$stage" "$*" "$status" "$seconds" >>"$runs_dir/stages.log"
  cat "$output" >>"$runs_dir/stages.log"
  [ "$status" -eq 0 ] && printf '%s\t%s\t%s\t%s\n' "$(date -u -d "@$started" +%FT%T)" "$seconds" "$stage" "$*" \
    >>"$runs_dir/timings.tsv"
} 9>>"$runs_dir/.lock"
if [ "$status" -ne 0 ]; then
  cat "$output"
  echo "failed after $seconds s: mlnseq $stage $*" >&2
  exit "$status"
fi
grep -E '^(warning|note)|: wrote ' "$output" | sed "s/\$/  [$seconds s]/"
