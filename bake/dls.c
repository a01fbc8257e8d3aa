/* Dynamic light set passes and their sparse records (see dls.h). */
#include "bake/dls.h"

#include "probes/llg.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define UB_DILATE_RINGS 4

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

uint32_t ub_dls_texel_pixel(const ub_lightmap *lm, uint32_t texel)
{
  uint32_t a = lm->texel_atlas[texel];
  uint64_t base = 0;
  for (uint32_t b = 0; b < a; b++)
    base += (uint64_t)lm->atlases[b].width * lm->atlases[b].height;
  return (uint32_t)(base + (uint64_t)lm->texel_xy[2 * texel + 1] * lm->atlases[a].width +
                    lm->texel_xy[2 * texel]);
}

void ub_dls_records_free(ub_bakefile_record *records, uint32_t count)
{
  if (!records)
    return;
  for (uint32_t i = 0; i < count; i++) {
    free(records[i].texel_index);
    free(records[i].texel_sh);
    free(records[i].probe_index);
    free(records[i].probe_sh);
    free(records[i].llg_probe_index);
    free(records[i].llg_probe_sh);
  }
  free(records);
}

/* The set's texel SH into sparse atlas pixels, with the same dilation as the base so
 * padding texels follow when the set is toggled (no seams under bilinear filtering).
 * Works per atlas on the bounding rectangle of the kept texels plus the dilation rings. */
ub_result ub_dls_texel_record(const ub_lightmap *lm, const uint32_t *kept, uint32_t nkept,
                              const float *sh, ub_bakefile_record *rec)
{
  size_t cap = 0, n = 0;
  uint32_t *idx = NULL;
  float *val = NULL;
  uint64_t pixel_base = 0;
  for (uint32_t a = 0; a < lm->atlas_count; a++) {
    const ub_atlas *at = &lm->atlases[a];
    uint32_t x0 = UINT32_MAX, y0 = UINT32_MAX, x1 = 0, y1 = 0, m = 0;
    for (uint32_t i = 0; i < nkept; i++) {
      uint32_t t = kept[i];
      if (lm->texel_atlas[t] != a)
        continue;
      uint32_t x = lm->texel_xy[2 * t], y = lm->texel_xy[2 * t + 1];
      x0 = x < x0 ? x : x0;
      y0 = y < y0 ? y : y0;
      x1 = x > x1 ? x : x1;
      y1 = y > y1 ? y : y1;
      m++;
    }
    if (m == 0) {
      pixel_base += (uint64_t)at->width * at->height;
      continue;
    }
    x0 = x0 >= UB_DILATE_RINGS ? x0 - UB_DILATE_RINGS : 0;
    y0 = y0 >= UB_DILATE_RINGS ? y0 - UB_DILATE_RINGS : 0;
    x1 = x1 + UB_DILATE_RINGS < at->width ? x1 + UB_DILATE_RINGS : at->width - 1;
    y1 = y1 + UB_DILATE_RINGS < at->height ? y1 + UB_DILATE_RINGS : at->height - 1;
    uint32_t w = x1 - x0 + 1, h = y1 - y0 + 1;
    float *img = calloc((size_t)w * h * 12, sizeof(float));
    uint8_t *cov = calloc((size_t)w * h, 1);
    if (!img || !cov) {
      free(img);
      free(cov);
      free(idx);
      free(val);
      return UB_ERR_OUT_OF_MEMORY;
    }
    /* Covered texels of the window (kept or not: an unkept covered texel holds 0). */
    for (uint32_t y = y0; y <= y1; y++)
      for (uint32_t x = x0; x <= x1; x++)
        cov[(size_t)(y - y0) * w + (x - x0)] = at->texel_of[(size_t)y * at->width + x] >= 0;
    for (uint32_t i = 0; i < nkept; i++) {
      uint32_t t = kept[i];
      if (lm->texel_atlas[t] != a)
        continue;
      uint32_t x = lm->texel_xy[2 * t], y = lm->texel_xy[2 * t + 1];
      memcpy(img + 12 * ((size_t)(y - y0) * w + (x - x0)), sh + 12 * (size_t)t,
             12 * sizeof(float));
    }
    ub_lightmap_dilate(img, cov, w, h, 12, UB_DILATE_RINGS);
    for (uint32_t y = 0; y < h; y++)
      for (uint32_t x = 0; x < w; x++) {
        const float *v = img + 12 * ((size_t)y * w + x);
        int nz = 0;
        for (int k = 0; k < 12; k++)
          nz |= v[k] != 0.0f;
        if (!nz)
          continue;
        if (n == cap) {
          cap = cap ? 2 * cap : 1024;
          uint32_t *ni = realloc(idx, cap * sizeof *idx);
          float *nv = ni ? realloc(val, cap * 12 * sizeof *val) : NULL;
          if (ni)
            idx = ni;
          if (!ni || !nv) {
            free(img);
            free(cov);
            free(idx);
            free(val);
            return UB_ERR_OUT_OF_MEMORY;
          }
          val = nv;
        }
        idx[n] = (uint32_t)(pixel_base + (uint64_t)(y + y0) * at->width + (x + x0));
        memcpy(val + 12 * n, v, 12 * sizeof(float));
        n++;
      }
    free(img);
    free(cov);
    pixel_base += (uint64_t)at->width * at->height;
  }
  rec->texel_count = (uint32_t)n;
  rec->texel_index = idx;
  rec->texel_sh = val;
  return UB_OK;
}

