/* tests/test_refit.c - bvh_refit, bvh_save and bvh_load.

   Refit: for every scene and builder, the tree built on a scene and refitted to a deformed copy of
   its vertices (a twist and a wave, deterministic) passes bvh_validate and gives exactly the
   brute-force hits over the moved triangles on random rays (tu_make_rays), camera rays and
   diffuse-like bounce rays from the camera's hits, on the 8-wide layout and on a binary-only tree;
   the result does not depend on the thread count; refitted back to the original vertices, a tree
   whose builder does not split references is byte for byte the build's. Box trees likewise.
   Errors leave the tree unchanged; a refit allocates nothing.
   Save and load: every builder's tree comes back byte for byte (the 8-wide layout remade on
   load), through memory and through callbacks; truncation at every length, a bit flip in every
   byte, another version or byte order, hostile sizes and structures with valid checksums, and
   allocation failures all give their code, leak nothing and allocate no more than the input
   holds. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"
#include "test_util.h"
#include "tree_diff.h"

#define RF_RAYS 3000
#define RF_CAMERA 40 /* camera rays: RF_CAMERA x RF_CAMERA */
#define MAX_REPORTS 4

/* == moving the vertices ====================================================================== */
/* A copy of the scene whose vertices are twisted about the vertical axis through the centre (up
   to `amount` radians at the top and bottom) and waved vertically; computed in double, relative
   to the bounds, so that every scene stays finite. Bytes after x, y, z are kept. */
static void rf_deform(const tu_scene *s, tu_scene *out, double amount) {
    bvh_aabb b = tu_scene_bounds(s);
    double cx = 0.5 * ((double)b.min.x + b.max.x), cy = 0.5 * ((double)b.min.y + b.max.y);
    double cz = 0.5 * ((double)b.min.z + b.max.z), hy = 0.5 * ((double)b.max.y - b.min.y);
    double hx = 0.5 * ((double)b.max.x - b.min.x);
    size_t bytes = (size_t)s->vertex_count * tu_stride(s);
    uint32_t v;
    *out = *s;
    out->data = (float *)malloc(bytes ? bytes : 1);
    assert_non_null(out->data);
    memcpy(out->data, s->data, bytes);
    out->indices = NULL;
    if (s->indices) {
        out->indices = (uint32_t *)malloc(3 * sizeof(uint32_t) * s->tri_count);
        assert_non_null(out->indices);
        memcpy(out->indices, s->indices, 3 * sizeof(uint32_t) * s->tri_count);
    }
    for (v = 0; v < s->vertex_count; v++) {
        float *p = tu_vertex(out, v);
        double ny = hy > 0 ? (p[1] - cy) / hy : 0, nx = hx > 0 ? (p[0] - cx) / hx : 0;
        double a = amount * ny, x = p[0] - cx, z = p[2] - cz;
        if (!fp_finite(p[0]) || !fp_finite(p[1]) || !fp_finite(p[2])) continue;
        p[0] = (float)(cx + cos(a) * x - sin(a) * z);
        p[2] = (float)(cz + sin(a) * x + cos(a) * z);
        p[1] = (float)(p[1] + 0.1 * amount * (hy > 0 ? hy : 1) * sin(3.0 * nx));
    }
}
static bvh_refit_desc rf_desc(const tu_scene *s, uint32_t threads) {
    bvh_refit_desc d;
    memset(&d, 0, sizeof d);
    d.triangles = tu_scene_desc(s, BVH_BUILDER_DEFAULT).triangles;
    d.threads = threads;
    return d;
}
static void rf_valid(const bvh_tree *t, const bvh_aabb *boxes, const char *what) {
    bvh_validation rep;
    if (bvh_validate(t, boxes, &rep) != BVH_SUCCESS)
        fail_msg("%s/%s: bvh_validate: %s (node %u)", what, bvh_builder_name(t->builder), rep.message, rep.node);
}

/* == rays ===================================================================================== */
/* RF_CAMERA^2 camera rays over the triangles' bounds, then as many diffuse-like rays: from each
   camera hit (just off the surface, on the side the camera sees), a random direction in that
   hemisphere; a missed pixel gives a random ray from the camera. */
static size_t rf_camera_diffuse(const float *tris, uint32_t n, uint64_t seed, bvh_ray *rays) {
    bvh_aabb b;
    float diag = tu_diag(tris, n, &b);
    bvh_camera cam = bvh_camera_standard(b, RF_CAMERA, RF_CAMERA);
    tu_rng r = tu_rng_make(seed);
    size_t m = 0, i;
    uint32_t x, y;
    for (y = 0; y < RF_CAMERA; y++)
        for (x = 0; x < RF_CAMERA; x++) rays[m++] = bvh_camera_ray(&cam, x, y);
    for (i = 0; i < (size_t)RF_CAMERA * RF_CAMERA; i++) {
        bvh_hit h;
        bvh_ray ray = rays[i];
        bvh_vec3 d = tu_sphere_dir(&r);
        if (tu_brute(tris, n, &rays[i], &h)) {
            const float *t = tris + 9 * (size_t)h.prim;
            bvh_vec3 e1 = tu_v3(t[3] - t[0], t[4] - t[1], t[5] - t[2]),
                     e2 = tu_v3(t[6] - t[0], t[7] - t[1], t[8] - t[2]);
            bvh_vec3 nrm = tu_v3(e1.y * e2.z - e1.z * e2.y, e1.z * e2.x - e1.x * e2.z, e1.x * e2.y - e1.y * e2.x);
            float len = sqrtf(nrm.x * nrm.x + nrm.y * nrm.y + nrm.z * nrm.z), off = 1e-4f * diag;
            if (len > 0.0f && fp_finite(len)) nrm = tu_v3(nrm.x / len, nrm.y / len, nrm.z / len);
            if (nrm.x * ray.dir.x + nrm.y * ray.dir.y + nrm.z * ray.dir.z > 0.0f) nrm = tu_v3(-nrm.x, -nrm.y, -nrm.z);
            if (d.x * nrm.x + d.y * nrm.y + d.z * nrm.z < 0.0f) d = tu_v3(-d.x, -d.y, -d.z);
            ray.origin =
                tu_v3(ray.origin.x + h.t * ray.dir.x + off * nrm.x, ray.origin.y + h.t * ray.dir.y + off * nrm.y,
                      ray.origin.z + h.t * ray.dir.z + off * nrm.z);
        }
        ray.dir = d;
        if (!fp_finite(ray.origin.x) || !fp_finite(ray.origin.y) || !fp_finite(ray.origin.z)) ray.origin = cam.eye;
        rays[m++] = ray;
    }
    return m;
}
/* Mismatches of the tree's hits (bvh_intersect, bvh_occluded, and the batch call on 3 threads)
   against the brute-force ones. */
