/* rays.h - the secondary rays a renderer traces, made from a primary frame's hits (examples only)

   WHAT
     One generator that build/bvhbench and build/render share, so that both trace the same two
     ray sets beside the camera's primary rays:
       diffuse  one ray per primary hit: the origin is the hit point (from the barycentrics on
                the scene's own triangle hit.prim) moved along the geometric normal by
                RAYS_OFFSET x the scene diagonal, the normal turned toward the viewer
                (dot(n, camera ray) < 0); the direction is cosine-weighted about that normal;
                tmin 0, tmax BVH_INF. Traced for the closest hit (bvh_intersect_batch).
       shadow   from the same origins toward the fixed directional light
                L = normalize(0.3, 1, 0.2) (RAYS_LIGHT_*), only for the hits that face it
                (dot(n, L) > 0: a renderer skips the others); tmin 0, tmax BVH_INF. Traced for
                any hit (bvh_occluded_batch).
     Both sets keep pixel order. A hit on a triangle without a normal (zero area) gives no ray.
     Deterministic: the random numbers of the diffuse direction are a hash of the pixel index
     and RAYS_SEED (no global state, no rand()), so the same frame gives the same bytes on any
     thread count and in both programs. The origin carries the offset, so every tracer gets
     tmin 0 (Embree's tnear included).

   HOW TO INCLUDE
     In exactly ONE .c file (which also has bvh.h's implementation, or links it):
         #define RAYS_IMPLEMENTATION
         #include "rays.h"

   EXAMPLE
         rays_set set;
         if (rays_make(&cam, hits, scene.v, bvh_tree_bounds(&tree), &set) != 0) return 1;
         bvh_intersect_batch(&tree, set.diffuse, diffuse_hits, set.ndiffuse, 0);
         bvh_occluded_batch(&tree, set.shadow, occluded, set.nshadow, 0);
         rays_free(&set);

   LICENSE
     MIT, like bvh.h.
*/
#ifndef RAYS_H_INCLUDED
#define RAYS_H_INCLUDED

#include <stddef.h>
#include <stdint.h>
#include "bvh.h"

#define RAYS_OFFSET 1e-4f /* origin offset along the normal, a fraction of the scene diagonal */
#define RAYS_SEED 0x2545F491u
#define RAYS_LIGHT_X 0.3f /* the light direction before normalisation: (0.3, 1, 0.2) */
#define RAYS_LIGHT_Y 1.0f
#define RAYS_LIGHT_Z 0.2f

typedef struct rays_set {
    bvh_ray *diffuse; /* one per primary hit (with a normal), pixel order */
    size_t ndiffuse;
    bvh_ray *shadow; /* one per primary hit whose normal faces the light, pixel order */
    size_t nshadow;
} rays_set;

/* From the w x h hits (row-major, y = 0 at the top) of camera cam's primary rays on triangles
   tris (9 floats each, indexed by hit.prim) inside bounds: both sets into *out (malloc'd; free
   with rays_free). 0 on success, 1 out of memory (*out zeroed). */
int rays_make(const bvh_camera *cam, const bvh_hit *hits, const float *tris, bvh_aabb bounds, rays_set *out);
void rays_free(rays_set *s);
/* the unit light direction of the shadow rays */
bvh_vec3 rays_light(void);
/* An interior view of the box b (Sponza's atrium, a room): the eye low near one end of the box's
   longer horizontal side, looking along it and slightly down; vertical field of view 60 degrees,
   right and up scaled as bvh_camera_standard's. build/bvhbench --camera inside and
   build/pathtrace --inside use it: rays that start inside the model and travel through it. */
bvh_camera rays_camera_inside(bvh_aabb b, uint32_t width, uint32_t height);

#endif /* RAYS_H_INCLUDED */

