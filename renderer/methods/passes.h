/* passes.h — the statistics lines the ReSTIR methods share: the time of each pass and the shifts
 * of the reuse passes, as the daemon's "passes" object and the CLI's "last_frame" (followed there
 * by the session's bytes and one pixel's reservoir bytes). `type` is the method's counters struct;
 * INITIAL is the line of the initial pass (a method may add a pass of its own to it). */
#ifndef RESTIRD_PASSES_H
#define RESTIRD_PASSES_H

#include <stddef.h>

#include "methods/method.h"

#define METHOD_PASS_INITIAL(type) {"initial_ms", NULL, METHOD_STAT_MS, offsetof(type, initial_ms), 0}

#define METHOD_PASS_STATS(type, INITIAL)                                                                                \
    {"passes", "last_frame", METHOD_STAT_BEGIN, 0, 0},                                                                 \
        {"gbuffer_ms", NULL, METHOD_STAT_MS, offsetof(type, gbuffer_ms), 0}, INITIAL,                                  \
        {"temporal_ms", NULL, METHOD_STAT_MS, offsetof(type, temporal_ms), 0},                                         \
        {"spatial_ms", NULL, METHOD_STAT_MS, offsetof(type, spatial_ms), 0},                                           \
        {"shade_ms", NULL, METHOD_STAT_MS, offsetof(type, shade_ms), 0},                                               \
        {"shifts", NULL, METHOD_STAT_U64, offsetof(type, shifts), 0},                                                  \
        {"shift_failures", NULL, METHOD_STAT_U64, offsetof(type, shift_failures), 0},                                  \
        {"rejected", "", METHOD_STAT_U64, offsetof(type, rejected), 0}, {"passes", NULL, METHOD_STAT_END, 0, 0},      \
        {NULL, "session_bytes", METHOD_STAT_SESSION_BYTES, 0, 0},                                                      \
        {NULL, "reservoir_bytes_per_pixel", METHOD_STAT_RESERVOIR_BYTES_PER_PIXEL, 0, 0}

/* The frame's render_stats from a method's pass counters: one path per pixel, the sum of the
 * passes' times. */
#define METHOD_PASS_RENDER_STATS(out, threads, c, extra_ms)                                                            \
    method_frame_render_stats((out), (threads), (c)->rays_intersect, (c)->rays_occluded, (c)->nonfinite,              \
                              (c)->gbuffer_ms + (extra_ms) + (c)->initial_ms + (c)->temporal_ms + (c)->spatial_ms +   \
                                  (c)->shade_ms)

#endif
