/* Encode + write: atlases (dilated SH, AHD EXR, PNG preview), the .ubk and the report.
 * Every file is written at the staged path its output folder (bake/outdir.c) gives it and
 * renamed into place only when all of them succeeded, so a failed bake leaves no partial
 * outputs. The folders are made when the bake starts (ub_output_open), so a bad output
 * folder fails before hours of work, not after. */
#include "bake/output.h"

#include <errno.h>
#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "bake/outdir.h"
#include "lightmaps/image.h"
#include "ubake/ahd.h"
#include "ubake/bakefile.h"

#define UB_DILATE_RINGS 4

/* The output folder of one bake (bake/outdir.h); the write stage fills it. The options'
 * paths are checked here, where ub_bake_options and ub_bake_stats are known; outdir takes
 * them checked. */
struct ub_output {
  ub_outdir *dir;
};

/* Whether json_path names a file the bake itself writes into dir (NAME.ubk, NAME_lm<i> or
 * NAME_error<i> .exr/.png): the same folder (device and inode, once both exist) and one of
 * those names. NAME.report.json itself is fine: --json then only says the default. */
static int json_is_an_output(const char *json_path, const char *dir, const char *name)
{
  const char *slash = strrchr(json_path, '/');
  const char *base = slash ? slash + 1 : json_path;
  char jdir[1024];
  if (slash)
    snprintf(jdir, sizeof jdir, "%.*s", (int)(slash - json_path) ? (int)(slash - json_path) : 1,
             json_path);
  else
    snprintf(jdir, sizeof jdir, ".");
  struct stat a, b;
  if (stat(jdir, &a) != 0 || stat(dir, &b) != 0 || a.st_dev != b.st_dev || a.st_ino != b.st_ino)
    return 0;
  size_t n = strlen(name);
  if (strncmp(base, name, n) != 0)
    return 0;
  const char *rest = base + n;
  if (!strcmp(rest, ".ubk"))
    return 1;
  static const char *kinds[2] = {"_lm", "_error"};
  for (int k = 0; k < 2; k++) {
    size_t kl = strlen(kinds[k]);
    if (strncmp(rest, kinds[k], kl) != 0)
      continue;
    const char *d = rest + kl;
    if (*d < '0' || *d > '9')
      continue;
    while (*d >= '0' && *d <= '9')
      d++;
    if (!strcmp(d, ".exr") || !strcmp(d, ".png"))
      return 1;
  }
  return 0;
}

ub_result ub_output_open(const char *level_name, const ub_bake_options *opt, const ub_log *log,
                         ub_output **out)
{
  *out = NULL;
  const char *dir = opt->out_dir ? opt->out_dir : ".";
  if (!*dir) {
    ub_log_printf(log, UB_LOG_ERROR, "output folder \"\": an empty path");
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (opt->json_path && !*opt->json_path) {
    ub_log_printf(log, UB_LOG_ERROR, "report path \"\" (--json): an empty path");
    return UB_ERR_INVALID_ARGUMENT;
  }
  /* The bake's stats hold the .ubk's path: it must fit there. */
  if (strlen(dir) + strlen(level_name) + 6 > sizeof ((ub_bake_stats *)0)->ubk_path) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: output path too long (over %zu bytes)", dir,
                  sizeof ((ub_bake_stats *)0)->ubk_path - 1);
    return UB_ERR_INVALID_ARGUMENT;
  }
  ub_output *o = calloc(1, sizeof *o);
  if (!o)
    return UB_ERR_OUT_OF_MEMORY;
  ub_result r = ub_outdir_open(dir, level_name, opt->json_path, log, &o->dir);
  if (r == UB_OK && opt->json_path && json_is_an_output(opt->json_path, dir, level_name)) {
    ub_log_printf(log, UB_LOG_ERROR, "%s (--json): the report would replace one of the "
                  "bake's own files in %s", opt->json_path, dir);
    ub_outdir_close(o->dir);
    r = UB_ERR_INVALID_ARGUMENT;
  }
  if (r != UB_OK) {
    free(o);
    return r;
  }
  *out = o;
  return UB_OK;
}

void ub_output_close(ub_output *o)
{
  if (!o)
    return;
  ub_outdir_close(o->dir);
  free(o);
}

void ub_json_write_str(FILE *f, const char *s)
{
  fputc('"', f);
  for (; s && *s; s++) {
    unsigned char c = (unsigned char)*s;
    if (c == '"' || c == '\\')
      fprintf(f, "\\%c", c);
    else if (c < 0x20)
      fprintf(f, "\\u%04x", c);
    else
      fputc(c, f);
  }
  fputc('"', f);
}

/* Error map channels (EXR stores them sorted): the texel's luminance irradiance along
 * the normal E (W/m²), 1 where a texel is, its relative standard error (ub_rel_error) and
 * its standard error (W/m²). */
#define UB_ERR_EXR_CHANNELS 4
static const char *const err_channel_names[UB_ERR_EXR_CHANNELS] = {"E", "covered", "rel_se",
                                                                   "se"};
