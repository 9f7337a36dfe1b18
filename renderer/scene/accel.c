/* accel.c — the only file that includes Embree. Builds the scene's BVH (flat when nothing
 * moves; two-level when some shapes are movable, see accel_new) and answers closest-hit and
 * occlusion queries.
 * Must not know about materials or lights. Counts every query in caller-owned counters.
 * Refs: Embree 3 API (rtcore.h); instancing keeps per-frame transform updates to a top-level
 * re-commit (docs/architecture.md, "accel"). */
#include "scene/accel.h"

#include <embree3/rtcore.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene/scene.h"

struct accel {
    RTCDevice device;
    RTCScene top;
    RTCScene static_blas;     /* two-level layout only: the static geometry's bottom level */
    unsigned static_inst_id;  /* its instance id in top, or RTC_INVALID_GEOMETRY_ID */
    uint32_t *top_shape;      /* geomID in top (direct geometry or instance) -> shape */
    uint32_t *static_shape;   /* geomID in static_blas -> shape */
    int32_t *shape_to_inst;   /* shape -> instance id in top if movable, else -1 */
    RTCScene *inst_blas;      /* bottom levels of instanced shapes */
    uint32_t inst_count;
    struct xform *to_world;   /* current object->world per shape */
    struct xform *to_object;  /* inverse of to_world per shape */
    bool *is_identity;        /* to_world is exactly the identity (hit points skip it) */
};

/* Every scene, the instanced bottom levels included, allows a context filter
 * (accel_intersect_shape_all). Embree runs the leaf intersectors of an instanced hit with the
 * child scene as the current scene and requires the flag on whichever scene's geometry reaches
 * the filter: the distribution's libembree3 keeps its assertions and aborts otherwise (tried:
 * without the flag on the top level, or on the bottom levels only, the probe test aborts).
 * Other queries cost the same with it: the single-ray path always carries the filter check (a
 * null test on the context); the flag only selects the filtering variants of the ray-packet
 * intersectors, which we do not use. */
#define ACCEL_SCENE_FLAGS RTC_SCENE_FLAG_CONTEXT_FILTER_FUNCTION

static bool accel_xform_is_identity(const struct xform *x)
{
    const struct xform id = xform_identity();
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 4; j++)
            if (x->m[i][j] != id.m[i][j]) return false;
    return true;
}

static void accel_error_cb(void *user, enum RTCError code, const char *str)
{
    (void)user;
    /* Embree reports API misuse here; our builders validate inputs first, so this is a bug. */
    fprintf(stderr, "restird: embree error %d: %s\n", (int)code, str ? str : "");
}

/* A sphere can be baked into world space only under a similarity transform; otherwise it is an
 * ellipsoid and needs an instance. */
static bool accel_is_ellipsoid(const struct shape *s)
{
    if (s->kind != SHAPE_SPHERE) return false;
    struct vec3 c0 = xform_vector(&s->to_world, vec3_make(1, 0, 0));
    struct vec3 c1 = xform_vector(&s->to_world, vec3_make(0, 1, 0));
    struct vec3 c2 = xform_vector(&s->to_world, vec3_make(0, 0, 1));
    float l0 = vec3_length(c0), l1 = vec3_length(c1), l2 = vec3_length(c2);
    float lm = fmaxf(l0, fmaxf(l1, l2)), eps = 1e-5f * lm;
    return fabsf(l0 - l1) > eps || fabsf(l0 - l2) > eps || fabsf(vec3_dot(c0, c1)) > eps * lm ||
           fabsf(vec3_dot(c0, c2)) > eps * lm || fabsf(vec3_dot(c1, c2)) > eps * lm;
}

