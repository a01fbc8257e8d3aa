/* tests/test_lightmap.c — lightmap atlases, rasterisation, sample placement, dilation and
 * atlas images (lightmaps/lightmap.h, lightmaps/image.h). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#include "bake/rt.h"
#include "lightmaps/image.h"
#include "lightmaps/lightmap.h"
#include "test_util.h"
#include "ubake/scene.h"

static void log_fn(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  fprintf(stderr, "[%s] %s\n", level == UB_LOG_ERROR ? "error" : level == UB_LOG_WARNING ? "warn" : "info",
          msg);
}
static const ub_log g_log = {log_fn, NULL};

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---------------------------------------------------------------------------------- */
/* a hand-built scene */

typedef struct builder {
  ub_scene *s;
  uint32_t vcap, tcap;
} builder;

static void b_reserve(builder *b, uint32_t nv, uint32_t ntri)
{
  ub_scene *s = b->s;
  if (s->vertex_count + nv > b->vcap) {
    b->vcap = (s->vertex_count + nv) * 2;
    s->positions = realloc(s->positions, (size_t)b->vcap * 3 * sizeof(float));
    s->normals = realloc(s->normals, (size_t)b->vcap * 3 * sizeof(float));
    s->uv1 = realloc(s->uv1, (size_t)b->vcap * 2 * sizeof(float));
  }
  if (s->triangle_count + ntri > b->tcap) {
    b->tcap = (s->triangle_count + ntri) * 2;
    s->indices = realloc(s->indices, (size_t)b->tcap * 3 * sizeof(uint32_t));
    s->tri_material = realloc(s->tri_material, (size_t)b->tcap * sizeof(uint32_t));
    s->tri_node = realloc(s->tri_node, (size_t)b->tcap * sizeof(uint32_t));
    s->tri_flags = realloc(s->tri_flags, (size_t)b->tcap * sizeof(uint8_t));
  }
}

static uint32_t b_vertex(builder *b, const float p[3], const float n[3], const float *uv)
{
  ub_scene *s = b->s;
  uint32_t v = s->vertex_count++;
  memcpy(s->positions + 3 * v, p, 3 * sizeof(float));
  memcpy(s->normals + 3 * v, n, 3 * sizeof(float));
  s->uv1[2 * v] = uv ? uv[0] : 0.0f;
  s->uv1[2 * v + 1] = uv ? uv[1] : 0.0f;
  return v;
}

static void b_tri(builder *b, uint32_t node, uint32_t a, uint32_t c1, uint32_t c2, uint8_t flags)
{
  ub_scene *s = b->s;
  uint32_t t = s->triangle_count++;
  s->indices[3 * t] = a;
  s->indices[3 * t + 1] = c1;
  s->indices[3 * t + 2] = c2;
  s->tri_material[t] = 0;
  s->tri_node[t] = node;
  s->tri_flags[t] = flags;
  if (flags & UB_TRI_DEGENERATE)
    s->degenerate_count++;
}

/* Quad p0 p1 p2 p3, counter-clockwise seen from the side n points to. */
static void b_quad(builder *b, uint32_t node, const float p[4][3], const float n[3])
{
  b_reserve(b, 4, 2);
  uint32_t v[4];
  for (int i = 0; i < 4; i++)
    v[i] = b_vertex(b, p[i], n, NULL);
  b_tri(b, node, v[0], v[1], v[2], 0);
  b_tri(b, node, v[0], v[2], v[3], 0);
}

/* Axis-aligned box faces (outward normals) except the bottom. */
static void b_box_no_bottom(builder *b, uint32_t node, const float lo[3], const float hi[3])
{
  const float x0 = lo[0], y0 = lo[1], z0 = lo[2], x1 = hi[0], y1 = hi[1], z1 = hi[2];
  {
    const float p[4][3] = {{x0, y0, z0}, {x0, y0, z1}, {x0, y1, z1}, {x0, y1, z0}};
    const float n[3] = {-1, 0, 0};
    b_quad(b, node, p, n);
  }
  {
    const float p[4][3] = {{x1, y0, z1}, {x1, y0, z0}, {x1, y1, z0}, {x1, y1, z1}};
    const float n[3] = {1, 0, 0};
    b_quad(b, node, p, n);
  }
  {
    const float p[4][3] = {{x0, y1, z0}, {x0, y1, z1}, {x1, y1, z1}, {x1, y1, z0}};
    const float n[3] = {0, 1, 0};
    b_quad(b, node, p, n);
  }
  {
    const float p[4][3] = {{x1, y0, z0}, {x0, y0, z0}, {x0, y1, z0}, {x1, y1, z0}};
    const float n[3] = {0, 0, -1};
    b_quad(b, node, p, n);
  }
  {
    const float p[4][3] = {{x0, y0, z1}, {x1, y0, z1}, {x1, y1, z1}, {x0, y1, z1}};
    const float n[3] = {0, 0, 1};
    b_quad(b, node, p, n);
  }
}

static char *dupstr(const char *s)
{
  char *d = malloc(strlen(s) + 1);
  strcpy(d, s);
  return d;
}

/* Wall box: x in [WALL_X0, WALL_X1], y in [0, 2], z in [-2, 2], standing on the floor
 * (x in [-2, 3], z in [-2, 2]) which continues underneath it. A back wall at z = -2
 * faces the room. */
