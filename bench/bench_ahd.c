/* bench/bench_ahd.c — the AHD re-encode the run-time runs on every touched texel of an
 * update (ubake/ahd.h), alone: nanoseconds per texel for the scalar encoder, the
 * eight-at-a-time encoder on contiguous texels (rows, normals and AHD in order, as the
 * run-time's ranked texels) and on eight scattered rows; in cache (4096 texels, encoded
 * again and again) and streaming (1.6 M texels, the ESTATE-scale level's touched texels:
 * the rows, normals and AHD from and to memory), the latter against memcpy of the same bytes
 * in the same run; and the run-time's form, eight contiguous texels packed (ub_ahd_packed,
 * 16 B a texel), eight at a time and sixteen (two groups interleaved,
 * ub_ahd_encode_iz_packed_n). Prints figures, asserts nothing.
 *
 * usage: bench_ahd [--texels N] [--rounds R] */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench/bench_util.h"
#include "ubake/ahd.h"

typedef enum { MODE_SCALAR, MODE_IZ8, MODE_ROWS, MODE_PACKED, MODE_PACKED_N, MODE_COUNT } mode;

static ub_ahd_packed *g_packed; /* MODE_PACKED's output, as many texels as out */

static void encode_all(mode md, const float *rows, const float *nrm, ub_ahd *out, size_t n)
{
  size_t i = 0;
  if (md == MODE_SCALAR) {
    for (; i < n; i++)
      ub_ahd_encode_iz(rows + 12 * i, nrm + 3 * i, out + i);
    return;
  }
  if (md == MODE_PACKED_N) { /* the run-time's call: 16 at a time, two groups side by side */
    ub_ahd_encode_iz_packed_n(rows, nrm, 1.0f, g_packed, n);
    return;
  }
  for (; i + 8 <= n; i += 8) {
    if (md == MODE_IZ8) {
      ub_ahd_encode_iz8(rows + 12 * i, nrm + 3 * i, out + i);
    } else if (md == MODE_PACKED) {
      ub_ahd_encode_iz8_packed(rows + 12 * i, nrm + 3 * i, 1.0f, g_packed + i);
    } else {
      /* eight rows in a scattered order (a list group's receivers) */
      const float *rp[8];
      ub_ahd *op[8];
      for (int j = 0; j < 8; j++) {
        rp[j] = rows + 12 * (i + (size_t)((j * 5) & 7));
        op[j] = out + i + (size_t)((j * 5) & 7);
      }
      ub_ahd_encode_iz8_rows(rp, nrm + 3 * i, op);
    }
  }
  for (; i < n; i++)
    ub_ahd_encode_iz(rows + 12 * i, nrm + 3 * i, out + i);
}

/* Best seconds per texel over `rounds` passes over the n texels. */
static double time_mode(mode md, const float *rows, const float *nrm, ub_ahd *out, size_t n,
                        int rounds)
{
  double best = 1e30;
  for (int r = 0; r < rounds; r++) {
    double t0 = ub_bench_now();
    encode_all(md, rows, nrm, out, n);
    double t = ub_bench_now() - t0;
    best = t < best ? t : best;
  }
  return best / (double)n;
}

