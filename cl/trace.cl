/* cl/trace.cl - OpenCL C 1.2 ray tracing kernels for bvh.h trees (host side: cl/bvh_cl.h)

   DATA (uploaded byte for byte from a bvh_tree, no conversion on the host)
     nodes   bvh_node[node_count], 32 bytes: float min[3], uint index, float max[3], uint count.
             count == 0: interior node, children nodes[index] and nodes[index + 1];
             count > 0: leaf over references index .. index + count - 1. Root at 0.
             Read as two uint4 (the floats through as_float4), so that no index is ever held in
             a float register.
     tris    tree.tris: 9 floats (v0, v1, v2) per reference, in reference order
     prims   tree.prims: original triangle id per reference
     rays    bvh_ray[]: origin xyz, tmin, dir xyz, tmax (32 bytes, read as two float4)
     hits    bvh_hit[]: t, u, v, prim (16 bytes), written as one uint4 (float bits, then the id)
   A two-level scene (bvh_scene, see bvh_cl_scene below) adds: the top-level tree's nodes and prims
   (instance indices; no triangles); the distinct bottom-level trees' nodes, tris and prims, one
   tree after the other, with meshes[] = (first node, nodes, first reference, references) per
   tree; per instance its world-to-object 3x4 (bvh_scene.inverse) and (mask, id, tree, 0); scene
   hits are bvh_scene_hit (36 bytes: t, u, v, instance, id, prim, normal xyz).

   SEMANTICS: those of bvh.h (section "traversal"), statement for statement: watertight triangle
   test (Woop, Benthin & Wald 2013) in float with the exact fallback on zero edge functions, ties in t to the
   lowest primitive id, robust slab test (far distance widened by 1.0000004f, zero direction
   components get an inverse of +inf, the near plane is chosen by the sign of the inverse, the NaN
   of an origin on a slab plane is dropped by the order of the comparisons), near child first,
   invalid rays (NaN, non-finite origin or direction, zero direction, tmin > tmax) miss.
   Scenes: those of bvh_scene_intersect (bvh.h, section "instances"): the ray moved into each
   instance's space by bvh_ray_transform's operations, ties to the lowest instance then triangle,
   the world normal computed in double as bvh__scene_normal does.
   Hits equal the CPU's to the bit when the host builds with -cl-fp32-correctly-rounded-divide-sqrt
   and the device has cl_khr_fp64 (bvh_cl.h does both when it can); FP_CONTRACT is off so that
   no compiler fuses a*b-c*d into an fma the CPU code does not do. Without cl_khr_fp64 the edge
   fallback computes a*b-c*d with fma (Kahan), which has the same sign and zeros.

   OPTIONS (-D from the host)
     BVH_MAX_DEPTH   the host's value (64); the private stack holds BVH_MAX_DEPTH + 2 entries, like
                     the CPU's (twice that for a scene, whose two levels share it), and a traversal
                     that would overflow it stops (never writes past it).
*/
#pragma OPENCL FP_CONTRACT OFF
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#define BVH_CL_FP64 1
#endif

#ifndef BVH_MAX_DEPTH
#define BVH_MAX_DEPTH 64
#endif
#define BVH_CL_STACK (BVH_MAX_DEPTH + 2)

/* Helpers are inlined: PoCL's LLVM otherwise keeps the triangle test and the traversal as calls
   whose ray and hit go through memory, which cost a third of the speed. static needs OpenCL C 1.2. */
#if defined(__OPENCL_C_VERSION__) && __OPENCL_C_VERSION__ >= 120
#ifdef __clang__
#define BVH_CL_FN static inline __attribute__((always_inline))
#else
#define BVH_CL_FN static inline
#endif
#elif defined(__clang__)
#define BVH_CL_FN __attribute__((always_inline))
#else
#define BVH_CL_FN
#endif
#define BVH_CL_INVALID 0xFFFFFFFFu

/* ============================================================================================ */
/* == ray setup ================================================================================ */
/* ============================================================================================ */
typedef struct bvh_cl_rayx {
    float3 o, inv;
    int3 neg; /* inv < 0: the near plane is the max plane on that axis */
    float tmin;
    int kx, ky, kz;      /* watertight: kz = dominant axis, kx/ky swapped for d[kz] < 0 */
    float okx, oky, okz; /* the origin permuted like the axes */
    float sx, sy, sz;
} bvh_cl_rayx;

BVH_CL_FN float bvh_cl_comp(float3 v, int k) { return k == 0 ? v.x : (k == 1 ? v.y : v.z); }

/* bvh__ray_setup: 0 for an invalid ray. */
BVH_CL_FN int bvh_cl_ray_setup(float3 o, float tmin, float3 d, float tmax, bvh_cl_rayx *rx) {
    float ax, ay, az, dkz;
    int t;
    if (!(isfinite(o.x) && isfinite(o.y) && isfinite(o.z) && isfinite(d.x) && isfinite(d.y) && isfinite(d.z))) return 0;
    if (isnan(tmin) || isnan(tmax) || tmin > tmax) return 0;
    /* as bvh__ray_setup: subnormal components have no finite inverse and count as 0 */
    d.x = fabs(d.x) < FLT_MIN ? 0.0f : d.x;
    d.y = fabs(d.y) < FLT_MIN ? 0.0f : d.y;
    d.z = fabs(d.z) < FLT_MIN ? 0.0f : d.z;
    if (d.x == 0.0f && d.y == 0.0f && d.z == 0.0f) return 0;
    rx->o = o;
    rx->inv.x = d.x == 0.0f ? INFINITY : 1.0f / d.x;
    rx->inv.y = d.y == 0.0f ? INFINITY : 1.0f / d.y;
    rx->inv.z = d.z == 0.0f ? INFINITY : 1.0f / d.z;
    rx->neg = rx->inv < (float3)(0.0f);
    rx->tmin = tmin;
    ax = fabs(d.x);
    ay = fabs(d.y);
    az = fabs(d.z);
    rx->kz = ax > ay ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
    rx->kx = rx->kz == 2 ? 0 : rx->kz + 1;
    rx->ky = rx->kx == 2 ? 0 : rx->kx + 1;
    dkz = bvh_cl_comp(d, rx->kz);
    if (dkz < 0.0f) {
        t = rx->kx;
        rx->kx = rx->ky;
        rx->ky = t;
    }
    rx->sx = bvh_cl_comp(d, rx->kx) / dkz;
    rx->sy = bvh_cl_comp(d, rx->ky) / dkz;
    rx->sz = 1.0f / dkz;
    rx->okx = bvh_cl_comp(o, rx->kx);
    rx->oky = bvh_cl_comp(o, rx->ky);
    rx->okz = bvh_cl_comp(o, rx->kz);
    return 1;
}

