/* tests/test_custom.c - custom primitives and secondary rays.

   Custom primitives: spheres built as boxes by every builder and traced with a callback
   (bvh_intersect_custom, bvh_occluded_custom, the batch calls on 1, 2 and 3 threads and on two
   pools of the _ex calls) give exactly
   the hits of a brute-force loop over all spheres with the same callback (the same sphere, the
   same bits of t), exact ties (duplicated spheres) to the lowest index; a callback's t outside
   [tmin, tmax], NaN or infinite is ignored; a triangle tree traced with a callback that runs the
   built-in triangle test gives bvh_intersect's hits; NULL arguments miss or are refused.
   Secondary rays: shadow rays from hit points of a closed mesh, at unit scale, 1e3 and 1e5 from
   the origin and at small scale, never hit the mesh again from bvh_offset_origin's point (and do
   without it); bvh_hit_surface's point, normal and error codes; bvh_offset_origin moves each
   coordinate the way n says. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"
#include "test_util.h"

#include <pthread.h>

#define SPHERES 3000
#define DUPLICATES 300 /* spheres SPHERES - DUPLICATES .. SPHERES - 1 repeat the first ones */
#define SPHERE_RAYS 6000

typedef struct sphere {
    float c[3], r;
} sphere;

/* The nearest t in [tmin, tmax] on the sphere (the far root from inside it); u = the number of
   calls, so that a test sees the callback ran. */
static int hit_sphere(const bvh_ray *ray, uint32_t i, void *user, bvh_hit *hit) {
    const sphere *s = (const sphere *)user + i;
    float oc[3] = {ray->origin.x - s->c[0], ray->origin.y - s->c[1], ray->origin.z - s->c[2]};
    float a = ray->dir.x * ray->dir.x + ray->dir.y * ray->dir.y + ray->dir.z * ray->dir.z;
    float b = oc[0] * ray->dir.x + oc[1] * ray->dir.y + oc[2] * ray->dir.z;
    float c = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - s->r * s->r;
    float disc = b * b - a * c, t;
    if (disc < 0.0f) return 0;
    t = (-b - sqrtf(disc)) / a;
    if (t < ray->tmin) t = (-b + sqrtf(disc)) / a;
    if (!(t >= ray->tmin && t <= ray->tmax)) return 0;
    hit->t = t;
    hit->u = (float)i;
    hit->v = 0.5f;
    return 1;
}

/* The brute-force loop with the traversal's rules: the callback sees tmax = the best t so far, a
   t outside [tmin, tmax], NaN or infinite is no hit, and the first of equal t (the lowest index)
   wins. */
static int brute(const bvh_custom_desc *cd, uint32_t n, const bvh_ray *ray, bvh_hit *best) {
    bvh_ray r = *ray;
    uint32_t i;
    best->t = ray->tmax;
    best->u = best->v = 0.0f;
    best->prim = BVH_INVALID;
    if (r.tmin > r.tmax || !(r.dir.x != 0.0f || r.dir.y != 0.0f || r.dir.z != 0.0f)) return 0;
    for (i = 0; i < n; i++) {
        bvh_hit h;
        h.t = r.tmax;
        h.u = h.v = 0.0f;
        h.prim = i;
        if (!cd->intersect(&r, i, cd->user, &h)) continue;
        if (!(h.t >= r.tmin && h.t <= r.tmax && h.t < BVH_INF)) continue;
        if (h.t == r.tmax && best->prim != BVH_INVALID) continue;
        h.prim = i;
        *best = h;
        r.tmax = h.t;
    }
    return best->prim != BVH_INVALID;
}

