/* tests/test_pool.c - a caller's thread pool (bvh_build_desc.pool, bvh_batch_desc.pool,
   bvh_refit_desc.pool, bvh_load_desc.pool, bvh_scene_desc.pool) and the build's progress callback
   (bvh_build_desc.progress).

   Pool: three hooks, one that runs the tasks one after another on the calling thread, one that
   runs them on its own pthreads in reversed order and one in a shuffled order; for every scene,
   builder and task count, the tree is byte for byte the internal pool's (tree_diff.h), and so
   are a refitted and a loaded one and a scene's top level; the
   batch calls (a tree's and a scene's) give the internal pool's hits and flags. Progress:
   fractions rise from 0 to a single 1 on a completed build; cancelling at the k-th call, for every k a build makes,
   returns BVH_ERROR_CANCELLED with the tree empty and every block given back (a counting allocator; `make asan` checks
   the rest); on 200K random triangles the callback comes at least once per BVH__PROGRESS_WORK-ish slice of work and
   never leaves a long gap. Persistent workers (examples/workers.h): every builder's tree and
   hundreds of batch calls in a row, small and large, the same as the internal pool's (make tsan
   runs this file too: the workers' hand-over between runs). */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
/* sah-midpoint's rare paths, counted (on the calling thread): a subtree built again with its
   exact budget, a parallel build started again serially */
static struct { unsigned rebuilt, serial; } sm_events;
#define BVH__SM_EVENT(what) (sm_events.what++)
#include "bvh.h"
#include "test_util.h"
#include "tree_diff.h"
#include "examples/workers.h"

#include <pthread.h>
#include <time.h>

/* == pools =================================================================================== */
typedef struct pool_state {
    int order; /* 0: serial on the caller; 1: reversed, 2: shuffled, on `workers` pthreads */
    uint32_t workers;
    uint32_t runs; /* calls of run */
    uint64_t seed;
} pool_state;
typedef struct pool_job {
    bvh_task_fn task;
    void *arg;
    const uint32_t *order;
    uint32_t count, next;
    pthread_mutex_t mutex;
} pool_job;
static void *pool_worker(void *p) {
    pool_job *j = (pool_job *)p;
    for (;;) {
        uint32_t k;
        pthread_mutex_lock(&j->mutex);
        k = j->next < j->count ? j->next++ : j->count;
        pthread_mutex_unlock(&j->mutex);
        if (k == j->count) return NULL;
        j->task(j->arg, j->order[k]);
    }
}
static void pool_run(void *user, uint32_t count, bvh_task_fn task, void *arg) {
    pool_state *s = (pool_state *)user;
    pthread_t th[8];
    pool_job j;
    uint32_t *order, i, w;
    s->runs++;
    if (s->order == 0) {
        for (i = 0; i < count; i++) task(arg, i);
        return;
    }
    order = (uint32_t *)malloc((count ? count : 1) * sizeof *order);
    assert_non_null(order);
    for (i = 0; i < count; i++) order[i] = count - 1 - i;
    if (s->order == 2) {
        tu_rng r = tu_rng_make(s->seed++);
        for (i = count; i > 1; i--) {
            uint32_t k = tu_below(&r, i), t = order[i - 1];
            order[i - 1] = order[k];
            order[k] = t;
        }
    }
    j.task = task;
    j.arg = arg;
    j.order = order;
    j.count = count;
    j.next = 0;
    pthread_mutex_init(&j.mutex, NULL);
    for (w = 0; w < s->workers && w < 8; w++) assert_int_equal(pthread_create(&th[w], NULL, pool_worker, &j), 0);
    while (w-- > 0) pthread_join(th[w], NULL);
    pthread_mutex_destroy(&j.mutex);
    free(order);
}
static const char *const pool_names[] = {"serial", "reversed", "shuffled"};
/* A batch description on test pool `order` (see pool_run), three workers, its state in *ps. */
static bvh_batch_desc pool_batch_desc(pool_state *ps, int order, uint64_t seed) {
    bvh_batch_desc bd;
    memset(ps, 0, sizeof *ps);
    ps->order = order;
    ps->workers = 3;
    ps->seed = seed;
    memset(&bd, 0, sizeof bd);
    bd.pool.run = pool_run;
    bd.pool.user = ps;
    return bd;
}

/* == a counting allocator ==================================================================== */
typedef struct count_alloc {
    long live;
} count_alloc;
static void *ca_alloc(size_t size, void *user) {
    ((count_alloc *)user)->live++;
    return malloc(size);
}
static void ca_free(void *p, void *user) {
    ((count_alloc *)user)->live--;
    free(p);
}

/* == the allocator is called on the calling thread only ======================================= */
/* docs/GUIDE.md promises it (a caller's allocator need not be thread-safe: a block cache for
   builds every frame): every builder, the optimizer, the layout, validate, refit, save and load
   (copied and borrowed), the batch calls and a scene, each on 4 threads and small inputs that
   take the threaded paths (BVH__MIN_PRIMS_PER_THREAD 1). */
