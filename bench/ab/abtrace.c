/* abtrace.c - two versions of bvh.h on the same rays in one process: which is faster, and by how
   much, on a machine whose speed drifts.

   make abtrace AB_REF=<git revision>        (A: bvh.h at that revision; B: the working tree's)
   build/abtrace [--builder ploc-parallel|sah-midpoint] [--rounds N] [--loop L] [--camera outside|inside]
                 SCENE...

   Why: bvhbench pairs bvh.h with Embree inside a run, but two versions of bvh.h are two runs,
   and this VM's speed drifts in spells of seconds to minutes that move bvh.h by 25% and Embree by
   6% (docs/bench, 0.9.11): a spell over one run and not the other reads as a 20% change. Here
   both versions (bench/ab/version.c, compiled once against each bvh.h, each BVH_STATIC) build
   their own tree of the scene, and each round traces every ray set with A and with B one right
   after the other (the order alternating), and with Embree 3 medium around them when it is
   built in (BVH_HAVE_EMBREE). Ray sets: the standard camera's 1024x1024 primary rays (--camera
   inside: rays.h's interior view, as bvhbench's: a room's rays, which stop in a leaf) and the
   bounce and shadow rays made from their hits (examples/rays.h), as bvhbench has them; each
   pass traces its set L times on one thread (the batch calls). Prints, per set, the median of
   the rounds' B/A speed ratios with their min-max, the medians against Embree, and whether A's
   and B's hits are the same bytes (they must be, unless the change is meant to alter hits). */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define SCENE_IMPLEMENTATION
#include "examples/scene.h"
#define RAYS_IMPLEMENTATION
#include "examples/rays.h"
#define EMB_IMPLEMENTATION
#include "bench/embree_side.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench/ab/ab.h"

#define AB_MAX_ROUNDS 99

typedef struct ab_set {
    const char *name;
    const bvh_ray *rays;
    size_t count;
    int any; /* shadow rays: any hit */
} ab_set;

typedef struct ab_out {
    bvh_hit *hits;
    uint8_t *occluded;
} ab_out;

/* One pass of set s, loop times over, with version b (0: A, 1: B): milliseconds. */
static double ab_pass(int b, const bvh_tree *tree, const ab_set *s, int loop, ab_out *out) {
    double t0 = scene_now_ms();
    int k;
    for (k = 0; k < loop; k++) {
        if (s->any)
            (b ? ab_b_occluded : ab_a_occluded)(tree, s->rays, out->occluded, s->count);
        else
            (b ? ab_b_intersect : ab_a_intersect)(tree, s->rays, out->hits, s->count);
    }
    return scene_now_ms() - t0;
}

/* The same pass with Embree 3 medium (emb_builder_rays on one thread, into scratch arrays t,
   prim and occluded): milliseconds. */
static double ab_embree_pass(emb_builder *eb, const ab_set *s, int loop, float *t, uint32_t *prim, uint8_t *occluded) {
    double total = 0.0, ms = 0.0;
    int k;
    for (k = 0; k < loop; k++) {
        if (s->any)
            emb_builder_rays(eb, s->rays, s->count, 1, NULL, NULL, occluded, &ms);
        else
            emb_builder_rays(eb, s->rays, s->count, 1, t, prim, NULL, &ms);
        total += ms;
    }
    return total;
}

