/* bench_objects: show/hide objects on levels/inn (prints, asserts nothing).
 *  - bake time: the whole bake vs the same bake without its "objects" stage (the plain
 *    bake, measured in the same run);
 *  - storage: the .ubk vs the same file written without element records (paper Fig. 14);
 *  - run-time update: one object toggled, one set retinted, and every object and set
 *    changed at once, averaged over repetitions, one core.
 * Usage: bench_objects [LEVEL.gltf] [texel_size] (default: build/levels/inn.gltf at 0.2 and
 *        the 8 x 8 inn, generated with extra_barrels=4 sconces=6, at 0.25);
 *        bench_objects --ubk FILE.ubk [--repeat N]: the run-time part only, on a baked file
 *        (N × the repetitions, for a profiler). */
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "bench/bench_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"

static long file_size(const char *p)
{
  struct stat sb;
  return stat(p, &sb) == 0 ? (long)sb.st_size : -1;
}

static int runtime_part(const char *ubk, int reps);
static int bench_level(const char *level, float texel_size, const char *b);

int main(int argc, char **argv)
{
  if (argc > 2 && !strcmp(argv[1], "--ubk")) {
    int rep = argc > 4 && !strcmp(argv[3], "--repeat") ? atoi(argv[4]) : 1;
    return runtime_part(argv[2], 50 * (rep > 0 ? rep : 1));
  }
  const char *b = getenv("UB_BUILD") ? getenv("UB_BUILD") : "build";
  if (argc > 1)
    return bench_level(argv[1], argc > 2 ? (float)atof(argv[2]) : 0.2f, b);
  /* Default: inn (4 objects, 2 sets) and its 8 x 8 variant (issue 6's 8 lights x 8
   * objects: 4 extra barrels, 6 sconces, each its own set), generated here. */
  char level[1024];
  snprintf(level, sizeof level, "%s/levels/inn.gltf", b);
  printf("== inn, 0.2 m texels\n");
  if (bench_level(level, 0.2f, b))
    return 1;
  char out[1100];
  snprintf(out, sizeof out, "%s/bench_out", b);
  const char *inn8[] = {"extra_barrels=4", "sconces=6"};
  if (ub_bench_genlevel(b, "inn", out, "inn8x8", 0.0, inn8, 2, 0) < 0) {
    fprintf(stderr, "bench_objects: could not generate the 8 x 8 inn\n");
    return 1;
  }
  snprintf(level, sizeof level, "%s/bench_out/inn8x8.gltf", b);
  printf("== inn 8 x 8 (8 objects, 8 sets), 0.25 m texels\n");
  return bench_level(level, 0.25f, b);
}

/* Bakes one level at draft and prints bake time vs plain, storage and update times. */
static int bench_level(const char *level, float texel_size, const char *b)
{
  char dir[1024], plain[1200];
  snprintf(dir, sizeof dir, "%s/bench_out/objects", b);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = UB_QUALITY_DRAFT;
  o.out_dir = dir;
  o.texel_size = texel_size;
  ub_bake_stats st;
  if (ub_bake_level(level, &o, NULL, &st) != UB_OK) {
    fprintf(stderr, "bench_objects: bake of %s failed\n", level);
    return 1;
  }
  double obj_s = ub_bench_stage_seconds(&st, "objects");
  double plain_s = st.total_seconds - obj_s;
  printf("bake (draft, %u texels): total %.2f s, objects stage %.2f s, plain %.2f s: %.2fx a plain bake\n",
         st.texels, st.total_seconds, obj_s, plain_s, plain_s > 0 ? st.total_seconds / plain_s : 0.0);

  ub_bakefile *bf = NULL;
  if (ub_bakefile_read(st.ubk_path, NULL, &bf) != UB_OK)
    return 1;
  uint64_t rec_texels = 0, rec_probes = 0;
  uint32_t nobj = 0, ncombo = 0;
  for (uint32_t e = 0; e < bf->elem_count; e++) {
    rec_texels += bf->elems[e].texel_count;
    rec_probes += bf->elems[e].probe_count;
    nobj += bf->elems[e].kind == UB_ELEMENT_OBJECT;
    ncombo += bf->elems[e].kind == UB_ELEMENT_COMBO;
  }
  uint32_t ne = bf->elem_count;
  uint32_t *role = bf->tri_role;
  bf->elem_count = 0;
  bf->tri_role = NULL;
  snprintf(plain, sizeof plain, "%s/plain.ubk", dir);
  ub_result wr = ub_bakefile_write(bf, plain, NULL);
  if (wr != UB_OK)
    fprintf(stderr, "bench_objects: writing %s without elements: %s\n", plain, ub_result_string(wr));
  bf->elem_count = ne;
  bf->tri_role = role;
  long full_b = file_size(st.ubk_path), plain_b = wr == UB_OK ? file_size(plain) : -1;
  printf("storage: %ld bytes with %u object + %u combination records (%llu texels, %llu probes), "
         "%ld bytes without: %.2fx\n",
         full_b, nobj, ncombo, (unsigned long long)rec_texels, (unsigned long long)rec_probes,
         plain_b, plain_b > 0 ? (double)full_b / plain_b : 0.0);
  ub_bakefile_free(bf);

  return runtime_part(st.ubk_path, 50);
}