static size_t rf_compare(const tu_scene *s, const bvh_tree *t, const bvh_ray *rays, const bvh_hit *want, size_t count,
                         const char *what) {
    size_t i, bad = 0;
    bvh_hit *batch = (bvh_hit *)malloc(count * sizeof *batch);
    assert_non_null(batch);
    assert_int_equal(bvh_intersect_batch(t, rays, batch, count, 3), BVH_SUCCESS);
    for (i = 0; i < count; i++) {
        bvh_hit h;
        int found = bvh_intersect(t, &rays[i], &h), want_found = want[i].prim != BVH_INVALID;
        if (found == want_found && tu_hit_equal(&h, &want[i]) && tu_hit_equal(&batch[i], &h) &&
            bvh_occluded(t, &rays[i]) == want_found)
            continue;
        if (bad++ < MAX_REPORTS) {
            print_error("%s/%s (%s): ray %zu differs from the brute force\n", s->name, bvh_builder_name(t->builder),
                        what, i);
            tu_print_ray(&rays[i]);
            tu_print_hit("bvh", &h);
            tu_print_hit("brute force", &want[i]);
        }
    }
    free(batch);
    return bad;
}

/* == refit ==================================================================================== */
/* Every builder, refitted to the deformed scene on 1 and 3 threads (the same tree), with and
   without the 8-wide layout: valid, the brute-force hits; refitted back: the build's tree. */
static void refit_exact(void **state) {
    int id = tu_state_id(state), b;
    tu_scene s, moved;
    float *tris;
    bvh_ray *rays;
    bvh_hit *want;
    size_t count, bad = 0;
    if (!tu_scene_make(id, &s)) {
        skip();
        return;
    }
    rf_deform(&s, &moved, 0.8);
    tris = tu_scene_tris(&moved);
    rays = (bvh_ray *)malloc((RF_RAYS + 2 * RF_CAMERA * RF_CAMERA) * sizeof *rays);
    want = (bvh_hit *)malloc((RF_RAYS + 2 * RF_CAMERA * RF_CAMERA) * sizeof *want);
    assert_true(rays && want);
    tu_make_rays(tris, moved.tri_count, 0x726566697400ULL + (uint64_t)id, rays, RF_RAYS);
    count = RF_RAYS + rf_camera_diffuse(tris, moved.tri_count, 0x646966ULL + (uint64_t)id, rays + RF_RAYS);
    tu_oracle_run(tris, moved.tri_count, rays, count, want);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        int w;
        bvh_builder_info info;
        assert_int_equal(bvh_builder_get_info(tu_builder(b), &info), BVH_SUCCESS);
        for (w = 0; w < 2; w++) {
            bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
            bvh_refit_desc rd = rf_desc(&moved, 1);
            bvh_tree t, t3, orig;
            const char *diff;
            d.trace_width = w ? 2 : 0;
            d.threads = 3;
            tu_build_valid(&s, &d, &t);
            tu_build_valid(&s, &d, &t3);
            tu_build_valid(&s, &d, &orig);
            assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
            rd.threads = 3;
            assert_int_equal(bvh_refit(&t3, &rd), BVH_SUCCESS);
            rf_valid(&t, NULL, s.name);
            if ((diff = tree_diff(&t, &t3)) != NULL)
                fail_msg("%s/%s: refit on 1 and 3 threads: %s differs", s.name, info.name, diff);
            bad += rf_compare(&moved, &t, rays, want, count, w ? "binary" : "8-wide");
            /* twice in a row (the grouping is the build's, not the last refit's), then back */
            assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
            if ((diff = tree_diff(&t, &t3)) != NULL)
                fail_msg("%s/%s: a second refit changed %s", s.name, info.name, diff);
            rd = rf_desc(&s, 2);
            assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
            rf_valid(&t, NULL, s.name);
            if (!info.splits_references && (diff = tree_diff(&t, &orig)) != NULL)
                fail_msg("%s/%s: refitted back, %s differs from the build's", s.name, info.name, diff);
            bvh_free(&t);
            bvh_free(&t3);
            bvh_free(&orig);
        }
    }
    free(rays);
    free(want);
    free(tris);
    tu_scene_free(&moved);
    tu_scene_free(&s);
    assert_int_equal(bad, 0);
}

static int tu_builder_splits(bvh_builder b) {
    bvh_builder_info info;
    assert_int_equal(bvh_builder_get_info(b, &info), BVH_SUCCESS);
    return info.splits_references;
}
/* A box tree: boxes moved and scaled, refitted, valid against the new boxes; back: the build's. */
static void refit_boxes(void **state) {
    const uint32_t n = 2000;
    bvh_aabb *boxes = (bvh_aabb *)malloc(n * sizeof *boxes), *moved = (bvh_aabb *)malloc(n * sizeof *moved);
    tu_rng r = tu_rng_make(0x626f786573ULL);
    uint32_t i;
    int b;
    (void)state;
    assert_true(boxes && moved);
    for (i = 0; i < n; i++) {
        bvh_vec3 c = tu_v3(tu_range(&r, -50, 50), tu_range(&r, -50, 50), tu_range(&r, -50, 50));
        float e = tu_range(&r, 0.0f, 2.0f), k = tu_range(&r, 0.5f, 2.0f);
        boxes[i].min = tu_v3(c.x - e, c.y - e, c.z - e);
        boxes[i].max = tu_v3(c.x + e, c.y + e, c.z + e);
        moved[i].min = tu_v3(k * c.x - e + 0.1f * c.y, c.y - e * k, c.z - e);
        moved[i].max = tu_v3(k * c.x + e + 0.1f * c.y, c.y + e * k, c.z + e);
    }
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d;
        bvh_refit_desc rd;
        bvh_tree t, orig;
        const char *diff;
        memset(&d, 0, sizeof d);
        memset(&rd, 0, sizeof rd);
        d.builder = tu_builder(b);
        d.boxes = boxes;
        d.box_count = n;
        d.threads = 2;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_int_equal(bvh_build(&orig, &d), BVH_SUCCESS);
        rd.boxes = moved;
        rd.box_count = n;
        rd.threads = 3;
        assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
        rf_valid(&t, moved, "boxes");
        rd.boxes = boxes;
        assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
        if (!tu_builder_splits(d.builder) && (diff = tree_diff(&t, &orig)) != NULL)
            fail_msg("boxes/%s: refitted back, %s differs", bvh_builder_name(d.builder), diff);
        /* a triangle desc for a box tree, an inverted box */
        memset(&rd, 0, sizeof rd);
        rd.triangles.positions = &moved[0].min.x; /* 2000 boxes are 4000 vertices */
        rd.triangles.vertex_count = 2 * n;
        rd.triangles.triangle_count = n / 2;
        assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_ARGUMENT);
        memset(&rd, 0, sizeof rd);
        rd.boxes = moved;
        rd.box_count = n - 1;
        assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_ARGUMENT);
        rd.box_count = n;
        moved[7].min.x = moved[7].max.x + 1.0f;
        assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_GEOMETRY);
        moved[7].min.x = moved[7].max.x - 1.0f;
        if (!tu_builder_splits(d.builder) && (diff = tree_diff(&t, &orig)) != NULL)
            fail_msg("boxes: a refused refit changed %s", diff);
        bvh_free(&t);
        bvh_free(&orig);
    }
    free(boxes);
    free(moved);
}

