/* bench_blend — the run-time blend engine (runtime/blend.h) on an ESTATE-scale synthetic
 * case (UberBake Table 1): 2,637,824 lightmap texels (SH L1 × RGB, stride 12), 50,805 LLG
 * and 229,725 GLG probes (SH L2 × RGB, stride 27), 132 dynamic light sets. Base arrays are
 * float; records are half (the .ubk storage), with a float-record comparison.
 *
 * Records: each set belongs to an area (one great hall with 16 sets, 27 smaller areas);
 * its region is a stretch of each receiver array around the area's place (receiver arrays
 * are spatially ordered: atlas charts, grid order) cut into chart-sized chunks, ~80% of
 * them kept (walls); at most 16 sets per receiver. Values are SH of a warm/cool point
 * light: positive DC falling off from the set's centre, L1/L2 terms a fraction of it.
 *
 * Figures, single thread, each time the best of several runs (the machine is shared):
 * (a) one set toggled (all three representations; median / p90 / max over every set
 * toggled off and on), with every other set on, and with every other set off (the
 * base-copy fast path); (b) every group forced (update_all), half and float records, and
 * texels in streaming mode; (c) bytes moved per update (base rows + record rows + tables
 * read, output rows written; not counting write-allocate reads) and GB/s vs memcpy GB/s
 * of the same traffic, alternating with the blend runs; (d) run-time memory without and
 * with the sets. Prints; asserts nothing. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "runtime/blend.h"
#include "runtime/half.h"
#include "bench/bench_util.h"

#define NSETS 132
#define MAX_OVERLAP 16
#define NREP 3

static const char *rep_name[NREP] = {"lightmap texels", "LLG probes", "GLG probes"};
static const uint32_t rep_count[NREP] = {2637824u, 50805u, 229725u};
static const uint32_t rep_stride[NREP] = {12, 27, 27};

static uint64_t rng_state = 0x9E3779B97F4A7C15ull;
static double rnd(void)
{
  rng_state ^= rng_state << 13;
  rng_state ^= rng_state >> 7;
  rng_state ^= rng_state << 17;
  return (double)(rng_state >> 11) * (1.0 / 9007199254740992.0);
}
static double rnd_normal(void)
{
  double u = rnd() + 1e-12, v = rnd();
  return sqrt(-2.0 * log(u)) * cos(6.283185307179586 * v);
}

static int cmp_double(const void *a, const void *b)
{
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}
static double median(double *v, int n)
{
  qsort(v, (size_t)n, sizeof *v, cmp_double);
  return n ? v[n / 2] : 0.0;
}

typedef struct dls {
  double centre, radius; /* level coordinate in [0, 1) */
  float tint[3];
} dls;

typedef struct rep {
  uint32_t n, stride;
  float *base, *out;
  uint32_t *idx[NSETS];
  uint16_t *vh[NSETS];
  float *vf[NSETS];
  uint32_t cnt[NSETS];
  ub_blend_record rh[NSETS], rf[NSETS];
  uint32_t *hist; /* receivers per overlap count, 0..MAX_OVERLAP */
  ub_blend *bh, *bf;
} rep;

static void make_sets(dls *s)
{
  /* Areas: 0 is a great hall (16 sets), 1..27 smaller areas (1–8 sets). */
  double area_c[28], area_r[28];
  for (int a = 0; a < 28; a++) {
    area_c[a] = 0.02 + 0.96 * rnd();
    area_r[a] = 0.004 * exp(0.5 * rnd_normal());
  }
  area_r[0] = 0.012;
  for (int i = 0; i < NSETS; i++) {
    int a = i < 16 ? 0 : 1 + (int)(27.0 * rnd() * rnd()); /* skewed: some crowded areas */
    double r = area_r[a] * exp(0.6 * rnd_normal());
    if (i < 16)
      r = area_r[0] * (0.9 + 0.3 * rnd());
    s[i].centre = area_c[a] + area_r[a] * 0.8 * rnd_normal() * (i < 16 ? 0.1 : 1.0);
    s[i].radius = r;
    double warm = rnd();
    s[i].tint[0] = (float)(0.8 + 0.4 * warm);
    s[i].tint[1] = 0.9f;
    s[i].tint[2] = (float)(1.2 - 0.4 * warm);
  }
}

