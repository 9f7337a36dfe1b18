/* restir_bdpt.c — ReSTIR BDPT, lightweight and full variants: initial resampling (see restir_bdpt.h).
 * This file holds the frame driver, the parameters and buffers and the lightweight MIS; the passes
 * are in restir_bdpt_light.c, restir_bdpt_camera.c and restir_bdpt_reuse.c (restir_bdpt_internal.h).
 *
 * Conventions as bdpt.c (radiance-side BSDF values on both subpaths, Veach's adjoint
 * shading-normal correction on the light side, pinhole camera sampled with density 1 per pixel).
 *
 * Lightweight MIS. A path x_0 .. x_k (x_0 the camera, x_k on an emitter) is produced here by at
 * most three techniques: s = 0 (the camera subpath hits x_k), s = 1 (NEE from x_{k-1}) and
 * t = 1 (a light subpath reaches x_1 and connects to the eye), with the power or balance
 * heuristic over exactly these three — t = 1 only on a path through a caustic caster (a delta
 * or near-specular lobe: rbdpt_mis_vertex; on the others it adds variance and nothing else), so
 * any other path is weighed over s = 0 and s = 1 alone. The quantities are SmallVCM's dVCM /
 * dVC (bdpt_mis.h) with every term of a vertex-connection technique left out: on either subpath, dVCM before
 * the first scattering names the far end's nearest technique that we keep (t = 1 on the
 * camera side; s = 1 on the light side, whose dVC at the start is s = 0), and after it dVCM
 * names a connection technique (dropped from dVC's accumulation and from every weight), while
 * dVC carries only the kept far-end techniques. The emitter-hit weight's dVCM term is s = 1
 * itself and stays. Keeping dVCM after the first scattering as well (`full`) restores exactly
 * the terms left out, and these functions then compute bdpt_mis.h's weights over all techniques
 * (tests/unit/test_restir_bdpt.c compares the two): the full variant's MIS.
 *
 * Resampling. In primary sample space every candidate X_i has source pdf 1 and target
 * p̂(X_i) = lum(C_i), C_i = w_i f / p the MIS-weighted contribution: its resampling weight is
 * lum(C_i), W = sum / p̂(Y) and the pixel estimate C_Y W. Candidates from distinct techniques
 * (and path lengths) live in disjoint parts of the extended path space, each with one candidate
 * per pixel from the camera side; the t = 1 part gets N_L candidates per pixel — one per light
 * subpath, most of them null for this pixel — each with the MIS weight 1/N_L
 * ([ReSTIR BDPT eq. 26]), which C already carries. So the merge is unbiased whatever lands
 * where. */
#include "integrators/restir_bdpt.h"

#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "integrators/restir_bdpt_internal.h"
#include "core/parallel.h"

_Static_assert(sizeof(struct restir_bdpt_reservoir) == RESTIR_BDPT_RESERVOIR_BYTES, "restir_bdpt_reservoir changed size");
_Static_assert(sizeof(struct restir_bdpt_shifted) == 32, "restir_bdpt_shifted changed size");
_Static_assert(sizeof(struct restir_bdpt_path) == RESTIR_BDPT_PATH_BYTES, "restir_bdpt_path changed size");

/* ---- lightweight MIS ---------------------------------------------------------------------- */

struct restir_bdpt_mis restir_bdpt_mis_camera_start(float light_paths, float camera_pdf_w, bool power)
{
    return (struct restir_bdpt_mis){rbdpt_mis_f(light_paths / camera_pdf_w, power), 0.0f, true, false};
}

struct restir_bdpt_mis restir_bdpt_mis_light_start(float direct_pdf_a, float emission_pdf_w, float cos_light,
                                                   bool power)
{
    return (struct restir_bdpt_mis){rbdpt_mis_f(direct_pdf_a / emission_pdf_w, power),
                                    rbdpt_mis_f(cos_light / emission_pdf_w, power), true, false};
}

void restir_bdpt_mis_hit(struct restir_bdpt_mis *m, float dist2, float cos_hit, bool power)
{
    float c = rbdpt_mis_f(fabsf(cos_hit), power);
    m->dvcm *= rbdpt_mis_f(dist2, power) / c;
    m->dvc /= c;
}

void restir_bdpt_mis_scatter(struct restir_bdpt_mis *m, float cos_out, float pdf_fwd_w, float pdf_rev_w, bool delta,
                             bool power)
{
    float c = fabsf(cos_out);
    if (delta) {
        m->dvcm = 0.0f;
        m->dvc *= rbdpt_mis_f(c * pdf_rev_w / pdf_fwd_w, power);
    } else {
        m->dvc = rbdpt_mis_f(c / pdf_fwd_w, power) * (m->dvc * rbdpt_mis_f(pdf_rev_w, power) + (m->near ? m->dvcm : 0.0f));
        m->dvcm = rbdpt_mis_f(1.0f / pdf_fwd_w, power);
    }
    m->near = m->full;
}

float restir_bdpt_mis_emission(const struct restir_bdpt_mis *cam, float direct_pdf_a, float emission_pdf_w, bool power)
{
    /* After the first scattering dVCM is s = 1's term and dVC t = 1's (see above). */
    const float t1 = rbdpt_mis_keeps_t1(cam) ? rbdpt_mis_f(emission_pdf_w, power) * cam->dvc : 0.0f;
    return 1.0f / (1.0f + rbdpt_mis_f(direct_pdf_a, power) * cam->dvcm + t1);
}

float restir_bdpt_mis_nee(const struct restir_bdpt_mis *cam, float bsdf_fwd_w, float bsdf_rev_w, float direct_pdf_w,
                          float emission_pdf_w, float cos_camera, float cos_light, bool power)
{
    float w_light = rbdpt_mis_f(bsdf_fwd_w / direct_pdf_w, power);
    /* The techniques with more light vertices: t = 1 (and the full variant's connections). */
    float w_camera = !rbdpt_mis_keeps_t1(cam)
                         ? 0.0f
                         : rbdpt_mis_f(emission_pdf_w * fabsf(cos_camera) / (direct_pdf_w * fabsf(cos_light)), power) *
                               ((cam->near ? cam->dvcm : 0.0f) + cam->dvc * rbdpt_mis_f(bsdf_rev_w, power));
    return 1.0f / (w_light + 1.0f + w_camera);
}

