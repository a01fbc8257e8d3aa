/* ubake regress LEVEL: the door-opening regression check (issue #5) for any level.
 *
 * Bakes the level, then for every door picks fixed points on both sides of it (the floor
 * and ceiling 1, 2 and 4 m from the leaf's centre along its normal, found by rays straight
 * down/up from there) and compares, door closed (T = 0) and open (T = 1):
 *   query     = the run-time's lightmap answer (base + T × the door's record),
 *   reference = the path tracer with the closed leaf (real albedo) or the open pose.
 * Prints one row per point: the two answers, their absolute error (luminance, W/m²) and the
 * reference's standard error, for both states. With --golden FILE, each error must stay
 * ≤ its stored figure + 3 s.e. + 1e-4 (exit 1 otherwise); --write-golden FILE stores them.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bake/lights.h"
#include "bake/reference.h"
#include "bake/geomstate.h"
#include "bake/rt.h"
#include "doors/guide.h"
#include "tools/regress.h"
#include "ubake/bake.h"
#include "ubake/runtime.h"
#include "ubake/scene.h"

#define MAX_POINTS 256

typedef struct rpoint {
  char name[48];
  float p[3], n[3];
  double q[2], ref[2], se[2]; /* [0] closed, [1] open; luminance, W/m² */
} rpoint;

static void quiet_log(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  if (level == UB_LOG_ERROR)
    fprintf(stderr, "ubake regress: %s\n", msg);
}

static double lum(const float v[3])
{
  return 0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2];
}

static const char *HELP =
    "usage: ubake regress LEVEL.gltf [-o DIR] [--quality draft|fast|high] [--spp N]\n"
    "          [--texel-size M] [--golden FILE] [--write-golden FILE]\n"
    "Bakes LEVEL and compares query vs reference with every door closed and open at\n"
    "points on both sides of each door; prints point, closed error, open error, s.e.\n";

/* Points for door d: floor and ceiling, 1, 2 and 4 m from the leaf on both sides. */
static uint32_t door_points(const ub_scene *s, const ub_rt *rt, uint32_t d, rpoint *out,
                            uint32_t cap)
{
  uint32_t nv = 0;
  for (uint32_t t = 0; t < s->triangle_count; t++)
    if (s->nodes[s->tri_node[t]].door == (int32_t)d)
      nv += 3;
  if (!nv)
    return 0;
  float *pts = malloc((size_t)nv * 3 * sizeof *pts);
  if (!pts)
    return 0;
  nv = 0;
  for (uint32_t t = 0; t < s->triangle_count; t++)
    if (s->nodes[s->tri_node[t]].door == (int32_t)d)
      for (int v = 0; v < 3; v++)
        memcpy(pts + 3 * (size_t)nv++, s->positions + 3 * (size_t)s->indices[3 * t + v],
               3 * sizeof(float));
  ub_obb b;
  int ok = ub_obb_fit(pts, nv, 0.0f, &b);
  free(pts);
  if (!ok)
    return 0;
  int thin = 0;
  for (int k = 1; k < 3; k++)
    if (b.h[k] < b.h[thin])
      thin = k;
  uint32_t n = 0;
  static const float dist[3] = {1.0f, 2.0f, 4.0f};
  for (int side = 0; side < 2 && n < cap; side++)
    for (int di = 0; di < 3 && n < cap; di++)
      for (int up = 0; up < 2 && n < cap; up++) {
        float o[3], w[3] = {0, up ? 1.0f : -1.0f, 0};
        for (int k = 0; k < 3; k++)
          o[k] = b.c[k] + (side ? 1.0f : -1.0f) * dist[di] * b.axis[thin][k];
        ub_ray r = {{o[0], o[1], o[2]}, 0.0f, {w[0], w[1], w[2]}, INFINITY};
        ub_hit h;
        ub_rt_intersect(rt, &r, 1, &h);
        if (h.tri == UB_RT_MISS)
          continue;
        rpoint *q = &out[n++];
        memset(q, 0, sizeof *q);
        snprintf(q->name, sizeof q->name, "%s %c%.0fm %s", s->door_names[d],
                 side ? '+' : '-', (double)dist[di], up ? "ceiling" : "floor");
        for (int k = 0; k < 3; k++) {
          q->p[k] = o[k] + w[k] * h.t;
          q->n[k] = -w[k];
        }
      }
  return n;
}