/* ============================================================================================ */
/* == watertight triangle test (bvh__tri_test) =================================================== */
/* ============================================================================================ */
/* a*b - c*d as float(double(a)*double(b) - double(c)*double(d)): the products are exact in double */
BVH_CL_FN float bvh_cl_diff_of_products(float a, float b, float c, float d) {
#ifdef BVH_CL_FP64
    return (float)((double)a * (double)b - (double)c * (double)d);
#else
    float w = c * d;
    float e = fma(-c, d, w); /* w - c*d exactly */
    float f = fma(a, b, -w);
    return f + e;
#endif
}

BVH_CL_FN float bvh_cl_slab(const bvh_cl_rayx *r, float4 lo, float4 hi, float tfar);
/* as bvh__tri_test: the ray must reach the triangle's own box by t (hits that precision made up) */
BVH_CL_FN int bvh_cl_tri_box_reached(const bvh_cl_rayx *r, __global const float *tri, float tt) {
    float3 a = vload3(0, tri), b = vload3(1, tri), c = vload3(2, tri);
    float3 lo = fmin(fmin(a, b), c), hi = fmax(fmax(a, b), c);
    return bvh_cl_slab(r, (float4)(lo, 0.0f), (float4)(hi, 0.0f), tt) != INFINITY;
}

/* edge functions of both signs: a miss (bvh__edges_mixed) */
BVH_CL_FN int bvh_cl_edges_mixed(float U, float V, float W) {
    return (U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f);
}
/* bvh__tri_test: translated, sheared and tested in float; edge functions of both signs: a miss at
   once; else, where one is zero, all three redone as exact products (Woop et al.'s fallback) */
BVH_CL_FN int bvh_cl_tri_test(const bvh_cl_rayx *r, __global const float *tri, float tmax, float *t, float *u,
                              float *v) {
    const int kx = r->kx, ky = r->ky, kz = r->kz;
    float Az = tri[kz] - r->okz, Bz = tri[3 + kz] - r->okz, Cz = tri[6 + kz] - r->okz;
    float Ax = (tri[kx] - r->okx) - r->sx * Az, Ay = (tri[ky] - r->oky) - r->sy * Az;
    float Bx = (tri[3 + kx] - r->okx) - r->sx * Bz, By = (tri[3 + ky] - r->oky) - r->sy * Bz;
    float Cx = (tri[6 + kx] - r->okx) - r->sx * Cz, Cy = (tri[6 + ky] - r->oky) - r->sy * Cz;
    float U = Cx * By - Cy * Bx, V = Ax * Cy - Ay * Cx, W = Bx * Ay - By * Ax, det, T, tt;
    if (bvh_cl_edges_mixed(U, V, W)) return 0;
    if (U == 0.0f || V == 0.0f || W == 0.0f) {
        U = bvh_cl_diff_of_products(Cx, By, Cy, Bx);
        V = bvh_cl_diff_of_products(Ax, Cy, Ay, Cx);
        W = bvh_cl_diff_of_products(Bx, Ay, By, Ax);
        if (bvh_cl_edges_mixed(U, V, W)) return 0;
    }
    det = U + V + W;
    if (det == 0.0f) return 0;
    T = U * (r->sz * Az) + V * (r->sz * Bz) + W * (r->sz * Cz);
    tt = T / det;
    if (!(tt >= r->tmin && tt <= tmax && tt < INFINITY)) return 0;
#ifdef BVH_CL_FP64
    {
        double e1x = (double)tri[3] - tri[0], e1y = (double)tri[4] - tri[1], e1z = (double)tri[5] - tri[2];
        double e2x = (double)tri[6] - tri[0], e2y = (double)tri[7] - tri[1], e2z = (double)tri[8] - tri[2];
        if (e1y * e2z - e1z * e2y == 0.0 && e1z * e2x - e1x * e2z == 0.0 && e1x * e2y - e1y * e2x == 0.0) return 0;
    }
#else
    if (all(cross(vload3(1, tri) - vload3(0, tri), vload3(2, tri) - vload3(0, tri)) == (float3)(0.0f))) return 0;
#endif
    if (!bvh_cl_tri_box_reached(r, tri, tt)) return 0;
    *t = tt;
    *u = V / det;
    *v = W / det;
    return 1;
}

/* ============================================================================================ */
/* == slab test and traversal (bvh__slab, bvh__traverse) ========================================= */
/* ============================================================================================ */
/* Entry distance of the ray into the box (lo, hi) if it enters before tfar, else +inf. */
BVH_CL_FN float bvh_cl_slab(const bvh_cl_rayx *r, float4 lo, float4 hi, float tfar) {
    float3 a0 = (select(lo.xyz, hi.xyz, r->neg) - r->o) * r->inv;
    float3 a1 = (select(hi.xyz, lo.xyz, r->neg) - r->o) * r->inv;
    float tn = r->tmin, tf = INFINITY;
    tn = a0.x > tn ? a0.x : tn; /* NaN (origin on the plane) leaves tn as it is */
    tf = a1.x < tf ? a1.x : tf;
    tn = a0.y > tn ? a0.y : tn;
    tf = a1.y < tf ? a1.y : tf;
    tn = a0.z > tn ? a0.z : tn;
    tf = a1.z < tf ? a1.z : tf;
    tf *= 1.0000004f; /* 1 + 2 gamma(3) */
    {                 /* as bvh__slab: lower the entry by 2^-18 of the box's distances along the dominant axis */
        float k0 = fabs(r->kz == 0 ? a0.x : r->kz == 1 ? a0.y : a0.z);
        float k1 = fabs(r->kz == 0 ? a1.x : r->kz == 1 ? a1.y : a1.z);
        tn -= (k0 > k1 ? k0 : k1) * 0x1p-18f;
    }
    tn = tn < r->tmin ? r->tmin : tn; /* as bvh__slab_t: never below tmin (a NaN stays) */
    tf = tf < tfar ? tf : tfar;
    return tn <= tf ? tn : INFINITY;
}

typedef struct bvh_cl_hitrec {
    float t, u, v;
    uint prim;    /* BVH_CL_INVALID: miss */
    uint ref;     /* reference of the hit (index into its tree's tris) */
    uint inst;    /* the hit's instance (0 for a one-level tree) */
    uint visited; /* nodes whose box was tested, counted as bvh_intersect_counted does */
} bvh_cl_hitrec;

/* One tree's buffers: nodes, triangles and primitive ids (a scene's top level: its nodes and the
   instance of each reference, no triangles). */
typedef struct bvh_cl_level {
    __global const uint4 *nodes;
    __global const float *tris;
    __global const uint *prims;
    uint node_count, ref_count;
} bvh_cl_level;

/* A two-level scene (bvh_scene, uploaded by bvh_cl_scene_upload) and the world ray traced in it.
   The distinct bottom-level trees lie one after the other in nodes, tris and prims; meshes[m] =
   (first node, node count, first reference, reference count) of tree m. Instance i: inverse +
   12 i its world-to-object transform (bvh_scene.inverse), info[i] = (mask, id, tree, 0). */