float restir_bdpt_mis_camera(const struct restir_bdpt_mis *light, float camera_pdf_a, float light_paths,
                             float light_rev_w, bool power)
{
    if (!rbdpt_mis_keeps_t1(light)) return 0.0f;
    float w_light = rbdpt_mis_f(camera_pdf_a / light_paths, power) *
                    ((light->near ? light->dvcm : 0.0f) + light->dvc * rbdpt_mis_f(light_rev_w, power));
    return 1.0f / (w_light + 1.0f);
}

void restir_bdpt_rc_mis_emission(const struct restir_bdpt_mis *cam, float direct_pdf_a, float emission_pdf_w,
                                 float dist2, float cos_end, bool last, float suffix, bool power, float *a, float *b)
{
    float c = rbdpt_mis_f(fabsf(cos_end), power);
    if (last) {
        /* dVCM at the emitter is Mis(1 / p_fwd(x_k)) Mis(d^2) / Mis(|cos|), dVC = dVC_k / Mis(|cos|). */
        *a = rbdpt_mis_f(direct_pdf_a, power) * rbdpt_mis_f(dist2, power) / c;
        *b = rbdpt_mis_f(emission_pdf_w, power) / c;
    } else {
        *a = 1.0f + rbdpt_mis_f(direct_pdf_a, power) * cam->dvcm;
        *b = rbdpt_mis_f(emission_pdf_w, power) * suffix;
    }
}

void restir_bdpt_rc_mis_nee(float bsdf_fwd_w, float bsdf_rev_w, float direct_pdf_w,
                            float emission_pdf_w, float cos_camera, float cos_light, bool last, float suffix,
                            bool power, float *a, float *b)
{
    /* k >= 2: the NEE vertex has scattered before, so dVCM names no kept technique (near is false). */
    float K = rbdpt_mis_f(emission_pdf_w * fabsf(cos_camera) / (direct_pdf_w * fabsf(cos_light)), power);
    if (last) {
        *a = 1.0f / direct_pdf_w;
        *b = K;
    } else {
        *a = rbdpt_mis_f(bsdf_fwd_w / direct_pdf_w, power) + 1.0f;
        *b = K * rbdpt_mis_f(bsdf_rev_w, power) * suffix;
    }
}

float restir_bdpt_mis_reconnect(enum restir_bdpt_rc_kind kind, float a, float b, const struct restir_bdpt_mis *m,
                                float pdf_fwd, float pdf_rev, bool power)
{
    /* b carries t = 1's terms: m is the new prefix with the kept suffix's caster flag. */
    if (!rbdpt_mis_keeps_t1(m)) b = 0.0f;
    switch (kind) {
    case RBDPT_RC_AFTER: return 1.0f / (a + b * m->dvc);
    case RBDPT_RC_EMIT_LAST: return 1.0f / (1.0f + a * rbdpt_mis_f(1.0f / pdf_fwd, power) + b * m->dvc);
    case RBDPT_RC_NEE_LAST:
        return 1.0f / (rbdpt_mis_f(pdf_fwd * a, power) + 1.0f + b * m->dvc * rbdpt_mis_f(pdf_rev, power));
    }
    return 0.0f;
}

/* ---- parameters and sizes ----------------------------------------------------------------- */

struct restir_bdpt_params restir_bdpt_defaults(void)
{
    return (struct restir_bdpt_params){.variant = RESTIR_BDPT_LIGHTWEIGHT, .max_depth = 64, .rr_depth = 3,
                                       .light_paths = 0, .lt_capacity = 8, .lvc_capacity = 8,
                                       .heuristic = BDPT_HEURISTIC_POWER,
                                       .caustic_temporal = true, .temporal_cap = 20, .moving_cap = 1, .reuse = true,
                                       .reuse_temporal = true, .history_check = true, .emission_samples = 16, .spatial_neighbors = 2, .spatial_rounds = 1, .spatial_radius = 0.0f, .paired_spatial = true,
                                       .expected_shading = true, .camera_reconnect = true, .copy_mis = false,
                                       .reject_unshiftable = false};
}

