/* tests/test_robust.c - hostile input and faults (cmocka).

   Every builder (BVH_BUILDER_TOP_DOWN .. BVH_BUILDER_PLOC_PARALLEL) and the traversal against:
   empty, tiny and duplicated input; 100,000 copies of one triangle; degenerate triangles; NaN and
   Inf vertices (refused, or skipped and counted); far-from-origin, huge-and-tiny, planar and
   axis-aligned scenes hit by axis-parallel rays; out-of-range indices, strides, counts and
   options; an allocator that fails the k-th allocation for every k; hostile rays; hand-made trees
   deeper than BVH_MAX_DEPTH; inputs that make PLOC chain. Hits are compared exactly with a
   brute-force loop over bvh_intersect_triangle (lowest index wins at equal t); ray mismatches
   are counted per test and reported with the builders affected.

   Builds that might hang run in a forked child with an alarm (rb_watchdog), so that a hang fails
   its test in bounded time. The tests named test_threads_* are the ones `make tsan` runs
   (ROBUST_FILTER='test_threads_*', a cmocka test filter): the parallel builder with 2..8 threads
   must give PLOC's tree, and batch tracing the single-ray results. test_huge_coordinates runs
   last because a UBSan report under `make asan` ends the program.
   Self-contained (does not use tests/test_util.h). Built with -std=c11 -Wall -Wextra -Wpedantic
   -Werror and -D_GNU_SOURCE by the Makefile; `make asan` and `make tsan` (mk/robust.mk) rebuild it
   under the sanitizers. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <float.h>
#include <math.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <pthread.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include "fp_bits.h"
#include "tree_diff.h"

#define RB_FIRST ((bvh_builder)1) /* the builder table's rows after BVH_BUILDER_DEFAULT */
#define RB_LAST ((bvh_builder)(BVH_BUILDER_COUNT - 1))
#define RB_FOR_EACH_BUILDER(b) for ((b) = RB_FIRST; (b) <= RB_LAST; (b) = (bvh_builder)((int)(b) + 1))

/* == tracked memory ==========================================================================
   Scenes, buffers and the trees built through rb_desc() live in tracked blocks, which each
   test's teardown releases: a test that fails half-way (cmocka longjmps out of it) leaks nothing, so
   that a LeakSanitizer report under `make asan` always means bvh.h leaked. */
static pthread_mutex_t rb_mutex = PTHREAD_MUTEX_INITIALIZER;
static void **rb_blocks;
static size_t rb_nblocks, rb_capblocks;
static void *rb_track_alloc(size_t size, void *user) {
    void *p = malloc(size ? size : 1);
    (void)user;
    if (!p) return NULL;
    pthread_mutex_lock(&rb_mutex);
    if (rb_nblocks == rb_capblocks) {
        size_t cap = rb_capblocks ? 2 * rb_capblocks : 256;
        void **b = (void **)realloc(rb_blocks, cap * sizeof(void *));
        if (!b) {
            pthread_mutex_unlock(&rb_mutex);
            free(p);
            return NULL;
        }
        rb_blocks = b;
        rb_capblocks = cap;
    }
    rb_blocks[rb_nblocks++] = p;
    pthread_mutex_unlock(&rb_mutex);
    return p;
}
static void rb_track_free(void *p, void *user) {
    size_t i;
    (void)user;
    if (!p) return;
    pthread_mutex_lock(&rb_mutex);
    for (i = rb_nblocks; i-- > 0;)
        if (rb_blocks[i] == p) {
            rb_blocks[i] = rb_blocks[--rb_nblocks];
            break;
        }
    pthread_mutex_unlock(&rb_mutex);
    free(p);
}
static void *rb_xcalloc(size_t n, size_t size) {
    void *p = rb_track_alloc(n * size, NULL);
    assert_non_null(p);
    memset(p, 0, n * size != 0 ? n * size : 1);
    return p;
}
static void rb_xfree(void *p) { rb_track_free(p, NULL); }
static void rb_reset_mismatches(void);
static int rb_teardown(void **state) {
    (void)state;
    rb_reset_mismatches();
    while (rb_nblocks) free(rb_blocks[--rb_nblocks]);
    return 0;
}
static int rb_group_teardown(void **state) {
    rb_teardown(state);
    free(rb_blocks);
    rb_blocks = NULL;
    rb_capblocks = 0;
    return 0;
}

/* == deterministic RNG (xorshift64*) ========================================================= */
typedef struct rb_rng {
    uint64_t s;
} rb_rng;
static uint32_t rb_u32(rb_rng *r) {
    r->s ^= r->s >> 12;
    r->s ^= r->s << 25;
    r->s ^= r->s >> 27;
    return (uint32_t)((r->s * 0x2545F4914F6CDD1DULL) >> 32);
}
static rb_rng rb_rng_make(uint64_t seed) {
    rb_rng r;
    r.s = seed * 0x9E3779B97F4A7C15ULL + 1;
    rb_u32(&r);
    return r;
}
static float rb_unit(rb_rng *r) { return (float)(rb_u32(r) >> 8) * (1.0f / 16777216.0f); }
static float rb_range(rb_rng *r, float lo, float hi) { return lo + (hi - lo) * rb_unit(r); }
static uint32_t rb_below(rb_rng *r, uint32_t n) { return (uint32_t)(((uint64_t)rb_u32(r) * n) >> 32); }

/* == scenes ================================================================================== */
/* Vertices (pos, nv) and optional indices as given to bvh_build; tris = the triangles expanded
   to 9 floats each for the brute force. */
typedef struct rb_scene {
    float *pos;
    uint32_t nv;
    uint32_t *idx;
    uint32_t nt;
    float *tris;
} rb_scene;

static void rb_scene_soup(rb_scene *s, uint32_t nt) {
    memset(s, 0, sizeof *s);
    s->nt = nt;
    s->nv = 3 * nt;
    s->pos = (float *)rb_xcalloc(9 * (size_t)(nt ? nt : 1), sizeof(float));
}
/* Fills s->tris from pos/idx: call after the vertices are final. */
static void rb_scene_expand(rb_scene *s) {
    uint32_t i, k;
    rb_xfree(s->tris);
    s->tris = (float *)rb_xcalloc(9 * (size_t)(s->nt ? s->nt : 1), sizeof(float));
    for (i = 0; i < s->nt; i++)
        for (k = 0; k < 3; k++) {
            uint32_t v = s->idx ? s->idx[3 * i + k] : 3 * i + k;
            memcpy(s->tris + 9 * (size_t)i + 3 * k, s->pos + 3 * (size_t)v, 3 * sizeof(float));
        }
}
static void rb_scene_free(rb_scene *s) {
    rb_xfree(s->pos);
    rb_xfree(s->idx);
    rb_xfree(s->tris);
    memset(s, 0, sizeof *s);
}
static void rb_set_tri(float *p, float ax, float ay, float az, float bx, float by, float bz, float cx, float cy,
                       float cz) {
    p[0] = ax;
    p[1] = ay;
    p[2] = az;
    p[3] = bx;
    p[4] = by;
    p[5] = bz;
    p[6] = cx;
    p[7] = cy;
    p[8] = cz;
}
/* n random triangles of edge up to `size` with centres in [lo, hi]^3. */
static void rb_scene_random(rb_scene *s, uint32_t n, float lo, float hi, float size, uint64_t seed) {
    rb_rng r = rb_rng_make(seed);
    uint32_t i, k;
    rb_scene_soup(s, n);
    for (i = 0; i < n; i++) {
        float c[3];
        c[0] = rb_range(&r, lo, hi);
        c[1] = rb_range(&r, lo, hi);
        c[2] = rb_range(&r, lo, hi);
        for (k = 0; k < 9; k++) s->pos[9 * i + k] = c[k % 3] + rb_range(&r, -0.5f, 0.5f) * size;
    }
    rb_scene_expand(s);
}
static int rb_finite9(const float *t) {
    int k;
    for (k = 0; k < 9; k++)
        if (!fp_finite(t[k])) return 0;
    return 1;
}
static bvh_build_desc rb_desc(const rb_scene *s, bvh_builder b) {
    bvh_build_desc d;
    memset(&d, 0, sizeof d);
    d.builder = b;
    d.threads = 3;
    d.triangles.positions = s->pos;
    d.triangles.vertex_count = s->nv;
    d.triangles.indices = s->idx;
    d.triangles.triangle_count = s->nt;
    d.allocator.alloc = rb_track_alloc; /* released by the teardown if the test fails */
    d.allocator.free = rb_track_free;
    return d;
}

/* == checks ================================================================================== */
/* The tree is valid, no deeper than BVH_MAX_DEPTH, and accounts for every primitive. */
static void rb_check_tree(const bvh_tree *t, uint32_t prims, uint32_t excluded, const char *what) {
    bvh_validation rep;
    bvh_stats st;
    bvh_builder_info info;
    bvh_result r = bvh_validate(t, NULL, &rep);
    if (r != BVH_SUCCESS)
        fail_msg("%s (%s): bvh_validate: %s: %s (node %u)", what, bvh_builder_name(t->builder), bvh_result_string(r),
                 rep.message, rep.node);
    assert_int_equal(bvh_get_stats(t, &st), BVH_SUCCESS);
    if (st.max_depth > BVH_MAX_DEPTH) fail_msg("%s: depth %u > BVH_MAX_DEPTH", what, st.max_depth);
    assert_int_equal(t->prim_count, prims);
    assert_int_equal(t->excluded, excluded);
    assert_int_equal(bvh_builder_get_info(t->builder, &info), BVH_SUCCESS);
    if (!info.splits_references)
        assert_int_equal(t->ref_count, prims - excluded);
    else
        assert_true(t->ref_count >= prims - excluded && t->ref_count <= 2 * (prims - excluded)); /* budget <= 1 */
}
/* bvh_sah is finite and non-negative for any tree over finite input. */
static void rb_check_sah(const bvh_tree *t, const char *what) {
    double sah = -1.0;
    bvh_costs k = {1.0f, 0.5f, 2.0f};
    assert_int_equal(bvh_sah(t, NULL, &sah), BVH_SUCCESS);
    if (!fp_finite(sah) || sah < 0.0) fail_msg("%s (%s): SAH %g", what, bvh_builder_name(t->builder), sah);
    assert_int_equal(bvh_sah(t, &k, &sah), BVH_SUCCESS);
    if (!fp_finite(sah) || sah < 0.0)
        fail_msg("%s (%s): SAH %g with costs (1, 0.5, 2)", what, bvh_builder_name(t->builder), sah);
}

