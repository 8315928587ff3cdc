/* Height-map ray march and bilinear lookups for the depth camera, in plain C.
 *
 * The same algorithm as legoh_rl.envs.sensors.march_ground (the torch reference): each ray is
 * sampled at `samples` points between its bracket ends t0 and t1, the first sample below the
 * ground brackets the hit, and `refine` regula-falsi steps locate it. Written per ray, the march
 * stops at its first sample below the ground and touches nothing after it, which the vectorised
 * torch version cannot do; rays are split across POSIX threads (parallel.c).
 *
 * Heights h[i * ny + j] lie at world (x0 + i res, y0 + j res), bilinear between, clamped at the
 * border (torch.grid_sample with align_corners=True, padding_mode="border"). All arithmetic is
 * float32, as in the torch reference. Built by legoh_rl/envs/native/build.py with the system C
 * compiler and loaded through ctypes.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "height_map.h"
#include "obstacle_cast.h"
#include "parallel.h"

#define MAX_SAMPLES 1024
#define BLOCK 512 /* rays per work block; threads take blocks in turn, which balances the load */

/* Coarse blocks of the optional max map: block (I, J) holds the highest height of fine samples
 * i in [I B, I B + B], j in [J B, J B + B] (B = 1 << COARSE_SHIFT), so it bounds every bilinear
 * value whose cell (i, j) = (floor ix, floor iy) lies in the block. */
#define COARSE_SHIFT 3
/* A sample is skipped only when the ray is this far above the block's maximum (m): far more than
 * the bilinear blend's rounding, so a skipped sample is surely above the ground. */
#define COARSE_MARGIN 1e-3f

/* Whether a point at height z above fractional cell (ix, iy) is surely above the height map,
 * from the coarse max map alone (0 when there is none or the coordinates are NaN). */
static inline int surely_above(const hmap_t *m, float ix, float iy, float z) {
    if (!m->cmax || ix != ix || iy != iy) return 0;
    const float xmax = (float)(m->nx - 1), ymax = (float)(m->ny - 1);
    if (!(ix > 0.0f)) ix = 0.0f; else if (ix > xmax) ix = xmax;
    if (!(iy > 0.0f)) iy = 0.0f; else if (iy > ymax) iy = ymax;
    int64_t i = (int64_t)ix, j = (int64_t)iy;
    if (i > m->nx - 2) i = m->nx - 2;
    if (j > m->ny - 2) j = m->ny - 2;
    return z > m->cmax[(i >> COARSE_SHIFT) * m->cny + (j >> COARSE_SHIFT)] + COARSE_MARGIN;
}

static inline float interp(float t_lo, float t_hi, float f_lo, float f_hi) {
    float denom = f_lo - f_hi;
    if (!(denom > 1e-9f)) denom = 1e-9f;
    float w = f_lo / denom;
    w = w < 0.0f ? 0.0f : (w > 1.0f ? 1.0f : w);
    return t_lo + (t_hi - t_lo) * w;
}

/* Distance along the unit ray o + t d to its first crossing of the height map, INFINITY if it
 * stays above. z_max / z_min / t_min: the optional bracket bounds (NAN = none), as in
 * march_ground. frac[s] = s / samples. */