/* False-colour PNG scale of the relative standard error (log): 0.1% blue … 10% red. */
#define UB_ERR_PNG_MIN 0.001f
#define UB_ERR_PNG_MAX 0.1f

static double lum_f(const float *c)
{
  return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
}

static int cmp_float(const void *a, const void *b)
{
  float x = *(const float *)a, y = *(const float *)b;
  return (x > y) - (x < y);
}

/* Relative standard error over the lit receivers (E > UB_ERR_LIT × mean E): count, mean,
 * RMS, 95th percentile, max. */
typedef struct err_summary {
  uint32_t lit;
  double mean, rms, p95, max;
} err_summary;

static void summarise_errors(const float *e, const float *se, uint32_t n, err_summary *out)
{
  memset(out, 0, sizeof *out);
  if (!e || !se || n == 0)
    return;
  double floor_e = ub_err_floor(e, n), mean_e = floor_e / UB_ERR_FLOOR;
  float *rel = malloc((size_t)n * sizeof *rel);
  if (!rel)
    return;
  uint32_t m = 0;
  double sum = 0.0, sum2 = 0.0;
  for (uint32_t i = 0; i < n; i++) {
    if (!(e[i] > UB_ERR_LIT * mean_e))
      continue;
    double r = ub_rel_error(se[i], e[i], floor_e);
    if (!isfinite(r))
      continue;
    rel[m++] = (float)r;
    sum += r;
    sum2 += r * r;
  }
  if (m) {
    qsort(rel, m, sizeof *rel, cmp_float);
    out->lit = m;
    out->mean = sum / m;
    out->rms = sqrt(sum2 / m);
    out->p95 = rel[(size_t)((m - 1) * 0.95)];
    out->max = rel[m - 1];
  }
  free(rel);
}

static void json_err_summary(FILE *f, const char *name, const err_summary *s)
{
  fprintf(f, "\"%s\": {\"lit\": %u, \"mean_rel_se\": %.6g, \"rms_rel_se\": %.6g, "
             "\"p95_rel_se\": %.6g, \"max_rel_se\": %.6g}",
          name, s->lit, s->mean, s->rms, s->p95, s->max);
}

/* Luminance of every texel's irradiance along the normal and of every GLG probe's DC
 * irradiance (the quantities the standard errors are of). */
static ub_result receiver_lum(const ub_lightmap *lm, const ub_pass_result *base, uint32_t P,
                              float **out_tx, float **out_pr)
{
  *out_tx = malloc(((size_t)lm->texel_count + 1) * sizeof(float));
  *out_pr = malloc(((size_t)P + 1) * sizeof(float));
  if (!*out_tx || !*out_pr)
    return UB_ERR_OUT_OF_MEMORY;
  for (uint32_t t = 0; t < lm->texel_count; t++)
    (*out_tx)[t] = (float)lum_f(base->iz + 3 * (size_t)t);
  for (uint32_t q = 0; q < P; q++)
    (*out_pr)[q] = base->probe_direct[q] + base->probe_indirect[q];
  return UB_OK;
}

/* Per atlas: the error map (EXR channels above) and the relative error for the PNG (−1
 * where no texel is). */
static ub_result error_atlas(const ub_lightmap *lm, const ub_pass_result *base,
                             const float *e_tx, double floor_e, uint32_t a, float **out_exr,
                             float **out_rel)
{
  const ub_atlas *at = &lm->atlases[a];
  size_t npx = (size_t)at->width * at->height;
  *out_exr = calloc(npx * UB_ERR_EXR_CHANNELS, sizeof(float));
  *out_rel = malloc(npx * sizeof(float));
  if (!*out_exr || !*out_rel)
    return UB_ERR_OUT_OF_MEMORY;
  for (size_t px = 0; px < npx; px++)
    (*out_rel)[px] = -1.0f;
  for (uint32_t i = 0; i < at->texel_count; i++) {
    uint32_t t = at->first_texel + i;
    size_t px = (size_t)lm->texel_xy[2 * t + 1] * at->width + lm->texel_xy[2 * t];
    float rel = (float)ub_rel_error(base->texel_se[t], e_tx[t], floor_e);
    float *o = *out_exr + UB_ERR_EXR_CHANNELS * px;
    o[0] = e_tx[t];
    o[1] = 1.0f;
    o[2] = isfinite(rel) ? rel : 0.0f;
    o[3] = base->texel_se[t];
    (*out_rel)[px] = o[2];
  }
  return UB_OK;
}

