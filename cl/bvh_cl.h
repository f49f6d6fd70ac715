/* bvh_cl.h - v0.3.0 - OpenCL companion of bvh.h: trace bvh.h trees on any OpenCL 1.2 device

   WHAT
     Uploads a bvh_tree (nodes, reference-ordered triangles, primitive ids) to an OpenCL device as
     it is, and traces ray batches (closest hit, any hit) and whole camera frames there with the
     kernels of cl/trace.cl. The hits are those of bvh_intersect: same primitive, same t (to the
     bit on devices with correctly rounded division and fp64, such as PoCL on a CPU).

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
         bvh_cl_desc desc = {0};              // first device (or $BVH_CL_DEVICE="1:0"), cl/trace.cl
         desc.log = log;                      // receives the compiler's log if the build fails
         desc.log_size = sizeof log;
         bvh_cl_result r = bvh_cl_create(&cl, &desc);
         if (r != BVH_CL_SUCCESS) { printf("%s\n%s\n", bvh_cl_result_string(r), log); return 1; }
         r = bvh_cl_upload(cl, &tree, &gpu);                          // tree from bvh_build
         if (r == BVH_CL_SUCCESS) r = bvh_cl_intersect(gpu, rays, hits, ray_count);
         bvh_camera cam = bvh_camera_standard(bvh_tree_bounds(&tree), 640, 480);
         if (r == BVH_CL_SUCCESS) r = bvh_cl_render_frame(gpu, &cam, rgba, NULL, NULL);
         bvh_cl_tree_free(gpu);
         bvh_cl_destroy(cl);

   CONFIGURATION (define before including the implementation)
     BVH_CL_KERNEL_PATH    file read when bvh_cl_desc.kernel_source is NULL ("cl/trace.cl")
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
     No global state. A context and its trees must be used by one thread at a time (they share a
     command queue and scratch buffers); use one context per thread to trace concurrently.

   LICENSE
     MIT, like bvh.h.
*/
#ifndef BVH_CL_H_INCLUDED
#define BVH_CL_H_INCLUDED

#ifndef BVH_H_INCLUDED
#error "include bvh.h before cl/bvh_cl.h"
#endif

#define BVH_CL_VERSION_MAJOR 0
#define BVH_CL_VERSION_MINOR 3
#define BVH_CL_VERSION_PATCH 0

#ifndef BVH_CL_API
#if (defined(BVH_STATIC) || defined(BVH_CL_STATIC)) && (defined(__GNUC__) || defined(__clang__))
#define BVH_CL_API static __attribute__((unused)) /* a program need not call every function */
#elif defined(BVH_STATIC) || defined(BVH_CL_STATIC)
#define BVH_CL_API static
#else
#define BVH_CL_API extern
#endif
#endif

#ifndef BVH_CL_KERNEL_PATH
#define BVH_CL_KERNEL_PATH "cl/trace.cl"
#endif

