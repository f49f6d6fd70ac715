/* bvhbench.c - the study's Table I ("Comparison of BVH construction methods"), reproduced and
   extended: every builder of bvh.h on a set of scenes, side by side with Embree 3.

   build/bvhbench [--builder all|LIST] [--embree all|none|LIST] [--embree-flags default|robust]
                  [--threads N] [--repeat R]
                  [--size WxH] [--camera outside|inside] [--trace cpu|opencl|both|none] [--brute-max N] [--strict]
                  [--paired N] [--ploc-top N|off] [--max-bytes N|off] [--trace-width 2|8]
                  [--instances N] [--refit N] [--save-load] [--layout-cost]
                  [--md FILE] [--json FILE|-] [--plots DIR] [--quiet] [SCENE...]
   e.g. build/bvhbench --repeat 2 --size 256x256 gen:random:500 /usr/share/glmark2/models/bunny.obj
        make bench          (the default scenes below, writing out/bench/)

   Scenes: files or generators as build/render takes them (see --help). None given: the study's
   four sizes, gen:random:500, the Stanford bunny (~70K), gen:field:15 (~1M), gen:field:44 (~3M).

   Per scene and row: build time (median, min and max of R builds after one warm-up; for the
   builders that use threads, ploc-parallel and sah-midpoint, on N threads, and "build 1t" the
   median of R more on one thread), SAH with
   costs (1, 0, 1), tree statistics, bytes per triangle of the binary tree (nodes + references)
   and of the 8-wide copy CPU traversal uses (built by default, --trace-width), peak memory of
   the build (a counting bvh_allocator), the standard camera's primary rays (bvh_camera_standard
   over the tree bounds, bvh_camera_ray per pixel) traced on 1 CPU thread and on N CPU threads
   (bvh_intersect_batch; median time of 3 frames each) and with OpenCL (cl/bvh_cl.h: packets
   of 4 x 4 rays on a CPU device); frame ms = the fastest of those tracers, FPS = 1000 / frame ms.
   Beside the camera rays, the two sets of rays a renderer traces next (examples/rays.h, shared
   with build/render), made once per scene from the first bvh.h frame's hits and traced by every
   tracer on the same arrays, on 1 and on N CPU threads (median of 3 passes): "diffuse", one ray
   per primary hit, cosine-weighted about the geometric normal turned toward the viewer, from
   the hit point moved 1e-4 x the scene diagonal along that normal (fixed seed; closest hit:
   bvh_intersect_batch, Embree rtcIntersect1), and "shadow", from the same points toward the
   fixed light normalize(0.3, 1, 0.2) for the hits that face it (any hit, tmax infinite:
   bvh_occluded_batch, Embree rtcOccluded1); columns diff/shad 1t and Nt, their counts under
   the table. With --paired N, N rounds then each build once with every builder and once with
   Embree medium, and N more each trace the camera rays, the diffuse and the shadow rays on one
   thread with every tree and with Embree's scene, one right after the other, and N more each
   render a frame with OpenCL and trace it on the CPU's N threads: the medians of the rounds'
   ratios (and of the Mrays/s) are printed under the table and written to the JSON
   (ratio_build_paired; ratio_build_high_paired where the table has Embree high, which then
   builds once in each of the same rounds; ratio_build_ploc_paired for a <builder>+opt row where
   the table has ploc-parallel, the build time issue 19 measures the optimizer against;
   ratio_mrays_1t_paired, ratio_diffuse_1t_paired, ratio_shadow_1t_paired,
   ratio_opencl_mt_paired; mrays_1t_paired, diffuse_mrays_1t_paired,
   shadow_mrays_1t_paired), robust to a shared machine's slow moments in a way the ratio of two
   medians taken seconds apart is not. Each of bvh.h's one-thread passes is followed at once by
   the same pass on --threads threads: their ratio is the thread scaling, paired as well
   (scaling_mt_paired, diffuse_scaling_mt_paired, shadow_scaling_mt_paired; Embree medium's
   row has its own, on bvhbench's threads in chunks of 64 rays).
   Rows: "none" (brute force, the study's first row; only up to --brute-max triangles), the five
   builders, and Embree's scene API at build quality low, medium and high (rtcIntersect1 for the
   frame; the SAH, nodes and leaves of a binary tree from rtcBuildBVH at the same quality).
   Every Embree scene (the rows' builds and frames, the ray sets, the paired rounds) is built with
   the scene flags of --embree-flags: "default" (the default: no flags, Embree's own, what a
   renderer that picks Embree gets unless it opts in) or "robust" (RTC_SCENE_FLAG_ROBUST, the
   closest Embree comes to the watertight test bvh.h always makes; slower, see docs/bench/). The
   header line "Embree:", the Markdown and the JSON's "embree_flags" say which.
   Every frame must give the same hits. bvh.h's frames (brute force, every builder, 1 and N
   threads, OpenCL) must agree pixel for pixel, primitive and t. Embree's frames are compared
   pixel by pixel with bvh.h's and an exact (long double) ray-triangle test referees each pixel
   where they differ: a pixel bvh.h loses is a disagreement; pixels it wins, or grazing rays
   within float precision of an edge, mark Embree's row "(e)" with a note (a disagreement only
   with --strict). The diffuse rays (triangle and t to the bit) and the shadow rays (occluded or
   not) of bvh.h's tracers (brute force, every builder, 1 and N threads) must agree exactly too;
   Embree's N-thread answers must be its 1-thread ones, and its 1-thread answers may differ from
   bvh.h's on at most 1e-3 of a set's rays (grazing rays: noted "(e)" under the table, counted in
   the JSON's diffuse_rays_other_answer / shadow_rays_other_answer), beyond which they disagree.
   A disagreement is reported on stderr, marked "(!)" in the tables, and makes the exit status 3.

   With --refit N, each bvh.h row also runs an animated case: the scene twisted about its vertical
   axis and waved, a little more each of N frames; per frame bvh_refit of the row's tree and a
   rebuild by bottom-up (the fastest builder) are timed (medians: refit_ms, rebuild_ms), and, with
   Embree (unless --embree none), Embree 3's refit of the same frame in the one scene layout where
   it refits (two-level, a RTC_BUILD_QUALITY_REFIT mesh; embree_refit_ms); after the
   last frame the SAH of the refitted tree and of the row's builder rebuilt on it (refit_sah,
   rebuild_sah) and the camera rays' Mrays/s on N threads with each (refit_mrays, rebuild_mrays;
   their hits must agree). With --save-load, bvh_save and bvh_load to and from memory, a warm-up
   pair then R timed ones as the builds have them (medians: save_ms, load_ms; the warm-up's:
   save_first_ms, load_first_ms: a process's first touch of fresh huge pages can cost several
   times more, docs/bench 0.9.14); the 8-wide nodes are read and their packets remade on load.
   Each round also loads the same buffer with bvh_load_desc.borrow (the binary nodes, references
   and triangles read in place; load_borrow_ms), the two loads in turns (which goes first
   alternates).
   With --layout-cost, each timed build of a row is paired with one of the same desc but
   trace_width = 2, the two in turns (which goes first alternates), so that what the 8-wide
   layout adds to the build is measured in the same rounds: layout_ms, the median of the pairs'
   differences, and layout_share, that over the median build without it (build_ms_binary).
   All three are off by default.

   Exit status: 0 ok; 1 an error (a scene, build or output failed); 2 bad command line;
   3 the hits disagree. */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define SCENE_IMPLEMENTATION
#include "examples/scene.h"
#define EMB_IMPLEMENTATION
#include "embree_side.h"
#define RAYS_IMPLEMENTATION
#include "examples/rays.h"
#include "tests/tree_diff.h" /* "the same tree": the tests' one definition */
#define BVH_CL_IMPLEMENTATION
#include "cl/bvh_cl.h"

#include <errno.h>
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#define BENCH_MAX_PIXELS (64u * 1024u * 1024u)
#define BENCH_MAX_SCENES 64
#define BENCH_MAX_ROWS (1 + 2 * BVH_BUILDER_COUNT + 3)
#define BENCH_MAX_REPEAT 1000
#define BENCH_TRACE_REPEAT 3  /* frames per CPU, OpenCL and Embree tracer; median time */
#define BENCH_INST_ROUNDS 9   /* --instances: paired rounds of the tree and its one-instance scene */
#define BENCH_BRUTE_TESTS 1e9 /* brute force: at most this many ray-triangle tests per frame */
#define BENCH_BUNNY "/usr/share/glmark2/models/bunny.obj"
#define BENCH_OPT_ROUNDS 8     /* desc.optimize.rounds of the <builder>+opt rows */
#define BENCH_MAX_PAIRED 1000u /* --paired's limit */
#define BENCH_SET_TOLERANCE                                                                                            \
    1e-3 /* Embree may answer another way on this fraction of a secondary                                              \
            set's rays (grazing rays, float noise) before it disagrees */

typedef struct options {
    const char *scenes[BENCH_MAX_SCENES];
    int nscenes;
    int brute; /* the "none" row */
    bvh_builder builders[2 * BVH_BUILDER_COUNT];
    int opt[2 * BVH_BUILDER_COUNT]; /* the row's tree goes through the optimizer (<builder>+opt) */
    int nbuilders;
    emb_quality qualities[3];
    int nqualities;
    uint32_t threads;  /* as given, 0 = all cores */
    uint32_t nthreads; /* resolved */
    uint32_t repeat, width, height, brute_max, trace_width, ploc_top, max_bytes;
    uint32_t paired;    /* rounds of interleaved builds against Embree medium (0: none) */
    uint32_t instances; /* instances of the scene's tree for the top-level rebuild (0: none) */
    uint32_t refit;     /* frames of the animated case (--refit; 0: none) */
    int embree_robust;  /* --embree-flags robust: RTC_SCENE_FLAG_ROBUST on every Embree scene */
    int save_load;      /* --save-load: time bvh_save and bvh_load of every tree */
    int layout_cost;    /* --layout-cost: pair each timed build with one without the 8-wide layout */
    int inside;         /* --camera inside: rays.h's interior view instead of the standard camera */
    int trace_cpu, trace_cl, trace_auto;
    const char *md, *json, *plots, *argv0;
    int quiet, strict;
} options;

/* The secondary ray sets (examples/rays.h), made once per scene from the reference frame. */
enum { SET_DIFFUSE, SET_SHADOW, SET_COUNT };
static const char *const g_set_names[SET_COUNT] = {"diffuse", "shadow"};
typedef struct set_figs {
    double rays, count, t_sum; /* count: diffuse hits, shadow rays occluded */
    double ms_1t, mrays_1t, ms_mt, mrays_mt;
    double x_p, x_p_min, x_p_max; /* 1-thread Mrays/s / Embree medium's, paired rounds */
    double p_mrays;               /* median 1-thread Mrays/s of the paired rounds */
    double x_s, x_s_min, x_s_max; /* Mrays/s on N threads / on 1 thread, the same paired rounds */
    double other;                 /* Embree: rays answered otherwise than by bvh.h */
} set_figs;

/* One row of a scene's table. Every number is NAN when it does not apply ("-" / null). */
typedef enum row_kind { ROW_BRUTE, ROW_BVH, ROW_EMBREE } row_kind;
typedef enum row_state { ROW_OK, ROW_SKIPPED, ROW_FAILED } row_state;
typedef struct row {
    row_kind kind;
    bvh_builder builder;
    int opt; /* desc.optimize as BENCH_OPT_ROUNDS gives it (<builder>+opt) */
    emb_quality quality;
    char name[24];
    row_state state;
    char note[200]; /* why skipped or failed */
    double build_ms, build_min, build_max;
    double build_1t; /* bvh.h rows: median build ms on one thread (the builders that use threads) */
    double sah, nodes, leaves, refs, max_depth, max_leaf, bvh_bytes, tri_bytes, wide_bytes, peak_bytes;
    double ms_1t, mrays_1t, ms_mt, mrays_mt, ms_cl, mrays_cl, cl_kernel_ms;
    double frame_ms, fps, hits, t_sum;
    double x_build, x_sah, x_mrays;              /* ours / Embree medium */
    double x_pair, x_pair_min, x_pair_max;       /* build time / Embree medium's in paired rounds:
                                                    median, min, max of the rounds' ratios */
    double pair_ms;                              /* median build ms in the paired rounds (bvh.h rows
                                                    and the Embree medium and high rows) */
    double x_pairh, x_pairh_min, x_pairh_max;    /* the same against Embree high, where the table has it */
    double x_pairo, x_pairo_min, x_pairo_max;    /* <builder>+opt rows: build time /
                                                    ploc-parallel's (issue 19's yardstick) in
                                                    the same paired rounds, where it is run */
    double x_ptrace, x_ptrace_min, x_ptrace_max; /* 1-thread Mrays/s / Embree medium's, paired */
    double x_scale, x_scale_min, x_scale_max;    /* camera rays' Mrays/s on N threads / on 1, paired */
    double x_pcl, x_pcl_min, x_pcl_max;          /* OpenCL frame Mrays/s / the CPU's on N threads, paired */
    double p_mrays;                              /* median 1-thread Mrays/s of the paired rounds */
    set_figs set[SET_COUNT];                     /* the diffuse and shadow rays */
    char set_note[320];                          /* Embree: its answers on the sets, where they differ */
    double emb_bvh_ms, emb_prim_diff;            /* Embree: rtcBuildBVH time; pixels whose triangle
                                                    differs from bvh.h's */
    double refit_ms, rebuild_ms;                 /* --refit: median per-frame bvh_refit of this tree,
                                                    and rebuild by the fastest builder (bottom-up) */
    double emb_refit_ms;                         /* the same frames refitted by Embree (NAN: none) */
    double refit_sah, rebuild_sah;               /* the last frame: SAH of the refitted tree, and of
                                                    this builder's tree rebuilt on it */
    double refit_mrays, rebuild_mrays;           /* camera rays of the last frame on N threads */
    double save_ms, load_ms;                     /* --save-load: to and from memory (median of R) */
    double load_borrow_ms;                       /* the same loads with bvh_load_desc.borrow */
    double build2_ms, layout_ms;                 /* --layout-cost: median build with trace_width 2, and
                                                    median of the paired differences */
    double save_first_ms, load_first_ms;         /* the warm-up pair's */
    const char *frame_tracer;
    int disagree; /* (!): the hits disagree */
    char disagree_msg[320];
    int refereed; /* (e): Embree differs from bvh.h on pixels where an
                     exact test decides for bvh.h */
    char referee_msg[320];
} row;

typedef struct bench_scene {
    char name[256];
    uint32_t triangles;
    row rows[BENCH_MAX_ROWS];
    int nrows;
    int disagree;
    /* instances (--instances): bvh_scene_build over that many instances of the default tree (the
       top-level rebuild), median/min/max ms; the camera rays on 1 thread through a scene of one
       identity instance and through the tree itself (Mrays/s). NAN: not measured. */
    double inst_ms, inst_min, inst_max, inst_mrays_1t, one_level_mrays_1t;
    double inst_ratio, inst_ratio_min, inst_ratio_max; /* per round: scene Mrays/s over the tree's */
} bench_scene;

/* ============================================================================================ */
/* == small helpers ============================================================================= */
/* ============================================================================================ */
static int g_quiet, g_progress_open;