/* A counting allocator whose allocations fail from number fail_at on (-1: never). */
typedef struct rf_alloc {
    long calls, live, fail_at;
    size_t largest;
} rf_alloc;
static void *rf_alloc_fn(size_t size, void *user) {
    rf_alloc *a = (rf_alloc *)user;
    void *p;
    if (a->fail_at >= 0 && a->calls >= a->fail_at) return NULL;
    a->calls++;
    if (size > a->largest) a->largest = size;
    if ((p = malloc(size)) != NULL) a->live++;
    return p;
}
static void rf_free_fn(void *p, void *user) {
    rf_alloc *a = (rf_alloc *)user;
    if (p) a->live--;
    free(p);
}
static bvh_allocator rf_allocator(rf_alloc *a, long fail_at) {
    bvh_allocator al;
    memset(a, 0, sizeof *a);
    a->fail_at = fail_at;
    al.alloc = rf_alloc_fn;
    al.free = rf_free_fn;
    al.user = a;
    return al;
}

/* Refused refits leave the tree as it was; a refit allocates nothing (on one thread), and a team
   that cannot be allocated runs on one thread. */
static void refit_errors(void **state) {
    tu_scene s, moved;
    bvh_tree t, orig;
    bvh_refit_desc rd;
    bvh_build_desc d;
    rf_alloc a;
    const char *diff;
    float keep;
    uint32_t keep_index;
    (void)state;
    tu_scene_strided32(&s); /* indexed, stride 32 */
    rf_deform(&s, &moved, 0.5);
    d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
    d.allocator = rf_allocator(&a, -1);
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    d.allocator.alloc = NULL;
    d.allocator.free = NULL;
    d.allocator.user = NULL;
    assert_int_equal(bvh_build(&orig, &d), BVH_SUCCESS);
    rd = rf_desc(&moved, 1);
    assert_int_equal(bvh_refit(NULL, &rd), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_refit(&t, NULL), BVH_ERROR_INVALID_ARGUMENT);
    rd.triangles.triangle_count--;
    assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_ARGUMENT);
    rd = rf_desc(&moved, 1);
    rd.triangles.stride = 8;
    assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_ARGUMENT);
    rd = rf_desc(&moved, 1);
    rd.triangles.positions = NULL;
    assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_ARGUMENT);
    rd = rf_desc(&moved, 1);
    rd.boxes = (const bvh_aabb *)(const void *)moved.data;
    rd.box_count = 1;
    assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_ARGUMENT);
    /* an index out of range, a NaN and an Inf in used vertices, on 1 and 3 threads */
    rd = rf_desc(&moved, 3);
    keep_index = moved.indices[100];
    moved.indices[100] = moved.vertex_count;
    assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INDEX_OUT_OF_RANGE);
    moved.indices[100] = keep_index;
    keep = tu_vertex(&moved, 17)[1];
    tu_vertex(&moved, 17)[1] = NAN;
    assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_GEOMETRY);
    rd.threads = 1;
    tu_vertex(&moved, 17)[1] = -INFINITY;
    assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_GEOMETRY);
    tu_vertex(&moved, 17)[1] = keep;
    if ((diff = tree_diff(&t, &orig)) != NULL) fail_msg("a refused refit changed %s", diff);
    /* a NaN in a vertex no triangle uses: accepted, as the build accepts it */
    moved.data = (float *)realloc(moved.data, (moved.vertex_count + 1) * tu_stride(&moved));
    assert_non_null(moved.data);
    tu_set3(tu_vertex(&moved, moved.vertex_count), NAN, INFINITY, NAN);
    moved.vertex_count++;
    rd = rf_desc(&moved, 2);
    assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
    rd.threads = 1;
    a.calls = 0;
    a.fail_at = 0; /* ... and nothing may be allocated: on one thread, nor on three (the team's
                      bookkeeping cannot be had: the refit runs on one) */
    keep = tu_vertex(&moved, 5)[0];
    assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
    rd.threads = 3;
    assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
    assert_int_equal(a.calls, 0);
    a.fail_at = -1;
    rf_valid(&t, NULL, "stride-32");
    bvh_free(&t);
    assert_int_equal(a.live, 0);
    (void)keep;
    /* a damaged grouping: a slot twice in a wide node's order (the walk still takes each child
       once; the grouping's check refuses the tree) */
    d = tu_scene_desc(&s, BVH_BUILDER_PLOC_PARALLEL);
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    assert_non_null(t.nodes8);
    t.nodes8[0].order[1] = t.nodes8[0].order[0];
    rd = rf_desc(&moved, 2);
    assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_TREE);
    bvh_free(&t);
    /* skip_invalid: an excluded triangle may stay NaN; a kept one may not become NaN */
    tu_vertex(&s, s.indices[0])[0] = NAN;
    d = tu_scene_desc(&s, BVH_BUILDER_TOP_DOWN);
    d.skip_invalid = 1;
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    assert_true(t.excluded > 0);
    tu_vertex(&moved, moved.indices[0])[0] = NAN;
    rd = rf_desc(&moved, 2);
    assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
    rf_valid(&t, NULL, "skip_invalid");
    tu_vertex(&moved, moved.indices[3 * 500])[2] = INFINITY;
    assert_int_equal(bvh_refit(&t, &rd), BVH_ERROR_INVALID_GEOMETRY);
    rf_valid(&t, NULL, "skip_invalid");
    bvh_free(&t);
    /* an empty tree */
    memset(&d, 0, sizeof d);
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    memset(&rd, 0, sizeof rd);
    assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
    bvh_free(&t);
    bvh_free(&orig);
    tu_scene_free(&moved);
    tu_scene_free(&s);
}

/* == save and load ============================================================================ */
typedef struct rf_buf {
    unsigned char *data;
    size_t size, cap, pos;
    long fail_after;
} rf_buf;
static size_t rf_write(void *user, const void *data, size_t size) {
    rf_buf *b = (rf_buf *)user;
    if (b->fail_after >= 0 && b->size + size > (size_t)b->fail_after) return 0;
    if (b->size + size > b->cap) {
        size_t cap = b->cap ? b->cap : 256;
        while (cap < b->size + size) cap *= 2;
        b->data = (unsigned char *)realloc(b->data, cap);
        assert_non_null(b->data);
        b->cap = cap;
    }
    memcpy(b->data + b->size, data, size);
    b->size += size;
    return size;
}
static size_t rf_read(void *user, void *data, size_t size) {
    rf_buf *b = (rf_buf *)user;
    size_t n = size < b->size - b->pos ? size : b->size - b->pos;
    memcpy(data, b->data + b->pos, n);
    b->pos += n;
    return n;
}
static rf_buf rf_save(const bvh_tree *t) {
    rf_buf b;
    memset(&b, 0, sizeof b);
    b.fail_after = -1;
    assert_int_equal(bvh_save(t, rf_write, &b), BVH_SUCCESS);
    assert_int_equal(b.size, bvh_save_size(t));
    return b;
}
/* Loads from memory, through the read callback and borrowing the memory (desc.borrow): all three
   must give the same result (and tree). */
