/* workers.h - a persistent pthread pool for bvh.h's bvh_thread_pool: copy it into a program that
   has no job system of its own.

   Without a pool, bvh.h starts its threads for every parallel phase of a build and for every
   batch call, and joins them at its end (docs/GUIDE.md, "Your own thread pool"). A renderer that
   traces several small batches a frame (bounce and shadow rays, one batch each per bounce) pays
   that start each time; these workers are started once and sleep between runs.

       workers w;
       if (workers_start(&w, 0) != 0) ...;          // 0: one thread per online CPU (the caller is one)
       bvh_batch_desc bd = {0};
       bd.pool = workers_pool(&w);                  // bd.threads: tasks a run (0 = CPUs)
       bvh_intersect_batch_ex(&tree, rays, hits, n, &bd);
       desc.pool = workers_pool(&w);                // builds too: the same tree as without a pool
       ...
       workers_stop(&w);

   One run at a time: workers_run may be called from one thread at a time (bvh.h calls it only
   from the thread that called into it; two threads that each call bvh.h need a pool each). The
   calling thread takes tasks too. Tasks are taken by an atomic counter (gcc's and clang's
   builtins), so a batch's many small tasks cost no lock each. POSIX threads: build with
   -pthread (or -lpthread).

   Invariant: the run's fields (task, arg, count, next) change only under the mutex while no
   worker is inside a run (active == 0), and a worker reads them under the mutex when it joins
   one; so a worker that wakes late never takes a task of another run. */
#ifndef WORKERS_H
#define WORKERS_H

#include "bvh.h"

#include <pthread.h>
#include <stdint.h>
#include <string.h>
#include <unistd.h>

#define WORKERS_MAX 256

typedef struct workers {
    pthread_mutex_t mutex;
    pthread_cond_t wake; /* a new run, or quit */
    pthread_cond_t idle; /* active fell to 0 */
    pthread_t thread[WORKERS_MAX];
    uint32_t threads;    /* workers started (the caller is not counted) */
    uint32_t generation; /* runs so far: a worker joins each run once */
    uint32_t active;     /* workers inside a run */
    int quit;
    bvh_task_fn task; /* the run: task(arg, i) for every i < count */
    void *arg;
    uint32_t count;
    uint32_t next; /* the next task to take (atomic while a run lasts) */
} workers;

static inline void *workers_main(void *p) {
    workers *w = (workers *)p;
    uint32_t seen;
    pthread_mutex_lock(&w->mutex);
    seen = w->generation;
    for (;;) {
        bvh_task_fn task;
        void *arg;
        uint32_t count, i;
        while (!w->quit && w->generation == seen) pthread_cond_wait(&w->wake, &w->mutex);
        if (w->quit) break;
        seen = w->generation;
        task = w->task;
        arg = w->arg;
        count = w->count;
        w->active++;
        pthread_mutex_unlock(&w->mutex);
        while ((i = __atomic_fetch_add(&w->next, 1u, __ATOMIC_RELAXED)) < count) task(arg, i);
        pthread_mutex_lock(&w->mutex);
        if (--w->active == 0) pthread_cond_broadcast(&w->idle);
    }
    pthread_mutex_unlock(&w->mutex);
    return NULL;
}

/* bvh_thread_pool.run: every task once, on the workers and the calling thread; returns when all
   have returned. */
static inline void workers_run(void *user, uint32_t count, bvh_task_fn task, void *arg) {
    workers *w = (workers *)user;
    uint32_t i;
    pthread_mutex_lock(&w->mutex);
    while (w->active) pthread_cond_wait(&w->idle, &w->mutex); /* a late joiner of the last run */
    w->task = task;
    w->arg = arg;
    w->count = count;
    __atomic_store_n(&w->next, 0u, __ATOMIC_RELAXED); /* no worker is in a run (active 0) */
    w->generation++;
    pthread_cond_broadcast(&w->wake);
    pthread_mutex_unlock(&w->mutex);
    while ((i = __atomic_fetch_add(&w->next, 1u, __ATOMIC_RELAXED)) < count) task(arg, i);
    pthread_mutex_lock(&w->mutex); /* the tasks are all taken; wait for those still running */
    while (w->active) pthread_cond_wait(&w->idle, &w->mutex);
    pthread_mutex_unlock(&w->mutex);
}

/* Starts threads - 1 workers (threads 0: one per online CPU; at most WORKERS_MAX). Returns 0, or
   -1 if the mutex or conditions cannot be made; fewer workers where a thread cannot start. */
static inline int workers_start(workers *w, uint32_t threads) {
    uint32_t i;
    memset(w, 0, sizeof *w);
    if (threads == 0) {
        long n = sysconf(_SC_NPROCESSORS_ONLN);
        threads = n > 0 ? (uint32_t)n : 1;
    }
    if (threads > WORKERS_MAX) threads = WORKERS_MAX;
    if (pthread_mutex_init(&w->mutex, NULL) != 0) return -1;
    if (pthread_cond_init(&w->wake, NULL) != 0) {
        pthread_mutex_destroy(&w->mutex);
        return -1;
    }
    if (pthread_cond_init(&w->idle, NULL) != 0) {
        pthread_cond_destroy(&w->wake);
        pthread_mutex_destroy(&w->mutex);
        return -1;
    }
    for (i = 0; i + 1 < threads; i++) {
        if (pthread_create(&w->thread[i], NULL, workers_main, w) != 0) break;
        w->threads++;
    }
    return 0;
}

/* The pool to put in bvh_build_desc.pool or bvh_batch_desc.pool. */
static inline bvh_thread_pool workers_pool(workers *w) {
    bvh_thread_pool p;
    p.run = workers_run;
    p.user = w;
    return p;
}

/* Wakes the workers to quit and joins them. */
static inline void workers_stop(workers *w) {
    uint32_t i;
    pthread_mutex_lock(&w->mutex);
    w->quit = 1;
    pthread_cond_broadcast(&w->wake);
    pthread_mutex_unlock(&w->mutex);
    for (i = 0; i < w->threads; i++) pthread_join(w->thread[i], NULL);
    pthread_cond_destroy(&w->idle);
    pthread_cond_destroy(&w->wake);
    pthread_mutex_destroy(&w->mutex);
}

#endif /* WORKERS_H */
