/* tests/test_api.c - the public API around the builders: names, argument and geometry errors,
   empty and box-only trees, allocation failures, statistics, AABB and camera helpers, and the
   validator catching corrupted trees. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"
#include "test_util.h"
#include "tree_diff.h"

static void assert_tree_empty(const bvh_tree *t) {
    assert_null(t->nodes);
    assert_null(t->prims);
    assert_null(t->tris);
    assert_int_equal(t->node_count, 0);
    assert_int_equal(t->ref_count, 0);
}

/* == names ==================================================================================== */
static void result_strings(void **state) {
    const char *unknown = bvh_result_string(BVH_RESULT_COUNT);
    int r, q;
    (void)state;
    assert_non_null(unknown);
    assert_string_equal(bvh_result_string((bvh_result)-1), unknown);
    for (r = 0; r < BVH_RESULT_COUNT; r++) {
        const char *s = bvh_result_string((bvh_result)r);
        assert_non_null(s);
        assert_true(strlen(s) > 3);
        if (strcmp(s, unknown) == 0) fail_msg("result %d has no string of its own", r);
        for (q = 0; q < r; q++)
            if (strcmp(s, bvh_result_string((bvh_result)q)) == 0) fail_msg("results %d and %d share \"%s\"", q, r, s);
    }
    assert_string_equal(bvh_result_string(BVH_SUCCESS), "success");
}

static void builder_names(void **state) {
    static const char *const names[BVH_BUILDER_COUNT] = {"default",      "top-down", "bottom-up",
                                                         "sah-midpoint", "ploc",     "ploc-parallel"};
    bvh_builder out;
    int b;
    (void)state;
    for (b = 0; b < BVH_BUILDER_COUNT; b++) {
        assert_string_equal(bvh_builder_name((bvh_builder)b), names[b]);
        out = (bvh_builder)-1;
        assert_int_equal(bvh_builder_from_name(bvh_builder_name((bvh_builder)b), &out), BVH_SUCCESS);
        assert_int_equal(out, b);
    }
    assert_string_equal(bvh_builder_name(BVH_BUILDER_COUNT), "unknown");
    assert_string_equal(bvh_builder_name((bvh_builder)-1), "unknown");
    assert_int_equal(bvh_builder_from_name("unknown", &out), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_builder_from_name("", &out), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_builder_from_name("ploc ", &out), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_builder_from_name(NULL, &out), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_builder_from_name("ploc", NULL), BVH_ERROR_INVALID_ARGUMENT);
    { /* the table: the default is ploc-parallel's row; only sah-midpoint splits references */
        bvh_builder_info info, par;
        assert_int_equal(bvh_builder_get_info(BVH_BUILDER_PLOC_PARALLEL, &par), BVH_SUCCESS);
        assert_int_equal(bvh_builder_get_info(BVH_BUILDER_DEFAULT, &info), BVH_SUCCESS);
        assert_string_equal(info.name, "ploc-parallel");
        assert_true(par.uses_threads && !par.splits_references && par.max_leaf_size == 8);
        for (b = 1; b < BVH_BUILDER_COUNT; b++) {
            assert_int_equal(bvh_builder_get_info((bvh_builder)b, &info), BVH_SUCCESS);
            assert_string_equal(info.name, names[b]);
            assert_int_equal(info.splits_references, b == BVH_BUILDER_SAH_MIDPOINT);
            assert_true(info.max_leaf_size >= 1 && info.max_leaf_size <= 255 && info.interior_cost > 0.0f);
        }
        assert_int_equal(bvh_builder_get_info(BVH_BUILDER_COUNT, &info), BVH_ERROR_INVALID_ARGUMENT);
        assert_int_equal(bvh_builder_get_info(BVH_BUILDER_PLOC, NULL), BVH_ERROR_INVALID_ARGUMENT);
    }
}

/* == argument errors ============================================================================ */
static bvh_result build_expect(const bvh_build_desc *d, bvh_result want) {
    bvh_tree t;
    bvh_result r;
    memset(&t, 0x5a, sizeof t); /* garbage: bvh_build must zero it */
    r = bvh_build(&t, d);
    if (r != want)
        fail_msg("%s: got \"%s\", expected \"%s\"", bvh_builder_name(d->builder), bvh_result_string(r),
                 bvh_result_string(want));
    if (r == BVH_SUCCESS)
        bvh_free(&t);
    else
        assert_tree_empty(&t);
    return r;
}

static void build_argument_errors(void **state) {
    tu_scene soup, mesh;
    int b;
    (void)state;
    tu_scene_random(&soup, 50, 0x415247ULL);
    tu_scene_strided32(&mesh);
    assert_int_equal(bvh_build(NULL, NULL), BVH_ERROR_INVALID_ARGUMENT);
    {
        bvh_build_desc d = tu_scene_desc(&soup, BVH_BUILDER_PLOC);
        bvh_tree t;
        assert_int_equal(bvh_build(NULL, &d), BVH_ERROR_INVALID_ARGUMENT);
        memset(&t, 0x5a, sizeof t);
        assert_int_equal(bvh_build(&t, NULL), BVH_ERROR_INVALID_ARGUMENT);
        assert_tree_empty(&t);
    }
    for (b = 0; b <= TU_BUILDER_COUNT; b++) {
        bvh_builder builder = b < TU_BUILDER_COUNT ? tu_builder(b) : BVH_BUILDER_DEFAULT;
        bvh_build_desc ok = tu_scene_desc(&soup, builder), d;
        bvh_costs bad_costs[5] = {{-1, 0, 1}, {1, -0.5f, 1}, {1, 0, -1}, {NAN, 0, 1}, {1, BVH_INF, 1}};
        int k;
        build_expect(&ok, BVH_SUCCESS);
        d = ok;
        d.triangles.stride = 8;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.triangles.stride = 4;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.triangles.stride = 12;
        build_expect(&d, BVH_SUCCESS);
        d = ok;
        d.triangles.positions = NULL;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.triangles.vertex_count = 3 * 50 - 1; /* a soup needs 3 vertices per triangle */
        build_expect(&d, BVH_ERROR_INDEX_OUT_OF_RANGE);
        d = ok;
        d.max_leaf_size = 256;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.max_leaf_size = 255;
        build_expect(&d, BVH_SUCCESS);
        d = ok;
        d.ploc.radius = 257;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.trace_width = 3;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.trace_width = 4;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.trace_width = 8;
        build_expect(&d, BVH_SUCCESS);
        d = ok;
        d.trace_width = 2;
        build_expect(&d, BVH_SUCCESS);
        d = ok;
        d.sah_midpoint.split_budget = 1.5f;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.sah_midpoint.split_budget = NAN;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        { /* the optimizer: rounds above 1024, a batch outside [2^-16, 1] (0: the default) or NaN */
            static const float batches[] = {-0.5f, 1.5f, 1e-6f, NAN, BVH_INF};
            d = ok;
            d.optimize.rounds = 1025;
            build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
            d.optimize.rounds = BVH_OFF;
            build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
            d.optimize.rounds = 1024;
            d.optimize.batch = 1.0f;
            build_expect(&d, BVH_SUCCESS);
            d.optimize.rounds = 3;
            d.optimize.batch = 1.0f / 65536.0f;
            build_expect(&d, BVH_SUCCESS);
            for (k = 0; k < 5; k++) {
                d.optimize.batch = batches[k];
                build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
            }
        }
        for (k = 0; k < 5; k++) {
            d = ok;
            d.costs = bad_costs[k];
            build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        }
        d = ok;
        d.builder = BVH_BUILDER_COUNT;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.builder = (bvh_builder)-1;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d = ok;
        d.box_count = 3; /* triangles and boxes at once */
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        /* indexed: one index equal to vertex_count, or far beyond it */
        d = tu_scene_desc(&mesh, builder);
        build_expect(&d, BVH_SUCCESS);
        mesh.indices[3 * 100 + 1] = mesh.vertex_count;
        build_expect(&d, BVH_ERROR_INDEX_OUT_OF_RANGE);
        mesh.indices[3 * 100 + 1] = 0xFFFFFFFFu;
        build_expect(&d, BVH_ERROR_INDEX_OUT_OF_RANGE);
        mesh.indices[3 * 100 + 1] = 7;
        d.triangles.stride = 8;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
    }
    tu_scene_free(&soup);
    tu_scene_free(&mesh);
}

