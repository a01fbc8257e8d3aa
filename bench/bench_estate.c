/* bench_estate — the ESTATE-scale level (ubake-genlevel estate, UberBake Table 1) end to end:
 * generate it at a reduced scale, bake it at draft, load it in the run-time and toggle
 * its sets. Prints figures; asserts nothing.
 *
 *   bench_estate [--scale S] [--full] [--bounces N] [--texel-size M] [--no-extrapolate]
 *                [--param k=v ...] [--ubk FILE.ubk [--repeat N]] [--jobs N] [--records8] [--plain-sums]
 *                [--separate-groups]
 *
 * --ubk FILE skips generating and baking and measures the run-time on a file already baked
 * (e.g. estate_small, or a full ESTATE bake): records, memory, toggles, all-sets update;
 * --repeat N repeats the toggle loop N times (for a profiler).
 * --records8 loads the run-time with its records in 8 bits (UB_RUNTIME_RECORDS_8BIT);
 * --plain-sums without the all-ones sums (UB_RUNTIME_PLAIN_SUMS); --keep-state,
 * --glg-small-walk, --no-base-ahd, --separate-groups: the load flags of those names.
 * Toggles are measured with the other sets on, then with them off (each set on and off
 * again: the off fast path).
 * --jobs N (default: the CPUs, at most 8) also measures toggles and the all-sets update
 * split into N jobs (ub_runtime_update_begin/job/end) on N OpenMP threads, against a
 * memcpy of the same bytes by N threads (each its share) in the same run; 1: not.
 * --scale S (default 0.05) shrinks rooms, room sets and props (the 16-set hall stays);
 * --full is --scale 1 (hours on 2 cores). The reduced level is baked with --bounces
 * (default 2) and --texel-size (default 0.2 m; 0: the level's 0.138 m) so that it ends in
 * minutes on 2 cores; --full bakes with the level's defaults and automatic bounces unless
 * told. --param passes generator parameters on.
 * Figures: per-stage seconds; rays/s of the passes against the ray-tracing ceiling of the
 * same level measured in the same run (bench/bench_util.h); bake seconds without the sets
 * (every stage but "dls") and with them; peak RSS; .ubk bytes; record bytes per set; the
 * overlap histogram of the records; run-time load seconds and resident memory, one set
 * toggled (median / p90 / max over sets, each the best of 3) and the floor of a toggle
 * on one core for the data it moves and encodes (its bytes at the memcpy rate of the run,
 * its texels at the AHD encode's in-cache rate), every set changed at once
 * (GB/s against memcpy of the same bytes, measured alternately). Unless --no-extrapolate
 * (or --full), the full level is generated too and its receivers counted by a
 * --plan-only bake, and the full-scale bake is extrapolated stage by stage (the model is
 * printed with the figures). Needs UB_BUILD (default "build") for ubake-genlevel. */
#include <errno.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "bake/output.h"
#include "bench/bench_util.h"
#include "ubake/ahd.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/glg.h"
#include "ubake/runtime.h"
#include "ubake/scene.h"

/* Log sink: stage lines ("[name] ...") go to stdout; the influence/full split of the DLS
 * stage and the plan's reach bound per set (the share of the texels a set's influence
 * pass may visit), summed over the sets, are kept for the extrapolation. */
typedef struct bake_log {
  int echo;
  double inf_rays, inf_s, full_rays, full_s;
  double plan_sets_s; /* the plan stage's set work ("the sets' reach X s") */
  double reach_sum; /* Σ over sets of the reach bound's share of the texels (0..1) */
  int reach_sets;
} bake_log;

static void log_fn(void *user, ub_log_level level, const char *msg)
{
  bake_log *bl = user;
  if (level == UB_LOG_ERROR || level == UB_LOG_WARNING) {
    fprintf(stderr, "  %s\n", msg);
    return;
  }
  const char *p = strstr(msg, "influence ");
  if (!strncmp(msg, "[dls", 4) && p)
    sscanf(p, "influence %lf M rays %lf s, full %lf M rays %lf s", &bl->inf_rays, &bl->inf_s,
           &bl->full_rays, &bl->full_s);
  const char *sr = strstr(msg, "(the sets' reach ");
  if (!strncmp(msg, "[plan", 5) && sr)
    sscanf(sr, "(the sets' reach %lf s)", &bl->plan_sets_s);
  const char *rb = strstr(msg, "(influence-culled; reach bound ");
  double pct;
  if (!strncmp(msg, "  pass dls ", 11) && rb &&
      sscanf(rb, "(influence-culled; reach bound %lf%%", &pct) == 1) {
    bl->reach_sum += pct / 100.0;
    bl->reach_sets++;
  }
  if (bl->echo && msg[0] == '[')
    printf("  %s\n", msg);
}

static long long file_bytes(const char *path)
{
  struct stat sb;
  return stat(path, &sb) == 0 ? (long long)sb.st_size : -1;
}

/* On-disk bytes of a record, as `ubake info` counts them: index + 12 halves per texel,
 * index + 27 halves per probe. */
static double record_bytes(const ub_bakefile_record *r)
{
  return 28.0 * r->texel_count + 58.0 * r->probe_count;
}

/* One update: plain with one job (ub_runtime_update, as a game without a job system calls
 * it), else split into `jobs` jobs on as many OpenMP threads. */
/* The run-time's memory for the same level without its sets (the paper's "no DLS"
 * column): bf written again with no sets or elements (its lights' set links cut) next to
 * ubk_path, loaded, counted, deleted. bf is left as it was. 0 on failure. */
static int memory_without_sets(ub_bakefile *bf, const char *ubk_path, ub_runtime_memory *out)
{
  char tmp[1200];
  snprintf(tmp, sizeof tmp, "%s.nosets.ubk", ubk_path);
  int32_t *ld = malloc(sizeof(int32_t) * (bf->light_count + 1));
  if (!ld)
    return 0;
  uint32_t nd = bf->dls_count, ne = bf->elem_count;
  for (uint32_t l = 0; l < bf->light_count; l++) {
    ld[l] = bf->lights[l].dls;
    bf->lights[l].dls = -1;
  }
  bf->dls_count = bf->elem_count = 0;
  ub_result r = ub_bakefile_write(bf, tmp, NULL);
  bf->dls_count = nd;
  bf->elem_count = ne;
  for (uint32_t l = 0; l < bf->light_count; l++)
    bf->lights[l].dls = ld[l];
  free(ld);
  ub_runtime *rt = NULL;
  if (r == UB_OK && ub_runtime_load(tmp, NULL, &rt) == UB_OK) {
    ub_runtime_memory_usage(rt, out);
    ub_runtime_free(rt);
  } else {
    r = UB_ERR_IO;
  }
  remove(tmp);
  return r == UB_OK;
}