typedef struct thread_alloc {
    pthread_t owner;
    long calls, elsewhere;
} thread_alloc;
static void *ta_alloc(size_t size, void *user) {
    thread_alloc *a = (thread_alloc *)user;
    a->calls++; /* a data race, which `make tsan` would report, if it were not the owner */
    if (!pthread_equal(a->owner, pthread_self())) a->elsewhere++;
    return malloc(size);
}
static void ta_free(void *p, void *user) {
    thread_alloc *a = (thread_alloc *)user;
    a->calls++;
    if (!pthread_equal(a->owner, pthread_self())) a->elsewhere++;
    free(p);
}
typedef struct ta_buf {
    unsigned char *data;
    size_t size, cap;
} ta_buf;
static size_t ta_write(void *user, const void *p, size_t n) {
    ta_buf *b = (ta_buf *)user;
    if (n > b->cap - b->size) return 0;
    memcpy(b->data + b->size, p, n);
    b->size += n;
    return n;
}
static void allocator_on_calling_thread(void **state) {
    tu_scene s;
    thread_alloc ta;
    int b;
    (void)state;
    tu_scene_random(&s, 20000, 0x414c4c4fULL);
    memset(&ta, 0, sizeof ta);
    ta.owner = pthread_self();
    for (b = 0; b <= TU_BUILDER_COUNT; b++) {
        bvh_build_desc d = tu_scene_desc(&s, tu_builder(b < TU_BUILDER_COUNT ? b : 0));
        bvh_refit_desc rd;
        bvh_load_desc ld;
        bvh_batch_desc bd;
        bvh_tree t, u;
        bvh_validation rep;
        ta_buf buf;
        bvh_ray rays[256];
        bvh_hit hits[256];
        uint8_t occ[256];
        d.allocator.alloc = ta_alloc;
        d.allocator.free = ta_free;
        d.allocator.user = &ta;
        d.threads = 4;
        if (b == TU_BUILDER_COUNT) d.optimize.rounds = 2; /* the optimizer's threads */
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        assert_int_equal(bvh_validate(&t, NULL, &rep), BVH_SUCCESS);
        memset(&rd, 0, sizeof rd);
        rd.triangles = d.triangles;
        rd.threads = 4;
        assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
        tu_make_rays(s.data, s.tri_count, 5 + (uint64_t)b, rays, 256);
        memset(&bd, 0, sizeof bd);
        bd.threads = 4;
        assert_int_equal(bvh_intersect_batch_ex(&t, rays, hits, 256, &bd), BVH_SUCCESS);
        assert_int_equal(bvh_occluded_batch_ex(&t, rays, occ, 256, &bd), BVH_SUCCESS);
        buf.size = 0;
        buf.cap = bvh_save_size(&t);
        buf.data = (unsigned char *)malloc(buf.cap);
        assert_non_null(buf.data);
        assert_int_equal(bvh_save(&t, ta_write, &buf), BVH_SUCCESS);
        for (int borrow = 0; borrow < 2; borrow++) {
            memset(&ld, 0, sizeof ld);
            ld.data = buf.data;
            ld.size = buf.size;
            ld.borrow = (uint32_t)borrow;
            ld.threads = 4;
            ld.allocator = d.allocator;
            assert_int_equal(bvh_load(&u, &ld), BVH_SUCCESS);
            bvh_free(&u);
        }
        if (b == 0) { /* a scene of two instances of the tree */
            bvh_instance in[2];
            bvh_scene_desc sd;
            bvh_scene sc;
            int k;
            memset(in, 0, sizeof in);
            for (k = 0; k < 2; k++) {
                in[k].tree = &t;
                in[k].transform[0] = in[k].transform[5] = in[k].transform[10] = 1.0f;
                in[k].transform[3] = 30.0f * (float)k;
                in[k].mask = ~0u;
            }
            memset(&sd, 0, sizeof sd);
            sd.instances = in;
            sd.instance_count = 2;
            sd.threads = 4;
            sd.allocator = d.allocator;
            assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
            bvh_scene_free(&sc);
        }
        free(buf.data);
        bvh_free(&t);
    }
    assert_true(ta.calls > 0);
    if (ta.elsewhere) fail_msg("%ld of %ld allocator calls came from another thread", ta.elsewhere, ta.calls);
    tu_scene_free(&s);
}

