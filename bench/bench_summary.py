#!/usr/bin/env python3
"""Condensed Markdown table from bvhbench --json output (the README's Figures section).

usage: bench/bench_summary.py out/bench/bench.json [more.json ...]
One table per scene with the columns a reader compares first; the full tables are in the
--md output of bvhbench. Standard library only.
"""
import json
import sys


def fmt(v, nd):
    if v is None:
        return "-"
    if nd == 0:
        return "%d" % round(v)
    if nd < 0:  # three significant digits, no exponent
        return "%.0f" % v if v >= 100 else "%.3g" % v
    return ("%%.%df" % nd) % v


def main(paths):
    rows = []
    for p in paths:
        with open(p) as f:
            rows += [json.loads(line) for line in f if line.strip()]
    scenes = []
    for r in rows:
        if r["scene"] not in scenes:
            scenes.append(r["scene"])
    cols = [("build ms", "build_ms", -1), ("SAH", "sah", 2), ("B/tri", "bytes_per_tri", 1),
            ("CPU layout B/tri", "wide_bytes_per_tri", 1), ("peak B/tri", "peak_build_bytes_per_tri", 0), ("Mrays/s 1t", "mrays_1t", 1),
            ("Mrays/s 2t", "mrays_mt", 1), ("Mrays/s OpenCL", "mrays_opencl", 1),
            ("diffuse Mrays/s 1t", "diffuse_mrays_1t", 2), ("diffuse Mrays/s 2t", "diffuse_mrays_mt", 2),
            ("shadow Mrays/s 1t", "shadow_mrays_1t", 2), ("shadow Mrays/s 2t", "shadow_mrays_mt", 2),
            ("frame ms", "frame_ms", 1), ("hits", "hits", 0), ("build / Embree med.", "ratio_build", 2),
            ("paired build / Embree med.", "ratio_build_paired", 2), ("SAH / Embree med.", "ratio_sah", 3), ("Mrays 1t / Embree med.", None, 2),
            ("paired Mrays 1t / Embree med.", "ratio_mrays_1t_paired", 2),
            ("paired diffuse 1t / Embree med.", "ratio_diffuse_1t_paired", 2),
            ("paired shadow 1t / Embree med.", "ratio_shadow_1t_paired", 2),
            ("paired OpenCL / CPU 2t", "ratio_opencl_mt_paired", 2)]
    for s in scenes:
        sr = [r for r in rows if r["scene"] == s and r.get("status") == "ok" and r["builder"] != "none"]
        if not sr:
            continue
        emb = [r for r in sr if r["builder"] == "embree-medium"]
        emb1 = emb[0]["mrays_1t"] if emb and emb[0].get("mrays_1t") else None
        print("**%s** (%s triangles)\n" % (s, "{:,}".format(sr[0]["triangles"])))
        print("| builder | " + " | ".join(c[0] for c in cols) + " |")
        print("|:---|" + "---:|" * len(cols))
        for r in sr:
            cells = []
            for name, key, nd in cols:
                if key is None:
                    v = r["mrays_1t"] / emb1 if emb1 and r.get("mrays_1t") and r["kind"] == "bvh.h" else None
                else:
                    v = r.get(key)
                cells.append(fmt(v, nd))
            print("| %s | %s |" % (r["builder"], " | ".join(cells)))
        print()


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
