/* The ESTATE-scale level's small variant (build/levels/estate_small.gltf, made by
 * ubake-genlevel estate with the parameters in CMakeLists.txt) bakes at draft, and:
 * - the .ubk holds one record per set named in the glTF;
 * - some covered texels are in >= 8 sets' records (the hall's sets overlap), computed
 *   from the records themselves;
 * - records are sparse: each set touches a minority of the level's texels and probes;
 * - the run-time blend, after many toggles and tints of every set, returns bit for bit to
 *   the all-on and the all-off state (texels decoded from AHD, GLG probe SH), and toggling
 *   one set updates only about its own receivers. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <pthread.h>
#if defined(__SSE2__)
#include <xmmintrin.h>
#endif

#include "test_util.h"
#include "test_rt_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/glg.h"
#include "ubake/runtime.h"

#define MIN_MAX_OVERLAP 8   /* the level's hall has 8 sets */
#define MAX_SET_SHARE 0.40  /* of the level's pixels (or probes) one set may touch */
#define MAX_MEAN_SHARE 0.30 /* mean over sets */

/* Distinct values of "ubake_dls" in a glTF file (the generator writes `"ubake_dls": "NAME"`). */
static int gltf_set_count(const char *path)
{
  FILE *f = fopen(path, "rb");
  if (!f)
    return -1;
  fseek(f, 0, SEEK_END);
  long n = ftell(f);
  fseek(f, 0, SEEK_SET);
  char *s = malloc((size_t)n + 1);
  if (!s || fread(s, 1, (size_t)n, f) != (size_t)n) {
    fclose(f);
    free(s);
    return -1;
  }
  fclose(f);
  s[n] = 0;
  char names[256][64];
  int count = 0;
  for (const char *p = strstr(s, "\"ubake_dls\": \""); p; p = strstr(p + 1, "\"ubake_dls\": \"")) {
    const char *a = p + strlen("\"ubake_dls\": \""), *b = strchr(a, '"');
    if (!b || b - a >= 64)
      break;
    char nm[64];
    memcpy(nm, a, (size_t)(b - a));
    nm[b - a] = 0;
    int seen = 0;
    for (int i = 0; i < count && !seen; i++)
      seen = !strcmp(names[i], nm);
    if (!seen && count < 256)
      memcpy(names[count++], nm, sizeof nm);
  }
  free(s);
  return count;
}

/* Snapshot of the run-time state: irradiance along the normal of every covered texel (RGB)
 * and every GLG probe's raw SH. */
typedef struct snap {
  float *tex, *glg;
  size_t ntex, nglg;
} snap;

static void take(const ub_runtime *rt, snap *s)
{
  const ub_bakefile *f = ub_runtime_bakefile(rt);
  size_t n = 0;
  for (uint32_t a = 0; a < f->atlas_count; a++)
    for (size_t px = 0; px < (size_t)f->atlases[a].width * f->atlases[a].height; px++)
      n += f->atlases[a].coverage[px] == 1;
  s->ntex = n;
  s->tex = malloc((3 * n + 1) * sizeof *s->tex);
  n = 0;
  for (uint32_t a = 0; a < f->atlas_count; a++)
    for (uint32_t y = 0; y < f->atlases[a].height; y++)
      for (uint32_t x = 0; x < f->atlases[a].width; x++) {
        size_t px = (size_t)y * f->atlases[a].width + x;
        if (f->atlases[a].coverage[px] != 1)
          continue;
        float nn[3];
        ASSERT_OK(ub_runtime_texel_normal(rt, a, x, y, nn));
        ASSERT_OK(ub_runtime_texel_irradiance(rt, a, x, y, nn, s->tex + 3 * n));
        n++;
      }
  s->nglg = (size_t)f->glg_probe_count * 27;
  s->glg = malloc((s->nglg + 1) * sizeof *s->glg);
  if (ub_runtime_glg_probe_sh(rt, 0, s->glg) != UB_OK)
    memset(s->glg, 0, s->nglg * sizeof *s->glg);
}

/* Number of floats that differ (bitwise). */
static size_t diff(const snap *a, const snap *b)
{
  size_t d = 0;
  for (size_t i = 0; i < 3 * a->ntex && i < 3 * b->ntex; i++)
    d += memcmp(&a->tex[i], &b->tex[i], sizeof(float)) != 0;
  for (size_t i = 0; i < a->nglg && i < b->nglg; i++)
    d += memcmp(&a->glg[i], &b->glg[i], sizeof(float)) != 0;
  return d;
}

static void set_all(ub_runtime *rt, float w)
{
  const float rgb[3] = {w, w, w};
  for (uint32_t d = 0; d < ub_runtime_dls_count(rt); d++)
    ASSERT_OK(ub_runtime_set_dls(rt, d, rgb));
  ASSERT_OK(ub_runtime_update(rt, NULL));
}

static void check_records(const ub_bakefile *bf)
{
  size_t pixels = ub_bakefile_atlas_pixels(bf), covered = 0;
  uint8_t *cov = calloc(pixels, 1);
  uint16_t *over = calloc(pixels, sizeof *over);
  size_t off = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    size_t n = (size_t)bf->atlases[a].width * bf->atlases[a].height;
    for (size_t px = 0; px < n; px++)
      covered += (cov[off + px] = bf->atlases[a].coverage[px] == 1);
    off += n;
  }
  double share_sum = 0.0, share_max = 0.0, probe_share_max = 0.0;
  for (uint32_t d = 0; d < bf->dls_count; d++) {
    const ub_bakefile_record *r = &bf->dls[d];
    for (uint32_t i = 0; i < r->texel_count; i++)
      over[r->texel_index[i]]++;
    double share = (double)r->texel_count / (double)pixels;
    double pshare = bf->glg_probe_count ? (double)r->probe_count / bf->glg_probe_count : 0.0;
    share_sum += share;
    share_max = share > share_max ? share : share_max;
    probe_share_max = pshare > probe_share_max ? pshare : probe_share_max;
    ASSERT_TRUE(r->texel_count > 0); /* every set lights something */
  }
  uint32_t hist[33] = {0}, max_over = 0;
  for (size_t px = 0; px < pixels; px++)
    if (cov[px]) {
      hist[over[px] > 32 ? 32 : over[px]]++;
      max_over = over[px] > max_over ? over[px] : max_over;
    }
  printf("records: %u sets over %zu pixels (%zu covered); share of pixels per set: mean %.1f%%, "
         "max %.1f%%; GLG probes per set: max %.1f%% of %u\n",
         bf->dls_count, pixels, covered, 100.0 * share_sum / (bf->dls_count ? bf->dls_count : 1),
         100.0 * share_max, 100.0 * probe_share_max, bf->glg_probe_count);
  printf("overlap histogram of covered texels (sets: texels):");
  for (uint32_t k = 0; k <= max_over && k <= 32; k++)
    printf(" %u:%u", k, hist[k]);
  printf("\nmax overlap %u (want >= %d)\n", max_over, MIN_MAX_OVERLAP);
  ASSERT_TRUE(max_over >= MIN_MAX_OVERLAP);
  ASSERT_TRUE(share_max < MAX_SET_SHARE);
  ASSERT_TRUE(probe_share_max < MAX_SET_SHARE);
  ASSERT_TRUE(share_sum / (bf->dls_count ? bf->dls_count : 1) < MAX_MEAN_SHARE);
  free(cov);
  free(over);
}

/* The last update's changed texels (ub_runtime_changed_texels) against the AHD before
 * (snapshot) and now: as many as the update re-encoded (reencoded), covered texels, each
 * once, each with its current packed AHD; every covered texel whose AHD differs from the
 * snapshot among them; read in two pieces the same as at once. Returns the failures;
 * *out_list (may be NULL) gets the list (caller frees), *out_n its length, *out_moved the
 * texels whose AHD differs. */
