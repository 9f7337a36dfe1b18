/* scene_load.c — scene format v1: JSON text -> struct scene, validated strictly at the edge.
 * Owns the schema (docs/scene-format.md is its prose twin: keep them in step), JSON pointers
 * in errors, mesh path confinement to the scene folder, and the tessellation of quads, boxes
 * and disks into object-space triangles. cJSON is included here and in protocol/ only.
 * Must not: commit the scene (scene_commit), build acceleration or light structures, invent a
 * value the file did not give (every default is documented), or exit on bad input.
 * Refs: RFC 6901 (JSON pointer); docs/scene-format.md. */
#include "scene/scene.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <float.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "material/bssrdf.h"
#include "input/fileio.h"
#include "input/json_read.h"
#include "input/mesh_io.h"

#define SCENE_LOAD_MAX_JSON_BYTES (4u << 20)
#define SCENE_LOAD_MAX_SHAPES 100000u
#define SCENE_LOAD_MAX_MATERIALS 4096u
#define SCENE_LOAD_MAX_TRIANGLES (32u << 20)  /* all meshes of a scene together */
#define SCENE_LOAD_DISK_SEGMENTS 64u
#define SCENE_LOAD_PTR 256  /* same size as err.where: deeper pointers are truncated, never overrun */

struct scene_load_names;

struct scene_load {
    struct scene *scene;
    const char *base_dir;  /* NULL: mesh shapes are refused */
    char *real_base;       /* realpath of base_dir, resolved on first mesh */
    struct err *err;
    struct scene_load_names *material_index;  /* material name -> index, for shapes */
    /* Mesh files decoded in this load: resolved path -> index of the first shape that loaded
     * it, so a file named by many shapes is decoded once (the others copy its arrays). */
    struct scene_load_names *mesh_index;
    char **mesh_paths;                        /* owned keys of mesh_index */
    size_t mesh_path_count;
    uint64_t triangles;                       /* all shapes so far, against the scene budget */
};

/* ---- JSON pointers (RFC 6901; keys: input/json_read.h) ---- */

static void scene_load_ptr_index(char out[SCENE_LOAD_PTR], const char *parent, size_t i)
{
    snprintf(out, SCENE_LOAD_PTR, "%.200s/%zu", parent, i);
}

/* ---- typed, strict accessors (the shared ones: input/json_read.h) ---- */

static const cJSON *scene_load_require(const cJSON *obj, const char *ptr, const char *key, struct err *err)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!v) {
        char p[SCENE_LOAD_PTR];
        json_pointer_key(p, SCENE_LOAD_PTR, ptr, key);
        err_set(err, ERR_INVALID, p, "missing required key");
    }
    return v;
}

/* A finite number that is also finite as a 32-bit float (cJSON turns 1e999 into inf). */
static bool scene_load_float(const cJSON *v, const char *ptr, float *out, struct err *err)
{
    if (!cJSON_IsNumber(v)) return err_set(err, ERR_INVALID, ptr, "expected a number, got %s", json_type_name(v));
    double d = v->valuedouble;
    if (!isfinite(d)) return err_set(err, ERR_INVALID, ptr, "expected a finite number (the value overflows to infinity)");
    if (fabs(d) > (double)FLT_MAX)
        return err_set(err, ERR_INVALID, ptr, "%g is not finite as a 32-bit float (|x| <= 3.4e38)", d);
    *out = (float)d;
    return true;
}

enum scene_load_range { RANGE_ANY, RANGE_NONNEG, RANGE_POS, RANGE_UNIT };

static bool scene_load_check_range(float x, const char *ptr, enum scene_load_range r, struct err *err)
{
    switch (r) {
    case RANGE_ANY: return true;
    case RANGE_NONNEG:
        if (!(x >= 0.0f)) return err_set(err, ERR_INVALID, ptr, "must be >= 0, got %g", (double)x);
        return true;
    case RANGE_POS:
        if (!(x > 0.0f)) return err_set(err, ERR_INVALID, ptr, "must be > 0, got %g", (double)x);
        return true;
    case RANGE_UNIT:
        if (!(x >= 0.0f && x <= 1.0f)) return err_set(err, ERR_INVALID, ptr, "must be in [0, 1], got %g", (double)x);
        return true;
    }
    return true;
}

static bool scene_load_number_in(const cJSON *v, const char *ptr, enum scene_load_range r, float *out, struct err *err)
{
    return scene_load_float(v, ptr, out, err) && scene_load_check_range(*out, ptr, r, err);
}

static bool scene_load_vec3_in(const cJSON *v, const char *ptr, enum scene_load_range r, struct vec3 *out,
                               struct err *err)
{
    if (!cJSON_IsArray(v))
        return err_set(err, ERR_INVALID, ptr, "expected an array of 3 numbers, got %s", json_type_name(v));
    int n = cJSON_GetArraySize(v);
    if (n != 3) return err_set(err, ERR_INVALID, ptr, "expected an array of 3 numbers, got %d elements", n);
    float f[3];
    char p[SCENE_LOAD_PTR];
    int i = 0;
    for (const cJSON *c = v->child; c; c = c->next, i++) {
        scene_load_ptr_index(p, ptr, (size_t)i);
        if (!scene_load_number_in(c, p, r, &f[i], err)) return false;
    }
    *out = vec3_make(f[0], f[1], f[2]);
    return true;
}

/* Reads key `key` of `obj` as a vec3 in range r; `required` false leaves *out alone if absent. */
static bool scene_load_key_vec3(const cJSON *obj, const char *ptr, const char *key, bool required,
                                enum scene_load_range r, struct vec3 *out, struct err *err)
{
    const cJSON *v = required ? scene_load_require(obj, ptr, key, err) : cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!v) return !required;
    char p[SCENE_LOAD_PTR];
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, key);
    return scene_load_vec3_in(v, p, r, out, err);
}

static bool scene_load_key_number(const cJSON *obj, const char *ptr, const char *key, bool required,
                                  enum scene_load_range r, float *out, struct err *err)
{
    const cJSON *v = required ? scene_load_require(obj, ptr, key, err) : cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!v) return !required;
    char p[SCENE_LOAD_PTR];
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, key);
    return scene_load_number_in(v, p, r, out, err);
}