/* == invalid geometry =========================================================================== */
/* Traces rays at the scene and checks that no hit is an excluded triangle. */
static void assert_no_hit_on(const bvh_tree *t, const float *tris, uint32_t n, const uint8_t *bad) {
    enum { RAYS = 3000 };
    bvh_ray *rays = (bvh_ray *)malloc(RAYS * sizeof *rays);
    size_t i, hits = 0;
    assert_non_null(rays);
    tu_make_rays(tris, n, 0x626164ULL, rays, RAYS);
    for (i = 0; i < RAYS; i++) {
        bvh_hit h;
        if (!bvh_intersect(t, &rays[i], &h)) continue;
        hits++;
        assert_true(h.prim < n);
        if (bad[h.prim]) fail_msg("%s: ray %zu hit excluded triangle %u", bvh_builder_name(t->builder), i, h.prim);
    }
    assert_true(hits > RAYS / 10);
    free(rays);
}
static void check_skip_invalid(const tu_scene *s, const uint8_t *bad, uint32_t nbad) {
    float *tris = tu_scene_tris(s);
    int b;
    uint32_t k;
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d = tu_scene_desc(s, tu_builder(b));
        bvh_tree t;
        build_expect(&d, BVH_ERROR_INVALID_GEOMETRY);
        d.skip_invalid = 1;
        tu_build_valid(s, &d, &t);
        assert_int_equal(t.prim_count, s->tri_count);
        assert_int_equal(t.excluded, nbad);
        if (tu_builder(b) != BVH_BUILDER_SAH_MIDPOINT) assert_int_equal(t.ref_count, s->tri_count - nbad);
        for (k = 0; k < t.ref_count; k++)
            if (bad[t.prims[k]])
                fail_msg("%s: excluded triangle %u is in the tree", bvh_builder_name(t.builder), t.prims[k]);
        assert_no_hit_on(&t, tris, s->tri_count, bad);
        bvh_free(&t);
    }
    free(tris);
}
static void invalid_geometry(void **state) {
    tu_scene s;
    uint8_t *bad;
    uint32_t i, nbad = 0, v;
    (void)state;
    /* a soup: NaN, +Inf and -Inf in three triangles */
    tu_scene_random(&s, 300, 0x4e414eULL);
    bad = (uint8_t *)calloc(s.tri_count, 1);
    assert_non_null(bad);
    tu_vertex(&s, 3 * 5)[0] = NAN;
    tu_vertex(&s, 3 * 77 + 1)[1] = BVH_INF;
    tu_vertex(&s, 3 * 299 + 2)[2] = -BVH_INF;
    bad[5] = bad[77] = bad[299] = 1;
    check_skip_invalid(&s, bad, 3);
    free(bad);
    tu_scene_free(&s);
    /* an indexed mesh: a NaN in a shared vertex excludes every triangle that uses it */
    tu_scene_grid(&s);
    bad = (uint8_t *)calloc(s.tri_count, 1);
    assert_non_null(bad);
    v = s.indices[3 * 40 + 2];
    tu_vertex(&s, v)[2] = NAN;
    for (i = 0; i < s.tri_count; i++)
        if (s.indices[3 * i] == v || s.indices[3 * i + 1] == v || s.indices[3 * i + 2] == v) {
            bad[i] = 1;
            nbad++;
        }
    assert_true(nbad >= 3);
    check_skip_invalid(&s, bad, nbad);
    free(bad);
    tu_scene_free(&s);
}

/* Every triangle invalid, with skip_invalid: an empty tree, everything excluded. */
static void all_invalid_skipped(void **state) {
    tu_scene s;
    int b;
    uint32_t v;
    (void)state;
    tu_scene_random(&s, 20, 0x414c4cULL);
    for (v = 0; v < s.vertex_count; v++) tu_vertex(&s, v)[1] = NAN;
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
        bvh_tree t;
        bvh_validation rep;
        d.skip_invalid = 1;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_int_equal(t.node_count, 0);
        assert_int_equal(t.ref_count, 0);
        assert_int_equal(t.prim_count, 20);
        assert_int_equal(t.excluded, 20);
        assert_int_equal(bvh_validate(&t, NULL, &rep), BVH_SUCCESS);
        bvh_free(&t);
    }
    tu_scene_free(&s);
}

