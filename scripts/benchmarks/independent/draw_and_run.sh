#!/usr/bin/env bash
# One draw of the truth-finding protocol (README.md, "Truth-finding measured as a rate"):
# generate N random cases, diagnose each (2 ranks, one case at a time, a per-case timeout),
# score the draw with rates.py.
#
#   scripts/benchmarks/independent/draw_and_run.sh test N OUT
#       the test draw: its seed is derived from the hash of HEAD, the commit that froze the
#       rules (rates.py --seed-from-commit HEAD); refused with uncommitted changes to tracked
#       files, since the rules run would then not be the commit's
#   scripts/benchmarks/independent/draw_and_run.sh training N SEED OUT
#       a training draw (rules may be tuned on it); refused when SEED is HEAD's test seed
#   scripts/benchmarks/independent/draw_and_run.sh test-cases N OUT [ONLY]
#   scripts/benchmarks/independent/draw_and_run.sh test-diagnose OUT
#       the test draw in two parts, for a draw whose truths take longer than one sitting
#       (README.md, "A test draw generated over several sittings"): test-cases generates the
#       cases ONLY (generate.py --only, default all) of HEAD's test seed into OUT/cases and may
#       be re-run in the same OUT at the same commit until none is pending (it refuses an OUT
#       whose protocol.json names another commit); test-diagnose diagnoses and scores them all,
#       as one job, refusing unless HEAD is that commit and no case is pending; a job cut
#       short (the sitting ended) is resumed by running it again: the cases with a row.json
#       are kept, the one it was in is diagnosed again from its start
#
# OUT must not exist yet (a new draw for every report: a draw is never re-run in part or
# topped up). Environment: SIZE (generate.py --size, default realistic), TIMEOUT (seconds per
# case, default 1200: twice issue 37's 10-minute target, so a slow case still shows what it
# found; the wall-time target is checked on the table), NP (ranks, default 2).
# Writes OUT/protocol.json (kind, commit, seed and its derivation, N, settings, start and end
# times), OUT/cases (generate.py), OUT/diagnoses (run.py: one folder per case with its
# report.json, diagnose.log, row.json), OUT/rates.md, rates.json, power.png, confusion.png,
# and the whole job's output in OUT/job.log.
set -euo pipefail