static int check_changed(const ub_runtime *rt, const ub_bakefile *bf, const ub_ahd_packed *before,
                         uint64_t reencoded, ub_runtime_texel_change **out_list, size_t *out_n,
                         uint64_t *out_moved)
{
  int bad = 0;
  const uint64_t n = ub_runtime_changed_texel_count(rt);
  bad += n != reencoded;
  ub_runtime_texel_change *l = malloc((n ? n : 1) * sizeof *l);
  ub_runtime_texel_change *l2 = malloc((n ? n : 1) * sizeof *l2);
  ASSERT_TRUE(l && l2);
  bad += ub_runtime_changed_texels(rt, 0, (size_t)n + 5, l) != n;
  size_t h = (size_t)n / 3;
  bad += ub_runtime_changed_texels(rt, 0, h, l2) != h;
  bad += ub_runtime_changed_texels(rt, h, (size_t)n, l2 + h) != n - h;
  bad += n && memcmp(l, l2, (size_t)n * sizeof *l) != 0;
  ub_ahd_packed *now = ahd_snapshot(rt, bf);
  const size_t total = atlas_pixels(bf, bf->atlas_count);
  uint64_t moved = 0;
  size_t *first = malloc((bf->atlas_count + 1) * sizeof *first);
  ASSERT_TRUE(first != NULL);
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    first[a] = atlas_pixels(bf, a);
  uint8_t *in = calloc(total ? total : 1, 1);
  ASSERT_TRUE(in != NULL);
  for (uint64_t k = 0; k < n; k++) {
    const ub_runtime_texel_change *c = &l[k];
    if (c->atlas >= bf->atlas_count || c->x >= bf->atlases[c->atlas].width ||
        c->y >= bf->atlases[c->atlas].height) {
      bad++;
      continue;
    }
    const size_t px = (size_t)c->y * bf->atlases[c->atlas].width + c->x;
    bad += bf->atlases[c->atlas].coverage[px] != 1 || in[first[c->atlas] + px]++ != 0 ||
           memcmp(&c->ahd, &now[first[c->atlas] + px], sizeof c->ahd) != 0;
  }
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    for (size_t px = 0; px < (size_t)bf->atlases[a].width * bf->atlases[a].height; px++)
      if (bf->atlases[a].coverage[px] == 1 &&
          memcmp(&now[first[a] + px], &before[first[a] + px], sizeof *now) != 0) {
        moved++;
        bad += !in[first[a] + px];
      }
  free(in);
  free(first);
  free(now);
  free(l2);
  if (out_list)
    *out_list = l;
  else
    free(l);
  *out_n = (size_t)n;
  *out_moved = moved;
  return bad;
}

static void check_blend(const char *ubk, const ub_bakefile *bf, unsigned load_flags)
{
  ub_runtime *rt = NULL;
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, load_flags, &rt));
  if (!rt)
    return;
  uint32_t nd = ub_runtime_dls_count(rt);
  ASSERT_TRUE(nd == bf->dls_count);
  snap on, off, s;
  set_all(rt, 1.0f);
  take(rt, &on);
  set_all(rt, 0.0f);
  take(rt, &off);
  size_t on_off = diff(&on, &off);
  printf("all on vs all off: %zu of %zu values differ\n", on_off, 3 * on.ntex + on.nglg);
  ASSERT_TRUE(on_off > 0);
  /* Toggle one set at a time from all-off: the update touches about its own record. */
  int32_t hall = ub_runtime_dls_find(rt, "hall_00");
  ASSERT_TRUE(hall >= 0);
  if (hall >= 0) {
    const float one[3] = {1, 1, 1};
    ub_runtime_update_stats st;
    ub_ahd_packed *before = ahd_snapshot(rt, bf);
    /* the LLG models' grids before (the run-time's bake file holds the current state) */
    const ub_bakefile *rbf = ub_runtime_bakefile(rt);
    size_t nlp = (size_t)ub_bakefile_llg_probes(rbf) * 27;
    float *llg0 = malloc((nlp ? nlp : 1) * sizeof *llg0);
    ASSERT_TRUE(llg0 != NULL);
    for (uint32_t m = 0, o = 0; m < rbf->llg_count; m++) {
      size_t c = (size_t)rbf->llgs[m].dims[0] * rbf->llgs[m].dims[1] * rbf->llgs[m].dims[2] * 27;
      memcpy(llg0 + o, rbf->llgs[m].probe_sh, c * sizeof *llg0);
      o += (uint32_t)c;
    }
    ASSERT_OK(ub_runtime_set_dls(rt, (uint32_t)hall, one));
    ASSERT_OK(ub_runtime_update(rt, &st));
    /* LLG models to re-upload: every model whose grid moved is flagged, not every model */
    uint32_t moved_m = 0, flagged = 0, unflagged_moved = 0;
    for (uint32_t m = 0, o = 0; m < rbf->llg_count; m++) {
      size_t c = (size_t)rbf->llgs[m].dims[0] * rbf->llgs[m].dims[1] * rbf->llgs[m].dims[2] * 27;
      int mv = memcmp(llg0 + o, rbf->llgs[m].probe_sh, c * sizeof *llg0) != 0;
      int fl = ub_runtime_llg_changed(rt, m);
      moved_m += mv;
      flagged += fl;
      unflagged_moved += mv && !fl;
      o += (uint32_t)c;
    }
    printf("toggle hall_00 on: %u of %u LLG models flagged changed, %u moved, %u moved "
           "unflagged (want 0)\n", flagged, rbf->llg_count, moved_m, unflagged_moved);
    ASSERT_TRUE(moved_m > 0 && unflagged_moved == 0 && flagged < rbf->llg_count);
    ASSERT_TRUE(!ub_runtime_llg_changed(rt, rbf->llg_count));
    free(llg0);
    /* what a game re-uploads: the texels the toggle re-encoded, among them every texel
     * whose packed AHD moved */
    size_t nch = 0;
    uint64_t moved = 0;
    int bad_ch = check_changed(rt, bf, before, st.texels_reencoded, NULL, &nch, &moved);
    printf("toggle hall_00 on: %zu changed texels listed (%llu with a new AHD), %d failures\n",
           nch, (unsigned long long)moved, bad_ch);
    ASSERT_TRUE(bad_ch == 0 && moved > 0 && nch >= moved);
    free(before);
    const ub_bakefile_record *r = &bf->dls[hall];
    printf("toggle hall_00 on: %llu texels written (record %u), %llu GLG probes (record %u), "
           "%llu LLG probes (record %u)\n",
           (unsigned long long)st.texels_written, r->texel_count,
           (unsigned long long)st.probes_written, r->probe_count,
           (unsigned long long)st.llg_probes_written, r->llg_probe_count);
    ASSERT_TRUE(st.texels_written > 0 && st.texels_written <= r->texel_count);
    ASSERT_TRUE(st.probes_written <= r->probe_count);
    ASSERT_TRUE(st.llg_probes_written <= r->llg_probe_count);
    take(rt, &s);
    ASSERT_TRUE(diff(&s, &off) > 0);
    free(s.tex);
    free(s.glg);
  }
  /* Many random toggles and tints, then back to all off / all on: identical bits. */
  uint32_t h = 12345u;
  for (int step = 0; step < 200; step++) {
    h = h * 1664525u + 1013904223u;
    uint32_t d = (h >> 8) % nd;
    h = h * 1664525u + 1013904223u;
    float w = (h >> 28) < 6 ? 0.0f : (float)((h >> 8) & 0xffff) / 32768.0f;
    float rgb[3] = {w, w * 0.7f, w * 1.3f};
    ASSERT_OK(ub_runtime_set_dls(rt, d, rgb));
    if (step % 3 == 0)
      ASSERT_OK(ub_runtime_update(rt, NULL));
  }
  ASSERT_OK(ub_runtime_update(rt, NULL));
  set_all(rt, 0.0f);
  take(rt, &s);
  size_t d_off = diff(&s, &off);
  free(s.tex);
  free(s.glg);
  set_all(rt, 1.0f);
  take(rt, &s);
  size_t d_on = diff(&s, &on);
  printf("after 200 random toggles: all off differs in %zu values, all on in %zu (want 0)\n",
         d_off, d_on);
  ASSERT_TRUE(d_off == 0);
  ASSERT_TRUE(d_on == 0);
  free(s.tex);
  free(s.glg);
  free(on.tex);
  free(on.glg);
  free(off.tex);
  free(off.glg);
  ub_runtime_free(rt);
}

/* UB_RUNTIME_RECORDS_8BIT against the file's halves, every set on with a tint: each
 * texel's irradiance along its normal is the same (I_z is kept: float rounding of the AHD
 * encode only), each GLG probe's raw SH is within the 8-bit bound (Σ over the sets reaching
 * it of |weight| × its row's largest non-DC |value| / 127, DC exact) plus the store's half
 * rounding of both; the error off the normal (45°) and the memory saved are printed. */
