/* test_registry.c — the scene registry (server/registry.c): built-in ids from the library in
 * scenes/, idempotent uploads by content hash, asset rules, crash-safe persistence and reload
 * on restart, delete conflicts with live sessions, and writers racing on one id.
 * Every test works in its own mkdtemp data directory and removes it at the end. Run from the
 * repository root (the library is the real scenes/ folder). */
#include <dirent.h>
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "registry.h"
#include "test.h"

#define CAM "\"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], \"fov_deg\": 40}"
#define WHITE "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}}"
#define SPHERE(r) "{" CAM ", " WHITE ", \"shapes\": [{\"type\": \"sphere\", \"material\": \"white\", " \
                  "\"center\": [0, 0, 0], \"radius\": " #r "}]}"
#define MESH_SCENE(file, extra) "{" CAM ", " WHITE ", \"shapes\": [{\"type\": \"mesh\", \"material\": \"white\", " \
                                "\"file\": \"" file "\"" extra "}]}"

static const char tetra_ply[] =
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 4\nproperty list uchar int vertex_indices\nend_header\n"
    "1 1 1\n1 -1 -1\n-1 1 -1\n-1 -1 1\n3 0 2 3\n3 0 3 1\n3 0 1 2\n3 1 3 2\n";
/* Two triangles; the second variant reaches 1e10, which a 1e30 scale sends past float range. */
static const char square_ply[] =
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n";
static const char huge_ply[] =
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n1e10 0 0\n0 1 0\n3 0 1 2\n";
static const char square_obj[] = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";
/* Line 11 has two values where the header declares three. */
static const char corrupt_ply[] =
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n1 0\n0 1 0\n3 0 1 2\n";

/* ---- helpers ---- */

struct warnings {
    int count;
    char last[1024];
    char all[4096];
};

static void collect_warning(void *ctx, const char *message)
{
    struct warnings *w = ctx;
    w->count++;
    snprintf(w->last, sizeof w->last, "%s", message);
    size_t n = strlen(w->all);
    snprintf(w->all + n, sizeof w->all - n, "%s\n", message);
}

static char *make_data_dir(void)
{
    char tmpl[] = "/tmp/restird-registry-XXXXXX";
    char *dir = mkdtemp(tmpl);
    return dir ? strdup(dir) : NULL;
}

static void remove_tree(const char *path)
{
    struct stat st;
    if (lstat(path, &st) != 0) return;
    if (S_ISDIR(st.st_mode)) {
        DIR *d = opendir(path);
        if (d) {
            struct dirent *de;
            while ((de = readdir(d))) {
                if (strcmp(de->d_name, ".") == 0 || strcmp(de->d_name, "..") == 0) continue;
                char child[4096];
                snprintf(child, sizeof child, "%s/%s", path, de->d_name);
                remove_tree(child);
            }
            closedir(d);
        }
        rmdir(path);
    } else {
        unlink(path);
    }
}

static void free_data_dir(char *dir)
{
    if (dir) remove_tree(dir);
    free(dir);
}

static bool path_exists(const char *fmt_dir, const char *rest)
{
    char p[4096];
    snprintf(p, sizeof p, "%s%s", fmt_dir, rest);
    struct stat st;
    return lstat(p, &st) == 0;
}

/* Contents of dir+rest, malloc'd and NUL-terminated, or NULL. */
static char *read_text(const char *dir, const char *rest, size_t *len)
{
    char p[4096];
    snprintf(p, sizeof p, "%s%s", dir, rest);
    FILE *f = fopen(p, "rb");
    if (!f) return NULL;
    char *buf = malloc(1 << 20);
    size_t n = buf ? fread(buf, 1, (1 << 20) - 1, f) : 0;
    fclose(f);
    if (!buf) return NULL;
    buf[n] = '\0';
    if (len) *len = n;
    return buf;
}

static bool file_equals(const char *dir, const char *rest, const char *want)
{
    size_t n;
    char *got = read_text(dir, rest, &n);
    bool same = got && n == strlen(want) && memcmp(got, want, n) == 0;
    free(got);
    return same;
}

