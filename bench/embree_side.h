/* embree_side.h - Embree 3 figures beside bvh.h's, for the benchmark (bench/bvhbench.c) and
   bench/embree_compare.c (C11)

   WHAT
     Measures Embree 3 on a triangle soup, with the same rays and the same SAH costs as bvh.h:
       emb_scene_bench  Embree's scene API (what a renderer uses): build time at a build quality
                        on N threads (rtcNewScene .. rtcCommitScene, and rtcCommitScene alone;
                        median/min/max of R builds after one warm-up), then W x H frames of
                        the project's standard camera (median time of trace_repeat frames) (bvh_camera_standard over the
   scene bounds, bvh_camera_ray per pixel centre: bit-identical rays to bvh.h's) traced with rtcIntersect1 on 1 thread
   and on T pthreads (rows interleaved): hits, t_sum, Mrays/s. emb_builder_*    one timed scene build at a time on a
   device kept open, so that a benchmark can interleave Embree's builds with its own (paired rounds on a shared machine:
   both see the same moments of noise); a scene kept open traces frames (emb_builder_trace) or any ray array
                        (emb_builder_rays: rtcIntersect1, or rtcOccluded1 for shadow rays).
       emb_bvh_sah      Embree's BVH builder API (rtcBuildBVH) making a binary tree of our own
                        nodes over the triangle boxes, with maxBranchingFactor 2, maxDepth 64,
                        sahBlockSize 1, minLeafSize 1, maxLeafSize 8 (a parameter), traversal
                        and intersection cost 1; returns its SAH with costs (Ci, Cl, Ct) =
                        (1, 0, 1), exactly as bvh_sah() computes it, node/leaf counts and the
                        time of rtcBuildBVH. The scene API's own BVH4/BVH8 is not reachable
                        through the API: this is the closest like-for-like tree Embree builds.

   HOW TO INCLUDE
     In exactly ONE .c file (which also has, or links, bvh.h's implementation for the camera, and
     examples/scene.h's for the clock, the median and the CPU count):
         #define BVH_IMPLEMENTATION
         #include "bvh.h"
         #define SCENE_IMPLEMENTATION
         #include "examples/scene.h"
         #define EMB_IMPLEMENTATION
         #include "embree_side.h"
     Compile with -I. (the repository root) and with -DBVH_HAVE_EMBREE, and link -lembree3
     -lpthread for real figures (the Makefile does all three when <embree3/rtcore.h> exists).
     Without BVH_HAVE_EMBREE the header still compiles and every call returns EMB_ERR_UNAVAILABLE
     with the message "Embree not installed".

   ERRORS
     Every call returns an emb_status (EMB_OK = 0) and writes a one-line reason into the result's
     message ("ok" on success). Embree errors are caught with rtcSetDeviceErrorFunction and
     rtcGetDeviceError. Nothing here prints, aborts or exits.

   NOTES ON WHAT IS MEASURED
     - Scene flags: none by default (Embree's own default, what a renderer gets unless it opts
       in), or RTC_SCENE_FLAG_ROBUST (emb_scene_desc.robust, emb_builder_open's robust), the
       closest Embree comes to a watertight test, which traces slower (figures: docs/bench/).
     - Build time includes, like shared/tools/embree_ref.c, the geometry set-up: the copy of the
       vertices into Embree's buffer and the trivial index buffer 0,1,2,3...; commit time is the
       BVH build proper.
     - Rays are made before the clock starts (the timed loop is RTCRayHit set-up + rtcIntersect1
       + storing t and the primitive per pixel), like a batch of precomputed rays in bvh.h.
     - t_sum is summed in pixel order from the per-pixel t, so it does not depend on the number
       of threads; the multi-threaded frame is compared pixel by pixel with the 1-thread frame.
     - RTC_BUILD_QUALITY_LOW in rtcBuildBVH is Embree's Morton builder; with minLeafSize 1 it
       makes one-triangle leaves (it has no SAH leaf collapse). MEDIUM is the binned SAH builder.
       HIGH is the binned SAH builder with spatial splits (SBVH) only when a splitPrimitive
       callback and spare room in the primitive array are given: this file gives an exact
       triangle clipper and room for split_factor x n references (default 1.2, Embree's own
       default replication budget for scenes); split_factor < 0 gives HIGH without splits,
       which in Embree 3.13 is the same builder as MEDIUM.
*/
#ifndef EMB_SIDE_H_INCLUDED
#define EMB_SIDE_H_INCLUDED

#include <stddef.h>
#include <stdint.h>
#include "bvh.h"

#ifndef EMB_API
#define EMB_API extern
#endif

