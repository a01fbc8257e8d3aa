/* `ubake sweep`: error vs seconds ladders for one level (see sweep.h).
 *
 * Script: load the level → bake the middle setting → pick the ground-truth points from it
 * → reference at each point (cached) → converged bake → every rung: bake, time, measure
 * → sweep.csv after each rung → gnuplot. */
#include "tools/sweep.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "bake/fsutil.h"
#include "bake/lights.h"
#include "bake/outdir.h"
#include "bake/reference.h"
#include "bake/rt.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/glg.h"
#include "ubake/runtime.h"
#include "ubake/sh.h"
#include "ubake/scene.h"

/* Rays of the inside / hidden-surface test for ground-truth points (as GLG placement). */
#define SWEEP_TEST_RAYS 24
/* A point whose test rays hit back faces more than this share is inside solid geometry. */
#define SWEEP_BACKFACE_SHARE 0.25
/* A surface point is covered if most of its hemisphere rays stop within this many texels. */
#define SWEEP_NEAR_TEXELS 0.05f
/* Per-point relative error: |bake − ref| / max(ref, floor × mean ref), so that points in
 * near darkness do not dominate the maximum and the percentile. */
#define SWEEP_ERR_FLOOR 0.1
/* Attempts per wanted point before giving up on finding more. */
#define SWEEP_TRIES 64
#define SWEEP_MAX_RUNGS 32
/* Default timing: bakes shorter than this many seconds are repeated, the fastest kept. */
#define SWEEP_AUTO_REPEAT_SECONDS 10.0
#define SWEEP_AUTO_REPEAT 3
/* Seeds of the point picker, the references and the converged bake: fixed so that runs
 * are comparable and the cache stays valid. */
#define SWEEP_POINT_SEED 0x5eedu
#define SWEEP_REF_SEED 0x7e4u
#define SWEEP_CONVERGED_SEED 0xc0u

enum { PT_LIGHTMAP = 0, PT_GLG = 1 };

typedef struct sweep_pt {
  int kind;
  float p[3], n[3];   /* world metres; unit normal */
  float ref[3], se[3]; /* reference irradiance W/m² and its standard error */
  float floor[3], floor_se[3]; /* GLG points: an exact SH L2 probe's irradiance here
                                  (windowed, as the GLG) and its s.e.; NAN elsewhere */
  int have_ref;
} sweep_pt;

/* One bake configuration. 0 / -1 fields mean "the level's or the preset's value". */
typedef struct sweep_cfg {
  ub_quality quality;
  uint32_t gather_rays; /* per texel per bounce; 0 = the preset's */
  int bounces;          /* -1 = auto */
  float texel_size;     /* metres; 0 = level default */
  float glg_spacing;    /* metres; 0 = level default */
  double target_error;  /* adaptive sampling target (relative s.e.); 0 = off */
} sweep_cfg;

typedef struct sweep_result {
  int done;
  double seconds, core_seconds;
  uint64_t rays;
  uint32_t texels, bounces;
  double rmse_pts, max_pts, p95_pts, rmse_lm, rmse_glg, rmse_texels; /* NAN: n/a */
  double glg_vs_floor; /* GLG points: sqrt(Σ (bake − L2 floor)² / Σ ref²) */
} sweep_result;

typedef struct sweep_rung {
  const char *setting;
  char value[32];
  char note[16];  /* "x0.5" etc., progress lines only */
  sweep_cfg cfg;
  int result;     /* index into sweep.results: equal configurations share one bake */
} sweep_rung;

typedef struct sweep {
  const char *level, *out_dir;
  char name[64];
  int points, threads, repeat, keep_bakes, plot, verbose, quick, reuse_conv;
  int presets;             /* --ladder presets: the three presets only (the README table) */
  int argc;                /* the command line after "sweep", quoted in presets.md */
  char **argv;
  int sampling;            /* --ladder sampling: the gather-rays and adaptive ladders only;
                              2 (--ladder sampling-short): gather rays 64, 256 and targets
                              0.2..0.02 (big levels) */
  uint32_t ref_spp, converged_rays, seed;
  ub_scene *scene;
  ub_rt *rt;
  ub_emitters *em;
  float texel0, glg0;      /* the level's defaults, metres */
  sweep_pt *pts;
  int npts, nlm, nglg;
  double ref_noise;        /* sqrt(Σ se² / Σ ref²) over the points (luminance) */
  double glg_floor, glg_floor_noise; /* GLG points: exact L2 probes vs the reference,
                              sqrt(Σ (floor − ref)² / Σ ref²), and the floor's noise */
  ub_runtime *conv;        /* converged bake, NULL if skipped */
  uint32_t conv_texels;
  sweep_rung rungs[SWEEP_MAX_RUNGS];
  int nrungs;
  sweep_cfg cfgs[SWEEP_MAX_RUNGS];
  sweep_result results[SWEEP_MAX_RUNGS];
  int nresults;
  int log_errors;
  double load_begin;
} sweep;

/* ---- small helpers ----------------------------------------------------------------- */

