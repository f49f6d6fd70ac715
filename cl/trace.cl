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

   SEMANTICS: those of bvh.h (section "traversal"), statement for statement: watertight triangle
   test (Woop, Benthin & Wald 2013) with the double-precision fallback on edges, ties in t to the
   lowest primitive id, robust slab test (far distance widened by 1.0000004f, zero direction
   components get an inverse of +inf, the near plane is chosen by the sign of the inverse, the NaN
   of an origin on a slab plane is dropped by the order of the comparisons), near child first,
   invalid rays (NaN, non-finite origin or direction, zero direction, tmin > tmax) miss.
   Hits equal the CPU's to the bit when the host builds with -cl-fp32-correctly-rounded-divide-sqrt
   and the device has cl_khr_fp64 (bvh_cl.h does both when it can); FP_CONTRACT is off so that
   no compiler fuses a*b-c*d into an fma the CPU code does not do. Without cl_khr_fp64 the edge
   fallback computes a*b-c*d with fma (Kahan), which has the same sign and zeros.

   OPTIONS (-D from the host)
     BVH_MAX_DEPTH   the host's value (64); the private stack holds BVH_MAX_DEPTH + 2 entries, like
                     the CPU's, and a traversal that would overflow it stops (never writes past it).
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
    int3 neg;            /* inv < 0: the near plane is the max plane on that axis */
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
    if (!(isfinite(o.x) && isfinite(o.y) && isfinite(o.z) && isfinite(d.x) && isfinite(d.y) && isfinite(d.z)))
        return 0;
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
    ax = fabs(d.x); ay = fabs(d.y); az = fabs(d.z);
    rx->kz = ax > ay ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
    rx->kx = rx->kz == 2 ? 0 : rx->kz + 1;
    rx->ky = rx->kx == 2 ? 0 : rx->kx + 1;
    dkz = bvh_cl_comp(d, rx->kz);
    if (dkz < 0.0f) { t = rx->kx; rx->kx = rx->ky; rx->ky = t; }
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