/* Closest hit over every finite triangle of the scene, lowest index first at equal t. */
static int rb_brute(const rb_scene *s, const bvh_ray *ray, bvh_hit *best) {
    uint32_t i;
    bvh_hit h;
    best->prim = BVH_INVALID;
    best->t = ray->tmax;
    best->u = best->v = 0.0f;
    for (i = 0; i < s->nt; i++) {
        const float *p = s->tris + 9 * (size_t)i;
        if (!rb_finite9(p) || !bvh_intersect_triangle(ray, p, p + 3, p + 6, &h)) continue;
        if (best->prim == BVH_INVALID || h.t < best->t) {
            *best = h;
            best->prim = i;
        }
    }
    return best->prim != BVH_INVALID;
}

/* Ray mismatches are counted (and the first few of each test printed) rather than failing at
   once, so that a failing test tells which builders and how many rays are affected;
   rb_expect_no_mismatch() fails the test at the end of a part if any was found. */
static uint32_t rb_mismatches, rb_printed;
static const char *rb_mismatch_builders[BVH_BUILDER_COUNT];
static void rb_fail_ray(const char *what, const bvh_tree *t, const bvh_ray *ray, const char *call, int got,
                        const bvh_hit *h, const bvh_hit *want) {
    rb_mismatches++;
    if ((unsigned)t->builder < BVH_BUILDER_COUNT) rb_mismatch_builders[t->builder] = bvh_builder_name(t->builder);
    if (rb_printed++ >= 4) return;
    print_error("%s (%s) %s: ray o=(%a %a %a) d=(%a %a %a) t=[%a %a]: tree %d prim %u t=%a u=%a v=%a, brute force "
                "prim %u t=%a u=%a v=%a",
                what, bvh_builder_name(t->builder), call, (double)ray->origin.x, (double)ray->origin.y,
                (double)ray->origin.z, (double)ray->dir.x, (double)ray->dir.y, (double)ray->dir.z, (double)ray->tmin,
                (double)ray->tmax, got, h->prim, (double)h->t, (double)h->u, (double)h->v, want->prim, (double)want->t,
                (double)want->u, (double)want->v);
    print_error("\n");
}
static void rb_reset_mismatches(void) {
    memset(rb_mismatch_builders, 0, sizeof rb_mismatch_builders);
    rb_mismatches = rb_printed = 0;
}
static void rb_expect_no_mismatch(const char *what, uint32_t rays) {
    char list[160] = "";
    int b;
    uint32_t n = rb_mismatches;
    for (b = 0; b < BVH_BUILDER_COUNT; b++)
        if (rb_mismatch_builders[b]) {
            strncat(list, " ", sizeof list - strlen(list) - 1);
            strncat(list, rb_mismatch_builders[b], sizeof list - strlen(list) - 1);
            rb_mismatch_builders[b] = NULL;
        }
    rb_mismatches = rb_printed = 0;
    if (n) fail_msg("%s: %u of %u ray checks differ from the brute force (builders:%s)", what, n, rays, list);
}

/* bvh_intersect, bvh_intersect_counted and bvh_occluded give exactly the brute-force answer
   (counted in rb_mismatches). */
static void rb_check_ray(const char *what, const bvh_tree *t, const rb_scene *s, const bvh_ray *ray) {
    bvh_hit want, h;
    int w = rb_brute(s, ray, &want), got;
    uint32_t visited = 0;
    got = bvh_intersect(t, ray, &h);
    if (got != w || h.prim != want.prim || (w && (h.t != want.t || h.u != want.u || h.v != want.v))) {
        rb_fail_ray(what, t, ray, "bvh_intersect", got, &h, &want);
        return;
    }
    got = bvh_intersect_counted(t, ray, &h, &visited);
    if (got != w || h.prim != want.prim || (w && h.t != want.t)) {
        rb_fail_ray(what, t, ray, "bvh_intersect_counted", got, &h, &want);
        return;
    }
    got = bvh_occluded(t, ray);
    if (got != w) rb_fail_ray(what, t, ray, "bvh_occluded", got, &h, &want);
}

/* == rays ==================================================================================== */
static bvh_vec3 rb_v3(float x, float y, float z) {
    bvh_vec3 v;
    v.x = x;
    v.y = y;
    v.z = z;
    return v;
}
static bvh_ray rb_ray(bvh_vec3 o, bvh_vec3 d, float tmin, float tmax) {
    bvh_ray r;
    r.origin = o;
    r.dir = d;
    r.tmin = tmin;
    r.tmax = tmax;
    return r;
}
static bvh_aabb rb_bounds(const rb_scene *s) {
    bvh_aabb b = bvh_aabb_empty();
    uint32_t i, k;
    for (i = 0; i < s->nt; i++)
        if (rb_finite9(s->tris + 9 * (size_t)i))
            for (k = 0; k < 3; k++)
                bvh_aabb_grow(&b,
                              rb_v3(s->tris[9 * i + 3 * k], s->tris[9 * i + 3 * k + 1], s->tris[9 * i + 3 * k + 2]));
    if (b.min.x > b.max.x) {
        b.min = rb_v3(-1, -1, -1);
        b.max = rb_v3(1, 1, 1);
    }
    return b;
}
static float rb_coord(rb_rng *r, const bvh_aabb *b, int a) {
    float lo = a == 0 ? b->min.x : a == 1 ? b->min.y : b->min.z, hi = a == 0 ? b->max.x : a == 1 ? b->max.y : b->max.z;
    float m = 0.25f * (hi - lo) + 1e-3f * (fabsf(lo) + fabsf(hi)) + 1e-6f;
    return rb_range(r, lo - m, hi + m);
}
/* A vertex coordinate of a random finite triangle (origins exactly on box planes). */
static int rb_vertex(rb_rng *r, const rb_scene *s, float out[3]) {
    uint32_t tries;
    for (tries = 0; tries < 64 && s->nt; tries++) {
        const float *p = s->tris + 9 * (size_t)rb_below(r, s->nt);
        if (!rb_finite9(p)) continue;
        memcpy(out, p + 3 * rb_below(r, 3), 3 * sizeof(float));
        return 1;
    }
    return 0;
}
/* Ray kind k of 6: random; aimed at a point inside a triangle; through a vertex; axis-parallel
   with +0/-0 components from a vertex coordinate; axis-parallel from a random origin snapped to
   vertex planes; short (finite tmax). */
static bvh_ray rb_gen_ray(rb_rng *r, const rb_scene *s, const bvh_aabb *b, int kind) {
    float o[3], d[3], v[3];
    int a;
    for (a = 0; a < 3; a++) {
        o[a] = rb_coord(r, b, a);
        d[a] = rb_range(r, -1, 1);
    }
    if ((kind == 1 || kind == 2 || kind == 5) && rb_vertex(r, s, v)) {
        if (kind != 2) { /* a point inside some triangle */
            const float *p = s->tris + 9 * (size_t)rb_below(r, s->nt);
            float u = rb_unit(r), w = rb_unit(r) * (1 - u);
            if (rb_finite9(p))
                for (a = 0; a < 3; a++) v[a] = p[a] + u * (p[3 + a] - p[a]) + w * (p[6 + a] - p[a]);
        }
        for (a = 0; a < 3; a++) d[a] = v[a] - o[a];
    } else if (kind == 3 || kind == 4) {
        int axis = (int)rb_below(r, 3);
        if (rb_vertex(r, s, v))
            for (a = 0; a < 3; a++)
                if (kind == 3 || rb_below(r, 2)) o[a] = v[a];
        for (a = 0; a < 3; a++) d[a] = rb_below(r, 2) ? 0.0f : -0.0f;
        d[axis] = rb_below(r, 2) ? 1.0f : -1.0f;
        if (kind == 3) o[axis] = rb_coord(r, b, axis); /* then the ray runs along vertex planes */
    }
    if (d[0] == 0.0f && d[1] == 0.0f && d[2] == 0.0f) d[2] = 1.0f;
    return rb_ray(rb_v3(o[0], o[1], o[2]), rb_v3(d[0], d[1], d[2]), 0.0f, kind == 5 ? rb_unit(r) : BVH_INF);
}
static void rb_check_rays(const char *what, const bvh_tree *t, const rb_scene *s, uint32_t count, uint64_t seed) {
    rb_rng r = rb_rng_make(seed);
    bvh_aabb b = rb_bounds(s);
    uint32_t i;
    for (i = 0; i < count; i++) {
        bvh_ray ray = rb_gen_ray(&r, s, &b, (int)(i % 6));
        rb_check_ray(what, t, s, &ray);
    }
}

/* Builds the scene with every builder and checks the tree and `rays` rays; ray mismatches and
   SAH values are reported after every builder has run. */
static void rb_every_builder(const char *what, const rb_scene *s, uint32_t rays, int skip_invalid, uint32_t excluded) {
    bvh_builder b;
    bvh_tree kept[BVH_BUILDER_COUNT];
    memset(kept, 0, sizeof kept);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(s, b);
        bvh_tree t;
        bvh_result r;
        d.skip_invalid = skip_invalid;
        r = bvh_build(&t, &d);
        if (r != BVH_SUCCESS) fail_msg("%s (%s): bvh_build: %s", what, bvh_builder_name(b), bvh_result_string(r));
        assert_int_equal(t.builder, b);
        rb_check_tree(&t, s->nt, excluded, what);
        rb_check_rays(what, &t, s, rays, 0x5EED0000ULL + (uint64_t)b);
        kept[b] = t;
    }
    rb_expect_no_mismatch(what, 5 * rays);
    RB_FOR_EACH_BUILDER(b) rb_check_sah(&kept[b], what);
    RB_FOR_EACH_BUILDER(b) {
        bvh_free(&kept[b]);
        assert_null(kept[b].nodes);
    }
}

/* Runs fn(arg) in a child process that is killed after `seconds`: a hang fails the test in
   bounded time. fn returns 0 on success, else a code printed in the failure. */
