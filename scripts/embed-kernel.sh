#!/bin/sh
# scripts/embed-kernel.sh [OUT] - writes cl/bvh_cl.h with cl/trace.cl embedded between its
# "kernel source" markers (to OUT when given, else in place), one C string per line, so that a
# program that includes bvh_cl.h needs no kernel file. `make kernel` runs it; `make test` checks
# that the checked-in header holds the current kernel.
set -eu
cd "$(dirname "$0")/.."
out=${1:-cl/bvh_cl.h}
begin='/* == kernel source: generated from cl/trace.cl by scripts/embed-kernel.sh, do not edit == */'
end='/* == end of kernel source == */'
grep -qxF "$begin" cl/bvh_cl.h && grep -qxF "$end" cl/bvh_cl.h || {
  echo "embed-kernel: cl/bvh_cl.h lacks the kernel source markers" >&2; exit 1; }
tmp=$(mktemp)
lines=$(mktemp)
trap 'rm -f "$tmp" "$lines"' EXIT
# each line as a C string: backslashes and quotes escaped (by sed: awk's gsub differs between
# awks on backslashes), then a newline
sed -e 's/\\/\\\\/g' -e 's/"/\\"/g' -e 's/^/"/' -e 's/$/\\n",/' cl/trace.cl >"$lines"
awk -v begin="$begin" -v end="$end" '
  FNR == NR { src[++n] = $0; next }
  $0 == begin { print; print "static const char *const bvh_cl__source[] = {";
                for (i = 1; i <= n; i++) print src[i];
                print "};"; skip = 1; next }
  $0 == end { skip = 0 }
  !skip' "$lines" cl/bvh_cl.h >"$tmp"
cat "$tmp" >"$out"
