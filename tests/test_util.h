/* tests/test_util.h - shared helpers of the bvh.h tests (cmocka).

   A deterministic RNG (PCG32), scene generators, a tiny OBJ reader for the Stanford bunny of
   glmark2-data, a brute-force closest hit over all triangles (bvh_intersect_triangle, lowest
   triangle index wins at equal t) and random ray sets that aim at the hard cases: axis-parallel
   rays with +0.0 and -0.0 components, origins inside the scene and at exact vertex coordinates,
   rays through exact vertices, finite tmax.

   Include after bvh.h (with BVH_IMPLEMENTATION in the test file). Every function is static
   inline so that a test file may use any subset of them without unused-function warnings. */
#ifndef TEST_UTIL_H
#define TEST_UTIL_H

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bvh.h"
#include "fp_bits.h"

#define TU_FN static inline
#define TU_BUNNY_PATH "/usr/share/glmark2/models/bunny.obj"
#define TU_RAYS 10000 /* rays per scene in the exactness tests */

/* Every real builder, i = 0 .. TU_BUILDER_COUNT - 1: the builder table's rows after
   BVH_BUILDER_DEFAULT (which stands for ploc-parallel). */
#define TU_BUILDER_COUNT (BVH_BUILDER_COUNT - 1)
TU_FN bvh_builder tu_builder(int i) { return (bvh_builder)(i + 1); }
/* Largest leaf a builder makes by default (bvh_build_desc.max_leaf_size = 0): its table row. */
TU_FN uint32_t tu_default_leaf(bvh_builder b) {
    bvh_builder_info info;
    if (bvh_builder_get_info(b, &info) != BVH_SUCCESS) return 0;
    return info.max_leaf_size;
}