/* == empty and box-only trees ==================================================================== */
static void zero_triangles(void **state) {
    float dummy[3] = {0, 0, 0};
    int b, i;
    (void)state;
    for (b = 0; b <= TU_BUILDER_COUNT; b++) {
        bvh_build_desc d;
        bvh_tree t;
        bvh_validation rep;
        bvh_stats st;
        bvh_ray rays[300];
        bvh_hit hits[300];
        uint8_t occ[300];
        double cost = -1.0;
        bvh_aabb bounds;
        memset(&d, 0, sizeof d);
        d.builder = b < TU_BUILDER_COUNT ? tu_builder(b) : BVH_BUILDER_DEFAULT;
        if (b & 1) {
            d.triangles.positions = dummy;
            d.triangles.vertex_count = 1;
        }
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_int_equal(t.node_count, 0);
        assert_int_equal(t.ref_count, 0);
        assert_int_equal(t.prim_count, 0);
        assert_int_equal(bvh_validate(&t, NULL, &rep), BVH_SUCCESS);
        assert_string_equal(rep.message, "ok");
        assert_int_equal(bvh_get_stats(&t, &st), BVH_SUCCESS);
        assert_int_equal(st.nodes + st.leaves + st.refs + st.max_depth + st.max_leaf_size, 0);
        assert_int_equal(st.bytes + st.triangle_bytes, 0);
        assert_int_equal(bvh_sah(&t, NULL, &cost), BVH_SUCCESS);
        assert_true(cost == 0.0);
        bounds = bvh_tree_bounds(&t);
        assert_true(bounds.min.x > bounds.max.x);
        for (i = 0; i < 300; i++) {
            rays[i].origin = tu_v3((float)i, 0, -1);
            rays[i].dir = tu_v3(0, 0, 1);
            rays[i].tmin = 0;
            rays[i].tmax = BVH_INF;
            hits[i].prim = 7;
            occ[i] = 7;
        }
        assert_int_equal(bvh_intersect(&t, &rays[0], &hits[0]), 0);
        assert_int_equal(hits[0].prim, BVH_INVALID);
        assert_int_equal(bvh_occluded(&t, &rays[0]), 0);
        assert_int_equal(bvh_intersect_batch(&t, rays, hits, 300, 2), BVH_SUCCESS);
        assert_int_equal(bvh_occluded_batch(&t, rays, occ, 300, 2), BVH_SUCCESS);
        for (i = 0; i < 300; i++) {
            assert_int_equal(hits[i].prim, BVH_INVALID);
            assert_int_equal(occ[i], 0);
        }
        bvh_free(&t);
    }
}

static void box_input(void **state) {
    tu_scene s;
    float *tris;
    bvh_aabb *boxes;
    uint32_t i, n = 400;
    int b;
    (void)state;
    tu_scene_random(&s, n, 0x424f58ULL);
    tris = tu_scene_tris(&s);
    boxes = (bvh_aabb *)malloc(n * sizeof *boxes);
    assert_non_null(boxes);
    for (i = 0; i < n; i++) boxes[i] = tu_tri_box(tris + 9 * (size_t)i);
    boxes[10].max = boxes[10].min; /* a point box */
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d;
        bvh_tree t;
        bvh_validation rep;
        bvh_stats st;
        bvh_ray rays[600];
        bvh_hit hits[600];
        uint8_t occ[600];
        memset(&d, 0, sizeof d);
        d.builder = tu_builder(b);
        d.boxes = boxes;
        d.box_count = n;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_null(t.tris);
        assert_int_equal(t.prim_count, n);
        if (bvh_validate(&t, boxes, &rep) != BVH_SUCCESS)
            fail_msg("%s: box tree: %s (node %u)", bvh_builder_name(t.builder), rep.message, rep.node);
        assert_int_equal(bvh_validate(&t, NULL, &rep),
                         BVH_ERROR_INVALID_ARGUMENT); /* nothing to check leaves against */
        assert_int_equal(bvh_get_stats(&t, &st), BVH_SUCCESS);
        assert_int_equal(st.triangle_bytes, 0);
        assert_true(st.bytes == (size_t)st.nodes * 32 + (size_t)st.refs * 4);
        tu_make_rays(tris, n, 0x72ULL, rays, 600);
        for (i = 0; i < 600; i++) {
            bvh_hit h;
            h.prim = 3;
            assert_int_equal(bvh_intersect(&t, &rays[i], &h), 0);
            assert_int_equal(h.prim, BVH_INVALID);
            assert_int_equal(bvh_occluded(&t, &rays[i]), 0);
        }
        memset(hits, 0x5a, sizeof hits);
        memset(occ, 0x5a, sizeof occ);
        assert_int_equal(bvh_intersect_batch(&t, rays, hits, 600, 2), BVH_ERROR_NO_TRIANGLES);
        assert_int_equal(bvh_occluded_batch(&t, rays, occ, 600, 2), BVH_ERROR_NO_TRIANGLES);
        for (i = 0; i < 600; i++) { /* every ray misses, as in the single-ray calls */
            assert_int_equal(hits[i].prim, BVH_INVALID);
            assert_int_equal(occ[i], 0);
        }
        bvh_free(&t);
        /* bad boxes: NaN, Inf, inverted; refused, or skipped and counted */
        {
            bvh_aabb keep[3] = {boxes[3], boxes[50], boxes[399]};
            boxes[3].min.y = NAN;
            boxes[50].max.z = BVH_INF;
            boxes[399].min.x = boxes[399].max.x + 1.0f;
            build_expect(&d, BVH_ERROR_INVALID_GEOMETRY);
            d.skip_invalid = 1;
            assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
            assert_int_equal(t.excluded, 3);
            boxes[3] = keep[0];
            boxes[50] = keep[1];
            boxes[399] = keep[2];
            if (bvh_validate(&t, boxes, &rep) != BVH_SUCCESS)
                fail_msg("%s: box tree with skipped boxes: %s", bvh_builder_name(t.builder), rep.message);
            for (i = 0; i < t.ref_count; i++) assert_true(t.prims[i] != 3 && t.prims[i] != 50 && t.prims[i] != 399);
            bvh_free(&t);
        }
        d.skip_invalid = 0;
        d.boxes = NULL;
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT); /* box_count without boxes */
    }
    free(boxes);
    free(tris);
    tu_scene_free(&s);
}

/* == allocation failures ========================================================================== */
typedef struct counting {
    long calls, fail_at, live;
} counting;
static void *counting_alloc(size_t size, void *user) {
    counting *c = (counting *)user;
    void *p;
    if (++c->calls == c->fail_at) return NULL;
    p = malloc(size);
    if (p) c->live++;
    return p;
}
static void counting_free(void *p, void *user) {
    counting *c = (counting *)user;
    if (!p) return;
    c->live--;
    free(p);
}
static bvh_allocator counting_allocator(counting *c) {
    bvh_allocator a;
    a.alloc = counting_alloc;
    a.free = counting_free;
    a.user = c;
    return a;
}

/* For every builder: failing the k-th allocation, for every k the build makes, returns
   BVH_ERROR_OUT_OF_MEMORY, leaves the tree empty and nothing allocated. */
