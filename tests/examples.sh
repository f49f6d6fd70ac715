#!/usr/bin/env bash
# tests/examples.sh - the programs a user copies work: build/minimal prints the hit of the manual's
#   example, and its main is that example line for line (bvh.h's EXAMPLE section); build/boxes
#   finds, tracing a box build with bvh_intersect_custom, the same sphere as brute force for every ray;
#   build/animate refits a waving sheet, saves the tree to a file and loads it back.
#   build/pathtrace renders its built-in scene (instances and spheres) into a real picture, the
#   same bytes on 1 and 2 threads and with --trace opencl (on an exact device), prints one JSON
#   line with --json, an image within noise of bvh.h's with --embree (Embree 3 tracing, where
#   built with it), and refuses a bad command line with status 2.
# Usage: tests/examples.sh  (`make test` runs it after building both; BUILD=dir picks another
#   build directory). Prints one line per failed check and a closing result line; exits 1 on failure.
set -u
cd "$(dirname "$0")/.." || exit 1
build=${BUILD:-build}
checks=0
failed=0
fail() { failed=$((failed + 1)); echo "FAIL $*"; }

# minimal: runs, exits 0 and prints the hit (triangle 0 at t = 1)
checks=$((checks + 1))
out=$("$build/minimal" 2>&1)
rc=$?
if [ "$rc" != 0 ] || ! grep -q '^hit triangle 0 at t=1 ' <<<"$out"; then
  fail "$build/minimal: exit status $rc, printed: $out"
fi

# minimal: its main is the manual's example (bvh.h: from the line after EXAMPLE to the first blank line)
checks=$((checks + 1))
manual=$(sed -n '/^   EXAMPLE$/,/^$/p' bvh.h | sed '1d;$d;s/^         //')
program=$(sed -n '/^int main(void) {$/,/^    return 0;$/p' examples/minimal.c | sed '1d;$d;s/^    //')
if [ -z "$manual" ] || [ "$manual" != "$program" ]; then
  fail "examples/minimal.c's main differs from bvh.h's EXAMPLE:"
  diff <(echo "$manual") <(echo "$program")
fi

# boxes: every ray agrees with brute force
checks=$((checks + 1))
out=$("$build/boxes" 2>&1)
rc=$?
[ "$rc" = 0 ] || fail "$build/boxes: exit status $rc, printed: $out"

# animate: refits over 30 frames, saves the tree to a file, loads it back (copied, then borrowed
# from the file's bytes) with the same hit both times
checks=$((checks + 1))
tmp=$(mktemp -d)
out=$("$build/animate" "$tmp/tree.bvh" 2>&1)
rc=$?
if [ "$rc" != 0 ] || [ "$(grep -c '(the same)$' <<<"$out")" != 2 ] || [ ! -s "$tmp/tree.bvh" ]; then
  fail "$build/animate: exit status $rc, printed: $out"
fi
rm -rf "$tmp"

# pathtrace: the built-in scene at 64x64, 2 spp, as PPM (no PNG support needed): exit 0, a full
# image that is not one flat colour, identical for 1 and 2 threads (per-pixel random sequences)
tmp=$(mktemp -d) || exit 1
trap 'rm -rf "$tmp"' EXIT
checks=$((checks + 1))
out=$("$build/pathtrace" --size 64x64 --spp 2 --threads 1 --out "$tmp/a.ppm" 2>&1)
rc=$?
pixels=$(tail -c $((64 * 64 * 3)) "$tmp/a.ppm" 2>/dev/null | od -An -v -tu1 -w3 | sort -u | wc -l)
if [ "$rc" != 0 ] || [ "$(wc -c <"$tmp/a.ppm" 2>/dev/null)" != $((64 * 64 * 3 + 13)) ] || [ "$pixels" -lt 16 ]; then
  fail "$build/pathtrace: exit status $rc, $pixels distinct colours, printed: $out"
