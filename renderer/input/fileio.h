/* fileio.h — reading a whole input file (scene JSON, mesh) into memory, safely: only regular
 * files, a size limit checked before reading, no blocking on FIFOs or devices. */
#ifndef RESTIRD_FILEIO_H
#define RESTIRD_FILEIO_H

#include <stddef.h>

#include "core/err.h"

/* Reads `path` into a malloc'd buffer with a NUL byte after the data (*data, *size exclude
 * it); the caller frees *data. `what` names the file in messages ("scene file", "mesh file"),
 * `name` is used as err->where and in messages (NULL: the path). Errors: ERR_NOT_FOUND,
 * ERR_IO (not a regular file, read failure), ERR_LIMIT (larger than max_bytes), ERR_NOMEM. */
bool fileio_read_all(const char *path, const char *what, const char *name, size_t max_bytes, char **data,
                     size_t *size, struct err *err);

#endif