static void failing_allocator(void **state) {
    tu_scene s;
    int b;
    (void)state;
    tu_scene_random(&s, 600, 0x4f4f4dULL);
    tu_vertex(&s, 3 * 17)[0] = NAN; /* with skip_invalid: the id map of the survivors is allocated too */
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
        counting c = {0, 0, 0};
        bvh_tree t;
        long k, total;
        d.skip_invalid = 1;
        d.threads = 3;
        d.allocator = counting_allocator(&c);
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        total = c.calls;
        assert_true(total >= 3);
        assert_true(c.live >= 1);
        bvh_free(&t);
        assert_int_equal(c.live, 0);
        for (k = 1; k <= total; k++) {
            bvh_result r;
            c.calls = 0;
            c.live = 0;
            c.fail_at = k;
            memset(&t, 0x5a, sizeof t);
            r = bvh_build(&t, &d);
            if (r != BVH_ERROR_OUT_OF_MEMORY)
                fail_msg("%s: allocation %ld of %ld failing: got \"%s\"", bvh_builder_name(tu_builder(b)), k, total,
                         bvh_result_string(r));
            if (c.live != 0)
                fail_msg("%s: allocation %ld of %ld failing: %ld allocations leaked", bvh_builder_name(tu_builder(b)),
                         k, total, c.live);
            assert_tree_empty(&t);
            bvh_free(&t);
            assert_int_equal(c.live, 0);
        }
        print_message("%-14s %ld allocations, each failure handled\n", bvh_builder_name(tu_builder(b)), total);
    }
    tu_scene_free(&s);
}

/* An allocator whose blocks sit `offset` bytes past malloc's alignment. */
typedef struct skewed {
    size_t offset;
    long live;
} skewed;
static void *skewed_alloc(size_t size, void *user) {
    skewed *k = (skewed *)user;
    char *p = (char *)malloc(size + 16);
    void *start = p;
    if (!p) return NULL;
    k->live++;
    memcpy(p, &start, sizeof start); /* the block's start, found again by skewed_free */
    return p + 16 - k->offset;
}
static void skewed_free(void *q, void *user) {
    skewed *k = (skewed *)user;
    void *p;
    if (!q) return;
    memcpy(&p, (char *)q - (16 - k->offset), sizeof p);
    k->live--;
    free(p);
}

/* Vertices at any byte alignment (strides 13-15, a positions pointer one byte off) are read
   safely (make asan's UBSan checks alignment) and give the tree of the aligned copy; indices not
   aligned to 4 bytes, an allocator aligned less than malloc, and an allocator without its free
   are refused with BVH_ERROR_INVALID_ARGUMENT, nothing leaked. */
static void unaligned_input(void **state) {
    static const size_t offsets[] = {1, 4, 8, 12};
    tu_scene s;
    size_t stride, k;
    uint32_t v;
    int b;
    (void)state;
    tu_scene_random(&s, 300, 0x616c6eULL);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
        bvh_tree ref, t;
        tu_build_valid(&s, &d, &ref);
        for (stride = 12; stride <= 16; stride++) {
            char *buf = (char *)malloc(stride * s.vertex_count + 1), *base = buf + (stride == 12 ? 1 : 0);
            const char *diff;
            assert_non_null(buf);
            for (v = 0; v < s.vertex_count; v++) memcpy(base + stride * v, tu_vertex(&s, v), 3 * sizeof(float));
            d.triangles.positions = (const float *)(const void *)base;
            d.triangles.stride = stride;
            tu_build_valid(&s, &d, &t);
            diff = tree_diff(&ref, &t);
            if (diff) fail_msg("%s: stride %zu differs in %s", bvh_builder_name(tu_builder(b)), stride, diff);
            bvh_free(&t);
            free(buf);
        }
        d = tu_scene_desc(&s, tu_builder(b));
        for (k = 0; k < sizeof offsets / sizeof offsets[0]; k++) {
            skewed sk;
            sk.offset = offsets[k];
            sk.live = 0;
            d.allocator.alloc = skewed_alloc;
            d.allocator.free = skewed_free;
            d.allocator.user = &sk;
            build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
            assert_int_equal(sk.live, 0);
        }
        d.allocator.free = NULL; /* alloc without free */
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        d.allocator.alloc = NULL;
        d.allocator.free = skewed_free; /* free without alloc */
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        bvh_free(&ref);
    }
    tu_scene_free(&s);
    tu_scene_strided32(&s);
    {
        uint32_t *idx = (uint32_t *)malloc(3 * sizeof(uint32_t) * s.tri_count + 2);
        bvh_build_desc d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
        assert_non_null(idx);
        memcpy((char *)idx + 2, s.indices, 3 * sizeof(uint32_t) * s.tri_count);
        d.triangles.indices = (const uint32_t *)(const void *)((char *)idx + 2);
        build_expect(&d, BVH_ERROR_INVALID_ARGUMENT);
        free(idx);
    }
    tu_scene_free(&s);
}

/* The validator and the batch calls use the tree's allocator too, and report its failure. */
static void failing_allocator_after_build(void **state) {
    tu_scene s;
    counting c = {0, 0, 0};
    bvh_build_desc d;
    bvh_tree t;
    bvh_validation rep;
    bvh_ray rays[1024];
    bvh_hit hits[1024];
    uint8_t occ[1024];
    float *tris;
    long k, calls;
    (void)state;
    tu_scene_random(&s, 300, 0x56414cULL);
    tris = tu_scene_tris(&s);
    tu_make_rays(tris, s.tri_count, 1, rays, 1024);
    d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
    d.allocator = counting_allocator(&c);
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    /* validator */
    c.calls = 0;
    c.fail_at = 0;
    assert_int_equal(bvh_validate(&t, NULL, &rep), BVH_SUCCESS);
    calls = c.calls;
    for (k = 1; k <= calls; k++) {
        long live = c.live;
        c.calls = 0;
        c.fail_at = k;
        assert_int_equal(bvh_validate(&t, NULL, &rep), BVH_ERROR_OUT_OF_MEMORY);
        assert_int_equal(c.live, live);
    }
    /* batch tracing on 2 threads */
    c.calls = 0;
    c.fail_at = 0;
    assert_int_equal(bvh_intersect_batch(&t, rays, hits, 1024, 2), BVH_SUCCESS);
    calls = c.calls;
    for (k = 1; k <= calls; k++) {
        long live = c.live;
        c.calls = 0;
        c.fail_at = k;
        assert_int_equal(bvh_intersect_batch(&t, rays, hits, 1024, 2), BVH_ERROR_OUT_OF_MEMORY);
        c.calls = 0;
        c.fail_at = k;
        assert_int_equal(bvh_occluded_batch(&t, rays, occ, 1024, 2), BVH_ERROR_OUT_OF_MEMORY);
        assert_int_equal(c.live, live);
    }
    c.fail_at = 0;
    { /* a tree whose allocator is a half pair is refused, as bvh_build refuses such a desc */
        bvh_allocator whole = t.allocator;
        t.allocator.free = NULL;
        assert_int_equal(bvh_validate(&t, NULL, &rep), BVH_ERROR_INVALID_ARGUMENT);
        assert_int_equal(bvh_intersect_batch(&t, rays, hits, 1024, 2), BVH_ERROR_INVALID_ARGUMENT);
        assert_int_equal(bvh_occluded_batch(&t, rays, occ, 1024, 2), BVH_ERROR_INVALID_ARGUMENT);
        t.allocator = whole;
        t.allocator.alloc = NULL;
        assert_int_equal(bvh_validate(&t, NULL, &rep), BVH_ERROR_INVALID_ARGUMENT);
        t.allocator = whole;
    }
    bvh_free(&t);
    assert_int_equal(c.live, 0);
    free(tris);
    tu_scene_free(&s);
}

