/* cli.c — `build/restir`, the offline command line: render a scene file to EXR, or compare two
 * EXR images. A thin front end over renderer/: it parses arguments strictly, reports progress
 * on a terminal, and prints one summary (or one JSON object with --json). Exit status: 0 done,
 * 1 the work failed (the message says why), 2 the command line is wrong; compare's is its
 * verdict for CI instead: 0 pass, 1 warn, 2 fail, 3 could not compare (its command line too). */
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

#include "animate.h"
#include "image/exrio.h"
#include "input/fileio.h"
#include "image/metrics.h"
#include "image/tonemap.h"
#include "integrators/reference_pt.h"
#include "methods/path_params.h"
#include "scene/scene.h"
#include "session/view.h"
#include "version.h"

/* The most samples per pixel and frame the CLI takes (--spp and --params). */
#define CLI_MAX_SPP (1u << 24)

/* What the CLI accepts in --params and --animation: the daemon's parsers, with limits that
 * only the options' own ranges bound. */
static const struct protocol_limits cli_limits = {.max_side = 16384, .max_pixels = 16384ull * 16384ull,
                                                  .max_spp = CLI_MAX_SPP, .max_frames = 1000000, .max_keys = 100000};

#define CLI_USAGE                                                                                  \
    "usage:\n"                                                                                     \
    "  restir render SCENE.json|SCENE_FOLDER [--method NAME]\n"                                    \
    "                [--spp N] [--size WxH]\n" \
    "                [--seed S] [--frame F]\n" \
    "                [--threads T] [--max-depth D] [--rr-depth R] [--no-nee] [--crop X0,Y0,X1,Y1]\n"    \
    "                [--frames F] [--average-last N] [--animation FILE.json] [--params JSON]\n"       \
    "                [--profile real-time|converge]\n"                                               \
    "                [--half] [--json] -o OUT.exr|OUT.png   (.png: an 8-bit preview, exposure 0, clamp)\n" \
    "  restir compare A.exr B.exr [--fail-mape X] [--fail-relmse X] [--fail-rmse X] [--fail-mean X]\n" \
    "                [--warn-mape X] [--warn-relmse X] [--warn-rmse X] [--warn-mean X]\n"       \
    "                [--diff OUT.exr|OUT.png] [--fail-percent P --pixel-threshold T]\n"          \
    "                [--fail-nonfinite N] [--json]\n"                                              \
    "                (B is the reference; prints one JSON object with or without --json, and a\n" \
    "                verdict line on stderr; exit 0 pass, 1 warn, 2 fail, 3 could not compare,\n" \
    "                a wrong compare command line included)\n"                                   \
    "  restir methods [--json]         (the methods, their capabilities and parameters)\n"        \
    "  restir --version                (the version and the commit it was built from)\n"         \
    "defaults: --spp 16 --size 256x256 --seed 0 --max-depth 64 --rr-depth 3 (Russian roulette\n"  \
    "after R bounces; a method whose own rr_depth differs keeps it unless --rr-depth is given;\n" \
    "R >= max depth turns it off), next-event estimation with MIS (--no-nee: BSDF sampling\n"     \
    "only), all cores, float EXR; --method: the first method below.\n"                           \
    "--spp, --max-depth, --rr-depth and --no-nee set the method's parameter of that name (spp,\n" \
    "max_depth, rr_depth; nee or nee_candidates): a method without it refuses the option.\n"     \
    "--frames F renders F consecutive frames in one session (seeds per frame, as the daemon's\n"   \
    "sessions) and writes the last; --average-last N writes the mean of the last N instead.\n"    \
    "--animation FILE.json takes camera and light keys from a file holding the body of a daemon\n" \
    "animation job ({\"animation\": {...}}, protocol/API.md) and its frame count unless --frames\n" \
    "is given. A method that takes no spp traces one path per pixel and frame: render more frames.\n" \
    "compare: a metric above its --fail- level fails, above its --warn- level warns (one that is\n" \
    "not a number trips any level set); \"mean\" is |mean A / mean B - 1| of the channel where it\n" \
    "is largest, a bias of the whole image; --fail-percent P --pixel-threshold T fails when more than\n" \
    "P % of the pixels have a relative error (MAPE's per-pixel term) above T; --diff writes that\n" \
    "error per pixel (.exr: float; .png: 8-bit, white at 1 and above). A pixel of A with a NaN or\n" \
    "Inf channel has an infinite error (above any T), and more than N of them fail\n"             \
    "(--fail-nonfinite, default 0).\n"                                                             \
    "--params sets the method's parameters as the daemon's session \"params\" object (keys it\n"  \
    "leaves out take the options given, else their defaults: spp --spp's 16, the others the\n"  \
    "method's own; an option and a key that set the same parameter are refused), e.g.\n"           \
    "--params '{\"spatial_neighbors\": 0}'; restir methods lists every method's parameters. A still\n" \
    "image of pt (the one --crop and --frame take) is not a session's frame and takes no --params:\n" \
    "give --frames 1 beside --params.\n"                                                       \
    "--profile converge starts a sequence's parameters from the method's converge profile (its\n" \
    "frames unbiased draws of their own, for an image averaged with --average-last; restir\n" \
    "methods --json lists each parameter's converge_default) instead of its real-time defaults;\n" \
    "--params is read over either. The default: converge for --average-last without --animation\n" \
    "(a still image), else real-time.\n"

/* The usage text, then the methods --method takes, from the registry. */
static void cli_usage(FILE *out)
{
    fputs(CLI_USAGE, out);
    fputs("methods (restir methods --json gives their parameters, defaults and ranges; --crop and\n"
          "--frame are options of a still image of the methods marked *):\n", out);
    for (uint32_t i = 0; i < method_count(); i++)
        fprintf(out, "  %-12s%s %s\n", method_at(i)->name, method_at(i)->caps & METHOD_STILL_CROP ? "*" : " ",
                method_at(i)->summary);
}

