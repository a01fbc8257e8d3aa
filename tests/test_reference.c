/* Reference path tracer: analytic cases (point/spot lights, sky, emissive rectangle,
 * furnace), path classes (primary lights), DLS weights, determinism, throughput. */
#include <math.h>
#include <omp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bake/lights.h"
#include "bake/reference.h"
#include "bake/rt.h"
#include "test_util.h"
#include "ubake/sh.h"

/* ---- an in-memory scene builder ---------------------------------------------------- */

static void *grow(void *p, uint32_t count, size_t size)
{
  /* Grows to a power of two so repeated appends stay linear. */
  uint32_t cap = 1;
  while (cap < count)
    cap *= 2;
  void *q = realloc(p, (size_t)cap * size);
  if (!q) {
    fprintf(stderr, "out of memory\n");
    exit(1);
  }
  return q;
}

static void scene_init(ub_scene *s)
{
  memset(s, 0, sizeof *s);
  s->texel_size = 0.25f;
  s->glg_spacing = 2.0f;
}

static uint32_t add_material(ub_scene *s, float ar, float ag, float ab, float er, float eg,
                             float eb)
{
  s->materials = grow(s->materials, s->material_count + 1, sizeof *s->materials);
  ub_material *m = s->materials + s->material_count;
  memset(m, 0, sizeof *m);
  m->albedo[0] = ar;
  m->albedo[1] = ag;
  m->albedo[2] = ab;
  m->emission[0] = er;
  m->emission[1] = eg;
  m->emission[2] = eb;
  return s->material_count++;
}

static void add_tri(ub_scene *s, const float a[3], const float b[3], const float c[3],
                    uint32_t mat)
{
  uint32_t v = s->vertex_count, t = s->triangle_count;
  s->positions = grow(s->positions, (v + 3) * 3, sizeof(float));
  s->normals = grow(s->normals, (v + 3) * 3, sizeof(float));
  s->uv1 = grow(s->uv1, (v + 3) * 2, sizeof(float));
  s->indices = grow(s->indices, (t + 1) * 3, sizeof(uint32_t));
  s->tri_material = grow(s->tri_material, t + 1, sizeof(uint32_t));
  s->tri_node = grow(s->tri_node, t + 1, sizeof(uint32_t));
  s->tri_flags = grow(s->tri_flags, t + 1, 1);
  const float *pts[3] = {a, b, c};
  float e1[3], e2[3], n[3];
  for (int i = 0; i < 3; i++) {
    e1[i] = b[i] - a[i];
    e2[i] = c[i] - a[i];
  }
  n[0] = e1[1] * e2[2] - e1[2] * e2[1];
  n[1] = e1[2] * e2[0] - e1[0] * e2[2];
  n[2] = e1[0] * e2[1] - e1[1] * e2[0];
  float len = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  for (int k = 0; k < 3; k++) {
    memcpy(s->positions + 3 * (v + k), pts[k], 3 * sizeof(float));
    for (int i = 0; i < 3; i++)
      s->normals[3 * (v + k) + i] = len > 0.0f ? n[i] / len : 0.0f;
    s->uv1[2 * (v + k)] = s->uv1[2 * (v + k) + 1] = 0.0f;
    s->indices[3 * t + k] = v + k;
  }
  s->tri_material[t] = mat;
  s->tri_node[t] = 0;
  s->tri_flags[t] = len > 0.0f ? 0 : UB_TRI_DEGENERATE;
  s->vertex_count += 3;
  s->triangle_count++;
}

/* Quad o, o+e1, o+e1+e2, o+e2; front side along e1 × e2. */
static void add_quad(ub_scene *s, const float o[3], const float e1[3], const float e2[3],
                     uint32_t mat)
{
  float b[3], c[3], d[3];
  for (int i = 0; i < 3; i++) {
    b[i] = o[i] + e1[i];
    c[i] = o[i] + e1[i] + e2[i];
    d[i] = o[i] + e2[i];
  }
  add_tri(s, o, b, c, mat);
  add_tri(s, o, c, d, mat);
}

/* Horizontal square of half-size h at height y, centred on the Y axis, front facing
 * up (up = 1) or down (up = 0). */
static void add_hsquare(ub_scene *s, float cx, float cz, float h, float y, int up,
                        uint32_t mat)
{
  float o[3] = {cx - h, y, cz - h};
  float ex[3] = {2 * h, 0, 0}, ez[3] = {0, 0, 2 * h};
  if (up)
    add_quad(s, o, ez, ex, mat); /* ez × ex = +Y */
  else
    add_quad(s, o, ex, ez, mat);
}

/* Axis-aligned box [lo, hi], faces pointing inward; mat[6] per face: -x +x -y +y -z +z. */
static void add_box_inward(ub_scene *s, const float lo[3], const float hi[3],
                           const uint32_t mat[6])
{
  float dx = hi[0] - lo[0], dy = hi[1] - lo[1], dz = hi[2] - lo[2];
  float X[3] = {dx, 0, 0}, Y[3] = {0, dy, 0}, Z[3] = {0, 0, dz};
  float o_hx[3] = {hi[0], lo[1], lo[2]}, o_hy[3] = {lo[0], hi[1], lo[2]},
        o_hz[3] = {lo[0], lo[1], hi[2]};
  add_quad(s, lo, Y, Z, mat[0]);   /* x = lo, normal Y×Z = +x (inward) */
  add_quad(s, o_hx, Z, Y, mat[1]); /* x = hi, normal Z×Y = -x */
  add_quad(s, lo, Z, X, mat[2]);   /* y = lo, +y */
  add_quad(s, o_hy, X, Z, mat[3]); /* y = hi, -y */
  add_quad(s, lo, X, Y, mat[4]);   /* z = lo, +z */
  add_quad(s, o_hz, Y, X, mat[5]); /* z = hi, -z */
}