static bvh_result rf_load(bvh_tree *t, const unsigned char *data, size_t size, bvh_load_desc d) {
    bvh_tree t2, t3;
    rf_buf b;
    bvh_result r, r2, r3;
    memset(&b, 0, sizeof b);
    b.data = (unsigned char *)(uintptr_t)data;
    b.size = size;
    d.data = data;
    d.size = size;
    d.read = NULL;
    r = bvh_load(t, &d);
    d.data = NULL;
    d.size = 0;
    d.read = rf_read;
    d.user = &b;
    r2 = bvh_load(&t2, &d);
    if (r != r2)
        fail_msg("bvh_load from memory: %s, through a callback: %s", bvh_result_string(r), bvh_result_string(r2));
    if (r == BVH_SUCCESS && tree_diff(t, &t2)) fail_msg("memory and callback loads differ: %s", tree_diff(t, &t2));
    d.data = data;
    d.size = size;
    d.read = NULL;
    d.borrow = 1;
    r3 = bvh_load(&t3, &d);
    if (r != r3) fail_msg("bvh_load from memory: %s, borrowing it: %s", bvh_result_string(r), bvh_result_string(r3));
    if (r == BVH_SUCCESS && tree_diff(t, &t3)) fail_msg("copied and borrowed loads differ: %s", tree_diff(t, &t3));
    if (r3 == BVH_SUCCESS) assert_int_equal(t3.borrowed, t3.node_count != 0);
    if (r != BVH_SUCCESS) assert_null(t->nodes);
    if (r3 != BVH_SUCCESS) assert_null(t3.nodes);
    bvh_free(&t2);
    bvh_free(&t3); /* leaves the buffer: freeing it would fail under ASan, or abort */
    return r;
}

/* Every builder's tree, with and without the 8-wide layout, a box tree, a skip_invalid tree and
   an empty one, come back byte for byte; a refitted tree comes back with the same hits. */
static void save_load_round_trip(void **state) {
    int id = tu_state_id(state), b;
    tu_scene s;
    bvh_load_desc ld;
    if (!tu_scene_make(id, &s)) {
        skip();
        return;
    }
    memset(&ld, 0, sizeof ld);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        int w;
        for (w = 0; w < 2; w++) {
            bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
            bvh_tree t, u;
            rf_buf buf;
            const char *diff;
            d.trace_width = w ? 2 : 0;
            tu_build_valid(&s, &d, &t);
            buf = rf_save(&t);
            ld.threads = 2;
            assert_int_equal(rf_load(&u, buf.data, buf.size, ld), BVH_SUCCESS);
            if ((diff = tree_diff(&t, &u)) != NULL)
                fail_msg("%s/%s: loaded tree: %s differs", s.name, bvh_builder_name(d.builder), diff);
            assert_int_equal(u.builder, t.builder);
            bvh_free(&u);
            ld.trace_width = w ? 8 : 2; /* the other layout than saved */
            assert_int_equal(rf_load(&u, buf.data, buf.size, ld), BVH_SUCCESS);
            assert_true((u.nodes8 != NULL) == (w != 0));
            rf_valid(&u, NULL, s.name);
            ld.trace_width = 0;
            bvh_free(&u);
            bvh_free(&t);
            free(buf.data);
        }
    }
    { /* refitted, saved, loaded: the hits of the refitted tree */
        tu_scene moved;
        bvh_tree t, u;
        bvh_refit_desc rd;
        rf_buf buf;
        float *tris;
        bvh_ray *rays = (bvh_ray *)malloc(RF_RAYS * sizeof *rays);
        bvh_hit *want = (bvh_hit *)malloc(RF_RAYS * sizeof *want);
        assert_true(rays && want);
        rf_deform(&s, &moved, 0.6);
        tris = tu_scene_tris(&moved);
        tu_make_rays(tris, moved.tri_count, 0x6c6f6164ULL, rays, RF_RAYS);
        tu_oracle_run(tris, moved.tri_count, rays, RF_RAYS, want);
        tu_build(&s, BVH_BUILDER_PLOC, &t);
        rd = rf_desc(&moved, 2);
        assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
        buf = rf_save(&t);
        assert_int_equal(rf_load(&u, buf.data, buf.size, ld), BVH_SUCCESS);
        assert_null(tree_diff_ex(&t, &u, 1));
        assert_int_equal(rf_compare(&moved, &u, rays, want, RF_RAYS, "loaded after refit"), 0);
        bvh_free(&t);
        bvh_free(&u);
        free(buf.data);
        free(tris);
        free(rays);
        free(want);
        tu_scene_free(&moved);
    }
    tu_scene_free(&s);
}

static void save_load_kinds(void **state) {
    tu_scene s;
    bvh_tree t, u;
    bvh_build_desc d;
    bvh_load_desc ld;
    rf_buf buf;
    bvh_aabb *boxes;
    float *tris;
    uint32_t i;
    (void)state;
    memset(&ld, 0, sizeof ld);
    tu_scene_random(&s, 500, 0x6b696e6473ULL);
    tris = tu_scene_tris(&s);
    boxes = (bvh_aabb *)malloc(s.tri_count * sizeof *boxes);
    assert_non_null(boxes);
    for (i = 0; i < s.tri_count; i++) boxes[i] = tu_tri_box(tris + 9 * (size_t)i);
    /* a box tree: structure checked on load, leaves against the boxes by the caller */
    memset(&d, 0, sizeof d);
    d.builder = BVH_BUILDER_SAH_MIDPOINT;
    d.boxes = boxes;
    d.box_count = s.tri_count;
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    buf = rf_save(&t);
    assert_int_equal(rf_load(&u, buf.data, buf.size, ld), BVH_SUCCESS);
    assert_null(tree_diff(&t, &u));
    assert_null(u.tris);
    rf_valid(&u, boxes, "boxes");
    bvh_free(&t);
    bvh_free(&u);
    free(buf.data);
    /* skip_invalid: excluded primitives stay out */
    tu_vertex(&s, 7)[1] = NAN;
    d = tu_scene_desc(&s, BVH_BUILDER_BOTTOM_UP);
    d.skip_invalid = 1;
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    buf = rf_save(&t);
    assert_int_equal(rf_load(&u, buf.data, buf.size, ld), BVH_SUCCESS);
    assert_null(tree_diff(&t, &u));
    assert_int_equal(u.excluded, 1);
    bvh_free(&t);
    bvh_free(&u);
    free(buf.data);
    /* empty trees: no primitives, and all excluded */
    memset(&d, 0, sizeof d);
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    buf = rf_save(&t);
    assert_int_equal(buf.size, 64);
    assert_int_equal(rf_load(&u, buf.data, buf.size, ld), BVH_SUCCESS);
    assert_int_equal(u.node_count, 0);
    bvh_free(&t);
    bvh_free(&u);
    free(buf.data);
    /* a write callback that fails: BVH_ERROR_IO at every point */
    d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
    d.skip_invalid = 1;
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    for (i = 0; i < 4; i++) {
        rf_buf fb;
        static const long at[] = {0, 63, 64, 1000};
        memset(&fb, 0, sizeof fb);
        fb.fail_after = at[i];
        assert_int_equal(bvh_save(&t, rf_write, &fb), BVH_ERROR_IO);
        free(fb.data);
    }
    assert_int_equal(bvh_save(NULL, rf_write, &buf), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_save(&t, NULL, &buf), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_load(NULL, &ld), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_load(&u, NULL), BVH_ERROR_INVALID_ARGUMENT);
    ld.trace_width = 4;
    assert_int_equal(bvh_load(&u, &ld), BVH_ERROR_INVALID_ARGUMENT);
    bvh_free(&t);
    free(boxes);
    free(tris);
    tu_scene_free(&s);
}