static void write_text(const char *dir, const char *rest, const char *text)
{
    char p[4096];
    snprintf(p, sizeof p, "%s%s", dir, rest);
    FILE *f = fopen(p, "wb");
    if (!f) return;
    fwrite(text, 1, strlen(text), f);
    fclose(f);
}

static ino_t inode_of(const char *dir, const char *rest)
{
    char p[4096];
    snprintf(p, sizeof p, "%s%s", dir, rest);
    struct stat st;
    return stat(p, &st) == 0 ? st.st_ino : 0;
}

static struct registry *open_registry(const char *data, struct warnings *w)
{
    struct err err = {0};
    struct registry *r = registry_new("scenes", data, w ? collect_warning : NULL, w, &err);
    if (!r) fprintf(stderr, "  registry_new: %s: %s: %s\n", err_code_name(err.code), err.where, err.message);
    return r;
}

/* A fresh data directory and a registry on it; NULL (and the directory removed) on failure. */
static struct registry *fresh_registry(char **data, struct warnings *w)
{
    *data = make_data_dir();
    struct registry *r = open_registry(*data, w);
    CHECK(r != NULL);
    if (!r) free_data_dir(*data);
    return r;
}

static bool put(struct registry *r, const char *id, const char *json, enum registry_put_result *res, struct err *err)
{
    memset(err, 0, sizeof *err);
    return registry_put_scene(r, id, json, strlen(json), res, err);
}

static bool put_asset(struct registry *r, const char *id, const char *name, const char *text, bool *created,
                      struct err *err)
{
    memset(err, 0, sizeof *err);
    return registry_put_asset(r, id, name, text, strlen(text), created, err);
}

#define CHECK_ERR(ok, err, want_code, want_where)                                                             \
    CHECK_MSG(!(ok) && (err).code == (want_code) && strcmp((err).where, (want_where)) == 0,                    \
              "want %s at '%s', got ok=%d %s at '%s': %s", err_code_name(want_code), want_where, (int)(ok),      \
              err_code_name((err).code), (err).where, (err).message)

#define CHECK_OK(ok, err) \
    CHECK_MSG(ok, "unexpected error %s at '%s': %s", err_code_name((err).code), (err).where, (err).message)

/* ---- built-ins ---- */

static void test_builtins_listed_with_ids_and_counts(void)
{
    struct warnings w = {0};
    char *data;
    struct registry *r = fresh_registry(&data, &w);
    if (!r) return;
    CHECK_MSG(w.count == 0, "unexpected warning: %s", w.last);

    static const struct {
        const char *id;
        uint32_t materials, shapes, triangles, emitters;
    } want[] = {
        {"cornell-box", 4, 16, 32, 2},
        {"cornell-glossy", 8, 20, 32, 2},
        {"door-ajar", 8, 18, 124, 2},
        {"furnace", 1, 1, 0, 1},
        {"furnace-albedo-half", 1, 1, 0, 1},
    };
    struct registry_info list[64];
    size_t total = registry_list(r, list, 64);
    CHECK(total >= 5 && total <= 64);
    for (size_t i = 1; i < total && i < 64; i++) CHECK_MSG(strcmp(list[i - 1].id, list[i].id) < 0, "list not sorted");
    for (size_t k = 0; k < sizeof want / sizeof want[0]; k++) {
        struct registry_info info;
        bool found = registry_info(r, want[k].id, &info);
        CHECK_MSG(found, "built-in '%s' missing", want[k].id);
        if (!found) continue;
        CHECK(info.builtin);
        CHECK_MSG(info.materials == want[k].materials && info.shapes == want[k].shapes &&
                      info.triangles == want[k].triangles && info.emitters == want[k].emitters,
                  "%s: %u materials, %u shapes, %u triangles, %u emitters", want[k].id, info.materials, info.shapes,
                  info.triangles, info.emitters);
        CHECK(info.assets == 0 && info.sessions == 0);
        CHECK(strlen(info.hash) == 16 && strspn(info.hash, "0123456789abcdef") == 16);
        CHECK(info.scene_bytes > 0);
    }
    /* 32 triangles with positions and indices plus the 64-byte-per-primitive BVH estimate. */
    struct registry_info cb;
    CHECK(registry_info(r, "cornell-box", &cb) && cb.scene_bytes >= 32 * 64);

    /* The documented hash of a scene without assets: FNV-1a of (u64 LE length, bytes). */
    size_t len;
    char *json = read_text("scenes/cornell-box/scene.json", "", &len);
    CHECK(json != NULL);
    if (json) {
        uint64_t h = 0xcbf29ce484222325ull;
        for (int i = 0; i < 8; i++) h = (h ^ (unsigned char)((uint64_t)len >> (8 * i))) * 0x100000001b3ull;
        for (size_t i = 0; i < len; i++) h = (h ^ (unsigned char)json[i]) * 0x100000001b3ull;
        char hex[17];
        snprintf(hex, sizeof hex, "%016llx", (unsigned long long)h);
        CHECK_MSG(strcmp(hex, cb.hash) == 0, "hash %s, want %s", cb.hash, hex);
    }
    free(json);

    struct scene *s = registry_acquire(r, "cornell-box");
    CHECK(s != NULL && s->refcount == 2 && s->accel != NULL);
    if (s) scene_release(s);
    CHECK(registry_acquire(r, "no-such-scene") == NULL);
    CHECK(!registry_info(r, "no-such-scene", NULL));
    registry_free(r);
    free_data_dir(data);
}

