/* version.c - one version of bvh.h behind a prefix, for build/abtrace (bench/ab/abtrace.c).

   Compiled twice, each time against another bvh.h (-I to its directory) and with another
   AB_PREFIX: the implementation is BVH_STATIC, so both copies live in one program without a
   clash, and the drivers (abtrace.c; abrefit.c for refit, save and load) reach each through the
   functions below, declared once in ab.h. The two versions must agree on the public structs
   (bvh_tree, bvh_ray, bvh_hit, bvh_build_desc). */
#define BVH_STATIC
#define BVH_IMPLEMENTATION
#include "bvh.h"

#include <stdlib.h>
#include <string.h>

#include "ab.h" /* the prototypes, for both prefixes */

#define AB_FN(name) AB_CAT(AB_PREFIX, name)

int AB_FN(build)(bvh_tree *tree, const bvh_build_desc *desc) { return (int)bvh_build(tree, desc); }
int AB_FN(intersect)(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count) {
    return (int)bvh_intersect_batch(tree, rays, hits, count, 1);
}
int AB_FN(occluded)(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count) {
    return (int)bvh_occluded_batch(tree, rays, occluded, count, 1);
}
void AB_FN(free)(bvh_tree *tree) { bvh_free(tree); }
int AB_FN(version)(void) { return BVH_VERSION_MAJOR * 10000 + BVH_VERSION_MINOR * 100 + BVH_VERSION_PATCH; }
int AB_FN(refit)(bvh_tree *tree, const float *positions, uint32_t triangles, uint32_t threads) {
    bvh_refit_desc d;
    memset(&d, 0, sizeof d);
    d.triangles.positions = positions;
    d.triangles.vertex_count = 3 * triangles;
    d.triangles.triangle_count = triangles;
    d.threads = threads;
    return (int)bvh_refit(tree, &d);
}
typedef struct AB_FN(sink) {
    char *p;
    size_t n;
} AB_FN(sink);
static size_t AB_FN(write)(void *user, const void *data, size_t size) {
    AB_FN(sink) *s = (AB_FN(sink) *)user;
    memcpy(s->p + s->n, data, size);
    s->n += size;
    return size;
}
size_t AB_FN(save)(const bvh_tree *tree, void **bytes) {
    AB_FN(sink) s;
    s.n = 0;
    s.p = (char *)malloc(bvh_save_size(tree));
    *bytes = s.p;
    if (!s.p || bvh_save(tree, AB_FN(write), &s) != BVH_SUCCESS) return 0;
    return s.n;
}
int AB_FN(load)(bvh_tree *tree, const void *bytes, size_t size, uint32_t threads) {
    bvh_load_desc d;
    memset(&d, 0, sizeof d);
    d.data = bytes;
    d.size = size;
    d.threads = threads;
#ifdef AB_BORROW /* both versions loading in place (bvh_load_desc.borrow, 0.9.18 and later) */
    d.borrow = 1;
#endif
    return (int)bvh_load(tree, &d);
}
