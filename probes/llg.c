/* probes/llg.c — local light grids: boxes, probe placement, self-visibility (see llg.h). */
#include "probes/llg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bake/lights.h"
#include "ubake/llg.h"
#include "ubake/sh.h"

#define UB_LLG_VALID_RAYS 64
#define UB_LLG_BACKFACE_FRACTION 0.3 /* more back-face hits than this: probe inside geometry */

static int cmp_u32(const void *a, const void *b)
{
  uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
  return x < y ? -1 : x > y;
}

/* Eigenvectors of a symmetric 3×3 matrix by cyclic Jacobi rotations; rows of out_v. */
static void jacobi3(double a[3][3], double out_v[3][3])
{
  double v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  for (int sweep = 0; sweep < 32; sweep++) {
    double off = fabs(a[0][1]) + fabs(a[0][2]) + fabs(a[1][2]);
    if (off < 1e-18)
      break;
    for (int p = 0; p < 2; p++)
      for (int q = p + 1; q < 3; q++) {
        if (fabs(a[p][q]) < 1e-30)
          continue;
        double th = 0.5 * atan2(2.0 * a[p][q], a[q][q] - a[p][p]);
        double c = cos(th), s = sin(th);
        for (int k = 0; k < 3; k++) { /* A ← A·J */
          double akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (int k = 0; k < 3; k++) { /* A ← Jᵀ·A */
          double apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (int k = 0; k < 3; k++) { /* V ← V·J (columns are eigenvectors) */
          double vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
  }
  for (int i = 0; i < 3; i++)
    for (int k = 0; k < 3; k++)
      out_v[i][k] = v[k][i];
}

/* Box of the points along orthonormal axes (rows): centre, half extents, volume. */
static double fit_box(const ub_scene *s, const uint32_t *vi, uint32_t n, const double ax[3][3],
                      float out_c[3], float out_h[3])
{
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (uint32_t i = 0; i < n; i++) {
    const float *p = s->positions + 3 * (size_t)vi[i];
    for (int a = 0; a < 3; a++) {
      double d = ax[a][0] * p[0] + ax[a][1] * p[1] + ax[a][2] * p[2];
      lo[a] = fmin(lo[a], d);
      hi[a] = fmax(hi[a], d);
    }
  }
  double vol = 1.0;
  for (int k = 0; k < 3; k++)
    out_c[k] = 0.0f;
  for (int a = 0; a < 3; a++) {
    double m = 0.5 * (lo[a] + hi[a]), h = 0.5 * (hi[a] - lo[a]);
    for (int k = 0; k < 3; k++)
      out_c[k] += (float)(ax[a][k] * m);
    out_h[a] = (float)h;
    vol *= fmax(h, 1e-3);
  }
  return vol;
}

static void model_box(const ub_scene *s, ub_llg_model *m)
{
  static const double world[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  double mean[3] = {0, 0, 0};
  for (uint32_t i = 0; i < m->vertex_count; i++)
    for (int k = 0; k < 3; k++)
      mean[k] += s->positions[3 * (size_t)m->vertices[i] + k];
  for (int k = 0; k < 3; k++)
    mean[k] /= m->vertex_count ? m->vertex_count : 1;
  double cov[3][3] = {{0}};
  for (uint32_t i = 0; i < m->vertex_count; i++) {
    const float *p = s->positions + 3 * (size_t)m->vertices[i];
    double d[3] = {p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]};
    for (int a = 0; a < 3; a++)
      for (int b = 0; b < 3; b++)
        cov[a][b] += d[a] * d[b];
  }
  double ax[3][3];
  jacobi3(cov, ax);
  int ok = 1;
  for (int a = 0; a < 3; a++)
    for (int k = 0; k < 3; k++)
      ok &= isfinite(ax[a][k]);
  /* Right-handed, re-orthonormalised: a2 = a0 × a1. */
  if (ok) {
    double l0 = sqrt(ax[0][0] * ax[0][0] + ax[0][1] * ax[0][1] + ax[0][2] * ax[0][2]);
    for (int k = 0; k < 3; k++)
      ax[0][k] /= l0;
    double d = ax[1][0] * ax[0][0] + ax[1][1] * ax[0][1] + ax[1][2] * ax[0][2];
    for (int k = 0; k < 3; k++)
      ax[1][k] -= d * ax[0][k];
    double l1 = sqrt(ax[1][0] * ax[1][0] + ax[1][1] * ax[1][1] + ax[1][2] * ax[1][2]);
    ok = l0 > 0.5 && l1 > 0.5;
    for (int k = 0; k < 3; k++)
      ax[1][k] /= l1;
    ax[2][0] = ax[0][1] * ax[1][2] - ax[0][2] * ax[1][1];
    ax[2][1] = ax[0][2] * ax[1][0] - ax[0][0] * ax[1][2];
    ax[2][2] = ax[0][0] * ax[1][1] - ax[0][1] * ax[1][0];
  }
  float cw[3], hw[3], cp[3], hp[3];
  double vw = fit_box(s, m->vertices, m->vertex_count, world, cw, hw);
  double vp = ok ? fit_box(s, m->vertices, m->vertex_count, (const double(*)[3])ax, cp, hp)
                 : INFINITY;
  /* PCA only when clearly tighter: a box-shaped prop keeps the world axes. */
  int use_pca = ok && vp < 0.9 * vw;
  for (int a = 0; a < 3; a++)
    for (int k = 0; k < 3; k++)
      m->axes[3 * a + k] = (float)(use_pca ? ax[a][k] : world[a][k]);
  memcpy(m->center, use_pca ? cp : cw, sizeof m->center);
  memcpy(m->half, use_pca ? hp : hw, sizeof m->half);
  for (int a = 0; a < 3; a++) {
    m->half[a] = m->half[a] * (1.0f + UB_LLG_PAD_REL) + UB_LLG_PAD_ABS;
    uint32_t n = (uint32_t)ceilf(2.0f * m->half[a] / UB_LLG_SPACING) + 1u;
    m->dims[a] = n < 2u ? 2u : (n > UB_LLG_MAX_DIM ? UB_LLG_MAX_DIM : n);
  }
}

static void sphere_dir(float u1, float u2, float out[3])
{
  float z = 1.0f - 2.0f * u1, r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
  float phi = 2.0f * (float)M_PI * u2;
  out[0] = r * cosf(phi);
  out[1] = z;
  out[2] = r * sinf(phi);
}

/* 3×3 inverse of a column-major linear part (world[3c + r]), into row-major out; 0 when
 * singular. */
static int inverse3(const float w[12], double out[3][3])
{
  double a[3][3];
  for (int r = 0; r < 3; r++)
    for (int c = 0; c < 3; c++)
      a[r][c] = w[3 * c + r];
  double det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) -
               a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0]) +
               a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
  if (!(fabs(det) > 1e-12) || !isfinite(det))
    return 0;
  for (int r = 0; r < 3; r++)
    for (int c = 0; c < 3; c++) {
      int r1 = (c + 1) % 3, r2 = (c + 2) % 3, c1 = (r + 1) % 3, c2 = (r + 2) % 3;
      out[r][c] = (a[r1][c1] * a[r2][c2] - a[r1][c2] * a[r2][c1]) / det;
    }
  return 1;
}

/* Can model j carry model i's self-visibility along? Instances of the same glTF mesh
 * (same local vertices and triangles) whose world transforms differ by a similarity:
 * L = A_j·A_i⁻¹ with LᵀL = σ²I; R = L/σ. Verified on every vertex (position within
 * UB_LLG_SHARE_TOL of the model's size, normal within UB_LLG_SHARE_TOL) so a loader quirk
 * or a hand-built scene never shares wrongly. */
#define UB_LLG_SHARE_TOL 1e-3
static int share_rotation(const ub_scene *s, const ub_llg_model *mi, const ub_llg_model *mj,
                          float out_R[9])
{
  const ub_node *ni = &s->nodes[mi->node], *nj = &s->nodes[mj->node];
  if (ni->mesh < 0 || ni->mesh != nj->mesh || mi->vertex_count != mj->vertex_count ||
      mi->triangle_count != mj->triangle_count ||
      memcmp(mi->local_indices, mj->local_indices,
             (size_t)mi->triangle_count * 3 * sizeof *mi->local_indices) != 0)
    return 0;
  double inv[3][3], L[3][3];
  if (!inverse3(ni->world, inv))
    return 0;
  for (int r = 0; r < 3; r++)
    for (int c = 0; c < 3; c++) {
      L[r][c] = 0.0;
      for (int k = 0; k < 3; k++)
        L[r][c] += (double)nj->world[3 * k + r] * inv[k][c];
    }
  double g[3][3], tr = 0.0;
  for (int r = 0; r < 3; r++)
    for (int c = 0; c < 3; c++) {
      g[r][c] = L[0][r] * L[0][c] + L[1][r] * L[1][c] + L[2][r] * L[2][c];
      tr += r == c ? g[r][c] : 0.0;
    }
  double s2 = tr / 3.0;
  if (!(s2 > 1e-12) || !isfinite(s2))
    return 0;
  for (int r = 0; r < 3; r++)
    for (int c = 0; c < 3; c++)
      if (fabs(g[r][c] - (r == c ? s2 : 0.0)) > 1e-4 * s2)
        return 0;
  double sig = sqrt(s2), R[3][3];
  for (int r = 0; r < 3; r++)
    for (int c = 0; c < 3; c++)
      R[r][c] = L[r][c] / sig;
  /* Every vertex: p_j = L·(p_i − t_i) + t_j, n_j = R·n_i. */
  double size = 0.0;
  for (int a = 0; a < 3; a++)
    size = fmax(size, 2.0 * mj->half[a]);
  double tol = UB_LLG_SHARE_TOL * (size > 0.0 ? size : 1.0);
  for (uint32_t v = 0; v < mi->vertex_count; v++) {
    const float *pi = s->positions + 3 * (size_t)mi->vertices[v];
    const float *pj = s->positions + 3 * (size_t)mj->vertices[v];
    const float *qi = s->normals + 3 * (size_t)mi->vertices[v];
    const float *qj = s->normals + 3 * (size_t)mj->vertices[v];
    double d[3] = {pi[0] - ni->world[9], pi[1] - ni->world[10], pi[2] - ni->world[11]};
    double ep = 0.0, en = 0.0;
    for (int r = 0; r < 3; r++) {
      double x = nj->world[9 + r] + L[r][0] * d[0] + L[r][1] * d[1] + L[r][2] * d[2];
      double y = R[r][0] * qi[0] + R[r][1] * qi[1] + R[r][2] * qi[2];
      ep += (x - pj[r]) * (x - pj[r]);
      en += (y - qj[r]) * (y - qj[r]);
    }
    if (!(sqrt(ep) <= tol) || !(sqrt(en) <= UB_LLG_SHARE_TOL))
      return 0;
  }
  for (int r = 0; r < 3; r++)
    for (int c = 0; c < 3; c++)
      out_R[3 * r + c] = (float)R[r][c];
  return 1;
}

/* Self-visibility of every vertex of model m against its own triangles (or, for an
 * instance of an earlier model, that model's rotated: no rays). */
static ub_result model_visibility(const ub_scene *s, ub_llg_set *set, ub_llg_model *m,
                                  uint32_t mi, uint32_t vis_rays, uint32_t seed,
                                  const ub_log *log, uint64_t *rays_out)
{
  uint8_t *mask = calloc(s->triangle_count ? s->triangle_count : 1, 1);
  if (!mask)
    return UB_ERR_OUT_OF_MEMORY;
  const ub_node *nd = &s->nodes[m->node];
  for (uint32_t t = 0; t < nd->triangle_count; t++)
    mask[nd->first_triangle + t] = 1;
  ub_result r = ub_rt_create(s, mask, log, &m->rt_self);
  free(mask);
  if (r != UB_OK)
    return r;
  m->vis_source = mi;
  for (int k = 0; k < 9; k++)
    m->vis_rot[k] = k % 4 == 0 ? 1.0f : 0.0f;
  memset(m->self, 0, (size_t)m->vertex_count * 3 * sizeof *m->self);
  for (uint32_t i = 0; i < mi; i++) {
    const ub_llg_model *src = &set->models[i];
    if (src->vis_source != i || !share_rotation(s, src, m, m->vis_rot))
      continue;
    float M[81];
    ub_llg_sh_rotation(m->vis_rot, M);
    for (uint32_t v = 0; v < m->vertex_count; v++)
      ub_llg_sh_rotate(M, src->vis + 9 * (size_t)v, m->vis + 9 * (size_t)v);
    m->vis_source = i;
    set->vis_shared++;
    return UB_OK;
  }
  uint32_t K = vis_rays ? vis_rays : 256;
  uint32_t kx = (uint32_t)sqrtf((float)K);
  if (kx < 1)
    kx = 1;
  uint32_t ky = K / kx;
  K = kx * ky;
  ub_ray *rays = malloc((size_t)K * sizeof *rays);
  float *dirs = malloc((size_t)K * 3 * sizeof *dirs);
  uint8_t *occ = malloc(K);
  if (!rays || !dirs || !occ) {
    free(rays);
    free(dirs);
    free(occ);
    return UB_ERR_OUT_OF_MEMORY;
  }
  uint64_t traced = 0;
  for (uint32_t i = 0; i < m->vertex_count; i++) {
    const float *p = s->positions + 3 * (size_t)m->vertices[i];
    const float *n = s->normals + 3 * (size_t)m->vertices[i];
    float org[3];
    ub_rt_offset_point(m->rt_self, p, n, org);
    uint32_t nr = 0;
    for (uint32_t j = 0; j < K; j++) {
      uint32_t h = ub_hash4(seed, 0x11100000u + mi, m->vertices[i], j);
      float u1 = ((float)(j % kx) + ub_u01(h)) / (float)kx;
      float u2 = ((float)(j / kx) + ub_u01(ub_hash4(h, 5, 0, 0))) / (float)ky;
      float w[3];
      sphere_dir(u1, u2, w);
      if (w[0] * n[0] + w[1] * n[1] + w[2] * n[2] <= 0.0f)
        continue;
      memcpy(rays[nr].org, org, sizeof org);
      memcpy(rays[nr].dir, w, sizeof w);
      memcpy(dirs + 3 * (size_t)nr, w, sizeof w);
      rays[nr].tnear = 0.0f;
      rays[nr].tfar = INFINITY;
      nr++;
    }
    ub_rt_occluded(m->rt_self, rays, nr, occ);
    traced += nr;
    double v[9] = {sqrt(4.0 * M_PI), 0, 0, 0, 0, 0, 0, 0, 0};
    for (uint32_t j = 0; j < nr; j++) {
      if (!occ[j])
        continue;
      float y[9];
      ub_sh2_eval_basis(dirs + 3 * (size_t)j, y);
      for (int k = 0; k < 9; k++)
        v[k] -= 4.0 * M_PI / K * y[k];
    }
    for (int k = 0; k < 9; k++)
      m->vis[9 * (size_t)i + k] = (float)v[k];
    m->self[3 * (size_t)i] = m->self[3 * (size_t)i + 1] = m->self[3 * (size_t)i + 2] = 0.0f;
  }
  *rays_out += traced;
  free(rays);
  free(dirs);
  free(occ);
  return UB_OK;
}

/* Fraction of a point's rays (against rt_env) that hit back faces. */
static double backface_fraction(ub_llg_set *set, const float p[3], uint32_t q, uint32_t seed)
{
  ub_ray rays[UB_LLG_VALID_RAYS];
  ub_hit hits[UB_LLG_VALID_RAYS];
  for (uint32_t j = 0; j < UB_LLG_VALID_RAYS; j++) {
    uint32_t h = ub_hash4(seed, 0x11200000u, q, j);
    memcpy(rays[j].org, p, 3 * sizeof(float));
    sphere_dir(((float)(j % 8) + ub_u01(h)) / 8.0f,
               ((float)(j / 8) + ub_u01(ub_hash4(h, 5, 0, 0))) / 8.0f, rays[j].dir);
    rays[j].tnear = 0.0f;
    rays[j].tfar = INFINITY;
  }
  ub_rt_intersect(set->rt_env, rays, UB_LLG_VALID_RAYS, hits);
  set->rays += UB_LLG_VALID_RAYS;
  uint32_t back = 0;
  for (uint32_t j = 0; j < UB_LLG_VALID_RAYS; j++)
    if (hits[j].tri != UB_RT_MISS && hits[j].ng[0] * rays[j].dir[0] +
                                             hits[j].ng[1] * rays[j].dir[1] +
                                             hits[j].ng[2] * rays[j].dir[2] > 0.0f)
      back++;
  return (double)back / UB_LLG_VALID_RAYS;
}

/* Probes inside other geometry (most of their rays against rt_env hit back faces, e.g.
 * under the floor the model stands on) move toward their box's centre in
 * UB_LLG_MOVE_STEP steps until they are out, plus UB_LLG_MOVE_MARGIN steps: they then
 * sample the light just above that surface, where the model's lower vertices are. A
 * probe that finds no free spot on the way is invalid (filled from its neighbours). */
#define UB_LLG_MOVE_STEP 0.02f
#define UB_LLG_MOVE_MARGIN 2
static void probe_validity(ub_llg_set *set, uint32_t seed)
{
  for (uint32_t mi = 0; mi < set->model_count; mi++) {
    const ub_llg_model *m = &set->models[mi];
    uint32_t np = m->dims[0] * m->dims[1] * m->dims[2];
    for (uint32_t q = m->probe_first; q < m->probe_first + np; q++) {
      float *p = set->probe_pos + 3 * (size_t)q;
      set->probe_valid[q] = 1;
      if (backface_fraction(set, p, q, seed) <= UB_LLG_BACKFACE_FRACTION)
        continue;
      float d[3] = {m->center[0] - p[0], m->center[1] - p[1], m->center[2] - p[2]};
      float len = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      uint32_t steps = len > 0.0f ? (uint32_t)(len / UB_LLG_MOVE_STEP) : 0;
      int found = -1;
      for (uint32_t k = 1; k <= steps; k++) {
        float t = (float)k * UB_LLG_MOVE_STEP / len, x[3];
        for (int c = 0; c < 3; c++)
          x[c] = p[c] + t * d[c];
        if (backface_fraction(set, x, q, seed) <= UB_LLG_BACKFACE_FRACTION) {
          found = (int)(k + UB_LLG_MOVE_MARGIN < steps ? k + UB_LLG_MOVE_MARGIN : k);
          break;
        }
      }
      if (found < 0) {
        set->probe_valid[q] = 0;
        set->invalid_count++;
        continue;
      }
      float t = (float)found * UB_LLG_MOVE_STEP / len;
      for (int c = 0; c < 3; c++)
        p[c] += t * d[c];
      set->moved_count++;
    }
  }
}

ub_result ub_llg_build(const ub_scene *s, uint32_t vis_rays, uint32_t seed, const ub_log *log,
                       ub_llg_set *out)
{
  memset(out, 0, sizeof *out);
  out->node_model = malloc((size_t)(s->node_count ? s->node_count : 1) * sizeof(int32_t));
  if (!out->node_model)
    return UB_ERR_OUT_OF_MEMORY;
  uint32_t nm = 0;
  for (uint32_t n = 0; n < s->node_count; n++) {
    out->node_model[n] = -1;
    if (s->nodes[n].receiver == UB_RECEIVER_LLG && s->nodes[n].triangle_count)
      out->node_model[n] = (int32_t)nm++;
  }
  if (nm == 0)
    return UB_OK;
  ub_result r = UB_ERR_OUT_OF_MEMORY;
  out->models = calloc(nm, sizeof *out->models);
  if (!out->models)
    goto fail;
  out->model_count = nm;
  for (uint32_t n = 0; n < s->node_count; n++) {
    if (out->node_model[n] < 0)
      continue;
    ub_llg_model *m = &out->models[out->node_model[n]];
    const ub_node *nd = &s->nodes[n];
    m->node = n;
    m->triangle_count = nd->triangle_count;
    uint32_t *all = malloc((size_t)nd->triangle_count * 3 * sizeof *all);
    m->local_indices = malloc((size_t)nd->triangle_count * 3 * sizeof *m->local_indices);
    if (!all || !m->local_indices) {
      free(all);
      goto fail;
    }
    memcpy(all, s->indices + 3 * (size_t)nd->first_triangle,
           (size_t)nd->triangle_count * 3 * sizeof *all);
    qsort(all, (size_t)nd->triangle_count * 3, sizeof *all, cmp_u32);
    uint32_t u = 0;
    for (size_t i = 0; i < (size_t)nd->triangle_count * 3; i++)
      if (i == 0 || all[i] != all[i - 1])
        all[u++] = all[i];
    m->vertices = all;
    m->vertex_count = u;
    for (size_t i = 0; i < (size_t)nd->triangle_count * 3; i++) {
      uint32_t sv = s->indices[3 * (size_t)nd->first_triangle + i];
      const uint32_t *f = bsearch(&sv, all, u, sizeof *all, cmp_u32);
      m->local_indices[i] = (uint32_t)(f - all);
    }
    m->vis = malloc((size_t)u * 9 * sizeof *m->vis);
    m->self = malloc((size_t)u * 3 * sizeof *m->self);
    if (!m->vis || !m->self)
      goto fail;
    model_box(s, m);
    m->probe_first = out->probe_count;
    out->probe_count += m->dims[0] * m->dims[1] * m->dims[2];
    r = model_visibility(s, out, m, (uint32_t)out->node_model[n], vis_rays, seed, log,
                         &out->rays);
    if (r != UB_OK)
      goto fail;
  }
  r = UB_ERR_OUT_OF_MEMORY;
  out->probe_pos = malloc((size_t)out->probe_count * 3 * sizeof *out->probe_pos);
  out->probe_valid = malloc(out->probe_count);
  if (!out->probe_pos || !out->probe_valid)
    goto fail;
  for (uint32_t i = 0; i < nm; i++) {
    const ub_llg_model *m = &out->models[i];
    for (uint32_t z = 0; z < m->dims[2]; z++)
      for (uint32_t y = 0; y < m->dims[1]; y++)
        for (uint32_t x = 0; x < m->dims[0]; x++) {
          size_t q = m->probe_first + ((size_t)z * m->dims[1] + y) * m->dims[0] + x;
          ub_llg_probe_position(m->center, m->axes, m->half, m->dims, x, y, z,
                                out->probe_pos + 3 * q);
        }
  }
  uint8_t *mask = malloc(s->triangle_count ? s->triangle_count : 1);
  if (!mask)
    goto fail;
  for (uint32_t t = 0; t < s->triangle_count; t++)
    mask[t] = out->node_model[s->tri_node[t]] < 0;
  r = ub_rt_create(s, mask, log, &out->rt_env);
  free(mask);
  if (r != UB_OK)
    goto fail;
  probe_validity(out, seed);
  return UB_OK;
fail:
  ub_llg_free(out);
  return r;
}

void ub_llg_free(ub_llg_set *set)
{
  if (!set)
    return;
  for (uint32_t i = 0; i < set->model_count; i++) {
    free(set->models[i].vertices);
    free(set->models[i].vis);
    free(set->models[i].self);
    ub_rt_free(set->models[i].rt_self);
    free(set->models[i].local_indices);
  }
  free(set->models);
  free(set->node_model);
  free(set->probe_pos);
  free(set->probe_valid);
  ub_rt_free(set->rt_env);
  memset(set, 0, sizeof *set);
}

void ub_llg_fill_invalid(const ub_llg_set *set, float *sh)
{
  if (!set || !set->invalid_count)
    return;
  uint8_t *filled = malloc(set->probe_count);
  uint8_t *next = malloc(set->probe_count);
  if (!filled || !next) {
    free(filled);
    free(next);
    return;
  }
  memcpy(filled, set->probe_valid, set->probe_count);
  for (uint32_t mi = 0; mi < set->model_count; mi++) {
    const ub_llg_model *m = &set->models[mi];
    uint32_t np = m->dims[0] * m->dims[1] * m->dims[2];
    for (uint32_t iter = 0; iter < 3 * UB_LLG_MAX_DIM; iter++) {
      int changed = 0;
      memcpy(next + m->probe_first, filled + m->probe_first, np);
      for (uint32_t z = 0; z < m->dims[2]; z++)
        for (uint32_t y = 0; y < m->dims[1]; y++)
          for (uint32_t x = 0; x < m->dims[0]; x++) {
            uint32_t q = m->probe_first + (z * m->dims[1] + y) * m->dims[0] + x;
            if (filled[q])
              continue;
            double acc[27] = {0};
            uint32_t cnt = 0;
            for (int dz = -1; dz <= 1; dz++)
              for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                  int64_t xx = (int64_t)x + dx, yy = (int64_t)y + dy, zz = (int64_t)z + dz;
                  if (xx < 0 || yy < 0 || zz < 0 || xx >= m->dims[0] || yy >= m->dims[1] ||
                      zz >= m->dims[2])
                    continue;
                  uint32_t o = m->probe_first +
                               (uint32_t)((zz * m->dims[1] + yy) * m->dims[0] + xx);
                  if (!filled[o])
                    continue;
                  for (int k = 0; k < 27; k++)
                    acc[k] += sh[27 * (size_t)o + k];
                  cnt++;
                }
            if (!cnt)
              continue;
            for (int k = 0; k < 27; k++)
              sh[27 * (size_t)q + k] = (float)(acc[k] / cnt);
            next[q] = 1;
            changed = 1;
          }
      memcpy(filled + m->probe_first, next + m->probe_first, np);
      if (!changed)
        break;
    }
  }
  free(filled);
  free(next);
}

