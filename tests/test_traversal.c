/* tests/test_traversal.c - every builder's tree gives exactly the brute-force hits.

   For each scene of test_util.h and each builder: bvh_intersect equals the brute-force closest
   hit (same primitive, bitwise-same t, u, v) on TU_RAYS rays of every kind, also with tmax set to
   the hit distance and just below it; bvh_occluded equals "a closest hit exists";
   bvh_intersect_counted equals bvh_intersect; the batch calls on 1, 2, 3, 8 and all threads equal
   the single-ray calls. bvh_intersect and bvh_occluded are checked on the default 8-wide copy and
   on a binary-only tree (trace_width 2); bvh_intersect_counted always walks the binary nodes. The same on the rays a
   renderer traces from surfaces (bounce rays on and just off a triangle, shadow rays, grazing rays). Also: invalid rays
   miss, a tree exactly BVH_MAX_DEPTH deep traces, and the wide nodes' slots are in any-hit order. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"
#include "test_util.h"

#define MAX_REPORTS 4

/* Compares one builder's tree with the brute-force hits; returns the number of mismatches and
   prints the first few. */
static size_t compare(const tu_scene *s, const bvh_tree *t, const bvh_ray *rays, const bvh_hit *want, size_t count) {
    size_t i, bad = 0;
    for (i = 0; i < count; i++) {
        bvh_hit h, hc;
        uint32_t visited = 0;
        int found = bvh_intersect(t, &rays[i], &h);
        int occ = bvh_occluded(t, &rays[i]);
        int foundc = bvh_intersect_counted(t, &rays[i], &hc, &visited);
        int want_found = want[i].prim != BVH_INVALID;
        if (found == want_found && tu_hit_equal(&h, &want[i]) && occ == want_found && foundc == found &&
            tu_hit_equal(&hc, &h) && visited >= 1)
            continue;
        if (bad++ < MAX_REPORTS) {
            print_error("%s/%s: ray %zu (kind %zu): intersect %d occluded %d counted %d (visited %u), brute force %d\n",
                        s->name, bvh_builder_name(t->builder), i, i % 10, found, occ, foundc, visited, want_found);
            tu_print_ray(&rays[i]);
            tu_print_hit("bvh", &h);
            tu_print_hit("brute force", &want[i]);
        }
    }
    return bad;
}

/* For rays that hit: tmax = the hit distance (tmin <= t <= tmax: the same hit), and for every
   other one tmax just below it (that triangle is out of range; another may still be hit). */
static size_t tmax_rays(const bvh_ray *rays, const bvh_hit *hits, size_t count, bvh_ray *out) {
    size_t i, m = 0;
    for (i = 0; i < count; i++) {
        if (hits[i].prim == BVH_INVALID) continue;
        out[m] = rays[i];
        out[m].tmax = (m & 1) ? nextafterf(hits[i].t, -BVH_INF) : hits[i].t;
        if (out[m].tmax < out[m].tmin) out[m].tmax = out[m].tmin;
        m++;
    }
    return m;
}