/* Adds the shape's geometry to `target`, transformed by `xf` (identity for instanced shapes). */
static bool accel_add_geometry(RTCDevice dev, RTCScene target, const struct shape *s, const struct xform *xf,
                               unsigned *geom_id, struct err *err)
{
    RTCGeometry g;
    if (s->kind == SHAPE_MESH) {
        g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
        float *v = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                           s->vertex_count);
        unsigned *idx = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                                s->triangle_count);
        if (!v || !idx) {
            rtcReleaseGeometry(g);
            return err_set(err, ERR_NOMEM, NULL, "embree: out of memory for a mesh of %u triangles", s->triangle_count);
        }
        for (uint32_t i = 0; i < s->vertex_count; i++) {
            struct vec3 p = xform_point(xf, s->positions[i]);
            v[3 * i] = p.x;
            v[3 * i + 1] = p.y;
            v[3 * i + 2] = p.z;
        }
        memcpy(idx, s->indices, 3 * sizeof(unsigned) * s->triangle_count);
    } else {
        g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_SPHERE_POINT);
        float *v = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), 1);
        if (!v) {
            rtcReleaseGeometry(g);
            return err_set(err, ERR_NOMEM, NULL, "embree: out of memory for a sphere");
        }
        struct vec3 c = xform_point(xf, s->center);
        float scale = vec3_length(xform_vector(xf, vec3_make(1, 0, 0)));
        v[0] = c.x;
        v[1] = c.y;
        v[2] = c.z;
        v[3] = s->radius * scale;
    }
    rtcCommitGeometry(g);
    *geom_id = rtcAttachGeometry(target, g);
    rtcReleaseGeometry(g);
    return true;
}

/* Attaches `blas` to the top level as an instance placed by `xf`; returns its geomID. */
static unsigned accel_attach_instance(struct accel *a, RTCScene blas, const struct xform *xf)
{
    RTCGeometry inst = rtcNewGeometry(a->device, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(inst, blas);
    rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, &xf->m[0][0]);
    rtcCommitGeometry(inst);
    unsigned id = rtcAttachGeometry(a->top, inst);
    rtcReleaseGeometry(inst);
    return id;
}

static bool accel_alloc(struct accel *a, uint32_t n)
{
    size_t m = n ? n : 1;
    /* Top-level ids: at most one per shape plus the static instance. */
    a->top_shape = malloc((m + 1) * sizeof *a->top_shape);
    a->static_shape = malloc(m * sizeof *a->static_shape);
    a->shape_to_inst = malloc(m * sizeof *a->shape_to_inst);
    a->inst_blas = calloc(m, sizeof *a->inst_blas);
    a->to_world = malloc(m * sizeof *a->to_world);
    a->to_object = malloc(m * sizeof *a->to_object);
    a->is_identity = malloc(m * sizeof *a->is_identity);
    return a->top_shape && a->static_shape && a->shape_to_inst && a->inst_blas && a->to_world && a->to_object &&
           a->is_identity;
}

/* Layouts. With no movable shape, all geometry sits directly in one flat top-level scene (the
 * fastest traversal; ellipsoids still need an instance each). With movable shapes, static
 * geometry goes into one bottom level, instanced once, beside one instance per movable shape,
 * so that moving a shape rebuilds only a top level of a few boxes, never the static BVH. */
struct accel *accel_new(const struct scene *scene, const bool *movable, struct err *err)
{
    struct accel *a = calloc(1, sizeof *a);
    uint32_t n = scene->shape_count;
    if (!a || !accel_alloc(a, n)) {
        accel_free(a);
        err_set(err, ERR_NOMEM, NULL, "out of memory building the acceleration structure");
        return NULL;
    }
    a->static_inst_id = RTC_INVALID_GEOMETRY_ID;
    bool two_level = false;
    for (uint32_t i = 0; movable && i < n; i++) two_level |= movable[i];

    a->device = rtcNewDevice(NULL);
    if (!a->device) {
        err_set(err, ERR_INTERNAL, NULL, "embree: cannot create a device (error %d)", (int)rtcGetDeviceError(NULL));
        accel_free(a);
        return NULL;
    }
    rtcSetDeviceErrorFunction(a->device, accel_error_cb, NULL);
    a->top = rtcNewScene(a->device);
    /* Build quality LOW in both layouts. For the flat layout this is a traversal-speed choice,
     * not a build-time one: at LOW Embree builds one SAH BVH per geometry (each geometry keeps
     * its default MEDIUM quality) and merges them under a common top, still one BVH4 of
     * triangle4 leaves, whereas MEDIUM/HIGH build one BVH over all triangles (HIGH with
     * spatial splits). Scenes are made of separate shapes (the Cornell box: 16 quads), and the
     * per-shape trees bound them tightly: on the Cornell box Embree needs 18 % fewer
     * instructions per ray at LOW than at HIGH, with identical hits (bit-identical images;
     * docs/benchmarks.md), and a large single-mesh scene we tried was faster too. Where
     * triangles share an edge, which of the two a ray exactly on the edge reports can differ
     * between the two trees. */
    rtcSetSceneBuildQuality(a->top, RTC_BUILD_QUALITY_LOW);
    rtcSetSceneFlags(a->top, (two_level ? RTC_SCENE_FLAG_DYNAMIC : RTC_SCENE_FLAG_NONE) | ACCEL_SCENE_FLAGS);

