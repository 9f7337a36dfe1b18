/* method_json.c — methods as JSON, from their descriptors alone (methods/method.h): a session's
 * params object, a frame's method counters (the daemon's frame JSON and the CLI's --json), and
 * the registry itself (GET /v1/methods). Nothing here names a method. */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "protocol.h"

/* A float parameter as the shortest decimal that reads back as the same float (0.02, not the
 * double 0.019999999552965164 the float holds). */
static void method_json_float(struct jsonw *w, float f)
{
    char text[32];
    for (int digits = 6; digits <= 9; digits++) {
        snprintf(text, sizeof text, "%.*g", digits, (double)f);
        if ((float)strtod(text, NULL) == f) break;
    }
    jsonw_double(w, strtod(text, NULL));
}

/* The value of a parameter, as a session create request would send it. */
static void method_json_param_value(struct jsonw *w, const struct method_param *mp, const void *params)
{
    const char *at = (const char *)params + mp->offset;
    switch (mp->kind) {
    case METHOD_PARAM_UINT: {
        uint32_t u;
        memcpy(&u, at, sizeof u);
        jsonw_uint(w, u);
        break;
    }
    case METHOD_PARAM_BOOL: {
        bool b;
        memcpy(&b, at, sizeof b);
        jsonw_bool(w, b);
        break;
    }
    case METHOD_PARAM_FLOAT: {
        float f;
        memcpy(&f, at, sizeof f);
        method_json_float(w, f);
        break;
    }
    case METHOD_PARAM_ENUM: {
        int e;
        memcpy(&e, at, sizeof e);
        int n = 0;
        while (mp->choices[n]) n++;
        if (e >= 0 && e < n) jsonw_string(w, mp->choices[e]);
        else jsonw_null(w);
        break;
    }
    }
}

void protocol_write_method_params(struct jsonw *w, const struct method_desc *m, const void *params)
{
    jsonw_object_begin(w);
    for (uint32_t i = 0; i < m->param_count; i++) {
        jsonw_key(w, m->params[i].key);
        method_json_param_value(w, &m->params[i], params);
    }
    jsonw_object_end(w);
}

static uint64_t method_json_u64(const unsigned char *c, uint16_t off)
{
    uint64_t v;
    memcpy(&v, c + off, sizeof v);
    return v;
}

static double method_json_f64(const unsigned char *c, uint16_t off)
{
    double v;
    memcpy(&v, c + off, sizeof v);
    return v;
}

/* A ratio line's value: off / off2, or 1 - that (METHOD_STAT_SUCCESS); 0 when off2 holds 0. */
static double method_json_ratio(const struct method_stat *s, const unsigned char *c)
{
    uint64_t den = method_json_u64(c, s->off2);
    if (!den) return 0.0;
    double r = (double)method_json_u64(c, s->off) / (double)den;
    return s->kind == METHOD_STAT_SUCCESS ? 1.0 - r : r;
}

void protocol_write_method_counters(struct jsonw *w, const struct method_desc *m, const struct frame_stats *st)
{
    const unsigned char *c = st->counters;
    for (uint32_t i = 0; i < m->stat_count; i++) {
        const struct method_stat *s = &m->stats[i];
        if (!s->key) continue;   /* the CLI's own lines */
        if (s->kind != METHOD_STAT_END) jsonw_key(w, s->key);
        switch (s->kind) {
        case METHOD_STAT_BEGIN: jsonw_object_begin(w); break;
        case METHOD_STAT_END: jsonw_object_end(w); break;
        case METHOD_STAT_U64: jsonw_uint(w, method_json_u64(c, s->off)); break;
        case METHOD_STAT_MS: jsonw_double(w, method_json_f64(c, s->off)); break;
        case METHOD_STAT_MS_SUM: jsonw_double(w, method_json_f64(c, s->off) + method_json_f64(c, s->off2)); break;
        case METHOD_STAT_RATIO:
        case METHOD_STAT_SUCCESS: jsonw_double(w, method_json_ratio(s, c)); break;
        case METHOD_STAT_SESSION_BYTES:
        case METHOD_STAT_RESERVOIR_BYTES_PER_PIXEL: jsonw_null(w); break;
        }
    }
}

void protocol_print_method_counters(FILE *out, const struct method_desc *m, const struct frame_stats *st,
                                    size_t session_bytes, uint32_t reservoir_bytes_per_pixel)
{
    const unsigned char *c = st->counters;
    bool first = false;   /* the envelope has members before these: every top-level line takes a comma */
    for (uint32_t i = 0; i < m->stat_count; i++) {
        const struct method_stat *s = &m->stats[i];
        const char *key = s->cli_key ? s->cli_key : s->key;
        if (!key[0]) {
            /* Hidden here: a hidden object is skipped whole. */
            if (s->kind == METHOD_STAT_BEGIN)
                for (int depth = 1; depth && i + 1 < m->stat_count; i++)
                    depth += m->stats[i + 1].kind == METHOD_STAT_BEGIN ? 1 : m->stats[i + 1].kind == METHOD_STAT_END ? -1 : 0;
            continue;
        }
        if (s->kind == METHOD_STAT_END) {
            fputc('}', out);
            first = false;
            continue;
        }
        fprintf(out, "%s\"%s\":", first ? "" : ",", key);
        first = false;
        switch (s->kind) {
        case METHOD_STAT_BEGIN:
            fputc('{', out);
            first = true;
            break;
        case METHOD_STAT_U64: fprintf(out, "%" PRIu64, method_json_u64(c, s->off)); break;
        case METHOD_STAT_MS: fprintf(out, "%.3f", method_json_f64(c, s->off)); break;
        case METHOD_STAT_MS_SUM: fprintf(out, "%.3f", method_json_f64(c, s->off) + method_json_f64(c, s->off2)); break;
        case METHOD_STAT_RATIO:
        case METHOD_STAT_SUCCESS: fprintf(out, "%.6g", method_json_ratio(s, c)); break;
        case METHOD_STAT_SESSION_BYTES: fprintf(out, "%zu", session_bytes); break;
        case METHOD_STAT_RESERVOIR_BYTES_PER_PIXEL: fprintf(out, "%u", reservoir_bytes_per_pixel); break;
        case METHOD_STAT_END: break;
        }
    }
}

