/* tests/test_scene.c - two-level scenes: instances of bottom-level trees under a top-level tree.

   Several meshes placed by instances (rotations, non-uniform scales, a mirror, a shear, far
   translations, the identity, an exact duplicate for ties, an instance of an empty tree): for every builder as
   bottom level and as top level, bvh_scene_intersect equals a brute force that walks the instances
   in order, transforms the ray into each (bvh_ray_transform with the scene's inverse, as the
   traversal does) and tests every triangle (same instance, triangle, id and bits of t, u, v;
   the normal within rounding of the one computed here); bvh_scene_occluded equals "a hit
   exists"; ray masks skip instances; the batch calls give the single-ray calls' records. Bad input
   gets its code. */
#define BVH_IMPLEMENTATION
#include "bvh.h"
#include "test_util.h"

#define MESHES 3
#define INSTANCES 24
#define SCENE_RAYS 3000

typedef struct world {
    tu_scene mesh[MESHES];
    float *tris[MESHES];
    bvh_instance inst[INSTANCES]; /* tree pointers filled per bottom-level builder */
    uint32_t mesh_of[INSTANCES];
} world;

/* Rotation about a random axis (Rodrigues) times a diagonal scale, then a translation. */
static void make_transform(tu_rng *r, float m[12], float spread) {
    bvh_vec3 a = tu_sphere_dir(r);
    float l = sqrtf(a.x * a.x + a.y * a.y + a.z * a.z), th = tu_range(r, 0.0f, 6.2831853f);
    float c = cosf(th), s = sinf(th), C = 1.0f - c, x, y, z;
    float sc[3] = {tu_range(r, 0.5f, 2.0f), tu_range(r, 0.5f, 2.0f), tu_range(r, 0.5f, 2.0f)};
    float R[9];
    int i, j;
    x = a.x / l;
    y = a.y / l;
    z = a.z / l;
    R[0] = c + x * x * C;
    R[1] = x * y * C - z * s;
    R[2] = x * z * C + y * s;
    R[3] = y * x * C + z * s;
    R[4] = c + y * y * C;
    R[5] = y * z * C - x * s;
    R[6] = z * x * C - y * s;
    R[7] = z * y * C + x * s;
    R[8] = c + z * z * C;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) m[4 * i + j] = R[3 * i + j] * sc[j];
    m[3] = tu_range(r, -spread, spread);
    m[7] = tu_range(r, -spread, spread);
    m[11] = tu_range(r, -spread, spread);
}

static void world_make(world *w) {
    tu_rng r = tu_rng_make(0x5343454e45ULL);
    uint32_t i;
    tu_scene_random(&w->mesh[0], 1200, 0x4d455348ULL);
    tu_scene_few(&w->mesh[1], 3);
    tu_scene_strided32(&w->mesh[2]); /* a height field, indexed, 32-byte vertices */
    for (i = 0; i < MESHES; i++) w->tris[i] = tu_scene_tris(&w->mesh[i]);
    memset(w->inst, 0, sizeof w->inst);
    for (i = 0; i < INSTANCES; i++) {
        w->mesh_of[i] = i % MESHES;
        make_transform(&r, w->inst[i].transform, 30.0f);
        w->inst[i].id = 1000 + i;
        w->inst[i].mask = 1u << (i % 4);
    }
    /* a mirror, a shear, a far translation (the whole scene is still traced from its own rays) */
    w->inst[3].transform[0] = -w->inst[3].transform[0];
    w->inst[3].transform[4] = -w->inst[3].transform[4];
    w->inst[3].transform[8] = -w->inst[3].transform[8];
    w->inst[4].transform[1] += 0.7f;
    w->inst[5].transform[3] += 1e4f;
    /* instances 9 and 10 are placed by the identity (the traversal keeps the world ray's set-up
       for them) */
    memset(w->inst[9].transform, 0, sizeof w->inst[9].transform);
    w->inst[9].transform[0] = w->inst[9].transform[5] = w->inst[9].transform[10] = 1.0f;
    memcpy(w->inst[10].transform, w->inst[9].transform, sizeof w->inst[9].transform);
    /* instance 7 is instance 1 again (same mesh, same transform): every hit on it ties */
    w->inst[7] = w->inst[1];
    w->mesh_of[7] = w->mesh_of[1];
    w->inst[7].id = 1007;
    w->inst[7].mask = 1u << 3;
}
static void world_free(world *w) {
    uint32_t i;
    for (i = 0; i < MESHES; i++) {
        free(w->tris[i]);
        tu_scene_free(&w->mesh[i]);
    }
}