typedef struct bvh_cl_scene {
    bvh_cl_level top;
    __global const uint4 *nodes;
    __global const float *tris;
    __global const uint *prims;
    __global const uint4 *meshes;
    __global const float *inverse;
    __global const uint4 *info;
    uint mesh_count, instance_count, mask;
    float3 o, d; /* the world ray */
    float tmin;
} bvh_cl_scene;

/* The children pair (c, c + 1) of an interior node as two uint4 each; 0 when the pair lies
   outside the array (a corrupt tree: the traversal ends). */
BVH_CL_FN int bvh_cl_children(const bvh_cl_level *s, uint c, uint4 *lo0, uint4 *hi0, uint4 *lo1, uint4 *hi1) {
    if (c >= s->node_count - 1) return 0;
    *lo0 = s->nodes[2 * c];
    *hi0 = s->nodes[2 * c + 1];
    *lo1 = s->nodes[2 * c + 2];
    *hi1 = s->nodes[2 * c + 3];
    return 1;
}

/* Enters instance i of a scene (bvh__instance_step): its tree's level, the world ray moved into
   its space by the operations of bvh_ray_transform (FP_CONTRACT is off: the same bits), set up,
   and the tree's root node. 0 when the mask skips the instance, its tree is empty, the ray in its
   space is invalid or misses the root box before tmax (the current best), or i is out of range. */
BVH_CL_FN int bvh_cl_enter(const bvh_cl_scene *sc, uint i, float tmax, bvh_cl_rayx *rx, bvh_cl_level *lv, uint4 *lo,
                           uint4 *hi) {
    __global const float *m;
    float3 o, d, wo = sc->o, wd = sc->d;
    uint4 info, mesh, a, b;
    if (i >= sc->instance_count) return 0;
    info = sc->info[i];
    if (!(info.x & sc->mask) || info.z >= sc->mesh_count) return 0;
    mesh = sc->meshes[info.z];
    if (!mesh.y) return 0;
    m = sc->inverse + 12 * (size_t)i;
    o.x = m[0] * wo.x + m[1] * wo.y + m[2] * wo.z + m[3];
    o.y = m[4] * wo.x + m[5] * wo.y + m[6] * wo.z + m[7];
    o.z = m[8] * wo.x + m[9] * wo.y + m[10] * wo.z + m[11];
    d.x = m[0] * wd.x + m[1] * wd.y + m[2] * wd.z;
    d.y = m[4] * wd.x + m[5] * wd.y + m[6] * wd.z;
    d.z = m[8] * wd.x + m[9] * wd.y + m[10] * wd.z;
    if (!bvh_cl_ray_setup(o, sc->tmin, d, tmax, rx)) return 0;
    a = sc->nodes[2 * (size_t)mesh.x];
    b = sc->nodes[2 * (size_t)mesh.x + 1];
    if (bvh_cl_slab(rx, as_float4(a), as_float4(b), tmax) == INFINITY) return 0;
    lv->nodes = sc->nodes + 2 * (size_t)mesh.x;
    lv->node_count = mesh.y;
    lv->tris = sc->tris + 9 * (size_t)mesh.z;
    lv->prims = sc->prims + mesh.z;
    lv->ref_count = mesh.w;
    *lo = a;
    *hi = b;
    return 1;
}

/* Closest hit (any = 0) or first hit found (any = 1) of a set-up ray in [tmin, tmax], in one tree
   (sc NULL: the tree `top`) or in a scene (sc; top = sc->top). One loop for both levels, with a
   level switch: a leaf of the top level hands its instances, one by one in order, to the loop,
   which enters each (bvh_cl_enter) and walks its tree above the top level's part of the stack
   (from `floor` up), with the ray in the instance's space; when that part is empty, the loop is
   back at the top level with the world ray and takes the leaf's next instance. This is the CPU's
   order (bvh__trace_leaves with bvh__instance_step), and the best hit is theirs: the lowest
   (t, instance, triangle), t in world units because the transformed ray is not normalised.
   The stack holds `cap` entries (two trees deep for a scene). A child index or leaf range outside
   the arrays (a corrupt tree) ends the traversal, so that no read ever leaves the buffers; a tree
   deeper than the stack does too, as on the CPU. After inlining, sc is a constant: a one-level
   kernel keeps none of the scene's code. */
BVH_CL_FN void bvh_cl_traverse(const bvh_cl_level *top, const bvh_cl_scene *sc, const bvh_cl_rayx *rxw, float tmax,
                               int any, uint *stack, float *stack_t, uint cap, bvh_cl_hitrec *res) {
    bvh_cl_level lv = *top; /* the level the loop is in */
    bvh_cl_rayx rxl;        /* the ray in the current instance's space */
    const bvh_cl_rayx *rx = rxw;
    uint sp = 0, nvis = 1, floor = 0, inst = 0, next = 0, end_inst = 0;
    int bottom = 0;
    float best_t = tmax;
    uint4 lo = lv.nodes[0], hi = lv.nodes[1]; /* the current node */
    int done = bvh_cl_slab(rx, as_float4(lo), as_float4(hi), best_t) == INFINITY;
    res->prim = res->inst = BVH_CL_INVALID;
    res->ref = 0;
    res->u = res->v = 0.0f;
    while (!done) {
        int descended = 0;
        if (hi.w) {
            uint k, end = lo.w + hi.w;
            if (end > lv.ref_count || end < lo.w) break;
            if (sc && !bottom) { /* a leaf of instances: entered below, one at a time */
                next = lo.w;
                end_inst = end;
            } else {
                for (k = lo.w; k < end; k++) {
                    float t, u, v;
                    uint prim;
                    if (!bvh_cl_tri_test(rx, lv.tris + 9 * (size_t)k, best_t, &t, &u, &v)) continue;
                    prim = lv.prims[k];
                    /* ties: the lowest instance, then the lowest index */
                    if (t == best_t && (inst > res->inst || (inst == res->inst && prim > res->prim))) continue;
                    best_t = t;
                    res->u = u;
                    res->v = v;
                    res->prim = prim;
                    res->ref = k;
                    res->inst = inst;
                    if (any) {
                        done = 1;
                        break;
                    }
                }
            }
        } else {
            uint c = lo.w;
            uint4 lo0, hi0, lo1, hi1;
            float t0, t1;
            if (!bvh_cl_children(&lv, c, &lo0, &hi0, &lo1, &hi1)) break;
            t0 = bvh_cl_slab(rx, as_float4(lo0), as_float4(hi0), best_t);
            t1 = bvh_cl_slab(rx, as_float4(lo1), as_float4(hi1), best_t);
            nvis += 2;
            if (t0 != INFINITY || t1 != INFINITY) {
                uint far = c + 1;
                if (t1 < t0) {
                    float tt = t0;
                    t0 = t1;
                    t1 = tt;
                    lo = lo1;
                    hi = hi1;
                    far = c;
                } else {
                    lo = lo0;
                    hi = hi0;
                }
                if (t1 != INFINITY) {
                    if (sp == cap) break; /* a tree deeper than the validator allows */
                    stack_t[sp] = t1;
                    stack[sp++] = far;
                }
                descended = 1;
            }
        }
        if (!descended && !done) {
            for (;;) { /* the next node: of the leaf's next instance, or popped if still in reach */
                if (sc && !bottom && next < end_inst) {
                    inst = lv.prims[next++];
                    if (!bvh_cl_enter(sc, inst, best_t, &rxl, &lv, &lo, &hi)) continue;
                    nvis++;
                    bottom = 1;
                    floor = sp;
                    rx = &rxl;
                    break;
                }
                if (sc && bottom && sp == floor) { /* the instance's tree is done: back to the top */
                    bottom = 0;
                    lv = *top;
                    rx = rxw;
                    continue;
                }
                if (!sp) {
                    done = 1;
                    break;
                }
                --sp;
                if (stack_t[sp] <= best_t) {
                    lo = lv.nodes[2 * stack[sp]];
                    hi = lv.nodes[2 * stack[sp] + 1];
                    break;
                }
            }
        }
    }
    res->t = best_t;
    res->visited = nvis;
}