/* The methods that render a still image in one go (METHOD_STILL_CROP), for messages. */
static const char *cli_still_methods(void)
{
    static char names[128];
    size_t n = 0;
    names[0] = '\0';
    for (uint32_t i = 0; i < method_count() && n < sizeof names; i++)
        if (method_at(i)->caps & METHOD_STILL_CROP)
            n += (size_t)snprintf(names + n, sizeof names - n, "%s%s", n ? ", " : "", method_at(i)->name);
    return names;
}

static int cli_usage_error(const char *fmt, const char *arg)
{
    fprintf(stderr, "restir: ");
    fprintf(stderr, fmt, arg);
    fputc('\n', stderr);
    cli_usage(stderr);
    return 2;
}

/* --help or -h among a command's arguments. */
static bool cli_wants_help(int argc, char **argv)
{
    for (int i = 0; i < argc; i++)
        if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) return true;
    return false;
}

/* The registry: one line per method, or with --json the body of the daemon's GET /v1/methods
 * (spp ranges within the CLI's own limit). */
static int cli_methods(int argc, char **argv)
{
    if (cli_wants_help(argc, argv)) {
        cli_usage(stdout);
        return 0;
    }
    bool json = argc == 1 && strcmp(argv[0], "--json") == 0;
    if (argc > 1 || (argc == 1 && !json)) return cli_usage_error("%s", "methods takes only --json");
    if (!json) {
        for (uint32_t i = 0; i < method_count(); i++) {
            const struct method_desc *m = method_at(i);
            printf("%-12s %s\n", m->name, m->summary);
            for (uint32_t k = 0; k < m->param_count; k++) printf("    %-20s %s\n", m->params[k].key, m->params[k].help);
        }
        return 0;
    }
    struct jsonw w;
    jsonw_init(&w);
    protocol_write_methods(&w, &cli_limits);
    size_t len = 0;
    char *text = jsonw_finish(&w, &len);
    if (!text) {
        fprintf(stderr, "restir: out of memory\n");
        return 1;
    }
    printf("%s\n", text);
    free(text);
    return 0;
}

/* The output's format, from its file name: .exr, or .png (an 8-bit preview through the
 * daemon's tone mapper: exposure 0, clamp). */
enum cli_format { CLI_EXR, CLI_PNG };
static bool cli_output_format(const char *path, enum cli_format *out)
{
    const char *dot = strrchr(path, '.');
    if (dot && strchr(dot, '/') == NULL) {
        if (strcasecmp(dot, ".exr") == 0) return *out = CLI_EXR, true;
        if (strcasecmp(dot, ".png") == 0) return *out = CLI_PNG, true;
    }
    return false;
}

/* The folder `path` would be written into exists: checked before a render, so a long render is
 * not lost to a typo in -o. */
static bool cli_output_folder_exists(const char *path)
{
    char dir[4096];
    const char *slash = strrchr(path, '/');
    if (!slash) return true;
    size_t n = slash == path ? 1 : (size_t)(slash - path);
    if (n >= sizeof dir) return false;
    memcpy(dir, path, n);
    dir[n] = '\0';
    struct stat sb;
    return stat(dir, &sb) == 0 && S_ISDIR(sb.st_mode);
}

/* Writes the image in the format its name says; false with a message on stderr. */
static bool cli_write_image(const char *path, enum cli_format format, const struct image *img, bool half)
{
    struct err err = {0};
    char msg[1024];
    bool ok;
    if (format == CLI_EXR) {
        struct exrio_write_opts wo = {.pixel = half ? EXRIO_HALF : EXRIO_FLOAT, .compression = EXRIO_ZIP};
        ok = exrio_write_file(path, img, &wo, &err);
    } else {
        unsigned char *png = NULL;
        size_t size = 0;
        const struct tonemap_opts to = {.exposure_ev = 0.0f, .curve = TONEMAP_CLAMP};
        ok = tonemap_png(img, &to, &png, &size, &err);
        FILE *f = ok ? fopen(path, "wb") : NULL;
        if (ok && !f) ok = err_set(&err, ERR_IO, NULL, "%s", strerror(errno));
        if (f && fwrite(png, 1, size, f) != size) ok = err_set(&err, ERR_IO, NULL, "%s", strerror(errno));
        if (f && fclose(f) != 0 && ok) ok = err_set(&err, ERR_IO, NULL, "%s", strerror(errno));
        free(png);
    }
    if (!ok) fprintf(stderr, "restir: cannot write %s: %s\n", path, err_format(&err, msg, sizeof msg));
    return ok;
}

static bool cli_parse_u64(const char *s, uint64_t max, uint64_t *out)
{
    if (!s || !*s || *s == '-' || *s == '+') return false;
    errno = 0;
    char *end;
    unsigned long long v = strtoull(s, &end, 10);
    if (errno || *end || v > max) return false;
    *out = v;
    return true;
}

static bool cli_parse_u32(const char *s, uint32_t max, uint32_t *out)
{
    uint64_t v;
    if (!cli_parse_u64(s, max, &v)) return false;
    *out = (uint32_t)v;
    return true;
}

static bool cli_parse_size(const char *s, uint32_t *w, uint32_t *h)
{
    char buf[64];
    if (!s || strlen(s) >= sizeof buf) return false;
    strcpy(buf, s);
    char *x = strchr(buf, 'x');
    if (!x) return false;
    *x = 0;
    return cli_parse_u32(buf, 16384, w) && cli_parse_u32(x + 1, 16384, h) && *w > 0 && *h > 0;
}