/* The brute force: instances in order, the ray transformed as the traversal does, every
   triangle; a strictly smaller t replaces (ties: lowest instance, then lowest triangle). */
static int brute(const world *w, const bvh_scene *sc, const bvh_ray *ray, uint32_t mask, bvh_scene_hit *best) {
    bvh_ray r = *ray;
    uint32_t i;
    best->instance = best->prim = best->id = BVH_INVALID;
    best->t = ray->tmax;
    for (i = 0; i < INSTANCES; i++) {
        bvh_ray local;
        bvh_hit h;
        if (!(w->inst[i].mask & mask) || !w->inst[i].tree->node_count) continue;
        local = bvh_ray_transform(&r, sc->inverse + 12 * (size_t)i);
        if (!tu_brute(w->tris[w->mesh_of[i]], w->mesh[w->mesh_of[i]].tri_count, &local, &h)) continue;
        if (best->instance != BVH_INVALID && !(h.t < r.tmax)) continue;
        best->t = h.t;
        best->u = h.u;
        best->v = h.v;
        best->prim = h.prim;
        best->instance = i;
        best->id = w->inst[i].id;
        r.tmax = h.t;
    }
    return best->instance != BVH_INVALID;
}
/* The world normal computed here: object normal in double by the inverse transpose. */
static bvh_vec3 tri_normal(const float *t, const float *inv) {
    double e1[3], e2[3], n[3], o[3], l;
    int k;
    for (k = 0; k < 3; k++) {
        e1[k] = (double)t[3 + k] - t[k];
        e2[k] = (double)t[6 + k] - t[k];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    for (k = 0; k < 3; k++) o[k] = inv[k] * n[0] + inv[4 + k] * n[1] + inv[8 + k] * n[2];
    l = sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2]);
    return tu_v3((float)(o[0] / l), (float)(o[1] / l), (float)(o[2] / l));
}
static bvh_vec3 expected_normal(const world *w, const bvh_scene *sc, const bvh_scene_hit *h) {
    return tri_normal(w->tris[w->mesh_of[h->instance]] + 9 * (size_t)h->prim, sc->inverse + 12 * (size_t)h->instance);
}

static void make_world_rays(const world *w, const bvh_scene *sc, bvh_ray *rays, uint32_t *masks, size_t count) {
    tu_rng r = tu_rng_make(0x57524159ULL);
    bvh_aabb b;
    size_t i;
    (void)sc;
    b.min = tu_v3(-35, -35, -35); /* where the instances are (but the far one) */
    b.max = tu_v3(35, 35, 35);
    for (i = 0; i < count; i++) {
        const bvh_instance *in = &w->inst[tu_below(&r, INSTANCES)];
        bvh_vec3 target = tu_v3(in->transform[3], in->transform[7], in->transform[11]);
        rays[i].origin = tu_point_in(&r, b, 0.1f);
        rays[i].tmin = 0.0f;
        rays[i].tmax = BVH_INF;
        switch (i % 4) {
        case 0:
            rays[i].dir = tu_sphere_dir(&r);
            break;
        case 1:
            rays[i].dir = tu_sub(target, rays[i].origin);
            break; /* at an instance's origin */
        case 2:
            rays[i].dir = tu_axis_dir(&r, (int)tu_below(&r, 3));
            break;
        default:
            rays[i].dir = tu_sub(target, rays[i].origin);
            rays[i].tmax = tu_range(&r, 0.5f, 1.2f);
            break;
        }
        masks[i] = i % 3 == 0 ? ~0u : i % 3 == 1 ? (1u << tu_below(&r, 4)) : tu_u32(&r);
    }
}