/* == statistics, free, helpers ==================================================================== */
static void stats_and_free(void **state) {
    tu_scene s;
    bvh_tree t;
    bvh_stats st;
    int b;
    (void)state;
    assert_int_equal(sizeof(bvh_node), 32);
    tu_scene_few(&s, 1);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        tu_build(&s, tu_builder(b), &t);
        assert_int_equal(bvh_get_stats(&t, &st), BVH_SUCCESS);
        assert_int_equal(st.nodes, 1);
        assert_int_equal(st.leaves, 1);
        assert_int_equal(st.refs, 1);
        assert_int_equal(st.max_depth, 1);
        assert_int_equal(st.max_leaf_size, 1);
        assert_int_equal(st.bytes, 32 + 4);
        assert_int_equal(st.triangle_bytes, 36);
        bvh_free(&t);
        assert_tree_empty(&t);
        bvh_free(&t); /* twice is harmless */
    }
    tu_scene_free(&s);
    tu_scene_random(&s, 999, 0x535441ULL);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        tu_build(&s, tu_builder(b), &t);
        assert_int_equal(bvh_get_stats(&t, &st), BVH_SUCCESS);
        assert_int_equal(st.nodes, t.node_count);
        assert_int_equal(st.refs, t.ref_count);
        assert_true(st.bytes == (size_t)st.nodes * 32 + (size_t)st.refs * 4);
        assert_true(st.triangle_bytes == (size_t)st.refs * 36);
        assert_int_equal(st.leaves * 2 - 1, st.nodes);
        assert_true(st.max_depth >= 8 && st.max_depth <= BVH_MAX_DEPTH); /* 125+ leaves: >= ceil(log2 125) + 1 */
        assert_true(st.max_leaf_size >= 1 && st.max_leaf_size <= tu_default_leaf(tu_builder(b)));
        assert_int_equal(bvh_get_stats(&t, NULL), BVH_ERROR_INVALID_ARGUMENT);
        bvh_free(&t);
    }
    assert_int_equal(bvh_get_stats(NULL, &st), BVH_ERROR_INVALID_ARGUMENT);
    tu_scene_free(&s);
    bvh_free(NULL);
}

static void aabb_helpers(void **state) {
    bvh_aabb e = bvh_aabb_empty(), a = bvh_aabb_empty(), b;
    bvh_vec3 c;
    (void)state;
    assert_true(e.min.x > e.max.x && e.min.y > e.max.y && e.min.z > e.max.z);
    assert_true(bvh_aabb_area(e) == 0.0f);
    bvh_aabb_grow(&a, tu_v3(1, 2, 3));
    assert_true(bvh_aabb_area(a) == 0.0f);
    bvh_aabb_grow(&a, tu_v3(2, 4, 6));
    assert_true(bvh_aabb_area(a) == 2.0f * (1 * 2 + 2 * 3 + 3 * 1));
    c = bvh_aabb_centroid(a);
    assert_true(c.x == 1.5f && c.y == 3.0f && c.z == 4.5f);
    b = bvh_aabb_merge(a, e);
    assert_memory_equal(&a, &b, sizeof a);
    b = bvh_aabb_merge(e, a);
    assert_memory_equal(&a, &b, sizeof a);
    assert_true(bvh_aabb_contains(a, a));
    assert_true(bvh_aabb_contains(a, e)); /* everything contains the empty box */
    b = a;
    b.max.z = 6.5f;
    assert_true(bvh_aabb_contains(b, a));
    assert_false(bvh_aabb_contains(a, b));
}

static void triangle_and_camera(void **state) {
    float v0[3] = {0, 0, 0}, v1[3] = {1, 0, 0}, v2[3] = {0, 1, 0};
    bvh_ray ray = {{0.25f, 0.5f, -1.0f}, 0.0f, {0.0f, 0.0f, 2.0f}, BVH_INF};
    bvh_hit h;
    bvh_aabb box = bvh_aabb_empty();
    bvh_camera cam;
    bvh_ray r;
    uint32_t x, y;
    (void)state;
    assert_int_equal(bvh_intersect_triangle(&ray, v0, v1, v2, &h), 1);
    assert_true(h.t == 0.5f && h.u == 0.25f && h.v == 0.5f); /* p = (1-u-v) v0 + u v1 + v v2 */
    assert_int_equal(h.prim, 0);
    assert_int_equal(bvh_intersect_triangle(&ray, v0, v2, v1, NULL), 1); /* either winding, no output */
    ray.tmax = 0.25f;
    assert_int_equal(bvh_intersect_triangle(&ray, v0, v1, v2, &h), 0);
    assert_int_equal(h.prim, BVH_INVALID);
    assert_int_equal(bvh_intersect_triangle(NULL, v0, v1, v2, &h), 0);
    assert_int_equal(bvh_intersect_triangle(&ray, NULL, v1, v2, &h), 0);
    /* the standard camera: unit directions from the eye, the centre pixel looks at the centre */
    bvh_aabb_grow(&box, tu_v3(-1, -2, -3));
    bvh_aabb_grow(&box, tu_v3(3, 2, 1));
    cam = bvh_camera_standard(box, 5, 3);
    assert_int_equal(cam.width, 5);
    assert_int_equal(cam.height, 3);
    for (y = 0; y < 3; y++)
        for (x = 0; x < 5; x++) {
            r = bvh_camera_ray(&cam, x, y);
            assert_memory_equal(&r.origin, &cam.eye, sizeof r.origin);
            assert_true(fabsf(r.dir.x * r.dir.x + r.dir.y * r.dir.y + r.dir.z * r.dir.z - 1.0f) < 1e-5f);
            assert_true(r.tmin == 0.0f && r.tmax == BVH_INF);
        }
    r = bvh_camera_ray(&cam, 2, 1);
    {
        bvh_vec3 c = bvh_aabb_centroid(box), to = tu_sub(c, cam.eye);
        float l = sqrtf(to.x * to.x + to.y * to.y + to.z * to.z);
        assert_true(fabsf(r.dir.x - to.x / l) < 1e-5f && fabsf(r.dir.y - to.y / l) < 1e-5f &&
                    fabsf(r.dir.z - to.z / l) < 1e-5f);
        assert_true(cam.eye.x > box.max.x && cam.eye.y > box.max.y && cam.eye.z > box.max.z);
    }
    r = bvh_camera_ray(&cam, 0, 0); /* y = 0 is the top row */
    assert_true(r.dir.y > bvh_camera_ray(&cam, 0, 2).dir.y);
    for (x = 0; x < 3; x++) { /* a width or height of 0 is taken as 1: finite unit directions */
        cam = bvh_camera_standard(box, x == 1 ? 7 : 0, x == 2 ? 7 : 0);
        r = bvh_camera_ray(&cam, 0, 0);
        assert_true(fp_finite(r.dir.x) && fp_finite(r.dir.y) && fp_finite(r.dir.z));
        assert_true(fabsf(r.dir.x * r.dir.x + r.dir.y * r.dir.y + r.dir.z * r.dir.z - 1.0f) < 1e-5f);
    }
}

