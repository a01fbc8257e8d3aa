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
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
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
#define DOOR_POINTS 12 /* per door: 2 sides × 3 distances × floor and ceiling */

typedef struct rpoint {
  char name[48];
  float p[3], n[3];
  double q[2], ref[2], se[2]; /* [0] closed, [1] open; luminance, W/m² */
} rpoint;

typedef struct regress_log_state {
  int errors;
} regress_log_state;

/* The library's first error only (as the other commands print it); the caller's fallback
 * message only when none came. */
static void quiet_log(void *user, ub_log_level level, const char *msg)
{
  regress_log_state *st = user;
  if (level == UB_LOG_ERROR && st->errors++ == 0)
    fprintf(stderr, "ubake regress: %s\n", msg);
}

static double lum(const float v[3])
{
  return 0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2];
}

static const char *HELP =
    "usage: ubake regress LEVEL.gltf [-o DIR] [--quality draft|fast|high] [--spp N]\n"
    "          [--texel-size M] [--threads N] [--golden FILE] [--write-golden FILE]\n"
    "Bakes LEVEL and compares query vs reference with every door closed and open at\n"
    "points on both sides of each door; prints point, closed error, open error, s.e.\n"
    "  -o DIR               bake output folder (default: regress_NAME in the current\n"
    "                       folder, NAME the level's file name without extension)\n"
    "  --quality Q          bake quality: draft (default), fast or high\n"
    "  --spp N              reference paths per point, 1..2^30 (default 4096)\n"
    "  --texel-size M       override metres per lightmap texel (> 0)\n"
    "  --threads N          worker threads for the bake and the references, 1..1024\n"
    "                       (default: all cores)\n"
    "  --golden FILE        exit 1 where an error exceeds FILE's figure + 3 s.e. + 1e-4\n"
    "                       (FILE is read and checked before the bake)\n"
    "  --write-golden FILE  store this run's errors in FILE (replaced only when complete)\n";

/* One line on stderr in the style of the other commands' usage errors; returns 1. */
static int regress_usage(const char *fmt, ...)
{
  va_list ap;
  va_start(ap, fmt);
  fputs("ubake regress: ", stderr);
  vfprintf(stderr, fmt, ap);
  fputs(" (see 'ubake regress --help')\n", stderr);
  va_end(ap);
  return 1;
}

/* The whole of s a decimal integer in [min, max]: no sign, blanks, exponent or suffix. */
static int parse_count(const char *s, unsigned long min, unsigned long max, unsigned long *out)
{
  if (s[0] < '0' || s[0] > '9')
    return 0;
  char *end;
  errno = 0;
  unsigned long v = strtoul(s, &end, 10);
  if (*end || errno || v < min || v > max)
    return 0;
  *out = v;
  return 1;
}

/* The whole of s a number of metres that stays positive and finite as a float. */
static int parse_metres(const char *s, float *out)
{
  char *end;
  errno = 0;
  double v = strtod(s, &end);
  if (end == s || *end || errno || !(v > 0.0) || !((float)v > 0.0f) || !isfinite((float)v))
    return 0;
  *out = (float)v;
  return 1;
}

/* Golden errors by point index: have[i] set for each point the file lists. */
typedef struct golden_table {
  uint8_t have[MAX_POINTS];
  double err[MAX_POINTS][2]; /* closed, open; luminance, W/m² */
} golden_table;

/* Reads a golden file ("# comment" lines, blank lines, and "INDEX CLOSED_ERR OPEN_ERR"
 * rows with INDEX < MAX_POINTS given once and errors finite and >= 0). Prints one line
 * naming the file (and line) on failure and returns 0. */
