/* tests/test_bakefile.c — .ubk writer/reader round trip, corruption and hostile input,
 * half/CRC helpers, and the first run-time queries (ubake/runtime.h). */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "bake/fsutil.h"
#include "runtime/crc32.h"
#include "runtime/half.h"
#include "runtime/texel_links.h"
#include "runtime/texel_sh.h"
#include "test_util.h"
#include "ubake/ahd.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"

#define PI 3.14159265358979323846
#define HALF_REL 0.00048828125 /* 2^-11 */
#define SH_Y00 0.28209479177387814

/* ---------------------------------------------------------------------------------- */
/* Helpers.                                                                            */

typedef struct capture {
  char last[1024];
  int errors;
} capture;

static void capture_fn(void *user, ub_log_level level, const char *msg)
{
  capture *c = user;
  if (level == UB_LOG_ERROR)
    c->errors++;
  snprintf(c->last, sizeof c->last, "%s", msg);
}

static char tmp_dir[256];

static void path_in_tmp(char *out, size_t n, const char *name)
{
  snprintf(out, n, "%s/%s", tmp_dir, name);
}

static uint8_t *slurp(const char *path, size_t *out_size)
{
  FILE *f = fopen(path, "rb");
  if (!f)
    return NULL;
  fseek(f, 0, SEEK_END);
  long n = ftell(f);
  fseek(f, 0, SEEK_SET);
  uint8_t *buf = malloc(n > 0 ? (size_t)n : 1);
  if (fread(buf, 1, (size_t)n, f) != (size_t)n) {
    free(buf);
    fclose(f);
    return NULL;
  }
  fclose(f);
  *out_size = (size_t)n;
  return buf;
}

static int file_exists(const char *path)
{
  struct stat st;
  return stat(path, &st) == 0;
}

static uint32_t rd32(const uint8_t *p)
{
  return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static void wr32(uint8_t *p, uint32_t v)
{
  for (int i = 0; i < 4; i++)
    p[i] = (uint8_t)(v >> (8 * i));
}

static void wr64(uint8_t *p, uint64_t v)
{
  for (int i = 0; i < 8; i++)
    p[i] = (uint8_t)(v >> (8 * i));
}

static uint64_t rd64(const uint8_t *p)
{
  return (uint64_t)rd32(p) | (uint64_t)rd32(p + 4) << 32;
}

/* A .ubk split into sections so tests can edit payloads and reassemble a file with
 * correct CRCs (a "hostile but well-formed" file). */
typedef struct section {
  char tag[4];
  uint32_t flags;
  uint8_t *data;
  size_t size;
} section;

static int split_file(const uint8_t *file, size_t size, section *out, int max)
{
  (void)size;
  int n = (int)rd32(file + 8);
  if (n > max)
    return -1;
  for (int i = 0; i < n; i++) {
    const uint8_t *e = file + 16 + 32 * i;
    memcpy(out[i].tag, e, 4);
    out[i].flags = rd32(e + 4);
    uint64_t off = rd64(e + 8);
    out[i].size = (size_t)rd64(e + 16);
    out[i].data = malloc(out[i].size ? out[i].size : 1);
    memcpy(out[i].data, file + off, out[i].size);
  }
  return n;
}

static uint8_t *assemble(const section *s, int n, uint32_t version, size_t *out_size)
{
  size_t pos = 16 + 32 * (size_t)n;
  size_t total = pos;
  for (int i = 0; i < n; i++)
    total = ((total + 7) & ~(size_t)7) + s[i].size;
  uint8_t *f = calloc(1, total);
  memcpy(f, "UBK", 4);
  wr32(f + 4, version);
  wr32(f + 8, (uint32_t)n);
  for (int i = 0; i < n; i++) {
    pos = (pos + 7) & ~(size_t)7;
    uint8_t *e = f + 16 + 32 * i;
    memcpy(e, s[i].tag, 4);
    wr32(e + 4, s[i].flags);
    wr64(e + 8, pos);
    wr64(e + 16, s[i].size);
    wr32(e + 24, ub_crc32_update(0, s[i].data, s[i].size));
    memcpy(f + pos, s[i].data, s[i].size);
    pos += s[i].size;
  }
  uint32_t crc = ub_crc32_update(0, f, 12);
  crc = ub_crc32_update(crc, f + 16, 32 * (size_t)n);
  wr32(f + 12, crc);
  *out_size = total;
  return f;
}

static void free_sections(section *s, int n)
{
  for (int i = 0; i < n; i++)
    free(s[i].data);
}

static int find_section(const section *s, int n, const char *tag)
{
  for (int i = 0; i < n; i++)
    if (memcmp(s[i].tag, tag, 4) == 0)
      return i;
  return -1;
}

/* ---------------------------------------------------------------------------------- */
/* Sample bake file: 7 vertices, 4 triangles, 2 atlases.                               */

#define NV 7

static uint32_t rng_state = 12345u;
static float frand(float lo, float hi)
{
  rng_state = rng_state * 1664525u + 1013904223u;
  return lo + (hi - lo) * (float)(rng_state >> 8) / 16777216.0f;
}

static void make_atlas(ub_bakefile_atlas *at, uint32_t w, uint32_t h)
{
  size_t n = (size_t)w * h;
  at->width = w;
  at->height = h;
  at->sh = calloc(n * UB_SH1_FLOATS, sizeof(float));
  at->coverage = calloc(n, 1);
  at->normal = calloc(n * 3, sizeof(float));
  for (size_t i = 0; i < n; i++) {
    at->coverage[i] = (uint8_t)(i % 3);
    for (int k = 0; k < UB_SH1_FLOATS; k++)
      at->sh[i * UB_SH1_FLOATS + k] = frand(-20.0f, 20.0f);
    if (at->coverage[i]) {
      float v[3] = {frand(-1, 1), frand(-1, 1), frand(0.2f, 1)};
      float l = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      for (int c = 0; c < 3; c++)
        at->normal[i * 3 + c] = v[c] / l;
    }
  }
  at->sh[0] = 1e-6f; /* a half subnormal */
  at->sh[1] = -0.0f;
}

static ub_bakefile *make_sample(void)
{
  ub_bakefile *bf = calloc(1, sizeof *bf);
  snprintf(bf->level_name, sizeof bf->level_name, "test_level");
  bf->seed = 42;
  bf->bounces = 3;
  bf->vertex_count = NV; /* vertex 6 unused: GEOM is 300 bytes, a 4-byte gap follows */
  bf->positions = malloc(NV * 3 * sizeof(float));
  for (int i = 0; i < NV * 3; i++)
    bf->positions[i] = frand(-5, 5);
  bf->triangle_count = 4;
  static const uint32_t idx[12] = {0, 1, 2, 2, 1, 3, 3, 4, 5, 0, 5, 4};
  static const int32_t ta[4] = {0, 1, -1, 1};
  bf->indices = malloc(sizeof idx);
  memcpy(bf->indices, idx, sizeof idx);
  bf->tri_atlas = malloc(sizeof ta);
  memcpy(bf->tri_atlas, ta, sizeof ta);
  bf->tri_uv = malloc(4 * 6 * sizeof(float));
  bf->tri_albedo = malloc(4 * 3 * sizeof(float));
  for (int i = 0; i < 24; i++)
    bf->tri_uv[i] = frand(0, 1);
  for (int i = 0; i < 12; i++)
    bf->tri_albedo[i] = frand(0, 0.9f);
  bf->atlas_count = 2;
  bf->atlases = calloc(2, sizeof *bf->atlases);
  make_atlas(&bf->atlases[0], 4, 3);
  make_atlas(&bf->atlases[1], 3, 5); /* 15 texels: 31·15 = 465 bytes, padded to 472 */

  /* Global light grid: 5 probes, 2 tetrahedra sharing a face, 1 leak plane. */
  bf->glg_probe_count = 5;
  bf->glg_positions = malloc(5 * 3 * sizeof(float));
  static const float gp[15] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, 1};
  memcpy(bf->glg_positions, gp, sizeof gp);
  bf->glg_sh = malloc(5 * 27 * sizeof(float));
  for (int i = 0; i < 5 * 27; i++)
    bf->glg_sh[i] = frand(-3, 3);
  bf->glg_tet_count = 2;
  static const uint32_t tets[8] = {0, 1, 2, 3, 1, 2, 3, 4};
  static const int32_t neigh[8] = {1, -1, -1, -1, -1, -1, -1, 0};
  bf->glg_tets = malloc(sizeof tets);
  memcpy(bf->glg_tets, tets, sizeof tets);
  bf->glg_neigh = malloc(sizeof neigh);
  memcpy(bf->glg_neigh, neigh, sizeof neigh);
  bf->glg_plane_count = 1;
  bf->glg_planes = malloc(4 * sizeof(float));
  static const float plane[4] = {0.57735f, 0.57735f, 0.57735f, -0.8f};
  memcpy(bf->glg_planes, plane, sizeof plane);
  bf->glg_plane_of = malloc(2 * sizeof(uint32_t));
  bf->glg_plane_of[0] = 0xffffffffu;
  bf->glg_plane_of[1] = 0;
  return bf;
}

