/* consumer.c - a program built against bvh.h as an application does, through pkg-config, CMake's
   find_package or add_subdirectory (tests/install.sh builds it all three ways): a tree of two
   triangles and one ray, traced on the CPU and, when built with BVH_HAVE_OPENCL, with OpenCL
   through the kernel that came with bvh_cl.h (read from where it was installed, not from the
   working directory). Prints "consumer: bvh X.Y.Z: hit triangle 0 at t=1" and a line about
   OpenCL; exits 1 on a wrong answer or an error. */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define BVH_CL_IMPLEMENTATION
#include "cl/bvh_cl.h"

#include <stdio.h>

int main(void) {
    float v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 0, 1, 0, 1, 1};
    bvh_build_desc desc = {0};
    bvh_tree tree;
    bvh_ray ray = {{0.2f, 0.2f, -1}, 0.0f, {0, 0, 1}, BVH_INF};
    bvh_hit hit;
    bvh_cl_context *cl = NULL;
    bvh_cl_tree *gpu = NULL;
    bvh_cl_desc cd = {0};
    bvh_cl_result cr;
    char log[4096] = "";
    desc.triangles.positions = v;
    desc.triangles.vertex_count = 6;
    desc.triangles.triangle_count = 2;
    if (bvh_build(&tree, &desc) != BVH_SUCCESS) return 1;
    if (!bvh_intersect(&tree, &ray, &hit) || hit.prim != 0 || hit.t != 1.0f) {
        printf("consumer: wrong hit: triangle %u at t=%g\n", hit.prim, hit.t);
        return 1;
    }
    printf("consumer: bvh %d.%d.%d: hit triangle %u at t=%g\n", BVH_VERSION_MAJOR, BVH_VERSION_MINOR, BVH_VERSION_PATCH,
           hit.prim, hit.t);
    cd.log = log;
    cd.log_size = sizeof log;
    cr = bvh_cl_create(&cl, &cd);
    if (cr == BVH_CL_ERROR_NOT_AVAILABLE || cr == BVH_CL_ERROR_NO_PLATFORM || cr == BVH_CL_ERROR_NO_DEVICE) {
        printf("consumer: OpenCL not tried (%s)\n", bvh_cl_result_string(cr));
    } else {
        bvh_hit gh;
        if (cr == BVH_CL_SUCCESS) cr = bvh_cl_upload(cl, &tree, &gpu);
        if (cr == BVH_CL_SUCCESS) cr = bvh_cl_intersect(gpu, &ray, &gh, 1);
        if (cr != BVH_CL_SUCCESS) {
            printf("consumer: OpenCL: %s %s\n", bvh_cl_result_string(cr), log);
            return 1;
        }
        if (gh.prim != hit.prim || gh.t != hit.t) {
            printf("consumer: OpenCL hit triangle %u at t=%g, the CPU's is %u at t=%g\n", gh.prim, gh.t, hit.prim,
                   hit.t);
            return 1;
        }
        printf("consumer: OpenCL, the kernel bvh_cl.h holds: the same hit\n");
        bvh_cl_tree_free(gpu);
        bvh_cl_destroy(cl);
    }
    bvh_free(&tree);
    return 0;
}
