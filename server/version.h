/* version.h — the release version, and the commit the binaries were built from, for
 * `restir --version`, `restird --version` and GET /metrics (restird_build_info). The Python
 * client's __version__ (clients/python/restir.py) repeats the release, and a test checks they
 * agree. The commit is defined in version.c, which the Makefile compiles with
 * -DRESTIRD_COMMIT="...". */
#ifndef RESTIRD_VERSION_H
#define RESTIRD_VERSION_H

#define RESTIRD_VERSION "0.1.0"

/* The short commit hash the binary was built from: git's HEAD, or `make COMMIT=...`; "unknown"
 * outside a git checkout without COMMIT. */
extern const char restird_commit[];

#endif
