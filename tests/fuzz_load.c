/* tests/fuzz_load.c - libFuzzer target for bvh_load (and, on what it accepts, bvh_validate,
   traversal, bvh_refit and bvh_save).

   Build and run:  make fuzz FUZZ_SECONDS=120      (mk/robust.mk; build/fuzz/fuzz_load, after
                   fuzz_build; seeds in tests/fuzz/load/)
   or by hand:     clang -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
                       -I. tests/fuzz_load.c -o fuzz_load -lm -lpthread
   Seeds:          cc -std=c11 -I. -DFUZZ_LOAD_SEEDS tests/fuzz_load.c -o /tmp/seeds -lm -lpthread &&
                   /tmp/seeds tests/fuzz/load     (saved trees of every builder and kind, < 4 KiB)

   Input: byte 0 is a mode, the rest a file for bvh_load. Mode bit 0 reseals the file (rewrites
   its header and payload checksums where the header's counts fit the bytes), so that mutations
   reach the size and structure checks behind the checksums; bit 1 loads through a read callback
   (in pieces of 1 to 8 bytes, by bits 2-4) instead of from memory; a memory load borrows the
   buffer when bit 2 is set (bvh_load_desc.borrow: read in place, never written); bit 5 asks for
   the 8-wide layout, bit 6 for none (else: as saved); bit 7 limits the allocator to 4 times the
   file's size.
   Checked, any disagreement traps:
   - the result is SUCCESS or one of TRUNCATED, CORRUPT, UNSUPPORTED_FORMAT, OUT_OF_MEMORY, and
     after a failure the tree is empty and nothing allocated is live;
   - no allocation is larger than the file (a memory load) or than 4 times it plus 64 KiB (the
     8-wide layout), whatever the header says;
   - after a success: bvh_validate passes (triangle trees; box trees have no boxes to check
     against), bvh_sah works, rays trace without fault, a refit to the tree's own triangles
     succeeds and stays valid (a borrowed tree's is refused and the tree stays valid), and bvh_save
     writes bytes that load to the same tree;
   - a borrowed buffer's bytes are the same after the load and after bvh_free. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "tree_diff.h"

#define FZ_CHECK(cond, ...)                                                                                            \
    do {                                                                                                               \
        if (!(cond)) {                                                                                                 \
            fprintf(stderr, "fuzz_load: %s:%d: check failed: %s: ", __FILE__, __LINE__, #cond);                        \
            fprintf(stderr, __VA_ARGS__);                                                                              \
            fputc('\n', stderr);                                                                                       \
            abort();                                                                                                   \
        }                                                                                                              \
    } while (0)

typedef struct fz_alloc {
    long live;
    size_t largest, limit;
} fz_alloc;
static void *fz_alloc_fn(size_t size, void *user) {
    fz_alloc *a = (fz_alloc *)user;
    void *p;
    if (size > a->largest) a->largest = size;
    if (a->limit && size > a->limit) return NULL;
    if ((p = malloc(size)) != NULL) a->live++;
    return p;
}
static void fz_free_fn(void *p, void *user) {
    fz_alloc *a = (fz_alloc *)user;
    if (p) a->live--;
    free(p);
}
typedef struct fz_stream {
    const uint8_t *p;
    size_t size, pos, piece;
} fz_stream;
static size_t fz_read(void *user, void *data, size_t size) {
    fz_stream *s = (fz_stream *)user;
    size_t n = size < s->piece ? size : s->piece; /* short reads are the callback's right too */
    size_t done = 0;
    while (done < size) {
        n = size - done < s->piece ? size - done : s->piece;
        if (n > s->size - s->pos) n = s->size - s->pos;
        if (!n) break;
        memcpy((char *)data + done, s->p + s->pos, n);
        s->pos += n;
        done += n;
    }
    return done;
}
typedef struct fz_buf {
    uint8_t *p;
    size_t size;
} fz_buf;
static size_t fz_write(void *user, const void *data, size_t size) {
    fz_buf *b = (fz_buf *)user;
    uint8_t *q = (uint8_t *)realloc(b->p, b->size + size);
    if (!q) return 0;
    b->p = q;
    memcpy(b->p + b->size, data, size);
    b->size += size;
    return size;
}