static inline float march_ray(const hmap_t *m, const float *o, const float *d, float tm, float z_max,
                              float z_min, float t_min, int samples, int refine, const float *frac) {
    const float oz = o[2], dz = d[2];
    const float gx = (o[0] - m->x0) * m->inv_res, gy = (o[1] - m->y0) * m->inv_res;
    const float dgx = d[0] * m->inv_res, dgy = d[1] * m->inv_res;
    const int down = dz < 0.0f;
    float nd = -dz;
    if (!(nd > 1e-6f)) nd = 1e-6f;
    const float inv_down = 1.0f / nd;
    float t0 = 0.0f;
    if (z_max == z_max) {
        const float above = oz - z_max;
        if (down) t0 = fmaxf(above * inv_down, 0.0f);
        else if (above > 0.0f) t0 = tm;
        t0 = fminf(t0, tm);
    }
    if (t_min == t_min) t0 = fminf(fmaxf(t0, t_min), tm);
    if (z_min == z_min) {
        const float depth = oz - z_min + 1e-3f;
        if (down) tm = fminf(tm, fmaxf(depth, 0.0f) * inv_down);
        tm = fmaxf(tm, t0);
    }
    const float span = tm - t0;
    /* an empty bracket (a ray that never descends into the terrain's band of heights: the sky)
     * puts every sample at t0: one evaluation gives the loop's answer */
    const int n_samples = span > 0.0f ? samples : 1;
    float t_lo = t0, f_lo = 0.0f, t_hi = 0.0f, f_hi = 0.0f;
    int hit = 0, first = 1, lazy = 0;
    for (int s = 1; s <= n_samples; ++s) {
        const float t = t0 + span * frac[s];
        /* a sample surely above the terrain (coarse max map) needs no lookup; its value is
         * computed below only if the next sample brackets the hit */
        if (surely_above(m, gx + t * dgx, gy + t * dgy, oz + t * dz)) {
            t_lo = t;
            first = 0;
            lazy = 1;
            continue;
        }
        const float f = oz + t * dz - bilinear(m, gx + t * dgx, gy + t * dgy);
        if (f <= 0.0f) {
            t_hi = t;
            f_hi = f;
            hit = 1;
            break;
        }
        t_lo = t;
        f_lo = f;
        first = 0;
        lazy = 0;
    }
    if (!hit) return INFINITY;
    if (first) f_lo = oz + t0 * dz - bilinear(m, gx + t0 * dgx, gy + t0 * dgy);
    else if (lazy) f_lo = oz + t_lo * dz - bilinear(m, gx + t_lo * dgx, gy + t_lo * dgy);
    for (int r = 0; r < refine; ++r) {
        const float t = interp(t_lo, t_hi, f_lo, f_hi);
        const float f = oz + t * dz - bilinear(m, gx + t * dgx, gy + t * dgy);
        if (f > 0.0f) {
            t_lo = t;
            f_lo = f;
        } else {
            t_hi = t;
            f_hi = f;
        }
    }
    return interp(t_lo, t_hi, f_lo, f_hi);
}

static void fill_frac(float *frac, int samples) {
    for (int s = 0; s <= samples; ++s) frac[s] = (float)s / (float)samples;
}

/* ---------------------------------------------------------------- rays given per world */

typedef struct {
    hmap_t map;
    const float *origin, *dirs, *t_max, *z_max, *z_min, *t_min;
    int64_t rays_per_world;
    int samples, refine;
    const float *frac;
    double *out;
} march_ctx_t;

static void march_block(const void *arg, int64_t begin, int64_t end) {
    const march_ctx_t *C = (const march_ctx_t *)arg;
    int64_t w = begin / C->rays_per_world, next = (w + 1) * C->rays_per_world;
    for (int64_t k = begin; k < end; ++k) {
        if (k == next) { /* no division per ray: it costs as much as a march sample */
            ++w;
            next += C->rays_per_world;
        }
        const float t = march_ray(&C->map, C->origin + 3 * w, C->dirs + 3 * k, C->t_max[k],
                                  C->z_max ? C->z_max[w] : NAN, C->z_min ? C->z_min[w] : NAN,
                                  C->t_min ? C->t_min[k] : NAN, C->samples, C->refine, C->frac);
        C->out[k] = (double)t;
    }
}

/* Marches rays o_w + t d_wr: origin (n, 3), dirs (n, R, 3) unit, t_max (n, R); z_max, z_min (n,)
 * and t_min (n, R) may be NULL. out (n, R): distance to the hit, INFINITY for none. cmax: the
 * map's coarse max map (see COARSE_SHIFT; cny columns) to skip lookups, or NULL. */
int lh_march(const float *h, int64_t nx, int64_t ny, float x0, float y0, float inv_res,
             const float *cmax, int64_t cny, const float *origin, const float *dirs, const float *t_max,
             const float *z_max, const float *z_min, const float *t_min, int64_t n_worlds, int64_t rays_per_world,
             int samples, int refine, double *out, int threads) {
    if (samples < 1 || samples > MAX_SAMPLES || refine < 0) return -2;
    float frac[MAX_SAMPLES + 1];
    fill_frac(frac, samples);
    const march_ctx_t ctx = {{h, nx, ny, x0, y0, inv_res, cmax, cny}, origin, dirs, t_max, z_max, z_min, t_min,
                             rays_per_world, samples, refine, frac, out};
    return lh_parallel_for(march_block, &ctx, n_worlds * rays_per_world, BLOCK, threads);
}