static bool scene_load_key_bool(const cJSON *obj, const char *ptr, const char *key, bool *out, struct err *err)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!v) return true;
    char p[SCENE_LOAD_PTR];
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, key);
    return json_bool(v, p, out, err);
}


/* Names of materials and shapes: [A-Za-z0-9_-]{1,63}, safe in URLs and JSON pointers. */
static bool scene_load_valid_name(const char *s)
{
    size_t n = 0;
    for (; s[n]; n++) {
        char c = s[n];
        bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
        if (!ok || n >= SCENE_NAME_MAX - 1) return false;
    }
    return n > 0;
}

/* ---- a small open-addressing name set, so duplicate detection stays linear ---- */

struct scene_load_names {
    const char **keys;
    uint32_t *values;
    size_t mask;
};

static bool scene_load_names_init(struct scene_load_names *s, size_t n)
{
    size_t cap = 16;
    while (cap < 2 * n) cap *= 2;
    s->keys = calloc(cap, sizeof *s->keys);
    s->values = calloc(cap, sizeof *s->values);
    s->mask = cap - 1;
    return s->keys && s->values;
}

static void scene_load_names_destroy(struct scene_load_names *s)
{
    free(s->keys);
    free(s->values);
}

/* Inserts key -> value; returns the earlier value when the key is already present, else -1. */
static int64_t scene_load_names_insert(struct scene_load_names *s, const char *key, uint32_t value)
{
    uint64_t h = 1469598103934665603ull;  /* FNV-1a */
    for (const char *c = key; *c; c++) h = (h ^ (unsigned char)*c) * 1099511628211ull;
    for (size_t i = (size_t)h & s->mask;; i = (i + 1) & s->mask) {
        if (!s->keys[i]) {
            s->keys[i] = key;
            s->values[i] = value;
            return -1;
        }
        if (strcmp(s->keys[i], key) == 0) return s->values[i];
    }
}

/* Value stored for key, or -1. */
static int64_t scene_load_names_find(const struct scene_load_names *s, const char *key)
{
    uint64_t h = 1469598103934665603ull;  /* FNV-1a, as in scene_load_names_insert */
    for (const char *c = key; *c; c++) h = (h ^ (unsigned char)*c) * 1099511628211ull;
    for (size_t i = (size_t)h & s->mask; s->keys[i]; i = (i + 1) & s->mask)
        if (strcmp(s->keys[i], key) == 0) return s->values[i];
    return -1;
}

/* ---- top-level parts ---- */

static bool scene_load_camera(const cJSON *root, struct camera_desc *cam, struct err *err)
{
    static const char *const keys[] = {"position", "look_at", "up", "fov_deg", NULL};
    const cJSON *c = scene_load_require(root, "", "camera", err);
    if (!c || !json_object(c, "/camera", "a camera", err) ||
        !json_check_keys(c, "/camera", keys, " in the camera", err) ||
        !scene_load_key_vec3(c, "/camera", "position", true, RANGE_ANY, &cam->position, err) ||
        !scene_load_key_vec3(c, "/camera", "look_at", true, RANGE_ANY, &cam->look_at, err) ||
        !scene_load_key_vec3(c, "/camera", "up", true, RANGE_ANY, &cam->up, err) ||
        !scene_load_key_number(c, "/camera", "fov_deg", true, RANGE_ANY, &cam->fov_deg, err))
        return false;
    if (!(cam->fov_deg > 0.0f && cam->fov_deg < 180.0f))
        return err_set(err, ERR_INVALID, "/camera/fov_deg", "must be in (0, 180) degrees, got %g", (double)cam->fov_deg);
    struct vec3 dir = vec3_sub(cam->look_at, cam->position);
    if (!vec3_is_finite(dir) || vec3_is_zero(dir))
        return err_set(err, ERR_INVALID, "/camera/look_at", "look_at must differ from position (and the difference be finite)");
    double cx = (double)dir.y * cam->up.z - (double)dir.z * cam->up.y;
    double cy = (double)dir.z * cam->up.x - (double)dir.x * cam->up.z;
    double cz = (double)dir.x * cam->up.y - (double)dir.y * cam->up.x;
    double lens = sqrt(((double)dir.x * dir.x + (double)dir.y * dir.y + (double)dir.z * dir.z) *
                       ((double)cam->up.x * cam->up.x + (double)cam->up.y * cam->up.y + (double)cam->up.z * cam->up.z));
    if (!(sqrt(cx * cx + cy * cy + cz * cz) > 1e-6 * lens))
        return err_set(err, ERR_INVALID, "/camera/up", "up must be non-zero and not parallel to the view direction");
    return true;
}

static bool scene_load_environment(const cJSON *root, struct vec3 *radiance, struct err *err)
{
    static const char *const keys[] = {"radiance", NULL};
    const cJSON *e = cJSON_GetObjectItemCaseSensitive(root, "environment");
    *radiance = vec3_splat(0.0f);
    if (!e) return true;
    return json_object(e, "/environment", "an environment", err) &&
           json_check_keys(e, "/environment", keys, " in the environment", err) &&
           scene_load_key_vec3(e, "/environment", "radiance", true, RANGE_NONNEG, radiance, err);
}