static void scenes_exact(void **state) {
    static world w;
    static bvh_ray rays[SCENE_RAYS];
    static uint32_t masks[SCENE_RAYS];
    static bvh_scene_hit want[SCENE_RAYS];
    bvh_tree bottom[MESHES], empty;
    bvh_scene sc;
    bvh_scene_desc sd;
    size_t i, hits = 0, ties = 0;
    int pass;
    (void)state;
    world_make(&w);
    memset(&empty, 0, sizeof empty);
    memset(&sd, 0, sizeof sd);
    sd.instances = w.inst;
    sd.instance_count = INSTANCES;
    /* pass p < TU_BUILDER_COUNT: builder p at the bottom, the default on top; then the default at
       the bottom and each builder on top */
    for (pass = 0; pass < 2 * TU_BUILDER_COUNT; pass++) {
        bvh_builder bb = pass < TU_BUILDER_COUNT ? tu_builder(pass) : BVH_BUILDER_DEFAULT;
        bvh_builder tb = pass < TU_BUILDER_COUNT ? BVH_BUILDER_DEFAULT : tu_builder(pass - TU_BUILDER_COUNT);
        size_t bad = 0;
        uint32_t m;
        for (m = 0; m < MESHES; m++) {
            bvh_build_desc d = tu_scene_desc(&w.mesh[m], bb);
            if (pass == 1) d.trace_width = 2; /* one bottom level without the 8-wide copy */
            assert_int_equal(bvh_build(&bottom[m], &d), BVH_SUCCESS);
        }
        for (i = 0; i < INSTANCES; i++) w.inst[i].tree = &bottom[w.mesh_of[i]];
        w.inst[11].tree = &empty; /* never hit */
        sd.builder = tb;
        assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
        if (pass == 0) { /* the oracle depends on the transforms only: once */
            make_world_rays(&w, &sc, rays, masks, SCENE_RAYS);
            for (i = 0; i < SCENE_RAYS; i++) {
                hits += (size_t)brute(&w, &sc, &rays[i], masks[i], &want[i]);
                ties += want[i].instance == 1;
            }
            print_message("%zu of %d rays hit, %zu on an instance that has a twin\n", hits, SCENE_RAYS, ties);
            assert_true(hits > SCENE_RAYS / 8 && ties > 0);
        }
        for (i = 0; i < SCENE_RAYS; i++) {
            bvh_scene_hit h;
            int found = bvh_scene_intersect(&sc, &rays[i], masks[i], &h),
                occ = bvh_scene_occluded(&sc, &rays[i], masks[i]);
            int ok = found == (want[i].instance != BVH_INVALID) && occ == found && h.instance == want[i].instance &&
                     h.prim == want[i].prim && h.id == want[i].id;
            if (ok && found) {
                bvh_vec3 n = expected_normal(&w, &sc, &h);
                ok = tu_fbits(h.t) == tu_fbits(want[i].t) && tu_fbits(h.u) == tu_fbits(want[i].u) &&
                     tu_fbits(h.v) == tu_fbits(want[i].v) && fabsf(n.x - h.normal.x) < 1e-5f &&
                     fabsf(n.y - h.normal.y) < 1e-5f && fabsf(n.z - h.normal.z) < 1e-5f;
            }
            if (ok) continue;
            if (bad++ < 4) {
                print_error(
                    "bottom %s top %s ray %zu mask %x: found %d occluded %d; instance %u/%u prim %u/%u t %a/%a\n",
                    bvh_builder_name(bb), bvh_builder_name(tb), i, masks[i], found, occ, h.instance, want[i].instance,
                    h.prim, want[i].prim, (double)h.t, (double)want[i].t);
                tu_print_ray(&rays[i]);
            }
        }
        if (bad) fail_msg("bottom %s, top %s: %zu rays differ", bvh_builder_name(bb), bvh_builder_name(tb), bad);
        bvh_scene_free(&sc);
        for (m = 0; m < MESHES; m++) bvh_free(&bottom[m]);
    }
    world_free(&w);
}

/* The batch calls: for two masks and 1, 2 and 3 threads (and desc NULL), every ray's hit record
   and flag are the single-ray calls', byte for byte; bad arguments get their code. */
