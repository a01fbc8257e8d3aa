/* tests/hard/hard_util.h — shared helpers of the hard numerical cases (tests/hard/README.md).
 *
 * Each case generates its level with ubake-genlevel (UB_BUILD/ubake-genlevel) into
 * UB_BUILD/test_out/hard_<case>/, bakes it through the library (ub_bake_level) and reads
 * the result back through the run-time (ub_runtime_load, queries, texel irradiance), the
 * way a game would. Failures print the numbers; outputs stay in the case's directory.
 */
#ifndef UBAKE_TESTS_HARD_UTIL_H
#define UBAKE_TESTS_HARD_UTIL_H

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "report_util.h"
#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"
#include "ubake/scene.h"

static char hard_build[512];
static char hard_out[1024];

static inline void hard_log_fn(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  if (level <= UB_LOG_WARNING)
    fprintf(stderr, "%s: %s\n", level == UB_LOG_ERROR ? "error" : "warning", msg);
}
static const ub_log hard_log = {hard_log_fn, NULL};

static inline void hard_mkdir_p(const char *dir)
{
  char tmp[1024];
  snprintf(tmp, sizeof tmp, "%s", dir);
  for (char *p = tmp + 1; *p; p++)
    if (*p == '/') {
      *p = '\0';
      mkdir(tmp, 0777);
      *p = '/';
    }
  mkdir(tmp, 0777);
}

/* Output directory UB_BUILD/test_out/hard_<name>. */
static inline void hard_init(const char *name)
{
  const char *b = getenv("UB_BUILD");
  snprintf(hard_build, sizeof hard_build, "%s", b ? b : "build");
  snprintf(hard_out, sizeof hard_out, "%s/test_out/hard_%s", hard_build, name);
  hard_mkdir_p(hard_out);
  printf("hard case %s: outputs in %s\n", name, hard_out);
}

/* Generates `level` with space-separated k=v `params` as hard_out/<base>.gltf. */
static inline int hard_genlevel(const char *level, const char *base, const char *params, char *out_path,
                         size_t cap)
{
  char cmd[2048];
  int n = snprintf(cmd, sizeof cmd, "'%s/ubake-genlevel' %s -o '%s' --name %s", hard_build,
                   level, hard_out, base);
  if (params && *params) {
    char buf[1024];
    snprintf(buf, sizeof buf, "%s", params);
    for (char *tok = strtok(buf, " "); tok; tok = strtok(NULL, " "))
      n += snprintf(cmd + n, sizeof cmd - (size_t)n, " --param %s", tok);
  }
  fflush(stdout);
  if (system(cmd) != 0) {
    fprintf(stderr, "failed: %s\n", cmd);
    return 0;
  }
  snprintf(out_path, cap, "%s/%s.gltf", hard_out, base);
  return 1;
}

static inline void hard_options(ub_bake_options *o, ub_quality q, int bounces, float texel)
{
  ub_bake_options_default(o);
  o->quality = q;
  o->bounces = bounces;
  o->texel_size = texel;
  o->out_dir = hard_out;
}

/* Bakes and loads; NULL (and a message) on failure. */
static inline ub_runtime *hard_bake(const char *gltf, const ub_bake_options *o, ub_bake_stats *out_st)
{
  ub_bake_stats st;
  ub_result r = ub_bake_level(gltf, o, &hard_log, &st);
  if (r != UB_OK) {
    fprintf(stderr, "bake %s failed: %s\n", gltf, ub_result_string(r));
    return NULL;
  }
  printf("  baked %s: %u texels, %u bounces, %llu clamped, %.2f s\n", st.level_name, st.texels,
         st.bounces, (unsigned long long)st.clamped_values, st.total_seconds);
  ub_runtime *rt = NULL;
  if (ub_runtime_load(st.ubk_path, &hard_log, &rt) != UB_OK) {
    fprintf(stderr, "cannot load %s\n", st.ubk_path);
    return NULL;
  }
  if (out_st)
    *out_st = st;
  return rt;
}

/* The reference path tracer (bake/reference.h) on a level: its scene, geometry and
 * emitters, opened once per case. The including case includes bake/reference.h,
 * bake/lights.h and bake/rt.h. */
#ifdef UBAKE_BAKE_REFERENCE_H
typedef struct hard_ref {
  ub_scene *scene;
  ub_rt *rt;
  ub_emitters *em;
} hard_ref;

static inline int hard_ref_open(const char *gltf, hard_ref *r)
{
  memset(r, 0, sizeof *r);
  return ub_scene_load(gltf, NULL, &r->scene) == UB_OK &&
         ub_rt_create(r->scene, NULL, NULL, &r->rt) == UB_OK &&
         ub_emitters_build(r->scene, &r->em) == UB_OK;
}

