/* doors/guide.h — guided gather directions toward boxes, combined with cosine (or uniform
 * sphere) sampling by multiple importance sampling.
 *
 * A box is an oriented bounding box (OBB). Sampling a box = a point uniform in its volume,
 * the direction from the shading point x toward it. The solid-angle pdf of a direction w
 * under that strategy is exact and cheap: the points along the ray x + t·w inside the box
 * are [t0, t1] (t0 ≥ 0), and p(w) = ∫ t² dt / V = (t1³ − t0³) / (3V). A thin portal is a
 * box with a small minimum thickness (UB_OBB_MIN_HALF), so V > 0 always.
 *
 * A guide mixes strategies: cosine about the normal (or uniform sphere for a point
 * receiver) with probability c_0 and each box j with probability c_j (Σ c = 1). One
 * direction is drawn from the mixture; its pdf is Σ c_j p_j(w), i.e. one-sample MIS with
 * the balance heuristic (Veach 1997, §9.2.4): the weight of strategy j for w is
 * c_j p_j(w) / Σ c_k p_k(w), and those weights sum to one for every w. The estimator
 * f(w) / pdf(w) is unbiased as long as the cosine/sphere strategy has c_0 > 0 wherever f
 * can be non-zero; ub_guide_init enforces c_0 ≥ UB_GUIDE_MIN_COSINE.
 */
#ifndef UBAKE_DOORS_GUIDE_H
#define UBAKE_DOORS_GUIDE_H

#include <stdint.h>

#define UB_OBB_MIN_HALF 1e-3f   /* metres: the thinnest half extent of a sampled box */
#define UB_GUIDE_MAX_BOXES 16
#define UB_GUIDE_MIN_COSINE 0.1

typedef struct ub_obb {
  float c[3];       /* centre, world metres */
  float axis[3][3]; /* orthonormal rows */
  float h[3];       /* half extents along the axes, ≥ UB_OBB_MIN_HALF */
} ub_obb;

/* The OBB of n points: axes by principal components (or axis-aligned when the spread is
 * degenerate), half extents grown by margin and clamped to ≥ UB_OBB_MIN_HALF. Returns 0
 * (out untouched) for n == 0 or non-finite input. */
int ub_obb_fit(const float *pts, uint32_t n, float margin, ub_obb *out);
/* An OBB from a centre, axes and half extents (clamped to ≥ UB_OBB_MIN_HALF). */
void ub_obb_make(const float c[3], const float axis[3][3], const float h[3], ub_obb *out);
double ub_obb_volume(const ub_obb *b);
/* Interval of the ray o + t·w (w unit) inside the box, t ≥ 0. Returns 0 if empty. */
int ub_obb_ray(const ub_obb *b, const float o[3], const float w[3], float *t0, float *t1);
/* Uniform point in the box from three uniforms in [0,1). */
void ub_obb_point(const ub_obb *b, const float u[3], float out[3]);
/* Solid-angle pdf at x of direction w (unit) when sampling a uniform point in the box. */
double ub_obb_pdf(const ub_obb *b, const float x[3], const float w[3]);
int ub_obb_contains(const ub_obb *b, const float p[3]);

typedef struct ub_guide {
  uint32_t box_count;
  ub_obb box[UB_GUIDE_MAX_BOXES];
  double prob[UB_GUIDE_MAX_BOXES + 1]; /* [0]: cosine/sphere, [1 + j]: box j; Σ = 1 */
} ub_guide;

/* cosine_prob: the share of the cosine/sphere strategy (clamped to
 * [UB_GUIDE_MIN_COSINE, 1]); box_weight: relative weights of the boxes (NULL = equal),
 * non-finite or negative weights count as 0. At most UB_GUIDE_MAX_BOXES boxes. */
void ub_guide_init(ub_guide *g, const ub_obb *boxes, uint32_t box_count,
                   const double *box_weight, double cosine_prob);
/* A direction at x for a receiver with unit normal n (NULL: point receiver, uniform
 * sphere) from four uniforms in [0,1). Returns the mixture pdf (> 0), or 0 when the draw
 * is unusable (a box direction below the receiver's horizon): the caller then counts
 * the sample as zero — still unbiased, the pdf is the mixture's. */
double ub_guide_sample(const ub_guide *g, const float x[3], const float n[3], const float u[4],
                       float out_w[3]);
/* The mixture pdf of direction w at x (0 below the horizon of n). */
double ub_guide_pdf(const ub_guide *g, const float x[3], const float n[3], const float w[3]);
/* Balance-heuristic weight of strategy s (0 = cosine/sphere, 1 + j = box j) for w. */
double ub_guide_weight(const ub_guide *g, uint32_t s, const float x[3], const float n[3],
                       const float w[3]);

#endif
