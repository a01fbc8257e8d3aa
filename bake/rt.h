/* bake/rt.h — the Embree wrapper: one robust static scene, batched ray queries.
 *
 * Lifecycle: ub_rt_create() builds a BVH over the scene's non-degenerate triangles for
 * which include(tri) is true (NULL mask: all); ub_rt_free() releases it (NULL-safe).
 * Thread safety: after creation every query function may be called from any number of
 * threads at once. Each query call sets FTZ/DAZ on the calling thread (DESIGN §6).
 * Primitive ids in hits are the scene's triangle indices.
 */
#ifndef UBAKE_BAKE_RT_H
#define UBAKE_BAKE_RT_H

#include <stdint.h>

#include "ubake/scene.h"

#define UB_RT_MISS 0xFFFFFFFFu

typedef struct ub_rt ub_rt;

typedef struct ub_ray {
  float org[3];
  float tnear;  /* metres, usually 0: the origin is offset instead (ub_rt_offset_point) */
  float dir[3]; /* need not be unit; t is in units of |dir| */
  float tfar;   /* INFINITY for an unbounded ray */
} ub_ray;

typedef struct ub_hit {
  uint32_t tri; /* scene triangle index, UB_RT_MISS on a miss */
  float t;
  float u, v;   /* barycentrics of vertices 1 and 2 (Embree convention) */
  float ng[3];  /* unnormalised geometric normal, front side = counter-clockwise winding */
} ub_hit;

/* mask: NULL, or triangle_count bytes, non-zero = include the triangle. */
ub_result ub_rt_create(const ub_scene *scene, const uint8_t *mask, const ub_log *log,
                       ub_rt **out_rt);
void ub_rt_free(ub_rt *rt);

/* Closest hits for n rays (any n; traced in coherent streams internally). */
void ub_rt_intersect(const ub_rt *rt, const ub_ray *rays, uint32_t n, ub_hit *out_hits);
/* The same for rays the caller sorted into runs of like directions from nearby origins
 * (the gathers' direction buckets): with at least UB_RT_COHERENT_MIN of them Embree is
 * told they are coherent and traces them as packets. The same hit triangles as
 * ub_rt_intersect, t and barycentrics within float rounding (test_rt: test_sorted). */
#define UB_RT_COHERENT_MIN 4096u
void ub_rt_intersect_sorted(const ub_rt *rt, const ub_ray *rays, uint32_t n, ub_hit *out_hits);
/* Any-hit: out_occluded[i] = 1 if something lies in (tnear, tfar). */
void ub_rt_occluded(const ub_rt *rt, const ub_ray *rays, uint32_t n, uint8_t *out_occluded);
/* The same for rays the caller grouped by target (a light's shadow rays from a block of
 * nearby receivers): traced as packets (Embree's coherent flag). The same answers as
 * ub_rt_occluded but for rays grazing an edge (test_rt: test_occluded_sorted). */
void ub_rt_occluded_sorted(const ub_rt *rt, const ub_ray *rays, uint32_t n,
                           uint8_t *out_occluded);

/* Ray origin offset for a point p on a surface with unit normal n (pointing to the side
 * the ray leaves from): p + n × eps, with eps relative to |p| and the level's extent so
 * a room 10 km from the origin has no self-intersection acne. */
void ub_rt_offset_point(const ub_rt *rt, const float p[3], const float n[3], float out[3]);
float ub_rt_epsilon(const ub_rt *rt, const float p[3]);

/* Counters (rays traced since creation, summed across threads). */
uint64_t ub_rt_rays_traced(const ub_rt *rt);
/* Triangles with another in their plane facing the other way (a wall two rooms share,
 * each with its own face): where a back-face hit on one is traced again for the front. */
uint64_t ub_rt_twin_count(const ub_rt *rt);

const ub_scene *ub_rt_scene(const ub_rt *rt);

#endif
