/* registry.c — the daemon's scene table (see registry.h): built-ins from the library folder and
 * uploads persisted under <data>/scenes/<id>/. Owns the data directory's layout and its crash
 * safety (temporary name, fsync, rename, fsync of the folder). It must not parse JSON or meshes
 * itself: an upload is validated by the same scene loader and mesh_io as a library scene.
 * Locks: `lock` guards the table only; a write lock lets one writer at a time change one
 * scene's entry and folder. Loading, committing and file I/O run with only the scene's write
 * lock held, so lookups (acquire, info, list, session counts) never wait for a slow upload, and
 * an upload to one scene never waits for a slow upload to another (unless their ids share one
 * of the REGISTRY_WRITE_STRIPES locks). */
#include "registry.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "input/fileio.h"
#include "scene/light_sampler.h"
#include "input/mesh_io.h"

/* Content hash: 64-bit FNV-1a over
 *     u64 json length, json bytes,
 *     then for each asset in strcmp order of names: u64 name length, name, u64 size, bytes
 * (every u64 little-endian). The lengths make the framing unambiguous: without them, moving
 * bytes between the JSON and an asset name would keep the hash. FNV-1a is not
 * collision-resistant, which is acceptable because the hash only decides idempotency: a
 * client that forges a collision for an id could as well PUT anything under that id. */
#define REGISTRY_FNV_OFFSET 0xcbf29ce484222325ull
#define REGISTRY_FNV_PRIME 0x100000001b3ull

/* Memory estimate of the acceleration structure per primitive (triangle or sphere): Embree's
 * BVH4 with its triangle leaves measures roughly 50–80 bytes per triangle on the library
 * scenes, so 64 is the planning figure; scene_bytes is for budgets, not an exact account. */
#define REGISTRY_BVH_BYTES_PER_PRIM 64

/* The scene loader's own limit (4 MiB); a larger persisted file would fail to load anyway,
 * so it is not read into memory. */
#define REGISTRY_JSON_MAX_BYTES (4u << 20)
#define REGISTRY_CHUNK_BYTES (64u << 10)
#define REGISTRY_TMP_PREFIX ".tmp-"
#define REGISTRY_STAGE_PREFIX ".stage-"

struct registry_entry {
    struct registry_info info;  /* info.sessions is the live counter */
    struct scene *scene;        /* committed; the registry's own reference */
    uint64_t hash;
};

#define REGISTRY_WRITE_STRIPES 16

struct registry {
    pthread_mutex_t lock;         /* guards entries, count, cap and every entry */
    /* Serialise put/delete/load of one id (taken before `lock`, never after; one at a time,
     * except registry_set_budget, which takes them all in order). */
    pthread_mutex_t write_locks[REGISTRY_WRITE_STRIPES];
    struct registry_entry **entries;  /* sorted by id */
    size_t count, cap;
    char *scenes_dir;             /* <data>/scenes */
    registry_warn_fn *warn;
    void *warn_ctx;
    struct budget *budget;        /* uploaded scenes' bytes are reserved from it; NULL = none */
};

/* The write lock of scene `id` (FNV-1a of the id picks the stripe). */
static pthread_mutex_t *registry_write_lock(struct registry *r, const char *id)
{
    uint32_t h = 2166136261u;
    for (const unsigned char *p = (const unsigned char *)id; *p; p++) h = (h ^ *p) * 16777619u;
    return &r->write_locks[h % REGISTRY_WRITE_STRIPES];
}

struct registry_names {
    char **v;
    size_t n, cap;
};

/* ---- small helpers ---- */