static const char *method_json_kind(enum method_param_kind k)
{
    switch (k) {
    case METHOD_PARAM_UINT: return "integer";
    case METHOD_PARAM_BOOL: return "boolean";
    case METHOD_PARAM_FLOAT: return "number";
    case METHOD_PARAM_ENUM: return "string";
    }
    return "?";
}

/* The capabilities as named flags. */
static void method_json_caps(struct jsonw *w, unsigned caps)
{
    jsonw_object_begin(w);
    jsonw_key(w, "takes_spp"); jsonw_bool(w, caps & METHOD_TAKES_SPP);
    jsonw_key(w, "reuses_frames"); jsonw_bool(w, caps & METHOD_REUSES_FRAMES);
    jsonw_key(w, "reuses_pixels"); jsonw_bool(w, caps & METHOD_REUSES_PIXELS);
    jsonw_key(w, "manifold_counters"); jsonw_bool(w, caps & METHOD_MANIFOLD_COUNTERS);
    jsonw_object_end(w);
}

void protocol_write_method(struct jsonw *w, const struct method_desc *m, const struct protocol_limits *limits)
{
    _Alignas(8) unsigned char defaults[METHOD_PARAMS_BYTES], converge[METHOD_PARAMS_BYTES];
    memset(defaults, 0, sizeof defaults);
    memset(converge, 0, sizeof converge);
    method_profile_defaults(m, METHOD_PROFILE_REAL_TIME, defaults);
    method_profile_defaults(m, METHOD_PROFILE_CONVERGE, converge);
    jsonw_object_begin(w);
    jsonw_key(w, "name"); jsonw_string(w, m->name);
    jsonw_key(w, "summary"); jsonw_string(w, m->summary);
    jsonw_key(w, "capabilities"); method_json_caps(w, m->caps);
    jsonw_key(w, "refuses");
    if (m->refuses) jsonw_string(w, m->refuses); else jsonw_null(w);
    jsonw_key(w, "params");
    jsonw_array_begin(w);
    for (uint32_t i = 0; i < m->param_count; i++) {
        const struct method_param *mp = &m->params[i];
        jsonw_object_begin(w);
        jsonw_key(w, "name"); jsonw_string(w, mp->key);
        jsonw_key(w, "type"); jsonw_string(w, method_json_kind(mp->kind));
        jsonw_key(w, "default");
        if (mp->flags & METHOD_PARAM_SCENE_DEFAULT) jsonw_null(w);
        else method_json_param_value(w, mp, defaults);
        /* Only where the converge profile changes the default: absent, a session of either
         * profile starts from "default". */
        if (memcmp(defaults + mp->offset, converge + mp->offset, method_param_size(mp->kind)) != 0) {
            jsonw_key(w, "converge_default");
            method_json_param_value(w, mp, converge);
        }
        if (mp->kind == METHOD_PARAM_UINT || mp->kind == METHOD_PARAM_FLOAT) {
            double hi = (mp->flags & METHOD_PARAM_SPP_LIMIT) && limits && limits->max_spp < mp->max ? limits->max_spp : mp->max;
            jsonw_key(w, "minimum"); jsonw_double(w, mp->min);
            jsonw_key(w, "maximum"); jsonw_double(w, hi);
            if (mp->min_open) { jsonw_key(w, "exclusive_minimum"); jsonw_bool(w, true); }
            if (mp->max_open) { jsonw_key(w, "exclusive_maximum"); jsonw_bool(w, true); }
        }
        if (mp->kind == METHOD_PARAM_ENUM) {
            jsonw_key(w, "choices");
            jsonw_array_begin(w);
            for (int k = 0; mp->choices[k]; k++) jsonw_string(w, mp->choices[k]);
            jsonw_array_end(w);
        }
        jsonw_key(w, "help"); jsonw_string(w, mp->help);
        jsonw_object_end(w);
    }
    jsonw_array_end(w);
    jsonw_object_end(w);
}

void protocol_write_methods(struct jsonw *w, const struct protocol_limits *limits)
{
    jsonw_object_begin(w);
    jsonw_key(w, "methods");
    jsonw_array_begin(w);
    for (uint32_t i = 0; i < method_count(); i++) protocol_write_method(w, method_at(i), limits);
    jsonw_array_end(w);
    jsonw_object_end(w);
}