int main(int argc, char **argv)
{
  size_t big = 1600000;
  int rounds = 7;
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--texels") && i + 1 < argc)
      big = (size_t)strtoull(argv[++i], NULL, 10);
    else if (!strcmp(argv[i], "--rounds") && i + 1 < argc)
      rounds = atoi(argv[++i]);
    else {
      fprintf(stderr, "usage: bench_ahd [--texels N] [--rounds R]\n"
                      "Times the AHD re-encode (scalar, eight contiguous, eight scattered), in\n"
                      "cache and streaming N texels (default 1600000) against memcpy.\n");
      return strcmp(argv[i], "--help") ? 2 : 0;
    }
  }
  if (big < 4096)
    big = 4096;
  if (rounds < 1)
    rounds = 1;
  float *rows = malloc(big * 12 * sizeof(float)), *nrm = malloc(big * 3 * sizeof(float));
  ub_ahd *out = malloc(big * sizeof(ub_ahd));
  g_packed = malloc(big * sizeof *g_packed);
  size_t cbytes = big * (12 * sizeof(float) + 3 * sizeof(float) + sizeof(ub_ahd));
  char *ca = malloc(cbytes), *cb = malloc(cbytes);
  if (!rows || !nrm || !out || !g_packed || !ca || !cb) {
    fprintf(stderr, "bench_ahd: out of memory\n");
    return 1;
  }
  ub_bench_make_texels(big, rows, nrm);
  memset(out, 0, big * sizeof(ub_ahd));
  memset(g_packed, 0, big * sizeof *g_packed);
  memset(ca, 1, cbytes);
  memset(cb, 2, cbytes);
  printf("bench_ahd: load average %.1f\n", ub_bench_load_average());
  const char *names[MODE_COUNT] = {"scalar (ub_ahd_encode_iz)",
                                   "8 contiguous (ub_ahd_encode_iz8)",
                                   "8 scattered (ub_ahd_encode_iz8_rows)",
                                   "8 contiguous packed (ub_ahd_encode_iz8_packed)",
                                   "16 contiguous packed (ub_ahd_encode_iz_packed_n)"};
  /* bytes a texel moves: rows 48 + normal 12 read, AHD written (36 B, packed 16 B) */
  const double tbytes[MODE_COUNT] = {96.0, 96.0, 96.0, 76.0, 76.0};
  const size_t small = 4096;
  double tsmall[MODE_COUNT], tbig[MODE_COUNT];
  for (int m = 0; m < MODE_COUNT; m++)
    tsmall[m] = time_mode((mode)m, rows, nrm, out, small, rounds * 50);
  double tcpy = 1e30;
  for (int m = 0; m < MODE_COUNT; m++) {
    tbig[m] = 1e30;
    for (int r = 0; r < rounds; r++) { /* alternating with memcpy of the same bytes */
      double t = time_mode((mode)m, rows, nrm, out, big, 1);
      tbig[m] = t < tbig[m] ? t : tbig[m];
      double t0 = ub_bench_now();
      memcpy(r & 1 ? ca : cb, r & 1 ? cb : ca, cbytes / 2);
      double tc = ub_bench_now() - t0;
      tcpy = tc < tcpy ? tc : tcpy;
    }
  }
  /* memcpy moved cbytes/2 read + cbytes/2 written = the encode's cbytes */
  double cgbs = (double)cbytes / tcpy / 1e9;
  printf("  in cache, %zu texels: ", small);
  for (int m = 0; m < MODE_COUNT; m++)
    printf("%s%s %.2f ns/texel", m ? "; " : "", names[m], tsmall[m] * 1e9);
  printf("\n  streaming %zu texels (%.0f MB: rows 48 B, normal 12 B read, AHD 36 B written per "
         "texel, 16 B packed): ",
         big, (double)cbytes / 1e6);
  for (int m = 0; m < MODE_COUNT; m++)
    printf("%s%s %.2f ns/texel (%.2f GB/s)", m ? "; " : "", names[m], tbig[m] * 1e9,
           tbytes[m] / tbig[m] / 1e9);
  printf("\n  memcpy of the same bytes %.2f GB/s; 8 contiguous at %.0f%% of it, packed at "
         "%.0f%%, 16 packed at %.0f%%\n", cgbs, 100.0 * (96.0 / tbig[MODE_IZ8] / 1e9) / cgbs,
         100.0 * (76.0 / tbig[MODE_PACKED] / 1e9) / cgbs,
         100.0 * (76.0 / tbig[MODE_PACKED_N] / 1e9) / cgbs);
  free(rows);
  free(nrm);
  free(out);
  free(g_packed);
  free(ca);
  free(cb);
  return 0;
}
