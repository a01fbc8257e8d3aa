/* lightmaps/charts.c — generated lightmap charts for triangles without TEXCOORD_1:
 * position welding, edge adjacency, chart growth (edge-connected, same node, within 30° of
 * the seed normal), projection on the average-normal plane rotated to the smallest box,
 * splitting/scaling of charts larger than an atlas, and skyline packing with padding.
 * Sequential and deterministic; O(n log n) in the triangle count. */
#include "lightmaps/lm_internal.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

float ub_lm_texel_size(const lm_ctx *c, uint32_t t, float default_ts)
{
  const ub_scene *s = c->scene;
  uint32_t nd = s->tri_node ? s->tri_node[t] : UINT32_MAX;
  if (nd < s->node_count && s->nodes[nd].texel_size > 0.0f && isfinite(s->nodes[nd].texel_size))
    return s->nodes[nd].texel_size;
  if (s->texel_size > 0.0f && isfinite(s->texel_size))
    return s->texel_size;
  return default_ts;
}
void ub_lm_charts_free(lm_charts *g)
{
  free(g->gtri);
  free(g->guv);
  free(g->order);
  free(g->charts);
  memset(g, 0, sizeof *g);
}

static int charts_push(lm_charts *g, const lm_chart *c)
{
  if (g->chart_count == g->chart_cap) {
    uint32_t cap = g->chart_cap ? g->chart_cap * 2 : 256;
    lm_chart *n = realloc(g->charts, (size_t)cap * sizeof *n);
    if (!n)
      return 0;
    g->charts = n;
    g->chart_cap = cap;
  }
  g->charts[g->chart_count++] = *c;
  return 1;
}

/* Position welding: cells of 4 × tol; a vertex joins the first earlier representative
 * within tol (max-norm) in its cell or the neighbouring cells it is within tol of. */
typedef struct weld_cell {
  int32_t k[3];
  int32_t head; /* first representative, -1 = empty slot */
} weld_cell;

static uint64_t cell_hash(const int32_t k[3])
{
  uint64_t h = (uint64_t)(uint32_t)k[0] * 0x9E3779B97F4A7C15ull;
  h ^= (uint64_t)(uint32_t)k[1] * 0xC2B2AE3D27D4EB4Full + (h >> 29);
  h ^= (uint64_t)(uint32_t)k[2] * 0x165667B19E3779F9ull + (h >> 31);
  return h ^ (h >> 32);
}

static int32_t *cell_find(weld_cell *tab, uint64_t mask, const int32_t k[3], int insert)
{
  uint64_t i = cell_hash(k) & mask;
  for (;;) {
    weld_cell *c = &tab[i];
    if (c->head < 0) {
      if (!insert)
        return NULL;
      c->k[0] = k[0];
      c->k[1] = k[1];
      c->k[2] = k[2];
      return &c->head;
    }
    if (c->k[0] == k[0] && c->k[1] == k[1] && c->k[2] == k[2])
      return &c->head;
    i = (i + 1) & mask;
  }
}

/* weld[v] for every vertex used by the generated triangles; -1 elsewhere. */
static int weld_vertices(const lm_ctx *c, const lm_charts *g, int32_t *weld)
{
  const ub_scene *s = c->scene;
  uint32_t used = 0;
  for (uint32_t v = 0; v < s->vertex_count; v++)
    weld[v] = -1;
  for (uint32_t i = 0; i < g->gcount; i++)
    for (int k = 0; k < 3; k++) {
      uint32_t v = s->indices[3 * (size_t)g->gtri[i] + k];
      if (weld[v] == -1) {
        weld[v] = -2;
        used++;
      }
    }
  uint64_t size = 64;
  while (size < 2ull * used + 16)
    size <<= 1;
  weld_cell *tab = malloc(size * sizeof *tab);
  int32_t *next = malloc((size_t)(used ? used : 1) * sizeof *next);
  uint32_t *rep_vertex = malloc((size_t)(used ? used : 1) * sizeof *rep_vertex);
  if (!tab || !next || !rep_vertex) {
    free(tab);
    free(next);
    free(rep_vertex);
    return 0;
  }
  for (uint64_t i = 0; i < size; i++)
    tab[i].head = -1;
  double tol = c->plane_tol;
  double cell = 4.0 * tol;
  const float *bmin_src = s->positions;
  double bmin[3] = {bmin_src[0], bmin_src[1], bmin_src[2]};
  for (uint32_t v = 0; v < s->vertex_count; v++)
    for (int a = 0; a < 3; a++)
      bmin[a] = fmin(bmin[a], s->positions[3 * (size_t)v + a]);
  int32_t reps = 0;
  for (uint32_t v = 0; v < s->vertex_count; v++) {
    if (weld[v] != -2)
      continue;
    const float *p = s->positions + 3 * (size_t)v;
    int32_t k[3];
    int lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
      double q = (p[a] - bmin[a]) / cell;
      double f = floor(q);
      k[a] = (int32_t)f;
      double frac = (q - f) * cell;
      lo[a] = frac <= tol ? -1 : 0;
      hi[a] = frac >= cell - tol ? 1 : 0;
    }
    int32_t found = -1;
    for (int dz = lo[2]; dz <= hi[2] && found < 0; dz++)
      for (int dy = lo[1]; dy <= hi[1] && found < 0; dy++)
        for (int dx = lo[0]; dx <= hi[0] && found < 0; dx++) {
          int32_t kk[3] = {k[0] + dx, k[1] + dy, k[2] + dz};
          int32_t *head = cell_find(tab, size - 1, kk, 0);
          for (int32_t r = head ? *head : -1; r >= 0; r = next[r]) {
            const float *q = s->positions + 3 * (size_t)rep_vertex[r];
            if (fabs((double)q[0] - p[0]) <= tol && fabs((double)q[1] - p[1]) <= tol &&
                fabs((double)q[2] - p[2]) <= tol) {
              found = r;
              break;
            }
          }
        }
    if (found < 0) {
      int32_t *head = cell_find(tab, size - 1, k, 1);
      found = reps++;
      rep_vertex[found] = v;
      next[found] = *head;
      *head = found;
    }
    weld[v] = found;
  }
  free(tab);
  free(next);
  free(rep_vertex);
  return 1;
}