    struct xform identity = xform_identity();
    for (uint32_t i = 0; i < n; i++) {
        const struct shape *s = &scene->shapes[i];
        a->to_world[i] = s->to_world;
        a->is_identity[i] = accel_xform_is_identity(&s->to_world);
        a->shape_to_inst[i] = -1;
        if (!xform_invert(&s->to_world, &a->to_object[i])) {
            char where[64];
            snprintf(where, sizeof where, "/shapes/%u/transform", i);
            err_set(err, ERR_INVALID, where, "transform is singular");
            accel_free(a);
            return NULL;
        }
        bool is_movable = movable && movable[i];
        unsigned gid;
        if (is_movable || accel_is_ellipsoid(s)) {
            RTCScene blas = rtcNewScene(a->device);
            rtcSetSceneBuildQuality(blas, RTC_BUILD_QUALITY_HIGH);
            rtcSetSceneFlags(blas, ACCEL_SCENE_FLAGS);
            a->inst_blas[a->inst_count++] = blas;
            if (!accel_add_geometry(a->device, blas, s, &identity, &gid, err)) {
                accel_free(a);
                return NULL;
            }
            rtcCommitScene(blas);
            unsigned iid = accel_attach_instance(a, blas, &s->to_world);
            a->top_shape[iid] = i;
            if (is_movable) a->shape_to_inst[i] = (int32_t)iid;
        } else if (two_level) {
            if (!a->static_blas) {
                a->static_blas = rtcNewScene(a->device);
                rtcSetSceneBuildQuality(a->static_blas, RTC_BUILD_QUALITY_HIGH);
                rtcSetSceneFlags(a->static_blas, ACCEL_SCENE_FLAGS);
            }
            if (!accel_add_geometry(a->device, a->static_blas, s, &s->to_world, &gid, err)) {
                accel_free(a);
                return NULL;
            }
            a->static_shape[gid] = i;
        } else {
            if (!accel_add_geometry(a->device, a->top, s, &s->to_world, &gid, err)) {
                accel_free(a);
                return NULL;
            }
            a->top_shape[gid] = i;
        }
    }
    if (a->static_blas) {
        rtcCommitScene(a->static_blas);
        a->static_inst_id = accel_attach_instance(a, a->static_blas, &identity);
    }
    rtcCommitScene(a->top);
    enum RTCError e = rtcGetDeviceError(a->device);
    if (e != RTC_ERROR_NONE) {
        err_set(err, ERR_INTERNAL, NULL, "embree: scene build failed (error %d)", (int)e);
        accel_free(a);
        return NULL;
    }
    return a;
}

void accel_free(struct accel *a)
{
    if (!a) return;
    if (a->top) rtcReleaseScene(a->top);
    if (a->static_blas) rtcReleaseScene(a->static_blas);
    for (uint32_t i = 0; i < a->inst_count; i++) rtcReleaseScene(a->inst_blas[i]);
    if (a->device) rtcReleaseDevice(a->device);
    free(a->shape_to_inst);
    free(a->top_shape);
    free(a->static_shape);
    free(a->inst_blas);
    free(a->to_world);
    free(a->to_object);
    free(a->is_identity);
    free(a);
}

/* Four floats stored as one: Embree's single-ray kernels load a ray's origin with its tnear, and
 * its direction with its time, 16 bytes at a time. Written as separate floats, such a load
 * finds three or four smaller stores still in flight, which the processor cannot forward to
 * it, and waits until they reach the cache; written as one 16-byte store it is forwarded at
 * once (docs/benchmarks.md, "Path tracer throughput"). */
typedef float accel_float4 __attribute__((vector_size(16), may_alias));

/* The part of an Embree ray a query sets every time: origin, tnear, direction, time (0) and far
 * end. */