static void exact_hits(void **state) {
    int id = tu_state_id(state), b;
    tu_scene s;
    float *tris;
    bvh_ray *rays, *rays2;
    bvh_hit *want, *want2;
    size_t n2, bad = 0, hits = 0, i;
    bvh_tree trees[TU_BUILDER_COUNT];
    int w;
    if (!tu_scene_make(id, &s)) {
        skip();
        return;
    }
    tris = tu_scene_tris(&s);
    rays = (bvh_ray *)malloc(TU_RAYS * sizeof *rays);
    rays2 = (bvh_ray *)malloc(TU_RAYS * sizeof *rays2);
    want = (bvh_hit *)malloc(TU_RAYS * sizeof *want);
    want2 = (bvh_hit *)malloc(TU_RAYS * sizeof *want2);
    assert_true(rays && rays2 && want && want2);
    tu_make_rays(tris, s.tri_count, 0x7261797300ULL + (uint64_t)id, rays, TU_RAYS);
    tu_oracle_run(tris, s.tri_count, rays, TU_RAYS, want);
    n2 = tmax_rays(rays, want, TU_RAYS, rays2);
    tu_oracle_run(tris, s.tri_count, rays2, n2, want2);
    for (i = 0; i < TU_RAYS; i++) hits += want[i].prim != BVH_INVALID;
    print_message("%-18s %7u triangles, %zu of %d rays hit\n", s.name, s.tri_count, hits, TU_RAYS);
    assert_true(hits > 0);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        size_t bad_b;
        bvh_tree bin;
        bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
        tu_build(&s, tu_builder(b), &trees[b]);
        assert_non_null(trees[b].nodes8); /* the default: 8-wide traversal (counted: binary) */
        bad_b = compare(&s, &trees[b], rays, want, TU_RAYS) + compare(&s, &trees[b], rays2, want2, n2);
        if (bad_b)
            print_error("%s/%s: %zu of %zu rays differ from the brute force\n", s.name, bvh_builder_name(tu_builder(b)),
                        bad_b, TU_RAYS + n2);
        bad += bad_b;
        d.trace_width = 2; /* binary traversal only */
        tu_build_valid(&s, &d, &bin);
        assert_null(bin.nodes8);
        bad_b = compare(&s, &bin, rays, want, TU_RAYS) + compare(&s, &bin, rays2, want2, n2);
        if (bad_b)
            print_error("%s/%s, trace_width 2: %zu of %zu rays differ from the brute force\n", s.name,
                        bvh_builder_name(tu_builder(b)), bad_b, TU_RAYS + n2);
        bad += bad_b;
        bvh_free(&bin);
        /* the optimizer's tree (<builder>+opt), on both layouts: two rounds over half the nodes */
        d.optimize.rounds = 2;
        d.optimize.batch = 0.5f;
        for (w = 0; w < 2; w++) {
            d.trace_width = w ? 2 : 8;
            tu_build_valid(&s, &d, &bin);
            bad_b = compare(&s, &bin, rays, want, TU_RAYS) + compare(&s, &bin, rays2, want2, n2);
            if (bad_b)
                print_error("%s/%s+opt, trace_width %u: %zu of %zu rays differ from the brute force\n", s.name,
                            bvh_builder_name(tu_builder(b)), d.trace_width, bad_b, TU_RAYS + n2);
            bad += bad_b;
            bvh_free(&bin);
        }
    }
    for (b = 0; b < TU_BUILDER_COUNT; b++) bvh_free(&trees[b]);
    free(rays);
    free(rays2);
    free(want);
    free(want2);
    free(tris);
    tu_scene_free(&s);
    assert_int_equal(bad, 0);
}

/* The rays a renderer traces after the camera's, from points on the surface (kind = i % 4):
   0 a bounce ray from exactly on a triangle, into the hemisphere of its normal that faces the
   direction drawn; 1 the same from just off the surface (1e-4 of the diagonal); 2 a shadow ray
   toward a fixed light direction; 3 a grazing ray, in the triangle's plane. */
static void renderer_rays(const float *tris, uint32_t n, uint64_t seed, bvh_ray *rays, size_t count) {
    unsigned retries = 0;
    tu_rng r = tu_rng_make(seed);
    const bvh_vec3 light = tu_v3(0.3f, 1.0f, 0.2f);
    float diag = tu_diag(tris, n, NULL);
    size_t i;
    for (i = 0; i < count; i++) {
        const float *t;
        bvh_vec3 e1, e2, nrm, d;
        float len, side;
        do {
            t = tris + 9 * (size_t)tu_below(&r, n);
        } while (!tu_finite9(t));
        e1 = tu_v3(t[3] - t[0], t[4] - t[1], t[5] - t[2]);
        e2 = tu_v3(t[6] - t[0], t[7] - t[1], t[8] - t[2]);
        nrm = tu_v3(e1.y * e2.z - e1.z * e2.y, e1.z * e2.x - e1.x * e2.z, e1.x * e2.y - e1.y * e2.x);
        len = sqrtf(nrm.x * nrm.x + nrm.y * nrm.y + nrm.z * nrm.z);
        if (len > 0.0f) nrm = tu_v3(nrm.x / len, nrm.y / len, nrm.z / len);
        {
            float a = tu_unit(&r), c = tu_unit(&r);
            if (a + c > 1.0f) {
                a = 1.0f - a;
                c = 1.0f - c;
            }
            rays[i].origin = tu_v3(t[0] + a * e1.x + c * e2.x, t[1] + a * e1.y + c * e2.y, t[2] + a * e1.z + c * e2.z);
        }
        d = tu_sphere_dir(&r);
        side = d.x * nrm.x + d.y * nrm.y + d.z * nrm.z;
        if (i % 4 == 1) {
            float off = side < 0.0f ? -1e-4f * diag : 1e-4f * diag;
            rays[i].origin =
                tu_v3(rays[i].origin.x + off * nrm.x, rays[i].origin.y + off * nrm.y, rays[i].origin.z + off * nrm.z);
        }
        if (i % 4 == 2) d = light;
        if (i % 4 == 3) /* the drawn direction less its normal part */
            d = tu_v3(d.x - side * nrm.x, d.y - side * nrm.y, d.z - side * nrm.z);
        if (d.x == 0.0f && d.y == 0.0f && d.z == 0.0f) d = light;
        rays[i].dir = d;
        rays[i].tmin = 0.0f;
        rays[i].tmax = BVH_INF;
        /* a triangle whose normal overflows gives no surface ray: draw another (the test code is
           also built with -ffast-math, where the overflow can reach the origin as a NaN) */
        if (!(fp_finite(rays[i].origin.x) && fp_finite(rays[i].origin.y) && fp_finite(rays[i].origin.z) &&
              fp_finite(d.x) && fp_finite(d.y) && fp_finite(d.z)) &&
            retries++ < 1000)
            i--;
    }
}