/* Rewrites the header's checksum (or the payload's too) after an edit, so that the edit itself
   is what the loader meets. */
static void rf_reseal(unsigned char *data, int payload) {
    bvh__file_header h;
    memcpy(&h, data, sizeof h);
    if (payload) {
        bvh_tree t;
        memset(&t, 0, sizeof t);
        t.node_count = h.node_count;
        t.ref_count = h.ref_count;
        t.nodes = (bvh_node *)(void *)(data + 64);
        t.prims = (uint32_t *)(void *)(data + 64 + (size_t)h.node_count * sizeof(bvh_node));
        t.tris = (h.flags & BVH__FILE_TRIANGLES) ? (float *)(void *)(t.prims + h.ref_count) : NULL;
        if (h.flags & BVH__FILE_WIDE) { /* the 8-wide nodes: what the payload leaves for them */
            t.nodes8 = (bvh_node8 *)(void *)(t.tris + 9 * (size_t)h.ref_count);
            t.node8_count =
                (uint32_t)((h.payload_bytes - bvh__payload_bytes(h.node_count, h.ref_count, 1, 0)) / sizeof(bvh_node8));
        }
        h.payload_check = bvh__payload_check(&t);
    }
    h.header_check = bvh__header_check(h);
    memcpy(data, &h, sizeof h);
}

/* The leaf cap (BVH__MAX_LEAF references, as no builder exceeds): a hand-made binary-only file,
   a root over two leaves of all 301 triangles, loads with a leaf of 255 and is refused with one of
   256, whose structure is otherwise sound. The ordered check is the only one to find it. */
static void load_leaf_cap(void **state) {
    enum { N = 301 };
    tu_scene s;
    bvh_build_desc d;
    bvh_tree t;
    bvh_load_desc ld;
    bvh__file_header h;
    rf_buf buf;
    uint32_t left;
    (void)state;
    tu_scene_random(&s, N, 0x4c454146ULL);
    d = tu_scene_desc(&s, BVH_BUILDER_BOTTOM_UP);
    d.trace_width = 2;
    tu_build_valid(&s, &d, &t);
    assert_int_equal(t.ref_count, N);
    buf = rf_save(&t);
    memcpy(&h, buf.data, sizeof h);
    memset(&ld, 0, sizeof ld);
    for (left = 255; left <= 256; left++) {
        const size_t tail = (size_t)N * (sizeof(uint32_t) + 9 * sizeof(float)); /* references, triangles */
        const size_t size = 64 + 3 * sizeof(bvh_node) + tail;
        unsigned char *file = (unsigned char *)malloc(size);
        bvh_node nodes[3];
        bvh__file_header g = h;
        bvh_tree u;
        bvh_result r;
        uint32_t k;
        assert_non_null(file);
        for (k = 0; k < 3; k++) { /* every box the root's: each holds its leaves' triangles */
            nodes[k] = t.nodes[0];
            nodes[k].count = 0;
            nodes[k].index = 1;
        }
        nodes[1].index = 0;
        nodes[1].count = left;
        nodes[2].index = left;
        nodes[2].count = N - left;
        g.node_count = 3;
        g.payload_bytes = bvh__payload_bytes(3, N, 1, 0);
        memcpy(file, &g, sizeof g);
        memcpy(file + 64, nodes, sizeof nodes);
        memcpy(file + 64 + sizeof nodes, buf.data + 64 + (size_t)t.node_count * sizeof(bvh_node), tail);
        rf_reseal(file, 1);
        r = rf_load(&u, file, size, ld);
        if (left <= 255) {
            if (r != BVH_SUCCESS) fail_msg("a leaf of %u: %s", left, bvh_result_string(r));
            assert_int_equal(bvh_validate(&u, NULL, NULL), BVH_SUCCESS);
            bvh_free(&u);
        } else if (r != BVH_ERROR_CORRUPT) {
            fail_msg("a leaf of %u: %s", left, bvh_result_string(r));
        }
        free(file);
    }
    free(buf.data);
    bvh_free(&t);
    tu_scene_free(&s);
}

/* A build that left nearly all of its primitives out (skip_invalid): a small file with a large
   primitive count. It loads, the same tree, and load allocates in proportion to the file, not to
   the primitive count (found by fuzz_load: a byte per primitive; tests/fuzz/load/
   regress-excluded-sparse). With the 8-wide layout and without. */
static void load_sparse_primitives(void **state) {
    const uint32_t n = 200000, kept[3] = {0, 99999, 199999};
    float *v = (float *)malloc((size_t)n * 9 * sizeof(float));
    bvh_build_desc d;
    bvh_load_desc ld;
    bvh_tree t, u;
    rf_buf buf;
    rf_alloc a;
    uint32_t i, w;
    (void)state;
    assert_non_null(v);
    for (i = 0; i < n * 9; i++) v[i] = NAN;
    for (i = 0; i < 3; i++) {
        const float z = (float)i, tri[9] = {0, 0, z, 1, 0, z, 0, 1, z};
        memcpy(v + 9 * (size_t)kept[i], tri, sizeof tri);
    }
    for (w = 0; w < 2; w++) {
        memset(&d, 0, sizeof d);
        d.builder = w ? BVH_BUILDER_PLOC : BVH_BUILDER_SAH_MIDPOINT;
        d.triangles.positions = v;
        d.triangles.vertex_count = 3 * n;
        d.triangles.triangle_count = n;
        d.skip_invalid = 1;
        d.trace_width = w ? 8 : 2;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_int_equal(t.excluded, n - 3);
        buf = rf_save(&t);
        memset(&ld, 0, sizeof ld);
        ld.allocator = rf_allocator(&a, -1);
        assert_int_equal(rf_load(&u, buf.data, buf.size, ld), BVH_SUCCESS);
        assert_null(tree_diff(&t, &u));
        if (a.largest > 4 * buf.size + 65536)
            fail_msg("a file of %zu bytes: an allocation of %zu bytes", buf.size, a.largest);
        bvh_free(&u);
        assert_int_equal(a.live, 0);
        bvh_free(&t);
        free(buf.data);
    }
    free(v);
}