static void make_spheres(sphere *s, bvh_aabb *boxes, uint32_t n) {
    tu_rng r = tu_rng_make(0x5350484552ULL);
    uint32_t i;
    for (i = 0; i < n; i++) {
        if (i >= n - DUPLICATES) {
            s[i] = s[i - (n - DUPLICATES)];
        } else {
            s[i].c[0] = tu_range(&r, -10, 10);
            s[i].c[1] = tu_range(&r, -10, 10);
            s[i].c[2] = tu_range(&r, -10, 10);
            s[i].r = tu_range(&r, 0.05f, 0.6f);
        }
        boxes[i].min = tu_v3(s[i].c[0] - s[i].r, s[i].c[1] - s[i].r, s[i].c[2] - s[i].r);
        boxes[i].max = tu_v3(s[i].c[0] + s[i].r, s[i].c[1] + s[i].r, s[i].c[2] + s[i].r);
    }
}
/* Rays of five kinds: anywhere in and around the spheres; from outside at a sphere's centre (tmax
   1: the centre, inside it); axis-parallel with +-0.0 components; from a sphere's centre; a
   finite tmax and sometimes tmin > 0. */
static void make_sphere_rays(const sphere *s, uint32_t n, bvh_ray *rays, size_t count) {
    tu_rng r = tu_rng_make(0x5241595300ULL);
    bvh_aabb b;
    size_t i;
    b.min = tu_v3(-12, -12, -12);
    b.max = tu_v3(12, 12, 12);
    for (i = 0; i < count; i++) {
        bvh_ray *ray = &rays[i];
        const sphere *t = &s[tu_below(&r, n)];
        ray->tmin = 0.0f;
        ray->tmax = BVH_INF;
        ray->origin = tu_point_in(&r, b, 0.2f);
        ray->dir = tu_sphere_dir(&r);
        switch (i % 5) {
        case 1:
            ray->dir = tu_sub(tu_v3(t->c[0], t->c[1], t->c[2]), ray->origin);
            if (i % 10 == 1) ray->tmax = 1.0f;
            break;
        case 2:
            ray->dir = tu_axis_dir(&r, (int)tu_below(&r, 3));
            break;
        case 3:
            ray->origin = tu_v3(t->c[0], t->c[1], t->c[2]);
            break;
        case 4:
            ray->tmax = tu_range(&r, 0.0f, 20.0f);
            if (tu_u32(&r) & 1) ray->tmin = tu_range(&r, 0.0f, ray->tmax);
            break;
        default:
            break;
        }
    }
}

static int same_hit(const bvh_hit *a, const bvh_hit *b) { return tu_hit_equal(a, b); }

/* Pools for the _ex batch calls: 0 runs the tasks last to first on the calling thread, 1 on two
   pthreads of its own (even tasks on one, odd on the other); runs counts its calls. */
typedef struct cpool {
    int kind, runs;
    bvh_task_fn task;
    void *arg;
    uint32_t count;
} cpool;
static void *cpool_odd(void *p) {
    cpool *c = (cpool *)p;
    uint32_t i;
    for (i = 1; i < c->count; i += 2) c->task(c->arg, i);
    return NULL;
}
static void cpool_run(void *user, uint32_t count, bvh_task_fn task, void *arg) {
    cpool *c = (cpool *)user;
    uint32_t i;
    pthread_t th;
    c->runs++;
    if (c->kind == 0) {
        for (i = count; i-- > 0;) task(arg, i);
        return;
    }
    c->task = task;
    c->arg = arg;
    c->count = count;
    assert_int_equal(pthread_create(&th, NULL, cpool_odd, c), 0);
    for (i = 0; i < count; i += 2) task(arg, i);
    pthread_join(th, NULL);
}