static void scene_batches(void **state) {
    static world w;
    static bvh_ray rays[SCENE_RAYS];
    static uint32_t masks[SCENE_RAYS];
    static bvh_scene_hit want[SCENE_RAYS], got[SCENE_RAYS];
    static uint8_t wocc[SCENE_RAYS], gocc[SCENE_RAYS];
    const uint32_t mask_of[2] = {~0u, 0x5u};
    bvh_tree bottom[MESHES];
    bvh_scene sc;
    bvh_scene_desc sd;
    bvh_batch_desc bd;
    size_t i, found = 0;
    uint32_t m, k, threads;
    (void)state;
    world_make(&w);
    for (m = 0; m < MESHES; m++) {
        bvh_build_desc d = tu_scene_desc(&w.mesh[m], BVH_BUILDER_DEFAULT);
        assert_int_equal(bvh_build(&bottom[m], &d), BVH_SUCCESS);
    }
    for (i = 0; i < INSTANCES; i++) w.inst[i].tree = &bottom[w.mesh_of[i]];
    memset(&sd, 0, sizeof sd);
    sd.instances = w.inst;
    sd.instance_count = INSTANCES;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    make_world_rays(&w, &sc, rays, masks, SCENE_RAYS);
    for (k = 0; k < 2; k++) {
        for (i = 0; i < SCENE_RAYS; i++) {
            found += (size_t)bvh_scene_intersect(&sc, &rays[i], mask_of[k], &want[i]);
            wocc[i] = (uint8_t)bvh_scene_occluded(&sc, &rays[i], mask_of[k]);
        }
        for (threads = 0; threads <= 3; threads++) {
            memset(&bd, 0, sizeof bd);
            bd.threads = threads;
            memset(got, 0xab, sizeof got);
            memset(gocc, 0xab, sizeof gocc);
            assert_int_equal(bvh_scene_intersect_batch(&sc, rays, mask_of[k], got, SCENE_RAYS, threads ? &bd : NULL),
                             BVH_SUCCESS);
            assert_int_equal(bvh_scene_occluded_batch(&sc, rays, mask_of[k], gocc, SCENE_RAYS, threads ? &bd : NULL),
                             BVH_SUCCESS);
            if (memcmp(got, want, sizeof got) != 0) fail_msg("mask %x, %u threads: other hits", mask_of[k], threads);
            if (memcmp(gocc, wocc, sizeof gocc) != 0)
                fail_msg("mask %x, %u threads: other occlusion flags", mask_of[k], threads);
        }
    }
    assert_true(found > SCENE_RAYS / 8);
    assert_int_equal(bvh_scene_intersect_batch(NULL, rays, ~0u, got, 1, NULL), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_scene_intersect_batch(&sc, NULL, ~0u, got, 1, NULL), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_scene_intersect_batch(&sc, rays, ~0u, NULL, 1, NULL), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_scene_occluded_batch(&sc, rays, ~0u, NULL, 1, NULL), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_scene_intersect_batch(&sc, NULL, ~0u, NULL, 0, NULL), BVH_SUCCESS);
    bvh_scene_free(&sc);
    for (m = 0; m < MESHES; m++) bvh_free(&bottom[m]);
    world_free(&w);
}

