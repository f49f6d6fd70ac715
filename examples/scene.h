/* scene.h - scenes, images and timing for the bvh.h example programs (not part of the library)

   WHAT
     Loads a mesh file or generates a test scene as a flat, world-space triangle soup (9 floats
     per triangle), writes PNG/PPM images, and gives a monotonic clock, a median, the CPU count,
     JSON string output and command-line number parsing: the pieces build/render, the benchmark
     (bench/) and the OpenCL renderer share.

   HOW TO INCLUDE
     In exactly ONE .c file:
         #define SCENE_IMPLEMENTATION
         #include "scene.h"
     Everywhere else just #include "scene.h". It includes "bvh.h" (declarations only).

   EXAMPLE
         scene s;
         char err[256];
         if (scene_load("gen:field:15", &s, err, sizeof err) != 0) {
             fprintf(stderr, "%s\n", err);
             return 1;
         }
         printf("%s: %u triangles\n", s.name, s.triangles);  // s.v: 9 floats per triangle
         bvh_aabb box = scene_bounds(&s);
         scene_free(&s);

   SCENE SPECS (scene_load)
     PATH                  any file assimp reads (OBJ, PLY, glTF/GLB, 3DS, ...), all meshes
                           flattened to world space; polygons are triangulated, points and lines dropped
     PATH.tri              a raw triangle soup: "TRI1", uint32 count, count x 9 float32, host
                           byte order (the format of ../shared/tools/embree_ref.c)
     gen:random:N          N small random triangles in the unit cube (fixed seed)
     gen:field:K           K Stanford bunnies on a ground plane: K*69666+2 triangles
                           (gen:field:15 = 1,044,992; gen:field:44 = 3,065,306); needs the Debian
                           package glmark2-data (/usr/share/glmark2/models/bunny.obj), read with
                           the built-in OBJ reader so the scene does not depend on assimp
     gen:procedural:N      spheres and tori on a ground plane, about N triangles, no file needed
     gen:spheres:N         the same as gen:procedural:N
     gen:grid:N            N x N unit quads (2N^2 triangles) in the y = 0 plane, normals +y
     Every generator is deterministic (own LCG, not rand()): the same spec gives the same bytes.

   CONFIGURATION (compiler flags; the Makefile sets them when the packages are installed)
     BVH_HAVE_ASSIMP       load files with assimp (link -lassimp, Debian libassimp-dev); without
                           it only Wavefront .obj files load, with a small built-in reader
     BVH_HAVE_STB          PNG output with stb_image_write (Debian libstb-dev); PPM always works
     SCENE_BUNNY_PATH      the bunny used by gen:field (default: glmark2-data's)
     SCENE_MAX_GENERATED   largest triangle count a generator produces (default 100,000,000)

   ERRORS
     Functions that can fail return 0 on success and non-zero on failure, with a one-line message
     in err (when err is not NULL). Nothing here prints, exits or aborts. Missing, empty and
     unreadable files, truncated GLB and PLY files (checked here first: assimp 5.2 hangs, aborts or
     crashes on some truncated PLY files), faces without indices or with an index past their
     mesh's vertices (checked with assimp's validator and here, before assimp's post-processing,
     which aborts or crashes on them), files assimp cannot read and files without a triangle are
     all refused with a message; a deliberately corrupted file may still trip an assimp reader.

   LICENSE
     MIT, like bvh.h.
*/
#ifndef SCENE_H_INCLUDED
#define SCENE_H_INCLUDED

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "bvh.h"

#ifndef SCENE_BUNNY_PATH
#define SCENE_BUNNY_PATH "/usr/share/glmark2/models/bunny.obj"
#endif
#ifndef SCENE_MAX_GENERATED
#define SCENE_MAX_GENERATED 100000000u
#endif

#ifdef __cplusplus
extern "C" {
#endif

typedef struct scene {
    float *v;           /* triangle i is v[9i .. 9i+8]: x0 y0 z0 x1 y1 z1 x2 y2 z2, world space */
    uint32_t triangles; /* > 0 after a successful load */
    uint32_t skipped;   /* faces the loader dropped (points, lines) */
    char name[256];     /* file name without its directory, or the generator spec */
} scene;

/* Loads a file or runs a generator (see SCENE SPECS). 0 on success; on failure *out is zeroed
   and err holds one line naming the problem. */
int scene_load(const char *spec, scene *out, char *err, size_t errlen);
void scene_free(scene *s);
/* Bounds of every vertex (an empty box for an empty scene). */
bvh_aabb scene_bounds(const scene *s);
/* Multi-line summary of the SCENE SPECS above, for usage messages. */
const char *scene_spec_help(void);

/* Writes width x height RGB8 pixels (row 0 at the top): PNG for *.png (needs BVH_HAVE_STB),
   binary PPM (P6) for *.ppm. 0 on success. */
int scene_write_image(const char *path, uint32_t width, uint32_t height, const uint8_t *rgb, char *err, size_t errlen);
/* 0 when scene_write_image can write this path's format (checks the extension and PNG support
   only, not the file system): lets a program refuse --out before doing the work. */
int scene_check_image_path(const char *path, char *err, size_t errlen);
/* 1 when scene_write_image can write PNG files (built with BVH_HAVE_STB). */
int scene_can_write_png(void);
/* 1 when scene_load reads files through assimp (built with BVH_HAVE_ASSIMP). */
int scene_can_use_assimp(void);

/* Milliseconds on a monotonic clock (CLOCK_MONOTONIC when available). */
double scene_now_ms(void);
/* Median of n values (0 when n == 0); sorts values in place, so that values[0] and values[n-1]
   are then the smallest and the largest. */
double scene_median(double *values, size_t n);
/* Online CPUs (1 when unknown), at most 256: the programs' default thread count. */
uint32_t scene_cpu_count(void);
/* A command-line count: decimal digits only (no sign, no space), in [lo, hi]. With end, *end is
   set to the first character after the digits; without, nothing may follow them. 0 on success. */
int scene_parse_u32(const char *s, uint32_t lo, uint32_t hi, uint32_t *out, const char **end);
/* A frame size "WxH" (or "WXH"): each side 1 to 16384, W * H at most max_pixels. 0 on success. */
int scene_parse_size(const char *s, uint64_t max_pixels, uint32_t *w, uint32_t *h);
/* Writes s to f as a JSON string: in quotes, with '"', '\\' and control characters escaped
   (NULL: ""). */
void scene_json_string(FILE *f, const char *s);

#ifdef __cplusplus
}
#endif
#endif /* SCENE_H_INCLUDED */