#define WALL_X0 1.05f
#define WALL_X1 1.30f
#define TEXEL 0.1f

enum { NODE_ROOM = 0, NODE_PROP = 1, NODE_AUTHORED = 2, NODE_COUNT = 3 };

static ub_scene *make_scene(void)
{
  builder b = {calloc(1, sizeof(ub_scene)), 0, 0};
  ub_scene *s = b.s;
  s->path = dupstr("(test scene)");
  s->texel_size = TEXEL;
  s->glg_spacing = 2.0f;
  s->material_count = 1;
  s->materials = calloc(1, sizeof(ub_material));
  s->materials[0].albedo[0] = s->materials[0].albedo[1] = s->materials[0].albedo[2] = 0.5f;
  s->materials[0].name = dupstr("grey");
  s->node_count = NODE_COUNT;
  s->nodes = calloc(NODE_COUNT, sizeof(ub_node));
  const char *names[NODE_COUNT] = {"room", "prop", "authored"};
  const ub_receiver_kind kinds[NODE_COUNT] = {UB_RECEIVER_LIGHTMAP, UB_RECEIVER_NONE,
                                              UB_RECEIVER_LIGHTMAP};
  for (int i = 0; i < NODE_COUNT; i++) {
    s->nodes[i].name = dupstr(names[i]);
    s->nodes[i].gltf_index = i;
    s->nodes[i].receiver = kinds[i];
    s->nodes[i].door = s->nodes[i].door_open = s->nodes[i].semidynamic = -1;
  }

  s->nodes[NODE_ROOM].first_triangle = 0;
  {
    const float p[4][3] = {{-2, 0, -2}, {-2, 0, 2}, {3, 0, 2}, {3, 0, -2}};
    const float n[3] = {0, 1, 0};
    b_quad(&b, NODE_ROOM, p, n);
  }
  {
    const float lo[3] = {WALL_X0, 0, -2}, hi[3] = {WALL_X1, 2, 2};
    b_box_no_bottom(&b, NODE_ROOM, lo, hi);
  }
  {
    const float p[4][3] = {{-2, 0, -2}, {WALL_X0, 0, -2}, {WALL_X0, 2, -2}, {-2, 2, -2}};
    const float n[3] = {0, 0, 1};
    b_quad(&b, NODE_ROOM, p, n);
  }
  { /* a degenerate triangle (collinear) */
    b_reserve(&b, 3, 1);
    const float n[3] = {0, 1, 0};
    const float p0[3] = {0, 1, 0}, p1[3] = {1, 1, 0}, p2[3] = {2, 1, 0};
    uint32_t a = b_vertex(&b, p0, n, NULL), c = b_vertex(&b, p1, n, NULL),
             d = b_vertex(&b, p2, n, NULL);
    b_tri(&b, NODE_ROOM, a, c, d, UB_TRI_DEGENERATE);
  }
  s->nodes[NODE_ROOM].triangle_count = s->triangle_count;

  s->nodes[NODE_PROP].first_triangle = s->triangle_count;
  {
    const float p[4][3] = {{-1.5f, 1, 0}, {-1.0f, 1, 0}, {-1.0f, 1.5f, 0}, {-1.5f, 1.5f, 0}};
    const float n[3] = {0, 0, 1};
    b_quad(&b, NODE_PROP, p, n);
  }
  s->nodes[NODE_PROP].triangle_count = s->triangle_count - s->nodes[NODE_PROP].first_triangle;

  s->nodes[NODE_AUTHORED].first_triangle = s->triangle_count;
  { /* ceiling triangle facing down, authored UVs */
    b_reserve(&b, 3, 1);
    const float n[3] = {0, -1, 0};
    const float p0[3] = {-2, 2.5f, -2}, p1[3] = {-2, 2.5f, 0}, p2[3] = {0, 2.5f, -2};
    const float u0[2] = {0.1f, 0.1f}, u1[2] = {0.1f, 0.9f}, u2[2] = {0.9f, 0.1f};
    uint32_t a = b_vertex(&b, p0, n, u0), c = b_vertex(&b, p1, n, u1),
             d = b_vertex(&b, p2, n, u2);
    b_tri(&b, NODE_AUTHORED, a, c, d, UB_TRI_HAS_UV1);
  }
  s->nodes[NODE_AUTHORED].triangle_count =
      s->triangle_count - s->nodes[NODE_AUTHORED].first_triangle;

  for (int a = 0; a < 3; a++) {
    s->bounds_min[a] = INFINITY;
    s->bounds_max[a] = -INFINITY;
  }
  for (uint32_t v = 0; v < s->vertex_count; v++)
    for (int a = 0; a < 3; a++) {
      s->bounds_min[a] = fminf(s->bounds_min[a], s->positions[3 * v + a]);
      s->bounds_max[a] = fmaxf(s->bounds_max[a], s->positions[3 * v + a]);
    }
  return s;
}

/* ---------------------------------------------------------------------------------- */
/* checks */

static double tri_area(const ub_scene *s, uint32_t t)
{
  const float *a = s->positions + 3 * s->indices[3 * t], *b = s->positions + 3 * s->indices[3 * t + 1],
              *c = s->positions + 3 * s->indices[3 * t + 2];
  double e1[3], e2[3];
  for (int i = 0; i < 3; i++) {
    e1[i] = b[i] - a[i];
    e2[i] = c[i] - a[i];
  }
  double x = e1[1] * e2[2] - e1[2] * e2[1], y = e1[2] * e2[0] - e1[0] * e2[2],
         z = e1[0] * e2[1] - e1[1] * e2[0];
  return 0.5 * sqrt(x * x + y * y + z * z);
}

