/* The height grid the native kernels read, and its bilinear lookup (shared by height_march.c and
 * body_state.c).
 *
 * Heights h[i * ny + j] lie at world (x0 + i res, y0 + j res), bilinear between, clamped at the
 * border (torch.grid_sample with align_corners=True, padding_mode="border"); float32 arithmetic,
 * as in legoh_rl.envs.height_map.HeightMap. */
#ifndef LEGOH_RL_HEIGHT_MAP_H
#define LEGOH_RL_HEIGHT_MAP_H
#include <math.h>
#include <stdint.h>

typedef struct {
    const float *h;
    int64_t nx, ny;
    float x0, y0, inv_res;
    const float *cmax; /* coarse max map (height_march.c's COARSE_SHIFT) or NULL; cny its columns */
    int64_t cny;
} hmap_t;

/* Bilinear height at fractional cell coordinates (ix along x, iy along y); NaN in, NaN out. */
static inline float bilinear(const hmap_t *m, float ix, float iy) {
    const float xmax = (float)(m->nx - 1), ymax = (float)(m->ny - 1);
    if (ix != ix || iy != iy) return NAN;
    if (!(ix > 0.0f)) ix = 0.0f; else if (ix > xmax) ix = xmax;
    if (!(iy > 0.0f)) iy = 0.0f; else if (iy > ymax) iy = ymax;
    int64_t i = (int64_t)ix, j = (int64_t)iy;
    if (i > m->nx - 2) i = m->nx - 2;
    if (j > m->ny - 2) j = m->ny - 2;
    const float fx = ix - (float)i, fy = iy - (float)j;
    const float *p = m->h + i * m->ny + j;
    const float a = p[0] + (p[1] - p[0]) * fy;
    const float b = p[m->ny] + (p[m->ny + 1] - p[m->ny]) * fy;
    return a + (b - a) * fx;
}

static inline float height_at(const hmap_t *m, float x, float y) {
    return bilinear(m, (x - m->x0) * m->inv_res, (y - m->y0) * m->inv_res);
}

#endif
