/* version.c — the build's commit, which the Makefile passes as -DRESTIRD_COMMIT="..." to this
 * file alone: a new commit recompiles one small file and relinks, not the programs' sources. */
#include "version.h"

#ifndef RESTIRD_COMMIT
#define RESTIRD_COMMIT "unknown"
#endif

const char restird_commit[] = RESTIRD_COMMIT;
