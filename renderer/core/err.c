/* err.c — filling and printing `struct err` values (see err.h). */
#include "core/err.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

bool err_set(struct err *err, enum err_code code, const char *where, const char *fmt, ...)
{
    if (!err) return false;
    err->code = code;
    snprintf(err->where, sizeof err->where, "%s", where ? where : "");
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err->message, sizeof err->message, fmt, ap);
    va_end(ap);
    return false;
}

const char *err_code_name(enum err_code code)
{
    switch (code) {
    case ERR_NONE: return "none";
    case ERR_PARSE: return "parse";
    case ERR_INVALID: return "invalid";
    case ERR_NOT_FOUND: return "not_found";
    case ERR_IO: return "io";
    case ERR_LIMIT: return "limit";
    case ERR_UNSUPPORTED: return "unsupported";
    case ERR_NOMEM: return "nomem";
    case ERR_INTERNAL: return "internal";
    case ERR_CONFLICT: return "conflict";
    case ERR_BUSY: return "busy";
    case ERR_STORAGE: return "storage";
    }
    return "unknown";
}

const char *err_format(const struct err *err, char *buf, unsigned long size)
{
    if (err->where[0])
        snprintf(buf, size, "%s: %s", err->where, err->message);
    else
        snprintf(buf, size, "%s", err->message);
    return buf;
}

bool err_under(struct err *err, const char *base)
{
    if (!err || !err->where[0] || err->where[0] == '/') return false;
    char where[sizeof err->where];
    snprintf(where, sizeof where, "%s/%s", base, err->where);
    memcpy(err->where, where, sizeof where);
    return false;
}