/* == the pool gives the internal pool's tree ================================================= */
static void pool_same_tree(void **state) {
    static const uint32_t tasks[] = {1, 2, 3, 7};
    int id = tu_state_id(state), b, h;
    size_t k;
    tu_scene s;
    if (!tu_scene_make(id, &s)) skip();
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_builder builder = tu_builder(b);
        bvh_build_desc d = tu_scene_desc(&s, builder);
        bvh_tree ref, t;
        d.threads = 2;
        assert_int_equal(bvh_build(&ref, &d), BVH_SUCCESS);
        for (h = 0; h < 3; h++)
            for (k = 0; k < sizeof tasks / sizeof tasks[0]; k++) {
                pool_state ps;
                const char *diff;
                memset(&ps, 0, sizeof ps);
                ps.order = h;
                ps.workers = 3;
                ps.seed = 7 + k;
                d.pool.run = pool_run;
                d.pool.user = &ps;
                d.threads = tasks[k];
                assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
                diff = tree_diff(&ref, &t);
                if (diff)
                    fail_msg("%s/%s: pool %s with %u tasks: %s differs from the internal pool's", s.name,
                             bvh_builder_name(builder), pool_names[h], tasks[k], diff);
                /* the builders that use threads hand their phases to the pool */
                if (tasks[k] > 1 && s.tri_count >= 64 &&
                    (builder == BVH_BUILDER_PLOC_PARALLEL || builder == BVH_BUILDER_SAH_MIDPOINT) && ps.runs == 0)
                    fail_msg("%s/%s: the pool was never asked to run anything", s.name, bvh_builder_name(builder));
                bvh_free(&t);
            }
        bvh_free(&ref);
    }
    tu_scene_free(&s);
}

/* PLOC over its memory budget (a soup: bvh__fit_budget), with the SAH top off, and the optimizer
   on PLOC and sah-midpoint trees, on a pool; and PLOC on clustered input (3/5 of the vertices
   shrunk to the origin: one top Morton digit holds over a quarter of the keys, so the sort takes its
   LSD passes, each a step of its own on a pool). */
static void pool_same_tree_options(void **state) {
    tu_scene s;
    int v;
    uint32_t i;
    (void)state;
    tu_scene_random(&s, 30000, 0x504f4f4cULL);
    for (v = 0; v < 6; v++) {
        bvh_build_desc d;
        bvh_tree ref, t;
        pool_state ps;
        const char *diff;
        if (v == 5)
            for (i = 0; i < s.vertex_count / 5 * 3; i++) {
                float *p = tu_vertex(&s, i);
                p[0] *= 1e-3f;
                p[1] *= 1e-3f;
                p[2] *= 1e-3f;
            }
        d = tu_scene_desc(&s, v == 4 ? BVH_BUILDER_SAH_MIDPOINT : BVH_BUILDER_PLOC_PARALLEL);
        if (v == 1) d.ploc.top = BVH_OFF;
        if (v == 2) d.ploc.max_bytes_per_prim = 24;
        if (v >= 3) d.optimize.rounds = 3; /* the optimizer's searches run on the pool */
        d.threads = 3;
        assert_int_equal(bvh_build(&ref, &d), BVH_SUCCESS);
        memset(&ps, 0, sizeof ps);
        ps.order = 2;
        ps.workers = 4;
        ps.seed = 99;
        d.pool.run = pool_run;
        d.pool.user = &ps;
        d.threads = 5;
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        diff = tree_diff(&ref, &t);
        if (diff) fail_msg("variant %d: %s differs", v, diff);
        bvh_free(&t);
        bvh_free(&ref);
    }
    tu_scene_free(&s);
}

/* == refit and load through the pool ========================================================= */
/* bvh_refit_desc.pool and bvh_load_desc.pool: the same bytes as the library's threads give, on
   each test pool, for a PLOC tree and a sah-midpoint one (split references): refitted to moved
   vertices; loaded as a copy and borrowed; and loaded with the 8-wide layout made from a file
   saved without it. The pool must have been asked to run something each time. */
