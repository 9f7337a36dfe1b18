/* refstore.h — reference images by (scene, name): rendered by the server (`pt`, or `pt` with
 * specular manifold sampling) or uploaded as EXR. Immutable once stored and shared by reference
 * count, so a metrics computation keeps its reference alive while another request replaces it.
 * In memory until deleted, or until their scene is. Thread-safe. */
#ifndef RESTIRD_REFSTORE_H
#define RESTIRD_REFSTORE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <time.h>

#include "budget.h"
#include "core/err.h"
#include "image/image.h"

struct ref_image {
    int refcount;
    char scene[65], name[65];
    uint32_t spp;                /* 0 = uploaded */
    const char *method;          /* static: "pt" or "sms"; NULL = uploaded */
    time_t created;              /* when it was stored */
    struct budget *budget;       /* its bytes are reserved from it until the last release; or NULL */
    struct image img;
};

/* What a listing tells of a reference, copied out so the listing holds no pixels. */
struct ref_info {
    char name[65];
    uint32_t width, height, spp;
    const char *method;
    uint64_t bytes;
    time_t created;
};

struct refstore;
/* budget: references' pixels are reserved from it (BUDGET_REFERENCES) while stored; NULL = none. */
struct refstore *refstore_new(struct budget *budget);
void refstore_free(struct refstore *rs);
/* Stores (or replaces) a reference (method: a static string, or NULL for an upload); takes the
 * image's pixels (img is left empty, also on failure). *replaced tells whether a reference of
 * that name existed. Errors: ERR_BUSY (the memory budget cannot hold the pixels), ERR_NOMEM. */
bool refstore_put(struct refstore *rs, const char *scene, const char *name, struct image *img, uint32_t spp,
                  const char *method, bool *replaced, struct err *err);
/* Retained reference or NULL; ref_image_release when done. */
struct ref_image *refstore_get(struct refstore *rs, const char *scene, const char *name);
void ref_image_release(struct ref_image *r);
/* Removes one reference; false when the scene has none of that name. A request or job that
 * retained it keeps the pixels until it releases them, and its bytes go back to the budget
 * then, with the pixels (so does a replaced reference's). */
bool refstore_delete(struct refstore *rs, const char *scene, const char *name);
/* The references of a scene, in the order they were first stored, into out[max]; returns how
 * many the scene has (more than max when out was too small). */
size_t refstore_list(struct refstore *rs, const char *scene, struct ref_info *out, size_t max);
/* Forgets every reference of a scene (the scene was deleted). */
void refstore_drop_scene(struct refstore *rs, const char *scene);
/* Bytes of pixels held. */
size_t refstore_bytes(struct refstore *rs);

#endif