int ub_cli_regress(int argc, char **argv)
{
  const char *level = NULL, *dir = NULL, *golden = NULL, *write_golden = NULL;
  ub_bake_options opt;
  ub_bake_options_default(&opt);
  opt.quality = UB_QUALITY_DRAFT;
  uint32_t spp = 4096;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      fputs(HELP, stdout);
      return 0;
    } else if (!strcmp(a, "-o") && v) {
      dir = v, i++;
    } else if (!strcmp(a, "--quality") && v) {
      opt.quality = !strcmp(v, "draft") ? UB_QUALITY_DRAFT
                    : !strcmp(v, "high") ? UB_QUALITY_HIGH : UB_QUALITY_FAST;
      i++;
    } else if (!strcmp(a, "--spp") && v) {
      spp = (uint32_t)strtoul(v, NULL, 10), i++;
    } else if (!strcmp(a, "--texel-size") && v) {
      opt.texel_size = strtof(v, NULL), i++;
    } else if (!strcmp(a, "--golden") && v) {
      golden = v, i++;
    } else if (!strcmp(a, "--write-golden") && v) {
      write_golden = v, i++;
    } else if (a[0] == '-') {
      fprintf(stderr, "ubake regress: unknown option or missing value: %s\n%s", a, HELP);
      return 1;
    } else {
      level = a;
    }
  }
  if (!level || spp == 0) {
    fputs(HELP, stderr);
    return 1;
  }
  char out_dir[1024];
  if (!dir) {
    const char *base = strrchr(level, '/');
    snprintf(out_dir, sizeof out_dir, "regress_%s", base ? base + 1 : level);
    char *dot = strrchr(out_dir, '.');
    if (dot)
      *dot = '\0';
    dir = out_dir;
  }
  opt.out_dir = dir;
  ub_log log = {quiet_log, NULL};
  ub_bake_stats st;
  ub_result r = ub_bake_level(level, &opt, &log, &st);
  if (r != UB_OK) {
    fprintf(stderr, "ubake regress: %s: bake failed: %s\n", level, ub_result_string(r));
    return 1;
  }
  ub_scene *s = NULL;
  ub_runtime *run = NULL;
  ub_emitters *em = NULL;
  ub_rt *rt_state[2] = {NULL, NULL};
  uint8_t *open = NULL;
  static rpoint pts[MAX_POINTS];
  uint32_t np = 0;
  int status = 0;
  r = ub_scene_load(level, &log, &s);
  if (r == UB_OK)
    r = ub_runtime_load(st.ubk_path, &log, &run);
  if (r == UB_OK)
    r = ub_emitters_build(s, &em);
  if (r == UB_OK && !(open = calloc(s->door_count + 1, 1)))
    r = UB_ERR_OUT_OF_MEMORY;
  if (r != UB_OK) {
    fprintf(stderr, "ubake regress: %s: %s\n", level, ub_result_string(r));
    status = 1;
    goto done;
  }
  printf("%s: %u door(s), bake %.1f s, reference %u spp; errors |query - reference| "
         "(luminance, W/m²)\n", level, s->door_count, st.total_seconds, spp);
  printf("%-28s %10s %10s %9s %8s | %10s %10s %9s %8s\n", "point", "closed q", "ref",
         "err", "s.e.", "open q", "ref", "err", "s.e.");
  for (uint32_t d = 0; d < s->door_count; d++) {
    int32_t el = ub_runtime_element_find(run, UB_ELEMENT_DOOR, s->door_names[d]);
    for (int state = 0; state < 2 && r == UB_OK; state++) {
      memset(open, 0, s->door_count + 1);
      open[d] = (uint8_t)state;
      ub_geom_state gs = {open, NULL};
      uint8_t *mask = ub_geom_mask(s, &gs);
      r = mask ? ub_rt_create(s, mask, &log, &rt_state[state]) : UB_ERR_OUT_OF_MEMORY;
      free(mask);
    }
    if (r != UB_OK)
      break;
    uint32_t p0 = np;
    np += door_points(s, rt_state[0], d, pts + np, MAX_POINTS - np);
    for (int state = 0; state < 2; state++) {
      if (el >= 0) {
        ub_runtime_set_element(run, (uint32_t)el, (float)state);
        ub_runtime_update(run, NULL);
      }
      for (uint32_t i = p0; i < np; i++) {
        rpoint *q = &pts[i];
        float rgb[3], dist, se[3];
        if (ub_runtime_query_lightmap(run, q->p, q->n, rgb, &dist) != UB_OK)
          rgb[0] = rgb[1] = rgb[2] = NAN;
        q->q[state] = lum(rgb);
        ub_reference_params rp;
        ub_reference_params_init(&rp);
        memcpy(rp.position, q->p, sizeof rp.position);
        memcpy(rp.normal, q->n, sizeof rp.normal);
        rp.spp = spp;
        rp.seed = 11;
        if (ub_reference_irradiance(s, rt_state[state], em, &rp, rgb, se, NULL) != UB_OK)
          rgb[0] = rgb[1] = rgb[2] = se[0] = se[1] = se[2] = NAN;
        q->ref[state] = lum(rgb);
        q->se[state] = lum(se);
      }
    }
    if (el >= 0) {
      ub_runtime_set_element(run, (uint32_t)el, 0.0f);
      ub_runtime_update(run, NULL);
    }
    ub_rt_free(rt_state[0]);
    ub_rt_free(rt_state[1]);
    rt_state[0] = rt_state[1] = NULL;
  }
  FILE *gf = golden ? fopen(golden, "r") : NULL;
  if (golden && !gf) {
    fprintf(stderr, "ubake regress: %s: cannot open the golden file\n", golden);
    status = 1;
  }
  FILE *wf = write_golden ? fopen(write_golden, "w") : NULL;
  if (wf)
    fprintf(wf, "# ubake regress golden: point closed_err open_err (luminance, W/m²)\n");
  for (uint32_t i = 0; i < np; i++) {
    rpoint *q = &pts[i];
    double e0 = fabs(q->q[0] - q->ref[0]), e1 = fabs(q->q[1] - q->ref[1]);
    printf("%-28s %10.5f %10.5f %9.5f %8.5f | %10.5f %10.5f %9.5f %8.5f\n", q->name, q->q[0],
           q->ref[0], e0, q->se[0], q->q[1], q->ref[1], e1, q->se[1]);
    if (wf)
      fprintf(wf, "%u %.6g %.6g\n", i, e0, e1);
    if (gf) {
      char line[256];
      unsigned idx = 0;
      double g0 = NAN, g1 = NAN;
      int found = 0;
      rewind(gf);
      while (fgets(line, sizeof line, gf))
        if (line[0] != '#' && sscanf(line, "%u %lf %lf", &idx, &g0, &g1) == 3 && idx == i) {
          found = 1;
          break;
        }
      double t0 = found ? g0 + 3.0 * q->se[0] + 1e-4 : NAN;
      double t1 = found ? g1 + 3.0 * q->se[1] + 1e-4 : NAN;
      if (!found || !(e0 <= t0) || !(e1 <= t1)) {
        fprintf(stderr, "ubake regress: %s: point %u (%s): closed error %.5f (limit %.5f), "
                "open error %.5f (limit %.5f)%s\n", level, i, q->name, e0, t0, e1, t1,
                found ? "" : ": not in the golden file");
        status = 1;
      }
    }
  }
  if (gf)
    fclose(gf);
  if (wf)
    fclose(wf);
  if (golden && !status)
    printf("%u point(s) within their golden errors + 3 s.e.\n", np);
done:
  ub_rt_free(rt_state[0]);
  ub_rt_free(rt_state[1]);
  free(open);
  ub_emitters_free(em);
  ub_runtime_free(run);
  ub_scene_free(s);
  return status;
}
