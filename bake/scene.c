/* bake/scene.c — the C side of ub_scene: release and derived quantities.
 * Loading lives in gltf_load.cpp (the one file that knows glTF). */
#include "ubake/scene.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static void free_names(char **names, uint32_t count)
{
  if (!names)
    return;
  for (uint32_t i = 0; i < count; i++)
    free(names[i]);
  free(names);
}

void ub_scene_free(ub_scene *scene)
{
  if (!scene)
    return;
  free(scene->path);
  free(scene->positions);
  free(scene->normals);
  free(scene->uv1);
  free(scene->indices);
  free(scene->tri_material);
  free(scene->tri_node);
  free(scene->tri_flags);
  if (scene->materials)
    for (uint32_t i = 0; i < scene->material_count; i++)
      free(scene->materials[i].name);
  free(scene->materials);
  if (scene->nodes)
    for (uint32_t i = 0; i < scene->node_count; i++)
      free(scene->nodes[i].name), free(scene->nodes[i].combine);
  free(scene->nodes);
  free(scene->lights);
  free_names(scene->dls_names, scene->dls_count);
  free_names(scene->door_names, scene->door_count);
  free_names(scene->object_names, scene->object_count);
  free(scene);
}

float ub_scene_extent(const ub_scene *scene)
{
  if (!scene || scene->triangle_count == 0)
    return 0.0f;
  float e = 0.0f;
  for (int i = 0; i < 3; i++) {
    float d = scene->bounds_max[i] - scene->bounds_min[i];
    if (d > e)
      e = d;
  }
  return e;
}

double ub_scene_area(const ub_scene *scene)
{
  if (!scene)
    return 0.0;
  double sum = 0.0;
  for (uint32_t t = 0; t < scene->triangle_count; t++) {
    if (scene->tri_flags[t] & UB_TRI_DEGENERATE)
      continue;
    const float *a = scene->positions + 3 * (size_t)scene->indices[3 * (size_t)t];
    const float *b = scene->positions + 3 * (size_t)scene->indices[3 * (size_t)t + 1];
    const float *c = scene->positions + 3 * (size_t)scene->indices[3 * (size_t)t + 2];
    double e1[3], e2[3];
    for (int i = 0; i < 3; i++) {
      e1[i] = (double)b[i] - a[i];
      e2[i] = (double)c[i] - a[i];
    }
    double x = e1[1] * e2[2] - e1[2] * e2[1];
    double y = e1[2] * e2[0] - e1[0] * e2[2];
    double z = e1[0] * e2[1] - e1[1] * e2[0];
    sum += 0.5 * sqrt(x * x + y * y + z * z);
  }
  return sum;
}

int ub_combine_next(const char *list, size_t *pos, size_t *start, size_t *len)
{
  const char *p = list + *pos;
  while (*p == ',' || *p == ' ')
    p++;
  size_t n = strcspn(p, ",");
  size_t m = n;
  while (m && p[m - 1] == ' ')
    m--;
  if (!m)
    return 0;
  *start = (size_t)(p - list);
  *len = m;
  *pos = *start + n;
  return 1;
}