static void rb_watchdog(const char *what, unsigned seconds, int (*fn)(void *), void *arg) {
    pid_t pid;
    int status = 0;
    fflush(stdout);
    fflush(stderr);
    pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        alarm(seconds);
        _exit(fn(arg));
    }
    assert_int_equal(waitpid(pid, &status, 0), pid);
    if (WIFSIGNALED(status))
        fail_msg("%s: killed by signal %d%s", what, WTERMSIG(status),
                 WTERMSIG(status) == SIGALRM ? " (time limit exceeded)" : "");
    if (WEXITSTATUS(status) != 0) fail_msg("%s: check %d failed", what, WEXITSTATUS(status));
}

/* == empty, tiny and duplicated input ======================================================== */
static void test_empty(void **state) {
    bvh_builder b;
    (void)state;
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d;
        bvh_tree t;
        bvh_hit h;
        bvh_ray ray = rb_ray(rb_v3(0, 0, -1), rb_v3(0, 0, 1), 0, BVH_INF);
        bvh_stats st;
        double sah = -1;
        memset(&d, 0, sizeof d);
        d.builder = b; /* no triangles, positions NULL */
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_int_equal(t.node_count, 0);
        assert_int_equal(bvh_validate(&t, NULL, NULL), BVH_SUCCESS);
        assert_int_equal(bvh_get_stats(&t, &st), BVH_SUCCESS);
        assert_int_equal(bvh_sah(&t, NULL, &sah), BVH_SUCCESS);
        assert_true(sah == 0.0);
        assert_int_equal(bvh_intersect(&t, &ray, &h), 0);
        assert_int_equal(h.prim, BVH_INVALID);
        assert_int_equal(bvh_occluded(&t, &ray), 0);
        assert_int_equal(bvh_intersect_batch(&t, &ray, &h, 1, 2), BVH_SUCCESS);
        assert_int_equal(h.prim, BVH_INVALID);
        bvh_free(&t);
        bvh_free(&t); /* twice is harmless */
    }
}

static void test_one_triangle(void **state) {
    rb_scene s;
    (void)state;
    rb_scene_soup(&s, 1);
    rb_set_tri(s.pos, 0, 0, 0, 1, 0, 0, 0, 1, 0);
    rb_scene_expand(&s);
    rb_every_builder("one triangle", &s, 600, 0, 0);
    rb_scene_free(&s);
}

static void test_two_identical(void **state) {
    rb_scene s;
    bvh_builder b;
    (void)state;
    rb_scene_soup(&s, 2);
    rb_set_tri(s.pos, 0, 0, 0, 1, 0, 0, 0, 1, 0);
    memcpy(s.pos + 9, s.pos, 9 * sizeof(float));
    rb_scene_expand(&s);
    rb_every_builder("two identical triangles", &s, 600, 0, 0);
    RB_FOR_EACH_BUILDER(b) { /* the tie goes to triangle 0, from either side */
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        bvh_hit h;
        bvh_ray up = rb_ray(rb_v3(0.25f, 0.25f, -1), rb_v3(0, 0, 1), 0, BVH_INF);
        bvh_ray down = rb_ray(rb_v3(0.25f, 0.25f, 1), rb_v3(0, 0, -1), 0, BVH_INF);
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_int_equal(bvh_intersect(&t, &up, &h), 1);
        assert_int_equal(h.prim, 0);
        assert_true(h.t == 1.0f);
        assert_int_equal(bvh_intersect(&t, &down, &h), 1);
        assert_int_equal(h.prim, 0);
        bvh_free(&t);
    }
    rb_scene_free(&s);
}

/* 100,000 copies of one triangle: every centroid and Morton code equal. */
typedef struct rb_copies {
    const rb_scene *s;
    bvh_builder b;
} rb_copies;
static int rb_copies_child(void *arg) {
    const rb_copies *c = (const rb_copies *)arg;
    bvh_build_desc d = rb_desc(c->s, c->b);
    bvh_tree t;
    bvh_stats st;
    bvh_hit h;
    bvh_ray ray = rb_ray(rb_v3(0.5f, 0.45f, 5), rb_v3(0, 0, -1), 0, BVH_INF);
    if (!bvh_intersect_triangle(&ray, c->s->pos, c->s->pos + 3, c->s->pos + 6, &h)) return 7;
    if (bvh_build(&t, &d) != BVH_SUCCESS) return 1;
    if (bvh_validate(&t, NULL, NULL) != BVH_SUCCESS) return 2;
    if (bvh_get_stats(&t, &st) != BVH_SUCCESS || st.max_depth > BVH_MAX_DEPTH) return 3;
    if (c->b == BVH_BUILDER_SAH_MIDPOINT ? t.ref_count < c->s->nt || t.ref_count > c->s->nt + c->s->nt / 10 * 3
                                         : t.ref_count != c->s->nt)
        return 4; /* sah-midpoint may split references, within the default budget of 0.3 n */
    if (!bvh_intersect(&t, &ray, &h) || h.prim != 0) return 5; /* all at the same t: index 0 */
    if (!bvh_occluded(&t, &ray)) return 6;
    bvh_free(&t);
    return 0;
}
static void test_100k_copies(void **state) {
    rb_scene s;
    bvh_builder b;
    uint32_t i;
    (void)state;
    rb_scene_soup(&s, 100000);
    for (i = 0; i < s.nt; i++) rb_set_tri(s.pos + 9 * (size_t)i, 0.1f, 0.2f, 0.3f, 1.1f, 0.25f, 0.3f, 0.4f, 0.9f, 0.7f);
    RB_FOR_EACH_BUILDER(b) {
        rb_copies c;
        char what[64];
        c.s = &s;
        c.b = b;
        snprintf(what, sizeof what, "100,000 copies, %s", bvh_builder_name(b));
        rb_watchdog(what, 20, rb_copies_child, &c);
    }
    rb_scene_free(&s);
}

/* Points, exactly collinear vertices (integer coordinates) and repeated vertices: a valid tree
   that no ray hits. */
static void test_degenerate_only(void **state) {
    rb_scene s;
    rb_rng r = rb_rng_make(7);
    uint32_t i, k;
    (void)state;
    rb_scene_soup(&s, 600);
    for (i = 0; i < s.nt; i++) {
        float *p = s.pos + 9 * (size_t)i, o[3], d[3];
        for (k = 0; k < 3; k++) {
            o[k] = (float)((int)rb_below(&r, 21) - 10);
            d[k] = (float)((int)rb_below(&r, 7) - 3);
        }
        if (i % 5 == 4) d[rb_below(&r, 3)] = 0.0f, d[rb_below(&r, 3)] = 0.0f; /* often axis-parallel */
        for (k = 0; k < 3; k++) {
            float f1 = i % 3 == 0 ? 0.0f : 1.0f, f2 = i % 3 == 0 ? 0.0f : i % 3 == 1 ? 2.0f : 1.0f;
            p[k] = o[k];
            p[3 + k] = o[k] + f1 * d[k];
            p[6 + k] = o[k] + f2 * d[k]; /* point, line, repeated */
        }
    }
    rb_scene_expand(&s);
    { /* the brute force (bvh_intersect_triangle) hits nothing: counted, reported at the end */
        rb_rng q = rb_rng_make(8);
        bvh_aabb b = rb_bounds(&s);
        bvh_hit h;
        uint32_t hits = 0;
        for (i = 0; i < 3000; i++) {
            bvh_ray ray = rb_gen_ray(&q, &s, &b, (int)(i % 6));
            const float *p;
            if (!rb_brute(&s, &ray, &h)) continue;
            p = s.tris + 9 * (size_t)h.prim;
            if (hits++ < 3)
                print_error("bvh_intersect_triangle hits degenerate triangle %u (%g %g %g, %g %g %g, %g %g %g) at t=%a "
                            "u=%a v=%a: ray o=(%a %a %a) d=(%a %a %a)\n",
                            h.prim, (double)p[0], (double)p[1], (double)p[2], (double)p[3], (double)p[4], (double)p[5],
                            (double)p[6], (double)p[7], (double)p[8], (double)h.t, (double)h.u, (double)h.v,
                            (double)ray.origin.x, (double)ray.origin.y, (double)ray.origin.z, (double)ray.dir.x,
                            (double)ray.dir.y, (double)ray.dir.z);
        }
        rb_every_builder("degenerate triangles", &s, 3000, 0, 0); /* the trees agree with the brute force */
        if (hits) fail_msg("bvh_intersect_triangle hits zero-area triangles: %u of 3000 rays", hits);
    }
    rb_scene_free(&s);
}

