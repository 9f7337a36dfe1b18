/* bench/sss_hybrid_map.c — which shift the hybrid criterion of restir_sss picks per pixel
 * ([ReSTIR SSS §4.1], as its Fig. 4): the initial samples of one frame are classified by
 * |x2 - x1| >= 2 max(d) or n1 . n2 <= 0.5 (reconnection) versus delayed reconnection.
 * Writes an EXR: blue = reconnection, yellow = delayed, dark grey = translucent but no sample,
 * black = not translucent; prints the counts as JSON. Built and run by bench/restir_sss.py
 * (a benchmark helper, not part of the daemon).
 * usage: sss_hybrid_map SCENE.json WIDTHxHEIGHT OUT.exr [candidates] */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "image/exrio.h"
#include "integrators/restir_sss.h"
#include "scene/scene.h"

int main(int argc, char **argv)
{
    if (argc < 4) {
        fprintf(stderr, "usage: %s SCENE.json WIDTHxHEIGHT OUT.exr [candidates]\n", argv[0]);
        return 2;
    }
    unsigned w = 0, h = 0;
    if (sscanf(argv[2], "%ux%u", &w, &h) != 2 || w == 0 || h == 0) return 2;
    struct err err = {0};
    struct scene *sc = scene_load_file(argv[1], &err);
    if (!sc || !scene_commit(sc, &err)) {
        fprintf(stderr, "%s: %s\n", argv[1], err.message);
        return 1;
    }
    struct restir_sss_params p = restir_sss_defaults();
    p.shift = RESTIR_SSS_HYBRID;
    if (argc > 4) p.candidates = (uint32_t)atoi(argv[4]);
    struct restir_sss_state st;
    struct method_frame f = {.scene = sc, .camera = &sc->camera, .seed = 1, .frame = 0, .threads = 0};
    struct image img;
    if (!restir_sss_init(&st, sc, &p, w, h, &err) || !restir_sss_initial_only(&st, &p, &f, &err) ||
        !image_init(&img, w, h, &err)) {
        fprintf(stderr, "%s\n", err.message);
        return 1;
    }
    _Alignas(16) unsigned char ctx[RESTIR_SSS_CTX_BYTES];
    restir_sss_bind(&st, &p, &f, ctx);
    unsigned long counts[4] = {0, 0, 0, 0};
    const size_t stride = restir_sss_ops.stride;
    for (uint32_t i = 0; i < w * h; i++) {
        const unsigned char *elem = st.rs.res[0] + (size_t)i * stride;
        const struct restir_head *head = (const struct restir_head *)elem;
        const struct gbuffer_pixel *g = &st.rs.gbuf[st.rs.cur].px[i];
        bool translucent = isfinite(g->t) &&
                           sc->materials[sc->shapes[g->shape].material].kind == MATERIAL_TRANSLUCENT;
        int cls = 0;
        if (translucent && head->M > 0) {
            struct restir_sss_info info;
            restir_sss_info(ctx, elem, i, &info);
            cls = head->W > 0.0f ? (info.reconnect ? 1 : 2) : 3;
        } else if (translucent) {
            cls = 3;
        }
        counts[cls]++;
        static const struct vec3 colours[4] = {{0, 0, 0}, {0.1f, 0.3f, 1.0f}, {1.0f, 0.8f, 0.0f}, {0.15f, 0.15f, 0.15f}};
        img.pixels[i] = colours[cls];
    }
    struct exrio_write_opts wo = {.pixel = EXRIO_HALF, .compression = EXRIO_ZIP};
    if (!exrio_write_file(argv[3], &img, &wo, &err)) {
        fprintf(stderr, "%s\n", err.message);
        return 1;
    }
    printf("{\"not_translucent\": %lu, \"reconnection\": %lu, \"delayed\": %lu, \"no_sample\": %lu}\n", counts[0],
           counts[1], counts[2], counts[3]);
    image_destroy(&img);
    restir_sss_destroy(&st);
    scene_release(sc);
    return 0;
}
