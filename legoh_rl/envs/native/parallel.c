/* Blocks of a range of work items split across POSIX threads: the threading every native kernel
 * uses (the ray march and the camera in height_march.c, the obstacle rays in obstacle_cast.c),
 * declared in parallel.h. Built with them into one library (see build.py).
 */
#include <pthread.h>
#include <stdint.h>

#include "parallel.h"

#define MAX_THREADS 64

typedef struct {
    lh_range_fn fn;
    const void *ctx;
    int64_t n, block;
    int64_t *next; /* the next block's first item, shared: threads take blocks as they come free */
} worker_t;

static void *run_worker(void *arg) {
    const worker_t *W = (const worker_t *)arg;
    for (;;) {
        const int64_t b = __atomic_fetch_add(W->next, W->block, __ATOMIC_RELAXED);
        if (b >= W->n) break;
        W->fn(W->ctx, b, b + W->block < W->n ? b + W->block : W->n);
    }
    return NULL;
}

int lh_parallel_for(lh_range_fn fn, const void *ctx, int64_t n, int64_t block, int threads) {
    if (block < 1) block = 1;
    const int64_t blocks = (n + block - 1) / block;
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    if ((int64_t)threads > blocks) threads = blocks > 0 ? (int)blocks : 1;
    int64_t next = 0;
    const worker_t worker = {fn, ctx, n, block, &next};
    pthread_t tids[MAX_THREADS];
    int started[MAX_THREADS] = {0};
    int rc = 0;
    /* The calling thread works too, and takes every block a late or failed thread leaves: a
     * thread that starts slowly (its creation can cost as much as a small call's work) delays
     * nothing. */
    for (int i = 1; i < threads; ++i) {
        started[i] = pthread_create(&tids[i], NULL, run_worker, (void *)&worker) == 0;
        if (!started[i]) rc = -1;
    }
    run_worker((void *)&worker);
    for (int i = 1; i < threads; ++i)
        if (started[i]) pthread_join(tids[i], NULL);
    return rc;
}
