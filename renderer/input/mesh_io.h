/* mesh_io.h — reads triangle meshes (PLY, OBJ) from bytes or files into plain arrays.
 * The only home of assimp: no other file may include it. Input is untrusted (scene folders
 * now, uploaded assets later), so everything is bounded and checked: file size, header
 * counts, indices, finiteness. Assimp never touches the file system (an OBJ's mtllib is
 * refused), and imports are serialised because assimp's error string is a global.
 * Refs: docs/scene-format.md ("Mesh files"). */
#ifndef RESTIRD_MESH_IO_H
#define RESTIRD_MESH_IO_H

#include <stddef.h>
#include <stdint.h>

#include "core/err.h"
#include "core/vec.h"

#define MESH_IO_MAX_FILE_BYTES (512u << 20)   /* 512 MiB */
#define MESH_IO_MAX_TRIANGLES (16u << 20)     /* 16,777,216 after triangulation */
#define MESH_IO_MAX_VERTICES (3u * MESH_IO_MAX_TRIANGLES)
/* Vertices of one polygon (OBJ `f` line, PLY face list): assimp's triangulation takes time
 * quadratic in it (a 200,000-vertex face: 83 s), so larger ones are refused. */
#define MESH_IO_MAX_FACE_VERTICES 256u

/* An indexed triangle mesh in the file's own coordinates. Front face = counter-clockwise
 * winding as stored in the file (no reordering). normals is NULL unless the file gives a
 * normal for every vertex of every triangle-bearing part. All arrays are malloc'd and owned
 * by the struct until moved out or freed with mesh_io_destroy. */
struct mesh {
    uint32_t vertex_count, triangle_count;
    struct vec3 *positions;   /* vertex_count */
    struct vec3 *normals;     /* vertex_count, or NULL */
    uint32_t *indices;        /* 3 * triangle_count, each < vertex_count */
};

/* "ply" or "obj" when the name ends in .ply/.obj (any case), else NULL. */
const char *mesh_io_format_of(const char *name);

/* Decodes `len` bytes of a PLY or OBJ file (`ext` "ply"/"obj", any case). Points and lines are
 * dropped; polygons are triangulated; all parts are merged into one mesh; vertices are not
 * joined and normals are never generated. Errors: ERR_PARSE (malformed; where = name or
 * "name:line"), ERR_INVALID (index out of range, non-finite or zero normal, no triangle),
 * ERR_LIMIT (size, counts), ERR_UNSUPPORTED (extension), ERR_NOMEM. `name_for_errors` is what
 * `where` shows. On failure *out is left empty. Thread-safe (serialised internally). */
bool mesh_io_load_memory(const void *data, size_t len, const char *name_for_errors, const char *ext,
                         struct mesh *out, struct err *err);
/* Reads the file at `path` (at most MESH_IO_MAX_FILE_BYTES) and decodes it as above; `ext` may
 * be NULL to take the format from `path`. ERR_NOT_FOUND when the file does not exist, ERR_IO
 * when it cannot be read; `where` is name_for_errors. */
bool mesh_io_load_file(const char *path, const char *name_for_errors, const char *ext, struct mesh *out,
                       struct err *err);
/* Frees the arrays and zeroes the struct; safe on an empty or zeroed mesh. */
void mesh_io_destroy(struct mesh *mesh);

#endif
