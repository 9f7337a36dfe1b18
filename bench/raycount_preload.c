/* raycount_preload.c — LD_PRELOAD shim that counts the ray queries a program sends to Embree 3.
 *
 * Used only by bench/run.sh to turn the peer's frames per second into rays per second; it is
 * never linked into restird. Build:
 *   cc -O2 -std=c17 -D_GNU_SOURCE -fPIC -shared bench/raycount_preload.c -o build/bench/raycount_preload.so -ldl -pthread
 * Use:
 *   RAYCOUNT_OUT=/tmp/counts.json LD_PRELOAD=build/bench/raycount_preload.so pathtracer ...
 *
 * Every rtcIntersect* / rtcOccluded* entry point of the Embree 3 API is wrapped: the wrapper
 * counts the rays it was given and forwards the call to the real function found with
 * dlsym(RTLD_NEXT). What counts as one ray:
 *   - rtcIntersect1 / rtcOccluded1: every call is one ray.
 *   - 4/8/16-wide packets: lanes whose valid mask is -1 (Embree's "active") and whose
 *     tnear <= tfar (Embree skips the others), i.e. the lanes Embree actually traces.
 *   - streams (1M, 1Mp, NM, Np): rays with tnear <= tfar, which Embree treats as active.
 * Counters are per thread: each thread owns a cache-line-aligned slot of a static table and
 * updates it with relaxed atomic loads/stores (a single writer per slot, so no read-modify-write
 * lock is needed on the hot path); the destructor sums the table at exit and writes one JSON
 * object (totals, the per-function counts and the number of threads that made queries) to
 * the file named by RAYCOUNT_OUT (or to stderr when the variable is unset). Threads beyond the
 * table size share one overflow slot updated with relaxed fetch_add. */

#include <dlfcn.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include <embree3/rtcore.h>

/* ---- counter table ---------------------------------------------------------------------- */

enum counter {
    C_I1, C_I4, C_I8, C_I16, C_I1M, C_I1MP, C_INM, C_INP,   /* rays per intersect entry point */
    C_O1, C_O4, C_O8, C_O16, C_O1M, C_O1MP, C_ONM, C_ONP,   /* rays per occluded entry point */
    C_CALLS,                                                 /* API calls of any kind */
    C_COUNT
};

static const char *const counter_names[C_COUNT] = {
    "rtcIntersect1", "rtcIntersect4", "rtcIntersect8", "rtcIntersect16",
    "rtcIntersect1M", "rtcIntersect1Mp", "rtcIntersectNM", "rtcIntersectNp",
    "rtcOccluded1", "rtcOccluded4", "rtcOccluded8", "rtcOccluded16",
    "rtcOccluded1M", "rtcOccluded1Mp", "rtcOccludedNM", "rtcOccludedNp",
    "calls",
};

#define MAX_SLOTS 256

/* C_COUNT (17) counters of 8 bytes: padded to a multiple of the cache line so no two threads
 * share a line. */
struct slot {
    _Alignas(64) _Atomic uint64_t n[C_COUNT];
    char pad[64 - (C_COUNT * sizeof(uint64_t)) % 64];
};

static struct slot slots[MAX_SLOTS];
static struct slot overflow_slot;
static atomic_uint next_slot;
/* initial-exec: the shim is loaded at start-up (LD_PRELOAD), so its TLS is static and each
 * access is one %fs-relative load instead of a __tls_get_addr call. */
static _Thread_local struct slot *my_slot __attribute__((tls_model("initial-exec")));

static struct slot *this_thread_slot(void)
{
    struct slot *s = my_slot;
    if (s) return s;
    unsigned i = atomic_fetch_add_explicit(&next_slot, 1u, memory_order_relaxed);
    s = i < MAX_SLOTS ? &slots[i] : &overflow_slot;
    my_slot = s;
    return s;
}

static inline void count(enum counter c, uint64_t rays)
{
    struct slot *s = this_thread_slot();
    if (s == &overflow_slot) {
        atomic_fetch_add_explicit(&s->n[c], rays, memory_order_relaxed);
        atomic_fetch_add_explicit(&s->n[C_CALLS], 1, memory_order_relaxed);
        return;
    }
    /* Single writer: a relaxed load + store is race-free and compiles to plain moves. */
    atomic_store_explicit(&s->n[c], atomic_load_explicit(&s->n[c], memory_order_relaxed) + rays,
                          memory_order_relaxed);
    atomic_store_explicit(&s->n[C_CALLS],
                          atomic_load_explicit(&s->n[C_CALLS], memory_order_relaxed) + 1,
                          memory_order_relaxed);
}