bool restir_bdpt_params_valid(const struct restir_bdpt_params *p, struct err *err)
{
    if (p->variant != RESTIR_BDPT_LIGHTWEIGHT && p->variant != RESTIR_BDPT_FULL)
        return err_set(err, ERR_INVALID, "/params/variant", "variant must be \"lightweight\" or \"full\"");
    if (p->copy_mis && !p->reuse)
        return err_set(err, ERR_INVALID, "/params/copy_mis",
                       "copy_mis changes the shifts of the non-caustic reuse: it needs \"reuse\": true");
    if (p->copy_mis && p->variant == RESTIR_BDPT_FULL)
        return err_set(err, ERR_INVALID, "/params/copy_mis",
                       "copy_mis is a shortcut of the lightweight variant's reconnection shift; the full variant "
                       "recomputes the MIS weight of every shifted path");
    /* A sample keeps its vertex count (depth + 2) in 8 bits of head.bits. */
    if (p->max_depth < 1 || p->max_depth > RESTIR_BDPT_MAX_DEPTH)
        return err_set(err, ERR_INVALID, "/params/max_depth", "max_depth must be in 1..%u", RESTIR_BDPT_MAX_DEPTH);
    if (p->rr_depth > 1024) return err_set(err, ERR_INVALID, "/params/rr_depth", "rr_depth must be in 0..1024");
    if (p->light_paths > (1u << 26))
        return err_set(err, ERR_INVALID, "/params/light_paths", "light_paths must be in 0..%u (0 = automatic)",
                       1u << 26);
    if (p->lt_capacity < 1 || p->lt_capacity > 64)
        return err_set(err, ERR_INVALID, "/params/lt_capacity", "lt_capacity must be in 1..64");
    if (p->lvc_capacity < 1 || p->lvc_capacity > 64)
        return err_set(err, ERR_INVALID, "/params/lvc_capacity", "lvc_capacity must be in 1..64");
    if (p->heuristic != BDPT_HEURISTIC_POWER && p->heuristic != BDPT_HEURISTIC_BALANCE)
        return err_set(err, ERR_INVALID, "/params/heuristic", "heuristic must be \"power\" or \"balance\"");
    if (p->temporal_cap < 1 || p->temporal_cap > 65535)
        return err_set(err, ERR_INVALID, "/params/temporal_cap", "temporal_cap must be in 1..65535");
    if (p->moving_cap < 1 || p->moving_cap > 65535)
        return err_set(err, ERR_INVALID, "/params/moving_cap", "moving_cap must be in 1..65535");
    if (!gbuffer_emission_samples_valid(p->emission_samples, err)) return false;
    if (p->spatial_neighbors > 32)
        return err_set(err, ERR_INVALID, "/params/spatial_neighbors", "spatial_neighbors must be in 0..32");
    if (!(p->spatial_radius >= 0.0f && p->spatial_radius <= 256.0f))
        return err_set(err, ERR_INVALID, "/params/spatial_radius",
                       "spatial_radius must be in [0, 256] pixels (0 = by resolution)");
    if (p->spatial_rounds < 1 || p->spatial_rounds > 8)
        return err_set(err, ERR_INVALID, "/params/spatial_rounds", "spatial_rounds must be in 1..8");
    return true;
}

const char *restir_bdpt_variant_name(enum restir_bdpt_variant v)
{
    return v == RESTIR_BDPT_FULL ? "full" : "lightweight";
}

struct rbdpt_sizes {
    struct bdpt_blocks lb, lvb;   /* no counters allocated; lvb empty but in the full variant */
    uint64_t lt, pixels, blocks_b, res, lvc, pairs, x2c;
};

/* The full variant's LVC blocks: those of the light pass, lvc_capacity slots per path, no rays. */
static struct bdpt_blocks rbdpt_lvc_blocks_of(const struct restir_bdpt_params *p, uint32_t width, uint32_t height)
{
    return bdpt_blocks_of(p->light_paths, p->lvc_capacity, 0, width, height);
}

/* Whether the session keeps the previous frame's G-buffer: only for the history check. */
static bool rbdpt_checks_history(const struct restir_bdpt_params *p)
{
    return p->reuse && p->reuse_temporal && p->history_check;
}

/* With reuse the G-buffer pass estimates the emission seen directly (gbuffer.h) and the camera
 * subpaths offer no candidate that ends on the primary hit: those paths (the camera sees an
 * emitter) have one strategy only, s = 0 with MIS weight 1, so they leave the reservoirs' integrand
 * whole, and a shift, which keeps a path's length, never makes one. A scene without an emitting
 * shape has no edge pixels and keeps no buffers for them (it renders black: restir_bdpt's light
 * subpaths start on shapes). */
static bool rbdpt_emission_apart(const struct restir_bdpt_params *p, const struct scene *scene)
{
    return p->reuse && p->emission_samples > 1 && scene_has_emitting_shape(scene);
}

/* Whether a frame estimates it apart: the session kept the buffers (rbdpt_emission_apart, decided
 * at init) and reuses. */
static bool rbdpt_frame_emission_apart(const struct restir_bdpt_state *st, const struct restir_bdpt_params *p)
{
    return p->reuse && st->gbuf[0].emission != NULL;
}

/* Whether some shape's material is a caustic caster (rbdpt_caster): only a path through one keeps
 * the lightweight variant's t = 1 technique. */
static bool rbdpt_scene_has_caustic_caster(const struct scene *scene)
{
    return scene_has_near_specular(scene, RBDPT_CASTER_ROUGHNESS);
}

/* What light_paths 0 means for `variant` in `scene`. The lightweight variant weighs t = 1 only on
 * paths through a caustic caster (rbdpt_mis_vertex): in a scene without one its light subpaths
 * would make no sample, and it traces none (N_L = 0 also leaves t = 1's terms out of the camera
 * side's weights). The full variant's light subpaths also feed its vertex connections; it keeps
 * them. */
static uint32_t rbdpt_auto_light_paths(enum restir_bdpt_variant variant, const struct scene *scene, uint32_t width,
                                       uint32_t height)
{
    if (variant == RESTIR_BDPT_LIGHTWEIGHT && !rbdpt_scene_has_caustic_caster(scene)) return 0;
    return width * height;
}

uint32_t restir_bdpt_light_paths(const struct restir_bdpt_params *p, const struct scene *scene, uint32_t width,
                                 uint32_t height)
{
    return p->light_paths ? p->light_paths : rbdpt_auto_light_paths(p->variant, scene, width, height);
}

/* The light subpaths a frame of session st traces (its automatic count decided at init). */
static uint32_t rbdpt_session_light_paths(const struct restir_bdpt_state *st, const struct restir_bdpt_params *p)
{
    return p->light_paths ? p->light_paths : st->auto_light_paths;
}

/* The light pass's blocks for `light_paths` resolved subpaths (none: no blocks). */
static struct bdpt_blocks rbdpt_light_blocks_of(uint32_t light_paths, const struct restir_bdpt_params *p,
                                                uint32_t width, uint32_t height)
{
    return light_paths ? bdpt_blocks_of(light_paths, p->lt_capacity, 3, width, height) : (struct bdpt_blocks){0};
}

