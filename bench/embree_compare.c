/* embree_compare - Embree 3 figures for a scene, one JSON line per build quality:
       build time (scene API, rtcNewScene .. rtcCommitScene), SAH of Embree's binary BVH built with
       rtcBuildBVH at the same quality (costs 1, 0, 1: comparable with bvh_sah), hits and t_sum of
       one frame of the standard camera (the rays of bvh_camera_ray), Mrays/s on 1 and N threads.

   usage: embree_compare [--quality low|medium|high|all] [--threads N] [--repeat R] [--size WxH]
                         [--trace-threads T] [--max-leaf L] [--robust] SCENE
     SCENE              a file or a generator, as build/render takes them (examples/scene.h):
                        FILE.tri (a raw soup), any file assimp reads, gen:random:N ...
     --threads N        Embree build threads (0 = all hardware threads, the default)
     --trace-threads T  threads of the multi-threaded frame (default: N, or online CPUs if N = 0)
     --repeat R         timed builds after one warm-up (default 5); median, min and max are given
     --size WxH         frame (default 1024x1024, at most 16384 a side); 0x0: no frame
     --max-leaf L       maxLeafSize of rtcBuildBVH (default 8, at most 32)
     --robust           RTC_SCENE_FLAG_ROBUST on every scene (timed and traced); without it the
                        scenes have no flags, Embree's default (as bvhbench --embree-flags default)

   Keys: scene, triangles, builder ("embree-low"...), threads, build_ms, build_ms_min,
   build_ms_max, sah, nodes, leaves, hits, t_sum, mrays (1 thread), mrays_mt, then commit_ms
   (rtcCommitScene alone), bvh_build_ms (rtcBuildBVH), refs, spatial_splits, trace_threads,
   mt_identical, width, height, robust (true: RTC_SCENE_FLAG_ROBUST), embree (its version).
   Exit status: 0 ok, 1 error, 2 usage, 3 Embree not installed. */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define SCENE_IMPLEMENTATION
#include "examples/scene.h"
#define EMB_IMPLEMENTATION
#include "embree_side.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int usage(void) {
    fprintf(stderr,
            "usage: embree_compare [--quality low|medium|high|all] [--threads N] [--repeat R]\n"
            "                      [--size WxH] [--trace-threads T] [--max-leaf L] [--robust]\n"
            "                      SCENE\n%s",
            scene_spec_help());
    return 2;
}

