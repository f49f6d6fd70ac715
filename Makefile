# bvh.h - build the examples, run the tests, the demo and the benchmark.
#   make            examples and tools (build/render, build/minimal ..., build/bvhbench ...)
#   make demo       the main job: render the bunny with every builder and print a table
#   make test       every test (installs missing Debian packages first when run as root)
#   make bench      the study's Table I, side by side with Embree
#   make install    bvh.h, cl/bvh_cl.h, cl/trace.cl, pkg-config and CMake files (PREFIX, DESTDIR)
#   make abtrace    build/abtrace, build/abrefit: bvh.h at AB_REF (git) against the working tree's
#   make kernel     copies cl/trace.cl into cl/bvh_cl.h (after an edit of the kernel)
#   make format     applies .clang-format to the sources (make format-check: CI's check)
# CFLAGS, CC, CXX may be overridden.
CC      ?= cc
CXX     ?= c++
CFLAGS  ?= -O2 -g
BUILD   ?= build
STD      = -std=c11
WARN     = -Wall -Wextra -Wpedantic -Werror
LDLIBS   = -lm -lpthread

# Parallel compiles inside make test and make robust (the tests themselves run one at a time).
JOBS    ?= $(shell nproc 2>/dev/null || echo 1)

# Optional dependencies, detected (scripts/deps.sh installs them when run as root).
HAVE_OPENCL := $(shell [ -f /usr/include/CL/cl.h ] && ls /usr/lib/*/libOpenCL.so >/dev/null 2>&1 && echo 1)
HAVE_EMBREE := $(shell [ -f /usr/include/embree3/rtcore.h ] && echo 1)
HAVE_ASSIMP := $(shell [ -f /usr/include/assimp/cimport.h ] && echo 1)
HAVE_STB    := $(shell [ -f /usr/include/stb/stb_image_write.h ] && echo 1)

EX_DEFS = $(if $(HAVE_OPENCL),-DBVH_HAVE_OPENCL -DCL_TARGET_OPENCL_VERSION=120) \
          $(if $(HAVE_EMBREE),-DBVH_HAVE_EMBREE) $(if $(HAVE_ASSIMP),-DBVH_HAVE_ASSIMP) \
          $(if $(HAVE_STB),-DBVH_HAVE_STB)
EX_LIBS = $(if $(HAVE_OPENCL),-lOpenCL) $(if $(HAVE_EMBREE),-lembree3) $(if $(HAVE_ASSIMP),-lassimp)

# examples/: programs a user copies; bench/: the benchmark and the Embree comparison (tools). Both
# build into $(BUILD)/NAME.
EXAMPLES = $(patsubst examples/%.c,$(BUILD)/%,$(wildcard examples/*.c))
BENCH    = $(patsubst bench/%.c,$(BUILD)/%,$(wildcard bench/*.c))
TESTS    = $(patsubst tests/%.c,$(BUILD)/tests/%,$(wildcard tests/test_*.c))
HEADERS  = bvh.h $(wildcard examples/*.h) $(wildcard bench/*.h) $(wildcard cl/*.h) $(wildcard cl/*.cl) $(wildcard tests/*.h)

.PHONY: all demo test bench clean deps-test deps-demo deps-bench kernel format format-check install uninstall abtrace
all: $(EXAMPLES) $(BENCH)

$(BUILD)/%: examples/%.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -I. $(EX_DEFS) $< -o $@ $(EX_LIBS) $(LDLIBS)
$(BUILD)/%: bench/%.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -I. $(EX_DEFS) $< -o $@ $(EX_LIBS) $(LDLIBS)
# The programs a user copies build as a user would: strict C11, bvh.h only, no feature macros.
COPYABLE = $(BUILD)/minimal $(BUILD)/boxes $(BUILD)/animate
$(COPYABLE): $(BUILD)/%: examples/%.c bvh.h
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -I. $< -o $@ $(LDLIBS)

# Tests: warnings are errors; test_opencl also links OpenCL.
$(BUILD)/tests/%: tests/%.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -I. $(EX_DEFS) $< -o $@ -lcmocka $(EX_LIBS) $(LDLIBS)

# Compile checks of the header itself, built and run by `make test` (a warning or a wrong answer
# fails it): C11 with BVH_STATIC, with and without threads (tests/compile_static.c); two C
# translation units (tests/two_tu_*.c); C++11 (tests/compile_cpp.cpp); a C++ program linked with
# the implementation compiled as C; BVH_MALLOC without BVH_FREE refused; the traversal and scene
# tests without SSE (BVH_NO_SIMD) and without AVX2, the builder tests without AVX2 (BVH_NO_AVX2). With $(CC)/$(CXX) in
# build/check/cc/, and with clang/clang++ in build/check/clang/ when present. No -D_GNU_SOURCE:
# the header must build in strict ISO mode.
CXXSTD      = -std=c++11
CXXWARN     = -Wall -Wextra -Wpedantic -Werror
HAVE_CLANG := $(shell command -v clang >/dev/null 2>&1 && command -v clang++ >/dev/null 2>&1 && echo 1)
CHECK_CC_cc     = $(CC)
CHECK_CXX_cc    = $(CXX)
CHECK_CC_clang  = clang
CHECK_CXX_clang = clang++
CHECKS = $(foreach c,cc $(if $(HAVE_CLANG),clang),\
           $(addprefix $(BUILD)/check/$(c)/,static static-no-threads two-tu cxx11 cxx11-links-c)) \
         $(if $(HAVE_CLANG),$(BUILD)/check/clang/fast-math-refused) \
         $(BUILD)/check/traversal-no-simd $(BUILD)/check/traversal-no-avx2 \
         $(BUILD)/check/traversal-slab-int $(BUILD)/check/traversal-slab-float \
         $(BUILD)/check/traversal-pair-int $(BUILD)/check/traversal-pair-float $(BUILD)/check/traversal-tune \
         $(BUILD)/check/scene-no-simd $(BUILD)/check/scene-no-avx2 \
         $(BUILD)/check/builders-no-avx2 \
         $(addprefix $(BUILD)/check/,$(addsuffix -fast-math,traversal robust builders refit scene custom pool)) \
         $(BUILD)/check/half-allocator-refused $(BUILD)/check/kernel-embedded \
         $(BUILD)/check/pool-no-threads

$(BUILD)/check/%/static: tests/compile_static.c bvh.h
	@mkdir -p $(dir $@)
	$(CHECK_CC_$*) $(STD) $(WARN) $(CFLAGS) -DBVH_STATIC -I. $< -o $@ $(LDLIBS)
$(BUILD)/check/%/static-no-threads: tests/compile_static.c bvh.h
	@mkdir -p $(dir $@)
	$(CHECK_CC_$*) $(STD) $(WARN) $(CFLAGS) -DBVH_STATIC -DBVH_NO_THREADS -I. $< -o $@ -lm
# The exact-hits traversal test again with the plain-C 8-wide slab test (BVH_NO_SIMD).
$(BUILD)/check/traversal-no-simd: tests/test_traversal.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -DBVH_NO_SIMD -I. $< -o $@ -lcmocka $(LDLIBS)
# The exact-hits traversal test again on the SSE paths only (BVH_NO_AVX2), where the CPU would
# take the AVX2 slab and packet tests.
$(BUILD)/check/traversal-no-avx2: tests/test_traversal.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -DBVH_NO_AVX2 -I. $< -o $@ -lcmocka $(LDLIBS)
# Again with each of the fast AVX2 slab test's two forms, whichever the CPU's vendor picks
# (integer max and min, float ones on AMD).
$(BUILD)/check/traversal-slab-%: tests/test_traversal.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -DBVH__SLAB_FLOAT=$(if $(filter float,$*),1,0) -I. $< -o $@ -lcmocka $(LDLIBS)
# Again with a batch's closest-hit rays always two in turns (BVH__PAIR=1; by default only on large
# trees), in each form of the fast slab test.
$(BUILD)/check/traversal-pair-%: tests/test_traversal.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -DBVH__PAIR=1 -DBVH__SLAB_FLOAT=$(if $(filter float,$*),1,0) -I. $< \
	    -o $@ -lcmocka $(LDLIBS)
# Again with every batch timing both ways where the rule leaves it open (BVH__TUNE_MIN=1; by
# default only batches of 16,384 rays a thread): each sample's rays are traced twice, once each
# way, and the rest by the faster.
$(BUILD)/check/traversal-tune: tests/test_traversal.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -DBVH__TUNE_MIN=1 -I. $< -o $@ -lcmocka $(LDLIBS)
# The scene test likewise: its top level runs the same 8-wide loop with the instance step.
$(BUILD)/check/scene-no-simd: tests/test_scene.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -DBVH_NO_SIMD -I. $< -o $@ -lcmocka $(LDLIBS)
$(BUILD)/check/scene-no-avx2: tests/test_scene.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -DBVH_NO_AVX2 -I. $< -o $@ -lcmocka $(LDLIBS)
# Every example and tool again without the optional packages (no BVH_HAVE_*), as a machine
# without Embree, Assimp, stb or OpenCL builds them: objects only, built by `make test`.
BARE = $(patsubst %.c,$(BUILD)/check/bare/%.o,$(wildcard examples/*.c) $(wildcard bench/*.c))
$(BUILD)/check/bare/%.o: %.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -I. -c $< -o $@
# cl/bvh_cl.h holds the current cl/trace.cl (`make kernel` copies it in after an edit).
$(BUILD)/check/kernel-embedded: cl/trace.cl cl/bvh_cl.h scripts/embed-kernel.sh
	@mkdir -p $(dir $@)
	@scripts/embed-kernel.sh $@.h
	@cmp -s $@.h cl/bvh_cl.h || { echo "cl/bvh_cl.h does not hold the current cl/trace.cl: run make kernel"; exit 1; }
	@printf '#!/bin/sh\necho "cl/bvh_cl.h holds the current cl/trace.cl"\n' >$@
	@chmod +x $@
kernel:
	scripts/embed-kernel.sh
# The repository's .clang-format on every C source (the kernel is formatted in cl/trace.cl and
# copied into cl/bvh_cl.h as it is). `make format` applies it; .ci/run checks it.
FORMAT_FILES = bvh.h cl/bvh_cl.h cl/trace.cl $(wildcard examples/*.c examples/*.h bench/*.c bench/*.h bench/ab/*.c bench/ab/*.h \
               tests/*.c tests/*.h tests/*.cpp tests/install/*.c)
format:
	clang-format -i $(FORMAT_FILES)
	scripts/embed-kernel.sh
format-check:
	@clang-format --dry-run --Werror $(FORMAT_FILES) && echo "format: $(words $(FORMAT_FILES)) files as .clang-format has them"
# The suites that build, trace, refit, load and run scenes again as many renderers compile:
# -O3 -march=native -ffast-math (the implementation keeps IEEE semantics under any flags; see its
# first lines): the same trees and hits as under the test build's flags.
FAST_MATH = -O3 -march=native -ffast-math
$(BUILD)/check/%-fast-math: tests/test_%.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(FAST_MATH) -D_GNU_SOURCE -I. $< -o $@ -lcmocka $(LDLIBS)
# clang cannot undo -ffast-math for part of a file: the header refuses it with #error (checked
# here); clang without it is tested by the clang compile checks above.
$(BUILD)/check/clang/fast-math-refused: tests/compile_static.c bvh.h
	@mkdir -p $(dir $@)
	@if clang $(STD) -ffast-math -DBVH_STATIC -I. -c $< -o $@.o 2>$@.log; then echo "clang -ffast-math was not refused"; exit 1; fi
	@grep -q "with -fno-fast-math" $@.log || { cat $@.log; exit 1; }
	@printf '#!/bin/sh\necho "clang -ffast-math: the implementation is refused with #error, as documented"\n' >$@
	@chmod +x $@
# BVH_MALLOC without BVH_FREE (and the reverse) is refused with #error: a half pair would free
# one allocator's blocks with the other.
$(BUILD)/check/half-allocator-refused: bvh.h
	@mkdir -p $(dir $@)
	@for m in 'BVH_MALLOC(s,u)=malloc(s)' 'BVH_FREE(p,u)=free(p)'; do \
	    if printf '#define BVH_IMPLEMENTATION\n#include "bvh.h"\n' | \
	        $(CC) $(STD) -DBVH_STATIC "-D$$m" -I. -x c -c - -o $@.o 2>$@.log; then \
	        echo "half allocator pair $$m not refused"; exit 1; fi; \
	    grep -q "define both BVH_MALLOC and BVH_FREE" $@.log || { cat $@.log; exit 1; }; \
	done
	@printf '#!/bin/sh\necho "BVH_MALLOC or BVH_FREE alone: refused with #error, as documented"\n' >$@
	@chmod +x $@
# The builder tests again with PLOC's neighbour search on SSE only (BVH_NO_AVX2), where the CPU
# would take the AVX2 path.
$(BUILD)/check/builders-no-avx2: tests/test_builders.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -DBVH_NO_AVX2 -I. $(EX_DEFS) $< -o $@ -lcmocka $(EX_LIBS) $(LDLIBS)
# The pool tests with BVH_NO_THREADS: the route for platforms without pthreads (the library has
# none; the test's own pool still uses them) gives the same trees and hits.
$(BUILD)/check/pool-no-threads: tests/test_pool.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -DBVH_NO_THREADS -I. $< -o $@ -lcmocka $(LDLIBS)
$(BUILD)/check/%/two-tu: tests/two_tu_a.c tests/two_tu_b.c bvh.h
	@mkdir -p $(dir $@)
	$(CHECK_CC_$*) $(STD) $(WARN) $(CFLAGS) -I. tests/two_tu_a.c tests/two_tu_b.c -o $@ $(LDLIBS)
$(BUILD)/check/%/cxx11: tests/compile_cpp.cpp bvh.h
	@mkdir -p $(dir $@)
	$(CHECK_CXX_$*) $(CXXSTD) $(CXXWARN) $(CFLAGS) -I. $< -o $@ $(LDLIBS)
$(BUILD)/check/%/cxx11-links-c: tests/compile_cpp.cpp tests/two_tu_a.c bvh.h
	@mkdir -p $(dir $@)
	$(CHECK_CC_$*) $(STD) $(WARN) $(CFLAGS) -I. -c tests/two_tu_a.c -o $@-impl.o
	$(CHECK_CXX_$*) $(CXXSTD) $(CXXWARN) $(CFLAGS) -I. -DBVH_TEST_DECLARATIONS_ONLY $< $@-impl.o -o $@ $(LDLIBS)

# build/abtrace: bvh.h at AB_REF (a git revision; default HEAD) against the working tree's, in one
# process on the same rays (bench/ab/abtrace.c says why); build/abrefit: the same two versions on
# bvh_refit and bvh_load (bench/ab/abrefit.c); build/abbuild: on bvh_build, on the library's
# threads and on a caller's pool (bench/ab/abbuild.c). Not part of `make`: it needs git.
AB_REF ?= HEAD
abtrace:
	@mkdir -p $(BUILD)/ab/a
	@git show $(AB_REF):bvh.h >$(BUILD)/ab/a/bvh.h.new || { rm -f $(BUILD)/ab/a/bvh.h.new; exit 1; }
	@mv $(BUILD)/ab/a/bvh.h.new $(BUILD)/ab/a/bvh.h
	$(CC) $(STD) $(WARN) $(CFLAGS) -c -DAB_PREFIX=ab_a_ -I$(BUILD)/ab/a bench/ab/version.c -o $(BUILD)/ab/a.o
	$(CC) $(STD) $(WARN) $(CFLAGS) -c -DAB_PREFIX=ab_b_ -I. bench/ab/version.c -o $(BUILD)/ab/b.o
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -I. $(EX_DEFS) bench/ab/abtrace.c $(BUILD)/ab/a.o $(BUILD)/ab/b.o \
	    -o $(BUILD)/abtrace $(EX_LIBS) $(LDLIBS)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -I. $(EX_DEFS) bench/ab/abrefit.c $(BUILD)/ab/a.o $(BUILD)/ab/b.o \
	    -o $(BUILD)/abrefit $(EX_LIBS) $(LDLIBS)
	$(CC) $(STD) $(WARN) $(CFLAGS) -D_GNU_SOURCE -I. $(EX_DEFS) bench/ab/abbuild.c $(BUILD)/ab/a.o $(BUILD)/ab/b.o \
	    -o $(BUILD)/abbuild $(EX_LIBS) $(LDLIBS)
	@echo "build/abtrace, build/abrefit, build/abbuild: A = bvh.h at $(AB_REF), B = the working tree's"

deps-test:
	@scripts/deps.sh test
deps-demo:
	@scripts/deps.sh demo
deps-bench:
	@scripts/deps.sh bench

# tests/exit_codes.sh runs $(BUILD)/render, $(BUILD)/cl_info and $(BUILD)/bvhbench; tests/examples.sh runs
# $(BUILD)/minimal, $(BUILD)/boxes, $(BUILD)/animate and $(BUILD)/pathtrace; tests/install.sh
# installs into $(BUILD)/install-test/ and builds a consumer with pkg-config and CMake.
# scripts/run-tests.sh prints a line per program and keeps every output in $(BUILD)/test-logs/.
test: deps-test
	@$(MAKE) --no-print-directory -j$(JOBS) $(TESTS) $(CHECKS) $(BUILD)/render $(BUILD)/cl_info $(BUILD)/bvhbench $(COPYABLE) \
		$(BUILD)/pathtrace $(BARE)
	@BUILD=$(BUILD) scripts/run-tests.sh $(TESTS) $(CHECKS) tests/exit_codes.sh tests/examples.sh tests/install.sh

demo: deps-demo
	@$(MAKE) --no-print-directory $(BUILD)/render
	@scripts/demo.sh

# Install (header-only: nothing to build). PREFIX (default /usr/local) is where the files are used;
# DESTDIR, if set, is prepended when writing them (staged installs, packages).
#   include/bvh.h              #include "bvh.h"
#   include/bvh/cl/bvh_cl.h    #include "cl/bvh_cl.h" (the .pc and CMake files add include/bvh)
#   share/bvh/trace.cl         the OpenCL kernel's source (bvh_cl.h holds a copy and needs no file)
#   share/pkgconfig/bvh.pc     pkg-config module bvh
#   share/cmake/bvh/           find_package(bvh) gives the INTERFACE target bvh::bvh
# The version is bvh.h's BVH_VERSION_* macros, read here.
PREFIX  ?= /usr/local
DESTDIR ?=
VERSION := $(shell awk '/^.define BVH_VERSION_(MAJOR|MINOR|PATCH) / { v = v (v == "" ? "" : ".") $$3 } END { print v }' bvh.h)
KERNEL   = $(PREFIX)/share/bvh/trace.cl
INSTALLED = include/bvh.h include/bvh/cl/bvh_cl.h share/bvh/trace.cl share/pkgconfig/bvh.pc \
            share/cmake/bvh/bvhConfig.cmake share/cmake/bvh/bvhConfigVersion.cmake
SUBST    = sed -e 's|@PREFIX@|$(PREFIX)|g' -e 's|@KERNEL@|$(KERNEL)|g' -e 's|@VERSION@|$(VERSION)|g' \
               -e 's|@MAJOR@|$(word 1,$(subst ., ,$(VERSION)))|g' -e 's|@MINOR@|$(word 2,$(subst ., ,$(VERSION)))|g'
install:
	@case "$(PREFIX)" in /*) ;; *) echo "install: PREFIX must be an absolute path, not '$(PREFIX)'"; exit 1 ;; esac
	@case "$(VERSION)" in [0-9]*.[0-9]*.[0-9]*) ;; *) echo "install: no version in bvh.h's BVH_VERSION_* macros"; exit 1 ;; esac
	install -d $(DESTDIR)$(PREFIX)/include/bvh/cl $(DESTDIR)$(PREFIX)/share/bvh \
	  $(DESTDIR)$(PREFIX)/share/pkgconfig $(DESTDIR)$(PREFIX)/share/cmake/bvh
	install -m 644 bvh.h $(DESTDIR)$(PREFIX)/include/bvh.h
	install -m 644 cl/trace.cl $(DESTDIR)$(KERNEL)
	install -m 644 cl/bvh_cl.h $(DESTDIR)$(PREFIX)/include/bvh/cl/bvh_cl.h
	$(SUBST) packaging/bvh.pc.in >$(DESTDIR)$(PREFIX)/share/pkgconfig/bvh.pc
	$(SUBST) packaging/bvhConfig.cmake.in >$(DESTDIR)$(PREFIX)/share/cmake/bvh/bvhConfig.cmake
	$(SUBST) packaging/bvhConfigVersion.cmake.in >$(DESTDIR)$(PREFIX)/share/cmake/bvh/bvhConfigVersion.cmake
	@echo "installed bvh.h $(VERSION) into $(DESTDIR)$(PREFIX)"
# Removes the files install writes, then the directories of its own that are left empty.
uninstall:
	rm -f $(addprefix $(DESTDIR)$(PREFIX)/,$(INSTALLED))
	-rmdir $(DESTDIR)$(PREFIX)/include/bvh/cl $(DESTDIR)$(PREFIX)/include/bvh $(DESTDIR)$(PREFIX)/share/bvh \
	  $(DESTDIR)$(PREFIX)/share/cmake/bvh 2>/dev/null

clean:
	rm -rf $(BUILD) out

# Further targets (sanitizers, fuzzing, benchmarks) live in mk/*.mk
-include $(wildcard mk/*.mk)
