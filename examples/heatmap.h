/* heatmap.h - traversal heat maps with a legend, for the bvh.h example programs (not the library)

   WHAT
     Turns a per-pixel count (nodes visited, from bvh_intersect_counted or the OpenCL frame
     kernel's `visited` output) into an RGB image: the counts colour-mapped over a FIXED scale
     0 .. scale_max (so that maps of different builders compare at a glance), with a legend strip
     added below the map: a title line, a colour bar, ticks and their labels, written with a
     built-in 5x7 bitmap font. No dependency beyond the C library.

   HOW TO INCLUDE
     In exactly ONE .c file:
         #define HEATMAP_IMPLEMENTATION
         #include "heatmap.h"
     Everywhere else just #include "heatmap.h".

   EXAMPLE
         uint32_t h2 = h + heatmap_legend_height(w);          // the legend goes below the map
         uint8_t *rgb = malloc((size_t)w * h2 * 3);
         heatmap_render(visited, w, h, 200, "ploc: nodes visited per pixel", rgb);
         scene_write_image("heat.png", w, h2, rgb, err, sizeof err);

   COLOURS
     An inferno-like ramp (black, purple, red, orange, pale yellow) interpolated between a few
     hand-picked control points: dark means cheap, bright means many nodes visited. Counts at or
     above scale_max get the top colour; the last tick label then reads "N+".

   LICENSE
     MIT, like bvh.h.
*/
#ifndef HEATMAP_H_INCLUDED
#define HEATMAP_H_INCLUDED

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Colour of x in [0, 1] (clamped) on the ramp. */
void heatmap_color(float x, uint8_t rgb[3]);
/* The smallest value v of v[0 .. n) such that a fraction p (0..1) of the values are <= v
   (nearest rank); 0 when n == 0. */
uint32_t heatmap_percentile(const uint32_t *v, size_t n, double p);
/* Height in pixels of the legend strip heatmap_render adds below a map `width` pixels wide. */
uint32_t heatmap_legend_height(uint32_t width);
/* Writes width x (height + heatmap_legend_height(width)) RGB8 pixels to rgb: v[0 .. width*height)
   (row-major, row 0 at the top) mapped over 0 .. scale_max (0 is taken as 1), then the legend:
   title (may be NULL) on the first line, the bar with ticks and labels below it. */
void heatmap_render(const uint32_t *v, uint32_t width, uint32_t height, uint32_t scale_max, const char *title,
                    uint8_t *rgb);
/* Draws text with the 5x7 font, each font pixel a scale x scale block, top-left at (x, y), clipped
   to the width x height image. Letters are drawn as capitals; unknown characters as '?'. */
void heatmap_text(uint8_t *rgb, uint32_t width, uint32_t height, int x, int y, int scale, const char *text,
                  const uint8_t color[3]);
/* Width in pixels of text drawn at this scale (6 * scale per character, minus the last gap). */
int heatmap_text_width(const char *text, int scale);

#ifdef __cplusplus
}
#endif
#endif /* HEATMAP_H_INCLUDED */

#ifdef HEATMAP_IMPLEMENTATION
#ifndef HEATMAP_IMPLEMENTATION_DONE
#define HEATMAP_IMPLEMENTATION_DONE

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ============================================================================================ */
/* == colour ramp ============================================================================= */
/* ============================================================================================ */
/* Hand-picked points along an inferno-like path: rising lightness, hue from purple to yellow. */
static const float heatmap__stops[][4] = {
    {0.00f, 0, 0, 4},      {0.18f, 50, 10, 95},   {0.36f, 120, 28, 109},  {0.54f, 190, 55, 82},
    {0.70f, 237, 105, 37}, {0.85f, 251, 175, 20}, {1.00f, 252, 250, 165},
};

void heatmap_color(float x, uint8_t rgb[3]) {
    size_t i, n = sizeof heatmap__stops / sizeof heatmap__stops[0];
    const float *a, *b;
    float f;
    int c;
    if (!(x > 0.0f)) x = 0.0f; /* also NaN */
    if (x > 1.0f) x = 1.0f;
    for (i = 1; i < n - 1 && x > heatmap__stops[i][0]; i++) {
    }
    a = heatmap__stops[i - 1];
    b = heatmap__stops[i];
    f = (x - a[0]) / (b[0] - a[0]);
    for (c = 0; c < 3; c++) rgb[c] = (uint8_t)(a[c + 1] + f * (b[c + 1] - a[c + 1]) + 0.5f);
}