static bool cli_parse_crop(const char *s, uint32_t v[4])
{
    char buf[128];
    if (!s || strlen(s) >= sizeof buf) return false;
    strcpy(buf, s);
    char *save = NULL, *tok = strtok_r(buf, ",", &save);
    for (int i = 0; i < 4; i++) {
        if (!tok || !cli_parse_u32(tok, 16384, &v[i])) return false;
        tok = strtok_r(NULL, ",", &save);
    }
    return tok == NULL;
}

/* The methods with a parameter named `key`, for messages. */
static const char *cli_methods_with(const char *key, const char *or_key)
{
    static char names[128];
    size_t n = 0;
    names[0] = '\0';
    for (uint32_t i = 0; i < method_count() && n < sizeof names; i++) {
        const struct method_desc *m = method_at(i);
        if (method_param_find(m, key) || (or_key && method_param_find(m, or_key)))
            n += (size_t)snprintf(names + n, sizeof names - n, "%s%s", n ? ", " : "", m->name);
    }
    return names;
}

/* An option that sets one of the method's parameters: given or not, and the parameter's key in
 * the registry (NULL when the method has none such). */
struct cli_param_option {
    const char *option;
    const char *key;
    bool given;
    uint32_t value;                    /* a uint parameter's value, checked against its range */
};

/* --params names the method's parameter `key`: `params_given` has bit i set when it names
 * rm->params[i] (protocol_parse_method_params). */
static bool cli_params_name(const struct method_desc *rm, uint32_t params_given, const char *key)
{
    const struct method_param *mp = method_param_find(rm, key);
    return mp && (params_given & (1u << (mp - rm->params)));
}

/* Each option given must set a parameter the method has, and --params must not set the same
 * one: the usage message, or NULL when the options hold. */
static const char *cli_check_param_options(const struct method_desc *rm, const struct cli_param_option *opts,
                                           size_t count, uint32_t params_given, char *msg, size_t size)
{
    for (size_t i = 0; i < count; i++) {
        const struct cli_param_option *o = &opts[i];
        if (!o->given) continue;
        if (strcmp(o->option, "--spp") == 0 && !(rm->caps & METHOD_TAKES_SPP)) {
            snprintf(msg, size,
                     "--spp: %s takes no spp, it traces one path per pixel and frame: render N frames with "
                     "--frames N and write their mean with --average-last N",
                     rm->name);
            return msg;
        }
        if (strcmp(o->option, "--no-nee") == 0 && !o->key) {
            snprintf(msg, size, "--no-nee: %s has no next-event estimation switch (the methods with one: %s)", rm->name,
                     cli_methods_with("nee", "nee_candidates"));
            return msg;
        }
        if (!o->key || !method_param_find(rm, o->key)) {
            snprintf(msg, size, "%s: %s has no %s parameter (restir methods lists its parameters)", o->option,
                     rm->name, o->key ? o->key : o->option + 2);
            return msg;
        }
        const struct method_param *mp = method_param_find(rm, o->key);
        double max = mp->flags & METHOD_PARAM_SPP_LIMIT ? CLI_MAX_SPP : mp->max;
        if (mp->kind == METHOD_PARAM_UINT && (o->value < mp->min || o->value > max)) {
            snprintf(msg, size, "%s: %s's %s must be in %.0f..%.0f, got %u", o->option, rm->name, o->key, mp->min, max,
                     o->value);
            return msg;
        }
        if (cli_params_name(rm, params_given, o->key)) {
            snprintf(msg, size, "%s and \"%s\" in --params both set %s's %s: give it once", o->option, o->key,
                     rm->name, o->key);
            return msg;
        }
    }
    return NULL;
}

static void cli_progress(void *ctx, uint32_t done, uint32_t total)
{
    (void)ctx;
    int width = 40, filled = total ? (int)((uint64_t)done * width / total) : width;
    fprintf(stderr, "\r[%.*s%*s] %3u%%", filled, "########################################", width - filled, "",
            total ? (unsigned)((uint64_t)done * 100 / total) : 100u);
    if (done == total) fputc('\n', stderr);
    fflush(stderr);
}

/* --frames / --animation: F frames of one view (the daemon's session state, without the
 * server), writing the last. *st sums the frames' ray counts and times. Returns the exit
 * status: 0 rendered, 1 failed, 2 the options do not fit the animation. */