static ub_light *add_light(ub_scene *s, ub_light_type type, float x, float y, float z,
                           float ir, float ig, float ib)
{
  s->lights = grow(s->lights, s->light_count + 1, sizeof *s->lights);
  ub_light *l = s->lights + s->light_count++;
  memset(l, 0, sizeof *l);
  l->type = type;
  l->cls = UB_LIGHT_STATIC;
  l->position[0] = x;
  l->position[1] = y;
  l->position[2] = z;
  l->direction[1] = -1.0f;
  l->intensity[0] = ir;
  l->intensity[1] = ig;
  l->intensity[2] = ib;
  l->cos_inner = 1.0f;
  l->cos_outer = -1.0f;
  l->dls = -1;
  l->node = 0;
  return l;
}

/* One node over all triangles, bounds. */
static void scene_finish(ub_scene *s)
{
  free(s->nodes);
  s->nodes = calloc(1, sizeof *s->nodes);
  s->node_count = 1;
  s->nodes[0].name = NULL;
  s->nodes[0].receiver = UB_RECEIVER_LIGHTMAP;
  s->nodes[0].door = s->nodes[0].door_open = s->nodes[0].semidynamic = -1;
  s->nodes[0].triangle_count = s->triangle_count;
  for (int i = 0; i < 3; i++) {
    s->bounds_min[i] = INFINITY;
    s->bounds_max[i] = -INFINITY;
  }
  for (uint32_t v = 0; v < s->vertex_count; v++)
    for (int i = 0; i < 3; i++) {
      s->bounds_min[i] = fminf(s->bounds_min[i], s->positions[3 * v + i]);
      s->bounds_max[i] = fmaxf(s->bounds_max[i], s->positions[3 * v + i]);
    }
}

static void scene_release(ub_scene *s)
{
  free(s->positions);
  free(s->normals);
  free(s->uv1);
  free(s->indices);
  free(s->tri_material);
  free(s->tri_node);
  free(s->tri_flags);
  free(s->materials);
  free(s->nodes);
  free(s->lights);
  free(s->dls_names);
  memset(s, 0, sizeof *s);
}

/* ---- running the tracer ------------------------------------------------------------- */

static void log_fn(void *user, ub_log_level level, const char *msg)
{
  if (user && level == UB_LOG_WARNING)
    ++*(int *)user;
  if (level <= UB_LOG_WARNING)
    fprintf(stderr, "[%s] %s\n", level == UB_LOG_ERROR ? "error" : "warning", msg);
}
static const ub_log test_log = {log_fn, NULL};

typedef struct fixture {
  ub_scene *s;
  ub_rt *rt;
  ub_emitters *em;
} fixture;

static void fixture_open(fixture *f, ub_scene *s)
{
  scene_finish(s);
  f->s = s;
  f->rt = NULL;
  f->em = NULL;
  ASSERT_OK(ub_rt_create(s, NULL, &test_log, &f->rt));
  ASSERT_OK(ub_emitters_build(s, &f->em));
}

static void fixture_close(fixture *f)
{
  ub_rt_free(f->rt);
  ub_emitters_free(f->em);
  scene_release(f->s);
}

typedef struct est {
  float e[3], se[3];
} est;

/* Defaults (ub_reference_params_init) with this receiver, path count and seed. */
static ub_reference_params ref_params(float px, float py, float pz, float nx, float ny,
                                      float nz, uint32_t spp, uint32_t seed)
{
  ub_reference_params p;
  ub_reference_params_init(&p);
  p.position[0] = px;
  p.position[1] = py;
  p.position[2] = pz;
  p.normal[0] = nx;
  p.normal[1] = ny;
  p.normal[2] = nz;
  p.spp = spp;
  p.seed = seed;
  return p;
}

static est run_full(const fixture *f, float px, float py, float pz, float nx, float ny,
                    float nz, uint32_t spp, uint32_t seed, uint32_t bounces,
                    const float *dls_weight, int threads)
{
  ub_reference_params p = ref_params(px, py, pz, nx, ny, nz, spp, seed);
  p.max_bounces = bounces;
  p.dls_weight = dls_weight;
  p.threads = threads;
  est r;
  memset(&r, 0, sizeof r);
  ASSERT_OK(ub_reference_irradiance(f->s, f->rt, f->em, &p, r.e, r.se, &test_log));
  return r;
}

static est run(const fixture *f, float px, float py, float pz, float nx, float ny, float nz,
               uint32_t spp, uint32_t bounces)
{
  return run_full(f, px, py, pz, nx, ny, nz, spp, 1, bounces, NULL, 0);
}

/* |got - want| <= k·s.e. + rel·|want|, per channel, and prints the measured error. */
static void check(const char *what, const est *r, const double want[3], double k, double rel)
{
  double worst = 0.0;
  for (int c = 0; c < 3; c++) {
    double err = fabs(r->e[c] - want[c]);
    double relerr = want[c] != 0.0 ? err / fabs(want[c]) : err;
    worst = fmax(worst, relerr);
    ASSERT_NEAR(r->e[c], want[c], k * r->se[c], rel);
  }
  printf("  %-44s E = (%.5g %.5g %.5g)  want (%.5g %.5g %.5g)  s.e. %.2g  %s %.2e\n", what,
         r->e[0], r->e[1], r->e[2], want[0], want[1], want[2], r->se[1],
         want[0] != 0.0 || want[1] != 0.0 ? "rel.err" : "abs.err", worst);
}

static const uint32_t UNL = UB_REFERENCE_UNLIMITED;