static void tri_geo_normal(const ub_scene *s, uint32_t t, double n[3])
{
  const float *a = s->positions + 3 * s->indices[3 * t], *b = s->positions + 3 * s->indices[3 * t + 1],
              *c = s->positions + 3 * s->indices[3 * t + 2];
  double e1[3], e2[3];
  for (int i = 0; i < 3; i++) {
    e1[i] = b[i] - a[i];
    e2[i] = c[i] - a[i];
  }
  n[0] = e1[1] * e2[2] - e1[2] * e2[1];
  n[1] = e1[2] * e2[0] - e1[0] * e2[2];
  n[2] = e1[0] * e2[1] - e1[1] * e2[0];
  double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  for (int i = 0; i < 3; i++)
    n[i] /= l;
}

/* Texel (x, y) containing a point of triangle t at barycentrics (1-u-v, u, v). */
static void texel_at(const ub_lightmap *lm, uint32_t t, double u, double v, int64_t *x, int64_t *y)
{
  const ub_atlas *a = &lm->atlases[lm->tri_atlas[t]];
  const float *uv = lm->tri_uv + 6 * (size_t)t;
  double w = 1.0 - u - v;
  double px = (w * uv[0] + u * uv[2] + v * uv[4]) * a->width;
  double py = (w * uv[1] + u * uv[3] + v * uv[5]) * a->height;
  *x = (int64_t)floor(px);
  *y = (int64_t)floor(py);
  if (*x >= (int64_t)a->width)
    *x = a->width - 1;
  if (*y >= (int64_t)a->height)
    *y = a->height - 1;
}

/* Generic invariants for any scene: UVs in range, dense point samples of every lightmapped
 * triangle land on covered texels, texel tables consistent, samples finite and on the
 * front side of their texel's plane. Returns uncovered point count. */
static void check_invariants(const ub_scene *s, const ub_lightmap *lm, int strict_front)
{
  uint32_t bad_uv = 0, uncovered = 0, lit = 0;
  for (uint32_t t = 0; t < s->triangle_count; t++) {
    int32_t a = lm->tri_atlas[t];
    if (s->tri_flags[t] & UB_TRI_DEGENERATE) {
      ASSERT_TRUE(a == -1);
      continue;
    }
    uint32_t nd = s->tri_node[t];
    if (s->nodes[nd].receiver != UB_RECEIVER_LIGHTMAP) {
      ASSERT_TRUE(a == -1);
      continue;
    }
    ASSERT_TRUE(a >= 0 && (uint32_t)a < lm->atlas_count);
    if (a < 0)
      continue;
    lit++;
    for (int k = 0; k < 6; k++)
      if (!(lm->tri_uv[6 * (size_t)t + k] >= 0.0f && lm->tri_uv[6 * (size_t)t + k] <= 1.0f))
        bad_uv++;
    /* dense interior points (skip triangles with zero UV area: they get no texels) */
    const float *uv = lm->tri_uv + 6 * (size_t)t;
    double uva = fabs((uv[2] - uv[0]) * (uv[5] - uv[1]) - (uv[4] - uv[0]) * (uv[3] - uv[1]));
    if (!(uva * lm->atlases[a].width * lm->atlases[a].height > 1e-9))
      continue;
    const int N = 24;
    for (int i = 0; i <= N; i++)
      for (int j = 0; i + j <= N; j++) {
        double u = (i + 1e-3) / (N + 3e-3), v = (j + 1e-3) / (N + 3e-3);
        int64_t x, y;
        texel_at(lm, t, u, v, &x, &y);
        if (lm->atlases[a].texel_of[(size_t)y * lm->atlases[a].width + x] < 0)
          uncovered++;
      }
  }
  ASSERT_TRUE(bad_uv == 0);
  ASSERT_TRUE(uncovered == 0);
  if (uncovered)
    fprintf(stderr, "  %u triangle points on uncovered texels (%u lightmapped triangles)\n",
            uncovered, lit);

  uint32_t sum = 0, bad_index = 0, nonfinite = 0, behind = 0;
  for (uint32_t a = 0; a < lm->atlas_count; a++) {
    const ub_atlas *at = &lm->atlases[a];
    ASSERT_TRUE(at->first_texel == sum);
    ASSERT_TRUE(at->width <= UB_ATLAS_MAX_SIZE && at->height <= UB_ATLAS_MAX_SIZE);
    for (uint32_t y = 0; y < at->height; y++)
      for (uint32_t x = 0; x < at->width; x++) {
        int32_t ti = at->texel_of[(size_t)y * at->width + x];
        if (ti < 0)
          continue;
        if ((uint32_t)ti >= lm->texel_count || lm->texel_atlas[ti] != a ||
            lm->texel_xy[2 * ti] != x || lm->texel_xy[2 * ti + 1] != y ||
            lm->tri_atlas[lm->texel_tri[ti]] != (int32_t)a)
          bad_index++;
      }
    sum += at->texel_count;
  }
  ASSERT_TRUE(sum == lm->texel_count);
  ASSERT_TRUE(bad_index == 0);
  for (uint32_t ti = 0; ti < lm->texel_count; ti++) {
    double n[3];
    tri_geo_normal(s, lm->texel_tri[ti], n);
    const float *p0 = s->positions + 3 * s->indices[3 * lm->texel_tri[ti]];
    for (int j = 0; j < UB_TEXEL_SAMPLES; j++) {
      const float *sp = lm->sample_pos + ((size_t)ti * UB_TEXEL_SAMPLES + j) * 3;
      if (!isfinite(sp[0]) || !isfinite(sp[1]) || !isfinite(sp[2]))
        nonfinite++;
      double d = (sp[0] - p0[0]) * n[0] + (sp[1] - p0[1]) * n[1] + (sp[2] - p0[2]) * n[2];
      if (!(d > 0.0))
        behind++;
    }
    const float *tn = lm->texel_normal + 3 * (size_t)ti;
    double nl = sqrt(tn[0] * tn[0] + tn[1] * tn[1] + tn[2] * tn[2]);
    if (!(fabs(nl - 1.0) < 1e-3))
      nonfinite++;
  }
  ASSERT_TRUE(nonfinite == 0);
  if (strict_front)
    ASSERT_TRUE(behind == 0);
  else if (behind)
    printf("  %u sample points behind their own triangle's plane (curved/creased surfaces)\n",
           behind);
}

