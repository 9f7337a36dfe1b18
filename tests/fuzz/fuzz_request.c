/* fuzz_request.c — libFuzzer targets for the request parsers (protocol/request.c). Built once
 * per parser with -DFUZZ_PARSER=<n> (make: build/fuzz/fuzz_request_<name>), so each binary's
 * corpus holds bodies of one kind. Besides memory errors (ASan/UBSan), a failed parse must
 * carry an error code, and an accepted body must respect the limits it was parsed under. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "protocol.h"

#define FUZZ_SESSION 1
#define FUZZ_FRAME 2
#define FUZZ_RENDER 3
#define FUZZ_REFERENCE 4

#ifndef FUZZ_PARSER
#error "build with -DFUZZ_PARSER=1..4"
#endif

#if FUZZ_PARSER != FUZZ_FRAME
/* Small limits, so bodies a fuzzer can write reach them (the frame parser takes none). */
static const struct protocol_limits LIMITS = {
    .max_side = 512, .max_pixels = 512u * 256u, .max_spp = 64, .max_frames = 8, .max_keys = 4,
};
#endif

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void fuzz_check(bool ok, const struct err *err, bool within_limits)
{
    if (!ok && err->code == ERR_NONE) {
        fprintf(stderr, "parser failed without an error code\n");
        abort();
    }
    if (ok && !within_limits) {
        fprintf(stderr, "parser accepted a body over its limits\n");
        abort();
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const char *body = (const char *)data;
    struct err err = {0};
#if FUZZ_PARSER == FUZZ_SESSION
    struct view_params p;
    bool ok = protocol_parse_session_create(body, size, &LIMITS, &p, &err);
    /* A method that takes spp has 1..max_spp of them. */
    uint32_t spp = 1;
    if (ok) view_params_get_uint(&p, "spp", &spp);
    fuzz_check(ok, &err, !ok || (p.width >= 1 && p.width <= LIMITS.max_side && p.height >= 1 &&
                                 p.height <= LIMITS.max_side &&
                                 (uint64_t)p.width * p.height <= LIMITS.max_pixels && spp >= 1 && spp <= LIMITS.max_spp));
#elif FUZZ_PARSER == FUZZ_FRAME
    static struct protocol_frame_request f; /* large: kept off the stack */
    bool ok = protocol_parse_frame_request(body, size, &f, &err);
    fuzz_check(ok, &err, !ok || f.shape_count <= PROTOCOL_MAX_SHAPE_CHANGES);
#elif FUZZ_PARSER == FUZZ_RENDER
    struct protocol_render_request r;
    bool ok = protocol_parse_render_request(body, size, &LIMITS, &r, &err);
    bool within = !ok || (r.frames >= 1 && r.frames <= LIMITS.max_frames && r.camera_key_count <= LIMITS.max_keys &&
                          r.shape_track_count <= PROTOCOL_MAX_SHAPE_CHANGES);
    for (uint32_t i = 0; ok && i < r.shape_track_count; i++)
        within = within && r.shape_tracks[i].key_count >= 1 && r.shape_tracks[i].key_count <= LIMITS.max_keys;
    fuzz_check(ok, &err, within);
    protocol_render_request_destroy(&r);
#elif FUZZ_PARSER == FUZZ_REFERENCE
    struct protocol_reference_request r = {0};
    bool ok = protocol_parse_reference_request(body, size, &LIMITS, &r, &err);
    fuzz_check(ok, &err, !ok || (r.spp >= 1 && r.spp <= LIMITS.max_spp &&
                                 (r.method == PROTOCOL_REFERENCE_PT || r.method == PROTOCOL_REFERENCE_SMS)));
#else
#error "FUZZ_PARSER must be 1..4"
#endif
    return 0;
}