/* ---- cases -------------------------------------------------------------------------- */

static void test_point_light(void)
{
  printf("point light over an albedo-0 plane\n");
  ub_scene s;
  scene_init(&s);
  uint32_t black = add_material(&s, 0, 0, 0, 0, 0, 0);
  add_hsquare(&s, 0, 0, 100.0f, 0.0f, 1, black);
  const float I[3] = {10.0f, 20.0f, 5.0f};
  const float h = 2.0f;
  add_light(&s, UB_LIGHT_POINT, 0, h, 0, I[0], I[1], I[2]);
  fixture f;
  fixture_open(&f, &s);

  const float rs[] = {0.0f, 0.5f, 1.0f, 3.0f, 7.0f, 20.0f};
  for (size_t i = 0; i < sizeof rs / sizeof rs[0]; i++) {
    float r = rs[i];
    /* Receivers along a diagonal so both horizontal axes are exercised. */
    float x = r * 0.6f, z = -r * 0.8f;
    double g = h / pow((double)h * h + (double)r * r, 1.5);
    double want[3] = {I[0] * g, I[1] * g, I[2] * g};
    char what[64];
    snprintf(what, sizeof what, "r = %.1f m, unlimited bounces", r);
    est e = run(&f, x, 0.0f, z, 0, 1, 0, 256, UNL);
    check(what, &e, want, 0.0, 1e-4);
    ASSERT_TRUE(e.se[0] <= 1e-6 * want[0]);
  }
  /* Free-space receivers with tilted normals: E = I·max(0, n·l)/d². */
  const float tilt[][6] = {{1.0f, 0.5f, 0.5f, 0.6f, 0.8f, 0.0f},
                           {-2.0f, 1.5f, 1.0f, 0.0f, 0.0f, -1.0f},
                           {0.5f, 1.0f, 0.0f, -1.0f, 0.2f, 0.3f},
                           {0.5f, 1.0f, 0.0f, 1.0f, 0.0f, 0.0f}}; /* faces away: 0 */
  for (size_t i = 0; i < sizeof tilt / sizeof tilt[0]; i++) {
    const float *t = tilt[i];
    double l[3] = {0 - t[0], h - t[1], 0 - t[2]};
    double d2 = l[0] * l[0] + l[1] * l[1] + l[2] * l[2], d = sqrt(d2);
    double nn = sqrt((double)t[3] * t[3] + (double)t[4] * t[4] + (double)t[5] * t[5]);
    double c = (t[3] * l[0] + t[4] * l[1] + t[5] * l[2]) / (nn * d);
    double g = c > 0 ? c / d2 : 0.0;
    double want[3] = {I[0] * g, I[1] * g, I[2] * g};
    char what[64];
    snprintf(what, sizeof what, "free space, tilted normal #%zu", i);
    est e = run(&f, t[0], t[1], t[2], t[3], t[4], t[5], 256, UNL);
    check(what, &e, want, 0.0, 1e-4);
  }
  fixture_close(&f);

  /* The same light behind a small occluder: no light. */
  scene_init(&s);
  black = add_material(&s, 0, 0, 0, 0, 0, 0);
  add_hsquare(&s, 0, 0, 100.0f, 0.0f, 1, black);
  add_hsquare(&s, 0, 0, 0.5f, 1.0f, 1, black);
  add_light(&s, UB_LIGHT_POINT, 0, h, 0, I[0], I[1], I[2]);
  fixture_open(&f, &s);
  est e = run(&f, 0.1f, 0.0f, 0.1f, 0, 1, 0, 64, UNL);
  double zero[3] = {0, 0, 0};
  check("occluded by a quad", &e, zero, 0.0, 0.0);
  fixture_close(&f);
}

static void test_directional_light(void)
{
  printf("directional light over an albedo-0 plane\n");
  ub_scene s;
  scene_init(&s);
  uint32_t black = add_material(&s, 0, 0, 0, 0, 0, 0);
  add_hsquare(&s, 0, 0, 50.0f, 0.0f, 1, black);
  ub_light *l = add_light(&s, UB_LIGHT_DIRECTIONAL, 0, 0, 0, 3.0f, 2.0f, 1.0f);
  float d[3] = {0.3f, -0.8f, 0.2f};
  float dl = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  for (int i = 0; i < 3; i++)
    l->direction[i] = d[i] / dl;
  fixture f;
  fixture_open(&f, &s);
  est e = run(&f, 1.0f, 0.0f, 2.0f, 0, 1, 0, 64, UNL);
  double c = 0.8 / dl;
  double want[3] = {3.0 * c, 2.0 * c, 1.0 * c};
  check("sun, receiver on the plane", &e, want, 0.0, 1e-4);
  fixture_close(&f);
}

/* A black square of half size `half` at y = 0 facing up under a constant sky L, opened. */
static void sky_over_black(ub_scene *s, fixture *f, float half, const float L[3])
{
  scene_init(s);
  uint32_t black = add_material(s, 0, 0, 0, 0, 0, 0);
  add_hsquare(s, 0, 0, half, 0.0f, 1, black);
  s->has_sky = 1;
  memcpy(s->sky, L, sizeof s->sky);
  fixture_open(f, s);
}