#ifdef BVH_CL_FP64
/* bvh__tri_test: vertices translated in float, shear and edge functions in double */
BVH_CL_FN int bvh_cl_tri_test(const bvh_cl_rayx *r, __global const float *tri, float tmax, float *t, float *u,
                              float *v) {
    const int kx = r->kx, ky = r->ky, kz = r->kz;
    const double sx = r->sx, sy = r->sy, sz = r->sz;
    float Akx = tri[kx] - r->okx, Aky = tri[ky] - r->oky, Akz = tri[kz] - r->okz;
    float Bkx = tri[3 + kx] - r->okx, Bky = tri[3 + ky] - r->oky, Bkz = tri[3 + kz] - r->okz;
    float Ckx = tri[6 + kx] - r->okx, Cky = tri[6 + ky] - r->oky, Ckz = tri[6 + kz] - r->okz;
    double Ax = (double)Akx - sx * (double)Akz, Ay = (double)Aky - sy * (double)Akz;
    double Bx = (double)Bkx - sx * (double)Bkz, By = (double)Bky - sy * (double)Bkz;
    double Cx = (double)Ckx - sx * (double)Ckz, Cy = (double)Cky - sy * (double)Ckz;
    double U = Cx * By - Cy * Bx, V = Ax * Cy - Ay * Cx, W = Bx * Ay - By * Ax, det, T;
    float tt;
    if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return 0;
    det = U + V + W;
    if (det == 0.0) return 0;
    T = U * (sz * (double)Akz) + V * (sz * (double)Bkz) + W * (sz * (double)Ckz);
    tt = (float)(T / det);
    if (!(tt >= r->tmin && tt <= tmax && tt < INFINITY)) return 0;
    {
        double e1x = (double)tri[3] - tri[0], e1y = (double)tri[4] - tri[1], e1z = (double)tri[5] - tri[2];
        double e2x = (double)tri[6] - tri[0], e2y = (double)tri[7] - tri[1], e2z = (double)tri[8] - tri[2];
        if (e1y * e2z - e1z * e2y == 0.0 && e1z * e2x - e1x * e2z == 0.0 && e1x * e2y - e1y * e2x == 0.0) return 0;
    }
    if (!bvh_cl_tri_box_reached(r, tri, tt)) return 0;
    *t = tt;
    *u = (float)(V / det);
    *v = (float)(W / det);
    return 1;
}
#else
BVH_CL_FN int bvh_cl_tri_test(const bvh_cl_rayx *r, __global const float *tri, float tmax, float *t, float *u,
                              float *v) {
    const int kx = r->kx, ky = r->ky, kz = r->kz;
    float Akx = tri[kx] - r->okx, Aky = tri[ky] - r->oky, Akz = tri[kz] - r->okz;
    float Bkx = tri[3 + kx] - r->okx, Bky = tri[3 + ky] - r->oky, Bkz = tri[3 + kz] - r->okz;
    float Ckx = tri[6 + kx] - r->okx, Cky = tri[6 + ky] - r->oky, Ckz = tri[6 + kz] - r->okz;
    float Ax = Akx - r->sx * Akz, Ay = Aky - r->sy * Akz;
    float Bx = Bkx - r->sx * Bkz, By = Bky - r->sy * Bkz;
    float Cx = Ckx - r->sx * Ckz, Cy = Cky - r->sy * Ckz;
    float U = bvh_cl_diff_of_products(Cx, By, Cy, Bx); /* as the CPU: always exact products */
    float V = bvh_cl_diff_of_products(Ax, Cy, Ay, Cx);
    float W = bvh_cl_diff_of_products(Bx, Ay, By, Ax);
    float det, T, rcp, tt;
    if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f)) return 0;
    det = U + V + W;
    if (det == 0.0f) return 0;
    T = U * (r->sz * Akz) + V * (r->sz * Bkz) + W * (r->sz * Ckz);
    rcp = 1.0f / det;
    tt = T * rcp;
    if (!(tt >= r->tmin && tt <= tmax && tt < INFINITY)) return 0;
    if (all(cross(vload3(1, tri) - vload3(0, tri), vload3(2, tri) - vload3(0, tri)) == (float3)(0.0f))) return 0;
    if (!bvh_cl_tri_box_reached(r, tri, tt)) return 0;
    *t = tt;
    *u = V * rcp;
    *v = W * rcp;
    return 1;
}
#endif

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
    { /* as bvh__slab: lower the entry by 2^-18 of the box's distances along the dominant axis */
        float k0 = fabs(r->kz == 0 ? a0.x : r->kz == 1 ? a0.y : a0.z);
        float k1 = fabs(r->kz == 0 ? a1.x : r->kz == 1 ? a1.y : a1.z);
        tn -= (k0 > k1 ? k0 : k1) * 0x1p-18f;
    }
    tf = tf < tfar ? tf : tfar;
    return tn <= tf ? tn : INFINITY;
}

typedef struct bvh_cl_hitrec {
    float t, u, v;
    uint prim;    /* BVH_CL_INVALID: miss */
    uint ref;     /* reference of the hit (index into tris) */
    uint visited; /* nodes whose box was tested, counted as bvh_intersect_counted does */
} bvh_cl_hitrec;

typedef struct bvh_cl_scene {
    __global const uint4 *nodes;
    __global const float *tris;
    __global const uint *prims;
    uint node_count, ref_count;
} bvh_cl_scene;

/* Closest hit (any = 0) or first hit found (any = 1) of a set-up ray in [tmin, tmax]. A child
   index or leaf range outside the arrays (a corrupt tree) ends the traversal, so that no read
   ever leaves the buffers; a tree deeper than the stack does too, as on the CPU. */