#ifdef __cplusplus
extern "C" {
#endif

typedef enum emb_status {
    EMB_OK = 0,
    EMB_ERR_UNAVAILABLE, /* compiled without BVH_HAVE_EMBREE */
    EMB_ERR_ARGUMENT,    /* NULL pointer, option out of range, too many triangles */
    EMB_ERR_MEMORY,      /* an allocation failed */
    EMB_ERR_THREAD,      /* a tracing thread could not be created */
    EMB_ERR_EMBREE,      /* Embree reported an error (see message) */
    EMB_STATUS_COUNT
} emb_status;

typedef enum emb_quality {
    EMB_QUALITY_DEFAULT = 0, /* = MEDIUM */
    EMB_QUALITY_LOW,         /* RTC_BUILD_QUALITY_LOW */
    EMB_QUALITY_MEDIUM,      /* RTC_BUILD_QUALITY_MEDIUM */
    EMB_QUALITY_HIGH,        /* RTC_BUILD_QUALITY_HIGH */
    EMB_QUALITY_COUNT
} emb_quality;

typedef struct emb_timing {
    double ms, min_ms, max_ms;
} emb_timing; /* ms = median */

typedef struct emb_scene_desc {
    emb_quality quality;      /* DEFAULT = MEDIUM */
    uint32_t threads;         /* Embree device "threads=N" for the build; 0 = all hardware threads */
    uint32_t repeat;          /* timed builds after one warm-up; 0 = 5; at most 100000 */
    uint32_t width, height;   /* the frame; 0 (either) = build only */
    uint32_t trace_threads;   /* pthreads for the multi-threaded frame; 0 = online CPUs */
    uint32_t trace_repeat;    /* frames traced per thread count, the median time reported; 0 = 1 */
    int robust;               /* 1: RTC_SCENE_FLAG_ROBUST (watertight-ish hits); 0: no scene flags,
                                 Embree's default (as embree_ref without EMBREE_REF_ROBUST) */
    const bvh_aabb *bounds;   /* camera bounds; NULL = bounds of the finite vertices (= the root
                                 box of a bvh.h tree over the same triangles) */
    const bvh_camera *camera; /* the frame's camera; NULL = bvh_camera_standard over the bounds */
    float *t_out;             /* optional, width*height: hit t per pixel (y = 0 at the top), +inf
                                 for a miss, from the 1-thread frame */
    uint32_t *prim_out;       /* optional, width*height: triangle index, BVH_INVALID for a miss */
} emb_scene_desc;

typedef struct emb_scene_result {
    emb_timing build;  /* rtcNewScene .. rtcCommitScene */
    emb_timing commit; /* rtcCommitScene alone */
    uint32_t threads;  /* build threads asked (0 = all) */
    uint32_t repeat;
    uint64_t rays, hits;    /* the frame */
    double t_sum;           /* sum of hit t over the frame, in pixel order */
    double trace_ms, mrays; /* 1 thread */
    uint32_t trace_threads; /* threads of the multi-threaded frame */
    double trace_ms_mt, mrays_mt;
    int mt_identical; /* 1: the multi-threaded frame gave the same t and triangle per
                         pixel as the 1-thread frame (also 1 when there is no frame) */
    char message[160];
} emb_scene_result;

typedef struct emb_sah_desc {
    emb_quality quality; /* DEFAULT = MEDIUM */
    uint32_t threads;    /* Embree device "threads=N"; 0 = all hardware threads */
    uint32_t repeat;     /* timed builds after one warm-up; 0 = 5; at most 100000 */
    uint32_t max_leaf;   /* maxLeafSize; 0 = 8; 1..32 (RTC_BUILD_MAX_PRIMITIVES_PER_LEAF) */
    float split_factor;  /* HIGH only: room for split_factor * n references for spatial
                            splits; 0 = 1.2; < 0 or <= 1: no spatial splits */
} emb_sah_desc;

typedef struct emb_sah_result {
    double sah;             /* (sum_interior A + sum_leaves A * N) / A(root) */
    uint32_t nodes, leaves; /* nodes counts interior nodes and leaves */
    uint32_t refs;          /* sum of leaf sizes (> triangles with spatial splits) */
    uint32_t max_depth;     /* root = 1 */
    uint32_t max_leaf_size;
    int spatial_splits; /* 1 when rtcBuildBVH was given a splitter and room (HIGH) */
    emb_timing build;   /* rtcBuildBVH alone */
    uint32_t threads, repeat;
    char message[160];
} emb_sah_result;

EMB_API int emb_available(void);       /* 1 when compiled with BVH_HAVE_EMBREE */
EMB_API const char *emb_version(void); /* "3.13.5", or "none" */
EMB_API const char *emb_status_string(int status);
EMB_API const char *emb_quality_name(emb_quality q);                   /* "low", "medium"... */
EMB_API int emb_quality_from_name(const char *name, emb_quality *out); /* 0 ok, -1 unknown */

/* v: 9 floats (x0 y0 z0 x1 ... z2) per triangle, n triangles; desc NULL = all defaults. */
EMB_API int emb_scene_bench(const float *v, uint32_t n, const emb_scene_desc *desc, emb_scene_result *out);
EMB_API int emb_bvh_sah(const float *v, uint32_t n, const emb_sah_desc *desc, emb_sah_result *out);

/* A device for single timed scene builds (as emb_scene_bench's): open once, then
   emb_builder_time builds, times and releases one scene per call (*ms as emb_scene_bench's build
   time). Every scene it builds (emb_builder_time, emb_builder_keep) has RTC_SCENE_FLAG_ROBUST when
   robust is 1, no scene flags (Embree's default) when it is 0, as emb_scene_desc.robust.
   message: at least 160 bytes, or NULL. */
typedef struct emb_builder emb_builder;
EMB_API int emb_builder_open(emb_builder **out, emb_quality quality, uint32_t threads, int robust, char *message);
EMB_API int emb_builder_time(emb_builder *b, const float *v, uint32_t n, double *ms);
/* Builds a scene (untimed) and keeps it for emb_builder_trace, which traces one w x h frame of
   rays on it with rtcIntersect1 on `threads` threads, as emb_scene_bench's frames (*ms). */
EMB_API int emb_builder_keep(emb_builder *b, const float *v, uint32_t n);
EMB_API int emb_builder_trace(emb_builder *b, const bvh_ray *rays, uint32_t w, uint32_t h, uint32_t threads,
                              double *ms);
/* Traces n rays of any kind (examples/rays.h's diffuse or shadow sets) on the kept scene, in
   chunks of 64 rays interleaved over `threads` threads: rtcIntersect1 into t (+inf: a miss) and
   prim (BVH_INVALID: a miss), or, when occluded is not NULL, rtcOccluded1 into occluded[i]
   (1: blocked; t and prim may be NULL). The rays go to Embree as they are: tnear = tmin, tfar =
   tmax. *ms: the wall time. */
EMB_API int emb_builder_rays(emb_builder *b, const bvh_ray *rays, size_t n, uint32_t threads, float *t, uint32_t *prim,
                             uint8_t *occluded, double *ms);
/* Embree's own refit, for bvh_refit's figures (bvhbench --refit): emb_builder_refit_keep builds
   (untimed) the one scene layout in which Embree 3 refits a mesh, a two-level scene
   (RTC_BUILD_QUALITY_LOW, RTC_SCENE_FLAG_DYNAMIC: without the flag each commit rebuilds the
   mesh) over a geometry of RTC_BUILD_QUALITY_REFIT (the builder's own quality does not apply); emb_builder_refit copies
   n moved triangles (the same n, untimed: an application sharing its buffer with Embree has no copy) into the vertex
   buffer and times rtcUpdateGeometryBuffer, rtcCommitGeometry and rtcCommitScene (*ms). */
EMB_API int emb_builder_refit_keep(emb_builder *b, const float *v, uint32_t n);
EMB_API int emb_builder_refit(emb_builder *b, const float *v, uint32_t n, double *ms);
EMB_API void emb_builder_close(emb_builder *b);

#ifdef __cplusplus
}
#endif
#endif /* EMB_SIDE_H_INCLUDED */

/* ============================================================================================ */
/*                                      IMPLEMENTATION                                          */
/* ============================================================================================ */
#ifdef EMB_IMPLEMENTATION
#ifndef EMB_IMPLEMENTATION_DONE
#define EMB_IMPLEMENTATION_DONE

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* every message buffer of this file is char[160] */
static void emb__msg(char *buf, const char *text) { snprintf(buf, 160, "%s", text); }

EMB_API const char *emb_status_string(int s) {
    static const char *names[EMB_STATUS_COUNT] = {
        "ok", "Embree not installed", "invalid argument", "out of memory", "thread creation failed", "Embree error"};
    return s >= 0 && s < EMB_STATUS_COUNT ? names[s] : "unknown status";
}
EMB_API const char *emb_quality_name(emb_quality q) {
    switch (q) {
    case EMB_QUALITY_LOW:
        return "low";
    case EMB_QUALITY_DEFAULT:
    case EMB_QUALITY_MEDIUM:
        return "medium";
    case EMB_QUALITY_HIGH:
        return "high";
    default:
        return "invalid";
    }
}
EMB_API int emb_quality_from_name(const char *s, emb_quality *out) {
    emb_quality q;
    if (!s || !out) return -1;
    if (!strcmp(s, "low"))
        q = EMB_QUALITY_LOW;
    else if (!strcmp(s, "medium"))
        q = EMB_QUALITY_MEDIUM;
    else if (!strcmp(s, "high"))
        q = EMB_QUALITY_HIGH;
    else
        return -1;
    *out = q;
    return 0;
}

