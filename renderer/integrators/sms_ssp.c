/* sms_ssp.c — sample-space partitioning and per-frame priors for SMS (see sms_ssp.h).
 * Refs: [SMS-SSP §3.3] (trust regions, conditional sample space, eqs. 4-5), §4.1 (prior,
 * eqs. 7-9). */
#include "integrators/sms_ssp.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scene/light_sampler.h"
#include "core/parallel.h"
#include "core/sampling.h"
#include "scene/scene.h"

struct ssp_params ssp_defaults(void)
{
    return (struct ssp_params){.sms = sms_defaults(), .tiles = 16, .prior = true, .prior_samples = 128, .alpha = 0.8f,
                                .prior_frames = 4};
}

bool ssp_params_valid(const struct ssp_params *p, struct err *err)
{
    if (!sms_params_valid(&p->sms, err)) return false;
    if (p->tiles < 3 || p->tiles > SSP_MAX_TILES)
        return err_set(err, ERR_INVALID, "tiles", "tiles must be in [3, %d], got %u", SSP_MAX_TILES, p->tiles);
    if (p->prior_samples > 4096)
        return err_set(err, ERR_INVALID, "prior_samples", "prior_samples must be at most 4096, got %u", p->prior_samples);
    if (p->prior_frames < 1 || p->prior_frames > SSP_MAX_PRIOR_FRAMES)
        return err_set(err, ERR_INVALID, "prior_frames", "prior_frames must be in [1, %u], got %u", SSP_MAX_PRIOR_FRAMES,
                       p->prior_frames);
    if (!(p->alpha >= 0.0f && p->alpha < 1.0f))
        return err_set(err, ERR_INVALID, "alpha", "alpha must be in [0, 1), got %g", (double)p->alpha);
    return true;
}

static uint32_t ssp_blocks(uint32_t n) { return (n + SSP_BLOCK - 1) / SSP_BLOCK; }

static size_t ssp_table_entries(uint32_t width, uint32_t height)
{
    return (size_t)ssp_blocks(width) * ssp_blocks(height) * SSP_PRIOR_ENTRIES;
}

size_t ssp_prior_bytes(uint32_t width, uint32_t height, uint32_t frames)
{
    return (frames > 1 ? 1 + (size_t)frames : 1) * ssp_table_entries(width, height) * sizeof(struct ssp_entry);
}

bool ssp_prior_init(struct ssp_prior *pr, uint32_t width, uint32_t height, uint32_t frames, struct err *err)
{
    memset(pr, 0, sizeof *pr);
    pr->blocks_x = ssp_blocks(width);
    pr->blocks_y = ssp_blocks(height);
    pr->frames = frames > 1 ? frames : 1;
    size_t n = ssp_table_entries(width, height);
    pr->entries = calloc(n, sizeof *pr->entries);
    if (pr->frames > 1) pr->walks = calloc(n * pr->frames, sizeof *pr->walks);
    if (!pr->entries || (pr->frames > 1 && !pr->walks)) {
        ssp_prior_destroy(pr);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for the sms_ssp prior");
    }
    return true;
}

void ssp_prior_destroy(struct ssp_prior *pr)
{
    free(pr->entries);
    free(pr->walks);
    pr->entries = pr->walks = NULL;
}

/* ---- the seed space: directions in the caster's bounding cone ---- */

struct ssp_cone {
    struct frame f;
    float cos_max, dist;
    struct vec3 x1;
};

static void ssp_cone_at(const struct sms_caster *c, struct vec3 x1, struct ssp_cone *k)
{
    struct vec3 centre = c->sphere ? c->centre : vec3_scale(vec3_add(c->lo, c->hi), 0.5f);
    struct vec3 a = vec3_sub(centre, x1);
    float d = vec3_length(a);
    k->x1 = x1;
    k->dist = d > 0.0f ? d : 1.0f;
    k->f = frame_from_normal(d > 0.0f ? vec3_scale(a, 1.0f / d) : vec3_make(0.0f, 0.0f, 1.0f));
    k->cos_max = -1.0f;
    if (c->sphere) {
        if (d > 1.0001f * c->radius) k->cos_max = sqrtf(fmaxf(0.0f, 1.0f - (c->radius / d) * (c->radius / d)));
        return;
    }
    /* The narrowest cone about the centre direction holding the box's 8 corners holds the box
     * (their convex hull) while its half-angle is below 90 degrees. */
    bool inside = x1.x >= c->lo.x && x1.x <= c->hi.x && x1.y >= c->lo.y && x1.y <= c->hi.y && x1.z >= c->lo.z &&
                  x1.z <= c->hi.z;
    if (inside || !(d > 0.0f)) return;
    float cmin = 1.0f;
    for (int i = 0; i < 8; i++) {
        struct vec3 q = vec3_make(i & 1 ? c->hi.x : c->lo.x, i & 2 ? c->hi.y : c->lo.y, i & 4 ? c->hi.z : c->lo.z);
        cmin = fminf(cmin, vec3_dot(k->f.n, vec3_normalize(vec3_sub(q, x1))));
    }
    if (cmin > 0.0f) k->cos_max = fmaxf(-1.0f, cmin - 1e-4f);
}