static bool scene_load_material(const cJSON *m, const char *ptr, struct material *out, struct err *err)
{
    static const char *const diffuse_keys[] = {"type", "albedo", "emission", "two_sided", NULL};
    static const char *const conductor_keys[] = {"type", "eta", "k", "roughness", "emission", "two_sided", NULL};
    static const char *const dielectric_keys[] = {"type", "ior", "roughness", "emission", "two_sided", NULL};
    static const char *const translucent_keys[] = {"type", "albedo", "mfp", "ior", "emission", "two_sided", NULL};
    char p[SCENE_LOAD_PTR];

    memset(out, 0, sizeof *out);
    if (!json_object(m, ptr, "a material", err)) return false;
    const cJSON *tv = scene_load_require(m, ptr, "type", err);
    if (!tv) return false;
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, "type");
    const char *type = json_string(tv, p, err);
    if (!type) return false;
    if (strcmp(type, "diffuse") == 0) {
        out->kind = MATERIAL_DIFFUSE;
        if (!json_check_keys(m, ptr, diffuse_keys, " for a diffuse material", err) ||
            !scene_load_key_vec3(m, ptr, "albedo", true, RANGE_UNIT, &out->albedo, err))
            return false;
    } else if (strcmp(type, "conductor") == 0) {
        out->kind = MATERIAL_CONDUCTOR;
        if (!json_check_keys(m, ptr, conductor_keys, " for a conductor material", err) ||
            !scene_load_key_vec3(m, ptr, "eta", true, RANGE_POS, &out->eta, err) ||
            !scene_load_key_vec3(m, ptr, "k", true, RANGE_NONNEG, &out->k, err) ||
            !scene_load_key_number(m, ptr, "roughness", true, RANGE_NONNEG, &out->roughness, err))
            return false;
    } else if (strcmp(type, "dielectric") == 0) {
        out->kind = MATERIAL_DIELECTRIC;
        if (!json_check_keys(m, ptr, dielectric_keys, " for a dielectric material", err) ||
            !scene_load_key_number(m, ptr, "ior", true, RANGE_POS, &out->ior, err) ||
            !scene_load_key_number(m, ptr, "roughness", false, RANGE_NONNEG, &out->roughness, err))
            return false;
        if (out->ior == 1.0f) {
            json_pointer_key(p, SCENE_LOAD_PTR, ptr, "ior");
            return err_set(err, ERR_INVALID, p, "ior must not be 1 (an index-matched interface is invisible)");
        }
    } else if (strcmp(type, "translucent") == 0) {
        out->kind = MATERIAL_TRANSLUCENT;
        out->ior = 1.4f;
        if (!json_check_keys(m, ptr, translucent_keys, " for a translucent material", err) ||
            !scene_load_key_vec3(m, ptr, "albedo", true, RANGE_UNIT, &out->albedo, err) ||
            !scene_load_key_vec3(m, ptr, "mfp", true, RANGE_POS, &out->mfp, err) ||
            !scene_load_key_number(m, ptr, "ior", false, RANGE_POS, &out->ior, err))
            return false;
        if (out->ior == 1.0f) {
            json_pointer_key(p, SCENE_LOAD_PTR, ptr, "ior");
            return err_set(err, ERR_INVALID, p, "ior must not be 1 (the boundary's Fresnel terms need an interface)");
        }
        bssrdf_prepare(out);
    } else {
        return err_set(err, ERR_INVALID, p,
                       "unknown material type '%.64s' (expected diffuse, conductor, dielectric or translucent)", type);
    }
    return scene_load_key_vec3(m, ptr, "emission", false, RANGE_NONNEG, &out->emission, err) &&
           scene_load_key_bool(m, ptr, "two_sided", &out->two_sided_emission, err);
}

/* Fills scene->materials and `names` (keys borrowed from the cJSON tree; the caller destroys
 * `names` after the shapes have resolved their materials through it). */
static bool scene_load_materials(const cJSON *root, struct scene *scene, struct scene_load_names *names,
                                 struct err *err)
{
    const cJSON *ms = scene_load_require(root, "", "materials", err);
    if (!ms || !json_object(ms, "/materials", "an", err)) return false;
    int n = cJSON_GetArraySize(ms);
    if ((unsigned)n > SCENE_LOAD_MAX_MATERIALS)
        return err_set(err, ERR_LIMIT, "/materials", "%d materials, more than the limit of %u", n, SCENE_LOAD_MAX_MATERIALS);
    scene->materials = calloc((size_t)n + 1, sizeof *scene->materials);
    scene->material_names = calloc((size_t)n + 1, sizeof *scene->material_names);
    if (!scene->materials || !scene->material_names || !scene_load_names_init(names, (size_t)n))
        return err_set(err, ERR_NOMEM, "/materials", "out of memory");
    scene->material_count = (uint32_t)n;
    bool ok = true;
    char p[SCENE_LOAD_PTR];
    uint32_t i = 0;
    for (const cJSON *m = ms->child; m && ok; m = m->next, i++) {
        json_pointer_key(p, SCENE_LOAD_PTR, "/materials", m->string);
        if (!scene_load_valid_name(m->string))
            ok = err_set(err, ERR_INVALID, p, "invalid material name: names must match [A-Za-z0-9_-]{1,63}");
        else if (scene_load_names_insert(names, m->string, i) >= 0)
            ok = err_set(err, ERR_INVALID, p, "duplicate key (material '%s' is defined twice)", m->string);
        else {
            snprintf(scene->material_names[i], SCENE_NAME_MAX, "%s", m->string);
            ok = scene_load_material(m, p, &scene->materials[i], err);
        }
    }
    return ok;
}

/* translate * rotate(Z after Y after X) * scale. Scale factors must be > 0: a mirroring
 * transform would flip which side is the front face differently for baked and instanced
 * geometry, so it is refused rather than half-supported. */
static bool scene_load_transform(const cJSON *t, const char *ptr, struct xform *out, bool *uniform, struct err *err)
{
    static const char *const keys[] = {"translate", "rotate_deg", "scale", NULL};
    struct vec3 tr = vec3_splat(0.0f), rot = vec3_splat(0.0f);
    float s[3] = {1.0f, 1.0f, 1.0f};
    char p[SCENE_LOAD_PTR], q[SCENE_LOAD_PTR];

    *out = xform_identity();
    *uniform = true;
    if (!json_object(t, ptr, "a transform", err) ||
        !json_check_keys(t, ptr, keys, " in a transform", err) ||
        !scene_load_key_vec3(t, ptr, "translate", false, RANGE_ANY, &tr, err) ||
        !scene_load_key_vec3(t, ptr, "rotate_deg", false, RANGE_ANY, &rot, err))
        return false;
    const cJSON *sv = cJSON_GetObjectItemCaseSensitive(t, "scale");
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, "scale");
    if (sv && cJSON_IsNumber(sv)) {
        if (!scene_load_float(sv, p, &s[0], err)) return false;
        s[1] = s[2] = s[0];
    } else if (sv && cJSON_IsArray(sv)) {
        struct vec3 v;
        if (!scene_load_vec3_in(sv, p, RANGE_ANY, &v, err)) return false;
        s[0] = v.x, s[1] = v.y, s[2] = v.z;
        *uniform = s[0] == s[1] && s[1] == s[2];
    } else if (sv) {
        return err_set(err, ERR_INVALID, p, "expected a number or an array of 3 numbers, got %s", json_type_name(sv));
    }
    for (int i = 0; i < 3; i++) {
        const char *where = p;
        if (cJSON_IsArray(sv)) { scene_load_ptr_index(q, p, (size_t)i); where = q; }
        if (s[i] == 0.0f) return err_set(err, ERR_INVALID, where, "scale must be non-zero");
        if (s[i] < 0.0f) return err_set(err, ERR_INVALID, where, "negative scale (mirroring) is not supported, got %g", (double)s[i]);
    }

    const struct trs parts = {tr, rot, vec3_make(s[0], s[1], s[2])};
    if (!xform_from_trs(&parts, out))
        return err_set(err, ERR_INVALID, ptr, "the transform overflows the 32-bit float range");
    return true;
}