#ifndef BVH_HAVE_EMBREE
/* ---- stubs: Embree not compiled in --------------------------------------------------------- */
EMB_API int emb_available(void) { return 0; }
EMB_API const char *emb_version(void) { return "none"; }
/* The stubs' answer: a result of `size` bytes zeroed, with the reason in its message. */
static int emb__unavailable(void *result, size_t size, char *message) {
    if (result) {
        memset(result, 0, size);
        emb__msg(message, "Embree not installed");
    }
    return EMB_ERR_UNAVAILABLE;
}
EMB_API int emb_scene_bench(const float *v, uint32_t n, const emb_scene_desc *d, emb_scene_result *o) {
    (void)v;
    (void)n;
    (void)d;
    return emb__unavailable(o, sizeof *o, o ? o->message : NULL);
}
EMB_API int emb_bvh_sah(const float *v, uint32_t n, const emb_sah_desc *d, emb_sah_result *o) {
    (void)v;
    (void)n;
    (void)d;
    return emb__unavailable(o, sizeof *o, o ? o->message : NULL);
}
EMB_API int emb_builder_open(emb_builder **out, emb_quality quality, uint32_t threads, int robust, char *message) {
    (void)quality;
    (void)threads;
    (void)robust;
    if (out) *out = NULL;
    if (message) emb__msg(message, "Embree not installed");
    return EMB_ERR_UNAVAILABLE;
}
EMB_API int emb_builder_time(emb_builder *b, const float *v, uint32_t n, double *ms) {
    (void)b;
    (void)v;
    (void)n;
    if (ms) *ms = 0.0;
    return EMB_ERR_UNAVAILABLE;
}
EMB_API int emb_builder_keep(emb_builder *b, const float *v, uint32_t n) {
    (void)b;
    (void)v;
    (void)n;
    return EMB_ERR_UNAVAILABLE;
}
EMB_API int emb_builder_trace(emb_builder *b, const bvh_ray *rays, uint32_t w, uint32_t h, uint32_t threads,
                              double *ms) {
    (void)b;
    (void)rays;
    (void)w;
    (void)h;
    (void)threads;
    if (ms) *ms = 0.0;
    return EMB_ERR_UNAVAILABLE;
}
EMB_API int emb_builder_rays(emb_builder *b, const bvh_ray *rays, size_t n, uint32_t threads, float *t, uint32_t *prim,
                             uint8_t *occluded, double *ms) {
    (void)b;
    (void)rays;
    (void)n;
    (void)threads;
    (void)t;
    (void)prim;
    (void)occluded;
    if (ms) *ms = 0.0;
    return EMB_ERR_UNAVAILABLE;
}
EMB_API int emb_builder_refit_keep(emb_builder *b, const float *v, uint32_t n) {
    (void)b;
    (void)v;
    (void)n;
    return EMB_ERR_UNAVAILABLE;
}
EMB_API int emb_builder_refit(emb_builder *b, const float *v, uint32_t n, double *ms) {
    (void)b;
    (void)v;
    (void)n;
    if (ms) *ms = 0.0;
    return EMB_ERR_UNAVAILABLE;
}
EMB_API void emb_builder_close(emb_builder *b) { (void)b; }
#else
/* The start of an entry: the result zeroed, its message "ok", the description copied (NULL: all
   zero, the defaults). */
static void emb__start(void *out, size_t out_size, char *message, void *d, const void *desc, size_t d_size) {
    memset(out, 0, out_size);
    emb__msg(message, "ok");
    memset(d, 0, d_size);
    if (desc) memcpy(d, desc, d_size);
}
/* ---- Embree ------------------------------------------------------------------------------- */
#include <embree3/rtcore.h>
#include <pthread.h>

#include "examples/scene.h"

#define EMB__MAX_TRIANGLES (UINT32_MAX / 3u) /* the index buffer is 3n unsigned ints */
#define EMB__RAYS_CHUNK 64                   /* emb_builder_rays: rays per chunk, chunks interleaved over the threads */

EMB_API int emb_available(void) { return 1; }
EMB_API const char *emb_version(void) { return RTC_VERSION_STRING; }

/* sorts ms[0..n) and fills median (mean of the two middle ones for even n), min, max */
static emb_timing emb__timing(double *ms, uint32_t n) {
    emb_timing t;
    t.ms = scene_median(ms, n);
    t.min_ms = ms[0];
    t.max_ms = ms[n - 1];
    return t;
}
static enum RTCBuildQuality emb__rtc_quality(emb_quality q) {
    return q == EMB_QUALITY_LOW    ? RTC_BUILD_QUALITY_LOW
           : q == EMB_QUALITY_HIGH ? RTC_BUILD_QUALITY_HIGH
                                   : RTC_BUILD_QUALITY_MEDIUM;
}

/* Device errors land in the caller's message buffer (first error wins) and a flag. */
/* The callback may run on Embree's worker threads, hence the lock. */
typedef struct emb__err {
    char *message;
    int failed;
    pthread_mutex_t lock;
} emb__err;
static void emb__on_error(void *user, enum RTCError code, const char *str) {
    emb__err *e = (emb__err *)user;
    pthread_mutex_lock(&e->lock);
    if (!e->failed) {
        char tmp[120];
        snprintf(tmp, sizeof tmp, "Embree error %d: %s", (int)code, str ? str : "");
        emb__msg(e->message, tmp);
    }
    e->failed = 1;
    pthread_mutex_unlock(&e->lock);
}
static RTCDevice emb__device(uint32_t threads, emb__err *err) {
    char cfg[48];
    RTCDevice dev;
    snprintf(cfg, sizeof cfg, "threads=%u", threads);
    dev = rtcNewDevice(threads ? cfg : NULL);
    if (!dev) {
        char tmp[64];
        snprintf(tmp, sizeof tmp, "rtcNewDevice failed (error %d)", (int)rtcGetDeviceError(NULL));
        emb__msg(err->message, tmp);
        err->failed = 1;
        return NULL;
    }
    rtcSetDeviceErrorFunction(dev, emb__on_error, err);
    return dev;
}
/* 1 when the device has an error pending or the callback saw one */
static int emb__check(RTCDevice dev, emb__err *err, const char *where) {
    enum RTCError code = rtcGetDeviceError(dev);
    int failed;
    pthread_mutex_lock(&err->lock);
    if (code != RTC_ERROR_NONE && !err->failed) {
        char tmp[120];
        snprintf(tmp, sizeof tmp, "%s: Embree error %d", where, (int)code);
        emb__msg(err->message, tmp);
        err->failed = 1;
    }
    failed = err->failed;
    pthread_mutex_unlock(&err->lock);
    return failed;
}

static bvh_aabb emb__bounds(const float *v, uint32_t n) {
    bvh_aabb b = bvh_aabb_empty();
    size_t i;
    for (i = 0; i < (size_t)n * 3; i++) {
        const float *p = v + i * 3;
        if (isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2])) {
            bvh_vec3 q;
            q.x = p[0];
            q.y = p[1];
            q.z = p[2];
            bvh_aabb_grow(&b, q);
        }
    }
    return b;
}