static double now_seconds(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* write_seconds: the write stage so far (this file is its last step), listed with the
 * stages before it and included in st->total_seconds. */
static ub_result write_report(const char *path, const ub_scene *scene, const ub_lightmap *lm,
                              const ub_plan *plan, const ub_pass_result *base,
                              const ub_bakefile *bf, const ub_llg_set *llg,
                              const ub_dls_stats *dstats,
                              const ub_bake_options *opt, const ub_bake_stats *st,
                              double write_seconds, const ub_log *log)
{
  FILE *f = fopen(path, "w");
  if (!f) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write: %s", path, strerror(errno));
    return UB_ERR_IO;
  }
  fprintf(f, "{\n  \"level\": ");
  ub_json_write_str(f, scene->path);
  fprintf(f, ",\n  \"name\": ");
  ub_json_write_str(f, st->level_name);
  fprintf(f, ",\n  \"quality\": \"%s\",\n  \"seed\": %u,\n  \"threads\": %d,\n",
          ub_quality_name(opt->quality), opt->seed,
          opt->threads > 0 ? opt->threads : omp_get_max_threads()); /* the count used */
  fprintf(f, "  \"scene\": {\"triangles\": %u, \"degenerate_triangles\": %u, \"materials\": %u, "
             "\"lights\": %u, \"emissive_triangles\": %u, \"nodes\": %u, \"sky\": %s},\n",
          scene->triangle_count, scene->degenerate_count, scene->material_count,
          scene->light_count, st->emissive_triangles, scene->node_count,
          scene->has_sky ? "true" : "false");
  fprintf(f, "  \"plan\": {\n    \"forced_all\": %s, \"ray_rate\": %.0f, \"doors\": %u, "
             "\"door_passes\": %u, \"bounce_ratio\": %.4f, \"estimated_bounces\": %u, "
             "\"actual_bounces\": %u, \"bounce_full_rays\": %s,\n",
          plan->forced ? "true" : "false", plan->ray_rate, plan->doors, plan->door_passes,
          plan->bounce_ratio, plan->est_bounces, base->bounces,
          opt && opt->bounce_full_rays ? "true" : "false");
  fprintf(f, "    \"passes\": [{\"name\": \"base\", \"lights\": %u, "
             "\"static_lights\": %u, \"primary_lights\": %u, \"sky\": %s, \"emissive\": %s, "
             "\"gather_rays\": %u, \"emissive_samples\": %u, \"shadow_samples\": %u, "
             "\"estimated_rays\": %.0f, \"actual_rays\": %llu, \"estimated_seconds\": %.3f, "
             "\"actual_seconds\": %.3f}",
          plan->base_lights, plan->static_lights, plan->primary_lights,
          plan->sky ? "true" : "false", plan->emissive ? "true" : "false", plan->gather_rays,
          plan->emissive_samples, plan->shadow_samples, plan->est_rays,
          (unsigned long long)(base->rays_gather + base->rays_shadow),
          plan->est_rays / plan->ray_rate, st->gather_seconds);
  for (uint32_t d = 0; d < scene->dls_count; d++) {
    fprintf(f, ", {\"name\": ");
    char nm[80];
    snprintf(nm, sizeof nm, "dls %s", scene->dls_names[d]);
    ub_json_write_str(f, nm);
    fprintf(f, ", \"estimated_rays\": %.0f, \"estimated_seconds\": %.3f, \"skipped\": %s",
            plan->dls_est_rays[d], plan->dls_est_seconds[d],
            plan->dls_est_rays[d] > 0 ? "false" : "true");
    if (dstats && dstats->sets) {
      const ub_dls_set_stats *ss = &dstats->sets[d];
      fprintf(f, ", \"actual_rays\": %llu, \"actual_seconds\": %.3f, \"influence_rays\": %llu, "
                 "\"influence_seconds\": %.3f",
              (unsigned long long)(ss->rays_influence + ss->rays_full),
              ss->seconds_influence + ss->seconds_full,
              (unsigned long long)ss->rays_influence, ss->seconds_influence);
    }
    fprintf(f, "}");
  }
  for (uint32_t k = 0; k < plan->combo_count; k++) {
    char nm[160];
    snprintf(nm, sizeof nm, "combination door %s x %s", scene->door_names[plan->combos[k].door],
             plan->combos[k].name);
    fprintf(f, ", {\"name\": ");
    ub_json_write_str(f, nm);
    fprintf(f, ", \"baked\": %s, \"why\": ", plan->combos[k].baked ? "true" : "false");
    ub_json_write_str(f, plan->combos[k].why);
    fprintf(f, "}");
  }
  fprintf(f, "],\n");
  fprintf(f, "    \"effect_counters\": {\"emissive_shadow_rays\": %llu, \"sky_gather_hits\": "
             "%llu, \"emitter_gather_hits\": %llu, \"dls_passes\": %u, \"door_passes\": %u},\n",
          (unsigned long long)st->rays_emissive, (unsigned long long)st->sky_hits,
          (unsigned long long)st->emitter_hits, st->dls_sets, st->door_passes);
  fprintf(f, "    \"dls\": {\"sets\": %u, \"baked\": %u, \"reach_nothing\": %u, "
             "\"influence_rays\": %llu, \"influence_seconds\": %.4f, \"full_rays\": %llu, "
             "\"full_seconds\": %.4f, \"scaled_rays\": %s, \"gather_share\": %.4f, "
             "\"records\": [",
          scene->dls_count, dstats ? dstats->sets_baked : 0, dstats ? dstats->sets_empty : 0,
          dstats ? (unsigned long long)dstats->rays_influence : 0ULL,
          dstats ? dstats->seconds_influence : 0.0,
          dstats ? (unsigned long long)dstats->rays_full : 0ULL,
          dstats ? dstats->seconds_full : 0.0, plan->dls_scaled_rays ? "true" : "false",
          dstats && dstats->gather_units_full
              ? (double)dstats->gather_units / dstats->gather_units_full
              : 1.0);
  for (uint32_t d = 0; d < bf->dls_count; d++) {
    fprintf(f, "%s{\"name\": ", d ? ", " : "");
    ub_json_write_str(f, bf->dls[d].name);
    fprintf(f, ", \"lights\": %u, \"texel_pixels\": %u, \"probes\": %u}",
            bf->dls[d].light_count, bf->dls[d].texel_count, bf->dls[d].probe_count);
  }
  fprintf(f, "]},\n    \"lights\": [");
  for (uint32_t l = 0; l < scene->light_count; l++) {
    const ub_light *L = &scene->lights[l];
    static const char *types[] = {"point", "spot", "directional"};
    fprintf(f, "%s\n      {\"index\": %u, \"node\": ", l ? "," : "", l);
    ub_json_write_str(f, L->node >= 0 && (uint32_t)L->node < scene->node_count
                    ? scene->nodes[L->node].name
                    : "");
    fprintf(f, ", \"type\": \"%s\", \"class\": \"%s\", \"status\": ", types[L->type],
            L->cls == UB_LIGHT_PRIMARY ? "primary" : "static");
    ub_json_write_str(f, ub_light_skip_reason((ub_light_skip)plan->light_skip[l]));
    fputc('}', f);
  }
  fprintf(f, "\n    ]\n  },\n");
  fprintf(f, "  \"receivers\": {\"atlases\": [");
  for (uint32_t a = 0; a < lm->atlas_count; a++)
    fprintf(f, "%s{\"width\": %u, \"height\": %u, \"texels\": %u, \"generated\": %s}",
            a ? ", " : "", lm->atlases[a].width, lm->atlases[a].height,
            lm->atlases[a].texel_count, lm->atlases[a].generated ? "true" : "false");
  fprintf(f, "], \"texels\": %u, \"backface_fixes\": %u, \"overlap_texels\": %u, "
          "\"separated_texel_pairs\": %u},\n",
          lm->texel_count, lm->backface_fixes, lm->overlap_texels, lm->separated_links);
  fprintf(f, "  \"glg\": {\"probes\": %u, \"tets\": %u, \"leak_plane_tets\": %u, \"spacing\": %.4g},\n",
          st->glg_probes, st->glg_tets, st->glg_leak_tets, scene->glg_spacing);
  fprintf(f, "  \"llg\": {\"models\": %u, \"probes\": %u, \"invalid_probes\": %u, "
             "\"visibility_rays\": %llu, \"auto\": %u, \"auto_nodes\": [",
          llg ? llg->model_count : 0, llg ? llg->probe_count : 0, llg ? llg->invalid_count : 0,
          llg ? (unsigned long long)llg->rays : 0ULL, st->llg_auto_nodes);
  for (uint32_t n = 0, k = 0; n < scene->node_count; n++)
    if (scene->nodes[n].receiver_source == UB_RECEIVER_AUTO) {
      fprintf(f, "%s", k++ ? ", " : "");
      ub_json_write_str(f, scene->nodes[n].name);
    }
  fprintf(f, "]},\n");
  fprintf(f, "  \"bounces\": %u,\n  \"bounce_energy\": [", st->bounces);
  for (uint32_t b = 0; b <= st->bounces && b <= UB_BAKE_MAX_BOUNCES; b++)
    fprintf(f, "%s%.6g", b ? ", " : "", st->bounce_energy[b]);
  fprintf(f, "],\n  \"bounce_cap_reached\": %s, \"bounce_cap_missing_fraction\": ",
          st->bounce_cap_tail > 0.0 ? "true" : "false");
  if (isfinite(st->bounce_cap_tail))
    fprintf(f, "%.6g,\n", st->bounce_cap_tail);
  else
    fprintf(f, "null,\n");
  fprintf(f, "  \"stages\": [");
  for (uint32_t s = 0; s < st->stage_count; s++) {
    fprintf(f, "%s{\"name\": ", s ? ", " : "");
    ub_json_write_str(f, st->stage_name[s]);
    fprintf(f, ", \"seconds\": %.4f}", st->stage_seconds[s]);
  }
  fprintf(f, "%s{\"name\": \"write\", \"seconds\": %.4f}", st->stage_count ? ", " : "",
          write_seconds);
  double rps = st->gather_seconds > 0
                   ? (double)(st->rays_gather + st->rays_shadow) / st->gather_seconds
                   : 0.0;
  fprintf(f, "],\n  \"seconds\": %.4f,\n", st->total_seconds);
  fprintf(f, "  \"rays\": {\"total\": %llu, \"gather\": %llu, \"shadow\": %llu, "
             "\"pass_seconds\": %.4f, \"rays_per_second\": %.0f},\n",
          (unsigned long long)st->rays_total, (unsigned long long)st->rays_gather,
          (unsigned long long)st->rays_shadow, st->gather_seconds, rps);
  fprintf(f, "  \"escaped_gather_rays\": %llu,\n", (unsigned long long)base->misses);
  {
    /* Standard error estimates (bake/pass.h): relative to max(E, floor × mean E). */
    err_summary es_tx, es_pr;
    float *e_tx = NULL, *e_pr = NULL;
    if (receiver_lum(lm, base, st->glg_probes, &e_tx, &e_pr) == UB_OK) {
      summarise_errors(e_tx, base->texel_se, lm->texel_count, &es_tx);
      summarise_errors(e_pr, base->probe_se, st->glg_probes, &es_pr);
    } else {
      memset(&es_tx, 0, sizeof es_tx);
      memset(&es_pr, 0, sizeof es_pr);
    }
    free(e_tx);
    free(e_pr);
    fprintf(f, "  \"error_estimate\": {\"floor\": %.3g, \"lit_above\": %.3g, ", UB_ERR_FLOOR,
            UB_ERR_LIT);
    json_err_summary(f, "texels", &es_tx);
    fprintf(f, ", ");
    json_err_summary(f, "probes", &es_pr);
    fprintf(f, ",\n    \"target_error\": %.6g, \"adaptive_rounds\": %u, "
               "\"adaptive_receiver_rounds\": %llu, \"adaptive_rays\": %llu},\n",
            opt->target_error, base->adaptive_rounds,
            (unsigned long long)base->adaptive_receivers,
            (unsigned long long)base->rays_adaptive);
  }
  fprintf(f, "  \"clamped_values\": %llu,\n  \"backface_hits\": %llu,\n  \"unlit_hits\": %llu,\n",
          (unsigned long long)st->clamped_values, (unsigned long long)st->backface_hits,
          (unsigned long long)st->unlit_hits);
  /* getrusage's KiB: MiB as the command line prints it, and MB (10^6 bytes) */
  fprintf(f, "  \"peak_rss_mib\": %.1f,\n  \"peak_rss_mb\": %.1f\n}\n", st->peak_rss_kb / 1024.0,
          st->peak_rss_kb * 1.024e-3);
  int bad = ferror(f);
  if (fclose(f) != 0 || bad) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: write failed", path);
    return UB_ERR_IO;
  }
  return UB_OK;
}

