/* test_methods.c — the method registry's descriptors keep their promises: every name is found
 * again, defaults pass the method's own validation, the parameter table never advertises a value
 * the method refuses (both ends of every range are accepted), keys are unique, spp is a parameter
 * exactly of the methods that say they take it, and every statistics table closes the objects it
 * opens. A descriptor whose table drifts from its validation fails here. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "integrators/bdpt.h"
#include "integrators/reference_pt.h"
#include "integrators/restir_bdpt.h"
#include "integrators/restir_sms.h"
#include "integrators/restir_sss.h"
#include "integrators/sms.h"
#include "methods/method.h"
#include "test.h"

/* A copy of the method's defaults with one parameter set to `value` (uint or float kinds). */
static void with_value(const struct method_desc *m, const struct method_param *p, double value,
                       unsigned char params[METHOD_PARAMS_BYTES])
{
    memset(params, 0, METHOD_PARAMS_BYTES);
    m->defaults(params);
    if (p->kind == METHOD_PARAM_UINT) {
        uint32_t u = (uint32_t)value;
        memcpy(params + p->offset, &u, sizeof u);
    } else {
        float f = (float)value;
        memcpy(params + p->offset, &f, sizeof f);
    }
}

static void test_names_and_defaults(void)
{
    CHECK(method_count() == 8);
    CHECK(method_default() == method_at(0) && strcmp(method_default()->name, "pt") == 0);
    for (uint32_t i = 0; i < method_count(); i++) {
        const struct method_desc *m = method_at(i);
        CHECK_MSG(method_find(m->name) == m, "%s", m->name);
        CHECK(m->summary && m->summary[0] && m->defaults && m->validate && m->init && m->destroy && m->render);
        _Alignas(8) unsigned char params[METHOD_PARAMS_BYTES] = {0};
        m->defaults(params);
        struct err err = {0};
        CHECK_MSG(m->validate(params, &err), "%s defaults: %s", m->name, err.message);
    }
    CHECK(method_find("nope") == NULL);
    char names[256];
    method_names(names, sizeof names, ", ");
    CHECK(strcmp(names, "pt, restir_pt, bdpt, sms, restir_sss, sms_ssp, restir_bdpt, restir_sms") == 0);
}

static void test_parameter_tables(void)
{
    for (uint32_t i = 0; i < method_count(); i++) {
        const struct method_desc *m = method_at(i);
        CHECK_MSG(((m->caps & METHOD_TAKES_SPP) != 0) == (method_param_find(m, "spp") != NULL), "%s", m->name);
        /* The strict key check (input/json_read.h) tracks at most 32 keys. */
        CHECK_MSG(m->param_count <= 32, "%s has %u parameters", m->name, m->param_count);
        for (uint32_t k = 0; k < m->param_count; k++) {
            const struct method_param *p = &m->params[k];
            CHECK_MSG(p->help && p->help[0], "%s.%s has no help", m->name, p->key);
            CHECK_MSG(method_param_find(m, p->key) == p, "%s.%s appears twice", m->name, p->key);
            if (p->kind == METHOD_PARAM_ENUM) {
                int n = 0;
                while (p->choices[n]) n++;
                _Alignas(8) unsigned char params[METHOD_PARAMS_BYTES] = {0};
                m->defaults(params);
                int e;
                memcpy(&e, params + p->offset, sizeof e);
                CHECK_MSG(n >= 2 && e >= 0 && e < n, "%s.%s default %d of %d choices", m->name, p->key, e, n);
                continue;
            }
            if (p->kind != METHOD_PARAM_UINT && p->kind != METHOD_PARAM_FLOAT) continue;
            CHECK_MSG(p->min <= p->max, "%s.%s", m->name, p->key);
            /* The ends the table accepts (an open end: the nearest float inside it). */
            double lo = p->min_open ? nextafterf((float)p->min, INFINITY) : p->min;
            double hi = p->max_open ? nextafterf((float)p->max, -INFINITY) : p->max;
            if (p->flags & METHOD_PARAM_SPP_LIMIT) hi = 65536;   /* the daemon's default max_spp */
            const double ends[2] = {lo, hi};
            for (int e = 0; e < 2; e++) {
                _Alignas(8) unsigned char params[METHOD_PARAMS_BYTES];
                with_value(m, p, ends[e], params);
                struct err err = {0};
                CHECK_MSG(m->validate(params, &err), "%s.%s = %g is in the table's range but refused: %s", m->name,
                          p->key, ends[e], err.message);
            }
            /* The default is within the range, unless the scene chooses it. */
            if (!(p->flags & METHOD_PARAM_SCENE_DEFAULT)) {
                _Alignas(8) unsigned char params[METHOD_PARAMS_BYTES] = {0};
                m->defaults(params);
                double v;
                if (p->kind == METHOD_PARAM_UINT) {
                    uint32_t u;
                    memcpy(&u, params + p->offset, sizeof u);
                    v = u;
                } else {
                    float f;
                    memcpy(&f, params + p->offset, sizeof f);
                    v = f;
                }
                CHECK_MSG(v >= lo && v <= (p->flags & METHOD_PARAM_SPP_LIMIT ? p->max : hi), "%s.%s default %g",
                          m->name, p->key, v);
            }
        }
    }
}