/* ---------------------------------------------------------------- the head camera, fused */

typedef struct {
    hmap_t surface, ground;
    const float *cam_pos, *cam_mat, *dirs_cam, *t_max, *z_max, *z_min;
    int64_t rays;
    int samples, refine;
    float obstacle_margin;
    const float *frac;
    double *dist;
    uint8_t *on_obstacle;
    const obs_ctx_t *obstacles; /* geoms to resolve flagged rays against, or NULL (flags only) */
} camera_ctx_t;

/* Flagged rays of one chunk (at most CULL consecutive rays), in the obstacle caster's layout. */
typedef struct {
    int64_t k[CULL], w[CULL];
    float d[CULL][3], t_surface[CULL], t_max[CULL];
    double o[3 * CULL], dd[3 * CULL], tm[CULL], out[CULL];
    int n;
} flagged_t;

/* The exact distance of each flagged ray: the nearer of the obstacle geoms and the bare ground,
 * marched from where the ray met the surface (the ground lies at or below it). */
static void resolve_flagged(const camera_ctx_t *C, flagged_t *F, int64_t *survivors) {
    obs_ctx_t rays = *C->obstacles;
    rays.o = F->o;
    rays.d = F->dd;
    rays.tm = F->tm;
    rays.out = F->out;
    rays.M = F->n;
    lh_cast_rays(&rays, 0, F->n, survivors);
    for (int i = 0; i < F->n; ++i) {
        const int64_t w = F->w[i];
        const float g = march_ray(&C->ground, C->cam_pos + 3 * w, F->d[i], F->t_max[i],
                                  C->z_max ? C->z_max[w] : NAN, C->z_min ? C->z_min[w] : NAN, F->t_surface[i],
                                  C->samples, C->refine, C->frac);
        C->dist[F->k[i]] = fmin(F->out[i], (double)g);
    }
    F->n = 0;
}

static void camera_block(const void *arg, int64_t begin, int64_t end) {
    const camera_ctx_t *C = (const camera_ctx_t *)arg;
    int64_t w = begin / C->rays, r = begin - w * C->rays;
    flagged_t F;
    F.n = 0;
    /* the obstacle cull's scratch; without memory every flagged ray tests every geom (same result) */
    int64_t *survivors = NULL;
    if (C->obstacles && C->obstacles->G > 0) survivors = (int64_t *)malloc(sizeof(int64_t) * (size_t)C->obstacles->G);
    for (int64_t k = begin; k < end; ++k, ++r) {
        if (r == C->rays) {
            ++w;
            r = 0;
        }
        const float *o = C->cam_pos + 3 * w, *R = C->cam_mat + 9 * w, *c = C->dirs_cam + 3 * r;
        const float d[3] = {R[0] * c[0] + R[1] * c[1] + R[2] * c[2], R[3] * c[0] + R[4] * c[1] + R[5] * c[2],
                            R[6] * c[0] + R[7] * c[1] + R[8] * c[2]};
        const float t = march_ray(&C->surface, o, d, C->t_max[r], C->z_max ? C->z_max[w] : NAN,
                                  C->z_min ? C->z_min[w] : NAN, NAN, C->samples, C->refine, C->frac);
        C->dist[k] = (double)t;
        uint8_t flag = 0;
        if (t < INFINITY) { /* the hit's height above the bare ground: an obstacle's top or side */
            const float hz = o[2] + t * d[2];
            flag = hz - height_at(&C->ground, o[0] + t * d[0], o[1] + t * d[1]) > C->obstacle_margin;
        }
        C->on_obstacle[k] = flag;
        if (flag && C->obstacles) {
            const int i = F.n++;
            F.k[i] = k;
            F.w[i] = w;
            F.t_surface[i] = t;
            F.t_max[i] = C->t_max[r];
            F.tm[i] = (double)C->t_max[r];
            for (int a = 0; a < 3; ++a) {
                F.d[i][a] = d[a];
                F.o[3 * i + a] = (double)o[a];
                F.dd[3 * i + a] = (double)d[a];
            }
            if (F.n == CULL) resolve_flagged(C, &F, survivors);
        }
    }
    if (F.n) resolve_flagged(C, &F, survivors);
    free(survivors);
}

