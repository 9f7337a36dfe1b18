/* refstore.c — reference images by (scene, name) (see refstore.h). A flat array: a daemon holds
 * a handful of references, and a linear scan under a mutex is the simplest correct thing. */
#include "refstore.h"

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct refstore {
    pthread_mutex_t lock;
    struct budget *budget;       /* or NULL */
    struct ref_image **items;
    size_t count, cap;
};

struct refstore *refstore_new(struct budget *budget)
{
    struct refstore *rs = calloc(1, sizeof *rs);
    if (!rs) return NULL;
    pthread_mutex_init(&rs->lock, NULL);
    rs->budget = budget;
    return rs;
}

static uint64_t refstore_image_bytes(const struct image *img)
{
    return (uint64_t)img->width * img->height * sizeof(struct vec3);
}

/* The bytes a reference holds go back to the budget with its pixels, when its last holder lets
 * go: the store, or an animation job or metrics request that retained it before it was
 * deleted or replaced. Crediting them at the deletion would let a new reference take the same
 * bytes while the old pixels are still in memory. */
void ref_image_release(struct ref_image *r)
{
    if (r && __atomic_sub_fetch(&r->refcount, 1, __ATOMIC_ACQ_REL) == 0) {
        if (r->budget) budget_release(r->budget, BUDGET_REFERENCES, refstore_image_bytes(&r->img));
        image_destroy(&r->img);
        free(r);
    }
}

void refstore_free(struct refstore *rs)
{
    if (!rs) return;
    for (size_t i = 0; i < rs->count; i++) ref_image_release(rs->items[i]);
    free(rs->items);
    pthread_mutex_destroy(&rs->lock);
    free(rs);
}

static long refstore_find(struct refstore *rs, const char *scene, const char *name)
{
    for (size_t i = 0; i < rs->count; i++)
        if (strcmp(rs->items[i]->scene, scene) == 0 && strcmp(rs->items[i]->name, name) == 0) return (long)i;
    return -1;
}

bool refstore_put(struct refstore *rs, const char *scene, const char *name, struct image *img, uint32_t spp,
                  const char *method, bool *replaced, struct err *err)
{
    *replaced = false;
    uint64_t bytes = refstore_image_bytes(img);
    if (rs->budget && !budget_reserve(rs->budget, BUDGET_REFERENCES, bytes, err)) {
        image_destroy(img);
        return false;
    }
    struct ref_image *r = calloc(1, sizeof *r);
    if (!r) {
        if (rs->budget) budget_release(rs->budget, BUDGET_REFERENCES, bytes);
        image_destroy(img);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for a reference");
    }
    r->refcount = 1;
    r->budget = rs->budget;  /* from here on the last release gives the bytes back */
    snprintf(r->scene, sizeof r->scene, "%s", scene);
    snprintf(r->name, sizeof r->name, "%s", name);
    r->spp = spp;
    r->method = method;
    r->created = time(NULL);
    r->img = *img;
    img->pixels = NULL;
    img->width = img->height = 0;

    pthread_mutex_lock(&rs->lock);
    long i = refstore_find(rs, scene, name);
    if (i >= 0) {
        /* A replacement keeps its predecessor's place in listings. */
        ref_image_release(rs->items[i]);
        rs->items[i] = r;
        *replaced = true;
    } else {
        if (rs->count == rs->cap) {
            size_t cap = rs->cap ? 2 * rs->cap : 8;
            struct ref_image **items = realloc(rs->items, cap * sizeof *items);
            if (!items) {
                pthread_mutex_unlock(&rs->lock);
                ref_image_release(r);
                return err_set(err, ERR_NOMEM, NULL, "out of memory for a reference");
            }
            rs->items = items;
            rs->cap = cap;
        }
        rs->items[rs->count++] = r;
    }
    pthread_mutex_unlock(&rs->lock);
    return true;
}

struct ref_image *refstore_get(struct refstore *rs, const char *scene, const char *name)
{
    pthread_mutex_lock(&rs->lock);
    long i = refstore_find(rs, scene, name);
    struct ref_image *r = i >= 0 ? rs->items[i] : NULL;
    if (r) __atomic_add_fetch(&r->refcount, 1, __ATOMIC_RELAXED);
    pthread_mutex_unlock(&rs->lock);
    return r;
}

bool refstore_delete(struct refstore *rs, const char *scene, const char *name)
{
    pthread_mutex_lock(&rs->lock);
    long i = refstore_find(rs, scene, name);
    if (i >= 0) {
        ref_image_release(rs->items[i]);
        memmove(&rs->items[i], &rs->items[i + 1], (rs->count - (size_t)i - 1) * sizeof *rs->items);
        rs->count--;
    }
    pthread_mutex_unlock(&rs->lock);
    return i >= 0;
}

size_t refstore_list(struct refstore *rs, const char *scene, struct ref_info *out, size_t max)
{
    size_t n = 0;
    pthread_mutex_lock(&rs->lock);
    for (size_t i = 0; i < rs->count; i++) {
        const struct ref_image *r = rs->items[i];
        if (strcmp(r->scene, scene) != 0) continue;
        if (n < max) {
            struct ref_info *o = &out[n];
            snprintf(o->name, sizeof o->name, "%s", r->name);
            o->width = r->img.width;
            o->height = r->img.height;
            o->spp = r->spp;
            o->method = r->method;
            o->bytes = refstore_image_bytes(&r->img);
            o->created = r->created;
        }
        n++;
    }
    pthread_mutex_unlock(&rs->lock);
    return n;
}

void refstore_drop_scene(struct refstore *rs, const char *scene)
{
    pthread_mutex_lock(&rs->lock);
    size_t k = 0;
    for (size_t i = 0; i < rs->count; i++) {
        if (strcmp(rs->items[i]->scene, scene) == 0)
            ref_image_release(rs->items[i]);
        else
            rs->items[k++] = rs->items[i];
    }
    rs->count = k;
    pthread_mutex_unlock(&rs->lock);
}

size_t refstore_bytes(struct refstore *rs)
{
    size_t b = 0;
    pthread_mutex_lock(&rs->lock);
    for (size_t i = 0; i < rs->count; i++) b += refstore_image_bytes(&rs->items[i]->img);
    pthread_mutex_unlock(&rs->lock);
    return b;
}
