/* bvh_cl.h - v0.4.2 - OpenCL companion of bvh.h: trace bvh.h trees on any OpenCL 1.2 device

   WHAT
     Uploads a bvh_tree (nodes, reference-ordered triangles, primitive ids) to an OpenCL device as
     it is, and traces ray batches (closest hit, any hit) and whole camera frames there with the
     kernels of cl/trace.cl. The hits are those of bvh_intersect: same primitive, same t (to the
     bit on devices with correctly rounded division and fp64, such as PoCL on a CPU). Two-level
     scenes (bvh_scene: instances of bottom-level trees) go up and are traced the same way, with
     bvh_scene_intersect's hits (instance, id, triangle, t, u, v, world normal) and ray masks.

   HOW TO INCLUDE
     In exactly ONE .c file, after bvh.h:
         #include "bvh.h"
         #define BVH_CL_IMPLEMENTATION
         #include "cl/bvh_cl.h"
     Compile with -DBVH_HAVE_OPENCL and link -lOpenCL. Without BVH_HAVE_OPENCL the header still
     compiles and every call returns BVH_CL_ERROR_NOT_AVAILABLE, so that a program can fall back
     to bvh_intersect_batch.

   EXAMPLE
         bvh_cl_context *cl;
         bvh_cl_tree *gpu;
         char log[4096] = "";
         bvh_cl_desc desc = {0};              // first device (or $BVH_CL_DEVICE="1:0"), kernel built in
         desc.log = log;                      // receives the compiler's log if the build fails
         desc.log_size = sizeof log;
         bvh_cl_result r = bvh_cl_create(&cl, &desc);
         if (r != BVH_CL_SUCCESS) { printf("%s\n%s\n", bvh_cl_result_string(r), log); return 1; }
         r = bvh_cl_upload(cl, &tree, &gpu);                          // tree from bvh_build
         if (r == BVH_CL_SUCCESS) r = bvh_cl_intersect(gpu, rays, hits, ray_count);
         bvh_camera cam = bvh_camera_standard(bvh_tree_bounds(&tree), 640, 480);
         if (r == BVH_CL_SUCCESS) r = bvh_cl_render_frame(gpu, &cam, rgba, NULL, NULL);
         bvh_cl_tree_free(gpu);
         bvh_cl_scene *gs;                    // a scene from bvh_scene_build, likewise
         r = bvh_cl_scene_upload(cl, &scene, &gs);
         if (r == BVH_CL_SUCCESS) r = bvh_cl_scene_intersect(gs, rays, ~0u, scene_hits, ray_count);
         bvh_cl_scene_free(gs);
         bvh_cl_destroy(cl);

   CONFIGURATION (define before including the implementation)
     BVH_CL_KERNEL_PATH    a kernel file read when bvh_cl_desc.kernel_source and kernel_path
                           are NULL; undefined (the default): the kernel embedded in this
                           header (cl/trace.cl, copied in by scripts/embed-kernel.sh) is built,
                           so no file is needed at run time
     BVH_CL_MALLOC(size, user) / BVH_CL_FREE(ptr, user)  default host allocator (malloc/free);
                           define both or neither; a per-context allocator with a user pointer
                           goes in bvh_cl_desc.allocator (also both or neither)
     BVH_CL_API            decoration of every public function (extern; static with BVH_STATIC
                           or BVH_CL_STATIC)
     BVH_CL_DEVICE         (environment variable) "platform:device" indices used when
                           bvh_cl_desc.device is NULL, e.g. BVH_CL_DEVICE=1:0

   ERRORS
     Every call that can fail returns a bvh_cl_result; bvh_cl_result_string() names it and
     bvh_cl_last_error() gives the OpenCL error number and call. The library never aborts, exits
     or prints. Every call returns BVH_CL_ERROR_NOT_AVAILABLE without BVH_HAVE_OPENCL, and
     BVH_CL_ERROR_INVALID_ARGUMENT for a NULL context, tree or output; the other codes each call
     returns are listed beside its prototype.

   THREADS
     No global state. A context and its trees and scenes must be used by one thread at a time
     (they share a command queue and scratch buffers); use one context per thread to trace
     concurrently.

   LICENSE
     MIT, like bvh.h.
*/
#ifndef BVH_CL_H_INCLUDED
#define BVH_CL_H_INCLUDED

#ifndef BVH_H_INCLUDED
#error "include bvh.h before cl/bvh_cl.h"
#endif

#define BVH_CL_VERSION_MAJOR 0
#define BVH_CL_VERSION_MINOR 4
#define BVH_CL_VERSION_PATCH 2

#ifndef BVH_CL_API
#if (defined(BVH_STATIC) || defined(BVH_CL_STATIC)) && (defined(__GNUC__) || defined(__clang__))
#define BVH_CL_API static __attribute__((unused)) /* a program need not call every function */
#elif defined(BVH_STATIC) || defined(BVH_CL_STATIC)
#define BVH_CL_API static
#else
#define BVH_CL_API extern
#endif
#endif

#ifdef __cplusplus
extern "C" {
#endif

typedef enum bvh_cl_result {
    BVH_CL_SUCCESS = 0,
    BVH_CL_ERROR_NOT_AVAILABLE,    /* compiled without BVH_HAVE_OPENCL */
    BVH_CL_ERROR_NO_PLATFORM,      /* no OpenCL platform, or platform index out of range */
    BVH_CL_ERROR_NO_DEVICE,        /* the platform has no device, or device index out of range */
    BVH_CL_ERROR_KERNEL_NOT_FOUND, /* the kernel file could not be read (path in desc.log) */
    BVH_CL_ERROR_BUILD_FAILED,     /* the kernel did not compile: the compiler's log in desc.log */
    BVH_CL_ERROR_OUT_OF_RESOURCES, /* host or device memory or resources exhausted */
    BVH_CL_ERROR_BUFFER_TOO_LARGE, /* a buffer exceeds CL_DEVICE_MAX_MEM_ALLOC_SIZE (or
                                      desc.max_alloc), or the tree the global memory */
    BVH_CL_ERROR_INVALID_ARGUMENT, /* NULL pointer, bad "platform:device" string, box-only tree */
    BVH_CL_ERROR_OPENCL,           /* any other OpenCL error: see bvh_cl_last_error() */
    BVH_CL_RESULT_COUNT
} bvh_cl_result;

/* Zero is the sensible default for every field. */
typedef struct bvh_cl_desc {
    const char *device;        /* "platform:device" indices (or "platform"); NULL: $BVH_CL_DEVICE,
                                  else the first device of the first platform that has one */
    const char *kernel_path;   /* a kernel file to read; NULL: BVH_CL_KERNEL_PATH if defined, else
                                  the kernel embedded in this header */
    const char *kernel_source; /* if set, compiled instead of reading kernel_path */
    const char *build_options; /* appended to the options bvh_cl_create passes (-D..., -cl-...) */
    size_t max_alloc;          /* largest buffer in bytes: 0 = CL_DEVICE_MAX_MEM_ALLOC_SIZE, else
                                  the lower of both (batches and frames are split to fit) */
    size_t local_size;         /* work-group size: 0 = 64 (frames: 8 x 8 work-items) */
    int frame_rays;            /* rays per work-item of bvh_cl_render_frame: 0 = by device (CPU:
                                  16, GPU: 1); 16 or 8 = a packet of 4 x 4 or 4 x 2 pixels whose
                                  setup and box tests run as float16 / float8 (what a CPU driver
                                  vectorises); 1 = one ray. Frames that ask for visited counts
                                  always take one ray. Anything else is refused */
    char *log;                 /* optional: on failure of bvh_cl_create, receives the compiler's
                                  log (BUILD_FAILED) or the failing call; NUL-terminated */
    size_t log_size;
    bvh_allocator allocator; /* host memory of the context and its trees, as bvh.h's: both
                                NULL = BVH_CL_MALLOC / BVH_CL_FREE, one alone refused; blocks
                                aligned less than malloc's count as failed allocations */
} bvh_cl_desc;

typedef struct bvh_cl_device_info {
    char platform[128], device[128], version[128];
    uint32_t platform_index, device_index;
    uint32_t compute_units;
    uint64_t max_alloc; /* effective limit on one buffer (device limit, or desc.max_alloc) */
    uint64_t global_mem;
    int is_gpu;
    int exact; /* correctly rounded divide/sqrt and fp64: t bit-identical to the CPU */
} bvh_cl_device_info;

typedef struct bvh_cl_context bvh_cl_context; /* device, queue, compiled kernels */
typedef struct bvh_cl_tree bvh_cl_tree;       /* a tree uploaded to the device of a context */
typedef struct bvh_cl_scene bvh_cl_scene;     /* a two-level scene (bvh_scene) uploaded likewise */

BVH_CL_API const char *bvh_cl_result_string(bvh_cl_result r);

/* Lists up to `capacity` devices of all platforms (max_alloc and exact filled as for a context
   without override); *count receives the number of devices found.
   SUCCESS; ARGUMENT: count NULL (or out NULL with capacity > 0); NO_PLATFORM; NO_DEVICE. */
BVH_CL_API bvh_cl_result bvh_cl_enumerate(bvh_cl_device_info *out, uint32_t capacity, uint32_t *count);

/* Picks the device, creates a context and queue, compiles the kernels. On failure *ctx is NULL
   and desc->log (if given) says why. desc NULL = all defaults.
   SUCCESS; ARGUMENT: ctx NULL, frame_rays out of range, a bad device string, a half allocator
   pair; NO_PLATFORM; NO_DEVICE; KERNEL_NOT_FOUND; BUILD_FAILED; OUT_OF_RESOURCES; OPENCL. */
BVH_CL_API bvh_cl_result bvh_cl_create(bvh_cl_context **ctx, const bvh_cl_desc *desc);
BVH_CL_API void bvh_cl_destroy(bvh_cl_context *ctx); /* free its trees and scenes first; NULL is ignored */
/* SUCCESS; ARGUMENT. */
BVH_CL_API bvh_cl_result bvh_cl_get_info(const bvh_cl_context *ctx, bvh_cl_device_info *out);
/* The compiler's log of the successful build (warnings), "" if none. */
BVH_CL_API const char *bvh_cl_build_log(const bvh_cl_context *ctx);
/* The OpenCL error number of the last failing call of ctx (0 if none); *call names it. */
BVH_CL_API int bvh_cl_last_error(const bvh_cl_context *ctx, const char **call);
/* Device time in milliseconds of the kernels of the last trace or frame call (profiling). */
BVH_CL_API double bvh_cl_last_kernel_ms(const bvh_cl_context *ctx);

/* Copies the tree's nodes, triangles and primitive ids to the device (the tree may be freed
   afterwards). SUCCESS; ARGUMENT: also a tree built from boxes (no triangles); BUFFER_TOO_LARGE;
   OUT_OF_RESOURCES; OPENCL. */
BVH_CL_API bvh_cl_result bvh_cl_upload(bvh_cl_context *ctx, const bvh_tree *tree, bvh_cl_tree **out);
BVH_CL_API void bvh_cl_tree_free(bvh_cl_tree *tree);

/* bvh_intersect_batch / bvh_occluded_batch on the device; blocking.
   SUCCESS; ARGUMENT: rays or the output NULL with count > 0; BUFFER_TOO_LARGE; OUT_OF_RESOURCES;
   OPENCL. */
BVH_CL_API bvh_cl_result bvh_cl_intersect(bvh_cl_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count);
BVH_CL_API bvh_cl_result bvh_cl_occluded(bvh_cl_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count);

/* Traces the camera's width x height primary rays (bvh_camera_ray, row 0 at the top), generated
   on the device. Outputs, each optional (NULL), width*height entries in row-major order:
   rgba     4 bytes per pixel: hits grey * (0.2 + 0.8 |dot(n, d)|) (headlight), misses a gradient
   hits     bvh_hit per pixel, equal to bvh_intersect of bvh_camera_ray(cam, x, y)
   visited  nodes visited per pixel, equal to bvh_intersect_counted (for heat maps)
   On a CPU device (desc.frame_rays), frames without visited counts trace packets of 4 x 4 pixels
   per work-item, set up and box-tested as float16.
   SUCCESS; ARGUMENT: cam NULL; BUFFER_TOO_LARGE; OUT_OF_RESOURCES; OPENCL. */
BVH_CL_API bvh_cl_result bvh_cl_render_frame(bvh_cl_tree *tree, const bvh_camera *cam, uint8_t *rgba, bvh_hit *hits,
                                             uint32_t *visited);

/* Two-level scenes. Copies a bvh_scene to the device: its top-level tree, the instances
   (world-to-object transforms, masks, ids) and each distinct bottom-level tree once, however many
   instances use it (the scene and its trees may be freed or changed afterwards: upload again after
   bvh_scene_build). SUCCESS; ARGUMENT: ctx, scene or out NULL, a scene whose arrays are missing,
   an instance whose tree is NULL or built from boxes, or that has a custom test (a device cannot
   call the host's callback: trace those instances on the CPU); BUFFER_TOO_LARGE: the bottom-level trees
   together exceed a buffer (they lie in one) or the global memory; OUT_OF_RESOURCES; OPENCL. */
BVH_CL_API bvh_cl_result bvh_cl_scene_upload(bvh_cl_context *ctx, const bvh_scene *scene, bvh_cl_scene **out);
BVH_CL_API void bvh_cl_scene_free(bvh_cl_scene *scene); /* NULL is ignored */
/* bvh_scene_intersect / bvh_scene_occluded of each ray on the device, for the instances whose mask
   shares a bit with `mask` (one mask for the batch, as the CPU call takes one per ray: rays of
   different masks go in separate calls); blocking. The hits are the CPU's record (instance, id,
   triangle, t, u, v, world normal), to the bit on an exact device (bvh_cl_device_info.exact).
   SUCCESS; ARGUMENT: scene NULL, rays or the output NULL with count > 0; BUFFER_TOO_LARGE;
   OUT_OF_RESOURCES; OPENCL. */
BVH_CL_API bvh_cl_result bvh_cl_scene_intersect(bvh_cl_scene *scene, const bvh_ray *rays, uint32_t mask,
                                                bvh_scene_hit *hits, size_t count);
BVH_CL_API bvh_cl_result bvh_cl_scene_occluded(bvh_cl_scene *scene, const bvh_ray *rays, uint32_t mask,
                                               uint8_t *occluded, size_t count);

#ifdef __cplusplus
}
#endif
#endif /* BVH_CL_H_INCLUDED */

/* ============================================================================================ */
/*                                      IMPLEMENTATION                                          */
/* ============================================================================================ */
#ifdef BVH_CL_IMPLEMENTATION
#ifndef BVH_CL_IMPLEMENTATION_DONE
#define BVH_CL_IMPLEMENTATION_DONE

#include <stdlib.h>
#include <string.h>

#if defined(BVH_CL_MALLOC) != defined(BVH_CL_FREE)
#error "bvh_cl.h: define both BVH_CL_MALLOC and BVH_CL_FREE, or neither"
#endif
#ifndef BVH_CL_MALLOC
#define BVH_CL_MALLOC(size, user) ((void)(user), malloc(size))
#define BVH_CL_FREE(ptr, user) ((void)(user), free(ptr))
#endif

#ifdef __cplusplus
#define BVH_CL__CAST(T, x) static_cast<T>(x)
#else
#define BVH_CL__CAST(T, x) ((T)(x))
#endif

BVH_CL_API const char *bvh_cl_result_string(bvh_cl_result r) {
    switch (r) {
    case BVH_CL_SUCCESS:
        return "success";
    case BVH_CL_ERROR_NOT_AVAILABLE:
        return "OpenCL not available (built without BVH_HAVE_OPENCL)";
    case BVH_CL_ERROR_NO_PLATFORM:
        return "no OpenCL platform (or platform index out of range)";
    case BVH_CL_ERROR_NO_DEVICE:
        return "no OpenCL device (or device index out of range)";
    case BVH_CL_ERROR_KERNEL_NOT_FOUND:
        return "kernel source file could not be read";
    case BVH_CL_ERROR_BUILD_FAILED:
        return "kernel build failed (see the build log)";
    case BVH_CL_ERROR_OUT_OF_RESOURCES:
        return "out of device or host memory/resources";
    case BVH_CL_ERROR_BUFFER_TOO_LARGE:
        return "buffer too large for the device";
    case BVH_CL_ERROR_INVALID_ARGUMENT:
        return "invalid argument";
    case BVH_CL_ERROR_OPENCL:
        return "OpenCL error (see bvh_cl_last_error)";
    default:
        return "unknown result code";
    }
}

