#!/usr/bin/env bash
# The whole test suite, serial and on 2 MPI ranks (installs what it needs first).
#   bash scripts/run_tests.sh [extra pytest args]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/bootstrap.sh"
cd "$ROOT"
PY="$ROOT/.venv/bin/python"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export MPLBACKEND=Agg
# one BLAS thread per process (petsoft/__init__.py sets the same default; a test module may
# load PETSc before importing petsoft)
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
echo "== serial (two pytest workers, one test file each at a time) =="
# Two single-rank workers use the 2 cores the 2-rank pass uses; a file stays on one worker so
# its module fixtures (the diagnose cases' syntheses) are made once.
# A serial failure does not stop the 2-rank pass: the log shows both before the script fails.
set +e
"$PY" -m pytest -q --color=no -p no:cacheprovider -n 2 --dist loadfile "$@" tests
serial_status=$?
set -e
echo "== 2 MPI ranks =="
# Rank 1's report goes to a file (shown if it fails) so the log reads as one run.
RANK1_LOG="$(mktemp)"
set +e
timeout 1800 mpiexec -n 2 bash -c '
  if [ "$OMPI_COMM_WORLD_RANK" = "0" ]; then exec "$0" "$@"; else exec "$0" "$@" > "'"$RANK1_LOG"'" 2>&1; fi
' "$PY" -m pytest -q --color=no -p no:cacheprovider -m "not serial_only" "$@" tests
status=$?
set -e
if [ $status -ne 0 ]; then echo "== rank 1 report =="; cat "$RANK1_LOG"; fi
rm -f "$RANK1_LOG"
if [ $serial_status -ne 0 ]; then echo "== the serial pass failed (above) =="; exit $serial_status; fi
exit $status
