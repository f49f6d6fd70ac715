/* tests/test_opencl.c - the OpenCL kernels of cl/trace.cl give the CPU's hits, for every builder.

   For every builder (top-down .. ploc-parallel) and every scene below, built here with a fixed
   seed: bvh_cl_intersect equals bvh_intersect ray for ray (same primitive; t within 1e-5
   relative, and bit for bit on an "exact" device such as PoCL), bvh_cl_occluded equals
   bvh_occluded, on thousands of rays of every kind (random, axis-parallel, on grid planes, aimed
   at vertices and edges, tmin/tmax cut at the hit, invalid); again with tmax set to the hit
   distance and just below it. The frame kernel equals bvh_intersect_counted of bvh_camera_ray
   for the standard camera. Batches and frames split to fit a small max_alloc give the same
   results. Error paths: bad kernel source, missing kernel file, buffer too large, platform or
   device index out of range (also through $BVH_CL_DEVICE), bad arguments.
   Two-level scenes: five meshes (one empty) under 40 instances (rotations, non-uniform scales, a
   mirror, a shear, a far one, an exact twin for ties, four masks), every builder at the bottom
   and on top: bvh_cl_scene_intersect equals bvh_scene_intersect field for field (instance, id,
   triangle, t, u, v, normal; bit for bit on an exact device) and bvh_cl_scene_occluded equals
   bvh_scene_occluded, for rays from inside and outside, at vertices and edges, grazing along
   edges, axis-parallel, cut at the hit, invalid, under four masks (0 included); empty scenes,
   an instance of an empty tree, one mesh under the identity (the one-level hits), small
   buffers; bad arguments; the caller's allocator gets every block back.
   Without an OpenCL device the tests skip, except under CI=true, where the first one fails.
   The kernel is read from cl/trace.cl: run from the repository root. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"
#define BVH_CL_IMPLEMENTATION
#include "cl/bvh_cl.h"

#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#define RAYS 4096
#define MAX_REPORTS 4

static bvh_cl_context *g_cl;
static bvh_cl_device_info g_info;
static bvh_cl_result g_create_result = BVH_CL_ERROR_NOT_AVAILABLE;
static char g_log[4096];

/* ============================================================================================ */
/* == small helpers (kept in this file on purpose) ================================================ */
/* ============================================================================================ */
static uint32_t oc_rand(uint64_t *s) { /* PCG32 */
    uint64_t old = *s;
    uint32_t x, r;
    *s = old * 6364136223846793005ull + 1442695040888963407ull;
    x = (uint32_t)(((old >> 18) ^ old) >> 27);
    r = (uint32_t)(old >> 59);
    return (x >> r) | (x << ((32 - r) & 31));
}
static float oc_unit(uint64_t *s) { return (float)(oc_rand(s) >> 8) * (1.0f / 16777216.0f); }
static float oc_range(uint64_t *s, float lo, float hi) { return lo + (hi - lo) * oc_unit(s); }

typedef struct oc_scene {
    const char *name;
    float *v;   /* 9 floats per triangle */
    uint32_t n; /* triangles */
} oc_scene;

enum { SC_RANDOM, SC_QUADS, SC_HUGE, SC_ONE, SC_TWO, SC_THREE, SC_EMPTY, SC_COUNT };

static void oc_tri(float *t, float a, float b, float c, float d, float e, float f, float g, float h, float i) {
    t[0] = a;
    t[1] = b;
    t[2] = c;
    t[3] = d;
    t[4] = e;
    t[5] = f;
    t[6] = g;
    t[7] = h;
    t[8] = i;
}

/* an axis-aligned unit quad (two triangles sharing the diagonal) on plane `axis` = w at (a, b) */
static void oc_quad(float *t, int axis, float w, float a, float b) {
    float p[4][3];
    int k, u = (axis + 1) % 3, v = (axis + 2) % 3;
    for (k = 0; k < 4; k++) {
        p[k][axis] = w;
        p[k][u] = a + (float)(k == 1 || k == 2);
        p[k][v] = b + (float)(k >= 2);
    }
    oc_tri(t, p[0][0], p[0][1], p[0][2], p[1][0], p[1][1], p[1][2], p[2][0], p[2][1], p[2][2]);
    oc_tri(t + 9, p[0][0], p[0][1], p[0][2], p[2][0], p[2][1], p[2][2], p[3][0], p[3][1], p[3][2]);
}

static int oc_scene_make(int id, oc_scene *s) {
    uint64_t rng = 0x5eed0000u + (uint64_t)id;
    uint32_t i, j, k = 0;
    static const char *names[SC_COUNT] = {"random", "quads", "huge", "one", "two", "three", "empty"};
    static const uint32_t counts[SC_COUNT] = {3000, 3 * 2 * 64 + 16, 501, 1, 2, 3, 0};
    s->name = names[id];
    s->n = counts[id];
    s->v = (float *)calloc(9 * (size_t)s->n + 9, sizeof(float));
    if (!s->v) return 0;
    switch (id) {
    case SC_RANDOM: /* small triangles of random orientation in [-1, 1]^3 */
        for (i = 0; i < s->n; i++) {
            float c[3] = {oc_range(&rng, -1, 1), oc_range(&rng, -1, 1), oc_range(&rng, -1, 1)};
            for (j = 0; j < 9; j++) s->v[9 * i + j] = c[j % 3] + oc_range(&rng, -0.08f, 0.08f);
        }
        break;
    case SC_QUADS: /* three 8x8 grids of unit quads on the planes z=0, x=0, y=4; 8 quads twice (ties) */
        for (i = 0; i < 8; i++)
            for (j = 0; j < 8; j++, k += 6) {
                oc_quad(s->v + 9 * k, 2, 0.0f, (float)i, (float)j);
                oc_quad(s->v + 9 * (k + 2), 0, 0.0f, (float)i, (float)j);
                oc_quad(s->v + 9 * (k + 4), 1, 4.0f, (float)i, (float)j);
            }
        for (i = 0; i < 8; i++, k += 2) oc_quad(s->v + 9 * k, 2, 0.0f, (float)i, (float)i);
        break;
    case SC_HUGE: /* one triangle of size 2000 through 500 small ones */
        oc_tri(s->v, -1000, -1000, 0.1f, 1000, -1000, -0.1f, 0, 1000, 0);
        for (i = 1; i < s->n; i++) {
            float c[3] = {oc_range(&rng, -2, 2), oc_range(&rng, -2, 2), oc_range(&rng, -2, 2)};
            for (j = 0; j < 9; j++) s->v[9 * i + j] = c[j % 3] + oc_range(&rng, -0.05f, 0.05f);
        }
        break;
    case SC_THREE:
        oc_tri(s->v + 18, 0, 0, 2, 1, 0, 2, 1, 1, 2); /* fall through */
    case SC_TWO:
        oc_tri(s->v + 9, 0, 0, 1, 1, 0, 1, 0, 1, 1); /* fall through */
    case SC_ONE:
        oc_tri(s->v, 0, 0, 0, 1, 0, 0, 0, 1, 0);
        break;
    default:
        break;
    }
    return 1;
}

static bvh_aabb oc_bounds(const oc_scene *s) {
    bvh_aabb b = bvh_aabb_empty();
    uint32_t i;
    for (i = 0; i < 3 * s->n; i++) {
        bvh_vec3 p;
        p.x = s->v[3 * i];
        p.y = s->v[3 * i + 1];
        p.z = s->v[3 * i + 2];
        bvh_aabb_grow(&b, p);
    }
    if (!s->n) {
        b.min.x = b.min.y = b.min.z = -1;
        b.max.x = b.max.y = b.max.z = 1;
    }
    if (b.max.x - b.min.x > 8) {
        b.min.x = b.min.y = b.min.z = -3;
        b.max.x = b.max.y = b.max.z = 3;
    } /* huge */
    return b;
}

static bvh_result oc_build(const oc_scene *s, bvh_builder b, bvh_tree *t) {
    bvh_build_desc d;
    memset(&d, 0, sizeof d);
    d.builder = b;
    d.threads = 2;
    d.triangles.positions = s->v;
    d.triangles.vertex_count = 3 * s->n;
    d.triangles.triangle_count = s->n;
    return bvh_build(t, &d);
}