static void test_statistics_tables(void)
{
    for (uint32_t i = 0; i < method_count(); i++) {
        const struct method_desc *m = method_at(i);
        int depth = 0;
        for (uint32_t k = 0; k < m->stat_count; k++) {
            const struct method_stat *s = &m->stats[k];
            CHECK_MSG(s->key || s->cli_key, "%s line %u names nothing", m->name, k);
            if (s->kind == METHOD_STAT_BEGIN) depth++;
            if (s->kind == METHOD_STAT_END) depth--;
            CHECK_MSG(depth >= 0, "%s closes an object it did not open", m->name);
            CHECK_MSG(s->off < METHOD_COUNTERS_BYTES && s->off2 < METHOD_COUNTERS_BYTES, "%s.%s", m->name, s->key);
        }
        CHECK_MSG(depth == 0, "%s leaves %d objects open", m->name, depth);
        /* A method that keeps history across frames must be able to forget it (a session reset). */
        CHECK_MSG(!(m->caps & METHOD_REUSES_FRAMES) || m->reset, "%s reuses frames but cannot reset", m->name);
    }
}

/* The request parser stores the index of a choice as the parameter's enum value: each table's
 * choices must be in the order of the integrator's enum. */
static void test_enum_choices_follow_the_enums(void)
{
    static const struct {
        const char *method, *key, *name;
        int value;
    } cases[] = {
        {"pt", "subset", "all", PT_SUBSET_ALL},
        {"pt", "subset", "caustic", PT_SUBSET_CAUSTIC},
        {"pt", "subset", "rest", PT_SUBSET_REST},
        {"pt", "sampler", "random", PT_SAMPLER_RANDOM},
        {"pt", "sampler", "sobol", PT_SAMPLER_SOBOL},
        {"pt", "light_sampling", "area", PT_LIGHT_SAMPLING_AREA},
        {"pt", "light_sampling", "solid_angle", PT_LIGHT_SAMPLING_SOLID_ANGLE},
        {"bdpt", "heuristic", "power", BDPT_HEURISTIC_POWER},
        {"bdpt", "heuristic", "balance", BDPT_HEURISTIC_BALANCE},
        {"restir_bdpt", "heuristic", "balance", BDPT_HEURISTIC_BALANCE},
        {"restir_bdpt", "variant", "lightweight", RESTIR_BDPT_LIGHTWEIGHT},
        {"restir_bdpt", "variant", "full", RESTIR_BDPT_FULL},
        {"restir_sss", "shift", "reconnection", RESTIR_SSS_RECONNECTION},
        {"restir_sss", "shift", "delayed", RESTIR_SSS_DELAYED},
        {"restir_sss", "shift", "hybrid", RESTIR_SSS_HYBRID},
        {"restir_sss", "shift", "sequential", RESTIR_SSS_SEQUENTIAL},
        {"restir_sss", "target", "luminance", RESTIR_SSS_TARGET_LUMINANCE},
        {"restir_sss", "target", "per_channel", RESTIR_SSS_TARGET_PER_CHANNEL},
        {"restir_sss", "rest", "by_scene", RESTIR_SSS_REST_BY_SCENE},
        {"restir_sss", "rest", "pt", RESTIR_SSS_REST_PT},
        {"restir_sss", "rest", "restir_pt", RESTIR_SSS_REST_RESTIR_PT},
        {"restir_sms", "sampler", "ssp", RESTIR_SMS_SAMPLER_SSP},
        {"restir_sms", "sampler", "sms", RESTIR_SMS_SAMPLER_SMS},
        {"restir_sms", "rest", "by_scene", RESTIR_SMS_REST_BY_SCENE},
        {"restir_sms", "rest", "pt", RESTIR_SMS_REST_PT},
        {"restir_sms", "rest", "restir_pt", RESTIR_SMS_REST_RESTIR_PT},
        {"restir_pt", "subset", "all", PT_SUBSET_ALL},
        {"restir_pt", "subset", "caustic", PT_SUBSET_CAUSTIC},
        {"restir_pt", "subset", "rest", PT_SUBSET_REST},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        const struct method_param *p = method_param_find(method_find(cases[i].method), cases[i].key);
        CHECK_MSG(p && p->kind == METHOD_PARAM_ENUM, "%s.%s", cases[i].method, cases[i].key);
        if (p) CHECK_MSG(strcmp(p->choices[cases[i].value], cases[i].name) == 0, "%s.%s[%d] is %s, not %s",
                         cases[i].method, cases[i].key, cases[i].value, p->choices[cases[i].value], cases[i].name);
    }
    /* Every enum parameter of the registry is covered above. */
    uint32_t enums = 0;
    for (uint32_t m = 0; m < method_count(); m++)
        for (uint32_t k = 0; k < method_at(m)->param_count; k++) enums += method_at(m)->params[k].kind == METHOD_PARAM_ENUM;
    CHECK_MSG(enums == 12, "%u enum parameters: add the new one's values above", enums);
}

