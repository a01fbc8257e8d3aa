/* tests/test_llg_share.c — instances of one mesh share the LLG self-visibility.
 *
 * Level (written here as glTF + .bin): a 6 × 6 m floor, a constant sky, a static point
 * light, and an L-shaped prop (a 0.6 × 0.1 × 0.6 m base with a 0.1 m thick, 0.5 m tall
 * wall on one edge: the base's top is half-hidden by the wall) as LLG receivers:
 *   shared: prop_a and prop_b use the same glTF mesh, prop_b rotated 90° about y;
 *           prop_c uses it too but scaled 1.5× along y (not a similarity: must not share);
 *   copies: the same, but prop_b uses a second mesh with identical data (no sharing).
 * Checks:
 *   - ub_llg_sh_rotation: exact for band-limited functions (vs direct evaluation at random
 *     directions), identity, a reflection, composition;
 *   - shared bake: prop_b carries prop_a's visibility (vis_shared_from = 1), prop_c does
 *     not; copies bake: nobody shares;
 *   - the LLGM section of the shared file is smaller by exactly the stored visibility of
 *     prop_b (18 bytes per vertex) minus the larger model headers (40 bytes per model),
 *     up to the 8-byte padding;
 *   - shading: prop_b's per-vertex irradiance (grid × visibility + self term, its own
 *     vertex data) in the shared file vs the copies file: mean relative difference
 *     < 3% and every vertex within 15% (the two visibilities are independent 256-ray
 *     estimates in different frames: Monte Carlo noise only, see the printed figures);
 *   - a hand-built two-model file: byte-identical round trip, shared visibility expanded
 *     by the reader, and hostile sharing fields refused (source later / itself / itself
 *     shared, vertex counts differ, rotation not orthonormal, unknown flags). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "runtime/crc32.h"
#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/llg.h"
#include "ubake/sh.h"

static void test_log(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  if (level <= UB_LOG_WARNING)
    fprintf(stderr, "%s: %s\n", level == UB_LOG_ERROR ? "error" : "warning", msg);
}
static const ub_log g_log = {test_log, NULL};

/* ---- SH rotation ------------------------------------------------------------------- */

static void rot_axis(const double ax[3], double ang, float R[9])
{
  double l = sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2]);
  double x = ax[0] / l, y = ax[1] / l, z = ax[2] / l, c = cos(ang), s = sin(ang), t = 1 - c;
  double m[9] = {t * x * x + c,     t * x * y - s * z, t * x * z + s * y,
                 t * x * y + s * z, t * y * y + c,     t * y * z - s * x,
                 t * x * z - s * y, t * y * z + s * x, t * z * z + c};
  for (int k = 0; k < 9; k++)
    R[k] = (float)m[k];
}

