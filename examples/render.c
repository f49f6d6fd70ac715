/* render.c - builds a BVH over a scene, checks it, traces one frame and reports the numbers.

   build/render [--builder NAME] [--threads N] [--size WxH] [--out FILE.png|FILE.ppm] [--json]
                [--repeat R] SCENE
   e.g. build/render --out out/bunny.png /usr/share/glmark2/models/bunny.obj
        build/render --json --builder top-down gen:random:100000

   Steps: load (or generate) the scene; build with the chosen builder (median time of R builds);
   validate (a defect is an error); SAH with costs (1, 0, 1) and tree statistics; one frame of
   primary rays from the standard camera (bvh_camera_standard over the tree bounds) traced with
   bvh_intersect_batch; headlight shading; the image and the report.
   Default: ploc-parallel, all cores, 800x600, no image, human-readable report.

   Tracing and shading are separate: a backend fills frame.hits (trace_frame_cpu below) and
   everything after it (hit count, t_sum, shading) reads only that array, so another backend
   (e.g. OpenCL behind a --trace option) only has to fill the same array. */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define SCENE_IMPLEMENTATION
#include "scene.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define RENDER_MAX_PIXELS (64u * 1024u * 1024u)

typedef struct options {
    const char *scene_spec;
    const char *out;        /* image path or NULL */
    bvh_builder builder;
    uint32_t threads;       /* 0 = all online CPUs */
    uint32_t width, height;
    uint32_t repeat;        /* builds timed; the median is reported */
    int json;
} options;

typedef struct frame {
    uint32_t width, height;
    bvh_camera cam;
    bvh_hit *hits; /* width * height, row-major, row 0 at the top */
} frame;

typedef struct report {
    double load_ms, build_ms, sah, trace_ms, t_sum;
    uint64_t hits;
    uint32_t threads;
    bvh_stats stats;
} report;

/* ============================================================================================ */
/* == options =================================================================================== */
/* ============================================================================================ */
static void usage(FILE *f) {
    fprintf(f,
            "usage: render [--builder NAME] [--threads N] [--size WxH] [--out FILE.png|FILE.ppm]\n"
            "              [--json] [--repeat R] SCENE\n"
            "  --builder NAME  top-down, bottom-up, sah-midpoint, ploc, ploc-parallel (default)\n"
            "  --threads N     build (ploc-parallel) and trace threads, 0 = all cores (default 0)\n"
            "  --size WxH      image size in pixels (default 800x600)\n"
            "  --out FILE      write the frame as PNG or binary PPM (by extension)\n"
            "  --json          print one JSON object on one line instead of the report\n"
            "  --repeat R      build R times and report the median build time (default 1)\n"
            "  --help          this text\n"
            "%s"
            "built with: assimp=%s png=%s\n",
            scene_spec_help(), scene_can_use_assimp() ? "yes" : "no (only .obj files load)",
            scene_can_write_png() ? "yes" : "no (use .ppm)");
}

static int parse_u32(const char *s, uint32_t lo, uint32_t hi, uint32_t *out, const char **end) {
    char *e;
    unsigned long long v;
    if (!s || *s < '0' || *s > '9') return 1;
    v = strtoull(s, &e, 10);
    if (v < lo || v > hi || (!end && *e)) return 1;
    if (end) *end = e;
    *out = (uint32_t)v;
    return 0;
}

static int parse_size(const char *s, uint32_t *w, uint32_t *h) {
    const char *e;
    if (parse_u32(s, 1, 16384, w, &e) || (*e != 'x' && *e != 'X')) return 1;
    if (parse_u32(e + 1, 1, 16384, h, NULL)) return 1;
    return (uint64_t)*w * *h > RENDER_MAX_PIXELS;
}