#ifdef RAYS_IMPLEMENTATION
#ifndef RAYS_IMPLEMENTATION_DONE
#define RAYS_IMPLEMENTATION_DONE
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* A 32-bit integer mix (xorshift-multiply rounds, the constants of Wellons' "lowbias32"). */
static uint32_t rays__hash(uint32_t x) {
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    x ^= x >> 16;
    return x;
}
/* [0, 1) from the top 24 bits */
static float rays__unit(uint32_t x) { return (float)(x >> 8) * (1.0f / 16777216.0f); }

static bvh_vec3 rays__v(float x, float y, float z) {
    bvh_vec3 v;
    v.x = x;
    v.y = y;
    v.z = z;
    return v;
}

bvh_vec3 rays_light(void) {
    float len = sqrtf(RAYS_LIGHT_X * RAYS_LIGHT_X + RAYS_LIGHT_Y * RAYS_LIGHT_Y + RAYS_LIGHT_Z * RAYS_LIGHT_Z);
    return rays__v(RAYS_LIGHT_X / len, RAYS_LIGHT_Y / len, RAYS_LIGHT_Z / len);
}

static bvh_vec3 rays__unit3(bvh_vec3 a) {
    float k = 1.0f / sqrtf(a.x * a.x + a.y * a.y + a.z * a.z);
    return rays__v(a.x * k, a.y * k, a.z * k);
}

bvh_camera rays_camera_inside(bvh_aabb b, uint32_t width, uint32_t height) {
    bvh_vec3 c = bvh_aabb_centroid(b), d = rays__v(b.max.x - b.min.x, b.max.y - b.min.y, b.max.z - b.min.z), f, r;
    float th = tanf(3.14159265f / 6);
    bvh_camera cam;
    f = d.x > d.z ? rays__v(1.0f, -0.12f, 0.0f) : rays__v(0.0f, -0.12f, 1.0f);
    cam.eye = rays__v(c.x - 0.4f * f.x * d.x, b.min.y + 0.3f * d.y, c.z - 0.4f * f.z * d.z);
    cam.forward = f = rays__unit3(f);
    r = rays__unit3(rays__v(-f.z, 0.0f, f.x)); /* forward x (0, 1, 0) */
    cam.right = rays__v(r.x * th * (float)width / (float)height, r.y * th * (float)width / (float)height,
                        r.z * th * (float)width / (float)height);
    cam.up = rays__v((r.y * f.z - r.z * f.y) * th, (r.z * f.x - r.x * f.z) * th,
                     (r.x * f.y - r.y * f.x) * th); /* right x forward */
    cam.width = width;
    cam.height = height;
    return cam;
}

/* Cosine-weighted direction about the unit normal n (Malley: a uniform point on the unit disk
   lifted to the hemisphere), in a tangent frame built from whichever axis is least along n. */
static bvh_vec3 rays__cosine(bvh_vec3 n, float r1, float r2) {
    float r = sqrtf(r1), phi = 6.28318530718f * r2, a = r * cosf(phi), b = r * sinf(phi);
    float h = sqrtf(1.0f - r1 > 0.0f ? 1.0f - r1 : 0.0f), len;
    bvh_vec3 t, s;
    if (fabsf(n.x) < 0.6f)
        t = rays__v(0.0f, n.z, -n.y); /* n x (1,0,0) */
    else
        t = rays__v(-n.z, 0.0f, n.x); /* n x (0,1,0) */
    len = sqrtf(t.x * t.x + t.y * t.y + t.z * t.z);
    t = rays__v(t.x / len, t.y / len, t.z / len);
    s = rays__v(n.y * t.z - n.z * t.y, n.z * t.x - n.x * t.z, n.x * t.y - n.y * t.x);
    return rays__v(a * t.x + b * s.x + h * n.x, a * t.y + b * s.y + h * n.y, a * t.z + b * s.z + h * n.z);
}

int rays_make(const bvh_camera *cam, const bvh_hit *hits, const float *tris, bvh_aabb bounds, rays_set *out) {
    size_t npix = (size_t)cam->width * cam->height, i;
    bvh_vec3 ext = rays__v(bounds.max.x - bounds.min.x, bounds.max.y - bounds.min.y, bounds.max.z - bounds.min.z);
    float offset = RAYS_OFFSET * sqrtf(ext.x * ext.x + ext.y * ext.y + ext.z * ext.z);
    bvh_vec3 L = rays_light();
    memset(out, 0, sizeof *out);
    for (i = 0; i < npix; i++) out->ndiffuse += hits[i].prim != BVH_INVALID;
    out->diffuse = (bvh_ray *)malloc((out->ndiffuse ? out->ndiffuse : 1) * sizeof(bvh_ray));
    out->shadow = (bvh_ray *)malloc((out->ndiffuse ? out->ndiffuse : 1) * sizeof(bvh_ray));
    out->ndiffuse = 0;
    if (!out->diffuse || !out->shadow) {
        rays_free(out);
        return 1;
    }
    for (i = 0; i < npix; i++) {
        const bvh_hit *h = &hits[i];
        const float *t;
        bvh_ray cr, ray;
        float e1[3], e2[3], n[3], len, w, p[3];
        uint32_t k;
        if (h->prim == BVH_INVALID) continue;
        t = tris + 9 * (size_t)h->prim;
        for (k = 0; k < 3; k++) {
            e1[k] = t[3 + k] - t[k];
            e2[k] = t[6 + k] - t[k];
        }
        n[0] = e1[1] * e2[2] - e1[2] * e2[1];
        n[1] = e1[2] * e2[0] - e1[0] * e2[2];
        n[2] = e1[0] * e2[1] - e1[1] * e2[0];
        len = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(len > 0.0f) || !isfinite(len)) continue;
        cr = bvh_camera_ray(cam, (uint32_t)(i % cam->width), (uint32_t)(i / cam->width));
        if (n[0] * cr.dir.x + n[1] * cr.dir.y + n[2] * cr.dir.z > 0.0f) len = -len; /* face the viewer */
        w = 1.0f - h->u - h->v;
        for (k = 0; k < 3; k++) {
            n[k] /= len;
            p[k] = w * t[k] + h->u * t[3 + k] + h->v * t[6 + k] + offset * n[k];
        }
        ray.origin = rays__v(p[0], p[1], p[2]);
        ray.tmin = 0.0f;
        ray.tmax = BVH_INF;
        {
            uint32_t a = rays__hash((uint32_t)i ^ RAYS_SEED), b = rays__hash(a + 0x9E3779B9u);
            ray.dir = rays__cosine(rays__v(n[0], n[1], n[2]), rays__unit(a), rays__unit(b));
        }
        out->diffuse[out->ndiffuse++] = ray;
        if (n[0] * L.x + n[1] * L.y + n[2] * L.z > 0.0f) {
            ray.dir = L;
            out->shadow[out->nshadow++] = ray;
        }
    }
    return 0;
}

void rays_free(rays_set *s) {
    free(s->diffuse);
    free(s->shadow);
    memset(s, 0, sizeof *s);
}

#endif /* RAYS_IMPLEMENTATION_DONE */
#endif /* RAYS_IMPLEMENTATION */