/* cmocka_unit_test_prestate passes an integer (a scene id) as the state; + 1 keeps it non-NULL. */
#define TU_STATE(id) ((void *)(uintptr_t)((id) + 1))
TU_FN int tu_state_id(void **state) { return (int)((uintptr_t)*state - 1); }
/* A cmocka test named "function/label" that runs on scene `id`. */
#define TU_SCENE_TEST(f, id, label)                                                                                    \
    { #f "/" label, f, NULL, NULL, TU_STATE(id) }
/* The same, once per scene (the bunny last). */
#define TU_EVERY_SCENE(f)                                                                                              \
    TU_SCENE_TEST(f, TU_SCENE_RANDOM, "random"), TU_SCENE_TEST(f, TU_SCENE_GRID, "grid"),                              \
        TU_SCENE_TEST(f, TU_SCENE_HUGE, "huge"), TU_SCENE_TEST(f, TU_SCENE_ONE, "1-triangle"),                         \
        TU_SCENE_TEST(f, TU_SCENE_TWO, "2-triangles"), TU_SCENE_TEST(f, TU_SCENE_THREE, "3-triangles"),                \
        TU_SCENE_TEST(f, TU_SCENE_STRIDED32, "indexed-stride-32"),                                                     \
        TU_SCENE_TEST(f, TU_SCENE_STRIDED16, "soup-stride-16"), TU_SCENE_TEST(f, TU_SCENE_DUPLICATES, "duplicates"),   \
        TU_SCENE_TEST(f, TU_SCENE_CHAIN, "chain"), TU_SCENE_TEST(f, TU_SCENE_BUNNY, "bunny")

/* == deterministic RNG (PCG32, O'Neill 2014) ================================================ */
typedef struct tu_rng {
    uint64_t state, inc;
} tu_rng;

TU_FN uint32_t tu_u32(tu_rng *r) {
    uint64_t old = r->state;
    uint32_t x, rot;
    r->state = old * 6364136223846793005ULL + r->inc;
    x = (uint32_t)(((old >> 18) ^ old) >> 27);
    rot = (uint32_t)(old >> 59);
    return (x >> rot) | (x << ((32u - rot) & 31u));
}
TU_FN tu_rng tu_rng_make(uint64_t seed) {
    tu_rng r;
    r.state = 0;
    r.inc = (seed << 1) | 1u;
    tu_u32(&r);
    r.state += seed ^ 0x853c49e6748fea9bULL;
    tu_u32(&r);
    return r;
}
TU_FN float tu_unit(tu_rng *r) { return (float)(tu_u32(r) >> 8) * (1.0f / 16777216.0f); } /* [0, 1) */
TU_FN float tu_range(tu_rng *r, float lo, float hi) { return lo + (hi - lo) * tu_unit(r); }
TU_FN uint32_t tu_below(tu_rng *r, uint32_t n) { return (uint32_t)(((uint64_t)tu_u32(r) * n) >> 32); }

/* == scenes ================================================================================= */
/* A triangle mesh as the caller of bvh_build would hold it: vertex data with a byte stride
   (x, y, z first, then anything), optional indices. */
typedef struct tu_scene {
    char name[32];
    float *data;   /* vertex_count vertices of stride bytes */
    size_t stride; /* bytes between vertices; 0 = 12 */
    uint32_t vertex_count;
    uint32_t *indices; /* 3 per triangle, NULL for a soup */
    uint32_t tri_count;
} tu_scene;

TU_FN size_t tu_stride(const tu_scene *s) { return s->stride ? s->stride : 3 * sizeof(float); }
TU_FN float *tu_vertex(const tu_scene *s, uint32_t v) {
    return (float *)(void *)((char *)(void *)s->data + (size_t)v * tu_stride(s));
}
TU_FN void tu_scene_tri(const tu_scene *s, uint32_t i, float out[9]) {
    int k;
    for (k = 0; k < 3; k++) {
        uint32_t v = s->indices ? s->indices[3 * (size_t)i + k] : 3 * i + (uint32_t)k;
        memcpy(out + 3 * k, tu_vertex(s, v), 3 * sizeof(float));
    }
}
/* All triangles as 9 floats each (caller frees). */
TU_FN float *tu_scene_tris(const tu_scene *s) {
    float *t = (float *)malloc(9 * sizeof(float) * (s->tri_count ? s->tri_count : 1));
    uint32_t i;
    assert_non_null(t);
    for (i = 0; i < s->tri_count; i++) tu_scene_tri(s, i, t + 9 * (size_t)i);
    return t;
}
TU_FN int tu_finite9(const float *t) {
    int k;
    for (k = 0; k < 9; k++)
        if (!fp_finite(t[k])) return 0;
    return 1;
}
TU_FN bvh_aabb tu_tri_box(const float *t) {
    bvh_aabb b = bvh_aabb_empty();
    int k;
    for (k = 0; k < 3; k++) {
        bvh_vec3 p;
        p.x = t[3 * k];
        p.y = t[3 * k + 1];
        p.z = t[3 * k + 2];
        bvh_aabb_grow(&b, p);
    }
    return b;
}
/* Bounds of the finite triangles. */
TU_FN bvh_aabb tu_scene_bounds(const tu_scene *s) {
    bvh_aabb b = bvh_aabb_empty();
    float t[9];
    uint32_t i;
    for (i = 0; i < s->tri_count; i++) {
        tu_scene_tri(s, i, t);
        if (tu_finite9(t)) b = bvh_aabb_merge(b, tu_tri_box(t));
    }
    return b;
}
TU_FN bvh_build_desc tu_scene_desc(const tu_scene *s, bvh_builder builder) {
    bvh_build_desc d;
    memset(&d, 0, sizeof d);
    d.builder = builder;
    d.triangles.positions = s->data;
    d.triangles.stride = s->stride;
    d.triangles.vertex_count = s->vertex_count;
    d.triangles.indices = s->indices;
    d.triangles.triangle_count = s->tri_count;
    return d;
}
TU_FN void tu_scene_free(tu_scene *s) {
    free(s->data);
    free(s->indices);
    memset(s, 0, sizeof *s);
}
TU_FN void tu_scene_alloc(tu_scene *s, const char *name, uint32_t vertex_count, size_t stride, uint32_t index_count) {
    size_t floats = (size_t)vertex_count * (stride ? stride : 12) / sizeof(float);
    memset(s, 0, sizeof *s);
    snprintf(s->name, sizeof s->name, "%s", name);
    s->data = (float *)calloc(floats ? floats : 1, sizeof(float));
    assert_non_null(s->data);
    s->stride = stride;
    s->vertex_count = vertex_count;
    if (index_count) {
        s->indices = (uint32_t *)malloc(index_count * sizeof(uint32_t));
        assert_non_null(s->indices);
    }
}
TU_FN void tu_set3(float *p, float x, float y, float z) {
    p[0] = x;
    p[1] = y;
    p[2] = z;
}

/* n small random triangles (edges up to ~1) in the cube [-10, 10]^3, a soup. */
TU_FN void tu_scene_random(tu_scene *s, uint32_t n, uint64_t seed) {
    tu_rng r = tu_rng_make(seed);
    uint32_t i;
    tu_scene_alloc(s, "random", 3 * n, 0, 0);
    s->tri_count = n;
    for (i = 0; i < n; i++) {
        float cx = tu_range(&r, -10, 10), cy = tu_range(&r, -10, 10), cz = tu_range(&r, -10, 10);
        int k;
        for (k = 0; k < 3; k++)
            tu_set3(tu_vertex(s, 3 * i + k), cx + tu_range(&r, -0.5f, 0.5f), cy + tu_range(&r, -0.5f, 0.5f),
                    cz + tu_range(&r, -0.5f, 0.5f));
    }
}

/* Adds a (nu x nv)-cell lattice on the plane `axis` = w: u and v are the two other axes, vertex
   coordinates are multiples of h (exact in binary); quads split along alternating diagonals. */
TU_FN void tu_grid_plane(tu_scene *s, uint32_t *vbase, uint32_t *tbase, int axis, float w, uint32_t nu, uint32_t nv,
                         float h) {
    uint32_t i, j, b = *vbase;
    int au = (axis + 1) % 3, av = (axis + 2) % 3;
    for (j = 0; j <= nv; j++)
        for (i = 0; i <= nu; i++) {
            float *p = tu_vertex(s, b + j * (nu + 1) + i);
            p[axis] = w;
            p[au] = (float)i * h;
            p[av] = (float)j * h;
        }
    for (j = 0; j < nv; j++)
        for (i = 0; i < nu; i++) {
            uint32_t v00 = b + j * (nu + 1) + i, v10 = v00 + 1, v01 = v00 + nu + 1, v11 = v01 + 1;
            uint32_t *t = s->indices + 3 * (size_t)*tbase;
            if ((i + j) & 1) {
                t[0] = v00;
                t[1] = v10;
                t[2] = v11;
                t[3] = v00;
                t[4] = v11;
                t[5] = v01;
            } else {
                t[0] = v00;
                t[1] = v10;
                t[2] = v01;
                t[3] = v10;
                t[4] = v11;
                t[5] = v01;
            }
            *tbase += 2;
        }
    *vbase += (nu + 1) * (nv + 1);
}
/* Axis-aligned lattices: four z planes of 16 x 16 cells and five x planes crossing them, all on
   multiples of 0.5 - exactly coplanar triangles, shared edges and vertices everywhere. */
TU_FN void tu_scene_grid(tu_scene *s) {
    uint32_t nv = 4 * 17 * 17 + 5 * 17 * 7, nt = 4 * 16 * 16 * 2 + 5 * 16 * 6 * 2, vb = 0, tb = 0, k;
    tu_scene_alloc(s, "grid", nv, 0, 3 * nt);
    for (k = 0; k < 4; k++) tu_grid_plane(s, &vb, &tb, 2, (float)k, 16, 16, 0.5f); /* z = 0..3, x,y in [0,8] */
    for (k = 0; k < 5; k++)
        tu_grid_plane(s, &vb, &tb, 0, 2.0f * (float)k, 16, 6, 0.5f); /* x = 0..8, y in [0,8], z in [0,3] */
    assert_int_equal(vb, nv);
    assert_int_equal(tb, nt);
    s->tri_count = nt;
}

/* 2000 small random triangles and, at index 1000, one triangle 100 times larger than the scene. */
TU_FN void tu_scene_huge(tu_scene *s) {
    tu_scene_random(s, 2001, 0x4855474555ULL);
    snprintf(s->name, sizeof s->name, "huge");
    tu_set3(tu_vertex(s, 3000), -1000, -1000, -3);
    tu_set3(tu_vertex(s, 3001), 1000, -1000, 3);
    tu_set3(tu_vertex(s, 3002), 0, 1000, 0.5f);
}

/* 1, 2 or 3 triangles: one; a quad (two triangles sharing an edge); the same triangle twice
   (exact ties) and a third one behind them. */
TU_FN void tu_scene_few(tu_scene *s, uint32_t n) {
    static const float v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1,  0,  0, 1, 1,  0, 0,  1, 0,
                              0, 0, 0, 1, 0, 0, 0, 1, 0, -1, -1, 1, 2, -1, 1, -1, 2, 1};
    static const uint32_t quad[] = {0, 1, 2, 3, 4, 5};
    static const uint32_t twice[] = {0, 1, 2, 6, 7, 8, 9, 10, 11};
    char name[32];
    uint32_t k;
    snprintf(name, sizeof name, "%u-triangle%s", n, n > 1 ? "s" : "");
    tu_scene_alloc(s, name, 12, 0, 3 * n);
    memcpy(s->data, v, sizeof v);
    for (k = 0; k < 3 * n; k++) s->indices[k] = n == 1 ? k : n == 2 ? quad[k] : twice[k];
    s->tri_count = n;
}