/* ---- geometry ---- */

static bool scene_load_alloc_mesh(struct shape *s, uint32_t vertices, uint32_t triangles, const char *ptr,
                                  struct err *err)
{
    s->kind = SHAPE_MESH;
    s->vertex_count = vertices;
    s->triangle_count = triangles;
    s->positions = calloc(vertices, sizeof *s->positions);
    s->indices = calloc(3 * (size_t)triangles, sizeof *s->indices);
    if (!s->positions || !s->indices) return err_set(err, ERR_NOMEM, ptr, "out of memory");
    return true;
}

/* Twice the area of (a, b, c) compared with the product of its edge lengths, in double: a
 * sine of the corner angle below 1e-7 is a line at float precision. */
static bool scene_load_triangle_degenerate(struct vec3 a, struct vec3 b, struct vec3 c)
{
    double e1[3] = {(double)b.x - a.x, (double)b.y - a.y, (double)b.z - a.z};
    double e2[3] = {(double)c.x - a.x, (double)c.y - a.y, (double)c.z - a.z};
    double x = e1[1] * e2[2] - e1[2] * e2[1], y = e1[2] * e2[0] - e1[0] * e2[2], z = e1[0] * e2[1] - e1[1] * e2[0];
    double cross = sqrt(x * x + y * y + z * z);
    double l1 = sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]);
    double l2 = sqrt(e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2]);
    return !(cross > 1e-7 * l1 * l2);
}

static bool scene_load_quad(const cJSON *sh, const char *ptr, struct shape *s, struct err *err)
{
    char p[SCENE_LOAD_PTR], q[SCENE_LOAD_PTR];
    const cJSON *v = scene_load_require(sh, ptr, "vertices", err);
    if (!v) return false;
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, "vertices");
    if (!cJSON_IsArray(v))
        return err_set(err, ERR_INVALID, p, "expected an array of 4 points, got %s", json_type_name(v));
    int n = cJSON_GetArraySize(v);
    if (n != 4) return err_set(err, ERR_INVALID, p, "expected an array of 4 points, got %d elements", n);
    struct vec3 pts[4];
    int i = 0;
    for (const cJSON *c = v->child; c; c = c->next, i++) {
        scene_load_ptr_index(q, p, (size_t)i);
        if (!scene_load_vec3_in(c, q, RANGE_ANY, &pts[i], err)) return false;
    }
    if (scene_load_triangle_degenerate(pts[0], pts[1], pts[2]) || scene_load_triangle_degenerate(pts[0], pts[2], pts[3]))
        return err_set(err, ERR_INVALID, p, "degenerate quad: triangles (v0, v1, v2) and (v0, v2, v3) must both have non-zero area");
    if (!scene_load_alloc_mesh(s, 4, 2, ptr, err)) return false;
    memcpy(s->positions, pts, sizeof pts);
    static const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    memcpy(s->indices, idx, sizeof idx);
    return true;
}