/* Masks: with all bits a ray sees what a scene of only its instances shows; mask 0 sees nothing. */
static void masks_select(void **state) {
    float v[9] = {-1, -1, 0, 1, -1, 0, 0, 1, 0};
    bvh_build_desc d;
    bvh_tree mesh;
    bvh_instance inst[2];
    bvh_scene_desc sd;
    bvh_scene sc;
    bvh_scene_hit h;
    bvh_ray ray = {{0, 0, -10}, 0.0f, {0, 0, 1}, BVH_INF};
    (void)state;
    memset(&d, 0, sizeof d);
    d.triangles.positions = v;
    d.triangles.vertex_count = 3;
    d.triangles.triangle_count = 1;
    assert_int_equal(bvh_build(&mesh, &d), BVH_SUCCESS);
    memset(inst, 0, sizeof inst);
    inst[0].tree = inst[1].tree = &mesh;
    inst[0].transform[0] = inst[0].transform[5] = inst[0].transform[10] = 1.0f; /* at z = 0 */
    inst[1] = inst[0];
    inst[1].transform[11] = 5.0f; /* at z = 5, behind */
    inst[0].mask = 1;
    inst[0].id = 10;
    inst[1].mask = 2;
    inst[1].id = 20;
    memset(&sd, 0, sizeof sd);
    sd.instances = inst;
    sd.instance_count = 2;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    assert_int_equal(bvh_scene_intersect(&sc, &ray, ~0u, &h), 1);
    assert_int_equal(h.id, 10);
    assert_true(h.t == 10.0f && h.normal.z == 1.0f);
    assert_int_equal(bvh_scene_intersect(&sc, &ray, 2, &h), 1);
    assert_int_equal(h.id, 20);
    assert_int_equal(h.instance, 1);
    assert_true(h.t == 15.0f);
    assert_int_equal(bvh_scene_intersect(&sc, &ray, 4, &h), 0);
    assert_int_equal(h.instance, BVH_INVALID);
    assert_int_equal(bvh_scene_intersect(&sc, &ray, 0, &h), 0);
    assert_int_equal(bvh_scene_occluded(&sc, &ray, 2), 1);
    assert_int_equal(bvh_scene_occluded(&sc, &ray, 8), 0);
    ray.tmax = 12.0f;
    assert_int_equal(bvh_scene_occluded(&sc, &ray, 2), 0);
    bvh_scene_free(&sc);
    bvh_free(&mesh);
}

static void my_free(void *p, void *user) {
    (void)user;
    free(p);
}
static void scene_errors(void **state) {
    float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    bvh_aabb box = {{0, 0, 0}, {1, 1, 1}};
    bvh_build_desc d;
    bvh_tree mesh, boxes;
    bvh_instance inst;
    bvh_scene_desc sd;
    bvh_scene sc;
    bvh_ray ray = {{0.2f, 0.2f, -1}, 0.0f, {0, 0, 1}, BVH_INF};
    bvh_custom_desc no_test = {NULL, NULL};
    (void)state;
    memset(&d, 0, sizeof d);
    d.triangles.positions = v;
    d.triangles.vertex_count = 3;
    d.triangles.triangle_count = 1;
    assert_int_equal(bvh_build(&mesh, &d), BVH_SUCCESS);
    memset(&d, 0, sizeof d);
    d.boxes = &box;
    d.box_count = 1;
    assert_int_equal(bvh_build(&boxes, &d), BVH_SUCCESS);
    memset(&inst, 0, sizeof inst);
    inst.tree = &mesh;
    inst.transform[0] = inst.transform[5] = inst.transform[10] = 1.0f;
    inst.mask = ~0u;
    memset(&sd, 0, sizeof sd);
    sd.instances = &inst;
    sd.instance_count = 1;
    assert_int_equal(bvh_scene_build(NULL, &sd), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_scene_build(&sc, NULL), BVH_ERROR_INVALID_ARGUMENT);
    sd.instances = NULL;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_ARGUMENT);
    sd.instances = &inst;
    sd.builder = BVH_BUILDER_COUNT;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_ARGUMENT);
    sd.builder = BVH_BUILDER_DEFAULT;
    sd.allocator.free = my_free;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_ARGUMENT);
    sd.allocator.free = NULL;
    inst.tree = NULL;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_ARGUMENT);
    inst.tree = &boxes; /* a box tree needs a callback */
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_ARGUMENT);
    inst.custom = &no_test; /* ... that is set */
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_ARGUMENT);
    inst.tree = &mesh; /* on a triangle tree too */
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_ARGUMENT);
    inst.custom = NULL;
    inst.tree = &mesh;
    inst.transform[10] = 0.0f; /* singular */
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_GEOMETRY);
    assert_null(sc.instances);
    inst.transform[10] = NAN;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_GEOMETRY);
    inst.transform[10] = 1.0f;
    inst.transform[3] = BVH_INF;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_GEOMETRY);
    inst.transform[3] = 0.0f;
    inst.transform[0] = inst.transform[5] = inst.transform[10] = 1e-39f; /* the inverse overflows */
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_ERROR_INVALID_GEOMETRY);
    inst.transform[0] = inst.transform[5] = inst.transform[10] = 1.0f;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    assert_int_equal(bvh_scene_intersect(&sc, &ray, ~0u, NULL), 1);
    assert_int_equal(bvh_scene_intersect(NULL, &ray, ~0u, NULL), 0);
    assert_int_equal(bvh_scene_intersect(&sc, NULL, ~0u, NULL), 0);
    bvh_scene_free(&sc);
    bvh_scene_free(NULL);
    /* zero instances: an empty scene that every ray misses */
    sd.instance_count = 0;
    assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
    assert_int_equal(bvh_scene_intersect(&sc, &ray, ~0u, NULL), 0);
    bvh_scene_free(&sc);
    bvh_free(&mesh);
    bvh_free(&boxes);
}