static uint32_t local_vertex(const ub_llg_model *m, uint32_t sv)
{
  const uint32_t *f = bsearch(&sv, m->vertices, m->vertex_count, sizeof sv, cmp_u32);
  return f ? (uint32_t)(f - m->vertices) : 0;
}

int ub_llg_hit_irradiance(const ub_llg_set *set, const ub_scene *s, const float *probe_sh,
                          uint32_t tri, float u, float v, const float p[3], const float dir[3],
                          float out_rgb[3])
{
  if (!set || !set->model_count)
    return 0;
  int32_t mi = set->node_model[s->tri_node[tri]];
  if (mi < 0)
    return 0;
  const ub_llg_model *m = &set->models[mi];
  float b[3] = {1.0f - u - v, u, v};
  float vis[9] = {0}, self[3] = {0}, n[3] = {0};
  for (int k = 0; k < 3; k++) {
    uint32_t sv = s->indices[3 * (size_t)tri + k];
    uint32_t lv = local_vertex(m, sv);
    for (int j = 0; j < 9; j++)
      vis[j] += b[k] * m->vis[9 * (size_t)lv + j];
    for (int j = 0; j < 3; j++) {
      self[j] += b[k] * m->self[3 * (size_t)lv + j];
      n[j] += b[k] * s->normals[3 * (size_t)sv + j];
    }
  }
  float len = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  if (!(len > 1e-6f))
    return 0;
  float sgn = (n[0] * dir[0] + n[1] * dir[1] + n[2] * dir[2]) > 0.0f ? -1.0f : 1.0f;
  for (int j = 0; j < 3; j++)
    n[j] *= sgn / len;
  /* ub_llg_irradiance(grid sample at p, vis, self, n) with the product folded into nine
   * weights on the corners' radiance (a gather hit on a prop: ~a third of the work) */
  float wi[9], wc[8];
  uint32_t idx[8];
  ub_llg_irradiance_weights(vis, n, wi);
  const uint32_t nc = ub_llg_grid_corners(m->center, m->axes, m->half, m->dims, p, idx, wc);
  const float *sh = probe_sh + 27 * (size_t)m->probe_first;
  float acc[27] = {0.0f};
  for (uint32_t c = 0; c < nc; c++) { /* the corners' radiance, weighted (27 in a row) */
    const float *L = sh + 27 * (size_t)idx[c];
    const float w = wc[c];
    #pragma GCC unroll 27
    for (int k = 0; k < 27; k++)
      acc[k] += w * L[k];
  }
  float e[3];
  for (int ch = 0; ch < 3; ch++) {
    e[ch] = 0.0f;
    for (int i = 0; i < 9; i++)
      e[ch] += wi[i] * acc[3 * i + ch];
  }
  ub_llg_irradiance_finish(e, self, out_rgb);
  return 1;
}

