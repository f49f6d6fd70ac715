/* ab_args.h - what build/abrefit and build/abbuild share: the command line (--builder NAME,
   --rounds N, --threads T, and every other argument a scene, run in turn) and a scene's build
   description. Include after bvh.h and examples/scene.h. */
#ifndef AB_ARGS_H_INCLUDED
#define AB_ARGS_H_INCLUDED

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define AB_MAX_ROUNDS 99

typedef struct ab_opts {
    bvh_builder builder;
    int rounds, max_rounds;
    uint32_t threads, threads_lo, threads_hi; /* --threads takes threads_lo to threads_hi */
} ab_opts;
typedef int (*ab_scene_fn)(const char *spec, const ab_opts *o); /* 0: done */

/* The build description of a scene (a triangle soup, as scene.h loads it) with the options. */
static bvh_build_desc ab_desc(const scene *sc, const ab_opts *o) {
    bvh_build_desc d;
    memset(&d, 0, sizeof d);
    d.builder = o->builder;
    d.threads = o->threads;
    d.triangles.positions = sc->v;
    d.triangles.vertex_count = 3 * sc->triangles;
    d.triangles.triangle_count = sc->triangles;
    return d;
}

/* Parses the options (defaults: builder, 15 rounds, `threads` threads) and runs fn on each scene:
   2 on a usage error, else the OR of fn's returns. */
static int ab_run(int argc, char **argv, const char *prog, bvh_builder builder, uint32_t threads, uint32_t threads_lo,
                  uint32_t threads_hi, ab_scene_fn fn) {
    ab_opts opts, *o = &opts;
    int i, scenes = 0, rc = 0;
    o->builder = builder;
    o->rounds = 15;
    o->max_rounds = AB_MAX_ROUNDS;
    o->threads = threads;
    o->threads_lo = threads_lo;
    o->threads_hi = threads_hi;
    for (i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--builder") && i + 1 < argc) {
            const char *name = argv[++i];
            int k;
            for (k = 1; k < BVH_BUILDER_COUNT && strcmp(name, bvh_builder_name((bvh_builder)k)); k++) {
            }
            if (k == BVH_BUILDER_COUNT) {
                fprintf(stderr, "%s: --builder takes a builder's name (e.g. ploc-parallel, bottom-up)\n", prog);
                return 2;
            }
            o->builder = (bvh_builder)k;
        } else if (!strcmp(argv[i], "--rounds") && i + 1 < argc) {
            o->rounds = atoi(argv[++i]);
            if (o->rounds < 1 || o->rounds > o->max_rounds) {
                fprintf(stderr, "%s: --rounds takes 1 to %d\n", prog, o->max_rounds);
                return 2;
            }
        } else if (!strcmp(argv[i], "--threads") && i + 1 < argc) {
            if (scene_parse_u32(argv[++i], o->threads_lo, o->threads_hi, &o->threads, NULL)) {
                fprintf(stderr, "%s: --threads takes %u to %u\n", prog, o->threads_lo, o->threads_hi);
                return 2;
            }
        } else if (argv[i][0] == '-') {
            break;
        } else {
            rc |= fn(argv[i], o);
            scenes++;
        }
    }
    if (i < argc || !scenes) {
        fprintf(stderr, "usage: build/%s [--builder NAME] [--rounds N] [--threads T] SCENE...\n", prog);
        return 2;
    }
    return rc;
}

#endif