/* Damaged and hostile inputs: a code, nothing leaked, no allocation larger than the input. */
static void load_damaged(void **state) {
    tu_scene s;
    bvh_tree t, u;
    bvh_load_desc ld;
    rf_buf buf;
    rf_alloc a;
    unsigned char *copy;
    size_t n, i;
    bvh__file_header h;
    (void)state;
    tu_scene_grid(&s);
    tu_build(&s, BVH_BUILDER_SAH_MIDPOINT, &t);
    buf = rf_save(&t);
    copy = (unsigned char *)malloc(buf.size);
    assert_non_null(copy);
    memset(&ld, 0, sizeof ld);
    ld.allocator = rf_allocator(&a, -1);
    /* truncated: at every length in the header and the first 4 KiB of the payload, then every
       251st and the last 256 (every length of the whole file made this test quadratic: 24 s) */
    print_message("saved grid tree: %zu bytes\n", buf.size);
    for (n = 0; n < buf.size; n += n < 4096 || n + 256 >= buf.size ? 1 : 251) {
        assert_int_equal(rf_load(&u, buf.data, n, ld), BVH_ERROR_TRUNCATED);
        assert_int_equal(a.live, 0);
        if (a.largest > buf.size) fail_msg("truncated at %zu: an allocation of %zu bytes", n, a.largest);
    }
    /* one bit flipped in every byte of the first 4 KiB and the last 256, in every 97th between
       (the bit turns with the byte; the stride is odd, so every array sees every bit) */
    for (i = 0; i < buf.size; i += i < 4096 || i + 256 >= buf.size ? 1 : 97) {
        bvh_result r;
        memcpy(copy, buf.data, buf.size);
        copy[i] ^= (unsigned char)(1u << (i % 8));
        r = rf_load(&u, copy, buf.size, ld);
        if (r != BVH_ERROR_CORRUPT && r != BVH_ERROR_UNSUPPORTED_FORMAT)
            fail_msg("bit %zu of byte %zu flipped: %s", i % 8, i, bvh_result_string(r));
        assert_int_equal(a.live, 0);
    }
    /* another byte order; another version (the header resealed) */
    memcpy(copy, buf.data, buf.size);
    memcpy(&h, copy, sizeof h);
    h.endian = 0x04030201u;
    memcpy(copy, &h, sizeof h);
    assert_int_equal(rf_load(&u, copy, buf.size, ld), BVH_ERROR_UNSUPPORTED_FORMAT);
    for (i = 1; i <= 3; i += 2) { /* version 1 (0.6.0's: no 8-wide nodes) is refused, as a later one */
        memcpy(copy, buf.data, buf.size);
        memcpy(&h, copy, sizeof h);
        h.version = (uint32_t)i;
        memcpy(copy, &h, sizeof h);
        rf_reseal(copy, 0);
        assert_int_equal(rf_load(&u, copy, buf.size, ld), BVH_ERROR_UNSUPPORTED_FORMAT);
    }
    memcpy(copy, "NOT.TREE", 8);
    assert_int_equal(rf_load(&u, copy, buf.size, ld), BVH_ERROR_CORRUPT);
    /* hostile sizes behind a valid header checksum: refused before any allocation */
    {
        static const uint32_t counts[][4] = {/* nodes, refs, prims, excluded */
                                             {0xffffffffu, 0x7fffffffu, 0x40000000u, 0},
                                             {2047u, 1024u, 1024u, 0},
                                             {1u << 31, 1u << 30, 1u << 30, 0},
                                             {3, 2, 2, 3},
                                             {4, 2, 2, 0},
                                             {0, 0, 5, 0},
                                             {1, 0, 0, 0},
                                             {1, 5, 2, 0}};
        for (i = 0; i < sizeof counts / sizeof counts[0]; i++) {
            bvh_result r;
            memcpy(copy, buf.data, buf.size);
            memcpy(&h, copy, sizeof h);
            h.node_count = counts[i][0];
            h.ref_count = counts[i][1];
            h.prim_count = counts[i][2];
            h.excluded = counts[i][3];
            h.payload_bytes = bvh__payload_bytes(h.node_count, h.ref_count, 1, 0);
            memcpy(copy, &h, sizeof h);
            rf_reseal(copy, 0);
            a.largest = 0;
            r = rf_load(&u, copy, buf.size, ld);
            if (r != BVH_ERROR_CORRUPT && r != BVH_ERROR_TRUNCATED)
                fail_msg("hostile counts %zu: %s", i, bvh_result_string(r));
            if (a.largest > buf.size) fail_msg("hostile counts %zu: an allocation of %zu bytes", i, a.largest);
            assert_int_equal(a.live, 0);
        }
        /* a stream declaring more than max_bytes */
        memcpy(copy, buf.data, buf.size);
        ld.max_bytes = buf.size - 65;
        assert_int_equal(rf_load(&u, copy, buf.size, ld), BVH_ERROR_CORRUPT);
        ld.max_bytes = 0;
    }
    /* damaged structures behind valid checksums; the binary tree's damage also with trace_width 2,
       where no 8-wide pass checks the boxes */
    for (i = 0; i < 18; i++) {
        bvh_node *nodes;
        uint32_t *prims;
        float *tris;
        bvh_node8 *wide;
        uint32_t w = 0, k;
        bvh_result r;
        memcpy(copy, buf.data, buf.size);
        memcpy(&h, copy, sizeof h);
        nodes = (bvh_node *)(void *)(copy + 64);
        prims = (uint32_t *)(void *)(nodes + h.node_count);
        tris = (float *)(void *)(prims + h.ref_count);
        wide = (bvh_node8 *)(void *)(tris + 9 * (size_t)h.ref_count);
        assert_true(h.flags & BVH__FILE_WIDE);
        assert_true(t.node8_count > 2);
        for (k = 0; k < 8; k++) /* w: the root's first interior slot */
            if (!wide[0].count[k] && wide[0].child[k]) {
                w = k;
                break;
            }
        switch (i) {
        case 6:
            wide[0].head = 1;
            break; /* the root made from another node */
        case 7:
            wide[1].shape ^= 2u;
            break; /* another grouping */
        case 8:
            wide[1].shape |= 1u << 20;
            break; /* bits past the grouping */
        case 9:
            wide[0].child[w] = 0;
            break; /* a child before its parent */
        case 10:
            wide[t.node8_count - 1].child[0] = 1;
            wide[t.node8_count - 1].count[0] = 0;
            break; /* a second parent, or a leaf slot turned interior */
        case 11:
            wide[0].count[w] = 1;
            break; /* an interior slot turned leaf */
        case 12:
            wide[1].head = wide[2].head;
            break; /* two nodes from one binary node */
        case 13:
            for (k = 0; k < 8 * t.node8_count; k++)
                if (wide[k / 8].count[k % 8]) {
                    wide[k / 8].count[k % 8]++;
                    break;
                }
            break; /* a leaf slot with one packet too many */
        case 14:
            wide[0].order[1] = wide[0].order[0];
            break; /* two slots of the grouping in one place */
        case 15:
            wide[0].order[0] = 8;
            break; /* a slot past the node */
        case 0:
            nodes[0].index = 0;
            break; /* a cycle */
        case 1:
            prims[3] = h.prim_count;
            break; /* a reference out of range */
        case 2:
            tris[5] = NAN;
            break; /* a NaN vertex */
        case 3:
            nodes[1].max.x = nodes[0].max.x + 1.0f;
            break; /* a child outside its parent */
        case 4:
            nodes[0].count = 300;
            nodes[0].index = 0;
            break; /* a leaf too large */
        case 16:
            for (k = 0; k < h.node_count; k++)
                if (!nodes[k].count && nodes[k].index + 1 == h.node_count - 1) {
                    nodes[h.node_count - 1].max.x = nodes[k].max.x + 1.0f;
                    break;
                }
            assert_true(k < h.node_count);
            break; /* the last node (deep, in a leaf slot) outside its parent */
        case 17:
            assert_true(nodes[1].count == 0);
            nodes[nodes[1].index + 1].min.z = nodes[1].min.z - 1.0f;
            break; /* a grandchild of the root (inside the root's grouping) outside its parent */
        default:
            nodes[h.node_count - 1].min.y = NAN;
            break; /* a NaN box */
        }
        rf_reseal(copy, 1);
        r = rf_load(&u, copy, buf.size, ld);
        if (r != BVH_ERROR_CORRUPT) fail_msg("damaged structure %zu: %s", i, bvh_result_string(r));
        assert_int_equal(a.live, 0);
        if (i >= 6 && i < 16) continue;
        ld.trace_width = 2;
        r = rf_load(&u, copy, buf.size, ld);
        ld.trace_width = 0;
        if (r != BVH_ERROR_CORRUPT) fail_msg("damaged structure %zu, trace_width 2: %s", i, bvh_result_string(r));
        assert_int_equal(a.live, 0);
    }
    /* allocation failures at every point */
    {
        long k, total;
        ld.allocator = rf_allocator(&a, -1);
        ld.data = buf.data;
        ld.size = buf.size;
        assert_int_equal(bvh_load(&u, &ld), BVH_SUCCESS);
        bvh_free(&u);
        total = a.calls;
        for (k = 0; k < 2 * total; k++) { /* copying, then borrowing (fewer allocations) */
            bvh_result r;
            ld.borrow = k >= total;
            ld.allocator = rf_allocator(&a, k % total);
            r = bvh_load(&u, &ld);
            if (r != BVH_SUCCESS && r != BVH_ERROR_OUT_OF_MEMORY)
                fail_msg("allocation %ld failed%s: %s", k % total, ld.borrow ? " (borrowed)" : "",
                         bvh_result_string(r));
            bvh_free(&u);
            assert_int_equal(a.live, 0);
        }
    }
    free(copy);
    free(buf.data);
    bvh_free(&t);
    tu_scene_free(&s);
}

