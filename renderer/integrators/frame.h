/* frame.h — what every integrator is given to render one frame of a session: this frame's
 * scene and camera, the previous frame's (for temporal reuse, which evaluates the previous
 * domain with them), the session's seed and the frame's index (which decorrelate frames), and
 * the thread count. One struct for all methods, so the session driver (session/view.c) fills it
 * once whatever the method. */
#ifndef RESTIRD_FRAME_H
#define RESTIRD_FRAME_H

#include <stdint.h>

#include "scene/camera.h"
#include "integrators/sms.h"
#include "scene/scene.h"

struct method_frame {
    const struct scene *scene;             /* this frame */
    const struct camera_desc *camera;
    const struct scene *prev_scene;        /* the previous frame's (NULL = no previous frame) */
    const struct camera_desc *prev_camera;
    uint64_t seed;
    uint32_t frame;                        /* frames rendered before this one since the last reset */
    unsigned threads;                      /* 0 = all cores */
};

/* What one frame cost and produced, counted the same way by every method. The manifold sampling
 * counters are set by the methods that sample specular manifolds (sms, sms_ssp, restir_sms) and
 * stay zero for the others. */
struct render_stats {
    uint64_t rays_intersect, rays_occluded;
    uint64_t samples;
    uint64_t nonfinite;    /* samples dropped because their value was NaN or Inf */
    unsigned threads;      /* worker threads used */
    double render_ms;
    /* CPU time of the frame on every thread it used (parallel_cpu_ms), set by view_render for a
     * session's frame and by reference_pt_render for a still image: on a shared machine a
     * steadier measure of the frame's cost than render_ms. */
    double render_cpu_ms;
    struct sms_counters sms;   /* sms, sms_ssp, restir_sms: [SMS-SSP Table 1] counters */
};

#endif
