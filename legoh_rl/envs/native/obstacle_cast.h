/* The exact obstacle ray tests of obstacle_cast.c, shared with the fused camera of height_march.c. */
#ifndef LEGOH_RL_OBSTACLE_CAST_H
#define LEGOH_RL_OBSTACLE_CAST_H
#include <stdint.h>

/* Consecutive rays are culled together in blocks of CULL rays. */
#define CULL 32

/* Static obstacle geoms and a batch of rays. */
typedef struct {
    int64_t G;
    const int32_t *kind;        /* (G,): 0 box (size = half-sizes), 1 cylinder (radius, half-length), 2 mesh */
    const double *pos, *mat;    /* (G, 3), (G, 3, 3) row-major, columns = geom axes */
    const double *size, *r2;    /* (G, 3), (G,) squared bounding radius */
    const int64_t *plane_start; /* (G,) first plane of a mesh in planes */
    const int64_t *plane_count; /* (G,) */
    const double *planes;       /* (F, 4): n . x <= h, rows (nx, ny, nz, h) in the geom frame */
    const double *o, *d, *tm;   /* rays (M, 3), (M, 3), (M,) */
    double *out;                /* (M,) */
    int64_t M;
} obs_ctx_t;

/* Rays [begin, end) of C (at most CULL of them): out[k] = distance to the first geom surface
 * within tm[k] (INFINITY for none). survivors: scratch for G indices, or NULL (every geom is then
 * tested: slower, same result). */
void lh_cast_rays(const obs_ctx_t *C, int64_t begin, int64_t end, int64_t *survivors);

#endif
