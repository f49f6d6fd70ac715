#!/usr/bin/env python3
"""The README's picture: one-thread tracing speed against Embree medium, per scene and ray kind.

usage: bench/ratio_chart.py OUT.png BUILDER bench.json [more.json ...]
Reads bvhbench --json rows (run with --paired N) and draws, for BUILDER's tree on every scene
(rows of a --camera inside run labelled "<scene> inside"),
the median paired ratio of its Mrays/s over Embree medium's on camera, diffuse and shadow rays
(the title names Embree's scene flags from the rows' embree_flags; rows from before that key:
the robust flag),
as bars on a linear axis with Embree at 1 (the min-max of the rounds as error bars). Needs
gnuplot (Debian gnuplot-nox). Standard library only.
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile

KINDS = [("camera", "ratio_mrays_1t_paired"), ("diffuse", "ratio_diffuse_1t_paired"),
         ("shadow", "ratio_shadow_1t_paired")]


def main(out, builder, paths):
    rows = []
    for p in paths:
        with open(p) as f:
            rows += [json.loads(line) for line in f if line.strip()]
    rows = [r for r in rows if r.get("builder") == builder and r.get("status") == "ok"]
    if not rows:
        sys.exit("ratio_chart: no rows of %s with paired ratios" % builder)
    with tempfile.TemporaryDirectory() as tmp:
        dat = os.path.join(tmp, "ratios.dat")
        with open(dat, "w") as f:
            f.write("# scene " + " ".join("%s lo hi" % k for k, _ in KINDS) + "\n")
            for r in rows:
                cells = []
                for _, key in KINDS:
                    v = r.get(key)
                    lo, hi = r.get(key + "_min", v), r.get(key + "_max", v)
                    cells += ["%.3f %.3f %.3f" % (v, lo, hi) if v is not None else "NaN NaN NaN"]
                name = r["scene"].replace(".glb", "").replace(".obj", "")
                if r.get("camera") == "inside":  # bvhbench --camera inside: an interior's rays
                    name += " inside"
                f.write('"%s" %s\n' % (name, " ".join(cells)))
        flags = sorted({r.get("embree_flags") or "robust" for r in rows})  # before the key: robust
        flags = "default flags" if flags == ["default"] else "robust flag" if flags == ["robust"] else "mixed flags"
        top = max([1.2] + [r.get(k + "_max") or 0 for r in rows for _, k in KINDS]) * 1.1
        script = f"""
set terminal pngcairo size {max(900, 160 * len(rows))},420 font "sans,11" noenhanced
set output "{out}"
set title "bvh.h ({builder} tree) against Embree 3 medium ({flags}): Mrays/s on one thread, same rays"
set ylabel "bvh.h / Embree  (1 = as fast)"
set yrange [0:{top:.2f}]
set style data histograms
set style histogram errorbars gap 2 lw 1
set style fill solid 0.8 border -1
set key top left
set grid ytics
set arrow from graph 0, first 1 to graph 1, first 1 nohead lw 2 dt 2 lc rgb "black"
plot "{dat}" using 2:3:4:xtic(1) title "camera rays", '' using 5:6:7 title "diffuse bounces", \\
     '' using 8:9:10 title "shadow rays"
"""
        subprocess.run(["gnuplot"], input=script.encode(), check=True)


if __name__ == "__main__":
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    if shutil.which("gnuplot") is None:  # as bench/plot.sh: say what to install, write nothing
        print("ratio_chart: gnuplot is not installed (Debian: sudo apt-get install gnuplot-nox)", file=sys.stderr)
        sys.exit(3)
    main(sys.argv[1], sys.argv[2], sys.argv[3:])