static inline void accel_ray_aim(struct RTCRay *r, struct vec3 org, float tmin, struct vec3 dir, float tmax)
{
    *(accel_float4 *)(void *)&r->org_x = (accel_float4){org.x, org.y, org.z, tmin};
    *(accel_float4 *)(void *)&r->dir_x = (accel_float4){dir.x, dir.y, dir.z, 0.0f};
    r->tfar = tmax;
}

/* The rest of a single ray, the same for every query: seen by all masks. */
static inline void accel_ray_fixed(struct RTCRay *r)
{
    r->mask = 0xFFFFFFFFu;
    r->id = 0;
    r->flags = 0;
}

/* A single ray over [tmin, tmax] with no hit yet, written in place (returned by value, the
 * 80-byte struct was built in a temporary and copied). */
static void accel_ray_hit(struct RTCRayHit *out, struct vec3 org, struct vec3 dir, float tmin, float tmax)
{
    accel_ray_aim(&out->ray, org, tmin, dir, tmax);
    accel_ray_fixed(&out->ray);
    out->hit.geomID = RTC_INVALID_GEOMETRY_ID;
    out->hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
}

/* A closest-hit query's answer as a struct hit (false: no hit). */
static inline bool accel_hit_from(const struct accel *a, const struct RTCRayHit *rh, struct hit *hit)
{
    if (rh->hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;

    /* Embree's Ng is unnormalised and, for instanced hits, in the instance's object space. For
     * triangles it already points to the counter-clockwise (front) side, for spheres outwards
     * (both checked by tests/unit/test_core.c). */
    unsigned iid = rh->hit.instID[0];
    struct vec3 ng = vec3_make(rh->hit.Ng_x, rh->hit.Ng_y, rh->hit.Ng_z);
    uint32_t shape;
    if (iid == RTC_INVALID_GEOMETRY_ID) {
        shape = a->top_shape[rh->hit.geomID];
    } else if (iid == a->static_inst_id) {
        shape = a->static_shape[rh->hit.geomID];
    } else {
        shape = a->top_shape[iid];
        ng = xform_normal(&a->to_object[shape], ng);
    }
    hit->t = rh->ray.tfar;
    hit->shape = shape;
    hit->prim = rh->hit.primID;
    hit->b1 = rh->hit.u;
    hit->b2 = rh->hit.v;
    hit->ng = vec3_normalize(ng);
    return true;
}

bool accel_intersect(const struct accel *a, struct vec3 org, struct vec3 dir, float tmin, float tmax,
                     struct hit *hit, struct ray_counters *counters)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    struct RTCRayHit rh;
    accel_ray_hit(&rh, org, dir, tmin, tmax);
    rtcIntersect1(a->top, &ctx, &rh);
    counters->intersect++;
    return accel_hit_from(a, &rh, hit);
}

/* struct accel_query's bytes as Embree's structs. may_alias: the bytes are declared as a char
 * array (accel.h keeps Embree's types out of its includers), and are only ever accessed as
 * these types. */
struct accel_query_rtc {
    struct RTCIntersectContext ctx;
    struct RTCRayHit rh;   /* closest-hit queries */
    struct RTCRay ray;     /* occlusion queries */
} __attribute__((may_alias));
_Static_assert(sizeof(struct accel_query_rtc) <= sizeof(struct accel_query), "accel_query holds Embree's structs");
_Static_assert(_Alignof(struct accel_query_rtc) <= _Alignof(struct accel_query), "accel_query is aligned for them");

static inline struct accel_query_rtc *accel_query_rtc(struct accel_query *q)
{
    return (struct accel_query_rtc *)(void *)q->opaque;
}

void accel_query_init(struct accel_query *q)
{
    struct accel_query_rtc *r = accel_query_rtc(q);
    rtcInitIntersectContext(&r->ctx);
    accel_ray_hit(&r->rh, vec3_splat(0.0f), vec3_make(0.0f, 0.0f, 1.0f), 0.0f, INFINITY);
    r->ray = r->rh.ray;
}