static int runtime_part(const char *ubk, const int reps)
{
  double t0;
  omp_set_num_threads(1);
  ub_runtime *rt = NULL;
  if (ub_runtime_load(ubk, NULL, &rt) != UB_OK)
    return 1;
  int32_t obj = -1;
  for (uint32_t e = 0; e < ub_runtime_element_count(rt); e++)
    if (ub_runtime_element_kind(rt, e) == UB_ELEMENT_OBJECT && obj < 0)
      obj = (int32_t)e;
  t0 = ub_bench_now();
  for (int i = 0; i < reps; i++)
    ub_runtime_update(rt, NULL);
  double idle = (ub_bench_now() - t0) / reps;
  uint64_t written = 0;
  t0 = ub_bench_now();
  for (int i = 0; i < reps; i++) {
    ub_runtime_update_stats us;
    ub_runtime_set_element(rt, (uint32_t)obj, (float)(i & 1 ? 1.0 : 0.0));
    ub_runtime_update(rt, &us);
    written += us.texels_written;
  }
  double one_obj = (ub_bench_now() - t0) / reps;
  t0 = ub_bench_now();
  for (int i = 0; i < reps; i++) {
    ub_runtime_set_element(rt, (uint32_t)obj, (float)(i & 1 ? 1.0 : 0.0));
    ub_runtime_update(rt, NULL);
  }
  double one = (ub_bench_now() - t0) / reps;
  t0 = ub_bench_now();
  for (int i = 0; i < reps; i++) {
    float tint[3] = {0.2f + 0.01f * (i & 7), 0.4f, 1.0f};
    ub_runtime_set_dls(rt, 0, tint);
    ub_runtime_update(rt, NULL);
  }
  double set = (ub_bench_now() - t0) / reps;
  uint32_t nel = ub_runtime_element_count(rt), nd = ub_runtime_dls_count(rt), nobjs = 0;
  t0 = ub_bench_now();
  for (int i = 0; i < reps; i++) {
    for (uint32_t e = 0; e < nel; e++)
      if (ub_runtime_element_kind(rt, e) == UB_ELEMENT_OBJECT) {
        ub_runtime_set_element(rt, e, (float)((i + e) & 1));
        nobjs += i == 0;
      }
    for (uint32_t d = 0; d < nd; d++) {
      float tint[3] = {(float)((i + d) & 1), 0.5f, 1.0f};
      ub_runtime_set_dls(rt, d, tint);
    }
    ub_runtime_update(rt, NULL);
  }
  double all = (ub_bench_now() - t0) / reps;
  printf("update (1 core): nothing changed %.3f ms; one object %.3f ms (%.0f texels written)\n",
         idle * 1e3, one_obj * 1e3, (double)written / reps);
  printf("update (1 core): one object %.3f ms, one set %.3f ms, all %u objects + %u sets at once "
         "%.3f ms\n",
         one * 1e3, set * 1e3, nobjs, nd, all * 1e3);
  ub_runtime_free(rt);
  return 0;
}
