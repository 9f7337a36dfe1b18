/* mesh_io.c — PLY/OBJ decoding through assimp, plus the checks assimp does not do.
 * The only file that includes assimp. Assimp reads through an in-memory aiFileIO that serves
 * exactly one file, so an OBJ's `mtllib /etc/...` cannot reach the disk. Before assimp sees
 * the bytes we walk every PLY row against its header and pre-scan OBJ text, because assimp's
 * PLY reader passes bad indices and short rows through silently; the walks also give
 * "file:line" errors. After import every index and number is checked again.
 * Must not: generate normals, join vertices, or touch scene structures. */
#include "input/mesh_io.h"

#include "input/fileio.h"

#include <assimp/cfileio.h>
#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <errno.h>
#include <limits.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

/* Assimp keeps its last error in a process-wide string, so concurrent imports would read
 * each other's messages; one import at a time keeps messages attached to their files. */
static pthread_mutex_t mesh_io_lock = PTHREAD_MUTEX_INITIALIZER;

const char *mesh_io_format_of(const char *name)
{
    const char *dot = name ? strrchr(name, '.') : NULL;
    if (!dot || strchr(dot, '/')) return NULL;
    if (strcasecmp(dot, ".ply") == 0) return "ply";
    if (strcasecmp(dot, ".obj") == 0) return "obj";
    return NULL;
}

void mesh_io_destroy(struct mesh *mesh)
{
    if (!mesh) return;
    free(mesh->positions);
    free(mesh->normals);
    free(mesh->indices);
    memset(mesh, 0, sizeof *mesh);
}

/* ---- line and token scanning shared by the PLY header check and the OBJ pre-scan ---- */

struct mesh_io_lines {
    const char *p, *end;
    uint32_t number;  /* 1-based number of the line last returned */
};

static bool mesh_io_next_line(struct mesh_io_lines *it, const char **b, const char **e)
{
    if (it->p >= it->end) return false;
    const char *nl = memchr(it->p, '\n', (size_t)(it->end - it->p));
    *b = it->p;
    *e = nl ? nl : it->end;
    it->p = nl ? nl + 1 : it->end;
    it->number++;
    return true;
}