/* Direct irradiance of the enabled primary lights at surface point p (normal n), with
 * shadow rays against the whole level. */
static void primary_direct(const ub_scene *s, const ub_rt *rt, const uint8_t *enabled,
                           const float p[3], const float n[3], float out[3])
{
  out[0] = out[1] = out[2] = 0.0f;
  float po[3];
  ub_rt_offset_point(rt, p, n, po);
  for (uint32_t l = 0; l < s->light_count; l++) {
    if (!enabled[l] || s->lights[l].cls != UB_LIGHT_PRIMARY)
      continue;
    float dir[3], dist, e[3];
    if (!ub_light_incident(&s->lights[l], po, dir, &dist, e))
      continue;
    float cs = dir[0] * n[0] + dir[1] * n[1] + dir[2] * n[2];
    if (cs <= 0.0f)
      continue;
    ub_ray ray;
    memcpy(ray.org, po, sizeof po);
    memcpy(ray.dir, dir, sizeof dir);
    ray.tnear = 0.0f;
    ray.tfar = isfinite(dist) ? dist * (1.0f - 1e-4f) : INFINITY;
    uint8_t occ = 0;
    ub_rt_occluded(rt, &ray, 1, &occ);
    if (!occ)
      for (int c = 0; c < 3; c++)
        out[c] += e[c] * cs;
  }
}