/* ---- forwarding ------------------------------------------------------------------------- */

typedef void (*fn_i1)(RTCScene, struct RTCIntersectContext *, struct RTCRayHit *);
typedef void (*fn_i4)(const int *, RTCScene, struct RTCIntersectContext *, struct RTCRayHit4 *);
typedef void (*fn_i8)(const int *, RTCScene, struct RTCIntersectContext *, struct RTCRayHit8 *);
typedef void (*fn_i16)(const int *, RTCScene, struct RTCIntersectContext *, struct RTCRayHit16 *);
typedef void (*fn_i1m)(RTCScene, struct RTCIntersectContext *, struct RTCRayHit *, unsigned, size_t);
typedef void (*fn_i1mp)(RTCScene, struct RTCIntersectContext *, struct RTCRayHit **, unsigned);
typedef void (*fn_inm)(RTCScene, struct RTCIntersectContext *, struct RTCRayHitN *, unsigned, unsigned, size_t);
typedef void (*fn_inp)(RTCScene, struct RTCIntersectContext *, const struct RTCRayHitNp *, unsigned);
typedef void (*fn_o1)(RTCScene, struct RTCIntersectContext *, struct RTCRay *);
typedef void (*fn_o4)(const int *, RTCScene, struct RTCIntersectContext *, struct RTCRay4 *);
typedef void (*fn_o8)(const int *, RTCScene, struct RTCIntersectContext *, struct RTCRay8 *);
typedef void (*fn_o16)(const int *, RTCScene, struct RTCIntersectContext *, struct RTCRay16 *);
typedef void (*fn_o1m)(RTCScene, struct RTCIntersectContext *, struct RTCRay *, unsigned, size_t);
typedef void (*fn_o1mp)(RTCScene, struct RTCIntersectContext *, struct RTCRay **, unsigned);
typedef void (*fn_onm)(RTCScene, struct RTCIntersectContext *, struct RTCRayN *, unsigned, unsigned, size_t);
typedef void (*fn_onp)(RTCScene, struct RTCIntersectContext *, const struct RTCRayNp *, unsigned);

/* Looked up once; dlsym is thread-safe and idempotent, so a racing first call only repeats it. */
static void *real(_Atomic(void *) *cache, const char *name)
{
    void *f = atomic_load_explicit(cache, memory_order_acquire);
    if (f) return f;
    f = dlsym(RTLD_NEXT, name);
    if (!f) {
        fprintf(stderr, "raycount_preload: %s not found after the shim (%s)\n", name, dlerror());
        abort();
    }
    atomic_store_explicit(cache, f, memory_order_release);
    return f;
}

#define REAL(type, name) ((type)real(&real_##name, #name))
#define DECLARE_REAL(name) static _Atomic(void *) real_##name

DECLARE_REAL(rtcIntersect1);  DECLARE_REAL(rtcIntersect4);   DECLARE_REAL(rtcIntersect8);
DECLARE_REAL(rtcIntersect16); DECLARE_REAL(rtcIntersect1M);  DECLARE_REAL(rtcIntersect1Mp);
DECLARE_REAL(rtcIntersectNM); DECLARE_REAL(rtcIntersectNp);
DECLARE_REAL(rtcOccluded1);   DECLARE_REAL(rtcOccluded4);    DECLARE_REAL(rtcOccluded8);
DECLARE_REAL(rtcOccluded16);  DECLARE_REAL(rtcOccluded1M);   DECLARE_REAL(rtcOccluded1Mp);
DECLARE_REAL(rtcOccludedNM);  DECLARE_REAL(rtcOccludedNp);

/* A lane/ray is traced when its mask is -1 (packets only) and tnear <= tfar (false for NaN). */
static inline unsigned lanes(const int *valid, const float *tnear, const float *tfar, unsigned n)
{
    unsigned k = 0;
    for (unsigned i = 0; i < n; i++)
        k += (valid[i] == -1) & (tnear[i] <= tfar[i]);
    return k;
}

