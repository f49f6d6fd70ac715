/* render.c - builds a BVH over a scene, checks it, traces primary rays on the CPU or with OpenCL
   and reports the numbers; writes the image and a traversal heat map on request.

   build/render [--builder NAME] [--threads N] [--size WxH] [--trace cpu|opencl] [--frames F]
                [--out FILE.png|FILE.ppm] [--heatmap FILE.png|FILE.ppm] [--heat-max N] [--json]
                [--repeat R] SCENE
   e.g. build/render --out out/bunny.png /usr/share/glmark2/models/bunny.obj
        build/render --json --trace cpu --heatmap out/heat.png --builder top-down gen:random:100000

   Steps: load (or generate) the scene; build with the chosen builder (median time of R builds);
   validate (a defect is an error); SAH with costs (1, 0, 1) and tree statistics; primary rays of
   the standard camera (bvh_camera_standard over the tree bounds), traced by one backend:
     cpu     a warm-up frame with bvh_intersect_counted (hits and nodes visited per pixel, rows
             interleaved over the threads), then F timed frames of bvh_intersect_batch (the rays
             are generated before the clock starts)
     opencl  one frame of bvh_intersect_batch on the CPU (the reference hits and the CPU Mrays/s),
             then bvh_cl_render_frame, which makes the same rays on the device: a warm-up frame
             (hits and nodes visited), then F timed frames (hits; wall clock, copy back included).
             Its hits must equal the CPU's (to the bit on an exact device): else render says so
             and exits with status 1.
   Then, from the CPU frame's hits, the rays a renderer traces next (examples/rays.h, the same
   sets as build/bvhbench's): F passes over the diffuse rays (bvh_intersect_batch) and over the
   shadow rays (bvh_occluded_batch) on the CPU threads, the median reported (diffuse_*, shadow_*).
   frame_ms is the median of the F frames of the backend used. Then headlight shading of the
   backend's hits (--out) and the heat map of the nodes visited (--heatmap, heatmap.h).
   Default: ploc-parallel, all cores, 800x600, OpenCL when a device is found (else the CPU, said
   once on stderr), 5 frames, heat scale 0..200 nodes, no image, human-readable report. An explicit
   --trace opencl never falls back: without a usable device render says so and exits with status 1.
   Exit status: 0 done; 1 an error (said on stderr in one line); 2 a bad command line. */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define BVH_CL_IMPLEMENTATION
#include "cl/bvh_cl.h"
#define SCENE_IMPLEMENTATION
#include "scene.h"
#define HEATMAP_IMPLEMENTATION
#include "heatmap.h"
#define RAYS_IMPLEMENTATION
#include "rays.h"

#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define RENDER_MAX_PIXELS (64u * 1024u * 1024u)
#define RENDER_MAX_FRAMES 100u
#define RENDER_MISMATCH 3 /* trace(): the backends disagree */

typedef enum trace_kind { TRACE_AUTO, TRACE_CPU, TRACE_OPENCL } trace_kind;

typedef struct options {
    const char *scene_spec;
    const char *out;     /* image path or NULL */
    const char *heatmap; /* heat map path or NULL */
    bvh_builder builder;
    trace_kind trace;
    uint32_t threads; /* 0 = all online CPUs */
    uint32_t width, height;
    uint32_t repeat;   /* builds timed; the median is reported */
    uint32_t frames;   /* frames timed after the warm-up; the median is reported */
    uint32_t heat_max; /* top of the heat map's scale; 0 = the 99th percentile */
    int json;
} options;

typedef struct frame {
    uint32_t width, height;
    bvh_camera cam;
    bvh_hit *hits;     /* CPU hits: width * height, row-major, row 0 at the top */
    bvh_hit *cl_hits;  /* OpenCL hits, NULL when OpenCL is not used */
    uint32_t *visited; /* nodes visited per pixel (bvh_intersect_counted, or the frame kernel) */
} frame;

typedef struct report {
    double load_ms, build_ms, sah;
    double trace_ms, t_sum; /* the CPU: median frame (--trace cpu) or the one reference frame */
    uint64_t hits;
    uint32_t threads;
    bvh_stats stats;
    int opencl;       /* the backend: 0 cpu, 1 opencl */
    int disagree;     /* opencl: its hits are not the CPU's */
    char device[128]; /* "cpu" or the OpenCL device's name */
    double frame_ms;  /* median frame of the backend */
    double cl_kernel_ms, cl_t_sum;
    uint64_t cl_hits;
    uint64_t diffuse_rays, diffuse_hits; /* examples/rays.h's sets from the CPU frame's hits */
    uint64_t shadow_rays, shadow_occluded;
    double diffuse_ms, shadow_ms; /* median of F passes on the CPU threads */
    double heat_mean;
    uint32_t heat_max, heat_scale;
} report;

/* ============================================================================================ */
/* == options ================================================================================= */
/* ============================================================================================ */
#ifdef BVH_HAVE_OPENCL
#define RENDER_OPENCL "yes"
#else
#define RENDER_OPENCL "no (--trace cpu only)"
#endif

