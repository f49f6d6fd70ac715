/* tests/fuzz_build.c - libFuzzer target for bvh_build, bvh_validate and the traversal.

   Build and run:  make fuzz FUZZ_SECONDS=120      (mk/robust.mk; build/fuzz/fuzz_build)
   or by hand:     clang -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
                       -I. tests/fuzz_build.c -o fuzz_build -lm -lpthread
                   ./fuzz_build -max_len=4096 -timeout=10 corpus/   (corpus: a copy of tests/fuzz/)
   A crash leaves crash-<sha1> (or timeout-/leak-/oom-) in build/fuzz/; replay it with
   `build/fuzz/fuzz_build build/fuzz/crash-...`, and once fixed add it to tests/fuzz/ so that every
   later run replays it first.

   The input bytes become build options (two builders, max_leaf_size, ploc.radius, threads 1-3,
   ploc.top, ploc.max_bytes_per_prim, skip_invalid, costs, split budget, trace_width 0 or 2, stride, an
   allocation to fail) and a triangle list: vertex
   coordinates straight from the bytes (raw floats: NaN, Inf, huge, denormal values occur), or
   quantized to small multiples of 1/4 (exact coincidences, shared edges, axis-aligned and
   degenerate triangles), optionally indexed with indices from the bytes. The vertex buffer is
   allocated to the exact byte, its padding floats are NaN. Checked, any disagreement traps:
   - the result is the one the input calls for: SUCCESS when nothing is wrong, else one of the
     errors the input has (invalid argument, index out of range, invalid geometry), or out of
     memory when an allocation was made to fail; the tree is empty after a failure;
   - nothing allocated stays live after bvh_free or a failed build (counting allocator);
   - after a success: bvh_validate passes (with the tree's triangles and with the caller's
     boxes), depth <= BVH_MAX_DEPTH, excluded = the triangles with a non-finite vertex, and every
     ray (from the bytes and fixed ones: through centroids and vertices, axis-parallel with +0/-0
     components) gets exactly the brute-force closest hit (bvh_intersect_triangle over the finite
     triangles, lowest index at equal t) from bvh_intersect, bvh_intersect_counted, bvh_occluded
     and the batch calls;
   - ploc and ploc-parallel give the same tree; a build from the triangles' boxes is valid and,
     except for sah-midpoint (whose spatial splits clip the triangles), the same tree as the
     build from the triangles. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fp_bits.h"
#include "tree_diff.h"

#define FZ_MAX_RAYS 96

#define FZ_CHECK(cond, ...)                                                                                            \
    do {                                                                                                               \
        if (!(cond)) {                                                                                                 \
            fprintf(stderr, "fuzz_build: %s:%d: check failed: %s: ", __FILE__, __LINE__, #cond);                       \
            fprintf(stderr, __VA_ARGS__);                                                                              \
            fprintf(stderr, "\n");                                                                                     \
            __builtin_trap();                                                                                          \
        }                                                                                                              \
    } while (0)

/* == input reader: past the end every read gives zeros ====================================== */
typedef struct fz_in {
    const uint8_t *p;
    size_t n, at;
} fz_in;
static uint8_t fz_u8(fz_in *in) { return in->at < in->n ? in->p[in->at++] : 0; }
static uint16_t fz_u16(fz_in *in) {
    uint16_t a = fz_u8(in);
    return (uint16_t)(a | fz_u8(in) << 8);
}
static float fz_raw(fz_in *in) {
    uint32_t b = 0;
    float f;
    int k;
    for (k = 0; k < 4; k++) b |= (uint32_t)fz_u8(in) << (8 * k);
    memcpy(&f, &b, sizeof f);
    return f;
}
/* Coordinates: 0 raw float; 1 int8 / 4; 2 int16 / 256; 3 int8 / 4 with an escape to raw floats. */
static float fz_coord(fz_in *in, int mode) {
    uint8_t t;
    switch (mode) {
    case 0:
        return fz_raw(in);
    case 1:
        return (float)(int8_t)fz_u8(in) * 0.25f;
    case 2:
        return (float)(int16_t)fz_u16(in) * (1.0f / 256.0f);
    default:
        t = fz_u8(in);
        return t >= 248 ? fz_raw(in) : (float)((int)t - 124) * 0.25f;
    }
}