/* Rays of ten kinds (i % 10): 0-2 random, 3 axis-parallel, 4 axis-parallel from integer
   coordinates (origins on the quads' planes and edges), 5 aimed at a vertex, 6 at an edge
   midpoint, 7 at a centroid with a random [tmin, tmax], 8 zero and -0 components, 9 invalid. */
static void oc_rays(const oc_scene *s, bvh_ray *r, size_t count, uint64_t seed) {
    bvh_aabb b = oc_bounds(s);
    float lo[3] = {b.min.x, b.min.y, b.min.z}, hi[3] = {b.max.x, b.max.y, b.max.z}, o[3], d[3];
    uint64_t rng = seed;
    size_t i;
    int a;
    for (i = 0; i < count; i++) {
        int kind = (int)(i % 10);
        float tmin = 0.0f, tmax = BVH_INF;
        for (a = 0; a < 3; a++) {
            float ext = hi[a] - lo[a] + 0.5f;
            o[a] = oc_range(&rng, lo[a] - 0.5f * ext, hi[a] + 0.5f * ext);
            d[a] = oc_range(&rng, -1, 1);
        }
        if (kind == 3 || kind == 4) {
            int ax = (int)(oc_rand(&rng) % 3);
            d[0] = d[1] = d[2] = (oc_rand(&rng) & 1) ? 0.0f : -0.0f;
            d[ax] = (oc_rand(&rng) & 1) ? 1.0f : -0.5f;
            if (kind == 4)
                for (a = 0; a < 3; a++)
                    if (a != ax) o[a] = floorf(o[a] + 0.5f);
        } else if (kind >= 5 && kind <= 7 && s->n) {
            const float *t = s->v + 9 * (size_t)(oc_rand(&rng) % s->n);
            int v = (int)(oc_rand(&rng) % 3), w = (v + 1) % 3;
            for (a = 0; a < 3; a++) {
                float target = kind == 5   ? t[3 * v + a]
                               : kind == 6 ? 0.5f * (t[3 * v + a] + t[3 * w + a])
                                           : (t[a] + t[3 + a] + t[6 + a]) / 3.0f;
                d[a] = target - o[a];
            }
            if (kind == 7) {
                tmin = oc_range(&rng, 0, 0.9f);
                tmax = oc_range(&rng, tmin, 1.2f);
            }
        } else if (kind == 8) {
            d[oc_rand(&rng) % 3] = (oc_rand(&rng) & 1) ? 0.0f : -0.0f;
        } else if (kind == 9) {
            switch ((i / 10) % 6) {
            case 0:
                o[oc_rand(&rng) % 3] = NAN;
                break;
            case 1:
                d[0] = d[1] = d[2] = 0.0f;
                break;
            case 2:
                tmin = 2.0f;
                tmax = 1.0f;
                break;
            case 3:
                d[oc_rand(&rng) % 3] = BVH_INF;
                break;
            case 4:
                tmax = NAN;
                break;
            default:
                o[oc_rand(&rng) % 3] = -BVH_INF;
                break;
            }
        }
        r[i].origin.x = o[0];
        r[i].origin.y = o[1];
        r[i].origin.z = o[2];
        r[i].dir.x = d[0];
        r[i].dir.y = d[1];
        r[i].dir.z = d[2];
        r[i].tmin = tmin;
        r[i].tmax = tmax;
    }
}

static int oc_close(float a, float b) { return fabsf(a - b) <= 1e-5f * fmaxf(fabsf(a), fabsf(b)); }

/* Bit for bit on an exact device (correctly rounded division and fp64, e.g. PoCL). Elsewhere the
   last bits of t may differ, so: the same primitive with t within 1e-5 relative; or both hit at
   such a t (an edge or vertex two triangles share); or one misses where the other's t is that
   close to tmin or tmax (the ray ends on the triangle). */
static int oc_hit_equal(const bvh_ray *r, const bvh_hit *a, const bvh_hit *b) {
    const bvh_hit *h;
    if (g_info.exact) return memcmp(a, b, sizeof *a) == 0;
    if (a->prim == BVH_INVALID && b->prim == BVH_INVALID) return 1;
    if (a->prim != BVH_INVALID && b->prim != BVH_INVALID) return oc_close(a->t, b->t);
    h = a->prim != BVH_INVALID ? a : b;
    return oc_close(h->t, r->tmax) || oc_close(h->t, r->tmin);
}

static void oc_print_case(const char *what, const oc_scene *s, bvh_builder b, size_t i, const bvh_ray *r,
                          const bvh_hit *cpu, const bvh_hit *gpu) {
    print_error("%s/%s/%s: ray %zu o=(%a %a %a) d=(%a %a %a) [%a, %a]\n", what, s->name, bvh_builder_name(b), i,
                r->origin.x, r->origin.y, r->origin.z, r->dir.x, r->dir.y, r->dir.z, r->tmin, r->tmax);
    if (cpu && gpu)
        print_error("  cpu prim %u t %a u %a v %a | opencl prim %u t %a u %a v %a\n", cpu->prim, cpu->t, cpu->u, cpu->v,
                    gpu->prim, gpu->t, gpu->u, gpu->v);
}

/* Traces rays on both sides; returns mismatches (closest and any). */
static size_t oc_compare(const char *what, const oc_scene *s, bvh_builder b, const bvh_tree *t, bvh_cl_tree *g,
                         const bvh_ray *rays, size_t count, bvh_hit *cpu) {
    bvh_hit *gpu = (bvh_hit *)calloc(count + 1, sizeof(bvh_hit));
    uint8_t *occ = (uint8_t *)calloc(count + 1, 1);
    size_t i, bad = 0;
    assert_non_null(gpu);
    assert_non_null(occ);
    assert_int_equal(bvh_cl_intersect(g, rays, gpu, count), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_occluded(g, rays, occ, count), BVH_CL_SUCCESS);
    for (i = 0; i < count; i++) {
        int found = bvh_intersect(t, &rays[i], &cpu[i]), blocked = bvh_occluded(t, &rays[i]);
        /* any hit <=> a closest hit exists, on each side; the closest hits agree across sides */
        if (!oc_hit_equal(&rays[i], &cpu[i], &gpu[i]) || found != (cpu[i].prim != BVH_INVALID) || blocked != found ||
            occ[i] != (gpu[i].prim != BVH_INVALID)) {
            if (bad++ < MAX_REPORTS) oc_print_case(what, s, b, i, &rays[i], &cpu[i], &gpu[i]);
            if (bad <= MAX_REPORTS) print_error("  any hit: cpu %d opencl %d\n", blocked, occ[i]);
        }
    }
    free(gpu);
    free(occ);
    return bad;
}

#define NEED_DEVICE()                                                                                                  \
    do {                                                                                                               \
        if (!g_cl) {                                                                                                   \
            skip();                                                                                                    \
            return;                                                                                                    \
        }                                                                                                              \
    } while (0)

/* ============================================================================================ */
/* == tests ======================================================================================== */
/* ============================================================================================ */
static void device_available(void **state) {
    const char *ci = getenv("CI");
    (void)state;
    if (g_cl) {
        print_message("OpenCL: %s / %s (%s), exact: %d\n", g_info.platform, g_info.device, g_info.version,
                      g_info.exact);
        return;
    }
    if (ci && strcmp(ci, "true") == 0)
        fail_msg("CI=true and no OpenCL device: %s (%s)", bvh_cl_result_string(g_create_result), g_log);
    /* a device was there but the kernel did not build: the kernel is broken, not the machine */
    if (g_create_result == BVH_CL_ERROR_BUILD_FAILED || g_create_result == BVH_CL_ERROR_KERNEL_NOT_FOUND)
        fail_msg("the kernel does not build: %s (%s)", bvh_cl_result_string(g_create_result), g_log);
    print_message("no OpenCL device, skipping: %s (%s)\n", bvh_cl_result_string(g_create_result), g_log);
    skip();
}

