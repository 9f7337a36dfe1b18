/* test_budget.c — the daemon's memory budget (server/budget.c) and the session size it is
 * charged with (session_bytes_planned): reservations stop exactly at the limit, releases give
 * the bytes back, and the planned size equals what a created session really allocates. */
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "budget.h"
#include "session.h"
#include "test.h"

static void test_reserve_up_to_the_limit(void)
{
    struct budget b;
    budget_init(&b, 1000);
    struct err err = {0};
    CHECK(budget_reserve(&b, BUDGET_SESSIONS, 600, &err));
    CHECK(budget_reserve(&b, BUDGET_SCENES, 300, &err));
    CHECK(budget_reserve(&b, BUDGET_REFERENCES, 100, &err));   /* exactly at the limit */
    CHECK(budget_total(&b) == 1000);
    CHECK(!budget_reserve(&b, BUDGET_REFERENCES, 1, &err) && err.code == ERR_BUSY);
    CHECK(strstr(err.message, "1000 of 1000 bytes") != NULL);
    CHECK(budget_used(&b, BUDGET_REFERENCES) == 100);          /* a refusal charges nothing */
    budget_release(&b, BUDGET_SESSIONS, 600);
    CHECK(budget_reserve(&b, BUDGET_SESSIONS, 600, &err));
    /* More than the limit on its own, and the sum overflowing 64 bits, are both refused. */
    budget_release(&b, BUDGET_SESSIONS, 600);
    CHECK(!budget_reserve(&b, BUDGET_SESSIONS, 1001, &err));
    CHECK(!budget_reserve(&b, BUDGET_SESSIONS, UINT64_MAX, &err));
    /* Charging never refuses (memory already held); a release never goes below zero. */
    budget_charge(&b, BUDGET_SCENES, 5000);
    CHECK(budget_total(&b) == 5400);
    CHECK(!budget_reserve(&b, BUDGET_SESSIONS, 1, &err));
    budget_release(&b, BUDGET_REFERENCES, 1u << 20);
    CHECK(budget_used(&b, BUDGET_REFERENCES) == 0);
    budget_destroy(&b);
}

static void test_no_limit(void)
{
    struct budget b;
    budget_init(&b, 0);
    struct err err = {0};
    CHECK(budget_reserve(&b, BUDGET_SESSIONS, UINT64_MAX / 2, &err));
    CHECK(budget_reserve(&b, BUDGET_SESSIONS, UINT64_MAX / 4, &err));
    budget_destroy(&b);
}

static void test_planned_session_bytes_match_the_session(void)
{
    struct err err = {0};
    struct scene *scene = scene_load_file("scenes/cornell-box/scene.json", &err);
    CHECK_MSG(scene && scene_commit(scene, &err), "%s", err.message);
    if (!scene) return;
    struct sessions *t = sessions_new(4);
    struct budget b;
    budget_init(&b, 1u << 30);
    const uint32_t sizes[][2] = {{1, 1}, {16, 9}, {33, 17}};
    for (int i = 0; i < 3; i++) {
        struct view_params p = view_params_defaults(method_find("pt"), sizes[i][0], sizes[i][1]);
        uint64_t planned = session_bytes_planned(&p, scene, 3);
        CHECK(budget_reserve(&b, BUDGET_SESSIONS, planned, &err));
        struct session *s = sessions_create(t, "cb", NULL, scene, &p, 3, 1, &b, planned, &err);
        CHECK_MSG(s != NULL, "%s", err.message);
        if (!s) continue;
        /* Before any frame: the buffers alone; the kept frames fill the rest of the plan. */
        uint64_t frame = (uint64_t)p.width * p.height * 12;
        CHECK(session_bytes(s) + 3 * frame == planned);
        CHECK(budget_used(&b, BUDGET_SESSIONS) == planned);
        CHECK(sessions_remove(t, "cb", s->id));
        session_release(s);  /* the last reference: the bytes go back */
        CHECK(budget_used(&b, BUDGET_SESSIONS) == 0);
    }
    sessions_free(t);
    budget_destroy(&b);
    scene_release(scene);
}

TEST_MAIN(TEST(test_reserve_up_to_the_limit), TEST(test_no_limit), TEST(test_planned_session_bytes_match_the_session))