/* == counting allocator that can fail one allocation ========================================= */
typedef struct fz_alloc {
    long calls, live, fail_at;
} fz_alloc;
static void *fz_alloc_fn(size_t size, void *user) {
    fz_alloc *a = (fz_alloc *)user;
    long k = __atomic_fetch_add(&a->calls, 1, __ATOMIC_RELAXED);
    void *p;
    if (k == a->fail_at) return NULL;
    p = malloc(size);
    if (p) __atomic_fetch_add(&a->live, 1, __ATOMIC_RELAXED);
    return p;
}
static void fz_free_fn(void *p, void *user) {
    fz_alloc *a = (fz_alloc *)user;
    if (p) __atomic_fetch_sub(&a->live, 1, __ATOMIC_RELAXED);
    free(p);
}

/* == the case built from the bytes =========================================================== */
typedef struct fz_case {
    bvh_build_desc desc; /* options + triangles */
    bvh_builder other;   /* second builder */
    float *vbuf;         /* the caller's vertex buffer, exact size */
    uint32_t *ibuf;      /* indices or NULL */
    float *tris;         /* nt * 9 floats, fetched as bvh_build would (valid indices only) */
    bvh_aabb *boxes;     /* per triangle; NaN box for a non-finite triangle */
    uint32_t nt, bad;    /* triangles, triangles with a non-finite coordinate */
    int arg_err, idx_err, fail_alloc, batch, negative_tmin;
    fz_alloc alloc;
    bvh_ray rays[FZ_MAX_RAYS];
    uint32_t nrays;
} fz_case;

static int fz_finite9(const float *t) {
    int k;
    for (k = 0; k < 9; k++)
        if (!fp_finite(t[k])) return 0;
    return 1;
}
static int fz_costs_ok(const bvh_costs *c) {
    return fp_finite(c->interior) && fp_finite(c->leaf) && fp_finite(c->triangle) && c->interior >= 0.0f &&
           c->leaf >= 0.0f && c->triangle >= 0.0f;
}

static void fz_parse_options(fz_in *in, fz_case *c, uint8_t *flags, uint8_t *extra, uint32_t *nv, uint32_t *nidx) {
    static const size_t strides[8] = {0, 12, 16, 20, 12, 0, 8, 4};
    bvh_build_desc *d = &c->desc;
    uint8_t b0 = fz_u8(in), b1 = fz_u8(in), lf, rad, th, st, fail;
    *flags = fz_u8(in);
    lf = fz_u8(in);
    rad = fz_u8(in);
    th = fz_u8(in);
    st = fz_u8(in);
    fail = fz_u8(in);
    *nv = fz_u8(in);
    *nidx = fz_u8(in);
    c->nrays = fz_u8(in) % 16;
    *extra = fz_u8(in);
    d->builder = (bvh_builder)(1 + b0 % (BVH_BUILDER_COUNT - 1)); /* the table's rows after the default */
    c->other = (bvh_builder)(1 + b1 % (BVH_BUILDER_COUNT - 1));
    if (c->other == d->builder)
        c->other = d->builder == BVH_BUILDER_PLOC ? BVH_BUILDER_PLOC_PARALLEL : BVH_BUILDER_PLOC;
    d->skip_invalid = *flags & 1;
    d->max_leaf_size = (*extra & 4) ? fz_u16(in) : lf;
    d->ploc.radius = rad >= 240 ? 256u + (rad - 240u) % 3u : rad % 20u;
    d->threads = 1u + th % 3u;
    d->optimize.rounds = (th / 60u) % 2u ? 2u : 0u; /* the optimizer on some inputs (the byte's top) */
    { /* PLOC's SAH top: default, every other cut, off (the byte's other bits) */
        static const uint32_t tops[5] = {0, 2, 3, 1, BVH_OFF};
        d->ploc.top = tops[(th / 3u) % 5u];
    }
    { /* PLOC's memory budget: default (40), none, unreachable (1 byte), 60 */
        static const uint32_t budgets[4] = {0, BVH_OFF, 1, 60};
        d->ploc.max_bytes_per_prim = budgets[(th / 15u) % 4u];
    }
    d->triangles.stride = strides[st % 8];
    c->fail_alloc = (*flags & 0x80) != 0;
    c->alloc.fail_at = c->fail_alloc ? (long)fail : -1;
    if (*extra & 1) {
        d->costs.interior = fz_raw(in);
        d->costs.leaf = fz_raw(in);
        d->costs.triangle = fz_raw(in);
    }
    if (*extra & 2) d->sah_midpoint.split_budget = fz_raw(in);
    c->batch = (*extra & 16) != 0;
    c->negative_tmin = (*extra & 64) != 0;
    if (*extra & 128) d->trace_width = 2; /* binary traversal; else the 8-wide copy */
    c->arg_err = d->max_leaf_size > 255 || d->ploc.radius > 256 || !fz_costs_ok(&d->costs) ||
                 (d->sah_midpoint.split_budget != (float)BVH_OFF &&
                  !(d->sah_midpoint.split_budget >= 0.0f && d->sah_midpoint.split_budget <= 1.0f));
}

