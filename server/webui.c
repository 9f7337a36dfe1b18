/* webui.c — lookup in the preview page's built-in file table (see webui.h). */
#include "webui.h"

#include <string.h>

const struct webui_file *webui_find(const char *name)
{
    for (size_t i = 0; i < webui_file_count; i++)
        if (strcmp(webui_files[i].name, name) == 0) return &webui_files[i];
    return NULL;
}
