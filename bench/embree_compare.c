/* embree_compare - Embree 3 figures for a scene, one JSON line per build quality:
       build time (scene API, rtcNewScene .. rtcCommitScene), SAH of Embree's binary BVH built with
       rtcBuildBVH at the same quality (costs 1, 0, 1: comparable with bvh_sah), hits and t_sum of
       one frame of the standard camera (the rays of bvh_camera_ray), Mrays/s on 1 and N threads.

   usage: embree_compare [--quality low|medium|high|all] [--threads N] [--repeat R] [--size WxH]
                         [--trace-threads T] [--max-leaf L] [--robust] FILE.tri|FILE(assimp)
     --threads N        Embree build threads (0 = all hardware threads, the default)
     --trace-threads T  threads of the multi-threaded frame (default: N, or online CPUs if N = 0)
     --repeat R         timed builds after one warm-up (default 5); median, min and max are given
     --size WxH         frame (default 1024x1024); 0x0: no frame
     --max-leaf L       maxLeafSize of rtcBuildBVH (default 8, at most 32)
     --robust           RTC_SCENE_FLAG_ROBUST for the traced scene

   Keys: scene, triangles, builder ("embree-low"...), threads, build_ms, build_ms_min,
   build_ms_max, sah, nodes, leaves, hits, t_sum, mrays (1 thread), mrays_mt, then commit_ms
   (rtcCommitScene alone), bvh_build_ms (rtcBuildBVH), refs, spatial_splits, trace_threads,
   mt_identical. Exit status: 0 ok, 1 error, 2 usage, 3 Embree not installed. */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define EMB_IMPLEMENTATION
#include "embree_side.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#ifdef BVH_HAVE_ASSIMP
#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#endif

/* ---- scene loading -------------------------------------------------------------------------- */
/* The one place that reads a file: a raw .tri soup ("TRI1", uint32 count, count * 9 float32) or,
   with BVH_HAVE_ASSIMP, anything assimp reads (triangulated, node transforms applied). Returns a
   malloc'ed soup of 9 floats per triangle, or NULL with a reason in err.
   TODO(lead): switch to examples/scene.h's scene_load once it lands. */
static float *load_triangles(const char *path, uint32_t *n, char *err, size_t errsize) {
    size_t len = strlen(path);
    *n = 0;
    if (len > 4 && !strcmp(path + len - 4, ".tri")) {
        FILE *f = fopen(path, "rb");
        char magic[4];
        uint32_t count;
        float *v;
        if (!f) { snprintf(err, errsize, "%s: %s", path, strerror(errno)); return NULL; }
        if (fread(magic, 1, 4, f) != 4 || memcmp(magic, "TRI1", 4) || fread(&count, 4, 1, f) != 1 ||
            count > UINT32_MAX / 3) {
            fclose(f);
            snprintf(err, errsize, "%s: not a TRI1 file", path);
            return NULL;
        }
        v = (float *)malloc((size_t)count * 9 * sizeof(float) + 1);
        if (!v) { fclose(f); snprintf(err, errsize, "out of memory"); return NULL; }
        if (fread(v, sizeof(float), (size_t)count * 9, f) != (size_t)count * 9) {
            fclose(f); free(v);
            snprintf(err, errsize, "%s: truncated (%u triangles announced)", path, count);
            return NULL;
        }
        fclose(f);
        *n = count;
        return v;
    }
#ifdef BVH_HAVE_ASSIMP
    {
        const struct aiScene *sc = aiImportFile(path, aiProcess_Triangulate | aiProcess_PreTransformVertices);
        size_t nt = 0, k = 0;
        unsigned m, f;
        float *t;
        if (!sc) { snprintf(err, errsize, "assimp: %s", aiGetErrorString()); return NULL; }
        for (m = 0; m < sc->mNumMeshes; m++)
            for (f = 0; f < sc->mMeshes[m]->mNumFaces; f++) nt += sc->mMeshes[m]->mFaces[f].mNumIndices == 3;
        if (nt > UINT32_MAX / 3) { aiReleaseImport(sc); snprintf(err, errsize, "too many triangles"); return NULL; }
        t = (float *)malloc(nt * 9 * sizeof(float) + 1);
        if (!t) { aiReleaseImport(sc); snprintf(err, errsize, "out of memory"); return NULL; }
        for (m = 0; m < sc->mNumMeshes; m++) {
            const struct aiMesh *me = sc->mMeshes[m];
            for (f = 0; f < me->mNumFaces; f++) {
                int c;
                if (me->mFaces[f].mNumIndices != 3) continue; /* points and lines */
                for (c = 0; c < 3; c++) {
                    const struct aiVector3D *p = &me->mVertices[me->mFaces[f].mIndices[c]];
                    t[k * 9 + c * 3] = p->x; t[k * 9 + c * 3 + 1] = p->y; t[k * 9 + c * 3 + 2] = p->z;
                }
                k++;
            }
        }
        aiReleaseImport(sc);
        *n = (uint32_t)nt;
        return t;
    }
#else
    snprintf(err, errsize, "%s: only .tri files can be read (built without assimp)", path);
    return NULL;
#endif
}

/* ---- output --------------------------------------------------------------------------------- */
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

static int usage(void) {
    fprintf(stderr, "usage: embree_compare [--quality low|medium|high|all] [--threads N] [--repeat R]\n"
                    "                      [--size WxH] [--trace-threads T] [--max-leaf L] [--robust]\n"
                    "                      FILE.tri|FILE(assimp)\n");
    return 2;
}
static int parse_u32(const char *s, uint32_t *out) {
    char *end;
    unsigned long x;
    if (!s || !*s || *s == '-') return -1;
    errno = 0;
    x = strtoul(s, &end, 10);
    if (errno || *end || x > UINT32_MAX) return -1;
    *out = (uint32_t)x;
    return 0;
}

