/* lightmaps/lightmap.h — lightmap atlases, texel receivers and their sample points.
 *
 * ub_lightmap_build() decides every lightmapped triangle's atlas and lightmap UV
 * (TEXCOORD_1 where the triangle has it, else generated charts packed with padding at the
 * node's texel size), rasterises triangles conservatively into texels, and places up to
 * UB_TEXEL_SAMPLES sample points inside each covered texel's footprint, moved off back
 * faces (a texel at a wall/floor junction never sees through the wall).
 * Lifecycle: build → use → ub_lightmap_free (NULL-safe). Read-only after build; any
 * number of threads may read it.
 */
#ifndef UBAKE_LIGHTMAPS_LIGHTMAP_H
#define UBAKE_LIGHTMAPS_LIGHTMAP_H

#include <stdint.h>

#include "ubake/scene.h"
#include "bake/rt.h"

#define UB_TEXEL_SAMPLES 4
#define UB_ATLAS_MAX_SIZE 4096
/* Texels the lightmapped surfaces may ask for (their area over the texel size squared,
 * summed): 64 Mi, ~25× the ESTATE-scale level. A bake holds a few hundred bytes a texel
 * (~20-30 GB here), so beyond it a typo in --texel-size or ubake_texel_size (1e-4 for
 * 1e-1) would run out of memory after minutes instead of being told at once. */
#define UB_LM_MAX_TEXELS (64.0 * 1024 * 1024)

typedef struct ub_atlas {
  uint32_t width, height;   /* texels */
  int generated;            /* 0: authored TEXCOORD_1, 1: generated charts */
  uint32_t first_texel;     /* texels of this atlas are [first_texel, first_texel+texel_count) */
  uint32_t texel_count;
  int32_t *texel_of;        /* width × height: index of the covered texel there, -1 = empty */
  uint8_t *link;            /* width × height, or NULL: UB_LINK_X / UB_LINK_Y set where the
                               texel is separated from its +x / +y neighbour by geometry
                               (runtime/texel_links.h) */
} ub_atlas;

typedef struct ub_lightmap {
  uint32_t atlas_count;
  ub_atlas *atlases;

  int32_t *tri_atlas;       /* triangle_count: atlas index, -1 = not lightmapped */
  float *tri_uv;            /* triangle_count × 3 × 2: lightmap UV per corner in [0,1] of its atlas */

  /* Covered texels (receivers), atlas by atlas, row-major inside an atlas. */
  uint32_t texel_count;
  uint32_t *texel_atlas;    /* texel_count */
  uint32_t *texel_xy;       /* texel_count × 2: x, y in the atlas */
  uint32_t *texel_tri;      /* texel_count: triangle giving the texel's normal/material */
  float *texel_pos;         /* texel_count × 3: centre of the texel on the surface, world */
  float *texel_normal;      /* texel_count × 3: unit shading normal */
  float *sample_pos;        /* texel_count × UB_TEXEL_SAMPLES × 3: sample points, world,
                               already off back faces; unused slots repeat earlier ones */
  float *texel_area;        /* texel_count: world area (m²) of the surface whose lightmap UV
                               falls in the texel's pixel, what a ray hitting it reads as this
                               texel; less than the square's at a chart's edge */
  uint32_t backface_fixes;  /* sample points moved off a back face */
  uint32_t overlap_texels;  /* texels claimed by triangles of different planes (warned) */
  uint32_t separated_links; /* neighbour pairs separated by geometry (atlas link bits set) */

  /* Added by the lightmaps module: generated charts (for tests and debug views). */
  uint32_t chart_count;
  int32_t *tri_chart;       /* triangle_count: generated chart index, -1 = authored/none */
} ub_lightmap;

/* default_texel_size: metres per texel where neither node nor level says (e.g. 0.25). */
ub_result ub_lightmap_build(const ub_scene *scene, const ub_rt *rt, float default_texel_size,
                            const ub_log *log, ub_lightmap **out_lightmap);
void ub_lightmap_free(ub_lightmap *lm);

/* Fills padding texels (texel_of == -1) of a per-texel-of-atlas image from their covered
 * neighbours, `passes` rings deep, so bilinear filtering shows no dark seams.
 * image: width × height × channels floats; covered: width × height (non-zero = covered). */
void ub_lightmap_dilate(float *image, const uint8_t *covered, uint32_t width, uint32_t height,
                        uint32_t channels, uint32_t passes);