/* u -> direction: the concentric map takes the square to the unit disk, and the disk's radius r
 * to the cone's polar angle with 1 - cos θ = r² (1 - cos θmax), which keeps areas: a uniform u
 * is a uniform direction in the cone. Tiles stay near-square in direction space. The polar map
 * (cos θ from u1, φ from u2) made tiles wedges meeting at the axis and slivers at the rim, and a
 * 3 x 3 trust region there spans a wide range of azimuth but almost no polar angle: walks that
 * would converge left it. */
static struct vec3 ssp_dir(const struct ssp_cone *k, float u1, float u2)
{
    float x, y;
    sampling_concentric_disk(u1, u2, &x, &y);
    float r2 = x * x + y * y;
    float c = 1.0f - r2 * (1.0f - k->cos_max), s = sqrtf(fmaxf(0.0f, 1.0f - c * c));
    float sr = r2 > 0.0f ? s / sqrtf(r2) : 0.0f;
    return frame_to_world(&k->f, vec3_make(x * sr, y * sr, c));
}

/* The tile (i along u1, j along u2) of the direction towards p; false outside the cone. */
static bool ssp_tile_of(const struct ssp_cone *k, uint32_t n, struct vec3 p, uint32_t *ti, uint32_t *tj)
{
    struct vec3 w = frame_to_local(&k->f, vec3_normalize(vec3_sub(p, k->x1)));
    float r2 = (1.0f - w.z) / (1.0f - k->cos_max);
    if (!(r2 >= 0.0f && r2 < 1.0f)) return false;
    float h = sqrtf(w.x * w.x + w.y * w.y), u1 = 0.5f, u2 = 0.5f;
    if (h > 0.0f) {
        float r = sqrtf(r2) / h;
        sampling_concentric_disk_inverse(w.x * r, w.y * r, &u1, &u2);
    }
    uint32_t i = (uint32_t)(fmaxf(u1, 0.0f) * (float)n), j = (uint32_t)(fmaxf(u2, 0.0f) * (float)n);
    *ti = i < n ? i : n - 1;
    *tj = j < n ? j : n - 1;
    return true;
}

/* Cyclic tile distance <= 1 in both coordinates: the 3 x 3 trust region (periodic). */
static bool ssp_near(uint32_t a, uint32_t b, uint32_t n)
{
    uint32_t d = a > b ? a - b : b - a;
    return d <= 1 || d == n - 1;
}

struct ssp_region {
    const struct ssp_cone *cone;
    uint32_t n, ti, tj;
};

static bool ssp_inside(const void *ctx, struct vec3 x2)
{
    const struct ssp_region *r = ctx;
    uint32_t i, j;
    return ssp_tile_of(r->cone, r->n, x2, &i, &j) && ssp_near(i, r->ti, r->n) && ssp_near(j, r->tj, r->n);
}

static bool ssp_bit(const struct ssp_entry *e, uint32_t t) { return (e->bits[t >> 6] >> (t & 63)) & 1u; }

/* The k-th set tile of a tile set. */
static uint32_t ssp_nth(const struct ssp_entry *e, uint32_t k, uint32_t n2)
{
    for (uint32_t t = 0; t < n2; t++)
        if (ssp_bit(e, t) && k-- == 0) return t;
    return 0;
}

static const struct ssp_entry *ssp_find(const struct ssp_prior *pr, uint32_t block, uint32_t light, uint32_t caster)
{
    const struct ssp_entry *e = &pr->entries[(size_t)block * SSP_PRIOR_ENTRIES];
    for (int i = 0; i < SSP_PRIOR_ENTRIES; i++)
        if (e[i].light_shape == (int32_t)light && e[i].caster == (int32_t)caster) return &e[i];
    return NULL;
}

