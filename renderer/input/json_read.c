/* json_read.c — strict reading of untrusted JSON (json_read.h). */
#include "input/json_read.h"

#include <stdint.h>
#include <stdio.h>
#include <string.h>

size_t json_utf8_seq(const unsigned char *s, size_t n)
{
    unsigned char c = s[0];
    if (c < 0x80) return 1;
    size_t len;
    unsigned char lo = 0x80, hi = 0xbf;
    if (c >= 0xc2 && c <= 0xdf) len = 2;
    else if (c == 0xe0) { len = 3; lo = 0xa0; }
    else if (c == 0xed) { len = 3; hi = 0x9f; }
    else if (c >= 0xe1 && c <= 0xef) len = 3;
    else if (c == 0xf0) { len = 4; lo = 0x90; }
    else if (c == 0xf4) { len = 4; hi = 0x8f; }
    else if (c >= 0xf1 && c <= 0xf3) len = 4;
    else return 0;
    if (n < len || s[1] < lo || s[1] > hi) return 0;
    for (size_t i = 2; i < len; i++)
        if (s[i] < 0x80 || s[i] > 0xbf) return 0;
    return len;
}

void json_pointer_key(char *out, size_t size, const char *base, const char *key)
{
    if (!out || size == 0) return;
    size_t n = 0;
    const char *parts[2] = {base ? base : "", key ? key : ""};
    for (int part = 0; part < 2; part++) {
        if (part == 1) {
            if (n + 1 >= size) break;
            out[n++] = '/';
        }
        const unsigned char *s = (const unsigned char *)parts[part];
        size_t avail = strlen(parts[part]);
        bool full = false;
        for (size_t i = 0; i < avail && !full;) {
            char esc[2];
            const char *unit = (const char *)s + i;
            size_t ulen = json_utf8_seq(s + i, avail - i);
            if (ulen == 0) ulen = 1;
            if (part == 1 && (s[i] == '~' || s[i] == '/')) {
                esc[0] = '~';
                esc[1] = s[i] == '~' ? '0' : '1';
                unit = esc;
                ulen = 2;
                i++;
            } else {
                i += ulen;
            }
            if (n + ulen >= size) { full = true; break; }
            memcpy(out + n, unit, ulen);
            n += ulen;
        }
        if (full) break;
    }
    out[n] = '\0';
}

const char *json_type_name(const cJSON *v)
{
    if (cJSON_IsNull(v)) return "null";
    if (cJSON_IsBool(v)) return "a boolean";
    if (cJSON_IsNumber(v)) return "a number";
    if (cJSON_IsString(v)) return "a string";
    if (cJSON_IsArray(v)) return "an array";
    if (cJSON_IsObject(v)) return "an object";
    return "an invalid value";
}

bool json_check_keys(const cJSON *obj, const char *ptr, const char *const *allowed, const char *context,
                     struct err *err)
{
    uint32_t seen = 0;
    char p[512];
    for (const cJSON *c = obj->child; c; c = c->next) {
        int idx = -1;
        for (int i = 0; allowed[i]; i++)
            if (strcmp(c->string, allowed[i]) == 0) { idx = i; break; }
        json_pointer_key(p, sizeof p, ptr, c->string);
        if (idx < 0) {
            char list[256];
            size_t n = 0;
            list[0] = '\0';
            for (int i = 0; allowed[i] && n < sizeof list; i++)
                n += (size_t)snprintf(list + n, sizeof list - n, "%s%s", i ? ", " : "", allowed[i]);
            return err_set(err, ERR_INVALID, p, "unknown key \"%.64s\"%s (expected one of: %s)", c->string, context, list);
        }
        if (seen & (1u << idx)) return err_set(err, ERR_INVALID, p, "duplicate key \"%s\"", allowed[idx]);
        seen |= 1u << idx;
    }
    return true;
}

bool json_object(const cJSON *v, const char *ptr, const char *what, struct err *err)
{
    if (!cJSON_IsObject(v)) return err_set(err, ERR_INVALID, ptr, "expected %s object, got %s", what, json_type_name(v));
    return true;
}

bool json_bool(const cJSON *v, const char *ptr, bool *out, struct err *err)
{
    if (!cJSON_IsBool(v)) return err_set(err, ERR_INVALID, ptr, "expected true or false, got %s", json_type_name(v));
    *out = cJSON_IsTrue(v);
    return true;
}

const char *json_string(const cJSON *v, const char *ptr, struct err *err)
{
    if (!cJSON_IsString(v) || !v->valuestring) {
        err_set(err, ERR_INVALID, ptr, "expected a string, got %s", json_type_name(v));
        return NULL;
    }
    return v->valuestring;
}
