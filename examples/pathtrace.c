/* pathtrace.c - a small path tracer on bvh.h: instances of per-mesh trees, spheres as custom
   primitives, diffuse bounces, a sun with shadow rays and a sky, on all CPUs.

   build/pathtrace [SCENE] [--spp N] [--depth D] [--size WxH] [--out FILE] [--threads N] [--inside]
                   [--trace cpu|opencl|auto]
   e.g. build/pathtrace sponza.glb --inside --size 512x512 --spp 4 --out sponza.png
        build/pathtrace                       (the built-in scene: boxes on a ground quad)
        build/pathtrace --trace opencl        (the same image, the rays traced by cl/bvh_cl.h)

   The scene keeps the file's structure: one bottom-level tree per mesh (assimp's aiMesh), built
   once, and one bvh_instance per node that uses the mesh, placed by the node's world transform
   (nothing is copied into world space). bvh_scene_build puts a top-level tree over them. Three
   spheres are custom primitives: a tree over their boxes, traced by bvh_intersect_custom with a
   sphere test; the nearer of the scene's hit and the spheres' wins.
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
   used, else the CPU (said on stderr); --trace opencl without one is an error. Without assimp (BVH_HAVE_ASSIMP) a file
   is read by scene.h's OBJ reader as one mesh; without stb (BVH_HAVE_STB) the image is a .ppm. Exit status: 0 done; 1
   an error (said on stderr); 2 a bad command line. */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#define BVH_CL_IMPLEMENTATION