/* exact_hits on renderer_rays, for every builder, on the 8-wide layout and the binary nodes. */
static void exact_renderer_hits(void **state) {
    int id = tu_state_id(state), b;
    tu_scene s;
    float *tris;
    bvh_ray *rays;
    bvh_hit *want;
    size_t bad = 0;
    if (!tu_scene_make(id, &s)) {
        skip();
        return;
    }
    tris = tu_scene_tris(&s);
    rays = (bvh_ray *)malloc(TU_RAYS * sizeof *rays);
    want = (bvh_hit *)malloc(TU_RAYS * sizeof *want);
    assert_true(rays && want);
    renderer_rays(tris, s.tri_count, 0x626f756e6365ULL + (uint64_t)id, rays, TU_RAYS);
    tu_oracle_run(tris, s.tri_count, rays, TU_RAYS, want);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        int w;
        for (w = 0; w < 2; w++) {
            bvh_tree t;
            bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
            size_t bad_b;
            d.trace_width = w ? 2 : 0;
            tu_build_valid(&s, &d, &t);
            bad_b = compare(&s, &t, rays, want, TU_RAYS);
            if (bad_b)
                print_error("%s/%s, trace_width %d: %zu of %d renderer rays differ from the brute force\n", s.name,
                            bvh_builder_name(tu_builder(b)), w ? 2 : 4, bad_b, TU_RAYS);
            bad += bad_b;
            bvh_free(&t);
        }
    }
    free(rays);
    free(want);
    free(tris);
    tu_scene_free(&s);
    assert_int_equal(bad, 0);
}

/* The scene of the test's state and room for count rays and two hit arrays (single calls and
   a batch); 0 when the scene is not available here (the test skips). */
static int batch_setup(void **state, tu_scene *s, size_t count, bvh_ray **rays, bvh_hit **single, bvh_hit **batch) {
    if (!tu_scene_make(tu_state_id(state), s)) return 0;
    *rays = (bvh_ray *)malloc(count * sizeof **rays);
    *single = (bvh_hit *)malloc(count * sizeof **single);
    *batch = (bvh_hit *)malloc(count * sizeof **batch);
    assert_true(*rays && *single && *batch);
    return 1;
}