/* The checksums rewritten to match the bytes, where the header's counts fit them. */
static void fz_reseal(uint8_t *file, size_t size) {
    bvh__file_header h;
    uint64_t payload;
    if (size < sizeof h) return;
    memcpy(&h, file, sizeof h);
    payload = bvh__payload_bytes(h.node_count, h.ref_count, (h.flags & BVH__FILE_TRIANGLES) != 0, 0);
    if ((h.flags & BVH__FILE_WIDE) && h.payload_bytes > payload && h.payload_bytes - payload < (uint64_t)1 << 40 &&
        (h.payload_bytes - payload) % sizeof(bvh_node8) == 0)
        payload = h.payload_bytes; /* the 8-wide nodes: what the payload leaves for them */
    if (payload <= size - sizeof h) {
        bvh_tree t;
        memset(&t, 0, sizeof t);
        t.node_count = h.node_count;
        t.ref_count = h.ref_count;
        t.nodes = (bvh_node *)(void *)(file + sizeof h);
        t.prims = (uint32_t *)(void *)(t.nodes + h.node_count);
        t.tris = (h.flags & BVH__FILE_TRIANGLES) ? (float *)(void *)(t.prims + h.ref_count) : NULL;
        if (t.tris && payload == h.payload_bytes && (h.flags & BVH__FILE_WIDE)) {
            t.nodes8 = (bvh_node8 *)(void *)(t.tris + 9 * (size_t)h.ref_count);
            t.node8_count =
                (uint32_t)((payload - bvh__payload_bytes(h.node_count, h.ref_count, 1, 0)) / sizeof(bvh_node8));
        }
        h.payload_check = bvh__payload_check(&t);
    }
    h.header_check = bvh__header_check(h);
    memcpy(file, &h, sizeof h);
}

/* The tree's triangles by primitive (each from its first reference; excluded ones a point). */
static float *fz_prim_tris(const bvh_tree *t) {
    float *v = (float *)calloc(9 * (size_t)(t->prim_count ? t->prim_count : 1), sizeof(float));
    uint32_t k;
    FZ_CHECK(v != NULL, "out of memory");
    for (k = t->ref_count; k-- > 0;) memcpy(v + 9 * (size_t)t->prims[k], t->tris + 9 * (size_t)k, 9 * sizeof(float));
    return v;
}

