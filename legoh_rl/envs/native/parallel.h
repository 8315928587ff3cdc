/* Blocks of a range of work items split across POSIX threads (defined in parallel.c, shared by
 * the native kernels). */
#ifndef LEGOH_RL_PARALLEL_H
#define LEGOH_RL_PARALLEL_H
#include <stdint.h>

typedef void (*lh_range_fn)(const void *ctx, int64_t begin, int64_t end);

/* fn over [0, n) in blocks of `block` items, which `threads` threads (the caller among them) take
 * as they come free. Returns 0, or -1 when a thread could not be started (the others then run
 * every block; the result is the same). */
int lh_parallel_for(lh_range_fn fn, const void *ctx, int64_t n, int64_t block, int threads);

#endif
