/* tests/test_loader.c - the examples' scene loader (examples/scene.h) refuses corrupted PLY files
   with a one-line message instead of crashing inside assimp.

   Each file is a small PLY written here (ASCII, and binary little-endian for the same faults):
   a face with no indices, a negative index count, quads and a pentagon with an index past the
   vertices (out of range, negative, huge), a triangle likewise, a truncated face list. Each is
   loaded in a forked child with an alarm, so that a crash or a hang in assimp fails that test
   alone and says how. Good files (a quad, a triangle and a line, the binary twin) still load, with
   the expected triangles. Without assimp (BVH_HAVE_ASSIMP) only .obj files load: the tests skip.
   A raw .tri soup (read without assimp) loads as written, and a wrong magic or a short body is
   refused with one line naming the file. */
#define SCENE_IMPLEMENTATION
#include "examples/scene.h"

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#define LD_SECONDS 10 /* a load that takes longer has hung */

static char g_dir[64];

/* Four vertices of the unit square in z = 0, then `nfaces` faces, each "count i0 i1 ..." (ASCII:
   the words as given; binary: a uchar count and int indices). */
static void write_ply(const char *name, int binary, int nfaces, const char *const *faces, char *path, size_t pathlen) {
    static const float v[12] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
    FILE *f;
    int i;
    snprintf(path, pathlen, "%s/%s", g_dir, name);
    f = fopen(path, "wb");
    assert_non_null(f);
    fprintf(f,
            "ply\nformat %s 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face %d\nproperty list uchar int vertex_indices\nend_header\n",
            binary ? "binary_little_endian" : "ascii", nfaces);
    for (i = 0; i < 4; i++) {
        if (binary)
            assert_int_equal(fwrite(v + 3 * i, sizeof(float), 3, f), 3);
        else
            fprintf(f, "%g %g %g\n", (double)v[3 * i], (double)v[3 * i + 1], (double)v[3 * i + 2]);
    }
    for (i = 0; i < nfaces; i++) {
        const char *p = faces[i];
        char *end;
        long long w = strtoll(p, &end, 10);
        if (!binary) {
            fprintf(f, "%s\n", p);
            continue;
        }
        assert_true(end != p);
        fputc((int)(unsigned char)w, f); /* the count, as a uchar: -1 is 255 */
        for (p = end; (w = strtoll(p, &end, 10)), end != p; p = end) {
            int32_t idx = (int32_t)(uint32_t)w; /* 4000000000 wraps as the int the file holds */
            assert_int_equal(fwrite(&idx, sizeof idx, 1, f), 1);
        }
    }
    assert_int_equal(fclose(f), 0);
}

/* Loads path in a child; passes when scene_load refuses it with one line naming the file. */
static void expect_refused(const char *path) {
    pid_t pid;
    int status = 0;
    if (!scene_can_use_assimp()) {
        skip();
        return;
    }
    fflush(NULL);
    pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        scene s;
        char err[512];
        int rc;
        static const int sig[] = {SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT};
        size_t i;
        for (i = 0; i < sizeof sig / sizeof sig[0]; i++) /* cmocka's handlers would resume the tests here */
            signal(sig[i], SIG_DFL);
        alarm(LD_SECONDS);
        rc = scene_load(path, &s, err, sizeof err);
        if (rc == 0) _exit(10);
        _exit(!err[0] || strchr(err, '\n') || !strstr(err, strrchr(path, '/') + 1) ? 11 : 0);
    }
    assert_int_equal(waitpid(pid, &status, 0), pid);
    if (WIFSIGNALED(status))
        fail_msg("%s: scene_load died of signal %d%s", path, WTERMSIG(status),
                 WTERMSIG(status) == SIGALRM ? " (hung)" : "");
    if (WEXITSTATUS(status) == 10) fail_msg("%s: scene_load accepted a corrupted file", path);
    if (WEXITSTATUS(status) == 11) fail_msg("%s: refused, but not with one line naming the file", path);
    assert_int_equal(WEXITSTATUS(status), 0);
}

/* One test per fault, ASCII and binary: name, then the faces. */
#define LD_BAD_TEST(fn, ...)                                                                                           \
    static void fn(void **state) {                                                                                     \
        char path[128];                                                                                                \
        const char *const faces[] = {__VA_ARGS__};                                                                     \
        int binary = *state != NULL;                                                                                   \
        write_ply(binary ? #fn ".bin.ply" : #fn ".ply", binary, (int)(sizeof faces / sizeof faces[0]), faces, path,    \
                  sizeof path);                                                                                        \
        expect_refused(path);                                                                                          \
    }
LD_BAD_TEST(test_face_without_indices, "3 0 1 2", "0")
LD_BAD_TEST(test_negative_index_count, "-1 0 1 2")
LD_BAD_TEST(test_quad_index_out_of_range, "4 0 1 2 9")
LD_BAD_TEST(test_quad_index_negative, "4 0 1 -2 3")
LD_BAD_TEST(test_quad_index_huge, "4 0 1 2 4000000000")
LD_BAD_TEST(test_pentagon_index_out_of_range, "5 0 1 2 3 7")
LD_BAD_TEST(test_triangle_index_out_of_range, "3 0 1 2", "3 0 2 4")

/* The header promises two faces, the body holds one (ASCII: a short row; binary: cut bytes). */
static void test_truncated_faces(void **state) {
    char path[128];
    const char *const faces[] = {"3 0 1 2", "3 0 2"};
    int binary = *state != NULL;
    write_ply(binary ? "truncated.bin.ply" : "truncated.ply", binary, 2, faces, path, sizeof path);
    expect_refused(path);
}