/* == the validator catches corrupted trees ======================================================== */
static bvh_tree copy_tree(const bvh_tree *t, uint32_t extra_nodes) {
    bvh_tree c = *t;
    c.nodes = (bvh_node *)malloc((t->node_count + extra_nodes) * sizeof(bvh_node));
    c.prims = (uint32_t *)malloc(t->ref_count * sizeof(uint32_t));
    c.tris = (float *)malloc(t->ref_count * 9 * sizeof(float));
    c.nodes8 = (bvh_node8 *)malloc((t->node8_count ? t->node8_count : 1) * sizeof(bvh_node8));
    c.tri4 = (bvh_tri4 *)malloc((t->tri4_count ? t->tri4_count : 1) * sizeof(bvh_tri4));
    assert_true(c.nodes && c.prims && c.tris && c.nodes8 && c.tri4);
    if (t->nodes8) {
        memcpy(c.nodes8, t->nodes8, t->node8_count * sizeof(bvh_node8));
        memcpy(c.tri4, t->tri4, t->tri4_count * sizeof(bvh_tri4));
    } else {
        free(c.nodes8);
        free(c.tri4);
        c.nodes8 = NULL;
        c.tri4 = NULL;
    }
    memcpy(c.nodes, t->nodes, t->node_count * sizeof(bvh_node));
    memcpy(c.prims, t->prims, t->ref_count * sizeof(uint32_t));
    memcpy(c.tris, t->tris, t->ref_count * 9 * sizeof(float));
    memset(&c.allocator, 0, sizeof c.allocator);
    return c;
}
static void free_copy(bvh_tree *c) {
    free(c->nodes);
    free(c->prims);
    free(c->tris);
    free(c->nodes8);
    free(c->tri4);
    memset(c, 0, sizeof *c);
}
/* bvh_validate reports the corruption with a message; the copy is freed. */
static void expect_invalid(bvh_tree *c, const char *what) {
    bvh_validation rep;
    bvh_result r;
    memset(&rep, 0, sizeof rep);
    r = bvh_validate(c, NULL, &rep);
    if (r != BVH_ERROR_INVALID_TREE)
        fail_msg("%s/%s: bvh_validate returned \"%s\" (%s)", bvh_builder_name(c->builder), what, bvh_result_string(r),
                 rep.message);
    if (rep.message[0] == 0 || strcmp(rep.message, "ok") == 0 || memchr(rep.message, 0, sizeof rep.message) == NULL)
        fail_msg("%s/%s: no message", bvh_builder_name(c->builder), what);
    print_message("%-14s %-34s -> node %10u: %s\n", bvh_builder_name(c->builder), what, rep.node, rep.message);
    free_copy(c);
}
/* A broken structure: bvh_sah and bvh_get_stats refuse to walk it as bvh_validate does. */
static void expect_broken(bvh_tree *c, const char *what) {
    double sah;
    bvh_stats st;
    if (bvh_sah(c, NULL, &sah) != BVH_ERROR_INVALID_TREE) fail_msg("%s: bvh_sah accepted it", what);
    if (bvh_get_stats(c, &st) != BVH_ERROR_INVALID_TREE) fail_msg("%s: bvh_get_stats accepted it", what);
    expect_invalid(c, what);
}
static uint32_t first_leaf(const bvh_tree *t, uint32_t min_count) {
    uint32_t i;
    for (i = 0; i < t->node_count; i++)
        if (t->nodes[i].count >= min_count) return i;
    fail_msg("no leaf of %u or more", min_count);
    return 0;
}
/* An interior node other than the root, and the first node of the pair it belongs to. */
static uint32_t inner_interior(const bvh_tree *t, uint32_t *pair) {
    uint32_t i;
    for (i = 0; i < t->node_count; i++) {
        const bvh_node *p = &t->nodes[i];
        if (p->count) continue;
        if (!t->nodes[p->index].count) {
            *pair = p->index;
            return p->index;
        }
        if (!t->nodes[p->index + 1].count) {
            *pair = p->index;
            return p->index + 1;
        }
    }
    fail_msg("no interior node below the root");
    return 0;
}
/* The node-order invariant (children stored after their parent, bvh_node): a hand-made box tree
   that keeps every other rule is valid in order and refused with a child before its parent. */
static void child_before_parent(void **state) {
    static const bvh_aabb boxes[3] = {{{0, 0, 0}, {1, 1, 1}}, {{2, 0, 0}, {3, 1, 1}}, {{4, 0, 0}, {5, 1, 1}}};
    /* in order: root -> (leaf prim 2, interior -> (leaf prim 0, leaf prim 1)) */
    static const bvh_node in_order[5] = {{{0, 0, 0}, 1, {5, 1, 1}, 0},
                                         {{4, 0, 0}, 0, {5, 1, 1}, 1},
                                         {{0, 0, 0}, 3, {3, 1, 1}, 0},
                                         {{0, 0, 0}, 1, {1, 1, 1}, 1},
                                         {{2, 0, 0}, 2, {3, 1, 1}, 1}};
    /* the same tree with the interior pair's leaves stored before it: root -> (3, 4), 4 -> (1, 2) */
    static const bvh_node reversed[5] = {{{0, 0, 0}, 3, {5, 1, 1}, 0},
                                         {{0, 0, 0}, 1, {1, 1, 1}, 1},
                                         {{2, 0, 0}, 2, {3, 1, 1}, 1},
                                         {{4, 0, 0}, 0, {5, 1, 1}, 1},
                                         {{0, 0, 0}, 1, {3, 1, 1}, 0}};
    uint32_t prims[3] = {2, 0, 1};
    bvh_node nodes[5];
    bvh_tree t;
    bvh_validation rep;
    double sah;
    (void)state;
    memset(&t, 0, sizeof t);
    t.nodes = nodes;
    t.node_count = 5;
    t.prims = prims;
    t.ref_count = 3;
    t.prim_count = 3;
    t.builder = BVH_BUILDER_TOP_DOWN;
    memcpy(nodes, in_order, sizeof nodes);
    assert_int_equal(bvh_validate(&t, boxes, &rep), BVH_SUCCESS);
    memcpy(nodes, reversed, sizeof nodes);
    assert_int_equal(bvh_sah(&t, NULL, &sah), BVH_SUCCESS); /* reachable once each: walkable */
    assert_int_equal(bvh_validate(&t, boxes, &rep), BVH_ERROR_INVALID_TREE);
    assert_int_equal(rep.node, 4);
    assert_string_equal(rep.message, "child stored before its parent");
}
/* Leaves whose reference ranges overlap, with the count of references and of primitives used
   still right: a tree with split references (a primitive in two references), so no primitive
   appears twice where it should not. Refused: every reference is in exactly one leaf. */