/* One progress line on stderr, rewritten in place on a terminal. */
static void progress(const char *fmt, ...) {
    va_list ap;
    if (g_quiet) return;
    if (isatty(2)) fputs("\r\033[K", stderr);
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    if (isatty(2))
        g_progress_open = 1;
    else
        fputc('\n', stderr);
    fflush(stderr);
}
static void progress_end(void) {
    if (g_progress_open) fputs("\r\033[K", stderr);
    g_progress_open = 0;
}
/* A message on stderr that does not mix with the progress line. */
static void say(const char *fmt, ...) {
    va_list ap;
    progress_end();
    va_start(ap, fmt);
    fputs("bvhbench: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
}

/* The median, smallest and largest of x[0..n), n > 0 (sorts x). */
static void median_range(double *x, uint32_t n, double *med, double *lo, double *hi) {
    *med = scene_median(x, n);
    *lo = x[0];
    *hi = x[n - 1];
}

static void row_init(row *r, row_kind kind, const char *name) {
    int k;
    memset(r, 0, sizeof *r);
    r->kind = kind;
    snprintf(r->name, sizeof r->name, "%s", name);
    r->build_ms = r->build_min = r->build_max = r->build_1t = NAN;
    r->sah = r->nodes = r->leaves = r->refs = r->max_depth = r->max_leaf = NAN;
    r->bvh_bytes = r->tri_bytes = r->wide_bytes = r->peak_bytes = NAN;
    r->ms_1t = r->mrays_1t = r->ms_mt = r->mrays_mt = r->ms_cl = r->mrays_cl = r->cl_kernel_ms = NAN;
    r->frame_ms = r->fps = r->hits = r->t_sum = NAN;
    r->x_build = r->x_sah = r->x_mrays = r->emb_bvh_ms = r->emb_prim_diff = NAN;
    r->x_pair = r->x_pair_min = r->x_pair_max = r->pair_ms = NAN;
    r->x_pairh = r->x_pairh_min = r->x_pairh_max = NAN;
    r->x_pairo = r->x_pairo_min = r->x_pairo_max = NAN;
    r->x_ptrace = r->x_ptrace_min = r->x_ptrace_max = NAN;
    r->x_scale = r->x_scale_min = r->x_scale_max = NAN;
    r->x_pcl = r->x_pcl_min = r->x_pcl_max = r->p_mrays = NAN;
    r->refit_ms = r->rebuild_ms = r->emb_refit_ms = r->refit_sah = r->rebuild_sah = r->refit_mrays = r->rebuild_mrays =
        NAN;
    r->save_ms = r->load_ms = r->save_first_ms = r->load_first_ms = r->load_borrow_ms = NAN;
    r->build2_ms = r->layout_ms = NAN;
    for (k = 0; k < SET_COUNT; k++) {
        set_figs *f = &r->set[k];
        f->rays = f->count = f->t_sum = f->ms_1t = f->mrays_1t = f->ms_mt = f->mrays_mt = NAN;
        f->x_p = f->x_p_min = f->x_p_max = f->p_mrays = f->other = NAN;
        f->x_s = f->x_s_min = f->x_s_max = NAN;
    }
    r->frame_tracer = NULL;
}

static double mrays_of(size_t rays, double ms) { return ms > 0.0 ? (double)rays / (ms * 1e3) : NAN; }

/* the fastest tracer gives the frame time */
static void frame_pick(row *r, double ms, const char *tracer) {
    if (!isnan(ms) && (isnan(r->frame_ms) || ms < r->frame_ms)) {
        r->frame_ms = ms;
        r->fps = ms > 0.0 ? 1000.0 / ms : NAN;
        r->frame_tracer = tracer;
    }
}

/* ============================================================================================ */
/* == peak build memory: a counting allocator ==================================================== */
/* ============================================================================================ */
typedef union mem_header {
    size_t size;
    max_align_t align;
} mem_header;
typedef struct mem_counter {
    atomic_size_t live, peak;
} mem_counter;

static void *count_alloc(size_t size, void *user) {
    mem_counter *c = (mem_counter *)user;
    mem_header *h;
    size_t now, peak;
    if (size > SIZE_MAX - sizeof *h) return NULL;
    h = (mem_header *)malloc(sizeof *h + size);
    if (!h) return NULL;
    h->size = size;
    now = atomic_fetch_add(&c->live, size) + size;
    peak = atomic_load(&c->peak);
    while (now > peak && !atomic_compare_exchange_weak(&c->peak, &peak, now)) {
    }
    return h + 1;
}
static void count_free(void *ptr, void *user) {
    mem_counter *c = (mem_counter *)user;
    mem_header *h = (mem_header *)ptr - 1;
    atomic_fetch_sub(&c->live, h->size);
    free(h);
}

/* ============================================================================================ */
/* == OpenCL adapter: the only code that calls cl/bvh_cl.h ======================================= */
/* ============================================================================================ */
typedef struct bench_cl {
    bvh_cl_context *ctx;
    char device[400];
} bench_cl;

/* Opens the first device (or $BVH_CL_DEVICE) with the kernel bvh_cl.h holds. 0 on success, else
   a reason in msg. */
static int bcl_open(bench_cl *b, char *msg, size_t msglen) {
    char log[4096] = "";
    bvh_cl_desc d;
    bvh_cl_device_info info;
    bvh_cl_result r;
    memset(b, 0, sizeof *b);
    memset(&d, 0, sizeof d);
    d.log = log;
    d.log_size = sizeof log;
    if (getenv("BVH_CL_FRAME_RAYS")) d.frame_rays = atoi(getenv("BVH_CL_FRAME_RAYS")); /* 1 or 8: compare */
    r = bvh_cl_create(&b->ctx, &d);
    if (r != BVH_CL_SUCCESS) {
        const char *what = bvh_cl_result_string(r);
        if (!log[0] || strstr(what, log))
            snprintf(msg, msglen, "%s", what);
        else
            snprintf(msg, msglen, "%s: %.300s", what, log);
        return 1;
    }
    if (bvh_cl_get_info(b->ctx, &info) == BVH_CL_SUCCESS)
        snprintf(b->device, sizeof b->device, "%s, %s (%s)", info.platform, info.device, info.version);
    return 0;
}

/* The camera's primary rays on the device: hits per pixel, the wall time of a frame (hits read
   back included) and the kernels' own time, both of the median of BENCH_TRACE_REPEAT frames after
   a warm-up, as for the CPU tracers. 0 on success. */
static int bcl_frame(bench_cl *b, const bvh_tree *tree, const bvh_camera *cam, bvh_hit *hits, double *wall_ms,
                     double *kernel_ms, char *msg, size_t msglen) {
    bvh_cl_tree *gpu = NULL;
    bvh_cl_result r = bvh_cl_upload(b->ctx, tree, &gpu);
    double t0;
    if (r == BVH_CL_SUCCESS) { /* warm-up: the first launch compiles the work-group function */
        bvh_camera tiny = *cam;
        tiny.width = tiny.height = 8;
        r = bvh_cl_render_frame(gpu, &tiny, NULL, NULL, NULL);
    }
    if (r == BVH_CL_SUCCESS) {
        double wall[BENCH_TRACE_REPEAT], kern[BENCH_TRACE_REPEAT];
        int i;
        for (i = 0; i < BENCH_TRACE_REPEAT && r == BVH_CL_SUCCESS; i++) {
            t0 = scene_now_ms();
            r = bvh_cl_render_frame(gpu, cam, NULL, hits, NULL);
            wall[i] = scene_now_ms() - t0;
            kern[i] = bvh_cl_last_kernel_ms(b->ctx);
        }
        if (r == BVH_CL_SUCCESS) {
            *wall_ms = scene_median(wall, BENCH_TRACE_REPEAT);
            *kernel_ms = scene_median(kern, BENCH_TRACE_REPEAT);
        }
    }
    bvh_cl_tree_free(gpu);
    if (r != BVH_CL_SUCCESS) {
        const char *call = "";
        int err = bvh_cl_last_error(b->ctx, &call);
        snprintf(msg, msglen, "OpenCL: %s (%s %d)", bvh_cl_result_string(r), call, err);
        return 1;
    }
    return 0;
}

static void bcl_close(bench_cl *b) {
    bvh_cl_destroy(b->ctx);
    b->ctx = NULL;
}

/* ============================================================================================ */
/* == brute force (the "none" row) ================================================================ */
/* ============================================================================================ */
typedef struct brute_job {
    const float *v;
    const uint32_t *ids; /* triangles to test (the finite ones), ascending */
    uint32_t nids;
    const bvh_ray *rays;
    bvh_hit *hits;
    size_t count;
    uint32_t tid, nt;
    int any; /* any hit: stop at the first (shadow rays) */
} brute_job;

/* Closest hit over every triangle in index order; ties in t keep the lower index, as bvh.h. */
static void brute_ray(const brute_job *j, size_t i) {
    bvh_ray ray = j->rays[i];
    bvh_hit best, h;
    uint32_t k;
    best.t = ray.tmax;
    best.u = best.v = 0.0f;
    best.prim = BVH_INVALID;
    for (k = 0; k < j->nids; k++) {
        const float *t = j->v + 9 * (size_t)j->ids[k];
        if (bvh_intersect_triangle(&ray, t, t + 3, t + 6, &h) && (best.prim == BVH_INVALID || h.t < best.t)) {
            best = h;
            best.prim = j->ids[k];
            ray.tmax = h.t;
            if (j->any) break;
        }
    }
    j->hits[i] = best;
}
static void *brute_worker(void *arg) {
    const brute_job *j = (const brute_job *)arg;
    size_t chunk, i, end;
    for (chunk = (size_t)j->tid * 256; chunk < j->count; chunk += (size_t)j->nt * 256) {
        end = chunk + 256 < j->count ? chunk + 256 : j->count;
        for (i = chunk; i < end; i++) brute_ray(j, i);
    }
    return NULL;
}
/* Traces on `threads` threads (the caller is one of them); 0 on success. */
static int trace_brute(const float *v, const uint32_t *ids, uint32_t nids, const bvh_ray *rays, bvh_hit *hits,
                       size_t count, uint32_t threads, int any, double *ms) {
    brute_job jobs[256];
    pthread_t tid[256];
    uint32_t k, started = 1;
    double t0;
    int rc = 0;
    for (k = 0; k < threads; k++) {
        jobs[k].v = v;
        jobs[k].ids = ids;
        jobs[k].nids = nids;
        jobs[k].rays = rays;
        jobs[k].hits = hits;
        jobs[k].count = count;
        jobs[k].tid = k;
        jobs[k].nt = threads;
        jobs[k].any = any;
    }
    t0 = scene_now_ms();
    for (k = 1; k < threads; k++, started++)
        if (pthread_create(&tid[k], NULL, brute_worker, &jobs[k]) != 0) {
            rc = 1;
            break;
        }
    if (!rc) brute_worker(&jobs[0]);
    for (k = 1; k < started; k++) pthread_join(tid[k], NULL);
    *ms = scene_now_ms() - t0;
    return rc;
}

/* ============================================================================================ */
/* == one scene ================================================================================== */
/* ============================================================================================ */
typedef struct run_ctx {
    const options *o;
    const scene *s;
    bench_scene *out;
    bench_cl *cl;  /* NULL: no OpenCL */
    uint32_t *ids; /* the finite triangles */
    uint32_t nids;
    bvh_aabb bounds; /* of the finite triangles = the root box of every tree */
    size_t npix;
    bvh_ray *rays;
    bvh_hit *hits, *ref; /* a frame; the scene's reference frame (the first bvh.h traced) */
    uint32_t *emb_prims;
    int has_ref;
    char ref_name[48];
    double ref_hits;        /* hit count of the first frame (bvh.h or Embree) ... */
    char ref_hits_name[48]; /* ... and its row */
    rays_set sets;          /* diffuse and shadow rays from the reference frame, made once */
    int has_sets;
    bvh_hit *dhits, *dref; /* a diffuse frame; the reference one (the first bvh.h traced) */
    uint8_t *occ, *oref;   /* a shadow frame; the reference one */
    int has_sref[SET_COUNT];
    char sref_name[SET_COUNT][48];
    double sref_count[SET_COUNT]; /* the reference's diffuse hits, shadow rays occluded */
    mem_counter mem;
} run_ctx;

static void flag(run_ctx *c, row *r, const char *fmt, ...) {
    va_list ap;
    char msg[320];
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (!r->disagree) snprintf(r->disagree_msg, sizeof r->disagree_msg, "%s", msg);
    r->disagree = 1;
    c->out->disagree = 1;
    say("!!! HITS DISAGREE on %s: %s", c->out->name, msg);
}

/* Hit count and t_sum of a frame (in pixel order); compares it with the reference frame, or
   makes it the reference. */
static void check_frame(run_ctx *c, row *r, const char *tracer, const bvh_hit *h) {
    size_t i, diff = 0, first = 0;
    double hits = 0.0, t_sum = 0.0;
    for (i = 0; i < c->npix; i++)
        if (h[i].prim != BVH_INVALID) {
            hits += 1.0;
            t_sum += (double)h[i].t;
        }
    if (isnan(r->hits)) {
        r->hits = hits;
        r->t_sum = t_sum;
    }
    if (!c->has_ref) {
        memcpy(c->ref, h, c->npix * sizeof *h);
        c->has_ref = 1;
        snprintf(c->ref_name, sizeof c->ref_name, "%s %s", r->name, tracer);
        if (isnan(c->ref_hits)) {
            c->ref_hits = hits;
            snprintf(c->ref_hits_name, sizeof c->ref_hits_name, "%s", c->ref_name);
        }
        return;
    }
    for (i = 0; i < c->npix; i++)
        if (h[i].prim != c->ref[i].prim || (h[i].prim != BVH_INVALID && memcmp(&h[i].t, &c->ref[i].t, sizeof(float))))
            if (!diff++) first = i;
    if (hits != c->ref_hits || diff)
        flag(c, r, "%s %s: %.0f hits, %zu pixels differ from %s (first at x=%zu y=%zu)", r->name, tracer, hits, diff,
             c->ref_name, first % c->o->width, first / c->o->width);
    else if (hits != r->hits || t_sum != r->t_sum)
        flag(c, r, "%s %s: hits or t_sum differ from the row's first frame", r->name, tracer);
}

/* The frame's camera over bounds: the standard one (outside, looking at the centre) or, with
   --camera inside, rays.h's interior view (a path tracer's rays inside a room). */
static bvh_camera bench_camera(const options *o, bvh_aabb bounds) {
    return o->inside ? rays_camera_inside(bounds, o->width, o->height)
                     : bvh_camera_standard(bounds, o->width, o->height);
}

static void make_rays(run_ctx *c, bvh_aabb bounds, bvh_camera *cam) {
    uint32_t x, y;
    size_t i = 0;
    *cam = bench_camera(c->o, bounds);
    for (y = 0; y < c->o->height; y++)
        for (x = 0; x < c->o->width; x++) c->rays[i++] = bvh_camera_ray(cam, x, y);
}

/* ---- the secondary ray sets (examples/rays.h) --------------------------------------------------- */
/* Makes the diffuse and shadow rays from the reference frame (once per scene, the first bvh.h
   frame: every tracer gets the same arrays) and the buffers of their answers. 0 when the sets
   exist. */
static int make_sets(run_ctx *c) {
    bvh_camera cam;
    size_t n;
    if (c->has_sets) return 0;
    if (!c->has_ref) return 1;
    cam = bench_camera(c->o, c->bounds);
    if (rays_make(&cam, c->ref, c->s->v, c->bounds, &c->sets)) return 1;
    n = c->sets.ndiffuse ? c->sets.ndiffuse : 1; /* nshadow <= ndiffuse */
    c->dhits = (bvh_hit *)malloc(n * sizeof *c->dhits);
    c->dref = (bvh_hit *)malloc(n * sizeof *c->dref);
    c->occ = (uint8_t *)malloc(n);
    c->oref = (uint8_t *)malloc(n);
    if (!c->dhits || !c->dref || !c->occ || !c->oref) {
        say("%s: out of memory for the diffuse and shadow rays", c->out->name);
        return 1;
    }
    c->has_sets = 1;
    return 0;
}
static size_t set_size(const run_ctx *c, int set) { return set == SET_DIFFUSE ? c->sets.ndiffuse : c->sets.nshadow; }
static const bvh_ray *set_rays(const run_ctx *c, int set) {
    return set == SET_DIFFUSE ? c->sets.diffuse : c->sets.shadow;
}

/* The count (diffuse hits, shadow rays occluded) and t_sum of a set's answers (c->dhits or
   c->occ); compares them ray by ray (prim and t to the bit; occluded or not) with the set's
   reference, or makes them the reference. bvh.h's tracers must agree exactly. */
static void check_set(run_ctx *c, row *r, int set, const char *tracer) {
    size_t i, n = set_size(c, set), diff = 0, first = 0;
    double count = 0.0, t_sum = 0.0;
    set_figs *f = &r->set[set];
    for (i = 0; i < n; i++) {
        if (set == SET_SHADOW)
            count += c->occ[i];
        else if (c->dhits[i].prim != BVH_INVALID) {
            count += 1.0;
            t_sum += (double)c->dhits[i].t;
        }
    }
    f->rays = (double)n;
    if (isnan(f->count)) {
        f->count = count;
        f->t_sum = t_sum;
    }
    if (!c->has_sref[set]) {
        if (set == SET_SHADOW)
            memcpy(c->oref, c->occ, n);
        else
            memcpy(c->dref, c->dhits, n * sizeof *c->dhits);
        c->has_sref[set] = 1;
        c->sref_count[set] = count;
        snprintf(c->sref_name[set], sizeof c->sref_name[set], "%s %s", r->name, tracer);
        return;
    }
    for (i = 0; i < n; i++) {
        int same = set == SET_SHADOW
                       ? c->occ[i] == c->oref[i]
                       : c->dhits[i].prim == c->dref[i].prim &&
                             (c->dhits[i].prim == BVH_INVALID || !memcmp(&c->dhits[i].t, &c->dref[i].t, sizeof(float)));
        if (!same && !diff++) first = i;
    }
    if (diff)
        flag(c, r, "%s %s %s rays: %.0f %s, %zu rays differ from %s (first: ray %zu)", r->name, tracer,
             g_set_names[set], count, set == SET_SHADOW ? "occluded" : "hits", diff, c->sref_name[set], first);
    else if (count != f->count || t_sum != f->t_sum)
        flag(c, r, "%s %s %s rays: the answers differ from the row's first pass", r->name, tracer, g_set_names[set]);
}

/* BENCH_TRACE_REPEAT passes over a set on `threads` threads; *ms = the median time */
static bvh_result trace_set(run_ctx *c, const bvh_tree *tree, int set, uint32_t threads, double *ms) {
    double v[BENCH_TRACE_REPEAT];
    uint32_t i;
    for (i = 0; i < BENCH_TRACE_REPEAT; i++) {
        double t0 = scene_now_ms();
        bvh_result res = set == SET_DIFFUSE
                             ? bvh_intersect_batch(tree, c->sets.diffuse, c->dhits, c->sets.ndiffuse, threads)
                             : bvh_occluded_batch(tree, c->sets.shadow, c->occ, c->sets.nshadow, threads);
        v[i] = scene_now_ms() - t0;
        if (res != BVH_SUCCESS) return res;
    }
    *ms = scene_median(v, BENCH_TRACE_REPEAT);
    return BVH_SUCCESS;
}

/* Both sets with a tree, on 1 and on N threads. */
static bvh_result tree_sets(run_ctx *c, row *r, const bvh_tree *tree) {
    const options *o = c->o;
    char tag[32];
    int set;
    if (make_sets(c)) return BVH_SUCCESS;
    for (set = 0; set < SET_COUNT; set++) {
        set_figs *f = &r->set[set];
        size_t n = set_size(c, set);
        bvh_result res;
        progress("%s: %s, %s rays, 1 thread", c->out->name, r->name, g_set_names[set]);
        if ((res = trace_set(c, tree, set, 1, &f->ms_1t)) != BVH_SUCCESS) return res;
        f->mrays_1t = mrays_of(n, f->ms_1t);
        check_set(c, r, set, "cpu-1t");
        f->ms_mt = f->ms_1t;
        if (o->nthreads > 1) {
            progress("%s: %s, %s rays, %u threads", c->out->name, r->name, g_set_names[set], o->nthreads);
            if ((res = trace_set(c, tree, set, o->nthreads, &f->ms_mt)) != BVH_SUCCESS) return res;
            snprintf(tag, sizeof tag, "cpu-%ut", o->nthreads);
            check_set(c, r, set, tag);
        }
        f->mrays_mt = mrays_of(n, f->ms_mt);
    }
    return BVH_SUCCESS;
}

/* Both sets by brute force (closest hit, or any hit for the shadow rays); one pass each. */
static int brute_sets(run_ctx *c, row *r) {
    uint32_t threads[2] = {1, c->o->nthreads}, passes = c->o->nthreads > 1 ? 2 : 1, k;
    char tag[32];
    int set;
    if (make_sets(c)) return 0;
    for (set = 0; set < SET_COUNT; set++) {
        set_figs *f = &r->set[set];
        size_t n = set_size(c, set), i;
        for (k = 0; k < passes; k++) {
            uint32_t th = threads[k];
            double ms;
            progress("%s: none (brute force), %s rays, %u thread(s)", c->out->name, g_set_names[set], th);
            if (trace_brute(c->s->v, c->ids, c->nids, set_rays(c, set), c->dhits, n, th, set == SET_SHADOW, &ms))
                return 1;
            if (set == SET_SHADOW)
                for (i = 0; i < n; i++) c->occ[i] = c->dhits[i].prim != BVH_INVALID;
            snprintf(tag, sizeof tag, "cpu-%ut", th);
            check_set(c, r, set, tag);
            if (th == 1) {
                f->ms_1t = ms;
                f->mrays_1t = mrays_of(n, ms);
            }
            f->ms_mt = ms;
            f->mrays_mt = mrays_of(n, ms);
        }
    }
    return 0;
}

static void run_brute(run_ctx *c, row *r) {
    const options *o = c->o;
    bvh_camera cam;
    double tests = (double)c->nids * (double)c->npix, ms;
    char tag[32];
    r->build_ms = r->build_min = r->build_max = 0.0; /* the study's "0": nothing is built */
    if (!o->trace_cpu) {
        r->state = ROW_SKIPPED;
        snprintf(r->note, sizeof r->note, "skipped (%s)",
                 o->trace_cl ? "brute force runs on the CPU only, see --trace" : "no tracing: --trace none");
        return;
    }
    if (c->nids > o->brute_max || tests > BENCH_BRUTE_TESTS) {
        r->state = ROW_SKIPPED;
        snprintf(r->note, sizeof r->note, "skipped (too slow: %u triangles x %zu rays%s)", c->nids, c->npix,
                 c->nids > o->brute_max ? ", above --brute-max" : "");
        return;
    }
    make_rays(c, c->bounds, &cam);
    progress("%s: none (brute force), 1 thread", c->out->name);
    if (trace_brute(c->s->v, c->ids, c->nids, c->rays, c->hits, c->npix, 1, 0, &ms)) goto thread_fail;
    r->ms_1t = ms;
    r->mrays_1t = mrays_of(c->npix, ms);
    frame_pick(r, ms, "cpu-1t");
    check_frame(c, r, "cpu-1t", c->hits);
    if (o->nthreads > 1) {
        progress("%s: none (brute force), %u threads", c->out->name, o->nthreads);
        if (trace_brute(c->s->v, c->ids, c->nids, c->rays, c->hits, c->npix, o->nthreads, 0, &ms)) goto thread_fail;
        snprintf(tag, sizeof tag, "cpu-%ut", o->nthreads);
        check_frame(c, r, tag, c->hits);
    }
    r->ms_mt = ms;
    r->mrays_mt = mrays_of(c->npix, ms);
    frame_pick(r, ms, "cpu-mt");
    if (brute_sets(c, r)) goto thread_fail;
    return;
thread_fail:
    r->state = ROW_FAILED;
    snprintf(r->note, sizeof r->note, "failed: cannot create a thread");
}

/* Builds 1 + repeat times (the first is a warm-up); keeps the last tree. The warm-up build goes
   through the counting allocator for the peak memory; the timed ones use the library's default
   allocator, as a user's would (no atomic counting in the timings, and on Linux the library's
   huge-page advice, which it gives only to its default allocator's blocks). */
static void bench_desc(const run_ctx *c, const row *r, bvh_build_desc *desc) {
    const options *o = c->o;
    memset(desc, 0, sizeof *desc);
    desc->builder = r->builder;
    desc->optimize.rounds = r->opt ? BENCH_OPT_ROUNDS : 0;
    desc->threads = o->threads;
    desc->trace_width = o->trace_width;
    desc->ploc.top = o->ploc_top;
    desc->ploc.max_bytes_per_prim = o->max_bytes;
    desc->skip_invalid = 1;
    desc->triangles.positions = c->s->v;
    desc->triangles.vertex_count = 3 * c->s->triangles;
    desc->triangles.triangle_count = c->s->triangles;
}
/* --layout-cost: one build of desc without the 8-wide layout, its time into *ms; 0 if it failed. */
static int build_binary(bvh_build_desc desc, double *ms) {
    bvh_tree t;
    double t0;
    bvh_result res;
    memset(&desc.allocator, 0, sizeof desc.allocator);
    desc.trace_width = 2;
    t0 = scene_now_ms();
    res = bvh_build(&t, &desc);
    *ms = scene_now_ms() - t0;
    if (res == BVH_SUCCESS) bvh_free(&t);
    return res == BVH_SUCCESS;
}
static int build_repeated(run_ctx *c, row *r, bvh_tree *tree) {
    const options *o = c->o;
    bvh_build_desc desc;
    double ms[BENCH_MAX_REPEAT], ms2[BENCH_MAX_REPEAT], diff[BENCH_MAX_REPEAT], peak = 0.0;
    uint32_t rep;
    int pair;
    bench_desc(c, r, &desc);
    pair = o->layout_cost && desc.trace_width != 2;
    for (rep = 0; rep <= o->repeat; rep++) {
        double t0;
        size_t live;
        bvh_result res;
        progress("%s: %s, build %u/%u%s", c->out->name, r->name, rep, o->repeat, rep ? "" : " (warm-up)");
        bvh_free(tree);
        if (pair && (rep & 1) && !build_binary(desc, &ms2[rep - 1])) {
            r->state = ROW_FAILED;
            snprintf(r->note, sizeof r->note, "failed with trace_width 2");
            return 1;
        }
        if (rep == 0) {
            desc.allocator.alloc = count_alloc;
            desc.allocator.free = count_free;
            desc.allocator.user = &c->mem;
        } else {
            memset(&desc.allocator, 0, sizeof desc.allocator);
        }
        live = atomic_load(&c->mem.live);
        atomic_store(&c->mem.peak, live);
        t0 = scene_now_ms();
        res = bvh_build(tree, &desc);
        if (rep) ms[rep - 1] = scene_now_ms() - t0;
        if (res != BVH_SUCCESS) {
            r->state = ROW_FAILED;
            snprintf(r->note, sizeof r->note, "failed: %s", bvh_result_string(res));
            return 1;
        }
        if (rep == 0) peak = (double)(atomic_load(&c->mem.peak) - live);
        /* without the layout after it in even rounds and the warm-up, before it in odd ones */
        if (pair && !(rep & 1) && !build_binary(desc, &ms2[rep ? rep - 1 : 0])) {
            r->state = ROW_FAILED;
            snprintf(r->note, sizeof r->note, "failed with trace_width 2");
            return 1;
        }
    }
    if (pair) {
        for (rep = 0; rep < o->repeat; rep++) diff[rep] = ms[rep] - ms2[rep];
        r->build2_ms = scene_median(ms2, o->repeat);
        r->layout_ms = scene_median(diff, o->repeat);
    }
    median_range(ms, o->repeat, &r->build_ms, &r->build_min, &r->build_max);
    r->peak_bytes = peak;
    r->build_1t = r->build_ms;
    if (desc.threads != 1 && o->nthreads > 1) {
        bvh_builder_info info;
        if (bvh_builder_get_info(r->builder, &info) == BVH_SUCCESS && info.uses_threads) {
            desc.threads = 1;
            for (rep = 0; rep < o->repeat; rep++) {
                double t0;
                progress("%s: %s, build on 1 thread %u/%u", c->out->name, r->name, rep + 1, o->repeat);
                bvh_free(tree);
                t0 = scene_now_ms();
                if (bvh_build(tree, &desc) != BVH_SUCCESS) {
                    r->state = ROW_FAILED;
                    snprintf(r->note, sizeof r->note, "failed on 1 thread");
                    return 1;
                }
                ms[rep] = scene_now_ms() - t0;
            }
            r->build_1t = scene_median(ms, o->repeat);
        }
    }
    return 0;
}

static int tree_figures(row *r, const bvh_tree *tree) {
    bvh_validation v;
    bvh_stats st;
    bvh_result res = bvh_validate(tree, NULL, &v);
    if (res != BVH_SUCCESS) {
        r->state = ROW_FAILED;
        snprintf(r->note, sizeof r->note, "failed: invalid tree: %s (node %d)",
                 res == BVH_ERROR_INVALID_TREE ? v.message : bvh_result_string(res),
                 v.node == BVH_INVALID ? -1 : (int)v.node);
        return 1;
    }
    if (bvh_sah(tree, NULL, &r->sah) != BVH_SUCCESS || bvh_get_stats(tree, &st) != BVH_SUCCESS) {
        r->state = ROW_FAILED;
        snprintf(r->note, sizeof r->note, "failed: no SAH or statistics");
        return 1;
    }
    r->nodes = st.nodes;
    r->leaves = st.leaves;
    r->refs = st.refs;
    r->max_depth = st.max_depth;
    r->max_leaf = st.max_leaf_size;
    r->bvh_bytes = (double)st.bytes;
    r->tri_bytes = (double)st.triangle_bytes;
    r->wide_bytes = (double)st.wide_bytes;
    return 0;
}

/* BENCH_TRACE_REPEAT frames on `threads` threads; *ms = the median time */
static bvh_result trace_median(run_ctx *c, const bvh_tree *tree, uint32_t threads, double *ms) {
    double v[BENCH_TRACE_REPEAT];
    uint32_t i;
    for (i = 0; i < BENCH_TRACE_REPEAT; i++) {
        double t0 = scene_now_ms();
        bvh_result res = bvh_intersect_batch(tree, c->rays, c->hits, c->npix, threads);
        v[i] = scene_now_ms() - t0;
        if (res != BVH_SUCCESS) return res;
    }
    *ms = scene_median(v, BENCH_TRACE_REPEAT);
    return BVH_SUCCESS;
}

static void trace_tree(run_ctx *c, row *r, const bvh_tree *tree) {
    const options *o = c->o;
    bvh_camera cam;
    double ms = NAN, kms = NAN;
    char tag[32], msg[400];
    bvh_result res;
    make_rays(c, bvh_tree_bounds(tree), &cam);
    if (o->trace_cpu) {
        progress("%s: %s, trace 1 thread", c->out->name, r->name);
        res = trace_median(c, tree, 1, &r->ms_1t);
        if (res != BVH_SUCCESS) goto fail;
        r->mrays_1t = mrays_of(c->npix, r->ms_1t);
        frame_pick(r, r->ms_1t, "cpu-1t");
        check_frame(c, r, "cpu-1t", c->hits);
        r->ms_mt = r->ms_1t;
        if (o->nthreads > 1) {
            progress("%s: %s, trace %u threads", c->out->name, r->name, o->nthreads);
            res = trace_median(c, tree, o->nthreads, &r->ms_mt);
            if (res != BVH_SUCCESS) goto fail;
            snprintf(tag, sizeof tag, "cpu-%ut", o->nthreads);
            check_frame(c, r, tag, c->hits);
        }
        r->mrays_mt = mrays_of(c->npix, r->ms_mt);
        frame_pick(r, r->ms_mt, "cpu-mt");
        if ((res = tree_sets(c, r, tree)) != BVH_SUCCESS) goto fail;
    }
    if (c->cl) {
        progress("%s: %s, trace OpenCL", c->out->name, r->name);
        if (bcl_frame(c->cl, tree, &cam, c->hits, &ms, &kms, msg, sizeof msg)) {
            r->state = ROW_FAILED;
            snprintf(r->note, sizeof r->note, "failed: %.180s", msg);
            return;
        }
        r->ms_cl = ms;
        r->cl_kernel_ms = kms;
        r->mrays_cl = mrays_of(c->npix, ms);
        frame_pick(r, ms, "opencl");
        check_frame(c, r, "opencl", c->hits);
    }
    return;
fail:
    r->state = ROW_FAILED;
    snprintf(r->note, sizeof r->note, "failed: tracing: %s", bvh_result_string(res));
}

/* --save-load: bvh_save into a buffer of bvh_save_size bytes and bvh_load from it (on N threads:
   the 8-wide packets remade from the saved groupings), copied and borrowed in turns, R times
   each after a warm-up; the median times. The loaded trees must be the saved one. */
typedef struct mem_writer {
    unsigned char *p;
} mem_writer;
static size_t mem_write(void *user, const void *data, size_t size) {
    mem_writer *w = (mem_writer *)user;
    memcpy(w->p, data, size);
    w->p += size;
    return size;
}
static void save_load(run_ctx *c, row *r, const bvh_tree *tree) {
    size_t size = bvh_save_size(tree);
    unsigned char *buf = (unsigned char *)malloc(size);
    double save[BENCH_MAX_REPEAT + 1], load[BENCH_MAX_REPEAT + 1], borrow[BENCH_MAX_REPEAT + 1];
    uint32_t k, b, n = c->o->repeat;
    bvh_result res = buf ? BVH_SUCCESS : BVH_ERROR_OUT_OF_MEMORY;
    for (k = 0; k <= n && res == BVH_SUCCESS; k++) { /* k = 0: the warm-up, as build_repeated's */
        mem_writer w = {buf};
        bvh_load_desc ld;
        bvh_tree t;
        double t0;
        progress("%s: %s, save and load %u/%u%s", c->out->name, r->name, k, n, k ? "" : " (warm-up)");
        t0 = scene_now_ms();
        res = bvh_save(tree, mem_write, &w);
        save[k] = scene_now_ms() - t0;
        if (res != BVH_SUCCESS) break;
        memset(&ld, 0, sizeof ld);
        ld.data = buf;
        ld.size = size;
        ld.threads = c->o->threads;
        for (b = 0; b < 2 && res == BVH_SUCCESS; b++) { /* copied, borrowed; every other round the other way */
            ld.borrow = (uint32_t)(b ^ (k & 1u));
            t0 = scene_now_ms();
            res = bvh_load(&t, &ld);
            (ld.borrow ? borrow : load)[k] = scene_now_ms() - t0;
            if (res == BVH_SUCCESS && (t.borrowed != ld.borrow || tree_diff(tree, &t)))
                flag(c, r, "the loaded tree differs from the saved one");
            bvh_free(&t);
        }
    }
    free(buf);
    if (res != BVH_SUCCESS) {
        r->state = ROW_FAILED;
        snprintf(r->note, sizeof r->note, "failed: save and load: %s", bvh_result_string(res));
        return;
    }
    r->save_first_ms = save[0];
    r->load_first_ms = load[0];
    r->save_ms = scene_median(save + 1, n);
    r->load_ms = scene_median(load + 1, n);
    r->load_borrow_ms = scene_median(borrow + 1, n);
}

/* --refit N: the scene twisted about its vertical axis through the centre, a little more each
   frame (frame f of N: f / N * 0.6 radians at the top and bottom), and waved vertically
   (deterministic). Each frame: bvh_refit of this row's tree, and a rebuild by bottom-up, the
   fastest builder, both timed. After the last: the SAH of the refitted tree and of this
   builder's tree rebuilt on that frame, and the camera rays over the moved scene traced on N
   threads with each (the two frames must agree). */
static void deform(const scene *s, float *out, double amount) {
    bvh_aabb b = scene_bounds(s);
    double cx = 0.5 * ((double)b.min.x + b.max.x), cy = 0.5 * ((double)b.min.y + b.max.y);
    double cz = 0.5 * ((double)b.min.z + b.max.z), hy = 0.5 * ((double)b.max.y - b.min.y);
    double hx = 0.5 * ((double)b.max.x - b.min.x);
    size_t i, n = 3 * (size_t)s->triangles;
    for (i = 0; i < n; i++) {
        const float *p = s->v + 3 * i;
        float *q = out + 3 * i;
        double ny = hy > 0 ? (p[1] - cy) / hy : 0, nx = hx > 0 ? (p[0] - cx) / hx : 0;
        double a = amount * ny, x = p[0] - cx, z = p[2] - cz;
        q[0] = (float)(cx + cos(a) * x - sin(a) * z);
        q[1] = (float)(p[1] + 0.1 * amount * hy * sin(3.0 * nx));
        q[2] = (float)(cz + sin(a) * x + cos(a) * z);
    }
}
static void animate(run_ctx *c, row *r, bvh_tree *tree) {
    const options *o = c->o;
    float *moved = (float *)malloc(9 * sizeof(float) * (size_t)(c->s->triangles ? c->s->triangles : 1));
    double refit[BENCH_MAX_REPEAT], rebuild[BENCH_MAX_REPEAT], emb_refit[BENCH_MAX_REPEAT], ms;
    emb_builder *eb = NULL; /* Embree's refit beside bvh_refit, on the same frames */
    char msg[160];
    bvh_build_desc desc;
    bvh_refit_desc rd;
    bvh_tree fresh;
    bvh_camera cam;
    bvh_hit *hits = (bvh_hit *)malloc(c->npix * sizeof *hits);
    bvh_result res = moved && hits ? BVH_SUCCESS : BVH_ERROR_OUT_OF_MEMORY;
    uint32_t f;
    size_t i;
    memset(&fresh, 0, sizeof fresh);
    memset(&rd, 0, sizeof rd);
    rd.triangles.positions = moved;
    rd.triangles.vertex_count = 3 * c->s->triangles;
    rd.triangles.triangle_count = c->s->triangles;
    rd.threads = o->threads;
    if (o->nqualities && emb_available()) {
        if (emb_builder_open(&eb, EMB_QUALITY_MEDIUM, o->threads, o->embree_robust, msg) != EMB_OK) {
            say("%s: %s: Embree's refit: %s", c->out->name, r->name, msg);
        } else if (emb_builder_refit_keep(eb, c->s->v, c->s->triangles) != EMB_OK) {
            say("%s: %s: Embree's refit: its scene build failed", c->out->name, r->name);
            emb_builder_close(eb);
            eb = NULL;
        }
    }
    for (f = 1; f <= o->refit && res == BVH_SUCCESS; f++) {
        double t0;
        progress("%s: %s, refit frame %u/%u", c->out->name, r->name, f, o->refit);
        deform(c->s, moved, 0.6 * f / o->refit);
        t0 = scene_now_ms();
        res = bvh_refit(tree, &rd);
        refit[f - 1] = scene_now_ms() - t0;
        if (res != BVH_SUCCESS) break;
        if (eb && emb_builder_refit(eb, moved, c->s->triangles, &emb_refit[f - 1]) != EMB_OK) {
            say("%s: %s: Embree's refit failed", c->out->name, r->name);
            emb_builder_close(eb);
            eb = NULL;
        }
        bench_desc(c, r, &desc);
        desc.builder = BVH_BUILDER_BOTTOM_UP; /* the rebuild: the fastest builder, as it is */
        desc.optimize.rounds = 0;
        desc.triangles.positions = moved;
        t0 = scene_now_ms();
        res = bvh_build(&fresh, &desc);
        rebuild[f - 1] = scene_now_ms() - t0;
        bvh_free(&fresh);
    }
    if (res == BVH_SUCCESS) {
        bench_desc(c, r, &desc);
        desc.triangles.positions = moved;
        res = bvh_build(&fresh, &desc);
    }
    if (res == BVH_SUCCESS && (res = bvh_validate(tree, NULL, NULL)) == BVH_SUCCESS &&
        (res = bvh_sah(tree, NULL, &r->refit_sah)) == BVH_SUCCESS &&
        (res = bvh_sah(&fresh, NULL, &r->rebuild_sah)) == BVH_SUCCESS && o->trace_cpu) {
        progress("%s: %s, trace after refit and after rebuild", c->out->name, r->name);
        make_rays(c, bvh_tree_bounds(tree), &cam);
        if ((res = trace_median(c, tree, o->nthreads, &ms)) == BVH_SUCCESS) {
            r->refit_mrays = mrays_of(c->npix, ms);
            memcpy(hits, c->hits, c->npix * sizeof *hits);
            if ((res = trace_median(c, &fresh, o->nthreads, &ms)) == BVH_SUCCESS)
                r->rebuild_mrays = mrays_of(c->npix, ms);
            for (i = 0; res == BVH_SUCCESS && i < c->npix; i++)
                if (hits[i].prim != c->hits[i].prim || memcmp(&hits[i].t, &c->hits[i].t, sizeof hits[i].t)) {
                    flag(c, r, "pixel %zu: the refitted tree hits triangle %u, the rebuilt one %u", i, hits[i].prim,
                         c->hits[i].prim);
                    break;
                }
        }
        make_rays(c, c->bounds, &cam); /* the scene's own rays again, for the rows and rounds after */
    }
    bvh_free(&fresh);
    free(moved);
    free(hits);
    if (res != BVH_SUCCESS) {
        emb_builder_close(eb);
        r->state = ROW_FAILED;
        snprintf(r->note, sizeof r->note, "failed: refit: %s", bvh_result_string(res));
        return;
    }
    r->refit_ms = scene_median(refit, o->refit);
    r->rebuild_ms = scene_median(rebuild, o->refit);
    if (eb) r->emb_refit_ms = scene_median(emb_refit, o->refit);
    emb_builder_close(eb);
}

static void run_builder(run_ctx *c, row *r) {
    bvh_tree tree;
    memset(&tree, 0, sizeof tree);
    if (!build_repeated(c, r, &tree) && !tree_figures(r, &tree)) {
        if (c->o->trace_cpu || c->cl) trace_tree(c, r, &tree);
        if (c->o->save_load && r->state == ROW_OK) save_load(c, r, &tree);
        if (c->o->refit && r->state == ROW_OK) animate(c, r, &tree);
    }
    bvh_free(&tree);
}

/* Ray against triangle in long double (x87: 64-bit mantissa): the signed volumes of the ray with
   the three edges (Pluecker). Origin, direction and vertices are floats, so the differences are
   exact and the products keep 64 bits. Both tracers test in float, so their answers can only be
   held to float precision: a volume within 4 FLT_EPSILON of the size of its terms counts as "on
   the edge", where either answer is right (a watertight test gives such a ray to one of the two
   triangles of the edge, not always to the one an exact test picks). Returns 1 hit, 0 miss, -1
   on an edge (or parallel); *t is the distance of the triangle's plane. */
static long double edge_volume(const long double o[3], const long double d[3], const float *a, const float *b,
                               long double *bound) {
    long double A[3], B[3], c[3], m[3];
    int k;
    for (k = 0; k < 3; k++) {
        A[k] = (long double)a[k] - o[k];
        B[k] = (long double)b[k] - o[k];
    }
    c[0] = A[1] * B[2] - A[2] * B[1];
    m[0] = fabsl(A[1] * B[2]) + fabsl(A[2] * B[1]);
    c[1] = A[2] * B[0] - A[0] * B[2];
    m[1] = fabsl(A[2] * B[0]) + fabsl(A[0] * B[2]);
    c[2] = A[0] * B[1] - A[1] * B[0];
    m[2] = fabsl(A[0] * B[1]) + fabsl(A[1] * B[0]);
    *bound = 4.0L * FLT_EPSILON * (m[0] * fabsl(d[0]) + m[1] * fabsl(d[1]) + m[2] * fabsl(d[2]));
    return c[0] * d[0] + c[1] * d[1] + c[2] * d[2];
}
static int exact_hit(const bvh_ray *r, const float *t3, long double *t) {
    long double o[3], d[3], v[3], bound[3], e1[3], e2[3], n[3], nd;
    int k, pos = 0, neg = 0, unsure = 0;
    o[0] = r->origin.x;
    o[1] = r->origin.y;
    o[2] = r->origin.z;
    d[0] = r->dir.x;
    d[1] = r->dir.y;
    d[2] = r->dir.z;
    v[0] = edge_volume(o, d, t3 + 3, t3 + 6, &bound[0]);
    v[1] = edge_volume(o, d, t3 + 6, t3, &bound[1]);
    v[2] = edge_volume(o, d, t3, t3 + 3, &bound[2]);
    for (k = 0; k < 3; k++) {
        if (fabsl(v[k]) <= bound[k])
            unsure = 1;
        else if (v[k] > 0)
            pos = 1;
        else
            neg = 1;
    }
    for (k = 0; k < 3; k++) {
        e1[k] = (long double)t3[3 + k] - t3[k];
        e2[k] = (long double)t3[6 + k] - t3[k];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    nd = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
    if (nd == 0.0L) return -1;
    *t = (n[0] * (t3[0] - o[0]) + n[1] * (t3[1] - o[1]) + n[2] * (t3[2] - o[2])) / nd;
    if (pos && neg) return 0;
    if (*t < r->tmin) return 0;
    return unsure ? -1 : 1;
}

static const char *prim_text(uint32_t prim, char *b, size_t n) {
    if (prim == BVH_INVALID)
        snprintf(b, n, "miss");
    else
        snprintf(b, n, "triangle %u", prim);
    return b;
}

/* Embree's frame against the reference frame (bvh.h's), pixel by pixel. Where they differ, an
   exact test referees: bvh.h is right when its triangle is hit (or grazed) and Embree's is
   missed, grazed or not nearer. Pixels bvh.h loses are disagreements (!); when it wins them all,
   the row is marked (e) and noted, and is a disagreement only with --strict. */
/* 1 when an exact test says bvh.h's answer b (a triangle or BVH_INVALID) for the ray is wrong
   and Embree's e (another) is right: b is missed, or e is surely hit and surely nearer. */
static int ours_loses(const run_ctx *c, const bvh_ray *ray, uint32_t e, uint32_t b) {
    long double te = 0.0L, tb = 0.0L;
    int se = e == BVH_INVALID ? 0 : exact_hit(ray, c->s->v + 9 * (size_t)e, &te);
    int sb = b == BVH_INVALID ? 0 : exact_hit(ray, c->s->v + 9 * (size_t)b, &tb);
    return b == BVH_INVALID ? se == 1 : sb == 0 || (se == 1 && te < tb * (1.0L - 1e-6L));
}

static void referee_embree(run_ctx *c, row *r) {
    const options *o = c->o;
    bvh_camera cam = bench_camera(o, c->bounds);
    size_t i, diff = 0, lost = 0, first = 0, first_lost = 0, x, y;
    char pb[32], pe[32];
    for (i = 0; i < c->npix; i++) {
        uint32_t e = c->emb_prims[i], b = c->ref[i].prim;
        bvh_ray ray;
        if (e == b) continue;
        if (!diff++) first = i;
        ray = bvh_camera_ray(&cam, (uint32_t)(i % o->width), (uint32_t)(i / o->width));
        if (ours_loses(c, &ray, e, b))
            if (!lost++) first_lost = i;
    }
    r->emb_prim_diff = (double)diff;
    if (lost) {
        x = first_lost % o->width;
        y = first_lost / o->width;
        flag(c, r,
             "%s: %.0f hits (%s: %.0f); %zu pixels differ, at %zu an exact test says bvh.h is wrong (first "
             "x=%zu y=%zu: bvh.h %s, Embree %s)",
             r->name, r->hits, c->ref_name, c->ref_hits, diff, lost, x, y,
             prim_text(c->ref[first_lost].prim, pb, sizeof pb), prim_text(c->emb_prims[first_lost], pe, sizeof pe));
    } else if (diff || r->hits != c->ref_hits) {
        x = first % o->width;
        y = first / o->width;
        r->refereed = 1;
        snprintf(r->referee_msg, sizeof r->referee_msg,
                 "%s: %.0f hits (%s: %.0f); %zu pixel(s) differ, all grazing rays (float precision) or decided "
                 "for bvh.h by an exact test (first "
                 "x=%zu y=%zu: bvh.h %s, Embree %s)",
                 r->name, r->hits, c->ref_name, c->ref_hits, diff, x, y, prim_text(c->ref[first].prim, pb, sizeof pb),
                 prim_text(c->emb_prims[first], pe, sizeof pe));
        if (o->strict)
            flag(c, r, "%s (--strict)", r->referee_msg);
        else
            say("note on %s: %s", c->out->name, r->referee_msg);
    }
}

/* Embree's answers on a set against bvh.h's reference: rays answered otherwise (another
   triangle or none; blocked or not), counted. Up to BENCH_SET_TOLERANCE of the set's rays are
   float noise (grazing rays; Embree's test is not watertight) and noted in the row; more are a
   disagreement, and so is a diffuse ray where the exact test of referee_embree says bvh.h is
   wrong (a shadow ray's blocker is not known, so those are held to the tolerance alone). */
static void embree_set_compare(run_ctx *c, row *r, int set, const uint32_t *prim, const float *t, const uint8_t *occ) {
    size_t i, n = set_size(c, set), other = 0, first = 0, lost = 0, first_lost = 0;
    double count = 0.0, t_sum = 0.0;
    set_figs *f = &r->set[set];
    char line[160];
    for (i = 0; i < n; i++) {
        int differs;
        if (set == SET_SHADOW) {
            count += occ[i];
            differs = occ[i] != c->oref[i];
        } else {
            if (prim[i] != BVH_INVALID) {
                count += 1.0;
                t_sum += (double)t[i];
            }
            differs = prim[i] != c->dref[i].prim;
            if (differs && ours_loses(c, &c->sets.diffuse[i], prim[i], c->dref[i].prim) && !lost++) first_lost = i;
        }
        if (differs && !other++) first = i;
    }
    f->rays = (double)n;
    f->count = count;
    f->t_sum = t_sum;
    f->other = (double)other;
    if (lost)
        flag(c, r, "%s: %zu %s rays answered otherwise, at %zu an exact test says bvh.h is wrong (first: ray %zu)",
             r->name, other, g_set_names[set], lost, first_lost);
    if (!other || !c->has_sref[set]) return;
    snprintf(line, sizeof line, "%s rays: %.0f %s (%s: %.0f), %zu of %zu rays answered otherwise (first: ray %zu)",
             g_set_names[set], count, set == SET_SHADOW ? "occluded" : "hits", c->sref_name[set], c->sref_count[set],
             other, n, first);
    if ((double)other > BENCH_SET_TOLERANCE * (double)n)
        flag(c, r, "%s: %s, more than the tolerance of %g of the rays", r->name, line, BENCH_SET_TOLERANCE);
    else if (!lost)
        snprintf(r->set_note + strlen(r->set_note), sizeof r->set_note - strlen(r->set_note), "%s%s",
                 r->set_note[0] ? "; " : "", line);
}

/* Embree on the diffuse and shadow sets: a scene of the row's quality (emb_builder, the scene
   flags of --embree-flags, as the frame's), BENCH_TRACE_REPEAT passes on 1 and on N threads
   (median), the same rays as bvh.h's (origin already offset, tnear 0). The N-thread answers must
   be the 1-thread ones; the 1-thread ones are compared with bvh.h's (embree_set_compare). */
static void embree_sets(run_ctx *c, row *r) {
    const options *o = c->o;
    emb_builder *eb = NULL;
    char msg[160] = "out of memory";
    size_t n = c->sets.ndiffuse ? c->sets.ndiffuse : 1;
    float *t = (float *)malloc(2 * n * sizeof *t);
    uint32_t *p = (uint32_t *)malloc(2 * n * sizeof *p), passes = o->nthreads > 1 ? 2 : 1, pass;
    uint8_t *occ = (uint8_t *)malloc(2 * n);
    int set, st = t && p && occ ? EMB_OK : EMB_ERR_MEMORY;
    if (st == EMB_OK) st = emb_builder_open(&eb, r->quality, o->threads, o->embree_robust, msg);
    if (st == EMB_OK && (st = emb_builder_keep(eb, c->s->v, c->s->triangles)) != EMB_OK)
        snprintf(msg, sizeof msg, "scene build failed");
    for (set = 0; st == EMB_OK && set < SET_COUNT; set++) {
        set_figs *f = &r->set[set];
        size_t m = set_size(c, set), i, mt_diff = 0;
        for (pass = 0; st == EMB_OK && pass < passes; pass++) {
            uint32_t th = pass ? o->nthreads : 1, k;
            double v[BENCH_TRACE_REPEAT], ms;
            progress("%s: %s, %s rays, %u thread(s)", c->out->name, r->name, g_set_names[set], th);
            for (k = 0; st == EMB_OK && k < BENCH_TRACE_REPEAT; k++)
                st = emb_builder_rays(eb, set_rays(c, set), m, th, t + pass * n, p + pass * n,
                                      set == SET_SHADOW ? occ + pass * n : NULL, &v[k]);
            if (st != EMB_OK) {
                snprintf(msg, sizeof msg, "%s rays: %s", g_set_names[set], emb_status_string(st));
                break;
            }
            ms = scene_median(v, BENCH_TRACE_REPEAT);
            if (!pass) {
                f->ms_1t = ms;
                f->mrays_1t = mrays_of(m, ms);
            }
            f->ms_mt = ms;
            f->mrays_mt = mrays_of(m, ms);
        }
        if (st != EMB_OK) break;
        for (i = 0; passes == 2 && i < m; i++)
            mt_diff += set == SET_SHADOW ? occ[i] != occ[n + i]
                                         : p[i] != p[n + i] || (p[i] != BVH_INVALID && t[i] != t[n + i]);
        if (mt_diff)
            flag(c, r, "%s: %zu %s rays answered otherwise on %u threads than on 1", r->name, mt_diff, g_set_names[set],
                 o->nthreads);
        embree_set_compare(c, r, set, p, t, occ);
    }
    if (st != EMB_OK) {
        r->state = ROW_FAILED;
        snprintf(r->note, sizeof r->note, "failed: Embree on the secondary rays: %.150s", msg);
    } else if (r->set_note[0]) {
        say("note on %s: %s: %s", c->out->name, r->name, r->set_note);
    }
    emb_builder_close(eb);
    free(t);
    free(p);
    free(occ);
}

static void run_embree(run_ctx *c, row *r) {
    const options *o = c->o;
    emb_scene_desc d;
    emb_scene_result res;
    emb_sah_desc sd;
    emb_sah_result sah;
    bvh_camera cam = bench_camera(o, c->bounds);
    int st;
    memset(&d, 0, sizeof d);
    d.camera = &cam;
    d.quality = r->quality;
    d.threads = o->threads;
    d.repeat = o->repeat;
    if (o->trace_cpu) {
        d.width = o->width;
        d.height = o->height;
    }
    d.trace_threads = o->nthreads;
    d.trace_repeat = BENCH_TRACE_REPEAT;
    d.robust = o->embree_robust; /* --embree-flags: Embree's default flags (0) or RTC_SCENE_FLAG_ROBUST */
    d.bounds = &c->bounds;
    d.prim_out = c->emb_prims;
    progress("%s: %s, %u builds + frame", c->out->name, r->name, o->repeat + 1);
    st = emb_scene_bench(c->s->v, c->s->triangles, &d, &res);
    if (st != EMB_OK) {
        r->state = ROW_FAILED;
        snprintf(r->note, sizeof r->note, "failed: %s", res.message);
        return;
    }
    r->build_ms = res.build.ms;
    r->build_min = res.build.min_ms;
    r->build_max = res.build.max_ms;
    if (d.width) {
        r->ms_1t = res.trace_ms;
        r->mrays_1t = res.mrays;
        r->ms_mt = res.trace_ms_mt;
        r->mrays_mt = res.mrays_mt;
        r->hits = (double)res.hits;
        r->t_sum = res.t_sum;
        frame_pick(r, r->ms_1t, "cpu-1t");
        frame_pick(r, r->ms_mt, "cpu-mt");
        if (!res.mt_identical)
            flag(c, r, "%s: the %u-thread frame differs from the 1-thread frame", r->name, o->nthreads);
        if (c->has_ref)
            referee_embree(c, r);
        else if (isnan(c->ref_hits)) {
            c->ref_hits = r->hits;
            snprintf(c->ref_hits_name, sizeof c->ref_hits_name, "%s", r->name);
        } else if (r->hits != c->ref_hits)
            flag(c, r, "%s: %.0f hits, %s has %.0f", r->name, r->hits, c->ref_hits_name, c->ref_hits);
        if (c->has_sets) embree_sets(c, r);
        if (r->state != ROW_OK) return;
    }
    memset(&sd, 0, sizeof sd);
    sd.quality = r->quality;
    sd.threads = o->threads;
    sd.repeat = 1;
    progress("%s: %s, rtcBuildBVH for the SAH", c->out->name, r->name);
    st = emb_bvh_sah(c->s->v, c->s->triangles, &sd, &sah);
    if (st != EMB_OK) {
        r->state = ROW_FAILED;
        snprintf(r->note, sizeof r->note, "failed: rtcBuildBVH: %s", sah.message);
        return;
    }
    r->sah = sah.sah;
    r->nodes = sah.nodes;
    r->leaves = sah.leaves;
    r->refs = sah.refs;
    r->max_depth = sah.max_depth;
    r->max_leaf = sah.max_leaf_size;
    r->emb_bvh_ms = sah.build.ms;
}

/* OpenCL against the CPU on N threads, paired: each round renders one frame of every tree with
   bvh_cl_render_frame (hits read back, as the table's OpenCL column) and traces it with
   bvh_intersect_batch on N threads, one right after the other. */
static void paired_opencl(run_ctx *c, bench_scene *out, bvh_tree *trees, int made, double *ratio) {
    const options *o = c->o;
    bvh_cl_tree *g[BENCH_MAX_ROWS];
    bvh_camera cam = bench_camera(o, c->bounds);
    int i, ok = 1;
    uint32_t k;
    memset(g, 0, sizeof g);
    for (i = 0; i < made; i++)
        if (trees[i].node_count && bvh_cl_upload(c->cl->ctx, &trees[i], &g[i]) != BVH_CL_SUCCESS) ok = 0;
    for (k = 0; ok && k <= o->paired; k++) { /* round 0: warm-up */
        for (i = 0; ok && i < made; i++) {
            double t0, mt, cl;
            if (!g[i]) continue;
            progress("%s: paired OpenCL round %u/%u%s, %s", out->name, k, o->paired, k ? "" : " (warm-up)",
                     out->rows[i].name);
            t0 = scene_now_ms();
            ok = bvh_intersect_batch(&trees[i], c->rays, c->hits, c->npix, o->nthreads) == BVH_SUCCESS;
            mt = scene_now_ms() - t0;
            t0 = scene_now_ms();
            ok = ok && bvh_cl_render_frame(g[i], &cam, NULL, c->hits, NULL) == BVH_CL_SUCCESS;
            cl = scene_now_ms() - t0;
            if (ok && k) ratio[(size_t)i * o->paired + k - 1] = mt / cl;
        }
    }
    if (!ok) say("%s: paired OpenCL rounds failed", out->name);
    for (i = 0; ok && i < made; i++)
        if (g[i]) {
            row *r = &out->rows[i];
            median_range(ratio + (size_t)i * o->paired, o->paired, &r->x_pcl, &r->x_pcl_min, &r->x_pcl_max);
        }
    for (i = 0; i < made; i++) bvh_cl_tree_free(g[i]);
}

/* The same for one-thread tracing: every builder's tree and Embree medium's scene are made
   once, then each round traces one frame with each tree and one with Embree, on one thread.
   Each of bvh.h's passes is followed at once by the same pass on N threads (--threads), whose
   ratio to it is the thread scaling, paired as well. */
static void paired_trace(run_ctx *c, bench_scene *out, emb_builder *eb, double *ratio) {
    const options *o = c->o;
    bvh_tree trees[BENCH_MAX_ROWS];
    double *pms = ratio + (size_t)(1 + SET_COUNT) * out->nrows * o->paired; /* ms per kind, tree, round */
    double *ems = NULL;                                                     /* Embree's ms per kind and round */
    double *scale = NULL; /* 1-thread ms / N-thread ms per kind, tree and round; Embree's per kind last */
    float *et = NULL;
    uint32_t *ep = NULL;
    uint8_t *eo = NULL;
    size_t n = c->sets.ndiffuse ? c->sets.ndiffuse : 1;
    int i, made = 0, kind, kinds;
    uint32_t k;
    memset(trees, 0, sizeof trees);
    progress("%s: paired tracing, building the trees", out->name);
    if (emb_builder_keep(eb, c->s->v, c->s->triangles) != EMB_OK) {
        say("%s: paired tracing: Embree scene build failed", out->name);
        return;
    }
    for (i = 0; i < out->nrows; i++) {
        bvh_build_desc desc;
        if (out->rows[i].kind != ROW_BVH || out->rows[i].state != ROW_OK) continue;
        bench_desc(c, &out->rows[i], &desc);
        if (bvh_build(&trees[i], &desc) != BVH_SUCCESS) {
            say("%s: paired tracing: build failed", out->name);
            goto done;
        }
        made = i + 1;
    }
    kinds = c->has_sets ? 1 + SET_COUNT : 1;
    ems = (double *)malloc((size_t)kinds * o->paired * sizeof *ems);
    scale = (double *)malloc((size_t)kinds * (size_t)(made + 1) * o->paired * sizeof *scale);
    et = (float *)malloc(n * sizeof *et);
    ep = (uint32_t *)malloc(n * sizeof *ep);
    eo = (uint8_t *)malloc(n);
    if (!ems || !scale || !et || !ep || !eo) {
        say("%s: paired tracing: out of memory", out->name);
        goto done;
    }
    for (k = 0; k <= o->paired; k++) { /* round 0: warm-up */
        double ms[BENCH_MAX_ROWS][1 + SET_COUNT], mt[BENCH_MAX_ROWS][1 + SET_COUNT], em[1 + SET_COUNT];
        double emt[1 + SET_COUNT];
        for (i = 0; i < made; i++) {
            if (!trees[i].node_count) continue;
            progress("%s: paired tracing round %u/%u%s, %s", out->name, k, o->paired, k ? "" : " (warm-up)",
                     out->rows[i].name);
            for (kind = 0; kind < kinds; kind++) { /* the camera rays, then each set */
                int pass;
                for (pass = 0; pass < 2; pass++) { /* one thread, then N */
                    const uint32_t nt = pass ? o->nthreads : 1;
                    double t0 = scene_now_ms();
                    bvh_result res =
                        kind == 0 ? bvh_intersect_batch(&trees[i], c->rays, c->hits, c->npix, nt)
                        : kind == 1 + SET_DIFFUSE
                            ? bvh_intersect_batch(&trees[i], c->sets.diffuse, c->dhits, c->sets.ndiffuse, nt)
                            : bvh_occluded_batch(&trees[i], c->sets.shadow, c->occ, c->sets.nshadow, nt);
                    *(pass ? &mt[i][kind] : &ms[i][kind]) = scene_now_ms() - t0;
                    if (res != BVH_SUCCESS) goto done;
                }
            }
        }
        for (kind = 0; kind < kinds; kind++) {
            int pass;
            for (pass = 0; pass < 2; pass++) { /* one thread, then N, as bvh.h's */
                const uint32_t nt = pass ? o->nthreads : 1;
                double *at = pass ? &emt[kind] : &em[kind];
                int st = kind == 0 ? emb_builder_trace(eb, c->rays, o->width, o->height, nt, at)
                                   : emb_builder_rays(eb, set_rays(c, kind - 1), set_size(c, kind - 1), nt, et, ep,
                                                      kind == 1 + SET_SHADOW ? eo : NULL, at);
                if (st != EMB_OK || !(*at > 0.0)) {
                    say("%s: paired tracing: Embree failed", out->name);
                    goto done;
                }
            }
        }
        for (kind = 0; k && kind < kinds; kind++) {
            ems[kind * (size_t)o->paired + k - 1] = em[kind];
            scale[((size_t)kinds * made + kind) * o->paired + k - 1] = em[kind] / emt[kind];
            for (i = 0; i < made; i++)
                if (trees[i].node_count) {
                    ratio[((size_t)kind * made + i) * o->paired + k - 1] = em[kind] / ms[i][kind];
                    pms[((size_t)kind * made + i) * o->paired + k - 1] = ms[i][kind];
                    scale[((size_t)kind * made + i) * o->paired + k - 1] = ms[i][kind] / mt[i][kind];
                }
        }
    }
    for (kind = 0; kind < kinds; kind++) {
        size_t rays = kind ? set_size(c, kind - 1) : c->npix;
        for (i = 0; i < made; i++) {
            row *r = &out->rows[i];
            double *x = ratio + ((size_t)kind * made + i) * o->paired, *med, *lo, *hi;
            if (!trees[i].node_count) continue;
            med = kind ? &r->set[kind - 1].x_p : &r->x_ptrace;
            lo = kind ? &r->set[kind - 1].x_p_min : &r->x_ptrace_min;
            hi = kind ? &r->set[kind - 1].x_p_max : &r->x_ptrace_max;
            median_range(x, o->paired, med, lo, hi);
            median_range(scale + ((size_t)kind * made + i) * o->paired, o->paired,
                         kind ? &r->set[kind - 1].x_s : &r->x_scale, kind ? &r->set[kind - 1].x_s_min : &r->x_scale_min,
                         kind ? &r->set[kind - 1].x_s_max : &r->x_scale_max);
            *(kind ? &r->set[kind - 1].p_mrays : &r->p_mrays) =
                mrays_of(rays, scene_median(pms + ((size_t)kind * made + i) * o->paired, o->paired));
        }
        for (i = 0; i < out->nrows; i++) {
            row *r = &out->rows[i];
            if (r->kind == ROW_EMBREE && r->quality == EMB_QUALITY_MEDIUM && r->state == ROW_OK) {
                *(kind ? &r->set[kind - 1].p_mrays : &r->p_mrays) =
                    mrays_of(rays, scene_median(ems + (size_t)kind * o->paired, o->paired));
                median_range(scale + ((size_t)kinds * made + kind) * o->paired, o->paired,
                             kind ? &r->set[kind - 1].x_s : &r->x_scale,
                             kind ? &r->set[kind - 1].x_s_min : &r->x_scale_min,
                             kind ? &r->set[kind - 1].x_s_max : &r->x_scale_max);
            }
        }
    }
    if (c->cl && o->trace_cl) paired_opencl(c, out, trees, made, ratio);
done:
    for (i = 0; i < made; i++) bvh_free(&trees[i]);
    free(ems);
    free(scale);
    free(et);
    free(ep);
    free(eo);
}

/* Paired rounds (--paired N): on a shared machine a builder's five builds and Embree's five
   later ones can fall into different moments of noise, and their medians' ratio with them. Here
   each round builds once with every bvh.h builder of the table and once with Embree medium, one
   after the other, and the ratio is taken within the round; the median over N rounds (after one
   warm-up round) is reported beside the table's ratio. */
static void run_paired(run_ctx *c, bench_scene *out) {
    const options *o = c->o;
    emb_builder *eb = NULL, *ebh = NULL;
    char msg[160];
    double *ratio = NULL, *pms, *rh = NULL, ems = 0.0, emsh = 0.0;
    int i, nb = 0, have_medium = 0, have_high = 0;
    uint32_t k;
    for (i = 0; i < out->nrows; i++) {
        const row *r = &out->rows[i];
        if (r->kind == ROW_EMBREE && r->quality == EMB_QUALITY_MEDIUM && r->state == ROW_OK) have_medium = 1;
        if (r->kind == ROW_EMBREE && r->quality == EMB_QUALITY_HIGH && r->state == ROW_OK) have_high = 1;
        if (r->kind == ROW_BVH && r->state == ROW_OK) nb++;
    }
    if (!o->paired || !have_medium || !nb) return;
    if (emb_builder_open(&eb, EMB_QUALITY_MEDIUM, o->threads, o->embree_robust, msg) != EMB_OK) {
        say("%s: paired rounds: %s", out->name, msg);
        return;
    }
    /* Embree high in the same rounds, where the table has it (the quality builders' yardstick) */
    if (have_high && emb_builder_open(&ebh, EMB_QUALITY_HIGH, o->threads, o->embree_robust, msg) != EMB_OK) {
        say("%s: paired rounds against embree-high: %s", out->name, msg);
        ebh = NULL;
    }
    /* the builds' ratios and times; then paired_trace's: ratios and times per kind of ray; then
       the ratios and Embree high's times of the rounds against it */
    ratio = (double *)malloc(((size_t)(2 * (1 + SET_COUNT) * out->nrows + 1) + (size_t)out->nrows + 1) * o->paired *
                             sizeof *ratio);
    if (!ratio) {
        emb_builder_close(eb);
        if (ebh) emb_builder_close(ebh);
        say("%s: paired rounds: out of memory", out->name);
        return;
    }
    pms = ratio + (size_t)out->nrows * o->paired; /* build ms per row and round; Embree's last */
    rh = ratio + (size_t)(2 * (1 + SET_COUNT) * out->nrows + 1) * o->paired; /* against high; its ms last */
    for (k = 0; k <= o->paired; k++) {                                       /* round 0: warm-up */
        double ms[BENCH_MAX_ROWS];
        for (i = 0; i < out->nrows; i++) {
            row *r = &out->rows[i];
            bvh_build_desc desc;
            bvh_tree t;
            double t0;
            if (r->kind != ROW_BVH || r->state != ROW_OK) continue;
            progress("%s: paired round %u/%u%s, %s", out->name, k, o->paired, k ? "" : " (warm-up)", r->name);
            bench_desc(c, r, &desc);
            t0 = scene_now_ms();
            if (bvh_build(&t, &desc) != BVH_SUCCESS) {
                say("%s: paired rounds: %s failed", out->name, r->name);
                goto done;
            }
            ms[i] = scene_now_ms() - t0;
            bvh_free(&t);
        }
        progress("%s: paired round %u/%u%s, embree-medium", out->name, k, o->paired, k ? "" : " (warm-up)");
        if (emb_builder_time(eb, c->s->v, c->s->triangles, &ems) != EMB_OK || !(ems > 0.0)) {
            say("%s: paired rounds: Embree build failed", out->name);
            goto done;
        }
        for (i = 0; k && i < out->nrows; i++)
            if (out->rows[i].kind == ROW_BVH && out->rows[i].state == ROW_OK) {
                ratio[(size_t)i * o->paired + k - 1] = ms[i] / ems;
                pms[(size_t)i * o->paired + k - 1] = ms[i];
            }
        if (k) pms[(size_t)out->nrows * o->paired + k - 1] = ems;
        if (ebh) {
            progress("%s: paired round %u/%u%s, embree-high", out->name, k, o->paired, k ? "" : " (warm-up)");
            if (emb_builder_time(ebh, c->s->v, c->s->triangles, &emsh) != EMB_OK || !(emsh > 0.0)) {
                say("%s: paired rounds: Embree high build failed", out->name);
                emb_builder_close(ebh);
                ebh = NULL;
                continue;
            }
            for (i = 0; k && i < out->nrows; i++)
                if (out->rows[i].kind == ROW_BVH && out->rows[i].state == ROW_OK)
                    rh[(size_t)i * o->paired + k - 1] = ms[i] / emsh;
            if (k) rh[(size_t)out->nrows * o->paired + k - 1] = emsh;
        }
    }
    for (i = 0; i < out->nrows; i++) {
        row *r = &out->rows[i];
        if (r->kind == ROW_BVH && r->state == ROW_OK) {
            median_range(ratio + (size_t)i * o->paired, o->paired, &r->x_pair, &r->x_pair_min, &r->x_pair_max);
            r->pair_ms = scene_median(pms + (size_t)i * o->paired, o->paired);
        }
        if (r->kind == ROW_BVH && r->state == ROW_OK && r->opt) { /* against ploc-parallel, round by round */
            int j;
            for (j = 0; j < out->nrows; j++) {
                const row *b = &out->rows[j];
                double x[BENCH_MAX_PAIRED];
                if (b->kind != ROW_BVH || b->state != ROW_OK || b->opt || b->builder != BVH_BUILDER_PLOC_PARALLEL)
                    continue;
                for (k = 0; k < o->paired; k++) x[k] = pms[(size_t)i * o->paired + k] / pms[(size_t)j * o->paired + k];
                median_range(x, o->paired, &r->x_pairo, &r->x_pairo_min, &r->x_pairo_max);
            }
        }
        if (r->kind == ROW_EMBREE && r->quality == EMB_QUALITY_MEDIUM && r->state == ROW_OK)
            r->pair_ms = scene_median(pms + (size_t)out->nrows * o->paired, o->paired);
        if (!ebh) continue;
        if (r->kind == ROW_BVH && r->state == ROW_OK)
            median_range(rh + (size_t)i * o->paired, o->paired, &r->x_pairh, &r->x_pairh_min, &r->x_pairh_max);
        if (r->kind == ROW_EMBREE && r->quality == EMB_QUALITY_HIGH && r->state == ROW_OK)
            r->pair_ms = scene_median(rh + (size_t)out->nrows * o->paired, o->paired);
    }
    if (ebh) emb_builder_close(ebh);
    ebh = NULL;
    if (o->trace_cpu) paired_trace(c, out, eb, ratio);
done:
    free(ratio);
    emb_builder_close(eb);
    if (ebh) emb_builder_close(ebh);
}

/* ours / Embree medium */
static void ratios(bench_scene *s) {
    const row *m = NULL;
    int i;
    for (i = 0; i < s->nrows; i++)
        if (s->rows[i].kind == ROW_EMBREE && s->rows[i].quality == EMB_QUALITY_MEDIUM && s->rows[i].state == ROW_OK)
            m = &s->rows[i];
    if (!m) return;
    for (i = 0; i < s->nrows; i++) {
        row *r = &s->rows[i];
        if (r->kind == ROW_EMBREE || r->state != ROW_OK) continue;
        if (r->kind == ROW_BVH) r->x_build = r->build_ms / m->build_ms;
        r->x_sah = r->sah / m->sah;
        r->x_mrays = r->mrays_mt / m->mrays_mt;
    }
}

/* ---- instances ------------------------------------------------------------------------------------ */
/* The camera rays on one thread through the tree, or through a scene when sc is given: ms. */
static double trace_1t(const run_ctx *c, const bvh_tree *tree, const bvh_scene *sc) {
    double t0 = scene_now_ms();
    size_t i;
    for (i = 0; i < c->npix; i++) {
        if (sc) {
            bvh_scene_hit h;
            bvh_scene_intersect(sc, &c->rays[i], ~0u, &h);
        } else {
            bvh_hit h;
            bvh_intersect(tree, &c->rays[i], &h);
        }
    }
    return scene_now_ms() - t0;
}
/* o->instances instances of the scene's default tree on a cube grid one scene diagonal apart,
   each turned about y (fixed seed): the top-level rebuild is bvh_scene_build over them (the
   bottom-level tree is built once), timed o->repeat times after a warm-up. Then the instancing
   overhead: one identity instance against the tree itself, camera rays on one thread. */
static int run_instances(run_ctx *c, bench_scene *out) {
    const options *o = c->o;
    bvh_build_desc desc;
    bvh_tree tree;
    bvh_scene sc;
    bvh_scene_desc sd;
    bvh_instance *inst;
    double ms[BENCH_MAX_REPEAT], one[BENCH_INST_ROUNDS], scn[BENCH_INST_ROUNDS], ratio[BENCH_INST_ROUNDS], lo, hi, med;
    float diag = sqrtf((c->bounds.max.x - c->bounds.min.x) * (c->bounds.max.x - c->bounds.min.x) +
                       (c->bounds.max.y - c->bounds.min.y) * (c->bounds.max.y - c->bounds.min.y) +
                       (c->bounds.max.z - c->bounds.min.z) * (c->bounds.max.z - c->bounds.min.z));
    uint32_t n = o->instances, side = 1, i, rep, seed = 12345;
    bvh_result r = BVH_SUCCESS;
    bvh_camera cam;
    if (!n) return 0;
    while (side * side * side < n) side++;
    progress("%s: %u instances, building the tree", out->name, n);
    {
        row def;
        memset(&def, 0, sizeof def);
        def.builder = BVH_BUILDER_DEFAULT;
        bench_desc(c, &def, &desc);
    }
    if ((r = bvh_build(&tree, &desc)) != BVH_SUCCESS) {
        say("%s: instances: %s", out->name, bvh_result_string(r));
        return 1;
    }
    inst = (bvh_instance *)calloc(n, sizeof *inst);
    if (!inst) {
        bvh_free(&tree);
        say("%s: out of memory", out->name);
        return 1;
    }
    for (i = 0; i < n; i++) {
        float a;
        seed = seed * 1664525u + 1013904223u;
        a = (float)(seed >> 8) * (6.2831853f / 16777216.0f);
        inst[i].tree = &tree;
        inst[i].transform[0] = cosf(a);
        inst[i].transform[2] = sinf(a);
        inst[i].transform[5] = 1.0f;
        inst[i].transform[8] = -sinf(a);
        inst[i].transform[10] = cosf(a);
        inst[i].transform[3] = diag * (float)(i % side);
        inst[i].transform[7] = diag * (float)(i / side % side);
        inst[i].transform[11] = diag * (float)(i / side / side);
        inst[i].id = i;
        inst[i].mask = ~0u;
    }
    memset(&sd, 0, sizeof sd);
    sd.instances = inst;
    sd.instance_count = n;
    sd.threads = o->threads;
    for (rep = 0; rep <= o->repeat; rep++) {
        double t0;
        progress("%s: %u instances, top-level build %u/%u%s", out->name, n, rep, o->repeat, rep ? "" : " (warm-up)");
        t0 = scene_now_ms();
        r = bvh_scene_build(&sc, &sd);
        if (rep) ms[rep - 1] = scene_now_ms() - t0;
        if (r != BVH_SUCCESS) break;
        bvh_scene_free(&sc);
    }
    if (r == BVH_SUCCESS) median_range(ms, o->repeat, &out->inst_ms, &out->inst_min, &out->inst_max);
    /* one identity instance against the tree */
    memset(inst, 0, sizeof *inst);
    inst[0].tree = &tree;
    inst[0].transform[0] = inst[0].transform[5] = inst[0].transform[10] = 1.0f;
    inst[0].mask = ~0u;
    sd.instance_count = 1;
    if (r == BVH_SUCCESS) r = bvh_scene_build(&sc, &sd);
    if (r == BVH_SUCCESS) {
        make_rays(c, bvh_tree_bounds(&tree), &cam);
        /* paired rounds, the order alternating: a slow moment hits both of a round, and the
           median of the rounds' ratios is robust to a spell that spans a few rounds */
        for (rep = 0; rep < BENCH_INST_ROUNDS; rep++) {
            progress("%s: one instance against the tree, %u/%u", out->name, rep + 1, BENCH_INST_ROUNDS);
            if (rep & 1) {
                scn[rep] = trace_1t(c, &tree, &sc);
                one[rep] = trace_1t(c, &tree, NULL);
            } else {
                one[rep] = trace_1t(c, &tree, NULL);
                scn[rep] = trace_1t(c, &tree, &sc);
            }
            ratio[rep] = one[rep] / scn[rep];
        }
        median_range(one, BENCH_INST_ROUNDS, &med, &lo, &hi);
        out->one_level_mrays_1t = mrays_of(c->npix, med);
        median_range(scn, BENCH_INST_ROUNDS, &med, &lo, &hi);
        out->inst_mrays_1t = mrays_of(c->npix, med);
        median_range(ratio, BENCH_INST_ROUNDS, &out->inst_ratio, &out->inst_ratio_min, &out->inst_ratio_max);
        bvh_scene_free(&sc);
    }
    free(inst);
    bvh_free(&tree);
    if (r != BVH_SUCCESS) say("%s: instances: %s", out->name, bvh_result_string(r));
    return r != BVH_SUCCESS;
}

/* Runs every row on one loaded scene; 0 when nothing failed. */
static int run_scene(const options *o, const scene *s, bench_cl *cl, bench_scene *out) {
    run_ctx c;
    int i, failed = 0;
    uint32_t t;
    memset(&c, 0, sizeof c);
    c.o = o;
    c.s = s;
    c.out = out;
    c.cl = cl;
    out->inst_ms = out->inst_min = out->inst_max = out->inst_mrays_1t = out->one_level_mrays_1t = NAN;
    out->inst_ratio = out->inst_ratio_min = out->inst_ratio_max = NAN;
    c.ref_hits = NAN;
    atomic_init(&c.mem.live, 0);
    atomic_init(&c.mem.peak, 0);
    c.npix = (size_t)o->width * o->height;
    c.ids = (uint32_t *)malloc((size_t)s->triangles * sizeof *c.ids);
    c.rays = (bvh_ray *)malloc(c.npix * sizeof *c.rays);
    c.hits = (bvh_hit *)malloc(c.npix * sizeof *c.hits);
    c.ref = (bvh_hit *)malloc(c.npix * sizeof *c.ref);
    c.emb_prims = (uint32_t *)malloc(c.npix * sizeof *c.emb_prims);
    if (!c.ids || !c.rays || !c.hits || !c.ref || !c.emb_prims) {
        say("%s: out of memory", out->name);
        failed = 1;
        goto done;
    }
    c.bounds = bvh_aabb_empty();
    for (t = 0; t < s->triangles; t++) {
        const float *p = s->v + 9 * (size_t)t;
        int k, ok = 1;
        for (k = 0; k < 9; k++) ok &= isfinite(p[k]) != 0;
        if (!ok) continue;
        c.ids[c.nids++] = t;
        for (k = 0; k < 3; k++) {
            bvh_vec3 q;
            q.x = p[3 * k];
            q.y = p[3 * k + 1];
            q.z = p[3 * k + 2];
            bvh_aabb_grow(&c.bounds, q);
        }
    }
    if (o->brute) row_init(&out->rows[out->nrows++], ROW_BRUTE, "none");
    for (i = 0; i < o->nbuilders; i++) {
        row *r = &out->rows[out->nrows++];
        char name[24];
        snprintf(name, sizeof name, "%s%s", bvh_builder_name(o->builders[i]), o->opt[i] ? "+opt" : "");
        row_init(r, ROW_BVH, name);
        r->builder = o->builders[i];
        r->opt = o->opt[i];
    }
    for (i = 0; emb_available() && i < o->nqualities; i++) {
        row *r = &out->rows[out->nrows++];
        char name[24];
        snprintf(name, sizeof name, "embree-%s", emb_quality_name(o->qualities[i]));
        row_init(r, ROW_EMBREE, name);
        r->quality = o->qualities[i];
    }
    for (i = 0; i < out->nrows; i++) {
        row *r = &out->rows[i];
        if (r->kind == ROW_BRUTE)
            run_brute(&c, r);
        else if (r->kind == ROW_BVH)
            run_builder(&c, r);
        else
            run_embree(&c, r);
        if (r->state == ROW_FAILED) {
            say("%s: %s %s", out->name, r->name, r->note);
            failed = 1;
        }
    }
    ratios(out);
    run_paired(&c, out);
    failed |= run_instances(&c, out);
done:
    progress_end();
    free(c.ids);
    free(c.rays);
    free(c.hits);
    free(c.ref);
    free(c.emb_prims);
    rays_free(&c.sets);
    free(c.dhits);
    free(c.dref);
    free(c.occ);
    free(c.oref);
    return failed;
}

/* ============================================================================================ */
/* == tables: columns, cells, best values ========================================================= */
/* ============================================================================================ */
enum {
    C_BUILDER,
    C_BUILD,
    C_RANGE,
    C_BUILD1,
    C_SAH,
    C_NODES,
    C_LEAVES,
    C_REFS,
    C_DEPTH,
    C_BPT,
    C_WBPT,
    C_PEAK,
    C_PEAKBPT,
    C_MR1,
    C_MRN,
    C_MRCL,
    C_DMR1,
    C_DMRN,
    C_SMR1,
    C_SMRN,
    C_FRAME,
    C_FPS,
    C_HITS,
    C_XBUILD,
    C_XSAH,
    C_XMR,
    C_COUNT
};
typedef struct column {
    const char *head; /* text table; "%u" becomes the thread count */
    const char *md;   /* Markdown header */
    int width;        /* text table */
    int better;       /* -1 lower is better, +1 higher, 0 not ranked */
} column;
static const column g_cols[C_COUNT] = {
    {"builder", "Builder", 14, 0},
    {"build ms", "Build ms (median)", 9, -1},
    {"min-max", "min-max", 15, 0},
    {"build 1t", "Build ms 1 thread", 9, -1},
    {"SAH", "SAH (1,0,1)", 9, -1},
    {"nodes", "Nodes", 9, 0},
    {"leaves", "Leaves", 8, 0},
    {"refs", "Refs", 8, 0},
    {"depth", "Max depth", 5, -1},
    {"B/tri", "BVH B/tri", 6, -1},
    {"8w B/tri", "8-wide B/tri", 8, 0},
    {"peak MB", "Peak build MB", 8, -1},
    {"pk B/tri", "Peak B/tri", 8, -1},
    {"Mr/s 1t", "CPU Mrays/s 1 thread", 8, +1},
    {"Mr/s %ut", "CPU Mrays/s %u threads", 8, +1},
    {"Mr/s CL", "OpenCL Mrays/s", 8, +1},
    {"diff 1t", "Diffuse Mrays/s 1 thread", 8, +1},
    {"diff %ut", "Diffuse Mrays/s %u threads", 8, +1},
    {"shad 1t", "Shadow Mrays/s 1 thread", 8, +1},
    {"shad %ut", "Shadow Mrays/s %u threads", 8, +1},
    {"frame ms", "Frame ms", 9, -1},
    {"FPS", "FPS", 7, +1},
    {"hits", "Hits", 13, 0},
    {"xbuild", "Build / Embree med.", 7, -1},
    {"xSAH", "SAH / Embree med.", 6, -1},
    {"xMrays", "Mrays / Embree med.", 7, +1},
};

static void fmt_num(char *b, size_t n, double v, int prec) {
    if (isnan(v))
        snprintf(b, n, "-");
    else
        snprintf(b, n, "%.*f", prec, v);
}
static void fmt_ms(char *b, size_t n, double v) { /* 3 significant digits, at least 0 decimals */
    fmt_num(b, n, v, isnan(v) ? 0 : v < 10.0 ? 3 : v < 100.0 ? 2 : v < 1000.0 ? 1 : 0);
}

/* The text of one cell (without markers); returns the value used to rank it (NAN: none). */
static double cell(const bench_scene *s, const row *r, int col, char *b, size_t n) {
    double tris = s->triangles ? (double)s->triangles : NAN;
    char lo[16], hi[16];
    switch (col) {
    case C_BUILDER:
        snprintf(b, n, "%s", r->name);
        return NAN;
    case C_BUILD:
        if (r->kind == ROW_BRUTE) {
            snprintf(b, n, "0");
            return NAN;
        } /* the study's 0: nothing built */
        fmt_ms(b, n, r->build_ms);
        return r->build_ms;
    case C_RANGE:
        if (isnan(r->build_min) || r->kind == ROW_BRUTE) {
            snprintf(b, n, "-");
            return NAN;
        }
        fmt_ms(lo, sizeof lo, r->build_min);
        fmt_ms(hi, sizeof hi, r->build_max);
        snprintf(b, n, "%s-%s", lo, hi);
        return NAN;
    case C_BUILD1:
        fmt_ms(b, n, r->build_1t);
        return r->build_1t;
    case C_SAH:
        fmt_num(b, n, r->sah, 2);
        return r->sah;
    case C_NODES:
        fmt_num(b, n, r->nodes, 0);
        return r->nodes;
    case C_LEAVES:
        fmt_num(b, n, r->leaves, 0);
        return r->leaves;
    case C_REFS:
        fmt_num(b, n, r->refs, 0);
        return r->refs;
    case C_DEPTH:
        fmt_num(b, n, r->max_depth, 0);
        return r->max_depth;
    case C_BPT:
        fmt_num(b, n, r->bvh_bytes / tris, 1);
        return r->bvh_bytes / tris;
    case C_WBPT:
        fmt_num(b, n, r->wide_bytes / tris, 1);
        return r->wide_bytes / tris;
    case C_PEAK:
        fmt_ms(b, n, r->peak_bytes / 1048576.0);
        return r->peak_bytes;
    case C_PEAKBPT:
        fmt_num(b, n, r->peak_bytes / tris, 0);
        return r->peak_bytes / tris;
    case C_MR1:
        fmt_num(b, n, r->mrays_1t, 2);
        return r->mrays_1t;
    case C_MRN:
        fmt_num(b, n, r->mrays_mt, 2);
        return r->mrays_mt;
    case C_MRCL:
        fmt_num(b, n, r->mrays_cl, 2);
        return r->mrays_cl;
    case C_DMR1:
        fmt_num(b, n, r->set[SET_DIFFUSE].mrays_1t, 2);
        return r->set[SET_DIFFUSE].mrays_1t;
    case C_DMRN:
        fmt_num(b, n, r->set[SET_DIFFUSE].mrays_mt, 2);
        return r->set[SET_DIFFUSE].mrays_mt;
    case C_SMR1:
        fmt_num(b, n, r->set[SET_SHADOW].mrays_1t, 2);
        return r->set[SET_SHADOW].mrays_1t;
    case C_SMRN:
        fmt_num(b, n, r->set[SET_SHADOW].mrays_mt, 2);
        return r->set[SET_SHADOW].mrays_mt;
    case C_FRAME:
        fmt_ms(b, n, r->frame_ms);
        return r->frame_ms;
    case C_FPS:
        fmt_num(b, n, r->fps, r->fps < 10.0 ? 2 : 1);
        return r->fps;
    case C_HITS:
        fmt_num(b, n, r->hits, 0);
        return NAN;
    case C_XBUILD:
        fmt_num(b, n, r->x_build, 2);
        return r->x_build;
    case C_XSAH:
        fmt_num(b, n, r->x_sah, 3);
        return r->x_sah;
    case C_XMR:
        fmt_num(b, n, r->x_mrays, 2);
        return r->x_mrays;
    default:
        snprintf(b, n, "?");
        return NAN;
    }
}

/* best[col]: the text of the best value of the column in this scene ("" if none) */
static void best_cells(const bench_scene *s, char best[C_COUNT][40]) {
    int col, i;
    for (col = 0; col < C_COUNT; col++) {
        double bv = NAN;
        best[col][0] = 0;
        if (!g_cols[col].better) continue;
        for (i = 0; i < s->nrows; i++) {
            char b[40];
            double v = cell(s, &s->rows[i], col, b, sizeof b);
            if (s->rows[i].state != ROW_OK || isnan(v)) continue;
            if (isnan(bv) || (g_cols[col].better < 0 ? v < bv : v > bv)) {
                bv = v;
                snprintf(best[col], sizeof best[col], "%s", b);
            }
        }
    }
}

static void head_text(int col, const options *o, int md, char *b, size_t n) {
    const char *h = md ? g_cols[col].md : g_cols[col].head;
    if (col == C_MRN || col == C_DMRN || col == C_SMRN)
        snprintf(b, n, h, o->nthreads);
    else
        snprintf(b, n, "%s", h);
}

/* ---- the text table ------------------------------------------------------------------------ */
/* One block of paired ratios, a line per builder that has them (none without --paired): which
   0 = build time, 1 = one-thread tracing against Embree, 2 = OpenCL against the CPU, 3 and 4 =
   one-thread tracing of the diffuse and the shadow rays against Embree. em: Embree medium's row. */
static void paired_block(FILE *f, const bench_scene *s, const row *em, const char *prefix, int which,
                         const char *title) {
    int i, any = 0;
    for (i = 0; i < s->nrows; i++) {
        const row *r = &s->rows[i];
        const set_figs *sf = which >= 3 ? &r->set[which - 3] : NULL;
        double med = which == 0 ? r->x_pair : which == 1 ? r->x_ptrace : which == 2 ? r->x_pcl : sf->x_p;
        double lo = which == 0 ? r->x_pair_min : which == 1 ? r->x_ptrace_min : which == 2 ? r->x_pcl_min : sf->x_p_min;
        double hi = which == 0 ? r->x_pair_max : which == 1 ? r->x_ptrace_max : which == 2 ? r->x_pcl_max : sf->x_p_max;
        double mr = which == 1 ? r->p_mrays : sf ? sf->p_mrays : NAN;
        double emr = !em ? NAN : which == 1 ? em->p_mrays : sf ? em->set[which - 3].p_mrays : NAN;
        if (r->kind != ROW_BVH || r->state != ROW_OK || isnan(med)) continue;
        if (!any++) fprintf(f, "%s%s: median (min-max)\n", prefix, title);
        fprintf(f, "%s  %-14s %.2f (%.2f-%.2f)", prefix, r->name, med, lo, hi);
        if (which == 0 && !isnan(r->pair_ms))
            fprintf(f, "   median build %.4g ms (table: %.4g)", r->pair_ms, r->build_ms);
        if (!isnan(mr)) fprintf(f, "   median %.3g Mrays/s (embree-medium %.3g)", mr, emr);
        fputc('\n', f);
    }
}
/* The thread scaling of the paired tracing rounds: a line per builder, camera / diffuse / shadow */
static void scaling_block(FILE *f, const options *o, const bench_scene *s, const char *prefix) {
    int i, k, any = 0;
    for (i = 0; i < s->nrows; i++) {
        const row *r = &s->rows[i];
        if (r->kind == ROW_BRUTE || r->state != ROW_OK || isnan(r->x_scale)) continue;
        if (!any++)
            fprintf(f,
                    "%sMrays/s on %u threads / on 1 thread in the same paired rounds (each pass right after the "
                    "1-thread one): median (min-max), camera",
                    prefix, o->nthreads);
        if (any == 1) {
            for (k = 0; k < SET_COUNT; k++) fprintf(f, " / %s", g_set_names[k]);
            fputc('\n', f);
        }
        fprintf(f, "%s  %-14s %.2f (%.2f-%.2f)", prefix, r->name, r->x_scale, r->x_scale_min, r->x_scale_max);
        for (k = 0; k < SET_COUNT; k++)
            fprintf(f, " / %.2f (%.2f-%.2f)", r->set[k].x_s, r->set[k].x_s_min, r->set[k].x_s_max);
        fputc('\n', f);
    }
}
static void paired_lines(FILE *f, const options *o, const bench_scene *s, const char *prefix) {
    char t[200];
    const row *em = NULL;
    int i;
    for (i = 0; i < s->nrows; i++)
        if (s->rows[i].kind == ROW_EMBREE && s->rows[i].quality == EMB_QUALITY_MEDIUM && !isnan(s->rows[i].pair_ms))
            em = &s->rows[i];
    if (em)
        snprintf(t, sizeof t,
                 "build / embree-medium in %u paired rounds (one build each, interleaved; embree-medium's "
                 "median build %.4g ms, table: %.4g)",
                 o->paired, em->pair_ms, em->build_ms);
    else
        snprintf(t, sizeof t, "build / embree-medium in %u paired rounds (one build each, interleaved)", o->paired);
    paired_block(f, s, em, prefix, 0, t);
    for (i = 0; i < s->nrows; i++)
        if (s->rows[i].kind == ROW_EMBREE && s->rows[i].quality == EMB_QUALITY_HIGH && !isnan(s->rows[i].pair_ms)) {
            const row *eh = &s->rows[i];
            int j, any = 0;
            for (j = 0; j < s->nrows; j++) {
                const row *r = &s->rows[j];
                if (r->kind != ROW_BVH || r->state != ROW_OK || isnan(r->x_pairh)) continue;
                if (!any++)
                    fprintf(f,
                            "%sbuild / embree-high in the same %u rounds (embree-high's median build %.4g ms, "
                            "table: %.4g): median (min-max)\n",
                            prefix, o->paired, eh->pair_ms, eh->build_ms);
                fprintf(f, "%s  %-14s %.2f (%.2f-%.2f)\n", prefix, r->name, r->x_pairh, r->x_pairh_min, r->x_pairh_max);
            }
        }
    {
        int any = 0;
        for (i = 0; i < s->nrows; i++) {
            const row *r = &s->rows[i];
            if (r->kind != ROW_BVH || r->state != ROW_OK || isnan(r->x_pairo)) continue;
            if (!any++)
                fprintf(f, "%sbuild / ploc-parallel's in the same %u rounds: median (min-max)\n", prefix, o->paired);
            fprintf(f, "%s  %-14s %.2f (%.2f-%.2f)\n", prefix, r->name, r->x_pairo, r->x_pairo_min, r->x_pairo_max);
        }
    }
    for (i = 0; i < s->nrows; i++)
        if (s->rows[i].kind == ROW_EMBREE && s->rows[i].quality == EMB_QUALITY_MEDIUM && !isnan(s->rows[i].p_mrays))
            em = &s->rows[i];
    snprintf(t, sizeof t, "Mrays/s on 1 thread / embree-medium's in %u paired rounds (one frame each)", o->paired);
    paired_block(f, s, em, prefix, 1, t);
    for (i = 0; i < SET_COUNT; i++) {
        snprintf(t, sizeof t, "%s rays' Mrays/s on 1 thread / embree-medium's in %u paired rounds (one pass each)",
                 g_set_names[i], o->paired);
        paired_block(f, s, em, prefix, 3 + i, t);
    }
    snprintf(t, sizeof t, "OpenCL Mrays/s / the CPU's on %u threads in %u paired rounds (one frame each)", o->nthreads,
             o->paired);
    paired_block(f, s, em, prefix, 2, t);
    scaling_block(f, o, s, prefix);
}

/* What the secondary ray sets are, and their counts (from the first row that traced them) */
static void sets_lines(FILE *f, const bench_scene *s, const char *prefix) {
    const row *r = NULL;
    bvh_vec3 L = rays_light();
    int i;
    for (i = 0; i < s->nrows && !r; i++)
        if (s->rows[i].kind != ROW_EMBREE && !isnan(s->rows[i].set[SET_SHADOW].count)) r = &s->rows[i];
    if (!r) return;
    fprintf(f,
            "%sdiffuse rays: %.0f (one per primary hit, cosine-weighted about the normal, origin %g x the scene "
            "diagonal off the surface), %.0f hit; shadow rays: %.0f (to the light (%.3f, %.3f, %.3f) from the "
            "hits facing it, any hit), %.0f occluded\n",
            prefix, r->set[SET_DIFFUSE].rays, (double)RAYS_OFFSET, r->set[SET_DIFFUSE].count, r->set[SET_SHADOW].rays,
            (double)L.x, (double)L.y, (double)L.z, r->set[SET_SHADOW].count);
    for (i = 0; i < s->nrows; i++)
        if (s->rows[i].set_note[0])
            fprintf(f, "%s(e) %s on the secondary rays (tolerance %g of a set): %s\n", prefix, s->rows[i].name,
                    BENCH_SET_TOLERANCE, s->rows[i].set_note);
}

static void instances_line(FILE *f, const options *o, const bench_scene *s, const char *prefix) {
    if (isnan(s->inst_ms)) return;
    fprintf(f,
            "%sinstances: top-level rebuild for %u instances of the default tree: %.2f ms (%.2f..%.2f, %s top, "
            "%u threads); one instance vs the tree itself, camera rays on 1 thread: %.2f vs %.2f Mrays/s, "
            "%.3fx (median of %d paired rounds' ratios; %.3f..%.3f)\n",
            prefix, o->instances, s->inst_ms, s->inst_min, s->inst_max, bvh_builder_name(BVH_BUILDER_PLOC_PARALLEL),
            o->nthreads, s->inst_mrays_1t, s->one_level_mrays_1t, s->inst_ratio, BENCH_INST_ROUNDS, s->inst_ratio_min,
            s->inst_ratio_max);
}
/* --refit and --save-load: a line per bvh.h row. */
static void anim_lines(FILE *f, const options *o, const bench_scene *s, const char *prefix) {
    int i;
    if (o->refit)
        fprintf(f,
                "%sanimated (--refit %u: a twist and a wave, %u threads): per-frame refit ms, rebuild ms (bottom-up), "
                "Embree 3's refit ms of the same frames (two-level scene, REFIT mesh), SAH refitted / rebuilt by the "
                "builder at the last frame, Mrays/s after refit / after rebuild\n",
                prefix, o->refit, o->nthreads);
    for (i = 0; o->refit && i < s->nrows; i++) {
        const row *r = &s->rows[i];
        char emb[48] = "       - ms (    -)"; /* Embree's refit ms and its time / ours */
        if (r->kind != ROW_BVH || r->state != ROW_OK) continue;
        if (!isnan(r->emb_refit_ms))
            snprintf(emb, sizeof emb, "%8.2f ms (%5.2fx)", r->emb_refit_ms, r->emb_refit_ms / r->refit_ms);
        fprintf(f,
                "%s  %-14s refit %8.2f ms  rebuild %8.2f ms (%5.1fx)  Embree refit %s  SAH %8.2f / %8.2f "
                "(%+.1f%%)  Mrays/s %7.2f / %7.2f\n",
                prefix, r->name, r->refit_ms, r->rebuild_ms, r->rebuild_ms / r->refit_ms, emb, r->refit_sah,
                r->rebuild_sah, 100.0 * (r->refit_sah / r->rebuild_sah - 1.0), r->refit_mrays, r->rebuild_mrays);
    }
    if (o->save_load)
        fprintf(f,
                "%ssave and load (--save-load, memory, 8-wide packets remade on load; borrowed: "
                "bvh_load_desc.borrow, the arrays read in place): ms, medians after a warm-up pair (its times "
                "last), the build over each\n",
                prefix);
    for (i = 0; o->save_load && i < s->nrows; i++) {
        const row *r = &s->rows[i];
        if (r->kind != ROW_BVH || r->state != ROW_OK) continue;
        fprintf(f,
                "%s  %-14s save %8.2f  load %8.2f  borrowed %8.2f  (build %8.2f: %4.1fx | %4.1fx)  warm-up save "
                "%8.2f  load %8.2f\n",
                prefix, r->name, r->save_ms, r->load_ms, r->load_borrow_ms, r->build_ms, r->build_ms / r->load_ms,
                r->build_ms / r->load_borrow_ms, r->save_first_ms, r->load_first_ms);
    }
    if (o->layout_cost)
        fprintf(f,
                "%swhat the 8-wide layout adds to the build (--layout-cost, %u threads): the build without it "
                "(trace_width 2, median), the median of the paired differences, and their ratio\n",
                prefix, o->nthreads);
    for (i = 0; o->layout_cost && i < s->nrows; i++) {
        const row *r = &s->rows[i];
        if (r->kind != ROW_BVH || r->state != ROW_OK || isnan(r->layout_ms)) continue;
        fprintf(f, "%s  %-14s without %9.2f ms  layout %+8.2f ms  (%+5.1f%%)\n", prefix, r->name, r->build2_ms,
                r->layout_ms, 100.0 * r->layout_ms / r->build2_ms);
    }
}

static void print_block(FILE *f, const options *o, const bench_scene *s) {
    char b[220];
    int col, i;
    fprintf(f, "\nscene %s: %u triangles, %ux%u primary rays\n", s->name, s->triangles, o->width, o->height);
    for (col = 0; col < C_COUNT; col++) {
        head_text(col, o, 0, b, sizeof b);
        fprintf(f, col == C_BUILDER ? "%-*s" : " %*s", g_cols[col].width, b);
    }
    fputc('\n', f);
    for (i = 0; i < s->nrows; i++) {
        const row *r = &s->rows[i];
        fprintf(f, "%-*s", g_cols[C_BUILDER].width, r->name);
        if (r->state != ROW_OK) {
            if (r->kind == ROW_BRUTE) fprintf(f, " %*s", g_cols[C_BUILD].width, "0");
            fprintf(f, "  %s\n", r->note);
            continue;
        }
        for (col = 1; col < C_COUNT; col++) {
            cell(s, r, col, b, sizeof b);
            if (col == C_HITS && (r->disagree || r->refereed))
                strncat(b, r->disagree ? " (!)" : " (e)", sizeof b - strlen(b) - 1);
            fprintf(f, " %*s", g_cols[col].width, b);
        }
        fputc('\n', f);
    }
    for (i = 0; i < s->nrows; i++)
        if (s->rows[i].disagree)
            fprintf(f, "(!) HITS DISAGREE: %s\n", s->rows[i].disagree_msg);
        else if (s->rows[i].refereed)
            fprintf(f, "(e) %s\n", s->rows[i].referee_msg);
    sets_lines(f, s, "");
    anim_lines(f, o, s, "");
    paired_lines(f, o, s, "");
    instances_line(f, o, s, "");
}

/* ---- Markdown --------------------------------------------------------------------------------- */
static void md_block(FILE *f, const options *o, const bench_scene *s) {
    char b[220], best[C_COUNT][40];
    int col, i;
    best_cells(s, best);
    fprintf(f, "\n### %s: %u triangles\n\n|", s->name, s->triangles);
    for (col = 0; col < C_COUNT; col++) {
        head_text(col, o, 1, b, sizeof b);
        fprintf(f, " %s |", b);
    }
    fputs("\n|", f);
    for (col = 0; col < C_COUNT; col++) fputs(col == C_BUILDER ? ":---|" : "---:|", f);
    fputc('\n', f);
    for (i = 0; i < s->nrows; i++) {
        const row *r = &s->rows[i];
        fprintf(f, "| %s |", r->name);
        for (col = 1; col < C_COUNT; col++) {
            if (r->state != ROW_OK) {
                const char *t = col == C_BUILD && r->kind == ROW_BRUTE ? "0"
                                : col == C_RANGE ? (r->state == ROW_SKIPPED ? "skipped (too slow)" : "failed")
                                : (col == C_FRAME || col == C_FPS) ? "X"
                                                                   : "";
                if (col == C_RANGE && r->state == ROW_SKIPPED && strncmp(r->note, "skipped (too slow", 17))
                    t = "skipped";
                fprintf(f, " %s |", t);
                continue;
            }
            cell(s, r, col, b, sizeof b);
            if (best[col][0] && !strcmp(b, best[col]))
                fprintf(f, " **%s** |", b);
            else
                fprintf(f, " %s%s |", b, col != C_HITS ? "" : r->disagree ? " **(!)**" : r->refereed ? " (e)" : "");
        }
        fputc('\n', f);
    }
    for (i = 0; i < s->nrows; i++) {
        const row *r = &s->rows[i];
        if (r->disagree)
            fprintf(f, "\n**(!) HITS DISAGREE:** %s\n", r->disagree_msg);
        else if (r->refereed)
            fprintf(f, "\n(e) %s\n", r->referee_msg);
        if (r->state != ROW_OK) fprintf(f, "\n%s: %s\n", r->name, r->note);
    }
    fputc('\n', f);
    sets_lines(f, s, "- ");
    for (i = 0; i < s->nrows; i++)
        if (s->rows[i].kind == ROW_BVH && !isnan(s->rows[i].x_pair)) {
            fputc('\n', f);
            paired_lines(f, o, s, "");
            break;
        }
}

/* ---- the top lines ------------------------------------------------------------------------------ */
static void cpu_model(char *b, size_t n) {
    FILE *f = fopen("/proc/cpuinfo", "r");
    char line[512];
    snprintf(b, n, "unknown");
    if (!f) return;
    while (fgets(line, sizeof line, f)) {
        char *colon = strchr(line, ':');
        if (strncmp(line, "model name", 10) || !colon) continue;
        colon++;
        while (*colon == ' ' || *colon == '\t') colon++;
        colon[strcspn(colon, "\n")] = 0;
        snprintf(b, n, "%s", colon);
        break;
    }
    fclose(f);
}

typedef struct header_info {
    char date[64], cpu[256], embree[200], opencl[400], trace[64];
} header_info;

/* --embree-flags: the JSON's value, and the header's and Markdown's words */
static const char *embree_flags_name(const options *o) { return o->embree_robust ? "robust" : "default"; }
static const char *embree_flags_text(const options *o) {
    return o->embree_robust ? "robust (RTC_SCENE_FLAG_ROBUST)" : "default (none: Embree's own)";
}

static void header_lines(FILE *f, const options *o, const header_info *h, const char *prefix) {
    fprintf(f, "%sbvhbench: bvh.h %d.%d.%d, %s\n", prefix, BVH_VERSION_MAJOR, BVH_VERSION_MINOR, BVH_VERSION_PATCH,
            h->date);
    fprintf(f, "%sCPU: %s, %u cores online; threads %u (ploc-parallel, multi-thread tracing, Embree)\n", prefix, h->cpu,
            scene_cpu_count(), o->nthreads);
    fprintf(f, "%sEmbree: %s\n", prefix, h->embree);
    bvh_builder_info ploc;
    bvh_builder_get_info(BVH_BUILDER_PLOC, &ploc); /* the defaults of desc.ploc */
    if (o->ploc_top == BVH_OFF)
        fprintf(f, "%sPLOC: the paper's, without the SAH top (--ploc-top off)\n", prefix);
    else
        fprintf(f, "%sPLOC: with the SAH top over the last n/%u clusters (--ploc-top)\n", prefix,
                o->ploc_top ? o->ploc_top : ploc.ploc.top);
    if (o->max_bytes == BVH_OFF)
        fprintf(f, "%sPLOC's collapse: the SAH alone (--max-bytes off)\n", prefix);
    else
        fprintf(f, "%sPLOC's collapse: tree at most %u bytes per triangle (--max-bytes)\n", prefix,
                o->max_bytes ? o->max_bytes : ploc.ploc.max_bytes_per_prim);
    fprintf(f, "%sOpenCL: %s\n", prefix, h->opencl);
    fprintf(f,
            "%sbuild: median of %u timed build(s) after one warm-up; frame: %ux%u primary rays of the %s, "
            "traced %s (CPU, OpenCL and Embree: median of %d frames); frame ms = fastest tracer; CPU tracing walks the "
            "%s\n",
            prefix, o->repeat, o->width, o->height, o->inside ? "interior camera (--camera inside)" : "standard camera",
            h->trace, BENCH_TRACE_REPEAT,
            o->trace_width == 2 ? "binary nodes (--trace-width 2)" : "8-wide copy (OpenCL: the binary nodes)");
}

static int mkdir_p(const char *dir);

/* fopen(path, "w"), creating the directory first */
static FILE *create_file(const char *path) {
    char dir[1024];
    const char *slash = strrchr(path, '/');
    if (slash && slash != path && (size_t)(slash - path) < sizeof dir) {
        memcpy(dir, path, (size_t)(slash - path));
        dir[slash - path] = 0;
        mkdir_p(dir);
    }
    return fopen(path, "w");
}

static int write_md(const char *path, const options *o, const header_info *h, const bench_scene *sc, int n) {
    FILE *f = create_file(path);
    int i;
    if (!f) {
        say("cannot write %s: %s", path, strerror(errno));
        return 1;
    }
    fputs("# bvh.h benchmark: the study's Table I, with Embree\n\n", f);
    header_lines(f, o, h, "- ");
    fprintf(f,
            "- best value per column and scene in **bold**; \"-\": does not apply; X: too slow to be measured "
            "(as in the study); hits: (!) disagreement, (e) Embree differs from bvh.h only on grazing rays or "
            "where an exact test agrees with bvh.h\n"
            "- Embree rows: build ms and Mrays/s of the scene API (rtcIntersect1 / rtcOccluded1), scene flags: %s; "
            "SAH, nodes, leaves, refs, depth of rtcBuildBVH's binary tree at the same quality (max leaf 8)\n",
            embree_flags_text(o));
    for (i = 0; i < n; i++) md_block(f, o, &sc[i]);
    if (fclose(f) != 0) {
        say("cannot write %s", path);
        return 1;
    }
    return 0;
}

/* ---- JSON lines ------------------------------------------------------------------------------------ */
static void json_num(FILE *f, const char *key, double v, int prec) {
    fprintf(f, ",\"%s\":", key);
    if (isnan(v) || isinf(v))
        fputs("null", f);
    else
        fprintf(f, "%.*f", prec, v);
}

/* "diffuse_KEY" / "shadow_KEY" */
static void json_set_num(FILE *f, int set, const char *key, double v, int prec) {
    char k[64];
    snprintf(k, sizeof k, "%s_%s", g_set_names[set], key);
    json_num(f, k, v, prec);
}

static void json_rows(FILE *f, const options *o, const bench_scene *s) {
    char key[64];
    int i, k;
    for (i = 0; i < s->nrows; i++) {
        const row *r = &s->rows[i];
        double tris = (double)s->triangles;
        fputs("{\"scene\":", f);
        scene_json_string(f, s->name);
        fprintf(f, ",\"triangles\":%u,\"camera\":\"%s\",\"builder\":", s->triangles, o->inside ? "inside" : "outside");
        scene_json_string(f, r->name);
        fprintf(f, ",\"kind\":\"%s\",\"status\":\"%s\",\"threads\":%u,\"repeat\":%u",
                r->kind == ROW_BRUTE ? "brute-force"
                : r->kind == ROW_BVH ? "bvh.h"
                                     : "embree",
                r->state == ROW_OK        ? "ok"
                : r->state == ROW_SKIPPED ? "skipped"
                                          : "failed",
                o->nthreads, o->repeat);
        json_num(f, "build_ms", r->build_ms, 4);
        json_num(f, "build_ms_min", r->build_min, 4);
        json_num(f, "build_ms_max", r->build_max, 4);
        json_num(f, "build_ms_1t", r->build_1t, 4);
        json_num(f, "sah", r->sah, 6);
        json_num(f, "nodes", r->nodes, 0);
        json_num(f, "leaves", r->leaves, 0);
        json_num(f, "refs", r->refs, 0);
        json_num(f, "max_depth", r->max_depth, 0);
        json_num(f, "max_leaf_size", r->max_leaf, 0);
        json_num(f, "bvh_bytes", r->bvh_bytes, 0);
        json_num(f, "triangle_bytes", r->tri_bytes, 0);
        json_num(f, "bytes_per_tri", r->bvh_bytes / tris, 3);
        json_num(f, "wide_bytes", r->wide_bytes, 0);
        json_num(f, "wide_bytes_per_tri", r->wide_bytes / tris, 3);
        json_num(f, "peak_build_bytes", r->peak_bytes, 0);
        json_num(f, "peak_build_bytes_per_tri", r->peak_bytes / tris, 3);
        fprintf(f, ",\"width\":%u,\"height\":%u", o->width, o->height);
        json_num(f, "hits", r->hits, 0);
        json_num(f, "t_sum", r->t_sum, 6);
        json_num(f, "mrays", r->mrays_mt, 4);
        json_num(f, "trace_ms_1t", r->ms_1t, 4);
        json_num(f, "mrays_1t", r->mrays_1t, 4);
        json_num(f, "trace_ms_mt", r->ms_mt, 4);
        json_num(f, "mrays_mt", r->mrays_mt, 4);
        json_num(f, "trace_ms_opencl", r->ms_cl, 4);
        json_num(f, "kernel_ms_opencl", r->cl_kernel_ms, 4);
        json_num(f, "mrays_opencl", r->mrays_cl, 4);
        json_num(f, "frame_ms", r->frame_ms, 4);
        json_num(f, "fps", r->fps, 3);
        fputs(",\"frame_tracer\":", f);
        if (r->frame_tracer)
            scene_json_string(f, r->frame_tracer);
        else
            fputs("null", f);
        /* the scene flags of every Embree scene, which the ratios below are taken against (null:
           no Embree) */
        fputs(",\"embree_flags\":", f);
        if (emb_available() && o->nqualities)
            scene_json_string(f, embree_flags_name(o));
        else
            fputs("null", f);
        json_num(f, "ratio_build", r->x_build, 4);
        json_num(f, "ratio_build_paired", r->x_pair, 4);
        json_num(f, "build_ms_paired", r->pair_ms, 4);
        json_num(f, "ratio_build_paired_min", r->x_pair_min, 4);
        json_num(f, "ratio_build_paired_max", r->x_pair_max, 4);
        json_num(f, "ratio_build_high_paired", r->x_pairh, 4);
        json_num(f, "ratio_build_high_paired_min", r->x_pairh_min, 4);
        json_num(f, "ratio_build_high_paired_max", r->x_pairh_max, 4);
        json_num(f, "ratio_build_ploc_paired", r->x_pairo, 4);
        json_num(f, "ratio_build_ploc_paired_min", r->x_pairo_min, 4);
        json_num(f, "ratio_build_ploc_paired_max", r->x_pairo_max, 4);
        json_num(f, "ratio_mrays_1t_paired", r->x_ptrace, 4);
        json_num(f, "ratio_mrays_1t_paired_min", r->x_ptrace_min, 4);
        json_num(f, "ratio_mrays_1t_paired_max", r->x_ptrace_max, 4);
        json_num(f, "ratio_opencl_mt_paired", r->x_pcl, 4);
        json_num(f, "ratio_opencl_mt_paired_min", r->x_pcl_min, 4);
        json_num(f, "ratio_opencl_mt_paired_max", r->x_pcl_max, 4);
        json_num(f, "mrays_1t_paired", r->p_mrays, 4);
        json_num(f, "scaling_mt_paired", r->x_scale, 4);
        json_num(f, "scaling_mt_paired_min", r->x_scale_min, 4);
        json_num(f, "scaling_mt_paired_max", r->x_scale_max, 4);
        for (k = 0; k < SET_COUNT; k++) {
            const set_figs *sf = &r->set[k];
            json_set_num(f, k, "rays", sf->rays, 0);
            json_set_num(f, k, k == SET_SHADOW ? "occluded" : "hits", sf->count, 0);
            if (k == SET_DIFFUSE) json_set_num(f, k, "t_sum", sf->t_sum, 6);
            json_set_num(f, k, "trace_ms_1t", sf->ms_1t, 4);
            json_set_num(f, k, "mrays_1t", sf->mrays_1t, 4);
            json_set_num(f, k, "trace_ms_mt", sf->ms_mt, 4);
            json_set_num(f, k, "mrays_mt", sf->mrays_mt, 4);
            json_set_num(f, k, "mrays_1t_paired", sf->p_mrays, 4);
            snprintf(key, sizeof key, "ratio_%s_1t_paired", g_set_names[k]);
            json_num(f, key, sf->x_p, 4);
            snprintf(key, sizeof key, "ratio_%s_1t_paired_min", g_set_names[k]);
            json_num(f, key, sf->x_p_min, 4);
            snprintf(key, sizeof key, "ratio_%s_1t_paired_max", g_set_names[k]);
            json_num(f, key, sf->x_p_max, 4);
            json_set_num(f, k, "scaling_mt_paired", sf->x_s, 4);
            json_set_num(f, k, "scaling_mt_paired_min", sf->x_s_min, 4);
            json_set_num(f, k, "scaling_mt_paired_max", sf->x_s_max, 4);
            if (r->kind == ROW_EMBREE) json_set_num(f, k, "rays_other_answer", sf->other, 0);
        }
        json_num(f, "instances", o->instances ? (double)o->instances : NAN, 0);
        json_num(f, "top_rebuild_ms", s->inst_ms, 4);
        json_num(f, "instance_mrays_1t", s->inst_mrays_1t, 4);
        json_num(f, "one_level_mrays_1t", s->one_level_mrays_1t, 4);
        json_num(f, "ratio_instance_mrays_1t", s->inst_ratio, 4);
        json_num(f, "ratio_instance_mrays_1t_min", s->inst_ratio_min, 4);
        json_num(f, "ratio_instance_mrays_1t_max", s->inst_ratio_max, 4);
        json_num(f, "refit_ms", r->refit_ms, 4);
        json_num(f, "rebuild_ms", r->rebuild_ms, 4);
        json_num(f, "embree_refit_ms", r->emb_refit_ms, 4);
        json_num(f, "refit_sah", r->refit_sah, 6);
        json_num(f, "rebuild_sah", r->rebuild_sah, 6);
        json_num(f, "refit_mrays", r->refit_mrays, 4);
        json_num(f, "rebuild_mrays", r->rebuild_mrays, 4);
        json_num(f, "save_ms", r->save_ms, 4);
        json_num(f, "load_ms", r->load_ms, 4);
        json_num(f, "load_borrow_ms", r->load_borrow_ms, 4);
        json_num(f, "save_first_ms", r->save_first_ms, 4);
        json_num(f, "load_first_ms", r->load_first_ms, 4);
        json_num(f, "build_ms_binary", r->build2_ms, 4);
        json_num(f, "layout_ms", r->layout_ms, 4);
        json_num(f, "layout_share", r->layout_ms / r->build2_ms, 4);
        json_num(f, "ratio_sah", r->x_sah, 4);
        json_num(f, "ratio_mrays", r->x_mrays, 4);
        if (r->kind == ROW_EMBREE) {
            json_num(f, "rtcbuildbvh_ms", r->emb_bvh_ms, 4);
            json_num(f, "pixels_other_triangle", r->emb_prim_diff, 0);
        }
        fprintf(f, ",\"hits_agree\":%s,\"hits_refereed\":%s,\"note\":", r->disagree || r->refereed ? "false" : "true",
                r->refereed && !r->disagree ? "true" : "false");
        scene_json_string(f, r->disagree ? r->disagree_msg : r->refereed ? r->referee_msg : r->note);
        fputs(",\"sets_note\":", f);
        scene_json_string(f, r->set_note);
        fputs("}\n", f);
    }
    fflush(f);
}

/* ============================================================================================ */
/* == plots: data files and gnuplot ================================================================ */
/* ============================================================================================ */
static int mkdir_p(const char *dir) {
    char p[1024];
    size_t i, n = strlen(dir);
    if (n == 0 || n >= sizeof p) return 1;
    memcpy(p, dir, n + 1);
    for (i = 1; i <= n; i++) {
        if (p[i] != '/' && p[i] != 0) continue;
        p[i] = 0;
        if (mkdir(p, 0777) != 0 && errno != EEXIST) return 1;
        if (i < n) p[i] = '/';
    }
    return 0;
}

static FILE *open_in(const char *dir, const char *name) {
    char path[1200];
    FILE *f;
    snprintf(path, sizeof path, "%s/%s", dir, name);
    f = fopen(path, "w");
    if (!f) say("cannot write %s: %s", path, strerror(errno));
    return f;
}

/* the distinct row names over all scenes, in order of appearance */
static int row_names(const bench_scene *sc, int n, const char *names[BENCH_MAX_ROWS * 2]) {
    int count = 0, i, j, k;
    for (i = 0; i < n; i++)
        for (j = 0; j < sc[i].nrows; j++) {
            for (k = 0; k < count && strcmp(names[k], sc[i].rows[j].name); k++) {
            }
            if (k == count && count < BENCH_MAX_ROWS * 2) names[count++] = sc[i].rows[j].name;
        }
    return count;
}

static const row *find_row(const bench_scene *s, const char *name) {
    int i;
    for (i = 0; i < s->nrows; i++)
        if (!strcmp(s->rows[i].name, name) && s->rows[i].state == ROW_OK) return &s->rows[i];
    return NULL;
}

/* 500, 69.7K, 1.04M */
static void fmt_count(char *b, size_t n, uint32_t v) {
    if (v < 10000)
        snprintf(b, n, "%u", v);
    else if (v < 1000000)
        snprintf(b, n, "%.3gK", v / 1e3);
    else
        snprintf(b, n, "%.3gM", v / 1e6);
}

static double per_scene_value(const bench_scene *s, const char *name, int field) {
    const row *r = find_row(s, name);
    return !r           ? NAN
           : field == 0 ? r->mrays_1t
           : field == 1 ? r->mrays_mt
           : field == 2 ? r->mrays_cl
                        : r->set[field - 3].mrays_1t; /* 3, 4: the diffuse and shadow rays */
}

/* One data column per row name that has a value somewhere (gnuplot cannot draw a histogram
   column without any), one line per scene; "-" = missing. No file when nothing was measured. */
static int write_per_scene(const char *dir, const char *file, const char *what, const bench_scene *sc, int n,
                           const char **names, int nn, int field) {
    int use[BENCH_MAX_ROWS * 2], i, k, any = 0;
    char count[32];
    FILE *f;
    for (k = 0; k < nn; k++) {
        for (i = 0, use[k] = 0; i < n; i++) use[k] |= !isnan(per_scene_value(&sc[i], names[k], field));
        any |= use[k];
    }
    if (!any) return 0;
    if (!(f = open_in(dir, file))) return 1;
    fprintf(f, "# %s per scene (rows) and builder (columns); '-' = not measured\n\"scene\"", what);
    for (k = 0; k < nn; k++)
        if (use[k]) fprintf(f, " \"%s\"", names[k]);
    fputc('\n', f);
    for (i = 0; i < n; i++) {
        fmt_count(count, sizeof count, sc[i].triangles);
        fprintf(f, "\"%s\\n%s triangles\"", sc[i].name, count);
        for (k = 0; k < nn; k++) {
            double v = per_scene_value(&sc[i], names[k], field);
            if (!use[k]) continue;
            if (isnan(v))
                fputs(" -", f);
            else
                fprintf(f, " %.4f", v);
        }
        fputc('\n', f);
    }
    return fclose(f) != 0;
}

static int write_plot_data(const char *dir, const options *o, const bench_scene *sc, int n) {
    const char *names[BENCH_MAX_ROWS * 2];
    int nn = row_names(sc, n, names), i, k, rc = 0, blocks, points;
    FILE *f;
    if (mkdir_p(dir)) {
        say("cannot create %s: %s", dir, strerror(errno));
        return 1;
    }
    for (k = 0; k < 5; k++) { /* no stale panel from an earlier run */
        static const char *const which[5] = {"1t", "mt", "cl", "diffuse_1t", "shadow_1t"};
        char path[1200];
        snprintf(path, sizeof path, "%s/mrays_%s.dat", dir, which[k]);
        remove(path);
    }
    /* build time vs triangles: one block (gnuplot index) per builder */
    if (!(f = open_in(dir, "build_time.dat"))) return 1;
    fprintf(f, "# build time (median of %u, ms) vs triangles; one block per builder\n", o->repeat);
    for (k = 0, blocks = 0; k < nn; k++) {
        for (i = 0, points = 0; i < n; i++) {
            const row *r = find_row(&sc[i], names[k]);
            if (!r || r->kind == ROW_BRUTE || isnan(r->build_ms)) continue;
            if (!points++)
                fprintf(f, "%s\"%s\" \"build_ms\" \"min\" \"max\" \"scene\"\n", blocks++ ? "\n\n" : "", names[k]);
            fprintf(f, "%u %.4f %.4f %.4f \"%s\"\n", sc[i].triangles, r->build_ms, r->build_min, r->build_max,
                    sc[i].name);
        }
    }
    rc |= fclose(f) != 0;
    /* SAH vs build time: one block per scene */
    if (!(f = open_in(dir, "sah_build.dat"))) return 1;
    fputs("# SAH (costs 1,0,1) vs build time (ms); one block per scene\n", f);
    for (i = 0; i < n; i++) {
        fprintf(f, "%s\"%s (%u triangles)\" \"sah\" \"builder\"\n", i ? "\n\n" : "", sc[i].name, sc[i].triangles);
        for (k = 0; k < sc[i].nrows; k++) {
            const row *r = &sc[i].rows[k];
            if (r->state == ROW_OK && r->kind != ROW_BRUTE && !isnan(r->build_ms) && !isnan(r->sah))
                fprintf(f, "%.4f %.6f \"%s\"\n", r->build_ms, r->sah, r->name);
        }
    }
    rc |= fclose(f) != 0;
    rc |= write_per_scene(dir, "mrays_1t.dat", "CPU Mrays/s on 1 thread", sc, n, names, nn, 0);
    if (o->nthreads > 1) {
        char what[64];
        snprintf(what, sizeof what, "CPU Mrays/s on %u threads", o->nthreads);
        rc |= write_per_scene(dir, "mrays_mt.dat", what, sc, n, names, nn, 1);
    }
    if (o->trace_cl) rc |= write_per_scene(dir, "mrays_cl.dat", "OpenCL Mrays/s", sc, n, names, nn, 2);
    rc |= write_per_scene(dir, "mrays_diffuse_1t.dat", "Diffuse rays: CPU Mrays/s on 1 thread", sc, n, names, nn, 3);
    rc |= write_per_scene(dir, "mrays_shadow_1t.dat", "Shadow rays: CPU Mrays/s on 1 thread", sc, n, names, nn, 4);
    if (rc) say("writing the plot data in %s failed", dir);
    return rc;
}

/* Runs bench/plot.sh DIR (found from the working directory or next to the program). */
static int run_plot_script(const char *argv0, const char *dir) {
    char script[1024];
    const char *slash = strrchr(argv0, '/');
    pid_t pid;
    int status;
    snprintf(script, sizeof script, "bench/plot.sh");
    if (access(script, R_OK) != 0 && slash)
        snprintf(script, sizeof script, "%.*s/../bench/plot.sh", (int)(slash - argv0), argv0);
    if (access(script, R_OK) != 0) {
        say("bench/plot.sh not found: plot data left in %s", dir);
        return 1;
    }
    fflush(NULL);
    pid = fork();
    if (pid < 0) {
        say("cannot run %s: %s", script, strerror(errno));
        return 1;
    }
    if (pid == 0) {
        execlp("sh", "sh", script, dir, (char *)NULL);
        _exit(127);
    }
    if (waitpid(pid, &status, 0) < 0) status = -1;
    if (WIFEXITED(status) && WEXITSTATUS(status) == 3) return 0; /* no gnuplot: plot.sh said so */
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
        say("%s %s failed (the .dat files are in %s)", script, dir, dir);
        return 1;
    }
    return 0;
}

/* ============================================================================================ */
/* == options ===================================================================================== */
/* ============================================================================================ */
static void usage(FILE *f) {
    fprintf(f,
            "usage: bvhbench [options] [SCENE...]\n"
            "  --builder LIST   'all' (default: none + the five builders + ploc-parallel+opt and\n"
            "                   sah-midpoint+opt) or a comma list of none, top-down, bottom-up,\n"
            "                   sah-midpoint, ploc, ploc-parallel, each optionally with '+opt' (the\n"
            "                   tree optimizer, desc.optimize: 8 rounds); none = brute force, the\n"
            "                   study's first row\n"
            "  --embree LIST    'all' (default: low,medium,high), 'none', or a comma list\n"
            "  --embree-flags F scene flags of every Embree scene: 'default' (the default: none,\n"
            "                   Embree's own, what a renderer gets unless it opts in) or 'robust'\n"
            "                   (RTC_SCENE_FLAG_ROBUST: the closest Embree comes to bvh.h's\n"
            "                   watertight test; slower)\n"
            "  --threads N      ploc-parallel, sah-midpoint, multi-thread tracing and Embree; 0 = all\n"
            "                   cores (default); their 'build 1t' column: the same builds on 1 thread\n"
            "  --repeat R       timed builds after one warm-up; the median is reported (default 5)\n"
            "  --size WxH       frame size (default 1024x1024)\n"
            "  --camera C       outside (default: bvh_camera_standard, outside the scene looking at\n"
            "                   its centre) or inside (low near one end, looking along the longer\n"
            "                   side: an interior's rays, as build/pathtrace --inside)\n"
            "  --trace-width W  8: builds add the 8-wide copy CPU tracing uses (default); 2: binary only\n"
            "  --ploc-top N     ploc builders: binned-SAH top over the last n/N clusters, kept where\n"
            "                   cheaper (0 = the library's default, 8); 'off': PLOC alone, as the study\n"
            "  --paired N       after the table, N rounds each building once with every builder and\n"
            "                   once with Embree medium (and high, when --embree has it),\n"
            "                   interleaved, then N rounds tracing a frame and the diffuse and\n"
            "                   shadow rays on 1 thread with each (each followed by the same\n"
            "                   on --threads: the thread scaling), and N rendering a frame\n"
            "                   with OpenCL and with the CPU on all threads; medians of the\n"
            "                   rounds' ratios and Mrays/s (robust to a shared machine's slow\n"
            "                   moments; <builder>+opt rows also against ploc-parallel's build,\n"
            "                   when --builder has it; default 0: none)\n"
            "  --instances N    after the table, the top-level rebuild (bvh_scene_build) for N instances\n"
            "                   of the default tree, and one instance against the tree on 1 thread, in 9\n"
            "                   paired rounds (the median of their ratios)\n"
            "                   (default 10000; 0: none)\n"
            "  --max-bytes N    ploc builders: tree (nodes + indices) at most N bytes per triangle, by\n"
            "                   bigger leaves where needed (0 = the library's default, 40); 'off': the SAH alone\n"
            "  --trace MODE     cpu, opencl, both or none (default: both when OpenCL works, else cpu)\n"
            "  --brute-max N    brute force only up to N triangles (default 20000) and %.0e tests\n"
            "  --refit N        animated case: N frames of a twisting, waving scene; per frame bvh_refit\n"
            "                   of each tree and a bottom-up rebuild (ms), then SAH and Mrays/s of the\n"
            "                   refitted tree against this builder's rebuild (default 0: none)\n"
            "  --save-load      time bvh_save and bvh_load (from memory, the 8-wide packets remade)\n",
            BENCH_BRUTE_TESTS);
    fprintf(f, /* in two: ISO C's longest string literal is 4095 characters */
            "  --layout-cost    pair each timed build with one without the 8-wide layout (trace_width\n"
            "                   2): what the layout adds to the build, ms and share\n"
            "  --md FILE        Markdown tables, best value per column and scene in bold\n"
            "  --json FILE      one JSON object per line and row ('-': stdout; the table goes to stderr)\n"
            "  --plots DIR      plot data (*.dat) and, with gnuplot, PNG plots (bench/plot.sh)\n"
            "  --strict         Embree's differences from bvh.h count as disagreements even where an\n"
            "                   exact test decides for bvh.h (they are marked (e) and noted otherwise)\n"
            "  --quiet          no progress line on stderr\n"
            "Without SCENE: gen:random:500, %s (or gen:random:100000), gen:field:15, gen:field:44.\n"
            "%s"
            "Exit status: 0 ok, 1 error, 2 bad command line, 3 hits disagree.\n",
            BENCH_BUNNY, scene_spec_help());
}

/* "off" (gives `off`) or a count up to 2^30: the --ploc-top and --max-bytes values */
static int parse_count_or_off(const char *s, uint32_t off, uint32_t *out) {
    if (s && !strcmp(s, "off")) {
        *out = off;
        return 0;
    }
    return scene_parse_u32(s, 0, 1u << 30, out, NULL);
}

static int parse_builders(const char *list, options *o) {
    char buf[256], *tok, *save = NULL;
    int i;
    o->brute = 0;
    o->nbuilders = 0;
    if (strlen(list) >= sizeof buf) return 1;
    strcpy(buf, list);
    for (tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
        bvh_builder b;
        char *plus = strchr(tok, '+');
        int opt = 0;
        if (!strcmp(tok, "all")) {
            o->brute = 1;
            o->nbuilders = 0;
            for (i = BVH_BUILDER_TOP_DOWN; i < BVH_BUILDER_COUNT; i++) {
                o->opt[o->nbuilders] = 0;
                o->builders[o->nbuilders++] = (bvh_builder)i;
            }
            /* the optimizer on the fastest builder of good trees and on the best one */
            o->opt[o->nbuilders] = 1;
            o->builders[o->nbuilders++] = BVH_BUILDER_PLOC_PARALLEL;
            o->opt[o->nbuilders] = 1;
            o->builders[o->nbuilders++] = BVH_BUILDER_SAH_MIDPOINT;
            continue;
        }
        if (!strcmp(tok, "none")) {
            o->brute = 1;
            continue;
        }
        if (plus) {
            if (strcmp(plus, "+opt")) return 1;
            *plus = 0;
            opt = 1;
        }
        if (bvh_builder_from_name(tok, &b) != BVH_SUCCESS || b == BVH_BUILDER_DEFAULT) return 1;
        for (i = 0; i < o->nbuilders && (o->builders[i] != b || o->opt[i] != opt); i++) {
        }
        if (i == o->nbuilders) {
            o->opt[o->nbuilders] = opt;
            o->builders[o->nbuilders++] = b;
        }
    }
    return 0;
}

static int parse_embree(const char *list, options *o) {
    char buf[64], *tok, *save = NULL;
    int i;
    o->nqualities = 0;
    if (strlen(list) >= sizeof buf) return 1;
    if (!strcmp(list, "none")) return 0;
    if (!strcmp(list, "all")) list = "low,medium,high";
    strcpy(buf, list);
    for (tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
        emb_quality q;
        if (emb_quality_from_name(tok, &q) != 0) return 1;
        for (i = 0; i < o->nqualities && o->qualities[i] != q; i++) {
        }
        if (i == o->nqualities) o->qualities[o->nqualities++] = q;
    }
    return 0;
}

/* 0: run; 1: --help printed; 2: bad command line (message printed) */
static int parse_args(int argc, char **argv, options *o) {
    int i;
    memset(o, 0, sizeof *o);
    o->argv0 = argv[0];
    parse_builders("all", o);
    parse_embree("all", o);
    o->repeat = 5;
    o->instances = 10000;
    o->trace_width = 8;
    o->width = o->height = 1024;
    o->brute_max = 20000;
    o->trace_auto = 1;
    for (i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int takes = a[0] == '-' && a[1] == '-' && strcmp(a, "--quiet") && strcmp(a, "--strict") &&
                    strcmp(a, "--help") && strcmp(a, "--save-load") && strcmp(a, "--layout-cost");
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
            usage(stdout);
            return 1;
        }
        if (takes && !v) {
            fprintf(stderr, "bvhbench: %s needs a value (see --help)\n", a);
            return 2;
        }
        if (!strcmp(a, "--quiet"))
            o->quiet = 1;
        else if (!strcmp(a, "--save-load"))
            o->save_load = 1;
        else if (!strcmp(a, "--layout-cost"))
            o->layout_cost = 1;
        else if (!strcmp(a, "--strict"))
            o->strict = 1;
        else if (!strcmp(a, "--builder")) {
            if (parse_builders(v, o)) {
                fprintf(stderr,
                        "bvhbench: --builder wants all or a comma list of none, top-down, bottom-up, "
                        "sah-midpoint, ploc, ploc-parallel (each may end in +opt), not '%s'\n",
                        v);
                return 2;
            }
        } else if (!strcmp(a, "--embree")) {
            if (parse_embree(v, o)) {
                fprintf(stderr, "bvhbench: --embree wants all, none or a comma list of low, medium, high, not '%s'\n",
                        v);
                return 2;
            }
        } else if (!strcmp(a, "--embree-flags")) {
            if (strcmp(v, "default") && strcmp(v, "robust")) {
                fprintf(stderr, "bvhbench: --embree-flags wants default or robust, not '%s'\n", v);
                return 2;
            }
            o->embree_robust = !strcmp(v, "robust");
        } else if (!strcmp(a, "--threads")) {
            if (scene_parse_u32(v, 0, 256, &o->threads, NULL)) {
                fprintf(stderr, "bvhbench: --threads wants 0 (all cores) to 256, not '%s'\n", v);
                return 2;
            }
        } else if (!strcmp(a, "--ploc-top")) {
            if (parse_count_or_off(v, BVH_OFF, &o->ploc_top)) {
                fprintf(stderr, "bvhbench: --ploc-top wants a divisor (0 = default) or off, not '%s'\n", v ? v : "");
                return 2;
            }
        } else if (!strcmp(a, "--instances")) {
            if (scene_parse_u32(v, 0, 1u << 24, &o->instances, NULL)) {
                fprintf(stderr, "bvhbench: --instances wants 0 (none) to 16777216, not '%s'\n", v ? v : "");
                return 2;
            }
        } else if (!strcmp(a, "--paired")) {
            if (scene_parse_u32(v, 0, BENCH_MAX_PAIRED, &o->paired, NULL)) {
                fprintf(stderr, "bvhbench: --paired wants 0 to %u rounds, not '%s'\n", BENCH_MAX_PAIRED, v ? v : "");
                return 2;
            }
        } else if (!strcmp(a, "--refit")) {
            if (scene_parse_u32(v, 0, BENCH_MAX_REPEAT, &o->refit, NULL)) {
                fprintf(stderr, "bvhbench: --refit wants 0 to %d frames, not '%s'\n", BENCH_MAX_REPEAT, v);
                return 2;
            }
        } else if (!strcmp(a, "--max-bytes")) {
            if (parse_count_or_off(v, BVH_OFF, &o->max_bytes)) {
                fprintf(stderr, "bvhbench: --max-bytes wants bytes per triangle (0 = default) or off, not '%s'\n",
                        v ? v : "");
                return 2;
            }
        } else if (!strcmp(a, "--camera")) {
            if (!v || (strcmp(v, "outside") && strcmp(v, "inside"))) {
                fprintf(stderr, "bvhbench: --camera wants outside or inside, not '%s'\n", v ? v : "");
                return 2;
            }
            o->inside = !strcmp(v, "inside");
        } else if (!strcmp(a, "--trace-width")) {
            if (scene_parse_u32(v, 2, 8, &o->trace_width, NULL) || (o->trace_width != 2 && o->trace_width != 8)) {
                fprintf(stderr, "bvhbench: --trace-width wants 2 or 8, not '%s'\n", v);
                return 2;
            }
        } else if (!strcmp(a, "--repeat")) {
            if (scene_parse_u32(v, 1, BENCH_MAX_REPEAT, &o->repeat, NULL)) {
                fprintf(stderr, "bvhbench: --repeat wants 1 to %d, not '%s'\n", BENCH_MAX_REPEAT, v);
                return 2;
            }
        } else if (!strcmp(a, "--brute-max")) {
            if (scene_parse_u32(v, 0, 0xFFFFFFFFu, &o->brute_max, NULL)) {
                fprintf(stderr, "bvhbench: --brute-max wants a triangle count, not '%s'\n", v);
                return 2;
            }
        } else if (!strcmp(a, "--size")) {
            if (scene_parse_size(v, BENCH_MAX_PIXELS, &o->width, &o->height)) {
                fprintf(stderr,
                        "bvhbench: --size wants WxH (e.g. 1024x1024, at most 16384 a side and %u pixels), "
                        "not '%s'\n",
                        BENCH_MAX_PIXELS, v);
                return 2;
            }
        } else if (!strcmp(a, "--trace")) {
            o->trace_auto = 0;
            o->trace_cpu = !strcmp(v, "cpu") || !strcmp(v, "both");
            o->trace_cl = !strcmp(v, "opencl") || !strcmp(v, "both");
            if (!o->trace_cpu && !o->trace_cl && strcmp(v, "none")) {
                fprintf(stderr, "bvhbench: --trace wants cpu, opencl, both or none, not '%s'\n", v);
                return 2;
            }
        } else if (!strcmp(a, "--md"))
            o->md = v;
        else if (!strcmp(a, "--json"))
            o->json = v;
        else if (!strcmp(a, "--plots"))
            o->plots = v;
        else if (a[0] == '-' && a[1]) {
            fprintf(stderr, "bvhbench: unknown option '%s' (see --help)\n", a);
            return 2;
        } else if (o->nscenes == BENCH_MAX_SCENES) {
            fprintf(stderr, "bvhbench: at most %d scenes\n", BENCH_MAX_SCENES);
            return 2;
        } else
            o->scenes[o->nscenes++] = a;
        if (takes) i++;
    }
    if (!o->brute && !o->nbuilders && !o->nqualities) {
        fprintf(stderr, "bvhbench: nothing to run (no builder and --embree none)\n");
        return 2;
    }
    o->nthreads = o->threads ? o->threads : scene_cpu_count();
    return 0;
}