static void pool_refit_load_same_tree(void **state) {
    tu_scene s;
    float *moved;
    int b, h, v;
    uint32_t i;
    (void)state;
    tu_scene_random(&s, 20000, 0x52454649ULL);
    moved = (float *)malloc((size_t)s.vertex_count * tu_stride(&s));
    assert_non_null(moved);
    memcpy(moved, s.data, (size_t)s.vertex_count * tu_stride(&s));
    for (i = 0; i < s.vertex_count; i++) { /* a wave along x */
        float *p = (float *)(void *)((char *)(void *)moved + (size_t)i * tu_stride(&s));
        p[1] += 0.05f * sinf(4.0f * p[0]);
    }
    for (b = 0; b < 2; b++)
        for (v = 0; v < 2; v++) {
            bvh_build_desc d = tu_scene_desc(&s, b ? BVH_BUILDER_SAH_MIDPOINT : BVH_BUILDER_PLOC_PARALLEL);
            bvh_refit_desc rd;
            bvh_load_desc ld;
            bvh_tree ref, t, lref, l;
            ta_buf buf;
            const char *diff;
            d.threads = 2;
            d.trace_width = v ? 2 : 0; /* v = 1: saved without the 8-wide layout, made on load */
            assert_int_equal(bvh_build(&ref, &d), BVH_SUCCESS);
            memset(&rd, 0, sizeof rd);
            rd.triangles = d.triangles;
            rd.triangles.positions = moved;
            rd.threads = 3;
            assert_int_equal(bvh_refit(&ref, &rd), BVH_SUCCESS);
            buf.size = 0;
            buf.cap = bvh_save_size(&ref);
            buf.data = (unsigned char *)malloc(buf.cap);
            assert_non_null(buf.data);
            assert_int_equal(bvh_save(&ref, ta_write, &buf), BVH_SUCCESS);
            memset(&ld, 0, sizeof ld);
            ld.data = buf.data;
            ld.size = buf.size;
            ld.threads = 3;
            ld.trace_width = 8;
            assert_int_equal(bvh_load(&lref, &ld), BVH_SUCCESS);
            for (h = 0; h < 3; h++) {
                pool_state ps;
                memset(&ps, 0, sizeof ps);
                ps.order = h;
                ps.workers = 3;
                ps.seed = 11 + (uint64_t)h;
                assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
                rd.pool.run = pool_run;
                rd.pool.user = &ps;
                assert_int_equal(bvh_refit(&t, &rd), BVH_SUCCESS);
                rd.pool.run = NULL;
                if ((diff = tree_diff(&ref, &t)) != NULL || ps.runs == 0)
                    fail_msg("%s refit on pool %s: %s", bvh_builder_name(d.builder), pool_names[h],
                             diff ? diff : "the pool ran nothing");
                bvh_free(&t);
                ld.pool.run = pool_run;
                ld.pool.user = &ps;
                for (ld.borrow = 0; ld.borrow < 2; ld.borrow++) {
                    ps.runs = 0;
                    assert_int_equal(bvh_load(&l, &ld), BVH_SUCCESS);
                    if ((diff = tree_diff(&lref, &l)) != NULL || ps.runs == 0)
                        fail_msg("%s (trace_width %u) loaded %s on pool %s: %s", bvh_builder_name(d.builder),
                                 d.trace_width, ld.borrow ? "borrowed" : "as a copy", pool_names[h],
                                 diff ? diff : "the pool ran nothing");
                    bvh_free(&l);
                }
                ld.borrow = 0;
                ld.pool.run = NULL;
            }
            bvh_free(&lref);
            bvh_free(&ref);
            free(buf.data);
        }
    free(moved);
    tu_scene_free(&s);
}

/* bvh_scene_desc.pool: a scene of 3000 instances (a grid of scaled copies of one tree) builds
   the same top level, binary and 8-wide, on each test pool as on the library's threads. */
static void pool_scene_same_top(void **state) {
    enum { N = 3000 };
    tu_scene s;
    bvh_tree t;
    bvh_build_desc d;
    bvh_instance *in = (bvh_instance *)calloc(N, sizeof *in);
    bvh_scene ref, sc;
    bvh_scene_desc sd;
    int h;
    uint32_t i;
    (void)state;
    assert_non_null(in);
    tu_scene_random(&s, 500, 0x5343454eULL);
    d = tu_scene_desc(&s, BVH_BUILDER_PLOC_PARALLEL);
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    for (i = 0; i < N; i++) {
        const float k = 0.5f + 0.01f * (float)(i % 7);
        in[i].tree = &t;
        in[i].mask = ~0u;
        in[i].id = i;
        in[i].transform[0] = in[i].transform[5] = in[i].transform[10] = k;
        in[i].transform[3] = 3.0f * (float)(i % 15);
        in[i].transform[7] = 3.0f * (float)(i / 15 % 20);
        in[i].transform[11] = 3.0f * (float)(i / 300);
    }
    memset(&sd, 0, sizeof sd);
    sd.instances = in;
    sd.instance_count = N;
    sd.threads = 3;
    assert_int_equal(bvh_scene_build(&ref, &sd), BVH_SUCCESS);
    for (h = 0; h < 3; h++) {
        pool_state ps;
        const char *diff;
        memset(&ps, 0, sizeof ps);
        ps.order = h;
        ps.workers = 3;
        ps.seed = 21 + (uint64_t)h;
        sd.pool.run = pool_run;
        sd.pool.user = &ps;
        assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
        diff = tree_diff(&ref.top, &sc.top);
        if (!diff && (sc.top8_count != ref.top8_count ||
                      memcmp(sc.top8, ref.top8, (size_t)ref.top8_count * sizeof(bvh_node8)) != 0))
            diff = "top8";
        if (diff || ps.runs == 0) fail_msg("scene on pool %s: %s", pool_names[h], diff ? diff : "the pool ran nothing");
        bvh_scene_free(&sc);
    }
    bvh_scene_free(&ref);
    bvh_free(&t);
    tu_scene_free(&s);
    free(in);
}

/* == batch tracing through the pool ========================================================== */
/* A batch test's rays over a random scene's tree, with the library's own threads' hits and flags
   (ref, oref) and room for a pool's (hits, occ). */