/* Vertices into an exact-size buffer (padding floats NaN), indices, and the expanded triangles. */
static void fz_parse_geometry(fz_in *in, fz_case *c, uint8_t flags, uint8_t extra, uint32_t nv, uint32_t nidx) {
    bvh_build_desc *d = &c->desc;
    int mode = (flags >> 2) & 3, indexed = (flags & 2) != 0;
    size_t stride = d->triangles.stride ? d->triangles.stride : 12, bytes, i;
    uint32_t k;
    if (stride < 12) stride = 12; /* refused anyway; keep the buffer readable */
    bytes = nv ? (size_t)(nv - 1) * stride + 12 : 4;
    c->vbuf = (float *)malloc(bytes);
    FZ_CHECK(c->vbuf != NULL, "malloc");
    for (i = 0; i < bytes / 4; i++) c->vbuf[i] = NAN;
    for (k = 0; k < nv; k++) {
        float *p = (float *)(void *)((char *)c->vbuf + (size_t)k * stride);
        p[0] = fz_coord(in, mode);
        p[1] = fz_coord(in, mode);
        p[2] = fz_coord(in, mode);
    }
    d->triangles.positions = c->vbuf;
    d->triangles.vertex_count = nv;
    c->nt = indexed ? nidx : nv / 3;
    if (!indexed && (extra & 8) && c->nt) {
        c->nt++;
        c->idx_err = 1;
    } /* declares one more than the soup has */
    if (indexed) {
        c->ibuf = (uint32_t *)malloc(3 * (size_t)(c->nt ? c->nt : 1) * sizeof(uint32_t));
        FZ_CHECK(c->ibuf != NULL, "malloc");
        for (i = 0; i < 3 * (size_t)c->nt; i++) {
            uint8_t b = fz_u8(in);
            c->ibuf[i] = b == 255 ? nv + (uint32_t)(i & 1) * 1000u : nv ? b % nv : b;
            if (c->ibuf[i] >= nv) c->idx_err = 1;
        }
        d->triangles.indices = c->ibuf;
    }
    d->triangles.triangle_count = c->nt;
    if (c->nt && d->triangles.stride && d->triangles.stride < 12) c->arg_err = 1;
    c->tris = (float *)calloc(9 * (size_t)(c->nt ? c->nt : 1), sizeof(float));
    c->boxes = (bvh_aabb *)calloc(c->nt ? c->nt : 1, sizeof(bvh_aabb));
    FZ_CHECK(c->tris && c->boxes, "calloc");
    if (c->idx_err) return;
    for (i = 0; i < c->nt; i++) {
        float *t = c->tris + 9 * i;
        int v;
        for (v = 0; v < 3; v++) {
            uint32_t vi = indexed ? c->ibuf[3 * i + v] : (uint32_t)(3 * i + v);
            memcpy(t + 3 * v, (char *)c->vbuf + (size_t)vi * stride, 3 * sizeof(float));
        }
        if (!fz_finite9(t)) {
            c->bad++;
            c->boxes[i].min.x = c->boxes[i].max.x = NAN;
            continue;
        }
        c->boxes[i] = bvh_aabb_empty();
        for (v = 0; v < 3; v++) {
            bvh_vec3 p;
            p.x = t[3 * v];
            p.y = t[3 * v + 1];
            p.z = t[3 * v + 2];
            bvh_aabb_grow(&c->boxes[i], p);
        }
    }
}