BVH_CL_FN void bvh_cl_traverse(const bvh_cl_scene *s, const bvh_cl_rayx *rx, float tmax, int any, bvh_cl_hitrec *res) {
    uint stack[BVH_CL_STACK];
    float stack_t[BVH_CL_STACK]; /* entry distance of each pushed node */
    uint sp = 0, nvis = 1;
    float best_t = tmax;
    uint4 lo = s->nodes[0], hi = s->nodes[1]; /* the current node */
    int done = bvh_cl_slab(rx, as_float4(lo), as_float4(hi), best_t) == INFINITY;
    res->prim = BVH_CL_INVALID;
    res->ref = 0;
    res->u = res->v = 0.0f;
    while (!done) {
        int descended = 0;
        if (hi.w) {
            uint k, end = lo.w + hi.w;
            if (end > s->ref_count || end < lo.w) break;
            for (k = lo.w; k < end; k++) {
                float t, u, v;
                uint prim;
                if (!bvh_cl_tri_test(rx, s->tris + 9 * (size_t)k, best_t, &t, &u, &v)) continue;
                prim = s->prims[k];
                if (t == best_t && prim > res->prim) continue; /* ties: lowest index */
                best_t = t; res->u = u; res->v = v; res->prim = prim; res->ref = k;
                if (any) { done = 1; break; }
            }
        } else {
            uint c = lo.w;
            uint4 lo0, hi0, lo1, hi1;
            float t0, t1;
            if (c >= s->node_count - 1) break;
            lo0 = s->nodes[2 * c]; hi0 = s->nodes[2 * c + 1];
            lo1 = s->nodes[2 * c + 2]; hi1 = s->nodes[2 * c + 3];
            t0 = bvh_cl_slab(rx, as_float4(lo0), as_float4(hi0), best_t);
            t1 = bvh_cl_slab(rx, as_float4(lo1), as_float4(hi1), best_t);
            nvis += 2;
            if (t0 != INFINITY || t1 != INFINITY) {
                uint far = c + 1;
                if (t1 < t0) { float tt = t0; t0 = t1; t1 = tt; lo = lo1; hi = hi1; far = c; }
                else { lo = lo0; hi = hi0; }
                if (t1 != INFINITY) {
                    if (sp == BVH_CL_STACK) break; /* a tree deeper than the validator allows */
                    stack_t[sp] = t1;
                    stack[sp++] = far;
                }
                descended = 1;
            }
        }
        if (!descended && !done) {
            for (;;) { /* pop the next node still in reach of the current best */
                if (!sp) { done = 1; break; }
                --sp;
                if (stack_t[sp] <= best_t) { lo = s->nodes[2 * stack[sp]]; hi = s->nodes[2 * stack[sp] + 1]; break; }
            }
        }
    }
    res->t = best_t;
    res->visited = nvis;
}

/* Traces one ray; a miss leaves t = tmax, u = v = 0, prim = BVH_CL_INVALID, like bvh_intersect. */
BVH_CL_FN void bvh_cl_trace(const bvh_cl_scene *s, float3 o, float tmin, float3 d, float tmax, int any,
                            bvh_cl_hitrec *res) {
    bvh_cl_rayx rx;
    res->t = tmax; res->u = res->v = 0.0f; res->prim = BVH_CL_INVALID; res->ref = 0; res->visited = 0;
    if (!s->node_count || !bvh_cl_ray_setup(o, tmin, d, tmax, &rx)) return;
    bvh_cl_traverse(s, &rx, tmax, any, res);
    if (res->prim == BVH_CL_INVALID) { res->t = tmax; res->u = res->v = 0.0f; }
}

/* ============================================================================================ */
/* == kernels =================================================================================== */
/* ============================================================================================ */
/* Closest hit of rays[0 .. count) into hits (bvh_intersect_batch). */
__kernel void bvh_intersect_kernel(__global const uint4 *nodes, uint node_count, __global const float *tris,
                               __global const uint *prims, uint ref_count, __global const float *rays,
                               __global uint4 *hits, uint count) {
    uint i = (uint)get_global_id(0);
    bvh_cl_scene s;
    bvh_cl_hitrec res;
    float4 r0, r1;
    if (i >= count) return;
    s.nodes = nodes; s.tris = tris; s.prims = prims; s.node_count = node_count; s.ref_count = ref_count;
    r0 = vload4(2 * (size_t)i, rays);
    r1 = vload4(2 * (size_t)i + 1, rays);
    bvh_cl_trace(&s, r0.xyz, r0.w, r1.xyz, r1.w, 0, &res);
    hits[i] = (uint4)(as_uint(res.t), as_uint(res.u), as_uint(res.v), res.prim);
}

