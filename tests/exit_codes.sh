#!/usr/bin/env bash
# tests/exit_codes.sh - build/render and build/cl_info exit with a status that tells the truth.
#   render: 0 done, 1 error, 2 bad command line. `--trace opencl` asks for OpenCL by name: an
#   unusable $BVH_CL_DEVICE (or a build without OpenCL) is an error, while the default (auto) may
#   fall back to the CPU with a one-line note. A corrupted scene file is a one-line error, not a
#   crash. cl_info: a device named in $BVH_CL_DEVICE that cannot be used is an error. bvhbench:
#   a bad value of an option is a usage error (2), and so is --embree-flags without a value.
# Usage: tests/exit_codes.sh  (`make test` runs it after building both; BUILD=dir picks another
#   build directory). Prints one line per failed check and a closing result line; exits 1 on failure.
set -u
cd "$(dirname "$0")/.." || exit 1
build=${BUILD:-build}
render=$build/render
cl_info=$build/cl_info
bvhbench=$build/bvhbench
for b in "$render" "$cl_info" "$bvhbench"; do
  [ -x "$b" ] || { echo "exit_codes: $b is missing (make $b)"; exit 1; }
done
tmp=$(mktemp -d) || exit 1
trap 'rm -rf "$tmp"' EXIT
scene=gen:random:1000
small=(--size 32x24 --frames 1 --threads 1)
checks=0
failed=0

# expect NAME STATUS LINES CMD...: CMD exits with STATUS and writes at most LINES lines on stderr
# (-1: any number).
expect() {
  local name=$1 want=$2 lines=$3 got n
  shift 3
  "$@" >"$tmp/out" 2>"$tmp/err"
  got=$?
  n=$(wc -l <"$tmp/err")
  checks=$((checks + 1))
  if [ "$got" != "$want" ] || { [ "$lines" -ge 0 ] && [ "$n" -gt "$lines" ]; }; then
    failed=$((failed + 1))
    echo "FAIL $name: exit status $got (want $want), $n line(s) on stderr: $(head -c 300 "$tmp/err" | tr '\n' '|')"
  fi
}

has_opencl=0
"$render" --help | grep -q 'opencl=yes' && has_opencl=1
has_assimp=0
"$render" --help | grep -q 'assimp=yes' && has_assimp=1

# render: the command line
expect "render without a scene" 2 1 "$render"
expect "render --trace gpu" 2 1 "$render" --trace gpu "$scene"
expect "render --help" 0 0 "$render" --help

# render: OpenCL asked for by name, with a device that cannot be used
for dev in garbage 99:0 0:99; do
  expect "render --trace opencl, BVH_CL_DEVICE=$dev" 1 1 env BVH_CL_DEVICE=$dev "$render" --trace opencl "${small[@]}" "$scene"
  expect "render (auto), BVH_CL_DEVICE=$dev: falls back" 0 1 env BVH_CL_DEVICE=$dev "$render" "${small[@]}" "$scene"
  expect "render --trace cpu, BVH_CL_DEVICE=$dev" 0 0 env BVH_CL_DEVICE=$dev "$render" --trace cpu "${small[@]}" "$scene"
done
# and with the default device: it works exactly when cl_info traces on one
if [ "$has_opencl" = 1 ] && env -u BVH_CL_DEVICE "$cl_info" 2>/dev/null | grep -q '^traced'; then
  expect "render --trace opencl on the first device" 0 0 env -u BVH_CL_DEVICE "$render" --trace opencl "${small[@]}" "$scene"
else
  expect "render --trace opencl without a device" 1 1 env -u BVH_CL_DEVICE "$render" --trace opencl "${small[@]}" "$scene"
fi

# cl_info: a named device that cannot be used is an error; no device named may fall back
for dev in garbage 99:0 0:99; do
  expect "cl_info, BVH_CL_DEVICE=$dev" 1 1 env BVH_CL_DEVICE=$dev "$cl_info"
done
expect "cl_info, no BVH_CL_DEVICE" 0 -1 env -u BVH_CL_DEVICE "$cl_info"

# render: a corrupted scene file is a one-line error (status 1), not a signal
printf 'ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n0\n' >"$tmp/empty-face.ply"
printf 'ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 -2 3\n' >"$tmp/bad-quad.ply"
expect "render, a missing file" 1 1 "$render" --trace cpu "${small[@]}" "$tmp/missing.ply"
if [ "$has_assimp" = 1 ]; then
  expect "render, a PLY face without indices" 1 1 "$render" --trace cpu "${small[@]}" "$tmp/empty-face.ply"
  expect "render, a PLY quad with index -2" 1 1 "$render" --trace cpu "${small[@]}" "$tmp/bad-quad.ply"
fi

# bvhbench: Embree's scene flags are default or robust, nothing else (a usage error before any work)
expect "bvhbench, --embree-flags bogus" 2 -1 "$bvhbench" --embree-flags bogus gen:random:100
expect "bvhbench, --embree-flags without a value" 2 -1 "$bvhbench" --embree-flags
expect "bvhbench, --camera sideways" 2 -1 "$bvhbench" --camera sideways gen:random:100

echo "exit_codes: $((checks - failed)) of $checks checks passed (opencl=$has_opencl assimp=$has_assimp)"
[ "$failed" = 0 ]