static void fz_add_ray(fz_case *c, float ox, float oy, float oz, float dx, float dy, float dz, float tmin, float tmax) {
    bvh_ray *r;
    if (c->nrays >= FZ_MAX_RAYS) return;
    r = &c->rays[c->nrays++];
    r->origin.x = ox;
    r->origin.y = oy;
    r->origin.z = oz;
    r->dir.x = dx;
    r->dir.y = dy;
    r->dir.z = dz;
    r->tmin = tmin;
    r->tmax = tmax;
}
/* Rays from the bytes, then fixed ones aimed at the finite triangles. */
static void fz_parse_rays(fz_in *in, fz_case *c, int mode) {
    uint32_t i, from_bytes = c->nrays;
    float tmin0 = c->negative_tmin ? -BVH_INF : 0.0f;
    c->nrays = 0;
    for (i = 0; i < from_bytes; i++) {
        float o[3], d[3], tmin, tmax;
        uint8_t m;
        int a;
        for (a = 0; a < 3; a++) o[a] = fz_coord(in, mode);
        for (a = 0; a < 3; a++) d[a] = fz_coord(in, mode);
        m = fz_u8(in);
        tmin = (m & 1) ? fz_coord(in, mode) : 0.0f;
        tmax = (m & 2) ? fz_coord(in, mode) : BVH_INF;
        fz_add_ray(c, o[0], o[1], o[2], d[0], d[1], d[2], tmin, tmax);
    }
    for (i = 0; i < c->nt && c->nrays + 4 <= FZ_MAX_RAYS; i++) {
        const float *t = c->tris + 9 * (size_t)i;
        float cx = (t[0] + t[3] + t[6]) / 3.0f, cy = (t[1] + t[4] + t[7]) / 3.0f, cz = (t[2] + t[5] + t[8]) / 3.0f;
        float z0 = (i & 1) ? 0.0f : -0.0f, z1 = (i & 2) ? 0.0f : -0.0f;
        int axis = (int)(i % 3);
        if (!fz_finite9(t) || i % 2) continue;
        fz_add_ray(c, cx + 1.25f, cy + 2.5f, cz - 3.75f, -1.25f, -2.5f, 3.75f, tmin0,
                   BVH_INF); /* through the centroid */
        fz_add_ray(c, t[3] - 0.5f, t[4] + 2.0f, t[5] + 0.25f, 0.5f, -2.0f, -0.25f, tmin0, BVH_INF); /* through v1 */
        /* axis-parallel through v0's coordinates (origin on box planes), +0 / -0 elsewhere */
        fz_add_ray(c, axis == 0 ? t[0] - 4.0f : t[0], axis == 1 ? t[1] - 4.0f : t[1], axis == 2 ? t[2] - 4.0f : t[2],
                   axis == 0 ? 1.0f : z0, axis == 1 ? 1.0f : z1, axis == 2 ? 1.0f : z0, tmin0, BVH_INF);
        fz_add_ray(c, axis == 0 ? cx + 4.0f : cx, axis == 1 ? cy + 4.0f : cy, axis == 2 ? cz + 4.0f : cz,
                   axis == 0 ? -1.0f : z1, axis == 1 ? -1.0f : z0, axis == 2 ? -1.0f : z1, tmin0, 8.0f);
    }
}

/* == checks ================================================================================== */
static int fz_brute(const fz_case *c, const bvh_ray *ray, bvh_hit *best) {
    uint32_t i;
    bvh_hit h;
    best->prim = BVH_INVALID;
    best->t = ray->tmax;
    best->u = best->v = 0.0f;
    for (i = 0; i < c->nt; i++) {
        const float *t = c->tris + 9 * (size_t)i;
        if (!fz_finite9(t) || !bvh_intersect_triangle(ray, t, t + 3, t + 6, &h)) continue;
        if (best->prim == BVH_INVALID || h.t < best->t) {
            *best = h;
            best->prim = i;
        }
    }
    return best->prim != BVH_INVALID;
}