typedef struct batch_fixture {
    tu_scene s;
    bvh_tree t;
    float *tris;
    bvh_ray *rays;
    bvh_hit *ref, *hits;
    uint8_t *oref, *occ;
    size_t count;
} batch_fixture;
static void batch_fixture_make(batch_fixture *f, size_t count, uint64_t scene_seed, uint64_t ray_seed, bvh_builder b) {
    bvh_build_desc d;
    f->count = count;
    f->rays = (bvh_ray *)malloc(count * sizeof *f->rays);
    f->ref = (bvh_hit *)malloc(count * sizeof *f->ref);
    f->hits = (bvh_hit *)malloc(count * sizeof *f->hits);
    f->oref = (uint8_t *)malloc(count);
    f->occ = (uint8_t *)malloc(count);
    assert_true(f->rays && f->ref && f->hits && f->oref && f->occ);
    tu_scene_random(&f->s, 5000, scene_seed);
    f->tris = tu_scene_tris(&f->s);
    tu_make_rays(f->tris, f->s.tri_count, ray_seed, f->rays, count);
    d = tu_scene_desc(&f->s, b);
    assert_int_equal(bvh_build(&f->t, &d), BVH_SUCCESS);
    assert_int_equal(bvh_intersect_batch(&f->t, f->rays, f->ref, count, 2), BVH_SUCCESS);
    assert_int_equal(bvh_occluded_batch(&f->t, f->rays, f->oref, count, 2), BVH_SUCCESS);
}
static void batch_fixture_free(batch_fixture *f) {
    bvh_free(&f->t);
    free(f->tris);
    tu_scene_free(&f->s);
    free(f->rays);
    free(f->ref);
    free(f->hits);
    free(f->oref);
    free(f->occ);
}
static void pool_batch_same_hits(void **state) {
    batch_fixture f;
    const size_t count = 5000;
    const bvh_tree *t;
    bvh_ray *rays;
    bvh_hit *ref, *hits;
    uint8_t *oref, *occ;
    int h;
    (void)state;
    batch_fixture_make(&f, count, 0x42415443ULL, 11, BVH_BUILDER_PLOC);
    t = &f.t;
    rays = f.rays;
    ref = f.ref;
    hits = f.hits;
    oref = f.oref;
    occ = f.occ;
    for (h = 0; h < 3; h++) {
        pool_state ps;
        const bvh_batch_desc bd = pool_batch_desc(&ps, h, 5);
        memset(hits, 0xab, count * sizeof *hits);
        memset(occ, 0xab, count);
        assert_int_equal(bvh_intersect_batch_ex(t, rays, hits, count, &bd), BVH_SUCCESS);
        assert_int_equal(bvh_occluded_batch_ex(t, rays, occ, count, &bd), BVH_SUCCESS);
        assert_true(ps.runs >= 2);
        if (memcmp(hits, ref, count * sizeof *hits) != 0) fail_msg("pool %s: other hits", pool_names[h]);
        if (memcmp(occ, oref, count) != 0) fail_msg("pool %s: other occlusion flags", pool_names[h]);
    }
    /* desc NULL: the internal threads */
    assert_int_equal(bvh_intersect_batch_ex(t, rays, hits, count, NULL), BVH_SUCCESS);
    assert_memory_equal(hits, ref, count * sizeof *hits);
    assert_int_equal(bvh_intersect_batch_ex(t, rays, NULL, count, NULL), BVH_ERROR_INVALID_ARGUMENT);
    { /* a scene's batches: two instances of the tree, one moved */
        bvh_instance in[2];
        bvh_scene sc;
        bvh_scene_desc sd;
        bvh_scene_hit *sref = (bvh_scene_hit *)malloc(count * sizeof *sref);
        bvh_scene_hit *shits = (bvh_scene_hit *)malloc(count * sizeof *shits);
        size_t i;
        assert_true(sref && shits);
        memset(in, 0, sizeof in);
        memset(&sd, 0, sizeof sd);
        in[0].tree = in[1].tree = t;
        in[0].mask = in[1].mask = ~0u;
        in[0].transform[0] = in[0].transform[5] = in[0].transform[10] = 1.0f;
        in[1].transform[0] = in[1].transform[5] = in[1].transform[10] = 1.0f;
        in[1].transform[3] = 0.25f;
        in[1].id = 7;
        sd.instances = in;
        sd.instance_count = 2;
        assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
        for (i = 0; i < count; i++) {
            bvh_scene_intersect(&sc, &rays[i], ~0u, &sref[i]);
            oref[i] = (uint8_t)bvh_scene_occluded(&sc, &rays[i], ~0u);
        }
        for (h = 0; h < 3; h++) {
            pool_state ps;
            const bvh_batch_desc bd = pool_batch_desc(&ps, h, 9);
            memset(shits, 0xab, count * sizeof *shits);
            memset(occ, 0xab, count);
            assert_int_equal(bvh_scene_intersect_batch(&sc, rays, ~0u, shits, count, &bd), BVH_SUCCESS);
            assert_int_equal(bvh_scene_occluded_batch(&sc, rays, ~0u, occ, count, &bd), BVH_SUCCESS);
            assert_true(ps.runs >= 2);
            if (memcmp(shits, sref, count * sizeof *shits) != 0) fail_msg("pool %s: other scene hits", pool_names[h]);
            if (memcmp(occ, oref, count) != 0) fail_msg("pool %s: other scene occlusion flags", pool_names[h]);
        }
        bvh_scene_free(&sc);
        free(sref);
        free(shits);
    }
    batch_fixture_free(&f);
}