static void test_builtin_is_read_only(void)
{
    char *data;
    struct registry *r = fresh_registry(&data, NULL);
    if (!r) return;
    struct err err;
    enum registry_put_result res = REGISTRY_CREATED;
    char *json = read_text("scenes/furnace/albedo-half.json", "", NULL);
    CHECK(json != NULL);
    if (json) {
        bool ok = put(r, "furnace-albedo-half", json, &res, &err);
        CHECK_OK(ok, err);
        CHECK(res == REGISTRY_UNCHANGED);
    }
    free(json);
    bool ok = put(r, "furnace-albedo-half", SPHERE(2), &res, &err);
    CHECK_ERR(ok, err, ERR_CONFLICT, "id");
    CHECK(strstr(err.message, "read-only") != NULL);
    ok = put_asset(r, "furnace", "x.ply", tetra_ply, NULL, &err);
    CHECK_ERR(ok, err, ERR_CONFLICT, "id");
    memset(&err, 0, sizeof err);
    ok = registry_delete(r, "cornell-box", true, &err);
    CHECK_ERR(ok, err, ERR_CONFLICT, "id");
    CHECK(registry_info(r, "cornell-box", NULL));
    CHECK(!path_exists(data, "/scenes/furnace-albedo-half") && !path_exists(data, "/scenes/furnace"));
    registry_free(r);
    free_data_dir(data);
}

static void test_library_ids_and_skips(void)
{
    char *data = make_data_dir();
    char lib[4096], dir[4096];
    snprintf(lib, sizeof lib, "%s/lib", data);
    static const char *const dirs[] = {"", "/ok", "/a", "/a-b", "/broken", "/.hidden"};
    for (size_t i = 0; i < sizeof dirs / sizeof dirs[0]; i++) {
        snprintf(dir, sizeof dir, "%s%s", lib, dirs[i]);
        mkdir(dir, 0755);
    }
    write_text(lib, "/ok/scene.json", SPHERE(1));
    write_text(lib, "/ok/two.json", SPHERE(2));
    write_text(lib, "/ok/bad name.json", SPHERE(1));      /* id "ok-bad name": skipped */
    write_text(lib, "/ok/notes.txt", "not a scene");
    write_text(lib, "/a/b.json", SPHERE(1));              /* id "a-b", loaded first (sorted) */
    write_text(lib, "/a-b/scene.json", SPHERE(3));        /* id "a-b" again: skipped */
    write_text(lib, "/broken/scene.json", SPHERE(-1));    /* does not load: skipped */
    write_text(lib, "/.hidden/scene.json", SPHERE(1));    /* hidden folder: ignored */
    char store[4096];
    snprintf(store, sizeof store, "%s/store", data);
    struct warnings w = {0};
    struct err err = {0};
    struct registry *r = registry_new(lib, store, collect_warning, &w, &err);
    CHECK(r != NULL);
    if (r) {
        struct registry_info list[8];
        size_t n = registry_list(r, list, 8);
        CHECK_MSG(n == 3, "%zu scenes", n);
        if (n == 3) {
            CHECK(strcmp(list[0].id, "a-b") == 0 && strcmp(list[1].id, "ok") == 0 && strcmp(list[2].id, "ok-two") == 0);
            for (size_t i = 0; i < 3; i++) CHECK(list[i].builtin);
        }
        CHECK_MSG(w.count == 3, "%d warnings, last: %s", w.count, w.last);
        CHECK_MSG(strstr(w.all, "broken/scene.json") && strstr(w.all, "/shapes/0/radius") &&
                      strstr(w.all, "'ok-bad name'") && strstr(w.all, "a-b/scene.json"),
                  "%s", w.all);
        /* The duplicate kept the first one: a-b has radius 1. */
        struct scene *s = registry_acquire(r, "a-b");
        CHECK(s && s->shapes[0].radius == 1.0f);
        if (s) scene_release(s);
        registry_free(r);
    }
    /* No library at all is fine. */
    r = registry_new(NULL, store, NULL, NULL, &err);
    CHECK(r && registry_list(r, NULL, 0) == 0);
    registry_free(r);
    free_data_dir(data);
}