/* An indexed height field whose vertices are 8 floats (32 bytes: position, normal, uv); every
   float after the position is NaN, so reading with a wrong stride is refused, not ignored. */
TU_FN void tu_scene_strided32(tu_scene *s) {
    const uint32_t n = 40; /* cells per side */
    uint32_t i, j, t = 0, k;
    tu_scene_alloc(s, "indexed-stride-32", (n + 1) * (n + 1), 32, 6 * n * n);
    for (j = 0; j <= n; j++)
        for (i = 0; i <= n; i++) {
            float *p = tu_vertex(s, j * (n + 1) + i);
            float x = (float)i * 0.25f, y = (float)j * 0.25f;
            tu_set3(p, x, y, 0.7f * sinf(x) * cosf(1.3f * y));
            for (k = 3; k < 8; k++) p[k] = NAN;
        }
    for (j = 0; j < n; j++)
        for (i = 0; i < n; i++) {
            uint32_t v00 = j * (n + 1) + i, v10 = v00 + 1, v01 = v00 + n + 1, v11 = v01 + 1;
            uint32_t *q = s->indices + 3 * (size_t)t;
            q[0] = v00;
            q[1] = v10;
            q[2] = v11;
            q[3] = v00;
            q[4] = v11;
            q[5] = v01;
            t += 2;
        }
    s->tri_count = t;
}
/* A soup of random triangles whose vertices are 4 floats (16 bytes), the fourth NaN. */
TU_FN void tu_scene_strided16(tu_scene *s) {
    tu_scene tmp;
    uint32_t v;
    tu_scene_random(&tmp, 1500, 0x5354524944ULL);
    tu_scene_alloc(s, "soup-stride-16", tmp.vertex_count, 16, 0);
    for (v = 0; v < tmp.vertex_count; v++) {
        memcpy(tu_vertex(s, v), tu_vertex(&tmp, v), 3 * sizeof(float));
        tu_vertex(s, v)[3] = NAN;
    }
    s->tri_count = tmp.tri_count;
    tu_scene_free(&tmp);
}

/* Exact ties and degenerate input: 48 random triangles, each present 8 times (copy c of
   triangle j at index 48 c + j), then zero-area triangles (points and segments) in the mix,
   then 300 copies of one more triangle (all centroids equal). */
