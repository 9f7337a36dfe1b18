/* test.h — a minimal C test harness. Each test file defines test functions, lists them in
 * TEST_MAIN, and prints the closing line "N passed, N failed". A CHECK failure prints
 * file:line and the expression, marks the current test failed, and continues. */
#ifndef RESTIRD_TEST_H
#define RESTIRD_TEST_H

#include <stdio.h>
#include <string.h>

static int test_current_failed;

#define CHECK(cond)                                                                 \
    do {                                                                            \
        if (!(cond)) {                                                              \
            fprintf(stderr, "  %s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
            test_current_failed = 1;                                                \
        }                                                                           \
    } while (0)

#define CHECK_MSG(cond, ...)                                                        \
    do {                                                                            \
        if (!(cond)) {                                                              \
            fprintf(stderr, "  %s:%d: CHECK failed: %s: ", __FILE__, __LINE__, #cond); \
            fprintf(stderr, __VA_ARGS__);                                           \
            fputc('\n', stderr);                                                    \
            test_current_failed = 1;                                                \
        }                                                                           \
    } while (0)

#define CHECK_NEAR(a, b, tol)                                                       \
    CHECK_MSG(fabs((double)(a) - (double)(b)) <= (double)(tol), "%.9g vs %.9g (tol %.3g)", \
              (double)(a), (double)(b), (double)(tol))

struct test_case { const char *name; void (*fn)(void); };

static inline int test_run_all(const char *file, const struct test_case *cases, int n)
{
    int passed = 0, failed = 0;
    for (int i = 0; i < n; i++) {
        test_current_failed = 0;
        cases[i].fn();
        if (test_current_failed) { failed++; fprintf(stderr, "FAIL %s: %s\n", file, cases[i].name); }
        else { passed++; printf("ok   %s\n", cases[i].name); }
    }
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}

#define TEST(name) { #name, name }
#define TEST_MAIN(...)                                                              \
    int main(void)                                                                  \
    {                                                                               \
        static const struct test_case cases[] = {__VA_ARGS__};                      \
        return test_run_all(__FILE__, cases, (int)(sizeof cases / sizeof cases[0])); \
    }

#endif
