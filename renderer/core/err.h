/* err.h — errors as values. A fallible function returns bool (or NULL) and takes
 * `struct err *err` last; on failure it fills code, where (a JSON pointer such as
 * "/shapes/3/radius" or "file.ply:12") and a human message. Only server/ maps codes to HTTP. */
#ifndef RESTIRD_ERR_H
#define RESTIRD_ERR_H

#include <stdbool.h>

enum err_code {
    ERR_NONE = 0,
    ERR_PARSE,       /* malformed syntax (JSON, PLY/OBJ, EXR) */
    ERR_INVALID,     /* well-formed but meaningless: wrong type, NaN, negative size, unknown key */
    ERR_NOT_FOUND,   /* a named thing (file, material, shape) does not exist */
    ERR_IO,          /* the operating system refused a read or write */
    ERR_LIMIT,       /* over a size or count limit */
    ERR_UNSUPPORTED, /* valid input this build does not handle */
    ERR_NOMEM,
    ERR_INTERNAL,    /* a library we call failed in a way the caller cannot fix */
    ERR_CONFLICT,    /* the request contradicts the current state (a session is busy, live) */
    ERR_BUSY,        /* a queue or memory budget is full; retrying later can succeed */
    ERR_STORAGE,     /* the disk refused to hold more (ENOSPC, EDQUOT, EFBIG): nothing was stored */
};

struct err {
    enum err_code code;
    char where[256];
    char message[512];
};

/* Fills *err (when err is non-NULL) and returns false, so callers can `return err_set(...)`.
 * `where` may be NULL. The message is printf-formatted. */
bool err_set(struct err *err, enum err_code code, const char *where, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
const char *err_code_name(enum err_code code);
/* Puts a relative `where` ("tiles") under `base` ("/params" -> "/params/tiles"); an absolute or
 * empty one is left as it is. Returns false, for `return err_under(err, "/params");`. */
bool err_under(struct err *err, const char *base);
/* "where: message" (or just the message) into buf; returns buf. */
const char *err_format(const struct err *err, char *buf, unsigned long size);

#endif