static double sw_now(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* CPU seconds of this process and its waited-for children (the TetGen runs). */
static double sw_cpu_seconds(void)
{
  struct rusage a, b;
  double s = 0.0;
  if (getrusage(RUSAGE_SELF, &a) == 0)
    s += a.ru_utime.tv_sec + 1e-6 * a.ru_utime.tv_usec + a.ru_stime.tv_sec +
         1e-6 * a.ru_stime.tv_usec;
  if (getrusage(RUSAGE_CHILDREN, &b) == 0)
    s += b.ru_utime.tv_sec + 1e-6 * b.ru_utime.tv_usec + b.ru_stime.tv_sec +
         1e-6 * b.ru_stime.tv_usec;
  return s;
}

static double sw_loadavg(void)
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

static double sw_lum(const float c[3])
{
  return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
}

static int sw_mkdir_p(const char *path)
{
  char buf[1024];
  if (snprintf(buf, sizeof buf, "%s", path) >= (int)sizeof buf)
    return -1;
  for (char *s = buf + 1; *s; s++) {
    if (*s != '/')
      continue;
    *s = '\0';
    if (mkdir(buf, 0777) != 0 && errno != EEXIST)
      return -1;
    *s = '/';
  }
  if (mkdir(buf, 0777) != 0 && errno != EEXIST)
    return -1;
  return 0;
}

static int sw_file_exists(const char *path)
{
  struct stat sb;
  return stat(path, &sb) == 0 && S_ISREG(sb.st_mode);
}

static int sw_parse_uint(const char *s, long min, long max, long *out)
{
  char *end;
  errno = 0;
  long v = strtol(s, &end, 10);
  if (end == s || *end || errno || v < min || v > max)
    return 0;
  *out = v;
  return 1;
}

/* Spherical Fibonacci direction r of SWEEP_TEST_RAYS. */
static void sw_fib_dir(int r, float out[3])
{
  float z = 1.0f - (2.0f * r + 1.0f) / SWEEP_TEST_RAYS;
  float rr = sqrtf(fmaxf(0.0f, 1.0f - z * z)), phi = 2.39996323f * r;
  out[0] = rr * cosf(phi);
  out[1] = z;
  out[2] = rr * sinf(phi);
}

/* 1 if the point sees mostly front faces: for a surface point (n != NULL) over the
 * hemisphere of n from the offset origin, for a free point over the whole sphere. A point
 * that sees nothing at all (open void) is rejected too, and so is a surface point covered
 * by other geometry (most of its rays stop within `near` metres: a floor under a wall). */
static int sw_point_open(const ub_rt *rt, const float p[3], const float *n, float near)
{
  ub_ray rays[SWEEP_TEST_RAYS];
  ub_hit hits[SWEEP_TEST_RAYS];
  float org[3] = {p[0], p[1], p[2]};
  if (n)
    ub_rt_offset_point(rt, p, n, org);
  for (int r = 0; r < SWEEP_TEST_RAYS; r++) {
    float d[3];
    sw_fib_dir(r, d);
    if (n) {
      float dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
      if (dn < 0.0f)
        for (int k = 0; k < 3; k++)
          d[k] -= 2.0f * dn * n[k];
    }
    memcpy(rays[r].org, org, sizeof org);
    memcpy(rays[r].dir, d, sizeof d);
    rays[r].tnear = 0.0f;
    rays[r].tfar = INFINITY;
  }
  ub_rt_intersect(rt, rays, SWEEP_TEST_RAYS, hits);
  int hit = 0, back = 0, close = 0;
  for (int r = 0; r < SWEEP_TEST_RAYS; r++) {
    if (hits[r].tri == UB_RT_MISS)
      continue;
    hit++;
    close += hits[r].t < near;
    const float *g = hits[r].ng;
    if (g[0] * rays[r].dir[0] + g[1] * rays[r].dir[1] + g[2] * rays[r].dir[2] > 0.0f)
      back++;
  }
  if (!n && hit == 0)
    return 0;
  if (n && 2 * close > SWEEP_TEST_RAYS)
    return 0;
  return back <= SWEEP_BACKFACE_SHARE * hit;
}

/* ---- logging and progress ---------------------------------------------------------- */

static void sw_log(void *user, ub_log_level level, const char *msg)
{
  sweep *s = user;
  if (level == UB_LOG_ERROR) {
    fprintf(stderr, "ubake: %s\n", msg);
    s->log_errors++;
  } else if (level == UB_LOG_WARNING) {
    if (s->verbose)
      fprintf(stderr, "ubake: warning: %s\n", msg);
  } else if (s->verbose) {
    printf("      %s\n", msg);
    fflush(stdout);
  }
}

typedef struct sw_progress {
  const char *label;
  double t0, last;
} sw_progress;

/* A line every 20 s, so a long bake shows it is alive without flooding a log file. */
static int sw_on_progress(void *user, const char *stage, double sf, double tf)
{
  sw_progress *p = user;
  double t = sw_now();
  if (t - p->last >= 20.0) {
    p->last = t;
    printf("      %s: %s %3.0f%% (bake %3.0f%%, %.0f s)\n", p->label, stage, 100 * sf,
           100 * tf, t - p->t0);
    fflush(stdout);
  }
  return 0;
}

/* ---- bakes ------------------------------------------------------------------------- */

static void sw_cfg_options(const sweep *s, const sweep_cfg *c, ub_bake_options *o)
{
  ub_bake_options_default(o);
  o->quality = c->quality;
  o->gather_rays = c->gather_rays;
  o->bounces = c->bounces;
  o->texel_size = c->texel_size;
  o->glg_spacing = c->glg_spacing;
  o->target_error = c->target_error;
  o->threads = s->threads;
  o->seed = s->seed;
}

/* Bakes c into dir (timed: s->repeat times, keeping the fastest wall time); s->repeat 0 (auto):
 * once, or SWEEP_AUTO_REPEAT times if the first bake was shorter than
 * SWEEP_AUTO_REPEAT_SECONDS (short bakes are the ones another process's burst distorts). */
static int sw_bake(sweep *s, const sweep_cfg *c, uint32_t seed, const char *dir,
                   const char *label, int timed, ub_bake_stats *out_st, double *out_seconds,
                   double *out_core)
{
  ub_bake_options o;
  sw_cfg_options(s, c, &o);
  o.seed = seed;
  o.out_dir = dir;
  ub_log log = {sw_log, s};
  double best = INFINITY, best_core = 0.0;
  int runs = timed && s->repeat > 0 ? s->repeat : 1;
  for (int k = 0; k < runs; k++) {
    sw_progress pr = {label, sw_now(), sw_now()};
    o.progress = sw_on_progress;
    o.progress_user = &pr;
    ub_bake_stats st;
    double c0 = sw_cpu_seconds(), t0 = sw_now();
    ub_result r = ub_bake_level(s->level, &o, &log, &st);
    double dt = sw_now() - t0, dc = sw_cpu_seconds() - c0;
    if (r != UB_OK) {
      if (!s->log_errors)
        fprintf(stderr, "ubake: %s: bake (%s) failed: %s\n", s->level, label,
                ub_result_string(r));
      return 0;
    }
    if (timed && s->repeat == 0 && k == 0 && dt < SWEEP_AUTO_REPEAT_SECONDS)
      runs = SWEEP_AUTO_REPEAT;
    if (dt < best) {
      best = dt;
      best_core = dc;
      *out_st = st;
    }
  }
  *out_seconds = best;
  *out_core = best_core;
  return 1;
}

static ub_runtime *sw_load(sweep *s, const char *ubk)
{
  ub_log log = {sw_log, s};
  ub_runtime *rt = NULL;
  ub_result r = ub_runtime_load(ubk, &log, &rt);
  if (r != UB_OK) {
    if (!s->log_errors)
      fprintf(stderr, "ubake: %s: %s\n", ubk, ub_result_string(r));
    return NULL;
  }
  return rt;
}

/* ---- ground-truth points ----------------------------------------------------------- */

/* Lightmap points: area-weighted random lightmapped triangles of the middle bake, uniform
 * barycentrics, the triangle's geometric normal; hidden surfaces (facing into solid
 * geometry) are skipped. GLG points: uniform points in random GLG tetrahedra of the middle
 * bake, outside solid geometry, uniformly random normals. */
static int sw_pick_points(sweep *s, const ub_bakefile *bf)
{
  int want_glg = bf->glg_tet_count ? s->points / 2 : 0;
  int want_lm = s->points - want_glg;
  s->pts = calloc((size_t)s->points, sizeof *s->pts);
  double *cdf = calloc(bf->triangle_count ? bf->triangle_count : 1, sizeof *cdf);
  if (!s->pts || !cdf) {
    free(cdf);
    fprintf(stderr, "ubake: sweep: out of memory\n");
    return 0;
  }
  double total = 0.0;
  for (uint32_t t = 0; t < bf->triangle_count; t++) {
    if (bf->tri_atlas[t] >= 0) {
      const float *a = bf->positions + 3 * (size_t)bf->indices[3 * t];
      const float *b = bf->positions + 3 * (size_t)bf->indices[3 * t + 1];
      const float *c = bf->positions + 3 * (size_t)bf->indices[3 * t + 2];
      double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
      double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
      double x = e1[1] * e2[2] - e1[2] * e2[1], y = e1[2] * e2[0] - e1[0] * e2[2],
             z = e1[0] * e2[1] - e1[1] * e2[0];
      total += 0.5 * sqrt(x * x + y * y + z * z);
    }
    cdf[t] = total;
  }
  int n = 0;
  for (int i = 0; n < want_lm && total > 0.0 && i < SWEEP_TRIES * want_lm; i++) {
    uint32_t h = ub_hash4(SWEEP_POINT_SEED, PT_LIGHTMAP, (uint32_t)i, 0);
    double u0 = ub_u01(h) * total;
    uint32_t lo = 0, hi = bf->triangle_count - 1;
    while (lo < hi) {
      uint32_t mid = lo + (hi - lo) / 2;
      if (cdf[mid] > u0)
        hi = mid;
      else
        lo = mid + 1;
    }
    uint32_t t = lo;
    if (bf->tri_atlas[t] < 0)
      continue;
    const float *a = bf->positions + 3 * (size_t)bf->indices[3 * t];
    const float *b = bf->positions + 3 * (size_t)bf->indices[3 * t + 1];
    const float *c = bf->positions + 3 * (size_t)bf->indices[3 * t + 2];
    float su = sqrtf(ub_u01(ub_hash4(h, 1, 0, 0))), u2 = ub_u01(ub_hash4(h, 2, 0, 0));
    float b0 = 1.0f - su, b1 = u2 * su, b2 = 1.0f - b0 - b1;
    sweep_pt *pt = &s->pts[n];
    float e1[3], e2[3];
    for (int k = 0; k < 3; k++) {
      pt->p[k] = b0 * a[k] + b1 * b[k] + b2 * c[k];
      e1[k] = b[k] - a[k];
      e2[k] = c[k] - a[k];
    }
    float nn[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                   e1[0] * e2[1] - e1[1] * e2[0]};
    float len = sqrtf(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]);
    if (!(len > 0.0f) || !isfinite(len))
      continue;
    for (int k = 0; k < 3; k++)
      pt->n[k] = nn[k] / len;
    if (!sw_point_open(s->rt, pt->p, pt->n, SWEEP_NEAR_TEXELS * s->texel0))
      continue;
    pt->kind = PT_LIGHTMAP;
    n++;
  }
  free(cdf);
  s->nlm = n;
  for (int i = 0; n - s->nlm < want_glg && i < SWEEP_TRIES * want_glg; i++) {
    uint32_t h = ub_hash4(SWEEP_POINT_SEED, PT_GLG, (uint32_t)i, 0);
    uint32_t tet = h % bf->glg_tet_count;
    /* Uniform barycentrics on the simplex: normalised exponentials. */
    double w[4], sum = 0.0;
    for (int k = 0; k < 4; k++) {
      w[k] = -log(1.0 - (double)ub_u01(ub_hash4(h, 1 + k, 0, 0)));
      sum += w[k];
    }
    sweep_pt *pt = &s->pts[n];
    for (int k = 0; k < 3; k++) {
      double v = 0.0;
      for (int c = 0; c < 4; c++)
        v += w[c] / sum * bf->glg_positions[3 * (size_t)bf->glg_tets[4 * (size_t)tet + c] + k];
      pt->p[k] = (float)v;
    }
    if (!sw_point_open(s->rt, pt->p, NULL, 0.0f))
      continue;
    float z = 1.0f - 2.0f * ub_u01(ub_hash4(h, 5, 0, 0)),
          phi = 6.2831853f * ub_u01(ub_hash4(h, 6, 0, 0)), r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    pt->n[0] = r * cosf(phi);
    pt->n[1] = z;
    pt->n[2] = r * sinf(phi);
    pt->kind = PT_GLG;
    n++;
  }
  s->nglg = n - s->nlm;
  s->npts = n;
  if (s->nlm < want_lm || s->nglg < want_glg)
    fprintf(stderr, "ubake: warning: sweep: found %d of %d lightmap and %d of %d GLG points\n",
            s->nlm, want_lm, s->nglg, want_glg);
  if (n == 0) {
    fprintf(stderr, "ubake: %s: no ground-truth points found (no lightmapped surfaces?)\n",
            s->level);
    return 0;
  }
  return 1;
}