static int is_floor_tri(const ub_scene *s, uint32_t t)
{
  double n[3];
  tri_geo_normal(s, t, n);
  const float *p = s->positions + 3 * s->indices[3 * t];
  return s->tri_node[t] == NODE_ROOM && n[1] > 0.99 && fabsf(p[1]) < 1e-6f;
}

static void test_small_scene(const char *outdir)
{
  ub_scene *s = make_scene();
  ub_rt *rt = NULL;
  ASSERT_OK(ub_rt_create(s, NULL, &g_log, &rt));
  ub_lightmap *lm = NULL;
  ASSERT_OK(ub_lightmap_build(s, rt, 0.25f, &g_log, &lm));
  if (!lm) {
    ub_rt_free(rt);
    ub_scene_free(s);
    return;
  }
  printf("small scene: %u atlases, %u texels, %u charts, %u backface fixes, %u overlaps\n",
         lm->atlas_count, lm->texel_count, lm->chart_count, lm->backface_fixes,
         lm->overlap_texels);
  ASSERT_TRUE(lm->atlas_count == 2);
  ASSERT_TRUE(lm->atlases[0].generated == 0 && lm->atlases[1].generated == 1);
  ASSERT_TRUE(lm->overlap_texels == 0);
  check_invariants(s, lm, 1);

  /* authored atlas resolution: sqrt(world / uv area) / texel, multiple of 4 */
  {
    double world = 2.0, uvarea = 0.5 * 0.8 * 0.8;
    uint32_t expect = (uint32_t)ceil(sqrt(world / uvarea) / TEXEL);
    expect = (expect + 3) & ~3u;
    if (expect < 16)
      expect = 16;
    ASSERT_TRUE(lm->atlases[0].width == expect && lm->atlases[0].height == expect);
  }

  /* generated texels ≈ area / texel² (conservative borders add some) */
  {
    double want = 0.0;
    for (uint32_t t = 0; t < s->triangle_count; t++)
      if (lm->tri_atlas[t] == 1)
        want += tri_area(s, t) / (TEXEL * TEXEL);
    double ratio = lm->atlases[1].texel_count / want;
    printf("generated atlas %ux%u: %u texels for %.0f texels of area (ratio %.2f)\n",
           lm->atlases[1].width, lm->atlases[1].height, lm->atlases[1].texel_count, want,
           ratio);
    ASSERT_TRUE(ratio >= 1.0 && ratio <= 1.6);
  }

  /* charts never share texels, padding included: covered texels of different charts
   * are ≥ 5 texels apart (2 padding texels on each side) */
  {
    const ub_atlas *at = &lm->atlases[1];
    uint32_t clashes = 0;
    for (uint32_t y = 0; y < at->height; y++)
      for (uint32_t x = 0; x < at->width; x++) {
        int32_t ti = at->texel_of[(size_t)y * at->width + x];
        if (ti < 0)
          continue;
        int32_t ca = lm->tri_chart[lm->texel_tri[ti]];
        ASSERT_TRUE(ca >= 0);
        for (int dy = -4; dy <= 4; dy++)
          for (int dx = -4; dx <= 4; dx++) {
            int64_t xx = (int64_t)x + dx, yy = (int64_t)y + dy;
            if (xx < 0 || yy < 0 || xx >= at->width || yy >= at->height)
              continue;
            int32_t tj = at->texel_of[(size_t)yy * at->width + xx];
            if (tj >= 0 && lm->tri_chart[lm->texel_tri[tj]] != ca)
              clashes++;
          }
      }
    ASSERT_TRUE(clashes == 0);
    /* independent: dense points of each chart's triangles, per-texel chart id */
    int32_t *owner = malloc((size_t)at->width * at->height * sizeof *owner);
    for (size_t i = 0; i < (size_t)at->width * at->height; i++)
      owner[i] = -1;
    uint32_t shared = 0;
    for (uint32_t t = 0; t < s->triangle_count; t++) {
      if (lm->tri_atlas[t] != 1)
        continue;
      for (int i = 0; i <= 40; i++)
        for (int j = 0; i + j <= 40; j++) {
          int64_t x, y;
          texel_at(lm, t, i / 40.0, j / 40.0, &x, &y);
          int32_t *o = &owner[(size_t)y * at->width + x];
          if (*o >= 0 && *o != lm->tri_chart[t])
            shared++;
          *o = lm->tri_chart[t];
        }
    }
    ASSERT_TRUE(shared == 0);
    free(owner);
    printf("generated charts: %u, clashes %u, shared texels %u\n", lm->chart_count, clashes, shared);
    ASSERT_TRUE(lm->chart_count >= 7); /* floor, 5 box faces, back wall at least */
  }

  /* The junction: floor samples stay above the floor, out of the wall box, in the same
   * room as the texel, and in front of the back wall. Texels whose whole footprint lies
   * under the wall (centre more than half a texel diagonal inside) see nothing but the
   * wall's inside and are never visible: short rays cannot rescue them, skip those. */
  {
    uint32_t floor_texels = 0, inside_wall = 0, wrong_room = 0, below = 0, behind_back = 0;
    uint32_t under_wall_centres = 0;
    for (uint32_t ti = 0; ti < lm->texel_count; ti++) {
      if (!is_floor_tri(s, lm->texel_tri[ti]))
        continue;
      floor_texels++;
      const float *c = lm->texel_pos + 3 * (size_t)ti;
      int side = c[0] < WALL_X0 ? -1 : c[0] > WALL_X1 ? 1 : 0;
      under_wall_centres += side == 0;
      const float hd = 0.5f * TEXEL * 1.41421356f;
      if (c[0] > WALL_X0 + hd && c[0] < WALL_X1 - hd)
        continue;
      for (int j = 0; j < UB_TEXEL_SAMPLES; j++) {
        const float *sp = lm->sample_pos + ((size_t)ti * UB_TEXEL_SAMPLES + j) * 3;
        if (!(sp[1] > 0.0f && sp[1] < 0.01f))
          below++;
        if (sp[0] > WALL_X0 && sp[0] < WALL_X1 && sp[1] < 2.0f && fabsf(sp[2]) < 2.0f)
          inside_wall++;
        if ((side < 0 && !(sp[0] < WALL_X0)) || (side > 0 && !(sp[0] > WALL_X1)))
          wrong_room++;
        if (c[0] < WALL_X0 && !(sp[2] > -2.0f)) /* the back wall spans x < WALL_X0 */
          behind_back++;
      }
    }
    printf("floor: %u texels (%u centred under the wall), inside wall %u, wrong room %u, "
           "below %u, behind back wall %u\n",
           floor_texels, under_wall_centres, inside_wall, wrong_room, below, behind_back);
    ASSERT_TRUE(floor_texels > 0 && under_wall_centres > 0);
    ASSERT_TRUE(inside_wall == 0);
    ASSERT_TRUE(wrong_room == 0);
    ASSERT_TRUE(below == 0);
    ASSERT_TRUE(behind_back == 0);
    ASSERT_TRUE(lm->backface_fixes > 0);
  }

  /* Determinism across thread counts. */
#ifdef _OPENMP
  {
    int saved = omp_get_max_threads();
    omp_set_num_threads(1);
    ub_lightmap *lm1 = NULL;
    ASSERT_OK(ub_lightmap_build(s, rt, 0.25f, NULL, &lm1));
    omp_set_num_threads(saved > 1 ? saved : 2);
    if (lm1) {
      ASSERT_TRUE(lm1->texel_count == lm->texel_count);
      if (lm1->texel_count == lm->texel_count) {
        ASSERT_TRUE(memcmp(lm1->sample_pos, lm->sample_pos,
                           (size_t)lm->texel_count * UB_TEXEL_SAMPLES * 3 * sizeof(float)) == 0);
        ASSERT_TRUE(memcmp(lm1->texel_pos, lm->texel_pos,
                           (size_t)lm->texel_count * 3 * sizeof(float)) == 0);
        ASSERT_TRUE(memcmp(lm1->tri_uv, lm->tri_uv, (size_t)s->triangle_count * 6 * sizeof(float)) == 0);
      }
      ub_lightmap_free(lm1);
    }
  }
#endif

  /* Dilation on the generated atlas: covered texels unchanged, 2 rings filled, nothing
   * beyond. Image = per-texel normal (3 channels), padding NaN-free zeros. */
  {
    const ub_atlas *at = &lm->atlases[1];
    size_t npx = (size_t)at->width * at->height;
    float *img = calloc(npx * 3, sizeof *img);
    uint8_t *cov = calloc(npx, 1);
    for (size_t i = 0; i < npx; i++)
      if (at->texel_of[i] >= 0) {
        cov[i] = 1;
        for (int c = 0; c < 3; c++)
          img[3 * i + c] = 1.0f + lm->texel_normal[3 * (size_t)at->texel_of[i] + c];
      }
    float *before = malloc(npx * 3 * sizeof *before);
    memcpy(before, img, npx * 3 * sizeof *before);
    ub_lightmap_dilate(img, cov, at->width, at->height, 3, 2);
    uint32_t changed = 0, unfilled = 0, overfilled = 0;
    for (uint32_t y = 0; y < at->height; y++)
      for (uint32_t x = 0; x < at->width; x++) {
        size_t i = (size_t)y * at->width + x;
        if (cov[i]) {
          changed += memcmp(img + 3 * i, before + 3 * i, 3 * sizeof(float)) != 0;
          continue;
        }
        int dist = 99; /* Chebyshev distance to the nearest covered texel, up to 3 */
        for (int dy = -3; dy <= 3; dy++)
          for (int dx = -3; dx <= 3; dx++) {
            int64_t xx = (int64_t)x + dx, yy = (int64_t)y + dy;
            if (xx < 0 || yy < 0 || xx >= at->width || yy >= at->height)
              continue;
            if (cov[(size_t)yy * at->width + xx]) {
              int d = abs(dx) > abs(dy) ? abs(dx) : abs(dy);
              if (d < dist)
                dist = d;
            }
          }
        int filled = img[3 * i] != 0.0f || img[3 * i + 1] != 0.0f || img[3 * i + 2] != 0.0f;
        if (dist <= 2 && !filled)
          unfilled++;
        if (dist > 2 && filled)
          overfilled++;
      }
    ASSERT_TRUE(changed == 0);
    ASSERT_TRUE(unfilled == 0);
    ASSERT_TRUE(overfilled == 0);

    /* EXR round trip with the AHD channel names. */
    float *ahd = malloc(npx * UB_AHD_EXR_CHANNELS * sizeof *ahd);
    for (size_t i = 0; i < npx; i++)
      for (int c = 0; c < UB_AHD_EXR_CHANNELS; c++)
        ahd[i * UB_AHD_EXR_CHANNELS + c] =
            (c < 3 ? img[3 * i + c] * 10.0f : c < 6 ? img[3 * i + c - 3] - 1.0f : 0.001f * (float)(i % 997)) *
            (c == 8 ? -1.0f : 1.0f);
    char path[1200], png[1200];
    snprintf(path, sizeof path, "%s/test_lightmap_ahd.exr", outdir);
    snprintf(png, sizeof png, "%s/test_lightmap_preview.png", outdir);
    ASSERT_OK(ub_image_write_exr(path, at->width, at->height, UB_AHD_EXR_CHANNELS,
                                 ub_ahd_exr_channel_names, ahd, &g_log));
    ub_image *back = NULL;
    ASSERT_OK(ub_image_read_exr(path, &g_log, &back));
    if (back) {
      ASSERT_TRUE(back->width == at->width && back->height == at->height &&
                  back->channels == UB_AHD_EXR_CHANNELS);
      double worst = 0.0;
      int missing = 0;
      for (int c = 0; c < UB_AHD_EXR_CHANNELS; c++) {
        int bc = ub_image_channel(back, ub_ahd_exr_channel_names[c]);
        if (bc < 0) {
          missing++;
          continue;
        }
        for (size_t i = 0; i < npx; i++) {
          double a = ahd[i * UB_AHD_EXR_CHANNELS + c], b2 = back->data[i * back->channels + bc];
          double err = fabs(a - b2) / (fabs(a) + 6.2e-5); /* half: 2^-11 relative, subnormal floor */
          if (err > worst)
            worst = err;
        }
      }
      ASSERT_TRUE(missing == 0);
      printf("EXR round trip %s: worst relative error %.2e\n", path, worst);
      ASSERT_TRUE(worst <= 4.9e-4 + 1e-6);
      /* channels come back sorted by name */
      for (uint32_t c = 1; c < back->channels; c++)
        ASSERT_TRUE(strcmp(back->channel_names[c - 1], back->channel_names[c]) < 0);
      ub_image_free(back);
    }
    ub_image *none = NULL;
    ASSERT_TRUE(ub_image_read_exr("/nonexistent/x.exr", NULL, &none) != UB_OK && none == NULL);

    ASSERT_OK(ub_image_write_png_preview(png, at->width, at->height, img, 1.0f, &g_log));
    FILE *f = fopen(png, "rb");
    unsigned char sig[8] = {0};
    ASSERT_TRUE(f != NULL);
    if (f) {
      ASSERT_TRUE(fread(sig, 1, 8, f) == 8);
      fclose(f);
    }
    ASSERT_TRUE(memcmp(sig, "\x89PNG\r\n\x1a\n", 8) == 0);
    free(ahd);
    free(img);
    free(before);
    free(cov);
  }

  ub_lightmap_free(lm);
  ub_rt_free(rt);
  ub_scene_free(s);
}