/* ============================================================================================ */
/*                                      IMPLEMENTATION                                          */
/* ============================================================================================ */
#ifdef SCENE_IMPLEMENTATION
#ifndef SCENE_IMPLEMENTATION_DONE
#define SCENE_IMPLEMENTATION_DONE

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#if defined(__unix__) || defined(__APPLE__)
#include <unistd.h>
#endif

#ifdef BVH_HAVE_ASSIMP
#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#endif

#ifdef BVH_HAVE_STB
#define STB_IMAGE_WRITE_STATIC
#define STB_IMAGE_WRITE_IMPLEMENTATION
#include <stb/stb_image_write.h>
#endif

#define SCENE__PI 3.14159265358979f

/* ============================================================================================ */
/* == errors, growable triangle buffer, random numbers ========================================== */
/* ============================================================================================ */
static int scene__fail(char *err, size_t errlen, const char *fmt, ...) {
    va_list ap;
    size_t i;
    if (!err || !errlen) return 1;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
    for (i = 0; err[i]; i++) /* one line, whatever a library put in the message */
        if (err[i] == '\n' || err[i] == '\r') err[i] = ' ';
    return 1;
}

typedef struct scene__buf {
    float *v;
    size_t count, cap; /* triangles */
} scene__buf;

static int scene__reserve(scene__buf *b, size_t count) {
    float *nv;
    if (count <= b->cap) return 0;
    if (count > SIZE_MAX / (9 * sizeof(float))) return 1;
    nv = (float *)realloc(b->v, count * 9 * sizeof(float));
    if (!nv) return 1;
    b->v = nv;
    b->cap = count;
    return 0;
}
static int scene__push(scene__buf *b, const float a[3], const float c[3], const float d[3]) {
    float *t;
    if (b->count == b->cap && scene__reserve(b, b->cap < 1024 ? 1024 : b->cap * 2)) return 1;
    t = b->v + 9 * b->count++;
    memcpy(t, a, 3 * sizeof(float));
    memcpy(t + 3, c, 3 * sizeof(float));
    memcpy(t + 6, d, 3 * sizeof(float));
    return 0;
}

/* 64-bit LCG (Knuth's MMIX constants), top 24 bits as a float in [0, 1) */
static float scene__rand(uint64_t *state) {
    *state = *state * 6364136223846793005ull + 1442695040888963407ull;
    return (float)(*state >> 40) * (1.0f / 16777216.0f);
}

static const char *scene__basename(const char *path) {
    const char *s = strrchr(path, '/');
    return s ? s + 1 : path;
}
static int scene__has_ext(const char *path, const char *ext) {
    size_t n = strlen(path), e = strlen(ext), i;
    if (n < e) return 0;
    for (i = 0; i < e; i++)
        if (tolower((unsigned char)path[n - e + i]) != ext[i]) return 0;
    return 1;
}

/* ============================================================================================ */
/* == files: whole-file read, GLB and PLY completeness checks =================================== */
/* ============================================================================================ */
/* Reads the whole file (NUL-terminated); refuses missing, unreadable and empty files. */
static char *scene__read_file(const char *path, size_t *size, char *err, size_t errlen) {
    FILE *f = fopen(path, "rb");
    char *data = NULL;
    size_t cap = 0, n = 0, got = 1;
    int failed = 0;
    if (!f) {
        scene__fail(err, errlen, "cannot open '%s': %s", path, strerror(errno));
        return NULL;
    }
    while (got && !failed) {
        if (cap - n < 65536) {
            size_t ncap = cap ? cap * 2 : (size_t)1 << 20;
            char *nd = (char *)realloc(data, ncap);
            if (!nd) {
                failed = scene__fail(err, errlen, "'%s': out of memory", path);
                break;
            }
            data = nd;
            cap = ncap;
        }
        got = fread(data + n, 1, cap - n - 1, f);
        n += got;
    }
    if (!failed && ferror(f)) failed = scene__fail(err, errlen, "cannot read '%s': %s", path, strerror(errno));
    if (!failed && n == 0) failed = scene__fail(err, errlen, "'%s' is empty", path);
    fclose(f);
    if (failed) {
        free(data);
        return NULL;
    }
    data[n] = 0;
    *size = n;
    return data;
}

/* Catches a truncated binary glTF before any parser sees it (the header holds the full size). */
static int scene__check_glb(const char *path, const char *data, size_t size, char *err, size_t errlen) {
    uint32_t length;
    if (size < 4 || memcmp(data, "glTF", 4) != 0) return 0;
    if (size < 12) return scene__fail(err, errlen, "'%s': truncated GLB file (%zu bytes)", path, size);
    length = (uint32_t)(unsigned char)data[8] | (uint32_t)(unsigned char)data[9] << 8 |
             (uint32_t)(unsigned char)data[10] << 16 | (uint32_t)(unsigned char)data[11] << 24;
    if (length > size)
        return scene__fail(err, errlen, "'%s': truncated GLB file (header says %u bytes, file has %zu)", path, length,
                           size);
    return 0;
}

/* PLY: assimp 5.2 hangs, aborts or crashes on a truncated PLY file, so its body is walked first:
   every row of every element must be complete (binary: byte sizes; ASCII: enough tokens). Headers
   with more than 32 elements, or 32 properties in an element, are left to assimp unchecked. */
typedef struct scene__ply_elem {
    char name[32];
    unsigned long long count;
    uint32_t nprops;
    unsigned char size[32], count_size[32]; /* count_size > 0: a list property */
} scene__ply_elem;