static int sw_same_point(const sweep_pt *a, int kind, const float p[3], const float n[3])
{
  if (a->kind != kind)
    return 0;
  for (int k = 0; k < 3; k++) {
    float tp = 1e-5f * (1.0f + fabsf(a->p[k])), tn = 1e-5f;
    if (!(fabsf(a->p[k] - p[k]) <= tp) || !(fabsf(a->n[k] - n[k]) <= tn))
      return 0;
  }
  return 1;
}

static const char *REF_HEADER =
    "kind,x,y,z,nx,ny,nz,spp,ref_r,ref_g,ref_b,se_r,se_g,se_b,l2_r,l2_g,l2_b,l2_se_r,"
    "l2_se_g,l2_se_b\n";

static void sw_write_ref_row(FILE *f, const sweep_pt *pt, uint32_t spp)
{
  fprintf(f, "%s,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%u,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g",
          pt->kind == PT_GLG ? "glg" : "lightmap", pt->p[0], pt->p[1], pt->p[2], pt->n[0],
          pt->n[1], pt->n[2], spp, pt->ref[0], pt->ref[1], pt->ref[2], pt->se[0], pt->se[1],
          pt->se[2]);
  for (int c = 0; c < 6; c++)
    fprintf(f, ",%.9g", c < 3 ? pt->floor[c] : pt->floor_se[c - 3]);
  fputc('\n', f);
}

/* Reads the cache: the rows that match our points, in order, with the same spp. Returns
 * how many leading points now have their reference. */
static int sw_read_ref_cache(sweep *s, const char *path)
{
  FILE *f = fopen(path, "r");
  if (!f)
    return 0;
  char line[1024];
  int i = 0;
  if (!fgets(line, sizeof line, f) || strcmp(line, REF_HEADER) != 0) {
    fclose(f);
    return 0;
  }
  while (i < s->npts && fgets(line, sizeof line, f)) {
    char kind[16];
    float p[3], n[3], ref[3], se[3], fl[3], fse[3];
    unsigned spp;
    if (sscanf(line, "%15[a-z],%f,%f,%f,%f,%f,%f,%u,%f,%f,%f,%f,%f,%f,%f,%f,%f,%f,%f,%f", kind,
               &p[0], &p[1], &p[2], &n[0], &n[1], &n[2], &spp, &ref[0], &ref[1], &ref[2],
               &se[0], &se[1], &se[2], &fl[0], &fl[1], &fl[2], &fse[0], &fse[1],
               &fse[2]) != 20)
      break;
    int k = !strcmp(kind, "glg") ? PT_GLG : !strcmp(kind, "lightmap") ? PT_LIGHTMAP : -1;
    if (spp != s->ref_spp || !sw_same_point(&s->pts[i], k, p, n))
      break;
    int finite = 1;
    for (int c = 0; c < 3; c++)
      finite &= isfinite(ref[c]) && isfinite(se[c]) && ref[c] >= 0.0f && se[c] >= 0.0f;
    if (!finite)
      break;
    for (int c = 0; c < 3 && k == PT_GLG; c++)
      finite &= isfinite(fl[c]) && isfinite(fse[c]) && fl[c] >= 0.0f && fse[c] >= 0.0f;
    if (!finite)
      break;
    memcpy(s->pts[i].ref, ref, sizeof ref);
    memcpy(s->pts[i].se, se, sizeof se);
    memcpy(s->pts[i].floor, fl, sizeof fl);
    memcpy(s->pts[i].floor_se, fse, sizeof fse);
    s->pts[i].have_ref = 1;
    i++;
  }
  fclose(f);
  return i;
}

/* Files the sweep rewrites are written to PATH.tmp and renamed into place, so a killed run
 * never leaves half a file: sw_tmp_open opens PATH.tmp (its name into tmp), sw_tmp_commit
 * closes and renames it. Both print the error and return NULL / 0 on failure. */
static FILE *sw_tmp_open(const char *path, char *tmp, size_t tmp_cap)
{
  snprintf(tmp, tmp_cap, "%s.tmp", path);
  FILE *f = fopen(tmp, "w");
  if (!f)
    fprintf(stderr, "ubake: %s: cannot write: %s\n", tmp, strerror(errno));
  return f;
}

static int sw_tmp_commit(FILE *f, const char *tmp, const char *path)
{
  if (fclose(f) != 0 || rename(tmp, path) != 0) {
    fprintf(stderr, "ubake: %s: cannot write: %s\n", path, strerror(errno));
    return 0;
  }
  return 1;
}

/* Reference at every point, once: reuses DIR/reference_points.csv where it matches and
 * appends each new point as soon as it is traced (a killed run resumes where it was). */
