/* ab.h - the entry points of one version of bvh.h behind a prefix (bench/ab/version.c defines
   them, compiled once as ab_a_ and once as ab_b_), declared here once for version.c and the
   drivers (abtrace.c, abrefit.c). Include after bvh.h. */
#ifndef AB_H_INCLUDED
#define AB_H_INCLUDED

#define AB_CAT_(a, b) a##b
#define AB_CAT(a, b) AB_CAT_(a, b)

/* clang-format off */
#define AB_DECLARE(P)                                                                                      \
    int AB_CAT(P, build)(bvh_tree *tree, const bvh_build_desc *desc);                                      \
    int AB_CAT(P, intersect)(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count);      \
    int AB_CAT(P, occluded)(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count);   \
    void AB_CAT(P, free)(bvh_tree *tree);                                                                  \
    int AB_CAT(P, version)(void); /* major * 10000 + minor * 100 + patch */                                \
    int AB_CAT(P, refit)(bvh_tree *tree, const float *positions, uint32_t triangles, uint32_t threads);    \
    size_t AB_CAT(P, save)(const bvh_tree *tree, void **bytes); /* malloc'd file bytes; 0: failed */      \
    int AB_CAT(P, load)(bvh_tree *tree, const void *bytes, size_t size, uint32_t threads);
/* clang-format on */

AB_DECLARE(ab_a_)
AB_DECLARE(ab_b_)

#endif
