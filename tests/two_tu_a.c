/* tests/two_tu_a.c - the translation unit with the implementation. bvh.h is included before
   BVH_IMPLEMENTATION is defined (as another header of the program would), then with it, then
   once more: the implementation must still appear exactly once. Linked with two_tu_b.c (and
   with compile_cpp.cpp built with -DBVH_TEST_DECLARATIONS_ONLY). */
#include "bvh.h"
#define BVH_IMPLEMENTATION
#include "bvh.h"
#include "bvh.h"

/* Used by two_tu_b.c: a tree over one triangle. */
int two_tu_a_build(bvh_tree *tree) {
    static const float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    bvh_build_desc d = {0};
    d.builder = BVH_BUILDER_PLOC;
    d.triangles.positions = v;
    d.triangles.vertex_count = 3;
    d.triangles.triangle_count = 1;
    return bvh_build(tree, &d) == BVH_SUCCESS;
}