static void usage(FILE *f) {
    fprintf(f,
            "usage: render [--builder NAME] [--threads N] [--size WxH] [--trace cpu|opencl] [--frames F]\n"
            "              [--out FILE.png|FILE.ppm] [--heatmap FILE.png|FILE.ppm] [--heat-max N]\n"
            "              [--json] [--repeat R] SCENE\n"
            "  --builder NAME  top-down, bottom-up, sah-midpoint, ploc, ploc-parallel (default)\n"
            "  --threads N     build (ploc-parallel) and CPU trace threads, 0 = all cores (default 0)\n"
            "  --size WxH      image size in pixels (default 800x600)\n"
            "  --trace B       cpu, or opencl (default when a device is found; $BVH_CL_DEVICE=P:D\n"
            "                  picks one); opencl also traces one frame on the CPU to check the hits,\n"
            "                  and fails (status 1) when no OpenCL device can be used\n"
            "  --frames F      frames timed after a warm-up frame, the median reported (default 5)\n"
            "  --out FILE      write the frame as PNG or binary PPM (by extension)\n"
            "  --heatmap FILE  write the nodes visited per pixel as a heat map with a legend\n"
            "  --heat-max N    top of the heat map's colour scale in nodes (default 200; 0 = the\n"
            "                  99th percentile of this frame; a fixed scale compares builders)\n"
            "  --json          print one JSON object on one line instead of the report\n"
            "  --repeat R      build R times and report the median build time (default 1)\n"
            "  --help          this text\n"
            "%s"
            "exit status: 0 done, 1 error (scene, build, --trace opencl without a device, OpenCL\n"
            "             hits not the CPU's), 2 bad command line\n"
            "built with: assimp=%s png=%s opencl=%s\n",
            scene_spec_help(), scene_can_use_assimp() ? "yes" : "no (only .obj files load)",
            scene_can_write_png() ? "yes" : "no (use .ppm)", RENDER_OPENCL);
}

static int parse_image_path(const char *opt, const char *val, const char **out) {
    char err[512];
    if (scene_check_image_path(val, err, sizeof err)) {
        fprintf(stderr, "render: %s: %s\n", opt, err);
        return 2;
    }
    *out = val;
    return 0;
}

/* one option with its value; 0: done, 2: bad value (message printed) */
static int parse_option(const char *a, const char *val, options *o) {
    if (strcmp(a, "--builder") == 0) {
        if (bvh_builder_from_name(val, &o->builder) != BVH_SUCCESS || o->builder == BVH_BUILDER_DEFAULT) {
            fprintf(stderr,
                    "render: unknown builder '%s' (top-down, bottom-up, sah-midpoint, ploc, "
                    "ploc-parallel)\n",
                    val);
            return 2;
        }
    } else if (strcmp(a, "--threads") == 0) {
        if (scene_parse_u32(val, 0, 256, &o->threads, NULL)) {
            fprintf(stderr, "render: --threads wants a number from 0 (all cores) to 256, not '%s'\n", val);
            return 2;
        }
    } else if (strcmp(a, "--size") == 0) {
        if (scene_parse_size(val, RENDER_MAX_PIXELS, &o->width, &o->height)) {
            fprintf(stderr,
                    "render: --size wants WxH (e.g. 800x600, at most 16384 a side and %u "
                    "pixels), not '%s'\n",
                    RENDER_MAX_PIXELS, val);
            return 2;
        }
    } else if (strcmp(a, "--trace") == 0) {
        if (strcmp(val, "cpu") == 0)
            o->trace = TRACE_CPU;
        else if (strcmp(val, "opencl") == 0)
            o->trace = TRACE_OPENCL;
        else {
            fprintf(stderr, "render: --trace wants cpu or opencl, not '%s'\n", val);
            return 2;
        }
    } else if (strcmp(a, "--frames") == 0) {
        if (scene_parse_u32(val, 1, RENDER_MAX_FRAMES, &o->frames, NULL)) {
            fprintf(stderr, "render: --frames wants a number from 1 to %u, not '%s'\n", RENDER_MAX_FRAMES, val);
            return 2;
        }
    } else if (strcmp(a, "--heat-max") == 0) {
        if (scene_parse_u32(val, 0, 1000000, &o->heat_max, NULL)) {
            fprintf(stderr,
                    "render: --heat-max wants a node count from 0 (the 99th percentile) to 1000000, "
                    "not '%s'\n",
                    val);
            return 2;
        }
    } else if (strcmp(a, "--repeat") == 0) {
        if (scene_parse_u32(val, 1, 1000, &o->repeat, NULL)) {
            fprintf(stderr, "render: --repeat wants a number from 1 to 1000, not '%s'\n", val);
            return 2;
        }
    } else if (strcmp(a, "--out") == 0)
        return parse_image_path(a, val, &o->out);
    else if (strcmp(a, "--heatmap") == 0)
        return parse_image_path(a, val, &o->heatmap);
    return 0;
}