int main(int argc, char **argv) {
    const char *path = NULL, *qarg = "all";
    uint32_t threads = 0, repeat = 5, w = 1024, h = 1024, trace_threads = 0, max_leaf = 8, n;
    int robust = 0, qi, nq = 0, status = 0;
    emb_quality qs[3];
    char err[256];
    scene s;

    for (qi = 1; qi < argc; qi++) {
        const char *a = argv[qi], *next = qi + 1 < argc ? argv[qi + 1] : NULL;
        if (!strcmp(a, "--quality") && next) {
            qarg = next;
            qi++;
        } else if (!strcmp(a, "--threads") && next) {
            if (scene_parse_u32(next, 0, UINT32_MAX, &threads, NULL)) return usage();
            qi++;
        } else if (!strcmp(a, "--trace-threads") && next) {
            if (scene_parse_u32(next, 1, UINT32_MAX, &trace_threads, NULL)) return usage();
            qi++;
        } else if (!strcmp(a, "--repeat") && next) {
            if (scene_parse_u32(next, 1, UINT32_MAX, &repeat, NULL)) return usage();
            qi++;
        } else if (!strcmp(a, "--max-leaf") && next) {
            if (scene_parse_u32(next, 1, 32, &max_leaf, NULL)) return usage();
            qi++;
        } else if (!strcmp(a, "--size") && next) {
            if (!strcmp(next, "0x0"))
                w = h = 0;
            else if (scene_parse_size(next, (uint64_t)16384 * 16384, &w, &h))
                return usage();
            qi++;
        } else if (!strcmp(a, "--robust"))
            robust = 1;
        else if (a[0] == '-' && a[1])
            return usage();
        else if (!path)
            path = a;
        else
            return usage();
    }
    if (!path) return usage();
    if (!strcmp(qarg, "all")) {
        qs[0] = EMB_QUALITY_LOW;
        qs[1] = EMB_QUALITY_MEDIUM;
        qs[2] = EMB_QUALITY_HIGH;
        nq = 3;
    } else if (!emb_quality_from_name(qarg, &qs[0]))
        nq = 1;
    else
        return usage();
    if (!emb_available()) {
        fprintf(stderr, "embree_compare: Embree not installed\n");
        return 3;
    }

    if (scene_load(path, &s, err, sizeof err)) {
        fprintf(stderr, "embree_compare: %s\n", err);
        return 1;
    }
    n = s.triangles;
    if (!trace_threads) trace_threads = threads; /* 0 = online CPUs, resolved by emb_scene_bench */

    for (qi = 0; qi < nq; qi++) {
        emb_scene_desc sd;
        emb_sah_desc hd;
        emb_scene_result sr;
        emb_sah_result hr;
        int s1, s2;
        memset(&sd, 0, sizeof sd);
        sd.quality = qs[qi];
        sd.threads = threads;
        sd.repeat = repeat;
        sd.width = w;
        sd.height = h;
        sd.trace_threads = trace_threads;
        sd.robust = robust;
        memset(&hd, 0, sizeof hd);
        hd.quality = qs[qi];
        hd.threads = threads;
        hd.repeat = repeat;
        hd.max_leaf = max_leaf;
        s1 = emb_scene_bench(s.v, n, &sd, &sr);
        if (s1 != EMB_OK) fprintf(stderr, "embree_compare: %s: scene API: %s\n", emb_quality_name(qs[qi]), sr.message);
        s2 = emb_bvh_sah(s.v, n, &hd, &hr);
        if (s2 != EMB_OK)
            fprintf(stderr, "embree_compare: %s: rtcBuildBVH: %s\n", emb_quality_name(qs[qi]), hr.message);
        if (s1 != EMB_OK || s2 != EMB_OK) {
            status = 1;
            continue;
        }
        if (w && !sr.mt_identical)
            fprintf(stderr, "embree_compare: %s: the %u-thread frame differs from the 1-thread frame\n",
                    emb_quality_name(qs[qi]), sr.trace_threads);
        printf("{\"scene\":");
        scene_json_string(stdout, path);
        printf(",\"triangles\":%u,\"builder\":\"embree-%s\",\"threads\":%u", n, emb_quality_name(qs[qi]), threads);
        printf(",\"build_ms\":%.3f,\"build_ms_min\":%.3f,\"build_ms_max\":%.3f", sr.build.ms, sr.build.min_ms,
               sr.build.max_ms);
        printf(",\"sah\":%.4f,\"nodes\":%u,\"leaves\":%u", hr.sah, hr.nodes, hr.leaves);
        printf(",\"hits\":%llu,\"t_sum\":%.17g", (unsigned long long)sr.hits, sr.t_sum);
        printf(",\"mrays\":%.3f,\"mrays_mt\":%.3f", sr.mrays, sr.mrays_mt);
        printf(",\"commit_ms\":%.3f,\"bvh_build_ms\":%.3f,\"refs\":%u,\"spatial_splits\":%d", sr.commit.ms, hr.build.ms,
               hr.refs, hr.spatial_splits);
        printf(
            ",\"width\":%u,\"height\":%u,\"trace_threads\":%u,\"mt_identical\":%s,\"robust\":%s,\"embree\":\"%s\"}\n",
            w, h, sr.trace_threads, sr.mt_identical ? "true" : "false", robust ? "true" : "false", emb_version());
        fflush(stdout);
    }
    scene_free(&s);
    return status;
}