/* Custom primitives through instances: spheres in a tree built from boxes, placed by four
   instances (one the twin of another: every hit on it ties) among the world's triangle instances,
   and an alpha-tested instance (a callback on a triangle tree that drops every third triangle).
   For every builder at the bottom, bvh_scene_intersect equals the brute force over the instances
   in order that calls the same callbacks on every primitive (bits of t, u, v); the normal of a
   sphere hit is zero, of an alpha-tested triangle the triangle's; bvh_scene_occluded agrees. */
#define BALLS 40
#define ALL (INSTANCES + 5)
#define CUSTOM_RAYS 2000
typedef struct ball {
    float c[3], r;
} ball;
static int hit_ball(const bvh_ray *ray, uint32_t i, void *user, bvh_hit *hit) {
    const ball *b = (const ball *)user + i;
    float o[3] = {ray->origin.x - b->c[0], ray->origin.y - b->c[1], ray->origin.z - b->c[2]};
    float d[3] = {ray->dir.x, ray->dir.y, ray->dir.z};
    float a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2], hb = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
    float disc = hb * hb - a * (o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - b->r * b->r), t;
    if (!(disc >= 0.0f)) return 0;
    t = (-hb - sqrtf(disc)) / a;
    if (t < ray->tmin) t = (-hb + sqrtf(disc)) / a; /* from inside */
    if (!(t >= ray->tmin && t <= ray->tmax)) return 0;
    hit->t = t;
    hit->u = (float)i;
    hit->v = 0.25f;
    return 1;
}
static int hit_alpha(const bvh_ray *ray, uint32_t i, void *user, bvh_hit *hit) {
    const float *t = (const float *)user + 9 * (size_t)i;
    return i % 3 != 0 && bvh_intersect_triangle(ray, t, t + 3, t + 6, hit);
}
/* The brute force over all: instances in order, each transformed as the traversal does, every
   primitive through tu_brute or the instance's callback; ties: lowest instance, lowest primitive. */
