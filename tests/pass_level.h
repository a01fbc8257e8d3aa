/* tests/pass_level.h — a generated test level opened for ub_pass_run directly (scene in
 * its base state, ray tracer, lightmap, emitters), for the tests that drive passes
 * without a whole bake (header-only). */
#ifndef UBAKE_TESTS_PASS_LEVEL_H
#define UBAKE_TESTS_PASS_LEVEL_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bake/geomstate.h"
#include "bake/lights.h"
#include "bake/pass.h"
#include "test_util.h"
#include "ubake/scene.h"

typedef struct level {
  ub_scene *s;
  uint8_t *mask;
  ub_rt *rt;
  ub_lightmap *lm;
  ub_emitters *em;
} level;

static inline void level_close(level *L)
{
  ub_emitters_free(L->em);
  ub_lightmap_free(L->lm);
  ub_rt_free(L->rt);
  free(L->mask);
  ub_scene_free(L->s);
}

/* BUILD/levels/NAME.gltf; 0 (and nothing held) when the level cannot be opened. */
static inline int level_open(const char *build, const char *name, level *L)
{
  char path[1024];
  memset(L, 0, sizeof *L);
  snprintf(path, sizeof path, "%s/levels/%s.gltf", build, name);
  ASSERT_OK(ub_scene_load(path, NULL, &L->s));
  if (!L->s)
    return 0;
  ASSERT_OK(ub_geom_prepare(L->s, NULL, NULL));
  L->mask = ub_geom_mask(L->s, NULL);
  ASSERT_OK(ub_rt_create(L->s, L->mask, NULL, &L->rt));
  if (L->rt)
    ASSERT_OK(ub_lightmap_build(L->s, L->rt, L->s->texel_size, NULL, &L->lm));
  if (L->rt)
    ASSERT_OK(ub_emitters_build(L->s, &L->em));
  if (L->rt && L->lm && L->em)
    return 1;
  level_close(L);
  return 0;
}

/* A pass description over L's base state with the tests' usual sampling: 64 gather rays,
 * 16 emissive and 4 shadow samples, 2 bounces, seed 3, pass 1; en: light_count bytes. */
static inline void level_desc_init(const level *L, const uint8_t *en, ub_pass_desc *pd)
{
  memset(pd, 0, sizeof *pd);
  pd->scene = L->s;
  pd->rt = L->rt;
  pd->emitters = L->em;
  pd->lightmap = L->lm;
  pd->light_enabled = en;
  pd->gather_rays = 64;
  pd->emissive_samples = 16;
  pd->shadow_samples = 4;
  pd->bounces = 2;
  pd->seed = 3;
  pd->pass_id = 1;
}

#endif