fi
checks=$((checks + 1))
"$build/pathtrace" --size 64x64 --spp 2 --threads 2 --out "$tmp/b.ppm" >/dev/null 2>&1
cmp -s "$tmp/a.ppm" "$tmp/b.ppm" || fail "$build/pathtrace: the image on 2 threads differs from 1 thread's"
# --builder: every builder's trees give the same hits, so the same image (the default is
# sah-midpoint+opt); an unknown name is a bad command line (exit 2)
checks=$((checks + 1))
"$build/pathtrace" --size 64x64 --spp 2 --threads 2 --builder ploc-parallel --out "$tmp/c.ppm" >/dev/null 2>&1
cmp -s "$tmp/a.ppm" "$tmp/c.ppm" || fail "$build/pathtrace --builder ploc-parallel: the image differs from the default builder's"
checks=$((checks + 1))
"$build/pathtrace" --builder no-such-builder >/dev/null 2>&1
rc=$?
[ "$rc" = 2 ] || fail "$build/pathtrace --builder no-such-builder: exit status $rc, not 2"
# pathtrace --trace opencl: on an exact device (PoCL) the same bytes as the CPU's image (the
# device's hits are the CPU's, the spheres and the shading the same code); without a usable device
# it says so and exits 1 (the check is skipped)
checks=$((checks + 1))
out=$("$build/pathtrace" --size 64x64 --spp 2 --trace opencl --out "$tmp/cl.ppm" 2>&1)
rc=$?
if [ "$rc" = 0 ] && grep -q "exact: the CPU's hits" <<<"$out"; then
  cmp -s "$tmp/a.ppm" "$tmp/cl.ppm" || fail "$build/pathtrace --trace opencl: the image differs from the CPU's"
elif [ "$rc" = 0 ]; then
  echo "note: $build/pathtrace --trace opencl ran on a device without exact hits: image not compared"
elif [ "$rc" = 1 ] && grep -q "OpenCL cannot be used" <<<"$out"; then
  echo "note: no OpenCL device, $build/pathtrace --trace opencl not checked: $out"
else
  fail "$build/pathtrace --trace opencl: exit status $rc, printed: $out"
fi
# pathtrace --json: one line of JSON with the counts; --embree (where built with Embree): the same
# job traced by Embree 3 gives bvh.h's image but for paths that float rounding in a hit sends
# elsewhere (none here: 0 measured; mean |difference| below 0.002 of full scale: Embree's
# occluded rays always unblocked gave 0.003), rendered in turns by 16 bands of rows, bvh.h's
# image (--out) unchanged by the comparison
checks=$((checks + 1))
out=$("$build/pathtrace" --size 64x64 --spp 2 --threads 2 --json --embree --out "$tmp/e.ppm" 2>&1)
rc=$?
keys='"instances":8,"meshes":2,"triangles":14,"instanced_triangles":86,"spheres":3'
if [ "$rc" = 1 ] && grep -q "built without Embree" <<<"$out"; then
  echo "note: $build/pathtrace built without Embree: --embree not checked"
  out=$("$build/pathtrace" --size 64x64 --spp 2 --threads 2 --json --out "$tmp/e.ppm" 2>&1)
  rc=$?
  if [ "$rc" != 0 ] || [ "$(wc -l <<<"$out")" != 1 ] || ! grep -q "$keys" <<<"$out" || ! grep -q '"mrays":' <<<"$out"; then
    fail "$build/pathtrace --json: exit status $rc, printed: $out"
  fi
elif [ "$rc" != 0 ] || [ "$(wc -l <<<"$out")" != 1 ] || ! grep -q "$keys" <<<"$out" ||
  ! grep -q '"rays":[1-9][0-9]*,"ms":[0-9.]*,"mrays":[0-9.]*,"embree_quality":"medium","embree_build_ms":' <<<"$out" ||
  ! grep -q '"embree_mrays":[0-9.]*,"ratio":[0-9.]*,"image_diff":0\.00[01][0-9]*,"bands":16,' <<<"$out" ||
  ! grep -q '"ratio_bands_median":[0-9.]*,"ratio_bands_min":[0-9.]*,"ratio_bands_max":[0-9.]*}$' <<<"$out"; then
  fail "$build/pathtrace --embree --json: exit status $rc (or image_diff not below 0.002), printed: $out"
else
  cmp -s "$tmp/a.ppm" "$tmp/e.ppm" || fail "$build/pathtrace --embree: bvh.h's image differs from the one without --embree"
fi
checks=$((checks + 1))
"$build/pathtrace" --spp 0 --out "$tmp/c.ppm" >/dev/null 2>&1
rc=$?
[ "$rc" = 2 ] || fail "$build/pathtrace --spp 0: exit status $rc, expected 2"

echo "examples: $((checks - failed)) of $checks checks passed"
[ "$failed" = 0 ]
