/* probes/llg.h — local light grids, baker side (UberBake §2.2; evaluation: ubake/llg.h).
 *
 * Which models: mesh nodes with ub_node.receiver == UB_RECEIVER_LLG: tagged
 * `ubake_receiver: "llg"`, or untagged small props whose lightmap charts would be poor,
 * switched by ub_llg_auto_select() (criterion in probes/llg_auto.c). Per model:
 *   - box: the principal axes of its vertices (PCA) or the world axes, whichever box is
 *     smaller (also the world axes when PCA is degenerate), padded by 10% + 5 cm per side;
 *   - grid: probes on the box corners and evenly in between, about one per
 *     UB_LLG_SPACING metres along each axis, 2..UB_LLG_MAX_DIM per axis;
 *   - probes: baked by the same series-expansion pass as every receiver, but their rays
 *     see the level WITHOUT the LLG models (ub_llg_set.rt_env): a probe stores the light of
 *     the model's surroundings, and the model's own occlusion lives only in the per-vertex
 *     visibility (no double counting; probes inside the model's solid parts are valid).
 *     Probes inside other geometry (e.g. under the floor the model stands on: most of
 *     their rays hit back faces) are baked at the first free spot toward the box centre
 *     (+4 cm) and used at their grid position; one that finds none is invalid and takes
 *     the mean of its valid grid neighbours after each bounce (ub_llg_fill_invalid);
 *   - self-visibility per vertex: rays over the normal's hemisphere against the model's
 *     own triangles only (its own Embree scene), projected to SH L2 as V = 1 − O (O the
 *     occluded directions), so an unoccluded vertex has V ≡ 1 exactly. Instances of one
 *     glTF mesh share it (UberBake §2.2): a model whose node uses the same mesh as an
 *     earlier model, with the same local vertices and triangles, and whose transform
 *     differs from it by a similarity (rotation or reflection, uniform scale,
 *     translation; checked on every vertex and normal), takes the earlier model's V
 *     rotated by R (ub_llg_sh_rotation) instead of tracing rays, and the .ubk stores V
 *     once (docs/FORMAT.md, LLGM);
 *   - self-inter-reflection per vertex (ub_llg_self_bounce, after the pass): the
 *     irradiance along the vertex normal that the model's own surfaces reflect onto it —
 *     exactly the directions V removes. Cosine rays against the model's own triangles; at
 *     each hit the model's radiance is albedo/π × (its LLG irradiance, grid × V, + the
 *     primary lights' direct light by shadow rays against the whole level + the hit's own
 *     self term of the previous iteration); UB_LLG_SELF_ITERATIONS iterations. Static
 *     lights' direct light is already in the grid. (UberBake shares V between instances;
 *     S depends on the instance's lighting, so it is per model instance, like the grid.)
 *     During the pass, before S exists, gather rays that hit an LLG model read grid × V.
 * Deterministic: rays are hashes of (seed, model, vertex/probe, ray).
 * Lifecycle: ub_llg_build() fills a ub_llg_set; ub_llg_free() releases it (NULL-safe).
 */
#ifndef UBAKE_PROBES_LLG_H
#define UBAKE_PROBES_LLG_H

#include <stdint.h>

#include "bake/rt.h"
#include "ubake/scene.h"

#define UB_LLG_SPACING 0.3f /* metres between probes, before clamping */
#define UB_LLG_MAX_DIM 8u
#define UB_LLG_PAD_REL 0.1f
#define UB_LLG_PAD_ABS 0.05f /* metres */

typedef struct ub_llg_model {
  uint32_t node;           /* scene node */
  float center[3], axes[9], half[3];
  uint32_t dims[3];
  uint32_t probe_first;    /* index of its first probe in ub_llg_set.probe_pos */
  uint32_t vertex_count;
  uint32_t *vertices;      /* sorted scene vertex indices */
  float *vis;              /* vertex_count × 9: self-visibility SH L2 */
  uint32_t vis_source;     /* model whose visibility this one carries along (itself when
                              traced here; an earlier instance of the same mesh otherwise) */
  float vis_rot[9];        /* row-major orthogonal R: vis(ω) = vis_source's (Rᵀω) */
  float *self;             /* vertex_count × 3: self-inter-reflection irradiance, W/m² */
  ub_rt *rt_self;          /* the model's own triangles */
  uint32_t triangle_count; /* the node's triangles, degenerate ones included */
  uint32_t *local_indices; /* triangle_count × 3, < vertex_count */
} ub_llg_model;

