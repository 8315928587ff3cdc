/* Exact rays on static obstacle geoms (boxes, cylinders, convex meshes), in plain C: the native
 * path of legoh_rl.envs.obstacle_rays.ObstacleRayCaster.cast, with the same conventions (mj_ray's:
 * distances in units of |d|, a ray starting inside a geom reports where it leaves it) and the
 * same tests, in float64.
 *
 * Culling: consecutive rays are taken in blocks of CULL rays; each geom's bounding sphere is
 * tested against the bounding box of the block's segments, and only the survivors are tested per
 * ray (bounding sphere against the segment, then the exact test). Blocks of rays are split
 * across threads (lh_parallel_for, parallel.c). Built with height_march.c into one library (see build.py).
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "obstacle_cast.h"
#include "parallel.h"

#define OBS_BLOCK (16 * CULL) /* rays per thread work block */

enum { KIND_BOX = 0, KIND_CYLINDER = 1, KIND_MESH = 2 };

/* nearest crossing at t >= 0 of the convex interval [t_lo, t_hi] */
static inline double entry_or_exit(double t_lo, double t_hi) {
    if (t_lo <= t_hi && t_hi >= 0.0) return t_lo >= 0.0 ? t_lo : t_hi;
    return INFINITY;
}

static double hit_box(const double *s, const double *lo, const double *ld) {
    double t_lo = -INFINITY, t_hi = INFINITY;
    for (int i = 0; i < 3; ++i) {
        if (ld[i] == 0.0) {
            if (fabs(lo[i]) > s[i]) return INFINITY;
            continue;
        }
        const double inv = 1.0 / ld[i];
        const double t1 = (-s[i] - lo[i]) * inv, t2 = (s[i] - lo[i]) * inv;
        t_lo = fmax(t_lo, fmin(t1, t2));
        t_hi = fmin(t_hi, fmax(t1, t2));
    }
    return entry_or_exit(t_lo, t_hi);
}

static double hit_cylinder(const double *s, const double *lo, const double *ld) {
    const double r = s[0], h = s[1];
    const double ox = lo[0], oy = lo[1], oz = lo[2], dx = ld[0], dy = ld[1], dz = ld[2];
    const double a = dx * dx + dy * dy, b = ox * dx + oy * dy, c = ox * ox + oy * oy - r * r;
    const double disc = b * b - a * c;
    double best = INFINITY;
    if (disc >= 0.0 && a > 0.0) {
        const double q = -(b + copysign(sqrt(disc), b)); /* stable roots q / a and c / q */
        const double roots[2] = {q / a, c / q};
        for (int k = 0; k < 2; ++k) {
            const double t = roots[k];
            if (t >= 0.0 && fabs(oz + t * dz) <= h && t < best) best = t;
        }
    }
    if (dz != 0.0) {
        for (int k = 0; k < 2; ++k) {
            const double tc = ((k ? 1.0 : -1.0) * h - oz) / dz;
            const double x = ox + tc * dx, y = oy + tc * dy;
            if (tc >= 0.0 && x * x + y * y <= r * r && tc < best) best = tc;
        }
    }
    return best;
}

static double hit_mesh(const double *planes, int64_t count, const double *lo, const double *ld) {
    double t_lo = -INFINITY, t_hi = INFINITY;
    for (int64_t f = 0; f < count; ++f) {
        const double *p = planes + 4 * f;
        const double denom = p[0] * ld[0] + p[1] * ld[1] + p[2] * ld[2];
        const double num = p[3] - (p[0] * lo[0] + p[1] * lo[1] + p[2] * lo[2]);
        if (denom < 0.0) t_lo = fmax(t_lo, num / denom);
        else if (denom > 0.0) t_hi = fmin(t_hi, num / denom);
        else if (num < 0.0) return INFINITY; /* parallel to a face, outside it */
    }
    return entry_or_exit(t_lo, t_hi);
}

