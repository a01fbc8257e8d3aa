/* tests/fuzz/fuzz_gltf.c — libFuzzer target for the glTF adapter (ub_scene_load_memory).
 * Seeds: tests/fuzz/corpus-fuzz_gltf, written by tests/fuzz/make_corpus_gltf.py from the
 * generated levels (.gltf with the buffer as a base64 data: URI, or packed .glb) plus the
 * hand-written glTF files of tests/data. Regression inputs: tests/fuzz/regress-fuzz_gltf (replayed
 * by test_fuzz_regress in the normal build).
 * Any input must be accepted or rejected without a crash, a leak, undefined behaviour, a
 * filesystem access or a huge allocation. An accepted scene must satisfy what scene.h
 * promises downstream code (indices in range, finite positions, unit normals, materials
 * in range), so the fuzzer also checks those invariants.
 * Note: tinygltf, stb_image and nlohmann-json come precompiled from Debian (not
 * instrumented); coverage counts our adapter's code only. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "ubake/scene.h"

static void check_scene(const ub_scene *s)
{
  for (uint32_t t = 0; t < s->triangle_count; t++) {
    for (int k = 0; k < 3; k++)
      if (s->indices[3 * (size_t)t + k] >= s->vertex_count)
        abort();
    if (s->tri_material[t] >= s->material_count || s->tri_node[t] >= s->node_count)
      abort();
  }
  for (uint32_t v = 0; v < s->vertex_count; v++) {
    const float *p = s->positions + 3 * (size_t)v, *n = s->normals + 3 * (size_t)v;
    if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
      abort();
    double l = (double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2];
    if (!(fabs(l - 1.0) < 1e-3))
      abort();
  }
  for (uint32_t m = 0; m < s->material_count; m++)
    for (int c = 0; c < 3; c++) {
      float a = s->materials[m].albedo[c], e = s->materials[m].emission[c];
      if (!(a >= 0.0f && a <= 0.999f) || !(e >= 0.0f) || !isfinite(e))
        abort();
    }
  for (uint32_t l = 0; l < s->light_count; l++) {
    const ub_light *L = &s->lights[l];
    for (int c = 0; c < 3; c++)
      if (!isfinite(L->position[c]) || !isfinite(L->direction[c]) ||
          !(L->intensity[c] >= 0.0f) || !isfinite(L->intensity[c]))
        abort();
  }
  if (!isfinite(ub_scene_extent(s)) || !isfinite(ub_scene_area(s)))
    abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
  ub_scene *scene = NULL;
  if (ub_scene_load_memory(data, size, "fuzz.gltf", NULL, &scene) == UB_OK) {
    check_scene(scene);
    ub_scene_free(scene);
  }
  return 0;
}
