/* camera.c — pinhole camera (see camera.h). */
#include "scene/camera.h"

bool camera_desc_valid(const struct camera_desc *desc, const char **why)
{
    struct vec3 fwd = vec3_sub(desc->look_at, desc->position);
    if (!(vec3_length(fwd) > 0.0f)) {
        if (why) *why = "the camera position and look_at coincide";
        return false;
    }
    struct vec3 side = vec3_cross(vec3_normalize(fwd), vec3_normalize(desc->up));
    if (!(vec3_length(side) > 1e-4f)) {
        if (why) *why = "the camera's up is parallel to its viewing direction";
        return false;
    }
    return true;
}

void camera_init(struct camera *cam, const struct camera_desc *desc, uint32_t width, uint32_t height)
{
    cam->position = desc->position;
    cam->forward = vec3_normalize(vec3_sub(desc->look_at, desc->position));
    cam->right = vec3_normalize(vec3_cross(cam->forward, desc->up));
    cam->up = vec3_cross(cam->right, cam->forward);
    cam->tan_half_fov_y = tanf(0.5f * desc->fov_deg * PI_F / 180.0f);
    cam->aspect = (float)width / (float)height;
    cam->width = width;
    cam->height = height;
    cam->width_f = (float)width;
    cam->height_f = (float)height;
}

struct vec3 camera_ray_dir(const struct camera *cam, float px, float py)
{
    float sx = (2.0f * px / cam->width_f - 1.0f) * cam->tan_half_fov_y * cam->aspect;
    float sy = (1.0f - 2.0f * py / cam->height_f) * cam->tan_half_fov_y;
    return vec3_normalize(vec3_add(cam->forward, vec3_add(vec3_scale(cam->right, sx), vec3_scale(cam->up, sy))));
}

bool camera_project_dir(const struct camera *cam, struct vec3 d, float *px, float *py)
{
    float z = vec3_dot(d, cam->forward);
    if (!(z > 0.0f)) return false;
    float sx = vec3_dot(d, cam->right) / (z * cam->tan_half_fov_y * cam->aspect);
    float sy = vec3_dot(d, cam->up) / (z * cam->tan_half_fov_y);
    *px = 0.5f * (sx + 1.0f) * (float)cam->width;
    *py = 0.5f * (1.0f - sy) * (float)cam->height;
    return true;
}

bool camera_project(const struct camera *cam, struct vec3 p, float *px, float *py)
{
    return camera_project_dir(cam, vec3_sub(p, cam->position), px, py);
}
