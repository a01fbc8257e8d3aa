/* Preview renderer tests: BVH closest hit and any hit vs brute force (random soup and
 * cornell), a cornell render (written, finite, red left / green right, lit centre), the
 * shading equals albedo/π × the lightmap query at the hit, the run-time direct light of a
 * primary light (hallway, DLS weight 1 vs 0) against the closed form, camera edge cases,
 * and the tone map. Baked outputs and images stay in UB_BUILD/test_out/render/. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include <stb_image_write.h>

#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/render.h"
#include "ubake/runtime.h"

static char g_build[512];

static void test_log(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  if (level <= UB_LOG_WARNING)
    fprintf(stderr, "%s: %s\n", level == UB_LOG_ERROR ? "error" : "warning", msg);
}
static const ub_log g_log = {test_log, NULL};

/* Swallows messages of calls expected to fail, counting them. */
static void count_log(void *user, ub_log_level level, const char *msg)
{
  (void)msg;
  if (level == UB_LOG_ERROR)
    (*(int *)user)++;
}

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* xorshift64*: deterministic test randomness. */
static uint64_t g_rng = 0x9E3779B97F4A7C15ull;
static double rnd(void)
{
  g_rng ^= g_rng >> 12;
  g_rng ^= g_rng << 25;
  g_rng ^= g_rng >> 27;
  return (double)((g_rng * 0x2545F4914F6CDD1Dull) >> 11) * (1.0 / 9007199254740992.0);
}

static void rnd_dir(float out[3])
{
  double z = 2.0 * rnd() - 1.0, phi = 2.0 * M_PI * rnd(), s = sqrt(fmax(0.0, 1.0 - z * z));
  out[0] = (float)(s * cos(phi));
  out[1] = (float)(s * sin(phi));
  out[2] = (float)z;
}

/* Closest hit over all triangles, Möller–Trumbore in double; -1 for a miss. */
static double brute_closest(const float *pos, const uint32_t *idx, uint32_t tris,
                            const float o[3], const float d[3], uint32_t *out_tri)
{
  double best = INFINITY;
  for (uint32_t t = 0; t < tris; t++) {
    const float *a = &pos[idx[t * 3] * 3], *b = &pos[idx[t * 3 + 1] * 3],
                *c = &pos[idx[t * 3 + 2] * 3];
    double e1[3], e2[3], p[3], s[3], q[3];
    for (int k = 0; k < 3; k++) {
      e1[k] = (double)b[k] - a[k];
      e2[k] = (double)c[k] - a[k];
      s[k] = (double)o[k] - a[k];
    }
    p[0] = d[1] * e2[2] - d[2] * e2[1];
    p[1] = d[2] * e2[0] - d[0] * e2[2];
    p[2] = d[0] * e2[1] - d[1] * e2[0];
    double det = e1[0] * p[0] + e1[1] * p[1] + e1[2] * p[2];
    if (det == 0.0)
      continue;
    double u = (s[0] * p[0] + s[1] * p[1] + s[2] * p[2]) / det;
    if (u < 0.0 || u > 1.0)
      continue;
    q[0] = s[1] * e1[2] - s[2] * e1[1];
    q[1] = s[2] * e1[0] - s[0] * e1[2];
    q[2] = s[0] * e1[1] - s[1] * e1[0];
    double v = (d[0] * q[0] + d[1] * q[1] + d[2] * q[2]) / det;
    if (v < 0.0 || u + v > 1.0)
      continue;
    double tt = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) / det;
    if (tt > 0.0 && tt < best) {
      best = tt;
      *out_tri = t;
    }
  }
  return best == INFINITY ? -1.0 : best;
}

/* rays random rays from inside lo..hi: BVH closest hit == brute force (t within 1e-4
 * relative), any hit agrees with the closest hit for a random segment length. */
