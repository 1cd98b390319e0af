#!/usr/bin/env bash
# Commit a draw's finished cases (written or discarded) and its manifests, never a case still
# being made (README.md, "A test draw generated over several sittings"):
#
#   scripts/benchmarks/independent/commit_draw.sh scripts/benchmarks/independent/random/test-SEED
#
# Adds DRAW/protocol.json, DRAW/cases/draw.json and every DRAW/cases/r*/ holding truth.json or
# discarded.json (the cached runs in .runs/ are .gitignore'd), and commits only those paths.
set -euo pipefail
[ $# -eq 1 ] || { sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
D=${1%/}
[ -e "$D/protocol.json" ] || [ -e "$D/cases/draw.json" ] || {
  echo "$D holds neither protocol.json nor cases/draw.json: not a draw" >&2; exit 2; }
paths=()
for f in "$D/protocol.json" "$D/cases/draw.json"; do [ -e "$f" ] && paths+=("$f"); done
for c in "$D"/cases/r*/; do
  if [ -e "$c/truth.json" ] || [ -e "$c/discarded.json" ]; then paths+=("${c%/}"); fi
done
git add -- "${paths[@]}"
status=$(python3 -c "import json, sys; print(json.load(open(sys.argv[1]))['status'])" \
  "$D/cases/draw.json" 2>/dev/null || echo "no manifest yet")
if git diff --cached --quiet -- "${paths[@]}"; then
  echo "nothing new in $D ($status)"
else
  git commit -q -m "$(basename "$D"): cases so far, $status" -- "${paths[@]}"
  git log --oneline -1
fi
