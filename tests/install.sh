#!/usr/bin/env bash
# tests/install.sh - `make install` gives a bvh.h an application can use: installed into a
#   temporary prefix, tests/install/consumer.c (two triangles, one ray; with OpenCL when present,
#   through the kernel bvh_cl.h holds, run from a directory without cl/trace.cl) builds
#   and runs three ways: pkg-config, CMake's find_package(bvh) and add_subdirectory of the
#   repository. Also: DESTDIR stages under the prefix, the versions agree with bvh.h's macros,
#   find_package refuses a version it cannot give, and `make uninstall` removes every file.
# Usage: tests/install.sh  (`make test` runs it; BUILD=dir picks another build directory, whose
#   install-test/ keeps the prefix and the logs). Prints one line per failed check and a closing
#   result line; exits 1 on failure. Without cmake or pkg-config (scripts/deps.sh test installs
#   them) their checks are skipped with a note.
set -u
cd "$(dirname "$0")/.." || exit 1
repo=$(pwd)
build=${BUILD:-build}
case "$build" in /*) ;; *) build=$repo/$build ;; esac
root=$build/install-test
rm -rf "$root" && mkdir -p "$root/run" || exit 1
prefix=$root/prefix
cc=${CC:-cc}
unset MAKEFLAGS MFLAGS MAKELEVEL # the make that runs the tests is not ours to share
version=$(awk '/^#define BVH_VERSION_(MAJOR|MINOR|PATCH) / { v = v (v == "" ? "" : ".") $3 } END { print v }' bvh.h)
opencl=()
if [ -f /usr/include/CL/cl.h ] && ls /usr/lib/*/libOpenCL.so >/dev/null 2>&1; then
  opencl=(-DBVH_HAVE_OPENCL -DCL_TARGET_OPENCL_VERSION=120)
fi
checks=0
failed=0
skipped=""
fail() { failed=$((failed + 1)); echo "FAIL $*"; }
check() { checks=$((checks + 1)); }
# run NAME CMD...: CMD's output goes to $root/NAME.log; on failure the log is printed
run() {
  local name=$1
  shift
  if "$@" >"$root/$name.log" 2>&1; then return 0; fi
  echo "    $name failed: $*"
  sed 's/^/    | /' "$root/$name.log" | tail -40
  return 1
}
# consumer NAME BINARY: runs it from a directory without cl/, expects the hit (and OpenCL's)
consumer() {
  local out rc
  out=$(cd "$root/run" && "$2" 2>&1)
  rc=$?
  echo "$out" >"$root/$1-run.log"
  if [ "$rc" != 0 ] || ! grep -q "^consumer: bvh $version: hit triangle 0 at t=1$" <<<"$out"; then
    fail "$1: the consumer exited with status $rc, printed: $out"
  elif [ ${#opencl[@]} -gt 0 ] && ! grep -q "^consumer: OpenCL" <<<"$out"; then
    fail "$1: the consumer was built without OpenCL although it is present: $out"
  else
    echo "$1: $(tr '\n' ' ' <<<"$out")"
  fi
}

# DESTDIR: the files land under DESTDIR + PREFIX and name PREFIX, not DESTDIR
check
stage=$root/stage
if run install-destdir make install DESTDIR="$stage" PREFIX=/opt/bvh; then
  for f in include/bvh.h include/bvh/cl/bvh_cl.h share/bvh/trace.cl share/pkgconfig/bvh.pc \
           share/cmake/bvh/bvhConfig.cmake share/cmake/bvh/bvhConfigVersion.cmake; do
    [ -f "$stage/opt/bvh/$f" ] || fail "DESTDIR: $stage/opt/bvh/$f is missing"
  done
  grep -q '^prefix=/opt/bvh$' "$stage/opt/bvh/share/pkgconfig/bvh.pc" || fail "DESTDIR: bvh.pc's prefix is not /opt/bvh"
  ! grep -rq "$stage" "$stage" || fail "DESTDIR: an installed file names the staging directory"
else
  fail "make install DESTDIR=$stage PREFIX=/opt/bvh"
fi

check
run install make install PREFIX="$prefix" || fail "make install PREFIX=$prefix"

# pkg-config
if command -v pkg-config >/dev/null; then
  export PKG_CONFIG_PATH=$prefix/share/pkgconfig
  check
  got=$(pkg-config --modversion bvh 2>&1)
  [ "$got" = "$version" ] || fail "pkg-config --modversion bvh: '$got', bvh.h says $version"
  check
  # shellcheck disable=SC2046 # the flags are words
  if run pkg-config-build "$cc" -std=c11 -Wall -Wextra -Wpedantic -Werror $(pkg-config --cflags bvh) "${opencl[@]}" \
    tests/install/consumer.c -o "$root/consumer-pkg-config" $(pkg-config --libs bvh) ${opencl:+-lOpenCL}; then
    consumer pkg-config "$root/consumer-pkg-config"
  else
    fail "pkg-config: the consumer does not build"
  fi
else
  skipped="$skipped pkg-config (2 checks)"
fi

# CMake: find_package(bvh) from the prefix, then add_subdirectory of the repository
if command -v cmake >/dev/null; then
  check
  if run find-package-configure cmake -S tests/install/find_package -B "$root/find_package" \
       -DCMAKE_PREFIX_PATH="$prefix" -DBVH_WANT="${version%.*}" &&
     run find-package-build cmake --build "$root/find_package"; then
    consumer find_package "$root/find_package/consumer"
  else
    fail "find_package(bvh ${version%.*}): the consumer does not build"
  fi
  check
  if cmake -S tests/install/find_package -B "$root/find_package_99" -DCMAKE_PREFIX_PATH="$prefix" -DBVH_WANT=99.0 \
       >"$root/find-package-99.log" 2>&1; then
    fail "find_package(bvh 99.0) accepted version $version"
  elif ! grep -q "$version" "$root/find-package-99.log"; then
    fail "find_package(bvh 99.0) failed without naming version $version: $(cat "$root/find-package-99.log")"
  fi
  check
  if run add-subdirectory-configure cmake -S tests/install/add_subdirectory -B "$root/add_subdirectory" \
       -DBVH_DIR="$repo" &&
     run add-subdirectory-build cmake --build "$root/add_subdirectory"; then
    consumer add_subdirectory "$root/add_subdirectory/consumer"
  else
    fail "add_subdirectory: the consumer does not build"
  fi
else
  skipped="$skipped cmake (3 checks: cmake is not installed and scripts/deps.sh test could not install it)"
fi

# make uninstall leaves no file behind
check
if run uninstall make uninstall PREFIX="$prefix"; then
  left=$(find "$prefix" -type f)
  [ -z "$left" ] || fail "make uninstall left: $left"
else
  fail "make uninstall PREFIX=$prefix"
fi

[ -n "$skipped" ] && echo "install: skipped:$skipped"
echo "install: $((checks - failed)) of $checks checks passed"
[ "$failed" = 0 ]