/* ---- scene uploads ---- */

static void test_put_created_unchanged_replaced(void)
{
    char *data;
    struct registry *r = fresh_registry(&data, NULL);
    if (!r) return;
    struct err err;
    enum registry_put_result res = REGISTRY_UNCHANGED;
    bool ok = put(r, "ball", SPHERE(1), &res, &err);
    CHECK_OK(ok, err);
    CHECK(res == REGISTRY_CREATED);
    CHECK(file_equals(data, "/scenes/ball/scene.json", SPHERE(1)));
    struct registry_info a, b, c;
    CHECK(registry_info(r, "ball", &a) && !a.builtin && a.shapes == 1 && a.emitters == 0 && a.assets == 0);
    ino_t ino = inode_of(data, "/scenes/ball/scene.json");

    ok = put(r, "ball", SPHERE(1), &res, &err);
    CHECK_OK(ok, err);
    CHECK(res == REGISTRY_UNCHANGED);
    CHECK_MSG(inode_of(data, "/scenes/ball/scene.json") == ino, "an identical PUT rewrote the file");
    CHECK(registry_info(r, "ball", &b) && strcmp(a.hash, b.hash) == 0);

    ok = put(r, "ball", SPHERE(2), &res, &err);
    CHECK_OK(ok, err);
    CHECK(res == REGISTRY_REPLACED);
    CHECK(file_equals(data, "/scenes/ball/scene.json", SPHERE(2)));
    CHECK(registry_info(r, "ball", &c) && strcmp(a.hash, c.hash) != 0);

    /* No temporary files are left next to the scene. */
    char p[4096];
    snprintf(p, sizeof p, "%s/scenes/ball", data);
    DIR *d = opendir(p);
    int entries = 0;
    for (struct dirent *de; d && (de = readdir(d));) entries += de->d_name[0] != '.';
    int hidden = 0;
    if (d) {
        rewinddir(d);
        for (struct dirent *de; (de = readdir(d));)
            hidden += de->d_name[0] == '.' && strcmp(de->d_name, ".") && strcmp(de->d_name, "..");
        closedir(d);
    }
    CHECK_MSG(entries == 1 && hidden == 0, "%d entries, %d hidden in the scene folder", entries, hidden);

    ok = put(r, "a/b", SPHERE(1), &res, &err);
    CHECK_ERR(ok, err, ERR_INVALID, "id");
    ok = put(r, "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa", SPHERE(1), &res, &err);
    CHECK_ERR(ok, err, ERR_INVALID, "id");
    ok = put(r, "", SPHERE(1), &res, &err);
    CHECK_ERR(ok, err, ERR_INVALID, "id");

    struct registry_info list[64];
    size_t n = registry_list(r, list, 64), seen = 0;
    for (size_t i = 0; i < n && i < 64; i++) seen += strcmp(list[i].id, "ball") == 0 && !list[i].builtin;
    CHECK(seen == 1);
    registry_free(r);
    free_data_dir(data);
}