#ifdef FZ_SKIP_KNOWN_BUGS
/* For exploring past bvh.h bugs already reported, never in `make fuzz` (build it with
   -DFZ_SKIP_KNOWN_BUGS -fno-sanitize=float-cast-overflow): rays with a denormal direction
   component (1/d overflows, boxes are culled); rays or hit triangles with coordinates below 1e-18
   or above 1e18 in magnitude (bvh_intersect_triangle reports hits outside the triangle, or at
   t = inf with NaN barycentrics). */
static int fz_extreme(const float *p, int n) {
    int k;
    for (k = 0; k < n; k++)
        if ((p[k] != 0.0f && fabsf(p[k]) < 1e-18f) || fabsf(p[k]) > 1e18f) return 1;
    return 0;
}
static int fz_known_bug(const fz_case *c, const bvh_ray *r, int got, const bvh_hit *h, int w, const bvh_hit *want) {
    if (fz_extreme(&r->origin.x, 3) || fz_extreme(&r->dir.x, 3)) return 1;
    if (got && h->prim < c->nt && fz_extreme(c->tris + 9 * (size_t)h->prim, 9)) return 1;
    if (w && want->prim < c->nt && fz_extreme(c->tris + 9 * (size_t)want->prim, 9)) return 1;
    return 0;
}
#endif

static void fz_check_rays(const fz_case *c, const bvh_tree *t) {
    uint32_t i, visited;
    bvh_hit hits[FZ_MAX_RAYS];
    uint8_t occ[FZ_MAX_RAYS];
    if (c->batch) {
        FZ_CHECK(bvh_intersect_batch(t, c->rays, hits, c->nrays, 2) == BVH_SUCCESS, "batch");
        FZ_CHECK(bvh_occluded_batch(t, c->rays, occ, c->nrays, 2) == BVH_SUCCESS, "occluded batch");
    }
    for (i = 0; i < c->nrays; i++) {
        const bvh_ray *r = &c->rays[i];
        bvh_hit want, h;
        int w = fz_brute(c, r, &want), got = bvh_intersect(t, r, &h);
#ifdef FZ_SKIP_KNOWN_BUGS
        if (w && !(fp_finite(want.t) && fp_finite(want.u) && fp_finite(want.v))) continue;
        if ((got != w || h.prim != want.prim) && fz_known_bug(c, r, got, &h, w, &want)) continue;
#endif
        FZ_CHECK(!w || (fp_finite(want.t) && fp_finite(want.u) && fp_finite(want.v)),
                 "bvh_intersect_triangle: hit on triangle %u at t=%a u=%a v=%a", want.prim, (double)want.t,
                 (double)want.u, (double)want.v);
        if (got != w || h.prim != want.prim) { /* print the triangles involved */
            uint32_t k, ids[2];
            ids[0] = got ? h.prim : BVH_INVALID;
            ids[1] = w ? want.prim : BVH_INVALID;
            for (k = 0; k < 2; k++) {
                const float *q = ids[k] < c->nt ? c->tris + 9 * (size_t)ids[k] : NULL;
                if (q)
                    fprintf(stderr, "fuzz_build: triangle %u: %a %a %a  %a %a %a  %a %a %a\n", ids[k], (double)q[0],
                            (double)q[1], (double)q[2], (double)q[3], (double)q[4], (double)q[5], (double)q[6],
                            (double)q[7], (double)q[8]);
            }
        }
        FZ_CHECK(got == w && h.prim == want.prim && (!w || (h.t == want.t && h.u == want.u && h.v == want.v)),
                 "%s ray %u o=(%a %a %a) d=(%a %a %a) [%a %a]: tree %u t=%a, brute force %u t=%a",
                 bvh_builder_name(t->builder), i, (double)r->origin.x, (double)r->origin.y, (double)r->origin.z,
                 (double)r->dir.x, (double)r->dir.y, (double)r->dir.z, (double)r->tmin, (double)r->tmax, h.prim,
                 (double)h.t, want.prim, (double)want.t);
        got = bvh_intersect_counted(t, r, &h, &visited);
        FZ_CHECK(got == w && h.prim == want.prim, "bvh_intersect_counted ray %u", i);
        FZ_CHECK(bvh_occluded(t, r) == w, "%s bvh_occluded ray %u: brute force %d", bvh_builder_name(t->builder), i, w);
        if (c->batch) {
            FZ_CHECK(hits[i].prim == want.prim, "bvh_intersect_batch ray %u", i);
            FZ_CHECK(occ[i] == (uint8_t)w, "bvh_occluded_batch ray %u", i);
        }
    }
}