/* bvh_intersect_batch and bvh_occluded_batch on 1, 2, 3, 8 and all threads equal single calls. */
static void batch_equals_single(void **state) {
    static const uint32_t threads[] = {1, 2, 3, 8, 0};
    /* on 1 thread 6 chunks of 1,024 rays, then 33 of 64, the last one short; on 2, 4 long ones
       and 78 short ones; on 3, 2 long ones; on 8, short ones only */
    const size_t count = 9000 + 77;
    int id = tu_state_id(state), b;
    size_t i, k;
    tu_scene s;
    float *tris;
    bvh_ray *rays;
    bvh_hit *single, *batch;
    uint8_t *occ, *occ_single;
    if (!batch_setup(state, &s, count, &rays, &single, &batch)) {
        skip();
        return;
    }
    occ = (uint8_t *)malloc(count);
    occ_single = (uint8_t *)malloc(count);
    assert_true(occ && occ_single);
    tris = tu_scene_tris(&s);
    /* the test's mix of rays, then a renderer's from the surfaces (each from its own origin: the
       batches take such rays two at a time in turns on a large tree, and always in the build with
       BVH__PAIR=1) */
    tu_make_rays(tris, s.tri_count, 0x6261746368ULL + (uint64_t)id, rays, count / 2);
    renderer_rays(tris, s.tri_count, 0x7061697273ULL + (uint64_t)id, rays + count / 2, count - count / 2);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_tree t;
        tu_build(&s, tu_builder(b), &t);
        for (i = 0; i < count; i++) {
            bvh_intersect(&t, &rays[i], &single[i]);
            occ_single[i] = (uint8_t)bvh_occluded(&t, &rays[i]);
        }
        for (k = 0; k < sizeof threads / sizeof threads[0]; k++) {
            memset(batch, 0xab, count * sizeof *batch);
            memset(occ, 0xab, count);
            assert_int_equal(bvh_intersect_batch(&t, rays, batch, count, threads[k]), BVH_SUCCESS);
            assert_int_equal(bvh_occluded_batch(&t, rays, occ, count, threads[k]), BVH_SUCCESS);
            for (i = 0; i < count; i++) {
                if (tu_hit_equal(&batch[i], &single[i]) && occ[i] == occ_single[i]) continue;
                tu_print_ray(&rays[i]);
                tu_print_hit("single", &single[i]);
                tu_print_hit("batch", &batch[i]);
                fail_msg("%s/%s: batch on %u threads differs from single calls at ray %zu (occluded %u vs %u)", s.name,
                         bvh_builder_name(tu_builder(b)), threads[k], i, occ[i], occ_single[i]);
            }
        }
        /* a few rays only (fewer than one chunk), and none */
        assert_int_equal(bvh_intersect_batch(&t, rays, batch, 3, 8), BVH_SUCCESS);
        for (i = 0; i < 3; i++) assert_true(tu_hit_equal(&batch[i], &single[i]));
        assert_int_equal(bvh_intersect_batch(&t, rays, batch, 0, 8), BVH_SUCCESS);
        assert_int_equal(bvh_occluded_batch(&t, rays, occ, 0, 8), BVH_SUCCESS);
        bvh_free(&t);
    }
    free(rays);
    free(single);
    free(batch);
    free(occ);
    free(occ_single);
    free(tris);
    tu_scene_free(&s);
}

/* A camera's batch (every ray from one origin: timed on a layout from 512 KiB, then traced one at
   a time or in turns) gives the single calls' hits, seen from outside (most rays stop early) and
   from inside the model (every ray goes deep), on one thread and on two. */
static void camera_batch_equals_single(void **state) {
    static const uint32_t threads[] = {1, 2};
    const uint32_t w = 128, h = 128;
    const size_t count = (size_t)w * h;
    int b, c;
    size_t i, k;
    tu_scene s;
    bvh_ray *rays;
    bvh_hit *single, *batch;
    if (!batch_setup(state, &s, count, &rays, &single, &batch)) {
        skip();
        return;
    }
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_tree t;
        tu_build(&s, tu_builder(b), &t);
        for (c = 0; c < 2; c++) {
            bvh_aabb box = bvh_tree_bounds(&t);
            bvh_camera cam;
            uint32_t x, y;
            if (c) { /* inside: the standard camera of a box a tenth of the model's, at its centre */
                const bvh_vec3 m = bvh_aabb_centroid(box);
                box.min.x = m.x - 0.05f * (box.max.x - box.min.x);
                box.min.y = m.y - 0.05f * (box.max.y - box.min.y);
                box.min.z = m.z - 0.05f * (box.max.z - box.min.z);
                box.max.x = 2.0f * m.x - box.min.x;
                box.max.y = 2.0f * m.y - box.min.y;
                box.max.z = 2.0f * m.z - box.min.z;
            }
            cam = bvh_camera_standard(box, w, h);
            for (y = 0; y < h; y++)
                for (x = 0; x < w; x++) rays[(size_t)y * w + x] = bvh_camera_ray(&cam, x, y);
            for (i = 0; i < count; i++) bvh_intersect(&t, &rays[i], &single[i]);
            for (k = 0; k < sizeof threads / sizeof threads[0]; k++) {
                memset(batch, 0xab, count * sizeof *batch);
                assert_int_equal(bvh_intersect_batch(&t, rays, batch, count, threads[k]), BVH_SUCCESS);
                for (i = 0; i < count; i++)
                    if (!tu_hit_equal(&batch[i], &single[i]))
                        fail_msg("%s/%s: camera %s, batch on %u threads differs from single calls at ray %zu", s.name,
                                 bvh_builder_name(tu_builder(b)), c ? "inside" : "outside", threads[k], i);
            }
        }
        bvh_free(&t);
    }
    free(rays);
    free(single);
    free(batch);
    tu_scene_free(&s);
}

