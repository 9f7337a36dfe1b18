/* camera.h — pinhole camera: primary ray directions from image positions.
 * Image x grows to the right (right = forward x up, right-handed), y grows downwards. */
#ifndef RESTIRD_CAMERA_H
#define RESTIRD_CAMERA_H

#include <stdint.h>

#include "scene/scene.h"
#include "core/vec.h"

struct camera {
    struct vec3 position, forward, right, up;
    float tan_half_fov_y, aspect;
    uint32_t width, height;
    /* (float)width and (float)height, which camera_ray_dir divides by: converted once here
     * instead of for every camera ray. */
    float width_f, height_f;
};

/* Whether `desc` can form an image: position != look_at, and up not parallel to the viewing
 * direction. On false, *why (when non-NULL) names the problem. */
bool camera_desc_valid(const struct camera_desc *desc, const char **why);

/* `desc` was validated (camera_desc_valid; the scene loader checks the same at load). */
void camera_init(struct camera *cam, const struct camera_desc *desc, uint32_t width, uint32_t height);
/* Unit direction through image position (px, py) in pixels from the top-left corner. */
struct vec3 camera_ray_dir(const struct camera *cam, float px, float py);
/* The inverse of camera_ray_dir: the image position (pixels) at which `p` appears; false when
 * p is not in front of the camera (then *px, *py are untouched). Positions outside the image
 * are returned as they are: the caller decides what off-screen means. */
bool camera_project(const struct camera *cam, struct vec3 p, float *px, float *py);
/* The same for a direction (a point at infinity, e.g. the environment behind a pixel). */
bool camera_project_dir(const struct camera *cam, struct vec3 dir, float *px, float *py);

#endif