__attribute__((format(printf, 2, 3))) static void registry_warn(struct registry *r, const char *fmt, ...)
{
    if (!r->warn) return;
    char buf[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    r->warn(r->warn_ctx, buf);
}

/* Formats a path into a fixed buffer; a path that does not fit is an I/O error rather than a
 * silently truncated (and therefore wrong) file name. */
__attribute__((format(printf, 4, 5))) static bool registry_path(char *out, size_t size, struct err *err,
                                                                  const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(out, size, fmt, ap);
    va_end(ap);
    if (n < 0 || (size_t)n >= size) return err_set(err, ERR_IO, NULL, "path too long in the data directory");
    return true;
}

static bool registry_id_char(char c)
{
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
}

static bool registry_id_valid(const char *id)
{
    if (!id) return false;
    size_t n = 0;
    for (; id[n]; n++)
        if (n >= REGISTRY_ID_MAX || !registry_id_char(id[n])) return false;
    return n > 0;
}

/* [A-Za-z0-9_-][A-Za-z0-9_.-]{0,63} ending in .ply/.obj: no separator and no leading dot, so
 * a name can neither leave the assets folder nor collide with our ".tmp-"/".stage-" files. */
static bool registry_asset_name_valid(const char *name)
{
    if (!name || !registry_id_char(name[0])) return false;
    size_t n = 1;
    for (; name[n]; n++)
        if (n >= REGISTRY_ASSET_NAME_MAX || !(registry_id_char(name[n]) || name[n] == '.')) return false;
    return mesh_io_format_of(name) != NULL;
}

static bool registry_has_prefix(const char *s, const char *prefix)
{
    return strncmp(s, prefix, strlen(prefix)) == 0;
}

static uint64_t registry_fnv(uint64_t h, const void *data, size_t len)
{
    const unsigned char *p = data;
    for (size_t i = 0; i < len; i++) {
        h ^= p[i];
        h *= REGISTRY_FNV_PRIME;
    }
    return h;
}

static uint64_t registry_fnv_u64(uint64_t h, uint64_t v)
{
    unsigned char b[8];
    for (int i = 0; i < 8; i++) b[i] = (unsigned char)(v >> (8 * i));
    return registry_fnv(h, b, sizeof b);
}

static void registry_names_free(struct registry_names *names)
{
    for (size_t i = 0; i < names->n; i++) free(names->v[i]);
    free(names->v);
    memset(names, 0, sizeof *names);
}

static bool registry_names_push(struct registry_names *names, const char *s, struct err *err)
{
    if (names->n == names->cap) {
        size_t cap = names->cap ? 2 * names->cap : 16;
        char **v = realloc(names->v, cap * sizeof *v);
        if (!v) return err_set(err, ERR_NOMEM, NULL, "out of memory listing a folder");
        names->v = v;
        names->cap = cap;
    }
    char *copy = strdup(s);
    if (!copy) return err_set(err, ERR_NOMEM, NULL, "out of memory listing a folder");
    names->v[names->n++] = copy;
    return true;
}

static int registry_names_cmp(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

/* The entries of `dir` of type `want` (S_IFDIR or S_IFREG), minus "." and "..", sorted.
 * follow: whether symbolic links count as what they point to (the library may use them; the
 * data directory, which we write ourselves, never does). A missing folder is an empty list
 * with *missing set (when non-NULL). */
static bool registry_list_dir(const char *dir, mode_t want, bool follow, struct registry_names *out, bool *missing,
                              struct err *err)
{
    memset(out, 0, sizeof *out);
    if (missing) *missing = false;
    DIR *d = opendir(dir);
    if (!d) {
        if (errno == ENOENT && missing) {
            *missing = true;
            return true;
        }
        return err_set(err, errno == ENOENT ? ERR_NOT_FOUND : ERR_IO, NULL, "cannot read folder '%s': %s", dir,
                       strerror(errno));
    }
    bool ok = true;
    for (;;) {
        errno = 0;
        struct dirent *de = readdir(d);
        if (!de) {
            if (errno) ok = err_set(err, ERR_IO, NULL, "cannot read folder '%s': %s", dir, strerror(errno));
            break;
        }
        if (strcmp(de->d_name, ".") == 0 || strcmp(de->d_name, "..") == 0) continue;
        struct stat st;
        if (fstatat(dirfd(d), de->d_name, &st, follow ? 0 : AT_SYMLINK_NOFOLLOW) != 0) continue;
        if ((st.st_mode & S_IFMT) != want) continue;
        if (!(ok = registry_names_push(out, de->d_name, err))) break;
    }
    closedir(d);
    if (!ok) {
        registry_names_free(out);
        return false;
    }
    if (out->n > 1) qsort(out->v, out->n, sizeof *out->v, registry_names_cmp);
    return true;
}

/* ---- durable writes ---- */

static bool registry_fsync_dir(const char *dir, struct err *err)
{
    int fd = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0) return err_set(err, ERR_IO, NULL, "cannot open folder '%s': %s", dir, strerror(errno));
    bool ok = fsync(fd) == 0 || errno == EINVAL;  /* some file systems cannot sync folders */
    int e = errno;
    close(fd);
    if (!ok) return err_set(err, ERR_IO, NULL, "cannot sync folder '%s': %s", dir, strerror(e));
    return true;
}

/* Creates one folder level; when it is new, the parent is synced so the entry survives a
 * crash together with whatever is later renamed into it. */
/* A full disk, a quota or a file-size limit is the operator's to fix, not a bug: it gets its
 * own code (507 insufficient-storage) so the client is told what happened. */
static enum err_code registry_io_code(int e)
{
    return e == ENOSPC || e == EDQUOT || e == EFBIG ? ERR_STORAGE : ERR_IO;
}

/* follow: whether an existing symbolic link to a folder will do. The path to the data directory
 * may have them (the operator's choice); the folders inside it are the daemon's own and never
 * are links: a link planted there would have scenes written and deleted through it. */
static bool registry_mkdir_at(const char *path, bool follow, struct err *err)
{
    if (mkdir(path, 0755) != 0) {
        int e = errno;
        struct stat st;
        if (e == EEXIST && (follow ? stat(path, &st) : lstat(path, &st)) == 0 && S_ISDIR(st.st_mode)) return true;
        if (e == EEXIST && lstat(path, &st) == 0 && S_ISLNK(st.st_mode))
            return err_set(err, ERR_IO, NULL, "'%s' is a symbolic link, and the data directory's folders may not be",
                           path);
        return err_set(err, registry_io_code(e), NULL, "cannot create folder '%s': %s", path, strerror(e));
    }
    char parent[PATH_MAX];
    if (!registry_path(parent, sizeof parent, err, "%s", path)) return false;
    char *slash = strrchr(parent, '/');
    if (!slash) return registry_fsync_dir(".", err);
    if (slash == parent) slash[1] = '\0';
    else *slash = '\0';
    return registry_fsync_dir(parent, err);
}

/* A folder of the daemon's own, inside the data directory: never through a symbolic link. */
static bool registry_mkdir(const char *path, struct err *err)
{
    return registry_mkdir_at(path, false, err);
}

/* A scene's folder as it is now: false (with the error) when it is a symbolic link or not a
 * folder; true when it is a folder or absent. */
static bool registry_own_dir(const char *path, struct err *err)
{
    struct stat st;
    if (lstat(path, &st) != 0 || S_ISDIR(st.st_mode)) return true;
    return err_set(err, ERR_IO, NULL, "'%s' is %s, and the data directory's folders may not be", path,
                   S_ISLNK(st.st_mode) ? "a symbolic link" : "not a folder");
}

static bool registry_mkdir_p(const char *path, struct err *err)
{
    char buf[PATH_MAX];
    if (!registry_path(buf, sizeof buf, err, "%s", path)) return false;
    for (char *p = buf + 1; *p; p++) {
        if (*p != '/') continue;
        *p = '\0';
        bool ok = registry_mkdir_at(buf, true, err);
        *p = '/';
        if (!ok) return false;
    }
    return registry_mkdir_at(buf, true, err);
}

/* Writes `data` to a new temporary file in `dir` and syncs it; *tmp receives its path. The
 * name starts with a dot, which no id or asset name may, so it never shadows a real file. */
static bool registry_write_tmp(const char *dir, const void *data, size_t len, char *tmp, size_t tmp_size,
                               struct err *err)
{
    if (!registry_path(tmp, tmp_size, err, "%s/" REGISTRY_TMP_PREFIX "XXXXXX", dir)) return false;
    int fd = mkstemp(tmp);  /* mkostemp would need _GNU_SOURCE; FD_CLOEXEC is set just after */
    if (fd < 0) return err_set(err, registry_io_code(errno), NULL, "cannot create a file in '%s': %s", dir, strerror(errno));
    (void)fcntl(fd, F_SETFD, FD_CLOEXEC);
    const char *p = data;
    size_t done = 0;
    bool ok = true;
    while (ok && done < len) {
        ssize_t w = write(fd, p + done, len - done);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) ok = false;
        else done += (size_t)w;
    }
    /* mkostemp creates 0600; the data files are ordinary readable files like the library's. */
    ok = ok && fchmod(fd, 0644) == 0 && fsync(fd) == 0;
    int e = errno;
    if (close(fd) != 0 && ok) {
        ok = false;
        e = errno;
    }
    if (!ok) {
        unlink(tmp);
        return err_set(err, registry_io_code(e), NULL, "cannot write a file in '%s': %s", dir, strerror(e));
    }
    return true;
}