/* == NaN and Inf ============================================================================= */
static void rb_poison(rb_scene *s, const uint32_t *tris, uint32_t count) {
    static const float bad[] = {NAN, INFINITY, -INFINITY, -NAN};
    uint32_t i;
    for (i = 0; i < count; i++) s->pos[9 * (size_t)tris[i] + (i * 4) % 9] = bad[i % 4];
}
static void rb_check_refused(const rb_scene *s, bvh_result expect, const char *what) {
    bvh_builder b;
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(s, b);
        bvh_tree t;
        bvh_result r = bvh_build(&t, &d);
        if (r != expect)
            fail_msg("%s (%s): got %s, want %s", what, bvh_builder_name(b), bvh_result_string(r),
                     bvh_result_string(expect));
        assert_null(t.nodes);
        assert_null(t.prims);
        assert_null(t.tris);
        assert_int_equal(t.node_count, 0);
        bvh_free(&t);
    }
}
static void test_nan_inf(void **state) {
    static const uint32_t bad[] = {0, 3, 10, 11, 20, 77, 250, 399};
    rb_scene s;
    bvh_builder b;
    (void)state;
    rb_scene_random(&s, 400, -10, 10, 1, 11);
    rb_poison(&s, bad, 8);
    rb_scene_expand(&s);
    rb_check_refused(&s, BVH_ERROR_INVALID_GEOMETRY, "NaN/Inf refused");
    rb_every_builder("NaN/Inf skipped", &s, 1500, 1, 8);
    RB_FOR_EACH_BUILDER(b) { /* the skipped triangles are referenced nowhere */
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        uint32_t i, k;
        d.skip_invalid = 1;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        for (i = 0; i < t.ref_count; i++)
            for (k = 0; k < 8; k++) assert_int_not_equal(t.prims[i], bad[k]);
        bvh_free(&t);
    }
    rb_scene_free(&s);
}
/* An indexed mesh in which one poisoned vertex is shared by three triangles. */
static void test_nan_shared_vertex(void **state) {
    rb_scene s;
    uint32_t i;
    (void)state;
    memset(&s, 0, sizeof s);
    s.nv = 6 * 6;
    s.nt = 2 * 5 * 5;
    s.pos = (float *)rb_xcalloc(3 * (size_t)s.nv, sizeof(float));
    s.idx = (uint32_t *)rb_xcalloc(3 * (size_t)s.nt, sizeof(uint32_t));
    for (i = 0; i < s.nv; i++) {
        s.pos[3 * i] = (float)(i % 6);
        s.pos[3 * i + 1] = (float)(i / 6);
        s.pos[3 * i + 2] = 0.25f * (float)(i % 5);
    }
    for (i = 0; i < 25; i++) {
        uint32_t v = (i / 5) * 6 + i % 5, *q = s.idx + 6 * i;
        q[0] = v;
        q[1] = v + 1;
        q[2] = v + 7;
        q[3] = v;
        q[4] = v + 7;
        q[5] = v + 6;
    }
    s.pos[3 * 14 + 1] = NAN; /* vertex 14 (x 2, y 2) is in triangles of three cells, 6 triangles */
    rb_scene_expand(&s);
    {
        uint32_t bad = 0;
        for (i = 0; i < s.nt; i++) bad += !rb_finite9(s.tris + 9 * (size_t)i);
        assert_int_equal(bad, 6);
        rb_check_refused(&s, BVH_ERROR_INVALID_GEOMETRY, "shared NaN vertex refused");
        rb_every_builder("shared NaN vertex skipped", &s, 1500, 1, bad);
    }
    rb_scene_free(&s);
}
static void test_all_invalid_skipped(void **state) {
    rb_scene s;
    uint32_t i;
    bvh_builder b;
    (void)state;
    rb_scene_random(&s, 50, -1, 1, 1, 12);
    for (i = 0; i < s.nt; i++) s.pos[9 * i + i % 9] = i & 1 ? NAN : -INFINITY;
    rb_scene_expand(&s);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        bvh_hit h;
        bvh_ray ray = rb_ray(rb_v3(0, 0, -5), rb_v3(0, 0, 1), 0, BVH_INF);
        d.skip_invalid = 1;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_int_equal(t.node_count, 0);
        assert_int_equal(t.excluded, 50);
        assert_int_equal(t.prim_count, 50);
        assert_int_equal(bvh_validate(&t, NULL, NULL), BVH_SUCCESS);
        assert_int_equal(bvh_intersect(&t, &ray, &h), 0);
        bvh_free(&t);
    }
    rb_scene_free(&s);
}

/* == awkward geometry, exact hits ============================================================= */
static void test_far_from_origin(void **state) {
    rb_scene s;
    (void)state;
    rb_scene_random(&s, 1500, 1e6f, 1e6f + 200.0f, 0.5f, 21); /* float spacing there: 0.0625 */
    rb_every_builder("coordinates around 1e6", &s, 1200, 0, 0);
    rb_scene_free(&s);
    rb_scene_random(&s, 1500, -3e6f, -3e6f + 50.0f, 2.0f, 22);
    rb_every_builder("coordinates around -3e6", &s, 1200, 0, 0);
    rb_scene_free(&s);
}
static void test_huge_and_tiny(void **state) {
    rb_scene s;
    (void)state;
    rb_scene_random(&s, 3000, -10, 10, 1e-3f, 31);
    rb_set_tri(s.pos + 9 * 100, -1e4f, -1e4f, -2, 1e4f, -1e4f, 3, 0, 1e4f, 0.5f);
    rb_set_tri(s.pos + 9 * 1500, -1e5f, 0.5f, -1e5f, 1e5f, 0.25f, -1e5f, 0, -0.5f, 1e5f);
    rb_set_tri(s.pos + 9 * 2999, 3, -1e4f, -1e4f, 3, 1e4f, 0, 3.5f, 0, 1e4f);
    rb_scene_expand(&s);
    rb_every_builder("huge and tiny triangles", &s, 1500, 0, 0);
    rb_scene_free(&s);
}
/* Every triangle in the plane z = 0: zero-thickness boxes everywhere. */
static void test_one_plane(void **state) {
    rb_scene s;
    rb_rng r = rb_rng_make(41);
    uint32_t i;
    bvh_builder b;
    (void)state;
    rb_scene_random(&s, 2000, -10, 10, 1, 42);
    for (i = 0; i < s.nt; i++) s.pos[9 * i + 2] = s.pos[9 * i + 5] = s.pos[9 * i + 8] = 0.0f;
    rb_scene_expand(&s);
    rb_every_builder("one plane", &s, 1500, 0, 0);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        rb_check_sah(&t, "one plane");
        for (i = 0; i < 600; i++) { /* rays in the plane (dz = +-0, oz = +-0) and straight down */
            float x = rb_range(&r, -12, 12), y = rb_range(&r, -12, 12), dx = rb_range(&r, -1, 1),
                  dy = rb_range(&r, -1, 1);
            bvh_ray in = rb_ray(rb_v3(x, y, i & 1 ? 0.0f : -0.0f), rb_v3(dx, dy, i & 2 ? 0.0f : -0.0f), 0, BVH_INF);
            bvh_ray down = rb_ray(rb_v3(x, y, 3), rb_v3(i & 1 ? 0.0f : -0.0f, i & 2 ? 0.0f : -0.0f, -1), 0, BVH_INF);
            rb_check_ray("one plane, in-plane ray", &t, &s, &in);
            rb_check_ray("one plane, perpendicular ray", &t, &s, &down);
        }
        bvh_free(&t);
    }
    rb_expect_no_mismatch("one plane, in-plane and perpendicular rays", 5 * 1200);
    { /* all on one line: the root has zero area */
        rb_scene l;
        bvh_tree t;
        bvh_build_desc d;
        rb_scene_soup(&l, 64);
        for (i = 0; i < l.nt; i++)
            rb_set_tri(l.pos + 9 * i, (float)i, 0, 0, (float)i + 0.5f, 0, 0, (float)i + 1.0f, 0, 0);
        rb_scene_expand(&l);
        RB_FOR_EACH_BUILDER(b) {
            d = rb_desc(&l, b);
            assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
            rb_check_tree(&t, l.nt, 0, "one line");
            rb_check_sah(&t, "one line");
            bvh_free(&t);
        }
        rb_scene_free(&l);
    }
    rb_scene_free(&s);
}
/* Axis-aligned lattices on multiples of 0.5 in the three orientations, and axis-parallel rays
   with +0/-0 components whose origins lie exactly on the lattice (and box) planes. */
static void test_axis_aligned(void **state) {
    rb_scene s;
    rb_rng r = rb_rng_make(51);
    uint32_t i, j, axis, t = 0, nc = 8;
    bvh_builder b;
    (void)state;
    rb_scene_soup(&s, 3 * 3 * nc * nc * 2);
    for (axis = 0; axis < 3; axis++)
        for (j = 0; j < 3 * nc * nc; j++, t += 2) {
            uint32_t w = j / (nc * nc), cu = j % nc, cv = (j / nc) % nc, au = (axis + 1) % 3, av = (axis + 2) % 3;
            float *p = s.pos + 9 * (size_t)t;
            float u0 = 0.5f * (float)cu, v0 = 0.5f * (float)cv, wv = 1.5f * (float)w - 0.25f * (float)axis;
            for (i = 0; i < 6; i++) { /* two triangles: (u0,v0) (u1,v0) (u1,v1) and (u0,v0) (u1,v1) (u0,v1) */
                static const int du[6] = {0, 1, 1, 0, 1, 0}, dv[6] = {0, 0, 1, 0, 1, 1};
                p[3 * i + axis] = wv;
                p[3 * i + au] = u0 + 0.5f * (float)du[i];
                p[3 * i + av] = v0 + 0.5f * (float)dv[i];
            }
        }
    rb_scene_expand(&s);
    rb_every_builder("axis-aligned lattice", &s, 1200, 0, 0);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree tr;
        assert_int_equal(bvh_build(&tr, &d), BVH_SUCCESS);
        for (i = 0; i < 3000; i++) {
            float o[3], dir[3];
            int a, k = (int)rb_below(&r, 3);
            for (a = 0; a < 3; a++) { /* lattice coordinates (multiples of 0.25, some outside) */
                o[a] = 0.25f * (float)((int)rb_below(&r, 22) - 3);
                dir[a] = rb_below(&r, 2) ? 0.0f : -0.0f;
            }
            dir[k] = rb_below(&r, 2) ? 1.0f : -1.0f;
            if (i % 3 == 0) dir[(k + 1) % 3] = rb_below(&r, 2) ? 0.5f : -2.0f; /* in a lattice plane, diagonal */
            {
                bvh_ray ray = rb_ray(rb_v3(o[0], o[1], o[2]), rb_v3(dir[0], dir[1], dir[2]), i % 7 == 0 ? 0.5f : 0.0f,
                                     i % 5 == 0 ? 2.0f : BVH_INF);
                rb_check_ray("axis-aligned lattice, axis-parallel ray", &tr, &s, &ray);
            }
        }
        bvh_free(&tr);
    }
    rb_expect_no_mismatch("axis-aligned lattice, axis-parallel rays", 5 * 3000);
    rb_scene_free(&s);
}

/* Finite coordinates near FLT_MAX: boxes and centroid sums overflow to Inf inside the builders,
   and PLOC's distances to NaN. */