/* Whether receiver x lies near the receivers that built tile set e: inside their box grown by its
 * largest extent on every side. The tiles are directions from those receivers; from a receiver
 * far from them they mark arbitrary tiles, and a solution outside them would carry the uniform
 * share's weight, N² / (9 (1 − α)). One receiver's set (an empty box) serves no other. */
static bool ssp_covers(const struct ssp_entry *e, struct vec3 x)
{
    float ext = 0.0f;
    for (int a = 0; a < 3; a++) ext = fmaxf(ext, e->hi[a] - e->lo[a]);
    for (int a = 0; a < 3; a++)
        if (vec3_comp(x, a) < e->lo[a] - ext || vec3_comp(x, a) > e->hi[a] + ext) return false;
    return true;
}

/* A walk from seed u (tile ti, tj plus offsets) confined to R(u). */
static bool ssp_walk(const struct scene *scene, const struct sms_caster *cs, const struct manifold_ends *e,
                     const struct ssp_cone *k, uint32_t n, float u1, float u2, uint32_t max_it,
                     struct manifold_vertex *v, uint64_t *newton, struct ray_counters *rc)
{
    uint32_t ti = (uint32_t)(u1 * (float)n), tj = (uint32_t)(u2 * (float)n);
    struct ssp_region reg = {k, n, ti < n ? ti : n - 1, tj < n ? tj : n - 1};
    struct vec3 target = vec3_madd(k->x1, ssp_dir(k, u1, u2), k->dist);
    if (!manifold_seed_path(scene, &cs->chain, e, target, v, rc)) return false;
    struct manifold_stats st = {0};
    bool ok = manifold_walk_within(scene, &cs->chain, e, v, max_it, ssp_inside, &reg, &st, rc);
    *newton += st.iterations;
    return ok;
}

static void ssp_table_clear(struct ssp_entry *tab)
{
    memset(tab, 0, SSP_PRIOR_ENTRIES * sizeof *tab);
    for (int i = 0; i < SSP_PRIOR_ENTRIES; i++) tab[i].light_shape = tab[i].caster = -1;
}

/* The entry of pair (light, caster) in a block's table, or else its first unused entry (NULL
 * when all SSP_PRIOR_ENTRIES hold other pairs). */
static struct ssp_entry *ssp_slot(struct ssp_entry *tab, int32_t light, int32_t caster)
{
    for (int q = 0; q < SSP_PRIOR_ENTRIES; q++)
        if ((tab[q].light_shape == light && tab[q].caster == caster) || tab[q].light_shape < 0) return &tab[q];
    return NULL;
}

/* The block's prior as the union of its kept frames' tile sets and boxes per pair, the newest
 * frame (`slot`) first. */
static void ssp_prior_unite(struct ssp_prior *pr, uint32_t block, uint32_t slot)
{
    const size_t table = (size_t)pr->blocks_x * pr->blocks_y * SSP_PRIOR_ENTRIES;
    struct ssp_entry *out = &pr->entries[(size_t)block * SSP_PRIOR_ENTRIES];
    ssp_table_clear(out);
    for (uint32_t age = 0; age < pr->kept; age++) {
        const struct ssp_entry *in = &pr->walks[((slot + pr->frames - age) % pr->frames) * table +
                                                (size_t)block * SSP_PRIOR_ENTRIES];
        for (int i = 0; i < SSP_PRIOR_ENTRIES && in[i].light_shape >= 0; i++) {
            struct ssp_entry *o = ssp_slot(out, in[i].light_shape, in[i].caster);
            if (!o) continue;
            if (o->light_shape < 0) {
                *o = in[i];
                continue;
            }
            for (int a = 0; a < 3; a++) {
                o->lo[a] = fminf(o->lo[a], in[i].lo[a]);
                o->hi[a] = fmaxf(o->hi[a], in[i].hi[a]);
            }
            o->count = 0;
            for (size_t w = 0; w < sizeof o->bits / sizeof o->bits[0]; w++) {
                o->bits[w] |= in[i].bits[w];
                o->count += (uint32_t)__builtin_popcountll(o->bits[w]);
            }
        }
    }
}