static void test_rotation(void)
{
  float c[9];
  for (int k = 0; k < 9; k++)
    c[k] = (float)(0.3 + 0.7 * sin(1.7 * k + 0.4));
  double ax[3] = {0.3, -0.8, 0.5};
  float R[9], M[81], out[9];
  rot_axis(ax, 1.1, R);
  float refl[9] = {1, 0, 0, 0, -1, 0, 0, 0, 1}; /* mirror y */
  float *mats[2] = {R, refl};
  double worst = 0.0;
  for (int t = 0; t < 2; t++) {
    ub_llg_sh_rotation(mats[t], M);
    ub_llg_sh_rotate(M, c, out);
    uint32_t h = 12345;
    for (int i = 0; i < 200; i++) {
      float d[3], rd[3], y[9], yr[9];
      for (int k = 0; k < 3; k++) {
        h = h * 1664525u + 1013904223u;
        d[k] = (float)((h >> 8) * (1.0 / 16777216.0)) * 2.0f - 1.0f;
      }
      float l = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      if (l < 0.1f)
        continue;
      for (int k = 0; k < 3; k++)
        d[k] /= l;
      const float *Q = mats[t];
      for (int k = 0; k < 3; k++) /* Rᵀ d */
        rd[k] = Q[k] * d[0] + Q[3 + k] * d[1] + Q[6 + k] * d[2];
      ub_sh2_eval_basis(d, y);
      ub_sh2_eval_basis(rd, yr);
      double g = 0, f = 0;
      for (int k = 0; k < 9; k++) {
        g += out[k] * y[k];
        f += c[k] * yr[k];
      }
      worst = fmax(worst, fabs(g - f));
    }
  }
  printf("  SH rotation: worst |g(ω) − f(Rᵀω)| over 400 directions = %.2e\n", worst);
  ASSERT_TRUE(worst < 1e-5);
  float I[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  ub_llg_sh_rotation(I, M);
  for (int k = 0; k < 81; k++)
    ASSERT_NEAR(M[k], k % 10 == 0 ? 1.0 : 0.0, 1e-6, 0);
  /* composition: M(R1·R2) = M(R1)·M(R2) */
  float R2[9], R12[9], M1[81], M2[81], M12[81];
  double ax2[3] = {1, 0.2, 0};
  rot_axis(ax2, -0.7, R2);
  for (int r = 0; r < 3; r++)
    for (int cc = 0; cc < 3; cc++)
      R12[3 * r + cc] = R[3 * r] * R2[cc] + R[3 * r + 1] * R2[3 + cc] + R[3 * r + 2] * R2[6 + cc];
  ub_llg_sh_rotation(R, M1);
  ub_llg_sh_rotation(R2, M2);
  ub_llg_sh_rotation(R12, M12);
  double wc = 0.0;
  for (int r = 0; r < 9; r++)
    for (int cc = 0; cc < 9; cc++) {
      double s = 0;
      for (int k = 0; k < 9; k++)
        s += (double)M1[9 * r + k] * M2[9 * k + cc];
      wc = fmax(wc, fabs(s - M12[9 * r + cc]));
    }
  printf("  SH rotation: composition error %.2e\n", wc);
  ASSERT_TRUE(wc < 1e-5);
}

/* ---- level writer -------------------------------------------------------------------- */

typedef struct mesh_buf {
  float *pos, *nrm;
  uint32_t *idx;
  uint32_t nv, ni;
} mesh_buf;

static void quad_grid(mesh_buf *m, const double o[3], const double eu[3], const double ev[3],
                      int nu, int nv)
{
  double n[3] = {eu[1] * ev[2] - eu[2] * ev[1], eu[2] * ev[0] - eu[0] * ev[2],
                 eu[0] * ev[1] - eu[1] * ev[0]};
  double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  uint32_t base = m->nv;
  m->pos = realloc(m->pos, (m->nv + (size_t)(nu + 1) * (nv + 1)) * 3 * sizeof(float));
  m->nrm = realloc(m->nrm, (m->nv + (size_t)(nu + 1) * (nv + 1)) * 3 * sizeof(float));
  m->idx = realloc(m->idx, (m->ni + (size_t)nu * nv * 6) * sizeof(uint32_t));
  for (int j = 0; j <= nv; j++)
    for (int i = 0; i <= nu; i++) {
      for (int k = 0; k < 3; k++) {
        m->pos[3 * m->nv + k] = (float)(o[k] + eu[k] * i / nu + ev[k] * j / nv);
        m->nrm[3 * m->nv + k] = (float)(n[k] / l);
      }
      m->nv++;
    }
  for (int j = 0; j < nv; j++)
    for (int i = 0; i < nu; i++) {
      uint32_t a = base + (uint32_t)(j * (nu + 1) + i), b = a + 1, c = a + (uint32_t)nu + 1,
               d = c + 1;
      uint32_t t[6] = {a, b, d, a, d, c};
      memcpy(m->idx + m->ni, t, sizeof t);
      m->ni += 6;
    }
}

static int divs(double len)
{
  int n = (int)ceil(len / 0.1 - 1e-9);
  return n < 1 ? 1 : n;
}

/* Closed box [lo, hi], outward faces, ~0.1 m quads. */
static void box(mesh_buf *m, const double lo[3], const double hi[3])
{
  for (int a = 0; a < 3; a++)
    for (int sd = 0; sd < 2; sd++) {
      int u = (a + 1) % 3, v = (a + 2) % 3;
      double o[3], eu[3] = {0, 0, 0}, ev[3] = {0, 0, 0};
      o[a] = sd ? hi[a] : lo[a];
      o[u] = lo[u];
      o[v] = lo[v];
      eu[u] = hi[u] - lo[u];
      ev[v] = hi[v] - lo[v];
      if (!sd) { /* flip: normal along −a */
        o[u] = hi[u];
        eu[u] = -eu[u];
      }
      quad_grid(m, o, eu, ev, divs(fabs(eu[u])), divs(ev[v]));
    }
}

static void floats(FILE *f, const float *v, int n)
{
  for (int i = 0; i < n; i++)
    fprintf(f, "%s%.9g", i ? "," : "", (double)v[i]);
}

/* shared: prop_b uses mesh 1 (else mesh 2, a copy); prop_c (scaled) only when shared. */
static int write_level(const char *dir, const char *name, int shared, char *out, size_t cap)
{
  mesh_buf fl = {0}, pr = {0};
  double o[3] = {-3, 0, 3}, eu[3] = {6, 0, 0}, ev[3] = {0, 0, -6};
  quad_grid(&fl, o, eu, ev, 1, 1);
  double b0[3] = {-0.3, 0, -0.3}, b1[3] = {0.3, 0.1, 0.3};
  double w0[3] = {-0.3, 0.1, -0.3}, w1[3] = {-0.2, 0.6, 0.3};
  box(&pr, b0, b1);
  box(&pr, w0, w1);
  char bin[1200];
  snprintf(bin, sizeof bin, "%s/%s.bin", dir, name);
  if (snprintf(out, cap, "%s/%s.gltf", dir, name) >= (int)cap)
    return 0;
  FILE *fb = fopen(bin, "wb");
  if (!fb)
    return 0;
  mesh_buf *ms[2] = {&fl, &pr};
  size_t off[2][3], len[2][3], at = 0;
  for (int k = 0; k < 2; k++) {
    len[k][0] = len[k][1] = ms[k]->nv * 12u;
    len[k][2] = ms[k]->ni * 4u;
    off[k][0] = at;
    at += fwrite(ms[k]->pos, 1, len[k][0], fb);
    off[k][1] = at;
    at += fwrite(ms[k]->nrm, 1, len[k][1], fb);
    off[k][2] = at;
    at += fwrite(ms[k]->idx, 1, len[k][2], fb);
  }
  fclose(fb);
  FILE *f = fopen(out, "w");
  if (!f)
    return 0;
  fprintf(f, "{\"asset\":{\"version\":\"2.0\"},\"extensionsUsed\":[\"KHR_lights_punctual\"],"
             "\"extensions\":{\"KHR_lights_punctual\":{\"lights\":[{\"type\":\"point\","
             "\"intensity\":20,\"color\":[1,1,1]}]}},"
             "\"scene\":0,\"scenes\":[{\"nodes\":[0,1,2,3%s],\"extras\":{\"ubake_sky\":"
             "[0.3,0.35,0.4],\"ubake_texel_size\":0.25,\"ubake_glg_spacing\":2}}],"
             "\"nodes\":[{\"name\":\"floor\",\"mesh\":0},"
             "{\"name\":\"prop_a\",\"mesh\":1,\"translation\":[-1.2,0,0],"
             "\"extras\":{\"ubake_receiver\":\"llg\"}},"
             "{\"name\":\"prop_b\",\"mesh\":%d,\"translation\":[1.2,0,0],"
             "\"rotation\":[0,0.70710678,0,0.70710678],\"extras\":{\"ubake_receiver\":\"llg\"}},"
             "{\"name\":\"lamp\",\"translation\":[0.2,2.5,0.8],\"extras\":{\"ubake_light\":"
             "\"static\"},\"extensions\":{\"KHR_lights_punctual\":{\"light\":0}}}%s],"
             "\"materials\":[{\"pbrMetallicRoughness\":{\"baseColorFactor\":[0.5,0.5,0.5,1]}},"
             "{\"pbrMetallicRoughness\":{\"baseColorFactor\":[0.7,0.6,0.5,1]}}],\"meshes\":[",
          shared ? ",4" : "", shared ? 1 : 2,
          shared ? ",{\"name\":\"prop_c\",\"mesh\":1,\"translation\":[0,0,1.8],\"scale\":[1,1.5,1],"
                   "\"extras\":{\"ubake_receiver\":\"llg\"}}"
                 : "");
  for (int k = 0; k < 3; k++) {
    int a = k ? 1 : 0;
    fprintf(f, "%s{\"primitives\":[{\"attributes\":{\"POSITION\":%d,\"NORMAL\":%d},"
               "\"indices\":%d,\"material\":%d}]}",
            k ? "," : "", 3 * a, 3 * a + 1, 3 * a + 2, a);
  }
  fprintf(f, "],\"buffers\":[{\"uri\":\"%s.bin\",\"byteLength\":%zu}],\"bufferViews\":[", name,
          at);
  for (int k = 0; k < 2; k++)
    for (int j = 0; j < 3; j++)
      fprintf(f, "%s{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%zu}", k || j ? "," : "",
              off[k][j], len[k][j]);
  fprintf(f, "],\"accessors\":[");
  for (int k = 0; k < 2; k++) {
    float mn[3] = {1e30f, 1e30f, 1e30f}, mx[3] = {-1e30f, -1e30f, -1e30f};
    for (uint32_t v = 0; v < ms[k]->nv; v++)
      for (int c = 0; c < 3; c++) {
        mn[c] = fminf(mn[c], ms[k]->pos[3 * v + c]);
        mx[c] = fmaxf(mx[c], ms[k]->pos[3 * v + c]);
      }
    fprintf(f, "%s{\"bufferView\":%d,\"componentType\":5126,\"count\":%u,\"type\":\"VEC3\","
               "\"min\":[",
            k ? "," : "", 3 * k, ms[k]->nv);
    floats(f, mn, 3);
    fprintf(f, "],\"max\":[");
    floats(f, mx, 3);
    fprintf(f, "]},{\"bufferView\":%d,\"componentType\":5126,\"count\":%u,\"type\":\"VEC3\"},"
               "{\"bufferView\":%d,\"componentType\":5125,\"count\":%u,\"type\":\"SCALAR\"}",
            3 * k + 1, ms[k]->nv, 3 * k + 2, ms[k]->ni);
  }
  fprintf(f, "]}\n");
  fclose(f);
  for (int k = 0; k < 2; k++) {
    free(ms[k]->pos);
    free(ms[k]->nrm);
    free(ms[k]->idx);
  }
  return 1;
}

static uint8_t *read_all(const char *path, size_t *out_n)
{
  FILE *f = fopen(path, "rb");
  if (!f)
    return NULL;
  fseek(f, 0, SEEK_END);
  long n = ftell(f);
  fseek(f, 0, SEEK_SET);
  uint8_t *b = malloc((size_t)n + 1);
  if (b && fread(b, 1, (size_t)n, f) != (size_t)n) {
    free(b);
    b = NULL;
  }
  fclose(f);
  *out_n = (size_t)n;
  return b;
}

/* Offset, size and table entry of section tag in a .ubk image; 0 if absent. */
static size_t find_section(const uint8_t *b, const char *tag, size_t *out_size, size_t *entry)
{
  uint32_t ns;
  memcpy(&ns, b + 8, 4);
  for (uint32_t i = 0; i < ns; i++) {
    const uint8_t *e = b + 16 + 32 * (size_t)i;
    if (!memcmp(e, tag, 4)) {
      uint64_t o, s;
      memcpy(&o, e + 8, 8);
      memcpy(&s, e + 16, 8);
      *out_size = (size_t)s;
      if (entry)
        *entry = 16 + 32 * (size_t)i;
      return (size_t)o;
    }
  }
  *out_size = 0;
  return 0;
}

static int32_t model_named(const ub_bakefile *bf, const char *name)
{
  for (uint32_t i = 0; i < bf->llg_count; i++)
    if (!strcmp(bf->llgs[i].name, name))
      return (int32_t)i;
  return -1;
}

static double lum(const float *c) { return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]; }