static void test_huge_coordinates(void **state) {
    rb_scene s;
    uint32_t i;
    (void)state;
    rb_scene_soup(&s, 8);
    for (i = 0; i < 8; i++) {
        float x = (i & 1 ? 1.0f : -1.0f) * 3e38f, y = (i & 2 ? 1.0f : -1.0f) * 3e37f * (float)(i + 1);
        rb_set_tri(s.pos + 9 * i, x, y, 0, x, y + 1e37f, 1e30f, x * 0.5f, 0, -1e38f);
    }
    rb_scene_expand(&s);
    rb_every_builder("coordinates near FLT_MAX", &s, 600, 0, 0);
    rb_scene_free(&s);
    /* Flat (y = 0) triangles at x = -3e38 and +3e38: a merged box is infinitely wide and has no
       height, so PLOC's distance (the half area) is Inf * 0 = NaN, which must stay an offer (the
       worst), or a cluster is left without a neighbour (found by the fuzzer). */
    rb_scene_soup(&s, 40);
    for (i = 0; i < 40; i++) {
        float x = (i & 1 ? 1.0f : -1.0f) * (3e38f - 1e36f * (float)i);
        rb_set_tri(s.pos + 9 * i, x, 0, (float)i, x + 1e36f, 0, (float)i, x, 0, (float)i + 1.0f);
    }
    rb_scene_expand(&s);
    rb_every_builder("flat, infinitely wide merged boxes", &s, 600, 0, 0);
    rb_scene_free(&s);
}

/* == the traversal: hostile rays, negative t, tiny directions ================================ */
static void test_hostile_rays(void **state) {
    rb_scene s;
    bvh_builder b;
    (void)state;
    rb_scene_random(&s, 300, -1, 1, 1, 61);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        bvh_ray rays[12];
        bvh_hit hits[12], h;
        uint8_t occ[12];
        uint32_t i, visited;
        const bvh_vec3 o = rb_v3(0, 0, -5), dz = rb_v3(0, 0, 1);
        rays[0] = rb_ray(rb_v3(NAN, 0, -5), dz, 0, BVH_INF);
        rays[1] = rb_ray(o, rb_v3(0, NAN, 1), 0, BVH_INF);
        rays[2] = rb_ray(o, rb_v3(0, 0, 0), 0, BVH_INF);
        rays[3] = rb_ray(o, rb_v3(-0.0f, 0.0f, -0.0f), 0, BVH_INF);
        rays[4] = rb_ray(o, dz, 10, 1); /* tmin > tmax */
        rays[5] = rb_ray(rb_v3(0, 0, -INFINITY), dz, 0, BVH_INF);
        rays[6] = rb_ray(rb_v3(INFINITY, 0, -5), dz, 0, BVH_INF);
        rays[7] = rb_ray(o, dz, NAN, BVH_INF);
        rays[8] = rb_ray(o, dz, 0, NAN);
        rays[9] = rb_ray(o, rb_v3(INFINITY, 0, 1), 0, BVH_INF);
        rays[10] = rb_ray(o, rb_v3(0, -INFINITY, 0), 0, BVH_INF);
        rays[11] = rb_ray(rb_v3(0, -NAN, -5), dz, 0, BVH_INF);
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        for (i = 0; i < 12; i++) {
            if (bvh_intersect(&t, &rays[i], &h) || h.prim != BVH_INVALID)
                fail_msg("%s: hostile ray %u hits %u", bvh_builder_name(b), i, h.prim);
            assert_int_equal(bvh_intersect_counted(&t, &rays[i], &h, &visited), 0);
            assert_int_equal(bvh_occluded(&t, &rays[i]), 0);
            assert_int_equal(bvh_intersect_triangle(&rays[i], s.tris, s.tris + 3, s.tris + 6, &h), 0);
        }
        assert_int_equal(bvh_intersect_batch(&t, rays, hits, 12, 2), BVH_SUCCESS);
        assert_int_equal(bvh_occluded_batch(&t, rays, occ, 12, 2), BVH_SUCCESS);
        for (i = 0; i < 12; i++) {
            assert_int_equal(hits[i].prim, BVH_INVALID);
            assert_int_equal(occ[i], 0);
        }
        rays[4].tmin = 0; /* the same ray made valid: exactly the brute-force answer */
        rays[4].tmax = BVH_INF;
        rb_check_ray("valid ray", &t, &s, &rays[4]);
        bvh_free(&t);
    }
    rb_expect_no_mismatch("valid ray", 5);
    assert_int_equal(bvh_intersect(NULL, NULL, NULL), 0);
    assert_int_equal(bvh_occluded(NULL, NULL), 0);
    rb_scene_free(&s);
}

/* Rays with tmin < 0 (hits behind the origin count: tmin <= t <= tmax). */
static void test_negative_tmin(void **state) {
    rb_scene s;
    bvh_builder b;
    (void)state;
    rb_scene_soup(&s, 1); /* minimal case: the triangle lies behind the origin, in its box's plane */
    rb_set_tri(s.pos, 0, 0, 0, 1, 0, 0, 0, 1, 0);
    rb_scene_expand(&s);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        bvh_ray ray = rb_ray(rb_v3(0.2f, 0.2f, 1), rb_v3(0, 0, 1), -BVH_INF, BVH_INF);
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        rb_check_ray("triangle behind the origin, tmin = -inf", &t, &s, &ray);
        bvh_free(&t);
    }
    rb_expect_no_mismatch("triangle behind the origin, tmin = -inf", 5);
    rb_scene_free(&s);
    rb_scene_random(&s, 1000, -10, 10, 1, 71);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        rb_rng r = rb_rng_make(72);
        bvh_aabb bb = rb_bounds(&s);
        uint32_t i;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        for (i = 0; i < 1200; i++) {
            bvh_ray ray = rb_gen_ray(&r, &s, &bb, (int)(i % 6));
            ray.tmin = i & 1 ? -BVH_INF : -rb_range(&r, 0, 20);
            ray.tmax = i % 3 == 0 ? 0.0f : ray.tmax;
            rb_check_ray("random scene, tmin < 0", &t, &s, &ray);
        }
        bvh_free(&t);
    }
    rb_expect_no_mismatch("random scene, tmin < 0", 5 * 1200);
    rb_scene_free(&s);
}

/* Direction components that are denormal but not zero: 1/d overflows to Inf. */
static void test_tiny_direction(void **state) {
    rb_scene s;
    bvh_builder b;
    (void)state;
    rb_scene_soup(&s, 2);
    rb_set_tri(s.pos, 5e-31f, -1, 1e9f, 1, -1, 1e9f, 5e-31f, 1, 1e9f); /* x from 5e-31, at z = 1e9 */
    rb_set_tri(s.pos + 9, 10, 0, 4, 11, 0, 4, 10, 1, 4);
    rb_scene_expand(&s);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        bvh_ray ray = rb_ray(rb_v3(0, 0, 0), rb_v3(1e-39f, 0, 1), 0, BVH_INF); /* reaches x = 1e-30 at t = 1e9 */
        bvh_ray ray2 = rb_ray(rb_v3(10.5f, 0.2f, 0), rb_v3(-1e-39f, 2e-45f, 1), 0, BVH_INF); /* hits t = 4 */
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        rb_check_ray("denormal direction component", &t, &s, &ray2);
        rb_check_ray("denormal direction component", &t, &s, &ray);
        bvh_free(&t);
    }
    rb_expect_no_mismatch("denormal direction component", 10);
    rb_scene_free(&s);
}

/* A hit is a point: finite t, u and v. Denormal and huge coordinates in one triangle, a ray in
   its plane (found by tests/fuzz_build.c). */
static void test_hit_is_finite(void **state) {
    rb_scene s;
    bvh_builder b;
    bvh_ray ray = rb_ray(rb_v3(-4.0f, 0x1p-139f, 0x1.0008p-119f), rb_v3(1.0f, -0.0f, -0.0f), 0, BVH_INF);
    bvh_hit h;
    (void)state;
    rb_scene_soup(&s, 1);
    rb_set_tri(s.pos, 0x1.0208p-113f, 0x1p-139f, 0x1.0008p-119f, -0x1.020208p+113f, 0x1.08p-31f, 0, 0, 0, 0);
    rb_scene_expand(&s);
    if (bvh_intersect_triangle(&ray, s.tris, s.tris + 3, s.tris + 6, &h) &&
        !(fp_finite(h.t) && fp_finite(h.u) && fp_finite(h.v)))
        fail_msg("bvh_intersect_triangle: hit at t=%a u=%a v=%a", (double)h.t, (double)h.u, (double)h.v);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        if (bvh_intersect(&t, &ray, &h) && !(fp_finite(h.t) && fp_finite(h.u) && fp_finite(h.v)))
            fail_msg("%s: hit at t=%a u=%a v=%a", bvh_builder_name(b), (double)h.t, (double)h.u, (double)h.v);
        bvh_free(&t);
    }
    rb_scene_free(&s);
}

/* A ray whose origin is ~1e33 away from a triangle ~1e17 wide: translated in float, the vertices
   leave the edge functions meaningless, and the triangle test used to report a hit far outside
   the triangle, which the traversal's box test (rightly) culled, so traversal and brute force
   disagreed (found by tests/fuzz_build.c; the input is tests/fuzz/crash-false-hit-far-origin).
   The hit must be rejected by both. */
static void test_far_origin_false_hit(void **state) {
    rb_scene s;
    bvh_builder b;
    bvh_ray ray = rb_ray(rb_v3(-0x1.4eff4p+40f, 0x1.4p+1f, -0x1.1efe1ap+111f), rb_v3(-0x1.4p+0f, -0x1.4p+1f, 0x1.ep+1f),
                         0, BVH_INF);
    bvh_hit h;
    (void)state;
    rb_scene_soup(&s, 2);
    rb_set_tri(s.pos, 0x1.527bb4p+57f, 0x1.ea78p-136f, 0x1.7ap-107f, 0x1.f038p-136f, 0, -0x1.9ap+26f, 0x1.f2ap-136f,
               -0x1.3ep-117f, -0x1.0a7a36p+88f);
    rb_set_tri(s.pos + 9, 10, 0, 4, 11, 0, 4, 10, 1, 4);
    rb_scene_expand(&s);
    if (bvh_intersect_triangle(&ray, s.tris, s.tris + 3, s.tris + 6, &h))
        fail_msg("bvh_intersect_triangle: hit at t=%a, where the ray is nowhere near the triangle", (double)h.t);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        bvh_tree t;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        rb_check_ray("far origin", &t, &s, &ray);
        bvh_free(&t);
    }
    rb_expect_no_mismatch("far origin", BVH_BUILDER_COUNT - 1);
    rb_scene_free(&s);
}