/* ---- scene API: build ---------------------------------------------------------------------- */
/* One build as embree_ref.c times it: scene, geometry, buffers, copy, commit; the scene at
   quality bq with flags, its geometry at gq (they differ only for a refit: see
   emb_builder_refit_keep); *vb_out (not NULL): the vertex buffer. */
static RTCScene emb__build_scene2(RTCDevice dev, const float *v, uint32_t n, enum RTCBuildQuality bq,
                                  enum RTCBuildQuality gq, enum RTCSceneFlags flags, double *total_ms,
                                  double *commit_ms, float **vb_out) {
    double t0 = scene_now_ms(), t1;
    RTCScene scene = rtcNewScene(dev);
    if (!scene) return NULL;
    rtcSetSceneBuildQuality(scene, bq);
    if (flags != RTC_SCENE_FLAG_NONE) rtcSetSceneFlags(scene, flags);
    if (n) {
        RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
        float *vb;
        unsigned *ib;
        uint32_t i;
        if (!g) {
            rtcReleaseScene(scene);
            return NULL;
        }
        rtcSetGeometryBuildQuality(g, gq);
        vb = (float *)rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                              (size_t)n * 3);
        ib =
            (unsigned *)rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), n);
        if (!vb || !ib) {
            rtcReleaseGeometry(g);
            rtcReleaseScene(scene);
            return NULL;
        }
        memcpy(vb, v, (size_t)n * 9 * sizeof(float));
        for (i = 0; i < n * 3; i++) ib[i] = i;
        rtcCommitGeometry(g);
        rtcAttachGeometry(scene, g);
        rtcReleaseGeometry(g);
        if (vb_out) *vb_out = vb;
    }
    t1 = scene_now_ms();
    rtcCommitScene(scene);
    *commit_ms = scene_now_ms() - t1;
    *total_ms = scene_now_ms() - t0;
    return scene;
}
static RTCScene emb__build_scene(RTCDevice dev, const float *v, uint32_t n, enum RTCBuildQuality bq, int robust,
                                 double *total_ms, double *commit_ms) {
    return emb__build_scene2(dev, v, n, bq, bq, robust ? RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_NONE, total_ms,
                             commit_ms, NULL);
}

/* ---- scene API: trace ---------------------------------------------------------------------- */
typedef struct emb__trace_job {
    RTCScene scene;
    const bvh_ray *rays;
    size_t count, chunk; /* rays, and rays per chunk (a frame: its width, a chunk a row) */
    size_t first, step;  /* this thread's chunks: first, first + step, ... */
    float *t;
    uint32_t *prim;
    uint8_t *occluded; /* not NULL: rtcOccluded1 into it (1 blocked), t and prim unused */
} emb__trace_job;

static void emb__occluded_chunk(const emb__trace_job *j, struct RTCIntersectContext *ctx, size_t lo, size_t hi) {
    size_t i;
    for (i = lo; i < hi; i++) {
        const bvh_ray *r = &j->rays[i];
        struct RTCRay ray;
        ray.org_x = r->origin.x;
        ray.org_y = r->origin.y;
        ray.org_z = r->origin.z;
        ray.tnear = r->tmin;
        ray.dir_x = r->dir.x;
        ray.dir_y = r->dir.y;
        ray.dir_z = r->dir.z;
        ray.time = 0.0f;
        ray.tfar = r->tmax;
        ray.mask = 0xFFFFFFFFu;
        ray.id = 0;
        ray.flags = 0;
        rtcOccluded1(j->scene, ctx, &ray);
        j->occluded[i] = ray.tfar < 0.0f; /* Embree sets tfar to -inf for a blocked ray */
    }
}

static void *emb__trace_rows(void *arg) {
    const emb__trace_job *j = (const emb__trace_job *)arg;
    struct RTCIntersectContext ctx;
    size_t c;
    rtcInitIntersectContext(&ctx);
    for (c = j->first; c * j->chunk < j->count; c += j->step) {
        size_t i, lo = c * j->chunk, hi = lo + j->chunk < j->count ? lo + j->chunk : j->count;
        if (j->occluded) {
            emb__occluded_chunk(j, &ctx, lo, hi);
            continue;
        }
        for (i = lo; i < hi; i++) {
            const bvh_ray *r = &j->rays[i];
            struct RTCRayHit rh;
            rh.ray.org_x = r->origin.x;
            rh.ray.org_y = r->origin.y;
            rh.ray.org_z = r->origin.z;
            rh.ray.tnear = r->tmin;
            rh.ray.dir_x = r->dir.x;
            rh.ray.dir_y = r->dir.y;
            rh.ray.dir_z = r->dir.z;
            rh.ray.time = 0.0f;
            rh.ray.tfar = r->tmax;
            rh.ray.mask = 0xFFFFFFFFu;
            rh.ray.id = 0;
            rh.ray.flags = 0;
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
            rtcIntersect1(j->scene, &ctx, &rh);
            if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) {
                j->t[i] = rh.ray.tfar;
                j->prim[i] = rh.hit.primID;
            } else {
                j->t[i] = HUGE_VALF;
                j->prim[i] = BVH_INVALID;
            }
        }
    }
    return NULL;
}

/* Traces `count` rays in chunks of `chunk` (a frame: its rows), the chunks interleaved over
   `threads` threads (1: on the calling thread); rtcOccluded1 into occluded when it is not NULL,
   else rtcIntersect1 into t and prim. Returns EMB_OK or EMB_ERR_THREAD / EMB_ERR_MEMORY; *ms is
   the wall time from the first thread start to the last join. */
static int emb__trace(RTCScene scene, const bvh_ray *rays, size_t count, size_t chunk, uint32_t threads, float *t,
                      uint32_t *prim, uint8_t *occluded, double *ms);
