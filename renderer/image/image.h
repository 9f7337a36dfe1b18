/* image.h — a linear-RGB float image, row-major, top row first. Owned memory. */
#ifndef RESTIRD_IMAGE_H
#define RESTIRD_IMAGE_H

#include <stdint.h>
#include <stdlib.h>

#include "core/err.h"
#include "core/vec.h"

struct image {
    uint32_t width, height;
    struct vec3 *pixels;  /* width * height */
};

/* Allocates a zeroed image; false (ERR_NOMEM / ERR_LIMIT) on failure. */
static inline bool image_init(struct image *img, uint32_t width, uint32_t height, struct err *err)
{
    img->width = img->height = 0;
    img->pixels = NULL;
    if (width == 0 || height == 0 || width > 16384 || height > 16384)
        return err_set(err, ERR_LIMIT, NULL, "image size %ux%u outside 1..16384", width, height);
    img->pixels = calloc((size_t)width * height, sizeof *img->pixels);
    if (!img->pixels) return err_set(err, ERR_NOMEM, NULL, "out of memory for a %ux%u image", width, height);
    img->width = width;
    img->height = height;
    return true;
}

static inline void image_destroy(struct image *img)
{
    free(img->pixels);
    img->pixels = NULL;
    img->width = img->height = 0;
}

/* img *= s, pixel by pixel. */
static inline void image_scale(struct image *img, float s)
{
    size_t n = (size_t)img->width * img->height;
    for (size_t i = 0; i < n; i++) img->pixels[i] = vec3_scale(img->pixels[i], s);
}

#endif