/* == bad arguments =========================================================================== */
static void rb_expect(bvh_build_desc d, bvh_result want, const char *what) {
    bvh_tree t;
    bvh_result r = bvh_build(&t, &d);
    if (r != want)
        fail_msg("%s (%s): got %s, want %s", what, bvh_builder_name(d.builder), bvh_result_string(r),
                 bvh_result_string(want));
    if (r == BVH_SUCCESS) {
        rb_check_tree(&t, t.prim_count, t.excluded, what);
    } else {
        assert_null(t.nodes);
        assert_int_equal(t.node_count, 0);
    }
    bvh_free(&t);
}
static void test_index_out_of_range(void **state) {
    rb_scene s;
    bvh_builder b;
    uint32_t i;
    (void)state;
    rb_scene_random(&s, 20, -1, 1, 1, 81);
    s.idx = (uint32_t *)rb_xcalloc(3 * (size_t)s.nt, sizeof(uint32_t));
    for (i = 0; i < 3 * s.nt; i++) s.idx[i] = i;
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        rb_expect(d, BVH_SUCCESS, "indices in range");
        s.idx[59] = s.nv;
        rb_expect(d, BVH_ERROR_INDEX_OUT_OF_RANGE, "index == vertex_count");
        s.idx[59] = 59;
        s.idx[0] = UINT32_MAX;
        rb_expect(d, BVH_ERROR_INDEX_OUT_OF_RANGE, "index 0xFFFFFFFF");
        d.skip_invalid = 1; /* skip_invalid is about geometry, not indices */
        rb_expect(d, BVH_ERROR_INDEX_OUT_OF_RANGE, "index 0xFFFFFFFF with skip_invalid");
        s.idx[0] = 0;
        d.triangles.indices = NULL;
        d.triangles.vertex_count = 3 * s.nt - 1; /* a soup needs 3 vertices per triangle */
        rb_expect(d, BVH_ERROR_INDEX_OUT_OF_RANGE, "soup with too few vertices");
        d.triangles.vertex_count = 0;
        rb_expect(d, BVH_ERROR_INDEX_OUT_OF_RANGE, "soup with vertex_count 0");
    }
    rb_scene_free(&s);
}
static void test_bad_stride(void **state) {
    rb_scene s;
    bvh_builder b;
    float *wide;
    uint32_t i;
    (void)state;
    rb_scene_random(&s, 30, -1, 1, 1, 91);
    wide = (float *)rb_xcalloc(s.nv, 16);
    for (i = 0; i < s.nv; i++) {
        memcpy(wide + 4 * i, s.pos + 3 * i, 12);
        wide[4 * i + 3] = NAN;
    }
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d = rb_desc(&s, b);
        size_t st;
        for (st = 1; st < 12; st++) {
            d.triangles.stride = st;
            rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "stride below 12");
        }
        d.triangles.stride = 12;
        rb_expect(d, BVH_SUCCESS, "stride 12");
        d.triangles.stride = 16;
        d.triangles.positions = wide;
        rb_expect(d, BVH_SUCCESS, "stride 16 (NaN padding not read)");
        d.triangles.positions = NULL;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "positions NULL");
    }
    rb_xfree(wide);
    rb_scene_free(&s);
}
/* A count above 2^30 is refused before any vertex, index or box is read: the buffers are one
   element long (ASan would report a read past them). */
static void test_too_many_primitives(void **state) {
    bvh_builder b;
    float *one = (float *)rb_xcalloc(3, sizeof(float));
    uint32_t *idx = (uint32_t *)rb_xcalloc(1, sizeof(uint32_t));
    bvh_aabb *box = (bvh_aabb *)rb_xcalloc(1, sizeof(bvh_aabb));
    (void)state;
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc d;
        const uint32_t counts[] = {(1u << 30) + 1, 0x55555556u, UINT32_MAX};
        int k;
        for (k = 0; k < 3; k++) {
            memset(&d, 0, sizeof d);
            d.builder = b;
            d.triangles.positions = one;
            d.triangles.vertex_count = UINT32_MAX;
            d.triangles.triangle_count = counts[k];
            rb_expect(d, BVH_ERROR_TOO_MANY_PRIMITIVES, "huge soup");
            d.triangles.indices = idx;
            rb_expect(d, BVH_ERROR_TOO_MANY_PRIMITIVES, "huge indexed mesh");
            d.skip_invalid = 1;
            rb_expect(d, BVH_ERROR_TOO_MANY_PRIMITIVES, "huge indexed mesh, skip_invalid");
            memset(&d, 0, sizeof d);
            d.builder = b;
            d.boxes = box;
            d.box_count = counts[k];
            rb_expect(d, BVH_ERROR_TOO_MANY_PRIMITIVES, "huge box count");
        }
    }
    rb_xfree(one);
    rb_xfree(idx);
    rb_xfree(box);
}
static void test_options(void **state) {
    rb_scene s;
    bvh_builder b;
    (void)state;
    rb_scene_random(&s, 500, -5, 5, 1, 101);
    RB_FOR_EACH_BUILDER(b) {
        bvh_build_desc base = rb_desc(&s, b), d;
        bvh_tree t;
        bvh_stats st;
        d = base;
        d.max_leaf_size = 0;
        rb_expect(d, BVH_SUCCESS, "max_leaf_size 0 (default)");
        d = base;
        d.max_leaf_size = 1;
        rb_expect(d, BVH_SUCCESS, "max_leaf_size 1");
        d = base;
        d.max_leaf_size = 255;
        rb_expect(d, BVH_SUCCESS, "max_leaf_size 255");
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_int_equal(bvh_get_stats(&t, &st), BVH_SUCCESS);
        assert_true(st.max_leaf_size <= 255);
        bvh_free(&t);
        d = base;
        d.max_leaf_size = 256;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "max_leaf_size 256");
        d = base;
        d.max_leaf_size = UINT32_MAX;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "max_leaf_size 2^32-1");
        d = base;
        d.ploc.radius = 0;
        rb_expect(d, BVH_SUCCESS, "ploc_radius 0 (default)");
        d = base;
        d.ploc.radius = 1;
        rb_expect(d, BVH_SUCCESS, "ploc_radius 1");
        d = base;
        d.ploc.radius = 256;
        rb_expect(d, BVH_SUCCESS, "ploc_radius 256");
        d = base;
        d.ploc.radius = 257;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "ploc_radius 257");
        d = base;
        d.threads = 0;
        rb_expect(d, BVH_SUCCESS, "threads 0 (all CPUs)");
        d = base;
        d.threads = 10000;
        rb_expect(d, BVH_SUCCESS, "threads 10000 (clamped to 256)");
        d = base;
        d.costs.interior = -1;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "negative interior cost");
        d = base;
        d.costs.leaf = -0.5f;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "negative leaf cost");
        d = base;
        d.costs.triangle = -1e-30f;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "negative triangle cost");
        d = base;
        d.costs.interior = NAN;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "NaN interior cost");
        d = base;
        d.costs.triangle = NAN;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "NaN triangle cost");
        d = base;
        d.costs.leaf = -INFINITY;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "-Inf leaf cost");
        d = base;
        d.costs.interior = 2;
        d.costs.leaf = 1;
        d.costs.triangle = 0.25f;
        rb_expect(d, BVH_SUCCESS, "positive costs");
        d = base;
        d.costs.interior = 0;
        d.costs.leaf = 0;
        d.costs.triangle = 1e-3f;
        rb_expect(d, BVH_SUCCESS, "zero interior cost");
        d = base;
        d.sah_midpoint.split_budget = NAN;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "split_budget NaN");
        d = base;
        d.sah_midpoint.split_budget = 1.0001f;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "split_budget > 1");
        d = base;
        d.sah_midpoint.split_budget = INFINITY;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "split_budget Inf");
        d = base;
        d.sah_midpoint.split_budget = 1.0f;
        rb_expect(d, BVH_SUCCESS, "split_budget 1");
        d = base;
        d.sah_midpoint.split_budget = -1.0f;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "split_budget -1");
        d = base;
        d.sah_midpoint.split_budget = -0.0f;
        rb_expect(d, BVH_SUCCESS, "split_budget -0 (default)");
        d = base;
        d.sah_midpoint.split_budget = BVH_OFF;
        rb_expect(d, BVH_SUCCESS, "split_budget BVH_OFF (no splits)");
        d = base;
        d.sah_midpoint.split_budget = 2147483520.0f;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "split_budget below BVH_OFF");
        d = base;
        d.sah_midpoint.bins = BVH_OFF;
        rb_expect(d, BVH_SUCCESS, "sah bins BVH_OFF (mid-point only)");
        d = base;
        d.sah_midpoint.bins = 65;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "sah bins 65");
        d = base;
        d.sah_midpoint.split_budget = 1e-7f;
        rb_expect(d, BVH_SUCCESS, "split_budget tiny");
    }
    {
        bvh_build_desc d = rb_desc(&s, BVH_BUILDER_PLOC);
        bvh_tree t;
        d.builder = (bvh_builder)BVH_BUILDER_COUNT;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "builder out of range");
        d.builder = (bvh_builder)-1;
        rb_expect(d, BVH_ERROR_INVALID_ARGUMENT, "builder -1");
        assert_int_equal(bvh_build(&t, NULL), BVH_ERROR_INVALID_ARGUMENT);
        assert_int_equal(bvh_build(NULL, &d), BVH_ERROR_INVALID_ARGUMENT);
    }
    rb_scene_free(&s);
}