/* Per atlas: dilated SH + normals + coverage for the .ubk, AHD for the EXR, irradiance
 * along the normal for the PNG. The dilation image becomes the SH in place and the AHD and
 * irradiance come after it is gone: 109 bytes a pixel at most, not 174 (at ESTATE scale
 * the write stage's images were the bake's peak RSS). */
static ub_result encode_atlas(const ub_lightmap *lm, const ub_pass_result *base, uint32_t a,
                              ub_bakefile_atlas *out, float **out_ahd, float **out_irr)
{
  const ub_atlas *at = &lm->atlases[a];
  size_t npx = (size_t)at->width * at->height;
  float *img = calloc(npx * 16, sizeof(float)); /* 12 SH + 3 normal + 1 filled */
  uint8_t *cov = calloc(npx, 1);
  out->normal = malloc(npx * 3 * sizeof(float));
  out->coverage = calloc(npx, 1);
  if (!img || !cov || !out->normal || !out->coverage) {
    free(img);
    free(cov);
    return UB_ERR_OUT_OF_MEMORY;
  }
  out->width = at->width;
  out->height = at->height;
  if (at->link) {
    out->link = malloc(npx + 1);
    if (!out->link) {
      free(img);
      free(cov);
      return UB_ERR_OUT_OF_MEMORY;
    }
    memcpy(out->link, at->link, npx);
  }
  for (uint32_t i = 0; i < at->texel_count; i++) {
    uint32_t t = at->first_texel + i;
    size_t px = (size_t)lm->texel_xy[2 * t + 1] * at->width + lm->texel_xy[2 * t];
    memcpy(img + 16 * px, base->sh + 12 * (size_t)t, 12 * sizeof(float));
    memcpy(img + 16 * px + 12, lm->texel_normal + 3 * (size_t)t, 3 * sizeof(float));
    img[16 * px + 15] = 1.0f;
    cov[px] = 1;
  }
  ub_lightmap_dilate(img, cov, at->width, at->height, 16, UB_DILATE_RINGS);
  /* Pixel px's SH moves from 16·px to 12·px: never past a pixel not yet read. */
  for (size_t px = 0; px < npx; px++) {
    float *p = img + 16 * px;
    float *n = p + 12;
    float *sh = img + UB_SH1_FLOATS * px;
    if (cov[px]) {
      out->coverage[px] = 1;
    } else if (p[15] > 0.0f) {
      out->coverage[px] = 2;
    } else {
      memset(sh, 0, UB_SH1_FLOATS * sizeof(float));
      memset(out->normal + 3 * px, 0, 3 * sizeof(float));
      continue;
    }
    float len = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int k = 0; k < 3; k++)
      out->normal[3 * px + k] = len > 1e-6f ? n[k] / len : (k == 1 ? 1.0f : 0.0f);
    memmove(sh, p, UB_SH1_FLOATS * sizeof(float));
  }
  free(cov);
  float *sh = realloc(img, npx * UB_SH1_FLOATS * sizeof(float) + 1);
  out->sh = sh ? sh : img; /* (a failed shrink keeps the block) */
  *out_ahd = calloc(npx * 9, sizeof(float));
  *out_irr = calloc(npx * 3, sizeof(float));
  if (!*out_ahd || !*out_irr)
    return UB_ERR_OUT_OF_MEMORY;
  for (size_t px = 0; px < npx; px++) {
    if (!out->coverage[px])
      continue;
    const float *n = out->normal + 3 * px;
    ub_ahd ahd;
    ub_ahd_encode(out->sh + UB_SH1_FLOATS * px, n, &ahd);
    float *o = *out_ahd + 9 * px;
    memcpy(o, ahd.ambient, 3 * sizeof(float));
    memcpy(o + 3, ahd.direction, 3 * sizeof(float));
    memcpy(o + 6, ahd.directional, 3 * sizeof(float));
    ub_ahd_irradiance(&ahd, n, *out_irr + 3 * px);
  }
  return UB_OK;
}

