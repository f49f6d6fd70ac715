/* tests/two_tu_b.c - a translation unit with bvh.h's declarations only, linked with
   two_tu_a.c (which has the implementation). */
#include <stdio.h>

#include "bvh.h"

int two_tu_a_build(bvh_tree *tree);

int main(void) {
    bvh_tree tree;
    bvh_ray ray = {{0.25f, 0.25f, 2}, 0.0f, {0, 0, -1}, BVH_INF};
    bvh_hit hit;
    int ok;
    if (!two_tu_a_build(&tree)) return 1;
    ok = bvh_intersect(&tree, &ray, &hit) && hit.prim == 0 && hit.t == 2.0f;
    printf("two translation units: %s (%s)\n", ok ? "ok" : "wrong hit", bvh_builder_name(tree.builder));
    bvh_free(&tree);
    return ok ? 0 : 1;
}