static int sw_references(sweep *s)
{
  char path[1280], tmp[1300];
  snprintf(path, sizeof path, "%s/reference_points.csv", s->out_dir);
  int cached = sw_read_ref_cache(s, path);
  /* Rewrite the file with the matching prefix only, then append. */
  FILE *f = sw_tmp_open(path, tmp, sizeof tmp);
  if (!f)
    return 0;
  fputs(REF_HEADER, f);
  for (int i = 0; i < cached; i++)
    sw_write_ref_row(f, &s->pts[i], s->ref_spp);
  if (!sw_tmp_commit(f, tmp, path))
    return 0;
  printf("sweep: reference at %d points (%d lightmap, %d GLG), %u spp: %d cached in %s\n",
         s->npts, s->nlm, s->nglg, s->ref_spp, cached, path);
  fflush(stdout);
  f = fopen(path, "a");
  if (!f) {
    fprintf(stderr, "ubake: %s: cannot append: %s\n", path, strerror(errno));
    return 0;
  }
  ub_log log = {sw_log, s};
  double t0 = sw_now(), last = t0;
  for (int i = cached; i < s->npts; i++) {
    ub_reference_params rp;
    ub_reference_params_init(&rp);
    memcpy(rp.position, s->pts[i].p, sizeof rp.position);
    memcpy(rp.normal, s->pts[i].n, sizeof rp.normal);
    rp.spp = s->ref_spp;
    rp.seed = SWEEP_REF_SEED + (uint32_t)i;
    rp.threads = s->threads;
    ub_result r = ub_reference_irradiance(s->scene, s->rt, s->em, &rp, s->pts[i].ref,
                                          s->pts[i].se, &log);
    sweep_pt *pt = &s->pts[i];
    for (int c = 0; c < 3; c++)
      pt->floor[c] = pt->floor_se[c] = NAN;
    if (r == UB_OK && pt->kind == PT_GLG) {
      /* The representation floor: what an exact SH L2 probe at this point answers
       * (windowed as the GLG's probes), from its own paths. */
      float sh[27], raw[3];
      rp.seed = SWEEP_REF_SEED + 0x10000u + (uint32_t)i;
      r = ub_reference_radiance_sh(s->scene, s->rt, s->em, &rp, sh, raw, pt->floor_se, &log);
      if (r == UB_OK) {
        ub_sh2_window(sh);
        ub_sh2_irradiance(sh, pt->n, pt->floor);
      }
    }
    if (r != UB_OK) {
      fclose(f);
      fprintf(stderr, "ubake: %s: reference at point %d failed: %s\n", s->level, i,
              ub_result_string(r));
      return 0;
    }
    s->pts[i].have_ref = 1;
    sw_write_ref_row(f, &s->pts[i], s->ref_spp);
    fflush(f);
    double t = sw_now();
    if (t - last >= 10.0 || i + 1 == s->npts) {
      last = t;
      printf("  reference %d/%d (%.0f s)\n", i + 1, s->npts, t - t0);
      fflush(stdout);
    }
  }
  if (fclose(f) != 0) {
    fprintf(stderr, "ubake: %s: write failed\n", path);
    return 0;
  }
  double se2 = 0.0, r2 = 0.0;
  for (int i = 0; i < s->npts; i++) {
    double se = 0.2126 * s->pts[i].se[0] + 0.7152 * s->pts[i].se[1] + 0.0722 * s->pts[i].se[2];
    double rl = sw_lum(s->pts[i].ref);
    se2 += se * se;
    r2 += rl * rl;
  }
  s->ref_noise = r2 > 0.0 ? sqrt(se2 / r2) : NAN;
  printf("sweep: reference noise floor (relative RMS standard error) %.2f%%\n",
         100 * s->ref_noise);
  double fd2 = 0.0, fse2 = 0.0, fr2 = 0.0;
  for (int i = 0; i < s->npts; i++)
    if (s->pts[i].kind == PT_GLG) {
      double d = sw_lum(s->pts[i].floor) - sw_lum(s->pts[i].ref), rl = sw_lum(s->pts[i].ref);
      double se = sw_lum(s->pts[i].floor_se);
      fd2 += d * d;
      fse2 += se * se;
      fr2 += rl * rl;
    }
  s->glg_floor = fr2 > 0.0 ? sqrt(fd2 / fr2) : NAN;
  s->glg_floor_noise = fr2 > 0.0 ? sqrt(fse2 / fr2) : NAN;
  if (s->nglg)
    printf("sweep: GLG points' SH L2 floor (exact L2 probes at the points vs the reference) "
           "%.2f%% (its noise %.2f%%)\n", 100 * s->glg_floor, 100 * s->glg_floor_noise);
  return 1;
}

/* ---- measuring a bake -------------------------------------------------------------- */

static int cmp_double(const void *a, const void *b)
{
  double x = *(const double *)a, y = *(const double *)b;
  return x < y ? -1 : x > y;
}

/* Errors of one bake at the points (luminance) and, when the atlas layout matches the
 * converged bake's, at every covered texel. */
static void sw_measure(sweep *s, const ub_runtime *rt, sweep_result *res)
{
  double *rel = malloc((size_t)(s->npts ? s->npts : 1) * sizeof *rel);
  double d2[2] = {0, 0}, r2[2] = {0, 0}, mean_ref = 0.0, fd2 = 0.0;
  int nmean = 0;
  for (int i = 0; i < s->npts; i++)
    if (s->pts[i].have_ref) {
      mean_ref += sw_lum(s->pts[i].ref);
      nmean++;
    }
  mean_ref = nmean ? mean_ref / nmean : 0.0;
  double floor_ref = SWEEP_ERR_FLOOR * mean_ref;
  int nrel = 0;
  uint32_t cache = UB_GLG_NO_CACHE;
  for (int i = 0; i < s->npts; i++) {
    const sweep_pt *pt = &s->pts[i];
    if (!pt->have_ref)
      continue;
    float rgb[3], dist;
    ub_result r = pt->kind == PT_GLG ? ub_runtime_query_glg(rt, pt->p, pt->n, &cache, rgb)
                                     : ub_runtime_query_lightmap(rt, pt->p, pt->n, rgb, &dist);
    if (r != UB_OK)
      continue;
    double b = sw_lum(rgb), ref = sw_lum(pt->ref), d = b - ref;
    d2[pt->kind] += d * d;
    if (pt->kind == PT_GLG)
      fd2 += (b - sw_lum(pt->floor)) * (b - sw_lum(pt->floor));
    r2[pt->kind] += ref * ref;
    double den = ref > floor_ref ? ref : floor_ref;
    if (rel && den > 0.0)
      rel[nrel++] = fabs(d) / den;
  }
  res->rmse_lm = r2[0] > 0.0 ? sqrt(d2[0] / r2[0]) : NAN;
  res->rmse_glg = r2[1] > 0.0 ? sqrt(d2[1] / r2[1]) : NAN;
  res->glg_vs_floor = r2[1] > 0.0 ? sqrt(fd2 / r2[1]) : NAN;
  res->rmse_pts = r2[0] + r2[1] > 0.0 ? sqrt((d2[0] + d2[1]) / (r2[0] + r2[1])) : NAN;
  res->max_pts = res->p95_pts = NAN;
  if (nrel > 0) {
    qsort(rel, (size_t)nrel, sizeof *rel, cmp_double);
    res->max_pts = rel[nrel - 1];
    int k = (int)ceil(0.95 * nrel) - 1; /* nearest rank */
    res->p95_pts = rel[k < 0 ? 0 : k];
  }
  free(rel);

  res->rmse_texels = NAN;
  if (!s->conv)
    return;
  const ub_bakefile *bf = ub_runtime_bakefile(rt), *cf = ub_runtime_bakefile(s->conv);
  if (bf->atlas_count != cf->atlas_count)
    return;
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    if (bf->atlases[a].width != cf->atlases[a].width ||
        bf->atlases[a].height != cf->atlases[a].height)
      return;
  double td2 = 0.0, tr2 = 0.0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a], *ct = &cf->atlases[a];
    for (uint32_t y = 0; y < at->height; y++)
      for (uint32_t x = 0; x < at->width; x++) {
        size_t px = (size_t)y * at->width + x;
        if (at->coverage[px] != 1 || ct->coverage[px] != 1)
          continue;
        float b[3], c[3], nn[3];
        if (ub_runtime_texel_normal(s->conv, a, x, y, nn) != UB_OK ||
            ub_runtime_texel_irradiance(rt, a, x, y, nn, b) != UB_OK ||
            ub_runtime_texel_irradiance(s->conv, a, x, y, nn, c) != UB_OK)
          continue;
        double d = sw_lum(b) - sw_lum(c);
        td2 += d * d;
        tr2 += sw_lum(c) * sw_lum(c);
      }
  }
  res->rmse_texels = tr2 > 0.0 ? sqrt(td2 / tr2) : NAN;
}