/* Traces one ray in a tree; a miss leaves t = tmax, u = v = 0, prim = BVH_CL_INVALID, like
   bvh_intersect. */
BVH_CL_FN void bvh_cl_trace(const bvh_cl_level *s, float3 o, float tmin, float3 d, float tmax, int any,
                            bvh_cl_hitrec *res) {
    uint stack[BVH_CL_STACK];
    float stack_t[BVH_CL_STACK]; /* entry distance of each pushed node */
    bvh_cl_rayx rx;
    res->t = tmax;
    res->u = res->v = 0.0f;
    res->prim = BVH_CL_INVALID;
    res->ref = 0;
    res->visited = 0;
    if (!s->node_count || !bvh_cl_ray_setup(o, tmin, d, tmax, &rx)) return;
    bvh_cl_traverse(s, 0, &rx, tmax, any, stack, stack_t, BVH_CL_STACK, res);
    if (res->prim == BVH_CL_INVALID) {
        res->t = tmax;
        res->u = res->v = 0.0f;
    }
}

/* The tree's buffers as every kernel takes them first (cl/bvh_cl.h sets them as arguments 0-4). */
#define BVH_CL_TREE_ARGS                                                                                               \
    __global const uint4 *nodes, uint node_count, __global const float *tris, __global const uint *prims, uint ref_count

/* The work-item's ray of a batch (origin, tmin, direction, tmax: 8 floats) traced into *res;
   0 for a work-item past the batch's count (nothing traced). */
int bvh_cl_trace_batch_ray(BVH_CL_TREE_ARGS, __global const float *rays, uint count, int any, bvh_cl_hitrec *res) {
    const uint i = (uint)get_global_id(0);
    bvh_cl_level s;
    float4 r0, r1;
    if (i >= count) return 0;
    r0 = vload4(2 * (size_t)i, rays);
    r1 = vload4(2 * (size_t)i + 1, rays);
    s.nodes = nodes;
    s.tris = tris;
    s.prims = prims;
    s.node_count = node_count;
    s.ref_count = ref_count;
    bvh_cl_trace(&s, r0.xyz, r0.w, r1.xyz, r1.w, any, res);
    return 1;
}

/* ============================================================================================ */
/* == two-level scenes ============================================================================ */
/* ============================================================================================ */
/* The world normal of a scene hit, as bvh__scene_normal: (v1 - v0) x (v2 - v0) of the triangle in
   object space by the transpose of the world-to-object matrix, normalised, in double (float
   without cl_khr_fp64, which is not the CPU's to the bit); zero for a zero-area triangle. */
