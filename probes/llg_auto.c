/* probes/llg_auto.c — LLG by default for small props whose lightmap charts would be poor
 * (ub_llg_auto_select, see llg.h).
 *
 * The criterion is measured on the lightmap layout the bake would use (covered texels and
 * generated charts of ub_lightmap_build), not guessed from the mesh:
 *   - texels per chart: the node's covered texels / its charts < UB_LLG_AUTO_TEXELS_PER_CHART
 *     (a prop a few texels across: its charts are mostly padding and show no gradient), or
 *   - many small charts: more than UB_LLG_AUTO_TINY_SHARE of its charts cover at most
 *     UB_LLG_AUTO_TINY_CHART texels (2 × 2: no interior texel, bilinear filtering blends it
 *     with padding; e.g. a fence of thin bars, a pile of small pieces);
 * and the node must be small enough for one grid at the LLG spacing: every side of its
 * world bounding box ≤ UB_LLG_AUTO_MAX_SIZE = (UB_LLG_MAX_DIM − 1) × UB_LLG_SPACING, so a
 * large mesh with poor charts (a whole level exported as one node) stays lightmapped.
 * Only nodes without an explicit `ubake_receiver` (ub_node.receiver_source ==
 * UB_RECEIVER_DEFAULT) with generated charts are considered: a tag always wins, authored
 * lightmap UVs (TEXCOORD_1) are the artist's choice, and door leaves, semi-dynamic objects
 * and emissive nodes keep their lightmap (their records and shading assume one).
 */
#include "probes/llg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "lightmaps/lightmap.h"

static int node_eligible(const ub_scene *s, const ub_lightmap *lm, uint32_t n)
{
  const ub_node *nd = &s->nodes[n];
  if (nd->receiver != UB_RECEIVER_LIGHTMAP || nd->receiver_source != UB_RECEIVER_DEFAULT ||
      nd->door >= 0 || nd->door_open >= 0 || nd->semidynamic >= 0 || !nd->triangle_count)
    return 0;
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  uint32_t live = 0;
  for (uint32_t t = nd->first_triangle; t < nd->first_triangle + nd->triangle_count; t++) {
    if (s->tri_flags[t] & UB_TRI_DEGENERATE)
      continue;
    if ((s->tri_flags[t] & UB_TRI_HAS_UV1) || lm->tri_chart[t] < 0)
      return 0; /* authored UVs, or not laid out by the chart generator */
    const float *em = s->materials[s->tri_material[t]].emission;
    if (em[0] > 0.0f || em[1] > 0.0f || em[2] > 0.0f)
      return 0;
    for (int k = 0; k < 3; k++) {
      const float *p = s->positions + 3 * (size_t)s->indices[3 * (size_t)t + k];
      for (int a = 0; a < 3; a++) {
        lo[a] = fminf(lo[a], p[a]);
        hi[a] = fmaxf(hi[a], p[a]);
      }
    }
    live++;
  }
  if (!live)
    return 0;
  for (int a = 0; a < 3; a++)
    if (!(hi[a] - lo[a] <= UB_LLG_AUTO_MAX_SIZE))
      return 0;
  return 1;
}

ub_result ub_llg_auto_select(ub_scene *s, const ub_lightmap *lm, ub_llg_auto_stats *out)
{
  memset(out, 0, sizeof *out);
  if (!s->node_count || !lm || !lm->tri_chart)
    return UB_OK;
  uint32_t nc = lm->chart_count;
  uint32_t *chart_texels = calloc((size_t)nc + 1, sizeof *chart_texels);
  int32_t *chart_node = malloc(((size_t)nc + 1) * sizeof *chart_node);
  uint8_t *eligible = calloc(s->node_count, 1);
  uint32_t *node_charts = calloc(s->node_count, sizeof *node_charts);
  uint32_t *node_tiny = calloc(s->node_count, sizeof *node_tiny);
  uint64_t *node_texels = calloc(s->node_count, sizeof *node_texels);
  ub_result r = UB_ERR_OUT_OF_MEMORY;
  if (!chart_texels || !chart_node || !eligible || !node_charts || !node_tiny || !node_texels)
    goto done;
  for (uint32_t c = 0; c < nc; c++)
    chart_node[c] = -1;
  for (uint32_t t = 0; t < s->triangle_count; t++) {
    int32_t c = lm->tri_chart[t];
    if (c >= 0 && (uint32_t)c < nc)
      chart_node[c] = (int32_t)s->tri_node[t];
  }
  for (uint32_t x = 0; x < lm->texel_count; x++) {
    int32_t c = lm->tri_chart[lm->texel_tri[x]];
    if (c >= 0 && (uint32_t)c < nc)
      chart_texels[c]++;
  }
  for (uint32_t n = 0; n < s->node_count; n++)
    eligible[n] = (uint8_t)node_eligible(s, lm, n);
  /* Per node: charts, their covered texels, tiny charts (charts never span nodes:
   * lightmaps/charts.c grows them within one node). */
  for (uint32_t c = 0; c < nc; c++) {
    int32_t n = chart_node[c];
    if (n < 0 || !eligible[n])
      continue;
    node_charts[n]++;
    node_texels[n] += chart_texels[c];
    node_tiny[n] += chart_texels[c] <= UB_LLG_AUTO_TINY_CHART;
  }
  for (uint32_t n = 0; n < s->node_count; n++) {
    if (!eligible[n] || !node_charts[n])
      continue;
    out->considered++;
    double per_chart = (double)node_texels[n] / node_charts[n];
    int poor = per_chart < UB_LLG_AUTO_TEXELS_PER_CHART ||
               node_tiny[n] > UB_LLG_AUTO_TINY_SHARE * node_charts[n];
    if (!poor)
      continue;
    s->nodes[n].receiver = UB_RECEIVER_LLG;
    s->nodes[n].receiver_source = UB_RECEIVER_AUTO;
    out->switched++;
    out->texels_freed += node_texels[n];
    out->charts_freed += node_charts[n];
  }
  r = UB_OK;
done:
  free(chart_texels);
  free(chart_node);
  free(eligible);
  free(node_charts);
  free(node_tiny);
  free(node_texels);
  return r;
}
