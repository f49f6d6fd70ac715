/* abrefit.c - two versions of bvh.h refitting and loading the same tree in one process: which is
   faster, and by how much, on a machine whose speed drifts.

   make abtrace AB_REF=<git revision>        (A: bvh.h at that revision; B: the working tree's)
   build/abrefit [--builder NAME] [--rounds N] [--threads T] SCENE...        (0: all CPUs)

   Why: as build/abtrace's (bench/ab/abtrace.c), for bvh_refit and bvh_load, whose times this VM's
   spells move by 20% between runs (docs/bench, 0.9.13). Both versions (bench/ab/version.c)
   build their own tree of the scene with the same builder; then each round refits both to the
   other of two vertex sets (the scene and the scene twisted about y), A and B one right after the
   other, the order alternating; then each saves its tree to memory once, and each round loads
   both files the same way. Prints the medians of the rounds' ms and of their B/A time ratios
   (below 1: B is faster) with their min-max, and whether the two saved files are the same bytes
   after the same refits (they are, unless the change is meant to alter the tree). */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define SCENE_IMPLEMENTATION
#include "examples/scene.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench/ab/ab.h"
#include "bench/ab/ab_args.h"

/* One refit (what 0) or load (what 1) with version b (0: A, 1: B): milliseconds, or -1. */
static double ab_step(int b, int what, bvh_tree *tree, const float *v, uint32_t n, const void *file, size_t size,
                      uint32_t threads) {
    double t0 = scene_now_ms(), ms;
    bvh_tree loaded;
    int r;
    if (!what) {
        r = (b ? ab_b_refit : ab_a_refit)(tree, v, n, threads);
        return r == BVH_SUCCESS ? scene_now_ms() - t0 : -1.0;
    }
    r = (b ? ab_b_load : ab_a_load)(&loaded, file, size, threads);
    ms = scene_now_ms() - t0;
    (b ? ab_b_free : ab_a_free)(&loaded); /* outside the time: bvhbench times the load alone too */
    return r == BVH_SUCCESS ? ms : -1.0;
}

static void ab_line(const char *what, double *a, double *b, double *ba, int rounds) {
    const double ma = scene_median(a, (size_t)rounds), mb = scene_median(b, (size_t)rounds);
    const double med = scene_median(ba, (size_t)rounds); /* sorts ba */
    printf("  %-5s A %8.2f ms  B %8.2f ms  B/A %.3f (%.3f-%.3f)\n", what, ma, mb, med, ba[0], ba[rounds - 1]);
}

static int ab_scene(const char *spec, const ab_opts *o) {
    const bvh_builder builder = o->builder;
    const int rounds = o->rounds;
    const uint32_t threads = o->threads;
    scene sc;
    char err[256];
    bvh_build_desc d;
    bvh_tree ta, tb;
    bvh_aabb box;
    float *twisted = NULL, span;
    void *fa = NULL, *fb = NULL;
    size_t na = 0, nb = 0, i;
    double a[2][AB_MAX_ROUNDS], b[2][AB_MAX_ROUNDS], ba[2][AB_MAX_ROUNDS];
    int what, r, rc = 1, va, vb;
    memset(&ta, 0, sizeof ta);
    memset(&tb, 0, sizeof tb);
    if (scene_load(spec, &sc, err, sizeof err) != 0) {
        fprintf(stderr, "abrefit: %s\n", err);
        return 1;
    }
    box = scene_bounds(&sc);
    span = box.max.y > box.min.y ? box.max.y - box.min.y : 1.0f;
    twisted = (float *)malloc((size_t)sc.triangles * 9 * sizeof(float));
    if (!twisted) {
        fprintf(stderr, "abrefit: out of memory\n");
        goto done;
    }
    for (i = 0; i < (size_t)sc.triangles * 3; i++) { /* up to a quarter turn about y, by height */
        const float *p = sc.v + 3 * i, ang = 1.5707963f * (p[1] - box.min.y) / span;
        twisted[3 * i] = p[0] * cosf(ang) - p[2] * sinf(ang);
        twisted[3 * i + 1] = p[1];
        twisted[3 * i + 2] = p[0] * sinf(ang) + p[2] * cosf(ang);
    }
    d = ab_desc(&sc, o);
    if (ab_a_build(&ta, &d) != BVH_SUCCESS || ab_b_build(&tb, &d) != BVH_SUCCESS) {
        fprintf(stderr, "abrefit: %s: a build failed\n", spec);
        goto done;
    }
    va = ab_a_version();
    vb = ab_b_version();
    printf("%s (%u triangles), %s trees, A = bvh.h %d.%d.%d, B = bvh.h %d.%d.%d: %d rounds, %u thread(s) (0: all)\n",
           sc.name, sc.triangles, bvh_builder_name(builder), va / 10000, va / 100 % 100, va % 100, vb / 10000,
           vb / 100 % 100, vb % 100, rounds, threads);
    for (what = 0; what < 2; what++) {
        if (what == 1) { /* the files, once, of the trees as the refits left them */
            na = ab_a_save(&ta, &fa);
            nb = ab_b_save(&tb, &fb);
            if (!na || !nb) {
                fprintf(stderr, "abrefit: %s: a save failed\n", spec);
                goto done;
            }
        }
        for (r = 0; r < rounds; r++) {
            const float *v = r & 1 ? sc.v : twisted; /* every refit moves every vertex */
            if (r & 1) {                             /* the order alternates: neither version always runs first */
                b[what][r] = ab_step(1, what, &tb, v, sc.triangles, fb, nb, threads);
                a[what][r] = ab_step(0, what, &ta, v, sc.triangles, fa, na, threads);
            } else {
                a[what][r] = ab_step(0, what, &ta, v, sc.triangles, fa, na, threads);
                b[what][r] = ab_step(1, what, &tb, v, sc.triangles, fb, nb, threads);
            }
            if (a[what][r] < 0.0 || b[what][r] < 0.0) {
                fprintf(stderr, "abrefit: %s: a %s failed\n", spec, what ? "load" : "refit");
                goto done;
            }
            ba[what][r] = b[what][r] / a[what][r];
        }
        ab_line(what ? "load" : "refit", a[what], b[what], ba[what], rounds);
    }
    printf("  files %s (%zu and %zu bytes)\n", na == nb && !memcmp(fa, fb, na) ? "the same" : "DIFFER", na, nb);
    rc = 0;
done:
    ab_a_free(&ta);
    ab_b_free(&tb);
    free(fa);
    free(fb);
    free(twisted);
    scene_free(&sc);
    return rc;
}

int main(int argc, char **argv) {
    return ab_run(argc, argv, "abrefit", BVH_BUILDER_PLOC_PARALLEL, 0, 0, 256, ab_scene);
}
