/* tests/compile_cpp.cpp - bvh.h from C++11 (g++/clang++ -std=c++11 -Wall -Wextra -Werror).
   Built twice by `make test`: with the implementation compiled as C++ here, and with
   -DBVH_TEST_DECLARATIONS_ONLY against two_tu_a.c compiled as C (extern "C" linkage).
   Builds a tree with every builder and traces a ray; exits non-zero on a wrong answer. */
#ifndef BVH_TEST_DECLARATIONS_ONLY
#define BVH_IMPLEMENTATION
#endif
#include "bvh.h"

#include <cstdio>
#include <vector>

int main() {
    // two triangles, the example of the manual: z = 0 and z = 1
    const float v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 0, 1, 0, 1, 1};
    int failures = 0;
    for (int b = 0; b < BVH_BUILDER_COUNT; b++) {
        bvh_build_desc desc = {};
        desc.builder = static_cast<bvh_builder>(b);
        desc.triangles.positions = v;
        desc.triangles.vertex_count = 6;
        desc.triangles.triangle_count = 2;
        bvh_tree tree;
        bvh_result r = bvh_build(&tree, &desc);
        if (r != BVH_SUCCESS) {
            std::printf("%s: %s\n", bvh_builder_name(desc.builder), bvh_result_string(r));
            failures++;
            continue;
        }
        bvh_ray ray = {{0.2f, 0.2f, -1}, 0.0f, {0, 0, 1}, BVH_INF};
        bvh_hit hit;
        std::vector<bvh_hit> hits(3);
        std::vector<bvh_ray> rays(3, ray);
        rays[1].origin.z = 0.5f; // between the two: hits triangle 1 at t = 0.5
        rays[2].dir.z = -1;      // away from both
        bvh_validation rep;
        if (!bvh_intersect(&tree, &ray, &hit) || hit.prim != 0 || hit.t != 1.0f ||
            bvh_intersect_batch(&tree, rays.data(), hits.data(), rays.size(), 2) != BVH_SUCCESS || hits[0].prim != 0 ||
            hits[1].prim != 1 || hits[1].t != 0.5f || hits[2].prim != BVH_INVALID ||
            bvh_validate(&tree, nullptr, &rep) != BVH_SUCCESS) {
            std::printf("%s: wrong answer (prim %u t %g, %s)\n", bvh_builder_name(desc.builder), hit.prim,
                        static_cast<double>(hit.t), rep.message);
            failures++;
        }
        bvh_free(&tree);
    }
    std::printf("C++: %d builders, %d failures\n", BVH_BUILDER_COUNT, failures);
    return failures ? 1 : 0;
}