/* desc.borrow: the tree reads the caller's buffer where it lies (4-byte aligned is enough), never
   writes it, and leaves it to the caller at bvh_free; only the 8-wide layout and the checks'
   scratch are allocated; bvh_refit refuses such a tree; a stream, a misaligned buffer or another
   value of borrow are refused. Every damaged and truncated file of load_damaged is also loaded
   borrowed (rf_load). */
static void load_borrowed(void **state) {
    tu_scene s;
    bvh_tree t, u, v;
    bvh_load_desc ld;
    bvh_refit_desc rd;
    rf_buf buf, again;
    rf_alloc a, a2;
    unsigned char *copy, *shifted;
    bvh_ray *rays = (bvh_ray *)malloc(RF_RAYS * sizeof *rays);
    bvh_hit *want = (bvh_hit *)malloc(RF_RAYS * sizeof *want);
    float *tris;
    long calls, live;
    int off;
    (void)state;
    assert_true(rays && want);
    tu_scene_grid(&s);
    tu_build(&s, BVH_BUILDER_PLOC_PARALLEL, &t);
    tris = tu_scene_tris(&s);
    tu_make_rays(tris, s.tri_count, 0x626f72726f77ULL, rays, RF_RAYS);
    tu_oracle_run(tris, s.tri_count, rays, RF_RAYS, want);
    buf = rf_save(&t);
    copy = (unsigned char *)malloc(buf.size);
    shifted = (unsigned char *)malloc(buf.size + 16);
    assert_true(copy && shifted);
    memcpy(copy, buf.data, buf.size);
    for (off = 0; off <= 12; off += 4) { /* the arrays at every 4-byte offset of a 16-byte line */
        memcpy(shifted + off, buf.data, buf.size);
        memset(&ld, 0, sizeof ld);
        ld.data = shifted + off;
        ld.size = buf.size;
        ld.borrow = 1;
        ld.allocator = rf_allocator(&a, -1);
        assert_int_equal(bvh_load(&u, &ld), BVH_SUCCESS);
        calls = a.calls;
        live = a.live;
        assert_int_equal(u.borrowed, 1);
        assert_ptr_equal(u.nodes, shifted + off + 64);
        assert_null(tree_diff(&t, &u));
        rf_valid(&u, NULL, "borrowed");
        assert_int_equal(rf_compare(&s, &u, rays, want, RF_RAYS, "borrowed"), 0);
        /* a copying load allocates the three arrays more, and holds them */
        ld.borrow = 0;
        ld.allocator = rf_allocator(&a2, -1);
        assert_int_equal(bvh_load(&v, &ld), BVH_SUCCESS);
        assert_int_equal(v.borrowed, 0);
        assert_int_equal(a2.calls, calls + 3);
        assert_int_equal(a2.live, live + 3);
        bvh_free(&v);
        assert_int_equal(a2.live, 0);
        /* saved again: the same bytes */
        again = rf_save(&u);
        assert_int_equal(again.size, buf.size);
        assert_memory_equal(again.data, buf.data, buf.size);
        free(again.data);
        /* refit refused, the tree as it was */
        rd = rf_desc(&s, 2);
        assert_int_equal(bvh_refit(&u, &rd), BVH_ERROR_INVALID_ARGUMENT);
        assert_null(tree_diff(&t, &u));
        bvh_free(&u);
        assert_int_equal(a.live, 0);
        assert_memory_equal(shifted + off, copy, buf.size); /* never written */
    }
    /* refused: a misaligned buffer, a stream, borrow 2; the tree zeroed, nothing allocated */
    memset(&ld, 0, sizeof ld);
    ld.allocator = rf_allocator(&a, -1);
    memcpy(shifted + 1, buf.data, buf.size);
    ld.data = shifted + 1;
    ld.size = buf.size;
    ld.borrow = 1;
    assert_int_equal(bvh_load(&u, &ld), BVH_ERROR_INVALID_ARGUMENT);
    assert_null(u.nodes);
    ld.data = buf.data;
    ld.borrow = 2;
    assert_int_equal(bvh_load(&u, &ld), BVH_ERROR_INVALID_ARGUMENT);
    {
        rf_buf b = buf;
        b.pos = 0;
        ld.borrow = 1;
        ld.data = NULL;
        ld.size = 0;
        ld.read = rf_read;
        ld.user = &b;
        assert_int_equal(bvh_load(&u, &ld), BVH_ERROR_INVALID_ARGUMENT);
        assert_null(u.nodes);
    }
    assert_int_equal(a.calls, 0);
    free(copy);
    free(shifted);
    free(buf.data);
    free(tris);
    free(rays);
    free(want);
    bvh_free(&t);
    tu_scene_free(&s);
}