/* The LLG models as the .ubk stores them (arrays owned by the caller's bakefile). */
static ub_result fill_llgs(const ub_scene *scene, const ub_llg_set *llg, const float *llg_sh,
                           ub_bakefile *bf)
{
  bf->llgs = calloc(llg->model_count, sizeof *bf->llgs);
  if (!bf->llgs)
    return UB_ERR_OUT_OF_MEMORY;
  bf->llg_count = llg->model_count;
  for (uint32_t i = 0; i < llg->model_count; i++) {
    const ub_llg_model *m = &llg->models[i];
    ub_bakefile_llg *o = &bf->llgs[i];
    snprintf(o->name, sizeof o->name, "%s", scene->nodes[m->node].name);
    memcpy(o->center, m->center, sizeof o->center);
    memcpy(o->axes, m->axes, sizeof o->axes);
    memcpy(o->half, m->half, sizeof o->half);
    memcpy(o->dims, m->dims, sizeof o->dims);
    o->probe_sh = (float *)(llg_sh + 27 * (size_t)m->probe_first);
    o->vertex_count = m->vertex_count;
    o->vis = m->vis;
    o->vis_shared_from = m->vis_source != i ? m->vis_source + 1u : 0u;
    memcpy(o->vis_rotation, m->vis_rot, sizeof o->vis_rotation);
    o->self = m->self;
    o->triangle_count = m->triangle_count;
    o->indices = m->local_indices;
    o->positions = malloc((size_t)m->vertex_count * 3 * sizeof(float) + 1);
    o->normals = malloc((size_t)m->vertex_count * 3 * sizeof(float) + 1);
    if (!o->positions || !o->normals)
      return UB_ERR_OUT_OF_MEMORY;
    for (uint32_t v = 0; v < m->vertex_count; v++) {
      memcpy(o->positions + 3 * (size_t)v, scene->positions + 3 * (size_t)m->vertices[v],
             3 * sizeof(float));
      memcpy(o->normals + 3 * (size_t)v, scene->normals + 3 * (size_t)m->vertices[v],
             3 * sizeof(float));
    }
  }
  return UB_OK;
}