/* == allocation failure ====================================================================== */
typedef struct rb_alloc {
    atomic_long calls, live;
    long fail_at; /* the allocation with this 0-based number fails; -1: none */
} rb_alloc;
static void *rb_alloc_fn(size_t size, void *user) {
    rb_alloc *a = (rb_alloc *)user;
    long k = atomic_fetch_add(&a->calls, 1);
    void *p;
    if (k == a->fail_at) return NULL;
    p = malloc(size);
    if (p) atomic_fetch_add(&a->live, 1);
    return p;
}
static void rb_free_fn(void *p, void *user) {
    rb_alloc *a = (rb_alloc *)user;
    if (p) atomic_fetch_sub(&a->live, 1);
    free(p);
}
static bvh_allocator rb_allocator(rb_alloc *a, long fail_at) {
    bvh_allocator al;
    atomic_store(&a->calls, 0);
    atomic_store(&a->live, 0);
    a->fail_at = fail_at;
    al.alloc = rb_alloc_fn;
    al.free = rb_free_fn;
    al.user = a;
    return al;
}
/* Fails allocation k of a build for every k below the count of a successful build. */
static void rb_fail_every_allocation(const rb_scene *s, bvh_builder b, int skip_invalid, uint32_t threads,
                                     const char *what) {
    rb_alloc a;
    bvh_build_desc d = rb_desc(s, b);
    bvh_tree t;
    long total, k;
    d.skip_invalid = skip_invalid;
    d.threads = threads;
    d.allocator = rb_allocator(&a, -1);
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    total = atomic_load(&a.calls);
    assert_true(total > 0);
    bvh_free(&t);
    assert_int_equal(atomic_load(&a.live), 0);
    for (k = 0; k < total; k++) {
        bvh_result r;
        d.allocator = rb_allocator(&a, k);
        r = bvh_build(&t, &d);
        if (r == BVH_SUCCESS) {
            rb_check_tree(&t, s->nt, t.excluded, what);
        } else if (r != BVH_ERROR_OUT_OF_MEMORY) {
            fail_msg("%s (%s): allocation %ld of %ld failed: %s", what, bvh_builder_name(b), k, total,
                     bvh_result_string(r));
        } else {
            assert_null(t.nodes);
            assert_null(t.prims);
            assert_null(t.tris);
            assert_null(t.nodes8);
            if (atomic_load(&a.live) != 0)
                fail_msg("%s (%s): allocation %ld of %ld failed: %ld blocks leaked", what, bvh_builder_name(b), k,
                         total, (long)atomic_load(&a.live));
        }
        bvh_free(&t);
        if (atomic_load(&a.live) != 0)
            fail_msg("%s (%s): allocation %ld of %ld failed: %ld blocks live after bvh_free", what, bvh_builder_name(b),
                     k, total, (long)atomic_load(&a.live));
    }
}
/* The geometric chain of test_ploc_chain (defined below): makes bvh__emit rebuild for depth. */
static void rb_scene_chain(rb_scene *s, uint32_t n, float growth);
static void test_allocation_failure(void **state) {
    rb_scene s, chain;
    bvh_builder b;
    (void)state;
    rb_scene_random(&s, 300, -3, 3, 1, 111);
    s.pos[9 * 17 + 4] = NAN; /* with skip_invalid: the map of kept primitives is allocated too */
    rb_scene_expand(&s);
    rb_scene_chain(&chain, 120, 1.3f);
    RB_FOR_EACH_BUILDER(b) {
        rb_fail_every_allocation(&s, b, 1, 3, "300 triangles, one skipped");
        rb_fail_every_allocation(&chain, b, 0, 2, "chain (depth rebuild)");
    }
    rb_fail_every_allocation(&s, BVH_BUILDER_PLOC_PARALLEL, 1, 1, "ploc-parallel, one thread");
    { /* bvh_validate and batch tracing allocate through the tree's allocator too */
        rb_alloc a;
        bvh_build_desc d = rb_desc(&s, BVH_BUILDER_PLOC);
        bvh_tree t;
        bvh_ray *rays = (bvh_ray *)rb_xcalloc(1024, sizeof(bvh_ray));
        bvh_hit *hits = (bvh_hit *)rb_xcalloc(1024, sizeof(bvh_hit));
        long k, base;
        uint32_t i;
        for (i = 0; i < 1024; i++)
            rays[i] = rb_ray(rb_v3(0, 0, -9), rb_v3(0.001f * (float)i - 0.5f, 0.3f, 1), 0, BVH_INF);
        d.skip_invalid = 1;
        d.allocator = rb_allocator(&a, -1);
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        base = atomic_load(&a.calls);
        for (k = 0; k < 2; k++) {
            a.fail_at = base + k;
            assert_int_equal(bvh_validate(&t, NULL, NULL), BVH_ERROR_OUT_OF_MEMORY);
            base = atomic_load(&a.calls);
            assert_int_equal(atomic_load(&a.live), 4); /* nodes, references, triangles, 8-wide nodes with packets */
        }
        for (k = 0; k < 2; k++) {
            a.fail_at = atomic_load(&a.calls) + k;
            assert_int_equal(bvh_intersect_batch(&t, rays, hits, 1024, 4), BVH_ERROR_OUT_OF_MEMORY);
            assert_int_equal(atomic_load(&a.live), 4);
        }
        a.fail_at = -1;
        assert_int_equal(bvh_validate(&t, NULL, NULL), BVH_SUCCESS);
        bvh_free(&t);
        assert_int_equal(atomic_load(&a.live), 0);
        rb_xfree(rays);
        rb_xfree(hits);
    }
    rb_scene_free(&chain);
    rb_scene_free(&s);
}

/* == depth: hand-made trees and PLOC chains ================================================== */
/* A caterpillar of `depth` levels: interior node 2l has children 2l+1 (a leaf with triangle l)
   and 2l+2; the last node is a leaf. Root depth 1. */
typedef struct rb_handmade {
    bvh_node *nodes;
    uint32_t *prims;
    float *tris;
    bvh_tree tree;
} rb_handmade;
static void rb_handmade_make(rb_handmade *h, uint32_t depth) {
    uint32_t n = 2 * depth - 1, l, i;
    h->nodes = (bvh_node *)rb_xcalloc(n, sizeof(bvh_node));
    h->prims = (uint32_t *)rb_xcalloc(depth, sizeof(uint32_t));
    h->tris = (float *)rb_xcalloc(9 * (size_t)depth, sizeof(float));
    for (l = 0; l < depth; l++) {
        h->prims[l] = l;
        rb_set_tri(h->tris + 9 * l, (float)l, 0, 0, (float)l + 1, 0, 0, (float)l, 1, 0);
    }
    for (i = n; i-- > 0;) { /* children have larger indices: fill from the end */
        bvh_node *x = &h->nodes[i];
        uint32_t leaf = i == n - 1 ? depth - 1 : (i - 1) / 2;
        if (i == n - 1 || (i & 1)) {
            x->min = rb_v3((float)leaf, 0, 0);
            x->max = rb_v3((float)leaf + 1, 1, 0);
            x->index = leaf;
            x->count = 1;
        } else {
            x->min = h->nodes[i + 1].min;
            x->max = h->nodes[i + 2].max;
            x->index = i + 1;
            x->count = 0;
        }
    }
    memset(&h->tree, 0, sizeof h->tree);
    h->tree.nodes = h->nodes;
    h->tree.node_count = n;
    h->tree.prims = h->prims;
    h->tree.ref_count = depth;
    h->tree.tris = h->tris;
    h->tree.prim_count = depth;
    h->tree.builder = BVH_BUILDER_TOP_DOWN;
}
static void rb_handmade_free(rb_handmade *h) {
    rb_xfree(h->nodes);
    rb_xfree(h->prims);
    rb_xfree(h->tris);
}
static void test_handmade_deep_tree(void **state) {
    rb_handmade h;
    bvh_validation rep;
    bvh_stats st;
    uint32_t depth;
    (void)state;
    for (depth = BVH_MAX_DEPTH - 1; depth <= BVH_MAX_DEPTH + 2; depth++) {
        rb_handmade_make(&h, depth);
        if (depth <= BVH_MAX_DEPTH) {
            bvh_result r = bvh_validate(&h.tree, NULL, &rep);
            if (r != BVH_SUCCESS) fail_msg("depth %u: %s (node %u)", depth, rep.message, rep.node);
            assert_int_equal(bvh_get_stats(&h.tree, &st), BVH_SUCCESS);
            assert_int_equal(st.max_depth, depth);
        } else {
            bvh_result r;
            assert_int_equal(bvh_validate(&h.tree, NULL, &rep), BVH_ERROR_INVALID_TREE);
            assert_non_null(strstr(rep.message, "deeper"));
            r = bvh_get_stats(&h.tree, &st); /* not a validator: may refuse, or report the depth */
            if (r == BVH_SUCCESS)
                assert_int_equal(st.max_depth, depth);
            else
                assert_int_equal(r, BVH_ERROR_INVALID_TREE);
        }
        { /* traversal must stay in bounds even on the rejected tree */
            uint32_t l;
            bvh_hit hit;
            for (l = 0; l < depth; l++) {
                bvh_ray ray = rb_ray(rb_v3((float)l + 0.25f, 0.25f, -1), rb_v3(0, 0, 1), 0, BVH_INF);
                int got = bvh_intersect(&h.tree, &ray, &hit);
                if (depth <= BVH_MAX_DEPTH) {
                    assert_int_equal(got, 1);
                    assert_int_equal(hit.prim, l);
                }
            }
        }
        rb_handmade_free(&h);
    }
    rb_handmade_make(&h, 300);
    assert_int_equal(bvh_validate(&h.tree, NULL, &rep), BVH_ERROR_INVALID_TREE);
    {
        bvh_ray ray = rb_ray(rb_v3(299.25f, 0.25f, -1), rb_v3(0, 0, 1), 0, BVH_INF);
        bvh_hit hit;
        (void)bvh_intersect(&h.tree, &ray, &hit);
        (void)bvh_occluded(&h.tree, &ray);
    }
    rb_handmade_free(&h);
}
/* Other defects the validator must catch without reading out of bounds. */
static void test_handmade_broken_trees(void **state) {
    rb_handmade h;
    bvh_validation rep;
    int k;
    (void)state;
    for (k = 0; k < 9; k++) {
        rb_handmade_make(&h, 6);
        switch (k) {
        case 0:
            h.nodes[0].index = 0;
            break; /* a cycle to the root */
        case 1:
            h.nodes[2].index = 1;
            break; /* a node reached twice */
        case 2:
            h.nodes[4].index = h.tree.node_count - 1;
            break; /* child index past the end */
        case 3:
            h.nodes[4].index = UINT32_MAX;
            break;
        case 4:
            h.nodes[1].index = 5;
            h.nodes[1].count = 2;
            break; /* leaf range past the end */
        case 5:
            h.nodes[1].count = UINT32_MAX;
            break;
        case 6:
            h.prims[2] = 99;
            break; /* reference out of range */
        case 7:
            h.prims[2] = 3;
            break; /* primitive twice, one missing */
        default:
            h.nodes[3].max.x = NAN;
            break; /* NaN box */
        }
        if (bvh_validate(&h.tree, NULL, &rep) != BVH_ERROR_INVALID_TREE) fail_msg("defect %d not found", k);
        rb_handmade_free(&h);
    }
}