static void fz_check_tree(const fz_case *c, const bvh_tree *t) {
    bvh_validation rep;
    bvh_stats st;
    bvh_builder_info info;
    bvh_result r = bvh_validate(t, NULL, &rep);
    FZ_CHECK(r == BVH_SUCCESS, "%s: bvh_validate: %s (node %u)", bvh_builder_name(t->builder), rep.message, rep.node);
    r = bvh_validate(t, c->boxes, &rep);
    FZ_CHECK(r == BVH_SUCCESS, "%s: bvh_validate with boxes: %s", bvh_builder_name(t->builder), rep.message);
    FZ_CHECK(bvh_get_stats(t, &st) == BVH_SUCCESS && st.max_depth <= BVH_MAX_DEPTH, "depth %u", st.max_depth);
    FZ_CHECK(t->prim_count == c->nt && t->excluded == c->bad, "prims %u excluded %u, want %u %u", t->prim_count,
             t->excluded, c->nt, c->bad);
    FZ_CHECK(bvh_builder_get_info(t->builder, &info) == BVH_SUCCESS, "builder %d", (int)t->builder);
    FZ_CHECK(info.splits_references ? t->ref_count >= c->nt - c->bad : t->ref_count == c->nt - c->bad, "ref_count %u",
             t->ref_count);
    {
        uint32_t lim = c->desc.max_leaf_size ? c->desc.max_leaf_size : info.max_leaf_size;
        FZ_CHECK(st.max_leaf_size <= lim, "%s: leaf of %u > %u", bvh_builder_name(t->builder), st.max_leaf_size, lim);
    }
}

/* Builds with `builder`; checks the result code, leaks and, on success, the tree and the rays.
   Returns the result; *out keeps the tree on success (caller frees). */
static bvh_result fz_build(fz_case *c, bvh_builder builder, bvh_tree *out) {
    bvh_build_desc d = c->desc;
    bvh_result r;
    int geo_err = c->bad && !d.skip_invalid && !c->idx_err;
    d.builder = builder;
    c->alloc.calls = 0;
    d.allocator.alloc = fz_alloc_fn;
    d.allocator.free = fz_free_fn;
    d.allocator.user = &c->alloc;
    r = bvh_build(out, &d);
    if (r != BVH_SUCCESS) {
        FZ_CHECK((r == BVH_ERROR_INVALID_ARGUMENT && c->arg_err) || (r == BVH_ERROR_INDEX_OUT_OF_RANGE && c->idx_err) ||
                     (r == BVH_ERROR_INVALID_GEOMETRY && geo_err) || (r == BVH_ERROR_OUT_OF_MEMORY && c->fail_alloc),
                 "%s: unexpected %s (arg %d idx %d geo %d alloc %d)", bvh_builder_name(builder), bvh_result_string(r),
                 c->arg_err, c->idx_err, geo_err, c->fail_alloc);
        FZ_CHECK(out->nodes == NULL && out->prims == NULL && out->tris == NULL && out->node_count == 0,
                 "tree not empty");
        FZ_CHECK(c->alloc.live == 0, "%s: %ld blocks leaked by a failed build", bvh_builder_name(builder),
                 c->alloc.live);
        return r;
    }
    FZ_CHECK(!c->arg_err && !c->idx_err && !geo_err, "%s: success on bad input (arg %d idx %d geo %d)",
             bvh_builder_name(builder), c->arg_err, c->idx_err, geo_err);
    c->alloc.fail_at = -1; /* bvh_validate and the batch calls allocate through the tree's allocator */
    fz_check_tree(c, out);
    fz_check_rays(c, out);
    return r;
}