void lh_cast_rays(const obs_ctx_t *C, int64_t begin, int64_t end, int64_t *survivors) {
    double bmin[3] = {INFINITY, INFINITY, INFINITY}, bmax[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int64_t k = begin; k < end; ++k) {
        for (int i = 0; i < 3; ++i) {
            const double a = C->o[3 * k + i];
            const double b = C->d[3 * k + i] == 0.0 ? a : a + C->d[3 * k + i] * C->tm[k];
            bmin[i] = fmin(bmin[i], fmin(a, b));
            bmax[i] = fmax(bmax[i], fmax(a, b));
        }
    }
    int64_t ns = 0;
    for (int64_t g = 0; g < C->G && survivors; ++g) {
        double dist2 = 0.0;
        for (int i = 0; i < 3; ++i) {
            const double c = C->pos[3 * g + i];
            const double gap = fmax(fmax(bmin[i] - c, c - bmax[i]), 0.0);
            dist2 += gap * gap;
        }
        if (dist2 <= C->r2[g]) survivors[ns++] = g;
    }
    for (int64_t k = begin; k < end; ++k) {
        const double *o = C->o + 3 * k, *d = C->d + 3 * k;
        const double tm = C->tm[k];
        double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        if (!(dd > 1e-300)) dd = 1e-300;
        double best = INFINITY;
        const int64_t count = survivors ? ns : C->G; /* no culling list: every geom */
        for (int64_t j = 0; j < count; ++j) {
            const int64_t g = survivors ? survivors[j] : j;
            const double *c = C->pos + 3 * g, *R = C->mat + 9 * g;
            const double oc[3] = {c[0] - o[0], c[1] - o[1], c[2] - o[2]};
            double ts = (oc[0] * d[0] + oc[1] * d[1] + oc[2] * d[2]) / dd;
            ts = fmin(fmax(ts, 0.0), tm);
            const double px = oc[0] - ts * d[0], py = oc[1] - ts * d[1], pz = oc[2] - ts * d[2];
            if (px * px + py * py + pz * pz > C->r2[g]) continue;
            double lo[3], ld[3]; /* the ray in the geom frame: R^T (o - c), R^T d */
            for (int i = 0; i < 3; ++i) {
                lo[i] = -(oc[0] * R[i] + oc[1] * R[3 + i] + oc[2] * R[6 + i]);
                ld[i] = d[0] * R[i] + d[1] * R[3 + i] + d[2] * R[6 + i];
            }
            double t;
            switch (C->kind[g]) {
                case KIND_BOX: t = hit_box(C->size + 3 * g, lo, ld); break;
                case KIND_CYLINDER: t = hit_cylinder(C->size + 3 * g, lo, ld); break;
                default: t = hit_mesh(C->planes + 4 * C->plane_start[g], C->plane_count[g], lo, ld);
            }
            if (t <= tm && t < best) best = t;
        }
        C->out[k] = best;
    }
}

static void cast_range(const void *arg, int64_t begin, int64_t end) {
    const obs_ctx_t *C = (const obs_ctx_t *)arg;
    /* the block cull's list; without memory every ray tests every geom (slower, same result) */
    int64_t *survivors = (int64_t *)malloc(sizeof(int64_t) * (size_t)(C->G > 0 ? C->G : 1));
    for (int64_t b = begin; b < end; b += CULL) lh_cast_rays(C, b, b + CULL < end ? b + CULL : end, survivors);
    free(survivors);
}

/* Distances (M,) of rays o + t d, t in [0, tm], to the first geom surface (INFINITY for none).
 * kind: 0 box (size = half-sizes), 1 cylinder (radius, half-length), 2 convex mesh (planes).
 * Returns 0, or -1 when a thread could not be started (the result is complete either way). */
int lh_obstacle_cast(int64_t G, const int32_t *kind, const double *pos, const double *mat,
                     const double *size, const double *r2, const int64_t *plane_start,
                     const int64_t *plane_count, const double *planes, int64_t M, const double *o,
                     const double *d, const double *tm, double *out, int threads) {
    const obs_ctx_t ctx = {G, kind, pos, mat, size, r2, plane_start, plane_count, planes, o, d, tm, out, M};
    return lh_parallel_for(cast_range, &ctx, M, OBS_BLOCK, threads);
}
