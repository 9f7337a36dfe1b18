/* fuzz_scene_json.c — libFuzzer target for the scene JSON loader (renderer/input/scene_load.c).
 * Mesh paths resolve under tests/meshes (make runs from the tree's root), so the path checks
 * and the mesh decoders behind them are reached too. A rejected scene must come back as an
 * error code; an accepted one must be within the shape limit (an empty scene is valid). */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "scene/scene.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct err err = {0};
    struct scene *scene = scene_load_json((const char *)data, size, "tests/meshes", &err);
    if (!scene) {
        if (err.code == ERR_NONE) {
            fprintf(stderr, "scene_load_json failed without an error code\n");
            abort();
        }
        return 0;
    }
    if (scene->shape_count > 100000) {  /* docs/scene-format.md: the shape limit */
        fprintf(stderr, "scene_load_json accepted %u shapes\n", scene->shape_count);
        abort();
    }
    scene_release(scene);
    return 0;
}
