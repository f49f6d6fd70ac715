/* minimal.c - the example of bvh.h's manual as a whole program: two triangles, one ray.

   Build and run (from the repository root; `make test` does both and checks the output):
       cc -std=c11 -O2 -I. examples/minimal.c -o build/minimal -lm -lpthread
       build/minimal
   Prints "hit triangle 0 at t=1 (u=0.2 v=0.2)". The body of main is the manual's EXAMPLE line for
   line (bvh.h, top of the file): keep the two the same. */
#define BVH_IMPLEMENTATION
#include "bvh.h"

#include <stdio.h>

/* main keeps the manual's layout (tests/examples.sh compares the two) */
/* clang-format off */
int main(void) {
    float v[] = { 0,0,0,  1,0,0,  0,1,0,    0,0,1,  1,0,1,  0,1,1 };  // two triangles
    bvh_build_desc desc = {0};                   // zero = sensible defaults
    desc.builder = BVH_BUILDER_PLOC;             // or TOP_DOWN, BOTTOM_UP, SAH_MIDPOINT...
    desc.triangles.positions = v;                // stride 0 = tightly packed xyz floats
    desc.triangles.vertex_count = 6;
    desc.triangles.triangle_count = 2;           // indices NULL = 3 vertices per triangle
    bvh_tree tree;
    bvh_result r = bvh_build(&tree, &desc);
    if (r != BVH_SUCCESS) { printf("%s\n", bvh_result_string(r)); return 1; }
    bvh_ray ray = { {0.2f, 0.2f, -1}, 0.0f, {0, 0, 1}, BVH_INF };
    bvh_hit hit;
    if (bvh_intersect(&tree, &ray, &hit))
        printf("hit triangle %u at t=%g (u=%g v=%g)\n", hit.prim, hit.t, hit.u, hit.v);
    bvh_free(&tree);
    return 0;
}
/* clang-format on */
