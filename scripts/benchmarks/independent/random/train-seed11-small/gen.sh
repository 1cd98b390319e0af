#!/usr/bin/env bash
# Training draw seed 11 at the small size, N = 24 (fixed in advance), made with the rules
# commit's own generator (a worktree at 8de795e: git worktree add --detach ../rules3 8de795e;
# cd ../rules3 && bash scripts/bootstrap.sh), one index at a time; a case already written or
# discarded is skipped here (generate.py would make it again), so this resumes:
#
#   RULES=/work/rules3 OUT=$PWD/cases bash gen.sh
set -euo pipefail
OUT=${OUT:?give OUT, the draw cases folder}
cd "${RULES:-/work/rules3}"
names=$(/usr/bin/python3 -c "import sys; sys.path.insert(0, 'scripts/benchmarks/independent')
import random_draw as rd; print(' '.join(c['name'] for c in rd.draw(11, 24, 'small')))")
i=0
for name in $names; do
  if [ -e "$OUT/$name/truth.json" ] || [ -e "$OUT/$name/discarded.json" ]; then i=$((i + 1)); continue; fi
  nice /usr/bin/python3 scripts/benchmarks/independent/generate.py --random 24 --seed 11 \
     --size small --out "$OUT" --only "$i"
  i=$((i + 1))
done