TU_FN void tu_scene_duplicates(tu_scene *s) {
    tu_scene base;
    uint32_t c, j, t = 0;
    const uint32_t nd = 48 * 8 + 64 + 300;
    tu_scene_random(&base, 49, 0x445550ULL);
    tu_scene_alloc(s, "duplicates", 3 * nd, 0, 0);
    for (c = 0; c < 8; c++)
        for (j = 0; j < 48; j++, t++) memcpy(tu_vertex(s, 3 * t), tu_vertex(&base, 3 * j), 9 * sizeof(float));
    for (j = 0; j < 64; j++, t++) {
        float *p = tu_vertex(s, 3 * t), *q = tu_vertex(&base, 3 * (j % 48));
        memcpy(p, q, 9 * sizeof(float));
        memcpy(p + 3, j & 1 ? q : q + 3, 3 * sizeof(float)); /* odd: a segment, even: v1 twice */
        if (j % 4 == 0) {
            memcpy(p + 3, q, 3 * sizeof(float));
            memcpy(p + 6, q, 3 * sizeof(float));
        } /* a point */
    }
    for (j = 0; j < 300; j++, t++) memcpy(tu_vertex(s, 3 * t), tu_vertex(&base, 3 * 48), 9 * sizeof(float));
    s->tri_count = t;
    tu_scene_free(&base);
}

/* 160 triangles side by side along x with widths growing by 1.25 each (1e-2 .. ~3e13): nearest-
   neighbour clustering merges them into a chain far deeper than BVH_MAX_DEPTH. */
TU_FN void tu_scene_chain(tu_scene *s) {
    uint32_t i, n = 160;
    float x = 0.0f, w = 0.01f;
    tu_scene_alloc(s, "chain", 3 * n, 0, 0);
    for (i = 0; i < n; i++) {
        tu_set3(tu_vertex(s, 3 * i), x, 0, 0);
        tu_set3(tu_vertex(s, 3 * i + 1), x + w, 0, w * 0.5f);
        tu_set3(tu_vertex(s, 3 * i + 2), x + 0.5f * w, w, 0);
        x += w;
        w *= 1.25f;
    }
    s->tri_count = n;
}

/* == a tiny OBJ reader: v and f lines, polygons as fans, v, v/vt, v//vn, v/vt/vn, negative
   (relative) indices. Returns 1 on success. ================================================== */
/* Returns buf grown to hold `need` elements (on failure: buf unchanged and *ok = 0). */
TU_FN void *tu_grow(void *buf, size_t *cap, size_t need, size_t elem, int *ok) {
    size_t c = *cap;
    void *p;
    if (need <= c) return buf;
    while (c < need) c = c ? 2 * c : 1024;
    p = realloc(buf, c * elem);
    if (!p) {
        *ok = 0;
        return buf;
    }
    *cap = c;
    return p;
}
TU_FN int tu_load_obj(const char *path, tu_scene *s) {
    FILE *f = fopen(path, "r");
    char line[1024];
    float *v = NULL;
    uint32_t *idx = NULL;
    size_t vn = 0, vcap = 0, in = 0, icap = 0;
    int ok = 1;
    if (!f) return 0;
    while (ok && fgets(line, sizeof line, f)) {
        char *p = line;
        while (*p == ' ' || *p == '\t') p++;
        if (p[0] == 'v' && (p[1] == ' ' || p[1] == '\t')) {
            char *e;
            int k;
            v = (float *)tu_grow(v, &vcap, vn + 3, sizeof(float), &ok);
            if (!ok) break;
            for (k = 0, p += 2; ok && k < 3; k++, p = e) {
                v[vn + k] = strtof(p, &e);
                if (e == p) ok = 0;
            }
            vn += 3;
        } else if (p[0] == 'f' && (p[1] == ' ' || p[1] == '\t')) {
            long poly[64];
            int np = 0, k;
            p += 2;
            for (;;) {
                char *e;
                long i;
                while (*p == ' ' || *p == '\t') p++;
                if (*p == 0 || *p == '\n' || *p == '\r') break;
                i = strtol(p, &e, 10);
                if (e == p || np == 64) {
                    ok = 0;
                    break;
                }
                i = i < 0 ? (long)(vn / 3) + i : i - 1; /* to 0-based */
                if (i < 0 || (size_t)i >= vn / 3) {
                    ok = 0;
                    break;
                }
                poly[np++] = i;
                p = e;
                while (*p && *p != ' ' && *p != '\t' && *p != '\n' && *p != '\r') p++; /* skip /vt/vn */
            }
            if (ok && np < 3) ok = 0;
            for (k = 1; ok && k + 1 < np; k++) {
                idx = (uint32_t *)tu_grow(idx, &icap, in + 3, sizeof(uint32_t), &ok);
                if (!ok) break;
                idx[in++] = (uint32_t)poly[0];
                idx[in++] = (uint32_t)poly[k];
                idx[in++] = (uint32_t)poly[k + 1];
            }
        }
    }
    fclose(f);
    if (!ok || in == 0) {
        free(v);
        free(idx);
        return 0;
    }
    memset(s, 0, sizeof *s);
    snprintf(s->name, sizeof s->name, "bunny");
    s->data = v;
    s->vertex_count = (uint32_t)(vn / 3);
    s->indices = idx;
    s->tri_count = (uint32_t)(in / 3);
    return 1;
}
/* Loads the bunny (TU_BUNNY_PATH, or the file named by $BVH_TEST_BUNNY). Missing: fails the test
   when CI=true, else returns 0 (the caller skips). */