static int scene__ply_type_size(const char *t, size_t n) {
    static const char *const names[16] = {"char", "int8",  "uchar", "uint8",  "short", "int16",   "ushort", "uint16",
                                          "int",  "int32", "uint",  "uint32", "float", "float32", "double", "float64"};
    static const int sizes[16] = {1, 1, 1, 1, 2, 2, 2, 2, 4, 4, 4, 4, 4, 4, 8, 8};
    int i;
    for (i = 0; i < 16; i++)
        if (strlen(names[i]) == n && memcmp(names[i], t, n) == 0) return sizes[i];
    return 0;
}

/* Splits [p, eol) into up to 4 words; returns the word count. */
static int scene__words(const char *p, const char *eol, const char *w[4], size_t len[4]) {
    int n = 0;
    while (p < eol && n < 4) {
        while (p < eol && isspace((unsigned char)*p)) p++;
        if (p >= eol) break;
        w[n] = p;
        while (p < eol && !isspace((unsigned char)*p)) p++;
        len[n] = (size_t)(p - w[n]);
        n++;
    }
    return n;
}
#define SCENE__WORD(i, s) (nw > (i) && len[i] == sizeof(s) - 1 && memcmp(w[i], s, len[i]) == 0)

/* One "property" line into element e; 0 on success, 1 malformed, 2 too many properties. */
static int scene__ply_property(scene__ply_elem *e, const char *w[4], const size_t len[4], int nw) {
    int list = SCENE__WORD(1, "list"), sz = nw > 1 + list ? scene__ply_type_size(w[1 + list], len[1 + list]) : 0;
    int item = list && nw > 3 ? scene__ply_type_size(w[3], len[3]) : 0;
    if (!sz || (list && !item)) return 1;
    if (e->nprops == 32) return 2;
    e->count_size[e->nprops] = (unsigned char)(list ? sz : 0);
    e->size[e->nprops] = (unsigned char)(list ? item : sz);
    e->nprops++;
    return 0;
}

/* Parses the header into el[]; returns the body, or NULL: truncated (*bad 0), malformed (1) or
   too big to check (2). */
static const char *scene__ply_header(const char *data, const char *end, scene__ply_elem *el, uint32_t *ne, int *format,
                                     int *bad) {
    const char *p = data;
    while (p < end) {
        const char *eol = (const char *)memchr(p, '\n', (size_t)(end - p)), *w[4] = {NULL, NULL, NULL, NULL};
        size_t len[4] = {0, 0, 0, 0};
        int nw;
        if (!eol) break;
        nw = scene__words(p, eol, w, len);
        p = eol + 1;
        if (SCENE__WORD(0, "end_header")) return p;
        if (SCENE__WORD(0, "format")) {
            *format = SCENE__WORD(1, "ascii")                  ? 0
                      : SCENE__WORD(1, "binary_little_endian") ? 1
                      : SCENE__WORD(1, "binary_big_endian")    ? 2
                                                               : -1;
        } else if (SCENE__WORD(0, "element")) {
            scene__ply_elem *e = &el[*ne];
            if (nw < 3) {
                *bad = 1;
                return NULL;
            }
            if (*ne == 32) {
                *bad = 2;
                return NULL;
            }
            memset(e, 0, sizeof *e);
            memcpy(e->name, w[1], len[1] < 31 ? len[1] : 31);
            e->count = strtoull(w[2], NULL, 10);
            (*ne)++;
        } else if (SCENE__WORD(0, "property")) {
            if (!*ne) {
                *bad = 1;
                return NULL;
            }
            if ((*bad = scene__ply_property(&el[*ne - 1], w, len, nw)) != 0) return NULL;
        }
    }
    return NULL;
}
#undef SCENE__WORD

static unsigned long long scene__ply_uint(const unsigned char *p, int size, int big_endian) {
    unsigned long long v = 0;
    int i;
    for (i = 0; i < size; i++) v |= (unsigned long long)p[big_endian ? size - 1 - i : i] << (8 * i);
    return v;
}

/* 1 when the binary body holds every row of e (advances *q past them) */
static int scene__ply_binary_ok(const scene__ply_elem *e, const unsigned char **q, const unsigned char *end, int be) {
    unsigned long long r;
    size_t row = 0;
    uint32_t k;
    for (k = 0; k < e->nprops && !e->count_size[k]; k++) row += e->size[k];
    if (k == e->nprops) { /* scalars only: one multiplication */
        if (row && e->count > (unsigned long long)(end - *q) / row) return 0;
        *q += row * e->count;
        return 1;
    }
    for (r = 0; r < e->count; r++)
        for (k = 0; k < e->nprops; k++) {
            unsigned long long n = 1, item = e->size[k];
            if (e->count_size[k]) {
                if ((size_t)(end - *q) < e->count_size[k]) return 0;
                n = scene__ply_uint(*q, e->count_size[k], be);
                *q += e->count_size[k];
            }
            if (n > (unsigned long long)(end - *q) / item) return 0;
            *q += n * item;
        }
    return 1;
}

/* 1 when the ASCII body holds every row of e, counted in whitespace-separated tokens */
static int scene__ply_ascii_ok(const scene__ply_elem *e, const char **q, const char *end) {
    unsigned long long r, n, j;
    uint32_t k;
    if (!e->nprops) return 1;
    for (r = 0; r < e->count; r++)
        for (k = 0; k < e->nprops; k++)
            for (j = 0, n = 1; j < n; j++) {
                while (*q < end && isspace((unsigned char)**q)) (*q)++;
                if (*q >= end) return 0;
                if (e->count_size[k] && j == 0) n = 1 + strtoull(*q, NULL, 10); /* the list count */
                while (*q < end && !isspace((unsigned char)**q)) (*q)++;
            }
    return 1;
}

