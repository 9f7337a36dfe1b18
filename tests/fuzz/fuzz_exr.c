/* fuzz_exr.c — libFuzzer target for the EXR reader and its header gate (renderer/image/exrio.c),
 * the code every uploaded reference goes through (PUT …/references/{name}). The probe runs
 * first (it parses the header without the gate), then the gated decode. An accepted image
 * must be within the gate's limits. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "image/exrio.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct exrio_info info;
    struct err err = {0};
    (void)exrio_probe_mem(data, size, "fuzz.exr", &info, &err);
    struct image img;
    err = (struct err){0};
    if (!exrio_read_mem(data, size, "fuzz.exr", &img, &err)) {
        if (err.code == ERR_NONE) {
            fprintf(stderr, "exrio_read_mem failed without an error code\n");
            abort();
        }
        return 0;
    }
    if (img.width < 1 || img.height < 1 || img.width > EXRIO_MAX_SIDE || img.height > EXRIO_MAX_SIDE ||
        (uint64_t)img.width * img.height > EXRIO_MAX_PIXELS) {
        fprintf(stderr, "exrio_read_mem accepted a %ux%u image past the gate\n", (unsigned)img.width,
                (unsigned)img.height);
        abort();
    }
    image_destroy(&img);
    return 0;
}
