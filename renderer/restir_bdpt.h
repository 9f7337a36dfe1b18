/* restir_bdpt.h — ReSTIR BDPT, lightweight variant (seed 000 §4–5, "Lightweight BDPT"): the
 * techniques s = 0 (emitter hits), s = 1 (next-event estimation) and t = 1 (light tracing), no
 * vertex connections, resampled in the extended path space (path, technique) with the target
 * p̂ = lum(w_{s,t} f / p), w the MIS weight among these three techniques only.
 *
 * Per frame: N_L light subpaths start on emitters in proportion to power; every connectable
 * light vertex is connected to the camera (t = 1). The samples that land in a pixel are
 * bucketed per pixel by a counting sort over pixel ids (prefix sum, in light-subpath order,
 * independent of the thread count) and merged into that pixel's reservoir next to its own
 * camera-path candidates, each with resampling weight lum(C) where C already carries the
 * light-tracing estimator's 1/N_L (seed 000 eq. 26). A t = 1 sample whose secondary hit x_2 is
 * not rough (its light-side scattering lobe was delta) is caustic and goes to the pixel's
 * separate caustic reservoir (§5.1); the image is the sum of both reservoirs' estimates.
 *
 * State of this module: initial resampling only. The temporal and spatial reuse of seed 000
 * (bidirectional hybrid shift, caustic random replay with eq. 27 confidence) is not
 * implemented here, so the module is not a session method; it is tested directly against
 * `bdpt` (tests/unit/test_restir_bdpt.c). */
#ifndef RESTIRD_RESTIR_BDPT_H
#define RESTIRD_RESTIR_BDPT_H

#include <stddef.h>
#include <stdint.h>

#include "bdpt.h"
#include "camera.h"
#include "err.h"
#include "image.h"
#include "restir.h"
#include "scene.h"

enum restir_bdpt_variant { RESTIR_BDPT_LIGHTWEIGHT, RESTIR_BDPT_FULL };

struct restir_bdpt_params {
    enum restir_bdpt_variant variant;  /* only the lightweight variant is implemented */
    uint32_t max_depth;        /* scattering events of a full path, 1..1024 (64, as bdpt) */
    uint32_t rr_depth;         /* Russian roulette after this many bounces of a subpath (3) */
    uint32_t light_paths;      /* N_L per frame; 0 = the pixel count (default) */
    uint32_t lt_capacity;      /* light-traced samples kept per light subpath on average, 1..64 (8) */
    enum bdpt_heuristic heuristic;  /* power (default) or balance */
};

struct restir_bdpt_params restir_bdpt_defaults(void);
/* Ranges; errors name /params/<key>; the full variant is refused as not implemented. */
bool restir_bdpt_params_valid(const struct restir_bdpt_params *p, struct err *err);

/* A light-traced (t = 1) sample: its pixel, its contribution C (MIS weight and 1/N_L included). */
struct restir_bdpt_lt_sample {
    struct vec3 F;
    uint32_t pixel;
    uint32_t light_path;       /* index of its light subpath in the frame */
    uint16_t depth;            /* light vertices up to x_1 */
    uint16_t caustic;          /* 1 when x_2 is not rough */
};

/* A reservoir: the shared head (W, M, technique in `bits`), the selected sample's contribution
 * C in its own pixel (primary sample space, so p̂ = lum(C)). */
struct restir_bdpt_reservoir {
    struct restir_head head;
    struct vec3 F;
    uint32_t light_path;       /* t = 1: its light subpath; else UINT32_MAX */
};

/* head.bits: technique s in the low byte (0, 1, or 0xff for t = 1), path vertices above. */
#define RESTIR_BDPT_TECH_LT 0xffu

struct restir_bdpt_state {
    uint32_t width, height;
    uint32_t light_paths, blocks, region;
    struct restir_bdpt_lt_sample *lt;        /* blocks * region, per-block regions */
    struct restir_bdpt_lt_sample *lt_sorted; /* blocks * region, by pixel */
    uint32_t *pixel_first;                   /* width * height + 1 (prefix sums) */
    uint32_t *block_count, *block_dropped;
    uint64_t *block_rays;                    /* 2 per block */
    struct restir_bdpt_reservoir *res;       /* width * height, non-caustic */
    struct restir_bdpt_reservoir *caustic;   /* width * height, caustic */
};

struct restir_bdpt_stats {
    double light_ms, sort_ms, camera_ms;
    uint64_t light_subpaths;    /* N_L */
    uint64_t light_traced;      /* t = 1 samples that reached a pixel */
    uint64_t caustic_samples;   /* of which caustic */
    uint64_t lt_dropped;        /* samples that found their block's region full (a bias; see bdpt.h) */
    uint64_t camera_candidates; /* s = 0 and s = 1 candidates with a non-zero contribution */
    uint64_t rejected;          /* candidates refused for a non-finite weight */
    uint64_t reservoir_bytes;
    uint64_t rays_intersect, rays_occluded;
};

struct restir_bdpt_frame {
    const struct scene *scene;
    const struct camera_desc *camera;
    uint64_t seed;
    uint32_t frame;
    unsigned threads;          /* 0 = all cores */
};

uint64_t restir_bdpt_bytes_planned(const struct restir_bdpt_params *p, uint32_t width, uint32_t height);
bool restir_bdpt_init(struct restir_bdpt_state *st, const struct scene *scene, const struct restir_bdpt_params *p,
                      uint32_t width, uint32_t height, struct err *err);
void restir_bdpt_destroy(struct restir_bdpt_state *st);
size_t restir_bdpt_bytes(const struct restir_bdpt_state *st);

bool restir_bdpt_render(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                        const struct restir_bdpt_frame *f, struct image *out, struct restir_bdpt_stats *stats,
                        struct err *err);

/* The lightweight MIS state a subpath carries (SmallVCM's dVCM / dVC restricted to the
 * techniques s = 0, s = 1, t = 1; see restir_bdpt.c). Exposed for the unit test. */
struct restir_bdpt_mis {
    float dvcm, dvc;
    bool near;                 /* no scattering yet: dvcm still names a wanted technique */
};
struct restir_bdpt_mis restir_bdpt_mis_camera_start(float light_paths, float camera_pdf_w, bool power);
struct restir_bdpt_mis restir_bdpt_mis_light_start(float direct_pdf_a, float emission_pdf_w, float cos_light,
                                                   bool power);
void restir_bdpt_mis_hit(struct restir_bdpt_mis *m, float dist2, float cos_hit, bool power);
void restir_bdpt_mis_scatter(struct restir_bdpt_mis *m, float cos_out, float pdf_fwd_w, float pdf_rev_w, bool delta,
                             bool power);
float restir_bdpt_mis_emission(const struct restir_bdpt_mis *cam, float direct_pdf_a, float emission_pdf_w,
                               bool power);
float restir_bdpt_mis_nee(const struct restir_bdpt_mis *cam, float bsdf_fwd_w, float bsdf_rev_w, float direct_pdf_w,
                          float emission_pdf_w, float cos_camera, float cos_light, bool power);
float restir_bdpt_mis_camera(const struct restir_bdpt_mis *light, float camera_pdf_a, float light_paths,
                             float light_rev_w, bool power);

#endif