static int cli_render_sequence(struct scene *scene, const struct view_params *vp, unsigned threads, uint32_t frames,
                                uint32_t average_last, const char *anim_path, bool tty, struct image *img,
                                struct render_stats *st, uint32_t *rendered, struct frame_stats *last,
                                size_t *session_bytes)
{
    struct err err = {0};
    char msg[1024];
    struct view_animation anim = {0};
    double fps = 30.0;
    bool has_anim = false;
    if (anim_path) {
        char *text = NULL;
        size_t len = 0;
        if (!fileio_read_all(anim_path, "animation file", NULL, 16u << 20, &text, &len, &err)) {
            fprintf(stderr, "restir: %s\n", err_format(&err, msg, sizeof msg));
            return 1;
        }
        struct protocol_render_request rq;
        bool ok = protocol_parse_render_request(text, len, &cli_limits, &rq, &err) &&
                  animate_resolve(&rq, scene, &scene->camera, &anim, &err);
        free(text);
        if (!ok) {
            protocol_render_request_destroy(&rq);
            fprintf(stderr, "restir: %s: %s\n", anim_path, err_format(&err, msg, sizeof msg));
            return 1;
        }
        if (!frames) frames = rq.frames;
        fps = rq.fps;
        protocol_render_request_destroy(&rq);
        has_anim = true;
    }
    if (!frames) frames = 1;
    if (average_last > frames) {
        fprintf(stderr, "restir: --average-last %u is more frames than %s's %u\n", average_last, anim_path, frames);
        animate_destroy(&anim);
        return 2;
    }
    struct view v;
    if (!view_init(&v, scene, vp, threads, &err)) {
        fprintf(stderr, "restir: %s\n", err_format(&err, msg, sizeof msg));
        animate_destroy(&anim);
        return 1;
    }
    struct view_shape_change shapes[anim.track_count ? anim.track_count : 1];
    memset(st, 0, sizeof *st);
    bool ok = image_init(img, v.output.width, v.output.height, &err);
    if (average_last == 0) average_last = 1;
    for (uint32_t i = 0; ok && i < frames; i++) {
        struct view_frame_change change;
        struct frame_stats fs;
        ok = !has_anim || view_animation_change(&anim, (double)i / fps, &change, shapes, &err);
        ok = ok && view_render(&v, has_anim ? &change : NULL, &fs, NULL, NULL, &err);
        if (!ok) break;
        st->rays_intersect += fs.render.rays_intersect;
        st->rays_occluded += fs.render.rays_occluded;
        st->samples += fs.render.samples;
        st->nonfinite += fs.render.nonfinite;
        st->render_ms += fs.render.render_ms + fs.scene_update_ms;
        st->render_cpu_ms += fs.render.render_cpu_ms;
        st->threads = fs.render.threads;
        sms_counters_add(&st->sms, &fs.render.sms);
        *last = fs;
        if (i + average_last >= frames) {
            size_t n = (size_t)img->width * img->height;
            for (size_t k = 0; k < n; k++) img->pixels[k] = vec3_add(img->pixels[k], v.output.pixels[k]);
        }
        if (tty) cli_progress(NULL, i + 1, frames);
    }
    struct view_buffer_bytes bufs[VIEW_MAX_BUFFERS];
    view_bytes(&v, bufs, session_bytes);
    if (ok) {
        image_scale(img, 1.0f / (float)average_last);
    } else {
        image_destroy(img);
        fprintf(stderr, "restir: render failed: %s\n", err_format(&err, msg, sizeof msg));
    }
    *rendered = frames;
    view_destroy(&v);
    animate_destroy(&anim);
    return ok ? 0 : 1;
}