/* The quad y = 0, x, z ∈ [0, 1], one atlas N × N covering it with uv = (x, z). Each texel
 * holds constant radiance L(x, y) = base · (1 + x + 10 y) (uniform over the sphere). */
static ub_bakefile *make_quad(uint32_t n_texels, const float base[3], int with_atlas)
{
  ub_bakefile *bf = calloc(1, sizeof *bf);
  snprintf(bf->level_name, sizeof bf->level_name, "quad");
  bf->vertex_count = 4;
  bf->positions = calloc(12, sizeof(float));
  static const float pos[12] = {0, 0, 0, 1, 0, 0, 0, 0, 1, 1, 0, 1};
  memcpy(bf->positions, pos, sizeof pos);
  bf->triangle_count = 2;
  static const uint32_t idx[6] = {0, 2, 1, 1, 2, 3};
  bf->indices = malloc(sizeof idx);
  memcpy(bf->indices, idx, sizeof idx);
  bf->tri_atlas = malloc(2 * sizeof(int32_t));
  bf->tri_atlas[0] = bf->tri_atlas[1] = with_atlas ? 0 : -1;
  bf->tri_uv = malloc(12 * sizeof(float));
  for (int t = 0; t < 2; t++)
    for (int j = 0; j < 3; j++) {
      const float *p = &pos[idx[t * 3 + j] * 3];
      bf->tri_uv[t * 6 + j * 2 + 0] = p[0];
      bf->tri_uv[t * 6 + j * 2 + 1] = p[2];
    }
  bf->tri_albedo = calloc(6, sizeof(float));
  if (!with_atlas)
    return bf;
  bf->atlas_count = 1;
  bf->atlases = calloc(1, sizeof *bf->atlases);
  ub_bakefile_atlas *at = &bf->atlases[0];
  size_t n = (size_t)n_texels * n_texels;
  at->width = at->height = n_texels;
  at->sh = calloc(n * UB_SH1_FLOATS, sizeof(float));
  at->coverage = malloc(n);
  at->normal = calloc(n * 3, sizeof(float));
  for (uint32_t y = 0; y < n_texels; y++)
    for (uint32_t x = 0; x < n_texels; x++) {
      size_t i = (size_t)y * n_texels + x;
      at->coverage[i] = 1;
      at->normal[i * 3 + 1] = 1.0f;
      for (int c = 0; c < 3; c++) /* L00 = L · 4π · Y00 */
        at->sh[i * UB_SH1_FLOATS + c] =
            (float)(base[c] * (1.0 + x + 10.0 * y) * 4.0 * PI * SH_Y00);
    }
  return bf;
}

/* ---------------------------------------------------------------------------------- */

static void test_crc_and_half(void)
{
  ASSERT_TRUE(ub_crc32_update(0, "123456789", 9) == 0xCBF43926u);
  uint32_t c = ub_crc32_update(0, "1234", 4);
  ASSERT_TRUE(ub_crc32_update(c, "56789", 5) == 0xCBF43926u);
  /* The sliced loop (8 bytes at a time from 64 on) against a bit-at-a-time CRC of the
   * same bytes, over lengths and split points that start and end it anywhere. */
  {
    uint8_t buf[600];
    uint32_t x = 12345u;
    for (size_t i = 0; i < sizeof buf; i++) {
      x = x * 1664525u + 1013904223u;
      buf[i] = (uint8_t)(x >> 24);
    }
    int bad = 0;
    for (size_t n = 0; n <= sizeof buf; n += (n < 140 ? 1 : 37)) {
      uint32_t r = 0xffffffffu;
      for (size_t i = 0; i < n; i++) {
        r ^= buf[i];
        for (int b = 0; b < 8; b++)
          r = (r >> 1) ^ (0xEDB88320u & (0u - (r & 1u)));
      }
      r = ~r;
      bad += ub_crc32_update(0, buf, n) != r;
      size_t cut = n / 3 + 1 < n ? n / 3 + 1 : n;
      bad += ub_crc32_update(ub_crc32_update(0, buf, cut), buf + cut, n - cut) != r;
    }
    ASSERT_TRUE(bad == 0);
  }

  /* Every half converts to a float and back to itself (NaNs stay NaN). */
  int bad_roundtrip = 0, bad_ties = 0;
  for (uint32_t h = 0; h < 0x10000u; h++) {
    float f = ub_half_to_float((uint16_t)h);
    uint16_t back = ub_half_from_float(f);
    if (ub_half_is_finite((uint16_t)h) || (h & 0x3ffu) == 0) {
      if (back != h)
        bad_roundtrip++;
    } else if (!isnan(f) || (back & 0x7c00u) != 0x7c00u || (back & 0x3ffu) == 0) {
      bad_roundtrip++;
    }
  }
  ASSERT_TRUE(bad_roundtrip == 0);
  /* Midpoints between consecutive positive finite halves round to the even one; one float
   * ulp either side rounds to the nearer one. Covers subnormals, the normal boundary and
   * the top of the range (65504 → 65520 midpoint → Inf). */
  for (uint32_t h = 0; h < 0x7c00u; h++) {
    double a = ub_half_to_float((uint16_t)h);
    double b = h + 1 == 0x7c00u ? 65536.0 : ub_half_to_float((uint16_t)(h + 1));
    float mid = (float)((a + b) / 2); /* exact in binary32 */
    uint16_t even = (h & 1u) ? (uint16_t)(h + 1) : (uint16_t)h;
    if (ub_half_from_float(mid) != even)
      bad_ties++;
    if (ub_half_from_float(nextafterf(mid, 0.0f)) != h)
      bad_ties++;
    if (ub_half_from_float(nextafterf(mid, INFINITY)) != h + 1)
      bad_ties++;
    if (ub_half_from_float(-mid) != (uint16_t)(even | 0x8000u))
      bad_ties++;
  }
  ASSERT_TRUE(bad_ties == 0);
  ASSERT_TRUE(ub_half_from_float(65504.0f) == 0x7bffu);
  ASSERT_TRUE(ub_half_from_float(65519.99f) == 0x7bffu);
  ASSERT_TRUE(ub_half_from_float(65520.0f) == 0x7c00u);
  ASSERT_TRUE(ub_half_from_float(1e30f) == 0x7c00u);
  ASSERT_TRUE(ub_half_from_float(-INFINITY) == 0xfc00u);
  ASSERT_TRUE((ub_half_from_float(NAN) & 0x7c00u) == 0x7c00u &&
              (ub_half_from_float(NAN) & 0x3ffu) != 0);
  ASSERT_TRUE(ub_half_from_float(1e-30f) == 0);     /* far below 2^-25 */
  ASSERT_TRUE(ub_half_from_float(1e-40f) == 0);     /* float subnormal */
  ASSERT_TRUE(ub_half_from_float(-1e-40f) == 0x8000u);
  ASSERT_TRUE(ub_half_from_float(5.9604645e-8f) == 1); /* 2^-24, smallest subnormal */
  ASSERT_TRUE(ub_half_from_float(1.0f) == 0x3c00u);
  ASSERT_TRUE(ub_half_from_float(1.0f + 1.0f / 2048) == 0x3c00u); /* tie → even */
  ASSERT_TRUE(ub_half_from_float(1.0f + 3.0f / 2048) == 0x3c02u); /* tie → even */
  /* Relative error of normal halves ≤ 2^-11 (FORMAT.md). */
  double worst = 0;
  for (int i = 0; i < 100000; i++) {
    float f = frand(6.2e-5f, 60000.0f) * (i % 2 ? 1.0f : 1e-3f);
    if (f < 6.2e-5f)
      continue;
    double e = fabs(ub_half_to_float(ub_half_from_float(f)) - (double)f) / f;
    if (e > worst)
      worst = e;
  }
  ASSERT_TRUE(worst <= HALF_REL);
}