static int golden_read(const char *path, golden_table *out)
{
  FILE *f = fopen(path, "r");
  if (!f) {
    fprintf(stderr, "ubake regress: %s: cannot read the golden file: %s\n", path,
            strerror(errno));
    return 0;
  }
  memset(out, 0, sizeof *out);
  char line[256];
  int ok = 1;
  for (unsigned ln = 1; ok && fgets(line, sizeof line, f); ln++) {
    size_t len = strlen(line);
    if (len == sizeof line - 1 && line[len - 1] != '\n' && !feof(f)) {
      fprintf(stderr, "ubake regress: %s:%u: line longer than %zu characters\n", path, ln,
              sizeof line - 2);
      ok = 0;
      break;
    }
    while (len && (line[len - 1] == '\n' || line[len - 1] == '\r' || line[len - 1] == ' ' ||
                   line[len - 1] == '\t'))
      line[--len] = '\0';
    if (!len || line[0] == '#')
      continue;
    char *p = line, *end;
    unsigned long idx = 0;
    double e[2] = {NAN, NAN};
    int good = *p >= '0' && *p <= '9';
    if (good) {
      errno = 0;
      idx = strtoul(p, &end, 10);
      good = !errno && end != p && (*end == ' ' || *end == '\t');
      p = end;
    }
    for (int k = 0; k < 2 && good; k++) {
      e[k] = strtod(p, &end);
      good = end != p && isfinite(e[k]) && e[k] >= 0.0 &&
             (k == 1 || *end == ' ' || *end == '\t');
      p = end;
    }
    if (!good || *p) {
      fprintf(stderr, "ubake regress: %s:%u: expected \"POINT CLOSED_ERR OPEN_ERR\" "
              "(an index and two errors >= 0), got \"%.60s\"\n", path, ln, line);
      ok = 0;
    } else if (idx >= MAX_POINTS || out->have[idx]) {
      fprintf(stderr, "ubake regress: %s:%u: point %lu %s\n", path, ln, idx,
              idx >= MAX_POINTS ? "is out of range (at most 255)" : "is listed twice");
      ok = 0;
    } else {
      out->have[idx] = 1;
      out->err[idx][0] = e[0];
      out->err[idx][1] = e[1];
    }
  }
  if (ok && ferror(f)) {
    fprintf(stderr, "ubake regress: %s: cannot read the golden file: %s\n", path,
            strerror(errno));
    ok = 0;
  }
  fclose(f);
  return ok;
}

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
  uint32_t spp = UB_REFERENCE_DEFAULT_SPP;
  int threads = 0;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
    unsigned long n;
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      fputs(HELP, stdout);
      return 0;
    }
    int takes_value = !strcmp(a, "-o") || !strcmp(a, "--quality") || !strcmp(a, "--spp") ||
                      !strcmp(a, "--texel-size") || !strcmp(a, "--threads") ||
                      !strcmp(a, "--golden") || !strcmp(a, "--write-golden");
    if (takes_value && (!v || !v[0]))
      return regress_usage("%s: missing value", a);
    if (!strcmp(a, "-o")) {
      dir = v;
    } else if (!strcmp(a, "--quality")) {
      if (!ub_quality_from_name(v, &opt.quality))
        return regress_usage("--quality %s: takes draft, fast or high", v);
    } else if (!strcmp(a, "--spp")) {
      if (!parse_count(v, 1, UB_REFERENCE_MAX_SPP, &n))
        return regress_usage("--spp %s: takes a whole number 1..%u (2^30)", v,
                             UB_REFERENCE_MAX_SPP);
      spp = (uint32_t)n;
    } else if (!strcmp(a, "--texel-size")) {
      if (!parse_metres(v, &opt.texel_size))
        return regress_usage("--texel-size %s: takes a positive number of metres", v);
    } else if (!strcmp(a, "--threads")) {
      if (!parse_count(v, 1, 1024, &n))
        return regress_usage("--threads %s: takes 1..1024", v);
      threads = (int)n;
    } else if (!strcmp(a, "--golden")) {
      golden = v;
    } else if (!strcmp(a, "--write-golden")) {
      write_golden = v;
    } else if (a[0] == '-') {
      return regress_usage("%s: unknown option", a);
    } else if (!level) {
      level = a;
    } else {
      return regress_usage("%s: more than one level given (%s first)", a, level);
    }
    if (takes_value)
      i++;
  }
  if (!level)
    return regress_usage("no level given");

  /* The files named on the command line, before the bake: a golden file that cannot be
   * read or parsed, or a folder that cannot take the new one, fails in a second, not
   * after the bake and every reference. The new golden file goes to PATH.tmp, renamed
   * into place only once complete. */
  static golden_table gold;
  if (golden && !golden_read(golden, &gold))
    return 1;
  char wtmp[1024];
  FILE *wf = NULL;
  if (write_golden) {
    if ((size_t)snprintf(wtmp, sizeof wtmp, "%s.tmp", write_golden) >= sizeof wtmp) {
      fprintf(stderr, "ubake regress: %s: path too long\n", write_golden);
      return 1;
    }
    if (!(wf = fopen(wtmp, "w"))) {
      fprintf(stderr, "ubake regress: %s: cannot write the golden file: %s\n", write_golden,
              strerror(errno));
      return 1;
    }
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
  opt.threads = threads;
  regress_log_state ls = {0};
  ub_log log = {quiet_log, &ls};
  ub_bake_stats st;
  ub_scene *s = NULL;
  ub_runtime *run = NULL;
  ub_emitters *em = NULL;
  ub_rt *rt_state[2] = {NULL, NULL};
  uint8_t *open = NULL;
  static rpoint pts[MAX_POINTS];
  uint32_t np = 0;
  int status = 0, ref_failed = 0;
  ub_result r = ub_bake_level(level, &opt, &log, &st);
  if (r != UB_OK) {
    if (!ls.errors)
      fprintf(stderr, "ubake regress: %s: bake failed: %s\n", level, ub_result_string(r));
    status = 1;
    goto done;
  }
  r = ub_scene_load(level, &log, &s);
  if (r == UB_OK)
    r = ub_runtime_load(st.ubk_path, &log, &run);
  if (r == UB_OK)
    r = ub_emitters_build(s, &em);
  if (r == UB_OK && !(open = calloc(s->door_count + 1, 1)))
    r = UB_ERR_OUT_OF_MEMORY;
  if (r != UB_OK) {
    if (!ls.errors)
      fprintf(stderr, "ubake regress: %s: %s\n", level, ub_result_string(r));
    status = 1;
    goto done;
  }
  char thr[32] = "all cores";
  if (threads)
    snprintf(thr, sizeof thr, "%d thread%s", threads, threads == 1 ? "" : "s");
  printf("%s: %u door(s), bake %.1f s, reference %u spp, %s; errors |query - reference| "
         "(luminance, W/m²)\n", level, s->door_count, st.total_seconds, spp, thr);
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
    if (r != UB_OK) {
      if (!ls.errors)
        fprintf(stderr, "ubake regress: %s: door '%s': %s\n", level, s->door_names[d],
                ub_result_string(r));
      status = 1;
      goto done;
    }
    uint32_t p0 = np;
    rpoint got[DOOR_POINTS];
    const uint32_t nd = door_points(s, rt_state[0], d, got, DOOR_POINTS);
    if (nd > MAX_POINTS - np) { /* a golden file numbers the points: none may go missing */
      fprintf(stderr, "ubake regress: %s: more than %u points: door '%s' and the ones after "
              "it are not measured\n", level, MAX_POINTS, s->door_names[d]);
      status = 1;
      goto done;
    }
    memcpy(pts + np, got, nd * sizeof *got);
    np += nd;
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
        rp.threads = threads;
        if (ub_reference_irradiance(s, rt_state[state], em, &rp, rgb, se, &log) != UB_OK) {
          rgb[0] = rgb[1] = rgb[2] = se[0] = se[1] = se[2] = NAN;
          ref_failed = status = 1; /* the log said why */
        }
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
  if (wf)
    fprintf(wf, "# ubake regress golden: point closed_err open_err (luminance, W/m²)\n");
  for (uint32_t i = 0; i < np; i++) {
    rpoint *q = &pts[i];
    double e0 = fabs(q->q[0] - q->ref[0]), e1 = fabs(q->q[1] - q->ref[1]);
    printf("%-28s %10.5f %10.5f %9.5f %8.5f | %10.5f %10.5f %9.5f %8.5f\n", q->name, q->q[0],
           q->ref[0], e0, q->se[0], q->q[1], q->ref[1], e1, q->se[1]);
    if (wf)
      fprintf(wf, "%u %.6g %.6g\n", i, e0, e1);
    if (golden) {
      int found = gold.have[i];
      double t0 = found ? gold.err[i][0] + 3.0 * q->se[0] + 1e-4 : NAN;
      double t1 = found ? gold.err[i][1] + 3.0 * q->se[1] + 1e-4 : NAN;
      if (!found || !(e0 <= t0) || !(e1 <= t1)) {
        fprintf(stderr, "ubake regress: %s: point %u (%s): closed error %.5f (limit %.5f), "
                "open error %.5f (limit %.5f)%s\n", level, i, q->name, e0, t0, e1, t1,
                found ? "" : ": not in the golden file");
        status = 1;
      }
    }
  }
  for (uint32_t i = np; golden && i < MAX_POINTS; i++)
    if (gold.have[i]) { /* the level gives fewer points than the file knows */
      fprintf(stderr, "ubake regress: %s: golden point %u was not measured (this level gives "
              "%u points)\n", golden, i, np);
      status = 1;
    }
  if (wf && ref_failed) {
    fprintf(stderr, "ubake regress: %s: golden file not written: a reference failed\n",
            write_golden);
  } else if (wf) {
    int bad = ferror(wf);
    bad |= fclose(wf) != 0;
    wf = NULL;
    if (bad || rename(wtmp, write_golden) != 0) {
      fprintf(stderr, "ubake regress: %s: cannot write the golden file: %s\n", write_golden,
              strerror(errno));
      remove(wtmp);
      status = 1;
    }
  }
  if (golden && !status)
    printf("%u point(s) within their golden errors + 3 s.e.\n", np);
done:
  if (wf) {
    fclose(wf);
    remove(wtmp);
  }
  ub_rt_free(rt_state[0]);
  ub_rt_free(rt_state[1]);
  free(open);
  ub_emitters_free(em);
  ub_runtime_free(run);
  ub_scene_free(s);
  return status;
}