static void test_sky(void)
{
  printf("constant sky\n");
  const float L[3] = {0.5f, 1.0f, 2.0f};
  ub_scene s;
  fixture f;
  sky_over_black(&s, &f, 10.0f, L);
  double want[3] = {M_PI * L[0], M_PI * L[1], M_PI * L[2]};
  est e = run(&f, 1.0f, 0.0f, -2.0f, 0, 1, 0, 4096, UNL);
  check("albedo-0 plane, receiver facing up", &e, want, 3.0, 0.01);
  e = run(&f, 1.0f, 0.0f, -2.0f, 0, 1, 0, 4096, 0);
  check("  same, max_bounces 0", &e, want, 3.0, 0.01);
  fixture_close(&f);

  /* Sky seen once bounced: a huge albedo-ρ plane, receiver 1 m above facing down.
   * The plane receives π·L, reflects ρ·L; the receiver sees only the plane (up to a
   * (h/R)² ≈ 1e-6 sliver of horizon): E = π·ρ·L, and 0 without bounces. */
  scene_init(&s);
  const float rho = 0.6f;
  uint32_t grey = add_material(&s, rho, rho, rho, 0, 0, 0);
  add_hsquare(&s, 0, 0, 1000.0f, 0.0f, 1, grey);
  s.has_sky = 1;
  memcpy(s.sky, L, sizeof s.sky);
  fixture_open(&f, &s);
  double want1[3] = {M_PI * rho * L[0], M_PI * rho * L[1], M_PI * rho * L[2]};
  double zero[3] = {0, 0, 0};
  e = run(&f, 0.0f, 1.0f, 0.0f, 0, -1, 0, 4096, 0);
  check("albedo-0.6 plane, facing down, 0 bounces", &e, zero, 0.0, 0.0);
  e = run(&f, 0.0f, 1.0f, 0.0f, 0, -1, 0, 4096, 1);
  check("albedo-0.6 plane, facing down, 1 bounce", &e, want1, 3.0, 0.01);
  e = run(&f, 0.0f, 1.0f, 0.0f, 0, -1, 0, 4096, UNL);
  check("albedo-0.6 plane, facing down, unlimited", &e, want1, 3.0, 0.01);
  fixture_close(&f);
}

/* ub_reference_radiance_sh: a point light and a sky over a huge black plane. The L2
 * truncation of the irradiance is closed-form: the sky's upper hemisphere gives
 * π·L·(1 + n_y)/2 (bands 0 and 1 only, so exactly), the light I/d²·Σ_l A_l·(2l+1)/(4π)·
 * P_l(ω·n). Checked at five normals within 4 s.e. + 0.3% of the largest value, and the
 * returned coefficients give the same irradiance as the returned L2 value. */
static void test_radiance_sh(void)
{
  printf("SH L2 projection (ub_reference_radiance_sh)\n");
  const float L[3] = {0.5f, 1.0f, 2.0f}, I[3] = {10.0f, 20.0f, 5.0f};
  const float lp[3] = {0.0f, 3.0f, 0.0f}, p[3] = {0.6f, 1.0f, -0.8f};
  ub_scene s;
  scene_init(&s);
  uint32_t black = add_material(&s, 0, 0, 0, 0, 0, 0);
  add_hsquare(&s, 0, 0, 1000.0f, 0.0f, 1, black);
  add_light(&s, UB_LIGHT_POINT, lp[0], lp[1], lp[2], I[0], I[1], I[2]);
  s.has_sky = 1;
  memcpy(s.sky, L, sizeof s.sky);
  fixture f;
  fixture_open(&f, &s);
  double w[3] = {lp[0] - p[0], lp[1] - p[1], lp[2] - p[2]};
  double d2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2], d = sqrt(d2);
  for (int k = 0; k < 3; k++)
    w[k] /= d;
  const float normals[5][3] = {{(float)w[0], (float)w[1], (float)w[2]},
                               {(float)-w[0], (float)-w[1], (float)-w[2]},
                               {0.8f, 0.0f, 0.6f}, /* perpendicular to ω */
                               {0, 1, 0},
                               {0, -1, 0}};
  const char *names[5] = {"toward the light", "away from the light", "perpendicular",
                          "up", "down"};
  for (int i = 0; i < 5; i++) {
    const float *n = normals[i];
    double x = w[0] * n[0] + w[1] * n[1] + w[2] * n[2];
    double kern = (M_PI + 3.0 * (2.0 * M_PI / 3.0) * x + 5.0 * (M_PI / 4.0) * 0.5 * (3 * x * x - 1)) /
                  (4.0 * M_PI);
    double want[3], big = 0.0;
    for (int c = 0; c < 3; c++) {
      want[c] = M_PI * L[c] * (1.0 + n[1]) / 2.0 + I[c] / d2 * kern;
      big = fmax(big, M_PI * L[c] + I[c] / d2 * 1.0625);
    }
    ub_reference_params rp = ref_params(p[0], p[1], p[2], n[0], n[1], n[2], 65536, 7);
    float sh[27], l2[3], se[3], from_sh[3];
    ASSERT_OK(ub_reference_radiance_sh(f.s, f.rt, f.em, &rp, sh, l2, se, &test_log));
    ub_sh2_irradiance(sh, n, from_sh);
    double worst = 0.0;
    for (int c = 0; c < 3; c++) {
      ASSERT_NEAR(l2[c], want[c], 4.0 * se[c] + 0.003 * big, 0.0);
      ASSERT_NEAR(from_sh[c], l2[c], 0.0, 1e-4);
      worst = fmax(worst, fabs(l2[c] - want[c]) / big);
    }
    printf("  %-22s L2 E = (%.4g %.4g %.4g) want (%.4g %.4g %.4g) s.e. %.2g, error %.2e of "
           "the peak\n", names[i], l2[0], l2[1], l2[2], want[0], want[1], want[2], se[1], worst);
  }
  fixture_close(&f);
}

/* Irradiance at a point a height h below the corner of a parallel a×b Lambertian
 * rectangle of radiance Le: E = Le·π·F, with the corner form factor F. */