/* Rays with NaN, Inf, a zero direction or tmin > tmax hit nothing, in every call. */
static void invalid_rays_miss(void **state) {
    tu_scene s;
    bvh_tree t;
    bvh_ray good = {{0.25f, 0.25f, -1.0f}, 0.0f, {0.0f, 0.0f, 1.0f}, BVH_INF}, bad[8];
    bvh_hit h, hits[8];
    uint8_t occ[8];
    int k;
    (void)state;
    tu_scene_few(&s, 1);
    tu_build(&s, BVH_BUILDER_PLOC, &t);
    assert_int_equal(bvh_intersect(&t, &good, &h), 1); /* the baseline: this ray hits */
    assert_int_equal(h.prim, 0);
    assert_true(h.t == 1.0f);
    for (k = 0; k < 8; k++) bad[k] = good;
    bad[0].origin.x = NAN;
    bad[1].dir.y = NAN;
    bad[2].dir.z = 0.0f; /* zero direction */
    bad[3].tmin = 2.0f;
    bad[3].tmax = 1.0f; /* tmin > tmax */
    bad[4].origin.z = -BVH_INF;
    bad[5].tmin = NAN;
    bad[6].tmax = NAN;
    bad[7].dir.z = BVH_INF;
    for (k = 0; k < 8; k++) {
        float v0[3] = {0, 0, 0}, v1[3] = {1, 0, 0}, v2[3] = {0, 1, 0};
        memset(&h, 0, sizeof h);
        assert_int_equal(bvh_intersect(&t, &bad[k], &h), 0);
        assert_int_equal(h.prim, BVH_INVALID);
        assert_int_equal(bvh_occluded(&t, &bad[k]), 0);
        assert_int_equal(bvh_intersect_triangle(&bad[k], v0, v1, v2, &h), 0);
        assert_int_equal(h.prim, BVH_INVALID);
    }
    assert_int_equal(bvh_intersect_batch(&t, bad, hits, 8, 2), BVH_SUCCESS);
    assert_int_equal(bvh_occluded_batch(&t, bad, occ, 8, 2), BVH_SUCCESS);
    for (k = 0; k < 8; k++) {
        assert_int_equal(hits[k].prim, BVH_INVALID);
        assert_int_equal(occ[k], 0);
    }
    /* the tmin <= t <= tmax boundaries are inclusive, and a miss reports t = tmax */
    good.tmin = good.tmax = 1.0f;
    assert_int_equal(bvh_intersect(&t, &good, &h), 1);
    good.tmax = nextafterf(1.0f, 0.0f);
    good.tmin = 0.0f;
    assert_int_equal(bvh_intersect(&t, &good, &h), 0);
    assert_true(h.t == good.tmax);
    assert_int_equal(h.prim, BVH_INVALID);
    bvh_free(&t);
    tu_scene_free(&s);
}

/* A hand-made chain tree `levels` deep (root depth 1): triangle k lies on the plane z = k over
   the same unit square, the leaf of triangle k at depth k + 1 (the last two share the deepest
   level). A ray from above hits the deepest triangle first, after the whole chain. */