static void brute_all(const world *w, const bvh_instance *all, const uint32_t *count, const bvh_scene *sc,
                      const bvh_ray *ray, uint32_t mask, bvh_scene_hit *want) {
    bvh_ray rr = *ray;
    uint32_t i, p;
    want->instance = want->prim = BVH_INVALID;
    want->t = want->u = want->v = 0.0f;
    for (i = 0; i < ALL; i++) {
        bvh_ray local;
        bvh_hit best, hh;
        int got = 0;
        memset(&best, 0, sizeof best);
        if (!(all[i].mask & mask)) continue;
        local = bvh_ray_transform(&rr, sc->inverse + 12 * (size_t)i);
        if (!all[i].custom) {
            got = tu_brute(w->tris[w->mesh_of[i]], count[i], &local, &best);
        } else
            for (p = 0; p < count[i]; p++) {
                bvh_ray lr = local;
                if (got) lr.tmax = best.t;
                if (!all[i].custom->intersect(&lr, p, all[i].custom->user, &hh) || (got && !(hh.t < best.t))) continue;
                best = hh;
                best.prim = p;
                got = 1;
            }
        if (!got || (want->instance != BVH_INVALID && !(best.t < rr.tmax))) continue;
        want->t = best.t;
        want->u = best.u;
        want->v = best.v;
        want->prim = best.prim;
        want->instance = i;
        rr.tmax = best.t;
    }
}
static void custom_instances_exact(void **state) {
    static world w;
    static bvh_ray rays[CUSTOM_RAYS];
    static uint32_t masks[CUSTOM_RAYS];
    static bvh_scene_hit want[CUSTOM_RAYS];
    static ball balls[BALLS];
    static bvh_instance all[ALL];
    bvh_aabb boxes[BALLS];
    bvh_custom_desc balls_test = {hit_ball, balls}, alpha_test;
    tu_rng r = tu_rng_make(0x42414c4cULL);
    bvh_tree bottom[MESHES], sphere_tree;
    uint32_t i, k, count[ALL];
    int b;
    (void)state;
    world_make(&w);
    for (i = 0; i < BALLS; i++) {
        for (k = 0; k < 3; k++) balls[i].c[k] = tu_range(&r, -3.0f, 3.0f);
        balls[i].r = tu_range(&r, 0.2f, 0.8f);
        for (k = 0; k < 3; k++) {
            (&boxes[i].min.x)[k] = balls[i].c[k] - balls[i].r;
            (&boxes[i].max.x)[k] = balls[i].c[k] + balls[i].r;
        }
    }
    alpha_test.intersect = hit_alpha;
    alpha_test.user = w.tris[0];
    for (i = 0; i < ALL; i++) { /* the world's instances, four of the spheres, one alpha-tested */
        if (i < INSTANCES) {
            all[i] = w.inst[i];
            count[i] = w.mesh[w.mesh_of[i]].tri_count;
            continue;
        }
        memset(&all[i], 0, sizeof all[i]);
        make_transform(&r, all[i].transform, 30.0f);
        all[i].id = 2000 + i;
        all[i].mask = ~0u;
        all[i].custom = &balls_test;
        count[i] = BALLS;
    }
    memcpy(all[INSTANCES + 2].transform, all[INSTANCES].transform, sizeof all[0].transform); /* the twin */
    all[ALL - 1].custom = &alpha_test;
    count[ALL - 1] = w.mesh[0].tri_count;
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_builder bb = tu_builder(b);
        bvh_build_desc d;
        bvh_scene_desc sd;
        bvh_scene sc;
        size_t bad = 0, on_balls = 0, on_alpha = 0, n;
        for (k = 0; k < MESHES; k++) {
            d = tu_scene_desc(&w.mesh[k], bb);
            assert_int_equal(bvh_build(&bottom[k], &d), BVH_SUCCESS);
        }
        memset(&d, 0, sizeof d);
        d.builder = bb;
        d.boxes = boxes;
        d.box_count = BALLS;
        assert_int_equal(bvh_build(&sphere_tree, &d), BVH_SUCCESS);
        for (i = 0; i < ALL; i++)
            all[i].tree = i == ALL - 1 ? &bottom[0] : all[i].custom ? &sphere_tree : &bottom[w.mesh_of[i]];
        memset(&sd, 0, sizeof sd);
        sd.instances = all;
        sd.instance_count = ALL;
        assert_int_equal(bvh_scene_build(&sc, &sd), BVH_SUCCESS);
        if (b == 0) { /* the oracle depends on the transforms only: once */
            make_world_rays(&w, &sc, rays, masks, CUSTOM_RAYS);
            for (n = 1; n < CUSTOM_RAYS; n += 2) { /* half the rays aimed at the sphere instances */
                const float *m = all[INSTANCES + n / 2 % 5].transform;
                rays[n].dir = tu_sub(tu_v3(m[3], m[7], m[11]), rays[n].origin);
                rays[n].tmax = BVH_INF;
            }
            for (n = 0; n < CUSTOM_RAYS; n++) brute_all(&w, all, count, &sc, &rays[n], masks[n], &want[n]);
        }
        for (n = 0; n < CUSTOM_RAYS; n++) {
            bvh_scene_hit h;
            int found = bvh_scene_intersect(&sc, &rays[n], masks[n], &h),
                occ = bvh_scene_occluded(&sc, &rays[n], masks[n]);
            int ok = found == (want[n].instance != BVH_INVALID) && occ == found && h.instance == want[n].instance &&
                     h.prim == want[n].prim;
            if (ok && found) {
                ok = tu_fbits(h.t) == tu_fbits(want[n].t) && tu_fbits(h.u) == tu_fbits(want[n].u) &&
                     tu_fbits(h.v) == tu_fbits(want[n].v) && h.id == all[h.instance].id;
                if (all[h.instance].tree == &sphere_tree) {
                    ok = ok && h.normal.x == 0.0f && h.normal.y == 0.0f && h.normal.z == 0.0f;
                    on_balls++;
                } else if (h.instance == ALL - 1) {
                    bvh_vec3 e = tri_normal(w.tris[0] + 9 * (size_t)h.prim, sc.inverse + 12 * (size_t)h.instance);
                    ok = ok && h.prim % 3 != 0 && fabsf(e.x - h.normal.x) < 1e-5f && fabsf(e.y - h.normal.y) < 1e-5f &&
                         fabsf(e.z - h.normal.z) < 1e-5f;
                    on_alpha++;
                }
            }
            if (ok) continue;
            if (bad++ < 4) {
                print_error("bottom %s ray %zu mask %x: found %d occluded %d; instance %u/%u prim %u/%u t %a/%a\n",
                            bvh_builder_name(bb), n, masks[n], found, occ, h.instance, want[n].instance, h.prim,
                            want[n].prim, (double)h.t, (double)want[n].t);
                tu_print_ray(&rays[n]);
            }
        }
        if (b == 0) print_message("%zu rays end on a sphere, %zu on the alpha-tested instance\n", on_balls, on_alpha);
        assert_true(on_balls > CUSTOM_RAYS / 20 && on_alpha > 0);
        if (bad) fail_msg("bottom %s: %zu rays differ", bvh_builder_name(bb), bad);
        bvh_scene_free(&sc);
        bvh_free(&sphere_tree);
        for (k = 0; k < MESHES; k++) bvh_free(&bottom[k]);
    }
    world_free(&w);
}

