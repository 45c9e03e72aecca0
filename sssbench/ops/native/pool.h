/* A persistent pool of worker threads and a kept workspace for the tap loop (type-independent;
 * included once per translation unit: gather.c's two halves, disk.c; each unit has its own).
 *
 * A pass splits its lines over torch.get_num_threads() threads (the caller passes the count).
 * By default a pass runs on torch's own OpenMP team (sss_set_omp: torch hands over its
 * runtime's GOMP entry points): after a torch operation that team's workers spin for
 * milliseconds waiting for more work (libgomp's default GOMP_SPINCOUNT), on the cores a
 * second pool would need. Measured (issue 30, 1080p close-up, 7-tap pre-integrated two-pass,
 * 2 threads, interleaved with kornia's 7x7 blur as experiments/perf does): the own pool's
 * two-pass took 1.13x kornia's time there and 0.84x alone; OMP_WAIT_POLICY=PASSIVE (no
 * spinning) gave 0.79x interleaved, the shared team 0.73-0.77x (docs/numerics.md). Without it
 * (another backend, a forked child, a call from inside an OpenMP region, sss_set_omp(NULL))
 * the pass uses its own workers, started once and sleeping on a condition variable between
 * passes: handing a pass to a sleeping worker cost 10 us (min; mean 35 us) against 21 us
 * (mean 80 us) for starting and joining a fresh thread per pass (2 threads, this 2-core
 * shared machine, 2000 runs each), on passes of 30-100 us for a small object. Workers never
 * spin: a sleeping thread takes no core from torch's OpenMP threads (spinning 200 us after
 * each pass, as an earlier version did, saved 1-2 us per pass and held a core meanwhile).
 * One pass at a time uses the pool; a concurrent caller (another Python thread) and a
 * process forked while a pass was running start their own threads instead. Which thread runs
 * a job never changes a result (every job's lines are computed alone). */

/* torch's OpenMP runtime (the GOMP ABI of libgomp, which Intel's runtime also exports), set
 * by sss_set_omp (gather.c) in the process that called it; NULL: the own pool */
typedef void (*sss_omp_parallel_fn)(void (*)(void *), void *, unsigned, unsigned);
extern sss_omp_parallel_fn sss_omp_parallel;
extern int (*sss_omp_thread_num)(void);
extern int (*sss_omp_num_threads)(void);
extern int (*sss_omp_in_parallel)(void);
extern pid_t sss_omp_pid;

typedef struct {
    void *(*run)(void *);
    char *args;
    size_t size;
    int jobs;
} omp_jobs;

/* one member of the OpenMP team: jobs t, t + n, ... (a team smaller than asked still runs
 * every job) */
static void omp_member(void *arg) {
    const omp_jobs *o = (const omp_jobs *)arg;
    const int n = sss_omp_num_threads(), t = sss_omp_thread_num();
    for (int i = t; i < o->jobs; i += n) o->run(o->args + (size_t)i * o->size);
}

enum { POOL_MAX = 64 };

typedef struct {
    void *(*run)(void *);
    void *arg;
} pool_task;

static struct {
    pthread_mutex_t lock; /* guards the fields below */
    pthread_cond_t wake, done;
    pid_t pid;                        /* the process the workers belong to */
    int started;                      /* workers 1..started run */
    unsigned long generation;         /* bumped per pass */
    unsigned long seen0[POOL_MAX];    /* generation at each worker's start */
    pool_task tasks[POOL_MAX];        /* worker i runs tasks[i] when i < active */
    int active, pending;
} pool = {PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, PTHREAD_COND_INITIALIZER};
static pthread_mutex_t pool_busy = PTHREAD_MUTEX_INITIALIZER; /* one pass at a time */

static void *pool_worker(void *arg) {
    const int i = (int)(intptr_t)arg;
    pthread_mutex_lock(&pool.lock);
    unsigned long seen = pool.seen0[i];
    for (;;) {
        while (pool.generation == seen) pthread_cond_wait(&pool.wake, &pool.lock);
        seen = pool.generation;
        if (i >= pool.active) continue;
        const pool_task task = pool.tasks[i];
        pthread_mutex_unlock(&pool.lock);
        task.run(task.arg);
        pthread_mutex_lock(&pool.lock);
        if (--pool.pending == 0) pthread_cond_signal(&pool.done);
    }
    return NULL;
}

