/* cl_info.c - lists the OpenCL devices and traces a small scene on one, checked against the CPU.

   build/cl_info            (run from the repository root: the kernel is read from cl/trace.cl)
   BVH_CL_DEVICE=1:0 build/cl_info     picks platform 1, device 0

   Prints every platform/device with its limits; then builds a BVH over a wavy grid of 2 x 64 x 64
   triangles, renders a 256 x 256 frame of the standard camera with bvh_cl_render_frame and compares
   every pixel's hit with bvh_intersect. Without OpenCL (built without BVH_HAVE_OPENCL, or no
   device) it says so and traces on the CPU only, which is the fallback every example can use;
   but a device named in $BVH_CL_DEVICE is asked for explicitly, and never falls back.

   Exit status: 0 when the device's hits are the CPU's, or when there is no OpenCL here and
   $BVH_CL_DEVICE is not set; 1 when they differ, when the device $BVH_CL_DEVICE names cannot be
   used, or when a device was found but could not trace (said in one line on stderr). */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define BVH_CL_IMPLEMENTATION
#include "cl/bvh_cl.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define GRID 64
#define SIZE 256

static void list_devices(void) {
    bvh_cl_device_info dev[16];
    uint32_t n = 0, i;
    bvh_cl_result r = bvh_cl_enumerate(dev, 16, &n);
    if (r != BVH_CL_SUCCESS) {
        printf("OpenCL devices: none (%s)\n", bvh_cl_result_string(r));
        return;
    }
    for (i = 0; i < n && i < 16; i++)
        printf("%u:%u  %s / %s\n     %s, %u compute units, max buffer %llu MB, memory %llu MB, %s%s\n",
               dev[i].platform_index, dev[i].device_index, dev[i].platform, dev[i].device, dev[i].version,
               dev[i].compute_units, (unsigned long long)(dev[i].max_alloc >> 20),
               (unsigned long long)(dev[i].global_mem >> 20), dev[i].is_gpu ? "GPU" : "not a GPU",
               dev[i].exact ? ", hits bit-identical to the CPU" : "");
}

/* Whether a failed OpenCL step may fall back to the CPU: only when there is no OpenCL here at all
   and no device was asked for. */
static int may_fall_back(bvh_cl_result r, const char *want) {
    if (want && *want) return 0;
    return r == BVH_CL_ERROR_NOT_AVAILABLE || r == BVH_CL_ERROR_NO_PLATFORM || r == BVH_CL_ERROR_NO_DEVICE;
}

/* a height field z = 0.2 sin(3x) cos(2y) over [0, 1]^2, two triangles per cell */
static float *wavy_grid(uint32_t *count) {
    float *v = (float *)malloc(sizeof(float) * 18 * GRID * GRID);
    uint32_t i, j, k = 0;
    if (!v) return NULL;
    for (j = 0; j < GRID; j++)
        for (i = 0; i < GRID; i++) {
            float x[4] = {(float)i, (float)i + 1, (float)i + 1, (float)i};
            float y[4] = {(float)j, (float)j, (float)j + 1, (float)j + 1};
            static const int tri[6] = {0, 1, 2, 0, 2, 3};
            int c;
            for (c = 0; c < 6; c++, k += 3) {
                v[k] = x[tri[c]] / GRID;
                v[k + 1] = y[tri[c]] / GRID;
                v[k + 2] = 0.2f * sinf(3.0f * v[k]) * cosf(2.0f * v[k + 1]);
            }
        }
    *count = 2 * GRID * GRID;
    return v;
}

int main(void) {
    bvh_build_desc desc;
    bvh_tree tree;
    bvh_cl_context *cl = NULL;
    bvh_cl_tree *gpu = NULL;
    bvh_cl_desc cd;
    bvh_cl_device_info info;
    bvh_camera cam;
    bvh_hit *hits = (bvh_hit *)malloc(sizeof(bvh_hit) * SIZE * SIZE);
    uint8_t *rgba = (uint8_t *)malloc(4 * SIZE * SIZE);
    char log[2048] = "";
    const char *want = getenv("BVH_CL_DEVICE");
    uint32_t n = 0, x, y, same = 0, hit = 0, i;
    int failed = 0;
    float *v = wavy_grid(&n);
    bvh_result br;
    bvh_cl_result r;
    if (!v || !hits || !rgba) return 1;

    list_devices();
    memset(&desc, 0, sizeof desc);
    desc.triangles.positions = v;
    desc.triangles.vertex_count = 3 * n;
    desc.triangles.triangle_count = n;
    br = bvh_build(&tree, &desc);
    if (br != BVH_SUCCESS) {
        printf("build: %s\n", bvh_result_string(br));
        return 1;
    }
    cam = bvh_camera_standard(bvh_tree_bounds(&tree), SIZE, SIZE);

    memset(&cd, 0, sizeof cd);
    cd.log = log;
    cd.log_size = sizeof log;
    r = bvh_cl_create(&cl, &cd);
    if (r == BVH_CL_SUCCESS) r = bvh_cl_upload(cl, &tree, &gpu);
    if (r == BVH_CL_SUCCESS) r = bvh_cl_render_frame(gpu, &cam, rgba, hits, NULL);
    if (r != BVH_CL_SUCCESS && !may_fall_back(r, want)) {
        for (i = 0; log[i]; i++) /* one line, even with a compiler's build log */
            if (log[i] == '\n' || log[i] == '\r') log[i] = ' ';
        fprintf(stderr, "cl_info: %s%s cannot be used: %s%s%s\n", want && *want ? "BVH_CL_DEVICE=" : "OpenCL",
                want && *want ? want : "", bvh_cl_result_string(r), log[0] ? ": " : "", log);
        failed = 1;
    } else if (r != BVH_CL_SUCCESS) {
        printf("OpenCL: %s%s%s\nfalling back to the CPU\n", bvh_cl_result_string(r), log[0] ? "\n" : "", log);
        for (y = 0; y < SIZE; y++)
            for (x = 0; x < SIZE; x++) {
                bvh_ray ray = bvh_camera_ray(&cam, x, y);
                hit += bvh_intersect(&tree, &ray, &hits[y * SIZE + x]);
            }
        printf("CPU: %u of %u pixels hit\n", hit, SIZE * SIZE);
    } else {
        bvh_cl_get_info(cl, &info);
        for (y = 0; y < SIZE; y++)
            for (x = 0; x < SIZE; x++) {
                bvh_ray ray = bvh_camera_ray(&cam, x, y);
                bvh_hit h;
                const bvh_hit *g = &hits[y * SIZE + x];
                hit += bvh_intersect(&tree, &ray, &h);
                same += h.prim == g->prim && (h.prim == BVH_INVALID || fabsf(h.t - g->t) <= 1e-5f * fabsf(h.t));
            }
        printf("traced %ux%u on %s in %.3f ms (kernel): %u pixels hit, %u of %u agree with the CPU\n", SIZE, SIZE,
               info.device, bvh_cl_last_kernel_ms(cl), hit, same, SIZE * SIZE);
    }
    bvh_cl_tree_free(gpu);
    bvh_cl_destroy(cl);
    bvh_free(&tree);
    free(v);
    free(hits);
    free(rgba);
    return failed || (r == BVH_CL_SUCCESS && same != SIZE * SIZE) ? 1 : 0;
}
