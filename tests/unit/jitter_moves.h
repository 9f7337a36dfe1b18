/* jitter_moves.h — how far the G-buffer's primary-ray positions moved between two frames, as the
 * unit tests of the methods with a jitter walk (gbuffer.h) check it. */
#ifndef RESTIRD_TEST_JITTER_MOVES_H
#define RESTIRD_TEST_JITTER_MOVES_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#include "reuse/gbuffer.h"

/* The largest move of a position along either axis from (jx, jy), the previous frame's, which
 * are then overwritten with this frame's; 0 when there is no previous frame (`first`). */
static inline float jitter_largest_move(const struct gbuffer_pixel *px, uint32_t n, float *jx, float *jy, bool first)
{
    float worst = 0.0f;
    for (uint32_t i = 0; i < n; i++) {
        if (!first) worst = fmaxf(worst, fmaxf(fabsf(px[i].jx - jx[i]), fabsf(px[i].jy - jy[i])));
        jx[i] = px[i].jx, jy[i] = px[i].jy;
    }
    return worst;
}

#endif