static void check_bvh(const char *what, const float *pos, uint32_t verts, const uint32_t *idx,
                      uint32_t tris, const float lo[3], const float hi[3], int rays)
{
  ub_bvh *bvh = NULL;
  double t0 = now_s();
  ASSERT_OK(ub_bvh_build(pos, verts, idx, tris, &bvh));
  if (!bvh)
    return;
  double tb = now_s() - t0;
  uint32_t nodes = 0, depth = 0;
  ub_bvh_stats(bvh, &nodes, &depth);
  int mismatch = 0, any_mismatch = 0, hits = 0;
  double brute_s = 0.0, bvh_s = 0.0;
  for (int i = 0; i < rays; i++) {
    float o[3], d[3];
    for (int k = 0; k < 3; k++)
      o[k] = lo[k] + (float)rnd() * (hi[k] - lo[k]);
    rnd_dir(d);
    uint32_t bt = 0;
    double s0 = now_s();
    double tref = brute_closest(pos, idx, tris, o, d, &bt);
    double s1 = now_s();
    ub_bvh_hit h;
    int hit = ub_bvh_intersect(bvh, o, d, INFINITY, &h);
    bvh_s += now_s() - s1;
    brute_s += s1 - s0;
    hits += hit;
    int ok = (tref < 0.0) == !hit && (!hit || fabs(h.t - tref) <= 1e-4 * tref);
    if (!ok && mismatch++ < 5)
      fprintf(stderr, "  %s ray %d: bvh %s t=%.9g tri %u, brute t=%.9g tri %u\n", what, i,
              hit ? "hit" : "miss", hit ? h.t : -1.0, hit ? h.tri : 0u, tref, bt);
    /* Any hit over a random length: blocked iff the closest hit is (clearly) shorter. */
    float len = (float)(rnd() * 2.0 * (hi[0] - lo[0]));
    if (tref < 0.0 || fabs(tref - len) > 1e-3 * len) {
      int occ = ub_bvh_occluded(bvh, o, d, len);
      if (occ != (tref > 0.0 && tref < len))
        any_mismatch++;
    }
  }
  printf("  bvh %-8s %6u tris, %6u nodes, depth %2u, build %.3f s; %d rays (%d hit): "
         "%d closest-hit and %d any-hit mismatches; %.2f M rays/s (brute %.3f M rays/s)\n",
         what, tris, nodes, depth, tb, rays, hits, mismatch, any_mismatch,
         rays / fmax(bvh_s, 1e-9) * 1e-6, rays / fmax(brute_s, 1e-9) * 1e-6);
  ASSERT_TRUE(mismatch == 0);
  ASSERT_TRUE(any_mismatch == 0);
  ub_bvh_free(bvh);
}

static void test_bvh_soup(void)
{
  /* Random small triangles in a 10 m cube, a few large ones, a degenerate one and many
   * coincident ones (equal centroids force the no-split path). */
  enum { N = 6000 };
  float *pos = malloc(N * 9 * sizeof *pos);
  uint32_t *idx = malloc(N * 3 * sizeof *idx);
  for (uint32_t t = 0; t < N; t++) {
    float c[3], s = t < 20 ? 6.0f : 0.4f;
    for (int k = 0; k < 3; k++)
      c[k] = t >= 5000 && t < 5100 ? 5.0f : (float)(rnd() * 10.0);
    for (int v = 0; v < 3; v++) {
      for (int k = 0; k < 3; k++)
        pos[(t * 3 + v) * 3 + k] = c[k] + (float)((rnd() - 0.5) * s);
      idx[t * 3 + v] = t * 3 + v;
    }
  }
  for (int k = 0; k < 3; k++) /* triangle 30: all corners equal */
    pos[(30 * 3 + 1) * 3 + k] = pos[(30 * 3 + 2) * 3 + k] = pos[(30 * 3) * 3 + k];
  float lo[3] = {0, 0, 0}, hi[3] = {10, 10, 10};
  check_bvh("soup", pos, N * 3, idx, N, lo, hi, 10000);

  /* Empty BVH, bad input. */
  ub_bvh *e = NULL;
  ASSERT_OK(ub_bvh_build(NULL, 0, NULL, 0, &e));
  if (e) {
    float o[3] = {0, 0, 0}, d[3] = {0, 0, 1};
    ub_bvh_hit h;
    ASSERT_TRUE(!ub_bvh_intersect(e, o, d, INFINITY, &h));
    ASSERT_TRUE(!ub_bvh_occluded(e, o, d, INFINITY));
  }
  ub_bvh_free(e);
  ub_bvh *bad = NULL;
  idx[5] = N * 3;
  ASSERT_TRUE(ub_bvh_build(pos, N * 3, idx, N, &bad) == UB_ERR_INVALID_ARGUMENT && !bad);
  idx[5] = 5;
  pos[7] = NAN;
  ASSERT_TRUE(ub_bvh_build(pos, N * 3, idx, N, &bad) == UB_ERR_INVALID_ARGUMENT && !bad);
  free(pos);
  free(idx);
}