/* == examples/workers.h: one set of workers for many runs ======================================= */
/* Every builder on the workers gives the internal pool's tree; then 300 batch calls in a row
   (closest and any hit, 1 to 5000 rays, so that runs of one task and of many follow each other
   with the workers asleep or still leaving) give the internal pool's hits and flags. */
static void workers_same_results(void **state) {
    const size_t count = 5000;
    batch_fixture f;
    workers w;
    int b, k;
    (void)state;
    assert_int_equal(workers_start(&w, 4), 0);
    assert_int_equal(w.threads, 3);
    batch_fixture_make(&f, count, 0x574f524bULL, 13, BVH_BUILDER_PLOC_PARALLEL);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d = tu_scene_desc(&f.s, tu_builder(b));
        bvh_tree r2, t;
        const char *diff;
        d.threads = 3;
        assert_int_equal(bvh_build(&r2, &d), BVH_SUCCESS);
        d.pool = workers_pool(&w);
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        diff = tree_diff(&r2, &t);
        if (diff) fail_msg("%s on the workers: %s differs from the internal pool's", bvh_builder_name(d.builder), diff);
        bvh_free(&t);
        bvh_free(&r2);
    }
    for (k = 0; k < 300; k++) {
        bvh_batch_desc bd;
        const size_t n = k % 3 == 0 ? count : (size_t)(1 + (k * 37) % 700), first = (size_t)(k * 11) % (count - n + 1);
        memset(&bd, 0, sizeof bd);
        bd.pool = workers_pool(&w);
        bd.threads = 1 + (uint32_t)k % 4;
        memset(f.hits, 0xab, n * sizeof *f.hits);
        memset(f.occ, 0xab, n);
        if (k % 2) {
            assert_int_equal(bvh_intersect_batch_ex(&f.t, f.rays + first, f.hits, n, &bd), BVH_SUCCESS);
            if (memcmp(f.hits, f.ref + first, n * sizeof *f.hits) != 0)
                fail_msg("call %d (%zu rays): other hits", k, n);
        } else {
            assert_int_equal(bvh_occluded_batch_ex(&f.t, f.rays + first, f.occ, n, &bd), BVH_SUCCESS);
            if (memcmp(f.occ, f.oref + first, n) != 0) fail_msg("call %d (%zu rays): other occlusion flags", k, n);
        }
    }
    workers_stop(&w);
    batch_fixture_free(&f);
}

/* == progress and cancel ===================================================================== */
typedef struct prog_state {
    uint32_t calls, cancel_at; /* cancel_at: return nonzero at that call (1-based), 0 never */
    uint32_t ones;             /* calls with fraction 1 */
    float last;
    int rising;             /* every fraction in [0, 1] and >= the one before */
    double t_last, max_gap; /* seconds */
} prog_state;
static double now_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}
static int on_progress(void *user, float f) {
    prog_state *p = (prog_state *)user;
    double t = now_s();
    if (p->calls && t - p->t_last > p->max_gap) p->max_gap = t - p->t_last;
    p->t_last = t;
    p->calls++;
    if (!(f >= 0.0f && f <= 1.0f && f >= p->last)) p->rising = 0;
    p->last = f;
    if (f == 1.0f) p->ones++;
    return p->cancel_at && p->calls == p->cancel_at;
}
static void prog_init(prog_state *p, uint32_t cancel_at) {
    memset(p, 0, sizeof *p);
    p->cancel_at = cancel_at;
    p->rising = 1;
    p->t_last = now_s();
}

/* A build on 2 threads that reports to p and allocates through ca. */
static void watch_build(bvh_build_desc *d, prog_state *p, count_alloc *ca) {
    d->threads = 2;
    d->progress = on_progress;
    d->progress_user = p;
    d->allocator.alloc = ca_alloc;
    d->allocator.free = ca_free;
    d->allocator.user = ca;
}

/* For every builder, with and without a pool: a completed build reports rising fractions ending
   in one 1; a cancel at each call k in turn returns BVH_ERROR_CANCELLED, an empty tree and no
   block left allocated. */