/* The study's four sizes; the bunny and the fields need glmark2-data's bunny. */
static void default_scenes(options *o) {
    int bunny = access(BENCH_BUNNY, R_OK) == 0;
    o->nscenes = 0;
    o->scenes[o->nscenes++] = "gen:random:500";
    o->scenes[o->nscenes++] = bunny ? BENCH_BUNNY : "gen:random:100000";
    o->scenes[o->nscenes++] = bunny ? "gen:field:15" : "gen:procedural:1044992";
    o->scenes[o->nscenes++] = bunny ? "gen:field:44" : "gen:procedural:3065306";
    if (!bunny)
        say("the Stanford bunny %s is missing (Debian glmark2-data): using gen:random:100000 and procedural "
            "scenes of 1M and 3M triangles instead",
            BENCH_BUNNY);
}

/* ============================================================================================ */
/* == main ======================================================================================== */
/* ============================================================================================ */
/* The top lines, and OpenCL: opened when asked (or by default, when it works). 0 on success. */
static int setup(options *o, header_info *h, bench_cl *store, bench_cl **cl) {
    time_t now = time(NULL);
    char msg[600];
    memset(h, 0, sizeof *h);
    strftime(h->date, sizeof h->date, "%Y-%m-%d %H:%M:%S %Z", localtime(&now));
    cpu_model(h->cpu, sizeof h->cpu);
    if (!emb_available())
        snprintf(h->embree, sizeof h->embree,
                 "not available (built without BVH_HAVE_EMBREE: install libembree-dev "
                 "and rebuild); no Embree rows");
    else if (!o->nqualities)
        snprintf(h->embree, sizeof h->embree, "%s, not run (--embree none)", emb_version());
    else
        snprintf(h->embree, sizeof h->embree, "%s, scene flags: %s; ratio columns: ours / embree-medium", emb_version(),
                 embree_flags_text(o));
    if (o->trace_auto) o->trace_cpu = o->trace_cl = 1;
    *cl = NULL;
    if (!o->trace_cl)
        snprintf(h->opencl, sizeof h->opencl, "not used (--trace)");
    else if (bcl_open(store, msg, sizeof msg) == 0) {
        *cl = store;
        snprintf(h->opencl, sizeof h->opencl, "%s", store->device);
    } else if (o->trace_auto) {
        o->trace_cl = 0;
        snprintf(h->opencl, sizeof h->opencl, "not used: %.380s", msg);
    } else {
        say("--trace needs OpenCL: %s", msg);
        return 1;
    }
    snprintf(h->trace, sizeof h->trace, "%s",
             o->trace_cpu && o->trace_cl ? "on the CPU and with OpenCL"
             : o->trace_cpu              ? "on the CPU"
             : o->trace_cl               ? "with OpenCL"
                                         : "not (--trace none)");
    return 0;
}