/* ---- ladder ------------------------------------------------------------------------ */

static float sw_resolved_texel(const sweep *s, const sweep_cfg *c)
{
  return c->texel_size > 0.0f ? c->texel_size : s->texel0;
}

static float sw_resolved_glg(const sweep *s, const sweep_cfg *c)
{
  return c->glg_spacing > 0.0f ? c->glg_spacing : s->glg0;
}

static uint32_t sw_resolved_rays(const sweep_cfg *c)
{
  static const uint32_t preset[3] = {64, 256, 1024}; /* bake/plan.c */
  return c->gather_rays ? c->gather_rays : preset[c->quality];
}

static int sw_cfg_equal(const sweep *s, const sweep_cfg *a, const sweep_cfg *b)
{
  return a->quality == b->quality && sw_resolved_rays(a) == sw_resolved_rays(b) &&
         a->bounces == b->bounces && sw_resolved_texel(s, a) == sw_resolved_texel(s, b) &&
         sw_resolved_glg(s, a) == sw_resolved_glg(s, b) && a->target_error == b->target_error;
}

static const sweep_cfg SW_MIDDLE = {UB_QUALITY_FAST, 0, -1, 0.0f, 0.0f, 0.0};
/* The adaptive ladder: --target-error values from SWEEP_ADAPTIVE_RAYS base gather rays
 * (the middle setting otherwise), to set beside the uniform gather-rays ladder. */
#define SWEEP_ADAPTIVE_RAYS 64u

static void sw_add_rung(sweep *s, const char *setting, const char *value, const char *note,
                        sweep_cfg cfg)
{
  if (s->nrungs >= SWEEP_MAX_RUNGS)
    return;
  sweep_rung *r = &s->rungs[s->nrungs++];
  r->setting = setting;
  snprintf(r->value, sizeof r->value, "%s", value);
  snprintf(r->note, sizeof r->note, "%s", note);
  r->cfg = cfg;
  for (int i = 0; i < s->nresults; i++)
    if (sw_cfg_equal(s, &s->cfgs[i], &cfg)) {
      r->result = i;
      return;
    }
  r->result = s->nresults;
  s->cfgs[s->nresults] = cfg;
  memset(&s->results[s->nresults], 0, sizeof s->results[0]);
  s->nresults++;
}

static void sw_build_ladder(sweep *s)
{
  char v[32], note[16];
  /* The middle setting first: it is baked first and the points are picked from it. */
  s->cfgs[0] = SW_MIDDLE;
  memset(&s->results[0], 0, sizeof s->results[0]);
  s->nresults = 1;
  static const uint32_t rays_full[] = {16, 32, 64, 128, 256, 512, 1024};
  static const uint32_t rays_quick[] = {16, 64, 256};
  static const uint32_t rays_short[] = {64, 256};
  const uint32_t *rays = s->quick ? rays_quick : s->sampling == 2 ? rays_short : rays_full;
  int nrays = s->presets ? 0 : s->quick ? 3 : s->sampling == 2 ? 2 : 7;
  for (int i = 0; i < nrays; i++) {
    sweep_cfg c = SW_MIDDLE;
    c.gather_rays = rays[i];
    snprintf(v, sizeof v, "%u", rays[i]);
    sw_add_rung(s, "gather_rays", v, "", c);
  }
  if (!s->quick && !s->sampling && !s->presets) {
    for (int b = 1; b <= 4; b++) {
      sweep_cfg c = SW_MIDDLE;
      c.bounces = b == 4 ? -1 : b;
      snprintf(v, sizeof v, b == 4 ? "auto" : "%d", b);
      sw_add_rung(s, "bounces", v, "", c);
    }
    static const float mul[3] = {2.0f, 1.0f, 0.5f};
    for (int i = 0; i < 3; i++) {
      sweep_cfg c = SW_MIDDLE;
      c.texel_size = mul[i] == 1.0f ? 0.0f : mul[i] * s->texel0;
      snprintf(v, sizeof v, "%.4g", mul[i] * s->texel0);
      snprintf(note, sizeof note, "x%g", mul[i]);
      sw_add_rung(s, "texel_size", v, note, c);
    }
    for (int i = 0; i < 3; i++) {
      sweep_cfg c = SW_MIDDLE;
      c.glg_spacing = mul[i] == 1.0f ? 0.0f : mul[i] * s->glg0;
      snprintf(v, sizeof v, "%.4g", mul[i] * s->glg0);
      snprintf(note, sizeof note, "x%g", mul[i]);
      sw_add_rung(s, "glg_spacing", v, note, c);
    }
  }
  static const double targets_full[] = {0.2, 0.1, 0.05, 0.02, 0.01};
  static const double targets_quick[] = {0.1};
  const double *targets = s->quick ? targets_quick : targets_full;
  int ntargets = s->presets ? 0 : s->quick ? 1 : s->sampling == 2 ? 4 : 5;
  for (int i = 0; i < ntargets; i++) {
    sweep_cfg c = SW_MIDDLE;
    c.gather_rays = SWEEP_ADAPTIVE_RAYS;
    c.target_error = targets[i];
    snprintf(v, sizeof v, "%g", targets[i]);
    snprintf(note, sizeof note, "%ur", SWEEP_ADAPTIVE_RAYS);
    sw_add_rung(s, "adaptive", v, note, c);
  }
  for (int q = UB_QUALITY_DRAFT; !s->sampling && q <= (s->quick ? UB_QUALITY_FAST : UB_QUALITY_HIGH); q++) {
    sweep_cfg c = SW_MIDDLE;
    c.quality = (ub_quality)q;
    sw_add_rung(s, "preset", ub_quality_name((ub_quality)q), "", c);
  }
}

static void sw_csv_num(FILE *f, double v)
{
  if (isfinite(v))
    fprintf(f, ",%.6g", v);
  else
    fputs(",", f);
}

static const char *CSV_HEADER =
    "setting,value,seconds,core_seconds,rays,rel_rmse_points,max_err_points,p95_err_points,"
    "rel_rmse_texels,texels,bounces,rel_rmse_lightmap_points,rel_rmse_glg_points,"
    "ref_noise_points,glg_l2_floor,rel_rmse_glg_vs_l2_floor\n";

/* DIR/sweep.csv with every rung measured so far (temporary file renamed into place). */
static int sw_write_csv(const sweep *s)
{
  char path[1280], tmp[1300];
  snprintf(path, sizeof path, "%s/sweep.csv", s->out_dir);
  FILE *f = sw_tmp_open(path, tmp, sizeof tmp);
  if (!f)
    return 0;
  fputs(CSV_HEADER, f);
  for (int i = 0; i < s->nrungs; i++) {
    const sweep_rung *r = &s->rungs[i];
    const sweep_result *m = &s->results[r->result];
    if (!m->done)
      continue;
    fprintf(f, "%s,%s,%.4f,%.4f,%llu", r->setting, r->value, m->seconds, m->core_seconds,
            (unsigned long long)m->rays);
    sw_csv_num(f, m->rmse_pts);
    sw_csv_num(f, m->max_pts);
    sw_csv_num(f, m->p95_pts);
    sw_csv_num(f, m->rmse_texels);
    fprintf(f, ",%u,%u", m->texels, m->bounces);
    sw_csv_num(f, m->rmse_lm);
    sw_csv_num(f, m->rmse_glg);
    sw_csv_num(f, s->ref_noise);
    sw_csv_num(f, s->glg_floor);
    sw_csv_num(f, m->glg_vs_floor);
    fputc('\n', f);
  }
  if (!sw_tmp_commit(f, tmp, path))
    return 0;
  return 1;
}