static struct rbdpt_sizes rbdpt_sizes_of(const struct restir_bdpt_params *p, const struct scene *scene,
                                         uint32_t light_paths, uint32_t width, uint32_t height)
{
    struct rbdpt_sizes z;
    uint64_t n = (uint64_t)width * height;
    z.lb = rbdpt_light_blocks_of(light_paths, p, width, height);
    const uint64_t blocks = z.lb.blocks;
    z.lt = 2 * blocks * z.lb.region * sizeof(struct restir_bdpt_lt_sample);
    z.pixels = (n + 1) * sizeof(uint32_t);
    z.blocks_b = bdpt_blocks_bytes(&z.lb);
    z.res = (p->reuse ? 3 : 1) * n * sizeof(struct restir_bdpt_path) + 2 * n * sizeof(struct restir_bdpt_reservoir) +
            2 * n * sizeof(struct restir_bdpt_shifted) +
            (n + 1) * sizeof(uint32_t) +
            (p->reuse ? (rbdpt_checks_history(p) ? 2 : 1) * n * sizeof(struct gbuffer_pixel) +
                            (rbdpt_emission_apart(p, scene) ? gbuffer_emission_bytes_planned(width, height) : 0)
                      : 0);
    z.pairs = p->reuse && p->paired_spatial ? restir_pair_scratch_bytes(width, height) : 0;
    z.x2c = p->reuse ? 2 * n * sizeof(struct rbdpt_x2_entry) : 0;   /* this render's and the previous one's */
    /* The full variant's LVC: the vertices (and their subpaths with reuse), per block its
     * counters (lvb, the layout of bdpt's) and its prefix sum (one more). */
    bool full = p->variant == RESTIR_BDPT_FULL;
    z.lvb = full ? rbdpt_lvc_blocks_of(p, width, height) : (struct bdpt_blocks){0};
    z.lvc = full ? blocks * z.lvb.region * (sizeof(struct bdpt_light_vertex) + (p->reuse ? sizeof(uint32_t) : 0)) +
                       bdpt_blocks_bytes(&z.lvb) + (blocks + 1) * sizeof(uint64_t)
                 : 0;
    return z;
}

uint64_t restir_bdpt_bytes_planned(const struct restir_bdpt_params *p, const struct scene *scene, uint32_t width,
                                   uint32_t height)
{
    struct rbdpt_sizes z = rbdpt_sizes_of(p, scene, restir_bdpt_light_paths(p, scene, width, height), width, height);
    return z.lt + z.pixels + z.blocks_b + z.res + z.lvc + z.pairs + z.x2c;
}

size_t restir_bdpt_x2_bytes(const struct restir_bdpt_state *st)
{
    return st->x2c_base ? 2 * (size_t)st->width * st->height * sizeof *st->x2c_base : 0;
}

size_t restir_bdpt_pair_bytes(const struct restir_bdpt_state *st)
{
    return st->pair_scratch ? restir_pair_scratch_bytes(st->width, st->height) : 0;
}

size_t restir_bdpt_lvc_bytes(const struct restir_bdpt_state *st)
{
    if (!st->lvc) return 0;
    return (size_t)st->lb.blocks * st->lvb.region * (sizeof *st->lvc + (st->lvc_path ? sizeof *st->lvc_path : 0)) +
           (size_t)bdpt_blocks_bytes(&st->lvb) + ((size_t)st->lb.blocks + 1) * sizeof *st->lvc_first;
}

size_t restir_bdpt_reservoir_bytes(const struct restir_bdpt_state *st)
{
    size_t n = (size_t)st->width * st->height;
    return (st->res_prev ? 3 : 1) * n * sizeof *st->res + 2 * n * sizeof *st->caustic;
}

size_t restir_bdpt_lt_bytes(const struct restir_bdpt_state *st)
{
    return 2 * (size_t)st->lb.blocks * st->lb.region * sizeof *st->lt;
}

size_t restir_bdpt_shift_bytes(const struct restir_bdpt_state *st)
{
    return 2 * (size_t)st->width * st->height * sizeof *st->shifted;
}

size_t restir_bdpt_bucket_bytes(const struct restir_bdpt_state *st)
{
    size_t n = (size_t)st->width * st->height;
    return (n + 1) * sizeof *st->pixel_first + (n + 1) * sizeof *st->shift_first;
}

size_t restir_bdpt_block_bytes(const struct restir_bdpt_state *st)
{
    return (size_t)bdpt_blocks_bytes(&st->lb);
}

size_t restir_bdpt_bytes(const struct restir_bdpt_state *st)
{
    return restir_bdpt_reservoir_bytes(st) + restir_bdpt_lt_bytes(st) + restir_bdpt_shift_bytes(st) +
           restir_bdpt_bucket_bytes(st) + restir_bdpt_block_bytes(st) + gbuffer_bytes(&st->gbuf[0]) + gbuffer_bytes(&st->gbuf[1]) +
           gbuffer_emission_bytes(&st->gbuf[0]) + gbuffer_emission_bytes(&st->gbuf[1]) +
           restir_bdpt_lvc_bytes(st) + restir_bdpt_pair_bytes(st) + restir_bdpt_x2_bytes(st);
}