static void compare(const ub_bakefile *a, const ub_bakefile *b)
{
  ASSERT_TRUE(strcmp(a->level_name, b->level_name) == 0);
  ASSERT_TRUE(a->seed == b->seed && a->bounces == b->bounces);
  ASSERT_TRUE(a->vertex_count == b->vertex_count && a->triangle_count == b->triangle_count);
  ASSERT_TRUE(memcmp(a->positions, b->positions, a->vertex_count * 12) == 0);
  ASSERT_TRUE(memcmp(a->indices, b->indices, a->triangle_count * 12) == 0);
  ASSERT_TRUE(memcmp(a->tri_atlas, b->tri_atlas, a->triangle_count * 4) == 0);
  ASSERT_TRUE(memcmp(a->tri_uv, b->tri_uv, a->triangle_count * 24) == 0);
  ASSERT_TRUE(memcmp(a->tri_albedo, b->tri_albedo, a->triangle_count * 12) == 0);
  ASSERT_TRUE(a->atlas_count == b->atlas_count);
  for (uint32_t k = 0; k < a->atlas_count && k < b->atlas_count; k++) {
    const ub_bakefile_atlas *x = &a->atlases[k], *y = &b->atlases[k];
    ASSERT_TRUE(x->width == y->width && x->height == y->height);
    size_t n = (size_t)x->width * x->height;
    ASSERT_TRUE(memcmp(x->coverage, y->coverage, n) == 0);
    int link_diff = 0; /* no links = all zero (no separation) */
    for (size_t t = 0; t < n; t++)
      link_diff += (x->link ? x->link[t] : 0) != (y->link ? y->link[t] : 0);
    ASSERT_TRUE(link_diff == 0);
    int bad = 0;
    /* SH storage (runtime/texel_sh.h): the linear band is stored as is (half precision);
     * where the texel has a normal, the DC term is carried by the irradiance along the
     * normal, which comes back to half precision of itself. */
    for (size_t t = 0; t < n; t++) {
      const float *xs = x->sh + t * UB_SH1_FLOATS, *ys = y->sh + t * UB_SH1_FLOATS;
      float un[3], ur[3];
      int has_n = ub_texel_normal(x->normal + 3 * t, un) && ub_texel_normal(y->normal + 3 * t, ur);
      for (int i = has_n ? 3 : 0; i < UB_SH1_FLOATS; i++) {
        double e = fabs((double)xs[i] - ys[i]);
        if (!(e <= HALF_REL * fabs(xs[i]) + 3e-8)) /* 2^-25 absolute for subnormals */
          bad++;
      }
      for (int c = 0; has_n && c < 3; c++) {
        double ex = M_PI * 0.282094791773878143 * xs[c] + ub_texel_sh_linear(xs, un, c);
        double ey = M_PI * 0.282094791773878143 * ys[c] + ub_texel_sh_linear(ys, ur, c);
        if (!(fabs(ex - ey) <= HALF_REL * fabs(ex) + 1e-6))
          bad++;
      }
    }
    for (size_t i = 0; i < n * 3; i++) {
      double e = fabs((double)x->normal[i] - y->normal[i]);
      if (!(e <= HALF_REL * fabs(x->normal[i]) + 3e-8))
        bad++;
    }
    ASSERT_TRUE(bad == 0);
  }
  ASSERT_TRUE(a->glg_probe_count == b->glg_probe_count && a->glg_tet_count == b->glg_tet_count &&
              a->glg_plane_count == b->glg_plane_count);
  if (a->glg_probe_count != b->glg_probe_count || a->glg_tet_count != b->glg_tet_count ||
      a->glg_plane_count != b->glg_plane_count)
    return;
  ASSERT_TRUE(a->glg_probe_count == 0 ||
              memcmp(a->glg_positions, b->glg_positions, a->glg_probe_count * 12) == 0);
  ASSERT_TRUE(a->glg_tet_count == 0 ||
              (memcmp(a->glg_tets, b->glg_tets, a->glg_tet_count * 16) == 0 &&
               memcmp(a->glg_neigh, b->glg_neigh, a->glg_tet_count * 16) == 0 &&
               memcmp(a->glg_plane_of, b->glg_plane_of, a->glg_tet_count * 4) == 0));
  ASSERT_TRUE(a->glg_plane_count == 0 ||
              memcmp(a->glg_planes, b->glg_planes, a->glg_plane_count * 16) == 0);
  int bad = 0;
  for (size_t i = 0; i < (size_t)a->glg_probe_count * 27; i++)
    if (!(fabs((double)a->glg_sh[i] - b->glg_sh[i]) <= HALF_REL * fabs(a->glg_sh[i]) + 3e-8))
      bad++;
  ASSERT_TRUE(bad == 0);
}

static int expect_reject(const uint8_t *data, size_t size)
{
  ub_bakefile *bf = (ub_bakefile *)(uintptr_t)0x1; /* must stay untouched */
  ub_result r = ub_bakefile_read_memory(data, size, "t.ubk", NULL, &bf);
  int ok = r != UB_OK && bf == (ub_bakefile *)(uintptr_t)0x1;
  if (r == UB_OK)
    ub_bakefile_free(bf);
  return ok;
}

/* Texel links (section TXLK, runtime/texel_links.h): a round trip keeps them, a file
 * without them reads back without them, the writer refuses a byte above 3, and the keep
 * rule blends across open links only. */
/* make_sample with texel links (section TXLK) in its first atlas: every link value 0..3. */
static ub_bakefile *make_sample_links(void)
{
  ub_bakefile *bf = make_sample();
  ub_bakefile_atlas *at = &bf->atlases[0];
  size_t n = (size_t)at->width * at->height;
  at->link = malloc(n);
  for (size_t i = 0; at->link && i < n; i++)
    at->link[i] = (uint8_t)(i % 4);
  return bf;
}

static void test_texel_links(void)
{
  ub_bakefile *bf = make_sample_links();
  char p1[512];
  path_in_tmp(p1, sizeof p1, "links.ubk");
  capture cap = {{0}, 0};
  ub_log log = {capture_fn, &cap};
  ub_bakefile_atlas *at = &bf->atlases[0];
  size_t n = (size_t)at->width * at->height;
  ASSERT_OK(ub_bakefile_write(bf, p1, &log));
  ub_bakefile *rd = NULL;
  ASSERT_OK(ub_bakefile_read(p1, &log, &rd));
  if (rd) {
    compare(bf, rd);
    for (uint32_t a = 1; a < rd->atlas_count; a++) /* written as zeros: no separation */
      for (size_t i = 0; rd->atlases[a].link &&
                         i < (size_t)rd->atlases[a].width * rd->atlases[a].height; i++)
        ASSERT_TRUE(rd->atlases[a].link[i] == 0);
  }
  ub_bakefile_free(rd);
  at->link[n / 2] = 4;
  ASSERT_TRUE(ub_bakefile_write(bf, p1, &log) == UB_ERR_INVALID_DATA);
  ASSERT_TRUE(cap.errors == 1 && strstr(cap.last, "section TXLK") != NULL);
  ub_bakefile_free(bf);

  /* 3 × 2 atlas; texel (0,0) separated from (1,0); (1,0) from (1,1) */
  const uint8_t link[6] = {UB_LINK_X, UB_LINK_Y, 0, 0, 0, 0};
  ASSERT_TRUE(ub_texel_links_keep(NULL, 3, 2, 0, 0, 0.3f, 0.3f) == 15u);
  ASSERT_TRUE(ub_texel_links_keep(link, 3, 2, 0, 0, 0.3f, 0.3f) == (1u | 4u | 8u)); /* (0,0) via (0,1),(1,1) */
  ASSERT_TRUE(ub_texel_links_keep(link, 3, 2, 0, 0, 0.7f, 0.3f) == 2u); /* (1,0): both cut */
  ASSERT_TRUE(ub_texel_links_keep(link, 3, 2, 1, 0, 0.3f, 0.7f) == 15u); /* block at x 1..2 */
  const uint8_t wall[6] = {UB_LINK_X, 0, 0, UB_LINK_X, 0, 0}; /* a wall between x 0 and 1 */
  ASSERT_TRUE(ub_texel_links_keep(wall, 3, 2, 0, 0, 0.2f, 0.9f) == 5u);
  ASSERT_TRUE(ub_texel_links_keep(wall, 3, 2, 0, 0, 0.8f, 0.1f) == 10u);
}