/* An allocator that fails from its k-th call on, and counts what is live. */
typedef struct failing {
    int left, live;
} failing;
static void *f_alloc(size_t n, void *user) {
    failing *f = (failing *)user;
    void *p;
    if (f->left-- <= 0) return NULL;
    p = malloc(n);
    f->live += p != NULL;
    return p;
}
static void f_free(void *p, void *user) {
    failing *f = (failing *)user;
    if (p) f->live--;
    free(p);
}
/* Every allocation of bvh_scene_build failing in turn: OUT_OF_MEMORY, a zeroed scene and
   nothing leaked, until it has all it needs. */
static void scene_out_of_memory(void **state) {
    float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    bvh_build_desc d;
    bvh_tree mesh;
    bvh_instance inst[40];
    bvh_scene_desc sd;
    bvh_scene sc;
    failing f;
    int k, i;
    (void)state;
    memset(&d, 0, sizeof d);
    d.triangles.positions = v;
    d.triangles.vertex_count = 3;
    d.triangles.triangle_count = 1;
    assert_int_equal(bvh_build(&mesh, &d), BVH_SUCCESS);
    memset(inst, 0, sizeof inst);
    for (i = 0; i < 40; i++) {
        inst[i].tree = &mesh;
        inst[i].transform[0] = inst[i].transform[5] = inst[i].transform[10] = 1.0f;
        inst[i].transform[3] = (float)i;
        inst[i].mask = ~0u;
    }
    memset(&sd, 0, sizeof sd);
    sd.instances = inst;
    sd.instance_count = 40;
    sd.builder = BVH_BUILDER_PLOC;
    sd.allocator.alloc = f_alloc;
    sd.allocator.free = f_free;
    sd.allocator.user = &f;
    for (k = 0;; k++) {
        bvh_result r;
        f.left = k;
        f.live = 0;
        r = bvh_scene_build(&sc, &sd);
        if (r == BVH_SUCCESS) break;
        assert_int_equal(r, BVH_ERROR_OUT_OF_MEMORY);
        assert_int_equal(f.live, 0);
        assert_null(sc.instances);
        assert_int_equal(sc.top.node_count, 0);
    }
    assert_true(k >= 3);
    bvh_scene_free(&sc);
    assert_int_equal(f.live, 0);
    bvh_free(&mesh);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(scenes_exact), cmocka_unit_test(scene_batches),
        cmocka_unit_test(masks_select), cmocka_unit_test(custom_instances_exact),
        cmocka_unit_test(scene_errors), cmocka_unit_test(scene_out_of_memory),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