typedef struct edge_rec {
  uint64_t key;
  uint32_t tri; /* generated-list index */
} edge_rec;

static int edge_cmp(const void *a, const void *b)
{
  const edge_rec *x = a, *y = b;
  if (x->key != y->key)
    return x->key < y->key ? -1 : 1;
  return x->tri < y->tri ? -1 : (x->tri > y->tri);
}

typedef struct pt2 {
  double x, y;
} pt2;

static int pt2_cmp(const void *a, const void *b)
{
  const pt2 *p = a, *q = b;
  if (p->x != q->x)
    return p->x < q->x ? -1 : 1;
  return p->y < q->y ? -1 : (p->y > q->y);
}

static double cross2(pt2 o, pt2 a, pt2 b)
{
  return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
}

/* Convex hull (Andrew's monotone chain) of pts (sorted in place); returns hull size in hull. */
static uint32_t convex_hull(pt2 *pts, uint32_t n, pt2 *hull)
{
  if (n < 3) {
    for (uint32_t i = 0; i < n; i++)
      hull[i] = pts[i];
    return n;
  }
  qsort(pts, n, sizeof *pts, pt2_cmp);
  uint32_t k = 0;
  for (uint32_t i = 0; i < n; i++) {
    while (k >= 2 && cross2(hull[k - 2], hull[k - 1], pts[i]) <= 0.0)
      k--;
    hull[k++] = pts[i];
  }
  for (uint32_t i = n - 1, t = k + 1; i-- > 0;) {
    while (k >= t && cross2(hull[k - 2], hull[k - 1], pts[i]) <= 0.0)
      k--;
    hull[k++] = pts[i];
  }
  return k - 1;
}

/* Projects the chart's members onto the plane of its area-weighted normal (texel units),
 * rotated to the smallest bounding box among the hull edge directions. */
