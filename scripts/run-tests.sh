#!/usr/bin/env bash
# Runs each test binary given, prints its output, and a closing "N passed, N failed" line.
set -u
pass=0; fail=0; failed=""
for t in "$@"; do
  echo "== $t"
  if "$t"; then pass=$((pass + 1)); else fail=$((fail + 1)); failed="$failed $t"; fi
done
[ -n "$failed" ] && echo "failed:$failed"
echo "tests: $pass passed, $fail failed"
[ "$fail" = 0 ]