static int ab_scene(const char *spec, bvh_builder builder, int rounds, int loop, int inside) {
    scene sc;
    char err[256];
    bvh_build_desc d;
    bvh_tree ta, tb;
    bvh_camera cam;
    bvh_ray *primary = NULL;
    bvh_hit *hits = NULL;
    rays_set rs;
    ab_out oa, ob;
    ab_set sets[3];
    const uint32_t w = 1024, h = 1024;
    size_t n = (size_t)w * h, i;
    int k, r, rc = 1, va, vb;
    emb_builder *eb = NULL; /* NULL: no Embree figures */
    float *et = NULL;
    uint32_t *ep = NULL;
    uint8_t *eo = NULL;
    memset(&rs, 0, sizeof rs);
    memset(&ta, 0, sizeof ta);
    memset(&tb, 0, sizeof tb);
    if (scene_load(spec, &sc, err, sizeof err) != 0) {
        fprintf(stderr, "abtrace: %s\n", err);
        return 1;
    }
    memset(&d, 0, sizeof d);
    d.builder = builder;
    d.triangles.positions = sc.v;
    d.triangles.vertex_count = 3 * sc.triangles;
    d.triangles.triangle_count = sc.triangles;
    oa.hits = (bvh_hit *)malloc(n * sizeof(bvh_hit));
    ob.hits = (bvh_hit *)malloc(n * sizeof(bvh_hit));
    oa.occluded = (uint8_t *)malloc(n);
    ob.occluded = (uint8_t *)malloc(n);
    primary = (bvh_ray *)malloc(n * sizeof(bvh_ray));
    hits = (bvh_hit *)malloc(n * sizeof(bvh_hit));
    if (!oa.hits || !ob.hits || !oa.occluded || !ob.occluded || !primary || !hits) {
        fprintf(stderr, "abtrace: out of memory\n");
        goto done;
    }
    if (ab_a_build(&ta, &d) != BVH_SUCCESS || ab_b_build(&tb, &d) != BVH_SUCCESS) {
        fprintf(stderr, "abtrace: %s: a build failed\n", spec);
        goto done;
    }
    cam = inside ? rays_camera_inside(bvh_tree_bounds(&tb), w, h) : bvh_camera_standard(bvh_tree_bounds(&tb), w, h);
    for (i = 0; i < n; i++) primary[i] = bvh_camera_ray(&cam, (uint32_t)(i % w), (uint32_t)(i / w));
    ab_b_intersect(&tb, primary, hits, n);
    if (rays_make(&cam, hits, sc.v, bvh_tree_bounds(&tb), &rs) != 0) {
        fprintf(stderr, "abtrace: out of memory\n");
        goto done;
    }
    sets[0].name = "camera";
    sets[0].rays = primary;
    sets[0].count = n;
    sets[0].any = 0;
    sets[1].name = "bounce";
    sets[1].rays = rs.diffuse;
    sets[1].count = rs.ndiffuse;
    sets[1].any = 0;
    sets[2].name = "shadow";
    sets[2].rays = rs.shadow;
    sets[2].count = rs.nshadow;
    sets[2].any = 1;
    et = (float *)malloc(n * sizeof(float));
    ep = (uint32_t *)malloc(n * sizeof(uint32_t));
    eo = (uint8_t *)malloc(n);
    if (et && ep && eo && emb_available()) { /* Embree medium's scene, default flags, as bvhbench's */
        if (emb_builder_open(&eb, EMB_QUALITY_MEDIUM, 1, 0, NULL) != EMB_OK)
            eb = NULL;
        else if (emb_builder_keep(eb, sc.v, sc.triangles) != EMB_OK) {
            emb_builder_close(eb);
            eb = NULL;
        }
    }
    va = ab_a_version();
    vb = ab_b_version();
    printf("%s (%u triangles), %s trees, %s camera, A = bvh.h %d.%d.%d, B = bvh.h %d.%d.%d: %d rounds, each set traced "
           "%d time(s) a pass\n",
           sc.name, sc.triangles, d.builder == BVH_BUILDER_SAH_MIDPOINT ? "sah-midpoint" : "ploc-parallel",
           inside ? "interior" : "standard", va / 10000, va / 100 % 100, va % 100, vb / 10000, vb / 100 % 100, vb % 100,
           rounds, loop);
    for (k = 0; k < 3; k++) {
        double ba[AB_MAX_ROUNDS], ae[AB_MAX_ROUNDS], be[AB_MAX_ROUNDS];
        double med;
        int same, have_e = 0;
        for (r = 0; r < rounds; r++) {
            double a, b, e = 0.0;
            if (eb) {
                e = ab_embree_pass(eb, &sets[k], loop, et, ep, eo);
                have_e = 1;
            }
            if (r & 1) { /* the order alternates: neither version always runs first */
                b = ab_pass(1, &tb, &sets[k], loop, &ob);
                a = ab_pass(0, &ta, &sets[k], loop, &oa);
            } else {
                a = ab_pass(0, &ta, &sets[k], loop, &oa);
                b = ab_pass(1, &tb, &sets[k], loop, &ob);
            }
            if (eb) e = 0.5 * (e + ab_embree_pass(eb, &sets[k], loop, et, ep, eo)); /* before and after */
            ba[r] = a / b;                                                          /* B's speed over A's */
            ae[r] = e / a;
            be[r] = e / b;
        }
        same = sets[k].any ? !memcmp(oa.occluded, ob.occluded, sets[k].count)
                           : !memcmp(oa.hits, ob.hits, sets[k].count * sizeof(bvh_hit));
        med = scene_median(ba, (size_t)rounds); /* sorts ba */
        printf("  %-6s %8zu rays  B/A %.3f (%.3f-%.3f)", sets[k].name, sets[k].count, med, ba[0], ba[rounds - 1]);
        if (have_e)
            printf("  vs Embree medium: A %.3f  B %.3f", scene_median(ae, (size_t)rounds),
                   scene_median(be, (size_t)rounds));
        printf("  hits %s\n", same ? "the same" : "DIFFER");
    }
    rc = 0;
done:
    if (eb) emb_builder_close(eb);
    free(et);
    free(ep);
    free(eo);
    ab_a_free(&ta);
    ab_b_free(&tb);
    rays_free(&rs);
    free(primary);
    free(hits);
    free(oa.hits);
    free(ob.hits);
    free(oa.occluded);
    free(ob.occluded);
    scene_free(&sc);
    return rc;
}

