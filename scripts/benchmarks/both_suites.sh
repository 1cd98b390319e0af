#!/bin/bash
# Both fixed concealed-effect suites at one checkout, one case at a time: bench_diagnose.py's
# sixteen bars, then the independent suite's cases (independent/run.py), each case on NP ranks.
#
#   bash scripts/benchmarks/both_suites.sh OUT [NP]       (NP default 2)
#
# Run with the checkout whose petsoft is to be measured: the script uses the .venv and scripts
# of the tree it sits in, so a worktree of an older commit (with its own .venv) runs its own
# code, e.g. `SUITES_ROOT=/work/old bash scripts/benchmarks/both_suites.sh out/before` (SUITES_ROOT:
# the checkout to run, default this one) beside `bash scripts/benchmarks/both_suites.sh out/after`
# (two diagnose runs at once at most on a 2-core machine: each case's wall time is then
# indicative only).
#
# Writes OUT/bench/<case>/ (row.json, diagnose/report.json; the case's log OUT/bench/<case>.log),
# OUT/independent/<case>/ (row.json, report.json, diagnose.log) and the two tables
# OUT/bench.txt and OUT/independent/table.md; OUT/times.txt has the commit and each part's start
# and end. Resumable: a case with its row.json is not run again (an interrupted one starts over).
# Compare two such OUTs case by case with scripts/tools/compare_reports.py.
set -u
ROOT="$(cd "${SUITES_ROOT:-$(dirname "$0")/../..}" && pwd)"
OUT="$(mkdir -p "${1:?usage: both_suites.sh OUT [NP]}" && cd "$1" && pwd)"
NP="${2:-2}"
PY="$ROOT/.venv/bin/python"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export OPENBLAS_NUM_THREADS=1 MPLBACKEND=Agg
cd "$ROOT"
stamp() { echo "$(date '+%F %T') $*" >> "$OUT/times.txt"; }
stamp "start; commit $(git rev-parse --short HEAD); petsoft tree $(git rev-parse --short HEAD:petsoft); np $NP"

mkdir -p "$OUT/bench"
CASES="$("$PY" -c "import sys; sys.path.insert(0, 'scripts/benchmarks'); import bench_diagnose as b; print(' '.join(b.CASES))")"
stamp "bench start"
for c in $CASES; do
  [ -f "$OUT/bench/$c/row.json" ] && continue
  rm -rf "$OUT/bench/$c"
  nice mpiexec -n "$NP" "$PY" scripts/benchmarks/bench_diagnose.py --dir "$OUT/bench" --cases "$c" \
    > "$OUT/bench/$c.log" 2>&1
  stamp "bench $c exit $?"
done
"$PY" scripts/benchmarks/bench_diagnose.py --dir "$OUT/bench" --collect > "$OUT/bench.txt" 2>&1
stamp "bench end"

stamp "independent start"
"$PY" scripts/benchmarks/independent/run.py --cases-dir scripts/benchmarks/independent/cases \
  --out "$OUT/independent" --np "$NP" --resume > "$OUT/independent.log" 2>&1
stamp "independent end (exit $?)"