static void test_dilate_small(void)
{
  /* 7×5 image, one covered texel at (3,2) with value 4, another at (0,0) with 8 */
  float img[35] = {0};
  uint8_t cov[35] = {0};
  img[2 * 7 + 3] = 4.0f;
  cov[2 * 7 + 3] = 1;
  img[0] = 8.0f;
  cov[0] = 1;
  ub_lightmap_dilate(img, cov, 7, 5, 1, 1);
  ASSERT_TRUE(img[2 * 7 + 3] == 4.0f && img[0] == 8.0f);
  ASSERT_NEAR(img[1 * 7 + 2], 4.0f, 0, 0);   /* ring of the centre texel */
  ASSERT_NEAR(img[1 * 7 + 1], 8.0f, 0, 0);   /* only (0,0) is a neighbour... */
  ASSERT_NEAR(img[1 * 7 + 2], 4.0f, 0, 0);
  ASSERT_TRUE(img[4 * 7 + 6] == 0.0f);       /* two rings away: still empty after 1 pass */
  ASSERT_TRUE(img[0 * 7 + 5] == 0.0f);
  /* (1,1) neighbours (0,0)=8; (2,2) is empty in the snapshot → 8 */
  float img2[35] = {0};
  img2[2 * 7 + 3] = 4.0f;
  img2[2 * 7 + 1] = 2.0f;
  uint8_t cov2[35] = {0};
  cov2[2 * 7 + 3] = cov2[2 * 7 + 1] = 1;
  ub_lightmap_dilate(img2, cov2, 7, 5, 1, 1);
  ASSERT_NEAR(img2[2 * 7 + 2], 3.0f, 1e-6, 0); /* average of both neighbours */
  ASSERT_NEAR(img2[1 * 7 + 2], 3.0f, 1e-6, 0);
  ub_lightmap_dilate(NULL, cov2, 7, 5, 1, 1); /* NULL-safe */
}

