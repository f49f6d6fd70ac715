/* animate.c - a tree that lives across frames: build once, bvh_refit as the vertices move, then
   bvh_save the tree to a file and bvh_load it back, copied and borrowed (FILE* helpers a program
   can copy).

   Build and run (from the repository root; `make test` does both and checks the output):
       cc -std=c11 -O2 -I. examples/animate.c -o build/animate -lm -lpthread
       build/animate [FILE]          (FILE: where the tree is saved; default animate.bvh)
   A 64 x 64 sheet of triangles waves over 30 frames; each frame the tree is refitted and a ray
   shot straight down at the centre reports the height it hits. The last frame's tree is saved,
   loaded back (through the FILE*, and borrowed from the file's bytes read whole) and must give
   the same hit both ways. Exit status 0 when it does. */
#define BVH_IMPLEMENTATION
#include "bvh.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#define N 64 /* cells per side */

/* File helpers: bvh_save and bvh_load move bytes through callbacks; these are FILE*'s. */
static size_t file_write(void *user, const void *data, size_t size) { return fwrite(data, 1, size, (FILE *)user); }
static size_t file_read(void *user, void *data, size_t size) { return fread(data, 1, size, (FILE *)user); }
static bvh_result tree_save_file(const bvh_tree *tree, const char *path) {
    FILE *f = fopen(path, "wb");
    bvh_result r;
    if (!f) return BVH_ERROR_IO;
    r = bvh_save(tree, file_write, f);
    if (fclose(f) != 0 && r == BVH_SUCCESS) r = BVH_ERROR_IO;
    return r;
}
static bvh_result tree_load_file(bvh_tree *tree, const char *path) {
    bvh_load_desc desc = {0}; /* zero: the layout the tree was saved with, all CPUs, malloc */
    FILE *f = fopen(path, "rb");
    bvh_result r;
    desc.read = file_read;
    desc.user = f;
    if (!f) return BVH_ERROR_IO;
    r = bvh_load(tree, &desc);
    fclose(f);
    return r;
}

/* The whole file in *bytes (malloc'd; free it after bvh_free), the tree borrowing them: its
   nodes, references and triangles stay in the buffer instead of being copied. A mapped file
   (mmap) serves the same way: keep it mapped until bvh_free. */
static bvh_result tree_load_file_borrowed(bvh_tree *tree, const char *path, void **bytes) {
    bvh_load_desc desc = {0};
    FILE *f = fopen(path, "rb");
    long size;
    *bytes = NULL;
    if (!f) return BVH_ERROR_IO;
    if (fseek(f, 0, SEEK_END) != 0 || (size = ftell(f)) < 0 || fseek(f, 0, SEEK_SET) != 0 ||
        !(*bytes = malloc(size ? (size_t)size : 1)) || fread(*bytes, 1, (size_t)size, f) != (size_t)size) {
        fclose(f);
        free(*bytes);
        *bytes = NULL;
        return BVH_ERROR_IO;
    }
    fclose(f);
    desc.data = *bytes;
    desc.size = (size_t)size;
    desc.borrow = 1;
    return bvh_load(tree, &desc);
}

static float v[(N + 1) * (N + 1)][3];
static uint32_t idx[N * N * 6];

static void wave(float time) {
    int i, j;
    for (j = 0; j <= N; j++)
        for (i = 0; i <= N; i++) {
            float x = (float)i / N, z = (float)j / N;
            v[j * (N + 1) + i][0] = x;
            v[j * (N + 1) + i][1] = 0.1f * sinf(6.0f * x + time) * cosf(4.0f * z - time);
            v[j * (N + 1) + i][2] = z;
        }
}
static float height_at_centre(const bvh_tree *tree) {
    bvh_ray ray = {{0.5f, 1.0f, 0.5f}, 0.0f, {0.0f, -1.0f, 0.0f}, BVH_INF};
    bvh_hit hit;
    return bvh_intersect(tree, &ray, &hit) ? 1.0f - hit.t : NAN;
}

int main(int argc, char **argv) {
    const char *path = argc > 1 ? argv[1] : "animate.bvh";
    bvh_build_desc desc = {0};
    bvh_refit_desc refit = {0};
    bvh_tree tree, loaded;
    bvh_result r;
    int i, j, frame;
    float h;
    for (j = 0, i = 0; j < N * N; j++) { /* two triangles per cell */
        uint32_t a = (uint32_t)(j / N * (N + 1) + j % N), b = a + 1, c = a + N + 1, d = c + 1;
        idx[i++] = a;
        idx[i++] = b;
        idx[i++] = d;
        idx[i++] = a;
        idx[i++] = d;
        idx[i++] = c;
    }
    wave(0.0f);
    desc.triangles.positions = &v[0][0];
    desc.triangles.vertex_count = (N + 1) * (N + 1);
    desc.triangles.indices = idx;
    desc.triangles.triangle_count = N * N * 2;
    if ((r = bvh_build(&tree, &desc)) != BVH_SUCCESS) {
        printf("build: %s\n", bvh_result_string(r));
        return 1;
    }
    refit.triangles = desc.triangles; /* the same triangles; their vertices move */
    for (frame = 1; frame <= 30; frame++) {
        wave(0.2f * (float)frame);
        if ((r = bvh_refit(&tree, &refit)) != BVH_SUCCESS) {
            printf("refit: %s\n", bvh_result_string(r));
            return 1;
        }
        if (frame % 10 == 0) printf("frame %d: height at the centre %.4f\n", frame, (double)height_at_centre(&tree));
    }
    h = height_at_centre(&tree);
    if ((r = tree_save_file(&tree, path)) != BVH_SUCCESS) {
        printf("save %s: %s\n", path, bvh_result_string(r));
        return 1;
    }
    bvh_free(&tree);
    if ((r = tree_load_file(&loaded, path)) != BVH_SUCCESS) {
        printf("load %s: %s\n", path, bvh_result_string(r));
        return 1;
    }
    printf("saved to and loaded from %s: height at the centre %.4f (%s)\n", path, (double)height_at_centre(&loaded),
           height_at_centre(&loaded) == h ? "the same" : "DIFFERENT");
    r = height_at_centre(&loaded) == h ? BVH_SUCCESS : BVH_ERROR_CORRUPT;
    bvh_free(&loaded);
    if (r != BVH_SUCCESS) return 1;
    {
        void *bytes;
        if ((r = tree_load_file_borrowed(&loaded, path, &bytes)) != BVH_SUCCESS) {
            printf("load %s borrowed: %s\n", path, bvh_result_string(r));
            free(bytes);
            return 1;
        }
        printf("borrowed from %s's bytes: height at the centre %.4f (%s)\n", path, (double)height_at_centre(&loaded),
               height_at_centre(&loaded) == h ? "the same" : "DIFFERENT");
        r = height_at_centre(&loaded) == h ? BVH_SUCCESS : BVH_ERROR_CORRUPT;
        bvh_free(&loaded); /* leaves the bytes */
        free(bytes);
    }
    return r == BVH_SUCCESS ? 0 : 1;
}