static void update_n(ub_runtime *rt, int jobs, ub_runtime_update_stats *us)
{
  if (jobs <= 1) {
    ub_runtime_update(rt, us);
    return;
  }
  uint32_t n = 0;
  if (ub_runtime_update_begin(rt, (uint32_t)jobs, &n) != UB_OK) {
    fprintf(stderr, "bench_estate: ub_runtime_update_begin(%d) failed\n", jobs);
    exit(1);
  }
#pragma omp parallel for num_threads(jobs) schedule(static, 1)
  for (int j = 0; j < (int)n; j++)
    ub_runtime_update_job(rt, (uint32_t)j);
  ub_runtime_update_end(rt, us);
}

/* What the toggles cost besides their time: every toggle's part seconds (lightmap, GLG,
 * LLG), the first pass's bytes and receivers. */
typedef struct toggle_sums {
  double seconds[3], bytes, texels, probes, llg;
  /* Optional (NULL: not kept), per set and state as tog: the first pass's bytes moved and
   * texels AHD-encoded (re-encoded, less those copied from the kept or base state). */
  double *set_bytes, *set_encoded;
} toggle_sums;

/* Each set off, then on again (the others as they are: on), `passes` times; tog[2d + 0/1]
 * the best milliseconds of set d's off/on update, once[2d + 0/1] (may be NULL) those of
 * the first pass (one measurement each: what a game's toggle sees, the best of several
 * is the luckiest). sums may be NULL. others_off: every set off first, each set then on
 * and off again (the same slots), every set back on at the end. */
static void toggle_times(ub_runtime *rt, int jobs, int passes, double *tog, double *once,
                         toggle_sums *sums, int others_off)
{
  const uint32_t nd = ub_runtime_dls_count(rt);
  const float one[3] = {1, 1, 1}, zero[3] = {0, 0, 0};
  ub_runtime_update_stats us;
  for (uint32_t i = 0; i < 2 * nd; i++)
    tog[i] = 1e30;
  if (others_off) {
    for (uint32_t d = 0; d < nd; d++)
      ub_runtime_set_dls(rt, d, zero);
    update_n(rt, jobs, &us);
  }
  for (int pass = 0; pass < passes; pass++)
    for (uint32_t d = 0; d < nd; d++)
      for (int ph = 0; ph < 2; ph++) {
        const int on = others_off ? !ph : ph;
        ub_runtime_set_dls(rt, d, on ? one : zero);
        double t = ub_bench_now();
        update_n(rt, jobs, &us);
        t = (ub_bench_now() - t) * 1e3;
        if (t < tog[2 * d + on])
          tog[2 * d + on] = t;
        if (once && pass == 0)
          once[2 * d + on] = t;
        if (!sums)
          continue;
        sums->seconds[0] += us.seconds_lightmap;
        sums->seconds[1] += us.seconds_glg;
        sums->seconds[2] += us.seconds_llg;
        if (pass == 0) {
          sums->bytes += (double)(us.bytes_read + us.bytes_written);
          sums->texels += (double)us.texels_written;
          sums->probes += (double)us.probes_written;
          sums->llg += (double)us.llg_probes_written;
          if (sums->set_bytes) {
            sums->set_bytes[2 * d + on] = (double)(us.bytes_read + us.bytes_written);
            sums->set_encoded[2 * d + on] =
                (double)(us.texels_reencoded - us.texels_kept - us.texels_base);
          }
        }
      }
  if (others_off) {
    for (uint32_t d = 0; d < nd; d++)
      ub_runtime_set_dls(rt, d, one);
    update_n(rt, jobs, &us);
  }
}

/* Nanoseconds a texel of the run-time's AHD encode in cache (ub_ahd_encode_iz_packed_n on
 * 512 texels from ub_bench_make_texels, best of 7 rounds of 200 calls). */
static double encode_ns_in_cache(void)
{
  enum { N = 512 };
  float *sh = malloc(sizeof(float) * 12 * N), *nrm = malloc(sizeof(float) * 3 * N);
  ub_ahd_packed *out = malloc(sizeof *out * N);
  if (!sh || !nrm || !out) {
    free(sh);
    free(nrm);
    free(out);
    return 0.0;
  }
  ub_bench_make_texels(N, sh, nrm);
  double best = 1e30;
  for (int r = 0; r < 7; r++) {
    double t = ub_bench_now();
    for (int k = 0; k < 200; k++)
      ub_ahd_encode_iz_packed_n(sh, nrm, 1.0f, out, N);
    t = ub_bench_now() - t;
    best = t < best ? t : best;
  }
  free(sh);
  free(nrm);
  free(out);
  return best * 1e9 / (200.0 * N);
}

/* By class: the hall's sets reach the big shared space (and each other: up to 16
 * overlaps), a room's set its room; at full scale rooms are most of the sets. cls[1]
 * gets the hall sets' toggles of tog, cls[0] the rooms' (each 2 × sets entries). */
static int set_class(const ub_runtime *rt, uint32_t set)
{
  return !strncmp(ub_runtime_dls_name(rt, set), "hall_", 5);
}

static void toggle_classes(const ub_runtime *rt, const double *tog, double *cls[2],
                           uint32_t ncls[2])
{
  ncls[0] = ncls[1] = 0;
  for (uint32_t i = 0; i < 2 * ub_runtime_dls_count(rt); i++) {
    int hall = set_class(rt, i / 2);
    cls[hall][ncls[hall]++] = tog[i];
  }
}

/* The medians of tog (toggle_times) by class (0 rooms, 1 halls) and direction (0 off,
 * 1 back on): med[class][dir], 0 where a class has none. */
static void toggle_directions(const ub_runtime *rt, const double *tog, double med[2][2])
{
  const uint32_t nd = ub_runtime_dls_count(rt);
  double *v = malloc(sizeof(double) * (nd + 1));
  for (int c = 0; c < 2; c++)
    for (int ph = 0; ph < 2; ph++) {
      uint32_t n = 0;
      for (uint32_t d = 0; v && d < nd; d++)
        if (set_class(rt, d) == c)
          v[n++] = tog[2 * d + ph];
      med[c][ph] = n ? ub_bench_percentile(v, n, 0.5) : 0.0;
    }
  free(v);
}