static int scene__check_ply(const char *path, const char *data, size_t size, char *err, size_t errlen) {
    scene__ply_elem el[32];
    uint32_t ne = 0, i;
    int format = -1, bad = 0;
    const char *body, *end = data + size;
    if (size < 4 || memcmp(data, "ply", 3) != 0 || (data[3] != '\n' && data[3] != '\r')) return 0;
    body = scene__ply_header(data, end, el, &ne, &format, &bad);
    if (bad == 2) return 0;
    if (bad) return scene__fail(err, errlen, "'%s': malformed PLY header", path);
    if (!body) return scene__fail(err, errlen, "'%s': truncated PLY file (no end_header)", path);
    if (format < 0) return scene__fail(err, errlen, "'%s': PLY header without a known format line", path);
    for (i = 0; i < ne; i++) {
        const unsigned char *q = (const unsigned char *)body;
        int ok = format ? scene__ply_binary_ok(&el[i], &q, (const unsigned char *)end, format == 2)
                        : scene__ply_ascii_ok(&el[i], &body, end);
        if (format) body = (const char *)q;
        if (!ok)
            return scene__fail(err, errlen, "'%s': truncated PLY file (element '%s' ends early)", path, el[i].name);
    }
    return 0;
}

/* ============================================================================================ */
/* == files: built-in OBJ reader, assimp ======================================================== */
/* ============================================================================================ */
/* One OBJ face corner "i", "i/t", "i//n" or "i/t/n" (negative = relative); 0 on success. */
static int scene__obj_index(const char **p, size_t nverts, size_t *out) {
    char *end;
    long i = strtol(*p, &end, 10);
    if (end == *p) return 1;
    while (*end && !isspace((unsigned char)*end)) end++; /* skip /t/n */
    *p = end;
    if (i > 0 && (size_t)i <= nverts) {
        *out = (size_t)i - 1;
        return 0;
    }
    if (i < 0 && (size_t)(-(i + 1)) < nverts) {
        *out = nverts - 1 - (size_t)(-(i + 1));
        return 0;
    }
    return 1;
}

/* "v x y z" appended to *pos; 0 on success, 1 bad line, 2 out of memory. */
static int scene__obj_vertex(const char *q, const char *eol, float **pos, size_t *nv, size_t *capv) {
    float x[3];
    char *end;
    int k;
    for (k = 0; k < 3; k++, q = end) {
        x[k] = strtof(q, &end);
        if (end == q || end > eol) return 1;
    }
    if (*nv == *capv) {
        size_t ncap = *capv ? *capv * 2 : 4096;
        float *np = (float *)realloc(*pos, ncap * 3 * sizeof(float));
        if (!np) return 2;
        *pos = np;
        *capv = ncap;
    }
    memcpy(*pos + 3 * (*nv)++, x, sizeof x);
    return 0;
}

/* "f a b c ..." as a triangle fan (0, k-1, k); 0 on success, 1 bad index, 2 out of memory. */
static int scene__obj_face(const char *q, const char *eol, const float *pos, size_t nv, scene__buf *b,
                           uint32_t *skipped) {
    size_t idx[3], corners = 0;
    for (;;) {
        while (q < eol && isspace((unsigned char)*q)) q++;
        if (q >= eol) break;
        if (scene__obj_index(&q, nv, &idx[corners < 2 ? corners : 2])) return 1;
        if (++corners >= 3) {
            if (scene__push(b, pos + 3 * idx[0], pos + 3 * idx[1], pos + 3 * idx[2])) return 2;
            idx[1] = idx[2];
        }
    }
    if (corners < 3) (*skipped)++;
    return 0;
}

/* Minimal Wavefront OBJ reader: "v" and "f" lines; everything else is ignored. */
static int scene__load_obj_text(const char *path, const char *text, scene__buf *b, uint32_t *skipped, char *err,
                                size_t errlen) {
    float *pos = NULL;
    size_t nv = 0, capv = 0, line = 1;
    const char *p = text;
    int rc = 0;
    while (*p && !rc) {
        const char *eol = strchr(p, '\n');
        if (!eol) eol = p + strlen(p);
        while (p < eol && (*p == ' ' || *p == '\t')) p++;
        if (p[0] == 'v' && (p[1] == ' ' || p[1] == '\t')) {
            rc = scene__obj_vertex(p + 2, eol, &pos, &nv, &capv);
            if (rc == 1) scene__fail(err, errlen, "'%s' line %zu: bad vertex", path, line);
        } else if (p[0] == 'f' && (p[1] == ' ' || p[1] == '\t')) {
            rc = scene__obj_face(p + 2, eol, pos, nv, b, skipped);
            if (rc == 1) scene__fail(err, errlen, "'%s' line %zu: bad face index", path, line);
        }
        if (rc == 2) scene__fail(err, errlen, "'%s': out of memory", path);
        line++;
        p = *eol ? eol + 1 : eol;
    }
    free(pos);
    return rc != 0;
}

/* The built-in reader on its own: gen:field reads the bunny with it, so the generated scene is the
   same bytes whichever assimp version (or none) is installed. */
static int scene__load_obj(const char *path, scene__buf *b, uint32_t *skipped, char *err, size_t errlen) {
    size_t size = 0;
    char *data = scene__read_file(path, &size, err, errlen);
    int rc;
    if (!data) return 1;
    rc = scene__load_obj_text(path, data, b, skipped, err, errlen);
    free(data);
    if (!rc && b->count == 0) rc = scene__fail(err, errlen, "'%s' contains no triangles", path);
    return rc;
}

#ifdef BVH_HAVE_ASSIMP
/* assimp 5.2's post-processing trusts the faces a reader made, whatever the format: triangulation
   asserts on a face without indices, and a polygon with an index past its mesh's vertices crashes
   it. So the file is first imported without post-processing, with assimp's validator (which, run
   this early, checks the indices but not the index counts), and every face is checked here; only
   then is it imported for real. aiApplyPostProcessing would save the second parse, but in assimp
   5.2.5 it frees the scene twice when a step fails. */
