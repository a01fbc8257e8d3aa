/* runtime/texel_links.h — which texels of a bilinear 2×2 block a lightmap lookup blends.
 *
 * A floor texel next to a closed door leaf or a wall standing on the floor spans both
 * sides: the texel beyond the leaf is lit, the one inside is dark, and plain bilinear
 * filtering between them carries the outside light up to half a texel into the room
 * (sunroom, door closed: 1.6 W/m² 5 cm inside the leaf, where the room reads 0.003). So
 * the baker stores one link byte per atlas pixel (ub_bakefile.texel_link): bit 0 set =
 * the texel and its +x neighbour are separated by geometry (the segment between their
 * sample points, lifted off the surface, is blocked), bit 1 = the same toward +y.
 * A lookup keeps the block's texel nearest to it and the texels joined to that one by
 * open links inside the block; the others get weight 0 and the rest are renormalised.
 * Where nothing separates texels the result is plain bilinear filtering; across a
 * separation it is continuous on either side and steps where the texel footprints meet,
 * at the wall. No links (NULL): all four texels. Header-only: the baker's lightmap reads
 * (lightmaps/sample.c) and the run-time's (runtime/runtime.c) share the rule; a GPU
 * shader can do the same with the links as an R8 texture.
 */
#ifndef UBAKE_RUNTIME_TEXEL_LINKS_H
#define UBAKE_RUNTIME_TEXEL_LINKS_H

#include <stdint.h>

#define UB_LINK_X 1u /* separated from the +x neighbour */
#define UB_LINK_Y 2u /* separated from the +y neighbour */

/* Mask of the block's texels to blend: bit k for texel (x0 + (k & 1), y0 + (k >> 1)),
 * coordinates clamped to the atlas like the lookup's; (tx, ty) in [0, 1]: the lookup's
 * position inside the block. link: w × h bytes, or NULL. */
static inline unsigned ub_texel_links_keep(const uint8_t *link, int64_t w, int64_t h,
                                           int64_t x0, int64_t y0, float tx, float ty)
{
  if (!link)
    return 15u;
  int64_t xa = x0 < 0 ? 0 : (x0 >= w ? w - 1 : x0);
  int64_t xb = x0 + 1 < 0 ? 0 : (x0 + 1 >= w ? w - 1 : x0 + 1);
  int64_t ya = y0 < 0 ? 0 : (y0 >= h ? h - 1 : y0);
  int64_t yb = y0 + 1 < 0 ? 0 : (y0 + 1 >= h ? h - 1 : y0 + 1);
  /* open edges of the block: 0-1, 2-3 (along x), 0-2, 1-3 (along y) */
  int o01 = xa == xb || !(link[ya * w + xa] & UB_LINK_X);
  int o23 = xa == xb || !(link[yb * w + xa] & UB_LINK_X);
  int o02 = ya == yb || !(link[ya * w + xa] & UB_LINK_Y);
  int o13 = ya == yb || !(link[ya * w + xb] & UB_LINK_Y);
  unsigned keep = 1u << ((tx >= 0.5f ? 1u : 0u) | (ty >= 0.5f ? 2u : 0u));
  for (int it = 0; it < 2; it++) {
    if (o01 && (keep & 3u))
      keep |= 3u;
    if (o23 && (keep & 12u))
      keep |= 12u;
    if (o02 && (keep & 5u))
      keep |= 5u;
    if (o13 && (keep & 10u))
      keep |= 10u;
  }
  return keep;
}

#endif