static void fz_after_success(bvh_tree *t) {
    bvh_validation rep;
    double sah;
    uint32_t i;
    fz_buf out;
    bvh_load_desc ld;
    bvh_tree again;
    FZ_CHECK(bvh_sah(t, NULL, &sah) == BVH_SUCCESS, "bvh_sah of a loaded tree");
    if (!t->tris || !t->node_count) return;
    FZ_CHECK(bvh_validate(t, NULL, &rep) == BVH_SUCCESS, "loaded tree invalid: %s (node %u)", rep.message, rep.node);
    for (i = 0; i < 16; i++) { /* rays through the root box; any answer, no fault */
        bvh_aabb b = bvh_tree_bounds(t);
        bvh_ray ray;
        bvh_hit hit;
        float f = (float)i / 16.0f;
        ray.origin.x = b.min.x + f * (b.max.x - b.min.x);
        ray.origin.y = b.max.y + 1.0f;
        ray.origin.z = b.min.z + (1.0f - f) * (b.max.z - b.min.z);
        ray.dir.x = 0.1f * f;
        ray.dir.y = -1.0f;
        ray.dir.z = 0.05f;
        ray.tmin = 0.0f;
        ray.tmax = BVH_INF;
        (void)bvh_intersect(t, &ray, &hit);
        (void)bvh_occluded(t, &ray);
    }
    {
        float *v = fz_prim_tris(t);
        bvh_refit_desc rd;
        bvh_result r;
        memset(&rd, 0, sizeof rd);
        rd.triangles.positions = v;
        rd.triangles.vertex_count = 3 * t->prim_count;
        rd.triangles.triangle_count = t->prim_count;
        rd.threads = 2;
        r = bvh_refit(t, &rd);
        free(v);
        if (t->borrowed)
            FZ_CHECK(r == BVH_ERROR_INVALID_ARGUMENT, "refit of a borrowed tree: %s", bvh_result_string(r));
        else
            FZ_CHECK(r == BVH_SUCCESS, "refit of a loaded tree: %s", bvh_result_string(r));
        FZ_CHECK(bvh_validate(t, NULL, &rep) == BVH_SUCCESS, "refitted tree invalid: %s", rep.message);
    }
    memset(&out, 0, sizeof out);
    FZ_CHECK(bvh_save(t, fz_write, &out) == BVH_SUCCESS, "save");
    FZ_CHECK(out.size == bvh_save_size(t), "save size");
    memset(&ld, 0, sizeof ld);
    ld.data = out.p;
    ld.size = out.size;
    ld.trace_width = t->nodes8 ? 8 : 2;
    FZ_CHECK(bvh_load(&again, &ld) == BVH_SUCCESS, "reload of a saved tree");
    FZ_CHECK(tree_diff_ex(t, &again, 1) == NULL, "reloaded tree differs: %s", tree_diff_ex(t, &again, 1));
    bvh_free(&again);
    free(out.p);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    uint8_t mode, *file, *before = NULL;
    fz_alloc a;
    fz_stream st;
    bvh_load_desc ld;
    bvh_tree t;
    bvh_result r;
    if (size < 1) return 0;
    mode = data[0];
    size--;
    file = (uint8_t *)malloc(size ? size : 1); /* its own block: ASan sees any read past the end */
    FZ_CHECK(file != NULL, "out of memory");
    memcpy(file, data + 1, size);
    if (mode & 1) fz_reseal(file, size);
    memset(&a, 0, sizeof a);
    if (mode & 128) a.limit = 4 * size + 65536;
    memset(&ld, 0, sizeof ld);
    ld.allocator.alloc = fz_alloc_fn;
    ld.allocator.free = fz_free_fn;
    ld.allocator.user = &a;
    ld.threads = 2;
    ld.trace_width = (mode & 32) ? 8 : (mode & 64) ? 2 : 0;
    if (mode & 2) {
        st.p = file;
        st.size = size;
        st.pos = 0;
        st.piece = 1 + ((mode >> 2) & 7);
        ld.read = fz_read;
        ld.user = &st;
        ld.max_bytes = 4 * size + 64; /* a stream: the caller's cap */
    } else {
        ld.data = file;
        ld.size = size;
        ld.borrow = (mode >> 2) & 1u;
        if (ld.borrow) {
            before = (uint8_t *)malloc(size ? size : 1);
            FZ_CHECK(before != NULL, "out of memory");
            memcpy(before, file, size);
        }
    }
    r = bvh_load(&t, &ld);
    FZ_CHECK(r == BVH_SUCCESS || r == BVH_ERROR_TRUNCATED || r == BVH_ERROR_CORRUPT ||
                 r == BVH_ERROR_UNSUPPORTED_FORMAT || r == BVH_ERROR_OUT_OF_MEMORY,
             "bvh_load: %s", bvh_result_string(r));
    FZ_CHECK(a.largest <= 4 * size + 65536 + 1024, "an allocation of %zu bytes for a file of %zu", a.largest, size);
    if (r == BVH_SUCCESS) {
        fz_after_success(&t);
    } else {
        FZ_CHECK(t.nodes == NULL && t.prims == NULL && t.tris == NULL && t.nodes8 == NULL, "a failed load left arrays");
    }
    bvh_free(&t);
    FZ_CHECK(a.live == 0, "%ld blocks live after bvh_free", a.live);
    FZ_CHECK(!before || memcmp(before, file, size) == 0, "a borrowed buffer was written");
    free(before);
    free(file);
    return 0;
}

#ifdef FUZZ_LOAD_SEEDS
/* Writes the seed files into the directory argv[1]: saved trees of every builder over a few small
   scenes, box and binary-only trees, an empty tree, a tree with an excluded triangle; each
   prefixed with a mode byte (plain memory load; and one streamed, resealed copy). */
