#!/usr/bin/env bash
# The main job on its embedded default (installs what it needs first):
#   bash scripts/run_demo.sh [extra `petsoft demo` arguments]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/bootstrap.sh" >&2
export MPLBACKEND=Agg
exec "$ROOT/.venv/bin/petsoft" demo "$@"