static void make_rep(rep *p, int ri, const dls *s)
{
  const uint32_t n = rep_count[ri], S = rep_stride[ri];
  memset(p, 0, sizeof *p);
  p->n = n;
  p->stride = S;
  p->base = malloc(sizeof(float) * (size_t)n * S);
  p->out = malloc(sizeof(float) * (size_t)n * S);
  for (size_t i = 0; i < (size_t)n * S; i++)
    p->base[i] = (i % (S / 3 * 3) < 3) ? (float)(0.05 + 0.2 * rnd()) : (float)(0.02 * rnd() - 0.01);
  uint8_t *ov = calloc(n, 1), *cov = malloc(n);
  /* Chart-sized chunks: ~64–2048 texels in the atlas, proportionally fewer probes. */
  double chunk_scale = (double)n / rep_count[0];
  for (int e = 0; e < NSETS; e++) {
    memset(cov, 0, n);
    double lo = (s[e].centre - s[e].radius) * n, hi = (s[e].centre + s[e].radius) * n;
    uint32_t a = lo < 0 ? 0 : (uint32_t)lo, b = hi > n ? n : (uint32_t)hi;
    uint32_t cnt = 0;
    for (uint32_t r = a; r < b;) {
      uint32_t len = (uint32_t)(64.0 * pow(32.0, rnd()) * chunk_scale) + 2;
      int keep = rnd() < 0.8;
      for (uint32_t q = r; q < r + len && q < b; q++)
        if (keep && ov[q] < MAX_OVERLAP) {
          cov[q] = 1;
          ov[q]++;
          cnt++;
        }
      r += len;
    }
    p->cnt[e] = cnt;
    p->idx[e] = malloc(sizeof(uint32_t) * (cnt + 1));
    p->vh[e] = malloc(sizeof(uint16_t) * ((size_t)cnt * S + 1));
    p->vf[e] = malloc(sizeof(float) * ((size_t)cnt * S + 1));
    uint32_t k = 0;
    double mid = s[e].centre * n, rad = s[e].radius * n + 1.0;
    for (uint32_t r = a; r < b; r++) {
      if (!cov[r])
        continue;
      p->idx[e][k] = r;
      double x = (r - mid) / rad, fall = 2.0 / (1.0 + 25.0 * x * x);
      float dir[3] = {(float)rnd_normal(), (float)rnd_normal(), (float)rnd_normal()};
      for (uint32_t j = 0; j < S; j++) {
        uint32_t coef = j / 3, c = j % 3;
        double v = fall * s[e].tint[c];
        if (coef >= 1 && coef <= 3)
          v *= 0.35 * dir[coef - 1] / 1.7;
        else if (coef > 3)
          v *= 0.08 * rnd_normal();
        uint16_t h = ub_half_from_float((float)v);
        p->vh[e][(size_t)k * S + j] = h;
        p->vf[e][(size_t)k * S + j] = ub_half_to_float(h);
      }
      k++;
    }
    p->rh[e] = (ub_blend_record){p->idx[e], p->vh[e], cnt};
    p->rf[e] = (ub_blend_record){p->idx[e], p->vf[e], cnt};
  }
  p->hist = calloc(MAX_OVERLAP + 1, sizeof(uint32_t));
  for (uint32_t r = 0; r < n; r++)
    p->hist[ov[r]]++;
  free(ov);
  free(cov);
}

static void free_rep(rep *p)
{
  for (int e = 0; e < NSETS; e++) {
    free(p->idx[e]);
    free(p->vh[e]);
    free(p->vf[e]);
  }
  free(p->base);
  free(p->out);
  free(p->hist);
  ub_blend_free(p->bh);
  ub_blend_free(p->bf);
}

static void log_stderr(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  (void)level;
  fprintf(stderr, "%s\n", msg);
}

static void set_all(rep *reps, int use_half, const dls *s, float scale)
{
  for (int ri = 0; ri < NREP; ri++)
    for (int e = 0; e < NSETS; e++) {
      float w[3] = {s[e].tint[0] * scale, s[e].tint[1] * scale, s[e].tint[2] * scale};
      ub_blend_set_weight(use_half ? reps[ri].bh : reps[ri].bf, (uint32_t)e, w);
    }
}

static double minv(const double *v, int n)
{
  double m = v[0];
  for (int i = 1; i < n; i++)
    m = v[i] < m ? v[i] : m;
  return m;
}

/* Toggles each set off then on again (or on then off), timing each update of the three
 * representations together; per set and direction the best of PASSES (the machine is
 * shared: the minimum is the least disturbed run), then median / p90 / max over sets. */