static bool registry_rename_into(const char *tmp, const char *dir, const char *name, struct err *err)
{
    char path[PATH_MAX];
    if (!registry_path(path, sizeof path, err, "%s/%s", dir, name)) return false;
    if (rename(tmp, path) != 0) return err_set(err, ERR_IO, NULL, "cannot rename into '%s': %s", path, strerror(errno));
    return registry_fsync_dir(dir, err);
}

static bool registry_write_atomic(const char *dir, const char *name, const void *data, size_t len, struct err *err)
{
    char tmp[PATH_MAX];
    if (!registry_write_tmp(dir, data, len, tmp, sizeof tmp, err)) return false;
    if (!registry_rename_into(tmp, dir, name, err)) {
        unlink(tmp);
        return false;
    }
    return true;
}

/* Removes a file or a folder with everything in it (symbolic links are removed, not followed).
 * Best effort: keeps going after a failure and reports whether everything went. */
static bool registry_remove_tree(const char *path, int depth)
{
    struct stat st;
    if (lstat(path, &st) != 0) return errno == ENOENT;
    if (!S_ISDIR(st.st_mode)) return unlink(path) == 0;
    if (depth <= 0) return false;
    bool ok = true;
    DIR *d = opendir(path);
    if (d) {
        struct dirent *de;
        while ((de = readdir(d))) {
            if (strcmp(de->d_name, ".") == 0 || strcmp(de->d_name, "..") == 0) continue;
            char child[PATH_MAX];
            if (!registry_path(child, sizeof child, NULL, "%s/%s", path, de->d_name)) {
                ok = false;
                continue;
            }
            ok = registry_remove_tree(child, depth - 1) && ok;
        }
        closedir(d);
    } else {
        ok = false;
    }
    return rmdir(path) == 0 && ok;
}

/* ---- reading and hashing ---- */

static bool registry_hash_file(uint64_t *h, const char *path, const char *name, unsigned char *buf, struct err *err)
{
    int fd = open(path, O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) return err_set(err, ERR_IO, name, "cannot open asset '%s': %s", name, strerror(errno));
    struct stat st;
    if (fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        close(fd);
        return err_set(err, ERR_IO, name, "asset '%s' is not a regular file", name);
    }
    uint64_t size = (uint64_t)st.st_size, got = 0;
    *h = registry_fnv_u64(*h, size);
    for (;;) {
        ssize_t n = read(fd, buf, REGISTRY_CHUNK_BYTES);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) break;
        *h = registry_fnv(*h, buf, (size_t)n);
        got += (uint64_t)n;
    }
    close(fd);
    if (got != size) return err_set(err, ERR_IO, name, "cannot read asset '%s' (%llu of %llu bytes)", name,
                                    (unsigned long long)got, (unsigned long long)size);
    return true;
}

/* The content hash (see the top of this file) of `json` with the assets in `assets_dir` (may
 * be NULL or missing: none). *assets receives the number of assets. */
static bool registry_hash_content(const char *json, size_t len, const char *assets_dir, uint64_t *hash,
                                  uint32_t *assets, struct err *err)
{
    uint64_t h = registry_fnv_u64(REGISTRY_FNV_OFFSET, len);
    h = registry_fnv(h, json, len);
    *assets = 0;
    if (assets_dir) {
        struct registry_names names;
        bool missing;
        if (!registry_list_dir(assets_dir, S_IFREG, false, &names, &missing, err)) return false;
        unsigned char *buf = names.n ? malloc(REGISTRY_CHUNK_BYTES) : NULL;
        if (names.n && !buf) {
            registry_names_free(&names);
            return err_set(err, ERR_NOMEM, NULL, "out of memory hashing assets");
        }
        bool ok = true;
        for (size_t i = 0; ok && i < names.n; i++) {
            if (!registry_asset_name_valid(names.v[i])) continue;  /* our temporary files */
            char path[PATH_MAX];
            ok = registry_path(path, sizeof path, err, "%s/%s", assets_dir, names.v[i]);
            size_t nlen = strlen(names.v[i]);
            h = registry_fnv(registry_fnv_u64(h, nlen), names.v[i], nlen);
            ok = ok && registry_hash_file(&h, path, names.v[i], buf, err);
            (*assets)++;
        }
        free(buf);
        registry_names_free(&names);
        if (!ok) return false;
    }
    *hash = h;
    return true;
}

/* Whether `path` holds exactly `len` bytes equal to `data` (false on any error). */
static bool registry_file_equals(const char *path, const void *data, size_t len)
{
    int fd = open(path, O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) return false;
    struct stat st;
    bool same = fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && (uint64_t)st.st_size == (uint64_t)len;
    unsigned char *buf = same ? malloc(REGISTRY_CHUNK_BYTES) : NULL;
    const unsigned char *p = data;
    size_t off = 0;
    same = same && buf;
    while (same && off < len) {
        ssize_t n = read(fd, buf, REGISTRY_CHUNK_BYTES);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0 || (size_t)n > len - off || memcmp(buf, p + off, (size_t)n) != 0) same = false;
        else off += (size_t)n;
    }
    free(buf);
    close(fd);
    return same;
}

/* ---- scenes and entries ---- */

/* Loads and commits a scene whose mesh paths resolve in `base_dir`. For uploads
 * (`assets_of` = the id) a missing assets folder is the client's mistake, not ours: the
 * loader's "scene folder '<server path>' is not accessible" would be unclear and would show a
 * server path, so the message is rewritten; code and where (/shapes/i/file) stay. */