/* Every builder: closest hit, any hit and the batch calls equal the brute force. */
static void spheres_exact(void **state) {
    static sphere s[SPHERES];
    static bvh_aabb boxes[SPHERES];
    bvh_custom_desc cd;
    bvh_ray *rays = (bvh_ray *)malloc(SPHERE_RAYS * sizeof *rays);
    bvh_hit *want = (bvh_hit *)malloc(SPHERE_RAYS * sizeof *want), *got = (bvh_hit *)malloc(SPHERE_RAYS * sizeof *got);
    uint8_t *occ = (uint8_t *)malloc(SPHERE_RAYS);
    size_t i, hits = 0, ties = 0;
    int b;
    (void)state;
    assert_true(rays && want && got && occ);
    make_spheres(s, boxes, SPHERES);
    make_sphere_rays(s, SPHERES - DUPLICATES, rays, SPHERE_RAYS);
    cd.intersect = hit_sphere;
    cd.user = s;
    for (i = 0; i < SPHERE_RAYS; i++) {
        bvh_hit h;
        hits += brute(&cd, SPHERES, &rays[i], &want[i]);
        /* the duplicate of the winner would tie: the brute force keeps the lower index */
        if (want[i].prim != BVH_INVALID && want[i].prim < DUPLICATES) ties++;
        (void)h;
    }
    print_message("spheres: %zu of %d rays hit, %zu of them a sphere that has a duplicate\n", hits, SPHERE_RAYS, ties);
    assert_true(hits > SPHERE_RAYS / 4 && ties > 0);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d;
        bvh_tree tree;
        size_t bad = 0;
        uint32_t threads;
        memset(&d, 0, sizeof d);
        d.builder = tu_builder(b);
        d.boxes = boxes;
        d.box_count = SPHERES;
        assert_int_equal(bvh_build(&tree, &d), BVH_SUCCESS);
        for (i = 0; i < SPHERE_RAYS; i++) {
            bvh_hit h;
            int found = bvh_intersect_custom(&tree, &rays[i], &h, &cd);
            int blocked = bvh_occluded_custom(&tree, &rays[i], &cd);
            int want_found = want[i].prim != BVH_INVALID;
            if (found == want_found && same_hit(&h, &want[i]) && blocked == want_found) continue;
            if (bad++ < 4) {
                print_error("%s: ray %zu: custom %d occluded %d brute force %d\n", bvh_builder_name(d.builder), i,
                            found, blocked, want_found);
                tu_print_ray(&rays[i]);
                tu_print_hit("bvh", &h);
                tu_print_hit("brute force", &want[i]);
            }
        }
        for (threads = 1; threads <= 5; threads++) { /* 4, 5: on a pool (bvh_batch_desc) */
            if (threads <= 3) {
                assert_int_equal(bvh_intersect_custom_batch(&tree, rays, got, SPHERE_RAYS, threads, &cd), BVH_SUCCESS);
                assert_int_equal(bvh_occluded_custom_batch(&tree, rays, occ, SPHERE_RAYS, threads, &cd), BVH_SUCCESS);
            } else {
                cpool cp;
                bvh_batch_desc bd;
                memset(&cp, 0, sizeof cp);
                memset(&bd, 0, sizeof bd);
                cp.kind = (int)threads - 4;
                bd.threads = 3;
                bd.pool.run = cpool_run;
                bd.pool.user = &cp;
                memset(got, 0xab, SPHERE_RAYS * sizeof *got);
                memset(occ, 0xab, SPHERE_RAYS);
                assert_int_equal(bvh_intersect_custom_batch_ex(&tree, rays, got, SPHERE_RAYS, &cd, &bd), BVH_SUCCESS);
                assert_int_equal(bvh_occluded_custom_batch_ex(&tree, rays, occ, SPHERE_RAYS, &cd, &bd), BVH_SUCCESS);
                assert_int_equal(cp.runs, 2);
            }
            for (i = 0; i < SPHERE_RAYS; i++)
                bad += !same_hit(&got[i], &want[i]) + (occ[i] != (want[i].prim != BVH_INVALID));
        }
        if (bad) fail_msg("%s: %zu mismatches with the brute force", bvh_builder_name(d.builder), bad);
        /* the box tree has nothing for the triangle calls, as documented */
        assert_int_equal(bvh_intersect(&tree, &rays[0], got), 0);
        bvh_free(&tree);
    }
    free(rays);
    free(want);
    free(got);
    free(occ);
}

/* A callback that reports nonsense: t outside [tmin, tmax], NaN, +inf, a t beyond tmax; none of
   them is a hit, and the genuine hits of the others still equal the brute force. */