static void vertex_irradiance(const ub_bakefile_llg *m, uint32_t v, float out[3])
{
  float L[27];
  ub_llg_grid_sample(m->center, m->axes, m->half, m->dims, m->probe_sh,
                     m->positions + 3 * (size_t)v, L);
  ub_llg_irradiance(L, m->vis + 9 * (size_t)v, m->self + 3 * (size_t)v,
                    m->normals + 3 * (size_t)v, out);
}

static void test_bakes(const char *dir)
{
  char lv[2][1200], out[2][1200], ubk[2][1200];
  ub_bakefile *bf[2] = {NULL, NULL};
  for (int k = 0; k < 2; k++) {
    ASSERT_TRUE(write_level(dir, k ? "share_copies" : "share_shared", !k, lv[k], sizeof lv[k]));
    snprintf(out[k], sizeof out[k], "%s/bake_%d", dir, k);
    ub_bake_options o;
    ub_bake_options_default(&o);
    o.quality = UB_QUALITY_FAST;
    o.out_dir = out[k];
    ub_bake_stats st;
    ASSERT_OK(ub_bake_level(lv[k], &o, &g_log, &st));
    snprintf(ubk[k], sizeof ubk[k], "%s", st.ubk_path);
    ASSERT_OK(ub_bakefile_read(ubk[k], &g_log, &bf[k]));
  }
  if (!bf[0] || !bf[1])
    goto done;
  int32_t a0 = model_named(bf[0], "prop_a"), b0 = model_named(bf[0], "prop_b"),
          c0 = model_named(bf[0], "prop_c"), b1 = model_named(bf[1], "prop_b");
  ASSERT_TRUE(a0 >= 0 && b0 >= 0 && c0 >= 0 && b1 >= 0 && bf[1]->llg_count == 2);
  if (a0 < 0 || b0 < 0 || c0 < 0 || b1 < 0)
    goto done;
  const ub_bakefile_llg *ms = &bf[0]->llgs[b0], *mc = &bf[1]->llgs[b1];
  printf("  shared: prop_b vis_shared_from %u, prop_c %u; copies: prop_b %u\n",
         ms->vis_shared_from, bf[0]->llgs[c0].vis_shared_from, mc->vis_shared_from);
  ASSERT_TRUE(ms->vis_shared_from == (uint32_t)a0 + 1);
  ASSERT_TRUE(bf[0]->llgs[c0].vis_shared_from == 0);
  ASSERT_TRUE(bf[1]->llgs[0].vis_shared_from == 0 && bf[1]->llgs[1].vis_shared_from == 0);
  /* bytes: the LLGM of the shared file without prop_c vs the copies file */
  {
    size_t n0 = 0, n1 = 0, s0, s1;
    uint8_t *f0 = read_all(ubk[0], &n0), *f1 = read_all(ubk[1], &n1);
    find_section(f0, "LLGM", &s0, NULL);
    find_section(f1, "LLGM", &s1, NULL);
    const ub_bakefile_llg *mcc = &bf[0]->llgs[c0];
    size_t npc = (size_t)mcc->dims[0] * mcc->dims[1] * mcc->dims[2];
    size_t c_block = 48u * mcc->vertex_count + 12u * mcc->triangle_count + 54u * npc;
    c_block = (c_block + 7) & ~(size_t)7;
    long without_c = (long)s0 - 184 - (long)c_block;
    long expect = (long)s1 - 18 * (long)ms->vertex_count + 2 * 40;
    printf("  LLGM bytes: shared %zu (%ld without prop_c), copies %zu; expected %ld ± 8 "
           "(prop_b's %u-vertex visibility, 18 B each, stored once)\n",
           s0, without_c, s1, expect, ms->vertex_count);
    ASSERT_TRUE(labs(without_c - expect) <= 8);
    ASSERT_TRUE(without_c < (long)s1);
    free(f0);
    free(f1);
  }
  /* shading of prop_b: shared vs separately traced */
  ASSERT_TRUE(ms->vertex_count == mc->vertex_count);
  if (ms->vertex_count == mc->vertex_count) {
    double sum = 0.0, worst = 0.0, vis_sum = 0.0;
    uint32_t n = 0;
    for (uint32_t v = 0; v < ms->vertex_count; v++) {
      float es[3], ec[3];
      vertex_irradiance(ms, v, es);
      vertex_irradiance(mc, v, ec);
      double r = lum(ec);
      if (!(r > 1e-3))
        continue;
      double d = fabs(lum(es) - r) / r;
      sum += d;
      worst = fmax(worst, d);
      vis_sum += ms->vis[9 * (size_t)v] / 3.5449077;
      n++;
    }
    printf("  prop_b per-vertex irradiance, shared vs copies: mean |Δ|/E %.2f%%, worst %.2f%% "
           "over %u vertices (mean visible fraction %.2f)\n",
           n ? 100.0 * sum / n : 0.0, 100.0 * worst, n, n ? vis_sum / n : 0.0);
    ASSERT_TRUE(n > 100);
    ASSERT_TRUE(n && sum / n < 0.03);
    ASSERT_TRUE(worst < 0.15);
  }
done:
  ub_bakefile_free(bf[0]);
  ub_bakefile_free(bf[1]);
}