/* Which dilation pass fills each pixel: level (width × height) holds 0 for covered pixels
 * and anything else for the rest on entry; on return 0 covered, k for the pixels that pass
 * k of ub_lightmap_dilate(…, rings) fills (1 ≤ k ≤ rings), rings + 1 for the others. */
void ub_lightmap_dilate_levels(uint8_t *level, uint32_t width, uint32_t height, uint8_t rings);

/* Bilinear lookup at lightmap UV (u, v) of atlas `atlas` in a per-atlas image of
 * width × height × 4 floats (rgb + a coverage weight): only covered texels count, weighted
 * by their coverage; 0 when none around. Used by every pass that reads stored lighting. */
void ub_lightmap_image_sample(const ub_lightmap *lm, const float *img, uint32_t atlas, float u,
                              float v, float out[3]);

/* Fills atlas `atlas`'s image (width × height × 4: rgb, coverage 1 on covered texels)
 * from per-texel irradiance (texel_count × 3: izf floats, or izd doubles when izf is
 * NULL; both NULL: zero light), zero elsewhere, then dilates it 2 rings so bilinear lookups see no dark seams.
 * Returns 0 when the dilation's scratch could not be allocated (image filled, not
 * dilated). */
int ub_lightmap_image_fill(const ub_lightmap *lm, uint32_t atlas, const float *izf,
                           const double *izd, float *img);

/* A sparse refill of an atlas image for a pass whose light lives at a few texels (a
 * set's subset pass): built once for the texels act[0..n) (ascending, any atlases; the
 * others are taken as 0), it makes the image ub_lightmap_image_fill would make from those
 * texels' values, bit for bit, by writing the full fill of zero light once
 * (ub_lightmap_sparse_init: coverage and the dilated rings) and then, per refill, only
 * the act texels' pixels and the dilated pixels next to them (1 ring) and next to those
 * (2nd ring), each summed over its neighbours in the dilation's order. */
typedef struct ub_lightmap_sparse {
  uint32_t atlas;
  uint32_t n0, n1, n2;  /* act texels in this atlas, ring-1 and ring-2 pixels to recompute */
  uint32_t *t0;         /* n0 texels */
  uint32_t *px;         /* n0 + n1 + n2 pixels: the texels', ring 1's, ring 2's */
  uint8_t *level;       /* per pixel: 0 covered, 1 / 2 dilated in that ring, 3 neither */
  int own_level;        /* level is this struct's (else the caller's base_level) */
} ub_lightmap_sparse;
/* The zero-light fill of an atlas (img: width × height × 4) and its pixels' levels (as
 * ub_lightmap_sparse.level); what every sparse init starts from, so passes may share it.
 * Returns 0 when out of memory. */
int ub_lightmap_sparse_base(const ub_lightmap *lm, uint32_t atlas, float *img, uint8_t *level);
/* Returns 0 when out of memory (sp zeroed; use ub_lightmap_image_fill). img: the atlas's
 * image, written with the zero-light fill (copied from base_img with base_level, both
 * from ub_lightmap_sparse_base and kept while sp lives, or computed when they are NULL;
 * base_img NULL with base_level: img holds that fill already, as a pass's image does
 * after restoring the pixels it refilled, ub_lightmap_sparse_restore). */
int ub_lightmap_sparse_init(const ub_lightmap *lm, uint32_t atlas, const uint32_t *act,
                            uint32_t n, const float *base_img, const uint8_t *base_level,
                            float *img, ub_lightmap_sparse *sp);
void ub_lightmap_sparse_fill(const ub_lightmap *lm, const ub_lightmap_sparse *sp,
                             const double *izd, float *img);
/* Puts back base_img's values at the pixels sp's refills write: img is then the
 * zero-light fill again, ready for another sparse init. */
void ub_lightmap_sparse_restore(const ub_lightmap_sparse *sp, const float *base_img, float *img);
void ub_lightmap_sparse_free(ub_lightmap_sparse *sp);

/* World point of texel t at (fx, fy) ∈ [0,1]² of its footprint, on its owning triangle's
 * plane (affine UV → world map; points past the triangle's edges stay in its plane).
 * Returns 1 for a point on the triangle, 2 for one past its edges (maybe past the
 * chart's, off any surface: at a chart's edge part of the square lies beyond it), 0 (out
 * unspecified) for a degenerate UV triangle or a non-finite result. */
int ub_lightmap_texel_point(const ub_scene *s, const ub_lightmap *lm, uint32_t t, float fx,
                            float fy, float out[3]);

#endif