static int hit_liar(const bvh_ray *ray, uint32_t i, void *user, bvh_hit *hit) {
    int r = hit_sphere(ray, i, user, hit);
    switch (i % 5) {
    case 0:
        hit->t = NAN;
        return 1;
    case 1:
        hit->t = ray->tmin - 1.0f;
        return 1;
    case 2:
        hit->t = BVH_INF;
        return 1;
    case 3:
        hit->t = ray->tmax * 2.0f + 1.0f;
        return 1;
    default:
        return r;
    }
}
static void bad_callback_t_ignored(void **state) {
    static sphere s[SPHERES];
    static bvh_aabb boxes[SPHERES];
    bvh_custom_desc cd;
    bvh_build_desc d;
    bvh_tree tree;
    bvh_ray rays[2000];
    size_t i, hits = 0;
    (void)state;
    make_spheres(s, boxes, SPHERES);
    make_sphere_rays(s, SPHERES - DUPLICATES, rays, 2000);
    cd.intersect = hit_liar;
    cd.user = s;
    memset(&d, 0, sizeof d);
    d.boxes = boxes;
    d.box_count = SPHERES;
    assert_int_equal(bvh_build(&tree, &d), BVH_SUCCESS);
    for (i = 0; i < 2000; i++) {
        bvh_hit h, w;
        int found = bvh_intersect_custom(&tree, &rays[i], &h, &cd);
        assert_int_equal(found, brute(&cd, SPHERES, &rays[i], &w));
        assert_true(same_hit(&h, &w));
        if (found) assert_int_equal(h.prim % 5, 4);
        hits += (size_t)found;
    }
    assert_true(hits > 0);
    bvh_free(&tree);
}

/* On a triangle tree the callback replaces the built-in test: running that test in it gives
   bvh_intersect's hits, for every builder and for the trees with and without the 8-wide copy. */
static int hit_triangle(const bvh_ray *ray, uint32_t i, void *user, bvh_hit *hit) {
    const float *t = (const float *)user + 9 * (size_t)i;
    return bvh_intersect_triangle(ray, t, t + 3, t + 6, hit);
}
static void triangle_tree_by_callback(void **state) {
    int id = tu_state_id(state), b;
    tu_scene s;
    float *tris;
    bvh_ray rays[3000];
    bvh_custom_desc cd;
    if (!tu_scene_make(id, &s)) {
        skip();
        return;
    }
    tris = tu_scene_tris(&s);
    tu_make_rays(tris, s.tri_count, 0x435553ULL, rays, 3000);
    cd.intersect = hit_triangle;
    cd.user = tris;
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
        bvh_tree tree;
        size_t i, bad = 0;
        assert_int_equal(bvh_build(&tree, &d), BVH_SUCCESS);
        for (i = 0; i < 3000; i++) {
            bvh_hit h, w;
            int found = bvh_intersect_custom(&tree, &rays[i], &h, &cd), want = bvh_intersect(&tree, &rays[i], &w);
            if (found == want && same_hit(&h, &w) && bvh_occluded_custom(&tree, &rays[i], &cd) == want) continue;
            if (bad++ < 3) {
                tu_print_ray(&rays[i]);
                tu_print_hit("custom", &h);
                tu_print_hit("bvh_intersect", &w);
            }
        }
        if (bad) fail_msg("%s/%s: %zu rays differ", s.name, bvh_builder_name(d.builder), bad);
        bvh_free(&tree);
    }
    free(tris);
    tu_scene_free(&s);
}

