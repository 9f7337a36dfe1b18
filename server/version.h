/* version.h — what this daemon is: its release and the commit it was built from, reported by
 * GET /metrics (restird_build_info). The build may define RESTIRD_COMMIT (-DRESTIRD_COMMIT=...);
 * a build from a tree without that says "unknown". */
#ifndef RESTIRD_VERSION_H
#define RESTIRD_VERSION_H

#define RESTIRD_VERSION "0.1.0"

#ifndef RESTIRD_COMMIT
#define RESTIRD_COMMIT "unknown"
#endif

#endif