static void check_records_8bit(const char *ubk, const ub_bakefile *bf)
{
  ub_runtime *rh = NULL, *r8 = NULL;
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, 0, &rh));
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, UB_RUNTIME_RECORDS_8BIT, &r8));
  ub_runtime *rbad = NULL;
  ASSERT_TRUE(ub_runtime_load_ex(ubk, NULL, 0x80u, &rbad) == UB_ERR_INVALID_ARGUMENT &&
              rbad == NULL);
  if (!rh || !r8) {
    ub_runtime_free(rh);
    ub_runtime_free(r8);
    return;
  }
  const float tint[3] = {1.0f, 0.7f, 1.3f};
  for (uint32_t d = 0; d < ub_runtime_dls_count(rh); d++) {
    ASSERT_OK(ub_runtime_set_dls(rh, d, tint));
    ASSERT_OK(ub_runtime_set_dls(r8, d, tint));
  }
  ASSERT_OK(ub_runtime_update(rh, NULL));
  ASSERT_OK(ub_runtime_update(r8, NULL));
  /* texels: along the normal, and 45° off it */
  const ub_bakefile *f = ub_runtime_bakefile(rh);
  size_t nt = 0, bad_n = 0;
  double max_rel_n = 0.0, sum_rel_t = 0.0, max_rel_t = 0.0, emax = 0.0;
  for (int pass = 0; pass < 2; pass++)
    for (uint32_t a = 0; a < f->atlas_count; a++)
      for (uint32_t y = 0; y < f->atlases[a].height; y++)
        for (uint32_t x = 0; x < f->atlases[a].width; x++) {
          if (f->atlases[a].coverage[(size_t)y * f->atlases[a].width + x] != 1)
            continue;
          float n[3], t[3], eh[3], e8[3], th[3], t8[3];
          ASSERT_OK(ub_runtime_texel_normal(rh, a, x, y, n));
          ASSERT_OK(ub_runtime_texel_irradiance(rh, a, x, y, n, eh));
          ASSERT_OK(ub_runtime_texel_irradiance(r8, a, x, y, n, e8));
          if (pass == 0) { /* the largest irradiance: the floor of relative errors */
            for (int c = 0; c < 3; c++)
              emax = eh[c] > emax ? eh[c] : emax;
            continue;
          }
          /* a tangent: n × (the axis least along n), then 45° toward it */
          int ax = fabsf(n[0]) < fabsf(n[1]) ? (fabsf(n[0]) < fabsf(n[2]) ? 0 : 2)
                                             : (fabsf(n[1]) < fabsf(n[2]) ? 1 : 2);
          float e[3] = {ax == 0, ax == 1, ax == 2};
          t[0] = n[1] * e[2] - n[2] * e[1];
          t[1] = n[2] * e[0] - n[0] * e[2];
          t[2] = n[0] * e[1] - n[1] * e[0];
          float tl = sqrtf(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
          if (!(tl > 0.0f))
            continue; /* no normal */
          float d45[3];
          for (int c = 0; c < 3; c++)
            d45[c] = n[c] + t[c] / tl;
          ASSERT_OK(ub_runtime_texel_irradiance(rh, a, x, y, d45, th));
          ASSERT_OK(ub_runtime_texel_irradiance(r8, a, x, y, d45, t8));
          for (int c = 0; c < 3; c++) {
            /* float rounding of the encode: its terms reach ~10× I_z (C_d under grazing
             * light), a few roundings each */
            double tol = 1e-5 * (10.0 * fabs(eh[c]) + 1e-6 * emax) + 1e-30;
            double dn = fabs((double)e8[c] - eh[c]);
            bad_n += !(dn <= tol);
            double rn = dn / (fabs(eh[c]) + 1e-6 * emax + 1e-30);
            max_rel_n = rn > max_rel_n ? rn : max_rel_n;
            double rt = fabs((double)t8[c] - th[c]) / (fabs(th[c]) + 1e-3 * emax + 1e-30);
            sum_rel_t += rt;
            max_rel_t = rt > max_rel_t ? rt : max_rel_t;
          }
          nt++;
        }
  /* GLG probes */
  size_t np = (size_t)f->glg_probe_count, bad_p = 0;
  double max_over = 0.0;
  if (np) {
    float *gh = malloc(np * 27 * sizeof *gh), *g8 = malloc(np * 27 * sizeof *g8);
    double *bound = calloc(np * 27, sizeof *bound);
    ASSERT_OK(ub_runtime_glg_probe_sh(rh, 0, gh));
    ASSERT_OK(ub_runtime_glg_probe_sh(r8, 0, g8));
    for (uint32_t d = 0; d < bf->dls_count; d++) {
      const ub_bakefile_record *r = &bf->dls[d];
      for (uint32_t i = 0; i < r->probe_count; i++) {
        const float *v = r->probe_sh + (size_t)i * 27;
        double m = 0.0;
        for (int j = 3; j < 27; j++)
          m = fabs(v[j]) > m ? fabs(v[j]) : m;
        for (int j = 3; j < 27; j++)
          bound[(size_t)r->probe_index[i] * 27 + j] += tint[j % 3] * m / 127.0;
      }
    }
    for (size_t p = 0; p < np; p++) {
      double pmax = 0.0;
      for (int j = 0; j < 27; j++)
        pmax = fabs(gh[p * 27 + j]) > pmax ? fabs(gh[p * 27 + j]) : pmax;
      for (int j = 0; j < 27; j++) {
        size_t q = p * 27 + j;
        /* the store: each value a half of value / 2^(probe exponent) */
        double tol = bound[q] + 1.0 / 1024.0 * (fabs(gh[q]) + fabs(g8[q]) + 1e-3 * pmax) + 1e-30;
        double dv = fabs((double)g8[q] - gh[q]);
        bad_p += !(dv <= tol);
        double o = dv / tol;
        max_over = o > max_over ? o : max_over;
      }
    }
    free(gh);
    free(g8);
    free(bound);
  }
  ub_runtime_memory mh, m8;
  ub_runtime_memory_usage(rh, &mh);
  ub_runtime_memory_usage(r8, &m8);
  printf("8-bit records: %zu texels, along the normal max relative difference %.2g (%zu over "
         "the float-rounding tolerance), 45° off it mean %.3g%% max %.3g%% (of the value + 0.1%% "
         "of the largest); %zu GLG probe values, %zu over the bound (largest difference %.2f "
         "of it); records %.2f -> %.2f MiB, run-time %.2f -> %.2f MiB\n",
         nt, max_rel_n, bad_n, 100.0 * sum_rel_t / (3.0 * (double)(nt ? nt : 1)),
         100.0 * max_rel_t, np * 27, bad_p, max_over, mh.records / 1048576.0,
         m8.records / 1048576.0, mh.total / 1048576.0, m8.total / 1048576.0);
  ASSERT_TRUE(nt > 0 && bad_n == 0 && bad_p == 0);
  ASSERT_TRUE(m8.records < mh.records * 0.7);
  ub_runtime_free(rh);
  ub_runtime_free(r8);
}

/* The values of a and b beyond the float rounding of two ways of summing the same rows;
 * *worst: the texels' largest difference over their tolerance. */
static size_t over_rounding(const snap *a, const snap *b, double *worst)
{
  double emax = 0.0;
  size_t bad = 0;
  *worst = 0.0;
  for (size_t i = 0; i < 3 * a->ntex; i++)
    emax = fabs(b->tex[i]) > emax ? fabs(b->tex[i]) : emax;
  for (size_t i = 0; i < 3 * a->ntex; i++) {
    /* float rounding of ~k + 2 sums of terms up to the texel's all-on value, then the AHD
     * encode's (terms ~10× I_z): 1e-5 of the value and 1e-6 of the largest */
    double d = fabs((double)a->tex[i] - b->tex[i]), tol = 1e-5 * fabs(b->tex[i]) + 1e-6 * emax;
    bad += !(d <= tol);
    *worst = d / tol > *worst ? d / tol : *worst;
  }
  for (size_t i = 0; i < a->nglg; i++) {
    double d = fabs((double)a->glg[i] - b->glg[i]);
    double tol = 1.0 / 1024.0 * (fabs(a->glg[i]) + fabs(b->glg[i])) + 1e-6 * emax;
    bad += !(d <= tol);
  }
  return bad;
}

/* ubk loaded by default (*ro) and with flags (*rf); 0, both freed, unless both loaded. */
static int load_two(const char *ubk, unsigned flags, ub_runtime **ro, ub_runtime **rf)
{
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, 0, ro));
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, flags, rf));
  if (*ro && *rf)
    return 1;
  ub_runtime_free(*ro);
  ub_runtime_free(*rf);
  return 0;
}