/* 0: run; 1: --help printed; 2: bad command line (message printed) */
static int parse_args(int argc, char **argv, options *o) {
    int i;
    memset(o, 0, sizeof *o);
    o->builder = BVH_BUILDER_PLOC_PARALLEL;
    o->width = 800;
    o->height = 600;
    o->repeat = 1;
    for (i = 1; i < argc; i++) {
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        int takes = strcmp(a, "--builder") == 0 || strcmp(a, "--threads") == 0 || strcmp(a, "--size") == 0 ||
                    strcmp(a, "--out") == 0 || strcmp(a, "--repeat") == 0;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) { usage(stdout); return 1; }
        if (takes && !val) { fprintf(stderr, "render: %s needs a value (see --help)\n", a); return 2; }
        if (strcmp(a, "--json") == 0) o->json = 1;
        else if (strcmp(a, "--builder") == 0) {
            if (bvh_builder_from_name(val, &o->builder) != BVH_SUCCESS || o->builder == BVH_BUILDER_DEFAULT) {
                fprintf(stderr, "render: unknown builder '%s' (top-down, bottom-up, sah-midpoint, ploc, "
                                "ploc-parallel)\n", val);
                return 2;
            }
        } else if (strcmp(a, "--threads") == 0) {
            if (parse_u32(val, 0, 256, &o->threads, NULL)) {
                fprintf(stderr, "render: --threads wants a number from 0 (all cores) to 256, not '%s'\n", val);
                return 2;
            }
        } else if (strcmp(a, "--size") == 0) {
            if (parse_size(val, &o->width, &o->height)) {
                fprintf(stderr, "render: --size wants WxH (e.g. 800x600, at most 16384 a side and %u "
                                "pixels), not '%s'\n", RENDER_MAX_PIXELS, val);
                return 2;
            }
        } else if (strcmp(a, "--repeat") == 0) {
            if (parse_u32(val, 1, 1000, &o->repeat, NULL)) {
                fprintf(stderr, "render: --repeat wants a number from 1 to 1000, not '%s'\n", val);
                return 2;
            }
        } else if (strcmp(a, "--out") == 0) {
            char err[512];
            if (scene_check_image_path(val, err, sizeof err)) { fprintf(stderr, "render: %s\n", err); return 2; }
            o->out = val;
        }
        else if (a[0] == '-' && a[1] != 0) {
            fprintf(stderr, "render: unknown option '%s' (see --help)\n", a);
            return 2;
        } else if (o->scene_spec) {
            fprintf(stderr, "render: one scene only ('%s' and '%s')\n", o->scene_spec, a);
            return 2;
        } else o->scene_spec = a;
        if (takes) i++;
    }
    if (!o->scene_spec) { fprintf(stderr, "render: no SCENE given (see --help)\n"); return 2; }
    return 0;
}

static uint32_t resolve_threads(uint32_t t) {
    long n;
    if (t) return t;
    n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (uint32_t)(n > 256 ? 256 : n) : 1;
}

/* ============================================================================================ */
/* == build and check ============================================================================ */
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
/* == tracing (backends fill frame.hits) ========================================================= */
/* ============================================================================================ */
static int frame_init(frame *f, const bvh_tree *tree, uint32_t width, uint32_t height) {
    f->width = width;
    f->height = height;
    f->cam = bvh_camera_standard(bvh_tree_bounds(tree), width, height);
    f->hits = (bvh_hit *)malloc((size_t)width * height * sizeof(bvh_hit));
    if (!f->hits) { fprintf(stderr, "render: out of memory for a %ux%u frame\n", width, height); return 1; }
    return 0;
}

/* CPU backend: one primary ray per pixel centre, bvh_intersect_batch on `threads` threads.
   Only the batch call is timed (ray generation is not). */
static int trace_frame_cpu(const bvh_tree *tree, frame *f, uint32_t threads, double *ms) {
    size_t n = (size_t)f->width * f->height, i = 0;
    bvh_ray *rays = (bvh_ray *)malloc(n * sizeof(bvh_ray));
    bvh_result res;
    uint32_t x, y;
    double t0;
    if (!rays) { fprintf(stderr, "render: out of memory for %zu rays\n", n); return 1; }
    for (y = 0; y < f->height; y++)
        for (x = 0; x < f->width; x++) rays[i++] = bvh_camera_ray(&f->cam, x, y);
    t0 = scene_now_ms();
    res = bvh_intersect_batch(tree, rays, f->hits, n, threads);
    *ms = scene_now_ms() - t0;
    free(rays);
    if (res != BVH_SUCCESS) { fprintf(stderr, "render: tracing failed: %s\n", bvh_result_string(res)); return 1; }
    return 0;
}

/* Hit count and sum of hit distances, in pixel order (so equal hits give an equal sum). */
static void frame_summary(const frame *f, uint64_t *hits, double *t_sum) {
    size_t i, n = (size_t)f->width * f->height;
    *hits = 0;
    *t_sum = 0.0;
    for (i = 0; i < n; i++)
        if (f->hits[i].prim != BVH_INVALID) { (*hits)++; *t_sum += (double)f->hits[i].t; }
}

/* ============================================================================================ */
/* == shading ==================================================================================== */
/* ============================================================================================ */
static uint8_t to_byte(float c) { /* no gamma: keeps the contrast of a plain headlight */
    c = c <= 0.0f ? 0.0f : c >= 1.0f ? 1.0f : c;
    return (uint8_t)(c * 255.0f + 0.5f);
}

/* Headlight diffuse on light grey: |cos| between the geometric normal of the ORIGINAL triangle
   hit.prim (the scene's own array) and the ray; misses get a blue-grey vertical gradient. */