static int cli_render(int argc, char **argv)
{
    const char *scene_path = NULL, *out_path = NULL, *method = method_default()->name;
    uint32_t width = 256, height = 256;
    struct pt_params p = reference_pt_defaults(width, height);
    p.sampler = pt_method_defaults().sampler;  /* a still image is pt's, with pt's sampler */
    bool half = false, json = false;
    uint32_t crop[4] = {0, 0, 0, 0};
    bool has_crop = false, has_frame = false, has_rr_depth = false, has_max_depth = false;
    uint32_t frames = 0;
    const char *anim_path = NULL, *params_json = NULL;
    uint32_t average_last = 0;
    bool has_spp = false;
    enum method_profile profile = METHOD_PROFILE_REAL_TIME;
    bool has_profile = false;
    /* Each option once: a second value would silently replace the first. */
    const char *seen[32];
    size_t seen_count = 0;

    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            cli_usage(stdout);
            return 0;
        }
        if (a[0] == '-') {
            for (size_t k = 0; k < seen_count; k++)
                if (strcmp(seen[k], a) == 0) return cli_usage_error("%s is given twice: give it once", a);
            if (seen_count < sizeof seen / sizeof seen[0]) seen[seen_count++] = a;
        }
        if (strcmp(a, "--half") == 0) { half = true; continue; }
        if (strcmp(a, "--json") == 0) { json = true; continue; }
        if (strcmp(a, "--no-nee") == 0) { p.nee = false; continue; }
        if (a[0] != '-') {
            if (scene_path) return cli_usage_error("unexpected argument '%s'", a);
            scene_path = a;
            continue;
        }
        if (!v) return cli_usage_error("option %s needs a value", a);
        i++;
        uint64_t u64;
        if (strcmp(a, "-o") == 0) out_path = v;
        else if (strcmp(a, "--method") == 0) method = v;
        else if (strcmp(a, "--spp") == 0) {
            if (!cli_parse_u32(v, CLI_MAX_SPP, &p.spp) || p.spp == 0) return cli_usage_error("--spp: expected 1..16777216, got '%s'", v);
            has_spp = true;
        } else if (strcmp(a, "--size") == 0) {
            if (!cli_parse_size(v, &width, &height)) return cli_usage_error("--size: expected WxH with sides 1..16384, got '%s'", v);
        } else if (strcmp(a, "--seed") == 0) {
            if (!cli_parse_u64(v, UINT64_MAX, &u64)) return cli_usage_error("--seed: expected a non-negative integer, got '%s'", v);
            p.seed = u64;
        } else if (strcmp(a, "--frame") == 0) {
            if (!cli_parse_u32(v, UINT32_MAX, &p.frame)) return cli_usage_error("--frame: expected a non-negative integer, got '%s'", v);
            has_frame = true;
        } else if (strcmp(a, "--frames") == 0) {
            if (!cli_parse_u32(v, 1000000, &frames) || frames == 0) return cli_usage_error("--frames: expected 1..1000000, got '%s'", v);
        } else if (strcmp(a, "--animation") == 0) {
            anim_path = v;
        } else if (strcmp(a, "--params") == 0) {
            params_json = v;
        } else if (strcmp(a, "--profile") == 0) {
            /* The command line's spelling of the protocol's real_time. */
            has_profile = true;
            if (strcmp(v, "real-time") == 0) profile = METHOD_PROFILE_REAL_TIME;
            else if (strcmp(v, "converge") == 0) profile = METHOD_PROFILE_CONVERGE;
            else return cli_usage_error("--profile: expected real-time or converge, got '%s'", v);
        } else if (strcmp(a, "--average-last") == 0) {
            if (!cli_parse_u32(v, 1000000, &average_last) || average_last == 0)
                return cli_usage_error("--average-last: expected 1..1000000, got '%s'", v);
        } else if (strcmp(a, "--threads") == 0) {
            uint32_t t;
            if (!cli_parse_u32(v, 1024, &t)) return cli_usage_error("--threads: expected 0..1024 (0 = all cores), got '%s'", v);
            p.threads = t;
        } else if (strcmp(a, "--max-depth") == 0) {
            if (!cli_parse_u32(v, 1024, &p.max_depth)) return cli_usage_error("--max-depth: expected 0..1024, got '%s'", v);
            has_max_depth = true;
        } else if (strcmp(a, "--rr-depth") == 0) {
            if (!cli_parse_u32(v, 1u << 20, &p.rr_depth)) return cli_usage_error("--rr-depth: expected 0..1048576, got '%s'", v);
            has_rr_depth = true;
        } else if (strcmp(a, "--crop") == 0) {
            if (!cli_parse_crop(v, crop)) return cli_usage_error("--crop: expected X0,Y0,X1,Y1, got '%s'", v);
            has_crop = true;
        } else return cli_usage_error("unknown option '%s'", a);
    }
    if (!scene_path) return cli_usage_error("%s", "render needs a scene file");
    if (!out_path) return cli_usage_error("%s", "render needs -o OUT.exr");
    enum cli_format format;
    if (!cli_output_format(out_path, &format))
        return cli_usage_error("-o: '%s' names no format: end it in .exr, or .png for an 8-bit preview", out_path);
    if (format == CLI_PNG && half) return cli_usage_error("%s", "--half is a pixel type of EXR output, not of .png");
    if (average_last && !frames && !anim_path)
        return cli_usage_error("%s", "--average-last averages a sequence's last frames: it needs --frames or --animation");
    if (frames && average_last > frames) {
        char m[128];
        snprintf(m, sizeof m, "--average-last %u is more frames than --frames %u renders", average_last, frames);
        return cli_usage_error("%s", m);
    }
    if (!cli_output_folder_exists(out_path)) {
        fprintf(stderr, "restir: cannot write %s: its folder does not exist\n", out_path);
        return 1;
    }
    const struct method_desc *rm = method_find(method);
    if (!rm) {
        char msg[400], names[256];
        method_names(names, sizeof names, ", ");
        snprintf(msg, sizeof msg, "--method: unknown method '%.48s' (available: %s)", method, names);
        return cli_usage_error("%s", msg);
    }
    if (!(rm->caps & METHOD_STILL_CROP) && (has_crop || has_frame))
        return cli_usage_error("--crop and --frame are options of a still image of %s", cli_still_methods());
    /* A still image of the reference path tracer, or a sequence of the method's frames. */
    const bool sequence = frames || anim_path || !(rm->caps & METHOD_STILL_CROP);
    if (sequence && (has_crop || has_frame))
        return cli_usage_error("%s", "--crop and --frame do not combine with --frames or --animation");
    if (!sequence && params_json)
        return cli_usage_error("--params needs --frames, --animation or a method other than %s", cli_still_methods());
    /* The mean of a still sequence's last frames is a still image: unless told otherwise, its
     * frames are the converge profile's (unbiased draws of their own), not the real-time defaults' (whose
     * temporal reuse correlates them, so that their mean gains less from each). */
    if (!has_profile && average_last && !anim_path) profile = METHOD_PROFILE_CONVERGE;
    /* A sequence's parameters: the method's defaults under the profile, --params over them (read
     * as the daemon reads a session's), then the options below over the keys --params leaves out. */
    struct view_params vp = view_params_defaults(rm, width, height);
    view_params_set_profile(&vp, profile);
    uint32_t params_given = 0;
    if (params_json) {
        struct err perr = {0};
        char pmsg[1024];
        if (!protocol_parse_method_params(params_json, strlen(params_json), &cli_limits, &vp, &params_given, &perr))
            return cli_usage_error("--params: %s", err_format(&perr, pmsg, sizeof pmsg));
    }
    const char *nee_key = method_param_find(rm, "nee")              ? "nee"
                          : method_param_find(rm, "nee_candidates") ? "nee_candidates"
                                                                    : NULL;
    /* --no-nee sets nee (a bool) or nee_candidates to 0. */
    const struct cli_param_option param_opts[] = {{"--spp", "spp", has_spp, p.spp},
                                                  {"--max-depth", "max_depth", has_max_depth, p.max_depth},
                                                  {"--rr-depth", "rr_depth", has_rr_depth, p.rr_depth},
                                                  {"--no-nee", nee_key, !p.nee, 0}};
    char refusal[512];
    const char *refused = cli_check_param_options(rm, param_opts, sizeof param_opts / sizeof param_opts[0],
                                                  params_given, refusal, sizeof refusal);
    if (refused) return cli_usage_error("%s", refused);
    p.width = width;
    p.height = height;
    if (has_crop) {
        p.crop_x0 = crop[0];
        p.crop_y0 = crop[1];
        p.crop_x1 = crop[2];
        p.crop_y1 = crop[3];
    }

    struct err err = {0};
    char msg[1024];
    /* A scene folder of the library (scenes/NAME/) stands for its scene.json. */
    char folder_scene[4096];
    struct stat sb;
    if (stat(scene_path, &sb) == 0 && S_ISDIR(sb.st_mode)) {
        int n = snprintf(folder_scene, sizeof folder_scene, "%s/scene.json", scene_path);
        if (n < 0 || (size_t)n >= sizeof folder_scene) return cli_usage_error("scene path too long: '%s'", scene_path);
        scene_path = folder_scene;
    }
    struct scene *scene = scene_load_file(scene_path, &err);
    if (!scene || !scene_commit(scene, &err)) {
        /* The file's name once: errors about the file itself already start with it. */
        if (strcmp(err.where, scene_path) == 0) fprintf(stderr, "restir: %s\n", err_format(&err, msg, sizeof msg));
        else fprintf(stderr, "restir: %s: %s\n", scene_path, err_format(&err, msg, sizeof msg));
        if (scene) scene_release(scene);
        return 1;
    }
    struct image img;
    struct render_stats st;
    struct frame_stats last = {0};
    size_t session_bytes = 0;
    bool tty = isatty(STDERR_FILENO) && !json;
    uint32_t rendered = 1;
    /* Samples per pixel and frame as rendered: --params may set the spp of a method that takes
     * it; the others trace one camera path per pixel and frame. */
    uint32_t frame_spp = p.spp;
    uint32_t reservoir_bytes = 0;   /* per pixel and reservoir buffer */
    if (sequence) {
        vp.seed = p.seed;
        /* The options given, on top: --params sets none of their parameters (checked above).
         * The CLI's own spp default (16) holds too unless --params names spp, so adding
         * --params for another key does not change the samples per frame. */
        if (!cli_params_name(rm, params_given, "spp")) view_params_set_uint(&vp, "spp", p.spp);
        if (has_max_depth) view_params_set_uint(&vp, "max_depth", p.max_depth);
        if (has_rr_depth) view_params_set_uint(&vp, "rr_depth", p.rr_depth);
        if (!p.nee && !view_params_set_bool(&vp, "nee", false)) view_params_set_uint(&vp, "nee_candidates", 0);
        frame_spp = 1;
        if (rm->caps & METHOD_TAKES_SPP) view_params_get_uint(&vp, "spp", &frame_spp);
        reservoir_bytes = view_reservoir_bytes_per_pixel(&vp, scene);
        int status = cli_render_sequence(scene, &vp, p.threads, frames, average_last, anim_path, tty, &img, &st,
                                         &rendered, &last, &session_bytes);
        if (status != 0) {
            scene_release(scene);
            return status;
        }
    } else if (!reference_pt_render(scene, &p, &img, &st, tty ? cli_progress : NULL, NULL, &err)) {
        fprintf(stderr, "restir: render failed: %s\n", err_format(&err, msg, sizeof msg));
        scene_release(scene);
        return 1;
    }
    /* A failed write ends here: no summary says the render succeeded. */
    if (!cli_write_image(out_path, format, &img, half)) {
        image_destroy(&img);
        scene_release(scene);
        return 1;
    }

    double mean[3];
    metrics_image_mean(&img, mean);
    uint64_t rays = st.rays_intersect + st.rays_occluded;
    double rays_per_s = st.render_ms > 0 ? rays / (st.render_ms * 1e-3) : 0.0;
    unsigned threads = st.threads;
    /* The last frame's CPU time on all its threads, so that a benchmark can time the frame after a
     * warm-up by CPU as the daemon's render_cpu_ms does; a still pt image is its only frame. */
    double last_cpu_ms = sequence ? last.render.render_cpu_ms : st.render_cpu_ms;
    if (json) {
        printf("{\"method\":\"%s\",\"width\":%u,\"height\":%u,\"spp\":%u,\"frames\":%u,\"seed\":%" PRIu64 ",\"threads\":%u,"
               "\"time_ms\":%.3f,\"cpu_ms\":%.3f,\"last_frame_cpu_ms\":%.3f,\"rays\":%" PRIu64
               ",\"rays_intersect\":%" PRIu64 ",\"rays_occluded\":%" PRIu64
               ",\"rays_per_s\":%.6g,\"samples\":%" PRIu64 ",\"nonfinite\":%" PRIu64 ",\"mean\":[%.9g,%.9g,%.9g]",
               method, width, height, frame_spp, rendered, p.seed, threads, st.render_ms, st.render_cpu_ms, last_cpu_ms,
               rays,
               st.rays_intersect, st.rays_occluded, rays_per_s, st.samples, st.nonfinite, mean[0], mean[1], mean[2]);
        /* The last frame's method counters, as its descriptor lays them out. */
        protocol_print_method_counters(stdout, rm, &last, session_bytes, reservoir_bytes);
        if (rm->caps & METHOD_MANIFOLD_COUNTERS) {
            /* [SMS-SSP Table 1] (manifold sampling) over all frames rendered. */
            const struct sms_counters *c = &st.sms;
            printf(",\"sms\":{\"samples\":%" PRIu64 ",\"solutions\":%" PRIu64 ",\"newton_sample\":%" PRIu64
                   ",\"trials\":%" PRIu64 ",\"newton_trials\":%" PRIu64 ",\"capped\":%" PRIu64 ",\"with_prior\":%" PRIu64
                   ",\"sample_ms\":%.3f}",
                   c->samples, c->solutions, c->newton_sample, c->trials, c->newton_trials, c->capped, c->with_prior,
                   c->sample_ms);
        }
        printf("}\n");
    } else {
        fprintf(stderr, "%s: %ux%u, %u spp%s, %s: %.3f s, %.2f Mrays/s (%" PRIu64 " rays, %u threads)%s\n", out_path,
                width, height, frame_spp,
                rendered <= 1 ? "" : average_last > 1 ? " per frame, mean of a sequence's last frames" : " per frame, last of a sequence", method, st.render_ms * 1e-3, rays_per_s * 1e-6, rays, threads,
                st.nonfinite ? ", non-finite samples dropped" : "");
    }
    image_destroy(&img);
    scene_release(scene);
    return 0;
}

