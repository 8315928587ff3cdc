/* Height-map ray march and bilinear lookups for the depth camera, in plain C.
 *
 * The same algorithm as legoh_rl.envs.sensors.march_ground (the torch reference): each ray is
 * sampled at `samples` points between its bracket ends t0 and t1, the first sample below the
 * ground brackets the hit, and `refine` regula-falsi steps locate it. Written per ray, the march
 * stops at its first sample below the ground and touches nothing after it, which the vectorised
 * torch version cannot do; rays are split across POSIX threads.
 *
 * Heights h[i * ny + j] lie at world (x0 + i res, y0 + j res), bilinear between, clamped at the
 * border (torch.grid_sample with align_corners=True, padding_mode="border"). All arithmetic is
 * float32, as in the torch reference. Built by legoh_rl/envs/native_march.py with the system C
 * compiler and loaded through ctypes.
 */
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>

typedef struct {
    const float *h;
    int64_t nx, ny;
    float x0, y0, inv_res;
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

typedef struct {
    hmap_t map;
    const float *origin;  /* (n, 3) */
    const float *dirs;    /* (n, R, 3) unit */
    const float *t_max;   /* (n, R) */
    const float *z_max;   /* (n,) or NULL */
    const float *z_min;   /* (n,) or NULL */
    const float *t_min;   /* (n, R) or NULL */
    int64_t rays_per_world;
    int samples, refine;
    double *out;          /* (n, R) */
    int64_t begin, end;   /* flat ray range of this job */
} march_job_t;

static inline float interp(float t_lo, float t_hi, float f_lo, float f_hi) {
    float denom = f_lo - f_hi;
    if (!(denom > 1e-9f)) denom = 1e-9f;
    float w = f_lo / denom;
    w = w < 0.0f ? 0.0f : (w > 1.0f ? 1.0f : w);
    return t_lo + (t_hi - t_lo) * w;
}

static void march_range(const march_job_t *J) {
    const hmap_t *m = &J->map;
    float frac[J->samples + 1];  /* s / samples, rounded as torch's arange(1, S + 1) / S */
    for (int s = 0; s <= J->samples; ++s) frac[s] = (float)s / (float)J->samples;
    int64_t w = J->begin / J->rays_per_world, next_world = (w + 1) * J->rays_per_world;
    for (int64_t k = J->begin; k < J->end; ++k) {
        if (k == next_world) {
            ++w;
            next_world += J->rays_per_world;
        }
        const float *o = J->origin + 3 * w, *d = J->dirs + 3 * k;
        const float oz = o[2], dz = d[2];
        const float gx = (o[0] - m->x0) * m->inv_res, gy = (o[1] - m->y0) * m->inv_res;
        const float dgx = d[0] * m->inv_res, dgy = d[1] * m->inv_res;
        const int down = dz < 0.0f;
        float nd = -dz;
        if (!(nd > 1e-6f)) nd = 1e-6f;
        const float inv_down = 1.0f / nd;
        float tm = J->t_max[k], t0 = 0.0f;
        if (J->z_max) {
            const float above = oz - J->z_max[w];
            if (down) t0 = fmaxf(above * inv_down, 0.0f);
            else if (above > 0.0f) t0 = tm;
            t0 = fminf(t0, tm);
        }
        if (J->t_min) t0 = fminf(fmaxf(t0, J->t_min[k]), tm);
        if (J->z_min) {
            const float depth = oz - J->z_min[w] + 1e-3f;
            if (down) tm = fminf(tm, fmaxf(depth, 0.0f) * inv_down);
            tm = fmaxf(tm, t0);
        }
        const float span = tm - t0;
        float t_lo = t0, f_lo = 0.0f, t_hi = 0.0f, f_hi = 0.0f;
        int hit = 0, first = 1;
        for (int s = 1; s <= J->samples; ++s) {
            const float t = t0 + span * frac[s];
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
        }
        if (!hit) {
            J->out[k] = INFINITY;
            continue;
        }
        if (first) f_lo = oz + t0 * dz - bilinear(m, gx + t0 * dgx, gy + t0 * dgy);
        for (int r = 0; r < J->refine; ++r) {
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
        J->out[k] = (double)interp(t_lo, t_hi, f_lo, f_hi);
    }
}

#define BLOCK 512 /* rays per work block; threads take blocks in turn, which balances the load */

typedef struct {
    march_job_t job;
    int64_t n_rays;
    int index, threads;
} worker_t;

static void *march_worker(void *arg) {
    const worker_t *W = (const worker_t *)arg;
    march_job_t J = W->job;
    for (int64_t b = (int64_t)W->index * BLOCK; b < W->n_rays; b += (int64_t)W->threads * BLOCK) {
        J.begin = b;
        J.end = b + BLOCK < W->n_rays ? b + BLOCK : W->n_rays;
        march_range(&J);
    }
    return NULL;
}

/* Marches the n_worlds * rays_per_world rays on `threads` threads (blocks of BLOCK rays taken in
 * turn). Returns 0, or -1 when a thread could not be started (the calling thread then marches
 * that thread's blocks itself). */
int lh_march(const float *h, int64_t nx, int64_t ny, float x0, float y0, float inv_res,
             const float *origin, const float *dirs, const float *t_max, const float *z_max,
             const float *z_min, const float *t_min, int64_t n_worlds, int64_t rays_per_world,
             int samples, int refine, double *out, int threads) {
    const int64_t n = n_worlds * rays_per_world;
    const int64_t blocks = (n + BLOCK - 1) / BLOCK;
    if (threads < 1) threads = 1;
    if (threads > 64) threads = 64;
    if ((int64_t)threads > blocks) threads = blocks > 0 ? (int)blocks : 1;
    const march_job_t job = {{h, nx, ny, x0, y0, inv_res}, origin, dirs, t_max, z_max, z_min, t_min,
                             rays_per_world, samples, refine, out, 0, 0};
    worker_t workers[64];
    pthread_t tids[64];
    int started[64] = {0};
    int rc = 0;
    for (int i = 0; i < threads; ++i) {
        workers[i].job = job;
        workers[i].n_rays = n;
        workers[i].index = i;
        workers[i].threads = threads;
    }
    for (int i = 1; i < threads; ++i) {
        started[i] = pthread_create(&tids[i], NULL, march_worker, &workers[i]) == 0;
        if (!started[i]) rc = -1;
    }
    march_worker(&workers[0]);
    for (int i = 1; i < threads; ++i) {
        if (started[i]) pthread_join(tids[i], NULL);
        else march_worker(&workers[i]);
    }
    return rc;
}

/* Bilinear heights at m world points xy (m, 2) -> out (m,). */
void lh_heights(const float *h, int64_t nx, int64_t ny, float x0, float y0, float inv_res,
                const float *xy, int64_t m, float *out) {
    hmap_t map = {h, nx, ny, x0, y0, inv_res};
    for (int64_t k = 0; k < m; ++k)
        out[k] = bilinear(&map, (xy[2 * k] - x0) * inv_res, (xy[2 * k + 1] - y0) * inv_res);
}