/* 0: run; 1: --help printed; 2: bad command line (message printed) */
static int parse_args(int argc, char **argv, options *o) {
    static const char *const with_value[] = {"--builder", "--threads", "--size",     "--trace", "--frames",
                                             "--out",     "--heatmap", "--heat-max", "--repeat"};
    int i;
    size_t k;
    memset(o, 0, sizeof *o);
    o->builder = BVH_BUILDER_PLOC_PARALLEL;
    o->width = 800;
    o->height = 600;
    o->repeat = 1;
    o->frames = 5;
    o->heat_max = 200;
    for (i = 1; i < argc; i++) {
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        int takes = 0;
        for (k = 0; k < sizeof with_value / sizeof with_value[0]; k++) takes |= strcmp(a, with_value[k]) == 0;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            return 1;
        }
        if (takes && !val) {
            fprintf(stderr, "render: %s needs a value (see --help)\n", a);
            return 2;
        }
        if (takes) {
            if (parse_option(a, val, o)) return 2;
            i++;
        } else if (strcmp(a, "--json") == 0)
            o->json = 1;
        else if (a[0] == '-' && a[1] != 0) {
            fprintf(stderr, "render: unknown option '%s' (see --help)\n", a);
            return 2;
        } else if (o->scene_spec) {
            fprintf(stderr, "render: one scene only ('%s' and '%s')\n", o->scene_spec, a);
            return 2;
        } else
            o->scene_spec = a;
    }
    if (!o->scene_spec) {
        fprintf(stderr, "render: no SCENE given (see --help)\n");
        return 2;
    }
    return 0;
}

/* ============================================================================================ */
/* == build and check ========================================================================= */
/* ============================================================================================ */
/* Builds o->repeat times (keeping the last tree) and returns the median build time. */
static int build_tree(const scene *s, const options *o, bvh_tree *tree, double *median_ms) {
    bvh_build_desc desc;
    double times[1000];
    uint32_t r;
    memset(&desc, 0, sizeof desc);
    desc.builder = o->builder;
    desc.threads = o->threads;
    desc.skip_invalid = 1; /* NaN/Inf triangles in a file are left out and reported as excluded */
    desc.triangles.positions = s->v;
    desc.triangles.vertex_count = 3 * s->triangles;
    desc.triangles.triangle_count = s->triangles;
    for (r = 0; r < o->repeat; r++) {
        double t0;
        bvh_result res;
        if (r) bvh_free(tree);
        t0 = scene_now_ms();
        res = bvh_build(tree, &desc);
        times[r] = scene_now_ms() - t0;
        if (res != BVH_SUCCESS) {
            fprintf(stderr, "render: %s build failed: %s\n", bvh_builder_name(o->builder), bvh_result_string(res));
            return 1;
        }
    }
    *median_ms = scene_median(times, o->repeat);
    return 0;
}

static int check_tree(const bvh_tree *tree, report *rep) {
    bvh_validation v;
    bvh_result res = bvh_validate(tree, NULL, &v);
    if (res != BVH_SUCCESS) {
        fprintf(stderr, "render: %s tree is invalid: %s (node %d)\n", bvh_builder_name(tree->builder),
                res == BVH_ERROR_INVALID_TREE ? v.message : bvh_result_string(res),
                v.node == BVH_INVALID ? -1 : (int)v.node);
        return 1;
    }
    if (bvh_sah(tree, NULL, &rep->sah) != BVH_SUCCESS || bvh_get_stats(tree, &rep->stats) != BVH_SUCCESS) {
        fprintf(stderr, "render: cannot compute the SAH or statistics of the tree\n");
        return 1;
    }
    return 0;
}

/* ============================================================================================ */
/* == CPU backend ============================================================================= */
/* ============================================================================================ */
static int frame_init(frame *f, const bvh_tree *tree, uint32_t width, uint32_t height) {
    size_t n = (size_t)width * height;
    f->width = width;
    f->height = height;
    f->cam = bvh_camera_standard(bvh_tree_bounds(tree), width, height);
    f->hits = (bvh_hit *)malloc(n * sizeof(bvh_hit));
    f->visited = (uint32_t *)calloc(n, sizeof(uint32_t));
    if (!f->hits || !f->visited) {
        fprintf(stderr, "render: out of memory for a %ux%u frame\n", width, height);
        return 1;
    }
    return 0;
}

typedef struct counted_job {
    const bvh_tree *tree;
    frame *f;
    uint32_t first, step; /* rows first, first + step, ... */
} counted_job;

static void *counted_rows(void *arg) {
    const counted_job *j = (const counted_job *)arg;
    uint32_t x, y;
    for (y = j->first; y < j->f->height; y += j->step)
        for (x = 0; x < j->f->width; x++) {
            size_t i = (size_t)y * j->f->width + x;
            bvh_ray ray = bvh_camera_ray(&j->f->cam, x, y);
            bvh_intersect_counted(j->tree, &ray, &j->f->hits[i], &j->f->visited[i]);
        }
    return NULL;
}

/* Hits and nodes visited per pixel with bvh_intersect_counted, rows interleaved over `threads`
   threads (a thread that cannot be started has its rows traced by this one). */
static void trace_counted(const bvh_tree *tree, frame *f, uint32_t threads) {
    pthread_t tid[256];
    counted_job job[256];
    int started[256];
    uint32_t t;
    if (threads > 256) threads = 256;
    if (threads > f->height) threads = f->height;
    for (t = 0; t < threads; t++) {
        job[t].tree = tree;
        job[t].f = f;
        job[t].first = t;
        job[t].step = threads;
    }
    for (t = 1; t < threads; t++) started[t] = pthread_create(&tid[t], NULL, counted_rows, &job[t]) == 0;
    counted_rows(&job[0]);
    for (t = 1; t < threads; t++) {
        if (started[t])
            pthread_join(tid[t], NULL);
        else
            counted_rows(&job[t]);
    }
}