/* The all-ones sums (default) against UB_RUNTIME_PLAIN_SUMS, most sets on, some off or
 * tinted: texels along their normals and GLG raw probes agree to float rounding (the two
 * sum the same rows in another order), and the sums cost what ub_runtime_memory says. */
static void check_plain_sums(const char *ubk)
{
  ub_runtime *ro = NULL, *rp = NULL;
  if (!load_two(ubk, UB_RUNTIME_PLAIN_SUMS, &ro, &rp))
    return;
  for (uint32_t d = 0; d < ub_runtime_dls_count(ro); d++) {
    const float w[3] = {d % 3 == 1 ? 0.0f : 1.0f, 1.0f, d % 5 == 2 ? 0.6f : 1.0f};
    ASSERT_OK(ub_runtime_set_dls(ro, d, w));
    ASSERT_OK(ub_runtime_set_dls(rp, d, w));
  }
  ASSERT_OK(ub_runtime_update(ro, NULL));
  ASSERT_OK(ub_runtime_update(rp, NULL));
  snap so, sp;
  take(ro, &so);
  take(rp, &sp);
  double worst = 0.0;
  size_t differ = diff(&so, &sp), bad = over_rounding(&so, &sp, &worst);
  ub_runtime_memory mo, mp;
  ub_runtime_memory_usage(ro, &mo);
  ub_runtime_memory_usage(rp, &mp);
  printf("all-ones sums vs plain: %zu of %zu values differ in bits, %zu over the rounding "
         "tolerance (texels: worst %.2f of it); blend engines %.2f vs %.2f MiB\n", differ,
         3 * so.ntex + so.nglg, bad, worst, mo.blend / 1048576.0, mp.blend / 1048576.0);
  ASSERT_TRUE(bad == 0 && differ > 0 && mo.blend > mp.blend);
  free(so.tex);
  free(so.glg);
  free(sp.tex);
  free(sp.glg);
  ub_runtime_free(ro);
  ub_runtime_free(rp);
}

/* How many texels rb's last update listed as changed (*nb) and how many of ra's list it
 * lacks. */
static uint64_t changes_missing(const ub_runtime *ra, const ub_runtime *rb, uint64_t *nb)
{
  const ub_bakefile *f = ub_runtime_bakefile(ra);
  size_t off[65], npx = 0;
  for (uint32_t a = 0; a < f->atlas_count && a < 64; a++) {
    off[a] = npx;
    npx += (size_t)f->atlases[a].width * f->atlases[a].height;
  }
  const uint64_t na = ub_runtime_changed_texel_count(ra);
  *nb = ub_runtime_changed_texel_count(rb);
  uint8_t *in_b = calloc(npx + 1, 1);
  ub_runtime_texel_change *c = malloc((size_t)(na > *nb ? na : *nb) * sizeof *c + 1);
  uint64_t missing = na + 1;
  if (in_b && c && f->atlas_count <= 64 && ub_runtime_changed_texels(rb, 0, *nb, c) == *nb) {
    for (uint64_t i = 0; i < *nb; i++)
      in_b[off[c[i].atlas] + (size_t)c[i].y * f->atlases[c[i].atlas].width + c[i].x] = 1;
    if (ub_runtime_changed_texels(ra, 0, na, c) == na) {
      missing = 0;
      for (uint64_t i = 0; i < na; i++)
        missing += !in_b[off[c[i].atlas] + (size_t)c[i].y * f->atlases[c[i].atlas].width + c[i].x];
    }
  }
  free(in_b);
  free(c);
  return missing;
}

/* 1 when ub_runtime_changed_texels gives the same list asked in pieces of 97 as whole. */
static int pieces_same(const ub_runtime *rt)
{
  const uint64_t n = ub_runtime_changed_texel_count(rt);
  ub_runtime_texel_change *a = malloc((n ? n : 1) * sizeof *a);
  ub_runtime_texel_change *b = malloc((n ? n : 1) * sizeof *b);
  int same = a && b && ub_runtime_changed_texels(rt, 0, (size_t)n + 5, a) == n;
  for (uint64_t k = 0; same && k < n; k += 97)
    same = ub_runtime_changed_texels(rt, k, 97, b + k) == (n - k < 97 ? n - k : 97);
  same = same && (!n || memcmp(a, b, (size_t)n * sizeof *a) == 0);
  free(a);
  free(b);
  return same;
}

/* Updates ro and rm and compares the texels they list: *missing gains those ro lists and
 * rm does not, *differ 1 when the counts differ or rm's list asked in pieces does.
 * Returns rm's count. */
static uint64_t update_two(ub_runtime *ro, ub_runtime *rm, ub_runtime_update_stats *so,
                           ub_runtime_update_stats *sm, uint64_t *missing, uint64_t *differ)
{
  ASSERT_OK(ub_runtime_update(ro, so));
  ASSERT_OK(ub_runtime_update(rm, sm));
  uint64_t nb = 0;
  *missing += changes_missing(ro, rm, &nb);
  *differ += nb != ub_runtime_changed_texel_count(ro) || !pieces_same(rm);
  return nb;
}

/* Merged groups (the default) against UB_RUNTIME_SEPARATE_GROUPS: texels of rare
 * combinations join common ones' groups through zero rows, so an all-sets update visits
 * fewer groups; every state (all sets at 0.5, then each set off and back on with the
 * others on) agrees to float rounding (a merged group may take its all-ones sums where the
 * small one summed its rows), and each toggle lists exactly the texels separate groups
 * list: a merged texel whose own sets did not change is left as it was (session 41's
 * version also listed the merged texels holding a zero row of the toggled set), also in
 * an update of every set after the toggles (where none is left) and asked in pieces. */
static void check_merge_groups(const char *ubk)
{
  ub_runtime *ro = NULL, *rm = NULL;
  if (!load_two(ubk, UB_RUNTIME_SEPARATE_GROUPS, &rm, &ro)) /* rm: the default */
    return;
  ub_runtime_update_stats so, sm;
  const float half[3] = {0.5f, 0.25f, 0.5f}, one[3] = {1.0f, 1.0f, 1.0f}, off[3] = {0, 0, 0};
  const uint32_t nd = ub_runtime_dls_count(ro);
  for (uint32_t d = 0; d < nd; d++) {
    ASSERT_OK(ub_runtime_set_dls(ro, d, half));
    ASSERT_OK(ub_runtime_set_dls(rm, d, half));
  }
  ASSERT_OK(ub_runtime_update(ro, &so));
  ASSERT_OK(ub_runtime_update(rm, &sm));
  printf("merged groups: an all-sets update visits %u groups (%u without)\n", sm.groups,
         so.groups);
  ASSERT_TRUE(sm.groups < so.groups && sm.groups > 0);
  size_t bad = 0, states = 0;
  uint64_t missing = 0, listed_o = 0, listed_m = 0, differ = 0;
  double worst = 0.0;
  for (uint32_t d = 0; d <= 2 * nd; d++) {
    if (d > 0) { /* set (d - 1) / 2 off, then back on */
      const uint32_t e = (d - 1) / 2;
      ASSERT_OK(ub_runtime_set_dls(ro, e, d % 2 ? off : one));
      ASSERT_OK(ub_runtime_set_dls(rm, e, d % 2 ? off : one));
      if (d == 1)
        for (uint32_t k = 1; k < nd; k++) { /* the others on */
          ASSERT_OK(ub_runtime_set_dls(ro, k, one));
          ASSERT_OK(ub_runtime_set_dls(rm, k, one));
        }
      listed_m += update_two(ro, rm, &so, &sm, &missing, &differ);
      listed_o += ub_runtime_changed_texel_count(ro);
    }
    snap a, b;
    take(ro, &a);
    take(rm, &b);
    double w = 0.0;
    bad += over_rounding(&a, &b, &w);
    worst = w > worst ? w : worst;
    states++;
    free(a.tex);
    free(a.glg);
    free(b.tex);
    free(b.glg);
  }
  const float third[3] = {0.3f, 0.3f, 0.3f}; /* every set changed */
  for (uint32_t d = 0; d < nd; d++) {
    ASSERT_OK(ub_runtime_set_dls(ro, d, third));
    ASSERT_OK(ub_runtime_set_dls(rm, d, third));
  }
  update_two(ro, rm, &so, &sm, &missing, &differ);
  ub_runtime_memory mo, mm;
  ub_runtime_memory_usage(ro, &mo);
  ub_runtime_memory_usage(rm, &mm);
  printf("merged groups: %zu states, %zu values over the rounding tolerance (texels: worst %.2f "
         "of it); toggles listed %llu texels (%llu without, %llu of those missing); records "
         "%.2f vs %.2f MiB, blend engines %.2f vs %.2f MiB\n", states, bad, worst,
         (unsigned long long)listed_m, (unsigned long long)listed_o,
         (unsigned long long)missing, mm.records / 1048576.0, mo.records / 1048576.0,
         mm.blend / 1048576.0, mo.blend / 1048576.0);
  ASSERT_TRUE(bad == 0 && missing == 0 && differ == 0);
  ub_runtime_free(ro);
  ub_runtime_free(rm);
}

