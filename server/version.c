/* version.c — the build's commit, which the Makefile passes as -DRESTIRD_COMMIT="..." to this
 * file alone: a new commit recompiles one small file and relinks the two programs (the only ones
 * that link it), not the programs' sources or the unit tests. */
#include "version.h"

#ifndef RESTIRD_COMMIT
#define RESTIRD_COMMIT "unknown"
#endif

const char restird_commit[] = RESTIRD_COMMIT;
