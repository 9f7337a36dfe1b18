/* camera.h — pinhole camera: primary ray directions from image positions.
 * Image x grows to the right (right = forward x up, right-handed), y grows downwards. */
#ifndef RESTIRD_CAMERA_H
#define RESTIRD_CAMERA_H

#include <stdint.h>

#include "scene.h"
#include "vec.h"

struct camera {
    struct vec3 position, forward, right, up;
    float tan_half_fov_y, aspect;
    uint32_t width, height;
};

/* `desc` was validated at load (non-degenerate look direction and up). */
void camera_init(struct camera *cam, const struct camera_desc *desc, uint32_t width, uint32_t height);
/* Unit direction through image position (px, py) in pixels from the top-left corner. */
struct vec3 camera_ray_dir(const struct camera *cam, float px, float py);

#endif
