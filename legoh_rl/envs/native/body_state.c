/* The env's per-step body state in one pass over the selected worlds (legoh_rl.envs.body_state).
 *
 * The same quantities as BodyStateReader's numpy path (the reference, also the fallback): base
 * pose, rotation, roll/pitch/yaw, velocities in the world and base frames, the leg joints'
 * positions, velocities and torques, the contact sensors' forces, the feet's positions, contact
 * flags and edge flags, the terrain height under the base and the feet, and the vector to P_B.
 * Reading ~30 small arrays and composing them in numpy costs ~40 calls per step; here it is one.
 */
#include <math.h>
#include <stdint.h>

#include "height_map.h"

/* Static description of where everything lives, filled once by BodyStateReader (ctypes). The
 * MuJoCo arrays are the batch's live views: row w of a field starts at base + w * stride. */
typedef struct {
    const double *qpos, *qvel, *sensordata, *xpos, *act_force;
    int64_t qpos_stride, qvel_stride, sd_stride, xpos_stride, act_stride; /* doubles per world */
    const int64_t *qpos_adr, *dof_adr, *act_ids; /* (A,) leg joints' qpos / dof / actuator ids */
    int64_t A;
    const int64_t *foot_cols; /* (2, 3) sensordata columns of the feet's contact forces */
    const int64_t *pen_cols;  /* (P, 3) of the penalised bodies' forces */
    int64_t P;
    const int64_t *foot_bodies; /* (2,) */
    hmap_t surface;             /* float32 surface heights (HeightMap) */
    const uint8_t *edge;        /* (enx, eny) edge mask, nearest sample */
    int64_t enx, eny;
    double ex0, ey0, eres;
    double foot_rest, contact_thr2;
} body_cfg_t;

static inline int edge_at(const body_cfg_t *c, double x, double y) {
    double fi = (x - c->ex0) / c->eres, fj = (y - c->ey0) / c->eres;
    if (fi != fi || fj != fj) return 0; /* NaN: no sample */
    const double imax = (double)(c->enx - 1), jmax = (double)(c->eny - 1);
    fi = fi < 0.0 ? 0.0 : (fi > imax ? imax : fi); /* np.clip, then np.rint (half to even) */
    fj = fj < 0.0 ? 0.0 : (fj > jmax ? jmax : fj);
    return c->edge[(int64_t)rint(fi) * c->eny + (int64_t)rint(fj)] != 0;
}

/* Rows r < n (world rows[r], or r when rows is NULL); end: (N, 3) P_B of every world. Output
 * blocks, each row-major (n, size), one after the other in `out` (float64): pos 3, rot 9,
 * gravity_b 3, roll 1, pitch 1, yaw 1, lin_vel_w 3, lin_vel_b 3, ang_vel_b 3, q A, dq A,
 * torques A, foot_force 6, pen_force 3P, base_height 1, goal_vec 2, goal_dist 1, feet_xy 4,
 * foot_lift 2; and in `flags` (uint8): contact 2, foot_on_edge 2. */
void lh_body_state(const body_cfg_t *c, const int64_t *rows, int64_t n, const double *end, double *out,
                   uint8_t *flags) {
    const int64_t A = c->A, P = c->P;
    double *pos = out, *rot = pos + 3 * n, *grav = rot + 9 * n, *roll = grav + 3 * n, *pitch = roll + n;
    double *yaw = pitch + n, *vw = yaw + n, *vb = vw + 3 * n, *wb = vb + 3 * n, *q = wb + 3 * n;
    double *dq = q + A * n, *tau = dq + A * n, *ff = tau + A * n, *pf = ff + 6 * n, *bh = pf + 3 * P * n;
    double *gv = bh + n, *gd = gv + 2 * n, *fxy = gd + n, *lift = fxy + 4 * n;
    uint8_t *contact = flags, *on_edge = flags + 2 * n;
    for (int64_t r = 0; r < n; ++r) {
        const int64_t w = rows ? rows[r] : r;
        const double *qp = c->qpos + w * c->qpos_stride, *qv = c->qvel + w * c->qvel_stride;
        const double *sd = c->sensordata + w * c->sd_stride, *xp = c->xpos + w * c->xpos_stride;
        const double *af = c->act_force + w * c->act_stride;
        double *R = rot + 9 * r;
        const double qw = qp[3], qx = qp[4], qy = qp[5], qz = qp[6];
        R[0] = 1.0 - 2.0 * (qy * qy + qz * qz), R[1] = 2.0 * (qx * qy - qw * qz), R[2] = 2.0 * (qx * qz + qw * qy);
        R[3] = 2.0 * (qx * qy + qw * qz), R[4] = 1.0 - 2.0 * (qx * qx + qz * qz), R[5] = 2.0 * (qy * qz - qw * qx);
        R[6] = 2.0 * (qx * qz - qw * qy), R[7] = 2.0 * (qy * qz + qw * qx), R[8] = 1.0 - 2.0 * (qx * qx + qy * qy);
        double *g = grav + 3 * r, *v = vw + 3 * r, *vl = vb + 3 * r;
        for (int k = 0; k < 3; ++k) {
            pos[3 * r + k] = qp[k];
            g[k] = -R[6 + k];
            v[k] = qv[k];
            wb[3 * r + k] = qv[3 + k];
        }
        for (int k = 0; k < 3; ++k) vl[k] = v[0] * R[k] + v[1] * R[3 + k] + v[2] * R[6 + k]; /* R^T v */
        roll[r] = atan2(-g[1], -g[2]);
        pitch[r] = asin(g[0] < -1.0 ? -1.0 : (g[0] > 1.0 ? 1.0 : g[0]));
        yaw[r] = atan2(R[3], R[0]);
        for (int64_t a = 0; a < A; ++a) {
            q[A * r + a] = qp[c->qpos_adr[a]];
            dq[A * r + a] = qv[c->dof_adr[a]];
            tau[A * r + a] = af[c->act_ids[a]];
        }
        for (int k = 0; k < 6; ++k) ff[6 * r + k] = sd[c->foot_cols[k]];
        for (int64_t k = 0; k < 3 * P; ++k) pf[3 * P * r + k] = sd[c->pen_cols[k]];
        bh[r] = qp[2] - (double)height_at(&c->surface, (float)qp[0], (float)qp[1]);
        const double gx = end[3 * w] - qp[0], gy = end[3 * w + 1] - qp[1];
        gv[2 * r] = gx, gv[2 * r + 1] = gy;
        gd[r] = hypot(gx, gy);
        for (int f = 0; f < 2; ++f) {
            const double *fp = xp + 3 * c->foot_bodies[f], *F = ff + 6 * r + 3 * f;
            const int in_contact = F[0] * F[0] + F[1] * F[1] + F[2] * F[2] > c->contact_thr2;
            fxy[4 * r + 2 * f] = fp[0], fxy[4 * r + 2 * f + 1] = fp[1];
            lift[2 * r + f] = fp[2] - (double)height_at(&c->surface, (float)fp[0], (float)fp[1]) - c->foot_rest;
            contact[2 * r + f] = (uint8_t)in_contact;
            on_edge[2 * r + f] = (uint8_t)(in_contact && edge_at(c, fp[0], fp[1]));
        }
    }
}