/* d->trace_repeat frames (at most 15); *ms = the median time */
static int emb__trace_median(RTCScene scene, const bvh_ray *rays, const emb_scene_desc *d, uint32_t threads, float *t,
                             uint32_t *prim, double *ms) {
    double v[15];
    uint32_t n = d->trace_repeat ? d->trace_repeat : 1, i, j;
    if (n > 15) n = 15;
    for (i = 0; i < n; i++) {
        int st = emb__trace(scene, rays, (size_t)d->width * d->height, d->width, threads, t, prim, NULL, &v[i]);
        if (st != EMB_OK) return st;
        for (j = i; j > 0 && v[j - 1] > v[j]; j--) {
            double x = v[j];
            v[j] = v[j - 1];
            v[j - 1] = x;
        }
    }
    *ms = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
    return EMB_OK;
}
static int emb__trace(RTCScene scene, const bvh_ray *rays, size_t count, size_t chunk, uint32_t threads, float *t,
                      uint32_t *prim, uint8_t *occluded, double *ms) {
    double t0;
    if (threads <= 1) {
        emb__trace_job j;
        j.scene = scene;
        j.rays = rays;
        j.count = count;
        j.chunk = chunk;
        j.first = 0;
        j.step = 1;
        j.t = t;
        j.prim = prim;
        j.occluded = occluded;
        t0 = scene_now_ms();
        emb__trace_rows(&j);
        *ms = scene_now_ms() - t0;
        return EMB_OK;
    } else {
        emb__trace_job *jobs = (emb__trace_job *)malloc(threads * sizeof *jobs);
        pthread_t *tid = (pthread_t *)malloc(threads * sizeof *tid);
        uint32_t k, started = 0;
        int st = EMB_OK;
        if (!jobs || !tid) {
            free(jobs);
            free(tid);
            return EMB_ERR_MEMORY;
        }
        for (k = 0; k < threads; k++) {
            jobs[k].scene = scene;
            jobs[k].rays = rays;
            jobs[k].count = count;
            jobs[k].chunk = chunk;
            jobs[k].first = k;
            jobs[k].step = threads;
            jobs[k].t = t;
            jobs[k].prim = prim;
            jobs[k].occluded = occluded;
        }
        t0 = scene_now_ms();
        for (k = 1; k < threads; k++) {
            if (pthread_create(&tid[k], NULL, emb__trace_rows, &jobs[k]) != 0) {
                st = EMB_ERR_THREAD;
                break;
            }
            started = k;
        }
        if (st == EMB_OK) emb__trace_rows(&jobs[0]); /* the calling thread takes rows 0, T, 2T... */
        for (k = 1; k <= started; k++) pthread_join(tid[k], NULL);
        *ms = scene_now_ms() - t0;
        free(jobs);
        free(tid);
        return st;
    }
}

/* ---- single timed builds (emb_builder) ---------------------------------------------------- */
struct emb_builder {
    RTCDevice dev;
    enum RTCBuildQuality bq;
    int robust; /* RTC_SCENE_FLAG_ROBUST on every scene */
    emb__err err;
    char message[160]; /* the last error */
    RTCScene kept;     /* emb_builder_keep's scene */
    RTCScene refit;    /* emb_builder_refit_keep's scene, its vertex buffer and triangle count */
    float *refit_vb;
    uint32_t refit_n;
    float *t; /* a frame's t and triangle per pixel */
    uint32_t *prim;
    size_t npix;
};
EMB_API int emb_builder_open(emb_builder **out, emb_quality quality, uint32_t threads, int robust, char *message) {
    emb_builder *b;
    if (!out) return EMB_ERR_ARGUMENT;
    *out = NULL;
    if ((int)quality < 0 || quality >= EMB_QUALITY_COUNT) return EMB_ERR_ARGUMENT;
    b = (emb_builder *)calloc(1, sizeof *b);
    if (!b) {
        if (message) emb__msg(message, "out of memory");
        return EMB_ERR_MEMORY;
    }
    b->err.message = b->message;
    b->err.failed = 0;
    pthread_mutex_init(&b->err.lock, NULL);
    b->bq = emb__rtc_quality(quality);
    b->robust = robust != 0;
    b->dev = emb__device(threads, &b->err);
    if (!b->dev) {
        if (message) emb__msg(message, b->message);
        pthread_mutex_destroy(&b->err.lock);
        free(b);
        return EMB_ERR_EMBREE;
    }
    if (message) emb__msg(message, "ok");
    *out = b;
    return EMB_OK;
}
EMB_API int emb_builder_time(emb_builder *b, const float *v, uint32_t n, double *ms) {
    double total = 0.0, commit = 0.0;
    RTCScene scene;
    if (ms) *ms = 0.0;
    if (!b || !ms || (!v && n) || n > EMB__MAX_TRIANGLES) return EMB_ERR_ARGUMENT;
    b->err.failed = 0;
    scene = emb__build_scene(b->dev, v, n, b->bq, b->robust, &total, &commit);
    if (!scene || emb__check(b->dev, &b->err, "scene build")) {
        if (scene) rtcReleaseScene(scene);
        return EMB_ERR_EMBREE;
    }
    rtcReleaseScene(scene);
    *ms = total;
    return EMB_OK;
}
EMB_API int emb_builder_keep(emb_builder *b, const float *v, uint32_t n) {
    double total, commit;
    if (!b || (!v && n) || n > EMB__MAX_TRIANGLES) return EMB_ERR_ARGUMENT;
    if (b->kept) rtcReleaseScene(b->kept);
    b->err.failed = 0;
    b->kept = emb__build_scene(b->dev, v, n, b->bq, b->robust, &total, &commit);
    if (!b->kept || emb__check(b->dev, &b->err, "scene build")) {
        if (b->kept) rtcReleaseScene(b->kept);
        b->kept = NULL;
        return EMB_ERR_EMBREE;
    }
    return EMB_OK;
}
EMB_API int emb_builder_trace(emb_builder *b, const bvh_ray *rays, uint32_t w, uint32_t h, uint32_t threads,
                              double *ms) {
    size_t npix = (size_t)w * h;
    if (ms) *ms = 0.0;
    if (!b || !b->kept || !rays || !ms || !npix) return EMB_ERR_ARGUMENT;
    if (npix > b->npix) {
        free(b->t);
        free(b->prim);
        b->t = (float *)malloc(npix * sizeof *b->t);
        b->prim = (uint32_t *)malloc(npix * sizeof *b->prim);
        b->npix = b->t && b->prim ? npix : 0;
        if (!b->npix) return EMB_ERR_MEMORY;
    }
    return emb__trace(b->kept, rays, npix, w, threads, b->t, b->prim, NULL, ms);
}
EMB_API int emb_builder_rays(emb_builder *b, const bvh_ray *rays, size_t n, uint32_t threads, float *t, uint32_t *prim,
                             uint8_t *occluded, double *ms) {
    int st;
    if (ms) *ms = 0.0;
    if (!b || !b->kept || (!rays && n) || !ms || (!occluded && (!t || !prim))) return EMB_ERR_ARGUMENT;
    b->err.failed = 0;
    st = emb__trace(b->kept, rays, n, EMB__RAYS_CHUNK, threads, t, prim, occluded, ms);
    if (st == EMB_OK && emb__check(b->dev, &b->err, occluded ? "rtcOccluded1" : "rtcIntersect1")) st = EMB_ERR_EMBREE;
    return st;
}
EMB_API int emb_builder_refit_keep(emb_builder *b, const float *v, uint32_t n) {
    double total, commit;
    if (!b || !v || !n || n > EMB__MAX_TRIANGLES) return EMB_ERR_ARGUMENT;
    if (b->refit) rtcReleaseScene(b->refit);
    b->err.failed = 0;
    b->refit_vb = NULL;
    b->refit = emb__build_scene2(b->dev, v, n, RTC_BUILD_QUALITY_LOW, RTC_BUILD_QUALITY_REFIT,
                                 b->robust ? RTC_SCENE_FLAG_DYNAMIC | RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_DYNAMIC,
                                 &total, &commit, &b->refit_vb);
    if (!b->refit || !b->refit_vb || emb__check(b->dev, &b->err, "refit scene build")) {
        if (b->refit) rtcReleaseScene(b->refit);
        b->refit = NULL;
        return EMB_ERR_EMBREE;
    }
    b->refit_n = n;
    return EMB_OK;
}
EMB_API int emb_builder_refit(emb_builder *b, const float *v, uint32_t n, double *ms) {
    RTCGeometry g;
    double t0;
    if (ms) *ms = 0.0;
    if (!b || !b->refit || !v || !ms || n != b->refit_n) return EMB_ERR_ARGUMENT;
    b->err.failed = 0;
    memcpy(b->refit_vb, v, (size_t)n * 9 * sizeof(float));
    g = rtcGetGeometry(b->refit, 0);
    t0 = scene_now_ms();
    rtcUpdateGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0);
    rtcCommitGeometry(g);
    rtcCommitScene(b->refit);
    *ms = scene_now_ms() - t0;
    return emb__check(b->dev, &b->err, "refit") ? EMB_ERR_EMBREE : EMB_OK;
}
EMB_API void emb_builder_close(emb_builder *b) {
    if (!b) return;
    if (b->refit) rtcReleaseScene(b->refit);
    if (b->kept) rtcReleaseScene(b->kept);
    free(b->t);
    free(b->prim);
    rtcReleaseDevice(b->dev);
    pthread_mutex_destroy(&b->err.lock);
    free(b);
}