/* n triangles side by side along x, width growing by `growth` each: nearest-neighbour clustering
   chains them far deeper than BVH_MAX_DEPTH. */
static void rb_scene_chain(rb_scene *s, uint32_t n, float growth) {
    uint32_t i;
    float x = 0.0f, w = 0.01f;
    rb_scene_soup(s, n);
    for (i = 0; i < n; i++) {
        rb_set_tri(s->pos + 9 * i, x, 0, 0, x + w, 0, w * 0.5f, x + 0.5f * w, w, 0);
        x += w;
        w *= growth;
    }
    rb_scene_expand(s);
}
/* n concentric triangles of linearly growing size: all centroids equal, every box inside the
   next, so PLOC merges one cluster per iteration. */
static void rb_scene_nested(rb_scene *s, uint32_t n) {
    uint32_t i;
    rb_scene_soup(s, n);
    for (i = 0; i < n; i++) {
        float r = 1.0f + (float)i;
        rb_set_tri(s->pos + 9 * i, -r, -r, -0.001f * (float)i, r, -r, 0.001f * (float)i, 0, r, 0);
    }
    rb_scene_expand(s);
}
static void test_ploc_chain(void **state) {
    rb_scene s;
    (void)state;
    rb_scene_chain(&s, 160, 1.25f); /* widths 0.01 .. 3e13 */
    rb_every_builder("geometric chain", &s, 600, 0, 0);
    rb_scene_free(&s);
    rb_scene_nested(&s, 1000);
    rb_every_builder("nested triangles", &s, 300, 0, 0);
    rb_scene_free(&s);
}
/* Chains must not make a build quadratic: 32,768 nested triangles within 5 s per builder (an
   O(n log n) build takes milliseconds, even under ASan; one PLOC iteration per cluster takes
   about 25 s). */
static int rb_nested_child(void *arg) {
    const rb_copies *c = (const rb_copies *)arg;
    bvh_build_desc d = rb_desc(c->s, c->b);
    bvh_tree t;
    d.threads = 2;
    if (bvh_build(&t, &d) != BVH_SUCCESS) return 1;
    if (bvh_validate(&t, NULL, NULL) != BVH_SUCCESS) return 2;
    bvh_free(&t);
    return 0;
}
static void test_ploc_chain_time(void **state) {
    rb_scene s;
    bvh_builder b;
    (void)state;
    rb_scene_nested(&s, 32768);
    RB_FOR_EACH_BUILDER(b) {
        rb_copies c;
        char what[80];
        c.s = &s;
        c.b = b;
        snprintf(what, sizeof what, "32,768 nested triangles, %s", bvh_builder_name(b));
        rb_watchdog(what, 5, rb_nested_child, &c);
    }
    rb_scene_free(&s);
}

/* == threads (also run under TSan) =========================================================== */
static void rb_same_tree(const bvh_tree *a, const bvh_tree *b, const char *what) {
    const char *diff = tree_diff(a, b);
    if (diff) fail_msg("%s: ploc-parallel's tree differs from ploc's in %s", what, diff);
}
static void rb_threads_scene(rb_scene *s, int which) {
    if (which == 0)
        rb_scene_random(s, 20000, -10, 10, 1, 121);
    else if (which == 1) {
        rb_scene_random(s, 3000, -10, 10, 1, 122);
        s->pos[9 * 5] = NAN;
        rb_scene_expand(s);
    } else if (which == 2)
        rb_scene_chain(s, 200, 1.25f);
    else {
        uint32_t i;
        rb_scene_soup(s, 5000); /* duplicates: ties everywhere */
        for (i = 0; i < s->nt; i++)
            rb_set_tri(s->pos + 9 * i, (float)(i % 7), 0, 0, (float)(i % 7) + 1, 0, 0, (float)(i % 7), 1, 0);
        rb_scene_expand(s);
    }
}
static void test_threads_ploc_parallel(void **state) {
    int which;
    (void)state;
    for (which = 0; which < 4; which++) {
        rb_scene s;
        bvh_build_desc d;
        bvh_tree ref, t;
        uint32_t th;
        rb_threads_scene(&s, which);
        d = rb_desc(&s, BVH_BUILDER_PLOC);
        d.skip_invalid = 1;
        d.ploc.radius = which == 3 ? 3 : 0;
        assert_int_equal(bvh_build(&ref, &d), BVH_SUCCESS);
        d.builder = BVH_BUILDER_PLOC_PARALLEL;
        for (th = 2; th <= 8; th++) {
            d.threads = th;
            assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
            rb_check_tree(&t, s.nt, ref.excluded, "ploc-parallel");
            rb_same_tree(&ref, &t, "ploc-parallel, 2..8 threads");
            bvh_free(&t);
        }
        bvh_free(&ref);
        rb_scene_free(&s);
    }
}
static void test_threads_batch(void **state) {
    rb_scene s;
    bvh_build_desc d;
    bvh_tree t;
    const uint32_t n = 5000;
    bvh_ray *rays = (bvh_ray *)rb_xcalloc(n, sizeof(bvh_ray));
    bvh_hit *hits = (bvh_hit *)rb_xcalloc(n, sizeof(bvh_hit)), h;
    uint8_t *occ = (uint8_t *)rb_xcalloc(n, 1);
    rb_rng r = rb_rng_make(131);
    bvh_aabb b;
    uint32_t i, th;
    (void)state;
    assert_non_null(rays);
    assert_non_null(hits);
    assert_non_null(occ);
    rb_scene_random(&s, 3000, -10, 10, 1, 132);
    b = rb_bounds(&s);
    for (i = 0; i < n; i++) rays[i] = rb_gen_ray(&r, &s, &b, (int)(i % 6));
    rays[7].dir = rb_v3(0, 0, 0); /* a few hostile ones in the batch */
    rays[300].origin.x = NAN;
    d = rb_desc(&s, BVH_BUILDER_PLOC_PARALLEL);
    d.threads = 4;
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    for (th = 2; th <= 8; th += 3) {
        memset(hits, 0xAB, n * sizeof(bvh_hit));
        memset(occ, 0xAB, n);
        assert_int_equal(bvh_intersect_batch(&t, rays, hits, n, th), BVH_SUCCESS);
        assert_int_equal(bvh_occluded_batch(&t, rays, occ, n, th), BVH_SUCCESS);
        for (i = 0; i < n; i++) {
            int got = bvh_intersect(&t, &rays[i], &h);
            if (hits[i].prim != h.prim || (got && hits[i].t != h.t))
                fail_msg("batch ray %u differs (%u threads)", i, th);
            assert_int_equal(occ[i], (uint8_t)bvh_occluded(&t, &rays[i]));
        }
    }
    assert_int_equal(bvh_intersect_batch(&t, NULL, NULL, 0, 4), BVH_SUCCESS);
    assert_int_equal(bvh_intersect_batch(&t, rays, NULL, 10, 4), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_occluded_batch(&t, rays, NULL, 10, 4), BVH_ERROR_INVALID_ARGUMENT);
    bvh_free(&t);
    rb_scene_free(&s);
    rb_xfree(rays);
    rb_xfree(hits);
    rb_xfree(occ);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_teardown(test_empty, rb_teardown),
        cmocka_unit_test_teardown(test_one_triangle, rb_teardown),
        cmocka_unit_test_teardown(test_two_identical, rb_teardown),
        cmocka_unit_test_teardown(test_100k_copies, rb_teardown),
        cmocka_unit_test_teardown(test_degenerate_only, rb_teardown),
        cmocka_unit_test_teardown(test_nan_inf, rb_teardown),
        cmocka_unit_test_teardown(test_nan_shared_vertex, rb_teardown),
        cmocka_unit_test_teardown(test_all_invalid_skipped, rb_teardown),
        cmocka_unit_test_teardown(test_far_from_origin, rb_teardown),
        cmocka_unit_test_teardown(test_huge_and_tiny, rb_teardown),
        cmocka_unit_test_teardown(test_one_plane, rb_teardown),
        cmocka_unit_test_teardown(test_axis_aligned, rb_teardown),
        cmocka_unit_test_teardown(test_hostile_rays, rb_teardown),
        cmocka_unit_test_teardown(test_negative_tmin, rb_teardown),
        cmocka_unit_test_teardown(test_tiny_direction, rb_teardown),
        cmocka_unit_test_teardown(test_hit_is_finite, rb_teardown),
        cmocka_unit_test_teardown(test_index_out_of_range, rb_teardown),
        cmocka_unit_test_teardown(test_bad_stride, rb_teardown),
        cmocka_unit_test_teardown(test_too_many_primitives, rb_teardown),
        cmocka_unit_test_teardown(test_options, rb_teardown),
        cmocka_unit_test_teardown(test_allocation_failure, rb_teardown),
        cmocka_unit_test_teardown(test_handmade_deep_tree, rb_teardown),
        cmocka_unit_test_teardown(test_handmade_broken_trees, rb_teardown),
        cmocka_unit_test_teardown(test_ploc_chain, rb_teardown),
        cmocka_unit_test_teardown(test_ploc_chain_time, rb_teardown),
        cmocka_unit_test_teardown(test_threads_ploc_parallel, rb_teardown),
        cmocka_unit_test_teardown(test_threads_batch, rb_teardown),
        /* last: under UBSan (make asan) a report stops the whole program */
        cmocka_unit_test_teardown(test_huge_coordinates, rb_teardown),
        cmocka_unit_test_teardown(test_far_origin_false_hit, rb_teardown),
    };
    const char *filter = getenv("ROBUST_FILTER"); /* e.g. "test_threads_*" for make tsan */
    if (filter && *filter) cmocka_set_test_filter(filter);
    return cmocka_run_group_tests_name("robust", tests, NULL, rb_group_teardown);
}
