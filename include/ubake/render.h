/* ubake/render.h — the run-time preview renderer: the picture an artist checks.
 *
 * What it is: a small ray tracer over a loaded bake (ubake/runtime.h), with its own BVH
 * (no Embree). Per pixel: a primary ray to the closest triangle; front faces are shaded
 * diffuse, radiance = albedo/π × irradiance, where irradiance is
 *   - the baked lightmap at the hit's lightmap UV (decoded AHD, for the geometric normal)
 *     on lightmapped triangles, else the global light grid just above the hit (props),
 *     else nothing;
 *   - plus the run-time direct light of the PRIMARY punctual lights (KHR_lights_punctual
 *     falloff, range window, spot cones) with a shadow ray, each scaled by the RGB weight
 *     of its dynamic light set (the state). Static lights' direct light is in the bake.
 * Back faces reflect nothing (as in the baker) and render black; rays that hit nothing
 * are black. Output is linear radiance, W/(m²·sr), RGB; ub_render_tonemap() makes 8-bit
 * sRGB from it.
 *
 * Lifecycle: ub_bvh_build() → queries → ub_bvh_free(); ub_renderer_create() (builds the
 * BVH of the bake's triangles) → ub_renderer_render()… → ub_renderer_free(). Free
 * functions accept NULL; a failed create allocates nothing and leaves *out untouched.
 * Ownership: a renderer borrows its runtime, which must outlive it.
 * Thread safety: after building, BVH queries and ub_renderer_render() take const objects
 * and may run on any number of threads at once (e.g. one band of rows per thread), as
 * long as nobody changes the runtime's state meanwhile.
 */
#ifndef UBAKE_RENDER_H
#define UBAKE_RENDER_H

#include <stdint.h>

#include "ubake/error.h"
#include "ubake/runtime.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- BVH over a triangle soup -------------------------------------------------------- */

typedef struct ub_bvh ub_bvh;

typedef struct ub_bvh_hit {
  float t;       /* ray parameter of the hit (metres for a unit direction) */
  float b1, b2;  /* barycentrics of corners 1 and 2 (corner 0: 1 − b1 − b2) */
  uint32_t tri;  /* triangle index */
} ub_bvh_hit;

/* Binned-SAH BVH over triangle_count triangles (indices: 3 per triangle, each
 * < vertex_count; positions: vertex_count × 3, finite, metres). Zero triangles is valid
 * (every ray misses). Errors: UB_ERR_INVALID_ARGUMENT (index out of range, non-finite
 * position, too many triangles), UB_ERR_OUT_OF_MEMORY. */
ub_result ub_bvh_build(const float *positions, uint32_t vertex_count, const uint32_t *indices,
                       uint32_t triangle_count, ub_bvh **out_bvh);
void ub_bvh_free(ub_bvh *bvh);
/* Closest hit with t in (0, tmax) of the ray org + t·dir (dir need not be unit; both
 * sides of a triangle count). Returns 1 and fills out_hit, or 0 (out_hit untouched). */
int ub_bvh_intersect(const ub_bvh *bvh, const float org[3], const float dir[3], float tmax,
                     ub_bvh_hit *out_hit);
/* Any hit with t in (0, tmax): 1 if the segment is blocked. */
int ub_bvh_occluded(const ub_bvh *bvh, const float org[3], const float dir[3], float tmax);
/* Nodes and the depth of the deepest leaf (for reports). */
void ub_bvh_stats(const ub_bvh *bvh, uint32_t *out_nodes, uint32_t *out_depth);

/* ---- renderer ------------------------------------------------------------------------ */

typedef struct ub_renderer ub_renderer;