/* run(args + t * size) for t in [0, threads): on torch's OpenMP team (sss_set_omp), else t = 0
 * on the caller's thread, the others on pool workers (or on threads of their own, or the
 * caller, when the pool is unavailable). */
static void pool_run(void *(*run)(void *), char *args, size_t size, int threads) {
    if (threads > POOL_MAX) threads = POOL_MAX;
    if (threads > 1 && sss_omp_parallel && sss_omp_pid == getpid() && !sss_omp_in_parallel()) {
        omp_jobs o = {run, args, size, threads};
        sss_omp_parallel(omp_member, &o, (unsigned)threads, 0);
        return;
    }
    if (threads > 1 && pthread_mutex_trylock(&pool_busy) == 0) {
        if (pool.pid != getpid()) { /* first use, or a fork child: the workers are gone and
                                       the lock and conditions may hold their state */
            pthread_mutex_init(&pool.lock, NULL);
            pthread_cond_init(&pool.wake, NULL);
            pthread_cond_init(&pool.done, NULL);
            pool.pid = getpid();
            pool.started = 0;
        }
        pthread_mutex_lock(&pool.lock);
        for (; pool.started < threads - 1; ++pool.started) {
            pthread_t id;
            const int i = pool.started + 1;
            pool.seen0[i] = pool.generation;
            if (pthread_create(&id, NULL, pool_worker, (void *)(intptr_t)i) != 0) break;
            pthread_detach(id);
        }
        const int workers = pool.started < threads - 1 ? pool.started : threads - 1;
        for (int t = 1; t <= workers; ++t) pool.tasks[t] = (pool_task){run, args + t * size};
        pool.active = workers + 1;
        pool.pending = workers;
        __atomic_store_n(&pool.generation, pool.generation + 1, __ATOMIC_RELEASE);
        pthread_cond_broadcast(&pool.wake);
        pthread_mutex_unlock(&pool.lock);
        for (int t = workers + 1; t < threads; ++t) run(args + t * size);
        run(args);
        pthread_mutex_lock(&pool.lock);
        while (pool.pending > 0) pthread_cond_wait(&pool.done, &pool.lock);
        pthread_mutex_unlock(&pool.lock);
        pthread_mutex_unlock(&pool_busy);
        return;
    }
    pthread_t ids[POOL_MAX];
    int started = 1;
    for (int t = 1; t < threads; ++t, ++started)
        if (pthread_create(&ids[t], NULL, run, args + t * size) != 0) break;
    for (int t = started; t < threads; ++t) run(args + t * size);
    run(args);
    for (int t = 1; t < started; ++t) pthread_join(ids[t], NULL);
}

/* A workspace kept between passes: a pass's line buffers and span lists (a few MB at most)
 * are allocated once and reused instead of being mapped and faulted in anew on every call.
 * One pass at a time holds it; another (concurrent, or in a child forked mid-pass) allocates
 * its own. */
static struct {
    pthread_mutex_t lock;
    void *ptr;
    size_t size;
} workspace = {PTHREAD_MUTEX_INITIALIZER, NULL, 0};

/* size bytes; *owned says whether workspace_release frees them or returns the workspace */
static void *workspace_acquire(size_t size, int *owned) {
    if (pthread_mutex_trylock(&workspace.lock) == 0) {
        if (workspace.size < size) {
            free(workspace.ptr);
            workspace.ptr = malloc(size);
            workspace.size = workspace.ptr ? size : 0;
        }
        if (workspace.ptr) {
            *owned = 0;
            return workspace.ptr;
        }
        pthread_mutex_unlock(&workspace.lock);
    }
    *owned = 1;
    return malloc(size);
}

static void workspace_release(void *ptr, int owned) {
    if (owned)
        free(ptr);
    else
        pthread_mutex_unlock(&workspace.lock);
}