static int scene__check_assimp(const char *path, char *err, size_t errlen) {
    const struct aiScene *s = aiImportFile(path, aiProcess_ValidateDataStructure);
    unsigned m, f, k;
    int rc = 0;
    if (!s && strstr(aiGetErrorString(), "contains no faces"))
        return scene__fail(err, errlen, "'%s' contains no triangles (assimp: %s)", path, aiGetErrorString());
    if (!s) return scene__fail(err, errlen, "cannot read '%s' as a mesh: %s", path, aiGetErrorString());
    for (m = 0; m < s->mNumMeshes && !rc; m++) {
        const struct aiMesh *mesh = s->mMeshes[m];
        if (!mesh || (mesh->mNumFaces && !mesh->mFaces))
            rc = scene__fail(err, errlen, "'%s': mesh %u has no face array", path, m);
        for (f = 0; !rc && f < mesh->mNumFaces; f++) {
            const struct aiFace *face = &mesh->mFaces[f];
            if (!face->mNumIndices || !face->mIndices)
                rc = scene__fail(err, errlen, "'%s': face %u of mesh %u has no vertex indices", path, f, m);
            for (k = 0; !rc && k < face->mNumIndices; k++)
                if (face->mIndices[k] >= mesh->mNumVertices)
                    rc = scene__fail(err, errlen, "'%s': face %u of mesh %u uses vertex %u, the mesh has %u", path, f,
                                     m, face->mIndices[k], mesh->mNumVertices);
        }
    }
    aiReleaseImport(s);
    return rc;
}

static int scene__load_assimp(const char *path, scene__buf *b, uint32_t *skipped, char *err, size_t errlen) {
    const struct aiScene *s;
    size_t total = 0;
    unsigned m, f;
    if (scene__check_assimp(path, err, errlen)) return 1;
    s = aiImportFile(path, aiProcess_Triangulate | aiProcess_PreTransformVertices);
    if (!s && strstr(aiGetErrorString(), "No output meshes"))
        return scene__fail(err, errlen, "'%s' contains no triangles (assimp: %s)", path, aiGetErrorString());
    if (!s) return scene__fail(err, errlen, "cannot read '%s' as a mesh: %s", path, aiGetErrorString());
    for (m = 0; m < s->mNumMeshes; m++) total += s->mMeshes[m]->mNumFaces;
    if (scene__reserve(b, total)) {
        aiReleaseImport(s);
        return scene__fail(err, errlen, "'%s': out of memory for %zu triangles", path, total);
    }
    for (m = 0; m < s->mNumMeshes; m++) {
        const struct aiMesh *mesh = s->mMeshes[m];
        for (f = 0; f < mesh->mNumFaces; f++) {
            const struct aiFace *face = &mesh->mFaces[f];
            float t[9];
            int k, ok = face->mNumIndices == 3;
            for (k = 0; ok && k < 3; k++) {
                unsigned i = face->mIndices[k];
                if (i >= mesh->mNumVertices) {
                    ok = 0;
                    break;
                }
                t[3 * k] = mesh->mVertices[i].x;
                t[3 * k + 1] = mesh->mVertices[i].y;
                t[3 * k + 2] = mesh->mVertices[i].z;
            }
            if (!ok) {
                (*skipped)++;
                continue;
            }
            scene__push(b, t, t + 3, t + 6); /* reserved above: cannot fail */
        }
    }
    aiReleaseImport(s);
    return 0;
}
#endif

/* A raw .tri soup (see SCENE SPECS), read as is: no check of the values. */
static int scene__load_tri(const char *path, scene__buf *b, char *err, size_t errlen) {
    size_t size = 0;
    char *data = scene__read_file(path, &size, err, errlen);
    uint32_t count = 0;
    int rc = 0;
    if (!data) return 1;
    if (size < 8 || memcmp(data, "TRI1", 4)) rc = scene__fail(err, errlen, "'%s' is not a TRI1 file", path);
    if (!rc) memcpy(&count, data + 4, sizeof count);
    if (!rc && (size - 8) / (9 * sizeof(float)) < count)
        rc = scene__fail(err, errlen, "'%s' is truncated (%u triangles announced)", path, count);
    if (!rc && scene__reserve(b, count)) rc = scene__fail(err, errlen, "'%s': out of memory", path);
    if (!rc && count) memcpy(b->v, data + 8, (size_t)count * 9 * sizeof(float));
    if (!rc) b->count = count;
    free(data);
    if (!rc && b->count == 0) rc = scene__fail(err, errlen, "'%s' contains no triangles", path);
    return rc;
}

static int scene__load_file(const char *path, scene__buf *b, uint32_t *skipped, char *err, size_t errlen) {
    size_t size = 0;
    char *data = scene__read_file(path, &size, err, errlen);
    int rc;
    if (!data) return 1;
    rc = scene__check_glb(path, data, size, err, errlen) || scene__check_ply(path, data, size, err, errlen);
#ifdef BVH_HAVE_ASSIMP
    free(data);
    data = NULL;
    if (!rc) rc = scene__load_assimp(path, b, skipped, err, errlen);
#else
    if (!rc && !scene__has_ext(path, ".obj"))
        rc = scene__fail(err, errlen,
                         "cannot read '%s': built without assimp, only .obj files load (install "
                         "libassimp-dev and rebuild)",
                         path);
    if (!rc) rc = scene__load_obj_text(path, data, b, skipped, err, errlen);
    free(data);
#endif
    if (!rc && b->count == 0) rc = scene__fail(err, errlen, "'%s' contains no triangles", path);
    return rc;
}

/* ============================================================================================ */
/* == generators ================================================================================ */
/* ============================================================================================ */
/* Ground plane y = 0 over [x0, x1] x [z0, z1], two triangles facing +y. */
static int scene__ground(scene__buf *b, float x0, float z0, float x1, float z1) {
    float a[3] = {x0, 0, z0}, c[3] = {x0, 0, z1}, d[3] = {x1, 0, z1}, e[3] = {x1, 0, z0};
    return scene__push(b, a, c, d) || scene__push(b, a, d, e);
}

