/* abbuild.c - two versions of bvh.h building the same scene in one process, each on the
   library's own threads and on a caller's pool: which is faster, and by how much, on a machine
   whose speed drifts.

   make abtrace AB_REF=<git revision>        (A: bvh.h at that revision; B: the working tree's)
   build/abbuild [--builder NAME] [--rounds N] [--threads T] SCENE...

   Why: as build/abtrace's (bench/ab/abtrace.c), for bvh_build, and for the pool route
   (desc.pool): each round builds the scene four times, A and B on the library's threads and on
   examples/workers.h's pool of T pthreads started once (default 2), the order reversed every
   other round. Prints the medians of the rounds' ms, the medians of the rounds' B/A ratios with
   their min-max (below 1: B is faster), each version's pool time over its threads' time, and
   whether the four trees are the same (their saved files: the same bytes, unless the change is
   meant to alter the tree). */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define SCENE_IMPLEMENTATION
#include "examples/scene.h"
#include "examples/workers.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench/ab/ab.h"
#include "bench/ab/ab_args.h"

/* Build k of a round: bit 0 the version (0: A, 1: B), bit 1 the pool. Milliseconds, or -1; the
   tree's saved bytes into *file when file is not NULL. */
static double ab_build_one(int k, const bvh_build_desc *base, workers *w, void **file, size_t *size) {
    bvh_build_desc d = *base;
    bvh_tree t;
    double t0, ms;
    int r;
    if (k & 2) d.pool = workers_pool(w);
    t0 = scene_now_ms();
    r = (k & 1 ? ab_b_build : ab_a_build)(&t, &d);
    ms = scene_now_ms() - t0;
    if (r != BVH_SUCCESS) return -1.0;
    if (file && !(*size = (k & 1 ? ab_b_save : ab_a_save)(&t, file))) ms = -1.0;
    (k & 1 ? ab_b_free : ab_a_free)(&t);
    return ms;
}

static int ab_scene(const char *spec, const ab_opts *o) {
    const bvh_builder builder = o->builder;
    const int rounds = o->rounds;
    const uint32_t threads = o->threads;
    static const char *const names[4] = {"A threads", "B threads", "A pool", "B pool"};
    scene sc;
    char err[256];
    bvh_build_desc d;
    workers w;
    void *file[4] = {NULL, NULL, NULL, NULL};
    size_t size[4] = {0, 0, 0, 0};
    double ms[4][AB_MAX_ROUNDS], ba[2][AB_MAX_ROUNDS], med[4];
    int r, j, k, rc = 1, va = ab_a_version(), vb = ab_b_version(), same = 1;
    if (scene_load(spec, &sc, err, sizeof err) != 0) {
        fprintf(stderr, "abbuild: %s\n", err);
        return 1;
    }
    if (workers_start(&w, threads) != 0) {
        fprintf(stderr, "abbuild: the pool's threads could not be started\n");
        scene_free(&sc);
        return 1;
    }
    d = ab_desc(&sc, o);
    printf("%s (%u triangles), %s, A = bvh.h %d.%d.%d, B = bvh.h %d.%d.%d: %d rounds, %u thread(s) or tasks\n", sc.name,
           sc.triangles, bvh_builder_name(builder), va / 10000, va / 100 % 100, va % 100, vb / 10000, vb / 100 % 100,
           vb % 100, rounds, threads);
    for (k = 0; k < 4; k++) /* a warm-up build each, whose trees are compared */
        if (ab_build_one(k, &d, &w, &file[k], &size[k]) < 0.0) {
            fprintf(stderr, "abbuild: %s: %s: a build or save failed\n", spec, names[k]);
            goto done;
        }
    for (r = 0; r < rounds; r++) {
        for (j = 0; j < 4; j++) {
            k = r & 1 ? 3 - j : j; /* the order reversed every other round */
            if ((ms[k][r] = ab_build_one(k, &d, &w, NULL, NULL)) < 0.0) {
                fprintf(stderr, "abbuild: %s: %s: a build failed\n", spec, names[k]);
                goto done;
            }
        }
        ba[0][r] = ms[1][r] / ms[0][r];
        ba[1][r] = ms[3][r] / ms[2][r];
    }
    for (k = 0; k < 4; k++) med[k] = scene_median(ms[k], (size_t)rounds);
    for (j = 0; j < 2; j++) {
        const double m = scene_median(ba[j], (size_t)rounds); /* sorts ba[j] */
        printf("  %-8s A %8.2f ms  B %8.2f ms  B/A %.3f (%.3f-%.3f)\n", j ? "pool" : "threads", med[2 * j],
               med[2 * j + 1], m, ba[j][0], ba[j][rounds - 1]);
    }
    printf("  pool / threads: A %.3f  B %.3f\n", med[2] / med[0], med[3] / med[1]);
    for (k = 1; k < 4; k++) same &= size[k] == size[0] && !memcmp(file[k], file[0], size[0]);
    printf("  trees %s\n", same ? "the same (all four)" : "DIFFER");
    rc = 0;
done:
    for (k = 0; k < 4; k++) free(file[k]);
    workers_stop(&w);
    scene_free(&sc);
    return rc;
}

int main(int argc, char **argv) { return ab_run(argc, argv, "abbuild", BVH_BUILDER_DEFAULT, 2, 1, 64, ab_scene); }