bool accel_query_intersect(const struct accel *a, struct accel_query *q, struct vec3 org, struct vec3 dir,
                           float tmax, struct hit *hit, struct ray_counters *counters)
{
    struct accel_query_rtc *r = accel_query_rtc(q);
    /* Only what a query changes: the ray, the tfar a hit shortened and the hit record. */
    accel_ray_aim(&r->rh.ray, org, 0.0f, dir, tmax);
    r->rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    r->rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(a->top, &r->ctx, &r->rh);
    counters->intersect++;
    return accel_hit_from(a, &r->rh, hit);
}

bool accel_query_occluded(const struct accel *a, struct accel_query *q, struct vec3 org, struct vec3 dir,
                          float tmax, struct ray_counters *counters)
{
    struct accel_query_rtc *r = accel_query_rtc(q);
    accel_ray_aim(&r->ray, org, 0.0f, dir, tmax);   /* Embree sets tfar to -inf on a hit */
    rtcOccluded1(a->top, &r->ctx, &r->ray);
    counters->occluded++;
    return r->ray.tfar < 0.0f;
}

/* Candidates kept by one accel_intersect_shape_all traversal. Larger than BSSRDF_MAX_HITS (16)
 * with room for the duplicates that are merged afterwards; a ray crossing more surfaces of the
 * shape keeps the closest ACCEL_ALL_HITS_CAP, so the list is then a correct but shorter prefix. */
#define ACCEL_ALL_HITS_CAP 64

/* RTCIntersectContext first, so that the filter can recover the whole struct from the context
 * pointer Embree hands it. */
struct accel_all_hits_ctx {
    struct RTCIntersectContext rtc;
    const struct accel *a;
    uint32_t shape;
    uint32_t n;
    bool instanced;  /* the shape's hits come from its own instance: Ng is in object space */
    struct hit cand[ACCEL_ALL_HITS_CAP];
};

/* Orders by t, then primID: the sort key of the candidates. */
static bool accel_hit_before(const struct hit *x, const struct hit *y)
{
    return x->t < y->t || (x->t == y->t && x->prim < y->prim);
}

/* Embree's RTCRayN/RTCHitN accessors are C++ only (they return references); these read the same
 * structure-of-arrays layout (rtcore_ray.h): word `field` of element i in a packet of N. */
static float accel_rayn_f(const struct RTCRayN *r, unsigned N, unsigned i, unsigned field)
{
    return ((const float *)r)[field * N + i];
}

static float accel_hitn_f(const struct RTCHitN *h, unsigned N, unsigned i, unsigned field)
{
    return ((const float *)h)[field * N + i];
}

static unsigned accel_hitn_u(const struct RTCHitN *h, unsigned N, unsigned i, unsigned field)
{
    return ((const unsigned *)h)[field * N + i];
}

enum { ACCEL_RAYN_TFAR = 8 };
enum { ACCEL_HITN_NG_X, ACCEL_HITN_NG_Y, ACCEL_HITN_NG_Z, ACCEL_HITN_U, ACCEL_HITN_V, ACCEL_HITN_PRIM,
       ACCEL_HITN_GEOM, ACCEL_HITN_INST0 };

/* Records every hit on the wanted shape and rejects all hits, so that Embree never shrinks tfar
 * and one traversal visits every surface in (tmin, tmax). Embree has already applied its own
 * interval test, the same one a closest-hit query with these bounds applies, so no t is tested
 * again here (a second test in t could only disagree at rounding level). */