/* closest and any hits equal the CPU's, for every builder; again with tmax at and below the hit */
static void hits_equal_cpu(void **state) {
    int id = (int)(intptr_t)*state, b;
    oc_scene s;
    bvh_ray *rays, *rays2;
    bvh_hit *cpu, *cpu2;
    size_t bad = 0, i, m, hits = 0;
    NEED_DEVICE();
    assert_true(oc_scene_make(id, &s));
    rays = (bvh_ray *)malloc(RAYS * sizeof *rays);
    rays2 = (bvh_ray *)malloc(RAYS * sizeof *rays2);
    cpu = (bvh_hit *)malloc(RAYS * sizeof *cpu);
    cpu2 = (bvh_hit *)malloc(RAYS * sizeof *cpu2);
    assert_true(rays && rays2 && cpu && cpu2);
    oc_rays(&s, rays, RAYS, 0xC0FFEEu + (uint64_t)id);
    for (b = BVH_BUILDER_TOP_DOWN; b <= BVH_BUILDER_PLOC_PARALLEL; b++) {
        bvh_tree t;
        bvh_cl_tree *g = NULL;
        bvh_validation val;
        assert_int_equal(oc_build(&s, (bvh_builder)b, &t), BVH_SUCCESS);
        if (t.node_count) assert_int_equal(bvh_validate(&t, NULL, &val), BVH_SUCCESS);
        assert_int_equal(bvh_cl_upload(g_cl, &t, &g), BVH_CL_SUCCESS);
        bad += oc_compare("rays", &s, (bvh_builder)b, &t, g, rays, RAYS, cpu);
        for (i = m = 0; i < RAYS; i++) {
            if (cpu[i].prim == BVH_INVALID) continue;
            rays2[m] = rays[i];
            rays2[m].tmax = (m & 1) ? nextafterf(cpu[i].t, -BVH_INF) : cpu[i].t;
            if (rays2[m].tmax < rays2[m].tmin) rays2[m].tmax = rays2[m].tmin;
            m++;
        }
        hits += m;
        bad += oc_compare("tmax at the hit", &s, (bvh_builder)b, &t, g, rays2, m, cpu2);
        bvh_cl_tree_free(g);
        bvh_free(&t);
    }
    if (s.n >= 1000) assert_true(hits > (size_t)(BVH_BUILDER_PLOC_PARALLEL * RAYS / 10)); /* rays do hit */
    free(rays);
    free(rays2);
    free(cpu);
    free(cpu2);
    free(s.v);
    assert_int_equal(bad, 0);
}

/* the frame kernel's hits and node counts equal bvh_intersect_counted of bvh_camera_ray */
static size_t oc_frame_check(const oc_scene *s, bvh_builder b, const bvh_tree *t, const bvh_camera *cam,
                             const uint8_t *rgba, const bvh_hit *hits, const uint32_t *visited) {
    size_t bad = 0, npix = (size_t)cam->width * cam->height, nhit = 0;
    uint32_t x, y;
    for (y = 0; y < cam->height; y++)
        for (x = 0; x < cam->width; x++) {
            size_t p = (size_t)y * cam->width + x;
            bvh_ray ray = bvh_camera_ray(cam, x, y);
            bvh_hit h;
            uint32_t vis;
            const uint8_t *c = rgba + 4 * p;
            int ok;
            bvh_intersect_counted(t, &ray, &h, &vis);
            nhit += h.prim != BVH_INVALID;
            ok = oc_hit_equal(&ray, &h, &hits[p]) && (!g_info.exact || vis == visited[p]) && c[3] == 255;
            ok = ok && (h.prim != BVH_INVALID ? c[0] == c[1] && c[2] <= c[1] : c[2] > c[0]); /* grey / blue */
            if (!ok && bad++ < MAX_REPORTS) {
                oc_print_case("frame", s, b, p, &ray, &h, &hits[p]);
                print_error("  pixel (%u, %u): visited cpu %u opencl %u, rgba %u %u %u %u\n", x, y, vis, visited[p],
                            c[0], c[1], c[2], c[3]);
            }
        }
    if (s->n >= 1000) assert_true(nhit > npix / 50 && nhit < npix); /* the camera sees the scene */
    return bad;
}

static void frame_equals_cpu(void **state) {
    int id = (int)(intptr_t)*state, b;
    oc_scene s;
    const uint32_t w = 67, h = 45; /* not multiples of the 8 x 8 work-groups */
    uint8_t *rgba = (uint8_t *)malloc(4 * (size_t)w * h);
    bvh_hit *hits = (bvh_hit *)malloc(sizeof(bvh_hit) * w * h);
    uint32_t *vis = (uint32_t *)malloc(sizeof(uint32_t) * w * h);
    uint8_t *rgba2 = (uint8_t *)malloc(4 * (size_t)w * h);
    bvh_hit *hits2 = (bvh_hit *)malloc(sizeof(bvh_hit) * w * h);
    size_t bad = 0;
    NEED_DEVICE();
    assert_true(rgba && hits && vis && rgba2 && hits2 && oc_scene_make(id, &s));
    for (b = BVH_BUILDER_TOP_DOWN; b <= BVH_BUILDER_PLOC_PARALLEL; b++) {
        bvh_tree t;
        bvh_cl_tree *g = NULL;
        bvh_camera cam;
        assert_int_equal(oc_build(&s, (bvh_builder)b, &t), BVH_SUCCESS);
        cam = bvh_camera_standard(bvh_tree_bounds(&t), w, h);
        assert_int_equal(bvh_cl_upload(g_cl, &t, &g), BVH_CL_SUCCESS);
        assert_int_equal(bvh_cl_render_frame(g, &cam, rgba, hits, vis), BVH_CL_SUCCESS);
        bad += oc_frame_check(&s, (bvh_builder)b, &t, &cam, rgba, hits, vis);
        /* without visited counts a CPU device takes packets of 4 x 4: the same pixels and hits */
        assert_int_equal(bvh_cl_render_frame(g, &cam, rgba2, hits2, NULL), BVH_CL_SUCCESS);
        assert_memory_equal(hits2, hits, sizeof(bvh_hit) * w * h);
        assert_memory_equal(rgba2, rgba, 4 * (size_t)w * h);
        memset(hits2, 0, sizeof(bvh_hit) * w * h);
        assert_int_equal(bvh_cl_render_frame(g, &cam, NULL, hits2, NULL), BVH_CL_SUCCESS);
        assert_memory_equal(hits2, hits, sizeof(bvh_hit) * w * h);
        assert_int_equal(bvh_cl_render_frame(g, &cam, NULL, NULL, NULL), BVH_CL_SUCCESS); /* timing only */
        bvh_cl_tree_free(g);
        bvh_free(&t);
    }
    free(rgba);
    free(hits);
    free(vis);
    free(rgba2);
    free(hits2);
    free(s.v);
    assert_int_equal(bad, 0);
}

static bvh_cl_result oc_create(bvh_cl_context **c, const char *device, const char *source, const char *path,
                               size_t max_alloc, char *log, size_t log_size) {
    bvh_cl_desc d;
    memset(&d, 0, sizeof d);
    d.device = device;
    d.kernel_source = source;
    d.kernel_path = path;
    d.max_alloc = max_alloc;
    d.log = log;
    d.log_size = log_size;
    return bvh_cl_create(c, &d);
}

