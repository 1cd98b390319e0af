#!/bin/bash
# The issue-15 benchmark tables at one commit, one after another on a quiet machine.
#
#   bash scripts/benchmarks/quiet_tables.sh [OUT]      (default out/quiet/<commit>)
#
# Each benchmark waits until the 1-minute load average is below 0.3 (nothing else running:
# MPI ranks spin, and the tables give ratios from the same run), then writes its output to
# OUT/<name>.txt with the commit, the start time and the load average at the start. The
# earlier commit of bench_forward (57eb1aa, the start of issue 15) is built in /work/wt/start
# (a git worktree + bootstrap) when absent. About 60-90 minutes in all.
set -u
cd "$(dirname "$0")/../.."
REV="$(git rev-parse --short HEAD)"
OUT="${1:-out/quiet/$REV}"
mkdir -p "$OUT"
PY=.venv/bin/python
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export OPENBLAS_NUM_THREADS=1 MPLBACKEND=Agg

quiet() {
  while :; do
    load="$(cut -d' ' -f1 /proc/loadavg)"
    awk -v l="$load" 'BEGIN { exit !(l < 0.3) }' && return
    echo "[quiet_tables] waiting: load average $load" >&2
    sleep 30
  done
}

run() {   # name, command...
  local name="$1"; shift
  quiet
  { echo "# $name at $REV, $(date -u +%FT%TZ), load $(cut -d' ' -f1-3 /proc/loadavg)"
    echo "# $*"
    "$@"; echo "# exit $?"; } > "$OUT/$name.txt" 2>&1
  echo "[quiet_tables] $name done: $OUT/$name.txt" >&2
}

if [ ! -x /work/wt/start/.venv/bin/python ]; then
  git worktree add --detach /work/wt/start 57eb1aa && (cd /work/wt/start && bash scripts/bootstrap.sh)
fi
run forward $PY scripts/benchmarks/bench_forward.py --sizes 600 5000 50000
run step_1rank $PY scripts/benchmarks/bench_step.py --sizes 3e4 3e5
run step_2ranks mpiexec -n 2 $PY scripts/benchmarks/bench_step.py --sizes 3e4 3e5
run assembly_1rank $PY scripts/benchmarks/bench_assembly.py --repeat 3
run assembly_2ranks mpiexec -n 2 $PY scripts/benchmarks/bench_assembly.py --repeat 3
run gradient $PY scripts/benchmarks/bench_gradient.py --params 2 10 100 --repeat 2
run adjoint_memory $PY scripts/benchmarks/bench_adjoint_memory.py
echo "[quiet_tables] all in $OUT" >&2