/* Loads a good file in this process: its triangle and skipped-face counts, and its bounds (the
   unit square, or a triangle of it: the lower-left corner is always there). */
static void expect_loaded(const char *path, uint32_t triangles, uint32_t skipped, float max_y) {
    scene s;
    char err[512];
    bvh_aabb box;
    if (!scene_can_use_assimp()) {
        skip();
        return;
    }
    if (scene_load(path, &s, err, sizeof err) != 0) fail_msg("%s: %s", path, err);
    assert_int_equal(s.triangles, triangles);
    assert_int_equal(s.skipped, skipped);
    box = scene_bounds(&s);
    assert_true(box.min.x == 0.0f && box.min.y == 0.0f && box.max.x == 1.0f && box.max.y == max_y);
    assert_true(box.min.z == 0.0f && box.max.z == 0.0f);
    scene_free(&s);
}

static void test_good_quad(void **state) {
    char path[128];
    const char *const faces[] = {"4 0 1 2 3"};
    int binary = *state != NULL;
    write_ply(binary ? "quad.bin.ply" : "quad.ply", binary, 1, faces, path, sizeof path);
    expect_loaded(path, 2, 0, 1.0f); /* triangulated: two triangles */
}

static void test_good_triangle_and_line(void **state) {
    char path[128];
    const char *const faces[] = {"3 0 1 2", "2 0 3"};
    int binary = *state != NULL;
    write_ply(binary ? "line.bin.ply" : "line.ply", binary, 2, faces, path, sizeof path);
    expect_loaded(path, 1, 1, 1.0f); /* the line is dropped and counted */
}

/* A .tri file: magic, the announced count, then `written` triangles of the unit square. */
static void write_tri(const char *name, const char *magic, uint32_t count, uint32_t written, char *path,
                      size_t pathlen) {
    static const float v[18] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 0, 0, 1, 1, 0, 0, 1, 0};
    FILE *f;
    snprintf(path, pathlen, "%s/%s", g_dir, name);
    f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(magic, 1, 4, f), 4);
    assert_int_equal(fwrite(&count, sizeof count, 1, f), 1);
    assert_int_equal(fwrite(v, sizeof(float), 9 * (size_t)written, f), 9 * (size_t)written);
    assert_int_equal(fclose(f), 0);
}

static void test_tri_soup(void **state) {
    static const char *const bad[] = {"bad-magic.tri", "short.tri"};
    char path[128], err[512];
    scene s;
    bvh_aabb box;
    size_t i;
    (void)state;
    write_tri("good.tri", "TRI1", 2, 2, path, sizeof path);
    if (scene_load(path, &s, err, sizeof err) != 0) fail_msg("%s: %s", path, err);
    assert_int_equal(s.triangles, 2);
    box = scene_bounds(&s);
    assert_true(box.min.x == 0.0f && box.min.y == 0.0f && box.max.x == 1.0f && box.max.y == 1.0f);
    scene_free(&s);
    write_tri(bad[0], "TRI2", 2, 2, path, sizeof path);
    write_tri(bad[1], "TRI1", 3, 2, path, sizeof path);
    for (i = 0; i < 2; i++) {
        snprintf(path, sizeof path, "%s/%s", g_dir, bad[i]);
        if (scene_load(path, &s, err, sizeof err) == 0) fail_msg("%s: accepted", path);
        if (!strstr(err, bad[i]) || strchr(err, '\n')) fail_msg("%s: refused with '%s'", path, err);
    }
}

static int ld_setup(void **state) {
    (void)state;
    snprintf(g_dir, sizeof g_dir, "/tmp/bvh_test_loader.XXXXXX");
    return mkdtemp(g_dir) ? 0 : -1;
}
static int ld_teardown(void **state) {
    static const char *const names[] = {"test_face_without_indices",
                                        "test_negative_index_count",
                                        "test_quad_index_out_of_range",
                                        "test_quad_index_negative",
                                        "test_quad_index_huge",
                                        "test_pentagon_index_out_of_range",
                                        "test_triangle_index_out_of_range",
                                        "truncated",
                                        "quad",
                                        "line"};
    static const char *const tri[] = {"good.tri", "bad-magic.tri", "short.tri"};
    char path[128];
    size_t i;
    (void)state;
    for (i = 0; i < sizeof tri / sizeof tri[0]; i++) {
        snprintf(path, sizeof path, "%s/%s", g_dir, tri[i]);
        remove(path);
    }
    for (i = 0; i < sizeof names / sizeof names[0]; i++) {
        snprintf(path, sizeof path, "%s/%s.ply", g_dir, names[i]);
        remove(path);
        snprintf(path, sizeof path, "%s/%s.bin.ply", g_dir, names[i]);
        remove(path);
    }
    return rmdir(g_dir);
}

/* Each test twice: state NULL writes ASCII, non-NULL binary little-endian. */
#define LD_BOTH(f)                                                                                                     \
    {#f "/ascii", f, NULL, NULL, NULL}, { #f "/binary", f, NULL, NULL, (void *)1 }

int main(void) {
    const struct CMUnitTest tests[] = {
        LD_BOTH(test_face_without_indices),
        LD_BOTH(test_negative_index_count),
        LD_BOTH(test_quad_index_out_of_range),
        LD_BOTH(test_quad_index_negative),
        LD_BOTH(test_quad_index_huge),
        LD_BOTH(test_pentagon_index_out_of_range),
        LD_BOTH(test_triangle_index_out_of_range),
        LD_BOTH(test_truncated_faces),
        LD_BOTH(test_good_quad),
        LD_BOTH(test_good_triangle_and_line),
        cmocka_unit_test(test_tri_soup),
    };
    return cmocka_run_group_tests(tests, ld_setup, ld_teardown);
}