/* A percentage cell of presets.md ("–" when not applicable). */
static void sw_md_pct(FILE *f, double v, int decimals)
{
  if (isfinite(v))
    fprintf(f, " %.*f%% |", decimals, 100 * v);
  else
    fputs(" – |", f);
}

/* The header of presets.md's table (also what `make sweep-presets` keeps once when it joins
 * the levels' tables). */
static const char *PRESETS_MD_HEADER =
    "| level | preset | wall s | core-s | rays | rel RMSE, all points | p95, all points | "
    "rel RMSE, lightmap points | rel RMSE, GLG points | rel RMSE, texels vs converged |\n"
    "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n";

/* DIR/presets.md: the preset rungs measured so far as the rows of README's "The presets,
 * measured" table, then one line saying how they were measured. Nothing if the ladder has
 * no preset rung. */
static int sw_write_presets_md(const sweep *s, double load_now)
{
  int any = 0;
  for (int i = 0; i < s->nrungs; i++)
    any |= !strcmp(s->rungs[i].setting, "preset") && s->results[s->rungs[i].result].done;
  if (!any)
    return 1;
  char path[1280], tmp[1300];
  snprintf(path, sizeof path, "%s/presets.md", s->out_dir);
  FILE *f = sw_tmp_open(path, tmp, sizeof tmp);
  if (!f)
    return 0;
  fputs(PRESETS_MD_HEADER, f);
  for (int i = 0; i < s->nrungs; i++) {
    const sweep_rung *r = &s->rungs[i];
    const sweep_result *m = &s->results[r->result];
    if (strcmp(r->setting, "preset") || !m->done)
      continue;
    fprintf(f, "| %s | %s | %.*f | %.*f | %.1f M |", s->name, r->value,
            m->seconds < 10.0 ? 2 : 1, m->seconds, m->core_seconds < 10.0 ? 2 : 1,
            m->core_seconds, m->rays * 1e-6);
    sw_md_pct(f, m->rmse_pts, 1);
    sw_md_pct(f, m->p95_pts, 1);
    sw_md_pct(f, m->rmse_lm, 2);
    sw_md_pct(f, m->rmse_glg, 1);
    sw_md_pct(f, m->rmse_texels, 2);
    fputc('\n', f);
  }
  fprintf(f, "\n%s: %d points (%d lightmap, %d GLG), reference %u spp (its noise %.2f%% "
             "relative RMS s.e.), ",
          s->name, s->npts, s->nlm, s->nglg, s->ref_spp,
          isfinite(s->ref_noise) ? 100 * s->ref_noise : 0.0);
  if (s->nglg && isfinite(s->glg_floor))
    fprintf(f, "exact SH L2 probes at the GLG points err %.1f%% (the GLG's representation "
               "floor; its noise %.1f%%), ", 100 * s->glg_floor, 100 * s->glg_floor_noise);
  if (s->conv)
    fprintf(f, "converged bake %u gather rays (%u texels), ", s->converged_rays,
            s->conv_texels);
  else
    fputs("no converged bake, ", f);
  fprintf(f, "%ld cores, load average %.2f at start, %.2f now; `ubake sweep",
          sysconf(_SC_NPROCESSORS_ONLN), s->load_begin, load_now);
  for (int i = 0; i < s->argc; i++)
    fprintf(f, " %s", s->argv[i]);
  fputs("`\n", f);
  if (!sw_tmp_commit(f, tmp, path))
    return 0;
  return 1;
}

/* DIR/sweep.gp, then gnuplot in DIR → DIR/sweep.png. Missing gnuplot is a warning (the
 * CSV is the result; the plot is a view of it). */
static int sw_plot(const sweep *s, double load_end)
{
  char path[1280];
  snprintf(path, sizeof path, "%s/sweep.gp", s->out_dir);
  FILE *f = fopen(path, "w");
  if (!f) {
    fprintf(stderr, "ubake: %s: cannot write: %s\n", path, strerror(errno));
    return 0;
  }
  long cores = sysconf(_SC_NPROCESSORS_ONLN);
  fprintf(f,
          "# ubake sweep plot of sweep.csv (written by ubake sweep; run: cd DIR && gnuplot sweep.gp)\n"
          "set terminal pngcairo size 1500,1150 font ',10' noenhanced\n"
          "set output 'sweep.png'\n"
          "set datafile separator ','\n"
          "set logscale xy\n"
          "set grid xtics ytics mxtics mytics lc rgb '#dddddd'\n"
          "set key bottom left\n"
          "# x axis: 3 = wall-clock seconds, 4 = core-seconds (steadier on a shared machine), 5 = rays\n"
          "xcol = 3\n"
          "set xlabel (xcol == 3 ? 'bake wall-clock seconds' : xcol == 4 ? 'bake core-seconds (CPU time)' : 'rays traced')\n"
          "knobs = 'gather_rays bounces texel_size glg_spacing preset adaptive'\n"
          "sel(k, c) = strcol(1) eq k ? column(c) : NaN\n"
          "refnoise = %.6g\n"
          "set multiplot layout 2,2 title '%s: error vs bake time, one knob at a time from the "
          "fast preset (%ld cores, load average %.1f-%.1f; reference %u spp)'\n"
          "do for [col in '6 12 13 9'] {\n"
          "  c = int(col)\n"
          "  set ylabel (c == 6 ? 'relative RMSE at all %d reference points' : c == 12 ? "
          "'relative RMSE at the %d lightmap points' : c == 13 ? 'relative RMSE at the %d GLG "
          "points' : 'relative RMSE vs converged bake, all texels')\n"
          "  plot for [i=1:words(knobs)] 'sweep.csv' using (sel(word(knobs,i),xcol)):(sel(word(knobs,i),c)) "
          "with linespoints lw 2 pt 7 lc i title word(knobs,i), \\\n"
          "       for [i=1:words(knobs)] 'sweep.csv' using (sel(word(knobs,i),xcol)):(sel(word(knobs,i),c)):2 "
          "with labels offset char 0,0.9 font ',8' notitle, \\\n"
          "       (c == 9 ? NaN : refnoise) with lines dt 2 lc rgb 'gray40' title "
          "(c == 9 ? '' : 'reference noise (all points)')\n"
          "}\n"
          "unset multiplot\n",
          isfinite(s->ref_noise) ? s->ref_noise : 0.0, s->name, cores, s->load_begin, load_end,
          s->ref_spp, s->npts, s->nlm, s->nglg);
  if (fclose(f) != 0) {
    fprintf(stderr, "ubake: %s: write failed\n", path);
    return 0;
  }
  fflush(stdout);
  pid_t pid = fork();
  if (pid < 0) {
    fprintf(stderr, "ubake: sweep: cannot start gnuplot: %s\n", strerror(errno));
    return 0;
  }
  if (pid == 0) {
    if (chdir(s->out_dir) != 0)
      _exit(126);
    execlp("gnuplot", "gnuplot", "sweep.gp", (char *)NULL);
    _exit(127);
  }
  int status = 0;
  while (waitpid(pid, &status, 0) < 0 && errno == EINTR)
    ;
  if (WIFEXITED(status) && WEXITSTATUS(status) == 127) {
    fprintf(stderr, "ubake: warning: gnuplot not found: no %s/sweep.png (install "
                    "gnuplot-nox, e.g. scripts/install-deps.sh; then cd %s && gnuplot sweep.gp)\n",
            s->out_dir, s->out_dir);
    return 1;
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    fprintf(stderr, "ubake: %s: gnuplot failed (status %d)\n", path, status);
    return 0;
  }
  printf("sweep: wrote %s/sweep.png\n", s->out_dir);
  return 1;
}

/* ---- the sweep --------------------------------------------------------------------- */