/* Whether two parameter structs of method m hold the same values, parameter by parameter (a
 * struct returned by value may leave its padding bytes anything, so not by memcmp of the whole). */
static bool params_equal(const struct method_desc *m, const unsigned char *a, const unsigned char *b)
{
    for (uint32_t k = 0; k < m->param_count; k++) {
        const struct method_param *p = &m->params[k];
        if (memcmp(a + p->offset, b + p->offset, method_param_size(p->kind)) != 0) return false;
    }
    return true;
}

/* The converge profile: the real_time profile is the defaults themselves; the converge values
 * pass the method's own validation, and turn off every temporal switch of the methods that reuse
 * frames (exactly the methods with a converge operation; the others' frames are independent
 * already). restir_sms also leaves its primary rays and prior to each frame alone. */
static void test_converge_profile(void)
{
    for (uint32_t i = 0; i < method_count(); i++) {
        const struct method_desc *m = method_at(i);
        _Alignas(8) unsigned char defaults[METHOD_PARAMS_BYTES] = {0}, real_time[METHOD_PARAMS_BYTES] = {0},
                                  converge[METHOD_PARAMS_BYTES] = {0};
        m->defaults(defaults);
        method_profile_defaults(m, METHOD_PROFILE_REAL_TIME, real_time);
        method_profile_defaults(m, METHOD_PROFILE_CONVERGE, converge);
        CHECK_MSG(params_equal(m, defaults, real_time), "%s: real_time is not the defaults", m->name);
        CHECK_MSG((m->converge != NULL) == ((m->caps & METHOD_REUSES_FRAMES) != 0), "%s", m->name);
        CHECK_MSG(params_equal(m, defaults, converge) == !m->converge, "%s", m->name);
        struct err err = {0};
        CHECK_MSG(m->validate(converge, &err), "%s converge: %s: %s", m->name, err.where, err.message);
        for (uint32_t k = 0; k < m->param_count; k++) {
            const struct method_param *p = &m->params[k];
            size_t len = strlen(p->key);
            /* A walking primary ray ties each frame's position to the last one's. */
            if (strcmp(p->key, "jitter_walk") == 0) {
                float walk;
                memcpy(&walk, converge + p->offset, sizeof walk);
                CHECK_MSG(walk == 0.0f, "%s converge: jitter_walk %g", m->name, walk);
            }
            if (p->kind != METHOD_PARAM_BOOL || len < 8 || strcmp(p->key + len - 8, "temporal") != 0) continue;
            bool on;
            memcpy(&on, converge + p->offset, sizeof on);
            CHECK_MSG(!on, "%s converge: %s is on", m->name, p->key);
        }
    }
    const struct method_desc *sms = method_find("restir_sms");
    _Alignas(8) unsigned char params[METHOD_PARAMS_BYTES] = {0};
    method_profile_defaults(sms, METHOD_PROFILE_CONVERGE, params);
    const struct restir_sms_params *sp = (const struct restir_sms_params *)(const void *)params;
    CHECK(sp->jitter_walk == 0.0f && sp->ssp.prior_frames == 1);
    CHECK(strcmp(method_profile_names[METHOD_PROFILE_REAL_TIME], "real_time") == 0 &&
          strcmp(method_profile_names[METHOD_PROFILE_CONVERGE], "converge") == 0 && !method_profile_names[2]);
}

TEST_MAIN(TEST(test_names_and_defaults), TEST(test_parameter_tables), TEST(test_statistics_tables),
          TEST(test_enum_choices_follow_the_enums), TEST(test_converge_profile))