BVH_CL_FN float3 bvh_cl_scene_normal(const bvh_cl_scene *sc, const bvh_cl_hitrec *res) {
    __global const float *inv = sc->inverse + 12 * (size_t)res->inst;
    __global const float *t = sc->tris + 9 * ((size_t)sc->meshes[sc->info[res->inst].z].z + res->ref);
#ifdef BVH_CL_FP64
    double e1[3], e2[3], n[3], w[3], l;
    int k;
    for (k = 0; k < 3; k++) {
        e1[k] = (double)t[3 + k] - t[k];
        e2[k] = (double)t[6 + k] - t[k];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    for (k = 0; k < 3; k++) w[k] = inv[k] * n[0] + inv[4 + k] * n[1] + inv[8 + k] * n[2];
    l = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    if (!(l > 0.0)) return (float3)(0.0f);
    return (float3)((float)(w[0] / l), (float)(w[1] / l), (float)(w[2] / l));
#else
    float3 n = cross(vload3(1, t) - vload3(0, t), vload3(2, t) - vload3(0, t)), w;
    float l;
    w.x = inv[0] * n.x + inv[4] * n.y + inv[8] * n.z;
    w.y = inv[1] * n.x + inv[5] * n.y + inv[9] * n.z;
    w.z = inv[2] * n.x + inv[6] * n.y + inv[10] * n.z;
    l = sqrt(dot(w, w));
    return l > 0.0f ? w / l : (float3)(0.0f);
#endif
}

/* A scene's buffers as the scene kernels take them first (cl/bvh_cl.h sets arguments 0-12). */
#define BVH_CL_SCENE_ARGS                                                                                              \
    __global const uint4 *top_nodes, uint top_node_count, __global const uint *top_prims, uint top_ref_count,          \
        __global const uint4 *nodes, __global const float *tris, __global const uint *prims,                           \
        __global const uint4 *meshes, uint mesh_count, __global const float *inverse, __global const uint4 *info,      \
        uint instance_count, uint mask

/* The work-item's ray of a scene batch traced into *res (bvh_scene_intersect / occluded); 0 for a
   work-item past the batch's count. A miss leaves t = tmax, prim = inst = BVH_CL_INVALID. */
int bvh_cl_trace_scene_ray(BVH_CL_SCENE_ARGS, __global const float *rays, uint count, int any, bvh_cl_scene *sc,
                           bvh_cl_hitrec *res) {
    const uint i = (uint)get_global_id(0);
    uint stack[2 * BVH_CL_STACK];
    float stack_t[2 * BVH_CL_STACK];
    bvh_cl_rayx rx;
    float4 r0, r1;
    if (i >= count) return 0;
    r0 = vload4(2 * (size_t)i, rays);
    r1 = vload4(2 * (size_t)i + 1, rays);
    sc->top.nodes = top_nodes;
    sc->top.tris = 0;
    sc->top.prims = top_prims;
    sc->top.node_count = top_node_count;
    sc->top.ref_count = top_ref_count;
    sc->nodes = nodes;
    sc->tris = tris;
    sc->prims = prims;
    sc->meshes = meshes;
    sc->mesh_count = mesh_count;
    sc->inverse = inverse;
    sc->info = info;
    sc->instance_count = instance_count;
    sc->mask = mask;
    sc->o = r0.xyz;
    sc->tmin = r0.w;
    sc->d = r1.xyz;
    res->prim = res->inst = BVH_CL_INVALID;
    if (top_node_count && mask && bvh_cl_ray_setup(r0.xyz, r0.w, r1.xyz, r1.w, &rx))
        bvh_cl_traverse(&sc->top, sc, &rx, r1.w, any, stack, stack_t, 2 * BVH_CL_STACK, res);
    if (res->prim == BVH_CL_INVALID) res->t = r1.w;
    return 1;
}

/* ============================================================================================ */
/* == kernels =================================================================================== */
/* ============================================================================================ */
/* Closest hit of rays[0 .. count) into hits (bvh_intersect_batch). */
__kernel void bvh_intersect_kernel(BVH_CL_TREE_ARGS, __global const float *rays, __global uint4 *hits, uint count) {
    bvh_cl_hitrec res;
    if (bvh_cl_trace_batch_ray(nodes, node_count, tris, prims, ref_count, rays, count, 0, &res))
        hits[get_global_id(0)] = (uint4)(as_uint(res.t), as_uint(res.u), as_uint(res.v), res.prim);
}

/* Any hit of rays[0 .. count): occluded[i] = 1 if blocked (bvh_occluded_batch). */
__kernel void bvh_occluded_kernel(BVH_CL_TREE_ARGS, __global const float *rays, __global uchar *occluded, uint count) {
    bvh_cl_hitrec res;
    if (bvh_cl_trace_batch_ray(nodes, node_count, tris, prims, ref_count, rays, count, 1, &res))
        occluded[get_global_id(0)] = res.prim != BVH_CL_INVALID ? (uchar)1 : (uchar)0;
}

/* The arguments of bvh_cl_trace_scene_ray, passed on by the scene kernels */
#define BVH_CL_SCENE_PASS                                                                                              \
    top_nodes, top_node_count, top_prims, top_ref_count, nodes, tris, prims, meshes, mesh_count, inverse, info,        \
        instance_count, mask

/* Closest hits of rays[0 .. count) in a scene for the instances `mask` selects
   (bvh_scene_intersect): hits as bvh_scene_hit, 9 words each: t, u, v, instance, id, prim, normal. */
__kernel void bvh_scene_intersect_kernel(BVH_CL_SCENE_ARGS, __global const float *rays, __global uint *hits,
                                         uint count) {
    bvh_cl_scene sc;
    bvh_cl_hitrec res;
    __global uint *h = hits + 9 * (size_t)get_global_id(0);
    float3 n = (float3)(0.0f);
    int found;
    if (!bvh_cl_trace_scene_ray(BVH_CL_SCENE_PASS, rays, count, 0, &sc, &res)) return;
    found = res.prim != BVH_CL_INVALID;
    if (found) n = bvh_cl_scene_normal(&sc, &res);
    h[0] = as_uint(res.t);
    h[1] = as_uint(found ? res.u : 0.0f);
    h[2] = as_uint(found ? res.v : 0.0f);
    h[3] = found ? res.inst : BVH_CL_INVALID;
    h[4] = found ? info[res.inst].y : BVH_CL_INVALID;
    h[5] = res.prim;
    h[6] = as_uint(n.x);
    h[7] = as_uint(n.y);
    h[8] = as_uint(n.z);
}

/* Any hit of rays[0 .. count) in a scene: occluded[i] = 1 if blocked (bvh_scene_occluded). */
__kernel void bvh_scene_occluded_kernel(BVH_CL_SCENE_ARGS, __global const float *rays, __global uchar *occluded,
                                        uint count) {
    bvh_cl_scene sc;
    bvh_cl_hitrec res;
    if (bvh_cl_trace_scene_ray(BVH_CL_SCENE_PASS, rays, count, 1, &sc, &res))
        occluded[get_global_id(0)] = res.prim != BVH_CL_INVALID ? (uchar)1 : (uchar)0;
}

/* The colour of a frame's pixel (ray direction d, sy as in bvh_frame_kernel): a hit grey by a
   headlight, grey * (0.2 + 0.8 |dot(n, d)|), a miss a vertical gradient. */
BVH_CL_FN uchar4 bvh_cl_shade(__global const float *tris, uint prim, uint ref, float3 d, float sy) {
    float3 c;
    if (prim != BVH_CL_INVALID) {
        __global const float *t = tris + 9 * (size_t)ref;
        float3 e1 = (float3)(t[3] - t[0], t[4] - t[1], t[5] - t[2]);
        float3 e2 = (float3)(t[6] - t[0], t[7] - t[1], t[8] - t[2]);
        float3 n = cross(e1, e2);
        float nl = sqrt(dot(n, n)), k = nl > 0.0f ? fabs(dot(n, d)) / nl : 0.0f;
        c = (float3)(0.82f, 0.82f, 0.80f) * (0.2f + 0.8f * k);
    } else {
        float g = 0.5f * (sy + 1.0f); /* 1 at the top */
        c = mix((float3)(0.16f, 0.18f, 0.22f), (float3)(0.36f, 0.44f, 0.56f), g);
    }
    c = clamp(c, 0.0f, 1.0f) * 255.0f + 0.5f;
    return (uchar4)((uchar)c.x, (uchar)c.y, (uchar)c.z, (uchar)255);
}

/* Rows y0 .. y0 + rows - 1 of a frame seen by a bvh_camera packed as cam.s0-2 eye, s3-5 forward,
   s6-8 right, s9-b up. Ray of pixel (x, y), y = 0 at the top, exactly as bvh_camera_ray:
   d = normalize(forward + sx*right + sy*up), sx = 2(x+0.5)/w - 1, sy = 1 - 2(y+0.5)/h.
   Outputs (each may be NULL), indexed from the first row of the band: rgba (4 bytes per pixel):
   hits shaded with a headlight, grey * (0.2 + 0.8 |dot(n, d)|), misses a vertical gradient;
   hits (bvh_hit); visited (nodes visited, as bvh_intersect_counted). */
__kernel void bvh_frame_kernel(BVH_CL_TREE_ARGS, float16 cam, uint width, uint height, uint y0, uint rows,
                               __global uchar *rgba, __global uint4 *hits, __global uint *visited) {
    uint x = (uint)get_global_id(0), row = (uint)get_global_id(1), y = y0 + row;
    size_t pix = (size_t)row * width + x;
    bvh_cl_level s;
    bvh_cl_hitrec res;
    float sx, sy, l;
    float3 d;
    if (x >= width || row >= rows) return;
    s.nodes = nodes;
    s.tris = tris;
    s.prims = prims;
    s.node_count = node_count;
    s.ref_count = ref_count;
    sx = 2.0f * ((float)x + 0.5f) / (float)width - 1.0f;
    sy = 1.0f - 2.0f * ((float)y + 0.5f) / (float)height;
    d.x = cam.s3 + sx * cam.s6 + sy * cam.s9;
    d.y = cam.s4 + sx * cam.s7 + sy * cam.sa;
    d.z = cam.s5 + sx * cam.s8 + sy * cam.sb;
    l = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
    if (l > 0.0f) {
        d.x = d.x / l;
        d.y = d.y / l;
        d.z = d.z / l;
    }
    bvh_cl_trace(&s, cam.s012, 0.0f, d, INFINITY, 0, &res);
    if (hits) hits[pix] = (uint4)(as_uint(res.t), as_uint(res.u), as_uint(res.v), res.prim);
    if (visited) visited[pix] = res.visited;
    if (rgba) vstore4(bvh_cl_shade(tris, res.prim, res.ref, d, sy), pix, rgba);
}

/* ============================================================================================ */
/* == packets: 8 or 16 rays per work-item (frames on CPU devices) =============================== */
/* ============================================================================================ */
/* A CPU OpenCL driver such as PoCL runs the one-ray kernels above as scalar code: its vectoriser
   does not take their data-dependent loops across work-items. Here one work-item traces the
   4 x BVH_CL_PACKET_H pixels of a tile together (BVH_CL_PACKET = 4 BVH_CL_PACKET_H rays, 8 or
   16, set by the host): the rays are set up and every box test is done for all of them at once
   in vectors of that width (a vector instruction or two per step), the node is entered when any ray of the packet
   reaches it, and the triangles of a leaf are tested ray by ray with the scalar watertight test, for the rays that
   reach the leaf. The slab test is bvh_cl_slab's, step for step, so every ray gets exactly its one-ray hit (visiting a
   node more for some ray never changes a closest hit: the triangle test alone decides). The node counts of a heat map
   are the one-ray kernel's. */
#ifndef BVH_CL_PACKET
#define BVH_CL_PACKET 8
#endif
#if BVH_CL_PACKET == 16
typedef float16 bvh_pkf;
typedef int16 bvh_pki;
typedef uint16 bvh_pku;
#define BVH_PK_LOAD vload16
#define BVH_PK_STORE vstore16
#define BVH_PK_CONVERT convert_float16
#define BVH_PK_ASU as_uint16
#define BVH_PK_IOTA ((bvh_pki)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define BVH_PK_OR(v) bvh_cl_or8((v).lo | (v).hi)
#elif BVH_CL_PACKET == 8
typedef float8 bvh_pkf;
typedef int8 bvh_pki;
typedef uint8 bvh_pku;
#define BVH_PK_LOAD vload8
#define BVH_PK_STORE vstore8
#define BVH_PK_CONVERT convert_float8
#define BVH_PK_ASU as_uint8
#define BVH_PK_IOTA ((bvh_pki)(0, 1, 2, 3, 4, 5, 6, 7))
#define BVH_PK_OR(v) bvh_cl_or8(v)
#else
#error "BVH_CL_PACKET must be 8 or 16"
#endif
#define BVH_CL_PACKET_H (BVH_CL_PACKET / 4)
BVH_CL_FN uint bvh_cl_or8(int8 v) {
    int4 a = v.lo | v.hi;
    int2 b = a.lo | a.hi;
    return (uint)(b.x | b.y);
}
/* the lanes of a mask (all bits or none per lane) as the bits of a uint */
BVH_CL_FN uint bvh_cl_bits(bvh_pki m) { return BVH_PK_OR(m & ((bvh_pki)(1) << BVH_PK_IOTA)); }

typedef struct bvh_cl_packet {
    bvh_pkf ox, oy, oz, ix, iy, iz, tmin;
    bvh_pki nx, ny, nz; /* inv < 0 (all bits set): the near plane is the max plane */
    bvh_pki kz;         /* dominant axis, for the entry's widening */
} bvh_cl_packet;

/* bvh_cl_slab for a packet's rays: entry distances, +inf where a ray does not enter before tfar. */
BVH_CL_FN bvh_pkf bvh_cl_slab8(const bvh_cl_packet *p, float4 lo, float4 hi, bvh_pkf tfar) {
    bvh_pkf a0x = (select((bvh_pkf)lo.x, (bvh_pkf)hi.x, p->nx) - p->ox) * p->ix;
    bvh_pkf a1x = (select((bvh_pkf)hi.x, (bvh_pkf)lo.x, p->nx) - p->ox) * p->ix;
    bvh_pkf a0y = (select((bvh_pkf)lo.y, (bvh_pkf)hi.y, p->ny) - p->oy) * p->iy;
    bvh_pkf a1y = (select((bvh_pkf)hi.y, (bvh_pkf)lo.y, p->ny) - p->oy) * p->iy;
    bvh_pkf a0z = (select((bvh_pkf)lo.z, (bvh_pkf)hi.z, p->nz) - p->oz) * p->iz;
    bvh_pkf a1z = (select((bvh_pkf)hi.z, (bvh_pkf)lo.z, p->nz) - p->oz) * p->iz;
    bvh_pkf tn = p->tmin, tf = (bvh_pkf)(INFINITY), k0, k1;
    tn = select(tn, a0x, a0x > tn); /* NaN (origin on the plane) leaves tn as it is */
    tf = select(tf, a1x, a1x < tf);
    tn = select(tn, a0y, a0y > tn);
    tf = select(tf, a1y, a1y < tf);
    tn = select(tn, a0z, a0z > tn);
    tf = select(tf, a1z, a1z < tf);
    tf *= 1.0000004f;
    k0 = fabs(select(select(a0z, a0y, p->kz == (bvh_pki)(1)), a0x, p->kz == (bvh_pki)(0)));
    k1 = fabs(select(select(a1z, a1y, p->kz == (bvh_pki)(1)), a1x, p->kz == (bvh_pki)(0)));
    tn -= select(k1, k0, k0 > k1) * 0x1p-18f;
    tn = select(tn, p->tmin, tn < p->tmin); /* never below tmin (bvh_cl_slab) */
    tf = select(tfar, tf, tf < tfar);
    return select((bvh_pkf)(INFINITY), tn, tn <= tf);
}

/* Closest hits of the packet's rays; best[] holds each ray's tmax on entry (-inf: no ray, which
   then enters no box) and its hit distance on return, prim[] BVH_CL_INVALID on entry. */
BVH_CL_FN void bvh_cl_traverse8(const bvh_cl_level *s, const bvh_cl_packet *p, const bvh_cl_rayx *rx, float *best,
                                float *u, float *v, uint *prim, uint *ref) {
    uint stack[BVH_CL_STACK];
    bvh_pkf stack_t[BVH_CL_STACK]; /* entry distances of each pushed node */
    uint sp = 0;
    bvh_pkf bt = BVH_PK_LOAD(0, best);
    uint4 lo = s->nodes[0], hi = s->nodes[1];
    bvh_pkf te = bvh_cl_slab8(p, as_float4(lo), as_float4(hi), bt);
    if (!any(te != (bvh_pkf)(INFINITY))) return;
    for (;;) {
        int descended = 0;
        if (hi.w) {
            uint k, end = lo.w + hi.w, l;
            /* the rays that reach the leaf, as bits; ray by ray, triangle by triangle */
            uint m = bvh_cl_bits((te != (bvh_pkf)(INFINITY)) & (te <= bt));
            if (end > s->ref_count || end < lo.w) return;
            for (; m; m &= m - 1) {
                const bvh_cl_rayx *r;
                float bl;
                l = 31 - clz(m & (0u - m));
                r = &rx[l];
                bl = best[l];
                for (k = lo.w; k < end; k++) {
                    float t, tu, tv;
                    uint pr;
                    if (!bvh_cl_tri_test(r, s->tris + 9 * (size_t)k, bl, &t, &tu, &tv)) continue;
                    pr = s->prims[k];
                    if (t == bl && pr > prim[l]) continue; /* ties: lowest index */
                    bl = t;
                    u[l] = tu;
                    v[l] = tv;
                    prim[l] = pr;
                    ref[l] = k;
                }
                best[l] = bl;
            }
            bt = BVH_PK_LOAD(0, best);
        } else {
            uint c = lo.w;
            uint4 lo0, hi0, lo1, hi1;
            bvh_pkf t0, t1;
            int h0, h1;
            if (!bvh_cl_children(s, c, &lo0, &hi0, &lo1, &hi1)) return;
            t0 = bvh_cl_slab8(p, as_float4(lo0), as_float4(hi0), bt);
            t1 = bvh_cl_slab8(p, as_float4(lo1), as_float4(hi1), bt);
            h0 = any(t0 != (bvh_pkf)(INFINITY));
            h1 = any(t1 != (bvh_pkf)(INFINITY));
            if (h0 || h1) {
                /* near child first: the one more of the packet's rays enter first */
                int one = h1 && (!h0 || 2 * popcount(bvh_cl_bits(t1 < t0)) > BVH_CL_PACKET);
                if (one) {
                    lo = lo1;
                    hi = hi1;
                    te = t1;
                } else {
                    lo = lo0;
                    hi = hi0;
                    te = t0;
                }
                if (h0 && h1) {
                    if (sp == BVH_CL_STACK) return; /* a tree deeper than the validator allows */
                    stack_t[sp] = one ? t0 : t1;
                    stack[sp++] = one ? c : c + 1;
                }
                descended = 1;
            }
        }
        if (!descended) {
            for (;;) { /* pop the next node some ray still reaches before its best */
                if (!sp) return;
                --sp;
                if (any((stack_t[sp] != (bvh_pkf)(INFINITY)) & (stack_t[sp] <= bt))) {
                    lo = s->nodes[2 * stack[sp]];
                    hi = s->nodes[2 * stack[sp] + 1];
                    te = stack_t[sp];
                    break;
                }
            }
        }
    }
}

/* bvh_cl_ray_setup for the camera rays of a packet at once (the same operations lane by
   lane, so the same bits), into the packet and the lanes' one-ray records for the triangle
   tests; a lane that is no ray (outside the image, or invalid) gets tmin = +inf and best = -inf,
   so that it enters no box. Vector divisions and square roots cost about what one scalar does. */
BVH_CL_FN void bvh_cl_packet_setup(float3 o, bvh_pkf dx, bvh_pkf dy, bvh_pkf dz, bvh_pki live, bvh_cl_packet *p,
                                   bvh_cl_rayx *rx, float *best) {
    bvh_pkf ax, ay, az, dkx, dky, dkz, sx, sy, sz, okx, oky, okz, inf = (bvh_pkf)(INFINITY);
    bvh_pki kx, ky, kz, sw, ok, t;
    float a[9][BVH_CL_PACKET];
    int m[6][BVH_CL_PACKET];
    uint l;
    ok = live & isfinite(dx) & isfinite(dy) & isfinite(dz);
    if (!(isfinite(o.x) && isfinite(o.y) && isfinite(o.z))) ok = (bvh_pki)(0);
    dx = select(dx, (bvh_pkf)(0.0f), fabs(dx) < (bvh_pkf)(FLT_MIN));
    dy = select(dy, (bvh_pkf)(0.0f), fabs(dy) < (bvh_pkf)(FLT_MIN));
    dz = select(dz, (bvh_pkf)(0.0f), fabs(dz) < (bvh_pkf)(FLT_MIN));
    ok &= (dx != (bvh_pkf)(0.0f)) | (dy != (bvh_pkf)(0.0f)) | (dz != (bvh_pkf)(0.0f));
    p->ox = (bvh_pkf)(o.x);
    p->oy = (bvh_pkf)(o.y);
    p->oz = (bvh_pkf)(o.z);
    p->ix = select((bvh_pkf)(1.0f) / dx, inf, dx == (bvh_pkf)(0.0f));
    p->iy = select((bvh_pkf)(1.0f) / dy, inf, dy == (bvh_pkf)(0.0f));
    p->iz = select((bvh_pkf)(1.0f) / dz, inf, dz == (bvh_pkf)(0.0f));
    p->nx = p->ix < (bvh_pkf)(0.0f);
    p->ny = p->iy < (bvh_pkf)(0.0f);
    p->nz = p->iz < (bvh_pkf)(0.0f);
    ax = fabs(dx);
    ay = fabs(dy);
    az = fabs(dz);
    kz = select(select((bvh_pki)(2), (bvh_pki)(1), ay > az), select((bvh_pki)(2), (bvh_pki)(0), ax > az), ax > ay);
    kx = select(kz + 1, (bvh_pki)(0), kz == (bvh_pki)(2));
    ky = select(kx + 1, (bvh_pki)(0), kx == (bvh_pki)(2));
    dkz = select(select(dz, dy, kz == (bvh_pki)(1)), dx, kz == (bvh_pki)(0));
    sw = dkz < (bvh_pkf)(0.0f);
    t = kx;
    kx = select(kx, ky, sw);
    ky = select(ky, t, sw);
    dkx = select(select(dz, dy, kx == (bvh_pki)(1)), dx, kx == (bvh_pki)(0));
    dky = select(select(dz, dy, ky == (bvh_pki)(1)), dx, ky == (bvh_pki)(0));
    sx = dkx / dkz;
    sy = dky / dkz;
    sz = (bvh_pkf)(1.0f) / dkz;
    okx = select(select(p->oz, p->oy, kx == (bvh_pki)(1)), p->ox, kx == (bvh_pki)(0));
    oky = select(select(p->oz, p->oy, ky == (bvh_pki)(1)), p->ox, ky == (bvh_pki)(0));
    okz = select(select(p->oz, p->oy, kz == (bvh_pki)(1)), p->ox, kz == (bvh_pki)(0));
    /* lanes that are no ray: finite stand-ins that enter no box */
    p->ix = select((bvh_pkf)(1.0f), p->ix, ok);
    p->iy = select((bvh_pkf)(1.0f), p->iy, ok);
    p->iz = select((bvh_pkf)(1.0f), p->iz, ok);
    p->nx &= ok;
    p->ny &= ok;
    p->nz &= ok;
    p->tmin = select(inf, (bvh_pkf)(0.0f), ok);
    p->kz = select((bvh_pki)(0), kz, ok);
    BVH_PK_STORE(p->ix, 0, a[0]);
    BVH_PK_STORE(p->iy, 0, a[1]);
    BVH_PK_STORE(p->iz, 0, a[2]);
    BVH_PK_STORE(sx, 0, a[3]);
    BVH_PK_STORE(sy, 0, a[4]);
    BVH_PK_STORE(sz, 0, a[5]);
    BVH_PK_STORE(okx, 0, a[6]);
    BVH_PK_STORE(oky, 0, a[7]);
    BVH_PK_STORE(okz, 0, a[8]);
    BVH_PK_STORE(kx, 0, m[0]);
    BVH_PK_STORE(ky, 0, m[1]);
    BVH_PK_STORE(kz, 0, m[2]);
    BVH_PK_STORE(p->nx, 0, m[3]);
    BVH_PK_STORE(p->ny, 0, m[4]);
    BVH_PK_STORE(p->nz, 0, m[5]);
    BVH_PK_STORE(select(-inf, inf, ok), 0, best);
    for (l = 0; l < BVH_CL_PACKET; l++) {
        rx[l].o = o;
        rx[l].inv = (float3)(a[0][l], a[1][l], a[2][l]);
        rx[l].neg = (int3)(m[3][l], m[4][l], m[5][l]);
        rx[l].tmin = 0.0f;
        rx[l].kx = m[0][l];
        rx[l].ky = m[1][l];
        rx[l].kz = m[2][l];
        rx[l].sx = a[3][l];
        rx[l].sy = a[4][l];
        rx[l].sz = a[5][l];
        rx[l].okx = a[6][l];
        rx[l].oky = a[7][l];
        rx[l].okz = a[8][l];
    }
}

/* bvh_frame_kernel with a 4 x BVH_CL_PACKET_H pixel tile per work-item: work-item (gx, gy) traces
   pixels x = 4 gx .. 4 gx + 3 of rows BVH_CL_PACKET_H gy .. of the band; the same outputs as
   bvh_frame_kernel but no visited counts. */
__kernel void bvh_frame_packet_kernel(BVH_CL_TREE_ARGS, float16 cam, uint width, uint height, uint y0, uint rows,
                                      __global uchar *rgba, __global uint4 *hits) {
    uint gx = (uint)get_global_id(0), gy = (uint)get_global_id(1), l;
    bvh_cl_level s;
    bvh_cl_rayx rx[BVH_CL_PACKET];
    bvh_cl_packet p;
    float best[BVH_CL_PACKET], u[BVH_CL_PACKET], v[BVH_CL_PACKET], dxl[BVH_CL_PACKET], dyl[BVH_CL_PACKET];
    float dzl[BVH_CL_PACKET], syl[BVH_CL_PACKET];
    uint prim[BVH_CL_PACKET], ref[BVH_CL_PACKET];
    int livel[BVH_CL_PACKET];
    bvh_pku x8, row8;
    bvh_pkf sx, sy, dx, dy, dz, ln;
    bvh_pki live;
    if (4 * gx >= width || BVH_CL_PACKET_H * gy >= rows) return;
    s.nodes = nodes;
    s.tris = tris;
    s.prims = prims;
    s.node_count = node_count;
    s.ref_count = ref_count;
    x8 = (bvh_pku)(4 * gx) + BVH_PK_ASU(BVH_PK_IOTA & (bvh_pki)(3));
    row8 = (bvh_pku)(BVH_CL_PACKET_H * gy) + BVH_PK_ASU(BVH_PK_IOTA >> (bvh_pki)(2));
    live = (x8 < (bvh_pku)(width)) & (row8 < (bvh_pku)(rows));
    /* bvh_camera_ray, as in bvh_frame_kernel */
    sx = 2.0f * (BVH_PK_CONVERT(x8) + 0.5f) / (float)width - 1.0f;
    sy = 1.0f - 2.0f * (BVH_PK_CONVERT(row8 + (bvh_pku)(y0)) + 0.5f) / (float)height;
    dx = (bvh_pkf)(cam.s3) + sx * cam.s6 + sy * cam.s9;
    dy = (bvh_pkf)(cam.s4) + sx * cam.s7 + sy * cam.sa;
    dz = (bvh_pkf)(cam.s5) + sx * cam.s8 + sy * cam.sb;
    ln = sqrt(dx * dx + dy * dy + dz * dz);
    dx = select(dx, dx / ln, ln > (bvh_pkf)(0.0f));
    dy = select(dy, dy / ln, ln > (bvh_pkf)(0.0f));
    dz = select(dz, dz / ln, ln > (bvh_pkf)(0.0f));
    BVH_PK_STORE(dx, 0, dxl);
    BVH_PK_STORE(dy, 0, dyl);
    BVH_PK_STORE(dz, 0, dzl);
    BVH_PK_STORE(sy, 0, syl);
    BVH_PK_STORE(live, 0, livel);
    bvh_cl_packet_setup(cam.s012, dx, dy, dz, live, &p, rx, best);
    for (l = 0; l < BVH_CL_PACKET; l++) {
        u[l] = v[l] = 0.0f;
        prim[l] = BVH_CL_INVALID;
        ref[l] = 0;
    }
    if (node_count) bvh_cl_traverse8(&s, &p, rx, best, u, v, prim, ref);
    for (l = 0; l < BVH_CL_PACKET; l++) {
        uint x = 4 * gx + (l & 3), row = BVH_CL_PACKET_H * gy + (l >> 2);
        size_t pix = (size_t)row * width + x;
        float3 d = (float3)(dxl[l], dyl[l], dzl[l]);
        if (!livel[l]) continue;
        if (prim[l] == BVH_CL_INVALID) {
            best[l] = INFINITY;
            u[l] = v[l] = 0.0f;
        }
        if (hits) hits[pix] = (uint4)(as_uint(best[l]), as_uint(u[l]), as_uint(v[l]), prim[l]);
        if (rgba) vstore4(bvh_cl_shade(tris, prim[l], ref[l], d, syl[l]), pix, rgba);
    }
}