static void test_put_invalid_leaves_registry_unchanged(void)
{
    char *data;
    struct registry *r = fresh_registry(&data, NULL);
    if (!r) return;
    struct err err;
    enum registry_put_result res;
    bool ok = put(r, "ball", SPHERE(1), &res, &err);
    CHECK_OK(ok, err);
    struct registry_info before, after;
    CHECK(registry_info(r, "ball", &before));
    size_t count = registry_list(r, NULL, 0);

    ok = put(r, "ball", SPHERE(-1), &res, &err);
    CHECK_ERR(ok, err, ERR_INVALID, "/shapes/0/radius");
    ok = put(r, "ball", "{\"camera\": ", &res, &err);
    CHECK_ERR(ok, err, ERR_PARSE, "");
    CHECK(registry_info(r, "ball", &after) && strcmp(before.hash, after.hash) == 0);
    CHECK(file_equals(data, "/scenes/ball/scene.json", SPHERE(1)));

    ok = put(r, "fresh", "{" CAM ", " WHITE ", \"shapes\": [{\"type\": \"sphere\", \"material\": \"black\", "
                         "\"center\": [0, 0, 0], \"radius\": 1}]}", &res, &err);
    CHECK_ERR(ok, err, ERR_NOT_FOUND, "/shapes/0/material");
    /* A mesh in a scene with no assets folder: clear message, pointer to the mesh path, and
     * no server path in the message. */
    ok = put(r, "fresh", MESH_SCENE("tetra.ply", ""), &res, &err);
    CHECK_ERR(ok, err, ERR_NOT_FOUND, "/shapes/0/file");
    CHECK_MSG(strstr(err.message, "no uploaded assets") && !strstr(err.message, data), "%s", err.message);
    CHECK(!registry_info(r, "fresh", NULL) && !path_exists(data, "/scenes/fresh"));
    CHECK(registry_list(r, NULL, 0) == count);
    registry_free(r);
    free_data_dir(data);
}

/* ---- assets ---- */

static void test_assets_then_scene(void)
{
    char *data;
    struct registry *r = fresh_registry(&data, NULL);
    if (!r) return;
    struct err err;
    bool created = false;
    bool ok = put_asset(r, "meshy", "tetra.ply", tetra_ply, &created, &err);
    CHECK_OK(ok, err);
    CHECK(created && file_equals(data, "/scenes/meshy/assets/tetra.ply", tetra_ply));
    CHECK(!registry_info(r, "meshy", NULL));  /* staged: no scene yet */
    ok = put_asset(r, "meshy", "tetra.ply", tetra_ply, &created, &err);
    CHECK_OK(ok, err);
    CHECK(!created);

    enum registry_put_result res;
    ok = put(r, "meshy", MESH_SCENE("missing.ply", ""), &res, &err);
    CHECK_ERR(ok, err, ERR_NOT_FOUND, "/shapes/0/file");
    ok = put(r, "meshy", MESH_SCENE("tetra.ply", ""), &res, &err);
    CHECK_OK(ok, err);
    CHECK(res == REGISTRY_CREATED);
    struct registry_info a, b, c, d;
    CHECK(registry_info(r, "meshy", &a) && a.triangles == 4 && a.assets == 1);
    ok = put(r, "meshy", MESH_SCENE("tetra.ply", ""), &res, &err);
    CHECK_OK(ok, err);
    CHECK(res == REGISTRY_UNCHANGED);

    /* A second asset changes the content hash (and reloads) even though the scene ignores it. */
    ok = put_asset(r, "meshy", "square.obj", square_obj, &created, &err);
    CHECK_OK(ok, err);
    CHECK(created);
    CHECK(registry_info(r, "meshy", &b) && b.assets == 2 && b.triangles == 4 && strcmp(a.hash, b.hash) != 0);

    /* Replacing the used asset reloads the scene with the new geometry; sessions keep theirs. */
    struct scene *old = registry_acquire(r, "meshy");
    ok = put_asset(r, "meshy", "tetra.ply", square_ply, &created, &err);
    CHECK_OK(ok, err);
    CHECK(!created);
    CHECK(registry_info(r, "meshy", &c) && c.triangles == 2 && c.assets == 2 && strcmp(b.hash, c.hash) != 0);
    CHECK(old && old->shapes[0].triangle_count == 4);
    struct scene *now = registry_acquire(r, "meshy");
    CHECK(now && now != old && now->shapes[0].triangle_count == 2);
    if (old) scene_release(old);
    if (now) scene_release(now);

    /* An asset that decodes but breaks the scene: the old asset and scene stay. */
    ok = put(r, "big", MESH_SCENE("m.ply", ", \"transform\": {\"scale\": 1e30}"), &res, &err);
    CHECK_ERR(ok, err, ERR_NOT_FOUND, "/shapes/0/file");
    ok = put_asset(r, "big", "m.ply", tetra_ply, &created, &err);
    CHECK_OK(ok, err);
    ok = put(r, "big", MESH_SCENE("m.ply", ", \"transform\": {\"scale\": 1e30}"), &res, &err);
    CHECK_OK(ok, err);
    CHECK(registry_info(r, "big", &c));
    ok = put_asset(r, "big", "m.ply", huge_ply, &created, &err);
    CHECK_ERR(ok, err, ERR_INVALID, "/shapes/0/transform");
    CHECK(!created);
    CHECK(file_equals(data, "/scenes/big/assets/m.ply", tetra_ply));
    CHECK(registry_info(r, "big", &d) && strcmp(c.hash, d.hash) == 0 && d.triangles == 4);
    registry_free(r);
    free_data_dir(data);
}

