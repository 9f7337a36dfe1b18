/* registry.h — the scenes this daemon holds: the built-in library (at start, every
 * <library>/<dir>/scene.json as id <dir> and every other <library>/<dir>/<x>.json as id
 * <dir>-<x>) and scenes uploaded over HTTP, which persist in the data directory and are
 * reloaded on restart. Each entry holds a committed, shared `struct scene` (sessions retain
 * it) and a content hash that makes uploads idempotent; the JSON text stays on disk only.
 * Thread-safe: one mutex guards the table; loading and committing a scene and file I/O happen
 * outside it, so a slow upload never blocks lookups. A second mutex serialises writers (put,
 * delete), so two uploads to the same id never interleave.
 * Layout of the data directory:
 *   <data>/scenes/<id>/scene.json          the uploaded scene text, byte for byte
 *   <data>/scenes/<id>/assets/<name>       uploaded mesh files (PLY/OBJ), referenced from
 *                                          scene.json by bare name
 * Files are written to a temporary name, fsync'd and renamed, so a crash never leaves half a
 * file under a final name. */
#ifndef RESTIRD_REGISTRY_H
#define RESTIRD_REGISTRY_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "budget.h"
#include "core/err.h"
#include "scene/scene.h"

#define REGISTRY_ID_MAX 64
#define REGISTRY_ASSET_NAME_MAX 64

struct registry;

struct registry_info {
    char id[REGISTRY_ID_MAX + 1];
    bool builtin;                 /* from the scene library (read-only) */
    char hash[17];                /* 64-bit content hash, hex; scene JSON plus its assets */
    uint32_t materials, shapes, triangles, emitters;
    size_t scene_bytes;           /* memory of the loaded scene (geometry, BVH estimate) */
    uint32_t sessions;            /* sessions currently using this scene */
    uint32_t assets;              /* uploaded asset files */
};

/* Loads every built-in scene under `library_dir` (may be NULL: none) and every persisted upload
 * under `data_dir` (created if missing). A built-in or persisted scene that fails to load is
 * skipped and reported through `warn` (may be NULL) — one bad file never keeps the daemon
 * down, and a persisted scene's files are never deleted for failing. Errors: ERR_IO when the
 * data directory cannot be created or read. */
typedef void registry_warn_fn(void *ctx, const char *message);
struct registry *registry_new(const char *library_dir, const char *data_dir, registry_warn_fn *warn, void *warn_ctx,
                              struct err *err);
/* The same without the uploaded scenes, which registry_load_stored then loads (the daemon
 * does so after it starts listening, so that its health checks answer meanwhile). */
struct registry *registry_new_deferred(const char *library_dir, const char *data_dir, registry_warn_fn *warn,
                                       void *warn_ctx, struct err *err);
/* Loads the uploaded scenes of the data directory, as registry_new does, while the registry is
 * in use: a scene a PUT created meanwhile is kept (the PUT wrote its files), one loaded after
 * registry_set_budget is charged to the budget. Stops between scenes once *stop (may be NULL)
 * is true. Errors: ERR_IO when the data directory cannot be read. */
bool registry_load_stored(struct registry *r, atomic_bool *stop, struct err *err);
/* From now on an uploaded scene reserves its scene_bytes from `budget` (BUDGET_SCENES) before it
 * enters the table, and a put that does not fit fails with ERR_BUSY (nothing written); the
 * uploads already loaded are charged without a check, so none is dropped. Built-ins are not
 * counted. */
void registry_set_budget(struct registry *r, struct budget *budget);
void registry_free(struct registry *r);

enum registry_put_result { REGISTRY_CREATED, REGISTRY_UNCHANGED, REGISTRY_REPLACED };

/* PUT /v1/scenes/{id}: validates and commits the scene (meshes resolve in the scene's asset
 * folder, so mesh paths are bare asset names), then persists it. Content hash: 64-bit FNV-1a
 * over the JSON and the scene's current assets (registry.c documents the framing); identical
 * content → REGISTRY_UNCHANGED and nothing is written. Bad id → ERR_INVALID, where = "id". A built-in id → ERR_CONFLICT (read-only) unless the content is identical. Invalid
 * scene → the scene loader's error (ERR_PARSE/ERR_INVALID/ERR_NOT_FOUND/ERR_LIMIT with the JSON
 * pointer), and the registry is unchanged. Sessions keep the scene they were created on. */
bool registry_put_scene(struct registry *r, const char *id, const char *json, size_t len,
                        enum registry_put_result *result, struct err *err);

/* PUT /v1/scenes/{id}/assets/{name}: stores a mesh file. name: [A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}
 * ending in .ply or .obj (case-insensitive), checked here (ERR_INVALID, where = "name").
 * At most MESH_IO_MAX_FILE_BYTES (ERR_LIMIT). The bytes must decode as a mesh of that format
 * (ERR_PARSE naming file:line otherwise) — nothing is stored on error. Allowed before the scene
 * exists (upload assets, then the scene); not for built-in ids (ERR_CONFLICT). When the scene
 * exists it is reloaded against the new asset set (used or not: the hash covers every asset);
 * if that fails, the old asset and scene are kept and the error returned. Bytes identical to
 * the stored asset change nothing. *created = true when no asset had that name. */
bool registry_put_asset(struct registry *r, const char *id, const char *name, const void *data, size_t len,
                        bool *created, struct err *err);

/* The scene with this id, retained (the caller scene_release()s it), or NULL. */
struct scene *registry_acquire(struct registry *r, const char *id);

/* Session bookkeeping for delete conflicts. session_added fails with ERR_NOT_FOUND when the
 * scene is gone. Counts are per id: session_removed after a forced delete and a re-upload of
 * the same id decrements the new entry (saturating at 0). */
bool registry_session_added(struct registry *r, const char *id, struct err *err);
void registry_session_removed(struct registry *r, const char *id);

/* DELETE /v1/scenes/{id}: ERR_NOT_FOUND; ERR_CONFLICT when sessions are live and !force, or the
 * scene is built-in; ERR_IO when scene.json cannot be removed (the scene then stays). Removes
 * the persisted files, staged assets included. Sessions keep their retained scene. */
bool registry_delete(struct registry *r, const char *id, bool force, struct err *err);

/* A snapshot of one entry; false when there is no such id. */
bool registry_info(struct registry *r, const char *id, struct registry_info *out);
/* Fills up to `max` entries sorted by id; returns the total count. */
size_t registry_list(struct registry *r, struct registry_info *out, size_t max);

#endif