TU_FN int tu_scene_bunny(tu_scene *s) {
    const char *ci = getenv("CI"), *path = getenv("BVH_TEST_BUNNY");
    if (!path || !*path) path = TU_BUNNY_PATH;
    if (tu_load_obj(path, s)) return 1;
    if (ci && strcmp(ci, "true") == 0) fail_msg("CI=true and %s is missing or unreadable (glmark2-data)", path);
    print_message("bunny skipped: %s not found (install glmark2-data)\n", path);
    return 0;
}

/* The scenes every property test runs on; TU_SCENE_BUNNY may be unavailable (returns 0). */
enum {
    TU_SCENE_RANDOM,
    TU_SCENE_GRID,
    TU_SCENE_HUGE,
    TU_SCENE_ONE,
    TU_SCENE_TWO,
    TU_SCENE_THREE,
    TU_SCENE_STRIDED32,
    TU_SCENE_STRIDED16,
    TU_SCENE_DUPLICATES,
    TU_SCENE_CHAIN,
    TU_SCENE_BUNNY,
    TU_SCENE_COUNT
};
TU_FN int tu_scene_make(int id, tu_scene *s) {
    switch (id) {
    case TU_SCENE_RANDOM:
        tu_scene_random(s, 3000, 0x52414e44ULL);
        return 1;
    case TU_SCENE_GRID:
        tu_scene_grid(s);
        return 1;
    case TU_SCENE_HUGE:
        tu_scene_huge(s);
        return 1;
    case TU_SCENE_ONE:
        tu_scene_few(s, 1);
        return 1;
    case TU_SCENE_TWO:
        tu_scene_few(s, 2);
        return 1;
    case TU_SCENE_THREE:
        tu_scene_few(s, 3);
        return 1;
    case TU_SCENE_STRIDED32:
        tu_scene_strided32(s);
        return 1;
    case TU_SCENE_STRIDED16:
        tu_scene_strided16(s);
        return 1;
    case TU_SCENE_DUPLICATES:
        tu_scene_duplicates(s);
        return 1;
    case TU_SCENE_CHAIN:
        tu_scene_chain(s);
        return 1;
    case TU_SCENE_BUNNY:
        return tu_scene_bunny(s);
    default:
        fail_msg("no scene %d", id);
        return 0;
    }
}

/* == building ================================================================================ */
/* Builds and validates (against the triangles and against caller-side boxes), printing the
   validator's message on failure. */
TU_FN void tu_build_valid(const tu_scene *s, bvh_build_desc *d, bvh_tree *t) {
    bvh_validation rep;
    bvh_result r = bvh_build(t, d);
    if (r != BVH_SUCCESS) fail_msg("%s/%s: bvh_build: %s", s->name, bvh_builder_name(d->builder), bvh_result_string(r));
    r = bvh_validate(t, NULL, &rep);
    if (r != BVH_SUCCESS)
        fail_msg("%s/%s: bvh_validate: %s (node %u)", s->name, bvh_builder_name(d->builder), rep.message, rep.node);
    assert_string_equal(rep.message, "ok");
}
TU_FN void tu_build(const tu_scene *s, bvh_builder b, bvh_tree *t) {
    bvh_build_desc d = tu_scene_desc(s, b);
    tu_build_valid(s, &d, t);
}

/* == brute force ============================================================================= */
/* Closest hit over all triangles with bvh_intersect_triangle; at equal t the lowest triangle
   index wins (the loop runs in index order and only a strictly smaller t replaces). Triangles
   with a non-finite coordinate are skipped, as skip_invalid leaves them out of the tree. */
TU_FN int tu_brute(const float *tris, uint32_t n, const bvh_ray *ray, bvh_hit *best) {
    uint32_t i;
    best->t = ray->tmax;
    best->u = best->v = 0.0f;
    best->prim = BVH_INVALID;
    for (i = 0; i < n; i++) {
        const float *t = tris + 9 * (size_t)i;
        bvh_hit h;
        if (!bvh_intersect_triangle(ray, t, t + 3, t + 6, &h)) continue;
        if (best->prim != BVH_INVALID && !(h.t < best->t)) continue;
        if (!tu_finite9(t)) continue;
        *best = h;
        best->prim = i;
    }
    return best->prim != BVH_INVALID;
}

/* The same result, faster: a triangle is only tested when the ray's [tmin, tmax] segment passes
   through its box grown by 1e-4 of the coordinates' magnitude (in double precision), and groups of
   TU_GROUP triangles close in Morton order are skipped when the segment misses their joint box,
   grown the same way. A watertight hit lies on the triangle up to a few float ulps of those
   magnitudes (t is a convex combination of the vertices' distances), so no skipped test could
   hit; ties go to the lowest index explicitly. The result is bitwise the one of tu_brute, which
   tu_oracle_run checks on a few hundred rays per set. */
