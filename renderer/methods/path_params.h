/* path_params.h — the parameter structs of the methods that trace `spp` independent paths per
 * pixel and frame with the reference path tracer's loop: `pt`, `sms` (manifold sampling at its
 * vertices) and `sms_ssp` (with sample-space partitioning). A session stores one of these in its
 * view_params (VIEW_METHOD_PARAMS). */
#ifndef RESTIRD_PATH_PARAMS_H
#define RESTIRD_PATH_PARAMS_H

#include <stdbool.h>
#include <stdint.h>

#include "core/alias.h"
#include "integrators/frame.h"
#include "integrators/reference_pt.h"
#include "integrators/sms.h"
#include "integrators/sms_ssp.h"

/* The path tracer's own (reference_pt.h documents them). */
struct RESTIRD_STORED_IN_BYTES pt_method_params {
    uint32_t spp, max_depth, rr_depth;
    bool nee;
    enum pt_subset subset;       /* which light transport the image holds (sms.h) */
    enum pt_sampler sampler;     /* where the paths' random numbers come from (reference_pt.h) */
    enum pt_light_sampling light_sampling;  /* how NEE samples emissive triangles (reference_pt.h) */
};

struct RESTIRD_STORED_IN_BYTES sms_method_params {
    struct pt_method_params pt;  /* subset, sampler and light_sampling unused: sms renders all of it, from PCG
                                    streams, by area */
    struct sms_params sms;
};

struct RESTIRD_STORED_IN_BYTES ssp_method_params {
    struct pt_method_params pt;  /* subset, sampler and light_sampling unused */
    struct ssp_params ssp;
};

/* The names of enum pt_subset's values, in order, NULL-terminated: pt's and restir_pt's `subset`. */
extern const char *const pt_subset_names[];

/* Every path method's spp/max_depth/rr_depth/nee defaults (1 spp per frame, 64, 3, NEE), all
 * transport, area light sampling, and pt's Sobol' sampler (the other path methods take none). */
struct pt_method_params pt_method_defaults(void);
/* spp >= 1 (the parameter tables give the other ranges). */
bool pt_method_params_valid(const struct pt_method_params *p, struct err *err);
/* The reference path tracer's parameters for one frame of a path method (subset left at all, the
 * sampler at random, light_sampling at area). */
struct pt_params pt_method_frame_params(const struct pt_method_params *pp, const struct method_frame *f,
                                        const struct image *out);

#endif