static void bench_toggle(rep *reps, const dls *s, int others_on, double *out_med_ms,
                         double *out_p90_ms, double *out_max_ms, double *out_med_bytes,
                         double *out_med_gbs)
{
  static double gbs[NSETS * 2];
  enum { PASSES = 5 };
  static double t[NSETS * 2][PASSES], best[NSETS * 2], by[NSETS * 2];
  set_all(reps, 1, s, others_on ? 1.0f : 0.0f);
  for (int ri = 0; ri < NREP; ri++)
    ub_blend_update(reps[ri].bh, NULL, NULL, reps[ri].out, NULL);
  for (int pass = 0; pass < PASSES; pass++)
    for (int e = 0; e < NSETS; e++)
      for (int phase = 0; phase < 2; phase++) {
        int on = others_on ? phase == 1 : phase == 0;
        float w[3] = {on ? s[e].tint[0] : 0.0f, on ? s[e].tint[1] : 0.0f,
                      on ? s[e].tint[2] : 0.0f};
        double t0 = ub_bench_now(), bytes = 0.0;
        for (int ri = 0; ri < NREP; ri++) {
          ub_blend_stats st;
          ub_blend_set_weight(reps[ri].bh, (uint32_t)e, w);
          ub_blend_update(reps[ri].bh, NULL, NULL, reps[ri].out, &st);
          bytes += (double)(st.bytes_read + st.bytes_written);
        }
        t[2 * e + phase][pass] = (ub_bench_now() - t0) * 1e3;
        by[2 * e + phase] = bytes;
      }
  for (int i = 0; i < NSETS * 2; i++) {
    best[i] = minv(t[i], PASSES);
    gbs[i] = by[i] / (best[i] * 1e-3) / 1e9;
  }
  *out_med_gbs = median(gbs, NSETS * 2);
  *out_med_ms = median(best, NSETS * 2);
  *out_p90_ms = best[NSETS * 2 * 9 / 10];
  *out_max_ms = best[NSETS * 2 - 1];
  *out_med_bytes = median(by, NSETS * 2);
}

/* Every group of the three representations, alternating with a memcpy of the same
 * traffic (read + write bytes) so both see the same machine; best of `runs` each. */
static void bench_all(rep *reps, int use_half, int runs, double *out_ms, double *out_bytes,
                      double *out_ms_rep, double *out_memcpy_gbs)
{
  double t[64], tr[NREP][64], tm[64];
  double bytes = 0.0;
  ub_blend_stats st;
  for (int ri = 0; ri < NREP; ri++) {
    ub_blend_update_all(use_half ? reps[ri].bh : reps[ri].bf, NULL, NULL, reps[ri].out, &st);
    bytes += (double)(st.bytes_read + st.bytes_written);
  }
  size_t n = (size_t)(bytes / 2.0);
  char *a = malloc(n), *b = malloc(n);
  memset(a, 1, n);
  memset(b, 2, n);
  for (int i = 0; i < runs; i++) {
    double t0 = ub_bench_now();
    for (int ri = 0; ri < NREP; ri++) {
      double t1 = ub_bench_now();
      ub_blend_update_all(use_half ? reps[ri].bh : reps[ri].bf, NULL, NULL, reps[ri].out, &st);
      tr[ri][i] = (ub_bench_now() - t1) * 1e3;
    }
    t[i] = (ub_bench_now() - t0) * 1e3;
    t0 = ub_bench_now();
    memcpy(i & 1 ? a : b, i & 1 ? b : a, n);
    tm[i] = ub_bench_now() - t0;
  }
  free(a);
  free(b);
  *out_ms = minv(t, runs);
  *out_bytes = bytes;
  for (int ri = 0; ri < NREP; ri++)
    out_ms_rep[ri] = minv(tr[ri], runs);
  *out_memcpy_gbs = 2.0 * (double)n / minv(tm, runs) / 1e9;
}

/* Streaming consumer: touches every row (as an AHD re-encode would read it). */
static void consume(void *user, uint32_t first, uint32_t count, const float *rows)
{
  (void)first;
  float acc = 0.0f;
  for (uint32_t i = 0; i < count; i++)
    acc += rows[12 * i];
  *(float *)user += acc;
}

static double bench_stream(rep *p, int runs, double *out_bytes)
{
  double t[32];
  float sink = 0.0f;
  ub_blend_stats st;
  for (int i = 0; i < runs; i++) {
    double t0 = ub_bench_now();
    ub_blend_update_all(p->bh, consume, &sink, NULL, &st);
    t[i] = (ub_bench_now() - t0) * 1e3;
  }
  *out_bytes = (double)(st.bytes_read + st.bytes_written);
  return minv(t, runs) + 0.0 * sink;
}

