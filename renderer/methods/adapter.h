/* adapter.h — what the method descriptors (method_*.c) share: their tables' wiring, the
 * operations that only hand an integrator's function its own types, the operations of a method
 * without state, and the end of a frame rendered in one go. A method's file keeps what is its own:
 * its tables and the operations that do more than convert. */
#ifndef RESTIRD_ADAPTER_H
#define RESTIRD_ADAPTER_H

#include "methods/method.h"

/* A descriptor's parameter and statistics tables (arrays), with their lengths. */
#define METHOD_PARAM_TABLE(table) .params = (table), .param_count = sizeof(table) / sizeof(table)[0]
#define METHOD_STAT_TABLE(table) .stats = (table), .stat_count = sizeof(table) / sizeof(table)[0]

/* The method's counters in a frame's statistics. */
#define METHOD_COUNTERS(type, frame_stats) ((type *)(void *)(frame_stats)->counters)

/* Operations that call the integrator's function with the method's own parameter or state type:
 * `defaults` from fn(void), `validate` from fn(const params *, err), `init` from fn(state *,
 * scene, const params *, width, height, err), and a state operation (destroy, reset) from
 * fn(state *). */
#define METHOD_DEFAULTS_OP(name, params_type, fn) \
    static void name(void *params) { *(params_type *)params = fn(); }
#define METHOD_VALIDATE_OP(name, params_type, fn) \
    static bool name(const void *params, struct err *err) { return fn((const params_type *)params, err); }
#define METHOD_INIT_OP(name, state_type, params_type, fn)                                                  \
    static bool name(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height, \
                     struct err *err)                                                                     \
    {                                                                                                     \
        return fn((state_type *)state, scene, (const params_type *)params, width, height, err);           \
    }
#define METHOD_STATE_OP(name, state_type, fn) \
    static void name(void *state) { fn((state_type *)state); }

/* The init and destroy of a method that keeps no state between frames. */
bool method_stateless_init(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height,
                           struct err *err);
void method_stateless_destroy(void *state);

/* The end of a frame rendered in one go: its render statistics, and all of its progress. */
static inline bool method_frame_done(struct frame_stats *stats, struct render_stats render,
                                     parallel_progress_fn *progress, void *progress_ctx)
{
    stats->render = render;
    if (progress) progress(progress_ctx, 1, 1);
    return true;
}

#endif