/* a max_alloc of 4 KiB splits batches (128 rays) and frames (bands of rows): same results */
static void small_allocations_split_work(void **state) {
    bvh_cl_context *c = NULL;
    bvh_cl_tree *g = NULL, *g_small = NULL;
    bvh_cl_device_info info;
    oc_scene s;
    bvh_tree t;
    bvh_camera cam;
    const size_t n = 1000;
    const uint32_t w = 50, h = 40;
    bvh_ray rays[1000];
    bvh_hit a[1000], b[1000];
    bvh_hit *fa = (bvh_hit *)malloc(sizeof(bvh_hit) * w * h), *fb = (bvh_hit *)malloc(sizeof(bvh_hit) * w * h);
    uint8_t oa[1000], ob[1000], *ra = (uint8_t *)malloc(4 * w * h), *rb = (uint8_t *)malloc(4 * w * h);
    uint32_t *va = (uint32_t *)malloc(4 * w * h), *vb = (uint32_t *)malloc(4 * w * h);
    (void)state;
    NEED_DEVICE();
    assert_true(fa && fb && ra && rb && va && vb && oc_scene_make(SC_THREE, &s));
    assert_int_equal(oc_build(&s, BVH_BUILDER_PLOC, &t), BVH_SUCCESS);
    assert_int_equal(oc_create(&c, NULL, NULL, NULL, 4096, g_log, sizeof g_log), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_get_info(c, &info), BVH_CL_SUCCESS);
    assert_int_equal(info.max_alloc, 4096);
    assert_int_equal(bvh_cl_upload(g_cl, &t, &g), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_upload(c, &t, &g_small), BVH_CL_SUCCESS);
    oc_rays(&s, rays, n, 77);
    assert_int_equal(bvh_cl_intersect(g, rays, a, n), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_intersect(g_small, rays, b, n), BVH_CL_SUCCESS);
    assert_memory_equal(a, b, sizeof a);
    assert_int_equal(bvh_cl_occluded(g, rays, oa, n), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_occluded(g_small, rays, ob, n), BVH_CL_SUCCESS);
    assert_memory_equal(oa, ob, sizeof oa);
    cam = bvh_camera_standard(bvh_tree_bounds(&t), w, h);
    assert_int_equal(bvh_cl_render_frame(g, &cam, ra, fa, va), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_render_frame(g_small, &cam, rb, fb, vb), BVH_CL_SUCCESS);
    assert_memory_equal(fa, fb, sizeof(bvh_hit) * w * h);
    assert_memory_equal(ra, rb, 4 * w * h);
    assert_memory_equal(va, vb, 4 * w * h);
    /* packets (no visited) in bands of 5 rows (4 KiB / 50 pixels / 16 bytes): tiles cut by bands */
    memset(fb, 0, sizeof(bvh_hit) * w * h);
    memset(rb, 0, 4 * w * h);
    assert_int_equal(bvh_cl_render_frame(g_small, &cam, rb, fb, NULL), BVH_CL_SUCCESS);
    assert_memory_equal(fa, fb, sizeof(bvh_hit) * w * h);
    assert_memory_equal(ra, rb, 4 * w * h);
    bvh_cl_tree_free(g);
    bvh_cl_tree_free(g_small);
    bvh_cl_destroy(c);
    bvh_free(&t);
    free(s.v);
    free(fa);
    free(fb);
    free(ra);
    free(rb);
    free(va);
    free(vb);
}

/* desc.frame_rays: 1 (a ray per work-item), 8 and 16 (4 x 2 and 4 x 4 pixel packets) give the
   same frames on every builder's tree of a scene, equal to the CPU's hits; anything else is
   refused. */
