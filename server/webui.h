/* webui.h — the preview page's files (clients/web), built into the daemon: a table generated at
 * build time by scripts/embed_web.py (name, media type, strong ETag, bytes) and linked into
 * build/restird like protocol/openapi.yaml. Nothing is read from the file system at run time, so
 * a request can only ever name one of these files: there is no path to traverse.
 * Served by api.c at GET / (index.html) and GET /ui/{name}. */
#ifndef RESTIRD_WEBUI_H
#define RESTIRD_WEBUI_H

#include <stddef.h>

struct webui_file {
    const char *name;          /* base name, [A-Za-z0-9_][A-Za-z0-9_.-]{0,63} */
    const char *type;          /* Content-Type */
    const char *etag;          /* quoted, from the content's SHA-256 */
    const unsigned char *data;
    size_t size;
};

/* The generated table (build/obj/webui_files.c). */
extern const struct webui_file webui_files[];
extern const size_t webui_file_count;

/* The file served as `name`, or NULL. Exact, case-sensitive match. */
const struct webui_file *webui_find(const char *name);

#endif
