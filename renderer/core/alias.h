/* alias.h — RESTIRD_STORED_IN_BYTES marks a struct that lives inside another object's byte
 * storage and is read and written through a pointer to it: a session keeps its method's
 * parameters in view_params.method_params, and a frame its method's counters in
 * frame_stats.counters (methods/method.h). Without it, type-based alias
 * analysis may assume that a write of the whole view_params and a read through the parameter
 * struct do not touch the same memory (C17 6.5p7), and an optimising build then reads stale
 * bytes. GCC and clang's may_alias makes every access through such a pointer alias anything. */
#ifndef RESTIRD_ALIAS_H
#define RESTIRD_ALIAS_H

#define RESTIRD_STORED_IN_BYTES __attribute__((may_alias))

#endif
