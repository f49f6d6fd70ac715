# make bench - the study's Table I, reproduced and extended, side by side with Embree
#   (bench/bvhbench.c). Installs what it needs first (scripts/deps.sh bench: Embree, PoCL,
#   assimp, stb, glmark2-data's bunny, gnuplot), builds build/bvhbench and runs it on the default
#   scenes (gen:random:500, the bunny, gen:field:15 ~1M, gen:field:44 ~3M triangles), writing
#   $(BENCH_OUT)/bench.md, bench.json, the plot data (*.dat) and the PNG plots. Every tracer runs
#   the camera rays and the diffuse and shadow rays made from their hits (examples/rays.h).
#   The full run takes several minutes. Variables:
#     BENCH_OUT=DIR         output directory (default out/bench)
#     BENCH_SCENES="..."    scenes instead of the defaults (as build/render takes them)
#     BENCH_ARGS="..."      more options, e.g. BENCH_ARGS="--repeat 2 --size 512x512 --threads 2"
#     BENCH_PAIRED=N        rounds of interleaved builds, and of 1-thread tracing of each ray set,
#                           against Embree medium (default 5; 0: none)
BENCH_OUT    ?= out/bench
BENCH_PAIRED ?= 5
BENCH_SCENES ?=
BENCH_ARGS   ?=

bench: deps-bench
	@$(MAKE) --no-print-directory $(BUILD)/bvhbench
	@mkdir -p $(BENCH_OUT)
	$(BUILD)/bvhbench --md $(BENCH_OUT)/bench.md --json $(BENCH_OUT)/bench.json --plots $(BENCH_OUT) \
	    --paired $(BENCH_PAIRED) $(BENCH_ARGS) $(BENCH_SCENES)
