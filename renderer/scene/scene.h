/* scene.h — the loaded, render-ready scene: camera, materials, shapes, environment, and (after
 * scene_commit) the acceleration structure and the light sampler.
 * Shapes are either triangle meshes (quad, box, disk and mesh files all become meshes at load)
 * or analytic spheres, each with its own object-to-world transform. A committed scene is
 * immutable and shared by sessions through a reference count.
 * Refs: docs/scene-format.md documents the JSON. */
#ifndef RESTIRD_SCENE_H
#define RESTIRD_SCENE_H

#include <stddef.h>
#include <stdint.h>

#include "core/err.h"
#include "material/material.h"
#include "core/vec.h"

#define SCENE_NAME_MAX 64

enum shape_kind { SHAPE_MESH, SHAPE_SPHERE };

struct shape {
    enum shape_kind kind;
    char name[SCENE_NAME_MAX];  /* "" when unnamed; named shapes can be animated */
    uint32_t material;          /* index into scene->materials */
    struct xform to_world;      /* object -> world */
    bool caustic_caster;        /* flagged for specular manifold sampling */
    uint8_t caustic_interfaces; /* casters: specular vertices on a caustic path through it (1, 2);
                                   0 when not a caster */
    /* SHAPE_MESH, object space. Front face = counter-clockwise winding (right-hand rule). */
    uint32_t vertex_count, triangle_count;
    struct vec3 *positions;     /* vertex_count */
    struct vec3 *normals;       /* vertex_count, or NULL (flat shading) */
    uint32_t *indices;          /* 3 * triangle_count, each < vertex_count */
    /* SHAPE_SPHERE, object space. Front face = outside. */
    struct vec3 center;
    float radius;
};

struct camera_desc {
    struct vec3 position, look_at, up;
    float fov_deg;  /* vertical field of view */
};

struct accel;
struct light_sampler;

struct scene {
    struct camera_desc camera;
    uint32_t material_count;
    struct material *materials;
    char (*material_names)[SCENE_NAME_MAX];
    uint32_t shape_count;
    struct shape *shapes;
    struct vec3 env_radiance;   /* constant environment radiance; zero = none */

    /* Filled by scene_commit. */
    struct accel *accel;
    struct light_sampler *lights;
    struct vec3 bounds_min, bounds_max;
    uint64_t serial;   /* unique in the process: caches keyed by a scene use it, not its address */
    int refcount;
    /* A derived scene (scene_derive) borrows the mesh arrays of the scene it was derived from
     * and holds a reference to it; NULL for a loaded scene, which owns its arrays. */
    struct scene *base;
};

/* Loads and validates a scene file; mesh paths resolve relative to the file's folder.
 * Errors name the JSON pointer (or mesh file and line/element). Returns NULL on error. */
struct scene *scene_load_file(const char *path, struct err *err);
/* Same from a JSON text of `len` bytes (need not be NUL-terminated). */
struct scene *scene_load_json(const char *json, size_t len, const char *base_dir, struct err *err);

/* Builds the acceleration structure and light sampler; the scene is immutable afterwards. */
bool scene_commit(struct scene *scene, struct err *err);
/* Whether a shape's transform or any emission differs between two frames' scenes (false for
 * the same scene). */
bool scene_moved(const struct scene *a, const struct scene *b);
/* Whether any material is `translucent` (subsurface scattering): methods that do not sample the
 * BSSRDF refuse such scenes rather than render its BSDF stand-in everywhere. */
bool scene_has_translucent(const struct scene *scene);
/* Whether a shape emits (an environment light is not a shape). */
bool scene_has_emitting_shape(const struct scene *scene);
/* Whether a shape's material is near-specular (material_near_specular at alpha_min). */
bool scene_has_near_specular(const struct scene *scene, float alpha_min);
/* Reference counting; scene_release frees at zero. A new scene has refcount 1. */
void scene_retain(struct scene *scene);
void scene_release(struct scene *scene);

/* A change to one shape of a scene: a new object-to-world transform and/or a new emitted
 * radiance (given to a private copy of the shape's material, so other shapes sharing the
 * material keep theirs). */
struct scene_shape_override {
    uint32_t shape;
    bool has_to_world, has_emission;
    struct xform to_world;
    struct vec3 emission;
};

/* A committed copy of the committed scene `base` with `count` shapes overridden; mesh data is
 * shared (the copy retains base). Used when a session moves or re-lights shapes: the copy has
 * its own acceleration structure and light sampler, and base is untouched, so other sessions
 * and the previous frame keep theirs. Errors: ERR_INVALID (shape index out of range, a
 * transform that is singular or sends geometry out of the float range, negative or non-finite
 * emission; where = "shape <i>"), ERR_NOMEM, or the accel's errors. */
struct scene *scene_derive(struct scene *base, const struct scene_shape_override *overrides, uint32_t count,
                           struct err *err);

/* Index of the material/shape with this name, or -1. */
int scene_find_material(const struct scene *scene, const char *name);
int scene_find_shape(const struct scene *scene, const char *name);

#endif