static void chain_tree(uint32_t levels, bvh_tree *t, bvh_node *nodes, uint32_t *prims, float *tris) {
    uint32_t k, n = levels; /* one triangle per leaf */
    memset(t, 0, sizeof *t);
    for (k = 0; k < n; k++) {
        float *v = tris + 9 * (size_t)k, z = (float)k;
        tu_set3(v, 0, 0, z);
        tu_set3(v + 3, 1, 0, z);
        tu_set3(v + 6, 0, 1, z);
        prims[k] = k;
    }
    /* interior node i (depth i + 1) at 2i, children at 2i + 1 (leaf of triangle i) and 2i + 2 */
    for (k = 0; k + 1 < n; k++) {
        nodes[2 * k].index = 2 * k + 1;
        nodes[2 * k].count = 0;
        nodes[2 * k + 1].index = k;
        nodes[2 * k + 1].count = 1;
    }
    nodes[2 * (n - 1)].index = n - 1;
    nodes[2 * (n - 1)].count = 1;
    for (k = 2 * n - 1; k-- > 0;) { /* boxes bottom-up: a node's box spans the triangles at and below it */
        uint32_t first = nodes[k].count ? nodes[k].index : k / 2;
        nodes[k].min = tu_v3(0, 0, (float)first);
        nodes[k].max = tu_v3(1, 1, nodes[k].count ? (float)first : (float)(n - 1));
    }
    t->nodes = nodes;
    t->node_count = 2 * n - 1;
    t->prims = prims;
    t->ref_count = n;
    t->prim_count = n;
    t->tris = tris;
    t->builder = BVH_BUILDER_TOP_DOWN;
}
static void max_depth_tree_traces(void **state) {
    enum { L = BVH_MAX_DEPTH };
    bvh_node nodes[2 * L - 1];
    uint32_t prims[L];
    float tris[9 * L];
    bvh_tree t;
    bvh_validation rep;
    bvh_stats st;
    bvh_ray ray = {{0.25f, 0.25f, 1000.0f}, 0.0f, {-0.0f, 0.0f, -1.0f}, BVH_INF};
    bvh_hit h;
    (void)state;
    chain_tree(L, &t, nodes, prims, tris);
    if (bvh_validate(&t, NULL, &rep) != BVH_SUCCESS) fail_msg("chain of %d levels: %s", L, rep.message);
    assert_int_equal(bvh_get_stats(&t, &st), BVH_SUCCESS);
    assert_int_equal(st.max_depth, L);
    assert_int_equal(bvh_intersect(&t, &ray, &h), 1);
    assert_int_equal(h.prim, L - 1);
    assert_true(h.t == 1000.0f - (float)(L - 1));
    ray.dir.z = 1.0f;
    ray.origin.z = -0.5f; /* from below: the root's left leaf, the least deep */
    assert_int_equal(bvh_intersect(&t, &ray, &h), 1);
    assert_int_equal(h.prim, 0);
    assert_int_equal(bvh_occluded(&t, &ray), 1);
    ray.dir.z = -1.0f;
    ray.origin.z = (float)L / 2 + 0.5f; /* from the middle, down */
    assert_int_equal(bvh_intersect(&t, &ray, &h), 1);
    assert_int_equal(h.prim, L / 2);
}

/* A box the ray's origin lies just outside, the ray leaving it (an eye above a long box, a bounce
   ray off a surface): its exit, rounded up, is before tmin, so no hit in it can count, and the
   slab test does not enter it, however large the box's slack for rounding (the entry lowered by
   2^-18 of the box's extent along the dominant axis: 3.8e-5 here, against an exit at -1e-5). A
   custom test on the triangle tree (the binary loop) sees which leaves are entered. */
static const float behind_tris[18] = {-10, 0,  -1, 10, 0, -1, 0,  1,  0, /* below the origin: box z in [-1, 0] */
                                      20,  -1, -1, 20, 3, -1, 20, -1, 5};
static int behind_test(const bvh_ray *ray, uint32_t prim, void *user, bvh_hit *hit) {
    const float *v = behind_tris + 9 * prim;
    ((uint32_t *)user)[prim]++;
    return bvh_intersect_triangle(ray, v, v + 3, v + 6, hit);
}
static void box_behind_origin_skipped(void **state) {
    bvh_build_desc d;
    bvh_tree t;
    bvh_ray ray = {{0.0f, 0.5f, 1e-6f}, 0.0f, {1.0f, 0.0f, 0.1f}, BVH_INF};
    bvh_hit h, hc;
    uint32_t calls[2] = {0, 0};
    bvh_custom_desc custom = {behind_test, calls};
    (void)state;
    memset(&d, 0, sizeof d);
    d.builder = BVH_BUILDER_TOP_DOWN;
    d.max_leaf_size = 1;
    d.triangles.positions = behind_tris;
    d.triangles.vertex_count = 6;
    d.triangles.triangle_count = 2;
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    assert_int_equal(t.node_count, 3);
    assert_int_equal(bvh_intersect(&t, &ray, &h), 1);
    assert_int_equal(h.prim, 1);
    assert_int_equal(bvh_intersect_custom(&t, &ray, &hc, &custom), 1);
    assert_true(tu_hit_equal(&hc, &h));
    assert_int_equal(calls[0], 0); /* the leaf behind: not entered */
    assert_int_equal(calls[1], 1);
    bvh_free(&t);
}

/* bvh__wide_prep's table of a tree, on `threads` threads. */
static bvh__wide_prep_job *prep_make(const bvh_node *nodes, uint32_t count, const float *tris, uint32_t threads) {
    bvh__wide_prep_job *j = (bvh__wide_prep_job *)calloc(1, sizeof *j);
    bvh_allocator al;
    memset(&al, 0, sizeof al);
    assert_non_null(j);
    j->nodes = nodes;
    j->tris = tris;
    j->count = count;
    j->info = (bvh__wide_info *)malloc(count * sizeof *j->info);
    assert_non_null(j->info);
    assert_int_equal(bvh__wide_prep(j, &al, NULL, threads), BVH_SUCCESS);
    return j;
}
static void prep_free(bvh__wide_prep_job *j) {
    free(j->info);
    free(j);
}
/* The slots of every wide node are stored in the order any-hit rays take them
   (bvh__wide_slot_order): leaf slots first, largest box first, then interior slots by the
   chance that their subtree stops a ray for what it costs, highest first, recomputed here from
   the binary tree. */