static struct scene *registry_load(const char *json, size_t len, const char *base_dir, const char *assets_of,
                                   struct err *err)
{
    struct stat st;
    bool base_missing = stat(base_dir, &st) != 0 || !S_ISDIR(st.st_mode);
    struct scene *scene = scene_load_json(json, len, base_dir, err);
    if (!scene) {
        size_t wl = err ? strlen(err->where) : 0;
        if (assets_of && base_missing && err && err->code == ERR_NOT_FOUND && wl > 5 &&
            strcmp(err->where + wl - 5, "/file") == 0)
            snprintf(err->message, sizeof err->message,
                     "mesh file not found: scene '%s' has no uploaded assets (PUT /v1/scenes/%s/assets/<name> first)",
                     assets_of, assets_of);
        return NULL;
    }
    if (!scene_commit(scene, err)) {
        scene_release(scene);
        return NULL;
    }
    return scene;
}

/* The scene_bytes estimate (geometry plus REGISTRY_BVH_BYTES_PER_PRIM per primitive) and the
 * triangle count. */
static size_t registry_scene_bytes(const struct scene *scene, uint64_t *triangles_out)
{
    uint64_t prims = 0, triangles = 0;
    size_t bytes = scene->shape_count * sizeof *scene->shapes +
                   scene->material_count * (sizeof *scene->materials + sizeof *scene->material_names);
    for (uint32_t i = 0; i < scene->shape_count; i++) {
        const struct shape *s = &scene->shapes[i];
        if (s->kind != SHAPE_MESH) {
            prims++;
            continue;
        }
        prims += s->triangle_count;
        triangles += s->triangle_count;
        bytes += (size_t)s->vertex_count * sizeof *s->positions * (s->normals ? 2 : 1) +
                 (size_t)s->triangle_count * 3 * sizeof *s->indices;
    }
    if (triangles_out) *triangles_out = triangles;
    return bytes + (size_t)prims * REGISTRY_BVH_BYTES_PER_PRIM;
}

/* An uploaded scene about to enter the table reserves its bytes (ERR_BUSY when the budget is
 * full); the scene it replaces or that leaves gives them back. Called with the scene's write
 * lock held. */
static bool registry_budget_reserve(struct registry *r, const struct scene *scene, struct err *err)
{
    return !r->budget || budget_reserve(r->budget, BUDGET_SCENES, registry_scene_bytes(scene, NULL), err);
}

static void registry_budget_release(struct registry *r, const struct scene *scene)
{
    if (r->budget && scene) budget_release(r->budget, BUDGET_SCENES, registry_scene_bytes(scene, NULL));
}

/* Fills everything in e->info that depends on the scene (sessions, id and builtin stay). */
static void registry_entry_set(struct registry_entry *e, struct scene *scene, uint64_t hash, uint32_t assets)
{
    uint64_t triangles = 0;
    size_t bytes = registry_scene_bytes(scene, &triangles);
    e->scene = scene;
    e->hash = hash;
    snprintf(e->info.hash, sizeof e->info.hash, "%016llx", (unsigned long long)hash);
    e->info.materials = scene->material_count;
    e->info.shapes = scene->shape_count;
    e->info.triangles = triangles > UINT32_MAX ? UINT32_MAX : (uint32_t)triangles;
    e->info.emitters = scene->lights ? light_sampler_count(scene->lights) : 0;
    e->info.scene_bytes = bytes;
    e->info.assets = assets;
}

/* Binary search; *pos is the match or the insertion point. Call with `lock` held. */
static bool registry_find_locked(const struct registry *r, const char *id, size_t *pos)
{
    size_t lo = 0, hi = r->count;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        int c = strcmp(r->entries[mid]->info.id, id);
        if (c == 0) {
            *pos = mid;
            return true;
        }
        if (c < 0) lo = mid + 1;
        else hi = mid;
    }
    *pos = lo;
    return false;
}

/* Adds a new entry for `scene` (taking over the caller's reference on success). Fails with
 * ERR_CONFLICT when the id is taken. */
static bool registry_insert(struct registry *r, const char *id, bool builtin, struct scene *scene, uint64_t hash,
                            uint32_t assets, struct err *err)
{
    struct registry_entry *e = calloc(1, sizeof *e);
    if (!e) return err_set(err, ERR_NOMEM, NULL, "out of memory");
    snprintf(e->info.id, sizeof e->info.id, "%s", id);
    e->info.builtin = builtin;
    registry_entry_set(e, scene, hash, assets);
    pthread_mutex_lock(&r->lock);
    size_t pos;
    bool ok = true;
    if (registry_find_locked(r, id, &pos)) {
        ok = err_set(err, ERR_CONFLICT, "id", "scene '%s' exists already", id);
    } else if (r->count == r->cap) {
        size_t cap = r->cap ? 2 * r->cap : 16;
        struct registry_entry **v = realloc(r->entries, cap * sizeof *v);
        if (!v) ok = err_set(err, ERR_NOMEM, NULL, "out of memory");
        else {
            r->entries = v;
            r->cap = cap;
        }
    }
    if (ok) {
        memmove(&r->entries[pos + 1], &r->entries[pos], (r->count - pos) * sizeof *r->entries);
        r->entries[pos] = e;
        r->count++;
    }
    pthread_mutex_unlock(&r->lock);
    if (!ok) free(e);
    return ok;
}

/* Replaces the scene of an existing entry; returns the old scene for the caller to release
 * outside the lock (releasing the last reference frees Embree data, which takes a while). */
static struct scene *registry_replace(struct registry *r, const char *id, struct scene *scene, uint64_t hash,
                                      uint32_t assets)
{
    struct scene *old = NULL;
    pthread_mutex_lock(&r->lock);
    size_t pos;
    if (registry_find_locked(r, id, &pos)) {
        old = r->entries[pos]->scene;
        registry_entry_set(r->entries[pos], scene, hash, assets);
    } else {
        old = scene;  /* cannot happen under the scene's write lock; never leak the scene */
    }
    pthread_mutex_unlock(&r->lock);
    return old;
}

/* Looks the id up: *exists, *builtin and *hash of the current entry. */
static void registry_peek(struct registry *r, const char *id, bool *exists, bool *builtin, uint64_t *hash)
{
    pthread_mutex_lock(&r->lock);
    size_t pos;
    *exists = registry_find_locked(r, id, &pos);
    *builtin = *exists && r->entries[pos]->info.builtin;
    *hash = *exists ? r->entries[pos]->hash : 0;
    pthread_mutex_unlock(&r->lock);
}