static bool mesh_io_is_space(char c)
{
    return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

/* Next whitespace-separated token of [*p, e); false at the end of the line. */
static bool mesh_io_next_token(const char **p, const char *e, const char **tb, const char **te)
{
    const char *s = *p;
    while (s < e && mesh_io_is_space(*s)) s++;
    if (s >= e) { *p = s; return false; }
    const char *t = s;
    while (t < e && !mesh_io_is_space(*t)) t++;
    *tb = s;
    *te = t;
    *p = t;
    return true;
}

/* PLY element and property names: a letter or '_', then letters, digits, '_' or '-', at most 63
 * bytes. Every real-world name fits; assimp misreads others (an element named by a 60-digit
 * number made it ask for 57 GB: tests/fuzz/mesh_ply/oom-numeric-element-name). */
static bool mesh_io_ply_name_ok(const char *tb, const char *te)
{
    if (te - tb < 1 || te - tb > 63) return false;
    for (const char *c = tb; c < te; c++) {
        bool alpha = (*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || *c == '_';
        bool digit = (*c >= '0' && *c <= '9') || *c == '-';
        if (!alpha && !(digit && c > tb)) return false;
    }
    return true;
}

/* True when [p, e) holds no more tokens. */
static bool mesh_io_line_done(const char *p, const char *e)
{
    const char *tb, *te;
    return !mesh_io_next_token(&p, e, &tb, &te);
}

static bool mesh_io_token_is(const char *tb, const char *te, const char *word)
{
    size_t n = strlen(word);
    return (size_t)(te - tb) == n && memcmp(tb, word, n) == 0;
}

/* Whole token as a double (strtod needs a terminated copy; real numbers are short). */
static bool mesh_io_token_double(const char *tb, const char *te, double *out)
{
    char buf[128];
    size_t n = (size_t)(te - tb);
    if (n == 0 || n >= sizeof buf) return false;
    memcpy(buf, tb, n);
    buf[n] = '\0';
    char *end;
    *out = strtod(buf, &end);
    return end == buf + n;
}

/* Whole token as an unsigned decimal no larger than `max`. */
static bool mesh_io_token_uint(const char *tb, const char *te, uint64_t max, uint64_t *out)
{
    if (tb >= te) return false;
    uint64_t v = 0;
    for (const char *c = tb; c < te; c++) {
        if (*c < '0' || *c > '9') return false;
        v = v * 10 + (uint64_t)(*c - '0');
        if (v > max) return false;
    }
    *out = v;
    return true;
}

/* ---- PLY: a full structural walk of header and body before assimp sees the bytes ----
 * Assimp's PLY reader is lenient: it passes face indices through unchecked, reads a list
 * that runs past the end of the data as garbage, and turns a short row into extra faces.
 * So every row is checked here against the header (value count, number syntax, vertex
 * coordinates finite, face indices in range), and counts are bounded before assimp
 * allocates for them. The walk itself allocates nothing. */

#define MESH_IO_PLY_MAX_ELEMENTS 16
#define MESH_IO_PLY_MAX_PROPS 32

enum mesh_io_ply_role { PLY_OTHER, PLY_X, PLY_Y, PLY_Z, PLY_INDICES };

struct mesh_io_ply_type { int size; bool is_float, is_signed; };

struct mesh_io_ply_prop {
    struct mesh_io_ply_type type;        /* of the value, or of each list item */
    struct mesh_io_ply_type count_type;  /* lists only */
    bool is_list;
    enum mesh_io_ply_role role;
};

struct mesh_io_ply_element {
    bool is_vertex, is_face;
    char name[32];
    uint64_t count;
    int prop_count;
    struct mesh_io_ply_prop props[MESH_IO_PLY_MAX_PROPS];
};

struct mesh_io_ply {
    enum { PLY_ASCII, PLY_LE, PLY_BE } format;
    int element_count;
    struct mesh_io_ply_element elements[MESH_IO_PLY_MAX_ELEMENTS];
    uint64_t vertex_count;
};

static bool mesh_io_ply_type_of(const char *tb, const char *te, struct mesh_io_ply_type *out)
{
    static const struct { const char *name; struct mesh_io_ply_type type; } types[] = {
        {"char", {1, false, true}}, {"uchar", {1, false, false}}, {"int8", {1, false, true}}, {"uint8", {1, false, false}},
        {"short", {2, false, true}}, {"ushort", {2, false, false}}, {"int16", {2, false, true}}, {"uint16", {2, false, false}},
        {"int", {4, false, true}}, {"uint", {4, false, false}}, {"int32", {4, false, true}}, {"uint32", {4, false, false}},
        {"float", {4, true, true}}, {"float32", {4, true, true}}, {"double", {8, true, true}}, {"float64", {8, true, true}},
    };
    for (size_t i = 0; i < sizeof types / sizeof types[0]; i++)
        if (mesh_io_token_is(tb, te, types[i].name)) { *out = types[i].type; return true; }
    return false;
}

/* Parses the header; on success *body_offset is where the data starts and *lines_done the
 * number of header lines (ASCII rows are counted from there). */
static bool mesh_io_ply_header(const char *data, size_t len, const char *name, struct mesh_io_ply *h,
                               size_t *body_offset, uint32_t *lines_done, struct err *err)
{
    struct mesh_io_lines it = {data, data + len, 0};
    const char *b, *e, *p, *tb, *te;
    char where[300];
    bool have_format = false;
    struct mesh_io_ply_element *el = NULL;

    memset(h, 0, sizeof *h);
    if (!mesh_io_next_line(&it, &b, &e) || !(p = b, mesh_io_next_token(&p, e, &tb, &te)) ||
        !(mesh_io_token_is(tb, te, "ply") || mesh_io_token_is(tb, te, "PLY"))) {
        snprintf(where, sizeof where, "%s:1", name);
        return err_set(err, ERR_PARSE, where, "not a PLY file: the first line must be 'ply'");
    }
    for (;;) {
        if (!mesh_io_next_line(&it, &b, &e)) return err_set(err, ERR_PARSE, name, "PLY header has no end_header line");
        snprintf(where, sizeof where, "%s:%u", name, it.number);
        if (it.number > 10000) return err_set(err, ERR_PARSE, where, "PLY header longer than 10000 lines");
        p = b;
        if (!mesh_io_next_token(&p, e, &tb, &te)) continue;
        if (mesh_io_token_is(tb, te, "comment") || mesh_io_token_is(tb, te, "obj_info")) continue;
        if (mesh_io_token_is(tb, te, "end_header")) {
            /* A file ending right after "end_header" (no newline) with an obj_info line in the
             * header sent assimp into an endless loop (tests/fuzz/mesh_ply/timeout-no-newline-
             * after-header); the format wants the newline anyway. */
            if (e == data + len || !mesh_io_line_done(p, e))
                return err_set(err, ERR_PARSE, where, "PLY end_header must be alone on a line that ends in a newline");
            break;
        }
        /* Header lines are read exactly: assimp takes the first format line and skips words it
         * does not expect, so a second format line or trailing words would make it read another
         * file than the one walked here (a second "format ascii" after a binary one made it
         * allocate 6.6 GB from a 451-byte file: tests/fuzz/mesh_ply/oom-second-format-line). */
        if (mesh_io_token_is(tb, te, "format")) {
            if (have_format) return err_set(err, ERR_PARSE, where, "a second PLY format line");
            if (!mesh_io_next_token(&p, e, &tb, &te)) return err_set(err, ERR_PARSE, where, "PLY format line without a format");
            if (mesh_io_token_is(tb, te, "ascii")) h->format = PLY_ASCII;
            else if (mesh_io_token_is(tb, te, "binary_little_endian")) h->format = PLY_LE;
            else if (mesh_io_token_is(tb, te, "binary_big_endian")) h->format = PLY_BE;
            else return err_set(err, ERR_PARSE, where, "unknown PLY format '%.*s'", (int)(te - tb), tb);
            if (!mesh_io_next_token(&p, e, &tb, &te) || !mesh_io_token_is(tb, te, "1.0") || !mesh_io_line_done(p, e))
                return err_set(err, ERR_PARSE, where, "PLY format line must end in version 1.0");
            have_format = true;
            continue;
        }
        if (mesh_io_token_is(tb, te, "element")) {
            const char *nb, *ne, *cb, *ce;
            uint64_t count;
            if (!mesh_io_next_token(&p, e, &nb, &ne) || !mesh_io_next_token(&p, e, &cb, &ce) ||
                !mesh_io_token_uint(cb, ce, UINT32_MAX, &count) || !mesh_io_line_done(p, e))
                return err_set(err, ERR_PARSE, where, "PLY element line needs a name and a count below 2^32, and nothing after");
            if (!mesh_io_ply_name_ok(nb, ne))
                return err_set(err, ERR_PARSE, where, "PLY element name '%.*s' is not [A-Za-z_][A-Za-z0-9_-]{0,62}",
                               (int)(ne - nb > 64 ? 64 : ne - nb), nb);
            if (h->element_count == MESH_IO_PLY_MAX_ELEMENTS)
                return err_set(err, ERR_LIMIT, where, "more than %d PLY elements", MESH_IO_PLY_MAX_ELEMENTS);
            el = &h->elements[h->element_count++];
            snprintf(el->name, sizeof el->name, "%.*s", (int)(ne - nb), nb);
            el->count = count;
            el->is_vertex = mesh_io_token_is(nb, ne, "vertex");
            el->is_face = mesh_io_token_is(nb, ne, "face");
            if (el->is_vertex && count > MESH_IO_MAX_VERTICES)
                return err_set(err, ERR_LIMIT, where, "%llu vertices, more than the limit of %u", (unsigned long long)count,
                               MESH_IO_MAX_VERTICES);
            if (el->is_face && count > MESH_IO_MAX_TRIANGLES)
                return err_set(err, ERR_LIMIT, where, "%llu faces, more than the limit of %u", (unsigned long long)count,
                               MESH_IO_MAX_TRIANGLES);
            if (el->is_vertex) h->vertex_count = count;
            continue;
        }
        if (mesh_io_token_is(tb, te, "property")) {
            if (!el) return err_set(err, ERR_PARSE, where, "PLY property before any element");
            if (el->prop_count == MESH_IO_PLY_MAX_PROPS)
                return err_set(err, ERR_LIMIT, where, "more than %d properties in element '%s'", MESH_IO_PLY_MAX_PROPS, el->name);
            struct mesh_io_ply_prop *pr = &el->props[el->prop_count++];
            if (!mesh_io_next_token(&p, e, &tb, &te)) return err_set(err, ERR_PARSE, where, "PLY property without a type");
            if (mesh_io_token_is(tb, te, "list")) {
                pr->is_list = true;
                if (!mesh_io_next_token(&p, e, &tb, &te) || !mesh_io_ply_type_of(tb, te, &pr->count_type) ||
                    pr->count_type.is_float)
                    return err_set(err, ERR_PARSE, where, "PLY list needs an integer count type");
                if (!mesh_io_next_token(&p, e, &tb, &te)) return err_set(err, ERR_PARSE, where, "PLY list without an item type");
            }
            if (!mesh_io_ply_type_of(tb, te, &pr->type))
                return err_set(err, ERR_PARSE, where, "unknown PLY property type '%.*s'", (int)(te - tb), tb);
            if (!mesh_io_next_token(&p, e, &tb, &te)) return err_set(err, ERR_PARSE, where, "PLY property without a name");
            if (!mesh_io_line_done(p, e)) return err_set(err, ERR_PARSE, where, "words after the PLY property's name");
            if (!mesh_io_ply_name_ok(tb, te))
                return err_set(err, ERR_PARSE, where, "PLY property name '%.*s' is not [A-Za-z_][A-Za-z0-9_-]{0,62}",
                               (int)(te - tb > 64 ? 64 : te - tb), tb);
            if (el->is_vertex && !pr->is_list) {
                if (mesh_io_token_is(tb, te, "x")) pr->role = PLY_X;
                if (mesh_io_token_is(tb, te, "y")) pr->role = PLY_Y;
                if (mesh_io_token_is(tb, te, "z")) pr->role = PLY_Z;
            }
            if (el->is_face && pr->is_list &&
                (mesh_io_token_is(tb, te, "vertex_indices") || mesh_io_token_is(tb, te, "vertex_index")))
                pr->role = PLY_INDICES;
            continue;
        }
        return err_set(err, ERR_PARSE, where, "unexpected PLY header line '%.*s'", (int)(te - tb), tb);
    }
    if (!have_format) return err_set(err, ERR_PARSE, name, "PLY header has no format line");
    for (int i = 0; i < h->element_count; i++) {
        const struct mesh_io_ply_element *x = &h->elements[i];
        int roles = 0;
        for (int k = 0; k < x->prop_count; k++) roles |= 1 << x->props[k].role;
        if (x->is_vertex && (roles & 0xe) != 0xe)
            return err_set(err, ERR_INVALID, name, "PLY vertex element lacks one of the properties x, y, z");
        if (x->is_face && !(roles & (1 << PLY_INDICES)))
            return err_set(err, ERR_INVALID, name, "PLY face element has no vertex_indices list");
    }
    *body_offset = (size_t)(it.p - data);
    *lines_done = it.number;
    return true;
}

/* Checks one value of a row. `v` is the value (integers converted exactly up to 2^53). */
static bool mesh_io_ply_value(const struct mesh_io_ply *h, enum mesh_io_ply_role role, uint64_t row, double v,
                              const char *where, struct err *err)
{
    if (role >= PLY_X && role <= PLY_Z && (!isfinite(v) || !isfinite((float)v)))
        return err_set(err, ERR_INVALID, where, "vertex %llu has a non-finite coordinate (%g)", (unsigned long long)row, v);
    if (role == PLY_INDICES && !(v >= 0.0 && v < (double)h->vertex_count && v == floor(v)))
        return err_set(err, ERR_INVALID, where, "face %llu refers to vertex %g, but the file has %llu vertices",
                       (unsigned long long)row, v, (unsigned long long)h->vertex_count);
    return true;
}

/* A face without vertices: assimp's triangulation aborts the process on one
 * (tests/fuzz/mesh_ply/crash-empty-face), so it is refused here, in both encodings. */
static bool mesh_io_ply_list_length(const struct mesh_io_ply_prop *pr, uint64_t row, uint64_t items, const char *where,
                                    struct err *err)
{
    if (pr->role == PLY_INDICES && items == 0)
        return err_set(err, ERR_INVALID, where, "face %llu has no vertices", (unsigned long long)row);
    if (pr->role == PLY_INDICES && items > MESH_IO_MAX_FACE_VERTICES)
        return err_set(err, ERR_LIMIT, where, "face %llu has %llu vertices, more than %u", (unsigned long long)row,
                       (unsigned long long)items, MESH_IO_MAX_FACE_VERTICES);
    return true;
}

static bool mesh_io_ply_ascii(const char *data, size_t len, size_t body, uint32_t line0, const char *name,
                              const struct mesh_io_ply *h, struct err *err)
{
    struct mesh_io_lines it = {data + body, data + len, line0};
    const char *b = NULL, *e = NULL, *p, *tb, *te;
    char where[300];
    for (int ei = 0; ei < h->element_count; ei++) {
        const struct mesh_io_ply_element *el = &h->elements[ei];
        for (uint64_t row = 0; row < el->count; row++) {
            bool got;
            do got = mesh_io_next_line(&it, &b, &e); while (got && (p = b, !mesh_io_next_token(&p, e, &tb, &te)));
            if (!got)
                return err_set(err, ERR_PARSE, name, "file ends at row %llu of element '%s' (%llu declared)",
                               (unsigned long long)row, el->name, (unsigned long long)el->count);
            snprintf(where, sizeof where, "%s:%u", name, it.number);
            p = b;
            for (int k = 0; k < el->prop_count; k++) {
                const struct mesh_io_ply_prop *pr = &el->props[k];
                uint64_t items = 1;
                if (pr->is_list) {
                    if (!mesh_io_next_token(&p, e, &tb, &te) || !mesh_io_token_uint(tb, te, 1u << 20, &items))
                        return err_set(err, ERR_PARSE, where, "expected a list length (0 .. 2^20) in element '%s'", el->name);
                    if (!mesh_io_ply_list_length(pr, row, items, where, err)) return false;
                }
                for (uint64_t j = 0; j < items; j++) {
                    double v;
                    if (!mesh_io_next_token(&p, e, &tb, &te))
                        return err_set(err, ERR_PARSE, where, "row of element '%s' has too few values", el->name);
                    if (!mesh_io_token_double(tb, te, &v))
                        return err_set(err, ERR_PARSE, where, "'%.*s' is not a number", (int)(te - tb), tb);
                    if (!mesh_io_ply_value(h, pr->role, row, v, where, err)) return false;
                }
            }
            if (mesh_io_next_token(&p, e, &tb, &te))
                return err_set(err, ERR_PARSE, where, "row of element '%s' has more values than the header declares", el->name);
        }
    }
    while (mesh_io_next_line(&it, &b, &e)) {
        p = b;
        if (mesh_io_next_token(&p, e, &tb, &te)) {
            snprintf(where, sizeof where, "%s:%u", name, it.number);
            return err_set(err, ERR_PARSE, where, "data after the last PLY element");
        }
    }
    return true;
}

static double mesh_io_ply_read(const unsigned char *p, struct mesh_io_ply_type t, bool big_endian)
{
    uint64_t u = 0;
    for (int i = 0; i < t.size; i++) u |= (uint64_t)p[big_endian ? t.size - 1 - i : i] << (8 * i);
    if (t.is_float) {
        if (t.size == 4) { uint32_t w = (uint32_t)u; float f; memcpy(&f, &w, 4); return f; }
        double d;
        memcpy(&d, &u, 8);
        return d;
    }
    if (t.is_signed && t.size < 8 && (u >> (8 * t.size - 1)) & 1) return (double)((int64_t)u - ((int64_t)1 << (8 * t.size)));
    return (double)u;
}

static bool mesh_io_ply_binary(const char *data, size_t len, size_t body, const char *name, const struct mesh_io_ply *h,
                               struct err *err)
{
    const unsigned char *p = (const unsigned char *)data + body, *end = (const unsigned char *)data + len;
    bool be = h->format == PLY_BE;
    for (int ei = 0; ei < h->element_count; ei++) {
        const struct mesh_io_ply_element *el = &h->elements[ei];
        for (uint64_t row = 0; row < el->count; row++) {
            for (int k = 0; k < el->prop_count; k++) {
                const struct mesh_io_ply_prop *pr = &el->props[k];
                uint64_t items = 1;
                if (pr->is_list) {
                    if ((size_t)(end - p) < (size_t)pr->count_type.size) goto short_body;
                    double c = mesh_io_ply_read(p, pr->count_type, be);
                    p += pr->count_type.size;
                    if (c < 0) return err_set(err, ERR_PARSE, name, "negative list length in row %llu of element '%s'",
                                              (unsigned long long)row, el->name);
                    items = (uint64_t)c;
                    if (!mesh_io_ply_list_length(pr, row, items, name, err)) return false;
                }
                if (items > (uint64_t)(end - p) / (uint64_t)pr->type.size) goto short_body;
                if (pr->role != PLY_OTHER)
                    for (uint64_t j = 0; j < items; j++)
                        if (!mesh_io_ply_value(h, pr->role, row,
                                               mesh_io_ply_read(p + j * (uint64_t)pr->type.size, pr->type, be), name, err))
                            return false;
                p += items * (uint64_t)pr->type.size;
            }
            continue;
        short_body:
            return err_set(err, ERR_PARSE, name, "file ends inside row %llu of element '%s' (%llu declared)",
                           (unsigned long long)row, el->name, (unsigned long long)el->count);
        }
    }
    if (p != end)
        return err_set(err, ERR_PARSE, name, "%zu bytes after the last PLY element", (size_t)(end - p));
    return true;
}

/* Text parts of a mesh file may hold no control character but tab, and CR only before LF.
 * Assimp ends a line at CR, FF and NUL where our walks see a separator or a token byte, so the
 * two would read different rows from one file: a PLY row that assimp splits in two made its
 * triangulation abort the process (tests/fuzz/mesh_ply/crash-cr-inside-row). */
static bool mesh_io_text_check(const char *data, size_t len, const char *name, struct err *err)
{
    uint32_t line = 1;
    for (size_t i = 0; i < len; i++) {
        unsigned char c = (unsigned char)data[i];
        if (c == '\n') line++;
        else if ((c < 0x20 && c != '\t' && !(c == '\r' && i + 1 < len && data[i + 1] == '\n')) || c == 0x7f) {
            char where[300];
            snprintf(where, sizeof where, "%s:%u", name, line);
            return err_set(err, ERR_PARSE, where, "control character 0x%02x in a text line (only tab, LF and CR LF are allowed)", c);
        }
    }
    return true;
}

static bool mesh_io_ply_check(const char *data, size_t len, const char *name, struct err *err)
{
    struct mesh_io_ply *h = malloc(sizeof *h);  /* ~10 KiB: keep it off the stack */
    if (!h) return err_set(err, ERR_NOMEM, name, "out of memory");
    size_t body = 0;
    uint32_t lines = 0;
    bool ok = mesh_io_ply_header(data, len, name, h, &body, &lines, err) &&
              mesh_io_text_check(data, h->format == PLY_ASCII ? len : body, name, err) &&
              (h->format == PLY_ASCII ? mesh_io_ply_ascii(data, len, body, lines, name, h, err)
                                      : mesh_io_ply_binary(data, len, body, name, h, err));
    free(h);
    return ok;
}

/* ---- OBJ: pre-scan for line-accurate errors that assimp reports vaguely or not at all ---- */

static bool mesh_io_obj_numbers(const char **p, const char *e, int n, const char *kind, const char *where,
                                struct err *err)
{
    const char *tb, *te;
    for (int i = 0; i < n; i++) {
        double v;
        if (!mesh_io_next_token(p, e, &tb, &te) || !mesh_io_token_double(tb, te, &v))
            return err_set(err, ERR_PARSE, where, "%s needs %d numbers", kind, n);
        if (!isfinite(v) || !isfinite((float)v))
            return err_set(err, ERR_INVALID, where, "%s has a non-finite coordinate '%.*s'", kind,
                           (int)(te - tb), tb);
    }
    return true;
}

static bool mesh_io_obj_prescan(const char *data, size_t len, const char *name, struct err *err)
{
    char where[300];
    const char *b, *e, *p, *tb, *te;
    uint64_t vertices = 0;

    if (!mesh_io_text_check(data, len, name, err)) return false;
    struct mesh_io_lines it = {data, data + len, 0};
    while (mesh_io_next_line(&it, &b, &e)) {
        p = b;
        if (!mesh_io_next_token(&p, e, &tb, &te)) continue;
        bool is_v = mesh_io_token_is(tb, te, "v"), is_vn = mesh_io_token_is(tb, te, "vn");
        if (!is_v && !is_vn) continue;
        snprintf(where, sizeof where, "%s:%u", name, it.number);
        if (!mesh_io_obj_numbers(&p, e, 3, is_v ? "vertex" : "normal", where, err)) return false;
        if (is_v && ++vertices > MESH_IO_MAX_VERTICES)
            return err_set(err, ERR_LIMIT, where, "more than %u vertices", MESH_IO_MAX_VERTICES);
    }

    /* Second pass: positive indices may refer forward (assimp allows it), negative ones count
     * back from the vertices seen so far. */
    uint64_t seen = 0;
    it = (struct mesh_io_lines){data, data + len, 0};
    while (mesh_io_next_line(&it, &b, &e)) {
        p = b;
        if (!mesh_io_next_token(&p, e, &tb, &te)) continue;
        if (mesh_io_token_is(tb, te, "v")) { seen++; continue; }
        if (!mesh_io_token_is(tb, te, "f")) continue;
        snprintf(where, sizeof where, "%s:%u", name, it.number);
        uint64_t corners = 0;
        while (mesh_io_next_token(&p, e, &tb, &te)) {
            if (++corners > MESH_IO_MAX_FACE_VERTICES)
                return err_set(err, ERR_LIMIT, where, "face has more than %u vertices", MESH_IO_MAX_FACE_VERTICES);
            const char *c = tb;
            bool neg = c < te && *c == '-';
            if (neg) c++;
            const char *digits = c;
            uint64_t v = 0;
            while (c < te && *c >= '0' && *c <= '9') {
                if (v <= UINT32_MAX) v = v * 10 + (uint64_t)(*c - '0');
                c++;
            }
            if (c == digits || (c < te && *c != '/'))
                return err_set(err, ERR_PARSE, where, "malformed face vertex '%.*s'", (int)(te - tb), tb);
            if (v == 0) return err_set(err, ERR_INVALID, where, "face refers to vertex 0 (OBJ indices start at 1)");
            if (!neg && v > vertices)
                return err_set(err, ERR_INVALID, where, "face refers to vertex %llu, but the file has %llu vertices",
                               (unsigned long long)v, (unsigned long long)vertices);
            if (neg && v > seen)
                return err_set(err, ERR_INVALID, where,
                               "face refers to vertex -%llu, but only %llu vertices precede it",
                               (unsigned long long)v, (unsigned long long)seen);
        }
    }
    return true;
}

/* ---- assimp, reading from memory through a one-file virtual file system ---- */

struct mesh_io_vfs {
    const char *name;  /* the one file it serves */
    const char *data;
    size_t len;
};

struct mesh_io_cursor {
    const struct mesh_io_vfs *vfs;
    size_t pos;
};

static size_t mesh_io_vfs_read(struct aiFile *f, char *buf, size_t size, size_t count)
{
    struct mesh_io_cursor *c = (struct mesh_io_cursor *)f->UserData;
    if (size == 0) return 0;
    size_t avail = (c->vfs->len - c->pos) / size;
    if (count > avail) count = avail;
    memcpy(buf, c->vfs->data + c->pos, count * size);
    c->pos += count * size;
    return count;
}

static size_t mesh_io_vfs_write(struct aiFile *f, const char *buf, size_t size, size_t count)
{
    (void)f, (void)buf, (void)size, (void)count;
    return 0;
}

static size_t mesh_io_vfs_tell(struct aiFile *f) { return ((struct mesh_io_cursor *)f->UserData)->pos; }
static size_t mesh_io_vfs_size(struct aiFile *f) { return ((struct mesh_io_cursor *)f->UserData)->vfs->len; }
static void mesh_io_vfs_flush(struct aiFile *f) { (void)f; }

static enum aiReturn mesh_io_vfs_seek(struct aiFile *f, size_t off, enum aiOrigin origin)
{
    struct mesh_io_cursor *c = (struct mesh_io_cursor *)f->UserData;
    size_t base = origin == aiOrigin_SET ? 0 : origin == aiOrigin_CUR ? c->pos : c->vfs->len;
    if (off > c->vfs->len - base) return aiReturn_FAILURE;
    c->pos = base + off;
    return aiReturn_SUCCESS;
}

static struct aiFile *mesh_io_vfs_open(struct aiFileIO *io, const char *path, const char *mode)
{
    const struct mesh_io_vfs *vfs = (const struct mesh_io_vfs *)io->UserData;
    /* Anything but the mesh itself (material libraries, absolute paths) does not exist. */
    if (strcmp(path, vfs->name) != 0 || strchr(mode, 'w') || strchr(mode, 'a')) return NULL;
    struct aiFile *f = calloc(1, sizeof *f);
    struct mesh_io_cursor *c = calloc(1, sizeof *c);
    if (!f || !c) { free(f); free(c); return NULL; }
    c->vfs = vfs;
    f->ReadProc = mesh_io_vfs_read;
    f->WriteProc = mesh_io_vfs_write;
    f->TellProc = mesh_io_vfs_tell;
    f->FileSizeProc = mesh_io_vfs_size;
    f->SeekProc = mesh_io_vfs_seek;
    f->FlushProc = mesh_io_vfs_flush;
    f->UserData = (aiUserData)c;
    return f;
}

static void mesh_io_vfs_close(struct aiFileIO *io, struct aiFile *f)
{
    (void)io;
    if (!f) return;
    free(f->UserData);
    free(f);
}

/* What assimp imported, before triangulation: every index in range, every number finite. */
static bool mesh_io_check_import(const struct aiScene *s, const char *name, struct err *err)
{
    for (unsigned m = 0; m < s->mNumMeshes; m++) {
        const struct aiMesh *me = s->mMeshes[m];
        char part[48] = "";
        if (s->mNumMeshes > 1) snprintf(part, sizeof part, "part %u, ", m);
        for (unsigned v = 0; v < me->mNumVertices; v++) {
            const struct aiVector3D *p = &me->mVertices[v];
            if (!isfinite(p->x) || !isfinite(p->y) || !isfinite(p->z))
                return err_set(err, ERR_INVALID, name, "%svertex %u has a non-finite coordinate (%g, %g, %g)",
                               part, v, (double)p->x, (double)p->y, (double)p->z);
            if (me->mNormals) {
                const struct aiVector3D *n = &me->mNormals[v];
                if (!isfinite(n->x) || !isfinite(n->y) || !isfinite(n->z))
                    return err_set(err, ERR_INVALID, name, "%snormal of vertex %u is not finite", part, v);
                if (n->x == 0.0f && n->y == 0.0f && n->z == 0.0f)
                    return err_set(err, ERR_INVALID, name, "%snormal of vertex %u has zero length", part, v);
            }
        }
        for (unsigned f = 0; f < me->mNumFaces; f++) {
            const struct aiFace *face = &me->mFaces[f];
            for (unsigned k = 0; k < face->mNumIndices; k++)
                if (face->mIndices[k] >= me->mNumVertices)
                    return err_set(err, ERR_INVALID, name, "%sface %u refers to vertex %u, but there are %u vertices",
                                   part, f, face->mIndices[k], me->mNumVertices);
        }
    }
    return true;
}

static bool mesh_io_has_polygons(const struct aiScene *s)
{
    for (unsigned m = 0; m < s->mNumMeshes; m++)
        for (unsigned f = 0; f < s->mMeshes[m]->mNumFaces; f++)
            if (s->mMeshes[m]->mFaces[f].mNumIndices > 3) return true;
    return false;
}

/* Merges the triangles of every part into one mesh; points and lines are dropped. */
static bool mesh_io_merge(const struct aiScene *s, const char *name, struct mesh *out, struct err *err)
{
    uint64_t tris = 0, verts = 0;
    bool all_normals = true;
    for (unsigned m = 0; m < s->mNumMeshes; m++) {
        const struct aiMesh *me = s->mMeshes[m];
        uint64_t t = 0;
        for (unsigned f = 0; f < me->mNumFaces; f++) t += me->mFaces[f].mNumIndices == 3;
        if (!t) continue;
        tris += t;
        verts += me->mNumVertices;
        all_normals = all_normals && me->mNormals;
    }
    if (tris == 0) return err_set(err, ERR_INVALID, name, "the file has no triangles (only points or lines, or nothing)");
    if (tris > MESH_IO_MAX_TRIANGLES)
        return err_set(err, ERR_LIMIT, name, "%llu triangles, more than the limit of %u", (unsigned long long)tris,
                       MESH_IO_MAX_TRIANGLES);
    if (verts > MESH_IO_MAX_VERTICES)
        return err_set(err, ERR_LIMIT, name, "%llu vertices, more than the limit of %u", (unsigned long long)verts,
                       MESH_IO_MAX_VERTICES);

    struct mesh r = {(uint32_t)verts, (uint32_t)tris, NULL, NULL, NULL};
    r.positions = malloc(sizeof *r.positions * verts);
    r.normals = all_normals ? malloc(sizeof *r.normals * verts) : NULL;
    r.indices = malloc(sizeof *r.indices * 3 * tris);
    if (!r.positions || !r.indices || (all_normals && !r.normals)) {
        mesh_io_destroy(&r);
        return err_set(err, ERR_NOMEM, name, "out of memory for %llu triangles", (unsigned long long)tris);
    }
    uint32_t vbase = 0, t = 0;
    for (unsigned m = 0; m < s->mNumMeshes; m++) {
        const struct aiMesh *me = s->mMeshes[m];
        bool any = false;
        for (unsigned f = 0; f < me->mNumFaces; f++) {
            const struct aiFace *face = &me->mFaces[f];
            if (face->mNumIndices != 3) continue;
            for (int k = 0; k < 3; k++) {
                if (face->mIndices[k] >= me->mNumVertices) {  /* triangulation must not invent any */
                    mesh_io_destroy(&r);
                    return err_set(err, ERR_INTERNAL, name, "triangulation produced an index out of range");
                }
                r.indices[3 * t + (uint32_t)k] = vbase + face->mIndices[k];
            }
            t++;
            any = true;
        }
        if (!any) continue;
        for (unsigned v = 0; v < me->mNumVertices; v++) {
            r.positions[vbase + v] = vec3_make(me->mVertices[v].x, me->mVertices[v].y, me->mVertices[v].z);
            if (r.normals)
                r.normals[vbase + v] = vec3_make(me->mNormals[v].x, me->mNormals[v].y, me->mNormals[v].z);
        }
        vbase += me->mNumVertices;
    }
    *out = r;
    return true;
}

bool mesh_io_load_memory(const void *data, size_t len, const char *name_for_errors, const char *ext,
                         struct mesh *out, struct err *err)
{
    const char *name = name_for_errors ? name_for_errors : "mesh";
    memset(out, 0, sizeof *out);
    bool is_ply = ext && strcasecmp(ext, "ply") == 0, is_obj = ext && strcasecmp(ext, "obj") == 0;
    if (!is_ply && !is_obj)
        return err_set(err, ERR_UNSUPPORTED, name, "unsupported mesh format '%s' (expected ply or obj)",
                       ext ? ext : "");
    if (len > MESH_IO_MAX_FILE_BYTES)
        return err_set(err, ERR_LIMIT, name, "mesh file is %zu bytes, more than the limit of %u", len,
                       MESH_IO_MAX_FILE_BYTES);
    if (len == 0) return err_set(err, ERR_PARSE, name, "mesh file is empty");
    if (is_ply && !mesh_io_ply_check(data, len, name, err)) return false;
    if (is_obj && !mesh_io_obj_prescan(data, len, name, err)) return false;

    struct mesh_io_vfs vfs = {is_ply ? "restird-mesh.ply" : "restird-mesh.obj", data, len};
    struct aiFileIO io = {mesh_io_vfs_open, mesh_io_vfs_close, (aiUserData)&vfs};
    bool ok = false;
    pthread_mutex_lock(&mesh_io_lock);
    const struct aiScene *s = aiImportFileExWithProperties(vfs.name, 0, &io, NULL);
    if (!s) {
        const char *msg = aiGetErrorString();
        int n = (int)strlen(msg);
        while (n > 0 && (msg[n - 1] == ' ' || msg[n - 1] == '\n')) n--;
        err_set(err, ERR_PARSE, name, "cannot read the mesh: %.*s", n, msg);
    } else if (mesh_io_check_import(s, name, err)) {
        /* Triangulate only after the check: it reads vertex positions through the indices. And
         * only when some face has more than three corners: a mesh the importer marked as holding
         * polygons whose faces are all points, lines and triangles (a malformed binary PLY can
         * give one) trips an assertion in assimp's triangulation, which aborts the process. */
        if (mesh_io_has_polygons(s)) {
            s = aiApplyPostProcessing(s, aiProcess_Triangulate);
            if (!s) err_set(err, ERR_PARSE, name, "cannot triangulate the mesh: %s", aiGetErrorString());
        }
        if (s) ok = mesh_io_merge(s, name, out, err);
    }
    if (s) aiReleaseImport(s);
    pthread_mutex_unlock(&mesh_io_lock);
    return ok;
}

bool mesh_io_load_file(const char *path, const char *name_for_errors, const char *ext, struct mesh *out,
                       struct err *err)
{
    const char *name = name_for_errors ? name_for_errors : path;
    memset(out, 0, sizeof *out);
    if (!ext) ext = mesh_io_format_of(path);
    if (!ext) return err_set(err, ERR_UNSUPPORTED, name, "mesh file '%s' is not .ply or .obj", name);
    char *buf;
    size_t size;
    if (!fileio_read_all(path, "mesh file", name, MESH_IO_MAX_FILE_BYTES, &buf, &size, err)) return false;
    bool ok = mesh_io_load_memory(buf, size, name, ext, out, err);
    free(buf);
    return ok;
}