static void slot_order_any_hit(void **state) {
    int id = tu_state_id(state), b;
    tu_scene s;
    if (!tu_scene_make(id, &s)) {
        skip();
        return;
    }
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_tree t;
        bvh__wide_prep_job *job;
        uint32_t w, i, interior = 0;
        tu_build(&s, tu_builder(b), &t);
        assert_non_null(t.nodes8);
        job = prep_make(t.nodes, t.node_count, t.tris, 1);
        for (w = 0; w < t.node8_count; w++) {
            const bvh_node8 *n = &t.nodes8[w];
            bvh__group g;
            float prev = BVH_INF;
            int seen_interior = 0;
            assert_true(bvh__group_read(t.nodes, t.node_count, n, &g));
            for (i = 0; i < g.nslot; i++) {
                const uint32_t x = g.slot[i];
                const float a = bvh_aabb_area(bvh__node_box(&t.nodes[x]));
                float key;
                if (n->count[i]) {
                    assert_false(seen_interior); /* leaf slots first */
                    key = a;
                } else {
                    const float chance = 2.0f * job->info[x].tarea / a;
                    if (!seen_interior) prev = BVH_INF;
                    seen_interior = 1;
                    key = (chance < 1.0f ? chance : 1.0f) / (job->info[x].cost / a);
                    if (!(key >= 0.0f)) key = 0.0f;
                    interior++;
                }
                /* a relative slack: this file may be compiled -ffast-math (the implementation keeps
                   IEEE semantics; this recomputation may round differently) */
                if (!(key <= prev * 1.0001f))
                    fail_msg("%s/%s: wide node %u slot %u: key %g after %g", s.name, bvh_builder_name(tu_builder(b)), w,
                             i, key, prev);
                prev = key;
            }
        }
        if (s.tri_count > 1000) assert_true(interior > 0); /* the order was exercised */
        prep_free(job);
        bvh_free(&t);
    }
    tu_scene_free(&s);
}

/* bvh__wide_prep's info over the depth-first tree on two threads equals its info over the same
   tree laid out breadth-first (children still after their parents, but the work shared out by
   wrong guesses) on one, node for node and bit for bit. */
static void prep_any_layout(void **state) {
    int id = tu_state_id(state), b;
    tu_scene s;
    if (!tu_scene_make(id, &s)) {
        skip();
        return;
    }
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_tree t;
        bvh_node *bfs;
        uint32_t *from, *to, head = 1, tail = 1, i;
        bvh__wide_prep_job *a, *c;
        tu_build(&s, tu_builder(b), &t);
        bfs = (bvh_node *)malloc(t.node_count * sizeof *bfs);
        from = (uint32_t *)malloc(t.node_count * sizeof *from); /* breadth-first index -> tree's */
        to = (uint32_t *)malloc(t.node_count * sizeof *to);
        assert_true(bfs && from && to);
        from[0] = 0;
        for (head = 0; head < tail; head++) { /* pairs of children stay side by side */
            const bvh_node *n = &t.nodes[from[head]];
            bfs[head] = *n;
            if (n->count) continue;
            bfs[head].index = tail;
            from[tail++] = n->index;
            from[tail++] = n->index + 1;
        }
        assert_int_equal(tail, t.node_count);
        for (i = 0; i < t.node_count; i++) to[from[i]] = i;
        a = prep_make(t.nodes, t.node_count, t.tris, 2);
        c = prep_make(bfs, t.node_count, t.tris, 1);
        for (i = 0; i < t.node_count; i++) {
            const uint32_t k = to[i];
            if (memcmp(&a->info[i], &c->info[k], sizeof a->info[i]))
                fail_msg("%s/%s: node %u: the tables differ", s.name, bvh_builder_name(tu_builder(b)), i);
        }
        prep_free(a);
        prep_free(c);
        free(bfs);
        free(from);
        free(to);
        bvh_free(&t);
    }
    tu_scene_free(&s);
}