/* ---- intersect -------------------------------------------------------------------------- */

void rtcIntersect1(RTCScene scene, struct RTCIntersectContext *ctx, struct RTCRayHit *rh)
{
    count(C_I1, 1);
    REAL(fn_i1, rtcIntersect1)(scene, ctx, rh);
}

void rtcIntersect4(const int *valid, RTCScene scene, struct RTCIntersectContext *ctx,
                   struct RTCRayHit4 *rh)
{
    count(C_I4, lanes(valid, rh->ray.tnear, rh->ray.tfar, 4));
    REAL(fn_i4, rtcIntersect4)(valid, scene, ctx, rh);
}

void rtcIntersect8(const int *valid, RTCScene scene, struct RTCIntersectContext *ctx,
                   struct RTCRayHit8 *rh)
{
    count(C_I8, lanes(valid, rh->ray.tnear, rh->ray.tfar, 8));
    REAL(fn_i8, rtcIntersect8)(valid, scene, ctx, rh);
}

void rtcIntersect16(const int *valid, RTCScene scene, struct RTCIntersectContext *ctx,
                    struct RTCRayHit16 *rh)
{
    count(C_I16, lanes(valid, rh->ray.tnear, rh->ray.tfar, 16));
    REAL(fn_i16, rtcIntersect16)(valid, scene, ctx, rh);
}

void rtcIntersect1M(RTCScene scene, struct RTCIntersectContext *ctx, struct RTCRayHit *rh,
                    unsigned int M, size_t stride)
{
    uint64_t k = 0;
    for (unsigned i = 0; i < M; i++) {
        const struct RTCRayHit *r = (const struct RTCRayHit *)((const char *)rh + i * stride);
        k += r->ray.tnear <= r->ray.tfar;
    }
    count(C_I1M, k);
    REAL(fn_i1m, rtcIntersect1M)(scene, ctx, rh, M, stride);
}

void rtcIntersect1Mp(RTCScene scene, struct RTCIntersectContext *ctx, struct RTCRayHit **rh,
                     unsigned int M)
{
    uint64_t k = 0;
    for (unsigned i = 0; i < M; i++) k += rh[i]->ray.tnear <= rh[i]->ray.tfar;
    count(C_I1MP, k);
    REAL(fn_i1mp, rtcIntersect1Mp)(scene, ctx, rh, M);
}

/* SOA packets of N lanes: tnear is float field 3 and tfar float field 8 of the ray part
 * (org_x org_y org_z tnear dir_x dir_y dir_z time tfar ...), each field N floats wide. */
static uint64_t soa_active(const void *packet, unsigned N)
{
    const float *f = packet;
    uint64_t k = 0;
    for (unsigned i = 0; i < N; i++) k += f[3 * N + i] <= f[8 * N + i];
    return k;
}

void rtcIntersectNM(RTCScene scene, struct RTCIntersectContext *ctx, struct RTCRayHitN *rh,
                    unsigned int N, unsigned int M, size_t stride)
{
    uint64_t k = 0;
    for (unsigned j = 0; j < M; j++) k += soa_active((const char *)rh + j * stride, N);
    count(C_INM, k);
    REAL(fn_inm, rtcIntersectNM)(scene, ctx, rh, N, M, stride);
}

void rtcIntersectNp(RTCScene scene, struct RTCIntersectContext *ctx,
                    const struct RTCRayHitNp *rh, unsigned int N)
{
    uint64_t k = 0;
    for (unsigned i = 0; i < N; i++) k += rh->ray.tnear[i] <= rh->ray.tfar[i];
    count(C_INP, k);
    REAL(fn_inp, rtcIntersectNp)(scene, ctx, rh, N);
}

/* ---- occluded --------------------------------------------------------------------------- */

void rtcOccluded1(RTCScene scene, struct RTCIntersectContext *ctx, struct RTCRay *ray)
{
    count(C_O1, 1);
    REAL(fn_o1, rtcOccluded1)(scene, ctx, ray);
}

void rtcOccluded4(const int *valid, RTCScene scene, struct RTCIntersectContext *ctx,
                  struct RTCRay4 *ray)
{
    count(C_O4, lanes(valid, ray->tnear, ray->tfar, 4));
    REAL(fn_o4, rtcOccluded4)(valid, scene, ctx, ray);
}