/* `runs` frames of bvh_intersect_batch on `threads` threads into f->hits; *ms = the median time
   of the batch calls (the rays are generated once, before the clock starts). */
static int trace_cpu(const bvh_tree *tree, frame *f, uint32_t threads, uint32_t runs, double *ms) {
    size_t n = (size_t)f->width * f->height, i = 0;
    bvh_ray *rays = (bvh_ray *)malloc(n * sizeof(bvh_ray));
    bvh_result res = BVH_SUCCESS;
    double times[RENDER_MAX_FRAMES];
    uint32_t x, y, k;
    if (!rays) {
        fprintf(stderr, "render: out of memory for %zu rays\n", n);
        return 1;
    }
    for (y = 0; y < f->height; y++)
        for (x = 0; x < f->width; x++) rays[i++] = bvh_camera_ray(&f->cam, x, y);
    for (k = 0; k < runs && res == BVH_SUCCESS; k++) {
        double t0 = scene_now_ms();
        res = bvh_intersect_batch(tree, rays, f->hits, n, threads);
        times[k] = scene_now_ms() - t0;
    }
    free(rays);
    if (res != BVH_SUCCESS) {
        fprintf(stderr, "render: tracing failed: %s\n", bvh_result_string(res));
        return 1;
    }
    *ms = scene_median(times, runs);
    return 0;
}

/* The rays a renderer traces next (examples/rays.h, the same sets as build/bvhbench), made from
   the CPU frame's hits: `runs` passes over the diffuse rays (bvh_intersect_batch) and over the
   shadow rays (bvh_occluded_batch) on `threads` threads; the median times and the counts. */
static int trace_sets(const scene *s, const bvh_tree *tree, const frame *f, uint32_t threads, uint32_t runs,
                      report *r) {
    rays_set set;
    bvh_hit *dh;
    uint8_t *occ;
    double td[RENDER_MAX_FRAMES], ts[RENDER_MAX_FRAMES];
    bvh_result res = BVH_SUCCESS;
    size_t i;
    uint32_t k;
    if (rays_make(&f->cam, f->hits, s->v, bvh_tree_bounds(tree), &set)) {
        fprintf(stderr, "render: out of memory for the diffuse and shadow rays\n");
        return 1;
    }
    dh = (bvh_hit *)malloc((set.ndiffuse ? set.ndiffuse : 1) * sizeof *dh);
    occ = (uint8_t *)malloc(set.nshadow ? set.nshadow : 1);
    if (!dh || !occ) res = BVH_ERROR_OUT_OF_MEMORY;
    for (k = 0; k < runs && res == BVH_SUCCESS; k++) {
        double t0 = scene_now_ms();
        res = bvh_intersect_batch(tree, set.diffuse, dh, set.ndiffuse, threads);
        td[k] = scene_now_ms() - t0;
        t0 = scene_now_ms();
        if (res == BVH_SUCCESS) res = bvh_occluded_batch(tree, set.shadow, occ, set.nshadow, threads);
        ts[k] = scene_now_ms() - t0;
    }
    if (res == BVH_SUCCESS) {
        r->diffuse_rays = set.ndiffuse;
        r->shadow_rays = set.nshadow;
        r->diffuse_hits = r->shadow_occluded = 0;
        for (i = 0; i < set.ndiffuse; i++) r->diffuse_hits += dh[i].prim != BVH_INVALID;
        for (i = 0; i < set.nshadow; i++) r->shadow_occluded += occ[i];
        r->diffuse_ms = scene_median(td, runs);
        r->shadow_ms = scene_median(ts, runs);
    } else {
        fprintf(stderr, "render: tracing the diffuse and shadow rays failed: %s\n", bvh_result_string(res));
    }
    free(dh);
    free(occ);
    rays_free(&set);
    return res != BVH_SUCCESS;
}

/* ============================================================================================ */
/* == OpenCL backend ========================================================================== */
/* ============================================================================================ */
typedef struct gpu {
    bvh_cl_context *ctx;
    bvh_cl_tree *tree;
    bvh_cl_device_info info;
} gpu;

static void gpu_close(gpu *g) {
    bvh_cl_tree_free(g->tree);
    bvh_cl_destroy(g->ctx);
    g->tree = NULL;
    g->ctx = NULL;
}

/* Opens the device ($BVH_CL_DEVICE or the first) and uploads the tree. 0: ready; 1: OpenCL cannot
   be used, said in one line on stderr: an error when `required` (--trace opencl), else a note (the
   caller traces on the CPU). */
