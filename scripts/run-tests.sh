#!/usr/bin/env bash
# Runs each test program given and prints one line per program: ok or FAILED, its name, its tests
# passed and failed, its time. Tests are counted from cmocka's "[  PASSED  ] N test(s).",
# "[  FAILED  ] N test(s)" and "[  SKIPPED ] N test(s)" lines (skipped ones are neither passed nor
# failed), or a script's "X of Y checks passed"; any other program is one test. The whole output
# of every program is kept in $BUILD/test-logs/NAME.log, and printed for a program that failed.
# Closes with "tests: N passed, N failed" (tests, not programs); the exit status is 1 when a
# program failed (a non-zero exit status), else 0.
set -u
build=${BUILD:-build}
logs=$build/test-logs
mkdir -p "$logs" || exit 1
pass=0; fail=0; failed=""
for t in "$@"; do
  name=${t#"$build"/}
  log=$logs/$(echo "${name%.sh}" | sed "s|^/||" | tr / -).log
  start=$(date +%s)
  "$t" >"$log" 2>&1
  rc=$?
  secs=$(( $(date +%s) - start ))
  read -r p f k < <(awk '
    /^\[  PASSED  \] [0-9]+ test\(s\)/ { p += $4; counted = 1 }
    /^\[  FAILED  \] [0-9]+ test\(s\)/ { f += $4; counted = 1 }
    /^\[  SKIPPED \] [0-9]+ test\(s\)/ { k += $4 }
    match($0, /[0-9]+ of [0-9]+ checks passed/) {
      split(substr($0, RSTART, RLENGTH), w, " "); p += w[1]; f += w[3] - w[1]; counted = 1
    }
    END { if (counted) print p + 0, f + 0, k + 0; else print "-", "-", 0 }' "$log")
  if [ "$p" = - ]; then p=$((rc == 0)); f=$((rc != 0)); fi
  [ "$rc" != 0 ] && [ "$f" = 0 ] && f=1 # a crash or an error before the counts
  pass=$((pass + p)); fail=$((fail + f))
  if [ "$rc" = 0 ]; then
    skipped=""
    [ "$k" != 0 ] && skipped=", $k skipped"
    printf 'ok      %-32s %5d passed%s %5d s\n' "$name" "$p" "$skipped" "$secs"
  else
    failed="$failed $name"
    printf 'FAILED  %-32s %5d passed, %d failed, exit status %d, %d s; its output (%s):\n' \
      "$name" "$p" "$f" "$rc" "$secs" "$log"
    sed 's/^/    /' "$log"
  fi
done
echo "logs: $logs/"
[ -n "$failed" ] && echo "failed:$failed"
echo "tests: $pass passed, $fail failed"
[ -z "$failed" ]