ub_result ub_dls_bake(const ub_pass_desc *base, const ub_plan *plan, const ub_log *log,
                      ub_bakefile_record **out_records, ub_dls_stats *out_stats)
{
  const ub_scene *s = base->scene;
  const ub_lightmap *lm = base->lightmap;
  memset(out_stats, 0, sizeof *out_stats);
  *out_records = NULL;
  if (s->dls_count == 0)
    return UB_OK;
  ub_bakefile_record *recs = calloc(s->dls_count, sizeof *recs);
  uint8_t *enabled = calloc(s->light_count ? s->light_count : 1, 1);
  uint32_t *kt = malloc(((size_t)lm->texel_count + 1) * sizeof *kt);
  uint32_t *kp = malloc(((size_t)base->probe_count + 1) * sizeof *kp);
  for (uint32_t d = 0; recs && d < s->dls_count; d++) {
    recs[d].kind = UB_ELEMENT_DLS;
    recs[d].parent[0] = recs[d].parent[1] = -1;
  }
  uint32_t nlp = base->llg ? base->llg->probe_count : 0; /* LLG probes */
  uint32_t *kl = malloc(((size_t)nlp + 1) * sizeof *kl);
  if (!recs || !enabled || !kt || !kp || !kl) {
    free(recs);
    free(enabled);
    free(kt);
    free(kp);
    free(kl);
    return UB_ERR_OUT_OF_MEMORY;
  }
  ub_result r = UB_OK;
  for (uint32_t d = 0; d < s->dls_count && r == UB_OK; d++) {
    ub_bakefile_record *rec = &recs[d];
    snprintf(rec->name, sizeof rec->name, "%s", s->dls_names[d]);
    uint32_t reaching = 0;
    double lum_sum = 0.0;
    for (uint32_t l = 0; l < s->light_count; l++) {
      const ub_light *L = &s->lights[l];
      enabled[l] = L->dls == (int32_t)d && plan->dls_light_reaches[l];
      if (L->dls == (int32_t)d) {
        rec->light_count++;
        lum_sum += 0.2126 * L->intensity[0] + 0.7152 * L->intensity[1] +
                   0.0722 * L->intensity[2];
      }
      reaching += enabled[l];
    }
    rec->mean_intensity = rec->light_count ? (float)(lum_sum / rec->light_count) : 0.0f;
    if (!reaching) {
      out_stats->sets_empty++;
      ub_log_printf(log, UB_LOG_INFO, "  dls %-16s: %u light(s) reach no receiver: skipped",
                    rec->name, rec->light_count);
      continue;
    }
    /* 1. Influence: direct + 2 bounces at a low sample count over every receiver. */
    ub_pass_desc pd = *base;
    pd.light_enabled = enabled;
    pd.emissive = 0;
    pd.sky = 0;
    pd.gather_rays = plan->influence_rays;
    pd.probe_rays = 2 * plan->influence_rays;
    pd.shadow_samples = 1;
    pd.bounces = 2;
    pd.pass_id = 2 + 2 * d;
    pd.texel_subset = NULL;
    pd.probe_subset = NULL;
    pd.llg_subset = NULL;
    pd.progress = NULL;
    double t0 = now_s();
    ub_pass_result inf;
    r = ub_pass_run(&pd, NULL, &inf);
    if (r != UB_OK)
      break;
    out_stats->rays_influence += inf.rays_gather + inf.rays_shadow;
    out_stats->seconds_influence += now_s() - t0;
    double ind_sum = 0.0;
    uint64_t lit = 0;
    for (uint32_t t = 0; t < lm->texel_count; t++)
      if (inf.texel_direct[t] > 0.0f) {
        ind_sum += inf.texel_indirect[t];
        lit++;
      }
    double thr = lit ? UB_DLS_INFLUENCE_FRACTION * ind_sum / lit : 0.0;
    uint32_t nkt = 0, nkp = 0, nkl = 0;
    /* --plan all keeps every receiver (no culling), to measure what culling drops. */
    for (uint32_t t = 0; t < lm->texel_count; t++)
      if (!plan->influence_culling || inf.texel_direct[t] > 0.0f || inf.texel_indirect[t] > thr)
        kt[nkt++] = t;
    for (uint32_t q = 0; q < base->probe_count; q++)
      if (!plan->influence_culling || inf.probe_direct[q] > 0.0f || inf.probe_indirect[q] > thr)
        kp[nkp++] = q;
    /* LLG probes: the GLG probes' rule (they are points in free space too). */
    for (uint32_t q = 0; q < nlp; q++)
      if (!plan->influence_culling || inf.llg_direct[q] > 0.0f || inf.llg_indirect[q] > thr)
        kl[nkl++] = q;
    ub_pass_result_free(&inf);
    if (nkt == 0 && nkp == 0 && nkl == 0) {
      out_stats->sets_empty++;
      ub_log_printf(log, UB_LOG_INFO, "  dls %-16s: no receiver above the threshold: skipped",
                    rec->name);
      continue;
    }
    /* 2. Full quality, only for the kept receivers. */
    pd = *base;
    pd.light_enabled = enabled;
    pd.emissive = 0;
    pd.sky = 0;
    pd.pass_id = 3 + 2 * d;
    pd.texel_subset = kt;
    pd.texel_subset_count = nkt;
    pd.probe_subset = kp;
    pd.probe_subset_count = nkp;
    pd.llg_subset = kl;
    pd.llg_subset_count = nkl;
    pd.progress = NULL;
    t0 = now_s();
    ub_pass_result full;
    r = ub_pass_run(&pd, NULL, &full);
    if (r != UB_OK)
      break;
    out_stats->rays_full += full.rays_gather + full.rays_shadow;
    out_stats->seconds_full += now_s() - t0;
    r = ub_dls_texel_record(lm, kt, nkt, full.sh, rec);
    if (r == UB_OK && nkp) {
      rec->probe_index = malloc((size_t)nkp * sizeof *rec->probe_index);
      rec->probe_sh = malloc((size_t)nkp * 27 * sizeof *rec->probe_sh);
      if (!rec->probe_index || !rec->probe_sh) {
        r = UB_ERR_OUT_OF_MEMORY;
      } else {
        rec->probe_count = nkp;
        for (uint32_t i = 0; i < nkp; i++) {
          rec->probe_index[i] = kp[i];
          memcpy(rec->probe_sh + 27 * (size_t)i, full.probe_sh + 27 * (size_t)kp[i],
                 27 * sizeof(float));
        }
      }
    }
    if (r == UB_OK && nkl) {
      rec->llg_probe_index = malloc((size_t)nkl * sizeof *rec->llg_probe_index);
      rec->llg_probe_sh = malloc((size_t)nkl * 27 * sizeof *rec->llg_probe_sh);
      if (!rec->llg_probe_index || !rec->llg_probe_sh) {
        r = UB_ERR_OUT_OF_MEMORY;
      } else {
        rec->llg_probe_count = nkl;
        for (uint32_t i = 0; i < nkl; i++) {
          rec->llg_probe_index[i] = kl[i];
          memcpy(rec->llg_probe_sh + 27 * (size_t)i, full.llg_sh + 27 * (size_t)kl[i],
                 27 * sizeof(float));
        }
      }
    }
    ub_pass_result_free(&full);
    if (r != UB_OK)
      break;
    out_stats->sets_baked++;
    out_stats->texels_kept += nkt;
    out_stats->probes_kept += nkp;
    ub_log_printf(log, UB_LOG_INFO,
                  "  dls %-16s: %u light(s), %u of %u texels, %u of %u probes and %u of %u "
                  "LLG probes in its influence (threshold %.3g W/m²), record %u pixels",
                  rec->name, reaching, nkt, lm->texel_count, nkp, base->probe_count, nkl, nlp,
                  thr, rec->texel_count);
  }
  free(enabled);
  free(kt);
  free(kp);
  free(kl);
  if (r != UB_OK) {
    ub_dls_records_free(recs, s->dls_count);
    return r;
  }
  *out_records = recs;
  return UB_OK;
}