static int gpu_open(gpu *g, const bvh_tree *tree, int required) {
    char log[2048] = "";
    const char *pre = required ? "render: --trace opencl: " : "render: ";
    const char *post = required ? "" : ": tracing on the CPU";
    bvh_cl_desc desc;
    bvh_cl_result r;
    size_t i;
    memset(&desc, 0, sizeof desc);
    desc.log = log;
    desc.log_size = sizeof log;
    r = bvh_cl_create(&g->ctx, &desc);
    if (r == BVH_CL_SUCCESS) r = bvh_cl_upload(g->ctx, tree, &g->tree);
    if (r == BVH_CL_SUCCESS) r = bvh_cl_get_info(g->ctx, &g->info);
    for (i = 0; log[i]; i++) /* one line, even with a compiler's build log */
        if (log[i] == '\n' || log[i] == '\r') log[i] = ' ';
    if (r == BVH_CL_ERROR_NOT_AVAILABLE)
        fprintf(stderr, "%sbuilt without OpenCL (BVH_HAVE_OPENCL)%s\n", pre, post);
    else if (r != BVH_CL_SUCCESS)
        fprintf(stderr, "%sOpenCL cannot be used (%s%s%s)%s\n", pre, bvh_cl_result_string(r), log[0] ? ": " : "", log,
                post);
    if (r != BVH_CL_SUCCESS) {
        gpu_close(g);
        return 1;
    }
    return 0;
}

/* bvh_cl_render_frame: a warm-up frame (hits and nodes visited), then `runs` timed frames (hits
   only) into f->cl_hits; *ms the median wall-clock time of a frame (launch, kernel and copy
   back), *kernel_ms the median device time. */
static int trace_opencl(gpu *g, frame *f, uint32_t runs, double *ms, double *kernel_ms) {
    double wall[RENDER_MAX_FRAMES], kern[RENDER_MAX_FRAMES];
    bvh_cl_result r = bvh_cl_render_frame(g->tree, &f->cam, NULL, f->cl_hits, f->visited);
    uint32_t k;
    for (k = 0; k < runs && r == BVH_CL_SUCCESS; k++) {
        double t0 = scene_now_ms();
        r = bvh_cl_render_frame(g->tree, &f->cam, NULL, f->cl_hits, NULL);
        wall[k] = scene_now_ms() - t0;
        kern[k] = bvh_cl_last_kernel_ms(g->ctx);
    }
    if (r != BVH_CL_SUCCESS) {
        const char *call;
        int code = bvh_cl_last_error(g->ctx, &call);
        fprintf(stderr, "render: OpenCL frame failed: %s (%s: %d)\n", bvh_cl_result_string(r), call, code);
        return 1;
    }
    *ms = scene_median(wall, runs);
    *kernel_ms = scene_median(kern, runs);
    return 0;
}

/* ============================================================================================ */
/* == checks and summaries ==================================================================== */
/* ============================================================================================ */
/* Hit count and sum of hit distances, in pixel order (so equal hits give an equal sum). */
static void hits_summary(const bvh_hit *h, size_t n, uint64_t *hits, double *t_sum) {
    size_t i;
    *hits = 0;
    *t_sum = 0.0;
    for (i = 0; i < n; i++)
        if (h[i].prim != BVH_INVALID) {
            (*hits)++;
            *t_sum += (double)h[i].t;
        }
}

/* Pixels whose OpenCL hit is not the CPU's: another primitive, or another t (any bit on an exact
   device, which must match bvh_intersect to the bit; more than 1e-5 relative elsewhere). */
static size_t hits_differ(const frame *f, int exact, size_t *first) {
    size_t i, n = (size_t)f->width * f->height, bad = 0;
    for (i = 0; i < n; i++) {
        const bvh_hit *a = &f->hits[i], *b = &f->cl_hits[i];
        int same = a->prim == b->prim &&
                   (a->prim == BVH_INVALID ||
                    (exact ? memcmp(&a->t, &b->t, sizeof a->t) == 0 : fabsf(a->t - b->t) <= 1e-5f * fabsf(a->t)));
        if (!same && !bad++) *first = i;
    }
    return bad;
}

/* 0 when the backends agree; else says so loudly on stderr and returns RENDER_MISMATCH. */
static int check_backends(const frame *f, const report *r, int exact) {
    size_t first = 0, bad = hits_differ(f, exact, &first);
    if (!bad && r->hits == r->cl_hits && (!exact || r->t_sum == r->cl_t_sum)) return 0;
    fprintf(stderr,
            "render: !!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!\n"
            "render: !!! OpenCL and CPU DISAGREE: %zu of %zu pixels have another hit%s\n"
            "render: !!!   cpu    hits %llu  t_sum %.6f\n"
            "render: !!!   opencl hits %llu  t_sum %.6f\n",
            bad, (size_t)f->width * f->height, exact ? " (the device is exact: every bit must match)" : "",
            (unsigned long long)r->hits, r->t_sum, (unsigned long long)r->cl_hits, r->cl_t_sum);
    if (bad)
        fprintf(stderr, "render: !!!   first at pixel (%zu, %zu): cpu prim %d t %.9g, opencl prim %d t %.9g\n",
                first % f->width, first / f->width, (int)f->hits[first].prim, (double)f->hits[first].t,
                (int)f->cl_hits[first].prim, (double)f->cl_hits[first].t);
    fprintf(stderr, "render: !!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!\n");
    return RENDER_MISMATCH;
}

