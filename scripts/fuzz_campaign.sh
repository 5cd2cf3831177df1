#!/usr/bin/env bash
# The fuzz campaign (issue 32), off CI: runs each libFuzzer target for
# SECONDS (default 3600) on one core, niced, resumed from its corpus, and
# records the run in tests/fuzz/CAMPAIGN.md (executions, coverage, features,
# corpus, findings). New coverage is merged into the committed, minimized
# corpus (tests/fuzz/corpus/<target>/); findings are kept under
# build-fuzz/campaign/<target>/findings/ to triage: each is fixed in our
# code or shown to be contained by the reader's process, and its
# reproducer goes into tests/data/vdb_crashers/ (tests/test_vdb_damaged.py)
# or the .nvdb tests.
#   scripts/fuzz_campaign.sh [SECONDS] [TARGET...]      (targets: nvdb vdb)
# Needs the fuzz build (scripts/test.sh makes it: build-fuzz/bin/fuzz_*).
# The run goes on in fork mode past a crash (-ignore_crashes), so one
# finding does not end the hour.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-3600}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(nvdb vdb)
shared="${NVDB_SHARED_DATA:-../shared/data}"
log=tests/fuzz/CAMPAIGN.md
for t in "${targets[@]}"; do
  bin=build-fuzz/bin/fuzz_$t
  [ -x "$bin" ] || { echo "fuzz_campaign: $bin is missing: run scripts/test.sh first" >&2; exit 2; }
  work=build-fuzz/campaign/$t
  mkdir -p "$work/corpus" "$work/findings" "tests/fuzz/corpus/$t"
  # .nvdb: small inputs, read at ~1000 a second against ~250 for the
  # 1.2-2.4 MB raw typed grids; the typed grids (Fp4/8/16, FpN, Vec3f)
  # enter zip-compressed (~2 KB each), and the 64 KB cap keeps mutants small
  seeds=(tests/fuzz/corpus/$t build-fuzz/seeds-zip)
  max_len=65536
  if [ "$t" = nvdb ]; then
    mkdir -p build-fuzz/seeds-zip
    for g in single_voxel lower_tiles; do
      for ty in fp4 fp8 fp16 fpn vec3f; do
        [ -f "build-fuzz/seeds-zip/${g}_${ty}_zip.nvdb" ] ||
          build/bin/nvdb_make_test_grid "$g" "build-fuzz/seeds-zip/${g}_${ty}_zip.nvdb" \
            --type "$ty" --codec zip >/dev/null
      done
    done
    find build-fuzz/seeds -type f -size -64k -exec cp -n {} build-fuzz/seeds-zip/ \;
  fi
  if [ "$t" = vdb ]; then
    seeds=(tests/fuzz/corpus/$t build-fuzz/seeds-vdb)
    max_len=131072  # (a 1.7 MB .vdb reads at a few per second; mutations of
  fi                #  its first 128 KB reach its header, descriptors and nodes)
  [ -d "$shared" ] && seeds+=("$shared")
  echo "== fuzz_$t for ${seconds} s"
  start=$(date -u +%Y-%m-%dT%H:%MZ)
  # (-rss_limit_mb: OpenVDB leaks what it built when a damaged file makes
  # it throw, which adds up over a job's inputs in one process; at 2 GB a
  # job ended every ~2.5 minutes and restarted, reloading its inputs)
  nice -n 10 "$bin" -fork=1 -ignore_crashes=1 -ignore_ooms=1 -ignore_timeouts=1 \
    -timeout=30 -rss_limit_mb=4096 -max_len="$max_len" -max_total_time="$seconds" \
    -artifact_prefix="$work/findings/" "$work/corpus" "${seeds[@]}" > "$work/last.log" 2>&1 || true
  # fork mode's status lines: "#EXECS: cov: C ft: F corp: N exec/s: E oom/timeout/crash: a/b/c ..."
  last=$(grep -E '^#[0-9]+: cov:' "$work/last.log" | tail -n 1 || true)
  execs=$(sed -E 's/^#([0-9]+):.*/\1/' <<<"$last")
  cov=$(sed -E 's/.* cov: ([0-9]+).*/\1/' <<<"$last")
  ft=$(sed -E 's/.* ft: ([0-9]+).*/\1/' <<<"$last")
  otc=$(sed -E 's#.*oom/timeout/crash: ([0-9/]+).*#\1#' <<<"$last")
  # the committed corpus: only inputs that add coverage (-merge=1)
  # (-artifact_prefix: an input that runs out of memory in the merge lands
  # there, not in the working directory)
  "$bin" -merge=1 -artifact_prefix="$work/" "tests/fuzz/corpus/$t" "$work/corpus" > "$work/merge.log" 2>&1 || true
  # kept small: new inputs over 256 KB (.nvdb: mutants of the generator's
  # typed seeds, which the test command makes again) or 64 KB (.vdb: mutants
  # of the shared files' first 128 KB) stay in the campaign's own corpus
  cap=256k
  [ "$t" = vdb ] && cap=64k
  find "tests/fuzz/corpus/$t" -type f -size +$cap | while read -r f; do
    git ls-files --error-unmatch "$f" >/dev/null 2>&1 || rm -f "$f"
  done
  files=$(ls "tests/fuzz/corpus/$t" | wc -l)
  kb=$(du -sk "tests/fuzz/corpus/$t" | cut -f1)
  findings=$(ls "$work/findings" | wc -l)
  triage=""
  if [ "$t" = vdb ] && [ "$findings" -gt 0 ]; then
    # only the findings that no earlier run triaged ($work/triaged.log keeps
    # every verdict: a finding's name is the hash of its bytes)
    touch "$work/triaged.log"
    new_findings=()
    for f in "$work"/findings/*; do
      grep -q -- ": $(basename "$f"): " "$work/triaged.log" || new_findings+=("$f")
    done
    if [ ${#new_findings[@]} -gt 0 ]; then
      python3 -u tests/fuzz/triage_vdb.py "$bin" build "${new_findings[@]}" > "$work/triage.log" 2>&1 || true
      grep -E '^(ok|FAIL): ' "$work/triage.log" >> "$work/triaged.log" || true
    fi
    contained=$(grep -c '^ok: ' "$work/triaged.log" || true)
    failed=$(grep -c '^FAIL' "$work/triaged.log" || true)
    # (the new ones that crashed the plugin's uninstrumented reader process:
    # contained, each a check the reader lacks; triage_vdb.py)
    crashed=0
    [ ${#new_findings[@]} -eq 0 ] || crashed=$(grep -E '^(ok|FAIL): ' "$work/triage.log" | grep -c "reader crashed" || true)
    triage=" (${#new_findings[@]} new, $crashed of them crashing the reader's process; triaged in all: $contained contained in the reader, $failed FAIL)"
  fi
  [ -f "$log" ] || printf '# Fuzz campaign\n\nOne row per run of `scripts/fuzz_campaign.sh` (one core, niced). Executions, coverage (edges) and features are libFuzzer'"'"'s final status line; oom/timeout/crash its counts; findings the artifacts kept.\n\n| start (UTC) | target | seconds | executions | cov | ft | oom/timeout/crash | findings | corpus files (KiB) |\n|---|---|---|---|---|---|---|---|---|\n' > "$log"
  echo "| $start | fuzz_$t | $seconds | ${execs:-?} | ${cov:-?} | ${ft:-?} | ${otc:-?} | $findings$triage | $files ($kb) |" >> "$log"
  tail -n 1 "$log"
done