static inline void hard_ref_close(hard_ref *r)
{
  ub_emitters_free(r->em);
  ub_rt_free(r->rt);
  ub_scene_free(r->scene);
  memset(r, 0, sizeof *r);
}

/* Irradiance at p with normal n, spp paths, seed: ref and its standard error se (RGB). */
static inline int hard_ref_irradiance(const hard_ref *r, const float p[3], const float n[3],
                                      uint32_t spp, uint32_t seed, float ref[3], float se[3])
{
  ub_reference_params rp;
  ub_reference_params_init(&rp);
  memcpy(rp.position, p, sizeof rp.position);
  memcpy(rp.normal, n, sizeof rp.normal);
  rp.spp = spp;
  rp.seed = seed;
  return ub_reference_irradiance(r->scene, r->rt, r->em, &rp, ref, se, NULL) == UB_OK;
}
#endif

/* Non-finite floats anywhere in a loaded bake file. */
static inline uint64_t hard_nonfinite(const ub_bakefile *bf)
{
  uint64_t bad = 0;
#define HARD_SCAN(ptr, count)                                                                \
  do {                                                                                       \
    for (size_t i_ = 0; (ptr) && i_ < (size_t)(count); i_++)                                \
      bad += !isfinite((ptr)[i_]);                                                           \
  } while (0)
  HARD_SCAN(bf->positions, (size_t)bf->vertex_count * 3);
  HARD_SCAN(bf->tri_uv, (size_t)bf->triangle_count * 6);
  HARD_SCAN(bf->tri_albedo, (size_t)bf->triangle_count * 3);
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    size_t px = (size_t)at->width * at->height;
    HARD_SCAN(at->sh, px * UB_SH1_FLOATS);
    HARD_SCAN(at->normal, px * 3);
  }
  HARD_SCAN(bf->glg_positions, (size_t)bf->glg_probe_count * 3);
  HARD_SCAN(bf->glg_sh, (size_t)bf->glg_probe_count * 27);
  HARD_SCAN(bf->glg_planes, (size_t)bf->glg_plane_count * 4);
#undef HARD_SCAN
  return bad;
}

/* "clamped_values" of DIR/NAME.report.json next to the .ubk; -1 if absent. */
static inline long long hard_report_clamped(const char *ubk_path)
{
  double v = ub_report_number(ubk_path, "clamped_values");
  return isnan(v) ? -1 : (long long)v;
}

/* Per-texel data of one atlas: irradiance along the stored normal (green channel and rgb),
 * world position of the texel centre (closest point of the closest lightmapped triangle in
 * UV space; NaN where no triangle of the atlas is near) and the stored normal. */
typedef struct hard_texels {
  uint32_t w, h;
  const uint8_t *coverage;
  float *e;      /* w × h × 3 (0 for uncovered) */
  float *pos;    /* w × h × 3 */
  float *normal; /* w × h × 3: the stored normals (ub_runtime_texel_normal) */
} hard_texels;

static inline void hard_closest_uv(const float *a, const float *b, const float *c, double px, double py,
                            double bary[3], double *out_d2)
{
  /* closest point on a 2-D triangle: try inside, else the closest of the three edges */
  double v0x = b[0] - a[0], v0y = b[1] - a[1], v1x = c[0] - a[0], v1y = c[1] - a[1];
  double v2x = px - a[0], v2y = py - a[1];
  double den = v0x * v1y - v1x * v0y;
  if (fabs(den) > 1e-20) {
    double s = (v2x * v1y - v1x * v2y) / den, t = (v0x * v2y - v2x * v0y) / den;
    if (s >= 0 && t >= 0 && s + t <= 1) {
      bary[0] = 1 - s - t, bary[1] = s, bary[2] = t;
      *out_d2 = 0.0;
      return;
    }
  }
  const float *p[3] = {a, b, c};
  *out_d2 = INFINITY;
  for (int e = 0; e < 3; e++) {
    const float *q0 = p[e], *q1 = p[(e + 1) % 3];
    double ex = q1[0] - q0[0], ey = q1[1] - q0[1], l2 = ex * ex + ey * ey;
    double t = l2 > 0 ? ((px - q0[0]) * ex + (py - q0[1]) * ey) / l2 : 0.0;
    t = t < 0 ? 0 : (t > 1 ? 1 : t);
    double dx = q0[0] + t * ex - px, dy = q0[1] + t * ey - py, d2 = dx * dx + dy * dy;
    if (d2 < *out_d2) {
      *out_d2 = d2;
      double w[3] = {0, 0, 0};
      w[e] = 1 - t;
      w[(e + 1) % 3] = t;
      memcpy(bary, w, sizeof w);
    }
  }
}