static ub_runtime *bake(const char *level, char *out_ubk, size_t cap)
{
  char path[1024], dir[1024];
  snprintf(path, sizeof path, "%s/levels/%s.gltf", g_build, level);
  snprintf(dir, sizeof dir, "%s/test_out/render/%s", g_build, level);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = UB_QUALITY_DRAFT;
  o.out_dir = dir;
  ub_bake_stats st;
  ub_result r = ub_bake_level(path, &o, &g_log, &st);
  if (r != UB_OK) {
    fprintf(stderr, "bake %s failed: %s\n", path, ub_result_string(r));
    return NULL;
  }
  printf("  baked %s: %u texels, %.2f s\n", level, st.texels, st.total_seconds);
  if (out_ubk)
    snprintf(out_ubk, cap, "%s", st.ubk_path);
  ub_runtime *rt = NULL;
  if (ub_runtime_load(st.ubk_path, &g_log, &rt) != UB_OK)
    return NULL;
  return rt;
}

/* The renderer's primary ray through the centre of pixel (x, y) (render.h: Y up,
 * right = forward × up, pixel centres, vertical field of view). */
static void pixel_ray(const ub_render_params *p, uint32_t x, uint32_t y, float out_d[3])
{
  double f[3], r[3], u[3], l = 0.0;
  for (int k = 0; k < 3; k++) {
    f[k] = (double)p->target[k] - p->eye[k];
    l += f[k] * f[k];
  }
  for (int k = 0; k < 3; k++)
    f[k] /= sqrt(l);
  r[0] = -f[2], r[1] = 0.0, r[2] = f[0]; /* f × (0,1,0) */
  l = sqrt(r[0] * r[0] + r[2] * r[2]);
  r[0] /= l, r[2] /= l;
  u[0] = r[1] * f[2] - r[2] * f[1];
  u[1] = r[2] * f[0] - r[0] * f[2];
  u[2] = r[0] * f[1] - r[1] * f[0];
  double hh = tan(0.5 * p->fovy_degrees * M_PI / 180.0), hw = hh * p->width / p->height;
  double sx = (2.0 * (x + 0.5) / p->width - 1.0) * hw, sy = (1.0 - 2.0 * (y + 0.5) / p->height) * hh;
  double d[3];
  l = 0.0;
  for (int k = 0; k < 3; k++) {
    d[k] = f[k] + sx * r[k] + sy * u[k];
    l += d[k] * d[k];
  }
  for (int k = 0; k < 3; k++)
    out_d[k] = (float)(d[k] / sqrt(l));
}

/* Triangle tri's corner-order normal (not normalised). */
static void tri_cross(const ub_bakefile *bf, uint32_t tri, float out[3])
{
  const float *v0 = &bf->positions[bf->indices[tri * 3] * 3],
              *v1 = &bf->positions[bf->indices[tri * 3 + 1] * 3],
              *v2 = &bf->positions[bf->indices[tri * 3 + 2] * 3];
  float e1[3], e2[3];
  for (int k = 0; k < 3; k++) {
    e1[k] = v1[k] - v0[k];
    e2[k] = v2[k] - v0[k];
  }
  out[0] = e1[1] * e2[2] - e1[2] * e2[1];
  out[1] = e1[2] * e2[0] - e1[0] * e2[2];
  out[2] = e1[0] * e2[1] - e1[1] * e2[0];
}

static double luma(const float *c)
{
  return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
}