/* Charts longer than an atlas: a 10 km strip of 100 m quads is split on a grid, a single
 * 6 km quad cannot be split and is scaled down; both stay fully covered. */
static void test_oversized_charts(void)
{
  builder b = {calloc(1, sizeof(ub_scene)), 0, 0};
  ub_scene *s = b.s;
  s->path = dupstr("(strip)");
  s->texel_size = 1.0f;
  s->material_count = 1;
  s->materials = calloc(1, sizeof(ub_material));
  s->materials[0].name = dupstr("m");
  s->node_count = 2;
  s->nodes = calloc(2, sizeof(ub_node));
  for (int i = 0; i < 2; i++) {
    s->nodes[i].name = dupstr(i ? "long" : "strip");
    s->nodes[i].receiver = UB_RECEIVER_LIGHTMAP;
    s->nodes[i].door = s->nodes[i].door_open = s->nodes[i].semidynamic = -1;
  }
  s->nodes[1].texel_size = 2.0f;
  const float up[3] = {0, 1, 0};
  for (int q = 0; q < 100; q++) {
    float x0 = q * 100.0f, x1 = x0 + 100.0f;
    const float p[4][3] = {{x0, 0, 0}, {x0, 0, 10}, {x1, 0, 10}, {x1, 0, 0}};
    b_quad(&b, 0, p, up);
  }
  s->nodes[0].triangle_count = s->triangle_count;
  s->nodes[1].first_triangle = s->triangle_count;
  {
    const float p[4][3] = {{0, 5, 20}, {0, 5, 30}, {12000, 5, 30}, {12000, 5, 20}};
    b_quad(&b, 1, p, up);
  }
  s->nodes[1].triangle_count = 2;
  for (int a = 0; a < 3; a++) {
    s->bounds_min[a] = 0;
    s->bounds_max[a] = a == 0 ? 12000.0f : 30.0f;
  }
  ub_lightmap *lm = NULL;
  ASSERT_OK(ub_lightmap_build(s, NULL, 0.25f, &g_log, &lm));
  if (lm) {
    printf("oversized: %u atlases (%ux%u), %u charts, %u texels\n", lm->atlas_count,
           lm->atlases[0].width, lm->atlases[0].height, lm->chart_count, lm->texel_count);
    check_invariants(s, lm, 1);
    ASSERT_TRUE(lm->chart_count >= 3 + 1);
    for (uint32_t a = 0; a < lm->atlas_count; a++)
      ASSERT_TRUE(lm->atlases[a].width <= UB_ATLAS_MAX_SIZE &&
                  lm->atlases[a].height <= UB_ATLAS_MAX_SIZE);
    /* the strip keeps its 1 m texels: ≥ 10000 × 10 texels */
    uint32_t strip_texels = 0;
    for (uint32_t ti = 0; ti < lm->texel_count; ti++)
      strip_texels += lm->texel_tri[ti] < 200;
    ASSERT_TRUE(strip_texels >= 100000 && strip_texels <= 130000);
    ub_lightmap_free(lm);
  }
  ub_scene_free(s);
}