static inline int hard_texels_get(const ub_runtime *rt, uint32_t atlas, hard_texels *out)
{
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  const ub_bakefile_atlas *at = &bf->atlases[atlas];
  size_t npx = (size_t)at->width * at->height;
  out->w = at->width;
  out->h = at->height;
  out->coverage = at->coverage;
  out->normal = malloc(npx * 3 * sizeof(float));
  out->e = calloc(npx * 3, sizeof(float));
  out->pos = malloc(npx * 3 * sizeof(float));
  double *best = malloc(npx * sizeof(double));
  if (!out->e || !out->pos || !out->normal || !best) {
    free(out->e);
    free(out->pos);
    free(out->normal);
    free(best);
    return 0;
  }
  for (size_t i = 0; i < npx; i++) {
    best[i] = INFINITY;
    out->pos[3 * i] = out->pos[3 * i + 1] = out->pos[3 * i + 2] = NAN;
    uint32_t x = (uint32_t)(i % at->width), y = (uint32_t)(i / at->width);
    ub_runtime_texel_normal(rt, atlas, x, y, out->normal + 3 * i);
    if (at->coverage[i] == 1)
      ub_runtime_texel_irradiance(rt, atlas, x, y, out->normal + 3 * i, out->e + 3 * i);
  }
  for (uint32_t t = 0; t < bf->triangle_count; t++) {
    if (bf->tri_atlas[t] != (int32_t)atlas)
      continue;
    float uv[3][2];
    double mn[2] = {1e30, 1e30}, mx[2] = {-1e30, -1e30};
    for (int k = 0; k < 3; k++) {
      uv[k][0] = bf->tri_uv[6 * (size_t)t + 2 * k] * (float)at->width;
      uv[k][1] = bf->tri_uv[6 * (size_t)t + 2 * k + 1] * (float)at->height;
      for (int j = 0; j < 2; j++) {
        mn[j] = fmin(mn[j], uv[k][j]);
        mx[j] = fmax(mx[j], uv[k][j]);
      }
    }
    int x0 = (int)floor(mn[0]) - 1, x1 = (int)ceil(mx[0]) + 1;
    int y0 = (int)floor(mn[1]) - 1, y1 = (int)ceil(mx[1]) + 1;
    for (int y = y0 < 0 ? 0 : y0; y <= y1 && y < (int)at->height; y++)
      for (int x = x0 < 0 ? 0 : x0; x <= x1 && x < (int)at->width; x++) {
        double bary[3], d2;
        hard_closest_uv(uv[0], uv[1], uv[2], x + 0.5, y + 0.5, bary, &d2);
        size_t i = (size_t)y * at->width + (size_t)x;
        if (!(d2 < best[i]) || d2 > 2.0)
          continue;
        best[i] = d2;
        for (int r = 0; r < 3; r++) {
          double s = 0;
          for (int k = 0; k < 3; k++)
            s += bary[k] * bf->positions[3 * (size_t)bf->indices[3 * (size_t)t + k] + r];
          out->pos[3 * i + r] = (float)s;
        }
      }
  }
  free(best);
  return 1;
}

static inline void hard_texels_free(hard_texels *t)
{
  free(t->e);
  free(t->pos);
  free(t->normal);
  t->e = t->pos = t->normal = NULL;
}

/* Median of up to 8 covered neighbours' green irradiance (8-connected); -1 if none. */
static inline double hard_neighbour_median(const hard_texels *tx, uint32_t x, uint32_t y)
{
  double v[8];
  int n = 0;
  for (int dy = -1; dy <= 1; dy++)
    for (int dx = -1; dx <= 1; dx++) {
      int xx = (int)x + dx, yy = (int)y + dy;
      if ((!dx && !dy) || xx < 0 || yy < 0 || xx >= (int)tx->w || yy >= (int)tx->h)
        continue;
      size_t i = (size_t)yy * tx->w + (size_t)xx;
      if (tx->coverage[i] == 1)
        v[n++] = tx->e[3 * i + 1];
    }
  if (!n)
    return -1.0;
  for (int i = 1; i < n; i++)
    for (int j = i; j > 0 && v[j - 1] > v[j]; j--) {
      double t = v[j];
      v[j] = v[j - 1];
      v[j - 1] = t;
    }
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

#endif
