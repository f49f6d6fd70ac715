#!/usr/bin/env bash
# Installs the Debian packages bvh.h's examples, tests and benchmarks use, when missing.
# Usage: scripts/deps.sh [core|test|demo|bench|all]   (default: all)
# As root it runs apt-get; otherwise it prints the exact command to run and fails.
set -u
want=${1:-all}
pkgs_core="build-essential"
pkgs_test="libcmocka-dev glmark2-data pocl-opencl-icd ocl-icd-opencl-dev opencl-headers libassimp-dev libstb-dev clang clang-format libclang-rt-14-dev valgrind cmake pkg-config"
pkgs_demo="libassimp-dev libstb-dev glmark2-data pocl-opencl-icd ocl-icd-opencl-dev opencl-headers"
pkgs_bench="$pkgs_demo libembree-dev gnuplot-nox"
case "$want" in
  core) list="$pkgs_core" ;;
  test) list="$pkgs_core $pkgs_test" ;;
  demo) list="$pkgs_core $pkgs_demo" ;;
  bench) list="$pkgs_core $pkgs_bench" ;;
  all) list="$pkgs_core $pkgs_test $pkgs_bench" ;;
  *) echo "usage: $0 [core|test|demo|bench|all]" >&2; exit 2 ;;
esac
missing=""
for p in $list; do
  case " $missing " in *" $p "*) continue ;; esac
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
  echo "deps: installing:$missing" >&2
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq >/dev/null && apt-get install -y -qq --no-install-recommends $missing >/dev/null || {
    echo "deps: apt-get install failed for:$missing" >&2; exit 1; }
  exit 0
fi
echo "deps: missing Debian packages:$missing" >&2
echo "deps: install them with: sudo apt-get install$missing" >&2
exit 1