/* One prior job: a block's walks, into its own entry table with its own random stream, so the
 * prior does not depend on which worker builds which block. Counters go to the worker's slot. */
struct ssp_prior_job {
    struct ssp_prior *pr;
    const struct scene *scene;
    const struct sms_scene *ss;
    const struct ssp_params *p;
    const struct camera *cam;
    uint64_t seed;
    uint32_t frame;
    uint32_t slot;     /* this frame's walks go to walks[slot] (K > 1) */
    struct ssp_prior_counters c[SSP_PRIOR_WORKERS];
    struct ray_counters rc[SSP_PRIOR_WORKERS];
};

static void ssp_prior_block(void *ctx, uint32_t block, unsigned worker)
{
    struct ssp_prior_job *job = ctx;
    struct ssp_prior *pr = job->pr;
    const struct scene *scene = job->scene;
    const struct sms_scene *ss = job->ss;
    const struct ssp_params *p = job->p;
    const struct camera *cam = job->cam;
    struct ssp_prior_counters *c = &job->c[worker];
    struct ray_counters *rc = &job->rc[worker];
    const uint32_t n = p->tiles, bx = block % pr->blocks_x, by = block / pr->blocks_x;
    const size_t table = (size_t)pr->blocks_x * pr->blocks_y * SSP_PRIOR_ENTRIES;
    struct ssp_entry *tab = pr->walks ? &pr->walks[job->slot * table + (size_t)block * SSP_PRIOR_ENTRIES]
                                      : &pr->entries[(size_t)block * SSP_PRIOR_ENTRIES];
    ssp_table_clear(tab);
    /* Its own stream: a frame's prior does not depend on the pixels' samples. */
    struct rng rng = rng_make(job->seed, job->frame, block, (uint64_t)2 << 40);
    for (uint32_t s = 0; s < p->prior_samples; s++) {
        float px = ((float)bx + rng_next_float(&rng)) * SSP_BLOCK, py = ((float)by + rng_next_float(&rng)) * SSP_BLOCK;
        float uc = rng_next_float(&rng), ul = rng_next_float(&rng), l1 = rng_next_float(&rng);
        float l2 = rng_next_float(&rng), u1 = rng_next_float(&rng), u2 = rng_next_float(&rng);
        if (px >= (float)cam->width || py >= (float)cam->height) continue;
        struct vec3 dir = camera_ray_dir(cam, px, py);
        struct hit h;
        if (!accel_intersect(scene->accel, cam->position, dir, 0.0f, INFINITY, &h, rc)) continue;
        /* The pixel's shading point (§4.1): its receiver, which for a pixel seen through
         * a glass slab or in a mirror lies behind the delta vertices, where its SMS estimate
         * is made. Primary hits alone left those pixels without a prior of their own, or
         * worse, with the tiles of other pixels' solutions, seen from elsewhere. */
        struct hit rh;
        struct surface x1;
        struct vec3 wo, T;
        uint32_t depth;
        if (!sms_receiver_trace(scene, UINT32_MAX, cam->position, dir, &h, &rh, &x1, &wo, &T, &depth, rc))
            continue;
        uint32_t ci = (uint32_t)(uc * (float)ss->count);
        if (ci >= ss->count) ci = ss->count - 1;
        const struct sms_caster *cs = &ss->casters[ci];
        struct light_sample ls;
        if (!light_sampler_sample(scene->lights, ul, l1, l2, &ls) || ls.is_env) continue;
        c->samples++;
        struct manifold_ends e = {.x1 = x1.p, .ng1 = x1.ng, .xe = ls.p, .nge = ls.n};
        struct ssp_cone k;
        ssp_cone_at(cs, x1.p, &k);
        struct manifold_vertex v[MANIFOLD_MAX_CHAIN];
        struct manifold_stats st = {0};
        /* Unrestricted walks (§4.1): no trust region while building the prior. */
        bool ok = manifold_seed_path(scene, &cs->chain, &e, vec3_madd(k.x1, ssp_dir(&k, u1, u2), k.dist), v, rc) &&
                  manifold_walk(scene, &cs->chain, &e, v, p->sms.max_iterations, &st, rc) &&
                  manifold_check(scene, &cs->chain, &e, v, rc);
        c->newton += st.iterations;
        uint32_t ti, tj;
        if (!ok || !ssp_tile_of(&k, n, v[0].p, &ti, &tj)) continue;
        c->solutions++;
        struct ssp_entry *slot = ssp_slot(tab, (int32_t)ls.shape, (int32_t)ci);
        if (!slot) {
            c->dropped_pairs++;
            continue;
        }
        if (slot->light_shape < 0)
            for (int a = 0; a < 3; a++) slot->lo[a] = slot->hi[a] = vec3_comp(x1.p, a);
        for (int a = 0; a < 3; a++) {
            slot->lo[a] = fminf(slot->lo[a], vec3_comp(x1.p, a));
            slot->hi[a] = fmaxf(slot->hi[a], vec3_comp(x1.p, a));
        }
        slot->light_shape = (int32_t)ls.shape;
        slot->caster = (int32_t)ci;
        uint32_t t = ti * n + tj;
        if (!ssp_bit(slot, t)) {
            slot->bits[t >> 6] |= (uint64_t)1 << (t & 63);
            slot->count++;
        }
    }
    if (pr->walks) ssp_prior_unite(pr, block, job->slot);
}

