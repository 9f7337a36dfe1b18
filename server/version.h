/* version.h — the one place the release version is written, and the commit the binaries were
 * built from (baked in at build time: the Makefile generates the header that defines it), for
 * `restir --version`, `restird --version` and GET /metrics (restird_build_info). */
#ifndef RESTIRD_VERSION_H
#define RESTIRD_VERSION_H

#define RESTIRD_VERSION "0.1.0"

/* The short commit hash of the checkout the binary was built from; "unknown" outside a git
 * checkout. */
extern const char restird_commit[];

#endif