static double corner_irradiance(double a, double b, double h, double le)
{
  double A = a / h, B = b / h;
  double f = (A / sqrt(1 + A * A) * atan(B / sqrt(1 + A * A)) +
              B / sqrt(1 + B * B) * atan(A / sqrt(1 + B * B))) /
             (2.0 * M_PI);
  return le * M_PI * f;
}

static void test_emissive_rectangle(void)
{
  printf("emissive rectangle over an albedo-0 plane\n");
  ub_scene s;
  scene_init(&s);
  uint32_t black = add_material(&s, 0, 0, 0, 0, 0, 0);
  uint32_t lamp = add_material(&s, 0, 0, 0, 4.0f, 2.0f, 1.0f);
  add_hsquare(&s, 0, 0, 20.0f, 0.0f, 1, black);
  add_hsquare(&s, 0, 0, 0.5f, 1.0f, 0, lamp);     /* 1×1 m at 1 m, facing down */
  fixture f;
  fixture_open(&f, &s);
  double E = 4.0 * corner_irradiance(0.5, 0.5, 1.0, 1.0);
  double want[3] = {4.0 * E, 2.0 * E, 1.0 * E};
  est e = run(&f, 0.0f, 0.0f, 0.0f, 0, 1, 0, 16384, UNL);
  check("under the centre, facing up", &e, want, 3.0, 0.01);
  /* Below a corner of the rectangle: a single corner term. */
  double Eq = corner_irradiance(1.0, 1.0, 1.0, 1.0);
  double want_c[3] = {4.0 * Eq, 2.0 * Eq, 1.0 * Eq};
  e = run(&f, 0.5f, 0.0f, 0.5f, 0, 1, 0, 16384, UNL);
  check("under a corner, facing up", &e, want_c, 3.0, 0.01);
  fixture_close(&f);

  /* The same rectangle facing up: it emits nothing downward. */
  scene_init(&s);
  black = add_material(&s, 0, 0, 0, 0, 0, 0);
  lamp = add_material(&s, 0, 0, 0, 4.0f, 2.0f, 1.0f);
  add_hsquare(&s, 0, 0, 20.0f, 0.0f, 1, black);
  add_hsquare(&s, 0, 0, 0.5f, 1.0f, 1, lamp);
  fixture_open(&f, &s);
  e = run(&f, 0.0f, 0.0f, 0.0f, 0, 1, 0, 4096, UNL);
  double zero[3] = {0, 0, 0};
  check("under a back-facing emitter", &e, zero, 0.0, 0.0);
  fixture_close(&f);
}

/* Closed cube [-1,1]³, every face inward with albedo rho and emission le. */
static void furnace_scene(ub_scene *s, float rho, float le)
{
  scene_init(s);
  uint32_t m = add_material(s, rho, rho, rho, le, le, le);
  const float lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
  const uint32_t mats[6] = {m, m, m, m, m, m};
  add_box_inward(s, lo, hi, mats);
}

static void test_furnace(void)
{
  printf("furnace (closed cube, Le = 1)\n");
  ub_scene s;
  fixture f;
  const uint32_t Ns[] = {0, 1, 2, 5, UNL};
  furnace_scene(&s, 0.5f, 1.0f);
  fixture_open(&f, &s);
  for (size_t i = 0; i < sizeof Ns / sizeof Ns[0]; i++) {
    uint32_t N = Ns[i];
    double sum = 0.0;
    if (N == UNL)
      sum = 1.0 / (1.0 - 0.5);
    else
      for (uint32_t k = 0; k <= N; k++)
        sum += pow(0.5, k);
    double w = M_PI * sum;
    double want[3] = {w, w, w};
    char what[80];
    if (N == UNL)
      snprintf(what, sizeof what, "rho 0.5, unlimited, centre");
    else
      snprintf(what, sizeof what, "rho 0.5, N = %u, centre", N);
    est e = run(&f, 0.1f, -0.2f, 0.3f, 0.3f, 0.9f, 0.1f, 16384, N);
    check(what, &e, want, 3.0, 0.01);
    if (N == UNL)
      snprintf(what, sizeof what, "rho 0.5, unlimited, on the floor");
    else
      snprintf(what, sizeof what, "rho 0.5, N = %u, on the floor", N);
    e = run(&f, 0.4f, -1.0f, -0.5f, 0, 1, 0, 16384, N);
    check(what, &e, want, 3.0, 0.01);
  }
  fixture_close(&f);

  furnace_scene(&s, 0.9f, 1.0f);
  fixture_open(&f, &s);
  double w = M_PI / (1.0 - 0.9);
  double want[3] = {w, w, w};
  est e = run(&f, 0.0f, 0.0f, 0.0f, 0, 1, 0, 16384, UNL);
  check("rho 0.9, unlimited, centre", &e, want, 3.0, 0.01);
  fixture_close(&f);
}