bool ssp_prior_build(struct ssp_prior *pr, const struct scene *scene, const struct sms_scene *ss,
                     const struct ssp_params *p, const struct camera *cam, uint64_t seed, uint32_t frame, bool still,
                     unsigned threads, struct ssp_prior_counters *c, struct ray_counters *rc, struct err *err)
{
    double t0 = sms_now_ms();
    const uint32_t blocks = pr->blocks_x * pr->blocks_y;
    if (!still) pr->kept = 0;
    if (!p->prior || ss->count == 0) {
        for (uint32_t b = 0; b < blocks; b++) ssp_table_clear(&pr->entries[(size_t)b * SSP_PRIOR_ENTRIES]);
        pr->kept = 0;
        return true;
    }
    struct ssp_prior_job job = {.pr = pr, .scene = scene, .ss = ss, .p = p, .cam = cam, .seed = seed, .frame = frame,
                                .slot = pr->next};
    if (pr->walks) {
        pr->kept = pr->kept < pr->frames ? pr->kept + 1 : pr->frames;
        pr->next = (pr->next + 1) % pr->frames;
    }
    /* Blocks are independent, so the pass runs on the frame's workers. */
    threads = parallel_threads(threads, SSP_PRIOR_WORKERS);
    if (!parallel_run(threads, blocks, ssp_prior_block, &job, NULL, NULL, err)) return false;
    for (unsigned w = 0; w < threads; w++) {
        c->samples += job.c[w].samples;
        c->solutions += job.c[w].solutions;
        c->newton += job.c[w].newton;
        c->dropped_pairs += job.c[w].dropped_pairs;
        rc->intersect += job.rc[w].intersect;
        rc->occluded += job.rc[w].occluded;
    }
    c->ms += sms_now_ms() - t0;
    return true;
}

/* A Bernoulli trial of ssp_sample, drawn in the conditional space C(u*) (eq. 9): a tile of I ∩ C
 * with probability alpha_c, else one of C's nine, a point in it, walked inside its trust region. */
struct ssp_trial {
    const struct scene *scene;
    const struct sms_caster *cs;
    const struct manifold_ends *e;
    const struct ssp_cone *k;
    uint32_t n, max_it;
    double alpha_c;
    const uint32_t *ic, *ctile;
    uint32_t nic;
};

static bool ssp_trial(const void *ctx, struct rng *rng, struct manifold_vertex *w, struct sms_counters *c,
                      struct ray_counters *rc)
{
    const struct ssp_trial *tr = ctx;
    const uint32_t n = tr->n;
    float a = rng_next_float(rng), b1 = rng_next_float(rng), b2 = rng_next_float(rng);
    uint32_t t = a < tr->alpha_c ? tr->ic[(uint32_t)(a / tr->alpha_c * (float)tr->nic) % tr->nic]
                                 : tr->ctile[(uint32_t)((a - tr->alpha_c) / (1.0 - tr->alpha_c) * 9.0) % 9];
    float t1 = ((float)(t / n) + b1) / (float)n, t2 = ((float)(t % n) + b2) / (float)n;
    return ssp_walk(tr->scene, tr->cs, tr->e, tr->k, n, t1, t2, tr->max_it, w, &c->newton_trials, rc);
}