#include "cl/bvh_cl.h" /* without BVH_HAVE_OPENCL its calls return BVH_CL_ERROR_NOT_AVAILABLE */
#define SCENE_IMPLEMENTATION
#include "scene.h" /* image writing, clock, command-line numbers, the OBJ reader */

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
    bvh_scene scene;
    sphere spheres[SPHERES];
    bvh_tree sphere_tree;        /* built from the spheres' boxes */
    bvh_custom_desc sphere_test; /* hit_sphere on w->spheres */
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
    bvh_build_desc desc = {0}; /* the default builder: a good tree for tracing, built in parallel */
    bvh_result r;
    m->tris = (bvh_triangles){pos, 0, nv, idx, nt};
    m->albedo = albedo;
    if (nt == 0) return BVH_SUCCESS;
    desc.triangles = m->tris;
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
    if (w->instance_count == w->instance_cap) {
        uint32_t cap = w->instance_cap ? 2 * w->instance_cap : 64;
        bvh_instance *p = realloc(w->instances, cap * sizeof *p);
        if (!p) return 1;
        w->instances = p;
        w->instance_cap = cap;
    }
    w->instances[w->instance_count] = (bvh_instance){&w->meshes[i].tree, {0}, i, ~0u};
    memcpy(w->instances[w->instance_count++].transform, m, 12 * sizeof(float));
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
static int add_nodes(world *w, const struct aiNode *node, struct aiMatrix4x4 parent) {
    uint32_t k;
    aiMultiplyMatrix4(&parent, &node->mTransformation); /* parent = parent * node's own */
    for (k = 0; k < node->mNumMeshes; k++) {
        const struct aiMatrix4x4 *t = &parent; /* assimp's rows a, b, c: the 3x4 we need */
        float m[12] = {t->a1, t->a2, t->a3, t->a4, t->b1, t->b2, t->b3, t->b4, t->c1, t->c2, t->c3, t->c4};
        if (node->mMeshes[k] < w->mesh_count && add_instance(w, node->mMeshes[k], m)) return 1;
    }
    for (k = 0; k < node->mNumChildren; k++)
        if (add_nodes(w, node->mChildren[k], parent)) return 1;
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

static int load_file(world *w, const char *path, char *err, size_t errlen) {
    const struct aiScene *s = aiImportFile(path, aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                                                     aiProcess_SortByPType | aiProcess_ValidateDataStructure);
    struct aiMatrix4x4 identity;
    uint32_t i, f, n;
    int rc = 0;
    if (!s || !s->mRootNode) return snprintf(err, errlen, "cannot read '%s': %s", path, aiGetErrorString()), 1;
    w->meshes = calloc(s->mNumMeshes ? s->mNumMeshes : 1, sizeof *w->meshes);
    w->mesh_count = w->meshes ? s->mNumMeshes : 0;
    for (i = 0; i < w->mesh_count && !rc; i++) { /* one bottom-level tree per aiMesh */
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
        r = add_mesh(w, i, pos, am->mNumVertices, idx, n, material_albedo(s->mMaterials[am->mMaterialIndex]));
        if (r != BVH_SUCCESS) rc = 1, snprintf(err, errlen, "mesh %u: bvh_build: %s", i, bvh_result_string(r));
    }
    aiIdentityMatrix4(&identity);
    if (!w->meshes || (!rc && add_nodes(w, s->mRootNode, identity))) rc = 1, snprintf(err, errlen, "out of memory");
    aiReleaseImport(s);
    return rc;
}
#else
/* Without assimp: scene.h reads an OBJ file into a world-space soup, used as one mesh. */
static int load_file(world *w, const char *path, char *err, size_t errlen) {
    static const float identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    scene s;
    bvh_result r;
    if (scene_load(path, &s, err, errlen)) return 1;
    w->meshes = calloc(1, sizeof *w->meshes);
    if (!w->meshes) return scene_free(&s), snprintf(err, errlen, "out of memory"), 1;
    w->mesh_count = 1;
    r = add_mesh(w, 0, s.v, 3 * s.triangles, NULL, s.triangles, v3(0.8f, 0.8f, 0.8f)); /* s.v now the mesh's */
    if (r != BVH_SUCCESS) return snprintf(err, errlen, "bvh_build: %s", bvh_result_string(r)), 1;
    return add_instance(w, 0, identity) ? (snprintf(err, errlen, "out of memory"), 1) : 0;
}
#endif

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

static void free_world(world *w) {
    uint32_t i;
    bvh_scene_free(&w->scene);
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

/* The closest hit among instances and spheres, given the scene's hit h of the ray (by
   bvh_scene_intersect, or from the device): its point, unit normal (facing the ray), albedo. */
static int resolve(const world *w, bvh_ray ray, const bvh_scene_hit *h, surface *s) {
    bvh_hit sh;
    int hit = h->instance != BVH_INVALID;
    ray.tmax = h->t; /* the scene's hit, or the ray's tmax on a miss: a sphere must be nearer */
    if (bvh_intersect_custom(&w->sphere_tree, &ray, &sh, &w->sphere_test)) {
        const sphere *sp = &w->spheres[sh.prim];
        s->n = normalize(sub(add(ray.origin, scale(ray.dir, sh.t)), sp->c));
        s->p = add(sp->c, scale(s->n, sp->r)); /* on the sphere, not origin + t dir's rounding */
        s->albedo = sp->albedo;
    } else if (hit) {
        const mesh *m = &w->meshes[h->id];
        const float *t = w->scene.instances[h->instance].transform;
        bvh_hit local = {h->t, h->u, h->v, h->prim};
        bvh_vec3 q; /* the point from the barycentrics in object space, then moved to the world */
        bvh_hit_surface(&m->tris, &local, &q, NULL);
        s->p = v3(t[0] * q.x + t[1] * q.y + t[2] * q.z + t[3], t[4] * q.x + t[5] * q.y + t[6] * q.z + t[7],
                  t[8] * q.x + t[9] * q.y + t[10] * q.z + t[11]);
        s->n = h->normal; /* geometric, world space, unit (zero for a zero-area triangle) */
        if (dot(s->n, s->n) == 0.0f) s->n = scale(ray.dir, -1.0f / sqrtf(dot(ray.dir, ray.dir)));
        s->albedo = m->albedo;
    } else {
        return 0;
    }
    if (dot(s->n, ray.dir) > 0.0f) s->n = scale(s->n, -1.0f); /* two-sided surfaces */
    return 1;
}
static int trace(const world *w, bvh_ray ray, surface *s) {
    bvh_scene_hit h;
    bvh_scene_intersect(&w->scene, &ray, ~0u, &h);
    return resolve(w, ray, &h, s);
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

/* One path: up to `depth` diffuse hits, each lit by the sun through a shadow ray. */
static bvh_vec3 radiance(const world *w, bvh_ray ray, bvh_vec3 sun_dir, uint32_t depth, uint32_t *rng, uint64_t *rays) {
    bvh_vec3 L = {0, 0, 0}, T = {1, 1, 1}, light;
    bvh_ray shadow;
    uint32_t d;
    for (d = 0; d < depth; d++) {
        surface s;
        ++*rays;
        if (!trace(w, ray, &s)) return add(L, mul(T, sky(ray.dir)));
        if (!scatter(&s, sun_dir, &ray, &T, rng, &shadow, &light)) continue;
        ++*rays;
        if (!bvh_scene_occluded(&w->scene, &shadow, ~0u) &&
            !bvh_occluded_custom(&w->sphere_tree, &shadow, &w->sphere_test))
            L = add(L, light);
    }
    return L;
}

typedef struct job {
    const world *w;
    bvh_camera cam;
    bvh_vec3 sun_dir;
    uint32_t spp, depth;
    uint8_t *rgb;
    atomic_uint next_row; /* rows are handed out one at a time: busy threads take fewer */
} job;
typedef struct worker {
    job *job;
    uint64_t rays;
    pthread_t thread;
} worker;

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
    while ((y = atomic_fetch_add(&j->next_row, 1)) < j->cam.height) {
        for (x = 0; x < j->cam.width; x++) {
            size_t i = (size_t)y * j->cam.width + x;
            bvh_vec3 sum = {0, 0, 0};
            for (k = 0; k < j->spp; k++) {
                uint32_t rng;
                bvh_ray ray = camera_ray(j, i, k, &rng);
                sum = add(sum, radiance(j->w, ray, j->sun_dir, j->depth, &rng, &wk->rays));
            }
            put_pixel(j, i, sum);
        }
    }
    return NULL;
}

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
   interiors such as Sponza's atrium), from low near one end of its longer side, looking along it.
   Vertical fov 60; right and up scaled by tan(fov / 2), as bvh_camera_standard's. */
static bvh_camera view(bvh_aabb b, int inside, uint32_t width, uint32_t height) {
    bvh_vec3 c = bvh_aabb_centroid(b), d = sub(b.max, b.min), f, r;
    float th = tanf(PI / 6);
    bvh_camera cam;
    if (inside) {
        f = d.x > d.z ? v3(1.0f, -0.12f, 0.0f) : v3(0.0f, -0.12f, 1.0f);
        cam.eye = v3(c.x - 0.4f * f.x * d.x, b.min.y + 0.3f * d.y, c.z - 0.4f * f.z * d.z);
    } else {
        f = v3(-0.35f, -1.0f, -0.6f);
        cam.eye = sub(c, scale(normalize(f), 0.75f * sqrtf(dot(d, d))));
    }
    cam.forward = f = normalize(f);
    r = normalize(v3(-f.z, 0.0f, f.x)); /* forward x (0, 1, 0) */
    cam.right = scale(r, th * (float)width / (float)height);
    cam.up = scale(v3(r.y * f.z - r.z * f.y, r.z * f.x - r.x * f.z, r.x * f.y - r.y * f.x), th); /* right x forward */
    cam.width = width;
    cam.height = height;
    return cam;
}

/* ---- main ----------------------------------------------------------------------------------- */
static int usage(void) {
    printf("usage: pathtrace [SCENE] [--spp N] [--depth D] [--size WxH] [--out FILE] [--threads N] [--inside]\n"
           "                 [--trace cpu|opencl|auto]\n"
           "  SCENE        a glTF/GLB, OBJ... file (assimp); none: the built-in scene\n"
           "  --spp N      samples per pixel (default 16)\n"
           "  --depth D    diffuse hits per path (default 4)\n"
           "  --size WxH   image size (default 640x480)\n"
           "  --out FILE   .png or .ppm (default pathtrace.png, or .ppm without PNG support)\n"
           "  --threads N  (default: all CPUs; the image is the same for any N)\n"
           "  --inside     view from inside the scene's box (interiors), not from above\n"
           "  --trace B    cpu (default), opencl (the same image; the spheres and the shading on\n"
           "               the host), or auto (opencl when a device can be used, else cpu)\n"
           "exit status: 0 done, 1 error, 2 bad command line\n");
    return 0;
}

int main(int argc, char **argv) {
    const char *path = NULL, *out = scene_can_write_png() ? "pathtrace.png" : "pathtrace.ppm";
    uint32_t spp = 16, depth = 4, width = 640, height = 480, threads = scene_cpu_count(), i;
    char err[512];
    world w = {0};
    job *j;
    worker *wk;
    uint64_t rays = 0;
    double t0, t1, t2, t3, kernel_ms = 0.0;
    bvh_result r;
    int ok = 1, inside = 0, trace = 0; /* trace: 0 cpu, 1 opencl, 2 auto */
    bvh_cl_context *ctx = NULL;
    bvh_cl_scene *dev = NULL;
    char device[160] = "";
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
        else if (a[0] != '-' && !path)
            path = a;
        else if (a[0] != '-')
            return fprintf(stderr, "pathtrace: one SCENE only (see --help)\n"), 2;
        else if (!n && strcmp(a, "--size") && strcmp(a, "--out") && strcmp(a, "--trace"))
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
        else
            out = !strcmp(a, "--out") ? v : out, i++;
    }

    t0 = scene_now_ms();
    if (path ? load_file(&w, path, err, sizeof err) : load_builtin(&w, err, sizeof err)) {
        fprintf(stderr, "pathtrace: %s\n", err);
        return free_world(&w), 1;
    }
    r = bvh_scene_build(&w.scene, &(bvh_scene_desc){.instances = w.instances, .instance_count = w.instance_count});
    if (r == BVH_SUCCESS && w.instance_count == 0) r = BVH_ERROR_INVALID_GEOMETRY; /* nothing to see */
    if (r == BVH_SUCCESS) r = add_spheres(&w, bvh_tree_bounds(&w.scene.top));
    if (r != BVH_SUCCESS) {
        fprintf(stderr, "pathtrace: %s: %s\n", w.instance_count ? "scene" : "no triangles", bvh_result_string(r));
        return free_world(&w), 1;
    }
    t1 = scene_now_ms();
    if (trace && open_device(&w, trace == 1, &ctx, &dev, device, sizeof device) && trace == 1) return free_world(&w), 1;
    t2 = scene_now_ms(); /* the kernel's build, the scene's upload, a first launch */

    j = calloc(1, sizeof *j);
    wk = calloc(threads, sizeof *wk);
    if (j) j->rgb = malloc(3 * (size_t)width * height);
    if (!j || !wk || !j->rgb) {
        fprintf(stderr, "pathtrace: out of memory\n");
        return free(j ? j->rgb : NULL), free(j), free(wk), bvh_cl_scene_free(dev), bvh_cl_destroy(ctx), free_world(&w),
               1;
    }
    j->w = &w;
    j->cam = view(bvh_tree_bounds(&w.scene.top), inside, width, height);
    j->sun_dir = normalize(SUN_DIR);
    j->spp = spp;
    j->depth = depth;
    atomic_init(&j->next_row, 0);
    if (dev) {
        ok = !render_opencl(j, ctx, dev, &rays, &kernel_ms);
    } else {
        for (i = 0; i < threads; i++) {
            wk[i].job = j;
            if (i > 0 && pthread_create(&wk[i].thread, NULL, render_rows, &wk[i]) != 0) threads = i; /* fewer */
        }
        render_rows(&wk[0]); /* the main thread is worker 0 */
        for (i = 0; i < threads; i++) {
            if (i > 0) pthread_join(wk[i].thread, NULL);
            rays += wk[i].rays;
        }
    }
    t3 = scene_now_ms();

    printf("pathtrace: %s: %u meshes, %u instances, %u spheres; load and build %.0f ms\n", path ? path : "built-in",
           w.mesh_count, w.instance_count, SPHERES, t1 - t0);
    if (dev)
        printf("pathtrace: %ux%u, %u spp, depth %u, OpenCL on %s (set up in %.0f ms): %.0f ms (kernels %.0f ms), "
               "%llu rays, %.2f Mrays/s\n",
               width, height, spp, depth, device, t2 - t1, t3 - t2, kernel_ms, (unsigned long long)rays,
               (double)rays / ((t3 - t2) * 1e3));
    else
        printf("pathtrace: %ux%u, %u spp, depth %u, %u threads: %.0f ms, %llu rays, %.2f Mrays/s\n", width, height, spp,
               depth, threads, t3 - t2, (unsigned long long)rays, (double)rays / ((t3 - t2) * 1e3));
    if (!ok) /* the device failed (said) */
        ;
    else if ((ok = !scene_write_image(out, width, height, j->rgb, err, sizeof err)) != 0)
        printf("pathtrace: wrote %s\n", out);
    else
        fprintf(stderr, "pathtrace: %s\n", err);
    free(j->rgb), free(j), free(wk), bvh_cl_scene_free(dev), bvh_cl_destroy(ctx), free_world(&w);
    return ok ? 0 : 1;
}