static void leaves_share_references(void **state) {
    static const bvh_aabb boxes[3] = {{{0, 0, 0}, {1, 1, 1}}, {{2, 0, 0}, {3, 1, 1}}, {{4, 0, 0}, {5, 1, 1}}};
    /* root -> (leaf refs 0-1: prims 0, 1; leaf refs 2-3: prims 2, 1) */
    static const bvh_node good[3] = {
        {{0, 0, 0}, 1, {5, 1, 1}, 0}, {{0, 0, 0}, 0, {3, 1, 1}, 2}, {{2, 0, 0}, 2, {5, 1, 1}, 2}};
    uint32_t prims[4] = {0, 1, 2, 1};
    bvh_node nodes[3];
    bvh_tree t;
    bvh_validation rep;
    (void)state;
    memset(&t, 0, sizeof t);
    t.nodes = nodes;
    t.node_count = 3;
    t.prims = prims;
    t.ref_count = 4;
    t.prim_count = 3;
    t.builder = BVH_BUILDER_SAH_MIDPOINT; /* a builder that splits references */
    memcpy(nodes, good, sizeof nodes);
    assert_int_equal(bvh_validate(&t, boxes, &rep), BVH_SUCCESS);
    nodes[2].index = 1; /* refs 1-2: ref 1 in both leaves, ref 3 in none; prims 0, 1, 2 all used */
    assert_int_equal(bvh_validate(&t, boxes, &rep), BVH_ERROR_INVALID_TREE);
    assert_string_equal(rep.message, "reference in two leaves");
}

static void corrupted_trees(void **state) {
    tu_scene s;
    int b;
    (void)state;
    tu_scene_random(&s, 700, 0x434f52ULL);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_tree t, c;
        bvh_validation rep;
        uint32_t i, x, pair, leaf, child;
        tu_build(&s, tu_builder(b), &t);
        child = t.nodes[0].index;

        c = copy_tree(&t, 0); /* the copy itself is valid */
        assert_int_equal(bvh_validate(&c, NULL, &rep), BVH_SUCCESS);
        free_copy(&c);

        c = copy_tree(&t, 0); /* a child box shrunk to its centre: its contents stick out */
        c.nodes[child].min = c.nodes[child].max = bvh_aabb_centroid(bvh_tree_bounds(&c));
        expect_invalid(&c, "child box shrunk to a point");

        c = copy_tree(&t, 0); /* a child box grown beyond its parent */
        c.nodes[child + 1].max.x = c.nodes[0].max.x + 1.0f;
        expect_invalid(&c, "child box outside its parent");

        c = copy_tree(&t, 0); /* a leaf box that does not contain its triangles */
        leaf = first_leaf(&c, 1);
        c.nodes[leaf].max.x = c.nodes[leaf].min.x;
        expect_invalid(&c, "leaf box shrunk");

        c = copy_tree(&t, 0); /* a NaN in a box */
        c.nodes[child].min.y = NAN;
        expect_invalid(&c, "NaN in a node box");

        c = copy_tree(&t, 0); /* a leaf range one past the references */
        leaf = first_leaf(&c, 1);
        c.nodes[leaf].index = c.ref_count - c.nodes[leaf].count + 1;
        expect_invalid(&c, "leaf range past the end");

        c = copy_tree(&t, 0); /* a leaf range whose end overflows 32 bits */
        c.nodes[leaf].index = 0xFFFFFFF0u;
        c.nodes[leaf].count = 0x20;
        expect_invalid(&c, "leaf range overflowing");

        c = copy_tree(&t, 0); /* an interior node pointing past the node array */
        c.nodes[0].index = c.node_count - 1;
        expect_broken(&c, "children past the node array");

        /* a cycle: an interior node's children are its own pair. All boxes are made the root's
           first, so that the cycle is the only defect. */
        c = copy_tree(&t, 0);
        for (i = 0; i < c.node_count; i++) {
            c.nodes[i].min = c.nodes[0].min;
            c.nodes[i].max = c.nodes[0].max;
        }
        assert_int_equal(bvh_validate(&c, NULL, &rep), BVH_SUCCESS);
        x = inner_interior(&c, &pair);
        c.nodes[x].index = pair;
        expect_broken(&c, "cycle (own pair as children)");

        c = copy_tree(&t, 0); /* a cycle back to the root */
        for (i = 0; i < c.node_count; i++) {
            c.nodes[i].min = c.nodes[0].min;
            c.nodes[i].max = c.nodes[0].max;
        }
        x = inner_interior(&c, &pair);
        c.nodes[x].index = 0;
        expect_broken(&c, "cycle (root as child)");

        c = copy_tree(&t, 0); /* a primitive referenced twice (and so another one missing) */
        c.prims[1] = c.prims[0];
        expect_invalid(&c, "primitive referenced twice");

        c = copy_tree(&t, 0); /* a reference out of the primitive range */
        c.prims[5] = c.prim_count;
        expect_invalid(&c, "reference out of range");

        c = copy_tree(&t, 0); /* a reference no leaf covers: a primitive missing */
        leaf = first_leaf(&c, 2);
        c.nodes[leaf].count--;
        expect_invalid(&c, "reference not in any leaf");

        c = copy_tree(&t, 0); /* one reference fewer: a primitive missing */
        for (i = 0; i < c.node_count; i++)
            if (c.nodes[i].count >= 2 && c.nodes[i].index + c.nodes[i].count == c.ref_count) break;
        if (i < c.node_count) {
            c.nodes[i].count--;
            c.ref_count--;
            expect_invalid(&c, "primitive missing");
        } else {
            free_copy(&c);
        }

        c = copy_tree(&t, 1); /* a node no one reaches */
        c.nodes[c.node_count] = c.nodes[first_leaf(&c, 1)];
        c.node_count++;
        expect_invalid(&c, "unreachable node");

        c = copy_tree(&t, 0); /* arrays missing */
        free(c.nodes);
        c.nodes = NULL;
        expect_invalid(&c, "node array missing");

        /* the 8-wide copy: the root's first slot and, if it is interior, the node it points to */
        assert_non_null(t.nodes8);
        c = copy_tree(&t, 0); /* a slot box grown beyond the root */
        c.nodes8[0].max[1][0] = c.nodes[0].max.y + 1.0f;
        expect_invalid(&c, "8-wide slot outside the root");
        c = copy_tree(&t, 0); /* a slot box shrunk to a point */
        c.nodes8[0].max[0][0] = c.nodes8[0].min[0][0];
        c.nodes8[0].max[1][0] = c.nodes8[0].min[1][0];
        c.nodes8[0].max[2][0] = c.nodes8[0].min[2][0];
        expect_invalid(&c, "8-wide slot shrunk");
        c = copy_tree(&t, 0); /* NaN in a slot box */
        c.nodes8[0].min[2][1] = NAN;
        expect_invalid(&c, "8-wide NaN");
        c = copy_tree(&t, 0); /* a slot pointing back at the root (a cycle), or a leaf past the end */
        if (c.nodes8[0].count[0])
            c.nodes8[0].child[0] = c.tri4_count;
        else
            c.nodes8[0].child[0] = 0;
        expect_invalid(&c, c.nodes8[0].count[0] ? "8-wide leaf past the end" : "8-wide cycle to the root");
        for (i = 0; i < t.node8_count * 8; i++) /* a leaf slot */
            if (t.nodes8[i / 8].count[i % 8]) break;
        assert_true(i < t.node8_count * 8);
        c = copy_tree(&t, 0); /* a leaf slot one packet short, or long */
        c.nodes8[i / 8].count[i % 8]--;
        expect_invalid(&c, "8-wide leaf one packet short");
        c = copy_tree(&t, 0);
        c.nodes8[i / 8].count[i % 8]++;
        expect_invalid(&c, "8-wide leaf one packet long");
        c = copy_tree(&t, 0); /* a packet lane holding another primitive */
        c.tri4[c.nodes8[i / 8].child[i % 8]].prim[0] ^= 1u;
        expect_invalid(&c, "packet lane with another primitive");
        c = copy_tree(&t, 0); /* a packet lane outside its slot's box */
        c.tri4[c.nodes8[i / 8].child[i % 8]].v[1][0][0] = c.nodes[0].max.x + 1.0f;
        expect_invalid(&c, "packet lane outside its box");
        c = copy_tree(&t, 0); /* a packet no leaf holds */
        c.tri4_count++;
        c.tri4 = (bvh_tri4 *)realloc(c.tri4, c.tri4_count * sizeof(bvh_tri4));
        assert_non_null(c.tri4);
        c.tri4[c.tri4_count - 1] = c.tri4[0];
        expect_invalid(&c, "packet in no leaf");
        c = copy_tree(&t, 0); /* a wide node no one reaches */
        c.node8_count--;
        expect_invalid(&c, "8-wide node array one short");
        bvh_free(&t);
    }
    tu_scene_free(&s);
    assert_int_equal(bvh_validate(NULL, NULL, NULL), BVH_ERROR_INVALID_ARGUMENT);
}