/* 1 when the last updates of ra and rb changed the same texels (ub_runtime_changed_texels:
 * the same list in the same order, with the same AHD) and flagged the same LLG models. */
static int same_changes(const ub_runtime *ra, const ub_runtime *rb)
{
  const uint64_t n = ub_runtime_changed_texel_count(ra);
  ub_runtime_texel_change *ca = malloc((n ? n : 1) * sizeof *ca);
  ub_runtime_texel_change *cb = malloc((n ? n : 1) * sizeof *cb);
  int same = ca && cb && ub_runtime_changed_texel_count(rb) == n &&
             ub_runtime_changed_texels(ra, 0, (size_t)n, ca) == n &&
             ub_runtime_changed_texels(rb, 0, (size_t)n, cb) == n &&
             (!n || memcmp(ca, cb, (size_t)n * sizeof *ca) == 0);
  free(ca);
  free(cb);
  for (uint32_t m = 0; m < ub_runtime_bakefile(ra)->llg_count; m++)
    same &= ub_runtime_llg_changed(ra, m) == ub_runtime_llg_changed(rb, m);
  return same;
}

/* The same update of ra and rb: plain, or (jobs) in 3 jobs run one after another (rb's in
 * reverse). */
static void update_pair(ub_runtime *ra, ub_runtime *rb, int jobs, ub_runtime_update_stats *sa,
                        ub_runtime_update_stats *sb)
{
  if (!jobs) {
    ASSERT_OK(ub_runtime_update(ra, sa));
    ASSERT_OK(ub_runtime_update(rb, sb));
    return;
  }
  uint32_t ja = 0, jb = 0;
  ASSERT_OK(ub_runtime_update_begin(ra, 3, &ja));
  ASSERT_OK(ub_runtime_update_begin(rb, 3, &jb));
  for (uint32_t j = 0; j < ja; j++)
    ub_runtime_update_job(ra, j);
  for (uint32_t j = 0; j < jb; j++)
    ub_runtime_update_job(rb, jb - 1 - j);
  ub_runtime_update_end(ra, sa);
  ub_runtime_update_end(rb, sb);
}

/* Counts, after an update of both, whether ra and rb differ in their whole atlas, their
 * changed-texel lists and LLG flags (same_changes), and their LLG grids as queries read
 * them. */
static void compare_pair(const ub_runtime *ra, const ub_runtime *rb, size_t *bad_atlas,
                         size_t *bad_changed, size_t *bad_llg)
{
  const ub_bakefile *fa = ub_runtime_bakefile(ra), *fb = ub_runtime_bakefile(rb);
  *bad_atlas += !same_atlases(ra, rb, fa);
  *bad_changed += !same_changes(ra, rb);
  int llg_same = fa->llg_count == fb->llg_count;
  for (uint32_t m = 0; llg_same && m < fa->llg_count; m++) {
    const size_t n = (size_t)fa->llgs[m].dims[0] * fa->llgs[m].dims[1] * fa->llgs[m].dims[2];
    llg_same = !memcmp(fa->llgs[m].probe_sh, fb->llgs[m].probe_sh, n * 27 * sizeof(float));
  }
  *bad_llg += !llg_same;
}

/* ub_runtime_keep_state (UB_RUNTIME_KEEP_STATE at load, and again mid-way at a tinted
 * state) against a run-time without: 300 random changes (mostly a set off or back on,
 * some tints, sometimes several at once, plain and 3-job updates), and after every update
 * the whole atlas and the changed-texel list bit for bit the same; the kept state's
 * texels are copied back (texels_kept > 0, and all of them when every set is back). */
static void check_keep_state(const char *ubk)
{
  ub_runtime *ra = NULL, *rb = NULL;
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, 0, &ra));
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, UB_RUNTIME_KEEP_STATE, &rb));
  const uint32_t nd = ra ? ub_runtime_dls_count(ra) : 0;
  float *cur = malloc(sizeof(float) * 3 * (nd + 1)), *kept_w = malloc(sizeof(float) * 3 * (nd + 1));
  if (!ra || !rb || !cur || !kept_w) {
    ASSERT_TRUE(cur && kept_w);
    free(cur);
    free(kept_w);
    ub_runtime_free(ra);
    ub_runtime_free(rb);
    return;
  }
  ub_runtime_memory ma, mb;
  ub_runtime_memory_usage(ra, &ma);
  ub_runtime_memory_usage(rb, &mb);
  for (uint32_t i = 0; i < 3 * nd; i++)
    cur[i] = kept_w[i] = 1.0f; /* the load state: every set on */
  uint32_t h = 4242u;
  size_t bad_atlas = 0, bad_changed = 0, bad_llg = 0;
  uint64_t kept = 0, reenc = 0, back_kept = 0, back_texels = 0, llg_kept = 0;
  for (int step = 0; step < 300; step++) {
    if (step == 150) { /* keep another state: set 1 tinted, the others as they are */
      const float t[3] = {0.7f, 1.0f, 0.4f};
      memcpy(cur + 3, t, sizeof t);
      ASSERT_OK(ub_runtime_set_dls(ra, 1, t));
      ASSERT_OK(ub_runtime_set_dls(rb, 1, t));
      /* refused while a change waits for its update, */
      ASSERT_TRUE(ub_runtime_keep_state(rb) == UB_ERR_INVALID_ARGUMENT);
      ASSERT_OK(ub_runtime_update(ra, NULL));
      uint32_t jobs = 0; /* and while an update is begun and not ended */
      ASSERT_OK(ub_runtime_update_begin(rb, 2, &jobs));
      ASSERT_TRUE(ub_runtime_keep_state(rb) == UB_ERR_INVALID_ARGUMENT);
      for (uint32_t j = 0; j < jobs; j++)
        ub_runtime_update_job(rb, j);
      ub_runtime_update_end(rb, NULL);
      ASSERT_OK(ub_runtime_keep_state(rb));
      memcpy(kept_w, cur, sizeof(float) * 3 * nd);
    }
    const int nchg = step % 7 == 3 ? 3 : 1;
    for (int c = 0; c < nchg; c++) {
      h = h * 1664525u + 1013904223u;
      uint32_t d = (h >> 8) % nd, kind = (h >> 4) % 8;
      float *w = cur + 3 * d;
      if (kind < 3) /* off */
        w[0] = w[1] = w[2] = 0.0f;
      else if (kind < 7) /* back to the kept value */
        memcpy(w, kept_w + 3 * d, 3 * sizeof(float));
      else
        w[0] = w[1] = 1.0f, w[2] = 0.5f;
    }
    const int back = step == 99 || step == 299; /* every set back to the kept state */
    if (back)
      memcpy(cur, kept_w, sizeof(float) * 3 * nd);
    for (uint32_t d = 0; d < nd; d++) {
      ASSERT_OK(ub_runtime_set_dls(ra, d, cur + 3 * d));
      ASSERT_OK(ub_runtime_set_dls(rb, d, cur + 3 * d));
    }
    ub_runtime_update_stats sa, sb;
    update_pair(ra, rb, step % 5 == 4, &sa, &sb);
    ASSERT_TRUE(sa.texels_kept == 0 && sa.texels_reencoded == sb.texels_reencoded);
    kept += sb.texels_kept;
    reenc += sb.texels_reencoded;
    if (back) {
      back_kept += sb.texels_kept;
      back_texels += sb.texels_reencoded;
    }
    compare_pair(ra, rb, &bad_atlas, &bad_changed, &bad_llg);
    llg_kept += sb.llg_probes_kept;
    bad_llg += sa.llg_probes_kept != 0 || sa.llg_probes_written != sb.llg_probes_written ||
               (back && sb.llg_probes_kept != sb.llg_probes_written);
  }
  printf("kept state: 300 changes, atlases differing after %zu updates, changed-texel lists "
         "or LLG flags after %zu, LLG grids after %zu (want 0); %llu of %llu texels copied back (%llu of "
         "%llu when every set returned to the kept state), %llu LLG probes; memory +%.2f "
         "MiB\n",
         bad_atlas, bad_changed, bad_llg, (unsigned long long)kept, (unsigned long long)reenc,
         (unsigned long long)back_kept, (unsigned long long)back_texels,
         (unsigned long long)llg_kept, ((double)mb.total - (double)ma.total) / 1048576.0);
  ASSERT_TRUE(bad_atlas == 0 && bad_changed == 0 && bad_llg == 0 && llg_kept > 0);
  ASSERT_TRUE(kept > 0 && kept < reenc);
  ASSERT_TRUE(back_texels > 0 && back_kept == back_texels);
  ASSERT_TRUE(mb.total > ma.total);
  free(cur);
  free(kept_w);
  ub_runtime_free(ra);
  ub_runtime_free(rb);
}