EMB_API int emb_scene_bench(const float *v, uint32_t n, const emb_scene_desc *desc, emb_scene_result *out) {
    emb_scene_desc d;
    emb__err err;
    RTCDevice dev = NULL;
    RTCScene scene = NULL;
    double *ms = NULL, *cms = NULL;
    bvh_ray *rays = NULL;
    float *t1 = NULL, *t2 = NULL;
    uint32_t *p1 = NULL, *p2 = NULL;
    enum RTCBuildQuality bq;
    uint32_t rep;
    size_t npix = 0, i;
    int st = EMB_OK;

    if (!out) return EMB_ERR_ARGUMENT;
    emb__start(out, sizeof *out, out->message, &d, desc, sizeof d);
    if ((!v && n) || n > EMB__MAX_TRIANGLES || (int)d.quality < 0 || d.quality >= EMB_QUALITY_COUNT) {
        emb__msg(out->message, "invalid argument (vertices NULL, too many triangles or bad quality)");
        return EMB_ERR_ARGUMENT;
    }
    if (!d.repeat) d.repeat = 5;
    if (d.repeat > 100000) d.repeat = 100000;
    if (!d.width || !d.height) d.width = d.height = 0;
    if (!d.trace_threads) d.trace_threads = scene_cpu_count();
    if (d.trace_threads > 1024) d.trace_threads = 1024;
    bq = emb__rtc_quality(d.quality);
    out->threads = d.threads;
    out->repeat = d.repeat;
    out->trace_threads = d.trace_threads;

    err.message = out->message;
    err.failed = 0;
    pthread_mutex_init(&err.lock, NULL);
    ms = (double *)malloc(2 * (size_t)d.repeat * sizeof *ms);
    if (!ms) {
        st = EMB_ERR_MEMORY;
        emb__msg(out->message, "out of memory");
        goto done;
    }
    cms = ms + d.repeat;
    dev = emb__device(d.threads, &err);
    if (!dev) {
        st = EMB_ERR_EMBREE;
        goto done;
    }

    /* one warm-up build, then d.repeat timed ones; the last scene is kept for tracing */
    for (rep = 0; rep <= d.repeat; rep++) {
        double total, commit;
        if (scene) rtcReleaseScene(scene);
        scene = emb__build_scene(dev, v, n, bq, d.robust, &total, &commit);
        if (!scene || emb__check(dev, &err, "scene build")) {
            if (!err.failed) emb__msg(out->message, "scene build failed");
            st = EMB_ERR_EMBREE;
            goto done;
        }
        if (rep) {
            ms[rep - 1] = total;
            cms[rep - 1] = commit;
        }
    }
    out->build = emb__timing(ms, d.repeat);
    out->commit = emb__timing(cms, d.repeat);
    out->mt_identical = 1;

    if (d.width) {
        bvh_aabb b = d.bounds ? *d.bounds : emb__bounds(v, n);
        bvh_camera cam = d.camera ? *d.camera : bvh_camera_standard(b, d.width, d.height);
        uint32_t x, y;
        double ms1 = 0.0, ms2 = 0.0;
        npix = (size_t)d.width * d.height;
        rays = (bvh_ray *)malloc(npix * sizeof *rays);
        t1 = d.t_out ? d.t_out : (float *)malloc(npix * sizeof *t1);
        p1 = d.prim_out ? d.prim_out : (uint32_t *)malloc(npix * sizeof *p1);
        if (!rays || !t1 || !p1) {
            st = EMB_ERR_MEMORY;
            emb__msg(out->message, "out of memory (rays)");
            goto done;
        }
        for (y = 0; y < d.height; y++)
            for (x = 0; x < d.width; x++) rays[(size_t)y * d.width + x] = bvh_camera_ray(&cam, x, y);
        st = emb__trace_median(scene, rays, &d, 1, t1, p1, &ms1);
        if (st == EMB_OK && d.trace_threads > 1) {
            t2 = (float *)malloc(npix * sizeof *t2);
            p2 = (uint32_t *)malloc(npix * sizeof *p2);
            if (!t2 || !p2)
                st = EMB_ERR_MEMORY;
            else
                st = emb__trace_median(scene, rays, &d, d.trace_threads, t2, p2, &ms2);
        } else {
            ms2 = ms1;
        }
        if (st != EMB_OK) {
            snprintf(out->message, sizeof out->message, "tracing: %s", emb_status_string(st));
            goto done;
        }
        if (emb__check(dev, &err, "rtcIntersect1")) {
            st = EMB_ERR_EMBREE;
            goto done;
        }
        out->rays = npix;
        for (i = 0; i < npix; i++) {
            if (p1[i] != BVH_INVALID) {
                out->hits++;
                out->t_sum += (double)t1[i];
            }
        }
        if (t2) {
            for (i = 0; i < npix; i++) {
                if (p1[i] != p2[i] || (p1[i] != BVH_INVALID && t1[i] != t2[i])) {
                    out->mt_identical = 0;
                    break;
                }
            }
        }
        out->trace_ms = ms1;
        out->mrays = ms1 > 0.0 ? (double)npix / (ms1 * 1e3) : 0.0;
        out->trace_ms_mt = ms2;
        out->mrays_mt = ms2 > 0.0 ? (double)npix / (ms2 * 1e3) : 0.0;
    }

done:
    if (scene) rtcReleaseScene(scene);
    if (dev) rtcReleaseDevice(dev);
    pthread_mutex_destroy(&err.lock);
    free(ms);
    free(rays);
    if (t1 != d.t_out) free(t1);
    if (p1 != d.prim_out) free(p1);
    free(t2);
    free(p2);
    return st;
}

/* ---- BVH builder API: a binary tree of our own nodes, and its SAH ---------------------------- */
typedef struct emb__bnode {
    uint32_t leaf;  /* 1: emb__bleaf */
    uint32_t count; /* leaf: primitive references */
} emb__bnode;
typedef struct emb__binner {
    emb__bnode head; /* leaf = 0 */
    emb__bnode *child[2];
    float box[2][6]; /* child bounds: lower xyz, upper xyz */
} emb__binner;