static void test_asset_name_rules(void)
{
    char *data;
    struct registry *r = fresh_registry(&data, NULL);
    if (!r) return;
    static const char *const bad[] = {
        "../x.ply", "a/b.ply", ".hidden.ply", "x.txt", "x", "", ".ply", "x.ply/", "x y.ply",
        "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa.ply",  /* 65 characters */
    };
    CHECK(strlen(bad[9]) == 65);
    struct err err;
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        bool created = true;
        bool ok = put_asset(r, "names", bad[i], tetra_ply, &created, &err);
        CHECK_ERR(ok, err, ERR_INVALID, "name");
        CHECK(!created);
    }
    CHECK(!path_exists(data, "/scenes/names"));
    bool ok = put_asset(r, "../etc", "x.ply", tetra_ply, NULL, &err);
    CHECK_ERR(ok, err, ERR_INVALID, "id");

    /* 64 characters, mixed-case extension, leading '-' or '_': allowed. */
    static const char *const good[] = {
        "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa.ply", "Tetra.PLY", "-x.ply", "_a.b.ply",
    };
    CHECK(strlen(good[0]) == 64);
    for (size_t i = 0; i < sizeof good / sizeof good[0]; i++) {
        ok = put_asset(r, "names", good[i], tetra_ply, NULL, &err);
        CHECK_OK(ok, err);
    }
    registry_free(r);
    free_data_dir(data);
}

static void test_corrupt_asset_not_stored(void)
{
    char *data;
    struct registry *r = fresh_registry(&data, NULL);
    if (!r) return;
    struct err err;
    bool created = true;
    bool ok = put_asset(r, "c", "bad.ply", corrupt_ply, &created, &err);
    CHECK_MSG(!ok && err.code == ERR_PARSE && strncmp(err.where, "bad.ply", 7) == 0, "%s at '%s': %s",
              err_code_name(err.code), err.where, err.message);
    CHECK(!created && !path_exists(data, "/scenes/c"));
    /* An OBJ body under a .ply name is decoded as PLY, and refused. */
    ok = put_asset(r, "c", "obj.ply", square_obj, &created, &err);
    CHECK(!ok && err.code == ERR_PARSE);
    CHECK(!path_exists(data, "/scenes/c"));

    ok = put_asset(r, "c", "good.ply", tetra_ply, &created, &err);
    CHECK_OK(ok, err);
    ok = put_asset(r, "c", "good.ply", corrupt_ply, &created, &err);
    CHECK(!ok && err.code == ERR_PARSE && !created);
    CHECK(file_equals(data, "/scenes/c/assets/good.ply", tetra_ply));
    registry_free(r);
    free_data_dir(data);
}

/* ---- delete ---- */