uint32_t heatmap_percentile(const uint32_t *v, size_t n, double p) {
    uint32_t max = 0, k;
    size_t i, rank, seen = 0, *count;
    if (!v || !n) return 0;
    for (i = 0; i < n; i++) max = v[i] > max ? v[i] : max;
    rank = p <= 0.0 ? 1 : p >= 1.0 ? n : (size_t)(p * (double)n + 0.999999);
    if (rank < 1) rank = 1;
    count = (size_t *)calloc((size_t)max + 1, sizeof *count); /* values are node counts: small */
    if (!count) return max;
    for (i = 0; i < n; i++) count[v[i]]++;
    for (k = 0; k < max; k++) {
        seen += count[k];
        if (seen >= rank) break;
    }
    free(count);
    return k;
}

/* ============================================================================================ */
/* == 5x7 font ================================================================================ */
/* ============================================================================================ */
/* One glyph per character of heatmap__chars: 7 rows top to bottom, bit 4 the leftmost column. */
static const char heatmap__chars[] = "0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ .,:-+/()%=_?<>";
static const uint8_t heatmap__glyphs[][7] = {
    {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E}, {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E}, /* 0 1 */
    {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F}, {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E}, /* 2 3 */
    {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02}, {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E}, /* 4 5 */
    {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E}, {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08}, /* 6 7 */
    {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E}, {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C}, /* 8 9 */
    {0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11}, {0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E}, /* A B */
    {0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E}, {0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C}, /* C D */
    {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F}, {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10}, /* E F */
    {0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F}, {0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11}, /* G H */
    {0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E}, {0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C}, /* I J */
    {0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11}, {0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F}, /* K L */
    {0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11}, {0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11}, /* M N */
    {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}, {0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10}, /* O P */
    {0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D}, {0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11}, /* Q R */
    {0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E}, {0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04}, /* S T */
    {0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}, {0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04}, /* U V */
    {0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A}, {0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11}, /* W X */
    {0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04}, {0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F}, /* Y Z */
    {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00}, {0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C}, /* space . */
    {0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08}, {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00}, /* , : */
    {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00}, {0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00}, /* - + */
    {0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00}, {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02}, /* / ( */
    {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08}, {0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03}, /* ) % */
    {0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00}, {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F}, /* = _ */
    {0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04}, {0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02}, /* ? < */
    {0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08},                                             /* > */
};
typedef char heatmap__one_glyph_per_char[sizeof heatmap__glyphs / 7 == sizeof heatmap__chars - 1 ? 1 : -1];

static const uint8_t *heatmap__glyph(char ch) {
    const char *p;
    if (ch >= 'a' && ch <= 'z') ch = (char)(ch - 'a' + 'A');
    p = ch ? strchr(heatmap__chars, ch) : NULL;
    return heatmap__glyphs[p ? (size_t)(p - heatmap__chars) : sizeof heatmap__chars - 4]; /* '?' */
}

static void heatmap__fill(uint8_t *rgb, uint32_t w, uint32_t h, int x0, int y0, int x1, int y1, const uint8_t c[3]) {
    int x, y;
    if (x0 < 0) x0 = 0;
    if (y0 < 0) y0 = 0;
    if (x1 > (int)w) x1 = (int)w;
    if (y1 > (int)h) y1 = (int)h;
    for (y = y0; y < y1; y++)
        for (x = x0; x < x1; x++) memcpy(rgb + 3 * ((size_t)y * w + (size_t)x), c, 3);
}

int heatmap_text_width(const char *text, int scale) {
    size_t n = text ? strlen(text) : 0;
    return n ? (int)(6 * n - 1) * scale : 0;
}

void heatmap_text(uint8_t *rgb, uint32_t width, uint32_t height, int x, int y, int scale, const char *text,
                  const uint8_t color[3]) {
    int row, col;
    if (!rgb || !text || scale < 1) return;
    for (; *text && x < (int)width; text++, x += 6 * scale) {
        const uint8_t *g = heatmap__glyph(*text);
        for (row = 0; row < 7; row++)
            for (col = 0; col < 5; col++)
                if (g[row] & (0x10 >> col))
                    heatmap__fill(rgb, width, height, x + col * scale, y + row * scale, x + (col + 1) * scale,
                                  y + (row + 1) * scale, color);
    }
}

/* ============================================================================================ */
/* == map and legend ========================================================================== */
/* ============================================================================================ */
/* Font scale of the legend: 1 below 600 pixels wide, 2 below 1200, 3 above. */
static int heatmap__scale(uint32_t width) { return width < 600 ? 1 : width < 1200 ? 2 : 3; }

/* Strip layout in font pixels (s each): 4 margin, 7 title, 4 gap, 8 bar, 3 ticks, 2 gap, 7
   labels, 4 margin. */