/* ---- start-up ---- */

static void registry_load_builtin(struct registry *r, const char *lib, const char *dir, const char *file)
{
    char id[2 * PATH_MAX], folder[PATH_MAX], path[PATH_MAX];
    size_t flen = strlen(file) - strlen(".json");
    if (flen == strlen("scene") && strncmp(file, "scene", flen) == 0) snprintf(id, sizeof id, "%s", dir);
    else snprintf(id, sizeof id, "%s-%.*s", dir, (int)flen, file);
    struct err err = {0};
    if (!registry_path(folder, sizeof folder, &err, "%s/%s", lib, dir) ||
        !registry_path(path, sizeof path, &err, "%s/%s", folder, file)) {
        registry_warn(r, "registry: skipping built-in scene '%s/%s/%s': %s", lib, dir, file, err.message);
        return;
    }
    if (!registry_id_valid(id)) {
        registry_warn(r, "registry: skipping built-in scene '%s': id '%s' is not [A-Za-z0-9_-]{1,64}", path, id);
        return;
    }
    /* Read once and load from the same bytes, so the hash describes exactly what was loaded;
     * meshes resolve in the file's folder, as scene_load_file does. */
    char *json = NULL;
    size_t len = 0;
    struct scene *scene = NULL;
    uint64_t hash = 0;
    uint32_t assets = 0;
    bool ok = fileio_read_all(path, "scene file", path, REGISTRY_JSON_MAX_BYTES, &json, &len, &err) &&
              registry_hash_content(json, len, NULL, &hash, &assets, &err) &&
              (scene = registry_load(json, len, folder, NULL, &err)) != NULL &&
              registry_insert(r, id, true, scene, hash, 0, &err);
    free(json);
    if (!ok) {
        char msg[800];
        registry_warn(r, "registry: skipping built-in scene '%s' (%s): %s: %s", id, path, err_code_name(err.code),
                      err_format(&err, msg, sizeof msg));
        scene_release(scene);
    }
}

static void registry_load_library(struct registry *r, const char *lib)
{
    struct registry_names dirs;
    struct err err = {0};
    if (!registry_list_dir(lib, S_IFDIR, true, &dirs, NULL, &err)) {
        registry_warn(r, "registry: no built-in scenes: %s", err.message);
        return;
    }
    for (size_t i = 0; i < dirs.n; i++) {
        if (dirs.v[i][0] == '.') continue;
        char folder[PATH_MAX];
        struct registry_names files;
        if (!registry_path(folder, sizeof folder, &err, "%s/%s", lib, dirs.v[i]) ||
            !registry_list_dir(folder, S_IFREG, true, &files, NULL, &err)) {
            registry_warn(r, "registry: skipping library folder '%s/%s': %s", lib, dirs.v[i], err.message);
            continue;
        }
        for (size_t k = 0; k < files.n; k++) {
            size_t n = strlen(files.v[k]);
            if (files.v[k][0] == '.' || n <= 5 || strcmp(files.v[k] + n - 5, ".json") != 0) continue;
            registry_load_builtin(r, lib, dirs.v[i], files.v[k]);
        }
        registry_names_free(&files);
    }
    registry_names_free(&dirs);
}

/* Leftovers of a crash between writing a temporary file and renaming it: only our own dotted
 * names are touched, never a scene or an asset. */
static void registry_clean_leftovers(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d) return;
    struct dirent *de;
    while ((de = readdir(d))) {
        if (!registry_has_prefix(de->d_name, REGISTRY_TMP_PREFIX) &&
            !registry_has_prefix(de->d_name, REGISTRY_STAGE_PREFIX))
            continue;
        char path[PATH_MAX];
        if (registry_path(path, sizeof path, NULL, "%s/%s", dir, de->d_name)) registry_remove_tree(path, 2);
    }
    closedir(d);
}

static void registry_load_upload(struct registry *r, const char *id)
{
    char scene_dir[PATH_MAX], assets_dir[PATH_MAX], path[PATH_MAX];
    struct err err = {0};
    if (!registry_path(scene_dir, sizeof scene_dir, &err, "%s/%s", r->scenes_dir, id) ||
        !registry_path(assets_dir, sizeof assets_dir, &err, "%s/assets", scene_dir) ||
        !registry_path(path, sizeof path, &err, "%s/scene.json", scene_dir)) {
        registry_warn(r, "registry: skipping uploaded scene '%s': %s", id, err.message);
        return;
    }
    registry_clean_leftovers(scene_dir);
    registry_clean_leftovers(assets_dir);
    struct stat st;
    if (lstat(path, &st) != 0 && errno == ENOENT) return;  /* assets staged before their scene */
    char *json = NULL;
    size_t len = 0;
    struct scene *scene = NULL;
    uint64_t hash = 0;
    uint32_t assets = 0;
    bool exists, builtin;
    registry_peek(r, id, &exists, &builtin, &hash);
    if (exists && builtin) {
        registry_warn(r, "registry: skipping uploaded scene '%s' (%s): a built-in scene has this id; its files are kept",
                      id, path);
        return;
    }
    if (exists) return;  /* loading after the start: a PUT of this id came first, and wrote it */
    bool ok = fileio_read_all(path, "scene file", path, REGISTRY_JSON_MAX_BYTES, &json, &len, &err) &&
              registry_hash_content(json, len, assets_dir, &hash, &assets, &err) &&
              (scene = registry_load(json, len, assets_dir, id, &err)) != NULL &&
              registry_insert(r, id, false, scene, hash, assets, &err);
    free(json);
    if (ok && r->budget) {
        /* Loaded after registry_set_budget: charged as those before it were (it is held). */
        struct registry_info info;
        if (registry_info(r, id, &info)) budget_charge(r->budget, BUDGET_SCENES, info.scene_bytes);
    }
    if (!ok) {
        char msg[800];
        registry_warn(r, "registry: skipping uploaded scene '%s' (%s, kept on disk): %s: %s", id, path,
                      err_code_name(err.code), err_format(&err, msg, sizeof msg));
        scene_release(scene);
    }
}

/* Each scene is loaded under its write lock, as a PUT is, so that loading while requests are
 * served cannot interleave with a PUT or DELETE of the same id. `stop` (may be NULL) is read
 * between scenes. */