static void test_delete_with_sessions(void)
{
    char *data;
    struct registry *r = fresh_registry(&data, NULL);
    if (!r) return;
    struct err err;
    enum registry_put_result res;
    bool ok = put(r, "gone", SPHERE(1), &res, &err);
    CHECK_OK(ok, err);
    ok = put_asset(r, "gone", "t.ply", tetra_ply, NULL, &err);
    CHECK_OK(ok, err);
    memset(&err, 0, sizeof err);
    CHECK(registry_session_added(r, "gone", &err));
    struct scene *held = registry_acquire(r, "gone");
    struct registry_info info;
    CHECK(registry_info(r, "gone", &info) && info.sessions == 1);

    ok = registry_delete(r, "gone", false, &err);
    CHECK_ERR(ok, err, ERR_CONFLICT, "id");
    CHECK(registry_info(r, "gone", NULL) && path_exists(data, "/scenes/gone/scene.json"));

    memset(&err, 0, sizeof err);
    ok = registry_delete(r, "gone", true, &err);
    CHECK_OK(ok, err);
    CHECK(!registry_info(r, "gone", NULL) && registry_acquire(r, "gone") == NULL);
    CHECK(!path_exists(data, "/scenes/gone"));
    CHECK(held && held->refcount == 1 && held->shape_count == 1);  /* the session's scene lives on */
    if (held) scene_release(held);
    registry_session_removed(r, "gone");
    memset(&err, 0, sizeof err);
    ok = registry_session_added(r, "gone", &err);
    CHECK_ERR(ok, err, ERR_NOT_FOUND, "id");
    memset(&err, 0, sizeof err);
    ok = registry_delete(r, "gone", false, &err);
    CHECK_ERR(ok, err, ERR_NOT_FOUND, "id");

    /* Without sessions (added then removed) no force is needed. */
    ok = put(r, "quiet", SPHERE(1), &res, &err);
    CHECK_OK(ok, err);
    CHECK(registry_session_added(r, "quiet", NULL));
    registry_session_removed(r, "quiet");
    registry_session_removed(r, "quiet");  /* saturates */
    CHECK(registry_info(r, "quiet", &info) && info.sessions == 0);
    memset(&err, 0, sizeof err);
    ok = registry_delete(r, "quiet", false, &err);
    CHECK_OK(ok, err);
    registry_free(r);
    free_data_dir(data);
}

/* ---- restart ---- */

static void test_restart_reloads_uploads(void)
{
    struct warnings w = {0};
    char *data;
    struct registry *r = fresh_registry(&data, &w);
    if (!r) return;
    struct err err;
    enum registry_put_result res;
    bool ok = put_asset(r, "keep", "tetra.ply", tetra_ply, NULL, &err) &&
              put(r, "keep", MESH_SCENE("tetra.ply", ""), &res, &err) && put(r, "plain", SPHERE(1), &res, &err) &&
              put_asset(r, "staged", "s.obj", square_obj, NULL, &err);
    CHECK_OK(ok, err);
    /* An asset added after its scene: the hash computed on the staged set must match the one
     * recomputed from the assets folder at restart. */
    ok = put_asset(r, "keep", "extra.obj", square_obj, NULL, &err);
    CHECK_OK(ok, err);
    struct registry_info keep1, plain1, keep2, plain2;
    CHECK(registry_info(r, "keep", &keep1) && registry_info(r, "plain", &plain1));
    size_t count = registry_list(r, NULL, 0);
    registry_free(r);

    /* Leftovers of an interrupted write are cleaned; scenes and assets are not. */
    write_text(data, "/scenes/keep/.tmp-abcdef", "half a file");
    r = open_registry(data, &w);
    CHECK(r != NULL);
    if (!r) {
        free_data_dir(data);
        return;
    }
    CHECK_MSG(w.count == 0, "unexpected warning: %s", w.last);
    CHECK(registry_list(r, NULL, 0) == count);
    CHECK(registry_info(r, "keep", &keep2) && strcmp(keep1.hash, keep2.hash) == 0 && keep2.triangles == 4 &&
          keep2.assets == 2 && !keep2.builtin);
    CHECK(registry_info(r, "plain", &plain2) && strcmp(plain1.hash, plain2.hash) == 0);
    CHECK(!registry_info(r, "staged", NULL) && path_exists(data, "/scenes/staged/assets/s.obj"));
    CHECK(!path_exists(data, "/scenes/keep/.tmp-abcdef"));
    ok = put(r, "keep", MESH_SCENE("tetra.ply", ""), &res, &err);
    CHECK_OK(ok, err);
    CHECK(res == REGISTRY_UNCHANGED);
    registry_free(r);

    /* A persisted scene that no longer loads: warned about, skipped, kept on disk. */
    static const char garbage[] = "{\"camera\": oops";
    write_text(data, "/scenes/plain/scene.json", garbage);
    w.count = 0;
    r = open_registry(data, &w);
    CHECK(r != NULL);
    if (!r) {
        free_data_dir(data);
        return;
    }
    CHECK_MSG(w.count == 1 && strstr(w.last, "plain") && strstr(w.last, "parse"), "%d warnings, last: %s", w.count,
              w.last);
    CHECK(!registry_info(r, "plain", NULL));
    CHECK(file_equals(data, "/scenes/plain/scene.json", garbage));
    CHECK(registry_info(r, "keep", &keep2) && strcmp(keep1.hash, keep2.hash) == 0);
    CHECK(registry_info(r, "cornell-box", NULL) && registry_info(r, "furnace-albedo-half", NULL));
    CHECK(registry_list(r, NULL, 0) == count - 1);
    /* A new PUT repairs it. */
    ok = put(r, "plain", SPHERE(1), &res, &err);
    CHECK_OK(ok, err);
    CHECK(res == REGISTRY_CREATED && registry_info(r, "plain", &plain2) && strcmp(plain1.hash, plain2.hash) == 0);
    registry_free(r);

    /* A data directory that cannot be created. */
    memset(&err, 0, sizeof err);
    char blocked[4096];
    snprintf(blocked, sizeof blocked, "%s/scenes/plain/scene.json/x", data);
    CHECK(registry_new(NULL, blocked, NULL, NULL, &err) == NULL && err.code == ERR_IO);
    free_data_dir(data);
}

