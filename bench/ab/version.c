/* version.c - one version of bvh.h behind a prefix, for build/abtrace (bench/ab/abtrace.c).

   Compiled twice, each time against another bvh.h (-I to its directory) and with another
   AB_PREFIX: the implementation is BVH_STATIC, so both copies live in one program without a
   clash, and the driver reaches each through the four functions below. The two versions must
   agree on the public structs (bvh_tree, bvh_ray, bvh_hit, bvh_build_desc). */
#define BVH_STATIC
#define BVH_IMPLEMENTATION
#include "bvh.h"

#define AB_CAT_(a, b) a##b
#define AB_CAT(a, b) AB_CAT_(a, b)
#define AB_FN(name) AB_CAT(AB_PREFIX, name)

int AB_FN(build)(bvh_tree *tree, const bvh_build_desc *desc);
int AB_FN(intersect)(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count);
int AB_FN(occluded)(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count);
void AB_FN(free)(bvh_tree *tree);
int AB_FN(version)(void); /* major * 10000 + minor * 100 + patch */

int AB_FN(build)(bvh_tree *tree, const bvh_build_desc *desc) { return (int)bvh_build(tree, desc); }
int AB_FN(intersect)(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count) {
    return (int)bvh_intersect_batch(tree, rays, hits, count, 1);
}
int AB_FN(occluded)(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count) {
    return (int)bvh_occluded_batch(tree, rays, occluded, count, 1);
}
void AB_FN(free)(bvh_tree *tree) { bvh_free(tree); }
int AB_FN(version)(void) { return BVH_VERSION_MAJOR * 10000 + BVH_VERSION_MINOR * 100 + BVH_VERSION_PATCH; }