static void test_primary(void)
{
  printf("primary lights bake indirect only\n");
  ub_scene s;
  fixture f;
  scene_init(&s);
  uint32_t black = add_material(&s, 0, 0, 0, 0, 0, 0);
  add_hsquare(&s, 0, 0, 50.0f, 0.0f, 1, black);
  add_light(&s, UB_LIGHT_POINT, 0, 2.0f, 0, 10, 10, 10)->cls = UB_LIGHT_PRIMARY;
  fixture_open(&f, &s);
  est e = run(&f, 0.5f, 0.0f, 0.0f, 0, 1, 0, 1024, UNL);
  double zero[3] = {0, 0, 0};
  check("albedo-0 plane: nothing", &e, zero, 0.0, 0.0);
  fixture_close(&f);

  /* Floor (ρ 0.5) under a white ceiling (ρ 0.8) 3 m up; light at 2 m. */
  est st, st0, pr;
  double direct;
  {
    const float I = 10.0f, hl = 2.0f;
    float rx = 1.0f, rz = 0.5f;
    double d2 = rx * rx + rz * rz + hl * hl;
    direct = I * hl / (d2 * sqrt(d2));
    for (int pass = 0; pass < 2; pass++) {
      scene_init(&s);
      uint32_t floor = add_material(&s, 0.5f, 0.5f, 0.5f, 0, 0, 0);
      uint32_t white = add_material(&s, 0.8f, 0.8f, 0.8f, 0, 0, 0);
      add_hsquare(&s, 0, 0, 10.0f, 0.0f, 1, floor);
      add_hsquare(&s, 0, 0, 10.0f, 3.0f, 0, white);
      ub_light *l = add_light(&s, UB_LIGHT_POINT, 0, hl, 0, I, I, I);
      l->cls = pass ? UB_LIGHT_PRIMARY : UB_LIGHT_STATIC;
      fixture_open(&f, &s);
      if (pass == 0) {
        st = run_full(&f, rx, 0, rz, 0, 1, 0, 65536, 11, UNL, NULL, 0);
        st0 = run_full(&f, rx, 0, rz, 0, 1, 0, 256, 12, 0, NULL, 0);
      } else {
        pr = run_full(&f, rx, 0, rz, 0, 1, 0, 65536, 13, UNL, NULL, 0);
      }
      fixture_close(&f);
    }
  }
  double wd[3] = {direct, direct, direct};
  check("static light, 0 bounces = analytic direct", &st0, wd, 0.0, 1e-4);
  double diff[3];
  est cmp = pr;
  for (int c = 0; c < 3; c++) {
    diff[c] = st.e[c] - direct;
    cmp.se[c] = sqrtf(st.se[c] * st.se[c] + pr.se[c] * pr.se[c]);
  }
  check("primary = static - direct (room)", &cmp, diff, 3.0, 0.02);
  ASSERT_TRUE(pr.e[0] > 0.05 * direct); /* the bounce is really there */
}

static void test_dls(void)
{
  printf("dynamic light set weights\n");
  ub_scene s;
  fixture f;
  scene_init(&s);
  uint32_t black = add_material(&s, 0, 0, 0, 0, 0, 0);
  add_hsquare(&s, 0, 0, 50.0f, 0.0f, 1, black);
  add_light(&s, UB_LIGHT_POINT, -1.0f, 2.0f, 0, 1.0f, 2.0f, 3.0f);
  add_light(&s, UB_LIGHT_POINT, 1.0f, 1.0f, 0, 5.0f, 5.0f, 5.0f)->dls = 0;
  s.dls_count = 1;
  s.dls_names = calloc(1, sizeof *s.dls_names);
  s.dls_names[0] = "lamp";
  fixture_open(&f, &s);
  /* Receiver at the origin: light A at (-1,2,0), B at (1,1,0). */
  double ga = 2.0 / pow(5.0, 1.5), gb = 1.0 / pow(2.0, 1.5);
  double base[3] = {1.0 * ga, 2.0 * ga, 3.0 * ga};
  const float w_one[3] = {1, 1, 1}, w_off[3] = {0, 0, 0}, w_red[3] = {1, 0, 0};
  double all[3] = {base[0] + 5 * gb, base[1] + 5 * gb, base[2] + 5 * gb};
  double red[3] = {base[0] + 5 * gb, base[1], base[2]};
  est e = run_full(&f, 0, 0, 0, 0, 1, 0, 64, 1, UNL, NULL, 0);
  check("default weights (1)", &e, all, 0.0, 1e-4);
  e = run_full(&f, 0, 0, 0, 0, 1, 0, 64, 1, UNL, w_one, 0);
  check("weight 1", &e, all, 0.0, 1e-4);
  e = run_full(&f, 0, 0, 0, 0, 1, 0, 64, 1, UNL, w_off, 0);
  check("weight 0: the set is off", &e, base, 0.0, 1e-4);
  e = run_full(&f, 0, 0, 0, 0, 1, 0, 64, 1, UNL, w_red, 0);
  check("weight (1,0,0): red only", &e, red, 0.0, 1e-4);

  /* A light naming a set the scene does not have. */
  s.lights[1].dls = 3;
  ub_reference_params p;
  ub_reference_params_init(&p);
  float out[3] = {-7, -7, -7}, se[3];
  ASSERT_TRUE(ub_reference_irradiance(f.s, f.rt, f.em, &p, out, se, NULL) ==
              UB_ERR_INVALID_DATA);
  ASSERT_TRUE(out[0] == -7.0f);
  s.dls_names[0] = NULL;
  fixture_close(&f);
}

static void test_spot(void)
{
  printf("spot light cones\n");
  ub_scene s;
  fixture f;
  scene_init(&s);
  uint32_t black = add_material(&s, 0, 0, 0, 0, 0, 0);
  add_hsquare(&s, 0, 0, 50.0f, 0.0f, 1, black);
  const float h = 3.0f, I = 50.0f;
  ub_light *l = add_light(&s, UB_LIGHT_SPOT, 0, h, 0, I, I, I);
  double ci = cos(20.0 * M_PI / 180.0), co = cos(30.0 * M_PI / 180.0);
  l->cos_inner = (float)ci;
  l->cos_outer = (float)co;
  fixture_open(&f, &s);
  const double angles[] = {0.0, 10.0, 19.0, 25.0, 31.0, 45.0};
  for (size_t i = 0; i < sizeof angles / sizeof angles[0]; i++) {
    double th = angles[i] * M_PI / 180.0;
    double r = h * tan(th);
    double ct = cos(th);
    double a = (ct - co) / (ci - co);
    a = a < 0 ? 0 : (a > 1 ? 1 : a);
    double g = h / pow((double)h * h + r * r, 1.5) * a * a;
    double want[3] = {I * g, I * g, I * g};
    char what[64];
    snprintf(what, sizeof what, "%.0f deg off axis%s", angles[i],
             angles[i] < 20 ? " (inner cone)" : angles[i] > 30 ? " (outside)" : "");
    est e = run(&f, (float)r, 0.0f, 0.0f, 0, 1, 0, 64, UNL);
    check(what, &e, want, 0.0, 1e-4);
    if (angles[i] > 30)
      ASSERT_TRUE(e.e[0] == 0.0f);
  }
  fixture_close(&f);
}

