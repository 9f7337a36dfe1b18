/* scene.c — scene lifetime (commit, reference counting, free) and name lookups.
 * Loading and validation live in scene_load.c; ray queries in accel.c; emitters in
 * light_sampler.c. */
#include "scene.h"

#include <stdlib.h>
#include <string.h>

#include "accel.h"
#include "light_sampler.h"

static void scene_free(struct scene *scene)
{
    if (!scene) return;
    accel_free(scene->accel);
    light_sampler_free(scene->lights);
    for (uint32_t i = 0; i < scene->shape_count; i++) {
        free(scene->shapes[i].positions);
        free(scene->shapes[i].normals);
        free(scene->shapes[i].indices);
    }
    free(scene->shapes);
    free(scene->materials);
    free(scene->material_names);
    free(scene);
}

bool scene_commit(struct scene *scene, struct err *err)
{
    struct vec3 lo = vec3_splat(INFINITY), hi = vec3_splat(-INFINITY);
    for (uint32_t i = 0; i < scene->shape_count; i++) {
        const struct shape *s = &scene->shapes[i];
        if (s->kind == SHAPE_MESH) {
            for (uint32_t v = 0; v < s->vertex_count; v++) {
                struct vec3 p = xform_point(&s->to_world, s->positions[v]);
                lo = vec3_make(fminf(lo.x, p.x), fminf(lo.y, p.y), fminf(lo.z, p.z));
                hi = vec3_make(fmaxf(hi.x, p.x), fmaxf(hi.y, p.y), fmaxf(hi.z, p.z));
            }
        } else {
            /* Bound the transformed sphere by its transformed bounding box corners. */
            for (int c = 0; c < 8; c++) {
                struct vec3 o = vec3_make(c & 1 ? 1.0f : -1.0f, c & 2 ? 1.0f : -1.0f, c & 4 ? 1.0f : -1.0f);
                struct vec3 p = xform_point(&s->to_world, vec3_madd(s->center, o, s->radius));
                lo = vec3_make(fminf(lo.x, p.x), fminf(lo.y, p.y), fminf(lo.z, p.z));
                hi = vec3_make(fmaxf(hi.x, p.x), fmaxf(hi.y, p.y), fmaxf(hi.z, p.z));
            }
        }
    }
    if (scene->shape_count == 0) lo = hi = vec3_splat(0.0f);
    scene->bounds_min = lo;
    scene->bounds_max = hi;
    /* Static renders move nothing; sessions that animate shapes build their own accel with those
     * shapes movable. */
    scene->accel = accel_new(scene, NULL, err);
    if (!scene->accel) return false;
    scene->lights = light_sampler_new(scene, err);
    return scene->lights != NULL;
}

void scene_retain(struct scene *scene)
{
    __atomic_add_fetch(&scene->refcount, 1, __ATOMIC_RELAXED);
}

void scene_release(struct scene *scene)
{
    if (scene && __atomic_sub_fetch(&scene->refcount, 1, __ATOMIC_ACQ_REL) == 0) scene_free(scene);
}

int scene_find_material(const struct scene *scene, const char *name)
{
    for (uint32_t i = 0; i < scene->material_count; i++)
        if (strcmp(scene->material_names[i], name) == 0) return (int)i;
    return -1;
}

int scene_find_shape(const struct scene *scene, const char *name)
{
    if (!name[0]) return -1;
    for (uint32_t i = 0; i < scene->shape_count; i++)
        if (strcmp(scene->shapes[i].name, name) == 0) return (int)i;
    return -1;
}