/* N triangles: centres uniform in [0,1]^3, corners within +-0.5/cbrt(N) of the centre. */
static int scene__gen_random(scene__buf *b, uint32_t n) {
    uint64_t rng = 0x5eed0001u;
    float s = 1.0f / cbrtf((float)n), c[3], t[9];
    uint32_t i;
    int k;
    if (scene__reserve(b, n)) return 1;
    for (i = 0; i < n; i++) {
        for (k = 0; k < 3; k++) c[k] = scene__rand(&rng);
        for (k = 0; k < 9; k++) t[k] = c[k % 3] + (scene__rand(&rng) - 0.5f) * s;
        scene__push(b, t, t + 3, t + 6);
    }
    return 0;
}

static int scene__gen_grid(scene__buf *b, uint32_t n) {
    uint32_t x, z;
    if (scene__reserve(b, 2 * (size_t)n * n)) return 1;
    for (z = 0; z < n; z++)
        for (x = 0; x < n; x++) {
            float a[3] = {(float)x, 0, (float)z}, c[3] = {(float)x, 0, (float)z + 1};
            float d[3] = {(float)x + 1, 0, (float)z + 1}, e[3] = {(float)x + 1, 0, (float)z};
            scene__push(b, a, c, d);
            scene__push(b, a, d, e);
        }
    return 0;
}

/* One bunny copy: normalised by `norm` around the centre of lo..hi (feet at y = 0), scaled by sc,
   turned by ang about y, moved to (ox, 0, oz). */
static void scene__place_copy(scene__buf *b, const scene__buf *src, const float lo[3], const float hi[3], float sc,
                              float ang, float ox, float oz) {
    float cs = cosf(ang), sn = sinf(ang), cx = 0.5f * (lo[0] + hi[0]), cz = 0.5f * (lo[2] + hi[2]);
    size_t t, j;
    for (t = 0; t < src->count; t++) {
        float out[9];
        for (j = 0; j < 3; j++) {
            const float *p = src->v + 9 * t + 3 * j;
            float x = (p[0] - cx) * sc, y = (p[1] - lo[1]) * sc, z = (p[2] - cz) * sc;
            out[3 * j] = ox + cs * x + sn * z;
            out[3 * j + 1] = y;
            out[3 * j + 2] = oz - sn * x + cs * z;
        }
        scene__push(b, out, out + 3, out + 6); /* reserved by the caller */
    }
}

/* K bunnies on a near-square grid of 3 x 3 cells, each 2 units wide, turned by up to +-34 degrees
   about y, scaled by 0.85..1.15 and nudged inside its cell; a ground plane under them. */
static int scene__gen_field(scene__buf *b, uint32_t k, char *err, size_t errlen) {
    scene__buf bunny = {NULL, 0, 0};
    uint32_t skipped = 0, cols = 1, i;
    size_t j;
    float lo[3] = {1e30f, 1e30f, 1e30f}, hi[3] = {-1e30f, -1e30f, -1e30f}, norm, spacing = 3.0f;
    uint64_t rng = 0x5eed0002u;
    FILE *probe = fopen(SCENE_BUNNY_PATH, "rb");
    if (!probe)
        return scene__fail(err, errlen,
                           "gen:field needs the Stanford bunny %s from the Debian package glmark2-data: "
                           "sudo apt-get install glmark2-data",
                           SCENE_BUNNY_PATH);
    fclose(probe);
    if (scene__load_obj(SCENE_BUNNY_PATH, &bunny, &skipped, err, errlen)) {
        free(bunny.v);
        return 1;
    }
    for (j = 0; j < 9 * bunny.count; j++) {
        lo[j % 3] = fminf(lo[j % 3], bunny.v[j]);
        hi[j % 3] = fmaxf(hi[j % 3], bunny.v[j]);
    }
    norm = 2.0f / fmaxf(fmaxf(hi[0] - lo[0], hi[2] - lo[2]), 1e-30f);
    while (cols * cols < k) cols++;
    if (scene__reserve(b, (size_t)k * bunny.count + 2)) {
        free(bunny.v);
        return scene__fail(err, errlen, "gen:field:%u: out of memory", k);
    }
    for (i = 0; i < k; i++) {
        float ang = (scene__rand(&rng) - 0.5f) * 1.2f, sc = norm * (0.85f + 0.3f * scene__rand(&rng));
        float ox = ((float)(i % cols) + 0.5f) * spacing + (scene__rand(&rng) - 0.5f) * 0.3f;
        float oz = ((float)(i / cols) + 0.5f) * spacing + (scene__rand(&rng) - 0.5f) * 0.3f;
        scene__place_copy(b, &bunny, lo, hi, sc, ang, ox, oz);
    }
    free(bunny.v);
    return scene__ground(b, -0.5f * spacing, -0.5f * spacing, ((float)cols + 0.5f) * spacing,
                         ((float)((k + cols - 1) / cols) + 0.5f) * spacing);
}

/* A shape sampled on a (u, v) grid of nu x nv quads: a sphere (the pole rows collapse to a point
   and lose their degenerate triangle) or a torus standing upright; turned by ang about y, at c. */
typedef struct scene__shape {
    int torus;
    float r0, r1, ang, c[3];
} scene__shape;

static void scene__shape_point(const scene__shape *s, uint32_t i, uint32_t j, uint32_t nu, uint32_t nv, float out[3]) {
    float u = 2.0f * SCENE__PI * (float)(i % nu) / (float)nu, p[3];
    if (s->torus) {
        float w = 2.0f * SCENE__PI * (float)(j % nv) / (float)nv, rad = s->r0 + s->r1 * cosf(w);
        p[0] = rad * cosf(u);
        p[1] = rad * sinf(u);
        p[2] = s->r1 * sinf(w);
    } else {
        float w = SCENE__PI * (float)j / (float)nv, sw = (j == 0 || j == nv) ? 0.0f : sinf(w);
        float cw = j == 0 ? 1.0f : j == nv ? -1.0f : cosf(w);
        p[0] = s->r0 * sw * cosf(u);
        p[1] = s->r0 * cw;
        p[2] = -s->r0 * sw * sinf(u);
    }
    out[0] = s->c[0] + cosf(s->ang) * p[0] + sinf(s->ang) * p[2];
    out[1] = s->c[1] + p[1];
    out[2] = s->c[2] - sinf(s->ang) * p[0] + cosf(s->ang) * p[2];
}