/* A value set and set back before the update is no change: set 0 off and on again, then
 * (after an update with it off) on and off again: the updates after re-encode no texel,
 * write no probe and list nothing, keep_state is refused while set 0 is away and allowed
 * once it is back, and the atlases equal a run-time that went to each state directly. */
static void check_set_back(const char *ubk)
{
  ub_runtime *ra = NULL, *rb = NULL;
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, 0, &ra));
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, 0, &rb));
  if (!ra || !rb) {
    ub_runtime_free(ra);
    ub_runtime_free(rb);
    return;
  }
  const float one[3] = {1, 1, 1}, zero[3] = {0, 0, 0};
  ub_runtime_update_stats st;
  for (int pass = 0; pass < 2; pass++) {
    const float *at = pass ? zero : one, *away = pass ? one : zero;
    ASSERT_OK(ub_runtime_set_dls(ra, 0, away));
    ASSERT_TRUE(ub_runtime_keep_state(ra) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_OK(ub_runtime_set_dls(ra, 0, at));
    ASSERT_OK(ub_runtime_keep_state(ra));
    ASSERT_OK(ub_runtime_update(ra, &st));
    printf("set back (%s): %llu texels re-encoded, %llu probes, %llu LLG probes written, %llu "
           "listed\n",
           pass ? "off, on, off" : "on, off, on", (unsigned long long)st.texels_reencoded,
           (unsigned long long)st.probes_written, (unsigned long long)st.llg_probes_written,
           (unsigned long long)ub_runtime_changed_texel_count(ra));
    ASSERT_TRUE(st.texels_reencoded == 0 && st.probes_written == 0 &&
                st.llg_probes_written == 0 && ub_runtime_changed_texel_count(ra) == 0);
    ASSERT_OK(ub_runtime_set_dls(rb, 0, at));
    ASSERT_OK(ub_runtime_update(rb, NULL));
    ASSERT_TRUE(same_atlases(ra, rb, ub_runtime_bakefile(ra)));
    if (!pass) { /* set 0 off for the second pass: a real change */
      ASSERT_OK(ub_runtime_set_dls(ra, 0, zero));
      ASSERT_OK(ub_runtime_update(ra, &st));
      ASSERT_TRUE(st.texels_reencoded > 0);
    }
  }
  ub_runtime_free(ra);
  ub_runtime_free(rb);
}

/* The base state's AHD (kept by default) against a run-time without it
 * (UB_RUNTIME_NO_BASE_AHD): 300 random changes, mostly sets off (from all on, then from a
 * state with most sets off, where a set turned off leaves texels no other set lights),
 * some back on or tinted, sometimes several at once, plain and 3-job updates; after every
 * update the whole atlas, the changed-texel list and the LLG grids bit for bit the same.
 * The base's texels are copied (texels_base > 0; all of them when every set is off) and
 * cost 16 B a touched texel. */
static void check_base_ahd(const char *ubk)
{
  ub_runtime *ra = NULL, *rb = NULL;
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, UB_RUNTIME_NO_BASE_AHD, &ra));
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, 0, &rb));
  if (!ra || !rb) {
    ub_runtime_free(ra);
    ub_runtime_free(rb);
    return;
  }
  const uint32_t nd = ub_runtime_dls_count(ra);
  uint32_t h = 9191u;
  size_t bad_atlas = 0, bad_changed = 0, bad_llg = 0;
  uint64_t based = 0, reenc = 0, all_off_base = 0, all_off_texels = 0;
  const float off[3] = {0.0f, 0.0f, 0.0f}, on[3] = {1.0f, 1.0f, 1.0f},
              tint[3] = {1.0f, 0.6f, 0.3f};
  for (int step = 0; step < 300; step++) {
    const int nchg = step % 7 == 3 ? 3 : 1;
    for (int c = 0; c < nchg; c++) {
      h = h * 1664525u + 1013904223u;
      uint32_t d = (h >> 8) % nd, kind = (h >> 4) % 8;
      /* the first half mostly turns sets off, the second mostly on */
      const int turn_off = step < 150 ? kind < 6 : kind < 2;
      const float *w = turn_off ? off : kind == 7 ? tint : on;
      ASSERT_OK(ub_runtime_set_dls(ra, d, w));
      ASSERT_OK(ub_runtime_set_dls(rb, d, w));
    }
    const int all_off = step == 149; /* every set off: every touched texel at the base */
    if (all_off)
      for (uint32_t d = 0; d < nd; d++) {
        ASSERT_OK(ub_runtime_set_dls(ra, d, off));
        ASSERT_OK(ub_runtime_set_dls(rb, d, off));
      }
    ub_runtime_update_stats sa, sb;
    update_pair(ra, rb, step % 5 == 4, &sa, &sb);
    ASSERT_TRUE(sa.texels_base == 0 && sa.texels_reencoded == sb.texels_reencoded);
    based += sb.texels_base;
    reenc += sb.texels_reencoded;
    if (all_off) {
      all_off_base += sb.texels_base;
      all_off_texels += sb.texels_reencoded;
    }
    compare_pair(ra, rb, &bad_atlas, &bad_changed, &bad_llg);
  }
  ub_runtime_memory ma, mb;
  ub_runtime_memory_usage(ra, &ma);
  ub_runtime_memory_usage(rb, &mb);
  printf("base AHD: 300 changes, atlases differing after %zu updates, changed-texel lists "
         "after %zu, LLG grids after %zu (want 0); %llu of %llu texels copied from the base "
         "(%llu of %llu with every set off); memory +%.3f MiB\n",
         bad_atlas, bad_changed, bad_llg, (unsigned long long)based, (unsigned long long)reenc,
         (unsigned long long)all_off_base, (unsigned long long)all_off_texels,
         ((double)mb.total - (double)ma.total) / 1048576.0);
  ASSERT_TRUE(bad_atlas == 0 && bad_changed == 0 && bad_llg == 0);
  ASSERT_TRUE(based > 0 && based < reenc);
  ASSERT_TRUE(all_off_texels > 0 && all_off_base == all_off_texels);
  /* 16 B a touched texel (at least the ones the all-off update re-encoded), nothing else */
  const size_t extra = mb.lightmap - ma.lightmap;
  ASSERT_TRUE(mb.lightmap > ma.lightmap && extra % sizeof(ub_ahd_packed) == 0 &&
              extra >= all_off_texels * sizeof(ub_ahd_packed) &&
              mb.total - ma.total == extra);
  ub_runtime_free(ra);
  ub_runtime_free(rb);
}

/* The decoded AHD lightmap at fixed points of the lit triangles and LLG irradiance at
 * fixed points (what a parallel update writes besides the SH the snapshot reads). */
static void take_decoded(const ub_runtime *rt, float *out, int n)
{
  const ub_bakefile *f = ub_runtime_bakefile(rt);
  uint32_t h = 777u;
  const float nrm[3] = {0.3f, 0.4f, 0.866f};
  for (int i = 0; i < n; i++) {
    h = h * 1664525u + 1013904223u;
    uint32_t t = (h >> 4) % f->triangle_count;
    out[6 * i] = out[6 * i + 1] = out[6 * i + 2] = -1.0f;
    ub_runtime_lightmap_at(rt, t, 0.25f, 0.35f, nrm, out + 6 * i);
    const float *v = f->positions + 3 * (size_t)f->indices[3 * (size_t)t];
    float p[3] = {v[0], v[1] + 0.5f, v[2]};
    out[6 * i + 3] = out[6 * i + 4] = out[6 * i + 5] = -1.0f;
    ub_runtime_query_llg(rt, p, nrm, out + 6 * i + 3);
  }
}