/* No ray tracer (offsets only), and a scene with nothing lightmapped. */
static void test_degenerate_inputs(void)
{
  ub_scene *s = make_scene();
  ub_lightmap *lm = NULL;
  ASSERT_OK(ub_lightmap_build(s, NULL, 0.25f, NULL, &lm));
  if (lm) {
    ASSERT_TRUE(lm->backface_fixes == 0 && lm->texel_count > 0);
    check_invariants(s, lm, 1);
    ub_lightmap_free(lm);
    lm = NULL;
  }
  for (uint32_t n = 0; n < s->node_count; n++)
    s->nodes[n].receiver = UB_RECEIVER_LLG;
  ub_rt *rt = NULL;
  ASSERT_OK(ub_rt_create(s, NULL, NULL, &rt));
  ASSERT_OK(ub_lightmap_build(s, rt, 0.25f, NULL, &lm));
  if (lm) {
    ASSERT_TRUE(lm->atlas_count == 0 && lm->texel_count == 0);
    for (uint32_t t = 0; t < s->triangle_count; t++)
      ASSERT_TRUE(lm->tri_atlas[t] == -1);
  }
  ub_lightmap_free(lm);
  ub_lightmap_free(NULL);
  ub_rt_free(rt);
  ub_scene_free(s);
}


/* Sparse refills (a subset pass's images) equal the full fill bit for bit: three subsets
 * (a run of texels, a scattered 5%, every texel), each refilled twice with new values
 * (the second refill must overwrite the first everywhere it wrote). */