static void shade_frame(const frame *f, const scene *s, uint8_t *rgb) {
    uint32_t x, y;
    for (y = 0; y < f->height; y++) {
        float g = (float)y / (float)(f->height > 1 ? f->height - 1 : 1);
        for (x = 0; x < f->width; x++) {
            const bvh_hit *h = &f->hits[(size_t)y * f->width + x];
            uint8_t *px = rgb + 3 * ((size_t)y * f->width + x);
            float c[3] = {0.45f - 0.30f * g, 0.55f - 0.35f * g, 0.75f - 0.40f * g};
            if (h->prim != BVH_INVALID) {
                const float *t = s->v + 9 * (size_t)h->prim;
                bvh_ray r = bvh_camera_ray(&f->cam, x, y);
                float e1[3] = {t[3] - t[0], t[4] - t[1], t[5] - t[2]}, e2[3] = {t[6] - t[0], t[7] - t[1], t[8] - t[2]};
                float n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
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
    if (!rgb) { fprintf(stderr, "render: out of memory for the image\n"); return 1; }
    shade_frame(f, s, rgb);
    rc = scene_write_image(path, f->width, f->height, rgb, err, sizeof err);
    free(rgb);
    if (rc) fprintf(stderr, "render: %s\n", err);
    return rc;
}

/* ============================================================================================ */
/* == report ===================================================================================== */
/* ============================================================================================ */
static void json_string(const char *s) {
    putchar('"');
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\') printf("\\%c", c);
        else if (c < 0x20) printf("\\u%04x", c);
        else putchar(c);
    }
    putchar('"');
}

static void print_report(const options *o, const scene *s, const bvh_tree *tree, const report *r) {
    double mrays = r->trace_ms > 0.0 ? (double)o->width * o->height / (r->trace_ms * 1e-3) / 1e6 : 0.0;
    double bpt = s->triangles ? (double)r->stats.bytes / s->triangles : 0.0;
    const char *builder = bvh_builder_name(o->builder);
    if (o->json) {
        printf("{\"scene\":");
        json_string(s->name);
        printf(",\"triangles\":%u,\"skipped\":%u,\"excluded\":%u,\"builder\":\"%s\",\"threads\":%u,\"repeat\":%u,"
               "\"load_ms\":%.3f,\"build_ms\":%.3f,\"valid\":true,\"sah\":%.6f,\"nodes\":%u,\"leaves\":%u,"
               "\"refs\":%u,\"max_depth\":%u,\"max_leaf_size\":%u,\"bvh_bytes\":%zu,\"triangle_bytes\":%zu,"
               "\"bytes_per_tri\":%.3f,\"trace\":\"cpu\",\"width\":%u,\"height\":%u,\"trace_ms\":%.3f,"
               "\"hits\":%llu,\"t_sum\":%.6f,\"mrays\":%.3f,\"image\":",
               s->triangles, s->skipped, tree->excluded, builder, r->threads, o->repeat, r->load_ms, r->build_ms, r->sah,
               r->stats.nodes, r->stats.leaves, r->stats.refs, r->stats.max_depth, r->stats.max_leaf_size,
               r->stats.bytes, r->stats.triangle_bytes, bpt, o->width, o->height, r->trace_ms,
               (unsigned long long)r->hits, r->t_sum, mrays);
        if (o->out) json_string(o->out);
        else printf("null");
        printf("}\n");
        return;
    }
    printf("scene    %s: %u triangles", s->name, s->triangles);
    if (s->skipped) printf(" (%u non-triangle or bad faces dropped)", s->skipped);
    if (tree->excluded) printf(" (%u excluded: NaN/Inf)", tree->excluded);
    printf(", loaded in %.1f ms\n", r->load_ms);
    printf("builder  %s, threads %u\n", builder, r->threads);
    printf("build    %.2f ms (median of %u)\n", r->build_ms, o->repeat);
    printf("tree     valid; %u nodes, %u leaves, %u refs, max depth %u, max leaf %u\n", r->stats.nodes,
           r->stats.leaves, r->stats.refs, r->stats.max_depth, r->stats.max_leaf_size);
    printf("memory   %.2f MB nodes+refs (%.1f bytes/triangle) + %.2f MB triangle copy\n",
           (double)r->stats.bytes / 1048576.0, bpt, (double)r->stats.triangle_bytes / 1048576.0);
    printf("SAH      %.4f (costs 1, 0, 1)\n", r->sah);
    printf("trace    %ux%u primary rays: %llu hits, t_sum %.6f, %.2f ms, %.2f Mrays/s\n", o->width, o->height,
           (unsigned long long)r->hits, r->t_sum, r->trace_ms, mrays);
    if (o->out) printf("image    %s\n", o->out);
}

/* ============================================================================================ */
/* == main ====================================================================================== */
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
    r.threads = resolve_threads(o.threads);
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
    rc = build_tree(&s, &o, &tree, &r.build_ms) || check_tree(&tree, &r) ||
         frame_init(&f, &tree, o.width, o.height) || trace_frame_cpu(&tree, &f, r.threads, &r.trace_ms);
    if (!rc) {
        frame_summary(&f, &r.hits, &r.t_sum);
        if (o.out) rc = write_frame(&f, &s, o.out);
    }
    if (!rc) print_report(&o, &s, &tree, &r);
    free(f.hits);
    bvh_free(&tree);
    scene_free(&s);
    return rc ? 1 : 0;
}