static int project_chart(const lm_ctx *c, lm_charts *g, lm_chart *ch, float ts)
{
  const ub_scene *s = c->scene;
  double nrm[3] = {0, 0, 0};
  for (uint32_t m = 0; m < ch->count; m++) {
    uint32_t t = g->gtri[g->order[ch->first + m]];
    for (int a = 0; a < 3; a++)
      nrm[a] += c->tri_area[t] * c->tri_n[3 * (size_t)t + a];
  }
  if (v3_normalize(nrm) == 0.0)
    load3(c->tri_n + 3 * (size_t)g->gtri[g->order[ch->first]], nrm);
  /* Tangent frame aligned with the world axes where possible (axis-aligned walls and
   * floors get axis-aligned, tight charts). */
  double up[3] = {0, 1, 0};
  if (fabs(nrm[1]) > 0.99) {
    up[1] = 0;
    up[2] = 1;
  }
  double T[3], B[3];
  v3_cross(up, nrm, T);
  v3_normalize(T);
  v3_cross(nrm, T, B);
  double org[3];
  load3(s->positions + 3 * (size_t)s->indices[3 * (size_t)g->gtri[g->order[ch->first]]], org);
  double inv = 1.0 / ts;

  uint32_t npts = ch->count * 3;
  pt2 *pts = malloc((size_t)npts * sizeof *pts);
  pt2 *hull = malloc((size_t)(npts + 1) * sizeof *hull);
  if (!pts || !hull) {
    free(pts);
    free(hull);
    return 0;
  }
  for (uint32_t m = 0; m < ch->count; m++) {
    uint32_t gi = g->order[ch->first + m];
    double p[3][3];
    tri_corners(s, g->gtri[gi], p);
    for (int k = 0; k < 3; k++) {
      double d[3];
      v3_sub(p[k], org, d);
      double u = v3_dot(d, T) * inv, v = v3_dot(d, B) * inv;
      g->guv[6 * (size_t)gi + 2 * k] = u;
      g->guv[6 * (size_t)gi + 2 * k + 1] = v;
      pts[3 * m + k].x = u;
      pts[3 * m + k].y = v;
    }
  }
  uint32_t h = convex_hull(pts, npts, hull);
  /* Axis-aligned box first; another direction must beat it by 10%. */
  double best_area = DBL_MAX, best_cos = 1.0, best_sin = 0.0;
  {
    double x0 = DBL_MAX, x1 = -DBL_MAX, y0 = DBL_MAX, y1 = -DBL_MAX;
    for (uint32_t i = 0; i < h; i++) {
      x0 = fmin(x0, hull[i].x);
      x1 = fmax(x1, hull[i].x);
      y0 = fmin(y0, hull[i].y);
      y1 = fmax(y1, hull[i].y);
    }
    best_area = (x1 - x0 + 1.0) * (y1 - y0 + 1.0);
  }
  double aligned_area = best_area;
  if (h >= 3) {
    uint32_t step = h > 128 ? h / 128 : 1;
    for (uint32_t e = 0; e < h; e += step) {
      pt2 a = hull[e], b = hull[(e + 1) % h];
      double dx = b.x - a.x, dy = b.y - a.y, l = sqrt(dx * dx + dy * dy);
      if (!(l > 1e-12))
        continue;
      double cs = dx / l, sn = dy / l;
      double x0 = DBL_MAX, x1 = -DBL_MAX, y0 = DBL_MAX, y1 = -DBL_MAX;
      for (uint32_t i = 0; i < h; i++) {
        double u = hull[i].x * cs + hull[i].y * sn, v = -hull[i].x * sn + hull[i].y * cs;
        x0 = fmin(x0, u);
        x1 = fmax(x1, u);
        y0 = fmin(y0, v);
        y1 = fmax(y1, v);
      }
      double area = (x1 - x0 + 1.0) * (y1 - y0 + 1.0);
      if (area < best_area && area < 0.9 * aligned_area) {
        best_area = area;
        best_cos = cs;
        best_sin = sn;
      }
    }
  }
  free(pts);
  free(hull);
  if (best_cos != 1.0 || best_sin != 0.0) {
    for (uint32_t m = 0; m < ch->count; m++) {
      double *uv = g->guv + 6 * (size_t)g->order[ch->first + m];
      for (int k = 0; k < 3; k++) {
        double u = uv[2 * k], v = uv[2 * k + 1];
        uv[2 * k] = u * best_cos + v * best_sin;
        uv[2 * k + 1] = -u * best_sin + v * best_cos;
      }
    }
  }
  return 1;
}

static void chart_bounds(const lm_charts *g, lm_chart *ch)
{
  ch->umin = ch->vmin = DBL_MAX;
  ch->umax = ch->vmax = -DBL_MAX;
  for (uint32_t m = 0; m < ch->count; m++) {
    const double *uv = g->guv + 6 * (size_t)g->order[ch->first + m];
    for (int k = 0; k < 3; k++) {
      ch->umin = fmin(ch->umin, uv[2 * k]);
      ch->umax = fmax(ch->umax, uv[2 * k]);
      ch->vmin = fmin(ch->vmin, uv[2 * k + 1]);
      ch->vmax = fmax(ch->vmax, uv[2 * k + 1]);
    }
  }
}

/* Largest chart extent (texels) whose padded rectangle still fits an atlas. */
#define UB_LM_MAX_EXTENT ((double)(UB_ATLAS_MAX_SIZE - 2 * UB_LM_PADDING - 3))

/* Splits an oversized chart on a grid of triangle centroids (sub-charts keep the parent's
 * projection), then scales down whatever is still too big. */
static int split_chart(lm_charts *g, uint32_t ci)
{
  lm_chart ch = g->charts[ci];
  double cellsz = UB_LM_MAX_EXTENT * 0.5;
  uint32_t nx = (uint32_t)ceil((ch.umax - ch.umin) / cellsz) + 1;
  uint32_t ny = (uint32_t)ceil((ch.vmax - ch.vmin) / cellsz) + 1;
  uint32_t ncell = nx * ny;
  uint32_t *cell_of = malloc((size_t)ch.count * sizeof *cell_of);
  uint32_t *cnt = calloc((size_t)ncell + 1, sizeof *cnt);
  uint32_t *tmp = malloc((size_t)ch.count * sizeof *tmp);
  if (!cell_of || !cnt || !tmp) {
    free(cell_of);
    free(cnt);
    free(tmp);
    return 0;
  }
  for (uint32_t m = 0; m < ch.count; m++) {
    const double *uv = g->guv + 6 * (size_t)g->order[ch.first + m];
    double cu = (uv[0] + uv[2] + uv[4]) / 3.0, cv = (uv[1] + uv[3] + uv[5]) / 3.0;
    uint32_t ix = (uint32_t)fmin(nx - 1, fmax(0.0, floor((cu - ch.umin) / cellsz)));
    uint32_t iy = (uint32_t)fmin(ny - 1, fmax(0.0, floor((cv - ch.vmin) / cellsz)));
    cell_of[m] = iy * nx + ix;
    cnt[cell_of[m] + 1]++;
  }
  for (uint32_t k = 0; k < ncell; k++)
    cnt[k + 1] += cnt[k];
  uint32_t *start = malloc((size_t)(ncell + 1) * sizeof *start);
  if (!start) {
    free(cell_of);
    free(cnt);
    free(tmp);
    return 0;
  }
  memcpy(start, cnt, (size_t)(ncell + 1) * sizeof *start);
  for (uint32_t m = 0; m < ch.count; m++) /* stable: keeps BFS order inside a cell */
    tmp[cnt[cell_of[m]]++] = g->order[ch.first + m];
  memcpy(g->order + ch.first, tmp, (size_t)ch.count * sizeof *tmp);
  int first = 1, ok = 1;
  for (uint32_t k = 0; k < ncell && ok; k++) {
    uint32_t n = start[k + 1] - start[k];
    if (n == 0)
      continue;
    lm_chart sub = ch;
    sub.first = ch.first + start[k];
    sub.count = n;
    chart_bounds(g, &sub);
    if (first) {
      g->charts[ci] = sub;
      first = 0;
    } else {
      ok = charts_push(g, &sub);
    }
  }
  free(cell_of);
  free(cnt);
  free(tmp);
  free(start);
  g->split_charts++;
  return ok;
}

