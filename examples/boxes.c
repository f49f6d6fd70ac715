/* boxes.c - a BVH over custom primitives (spheres), built from their boxes and walked by hand.

   bvh_build takes any primitive as a bounding box (desc.boxes, desc.box_count). bvh_intersect
   only knows triangles (on a box tree it misses, and the batch calls return
   BVH_ERROR_NO_TRIANGLES), so this program walks tree.nodes itself: an interior node
   (count == 0) has its children at nodes[index] and nodes[index + 1]; a leaf (count > 0) holds
   the spheres tree.prims[index .. index + count - 1]. Every ray's closest sphere is checked
   against a brute-force loop over all spheres.

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

/* The nearest t in [ray->tmin, *t_best) where the ray meets the sphere; a tie goes to the lower
   index, so that any visiting order picks the same sphere. */
static void hit_sphere(const bvh_ray *ray, const sphere *s, uint32_t i, float *t_best, uint32_t *best) {
    bvh_vec3 oc = {ray->origin.x - s->c.x, ray->origin.y - s->c.y, ray->origin.z - s->c.z};
    float a = ray->dir.x * ray->dir.x + ray->dir.y * ray->dir.y + ray->dir.z * ray->dir.z;
    float b = oc.x * ray->dir.x + oc.y * ray->dir.y + oc.z * ray->dir.z;
    float c = oc.x * oc.x + oc.y * oc.y + oc.z * oc.z - s->r * s->r;
    float disc = b * b - a * c, t;
    if (disc < 0.0f) return;
    t = (-b - sqrtf(disc)) / a;
    if (t < ray->tmin) t = (-b + sqrtf(disc)) / a; /* the origin is inside the sphere */
    if (t < ray->tmin || t > ray->tmax || t > *t_best || (t == *t_best && i > *best)) return;
    *t_best = t;
    *best = i;
}

/* Slab test: does the ray enter the box before t_best? */
static int hit_box(const bvh_ray *ray, const bvh_vec3 *inv, const bvh_node *n, float t_best) {
    float tx0 = (n->min.x - ray->origin.x) * inv->x, tx1 = (n->max.x - ray->origin.x) * inv->x;
    float ty0 = (n->min.y - ray->origin.y) * inv->y, ty1 = (n->max.y - ray->origin.y) * inv->y;
    float tz0 = (n->min.z - ray->origin.z) * inv->z, tz1 = (n->max.z - ray->origin.z) * inv->z;
    float lo = fmaxf(fmaxf(fminf(tx0, tx1), fminf(ty0, ty1)), fmaxf(fminf(tz0, tz1), ray->tmin));
    float hi = fminf(fminf(fmaxf(tx0, tx1), fmaxf(ty0, ty1)), fminf(fmaxf(tz0, tz1), t_best));
    return lo <= hi;
}

/* The closest sphere along the ray (BVH_INVALID: none), walking the tree depth first. */
static uint32_t trace(const bvh_tree *tree, const sphere *s, const bvh_ray *ray) {
    bvh_vec3 inv = {1.0f / ray->dir.x, 1.0f / ray->dir.y, 1.0f / ray->dir.z};
    uint32_t stack[2 * BVH_MAX_DEPTH], sp = 0, best = BVH_INVALID, k;
    float t_best = BVH_INF;
    if (tree->node_count) stack[sp++] = 0;
    while (sp) {
        const bvh_node *n = &tree->nodes[stack[--sp]];
        if (!hit_box(ray, &inv, n, t_best)) continue;
        if (n->count == 0) {
            stack[sp++] = n->index;
            stack[sp++] = n->index + 1;
            continue;
        }
        for (k = n->index; k < n->index + n->count; k++)
            hit_sphere(ray, &s[tree->prims[k]], tree->prims[k], &t_best, &best);
    }
    return best;
}

static uint32_t brute_force(const sphere *s, uint32_t count, const bvh_ray *ray) {
    uint32_t best = BVH_INVALID, i;
    float t_best = BVH_INF;
    for (i = 0; i < count; i++) hit_sphere(ray, &s[i], i, &t_best, &best);
    return best;
}

int main(void) {
    static sphere s[SPHERES];
    static bvh_aabb boxes[SPHERES];
    uint32_t seed = 12345, i, agree = 0, hits = 0;
    bvh_build_desc desc = {0};
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
        uint32_t a = trace(&tree, s, &ray), b = brute_force(s, SPHERES, &ray);
        agree += a == b;
        hits += b != BVH_INVALID;
    }
    printf("boxes: %u spheres, %u nodes, %u rays (%u hit a sphere): %u agree with brute force\n", SPHERES,
           tree.node_count, RAYS, hits, agree);
    bvh_free(&tree);
    return agree == RAYS ? 0 : 1;
}
