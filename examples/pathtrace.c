/* pathtrace.c - a small path tracer on bvh.h: instances of per-mesh trees, spheres as custom
   primitives, diffuse bounces, a sun with shadow rays and a sky, on all CPUs.

   build/pathtrace [SCENE] [--spp N] [--depth D] [--size WxH] [--out FILE] [--threads N] [--inside]
                   [--trace cpu|opencl|auto] [--add MODEL] [--builder B] [--embree [--embree-high]] [--json]
   e.g. build/pathtrace sponza.glb --inside --size 512x512 --spp 4 --out sponza.png
        build/pathtrace                       (the built-in scene: boxes on a ground quad)
        build/pathtrace --trace opencl        (the same image, the rays traced by cl/bvh_cl.h)
        build/pathtrace sponza.glb --inside --add bunny.obj --embree --json
                                              (three bunnies in Sponza; then the same image on
                                               Embree 3: both Mrays/s, the ratio, one JSON line)

   The scene keeps the file's structure: one bottom-level tree per mesh (assimp's aiMesh), built
   once, and one bvh_instance per node that uses the mesh, placed by the node's world transform
   (nothing is copied into world space). bvh_scene_build puts a top-level tree over them. Three
   spheres are custom primitives: a tree over their boxes with a sphere test (bvh_custom_desc),
   one more instance of the CPU's scene, so that one traversal finds the nearest of all, and a
   ray that passes far from the spheres never tests them.
   Each path: a camera ray, then up to D - 1 cosine-weighted diffuse bounces; at each hit a shadow
   ray toward the sun (next-event estimation), and the sky's colour when a ray escapes. Secondary
   rays start at bvh_offset_origin(point, normal) with tmin = 0: no epsilon to tune per scene.
   Pixels are independent and each has its own random sequence (a hash of pixel and sample), so
   the image is the same for any --threads.
   --trace opencl traces the scene's rays on an OpenCL device (cl/bvh_cl.h: bvh_cl_scene_upload,
   bvh_cl_scene_intersect, bvh_cl_scene_occluded) in wavefronts: the paths of a block of pixels
   advance together, one batch of rays per bounce and one of shadow rays. The spheres are custom
   primitives, whose test is C code the kernel cannot run: the host tests them on the same rays
   (bvh_intersect_custom, cheap for three spheres) and the nearer hit wins, as on the CPU; the
   shading runs on one host thread. The device's hits are the CPU's (to the bit on an exact device
   such as PoCL), every path keeps its random sequence and a pixel's samples are summed in the same
   order, so the image is the CPU's, byte for byte. --trace auto takes OpenCL when a device can be
   used, else the CPU (said on stderr); --trace opencl without one is an error.
   --embree renders the image again with Embree 3 tracing (see "the same renderer on Embree 3"):
   the same paths, so the images agree but where float rounding in a hit sends a path elsewhere;
   both Mrays/s (whole render, the same shading, rays counted alike) and their ratio. On the CPU
   the two render the image in turns, a band of rows each (PAIR_BANDS, the order alternating),
   so that both see the same moments of a machine whose speed drifts; the median and the range of
   the bands' ratios are printed too.
   --builder picks the meshes' trees (any builder, +opt for the optimizer); the default,
   sah-midpoint+opt, is the README's choice for a static scene traced for a long time. Every
   builder gives the same hits, so the same image. --embree-high builds Embree's meshes at its
   high quality (spatial splits) instead of its default, medium.
   Without assimp (BVH_HAVE_ASSIMP) a file is read by scene.h's OBJ reader as one mesh; without
   stb (BVH_HAVE_STB) the image is a .ppm. Exit status: 0 done; 1 an error (said on stderr); 2 a
   bad command line. */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define BVH_CL_IMPLEMENTATION
#include "cl/bvh_cl.h" /* without BVH_HAVE_OPENCL its calls return BVH_CL_ERROR_NOT_AVAILABLE */
#define SCENE_IMPLEMENTATION
#include "scene.h" /* image writing, clock, command-line numbers, the OBJ reader */
#define RAYS_IMPLEMENTATION
#include "rays.h" /* the interior view (--inside) */

#ifdef BVH_HAVE_ASSIMP
#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#endif
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265f
#define SPHERES 3

typedef struct mesh {
    bvh_triangles tris; /* the bottom-level build's input, kept for bvh_hit_surface */
    bvh_tree tree;
    bvh_vec3 albedo;
    int built; /* 0: no triangles (lines or points only): no instance uses it */
} mesh;

typedef struct sphere {
    bvh_vec3 c, albedo;
    float r;
} sphere;

typedef struct world {
    mesh *meshes;
    uint32_t mesh_count;
    bvh_instance *instances; /* instance.id = its mesh's index */
    uint32_t instance_count, instance_cap;
    bvh_scene scene; /* the meshes' instances (what a device traces) */
    sphere spheres[SPHERES];
    bvh_tree sphere_tree;        /* built from the spheres' boxes */
    bvh_custom_desc sphere_test; /* hit_sphere on w->spheres */
    bvh_scene cpu;               /* scene's instances and then the spheres' (instance_count) */
    bvh_builder builder;         /* the meshes' trees (--builder) ... */
    uint32_t optimize;           /* ... and their optimizer rounds (0: none) */
} world;