static void heat_summary(const frame *f, const options *o, report *r) {
    size_t i, n = (size_t)f->width * f->height;
    double sum = 0.0;
    r->heat_max = 0;
    for (i = 0; i < n; i++) {
        sum += f->visited[i];
        if (f->visited[i] > r->heat_max) r->heat_max = f->visited[i];
    }
    r->heat_mean = n ? sum / (double)n : 0.0;
    r->heat_scale = o->heat_max ? o->heat_max : heatmap_percentile(f->visited, n, 0.99);
    if (!r->heat_scale) r->heat_scale = 1;
}

/* Traces with the chosen backend (see the top of the file). 0, 1 (error, said; also --trace opencl
   without a usable device) or RENDER_MISMATCH. */
static int trace(const options *o, const bvh_tree *tree, frame *f, report *r) {
    size_t n = (size_t)f->width * f->height;
    gpu g;
    int rc, use_cl;
    memset(&g, 0, sizeof g);
    use_cl = o->trace != TRACE_CPU && gpu_open(&g, tree, o->trace == TRACE_OPENCL) == 0;
    if (!use_cl && o->trace == TRACE_OPENCL) return 1; /* asked for by name: no fallback */
    if (use_cl) {
        f->cl_hits = (bvh_hit *)malloc(n * sizeof(bvh_hit));
        if (!f->cl_hits) {
            fprintf(stderr, "render: out of memory for a %ux%u frame\n", f->width, f->height);
            gpu_close(&g);
            return 1;
        }
        r->opencl = 1;
        snprintf(r->device, sizeof r->device, "%s", g.info.device);
        rc = trace_cpu(tree, f, r->threads, 1, &r->trace_ms) ||
             trace_opencl(&g, f, o->frames, &r->frame_ms, &r->cl_kernel_ms);
        if (!rc) {
            hits_summary(f->hits, n, &r->hits, &r->t_sum);
            hits_summary(f->cl_hits, n, &r->cl_hits, &r->cl_t_sum);
            rc = check_backends(f, r, g.info.exact);
            r->disagree = rc != 0;
        }
    } else {
        snprintf(r->device, sizeof r->device, "cpu");
        trace_counted(tree, f, r->threads); /* the warm-up frame */
        rc = trace_cpu(tree, f, r->threads, o->frames, &r->trace_ms);
        r->frame_ms = r->trace_ms;
        if (!rc) hits_summary(f->hits, n, &r->hits, &r->t_sum);
    }
    gpu_close(&g);
    if (rc != 1) heat_summary(f, o, r);
    return rc;
}

/* ============================================================================================ */
/* == shading ================================================================================= */
/* ============================================================================================ */
static uint8_t to_byte(float c) { /* no gamma: keeps the contrast of a plain headlight */
    c = c <= 0.0f ? 0.0f : c >= 1.0f ? 1.0f : c;
    return (uint8_t)(c * 255.0f + 0.5f);
}

/* Headlight diffuse on light grey: |cos| between the geometric normal of the ORIGINAL triangle
   hit.prim (the scene's own array) and the ray; misses get a blue-grey vertical gradient. */
static void shade_frame(const frame *f, const bvh_hit *hits, const scene *s, uint8_t *rgb) {
    uint32_t x, y;
    for (y = 0; y < f->height; y++) {
        float g = (float)y / (float)(f->height > 1 ? f->height - 1 : 1);
        for (x = 0; x < f->width; x++) {
            const bvh_hit *h = &hits[(size_t)y * f->width + x];
            uint8_t *px = rgb + 3 * ((size_t)y * f->width + x);
            float c[3] = {0.45f - 0.30f * g, 0.55f - 0.35f * g, 0.75f - 0.40f * g};
            if (h->prim != BVH_INVALID) {
                const float *t = s->v + 9 * (size_t)h->prim;
                bvh_ray r = bvh_camera_ray(&f->cam, x, y);
                float e1[3] = {t[3] - t[0], t[4] - t[1], t[5] - t[2]}, e2[3] = {t[6] - t[0], t[7] - t[1], t[8] - t[2]};
                float n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                              e1[0] * e2[1] - e1[1] * e2[0]};
                float len = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
                float d = len > 0.0f ? fabsf(n[0] * r.dir.x + n[1] * r.dir.y + n[2] * r.dir.z) / len : 0.0f;
                c[0] = c[1] = c[2] = 0.9f * (0.1f + 0.9f * d);
            }
            px[0] = to_byte(c[0]);
            px[1] = to_byte(c[1]);
            px[2] = to_byte(c[2]);
        }
    }
}

static int write_frame(const frame *f, const scene *s, const char *path) {
    uint8_t *rgb = (uint8_t *)malloc((size_t)f->width * f->height * 3);
    char err[512];
    int rc;
    if (!rgb) {
        fprintf(stderr, "render: out of memory for the image\n");
        return 1;
    }
    shade_frame(f, f->cl_hits ? f->cl_hits : f->hits, s, rgb); /* the backend's own hits */
    rc = scene_write_image(path, f->width, f->height, rgb, err, sizeof err);
    free(rgb);
    if (rc) fprintf(stderr, "render: %s\n", err);
    return rc;
}