bool restir_bdpt_init(struct restir_bdpt_state *st, const struct scene *scene, const struct restir_bdpt_params *p,
                      uint32_t width, uint32_t height, struct err *err)
{
    memset(st, 0, sizeof *st);
    if (!restir_bdpt_params_valid(p, err) || !bdpt_scene_supported(scene, "restir_bdpt", err)) return false;
    /* Decided once, from the scene the session starts with (as the emission buffer): a session
     * whose scene later gains a caustic caster keeps no light subpaths, and its weights over s = 0
     * and s = 1 stay a partition of unity (every emitter is a shape, which s = 0 can hit through
     * any chain of surfaces), with caustics left to s = 0 alone. */
    st->auto_light_paths = rbdpt_auto_light_paths(p->variant, scene, width, height);
    const uint32_t light_paths = rbdpt_session_light_paths(st, p);
    if (light_paths && !bdpt_blocks_alloc(&st->lb, light_paths, p->lt_capacity, 3, width, height, err)) return false;
    struct rbdpt_sizes z = rbdpt_sizes_of(p, scene, light_paths, width, height);
    size_t n = (size_t)width * height;
    st->width = width;
    st->height = height;
    size_t lt_n = (size_t)st->lb.blocks * st->lb.region;
    st->lt = malloc(lt_n * sizeof *st->lt);
    st->lt_sorted = malloc(lt_n * sizeof *st->lt_sorted);
    st->pixel_first = calloc(n + 1, sizeof *st->pixel_first);
    st->res = calloc(n, sizeof *st->res);
    st->caustic = calloc(n, sizeof *st->caustic);
    st->caustic_prev = calloc(n, sizeof *st->caustic_prev);
    st->shifted = calloc(n, sizeof *st->shifted);
    st->shifted_sorted = calloc(n, sizeof *st->shifted_sorted);
    st->shift_first = calloc(n + 1, sizeof *st->shift_first);
    if (p->reuse) {
        st->res_prev = calloc(n, sizeof *st->res_prev);
        st->res_spatial = calloc(n, sizeof *st->res_spatial);
        if (p->paired_spatial) st->pair_scratch = restir_buffer_alloc(1, z.pairs);
        st->x2c_base = calloc(2 * n, sizeof *st->x2c_base);
        if (st->x2c_base) {
            st->x2c = st->x2c_base;
            st->x2c_prev = st->x2c_base + n;
        }
        if (st->res_prev && st->res_spatial &&
            !(gbuffer_init(&st->gbuf[0], width, height, err) &&
              (!rbdpt_checks_history(p) || gbuffer_init(&st->gbuf[1], width, height, err)) &&
              (!rbdpt_emission_apart(p, scene) || gbuffer_keep_emission(&st->gbuf[0], err)))) {
            restir_bdpt_destroy(st);
            return false;
        }
        /* A frame reads only its own G-buffer's emission: one copy serves both. */
        if (st->gbuf[1].px && st->gbuf[0].emission) gbuffer_share_emission(&st->gbuf[1], &st->gbuf[0]);
    }
    if (p->variant == RESTIR_BDPT_FULL) {
        if (!bdpt_blocks_alloc(&st->lvb, p->light_paths, p->lvc_capacity, 0, width, height, err)) {
            restir_bdpt_destroy(st);
            return false;
        }
        st->lvc = malloc((size_t)z.lb.blocks * z.lvb.region * sizeof *st->lvc);
        st->lvc_first = calloc((size_t)z.lb.blocks + 1, sizeof *st->lvc_first);
        if (p->reuse) st->lvc_path = malloc((size_t)z.lb.blocks * z.lvb.region * sizeof *st->lvc_path);
    }
    if ((lt_n && (!st->lt || !st->lt_sorted)) || !st->pixel_first ||
        !st->res || !st->caustic || !st->caustic_prev || !st->shifted || !st->shifted_sorted || !st->shift_first ||
        (p->reuse && (!st->res_prev || !st->res_spatial || !st->x2c || (p->paired_spatial && !st->pair_scratch))) ||
        (p->variant == RESTIR_BDPT_FULL && (!st->lvc || !st->lvc_first ||
                                             (p->reuse && !st->lvc_path)))) {
        restir_bdpt_destroy(st);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for restir_bdpt (%llu bytes)",
                       (unsigned long long)restir_bdpt_bytes_planned(p, scene, width, height));
    }
    return true;
}

void restir_bdpt_destroy(struct restir_bdpt_state *st)
{
    free(st->lt);
    free(st->lt_sorted);
    free(st->pixel_first);
    bdpt_blocks_destroy(&st->lb);
    free(st->res);
    free(st->caustic);
    free(st->caustic_prev);
    free(st->shifted);
    free(st->shifted_sorted);
    free(st->shift_first);
    free(st->res_prev);
    free(st->res_spatial);
    free(st->pair_scratch);
    free(st->x2c_base);
    free(st->lvc);
    free(st->lvc_path);
    bdpt_blocks_destroy(&st->lvb);
    free(st->lvc_first);
    gbuffer_destroy(&st->gbuf[0]);
    gbuffer_destroy(&st->gbuf[1]);
    memset(st, 0, sizeof *st);
}

void restir_bdpt_reset(struct restir_bdpt_state *st)
{
    st->has_history = false;
    st->gbuf_history = false;
}

static double rbdpt_ms_since(const struct timespec *t0)
{
    struct timespec t1;
    clock_gettime(CLOCK_MONOTONIC, &t1);
    return (double)(t1.tv_sec - t0->tv_sec) * 1e3 + (double)(t1.tv_nsec - t0->tv_nsec) * 1e-6;
}

bool restir_bdpt_render(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                        const struct method_frame *f, struct image *out, struct restir_bdpt_stats *stats,
                        struct err *err)
{
    if (!restir_bdpt_params_valid(p, err) || !bdpt_frame_valid(f, "restir_bdpt", out, st->width, st->height, err))
        return false;
    struct rbdpt_sizes z = rbdpt_sizes_of(p, f->scene, rbdpt_session_light_paths(st, p), st->width, st->height);
    if (!bdpt_blocks_same(&st->lb, z.lb) || !bdpt_blocks_same(&st->lvb, z.lvb))
        return err_set(err, ERR_INVALID, NULL, "the parameters changed the buffers' sizes since init");
    unsigned threads = f->threads ? f->threads : parallel_default_threads();
    if (threads > RBDPT_MAX_WORKERS) threads = RBDPT_MAX_WORKERS;