/* The head cameras of n worlds: pixel rays dirs_cam (R, 3) unit in the camera frame, rotated by
 * cam_mat (n, 3, 3) (row-major, columns = camera axes in the world) from cam_pos (n, 3), marched
 * against the surface map up to t_max (R,). dist (n, R): distance to the hit (INFINITY for
 * none); on_obstacle (n, R): the hit lies more than obstacle_margin above the bare ground.
 * cmax / gcmax: the surface's / ground's coarse max maps (cny columns each, one grid) or NULL,
 * as in lh_march. With obstacle geoms (G >= 0 and kind not NULL; the arrays of lh_obstacle_cast)
 * the flagged rays are resolved here: dist becomes the nearer of the geoms and the bare ground
 * marched from the surface hit, as ObstacleRayCaster.cast plus lh_march would give. */
int lh_camera(const float *surface, const float *ground, int64_t nx, int64_t ny, float x0, float y0,
              float inv_res, const float *cmax, const float *gcmax, int64_t cny, const float *cam_pos,
              const float *cam_mat, const float *dirs_cam, const float *t_max, const float *z_max,
              const float *z_min, int64_t n_worlds, int64_t rays, int samples, int refine, float obstacle_margin,
              double *dist, uint8_t *on_obstacle, int64_t G, const int32_t *kind, const double *pos,
              const double *mat, const double *size, const double *r2, const int64_t *plane_start,
              const int64_t *plane_count, const double *planes, int threads) {
    if (samples < 1 || samples > MAX_SAMPLES || refine < 0) return -2;
    float frac[MAX_SAMPLES + 1];
    fill_frac(frac, samples);
    const obs_ctx_t geoms = {G, kind, pos, mat, size, r2, plane_start, plane_count, planes, NULL, NULL, NULL, NULL, 0};
    const camera_ctx_t ctx = {{surface, nx, ny, x0, y0, inv_res, cmax, cny},
                              {ground, nx, ny, x0, y0, inv_res, gcmax, cny},
                              cam_pos, cam_mat, dirs_cam, t_max, z_max, z_min, rays, samples, refine,
                              obstacle_margin, frac, dist, on_obstacle, kind ? &geoms : NULL};
    return lh_parallel_for(camera_block, &ctx, n_worlds * rays, BLOCK, threads);
}

/* Bilinear heights at m world points xy (m, 2) -> out (m,). The points are rounded to float, as
 * the march's are; the heights come back as double. */
void lh_heights(const float *h, int64_t nx, int64_t ny, float x0, float y0, float inv_res,
                const double *xy, int64_t m, double *out) {
    const hmap_t map = {h, nx, ny, x0, y0, inv_res, NULL, 0};
    for (int64_t k = 0; k < m; ++k) out[k] = (double)height_at(&map, (float)xy[2 * k], (float)xy[2 * k + 1]);
}

/* Heights at k points around each of n robots: offsets (k, 2) in the yaw frame of a robot at xy
 * (n, 2) (world, m) with heading yaw (n,) -> out (n, k), row-major. */
void lh_heights_around(const float *h, int64_t nx, int64_t ny, float x0, float y0, float inv_res,
                       const double *xy, const double *yaw, const double *offsets, int64_t n, int64_t k,
                       double *out) {
    const hmap_t map = {h, nx, ny, x0, y0, inv_res, NULL, 0};
    for (int64_t i = 0; i < n; ++i) {
        const double c = cos(yaw[i]), s = sin(yaw[i]), bx = xy[2 * i], by = xy[2 * i + 1];
        double *row = out + i * k;
        for (int64_t j = 0; j < k; ++j) {
            const double ox = offsets[2 * j], oy = offsets[2 * j + 1];
            row[j] = (double)height_at(&map, (float)(bx + c * ox - s * oy), (float)(by + s * ox + c * oy));
        }
    }
}