static bvh_vec3 v3(float x, float y, float z) { return (bvh_vec3){x, y, z}; }
static bvh_vec3 add(bvh_vec3 a, bvh_vec3 b) { return v3(a.x + b.x, a.y + b.y, a.z + b.z); }
static bvh_vec3 sub(bvh_vec3 a, bvh_vec3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static bvh_vec3 mul(bvh_vec3 a, bvh_vec3 b) { return v3(a.x * b.x, a.y * b.y, a.z * b.z); }
static bvh_vec3 scale(bvh_vec3 a, float s) { return v3(a.x * s, a.y * s, a.z * s); }
static float dot(bvh_vec3 a, bvh_vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static bvh_vec3 normalize(bvh_vec3 a) { return scale(a, 1.0f / sqrtf(dot(a, a))); }

/* ---- the scene ------------------------------------------------------------------------------ */
/* Builds mesh i's bottom-level tree. positions and indices stay owned by the mesh, because
   bvh_hit_surface reads them to find a hit's point (the tree keeps its own copy for tracing). */
static bvh_result add_mesh(world *w, uint32_t i, float *pos, uint32_t nv, uint32_t *idx, uint32_t nt, bvh_vec3 albedo) {
    mesh *m = &w->meshes[i];
    bvh_build_desc desc = {0};
    bvh_result r;
    m->tris = (bvh_triangles){pos, 0, nv, idx, nt};
    m->albedo = albedo;
    if (nt == 0) return BVH_SUCCESS;
    desc.triangles = m->tris;
    desc.builder = w->builder;
    desc.optimize.rounds = w->optimize;
    r = bvh_build(&m->tree, &desc);
    m->built = r == BVH_SUCCESS;
    return r;
}

/* Appends an instance of mesh `i` placed by the row-major 3x4 matrix m (object to world).
   bvh_scene_build refuses a singular transform, so a node scaled to zero is left out here. */
static int add_instance(world *w, uint32_t i, const float m[12]) {
    float det =
        m[0] * (m[5] * m[10] - m[6] * m[9]) - m[1] * (m[4] * m[10] - m[6] * m[8]) + m[2] * (m[4] * m[9] - m[5] * m[8]);
    if (!w->meshes[i].built || !(fabsf(det) > 1e-30f) || !isfinite(det)) return 0;
    if (w->instance_count + 1 >= w->instance_cap) { /* a spare slot for build_cpu_scene */
        uint32_t cap = w->instance_cap ? 2 * w->instance_cap : 64;
        bvh_instance *p = realloc(w->instances, cap * sizeof *p);
        if (!p) return 1;
        w->instances = p;
        w->instance_cap = cap;
    }
    w->instances[w->instance_count] = (bvh_instance){&w->meshes[i].tree, {0}, i, ~0u, NULL};
    memcpy(w->instances[w->instance_count++].transform, m, 12 * sizeof(float));
    return 0;
}

/* Room for n more meshes (zeroed) after w's: 0, or 1 when out of memory. The instances point
   at their mesh's tree, which may have moved. */
static int more_meshes(world *w, uint32_t n) {
    mesh *p = realloc(w->meshes, ((size_t)w->mesh_count + n + 1) * sizeof *p);
    uint32_t i;
    if (!p) return 1;
    memset(p + w->mesh_count, 0, (n + 1) * sizeof *p);
    w->meshes = p;
    w->mesh_count += n;
    for (i = 0; i < w->instance_count; i++) w->instances[i].tree = &p[w->instances[i].id].tree;
    return 0;
}

/* Rotation about y by angle a, then scale (sx, sy, sz) and translation t: M = R_y(a) S. */
static void place(float m[12], float a, float sx, float sy, float sz, float tx, float ty, float tz) {
    float c = cosf(a), s = sinf(a);
    float r[12] = {c * sx, 0, s * sz, tx, 0, sy, 0, ty, -s * sx, 0, c * sz, tz};
    memcpy(m, r, sizeof r);
}

/* No file (or no assimp): a ground quad and a unit box, two meshes, the box placed 7 times. */
static int load_builtin(world *w, char *err, size_t errlen) {
    static const float quad[] = {-1, 0, -1, 1, 0, -1, 1, 0, 1, -1, 0, 1};
    static const uint32_t quad_idx[] = {0, 2, 1, 0, 3, 2};
    static const uint32_t box_idx[] = {0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4,
                                       1, 2, 6, 1, 6, 5, 2, 3, 7, 2, 7, 6, 3, 0, 4, 3, 4, 7};
    float *pos[2] = {malloc(sizeof quad), malloc(24 * sizeof(float))}, m[12];
    uint32_t *idx[2] = {malloc(sizeof quad_idx), malloc(sizeof box_idx)}, k;
    bvh_result r;
    w->meshes = calloc(2, sizeof *w->meshes);
    if (!w->meshes || !pos[0] || !pos[1] || !idx[0] || !idx[1]) {
        free(pos[0]), free(pos[1]), free(idx[0]), free(idx[1]);
        return snprintf(err, errlen, "out of memory"), 1;
    }
    w->mesh_count = 2;
    memcpy(pos[0], quad, sizeof quad);
    memcpy(idx[0], quad_idx, sizeof quad_idx);
    memcpy(idx[1], box_idx, sizeof box_idx);
    for (k = 0; k < 8; k++) { /* corners of [-0.5, 0.5] x [0, 1] x [-0.5, 0.5], bottom face first */
        pos[1][3 * k] = (k == 1 || k == 2 || k == 5 || k == 6) ? 0.5f : -0.5f;
        pos[1][3 * k + 1] = k < 4 ? 0.0f : 1.0f;
        pos[1][3 * k + 2] = (k == 2 || k == 3 || k == 6 || k == 7) ? 0.5f : -0.5f;
    }
    r = add_mesh(w, 0, pos[0], 4, idx[0], 2, v3(0.75f, 0.75f, 0.75f));
    if (r == BVH_SUCCESS) r = add_mesh(w, 1, pos[1], 8, idx[1], 12, v3(0.8f, 0.55f, 0.35f));
    if (r != BVH_SUCCESS) return snprintf(err, errlen, "bvh_build: %s", bvh_result_string(r)), 1;
    place(m, 0, 8, 1, 8, 0, 0, 0);
    if (add_instance(w, 0, m)) return snprintf(err, errlen, "out of memory"), 1;
    for (k = 0; k < 7; k++) { /* a ring of boxes, each turned and sized differently */
        float a = 2 * PI * (float)k / 7, s = 1.0f + 0.3f * (float)(k % 3);
        place(m, a * 1.7f, s, s * (1.0f + (float)(k % 2)), s, 4.5f * cosf(a), 0, 4.5f * sinf(a));
        if (add_instance(w, 1, m)) return snprintf(err, errlen, "out of memory"), 1;
    }
    return 0;
}

#ifdef BVH_HAVE_ASSIMP
/* Walks assimp's node tree, accumulating transforms: one instance per (node, mesh) pair. */
static int add_nodes(world *w, const struct aiNode *node, struct aiMatrix4x4 parent, uint32_t base) {
    uint32_t k;
    aiMultiplyMatrix4(&parent, &node->mTransformation); /* parent = parent * node's own */
    for (k = 0; k < node->mNumMeshes; k++) {
        const struct aiMatrix4x4 *t = &parent; /* assimp's rows a, b, c: the 3x4 we need */
        float m[12] = {t->a1, t->a2, t->a3, t->a4, t->b1, t->b2, t->b3, t->b4, t->c1, t->c2, t->c3, t->c4};
        if (base + node->mMeshes[k] < w->mesh_count && add_instance(w, base + node->mMeshes[k], m)) return 1;
    }
    for (k = 0; k < node->mNumChildren; k++)
        if (add_nodes(w, node->mChildren[k], parent, base)) return 1;
    return 0;
}

/* The material's colour (glTF's base colour, else the diffuse colour), kept below 1 so that
   light fades over bounces; textures are not read (a white texture base gives 0.8). */
static bvh_vec3 material_albedo(const struct aiMaterial *mat) {
    struct aiColor4D c = {0.8f, 0.8f, 0.8f, 1.0f};
    if (mat && aiGetMaterialColor(mat, AI_MATKEY_BASE_COLOR, &c) != aiReturn_SUCCESS)
        aiGetMaterialColor(mat, AI_MATKEY_COLOR_DIFFUSE, &c);
    return v3(0.8f * fminf(c.r, 1.0f), 0.8f * fminf(c.g, 1.0f), 0.8f * fminf(c.b, 1.0f));
}

/* Adds the file's meshes and its instances to w's. */
static int load_file(world *w, const char *path, char *err, size_t errlen) {
    const struct aiScene *s = aiImportFile(path, aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                                                     aiProcess_SortByPType | aiProcess_ValidateDataStructure);
    struct aiMatrix4x4 identity;
    uint32_t i, f, n, base = w->mesh_count;
    int rc = 0;
    if (!s || !s->mRootNode) return snprintf(err, errlen, "cannot read '%s': %s", path, aiGetErrorString()), 1;
    if (more_meshes(w, s->mNumMeshes)) return aiReleaseImport(s), snprintf(err, errlen, "out of memory"), 1;
    for (i = 0; i < s->mNumMeshes && !rc; i++) { /* one bottom-level tree per aiMesh */
        const struct aiMesh *am = s->mMeshes[i];
        float *pos = malloc(((size_t)am->mNumVertices + 1) * 3 * sizeof(float));
        uint32_t *idx = malloc(((size_t)am->mNumFaces + 1) * 3 * sizeof(uint32_t));
        bvh_result r;
        if (!pos || !idx) {
            free(pos), free(idx);
            rc = 1, snprintf(err, errlen, "out of memory");
            break;
        }
        for (n = 0; n < am->mNumVertices; n++) memcpy(pos + 3 * n, &am->mVertices[n], 3 * sizeof(float));
        for (f = n = 0; f < am->mNumFaces; f++) /* triangles only: SortByPType left lines apart */
            if (am->mFaces[f].mNumIndices == 3) memcpy(idx + 3 * n++, am->mFaces[f].mIndices, 3 * sizeof(uint32_t));
        r = add_mesh(w, base + i, pos, am->mNumVertices, idx, n, material_albedo(s->mMaterials[am->mMaterialIndex]));
        if (r != BVH_SUCCESS) rc = 1, snprintf(err, errlen, "mesh %u: bvh_build: %s", i, bvh_result_string(r));
    }
    aiIdentityMatrix4(&identity);
    if (!rc && add_nodes(w, s->mRootNode, identity, base)) rc = 1, snprintf(err, errlen, "out of memory");
    aiReleaseImport(s);
    return rc;
}
#else
/* Without assimp: scene.h reads an OBJ file into a world-space soup, used as one mesh. */
static int load_file(world *w, const char *path, char *err, size_t errlen) {
    static const float identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    scene s;
    bvh_result r;
    uint32_t i = w->mesh_count;
    if (scene_load(path, &s, err, errlen)) return 1;
    if (more_meshes(w, 1)) return scene_free(&s), snprintf(err, errlen, "out of memory"), 1;
    r = add_mesh(w, i, s.v, 3 * s.triangles, NULL, s.triangles, v3(0.8f, 0.8f, 0.8f)); /* s.v now the mesh's */
    if (r != BVH_SUCCESS) return snprintf(err, errlen, "bvh_build: %s", bvh_result_string(r)), 1;
    return add_instance(w, i, identity) ? (snprintf(err, errlen, "out of memory"), 1) : 0;
}
#endif

/* The world box of instances [from, to): their meshes' boxes, corner by corner, transformed. */
static bvh_aabb instances_box(const world *w, uint32_t from, uint32_t to) {
    bvh_aabb b = bvh_aabb_empty();
    uint32_t i, k;
    for (i = from; i < to; i++) {
        bvh_aabb mb = bvh_tree_bounds(w->instances[i].tree);
        const float *m = w->instances[i].transform;
        for (k = 0; k < 8 && mb.min.x <= mb.max.x; k++) {
            bvh_vec3 p = v3(k & 1 ? mb.max.x : mb.min.x, k & 2 ? mb.max.y : mb.min.y, k & 4 ? mb.max.z : mb.min.z);
            bvh_aabb_grow(&b,
                          v3(m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3], m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
                             m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]));
        }
    }
    return b;
}

