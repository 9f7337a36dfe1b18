/* json_read.h — strict reading of untrusted JSON (cJSON trees), shared by the scene loader
 * (input/scene_load.c) and the request parser (protocol/request.c): JSON pointers to name the
 * offending member (RFC 6901), exact type names in messages, objects whose keys must come from a
 * fixed list and appear once, and typed accessors that refuse what they do not expect. */
#ifndef RESTIRD_JSON_READ_H
#define RESTIRD_JSON_READ_H

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <stddef.h>

#include "core/err.h"

/* Writes "<base>/<key>" into out with key escaped per RFC 6901 (~ -> ~0, / -> ~1). A result
 * longer than size - 1 is cut before the first escape or UTF-8 character that does not fit. */
void json_pointer_key(char *out, size_t size, const char *base, const char *key);

/* Length (1..4) of the well-formed UTF-8 sequence at s[0..n), or 0 when it is malformed,
 * overlong, a surrogate or above U+10FFFF (RFC 3629). */
size_t json_utf8_seq(const unsigned char *s, size_t n);

/* "null", "a boolean", "a number", "a string", "an array", "an object". */
const char *json_type_name(const cJSON *v);

/* Every key of `obj` must be in the NULL-terminated `allowed` list (at most 32), at most once.
 * The first offending key in document order is reported by its pointer; `context` follows the
 * key in the message (" in pt params"). */
bool json_check_keys(const cJSON *obj, const char *ptr, const char *const *allowed, const char *context,
                     struct err *err);

/* v must be an object ("expected <what> object, got ..."). */
bool json_object(const cJSON *v, const char *ptr, const char *what, struct err *err);
bool json_bool(const cJSON *v, const char *ptr, bool *out, struct err *err);
/* The string's text, or NULL (and an error) when v is not a string. */
const char *json_string(const cJSON *v, const char *ptr, struct err *err);

#endif