/* Any hit of rays[0 .. count): occluded[i] = 1 if blocked (bvh_occluded_batch). */
__kernel void bvh_occluded_kernel(__global const uint4 *nodes, uint node_count, __global const float *tris,
                              __global const uint *prims, uint ref_count, __global const float *rays,
                              __global uchar *occluded, uint count) {
    uint i = (uint)get_global_id(0);
    bvh_cl_scene s;
    bvh_cl_hitrec res;
    float4 r0, r1;
    if (i >= count) return;
    s.nodes = nodes; s.tris = tris; s.prims = prims; s.node_count = node_count; s.ref_count = ref_count;
    r0 = vload4(2 * (size_t)i, rays);
    r1 = vload4(2 * (size_t)i + 1, rays);
    bvh_cl_trace(&s, r0.xyz, r0.w, r1.xyz, r1.w, 1, &res);
    occluded[i] = res.prim != BVH_CL_INVALID ? (uchar)1 : (uchar)0;
}

/* Rows y0 .. y0 + rows - 1 of a frame seen by a bvh_camera packed as cam.s0-2 eye, s3-5 forward,
   s6-8 right, s9-b up. Ray of pixel (x, y), y = 0 at the top, exactly as bvh_camera_ray:
   d = normalize(forward + sx*right + sy*up), sx = 2(x+0.5)/w - 1, sy = 1 - 2(y+0.5)/h.
   Outputs (each may be NULL), indexed from the first row of the band: rgba (4 bytes per pixel):
   hits shaded with a headlight, grey * (0.2 + 0.8 |dot(n, d)|), misses a vertical gradient;
   hits (bvh_hit); visited (nodes visited, as bvh_intersect_counted). */
__kernel void bvh_frame_kernel(__global const uint4 *nodes, uint node_count, __global const float *tris,
                           __global const uint *prims, uint ref_count, float16 cam, uint width, uint height,
                           uint y0, uint rows, __global uchar *rgba, __global uint4 *hits,
                           __global uint *visited) {
    uint x = (uint)get_global_id(0), row = (uint)get_global_id(1), y = y0 + row;
    size_t pix = (size_t)row * width + x;
    bvh_cl_scene s;
    bvh_cl_hitrec res;
    float sx, sy, l;
    float3 d, c;
    if (x >= width || row >= rows) return;
    s.nodes = nodes; s.tris = tris; s.prims = prims; s.node_count = node_count; s.ref_count = ref_count;
    sx = 2.0f * ((float)x + 0.5f) / (float)width - 1.0f;
    sy = 1.0f - 2.0f * ((float)y + 0.5f) / (float)height;
    d.x = cam.s3 + sx * cam.s6 + sy * cam.s9;
    d.y = cam.s4 + sx * cam.s7 + sy * cam.sa;
    d.z = cam.s5 + sx * cam.s8 + sy * cam.sb;
    l = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
    if (l > 0.0f) { d.x = d.x / l; d.y = d.y / l; d.z = d.z / l; }
    bvh_cl_trace(&s, cam.s012, 0.0f, d, INFINITY, 0, &res);
    if (hits) hits[pix] = (uint4)(as_uint(res.t), as_uint(res.u), as_uint(res.v), res.prim);
    if (visited) visited[pix] = res.visited;
    if (!rgba) return;
    if (res.prim != BVH_CL_INVALID) {
        __global const float *t = tris + 9 * (size_t)res.ref;
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
    vstore4((uchar4)((uchar)c.x, (uchar)c.y, (uchar)c.z, (uchar)255), pix, rgba);
}
