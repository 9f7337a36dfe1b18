/* registry.c — the one table of methods (method.h). Adding a method is its own files and one line
 * here; the order is the order of GET /v1/methods and of the names in messages, and the first is
 * the default method. */
#include <stdio.h>
#include <string.h>

#include "methods/method.h"

extern const struct method_desc method_pt, method_restir_pt, method_bdpt, method_sms, method_restir_sss,
    method_sms_ssp, method_restir_bdpt, method_restir_sms;

static const struct method_desc *const methods[] = {
    &method_pt,
    &method_restir_pt,
    &method_bdpt,
    &method_sms,
    &method_restir_sss,
    &method_sms_ssp,
    &method_restir_bdpt,
    &method_restir_sms,
};

uint32_t method_count(void)
{
    return sizeof methods / sizeof methods[0];
}

const struct method_desc *method_at(uint32_t i)
{
    return i < method_count() ? methods[i] : NULL;
}

const struct method_desc *method_default(void)
{
    return methods[0];
}

const struct method_desc *method_find(const char *name)
{
    for (uint32_t i = 0; i < method_count(); i++)
        if (strcmp(methods[i]->name, name) == 0) return methods[i];
    return NULL;
}

void method_names(char *out, size_t size, const char *separator)
{
    size_t n = 0;
    if (size) out[0] = '\0';
    for (uint32_t i = 0; i < method_count() && n < size; i++)
        n += (size_t)snprintf(out + n, size - n, "%s%s", i ? separator : "", methods[i]->name);
}

const char *const method_profile_names[] = {"real_time", "converge", NULL};

void method_profile_defaults(const struct method_desc *m, enum method_profile profile, void *params)
{
    m->defaults(params);
    if (profile == METHOD_PROFILE_CONVERGE && m->converge) m->converge(params);
}

const struct method_param *method_param_find(const struct method_desc *m, const char *key)
{
    for (uint32_t i = 0; i < m->param_count; i++)
        if (strcmp(m->params[i].key, key) == 0) return &m->params[i];
    return NULL;
}

struct render_stats method_frame_render_stats(const struct image *out, unsigned threads, uint64_t rays_intersect,
                                              uint64_t rays_occluded, uint64_t nonfinite, double ms)
{
    return (struct render_stats){.rays_intersect = rays_intersect, .rays_occluded = rays_occluded,
                                 .samples = (uint64_t)out->width * out->height, .nonfinite = nonfinite,
                                 .threads = threads ? threads : parallel_default_threads(), .render_ms = ms};
}