static void seed_write(const char *dir, const char *name, uint8_t mode, const bvh_tree *t) {
    char path[512];
    fz_buf b;
    FILE *f;
    memset(&b, 0, sizeof b);
    fz_write(&b, &mode, 1);
    FZ_CHECK(bvh_save(t, fz_write, &b) == BVH_SUCCESS, "save");
    snprintf(path, sizeof path, "%s/seed-%s", dir, name);
    f = fopen(path, "wb");
    FZ_CHECK(f != NULL, "cannot write %s", path);
    fwrite(b.p, 1, b.size, f);
    fclose(f);
    free(b.p);
}
int main(int argc, char **argv) {
    float v[3 * 3 * 24];
    bvh_aabb boxes[24];
    uint32_t i, seed = 12345;
    int b;
    char name[64];
    if (argc < 2) return 2;
    for (i = 0; i < 3 * 3 * 24; i++) {
        seed = seed * 1664525u + 1013904223u;
        v[i] = (float)(seed >> 8) / 16777216.0f * 4.0f + (float)(i / 9 % 4);
    }
    for (i = 0; i < 24; i++) {
        boxes[i].min.x = v[9 * i];
        boxes[i].min.y = v[9 * i + 1];
        boxes[i].min.z = v[9 * i + 2];
        boxes[i].max.x = v[9 * i] + 0.5f;
        boxes[i].max.y = v[9 * i + 1] + 0.25f;
        boxes[i].max.z = v[9 * i + 2] + 1.0f;
    }
    for (b = 1; b < BVH_BUILDER_COUNT; b++) {
        uint32_t n;
        for (n = 1; n <= 24; n += 23) {
            bvh_build_desc d;
            bvh_tree t;
            memset(&d, 0, sizeof d);
            d.builder = (bvh_builder)b;
            d.triangles.positions = v;
            d.triangles.vertex_count = 3 * n;
            d.triangles.triangle_count = n;
            d.max_leaf_size = n > 1 ? 2 : 0;
            FZ_CHECK(bvh_build(&t, &d) == BVH_SUCCESS, "build");
            snprintf(name, sizeof name, "%s-%u", bvh_builder_name(d.builder), n);
            seed_write(argv[1], name, 0, &t);
            if (n > 1) {
                snprintf(name, sizeof name, "%s-%u-streamed-resealed", bvh_builder_name(d.builder), n);
                seed_write(argv[1], name, 1 | 2 | (3 << 2) | 32, &t);
                snprintf(name, sizeof name, "%s-%u-borrowed-resealed", bvh_builder_name(d.builder), n);
                seed_write(argv[1], name, 1 | 4, &t);
            }
            bvh_free(&t);
            d.triangles.triangle_count = 0;
            d.triangles.positions = NULL;
            d.boxes = boxes;
            d.box_count = n;
            FZ_CHECK(bvh_build(&t, &d) == BVH_SUCCESS, "build");
            snprintf(name, sizeof name, "%s-boxes-%u", bvh_builder_name(d.builder), n);
            seed_write(argv[1], name, 1, &t);
            bvh_free(&t);
        }
    }
    {
        bvh_build_desc d;
        bvh_tree t;
        float w[sizeof v / sizeof v[0]];
        memset(&d, 0, sizeof d);
        FZ_CHECK(bvh_build(&t, &d) == BVH_SUCCESS, "build");
        seed_write(argv[1], "empty", 0, &t);
        bvh_free(&t);
        memcpy(w, v, sizeof v);
        w[9 * 5 + 4] = NAN;
        d.builder = BVH_BUILDER_PLOC;
        d.triangles.positions = w;
        d.triangles.vertex_count = 3 * 24;
        d.triangles.triangle_count = 24;
        d.skip_invalid = 1;
        d.trace_width = 2;
        FZ_CHECK(bvh_build(&t, &d) == BVH_SUCCESS, "build");
        seed_write(argv[1], "excluded-binary-only", 64, &t);
        seed_write(argv[1], "excluded-limited-allocator", 128 | 1, &t);
        bvh_free(&t);
    }
    return 0;
}
#endif
