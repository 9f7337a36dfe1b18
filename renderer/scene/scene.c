/* scene.c — scene lifetime (commit, reference counting, free) and name lookups.
 * Loading and validation live in scene_load.c; ray queries in accel.c; emitters in
 * light_sampler.c. */
#include "scene/scene.h"

#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene/accel.h"
#include "scene/light_sampler.h"

static void scene_free(struct scene *scene)
{
    if (!scene) return;
    accel_free(scene->accel);
    light_sampler_free(scene->lights);
    if (!scene->base) {
        for (uint32_t i = 0; i < scene->shape_count; i++) {
            free(scene->shapes[i].positions);
            free(scene->shapes[i].normals);
            free(scene->shapes[i].indices);
        }
    }
    scene_release(scene->base);
    free(scene->shapes);
    free(scene->materials);
    free(scene->material_names);
    free(scene);
}

bool scene_commit(struct scene *scene, struct err *err)
{
    static _Atomic uint64_t serials = 0;
    scene->serial = atomic_fetch_add(&serials, 1) + 1;
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

struct scene *scene_derive(struct scene *base, const struct scene_shape_override *overrides, uint32_t count,
                           struct err *err)
{
    char where[32];
    for (uint32_t i = 0; i < count; i++) {
        const struct scene_shape_override *o = &overrides[i];
        snprintf(where, sizeof where, "shape %u", o->shape);
        if (o->shape >= base->shape_count) return err_set(err, ERR_INVALID, where, "no such shape"), NULL;
        if (o->has_to_world) {
            struct xform inv;
            bool finite = true;
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 4; c++) finite = finite && isfinite(o->to_world.m[r][c]);
            if (!finite || !xform_invert(&o->to_world, &inv))
                return err_set(err, ERR_INVALID, where, "the transform is singular or not finite"), NULL;
        }
        if (o->has_emission && !(vec3_is_finite(o->emission) && vec3_min_comp(o->emission) >= 0.0f))
            return err_set(err, ERR_INVALID, where, "emission must be finite and >= 0"), NULL;
    }

    struct scene *s = calloc(1, sizeof *s);
    if (!s) return err_set(err, ERR_NOMEM, NULL, "out of memory deriving a scene"), NULL;
    s->refcount = 1;
    s->camera = base->camera;
    s->env_radiance = base->env_radiance;
    s->shape_count = base->shape_count;
    s->material_count = base->material_count;
    /* Room for one private material per overridden shape. */
    uint32_t mat_cap = base->material_count + count;
    s->materials = malloc(((size_t)mat_cap + 1) * sizeof *s->materials);
    s->material_names = malloc(((size_t)mat_cap + 1) * sizeof *s->material_names);
    s->shapes = malloc(((size_t)base->shape_count + 1) * sizeof *s->shapes);
    if (!s->materials || !s->material_names || !s->shapes) {
        free(s->materials), free(s->material_names), free(s->shapes), free(s);
        return err_set(err, ERR_NOMEM, NULL, "out of memory deriving a scene"), NULL;
    }
    memcpy(s->materials, base->materials, base->material_count * sizeof *s->materials);
    memcpy(s->material_names, base->material_names, base->material_count * sizeof *s->material_names);
    memcpy(s->shapes, base->shapes, base->shape_count * sizeof *s->shapes);
    scene_retain(base);
    s->base = base;
    for (uint32_t i = 0; i < count; i++) {
        const struct scene_shape_override *o = &overrides[i];
        struct shape *sh = &s->shapes[o->shape];
        if (o->has_to_world) sh->to_world = o->to_world;
        if (o->has_emission) {
            uint32_t m = s->material_count++;
            s->materials[m] = s->materials[sh->material];
            s->materials[m].emission = o->emission;
            memcpy(s->material_names[m], s->material_names[sh->material], SCENE_NAME_MAX);
            sh->material = m;
        }
    }
    if (!scene_commit(s, err)) {
        scene_release(s);
        return NULL;
    }
    if (!vec3_is_finite(s->bounds_min) || !vec3_is_finite(s->bounds_max)) {
        scene_release(s);
        return err_set(err, ERR_INVALID, NULL, "a transform sends geometry outside the float range"), NULL;
    }
    return s;
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

bool scene_moved(const struct scene *a, const struct scene *b)
{
    if (a == b) return false;
    if (a->shape_count != b->shape_count || !vec3_equal(a->env_radiance, b->env_radiance)) return true;
    for (uint32_t i = 0; i < a->shape_count; i++) {
        const struct shape *sa = &a->shapes[i], *sb = &b->shapes[i];
        if (memcmp(&sa->to_world, &sb->to_world, sizeof sa->to_world) != 0 ||
            !vec3_equal(a->materials[sa->material].emission, b->materials[sb->material].emission))
            return true;
    }
    return false;
}

bool scene_has_translucent(const struct scene *scene)
{
    for (uint32_t i = 0; i < scene->material_count; i++)
        if (scene->materials[i].kind == MATERIAL_TRANSLUCENT) return true;
    return false;
}

bool scene_has_emitting_shape(const struct scene *scene)
{
    for (uint32_t i = 0; i < scene->shape_count; i++)
        if (material_is_emissive(&scene->materials[scene->shapes[i].material])) return true;
    return false;
}

bool scene_has_near_specular(const struct scene *scene, float alpha_min)
{
    for (uint32_t i = 0; i < scene->shape_count; i++)
        if (material_near_specular(&scene->materials[scene->shapes[i].material], alpha_min)) return true;
    return false;
}