#ifndef BVH_HAVE_OPENCL
/* ============================================================================================ */
/* == without OpenCL: every call reports BVH_CL_ERROR_NOT_AVAILABLE ============================== */
/* ============================================================================================ */
BVH_CL_API bvh_cl_result bvh_cl_enumerate(bvh_cl_device_info *out, uint32_t capacity, uint32_t *count) {
    (void)out;
    (void)capacity;
    if (count) *count = 0;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API bvh_cl_result bvh_cl_create(bvh_cl_context **ctx, const bvh_cl_desc *desc) {
    if (ctx) *ctx = NULL;
    if (desc && desc->log && desc->log_size) {
        strncpy(desc->log, "built without BVH_HAVE_OPENCL", desc->log_size - 1);
        desc->log[desc->log_size - 1] = '\0';
    }
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API void bvh_cl_destroy(bvh_cl_context *ctx) { (void)ctx; }
BVH_CL_API bvh_cl_result bvh_cl_get_info(const bvh_cl_context *ctx, bvh_cl_device_info *out) {
    (void)ctx;
    if (out) memset(out, 0, sizeof *out);
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API const char *bvh_cl_build_log(const bvh_cl_context *ctx) {
    (void)ctx;
    return "";
}
BVH_CL_API int bvh_cl_last_error(const bvh_cl_context *ctx, const char **call) {
    (void)ctx;
    if (call) *call = "";
    return 0;
}
BVH_CL_API double bvh_cl_last_kernel_ms(const bvh_cl_context *ctx) {
    (void)ctx;
    return 0.0;
}
BVH_CL_API bvh_cl_result bvh_cl_upload(bvh_cl_context *ctx, const bvh_tree *tree, bvh_cl_tree **out) {
    (void)ctx;
    (void)tree;
    if (out) *out = NULL;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API void bvh_cl_tree_free(bvh_cl_tree *tree) { (void)tree; }
BVH_CL_API bvh_cl_result bvh_cl_intersect(bvh_cl_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count) {
    (void)tree;
    (void)rays;
    (void)hits;
    (void)count;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API bvh_cl_result bvh_cl_occluded(bvh_cl_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count) {
    (void)tree;
    (void)rays;
    (void)occluded;
    (void)count;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API bvh_cl_result bvh_cl_render_frame(bvh_cl_tree *tree, const bvh_camera *cam, uint8_t *rgba, bvh_hit *hits,
                                             uint32_t *visited) {
    (void)tree;
    (void)cam;
    (void)rgba;
    (void)hits;
    (void)visited;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}

BVH_CL_API bvh_cl_result bvh_cl_scene_upload(bvh_cl_context *ctx, const bvh_scene *scene, bvh_cl_scene **out) {
    (void)ctx;
    (void)scene;
    if (out) *out = NULL;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API void bvh_cl_scene_free(bvh_cl_scene *scene) { (void)scene; }
BVH_CL_API bvh_cl_result bvh_cl_scene_intersect(bvh_cl_scene *scene, const bvh_ray *rays, uint32_t mask,
                                                bvh_scene_hit *hits, size_t count) {
    (void)scene;
    (void)rays;
    (void)mask;
    (void)hits;
    (void)count;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API bvh_cl_result bvh_cl_scene_occluded(bvh_cl_scene *scene, const bvh_ray *rays, uint32_t mask,
                                               uint8_t *occluded, size_t count) {
    (void)scene;
    (void)rays;
    (void)mask;
    (void)occluded;
    (void)count;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}

#else /* BVH_HAVE_OPENCL */
/* ============================================================================================ */
/* == OpenCL implementation ====================================================================== */
/* ============================================================================================ */
#include <stdarg.h>
#include <stdio.h>
#ifndef CL_TARGET_OPENCL_VERSION
#define CL_TARGET_OPENCL_VERSION 120
#endif
#ifdef __APPLE__
#include <OpenCL/opencl.h>
#else
#include <CL/cl.h>
#endif

/* the kernels read these layouts as-is */
typedef char bvh_cl__node_is_32_bytes[sizeof(bvh_node) == 32 ? 1 : -1];
typedef char bvh_cl__ray_is_32_bytes[sizeof(bvh_ray) == 32 ? 1 : -1];
typedef char bvh_cl__hit_is_16_bytes[sizeof(bvh_hit) == 16 ? 1 : -1];
typedef char bvh_cl__scene_hit_is_9_words[sizeof(bvh_scene_hit) == 36 && offsetof(bvh_scene_hit, instance) == 12 &&
                                                  offsetof(bvh_scene_hit, normal) == 24
                                              ? 1
                                              : -1];

#define BVH_CL__PLATFORM_NOT_FOUND (-1001) /* CL_PLATFORM_NOT_FOUND_KHR of the ICD loader */
#define BVH_CL__MAX_IDS 64
#define BVH_CL__PACKET_DEFAULT 16       /* frame rays per work-item on CPU devices */
#define BVH_CL__CHUNK ((size_t)1 << 20) /* rays or pixels per kernel launch at most */
enum {
    BVH_CL__K_CLOSEST,
    BVH_CL__K_ANY,
    BVH_CL__K_FRAME,
    BVH_CL__K_FRAME8,
    BVH_CL__K_SCENE_CLOSEST,
    BVH_CL__K_SCENE_ANY,
    BVH_CL__K_COUNT
};
enum { BVH_CL__S_IN, BVH_CL__S_OUT, BVH_CL__S_RGBA, BVH_CL__S_VISITED, BVH_CL__S_COUNT };
static const char *const bvh_cl__kernel_names[BVH_CL__K_COUNT] = {
    "bvh_intersect_kernel",    "bvh_occluded_kernel",        "bvh_frame_kernel",
    "bvh_frame_packet_kernel", "bvh_scene_intersect_kernel", "bvh_scene_occluded_kernel"};

struct bvh_cl_context {
    bvh_allocator al; /* desc.allocator: the context's own block, its log and its trees' */
    cl_platform_id platform;
    cl_device_id device;
    cl_context context;
    cl_command_queue queue;
    cl_program program;
    cl_kernel kernels[BVH_CL__K_COUNT];
    cl_mem scratch[BVH_CL__S_COUNT]; /* grown on demand, reused across calls */
    size_t scratch_size[BVH_CL__S_COUNT];
    size_t local_size, max_alloc, max_items[3]; /* work-group size, buffer limit, per-dimension limits */
    int frame_rays;                             /* 1, 8 or 16 (desc.frame_rays resolved) */
    bvh_cl_device_info info;
    char *build_log;
    cl_int last_error;
    const char *last_call;
    double kernel_ms;
};

struct bvh_cl_tree {
    bvh_allocator al; /* the context's (the tree's block is freed after the context's trees) */
    bvh_cl_context *ctx;
    cl_mem nodes, tris, prims;
    cl_uint node_count, ref_count;
};

/* The buffers of trace.cl's bvh_cl_scene, in the order of BVH_CL_SCENE_ARGS. */
enum {
    BVH_CL__B_TOP_NODES,
    BVH_CL__B_TOP_PRIMS,
    BVH_CL__B_NODES,
    BVH_CL__B_TRIS,
    BVH_CL__B_PRIMS,
    BVH_CL__B_MESHES,
    BVH_CL__B_INVERSE,
    BVH_CL__B_INFO,
    BVH_CL__B_COUNT
};
struct bvh_cl_scene {
    bvh_allocator al;
    bvh_cl_context *ctx;
    cl_mem buf[BVH_CL__B_COUNT];
    cl_uint top_node_count, top_ref_count, mesh_count, instance_count;
};

/* Host memory through the caller's pair (or the macros); a block aligned less than malloc's is
   given back and counts as a failure, as in bvh.h. */
static void *bvh_cl__alloc(const bvh_allocator *al, size_t size) {
    void *p;
    if (!al->alloc) return BVH_CL_MALLOC(size, al->user);
    p = al->alloc(size, al->user);
    if (p && (uintptr_t)p % (sizeof(void *) >= 8 ? 16u : 8u)) {
        al->free(p, al->user);
        return NULL;
    }
    return p;
}
static void bvh_cl__free(const bvh_allocator *al, void *p) {
    if (!p) return;
    if (al->free)
        al->free(p, al->user);
    else
        BVH_CL_FREE(p, al->user);
}

static void bvh_cl__logf(const bvh_cl_desc *d, const char *fmt, ...) {
    va_list ap;
    if (!d || !d->log || !d->log_size) return;
    va_start(ap, fmt);
    vsnprintf(d->log, d->log_size, fmt, ap);
    va_end(ap);
}

static bvh_cl_result bvh_cl__map(cl_int err) {
    switch (err) {
    case CL_SUCCESS:
        return BVH_CL_SUCCESS;
    case BVH_CL__PLATFORM_NOT_FOUND:
        return BVH_CL_ERROR_NO_PLATFORM;
    case CL_DEVICE_NOT_FOUND:
    case CL_DEVICE_NOT_AVAILABLE:
        return BVH_CL_ERROR_NO_DEVICE;
    case CL_BUILD_PROGRAM_FAILURE:
    case CL_COMPILER_NOT_AVAILABLE:
        return BVH_CL_ERROR_BUILD_FAILED;
    case CL_OUT_OF_RESOURCES:
    case CL_OUT_OF_HOST_MEMORY:
    case CL_MEM_OBJECT_ALLOCATION_FAILURE:
        return BVH_CL_ERROR_OUT_OF_RESOURCES;
    case CL_INVALID_BUFFER_SIZE:
        return BVH_CL_ERROR_BUFFER_TOO_LARGE;
    default:
        return BVH_CL_ERROR_OPENCL;
    }
}

/* records the failing call in the context (if any) and maps the error */
static bvh_cl_result bvh_cl__fail(bvh_cl_context *c, cl_int err, const char *call) {
    if (c) {
        c->last_error = err;
        c->last_call = call;
    }
    return bvh_cl__map(err);
}

/* ============================================================================================ */
/* == device selection ============================================================================ */
/* ============================================================================================ */
/* "p" or "p:d" with decimal indices; returns 0 on a malformed string */
static int bvh_cl__parse_device(const char *s, cl_uint *p, cl_uint *d) {
    char *end;
    unsigned long a, b = 0;
    if (*s < '0' || *s > '9') return 0;
    a = strtoul(s, &end, 10);
    if (*end == ':') {
        if (end[1] < '0' || end[1] > '9') return 0;
        b = strtoul(end + 1, &end, 10);
    }
    if (*end != '\0' || a > 0xFFFFu || b > 0xFFFFu) return 0;
    *p = (cl_uint)a;
    *d = (cl_uint)b;
    return 1;
}

static void bvh_cl__describe(cl_platform_id p, cl_device_id d, bvh_cl_device_info *info) {
    cl_uint cu = 0;
    cl_ulong alloc = 0, mem = 0;
    cl_device_type type = 0;
    cl_device_fp_config sp = 0, dp = 0;
    memset(info, 0, sizeof *info);
    clGetPlatformInfo(p, CL_PLATFORM_NAME, sizeof info->platform - 1, info->platform, NULL);
    clGetDeviceInfo(d, CL_DEVICE_NAME, sizeof info->device - 1, info->device, NULL);
    clGetDeviceInfo(d, CL_DEVICE_VERSION, sizeof info->version - 1, info->version, NULL);
    clGetDeviceInfo(d, CL_DEVICE_MAX_COMPUTE_UNITS, sizeof cu, &cu, NULL);
    clGetDeviceInfo(d, CL_DEVICE_MAX_MEM_ALLOC_SIZE, sizeof alloc, &alloc, NULL);
    clGetDeviceInfo(d, CL_DEVICE_GLOBAL_MEM_SIZE, sizeof mem, &mem, NULL);
    clGetDeviceInfo(d, CL_DEVICE_TYPE, sizeof type, &type, NULL);
    clGetDeviceInfo(d, CL_DEVICE_SINGLE_FP_CONFIG, sizeof sp, &sp, NULL);
    if (clGetDeviceInfo(d, CL_DEVICE_DOUBLE_FP_CONFIG, sizeof dp, &dp, NULL) != CL_SUCCESS) dp = 0;
    info->compute_units = cu;
    info->max_alloc = alloc;
    info->global_mem = mem;
    info->is_gpu = (type & CL_DEVICE_TYPE_GPU) != 0;
    info->exact = (sp & CL_FP_CORRECTLY_ROUNDED_DIVIDE_SQRT) && dp != 0;
}

static cl_int bvh_cl__devices(cl_platform_id p, cl_device_id *ids, cl_uint *n) {
    cl_int err = clGetDeviceIDs(p, CL_DEVICE_TYPE_ALL, BVH_CL__MAX_IDS, ids, n);
    if (err == CL_DEVICE_NOT_FOUND) {
        *n = 0;
        err = CL_SUCCESS;
    }
    if (*n > BVH_CL__MAX_IDS) *n = BVH_CL__MAX_IDS;
    return err;
}

static bvh_cl_result bvh_cl__pick(const bvh_cl_desc *desc, bvh_cl_context *c) {
    cl_platform_id plats[BVH_CL__MAX_IDS];
    cl_device_id devs[BVH_CL__MAX_IDS];
    cl_uint np = 0, nd = 0, pi = 0, di = 0, i;
    const char *want = desc->device ? desc->device : getenv("BVH_CL_DEVICE");
    cl_int err = clGetPlatformIDs(BVH_CL__MAX_IDS, plats, &np);
    if (err == BVH_CL__PLATFORM_NOT_FOUND || (err == CL_SUCCESS && np == 0)) {
        bvh_cl__logf(desc, "no OpenCL platform found (ICD loader: %d)", (int)err);
        return BVH_CL_ERROR_NO_PLATFORM;
    }
    if (err != CL_SUCCESS) {
        bvh_cl__logf(desc, "clGetPlatformIDs: %d", (int)err);
        return bvh_cl__fail(c, err, "clGetPlatformIDs");
    }
    if (np > BVH_CL__MAX_IDS) np = BVH_CL__MAX_IDS;
    if (want && *want) {
        if (!bvh_cl__parse_device(want, &pi, &di)) {
            bvh_cl__logf(desc, "device \"%s\": expected \"platform:device\" indices", want);
            return BVH_CL_ERROR_INVALID_ARGUMENT;
        }
        if (pi >= np) {
            bvh_cl__logf(desc, "platform %u of %u", pi, np);
            return BVH_CL_ERROR_NO_PLATFORM;
        }
        if ((err = bvh_cl__devices(plats[pi], devs, &nd)) != CL_SUCCESS) return bvh_cl__fail(c, err, "clGetDeviceIDs");
        if (di >= nd) {
            bvh_cl__logf(desc, "device %u of %u on platform %u", di, nd, pi);
            return BVH_CL_ERROR_NO_DEVICE;
        }
    } else {
        for (i = 0; i < np; i++) {
            if (bvh_cl__devices(plats[i], devs, &nd) == CL_SUCCESS && nd > 0) {
                pi = i;
                break;
            }
        }
        if (i == np) {
            bvh_cl__logf(desc, "%u OpenCL platform(s), no device", np);
            return BVH_CL_ERROR_NO_DEVICE;
        }
    }
    c->platform = plats[pi];
    c->device = devs[di];
    bvh_cl__describe(c->platform, c->device, &c->info);
    c->info.platform_index = pi;
    c->info.device_index = di;
    return BVH_CL_SUCCESS;
}

BVH_CL_API bvh_cl_result bvh_cl_enumerate(bvh_cl_device_info *out, uint32_t capacity, uint32_t *count) {
    cl_platform_id plats[BVH_CL__MAX_IDS];
    cl_device_id devs[BVH_CL__MAX_IDS];
    cl_uint np = 0, nd, p, d;
    uint32_t n = 0;
    cl_int err;
    if (!count || (capacity && !out)) return BVH_CL_ERROR_INVALID_ARGUMENT;
    *count = 0;
    err = clGetPlatformIDs(BVH_CL__MAX_IDS, plats, &np);
    if (err == BVH_CL__PLATFORM_NOT_FOUND || (err == CL_SUCCESS && np == 0)) return BVH_CL_ERROR_NO_PLATFORM;
    if (err != CL_SUCCESS) return bvh_cl__map(err);
    if (np > BVH_CL__MAX_IDS) np = BVH_CL__MAX_IDS;
    for (p = 0; p < np; p++) {
        if (bvh_cl__devices(plats[p], devs, &nd) != CL_SUCCESS) continue;
        for (d = 0; d < nd; d++, n++) {
            if (n >= capacity) continue;
            bvh_cl__describe(plats[p], devs[d], &out[n]);
            out[n].platform_index = p;
            out[n].device_index = d;
        }
    }
    *count = n;
    return n ? BVH_CL_SUCCESS : BVH_CL_ERROR_NO_DEVICE;
}

/* ============================================================================================ */
/* == program build ================================================================================ */
/* ============================================================================================ */
/* cl/trace.cl as one string per line (clCreateProgramWithSource takes them as they are). */
/* clang-format off */
/* == kernel source: generated from cl/trace.cl by scripts/embed-kernel.sh, do not edit == */
static const char *const bvh_cl__source[] = {
"/* cl/trace.cl - OpenCL C 1.2 ray tracing kernels for bvh.h trees (host side: cl/bvh_cl.h)\n",
"\n",
"   DATA (uploaded byte for byte from a bvh_tree, no conversion on the host)\n",
"     nodes   bvh_node[node_count], 32 bytes: float min[3], uint index, float max[3], uint count.\n",
"             count == 0: interior node, children nodes[index] and nodes[index + 1];\n",
"             count > 0: leaf over references index .. index + count - 1. Root at 0.\n",
"             Read as two uint4 (the floats through as_float4), so that no index is ever held in\n",
"             a float register.\n",
"     tris    tree.tris: 9 floats (v0, v1, v2) per reference, in reference order\n",
"     prims   tree.prims: original triangle id per reference\n",
"     rays    bvh_ray[]: origin xyz, tmin, dir xyz, tmax (32 bytes, read as two float4)\n",
"     hits    bvh_hit[]: t, u, v, prim (16 bytes), written as one uint4 (float bits, then the id)\n",
"   A two-level scene (bvh_scene, see bvh_cl_scene below) adds: the top-level tree's nodes and prims\n",
"   (instance indices; no triangles); the distinct bottom-level trees' nodes, tris and prims, one\n",
"   tree after the other, with meshes[] = (first node, nodes, first reference, references) per\n",
"   tree; per instance its world-to-object 3x4 (bvh_scene.inverse) and (mask, id, tree, 0); scene\n",
"   hits are bvh_scene_hit (36 bytes: t, u, v, instance, id, prim, normal xyz).\n",
"\n",
"   SEMANTICS: those of bvh.h (section \"traversal\"), statement for statement: watertight triangle\n",
"   test (Woop, Benthin & Wald 2013) in float with the exact fallback on zero edge functions, ties in t to the\n",
"   lowest primitive id, robust slab test (far distance widened by 1.0000004f, zero direction\n",
"   components get an inverse of +inf, the near plane is chosen by the sign of the inverse, the NaN\n",
"   of an origin on a slab plane is dropped by the order of the comparisons), near child first,\n",
"   invalid rays (NaN, non-finite origin or direction, zero direction, tmin > tmax) miss.\n",
"   Scenes: those of bvh_scene_intersect (bvh.h, section \"instances\"): the ray moved into each\n",
"   instance's space by bvh_ray_transform's operations, ties to the lowest instance then triangle,\n",
"   the world normal computed in double as bvh__scene_normal does.\n",
"   Hits equal the CPU's to the bit when the host builds with -cl-fp32-correctly-rounded-divide-sqrt\n",
"   and the device has cl_khr_fp64 (bvh_cl.h does both when it can); FP_CONTRACT is off so that\n",
"   no compiler fuses a*b-c*d into an fma the CPU code does not do. Without cl_khr_fp64 the edge\n",
"   fallback computes a*b-c*d with fma (Kahan), which has the same sign and zeros.\n",
"\n",
"   OPTIONS (-D from the host)\n",
"     BVH_MAX_DEPTH   the host's value (64); the private stack holds BVH_MAX_DEPTH + 2 entries, like\n",
"                     the CPU's (twice that for a scene, whose two levels share it), and a traversal\n",
"                     that would overflow it stops (never writes past it).\n",
"*/\n",
"#pragma OPENCL FP_CONTRACT OFF\n",
"#ifdef cl_khr_fp64\n",
"#pragma OPENCL EXTENSION cl_khr_fp64 : enable\n",
"#define BVH_CL_FP64 1\n",
"#endif\n",
"\n",
"#ifndef BVH_MAX_DEPTH\n",
"#define BVH_MAX_DEPTH 64\n",
"#endif\n",
"#define BVH_CL_STACK (BVH_MAX_DEPTH + 2)\n",
"\n",
"/* Helpers are inlined: PoCL's LLVM otherwise keeps the triangle test and the traversal as calls\n",
"   whose ray and hit go through memory, which cost a third of the speed. static needs OpenCL C 1.2. */\n",
"#if defined(__OPENCL_C_VERSION__) && __OPENCL_C_VERSION__ >= 120\n",
"#ifdef __clang__\n",
"#define BVH_CL_FN static inline __attribute__((always_inline))\n",
"#else\n",
"#define BVH_CL_FN static inline\n",
"#endif\n",
"#elif defined(__clang__)\n",
"#define BVH_CL_FN __attribute__((always_inline))\n",
"#else\n",
"#define BVH_CL_FN\n",
"#endif\n",
"#define BVH_CL_INVALID 0xFFFFFFFFu\n",
"\n",
"/* ============================================================================================ */\n",
"/* == ray setup ================================================================================ */\n",
"/* ============================================================================================ */\n",
"typedef struct bvh_cl_rayx {\n",
"    float3 o, inv;\n",
"    int3 neg; /* inv < 0: the near plane is the max plane on that axis */\n",
"    float tmin;\n",
"    int kx, ky, kz;      /* watertight: kz = dominant axis, kx/ky swapped for d[kz] < 0 */\n",
"    float okx, oky, okz; /* the origin permuted like the axes */\n",
"    float sx, sy, sz;\n",
"} bvh_cl_rayx;\n",
"\n",
"BVH_CL_FN float bvh_cl_comp(float3 v, int k) { return k == 0 ? v.x : (k == 1 ? v.y : v.z); }\n",
"\n",
"/* bvh__ray_setup: 0 for an invalid ray. */\n",
"BVH_CL_FN int bvh_cl_ray_setup(float3 o, float tmin, float3 d, float tmax, bvh_cl_rayx *rx) {\n",
"    float ax, ay, az, dkz;\n",
"    int t;\n",
"    if (!(isfinite(o.x) && isfinite(o.y) && isfinite(o.z) && isfinite(d.x) && isfinite(d.y) && isfinite(d.z))) return 0;\n",
"    if (isnan(tmin) || isnan(tmax) || tmin > tmax) return 0;\n",
"    /* as bvh__ray_setup: subnormal components have no finite inverse and count as 0 */\n",
"    d.x = fabs(d.x) < FLT_MIN ? 0.0f : d.x;\n",
"    d.y = fabs(d.y) < FLT_MIN ? 0.0f : d.y;\n",
"    d.z = fabs(d.z) < FLT_MIN ? 0.0f : d.z;\n",
"    if (d.x == 0.0f && d.y == 0.0f && d.z == 0.0f) return 0;\n",
"    rx->o = o;\n",
"    rx->inv.x = d.x == 0.0f ? INFINITY : 1.0f / d.x;\n",
"    rx->inv.y = d.y == 0.0f ? INFINITY : 1.0f / d.y;\n",
"    rx->inv.z = d.z == 0.0f ? INFINITY : 1.0f / d.z;\n",
"    rx->neg = rx->inv < (float3)(0.0f);\n",
"    rx->tmin = tmin;\n",
"    ax = fabs(d.x);\n",
"    ay = fabs(d.y);\n",
"    az = fabs(d.z);\n",
"    rx->kz = ax > ay ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);\n",
"    rx->kx = rx->kz == 2 ? 0 : rx->kz + 1;\n",
"    rx->ky = rx->kx == 2 ? 0 : rx->kx + 1;\n",
"    dkz = bvh_cl_comp(d, rx->kz);\n",
"    if (dkz < 0.0f) {\n",
"        t = rx->kx;\n",
"        rx->kx = rx->ky;\n",
"        rx->ky = t;\n",
"    }\n",
"    rx->sx = bvh_cl_comp(d, rx->kx) / dkz;\n",
"    rx->sy = bvh_cl_comp(d, rx->ky) / dkz;\n",
"    rx->sz = 1.0f / dkz;\n",
"    rx->okx = bvh_cl_comp(o, rx->kx);\n",
"    rx->oky = bvh_cl_comp(o, rx->ky);\n",
"    rx->okz = bvh_cl_comp(o, rx->kz);\n",
"    return 1;\n",
"}\n",
"\n",
"/* ============================================================================================ */\n",
"/* == watertight triangle test (bvh__tri_test) =================================================== */\n",
"/* ============================================================================================ */\n",
"/* a*b - c*d as float(double(a)*double(b) - double(c)*double(d)): the products are exact in double */\n",
"BVH_CL_FN float bvh_cl_diff_of_products(float a, float b, float c, float d) {\n",
"#ifdef BVH_CL_FP64\n",
"    return (float)((double)a * (double)b - (double)c * (double)d);\n",
"#else\n",
"    float w = c * d;\n",
"    float e = fma(-c, d, w); /* w - c*d exactly */\n",
"    float f = fma(a, b, -w);\n",
"    return f + e;\n",
"#endif\n",
"}\n",
"\n",
"BVH_CL_FN float bvh_cl_slab(const bvh_cl_rayx *r, float4 lo, float4 hi, float tfar);\n",
"/* as bvh__tri_test: the ray must reach the triangle's own box by t (hits that precision made up) */\n",
"BVH_CL_FN int bvh_cl_tri_box_reached(const bvh_cl_rayx *r, __global const float *tri, float tt) {\n",
"    float3 a = vload3(0, tri), b = vload3(1, tri), c = vload3(2, tri);\n",
"    float3 lo = fmin(fmin(a, b), c), hi = fmax(fmax(a, b), c);\n",
"    return bvh_cl_slab(r, (float4)(lo, 0.0f), (float4)(hi, 0.0f), tt) != INFINITY;\n",
"}\n",
"\n",
"/* edge functions of both signs: a miss (bvh__edges_mixed) */\n",
"BVH_CL_FN int bvh_cl_edges_mixed(float U, float V, float W) {\n",
"    return (U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f);\n",
"}\n",
"/* bvh__tri_test: translated, sheared and tested in float; edge functions of both signs: a miss at\n",
"   once; else, where one is zero, all three redone as exact products (Woop et al.'s fallback) */\n",
"BVH_CL_FN int bvh_cl_tri_test(const bvh_cl_rayx *r, __global const float *tri, float tmax, float *t, float *u,\n",
"                              float *v) {\n",
"    const int kx = r->kx, ky = r->ky, kz = r->kz;\n",
"    float Az = tri[kz] - r->okz, Bz = tri[3 + kz] - r->okz, Cz = tri[6 + kz] - r->okz;\n",
"    float Ax = (tri[kx] - r->okx) - r->sx * Az, Ay = (tri[ky] - r->oky) - r->sy * Az;\n",
"    float Bx = (tri[3 + kx] - r->okx) - r->sx * Bz, By = (tri[3 + ky] - r->oky) - r->sy * Bz;\n",
"    float Cx = (tri[6 + kx] - r->okx) - r->sx * Cz, Cy = (tri[6 + ky] - r->oky) - r->sy * Cz;\n",
"    float U = Cx * By - Cy * Bx, V = Ax * Cy - Ay * Cx, W = Bx * Ay - By * Ax, det, T, tt;\n",
"    if (bvh_cl_edges_mixed(U, V, W)) return 0;\n",
"    if (U == 0.0f || V == 0.0f || W == 0.0f) {\n",
"        U = bvh_cl_diff_of_products(Cx, By, Cy, Bx);\n",
"        V = bvh_cl_diff_of_products(Ax, Cy, Ay, Cx);\n",
"        W = bvh_cl_diff_of_products(Bx, Ay, By, Ax);\n",
"        if (bvh_cl_edges_mixed(U, V, W)) return 0;\n",
"    }\n",
"    det = U + V + W;\n",
"    if (det == 0.0f) return 0;\n",
"    T = U * (r->sz * Az) + V * (r->sz * Bz) + W * (r->sz * Cz);\n",
"    tt = T / det;\n",
"    if (!(tt >= r->tmin && tt <= tmax && tt < INFINITY)) return 0;\n",
"#ifdef BVH_CL_FP64\n",
"    {\n",
"        double e1x = (double)tri[3] - tri[0], e1y = (double)tri[4] - tri[1], e1z = (double)tri[5] - tri[2];\n",
"        double e2x = (double)tri[6] - tri[0], e2y = (double)tri[7] - tri[1], e2z = (double)tri[8] - tri[2];\n",
"        if (e1y * e2z - e1z * e2y == 0.0 && e1z * e2x - e1x * e2z == 0.0 && e1x * e2y - e1y * e2x == 0.0) return 0;\n",
"    }\n",
"#else\n",
"    if (all(cross(vload3(1, tri) - vload3(0, tri), vload3(2, tri) - vload3(0, tri)) == (float3)(0.0f))) return 0;\n",
"#endif\n",
"    if (!bvh_cl_tri_box_reached(r, tri, tt)) return 0;\n",
"    *t = tt;\n",
"    *u = V / det;\n",
"    *v = W / det;\n",
"    return 1;\n",
"}\n",
"\n",
"/* ============================================================================================ */\n",
"/* == slab test and traversal (bvh__slab, bvh__traverse) ========================================= */\n",
"/* ============================================================================================ */\n",
"/* Entry distance of the ray into the box (lo, hi) if it enters before tfar, else +inf. */\n",
"BVH_CL_FN float bvh_cl_slab(const bvh_cl_rayx *r, float4 lo, float4 hi, float tfar) {\n",
"    float3 a0 = (select(lo.xyz, hi.xyz, r->neg) - r->o) * r->inv;\n",
"    float3 a1 = (select(hi.xyz, lo.xyz, r->neg) - r->o) * r->inv;\n",
"    float tn = r->tmin, tf = INFINITY;\n",
"    tn = a0.x > tn ? a0.x : tn; /* NaN (origin on the plane) leaves tn as it is */\n",
"    tf = a1.x < tf ? a1.x : tf;\n",
"    tn = a0.y > tn ? a0.y : tn;\n",
"    tf = a1.y < tf ? a1.y : tf;\n",
"    tn = a0.z > tn ? a0.z : tn;\n",
"    tf = a1.z < tf ? a1.z : tf;\n",
"    tf *= 1.0000004f; /* 1 + 2 gamma(3) */\n",
"    {                 /* as bvh__slab: lower the entry by 2^-18 of the box's distances along the dominant axis */\n",
"        float k0 = fabs(r->kz == 0 ? a0.x : r->kz == 1 ? a0.y : a0.z);\n",
"        float k1 = fabs(r->kz == 0 ? a1.x : r->kz == 1 ? a1.y : a1.z);\n",
"        tn -= (k0 > k1 ? k0 : k1) * 0x1p-18f;\n",
"    }\n",
"    tn = tn < r->tmin ? r->tmin : tn; /* as bvh__slab_t: never below tmin (a NaN stays) */\n",
"    tf = tf < tfar ? tf : tfar;\n",
"    return tn <= tf ? tn : INFINITY;\n",
"}\n",
"\n",
"typedef struct bvh_cl_hitrec {\n",
"    float t, u, v;\n",
"    uint prim;    /* BVH_CL_INVALID: miss */\n",
"    uint ref;     /* reference of the hit (index into its tree's tris) */\n",
"    uint inst;    /* the hit's instance (0 for a one-level tree) */\n",
"    uint visited; /* nodes whose box was tested, counted as bvh_intersect_counted does */\n",
"} bvh_cl_hitrec;\n",
"\n",
"/* One tree's buffers: nodes, triangles and primitive ids (a scene's top level: its nodes and the\n",
"   instance of each reference, no triangles). */\n",
"typedef struct bvh_cl_level {\n",
"    __global const uint4 *nodes;\n",
"    __global const float *tris;\n",
"    __global const uint *prims;\n",
"    uint node_count, ref_count;\n",
"} bvh_cl_level;\n",
"\n",
"/* A two-level scene (bvh_scene, uploaded by bvh_cl_scene_upload) and the world ray traced in it.\n",
"   The distinct bottom-level trees lie one after the other in nodes, tris and prims; meshes[m] =\n",
"   (first node, node count, first reference, reference count) of tree m. Instance i: inverse +\n",
"   12 i its world-to-object transform (bvh_scene.inverse), info[i] = (mask, id, tree, 0). */\n",
"typedef struct bvh_cl_scene {\n",
"    bvh_cl_level top;\n",
"    __global const uint4 *nodes;\n",
"    __global const float *tris;\n",
"    __global const uint *prims;\n",
"    __global const uint4 *meshes;\n",
"    __global const float *inverse;\n",
"    __global const uint4 *info;\n",
"    uint mesh_count, instance_count, mask;\n",
"    float3 o, d; /* the world ray */\n",
"    float tmin;\n",
"} bvh_cl_scene;\n",
"\n",
"/* The children pair (c, c + 1) of an interior node as two uint4 each; 0 when the pair lies\n",
"   outside the array (a corrupt tree: the traversal ends). */\n",
"BVH_CL_FN int bvh_cl_children(const bvh_cl_level *s, uint c, uint4 *lo0, uint4 *hi0, uint4 *lo1, uint4 *hi1) {\n",
"    if (c >= s->node_count - 1) return 0;\n",
"    *lo0 = s->nodes[2 * c];\n",
"    *hi0 = s->nodes[2 * c + 1];\n",
"    *lo1 = s->nodes[2 * c + 2];\n",
"    *hi1 = s->nodes[2 * c + 3];\n",
"    return 1;\n",
"}\n",
"\n",
"/* Enters instance i of a scene (bvh__instance_step): its tree's level, the world ray moved into\n",
"   its space by the operations of bvh_ray_transform (FP_CONTRACT is off: the same bits), set up,\n",
"   and the tree's root node. 0 when the mask skips the instance, its tree is empty, the ray in its\n",
"   space is invalid or misses the root box before tmax (the current best), or i is out of range. */\n",
"BVH_CL_FN int bvh_cl_enter(const bvh_cl_scene *sc, uint i, float tmax, bvh_cl_rayx *rx, bvh_cl_level *lv, uint4 *lo,\n",
"                           uint4 *hi) {\n",
"    __global const float *m;\n",
"    float3 o, d, wo = sc->o, wd = sc->d;\n",
"    uint4 info, mesh, a, b;\n",
"    if (i >= sc->instance_count) return 0;\n",
"    info = sc->info[i];\n",
"    if (!(info.x & sc->mask) || info.z >= sc->mesh_count) return 0;\n",
"    mesh = sc->meshes[info.z];\n",
"    if (!mesh.y) return 0;\n",
"    m = sc->inverse + 12 * (size_t)i;\n",
"    o.x = m[0] * wo.x + m[1] * wo.y + m[2] * wo.z + m[3];\n",
"    o.y = m[4] * wo.x + m[5] * wo.y + m[6] * wo.z + m[7];\n",
"    o.z = m[8] * wo.x + m[9] * wo.y + m[10] * wo.z + m[11];\n",
"    d.x = m[0] * wd.x + m[1] * wd.y + m[2] * wd.z;\n",
"    d.y = m[4] * wd.x + m[5] * wd.y + m[6] * wd.z;\n",
"    d.z = m[8] * wd.x + m[9] * wd.y + m[10] * wd.z;\n",
"    if (!bvh_cl_ray_setup(o, sc->tmin, d, tmax, rx)) return 0;\n",
"    a = sc->nodes[2 * (size_t)mesh.x];\n",
"    b = sc->nodes[2 * (size_t)mesh.x + 1];\n",
"    if (bvh_cl_slab(rx, as_float4(a), as_float4(b), tmax) == INFINITY) return 0;\n",
"    lv->nodes = sc->nodes + 2 * (size_t)mesh.x;\n",
"    lv->node_count = mesh.y;\n",
"    lv->tris = sc->tris + 9 * (size_t)mesh.z;\n",
"    lv->prims = sc->prims + mesh.z;\n",
"    lv->ref_count = mesh.w;\n",
"    *lo = a;\n",
"    *hi = b;\n",
"    return 1;\n",
"}\n",
"\n",
"/* Closest hit (any = 0) or first hit found (any = 1) of a set-up ray in [tmin, tmax], in one tree\n",
"   (sc NULL: the tree `top`) or in a scene (sc; top = sc->top). One loop for both levels, with a\n",
"   level switch: a leaf of the top level hands its instances, one by one in order, to the loop,\n",
"   which enters each (bvh_cl_enter) and walks its tree above the top level's part of the stack\n",
"   (from `floor` up), with the ray in the instance's space; when that part is empty, the loop is\n",
"   back at the top level with the world ray and takes the leaf's next instance. This is the CPU's\n",
"   order (bvh__trace_leaves with bvh__instance_step), and the best hit is theirs: the lowest\n",
"   (t, instance, triangle), t in world units because the transformed ray is not normalised.\n",
"   The stack holds `cap` entries (two trees deep for a scene). A child index or leaf range outside\n",
"   the arrays (a corrupt tree) ends the traversal, so that no read ever leaves the buffers; a tree\n",
"   deeper than the stack does too, as on the CPU. After inlining, sc is a constant: a one-level\n",
"   kernel keeps none of the scene's code. */\n",
"BVH_CL_FN void bvh_cl_traverse(const bvh_cl_level *top, const bvh_cl_scene *sc, const bvh_cl_rayx *rxw, float tmax,\n",
"                               int any, uint *stack, float *stack_t, uint cap, bvh_cl_hitrec *res) {\n",
"    bvh_cl_level lv = *top; /* the level the loop is in */\n",
"    bvh_cl_rayx rxl;        /* the ray in the current instance's space */\n",
"    const bvh_cl_rayx *rx = rxw;\n",
"    uint sp = 0, nvis = 1, floor = 0, inst = 0, next = 0, end_inst = 0;\n",
"    int bottom = 0;\n",
"    float best_t = tmax;\n",
"    uint4 lo = lv.nodes[0], hi = lv.nodes[1]; /* the current node */\n",
"    int done = bvh_cl_slab(rx, as_float4(lo), as_float4(hi), best_t) == INFINITY;\n",
"    res->prim = res->inst = BVH_CL_INVALID;\n",
"    res->ref = 0;\n",
"    res->u = res->v = 0.0f;\n",
"    while (!done) {\n",
"        int descended = 0;\n",
"        if (hi.w) {\n",
"            uint k, end = lo.w + hi.w;\n",
"            if (end > lv.ref_count || end < lo.w) break;\n",
"            if (sc && !bottom) { /* a leaf of instances: entered below, one at a time */\n",
"                next = lo.w;\n",
"                end_inst = end;\n",
"            } else {\n",
"                for (k = lo.w; k < end; k++) {\n",
"                    float t, u, v;\n",
"                    uint prim;\n",
"                    if (!bvh_cl_tri_test(rx, lv.tris + 9 * (size_t)k, best_t, &t, &u, &v)) continue;\n",
"                    prim = lv.prims[k];\n",
"                    /* ties: the lowest instance, then the lowest index */\n",
"                    if (t == best_t && (inst > res->inst || (inst == res->inst && prim > res->prim))) continue;\n",
"                    best_t = t;\n",
"                    res->u = u;\n",
"                    res->v = v;\n",
"                    res->prim = prim;\n",
"                    res->ref = k;\n",
"                    res->inst = inst;\n",
"                    if (any) {\n",
"                        done = 1;\n",
"                        break;\n",
"                    }\n",
"                }\n",
"            }\n",
"        } else {\n",
"            uint c = lo.w;\n",
"            uint4 lo0, hi0, lo1, hi1;\n",
"            float t0, t1;\n",
"            if (!bvh_cl_children(&lv, c, &lo0, &hi0, &lo1, &hi1)) break;\n",
"            t0 = bvh_cl_slab(rx, as_float4(lo0), as_float4(hi0), best_t);\n",
"            t1 = bvh_cl_slab(rx, as_float4(lo1), as_float4(hi1), best_t);\n",
"            nvis += 2;\n",
"            if (t0 != INFINITY || t1 != INFINITY) {\n",
"                uint far = c + 1;\n",
"                if (t1 < t0) {\n",
"                    float tt = t0;\n",
"                    t0 = t1;\n",
"                    t1 = tt;\n",
"                    lo = lo1;\n",
"                    hi = hi1;\n",
"                    far = c;\n",
"                } else {\n",
"                    lo = lo0;\n",
"                    hi = hi0;\n",
"                }\n",
"                if (t1 != INFINITY) {\n",
"                    if (sp == cap) break; /* a tree deeper than the validator allows */\n",
"                    stack_t[sp] = t1;\n",
"                    stack[sp++] = far;\n",
"                }\n",
"                descended = 1;\n",
"            }\n",
"        }\n",
"        if (!descended && !done) {\n",
"            for (;;) { /* the next node: of the leaf's next instance, or popped if still in reach */\n",
"                if (sc && !bottom && next < end_inst) {\n",
"                    inst = lv.prims[next++];\n",
"                    if (!bvh_cl_enter(sc, inst, best_t, &rxl, &lv, &lo, &hi)) continue;\n",
"                    nvis++;\n",
"                    bottom = 1;\n",
"                    floor = sp;\n",
"                    rx = &rxl;\n",
"                    break;\n",
"                }\n",
"                if (sc && bottom && sp == floor) { /* the instance's tree is done: back to the top */\n",
"                    bottom = 0;\n",
"                    lv = *top;\n",
"                    rx = rxw;\n",
"                    continue;\n",
"                }\n",
"                if (!sp) {\n",
"                    done = 1;\n",
"                    break;\n",
"                }\n",
"                --sp;\n",
"                if (stack_t[sp] <= best_t) {\n",
"                    lo = lv.nodes[2 * stack[sp]];\n",
"                    hi = lv.nodes[2 * stack[sp] + 1];\n",
"                    break;\n",
"                }\n",
"            }\n",
"        }\n",
"    }\n",
"    res->t = best_t;\n",
"    res->visited = nvis;\n",
"}\n",
"\n",
"/* Traces one ray in a tree; a miss leaves t = tmax, u = v = 0, prim = BVH_CL_INVALID, like\n",
"   bvh_intersect. */\n",
"BVH_CL_FN void bvh_cl_trace(const bvh_cl_level *s, float3 o, float tmin, float3 d, float tmax, int any,\n",
"                            bvh_cl_hitrec *res) {\n",
"    uint stack[BVH_CL_STACK];\n",
"    float stack_t[BVH_CL_STACK]; /* entry distance of each pushed node */\n",
"    bvh_cl_rayx rx;\n",
"    res->t = tmax;\n",
"    res->u = res->v = 0.0f;\n",
"    res->prim = BVH_CL_INVALID;\n",
"    res->ref = 0;\n",
"    res->visited = 0;\n",
"    if (!s->node_count || !bvh_cl_ray_setup(o, tmin, d, tmax, &rx)) return;\n",
"    bvh_cl_traverse(s, 0, &rx, tmax, any, stack, stack_t, BVH_CL_STACK, res);\n",
"    if (res->prim == BVH_CL_INVALID) {\n",
"        res->t = tmax;\n",
"        res->u = res->v = 0.0f;\n",
"    }\n",
"}\n",
"\n",
"/* The tree's buffers as every kernel takes them first (cl/bvh_cl.h sets them as arguments 0-4). */\n",
"#define BVH_CL_TREE_ARGS                                                                                               \\\n",
"    __global const uint4 *nodes, uint node_count, __global const float *tris, __global const uint *prims, uint ref_count\n",
"\n",
"/* The work-item's ray of a batch (origin, tmin, direction, tmax: 8 floats) traced into *res;\n",
"   0 for a work-item past the batch's count (nothing traced). */\n",
"int bvh_cl_trace_batch_ray(BVH_CL_TREE_ARGS, __global const float *rays, uint count, int any, bvh_cl_hitrec *res) {\n",
"    const uint i = (uint)get_global_id(0);\n",
"    bvh_cl_level s;\n",
"    float4 r0, r1;\n",
"    if (i >= count) return 0;\n",
"    r0 = vload4(2 * (size_t)i, rays);\n",
"    r1 = vload4(2 * (size_t)i + 1, rays);\n",
"    s.nodes = nodes;\n",
"    s.tris = tris;\n",
"    s.prims = prims;\n",
"    s.node_count = node_count;\n",
"    s.ref_count = ref_count;\n",
"    bvh_cl_trace(&s, r0.xyz, r0.w, r1.xyz, r1.w, any, res);\n",
"    return 1;\n",
"}\n",
"\n",
"/* ============================================================================================ */\n",
"/* == two-level scenes ============================================================================ */\n",
"/* ============================================================================================ */\n",
"/* The world normal of a scene hit, as bvh__scene_normal: (v1 - v0) x (v2 - v0) of the triangle in\n",
"   object space by the transpose of the world-to-object matrix, normalised, in double (float\n",
"   without cl_khr_fp64, which is not the CPU's to the bit); zero for a zero-area triangle. */\n",
"BVH_CL_FN float3 bvh_cl_scene_normal(const bvh_cl_scene *sc, const bvh_cl_hitrec *res) {\n",
"    __global const float *inv = sc->inverse + 12 * (size_t)res->inst;\n",
"    __global const float *t = sc->tris + 9 * ((size_t)sc->meshes[sc->info[res->inst].z].z + res->ref);\n",
"#ifdef BVH_CL_FP64\n",
"    double e1[3], e2[3], n[3], w[3], l;\n",
"    int k;\n",
"    for (k = 0; k < 3; k++) {\n",
"        e1[k] = (double)t[3 + k] - t[k];\n",
"        e2[k] = (double)t[6 + k] - t[k];\n",
"    }\n",
"    n[0] = e1[1] * e2[2] - e1[2] * e2[1];\n",
"    n[1] = e1[2] * e2[0] - e1[0] * e2[2];\n",
"    n[2] = e1[0] * e2[1] - e1[1] * e2[0];\n",
"    for (k = 0; k < 3; k++) w[k] = inv[k] * n[0] + inv[4 + k] * n[1] + inv[8 + k] * n[2];\n",
"    l = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);\n",
"    if (!(l > 0.0)) return (float3)(0.0f);\n",
"    return (float3)((float)(w[0] / l), (float)(w[1] / l), (float)(w[2] / l));\n",
"#else\n",
"    float3 n = cross(vload3(1, t) - vload3(0, t), vload3(2, t) - vload3(0, t)), w;\n",
"    float l;\n",
"    w.x = inv[0] * n.x + inv[4] * n.y + inv[8] * n.z;\n",
"    w.y = inv[1] * n.x + inv[5] * n.y + inv[9] * n.z;\n",
"    w.z = inv[2] * n.x + inv[6] * n.y + inv[10] * n.z;\n",
"    l = sqrt(dot(w, w));\n",
"    return l > 0.0f ? w / l : (float3)(0.0f);\n",
"#endif\n",
"}\n",
"\n",
"/* A scene's buffers as the scene kernels take them first (cl/bvh_cl.h sets arguments 0-12). */\n",
"#define BVH_CL_SCENE_ARGS                                                                                              \\\n",
"    __global const uint4 *top_nodes, uint top_node_count, __global const uint *top_prims, uint top_ref_count,          \\\n",
"        __global const uint4 *nodes, __global const float *tris, __global const uint *prims,                           \\\n",
"        __global const uint4 *meshes, uint mesh_count, __global const float *inverse, __global const uint4 *info,      \\\n",
"        uint instance_count, uint mask\n",
"\n",
"/* The work-item's ray of a scene batch traced into *res (bvh_scene_intersect / occluded); 0 for a\n",
"   work-item past the batch's count. A miss leaves t = tmax, prim = inst = BVH_CL_INVALID. */\n",
"int bvh_cl_trace_scene_ray(BVH_CL_SCENE_ARGS, __global const float *rays, uint count, int any, bvh_cl_scene *sc,\n",
"                           bvh_cl_hitrec *res) {\n",
"    const uint i = (uint)get_global_id(0);\n",
"    uint stack[2 * BVH_CL_STACK];\n",
"    float stack_t[2 * BVH_CL_STACK];\n",
"    bvh_cl_rayx rx;\n",
"    float4 r0, r1;\n",
"    if (i >= count) return 0;\n",
"    r0 = vload4(2 * (size_t)i, rays);\n",
"    r1 = vload4(2 * (size_t)i + 1, rays);\n",
"    sc->top.nodes = top_nodes;\n",
"    sc->top.tris = 0;\n",
"    sc->top.prims = top_prims;\n",
"    sc->top.node_count = top_node_count;\n",
"    sc->top.ref_count = top_ref_count;\n",
"    sc->nodes = nodes;\n",
"    sc->tris = tris;\n",
"    sc->prims = prims;\n",
"    sc->meshes = meshes;\n",
"    sc->mesh_count = mesh_count;\n",
"    sc->inverse = inverse;\n",
"    sc->info = info;\n",
"    sc->instance_count = instance_count;\n",
"    sc->mask = mask;\n",
"    sc->o = r0.xyz;\n",
"    sc->tmin = r0.w;\n",
"    sc->d = r1.xyz;\n",
"    res->prim = res->inst = BVH_CL_INVALID;\n",
"    if (top_node_count && mask && bvh_cl_ray_setup(r0.xyz, r0.w, r1.xyz, r1.w, &rx))\n",
"        bvh_cl_traverse(&sc->top, sc, &rx, r1.w, any, stack, stack_t, 2 * BVH_CL_STACK, res);\n",
"    if (res->prim == BVH_CL_INVALID) res->t = r1.w;\n",
"    return 1;\n",
"}\n",
"\n",
"/* ============================================================================================ */\n",
"/* == kernels =================================================================================== */\n",
"/* ============================================================================================ */\n",
"/* Closest hit of rays[0 .. count) into hits (bvh_intersect_batch). */\n",
"__kernel void bvh_intersect_kernel(BVH_CL_TREE_ARGS, __global const float *rays, __global uint4 *hits, uint count) {\n",
"    bvh_cl_hitrec res;\n",
"    if (bvh_cl_trace_batch_ray(nodes, node_count, tris, prims, ref_count, rays, count, 0, &res))\n",
"        hits[get_global_id(0)] = (uint4)(as_uint(res.t), as_uint(res.u), as_uint(res.v), res.prim);\n",
"}\n",
"\n",
"/* Any hit of rays[0 .. count): occluded[i] = 1 if blocked (bvh_occluded_batch). */\n",
"__kernel void bvh_occluded_kernel(BVH_CL_TREE_ARGS, __global const float *rays, __global uchar *occluded, uint count) {\n",
"    bvh_cl_hitrec res;\n",
"    if (bvh_cl_trace_batch_ray(nodes, node_count, tris, prims, ref_count, rays, count, 1, &res))\n",
"        occluded[get_global_id(0)] = res.prim != BVH_CL_INVALID ? (uchar)1 : (uchar)0;\n",
"}\n",
"\n",
"/* The arguments of bvh_cl_trace_scene_ray, passed on by the scene kernels */\n",
"#define BVH_CL_SCENE_PASS                                                                                              \\\n",
"    top_nodes, top_node_count, top_prims, top_ref_count, nodes, tris, prims, meshes, mesh_count, inverse, info,        \\\n",
"        instance_count, mask\n",
"\n",
"/* Closest hits of rays[0 .. count) in a scene for the instances `mask` selects\n",
"   (bvh_scene_intersect): hits as bvh_scene_hit, 9 words each: t, u, v, instance, id, prim, normal. */\n",
"__kernel void bvh_scene_intersect_kernel(BVH_CL_SCENE_ARGS, __global const float *rays, __global uint *hits,\n",
"                                         uint count) {\n",
"    bvh_cl_scene sc;\n",
"    bvh_cl_hitrec res;\n",
"    __global uint *h = hits + 9 * (size_t)get_global_id(0);\n",
"    float3 n = (float3)(0.0f);\n",
"    int found;\n",
"    if (!bvh_cl_trace_scene_ray(BVH_CL_SCENE_PASS, rays, count, 0, &sc, &res)) return;\n",
"    found = res.prim != BVH_CL_INVALID;\n",
"    if (found) n = bvh_cl_scene_normal(&sc, &res);\n",
"    h[0] = as_uint(res.t);\n",
"    h[1] = as_uint(found ? res.u : 0.0f);\n",
"    h[2] = as_uint(found ? res.v : 0.0f);\n",
"    h[3] = found ? res.inst : BVH_CL_INVALID;\n",
"    h[4] = found ? info[res.inst].y : BVH_CL_INVALID;\n",
"    h[5] = res.prim;\n",
"    h[6] = as_uint(n.x);\n",
"    h[7] = as_uint(n.y);\n",
"    h[8] = as_uint(n.z);\n",
"}\n",
"\n",
"/* Any hit of rays[0 .. count) in a scene: occluded[i] = 1 if blocked (bvh_scene_occluded). */\n",
"__kernel void bvh_scene_occluded_kernel(BVH_CL_SCENE_ARGS, __global const float *rays, __global uchar *occluded,\n",
"                                        uint count) {\n",
"    bvh_cl_scene sc;\n",
"    bvh_cl_hitrec res;\n",
"    if (bvh_cl_trace_scene_ray(BVH_CL_SCENE_PASS, rays, count, 1, &sc, &res))\n",
"        occluded[get_global_id(0)] = res.prim != BVH_CL_INVALID ? (uchar)1 : (uchar)0;\n",
"}\n",
"\n",
"/* The colour of a frame's pixel (ray direction d, sy as in bvh_frame_kernel): a hit grey by a\n",
"   headlight, grey * (0.2 + 0.8 |dot(n, d)|), a miss a vertical gradient. */\n",
"BVH_CL_FN uchar4 bvh_cl_shade(__global const float *tris, uint prim, uint ref, float3 d, float sy) {\n",
"    float3 c;\n",
"    if (prim != BVH_CL_INVALID) {\n",
"        __global const float *t = tris + 9 * (size_t)ref;\n",
"        float3 e1 = (float3)(t[3] - t[0], t[4] - t[1], t[5] - t[2]);\n",
"        float3 e2 = (float3)(t[6] - t[0], t[7] - t[1], t[8] - t[2]);\n",
"        float3 n = cross(e1, e2);\n",
"        float nl = sqrt(dot(n, n)), k = nl > 0.0f ? fabs(dot(n, d)) / nl : 0.0f;\n",
"        c = (float3)(0.82f, 0.82f, 0.80f) * (0.2f + 0.8f * k);\n",
"    } else {\n",
"        float g = 0.5f * (sy + 1.0f); /* 1 at the top */\n",
"        c = mix((float3)(0.16f, 0.18f, 0.22f), (float3)(0.36f, 0.44f, 0.56f), g);\n",
"    }\n",
"    c = clamp(c, 0.0f, 1.0f) * 255.0f + 0.5f;\n",
"    return (uchar4)((uchar)c.x, (uchar)c.y, (uchar)c.z, (uchar)255);\n",
"}\n",
"\n",
"/* Rows y0 .. y0 + rows - 1 of a frame seen by a bvh_camera packed as cam.s0-2 eye, s3-5 forward,\n",
"   s6-8 right, s9-b up. Ray of pixel (x, y), y = 0 at the top, exactly as bvh_camera_ray:\n",
"   d = normalize(forward + sx*right + sy*up), sx = 2(x+0.5)/w - 1, sy = 1 - 2(y+0.5)/h.\n",
"   Outputs (each may be NULL), indexed from the first row of the band: rgba (4 bytes per pixel):\n",
"   hits shaded with a headlight, grey * (0.2 + 0.8 |dot(n, d)|), misses a vertical gradient;\n",
"   hits (bvh_hit); visited (nodes visited, as bvh_intersect_counted). */\n",
"__kernel void bvh_frame_kernel(BVH_CL_TREE_ARGS, float16 cam, uint width, uint height, uint y0, uint rows,\n",
"                               __global uchar *rgba, __global uint4 *hits, __global uint *visited) {\n",
"    uint x = (uint)get_global_id(0), row = (uint)get_global_id(1), y = y0 + row;\n",
"    size_t pix = (size_t)row * width + x;\n",
"    bvh_cl_level s;\n",
"    bvh_cl_hitrec res;\n",
"    float sx, sy, l;\n",
"    float3 d;\n",
"    if (x >= width || row >= rows) return;\n",
"    s.nodes = nodes;\n",
"    s.tris = tris;\n",
"    s.prims = prims;\n",
"    s.node_count = node_count;\n",
"    s.ref_count = ref_count;\n",
"    sx = 2.0f * ((float)x + 0.5f) / (float)width - 1.0f;\n",
"    sy = 1.0f - 2.0f * ((float)y + 0.5f) / (float)height;\n",
"    d.x = cam.s3 + sx * cam.s6 + sy * cam.s9;\n",
"    d.y = cam.s4 + sx * cam.s7 + sy * cam.sa;\n",
"    d.z = cam.s5 + sx * cam.s8 + sy * cam.sb;\n",
"    l = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);\n",
"    if (l > 0.0f) {\n",
"        d.x = d.x / l;\n",
"        d.y = d.y / l;\n",
"        d.z = d.z / l;\n",
"    }\n",
"    bvh_cl_trace(&s, cam.s012, 0.0f, d, INFINITY, 0, &res);\n",
"    if (hits) hits[pix] = (uint4)(as_uint(res.t), as_uint(res.u), as_uint(res.v), res.prim);\n",
"    if (visited) visited[pix] = res.visited;\n",
"    if (rgba) vstore4(bvh_cl_shade(tris, res.prim, res.ref, d, sy), pix, rgba);\n",
"}\n",
"\n",
"/* ============================================================================================ */\n",
"/* == packets: 8 or 16 rays per work-item (frames on CPU devices) =============================== */\n",
"/* ============================================================================================ */\n",
"/* A CPU OpenCL driver such as PoCL runs the one-ray kernels above as scalar code: its vectoriser\n",
"   does not take their data-dependent loops across work-items. Here one work-item traces the\n",
"   4 x BVH_CL_PACKET_H pixels of a tile together (BVH_CL_PACKET = 4 BVH_CL_PACKET_H rays, 8 or\n",
"   16, set by the host): the rays are set up and every box test is done for all of them at once\n",
"   in vectors of that width (a vector instruction or two per step), the node is entered when any ray of the packet\n",
"   reaches it, and the triangles of a leaf are tested ray by ray with the scalar watertight test, for the rays that\n",
"   reach the leaf. The slab test is bvh_cl_slab's, step for step, so every ray gets exactly its one-ray hit (visiting a\n",
"   node more for some ray never changes a closest hit: the triangle test alone decides). The node counts of a heat map\n",
"   are the one-ray kernel's. */\n",
"#ifndef BVH_CL_PACKET\n",
"#define BVH_CL_PACKET 8\n",
"#endif\n",
"#if BVH_CL_PACKET == 16\n",
"typedef float16 bvh_pkf;\n",
"typedef int16 bvh_pki;\n",
"typedef uint16 bvh_pku;\n",
"#define BVH_PK_LOAD vload16\n",
"#define BVH_PK_STORE vstore16\n",
"#define BVH_PK_CONVERT convert_float16\n",
"#define BVH_PK_ASU as_uint16\n",
"#define BVH_PK_IOTA ((bvh_pki)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))\n",
"#define BVH_PK_OR(v) bvh_cl_or8((v).lo | (v).hi)\n",
"#elif BVH_CL_PACKET == 8\n",
"typedef float8 bvh_pkf;\n",
"typedef int8 bvh_pki;\n",
"typedef uint8 bvh_pku;\n",
"#define BVH_PK_LOAD vload8\n",
"#define BVH_PK_STORE vstore8\n",
"#define BVH_PK_CONVERT convert_float8\n",
"#define BVH_PK_ASU as_uint8\n",
"#define BVH_PK_IOTA ((bvh_pki)(0, 1, 2, 3, 4, 5, 6, 7))\n",
"#define BVH_PK_OR(v) bvh_cl_or8(v)\n",
"#else\n",
"#error \"BVH_CL_PACKET must be 8 or 16\"\n",
"#endif\n",
"#define BVH_CL_PACKET_H (BVH_CL_PACKET / 4)\n",
"BVH_CL_FN uint bvh_cl_or8(int8 v) {\n",
"    int4 a = v.lo | v.hi;\n",
"    int2 b = a.lo | a.hi;\n",
"    return (uint)(b.x | b.y);\n",
"}\n",
"/* the lanes of a mask (all bits or none per lane) as the bits of a uint */\n",
"BVH_CL_FN uint bvh_cl_bits(bvh_pki m) { return BVH_PK_OR(m & ((bvh_pki)(1) << BVH_PK_IOTA)); }\n",
"\n",
"typedef struct bvh_cl_packet {\n",
"    bvh_pkf ox, oy, oz, ix, iy, iz, tmin;\n",
"    bvh_pki nx, ny, nz; /* inv < 0 (all bits set): the near plane is the max plane */\n",
"    bvh_pki kz;         /* dominant axis, for the entry's widening */\n",
"} bvh_cl_packet;\n",
"\n",
"/* bvh_cl_slab for a packet's rays: entry distances, +inf where a ray does not enter before tfar. */\n",
"BVH_CL_FN bvh_pkf bvh_cl_slab8(const bvh_cl_packet *p, float4 lo, float4 hi, bvh_pkf tfar) {\n",
"    bvh_pkf a0x = (select((bvh_pkf)lo.x, (bvh_pkf)hi.x, p->nx) - p->ox) * p->ix;\n",
"    bvh_pkf a1x = (select((bvh_pkf)hi.x, (bvh_pkf)lo.x, p->nx) - p->ox) * p->ix;\n",
"    bvh_pkf a0y = (select((bvh_pkf)lo.y, (bvh_pkf)hi.y, p->ny) - p->oy) * p->iy;\n",
"    bvh_pkf a1y = (select((bvh_pkf)hi.y, (bvh_pkf)lo.y, p->ny) - p->oy) * p->iy;\n",
"    bvh_pkf a0z = (select((bvh_pkf)lo.z, (bvh_pkf)hi.z, p->nz) - p->oz) * p->iz;\n",
"    bvh_pkf a1z = (select((bvh_pkf)hi.z, (bvh_pkf)lo.z, p->nz) - p->oz) * p->iz;\n",
"    bvh_pkf tn = p->tmin, tf = (bvh_pkf)(INFINITY), k0, k1;\n",
"    tn = select(tn, a0x, a0x > tn); /* NaN (origin on the plane) leaves tn as it is */\n",
"    tf = select(tf, a1x, a1x < tf);\n",
"    tn = select(tn, a0y, a0y > tn);\n",
"    tf = select(tf, a1y, a1y < tf);\n",
"    tn = select(tn, a0z, a0z > tn);\n",
"    tf = select(tf, a1z, a1z < tf);\n",
"    tf *= 1.0000004f;\n",
"    k0 = fabs(select(select(a0z, a0y, p->kz == (bvh_pki)(1)), a0x, p->kz == (bvh_pki)(0)));\n",
"    k1 = fabs(select(select(a1z, a1y, p->kz == (bvh_pki)(1)), a1x, p->kz == (bvh_pki)(0)));\n",
"    tn -= select(k1, k0, k0 > k1) * 0x1p-18f;\n",
"    tn = select(tn, p->tmin, tn < p->tmin); /* never below tmin (bvh_cl_slab) */\n",
"    tf = select(tfar, tf, tf < tfar);\n",
"    return select((bvh_pkf)(INFINITY), tn, tn <= tf);\n",
"}\n",
"\n",
"/* Closest hits of the packet's rays; best[] holds each ray's tmax on entry (-inf: no ray, which\n",
"   then enters no box) and its hit distance on return, prim[] BVH_CL_INVALID on entry. */\n",
"BVH_CL_FN void bvh_cl_traverse8(const bvh_cl_level *s, const bvh_cl_packet *p, const bvh_cl_rayx *rx, float *best,\n",
"                                float *u, float *v, uint *prim, uint *ref) {\n",
"    uint stack[BVH_CL_STACK];\n",
"    bvh_pkf stack_t[BVH_CL_STACK]; /* entry distances of each pushed node */\n",
"    uint sp = 0;\n",
"    bvh_pkf bt = BVH_PK_LOAD(0, best);\n",
"    uint4 lo = s->nodes[0], hi = s->nodes[1];\n",
"    bvh_pkf te = bvh_cl_slab8(p, as_float4(lo), as_float4(hi), bt);\n",
"    if (!any(te != (bvh_pkf)(INFINITY))) return;\n",
"    for (;;) {\n",
"        int descended = 0;\n",
"        if (hi.w) {\n",
"            uint k, end = lo.w + hi.w, l;\n",
"            /* the rays that reach the leaf, as bits; ray by ray, triangle by triangle */\n",
"            uint m = bvh_cl_bits((te != (bvh_pkf)(INFINITY)) & (te <= bt));\n",
"            if (end > s->ref_count || end < lo.w) return;\n",
"            for (; m; m &= m - 1) {\n",
"                const bvh_cl_rayx *r;\n",
"                float bl;\n",
"                l = 31 - clz(m & (0u - m));\n",
"                r = &rx[l];\n",
"                bl = best[l];\n",
"                for (k = lo.w; k < end; k++) {\n",
"                    float t, tu, tv;\n",
"                    uint pr;\n",
"                    if (!bvh_cl_tri_test(r, s->tris + 9 * (size_t)k, bl, &t, &tu, &tv)) continue;\n",
"                    pr = s->prims[k];\n",
"                    if (t == bl && pr > prim[l]) continue; /* ties: lowest index */\n",
"                    bl = t;\n",
"                    u[l] = tu;\n",
"                    v[l] = tv;\n",
"                    prim[l] = pr;\n",
"                    ref[l] = k;\n",
"                }\n",
"                best[l] = bl;\n",
"            }\n",
"            bt = BVH_PK_LOAD(0, best);\n",
"        } else {\n",
"            uint c = lo.w;\n",
"            uint4 lo0, hi0, lo1, hi1;\n",
"            bvh_pkf t0, t1;\n",
"            int h0, h1;\n",
"            if (!bvh_cl_children(s, c, &lo0, &hi0, &lo1, &hi1)) return;\n",
"            t0 = bvh_cl_slab8(p, as_float4(lo0), as_float4(hi0), bt);\n",
"            t1 = bvh_cl_slab8(p, as_float4(lo1), as_float4(hi1), bt);\n",
"            h0 = any(t0 != (bvh_pkf)(INFINITY));\n",
"            h1 = any(t1 != (bvh_pkf)(INFINITY));\n",
"            if (h0 || h1) {\n",
"                /* near child first: the one more of the packet's rays enter first */\n",
"                int one = h1 && (!h0 || 2 * popcount(bvh_cl_bits(t1 < t0)) > BVH_CL_PACKET);\n",
"                if (one) {\n",
"                    lo = lo1;\n",
"                    hi = hi1;\n",
"                    te = t1;\n",
"                } else {\n",
"                    lo = lo0;\n",
"                    hi = hi0;\n",
"                    te = t0;\n",
"                }\n",
"                if (h0 && h1) {\n",
"                    if (sp == BVH_CL_STACK) return; /* a tree deeper than the validator allows */\n",
"                    stack_t[sp] = one ? t0 : t1;\n",
"                    stack[sp++] = one ? c : c + 1;\n",
"                }\n",
"                descended = 1;\n",
"            }\n",
"        }\n",
"        if (!descended) {\n",
"            for (;;) { /* pop the next node some ray still reaches before its best */\n",
"                if (!sp) return;\n",
"                --sp;\n",
"                if (any((stack_t[sp] != (bvh_pkf)(INFINITY)) & (stack_t[sp] <= bt))) {\n",
"                    lo = s->nodes[2 * stack[sp]];\n",
"                    hi = s->nodes[2 * stack[sp] + 1];\n",
"                    te = stack_t[sp];\n",
"                    break;\n",
"                }\n",
"            }\n",
"        }\n",
"    }\n",
"}\n",
"\n",
"/* bvh_cl_ray_setup for the camera rays of a packet at once (the same operations lane by\n",
"   lane, so the same bits), into the packet and the lanes' one-ray records for the triangle\n",
"   tests; a lane that is no ray (outside the image, or invalid) gets tmin = +inf and best = -inf,\n",
"   so that it enters no box. Vector divisions and square roots cost about what one scalar does. */\n",
"BVH_CL_FN void bvh_cl_packet_setup(float3 o, bvh_pkf dx, bvh_pkf dy, bvh_pkf dz, bvh_pki live, bvh_cl_packet *p,\n",
"                                   bvh_cl_rayx *rx, float *best) {\n",
"    bvh_pkf ax, ay, az, dkx, dky, dkz, sx, sy, sz, okx, oky, okz, inf = (bvh_pkf)(INFINITY);\n",
"    bvh_pki kx, ky, kz, sw, ok, t;\n",
"    float a[9][BVH_CL_PACKET];\n",
"    int m[6][BVH_CL_PACKET];\n",
"    uint l;\n",
"    ok = live & isfinite(dx) & isfinite(dy) & isfinite(dz);\n",
"    if (!(isfinite(o.x) && isfinite(o.y) && isfinite(o.z))) ok = (bvh_pki)(0);\n",
"    dx = select(dx, (bvh_pkf)(0.0f), fabs(dx) < (bvh_pkf)(FLT_MIN));\n",
"    dy = select(dy, (bvh_pkf)(0.0f), fabs(dy) < (bvh_pkf)(FLT_MIN));\n",
"    dz = select(dz, (bvh_pkf)(0.0f), fabs(dz) < (bvh_pkf)(FLT_MIN));\n",
"    ok &= (dx != (bvh_pkf)(0.0f)) | (dy != (bvh_pkf)(0.0f)) | (dz != (bvh_pkf)(0.0f));\n",
"    p->ox = (bvh_pkf)(o.x);\n",
"    p->oy = (bvh_pkf)(o.y);\n",
"    p->oz = (bvh_pkf)(o.z);\n",
"    p->ix = select((bvh_pkf)(1.0f) / dx, inf, dx == (bvh_pkf)(0.0f));\n",
"    p->iy = select((bvh_pkf)(1.0f) / dy, inf, dy == (bvh_pkf)(0.0f));\n",
"    p->iz = select((bvh_pkf)(1.0f) / dz, inf, dz == (bvh_pkf)(0.0f));\n",
"    p->nx = p->ix < (bvh_pkf)(0.0f);\n",
"    p->ny = p->iy < (bvh_pkf)(0.0f);\n",
"    p->nz = p->iz < (bvh_pkf)(0.0f);\n",
"    ax = fabs(dx);\n",
"    ay = fabs(dy);\n",
"    az = fabs(dz);\n",
"    kz = select(select((bvh_pki)(2), (bvh_pki)(1), ay > az), select((bvh_pki)(2), (bvh_pki)(0), ax > az), ax > ay);\n",
"    kx = select(kz + 1, (bvh_pki)(0), kz == (bvh_pki)(2));\n",
"    ky = select(kx + 1, (bvh_pki)(0), kx == (bvh_pki)(2));\n",
"    dkz = select(select(dz, dy, kz == (bvh_pki)(1)), dx, kz == (bvh_pki)(0));\n",
"    sw = dkz < (bvh_pkf)(0.0f);\n",
"    t = kx;\n",
"    kx = select(kx, ky, sw);\n",
"    ky = select(ky, t, sw);\n",
"    dkx = select(select(dz, dy, kx == (bvh_pki)(1)), dx, kx == (bvh_pki)(0));\n",
"    dky = select(select(dz, dy, ky == (bvh_pki)(1)), dx, ky == (bvh_pki)(0));\n",
"    sx = dkx / dkz;\n",
"    sy = dky / dkz;\n",
"    sz = (bvh_pkf)(1.0f) / dkz;\n",
"    okx = select(select(p->oz, p->oy, kx == (bvh_pki)(1)), p->ox, kx == (bvh_pki)(0));\n",
"    oky = select(select(p->oz, p->oy, ky == (bvh_pki)(1)), p->ox, ky == (bvh_pki)(0));\n",
"    okz = select(select(p->oz, p->oy, kz == (bvh_pki)(1)), p->ox, kz == (bvh_pki)(0));\n",
"    /* lanes that are no ray: finite stand-ins that enter no box */\n",
"    p->ix = select((bvh_pkf)(1.0f), p->ix, ok);\n",
"    p->iy = select((bvh_pkf)(1.0f), p->iy, ok);\n",
"    p->iz = select((bvh_pkf)(1.0f), p->iz, ok);\n",
"    p->nx &= ok;\n",
"    p->ny &= ok;\n",
"    p->nz &= ok;\n",
"    p->tmin = select(inf, (bvh_pkf)(0.0f), ok);\n",
"    p->kz = select((bvh_pki)(0), kz, ok);\n",
"    BVH_PK_STORE(p->ix, 0, a[0]);\n",
"    BVH_PK_STORE(p->iy, 0, a[1]);\n",
"    BVH_PK_STORE(p->iz, 0, a[2]);\n",
"    BVH_PK_STORE(sx, 0, a[3]);\n",
"    BVH_PK_STORE(sy, 0, a[4]);\n",
"    BVH_PK_STORE(sz, 0, a[5]);\n",
"    BVH_PK_STORE(okx, 0, a[6]);\n",
"    BVH_PK_STORE(oky, 0, a[7]);\n",
"    BVH_PK_STORE(okz, 0, a[8]);\n",
"    BVH_PK_STORE(kx, 0, m[0]);\n",
"    BVH_PK_STORE(ky, 0, m[1]);\n",
"    BVH_PK_STORE(kz, 0, m[2]);\n",
"    BVH_PK_STORE(p->nx, 0, m[3]);\n",
"    BVH_PK_STORE(p->ny, 0, m[4]);\n",
"    BVH_PK_STORE(p->nz, 0, m[5]);\n",
"    BVH_PK_STORE(select(-inf, inf, ok), 0, best);\n",
"    for (l = 0; l < BVH_CL_PACKET; l++) {\n",
"        rx[l].o = o;\n",
"        rx[l].inv = (float3)(a[0][l], a[1][l], a[2][l]);\n",
"        rx[l].neg = (int3)(m[3][l], m[4][l], m[5][l]);\n",
"        rx[l].tmin = 0.0f;\n",
"        rx[l].kx = m[0][l];\n",
"        rx[l].ky = m[1][l];\n",
"        rx[l].kz = m[2][l];\n",
"        rx[l].sx = a[3][l];\n",
"        rx[l].sy = a[4][l];\n",
"        rx[l].sz = a[5][l];\n",
"        rx[l].okx = a[6][l];\n",
"        rx[l].oky = a[7][l];\n",
"        rx[l].okz = a[8][l];\n",
"    }\n",
"}\n",
"\n",
"/* bvh_frame_kernel with a 4 x BVH_CL_PACKET_H pixel tile per work-item: work-item (gx, gy) traces\n",
"   pixels x = 4 gx .. 4 gx + 3 of rows BVH_CL_PACKET_H gy .. of the band; the same outputs as\n",
"   bvh_frame_kernel but no visited counts. */\n",
"__kernel void bvh_frame_packet_kernel(BVH_CL_TREE_ARGS, float16 cam, uint width, uint height, uint y0, uint rows,\n",
"                                      __global uchar *rgba, __global uint4 *hits) {\n",
"    uint gx = (uint)get_global_id(0), gy = (uint)get_global_id(1), l;\n",
"    bvh_cl_level s;\n",
"    bvh_cl_rayx rx[BVH_CL_PACKET];\n",
"    bvh_cl_packet p;\n",
"    float best[BVH_CL_PACKET], u[BVH_CL_PACKET], v[BVH_CL_PACKET], dxl[BVH_CL_PACKET], dyl[BVH_CL_PACKET];\n",
"    float dzl[BVH_CL_PACKET], syl[BVH_CL_PACKET];\n",
"    uint prim[BVH_CL_PACKET], ref[BVH_CL_PACKET];\n",
"    int livel[BVH_CL_PACKET];\n",
"    bvh_pku x8, row8;\n",
"    bvh_pkf sx, sy, dx, dy, dz, ln;\n",
"    bvh_pki live;\n",
"    if (4 * gx >= width || BVH_CL_PACKET_H * gy >= rows) return;\n",
"    s.nodes = nodes;\n",
"    s.tris = tris;\n",
"    s.prims = prims;\n",
"    s.node_count = node_count;\n",
"    s.ref_count = ref_count;\n",
"    x8 = (bvh_pku)(4 * gx) + BVH_PK_ASU(BVH_PK_IOTA & (bvh_pki)(3));\n",
"    row8 = (bvh_pku)(BVH_CL_PACKET_H * gy) + BVH_PK_ASU(BVH_PK_IOTA >> (bvh_pki)(2));\n",
"    live = (x8 < (bvh_pku)(width)) & (row8 < (bvh_pku)(rows));\n",
"    /* bvh_camera_ray, as in bvh_frame_kernel */\n",
"    sx = 2.0f * (BVH_PK_CONVERT(x8) + 0.5f) / (float)width - 1.0f;\n",
"    sy = 1.0f - 2.0f * (BVH_PK_CONVERT(row8 + (bvh_pku)(y0)) + 0.5f) / (float)height;\n",
"    dx = (bvh_pkf)(cam.s3) + sx * cam.s6 + sy * cam.s9;\n",
"    dy = (bvh_pkf)(cam.s4) + sx * cam.s7 + sy * cam.sa;\n",
"    dz = (bvh_pkf)(cam.s5) + sx * cam.s8 + sy * cam.sb;\n",
"    ln = sqrt(dx * dx + dy * dy + dz * dz);\n",
"    dx = select(dx, dx / ln, ln > (bvh_pkf)(0.0f));\n",
"    dy = select(dy, dy / ln, ln > (bvh_pkf)(0.0f));\n",
"    dz = select(dz, dz / ln, ln > (bvh_pkf)(0.0f));\n",
"    BVH_PK_STORE(dx, 0, dxl);\n",
"    BVH_PK_STORE(dy, 0, dyl);\n",
"    BVH_PK_STORE(dz, 0, dzl);\n",
"    BVH_PK_STORE(sy, 0, syl);\n",
"    BVH_PK_STORE(live, 0, livel);\n",
"    bvh_cl_packet_setup(cam.s012, dx, dy, dz, live, &p, rx, best);\n",
"    for (l = 0; l < BVH_CL_PACKET; l++) {\n",
"        u[l] = v[l] = 0.0f;\n",
"        prim[l] = BVH_CL_INVALID;\n",
"        ref[l] = 0;\n",
"    }\n",
"    if (node_count) bvh_cl_traverse8(&s, &p, rx, best, u, v, prim, ref);\n",
"    for (l = 0; l < BVH_CL_PACKET; l++) {\n",
"        uint x = 4 * gx + (l & 3), row = BVH_CL_PACKET_H * gy + (l >> 2);\n",
"        size_t pix = (size_t)row * width + x;\n",
"        float3 d = (float3)(dxl[l], dyl[l], dzl[l]);\n",
"        if (!livel[l]) continue;\n",
"        if (prim[l] == BVH_CL_INVALID) {\n",
"            best[l] = INFINITY;\n",
"            u[l] = v[l] = 0.0f;\n",
"        }\n",
"        if (hits) hits[pix] = (uint4)(as_uint(best[l]), as_uint(u[l]), as_uint(v[l]), prim[l]);\n",
"        if (rgba) vstore4(bvh_cl_shade(tris, prim[l], ref[l], d, syl[l]), pix, rgba);\n",
"    }\n",
"}\n",
};
/* == end of kernel source == */
/* clang-format on */
static char *bvh_cl__read_file(const bvh_allocator *al, const char *path) {
    FILE *f = fopen(path, "rb");
    char *s = NULL;
    long n;
    if (!f) return NULL;
    if (fseek(f, 0, SEEK_END) == 0 && (n = ftell(f)) >= 0 && fseek(f, 0, SEEK_SET) == 0 &&
        (s = BVH_CL__CAST(char *, bvh_cl__alloc(al, (size_t)n + 1))) != NULL) {
        if (fread(s, 1, (size_t)n, f) != (size_t)n) {
            bvh_cl__free(al, s);
            s = NULL;
        } else
            s[n] = '\0';
    }
    fclose(f);
    return s;
}

static char *bvh_cl__program_log(bvh_cl_context *c) {
    size_t n = 0;
    char *s;
    if (clGetProgramBuildInfo(c->program, c->device, CL_PROGRAM_BUILD_LOG, 0, NULL, &n) != CL_SUCCESS) n = 0;
    s = BVH_CL__CAST(char *, bvh_cl__alloc(&c->al, n + 1));
    if (!s) return NULL;
    if (n && clGetProgramBuildInfo(c->program, c->device, CL_PROGRAM_BUILD_LOG, n, s, NULL) != CL_SUCCESS) n = 0;
    s[n] = '\0';
    while (n && (s[n - 1] == '\n' || s[n - 1] == ' ' || s[n - 1] == '\0')) s[--n] = '\0';
    return s;
}

static bvh_cl_result bvh_cl__build(bvh_cl_context *c, const bvh_cl_desc *desc) {
#ifdef BVH_CL_KERNEL_PATH
    const char *path = desc->kernel_path ? desc->kernel_path : BVH_CL_KERNEL_PATH;
#else
    const char *path = desc->kernel_path;
#endif
    const char *extra = desc->build_options ? desc->build_options : "";
    char *file = NULL, *opts;
    const char *src = desc->kernel_source;
    char cver[64] = "";
    cl_device_fp_config sp = 0;
    size_t len;
    cl_int err;
    int i;
    if (!src && path) {
        src = file = bvh_cl__read_file(&c->al, path);
        if (!src) {
            bvh_cl__logf(desc, "cannot read the kernel source \"%s\"", path);
            return BVH_CL_ERROR_KERNEL_NOT_FOUND;
        }
    }
    if (src) {
        len = strlen(src);
        c->program = clCreateProgramWithSource(c->context, 1, &src, &len, &err);
    } else { /* the kernel this header holds */
        const char *const *held = bvh_cl__source;
        const char **lines;
        memcpy(&lines, &held, sizeof lines); /* drops const (C++ refuses the cast): OpenCL only reads */
        c->program = clCreateProgramWithSource(c->context, (cl_uint)(sizeof bvh_cl__source / sizeof bvh_cl__source[0]),
                                               lines, NULL, &err);
    }
    bvh_cl__free(&c->al, file);
    if (err != CL_SUCCESS) {
        bvh_cl__logf(desc, "clCreateProgramWithSource: %d", (int)err);
        return bvh_cl__fail(c, err, "clCreateProgramWithSource");
    }
    /* OpenCL C 1.2 when the device has it (the kernels need nothing newer than 1.1); correctly
       rounded division and sqrt when the device offers them, for hits identical to the CPU's */
    clGetDeviceInfo(c->device, CL_DEVICE_OPENCL_C_VERSION, sizeof cver - 1, cver, NULL);
    clGetDeviceInfo(c->device, CL_DEVICE_SINGLE_FP_CONFIG, sizeof sp, &sp, NULL);
    opts = BVH_CL__CAST(char *, bvh_cl__alloc(&c->al, strlen(extra) + 128));
    if (!opts) return BVH_CL_ERROR_OUT_OF_RESOURCES;
    sprintf(opts, "%s%s-DBVH_MAX_DEPTH=%d -DBVH_CL_PACKET=%d %s",
            strncmp(cver, "OpenCL C 1.0", 12) && strncmp(cver, "OpenCL C 1.1", 12) ? "-cl-std=CL1.2 " : "",
            (sp & CL_FP_CORRECTLY_ROUNDED_DIVIDE_SQRT) ? "-cl-fp32-correctly-rounded-divide-sqrt " : "",
            (int)BVH_MAX_DEPTH, c->frame_rays > 1 ? c->frame_rays : 8, extra);
    err = clBuildProgram(c->program, 1, &c->device, opts, NULL, NULL);
    bvh_cl__free(&c->al, opts);
    c->build_log = bvh_cl__program_log(c);
    if (err != CL_SUCCESS) {
        bvh_cl__logf(desc, "%s", c->build_log && *c->build_log ? c->build_log : "clBuildProgram failed, no log");
        if (err == CL_BUILD_PROGRAM_FAILURE || err == CL_INVALID_BUILD_OPTIONS) return BVH_CL_ERROR_BUILD_FAILED;
        return bvh_cl__fail(c, err, "clBuildProgram");
    }
    for (i = 0; i < BVH_CL__K_COUNT; i++) {
        c->kernels[i] = clCreateKernel(c->program, bvh_cl__kernel_names[i], &err);
        if (err != CL_SUCCESS) {
            bvh_cl__logf(desc, "clCreateKernel(%s): %d", bvh_cl__kernel_names[i], (int)err);
            return err == CL_INVALID_KERNEL_NAME ? BVH_CL_ERROR_BUILD_FAILED : bvh_cl__fail(c, err, "clCreateKernel");
        }
    }
    return BVH_CL_SUCCESS;
}

/* ============================================================================================ */
/* == context ===================================================================================== */
/* ============================================================================================ */
BVH_CL_API void bvh_cl_destroy(bvh_cl_context *c) {
    bvh_allocator al;
    int i;
    if (!c) return;
    al = c->al;
    for (i = 0; i < BVH_CL__S_COUNT; i++)
        if (c->scratch[i]) clReleaseMemObject(c->scratch[i]);
    for (i = 0; i < BVH_CL__K_COUNT; i++)
        if (c->kernels[i]) clReleaseKernel(c->kernels[i]);
    if (c->program) clReleaseProgram(c->program);
    if (c->queue) clReleaseCommandQueue(c->queue);
    if (c->context) clReleaseContext(c->context);
    bvh_cl__free(&al, c->build_log);
    bvh_cl__free(&al, c);
}

/* the work-group size: desc.local_size (64), within what the device and every kernel allow */
static void bvh_cl__local_size(bvh_cl_context *c, size_t want) {
    size_t dev = 0, k;
    int i;
    c->local_size = want ? want : 64;
    if (clGetDeviceInfo(c->device, CL_DEVICE_MAX_WORK_GROUP_SIZE, sizeof dev, &dev, NULL) == CL_SUCCESS && dev &&
        c->local_size > dev)
        c->local_size = dev;
    c->max_items[0] = c->max_items[1] = c->max_items[2] = 0;
    clGetDeviceInfo(c->device, CL_DEVICE_MAX_WORK_ITEM_SIZES, sizeof c->max_items, c->max_items, NULL);
    if (c->max_items[0] && c->local_size > c->max_items[0]) c->local_size = c->max_items[0];
    for (i = 0; i < BVH_CL__K_COUNT; i++) {
        if (clGetKernelWorkGroupInfo(c->kernels[i], c->device, CL_KERNEL_WORK_GROUP_SIZE, sizeof k, &k, NULL) ==
                CL_SUCCESS &&
            k && c->local_size > k)
            c->local_size = k;
    }
}

BVH_CL_API bvh_cl_result bvh_cl_create(bvh_cl_context **out, const bvh_cl_desc *desc) {
    bvh_cl_desc zero;
    bvh_cl_context *c;
    bvh_cl_result r;
    cl_context_properties props[3];
    cl_int err = CL_SUCCESS;
    if (!out) return BVH_CL_ERROR_INVALID_ARGUMENT;
    *out = NULL;
    if (!desc) {
        memset(&zero, 0, sizeof zero);
        desc = &zero;
    }
    if (desc->log && desc->log_size) desc->log[0] = '\0';
    if (desc->frame_rays != 0 && desc->frame_rays != 1 && desc->frame_rays != 8 && desc->frame_rays != 16)
        return BVH_CL_ERROR_INVALID_ARGUMENT;
    if (!desc->allocator.alloc != !desc->allocator.free) return BVH_CL_ERROR_INVALID_ARGUMENT; /* both or none */
    c = BVH_CL__CAST(bvh_cl_context *, bvh_cl__alloc(&desc->allocator, sizeof *c));
    if (!c) return BVH_CL_ERROR_OUT_OF_RESOURCES;
    memset(c, 0, sizeof *c);
    c->al = desc->allocator;
    r = bvh_cl__pick(desc, c);
    if (r == BVH_CL_SUCCESS) {
        props[0] = CL_CONTEXT_PLATFORM;
        props[1] = (cl_context_properties)c->platform;
        props[2] = 0;
        c->context = clCreateContext(props, 1, &c->device, NULL, NULL, &err);
        if (err != CL_SUCCESS) {
            bvh_cl__logf(desc, "clCreateContext: %d", (int)err);
            r = bvh_cl__fail(c, err, "clCreateContext");
        }
    }
    if (r == BVH_CL_SUCCESS) {
        c->queue = clCreateCommandQueue(c->context, c->device, CL_QUEUE_PROFILING_ENABLE, &err);
        if (err != CL_SUCCESS) {
            bvh_cl__logf(desc, "clCreateCommandQueue: %d", (int)err);
            r = bvh_cl__fail(c, err, "clCreateCommandQueue");
        }
    }
    c->frame_rays = desc->frame_rays ? desc->frame_rays : c->info.is_gpu ? 1 : BVH_CL__PACKET_DEFAULT;
    if (r == BVH_CL_SUCCESS) r = bvh_cl__build(c, desc);
    if (r != BVH_CL_SUCCESS) {
        bvh_cl_destroy(c);
        return r;
    }
    if (desc->max_alloc && desc->max_alloc < c->info.max_alloc) c->info.max_alloc = desc->max_alloc;
    c->max_alloc = c->info.max_alloc > (uint64_t)(size_t)-1 ? (size_t)-1 : (size_t)c->info.max_alloc;
    bvh_cl__local_size(c, desc->local_size);
    *out = c;
    return BVH_CL_SUCCESS;
}

BVH_CL_API bvh_cl_result bvh_cl_get_info(const bvh_cl_context *c, bvh_cl_device_info *out) {
    if (!c || !out) return BVH_CL_ERROR_INVALID_ARGUMENT;
    *out = c->info;
    return BVH_CL_SUCCESS;
}
BVH_CL_API const char *bvh_cl_build_log(const bvh_cl_context *c) { return c && c->build_log ? c->build_log : ""; }
BVH_CL_API int bvh_cl_last_error(const bvh_cl_context *c, const char **call) {
    if (call) *call = c && c->last_call ? c->last_call : "";
    return c ? (int)c->last_error : 0;
}
BVH_CL_API double bvh_cl_last_kernel_ms(const bvh_cl_context *c) { return c ? c->kernel_ms : 0.0; }

/* ============================================================================================ */
/* == trees ======================================================================================= */
/* ============================================================================================ */
BVH_CL_API void bvh_cl_tree_free(bvh_cl_tree *t) {
    if (!t) return;
    if (t->nodes) clReleaseMemObject(t->nodes);
    if (t->tris) clReleaseMemObject(t->tris);
    if (t->prims) clReleaseMemObject(t->prims);
    bvh_cl__free(&t->al, t);
}

static cl_mem bvh_cl__buffer(bvh_cl_context *c, size_t size, const void *data, cl_int *err) {
    void *p;
    memcpy(&p, &data, sizeof p); /* drops const: CL_MEM_COPY_HOST_PTR only reads */
    if (!size) return clCreateBuffer(c->context, CL_MEM_READ_ONLY, 32, NULL, err); /* empty tree */
    return clCreateBuffer(c->context, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, size, p, err);
}

BVH_CL_API bvh_cl_result bvh_cl_upload(bvh_cl_context *c, const bvh_tree *tree, bvh_cl_tree **out) {
    bvh_cl_tree *t;
    size_t nb, tb, pb;
    cl_int err = CL_SUCCESS;
    if (out) *out = NULL;
    if (!c || !tree || !out) return BVH_CL_ERROR_INVALID_ARGUMENT;
    if (tree->node_count && (!tree->nodes || !tree->prims || !tree->tris)) return BVH_CL_ERROR_INVALID_ARGUMENT;
    nb = tree->node_count ? (size_t)tree->node_count * sizeof(bvh_node) : 0;
    tb = tree->node_count ? (size_t)tree->ref_count * 9 * sizeof(float) : 0;
    pb = tree->node_count ? (size_t)tree->ref_count * sizeof(uint32_t) : 0;
    if (nb > c->max_alloc || tb > c->max_alloc || pb > c->max_alloc ||
        (c->info.global_mem && (uint64_t)nb + tb + pb > c->info.global_mem))
        return BVH_CL_ERROR_BUFFER_TOO_LARGE;
    t = BVH_CL__CAST(bvh_cl_tree *, bvh_cl__alloc(&c->al, sizeof *t));
    if (!t) return BVH_CL_ERROR_OUT_OF_RESOURCES;
    memset(t, 0, sizeof *t);
    t->al = c->al;
    t->ctx = c;
    t->node_count = tree->node_count;
    t->ref_count = tree->node_count ? tree->ref_count : 0;
    t->nodes = bvh_cl__buffer(c, nb, tree->nodes, &err);
    if (err == CL_SUCCESS) t->tris = bvh_cl__buffer(c, tb, tree->tris, &err);
    if (err == CL_SUCCESS) t->prims = bvh_cl__buffer(c, pb, tree->prims, &err);
    if (err != CL_SUCCESS) {
        bvh_cl_tree_free(t);
        return bvh_cl__fail(c, err, "clCreateBuffer");
    }
    *out = t;
    return BVH_CL_SUCCESS;
}

/* ============================================================================================ */
/* == launches ===================================================================================== */
/* ============================================================================================ */
/* a scratch buffer of at least `size` bytes in slot i */
static bvh_cl_result bvh_cl__scratch(bvh_cl_context *c, int i, size_t size, cl_mem_flags flags) {
    cl_int err;
    if (c->scratch[i] && c->scratch_size[i] >= size) return BVH_CL_SUCCESS;
    if (c->scratch[i]) clReleaseMemObject(c->scratch[i]);
    c->scratch[i] = NULL;
    c->scratch_size[i] = 0;
    if (size > c->max_alloc) return BVH_CL_ERROR_BUFFER_TOO_LARGE;
    c->scratch[i] = clCreateBuffer(c->context, flags, size, NULL, &err);
    if (err != CL_SUCCESS) {
        c->scratch[i] = NULL;
        return bvh_cl__fail(c, err, "clCreateBuffer");
    }
    c->scratch_size[i] = size;
    return BVH_CL_SUCCESS;
}

/* arguments 0..4 of every kernel: the tree */
static cl_int bvh_cl__tree_args(cl_kernel k, const bvh_cl_tree *t) {
    cl_int e = clSetKernelArg(k, 0, sizeof(cl_mem), &t->nodes);
    e |= clSetKernelArg(k, 1, sizeof(cl_uint), &t->node_count);
    e |= clSetKernelArg(k, 2, sizeof(cl_mem), &t->tris);
    e |= clSetKernelArg(k, 3, sizeof(cl_mem), &t->prims);
    e |= clSetKernelArg(k, 4, sizeof(cl_uint), &t->ref_count);
    return e == CL_SUCCESS ? CL_SUCCESS : CL_INVALID_KERNEL_ARGS;
}

static void bvh_cl__time(bvh_cl_context *c, cl_event ev) {
    cl_ulong a = 0, b = 0;
    if (clGetEventProfilingInfo(ev, CL_PROFILING_COMMAND_START, sizeof a, &a, NULL) == CL_SUCCESS &&
        clGetEventProfilingInfo(ev, CL_PROFILING_COMMAND_END, sizeof b, &b, NULL) == CL_SUCCESS && b > a)
        c->kernel_ms += (double)(b - a) * 1e-6;
    clReleaseEvent(ev);
}
/* After non-blocking reads that returned err: waits for the queue even when one failed (so that
   none is left writing into the caller's memory), times ev, and returns the first error. */
static cl_int bvh_cl__finish_reads(bvh_cl_context *c, cl_int err, cl_event ev) {
    const cl_int fin = clFinish(c->queue);
    bvh_cl__time(c, ev);
    return err != CL_SUCCESS ? err : fin;
}

static size_t bvh_cl__round_up(size_t n, size_t m) { return (n + m - 1) / m * m; }

/* rays in chunks that fit the device; out_elem bytes of output per ray. The kernel's arguments
   before `first` (the tree or scene) are set; it takes the rays, the output and the count next. */
static bvh_cl_result bvh_cl__batch(bvh_cl_context *c, cl_kernel k, cl_uint first, const bvh_ray *rays, void *out,
                                   size_t out_elem, size_t count) {
    size_t chunk = c->max_alloc / (out_elem > sizeof(bvh_ray) ? out_elem : sizeof(bvh_ray)), i, n, global;
    size_t local = c->local_size;
    bvh_cl_result r;
    cl_int err;
    cl_event ev;
    cl_uint nn;
    c->kernel_ms = 0.0;
    if (!count) return BVH_CL_SUCCESS;
    if (!chunk) return BVH_CL_ERROR_BUFFER_TOO_LARGE;
    if (chunk > BVH_CL__CHUNK) chunk = BVH_CL__CHUNK;
    if (chunk > count) chunk = count;
    if ((r = bvh_cl__scratch(c, BVH_CL__S_IN, chunk * sizeof(bvh_ray), CL_MEM_READ_ONLY)) != BVH_CL_SUCCESS) return r;
    if ((r = bvh_cl__scratch(c, BVH_CL__S_OUT, chunk * out_elem, CL_MEM_WRITE_ONLY)) != BVH_CL_SUCCESS) return r;
    for (i = 0; i < count; i += n) {
        n = count - i < chunk ? count - i : chunk;
        nn = (cl_uint)n;
        global = bvh_cl__round_up(n, local);
        err = clEnqueueWriteBuffer(c->queue, c->scratch[BVH_CL__S_IN], CL_FALSE, 0, n * sizeof(bvh_ray), rays + i, 0,
                                   NULL, NULL);
        if (err != CL_SUCCESS) return bvh_cl__fail(c, err, "clEnqueueWriteBuffer");
        err = clSetKernelArg(k, first, sizeof(cl_mem), &c->scratch[BVH_CL__S_IN]);
        err |= clSetKernelArg(k, first + 1, sizeof(cl_mem), &c->scratch[BVH_CL__S_OUT]);
        err |= clSetKernelArg(k, first + 2, sizeof(cl_uint), &nn);
        if (err != CL_SUCCESS) return bvh_cl__fail(c, CL_INVALID_KERNEL_ARGS, "clSetKernelArg");
        err = clEnqueueNDRangeKernel(c->queue, k, 1, NULL, &global, &local, 0, NULL, &ev);
        if (err != CL_SUCCESS) {
            clFinish(c->queue);
            return bvh_cl__fail(c, err, "clEnqueueNDRangeKernel");
        }
        /* a non-blocking read and clFinish: PoCL's blocking read spins on a core the kernel needs */
        err = clEnqueueReadBuffer(c->queue, c->scratch[BVH_CL__S_OUT], CL_FALSE, 0, n * out_elem,
                                  BVH_CL__CAST(char *, out) + i * out_elem, 0, NULL, NULL);
        if ((err = bvh_cl__finish_reads(c, err, ev)) != CL_SUCCESS) return bvh_cl__fail(c, err, "clEnqueueReadBuffer");
    }
    return BVH_CL_SUCCESS;
}

/* a tree's batch: its arguments 0..4, then the rays */
static bvh_cl_result bvh_cl__tree_batch(bvh_cl_tree *t, const bvh_ray *rays, void *out, size_t out_elem, size_t count,
                                        int kernel) {
    cl_kernel k = t->ctx->kernels[kernel];
    cl_int err = bvh_cl__tree_args(k, t);
    if (err != CL_SUCCESS) return bvh_cl__fail(t->ctx, err, "clSetKernelArg");
    return bvh_cl__batch(t->ctx, k, 5, rays, out, out_elem, count);
}
BVH_CL_API bvh_cl_result bvh_cl_intersect(bvh_cl_tree *t, const bvh_ray *rays, bvh_hit *hits, size_t count) {
    if (!t || (count && (!rays || !hits))) return BVH_CL_ERROR_INVALID_ARGUMENT;
    return bvh_cl__tree_batch(t, rays, hits, sizeof(bvh_hit), count, BVH_CL__K_CLOSEST);
}
BVH_CL_API bvh_cl_result bvh_cl_occluded(bvh_cl_tree *t, const bvh_ray *rays, uint8_t *occluded, size_t count) {
    if (!t || (count && (!rays || !occluded))) return BVH_CL_ERROR_INVALID_ARGUMENT;
    return bvh_cl__tree_batch(t, rays, occluded, 1, count, BVH_CL__K_ANY);
}

/* frames in bands of rows that fit the device */
BVH_CL_API bvh_cl_result bvh_cl_render_frame(bvh_cl_tree *t, const bvh_camera *cam, uint8_t *rgba, bvh_hit *hits,
                                             uint32_t *visited) {
    static const size_t elem[3] = {4, sizeof(bvh_hit), sizeof(uint32_t)};
    static const int slot[3] = {BVH_CL__S_RGBA, BVH_CL__S_OUT, BVH_CL__S_VISITED};
    void *dst[3];
    bvh_cl_context *c;
    cl_kernel k;
    cl_float16 cv;
    cl_uint w, h, y0, rows, band;
    size_t per = 1, lx, ly, local[2], global[2];
    bvh_cl_result r;
    cl_int err;
    cl_event ev;
    int i, packets;
    if (!t || !cam) return BVH_CL_ERROR_INVALID_ARGUMENT;
    c = t->ctx;
    packets = c->frame_rays > 1 && !visited ? c->frame_rays / 4 : 0; /* tile height */
    k = c->kernels[packets ? BVH_CL__K_FRAME8 : BVH_CL__K_FRAME];
    c->kernel_ms = 0.0;
    w = cam->width;
    h = cam->height;
    if (!w || !h) return BVH_CL_SUCCESS;
    dst[0] = rgba;
    dst[1] = hits;
    dst[2] = visited;
    for (i = 0; i < 3; i++)
        if (dst[i] && elem[i] > per) per = elem[i];
    band = (cl_uint)(BVH_CL__CHUNK / w > 0 ? BVH_CL__CHUNK / w : 1);
    if (band > h) band = h;
    if ((size_t)band * w * per > c->max_alloc) band = (cl_uint)(c->max_alloc / ((size_t)w * per));
    if (!band) return BVH_CL_ERROR_BUFFER_TOO_LARGE;
    for (i = 0; i < 3; i++) {
        if (!dst[i]) continue;
        r = bvh_cl__scratch(c, slot[i], (size_t)band * w * elem[i], CL_MEM_WRITE_ONLY);
        if (r != BVH_CL_SUCCESS) return r;
    }
    memset(&cv, 0, sizeof cv);
    memcpy(&cv.s[0], &cam->eye.x, 3 * sizeof(float));
    memcpy(&cv.s[3], &cam->forward.x, 3 * sizeof(float));
    memcpy(&cv.s[6], &cam->right.x, 3 * sizeof(float));
    memcpy(&cv.s[9], &cam->up.x, 3 * sizeof(float));
    err = bvh_cl__tree_args(k, t);
    err |= clSetKernelArg(k, 5, sizeof cv, &cv);
    err |= clSetKernelArg(k, 6, sizeof(cl_uint), &w);
    err |= clSetKernelArg(k, 7, sizeof(cl_uint), &h);
    for (i = 0; i < (packets ? 2 : 3); i++)
        err |= clSetKernelArg(k, 10 + i, sizeof(cl_mem), dst[i] ? &c->scratch[slot[i]] : NULL);
    if (err != CL_SUCCESS) return bvh_cl__fail(c, CL_INVALID_KERNEL_ARGS, "clSetKernelArg");
    lx = c->local_size >= 8 && c->local_size % 8 == 0 ? 8 : c->local_size; /* 8 x 8 tiles by default */
    ly = c->local_size / lx;
    while (c->max_items[1] && ly > c->max_items[1]) {
        lx *= 2;
        ly /= 2;
    } /* 8 x 64 may be too tall */
    local[0] = lx;
    local[1] = ly;
    for (y0 = 0; y0 < h; y0 += rows) {
        rows = h - y0 < band ? h - y0 : band;
        /* packets: a work-item per 4 x `packets` pixels */
        global[0] = bvh_cl__round_up(packets ? (w + 3) / 4 : w, lx);
        global[1] = bvh_cl__round_up(packets ? (rows + packets - 1) / packets : rows, ly);
        err = clSetKernelArg(k, 8, sizeof(cl_uint), &y0);
        err |= clSetKernelArg(k, 9, sizeof(cl_uint), &rows);
        if (err != CL_SUCCESS) return bvh_cl__fail(c, CL_INVALID_KERNEL_ARGS, "clSetKernelArg");
        err = clEnqueueNDRangeKernel(c->queue, k, 2, NULL, global, local, 0, NULL, &ev);
        if (err != CL_SUCCESS) {
            clFinish(c->queue);
            return bvh_cl__fail(c, err, "clEnqueueNDRangeKernel");
        }
        for (i = 0; i < 3 && err == CL_SUCCESS; i++) {
            if (!dst[i]) continue;
            err = clEnqueueReadBuffer(c->queue, c->scratch[slot[i]], CL_FALSE, 0, (size_t)rows * w * elem[i],
                                      BVH_CL__CAST(char *, dst[i]) + (size_t)y0 * w * elem[i], 0, NULL, NULL);
        }
        if ((err = bvh_cl__finish_reads(c, err, ev)) != CL_SUCCESS) return bvh_cl__fail(c, err, "clEnqueueReadBuffer");
    }
    return BVH_CL_SUCCESS;
}

/* ============================================================================================ */
/* == two-level scenes ============================================================================= */
/* ============================================================================================ */
/* Kernels index one buffer per kind, so the distinct bottom-level trees are laid one after the
   other in it (an OpenCL 1.2 kernel cannot take an array of buffers); meshes[m] gives tree m's first
   node and reference there. The top-level tree (a box tree: no triangles) and the per-instance
   arrays have their own buffers. */
BVH_CL_API void bvh_cl_scene_free(bvh_cl_scene *s) {
    int i;
    if (!s) return;
    for (i = 0; i < BVH_CL__B_COUNT; i++)
        if (s->buf[i]) clReleaseMemObject(s->buf[i]);
    bvh_cl__free(&s->al, s);
}

/* The checks of bvh_cl_scene_upload, and each distinct tree (one instance's) in trees[m]. */
static bvh_cl_result bvh_cl__scene_trees(const bvh_scene *sc, const bvh_tree **trees) {
    uint32_t i, m;
    for (m = 0; m < sc->mesh_count; m++) trees[m] = NULL;
    for (i = 0; i < sc->instance_count; i++) {
        const bvh_tree *t = sc->instances[i].tree;
        m = sc->mesh[i];
        if (m >= sc->mesh_count || !t || sc->instances[i].custom ||
            (t->node_count && (!t->nodes || !t->prims || !t->tris)))
            return BVH_CL_ERROR_INVALID_ARGUMENT;
        trees[m] = t;
    }
    return BVH_CL_SUCCESS;
}

/* The arrays in host memory and the sizes of the bottom-level buffers: meshes (4 words per tree:
   first node, node count, first reference, reference count), info (4 words per instance: mask, id,
   tree, 0). BUFFER_TOO_LARGE when the trees' nodes or references do not fit 32-bit offsets. */
static bvh_cl_result bvh_cl__scene_tables(const bvh_scene *sc, const bvh_tree *const *trees, cl_uint *meshes,
                                          cl_uint *info, size_t *nodes, size_t *refs) {
    uint32_t i, m;
    *nodes = *refs = 0;
    for (m = 0; m < sc->mesh_count; m++) {
        const bvh_tree *t = trees[m];
        meshes[4 * m] = (cl_uint)*nodes;
        meshes[4 * m + 1] = t ? t->node_count : 0;
        meshes[4 * m + 2] = (cl_uint)*refs;
        meshes[4 * m + 3] = t && t->node_count ? t->ref_count : 0;
        *nodes += meshes[4 * m + 1];
        *refs += meshes[4 * m + 3];
        if (*nodes > 0xFFFFFFFFu || *refs > 0xFFFFFFFFu) return BVH_CL_ERROR_BUFFER_TOO_LARGE;
    }
    for (i = 0; i < sc->instance_count; i++) {
        info[4 * i] = sc->instances[i].mask;
        info[4 * i + 1] = sc->instances[i].id;
        info[4 * i + 2] = sc->mesh[i];
        info[4 * i + 3] = 0;
    }
    return BVH_CL_SUCCESS;
}

/* Each tree's nodes, triangles and ids written at its offsets (non-blocking, then one wait). */
static cl_int bvh_cl__scene_write(bvh_cl_context *c, bvh_cl_scene *s, const bvh_tree *const *trees,
                                  const cl_uint *meshes) {
    cl_int err = CL_SUCCESS;
    uint32_t m;
    for (m = 0; m < s->mesh_count && err == CL_SUCCESS; m++) {
        const bvh_tree *t = trees[m];
        size_t n0 = meshes[4 * m], r0 = meshes[4 * m + 2];
        if (!t || !t->node_count) continue;
        err = clEnqueueWriteBuffer(c->queue, s->buf[BVH_CL__B_NODES], CL_FALSE, n0 * sizeof(bvh_node),
                                   (size_t)t->node_count * sizeof(bvh_node), t->nodes, 0, NULL, NULL);
        if (err == CL_SUCCESS)
            err = clEnqueueWriteBuffer(c->queue, s->buf[BVH_CL__B_TRIS], CL_FALSE, r0 * 9 * sizeof(float),
                                       (size_t)t->ref_count * 9 * sizeof(float), t->tris, 0, NULL, NULL);
        if (err == CL_SUCCESS)
            err = clEnqueueWriteBuffer(c->queue, s->buf[BVH_CL__B_PRIMS], CL_FALSE, r0 * sizeof(uint32_t),
                                       (size_t)t->ref_count * sizeof(uint32_t), t->prims, 0, NULL, NULL);
    }
    {
        const cl_int fin = clFinish(c->queue); /* the trees' memory may go when the call returns */
        return err != CL_SUCCESS ? err : fin;
    }
}

BVH_CL_API bvh_cl_result bvh_cl_scene_upload(bvh_cl_context *c, const bvh_scene *sc, bvh_cl_scene **out) {
    const bvh_tree **trees;
    cl_uint *meshes, *info;
    bvh_cl_scene *s = NULL;
    size_t nodes = 0, refs = 0, size[BVH_CL__B_COUNT], total = 0, top_refs;
    const void *data[BVH_CL__B_COUNT];
    const char *call = "clCreateBuffer";
    bvh_cl_result r;
    cl_int err = CL_SUCCESS;
    int i;
    if (out) *out = NULL;
    if (!c || !sc || !out) return BVH_CL_ERROR_INVALID_ARGUMENT;
    if ((sc->instance_count && (!sc->instances || !sc->inverse || !sc->mesh)) ||
        (sc->top.node_count && (!sc->top.nodes || !sc->top.prims)))
        return BVH_CL_ERROR_INVALID_ARGUMENT;
    top_refs = sc->top.node_count ? sc->top.ref_count : 0;
    trees = BVH_CL__CAST(const bvh_tree **, bvh_cl__alloc(&c->al, ((size_t)sc->mesh_count + 1) * sizeof *trees));
    meshes = BVH_CL__CAST(cl_uint *, bvh_cl__alloc(&c->al, ((size_t)sc->mesh_count + 1) * 4 * sizeof(cl_uint)));
    info = BVH_CL__CAST(cl_uint *, bvh_cl__alloc(&c->al, ((size_t)sc->instance_count + 1) * 4 * sizeof(cl_uint)));
    r = trees && meshes && info ? bvh_cl__scene_trees(sc, trees) : BVH_CL_ERROR_OUT_OF_RESOURCES;
    if (r == BVH_CL_SUCCESS) r = bvh_cl__scene_tables(sc, trees, meshes, info, &nodes, &refs);
    size[BVH_CL__B_TOP_NODES] = (size_t)sc->top.node_count * sizeof(bvh_node);
    size[BVH_CL__B_TOP_PRIMS] = top_refs * sizeof(uint32_t);
    size[BVH_CL__B_NODES] = nodes * sizeof(bvh_node);
    size[BVH_CL__B_TRIS] = refs * 9 * sizeof(float);
    size[BVH_CL__B_PRIMS] = refs * sizeof(uint32_t);
    size[BVH_CL__B_MESHES] = (size_t)sc->mesh_count * 4 * sizeof(cl_uint);
    size[BVH_CL__B_INVERSE] = (size_t)sc->instance_count * 12 * sizeof(float);
    size[BVH_CL__B_INFO] = (size_t)sc->instance_count * 4 * sizeof(cl_uint);
    data[BVH_CL__B_TOP_NODES] = sc->top.nodes;
    data[BVH_CL__B_TOP_PRIMS] = sc->top.prims;
    data[BVH_CL__B_NODES] = data[BVH_CL__B_TRIS] = data[BVH_CL__B_PRIMS] = NULL; /* written per tree */
    data[BVH_CL__B_MESHES] = meshes;
    data[BVH_CL__B_INVERSE] = sc->inverse;
    data[BVH_CL__B_INFO] = info;
    for (i = 0; i < BVH_CL__B_COUNT && r == BVH_CL_SUCCESS; i++) {
        total += size[i];
        if (size[i] > c->max_alloc || (c->info.global_mem && total > c->info.global_mem))
            r = BVH_CL_ERROR_BUFFER_TOO_LARGE;
    }
    if (r == BVH_CL_SUCCESS) {
        s = BVH_CL__CAST(bvh_cl_scene *, bvh_cl__alloc(&c->al, sizeof *s));
        if (!s) r = BVH_CL_ERROR_OUT_OF_RESOURCES;
    }
    if (r == BVH_CL_SUCCESS) {
        memset(s, 0, sizeof *s);
        s->al = c->al;
        s->ctx = c;
        s->top_node_count = sc->top.node_count;
        s->top_ref_count = (cl_uint)top_refs;
        s->mesh_count = sc->mesh_count;
        s->instance_count = sc->instance_count;
        for (i = 0; i < BVH_CL__B_COUNT && err == CL_SUCCESS; i++) {
            if (data[i] || !size[i])
                s->buf[i] = bvh_cl__buffer(c, size[i], data[i], &err);
            else
                s->buf[i] = clCreateBuffer(c->context, CL_MEM_READ_ONLY, size[i], NULL, &err);
        }
        if (err == CL_SUCCESS) {
            call = "clEnqueueWriteBuffer";
            err = bvh_cl__scene_write(c, s, trees, meshes);
        }
        if (err != CL_SUCCESS) {
            r = bvh_cl__fail(c, err, call);
            bvh_cl_scene_free(s);
            s = NULL;
        }
    }
    bvh_cl__free(&c->al, BVH_CL__CAST(void *, trees));
    bvh_cl__free(&c->al, meshes);
    bvh_cl__free(&c->al, info);
    *out = s;
    return r;
}

/* a scene's batch: its arguments 0..12 (the buffers, counts and the mask), then the rays */
static bvh_cl_result bvh_cl__scene_batch(bvh_cl_scene *s, const bvh_ray *rays, uint32_t mask, void *out,
                                         size_t out_elem, size_t count, int kernel) {
    cl_kernel k = s->ctx->kernels[kernel];
    cl_uint m = mask;
    cl_int e = clSetKernelArg(k, 0, sizeof(cl_mem), &s->buf[BVH_CL__B_TOP_NODES]);
    e |= clSetKernelArg(k, 1, sizeof(cl_uint), &s->top_node_count);
    e |= clSetKernelArg(k, 2, sizeof(cl_mem), &s->buf[BVH_CL__B_TOP_PRIMS]);
    e |= clSetKernelArg(k, 3, sizeof(cl_uint), &s->top_ref_count);
    e |= clSetKernelArg(k, 4, sizeof(cl_mem), &s->buf[BVH_CL__B_NODES]);
    e |= clSetKernelArg(k, 5, sizeof(cl_mem), &s->buf[BVH_CL__B_TRIS]);
    e |= clSetKernelArg(k, 6, sizeof(cl_mem), &s->buf[BVH_CL__B_PRIMS]);
    e |= clSetKernelArg(k, 7, sizeof(cl_mem), &s->buf[BVH_CL__B_MESHES]);
    e |= clSetKernelArg(k, 8, sizeof(cl_uint), &s->mesh_count);
    e |= clSetKernelArg(k, 9, sizeof(cl_mem), &s->buf[BVH_CL__B_INVERSE]);
    e |= clSetKernelArg(k, 10, sizeof(cl_mem), &s->buf[BVH_CL__B_INFO]);
    e |= clSetKernelArg(k, 11, sizeof(cl_uint), &s->instance_count);
    e |= clSetKernelArg(k, 12, sizeof(cl_uint), &m);
    if (e != CL_SUCCESS) return bvh_cl__fail(s->ctx, CL_INVALID_KERNEL_ARGS, "clSetKernelArg");
    return bvh_cl__batch(s->ctx, k, 13, rays, out, out_elem, count);
}
BVH_CL_API bvh_cl_result bvh_cl_scene_intersect(bvh_cl_scene *s, const bvh_ray *rays, uint32_t mask,
                                                bvh_scene_hit *hits, size_t count) {
    if (!s || (count && (!rays || !hits))) return BVH_CL_ERROR_INVALID_ARGUMENT;
    return bvh_cl__scene_batch(s, rays, mask, hits, sizeof(bvh_scene_hit), count, BVH_CL__K_SCENE_CLOSEST);
}
BVH_CL_API bvh_cl_result bvh_cl_scene_occluded(bvh_cl_scene *s, const bvh_ray *rays, uint32_t mask, uint8_t *occluded,
                                               size_t count) {
    if (!s || (count && (!rays || !occluded))) return BVH_CL_ERROR_INVALID_ARGUMENT;
    return bvh_cl__scene_batch(s, rays, mask, occluded, 1, count, BVH_CL__K_SCENE_ANY);
}

#endif /* BVH_HAVE_OPENCL */
#endif /* BVH_CL_IMPLEMENTATION_DONE */
#endif /* BVH_CL_IMPLEMENTATION */