    struct rbdpt_ctx ctx_storage;
    struct rbdpt_ctx *c = &ctx_storage;
    memset(c, 0, sizeof *c);
    c->p = p;
    c->st = st;
    for (int k = 0; k < 2; k++) {
        const struct scene *sc = k ? f->prev_scene : f->scene;
        const struct camera_desc *cd = k ? f->prev_camera : f->camera;
        if (!sc || !cd) continue;
        c->view[k].scene = sc;
        camera_init(&c->view[k].cam, cd, st->width, st->height);
        float plane = (float)st->height / (2.0f * c->view[k].cam.tan_half_fov_y);
        c->view[k].plane_dist2 = plane * plane;
    }
    c->has_prev = f->prev_scene && f->prev_camera && f->prev_scene->accel && f->prev_scene->lights;
    if (!c->has_prev) st->has_history = false;
    /* Eq. 27 takes a caustic reservoir's confidence from the pixel the camera's motion maps it
     * to, but caustics move with their lights and casters, not with the camera
     * ([ReSTIR BDPT §9.1]): in a frame whose scene moved the reservoirs under the caustic hold
     * history that no longer lies where they are, and with the cap of a still scene (20) a moving
     * caustic's error grows over the frames. A lower cap there bounds that history. The test reads
     * only the scenes, never the samples, so the weights stay a valid MIS whatever it decides. */
    const bool moved = c->has_prev && scene_moved(f->prev_scene, f->scene);
    c->caustic_cap = moved ? p->moving_cap : p->temporal_cap;
    c->static_scene = c->has_prev && !moved;
    _Atomic uint64_t reconnections = 0;
    c->reconnections = &reconnections;
    c->n_light = (float)st->lb.light_paths;
    c->seed = f->seed;
    c->frame = f->frame;
    c->power = p->heuristic == BDPT_HEURISTIC_POWER;
    c->full = p->variant == RESTIR_BDPT_FULL;
    c->emission_apart = rbdpt_frame_emission_apart(st, p);
    c->out = out;
    {
        /* Renders are numbered. The x_2 cache's entries stay valid while the scene object, the
         * seed and what a light subpath's replay depends on are the same (scenes are immutable:
         * an edit makes a new one, so pointer identity across consecutive renders means the same
         * scene); a render is still when, besides, the camera and every parameter are the
         * previous render's, so a shift evaluates a sample there exactly as it did then. */
        const uint32_t params[4] = {p->variant, p->max_depth, p->rr_depth, p->heuristic};
        const bool same = st->x2c_tick > 0 && f->prev_scene == f->scene && st->x2c_scene == f->scene &&
                          st->x2c_seed == f->seed && memcmp(st->x2c_params, params, sizeof params) == 0;
        const bool still = same && c->has_prev && memcmp(&st->last_params, p, sizeof *p) == 0 &&
                           memcmp(f->camera, f->prev_camera, sizeof *f->camera) == 0 &&
                           memcmp(&st->last_camera, f->camera, sizeof *f->camera) == 0;
        st->x2c_tick++;
        if (!same) st->x2c_tick_from = st->x2c_tick;
        if (!still || st->still_withheld) st->still_from = st->x2c_tick;
        st->x2c_scene = f->scene;
        st->x2c_seed = f->seed;
        memcpy(st->x2c_params, params, sizeof params);
        memcpy(&st->last_params, p, sizeof *p);
        st->last_camera = *f->camera;
        if (st->x2c && st->x2c_prev) {
            /* The previous render's entries become read-only: the history's samples find theirs
             * there. */
            struct rbdpt_x2_entry *t = st->x2c;
            st->x2c = st->x2c_prev;
            st->x2c_prev = t;
        }
    }
    c->tick = st->x2c_tick;
    c->tick_from = st->x2c_tick_from;
    c->still_from = st->still_from;

    struct restir_bdpt_stats s = {0};
    struct timespec t0;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    if (!parallel_run(threads, st->lb.blocks, rbdpt_light_block, c, NULL, NULL, err)) return false;
    if (c->full) {
        /* The cache's canonical order: blocks in order, each block's vertices in order. */
        st->lvc_first[0] = 0;
        for (uint32_t b = 0; b < st->lb.blocks; b++) {
            st->lvc_first[b + 1] = st->lvc_first[b] + st->lvb.count[b];
            s.lvc_dropped += st->lvb.dropped[b];
        }
        c->lvc = (struct bdpt_lvc_view){st->lvc, st->lvc_first, st->lb.blocks, st->lvb.region, st->lvc_first[st->lb.blocks],
                                        (float)((double)st->lvc_first[st->lb.blocks] / (double)st->lb.light_paths)};
    }
    s.light_ms = rbdpt_ms_since(&t0);

    /* Counting sort of the light-traced samples by pixel: counts, exclusive prefix sum, then a
     * stable scatter in block order — the buckets' contents and order depend only on the seed. */
    clock_gettime(CLOCK_MONOTONIC, &t0);
    uint32_t npix = st->width * st->height;
    memset(st->pixel_first, 0, ((size_t)npix + 1) * sizeof *st->pixel_first);
    for (uint32_t b = 0; b < st->lb.blocks; b++) {
        const struct restir_bdpt_lt_sample *v = &st->lt[(size_t)b * st->lb.region];
        for (uint32_t j = 0; j < st->lb.count[b]; j++) st->pixel_first[v[j].pixel + 1]++;
        s.lt_dropped += st->lb.dropped[b];
        s.rays_intersect += st->lb.rays[3 * b];
        s.rays_occluded += st->lb.rays[3 * b + 1];
        s.light_vertices += st->lb.rays[3 * b + 2];
    }
    for (uint32_t i = 0; i < npix; i++) st->pixel_first[i + 1] += st->pixel_first[i];
    for (uint32_t b = 0; b < st->lb.blocks; b++) {
        const struct restir_bdpt_lt_sample *v = &st->lt[(size_t)b * st->lb.region];
        for (uint32_t j = 0; j < st->lb.count[b]; j++) {
            /* pixel_first[pixel] is advanced as a cursor and restored below. */
            st->lt_sorted[st->pixel_first[v[j].pixel]++] = v[j];
            s.light_traced++;
            s.caustic_samples += v[j].caustic;
        }
    }
    for (uint32_t i = npix; i > 0; i--) st->pixel_first[i] = st->pixel_first[i - 1];
    st->pixel_first[0] = 0;
    s.sort_ms = rbdpt_ms_since(&t0);

