/* test_protocol.c — the wire format (protocol/request.c, protocol/jsonw.c).
 * Valid bodies must parse to exact values and the documented defaults; the malformed table
 * gives each bad body its exact error code and JSON pointer and a piece of its message; the
 * writer's output is parsed back with cJSON and compared field by field. */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "integrators/restir_pt.h"
#include "methods/path_params.h"
#include "protocol.h"
#include "test.h"

static const struct protocol_limits LIMITS = {
    .max_side = 4096, .max_pixels = 4096u * 2048u, .max_spp = 2048, .max_frames = 100, .max_keys = 4,
};

enum which { SESSION, FRAME, RENDER, REFERENCE };
static const char *const WHICH_NAME[] = {"session", "frame", "render", "reference"};

/* Runs one parser on body[0..len); returns its result and fills *err. */
static bool parse_one(enum which w, const char *body, size_t len, struct err *err)
{
    memset(err, 0, sizeof *err);
    switch (w) {
    case SESSION: {
        struct view_params p;
        return protocol_parse_session_create(body, len, &LIMITS, &p, err);
    }
    case FRAME: {
        static struct protocol_frame_request f;  /* large: kept off the stack */
        return protocol_parse_frame_request(body, len, &f, err);
    }
    case RENDER: {
        struct protocol_render_request r;
        bool ok = protocol_parse_render_request(body, len, &LIMITS, &r, err);
        protocol_render_request_destroy(&r);  /* also after failure, as the header allows */
        return ok;
    }
    case REFERENCE: {
        struct protocol_reference_request r;
        return protocol_parse_reference_request(body, len, &LIMITS, &r, err);
    }
    }
    return false;
}

static void expect_fail_len(enum which w, const char *body, size_t len, enum err_code code, const char *where,
                            const char *msg)
{
    struct err err;
    bool ok = parse_one(w, body, len, &err);
    CHECK_MSG(!ok, "%s accepted %.200s", WHICH_NAME[w], body);
    if (ok) return;
    CHECK_MSG(err.code == code && strcmp(err.where, where) == 0 && strstr(err.message, msg),
              "%s %.120s: got %s at \"%s\": %s; want %s at \"%s\" containing \"%s\"", WHICH_NAME[w], body,
              err_code_name(err.code), err.where, err.message, err_code_name(code), where, msg);
}

static void expect_fail(enum which w, const char *body, enum err_code code, const char *where, const char *msg)
{
    expect_fail_len(w, body, strlen(body), code, where, msg);
}

/* ---- valid requests ---- */

static void test_valid_id(void)
{
    CHECK(protocol_valid_id("cornell-box_2", 13));
    CHECK(protocol_valid_id("a", 1));
    char long_id[PROTOCOL_ID_MAX + 2];
    memset(long_id, 'x', sizeof long_id);
    CHECK(protocol_valid_id(long_id, PROTOCOL_ID_MAX));
    CHECK(!protocol_valid_id(long_id, PROTOCOL_ID_MAX + 1));
    CHECK(!protocol_valid_id("", 0));
    CHECK(!protocol_valid_id(NULL, 0));
    CHECK(!protocol_valid_id("a b", 3));
    CHECK(!protocol_valid_id("a/b", 3));
    CHECK(!protocol_valid_id("a.b", 3));
    CHECK(!protocol_valid_id("\xc3\xa9", 2));
    CHECK(!protocol_valid_id("ab\0", 3));   /* the length counts, not the NUL */
    CHECK(protocol_valid_id("abc", 2));     /* a prefix of a longer buffer */
}

static void test_pointer_key(void)
{
    char out[256];
    json_pointer_key(out, sizeof out, "", "a/b~c");
    CHECK(strcmp(out, "/a~1b~0c") == 0);
    json_pointer_key(out, sizeof out, "/lights", "lamp");
    CHECK(strcmp(out, "/lights/lamp") == 0);
    json_pointer_key(out, sizeof out, "", "");
    CHECK(strcmp(out, "/") == 0);
    /* Truncation keeps whole escapes and whole UTF-8 characters. */
    char small[8];
    json_pointer_key(small, sizeof small, "/abc", "~~~");
    CHECK_MSG(strcmp(small, "/abc/~0") == 0, "%s", small);
    char five[5];
    json_pointer_key(five, sizeof five, "", "\xc3\xa9\xc3\xa9");
    CHECK_MSG(strcmp(five, "/\xc3\xa9") == 0, "%s", five);
    char one[1] = {'x'};
    json_pointer_key(one, sizeof one, "/a", "b");
    CHECK(one[0] == '\0');
}

/* The pt params a parsed session holds. */
#define PT(vp) VIEW_METHOD_PARAMS(&(vp), const struct pt_method_params)