static bool registry_load_uploads(struct registry *r, atomic_bool *stop, struct err *err)
{
    struct registry_names ids;
    if (!registry_list_dir(r->scenes_dir, S_IFDIR, false, &ids, NULL, err)) {
        if (err) err->code = ERR_IO;
        return false;
    }
    for (size_t i = 0; i < ids.n && !(stop && atomic_load(stop)); i++) {
        if (ids.v[i][0] == '.') continue;
        if (!registry_id_valid(ids.v[i])) {
            registry_warn(r, "registry: skipping '%s/%s': not a valid scene id", r->scenes_dir, ids.v[i]);
            continue;
        }
        pthread_mutex_t *wl = registry_write_lock(r, ids.v[i]);
        pthread_mutex_lock(wl);
        registry_load_upload(r, ids.v[i]);
        pthread_mutex_unlock(wl);
    }
    registry_names_free(&ids);
    return true;
}

bool registry_load_stored(struct registry *r, atomic_bool *stop, struct err *err)
{
    return registry_load_uploads(r, stop, err);
}

static struct registry *registry_create(const char *library_dir, const char *data_dir, registry_warn_fn *warn,
                                        void *warn_ctx, bool stored, struct err *err)
{
    if (!data_dir || !data_dir[0]) {
        err_set(err, ERR_INVALID, NULL, "no data directory");
        return NULL;
    }
    struct registry *r = calloc(1, sizeof *r);
    if (!r) {
        err_set(err, ERR_NOMEM, NULL, "out of memory");
        return NULL;
    }
    pthread_mutex_init(&r->lock, NULL);
    for (int i = 0; i < REGISTRY_WRITE_STRIPES; i++) pthread_mutex_init(&r->write_locks[i], NULL);
    r->warn = warn;
    r->warn_ctx = warn_ctx;
    size_t n = strlen(data_dir) + sizeof "/scenes";
    r->scenes_dir = malloc(n);
    if (!r->scenes_dir) {
        registry_free(r);
        err_set(err, ERR_NOMEM, NULL, "out of memory");
        return NULL;
    }
    snprintf(r->scenes_dir, n, "%s/scenes", data_dir);
    if (!registry_mkdir_p(r->scenes_dir, err)) {
        registry_free(r);
        return NULL;
    }
    if (library_dir) registry_load_library(r, library_dir);
    if (stored && !registry_load_uploads(r, NULL, err)) {
        registry_free(r);
        return NULL;
    }
    return r;
}

struct registry *registry_new(const char *library_dir, const char *data_dir, registry_warn_fn *warn, void *warn_ctx,
                              struct err *err)
{
    return registry_create(library_dir, data_dir, warn, warn_ctx, true, err);
}

struct registry *registry_new_deferred(const char *library_dir, const char *data_dir, registry_warn_fn *warn,
                                       void *warn_ctx, struct err *err)
{
    return registry_create(library_dir, data_dir, warn, warn_ctx, false, err);
}

void registry_set_budget(struct registry *r, struct budget *budget)
{
    for (int i = 0; i < REGISTRY_WRITE_STRIPES; i++) pthread_mutex_lock(&r->write_locks[i]);
    pthread_mutex_lock(&r->lock);
    r->budget = budget;
    for (size_t i = 0; budget && i < r->count; i++)
        if (!r->entries[i]->info.builtin) budget_charge(budget, BUDGET_SCENES, r->entries[i]->info.scene_bytes);
    pthread_mutex_unlock(&r->lock);
    for (int i = REGISTRY_WRITE_STRIPES - 1; i >= 0; i--) pthread_mutex_unlock(&r->write_locks[i]);
}

void registry_free(struct registry *r)
{
    if (!r) return;
    for (size_t i = 0; i < r->count; i++) {
        scene_release(r->entries[i]->scene);
        free(r->entries[i]);
    }
    free(r->entries);
    free(r->scenes_dir);
    pthread_mutex_destroy(&r->lock);
    for (int i = 0; i < REGISTRY_WRITE_STRIPES; i++) pthread_mutex_destroy(&r->write_locks[i]);
    free(r);
}

/* ---- uploads ---- */

static bool registry_put_scene_locked(struct registry *r, const char *id, const char *json, size_t len,
                                      enum registry_put_result *result, struct err *err)
{
    bool exists, builtin;
    uint64_t old_hash, hash;
    uint32_t assets;
    registry_peek(r, id, &exists, &builtin, &old_hash);
    if (builtin) {
        /* Built-ins have no uploaded assets: their hash covers the JSON alone. */
        if (!registry_hash_content(json, len, NULL, &hash, &assets, err)) return false;
        if (hash == old_hash) {
            *result = REGISTRY_UNCHANGED;
            return true;
        }
        return err_set(err, ERR_CONFLICT, "id",
                       "scene '%s' is built-in, and built-in scenes are read-only (upload under another id)", id);
    }
    char scene_dir[PATH_MAX], assets_dir[PATH_MAX];
    if (!registry_path(scene_dir, sizeof scene_dir, err, "%s/%s", r->scenes_dir, id) ||
        !registry_path(assets_dir, sizeof assets_dir, err, "%s/assets", scene_dir) ||
        !registry_own_dir(scene_dir, err) || !registry_own_dir(assets_dir, err) ||
        !registry_hash_content(json, len, assets_dir, &hash, &assets, err))
        return false;
    if (exists && hash == old_hash) {
        *result = REGISTRY_UNCHANGED;
        return true;
    }
    /* Validate and commit from the request bytes before anything is written: a scene that
     * does not load never reaches the disk, and the one on disk stays the one in the table. */
    struct scene *scene = registry_load(json, len, assets_dir, id, err);
    if (!scene) return false;
    if (!registry_budget_reserve(r, scene, err)) {
        scene_release(scene);
        return false;
    }
    if (!registry_mkdir(scene_dir, err) || !registry_write_atomic(scene_dir, "scene.json", json, len, err)) {
        registry_budget_release(r, scene);
        scene_release(scene);
        return false;
    }
    if (exists) {
        struct scene *old = registry_replace(r, id, scene, hash, assets);
        registry_budget_release(r, old);
        scene_release(old);
        *result = REGISTRY_REPLACED;
        return true;
    }
    if (!registry_insert(r, id, false, scene, hash, assets, err)) {
        registry_budget_release(r, scene);
        scene_release(scene);
        return false;  /* only out of memory: the file is on disk and loads at the next start */
    }
    *result = REGISTRY_CREATED;
    return true;
}