    /* Caustic temporal reuse: replay the previous caustic samples, then sort them by the pixel
     * they land in (the same counting sort, in source-pixel order). */
    uint32_t *sf = st->shift_first;
    memset(sf, 0, ((size_t)npix + 1) * sizeof *sf);
    if (p->caustic_temporal && c->has_prev && st->has_history) {
        clock_gettime(CLOCK_MONOTONIC, &t0);
        if (!parallel_run(threads, st->height, rbdpt_history_row, c, NULL, NULL, err)) return false;
        for (uint32_t v = 0; v < npix; v++)
            if (st->shifted[v].valid) sf[st->shifted[v].pixel + 1]++;
        for (uint32_t i = 0; i < npix; i++) sf[i + 1] += sf[i];
        for (uint32_t v = 0; v < npix; v++)
            if (st->shifted[v].valid) st->shifted_sorted[sf[st->shifted[v].pixel]++] = st->shifted[v];
        for (uint32_t i = npix; i > 0; i--) sf[i] = sf[i - 1];
        sf[0] = 0;
        s.sort_ms += rbdpt_ms_since(&t0);
    }

    clock_gettime(CLOCK_MONOTONIC, &t0);
    c->tiles_x = (st->width + RBDPT_TILE - 1) / RBDPT_TILE;
    uint32_t tiles_y = (st->height + RBDPT_TILE - 1) / RBDPT_TILE;
    if (!parallel_run(threads, c->tiles_x * tiles_y, rbdpt_camera_tile, c, NULL, NULL, err)) return false;
    s.camera_ms = rbdpt_ms_since(&t0);

    if (p->reuse) {
        /* Temporal reuse of the non-caustic reservoirs along the G-buffer's motion vectors, then
         * spatial reuse (restir.c: generalized balance heuristic, defensive pairwise MIS), with
         * the random-replay shift above; the final reservoirs become the next frame's history. */
        clock_gettime(CLOCK_MONOTONIC, &t0);
        uint64_t grays = 0;
        struct gbuffer_frame gf = {.scene = f->scene, .camera = f->camera, .prev_scene = c->has_prev ? f->prev_scene : NULL,
                                   .prev_camera = c->has_prev ? f->prev_camera : NULL, .seed = f->seed,
                                   .frame = f->frame, .threads = f->threads, .check_history = p->history_check,
                                   .stratify = true, .emission_samples = p->emission_samples};
        if (st->gbuf[1].px) {
            if (!restir_gbuffer_next(st->gbuf, &st->gcur, &st->gbuf_history, gf, &grays, err)) return false;
            st->gbuf_history = true;
        } else if (!gbuffer_render(&st->gbuf[0], &gf, &grays, err)) {
            return false;
        }
        s.rays_intersect += grays;
        /* Every G-buffer of the session keeps its emission when emission_apart is on. */
        const struct vec3 *seen = st->gbuf[st->gcur].emission;
        if (c->emission_apart)
            for (uint32_t i = 0; i < npix; i++) out->pixels[i] = vec3_add(out->pixels[i], seen[i]);
        struct restir_reuse rr = {.ops = &rbdpt_ops, .ctx = c, .width = st->width, .height = st->height,
                                  .seed = f->seed, .frame = f->frame, .threads = f->threads, .gbuf = &st->gbuf[st->gcur],
                                  .history = p->reuse_temporal && c->has_prev && st->has_history
                                                 ? (const uint8_t *)st->res_prev : NULL,
                                  .temporal_cap = p->temporal_cap, .neighbors = p->spatial_neighbors,
                                  .radius = p->spatial_radius > 0.0f ? p->spatial_radius
                                                                     : restir_radius_auto(st->width, st->height),
                                  .paired = p->paired_spatial,
                                  .pair_scratch = st->pair_scratch};
        struct restir_counters rc = {{0, 0}, 0, 0, 0};
        if (rr.history && !restir_temporal_pass(&rr, (uint8_t *)st->res, &rc, err)) return false;
        /* With expected shading the last spatial round adds its estimate into the image itself. */
        const bool expected = p->expected_shading && p->spatial_neighbors;
        const uint32_t rounds = p->spatial_neighbors ? p->spatial_rounds : 0;
        for (uint32_t round = 0; round < rounds; round++) {
            /* Each round reads st->res (which rbdpt_x2_row caches from) and writes st->res_spatial;
             * the swap after it makes its output the next round's input. From the second round
             * on, the samples that the last round moved find their x_2 in its cache, in the entry
             * of the pixel they came from (rc.x2_pixel), which this round's rbdpt_x2_row would
             * overwrite: that cache becomes read-only (st->x2c_prev, whose previous render's
             * entries the temporal pass and the first round have used) and this round's entries
             * go to the other half. */
            if (st->x2c && round > 0) {
                struct rbdpt_x2_entry *t = st->x2c;
                st->x2c = st->x2c_prev;
                st->x2c_prev = t;
            }
            if (st->x2c && !parallel_run(threads, st->height, rbdpt_x2_row, c, NULL, NULL, err)) return false;
            rr.frame = f->frame * 8u + round;  /* a distinct neighbour stream per round */
            rr.estimate = expected && round + 1 == rounds ? out->pixels : NULL;
            if (!restir_spatial_pass(&rr, (const uint8_t *)st->res, (uint8_t *)st->res_spatial, &rc, err)) return false;
            struct restir_bdpt_path *t = st->res;
            st->res = st->res_spatial;
            st->res_spatial = t;
        }
        struct restir_bdpt_path *final = st->res;
        for (uint32_t i = 0; i < npix && !expected; i++)
            out->pixels[i] = vec3_add(out->pixels[i], vec3_scale(final[i].r.F, final[i].r.head.W));
        /* The final buffer becomes the history; the old history is the next frame's scratch. */
        st->res = st->res_prev;
        st->res_prev = final;
        s.rays_intersect += rc.rays.intersect;
        s.rays_occluded += rc.rays.occluded;
        s.reuse_shifts = rc.shifts;
        s.reuse_shift_failures = rc.shift_failures;
        s.reuse_reconnections = atomic_load(&reconnections);
        s.rejected += rc.rejected;
        s.reuse_ms = rbdpt_ms_since(&t0);
    }

