/* passes.h — the statistics lines the ReSTIR methods share: their struct restir_pass_stats (the
 * time of each pass and the shifts of the reuse passes), as the daemon's "passes" object and the
 * CLI's "last_frame" (followed there by the session's bytes and one pixel's reservoir bytes).
 * `type` is the method's counters struct and MEMBER the path of its restir_pass_stats in it, with
 * a trailing '.' (empty when the counters are the restir_pass_stats itself); INITIAL is the line
 * of the initial pass (a method may add a pass of its own to it). */
#ifndef RESTIRD_PASSES_H
#define RESTIRD_PASSES_H

#include <stddef.h>

#include "methods/method.h"
#include "reuse/restir.h"
#include "integrators/restir_pt.h"

#define METHOD_PASS_INITIAL(type, MEMBER) {"initial_ms", NULL, METHOD_STAT_MS, offsetof(type, MEMBER initial_ms), 0}

#define METHOD_PASS_STATS(type, MEMBER, INITIAL)                                                                       \
    {"passes", "last_frame", METHOD_STAT_BEGIN, 0, 0},                                                                 \
        {"gbuffer_ms", NULL, METHOD_STAT_MS, offsetof(type, MEMBER gbuffer_ms), 0}, INITIAL,                           \
        {"temporal_ms", NULL, METHOD_STAT_MS, offsetof(type, MEMBER temporal_ms), 0},                                  \
        {"spatial_ms", NULL, METHOD_STAT_MS, offsetof(type, MEMBER spatial_ms), 0},                                    \
        {"shade_ms", NULL, METHOD_STAT_MS, offsetof(type, MEMBER shade_ms), 0},                                        \
        {"shifts", NULL, METHOD_STAT_U64, offsetof(type, MEMBER shifts), 0},                                           \
        {"shift_failures", NULL, METHOD_STAT_U64, offsetof(type, MEMBER shift_failures), 0},                           \
        {"rejected", "", METHOD_STAT_U64, offsetof(type, MEMBER rejected), 0},                                         \
        {"passes", NULL, METHOD_STAT_END, 0, 0}, {NULL, "session_bytes", METHOD_STAT_SESSION_BYTES, 0, 0},             \
        {NULL, "reservoir_bytes_per_pixel", METHOD_STAT_RESERVOIR_BYTES_PER_PIXEL, 0, 0}

/* The frame's render_stats from a method's pass counters: one path per pixel, the sum of the
 * passes' times (extra_ms: a pass of the method's own, counted after the G-buffer). */
static inline struct render_stats method_pass_render_stats(const struct image *out, unsigned threads,
                                                           const struct restir_pass_stats *c, double extra_ms)
{
    return method_frame_render_stats(out, threads, c->rays_intersect, c->rays_occluded, c->nonfinite,
                                     c->gbuffer_ms + extra_ms + c->initial_ms + c->temporal_ms + c->spatial_ms +
                                         c->shade_ms);
}

/* The buffers of a restir_pt session kept as another method's rest (restir_sms, restir_sss), and
 * its frame, under names of their own. */
static inline void method_rest_buffers(struct view_buffer_bytes *out, uint32_t room, uint32_t *n,
                                       const struct restir_pt_state *rest, const struct image *frame)
{
    const struct restir_session *r = &rest->rs;
    method_buffer(out, room, n, "rest_reservoirs", restir_session_reservoir_bytes(r));
    method_buffer(out, room, n, "rest_gbuffers", restir_session_gbuffer_bytes(r) + restir_session_hit_bytes(r) +
                                                     (r->gbuf[0].emission ? restir_session_emission_bytes(r) : 0));
    method_buffer(out, room, n, "rest_primitive_table", ((size_t)rest->shape_count + 1) * sizeof *rest->prim_first);
    if (r->pair_scratch) method_buffer(out, room, n, "rest_spatial_pairs", restir_session_pair_bytes(r));
    method_buffer(out, room, n, "rest_frame", (size_t)frame->width * frame->height * sizeof *frame->pixels);
}

/* A ReSTIR method's reset: its session forgets the history. */
#define METHOD_SESSION_RESET_OP(name, state_type) \
    static void name(void *state) { restir_session_reset(&((state_type *)state)->rs); }

#endif
