/* boxes.c - a BVH over custom primitives (spheres), built from their boxes, traced with a callback.

   bvh_build takes any primitive as a bounding box (desc.boxes, desc.box_count).
   bvh_intersect_custom traces such a tree: it calls the caller's test (bvh_custom_desc) for each
   primitive whose box the ray reaches, with the ray's tmax lowered to the closest hit so far, and
   keeps the closest hit (ties to the lowest index). Every ray's closest sphere is checked against
   a brute-force loop over all spheres with the same test.

   Build and run (from the repository root; `make test` does both):
       cc -std=c11 -O2 -I. examples/boxes.c -o build/boxes -lm -lpthread
       build/boxes
   Prints how many rays agree and exits 0 when all do, 1 otherwise. */
#define BVH_IMPLEMENTATION
#include "bvh.h"

#include <math.h>
#include <stdio.h>

#define SPHERES 2000
#define RAYS 20000

typedef struct sphere {
    bvh_vec3 c;
    float r;
} sphere;

static float rand01(uint32_t *state) { /* xorshift32: the same scene on every machine */
    *state ^= *state << 13;
    *state ^= *state >> 17;
    *state ^= *state << 5;
    return (float)(*state >> 8) * (1.0f / 16777216.0f);
}

/* The custom primitive's test (bvh_custom_desc.intersect): the nearest t in
   [ray->tmin, ray->tmax] where the ray meets sphere i. ray->tmax is the closest hit so far, so
   farther roots are not reported. */
static int hit_sphere(const bvh_ray *ray, uint32_t i, void *user, bvh_hit *hit) {
    const sphere *s = (const sphere *)user + i;
    bvh_vec3 oc = {ray->origin.x - s->c.x, ray->origin.y - s->c.y, ray->origin.z - s->c.z};
    float a = ray->dir.x * ray->dir.x + ray->dir.y * ray->dir.y + ray->dir.z * ray->dir.z;
    float b = oc.x * ray->dir.x + oc.y * ray->dir.y + oc.z * ray->dir.z;
    float c = oc.x * oc.x + oc.y * oc.y + oc.z * oc.z - s->r * s->r;
    float disc = b * b - a * c, t;
    if (disc < 0.0f) return 0;
    t = (-b - sqrtf(disc)) / a;
    if (t < ray->tmin) t = (-b + sqrtf(disc)) / a; /* the origin is inside the sphere */
    if (t < ray->tmin || t > ray->tmax) return 0;
    hit->t = t;
    return 1;
}

/* Every sphere in turn with the same test; a tie in t goes to the lower index, as in the tree. */
static uint32_t brute_force(const sphere *s, uint32_t count, const bvh_ray *ray) {
    uint32_t best = BVH_INVALID, i;
    bvh_ray r = *ray;
    bvh_hit h;
    for (i = 0; i < count; i++)
        if (hit_sphere(&r, i, (void *)s, &h) && (h.t < r.tmax || best == BVH_INVALID)) {
            r.tmax = h.t;
            best = i;
        }
    return best;
}

int main(void) {
    static sphere s[SPHERES];
    static bvh_aabb boxes[SPHERES];
    uint32_t seed = 12345, i, agree = 0, hits = 0;
    bvh_build_desc desc = {0};
    bvh_custom_desc spheres = {hit_sphere, s}; /* the test and its user pointer */
    bvh_tree tree;
    bvh_result r;
    for (i = 0; i < SPHERES; i++) { /* spheres in the unit cube; each box holds its sphere */
        s[i].c = (bvh_vec3){rand01(&seed), rand01(&seed), rand01(&seed)};
        s[i].r = 0.005f + 0.02f * rand01(&seed);
        boxes[i].min = (bvh_vec3){s[i].c.x - s[i].r, s[i].c.y - s[i].r, s[i].c.z - s[i].r};
        boxes[i].max = (bvh_vec3){s[i].c.x + s[i].r, s[i].c.y + s[i].r, s[i].c.z + s[i].r};
    }
    desc.builder = BVH_BUILDER_PLOC;
    desc.boxes = boxes;
    desc.box_count = SPHERES;
    r = bvh_build(&tree, &desc);
    if (r != BVH_SUCCESS) {
        printf("bvh_build: %s\n", bvh_result_string(r));
        return 1;
    }
    for (i = 0; i < RAYS; i++) { /* from the plane z = -1 toward a point of the cube */
        bvh_vec3 o = {3.0f * rand01(&seed) - 1.0f, 3.0f * rand01(&seed) - 1.0f, -1.0f};
        bvh_ray ray = {o, 0.0f, {rand01(&seed) - o.x, rand01(&seed) - o.y, rand01(&seed) - o.z}, BVH_INF};
        bvh_hit hit;
        uint32_t b = brute_force(s, SPHERES, &ray);
        bvh_intersect_custom(&tree, &ray, &hit, &spheres);
        agree += hit.prim == b;
        hits += b != BVH_INVALID;
    }
    printf("boxes: %u spheres, %u nodes, %u rays (%u hit a sphere): %u agree with brute force\n", SPHERES,
           tree.node_count, RAYS, hits, agree);
    bvh_free(&tree);
    return agree == RAYS ? 0 : 1;
}