static void frame_rays_option(void **state) {
    static const uint32_t w = 37, h = 23; /* tiles cut at the right and the bottom */
    bvh_cl_context *c1 = NULL, *c8 = NULL, *c16 = NULL, *bad = NULL;
    bvh_cl_desc d;
    oc_scene s;
    int b;
    uint8_t *r1 = (uint8_t *)malloc(4 * w * h), *r8 = (uint8_t *)malloc(4 * w * h);
    bvh_hit *h1 = (bvh_hit *)malloc(sizeof(bvh_hit) * w * h), *h8 = (bvh_hit *)malloc(sizeof(bvh_hit) * w * h);
    (void)state;
    NEED_DEVICE();
    assert_true(r1 && r8 && h1 && h8 && oc_scene_make(SC_RANDOM, &s));
    memset(&d, 0, sizeof d);
    d.frame_rays = 3;
    assert_int_equal(bvh_cl_create(&bad, &d), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_null(bad);
    d.frame_rays = 1;
    assert_int_equal(bvh_cl_create(&c1, &d), BVH_CL_SUCCESS);
    d.frame_rays = 8;
    assert_int_equal(bvh_cl_create(&c8, &d), BVH_CL_SUCCESS);
    d.frame_rays = 16;
    assert_int_equal(bvh_cl_create(&c16, &d), BVH_CL_SUCCESS);
    for (b = BVH_BUILDER_TOP_DOWN; b <= BVH_BUILDER_PLOC_PARALLEL; b++) {
        bvh_tree t;
        bvh_cl_tree *g1 = NULL, *g8 = NULL, *g16 = NULL;
        bvh_camera cam;
        size_t i, nhit = 0;
        assert_int_equal(oc_build(&s, (bvh_builder)b, &t), BVH_SUCCESS);
        cam = bvh_camera_standard(bvh_tree_bounds(&t), w, h);
        assert_int_equal(bvh_cl_upload(c1, &t, &g1), BVH_CL_SUCCESS);
        assert_int_equal(bvh_cl_upload(c8, &t, &g8), BVH_CL_SUCCESS);
        assert_int_equal(bvh_cl_render_frame(g1, &cam, r1, h1, NULL), BVH_CL_SUCCESS);
        assert_int_equal(bvh_cl_render_frame(g8, &cam, r8, h8, NULL), BVH_CL_SUCCESS);
        assert_memory_equal(h1, h8, sizeof(bvh_hit) * w * h);
        assert_memory_equal(r1, r8, 4 * w * h);
        assert_int_equal(bvh_cl_upload(c16, &t, &g16), BVH_CL_SUCCESS);
        memset(h8, 0, sizeof(bvh_hit) * w * h);
        memset(r8, 0, 4 * w * h);
        assert_int_equal(bvh_cl_render_frame(g16, &cam, r8, h8, NULL), BVH_CL_SUCCESS);
        assert_memory_equal(h1, h8, sizeof(bvh_hit) * w * h);
        assert_memory_equal(r1, r8, 4 * w * h);
        for (i = 0; i < (size_t)w * h; i++) {
            bvh_ray ray = bvh_camera_ray(&cam, (uint32_t)(i % w), (uint32_t)(i / w));
            bvh_hit cpu;
            bvh_intersect(&t, &ray, &cpu);
            nhit += cpu.prim != BVH_INVALID;
            if (!oc_hit_equal(&ray, &cpu, &h8[i]))
                fail_msg("builder %d pixel %zu: packet hit differs from the CPU", b, i);
        }
        assert_true(nhit > 0);
        bvh_cl_tree_free(g1);
        bvh_cl_tree_free(g8);
        bvh_cl_tree_free(g16);
        bvh_free(&t);
    }
    bvh_cl_destroy(c1);
    bvh_cl_destroy(c8);
    bvh_cl_destroy(c16);
    free(r1);
    free(r8);
    free(h1);
    free(h8);
    free(s.v);
}

static void buffer_too_large(void **state) {
    bvh_cl_context *c = NULL;
    bvh_cl_tree *g = NULL;
    oc_scene s, one;
    bvh_tree t, t1;
    bvh_camera cam;
    bvh_hit hit[1];
    (void)state;
    NEED_DEVICE();
    assert_true(oc_scene_make(SC_RANDOM, &s) && oc_scene_make(SC_ONE, &one));
    assert_int_equal(oc_build(&s, BVH_BUILDER_PLOC, &t), BVH_SUCCESS);
    assert_int_equal(oc_build(&one, BVH_BUILDER_PLOC, &t1), BVH_SUCCESS);
    assert_int_equal(oc_create(&c, NULL, NULL, NULL, 1024, g_log, sizeof g_log), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_upload(c, &t, &g), BVH_CL_ERROR_BUFFER_TOO_LARGE); /* 108 KB of triangles */
    assert_null(g);
    assert_int_equal(bvh_cl_upload(c, &t1, &g), BVH_CL_SUCCESS);
    cam = bvh_camera_standard(bvh_tree_bounds(&t1), 100, 10); /* one row of hits: 1600 bytes */
    assert_int_equal(bvh_cl_render_frame(g, &cam, NULL, hit, NULL), BVH_CL_ERROR_BUFFER_TOO_LARGE);
    bvh_cl_tree_free(g);
    bvh_cl_destroy(c);
    assert_int_equal(oc_create(&c, NULL, NULL, NULL, 16, g_log, sizeof g_log), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_upload(c, &t1, &g), BVH_CL_ERROR_BUFFER_TOO_LARGE); /* one node: 32 bytes */
    bvh_cl_destroy(c);
    bvh_free(&t);
    bvh_free(&t1);
    free(s.v);
    free(one.v);
}

static void bad_kernel_source(void **state) {
    bvh_cl_context *c = (bvh_cl_context *)&c;
    char log[2048] = "";
    (void)state;
    NEED_DEVICE();
    assert_int_equal(oc_create(&c, NULL, "__kernel void bvh_intersect_kernel(__global float *x) { x[0] = y; }", NULL, 0,
                               log, sizeof log),
                     BVH_CL_ERROR_BUILD_FAILED);
    assert_null(c);
    assert_true(strlen(log) > 0);
    /* compiles, but lacks the kernels */
    assert_int_equal(
        oc_create(&c, NULL, "__kernel void other(__global float *x) { x[0] = 1.0f; }", NULL, 0, log, sizeof log),
        BVH_CL_ERROR_BUILD_FAILED);
    assert_true(strlen(log) > 0);
    assert_int_equal(oc_create(&c, NULL, NULL, "no/such/dir/trace.cl", 0, log, sizeof log),
                     BVH_CL_ERROR_KERNEL_NOT_FOUND);
    assert_non_null(strstr(log, "no/such/dir/trace.cl"));
    /* a kernel file read at run time (the tests run from the repository's root) */
    assert_int_equal(oc_create(&c, NULL, NULL, "cl/trace.cl", 0, log, sizeof log), BVH_CL_SUCCESS);
    bvh_cl_destroy(c);
    assert_int_equal(oc_create(&c, NULL, NULL, NULL, 0, NULL, 0), BVH_CL_SUCCESS); /* no log buffer */
    assert_string_equal(bvh_cl_build_log(NULL), "");
    bvh_cl_destroy(c);
}

static void no_platform_or_device(void **state) {
    bvh_cl_context *c = (bvh_cl_context *)&c;
    char log[256], *saved = getenv("BVH_CL_DEVICE") ? strdup(getenv("BVH_CL_DEVICE")) : NULL;
    (void)state;
    NEED_DEVICE();
    assert_int_equal(oc_create(&c, "99:0", NULL, NULL, 0, log, sizeof log), BVH_CL_ERROR_NO_PLATFORM);
    assert_null(c);
    assert_true(strlen(log) > 0);
    assert_int_equal(oc_create(&c, "0:99", NULL, NULL, 0, log, sizeof log), BVH_CL_ERROR_NO_DEVICE);
    assert_int_equal(oc_create(&c, "0:x", NULL, NULL, 0, log, sizeof log), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(oc_create(&c, "gpu", NULL, NULL, 0, log, sizeof log), BVH_CL_ERROR_INVALID_ARGUMENT);
    setenv("BVH_CL_DEVICE", "42:0", 1);
    assert_int_equal(oc_create(&c, NULL, NULL, NULL, 0, log, sizeof log), BVH_CL_ERROR_NO_PLATFORM);
    setenv("BVH_CL_DEVICE", "0:0", 1);
    assert_int_equal(oc_create(&c, NULL, NULL, NULL, 0, log, sizeof log), BVH_CL_SUCCESS);
    bvh_cl_destroy(c);
    if (saved)
        setenv("BVH_CL_DEVICE", saved, 1);
    else
        unsetenv("BVH_CL_DEVICE");
    free(saved);
}

static void invalid_arguments(void **state) {
    bvh_cl_tree *g = (bvh_cl_tree *)&g;
    bvh_tree t;
    bvh_build_desc d;
    bvh_aabb box = {{0, 0, 0}, {1, 1, 1}};
    bvh_ray ray = {{0, 0, -1}, 0, {0, 0, 1}, BVH_INF};
    bvh_hit hit;
    uint8_t occ;
    bvh_cl_device_info list[8];
    uint32_t count = 0;
    const char *call = NULL;
    int r;
    (void)state;
    for (r = 0; r <= BVH_CL_RESULT_COUNT; r++) assert_non_null(bvh_cl_result_string((bvh_cl_result)r));
    NEED_DEVICE();
    assert_int_equal(bvh_cl_create(NULL, NULL), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_upload(NULL, NULL, &g), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_null(g);
    memset(&d, 0, sizeof d);
    d.boxes = &box;
    d.box_count = 1;
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    assert_int_equal(bvh_cl_upload(g_cl, &t, &g), BVH_CL_ERROR_INVALID_ARGUMENT); /* no triangles */
    bvh_free(&t);
    assert_int_equal(bvh_cl_intersect(NULL, &ray, &hit, 1), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_occluded(NULL, &ray, &occ, 1), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_render_frame(NULL, NULL, NULL, NULL, NULL), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_get_info(NULL, list), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_last_error(g_cl, &call), 0);
    assert_string_equal(call, "");
    assert_int_equal(bvh_cl_enumerate(list, 8, &count), BVH_CL_SUCCESS);
    assert_true(count >= 1 && strlen(list[0].device) > 0 && list[0].max_alloc > 0);
    bvh_cl_tree_free(NULL);
    bvh_cl_destroy(NULL);
}

/* The host allocator of bvh_cl_desc (bvh.h's bvh_allocator): a half pair is refused, and a whole
   one gets every block of the context and its trees back. */
typedef struct oc_counting {
    long live, calls;
} oc_counting;
static void *oc_alloc(size_t size, void *user) {
    oc_counting *c = (oc_counting *)user;
    c->live++;
    c->calls++;
    return malloc(size);
}
static void oc_free(void *p, void *user) {
    oc_counting *c = (oc_counting *)user;
    if (p) c->live--;
    free(p);
}
static void caller_allocator(void **state) {
    static const float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    oc_counting count = {0, 0};
    bvh_cl_context *c = (bvh_cl_context *)&c;
    bvh_cl_tree *g = NULL;
    bvh_cl_desc d;
    bvh_build_desc bd;
    bvh_tree t;
    bvh_ray ray = {{0.2f, 0.2f, -1}, 0, {0, 0, 1}, BVH_INF};
    bvh_hit hit;
    bvh_instance inst[2];
    bvh_scene_desc sd;
    bvh_scene sc;
    bvh_cl_scene *gs = NULL;
    bvh_scene_hit sh;
    long calls;
    (void)state;
    NEED_DEVICE();
    memset(&d, 0, sizeof d);
    d.allocator.alloc = oc_alloc;
    d.allocator.user = &count;
    assert_int_equal(bvh_cl_create(&c, &d), BVH_CL_ERROR_INVALID_ARGUMENT); /* alloc without free */
    assert_null(c);
    assert_int_equal(count.calls, 0);
    d.allocator.free = oc_free;
    assert_int_equal(bvh_cl_create(&c, &d), BVH_CL_SUCCESS);
    memset(&bd, 0, sizeof bd);
    bd.triangles.positions = v;
    bd.triangles.vertex_count = 3;
    bd.triangles.triangle_count = 1;
    assert_int_equal(bvh_build(&t, &bd), BVH_SUCCESS);
    assert_int_equal(bvh_cl_upload(c, &t, &g), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_intersect(g, &ray, &hit, 1), BVH_CL_SUCCESS);
    assert_int_equal(hit.prim, 0);
    bvh_cl_tree_free(g);
    /* a scene of two instances of the tree: its blocks too */
    memset(inst, 0, sizeof inst);
    inst[0].tree = inst[1].tree = &t;
    inst[0].transform[0] = inst[0].transform[5] = inst[0].transform[10] = 1.0f;
    inst[0].mask = inst[1].mask = ~0u;
    inst[1] = inst[0];
    inst[1].transform[11] = 1.0f;
    memset(&sd, 0, sizeof sd);
    sd.instances = inst;
    sd.instance_count = 2;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    calls = count.calls;
    assert_int_equal(bvh_cl_scene_upload(c, &sc, &gs), BVH_CL_SUCCESS);
    assert_true(count.calls > calls);
    assert_int_equal(bvh_cl_scene_intersect(gs, &ray, ~0u, &sh, 1), BVH_CL_SUCCESS);
    assert_int_equal(sh.instance, 0);
    bvh_cl_scene_free(gs);
    bvh_scene_free(&sc);
    bvh_cl_destroy(c);
    bvh_free(&t);
    assert_true(count.calls >= 2); /* the context and the tree at least */
    assert_int_equal(count.live, 0);
}

/* ============================================================================================ */
/* == two-level scenes ============================================================================ */
/* ============================================================================================ */
/* Meshes: the scenes above (random, quads with ties, huge, three, empty), instanced INSTANCES times
   with rotations about random axes, non-uniform scales, a mirror, a shear, a far translation, an
   exact duplicate (ties between instances) and masks 1 << (i % 4). */
#define MESHES 5
#define INSTANCES 40
static const int oc_mesh_scene[MESHES] = {SC_RANDOM, SC_QUADS, SC_HUGE, SC_THREE, SC_EMPTY};

typedef struct oc_world {
    oc_scene mesh[MESHES];
    bvh_tree tree[MESHES];
    bvh_instance inst[INSTANCES];
    uint32_t mesh_of[INSTANCES];
} oc_world;

/* rotation about a random axis (Rodrigues) times a diagonal scale, then a translation */
static void oc_transform(uint64_t *rng, float m[12], float spread) {
    float a[3] = {oc_range(rng, -1, 1), oc_range(rng, -1, 1), oc_range(rng, 0.1f, 1)};
    float l = sqrtf(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]), th = oc_range(rng, 0, 6.2831853f);
    float c = cosf(th), s = sinf(th), C = 1.0f - c, x = a[0] / l, y = a[1] / l, z = a[2] / l;
    float R[9] = {c + x * x * C,     x * y * C - z * s, x * z * C + y * s, y * x * C + z * s, c + y * y * C,
                  y * z * C - x * s, z * x * C - y * s, z * y * C + x * s, c + z * z * C};
    float sc[3] = {oc_range(rng, 0.3f, 3), oc_range(rng, 0.3f, 3), oc_range(rng, 0.3f, 3)};
    int i, j;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) m[4 * i + j] = R[3 * i + j] * sc[j];
    m[3] = oc_range(rng, -spread, spread);
    m[7] = oc_range(rng, -spread, spread);
    m[11] = oc_range(rng, -spread, spread);
}

static void oc_world_make(oc_world *w) {
    uint64_t rng = 0x1257a7ceu;
    uint32_t i;
    memset(w, 0, sizeof *w);
    for (i = 0; i < MESHES; i++) assert_true(oc_scene_make(oc_mesh_scene[i], &w->mesh[i]));
    for (i = 0; i < INSTANCES; i++) {
        w->mesh_of[i] = i % MESHES;
        oc_transform(&rng, w->inst[i].transform, 12.0f);
        w->inst[i].id = 5000 + i;
        w->inst[i].mask = 1u << (i % 4);
    }
    for (i = 0; i < 9; i += 4) w->inst[3].transform[i] = -w->inst[3].transform[i]; /* a mirror */
    w->inst[6].transform[1] += 0.8f;                                               /* a shear */
    w->inst[8].transform[7] += 3e4f;                                               /* far away */
    w->inst[12] = w->inst[1]; /* the same mesh at the same place: every hit on it ties */
    w->mesh_of[12] = w->mesh_of[1];
    w->inst[12].id = 5012;
    w->inst[12].mask = 1u << 2;
}
static void oc_world_free(oc_world *w) {
    uint32_t i;
    for (i = 0; i < MESHES; i++) {
        bvh_free(&w->tree[i]);
        free(w->mesh[i].v);
    }
}
static void oc_world_build(oc_world *w, bvh_builder bottom, bvh_builder top, bvh_scene *sc) {
    bvh_scene_desc sd;
    uint32_t i;
    for (i = 0; i < MESHES; i++) {
        bvh_free(&w->tree[i]);
        assert_int_equal(oc_build(&w->mesh[i], bottom, &w->tree[i]), BVH_SUCCESS);
    }
    for (i = 0; i < INSTANCES; i++) w->inst[i].tree = &w->tree[w->mesh_of[i]];
    memset(&sd, 0, sizeof sd);
    sd.instances = w->inst;
    sd.instance_count = INSTANCES;
    sd.builder = top;
    sd.threads = 2;
    assert_int_equal(bvh_scene_build(sc, &sd), BVH_SUCCESS);
}

/* a mesh vertex (or edge point) of instance i in world space */
static bvh_vec3 oc_world_point(const oc_world *w, uint32_t i, uint64_t *rng, int edge) {
    const oc_scene *s = &w->mesh[w->mesh_of[i]];
    const float *m = w->inst[i].transform, *t = s->v + 9 * (size_t)(oc_rand(rng) % s->n);
    int a = (int)(oc_rand(rng) % 3), b = (a + 1) % 3;
    float p[3], f = edge ? oc_unit(rng) : 0.0f;
    bvh_vec3 q;
    int k;
    for (k = 0; k < 3; k++) p[k] = t[3 * a + k] + f * (t[3 * b + k] - t[3 * a + k]);
    q.x = m[0] * p[0] + m[1] * p[1] + m[2] * p[2] + m[3];
    q.y = m[4] * p[0] + m[5] * p[1] + m[6] * p[2] + m[7];
    q.z = m[8] * p[0] + m[9] * p[1] + m[10] * p[2] + m[11];
    return q;
}

/* Rays of eight kinds (i % 8): 0 random from anywhere in and around the instances (origins inside
   meshes' boxes too), 1 at an instance's origin, 2 at a vertex, 3 at an edge point, 4 grazing (in
   the plane of a triangle, from one of its vertices along an edge, nudged off it), 5
   axis-parallel, 6 at a vertex with a random [tmin, tmax], 7 invalid. */
static void oc_world_rays(const oc_world *w, bvh_ray *r, size_t count, uint64_t seed) {
    uint64_t rng = seed;
    size_t i;
    for (i = 0; i < count; i++) {
        int kind = (int)(i % 8), k;
        uint32_t in = oc_rand(&rng) % INSTANCES;
        float o[3], d[3];
        bvh_vec3 p;
        while (w->mesh_of[in] == 4) in = oc_rand(&rng) % INSTANCES; /* not the empty mesh */
        for (k = 0; k < 3; k++) {
            o[k] = oc_range(&rng, -16, 16);
            d[k] = oc_range(&rng, -1, 1);
        }
        r[i].tmin = 0.0f;
        r[i].tmax = BVH_INF;
        if (kind == 1) {
            d[0] = w->inst[in].transform[3] - o[0];
            d[1] = w->inst[in].transform[7] - o[1];
            d[2] = w->inst[in].transform[11] - o[2];
        } else if (kind == 2 || kind == 3 || kind == 6) {
            p = oc_world_point(w, in, &rng, kind == 3);
            d[0] = p.x - o[0];
            d[1] = p.y - o[1];
            d[2] = p.z - o[2];
            if (kind == 6) {
                r[i].tmin = oc_range(&rng, 0, 0.9f);
                r[i].tmax = oc_range(&rng, r[i].tmin, 1.2f);
            }
        } else if (kind == 4) {
            uint64_t again = rng; /* the same triangle and vertex twice: the vertex, then a point on its edge */
            bvh_vec3 a = oc_world_point(w, in, &rng, 0), b = oc_world_point(w, in, &again, 1);
            rng = again;
            o[0] = a.x;
            o[1] = a.y;
            o[2] = a.z;
            d[0] = b.x - a.x + oc_range(&rng, -1e-6f, 1e-6f);
            d[1] = b.y - a.y;
            d[2] = b.z - a.z;
            if (d[0] == 0 && d[1] == 0 && d[2] == 0) d[0] = 1;
        } else if (kind == 5) {
            d[0] = d[1] = d[2] = 0.0f;
            d[oc_rand(&rng) % 3] = (oc_rand(&rng) & 1) ? 1.0f : -2.0f;
        } else if (kind == 7) {
            switch ((i / 8) % 4) {
            case 0:
                o[0] = NAN;
                break;
            case 1:
                d[0] = d[1] = d[2] = 0.0f;
                break;
            case 2:
                r[i].tmin = 2.0f;
                r[i].tmax = 1.0f;
                break;
            default:
                d[1] = BVH_INF;
                break;
            }
        }
        r[i].origin.x = o[0];
        r[i].origin.y = o[1];
        r[i].origin.z = o[2];
        r[i].dir.x = d[0];
        r[i].dir.y = d[1];
        r[i].dir.z = d[2];
    }
}

/* Bit for bit on an exact device; elsewhere the same instance and triangle with t close (or the
   ambiguous cases of oc_hit_equal) and the normal within 1e-4. */
static int oc_scene_hit_equal(const bvh_ray *r, const bvh_scene_hit *a, const bvh_scene_hit *b) {
    bvh_hit ha, hb;
    if (g_info.exact) return memcmp(a, b, sizeof *a) == 0;
    ha.t = a->t, ha.u = a->u, ha.v = a->v, ha.prim = a->instance;
    hb.t = b->t, hb.u = b->u, hb.v = b->v, hb.prim = b->instance;
    if (!oc_hit_equal(r, &ha, &hb)) return 0;
    if (a->instance == BVH_INVALID || b->instance == BVH_INVALID) return 1;
    return a->instance == b->instance && a->prim == b->prim && a->id == b->id &&
           fabsf(a->normal.x - b->normal.x) < 1e-4f && fabsf(a->normal.y - b->normal.y) < 1e-4f &&
           fabsf(a->normal.z - b->normal.z) < 1e-4f;
}

/* Both sides for one mask; returns the rays that differ; *hits counts the CPU's hits. */
static size_t oc_scene_compare(const char *what, bvh_scene *sc, bvh_cl_scene *g, const bvh_ray *rays, size_t count,
                               uint32_t mask, bvh_scene_hit *cpu, size_t *hits) {
    bvh_scene_hit *gpu = (bvh_scene_hit *)calloc(count + 1, sizeof *gpu);
    uint8_t *occ = (uint8_t *)calloc(count + 1, 1);
    size_t i, bad = 0;
    assert_true(gpu && occ);
    memset(gpu, 0xAB, count * sizeof *gpu);
    assert_int_equal(bvh_cl_scene_intersect(g, rays, mask, gpu, count), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_scene_occluded(g, rays, mask, occ, count), BVH_CL_SUCCESS);
    for (i = 0; i < count; i++) {
        int found = bvh_scene_intersect(sc, &rays[i], mask, &cpu[i]), blocked = bvh_scene_occluded(sc, &rays[i], mask);
        *hits += (size_t)found;
        if (oc_scene_hit_equal(&rays[i], &cpu[i], &gpu[i]) && blocked == found && occ[i] == blocked) continue;
        if (bad++ >= MAX_REPORTS) continue;
        print_error("%s mask %x ray %zu o=(%a %a %a) d=(%a %a %a) [%a, %a]\n", what, mask, i, rays[i].origin.x,
                    rays[i].origin.y, rays[i].origin.z, rays[i].dir.x, rays[i].dir.y, rays[i].dir.z, rays[i].tmin,
                    rays[i].tmax);
        print_error("  cpu inst %u id %u prim %u t %a u %a v %a n (%a %a %a) any %d\n", cpu[i].instance, cpu[i].id,
                    cpu[i].prim, cpu[i].t, cpu[i].u, cpu[i].v, cpu[i].normal.x, cpu[i].normal.y, cpu[i].normal.z,
                    blocked);
        print_error("  ocl inst %u id %u prim %u t %a u %a v %a n (%a %a %a) any %d\n", gpu[i].instance, gpu[i].id,
                    gpu[i].prim, gpu[i].t, gpu[i].u, gpu[i].v, gpu[i].normal.x, gpu[i].normal.y, gpu[i].normal.z,
                    occ[i]);
    }
    free(gpu);
    free(occ);
    return bad;
}

/* Every builder at the bottom (the default on top), then every builder on top (the default at
   the bottom); four masks; the rays as made, then cut at the CPU's hit (tmax = t, and just below). */
static void scene_hits_equal_cpu(void **state) {
    static const uint32_t masks[4] = {~0u, 1u, 0x0Au, 0u};
    static oc_world w;
    const size_t n = RAYS;
    bvh_ray *rays = (bvh_ray *)malloc(n * sizeof *rays), *cut = (bvh_ray *)malloc(2 * n * sizeof *cut);
    bvh_scene_hit *cpu = (bvh_scene_hit *)malloc(2 * n * sizeof *cpu);
    size_t bad = 0, hits = 0, ties = 0;
    int pass;
    (void)state;
    NEED_DEVICE();
    assert_true(rays && cut && cpu);
    oc_world_make(&w);
    oc_world_rays(&w, rays, n, 0x5ce7e5u);
    for (pass = 0; pass < 2 * (BVH_BUILDER_COUNT - 1); pass++) {
        bvh_builder b = (bvh_builder)(pass % (BVH_BUILDER_COUNT - 1) + 1);
        bvh_builder bottom = pass < BVH_BUILDER_COUNT - 1 ? b : BVH_BUILDER_DEFAULT;
        bvh_builder top = pass < BVH_BUILDER_COUNT - 1 ? BVH_BUILDER_DEFAULT : b;
        bvh_scene sc;
        bvh_cl_scene *g = NULL;
        char what[96];
        size_t i, m, k;
        oc_world_build(&w, bottom, top, &sc);
        assert_int_equal(bvh_cl_scene_upload(g_cl, &sc, &g), BVH_CL_SUCCESS);
        snprintf(what, sizeof what, "bottom %s top %s", bvh_builder_name(bottom), bvh_builder_name(top));
        for (k = 0; k < 4; k++) {
            bad += oc_scene_compare(what, &sc, g, rays, n, masks[k], cpu, &hits);
            for (i = m = 0; i < n; i++) {
                if (cpu[i].instance == BVH_INVALID) continue;
                ties += cpu[i].instance == 1 && (masks[k] & 4);
                cut[m] = rays[i];
                cut[m++].tmax = cpu[i].t;
                cut[m] = rays[i];
                cut[m++].tmax = nextafterf(cpu[i].t, -BVH_INF);
            }
            bad += oc_scene_compare(what, &sc, g, cut, m, masks[k], cpu, &hits);
        }
        bvh_cl_scene_free(g);
        bvh_scene_free(&sc);
    }
    print_message("%zu hits, %zu on an instance with a twin\n", hits, ties);
    assert_true(hits > (size_t)n && ties > 0);
    oc_world_free(&w);
    free(rays);
    free(cut);
    free(cpu);
    assert_int_equal(bad, 0);
}

/* An empty scene, a scene of one instance of an empty tree, and a scene that is one mesh under
   the identity (its hits are the one-level tree's); small buffers: batches split, scenes refused. */
static void scene_edges(void **state) {
    static const float identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    oc_scene s, none;
    bvh_tree t, empty;
    bvh_instance inst[2];
    bvh_scene_desc sd;
    bvh_scene sc;
    bvh_cl_scene *g = NULL;
    bvh_cl_context *small = NULL;
    bvh_ray rays[1000];
    bvh_scene_hit a[1000], b[1000];
    bvh_hit one[1000];
    uint8_t occ[1000];
    size_t i;
    (void)state;
    NEED_DEVICE();
    assert_true(oc_scene_make(SC_RANDOM, &s));
    assert_true(oc_scene_make(SC_EMPTY, &none));
    assert_int_equal(oc_build(&s, BVH_BUILDER_PLOC, &t), BVH_SUCCESS);
    assert_int_equal(oc_build(&none, BVH_BUILDER_PLOC, &empty), BVH_SUCCESS);
    oc_rays(&s, rays, 1000, 99);
    memset(&sd, 0, sizeof sd);
    memset(inst, 0, sizeof inst);
    /* no instances */
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    assert_int_equal(bvh_cl_scene_upload(g_cl, &sc, &g), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_scene_intersect(g, rays, ~0u, a, 1000), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_scene_occluded(g, rays, ~0u, occ, 1000), BVH_CL_SUCCESS);
    for (i = 0; i < 1000; i++) {
        bvh_scene_intersect(&sc, &rays[i], ~0u, &b[i]);
        assert_int_equal(occ[i], 0);
    }
    assert_memory_equal(a, b, sizeof a);
    bvh_cl_scene_free(g);
    bvh_scene_free(&sc);
    /* one instance of an empty tree */
    inst[0].tree = &empty;
    memcpy(inst[0].transform, identity, sizeof identity);
    inst[0].mask = ~0u;
    sd.instances = inst;
    sd.instance_count = 1;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    assert_int_equal(bvh_cl_scene_upload(g_cl, &sc, &g), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_scene_intersect(g, rays, ~0u, a, 1000), BVH_CL_SUCCESS);
    for (i = 0; i < 1000; i++) assert_int_equal(a[i].instance, BVH_INVALID);
    bvh_cl_scene_free(g);
    bvh_scene_free(&sc);
    /* the mesh under the identity, and the empty tree after it */
    inst[1] = inst[0];
    inst[0].tree = &t;
    inst[0].id = 77;
    sd.instance_count = 2;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    assert_int_equal(bvh_cl_scene_upload(g_cl, &sc, &g), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_scene_intersect(g, rays, ~0u, a, 1000), BVH_CL_SUCCESS);
    for (i = 0; i < 1000; i++) {
        bvh_intersect(&t, &rays[i], &one[i]);
        bvh_scene_intersect(&sc, &rays[i], ~0u, &b[i]);
        if (!g_info.exact) continue;
        assert_memory_equal(&a[i], &b[i], sizeof a[i]);
        assert_int_equal(a[i].prim, one[i].prim);
        assert_int_equal(a[i].instance, one[i].prim == BVH_INVALID ? BVH_INVALID : 0);
        assert_int_equal(a[i].id, one[i].prim == BVH_INVALID ? BVH_INVALID : 77);
        assert_memory_equal(&a[i].t, &one[i].t, sizeof(float));
    }
    /* a max_alloc of 4 KiB: batches of 113 rays, the same hits; a tree of 108 KB refused */
    assert_int_equal(oc_create(&small, NULL, NULL, NULL, 4096, g_log, sizeof g_log), BVH_CL_SUCCESS);
    bvh_cl_scene_free(g);
    assert_int_equal(bvh_cl_scene_upload(small, &sc, &g), BVH_CL_ERROR_BUFFER_TOO_LARGE);
    assert_null(g);
    bvh_scene_free(&sc);
    inst[0].tree = &empty;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    assert_int_equal(bvh_cl_scene_upload(small, &sc, &g), BVH_CL_SUCCESS);
    memset(b, 0, sizeof b);
    assert_int_equal(bvh_cl_scene_intersect(g, rays, ~0u, b, 1000), BVH_CL_SUCCESS);
    for (i = 0; i < 1000; i++) {
        bvh_scene_hit h;
        bvh_scene_intersect(&sc, &rays[i], ~0u, &h);
        assert_memory_equal(&b[i], &h, sizeof h);
    }
    bvh_cl_scene_free(g);
    bvh_cl_destroy(small);
    bvh_scene_free(&sc);
    bvh_free(&t);
    bvh_free(&empty);
    free(s.v);
    free(none.v);
}

static int never_hit(const bvh_ray *ray, uint32_t prim, void *user, bvh_hit *hit) {
    (void)ray;
    (void)prim;
    (void)user;
    (void)hit;
    return 0;
}
/* Bad arguments get BVH_CL_ERROR_INVALID_ARGUMENT and leave *out NULL; count 0 is no error. */
static void scene_invalid_arguments(void **state) {
    bvh_custom_desc host_test = {never_hit, NULL};
    static const float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    bvh_cl_scene *g = (bvh_cl_scene *)&g;
    bvh_build_desc d;
    bvh_tree t, boxes;
    bvh_aabb box = {{0, 0, 0}, {1, 1, 1}};
    bvh_instance inst;
    bvh_scene_desc sd;
    bvh_scene sc, broken;
    bvh_ray ray = {{0.2f, 0.2f, -1}, 0, {0, 0, 1}, BVH_INF};
    bvh_scene_hit hit;
    uint8_t occ;
    (void)state;
    NEED_DEVICE();
    memset(&d, 0, sizeof d);
    d.triangles.positions = v;
    d.triangles.vertex_count = 3;
    d.triangles.triangle_count = 1;
    assert_int_equal(bvh_build(&t, &d), BVH_SUCCESS);
    memset(&d, 0, sizeof d);
    d.boxes = &box;
    d.box_count = 1;
    assert_int_equal(bvh_build(&boxes, &d), BVH_SUCCESS);
    memset(&inst, 0, sizeof inst);
    inst.tree = &t;
    inst.transform[0] = inst.transform[5] = inst.transform[10] = 1.0f;
    inst.mask = ~0u;
    inst.id = 9;
    memset(&sd, 0, sizeof sd);
    sd.instances = &inst;
    sd.instance_count = 1;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    assert_int_equal(bvh_cl_scene_upload(NULL, &sc, &g), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_null(g);
    assert_int_equal(bvh_cl_scene_upload(g_cl, NULL, &g), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_scene_upload(g_cl, &sc, NULL), BVH_CL_ERROR_INVALID_ARGUMENT);
    broken = sc; /* an instance of a tree built from boxes, without and with its callback */
    broken.instances = &inst;
    inst.tree = &boxes;
    assert_int_equal(bvh_cl_scene_upload(g_cl, &broken, &g), BVH_CL_ERROR_INVALID_ARGUMENT);
    inst.custom = &host_test; /* a device cannot call the host: refused, on a triangle tree too */
    assert_int_equal(bvh_cl_scene_upload(g_cl, &broken, &g), BVH_CL_ERROR_INVALID_ARGUMENT);
    inst.tree = &t;
    assert_int_equal(bvh_cl_scene_upload(g_cl, &broken, &g), BVH_CL_ERROR_INVALID_ARGUMENT);
    inst.custom = NULL;
    inst.tree = NULL;
    assert_int_equal(bvh_cl_scene_upload(g_cl, &broken, &g), BVH_CL_ERROR_INVALID_ARGUMENT);
    inst.tree = &t;
    broken.inverse = NULL;
    assert_int_equal(bvh_cl_scene_upload(g_cl, &broken, &g), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_null(g);
    assert_int_equal(bvh_cl_scene_upload(g_cl, &sc, &g), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_scene_intersect(NULL, &ray, ~0u, &hit, 1), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_scene_intersect(g, NULL, ~0u, &hit, 1), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_scene_intersect(g, &ray, ~0u, NULL, 1), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_scene_occluded(NULL, &ray, ~0u, &occ, 1), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_scene_occluded(g, &ray, ~0u, NULL, 1), BVH_CL_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_cl_scene_intersect(g, NULL, ~0u, NULL, 0), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_scene_occluded(g, NULL, ~0u, NULL, 0), BVH_CL_SUCCESS);
    assert_int_equal(bvh_cl_scene_intersect(g, &ray, ~0u, &hit, 1), BVH_CL_SUCCESS);
    assert_int_equal(hit.instance, 0);
    assert_int_equal(hit.id, 9);
    assert_int_equal(bvh_cl_scene_intersect(g, &ray, 0u, &hit, 1), BVH_CL_SUCCESS); /* mask 0: nothing */
    assert_int_equal(hit.instance, BVH_INVALID);
    bvh_cl_scene_free(g);
    bvh_cl_scene_free(NULL);
    bvh_scene_free(&sc);
    bvh_free(&t);
    bvh_free(&boxes);
}

static int group_setup(void **state) {
    bvh_cl_desc d;
    (void)state;
    memset(&d, 0, sizeof d);
    d.log = g_log;
    d.log_size = sizeof g_log;
    g_create_result = bvh_cl_create(&g_cl, &d);
    if (g_cl) bvh_cl_get_info(g_cl, &g_info);
    return 0;
}
static int group_teardown(void **state) {
    (void)state;
    bvh_cl_destroy(g_cl);
    g_cl = NULL;
    return 0;
}

#define SCENE_TEST(name, fn, id)                                                                                       \
    { name, fn, NULL, NULL, (void *)(intptr_t)(id) }

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(device_available),
        SCENE_TEST("hits_random", hits_equal_cpu, SC_RANDOM),
        SCENE_TEST("hits_quads", hits_equal_cpu, SC_QUADS),
        SCENE_TEST("hits_huge_triangle", hits_equal_cpu, SC_HUGE),
        SCENE_TEST("hits_one_triangle", hits_equal_cpu, SC_ONE),
        SCENE_TEST("hits_two_triangles", hits_equal_cpu, SC_TWO),
        SCENE_TEST("hits_three_triangles", hits_equal_cpu, SC_THREE),
        SCENE_TEST("hits_empty", hits_equal_cpu, SC_EMPTY),
        SCENE_TEST("frame_random", frame_equals_cpu, SC_RANDOM),
        SCENE_TEST("frame_quads", frame_equals_cpu, SC_QUADS),
        SCENE_TEST("frame_huge_triangle", frame_equals_cpu, SC_HUGE),
        cmocka_unit_test(small_allocations_split_work),
        cmocka_unit_test(frame_rays_option),
        cmocka_unit_test(buffer_too_large),
        cmocka_unit_test(bad_kernel_source),
        cmocka_unit_test(no_platform_or_device),
        cmocka_unit_test(invalid_arguments),
        cmocka_unit_test(caller_allocator),
        cmocka_unit_test(scene_hits_equal_cpu),
        cmocka_unit_test(scene_edges),
        cmocka_unit_test(scene_invalid_arguments),
    };
    return cmocka_run_group_tests(tests, group_setup, group_teardown);
}