/* A tree as 0.9.3 and before made it: every wide node's slots in ascending binary index order and
   bvh_node8.order all zero (the order the build now writes is undone here, slot by slot). Such a
   tree, in memory or saved, must stay valid, trace the brute force's hits, refit and load. */
static void legacy_slot_order(void **state) {
    int id = tu_state_id(state), b;
    tu_scene s;
    float *tris;
    bvh_ray *rays = (bvh_ray *)malloc((RF_RAYS + 2 * RF_CAMERA * RF_CAMERA) * sizeof *rays);
    bvh_hit *want = (bvh_hit *)malloc((RF_RAYS + 2 * RF_CAMERA * RF_CAMERA) * sizeof *want);
    size_t count, bad = 0;
    assert_true(rays && want);
    if (!tu_scene_make(id, &s)) {
        free(rays);
        free(want);
        skip();
        return;
    }
    tris = tu_scene_tris(&s);
    tu_make_rays(tris, s.tri_count, 0x6f72646572ULL + (uint64_t)id, rays, RF_RAYS);
    count = RF_RAYS + rf_camera_diffuse(tris, s.tri_count, 0x6f7264ULL + (uint64_t)id, rays + RF_RAYS);
    tu_oracle_run(tris, s.tri_count, rays, count, want);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
        bvh_refit_desc rd = rf_desc(&s, 2);
        bvh_load_desc ld;
        bvh_tree t, u;
        rf_buf buf;
        uint32_t w, j, a, moved = 0;
        tu_build_valid(&s, &d, &t);
        for (w = 0; w < t.node8_count; w++) {
            bvh_node8 *n = &t.nodes8[w], old = *n;
            for (j = 0; j < 8 && (old.count[j] || old.min[0][j] != BVH_INF); j++) {
                const uint32_t k = old.order[j]; /* the j-th slot by binary index */
                for (a = 0; a < 3; a++) {
                    n->min[a][j] = old.min[a][k];
                    n->max[a][j] = old.max[a][k];
                }
                n->child[j] = old.child[k];
                n->count[j] = old.count[k];
                moved += k != j;
            }
            memset(n->order, 0, sizeof n->order);
        }
        if (s.tri_count > 100) assert_true(moved > 0); /* the build's order is not the index order */
        rf_valid(&t, NULL, "legacy order");
        bad += rf_compare(&s, &t, rays, want, count, "legacy order");
        assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
        rf_valid(&t, NULL, "legacy order, refitted");
        bad += rf_compare(&s, &t, rays, want, count, "legacy order, refitted");
        buf = rf_save(&t);
        memset(&ld, 0, sizeof ld);
        assert_int_equal(rf_load(&u, buf.data, buf.size, ld), BVH_SUCCESS);
        bad += rf_compare(&s, &u, rays, want, count, "legacy order, loaded");
        bvh_free(&u);
        free(buf.data);
        bvh_free(&t);
    }
    if (bad) fail_msg("%zu rays differ", bad);
    free(tris);
    free(rays);
    free(want);
    tu_scene_free(&s);
}

/* The finite check that refits and loads run over whole arrays (bvh__any_nonfinite: SSE2 16
   floats a step, AVX2 32 where the CPU has it, then one at a time): a NaN or an Inf of either
   sign at every place of arrays of 1 to 160 floats, at 4 byte offsets, is found; the largest
   finite floats, zeros of both signs and denormals are not. */
static void nonfinite_every_place(void **state) {
    static const float bad[4] = {NAN, -NAN, INFINITY, -INFINITY};
    static const float good[5] = {FLT_MAX, -FLT_MAX, 0.0f, -0.0f, 1e-45f};
    float buf[168];
    uint32_t n, at, off, k;
    (void)state;
    for (off = 0; off < 4; off++)
        for (n = 1; n <= 160; n++) {
            float *a = buf + off;
            for (k = 0; k < n; k++) a[k] = good[(k + n) % 5];
            assert_int_equal(bvh__any_nonfinite(a, n), 0);
            for (at = 0; at < n; at++) {
                const float keep = a[at];
                a[at] = bad[(at + off) % 4];
                if (!bvh__any_nonfinite(a, n))
                    fail_msg("%g at %u of %u floats (offset %u) not found", a[at], at, n, off);
                a[at] = keep;
            }
        }
}

int main(void) {
    const struct CMUnitTest tests[] = {
        TU_SCENE_TEST(refit_exact, TU_SCENE_RANDOM, "random"),
        TU_SCENE_TEST(refit_exact, TU_SCENE_GRID, "grid"),
        TU_SCENE_TEST(refit_exact, TU_SCENE_HUGE, "huge"),
        TU_SCENE_TEST(refit_exact, TU_SCENE_ONE, "1-triangle"),
        TU_SCENE_TEST(refit_exact, TU_SCENE_THREE, "3-triangles"),
        TU_SCENE_TEST(refit_exact, TU_SCENE_STRIDED32, "indexed-stride-32"),
        TU_SCENE_TEST(refit_exact, TU_SCENE_STRIDED16, "soup-stride-16"),
        TU_SCENE_TEST(refit_exact, TU_SCENE_DUPLICATES, "duplicates"),
        TU_SCENE_TEST(refit_exact, TU_SCENE_CHAIN, "chain"),
        TU_SCENE_TEST(refit_exact, TU_SCENE_BUNNY, "bunny"),
        cmocka_unit_test(refit_boxes),
        cmocka_unit_test(refit_errors),
        cmocka_unit_test(nonfinite_every_place),
        TU_SCENE_TEST(save_load_round_trip, TU_SCENE_RANDOM, "random"),
        TU_SCENE_TEST(save_load_round_trip, TU_SCENE_GRID, "grid"),
        TU_SCENE_TEST(save_load_round_trip, TU_SCENE_DUPLICATES, "duplicates"),
        TU_SCENE_TEST(save_load_round_trip, TU_SCENE_BUNNY, "bunny"),
        cmocka_unit_test(save_load_kinds),
        cmocka_unit_test(load_damaged),
        cmocka_unit_test(load_leaf_cap),
        cmocka_unit_test(load_sparse_primitives),
        cmocka_unit_test(load_borrowed),
        TU_SCENE_TEST(legacy_slot_order, TU_SCENE_RANDOM, "random"),
        TU_SCENE_TEST(legacy_slot_order, TU_SCENE_BUNNY, "bunny"),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