static void scale_chart(lm_charts *g, lm_chart *ch)
{
  double ext = fmax(ch->umax - ch->umin, ch->vmax - ch->vmin);
  if (!(ext > UB_LM_MAX_EXTENT))
    return;
  double k = UB_LM_MAX_EXTENT / ext;
  for (uint32_t m = 0; m < ch->count; m++) {
    double *uv = g->guv + 6 * (size_t)g->order[ch->first + m];
    for (int i = 0; i < 6; i++)
      uv[i] *= k;
  }
  chart_bounds(g, ch);
  g->scaled_charts++;
}

/* Texels a chart of extent ext (texels) spans once centred in them: at least 0.01 texel
 * of margin on each side, so float rounding of the UVs never touches one more texel. */
uint32_t ub_lm_chart_cells(double ext)
{
  double cells = floor(ext) + 1.0;
  if (cells - ext < 0.02)
    cells += 1.0;
  return (uint32_t)cells;
}

/* Skyline (bottom-left) packer for one atlas. */
typedef struct sky_seg {
  uint32_t x, y, w;
} sky_seg;

typedef struct skyline {
  uint32_t width, used_h;
  sky_seg *seg;
  uint32_t n, cap;
} skyline;

static int sky_init(skyline *s, uint32_t width)
{
  s->width = width;
  s->used_h = 0;
  s->cap = 64;
  s->seg = malloc(s->cap * sizeof *s->seg);
  if (!s->seg)
    return 0;
  s->n = 1;
  s->seg[0].x = 0;
  s->seg[0].y = 0;
  s->seg[0].w = width;
  return 1;
}

/* Finds the lowest (then leftmost) spot for w × h under max_h. Returns 1 and the spot. */
static int sky_find(const skyline *s, uint32_t w, uint32_t h, uint32_t max_h, uint32_t *ox,
                    uint32_t *oy, uint32_t *oi)
{
  uint32_t best_y = UINT32_MAX, best_x = 0, best_i = 0;
  for (uint32_t i = 0; i < s->n; i++) {
    uint32_t x = s->seg[i].x;
    if (x + w > s->width)
      break;
    uint32_t y = 0, covered = 0;
    for (uint32_t j = i; j < s->n && covered < w; j++) {
      if (s->seg[j].y > y)
        y = s->seg[j].y;
      covered += s->seg[j].w;
      if (y >= best_y)
        break;
    }
    if (y + h > max_h || y >= best_y)
      continue;
    best_y = y;
    best_x = x;
    best_i = i;
  }
  if (best_y == UINT32_MAX)
    return 0;
  *ox = best_x;
  *oy = best_y;
  *oi = best_i;
  return 1;
}

static int sky_place(skyline *s, uint32_t i, uint32_t x, uint32_t y, uint32_t w, uint32_t h)
{
  if (s->n + 2 > s->cap) {
    uint32_t cap = s->cap * 2;
    sky_seg *n = realloc(s->seg, cap * sizeof *n);
    if (!n)
      return 0;
    s->seg = n;
    s->cap = cap;
  }
  /* Remove the covered segments [i, j), trim the partially covered one. */
  uint32_t end = x + w, j = i;
  while (j < s->n && s->seg[j].x + s->seg[j].w <= end)
    j++;
  if (j < s->n && s->seg[j].x < end) {
    uint32_t cut = end - s->seg[j].x;
    s->seg[j].x = end;
    s->seg[j].w -= cut;
  }
  sky_seg ns = {x, y + h, w};
  /* replace [i, j) by ns */
  uint32_t removed = j - i;
  if (removed == 0) {
    memmove(s->seg + i + 1, s->seg + i, (s->n - i) * sizeof *s->seg);
    s->n++;
  } else if (removed > 1) {
    memmove(s->seg + i + 1, s->seg + j, (s->n - j) * sizeof *s->seg);
    s->n -= removed - 1;
  }
  s->seg[i] = ns;
  /* merge equal heights with the neighbours */
  if (i + 1 < s->n && s->seg[i + 1].y == s->seg[i].y) {
    s->seg[i].w += s->seg[i + 1].w;
    memmove(s->seg + i + 1, s->seg + i + 2, (s->n - i - 2) * sizeof *s->seg);
    s->n--;
  }
  if (i > 0 && s->seg[i - 1].y == s->seg[i].y) {
    s->seg[i - 1].w += s->seg[i].w;
    memmove(s->seg + i, s->seg + i + 1, (s->n - i - 1) * sizeof *s->seg);
    s->n--;
  }
  if (y + h > s->used_h)
    s->used_h = y + h;
  return 1;
}