/* Every covered texel's decoded AHD irradiance for a tilted normal (all of its AHD). */
static void take_ahd(const ub_runtime *rt, float *out, size_t *n)
{
  const ub_bakefile *f = ub_runtime_bakefile(rt);
  const float nrm[3] = {-0.5f, 0.6f, 0.62f};
  size_t k = 0;
  for (uint32_t a = 0; a < f->atlas_count; a++)
    for (uint32_t y = 0; y < f->atlases[a].height; y++)
      for (uint32_t x = 0; x < f->atlases[a].width; x++)
        if (f->atlases[a].coverage[(size_t)y * f->atlases[a].width + x]) {
          if (out)
            ub_runtime_texel_irradiance(rt, a, x, y, nrm, out + 3 * k);
          k++;
        }
  *n = k;
}

typedef struct job_arg {
  ub_runtime *rt;
  uint32_t job;
  int ftz; /* run the job with FTZ and DAZ set, as a game thread may */
} job_arg;

static void *job_main(void *arg)
{
  job_arg *a = arg;
#if defined(__SSE2__)
  unsigned csr = _mm_getcsr();
  if (a->ftz)
    _mm_setcsr(csr | 0x8040u);
#endif
  ub_runtime_update_job(a->rt, a->job);
#if defined(__SSE2__)
  _mm_setcsr(csr);
#endif
  return NULL;
}

/* ub_runtime_update_begin/job/end with 2, 3 and 5 jobs on threads against a plain
 * ub_runtime_update of a second run-time under the same random states: identical texel
 * SH, GLG probes, decoded AHD and LLG queries, and the same counts. */
static void check_jobs(const char *ubk)
{
  ub_runtime *ra = NULL, *rb = NULL;
  ASSERT_OK(ub_runtime_load(ubk, NULL, &ra));
  ASSERT_OK(ub_runtime_load(ubk, NULL, &rb));
  if (!ra || !rb)
    return;
  uint32_t nd = ub_runtime_dls_count(ra), jobs = 0;
  ASSERT_TRUE(ub_runtime_update_begin(rb, 0, &jobs) == UB_ERR_INVALID_ARGUMENT);
  ASSERT_TRUE(ub_runtime_update_begin(rb, UB_RUNTIME_MAX_JOBS + 1, &jobs) ==
              UB_ERR_INVALID_ARGUMENT);
  enum { NQ = 3000 };
  float *qa = malloc(6 * NQ * sizeof(float)), *qb = malloc(6 * NQ * sizeof(float));
  size_t nt = 0;
  take_ahd(ra, NULL, &nt);
  float *ta = malloc((3 * nt + 1) * sizeof(float)), *tb = malloc((3 * nt + 1) * sizeof(float));
  uint32_t h = 4242u;
  size_t bad = 0, bad_q = 0, bad_stats = 0;
  for (int round = 0; round < 9; round++) {
    for (int c = 0; c < (round % 3 == 0 ? (int)nd : 3); c++) {
      h = h * 1664525u + 1013904223u;
      uint32_t d = round % 3 == 0 ? (uint32_t)c : (h >> 8) % nd;
      float w = (h >> 29) < 3 ? 0.0f : (float)((h >> 12) & 0xff) / 128.0f;
      float rgb[3] = {w, w * 0.6f, w * 1.2f};
      ASSERT_OK(ub_runtime_set_dls(ra, d, rgb));
      ASSERT_OK(ub_runtime_set_dls(rb, d, rgb));
    }
    ub_runtime_update_stats sa, sb;
    ASSERT_OK(ub_runtime_update(ra, &sa));
    const uint32_t want = round % 3 == 0 ? 2 : round % 3 == 1 ? 3 : 5;
    ASSERT_OK(ub_runtime_update_begin(rb, want, &jobs));
    ASSERT_TRUE(jobs == want);
    uint32_t again = 0;
    ASSERT_TRUE(ub_runtime_update_begin(rb, 2, &again) == UB_ERR_INVALID_ARGUMENT);
    pthread_t th[5];
    job_arg args[5];
    for (uint32_t j = 0; j < jobs && j < 5; j++) {
      args[j] = (job_arg){rb, j, round % 2};
      ASSERT_TRUE(pthread_create(&th[j], NULL, job_main, &args[j]) == 0);
    }
    for (uint32_t j = 0; j < jobs && j < 5; j++)
      pthread_join(th[j], NULL);
    ub_runtime_update_end(rb, &sb);
    bad_stats += sa.texels_written != sb.texels_written ||
                 sa.texels_reencoded != sb.texels_reencoded ||
                 sa.probes_written != sb.probes_written ||
                 sa.llg_probes_written != sb.llg_probes_written ||
                 sa.bytes_read != sb.bytes_read || sa.bytes_written != sb.bytes_written ||
                 sa.groups != sb.groups;
    snap a, b;
    take(ra, &a);
    take(rb, &b);
    bad += diff(&a, &b);
    free(a.tex);
    free(a.glg);
    free(b.tex);
    free(b.glg);
    take_decoded(ra, qa, NQ);
    take_decoded(rb, qb, NQ);
    bad_q += memcmp(qa, qb, 6 * NQ * sizeof(float)) != 0;
    take_ahd(ra, ta, &nt);
    take_ahd(rb, tb, &nt);
    bad_q += memcmp(ta, tb, 3 * nt * sizeof(float)) != 0;
    /* the changed texels: the same list, in the same order, whatever the jobs; the same
     * LLG models */
    bad_q += ub_runtime_changed_texel_count(ra) != sa.texels_reencoded || !same_changes(ra, rb);
  }
  /* Misuse of the protocol is harmless: sets and updates refused while begun; a job index
   * out of range ignored; a job not run is run by end (the state is still the plain
   * update's); an end without begin keeps the last changes listed. */
  {
    const float half3[3] = {0.5f, 0.5f, 0.5f};
    ASSERT_OK(ub_runtime_set_dls(ra, 0, half3));
    ASSERT_OK(ub_runtime_set_dls(rb, 0, half3));
    ub_runtime_update_stats sa, sb;
    ASSERT_OK(ub_runtime_update(ra, &sa));
    ASSERT_OK(ub_runtime_update_begin(rb, 3, &jobs));
    ASSERT_TRUE(ub_runtime_set_dls(rb, 1, half3) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_update(rb, NULL) == UB_ERR_INVALID_ARGUMENT);
    ub_runtime_update_job(rb, 7); /* ignored */
    ub_runtime_update_job(rb, 1); /* jobs 0 and 2 not run */
    ub_runtime_update_end(rb, &sb);
    snap a, b;
    take(ra, &a);
    take(rb, &b);
    const size_t miss = diff(&a, &b);
    const uint64_t n = ub_runtime_changed_texel_count(rb);
    ub_runtime_update_end(rb, &sb); /* no update begun */
    ub_runtime_update_job(rb, 0);   /* ignored */
    printf("jobs misused (a set and an update while begun refused, job 7 of 3 ignored, jobs 0 "
           "and 2 left to end): %zu SH values differ from the plain update; a stray end left "
           "%llu of %llu changed texels listed, texels_reencoded %llu\n", miss,
           (unsigned long long)ub_runtime_changed_texel_count(rb), (unsigned long long)n,
           (unsigned long long)sb.texels_reencoded);
    ASSERT_TRUE(miss == 0 && sa.texels_reencoded == n && n > 0 && same_changes(ra, rb));
    ASSERT_TRUE(ub_runtime_changed_texel_count(rb) == n && sb.texels_reencoded == 0);
    free(a.tex);
    free(a.glg);
    free(b.tex);
    free(b.glg);
  }
  printf("jobs (2, 3, 5 on threads, every other state with FTZ/DAZ set on them) vs plain "
         "updates, 9 states: %zu SH values, %zu decoded query sets (AHD at 3000 points, every "
         "texel's AHD, the changed-texel lists and LLG models), %zu stats differ (want 0)\n", bad, bad_q, bad_stats);
  ASSERT_TRUE(bad == 0 && bad_q == 0 && bad_stats == 0);
  free(qa);
  free(qb);
  free(ta);
  free(tb);
  ub_runtime_free(ra);
  ub_runtime_free(rb);
}

/* GLG queries on 4 threads right after each update (the probes the update marked are
 * blended by whichever query reads them first; several threads read the same ones at
 * once, each from its own point order, plain and through a cursor) against one thread
 * querying a second run-time under the same states: the same bits. A third run-time with
 * the small walk (UB_RUNTIME_GLG_SMALL_WALK), queried by one thread, gives the same values
 * to rounding: its barycentrics are computed in double from the corners instead of in
 * float from a stored inverse (where a tet's leak plane drops corners, the rest are
 * renormalised, which can magnify that rounding where the kept ones' λ are tiny: a few
 * points may differ more) and it holds 48 B a tet less. */