static void sw_print_result(const sweep_rung *r, const sweep_result *m)
{
  printf("  %-12s %-6s %-5s %8.2f s %8.2f core-s %9.2f M rays  points %6.2f%% (p95 %6.2f%%, "
         "max %6.2f%%)  texels %s%.2f%%%s",
         r->setting, r->value, r->note, m->seconds, m->core_seconds, m->rays * 1e-6,
         100 * m->rmse_pts, 100 * m->p95_pts, 100 * m->max_pts,
         isfinite(m->rmse_texels) ? "" : "(n/a ", isfinite(m->rmse_texels) ? 100 * m->rmse_texels : 0.0,
         isfinite(m->rmse_texels) ? "" : ")");
  if (isfinite(m->rmse_glg))
    printf("  GLG %.2f%% (vs exact L2 probes %.2f%%)", 100 * m->rmse_glg, 100 * m->glg_vs_floor);
  printf("\n");
  fflush(stdout);
}

/* Bakes and measures result index ri if not done yet; dir is where its bake goes. */
static int sw_run_result(sweep *s, int ri, const char *label, const char *dir, int keep)
{
  sweep_result *m = &s->results[ri];
  if (m->done)
    return 1;
  ub_bake_stats st;
  double sec, core;
  if (!sw_bake(s, &s->cfgs[ri], s->seed, dir, label, 1, &st, &sec, &core))
    return 0;
  ub_runtime *rt = sw_load(s, st.ubk_path);
  if (!rt)
    return 0;
  m->seconds = sec;
  m->core_seconds = core;
  m->rays = st.rays_total;
  m->texels = st.texels;
  m->bounces = st.bounces;
  sw_measure(s, rt, m);
  ub_runtime_free(rt);
  m->done = 1;
  if (!keep && !s->keep_bakes)
    ub_remove_dir(dir); /* a bake writes files only */
  return 1;
}

static int sw_run(sweep *s)
{
  ub_log log = {sw_log, s};
  s->load_begin = sw_loadavg();
  printf("ubake sweep %s -> %s (%s ladder, %d points, %u spp reference, converged bake %u "
         "rays, %ld cores, load average %.2f)\n",
         s->level, s->out_dir,
         s->quick ? "quick" : s->presets ? "presets" : s->sampling ? "sampling" : "full", s->points, s->ref_spp,
         s->converged_rays, sysconf(_SC_NPROCESSORS_ONLN), s->load_begin);
  fflush(stdout);
  ub_result r = ub_scene_load(s->level, &log, &s->scene);
  if (r == UB_OK)
    r = ub_rt_create(s->scene, NULL, &log, &s->rt);
  if (r == UB_OK)
    r = ub_emitters_build(s->scene, &s->em);
  if (r != UB_OK) {
    if (!s->log_errors)
      fprintf(stderr, "ubake: %s: %s\n", s->level, ub_result_string(r));
    return 0;
  }
  if (sw_mkdir_p(s->out_dir) != 0) {
    fprintf(stderr, "ubake: %s: cannot create: %s\n", s->out_dir, strerror(errno));
    return 0;
  }
  /* Only now: a level that does not load leaves no folder behind. */
  char bakes[1280], dir[1400], ubk[1500], rep[1500];
  snprintf(bakes, sizeof bakes, "%s/bakes", s->out_dir);
  if (sw_mkdir_p(bakes) != 0) {
    fprintf(stderr, "ubake: %s: cannot create: %s\n", bakes, strerror(errno));
    return 0;
  }
  s->texel0 = s->scene->texel_size > 0.0f ? s->scene->texel_size : 0.25f;
  s->glg0 = s->scene->glg_spacing > 0.0f ? s->scene->glg_spacing : 2.0f;
  sw_build_ladder(s);

  /* 1. The middle setting (the fast preset), kept for picking the points. It is baked again
   * in its place in the ladder, so that its time is taken next to its neighbours' (the
   * load of a shared machine drifts over a long sweep). The presets ladder picks them from
   * a draft bake instead: the points depend only on the atlas and the GLG, which the preset
   * does not change, and draft costs a quarter of fast. */
  sweep_cfg midc = s->cfgs[0];
  if (s->presets)
    midc.quality = UB_QUALITY_DRAFT;
  printf("sweep: [middle] %s preset (%u gather rays, auto bounces, texel %.4g m, GLG "
         "spacing %.4g m)\n",
         ub_quality_name(midc.quality), sw_resolved_rays(&midc), s->texel0, s->glg0);
  fflush(stdout);
  snprintf(dir, sizeof dir, "%s/middle", bakes);
  ub_bake_stats st;
  double sec, core;
  if (!sw_bake(s, &midc, s->seed, dir, "middle", 0, &st, &sec, &core))
    return 0;
  ub_runtime *mid = sw_load(s, st.ubk_path);
  if (!mid)
    return 0;

  /* 2. Ground truth at fixed points, cached. */
  /* the file as written: a run-time's copy keeps no GLG probe positions */
  ub_bakefile *midf = NULL;
  if (ub_bakefile_read(st.ubk_path, NULL, &midf) != UB_OK || !sw_pick_points(s, midf) ||
      !sw_references(s)) {
    ub_bakefile_free(midf);
    ub_runtime_free(mid);
    return 0;
  }
  ub_bakefile_free(midf);

  /* 3. The converged bake (per-texel ground truth). */
  if (s->converged_rays) {
    sweep_cfg c = SW_MIDDLE;
    c.quality = UB_QUALITY_HIGH;
    c.gather_rays = s->converged_rays;
    snprintf(dir, sizeof dir, "%s/converged_%u", bakes, s->converged_rays);
    snprintf(ubk, sizeof ubk, "%s/%s.ubk", dir, s->name);
    snprintf(rep, sizeof rep, "%s/%s.report.json", dir, s->name);
    if (s->reuse_conv && sw_file_exists(ubk) && sw_file_exists(rep)) {
      printf("sweep: converged bake: reusing %s\n", ubk);
    } else {
      printf("sweep: converged bake (%u gather rays, high preset's other samples, seed %u)\n",
             s->converged_rays, SWEEP_CONVERGED_SEED);
      fflush(stdout);
      ub_bake_stats cs;
      if (!sw_bake(s, &c, SWEEP_CONVERGED_SEED, dir, "converged", 0, &cs, &sec, &core)) {
        ub_runtime_free(mid);
        return 0;
      }
      printf("  converged: %.1f s, %.1f M rays, %u texels\n", sec, cs.rays_total * 1e-6,
             cs.texels);
    }
    s->conv = sw_load(s, ubk);
    if (!s->conv) {
      ub_runtime_free(mid);
      return 0;
    }
    const ub_bakefile *cf = ub_runtime_bakefile(s->conv);
    for (uint32_t at = 0; at < cf->atlas_count; at++)
      for (size_t px = 0; px < (size_t)cf->atlases[at].width * cf->atlases[at].height; px++)
        s->conv_texels += cf->atlases[at].coverage[px] == 1;
  }
  ub_runtime_free(mid);

  /* 4. The ladder. */
  int total = 0;
  for (int i = 0; i < s->nresults; i++)
    total += !s->results[i].done;
  int k = 0;
  const char *last_setting = "";
  for (int i = 0; i < s->nrungs; i++) {
    const sweep_rung *rg = &s->rungs[i];
    if (strcmp(last_setting, rg->setting)) {
      printf("sweep: knob %s\n", rg->setting);
      last_setting = rg->setting;
    }
    if (!s->results[rg->result].done) {
      char label[64];
      snprintf(label, sizeof label, "%s=%s", rg->setting, rg->value);
      printf("  [%d/%d] baking %s %s\n", ++k, total, label, rg->note);
      fflush(stdout);
      snprintf(dir, sizeof dir, "%s/%s_%s", bakes, rg->setting, rg->value);
      if (!sw_run_result(s, rg->result, label, dir, 0))
        return 0;
    }
    sw_print_result(rg, &s->results[rg->result]);
    if (!sw_write_csv(s) || !sw_write_presets_md(s, sw_loadavg()))
      return 0;
  }
  double load_end = sw_loadavg();
  printf("sweep: wrote %s/sweep.csv (%d rows, %d bakes); load average %.2f at start, %.2f "
         "at end\n",
         s->out_dir, s->nrungs, s->nresults, s->load_begin, load_end);
  if (s->plot && !sw_plot(s, load_end))
    return 0;
  return 1;
}