static int write_png(const char *name, const float *rgb, uint32_t w, uint32_t h)
{
  char path[1024];
  snprintf(path, sizeof path, "%s/test_out/render/%s", g_build, name);
  uint8_t *px = malloc((size_t)w * h * 3);
  float ev = 0.0f;
  int ok = px && ub_render_tonemap(rgb, w, h, 1, 0.0f, px, &ev) == UB_OK &&
           stbi_write_png(path, (int)w, (int)h, 3, px, (int)w * 3) != 0;
  free(px);
  struct stat sb;
  ok = ok && stat(path, &sb) == 0 && sb.st_size > 0;
  printf("  wrote %s (%s, auto exposure %.2f EV)\n", path, ok ? "ok" : "FAILED", ev);
  return ok;
}

/* Finite, ≥ 0 everywhere. */
static int image_clean(const float *rgb, size_t n)
{
  for (size_t i = 0; i < n * 3; i++)
    if (!isfinite(rgb[i]) || rgb[i] < 0.0f)
      return 0;
  return 1;
}

static void test_cornell(void)
{
  ub_runtime *rt = bake("cornell", NULL, 0);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  float lo[3] = {-0.99f, 0.01f, -0.99f}, hi[3] = {0.99f, 1.99f, 0.99f};
  check_bvh("cornell", bf->positions, bf->vertex_count, bf->indices, bf->triangle_count, lo,
            hi, 10000);

  ub_renderer *ren = NULL;
  ASSERT_OK(ub_renderer_create(rt, &g_log, &ren));
  if (!ren) {
    ub_runtime_free(rt);
    return;
  }
  ub_render_params p;
  ub_render_params_default(&p);
  const float eye[3] = {0.0f, 1.0f, 0.95f}, target[3] = {0.0f, 1.0f, -1.0f};
  memcpy(p.eye, eye, sizeof eye);
  memcpy(p.target, target, sizeof target);
  p.fovy_degrees = 70.0f;
  size_t n = (size_t)p.width * p.height;
  float *img = malloc(n * 3 * sizeof *img);
  double t0 = now_s();
  ASSERT_OK(ub_renderer_render(ren, &p, 0, p.height, img, &g_log));
  double t1 = now_s() - t0;
  printf("  render cornell %ux%u, 1 ray/pixel, one thread: %.3f s (%.2f M pixels/s)\n", p.width,
         p.height, t1, n / t1 * 1e-6);
  ASSERT_TRUE(image_clean(img, n));
  ASSERT_TRUE(write_png("cornell.png", img, p.width, p.height));

  /* Left third redder than the right third (red wall at x = −1, green at x = +1). */
  double sum[2][3] = {{0}};
  for (uint32_t y = 0; y < p.height; y++)
    for (uint32_t x = 0; x < p.width; x++) {
      int side = x < p.width / 3 ? 0 : x >= 2 * p.width / 3 ? 1 : -1;
      if (side < 0)
        continue;
      for (int c = 0; c < 3; c++)
        sum[side][c] += img[((size_t)y * p.width + x) * 3 + c];
    }
  double red_l = sum[0][0] / (sum[0][1] + 1e-12), red_r = sum[1][0] / (sum[1][1] + 1e-12);
  printf("  cornell R/G: left %.3f, right %.3f\n", red_l, red_r);
  ASSERT_TRUE(red_l > 1.5 * red_r);
  ASSERT_TRUE(sum[0][0] > sum[1][0] && sum[1][1] > sum[0][1]);
  const float *centre = &img[((size_t)(p.height / 2) * p.width + p.width / 2) * 3];
  printf("  centre pixel %.4g %.4g %.4g W/(m²·sr)\n", centre[0], centre[1], centre[2]);
  ASSERT_TRUE(luma(centre) > 1e-3);

  /* Shading = albedo/π × the lightmap query at the hit (away from triangle edges, where
   * the closest-point query could pick the neighbour). */
  int compared = 0, bad = 0;
  for (int i = 0; i < 400; i++) {
    uint32_t x = (uint32_t)(rnd() * p.width), y = (uint32_t)(rnd() * p.height);
    float d[3];
    pixel_ray(&p, x, y, d);
    ub_bvh_hit h;
    if (!ub_bvh_intersect(ub_renderer_bvh(ren), p.eye, d, INFINITY, &h))
      continue;
    float b0 = 1.0f - h.b1 - h.b2;
    if (b0 < 0.02f || h.b1 < 0.02f || h.b2 < 0.02f || bf->tri_atlas[h.tri] < 0)
      continue;
    const float *v0 = &bf->positions[bf->indices[h.tri * 3] * 3],
                *v1 = &bf->positions[bf->indices[h.tri * 3 + 1] * 3],
                *v2 = &bf->positions[bf->indices[h.tri * 3 + 2] * 3];
    float nn[3], q[3], e[3];
    for (int k = 0; k < 3; k++)
      q[k] = b0 * v0[k] + h.b1 * v1[k] + h.b2 * v2[k];
    tri_cross(bf, h.tri, nn);
    if (nn[0] * d[0] + nn[1] * d[1] + nn[2] * d[2] >= 0.0f)
      continue; /* back face */
    if (ub_runtime_query_lightmap(rt, q, nn, e, NULL) != UB_OK)
      continue;
    const float *px = &img[((size_t)y * p.width + x) * 3];
    for (int c = 0; c < 3; c++) {
      double want = bf->tri_albedo[h.tri * 3 + c] / M_PI * e[c];
      if (fabs(px[c] - want) > 1e-4 + 2e-3 * want) {
        if (bad++ < 5)
          fprintf(stderr, "  pixel (%u,%u) c%d: rendered %.6g, albedo/pi x lightmap %.6g\n",
                  x, y, c, px[c], want);
      }
    }
    compared++;
  }
  printf("  %d pixels compared with albedo/pi x ub_runtime_query_lightmap: %d off\n", compared,
         bad);
  ASSERT_TRUE(compared > 100 && bad == 0);

  /* Bands rendered separately give the same image. */
  float *img2 = malloc(n * 3 * sizeof *img2);
  for (uint32_t y0 = 0; y0 < p.height; y0 += 7)
    ASSERT_OK(ub_renderer_render(ren, &p, y0, y0 + 7 < p.height ? y0 + 7 : p.height, img2, NULL));
  ASSERT_TRUE(memcmp(img, img2, n * 3 * sizeof *img) == 0);

  /* Cameras outside the box, inside a box (the tall one), on a wall, looking straight
   * down or up: finite images. */
  static const float cams[][7] = {
      {0, 1, 5, 0, 1, 0, 60},          {-0.33f, 0.6f, -0.27f, 0, 0.6f, 1, 90},
      {-1, 1, 0, 1, 1, 0, 60},         {0, 1.5f, 0, 0, 0, 0, 60},
      {0, 0.5f, 0, 0, 2, 0, 120},      {0, 1, 0.95f, 0, 1, -1, 0.001f}};
  for (size_t k = 0; k < sizeof cams / sizeof cams[0]; k++) {
    ub_render_params q = p;
    q.width = 64;
    q.height = 48;
    memcpy(q.eye, cams[k], 3 * sizeof(float));
    memcpy(q.target, cams[k] + 3, 3 * sizeof(float));
    q.fovy_degrees = cams[k][6];
    ASSERT_OK(ub_renderer_render(ren, &q, 0, q.height, img2, &g_log));
    ASSERT_TRUE(image_clean(img2, (size_t)q.width * q.height));
  }
  /* What the camera sees (ub_renderer_view, the CLI's warning): from inside the box,
   * front faces everywhere; from outside it (a closed box with inward faces), its back
   * faces in the middle of the view and nothing around them; facing a wall from 1 mm
   * behind it, back faces alone. The fractions match a per-pixel count of the same rays. */
  {
    ub_render_view vw;
    ASSERT_OK(ub_renderer_view(ren, &p, 32, &vw, &g_log));
    printf("  view inside: front %.3f back %.3f miss %.3f\n", vw.front, vw.back, vw.miss);
    ASSERT_TRUE(vw.front == 1.0f && vw.back == 0.0f && vw.miss == 0.0f);
    ub_render_params q = p;
    q.width = q.height = 32; /* the view's lattice is this image's pixel centres */
    const float out_eye[3] = {0.0f, 1.0f, 5.0f}, out_tgt[3] = {0.0f, 1.0f, 0.0f};
    memcpy(q.eye, out_eye, sizeof out_eye);
    memcpy(q.target, out_tgt, sizeof out_tgt);
    q.fovy_degrees = 40.0f;
    ASSERT_OK(ub_renderer_view(ren, &q, 32, &vw, &g_log));
    int nf = 0, nb = 0, nm = 0;
    for (uint32_t y = 0; y < 32; y++)
      for (uint32_t x = 0; x < 32; x++) {
        float d[3];
        pixel_ray(&q, x, y, d);
        ub_bvh_hit h;
        if (!ub_bvh_intersect(ub_renderer_bvh(ren), q.eye, d, INFINITY, &h)) {
          nm++;
          continue;
        }
        float c[3];
        tri_cross(bf, h.tri, c);
        if (c[0] * d[0] + c[1] * d[1] + c[2] * d[2] < 0.0f)
          nf++;
        else
          nb++;
      }
    printf("  view outside: front %.3f back %.3f miss %.3f (per pixel: %d %d %d of 1024)\n",
           vw.front, vw.back, vw.miss, nf, nb, nm);
    ASSERT_TRUE(vw.front < 0.5f && vw.back > 0.3f && vw.miss > 0.1f);
    ASSERT_TRUE(fabsf(vw.front + vw.back + vw.miss - 1.0f) < 1e-6f);
    ASSERT_TRUE(abs(nf - (int)lroundf(vw.front * 1024)) <= 2 &&
                abs(nb - (int)lroundf(vw.back * 1024)) <= 2 &&
                abs(nm - (int)lroundf(vw.miss * 1024)) <= 2);
    const float wall_eye[3] = {0.0f, 1.0f, -1.001f}, wall_tgt[3] = {0.0f, 1.0f, 0.0f};
    memcpy(q.eye, wall_eye, sizeof wall_eye);
    memcpy(q.target, wall_tgt, sizeof wall_tgt);
    q.fovy_degrees = 1.0f;
    ASSERT_OK(ub_renderer_view(ren, &q, 8, &vw, &g_log));
    printf("  view behind the back wall: front %.3f back %.3f miss %.3f\n", vw.front, vw.back,
           vw.miss);
    ASSERT_TRUE(vw.back == 1.0f);
    int verr = 0;
    ub_log vl = {count_log, &verr};
    ASSERT_TRUE(ub_renderer_view(ren, &q, 1, &vw, &vl) == UB_ERR_INVALID_ARGUMENT && verr == 1);
  }

  /* Bad cameras: errors with a message, nothing written. */
  int errors = 0;
  ub_log cl = {count_log, &errors};
  ub_render_params q = p;
  memcpy(q.target, q.eye, sizeof q.eye);
  img2[0] = -7.0f;
  ASSERT_TRUE(ub_renderer_render(ren, &q, 0, q.height, img2, &cl) == UB_ERR_INVALID_ARGUMENT);
  ASSERT_TRUE(img2[0] == -7.0f);
  q = p;
  q.fovy_degrees = 180.0f;
  ASSERT_TRUE(ub_renderer_render(ren, &q, 0, q.height, img2, &cl) == UB_ERR_INVALID_ARGUMENT);
  q = p;
  q.eye[1] = NAN;
  ASSERT_TRUE(ub_renderer_render(ren, &q, 0, q.height, img2, &cl) == UB_ERR_INVALID_ARGUMENT);
  q = p;
  q.width = 0;
  ASSERT_TRUE(ub_renderer_render(ren, &q, 0, q.height, img2, &cl) == UB_ERR_INVALID_ARGUMENT);
  ASSERT_TRUE(ub_renderer_render(ren, &p, 3, p.height + 1, img2, &cl) == UB_ERR_INVALID_ARGUMENT);
  ASSERT_TRUE(errors == 5);
  ASSERT_TRUE(img2[0] == -7.0f);

  free(img);
  free(img2);
  ub_renderer_free(ren);
  ub_runtime_free(rt);
}

