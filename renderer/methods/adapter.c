/* adapter.c — the operations of adapter.h that are functions, not macros: the init and destroy of a
 * method that keeps no state between frames. */
#include "methods/adapter.h"

bool method_stateless_init(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height,
                           struct err *err)
{
    (void)state, (void)scene, (void)params, (void)width, (void)height, (void)err;
    return true;
}

void method_stateless_destroy(void *state)
{
    (void)state;
}