#ifdef __cplusplus
extern "C" {
#endif

typedef enum bvh_cl_result {
    BVH_CL_SUCCESS = 0,
    BVH_CL_ERROR_NOT_AVAILABLE,     /* compiled without BVH_HAVE_OPENCL */
    BVH_CL_ERROR_NO_PLATFORM,       /* no OpenCL platform, or platform index out of range */
    BVH_CL_ERROR_NO_DEVICE,         /* the platform has no device, or device index out of range */
    BVH_CL_ERROR_KERNEL_NOT_FOUND,  /* the kernel file could not be read (path in desc.log) */
    BVH_CL_ERROR_BUILD_FAILED,      /* the kernel did not compile: the compiler's log in desc.log */
    BVH_CL_ERROR_OUT_OF_RESOURCES,  /* host or device memory or resources exhausted */
    BVH_CL_ERROR_BUFFER_TOO_LARGE,  /* a buffer exceeds CL_DEVICE_MAX_MEM_ALLOC_SIZE (or
                                       desc.max_alloc), or the tree the global memory */
    BVH_CL_ERROR_INVALID_ARGUMENT,  /* NULL pointer, bad "platform:device" string, box-only tree */
    BVH_CL_ERROR_OPENCL,            /* any other OpenCL error: see bvh_cl_last_error() */
    BVH_CL_RESULT_COUNT
} bvh_cl_result;

/* Zero is the sensible default for every field. */
typedef struct bvh_cl_desc {
    const char *device;        /* "platform:device" indices (or "platform"); NULL: $BVH_CL_DEVICE,
                                  else the first device of the first platform that has one */
    const char *kernel_path;   /* NULL: BVH_CL_KERNEL_PATH */
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
    bvh_allocator allocator;   /* host memory of the context and its trees, as bvh.h's: both
                                  NULL = BVH_CL_MALLOC / BVH_CL_FREE, one alone refused; blocks
                                  aligned less than malloc's count as failed allocations */
} bvh_cl_desc;

typedef struct bvh_cl_device_info {
    char platform[128], device[128], version[128];
    uint32_t platform_index, device_index;
    uint32_t compute_units;
    uint64_t max_alloc;  /* effective limit on one buffer (device limit, or desc.max_alloc) */
    uint64_t global_mem;
    int is_gpu;
    int exact;           /* correctly rounded divide/sqrt and fp64: t bit-identical to the CPU */
} bvh_cl_device_info;

typedef struct bvh_cl_context bvh_cl_context; /* device, queue, compiled kernels */
typedef struct bvh_cl_tree bvh_cl_tree;       /* a tree uploaded to the device of a context */

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
BVH_CL_API void bvh_cl_destroy(bvh_cl_context *ctx); /* free its trees first; NULL is ignored */
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
BVH_CL_API bvh_cl_result bvh_cl_occluded(bvh_cl_tree *tree, const bvh_ray *rays, uint8_t *occluded,
                                         size_t count);

/* Traces the camera's width x height primary rays (bvh_camera_ray, row 0 at the top), generated
   on the device. Outputs, each optional (NULL), width*height entries in row-major order:
   rgba     4 bytes per pixel: hits grey * (0.2 + 0.8 |dot(n, d)|) (headlight), misses a gradient
   hits     bvh_hit per pixel, equal to bvh_intersect of bvh_camera_ray(cam, x, y)
   visited  nodes visited per pixel, equal to bvh_intersect_counted (for heat maps)
   On a CPU device (desc.frame_rays), frames without visited counts trace packets of 4 x 4 pixels
   per work-item, set up and box-tested as float16.
   SUCCESS; ARGUMENT: cam NULL; BUFFER_TOO_LARGE; OUT_OF_RESOURCES; OPENCL. */
BVH_CL_API bvh_cl_result bvh_cl_render_frame(bvh_cl_tree *tree, const bvh_camera *cam, uint8_t *rgba,
                                             bvh_hit *hits, uint32_t *visited);

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
    case BVH_CL_SUCCESS: return "success";
    case BVH_CL_ERROR_NOT_AVAILABLE: return "OpenCL not available (built without BVH_HAVE_OPENCL)";
    case BVH_CL_ERROR_NO_PLATFORM: return "no OpenCL platform (or platform index out of range)";
    case BVH_CL_ERROR_NO_DEVICE: return "no OpenCL device (or device index out of range)";
    case BVH_CL_ERROR_KERNEL_NOT_FOUND: return "kernel source file could not be read";
    case BVH_CL_ERROR_BUILD_FAILED: return "kernel build failed (see the build log)";
    case BVH_CL_ERROR_OUT_OF_RESOURCES: return "out of device or host memory/resources";
    case BVH_CL_ERROR_BUFFER_TOO_LARGE: return "buffer too large for the device";
    case BVH_CL_ERROR_INVALID_ARGUMENT: return "invalid argument";
    case BVH_CL_ERROR_OPENCL: return "OpenCL error (see bvh_cl_last_error)";
    default: return "unknown result code";
    }
}