static bool scene_load_box(const cJSON *sh, const char *ptr, struct shape *s, struct err *err)
{
    struct vec3 lo, hi;
    if (!scene_load_key_vec3(sh, ptr, "min", true, RANGE_ANY, &lo, err) ||
        !scene_load_key_vec3(sh, ptr, "max", true, RANGE_ANY, &hi, err))
        return false;
    for (int a = 0; a < 3; a++) {
        if (!(vec3_comp(hi, a) > vec3_comp(lo, a))) {
            char p[SCENE_LOAD_PTR];
            json_pointer_key(p, SCENE_LOAD_PTR, ptr, "max");
            return err_set(err, ERR_INVALID, p, "max must be greater than min in every component (%c: %g <= %g)",
                           "xyz"[a], (double)vec3_comp(hi, a), (double)vec3_comp(lo, a));
        }
    }
    if (!scene_load_alloc_mesh(s, 8, 12, ptr, err)) return false;
    /* Corner i has x = max if bit 0, y = max if bit 1, z = max if bit 2. Each face is listed
     * counter-clockwise seen from outside, so the right-hand normal points out. */
    for (uint32_t i = 0; i < 8; i++)
        s->positions[i] = vec3_make(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
    static const uint32_t faces[6][4] = {
        {0, 4, 6, 2},  /* -x */
        {1, 3, 7, 5},  /* +x */
        {0, 1, 5, 4},  /* -y */
        {2, 6, 7, 3},  /* +y */
        {0, 2, 3, 1},  /* -z */
        {4, 5, 7, 6},  /* +z */
    };
    for (int f = 0; f < 6; f++) {
        uint32_t *t = &s->indices[6 * f];
        t[0] = faces[f][0], t[1] = faces[f][1], t[2] = faces[f][2];
        t[3] = faces[f][0], t[4] = faces[f][2], t[5] = faces[f][3];
    }
    return true;
}

static bool scene_load_disk(const cJSON *sh, const char *ptr, struct shape *s, struct err *err)
{
    struct vec3 c, n;
    float r;
    if (!scene_load_key_vec3(sh, ptr, "center", true, RANGE_ANY, &c, err) ||
        !scene_load_key_vec3(sh, ptr, "normal", true, RANGE_ANY, &n, err))
        return false;
    double nl = sqrt((double)n.x * n.x + (double)n.y * n.y + (double)n.z * n.z);
    if (!(nl > 0.0) || !isfinite(nl)) {
        char p[SCENE_LOAD_PTR];
        json_pointer_key(p, SCENE_LOAD_PTR, ptr, "normal");
        return err_set(err, ERR_INVALID, p, "normal must be non-zero");
    }
    if (!scene_load_key_number(sh, ptr, "radius", true, RANGE_POS, &r, err)) return false;
    n = vec3_make((float)(n.x / nl), (float)(n.y / nl), (float)(n.z / nl));
    const uint32_t segs = SCENE_LOAD_DISK_SEGMENTS;
    if (!scene_load_alloc_mesh(s, segs + 1, segs, ptr, err)) return false;
    /* (s, t, n) is right-handed, so rim points ordered by increasing angle wind
     * counter-clockwise seen from +n: the front face is along the normal. */
    struct frame fr = frame_from_normal(n);
    s->positions[0] = c;
    for (uint32_t k = 0; k < segs; k++) {
        double phi = 2.0 * 3.14159265358979323846 * k / segs;
        struct vec3 d = vec3_add(vec3_scale(fr.s, (float)cos(phi)), vec3_scale(fr.t, (float)sin(phi)));
        s->positions[1 + k] = vec3_madd(c, d, r);
        s->indices[3 * k + 0] = 0;
        s->indices[3 * k + 1] = 1 + k;
        s->indices[3 * k + 2] = 1 + (k + 1) % segs;
    }
    return true;
}

static bool scene_load_sphere(const cJSON *sh, const char *ptr, struct shape *s, struct err *err)
{
    s->kind = SHAPE_SPHERE;
    return scene_load_key_vec3(sh, ptr, "center", true, RANGE_ANY, &s->center, err) &&
           scene_load_key_number(sh, ptr, "radius", true, RANGE_POS, &s->radius, err);
}

/* Mesh paths are relative, '/'-separated, without "..", and must resolve (symbolic links
 * included) inside the scene folder: a scene cannot make the server read other files. */
/* A mesh shape whose file an earlier shape already loaded: a copy of its arrays. */
static bool scene_load_copy_mesh(const struct shape *from, struct shape *s, const char *p, struct err *err)
{
    size_t nv = from->vertex_count, nt = from->triangle_count;
    s->kind = SHAPE_MESH;
    s->positions = malloc(nv * sizeof *s->positions);
    s->normals = from->normals ? malloc(nv * sizeof *s->normals) : NULL;
    s->indices = malloc(3 * nt * sizeof *s->indices);
    if (!s->positions || !s->indices || (from->normals && !s->normals))
        return err_set(err, ERR_NOMEM, p, "out of memory copying a mesh");
    memcpy(s->positions, from->positions, nv * sizeof *s->positions);
    if (from->normals) memcpy(s->normals, from->normals, nv * sizeof *s->normals);
    memcpy(s->indices, from->indices, 3 * nt * sizeof *s->indices);
    s->vertex_count = from->vertex_count;
    s->triangle_count = from->triangle_count;
    return true;
}

static bool scene_load_mesh(struct scene_load *L, const cJSON *sh, const char *ptr, struct shape *s)
{
    struct err *err = L->err;
    char p[SCENE_LOAD_PTR];
    const cJSON *fv = scene_load_require(sh, ptr, "file", err);
    if (!fv) return false;
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, "file");
    const char *file = json_string(fv, p, err);
    if (!file) return false;
    size_t len = strlen(file);
    if (len == 0) return err_set(err, ERR_INVALID, p, "empty mesh path");
    if (len > 1024) return err_set(err, ERR_INVALID, p, "mesh path longer than 1024 bytes");
    if (file[0] == '/') return err_set(err, ERR_INVALID, p, "absolute mesh path '%s' is not allowed (paths are relative to the scene folder)", file);
    if (strchr(file, '\\')) return err_set(err, ERR_INVALID, p, "backslash in mesh path '%s' (use '/')", file);
    for (const char *c = file; *c;) {
        const char *e = strchr(c, '/');
        size_t n = e ? (size_t)(e - c) : strlen(c);
        if (n == 2 && c[0] == '.' && c[1] == '.')
            return err_set(err, ERR_INVALID, p, "'..' in mesh path '%s' is not allowed (it could leave the scene folder)", file);
        c += n + (e ? 1 : 0);
    }
    const char *ext = mesh_io_format_of(file);
    if (!ext) return err_set(err, ERR_INVALID, p, "mesh file '%s' must end in .ply or .obj", file);
    if (!L->base_dir)
        return err_set(err, ERR_NOT_FOUND, p, "mesh file '%s': this scene has no folder to resolve it in", file);
    if (!L->real_base) {
        L->real_base = realpath(L->base_dir[0] ? L->base_dir : ".", NULL);
        if (!L->real_base)
            return err_set(err, ERR_NOT_FOUND, p, "scene folder '%s' is not accessible: %s", L->base_dir, strerror(errno));
    }
    size_t blen = strlen(L->base_dir);
    char *joined = malloc(blen + len + 2);
    if (!joined) return err_set(err, ERR_NOMEM, p, "out of memory");
    snprintf(joined, blen + len + 2, "%s/%s", L->base_dir[0] ? L->base_dir : ".", file);
    char *real = realpath(joined, NULL);
    int e = errno;
    free(joined);
    if (!real) {
        if (e == ENOENT || e == ENOTDIR) return err_set(err, ERR_NOT_FOUND, p, "mesh file '%s' not found", file);
        return err_set(err, ERR_IO, p, "mesh file '%s': %s", file, strerror(e));
    }
    size_t rb = strlen(L->real_base);
    bool inside = strcmp(L->real_base, "/") == 0 ||
                  (strncmp(real, L->real_base, rb) == 0 && real[rb] == '/');
    if (!inside) {
        free(real);
        return err_set(err, ERR_INVALID, p, "mesh file '%s' resolves outside the scene folder", file);
    }
    int64_t first = scene_load_names_find(L->mesh_index, real);
    if (first >= 0) {
        free(real);
        return scene_load_copy_mesh(&L->scene->shapes[first], s, p, err);
    }
    struct mesh m;
    bool ok = mesh_io_load_file(real, file, ext, &m, err);
    if (ok) {
        /* Remember the file; the key is owned by mesh_paths (freed with the loader). */
        L->mesh_paths[L->mesh_path_count++] = real;
        scene_load_names_insert(L->mesh_index, real, (uint32_t)(s - L->scene->shapes));
    } else {
        free(real);
    }
    if (!ok) {
        /* Not found / unreadable is about the scene's reference: point at it. Parse errors keep
         * the file (and line) mesh_io reported. */
        if (err && (err->code == ERR_NOT_FOUND || err->code == ERR_IO)) {
            snprintf(err->where, sizeof err->where, "%s", p);
        } else if (err) {
            size_t n = strlen(err->message);
            snprintf(err->message + n, sizeof err->message - n, " (mesh of %s)", ptr);
        }
        return false;
    }
    s->kind = SHAPE_MESH;
    s->vertex_count = m.vertex_count;
    s->triangle_count = m.triangle_count;
    s->positions = m.positions;
    s->normals = m.normals;
    s->indices = m.indices;
    return true;
}