static void progress_cancel_every_call(void **state) {
    tu_scene s;
    int b, pooled;
    (void)state;
    tu_scene_random(&s, 40000, 0x43414e43ULL);
    for (b = 0; b < TU_BUILDER_COUNT; b++)
        for (pooled = 0; pooled < 2; pooled++) {
            bvh_builder builder = tu_builder(b);
            bvh_build_desc d = tu_scene_desc(&s, builder);
            pool_state ps;
            prog_state p;
            count_alloc ca = {0};
            bvh_tree t;
            uint32_t total, k, step;
            memset(&ps, 0, sizeof ps);
            ps.order = 1;
            ps.workers = 2;
            if (pooled) {
                d.pool.run = pool_run;
                d.pool.user = &ps;
            }
            watch_build(&d, &p, &ca);
            prog_init(&p, 0);
            assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
            if (!p.rising || p.ones != 1 || p.last != 1.0f || p.calls < 3)
                fail_msg("%s (pool %d): %u calls, rising %d, %u ones, last %g", bvh_builder_name(builder), pooled,
                         p.calls, p.rising, p.ones, (double)p.last);
            bvh_free(&t);
            assert_int_equal(ca.live, 0);
            total = p.calls;
            /* every call up to the last before 1 (a cancel at 1 comes too late: the build is done);
               on long call sequences every step-th and the last ten */
            step = total > 60 ? total / 40 : 1;
            for (k = 1; k < total; k += (k + 10 < total ? step : 1)) {
                bvh_result r;
                prog_init(&p, k);
                r = bvh_build(&t, &d);
                if (r != BVH_ERROR_CANCELLED)
                    fail_msg("%s (pool %d): cancel at call %u of %u gave %s", bvh_builder_name(builder), pooled, k,
                             total, bvh_result_string(r));
                if (p.calls != k)
                    fail_msg("%s: called again (%u times) after the cancel at %u", bvh_builder_name(builder), p.calls,
                             k);
                assert_null(t.nodes);
                assert_null(t.prims);
                assert_null(t.tris);
                assert_null(t.nodes8);
                assert_int_equal(t.node_count, 0);
                if (ca.live != 0)
                    fail_msg("%s (pool %d): cancel at %u leaked %ld blocks", bvh_builder_name(builder), pooled, k,
                             ca.live);
            }
            /* a cancel returned with the final 1 is too late: the build stands */
            prog_init(&p, total);
            assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
            bvh_free(&t);
        }
    tu_scene_free(&s);
}

/* The empty build and a box build report too; a cancel at the first call stops even those. */
static void progress_small_builds(void **state) {
    bvh_build_desc d;
    bvh_tree t;
    prog_state p;
    bvh_aabb boxes[3] = {{{0, 0, 0}, {1, 1, 1}}, {{2, 0, 0}, {3, 1, 1}}, {{0, 2, 0}, {1, 3, 1}}};
    (void)state;
    memset(&d, 0, sizeof d);
    d.progress = on_progress;
    d.progress_user = &p;
    prog_init(&p, 0);
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    assert_true(p.rising && p.ones == 1);
    d.boxes = boxes;
    d.box_count = 3;
    prog_init(&p, 0);
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    assert_true(p.rising && p.ones == 1 && p.calls >= 3);
    bvh_free(&t);
    prog_init(&p, 1);
    assert_int_equal(bvh_build(&t, &d), BVH_ERROR_CANCELLED);
    assert_int_equal(t.node_count, 0);
    assert_string_equal(bvh_result_string(BVH_ERROR_CANCELLED), "the build was cancelled by its progress callback");
}

/* How often: on 200K random triangles, every builder calls at least once per 65536 primitives
   of input, counted against the work. The longest gap in wall-clock time is printed, never
   checked: a test cannot own the clock of a shared CI machine (a loaded one saw 298 ms in a
   build whose gaps are 20 ms when quiet). */
static void progress_cadence(void **state) {
    tu_scene s;
    int b;
    (void)state;
    tu_scene_random(&s, 200000, 0x434144ULL);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_builder builder = tu_builder(b);
        bvh_build_desc d = tu_scene_desc(&s, builder);
        prog_state p;
        bvh_tree t;
        double t0 = now_s(), took;
        d.progress = on_progress;
        d.progress_user = &p;
        prog_init(&p, 0);
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        took = now_s() - t0;
        print_message("%-14s %3u calls in %6.1f ms, longest gap %5.1f ms\n", bvh_builder_name(builder), p.calls,
                      1e3 * took, 1e3 * p.max_gap);
        if (p.calls < s.tri_count / 65536 + 3) fail_msg("%s: only %u calls", bvh_builder_name(builder), p.calls);
        bvh_free(&t);
    }
    tu_scene_free(&s);
}

/* The sanitizers slow some loops tenfold: the slowest scenes are left out under them. */
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define POOL_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define POOL_SANITIZED 1
#endif
#endif
#ifndef POOL_SANITIZED
#define POOL_SANITIZED 0
#endif

/* sah-midpoint on the threads: byte for byte the 1-thread tree on 2, 3 and 8 threads and on a
   pool (shuffled, 5 tasks), with reference splits (the default), without (split_budget off) and
   in the study's variant (bins off), on random triangles, random triangles of which every tenth
   is a long sliver (also with a small split budget) and the bunny (not under the sanitizers:
   slow there). The scenes take the rare paths (sm_events) at least once each (a subtree built
   again: the bunny's). */