/* Cornell-like box: 2 m cube, red/green side walls, white rest, an emissive panel just
 * under the ceiling, a point light and a small box inside. */
static void cornell_scene(ub_scene *s)
{
  scene_init(s);
  uint32_t white = add_material(s, 0.73f, 0.73f, 0.73f, 0, 0, 0);
  uint32_t red = add_material(s, 0.65f, 0.05f, 0.05f, 0, 0, 0);
  uint32_t green = add_material(s, 0.12f, 0.45f, 0.15f, 0, 0, 0);
  uint32_t lamp = add_material(s, 0.78f, 0.78f, 0.78f, 15.0f, 12.0f, 8.0f);
  const float lo[3] = {-1, 0, -1}, hi[3] = {1, 2, 1};
  const uint32_t mats[6] = {red, green, white, white, white, white};
  add_box_inward(s, lo, hi, mats);
  add_hsquare(s, 0, 0, 0.25f, 1.98f, 0, lamp);
  /* A small block (its faces pointing inward too: both sides reflect anyway). */
  const float blo[3] = {-0.6f, 0.0f, -0.5f}, bhi[3] = {-0.1f, 0.9f, 0.1f};
  const uint32_t bm[6] = {white, white, white, white, white, white};
  add_box_inward(s, blo, bhi, bm);
  add_light(s, UB_LIGHT_POINT, 0.5f, 1.5f, 0.3f, 2.0f, 2.0f, 2.0f);
}

static void test_determinism_and_speed(void)
{
  printf("determinism and throughput (Cornell box)\n");
  ub_scene s;
  fixture f;
  cornell_scene(&s);
  fixture_open(&f, &s);
  est a = run_full(&f, 0.5f, 0.0f, 0.4f, 0, 1, 0, 4096, 7, UNL, NULL, 1);
  est b = run_full(&f, 0.5f, 0.0f, 0.4f, 0, 1, 0, 4096, 7, UNL, NULL, 2);
  est c = run_full(&f, 0.5f, 0.0f, 0.4f, 0, 1, 0, 4096, 7, UNL, NULL, 0);
  ASSERT_TRUE(memcmp(&a, &b, sizeof a) == 0);
  ASSERT_TRUE(memcmp(&a, &c, sizeof a) == 0);
  printf("  threads 1/2/default: (%.9g %.9g %.9g) %s\n", a.e[0], a.e[1], a.e[2],
         memcmp(&a, &b, sizeof a) == 0 && memcmp(&a, &c, sizeof a) == 0 ? "bit-identical"
                                                                         : "DIFFER");
  for (int i = 0; i < 3; i++)
    ASSERT_TRUE(isfinite(a.e[i]) && a.e[i] > 0.0f && isfinite(a.se[i]));
  /* A different seed agrees within the noise. */
  est d = run_full(&f, 0.5f, 0.0f, 0.4f, 0, 1, 0, 4096, 8, UNL, NULL, 0);
  for (int i = 0; i < 3; i++)
    ASSERT_NEAR(d.e[i], a.e[i], 4.0 * sqrt(a.se[i] * a.se[i] + d.se[i] * d.se[i]), 0.0);

  /* Throughput on both cores. */
  uint64_t r0 = ub_rt_rays_traced(f.rt);
  double t0 = omp_get_wtime();
  const int reps = 4;
  for (int i = 0; i < reps; i++)
    run_full(&f, -0.3f + 0.1f * i, 1.0f, 0.2f, 0.3f, 0.5f, -0.2f, 4096, 100 + i, UNL, NULL,
             0);
  double dt = omp_get_wtime() - t0;
  uint64_t rays = ub_rt_rays_traced(f.rt) - r0;
  printf("  4096 spp, unlimited bounces: %.1f ms per estimate, %.2f M rays/s (%d threads)\n",
         dt / reps * 1e3, rays / dt * 1e-6, omp_get_max_threads());
  ASSERT_TRUE(dt / reps < 1.0);
  fixture_close(&f);
}

static void test_invalid(void)
{
  printf("invalid arguments\n");
  ub_scene s;
  fixture f;
  scene_init(&s);
  uint32_t black = add_material(&s, 0, 0, 0, 0, 0, 0);
  add_hsquare(&s, 0, 0, 1.0f, 0.0f, 1, black);
  fixture_open(&f, &s);
  ub_reference_params p;
  ub_reference_params_init(&p);
  float out[3] = {-7, -7, -7}, se[3] = {-7, -7, -7};
  p.normal[0] = p.normal[1] = p.normal[2] = 0.0f;
  ASSERT_TRUE(ub_reference_irradiance(f.s, f.rt, f.em, &p, out, se, NULL) ==
              UB_ERR_INVALID_ARGUMENT);
  p.normal[1] = NAN;
  ASSERT_TRUE(ub_reference_irradiance(f.s, f.rt, f.em, &p, out, se, NULL) ==
              UB_ERR_INVALID_ARGUMENT);
  p.normal[1] = 1.0f;
  p.position[2] = INFINITY;
  ASSERT_TRUE(ub_reference_irradiance(f.s, f.rt, f.em, &p, out, se, NULL) ==
              UB_ERR_INVALID_ARGUMENT);
  ASSERT_TRUE(out[0] == -7.0f && se[0] == -7.0f);
  /* em = NULL builds the emitters internally; spp 1 gives s.e. 0. */
  p.position[2] = 0.0f;
  p.spp = 1;
  ASSERT_OK(ub_reference_irradiance(f.s, f.rt, NULL, &p, out, se, NULL));
  ASSERT_TRUE(out[0] == 0.0f && se[0] == 0.0f);
  fixture_close(&f);
}