/* The nodes visited per pixel over 0 .. r->heat_scale, the legend below (heatmap.h). */
static int write_heatmap(const frame *f, const report *r, const char *builder, const char *path) {
    uint32_t h = f->height + heatmap_legend_height(f->width);
    uint8_t *rgb = (uint8_t *)malloc((size_t)f->width * h * 3);
    char title[160], err[512];
    int rc;
    if (!rgb) {
        fprintf(stderr, "render: out of memory for the heat map\n");
        return 1;
    }
    /* the longest title that fits the width with the smallest font */
    snprintf(title, sizeof title, "%s: nodes visited per pixel, mean %.1f, max %u", builder, r->heat_mean, r->heat_max);
    if (heatmap_text_width(title, 1) > (int)f->width - 8)
        snprintf(title, sizeof title, "%s: mean %.1f, max %u", builder, r->heat_mean, r->heat_max);
    if (heatmap_text_width(title, 1) > (int)f->width - 8) snprintf(title, sizeof title, "%s", builder);
    heatmap_render(f->visited, f->width, f->height, r->heat_scale, title, rgb);
    rc = scene_write_image(path, f->width, h, rgb, err, sizeof err);
    free(rgb);
    if (rc) fprintf(stderr, "render: %s\n", err);
    return rc;
}

/* ============================================================================================ */
/* == report ================================================================================== */
/* ============================================================================================ */
static void json_path(const char *path) {
    if (path)
        scene_json_string(stdout, path);
    else
        printf("null");
}

static double mrays(const options *o, double ms) {
    return ms > 0.0 ? (double)o->width * o->height / (ms * 1e-3) / 1e6 : 0.0;
}
static double set_mrays(uint64_t rays, double ms) { return ms > 0.0 ? (double)rays / (ms * 1e3) : 0.0; }

static void print_json(const options *o, const scene *s, const bvh_tree *tree, const report *r) {
    double bpt = s->triangles ? (double)r->stats.bytes / s->triangles : 0.0;
    printf("{\"scene\":");
    scene_json_string(stdout, s->name);
    printf(",\"triangles\":%u,\"skipped\":%u,\"excluded\":%u,\"builder\":\"%s\",\"threads\":%u,\"repeat\":%u,"
           "\"load_ms\":%.3f,\"build_ms\":%.3f,\"valid\":true,\"sah\":%.6f,\"nodes\":%u,\"leaves\":%u,"
           "\"refs\":%u,\"max_depth\":%u,\"max_leaf_size\":%u,\"bvh_bytes\":%zu,\"triangle_bytes\":%zu,"
           "\"bytes_per_tri\":%.3f,\"trace\":\"%s\",\"device\":",
           s->triangles, s->skipped, tree->excluded, bvh_builder_name(o->builder), r->threads, o->repeat, r->load_ms,
           r->build_ms, r->sah, r->stats.nodes, r->stats.leaves, r->stats.refs, r->stats.max_depth,
           r->stats.max_leaf_size, r->stats.bytes, r->stats.triangle_bytes, bpt, r->opencl ? "opencl" : "cpu");
    scene_json_string(stdout, r->device);
    printf(",\"width\":%u,\"height\":%u,\"frames\":%u,\"frame_ms\":%.3f,\"trace_ms\":%.3f,\"hits\":%llu,"
           "\"t_sum\":%.6f,\"mrays\":%.3f,",
           o->width, o->height, o->frames, r->frame_ms, r->trace_ms, (unsigned long long)r->hits, r->t_sum,
           mrays(o, r->trace_ms));
    if (r->opencl)
        printf("\"cl_mrays\":%.3f,\"cl_kernel_ms\":%.3f,\"cl_hits\":%llu,\"cl_t_sum\":%.6f,", mrays(o, r->frame_ms),
               r->cl_kernel_ms, (unsigned long long)r->cl_hits, r->cl_t_sum);
    else
        printf("\"cl_mrays\":null,\"cl_kernel_ms\":null,\"cl_hits\":null,\"cl_t_sum\":null,");
    if (r->diffuse_ms > 0.0)
        printf("\"diffuse_rays\":%llu,\"diffuse_hits\":%llu,\"diffuse_ms\":%.3f,\"diffuse_mrays\":%.3f,"
               "\"shadow_rays\":%llu,\"shadow_occluded\":%llu,\"shadow_ms\":%.3f,\"shadow_mrays\":%.3f,",
               (unsigned long long)r->diffuse_rays, (unsigned long long)r->diffuse_hits, r->diffuse_ms,
               set_mrays(r->diffuse_rays, r->diffuse_ms), (unsigned long long)r->shadow_rays,
               (unsigned long long)r->shadow_occluded, r->shadow_ms, set_mrays(r->shadow_rays, r->shadow_ms));
    else
        printf("\"diffuse_rays\":null,\"diffuse_hits\":null,\"diffuse_ms\":null,\"diffuse_mrays\":null,"
               "\"shadow_rays\":null,\"shadow_occluded\":null,\"shadow_ms\":null,\"shadow_mrays\":null,");
    printf("\"heat_mean\":%.3f,\"heat_max\":%u,\"heat_scale\":%u,\"image\":", r->heat_mean, r->heat_max, r->heat_scale);
    json_path(o->out);
    printf(",\"heatmap\":");
    json_path(o->heatmap);
    printf("}\n");
}