#define TU_GROUP 16
typedef struct tu_oracle {
    const float *tris;
    uint32_t n;
    uint32_t *order; /* triangle ids by Morton code of their box centre */
    float *boxes;    /* 6 per triangle in `order` (min, max); empty for non-finite triangles */
    float *groups;   /* 6 per group of TU_GROUP consecutive entries of `order` */
    double scale;    /* largest finite coordinate magnitude */
} tu_oracle;
typedef struct tu_keyed {
    uint32_t key, id;
} tu_keyed;
TU_FN int tu_keyed_cmp(const void *a, const void *b) {
    const tu_keyed *x = (const tu_keyed *)a, *y = (const tu_keyed *)b;
    return x->key != y->key ? (x->key < y->key ? -1 : 1) : (x->id < y->id ? -1 : x->id > y->id);
}
TU_FN uint32_t tu_spread10(uint32_t v) { /* 10 bits to every third bit */
    v &= 0x3ffu;
    v = (v | v << 16) & 0x030000ffu;
    v = (v | v << 8) & 0x0300f00fu;
    v = (v | v << 4) & 0x030c30c3u;
    v = (v | v << 2) & 0x09249249u;
    return v;
}
TU_FN uint32_t tu_quant(float x, float lo, float hi) {
    float f = hi > lo ? (x - lo) / (hi - lo) * 1023.0f : 0.0f;
    return f < 0.0f ? 0u : f > 1023.0f ? 1023u : (uint32_t)f;
}
TU_FN void tu_oracle_init(tu_oracle *o, const float *tris, uint32_t n) {
    uint32_t i, ng = (n + TU_GROUP - 1) / TU_GROUP;
    tu_keyed *keyed = (tu_keyed *)malloc(sizeof(tu_keyed) * (n ? n : 1));
    bvh_aabb all = bvh_aabb_empty();
    int k;
    o->tris = tris;
    o->n = n;
    o->scale = 0.0;
    o->order = (uint32_t *)malloc(sizeof(uint32_t) * (n ? n : 1));
    o->boxes = (float *)malloc(6 * sizeof(float) * (n ? n : 1));
    o->groups = (float *)malloc(6 * sizeof(float) * (ng ? ng : 1));
    assert_true(keyed && o->order && o->boxes && o->groups);
    for (i = 0; i < n; i++) {
        const float *t = tris + 9 * (size_t)i;
        if (!tu_finite9(t)) continue;
        all = bvh_aabb_merge(all, tu_tri_box(t));
        for (k = 0; k < 9; k++) o->scale = fabs(t[k]) > o->scale ? fabs(t[k]) : o->scale;
    }
    for (i = 0; i < n; i++) {
        const float *t = tris + 9 * (size_t)i;
        bvh_vec3 c = bvh_aabb_centroid(tu_tri_box(t));
        keyed[i].id = i;
        keyed[i].key = tu_finite9(t) ? tu_spread10(tu_quant(c.x, all.min.x, all.max.x)) << 2 |
                                           tu_spread10(tu_quant(c.y, all.min.y, all.max.y)) << 1 |
                                           tu_spread10(tu_quant(c.z, all.min.z, all.max.z))
                                     : 0xffffffffu;
    }
    qsort(keyed, n, sizeof *keyed, tu_keyed_cmp);
    for (i = 0; i < ng; i++) {
        bvh_aabb e = bvh_aabb_empty();
        memcpy(o->groups + 6 * (size_t)i, &e, 6 * sizeof(float));
    }
    for (i = 0; i < n; i++) {
        const float *t = tris + 9 * (size_t)keyed[i].id;
        bvh_aabb b = tu_finite9(t) ? tu_tri_box(t) : bvh_aabb_empty(), g;
        float *gp = o->groups + 6 * (size_t)(i / TU_GROUP);
        o->order[i] = keyed[i].id;
        memcpy(o->boxes + 6 * (size_t)i, &b, 6 * sizeof(float));
        memcpy(&g, gp, sizeof g);
        g = bvh_aabb_merge(g, b);
        memcpy(gp, &g, sizeof g);
    }
    free(keyed);
}
TU_FN void tu_oracle_free(tu_oracle *o) {
    free(o->order);
    free(o->boxes);
    free(o->groups);
    o->order = NULL;
    o->boxes = o->groups = NULL;
}
/* Does the segment [tmin, tmax] of the ray (origin org, 1/dir in inv, 0 for a zero component)
   pass through the box bx grown by pad? In double precision. */
TU_FN int tu_segment_meets(const float *bx, const float *org, const float *dir, const double *inv, double tmin,
                           double tmax, double pad) {
    int a;
    for (a = 0; a < 3; a++) {
        double lo = (double)bx[a] - pad, hi = (double)bx[3 + a] + pad, o0 = org[a];
        if (dir[a] == 0.0f) {
            if (o0 < lo || o0 > hi) return 0;
        } else {
            double t0 = (lo - o0) * inv[a], t1 = (hi - o0) * inv[a];
            if (t0 > t1) {
                double x = t0;
                t0 = t1;
                t1 = x;
            }
            tmin = t0 > tmin ? t0 : tmin;
            tmax = t1 < tmax ? t1 : tmax;
            if (!(tmin <= tmax)) return 0;
        }
    }
    return 1;
}
TU_FN int tu_brute_culled(const tu_oracle *o, const bvh_ray *ray, bvh_hit *best) {
    const float *org = &ray->origin.x, *dir = &ray->dir.x;
    double inv[3], pad = o->scale;
    uint32_t g, i;
    int a;
    best->t = ray->tmax;
    best->u = best->v = 0.0f;
    best->prim = BVH_INVALID;
    for (a = 0; a < 3; a++) {
        if (!fp_finite(org[a]) || !fp_finite(dir[a])) return 0; /* bvh_intersect_triangle refuses it */
        inv[a] = dir[a] != 0.0f ? 1.0 / (double)dir[a] : 0.0;
        pad = fabs((double)org[a]) > pad ? fabs((double)org[a]) : pad;
    }
    pad *= 1e-4;
    for (g = 0; g * TU_GROUP < o->n; g++) {
        uint32_t end = (g + 1) * TU_GROUP < o->n ? (g + 1) * TU_GROUP : o->n;
        if (!tu_segment_meets(o->groups + 6 * (size_t)g, org, dir, inv, ray->tmin, ray->tmax, pad)) continue;
        for (i = g * TU_GROUP; i < end; i++) {
            uint32_t id = o->order[i];
            const float *t = o->tris + 9 * (size_t)id;
            bvh_hit h;
            if (!tu_segment_meets(o->boxes + 6 * (size_t)i, org, dir, inv, ray->tmin, ray->tmax, pad)) continue;
            if (!bvh_intersect_triangle(ray, t, t + 3, t + 6, &h)) continue;
            if (best->prim != BVH_INVALID && !(h.t < best->t || (h.t == best->t && id < best->prim))) continue;
            if (!tu_finite9(t)) continue;
            *best = h;
            best->prim = id;
        }
    }
    return best->prim != BVH_INVALID;
}