typedef struct emb__bctx {
    const float *v;
} emb__bctx;

static void *emb__create_node(RTCThreadLocalAllocator a, unsigned int count, void *user) {
    emb__binner *n = (emb__binner *)rtcThreadLocalAlloc(a, sizeof(emb__binner), 16);
    (void)user;
    if (!n) return NULL;
    (void)count; /* always 2 with maxBranchingFactor 2 */
    n->head.leaf = 0;
    n->head.count = 0;
    n->child[0] = n->child[1] = NULL;
    return n;
}
static void emb__set_children(void *node, void **children, unsigned int count, void *user) {
    emb__binner *n = (emb__binner *)node;
    unsigned i;
    (void)user;
    for (i = 0; i < count && i < 2; i++) n->child[i] = (emb__bnode *)children[i];
}
static void emb__set_bounds(void *node, const struct RTCBounds **b, unsigned int count, void *user) {
    emb__binner *n = (emb__binner *)node;
    unsigned i;
    (void)user;
    for (i = 0; i < count && i < 2; i++) {
        n->box[i][0] = b[i]->lower_x;
        n->box[i][1] = b[i]->lower_y;
        n->box[i][2] = b[i]->lower_z;
        n->box[i][3] = b[i]->upper_x;
        n->box[i][4] = b[i]->upper_y;
        n->box[i][5] = b[i]->upper_z;
    }
}
static void *emb__create_leaf(RTCThreadLocalAllocator a, const struct RTCBuildPrimitive *prims, size_t count,
                              void *user) {
    emb__bnode *l = (emb__bnode *)rtcThreadLocalAlloc(a, sizeof(emb__bnode), 16);
    (void)prims;
    (void)user;
    if (!l) return NULL;
    l->leaf = 1;
    l->count = (uint32_t)count;
    return l;
}
static void emb__grow3(float *lo, float *hi, const float *p) {
    int k;
    for (k = 0; k < 3; k++) {
        if (p[k] < lo[k]) lo[k] = p[k];
        if (p[k] > hi[k]) hi[k] = p[k];
    }
}
/* Spatial split of a triangle reference (HIGH): clips the triangle at `pos` on axis `dim`, the
   bounds of each side intersected with the reference's current box. A side on which the
   clipped triangle has nothing inside the box gets the plain half box (always conservative). */
static void emb__split_prim(const struct RTCBuildPrimitive *p, unsigned int dim, float pos, struct RTCBounds *lb,
                            struct RTCBounds *rb, void *user) {
    const emb__bctx *c = (const emb__bctx *)user;
    const float *t = c->v + (size_t)p->primID * 9;
    float lo[2][3], hi[2][3], plo[3], phi[3];
    int s, k, i;
    plo[0] = p->lower_x;
    plo[1] = p->lower_y;
    plo[2] = p->lower_z;
    phi[0] = p->upper_x;
    phi[1] = p->upper_y;
    phi[2] = p->upper_z;
    for (s = 0; s < 2; s++)
        for (k = 0; k < 3; k++) {
            lo[s][k] = HUGE_VALF;
            hi[s][k] = -HUGE_VALF;
        }
    for (i = 0; i < 3; i++) {
        const float *a = t + 3 * i, *b = t + 3 * ((i + 1) % 3);
        float da = a[dim], db = b[dim];
        if (da <= pos) emb__grow3(lo[0], hi[0], a);
        if (da >= pos) emb__grow3(lo[1], hi[1], a);
        if ((da < pos && db > pos) || (da > pos && db < pos)) {
            float f = (pos - da) / (db - da), q[3];
            for (k = 0; k < 3; k++) q[k] = a[k] + f * (b[k] - a[k]);
            q[dim] = pos;
            emb__grow3(lo[0], hi[0], q);
            emb__grow3(lo[1], hi[1], q);
        }
    }
    for (s = 0; s < 2; s++) {
        int empty = 0;
        for (k = 0; k < 3; k++) {
            lo[s][k] = lo[s][k] > plo[k] ? lo[s][k] : plo[k];
            hi[s][k] = hi[s][k] < phi[k] ? hi[s][k] : phi[k];
        }
        if (s == 0 && hi[0][dim] > pos) hi[0][dim] = pos;
        if (s == 1 && lo[1][dim] < pos) lo[1][dim] = pos;
        for (k = 0; k < 3; k++) empty |= !(lo[s][k] <= hi[s][k]);
        if (empty) {
            for (k = 0; k < 3; k++) {
                lo[s][k] = plo[k];
                hi[s][k] = phi[k];
            }
            if (s == 0)
                hi[0][dim] = pos;
            else
                lo[1][dim] = pos;
        }
    }
    lb->lower_x = lo[0][0];
    lb->lower_y = lo[0][1];
    lb->lower_z = lo[0][2];
    lb->upper_x = hi[0][0];
    lb->upper_y = hi[0][1];
    lb->upper_z = hi[0][2];
    rb->lower_x = lo[1][0];
    rb->lower_y = lo[1][1];
    rb->lower_z = lo[1][2];
    rb->upper_x = hi[1][0];
    rb->upper_y = hi[1][1];
    rb->upper_z = hi[1][2];
}

/* half area as bvh.h computes it (float), 0 for an empty box */
static float emb__half_area(const float *b) {
    float dx = b[3] - b[0], dy = b[4] - b[1], dz = b[5] - b[2];
    if (!(dx >= 0.0f && dy >= 0.0f && dz >= 0.0f)) return 0.0f;
    return dx * dy + dy * dz + dz * dx;
}

/* Walks the tree from root (whose box is rootbox); fills sah, counts. */
static int emb__tree_sah(const emb__bnode *root, const float *rootbox, emb_sah_result *o) {
    typedef struct {
        const emb__bnode *n;
        const float *box;
        uint32_t depth;
    } item;
    size_t cap = 256, sp = 0;
    item *stack = (item *)malloc(cap * sizeof *stack);
    double ra = emb__half_area(rootbox), si = 0.0, st = 0.0;
    if (!stack) return EMB_ERR_MEMORY;
    stack[sp].n = root;
    stack[sp].box = rootbox;
    stack[sp].depth = 1;
    sp++;
    while (sp) {
        item it = stack[--sp];
        double a = ra > 0.0 ? emb__half_area(it.box) / ra : 1.0;
        o->nodes++;
        if (it.depth > o->max_depth) o->max_depth = it.depth;
        if (it.n->leaf) {
            o->leaves++;
            o->refs += it.n->count;
            if (it.n->count > o->max_leaf_size) o->max_leaf_size = it.n->count;
            st += a * it.n->count;
        } else {
            const emb__binner *in = (const emb__binner *)(const void *)it.n;
            int c;
            si += a;
            if (sp + 2 > cap) {
                item *ns = (item *)realloc(stack, 2 * cap * sizeof *stack);
                if (!ns) {
                    free(stack);
                    return EMB_ERR_MEMORY;
                }
                stack = ns;
                cap *= 2;
            }
            for (c = 1; c >= 0; c--) {
                if (!in->child[c]) {
                    free(stack);
                    return EMB_ERR_EMBREE;
                }
                stack[sp].n = in->child[c];
                stack[sp].box = in->box[c];
                stack[sp].depth = it.depth + 1;
                sp++;
            }
        }
    }
    free(stack);
    o->sah = si + st; /* (Ci, Cl, Ct) = (1, 0, 1) */
    return EMB_OK;
}