/* A chain of BVH_MAX_DEPTH levels is valid; one level more is not. */
static void make_chain(uint32_t levels, bvh_tree *t) {
    uint32_t k, n = levels;
    memset(t, 0, sizeof *t);
    t->nodes = (bvh_node *)malloc((2 * n - 1) * sizeof(bvh_node));
    t->prims = (uint32_t *)malloc(n * sizeof(uint32_t));
    t->tris = (float *)malloc(9 * n * sizeof(float));
    assert_true(t->nodes && t->prims && t->tris);
    for (k = 0; k < n; k++) {
        float *v = t->tris + 9 * (size_t)k;
        tu_set3(v, 0, 0, (float)k);
        tu_set3(v + 3, 1, 0, (float)k);
        tu_set3(v + 6, 0, 1, (float)k);
        t->prims[k] = k;
    }
    for (k = 0; k + 1 < n; k++) { /* interior node at 2k: children 2k + 1 (leaf k) and 2k + 2 */
        t->nodes[2 * k].index = 2 * k + 1;
        t->nodes[2 * k].count = 0;
        t->nodes[2 * k + 1].index = k;
        t->nodes[2 * k + 1].count = 1;
    }
    t->nodes[2 * (n - 1)].index = n - 1;
    t->nodes[2 * (n - 1)].count = 1;
    for (k = 0; k < 2 * n - 1; k++) {
        uint32_t first = t->nodes[k].count ? t->nodes[k].index : k / 2;
        t->nodes[k].min = tu_v3(0, 0, (float)first);
        t->nodes[k].max = tu_v3(1, 1, t->nodes[k].count ? (float)first : (float)(n - 1));
    }
    t->node_count = 2 * n - 1;
    t->ref_count = t->prim_count = n;
    t->builder = BVH_BUILDER_TOP_DOWN;
}
static void depth_limit(void **state) {
    bvh_tree t;
    bvh_validation rep;
    bvh_stats st;
    (void)state;
    make_chain(BVH_MAX_DEPTH, &t);
    if (bvh_validate(&t, NULL, &rep) != BVH_SUCCESS) fail_msg("%d levels: %s", BVH_MAX_DEPTH, rep.message);
    assert_int_equal(bvh_get_stats(&t, &st), BVH_SUCCESS);
    assert_int_equal(st.max_depth, BVH_MAX_DEPTH);
    free_copy(&t);
    make_chain(BVH_MAX_DEPTH + 1, &t);
    expect_invalid(&t, "one level beyond BVH_MAX_DEPTH");
    make_chain(3 * BVH_MAX_DEPTH, &t);
    assert_int_equal(bvh_get_stats(&t, &st), BVH_ERROR_INVALID_TREE);
    expect_invalid(&t, "three times BVH_MAX_DEPTH");
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(result_strings),
        cmocka_unit_test(builder_names),
        cmocka_unit_test(build_argument_errors),
        cmocka_unit_test(invalid_geometry),
        cmocka_unit_test(all_invalid_skipped),
        cmocka_unit_test(zero_triangles),
        cmocka_unit_test(box_input),
        cmocka_unit_test(failing_allocator),
        cmocka_unit_test(unaligned_input),
        cmocka_unit_test(failing_allocator_after_build),
        cmocka_unit_test(stats_and_free),
        cmocka_unit_test(aabb_helpers),
        cmocka_unit_test(triangle_and_camera),
        cmocka_unit_test(corrupted_trees),
        cmocka_unit_test(child_before_parent),
        cmocka_unit_test(leaves_share_references),
        cmocka_unit_test(depth_limit),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