static void test_session_valid(void)
{
    const char *body = "{\"method\": \"pt\", \"width\": 640, \"height\": 480, \"seed\": 42,"
                       " \"params\": {\"spp\": 16, \"max_depth\": 8, \"rr_depth\": 0, \"nee\": false}}";
    struct view_params p;
    struct err err;
    CHECK(protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK(p.method == method_find("pt") && p.width == 640 && p.height == 480 && p.seed == 42);
    CHECK(PT(p)->spp == 16 && PT(p)->max_depth == 8 && PT(p)->rr_depth == 0 && !PT(p)->nee);

    /* Defaults: the empty body and {} are the same; params default per view_params_defaults. */
    const struct view_params d = view_params_defaults(method_find("pt"), 256, 256);
    CHECK(protocol_parse_session_create("", 0, &LIMITS, &p, &err));
    CHECK(p.method == method_find("pt") && p.width == 256 && p.height == 256 && p.seed == 0);
    CHECK(PT(p)->spp == PT(d)->spp && PT(p)->max_depth == PT(d)->max_depth && PT(p)->rr_depth == PT(d)->rr_depth &&
          PT(p)->nee == PT(d)->nee);
    CHECK(protocol_parse_session_create(" {\n} ", 5, &LIMITS, &p, &err));
    CHECK(p.width == 256 && p.height == 256);

    /* Partial params keep the other defaults; the largest seed is exact. */
    body = "{\"params\": {\"spp\": 2048}, \"seed\": 9007199254740992, \"width\": 4096, \"height\": 2048}";
    CHECK(protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK(PT(p)->spp == 2048 && PT(p)->max_depth == PT(d)->max_depth && PT(p)->nee == PT(d)->nee);
    CHECK(p.seed == 9007199254740992ull);
    CHECK(p.width == 4096 && p.height == 2048);

    /* A body is a byte range: what follows len is never read. */
    body = "{\"width\": 8}garbage";
    CHECK(protocol_parse_session_create(body, 12, &LIMITS, &p, &err));
    CHECK(p.width == 8);
    /* Exponent notation of an integer is an integer. */
    body = "{\"width\": 1.6e1, \"height\": 3E2}";
    CHECK(protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK(p.width == 16 && p.height == 300);

    /* A default over a configured limit is reported, not silently changed. */
    const struct protocol_limits tiny = {.max_side = 128, .max_pixels = 1u << 20, .max_spp = 4, .max_frames = 1, .max_keys = 1};
    CHECK(!protocol_parse_session_create("{}", 2, &tiny, &p, &err));
    CHECK(err.code == ERR_LIMIT && strcmp(err.where, "/width") == 0 && strstr(err.message, "default"));
}

/* The profile chooses the defaults and the params are read over them, wherever either stands
 * in the body; an unknown profile is refused at /profile, naming the two. */
static void test_session_profile(void)
{
    struct view_params p;
    struct err err;
#define RPT(vp) VIEW_METHOD_PARAMS(&(vp), const struct restir_pt_params)
    const struct restir_pt_params d = restir_pt_defaults();
    const char *body = "{\"method\": \"restir_pt\"}";
    CHECK(protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK(p.profile == METHOD_PROFILE_REAL_TIME && RPT(p)->temporal == d.temporal &&
          RPT(p)->spatial_rounds == d.spatial_rounds);
    body = "{\"method\": \"restir_pt\", \"profile\": \"real_time\"}";
    CHECK(protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK(p.profile == METHOD_PROFILE_REAL_TIME && RPT(p)->temporal && RPT(p)->spatial_rounds == d.spatial_rounds);
    body = "{\"method\": \"restir_pt\", \"profile\": \"converge\"}";
    CHECK(protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK(p.profile == METHOD_PROFILE_CONVERGE && !RPT(p)->temporal && RPT(p)->spatial_rounds == 3 &&
          RPT(p)->spatial_neighbors == 6 && RPT(p)->max_depth == d.max_depth);
    body = "{\"params\": {\"temporal\": true, \"spatial_rounds\": 2}, \"profile\": \"converge\", \"method\": \"restir_pt\"}";
    CHECK(protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK(p.profile == METHOD_PROFILE_CONVERGE && RPT(p)->temporal && RPT(p)->spatial_rounds == 2 &&
          RPT(p)->spatial_neighbors == 6);
#undef RPT
    /* pt's frames are independent: the profile changes none of its parameters. */
    const struct view_params pt = view_params_defaults(method_find("pt"), 256, 256);
    body = "{\"profile\": \"converge\"}";
    CHECK(protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK(p.profile == METHOD_PROFILE_CONVERGE && memcmp(p.method_params, pt.method_params, sizeof pt.method_params) == 0);
    body = "{\"method\": \"restir_pt\", \"profile\": \"real-time\"}";
    CHECK(!protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK_MSG(err.code == ERR_INVALID && strcmp(err.where, "/profile") == 0 &&
              strstr(err.message, "unknown profile \"real-time\" (real_time or converge)"), "%s: %s", err.where, err.message);
    body = "{\"profile\": 1}";
    CHECK(!protocol_parse_session_create(body, strlen(body), &LIMITS, &p, &err));
    CHECK(strcmp(err.where, "/profile") == 0);
}

/* A params object on its own: the keys it names are reported, the others keep their values. */
static void test_method_params_alone(void)
{
    const struct method_desc *pt = method_find("pt");
    struct view_params vp = view_params_defaults(pt, 8, 8);
    const uint32_t default_spp = PT(vp)->spp;
    uint32_t given = 0;
    struct err err;
    const char *text = "{\"max_depth\": 3, \"nee\": false}";
    CHECK(protocol_parse_method_params(text, strlen(text), &LIMITS, &vp, &given, &err));
    CHECK(PT(vp)->max_depth == 3 && !PT(vp)->nee && PT(vp)->spp == default_spp);
    uint32_t expect = 0;
    for (uint32_t i = 0; i < pt->param_count; i++)
        if (strcmp(pt->params[i].key, "max_depth") == 0 || strcmp(pt->params[i].key, "nee") == 0) expect |= 1u << i;
    CHECK(given == expect);
    /* Errors: positions within the text, pointers as in a session's body; nothing written. */
    text = "{\"spp\": 0}";
    CHECK(!protocol_parse_method_params(text, strlen(text), &LIMITS, &vp, &given, &err));
    CHECK(strcmp(err.where, "/params/spp") == 0 && given == expect);
    CHECK(!protocol_parse_method_params("{bad", 4, &LIMITS, &vp, &given, &err));
    CHECK(err.code == ERR_PARSE && strstr(err.message, "at byte 1"));
    CHECK(!protocol_parse_method_params("[]", 2, &LIMITS, &vp, &given, &err));
    CHECK(strcmp(err.where, "/params") == 0);
}

static void test_frame_valid(void)
{
    const char *body =
        "{\"camera\": {\"position\": [1.5, -2, 3.25], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], \"fov_deg\": 45},"
        " \"lights\": {\"lamp\": {\"position\": [0, 1.9, 0], \"emission\": [17, 12, 4]},"
        "             \"ball-2\": {\"transform\": {\"translate\": [1, 2, 3], \"rotate_deg\": [0, 90, 0], \"scale\": 2}},"
        "             \"box_3\": {\"transform\": {\"scale\": [1, 2, 0.5]}}},"
        " \"time_s\": 0.25}";
    static struct protocol_frame_request f;
    struct err err;
    CHECK_MSG(protocol_parse_frame_request(body, strlen(body), &f, &err), "%s: %s", err.where, err.message);
    CHECK(f.camera.has_position && f.camera.has_look_at && f.camera.has_up && f.camera.has_fov_deg);
    CHECK(f.camera.position.x == 1.5f && f.camera.position.y == -2.0f && f.camera.position.z == 3.25f);
    CHECK(f.camera.up.y == 1.0f && f.camera.fov_deg == 45.0f);
    CHECK(f.shape_count == 3);
    CHECK(strcmp(f.shapes[0].name, "lamp") == 0 && f.shapes[0].state.has_position && !f.shapes[0].state.has_transform &&
          f.shapes[0].state.has_emission);
    CHECK(f.shapes[0].state.position.y == 1.9f && f.shapes[0].state.emission.x == 17.0f && f.shapes[0].state.emission.z == 4.0f);
    const struct protocol_shape_change *b = &f.shapes[1];
    CHECK(strcmp(b->name, "ball-2") == 0 && !b->state.has_position && b->state.has_transform && !b->state.has_emission);
    CHECK(b->state.transform.translate.z == 3.0f && b->state.transform.rotate_deg.y == 90.0f);
    CHECK(b->state.transform.scale.x == 2.0f && b->state.transform.scale.y == 2.0f && b->state.transform.scale.z == 2.0f);
    const struct protocol_shape_change *x = &f.shapes[2];
    CHECK(strcmp(x->name, "box_3") == 0 && x->state.transform.scale.y == 2.0f && x->state.transform.scale.z == 0.5f);
    CHECK(x->state.transform.translate.x == 0.0f && x->state.transform.rotate_deg.z == 0.0f);  /* identity parts */
    CHECK(f.has_time && f.time_s == 0.25);

    /* Everything is optional: the empty body and {} change nothing. */
    CHECK(protocol_parse_frame_request("", 0, &f, &err));
    CHECK(!f.camera.has_position && !f.camera.has_fov_deg && f.shape_count == 0 && !f.has_time);
    CHECK(protocol_parse_frame_request(NULL, 0, &f, &err));
    CHECK(protocol_parse_frame_request("{}", 2, &f, &err));
    CHECK(f.shape_count == 0 && !f.has_time);
    /* A partial camera: position == look_at is checked only when both come in one object. */
    body = "{\"camera\": {\"look_at\": [0, 0, 0]}}";
    CHECK(protocol_parse_frame_request(body, strlen(body), &f, &err));
    CHECK(f.camera.has_look_at && !f.camera.has_position && !f.camera.has_up);
    /* {} is the identity transform. */
    body = "{\"lights\": {\"lamp\": {\"transform\": {}}}}";
    CHECK(protocol_parse_frame_request(body, strlen(body), &f, &err));
    CHECK(f.shape_count == 1 && f.shapes[0].state.has_transform && f.shapes[0].state.transform.scale.x == 1.0f);
    /* Exactly the limit of shape changes is fine. */
    char big[8192];
    size_t n = (size_t)snprintf(big, sizeof big, "{\"lights\": {");
    for (int i = 0; i < PROTOCOL_MAX_SHAPE_CHANGES; i++)
        n += (size_t)snprintf(big + n, sizeof big - n, "%s\"s%d\": {\"emission\": [1, 1, 1]}", i ? ", " : "", i);
    snprintf(big + n, sizeof big - n, "}}");
    CHECK(protocol_parse_frame_request(big, strlen(big), &f, &err));
    CHECK(f.shape_count == PROTOCOL_MAX_SHAPE_CHANGES && strcmp(f.shapes[63].name, "s63") == 0);
}

static void test_render_valid(void)
{
    const char *body =
        "{\"animation\": {\"fps\": 24, \"frames\": 48, \"interpolation\": \"catmull_rom\","
        "  \"camera_keys\": [{\"t\": 0, \"position\": [0, 1, 5], \"look_at\": [0, 1, 0]},"
        "                   {\"t\": 1, \"fov_deg\": 30},"
        "                   {\"t\": 2.5, \"up\": [0, 0, 1], \"position\": [5, 1, 0]}],"
        "  \"light_keys\": {\"lamp\": [{\"t\": 0, \"emission\": [1, 2, 3]},"
        "                            {\"t\": 1, \"position\": [0, 2, 0]},"
        "                            {\"t\": 2, \"transform\": {\"scale\": [1, 1, 2]}, \"emission\": [0, 0, 0]}],"
        "                  \"ball\": [{\"t\": 0.5, \"position\": [1, 1, 1]}]}},"
        " \"reference\": \"ref-1\"}";
    struct protocol_render_request r;
    struct err err;
    CHECK_MSG(protocol_parse_render_request(body, strlen(body), &LIMITS, &r, &err), "%s: %s", err.where, err.message);
    CHECK(r.fps == 24.0 && r.frames == 48 && r.interp == ANIMATION_CATMULL_ROM);
    CHECK(strcmp(r.reference, "ref-1") == 0);
    CHECK(r.camera_key_count == 3);
    if (r.camera_key_count == 3) {
        CHECK(r.camera_keys[0].t_s == 0.0 && r.camera_keys[0].camera.has_position && r.camera_keys[0].camera.has_look_at &&
              !r.camera_keys[0].camera.has_up && !r.camera_keys[0].camera.has_fov_deg);
        CHECK(r.camera_keys[0].camera.position.z == 5.0f);
        CHECK(r.camera_keys[1].t_s == 1.0 && r.camera_keys[1].camera.has_fov_deg && r.camera_keys[1].camera.fov_deg == 30.0f &&
              !r.camera_keys[1].camera.has_position);
        CHECK(r.camera_keys[2].t_s == 2.5 && r.camera_keys[2].camera.up.z == 1.0f && r.camera_keys[2].camera.position.x == 5.0f);
    }
    CHECK(r.shape_track_count == 2);
    if (r.shape_track_count == 2) {
        const struct protocol_shape_track *lamp = &r.shape_tracks[0], *ball = &r.shape_tracks[1];
        CHECK(strcmp(lamp->name, "lamp") == 0 && lamp->key_count == 3);
        CHECK(lamp->keys[0].has_emission && !lamp->keys[0].has_position && lamp->keys[0].emission.z == 3.0f);
        CHECK(lamp->keys[1].t_s == 1.0 && lamp->keys[1].has_position && lamp->keys[1].position.y == 2.0f);
        CHECK(lamp->keys[2].has_transform && lamp->keys[2].has_emission && lamp->keys[2].transform.scale.z == 2.0f &&
              lamp->keys[2].emission.x == 0.0f);
        CHECK(strcmp(ball->name, "ball") == 0 && ball->key_count == 1 && ball->keys[0].t_s == 0.5);
    }
    protocol_render_request_destroy(&r);
    CHECK(r.camera_keys == NULL && r.shape_tracks == NULL);
    protocol_render_request_destroy(&r);  /* idempotent */

    /* Defaults: fps 30, linear, no keys, no reference. */
    body = "{\"animation\": {\"frames\": 100}}";
    CHECK(protocol_parse_render_request(body, strlen(body), &LIMITS, &r, &err));
    CHECK(r.fps == 30.0 && r.frames == 100 && r.interp == ANIMATION_LINEAR);
    CHECK(r.camera_key_count == 0 && r.camera_keys == NULL && r.shape_track_count == 0 && r.reference[0] == '\0');
    protocol_render_request_destroy(&r);
    body = "{\"animation\": {\"frames\": 2, \"fps\": 0.5, \"interpolation\": \"linear\", \"camera_keys\": []}}";
    CHECK(protocol_parse_render_request(body, strlen(body), &LIMITS, &r, &err));
    CHECK(r.fps == 0.5 && r.interp == ANIMATION_LINEAR && r.camera_key_count == 0);
    protocol_render_request_destroy(&r);
}

static void test_reference_valid(void)
{
    struct protocol_reference_request r = {0};
    struct err err;
    CHECK(protocol_parse_reference_request("{\"spp\": 16}", 11, &LIMITS, &r, &err) && r.spp == 16 &&
          r.method == PROTOCOL_REFERENCE_PT);
    CHECK(protocol_parse_reference_request("", 0, &LIMITS, &r, &err) && r.spp == 1024);
    CHECK(protocol_parse_reference_request("{}", 2, &LIMITS, &r, &err) && r.spp == 1024);
    CHECK(protocol_parse_reference_request("{\"spp\": 2048}", 13, &LIMITS, &r, &err) && r.spp == 2048);
    const char *sms = "{\"spp\": 64, \"method\": \"sms\"}";
    CHECK(protocol_parse_reference_request(sms, strlen(sms), &LIMITS, &r, &err) && r.spp == 64 &&
          r.method == PROTOCOL_REFERENCE_SMS && strcmp(protocol_reference_method_name(r.method), "sms") == 0);
    const char *pt = "{\"method\": \"pt\"}";
    CHECK(protocol_parse_reference_request(pt, strlen(pt), &LIMITS, &r, &err) && r.spp == 1024 &&
          r.method == PROTOCOL_REFERENCE_PT && strcmp(protocol_reference_method_name(r.method), "pt") == 0);
    const struct protocol_limits low = {.max_side = 64, .max_pixels = 4096, .max_spp = 512, .max_frames = 1, .max_keys = 1};
    r.spp = 7;
    CHECK(!protocol_parse_reference_request("", 0, &low, &r, &err) && r.spp == 7);
    CHECK(err.code == ERR_LIMIT && strcmp(err.where, "/spp") == 0 && strstr(err.message, "max_spp = 512"));
}

/* ---- the malformed table ---- */

struct bad_case {
    enum which which;
    const char *body;
    enum err_code code;
    const char *where;
    const char *msg;
};

#define AN "{\"animation\": {\"frames\": 10, "   /* an animation prefix */
#define CK AN "\"camera_keys\": "
#define LK AN "\"light_keys\": "

static const struct bad_case BAD[] = {
    /* not JSON */
    {SESSION, "{", ERR_PARSE, "", "byte 1"},
    {SESSION, "{\"width\": 64} x", ERR_PARSE, "", "byte 14"},
    {SESSION, "{\"width\": 64}{}", ERR_PARSE, "", "end of input after the JSON value"},
    {SESSION, "{\"width\": NaN}", ERR_PARSE, "", "byte 10"},
    {SESSION, "{\"width\": Infinity}", ERR_PARSE, "", "unexpected 'I'"},
    {SESSION, "{\"width\": -Infinity}", ERR_PARSE, "", "byte 11"},
    {SESSION, "{\"width\": 01}", ERR_PARSE, "", "leading zeros"},
    {SESSION, "{\"width\": 1.}", ERR_PARSE, "", "after '.'"},
    {SESSION, "{\"width\": .5}", ERR_PARSE, "", "byte 10"},
    {SESSION, "{\"width\": +5}", ERR_PARSE, "", "unexpected '+'"},
    {SESSION, "{\"width\": 64,}", ERR_PARSE, "", "starting a key"},
    {SESSION, "{'width': 64}", ERR_PARSE, "", "byte 1"},
    {SESSION, "{\"width\" 64}", ERR_PARSE, "", "expected ':'"},
    {SESSION, "{\"width\": 64 \"height\": 64}", ERR_PARSE, "", "expected ',' or '}'"},
    {SESSION, "{\"a\": [1 2]}", ERR_PARSE, "", "expected ',' or ']'"},
    {SESSION, "{\"a\": tru}", ERR_PARSE, "", "byte 9"},
    {SESSION, "{\"a\": \"x\x01y\"}", ERR_PARSE, "", "control characters"},
    {SESSION, "{\"a\": \"\\q\"}", ERR_PARSE, "", "expected an escape"},
    {SESSION, "{\"a\": \"\\u12g4\"}", ERR_PARSE, "", "4 hex digits"},
    {SESSION, "{\"a\": \"\\ud800\"}", ERR_PARSE, "", "high surrogate"},
    {SESSION, "{\"a\": \"\\udc00\"}", ERR_PARSE, "", "low surrogate"},
    {SESSION, "{\"method\": \"\xff\"}", ERR_PARSE, "", "UTF-8"},
    {SESSION, "{\"method\": \"\xc0\xaf\"}", ERR_PARSE, "", "UTF-8"},         /* overlong '/' */
    {SESSION, "{\"method\": \"\xed\xa0\x80\"}", ERR_PARSE, "", "UTF-8"},     /* encoded surrogate */
    {SESSION, "{\"a\": \"unterminated}", ERR_PARSE, "", "end of input"},
    {SESSION, "{\"a\\u0000b\": 1}", ERR_INVALID, "", "\\u0000"},
    {SESSION, "{\"width\": 1234567890123456789012345678901234567890123456789012345678901234567890}", ERR_PARSE, "",
     "more than the limit of 63"},
    {SESSION, "  ", ERR_PARSE, "", "end of input"},
    /* not an object */
    {SESSION, "[1, 2]", ERR_INVALID, "", "got an array"},
    {SESSION, "\"pt\"", ERR_INVALID, "", "got a string"},
    {FRAME, "null", ERR_INVALID, "", "got null"},
    {REFERENCE, "42", ERR_INVALID, "", "got a number"},
    /* session: types, ranges, limits, keys */
    {SESSION, "{\"width\": \"64\"}", ERR_INVALID, "/width", "expected a number, got a string"},
    {SESSION, "{\"width\": true}", ERR_INVALID, "/width", "got a boolean"},
    {SESSION, "{\"width\": null}", ERR_INVALID, "/width", "got null"},
    {SESSION, "{\"width\": 1e999}", ERR_INVALID, "/width", "finite"},
    {SESSION, "{\"width\": -5}", ERR_INVALID, "/width", "must be >= 1, got -5"},
    {SESSION, "{\"width\": 0}", ERR_INVALID, "/width", "must be >= 1"},
    {SESSION, "{\"height\": -0.0}", ERR_INVALID, "/height", "must be >= 1"},
    {SESSION, "{\"width\": 100000}", ERR_LIMIT, "/width", "max_side = 4096"},
    {SESSION, "{\"height\": 1e300}", ERR_LIMIT, "/height", "max_side = 4096"},
    {SESSION, "{\"width\": 64.5}", ERR_INVALID, "/width", "expected an integer, got 64.5"},
    {SESSION, "{\"width\": 4096, \"height\": 4096}", ERR_LIMIT, "", "max_pixels = 8388608"},
    {SESSION, "{\"seed\": 9007199254740994}", ERR_INVALID, "/seed", "<= 9007199254740992"},
    {SESSION, "{\"seed\": -1}", ERR_INVALID, "/seed", ">= 0"},
    {SESSION, "{\"seed\": 0.5}", ERR_INVALID, "/seed", "integer"},
    {SESSION, "{\"method\": \"restir\"}", ERR_INVALID, "/method", "known methods: pt"},
    {SESSION, "{\"method\": \"PT\"}", ERR_INVALID, "/method", "unknown method"},
    {SESSION, "{\"method\": 1}", ERR_INVALID, "/method", "expected a string, got a number"},
    {SESSION, "{\"colour\": 1}", ERR_INVALID, "/colour", "unknown key"},
    {SESSION, "{\"Width\": 64}", ERR_INVALID, "/Width", "unknown key"},
    {SESSION, "{\"a/b~\": 1}", ERR_INVALID, "/a~1b~0", "unknown key"},
    {SESSION, "{\"width\": 64, \"width\": 64}", ERR_INVALID, "/width", "duplicate key"},
    {SESSION, "{\"params\": []}", ERR_INVALID, "/params", "got an array"},
    {SESSION, "{\"params\": {\"spp\": 4, \"bounces\": 3}}", ERR_INVALID, "/params/bounces", "unknown key"},
    {SESSION, "{\"params\": {\"spp\": 4, \"spp\": 4}}", ERR_INVALID, "/params/spp", "duplicate key"},
    {SESSION, "{\"params\": {\"spp\": 5000}}", ERR_LIMIT, "/params/spp", "max_spp = 2048"},
    {SESSION, "{\"params\": {\"spp\": 0}}", ERR_INVALID, "/params/spp", ">= 1"},
    {SESSION, "{\"params\": {\"max_depth\": 1025}}", ERR_INVALID, "/params/max_depth", "<= 1024"},
    {SESSION, "{\"params\": {\"rr_depth\": -1}}", ERR_INVALID, "/params/rr_depth", ">= 0"},
    {SESSION, "{\"params\": {\"nee\": 1}}", ERR_INVALID, "/params/nee", "expected true or false"},
    /* frame request */
    {FRAME, "{\"camera\": []}", ERR_INVALID, "/camera", "expected a camera object"},
    {FRAME, "{\"camera\": {\"zoom\": 2}}", ERR_INVALID, "/camera/zoom", "unknown key"},
    {FRAME, "{\"camera\": {\"fov_deg\": 180}}", ERR_INVALID, "/camera/fov_deg", "(0, 180)"},
    {FRAME, "{\"camera\": {\"fov_deg\": 0}}", ERR_INVALID, "/camera/fov_deg", "(0, 180)"},
    {FRAME, "{\"camera\": {\"up\": [0, 0, 0]}}", ERR_INVALID, "/camera/up", "non-zero"},
    {FRAME, "{\"camera\": {\"position\": [1, 2, 3], \"look_at\": [1, 2, 3]}}", ERR_INVALID, "/camera/look_at", "differ"},
    {FRAME, "{\"camera\": {\"position\": [0, 0, 1], \"look_at\": [0, 0, 0], \"up\": [0, 0, 2]}}", ERR_INVALID, "/camera/up",
     "parallel"},
    {FRAME, "{\"camera\": {\"position\": [1, 2]}}", ERR_INVALID, "/camera/position", "got 2 elements"},
    {FRAME, "{\"camera\": {\"position\": [1, 2, 3, 4]}}", ERR_INVALID, "/camera/position", "got 4 elements"},
    {FRAME, "{\"camera\": {\"position\": [1, 2, \"3\"]}}", ERR_INVALID, "/camera/position/2", "expected a number, got a string"},
    {FRAME, "{\"camera\": {\"position\": [1e39, 0, 0]}}", ERR_INVALID, "/camera/position/0", "32-bit float"},
    {FRAME, "{\"camera\": {\"look_at\": [0, -1e999, 0]}}", ERR_INVALID, "/camera/look_at/1", "finite"},
    {FRAME, "{\"time_s\": -1}", ERR_INVALID, "/time_s", ">= 0"},
    {FRAME, "{\"time_s\": \"now\"}", ERR_INVALID, "/time_s", "expected a number"},
    {FRAME, "{\"lights\": []}", ERR_INVALID, "/lights", "expected a lights object"},
    {FRAME, "{\"lights\": {\"bad name\": {\"emission\": [1, 1, 1]}}}", ERR_INVALID, "/lights/bad name", "invalid name"},
    {FRAME, "{\"lights\": {\"a/b\": {\"emission\": [1, 1, 1]}}}", ERR_INVALID, "/lights/a~1b", "invalid name"},
    {FRAME, "{\"lights\": {\"\": {\"emission\": [1, 1, 1]}}}", ERR_INVALID, "/lights/", "invalid name"},
    {FRAME, "{\"lights\": {\"lamp\": {\"emission\": [1, 1, 1]}, \"lamp\": {\"emission\": [1, 1, 1]}}}", ERR_INVALID,
     "/lights/lamp", "duplicate key"},
    {FRAME, "{\"lights\": {\"lamp\": 3}}", ERR_INVALID, "/lights/lamp", "expected a shape change object"},
    {FRAME, "{\"lights\": {\"lamp\": {}}}", ERR_INVALID, "/lights/lamp", "no channel"},
    {FRAME, "{\"lights\": {\"lamp\": {\"glow\": 1}}}", ERR_INVALID, "/lights/lamp/glow", "unknown key"},
    {FRAME, "{\"lights\": {\"lamp\": {\"position\": [0, 0, 0], \"transform\": {}}}}", ERR_INVALID, "/lights/lamp",
     "either position or transform, not both"},
    {FRAME, "{\"lights\": {\"lamp\": {\"emission\": [1, -1, 1]}}}", ERR_INVALID, "/lights/lamp/emission/1", "must be >= 0"},
    {FRAME, "{\"lights\": {\"lamp\": {\"transform\": {\"scale\": 0}}}}", ERR_INVALID, "/lights/lamp/transform/scale",
     "scale must be > 0"},
    {FRAME, "{\"lights\": {\"lamp\": {\"transform\": {\"scale\": [1, 0, 1]}}}}", ERR_INVALID,
     "/lights/lamp/transform/scale/1", "scale must be > 0"},
    {FRAME, "{\"lights\": {\"lamp\": {\"transform\": {\"scale\": [1, 1, -2]}}}}", ERR_INVALID,
     "/lights/lamp/transform/scale/2", "mirroring"},
    {FRAME, "{\"lights\": {\"lamp\": {\"transform\": {\"scale\": \"big\"}}}}", ERR_INVALID, "/lights/lamp/transform/scale",
     "a number or an array of 3 numbers"},
    {FRAME, "{\"lights\": {\"lamp\": {\"transform\": {\"skew\": 1}}}}", ERR_INVALID, "/lights/lamp/transform/skew",
     "unknown key"},
    /* render request */
    {RENDER, "{}", ERR_INVALID, "/animation", "missing required key"},
    {RENDER, "", ERR_INVALID, "/animation", "missing required key"},
    {RENDER, "{\"animation\": 5}", ERR_INVALID, "/animation", "expected an animation object"},
    {RENDER, "{\"animation\": {}}", ERR_INVALID, "/animation/frames", "missing required key"},
    {RENDER, "{\"animation\": {\"frames\": 0}}", ERR_INVALID, "/animation/frames", ">= 1"},
    {RENDER, "{\"animation\": {\"frames\": 101}}", ERR_LIMIT, "/animation/frames", "max_frames = 100"},
    {RENDER, "{\"animation\": {\"frames\": 2.5}}", ERR_INVALID, "/animation/frames", "integer"},
    {RENDER, AN "\"fps\": 0}}", ERR_INVALID, "/animation/fps", "must be > 0"},
    {RENDER, AN "\"fps\": -30}}", ERR_INVALID, "/animation/fps", "must be > 0"},
    {RENDER, AN "\"fps\": 1e999}}", ERR_INVALID, "/animation/fps", "finite"},
    {RENDER, AN "\"interpolation\": \"cubic\"}}", ERR_INVALID, "/animation/interpolation", "linear or catmull_rom"},
    {RENDER, AN "\"interpolation\": 1}}", ERR_INVALID, "/animation/interpolation", "expected a string"},
    {RENDER, AN "\"loop\": true}}", ERR_INVALID, "/animation/loop", "unknown key"},
    {RENDER, "{\"animation\": {\"frames\": 10}, \"extra\": 1}", ERR_INVALID, "/extra", "unknown key"},
    {RENDER, CK "{}}}", ERR_INVALID, "/animation/camera_keys", "expected an array of camera keys"},
    {RENDER, CK "[{\"t\": 1, \"fov_deg\": 40}, {\"t\": 0.5, \"fov_deg\": 50}]}}", ERR_INVALID, "/animation/camera_keys/1/t",
     "strictly increasing"},
    {RENDER, CK "[{\"t\": 0, \"fov_deg\": 40}, {\"t\": 1, \"fov_deg\": 50}, {\"t\": 1, \"fov_deg\": 60}]}}", ERR_INVALID,
     "/animation/camera_keys/2/t", "strictly increasing"},
    {RENDER, CK "[{\"t\": 0}]}}", ERR_INVALID, "/animation/camera_keys/0", "no channel"},
    {RENDER, CK "[{\"fov_deg\": 40}]}}", ERR_INVALID, "/animation/camera_keys/0/t", "missing required key"},
    {RENDER, CK "[{\"t\": -1, \"fov_deg\": 40}]}}", ERR_INVALID, "/animation/camera_keys/0/t", ">= 0"},
    {RENDER, CK "[{\"t\": 0, \"fov_deg\": 40, \"roll\": 1}]}}", ERR_INVALID, "/animation/camera_keys/0/roll", "unknown key"},
    {RENDER, CK "[{\"t\": 0, \"up\": [0, 0, 0]}]}}", ERR_INVALID, "/animation/camera_keys/0/up", "non-zero"},
    {RENDER, CK "[{\"t\": 0, \"position\": [0, 0, 0], \"look_at\": [0, 0, 0]}]}}", ERR_INVALID,
     "/animation/camera_keys/0/look_at", "differ"},
    {RENDER, CK "[1, 2, 3, 4, 5]}}", ERR_LIMIT, "/animation/camera_keys", "max_keys = 4"},
    {RENDER, LK "[]}}", ERR_INVALID, "/animation/light_keys", "expected a light_keys object"},
    {RENDER, LK "{\"x y\": [{\"t\": 0, \"emission\": [1, 1, 1]}]}}}", ERR_INVALID, "/animation/light_keys/x y",
     "invalid name"},
    {RENDER, LK "{\"lamp\": []}}}", ERR_INVALID, "/animation/light_keys/lamp", "at least one key"},
    {RENDER, LK "{\"lamp\": {}}}}", ERR_INVALID, "/animation/light_keys/lamp", "expected an array of shape keys"},
    {RENDER, LK "{\"lamp\": [{\"t\": 0, \"position\": [0, 0, 0], \"transform\": {}}]}}}", ERR_INVALID,
     "/animation/light_keys/lamp/0", "not both"},
    {RENDER, LK "{\"lamp\": [{\"t\": 0}]}}}", ERR_INVALID, "/animation/light_keys/lamp/0", "no channel"},
    {RENDER, LK "{\"lamp\": [{\"t\": 0, \"emission\": [-1, 0, 0]}]}}}", ERR_INVALID,
     "/animation/light_keys/lamp/0/emission/0", "must be >= 0"},
    {RENDER, LK "{\"lamp\": [{\"t\": 0, \"emission\": [1, 1, 1]}, {\"t\": 0, \"emission\": [2, 2, 2]}]}}}", ERR_INVALID,
     "/animation/light_keys/lamp/1/t", "strictly increasing"},
    {RENDER, LK "{\"lamp\": [{\"t\": 0, \"transform\": {\"scale\": 0}}]}}}", ERR_INVALID,
     "/animation/light_keys/lamp/0/transform/scale", "scale must be > 0"},
    {RENDER, LK "{\"lamp\": [1, 2, 3, 4, 5]}}}", ERR_LIMIT, "/animation/light_keys/lamp", "max_keys = 4"},
    {RENDER, LK "{\"a\": [{\"t\": 0, \"emission\": [1, 1, 1]}], \"a\": [{\"t\": 0, \"emission\": [1, 1, 1]}]}}}",
     ERR_INVALID, "/animation/light_keys/a", "duplicate key"},
    {RENDER, "{\"animation\": {\"frames\": 10}, \"reference\": \"a b\"}", ERR_INVALID, "/reference", "invalid id"},
    {RENDER, "{\"animation\": {\"frames\": 10}, \"reference\": 7}", ERR_INVALID, "/reference", "expected a string"},
    {RENDER, "{\"animation\": {\"frames\": 10}, \"reference\": "
             "\"x1234567890123456789012345678901234567890123456789012345678901234\"}",
     ERR_INVALID, "/reference", "invalid id"},
    /* reference request */
    {REFERENCE, "{\"spp\": 0}", ERR_INVALID, "/spp", ">= 1"},
    {REFERENCE, "{\"spp\": 4096}", ERR_LIMIT, "/spp", "max_spp = 2048"},
    {REFERENCE, "{\"spp\": 2.5}", ERR_INVALID, "/spp", "expected an integer"},
    {REFERENCE, "{\"spp\": \"64\"}", ERR_INVALID, "/spp", "expected a number, got a string"},
    {REFERENCE, "{\"samples\": 4}", ERR_INVALID, "/samples", "unknown key"},
    {REFERENCE, "{\"method\": \"bdpt\"}", ERR_INVALID, "/method", "unknown reference method \"bdpt\" (known: pt, sms)"},
    {REFERENCE, "{\"method\": 1}", ERR_INVALID, "/method", "expected a string, got a number"},
    {REFERENCE, "{\"spp\": 4", ERR_PARSE, "", "end of input"},
};

static void test_malformed_table(void)
{
    int n = (int)(sizeof BAD / sizeof BAD[0]);
    CHECK(n >= 40);
    for (int i = 0; i < n; i++) expect_fail(BAD[i].which, BAD[i].body, BAD[i].code, BAD[i].where, BAD[i].msg);
    printf("     (%d malformed bodies)\n", n);
}

/* Bodies that are built, not written out: sizes, NUL bytes, depth. */
static void test_malformed_built(void)
{
    /* A NUL byte inside the length is a syntax error, not the end of the body. */
    expect_fail_len(SESSION, "{\0}", 3, ERR_PARSE, "", "byte 1");
    expect_fail_len(SESSION, "{\"method\": \"p\0t\"}", 17, ERR_PARSE, "", "control characters");
    /* A NULL body with a length. */
    expect_fail_len(FRAME, NULL, 4, ERR_INVALID, "", "no body");

    /* 1000 '[': refused by the gate before any parser recursion. */
    static char deep[2048];
    memset(deep, '[', 1000);
    memset(deep + 1000, ']', 1000);
    expect_fail_len(SESSION, deep, 2000, ERR_PARSE, "", "nested deeper than 16 levels at byte 16");
    /* Exactly PROTOCOL_MAX_DEPTH levels pass the gate (and then fail as a non-object body);
     * one more is refused. */
    char d16[64], d17[64];
    snprintf(d16, sizeof d16, "%.*s%.*s", PROTOCOL_MAX_DEPTH, deep, PROTOCOL_MAX_DEPTH, deep + 1000);
    snprintf(d17, sizeof d17, "%.*s%.*s", PROTOCOL_MAX_DEPTH + 1, deep, PROTOCOL_MAX_DEPTH + 1, deep + 1000);
    expect_fail(SESSION, d16, ERR_INVALID, "", "got an array");
    expect_fail(SESSION, d17, ERR_PARSE, "", "nested deeper");
    /* Depth inside an object, with the nesting hidden in an unknown key's value. */
    expect_fail(FRAME, "{\"x\": [[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]}", ERR_PARSE, "", "nested deeper");
    /* Brackets inside strings do not count. */
    expect_fail(SESSION, "{\"method\": \"[[[[[[[[[[[[[[[[[[[[[[[[\"}", ERR_INVALID, "/method", "unknown method");

    /* One shape change over the limit. */
    char big[8192];
    size_t n = (size_t)snprintf(big, sizeof big, "{\"lights\": {");
    for (int i = 0; i <= PROTOCOL_MAX_SHAPE_CHANGES; i++)
        n += (size_t)snprintf(big + n, sizeof big - n, "%s\"s%d\": {\"emission\": [1, 1, 1]}", i ? ", " : "", i);
    snprintf(big + n, sizeof big - n, "}}");
    expect_fail(FRAME, big, ERR_LIMIT, "/lights", "limit of 64");

    /* A long unknown key: the pointer is cut at a character boundary, never overrun. */
    char longkey[1200];
    n = (size_t)snprintf(longkey, sizeof longkey, "{\"");
    for (int i = 0; i < 400; i++) n += (size_t)snprintf(longkey + n, sizeof longkey - n, "\xc3\xa9");
    snprintf(longkey + n, sizeof longkey - n, "\": 1}");
    struct err err;
    CHECK(!parse_one(SESSION, longkey, strlen(longkey), &err));
    CHECK(err.code == ERR_INVALID && strlen(err.where) < sizeof err.where && strlen(err.where) % 2 == 1);
}

/* A failed render parse frees what it had allocated (LeakSanitizer checks) and leaves the
 * request empty, so the caller's destroy is harmless. */
static void test_render_failure_frees(void)
{
    const char *body = "{\"animation\": {\"frames\": 10, \"camera_keys\": [{\"t\": 0, \"fov_deg\": 40}],"
                       " \"light_keys\": {\"a\": [{\"t\": 0, \"emission\": [1, 1, 1]}], \"b\": [{\"t\": 0}]}}}";
    struct protocol_render_request r;
    struct err err;
    CHECK(!protocol_parse_render_request(body, strlen(body), &LIMITS, &r, &err));
    CHECK(strcmp(err.where, "/animation/light_keys/b/0") == 0);
    CHECK(r.camera_keys == NULL && r.shape_tracks == NULL && r.camera_key_count == 0 && r.shape_track_count == 0);
    protocol_render_request_destroy(&r);
}

/* Every truncation and many single-byte mutations of valid bodies: each parser either accepts
 * or fails with a code and a pointer, never crashes (ASan), never leaks (LSan), and never
 * reports ERR_NOMEM — which would mean cJSON refused text the strict gate accepted. */
static void test_mutations_never_crash(void)
{
    static const char *const bodies[] = {
        "{\"method\": \"pt\", \"width\": 64, \"height\": 32, \"seed\": 7, \"params\": {\"spp\": 2, \"nee\": true}}",
        "{\"camera\": {\"position\": [0, 1, 5], \"fov_deg\": 40}, \"lights\": {\"lamp\": {\"transform\": "
        "{\"scale\": [1, 2, 3]}, \"emission\": [1e1, 0.5, 2E-3]}}, \"time_s\": 1.5}",
        "{\"animation\": {\"frames\": 3, \"camera_keys\": [{\"t\": 0, \"up\": [0, 1, 0]}], \"light_keys\": "
        "{\"a\": [{\"t\": 0, \"position\": [1, 2, 3]}]}}, \"reference\": \"r\\u0041\"}",
        "{\"spp\": 64, \"x\\ud83d\\ude00\": \"\\u00e9\\n\"}",
    };
    static const unsigned char subst[] = {'\0', '"', '\\', '{', '}', '[', ']', ':', ',', '0', '-', 'e', '.', ' ', 0x80, 0xff};
    char buf[512];
    long runs = 0;
    for (size_t b = 0; b < sizeof bodies / sizeof bodies[0]; b++) {
        size_t len = strlen(bodies[b]);
        for (size_t cut = 0; cut <= len; cut++) {
            for (int w = SESSION; w <= REFERENCE; w++) {
                struct err err;
                memcpy(buf, bodies[b], cut);
                if (!parse_one((enum which)w, buf, cut, &err))
                    CHECK_MSG(err.code != ERR_NONE && err.code != ERR_NOMEM, "cut %zu: %s", cut, err.message);
                runs++;
            }
        }
        for (size_t i = 0; i < len; i++) {
            for (size_t k = 0; k < sizeof subst; k++) {
                memcpy(buf, bodies[b], len);
                buf[i] = (char)subst[k];
                for (int w = SESSION; w <= REFERENCE; w++) {
                    struct err err;
                    if (!parse_one((enum which)w, buf, len, &err))
                        CHECK_MSG(err.code != ERR_NONE && err.code != ERR_NOMEM, "byte %zu = 0x%02x: %s", i, subst[k],
                                  err.message);
                    runs++;
                }
            }
        }
    }
    CHECK(runs > 1000);
}

/* ---- the writer ---- */

static void test_jsonw_round_trip(void)
{
    static const char tricky[] = "quote\" back\\ slash/ nl\n tab\t cr\r ctrl\x01\x1f del\x7f e\xc3\xa9 \xe2\x82\xac \xf0\x9f\x98\x80";
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "s");
    jsonw_string(&w, tricky);
    jsonw_key(&w, "key \"with\" quotes");
    jsonw_int(&w, -7);
    jsonw_key(&w, "d");
    jsonw_double(&w, 0.1);
    jsonw_key(&w, "pi");
    jsonw_double(&w, 3.141592653589793);
    jsonw_key(&w, "third");
    jsonw_double(&w, 1.0 / 3.0);
    jsonw_key(&w, "tiny");
    jsonw_double(&w, 5e-324);
    jsonw_key(&w, "huge");
    jsonw_double(&w, 1.7976931348623157e308);
    jsonw_key(&w, "neg");
    jsonw_double(&w, -2.5e-7);
    jsonw_key(&w, "nan");
    jsonw_double(&w, NAN);
    jsonw_key(&w, "inf");
    jsonw_double(&w, -INFINITY);
    jsonw_key(&w, "u");
    jsonw_uint(&w, 9007199254740993ull);
    jsonw_key(&w, "i");
    jsonw_int(&w, INT64_MIN);
    jsonw_key(&w, "t");
    jsonw_bool(&w, true);
    jsonw_key(&w, "f");
    jsonw_bool(&w, false);
    jsonw_key(&w, "n");
    jsonw_null(&w);
    jsonw_key(&w, "nulls");
    jsonw_string(&w, NULL);
    jsonw_key(&w, "arr");
    jsonw_array_begin(&w);
    jsonw_uint(&w, 1);
    jsonw_array_begin(&w);
    jsonw_array_end(&w);
    jsonw_object_begin(&w);
    jsonw_object_end(&w);
    jsonw_string(&w, "x");
    jsonw_array_end(&w);
    jsonw_key(&w, "bad");
    jsonw_string(&w, "a\xff" "b\xc3");
    jsonw_object_end(&w);
    size_t len = 0;
    char *text = jsonw_finish(&w, &len);
    CHECK(text != NULL);
    if (!text) return;
    CHECK(len == strlen(text));
    /* Control characters as \u00XX; the doubles' shortest round-trip forms. */
    CHECK(strstr(text, "nl\\u000a tab\\u0009 cr\\u000d ctrl\\u0001\\u001f del\x7f") != NULL);
    CHECK(strstr(text, "\"d\":0.1,") != NULL);
    CHECK(strstr(text, "\"nan\":null,\"inf\":null,") != NULL);
    CHECK(strstr(text, "\"u\":9007199254740993,") != NULL);
    CHECK(strstr(text, "\"i\":-9223372036854775808,") != NULL);
    CHECK(strstr(text, "\"arr\":[1,[],{},\"x\"]") != NULL);

    cJSON *root = cJSON_ParseWithLength(text, len);
    CHECK_MSG(root != NULL, "writer output is not JSON: %s", text);
    if (root) {
        const cJSON *v = cJSON_GetObjectItemCaseSensitive(root, "s");
        CHECK(cJSON_IsString(v) && strcmp(v->valuestring, tricky) == 0);
        v = cJSON_GetObjectItemCaseSensitive(root, "key \"with\" quotes");
        CHECK(cJSON_IsNumber(v) && v->valuedouble == -7.0);
        static const struct { const char *key; double value; } nums[] = {
            {"d", 0.1}, {"pi", 3.141592653589793}, {"third", 1.0 / 3.0}, {"tiny", 5e-324},
            {"huge", 1.7976931348623157e308}, {"neg", -2.5e-7},
        };
        for (size_t k = 0; k < sizeof nums / sizeof nums[0]; k++) {
            v = cJSON_GetObjectItemCaseSensitive(root, nums[k].key);
            CHECK_MSG(cJSON_IsNumber(v) && v->valuedouble == nums[k].value, "%s", nums[k].key);
        }
        CHECK(cJSON_IsNull(cJSON_GetObjectItemCaseSensitive(root, "nan")));
        CHECK(cJSON_IsNull(cJSON_GetObjectItemCaseSensitive(root, "inf")));
        CHECK(cJSON_IsNull(cJSON_GetObjectItemCaseSensitive(root, "nulls")));
        CHECK(cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(root, "t")));
        CHECK(cJSON_IsFalse(cJSON_GetObjectItemCaseSensitive(root, "f")));
        const cJSON *arr = cJSON_GetObjectItemCaseSensitive(root, "arr");
        CHECK(cJSON_IsArray(arr) && cJSON_GetArraySize(arr) == 4);
        /* Bytes that are not UTF-8 become U+FFFD, so the text stays valid. */
        v = cJSON_GetObjectItemCaseSensitive(root, "bad");
        CHECK(cJSON_IsString(v) && strcmp(v->valuestring, "a\xef\xbf\xbd" "b\xef\xbf\xbd") == 0);
        cJSON_Delete(root);
    }
    free(text);

    /* Every double written is read back exactly. */
    const double samples[] = {0.0, -0.0, 1.0, 1e-300, 123456789.123456789, 2.2250738585072014e-308, 0.30000000000000004, 1e21, 4.35e-5};
    for (size_t k = 0; k < sizeof samples / sizeof samples[0]; k++) {
        jsonw_init(&w);
        jsonw_double(&w, samples[k]);
        char *t = jsonw_finish(&w, NULL);
        CHECK(t != NULL);
        if (!t) continue;
        cJSON *v = cJSON_Parse(t);
        CHECK_MSG(v && cJSON_IsNumber(v) && v->valuedouble == samples[k] && signbit(v->valuedouble) == signbit(samples[k]),
                  "%.17g -> %s", samples[k], t);
        cJSON_Delete(v);
        free(t);
    }
}

static void test_jsonw_failures(void)
{
    struct jsonw w;
    /* Nesting deeper than PROTOCOL_MAX_DEPTH fails the whole text. */
    jsonw_init(&w);
    for (int i = 0; i < PROTOCOL_MAX_DEPTH; i++) jsonw_array_begin(&w);
    for (int i = 0; i < PROTOCOL_MAX_DEPTH; i++) jsonw_array_end(&w);
    char *t = jsonw_finish(&w, NULL);
    CHECK(t != NULL);
    free(t);
    jsonw_init(&w);
    for (int i = 0; i <= PROTOCOL_MAX_DEPTH; i++) jsonw_array_begin(&w);
    for (int i = 0; i <= PROTOCOL_MAX_DEPTH; i++) jsonw_array_end(&w);
    size_t len = 99;
    CHECK(jsonw_finish(&w, &len) == NULL && len == 0);
    /* An unclosed container, a stray close, an empty writer. */
    jsonw_init(&w);
    jsonw_object_begin(&w);
    CHECK(jsonw_finish(&w, NULL) == NULL);
    jsonw_init(&w);
    jsonw_array_end(&w);
    CHECK(jsonw_finish(&w, NULL) == NULL);
    jsonw_init(&w);
    CHECK(jsonw_finish(&w, NULL) == NULL);
    /* Discarding an unfinished text, twice. */
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "a");
    jsonw_destroy(&w);
    jsonw_destroy(&w);
    /* A long text grows the buffer. */
    jsonw_init(&w);
    jsonw_array_begin(&w);
    for (int i = 0; i < 10000; i++) jsonw_uint(&w, (uint64_t)i);
    jsonw_array_end(&w);
    t = jsonw_finish(&w, &len);
    CHECK(t != NULL);
    if (t) {
        cJSON *v = cJSON_ParseWithLength(t, len);
        CHECK(cJSON_IsArray(v) && cJSON_GetArraySize(v) == 10000);
        cJSON_Delete(v);
        free(t);
    }
}

static void test_problem_json(void)
{
    const struct protocol_problem p = {
        .status = 413, .slug = "limit-exceeded", .title = "Over a limit",
        .detail = "100000 is over the limit max_side = \"4096\"\n", .instance = "/v1/scenes/cb/sessions",
        .field = "/width", .has_limit = true, .limit = 4096,
    };
    size_t len = 0;
    char *text = protocol_problem_json(&p, &len);
    CHECK(text != NULL && len == strlen(text));
    if (!text) return;
    CHECK(strstr(text, "\"limit\":4096") != NULL);
    cJSON *root = cJSON_ParseWithLength(text, len);
    CHECK(cJSON_IsObject(root));
    if (root) {
        const cJSON *v = cJSON_GetObjectItemCaseSensitive(root, "type");
        CHECK(cJSON_IsString(v) && strcmp(v->valuestring, "urn:restird:problem:limit-exceeded") == 0);
        v = cJSON_GetObjectItemCaseSensitive(root, "title");
        CHECK(cJSON_IsString(v) && strcmp(v->valuestring, "Over a limit") == 0);
        v = cJSON_GetObjectItemCaseSensitive(root, "status");
        CHECK(cJSON_IsNumber(v) && v->valuedouble == 413.0);
        v = cJSON_GetObjectItemCaseSensitive(root, "detail");
        CHECK(cJSON_IsString(v) && strcmp(v->valuestring, p.detail) == 0);
        v = cJSON_GetObjectItemCaseSensitive(root, "instance");
        CHECK(cJSON_IsString(v) && strcmp(v->valuestring, p.instance) == 0);
        v = cJSON_GetObjectItemCaseSensitive(root, "field");
        CHECK(cJSON_IsString(v) && strcmp(v->valuestring, "/width") == 0);
        v = cJSON_GetObjectItemCaseSensitive(root, "limit");
        CHECK(cJSON_IsNumber(v) && v->valuedouble == 4096.0);
        CHECK(cJSON_GetArraySize(root) == 7);
        cJSON_Delete(root);
    }
    free(text);

    /* field "" is the pointer to the whole body and is written; no limit, no "limit". */
    const struct protocol_problem q = {
        .status = 400, .slug = "malformed-json", .title = "Malformed JSON",
        .detail = "JSON syntax error at byte 1", .instance = "/v1/x", .field = "",
    };
    text = protocol_problem_json(&q, &len);
    CHECK(text != NULL);
    if (!text) return;
    root = cJSON_ParseWithLength(text, len);
    CHECK(cJSON_IsObject(root) && cJSON_GetArraySize(root) == 6);
    const cJSON *fv = cJSON_GetObjectItemCaseSensitive(root, "field");
    CHECK(cJSON_IsString(fv) && strcmp(fv->valuestring, "") == 0);
    CHECK(!cJSON_GetObjectItemCaseSensitive(root, "limit"));
    cJSON_Delete(root);
    free(text);

    /* field NULL: no "field" member at all (the problem is not about one member). */
    const struct protocol_problem nf = {
        .status = 404, .slug = "not-found", .title = "Not found", .detail = "no such session",
        .instance = "/v1/x", .field = NULL,
    };
    text = protocol_problem_json(&nf, &len);
    CHECK(text != NULL);
    if (!text) return;
    root = cJSON_ParseWithLength(text, len);
    CHECK(cJSON_IsObject(root) && cJSON_GetArraySize(root) == 5);
    CHECK(!cJSON_GetObjectItemCaseSensitive(root, "field") && !cJSON_GetObjectItemCaseSensitive(root, "limit"));
    const cJSON *st = cJSON_GetObjectItemCaseSensitive(root, "status");
    CHECK(cJSON_IsNumber(st) && st->valuedouble == 404.0);
    cJSON_Delete(root);
    free(text);

    /* A parser error carried all the way into a problem body stays valid JSON. */
    struct err err;
    static const char key_body[] = "{\"\xc3\xa9t\xc3\xa9\\n\": 1}";
    CHECK(!parse_one(SESSION, key_body, strlen(key_body), &err));
    const struct protocol_problem r = {.status = 422, .slug = "invalid-field", .title = "Invalid field",
                                       .detail = err.message, .instance = "/", .field = err.where};
    text = protocol_problem_json(&r, &len);
    root = text ? cJSON_ParseWithLength(text, len) : NULL;
    const cJSON *f = cJSON_GetObjectItemCaseSensitive(root, "field");
    CHECK(cJSON_IsString(f) && strcmp(f->valuestring, "/\xc3\xa9t\xc3\xa9\n") == 0);
    cJSON_Delete(root);
    free(text);
}

TEST_MAIN(TEST(test_valid_id), TEST(test_pointer_key), TEST(test_session_valid), TEST(test_session_profile),
          TEST(test_method_params_alone),
          TEST(test_frame_valid),
          TEST(test_render_valid), TEST(test_reference_valid), TEST(test_malformed_table), TEST(test_malformed_built),
          TEST(test_render_failure_frees), TEST(test_mutations_never_crash),
          TEST(test_jsonw_round_trip), TEST(test_jsonw_failures),
          TEST(test_problem_json))