static int scene__shape_emit(scene__buf *b, const scene__shape *s, uint32_t q) {
    uint32_t nu = 2 * q, nv = q, i, j;
    for (j = 0; j < nv; j++)
        for (i = 0; i < nu; i++) {
            float a[3], c[3], d[3], e[3];
            scene__shape_point(s, i, j, nu, nv, a);
            scene__shape_point(s, i + 1, j, nu, nv, c);
            scene__shape_point(s, i + 1, j + 1, nu, nv, d);
            scene__shape_point(s, i, j + 1, nu, nv, e);
            if ((s->torus || j > 0) && scene__push(b, a, e, d)) return 1;
            if ((s->torus || j + 1 < nv) && scene__push(b, a, d, c)) return 1;
        }
    return 0;
}

/* 16 objects on a 4 x 4 grid (spheres and upright tori in a checkerboard), about 4q^2 triangles
   each with q chosen so that the total is about n, on a ground plane. */
static int scene__gen_procedural(scene__buf *b, uint32_t n) {
    uint64_t rng = 0x5eed0003u;
    uint32_t q = (uint32_t)floor(sqrt((double)n / 64.0) + 0.5), i;
    float spacing = 3.0f;
    if (q < 2) q = 2;
    if (scene__reserve(b, 16 * 4 * (size_t)q * q + 2)) return 1;
    for (i = 0; i < 16; i++) {
        scene__shape s;
        s.torus = (int)((i + i / 4) & 1);
        s.r0 = s.torus ? 0.75f + 0.2f * scene__rand(&rng) : 0.6f + 0.4f * scene__rand(&rng);
        s.r1 = 0.22f + 0.1f * scene__rand(&rng);
        s.ang = 2.0f * SCENE__PI * scene__rand(&rng);
        s.c[0] = ((float)(i % 4) + 0.5f) * spacing;
        s.c[1] = s.torus ? s.r0 + s.r1 : s.r0;
        s.c[2] = ((float)(i / 4) + 0.5f) * spacing;
        if (scene__shape_emit(b, &s, q)) return 1;
    }
    return scene__ground(b, -0.5f * spacing, -0.5f * spacing, 4.5f * spacing, 4.5f * spacing);
}

/* Parses "gen:NAME:COUNT" and runs the generator. */
static int scene__generate(const char *spec, scene__buf *b, char *err, size_t errlen) {
    const char *name = spec + 4, *colon = strchr(name, ':');
    char *end;
    size_t len = colon ? (size_t)(colon - name) : strlen(name);
    unsigned long long n;
    double tris;
    int rc;
    if (!colon || !isdigit((unsigned char)colon[1]))
        return scene__fail(err, errlen, "bad scene '%s': expected gen:NAME:COUNT (e.g. gen:field:15)", spec);
    errno = 0;
    n = strtoull(colon + 1, &end, 10);
    if (*end || errno || n == 0 || n > 0xFFFFFFFFull)
        return scene__fail(err, errlen, "bad scene '%s': COUNT must be a positive integer", spec);
#define SCENE__IS(s) (len == sizeof(s) - 1 && memcmp(name, s, len) == 0)
    if (SCENE__IS("random") || SCENE__IS("procedural") || SCENE__IS("spheres"))
        tris = (double)n;
    else if (SCENE__IS("grid"))
        tris = 2.0 * (double)n * (double)n;
    else if (SCENE__IS("field"))
        tris = 69666.0 * (double)n + 2;
    else
        return scene__fail(err, errlen,
                           "unknown generator in '%s' (try gen:random:N, gen:field:K, gen:procedural:N, "
                           "gen:grid:N)",
                           spec);
    if (tris > (double)SCENE_MAX_GENERATED)
        return scene__fail(err, errlen, "'%s' would make %.0f triangles, above the limit of %u", spec, tris,
                           (unsigned)SCENE_MAX_GENERATED);
    if (SCENE__IS("random"))
        rc = scene__gen_random(b, (uint32_t)n);
    else if (SCENE__IS("grid"))
        rc = scene__gen_grid(b, (uint32_t)n);
    else if (SCENE__IS("field"))
        return scene__gen_field(b, (uint32_t)n, err, errlen);
    else
        rc = scene__gen_procedural(b, (uint32_t)n);
#undef SCENE__IS
    return rc ? scene__fail(err, errlen, "'%s': out of memory", spec) : 0;
}

/* ============================================================================================ */
/* == public functions ========================================================================== */
/* ============================================================================================ */
int scene_load(const char *spec, scene *out, char *err, size_t errlen) {
    scene__buf b = {NULL, 0, 0};
    uint32_t skipped = 0;
    int rc;
    if (err && errlen) err[0] = 0;
    if (!out) return scene__fail(err, errlen, "scene_load: no output scene");
    memset(out, 0, sizeof *out);
    if (!spec || !*spec) return scene__fail(err, errlen, "no scene given");
    if (strncmp(spec, "gen:", 4) == 0)
        rc = scene__generate(spec, &b, err, errlen);
    else if (scene__has_ext(spec, ".tri"))
        rc = scene__load_tri(spec, &b, err, errlen);
    else
        rc = scene__load_file(spec, &b, &skipped, err, errlen);
    if (!rc && b.count > 0xFFFFFFFFu) rc = scene__fail(err, errlen, "'%s': more than 2^32 triangles", spec);
    if (rc) {
        free(b.v);
        return 1;
    }
    out->v = b.v;
    out->triangles = (uint32_t)b.count;
    out->skipped = skipped;
    snprintf(out->name, sizeof out->name, "%s", strncmp(spec, "gen:", 4) == 0 ? spec : scene__basename(spec));
    return 0;
}