static void accel_all_hits_filter(const struct RTCFilterFunctionNArguments *args)
{
    struct accel_all_hits_ctx *c = (struct accel_all_hits_ctx *)args->context;
    const struct accel *a = c->a;
    for (unsigned i = 0; i < args->N; i++) {
        if (!args->valid[i]) continue;
        args->valid[i] = 0;
        unsigned iid = accel_hitn_u(args->hit, args->N, i, ACCEL_HITN_INST0);
        unsigned gid = accel_hitn_u(args->hit, args->N, i, ACCEL_HITN_GEOM);
        /* The shape mapping of accel_intersect. */
        uint32_t shape;
        bool instanced = false;
        if (iid == RTC_INVALID_GEOMETRY_ID) {
            shape = a->top_shape[gid];
        } else if (iid == a->static_inst_id) {
            shape = a->static_shape[gid];
        } else {
            shape = a->top_shape[iid];
            instanced = true;
        }
        if (shape != c->shape) continue;
        c->instanced = instanced;
        /* During the filter call Embree sets the ray's tfar to the hit's t (and restores it when
         * the hit is rejected); for instanced hits the ray is in object space, but the
         * instance transform keeps the parameter t. */
        struct hit h;
        h.t = accel_rayn_f(args->ray, args->N, i, ACCEL_RAYN_TFAR);
        h.shape = shape;
        h.prim = accel_hitn_u(args->hit, args->N, i, ACCEL_HITN_PRIM);
        h.b1 = accel_hitn_f(args->hit, args->N, i, ACCEL_HITN_U);
        h.b2 = accel_hitn_f(args->hit, args->N, i, ACCEL_HITN_V);
        h.ng = vec3_make(accel_hitn_f(args->hit, args->N, i, ACCEL_HITN_NG_X),
                         accel_hitn_f(args->hit, args->N, i, ACCEL_HITN_NG_Y),
                         accel_hitn_f(args->hit, args->N, i, ACCEL_HITN_NG_Z));
        /* Insertion into the sorted candidates; when full, the farthest one gives way, so the
         * closest ACCEL_ALL_HITS_CAP survive whatever order the traversal reports them in. */
        uint32_t k = c->n;
        if (k == ACCEL_ALL_HITS_CAP) {
            if (!accel_hit_before(&h, &c->cand[k - 1])) continue;
            k--;
        } else {
            c->n++;
        }
        while (k > 0 && accel_hit_before(&h, &c->cand[k - 1])) {
            c->cand[k] = c->cand[k - 1];
            k--;
        }
        c->cand[k] = h;
    }
}

uint32_t accel_intersect_shape_all(const struct accel *a, uint32_t shape, struct vec3 org, struct vec3 dir,
                                   float tmin, float tmax, struct hit *hits, uint32_t max_hits,
                                   struct ray_counters *counters)
{
    /* One traversal that sees every hit (the filter above), instead of one closest-hit query per
     * hit: BSSRDF probes cross the translucent shape several times, and a query restarted past
     * each hit re-traverses the BVH from the root every time. */
    if (max_hits == 0) return 0;
    struct accel_all_hits_ctx c;
    rtcInitIntersectContext(&c.rtc);
    c.rtc.filter = accel_all_hits_filter;
    c.a = a;
    c.shape = shape;
    c.n = 0;
    c.instanced = false;
    struct RTCRayHit rh;
    accel_ray_hit(&rh, org, dir, tmin, tmax);
    rtcIntersect1(a->top, &c.rtc, &rh);
    counters->intersect++;

    /* Duplicates. A ray through an edge shared by two triangles of the shape (or tangent to a
     * sphere) reports both, at equal or nearly equal t. The former method (closest-hit queries,
     * each restarted at nextafterf of the hit just reported) reported one of them: its restart
     * skipped everything up to one float step past the hit it returned, which was the smallest
     * t. The same rule here: in order of t, a hit within one float step of the last kept one is
     * dropped, so of a near-coincident group the smallest t is kept; at exactly equal t the
     * former choice followed the BVH traversal order, not knowable here, and the lower primID
     * (the sort key) is kept instead, which is deterministic.
     * At that rounding level the former method was itself inconsistent (Embree tests tnear on an
     * unnormalised distance, and culls boxes by tnear), and tests/unit/test_bssrdf.c compares
     * the two on every such ray: it could report one hit twice, stop at such a repeat (on any
     * shape) and lose every later hit, miss a second triangle a few floats beyond an edge, and it
     * lost hits within a float step of another shape's hit, as where the floor meets a wall.
     * This traversal has none of these; all need a ray within a few floats of an edge or of a
     * repeat, so away from them both return the same list. */
    uint32_t n = 0;
    for (uint32_t i = 0; i < c.n && n < max_hits; i++) {
        const struct hit *h = &c.cand[i];
        if (n > 0 && h->t <= nextafterf(hits[n - 1].t, INFINITY)) continue;
        hits[n] = *h;
        /* Embree's Ng is unnormalised and, for instanced hits, in object space (accel_intersect). */
        struct vec3 ng = c.instanced ? xform_normal(&a->to_object[shape], h->ng) : h->ng;
        hits[n].ng = vec3_normalize(ng);
        n++;
    }
    return n;
}