/* Hallway: lamp_2 (primary, set hall_a) at (−1.5, 2.4, 0), 5 W/sr. With the set at weight
 * 1 vs 0 the image differs exactly by its direct light where the lamp is visible:
 * albedo/π × I·cosθ/d². (The set's baked indirect part is the run-time's business and
 * is not switched here: the runtime state is left as loaded.) */
static void test_primary_direct(void)
{
  ub_runtime *rt = bake("hallway", NULL, 0);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  int32_t set = -1, lamp = -1;
  for (uint32_t s = 0; s < bf->dls_count; s++)
    if (!strcmp(bf->dls[s].name, "hall_a"))
      set = (int32_t)s;
  for (uint32_t i = 0; i < bf->light_count; i++)
    if (bf->lights[i].cls == 1)
      lamp = (int32_t)i;
  ASSERT_TRUE(set >= 0 && lamp >= 0);
  if (set < 0 || lamp < 0 || bf->lights[lamp].dls != set) {
    ub_runtime_free(rt);
    return;
  }
  const ub_bakefile_light *L = &bf->lights[lamp];
  ub_renderer *ren = NULL;
  ASSERT_OK(ub_renderer_create(rt, &g_log, &ren));
  ub_render_params p;
  ub_render_params_default(&p);
  p.width = 320;
  p.height = 180;
  const float eye[3] = {-5.5f, 1.5f, 0.0f}, target[3] = {5.0f, 0.8f, 0.0f};
  memcpy(p.eye, eye, sizeof eye);
  memcpy(p.target, target, sizeof target);
  p.fovy_degrees = 70.0f;
  size_t n = (size_t)p.width * p.height;
  float *on = malloc(n * 3 * sizeof *on), *off = malloc(n * 3 * sizeof *off);
  float *w = malloc((size_t)bf->dls_count * 3 * sizeof *w);
  for (uint32_t i = 0; i < bf->dls_count * 3; i++)
    w[i] = 1.0f;
  p.dls_weights = w;
  ASSERT_OK(ub_renderer_render(ren, &p, 0, p.height, on, &g_log));
  w[set * 3 + 0] = w[set * 3 + 1] = w[set * 3 + 2] = 0.0f;
  ASSERT_OK(ub_renderer_render(ren, &p, 0, p.height, off, &g_log));
  ASSERT_TRUE(image_clean(on, n) && image_clean(off, n));
  ASSERT_TRUE(write_png("hallway_on.png", on, p.width, p.height));
  ASSERT_TRUE(write_png("hallway_off.png", off, p.width, p.height));
  /* A tint (0.5, 1, 1) keeps half the red difference and all of the green. */
  w[set * 3 + 0] = 0.5f;
  w[set * 3 + 1] = w[set * 3 + 2] = 1.0f;
  float *half = malloc(n * 3 * sizeof *half);
  ASSERT_OK(ub_renderer_render(ren, &p, 0, p.height, half, &g_log));

  int compared = 0, bad = 0, lit = 0;
  double max_rel = 0.0;
  for (uint32_t y = 0; y < p.height; y += 3)
    for (uint32_t x = 0; x < p.width; x += 3) {
      float d[3];
      pixel_ray(&p, x, y, d);
      ub_bvh_hit h;
      if (!ub_bvh_intersect(ub_renderer_bvh(ren), p.eye, d, INFINITY, &h))
        continue;
      float q[3];
      for (int k = 0; k < 3; k++)
        q[k] = p.eye[k] + h.t * d[k];
      /* Hallway surfaces are axis aligned: the normal facing the camera, by the largest
       * component of the ray, is the axis along which q sits on a face. */
      float nf[3];
      tri_cross(bf, h.tri, nf);
      const double nn[3] = {nf[0], nf[1], nf[2]};
      double nl = sqrt(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]);
      if (nn[0] * d[0] + nn[1] * d[1] + nn[2] * d[2] >= 0.0)
        continue;
      double l[3], dist2 = 0.0;
      for (int k = 0; k < 3; k++) {
        l[k] = (double)L->position[k] - q[k];
        dist2 += l[k] * l[k];
      }
      double dist = sqrt(dist2), cs = (nn[0] * l[0] + nn[1] * l[1] + nn[2] * l[2]) / (nl * dist);
      if (dist < 0.3)
        continue; /* the ceiling right above the lamp: too steep for a fair comparison */
      double want = cs > 0.0 ? bf->tri_albedo[h.tri * 3 + 1] / M_PI * L->intensity[1] * cs / dist2 : 0.0;
      if (L->range > 0.0f) {
        double r = dist / L->range, win = 1.0 - r * r * r * r;
        want *= r < 1.0 ? win * win : 0.0;
      }
      size_t i = ((size_t)y * p.width + x) * 3;
      double got = (double)on[i + 1] - off[i + 1];
      /* The hallway is convex: every front point the lamp faces sees it. */
      if (fabs(got - want) > 1e-5 + 2e-3 * want) {
        if (bad++ < 5)
          fprintf(stderr, "  hallway pixel (%u,%u): direct %.6g, closed form %.6g\n", x, y, got,
                  want);
      }
      if (want > 0.0) {
        lit++;
        max_rel = fmax(max_rel, fabs(got - want) / want);
        double half_r = (double)half[i] - off[i], full_r = (double)on[i] - off[i];
        if (fabs(half_r - 0.5 * full_r) > 1e-5 + 1e-4 * full_r)
          bad++;
        if (fabs((double)half[i + 1] - on[i + 1]) > 1e-6 * on[i + 1])
          bad++;
      }
      compared++;
    }
  printf("  hallway primary lamp: %d pixels (%d lit) vs closed form, %d off, max rel %.2g\n",
         compared, lit, bad, max_rel);
  ASSERT_TRUE(compared > 1000 && lit > 500 && bad == 0);
  free(on);
  free(off);
  free(half);
  free(w);
  ub_renderer_free(ren);
  ub_runtime_free(rt);
}