/* Loads scene `spec` and runs every row on it into *bs. 0 ok, 1 failed (message printed). */
static int bench_one(const options *o, const char *spec, int index, bench_cl *cl, bench_scene *bs) {
    scene s;
    char err[512];
    int failed;
    memset(bs, 0, sizeof *bs);
    progress("loading %s (scene %d of %d)", spec, index + 1, o->nscenes);
    if (scene_load(spec, &s, err, sizeof err) != 0) {
        say("%s", err);
        return 1;
    }
    if (s.triangles > 0x55555555u) { /* vertex_count = 3 * triangles must fit 32 bits */
        say("%s has too many triangles (%u)", s.name, s.triangles);
        scene_free(&s);
        return 1;
    }
    snprintf(bs->name, sizeof bs->name, "%s", s.name);
    bs->triangles = s.triangles;
    failed = run_scene(o, &s, cl, bs);
    scene_free(&s);
    return failed;
}

int main(int argc, char **argv) {
    static bench_scene scenes[BENCH_MAX_SCENES];
    options o;
    header_info h;
    bench_cl cl_store, *cl = NULL;
    FILE *table = stdout, *json = NULL;
    double t_start = scene_now_ms();
    int rc = parse_args(argc, argv, &o), i, failed = 0, disagree = 0, done = 0;
    if (rc) return rc == 1 ? 0 : 2;
    memset(&cl_store, 0, sizeof cl_store);
    g_quiet = o.quiet;
    if (!o.nscenes) default_scenes(&o);
    if (setup(&o, &h, &cl_store, &cl)) return 1;
    if (o.json && !strcmp(o.json, "-")) {
        json = stdout;
        table = stderr;
    } else if (o.json && !(json = create_file(o.json))) {
        say("cannot write %s: %s", o.json, strerror(errno));
        bcl_close(&cl_store);
        return 1;
    }
    header_lines(table, &o, &h, "");
    fflush(table);

    for (i = 0; i < o.nscenes; i++) {
        bench_scene *bs = &scenes[done];
        failed |= bench_one(&o, o.scenes[i], i, cl, bs);
        if (!bs->nrows) continue;
        disagree |= bs->disagree;
        done++;
        print_block(table, &o, bs);
        fflush(table);
        if (json) json_rows(json, &o, bs);
        /* the files are rewritten after every scene, so that a long run leaves partial results */
        if (o.md) failed |= write_md(o.md, &o, &h, scenes, done);
        if (o.plots) failed |= write_plot_data(o.plots, &o, scenes, done);
    }
    if (json && json != stdout && fclose(json) != 0) {
        say("cannot write %s", o.json);
        failed = 1;
    }
    if (o.plots && done) failed |= run_plot_script(o.argv0, o.plots);
    bcl_close(&cl_store);
    progress_end();
    fprintf(table, "\ntotal %.1f s", (scene_now_ms() - t_start) / 1000.0);
    if (o.md) fprintf(table, "; Markdown: %s", o.md);
    if (o.json && json != stdout) fprintf(table, "; JSON: %s", o.json);
    if (o.plots) fprintf(table, "; plots: %s", o.plots);
    fputc('\n', table);
    if (disagree) {
        say("!!! HITS DISAGREE (see the rows marked (!) above) !!!");
        return 3;
    }
    return failed ? 1 : 0;
}
