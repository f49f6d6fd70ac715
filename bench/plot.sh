#!/bin/sh
# The benchmark's PNG plots, from the .dat files `build/bvhbench --plots DIR` writes in DIR:
#   build_time.png    build time vs triangles, log-log, one line per builder (build_time.dat)
#   sah_vs_build.png  SAH (costs 1,0,1) vs build time, one panel per scene     (sah_build.dat)
#   mrays.png         Mrays/s per builder and scene: CPU 1 thread, CPU N threads, OpenCL, and
#                     the diffuse and shadow rays on 1 thread (mrays_1t.dat, mrays_mt.dat,
#                     mrays_cl.dat, mrays_diffuse_1t.dat, mrays_shadow_1t.dat; a panel per file)
# Usage: bench/plot.sh [DIR]     (default out/bench; bvhbench --plots DIR runs it)
#   or directly: gnuplot -c bench/plot.gp DIR
# Exit status: 0 plots written; 1 gnuplot failed; 3 gnuplot is not installed (nothing written).
set -u
dir=${1:-out/bench}
here=$(dirname "$0")
if ! command -v gnuplot >/dev/null 2>&1; then
  echo "plot: gnuplot is not installed (Debian: sudo apt-get install gnuplot-nox): no PNG plots;" \
       "the plot data is in $dir/*.dat" >&2
  exit 3
fi
[ -f "$dir/build_time.dat" ] || { echo "plot: no $dir/build_time.dat (run build/bvhbench --plots $dir)" >&2; exit 1; }
gnuplot -c "$here/plot.gp" "$dir" || { echo "plot: gnuplot failed on $here/plot.gp" >&2; exit 1; }
echo "plot: $dir/build_time.png $dir/sah_vs_build.png $dir/mrays.png" >&2