static void test_nonfinite(void)
{
  printf("non-finite contributions are dropped\n");
  ub_scene s;
  fixture f;
  scene_init(&s);
  uint32_t black = add_material(&s, 0, 0, 0, 0, 0, 0);
  uint32_t hot = add_material(&s, 0, 0, 0, 1e38f, 1e38f, 1e38f);
  add_hsquare(&s, 0, 0, 20.0f, 0.0f, 1, black);
  add_hsquare(&s, 0, 0, 5.0f, 1.0f, 0, hot); /* 100 m², 1 m up: E/sample ≈ 1e40 */
  fixture_open(&f, &s);
  int warnings = 0;
  ub_log counting = {log_fn, &warnings};
  ub_reference_params p;
  ub_reference_params_init(&p);
  p.spp = 256;
  float out[3], se[3];
  ASSERT_OK(ub_reference_irradiance(f.s, f.rt, f.em, &p, out, se, &counting));
  for (int i = 0; i < 3; i++)
    ASSERT_TRUE(isfinite(out[i]) && isfinite(se[i]));
  ASSERT_TRUE(warnings == 1);
  printf("  E = (%g %g %g), s.e. %g, %d warning\n", out[0], out[1], out[2], se[0], warnings);
  fixture_close(&f);
}

/* Limits: a receiver beyond the level loader's coordinate limit (Embree aborted on 2e18;
 * up to 1e18 gave 0) and more paths than UB_REFERENCE_MAX_SPP (UINT32_MAX - 4 once wrapped
 * the block count to 0: E = 0, s.e. 0) are errors with one message; a point at the limit
 * and a count past one round of blocks trace normally. */
static void count_errors(void *user, ub_log_level level, const char *msg)
{
  if (level == UB_LOG_ERROR)
    ++*(int *)user;
  fprintf(stderr, "[%s] %s\n", level == UB_LOG_ERROR ? "error" : "note", msg);
}

static void test_limits(void)
{
  printf("limits: far receivers, path counts\n");
  const float L[3] = {0.5f, 1.0f, 2.0f};
  ub_scene s;
  fixture f;
  sky_over_black(&s, &f, 1000.0f, L);
  int errors = 0;
  ub_log counting = {count_errors, &errors};
  static const float far[][3] = {{2e18f, 0, 0}, {0, -1e18f, 0}, {0, 0, 1.5e7f}};
  for (int k = 0; k < 3; k++) {
    ub_reference_params p = ref_params(far[k][0], far[k][1], far[k][2], 0, 1, 0, 64, 1);
    float out[3] = {-7, -7, -7}, se[3] = {-7, -7, -7}, sh[27] = {-7};
    errors = 0;
    ASSERT_TRUE(ub_reference_irradiance(f.s, f.rt, f.em, &p, out, se, &counting) ==
                UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_reference_radiance_sh(f.s, f.rt, f.em, &p, sh, out, se, &counting) ==
                UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(errors == 2);
    ASSERT_TRUE(out[0] == -7.0f && se[0] == -7.0f && sh[0] == -7.0f);
  }
  ub_reference_params p = ref_params(-1e7f, 1.0f, 0, 0, 1, 0, 64, 1);
  float out[3], se[3];
  ASSERT_OK(ub_reference_irradiance(f.s, f.rt, f.em, &p, out, se, &test_log));

  static const uint32_t too_many[] = {UB_REFERENCE_MAX_SPP + 1u, UINT32_MAX - 4u, UINT32_MAX};
  for (int k = 0; k < 3; k++) {
    p = ref_params(0, 1.0f, 0, 0, 1, 0, too_many[k], 1);
    out[0] = se[0] = -7.0f;
    errors = 0;
    ASSERT_TRUE(ub_reference_irradiance(f.s, f.rt, f.em, &p, out, se, &counting) ==
                UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(errors == 1 && out[0] == -7.0f && se[0] == -7.0f);
  }

  /* 6 Mi paths, more than one round of blocks: a horizontal receiver 1 cm over the black
   * plane sees the sky through exactly half its cosine lobe, so each path gives π·L or 0:
   * E = π·L/2 and s.e. = π·L/(2·sqrt(spp)), which fails if a round is lost. */
  const uint32_t spp = 6u << 20;
  est e = run_full(&f, 0, 0.01f, 0, 1, 0, 0, spp, 3, UNL, NULL, 0);
  double want[3] = {M_PI * L[0] / 2, M_PI * L[1] / 2, M_PI * L[2] / 2};
  check("6 Mi paths, horizontal over a black plane", &e, want, 4.0, 1e-4);
  for (int c = 0; c < 3; c++)
    ASSERT_NEAR(e.se[c], want[c] / sqrt((double)spp), 0.0, 0.01);
  fixture_close(&f);
}

int main(void)
{
  test_point_light();
  test_directional_light();
  test_sky();
  test_radiance_sh();
  test_emissive_rectangle();
  test_furnace();
  test_primary();
  test_dls();
  test_spot();
  test_determinism_and_speed();
  test_invalid();
  test_nonfinite();
  test_limits();
  TEST_MAIN_END();
}