/* Every set changed at once, 7 times, alternating with a memcpy of the same bytes by
 * `jobs` threads (each its share; *ca, *cb: *cn bytes each, made at the first run when
 * NULL): the best seconds of each and the bytes an update moves. */
static void all_sets_times(ub_runtime *rt, int jobs, char **ca, char **cb, size_t *cn,
                           double *tall, double *tcpy, double *bytes)
{
  const uint32_t nd = ub_runtime_dls_count(rt);
  ub_runtime_update_stats us;
  *tall = *tcpy = 1e30;
  for (int run = 0; run < 7; run++) {
    /* never all 1: the all-ones sums would give every group's rows from one read (the
     * worst case is wanted here, every set changed to weights that are not 1) */
    float w = run & 1 ? 0.75f : 0.5f;
    const float rgb[3] = {w, w, w};
    for (uint32_t d = 0; d < nd; d++)
      ub_runtime_set_dls(rt, d, rgb);
    double t = ub_bench_now();
    update_n(rt, jobs, &us);
    t = ub_bench_now() - t;
    *tall = t < *tall ? t : *tall;
    *bytes = (double)(us.bytes_read + us.bytes_written); /* the same every run */
    if (!*ca) {
      *cn = (size_t)(*bytes / 2.0) + 1;
      *ca = malloc(*cn);
      *cb = malloc(*cn);
      memset(*ca, 1, *cn);
      memset(*cb, 2, *cn);
    }
    char *dst = run & 1 ? *ca : *cb;
    const char *src = run & 1 ? *cb : *ca;
    t = ub_bench_now();
    if (jobs <= 1) {
      memcpy(dst, src, *cn);
    } else {
#pragma omp parallel for num_threads(jobs) schedule(static, 1)
      for (int j = 0; j < jobs; j++) {
        size_t a = *cn * (size_t)j / (size_t)jobs, b = *cn * (size_t)(j + 1) / (size_t)jobs;
        memcpy(dst + a, src + a, b - a);
      }
    }
    t = ub_bench_now() - t;
    *tcpy = t < *tcpy ? t : *tcpy;
  }
}

/* Toggles (best of 3 per set and state) and the all-sets update with `jobs` jobs, the
 * latter against a memcpy by `jobs` threads (ca, cb: cn bytes each, from the one-thread
 * figure). */
static void bench_jobs(ub_runtime *rt, int jobs, char *ca, char *cb, size_t cn)
{
  const uint32_t nd = ub_runtime_dls_count(rt);
  const float one[3] = {1, 1, 1};
  ub_runtime_update_stats us;
  for (uint32_t d = 0; d < nd; d++)
    ub_runtime_set_dls(rt, d, one);
  update_n(rt, jobs, &us);
  double *tog = malloc(sizeof(double) * (2 * nd + 1)), *cls[2];
  cls[0] = malloc(sizeof(double) * (2 * nd + 1));
  cls[1] = malloc(sizeof(double) * (2 * nd + 1));
  uint32_t ncls[2];
  double *one_t = malloc(sizeof(double) * (2 * nd + 1)), *ocls[2];
  ocls[0] = malloc(sizeof(double) * (2 * nd + 1));
  ocls[1] = malloc(sizeof(double) * (2 * nd + 1));
  toggle_times(rt, jobs, 3, tog, one_t, NULL, 0);
  toggle_classes(rt, one_t, ocls, ncls);
  const double oroom = ncls[0] ? ub_bench_percentile(ocls[0], ncls[0], 0.5) : 0.0;
  toggle_classes(rt, tog, cls, ncls);
  double tall, tcpy, bytes = 0.0;
  all_sets_times(rt, jobs, &ca, &cb, &cn, &tall, &tcpy, &bytes);
  double med[2][2];
  toggle_directions(rt, tog, med);
  printf("  with %d jobs on %d threads (ub_runtime_update_begin/job/end): one set toggled median "
         "%.3f ms (room sets %.3f: off %.3f, back on %.3f; one measurement each %.3f; hall sets "
         "%.3f) [0.1 ms]; all %u sets changed: %.2f ms, %.2f GB/s; memcpy by %d threads %.2f "
         "GB/s; ratio %.0f%%\n",
         jobs, jobs, ub_bench_percentile(tog, 2 * nd, 0.5),
         ncls[0] ? ub_bench_percentile(cls[0], ncls[0], 0.5) : 0.0, med[0][0], med[0][1], oroom,
         ncls[1] ? ub_bench_percentile(cls[1], ncls[1], 0.5) : 0.0, nd, tall * 1e3,
         bytes / tall / 1e9, jobs, 2.0 * (double)cn / tcpy / 1e9,
         100.0 * (bytes / tall) / (2.0 * (double)cn / tcpy));
  free(tog);
  free(cls[0]);
  free(cls[1]);
  free(one_t);
  free(ocls[0]);
  free(ocls[1]);
}