bool registry_put_scene(struct registry *r, const char *id, const char *json, size_t len,
                        enum registry_put_result *result, struct err *err)
{
    enum registry_put_result dummy;
    if (!result) result = &dummy;
    if (!registry_id_valid(id)) return err_set(err, ERR_INVALID, "id", "scene id must match [A-Za-z0-9_-]{1,64}");
    if (!json && len) return err_set(err, ERR_INVALID, "", "no JSON text");
    pthread_mutex_t *wl = registry_write_lock(r, id);
    pthread_mutex_lock(wl);
    bool ok = registry_put_scene_locked(r, id, json, len, result, err);
    pthread_mutex_unlock(wl);
    return ok;
}

/* Copies a file when a hard link is impossible (file systems without them). */
static bool registry_link_or_copy(const char *from, const char *to, struct err *err)
{
    if (link(from, to) == 0) return true;
    char *data;
    size_t size;
    if (!fileio_read_all(from, "asset", NULL, MESH_IO_MAX_FILE_BYTES, &data, &size, err)) return false;
    int fd = open(to, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
    bool ok = fd >= 0;
    size_t done = 0;
    while (ok && done < size) {
        ssize_t w = write(fd, data + done, size - done);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) ok = false;
        else done += (size_t)w;
    }
    int e = errno;
    if (fd >= 0 && close(fd) != 0) ok = false;
    free(data);
    if (!ok) return err_set(err, ERR_IO, NULL, "cannot stage an asset in '%s': %s", to, strerror(e));
    return true;
}

/* A private folder holding the scene's assets as they would be with `tmp` stored as `name`
 * (hard links, so nothing is copied), to load the scene against them before the new asset
 * replaces anything under its final name. */
static bool registry_stage(const char *scene_dir, const char *assets_dir, const char *name, const char *tmp,
                           char *stage, size_t stage_size, struct err *err)
{
    if (!registry_path(stage, stage_size, err, "%s/" REGISTRY_STAGE_PREFIX "XXXXXX", scene_dir)) return false;
    if (!mkdtemp(stage)) return err_set(err, ERR_IO, NULL, "cannot create a folder in '%s': %s", scene_dir,
                                        strerror(errno));
    struct registry_names names;
    bool ok = registry_list_dir(assets_dir, S_IFREG, false, &names, NULL, err);
    for (size_t i = 0; ok && i < names.n; i++) {
        if (!registry_asset_name_valid(names.v[i]) || strcmp(names.v[i], name) == 0) continue;
        char from[PATH_MAX], to[PATH_MAX];
        ok = registry_path(from, sizeof from, err, "%s/%s", assets_dir, names.v[i]) &&
             registry_path(to, sizeof to, err, "%s/%s", stage, names.v[i]) && registry_link_or_copy(from, to, err);
    }
    registry_names_free(&names);
    char to[PATH_MAX];
    ok = ok && registry_path(to, sizeof to, err, "%s/%s", stage, name) && registry_link_or_copy(tmp, to, err);
    if (!ok) registry_remove_tree(stage, 1);
    return ok;
}

static bool registry_put_asset_locked(struct registry *r, const char *id, const char *name, const void *data,
                                      size_t len, bool *created, struct err *err)
{
    char scene_dir[PATH_MAX], assets_dir[PATH_MAX], path[PATH_MAX], json_path[PATH_MAX];
    if (!registry_path(scene_dir, sizeof scene_dir, err, "%s/%s", r->scenes_dir, id) ||
        !registry_path(assets_dir, sizeof assets_dir, err, "%s/assets", scene_dir) ||
        !registry_path(path, sizeof path, err, "%s/%s", assets_dir, name) ||
        !registry_path(json_path, sizeof json_path, err, "%s/scene.json", scene_dir))
        return false;
    if (!registry_own_dir(scene_dir, err) || !registry_own_dir(assets_dir, err)) return false;
    struct stat st;
    *created = lstat(path, &st) != 0;
    if (!*created && registry_file_equals(path, data, len)) return true;  /* nothing changes */
    char tmp[PATH_MAX];
    if (!registry_mkdir(scene_dir, err) || !registry_mkdir(assets_dir, err) ||
        !registry_write_tmp(assets_dir, data, len, tmp, sizeof tmp, err))
        return false;
    bool exists, builtin;
    uint64_t hash;
    uint32_t assets = 0;
    registry_peek(r, id, &exists, &builtin, &hash);
    struct scene *scene = NULL;
    if (exists) {
        /* The scene is reloaded against the new asset set before the asset takes its final
         * name, so a failure leaves the old asset and the old scene in place. The JSON is read
         * back from disk (this registry wrote it; the write lock keeps it stable) instead of being
         * kept in memory for every scene. Every asset change reloads the scene, used or not:
         * telling whether the JSON names the asset would need the JSON parser. */
        char stage[PATH_MAX], *json = NULL;
        size_t jlen = 0;
        bool staged = false;
        bool ok = fileio_read_all(json_path, "scene file", "scene.json", REGISTRY_JSON_MAX_BYTES, &json, &jlen, err) &&
                  (staged = registry_stage(scene_dir, assets_dir, name, tmp, stage, sizeof stage, err)) &&
                  registry_hash_content(json, jlen, stage, &hash, &assets, err) &&
                  (scene = registry_load(json, jlen, stage, id, err)) != NULL;
        free(json);
        if (staged) registry_remove_tree(stage, 1);
        if (ok && !registry_budget_reserve(r, scene, err)) {
            scene_release(scene);
            ok = false;
        }
        if (!ok) {
            unlink(tmp);
            return false;
        }
    }
    if (!registry_rename_into(tmp, assets_dir, name, err)) {
        unlink(tmp);
        registry_budget_release(r, scene);
        scene_release(scene);
        return false;
    }
    if (scene) {
        struct scene *old = registry_replace(r, id, scene, hash, assets);
        registry_budget_release(r, old);
        scene_release(old);
    }
    return true;
}

