/* animate.h — turns an animation request (protocol_render_request) into a view_animation for
 * one scene: camera keys completed in order (a member a key leaves out is the previous key's;
 * the first key's come from the starting camera) and checked, shape tracks found by name.
 * Shared by animation jobs (api_sessions.c) and the CLI's --animation (cli.c). */
#ifndef RESTIRD_ANIMATE_H
#define RESTIRD_ANIMATE_H

#include "protocol.h"
#include "session/view.h"

/* Fills *out (arrays malloc'd; the request's shape keys are moved out of it). Errors carry the
 * JSON pointer of the offending key: ERR_INVALID ("/animation/camera_keys/i" for a camera that
 * cannot form an image, "/animation/light_keys/<name>" for a shape the scene does not name),
 * ERR_NOMEM. On failure *out is empty. */
bool animate_resolve(struct protocol_render_request *rq, const struct scene *scene, const struct camera_desc *start,
                     struct view_animation *out, struct err *err);
void animate_destroy(struct view_animation *a);

/* Completes a partial camera over `base`; false (with *why) when the result cannot form an image. */
bool animate_complete_camera(const struct protocol_camera *pc, const struct camera_desc *base, struct camera_desc *out,
                             const char **why);

#endif