/* The packets' zero-area test (bvh__any_zero_area4) answers as the double test of each lane
   (bvh__tri_zero_area) on triangles made to sit at its edges: collinear and nearly so, repeated
   and one-ulp-apart vertices, coordinates from subnormal to near FLT_MAX; and its float pre-test
   (bvh__area4_nonzero) never passes a lane the double test finds flat, yet passes ordinary ones. */
#ifdef BVH__SSE
static float zr_coord(tu_rng *r) {
    static const float scale[] = {1.0f, 1e-3f, 1e3f, 1e-20f, 1e20f, 1e-38f, 1e-44f, 1e36f, 3e38f};
    return tu_range(r, -1.0f, 1.0f) * scale[tu_below(r, (uint32_t)(sizeof scale / sizeof scale[0]))];
}
static void zr_triangle(tu_rng *r, float t[9]) {
    uint32_t kind = tu_below(r, 6), a;
    for (a = 0; a < 9; a++) t[a] = zr_coord(r);
    if (kind == 1 || kind == 2) { /* the third vertex on the line through the first two, in float */
        const float k = kind == 1 ? 0.5f : tu_range(r, -2.0f, 2.0f);
        for (a = 0; a < 3; a++) t[6 + a] = t[a] + k * (t[3 + a] - t[a]);
    } else if (kind == 3) { /* a repeated vertex */
        for (a = 0; a < 3; a++) t[3 + a] = t[a];
    } else if (kind == 4) { /* all three one ulp or so apart */
        for (a = 0; a < 3; a++) {
            t[3 + a] = nextafterf(t[a], BVH_INF);
            t[6 + a] = tu_below(r, 2) ? nextafterf(t[a], -BVH_INF) : t[a];
        }
    }
    if (!tu_below(r, 4)) /* an axis-aligned triangle: one coordinate shared */
        t[5] = t[8] = t[2];
}
#endif
static void zero_area_packets(void **state) {
#ifdef BVH__SSE
    tu_rng r = tu_rng_make(0x5a45524fULL);
    uint32_t i, j, passed = 0, flat = 0;
    (void)state;
    for (i = 0; i < 200000u; i++) {
        float t[4][9], c[9][4];
        int want = 0, a;
        __m128 v[9];
        for (j = 0; j < 4; j++) {
            zr_triangle(&r, t[j]);
            want |= bvh__tri_zero_area(t[j]);
            for (a = 0; a < 9; a++) c[a][j] = t[j][a];
        }
        for (a = 0; a < 9; a++) v[a] = _mm_loadu_ps(c[a]);
        if (bvh__any_zero_area4(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8]) != want)
            fail_msg("packet %u: the packet test says %d, the lanes' double test %d", i, !want, want);
        for (j = 0; j < 4; j++) { /* each triangle alone in all four lanes */
            for (a = 0; a < 9; a++) v[a] = _mm_set1_ps(t[j][a]);
            if (bvh__area4_nonzero(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8])) {
                passed++;
                if (bvh__tri_zero_area(t[j]))
                    fail_msg("packet %u lane %u: the float pre-test passes a flat triangle", i, j);
            }
            flat += bvh__tri_zero_area(t[j]);
        }
    }
    assert_true(passed > 200000u); /* the pre-test decides most triangles ... */
    assert_true(flat > 100000u);   /* ... and flat ones were there to refuse */
#else
    (void)state;
    skip();
#endif
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(zero_area_packets),
        TU_EVERY_SCENE(exact_hits),
        TU_EVERY_SCENE(exact_renderer_hits),
        TU_SCENE_TEST(batch_equals_single, TU_SCENE_RANDOM, "random"),
        TU_SCENE_TEST(batch_equals_single, TU_SCENE_GRID, "grid"),
        TU_SCENE_TEST(batch_equals_single, TU_SCENE_BUNNY, "bunny"),
        TU_SCENE_TEST(camera_batch_equals_single, TU_SCENE_GRID, "grid"),
        TU_SCENE_TEST(camera_batch_equals_single, TU_SCENE_BUNNY, "bunny"),
        cmocka_unit_test(invalid_rays_miss),
        cmocka_unit_test(max_depth_tree_traces),
        cmocka_unit_test(box_behind_origin_skipped),
        TU_SCENE_TEST(slot_order_any_hit, TU_SCENE_BUNNY, "bunny"),
        TU_SCENE_TEST(slot_order_any_hit, TU_SCENE_GRID, "grid"),
        TU_SCENE_TEST(prep_any_layout, TU_SCENE_BUNNY, "bunny"),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