static void check_sparse_images(const ub_lightmap *lm)
{
  uint32_t T = lm->texel_count;
  double *iz = calloc((size_t)T * 3 + 1, sizeof *iz);
  uint32_t *act = malloc(((size_t)T + 1) * sizeof *act);
  uint64_t rng = 12345;
  int mismatch = 0, compared = 0;
  uint64_t rings = 0;
  for (int kind = 0; kind < 3 && iz && act; kind++) {
    uint32_t n = 0;
    for (uint32_t t = 0; t < T; t++) {
      rng = rng * 6364136223846793005ull + 1442695040888963407ull;
      int in = kind == 0 ? (t >= T / 3 && t < T / 3 + T / 10)
                         : kind == 1 ? ((rng >> 33) % 20 == 0) : 1;
      if (in)
        act[n++] = t;
    }
    for (uint32_t a = 0; a < lm->atlas_count; a++) {
      size_t npx = (size_t)lm->atlases[a].width * lm->atlases[a].height;
      float *full = malloc(npx * 4 * sizeof *full), *sp_img = malloc(npx * 4 * sizeof *sp_img);
      ub_lightmap_sparse sp;
      /* kind 1 from a shared base (as passes of one bake), the others computing it */
      float *bimg = kind == 1 ? malloc(npx * 4 * sizeof *bimg) : NULL;
      uint8_t *blev = kind == 1 ? malloc(npx) : NULL;
      if (kind == 1)
        ASSERT_TRUE(bimg && blev && ub_lightmap_sparse_base(lm, a, bimg, blev));
      ASSERT_TRUE(full && sp_img && ub_lightmap_sparse_init(lm, a, act, n, bimg, blev, sp_img, &sp));
      for (int round = 0; round < 2 && full && sp_img; round++) {
        memset(iz, 0, (size_t)T * 3 * sizeof *iz);
        for (uint32_t i = 0; i < n; i++)
          for (int c = 0; c < 3; c++) {
            rng = rng * 6364136223846793005ull + 1442695040888963407ull;
            iz[3 * (size_t)act[i] + c] = (rng >> 40) % 7 == 0 ? 0.0 : (double)(rng >> 11) * 0x1p-53 * 10.0;
          }
        ub_lightmap_image_fill(lm, a, NULL, iz, full);
        ub_lightmap_sparse_fill(lm, &sp, iz, sp_img);
        mismatch += memcmp(full, sp_img, npx * 4 * sizeof *full) != 0;
        compared++;
      }
      rings += sp.n1 + sp.n2;
      ub_lightmap_sparse_free(&sp);
      free(bimg);
      free(blev);
      free(full);
      free(sp_img);
    }
  }
  ASSERT_TRUE(compared > 0 && mismatch == 0);
  printf("  sparse image refills: %d images identical to the full fill (%d differ); %llu ring "
         "pixels recomputed\n", compared - mismatch, mismatch, (unsigned long long)rings);
  free(iz);
  free(act);
}

static void test_real_level(const char *path)
{
  struct stat st;
  if (stat(path, &st) != 0) {
    printf("note: %s not found, real-level check skipped\n", path);
    return;
  }
  double t0 = now_s();
  ub_scene *s = NULL;
  ub_result r = ub_scene_load(path, &g_log, &s);
  if (r != UB_OK || !s) {
    printf("note: ub_scene_load(%s) failed (%s), real-level check skipped\n", path,
           ub_result_string(r));
    return;
  }
  double t1 = now_s();
  ub_rt *rt = NULL;
  ASSERT_OK(ub_rt_create(s, NULL, &g_log, &rt));
  double t2 = now_s();
  ub_lightmap *lm = NULL;
  ASSERT_OK(ub_lightmap_build(s, rt, 0.25f, &g_log, &lm));
  double t3 = now_s();
  if (lm) {
    printf("%s: %u triangles, %u atlases:", path, s->triangle_count, lm->atlas_count);
    for (uint32_t a = 0; a < lm->atlas_count; a++)
      printf(" %ux%u%s (%u texels)", lm->atlases[a].width, lm->atlases[a].height,
             lm->atlases[a].generated ? " generated" : " authored", lm->atlases[a].texel_count);
    printf("\n  %u texels, %u charts, %u backface fixes, %u overlap texels; load %.2f s, "
           "rt %.2f s, lightmap build %.2f s\n",
           lm->texel_count, lm->chart_count, lm->backface_fixes, lm->overlap_texels, t1 - t0,
           t2 - t1, t3 - t2);
    check_invariants(s, lm, 0);
    check_sparse_images(lm);
    ub_lightmap_free(lm);
  }
  ub_rt_free(rt);
  ub_scene_free(s);
}

int main(void)
{
  const char *outdir = getenv("UB_BUILD");
  char dir[1024];
  snprintf(dir, sizeof dir, "%s/test_out", outdir ? outdir : "/tmp");
  mkdir(dir, 0777);
  test_dilate_small();
  test_small_scene(dir);
  test_degenerate_inputs();
  test_oversized_charts();
  const char *levels = getenv("UB_TEST_LEVELS");
  if (!levels) {
    test_real_level("/work/shared/levels/real/oa_dm4/oa_dm4.gltf");
  } else {
    char buf[4096];
    snprintf(buf, sizeof buf, "%s", levels);
    for (char *tok = strtok(buf, ":"); tok; tok = strtok(NULL, ":"))
      test_real_level(tok);
  }
  TEST_MAIN_END();
}
