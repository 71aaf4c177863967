#!/usr/bin/env bash
# Runs the Python tests beside CPU-bound processes (a busy machine: CI runners, a laptop doing other work),
# and stops those processes however the run ends (success, failure, Ctrl-C, SIGTERM).
#
#   scripts/test_under_load.sh [--load N] [--repeat K] [pytest arguments...]
#
#   --load N     busy processes beside the tests (default 2: as many as this project's 2-core CI machine)
#   --repeat K   run the selection K times in a row (default 1); every run is reported, the exit status is
#                the first failing run's (0 if all passed)
#   pytest arguments default to `python_tests -v -rs`; e.g.
#   scripts/test_under_load.sh --repeat 10 python_tests/test_cli.py -k ctrl_c_stops_everything
#
# PYTHON chooses the interpreter (default python3); the package must be installed in it (docs/testing.md).
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
LOAD=2
REPEAT=1
while [ $# -gt 0 ]; do
    case "$1" in
        --load) LOAD=$2; shift 2 ;;
        --repeat) REPEAT=$2; shift 2 ;;
        *) break ;;
    esac
done
case "$LOAD$REPEAT" in *[!0-9]*|'') echo "usage: $0 [--load N] [--repeat K] [pytest args...]" >&2; exit 2 ;; esac
[ $# -gt 0 ] || set -- python_tests -v -rs

pids=()
stop_load() {
    [ ${#pids[@]} -gt 0 ] && kill "${pids[@]}" 2>/dev/null
    [ ${#pids[@]} -gt 0 ] && wait "${pids[@]}" 2>/dev/null
    pids=()
}
trap stop_load EXIT
trap 'echo "test_under_load: interrupted" >&2; exit 130' INT
trap 'exit 143' TERM
trap 'exit 129' HUP

# Background jobs of a non-interactive shell ignore SIGINT: a Ctrl-C reaches pytest, the trap above ends them.
for _ in $(seq "$LOAD"); do
    "$PY" -c 'while True: pass' &
    pids+=($!)
done
echo "test_under_load: $LOAD busy processes (${pids[*]}) beside: $PY -m pytest $*"

status=0
passed=0
for k in $(seq "$REPEAT"); do
    t0=$EPOCHREALTIME
    "$PY" -m pytest "$@"
    rc=$?
    secs=$(awk -v a="$t0" -v b="$EPOCHREALTIME" 'BEGIN { print b - a }')
    printf 'test_under_load: run %d/%d: exit %d in %.1f s\n' "$k" "$REPEAT" "$rc" "$secs"
    if [ "$rc" -eq 0 ]; then
        passed=$((passed + 1))
    elif [ "$status" -eq 0 ]; then
        status=$rc
    fi
done
echo "test_under_load: $passed/$REPEAT runs passed beside $LOAD busy processes"
exit "$status"
