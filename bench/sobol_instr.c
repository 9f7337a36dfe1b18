/* sobol_instr.c — the work of one Sobol' sample (renderer/core/sobol.h) against one PCG pair,
 * for bench/sobol_instr.sh, which counts instructions under callgrind at two loop lengths and
 * divides the difference. `sobol_instr MODE N`: N draws of MODE (2d: sobol_2d; 1d: sobol_1d;
 * random2d: two rng_next_float), as a path tracer draws them: the dimension cycles through 0..7
 * with seeds derived once per pixel (every 1024 draws here), and the sample index changes every
 * 8 draws (reversed once per sample). batch: N sobol_batch_draw of 8 lanes (pt's seven dimensions
 * of a sample, drawn together); seed: N sobol_batch_seed of 8 lanes (a pixel's seeds). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/rng.h"
#include "core/sobol.h"

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: sobol_instr 2d|1d|random2d|batch|seed N\n");
        return 2;
    }
    const char *mode = argv[1];
    const unsigned long n = strtoul(argv[2], NULL, 10);
    float sum = 0.0f;
    if (strcmp(mode, "2d") == 0 || strcmp(mode, "1d") == 0) {
        const int two = mode[0] == '2';
        /* A pixel's seeds for 8 dimensions, derived once per pixel as the path tracer does (a
         * pixel draws many samples); the draws then cycle through them. */
        struct sobol_seeds seeds[8];
        uint32_t index_reversed = 0;
        for (unsigned long i = 0; i < n; i++) {
            if ((i & 1023) == 0)
                for (uint32_t d = 0; d < 8; d++) seeds[d] = sobol_dimension_seeds(rng_mix64(i), d);
            if ((i & 7) == 0) index_reversed = sobol_reverse_bits((uint32_t)(i >> 3));
            if (two) {
                float u0, u1;
                sobol_2d(index_reversed, &seeds[i & 7], &u0, &u1);
                sum += u0 + u1;
            } else {
                sum += sobol_1d(index_reversed, &seeds[i & 7]);
            }
        }
    } else if (strcmp(mode, "batch") == 0 || strcmp(mode, "seed") == 0) {
        struct sobol_batch b;
        float u0[8], u1[8];
        sobol_batch_seed(&b, rng_mix64(1), 8);
        for (unsigned long i = 0; i < n; i++) {
            if (mode[0] == 'b') {
                sobol_batch_draw(&b, sobol_reverse_bits((uint32_t)i), 8, u0, u1);
                sum += u0[i & 7] + u1[i & 7];
            } else {
                sobol_batch_seed(&b, i, 8);
                sum += (float)(b.scramble1[i & 7] >> 8);
            }
        }
    } else if (strcmp(mode, "random2d") == 0) {
        struct rng r = rng_make(0, 0, 0, 0);
        for (unsigned long i = 0; i < n; i++) {
            float u0 = rng_next_float(&r), u1 = rng_next_float(&r);
            sum += u0 + u1;
        }
    } else {
        fprintf(stderr, "sobol_instr: unknown mode '%s'\n", mode);
        return 2;
    }
    printf("%g\n", (double)sum);
    return 0;
}