/* The world-space geometry must stay finite, or bounds and intersection turn to NaN. */
static bool scene_load_check_world(const struct shape *s, const char *ptr, bool has_transform, struct err *err)
{
    char p[SCENE_LOAD_PTR];
    if (has_transform) json_pointer_key(p, SCENE_LOAD_PTR, ptr, "transform");
    else snprintf(p, sizeof p, "%s", ptr);
    if (s->kind == SHAPE_MESH) {
        for (uint32_t v = 0; v < s->vertex_count; v++)
            if (!vec3_is_finite(xform_point(&s->to_world, s->positions[v])))
                return err_set(err, ERR_INVALID, p, "vertex %u leaves the 32-bit float range in world space", v);
    } else {
        for (int c = 0; c < 8; c++) {
            struct vec3 o = vec3_make(c & 1 ? 1.0f : -1.0f, c & 2 ? 1.0f : -1.0f, c & 4 ? 1.0f : -1.0f);
            if (!vec3_is_finite(xform_point(&s->to_world, vec3_madd(s->center, o, s->radius))))
                return err_set(err, ERR_INVALID, p, "the sphere leaves the 32-bit float range in world space");
        }
        /* Its area (4 pi r^2, in world space) must be a float too: light sampling divides by it. */
        struct vec3 a = xform_point(&s->to_world, vec3_madd(s->center, vec3_make(1, 1, 1), s->radius));
        struct vec3 b = xform_point(&s->to_world, vec3_madd(s->center, vec3_make(-1, -1, -1), s->radius));
        double dx = (double)a.x - b.x, dy = (double)a.y - b.y, dz = (double)a.z - b.z;
        double r2 = (dx * dx + dy * dy + dz * dz) / 12.0;  /* the half diagonal / sqrt(3), squared */
        if (!(4.0 * 3.14159265358979323846 * r2 < (double)FLT_MAX)) {
            if (!has_transform) json_pointer_key(p, SCENE_LOAD_PTR, ptr, "radius");
            return err_set(err, ERR_INVALID, p,
                           "the sphere's surface area leaves the 32-bit float range in world space");
        }
    }
    return true;
}

/* How many specular interfaces a caster's light crosses on its way to a receiver (the chain
 * length of specular manifold sampling): a conductor reflects once; a dielectric is crossed
 * twice by default (a closed object: in and out) or once (an open surface such as water). */
static bool scene_load_caustic_interfaces(const cJSON *sh, const char *ptr, struct shape *s, const struct material *m,
                                          struct err *err)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(sh, "caustic_interfaces");
    s->caustic_interfaces = s->caustic_caster ? (m->kind == MATERIAL_DIELECTRIC ? 2 : 1) : 0;
    if (!v) return true;
    char p[SCENE_LOAD_PTR];
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, "caustic_interfaces");
    if (!cJSON_IsNumber(v)) return err_set(err, ERR_INVALID, p, "expected 1 or 2, got %s", json_type_name(v));
    if (!s->caustic_caster) return err_set(err, ERR_INVALID, p, "caustic_interfaces needs \"caustic_caster\": true");
    if (v->valuedouble != 1.0 && v->valuedouble != 2.0)
        return err_set(err, ERR_INVALID, p, "caustic_interfaces must be 1 or 2, got %g", v->valuedouble);
    if (m->kind != MATERIAL_DIELECTRIC && v->valuedouble != 1.0)
        return err_set(err, ERR_INVALID, p, "only a dielectric caster can have 2 interfaces (a reflection is one)");
    s->caustic_interfaces = (uint8_t)v->valuedouble;
    return true;
}

static bool scene_load_shape(struct scene_load *L, const cJSON *sh, const char *ptr, struct shape *s,
                             struct scene_load_names *names, uint32_t index)
{
#define SCENE_LOAD_COMMON "type", "material", "name", "transform", "caustic_caster", "caustic_interfaces"
    static const char *const mesh_keys[] = {SCENE_LOAD_COMMON, "file", NULL};
    static const char *const quad_keys[] = {SCENE_LOAD_COMMON, "vertices", NULL};
    static const char *const sphere_keys[] = {SCENE_LOAD_COMMON, "center", "radius", NULL};
    static const char *const box_keys[] = {SCENE_LOAD_COMMON, "min", "max", NULL};
    static const char *const disk_keys[] = {SCENE_LOAD_COMMON, "center", "normal", "radius", NULL};
#undef SCENE_LOAD_COMMON
    static const struct {
        const char *type;
        const char *const *keys;
        const char *context;
    } types[] = {
        {"mesh", mesh_keys, " for a mesh shape"},
        {"quad", quad_keys, " for a quad shape"},
        {"sphere", sphere_keys, " for a sphere shape"},
        {"box", box_keys, " for a box shape"},
        {"disk", disk_keys, " for a disk shape"},
    };
    struct err *err = L->err;
    char p[SCENE_LOAD_PTR];