bool ssp_sample(const struct scene *scene, const struct sms_scene *ss, const struct ssp_params *p,
                const struct ssp_prior *pr, uint32_t px, uint32_t py, const struct surface *s, const struct material *m,
                struct vec3 wo, uint32_t max_chain, struct rng *rng, struct sms_solution *out, struct sms_counters *c,
                struct ray_counters *rc)
{
    out->W = 0.0;
    float uc = rng_next_float(rng), ul = rng_next_float(rng), l1 = rng_next_float(rng), l2 = rng_next_float(rng);
    float us = rng_next_float(rng), s1 = rng_next_float(rng), s2 = rng_next_float(rng);
    if (ss->count == 0) return false;
    struct sms_draw d;
    if (!sms_draw_begin(scene, ss, uc, ul, l1, l2, max_chain, s, c, &d)) goto out;
    const uint32_t n = p->tiles, n2 = n * n;
    const struct sms_caster *cs = d.cs;
    struct ssp_cone k;
    ssp_cone_at(cs, s->p, &k);
    /* The prior of this pixel's block for the pair, or none (fallback: alpha = 0). */
    uint32_t block = pr ? (py / SSP_BLOCK) * pr->blocks_x + px / SSP_BLOCK : 0;
    const struct ssp_entry *I = p->prior && pr ? ssp_find(pr, block, d.ls.shape, d.ci) : NULL;
    float alpha = I && I->count && ssp_covers(I, s->p) ? p->alpha : 0.0f;
    if (alpha > 0.0f) c->with_prior++;
    /* Seed from eq. 7: a tile of I with probability alpha, else anywhere. */
    float u1 = s1, u2 = s2;
    if (us < alpha) {
        uint32_t t = ssp_nth(I, (uint32_t)(us / alpha * (float)I->count) % I->count, n2);
        u1 = ((float)(t / n) + s1) / (float)n;
        u2 = ((float)(t % n) + s2) / (float)n;
    }
    struct manifold_vertex *v = out->v;
    if (!ssp_walk(scene, cs, &d.e, &k, n, u1, u2, p->sms.max_iterations, v, &c->newton_sample, rc) ||
        !manifold_check(scene, &cs->chain, &d.e, v, rc))
        goto out;
    uint32_t ti, tj;
    if (!ssp_tile_of(&k, n, v[0].p, &ti, &tj)) goto out;
    struct vec3 value = sms_solution_value(scene, &cs->chain, &d.e, v, s, m, wo, d.ls.material);
    if (vec3_is_zero(value)) goto out;
    /* C(u*): the 3 x 3 tiles around u*'s (periodic). Eq. 8 and eq. 9. */
    uint32_t ctile[9], ic[9], nic = 0;
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) {
            uint32_t t = ((ti + n + (uint32_t)a - 1) % n) * n + (tj + n + (uint32_t)b - 1) % n;
            ctile[a * 3 + b] = t;
            if (alpha > 0.0f && ssp_bit(I, t)) ic[nic++] = t;
        }
    double mass_i = alpha > 0.0f ? (double)alpha * nic / I->count : 0.0;
    double pc = mass_i + (1.0 - alpha) * 9.0 / (double)n2;
    double alpha_c = mass_i / pc;
    const struct ssp_trial trial = {scene, cs, &d.e, &k, n, p->sms.max_iterations, alpha_c, ic, ctile, nic};
    uint32_t trials = sms_bernoulli(&p->sms, v, cs->chain.length, s->p, ssp_trial, &trial, rng, c, rc);
    if (!trials) goto out;
    sms_draw_keep(&d, value, out);
    /* The same float product sms_ssp's estimate has always used (its images stay bit-identical). */
    out->W = (double)((float)((double)trials / pc) * (float)ss->count / d.ls.pdf_a);
out:
    return sms_draw_end(&d, out, c);
}

struct vec3 ssp_estimate(const struct scene *scene, const struct sms_scene *ss, const struct ssp_params *p,
                         const struct ssp_prior *pr, uint32_t px, uint32_t py, const struct surface *s,
                         const struct material *m, struct vec3 wo, uint32_t max_chain, struct rng *rng,
                         struct sms_counters *c, struct ray_counters *rc)
{
    struct sms_solution sol;
    if (!ssp_sample(scene, ss, p, pr, px, py, s, m, wo, max_chain, rng, &sol, c, rc)) return vec3_splat(0.0f);
    return vec3_scale(sol.value, (float)sol.W);
}