usage() { sed -n '2,30p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
[ $# -ge 1 ] || usage
kind=$1
only=""
case "$kind" in
  test) [ $# -eq 3 ] || usage; n=$2; seed=""; out=$3 ;;
  training) [ $# -eq 4 ] || usage; n=$2; seed=$3; out=$4 ;;
  test-cases) [ $# -eq 3 ] || [ $# -eq 4 ] || usage; n=$2; seed=""; out=$3; only=${4:-} ;;
  test-diagnose) [ $# -eq 2 ] || usage; n=1; seed=""; out=$2 ;;
  *) usage ;;
esac
[[ "$n" =~ ^[1-9][0-9]*$ ]] || { echo "N must be a positive integer, got '$n'" >&2; exit 2; }

here=$(cd "$(dirname "$0")" && pwd)
root=$(git -C "$here" rev-parse --show-toplevel)
py="$root/.venv/bin/python"
size=${SIZE:-realistic}
timeout=${TIMEOUT:-1200}
np_=${NP:-2}

rev=$(git -C "$root" rev-parse HEAD)
test_seed=$("$py" "$here/rates.py" --seed-from-commit "$rev")
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \
       OMPI_MCA_rmaps_base_oversubscribe=1 MPLBACKEND=Agg OPENBLAS_NUM_THREADS=1
# a split test draw: OUT/protocol.json's commit must be HEAD (the rules the seed came from)
json_field() { "$py" -c "import json, sys; print(json.load(open(sys.argv[1])).get(sys.argv[2]))" "$@"; }
if [ "$kind" = test-cases ] || [ "$kind" = test-diagnose ]; then
  if [ -n "$(git -C "$root" status --porcelain --untracked-files=no -- petsoft)" ]; then
    echo "uncommitted changes under petsoft/: a test draw runs the rules commit as committed" >&2
    exit 2
  fi
  if [ -e "$out/protocol.json" ]; then
    if [ "$(json_field "$out/protocol.json" commit)" != "$rev" ]; then
      echo "$out is the test draw of commit $(json_field "$out/protocol.json" commit), HEAD is" \
           "$rev: run it from a worktree at that commit (git worktree add --detach DIR COMMIT)" >&2
      exit 2
    fi
  elif [ "$kind" = test-diagnose ]; then
    echo "$out/protocol.json is missing: make the cases first (draw_and_run.sh test-cases)" >&2
    exit 2
  fi
fi
if [ "$kind" = test-cases ]; then
  mkdir -p "$out"
  out=$(cd "$out" && pwd)
  if [ ! -e "$out/protocol.json" ]; then
    "$py" - "$out/protocol.json" "$rev" "$test_seed" "$n" "$size" <<'EOF'
import json, sys
path, rev, seed, n, size = sys.argv[1:]
json.dump({"kind": "test", "commit": rev, "seed": int(seed),
           "seed_derivation": f"rates.py --seed-from-commit {rev}: int(sha[:8], 16) % 2**31",
           "N": int(n), "size": size,
           "split": "cases generated over several sittings (draw_and_run.sh test-cases), "
                    "diagnosed and scored as one job (test-diagnose)",
           "started": None, "ended": None}, open(path, "w"), indent=1)
EOF
  fi
  # N may grow (case i is drawn from (seed, i) alone: more cases never change the earlier
  # ones), never shrink; the size is the protocol's
  if [ "$(json_field "$out/protocol.json" N)" -gt "$n" ]; then
    echo "$out has N $(json_field "$out/protocol.json" N): N may grow, never shrink" >&2
    exit 2
  fi
  "$py" - "$out/protocol.json" "$n" <<'EOF'
import json, sys
path, n = sys.argv[1:]
p = json.load(open(path))
p["N"] = int(n)
json.dump(p, open(path, "w"), indent=1)
EOF
  echo "[draw] test draw (split): commit $rev, seed $test_seed, N $n, cases ${only:-all}"
  exec nice -n 10 /usr/bin/python3 "$here/generate.py" --random "$n" --seed "$test_seed" \
      --size "$(json_field "$out/protocol.json" size)" --out "$out/cases" ${only:+--only "$only"}
fi
if [ "$kind" = test-diagnose ]; then
  out=$(cd "$out" && pwd)
  seed=$(json_field "$out/protocol.json" seed)
  n=$(json_field "$out/protocol.json" N)
  pending=$("$py" -c "import json, sys; print(json.load(open(sys.argv[1]))['status']['pending'])" \
      "$out/cases/draw.json")
  [ "$pending" = 0 ] || { echo "$pending cases are still pending: test-cases first" >&2; exit 2; }
  # a job cut short by the end of a sitting is resumed (its finished cases kept, the case it
  # was in made again from its start); a finished one is never run again
  resume=""
  if [ -e "$out/diagnoses" ]; then
    if [ "$(json_field "$out/protocol.json" ended)" != None ]; then
      echo "$out/diagnoses exists and was finished: a draw is diagnosed once" >&2
      exit 2
    fi
    if [ "$("$py" -c "import json, sys; print('sittings' in json.load(open(sys.argv[1])))" \
          "$out/protocol.json")" != True ]; then
      echo "$out/diagnoses exists without a recorded start: a draw is diagnosed once" >&2
      exit 2
    fi
    resume=--resume
  fi
  exec > >(tee -a "$out/job.log") 2>&1
  started=$(date -u +%Y-%m-%dT%H:%M:%SZ)
  "$py" - "$out/protocol.json" "$started" <<'EOF'
import json, sys
path, started = sys.argv[1:]
p = json.load(open(path))
p.setdefault("sittings", []).append(started)
json.dump(p, open(path, "w"), indent=1)
EOF
  echo "[draw] diagnosing the test draw: commit $rev, seed $seed, N $n${resume:+ (resumed)}"
  "$py" "$here/run.py" --cases-dir "$out/cases" --out "$out/diagnoses" --np "$np_" \
      --timeout "$timeout" $resume
  "$py" "$here/rates.py" "$out/cases" --reports "$out/diagnoses" --figures "$out" \
      --label "test draw: commit ${rev:0:10}, seed $seed, N $n"
  if [ "$(git -C "$root" rev-parse HEAD)" != "$rev" ]; then
    echo "[draw] HEAD moved during the job: this draw is void" >&2
    exit 1
  fi
  "$py" - "$out/protocol.json" "$started" "$(date -u +%Y-%m-%dT%H:%M:%SZ)" "$timeout" "$np_" <<'EOF'
import json, sys
path, started, ended, timeout, np_ = sys.argv[1:]
p = json.load(open(path))
p.update(started=p["sittings"][0], ended=ended, timeout_s=float(timeout), ranks=int(np_))
json.dump(p, open(path, "w"), indent=1)
EOF
  echo "[draw] done: $out/rates.md"
  exit 0
fi

if [ -e "$out" ]; then
  echo "$out exists: every draw gets a new folder (the protocol never re-runs part of one)" >&2
  exit 2
fi
if [ "$kind" = test ]; then

  if [ -n "$(git -C "$root" status --porcelain --untracked-files=no)" ]; then
    echo "uncommitted changes to tracked files: commit the rules first (the test draw runs" \
         "at one commit, and its seed comes from that commit's hash)" >&2
    git -C "$root" status --short --untracked-files=no >&2
    exit 2
  fi
  seed=$test_seed
  how="rates.py --seed-from-commit $rev: int(sha[:8], 16) % 2**31"
else
  [[ "$seed" =~ ^[0-9]+$ ]] || { echo "SEED must be a non-negative integer" >&2; exit 2; }
  if [ "$seed" = "$test_seed" ]; then
    echo "seed $seed is this commit's test seed: a training draw must use another" >&2
    exit 2
  fi
  how="given (training draw)"
fi

mkdir -p "$out"
out=$(cd "$out" && pwd)
exec > >(tee -a "$out/job.log") 2>&1
started=$(date -u +%Y-%m-%dT%H:%M:%SZ)
write_protocol() {
  "$py" - "$out/protocol.json" "$kind" "$rev" "$seed" "$how" "$n" "$size" "$timeout" "$np_" \
      "$started" "${1:-}" <<'EOF'
import json, sys
path, kind, rev, seed, how, n, size, timeout, np_, started, ended = sys.argv[1:]
json.dump({"kind": kind, "commit": rev, "seed": int(seed), "seed_derivation": how, "N": int(n),
           "size": size, "timeout_s": float(timeout), "ranks": int(np_), "started": started,
           "ended": ended or None}, open(path, "w"), indent=1)
EOF
}
write_protocol
echo "[draw] $kind draw: commit $rev, seed $seed ($how), N $n, size $size"

echo "[draw] generating $n cases (DOLFINx, gmsh) ..."
nice -n 10 /usr/bin/python3 "$here/generate.py" --random "$n" --seed "$seed" --size "$size" \
    --out "$out/cases"
echo "[draw] diagnosing every case ($np_ ranks, one at a time, timeout $timeout s) ..."
"$py" "$here/run.py" --cases-dir "$out/cases" --out "$out/diagnoses" --np "$np_" \
    --timeout "$timeout"
label="$kind draw: commit ${rev:0:10}, seed $seed, N $n"
"$py" "$here/rates.py" "$out/cases" --reports "$out/diagnoses" --figures "$out" --label "$label"

now=$(git -C "$root" rev-parse HEAD)
if [ "$now" != "$rev" ]; then
  echo "[draw] HEAD moved from $rev to $now during the job: this draw is void" >&2
  exit 1
fi
write_protocol "$(date -u +%Y-%m-%dT%H:%M:%SZ)"
echo "[draw] done: $out/rates.md"