/* Per-triangle roles (section TRIR) for door leaves and show/hide objects that have a
 * record; NULL when the level has none. */
static ub_result tri_roles(const ub_scene *s, const ub_bakefile_record *elems, uint32_t n,
                           uint32_t **out)
{
  *out = NULL;
  if (!n)
    return UB_OK;
  uint32_t *role = NULL;
  for (uint32_t i = 0; i < s->node_count; i++) {
    const ub_node *nd = &s->nodes[i];
    uint32_t r = 0, kind = UB_ELEMENT_DOOR;
    const char *name = NULL;
    if (nd->door >= 0) {
      r = UB_TRI_ROLE_DOOR_CLOSED;
      name = s->door_names[nd->door];
    } else if (nd->door_open >= 0) {
      r = UB_TRI_ROLE_DOOR_OPEN;
      name = s->door_names[nd->door_open];
    } else if (nd->semidynamic >= 0) {
      r = UB_TRI_ROLE_OBJECT;
      kind = UB_ELEMENT_OBJECT;
      name = s->object_names[nd->semidynamic];
    }
    if (!r || !nd->triangle_count)
      continue;
    uint32_t e = 0;
    while (e < n && !(elems[e].kind == kind && !strcmp(elems[e].name, name)))
      e++;
    if (e == n)
      continue; /* no record: drawn as in the base */
    if (!role) {
      role = calloc((size_t)s->triangle_count + 1, sizeof *role);
      if (!role)
        return UB_ERR_OUT_OF_MEMORY;
    }
    for (uint32_t t = nd->first_triangle; t < nd->first_triangle + nd->triangle_count; t++)
      role[t] = (r << 24) | e;
  }
  *out = role;
  return UB_OK;
}