typedef struct glg_q_arg {
  const ub_runtime *rt;
  const float *pts, *nrm;
  uint32_t n, start;
  float *out; /* n × 6: plain, cursor */
} glg_q_arg;

static void *glg_q_main(void *arg)
{
  glg_q_arg *a = arg;
  uint32_t cache = UB_GLG_NO_CACHE;
  ub_glg_cursor cur;
  ub_glg_cursor_init(&cur);
  for (uint32_t k = 0; k < a->n; k++) {
    uint32_t i = (a->start + k * 7919u) % a->n; /* a permutation: n is not a multiple of 7919 */
    ub_runtime_query_glg(a->rt, a->pts + 3 * (size_t)i, a->nrm + 3 * (size_t)i, &cache,
                         a->out + 6 * (size_t)i);
    ub_runtime_query_glg_cursor(a->rt, a->pts + 3 * (size_t)i, a->nrm + 3 * (size_t)i, &cur,
                                a->out + 6 * (size_t)i + 3);
  }
  return NULL;
}

static void check_glg_threads(const char *ubk)
{
  ub_runtime *ra = NULL, *rb = NULL, *rs = NULL;
  ASSERT_OK(ub_runtime_load(ubk, NULL, &ra));
  ASSERT_OK(ub_runtime_load(ubk, NULL, &rb));
  ASSERT_OK(ub_runtime_load_ex(ubk, NULL, UB_RUNTIME_GLG_SMALL_WALK, &rs));
  if (!ra || !rb || !rs) {
    ub_runtime_free(ra);
    ub_runtime_free(rb);
    ub_runtime_free(rs);
    return;
  }
  const ub_bakefile *bf = ub_runtime_bakefile(ra);
  float lo[3] = {1e30f, 1e30f, 1e30f}, hi[3] = {-1e30f, -1e30f, -1e30f};
  for (uint32_t v = 0; v < bf->vertex_count; v++)
    for (int k = 0; k < 3; k++) {
      lo[k] = fminf(lo[k], bf->positions[3 * (size_t)v + k]);
      hi[k] = fmaxf(hi[k], bf->positions[3 * (size_t)v + k]);
    }
  enum { NP = 20000, NT = 4 };
  float *pts = malloc(3 * NP * sizeof(float)), *nrm = malloc(3 * NP * sizeof(float));
  float *want = malloc(6 * NP * sizeof(float)), *got[NT];
  uint32_t h = 777u;
  for (uint32_t i = 0; i < 3 * NP; i++) {
    h = h * 1664525u + 1013904223u;
    float u = (float)(h >> 8) / 16777216.0f;
    pts[i] = lo[i % 3] + u * (hi[i % 3] - lo[i % 3]);
    nrm[i] = u - 0.5f;
  }
  for (int t = 0; t < NT; t++)
    got[t] = malloc(6 * NP * sizeof(float));
  float *small = malloc(6 * NP * sizeof(float));
  uint32_t nd = ub_runtime_dls_count(ra);
  size_t bad = 0, s_far = 0, s_loose = 0;
  double s_worst = 0.0;
  for (int round = 0; round < 6; round++) {
    for (uint32_t d = 0; d < nd; d++) {
      h = h * 1664525u + 1013904223u;
      if (round > 0 && (h >> 28) > 5)
        continue;
      float w = (h >> 29) < 2 ? 0.0f : (float)((h >> 12) & 0xff) / 128.0f;
      float rgb[3] = {w, w * 0.7f, w * 1.1f};
      ASSERT_OK(ub_runtime_set_dls(ra, d, rgb));
      ASSERT_OK(ub_runtime_set_dls(rb, d, rgb));
      ASSERT_OK(ub_runtime_set_dls(rs, d, rgb));
    }
    ASSERT_OK(ub_runtime_update(ra, NULL));
    ASSERT_OK(ub_runtime_update(rb, NULL));
    ASSERT_OK(ub_runtime_update(rs, NULL));
    glg_q_arg one = {rb, pts, nrm, NP, 0, want};
    glg_q_main(&one);
    glg_q_arg sw = {rs, pts, nrm, NP, 0, small};
    glg_q_main(&sw);
    double emax = 0.0;
    for (size_t i = 0; i < 6 * (size_t)NP; i++)
      emax = fabs(want[i]) > emax ? fabs(want[i]) : emax;
    for (size_t i = 0; i < 6 * (size_t)NP; i++) {
      double d = fabs((double)small[i] - want[i]), m = fabs(want[i]) + 1e-6 * emax;
      s_worst = d / m > s_worst ? d / m : s_worst;
      s_loose += !(d <= 1e-4 * m);
      s_far += !(d <= 1e-2 * m);
    }
    pthread_t th[NT];
    glg_q_arg args[NT];
    for (int t = 0; t < NT; t++) {
      args[t] = (glg_q_arg){ra, pts, nrm, NP, (uint32_t)t * (NP / NT), got[t]};
      ASSERT_TRUE(pthread_create(&th[t], NULL, glg_q_main, &args[t]) == 0);
    }
    for (int t = 0; t < NT; t++)
      pthread_join(th[t], NULL);
    for (int t = 0; t < NT; t++)
      bad += memcmp(got[t], want, 6 * NP * sizeof(float)) != 0;
  }
  printf("GLG queries on %d threads right after each update (marked probes blended by the "
         "first reader), 6 states x %d points, plain and cursor: %zu thread results differ "
         "from one thread's (want 0)\n", NT, NP, bad);
  ASSERT_TRUE(bad == 0);
  ub_runtime_memory ma, ms;
  ub_runtime_memory_usage(ra, &ma);
  ub_runtime_memory_usage(rs, &ms);
  printf("small GLG walk: %zu of %d values beyond 1e-4 of the walk records' (+1e-6 of the "
         "largest), %zu beyond 1e-2, worst %.2e; GLG %.2f vs %.2f MiB\n", s_loose,
         6 * 6 * NP, s_far, s_worst, ms.glg / 1048576.0, ma.glg / 1048576.0);
  ASSERT_TRUE(s_far == 0 && s_loose <= 6 * 6 * NP / 1000 && ms.glg < ma.glg);
  for (int t = 0; t < NT; t++)
    free(got[t]);
  free(pts);
  free(nrm);
  free(want);
  free(small);
  ub_runtime_free(ra);
  ub_runtime_free(rb);
  ub_runtime_free(rs);
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  char build[512], level[1024], dir[1024];
  snprintf(build, sizeof build, "%s", b ? b : "build");
  snprintf(level, sizeof level, "%s/levels/estate_small.gltf", build);
  snprintf(dir, sizeof dir, "%s/test_out/estate", build);
  int want_sets = gltf_set_count(level);
  printf("%s: %d sets named in the glTF\n", level, want_sets);
  ASSERT_TRUE(want_sets >= MIN_MAX_OVERLAP);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = UB_QUALITY_DRAFT;
  o.bounces = 2; /* the structure is under test, not convergence: keep it under a minute */
  o.out_dir = dir;
  ub_bake_stats st;
  ub_result r = ub_bake_level(level, &o, NULL, &st);
  ASSERT_OK(r);
  if (r != UB_OK)
    TEST_MAIN_END();
  printf("baked in %.1f s: %u texels, %u GLG probes, %u sets\n", st.total_seconds, st.texels,
         st.glg_probes, st.dls_sets);
  ub_bakefile *bf = NULL;
  ASSERT_OK(ub_bakefile_read(st.ubk_path, NULL, &bf));
  if (bf) {
    ASSERT_TRUE((int)bf->dls_count == want_sets);
    ASSERT_TRUE(st.dls_sets == bf->dls_count);
    ASSERT_TRUE(bf->llg_count > 0);
    check_records(bf);
    check_blend(st.ubk_path, bf, 0);
    check_blend(st.ubk_path, bf, UB_RUNTIME_RECORDS_8BIT);
    check_records_8bit(st.ubk_path, bf);
    check_plain_sums(st.ubk_path);
    check_merge_groups(st.ubk_path);
    check_keep_state(st.ubk_path);
    check_set_back(st.ubk_path);
    check_base_ahd(st.ubk_path);
    check_jobs(st.ubk_path);
    check_glg_threads(st.ubk_path);
  }
  ub_bakefile_free(bf);
  TEST_MAIN_END();
}