int main(int argc, char **argv)
{
  const char *build = getenv("UB_BUILD") ? getenv("UB_BUILD") : "build";
  double scale = 0.05, texel = 0.2;
  int bounces = 2, extrapolate = 1, full = 0, repeat = 1;
  unsigned load_flags = 0;
  int jobs = omp_get_num_procs() < 8 ? omp_get_num_procs() : 8;
  const char *ubk_in = NULL;
  char **params = malloc(sizeof(char *) * (size_t)(argc + 1));
  int nparams = 0;
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
      printf("usage: bench_estate [--scale S] [--full] [--bounces N] [--texel-size M]\n"
             "                    [--no-extrapolate] [--param k=v ...]\n"
             "                    [--ubk FILE.ubk [--repeat N]] [--jobs N] [--records8] [--plain-sums]\n"
             "                    [--keep-state] [--glg-small-walk] [--no-base-ahd] [--separate-groups]\n"
             "Generates the ESTATE-scale level (ubake-genlevel estate) at scale S (default 0.05;\n"
             "--full: 1), bakes it at draft (reduced: --bounces 2, --texel-size 0.2 by default;\n"
             "full: the level's settings), loads it in the run-time and toggles its sets;\n"
             "extrapolates the bake to full scale from a --plan-only of the full level.\n"
             "--ubk: the run-time figures of a file already baked; --jobs N: toggles and the\n"
             "all-sets update also split into N jobs on N threads (default: the CPUs, <= 8).\n"
             "--records8: the run-time keeps its records in 8 bits (UB_RUNTIME_RECORDS_8BIT);\n"
             "--plain-sums: without the all-ones sums (UB_RUNTIME_PLAIN_SUMS);\n"
             "--keep-state: the load state kept (UB_RUNTIME_KEEP_STATE);\n"
             "--glg-small-walk: the GLG's small walk (UB_RUNTIME_GLG_SMALL_WALK);\n"
             "--no-base-ahd: no AHD of the base state kept (UB_RUNTIME_NO_BASE_AHD);\n"
             "--separate-groups: each combination a group of its own (UB_RUNTIME_SEPARATE_GROUPS).\n"
             "UB_BUILD: the build folder (default build).\n");
      return 0;
    } else if (!strcmp(argv[i], "--scale") && i + 1 < argc) {
      char *end;
      errno = 0;
      scale = strtod(argv[++i], &end);
      if (*end || errno || !(scale > 0 && scale <= 1)) {
        fprintf(stderr, "bench_estate: --scale wants a number in (0, 1], got %s\n", argv[i]);
        return 1;
      }
    } else if (!strcmp(argv[i], "--full")) {
      full = 1;
    } else if (!strcmp(argv[i], "--texel-size") && i + 1 < argc) {
      texel = atof(argv[++i]);
    } else if (!strcmp(argv[i], "--bounces") && i + 1 < argc) {
      bounces = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--ubk") && i + 1 < argc) {
      ubk_in = argv[++i];
    } else if (!strcmp(argv[i], "--repeat") && i + 1 < argc) {
      repeat = atoi(argv[++i]);
      repeat = repeat < 1 ? 1 : repeat;
    } else if (!strcmp(argv[i], "--jobs") && i + 1 < argc) {
      jobs = atoi(argv[++i]);
      if (jobs < 1 || jobs > 64) {
        fprintf(stderr, "bench_estate: --jobs wants 1..64, got %s\n", argv[i]);
        return 2;
      }
    } else if (!strcmp(argv[i], "--records8")) {
      load_flags |= UB_RUNTIME_RECORDS_8BIT;
    } else if (!strcmp(argv[i], "--plain-sums")) {
      load_flags |= UB_RUNTIME_PLAIN_SUMS;
    } else if (!strcmp(argv[i], "--keep-state")) {
      load_flags |= UB_RUNTIME_KEEP_STATE;
    } else if (!strcmp(argv[i], "--glg-small-walk")) {
      load_flags |= UB_RUNTIME_GLG_SMALL_WALK;
    } else if (!strcmp(argv[i], "--no-base-ahd")) {
      load_flags |= UB_RUNTIME_NO_BASE_AHD;
    } else if (!strcmp(argv[i], "--separate-groups")) {
      load_flags |= UB_RUNTIME_SEPARATE_GROUPS;
    } else if (!strcmp(argv[i], "--no-extrapolate")) {
      extrapolate = 0;
    } else if (!strcmp(argv[i], "--param") && i + 1 < argc) {
      params[nparams++] = argv[++i];
    } else {
      fprintf(stderr, "bench_estate: unknown argument %s (try --help)\n", argv[i]);
      return 1;
    }
  }
  if (full) {
    scale = 1.0;
    texel = 0.0;
    bounces = -1;
  }
  for (int i = 1; i < argc; i++) /* explicit settings win over --full */
    if (!strcmp(argv[i], "--bounces") && i + 1 < argc)
      bounces = atoi(argv[i + 1]);
    else if (!strcmp(argv[i], "--texel-size") && i + 1 < argc)
      texel = atof(argv[i + 1]);
  if (scale >= 1.0)
    extrapolate = 0;
  setvbuf(stdout, NULL, _IOLBF, 0); /* progress shows when piped to a file */
  int threads = omp_get_max_threads();
  char dir[1024], name[64], level[1200], out[1100];
  snprintf(dir, sizeof dir, "%s/bench_out/estate", build);
  snprintf(name, sizeof name, "estate_s%g", scale);
  snprintf(level, sizeof level, "%s/%s.gltf", dir, name);
  snprintf(out, sizeof out, "%s/bake", dir);
  double t0 = ub_bench_now();
  ub_bake_stats st;
  memset(&st, 0, sizeof st);
  bake_log bl = {1, 0, 0, 0, 0, 0, 0, 0};
  ub_bake_options o;
  ub_bake_options_default(&o);
  long long ubk = -1;
  if (ubk_in) {
    printf("bench_estate: run-time only on %s, load average %.1f\n", ubk_in,
           ub_bench_load_average());
    snprintf(st.ubk_path, sizeof st.ubk_path, "%s", ubk_in);
    ubk = file_bytes(ubk_in);
    extrapolate = 0;
  } else {
    printf("bench_estate: scale %g, %d threads, load average %.1f\n", scale, threads,
           ub_bench_load_average());
    int sets = ub_bench_genlevel(build, "estate", dir, name, scale, (const char *const *)params, nparams, 1);
    if (sets < 0) {
      fprintf(stderr, "bench_estate: generating %s failed\n", level);
      return 1;
    }
    printf("generate: %.2f s -> %s\n", ub_bench_now() - t0, level);

    /* Ceiling on this level. */
    double hit = 0, shadow = 0;
    {
      ub_scene *s = NULL;
      ub_rt *rt = NULL;
      if (ub_scene_load(level, NULL, &s) != UB_OK || ub_rt_create(s, NULL, NULL, &rt) != UB_OK) {
        fprintf(stderr, "bench_estate: cannot load %s\n", level);
        return 1;
      }
      ub_bench_ceiling(s, rt, &hit, &shadow);
      printf("ceiling (random incoherent rays, %u triangles, %d threads): %.2f M closest-hit/s, "
             "%.2f M shadow/s\n", s->triangle_count, threads, hit * 1e-6, shadow * 1e-6);
      ub_rt_free(rt);
      ub_scene_free(s);
    }

    /* Bake at draft. */
    ub_log log = {log_fn, &bl};
    o.quality = UB_QUALITY_DRAFT;
    o.bounces = bounces;
    o.texel_size = (float)texel;
    o.out_dir = out;
    printf("bake (draft, %s bounces, texel size %s):\n", bounces >= 0 ? "fixed" : "automatic",
           texel > 0 ? "overridden" : "the level's");
    if (ub_bake_level(level, &o, &log, &st) != UB_OK) {
      fprintf(stderr, "bench_estate: bake of %s failed\n", level);
      return 1;
    }
    double dls_s = ub_bench_stage_seconds(&st, "dls"), base_total = st.total_seconds - dls_s;
    double ratio = ub_bench_ceiling_ratio((double)st.rays_gather, (double)st.rays_shadow,
                                          st.gather_seconds, hit, shadow);
    ubk = file_bytes(st.ubk_path);
    printf("bake: %.1f s total; without the sets %.1f s, the %u sets' pass %.1f s (influence %.1f "
           "s / %.0f M rays, full %.1f s / %.0f M rays): %.2fx the bake without sets (target <= "
           "1.5x; paper 3.3x)\n",
           st.total_seconds, base_total, st.dls_sets, dls_s, bl.inf_s, bl.inf_rays, bl.full_s,
           bl.full_rays, st.total_seconds / (base_total + 1e-30));
    /* The plan traces the sets' reach bounds and their lights' reach for them: set work in
     * a stage before the sets' own. */
    printf("  with the plan's %.1f s of set work counted with the sets: %.2fx\n", bl.plan_sets_s,
           st.total_seconds / (base_total - bl.plan_sets_s + 1e-30));
    printf("  base pass: %u texels, %u GLG probes, %u bounces, %.1f M gather + %.1f M shadow rays "
           "in %.1f s = %.2f M rays/s, %.2f of the ceiling for that mix\n",
           st.texels, st.glg_probes, st.bounces, st.rays_gather * 1e-6, st.rays_shadow * 1e-6,
           st.gather_seconds, (st.rays_gather + st.rays_shadow) / (st.gather_seconds + 1e-30) * 1e-6,
           ratio);
    if (bl.inf_s > 0 && bl.full_s > 0)
      printf("  sets' pass: influence %.2f M rays/s, full %.2f M rays/s (ceiling %.2f M closest-hit/s)\n",
             bl.inf_rays / bl.inf_s, bl.full_rays / bl.full_s, hit * 1e-6);
    printf("  peak RSS %.0f MiB, %s: %.1f MiB\n", st.peak_rss_kb / 1024.0, st.ubk_path, ubk / 1048576.0);


  }
  /* Records. */
  ub_bakefile *bf = NULL;
  if (ub_bakefile_read(st.ubk_path, NULL, &bf) != UB_OK) {
    fprintf(stderr, "bench_estate: cannot read %s\n", st.ubk_path);
    return 1;
  }
  size_t pixels = ub_bakefile_atlas_pixels(bf);
  double *rb = malloc(sizeof(double) * (bf->dls_count + 1));
  double rec_sum = 0.0, hall_sum = 0.0, room_sum = 0.0;
  uint32_t nhall = 0;
  uint16_t *over = calloc(pixels + 1, sizeof *over);
  for (uint32_t d = 0; d < bf->dls_count; d++) {
    const ub_bakefile_record *r = &bf->dls[d];
    rb[d] = record_bytes(r);
    rec_sum += rb[d];
    if (!strncmp(r->name, "hall_", 5)) {
      hall_sum += rb[d];
      nhall++;
    } else {
      room_sum += rb[d];
    }
    for (uint32_t i = 0; i < r->texel_count; i++)
      over[r->texel_index[i]]++;
  }
  uint64_t hist[18] = {0}, covered = 0;
  uint32_t max_over = 0;
  size_t off = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    size_t n = (size_t)bf->atlases[a].width * bf->atlases[a].height;
    for (size_t px = 0; px < n; px++)
      if (bf->atlases[a].coverage[px] == 1) {
        uint32_t k = over[off + px];
        hist[k > 17 ? 17 : k]++;
        max_over = k > max_over ? k : max_over;
        covered++;
      }
    off += n;
  }
  printf("records: %u sets, %.1f MB on disk (%.1f%% of the .ubk); per set min %.0f kB, median "
         "%.0f kB, p90 %.0f kB, max %.0f kB; %zu atlas pixels (%llu covered)\n",
         bf->dls_count, rec_sum / 1048576.0, 100.0 * rec_sum / (ubk > 0 ? ubk : 1),
         ub_bench_percentile(rb, bf->dls_count, 0.0) / 1024.0,
         ub_bench_percentile(rb, bf->dls_count, 0.5) / 1024.0,
         ub_bench_percentile(rb, bf->dls_count, 0.9) / 1024.0,
         ub_bench_percentile(rb, bf->dls_count, 1.0) / 1024.0, pixels,
         (unsigned long long)covered);
  printf("  overlap of covered texels (sets: %% of texels):");
  for (int k = 0; k < 18; k++)
    if (hist[k])
      printf(" %d%s:%.2f", k, k == 17 ? "+" : "", 100.0 * hist[k] / (covered ? covered : 1));
  printf("; max %u (paper: up to 16)\n", max_over);
  free(over);

  /* Run-time. */
  int hwm_reset = ub_peak_rss_reset(); /* bake/output.h: VmHWM from here on */
  long rss0 = ub_bench_rss_kb();
  double tl = ub_bench_now();
  ub_runtime *rt = NULL;
  if (ub_runtime_load_ex(st.ubk_path, NULL, load_flags, &rt) != UB_OK) {
    fprintf(stderr, "bench_estate: run-time cannot load %s\n", st.ubk_path);
    return 1;
  }
  tl = ub_bench_now() - tl;
  long rss1 = ub_bench_rss_kb(), hwm1 = ub_proc_status_kb("VmHWM:");
  uint32_t nd = ub_runtime_dls_count(rt);
  ub_runtime_update(rt, NULL);
  enum { PASSES = 3 };
  double *tog = malloc(sizeof(double) * (2 * nd + 1));
  toggle_sums ts = {{0, 0, 0}, 0, 0, 0, 0, NULL, NULL};
  ts.set_bytes = malloc(sizeof(double) * (2 * nd + 1));
  ts.set_encoded = malloc(sizeof(double) * (2 * nd + 1));
  if (!ts.set_bytes || !ts.set_encoded) {
    free(ts.set_bytes);
    free(ts.set_encoded);
    ts.set_bytes = ts.set_encoded = NULL;
  }
  double *tog1 = malloc(sizeof(double) * (2 * nd + 1));
  toggle_times(rt, 1, PASSES * repeat, tog, tog1, &ts, 0);
  double dmed[2][2]; /* before the percentiles below sort tog */
  toggle_directions(rt, tog, dmed);
  double omed[2][2]; /* the same with the other sets off */
  {
    double *to = malloc(sizeof(double) * (2 * nd + 1));
    toggle_times(rt, 1, PASSES * repeat, to, NULL, NULL, 1);
    toggle_directions(rt, to, omed);
    free(to);
  }
  double *tog_c[2];
  uint32_t ntog_c[2];
  tog_c[0] = malloc(sizeof(double) * (2 * nd + 1));
  tog_c[1] = malloc(sizeof(double) * (2 * nd + 1));
  toggle_classes(rt, tog, tog_c, ntog_c);
  double tmed = ub_bench_percentile(tog, 2 * nd, 0.5), tp90 = ub_bench_percentile(tog, 2 * nd, 0.9),
         tmax = ub_bench_percentile(tog, 2 * nd, 1.0);
  /* Every set changed at once, alternating with memcpy of the same bytes. */
  double tall, tcpy, all_bytes = 0.0;
  char *ca = NULL, *cb = NULL;
  size_t cn = 0;
  all_sets_times(rt, 1, &ca, &cb, &cn, &tall, &tcpy, &all_bytes);
  double gbs = all_bytes / tall / 1e9, cgbs = 2.0 * (double)cn / tcpy / 1e9;
  /* The peak: what the load needs above what the process held before it (this bench
   * holds the bake file it read for the figures above meanwhile). */
  printf("run-time%s%s: load %.2f s, resident +%.1f MB (base + %u sets' records %.1f MB on "
         "disk), %s +%.1f MB\n",
         load_flags & UB_RUNTIME_RECORDS_8BIT ? " (records in 8 bits)" : "",
         load_flags & UB_RUNTIME_SEPARATE_GROUPS ? " (separate groups)" : "", tl,
         (rss1 - rss0) / 1024.0, nd, rec_sum / 1048576.0,
         hwm_reset ? "peak during the load" : "peak since the start (no reset)",
         (hwm1 - rss0) / 1024.0);
  /* Counted bytes: the RSS delta above also holds freed pages malloc keeps. */
  ub_runtime_memory mu;
  ub_runtime_memory_usage(rt, &mu);
  {
    const double M = 1048576.0;
    printf("  run-time memory (counted): %.1f MiB = geometry %.1f + lightmap %.1f + GLG %.1f + "
           "LLG %.1f + records %.1f + blend engines %.1f\n", mu.total / M, mu.geometry / M,
           mu.lightmap / M, mu.glg / M, mu.llg / M, mu.records / M, mu.blend / M);
    ub_runtime_memory m0;
    if (memory_without_sets(bf, st.ubk_path, &m0))
      printf("  run-time memory without the sets (the same file written without them): %.1f MiB "
             "= geometry %.1f + lightmap %.1f + GLG %.1f + LLG %.1f; with them %.1f MiB, "
             "%.2fx (target <= 77 MB with the sets; paper 28 -> 77 MB)\n", m0.total / M,
             m0.geometry / M, m0.lightmap / M, m0.glg / M, m0.llg / M, mu.total / M,
             (double)mu.total / (double)(m0.total ? m0.total : 1));
    else
      printf("  run-time memory without the sets: not measured (cannot write or load a copy "
             "next to %s)\n", st.ubk_path);
  }
  printf("  one set toggled (others on), best of %d: median %.3f ms, p90 %.3f ms, max %.3f ms; "
         "mean %.2f MB moved (target <= 0.1 ms)\n",
         PASSES, tmed, tp90, tmax, ts.bytes / (2.0 * nd) / 1e6);
  if (ntog_c[0] && ntog_c[1])
    printf("  by class: room sets (%u toggles) median %.3f ms, p90 %.3f; hall sets (%u) median "
           "%.3f ms, p90 %.3f\n", ntog_c[0], ub_bench_percentile(tog_c[0], ntog_c[0], 0.5),
           ub_bench_percentile(tog_c[0], ntog_c[0], 0.9), ntog_c[1],
           ub_bench_percentile(tog_c[1], ntog_c[1], 0.5),
           ub_bench_percentile(tog_c[1], ntog_c[1], 0.9));
  printf("  by direction: room sets off %.3f ms, back on %.3f ms; hall sets off %.3f ms, back "
         "on %.3f ms (medians)%s\n", dmed[0][0], dmed[0][1], dmed[1][0], dmed[1][1],
         load_flags & UB_RUNTIME_KEEP_STATE
             ? "; the load state kept (UB_RUNTIME_KEEP_STATE): back on copies kept texels"
             : "");
  if (ts.set_bytes) {
    /* What one core cannot go below for a toggle whose data comes from memory: its bytes
     * at the memcpy rate of this run (measured with the all-sets update) and its encoded
     * texels at the encode's in-cache rate. The two overlap at best (the larger), not at
     * all the sum. A set toggled again soon may find part of its data in the cache. */
    double ens = encode_ns_in_cache(), fl[2][2][2], ms[2][2];
    for (int c = 0; c < 2; c++)
      for (int ph = 0; ph < 2; ph++) {
        double *v[2], *w = malloc(sizeof(double) * (nd + 1));
        v[0] = malloc(sizeof(double) * (nd + 1));
        v[1] = malloc(sizeof(double) * (nd + 1));
        uint32_t n = 0;
        for (uint32_t d = 0; v[0] && v[1] && w && d < nd; d++)
          if (set_class(rt, d) == c) {
            double tb = ts.set_bytes[2 * d + ph] / (cgbs * 1e9) * 1e3;
            double te = ts.set_encoded[2 * d + ph] * ens * 1e-6;
            v[0][n] = tb > te ? tb : te;
            v[1][n] = tb + te;
            w[n++] = tb;
          }
        for (int k = 0; k < 2; k++)
          fl[c][ph][k] = n ? ub_bench_percentile(v[k], n, 0.5) : 0.0;
        ms[c][ph] = n ? ub_bench_percentile(w, n, 0.5) : 0.0;
        free(v[0]);
        free(v[1]);
        free(w);
      }
    printf("  floor of a toggle on one core (its bytes at this run's memcpy rate, %.2f GB/s, and "
           "its encoded texels at %.2f ns each, the encode in cache; overlapped / one after the "
           "other, medians): room sets off %.3f / %.3f ms (measured %.3f), on %.3f / %.3f "
           "(%.3f); hall sets off %.3f / %.3f (%.3f), on %.3f / %.3f (%.3f); the bytes alone: "
           "room %.3f / %.3f, hall %.3f / %.3f ms (target 0.1 ms)\n", cgbs, ens, fl[0][0][0],
           fl[0][0][1], dmed[0][0], fl[0][1][0], fl[0][1][1], dmed[0][1], fl[1][0][0],
           fl[1][0][1], dmed[1][0], fl[1][1][0], fl[1][1][1], dmed[1][1], ms[0][0], ms[0][1],
           ms[1][0], ms[1][1]);
  }
  printf("  with the other sets off: room sets on %.3f ms, off again %.3f ms; hall sets on %.3f "
         "ms, off again %.3f ms (medians, best of %d)%s\n", omed[0][1], omed[0][0], omed[1][1],
         omed[1][0], PASSES * repeat,
         load_flags & UB_RUNTIME_NO_BASE_AHD
             ? "; no base AHD kept (UB_RUNTIME_NO_BASE_AHD): off re-encodes the base"
             : "; off copies the base's AHD where no other set lights a texel");
  {
    /* one measurement per toggle (the first pass): the spread a game sees */
    toggle_classes(rt, tog1, tog_c, ntog_c);
    if (ntog_c[0] && ntog_c[1])
      printf("  one measurement per toggle (not the best of %d): room sets median %.3f ms, p90 "
             "%.3f; hall sets median %.3f ms\n", PASSES * repeat,
             ub_bench_percentile(tog_c[0], ntog_c[0], 0.5),
             ub_bench_percentile(tog_c[0], ntog_c[0], 0.9),
             ub_bench_percentile(tog_c[1], ntog_c[1], 0.5));
    free(tog1);
  }
  printf("  per toggle (mean): %.0f texels re-blended and re-encoded, %.0f GLG probes marked "
         "(blended and windowed when a query reads them), %.0f LLG probes\n", ts.texels / (2.0 * nd), ts.probes / (2.0 * nd),
         ts.llg / (2.0 * nd));
  {
    double sum = ts.seconds[0] + ts.seconds[1] + ts.seconds[2] + 1e-30;
    printf("  toggle time by part (all toggles): lightmap blend + AHD %.0f%%, GLG "
           "marking %.0f%%, LLG %.0f%%; mean %.3f / %.3f / %.3f ms\n", 100.0 * ts.seconds[0] / sum,
           100.0 * ts.seconds[1] / sum, 100.0 * ts.seconds[2] / sum,
           ts.seconds[0] * 1e3 / (2.0 * nd * PASSES * repeat), ts.seconds[1] * 1e3 / (2.0 * nd * PASSES * repeat),
           ts.seconds[2] * 1e3 / (2.0 * nd * PASSES * repeat));
  }
  {
    /* What a game does after a toggle to re-upload: list the changed texels with their
     * packed AHD (ub_runtime_changed_texels), every set off and on once. */
    ub_runtime_memory_usage(rt, &mu);
    size_t cap = 0;
    ub_runtime_texel_change *chg = NULL;
    double tsum = 0.0, nsum = 0.0;
    const float zero3[3] = {0, 0, 0}, one3[3] = {1, 1, 1};
    for (uint32_t d = 0; d < nd; d++)
      for (int on = 0; on < 2; on++) {
        ub_runtime_set_dls(rt, d, on ? one3 : zero3);
        ub_runtime_update(rt, NULL);
        uint64_t n = ub_runtime_changed_texel_count(rt);
        if (n > cap) {
          free(chg);
          cap = (size_t)n;
          chg = malloc(cap * sizeof *chg);
          if (!chg)
            return 1;
        }
        double t0 = ub_bench_now();
        size_t got = ub_runtime_changed_texels(rt, 0, (size_t)n, chg);
        tsum += ub_bench_now() - t0;
        nsum += (double)got;
      }
    printf("  changed texels for upload (ub_runtime_changed_texels after each toggle, every set "
           "off and on): mean %.0f texels, %.3f ms a toggle (%.1f ns a texel, %zu B each)\n",
           nsum / (2.0 * nd), tsum * 1e3 / (2.0 * nd), tsum * 1e9 / (nsum > 0 ? nsum : 1),
           sizeof *chg);
    free(chg);
  }
  if (ub_runtime_glg(rt)) {
    /* The GLG work an update leaves to queries: the probes it marked are blended and
     * windowed by the first query that reads each. Here every marked probe is read at
     * once (ub_glg_refresh) after each toggle, the worst case: a game pays for the probes
     * its objects read only. The refresh's scan of every probe's word is timed apart. */
    const ub_glg *g = ub_runtime_glg(rt);
    const float zero3[3] = {0, 0, 0}, one3[3] = {1, 1, 1};
    double tref = 0.0, tscan = 0.0, nref = 0.0;
    ub_glg_refresh(g);
    for (uint32_t d = 0; d < nd; d++)
      for (int on = 0; on < 2; on++) {
        ub_runtime_set_dls(rt, d, on ? one3 : zero3);
        ub_runtime_update(rt, NULL);
        double t0 = ub_bench_now();
        nref += ub_glg_refresh(g);
        double t1 = ub_bench_now();
        ub_glg_refresh(g);
        tscan += ub_bench_now() - t1;
        tref += t1 - t0;
      }
    double work = tref - tscan > 0.0 ? tref - tscan : 0.0;
    printf("  GLG probes left to queries (the first query reading a marked probe blends and "
           "windows it): mean %.0f a toggle; reading every one of them after each toggle "
           "(ub_glg_refresh, its scan of all %u probes, %.3f ms, taken off): %.3f ms a toggle, "
           "%.0f ns a probe\n", nref / (2.0 * nd), g->probe_count, tscan * 1e3 / (2.0 * nd),
           work * 1e3 / (2.0 * nd), work * 1e9 / (nref > 0 ? nref : 1));
  }
  /* (since f0a8be6 the GLG probes' rows are not moved by the update: queries blend the
   * probes they read; the bytes and the time leave them out alike) */
  printf("  all %u sets changed: %.2f ms, %.1f MB moved, %.2f GB/s; memcpy %.2f GB/s; ratio %.0f%% "
         "(target >= 50%%; paper 1.47 ms on a PS4 GPU)\n",
         nd, tall * 1e3, all_bytes / 1e6, gbs, cgbs, 100.0 * gbs / cgbs);
  if (jobs > 1)
    bench_jobs(rt, jobs, ca, cb, cn);
  free(ca);
  free(cb);
  free(tog);
  free(ts.set_bytes);
  free(ts.set_encoded);
  ub_runtime_free(rt);

  /* Extrapolation to full scale. */
  if (extrapolate) {
    char fname[64], flevel[1200];
    snprintf(fname, sizeof fname, "estate_full");
    snprintf(flevel, sizeof flevel, "%s/%s.gltf", dir, fname);
    printf("full level (for the extrapolation):\n");
    int fsets = ub_bench_genlevel(build, "estate", dir, fname, 1.0, (const char *const *)params, nparams, 1);
    ub_bake_options fo = o;
    fo.plan_only = 1;
    fo.texel_size = 0.0f; /* the full level at its own texel size */
    ub_bake_stats fs;
    bake_log fbl = {0, 0, 0, 0, 0, 0, 0, 0};
    ub_log flog = {log_fn, &fbl};
    if (fsets < 0 || ub_bake_level(flevel, &fo, &flog, &fs) != UB_OK) {
      fprintf(stderr, "bench_estate: plan of the full level failed; no extrapolation\n");
    } else {
      double R = (double)st.texels + st.glg_probes, Rf = (double)fs.texels + fs.glg_probes;
      double kr = Rf / R;
      /* Stages up to the plan: measured on the full level. Base pass, LLG self term, leak
       * and write: proportional to receivers. Influence: below. Full set passes: proportional to what the sets keep (records): the hall's sets
       * as measured, the room sets at their mean record times the full count. */
      double pre = 0.0, post = 0.0;
      static const char *const before[] = {"load", "rays", "receivers", "probes", "llg", "plan"};
      static const char *const after[] = {"base pass", "llg self", "leak", "write"};
      for (size_t k = 0; k < sizeof before / sizeof *before; k++)
        pre += ub_bench_stage_seconds(&fs, before[k]);
      for (size_t k = 0; k < sizeof after / sizeof *after; k++)
        post += ub_bench_stage_seconds(&st, after[k]) * kr;
      uint32_t nroom = bf->dls_count - nhall, nroom_f = (uint32_t)(fsets - (int)nhall);
      double rec_f = hall_sum + (nroom ? room_sum / nroom : 0.0) * nroom_f;
      /* Influence passes visit the receivers inside each set's reach bound (dls.c), which
       * the plan traces and prints for both levels (the full level's plan ran above):
       * scaled by Σ_sets reach share × receivers. Upper bound: every set over every
       * receiver (what it would cost without the reach bound). */
      double inf_all = bl.inf_s * ((double)fsets * Rf) / ((double)bf->dls_count * R);
      int have_reach = bl.reach_sets > 0 && fbl.reach_sets > 0 && bl.reach_sum > 0.0;
      double inf_f = have_reach ? bl.inf_s * (fbl.reach_sum * Rf) / (bl.reach_sum * R) : inf_all;
      double full_f = bl.full_s * rec_f / (rec_sum + 1e-30);
      double base_f = pre + post;
      printf("extrapolated to full scale (%u texels + %u GLG probes = %.1fx, %d sets, records "
             "%.0f MB):\n", fs.texels, fs.glg_probes, kr, fsets, rec_f / 1048576.0);
      if (have_reach)
        printf("  reach bounds (the plans'): mean %.1f%% of the texels per set here, %.1f%% at "
               "full scale; sets x receivers inside them x%.1f\n",
               100.0 * bl.reach_sum / bl.reach_sets, 100.0 * fbl.reach_sum / fbl.reach_sets,
               (fbl.reach_sum * Rf) / (bl.reach_sum * R));
      printf("  bake without sets %.0f s (stages to the plan %.0f s measured; passes x%.1f), "
             "sets' influence %.0f s (x sets x receivers %s; %.0f s if every set saw every "
             "receiver), sets' full passes %.0f s (x record bytes): with sets %.0f s = %.1fx "
             "(paper: 10 -> 33 min fast on 18 cores; a model from this level: --full measures, and "
             "the full level at its own, finer texel size keeps more texels per set than scaled here)\n",
             base_f, pre, kr, inf_f, have_reach ? "inside the reach bounds" : "(no reach bounds "
             "in the plans)", inf_all, full_f, base_f + inf_f + full_f,
             (base_f + inf_f + full_f) / (base_f + 1e-30));
      /* A set's record does not grow with the level, the mix of sets does: the full
       * level's median toggle, each measured toggle standing for its class's share. */
      double tfull = -1.0;
      if (ntog_c[0] && ntog_c[1] && nroom) {
        double wc[2] = {(double)nroom_f / nroom, 1.0}, tot = wc[0] * ntog_c[0] + wc[1] * ntog_c[1];
        uint32_t i0 = 0, i1 = 0; /* both sorted by the percentiles above */
        for (double acc = 0.0; acc < 0.5 * tot && (i0 < ntog_c[0] || i1 < ntog_c[1]);) {
          int c = i1 >= ntog_c[1] || (i0 < ntog_c[0] && tog_c[0][i0] <= tog_c[1][i1]) ? 0 : 1;
          tfull = c ? tog_c[1][i1++] : tog_c[0][i0++];
          acc += wc[c];
        }
      }
      printf("  run-time: one set toggled, the full level's mix (%u room + %u hall sets, each "
             "as measured here): median %.3f ms [0.1 ms]; all sets changed ~%.1f ms at the "
             "measured GB/s; records %.0f MB\n", nroom_f, nhall, tfull,
             tall * 1e3 * rec_f / (rec_sum + 1e-30),
             rec_f / 1048576.0);
      /* Run-time memory: each part of the counted memory scaled by what it grows with:
       * geometry, lightmap and LLG by texels, the GLG by its probes, records and the
       * blends' tables and touched base rows by record bytes. */
      const double M = 1048576.0, kt = (double)fs.texels / (st.texels ? st.texels : 1);
      const double kg = (double)fs.glg_probes / (st.glg_probes ? st.glg_probes : 1);
      const double krec = rec_f / (rec_sum + 1e-30);
      double g = mu.geometry * kt, l = mu.lightmap * kt, gl = mu.glg * kg, ll = mu.llg * kt;
      double re = mu.records * krec, be = mu.blend * krec;
      printf("  run-time memory modelled at full scale: %.0f MB = geometry %.0f + lightmap %.0f "
             "+ GLG %.0f + LLG %.0f + records %.0f + blend engines %.0f (x%.1f texels, x%.1f GLG "
             "probes, x%.1f records; target <= 77 MB, paper 77 MB)\n",
             (g + l + gl + ll + re + be) / M, g / M, l / M, gl / M, ll / M, re / M, be / M, kt,
             kg, krec);
    }
  }
  free(rb);
  free(tog_c[0]);
  free(tog_c[1]);
  ub_bakefile_free(bf);
  free(params);
  printf("bench_estate: %.0f s\n", ub_bench_now() - t0);
  return 0;
}
