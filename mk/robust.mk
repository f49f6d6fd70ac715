# mk/robust.mk - sanitizers and fuzzing (included by the Makefile; uses its BUILD, STD, HEADERS,
# EX_DEFS, EX_LIBS and LDLIBS).
#   make asan      every tests/test_*.c built with ASan + UBSan (-fno-sanitize-recover) and run
#                  (build/asan/)
#   make tsan      the parallel builder and batch tracing tests (test_robust: test_threads_*,
#                  2..8 threads) under TSan (build/tsan/)
#   make fuzz      tests/fuzz_build.c under libFuzzer + ASan + UBSan (build/fuzz/): replays every
#                  input of tests/fuzz/, then fuzzes FUZZ_SECONDS (default 120) over a copy of it;
#                  then tests/fuzz_load.c (bvh_load) the same way over tests/fuzz/load/
#                  (build/fuzz-load/, FUZZ_LOAD_SECONDS, default 60; its seeds: see the file).
#                  A failure leaves its reproducer in build/fuzz/ (crash-*, leak-*, timeout-*);
#                  once fixed, add it to tests/fuzz/ under a descriptive name. Seeds:
#                  scripts/fuzz-seeds.py regenerates the seed-* files.
#   make robust    asan + tsan + fuzz (about 5 minutes on 2 cores with FUZZ_SECONDS=120)
# SAN_CC and FUZZ_CC may be overridden (SAN_CC=gcc works for asan and tsan; fuzz needs clang).
SAN_CC       ?= $(if $(shell command -v clang 2>/dev/null),clang,$(CC))
FUZZ_CC      ?= clang
FUZZ_SECONDS ?= 120
FUZZ_LOAD_SECONDS ?= 60
SAN_WARN      = -Wall -Wextra -Wpedantic
ASAN_FLAGS    = -g -O1 -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=undefined
TSAN_FLAGS    = -g -O1 -fsanitize=thread
FUZZ_FLAGS    = -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined

ASAN_TESTS = $(patsubst tests/%.c,$(BUILD)/asan/%,$(wildcard tests/test_*.c))
TSAN_TESTS = $(BUILD)/tsan/test_robust $(BUILD)/tsan/test_pool
FUZZ_BIN   = $(BUILD)/fuzz/fuzz_build
FUZZ_LOAD_BIN = $(BUILD)/fuzz/fuzz_load

.PHONY: asan tsan fuzz robust

$(BUILD)/asan/%: tests/%.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(SAN_CC) $(STD) $(SAN_WARN) $(ASAN_FLAGS) -D_GNU_SOURCE -I. $(EX_DEFS) $< -o $@ -lcmocka $(EX_LIBS) $(LDLIBS)

$(BUILD)/tsan/%: tests/%.c $(HEADERS)
	@mkdir -p $(dir $@)
	$(SAN_CC) $(STD) $(SAN_WARN) $(TSAN_FLAGS) -D_GNU_SOURCE -I. $< -o $@ -lcmocka $(LDLIBS)

$(FUZZ_BIN): tests/fuzz_build.c bvh.h
	@mkdir -p $(dir $@)
	$(FUZZ_CC) $(STD) $(SAN_WARN) $(FUZZ_FLAGS) -D_GNU_SOURCE -I. $< -o $@ -lm -lpthread
$(FUZZ_LOAD_BIN): tests/fuzz_load.c bvh.h tests/tree_diff.h
	@mkdir -p $(dir $@)
	$(FUZZ_CC) $(STD) $(SAN_WARN) $(FUZZ_FLAGS) -D_GNU_SOURCE -I. $< -o $@ -lm -lpthread

asan: deps-test
	@$(MAKE) --no-print-directory -j$(JOBS) $(ASAN_TESTS)
	@scripts/sanitize.sh asan $(ASAN_TESTS)

tsan: deps-test
	@$(MAKE) --no-print-directory -j$(JOBS) $(TSAN_TESTS)
	@scripts/sanitize.sh tsan $(TSAN_TESTS)

fuzz: deps-test
	@$(MAKE) --no-print-directory -j$(JOBS) $(FUZZ_BIN) $(FUZZ_LOAD_BIN)
	@rc=0; scripts/sanitize.sh fuzz $(FUZZ_BIN) tests/fuzz $(BUILD)/fuzz $(FUZZ_SECONDS) || rc=1; \
	scripts/sanitize.sh fuzz $(FUZZ_LOAD_BIN) tests/fuzz/load $(BUILD)/fuzz-load $(FUZZ_LOAD_SECONDS) || rc=1; exit $$rc

# Each part runs even if an earlier one failed; the target fails if any did.
robust:
	@rc=0; \
	for t in asan tsan fuzz; do \
	  s=$$(date +%s); $(MAKE) --no-print-directory $$t || rc=1; \
	  echo "== make $$t: $$(( $$(date +%s) - s )) s"; \
	done; exit $$rc