uint32_t heatmap_legend_height(uint32_t width) { return 39u * (uint32_t)heatmap__scale(width); }

/* Tick step: 1, 2 or 5 times a power of ten, giving at most 5 intervals up to max. */
static uint32_t heatmap__step(uint32_t max) {
    uint32_t p = 1;
    for (;;) {
        if (max <= 5 * p) return p;
        if (max <= 10 * p) return 2 * p;
        if (max <= 25 * p || p > 0xFFFFFFFFu / 100) return 5 * p;
        p *= 10;
    }
}

/* Where the label of a tick at tx starts: centred, kept inside the strip. */
static int heatmap__label_x(int tx, int lw, uint32_t w, int m) {
    int lx = tx - lw / 2;
    if (lx + lw > (int)w - m) lx = (int)w - m - lw;
    return lx < m ? m : lx;
}

static void heatmap__legend(uint8_t *rgb, uint32_t w, uint32_t h, uint32_t y0, uint32_t max, const char *title) {
    static const uint8_t bg[3] = {28, 28, 34}, fg[3] = {235, 235, 235};
    int s = heatmap__scale(w), ts = s, m = 4 * s, bx0 = m, bx1 = (int)w - m, by = (int)y0 + 15 * s, x;
    int prev_end = -1000000, max_lx;
    uint32_t v, step = heatmap__step(max);
    char label[16];
    heatmap__fill(rgb, w, h, 0, (int)y0, (int)w, (int)h, bg);
    if (title) { /* a smaller font when the title does not fit */
        while (ts > 1 && heatmap_text_width(title, ts) > (int)w - 2 * m) ts--;
        heatmap_text(rgb, w, h, m, (int)y0 + 4 * s + (7 * (s - ts)) / 2, ts, title, fg);
    }
    if (bx1 - bx0 < 2) return;
    for (x = bx0; x < bx1; x++) {
        uint8_t c[3];
        heatmap_color((float)(x - bx0) / (float)(bx1 - bx0 - 1), c);
        heatmap__fill(rgb, w, h, x, by, x + 1, by + 8 * s, c);
    }
    heatmap__fill(rgb, w, h, bx0 - 1, by - 1, bx1 + 1, by, fg); /* frame */
    heatmap__fill(rgb, w, h, bx0 - 1, by + 8 * s, bx1 + 1, by + 8 * s + 1, fg);
    heatmap__fill(rgb, w, h, bx0 - 1, by, bx0, by + 8 * s, fg);
    heatmap__fill(rgb, w, h, bx1, by, bx1 + 1, by + 8 * s, fg);
    /* ticks at the multiples of step and at max; the label "max+" is always drawn, the others
       where they overlap neither their left neighbour nor "max+" */
    snprintf(label, sizeof label, "%u+", max);
    max_lx = heatmap__label_x(bx1 - 1, heatmap_text_width(label, s), w, m / 2);
    for (v = 0;; v = v + step < v || v + step > max ? max : v + step) {
        int last = v == max, tx = bx0 + (int)((double)v / max * (bx1 - bx0 - 1) + 0.5), lw, lx;
        snprintf(label, sizeof label, last ? "%u+" : "%u", v);
        lw = heatmap_text_width(label, s);
        lx = heatmap__label_x(tx, lw, w, m / 2);
        heatmap__fill(rgb, w, h, tx - s / 2, by + 8 * s, tx - s / 2 + s, by + 11 * s, fg);
        if (last || (lx > prev_end + 2 * s && lx + lw + 2 * s < max_lx)) {
            heatmap_text(rgb, w, h, lx, by + 13 * s, s, label, fg);
            prev_end = lx + lw;
        }
        if (last) break;
    }
}

void heatmap_render(const uint32_t *v, uint32_t width, uint32_t height, uint32_t scale_max, const char *title,
                    uint8_t *rgb) {
    size_t i, n = (size_t)width * height;
    uint8_t lut[256][3];
    float inv;
    if (!v || !rgb || !width) return;
    if (!scale_max) scale_max = 1;
    inv = 1.0f / (float)scale_max;
    for (i = 0; i < 256; i++) heatmap_color((float)i / 255.0f, lut[i]);
    for (i = 0; i < n; i++) {
        float x = (float)v[i] * inv;
        memcpy(rgb + 3 * i, lut[x >= 1.0f ? 255 : (int)(x * 255.0f + 0.5f)], 3);
    }
    heatmap__legend(rgb, width, height + heatmap_legend_height(width), height, scale_max, title);
}

#endif /* HEATMAP_IMPLEMENTATION_DONE */
#endif /* HEATMAP_IMPLEMENTATION */