ub_result ub_output_write(ub_output *o, const ub_scene *scene, const ub_lightmap *lm,
                          const ub_glg_bake *glg, const ub_llg_set *llg, const float *llg_sh,
                          ub_bakefile_record *dls, const ub_dls_stats *dstats,
                          ub_bakefile_record *elems, uint32_t elem_count,
                          const uint32_t *tri_material, const ub_plan *plan,
                          const ub_pass_result *base, const ub_bake_options *opt,
                          ub_bake_stats *stats, const ub_log *user_log)
{
  /* stats->total_seconds is the bake's time up to this stage (bake/bake.c) */
  const double t_write = now_seconds(), seconds_before = stats->total_seconds;
  ub_outdir *od = o->dir;
  ub_outdir_log fl;
  ub_outdir_wrap_log(od, user_log, &fl);
  const ub_log *log = &fl.log;
  const char *name = ub_outdir_name(od);
  const char *path = NULL; /* the staged path of the file being written */
  ub_result r = ub_outdir_reserve(od, 4 * lm->atlas_count + 2);
  if (r != UB_OK)
    return r;

  ub_bakefile bf;
  memset(&bf, 0, sizeof bf);
  snprintf(bf.level_name, sizeof bf.level_name, "%s", name);
  bf.seed = opt->seed;
  bf.bounces = base->bounces;
  bf.vertex_count = scene->vertex_count;
  bf.positions = scene->positions;
  bf.triangle_count = scene->triangle_count;
  bf.indices = scene->indices;
  bf.tri_atlas = lm->tri_atlas;
  bf.tri_uv = lm->tri_uv;
  bf.tri_albedo = malloc((size_t)scene->triangle_count * 3 * sizeof(float) + 1);
  bf.atlas_count = lm->atlas_count;
  bf.atlases = calloc(lm->atlas_count ? lm->atlas_count : 1, sizeof *bf.atlases);
  if (!bf.tri_albedo || !bf.atlases) {
    r = UB_ERR_OUT_OF_MEMORY;
    goto done;
  }
  for (uint32_t t = 0; t < scene->triangle_count; t++)
    memcpy(bf.tri_albedo + 3 * (size_t)t,
           scene->materials[(tri_material ? tri_material : scene->tri_material)[t]].albedo,
           3 * sizeof(float));
  r = tri_roles(scene, elems, elems ? elem_count : 0, &bf.tri_role);
  if (r != UB_OK)
    goto done;
  bf.dls_count = dls ? scene->dls_count : 0;
  bf.dls = dls;
  bf.elem_count = elems ? elem_count : 0;
  bf.elems = elems;
  bf.light_count = scene->light_count;
  bf.lights = calloc(scene->light_count ? scene->light_count : 1, sizeof *bf.lights);
  if (!bf.lights) {
    r = UB_ERR_OUT_OF_MEMORY;
    goto done;
  }
  for (uint32_t l = 0; l < scene->light_count; l++) {
    const ub_light *L = &scene->lights[l];
    ub_bakefile_light *o = &bf.lights[l];
    o->type = (uint32_t)L->type;
    o->cls = (uint32_t)L->cls;
    o->dls = bf.dls_count ? L->dls : -1;
    memcpy(o->position, L->position, sizeof o->position);
    memcpy(o->direction, L->direction, sizeof o->direction);
    memcpy(o->intensity, L->intensity, sizeof o->intensity);
    o->range = L->range;
    o->cos_inner = L->cos_inner;
    o->cos_outer = L->cos_outer;
  }
  if (glg && glg->mesh) {
    bf.glg_probe_count = glg->mesh->point_count;
    bf.glg_positions = glg->mesh->points;
    bf.glg_sh = (float *)glg->sh;
    bf.glg_tet_count = glg->mesh->tet_count;
    bf.glg_tets = glg->mesh->tets;
    bf.glg_neigh = glg->mesh->neigh;
    bf.glg_plane_count = glg->leak->plane_count;
    bf.glg_planes = glg->leak->planes;
    bf.glg_plane_of = glg->leak->plane_of;
  }

  if (llg && llg->model_count) {
    r = fill_llgs(scene, llg, llg_sh, &bf);
    if (r != UB_OK)
      goto done;
  }

  float *e_tx = NULL, *e_pr = NULL;
  r = receiver_lum(lm, base, glg && glg->mesh ? glg->mesh->point_count : 0, &e_tx, &e_pr);
  double floor_e = r == UB_OK ? ub_err_floor(e_tx, lm->texel_count) : 0.0;
  if (r == UB_OK) {
    err_summary es;
    summarise_errors(e_tx, base->texel_se, lm->texel_count, &es);
    stats->texel_rel_se_mean = es.mean;
    stats->texel_rel_se_p95 = es.p95;
  }
  for (uint32_t a = 0; r == UB_OK && a < lm->atlas_count; a++) {
    float *exr = NULL, *rel = NULL;
    char fname[256];
    r = error_atlas(lm, base, e_tx, floor_e, a, &exr, &rel);
    if (r == UB_OK) {
      snprintf(fname, sizeof fname, "%s_error%u.exr", name, a);
      r = ub_outdir_add(od, fname, &path, NULL);
      if (r == UB_OK)
        r = ub_image_write_exr(path, lm->atlases[a].width, lm->atlases[a].height,
                               UB_ERR_EXR_CHANNELS, err_channel_names, exr, log);
    }
    if (r == UB_OK) {
      snprintf(fname, sizeof fname, "%s_error%u.png", name, a);
      r = ub_outdir_add(od, fname, &path, NULL);
      if (r == UB_OK)
        r = ub_image_write_png_false_colour(path, lm->atlases[a].width, lm->atlases[a].height,
                                            rel, UB_ERR_PNG_MIN, UB_ERR_PNG_MAX, log);
    }
    free(exr);
    free(rel);
  }
  free(e_tx);
  free(e_pr);
  if (r != UB_OK)
    goto done;

  for (uint32_t a = 0; a < lm->atlas_count; a++) {
    float *ahd = NULL, *irr = NULL;
    r = encode_atlas(lm, base, a, &bf.atlases[a], &ahd, &irr);
    char fname[256];
    if (r == UB_OK) {
      snprintf(fname, sizeof fname, "%s_lm%u.exr", name, a);
      r = ub_outdir_add(od, fname, &path, NULL);
      if (r == UB_OK)
        r = ub_image_write_exr(path, lm->atlases[a].width, lm->atlases[a].height,
                               UB_AHD_EXR_CHANNELS, ub_ahd_exr_channel_names, ahd, log);
    }
    if (r == UB_OK) {
      snprintf(fname, sizeof fname, "%s_lm%u.png", name, a);
      r = ub_outdir_add(od, fname, &path, NULL);
      if (r == UB_OK)
        r = ub_image_write_png_preview(path, lm->atlases[a].width, lm->atlases[a].height, irr,
                                       1.0f, log);
    }
    free(ahd);
    free(irr);
    if (r != UB_OK)
      goto done;
  }

  char fname[256];
  snprintf(fname, sizeof fname, "%s.ubk", name);
  const char *ubk_final = NULL;
  r = ub_outdir_add(od, fname, &path, &ubk_final);
  if (r != UB_OK)
    goto done;
  uint64_t half_clamped = 0;
  r = ub_bakefile_write_ex(&bf, path, log, &half_clamped);
  stats->clamped_values += half_clamped; /* reported with the baker's own clamps */
  if (r != UB_OK)
    goto done;
  snprintf(stats->ubk_path, sizeof stats->ubk_path, "%s", ubk_final);

  /* The report last: it records the time and memory of everything before it, this stage
   * included; the bake's totals become these (only the renames into place follow). */
  snprintf(fname, sizeof fname, "%s.report.json", name);
  r = ub_outdir_add_report(od, fname, &path);
  if (r != UB_OK)
    goto done;
  double write_seconds = now_seconds() - t_write;
  long rss = ub_peak_rss_kb();
  stats->total_seconds = seconds_before + write_seconds;
  stats->peak_rss_kb = rss > stats->peak_rss_kb ? rss : stats->peak_rss_kb;
  r = write_report(path, scene, lm, plan, base, &bf, llg, dstats, opt, stats, write_seconds,
                   log);
  if (r != UB_OK)
    goto done;

  r = ub_outdir_commit(od, lm->atlas_count, log);
done:
  /* What a failure left in the staging folder goes in ub_output_close. */
  if (bf.atlases)
    for (uint32_t a = 0; a < bf.atlas_count; a++) {
      free(bf.atlases[a].sh);
      free(bf.atlases[a].normal);
      free(bf.atlases[a].coverage);
      free(bf.atlases[a].link);
    }
  free(bf.atlases);
  free(bf.tri_albedo);
  free(bf.tri_role);
  free(bf.lights);
  for (uint32_t i = 0; bf.llgs && i < bf.llg_count; i++) {
    free(bf.llgs[i].positions);
    free(bf.llgs[i].normals);
  }
  free(bf.llgs);
  return r;
}