/* --add: the instances from `first` on (a model just loaded, e.g. a bunny) become ADD_COPIES
   instances of it (its node hierarchy under each) standing on the floor of the scene before them,
   each 7% of that scene's diagonal tall, turned differently, in a row across the view between
   the camera of --inside and the centre. 0, or 1 when out of memory. */
#define ADD_COPIES 3
static int add_copies(world *w, uint32_t first) {
    uint32_t n = w->instance_count, i, k, c;
    bvh_aabb b = instances_box(w, 0, first), mb = instances_box(w, first, n);
    bvh_vec3 mid = bvh_aabb_centroid(b), d = sub(b.max, b.min), base = bvh_aabb_centroid(mb);
    float size = mb.max.y > mb.min.y ? 0.07f * sqrtf(dot(d, d)) / (mb.max.y - mb.min.y) : 1.0f;
    bvh_scene floor = {0};
    if (first == 0 || n == first) return 0;
    if (bvh_scene_build(&floor, &(bvh_scene_desc){.instances = w->instances, .instance_count = first}) != BVH_SUCCESS)
        return 1;
    base.y = mb.min.y;
    for (k = ADD_COPIES; k-- > 0;) { /* copy 0 last: it overwrites the loaded instances */
        float along = -0.12f, across = 0.2f * ((float)k - 1.0f), p[12], q[3];
        bvh_vec3 at = d.x > d.z ? v3(mid.x + along * d.x, mid.y, mid.z + across * d.z)
                                : v3(mid.x + across * d.x, mid.y, mid.z + along * d.z);
        bvh_ray down = {at, 0.0f, {0.0f, -1.0f, 0.0f}, BVH_INF};
        bvh_scene_hit h;
        at.y = bvh_scene_intersect(&floor, &down, ~0u, &h) ? at.y - h.t : b.min.y;
        place(p, 1.1f * (float)k + 0.4f, size, size, size, 0, 0, 0);
        for (c = 0; c < 3; c++) q[c] = p[4 * c] * base.x + p[4 * c + 1] * base.y + p[4 * c + 2] * base.z;
        p[3] = at.x - q[0], p[7] = at.y - q[1], p[11] = at.z - q[2]; /* the model's foot on the floor */
        for (i = first; i < n; i++) {
            float t[12], m[12];
            uint32_t r;
            memcpy(t, w->instances[i].transform, sizeof t);
            for (r = 0; r < 3; r++)
                for (c = 0; c < 4; c++)
                    m[4 * r + c] = p[4 * r] * t[c] + p[4 * r + 1] * t[4 + c] + p[4 * r + 2] * t[8 + c] +
                                   (c == 3 ? p[4 * r + 3] : 0.0f);
            if (k == 0)
                memcpy(w->instances[i].transform, m, sizeof m);
            else if (add_instance(w, w->instances[i].id, m))
                return bvh_scene_free(&floor), 1;
        }
    }
    bvh_scene_free(&floor);
    return 0;
}

/* The spheres' test (bvh_custom_desc.intersect): the nearest t in [tmin, tmax] on sphere i. */
static int hit_sphere(const bvh_ray *ray, uint32_t i, void *user, bvh_hit *hit) {
    const sphere *s = (const sphere *)user + i;
    bvh_vec3 oc = sub(ray->origin, s->c);
    float a = dot(ray->dir, ray->dir), b = dot(oc, ray->dir), c = dot(oc, oc) - s->r * s->r;
    float disc = b * b - a * c, t;
    if (disc < 0.0f) return 0;
    t = (-b - sqrtf(disc)) / a;
    if (t < ray->tmin) t = (-b + sqrtf(disc)) / a; /* the origin is inside the sphere */
    if (t < ray->tmin || t > ray->tmax) return 0;
    hit->t = t;
    return 1;
}

/* Three spheres near the centre of the scene's box b, sized by it, in a tree built from boxes.
   They rest on the floor: whatever a ray cast down from the centre meets first (else b's bottom). */
static bvh_result add_spheres(world *w, bvh_aabb b) {
    bvh_vec3 c = bvh_aabb_centroid(b), d = sub(b.max, b.min);
    float r = 0.025f * sqrtf(dot(d, d));
    bvh_aabb boxes[SPHERES];
    bvh_build_desc desc = {0};
    bvh_ray down = {c, 0.0f, {0.0f, -1.0f, 0.0f}, BVH_INF};
    bvh_scene_hit floor;
    uint32_t i;
    float y = bvh_scene_intersect(&w->scene, &down, ~0u, &floor) ? c.y - floor.t : b.min.y;
    for (i = 0; i < SPHERES; i++) {
        sphere *s = &w->spheres[i];
        s->r = r * (1.0f + 0.25f * (float)i);
        s->c = v3(c.x + 3.0f * r * ((float)i - 1.0f), y + s->r, c.z + r * (float)i);
        s->albedo = v3(i == 0 ? 0.8f : 0.1f, i == 1 ? 0.8f : 0.1f, i == 2 ? 0.8f : 0.1f);
        boxes[i].min = sub(s->c, v3(s->r, s->r, s->r));
        boxes[i].max = add(s->c, v3(s->r, s->r, s->r));
    }
    desc.boxes = boxes;
    desc.box_count = SPHERES;
    w->sphere_test.intersect = hit_sphere;
    w->sphere_test.user = w->spheres;
    return bvh_build(&w->sphere_tree, &desc);
}
/* The CPU's scene: the meshes' instances and, after them, the spheres' tree placed by the
   identity with the sphere test (instances has room for it: add_instance keeps a spare slot). */
static bvh_result build_cpu_scene(world *w) {
    bvh_instance *s = &w->instances[w->instance_count];
    memset(s, 0, sizeof *s);
    s->tree = &w->sphere_tree;
    s->custom = &w->sphere_test;
    s->transform[0] = s->transform[5] = s->transform[10] = 1.0f;
    s->mask = ~0u;
    return bvh_scene_build(&w->cpu,
                           &(bvh_scene_desc){.instances = w->instances, .instance_count = w->instance_count + 1});
}

static void free_world(world *w) {
    uint32_t i;
    bvh_scene_free(&w->scene);
    bvh_scene_free(&w->cpu);
    bvh_free(&w->sphere_tree);
    for (i = 0; i < w->mesh_count; i++) {
        bvh_free(&w->meshes[i].tree); /* no-op on a tree never built (zeroed by calloc) */
        free((void *)w->meshes[i].tris.positions);
        free((void *)w->meshes[i].tris.indices);
    }
    free(w->meshes);
    free(w->instances);
}

/* ---- tracing -------------------------------------------------------------------------------- */
typedef struct surface {
    bvh_vec3 p, n, albedo;
} surface;

/* The surface a ray meets, from a hit record every tracer fills the same way (bvh.h on the CPU,
   OpenCL, Embree): sphere number `ball` at t (BVH_INVALID: none), else the scene's hit h of a
   triangle of an instance (NULL or h->instance = BVH_INVALID: none). 0 when the ray meets
   nothing. Its point, unit normal (facing the ray) and albedo. */
static int surface_at(const world *w, const bvh_ray *ray, const bvh_scene_hit *h, uint32_t ball, float t, surface *s) {
    if (ball != BVH_INVALID) {
        const sphere *sp = &w->spheres[ball];
        s->n = normalize(sub(add(ray->origin, scale(ray->dir, t)), sp->c));
        s->p = add(sp->c, scale(s->n, sp->r)); /* on the sphere, not origin + t dir's rounding */
        s->albedo = sp->albedo;
    } else if (h && h->instance != BVH_INVALID) {
        const mesh *m = &w->meshes[h->id];
        const float *x = w->instances[h->instance].transform;
        bvh_hit local = {h->t, h->u, h->v, h->prim};
        bvh_vec3 q; /* the point from the barycentrics in object space, then moved to the world */
        bvh_hit_surface(&m->tris, &local, &q, NULL);
        s->p = v3(x[0] * q.x + x[1] * q.y + x[2] * q.z + x[3], x[4] * q.x + x[5] * q.y + x[6] * q.z + x[7],
                  x[8] * q.x + x[9] * q.y + x[10] * q.z + x[11]);
        s->n = h->normal; /* geometric, world space, unit (zero for a zero-area triangle) */
        if (dot(s->n, s->n) == 0.0f) s->n = scale(ray->dir, -1.0f / sqrtf(dot(ray->dir, ray->dir)));
        s->albedo = m->albedo;
    } else {
        return 0;
    }
    if (dot(s->n, ray->dir) > 0.0f) s->n = scale(s->n, -1.0f); /* two-sided surfaces */
    return 1;
}

/* The closest hit among instances and spheres, given the device's hit h of the ray in the
   scene without spheres: the spheres are tested here. A sphere must be nearer than h->t: at an
   equal t the triangle wins, as in the CPU's scene, where the spheres are the last instance. */