typedef struct ub_render_params {
  float eye[3];         /* camera position, world, metres */
  float target[3];      /* a point the camera looks at, ≠ eye; Y is up */
  float fovy_degrees;   /* vertical field of view, in (0, 180); typical: 60 */
  uint32_t width, height; /* image size, pixels, each 1..16384; typical 960 × 540 */
  uint32_t samples;     /* rays per pixel along each axis (n × n grid), at most 16; 0 or
                           1: one ray */
  /* RGB weight of each dynamic light set (bakefile dls_count × 3) applied to the direct
   * light of its primary lights; NULL = every set at weight 1. Lights in no set: 1. */
  const float *dls_weights;
} ub_render_params;

/* Sets eye (0,0,0), target (0,0,-1), 60°, 960 × 540, one sample, all sets at 1. */
void ub_render_params_default(ub_render_params *out_params);

/* Builds the BVH of rt's triangles shown in its current state (ub_runtime_triangle_shown:
 * door leaves and objects as of the last update). It keeps them: after an update that
 * moved a door or showed or hid an object, create the renderer again (the hidden leaf
 * would render black, the new one not at all). log: messages during this call only. */
ub_result ub_renderer_create(const ub_runtime *rt, const ub_log *log, ub_renderer **out);
void ub_renderer_free(ub_renderer *r);
const ub_bvh *ub_renderer_bvh(const ub_renderer *r);

/* Renders rows [row_begin, row_end) (row 0 at the top) of the image described by params
 * into out_rgb, the WHOLE image's buffer (width × height × 3 floats, radiance
 * W/(m²·sr)); other rows are not touched, so threads may render disjoint bands into one
 * buffer. Every value written is finite and ≥ 0. A view straight up or down is fine (the
 * image's up is then −Z or +Z). Errors (nothing written, one message to log, may be
 * NULL): UB_ERR_INVALID_ARGUMENT for a non-finite camera, eye == target, a field of view
 * outside (0, 180), a size out of range, rows out of range, or a non-finite / negative
 * DLS weight. */
ub_result ub_renderer_render(const ub_renderer *r, const ub_render_params *params,
                             uint32_t row_begin, uint32_t row_end, float *out_rgb,
                             const ub_log *log);

/* What the camera sees, for telling a black image's cause: of a grid × grid lattice of
 * primary rays over the image (pixel-centre rays of a grid × grid image with the same
 * field of view and aspect), the fractions that hit a front face, a back face (rendered
 * black, as the baker reflects nothing there) and nothing. They sum to 1. A camera inside
 * a wall or outside a closed level sees mostly back faces. grid: 2..1024 (32 is 1024
 * rays, well under a millisecond on a game level). Errors as ub_renderer_render
 * (params; a grid out of range: UB_ERR_INVALID_ARGUMENT), nothing written. */
typedef struct ub_render_view {
  float front, back, miss;
} ub_render_view;
ub_result ub_renderer_view(const ub_renderer *r, const ub_render_params *params, uint32_t grid,
                           ub_render_view *out_view, const ub_log *log);

/* Checks params as ub_renderer_render() does (log: the message, may be NULL). */
ub_result ub_render_params_check(const ub_render_params *params, uint32_t dls_count,
                                 const ub_log *log);

/* ---- tone map ------------------------------------------------------------------------ */

/* Linear radiance (width × height × 3) → 8-bit sRGB (width × height × 3). Exposure:
 * pixels are scaled by 2^exposure_ev before the curve (ACES filmic fit, Narkowicz 2015)
 * and the sRGB transfer. If auto_exposure, exposure_ev is ignored and chosen so that the
 * 95th percentile of the luminance of the lit pixels (> 0) lands at a fixed mid-high
 * grey; *out_ev (may be NULL) receives the EV used. Non-finite pixels become black. */
/* UB_ERR_INVALID_ARGUMENT for a non-finite exposure_ev (without auto_exposure),
 * UB_ERR_OUT_OF_MEMORY (auto exposure's sort); nothing written then. */
ub_result ub_render_tonemap(const float *rgb, uint32_t width, uint32_t height,
                            int auto_exposure, float exposure_ev, uint8_t *out_srgb,
                            float *out_ev);

#ifdef __cplusplus
}
#endif
#endif