static void custom_arguments(void **state) {
    static sphere s[16];
    static bvh_aabb boxes[16];
    bvh_custom_desc cd = {hit_sphere, s}, none = {NULL, s};
    bvh_build_desc d;
    bvh_tree tree, empty;
    bvh_ray ray = {{-20, 0.1f, 0.2f}, 0.0f, {1, 0, 0}, 100.0f}, nan_ray = ray;
    bvh_hit h, hits[2];
    uint8_t occ[2];
    (void)state;
    make_spheres(s, boxes, 16);
    memset(&d, 0, sizeof d);
    d.boxes = boxes;
    d.box_count = 16;
    assert_int_equal(bvh_build(&tree, &d), BVH_SUCCESS);
    memset(&empty, 0, sizeof empty);
    /* NULL callback, desc, tree or ray: a miss with the miss record */
    h.prim = 7;
    assert_int_equal(bvh_intersect_custom(&tree, &ray, &h, &none), 0);
    assert_int_equal(h.prim, BVH_INVALID);
    assert_true(h.t == ray.tmax);
    assert_int_equal(bvh_intersect_custom(&tree, &ray, &h, NULL), 0);
    assert_int_equal(bvh_intersect_custom(NULL, &ray, &h, &cd), 0);
    assert_int_equal(bvh_intersect_custom(&tree, NULL, &h, &cd), 0);
    assert_int_equal(h.prim, BVH_INVALID);
    assert_int_equal(bvh_occluded_custom(&tree, &ray, &none), 0);
    assert_int_equal(bvh_occluded_custom(&tree, &ray, NULL), 0);
    assert_int_equal(bvh_intersect_custom(&empty, &ray, &h, &cd), 0);
    assert_int_equal(bvh_intersect_custom(&tree, &ray, NULL, &cd), bvh_occluded_custom(&tree, &ray, &cd));
    nan_ray.dir.y = NAN;
    assert_int_equal(bvh_intersect_custom(&tree, &nan_ray, &h, &cd), 0);
    /* batch calls: a code */
    assert_int_equal(bvh_intersect_custom_batch(&tree, &ray, hits, 1, 1, &none), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_intersect_custom_batch(&tree, &ray, hits, 1, 1, NULL), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_intersect_custom_batch(NULL, &ray, hits, 1, 1, &cd), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_intersect_custom_batch(&tree, NULL, hits, 1, 1, &cd), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_intersect_custom_batch(&tree, &ray, NULL, 1, 1, &cd), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_occluded_custom_batch(&tree, &ray, occ, 1, 1, &none), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_occluded_custom_batch(&tree, &ray, NULL, 1, 1, &cd), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_intersect_custom_batch(&tree, NULL, NULL, 0, 1, &cd), BVH_SUCCESS);
    assert_int_equal(bvh_intersect_custom_batch_ex(&tree, &ray, hits, 1, NULL, NULL), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_occluded_custom_batch_ex(&tree, &ray, NULL, 1, &cd, NULL), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_occluded_custom_batch_ex(&tree, &ray, occ, 1, &cd, NULL), BVH_SUCCESS);
    assert_int_equal(bvh_intersect_custom_batch(&empty, &ray, hits, 1, 0, &cd), BVH_SUCCESS);
    assert_int_equal(hits[0].prim, BVH_INVALID);
    bvh_free(&tree);
}

