#!/usr/bin/env bash
# scripts/sanitize.sh - the run steps of mk/robust.mk (make asan / tsan / fuzz / robust).
#
#   scripts/sanitize.sh asan TEST...          runs cmocka test binaries built with ASan + UBSan
#   scripts/sanitize.sh tsan TEST...          runs the threaded tests (ROBUST_FILTER) under TSan
#   scripts/sanitize.sh fuzz BIN SEEDS DIR SECONDS
#       replays every input of SEEDS (tests/fuzz) one by one (reporting all that fail), then, if
#       all pass, fuzzes for SECONDS over a fresh copy of SEEDS in DIR/corpus with
#       -max_len=4096 -timeout=10. A crash, leak, timeout or sanitizer report fails the step and
#       leaves the reproducer in DIR (crash-*, leak-*, timeout-*, oom-*): replay it with
#       `BIN DIR/crash-...`, fix bvh.h, then add the file to tests/fuzz/ under a descriptive name
#       so that every later run replays it first.
set -u
cmd=${1:-}
shift || true

# UBSan stops at the first report (the binaries are built with -fno-sanitize-recover=undefined).
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}

case "$cmd" in
asan)
  export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:check_initialization_order=1:strict_string_checks=1}
  # Leaks inside the OpenCL ICD loader and the pocl driver are theirs, not bvh.h's.
  supp=$(mktemp)
  printf 'leak:libOpenCL\nleak:libpocl\nleak:libLLVM\nleak:libhwloc\n' >"$supp"
  export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$supp:print_suppressions=0}
  scripts/run-tests.sh "$@"
  rc=$?
  rm -f "$supp"
  exit $rc
  ;;
tsan)
  export TSAN_OPTIONS=${TSAN_OPTIONS:-halt_on_error=1:second_deadlock_stack=1}
  export ROBUST_FILTER=${ROBUST_FILTER:-test_threads_*}
  # TSan of clang 14 cannot map its shadow memory when the kernel randomizes mmap with many
  # bits: then the test runs again without address randomization.
  out=$(mktemp)
  pass=0; fail=0; failed=""
  for t in "$@"; do
    echo "== $t (TSan, ROBUST_FILTER=$ROBUST_FILTER)"
    "$t" >"$out" 2>&1; rc=$?
    if grep -q "unexpected memory mapping" "$out"; then
      echo "(TSan cannot map its shadow memory: running with setarch -R)"
      setarch "$(uname -m)" -R "$t" >"$out" 2>&1; rc=$?
    fi
    cat "$out"
    if [ $rc = 0 ]; then pass=$((pass + 1)); else fail=$((fail + 1)); failed="$failed $t"; fi
  done
  rm -f "$out"
  [ -n "$failed" ] && echo "failed:$failed"
  echo "tsan: $pass passed, $fail failed"
  [ "$fail" = 0 ]
  ;;
fuzz)
  bin=$1 seeds=$2 dir=$3 secs=$4
  mkdir -p "$dir"
  echo "== replaying $(find "$seeds" -maxdepth 1 -type f | wc -l) inputs of $seeds"
  bad=""
  for f in "$seeds"/*; do
    [ -f "$f" ] || continue
    if ! "$bin" "$f" >"$dir/replay.log" 2>&1; then
      bad="$bad $f"
      echo "FAIL $f"
      grep -E "check failed|runtime error|ERROR: (Address|Leak|libFuzzer)|SUMMARY" "$dir/replay.log" | head -4 | sed 's/^/     /'
    fi
  done
  if [ -n "$bad" ]; then
    echo "fuzz: $(echo $bad | wc -w) input(s) of $seeds fail (listed above); not fuzzing until they pass"
    exit 1
  fi
  rm -rf "$dir/corpus"
  mkdir -p "$dir/corpus"
  find "$seeds" -maxdepth 1 -type f -exec cp {} "$dir/corpus/" \;  # files only: tests/fuzz/load/ is another target's
  echo "== fuzzing for ${secs}s: $bin $dir/corpus"
  "$bin" -max_len=4096 -timeout=10 -max_total_time="$secs" -print_final_stats=1 \
         -artifact_prefix="$dir/" "$dir/corpus" >"$dir/fuzz.log" 2>&1
  rc=$?
  grep -E "^#[0-9]+ +(INITED|DONE)|stat::number_of_executed_units|stat::peak_rss_mb" "$dir/fuzz.log"
  if [ $rc != 0 ]; then
    grep -E "check failed|runtime error|ERROR:|SUMMARY|Test unit written" "$dir/fuzz.log" | head -8
    echo "fuzz: FAILED (rc $rc); log $dir/fuzz.log; reproducer(s):"
    ls "$dir"/crash-* "$dir"/leak-* "$dir"/timeout-* "$dir"/oom-* 2>/dev/null
    echo "fuzz: replay with '$bin <file>'; once bvh.h is fixed add the file to $seeds/"
    exit 1
  fi
  echo "fuzz: no failure in ${secs}s"
  ;;
*)
  echo "usage: $0 asan TEST... | tsan TEST... | fuzz BIN SEEDS DIR SECONDS" >&2
  exit 2
  ;;
esac