static void print_report(const options *o, const scene *s, const bvh_tree *tree, const report *r) {
    double bpt = s->triangles ? (double)r->stats.bytes / s->triangles : 0.0;
    if (o->json) {
        print_json(o, s, tree, r);
        return;
    }
    printf("scene    %s: %u triangles", s->name, s->triangles);
    if (s->skipped) printf(" (%u non-triangle or bad faces dropped)", s->skipped);
    if (tree->excluded) printf(" (%u excluded: NaN/Inf)", tree->excluded);
    printf(", loaded in %.1f ms\n", r->load_ms);
    printf("builder  %s, threads %u\n", bvh_builder_name(o->builder), r->threads);
    printf("build    %.2f ms (median of %u)\n", r->build_ms, o->repeat);
    printf("tree     valid; %u nodes, %u leaves, %u refs, max depth %u, max leaf %u\n", r->stats.nodes, r->stats.leaves,
           r->stats.refs, r->stats.max_depth, r->stats.max_leaf_size);
    printf("memory   %.2f MB nodes+refs (%.1f bytes/triangle) + %.2f MB triangle copy\n",
           (double)r->stats.bytes / 1048576.0, bpt, (double)r->stats.triangle_bytes / 1048576.0);
    printf("SAH      %.4f (costs 1, 0, 1)\n", r->sah);
    printf("trace    %ux%u primary rays %s%s: frame %.2f ms (median of %u after a warm-up)\n", o->width, o->height,
           r->opencl ? "with OpenCL on " : "on the CPU", r->opencl ? r->device : "", r->frame_ms, o->frames);
    printf("cpu      %llu hits, t_sum %.6f, %.2f ms (%s), %.2f Mrays/s\n", (unsigned long long)r->hits, r->t_sum,
           r->trace_ms, r->opencl ? "one frame" : "median", mrays(o, r->trace_ms));
    if (r->opencl)
        printf("opencl   %llu hits, t_sum %.6f (%s), %.2f ms (kernel %.2f ms), %.2f Mrays/s\n",
               (unsigned long long)r->cl_hits, r->cl_t_sum, r->disagree ? "NOT the CPU's" : "the CPU's", r->frame_ms,
               r->cl_kernel_ms, mrays(o, r->frame_ms));
    if (r->diffuse_ms > 0.0) {
        bvh_vec3 L = rays_light();
        printf("diffuse  %llu rays (one per hit, cosine-weighted), %llu hits, %.2f ms (median, CPU), %.2f Mrays/s\n",
               (unsigned long long)r->diffuse_rays, (unsigned long long)r->diffuse_hits, r->diffuse_ms,
               set_mrays(r->diffuse_rays, r->diffuse_ms));
        printf("shadow   %llu rays to (%.2f, %.2f, %.2f), %llu occluded, %.2f ms (median, CPU), %.2f Mrays/s\n",
               (unsigned long long)r->shadow_rays, (double)L.x, (double)L.y, (double)L.z,
               (unsigned long long)r->shadow_occluded, r->shadow_ms, set_mrays(r->shadow_rays, r->shadow_ms));
    }
    printf("heat     nodes visited per pixel: mean %.2f, max %u", r->heat_mean, r->heat_max);
    if (o->heatmap) printf("; map over 0..%u in %s", r->heat_scale, o->heatmap);
    printf("\n");
    if (o->out) printf("image    %s\n", o->out);
}

/* ============================================================================================ */
/* == main ==================================================================================== */
/* ============================================================================================ */
int main(int argc, char **argv) {
    options o;
    scene s;
    bvh_tree tree;
    frame f;
    report r;
    char err[512];
    int rc = parse_args(argc, argv, &o);
    double t0;
    if (rc) return rc == 1 ? 0 : 2;
    memset(&tree, 0, sizeof tree);
    memset(&f, 0, sizeof f);
    memset(&r, 0, sizeof r);
    r.threads = o.threads ? o.threads : scene_cpu_count();
    t0 = scene_now_ms();
    if (scene_load(o.scene_spec, &s, err, sizeof err) != 0) {
        fprintf(stderr, "render: %s\n", err);
        return 1;
    }
    r.load_ms = scene_now_ms() - t0;
    if (s.triangles > 0x55555555u) { /* vertex_count = 3 * triangles must fit 32 bits */
        fprintf(stderr, "render: %s has too many triangles (%u)\n", s.name, s.triangles);
        scene_free(&s);
        return 1;
    }
    rc = build_tree(&s, &o, &tree, &r.build_ms) || check_tree(&tree, &r) || frame_init(&f, &tree, o.width, o.height);
    if (!rc) rc = trace(&o, &tree, &f, &r);
    if (!rc) rc = trace_sets(&s, &tree, &f, r.threads, o.frames, &r);
    if (!rc && o.out) rc = write_frame(&f, &s, o.out);
    if (!rc && o.heatmap) rc = write_heatmap(&f, &r, bvh_builder_name(o.builder), o.heatmap);
    if (!rc || rc == RENDER_MISMATCH) print_report(&o, &s, &tree, &r);
    free(f.hits);
    free(f.cl_hits);
    free(f.visited);
    bvh_free(&tree);
    scene_free(&s);
    return rc ? 1 : 0;
}