int main(int argc, char **argv) {
    const char *path = NULL, *qarg = "all";
    uint32_t threads = 0, repeat = 5, w = 1024, h = 1024, trace_threads = 0, max_leaf = 8, n;
    int robust = 0, qi, nq = 0, status = 0;
    emb_quality qs[3];
    char err[256];
    float *v;

    for (qi = 1; qi < argc; qi++) {
        const char *a = argv[qi], *next = qi + 1 < argc ? argv[qi + 1] : NULL;
        if (!strcmp(a, "--quality") && next) { qarg = next; qi++; }
        else if (!strcmp(a, "--threads") && next) { if (parse_u32(next, &threads)) return usage(); qi++; }
        else if (!strcmp(a, "--trace-threads") && next) {
            if (parse_u32(next, &trace_threads) || !trace_threads) return usage();
            qi++;
        }
        else if (!strcmp(a, "--repeat") && next) { if (parse_u32(next, &repeat) || !repeat) return usage(); qi++; }
        else if (!strcmp(a, "--max-leaf") && next) {
            if (parse_u32(next, &max_leaf) || !max_leaf || max_leaf > 32) return usage();
            qi++;
        }
        else if (!strcmp(a, "--size") && next) {
            char *x;
            unsigned long ww, hh;
            errno = 0;
            ww = strtoul(next, &x, 10);
            if (errno || (*x != 'x' && *x != 'X')) return usage();
            hh = strtoul(x + 1, &x, 10);
            if (errno || *x || ww > 65536 || hh > 65536 || (!ww) != (!hh)) return usage();
            w = (uint32_t)ww; h = (uint32_t)hh;
            qi++;
        }
        else if (!strcmp(a, "--robust")) robust = 1;
        else if (a[0] == '-' && a[1]) return usage();
        else if (!path) path = a;
        else return usage();
    }
    if (!path) return usage();
    if (!strcmp(qarg, "all")) { qs[0] = EMB_QUALITY_LOW; qs[1] = EMB_QUALITY_MEDIUM; qs[2] = EMB_QUALITY_HIGH; nq = 3; }
    else if (!emb_quality_from_name(qarg, &qs[0])) nq = 1;
    else return usage();
    if (!emb_available()) { fprintf(stderr, "embree_compare: Embree not installed\n"); return 3; }

    v = load_triangles(path, &n, err, sizeof err);
    if (!v) { fprintf(stderr, "embree_compare: %s\n", err); return 1; }
    if (!trace_threads) trace_threads = threads; /* 0 = online CPUs, resolved by emb_scene_bench */

    for (qi = 0; qi < nq; qi++) {
        emb_scene_desc sd;
        emb_sah_desc hd;
        emb_scene_result sr;
        emb_sah_result hr;
        int s1, s2;
        memset(&sd, 0, sizeof sd);
        sd.quality = qs[qi]; sd.threads = threads; sd.repeat = repeat;
        sd.width = w; sd.height = h; sd.trace_threads = trace_threads; sd.robust = robust;
        memset(&hd, 0, sizeof hd);
        hd.quality = qs[qi]; hd.threads = threads; hd.repeat = repeat; hd.max_leaf = max_leaf;
        s1 = emb_scene_bench(v, n, &sd, &sr);
        if (s1 != EMB_OK) fprintf(stderr, "embree_compare: %s: scene API: %s\n", emb_quality_name(qs[qi]), sr.message);
        s2 = emb_bvh_sah(v, n, &hd, &hr);
        if (s2 != EMB_OK) fprintf(stderr, "embree_compare: %s: rtcBuildBVH: %s\n", emb_quality_name(qs[qi]), hr.message);
        if (s1 != EMB_OK || s2 != EMB_OK) { status = 1; continue; }
        if (w && !sr.mt_identical) fprintf(stderr, "embree_compare: %s: the %u-thread frame differs from the 1-thread frame\n",
                                      emb_quality_name(qs[qi]), sr.trace_threads);
        printf("{\"scene\":");
        json_string(path);
        printf(",\"triangles\":%u,\"builder\":\"embree-%s\",\"threads\":%u", n, emb_quality_name(qs[qi]), threads);
        printf(",\"build_ms\":%.3f,\"build_ms_min\":%.3f,\"build_ms_max\":%.3f", sr.build.ms, sr.build.min_ms, sr.build.max_ms);
        printf(",\"sah\":%.4f,\"nodes\":%u,\"leaves\":%u", hr.sah, hr.nodes, hr.leaves);
        printf(",\"hits\":%llu,\"t_sum\":%.17g", (unsigned long long)sr.hits, sr.t_sum);
        printf(",\"mrays\":%.3f,\"mrays_mt\":%.3f", sr.mrays, sr.mrays_mt);
        printf(",\"commit_ms\":%.3f,\"bvh_build_ms\":%.3f,\"refs\":%u,\"spatial_splits\":%d", sr.commit.ms, hr.build.ms,
               hr.refs, hr.spatial_splits);
        printf(",\"width\":%u,\"height\":%u,\"trace_threads\":%u,\"mt_identical\":%s,\"robust\":%s,\"embree\":\"%s\"}\n",
               w, h, sr.trace_threads, sr.mt_identical ? "true" : "false", robust ? "true" : "false", emb_version());
        fflush(stdout);
    }
    free(v);
    return status;
}