typedef struct rect_key {
  uint32_t h, w, idx;
} rect_key;

/* Tallest first, then widest, then chart index: a total order, so qsort is deterministic. */
static int rect_cmp(const void *a, const void *b)
{
  const rect_key *x = a, *y = b;
  if (x->h != y->h)
    return x->h > y->h ? -1 : 1;
  if (x->w != y->w)
    return x->w > y->w ? -1 : 1;
  return x->idx < y->idx ? -1 : (x->idx > y->idx);
}

/* Charts → atlases. On success *out_atlases (width, height per generated atlas). */
ub_result ub_lm_charts_pack(lm_charts *g, uint32_t *out_count, uint32_t **out_w,
                             uint32_t **out_h)
{
  uint32_t n = g->chart_count;
  rect_key *keys = malloc((size_t)(n ? n : 1) * sizeof *keys);
  uint32_t *idx = malloc((size_t)(n ? n : 1) * sizeof *idx);
  if (!keys || !idx) {
    free(keys);
    free(idx);
    return UB_ERR_OUT_OF_MEMORY;
  }
  double remaining = 0.0;
  for (uint32_t i = 0; i < n; i++) {
    lm_chart *ch = &g->charts[i];
    double eu = ch->umax - ch->umin, ev = ch->vmax - ch->vmin;
    ch->rect_w = ub_lm_chart_cells(eu) + 2 * UB_LM_PADDING;
    ch->rect_h = ub_lm_chart_cells(ev) + 2 * UB_LM_PADDING;
    remaining += (double)ch->rect_w * ch->rect_h;
    keys[i].h = ch->rect_h;
    keys[i].w = ch->rect_w;
    keys[i].idx = i;
  }
  qsort(keys, n, sizeof *keys, rect_cmp);
  for (uint32_t i = 0; i < n; i++)
    idx[i] = keys[i].idx;
  free(keys);

  skyline *sky = NULL;
  uint32_t nsky = 0;
  ub_result res = UB_OK;
  for (uint32_t r = 0; r < n && res == UB_OK; r++) {
    lm_chart *ch = &g->charts[idx[r]];
    uint32_t x = 0, y = 0, si = 0, a;
    for (a = 0; a < nsky; a++)
      if (sky_find(&sky[a], ch->rect_w, ch->rect_h, UB_ATLAS_MAX_SIZE, &x, &y, &si))
        break;
    if (a == nsky) {
      uint32_t maxw = 0;
      for (uint32_t q = r; q < n; q++)
        if (g->charts[idx[q]].rect_w > maxw)
          maxw = g->charts[idx[q]].rect_w;
      uint32_t w = round_up4(sqrt(remaining * 1.12));
      if (w < round_up4(maxw))
        w = round_up4(maxw);
      if (w < UB_LM_MIN_SIZE)
        w = UB_LM_MIN_SIZE;
      if (w > UB_ATLAS_MAX_SIZE)
        w = UB_ATLAS_MAX_SIZE;
      skyline *ns = realloc(sky, (size_t)(nsky + 1) * sizeof *ns);
      if (!ns) {
        res = UB_ERR_OUT_OF_MEMORY;
        break;
      }
      sky = ns;
      if (!sky_init(&sky[nsky], w)) {
        res = UB_ERR_OUT_OF_MEMORY;
        break;
      }
      nsky++;
      if (!sky_find(&sky[a], ch->rect_w, ch->rect_h, UB_ATLAS_MAX_SIZE, &x, &y, &si)) {
        res = UB_ERR_INVALID_DATA; /* cannot happen: rectangles are ≤ the atlas */
        break;
      }
    }
    if (!sky_place(&sky[a], si, x, y, ch->rect_w, ch->rect_h)) {
      res = UB_ERR_OUT_OF_MEMORY;
      break;
    }
    ch->atlas = a;
    ch->x = x;
    ch->y = y;
    remaining -= (double)ch->rect_w * ch->rect_h;
  }
  free(idx);
  uint32_t *ws = NULL, *hs = NULL;
  if (res == UB_OK) {
    ws = malloc((size_t)(nsky ? nsky : 1) * sizeof *ws);
    hs = malloc((size_t)(nsky ? nsky : 1) * sizeof *hs);
    if (!ws || !hs)
      res = UB_ERR_OUT_OF_MEMORY;
  }
  for (uint32_t a = 0; a < nsky; a++) {
    if (res == UB_OK) {
      ws[a] = sky[a].width;
      uint32_t h = round_up4(sky[a].used_h);
      hs[a] = h < UB_LM_MIN_SIZE ? UB_LM_MIN_SIZE : (h > UB_ATLAS_MAX_SIZE ? UB_ATLAS_MAX_SIZE : h);
    }
    free(sky[a].seg);
  }
  free(sky);
  if (res != UB_OK) {
    free(ws);
    free(hs);
    return res;
  }
  *out_count = nsky;
  *out_w = ws;
  *out_h = hs;
  return UB_OK;
}