bool registry_put_asset(struct registry *r, const char *id, const char *name, const void *data, size_t len,
                        bool *created, struct err *err)
{
    bool dummy;
    if (!created) created = &dummy;
    *created = false;
    if (!registry_id_valid(id)) return err_set(err, ERR_INVALID, "id", "scene id must match [A-Za-z0-9_-]{1,64}");
    if (!registry_asset_name_valid(name))
        return err_set(err, ERR_INVALID, "name",
                       "asset name must match [A-Za-z0-9_-][A-Za-z0-9_.-]{0,63} and end in .ply or .obj");
    bool exists, builtin;
    uint64_t hash;
    /* Built-ins are fixed after registry_new, so this answer cannot go stale. */
    registry_peek(r, id, &exists, &builtin, &hash);
    if (builtin) return err_set(err, ERR_CONFLICT, "id", "scene '%s' is built-in, and built-in scenes are read-only", id);
    if (len > MESH_IO_MAX_FILE_BYTES)
        return err_set(err, ERR_LIMIT, "name", "asset '%s' is %zu bytes, more than the limit of %u", name, len,
                       MESH_IO_MAX_FILE_BYTES);
    if (!data && len) return err_set(err, ERR_INVALID, "name", "no asset bytes");
    /* Decoding is the expensive check and touches no state: done before taking the write lock. */
    struct mesh mesh = {0};
    if (!mesh_io_load_memory(data ? data : "", len, name, mesh_io_format_of(name), &mesh, err)) return false;
    mesh_io_destroy(&mesh);
    pthread_mutex_t *wl = registry_write_lock(r, id);
    pthread_mutex_lock(wl);
    bool ok = registry_put_asset_locked(r, id, name, data ? data : "", len, created, err);
    pthread_mutex_unlock(wl);
    if (!ok) *created = false;
    return ok;
}

/* ---- lookups and sessions ---- */

struct scene *registry_acquire(struct registry *r, const char *id)
{
    struct scene *scene = NULL;
    if (!id) return NULL;
    pthread_mutex_lock(&r->lock);
    size_t pos;
    if (registry_find_locked(r, id, &pos)) {
        scene = r->entries[pos]->scene;
        scene_retain(scene);
    }
    pthread_mutex_unlock(&r->lock);
    return scene;
}

bool registry_session_added(struct registry *r, const char *id, struct err *err)
{
    bool found = false;
    if (id) {
        pthread_mutex_lock(&r->lock);
        size_t pos;
        found = registry_find_locked(r, id, &pos);
        if (found) r->entries[pos]->info.sessions++;
        pthread_mutex_unlock(&r->lock);
    }
    if (!found) return err_set(err, ERR_NOT_FOUND, "id", "scene '%s' not found", id ? id : "");
    return true;
}

void registry_session_removed(struct registry *r, const char *id)
{
    if (!id) return;
    pthread_mutex_lock(&r->lock);
    size_t pos;
    /* Saturating: after a forced delete and a new PUT of the same id, the old scene's sessions
     * end against the new entry; the count must not wrap. */
    if (registry_find_locked(r, id, &pos) && r->entries[pos]->info.sessions > 0) r->entries[pos]->info.sessions--;
    pthread_mutex_unlock(&r->lock);
}

bool registry_delete(struct registry *r, const char *id, bool force, struct err *err)
{
    if (!registry_id_valid(id)) return err_set(err, ERR_NOT_FOUND, "id", "scene '%s' not found", id ? id : "");
    char scene_dir[PATH_MAX], json_path[PATH_MAX];
    if (!registry_path(scene_dir, sizeof scene_dir, err, "%s/%s", r->scenes_dir, id) ||
        !registry_path(json_path, sizeof json_path, err, "%s/scene.json", scene_dir))
        return false;
    pthread_mutex_t *wl = registry_write_lock(r, id);
    pthread_mutex_lock(wl);
    pthread_mutex_lock(&r->lock);
    size_t pos;
    struct registry_entry *e = NULL;
    bool ok = true;
    if (!registry_find_locked(r, id, &pos)) {
        ok = err_set(err, ERR_NOT_FOUND, "id", "scene '%s' not found", id);
    } else if (r->entries[pos]->info.builtin) {
        ok = err_set(err, ERR_CONFLICT, "id", "scene '%s' is built-in, and built-in scenes are read-only", id);
    } else if (r->entries[pos]->info.sessions > 0 && !force) {
        ok = err_set(err, ERR_CONFLICT, "id", "scene '%s' has %u live session(s); delete them or use force", id,
                     r->entries[pos]->info.sessions);
    } else if (!registry_own_dir(scene_dir, err)) {
        ok = false;
    } else if (unlink(json_path) != 0 && errno != ENOENT) {
        /* The one file operation under `lock`: the live-session check and the removal must be
         * atomic with respect to registry_session_added, and scene.json going is what makes the
         * deletion durable (staged assets without it are never loaded). */
        ok = err_set(err, ERR_IO, "id", "cannot delete scene '%s': %s", id, strerror(errno));
    } else {
        e = r->entries[pos];
        memmove(&r->entries[pos], &r->entries[pos + 1], (r->count - pos - 1) * sizeof *r->entries);
        r->count--;
    }
    pthread_mutex_unlock(&r->lock);
    if (e) {
        struct err ignored;
        registry_fsync_dir(scene_dir, &ignored);
        if (!registry_remove_tree(scene_dir, 2))
            registry_warn(r, "registry: scene '%s' deleted, but some of its files in '%s' remain", id, scene_dir);
        registry_budget_release(r, e->scene);
        scene_release(e->scene);  /* sessions keep their own references */
        free(e);
    }
    pthread_mutex_unlock(wl);
    return ok;
}

bool registry_info(struct registry *r, const char *id, struct registry_info *out)
{
    if (!id) return false;
    pthread_mutex_lock(&r->lock);
    size_t pos;
    bool found = registry_find_locked(r, id, &pos);
    if (found && out) *out = r->entries[pos]->info;
    pthread_mutex_unlock(&r->lock);
    return found;
}

size_t registry_list(struct registry *r, struct registry_info *out, size_t max)
{
    pthread_mutex_lock(&r->lock);
    size_t total = r->count;
    for (size_t i = 0; out && i < max && i < total; i++) out[i] = r->entries[i]->info;
    pthread_mutex_unlock(&r->lock);
    return total;
}