ub_result ub_llg_self_bounce(ub_llg_set *set, const ub_scene *s, const ub_rt *rt_full,
                             const float *llg_sh, const uint8_t *light_enabled, uint32_t rays,
                             uint32_t seed)
{
  if (!set || !set->model_count)
    return UB_OK;
  uint32_t N = rays ? rays : 256;
  for (uint32_t mi = 0; mi < set->model_count; mi++) {
    ub_llg_model *m = &set->models[mi];
    float *next = calloc((size_t)m->vertex_count * 3 + 1, sizeof *next);
    if (!next)
      return UB_ERR_OUT_OF_MEMORY;
    uint64_t traced = 0;
    for (uint32_t it = 0; it < UB_LLG_SELF_ITERATIONS; it++) {
      int oom = 0;
#pragma omp parallel for schedule(dynamic, 8) reduction(+ : traced, oom)
      for (uint32_t i = 0; i < m->vertex_count; i++) {
        ub_ray *rr = malloc((size_t)N * sizeof *rr);
        ub_hit *hh = malloc((size_t)N * sizeof *hh);
        if (!rr || !hh) {
          free(rr);
          free(hh);
          oom++;
          continue;
        }
        const float *p = s->positions + 3 * (size_t)m->vertices[i];
        const float *n = s->normals + 3 * (size_t)m->vertices[i];
        float org[3];
        ub_rt_offset_point(m->rt_self, p, n, org);
        uint32_t kx = (uint32_t)sqrtf((float)N), ky;
        kx = kx < 1 ? 1 : kx;
        ky = N / kx;
        for (uint32_t j = 0; j < N; j++) {
          uint32_t h = ub_hash4(seed, 0x11300000u + mi, m->vertices[i], j);
          float u1 = ub_u01(h), u2 = ub_u01(ub_hash4(h, 9, 0, 0));
          if (j < kx * ky) {
            u1 = ((float)(j % kx) + u1) / (float)kx;
            u2 = ((float)(j / kx) + u2) / (float)ky;
          }
          memcpy(rr[j].org, org, sizeof org);
          ub_sample_cosine(n, u1, u2, rr[j].dir);
          rr[j].tnear = 0.0f;
          rr[j].tfar = INFINITY;
        }
        ub_rt_intersect(m->rt_self, rr, N, hh);
        traced += N;
        double acc[3] = {0, 0, 0};
        for (uint32_t j = 0; j < N; j++) {
          const ub_hit *h = &hh[j];
          if (h->tri == UB_RT_MISS)
            continue;
          float ng = h->ng[0] * rr[j].dir[0] + h->ng[1] * rr[j].dir[1] + h->ng[2] * rr[j].dir[2];
          if (ng >= 0.0f)
            continue; /* back face: inside the model */
          float hp[3], e[3], pd[3];
          for (int k = 0; k < 3; k++)
            hp[k] = rr[j].org[k] + h->t * rr[j].dir[k];
          if (!ub_llg_hit_irradiance(set, s, llg_sh, h->tri, h->u, h->v, hp, rr[j].dir, e))
            continue;
          float hl = sqrtf(h->ng[0] * h->ng[0] + h->ng[1] * h->ng[1] + h->ng[2] * h->ng[2]);
          float hn[3] = {h->ng[0] / hl, h->ng[1] / hl, h->ng[2] / hl};
          primary_direct(s, rt_full, light_enabled, hp, hn, pd);
          const float *alb = s->materials[s->tri_material[h->tri]].albedo;
          for (int c = 0; c < 3; c++)
            acc[c] += alb[c] * (e[c] + pd[c]); /* π·(ρ/π)·E / N per ray */
        }
        for (int c = 0; c < 3; c++) {
          float v = (float)(acc[c] / N);
          next[3 * (size_t)i + c] = isfinite(v) && v > 0.0f ? v : 0.0f;
        }
        free(rr);
        free(hh);
      }
      if (oom) {
        free(next);
        return UB_ERR_OUT_OF_MEMORY;
      }
      memcpy(m->self, next, (size_t)m->vertex_count * 3 * sizeof *next);
    }
    set->rays += traced;
    free(next);
  }
  return UB_OK;
}