bool accel_occluded(const struct accel *a, struct vec3 org, struct vec3 dir, float tmin, float tmax,
                    struct ray_counters *counters)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    struct RTCRay ray;
    accel_ray_aim(&ray, org, tmin, dir, tmax);
    accel_ray_fixed(&ray);
    rtcOccluded1(a->top, &ctx, &ray);
    counters->occluded++;
    return ray.tfar < 0.0f;  /* Embree sets tfar = -inf on a hit */
}

bool accel_set_transform(struct accel *a, uint32_t shape, const struct xform *to_world)
{
    int32_t iid = a->shape_to_inst[shape];
    struct xform inv;
    if (iid < 0 || !xform_invert(to_world, &inv)) return false;
    RTCGeometry inst = rtcGetGeometry(a->top, (unsigned)iid);
    rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, &to_world->m[0][0]);
    rtcCommitGeometry(inst);
    a->to_world[shape] = *to_world;
    a->to_object[shape] = inv;
    a->is_identity[shape] = accel_xform_is_identity(to_world);
    return true;
}

void accel_commit_top(struct accel *a)
{
    rtcCommitScene(a->top);
}

const struct xform *accel_shape_to_world(const struct accel *a, uint32_t shape)
{
    return &a->to_world[shape];
}

const struct xform *accel_shape_to_object(const struct accel *a, uint32_t shape)
{
    return &a->to_object[shape];
}

bool accel_shape_is_identity(const struct accel *a, uint32_t shape)
{
    return a->is_identity[shape];
}

/* Up to ACCEL_BUNDLE rays from one origin (a pixel's camera rays) traced as one Embree packet:
 * they share the BVH nodes they visit, so each node is fetched and tested once for all of them
 * instead of once per ray. A single ray goes through the one-ray kernel, which a one-lane packet
 * is slower than (docs/benchmarks.md, "Camera rays in packets"). */
uint32_t accel_intersect_bundle(const struct accel *a, struct vec3 org, const struct vec3 *dirs, uint32_t n,
                                struct hit *hits, bool *found, struct ray_counters *counters)
{
    if (n == 1) {
        found[0] = accel_intersect(a, org, dirs[0], 0.0f, INFINITY, &hits[0], counters);
        return found[0] ? 1u : 0u;
    }
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    _Alignas(32) int valid[ACCEL_BUNDLE];
    struct RTCRayHit8 p;
    _Static_assert(ACCEL_BUNDLE == 8, "the packet is Embree's 8-wide one");
    for (uint32_t i = 0; i < ACCEL_BUNDLE; i++) {
        bool on = i < n;
        /* A lane past n is switched off; its ray is still a valid one (Embree reads it). */
        struct vec3 d = on ? dirs[i] : vec3_make(0.0f, 0.0f, 1.0f);
        valid[i] = on ? -1 : 0;
        p.ray.org_x[i] = org.x;
        p.ray.org_y[i] = org.y;
        p.ray.org_z[i] = org.z;
        p.ray.tnear[i] = 0.0f;
        p.ray.dir_x[i] = d.x;
        p.ray.dir_y[i] = d.y;
        p.ray.dir_z[i] = d.z;
        p.ray.time[i] = 0.0f;
        p.ray.tfar[i] = INFINITY;
        p.ray.mask[i] = 0xFFFFFFFFu;
        p.ray.id[i] = i;
        p.ray.flags[i] = 0;
        p.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
        p.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
    }
    rtcIntersect8(valid, a->top, &ctx, &p);
    counters->intersect += n;
    uint32_t count = 0;
    for (uint32_t i = 0; i < n; i++) {
        struct RTCRayHit rh;
        rh.ray.tfar = p.ray.tfar[i];
        rh.hit.Ng_x = p.hit.Ng_x[i];
        rh.hit.Ng_y = p.hit.Ng_y[i];
        rh.hit.Ng_z = p.hit.Ng_z[i];
        rh.hit.u = p.hit.u[i];
        rh.hit.v = p.hit.v[i];
        rh.hit.primID = p.hit.primID[i];
        rh.hit.geomID = p.hit.geomID[i];
        rh.hit.instID[0] = p.hit.instID[0][i];
        found[i] = accel_hit_from(a, &rh, &hits[i]);
        count += found[i];
    }
    return count;
}