typedef struct ub_llg_set {
  uint32_t model_count;
  ub_llg_model *models;
  int32_t *node_model;     /* node_count: model index or -1 */
  uint32_t probe_count;
  float *probe_pos;        /* probe_count × 3 */
  uint8_t *probe_valid;    /* probe_count */
  uint32_t invalid_count;   /* inside geometry, no free spot toward the centre: filled */
  uint32_t moved_count;     /* inside geometry, moved toward the centre to a free spot */
  uint32_t vis_shared;      /* models whose visibility is an earlier instance's, rotated */
  ub_rt *rt_env;           /* the level without LLG models (NULL when model_count == 0) */
  uint64_t rays;           /* visibility + validity rays traced */
} ub_llg_set;

/* vis_rays: rays per vertex over the sphere (those in the normal's hemisphere are
 * traced), e.g. 256. */
ub_result ub_llg_build(const ub_scene *scene, uint32_t vis_rays, uint32_t seed,
                       const ub_log *log, ub_llg_set *out);
void ub_llg_free(ub_llg_set *set);

/* LLG by default for small props (probes/llg_auto.c has the reasoning). */
#define UB_LLG_AUTO_TEXELS_PER_CHART 8.0 /* covered texels per chart below this: poor */
#define UB_LLG_AUTO_TINY_CHART 4u        /* a chart covering ≤ this many texels is tiny */
#define UB_LLG_AUTO_TINY_SHARE 0.5       /* more than this share of tiny charts: poor */
#define UB_LLG_AUTO_MAX_SIZE ((float)(UB_LLG_MAX_DIM - 1u) * UB_LLG_SPACING) /* metres */

typedef struct ub_llg_auto_stats {
  uint32_t considered;   /* untagged nodes with generated charts, small enough */
  uint32_t switched;     /* of those, made LLG receivers (receiver_source UB_RECEIVER_AUTO) */
  uint64_t texels_freed; /* their covered texels in the layout that was measured */
  uint32_t charts_freed;
} ub_llg_auto_stats;

struct ub_lightmap;
/* Makes untagged small props with poor lightmap charts LLG receivers, measured on lm (the
 * layout built with every untagged node lightmapped). The caller rebuilds the lightmap
 * when out->switched > 0. */
ub_result ub_llg_auto_select(ub_scene *scene, const struct ub_lightmap *lm,
                             ub_llg_auto_stats *out);

#define UB_LLG_SELF_ITERATIONS 3

/* Fills every model's self term. llg_sh: the baked LLG probes (probe_count × 27);
 * rt_full: the whole level (shadow rays); light_enabled: the pass's lights (primary ones
 * are added at the hits); rays: cosine rays per vertex. Deterministic for any thread
 * count. */
ub_result ub_llg_self_bounce(ub_llg_set *set, const ub_scene *scene, const ub_rt *rt_full,
                             const float *llg_sh, const uint8_t *light_enabled, uint32_t rays,
                             uint32_t seed);

/* Invalid probes take the mean of their valid (or already filled) grid neighbours,
 * repeated until every probe of a model with a valid probe is filled. sh: probe_count × 27. */
void ub_llg_fill_invalid(const ub_llg_set *set, float *sh);

/* Irradiance (W/m², ≥ 0) at a hit on triangle tri (barycentrics u, v of corners 1, 2) at
 * world point p, seen by a ray with direction dir, from the LLG probes' SH probe_sh
 * (probe_count × 27): grid × visibility + self term, shading normal facing the ray. Returns 0
 * (out untouched) when tri is not on an LLG model. */
int ub_llg_hit_irradiance(const ub_llg_set *set, const ub_scene *scene, const float *probe_sh,
                          uint32_t tri, float u, float v, const float p[3], const float dir[3],
                          float out_rgb[3]);

#endif