/* Breadth-first chart growth from seed over unassigned (chart_of < 0) edge neighbours
 * within 30° of the seed normal; members written to order[pos..]. Returns the count. */
static uint32_t grow_chart(const lm_ctx *c, lm_charts *g, uint32_t seed, uint32_t pos,
                           const uint32_t *adj_start, const uint32_t *adj, int32_t *chart_of,
                           int32_t id)
{
  const float *sn = c->tri_n + 3 * (size_t)g->gtri[seed];
  uint32_t placed = pos;
  chart_of[seed] = id;
  g->order[placed++] = seed;
  for (uint32_t q = pos; q < placed; q++) {
    uint32_t cur = g->order[q];
    for (uint32_t k = adj_start[cur]; k < adj_start[cur + 1]; k++) {
      uint32_t nb = adj[k];
      if (chart_of[nb] >= 0)
        continue;
      if (f3_dot(c->tri_n + 3 * (size_t)g->gtri[nb], sn) < UB_LM_CHART_COS)
        continue;
      chart_of[nb] = id;
      g->order[placed++] = nb;
    }
  }
  return placed - pos;
}

/* Positive-area overlap of two UV triangles (separating axis test; touching edges and
 * shared vertices do not count). */
static int uv_tris_overlap(const double *a, const double *b)
{
  const double eps = 1e-4; /* texels */
  for (int pass = 0; pass < 2; pass++) {
    const double *t = pass ? b : a;
    for (int e = 0; e < 3; e++) {
      double nx = -(t[2 * ((e + 1) % 3) + 1] - t[2 * e + 1]);
      double ny = t[2 * ((e + 1) % 3)] - t[2 * e];
      double len = sqrt(nx * nx + ny * ny);
      if (!(len > 0.0))
        continue;
      nx /= len;
      ny /= len;
      double amin = DBL_MAX, amax = -DBL_MAX, bmin = DBL_MAX, bmax = -DBL_MAX;
      for (int k = 0; k < 3; k++) {
        double pa = a[2 * k] * nx + a[2 * k + 1] * ny, pb = b[2 * k] * nx + b[2 * k + 1] * ny;
        amin = fmin(amin, pa);
        amax = fmax(amax, pa);
        bmin = fmin(bmin, pb);
        bmax = fmax(bmax, pb);
      }
      if (amax <= bmin + eps || bmax <= amin + eps)
        return 0;
    }
  }
  return 1;
}

/* Same orientation and within plane_tol of each other's plane: overlapping copies of one
 * surface (duplicated faces) share texels harmlessly. */
static int same_plane(const lm_ctx *c, uint32_t ta, uint32_t tb)
{
  const float *na = c->tri_n + 3 * (size_t)ta, *nb = c->tri_n + 3 * (size_t)tb;
  if (f3_dot(na, nb) < 0.999f)
    return 0;
  double pa[3][3], pb[3][3], d[3], n[3];
  tri_corners(c->scene, ta, pa);
  tri_corners(c->scene, tb, pb);
  load3(na, n);
  v3_sub(pb[0], pa[0], d);
  return fabs(v3_dot(d, n)) <= c->plane_tol;
}

/* A chart whose surface winds over itself (a ramp passing under a floor) projects onto
 * itself. Members are taken in BFS order; one overlapping an earlier accepted member of
 * another plane is rejected. Rejected members are regrown into new (unprojected) charts.
 * Returns 0 on out of memory. */