    s->to_world = xform_identity();
    if (!json_object(sh, ptr, "a shape", err)) return false;
    const cJSON *tv = scene_load_require(sh, ptr, "type", err);
    if (!tv) return false;
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, "type");
    const char *type = json_string(tv, p, err);
    if (!type) return false;
    int t = -1;
    for (int i = 0; i < (int)(sizeof types / sizeof types[0]); i++)
        if (strcmp(type, types[i].type) == 0) t = i;
    if (t < 0)
        return err_set(err, ERR_INVALID, p, "unknown shape type '%.64s' (expected mesh, quad, sphere, box or disk)", type);
    if (!json_check_keys(sh, ptr, types[t].keys, types[t].context, err)) return false;

    const cJSON *nv = cJSON_GetObjectItemCaseSensitive(sh, "name");
    if (nv) {
        json_pointer_key(p, SCENE_LOAD_PTR, ptr, "name");
        const char *name = json_string(nv, p, err);
        if (!name) return false;
        if (!scene_load_valid_name(name))
            return err_set(err, ERR_INVALID, p, "invalid shape name: names must match [A-Za-z0-9_-]{1,63}");
        int64_t prev = scene_load_names_insert(names, name, index);
        if (prev >= 0)
            return err_set(err, ERR_INVALID, p, "duplicate shape name '%s' (also /shapes/%lld/name)", name, (long long)prev);
        snprintf(s->name, sizeof s->name, "%s", name);
    }

    const cJSON *mv = scene_load_require(sh, ptr, "material", err);
    if (!mv) return false;
    json_pointer_key(p, SCENE_LOAD_PTR, ptr, "material");
    const char *mname = json_string(mv, p, err);
    if (!mname) return false;
    int64_t mi = scene_load_names_find(L->material_index, mname);
    if (mi < 0) return err_set(err, ERR_NOT_FOUND, p, "unknown material '%.64s'", mname);
    s->material = (uint32_t)mi;

    if (!scene_load_key_bool(sh, ptr, "caustic_caster", &s->caustic_caster, err)) return false;
    if (!scene_load_caustic_interfaces(sh, ptr, s, &L->scene->materials[mi], err)) return false;

    const cJSON *tf = cJSON_GetObjectItemCaseSensitive(sh, "transform");
    bool uniform = true;
    if (tf) {
        json_pointer_key(p, SCENE_LOAD_PTR, ptr, "transform");
        if (!scene_load_transform(tf, p, &s->to_world, &uniform, err)) return false;
    }
    /* The light sampler samples spheres uniformly by area, which an ellipsoid breaks. */
    if (t == 2 && !uniform && material_is_emissive(&L->scene->materials[mi])) {
        char q[SCENE_LOAD_PTR];
        json_pointer_key(q, SCENE_LOAD_PTR, p, "scale");
        return err_set(err, ERR_INVALID, q, "an emissive sphere needs a uniform scale (material '%s' emits)", mname);
    }

    bool ok;
    switch (t) {
    case 0: ok = scene_load_mesh(L, sh, ptr, s); break;
    case 1: ok = scene_load_quad(sh, ptr, s, err); break;
    case 2: ok = scene_load_sphere(sh, ptr, s, err); break;
    case 3: ok = scene_load_box(sh, ptr, s, err); break;
    default: ok = scene_load_disk(sh, ptr, s, err); break;
    }
    return ok && scene_load_check_world(s, ptr, tf != NULL, err);
}

static bool scene_load_shapes(struct scene_load *L, const cJSON *root)
{
    struct err *err = L->err;
    const cJSON *ss = scene_load_require(root, "", "shapes", err);
    if (!ss) return false;
    if (!cJSON_IsArray(ss)) return err_set(err, ERR_INVALID, "/shapes", "expected an array of shapes, got %s", json_type_name(ss));
    int n = cJSON_GetArraySize(ss);
    if ((unsigned)n > SCENE_LOAD_MAX_SHAPES)
        return err_set(err, ERR_LIMIT, "/shapes", "%d shapes, more than the limit of %u", n, SCENE_LOAD_MAX_SHAPES);
    L->scene->shapes = calloc((size_t)n + 1, sizeof *L->scene->shapes);
    struct scene_load_names names = {0};
    if (!L->scene->shapes || !scene_load_names_init(&names, (size_t)n)) {
        scene_load_names_destroy(&names);
        return err_set(err, ERR_NOMEM, "/shapes", "out of memory");
    }
    L->scene->shape_count = (uint32_t)n;
    struct scene_load_names meshes = {0};
    L->mesh_index = &meshes;
    L->mesh_paths = calloc((size_t)n + 1, sizeof *L->mesh_paths);
    bool ok = L->mesh_paths && scene_load_names_init(&meshes, (size_t)n);
    if (!ok) err_set(err, ERR_NOMEM, "/shapes", "out of memory");
    char p[SCENE_LOAD_PTR];
    uint32_t i = 0;
    for (const cJSON *sh = ss->child; sh && ok; sh = sh->next, i++) {
        scene_load_ptr_index(p, "/shapes", i);
        ok = scene_load_shape(L, sh, p, &L->scene->shapes[i], &names, i);
        L->triangles += L->scene->shapes[i].triangle_count;
        if (ok && L->triangles > SCENE_LOAD_MAX_TRIANGLES)
            ok = err_set(err, ERR_LIMIT, p, "the scene's meshes reach %llu triangles, more than the limit of %u",
                         (unsigned long long)L->triangles, SCENE_LOAD_MAX_TRIANGLES);
    }
    scene_load_names_destroy(&names);
    scene_load_names_destroy(&meshes);
    for (size_t k = 0; k < L->mesh_path_count; k++) free(L->mesh_paths[k]);
    free(L->mesh_paths);
    L->mesh_index = NULL;
    L->mesh_paths = NULL;
    return ok;
}

static bool scene_load_format(const cJSON *root, struct err *err)
{
    const cJSON *f = cJSON_GetObjectItemCaseSensitive(root, "format");
    if (!f) return true;
    /* Compared as the exact double: a version number is not a rounded quantity. */
    if (!cJSON_IsNumber(f))
        return err_set(err, ERR_INVALID, "/format", "expected the number 1, got %s", json_type_name(f));
    double v = f->valuedouble;
    if (v == 1.0) return true;
    if (isfinite(v) && v == floor(v) && v > 1.0)
        return err_set(err, ERR_UNSUPPORTED, "/format", "format %.17g is not supported (this build reads format 1)", v);
    return err_set(err, ERR_INVALID, "/format", "format must be 1, got %.17g", v);
}

/* ---- text-level checks ---- */

static void scene_load_line_col(const char *json, size_t len, size_t off, unsigned *line, unsigned *col)
{
    unsigned l = 1, c = 1;
    for (size_t i = 0; i < off && i < len; i++) {
        if (json[i] == '\n') { l++; c = 1; }
        else c++;
    }
    *line = l;
    *col = c;
}