#ifndef BVH_HAVE_OPENCL
/* ============================================================================================ */
/* == without OpenCL: every call reports BVH_CL_ERROR_NOT_AVAILABLE ============================== */
/* ============================================================================================ */
BVH_CL_API bvh_cl_result bvh_cl_enumerate(bvh_cl_device_info *out, uint32_t capacity, uint32_t *count) {
    (void)out; (void)capacity;
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
BVH_CL_API const char *bvh_cl_build_log(const bvh_cl_context *ctx) { (void)ctx; return ""; }
BVH_CL_API int bvh_cl_last_error(const bvh_cl_context *ctx, const char **call) {
    (void)ctx;
    if (call) *call = "";
    return 0;
}
BVH_CL_API double bvh_cl_last_kernel_ms(const bvh_cl_context *ctx) { (void)ctx; return 0.0; }
BVH_CL_API bvh_cl_result bvh_cl_upload(bvh_cl_context *ctx, const bvh_tree *tree, bvh_cl_tree **out) {
    (void)ctx; (void)tree;
    if (out) *out = NULL;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API void bvh_cl_tree_free(bvh_cl_tree *tree) { (void)tree; }
BVH_CL_API bvh_cl_result bvh_cl_intersect(bvh_cl_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count) {
    (void)tree; (void)rays; (void)hits; (void)count;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API bvh_cl_result bvh_cl_occluded(bvh_cl_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count) {
    (void)tree; (void)rays; (void)occluded; (void)count;
    return BVH_CL_ERROR_NOT_AVAILABLE;
}
BVH_CL_API bvh_cl_result bvh_cl_render_frame(bvh_cl_tree *tree, const bvh_camera *cam, uint8_t *rgba, bvh_hit *hits,
                                             uint32_t *visited) {
    (void)tree; (void)cam; (void)rgba; (void)hits; (void)visited;
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

#define BVH_CL__PLATFORM_NOT_FOUND (-1001) /* CL_PLATFORM_NOT_FOUND_KHR of the ICD loader */
#define BVH_CL__MAX_IDS 64
#define BVH_CL__PACKET_DEFAULT 16 /* frame rays per work-item on CPU devices */
#define BVH_CL__CHUNK ((size_t)1 << 20) /* rays or pixels per kernel launch at most */
enum { BVH_CL__K_CLOSEST, BVH_CL__K_ANY, BVH_CL__K_FRAME, BVH_CL__K_FRAME8, BVH_CL__K_COUNT };
enum { BVH_CL__S_IN, BVH_CL__S_OUT, BVH_CL__S_RGBA, BVH_CL__S_VISITED, BVH_CL__S_COUNT };
static const char *const bvh_cl__kernel_names[BVH_CL__K_COUNT] = {"bvh_intersect_kernel", "bvh_occluded_kernel",
                                                                   "bvh_frame_kernel", "bvh_frame_packet_kernel"};

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
    if (al->free) al->free(p, al->user);
    else BVH_CL_FREE(p, al->user);
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
    case CL_SUCCESS: return BVH_CL_SUCCESS;
    case BVH_CL__PLATFORM_NOT_FOUND: return BVH_CL_ERROR_NO_PLATFORM;
    case CL_DEVICE_NOT_FOUND: case CL_DEVICE_NOT_AVAILABLE: return BVH_CL_ERROR_NO_DEVICE;
    case CL_BUILD_PROGRAM_FAILURE: case CL_COMPILER_NOT_AVAILABLE: return BVH_CL_ERROR_BUILD_FAILED;
    case CL_OUT_OF_RESOURCES: case CL_OUT_OF_HOST_MEMORY: case CL_MEM_OBJECT_ALLOCATION_FAILURE:
        return BVH_CL_ERROR_OUT_OF_RESOURCES;
    case CL_INVALID_BUFFER_SIZE: return BVH_CL_ERROR_BUFFER_TOO_LARGE;
    default: return BVH_CL_ERROR_OPENCL;
    }
}

/* records the failing call in the context (if any) and maps the error */
static bvh_cl_result bvh_cl__fail(bvh_cl_context *c, cl_int err, const char *call) {
    if (c) { c->last_error = err; c->last_call = call; }
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
    *p = (cl_uint)a; *d = (cl_uint)b;
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
    if (err == CL_DEVICE_NOT_FOUND) { *n = 0; err = CL_SUCCESS; }
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
        if (pi >= np) { bvh_cl__logf(desc, "platform %u of %u", pi, np); return BVH_CL_ERROR_NO_PLATFORM; }
        if ((err = bvh_cl__devices(plats[pi], devs, &nd)) != CL_SUCCESS) return bvh_cl__fail(c, err, "clGetDeviceIDs");
        if (di >= nd) {
            bvh_cl__logf(desc, "device %u of %u on platform %u", di, nd, pi);
            return BVH_CL_ERROR_NO_DEVICE;
        }
    } else {
        for (i = 0; i < np; i++) {
            if (bvh_cl__devices(plats[i], devs, &nd) == CL_SUCCESS && nd > 0) { pi = i; break; }
        }
        if (i == np) { bvh_cl__logf(desc, "%u OpenCL platform(s), no device", np); return BVH_CL_ERROR_NO_DEVICE; }
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
static char *bvh_cl__read_file(const bvh_allocator *al, const char *path) {
    FILE *f = fopen(path, "rb");
    char *s = NULL;
    long n;
    if (!f) return NULL;
    if (fseek(f, 0, SEEK_END) == 0 && (n = ftell(f)) >= 0 && fseek(f, 0, SEEK_SET) == 0 &&
        (s = BVH_CL__CAST(char *, bvh_cl__alloc(al, (size_t)n + 1))) != NULL) {
        if (fread(s, 1, (size_t)n, f) != (size_t)n) { bvh_cl__free(al, s); s = NULL; }
        else s[n] = '\0';
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
    const char *path = desc->kernel_path ? desc->kernel_path : BVH_CL_KERNEL_PATH;
    const char *extra = desc->build_options ? desc->build_options : "";
    char *file = NULL, *opts;
    const char *src = desc->kernel_source;
    char cver[64] = "";
    cl_device_fp_config sp = 0;
    size_t len;
    cl_int err;
    int i;
    if (!src) {
        src = file = bvh_cl__read_file(&c->al, path);
        if (!src) {
            bvh_cl__logf(desc, "cannot read the kernel source \"%s\"", path);
            return BVH_CL_ERROR_KERNEL_NOT_FOUND;
        }
    }
    len = strlen(src);
    c->program = clCreateProgramWithSource(c->context, 1, &src, &len, &err);
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
                CL_SUCCESS && k && c->local_size > k)
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
    if (!desc) { memset(&zero, 0, sizeof zero); desc = &zero; }
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
    if (r != BVH_CL_SUCCESS) { bvh_cl_destroy(c); return r; }
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
BVH_CL_API const char *bvh_cl_build_log(const bvh_cl_context *c) {
    return c && c->build_log ? c->build_log : "";
}
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
    if (err != CL_SUCCESS) { bvh_cl_tree_free(t); return bvh_cl__fail(c, err, "clCreateBuffer"); }
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
    if (err != CL_SUCCESS) { c->scratch[i] = NULL; return bvh_cl__fail(c, err, "clCreateBuffer"); }
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

static size_t bvh_cl__round_up(size_t n, size_t m) { return (n + m - 1) / m * m; }

/* rays in chunks that fit the device; out_elem bytes of output per ray */
static bvh_cl_result bvh_cl__batch(bvh_cl_tree *t, const bvh_ray *rays, void *out, size_t out_elem, size_t count,
                                   int kernel) {
    bvh_cl_context *c = t->ctx;
    cl_kernel k = c->kernels[kernel];
    size_t chunk = c->max_alloc / sizeof(bvh_ray), i, n, global, local = c->local_size;
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
    if ((err = bvh_cl__tree_args(k, t)) != CL_SUCCESS) return bvh_cl__fail(c, err, "clSetKernelArg");
    for (i = 0; i < count; i += n) {
        n = count - i < chunk ? count - i : chunk;
        nn = (cl_uint)n;
        global = bvh_cl__round_up(n, local);
        err = clEnqueueWriteBuffer(c->queue, c->scratch[BVH_CL__S_IN], CL_FALSE, 0, n * sizeof(bvh_ray), rays + i, 0,
                                   NULL, NULL);
        if (err != CL_SUCCESS) return bvh_cl__fail(c, err, "clEnqueueWriteBuffer");
        err = clSetKernelArg(k, 5, sizeof(cl_mem), &c->scratch[BVH_CL__S_IN]);
        err |= clSetKernelArg(k, 6, sizeof(cl_mem), &c->scratch[BVH_CL__S_OUT]);
        err |= clSetKernelArg(k, 7, sizeof(cl_uint), &nn);
        if (err != CL_SUCCESS) return bvh_cl__fail(c, CL_INVALID_KERNEL_ARGS, "clSetKernelArg");
        err = clEnqueueNDRangeKernel(c->queue, k, 1, NULL, &global, &local, 0, NULL, &ev);
        if (err != CL_SUCCESS) { clFinish(c->queue); return bvh_cl__fail(c, err, "clEnqueueNDRangeKernel"); }
        /* a non-blocking read and clFinish: PoCL's blocking read spins on a core the kernel needs */
        err = clEnqueueReadBuffer(c->queue, c->scratch[BVH_CL__S_OUT], CL_FALSE, 0, n * out_elem,
                                  BVH_CL__CAST(char *, out) + i * out_elem, 0, NULL, NULL);
        if (err == CL_SUCCESS) err = clFinish(c->queue);
        else clFinish(c->queue);
        bvh_cl__time(c, ev);
        if (err != CL_SUCCESS) return bvh_cl__fail(c, err, "clEnqueueReadBuffer");
    }
    return BVH_CL_SUCCESS;
}

BVH_CL_API bvh_cl_result bvh_cl_intersect(bvh_cl_tree *t, const bvh_ray *rays, bvh_hit *hits, size_t count) {
    if (!t || (count && (!rays || !hits))) return BVH_CL_ERROR_INVALID_ARGUMENT;
    return bvh_cl__batch(t, rays, hits, sizeof(bvh_hit), count, BVH_CL__K_CLOSEST);
}
BVH_CL_API bvh_cl_result bvh_cl_occluded(bvh_cl_tree *t, const bvh_ray *rays, uint8_t *occluded, size_t count) {
    if (!t || (count && (!rays || !occluded))) return BVH_CL_ERROR_INVALID_ARGUMENT;
    return bvh_cl__batch(t, rays, occluded, 1, count, BVH_CL__K_ANY);
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
    w = cam->width; h = cam->height;
    if (!w || !h) return BVH_CL_SUCCESS;
    dst[0] = rgba; dst[1] = hits; dst[2] = visited;
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
    while (c->max_items[1] && ly > c->max_items[1]) { lx *= 2; ly /= 2; } /* 8 x 64 may be too tall */
    local[0] = lx; local[1] = ly;
    for (y0 = 0; y0 < h; y0 += rows) {
        rows = h - y0 < band ? h - y0 : band;
        /* packets: a work-item per 4 x `packets` pixels */
        global[0] = bvh_cl__round_up(packets ? (w + 3) / 4 : w, lx);
        global[1] = bvh_cl__round_up(packets ? (rows + packets - 1) / packets : rows, ly);
        err = clSetKernelArg(k, 8, sizeof(cl_uint), &y0);
        err |= clSetKernelArg(k, 9, sizeof(cl_uint), &rows);
        if (err != CL_SUCCESS) return bvh_cl__fail(c, CL_INVALID_KERNEL_ARGS, "clSetKernelArg");
        err = clEnqueueNDRangeKernel(c->queue, k, 2, NULL, global, local, 0, NULL, &ev);
        if (err != CL_SUCCESS) { clFinish(c->queue); return bvh_cl__fail(c, err, "clEnqueueNDRangeKernel"); }
        for (i = 0; i < 3 && err == CL_SUCCESS; i++) {
            if (!dst[i]) continue;
            err = clEnqueueReadBuffer(c->queue, c->scratch[slot[i]], CL_FALSE, 0, (size_t)rows * w * elem[i],
                                      BVH_CL__CAST(char *, dst[i]) + (size_t)y0 * w * elem[i], 0, NULL, NULL);
        }
        if (err == CL_SUCCESS) err = clFinish(c->queue);
        else clFinish(c->queue);
        bvh_cl__time(c, ev);
        if (err != CL_SUCCESS) return bvh_cl__fail(c, err, "clEnqueueReadBuffer");
    }
    return BVH_CL_SUCCESS;
}

#endif /* BVH_HAVE_OPENCL */
#endif /* BVH_CL_IMPLEMENTATION_DONE */
#endif /* BVH_CL_IMPLEMENTATION */