static int separate_overlaps(const lm_ctx *c, lm_charts *g, uint32_t ci,
                             const uint32_t *adj_start, const uint32_t *adj, int32_t *chart_of)
{
  lm_chart ch = g->charts[ci];
  if (ch.count < 2)
    return 1;
  chart_bounds(g, &ch);
  double bw = fmax(ch.umax - ch.umin, 1e-6), bh = fmax(ch.vmax - ch.vmin, 1e-6);
  double cs = fmax(sqrt(bw * bh / ch.count), 1e-3);
  uint32_t nx = (uint32_t)fmin(ceil(bw / cs), 2048.0), ny = (uint32_t)fmin(ceil(bh / cs), 2048.0);
  nx = nx ? nx : 1;
  ny = ny ? ny : 1;
  double sx = nx / bw, sy = ny / bh;
  size_t ncell = (size_t)nx * ny;
  int32_t *head = malloc(ncell * sizeof *head);
  uint32_t *stamp = calloc(ch.count, sizeof *stamp);
  uint8_t *rejected = calloc(ch.count, 1);
  size_t pool_cap = (size_t)ch.count * 4 + 64, pool_n = 0;
  struct cell_node {
    uint32_t member;
    int32_t next;
  } *pool = malloc(pool_cap * sizeof *pool);
  if (!head || !stamp || !rejected || !pool) {
    free(head);
    free(stamp);
    free(rejected);
    free(pool);
    return 0;
  }
  for (size_t i = 0; i < ncell; i++)
    head[i] = -1;
  uint32_t nrej = 0;
  for (uint32_t m = 0; m < ch.count; m++) {
    uint32_t gi = g->order[ch.first + m];
    const double *uv = g->guv + 6 * (size_t)gi;
    double u0 = fmin(uv[0], fmin(uv[2], uv[4])), u1 = fmax(uv[0], fmax(uv[2], uv[4]));
    double v0 = fmin(uv[1], fmin(uv[3], uv[5])), v1 = fmax(uv[1], fmax(uv[3], uv[5]));
    uint32_t cx0 = (uint32_t)fmin(nx - 1, fmax(0.0, floor((u0 - ch.umin) * sx)));
    uint32_t cx1 = (uint32_t)fmin(nx - 1, fmax(0.0, floor((u1 - ch.umin) * sx)));
    uint32_t cy0 = (uint32_t)fmin(ny - 1, fmax(0.0, floor((v0 - ch.vmin) * sy)));
    uint32_t cy1 = (uint32_t)fmin(ny - 1, fmax(0.0, floor((v1 - ch.vmin) * sy)));
    int bad = 0;
    for (uint32_t cy = cy0; cy <= cy1 && !bad; cy++)
      for (uint32_t cx = cx0; cx <= cx1 && !bad; cx++)
        for (int32_t k = head[(size_t)cy * nx + cx]; k >= 0 && !bad; k = pool[k].next) {
          uint32_t o = pool[k].member;
          if (stamp[o] == m + 1)
            continue;
          stamp[o] = m + 1;
          uint32_t go = g->order[ch.first + o];
          if (uv_tris_overlap(uv, g->guv + 6 * (size_t)go) &&
              !same_plane(c, g->gtri[gi], g->gtri[go]))
            bad = 1;
        }
    if (bad) {
      rejected[m] = 1;
      nrej++;
      continue;
    }
    for (uint32_t cy = cy0; cy <= cy1; cy++)
      for (uint32_t cx = cx0; cx <= cx1; cx++) {
        if (pool_n == pool_cap) {
          pool_cap *= 2;
          struct cell_node *np = realloc(pool, pool_cap * sizeof *np);
          if (!np) {
            free(head);
            free(stamp);
            free(rejected);
            free(pool);
            return 0;
          }
          pool = np;
        }
        pool[pool_n].member = m;
        pool[pool_n].next = head[(size_t)cy * nx + cx];
        head[(size_t)cy * nx + cx] = (int32_t)pool_n++;
      }
  }
  free(head);
  free(stamp);
  free(pool);
  if (nrej == 0) {
    free(rejected);
    return 1;
  }
  /* accepted members first (order kept), then regrow the rejected ones */
  uint32_t *rej = malloc((size_t)nrej * sizeof *rej);
  uint32_t *acc = malloc((size_t)(ch.count - nrej) * sizeof *acc);
  if (!rej || !acc) {
    free(rej);
    free(acc);
    free(rejected);
    return 0;
  }
  uint32_t na = 0, nr = 0;
  for (uint32_t m = 0; m < ch.count; m++) {
    uint32_t gi = g->order[ch.first + m];
    if (rejected[m]) {
      rej[nr++] = gi;
      chart_of[gi] = -1;
    } else {
      acc[na++] = gi;
    }
  }
  free(rejected);
  memcpy(g->order + ch.first, acc, (size_t)na * sizeof *acc);
  free(acc);
  g->charts[ci].count = na;
  uint32_t pos = ch.first + na;
  int ok = 1;
  for (uint32_t k = 0; k < nr && ok; k++) {
    if (chart_of[rej[k]] >= 0)
      continue;
    lm_chart nc;
    memset(&nc, 0, sizeof nc);
    nc.first = pos;
    nc.node = ch.node;
    nc.count = grow_chart(c, g, rej[k], pos, adj_start, adj, chart_of, (int32_t)g->chart_count);
    pos += nc.count;
    ok = charts_push(g, &nc);
  }
  free(rej);
  g->overlap_splits++;
  return ok;
}