/* restir compare's exit statuses: a verdict for CI. A wrong command line is "could not
 * compare" too (3), not the other commands' 2, which here means fail. */
enum cli_verdict { CLI_PASS = 0, CLI_WARN = 1, CLI_FAIL = 2, CLI_CANNOT_COMPARE = 3 };
static const char *const cli_verdict_names[] = {"pass", "warn", "fail"};

/* A metric's thresholds: it trips a level when it is above it, or not a number (an image with
 * no finite pixels, or MAPE of an all-black reference: no evidence that it is close). NAN: the
 * level is not set. */
struct cli_limit {
    const char *metric; /* the options' suffix and the name in "tripped" */
    const char *label;  /* the name in the verdict line */
    double value, fail, warn;
};

static bool cli_parse_level(const char *s, double *out)
{
    if (!s || !*s) return false;
    errno = 0;
    char *end;
    double v = strtod(s, &end);
    if (errno || *end || !isfinite(v) || v < 0.0) return false;
    *out = v;
    return true;
}

static enum cli_verdict cli_limit_level(const struct cli_limit *l)
{
    bool bad_fail = !isnan(l->fail) && (isnan(l->value) || l->value > l->fail);
    bool bad_warn = !isnan(l->warn) && (isnan(l->value) || l->value > l->warn);
    return bad_fail ? CLI_FAIL : bad_warn ? CLI_WARN : CLI_PASS;
}

