/* session_buffers.h — a session's buffers as the unit tests check them: what view_bytes lists
 * must add up to what view_bytes_planned promised before anything was allocated (the daemon
 * refuses a session on the planned figure), and each method's buffers follow its parameters. */
#ifndef RESTIRD_TEST_SESSION_BUFFERS_H
#define RESTIRD_TEST_SESSION_BUFFERS_H

#include <stdbool.h>
#include <stdio.h>
#include <string.h>

#include "session/view.h"

struct session_buffers {
    struct view_buffer_bytes b[VIEW_MAX_BUFFERS];
    uint32_t n;
    size_t total;
};

/* Fills *s with the view's buffers; whether their sum is the planned bytes for vp (if not, both
 * figures go to stderr). */
static inline bool session_buffers_agree(const struct view *v, const struct view_params *vp, const struct scene *scene,
                                         struct session_buffers *s)
{
    s->n = view_bytes(v, s->b, &s->total);
    unsigned long long planned = view_bytes_planned(vp, scene);
    if (s->total == planned) return true;
    fprintf(stderr, "  allocated %zu bytes, planned %llu\n", s->total, planned);
    return false;
}

/* The bytes of the buffer with that name; 0 when the session has none. */
static inline size_t session_buffer(const struct session_buffers *s, const char *name)
{
    for (uint32_t i = 0; i < s->n; i++)
        if (strcmp(s->b[i].name, name) == 0) return s->b[i].bytes;
    return 0;
}

#endif