static const char *SWEEP_HELP =
    "usage: ubake sweep LEVEL.gltf|.glb [-o DIR] [options]\n"
    "Bakes a ladder of settings, one knob at a time from the fast preset, and measures each\n"
    "bake against ground truth: the reference path tracer at fixed points (lightmap surface\n"
    "points and GLG points, traced once, cached in DIR/reference_points.csv) and a converged\n"
    "bake at every texel. Writes DIR/sweep.csv (setting, value, seconds, core_seconds, rays,\n"
    "rel_rmse_points, max_err_points, p95_err_points, rel_rmse_texels, ...) and DIR/sweep.png\n"
    "(gnuplot: error vs seconds, log-log, one curve per knob); with preset rungs also\n"
    "DIR/presets.md (README's preset table rows and how they were measured).\n"
    "  -o DIR               output folder (default out/sweep/LEVELNAME)\n"
    "  --ladder quick|full|presets|sampling|sampling-short\n"
    "                       full (default): gather rays 16..1024, bounces 1,2,3,auto, texel\n"
    "                       size x2,x1,x0.5, GLG spacing x2,x1,x0.5, adaptive (64 base gather\n"
    "                       rays, --target-error 0.2,0.1,0.05,0.02,0.01), presets\n"
    "                       draft,fast,high; quick (CI): gather rays 16,64,256, adaptive\n"
    "                       0.1, presets draft,fast; sampling: the gather-rays and adaptive\n"
    "                       ladders of full only (uniform vs adaptive sampling);\n"
    "                       sampling-short: gather rays 64,256 and adaptive 0.2..0.02;\n"
    "                       presets: draft,fast,high only (README's preset table)\n"
    "  --points N           ground-truth points, half lightmap, half GLG (default 64; quick 32)\n"
    "  --ref-spp N          reference paths per point (default 65536; quick 16384)\n"
    "  --converged-rays N   gather rays per texel of the converged bake (default 4096;\n"
    "                       quick 1024; 0 = no per-texel error)\n"
    "  --repeat N           bake every rung N times and keep the fastest (default: bakes\n"
    "                       under 10 s 3 times, longer ones once)\n"
    "  --threads N          worker threads (default: all cores)\n"
    "  --seed N             bake seed (default 1)\n"
    "  --reuse-converged    reuse DIR/bakes/converged_N/ from an earlier run (only if the\n"
    "                       baker has not changed since)\n"
    "  --keep-bakes         keep every rung's bake in DIR/bakes/ (default: only the middle\n"
    "                       and the converged bakes)\n"
    "  --no-plot            write the CSV and sweep.gp only\n"
    "  --verbose            show the bakes' stage lines and warnings\n"
    "Errors: relative RMSE = sqrt(sum (bake - ref)^2 / sum ref^2) of luminance; per-point\n"
    "error = |bake - ref| / max(ref, 0.1 x mean ref) (max and 95th percentile).\n"
    "GLG points also get the representation floor: the reference's incident radiance at the\n"
    "point projected to SH L2 and windowed as the GLG (what an exact probe there answers);\n"
    "glg_l2_floor is its error vs the reference, rel_rmse_glg_vs_l2_floor the bake's GLG vs\n"
    "it (interpolation between probes + bake noise), both relative to the reference.\n";

int ub_cli_sweep(int argc, char **argv)
{
  sweep s;
  memset(&s, 0, sizeof s);
  s.argc = argc;
  s.argv = argv;
  s.seed = 1;
  s.plot = 1;
  long points = -1, spp = -1, conv = -1, n;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i];
    const char *v = i + 1 < argc ? argv[i + 1] : NULL;
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      fputs(SWEEP_HELP, stdout);
      return 0;
    }
#define SW_USAGE(msg)                                                                       \
  do {                                                                                      \
    fprintf(stderr, "ubake sweep: %s (see 'ubake sweep --help')\n", msg);                  \
    return 1;                                                                               \
  } while (0)
    if (!strcmp(a, "-o") && v) {
      s.out_dir = v;
      i++;
    } else if (!strcmp(a, "--ladder") && v) {
      if (!strcmp(v, "quick"))
        s.quick = 1;
      else if (!strcmp(v, "presets"))
        s.presets = 1;
      else if (!strcmp(v, "sampling"))
        s.sampling = 1;
      else if (!strcmp(v, "sampling-short"))
        s.sampling = 2;
      else if (strcmp(v, "full"))
        SW_USAGE("--ladder takes quick, full, presets, sampling or sampling-short");
      i++;
    } else if (!strcmp(a, "--points") && v) {
      if (!sw_parse_uint(v, 1, 100000, &points))
        SW_USAGE("--points takes 1..100000");
      i++;
    } else if (!strcmp(a, "--ref-spp") && v) {
      if (!sw_parse_uint(v, 1, UB_REFERENCE_MAX_SPP, &spp))
        SW_USAGE("--ref-spp takes 1..2^30");
      i++;
    } else if (!strcmp(a, "--converged-rays") && v) {
      if (!sw_parse_uint(v, 0, 1L << 20, &conv))
        SW_USAGE("--converged-rays takes 0..1048576");
      i++;
    } else if (!strcmp(a, "--repeat") && v) {
      if (!sw_parse_uint(v, 1, 100, &n))
        SW_USAGE("--repeat takes 1..100");
      s.repeat = (int)n;
      i++;
    } else if (!strcmp(a, "--threads") && v) {
      if (!sw_parse_uint(v, 1, 1024, &n))
        SW_USAGE("--threads takes 1..1024");
      s.threads = (int)n;
      i++;
    } else if (!strcmp(a, "--seed") && v) {
      if (!sw_parse_uint(v, 0, 0xFFFFFFFFL, &n))
        SW_USAGE("--seed takes 0..4294967295");
      s.seed = (uint32_t)n;
      i++;
    } else if (!strcmp(a, "--reuse-converged")) {
      s.reuse_conv = 1;
    } else if (!strcmp(a, "--keep-bakes")) {
      s.keep_bakes = 1;
    } else if (!strcmp(a, "--no-plot")) {
      s.plot = 0;
    } else if (!strcmp(a, "--verbose")) {
      s.verbose = 1;
    } else if (a[0] == '-') {
      SW_USAGE("unknown option or missing value");
    } else if (!s.level) {
      s.level = a;
    } else {
      SW_USAGE("more than one level given");
    }
#undef SW_USAGE
  }
  if (!s.level) {
    fprintf(stderr, "ubake sweep: no level given (see 'ubake sweep --help')\n");
    return 1;
  }
  s.points = points > 0 ? (int)points : s.quick ? 32 : 64;
  s.ref_spp = spp > 0 ? (uint32_t)spp : s.quick ? 16384u : 65536u;
  s.converged_rays = conv >= 0 ? (uint32_t)conv : s.quick ? 1024u : 4096u;
  /* NAME as the bake names its files (DIR/NAME.ubk, where sw_run looks for them): a name
   * too long for the .ubk fails here, before any folder is made. */
  ub_log name_log = {sw_log, &s};
  if (ub_outdir_level_name(s.level, &name_log, s.name, sizeof s.name) != UB_OK)
    return 1;
  char defdir[1024];
  if (!s.out_dir) {
    snprintf(defdir, sizeof defdir, "out/sweep/%s", s.name);
    s.out_dir = defdir;
  }
  int ok = sw_run(&s);
  ub_runtime_free(s.conv);
  free(s.pts);
  ub_emitters_free(s.em);
  ub_rt_free(s.rt);
  ub_scene_free(s.scene);
  return ok ? 0 : 1;
}