/* Appends to buf at *used (never past size). */
static void cli_append(char *buf, size_t size, size_t *used, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static void cli_append(char *buf, size_t size, size_t *used, const char *fmt, ...)
{
    if (*used >= size) return;
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(buf + *used, size - *used, fmt, ap);
    va_end(ap);
    if (n > 0) *used = *used + (size_t)n < size ? *used + (size_t)n : size;
}

/* A JSON number, or null for what JSON cannot hold. */
static void cli_append_number(char *buf, size_t size, size_t *used, double v)
{
    if (isfinite(v)) cli_append(buf, size, used, "%.9g", v);
    else cli_append(buf, size, used, "null");
}

static int cli_compare_usage_error(const char *fmt, const char *arg)
{
    cli_usage_error(fmt, arg);
    return CLI_CANNOT_COMPARE;
}

static int cli_compare(int argc, char **argv)
{
    if (cli_wants_help(argc, argv)) {
        cli_usage(stdout);
        return 0;
    }
    struct cli_limit limits[] = {{"mape", "mape", NAN, NAN, NAN},
                                 {"relmse", "relmse", NAN, NAN, NAN},
                                 {"rmse", "rmse", NAN, NAN, NAN},
                                 {"mean", "|mean A / mean B - 1| (largest channel)", NAN, NAN, NAN}};
    const size_t nlimits = sizeof limits / sizeof limits[0];
    const char *paths[2] = {NULL, NULL}, *diff_path = NULL;
    double fail_percent = NAN, pixel_threshold = NAN, fail_nonfinite = NAN;
    size_t path_count = 0;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--json") == 0) continue; /* the JSON object is the output either way */
        if (a[0] != '-') {
            if (path_count == 2) return cli_compare_usage_error("compare: unexpected argument '%s'", a);
            paths[path_count++] = a;
            continue;
        }
        if (!v) return cli_compare_usage_error("option %s needs a value", a);
        i++;
        double *level = NULL;
        for (size_t k = 0; k < nlimits && !level; k++) {
            if (strncmp(a, "--fail-", 7) == 0 && strcmp(a + 7, limits[k].metric) == 0) level = &limits[k].fail;
            if (strncmp(a, "--warn-", 7) == 0 && strcmp(a + 7, limits[k].metric) == 0) level = &limits[k].warn;
        }
        if (strcmp(a, "--fail-percent") == 0) level = &fail_percent;
        if (strcmp(a, "--pixel-threshold") == 0) level = &pixel_threshold;
        if (strcmp(a, "--fail-nonfinite") == 0) level = &fail_nonfinite;
        if (level) {
            if (!isnan(*level)) return cli_compare_usage_error("%s is given twice: give it once", a);
            char m[160];
            snprintf(m, sizeof m, "%s: expected a number >= 0, got '%.64s'", a, v);
            if (!cli_parse_level(v, level)) return cli_compare_usage_error("%s", m);
        } else if (strcmp(a, "--diff") == 0) {
            if (diff_path) return cli_compare_usage_error("%s is given twice: give it once", a);
            diff_path = v;
        } else {
            return cli_compare_usage_error("unknown option '%s'", a);
        }
    }
    if (path_count != 2) return cli_compare_usage_error("%s", "compare needs exactly two EXR files");
    if (isnan(fail_percent) != isnan(pixel_threshold))
        return cli_compare_usage_error("%s", "--fail-percent P and --pixel-threshold T go together: fail when more "
                                             "than P % of the pixels have a relative error above T");
    if (!isnan(fail_percent) && fail_percent > 100.0)
        return cli_compare_usage_error("%s", "--fail-percent: expected a percentage, 0..100");
    if (!isnan(fail_nonfinite) && floor(fail_nonfinite) != fail_nonfinite)
        return cli_compare_usage_error("%s", "--fail-nonfinite: expected a whole number of pixels >= 0");
    /* A NaN or Inf in the candidate is a broken render whatever the metrics of the pixels left
     * say, so it fails unless a number of them is allowed. */
    if (isnan(fail_nonfinite)) fail_nonfinite = 0.0;
    for (size_t k = 0; k < nlimits; k++) {
        if (limits[k].warn > limits[k].fail) {
            char m[200];
            snprintf(m, sizeof m, "--warn-%s %g is above --fail-%s %g: a warning level sits below the failing one",
                     limits[k].metric, limits[k].warn, limits[k].metric, limits[k].fail);
            return cli_compare_usage_error("%s", m);
        }
    }
    enum cli_format diff_format = CLI_EXR;
    if (diff_path && !cli_output_format(diff_path, &diff_format))
        return cli_compare_usage_error("--diff: '%s' names no format: end it in .exr, or .png for an 8-bit view",
                                       diff_path);
    if (diff_path && !cli_output_folder_exists(diff_path)) {
        fprintf(stderr, "restir: cannot write %s: its folder does not exist\n", diff_path);
        return CLI_CANNOT_COMPARE;
    }

    struct err err = {0};
    char msg[1024];
    struct image a = {0}, b = {0}, errors = {0};
    struct metrics m = {0};
    char json[METRICS_JSON_MAX + 1024];
    bool ok = exrio_read_file(paths[0], &a, &err) && exrio_read_file(paths[1], &b, &err) &&
              metrics_compare(&a, &b, &m, &err) && metrics_format_json(&m, json, METRICS_JSON_MAX, &err);
    /* The error image serves --diff and the pixel rule. */
    bool need_errors = diff_path || !isnan(fail_percent);
    if (ok && need_errors)
        ok = image_init(&errors, a.width, a.height, &err) && metrics_error_image(&a, &b, &m, &errors, &err);
    if (!ok) fprintf(stderr, "restir: %s\n", err_format(&err, msg, sizeof msg));
    double percent_above = NAN;
    if (ok && !isnan(fail_percent)) percent_above = 100.0 * metrics_fraction_above(&errors, pixel_threshold);
    if (ok && diff_path) ok = cli_write_image(diff_path, diff_format, &errors, false);
    image_destroy(&a);
    image_destroy(&b);
    image_destroy(&errors);
    if (!ok) return CLI_CANNOT_COMPARE;

    limits[0].value = m.mape;
    limits[1].value = m.relmse;
    limits[2].value = m.rmse;
    limits[3].value = m.mean_rel_diff_max;
    enum cli_verdict verdict = CLI_PASS;
    char tripped[1024], human[1024];
    size_t tn = 0, hn = 0;
    for (size_t k = 0; k < nlimits; k++) {
        enum cli_verdict level = cli_limit_level(&limits[k]);
        if (level == CLI_PASS) continue;
        double at = level == CLI_FAIL ? limits[k].fail : limits[k].warn;
        cli_append(tripped, sizeof tripped, &tn, "%s{\"metric\":\"%s\",\"level\":\"%s\",\"value\":", tn ? "," : "",
                   limits[k].metric, cli_verdict_names[level]);
        cli_append_number(tripped, sizeof tripped, &tn, limits[k].value);
        cli_append(tripped, sizeof tripped, &tn, ",\"threshold\":%.9g}", at);
        cli_append(human, sizeof human, &hn, "%s%s %.6g > %s level %g", hn ? "; " : "", limits[k].label,
                   limits[k].value, cli_verdict_names[level], at);
        if (level > verdict) verdict = level;
    }
    if (!isnan(fail_percent) && (isnan(percent_above) || percent_above > fail_percent)) {
        cli_append(tripped, sizeof tripped, &tn,
                   "%s{\"metric\":\"percent_above\",\"level\":\"fail\",\"value\":", tn ? "," : "");
        cli_append_number(tripped, sizeof tripped, &tn, percent_above);
        cli_append(tripped, sizeof tripped, &tn, ",\"threshold\":%.9g,\"pixel_threshold\":%.9g}", fail_percent,
                   pixel_threshold);
        cli_append(human, sizeof human, &hn, "%s%.6g %% of the pixels have a relative error above %g > fail level %g %%",
                   hn ? "; " : "", percent_above, pixel_threshold, fail_percent);
        verdict = CLI_FAIL;
    }
    if ((double)m.nonfinite_image > fail_nonfinite) {
        cli_append(tripped, sizeof tripped, &tn,
                   "%s{\"metric\":\"nonfinite\",\"level\":\"fail\",\"value\":%" PRIu64 ",\"threshold\":%.9g}",
                   tn ? "," : "", m.nonfinite_image, fail_nonfinite);
        cli_append(human, sizeof human, &hn, "%sNaN or Inf pixels in %s: %" PRIu64 " > fail level %g", hn ? "; " : "",
                   paths[0], m.nonfinite_image, fail_nonfinite);
        verdict = CLI_FAIL;
    }
    /* The metrics' object, then the verdict and what tripped it. */
    size_t jn = strlen(json) - 1; /* drops the closing brace */
    if (!isnan(fail_percent)) {
        cli_append(json, sizeof json, &jn, ",\"percent_above\":");
        cli_append_number(json, sizeof json, &jn, percent_above);
        cli_append(json, sizeof json, &jn, ",\"pixel_threshold\":%.9g", pixel_threshold);
    }
    cli_append(json, sizeof json, &jn, ",\"verdict\":\"%s\",\"tripped\":[%.*s]}", cli_verdict_names[verdict], (int)tn,
               tripped);
    printf("%s\n", json);
    if (verdict == CLI_PASS)
        fprintf(stderr, "restir compare: pass (mape %.6g, relmse %.6g, rmse %.6g)\n", m.mape, m.relmse, m.rmse);
    else
        fprintf(stderr, "restir compare: %s (%s)\n", cli_verdict_names[verdict], human);
    return verdict;
}

int main(int argc, char **argv)
{
    if (argc < 2 || strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) {
        cli_usage(argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    if (strcmp(argv[1], "--version") == 0) {
        printf("restir %s (commit %s)\n", RESTIRD_VERSION, restird_commit);
        return 0;
    }
    if (strcmp(argv[1], "render") == 0) {
        int status = cli_render(argc - 2, argv + 2);
        parallel_shutdown(); /* joins the worker pool: the process exits with nothing allocated */
        return status;
    }
    if (strcmp(argv[1], "compare") == 0) return cli_compare(argc - 2, argv + 2);
    if (strcmp(argv[1], "methods") == 0) return cli_methods(argc - 2, argv + 2);
    return cli_usage_error("unknown command '%s' (render, compare, methods)", argv[1]);
}