/* == secondary rays ========================================================================= */
/* A closed UV sphere of radius `scale` around `centre` (n x 2n quads, poles as fans). */
static void make_ball(tu_scene *s, float scale, float centre, uint32_t n) {
    uint32_t i, j, t = 0, nv = (n + 1) * (2 * n + 1);
    const float pi = 3.14159265f;
    tu_scene_alloc(s, "ball", nv, 0, 3 * 2 * n * 2 * n);
    for (j = 0; j <= n; j++)
        for (i = 0; i <= 2 * n; i++) {
            float th = pi * (float)j / (float)n, ph = pi * (float)i / (float)n;
            float *p = tu_vertex(s, j * (2 * n + 1) + i);
            /* seam and poles: the same vertex bits as their twins, so the mesh is closed */
            if (i == 2 * n) ph = 0.0f;
            if (j == 0 || j == n) ph = 0.0f;
            tu_set3(p, centre + scale * sinf(th) * cosf(ph), centre + scale * cosf(th),
                    centre + scale * sinf(th) * sinf(ph));
        }
    for (j = 0; j < n; j++)
        for (i = 0; i < 2 * n; i++) {
            uint32_t a = j * (2 * n + 1) + i, b = a + 1, c = a + 2 * n + 1, d = c + 1;
            uint32_t *q = s->indices + 3 * (size_t)t;
            q[0] = a;
            q[1] = c;
            q[2] = b;
            q[3] = b;
            q[4] = c;
            q[5] = d;
            t += 2;
        }
    s->tri_count = t;
}
static bvh_vec3 scaled(bvh_vec3 v, float k) { return tu_v3(v.x * k, v.y * k, v.z * k); }
static float dot3(bvh_vec3 a, bvh_vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

/* Primary rays from outside the ball hit it; from each hit point a ray leaves into the
   hemisphere the hit side faces. The ball is convex, so any hit of such a ray is the surface
   hitting itself. */
static void offset_no_self_hits(void **state) {
    static const float scales[][2] = {{1, 0},     {1, 1e3f},  {1, 1e5f},     {100, 1e5f},
                                      {1e-3f, 0}, {1e-3f, 1}, {1e-4f, 1e-2f}};
    size_t k, raw_total = 0;
    (void)state;
    for (k = 0; k < sizeof scales / sizeof scales[0]; k++) {
        tu_scene s;
        bvh_tree tree;
        bvh_build_desc d;
        tu_rng r = tu_rng_make(0x4f4646ULL + k);
        float sc = scales[k][0], c = scales[k][1];
        size_t i, raw = 0, offset = 0, primary = 0;
        make_ball(&s, sc, c, 24);
        d = tu_scene_desc(&s, BVH_BUILDER_DEFAULT);
        assert_int_equal(bvh_build(&tree, &d), BVH_SUCCESS);
        for (i = 0; i < 4000; i++) {
            bvh_vec3 dir = tu_sphere_dir(&r), target = tu_sphere_dir(&r), p, n, out;
            bvh_ray ray, shadow;
            bvh_hit h;
            dir = scaled(dir, 1.0f / sqrtf(dot3(dir, dir))); /* the origin outside the ball */
            /* from 3 radii away toward a point well inside */
            ray.origin = tu_v3(c + 3.0f * sc * dir.x, c + 3.0f * sc * dir.y, c + 3.0f * sc * dir.z);
            ray.dir =
                tu_sub(tu_v3(c + 0.5f * sc * target.x, c + 0.5f * sc * target.y, c + 0.5f * sc * target.z), ray.origin);
            ray.tmin = 0.0f;
            ray.tmax = BVH_INF;
            if (!bvh_intersect(&tree, &ray, &h)) continue;
            primary++;
            assert_int_equal(bvh_hit_surface(&d.triangles, &h, &p, &n), BVH_SUCCESS);
            if (dot3(n, ray.dir) > 0.0f) n = scaled(n, -1.0f);
            do out = tu_sphere_dir(&r);
            while (dot3(out, n) <= 0.05f);
            shadow.dir = out;
            shadow.tmin = 0.0f;
            shadow.tmax = BVH_INF;
            shadow.origin = p;
            raw += (size_t)bvh_occluded(&tree, &shadow);
            shadow.origin = bvh_offset_origin(p, n);
            if (bvh_occluded(&tree, &shadow)) {
                bvh_hit sh;
                bvh_intersect(&tree, &shadow, &sh);
                if (offset++ < 3) {
                    print_error("scale %g at %g: self-hit from prim %u: prim %u t %a\n", (double)sc, (double)c, h.prim,
                                sh.prim, (double)sh.t);
                    tu_print_ray(&shadow);
                }
            }
        }
        print_message("scale %-6g at %-6g: %zu hit points, self-hits: %zu from the hit point, %zu offset\n", (double)sc,
                      (double)c, primary, raw, offset);
        assert_true(primary > 3000);
        assert_int_equal(offset, 0);
        raw_total += raw;
        bvh_free(&tree);
        tu_scene_free(&s);
    }
    assert_true(raw_total > 0); /* without the offset the problem shows */
}

static void offset_moves_along_n(void **state) {
    bvh_vec3 q;
    (void)state;
    /* far from 0: integer ulps, in the direction of n's sign on each axis, none where n is 0 */
    q = bvh_offset_origin(tu_v3(1000.0f, -1000.0f, 5.0f), tu_v3(0.6f, 0.8f, 0.0f));
    assert_true(q.x > 1000.0f && q.y > -1000.0f && q.z == 5.0f);
    assert_true(q.x == 1000.0f + 153.0f * (nextafterf(1000.0f, 2000.0f) - 1000.0f)); /* (int)(256 * 0.6) ulps */
    q = bvh_offset_origin(tu_v3(1000.0f, -1000.0f, 5.0f), tu_v3(-0.6f, -0.8f, 0.0f));
    assert_true(q.x < 1000.0f && q.y < -1000.0f && q.z == 5.0f);
    /* near 0: an absolute step of n / 65536 */
    q = bvh_offset_origin(tu_v3(0.0f, -0.01f, 0.02f), tu_v3(0.0f, 0.0f, -1.0f));
    assert_true(q.x == 0.0f && q.y == -0.01f && q.z == 0.02f - 1.0f / 65536.0f);
    /* what cannot move stays: infinities, NaN normals */
    q = bvh_offset_origin(tu_v3(BVH_INF, 1.0f, 1.0f), tu_v3(1.0f, NAN, 0.0f));
    assert_true(q.x == BVH_INF && q.y == 1.0f && q.z == 1.0f);
    /* a normal a rounding above unit length is taken as unit */
    q = bvh_offset_origin(tu_v3(1.0f, 1.0f, 1.0f), tu_v3(1.0000001f, 0.0f, 0.0f));
    assert_true(q.x == 1.0f + 256.0f * FLT_EPSILON);
}

static void hit_surface(void **state) {
    static const float v[] = {0, 0, 0, 2, 0, 0, 0, 4, 0, 1, 1, 1};
    static const uint32_t idx[] = {0, 1, 2, 0, 1, 9};
    bvh_triangles mesh;
    bvh_hit h;
    bvh_vec3 p, n;
    (void)state;
    memset(&mesh, 0, sizeof mesh);
    mesh.positions = v;
    mesh.vertex_count = 4;
    mesh.indices = idx;
    mesh.triangle_count = 2;
    h.prim = 0;
    h.t = 1.0f;
    h.u = 0.25f;
    h.v = 0.5f;
    assert_int_equal(bvh_hit_surface(&mesh, &h, &p, &n), BVH_SUCCESS);
    assert_true(p.x == 0.5f && p.y == 2.0f && p.z == 0.0f);
    assert_true(n.x == 0.0f && n.y == 0.0f && n.z == 1.0f);
    assert_int_equal(bvh_hit_surface(&mesh, &h, NULL, NULL), BVH_SUCCESS);
    h.prim = 1;
    assert_int_equal(bvh_hit_surface(&mesh, &h, &p, &n), BVH_ERROR_INDEX_OUT_OF_RANGE);
    h.prim = 2;
    assert_int_equal(bvh_hit_surface(&mesh, &h, &p, &n), BVH_ERROR_INVALID_ARGUMENT);
    h.prim = BVH_INVALID;
    assert_int_equal(bvh_hit_surface(&mesh, &h, &p, &n), BVH_ERROR_INVALID_ARGUMENT);
    h.prim = 0;
    assert_int_equal(bvh_hit_surface(NULL, &h, &p, &n), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_hit_surface(&mesh, NULL, &p, &n), BVH_ERROR_INVALID_ARGUMENT);
    mesh.stride = 8;
    assert_int_equal(bvh_hit_surface(&mesh, &h, &p, &n), BVH_ERROR_INVALID_ARGUMENT);
    /* a soup: triangle 1 is vertices 3..5, which do not exist */
    mesh.stride = 0;
    mesh.indices = NULL;
    h.prim = 1;
    assert_int_equal(bvh_hit_surface(&mesh, &h, &p, &n), BVH_ERROR_INDEX_OUT_OF_RANGE);
    /* a zero-area triangle has a zero normal */
    mesh.positions = v;
    mesh.vertex_count = 3;
    mesh.indices = (const uint32_t[]){0, 0, 1};
    h.prim = 0;
    assert_int_equal(bvh_hit_surface(&mesh, &h, &p, &n), BVH_SUCCESS);
    assert_true(n.x == 0.0f && n.y == 0.0f && n.z == 0.0f);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(spheres_exact),
        cmocka_unit_test(bad_callback_t_ignored),
        TU_SCENE_TEST(triangle_tree_by_callback, TU_SCENE_RANDOM, "random"),
        TU_SCENE_TEST(triangle_tree_by_callback, TU_SCENE_GRID, "grid"),
        TU_SCENE_TEST(triangle_tree_by_callback, TU_SCENE_DUPLICATES, "duplicates"),
        cmocka_unit_test(custom_arguments),
        cmocka_unit_test(offset_no_self_hits),
        cmocka_unit_test(offset_moves_along_n),
        cmocka_unit_test(hit_surface),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
