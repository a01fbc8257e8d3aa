/* Geometry states: the base state and per-element variants (see geomstate.h). */
#include "bake/geomstate.h"

#include <stdlib.h>
#include <string.h>

ub_result ub_geom_prepare(ub_scene *s, const ub_log *log, uint32_t **out_orig_material)
{
  if (out_orig_material)
    *out_orig_material = NULL;
  uint32_t *orig = malloc(((size_t)s->triangle_count + 1) * sizeof *orig);
  if (!orig)
    return UB_ERR_OUT_OF_MEMORY;
  memcpy(orig, s->tri_material, (size_t)s->triangle_count * sizeof *orig);

  /* Closed leaves keep their albedo and become lightmap receivers (pinned: the automatic
   * LLG switch of small props skips them), so the base bakes the light they bounce (S_C)
   * and the door pass reads it back. A leaf tagged `ubake_receiver: none` stays black:
   * nothing would store S_C. Open poses are never receivers. */
  uint32_t black_tris = 0;
  for (uint32_t n = 0; n < s->node_count; n++) {
    ub_node *nd = &s->nodes[n];
    if (nd->door < 0 && nd->door_open < 0)
      continue;
    if (nd->door >= 0) {
      if (nd->receiver == UB_RECEIVER_NONE && nd->receiver_source == UB_RECEIVER_TAGGED) {
        black_tris += nd->triangle_count;
        continue;
      }
      if (nd->receiver == UB_RECEIVER_LLG && nd->receiver_source == UB_RECEIVER_TAGGED &&
          nd->triangle_count)
        ub_log_printf(log, UB_LOG_WARNING, "%s: node '%s' is a closed door leaf: it is "
                      "lightmapped (its ubake_receiver: llg is ignored; the door pass reads "
                      "the light it bounces from its lightmap)", s->path, nd->name);
      nd->receiver = UB_RECEIVER_LIGHTMAP;
      nd->receiver_source = UB_RECEIVER_TAGGED;
      continue;
    }
    if (nd->receiver != UB_RECEIVER_NONE && nd->receiver_source == UB_RECEIVER_TAGGED &&
        nd->triangle_count)
      ub_log_printf(log, UB_LOG_WARNING, "%s: node '%s' is a door leaf's open pose: its "
                    "ubake_receiver tag is ignored (it moves; its own shading comes from the "
                    "GLG)", s->path, nd->name);
    nd->receiver = UB_RECEIVER_NONE;
  }
  if (black_tris) {
    ub_material *m = realloc(s->materials, ((size_t)s->material_count + 1) * sizeof *m);
    if (!m) {
      free(orig);
      return UB_ERR_OUT_OF_MEMORY;
    }
    s->materials = m;
    ub_material *black = &m[s->material_count];
    memset(black, 0, sizeof *black);
    black->name = strdup("closed door leaf without a lightmap (black in the base bake)");
    if (!black->name) {
      free(orig);
      return UB_ERR_OUT_OF_MEMORY;
    }
    uint32_t bi = s->material_count++;
    for (uint32_t n = 0; n < s->node_count; n++) {
      const ub_node *nd = &s->nodes[n];
      if (nd->door < 0 || nd->receiver != UB_RECEIVER_NONE)
        continue;
      for (uint32_t t = nd->first_triangle; t < nd->first_triangle + nd->triangle_count; t++)
        s->tri_material[t] = bi;
    }
  }
  if (out_orig_material)
    *out_orig_material = orig;
  else
    free(orig);
  return UB_OK;
}

uint8_t *ub_geom_mask(const ub_scene *s, const ub_geom_state *st)
{
  uint8_t *mask = malloc((size_t)s->triangle_count + 1);
  if (!mask)
    return NULL;
  memset(mask, 1, (size_t)s->triangle_count);
  for (uint32_t n = 0; n < s->node_count; n++) {
    const ub_node *nd = &s->nodes[n];
    int present = 1;
    if (nd->door >= 0)
      present = !(st && st->door_open && st->door_open[nd->door]);
    else if (nd->door_open >= 0)
      present = st && st->door_open && st->door_open[nd->door_open];
    if (nd->semidynamic >= 0 && st && st->object_shown && !st->object_shown[nd->semidynamic])
      present = 0;
    if (!present)
      memset(mask + nd->first_triangle, 0, nd->triangle_count);
  }
  return mask;
}

uint32_t ub_geom_door_triangles(const ub_scene *s, uint32_t door, int open_pose)
{
  uint32_t c = 0;
  for (uint32_t n = 0; n < s->node_count; n++) {
    const ub_node *nd = &s->nodes[n];
    if ((open_pose ? nd->door_open : nd->door) == (int32_t)door)
      c += nd->triangle_count;
  }
  return c;
}