/* Builds generated charts for the triangles with tri_kind == 1. */
ub_result ub_lm_charts_build(const lm_ctx *c, float default_ts, lm_charts *g)
{
  const ub_scene *s = c->scene;
  memset(g, 0, sizeof *g);
  for (uint32_t t = 0; t < s->triangle_count; t++)
    if (c->tri_kind[t] == 1)
      g->gcount++;
  if (g->gcount == 0)
    return UB_OK;
  uint32_t gn = g->gcount;
  g->gtri = malloc((size_t)gn * sizeof *g->gtri);
  g->guv = malloc((size_t)gn * 6 * sizeof *g->guv);
  g->order = malloc((size_t)gn * sizeof *g->order);
  int32_t *weld = malloc((size_t)s->vertex_count * sizeof *weld);
  edge_rec *edges = malloc((size_t)gn * 3 * sizeof *edges);
  uint32_t *adj_start = calloc((size_t)gn + 1, sizeof *adj_start);
  int32_t *chart_of = malloc((size_t)gn * sizeof *chart_of);
  uint32_t *adj = NULL;
  ub_result res = UB_OK;
  if (!g->gtri || !g->guv || !g->order || !weld || !edges || !adj_start || !chart_of) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto done;
  }
  for (uint32_t t = 0, i = 0; t < s->triangle_count; t++)
    if (c->tri_kind[t] == 1)
      g->gtri[i++] = t;
  if (!weld_vertices(c, g, weld)) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto done;
  }

  /* Edge adjacency: triangles of the same node sharing a welded edge. */
  uint32_t ne = 0;
  for (uint32_t i = 0; i < gn; i++) {
    const uint32_t *ix = s->indices + 3 * (size_t)g->gtri[i];
    for (int k = 0; k < 3; k++) {
      uint32_t a = (uint32_t)weld[ix[k]], b = (uint32_t)weld[ix[(k + 1) % 3]];
      if (a == b)
        continue;
      if (a > b) {
        uint32_t tmp = a;
        a = b;
        b = tmp;
      }
      edges[ne].key = ((uint64_t)a << 32) | b;
      edges[ne].tri = i;
      ne++;
    }
  }
  qsort(edges, ne, sizeof *edges, edge_cmp);
  /* Runs longer than this (non-manifold fans) only link consecutive members. */
  const uint32_t fan_cap = 8;
  for (int fill = 0; fill < 2; fill++) {
    if (fill) {
      for (uint32_t i = 0; i < gn; i++)
        adj_start[i + 1] += adj_start[i];
      adj = malloc((size_t)(adj_start[gn] ? adj_start[gn] : 1) * sizeof *adj);
      if (!adj) {
        res = UB_ERR_OUT_OF_MEMORY;
        goto done;
      }
    }
    uint32_t *cursor = NULL;
    if (fill) {
      cursor = malloc((size_t)gn * sizeof *cursor);
      if (!cursor) {
        res = UB_ERR_OUT_OF_MEMORY;
        goto done;
      }
      memcpy(cursor, adj_start, (size_t)gn * sizeof *cursor);
    }
    for (uint32_t e = 0; e < ne;) {
      uint32_t f = e;
      while (f < ne && edges[f].key == edges[e].key)
        f++;
      uint32_t run = f - e;
      for (uint32_t a = e; a < f; a++)
        for (uint32_t b = a + 1; b < f; b++) {
          if (run > fan_cap && b != a + 1)
            break;
          uint32_t ta = edges[a].tri, tb = edges[b].tri;
          if (ta == tb || s->tri_node[g->gtri[ta]] != s->tri_node[g->gtri[tb]])
            continue;
          if (!fill) {
            adj_start[ta + 1]++;
            adj_start[tb + 1]++;
          } else {
            adj[cursor[ta]++] = tb;
            adj[cursor[tb]++] = ta;
          }
        }
      e = f;
    }
    free(cursor);
  }

  /* Grow charts breadth-first from the lowest unassigned triangle. */
  for (uint32_t i = 0; i < gn; i++)
    chart_of[i] = -1;
  uint32_t placed = 0;
  for (uint32_t seed = 0; seed < gn; seed++) {
    if (chart_of[seed] >= 0)
      continue;
    lm_chart ch;
    memset(&ch, 0, sizeof ch);
    ch.first = placed;
    ch.node = s->tri_node[g->gtri[seed]];
    ch.count = grow_chart(c, g, seed, placed, adj_start, adj, chart_of, (int32_t)g->chart_count);
    placed += ch.count;
    if (!charts_push(g, &ch)) {
      res = UB_ERR_OUT_OF_MEMORY;
      goto done;
    }
  }

  /* Project (then separate self-overlaps: new charts are appended and visited by this
   * same loop), bound, split or scale what does not fit (sub-charts keep the parent's
   * projection and are already within bounds when the loop reaches them). */
  for (uint32_t ci = 0; ci < g->chart_count; ci++) {
    if (!g->charts[ci].projected) {
      lm_chart *ch = &g->charts[ci];
      float ts = ub_lm_texel_size(c, g->gtri[g->order[ch->first]], default_ts);
      if (!project_chart(c, g, ch, ts) ||
          !separate_overlaps(c, g, ci, adj_start, adj, chart_of)) {
        res = UB_ERR_OUT_OF_MEMORY;
        goto done;
      }
      g->charts[ci].projected = 1;
    }
    lm_chart *ch = &g->charts[ci];
    chart_bounds(g, ch);
    if (ch->umax - ch->umin > UB_LM_MAX_EXTENT || ch->vmax - ch->vmin > UB_LM_MAX_EXTENT) {
      uint32_t before = g->chart_count;
      if (!split_chart(g, ci)) {
        res = UB_ERR_OUT_OF_MEMORY;
        goto done;
      }
      scale_chart(g, &g->charts[ci]);
      for (uint32_t k = before; k < g->chart_count; k++)
        scale_chart(g, &g->charts[k]);
    }
  }

done:
  free(weld);
  free(edges);
  free(adj_start);
  free(adj);
  free(chart_of);
  if (res != UB_OK)
    ub_lm_charts_free(g);
  return res;
}