int main(int argc, char **argv) {
    bvh_builder builder = BVH_BUILDER_PLOC_PARALLEL;
    int rounds = 11, loop = 2, i, scenes = 0, rc = 0, inside = 0;
    for (i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--builder") && i + 1 < argc) {
            const char *b = argv[++i];
            if (!strcmp(b, "sah-midpoint"))
                builder = BVH_BUILDER_SAH_MIDPOINT;
            else if (strcmp(b, "ploc-parallel")) {
                fprintf(stderr, "abtrace: --builder takes ploc-parallel or sah-midpoint\n");
                return 2;
            }
        } else if (!strcmp(argv[i], "--rounds") && i + 1 < argc) {
            rounds = atoi(argv[++i]);
            if (rounds < 1 || rounds > AB_MAX_ROUNDS) {
                fprintf(stderr, "abtrace: --rounds takes 1 to %d\n", AB_MAX_ROUNDS);
                return 2;
            }
        } else if (!strcmp(argv[i], "--loop") && i + 1 < argc) {
            loop = atoi(argv[++i]);
            if (loop < 1 || loop > 1000) {
                fprintf(stderr, "abtrace: --loop takes 1 to 1000\n");
                return 2;
            }
        } else if (!strcmp(argv[i], "--camera") && i + 1 < argc) {
            const char *v = argv[++i];
            if (strcmp(v, "outside") && strcmp(v, "inside")) {
                fprintf(stderr, "abtrace: --camera takes outside or inside\n");
                return 2;
            }
            inside = !strcmp(v, "inside");
        } else if (argv[i][0] == '-') {
            fprintf(stderr, "usage: build/abtrace [--builder ploc-parallel|sah-midpoint] [--rounds N] [--loop L] "
                            "[--camera outside|inside] SCENE...\n");
            return 2;
        } else {
            rc |= ab_scene(argv[i], builder, rounds, loop, inside);
            scenes++;
        }
    }
    if (!scenes) {
        fprintf(stderr, "usage: build/abtrace [--builder ploc-parallel|sah-midpoint] [--rounds N] [--loop L] "
                        "[--camera outside|inside] SCENE...\n");
        return 2;
    }
    return rc;
}