void rtcOccluded8(const int *valid, RTCScene scene, struct RTCIntersectContext *ctx,
                  struct RTCRay8 *ray)
{
    count(C_O8, lanes(valid, ray->tnear, ray->tfar, 8));
    REAL(fn_o8, rtcOccluded8)(valid, scene, ctx, ray);
}

void rtcOccluded16(const int *valid, RTCScene scene, struct RTCIntersectContext *ctx,
                   struct RTCRay16 *ray)
{
    count(C_O16, lanes(valid, ray->tnear, ray->tfar, 16));
    REAL(fn_o16, rtcOccluded16)(valid, scene, ctx, ray);
}

void rtcOccluded1M(RTCScene scene, struct RTCIntersectContext *ctx, struct RTCRay *ray,
                   unsigned int M, size_t stride)
{
    uint64_t k = 0;
    for (unsigned i = 0; i < M; i++) {
        const struct RTCRay *r = (const struct RTCRay *)((const char *)ray + i * stride);
        k += r->tnear <= r->tfar;
    }
    count(C_O1M, k);
    REAL(fn_o1m, rtcOccluded1M)(scene, ctx, ray, M, stride);
}

void rtcOccluded1Mp(RTCScene scene, struct RTCIntersectContext *ctx, struct RTCRay **ray,
                    unsigned int M)
{
    uint64_t k = 0;
    for (unsigned i = 0; i < M; i++) k += ray[i]->tnear <= ray[i]->tfar;
    count(C_O1MP, k);
    REAL(fn_o1mp, rtcOccluded1Mp)(scene, ctx, ray, M);
}

void rtcOccludedNM(RTCScene scene, struct RTCIntersectContext *ctx, struct RTCRayN *ray,
                   unsigned int N, unsigned int M, size_t stride)
{
    uint64_t k = 0;
    for (unsigned j = 0; j < M; j++) k += soa_active((const char *)ray + j * stride, N);
    count(C_ONM, k);
    REAL(fn_onm, rtcOccludedNM)(scene, ctx, ray, N, M, stride);
}

void rtcOccludedNp(RTCScene scene, struct RTCIntersectContext *ctx, const struct RTCRayNp *ray,
                   unsigned int N)
{
    uint64_t k = 0;
    for (unsigned i = 0; i < N; i++) k += ray->tnear[i] <= ray->tfar[i];
    count(C_ONP, k);
    REAL(fn_onp, rtcOccludedNp)(scene, ctx, ray, N);
}

/* ---- report at exit --------------------------------------------------------------------- */

__attribute__((destructor)) static void raycount_report(void)
{
    uint64_t total[C_COUNT] = {0};
    unsigned used = atomic_load_explicit(&next_slot, memory_order_relaxed);
    if (used > MAX_SLOTS) used = MAX_SLOTS;
    for (unsigned s = 0; s < used; s++)
        for (int c = 0; c < C_COUNT; c++)
            total[c] += atomic_load_explicit(&slots[s].n[c], memory_order_relaxed);
    for (int c = 0; c < C_COUNT; c++)
        total[c] += atomic_load_explicit(&overflow_slot.n[c], memory_order_relaxed);

    uint64_t isect = 0, occl = 0;
    for (int c = C_I1; c <= C_INP; c++) isect += total[c];
    for (int c = C_O1; c <= C_ONP; c++) occl += total[c];

    const char *path = getenv("RAYCOUNT_OUT");
    FILE *f = path && *path ? fopen(path, "w") : stderr;
    if (!f) {
        fprintf(stderr, "raycount_preload: cannot write %s\n", path);
        f = stderr;
    }
    fprintf(f, "{\"intersect_rays\": %llu, \"occluded_rays\": %llu, \"rays\": %llu, "
               "\"threads\": %u",
            (unsigned long long)isect, (unsigned long long)occl,
            (unsigned long long)(isect + occl), atomic_load(&next_slot));
    for (int c = 0; c < C_COUNT; c++)
        fprintf(f, ", \"%s\": %llu", counter_names[c], (unsigned long long)total[c]);
    fprintf(f, "}\n");
    if (f != stderr) fclose(f);
}