/* ---- concurrency ---- */

struct race {
    struct registry *r;
    const char *json;
    int failures;
};

static void *race_writer(void *arg)
{
    struct race *x = arg;
    for (int i = 0; i < 8; i++) {
        struct err err;
        enum registry_put_result res;
        if (!registry_put_scene(x->r, "race", x->json, strlen(x->json), &res, &err)) x->failures++;
    }
    return NULL;
}

static void *race_reader(void *arg)
{
    struct race *x = arg;
    for (int i = 0; i < 200; i++) {
        struct scene *s = registry_acquire(x->r, "race");
        if (s && s->shape_count != 1) x->failures++;
        if (s) scene_release(s);
        struct registry_info list[64];
        registry_list(x->r, list, 64);
    }
    return NULL;
}

static void test_concurrent_writers_one_id(void)
{
    char *data;
    struct registry *r = fresh_registry(&data, NULL);
    if (!r) return;
    struct race a = {r, SPHERE(1), 0}, b = {r, SPHERE(3), 0}, c = {r, NULL, 0};
    pthread_t ta, tb, tc;
    pthread_create(&ta, NULL, race_writer, &a);
    pthread_create(&tb, NULL, race_writer, &b);
    pthread_create(&tc, NULL, race_reader, &c);
    pthread_join(ta, NULL);
    pthread_join(tb, NULL);
    pthread_join(tc, NULL);
    CHECK(a.failures == 0 && b.failures == 0 && c.failures == 0);
    /* Whichever writer won last, the table and the disk agree. */
    struct registry_info before, after;
    CHECK(registry_info(r, "race", &before));
    registry_free(r);
    r = open_registry(data, NULL);
    CHECK(r && registry_info(r, "race", &after) && strcmp(before.hash, after.hash) == 0);
    registry_free(r);
    free_data_dir(data);
}

TEST_MAIN(TEST(test_builtins_listed_with_ids_and_counts), TEST(test_builtin_is_read_only), TEST(test_library_ids_and_skips),
          TEST(test_put_created_unchanged_replaced), TEST(test_put_invalid_leaves_registry_unchanged),
          TEST(test_assets_then_scene), TEST(test_asset_name_rules), TEST(test_corrupt_asset_not_stored),
          TEST(test_delete_with_sessions), TEST(test_restart_reloads_uploads), TEST(test_concurrent_writers_one_id))