static int resolve(const world *w, bvh_ray ray, const bvh_scene_hit *h, surface *s) {
    bvh_hit sh;
    ray.tmax = h->t; /* the scene's hit, or the ray's tmax on a miss */
    if (bvh_intersect_custom(&w->sphere_tree, &ray, &sh, &w->sphere_test) && sh.t < h->t)
        return surface_at(w, &ray, NULL, sh.prim, sh.t, s);
    return surface_at(w, &ray, h, BVH_INVALID, 0.0f, s);
}

/* PCG hash (Jarzynski & Olano 2020): a well-mixed number from the previous one. */
static uint32_t hash(uint32_t x) {
    uint32_t s = x * 747796405u + 2891336453u, w = ((s >> ((s >> 28) + 4u)) ^ s) * 277803737u;
    return (w >> 22) ^ w;
}
static float rand01(uint32_t *state) { return (float)((*state = hash(*state)) >> 8) * (1.0f / 16777216.0f); }

/* A direction around n with density cos / pi (Malley's method; basis of Duff et al. 2017). */
static bvh_vec3 cosine_dir(bvh_vec3 n, uint32_t *rng) {
    float sign = copysignf(1.0f, n.z), a = -1.0f / (sign + n.z), b = n.x * n.y * a;
    bvh_vec3 t = v3(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    bvh_vec3 u = v3(b, sign + n.y * n.y * a, -n.y);
    float phi = 2.0f * PI * rand01(rng), r2 = rand01(rng), r = sqrtf(r2);
    return normalize(add(add(scale(t, r * cosf(phi)), scale(u, r * sinf(phi))), scale(n, sqrtf(1.0f - r2))));
}

static const bvh_vec3 SUN_DIR = {0.45f, 0.75f, 0.3f}; /* toward the sun (normalised in main) */
static const bvh_vec3 SUN = {1.3f, 1.2f, 1.05f};      /* its irradiance / pi */
static bvh_vec3 sky(bvh_vec3 d) {                     /* pale at the horizon, blue above, dim below */
    float y = fmaxf(d.y, 0.0f);
    return d.y < 0 ? v3(0.1f, 0.09f, 0.08f) : add(scale(v3(0.6f, 0.65f, 0.7f), 1 - y), scale(v3(0.2f, 0.35f, 0.7f), y));
}

/* A path meets surface s. Lambertian: BRDF albedo / pi; with cosine sampling the path weight T
   gains the albedo. Returns 1 when the sun lights the side the ray came from: *shadow is the ray
   toward it, whose light is *light unless something hides the sun. *ray becomes the next bounce. */
static int scatter(const surface *s, bvh_vec3 sun_dir, bvh_ray *ray, bvh_vec3 *T, uint32_t *rng, bvh_ray *shadow,
                   bvh_vec3 *light) {
    float c = dot(s->n, sun_dir);
    *T = mul(*T, s->albedo);
    *shadow = (bvh_ray){bvh_offset_origin(s->p, s->n), 0.0f, sun_dir, BVH_INF};
    *light = scale(mul(*T, SUN), c);
    *ray = *shadow;
    ray->dir = cosine_dir(s->n, rng);
    return c > 0.0f;
}

typedef struct embree_world embree_world; /* the scene on Embree (BVH_HAVE_EMBREE), below */
#define PAIR_BANDS 16                     /* --embree on the CPU: bands of rows rendered by each tracer in turn */

typedef struct job {
    const world *w;
    const embree_world *embree; /* NULL: trace with bvh.h */
    bvh_camera cam;
    bvh_vec3 sun_dir;
    uint32_t spp, depth;
    uint8_t *rgb;
    uint32_t row_begin, row_end; /* the rows to render (render_cpu) */
    atomic_uint next_row;        /* rows are handed out one at a time: busy threads take fewer */
} job;
typedef struct worker {
    job *job;
    uint64_t rays;
    pthread_t thread;
} worker;

#ifdef BVH_HAVE_EMBREE
static int embree_trace(const embree_world *e, const world *w, bvh_ray ray, surface *s);
static int embree_occluded(const embree_world *e, const bvh_ray *ray);
#endif

/* The surface the ray meets first (0: none), traced by bvh.h or by Embree. */
static int trace(const job *j, bvh_ray ray, surface *s) {
    bvh_scene_hit h;
#ifdef BVH_HAVE_EMBREE
    if (j->embree) return embree_trace(j->embree, j->w, ray, s);
#endif
    if (!bvh_scene_intersect(&j->w->cpu, &ray, ~0u, &h)) return 0;
    if (h.instance == j->w->instance_count) return surface_at(j->w, &ray, NULL, h.prim, h.t, s);
    return surface_at(j->w, &ray, &h, BVH_INVALID, 0.0f, s);
}
/* 1 when something lies on the ray (instances or spheres). */
static int occluded(const job *j, const bvh_ray *ray) {
#ifdef BVH_HAVE_EMBREE
    if (j->embree) return embree_occluded(j->embree, ray);
#endif
    return bvh_scene_occluded(&j->w->cpu, ray, ~0u);
}

/* One path: up to `depth` diffuse hits, each lit by the sun through a shadow ray. */
static bvh_vec3 radiance(const job *j, bvh_ray ray, uint32_t *rng, uint64_t *rays) {
    bvh_vec3 L = {0, 0, 0}, T = {1, 1, 1}, light;
    bvh_ray shadow;
    uint32_t d;
    for (d = 0; d < j->depth; d++) {
        surface s;
        ++*rays;
        if (!trace(j, ray, &s)) return add(L, mul(T, sky(ray.dir)));
        if (!scatter(&s, j->sun_dir, &ray, &T, rng, &shadow, &light)) continue;
        ++*rays;
        if (!occluded(j, &shadow)) L = add(L, light);
    }
    return L;
}

static uint8_t to_srgb8(float x) { /* a soft shoulder (1 - e^-x, no hard clipping), then gamma 2.2 */
    return (uint8_t)(255.0f * powf(1.0f - expf(-1.2f * fmaxf(x, 0.0f)), 1.0f / 2.2f) + 0.5f);
}

/* Sample k of pixel i (= y * width + x): the jittered camera ray, and in *rng the start of the
   sample's own sequence, so that the image does not depend on who renders it. */
static bvh_ray camera_ray(const job *j, size_t i, uint32_t k, uint32_t *rng) {
    const bvh_camera *cam = &j->cam;
    uint32_t x = (uint32_t)(i % cam->width), y = (uint32_t)(i / cam->width);
    float sx, sy;
    *rng = hash((uint32_t)i * j->spp + k);
    sx = 2.0f * ((float)x + rand01(rng)) / (float)cam->width - 1.0f;
    sy = 1.0f - 2.0f * ((float)y + rand01(rng)) / (float)cam->height;
    return (bvh_ray){cam->eye, 0.0f, normalize(add(cam->forward, add(scale(cam->right, sx), scale(cam->up, sy)))),
                     BVH_INF};
}
static void put_pixel(job *j, size_t i, bvh_vec3 sum) { /* sum: the pixel's samples, added in order */
    sum = scale(sum, 1.0f / (float)j->spp);
    j->rgb[3 * i] = to_srgb8(sum.x);
    j->rgb[3 * i + 1] = to_srgb8(sum.y);
    j->rgb[3 * i + 2] = to_srgb8(sum.z);
}

static void *render_rows(void *arg) {
    worker *wk = arg;
    job *j = wk->job;
    uint32_t y, x, k;
    while ((y = atomic_fetch_add(&j->next_row, 1)) < j->row_end) {
        for (x = 0; x < j->cam.width; x++) {
            size_t i = (size_t)y * j->cam.width + x;
            bvh_vec3 sum = {0, 0, 0};
            for (k = 0; k < j->spp; k++) {
                uint32_t rng;
                bvh_ray ray = camera_ray(j, i, k, &rng);
                sum = add(sum, radiance(j, ray, &rng, &wk->rays));
            }
            put_pixel(j, i, sum);
        }
    }
    return NULL;
}

/* ---- the same renderer on Embree 3 ------------------------------------------------------------ */
/* --embree renders the image a second time on the CPU with Embree 3 tracing the rays, everything
   else (camera, random sequences, shading) the same code: an RTCScene of one triangle geometry per
   mesh, a top RTCScene of Embree's own instances (RTC_GEOMETRY_TYPE_INSTANCE, the same 3x4
   transforms, nothing baked) plus the spheres as one user geometry (hit_sphere in Embree's
   callbacks), rtcIntersect1 / rtcOccluded1, RTC_BUILD_QUALITY_MEDIUM (Embree's default). Its hit
   becomes the record surface_at takes, as bvh.h's: instance, triangle, t, u, v (the same
   barycentric convention), Ng taken to the world as bvh.h does its normal. */
#ifdef BVH_HAVE_EMBREE
#include <embree3/rtcore.h>
#define RTC_VERSION_STRING_OR_NONE RTC_VERSION_STRING

struct embree_world {
    RTCDevice device;
    RTCScene top;     /* geometry i: instance i; geometry instance_count: the spheres */
    RTCScene *meshes; /* per mesh; NULL for a mesh without triangles */
    uint32_t mesh_count;
};

static void embree_sphere_bounds(const struct RTCBoundsFunctionArguments *a) {
    const sphere *s = (const sphere *)a->geometryUserPtr + a->primID;
    struct RTCBounds *b = a->bounds_o;
    b->lower_x = s->c.x - s->r, b->lower_y = s->c.y - s->r, b->lower_z = s->c.z - s->r;
    b->upper_x = s->c.x + s->r, b->upper_y = s->c.y + s->r, b->upper_z = s->c.z + s->r;
}
static bvh_ray from_embree(const struct RTCRay *r) {
    return (bvh_ray){{r->org_x, r->org_y, r->org_z}, r->tnear, {r->dir_x, r->dir_y, r->dir_z}, r->tfar};
}
/* rtcIntersect1 / rtcOccluded1 call these with N = 1: the ray is a plain RTCRayHit / RTCRay. */
static void embree_sphere_intersect(const struct RTCIntersectFunctionNArguments *a) {
    struct RTCRayHit *rh = (struct RTCRayHit *)a->rayhit;
    bvh_ray ray = from_embree(&rh->ray);
    bvh_hit h;
    if (a->N != 1 || !a->valid[0] || !hit_sphere(&ray, a->primID, a->geometryUserPtr, &h)) return;
    rh->ray.tfar = h.t;
    rh->hit.Ng_x = rh->hit.Ng_y = rh->hit.Ng_z = 0.0f; /* surface_at finds it from the centre */
    rh->hit.u = rh->hit.v = 0.0f;
    rh->hit.primID = a->primID;
    rh->hit.geomID = a->geomID;
    rh->hit.instID[0] = a->context->instID[0];
}
static void embree_sphere_occluded(const struct RTCOccludedFunctionNArguments *a) {
    struct RTCRay *r = (struct RTCRay *)a->ray;
    bvh_ray ray = from_embree(r);
    bvh_hit h;
    if (a->N == 1 && a->valid[0] && hit_sphere(&ray, a->primID, a->geometryUserPtr, &h)) r->tfar = -INFINITY;
}

static void embree_free(embree_world *e) {
    uint32_t i;
    if (e->top) rtcReleaseScene(e->top);
    for (i = 0; e->meshes && i < e->mesh_count; i++)
        if (e->meshes[i]) rtcReleaseScene(e->meshes[i]);
    free(e->meshes);
    if (e->device) rtcReleaseDevice(e->device);
}

/* w's meshes, instances and spheres on Embree, built with `threads` threads. 0, or 1 (err). */
static int embree_build(embree_world *e, const world *w, uint32_t threads, enum RTCBuildQuality quality, char *err,
                        size_t errlen) {
    char config[32];
    uint32_t i, k;
    enum RTCError code;
    snprintf(config, sizeof config, "threads=%u", threads);
    memset(e, 0, sizeof *e);
    e->device = rtcNewDevice(config);
    if (!e->device) return snprintf(err, errlen, "rtcNewDevice: error %d", (int)rtcGetDeviceError(NULL)), 1;
    e->meshes = calloc(w->mesh_count ? w->mesh_count : 1, sizeof *e->meshes);
    if (!e->meshes) return snprintf(err, errlen, "out of memory"), 1;
    e->mesh_count = w->mesh_count;
    for (i = 0; i < w->mesh_count; i++) { /* one scene of one triangle geometry per mesh */
        const bvh_triangles *t = &w->meshes[i].tris;
        RTCGeometry g;
        float *v;
        uint32_t *x;
        if (!w->meshes[i].built) continue;
        g = rtcNewGeometry(e->device, RTC_GEOMETRY_TYPE_TRIANGLE);
        v = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                    t->vertex_count);
        x = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t),
                                    t->triangle_count);
        if (!v || !x) return rtcReleaseGeometry(g), snprintf(err, errlen, "Embree: out of memory"), 1;
        memcpy(v, t->positions, 3 * sizeof(float) * t->vertex_count); /* stride 0: packed */
        for (k = 0; k < 3 * t->triangle_count; k++) x[k] = t->indices ? t->indices[k] : k;
        rtcCommitGeometry(g);
        e->meshes[i] = rtcNewScene(e->device);
        rtcSetSceneBuildQuality(e->meshes[i], quality);
        rtcAttachGeometry(e->meshes[i], g);
        rtcReleaseGeometry(g);
        rtcCommitScene(e->meshes[i]);
    }
    e->top = rtcNewScene(e->device);
    rtcSetSceneBuildQuality(e->top, RTC_BUILD_QUALITY_MEDIUM);
    for (i = 0; i < w->instance_count; i++) { /* Embree's instances: geometry i is instance i */
        RTCGeometry g = rtcNewGeometry(e->device, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(g, e->meshes[w->instances[i].id]);
        rtcSetGeometryTransform(g, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, w->instances[i].transform);
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(e->top, g, i);
        rtcReleaseGeometry(g);
    }
    {
        RTCGeometry g = rtcNewGeometry(e->device, RTC_GEOMETRY_TYPE_USER);
        rtcSetGeometryUserPrimitiveCount(g, SPHERES);
        rtcSetGeometryUserData(g, (void *)w->spheres);
        rtcSetGeometryBoundsFunction(g, embree_sphere_bounds, NULL);
        rtcSetGeometryIntersectFunction(g, embree_sphere_intersect);
        rtcSetGeometryOccludedFunction(g, embree_sphere_occluded);
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(e->top, g, w->instance_count);
        rtcReleaseGeometry(g);
    }
    rtcCommitScene(e->top);
    code = rtcGetDeviceError(e->device);
    return code != RTC_ERROR_NONE ? (snprintf(err, errlen, "Embree: error %d", (int)code), 1) : 0;
}