static void fz_same_tree(const bvh_tree *a, const bvh_tree *b, int structure_only, const char *what) {
    const char *diff = tree_diff_ex(a, b, structure_only);
    FZ_CHECK(!diff, "%s: %s differ", what, diff);
}

/* The same boxes given directly: same tree, validated against the boxes, no triangles to trace. */
static void fz_check_boxes(fz_case *c, const bvh_tree *ref) {
    bvh_build_desc d = c->desc;
    bvh_tree t;
    bvh_result r;
    bvh_validation rep;
    memset(&d.triangles, 0, sizeof d.triangles);
    d.boxes = c->boxes;
    d.box_count = c->nt;
    c->alloc.fail_at = -1;
    d.allocator.alloc = fz_alloc_fn;
    d.allocator.free = fz_free_fn;
    d.allocator.user = &c->alloc;
    d.builder = ref->builder;
    r = bvh_build(&t, &d);
    FZ_CHECK(r == BVH_SUCCESS, "box build: %s", bvh_result_string(r));
    FZ_CHECK(bvh_validate(&t, c->boxes, &rep) == BVH_SUCCESS, "box build: %s", rep.message);
    FZ_CHECK(t.tris == NULL && t.excluded == c->bad, "box build: excluded %u", t.excluded);
    if (ref->builder != BVH_BUILDER_SAH_MIDPOINT) /* its spatial splits clip triangles, not boxes */
        fz_same_tree(ref, &t, 1, "triangles vs boxes");
    if (c->nrays) {
        bvh_hit h;
        FZ_CHECK(bvh_intersect(&t, &c->rays[0], &h) == 0, "a box tree hits");
        FZ_CHECK(t.node_count == 0 || bvh_intersect_batch(&t, c->rays, &h, 1, 1) == BVH_ERROR_NO_TRIANGLES, "batch");
    }
    bvh_free(&t);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
#ifdef FZ_STANDALONE
/* Without libFuzzer (gcc, valgrind): fuzz_build FILE... runs each input once. */
int main(int argc, char **argv) {
    int i;
    for (i = 1; i < argc; i++) {
        FILE *f = fopen(argv[i], "rb");
        static uint8_t buf[1 << 16];
        size_t n;
        if (!f) {
            perror(argv[i]);
            return 2;
        }
        n = fread(buf, 1, sizeof buf, f);
        fclose(f);
        LLVMFuzzerTestOneInput(buf, n);
        printf("ok %s\n", argv[i]);
    }
    return 0;
}
#endif
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    fz_in in;
    fz_case *c = (fz_case *)calloc(1, sizeof(fz_case));
    uint8_t flags, extra;
    uint32_t nv, nidx;
    bvh_tree a, b;
    bvh_result ra, rb;
    FZ_CHECK(c != NULL, "calloc");
    in.p = data;
    in.n = size;
    in.at = 0;
    fz_parse_options(&in, c, &flags, &extra, &nv, &nidx);
    fz_parse_geometry(&in, c, flags, extra, nv, nidx);
    fz_parse_rays(&in, c, (flags >> 2) & 3);

    ra = fz_build(c, c->desc.builder, &a);
    c->alloc.fail_at = -1; /* the second builder with a working allocator */
    rb = fz_build(c, c->other, &b);
    if (ra == BVH_SUCCESS && rb == BVH_SUCCESS) {
        int ploc_pair = (a.builder == BVH_BUILDER_PLOC || a.builder == BVH_BUILDER_PLOC_PARALLEL) &&
                        (b.builder == BVH_BUILDER_PLOC || b.builder == BVH_BUILDER_PLOC_PARALLEL);
        if (ploc_pair) fz_same_tree(&a, &b, 0, "ploc vs ploc-parallel");
    }
    if (ra == BVH_SUCCESS && (extra & 32)) fz_check_boxes(c, &a);
    bvh_free(&a);
    bvh_free(&b);
    FZ_CHECK(c->alloc.live == 0, "%ld blocks live after bvh_free", c->alloc.live);
    free(c->vbuf);
    free(c->ibuf);
    free(c->tris);
    free(c->boxes);
    free(c);
    return 0;
}