static void test_roundtrip_and_corruption(void)
{
  ub_bakefile *bf = make_sample();
  char p1[512], p2[512], p1tmp[520];
  path_in_tmp(p1, sizeof p1, "a.ubk");
  path_in_tmp(p2, sizeof p2, "b.ubk");
  snprintf(p1tmp, sizeof p1tmp, "%s.tmp", p1);
  capture cap = {{0}, 0};
  ub_log log = {capture_fn, &cap};
  ASSERT_OK(ub_bakefile_write(bf, p1, &log));
  ASSERT_TRUE(!file_exists(p1tmp));
  ASSERT_OK(ub_bakefile_write(bf, p2, &log));

  ub_bakefile *rd = NULL;
  ASSERT_OK(ub_bakefile_read(p1, &log, &rd));
  ASSERT_TRUE(rd != NULL);
  if (rd)
    compare(bf, rd);

  /* Re-writing what was read gives the same bytes (halves are a fixed point). */
  size_t s1 = 0, s2 = 0, s3 = 0;
  uint8_t *f1 = slurp(p1, &s1), *f2 = slurp(p2, &s2);
  ASSERT_TRUE(f1 && f2 && s1 == s2 && memcmp(f1, f2, s1) == 0); /* determinism */
  if (rd) {
    ASSERT_OK(ub_bakefile_write(rd, p2, &log));
    uint8_t *f3 = slurp(p2, &s3);
    ASSERT_TRUE(f3 && s3 == s1 && memcmp(f1, f3, s1) == 0);
    free(f3);
  }
  ub_bakefile_free(rd);
  ASSERT_TRUE(cap.errors == 0);

  /* Layout facts from FORMAT.md. */
  ASSERT_TRUE(memcmp(f1, "UBK\0", 4) == 0 && rd32(f1 + 4) == UB_BAKEFILE_VERSION &&
              rd32(f1 + 8) == 4);
  for (int i = 0; i < 4; i++)
    ASSERT_TRUE(rd64(f1 + 16 + 32 * i + 8) % 8 == 0);

  /* Truncation at every length, a flipped byte at every offset (two patterns), a
   * flipped bit at every bit of the header and table: all rejected, none crash. */
  int accepted = 0;
  for (size_t n = 0; n < s1; n++)
    accepted += !expect_reject(f1, n);
  uint8_t *g = malloc(s1 + 8);
  for (size_t i = 0; i < s1; i++) {
    static const uint8_t pats[2] = {0xff, 0x01};
    for (int k = 0; k < 2; k++) {
      memcpy(g, f1, s1);
      g[i] ^= pats[k];
      accepted += !expect_reject(g, s1);
    }
  }
  size_t table_end = 16 + 32 * 4;
  for (size_t bit = 0; bit < table_end * 8; bit++) {
    memcpy(g, f1, s1);
    g[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    accepted += !expect_reject(g, s1);
  }
  /* Trailing bytes (zero or not) are rejected too. */
  memcpy(g, f1, s1);
  memset(g + s1, 0, 8);
  accepted += !expect_reject(g, s1 + 8);
  ASSERT_TRUE(accepted == 0);
  printf("corruption: %zu truncations, %zu byte flips, %zu header bit flips: all rejected\n",
         s1, 2 * s1, table_end * 8);

  /* Wrong magic; future version (even with a valid header CRC); version 0. */
  memcpy(g, f1, s1);
  g[0] = 'X';
  ASSERT_TRUE(ub_bakefile_read_memory(g, s1, "t.ubk", NULL, &rd) == UB_ERR_INVALID_DATA);
  section sec[8];
  int ns = split_file(f1, s1, sec, 8);
  ASSERT_TRUE(ns == 4);
  size_t sz;
  uint8_t *v2 = assemble(sec, ns, UB_BAKEFILE_VERSION + 1, &sz);
  cap.errors = 0;
  ASSERT_TRUE(ub_bakefile_read_memory(v2, sz, "t.ubk", &log, &rd) ==
              UB_ERR_UNSUPPORTED_VERSION);
  ASSERT_TRUE(cap.errors == 1 && strstr(cap.last, "t.ubk") && strstr(cap.last, "version"));
  free(v2);
  v2 = assemble(sec, ns, 0, &sz);
  ASSERT_TRUE(ub_bakefile_read_memory(v2, sz, "t.ubk", NULL, &rd) == UB_ERR_INVALID_DATA);
  free(v2);
  /* Reassembling unchanged sections reproduces the writer's bytes exactly. */
  v2 = assemble(sec, ns, UB_BAKEFILE_VERSION, &sz);
  ASSERT_TRUE(sz == s1 && memcmp(v2, f1, s1) == 0);
  free(v2);

  /* Forward compatibility: an unknown optional section is skipped; an unknown required
   * one makes the file unsupported. */
  section more[5];
  memcpy(more, sec, 4 * sizeof *sec);
  uint8_t extra[13] = "future data!";
  memcpy(more[4].tag, "XTRA", 4);
  more[4].flags = 0;
  more[4].data = extra;
  more[4].size = sizeof extra;
  v2 = assemble(more, 5, UB_BAKEFILE_VERSION, &sz);
  rd = NULL;
  ASSERT_OK(ub_bakefile_read_memory(v2, sz, "t.ubk", NULL, &rd));
  if (rd)
    compare(bf, rd);
  ub_bakefile_free(rd);
  free(v2);
  more[4].flags = 1;
  v2 = assemble(more, 5, UB_BAKEFILE_VERSION, &sz);
  ASSERT_TRUE(ub_bakefile_read_memory(v2, sz, "t.ubk", NULL, &rd) ==
              UB_ERR_UNSUPPORTED_VERSION);
  free(v2);
  /* Section order in the file does not matter; duplicates and missing ones do. */
  section perm[4] = {sec[2], sec[3], sec[0], sec[1]};
  v2 = assemble(perm, 4, UB_BAKEFILE_VERSION, &sz);
  rd = NULL;
  ASSERT_OK(ub_bakefile_read_memory(v2, sz, "t.ubk", NULL, &rd));
  ub_bakefile_free(rd);
  free(v2);
  section dup[5] = {sec[0], sec[1], sec[2], sec[3], sec[1]};
  v2 = assemble(dup, 5, UB_BAKEFILE_VERSION, &sz);
  ASSERT_TRUE(ub_bakefile_read_memory(v2, sz, "t.ubk", NULL, &rd) == UB_ERR_INVALID_DATA);
  free(v2);
  /* GLGP is optional: without it the file reads, with no global light grid. */
  v2 = assemble(sec, 3, UB_BAKEFILE_VERSION, &sz);
  rd = NULL;
  ASSERT_OK(ub_bakefile_read_memory(v2, sz, "t.ubk", NULL, &rd));
  ASSERT_TRUE(rd && rd->glg_probe_count == 0 && rd->glg_positions == NULL);
  ub_bakefile_free(rd);
  free(v2);
  v2 = assemble(sec, 2, UB_BAKEFILE_VERSION, &sz);
  cap.errors = 0;
  ASSERT_TRUE(ub_bakefile_read_memory(v2, sz, "t.ubk", &log, &rd) == UB_ERR_INVALID_DATA);
  ASSERT_TRUE(cap.errors == 1 && strstr(cap.last, "section ATLS") && strstr(cap.last, "missing"));
  free(v2);

  free_sections(sec, ns);
  free(g);
  free(f1);
  free(f2);
  ub_bakefile_free(bf);
}

/* Rewrites one section of a valid file through `edit`, reassembles it with correct CRCs
 * and returns the reader's result (the log message in cap). */
static ub_result read_edited(const uint8_t *file, size_t size, const char *tag,
                             void (*edit)(section *s), capture *cap)
{
  section sec[8];
  int ns = split_file(file, size, sec, 8);
  int k = find_section(sec, ns, tag);
  edit(&sec[k]);
  size_t sz;
  uint8_t *f = assemble(sec, ns, UB_BAKEFILE_VERSION, &sz);
  ub_log log = {capture_fn, cap};
  cap->errors = 0;
  cap->last[0] = 0;
  ub_bakefile *bf = NULL;
  ub_result r = ub_bakefile_read_memory(f, sz, "x.ubk", &log, &bf);
  if (r == UB_OK)
    ub_bakefile_free(bf);
  free(f);
  free_sections(sec, ns);
  return r;
}

static void edit_atls_huge_count(section *s) { wr32(s->data, 0xffffffffu); }
static void edit_atls_huge_atlas(section *s)
{
  wr32(s->data, 1);
  wr32(s->data + 8, 16384);
  wr32(s->data + 12, 16384);
}
static void edit_atls_big_dim(section *s) { wr32(s->data + 8, 16385); }
static void edit_atls_zero_dim(section *s) { wr32(s->data + 12, 0); }
static void edit_geom_huge_vertices(section *s) { wr32(s->data, 0x40000000u); }
static void edit_geom_huge_tris(section *s) { wr32(s->data + 4, 0xffffffffu); }
static void edit_geom_bad_index(section *s) { wr32(s->data + 8 + NV * 12 + 4, 77); }
static void edit_geom_bad_atlas(section *s) { wr32(s->data + 8 + NV * 12 + 4 * 12 + 4, 2); }
static void edit_geom_bad_atlas_neg(section *s)
{
  wr32(s->data + 8 + NV * 12 + 4 * 12, (uint32_t)-2);
}
static void edit_geom_nan_pos(section *s) { wr32(s->data + 8 + 4, 0x7fc00000u); }
static void edit_geom_inf_uv(section *s) { wr32(s->data + 8 + NV * 12 + 4 * 16 + 8, 0x7f800000u); }
static void edit_geom_short(section *s) { s->size -= 4; }
static void edit_meta_name(section *s) { memset(s->data, 'a', 64); }
static void edit_meta_size(section *s) { s->size = 4; }
/* Atlas 0 of the sample is 4 × 3: SH at 8 + 16, normals after 12·12·2 bytes, coverage
 * after 12·3·2 more. */
static void edit_atls_coverage(section *s) { s->data[24 + 12 * 24 + 12 * 6 + 5] = 3; }
static void edit_atls_inf_sh(section *s) { s->data[24 + 7] = 0x7c; s->data[24 + 6] = 0; }
static void edit_atls_nan_normal(section *s) { s->data[24 + 12 * 24 + 3] = 0x7e; }
static void edit_atls_trailing(section *s)
{
  s->size += 8;
  s->data = realloc(s->data, s->size);
  memset(s->data + s->size - 8, 0, 8);
}

/* GLGP of the sample: 16-byte counts, positions 60, tets 32, neigh 32, plane 16,
 * plane_of 8, SH 270. */
static void edit_glgp_huge_probes(section *s) { wr32(s->data, 0x7fffffffu); }
static void edit_glgp_corner(section *s) { wr32(s->data + 16 + 60 + 4 * 5, 9); }
static void edit_glgp_repeat(section *s) { wr32(s->data + 16 + 60 + 4 * 5, 1); }
static void edit_glgp_neigh(section *s) { wr32(s->data + 16 + 60 + 32 + 4 * 3, 2); }
static void edit_glgp_self(section *s) { wr32(s->data + 16 + 60 + 32, 0); }
static void edit_glgp_plane_of(section *s) { wr32(s->data + 16 + 60 + 32 + 32 + 16 + 4, 1); }
static void edit_glgp_inf_plane(section *s) { wr32(s->data + 16 + 60 + 64 + 4, 0x7f800000u); }
static void edit_glgp_nan_sh(section *s) { s->data[s->size - 1] = 0xfe; }
static void edit_glgp_no_probes(section *s)
{
  memset(s->data, 0, 16);
  wr32(s->data + 8, 0); /* 0 probes, 0 tets, 0 planes: valid and empty */
  s->size = 16;
}
static void edit_glgp_tets_no_probes(section *s)
{
  wr32(s->data, 0);
  wr32(s->data + 4, 0);
  wr32(s->data + 8, 1);
  wr32(s->data + 12, 0);
  memset(s->data + 16, 0, 16);
  s->size = 32;
}

static void test_hostile(void)
{
  ub_bakefile *bf = make_sample();
  char p[512];
  path_in_tmp(p, sizeof p, "h.ubk");
  ASSERT_OK(ub_bakefile_write(bf, p, NULL));
  size_t size = 0;
  uint8_t *f = slurp(p, &size);
  ASSERT_TRUE(f != NULL);
  capture cap;

  static const struct {
    const char *tag;
    void (*edit)(section *s);
    const char *expect; /* in the message */
  } cases[] = {
      {"ATLS", edit_atls_huge_count, "atlas count 4294967295"},
      {"ATLS", edit_atls_huge_atlas, "runs past the end"},
      {"ATLS", edit_atls_big_dim, "not in [1, 16384]"},
      {"ATLS", edit_atls_zero_dim, "not in [1, 16384]"},
      {"GEOM", edit_geom_huge_vertices, "does not match"},
      {"GEOM", edit_geom_huge_tris, "does not match"},
      {"GEOM", edit_geom_bad_index, "index 77 >= vertex count 7"},
      {"GEOM", edit_geom_bad_atlas, "atlas 2 not in [-1, 2)"},
      {"GEOM", edit_geom_bad_atlas_neg, "atlas -2 not in [-1, 2)"},
      {"GEOM", edit_geom_nan_pos, "non-finite position"},
      {"GEOM", edit_geom_inf_uv, "non-finite lightmap UV"},
      {"GEOM", edit_geom_short, "does not match"},
      {"META", edit_meta_name, "not NUL-terminated"},
      {"META", edit_meta_size, "size 4"},
      {"ATLS", edit_atls_coverage, "coverage 3"},
      {"ATLS", edit_atls_inf_sh, "non-finite SH"},
      {"ATLS", edit_atls_nan_normal, "non-finite normal"},
      {"ATLS", edit_atls_trailing, "trailing"},
      {"GLGP", edit_glgp_huge_probes, "does not match"},
      {"GLGP", edit_glgp_corner, "tetrahedron 1: corner 9 >= probe count 5"},
      {"GLGP", edit_glgp_repeat, "tetrahedron 1: corner 1 repeated"},
      {"GLGP", edit_glgp_neigh, "tetrahedron 0: neighbour 2 not"},
      {"GLGP", edit_glgp_self, "tetrahedron 0: neighbour 0 not"},
      {"GLGP", edit_glgp_plane_of, "tetrahedron 1: plane 1 >= plane count 1"},
      {"GLGP", edit_glgp_inf_plane, "plane 0 is not finite"},
      {"GLGP", edit_glgp_nan_sh, "probe 4 has a non-finite SH"},
      {"GLGP", edit_glgp_tets_no_probes, "but no probes"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    ub_result r = read_edited(f, size, cases[i].tag, cases[i].edit, &cap);
    char where[32];
    snprintf(where, sizeof where, "x.ubk: section %s: ", cases[i].tag);
    int ok = r == UB_ERR_INVALID_DATA && cap.errors == 1 && strstr(cap.last, where) &&
             strstr(cap.last, cases[i].expect);
    if (!ok)
      fprintf(stderr, "hostile case %zu: result %d, message \"%s\"\n", i, (int)r, cap.last);
    ASSERT_TRUE(ok);
  }

  ASSERT_TRUE(read_edited(f, size, "GLGP", edit_glgp_no_probes, &cap) == UB_OK);

  /* A hostile count must not make the reader allocate: with the address space capped at
   * 512 MiB the huge-atlas case still fails as invalid data, not out of memory. (Skipped
   * under AddressSanitizer, which reserves terabytes of address space.) */
#if defined(__SANITIZE_ADDRESS__)
#define UB_TEST_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define UB_TEST_ASAN 1
#endif
#endif
#ifndef UB_TEST_ASAN
  fflush(NULL);
  pid_t pid = fork();
  if (pid == 0) {
    struct rlimit rl = {512u << 20, 512u << 20};
    setrlimit(RLIMIT_AS, &rl);
    capture c2;
    ub_result r1 = read_edited(f, size, "ATLS", edit_atls_huge_atlas, &c2);
    ub_result r2 = read_edited(f, size, "GEOM", edit_geom_huge_tris, &c2);
    _exit(r1 == UB_ERR_INVALID_DATA && r2 == UB_ERR_INVALID_DATA ? 0 : 1);
  }
  int status = 0;
  waitpid(pid, &status, 0);
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
#endif

  /* ub_bakefile_read: missing file, a directory. */
  ub_bakefile *rd = (ub_bakefile *)(uintptr_t)0x1;
  char missing[512];
  path_in_tmp(missing, sizeof missing, "nope.ubk");
  ub_log log = {capture_fn, &cap};
  cap.errors = 0;
  ASSERT_TRUE(ub_bakefile_read(missing, &log, &rd) == UB_ERR_IO);
  ASSERT_TRUE(cap.errors == 1 && strstr(cap.last, "nope.ubk") && strstr(cap.last, "No such"));
  ASSERT_TRUE(ub_bakefile_read(tmp_dir, NULL, &rd) == UB_ERR_IO);
  ASSERT_TRUE(rd == (ub_bakefile *)(uintptr_t)0x1);

  free(f);
  ub_bakefile_free(bf);
}

static void test_writer_errors(void)
{
  ub_bakefile *bf = make_sample();
  capture cap = {{0}, 0};
  ub_log log = {capture_fn, &cap};
  char p[512], ptmp[520];
  path_in_tmp(p, sizeof p, "bad.ubk");
  snprintf(ptmp, sizeof ptmp, "%s.tmp", p);

  /* NaN / Inf input: invalid data, nothing written. */
  float keep = bf->atlases[1].sh[17];
  bf->atlases[1].sh[17] = NAN;
  ASSERT_TRUE(ub_bakefile_write(bf, p, &log) == UB_ERR_INVALID_DATA);
  ASSERT_TRUE(strstr(cap.last, "bad.ubk: section ATLS: atlas 1") != NULL);
  bf->atlases[1].sh[17] = keep;
  bf->positions[4] = INFINITY;
  ASSERT_TRUE(ub_bakefile_write(bf, p, &log) == UB_ERR_INVALID_DATA);
  bf->positions[4] = 1.0f;
  bf->tri_albedo[2] = NAN;
  ASSERT_TRUE(ub_bakefile_write(bf, p, &log) == UB_ERR_INVALID_DATA);
  bf->tri_albedo[2] = 0.5f;
  bf->indices[3] = NV;
  ASSERT_TRUE(ub_bakefile_write(bf, p, &log) == UB_ERR_INVALID_DATA);
  ASSERT_TRUE(strstr(cap.last, "index 7 >= vertex count 7") != NULL);
  bf->indices[3] = 2;
  bf->glg_sh[30] = -INFINITY;
  ASSERT_TRUE(ub_bakefile_write(bf, p, &log) == UB_ERR_INVALID_DATA);
  ASSERT_TRUE(strstr(cap.last, "bad.ubk: section GLGP: probe 1 has a non-finite SH") != NULL);
  bf->glg_sh[30] = 0.0f;
  ASSERT_TRUE(!file_exists(p) && !file_exists(ptmp));

  /* glg_plane_of NULL: no leak planes, written as "none" for every tetrahedron. */
  uint32_t *plane_of = bf->glg_plane_of;
  bf->glg_plane_of = NULL;
  ASSERT_OK(ub_bakefile_write(bf, p, &log));
  bf->glg_plane_of = plane_of;
  ub_bakefile *rd0 = NULL;
  ASSERT_OK(ub_bakefile_read(p, NULL, &rd0));
  ASSERT_TRUE(rd0 && rd0->glg_plane_of[0] == 0xffffffffu && rd0->glg_plane_of[1] == 0xffffffffu);
  ub_bakefile_free(rd0);
  remove(p);

  /* Texel SH beyond the half range survives through the atlas SH scale (a power of two);
   * other out-of-range finite SH (GLG) is clamped to the half range with a warning. */
  bf->atlases[0].sh[5] = 1e6f;
  cap.last[0] = 0;
  cap.errors = 0;
  ASSERT_OK(ub_bakefile_write(bf, p, &log));
  ASSERT_TRUE(cap.errors == 0 && strstr(cap.last, "clamped") == NULL);
  ub_bakefile *rd = NULL;
  ASSERT_OK(ub_bakefile_read(p, NULL, &rd));
  if (rd)
    ASSERT_NEAR(rd->atlases[0].sh[5], 1e6, 0.0, 1.0 / 2048.0);
  ub_bakefile_free(rd);
  bf->atlases[0].sh[5] = 1.0f;
  if (bf->glg_probe_count) {
    float keep = bf->glg_sh[0];
    bf->glg_sh[0] = 1e6f; /* scaled like the atlases since format 2: no clamp */
    cap.last[0] = 0;
    ASSERT_OK(ub_bakefile_write(bf, p, &log));
    ASSERT_TRUE(strstr(cap.last, "clamped") == NULL);
    rd = NULL;
    ASSERT_OK(ub_bakefile_read(p, NULL, &rd));
    if (rd)
      ASSERT_NEAR(rd->glg_sh[0], 1e6, 0.0, 1.0 / 2048.0);
    ub_bakefile_free(rd);
    bf->glg_sh[0] = keep;
  }

  /* Non-existent directory: I/O error naming the path, no temporary left. */
  char nodir[512], nodir_tmp[520];
  path_in_tmp(nodir, sizeof nodir, "no/such/dir/x.ubk");
  snprintf(nodir_tmp, sizeof nodir_tmp, "%s.tmp", nodir);
  cap.errors = 0;
  ASSERT_TRUE(ub_bakefile_write(bf, nodir, &log) == UB_ERR_IO);
  ASSERT_TRUE(cap.errors == 1 && strstr(cap.last, "no/such/dir/x.ubk") &&
              strstr(cap.last, "No such file"));
  ASSERT_TRUE(!file_exists(nodir_tmp));

  /* The temporary is written but the rename fails (the target is a directory): the
   * temporary is removed and the directory untouched. */
  char isdir[512], isdir_tmp[520];
  path_in_tmp(isdir, sizeof isdir, "dir.ubk");
  snprintf(isdir_tmp, sizeof isdir_tmp, "%s.tmp", isdir);
  mkdir(isdir, 0700);
  cap.errors = 0;
  ASSERT_TRUE(ub_bakefile_write(bf, isdir, &log) == UB_ERR_IO);
  ASSERT_TRUE(cap.errors == 1 && strstr(cap.last, "dir.ubk"));
  ASSERT_TRUE(!file_exists(isdir_tmp));
  rmdir(isdir);

  /* Writing over an existing file replaces it. */
  ASSERT_OK(ub_bakefile_write(bf, p, &log));
  ub_bakefile_free(bf);
}

/* A bake file the reader takes but whose probe grid the run-time cannot use: one error
 * naming the file, UB_ERR_INVALID_DATA (the GLG's own INVALID_ARGUMENT, its messages
 * without the file's name, or none at all before). */
static void test_runtime_bad_glg(void)
{
  char p[512];
  path_in_tmp(p, sizeof p, "bad_glg.ubk");
  for (int k = 0; k < 2; k++) {
    ub_bakefile *bf = make_sample();
    if (k == 0) /* every probe at one point: no volume */
      memset(bf->glg_positions, 0, (size_t)bf->glg_probe_count * 3 * sizeof(float));
    else /* tet 0 names tet 1 its neighbour, tet 1 does not name it back */
      bf->glg_neigh[7] = -1;
    capture cap = {{0}, 0};
    ub_log log = {capture_fn, &cap};
    ASSERT_OK(ub_bakefile_write(bf, p, &log));
    ub_bakefile_free(bf);
    ub_bakefile *back = NULL;
    ASSERT_OK(ub_bakefile_read(p, &log, &back));
    ub_bakefile_free(back);
    cap.errors = 0;
    ub_runtime *rt = NULL;
    ub_result r = ub_runtime_load(p, &log, &rt);
    printf("  run-time on a bad probe grid (%s): %s: %s\n", k ? "one-sided neighbours" : "one point",
           ub_result_string(r), cap.last);
    ASSERT_TRUE(r == UB_ERR_INVALID_DATA && rt == NULL && cap.errors == 1);
    ASSERT_TRUE(strstr(cap.last, p) != NULL);
  }
}

static void test_runtime(void)
{
  const float L[3] = {1.0f, 0.5f, 0.25f};
  capture cap = {{0}, 0};
  ub_log log = {capture_fn, &cap};
  char p[512];
  path_in_tmp(p, sizeof p, "quad.ubk");

  /* Constant radiance over the sphere: E(n) = π L for every normal. */
  ub_bakefile *bf = make_quad(1, L, 1);
  ASSERT_OK(ub_bakefile_write(bf, p, &log));
  ub_bakefile_free(bf);
  ub_runtime *rt = NULL;
  ASSERT_OK(ub_runtime_load(p, &log, &rt));
  ASSERT_TRUE(rt != NULL);
  if (rt) {
    ASSERT_TRUE(ub_runtime_bakefile(rt)->atlas_count == 1);
    static const float normals[4][3] = {{0, 1, 0}, {0, 0, 2}, {1, 1, 1}, {0, -1, 0}};
    for (int k = 0; k < 4; k++) {
      float p0[3] = {0.3f, 0.5f, 0.6f}, rgb[3] = {-1, -1, -1}, dist = -1;
      ASSERT_OK(ub_runtime_query_lightmap(rt, p0, normals[k], rgb, &dist));
      for (int c = 0; c < 3; c++)
        ASSERT_NEAR(rgb[c], PI * L[c], 0, 2 * HALF_REL);
      ASSERT_NEAR(dist, 0.5, 1e-6, 0);
      ASSERT_OK(ub_runtime_texel_irradiance(rt, 0, 0, 0, normals[k], rgb));
      for (int c = 0; c < 3; c++)
        ASSERT_NEAR(rgb[c], PI * L[c], 0, 2 * HALF_REL);
    }
    /* Closest point in the edge and vertex regions. */
    float rgb[3], dist;
    float pe[3] = {2.0f, 1.0f, 0.5f}, pv[3] = {-1.0f, -2.0f, -2.0f}, up[3] = {0, 1, 0};
    ASSERT_OK(ub_runtime_query_lightmap(rt, pe, up, rgb, &dist));
    ASSERT_NEAR(dist, sqrt(2.0), 1e-6, 0);
    ASSERT_OK(ub_runtime_query_lightmap(rt, pv, up, rgb, NULL));
    ASSERT_OK(ub_runtime_query_lightmap(rt, pv, up, rgb, &dist));
    ASSERT_NEAR(dist, 3.0, 1e-6, 0);
    float zero[3] = {0, 0, 0}, nan3[3] = {NAN, 0, 0};
    ASSERT_TRUE(ub_runtime_query_lightmap(rt, pe, zero, rgb, &dist) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_query_lightmap(rt, nan3, up, rgb, &dist) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_texel_irradiance(rt, 1, 0, 0, up, rgb) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_texel_irradiance(rt, 0, 1, 0, up, rgb) == UB_ERR_INVALID_ARGUMENT);
  }
  ub_runtime_free(rt);

  /* 4 × 4 atlas with L(x, y) = L · (1 + x + 10 y): texel centres give their own value,
   * points between centres the bilinear mix; u ↔ x, v ↔ y (FORMAT.md). */
  bf = make_quad(4, L, 1);
  ASSERT_OK(ub_bakefile_write(bf, p, &log));
  ub_bakefile_free(bf);
  rt = NULL;
  ASSERT_OK(ub_runtime_load(p, &log, &rt));
  if (rt) {
    float up[3] = {0, 1, 0}, rgb[3];
    static const float at[][3] = {
        /* u, v, expected factor */
        {0.125f, 0.125f, 1.0f},  {0.375f, 0.125f, 2.0f}, {0.125f, 0.375f, 11.0f},
        {0.875f, 0.875f, 34.0f}, {0.25f, 0.125f, 1.5f},  {0.25f, 0.25f, 6.5f},
        {0.0f, 0.0f, 1.0f},      {1.0f, 1.0f, 34.0f},    {0.3f, 0.6f, 1.0f + 0.7f + 10 * 1.9f},
    };
    for (size_t k = 0; k < sizeof at / sizeof at[0]; k++) {
      float q[3] = {at[k][0], 0.25f, at[k][1]};
      ASSERT_OK(ub_runtime_query_lightmap(rt, q, up, rgb, NULL));
      for (int c = 0; c < 3; c++)
        ASSERT_NEAR(rgb[c], PI * L[c] * at[k][2], 0, 2 * HALF_REL);
    }
    ASSERT_OK(ub_runtime_texel_irradiance(rt, 0, 2, 3, up, rgb));
    ASSERT_NEAR(rgb[0], PI * L[0] * 33.0, 0, 2 * HALF_REL);
  }
  ub_runtime_free(rt);

  /* Dilated padding (here without stored normals, and with SH of its own in the file)
   * shows the covered texel it copies, its nearest: both padding texels show texel (0, 0),
   * exact along that texel's normal. */
  bf = make_quad(2, L, 1);
  {
    ub_bakefile_atlas *at = &bf->atlases[0];
    float w[3] = {0.6f, 0.8f, 0.0f}, Ld[3] = {5.0f, 4.0f, 3.0f};
    for (int i = 0; i < 4; i++) {
      ub_sh1_add(&at->sh[i * UB_SH1_FLOATS], w, Ld, 4.0f);
      at->normal[i * 3 + 1] = 0.0f;
    }
    at->normal[0 * 3 + 2] = 1.0f; /* texel (0, 0): covered, normal +Z */
    at->coverage[1] = 2;          /* texel (1, 0): dilated, no normal → +Z */
    at->coverage[2] = 0;          /* texel (0, 1): empty */
    at->coverage[3] = 2;          /* texel (1, 1): dilated, no normal → +Z */
  }
  ASSERT_OK(ub_bakefile_write(bf, p, &log));
  ub_bakefile_free(bf);
  rt = NULL;
  ASSERT_OK(ub_runtime_load(p, &log, &rt));
  ub_bakefile *fr = NULL; /* the file's float SH (the run-time keeps its halves) */
  ASSERT_OK(ub_bakefile_read(p, &log, &fr));
  if (rt && fr) {
    const ub_bakefile_atlas *at = &fr->atlases[0];
    ASSERT_TRUE(ub_runtime_bakefile(rt)->atlases[0].sh == NULL);
    /* the stored normals, kept as the file's halves: the reader's values exactly */
    ASSERT_TRUE(ub_runtime_bakefile(rt)->atlases[0].normal == NULL);
    for (uint32_t t = 0; t < 4; t++) { /* padding: its source's (texel 0); empty: zero */
      float nn[3];
      static const float zero[3] = {0, 0, 0};
      ASSERT_OK(ub_runtime_texel_normal(rt, 0, t % 2, t / 2, nn));
      const float *want = at->coverage[t] == 0   ? zero
                          : at->coverage[t] == 1 ? &at->normal[3 * t]
                                                 : &at->normal[0];
      ASSERT_TRUE(memcmp(nn, want, sizeof nn) == 0);
    }
    float nx[3];
    uint32_t sx0 = 0, sy0 = 0;
    ASSERT_TRUE(ub_runtime_texel_normal(rt, 0, 2, 0, nx) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_texel_normal(rt, 1, 0, 0, nx) == UB_ERR_INVALID_ARGUMENT);
    float nz[3] = {0, 0, 1}, rgb[3], ref[3];
    for (uint32_t t = 0; t < 4; t++) {
      uint32_t sx = 9, sy = 9;
      ub_result rs = ub_runtime_texel_source(rt, 0, t % 2, t / 2, &sx, &sy);
      ASSERT_TRUE(at->coverage[t] ? rs == UB_OK && sx == 0 && sy == 0
                                  : rs == UB_ERR_NOT_BAKED && sx == 9 && sy == 9);
      ASSERT_OK(ub_runtime_texel_irradiance(rt, 0, t % 2, t / 2, nz, rgb));
      if (at->coverage[t])
        ub_sh1_irradiance(&at->sh[0], nz, ref); /* texel (0, 0)'s */
      else
        ref[0] = ref[1] = ref[2] = 0.0f;
      for (int c = 0; c < 3; c++)
        ASSERT_NEAR(rgb[c], ref[c], 1e-5, 1e-5);
    }
    ASSERT_TRUE(ub_runtime_texel_source(rt, 0, 2, 0, &sx0, &sy0) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_texel_source(rt, 1, 0, 0, &sx0, &sy0) == UB_ERR_INVALID_ARGUMENT);
    /* A query over the empty texel's quarter blends the three non-empty ones only. */
    float q[3] = {0.25f, 0.1f, 0.75f};
    ASSERT_OK(ub_runtime_query_lightmap(rt, q, nz, rgb, NULL));
    ASSERT_TRUE(rgb[0] > 0.0f);
  }
  ub_bakefile_free(fr);
  ub_runtime_free(rt);

  /* Padding no texel reaches through padding (a file may hold any shape): shows nothing.
   * 3 × 3: texel (0, 0) covered, (1, 0) padding next to it, (2, 2) padding alone among
   * empty pixels. */
  bf = make_quad(3, L, 1);
  for (int i = 0; i < 9; i++)
    bf->atlases[0].coverage[i] = 0;
  bf->atlases[0].coverage[0] = 1;
  bf->atlases[0].coverage[1] = 2;
  bf->atlases[0].coverage[8] = 2;
  ASSERT_OK(ub_bakefile_write(bf, p, &log));
  ub_bakefile_free(bf);
  rt = NULL;
  ASSERT_OK(ub_runtime_load(p, &log, &rt));
  if (rt) {
    uint32_t sx = 9, sy = 9;
    float nz[3] = {0, 1, 0}, rgb[3] = {1, 1, 1}, own[3];
    ASSERT_OK(ub_runtime_texel_source(rt, 0, 1, 0, &sx, &sy));
    ASSERT_TRUE(sx == 0 && sy == 0);
    ASSERT_TRUE(ub_runtime_texel_source(rt, 0, 2, 2, &sx, &sy) == UB_ERR_NOT_BAKED);
    ASSERT_OK(ub_runtime_texel_irradiance(rt, 0, 2, 2, nz, rgb));
    ASSERT_TRUE(rgb[0] == 0.0f && rgb[1] == 0.0f && rgb[2] == 0.0f);
    ASSERT_OK(ub_runtime_texel_irradiance(rt, 0, 1, 0, nz, rgb));
    ASSERT_OK(ub_runtime_texel_irradiance(rt, 0, 0, 0, nz, own));
    ASSERT_TRUE(memcmp(rgb, own, sizeof rgb) == 0 && own[0] > 0.0f);
  }
  ub_runtime_free(rt);

  /* No atlases: loads, but lightmap queries say "not baked". */
  bf = make_quad(1, L, 0);
  ASSERT_OK(ub_bakefile_write(bf, p, &log));
  ub_bakefile_free(bf);
  rt = NULL;
  ASSERT_OK(ub_runtime_load(p, &log, &rt));
  if (rt) {
    float q[3] = {0.5f, 1, 0.5f}, up[3] = {0, 1, 0}, rgb[3] = {7, 7, 7}, dist = 7;
    ASSERT_TRUE(ub_runtime_query_lightmap(rt, q, up, rgb, &dist) == UB_ERR_NOT_BAKED);
    ASSERT_TRUE(rgb[0] == 7 && dist == 7);
  }
  ub_runtime_free(rt);
  ub_runtime_free(NULL);
  ASSERT_TRUE(cap.errors == 0);

  /* Load failure leaves *out untouched. */
  ub_runtime *keep = (ub_runtime *)(uintptr_t)0x1;
  char missing[512];
  path_in_tmp(missing, sizeof missing, "missing.ubk");
  ASSERT_TRUE(ub_runtime_load(missing, NULL, &keep) == UB_ERR_IO);
  ASSERT_TRUE(keep == (ub_runtime *)(uintptr_t)0x1);
}

/* UB_WRITE_FUZZ_CORPUS=DIR: writes the seed files of tests/fuzz/corpus-fuzz_ubk. */
static void write_corpus(const char *dir)
{
  char p[512];
  const float L[3] = {1.0f, 0.5f, 0.25f};
  ub_bakefile *bf = make_sample();
  snprintf(p, sizeof p, "%s/sample.ubk", dir);
  ASSERT_OK(ub_bakefile_write(bf, p, NULL));
  ub_bakefile_free(bf);
  bf = make_quad(2, L, 1);
  snprintf(p, sizeof p, "%s/quad.ubk", dir);
  ASSERT_OK(ub_bakefile_write(bf, p, NULL));
  ub_bakefile_free(bf);
  bf = make_sample_links();
  snprintf(p, sizeof p, "%s/links.ubk", dir);
  ASSERT_OK(ub_bakefile_write(bf, p, NULL));
  ub_bakefile_free(bf);
}

/* Removes every file the tests left in dir, then dir (a fixed list of names missed files
 * added later: links, bright and halves stayed behind, and so did the directory). */
static void remove_tree(const char *dir)
{
  if (ub_remove_dir(dir) != 0)
    fprintf(stderr, "test_bakefile: could not remove %s: %s\n", dir, strerror(errno));
}

/* Probe and record SH far beyond the half range (a sun of 1e6 W/m²) round-trip within
 * half precision (2^-11 relative, 1e-3 with margin) thanks to the sections' power-of-two
 * scales, instead of clamping at 65504. */
/* One DLS record (no receivers yet) named name, added to a bake file without any. */
static ub_bakefile_record *add_dls_record(ub_bakefile *bf, const char *name)
{
  bf->dls_count = 1;
  bf->dls = calloc(1, sizeof *bf->dls);
  ub_bakefile_record *r = &bf->dls[0];
  snprintf(r->name, sizeof r->name, "%s", name);
  r->parent[0] = r->parent[1] = -1;
  return r;
}

static void test_bright_sections(void)
{
  ub_bakefile *bf = make_sample();
  for (int i = 0; i < 5 * 27; i++)
    bf->glg_sh[i] = (i % 2 ? 1.0f : -1.0f) * (float)(1e6 * (1 + i % 7));
  ub_bakefile_record *r = add_dls_record(bf, "sun");
  r->probe_count = 2;
  r->probe_index = malloc(2 * sizeof(uint32_t));
  r->probe_index[0] = 1;
  r->probe_index[1] = 4;
  r->probe_sh = malloc(2 * 27 * sizeof(float));
  for (int i = 0; i < 54; i++)
    r->probe_sh[i] = (float)(3e5 + 1e4 * i);
  char path[1200];
  snprintf(path, sizeof path, "%s/bright.ubk", tmp_dir);
  ASSERT_OK(ub_bakefile_write(bf, path, NULL));
  ub_bakefile *rd = NULL;
  ASSERT_OK(ub_bakefile_read(path, NULL, &rd));
  if (rd) {
    for (int i = 0; i < 5 * 27; i++)
      ASSERT_NEAR(rd->glg_sh[i], bf->glg_sh[i], 0, 1e-3);
    ASSERT_TRUE(rd->dls_count == 1);
    for (int i = 0; rd->dls_count == 1 && i < 54; i++)
      ASSERT_NEAR(rd->dls[0].probe_sh[i], r->probe_sh[i], 0, 1e-3);
  }
  ub_bakefile_free(rd);
  ub_bakefile_free(bf);
}

/* UB_BAKEFILE_RECORD_HALVES: the records' values as the file's halves and scale; a plain
 * read's floats are those halves times the scale (texel rows then unpacked from the I_z
 * form along the pixel's stored normal), bit for bit; such a bake file is not written. */
static void test_record_halves(void)
{
  ub_bakefile *bf = make_sample();
  ub_bakefile_record *r = add_dls_record(bf, "lamp");
  r->light_count = 1;
  const uint32_t tp[5] = {0, 1, 2, 5, 13}; /* empty, covered, padding... pixels of both atlases */
  r->texel_count = 5;
  r->texel_index = malloc(sizeof tp);
  memcpy(r->texel_index, tp, sizeof tp);
  r->texel_sh = malloc(5 * 12 * sizeof(float));
  for (int i = 0; i < 60; i++)
    r->texel_sh[i] = frand(-5e5f, 5e5f); /* beyond the half range: a scale > 1 */
  r->probe_count = 2;
  r->probe_index = malloc(2 * sizeof(uint32_t));
  r->probe_index[0] = 0;
  r->probe_index[1] = 3;
  r->probe_sh = malloc(54 * sizeof(float));
  for (int i = 0; i < 54; i++)
    r->probe_sh[i] = frand(-7.0f, 7.0f);
  char path[1200], back[1200];
  snprintf(path, sizeof path, "%s/halves.ubk", tmp_dir);
  snprintf(back, sizeof back, "%s/halves_back.ubk", tmp_dir);
  ASSERT_OK(ub_bakefile_write(bf, path, NULL));
  ub_bakefile *fl = NULL, *hf = NULL;
  ASSERT_OK(ub_bakefile_read(path, NULL, &fl));
  ASSERT_OK(ub_bakefile_read_ex(path, NULL, UB_BAKEFILE_RECORD_HALVES, &hf));
  if (fl && hf && fl->dls_count == 1 && hf->dls_count == 1) {
    const ub_bakefile_record *a = &fl->dls[0], *b = &hf->dls[0];
    ASSERT_TRUE(!b->texel_sh && !b->probe_sh && b->texel_sh_half && b->probe_sh_half);
    ASSERT_TRUE(!a->texel_sh_half && !a->probe_sh_half && b->sh_half_scale > 1.0f);
    int bad = 0;
    for (uint32_t i = 0; i < b->texel_count; i++) {
      float row[12];
      for (int k = 0; k < 12; k++)
        row[k] = ub_half_to_float(b->texel_sh_half[12 * i + k]) * b->sh_half_scale;
      uint32_t px = b->texel_index[i], at = px < 12 ? 0 : 1, loc = at ? px - 12 : px;
      float un[3];
      if (ub_texel_normal(&hf->atlases[at].normal[3 * loc], un))
        ub_texel_sh_unpack(row, un);
      bad += memcmp(row, &a->texel_sh[12 * i], sizeof row) != 0;
    }
    for (uint32_t i = 0; i < 54; i++)
      bad += ub_half_to_float(b->probe_sh_half[i]) * b->sh_half_scale != a->probe_sh[i];
    ASSERT_TRUE(bad == 0);
    ASSERT_TRUE(ub_bakefile_write(hf, back, NULL) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(!file_exists(back));
  }
  ub_bakefile_free(fl);
  ub_bakefile_free(hf);
  ub_bakefile_free(bf);
}

int main(void)
{
  const char *base = getenv("TMPDIR");
  snprintf(tmp_dir, sizeof tmp_dir, "%s/ubake_test_bakefile_XXXXXX", base ? base : "/tmp");
  if (!mkdtemp(tmp_dir)) {
    fprintf(stderr, "mkdtemp: %s\n", strerror(errno));
    return 1;
  }
  test_crc_and_half();
  test_roundtrip_and_corruption();
  test_texel_links();
  test_hostile();
  test_writer_errors();
  test_runtime();
  test_runtime_bad_glg();
  test_bright_sections();
  test_record_halves();
  const char *corpus = getenv("UB_WRITE_FUZZ_CORPUS");
  if (corpus)
    write_corpus(corpus);
  remove_tree(tmp_dir);
  TEST_MAIN_END();
}