static struct RTCRay to_embree(const bvh_ray *r) {
    struct RTCRay e = {0};
    e.org_x = r->origin.x, e.org_y = r->origin.y, e.org_z = r->origin.z, e.tnear = r->tmin;
    e.dir_x = r->dir.x, e.dir_y = r->dir.y, e.dir_z = r->dir.z, e.tfar = r->tmax;
    e.mask = ~0u;
    return e;
}

static int embree_trace(const embree_world *e, const world *w, bvh_ray ray, surface *s) {
    struct RTCIntersectContext context;
    struct RTCRayHit rh;
    bvh_scene_hit h;
    const float *inv;
    double n[3], l;
    uint32_t k;
    rtcInitIntersectContext(&context);
    rh.ray = to_embree(&ray);
    rh.hit.geomID = rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(e->top, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return 0;
    if (rh.hit.instID[0] == RTC_INVALID_GEOMETRY_ID) /* the spheres are the top scene's own geometry */
        return surface_at(w, &ray, NULL, rh.hit.primID, rh.ray.tfar, s);
    h.t = rh.ray.tfar, h.u = rh.hit.u, h.v = rh.hit.v;
    h.instance = rh.hit.instID[0];
    h.id = w->instances[h.instance].id;
    h.prim = rh.hit.primID;
    /* Ng is in the instance's space: to the world by M^-T, in double, normalised (as bvh.h) */
    inv = w->scene.inverse + 12 * (size_t)h.instance;
    for (k = 0; k < 3; k++)
        n[k] = (double)inv[k] * rh.hit.Ng_x + (double)inv[4 + k] * rh.hit.Ng_y + (double)inv[8 + k] * rh.hit.Ng_z;
    l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    h.normal = l > 0.0 ? v3((float)(n[0] / l), (float)(n[1] / l), (float)(n[2] / l)) : v3(0, 0, 0);
    return surface_at(w, &ray, &h, BVH_INVALID, 0.0f, s);
}
static int embree_occluded(const embree_world *e, const bvh_ray *ray) {
    struct RTCIntersectContext context;
    struct RTCRay r = to_embree(ray);
    rtcInitIntersectContext(&context);
    rtcOccluded1(e->top, &context, &r);
    return r.tfar < 0.0f; /* -inf when blocked */
}
#else
#define RTC_VERSION_STRING_OR_NONE "" /* never printed: --embree is refused */
#endif

/* ---- tracing on OpenCL ---------------------------------------------------------------------- */
/* The samples of PIXELS_PER_WAVE pixels (at least one pixel's) are paths that advance together:
   one device batch of their rays per bounce, then one of the shadow rays of those that hit. */
#define PATHS_PER_WAVE (1u << 18)

typedef struct path {
    bvh_ray ray;
    bvh_vec3 L, T, light; /* light: what the pending shadow ray brings if the sun is not hidden */
    uint32_t rng;
} path;

typedef struct wave {
    bvh_cl_context *ctx;
    bvh_cl_scene *dev;
    double kernel_ms; /* the device's time in the kernels, summed */
    path *paths;
    bvh_ray *rays;
    bvh_scene_hit *hits;
    uint8_t *occluded;
    uint32_t *live; /* the paths still tracing, then those with a shadow ray */
} wave;

/* The paths of one wave: pixel i0 onwards, `count` paths (whole pixels). 0, or 1 after an
   OpenCL error (said on stderr). */
static int trace_wave(job *j, wave *v, size_t i0, uint32_t count, uint64_t *rays) {
    const uint32_t lit = 0x80000000u; /* a path number with this bit has a shadow ray pending */
    const world *w = j->w;
    uint32_t n = count, m, ns, p, d, k;
    bvh_cl_result r = BVH_CL_SUCCESS;
    for (p = 0; p < count; p++) {
        path *q = &v->paths[p];
        q->ray = camera_ray(j, i0 + p / j->spp, p % j->spp, &q->rng);
        q->L = v3(0, 0, 0);
        q->T = v3(1, 1, 1);
        v->live[p] = p;
    }
    for (d = 0; d < j->depth && n && r == BVH_CL_SUCCESS; d++) {
        for (k = 0; k < n; k++) v->rays[k] = v->paths[v->live[k]].ray;
        r = bvh_cl_scene_intersect(v->dev, v->rays, ~0u, v->hits, n);
        v->kernel_ms += bvh_cl_last_kernel_ms(v->ctx);
        *rays += n;
        for (k = m = ns = 0; k < n && r == BVH_CL_SUCCESS; k++) { /* as radiance(), path by path */
            path *q = &v->paths[v->live[k]];
            surface s;
            bvh_ray shadow;
            if (!resolve(w, q->ray, &v->hits[k], &s)) {
                q->L = add(q->L, mul(q->T, sky(q->ray.dir)));
                continue; /* the path ends */
            }
            if (scatter(&s, j->sun_dir, &q->ray, &q->T, &q->rng, &shadow, &q->light)) {
                v->rays[ns++] = shadow; /* the shadow rays in the order of their paths */
                v->live[m++] = v->live[k] | lit;
            } else {
                v->live[m++] = v->live[k];
            }
        }
        n = m;
        if (ns && r == BVH_CL_SUCCESS) {
            r = bvh_cl_scene_occluded(v->dev, v->rays, ~0u, v->occluded, ns);
            v->kernel_ms += bvh_cl_last_kernel_ms(v->ctx);
        }
        *rays += ns;
        for (k = ns = 0; k < n && r == BVH_CL_SUCCESS; k++) {
            path *q = &v->paths[v->live[k] & ~lit];
            if (!(v->live[k] & lit)) continue;
            if (!v->occluded[ns] && !bvh_occluded_custom(&w->sphere_tree, &v->rays[ns], &w->sphere_test))
                q->L = add(q->L, q->light);
            ns++;
            v->live[k] &= ~lit;
        }
    }
    if (r != BVH_CL_SUCCESS) return fprintf(stderr, "pathtrace: OpenCL: %s\n", bvh_cl_result_string(r)), 1;
    for (p = 0; p < count; p += j->spp) { /* each pixel's samples in order, as render_rows adds them */
        bvh_vec3 sum = {0, 0, 0};
        for (k = 0; k < j->spp; k++) sum = add(sum, v->paths[p + k].L);
        put_pixel(j, i0 + p / j->spp, sum);
    }
    return 0;
}

/* The whole image on the device, wave after wave. 0, or 1 (said on stderr). */
static int render_opencl(job *j, bvh_cl_context *ctx, bvh_cl_scene *dev, uint64_t *rays, double *kernel_ms) {
    size_t pixels = (size_t)j->cam.width * j->cam.height, i, per = PATHS_PER_WAVE / j->spp;
    uint32_t n;
    wave v = {ctx, dev, 0.0, NULL, NULL, NULL, NULL, NULL};
    int rc = 0;
    if (per == 0) per = 1;
    n = (uint32_t)(per * j->spp);
    v.paths = malloc(n * sizeof *v.paths);
    v.rays = malloc(n * sizeof *v.rays);
    v.hits = malloc(n * sizeof *v.hits);
    v.occluded = malloc(n);
    v.live = malloc(n * sizeof *v.live);
    if (!v.paths || !v.rays || !v.hits || !v.occluded || !v.live) rc = 1, fprintf(stderr, "pathtrace: out of memory\n");
    for (i = 0; i < pixels && !rc; i += per)
        rc = trace_wave(j, &v, i, (uint32_t)((pixels - i < per ? pixels - i : per) * j->spp), rays);
    free(v.paths), free(v.rays), free(v.hits), free(v.occluded), free(v.live);
    *kernel_ms = v.kernel_ms;
    return rc;
}

/* The device ($BVH_CL_DEVICE or the first) with the scene on it. 0: ready; 1: OpenCL cannot be
   used, said on stderr (an error when `required`, else a note: the caller renders on the CPU). */
static int open_device(const world *w, int required, bvh_cl_context **ctx, bvh_cl_scene **dev, char *name, size_t len) {
    char log[1024] = "";
    bvh_cl_desc desc = {0};
    bvh_cl_device_info info;
    bvh_cl_result r;
    bvh_ray ray = {{0, 0, 0}, 0.0f, {0, 0, 1}, BVH_INF};
    bvh_scene_hit hit;
    uint8_t blocked;
    size_t i;
    desc.log = log;
    desc.log_size = sizeof log;
    r = bvh_cl_create(ctx, &desc);
    if (r == BVH_CL_SUCCESS) r = bvh_cl_scene_upload(*ctx, &w->scene, dev);
    if (r == BVH_CL_SUCCESS) r = bvh_cl_get_info(*ctx, &info);
    /* a first launch of each kernel: a driver may finish compiling it only then (PoCL does) */
    if (r == BVH_CL_SUCCESS) r = bvh_cl_scene_intersect(*dev, &ray, ~0u, &hit, 1);
    if (r == BVH_CL_SUCCESS) r = bvh_cl_scene_occluded(*dev, &ray, ~0u, &blocked, 1);
    if (r == BVH_CL_SUCCESS) {
        snprintf(name, len, "%s%s", info.device, info.exact ? ", exact: the CPU's hits" : "");
        return 0;
    }
    for (i = 0; log[i]; i++) /* one line, even with a compiler's log */
        if (log[i] == '\n' || log[i] == '\r') log[i] = ' ';
    fprintf(stderr, "pathtrace: %sOpenCL cannot be used (%s%s%s)%s\n", required ? "--trace opencl: " : "",
            bvh_cl_result_string(r), log[0] ? ": " : "", log, required ? "" : ": rendering on the CPU");
    bvh_cl_scene_free(*dev);
    bvh_cl_destroy(*ctx);
    *dev = NULL;
    *ctx = NULL;
    return 1;
}

/* The view of the scene's box b: from above, looking down at its centre; or, with --inside (for
   interiors such as Sponza's atrium), rays.h's interior view (bvhbench --camera inside has the
   same). Vertical fov 60; right and up scaled by tan(fov / 2), as bvh_camera_standard's. */
static bvh_camera view(bvh_aabb b, int inside, uint32_t width, uint32_t height) {
    bvh_vec3 c = bvh_aabb_centroid(b), d = sub(b.max, b.min), f, r;
    float th = tanf(PI / 6);
    bvh_camera cam;
    if (inside) return rays_camera_inside(b, width, height);
    f = v3(-0.35f, -1.0f, -0.6f);
    cam.eye = sub(c, scale(normalize(f), 0.75f * sqrtf(dot(d, d))));
    cam.forward = f = normalize(f);
    r = normalize(v3(-f.z, 0.0f, f.x)); /* forward x (0, 1, 0) */
    cam.right = scale(r, th * (float)width / (float)height);
    cam.up = scale(v3(r.y * f.z - r.z * f.y, r.z * f.x - r.x * f.z, r.x * f.y - r.y * f.x), th); /* right x forward */
    cam.width = width;
    cam.height = height;
    return cam;
}

/* ---- main ----------------------------------------------------------------------------------- */
/* The meshes' builder by default: a path tracer traces one scene for many samples, so the best
   trees (README's builder guide) repay their longer build. */
#define PATHTRACE_BUILDER "sah-midpoint+opt"
#define PATHTRACE_OPT_ROUNDS 8 /* +opt: the optimizer's rounds, as bvhbench's <builder>+opt rows */
/* "NAME" or "NAME+opt" into w's builder and optimizer rounds; 0, or 1 for an unknown name. */
static int parse_builder(const char *v, world *w) {
    char name[64];
    size_t n = strlen(v);
    const int opt = n > 4 && !strcmp(v + n - 4, "+opt");
    if (n >= sizeof name) return 1;
    memcpy(name, v, n + 1);
    if (opt) name[n - 4] = '\0';
    w->optimize = opt ? PATHTRACE_OPT_ROUNDS : 0;
    return bvh_builder_from_name(name, &w->builder) != BVH_SUCCESS;
}
static int usage(void) {
    printf("usage: pathtrace [SCENE] [--spp N] [--depth D] [--size WxH] [--out FILE] [--threads N] [--inside]\n"
           "                 [--trace cpu|opencl|auto] [--add MODEL] [--builder B] [--embree [--embree-high]]\n"
           "                 [--json]\n"
           "  SCENE        a glTF/GLB, OBJ... file (assimp); none: the built-in scene\n"
           "  --spp N      samples per pixel (default 16)\n"
           "  --depth D    diffuse hits per path (default 4)\n"
           "  --size WxH   image size (default 640x480)\n"
           "  --out FILE   .png or .ppm (default pathtrace.png, or .ppm without PNG support)\n"
           "  --threads N  (default: all CPUs; the image is the same for any N)\n"
           "  --inside     view from inside the scene's box (interiors), not from above\n"
           "  --trace B    cpu (default), opencl (the same image; the spheres and the shading on\n"
           "               the host), or auto (opencl when a device can be used, else cpu)\n"
           "  --add MODEL  %u instances of MODEL (e.g. a bunny) standing in the scene\n"
           "  --builder B  the meshes' trees: a builder's name, +opt for the tree optimizer (default\n"
           "               sah-midpoint+opt: the best trees, for a scene traced many times over)\n"
           "  --embree     then the same image again on the CPU, the rays traced by Embree 3 (its\n"
           "               own instances, the spheres a user geometry, build quality medium = its\n"
           "               default; --embree-high: high, spatial splits) on as many threads, the two\n"
           "               in turns by bands of rows: both Mrays/s, their ratio (bvh.h / Embree)\n"
           "               and the images' mean absolute difference (0..1); --out is bvh.h's image%s\n"
           "  --json       print one JSON line instead of the report: instances, meshes, triangles\n"
           "               (in the meshes), instanced_triangles, builder, spp, rays, ms, mrays and with\n"
           "               --embree embree_quality, embree_rays, embree_ms, embree_mrays, ratio, image_diff\n"
           "exit status: 0 done, 1 error, 2 bad command line\n",
           ADD_COPIES,
#ifdef BVH_HAVE_EMBREE
           ""
#else
           "\n               (this build has no Embree: --embree is an error)"
#endif
    );
    return 0;
}

/* Renders j's rows on `threads` threads (the caller's is one of them); the rays traced, added to
 *rays. */
static void render_cpu(job *j, worker *wk, uint32_t threads, uint64_t *rays) {
    uint32_t i;
    atomic_init(&j->next_row, j->row_begin);
    for (i = 0; i < threads; i++) {
        wk[i].job = j;
        wk[i].rays = 0;
        if (i > 0 && pthread_create(&wk[i].thread, NULL, render_rows, &wk[i]) != 0) threads = i; /* fewer */
    }
    render_rows(&wk[0]); /* the main thread is worker 0 */
    for (i = 0; i < threads; i++) {
        if (i > 0) pthread_join(wk[i].thread, NULL);
        *rays += wk[i].rays;
    }
}

/* s as a JSON string's contents (quotes and backslashes escaped, control characters dropped). */
static void json_string(const char *s) {
    for (; *s; s++)
        if (*s == '"' || *s == '\\')
            printf("\\%c", *s);
        else if ((unsigned char)*s >= 0x20)
            putchar(*s);
}

int main(int argc, char **argv) {
    const char *path = NULL, *extra = NULL, *out = scene_can_write_png() ? "pathtrace.png" : "pathtrace.ppm";
    uint32_t spp = 16, depth = 4, width = 640, height = 480, threads = scene_cpu_count(), i;
    char err[512];
    world w = {0};
    job *j;
    worker *wk;
    uint64_t rays = 0, embree_rays = 0, triangles = 0, instanced = 0;
    double t0, t1, t2, t3, kernel_ms = 0.0, embree_build_ms = 0.0, embree_ms = 0.0, diff = 0.0;
    double ratio_median = 0.0, ratio_min = 0.0, ratio_max = 0.0; /* --embree on the CPU */
    uint32_t bands = 0;
    bvh_result r;
    int ok = 1, inside = 0, trace = 0, embree = 0, embree_high = 0, json = 0; /* trace: 0 cpu, 1 opencl, 2 auto */
    const char *builder = PATHTRACE_BUILDER;
    bvh_cl_context *ctx = NULL;
    bvh_cl_scene *dev = NULL;
    char device[160] = "";
    parse_builder(builder, &w);
    for (i = 1; i < (uint32_t)argc; i++) { /* options with a value: "--spp 4", not "--spp=4" */
        const char *a = argv[i], *v = i + 1 < (uint32_t)argc ? argv[i + 1] : NULL;
        uint32_t *n = !strcmp(a, "--spp")       ? &spp
                      : !strcmp(a, "--depth")   ? &depth
                      : !strcmp(a, "--threads") ? &threads
                                                : NULL;
        uint32_t hi = n == &spp ? 65536 : n == &depth ? 64 : 256; /* n's largest value */
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) return usage();
        if (!strcmp(a, "--inside"))
            inside = 1;
        else if (!strcmp(a, "--embree"))
            embree = 1;
        else if (!strcmp(a, "--embree-high"))
            embree_high = 1;
        else if (!strcmp(a, "--json"))
            json = 1;
        else if (a[0] != '-' && !path)
            path = a;
        else if (a[0] != '-')
            return fprintf(stderr, "pathtrace: one SCENE only (see --help)\n"), 2;
        else if (!n && strcmp(a, "--size") && strcmp(a, "--out") && strcmp(a, "--trace") && strcmp(a, "--add") &&
                 strcmp(a, "--builder"))
            return fprintf(stderr, "pathtrace: unknown option '%s' (see --help)\n", a), 2;
        else if (!v)
            return fprintf(stderr, "pathtrace: %s needs a value (see --help)\n", a), 2;
        else if (n && scene_parse_u32(v, 1, hi, n, NULL))
            return fprintf(stderr, "pathtrace: %s wants 1 to %u, not '%s'\n", a, hi, v), 2;
        else if (!strcmp(a, "--size") && scene_parse_size(v, 64u << 20, &width, &height))
            return fprintf(stderr, "pathtrace: --size wants WxH (1 to 16384 each), not '%s'\n", v), 2;
        else if (!strcmp(a, "--out") && scene_check_image_path(v, err, sizeof err))
            return fprintf(stderr, "pathtrace: --out: %s\n", err), 2;
        else if (!strcmp(a, "--trace") && strcmp(v, "cpu") && strcmp(v, "opencl") && strcmp(v, "auto"))
            return fprintf(stderr, "pathtrace: --trace wants cpu, opencl or auto, not '%s'\n", v), 2;
        else if (!strcmp(a, "--trace"))
            trace = !strcmp(v, "opencl") ? 1 : !strcmp(v, "auto") ? 2 : 0, i++;
        else if (!strcmp(a, "--add"))
            extra = v, i++;
        else if (!strcmp(a, "--builder") && parse_builder(v, &w))
            return fprintf(stderr, "pathtrace: --builder wants a builder's name (+opt), not '%s'\n", v), 2;
        else if (!strcmp(a, "--builder"))
            builder = v, i++;
        else
            out = !strcmp(a, "--out") ? v : out, i++;
    }
    if (embree_high && !embree) return fprintf(stderr, "pathtrace: --embree-high goes with --embree\n"), 2;
#ifndef BVH_HAVE_EMBREE
    if (embree) return fprintf(stderr, "pathtrace: --embree: built without Embree (BVH_HAVE_EMBREE)\n"), 1;
#endif

    t0 = scene_now_ms();
    if (path ? load_file(&w, path, err, sizeof err) : load_builtin(&w, err, sizeof err)) {
        fprintf(stderr, "pathtrace: %s\n", err);
        return free_world(&w), 1;
    }
    if (extra) {
        uint32_t first = w.instance_count;
        if (load_file(&w, extra, err, sizeof err) ||
            (add_copies(&w, first) && snprintf(err, sizeof err, "out of memory"))) {
            fprintf(stderr, "pathtrace: --add: %s\n", err);
            return free_world(&w), 1;
        }
    }
    r = bvh_scene_build(&w.scene, &(bvh_scene_desc){.instances = w.instances, .instance_count = w.instance_count});
    if (r == BVH_SUCCESS && w.instance_count == 0) r = BVH_ERROR_INVALID_GEOMETRY; /* nothing to see */
    if (r == BVH_SUCCESS) r = add_spheres(&w, bvh_tree_bounds(&w.scene.top));
    if (r == BVH_SUCCESS) r = build_cpu_scene(&w);
    if (r != BVH_SUCCESS) {
        fprintf(stderr, "pathtrace: %s: %s\n", w.instance_count ? "scene" : "no triangles", bvh_result_string(r));
        return free_world(&w), 1;
    }
    for (i = 0; i < w.mesh_count; i++) triangles += w.meshes[i].built ? w.meshes[i].tris.triangle_count : 0;
    for (i = 0; i < w.instance_count; i++) instanced += w.meshes[w.instances[i].id].tris.triangle_count;
    t1 = scene_now_ms();
    if (trace && open_device(&w, trace == 1, &ctx, &dev, device, sizeof device) && trace == 1) return free_world(&w), 1;
    t2 = scene_now_ms(); /* the kernel's build, the scene's upload, a first launch */

    j = calloc(2, sizeof *j); /* j[1]: the same job on Embree */
    wk = calloc(threads, sizeof *wk);
    if (j) j->rgb = malloc(3 * (size_t)width * height);
    if (j && embree) j[1].rgb = malloc(3 * (size_t)width * height);
    if (!j || !wk || !j->rgb || (embree && !j[1].rgb)) {
        fprintf(stderr, "pathtrace: out of memory\n");
        return free(j ? j->rgb : NULL), free(j ? j[1].rgb : NULL), free(j), free(wk), bvh_cl_scene_free(dev),
               bvh_cl_destroy(ctx), free_world(&w), 1;
    }
    j->w = &w;
    j->cam = view(bvh_tree_bounds(&w.scene.top), inside, width, height);
    j->sun_dir = normalize(SUN_DIR);
    j->spp = spp;
    j->depth = depth;
    j->row_begin = 0;
    j->row_end = height;
    if (dev)
        ok = !render_opencl(j, ctx, dev, &rays, &kernel_ms);
    else if (!embree) /* with --embree: in turns with Embree, below */
        render_cpu(j, wk, threads, &rays);
    t3 = scene_now_ms();
#ifdef BVH_HAVE_EMBREE
    if (embree && ok) { /* the same job, the rays traced by Embree: only the tracer differs */
        embree_world e;
        double band_ratio[PAIR_BANDS];
        double e0 = scene_now_ms(), e1;
        uint8_t *rgb = j[1].rgb;
        size_t k, bytes = 3 * (size_t)width * height;
        uint64_t sum = 0;
        if (embree_build(&e, &w, threads, embree_high ? RTC_BUILD_QUALITY_HIGH : RTC_BUILD_QUALITY_MEDIUM, err,
                         sizeof err)) {
            fprintf(stderr, "pathtrace: --embree: %s\n", err);
            ok = 0;
        } else {
            e1 = scene_now_ms();
            embree_build_ms = e1 - e0;
            j[1] = j[0];
            j[1].rgb = rgb;
            j[1].embree = &e;
            if (dev) { /* OpenCL rendered first; Embree on the CPU after it */
                render_cpu(&j[1], wk, threads, &embree_rays);
                embree_ms = scene_now_ms() - e1;
            } else { /* band b: bvh.h then Embree when b is even, else Embree first */
                double ms[2] = {0.0, 0.0};
                uint32_t b, o;
                bands = height < PAIR_BANDS ? height : PAIR_BANDS;
                for (b = 0; b < bands; b++) {
                    double bms[2];
                    uint64_t brays[2];
                    for (o = 0; o < 2; o++) {
                        const uint32_t t = (o + b) & 1u; /* 0: bvh.h, 1: Embree */
                        uint64_t *count = t ? &embree_rays : &rays, before = *count;
                        double s0;
                        j[t].row_begin = (uint32_t)((uint64_t)height * b / bands);
                        j[t].row_end = (uint32_t)((uint64_t)height * (b + 1) / bands);
                        s0 = scene_now_ms();
                        render_cpu(&j[t], wk, threads, count);
                        bms[t] = scene_now_ms() - s0;
                        brays[t] = *count - before;
                        ms[t] += bms[t];
                    }
                    band_ratio[b] = ((double)brays[0] / bms[0]) / ((double)brays[1] / bms[1]);
                }
                t3 = t2 + ms[0];
                embree_ms = ms[1];
                ratio_median = scene_median(band_ratio, bands); /* sorts band_ratio */
                ratio_min = band_ratio[0];
                ratio_max = band_ratio[bands - 1];
            }
            for (k = 0; k < bytes; k++) sum += (uint64_t)abs((int)j[0].rgb[k] - (int)j[1].rgb[k]);
            diff = (double)sum / (255.0 * (double)bytes);
        }
        embree_free(&e);
    }
#endif

    if (json) {
        printf("{\"scene\":\"");
        json_string(path ? path : "built-in");
        printf("\",\"add\":\"");
        json_string(extra ? extra : "");
        printf("\",\"builder\":\"");
        json_string(builder);
        printf("\",\"width\":%u,\"height\":%u,\"spp\":%u,\"depth\":%u,\"threads\":%u,\"trace\":\"%s\",\"instances\":%u,"
               "\"meshes\":%u,\"triangles\":%llu,\"instanced_triangles\":%llu,\"spheres\":%u,\"build_ms\":%.1f,"
               "\"rays\":%llu,\"ms\":%.1f,\"mrays\":%.3f",
               width, height, spp, depth, dev ? 1 : threads, dev ? "opencl" : "cpu", w.instance_count, w.mesh_count,
               (unsigned long long)triangles, (unsigned long long)instanced, SPHERES, t1 - t0, (unsigned long long)rays,
               t3 - t2, (double)rays / ((t3 - t2) * 1e3));
        if (embree && embree_ms > 0.0)
            printf(",\"embree_quality\":\"%s\",\"embree_build_ms\":%.1f,\"embree_rays\":%llu,\"embree_ms\":%.1f,"
                   "\"embree_mrays\":%.3f,"
                   "\"ratio\":%.3f,\"image_diff\":%.5f",
                   embree_high ? "high" : "medium", embree_build_ms, (unsigned long long)embree_rays, embree_ms,
                   (double)embree_rays / (embree_ms * 1e3),
                   ((double)rays / (t3 - t2)) / ((double)embree_rays / embree_ms), diff);
        if (embree && bands)
            printf(",\"bands\":%u,\"ratio_bands_median\":%.3f,\"ratio_bands_min\":%.3f,\"ratio_bands_max\":%.3f", bands,
                   ratio_median, ratio_min, ratio_max);
        printf("}\n");
    } else {
        printf("pathtrace: %s: %u meshes (%llu triangles), %u instances (%llu triangles), %u spheres; load and build "
               "(%s) %.0f ms\n",
               path ? path : "built-in", w.mesh_count, (unsigned long long)triangles, w.instance_count,
               (unsigned long long)instanced, SPHERES, builder, t1 - t0);
        if (dev)
            printf("pathtrace: %ux%u, %u spp, depth %u, OpenCL on %s (set up in %.0f ms): %.0f ms (kernels %.0f ms), "
                   "%llu rays, %.2f Mrays/s\n",
                   width, height, spp, depth, device, t2 - t1, t3 - t2, kernel_ms, (unsigned long long)rays,
                   (double)rays / ((t3 - t2) * 1e3));
        else
            printf("pathtrace: %ux%u, %u spp, depth %u, %u threads: %.0f ms, %llu rays, %.2f Mrays/s\n", width, height,
                   spp, depth, threads, t3 - t2, (unsigned long long)rays, (double)rays / ((t3 - t2) * 1e3));
        if (embree && embree_ms > 0.0)
            printf("pathtrace: Embree %s (%s, built in %.0f ms), %u threads: %.0f ms, %llu rays, %.2f Mrays/s; "
                   "bvh.h / Embree %.2fx; images differ by %.4f (mean |difference| / 255)\n",
                   RTC_VERSION_STRING_OR_NONE, embree_high ? "high" : "medium", embree_build_ms, threads, embree_ms,
                   (unsigned long long)embree_rays, (double)embree_rays / (embree_ms * 1e3),
                   ((double)rays / (t3 - t2)) / ((double)embree_rays / embree_ms), diff);
        if (embree && bands)
            printf("pathtrace: rendered in turns, %u bands of rows: bvh.h / Embree per band %.2fx median (%.2f-%.2f)\n",
                   bands, ratio_median, ratio_min, ratio_max);
    }
    if (!ok) /* the device or Embree failed (said) */
        ;
    else if ((ok = !scene_write_image(out, width, height, j->rgb, err, sizeof err)) != 0) {
        if (!json) printf("pathtrace: wrote %s\n", out);
    } else {
        fprintf(stderr, "pathtrace: %s\n", err);
    }
    free(j->rgb), free(j[1].rgb), free(j), free(wk), bvh_cl_scene_free(dev), bvh_cl_destroy(ctx), free_world(&w);
    return ok ? 0 : 1;
}