/* ---- hand-built file ------------------------------------------------------------------ */

static void test_small_file(const char *dir)
{
  float sh[8 * 27], pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0}, nrm[9] = {0, 0, 1, 0, 0, 1, 0, 0, 1};
  float vis[27], self[9] = {0.1f, 0.2f, 0.3f, 0, 0, 0, 1, 1, 1};
  uint32_t idx[3] = {0, 1, 2};
  for (int i = 0; i < 8 * 27; i++)
    sh[i] = (float)((i * 37) % 11) * 0.125f - 0.5f;
  for (int i = 0; i < 27; i++)
    vis[i] = i % 9 == 0 ? 3.5f : 0.0625f * (float)(i % 5);
  ub_bakefile_llg m[2];
  memset(m, 0, sizeof m);
  for (int k = 0; k < 2; k++) {
    snprintf(m[k].name, sizeof m[k].name, "crate_%d", k);
    float c[3] = {0.5f + 2.0f * k, 0.5f, 0.0f}, ax[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1},
          h[3] = {0.7f, 0.7f, 0.2f};
    memcpy(m[k].center, c, sizeof c);
    memcpy(m[k].axes, ax, sizeof ax);
    memcpy(m[k].half, h, sizeof h);
    m[k].dims[0] = m[k].dims[1] = m[k].dims[2] = 2;
    m[k].probe_sh = sh;
    m[k].vertex_count = 3;
    m[k].positions = pos;
    m[k].normals = nrm;
    m[k].vis = vis;
    m[k].self = self;
    m[k].triangle_count = 1;
    m[k].indices = idx;
  }
  m[1].vis_shared_from = 1;
  float R[9] = {0, 0, 1, 0, 1, 0, -1, 0, 0}; /* 90° about y */
  memcpy(m[1].vis_rotation, R, sizeof R);
  ub_bakefile bf;
  memset(&bf, 0, sizeof bf);
  snprintf(bf.level_name, sizeof bf.level_name, "llg_shared");
  bf.llg_count = 2;
  bf.llgs = m;
  char path[1100], again[1100];
  snprintf(path, sizeof path, "%s/shared.ubk", dir);
  snprintf(again, sizeof again, "%s/shared_again.ubk", dir);
  ASSERT_OK(ub_bakefile_write(&bf, path, &g_log));
  ub_bakefile *rd = NULL;
  ASSERT_OK(ub_bakefile_read(path, &g_log, &rd));
  if (rd) {
    ASSERT_TRUE(rd->llg_count == 2 && rd->llgs[1].vis_shared_from == 1);
    float M[81], want[9];
    ub_llg_sh_rotation(R, M);
    for (int v = 0; v < 3; v++) {
      ub_llg_sh_rotate(M, vis + 9 * v, want);
      for (int k = 0; k < 9; k++) /* halves: vis values exact, rotation in float */
        ASSERT_NEAR(rd->llgs[1].vis[9 * v + k], want[k], 1e-5, 0);
    }
    ASSERT_OK(ub_bakefile_write(rd, again, &g_log));
  }
  ub_bakefile_free(rd);
  size_t na = 0, nb = 0;
  uint8_t *ba = read_all(path, &na), *bb = read_all(again, &nb);
  ASSERT_TRUE(ba && bb && na == nb && !memcmp(ba, bb, na));
  const char *corpus = getenv("UB_WRITE_FUZZ_CORPUS");
  if (corpus) {
    char seed[1100];
    snprintf(seed, sizeof seed, "%s/llg_shared.ubk", corpus);
    ASSERT_OK(ub_bakefile_write(&bf, seed, &g_log));
  }
  /* hostile variants of the sharing fields, re-CRC'd so the parser sees them */
  if (ba) {
    size_t size, entry, off = find_section(ba, "LLGM", &size, &entry);
    uint32_t ns;
    memcpy(&ns, ba + 8, 4);
    ASSERT_TRUE(size > 8 + 2 * 184);
    const size_t h1 = off + 8 + 184; /* model 1 header */
    int cases = 0, refused = 0;
    for (int c = 0; c < 6 && size; c++) {
      uint8_t *t = malloc(na);
      memcpy(t, ba, na);
      uint32_t u;
      float f;
      if (c == 0) { /* shares from itself */
        u = 2;
        memcpy(t + h1 + 144, &u, 4);
      } else if (c == 1) { /* model 0 shares from model 1 (later) */
        u = 2;
        memcpy(t + off + 8 + 144, &u, 4);
      } else if (c == 2) { /* rotation not orthonormal */
        f = 2.0f;
        memcpy(t + h1 + 148, &f, 4);
      } else if (c == 3) { /* rotation NaN */
        u = 0x7fc00000u;
        memcpy(t + h1 + 152, &u, 4);
      } else if (c == 4) { /* unknown flag */
        t[off + 4] |= 2;
      } else { /* source's vertex count differs (and sizes no longer match) */
        t[off + 8 + 136] += 1;
      }
      uint32_t crc = ub_crc32_update(0, t + off, size);
      memcpy(t + entry + 24, &crc, 4);
      uint32_t hcrc = ub_crc32_update(0, t, 12);
      hcrc = ub_crc32_update(hcrc, t + 16, 32 * (size_t)ns);
      memcpy(t + 12, &hcrc, 4);
      ub_bakefile *z = NULL;
      ub_result r = ub_bakefile_read_memory(t, na, "hostile", NULL, &z);
      cases++;
      refused += r == UB_ERR_INVALID_DATA && z == NULL;
      if (!(r == UB_ERR_INVALID_DATA && z == NULL))
        printf("  hostile case %d NOT refused (%d)\n", c, (int)r);
      ub_bakefile_free(z);
      free(t);
    }
    printf("  hostile sharing variants refused: %d of %d\n", refused, cases);
    ASSERT_TRUE(refused == cases && cases == 6);
  }
  free(ba);
  free(bb);
  /* the writer validates too */
  ub_bakefile_llg bad[2] = {m[0], m[1]};
  bad[1].vis_shared_from = 2;
  bf.llgs = bad;
  ASSERT_TRUE(ub_bakefile_write(&bf, path, NULL) == UB_ERR_INVALID_DATA);
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  char dir[1024];
  snprintf(dir, sizeof dir, "%s/test_out", b ? b : ".");
  mkdir(dir, 0777);
  snprintf(dir, sizeof dir, "%s/test_out/llg_share", b ? b : ".");
  mkdir(dir, 0777);
  test_rotation();
  test_small_file(dir);
  test_bakes(dir);
  TEST_MAIN_END();
}