static void sah_midpoint_threads_same_tree(void **state) {
    static const uint32_t threads[] = {2, 3, 8};
    tu_scene sc[3];
    int ns = 0, i, v;
    size_t k;
    (void)state;
    tu_scene_random(&sc[ns++], 20000, 0x534d5041ULL);
    tu_scene_random(&sc[ns], 3000, 0x534d5042ULL);
    for (k = 0; k < sc[ns].tri_count; k += 10) { /* slivers: splits pay at the top nodes */
        float *p = tu_vertex(&sc[ns], 3 * (uint32_t)k), *q = tu_vertex(&sc[ns], 3 * (uint32_t)k + 1);
        tu_set3(p, q[0] + 40 * (p[0] - q[0]), q[1] + 40 * (p[1] - q[1]), q[2] + 40 * (p[2] - q[2]));
    }
    ns++;
    if (!POOL_SANITIZED && tu_scene_bunny(&sc[ns])) ns++;
    memset(&sm_events, 0, sizeof sm_events);
    for (i = 0; i < ns; i++)
        for (v = 0; v < (i == 1 ? 4 : 3); v++) {
            bvh_build_desc d = tu_scene_desc(&sc[i], BVH_BUILDER_SAH_MIDPOINT);
            bvh_tree ref, t;
            pool_state ps;
            const char *diff;
            if (v == 1) d.sah_midpoint.split_budget = BVH_OFF;
            if (v == 2) d.sah_midpoint.bins = BVH_OFF;
            if (v == 3) d.sah_midpoint.split_budget = 0.02f; /* budgets bind: phase A starts again serially */
            d.threads = 1;
            assert_int_equal(bvh_build(&ref, &d), BVH_SUCCESS);
            for (k = 0; k <= sizeof threads / sizeof threads[0]; k++) {
                memset(&ps, 0, sizeof ps);
                if (k == sizeof threads / sizeof threads[0]) { /* the pool */
                    ps.order = 2;
                    ps.workers = 3;
                    ps.seed = 17 + (uint64_t)v;
                    d.pool.run = pool_run;
                    d.pool.user = &ps;
                    d.threads = 5;
                } else
                    d.threads = threads[k];
                assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
                diff = tree_diff(&ref, &t);
                if (diff)
                    fail_msg("%u triangles, variant %d, %u threads%s: %s differs from 1 thread's", sc[i].tri_count, v,
                             d.threads, d.pool.run ? " (pool)" : "", diff);
                if (d.pool.run && ps.runs == 0) fail_msg("the pool was never asked to run anything");
                bvh_free(&t);
            }
            bvh_free(&ref);
        }
    print_message("sah-midpoint: %u subtrees built again, %u builds started again serially\n", sm_events.rebuilt,
                  sm_events.serial);
    if (ns == 3) assert_true(sm_events.rebuilt > 0); /* the bunny's subtrees (random ones rarely) */
    assert_true(sm_events.serial > 0);
    for (i = 0; i < ns; i++) tu_scene_free(&sc[i]);
}

/* The optimizer's budget: a build with k rounds reports exactly k more times than without (one
   report per round; plus the collapse's for a builder without one of its own), and a cancel at any of its calls returns
   BVH_ERROR_CANCELLED with nothing leaked; for a builder that collapses its own tree (PLOC) and
   one whose tree is optimized after it (top-down). */
static void progress_optimizer_rounds(void **state) {
    static const bvh_builder builders[] = {BVH_BUILDER_PLOC_PARALLEL, BVH_BUILDER_TOP_DOWN};
    tu_scene s;
    size_t b;
    (void)state;
    tu_scene_random(&s, 20000, 0x4f505452ULL);
    for (b = 0; b < sizeof builders / sizeof builders[0]; b++) {
        bvh_build_desc d = tu_scene_desc(&s, builders[b]);
        count_alloc ca = {0};
        prog_state p;
        bvh_tree t;
        uint32_t plain, k;
        watch_build(&d, &p, &ca);
        prog_init(&p, 0);
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        bvh_free(&t);
        plain = p.calls;
        d.optimize.rounds = 5;
        prog_init(&p, 0);
        assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
        bvh_free(&t);
        /* top-down has no collapse of its own: the one after the optimizer reports once more */
        plain += builders[b] == BVH_BUILDER_TOP_DOWN;
        if (p.calls != plain + 5 || !p.rising || p.ones != 1)
            fail_msg("%s: %u calls with 5 rounds, %u without (rising %d, %u ones)", bvh_builder_name(builders[b]),
                     p.calls, plain, p.rising, p.ones);
        for (k = 1; k < plain + 5; k++) {
            prog_init(&p, k);
            assert_int_equal(bvh_build(&t, &d), BVH_ERROR_CANCELLED);
            assert_null(t.nodes);
            assert_int_equal(ca.live, 0);
        }
    }
    tu_scene_free(&s);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        TU_EVERY_SCENE(pool_same_tree),
        cmocka_unit_test(pool_same_tree_options),
        cmocka_unit_test(pool_refit_load_same_tree),
        cmocka_unit_test(pool_scene_same_top),
        cmocka_unit_test(allocator_on_calling_thread),
        cmocka_unit_test(sah_midpoint_threads_same_tree),
        cmocka_unit_test(pool_batch_same_hits),
        cmocka_unit_test(workers_same_results),
        cmocka_unit_test(progress_small_builds),
        cmocka_unit_test(progress_cancel_every_call),
        cmocka_unit_test(progress_cadence),
        cmocka_unit_test(progress_optimizer_rounds),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
