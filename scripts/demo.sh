#!/usr/bin/env bash
# The demo: builds a BVH over the Stanford bunny with every builder, renders one frame with each to
# out/demo-<builder>.png, writes its traversal heat map (nodes visited per pixel, one fixed colour
# scale for all builders) to out/heat-<builder>.png and prints a table (build time, SAH, tree size,
# hits, nodes visited per ray, trace backend, frame time, ray throughput).
# Usage: scripts/demo.sh [SCENE]     (`make demo` runs it; SCENE as for build/render --help)
#   default SCENE: /usr/share/glmark2/models/bunny.obj, or gen:procedural:100000 when the Debian
#   package glmark2-data is missing.
# Environment: DEMO_SIZE (800x600), DEMO_THREADS (0 = all cores), DEMO_TRACE (cpu or opencl;
#   default: render's choice, OpenCL when a device is found), DEMO_HEAT_MAX (top of the heat maps'
#   scale in nodes, 200), RENDER (a render binary to use instead of building build/render).
# Exit status: 0 when every builder ran and all report the same hits (render itself fails when
#   OpenCL's hits are not the CPU's); 1 otherwise.
set -u
cd "$(dirname "$0")/.." || exit 1
size=${DEMO_SIZE:-800x600}
threads=${DEMO_THREADS:-0}
trace=${DEMO_TRACE:-}
heat_max=${DEMO_HEAT_MAX:-200}
builders="top-down bottom-up sah-midpoint ploc ploc-parallel"
bunny=/usr/share/glmark2/models/bunny.obj

render=${RENDER:-}
if [ -z "$render" ]; then
  render=build/render
  make --no-print-directory -s "$render" || { echo "demo: cannot build $render" >&2; exit 1; }
fi
[ -x "$render" ] || { echo "demo: $render is not an executable" >&2; exit 1; }

if [ $# -ge 1 ]; then
  scene=$1
elif [ -f "$bunny" ]; then
  scene=$bunny
else
  scene=gen:procedural:100000
  echo "demo: the Stanford bunny ($bunny) is missing: install it with" >&2
  echo "demo:   sudo apt-get install glmark2-data" >&2
  echo "demo: rendering $scene instead" >&2
fi

ext=png
if ! "$render" --help | grep -q 'png=yes'; then
  ext=ppm
  echo "demo: build/render was built without PNG support (Debian libstb-dev): writing .ppm images" >&2
fi

mkdir -p out || exit 1
echo "scene $scene, ${size} pixels, threads ${threads} (0 = all cores)"
results=""
failed=""
for b in $builders; do
  if line=$("$render" --json --builder "$b" --size "$size" --threads "$threads" ${trace:+--trace "$trace"} \
              --heat-max "$heat_max" --out "out/demo-$b.$ext" --heatmap "out/heat-$b.$ext" "$scene"); then
    results="$results$line"$'\n'
    # the first run picked the backend (and said so if OpenCL is missing): keep it for the others
    [ -n "$trace" ] || trace=$(printf '%s' "$line" | sed -n 's/.*"trace":"\([a-z]*\)".*/\1/p')
  else
    failed="$failed $b"
  fi
done

# One JSON object per line, flat, produced by render: pull each value out with awk.
printf '%s' "$results" | awk '
  function get(key,   s) {
    if (!match($0, "\"" key "\":(\"[^\"]*\"|[^,}]*)")) return "?"
    s = substr($0, RSTART + length(key) + 3, RLENGTH - length(key) - 3)
    gsub(/"/, "", s)
    return s
  }
  BEGIN {
    fmt = "%-14s %9s %9s %8s %8s %5s %7s %9s %7s %9s %8s %8s\n"
    printf fmt, "builder", "triangles", "build ms", "SAH", "nodes", "depth", "hits", "nodes/ray", "trace",
           "frame ms", "Mrays/s", "CL Mr/s"
  }
  {
    n++
    hits[n] = get("hits"); tsum[n] = get("t_sum"); name[n] = get("builder"); dev = get("device")
    cl = get("cl_mrays"); if (cl != "null" && cl != "?") cl = sprintf("%.2f", cl); else cl = "-"
    printf "%-14s %9s %9.2f %8.3f %8s %5s %7s %9.2f %7s %9.2f %8.2f %8s\n", name[n], get("triangles"),
           get("build_ms"), get("sah"), get("nodes"), get("max_depth"), hits[n], get("heat_mean"), get("trace"),
           get("frame_ms"), get("mrays"), cl
  }
  END {
    bad = 0
    for (i = 2; i <= n; i++) if (hits[i] != hits[1] || tsum[i] != tsum[1]) bad = 1
    if (bad) {
      print "!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!"
      print "!!! WARNING: the builders DISAGREE on the primary hits (they must all be equal):"
      for (i = 1; i <= n; i++) printf "!!!   %-14s hits %s  t_sum %s\n", name[i], hits[i], tsum[i]
      print "!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!"
      exit 1
    }
    if (n) printf "all %d builders agree: %s hits, t_sum %s; traced on %s\n", n, hits[1], tsum[1], dev
    if (n) print "frame ms: median frame of the backend; Mrays/s: CPU; CL Mr/s: OpenCL; nodes/ray: mean nodes visited"
  }'
agree=$?

[ -n "$results" ] && echo "images: out/demo-<builder>.$ext, heat maps (0..$heat_max nodes): out/heat-<builder>.$ext"
if [ -n "$failed" ]; then
  echo "demo: FAILED for:$failed (see the messages above)" >&2
  exit 1
fi
exit $agree