EMB_API int emb_bvh_sah(const float *v, uint32_t n, const emb_sah_desc *desc, emb_sah_result *out) {
    emb_sah_desc d;
    emb__err err;
    emb__bctx ctx;
    RTCDevice dev = NULL;
    RTCBVH bvh = NULL;
    struct RTCBuildPrimitive *src = NULL, *prims = NULL;
    struct RTCBuildArguments args;
    double *ms = NULL;
    void *root = NULL;
    size_t cap = n, bytes;
    float rootbox[6];
    uint32_t i, rep;
    int st = EMB_OK;

    if (!out) return EMB_ERR_ARGUMENT;
    emb__start(out, sizeof *out, out->message, &d, desc, sizeof d);
    if (!d.max_leaf) d.max_leaf = 8;
    if ((!v && n) || n > EMB__MAX_TRIANGLES || (int)d.quality < 0 || d.quality >= EMB_QUALITY_COUNT ||
        d.max_leaf > RTC_BUILD_MAX_PRIMITIVES_PER_LEAF || !(d.split_factor == d.split_factor) ||
        d.split_factor > 16.0f) {
        emb__msg(out->message,
                 "invalid argument (vertices NULL, too many triangles, quality, max_leaf > 32 or split_factor)");
        return EMB_ERR_ARGUMENT;
    }
    if (!d.repeat) d.repeat = 5;
    if (d.repeat > 100000) d.repeat = 100000;
    if (d.split_factor == 0.0f) d.split_factor = 1.2f;
    out->threads = d.threads;
    out->repeat = d.repeat;
    if (!n) return EMB_OK;
    if (d.quality == EMB_QUALITY_HIGH && d.split_factor > 1.0f) {
        cap = (size_t)((double)d.split_factor * n);
        if (cap <= n) cap = (size_t)n + 1;
        out->spatial_splits = 1;
    }

    err.message = out->message;
    err.failed = 0;
    pthread_mutex_init(&err.lock, NULL);
    bytes = cap * sizeof(struct RTCBuildPrimitive); /* 32 bytes: a multiple of the alignment */
    src = (struct RTCBuildPrimitive *)aligned_alloc(32, (size_t)n * sizeof *src);
    prims = (struct RTCBuildPrimitive *)aligned_alloc(32, bytes);
    ms = (double *)malloc(d.repeat * sizeof *ms);
    if (!src || !prims || !ms) {
        st = EMB_ERR_MEMORY;
        emb__msg(out->message, "out of memory");
        goto done;
    }

    /* the primitives: one box per triangle; NaN/Inf triangles are left out as Embree's scene
       API does, so that refs may be < n for such input */
    rootbox[0] = rootbox[1] = rootbox[2] = HUGE_VALF;
    rootbox[3] = rootbox[4] = rootbox[5] = -HUGE_VALF;
    {
        uint32_t m = 0;
        for (i = 0; i < n; i++) {
            const float *t = v + (size_t)i * 9;
            float lo[3], hi[3];
            int k, ok = 1;
            for (k = 0; k < 9; k++) ok &= isfinite(t[k]) != 0;
            if (!ok) continue;
            for (k = 0; k < 3; k++) {
                lo[k] = fminf(t[k], fminf(t[3 + k], t[6 + k]));
                hi[k] = fmaxf(t[k], fmaxf(t[3 + k], t[6 + k]));
                if (lo[k] < rootbox[k]) rootbox[k] = lo[k];
                if (hi[k] > rootbox[3 + k]) rootbox[3 + k] = hi[k];
            }
            src[m].lower_x = lo[0];
            src[m].lower_y = lo[1];
            src[m].lower_z = lo[2];
            src[m].geomID = 0;
            src[m].upper_x = hi[0];
            src[m].upper_y = hi[1];
            src[m].upper_z = hi[2];
            src[m].primID = i;
            m++;
        }
        if (!m) goto done;
        n = m;
        if (out->spatial_splits && cap <= n) cap = (size_t)n + 1;
    }

    dev = emb__device(d.threads, &err);
    if (!dev) {
        st = EMB_ERR_EMBREE;
        goto done;
    }
    bvh = rtcNewBVH(dev);
    if (!bvh || emb__check(dev, &err, "rtcNewBVH")) {
        st = EMB_ERR_EMBREE;
        goto done;
    }

    ctx.v = v;
    args = rtcDefaultBuildArguments();
    args.byteSize = sizeof args;
    args.buildQuality = emb__rtc_quality(d.quality);
    args.buildFlags = RTC_BUILD_FLAG_NONE;
    args.maxBranchingFactor = 2;
    args.maxDepth = 64;
    args.sahBlockSize = 1;
    args.minLeafSize = 1;
    args.maxLeafSize = d.max_leaf;
    args.traversalCost = 1.0f;
    args.intersectionCost = 1.0f;
    args.bvh = bvh;
    args.primitives = prims;
    args.primitiveCount = n;
    args.primitiveArrayCapacity = cap;
    args.createNode = emb__create_node;
    args.setNodeChildren = emb__set_children;
    args.setNodeBounds = emb__set_bounds;
    args.createLeaf = emb__create_leaf;
    /* HIGH: spatial splits need this callback and capacity > count (else binned SAH = MEDIUM) */
    args.splitPrimitive = out->spatial_splits ? emb__split_prim : NULL;
    args.buildProgress = NULL;
    args.userPtr = &ctx;

    /* one warm-up build, then d.repeat timed ones; the builder reorders (and, with splits,
       grows) the primitive array, so it is refilled before each build, off the clock */
    for (rep = 0; rep <= d.repeat; rep++) {
        double t0;
        memcpy(prims, src, (size_t)n * sizeof *src);
        t0 = scene_now_ms();
        root = rtcBuildBVH(&args);
        if (rep) ms[rep - 1] = scene_now_ms() - t0;
        if (!root || emb__check(dev, &err, "rtcBuildBVH")) {
            if (!err.failed) emb__msg(out->message, "rtcBuildBVH returned no tree");
            st = EMB_ERR_EMBREE;
            goto done;
        }
    }
    out->build = emb__timing(ms, d.repeat);
    st = emb__tree_sah((const emb__bnode *)root, rootbox, out);
    if (st == EMB_ERR_EMBREE)
        emb__msg(out->message, "rtcBuildBVH left a node without children");
    else if (st != EMB_OK)
        emb__msg(out->message, "out of memory");

done:
    if (bvh) rtcReleaseBVH(bvh); /* frees the nodes */
    if (dev) rtcReleaseDevice(dev);
    pthread_mutex_destroy(&err.lock);
    free(src);
    free(prims);
    free(ms);
    return st;
}

#endif /* BVH_HAVE_EMBREE */
#endif /* EMB_IMPLEMENTATION_DONE */
#endif /* EMB_IMPLEMENTATION */
