/* scene_fixture.h — a committed scene for the unit tests, from a file (paths from the repository
 * root, where the tests run) or from JSON text. A scene that does not load or commit is a failed
 * CHECK naming it and the error, and gives NULL, which the tests then skip on. */
#ifndef RESTIRD_TEST_SCENE_FIXTURE_H
#define RESTIRD_TEST_SCENE_FIXTURE_H

#include <string.h>

#include "core/err.h"
#include "scene/scene.h"
#include "test.h"

/* s committed (NULL when s is NULL or does not commit: the failure is checked here). */
static inline struct scene *fixture_commit(struct scene *s, struct err *err, const char *what)
{
    CHECK_MSG(s != NULL, "%s: %s at %s", what, err->message, err->where);
    if (s && !scene_commit(s, err)) {
        CHECK_MSG(false, "%s: %s", what, err->message);
        scene_release(s);
        return NULL;
    }
    return s;
}

/* The scene file at `path`, committed. */
static inline struct scene *fixture_load(const char *path)
{
    struct err err = {0};
    return fixture_commit(scene_load_file(path, &err), &err, path);
}

/* A scene from JSON text (mesh files resolved in base_dir, NULL: none), committed. */
static inline struct scene *fixture_load_json(const char *json, const char *base_dir)
{
    struct err err = {0};
    return fixture_commit(scene_load_json(json, strlen(json), base_dir, &err), &err, "scene JSON");
}

#endif