TU_FN uint32_t tu_fbits(float f) {
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}
/* Hits equal: same primitive and bitwise-same t, u, v (the same watertight test computes them). */
TU_FN int tu_hit_equal(const bvh_hit *a, const bvh_hit *b) {
    return a->prim == b->prim && tu_fbits(a->t) == tu_fbits(b->t) && tu_fbits(a->u) == tu_fbits(b->u) &&
           tu_fbits(a->v) == tu_fbits(b->v);
}
TU_FN void tu_print_ray(const bvh_ray *r) {
    print_error("ray origin (%a, %a, %a) dir (%a, %a, %a) tmin %a tmax %a\n", (double)r->origin.x, (double)r->origin.y,
                (double)r->origin.z, (double)r->dir.x, (double)r->dir.y, (double)r->dir.z, (double)r->tmin,
                (double)r->tmax);
}

TU_FN void tu_print_hit(const char *what, const bvh_hit *h) {
    print_error("  %-12s prim %u t %a u %a v %a\n", what, h->prim, (double)h->t, (double)h->u, (double)h->v);
}
/* Brute-force hits of count rays (a miss: prim BVH_INVALID), the culled loop checked against
   the plain one on TU_ORACLE_CHECKS rays spread over the set (every ray of a small set). */
TU_FN void tu_oracle_run(const float *tris, uint32_t n, const bvh_ray *rays, size_t count, bvh_hit *hits) {
    tu_oracle o;
    size_t i, every, checks = n ? 8000000u / n : 384; /* about 8 million plain tests per set */
    tu_oracle_init(&o, tris, n);
    checks = checks < 64 ? 64 : checks > 384 ? 384 : checks;
    every = count / checks > 1 ? count / checks : 1;
    for (i = 0; i < count; i++) {
        tu_brute_culled(&o, &rays[i], &hits[i]);
        if (i % every == 0) {
            bvh_hit plain;
            tu_brute(tris, n, &rays[i], &plain);
            if (!tu_hit_equal(&plain, &hits[i])) {
                tu_print_ray(&rays[i]);
                tu_print_hit("plain", &plain);
                tu_print_hit("culled", &hits[i]);
                fail_msg("the culled brute force differs from the plain loop on ray %zu", i);
            }
        }
    }
    tu_oracle_free(&o);
}

/* == rays ==================================================================================== */
TU_FN bvh_vec3 tu_v3(float x, float y, float z) {
    bvh_vec3 v;
    v.x = x;
    v.y = y;
    v.z = z;
    return v;
}
TU_FN float tu_signed_zero(tu_rng *r) { return (tu_u32(r) & 1) ? -0.0f : 0.0f; }
TU_FN bvh_vec3 tu_point_in(tu_rng *r, bvh_aabb b, float grow) {
    float gx = (b.max.x - b.min.x) * grow, gy = (b.max.y - b.min.y) * grow, gz = (b.max.z - b.min.z) * grow;
    return tu_v3(tu_range(r, b.min.x - gx, b.max.x + gx), tu_range(r, b.min.y - gy, b.max.y + gy),
                 tu_range(r, b.min.z - gz, b.max.z + gz));
}
TU_FN bvh_vec3 tu_sphere_dir(tu_rng *r) {
    for (;;) {
        float x = tu_range(r, -1, 1), y = tu_range(r, -1, 1), z = tu_range(r, -1, 1), l = x * x + y * y + z * z;
        if (l > 1e-4f && l <= 1.0f) return tu_v3(x, y, z);
    }
}
TU_FN bvh_vec3 tu_sub(bvh_vec3 a, bvh_vec3 b) { return tu_v3(a.x - b.x, a.y - b.y, a.z - b.z); }
TU_FN float *tu_c(bvh_vec3 *v, int a) { return a == 0 ? &v->x : a == 1 ? &v->y : &v->z; }
/* A random finite vertex of a random triangle (exact coordinates of the input). */
TU_FN bvh_vec3 tu_some_vertex(tu_rng *r, const float *tris, uint32_t n) {
    for (;;) {
        uint32_t i = tu_below(r, n);
        const float *t = tris + 9 * (size_t)i;
        if (tu_finite9(t)) {
            t += 3 * tu_below(r, 3);
            return tu_v3(t[0], t[1], t[2]);
        }
    }
}
/* A random point on a random finite triangle. */
TU_FN bvh_vec3 tu_some_point(tu_rng *r, const float *tris, uint32_t n) {
    for (;;) {
        const float *t = tris + 9 * (size_t)tu_below(r, n);
        float a = tu_unit(r), b = tu_unit(r);
        if (!tu_finite9(t)) continue;
        if (a + b > 1.0f) {
            a = 1.0f - a;
            b = 1.0f - b;
        }
        return tu_v3(t[0] + a * (t[3] - t[0]) + b * (t[6] - t[0]), t[1] + a * (t[4] - t[1]) + b * (t[7] - t[1]),
                     t[2] + a * (t[5] - t[2]) + b * (t[8] - t[2]));
    }
}
/* An axis-parallel direction along `axis` (sign random), the other components +0.0 or -0.0. */
TU_FN bvh_vec3 tu_axis_dir(tu_rng *r, int axis) {
    bvh_vec3 d = tu_v3(tu_signed_zero(r), tu_signed_zero(r), tu_signed_zero(r));
    *tu_c(&d, axis) = (tu_u32(r) & 1) ? -1.0f : 1.0f;
    return d;
}