void scene_free(scene *s) {
    if (!s) return;
    free(s->v);
    memset(s, 0, sizeof *s);
}

bvh_aabb scene_bounds(const scene *s) {
    bvh_aabb box;
    size_t i;
    box.min.x = box.min.y = box.min.z = HUGE_VALF;
    box.max.x = box.max.y = box.max.z = -HUGE_VALF;
    for (i = 0; s && s->v && i < 3 * (size_t)s->triangles; i++) {
        const float *p = s->v + 3 * i;
        box.min.x = fminf(box.min.x, p[0]);
        box.max.x = fmaxf(box.max.x, p[0]);
        box.min.y = fminf(box.min.y, p[1]);
        box.max.y = fmaxf(box.max.y, p[1]);
        box.min.z = fminf(box.min.z, p[2]);
        box.max.z = fmaxf(box.max.z, p[2]);
    }
    return box;
}

const char *scene_spec_help(void) {
    return "SCENE is a mesh file (OBJ, PLY, glTF/GLB, 3DS... through assimp; a raw .tri soup)\n"
           "or a generator:\n"
           "  gen:random:N       N small random triangles in the unit cube\n"
           "  gen:field:K        K Stanford bunnies on a ground plane (K*69666+2 triangles;\n"
           "                     needs Debian glmark2-data)\n"
           "  gen:procedural:N   spheres and tori on a plane, about N triangles (alias gen:spheres:N)\n"
           "  gen:grid:N         N x N unit quads in the y=0 plane (2*N*N triangles)\n";
}

#ifdef BVH_HAVE_STB
static void scene__png_write(void *ctx, void *data, int size) {
    FILE *f = (FILE *)ctx;
    if (size > 0) fwrite(data, 1, (size_t)size, f);
}
#endif

int scene_check_image_path(const char *path, char *err, size_t errlen) {
    if (!path || !*path) return scene__fail(err, errlen, "no image file name");
    if (!scene__has_ext(path, ".png") && !scene__has_ext(path, ".ppm"))
        return scene__fail(err, errlen, "cannot write '%s': the file name must end in .png or .ppm", path);
#ifndef BVH_HAVE_STB
    if (scene__has_ext(path, ".png"))
        return scene__fail(err, errlen,
                           "cannot write '%s': built without PNG support (install libstb-dev and "
                           "rebuild), use a .ppm file",
                           path);
#endif
    return 0;
}

int scene_write_image(const char *path, uint32_t w, uint32_t h, const uint8_t *rgb, char *err, size_t errlen) {
    int png, ok;
    FILE *f;
    if (!path || !rgb || !w || !h) return scene__fail(err, errlen, "scene_write_image: bad argument");
    if (scene_check_image_path(path, err, errlen)) return 1;
    png = scene__has_ext(path, ".png");
    if ((size_t)w * h > (size_t)0x7FFFFFFF / 3)
        return scene__fail(err, errlen, "cannot write '%s': image too large", path);
    errno = 0;
    f = fopen(path, "wb");
    if (!f) return scene__fail(err, errlen, "cannot write '%s': %s", path, strerror(errno));
    if (png) {
#ifdef BVH_HAVE_STB
        ok = stbi_write_png_to_func(scene__png_write, f, (int)w, (int)h, 3, rgb, (int)(3 * w)) != 0;
#else
        ok = 0;
#endif
    } else {
        ok = fprintf(f, "P6\n%u %u\n255\n", w, h) > 0 && fwrite(rgb, 3 * (size_t)w, h, f) == h;
    }
    ok = !ferror(f) && ok;
    if (fclose(f) != 0) ok = 0;
    if (!ok) return scene__fail(err, errlen, "cannot write '%s': %s", path, errno ? strerror(errno) : "I/O error");
    return 0;
}

int scene_can_write_png(void) {
#ifdef BVH_HAVE_STB
    return 1;
#else
    return 0;
#endif
}

int scene_can_use_assimp(void) {
#ifdef BVH_HAVE_ASSIMP
    return 1;
#else
    return 0;
#endif
}

double scene_now_ms(void) {
#ifdef CLOCK_MONOTONIC
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
#else
    struct timespec ts; /* C11 fallback when the POSIX clock is not declared */
    timespec_get(&ts, TIME_UTC);
#endif
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

static int scene__cmp_double(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

double scene_median(double *v, size_t n) {
    if (!v || n == 0) return 0.0;
    qsort(v, n, sizeof *v, scene__cmp_double); /* up to 100,000 builds in bench/embree_side.h */
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

uint32_t scene_cpu_count(void) {
#ifdef _SC_NPROCESSORS_ONLN
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (uint32_t)(n > 256 ? 256 : n) : 1u;
#else
    return 1u;
#endif
}

int scene_parse_u32(const char *s, uint32_t lo, uint32_t hi, uint32_t *out, const char **end) {
    char *e;
    unsigned long long v;
    if (!s || *s < '0' || *s > '9') return 1;
    errno = 0;
    v = strtoull(s, &e, 10);
    if (errno || v < lo || v > hi || (!end && *e)) return 1;
    if (end) *end = e;
    *out = (uint32_t)v;
    return 0;
}

int scene_parse_size(const char *s, uint64_t max_pixels, uint32_t *w, uint32_t *h) {
    const char *e;
    if (scene_parse_u32(s, 1, 16384, w, &e) || (*e != 'x' && *e != 'X')) return 1;
    if (scene_parse_u32(e + 1, 1, 16384, h, NULL)) return 1;
    return (uint64_t)*w * *h > max_pixels;
}

void scene_json_string(FILE *f, const char *s) {
    fputc('"', f);
    for (; s && *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            fprintf(f, "\\%c", c);
        else if (c < 0x20)
            fprintf(f, "\\u%04x", c);
        else
            fputc(c, f);
    }
    fputc('"', f);
}

#endif /* SCENE_IMPLEMENTATION_DONE */
#endif /* SCENE_IMPLEMENTATION */