/* cJSON turns "\u0000" into a NUL inside a C string, silently cutting a key or value short;
 * such strings are refused. Runs only on text cJSON accepted, so strings are well-formed. */
static bool scene_load_check_nul_escapes(const char *json, size_t len, struct err *err)
{
    bool in_string = false;
    for (size_t i = 0; i < len; i++) {
        char c = json[i];
        if (!in_string) { in_string = c == '"'; continue; }
        if (c == '"') { in_string = false; continue; }
        if (c != '\\' || i + 1 >= len) continue;
        if (json[i + 1] == 'u' && i + 5 < len && memcmp(json + i + 2, "0000", 4) == 0) {
            unsigned line, col;
            scene_load_line_col(json, len, i, &line, &col);
            return err_set(err, ERR_INVALID, "", "\\u0000 in a string at line %u, column %u (byte %zu) is not allowed",
                           line, col, i);
        }
        i++;  /* skip the escaped character (it may be a quote) */
    }
    return true;
}

/* True when the text ends inside a string or with a bracket still open (truncated input). */
static bool scene_load_unclosed(const char *json, size_t len)
{
    bool in_string = false;
    long depth = 0;
    for (size_t i = 0; i < len; i++) {
        char c = json[i];
        if (in_string) {
            if (c == '\\') i++;
            else if (c == '"') in_string = false;
        } else if (c == '"') {
            in_string = true;
        } else if (c == '{' || c == '[') {
            depth++;
        } else if (c == '}' || c == ']') {
            depth--;
        }
    }
    return in_string || depth > 0;
}

static bool scene_load_parse(const char *json, size_t len, cJSON **out, struct err *err)
{
    unsigned line, col;
    const char *nul = len ? memchr(json, '\0', len) : NULL;
    if (nul) {
        size_t off = (size_t)(nul - json);
        scene_load_line_col(json, len, off, &line, &col);
        return err_set(err, ERR_PARSE, "", "JSON syntax error at line %u, column %u (byte %zu): NUL byte", line, col, off);
    }
    const char *end = json;
    cJSON *root = cJSON_ParseWithLengthOpts(json, len, &end, false);
    if (!root) {
        /* cJSON reports the last byte, not the end, when it runs out of input; an open string
         * or bracket at the end tells the two cases apart. */
        size_t off = end && end >= json ? (size_t)(end - json) : 0;
        if (off + 1 >= len && scene_load_unclosed(json, len)) off = len;
        scene_load_line_col(json, len, off, &line, &col);
        if (off >= len)
            return err_set(err, ERR_PARSE, "", "JSON syntax error at line %u, column %u (byte %zu): unexpected end of input",
                           line, col, off);
        unsigned char ch = (unsigned char)json[off];
        if (ch >= 0x20 && ch < 0x7f)
            return err_set(err, ERR_PARSE, "", "JSON syntax error at line %u, column %u (byte %zu): unexpected '%c'",
                           line, col, off, ch);
        return err_set(err, ERR_PARSE, "", "JSON syntax error at line %u, column %u (byte %zu): unexpected byte 0x%02x",
                       line, col, off, ch);
    }
    size_t off = (size_t)(end - json);
    while (off < len && (json[off] == ' ' || json[off] == '\t' || json[off] == '\n' || json[off] == '\r')) off++;
    if (off < len) {
        cJSON_Delete(root);
        scene_load_line_col(json, len, off, &line, &col);
        return err_set(err, ERR_PARSE, "", "JSON syntax error at line %u, column %u (byte %zu): trailing characters after the scene object",
                       line, col, off);
    }
    if (!scene_load_check_nul_escapes(json, len, err)) {
        cJSON_Delete(root);
        return false;
    }
    *out = root;
    return true;
}

/* ---- entry points ---- */

struct scene *scene_load_json(const char *json, size_t len, const char *base_dir, struct err *err)
{
    static const char *const keys[] = {"format", "camera", "materials", "shapes", "environment", NULL};
    if (!json && len) {
        err_set(err, ERR_INVALID, "", "no JSON text");
        return NULL;
    }
    if (len > SCENE_LOAD_MAX_JSON_BYTES) {
        err_set(err, ERR_LIMIT, "", "scene JSON is %zu bytes, more than the limit of %u (4 MiB)", len,
                SCENE_LOAD_MAX_JSON_BYTES);
        return NULL;
    }
    cJSON *root = NULL;
    if (!scene_load_parse(json ? json : "", len, &root, err)) return NULL;
    struct scene *scene = calloc(1, sizeof *scene);
    if (!scene) {
        cJSON_Delete(root);
        err_set(err, ERR_NOMEM, "", "out of memory");
        return NULL;
    }
    scene->refcount = 1;
    struct scene_load_names material_index = {0};
    struct scene_load L = {scene, base_dir, NULL, err, &material_index};
    bool ok = json_object(root, "", "the scene to be an", err) &&
              json_check_keys(root, "", keys, " at the top level", err) &&
              scene_load_format(root, err) &&
              scene_load_camera(root, &scene->camera, err) &&
              scene_load_materials(root, scene, &material_index, err) &&
              scene_load_environment(root, &scene->env_radiance, err) &&
              scene_load_shapes(&L, root);
    free(L.real_base);
    scene_load_names_destroy(&material_index);
    cJSON_Delete(root);
    if (!ok) {
        scene_release(scene);
        return NULL;
    }
    return scene;
}

struct scene *scene_load_file(const char *path, struct err *err)
{
    char *buf;
    size_t size;
    if (!fileio_read_all(path, "scene file", path, SCENE_LOAD_MAX_JSON_BYTES, &buf, &size, err)) {
        /* An oversized scene is a limit of the whole document ("" in RFC 6901), like an
         * oversized JSON text. */
        if (err && err->code == ERR_LIMIT) err->where[0] = '\0';
        return NULL;
    }
    const char *slash = strrchr(path, '/');
    size_t dlen = slash ? (slash == path ? 1 : (size_t)(slash - path)) : 1;
    char *dir = malloc(dlen + 1);
    struct scene *scene = NULL;
    if (!dir) {
        err_set(err, ERR_NOMEM, path, "out of memory");
    } else {
        memcpy(dir, slash ? path : ".", dlen);
        dir[dlen] = '\0';
        scene = scene_load_json(buf, size, dir, err);
    }
    free(buf);
    free(dir);
    return scene;
}