/* count rays of ten kinds in turn (tris: the scene's triangles, at least one finite):
   0 origin anywhere in the bounds grown by 20% (often inside the scene), random direction;
   1 from outside towards a random point on a random triangle (dir not normalised);
   2 the same with tmax = 1 (the target lies at t ~ 1: the tmax boundary matters);
   3 axis-parallel (+-0.0 components) from a random point of the grown bounds;
   4 axis-parallel through an exact vertex, from outside or from inside the scene;
   5 from an exact vertex, random direction (tmin 0: hits at t = 0 count);
   6 from outside through an exact vertex;
   7 from an exact vertex, one direction component +-0.0 (rays in the planes of the grid);
   8 random origin and direction with a finite tmax and sometimes tmin > 0;
   9 from an exact vertex along an axis (+-0.0 components), tmin 0. */
/* The finite triangles' bounds and their diagonal. */
TU_FN float tu_diag(const float *tris, uint32_t n, bvh_aabb *bounds) {
    bvh_aabb b = bvh_aabb_empty();
    uint32_t k;
    for (k = 0; k < n; k++)
        if (tu_finite9(tris + 9 * (size_t)k)) b = bvh_aabb_merge(b, tu_tri_box(tris + 9 * (size_t)k));
    if (bounds) *bounds = b;
    return sqrtf((b.max.x - b.min.x) * (b.max.x - b.min.x) + (b.max.y - b.min.y) * (b.max.y - b.min.y) +
                 (b.max.z - b.min.z) * (b.max.z - b.min.z));
}
TU_FN void tu_make_rays(const float *tris, uint32_t n, uint64_t seed, bvh_ray *rays, size_t count) {
    tu_rng r = tu_rng_make(seed);
    bvh_aabb b;
    float diag = tu_diag(tris, n, &b);
    size_t i;
    if (!(diag > 0.0f)) diag = 1.0f;
    for (i = 0; i < count; i++) {
        bvh_ray *ray = &rays[i];
        bvh_vec3 p;
        int axis = (int)tu_below(&r, 3);
        ray->tmin = 0.0f;
        ray->tmax = BVH_INF;
        switch (i % 10) {
        case 0:
            ray->origin = tu_point_in(&r, b, 0.2f);
            ray->dir = tu_sphere_dir(&r);
            break;
        case 1:
        case 2:
            p = tu_some_point(&r, tris, n);
            ray->origin = tu_point_in(&r, b, 0.5f);
            ray->dir = tu_sub(p, ray->origin);
            if (i % 10 == 2) ray->tmax = 1.0f;
            break;
        case 3:
            ray->origin = tu_point_in(&r, b, 0.1f);
            ray->dir = tu_axis_dir(&r, axis);
            break;
        case 4:
            ray->origin = tu_some_vertex(&r, tris, n);
            ray->dir = tu_axis_dir(&r, axis);
            /* step back along the axis: to outside the bounds, or to a point inside */
            *tu_c(&ray->origin, axis) -= *tu_c(&ray->dir, axis) * ((tu_u32(&r) & 1) ? diag : 0.5f);
            break;
        case 5:
            ray->origin = tu_some_vertex(&r, tris, n);
            ray->dir = tu_sphere_dir(&r);
            break;
        case 6:
            p = tu_some_vertex(&r, tris, n);
            ray->origin = tu_point_in(&r, b, 0.5f);
            ray->dir = tu_sub(p, ray->origin);
            break;
        case 7:
            ray->origin = tu_some_vertex(&r, tris, n);
            ray->dir = tu_sphere_dir(&r);
            *tu_c(&ray->dir, axis) = tu_signed_zero(&r);
            if (ray->dir.x == 0.0f && ray->dir.y == 0.0f && ray->dir.z == 0.0f) ray->dir.x = 1.0f;
            break;
        case 8:
            ray->origin = tu_point_in(&r, b, 0.3f);
            ray->dir = tu_sphere_dir(&r);
            ray->tmax = tu_range(&r, 0.0f, 0.5f * diag);
            if (tu_u32(&r) & 1) ray->tmin = tu_range(&r, 0.0f, ray->tmax);
            break;
        default:
            ray->origin = tu_some_vertex(&r, tris, n);
            ray->dir = tu_axis_dir(&r, axis);
            break;
        }
    }
}

#endif /* TEST_UTIL_H */