    for (unsigned i = 0; i < threads; i++) {
        s.rays_intersect += c->worker[i].rays_intersect;
        s.rays_occluded += c->worker[i].rays_occluded;
        s.camera_candidates += c->worker[i].candidates;
        s.rejected += c->worker[i].rejected;
        s.caustic_shifts += c->worker[i].shifts;
        s.caustic_replay_failed += c->worker[i].replay_failed;
        s.caustic_not_caustic += c->worker[i].not_caustic;
        s.caustic_inverse_failed += c->worker[i].inverse_failed;
        s.connections += c->worker[i].connections;
        s.lt_unshiftable += c->worker[i].unshiftable;
    }
    /* This frame's caustic reservoirs become the history of the next. */
    struct restir_bdpt_reservoir *tmp = st->caustic_prev;
    st->caustic_prev = st->caustic;
    st->caustic = tmp;
    st->has_history = true;
    s.light_subpaths = st->lb.light_paths;
    s.reservoir_bytes = restir_bdpt_reservoir_bytes(st);
    if (stats) *stats = s;
    return true;
}

/* Tests only: a context for one view (its worker array on the heap rather than the stack). */
static struct rbdpt_ctx *rbdpt_test_ctx(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                        const struct method_frame *f, _Atomic uint64_t *reconnections)
{
    struct rbdpt_ctx *c = calloc(1, sizeof *c);
    if (!c) return NULL;
    c->p = p;
    c->st = st;
    c->view[0].scene = f->scene;
    camera_init(&c->view[0].cam, f->camera, st->width, st->height);
    float plane = (float)st->height / (2.0f * c->view[0].cam.tan_half_fov_y);
    c->view[0].plane_dist2 = plane * plane;
    c->n_light = (float)st->lb.light_paths;
    c->seed = f->seed;
    c->frame = f->frame;
    c->power = p->heuristic == BDPT_HEURISTIC_POWER;
    c->full = p->variant == RESTIR_BDPT_FULL;
    c->emission_apart = rbdpt_frame_emission_apart(st, p);
    c->reconnections = reconnections;
    /* The cache as the last render left it, valid only in that render's scene. */
    c->tick = st->x2c_tick;
    c->tick_from = f->scene == st->x2c_scene ? st->x2c_tick_from : UINT32_MAX;
    c->still_from = UINT32_MAX;   /* no shift is taken as already evaluated */
    return c;
}

int restir_bdpt_shift_round_trip(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                 const struct method_frame *f, const struct method_frame *f_to,
                                 uint32_t pixel, uint32_t to, float target[3], float *jj)
{
    if (!st->res_prev) return -1;
    const struct restir_bdpt_path *x = &st->res_prev[pixel];   /* the frame just rendered */
    if (!(x->r.head.W > 0.0f)) return -1;
    _Atomic uint64_t reconnections = 0;
    struct rbdpt_ctx *c = rbdpt_test_ctx(st, p, f, &reconnections);
    if (!c) return -1;
    const bool lt = (x->r.head.bits & 0xffu) == RESTIR_BDPT_TECH_LT;
    const int kind = lt ? (x->rc.k ? 1 : 0) : rbdpt_is_connection(x) ? (x->rc.k >= 2 ? 4 : 3) : (x->rc.k >= 2 ? 2 : 0);
    struct restir_counters cnt = {{0, 0}, 0, 0, 0};
    if (f_to) {
        c->view[1].scene = f_to->scene;
        camera_init(&c->view[1].cam, f_to->camera, st->width, st->height);
        c->view[1].plane_dist2 = c->view[0].plane_dist2;
        c->static_scene = f_to->scene == f->scene;
    }
    const struct restir_domain dp = {pixel, RESTIR_CURRENT}, dq = {to, f_to ? RESTIR_PREVIOUS : RESTIR_CURRENT};
    struct restir_bdpt_path y, z;
    float j1 = 0.0f, j2 = 0.0f;
    target[0] = vec3_luminance(x->r.F);
    target[1] = target[2] = 0.0f;
    rbdpt_shift(c, x, dp, dq, &y, &target[1], &j1, &cnt);
    if (target[1] > 0.0f) rbdpt_shift(c, &y, dq, dp, &z, &target[2], &j2, &cnt);
    *jj = j1 * j2;
    free(c);
    return kind;
}

int restir_bdpt_shift_retrace_pair(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                   const struct method_frame *f, uint32_t pixel, uint32_t to, float target[2],
                                   float jacobian[2])
{
    if (!st->res_prev) return -1;
    const struct restir_bdpt_path *x = &st->res_prev[pixel];
    if (!(x->r.head.W > 0.0f) || (x->r.head.bits & 0xffu) == RESTIR_BDPT_TECH_LT || x->rc.k < 2) return -1;
    _Atomic uint64_t reconnections = 0;
    struct rbdpt_ctx *c = rbdpt_test_ctx(st, p, f, &reconnections);
    if (!c) return -1;
    struct restir_counters cnt = {{0, 0}, 0, 0, 0};
    const struct restir_domain dp = {pixel, RESTIR_CURRENT}, dq = {to, RESTIR_CURRENT};
    for (int k = 0; k < 2; k++) {
        c->force_retrace = k == 1;
        rbdpt_shift(c, x, dp, dq, NULL, &target[k], &jacobian[k], &cnt);
    }
    free(c);
    return rbdpt_is_connection(x) ? 4 : 2;
}

bool restir_bdpt_caustic_replay(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                const struct method_frame *f, uint32_t origin_frame, uint32_t light_path,
                                uint32_t depth, uint32_t *pixel, struct vec3 *F)
{
    struct rbdpt_ctx *c = rbdpt_test_ctx(st, p, f, NULL);
    if (!c) return false;
    struct ray_counters rc = {0, 0};
    bool ok = rbdpt_replay_caustic(c, &c->view[0], origin_frame, light_path, depth, pixel, F, &rc) == RBDPT_REPLAY_OK;
    free(c);
    return ok;
}
