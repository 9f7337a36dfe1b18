/* fuzz_mesh.c — libFuzzer targets for the mesh decoders (renderer/input/mesh_io.c). Built once per
 * format with -DFUZZ_MESH_EXT="ply" or "obj". An accepted mesh must keep the decoder's own
 * promises: at least one triangle, every index below vertex_count, every position finite. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "input/mesh_io.h"

#ifndef FUZZ_MESH_EXT
#error "build with -DFUZZ_MESH_EXT=\"ply\" or \"obj\""
#endif

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void fuzz_fail(const char *what)
{
    fprintf(stderr, "mesh_io_load_memory: %s\n", what);
    abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct mesh mesh;
    struct err err = {0};
    if (!mesh_io_load_memory(data, size, "fuzz." FUZZ_MESH_EXT, FUZZ_MESH_EXT, &mesh, &err)) {
        if (err.code == ERR_NONE) fuzz_fail("failed without an error code");
        if (mesh.positions || mesh.indices || mesh.triangle_count) fuzz_fail("failed but left a mesh");
        return 0;
    }
    if (mesh.triangle_count == 0) fuzz_fail("accepted a mesh without triangles");
    for (uint32_t i = 0; i < 3 * mesh.triangle_count; i++)
        if (mesh.indices[i] >= mesh.vertex_count) fuzz_fail("index out of range");
    for (uint32_t i = 0; i < mesh.vertex_count; i++) {
        struct vec3 p = mesh.positions[i];
        if (!isfinite(p.x) || !isfinite(p.y) || !isfinite(p.z)) fuzz_fail("non-finite position");
    }
    mesh_io_destroy(&mesh);
    return 0;
}
