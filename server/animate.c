/* animate.c — animation requests resolved against a scene (see animate.h). */
#include "animate.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene/camera.h"

bool animate_complete_camera(const struct protocol_camera *pc, const struct camera_desc *base, struct camera_desc *out,
                             const char **why)
{
    *out = *base;
    if (pc->has_position) out->position = pc->position;
    if (pc->has_look_at) out->look_at = pc->look_at;
    if (pc->has_up) out->up = vec3_normalize(pc->up);
    if (pc->has_fov_deg) out->fov_deg = pc->fov_deg;
    return camera_desc_valid(out, why);
}

void animate_destroy(struct view_animation *a)
{
    free(a->camera_keys);
    for (uint32_t i = 0; i < a->track_count; i++) free(a->tracks[i].keys);
    free(a->tracks);
    memset(a, 0, sizeof *a);
}

bool animate_resolve(struct protocol_render_request *rq, const struct scene *scene, const struct camera_desc *start,
                     struct view_animation *out, struct err *err)
{
    memset(out, 0, sizeof *out);
    out->interp = rq->interp;
    out->camera_keys = calloc(rq->camera_key_count ? rq->camera_key_count : 1, sizeof *out->camera_keys);
    out->tracks = calloc(rq->shape_track_count ? rq->shape_track_count : 1, sizeof *out->tracks);
    if (!out->camera_keys || !out->tracks) {
        animate_destroy(out);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for an animation");
    }
    struct camera_desc prev = *start;
    for (uint32_t i = 0; i < rq->camera_key_count; i++) {
        const char *why = NULL;
        out->camera_keys[i].t_s = rq->camera_keys[i].t_s;
        if (!animate_complete_camera(&rq->camera_keys[i].camera, &prev, &out->camera_keys[i].camera, &why)) {
            char ptr[64];
            snprintf(ptr, sizeof ptr, "/animation/camera_keys/%u", i);
            animate_destroy(out);
            return err_set(err, ERR_INVALID, ptr, "%s", why);
        }
        prev = out->camera_keys[i].camera;
        out->camera_key_count = i + 1;
    }
    for (uint32_t i = 0; i < rq->shape_track_count; i++) {
        int idx = scene_find_shape(scene, rq->shape_tracks[i].name);
        if (idx < 0) {
            char ptr[160];
            json_pointer_key(ptr, sizeof ptr, "/animation/light_keys", rq->shape_tracks[i].name);
            animate_destroy(out);
            return err_set(err, ERR_INVALID, ptr, "the scene has no shape named '%s'", rq->shape_tracks[i].name);
        }
        out->tracks[i].shape = (uint32_t)idx;
        out->tracks[i].key_count = rq->shape_tracks[i].key_count;
        out->tracks[i].keys = rq->shape_tracks[i].keys;  /* moved */
        rq->shape_tracks[i].keys = NULL;
        out->track_count = i + 1;
    }
    return true;
}