static void test_tonemap(void)
{
  enum { W = 64, H = 8 };
  float rgb[W * H * 3];
  for (int i = 0; i < W * H; i++)
    for (int c = 0; c < 3; c++)
      rgb[i * 3 + c] = (float)i * 0.01f;
  rgb[0] = NAN;
  rgb[4] = INFINITY;
  rgb[8] = -1.0f;
  rgb[9] = 1e38f;
  uint8_t px[W * H * 3];
  float ev = 0.0f;
  ASSERT_OK(ub_render_tonemap(rgb, W, H, 1, 0.0f, px, &ev));
  ASSERT_TRUE(isfinite(ev));
  ASSERT_TRUE(px[0] == 0 && px[4] == 0 && px[8] == 0 && px[9] == 255);
  /* Monotonic in the input; fixed exposure: +1 EV is brighter. */
  for (int i = 2; i < W * H; i++)
    ASSERT_TRUE(px[i * 3 + 1] >= px[(i - 1) * 3 + 1]);
  uint8_t a[W * H * 3], b[W * H * 3];
  ASSERT_OK(ub_render_tonemap(rgb, W, H, 0, -2.0f, a, NULL));
  ASSERT_OK(ub_render_tonemap(rgb, W, H, 0, -1.0f, b, NULL));
  ASSERT_TRUE(b[100 * 3] > a[100 * 3]);
  /* All black: EV 0, black image. */
  float zero[W * H * 3] = {0};
  ASSERT_OK(ub_render_tonemap(zero, W, H, 1, 0.0f, px, &ev));
  ASSERT_TRUE(ev == 0.0f && px[0] == 0);
  ASSERT_TRUE(ub_render_tonemap(rgb, W, H, 0, NAN, px, NULL) == UB_ERR_INVALID_ARGUMENT);
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  snprintf(g_build, sizeof g_build, "%s", b ? b : "build");
  char dir[1024];
  snprintf(dir, sizeof dir, "%s/test_out", g_build);
  mkdir(dir, 0777);
  snprintf(dir, sizeof dir, "%s/test_out/render", g_build);
  mkdir(dir, 0777);
  test_tonemap();
  test_bvh_soup();
  test_cornell();
  test_primary_direct();
  TEST_MAIN_END();
}