static double load_average(void)
{
  double l = -1.0;
  FILE *f = fopen("/proc/loadavg", "r");
  if (f) {
    if (fscanf(f, "%lf", &l) != 1)
      l = -1.0;
    fclose(f);
  }
  return l;
}

int main(void)
{
  double t0 = ub_bench_now();
  dls sets[NSETS];
  make_sets(sets);
  rep reps[NREP];
  ub_log log = {log_stderr, NULL};
  for (int ri = 0; ri < NREP; ri++) {
    make_rep(&reps[ri], ri, sets);
    /* Half records, the engine keeps the touched receivers' base rows (the run-time's
     * configuration); float records borrow the caller's base. */
    ub_blend_desc d = {rep_name[ri], reps[ri].n, reps[ri].stride, reps[ri].base,
                       UB_BLEND_FLOAT16, NSETS, reps[ri].rh, UB_BLEND_OWN_BASE, 0};
    double tc = ub_bench_now();
    if (ub_blend_create(&d, &log, reps[ri].out, &reps[ri].bh) != UB_OK)
      return 1;
    tc = ub_bench_now() - tc;
    d.storage = UB_BLEND_FLOAT32;
    d.elements = reps[ri].rf;
    d.flags = 0;
    if (ub_blend_create(&d, &log, NULL, &reps[ri].bf) != UB_OK)
      return 1;
    ub_blend_info in;
    ub_blend_get_info(reps[ri].bh, &in);
    printf("%-15s %8u receivers, stride %u: %u touched (%.1f%%), %llu memberships (%.2f per "
           "receiver), max overlap %u, %u groups (%u as runs, %llu runs), create %.0f ms\n",
           rep_name[ri], in.receiver_count, in.stride, in.touched_receivers,
           100.0 * in.touched_receivers / in.receiver_count,
           (unsigned long long)in.memberships, (double)in.memberships / in.receiver_count,
           in.max_overlap, in.group_count, in.run_groups, (unsigned long long)in.runs,
           tc * 1e3);
    uint32_t sz[NSETS];
    for (int e = 0; e < NSETS; e++)
      sz[e] = reps[ri].cnt[e];
    for (int e = 1; e < NSETS; e++) /* insertion sort, 132 entries */
      for (int q = e; q > 0 && sz[q - 1] > sz[q]; q--) {
        uint32_t x = sz[q];
        sz[q] = sz[q - 1];
        sz[q - 1] = x;
      }
    printf("  receivers per set: min %u, median %u, p90 %u, max %u\n", sz[0], sz[NSETS / 2],
           sz[NSETS * 9 / 10], sz[NSETS - 1]);
    printf("  overlap histogram (%% of receivers):");
    for (int k = 0; k <= MAX_OVERLAP; k++)
      printf(" %d:%.2f", k, 100.0 * reps[ri].hist[k] / reps[ri].n);
    printf("\n");
  }

  printf("single thread; times are the best of several runs (load average %.1f on this "
         "machine when the timing started)\n", load_average());
  /* (a) one set toggled. */
  double med, p90, mx, mb, tg;
  bench_toggle(reps, sets, 1, &med, &p90, &mx, &mb, &tg);
  printf("(a) one set toggled, others on : median %.3f ms, p90 %.3f ms, max %.3f ms; median "
         "%.2f MB moved, %.2f GB/s (target <= 0.1 ms)\n", med, p90, mx, mb / 1e6, tg);
  bench_toggle(reps, sets, 0, &med, &p90, &mx, &mb, &tg);
  printf("    one set toggled, others off: median %.3f ms, p90 %.3f ms, max %.3f ms; median "
         "%.2f MB moved, %.2f GB/s\n", med, p90, mx, mb / 1e6, tg);

  /* (b), (c) every set forced every update. */
  double ms_rep[NREP], mgbs;
  set_all(reps, 1, sets, 1.0f);
  bench_all(reps, 1, 15, &med, &mb, ms_rep, &mgbs);
  double gbs = mb / (med * 1e-3) / 1e9;
  printf("(b) all sets forced, half records : %.2f ms (texels %.2f, LLG %.2f, GLG %.2f) "
         "(paper: 1.47 ms on a PS4 GPU)\n", med, ms_rep[0], ms_rep[1], ms_rep[2]);
  printf("(c) %.1f MB moved per update: %.2f GB/s; memcpy of the same traffic %.2f GB/s; "
         "ratio %.0f%% (target >= 50%%)\n", mb / 1e6, gbs, mgbs, 100.0 * gbs / mgbs);
  double sb, sms = bench_stream(&reps[0], 9, &sb);
  printf("    texels streamed to a callback (no output array): %.2f ms, %.1f MB moved, "
         "%.2f GB/s\n", sms, sb / 1e6, sb / (sms * 1e-3) / 1e9);
  set_all(reps, 0, sets, 1.0f);
  bench_all(reps, 0, 9, &med, &mb, ms_rep, &mgbs);
  gbs = mb / (med * 1e-3) / 1e9;
  printf("    all sets forced, float records: %.2f ms, %.1f MB moved, %.2f GB/s; memcpy "
         "%.2f GB/s; ratio %.0f%%\n", med, mb / 1e6, gbs, mgbs, 100.0 * gbs / mgbs);

  /* (d) memory. */
  double base_b = 0, rec_h = 0, rec_f = 0, eng_h = 0, eng_f = 0, out_b = 0, base_half = 0;
  double touched_b = 0, rt_state = 0;
  for (int ri = 0; ri < NREP; ri++) {
    ub_blend_info ih, iff;
    ub_blend_get_info(reps[ri].bh, &ih);
    ub_blend_get_info(reps[ri].bf, &iff);
    base_b += 4.0 * reps[ri].n * reps[ri].stride;
    base_half += 2.0 * reps[ri].n * reps[ri].stride;
    out_b += 4.0 * reps[ri].n * reps[ri].stride;
    /* The run-time's lightmap state: none for the touched texels (the blend computes it:
     * ub_blend_row), the file's halves for the others (runtime.c lm_static); probes:
     * float for all. */
    rt_state += ri == 0 ? 2.0 * (reps[ri].n - ih.touched_receivers) * reps[ri].stride
                        : 4.0 * reps[ri].n * reps[ri].stride;
    touched_b += 4.0 * ih.touched_receivers * reps[ri].stride;
    rec_h += (double)ih.record_bytes;
    rec_f += (double)iff.record_bytes;
    eng_h += (double)ih.engine_bytes - 4.0 * ih.touched_receivers * reps[ri].stride;
    eng_f += (double)iff.engine_bytes;
  }
  const double MB = 1048576.0;
  printf("(d) memory without sets: base %.1f MB (float SH; %.1f MB if half) (paper: 28 MB, "
         "8-byte AHD texels)\n", base_b / MB, base_half / MB);
  printf("    with all 132 sets, base borrowed (float records' engine): base %.1f + records "
         "%.1f (half; %.1f float) + tables %.1f = %.1f MB, plus the blended output arrays "
         "%.1f MB = %.1f MB in all\n", base_b / MB, rec_h / MB, rec_f / MB, eng_f / MB,
         (base_b + rec_h + eng_f) / MB, out_b / MB, (base_b + rec_h + eng_f + out_b) / MB);
  printf("    with all 132 sets, UB_BLEND_OWN_BASE (half records' engine): output arrays %.1f "
         "(= base where no set touches) + touched base rows %.1f + records %.1f + tables "
         "%.1f = %.1f MB in all (paper: 77 MB, +49 MB for the sets; target <= 77 MB)\n",
         out_b / MB, touched_b / MB, rec_h / MB, eng_h / MB,
         (out_b + touched_b + rec_h + eng_h) / MB);
  /* What ub_runtime holds besides the blends (runtime/runtime.c, ub_runtime_memory_usage):
   * per texel the AHD encoding (9 floats), the file's normal (3 floats) and coverage byte
   * (every texel here is covered: the run-time's per-texel arrays hold covered texels
   * only); per GLG probe the windowed SH the queries read. */
  double rt_texel = (double)rep_count[0] * (9 * 4 + 3 * 4 + 1);
  double rt_glg_win = 4.0 * rep_count[2] * rep_stride[2];
  printf("    the run-time also holds, outside the blends: AHD texels + stored normals + "
         "coverage %.1f MB, windowed GLG SH %.1f MB: %.1f MB in all with the sets "
         "(before geometry, tets and the GLG's acceleration data)\n", rt_texel / MB,
         rt_glg_win / MB, (out_b + touched_b + rec_h + eng_h + rt_texel + rt_glg_win) / MB);
  printf("    as ub_runtime holds it (lightmap state float only where a set touches, the file's "
         "halves elsewhere): current state %.1f MB instead of %.1f: %.1f MB in all\n",
         rt_state / MB, out_b / MB,
         (rt_state + touched_b + rec_h + eng_h + rt_texel + rt_glg_win) / MB);
  for (int ri = 0; ri < NREP; ri++)
    free_rep(&reps[ri]);
  printf("bench_blend: %.1f s\n", ub_bench_now() - t0);
  return 0;
}
