/* tests/compile_static.c - bvh.h with -DBVH_STATIC (every function static, a private copy in this
   translation unit) and with its own BVH_MALLOC / BVH_FREE / BVH_ASSERT, compiled as C11 with
   -Wall -Wextra -Wpedantic -Werror. Calls every public function (an unused static function would
   be a warning). `make test` also builds it with -DBVH_NO_THREADS, where ploc-parallel and the
   batch calls run on one thread and must still give ploc's tree and the single-ray hits. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static long live_blocks; /* BVH_MALLOC minus BVH_FREE */
static void *counted_malloc(size_t size) {
    live_blocks++;
    return malloc(size);
}
static void counted_free(void *p) {
    if (p) live_blocks--;
    free(p);
}
static int assert_failures;
#define BVH_MALLOC(size, user) ((void)(user), counted_malloc(size))
#define BVH_FREE(ptr, user) ((void)(user), counted_free(ptr))
#define BVH_ASSERT(c) ((void)((c) || ++assert_failures))
#ifndef BVH_STATIC
#error "build with -DBVH_STATIC"
#endif
#define BVH_IMPLEMENTATION
#include "bvh.h"

#define CHECK(c)                                                                                                       \
    do {                                                                                                               \
        if (!(c)) {                                                                                                    \
            printf("%s:%d: check failed: %s\n", __FILE__, __LINE__, #c);                                               \
            failures++;                                                                                                \
        }                                                                                                              \
    } while (0)

int main(void) {
    static const float v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 0, 1, 0, 1, 1, 2, 2, 2, 3, 2, 2, 2, 3, 2};
    bvh_build_desc d;
    bvh_tree ploc, par;
    bvh_ray ray = {{0.2f, 0.2f, -1}, 0.0f, {0, 0, 1}, BVH_INF}, rays[2];
    bvh_hit hit, hits[2];
    uint8_t occ[2];
    uint32_t visited = 0;
    bvh_validation rep;
    bvh_stats st;
    bvh_builder b;
    bvh_aabb box = bvh_aabb_empty(), bounds;
    bvh_camera cam;
    double cost = 0.0;
    int failures = 0;

    memset(&d, 0, sizeof d);
    d.builder = BVH_BUILDER_PLOC;
    d.triangles.positions = v;
    d.triangles.vertex_count = 9;
    d.triangles.triangle_count = 3;
    CHECK(bvh_build(&ploc, &d) == BVH_SUCCESS);
    d.builder = BVH_BUILDER_PLOC_PARALLEL;
    d.threads = 4;
    CHECK(bvh_build(&par, &d) == BVH_SUCCESS);
    CHECK(par.node_count == ploc.node_count && par.ref_count == ploc.ref_count);
    CHECK(memcmp(par.nodes, ploc.nodes, ploc.node_count * sizeof(bvh_node)) == 0);
    CHECK(memcmp(par.prims, ploc.prims, ploc.ref_count * sizeof(uint32_t)) == 0);
    CHECK(live_blocks ==
          8); /* nodes, references, triangles, the wide nodes with their packets of each tree: BVH_MALLOC */

    CHECK(bvh_intersect(&par, &ray, &hit) == 1 && hit.prim == 0 && hit.t == 1.0f);
    CHECK(bvh_intersect_counted(&par, &ray, &hit, &visited) == 1 && visited >= 1);
    CHECK(bvh_occluded(&par, &ray) == 1);
    rays[0] = ray;
    rays[1] = ray;
    rays[1].origin.x = 2.5f;
    rays[1].origin.y = 2.25f;
    CHECK(bvh_intersect_batch(&par, rays, hits, 2, 2) == BVH_SUCCESS && hits[0].prim == 0 && hits[1].prim == 2);
    CHECK(bvh_occluded_batch(&par, rays, occ, 2, 2) == BVH_SUCCESS && occ[0] == 1 && occ[1] == 1);
    CHECK(bvh_intersect_triangle(&ray, v + 9, v + 12, v + 15, &hit) == 1 && hit.t == 2.0f);
    CHECK(bvh_validate(&par, NULL, &rep) == BVH_SUCCESS && strcmp(rep.message, "ok") == 0);
    CHECK(bvh_get_stats(&par, &st) == BVH_SUCCESS && st.refs == 3 && st.bytes == st.nodes * 32u + 12u);
    CHECK(bvh_sah(&par, NULL, &cost) == BVH_SUCCESS && cost > 0.0);

    bounds = bvh_tree_bounds(&par);
    bvh_aabb_grow(&box, bounds.min);
    bvh_aabb_grow(&box, bounds.max);
    CHECK(bvh_aabb_contains(bvh_aabb_merge(box, bvh_aabb_empty()), bounds));
    CHECK(bvh_aabb_area(box) == 2.0f * 21.0f); /* [0,3] x [0,3] x [0,2] */
    CHECK(bvh_aabb_centroid(box).x == 1.5f);
    cam = bvh_camera_standard(box, 4, 4);
    ray = bvh_camera_ray(&cam, 2, 2);
    CHECK(fabsf(ray.dir.x * ray.dir.x + ray.dir.y * ray.dir.y + ray.dir.z * ray.dir.z - 1.0f) < 1e-5f);
    CHECK(memcmp(&ray.origin, &cam.eye, sizeof ray.origin) == 0);

    CHECK(bvh_builder_from_name(bvh_builder_name(BVH_BUILDER_TOP_DOWN), &b) == BVH_SUCCESS &&
          b == BVH_BUILDER_TOP_DOWN);
    CHECK(strlen(bvh_result_string(BVH_ERROR_OUT_OF_MEMORY)) > 0);
    bvh_free(&ploc);
    bvh_free(&par);
    CHECK(live_blocks == 0);
    CHECK(assert_failures == 0);
#ifdef BVH_NO_THREADS
    printf("BVH_STATIC, BVH_NO_THREADS, own BVH_MALLOC/BVH_FREE/BVH_ASSERT: %d failures\n", failures);
#else
    printf("BVH_STATIC, own BVH_MALLOC/BVH_FREE/BVH_ASSERT: %d failures\n", failures);
#endif
    return failures ? 1 : 0;
}
