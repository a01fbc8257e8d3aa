/* tests/test_blend.c — run-time blend engine (runtime/blend.h): every overlap count 0…20
 * against a naive double sum, a random 100k-receiver scenario with 1000 weight changes
 * (only the changed elements' receivers are written, each once), bit-exact toggling,
 * exact half decoding, input validation.
 *
 * Tolerance: engine value vs the exact sum (double; products of two floats are exact in
 * double) within γ_{k+1}·Σ|terms| (k non-zero terms besides base, γ_n = n·u/(1 − n·u),
 * u = 2^-24): one rounding per product and one per addition, the bound blend.h states. */
#include "runtime/blend.h"
#include "runtime/half.h"
#include "test_util.h"

#include <stdint.h>
#include <string.h>
#include <pthread.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

static uint64_t rng_state = 0x243F6A8885A308D3ull;
static uint64_t rnd_u64(void)
{
  rng_state ^= rng_state << 13;
  rng_state ^= rng_state >> 7;
  rng_state ^= rng_state << 17;
  return rng_state;
}
static double rnd(void) /* [0, 1) */
{
  return (double)(rnd_u64() >> 11) * (1.0 / 9007199254740992.0);
}
static uint32_t rnd_below(uint32_t n)
{
  return (uint32_t)(rnd() * n);
}

/* ---- a test representation: base + records, plus a naive reference ------------------ */

typedef struct rep {
  uint32_t R, S, E;
  ub_blend_storage storage;
  float *base;
  uint32_t **idx;
  uint32_t *cnt;
  float **vf;     /* values as float (exact value of the half when storage is F16) */
  uint16_t **vh;  /* half storage */
  ub_blend_record *recs;
  /* membership lookup: per receiver, its (element, position) pairs */
  uint32_t *off, *m_elem, *m_pos;
  float *w; /* E × 3, what the test believes the weights are */
} rep;

static void rep_free(rep *p)
{
  for (uint32_t e = 0; e < p->E; e++) {
    free(p->idx[e]);
    free(p->vf[e]);
    free(p->vh[e]);
  }
  free(p->idx);
  free(p->cnt);
  free(p->vf);
  free(p->vh);
  free(p->recs);
  free(p->base);
  free(p->off);
  free(p->m_elem);
  free(p->m_pos);
  free(p->w);
  memset(p, 0, sizeof *p);
}

static float rnd_value(void)
{
  return (float)(rnd() * 3.0 - 1.0); /* signed: door/object deltas can remove light */
}

/* cover[e] is a receiver_count byte mask of element e (consumed). */
static void rep_init(rep *p, uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st,
                     uint8_t **cover)
{
  memset(p, 0, sizeof *p);
  p->R = R;
  p->S = S;
  p->E = E;
  p->storage = st;
  p->base = malloc(sizeof(float) * ((size_t)R * S + 1));
  for (size_t i = 0; i < (size_t)R * S; i++)
    p->base[i] = (float)(rnd() * 2.0);
  p->idx = calloc(E + 1, sizeof *p->idx);
  p->cnt = calloc(E + 1, sizeof *p->cnt);
  p->vf = calloc(E + 1, sizeof *p->vf);
  p->vh = calloc(E + 1, sizeof *p->vh);
  p->recs = calloc(E + 1, sizeof *p->recs);
  p->w = calloc((size_t)E * 3 + 1, sizeof(float));
  p->off = calloc((size_t)R + 1, sizeof(uint32_t));
  for (uint32_t e = 0; e < E; e++) {
    uint32_t n = 0;
    for (uint32_t r = 0; r < R; r++)
      n += cover[e][r] != 0;
    p->cnt[e] = n;
    p->idx[e] = malloc(sizeof(uint32_t) * (n + 1));
    p->vf[e] = malloc(sizeof(float) * ((size_t)n * S + 1));
    p->vh[e] = malloc(sizeof(uint16_t) * ((size_t)n * S + 1));
    n = 0;
    for (uint32_t r = 0; r < R; r++)
      if (cover[e][r]) {
        p->idx[e][n++] = r;
        p->off[r + 1]++;
      }
    for (size_t i = 0; i < (size_t)n * S; i++) {
      float v = rnd_value();
      if (rnd() < 0.02)
        v *= 1e-6f; /* some half subnormals */
      p->vh[e][i] = ub_half_from_float(v);
      p->vf[e][i] = st == UB_BLEND_FLOAT16 ? ub_half_to_float(p->vh[e][i]) : v;
    }
    p->recs[e].receivers = p->idx[e];
    p->recs[e].values = st == UB_BLEND_FLOAT16 ? (const void *)p->vh[e] : (const void *)p->vf[e];
    p->recs[e].count = p->cnt[e];
  }
  for (uint32_t r = 0; r < R; r++)
    p->off[r + 1] += p->off[r];
  p->m_elem = malloc(sizeof(uint32_t) * (p->off[R] + 1));
  p->m_pos = malloc(sizeof(uint32_t) * (p->off[R] + 1));
  uint32_t *cur = malloc(sizeof(uint32_t) * (R + 1));
  memcpy(cur, p->off, sizeof(uint32_t) * R);
  for (uint32_t e = 0; e < E; e++)
    for (uint32_t i = 0; i < p->cnt[e]; i++) {
      uint32_t r = p->idx[e][i];
      p->m_elem[cur[r]] = e;
      p->m_pos[cur[r]++] = i;
    }
  free(cur);
}

static ub_blend_desc rep_desc(const rep *p, const char *name)
{
  ub_blend_desc d = {name, p->R, p->S, p->base, p->storage, p->E, p->recs, 0, 0};
  return d;
}

/* Elements over runs: each a stretch of receivers, 90% of them, from a random start; with
 * scatter_every > 0, every scatter_every-th element (e % scatter_every == scatter_every - 1)
 * picks R/20 receivers anywhere instead (list groups). */
static void rep_init_runs(rep *p, uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st,
                          uint32_t scatter_every)
{
  uint8_t **cover = malloc(sizeof(uint8_t *) * E);
  for (uint32_t e = 0; e < E; e++) {
    cover[e] = calloc(R, 1);
    if (scatter_every && e % scatter_every == scatter_every - 1) {
      for (uint32_t i = 0; i < R / 20; i++)
        cover[e][rnd_below(R)] = 1;
    } else {
      uint32_t start = rnd_below(R), size = 10 + rnd_below(R / 4);
      for (uint32_t r = start; r < R && r < start + size; r++)
        cover[e][r] = rnd() < 0.9;
    }
  }
  rep_init(p, R, S, E, st, cover);
  for (uint32_t e = 0; e < E; e++)
    free(cover[e]);
  free(cover);
}

/* R bytes: 1 where some element touches the receiver (free it). */
static uint8_t *rep_touched_mask(const rep *p)
{
  uint8_t *m = calloc(p->R, 1);
  for (uint32_t e = 0; e < p->E; e++)
    for (uint32_t i = 0; i < p->cnt[e]; i++)
      m[p->idx[e][i]] = 1;
  return m;
}

/* Checks receiver r of out against the exact sum; returns 1 if good. */
static int check_receiver(const rep *p, const float *out, uint32_t r)
{
  int ok = 1;
  for (uint32_t j = 0; j < p->S; j++) {
    uint32_t c = j % 3;
    double b = p->base[(size_t)r * p->S + j];
    double sum = b, mag = fabs(b);
    int k = 0;
    for (uint32_t q = p->off[r]; q < p->off[r + 1]; q++) {
      uint32_t e = p->m_elem[q];
      const float *w = p->w + (size_t)e * 3;
      if (w[0] == 0.0f && w[1] == 0.0f && w[2] == 0.0f)
        continue;
      double t = (double)w[c] * (double)p->vf[e][(size_t)p->m_pos[q] * p->S + j];
      sum += t;
      mag += fabs(t);
      k++;
    }
    double u = 1.0 / 16777216.0, n = k + 1;
    double tol = n * u / (1.0 - n * u) * mag + 1e-12 * mag + 1e-30;
    double got = out[(size_t)r * p->S + j];
    if (!(fabs(got - sum) <= tol)) {
      if (ok)
        fprintf(stderr, "receiver %u value %u: %.9g, expected %.9g (tol %.3g, %d terms)\n", r,
                j, got, sum, tol, k);
      ok = 0;
    }
  }
  return ok;
}

static void set_w(rep *p, ub_blend *b, uint32_t e, float r, float g, float bl)
{
  float rgb[3] = {r, g, bl};
  ASSERT_OK(ub_blend_set_weight(b, e, rgb));
  memcpy(p->w + (size_t)e * 3, rgb, sizeof rgb);
}

static void rnd_weight(float rgb[3])
{
  double x = rnd();
  if (x < 0.25) {
    rgb[0] = rgb[1] = rgb[2] = 0.0f;
  } else if (x < 0.6) {
    rgb[0] = rgb[1] = rgb[2] = (float)(rnd() * 2.0);
  } else {
    for (int c = 0; c < 3; c++)
      rgb[c] = rnd() < 0.2 ? 0.0f : (float)(rnd() * 2.5 - 0.5);
  }
}

/* ---- touched-list collection --------------------------------------------------------- */

typedef struct touch_log {
  uint8_t *count;   /* per receiver: times reported */
  uint64_t total;
  uint32_t S;
  const float *out; /* non-streaming: rows must be out + first × S */
  float *copy;      /* streaming: rows copied here */
  int rows_bad;
  /* streaming: pieces longer than 32 receivers, and calls that continue the previous one
   * while it was shorter than 32 (the engine hands consecutive pieces over together) */
  uint32_t last_first, last_count;
  int pieces_bad;
} touch_log;

static void on_touched(void *user, uint32_t first, uint32_t count, const float *rows)
{
  touch_log *t = user;
  for (uint32_t i = 0; i < count; i++)
    if (t->count[first + i] < 255)
      t->count[first + i]++;
  t->total += count;
  if (t->out && rows != t->out + (size_t)first * t->S)
    t->rows_bad++;
  if (t->copy) {
    memcpy(t->copy + (size_t)first * t->S, rows, sizeof(float) * count * t->S);
    if (count > 32 || (t->last_count && t->last_count < 32 &&
                       first == t->last_first + t->last_count))
      t->pieces_bad++;
    t->last_first = first;
    t->last_count = count;
  }
}

/* on_touched for ub_blend_mark_part: counts, and rows must be NULL */
static void on_marked(void *user, uint32_t first, uint32_t count, const float *rows)
{
  touch_log *t = user;
  t->rows_bad += rows != NULL;
  for (uint32_t i = 0; i < count; i++)
    if (t->count[first + i] < 255)
      t->count[first + i]++;
  t->total += count;
}

/* ub_blend_listed_fn for ub_blend_mark_part_ex: counts into the touch_log's count (as
 * on_marked), rows_bad for an empty or unsorted list; pieces: the calls */
static void on_listed(void *user, const uint32_t *receivers, uint32_t count)
{
  touch_log *t = user;
  t->rows_bad += count == 0;
  for (uint32_t i = 0; i < count; i++) {
    t->rows_bad += i && receivers[i] <= receivers[i - 1];
    if (t->count[receivers[i]] < 255)
      t->count[receivers[i]]++;
  }
  t->total += count;
  t->pieces_bad++; /* (used as a call count here) */
}

/* One update of b, its reports counted into count (R receivers): rows into out, or (stream)
 * streamed and copied into out; as `parts` parts on this thread (ub_blend_update_begin /
 * _part), else ub_blend_update (all: _all) with its stats into st (may be NULL). */
static void update_as(ub_blend *b, float *out, uint8_t *count, uint32_t R, uint32_t S,
                      int stream, uint32_t parts, int all, ub_blend_stats *st)
{
  memset(count, 0, R);
  touch_log tl = {count, 0, S, stream ? NULL : out, stream ? out : NULL, 0, 0, 0, 0};
  if (parts > 1) {
    ub_blend_update_begin(b, all);
    for (uint32_t q = 0; q < parts; q++)
      ub_blend_update_part(b, q, parts, on_touched, &tl, stream ? NULL : out, NULL);
  } else if (all) {
    ub_blend_update_all(b, on_touched, &tl, stream ? NULL : out, st);
  } else {
    ub_blend_update(b, on_touched, &tl, stream ? NULL : out, st);
  }
}

/* ---- 1. every overlap count 0…20 ------------------------------------------------------- */

static void test_overlaps(uint32_t S, ub_blend_storage st)
{
  const uint32_t R = 300;
  for (uint32_t k = 0; k <= 20; k++) {
    /* The shared set: a run of 20 receivers and 20 scattered ones, overlapped by all k
     * elements; each element also covers random other receivers (fewer overlaps). */
    uint8_t **cover = malloc(sizeof(uint8_t *) * (k + 1));
    for (uint32_t e = 0; e < k; e++) {
      cover[e] = calloc(R, 1);
      for (uint32_t i = 0; i < 20; i++) {
        cover[e][100 + i] = 1;
        cover[e][130 + 7 * i] = 1;
      }
      for (uint32_t r = 0; r < R; r++)
        if (rnd() < 0.15)
          cover[e][r] = 1;
    }
    rep p;
    rep_init(&p, R, S, k, st, cover);
    for (uint32_t e = 0; e < k; e++)
      free(cover[e]);
    free(cover);

    float *out = malloc(sizeof(float) * R * S);
    ub_blend *b = NULL;
    ub_blend_desc d = rep_desc(&p, "overlap test");
    ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
    if (!b) {
      rep_free(&p);
      free(out);
      continue;
    }
    ASSERT_TRUE(memcmp(out, p.base, sizeof(float) * R * S) == 0);
    ub_blend_info info;
    ub_blend_get_info(b, &info);
    ASSERT_TRUE(info.max_overlap == k);
    uint32_t touched = 0;
    for (uint32_t r = 0; r < R; r++)
      touched += p.off[r + 1] > p.off[r];
    ASSERT_TRUE(info.touched_receivers == touched);

    /* Several rounds of random weights (some zero, so every active count ≤ k occurs). */
    for (int round = 0; round < 6; round++) {
      for (uint32_t e = 0; e < k; e++) {
        float rgb[3];
        rnd_weight(rgb);
        if (round == 0)
          rgb[0] = rgb[1] = rgb[2] = 0.5f + (float)e; /* all k non-zero */
        set_w(&p, b, e, rgb[0], rgb[1], rgb[2]);
      }
      ub_blend_update(b, NULL, NULL, out, NULL);
      int bad = 0;
      for (uint32_t r = 0; r < R; r++)
        bad += !check_receiver(&p, out, r);
      if (bad)
        fprintf(stderr, "stride %u storage %d overlap %u round %d: %d bad receivers\n", S,
                (int)st, k, round, bad);
      ASSERT_TRUE(bad == 0);
    }
    /* All off: bit-identical base. */
    for (uint32_t e = 0; e < k; e++)
      set_w(&p, b, e, 0, 0, 0);
    ub_blend_update(b, NULL, NULL, out, NULL);
    ASSERT_TRUE(memcmp(out, p.base, sizeof(float) * R * S) == 0);
    ub_blend_free(b);
    rep_free(&p);
    free(out);
  }
}

/* ---- 2. half decoding is exact for every finite half ---------------------------------- */

static void test_half_exact(uint32_t S)
{
  uint32_t nfin = 0;
  for (uint32_t h = 0; h < 65536; h++)
    nfin += ub_half_is_finite((uint16_t)h);
  uint32_t R = (nfin + S - 1) / S;
  float *base = calloc((size_t)R * S, sizeof(float));
  uint16_t *vals = calloc((size_t)R * S, sizeof(uint16_t));
  uint32_t *idx = malloc(sizeof(uint32_t) * R);
  uint32_t n = 0;
  for (uint32_t h = 0; h < 65536; h++)
    if (ub_half_is_finite((uint16_t)h))
      vals[n++] = (uint16_t)h;
  for (uint32_t r = 0; r < R; r++)
    idx[r] = r;
  ub_blend_record rec = {idx, vals, R};
  ub_blend_desc d = {"half", R, S, base, UB_BLEND_FLOAT16, 1, &rec, 0, 0};
  float *out = malloc(sizeof(float) * R * S);
  ub_blend *b = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
  float one[3] = {1, 1, 1};
  ASSERT_OK(ub_blend_set_weight(b, 0, one));
  ub_blend_update(b, NULL, NULL, out, NULL);
  uint32_t bad = 0;
  for (uint32_t i = 0; i < (uint32_t)R * S; i++)
    bad += out[i] != ub_half_to_float(vals[i]); /* 0 + -0 = +0 compares equal */
  ASSERT_TRUE(bad == 0);
  /* The portable decoder (SSE2 bit operations / scalar) gives the same bits. */
  float *outp = malloc(sizeof(float) * R * S);
  ub_blend *bp = NULL;
  d.flags = UB_BLEND_PORTABLE;
  ASSERT_OK(ub_blend_create(&d, NULL, outp, &bp));
  if (bp) {
    ASSERT_OK(ub_blend_set_weight(bp, 0, one));
    ub_blend_update(bp, NULL, NULL, outp, NULL);
    ASSERT_TRUE(memcmp(out, outp, sizeof(float) * R * S) == 0);
  }
  ub_blend_free(bp);
  free(outp);
#if defined(__SSE2__)
  /* The caller's FTZ/DAZ mode changes nothing (half subnormals are float denormals inside
   * the kernel) and is restored. */
  float *out2 = malloc(sizeof(float) * R * S);
  memcpy(out2, base, sizeof(float) * R * S);
  unsigned csr = _mm_getcsr();
  _mm_setcsr(csr | 0x8040u);
  ub_blend_update_all(b, NULL, NULL, out2, NULL);
  unsigned after = _mm_getcsr();
  _mm_setcsr(csr);
  ASSERT_TRUE(after == (csr | 0x8040u));
  ASSERT_TRUE(memcmp(out, out2, sizeof(float) * R * S) == 0);
  free(out2);
#endif
  ub_blend_free(b);
  free(base);
  free(vals);
  free(idx);
  free(out);
}

/* ---- 3. random scenario ---------------------------------------------------------------- */

/* ub_blend_row against rows (the engine's last update), for n random receivers (all when
 * n >= R): the number that differ in any bit. tmask: receivers some element touches; an
 * engine owning its base (own) must answer 0 for the others, else the base row. */
static int row_mismatches(const ub_blend *b, const float *rows, const float *base,
                          const uint8_t *tmask, uint32_t R, uint32_t S, uint32_t n, int own)
{
  int bad = 0;
  float got[UB_BLEND_MAX_STRIDE];
  for (uint32_t i = 0; i < n && i < R; i++) {
    uint32_t r = n >= R ? i : rnd_below(R);
    int ok = ub_blend_row(b, r, got);
    const float *want = tmask[r] ? rows + (size_t)r * S : base + (size_t)r * S;
    if (own && !tmask[r])
      bad += ok != 0;
    else
      bad += ok != 1 || memcmp(got, want, S * sizeof(float)) != 0;
  }
  return bad;
}

static void scenario(uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st, int changes)
{
  /* Records: contiguous-ish blobs with holes, or scattered picks; sizes log-uniform; at
   * most 16 elements per receiver; a hub of 16 elements shares one region. */
  uint8_t **cover = malloc(sizeof(uint8_t *) * E);
  uint8_t *ov = calloc(R, 1);
  for (uint32_t e = 0; e < E; e++) {
    cover[e] = calloc(R, 1);
    uint32_t size = (uint32_t)(20.0 * pow(200.0, rnd()));
    if (e < 16) { /* the hub */
      for (uint32_t r = R / 3; r < R / 3 + 400; r++)
        if (ov[r] < 16 && rnd() < 0.97) {
          cover[e][r] = 1;
          ov[r]++;
        }
      continue;
    }
    if (rnd() < 0.7) {
      uint32_t start = rnd_below(R);
      for (uint32_t r = start; r < R && r < start + size; r++)
        if (ov[r] < 16 && rnd() < 0.95) {
          cover[e][r] = 1;
          ov[r]++;
        }
    } else {
      for (uint32_t i = 0; i < size; i++) {
        uint32_t r = rnd_below(R);
        if (ov[r] < 16 && !cover[e][r]) {
          cover[e][r] = 1;
          ov[r]++;
        }
      }
    }
  }
  free(ov);
  rep p;
  rep_init(&p, R, S, E, st, cover);
  for (uint32_t e = 0; e < E; e++)
    free(cover[e]);
  free(cover);

  size_t nf = (size_t)R * S;
  float *out = malloc(sizeof(float) * nf), *prev = malloc(sizeof(float) * nf);
  ub_blend *b = NULL;
  ub_blend_desc d = rep_desc(&p, "scenario");
  ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
  if (!b)
    return;
  ub_blend_info info;
  ub_blend_get_info(b, &info);
  ASSERT_TRUE(info.max_overlap == 16);
  printf("scenario R=%u S=%u E=%u %s: %u touched, %u groups (%u as runs, %llu runs), "
         "engine %zu B = %.2f B per membership\n", R, S, E,
         st == UB_BLEND_FLOAT16 ? "half" : "float", info.touched_receivers, info.group_count,
         info.run_groups, (unsigned long long)info.runs, info.engine_bytes,
         (double)info.engine_bytes / (double)info.memberships);

  /* A second engine in streaming mode (no out array) with the portable half decoder gets
   * the same weights; its callback copies the rows into `streamed`, which must equal out
   * bit for bit. */
  float *streamed = malloc(sizeof(float) * nf);
  ub_blend *bs = NULL;
  ub_blend_desc dp = d;
  dp.flags = UB_BLEND_PORTABLE | UB_BLEND_ROW_QUERY;
  ASSERT_OK(ub_blend_create(&dp, NULL, streamed, &bs));
  /* A third engine with UB_BLEND_OWN_BASE, created from a copy of base that is poisoned
   * (NaN) right after create: it must never read it again and give out's bits. */
  float *own_out = malloc(sizeof(float) * nf), *base_copy = malloc(sizeof(float) * nf);
  memcpy(base_copy, p.base, sizeof(float) * nf);
  ub_blend *bo = NULL;
  ub_blend_desc dow = d;
  dow.base = base_copy;
  dow.flags = UB_BLEND_OWN_BASE | UB_BLEND_ROW_QUERY;
  ASSERT_OK(ub_blend_create(&dow, NULL, own_out, &bo));
  for (size_t i = 0; i < nf; i++)
    base_copy[i] = NAN;
  int bad_own = 0, bad_rows = 0;
  /* Row queries (UB_BLEND_ROW_QUERY): the receivers some element touches. */
  uint8_t *tmask = rep_touched_mask(&p);
  if (bo) /* at create: every weight 0, the base rows */
    bad_rows += row_mismatches(bo, p.base, p.base, tmask, R, S, R, 1);
  uint8_t *changed = calloc(E, 1), *expect = calloc(R, 1);
  touch_log tl = {calloc(R, 1), 0, S, out, NULL, 0, 0, 0, 0};
  touch_log ts = {calloc(R, 1), 0, S, NULL, streamed, 0, 0, 0, 0};
  int bad_updates = 0, bad_values = 0;
  for (int c = 0; c < changes;) {
    /* 1..5 weight changes, then an update. */
    int nchg = 1 + (int)rnd_below(5);
    memset(changed, 0, E);
    for (int i = 0; i < nchg && c < changes; i++, c++) {
      uint32_t e = rnd_below(E);
      float rgb[3];
      float *cur = p.w + (size_t)e * 3;
      if (rnd() < 0.1)
        memcpy(rgb, cur, sizeof rgb); /* no change: must not dirty */
      else
        rnd_weight(rgb);
      if (rnd() < 0.05)
        rgb[0] = rgb[1] = rgb[2] = -0.0f; /* same as 0 */
      if (!(rgb[0] == cur[0] && rgb[1] == cur[1] && rgb[2] == cur[2]))
        changed[e] = 1;
      set_w(&p, b, e, rgb[0], rgb[1], rgb[2]);
      if (bs)
        ASSERT_OK(ub_blend_set_weight(bs, e, rgb));
      if (bo)
        ASSERT_OK(ub_blend_set_weight(bo, e, rgb));
    }
    memset(expect, 0, R);
    uint64_t nexp = 0;
    for (uint32_t e = 0; e < E; e++)
      if (changed[e])
        for (uint32_t i = 0; i < p.cnt[e]; i++)
          if (!expect[p.idx[e][i]]) {
            expect[p.idx[e][i]] = 1;
            nexp++;
          }
    memcpy(prev, out, sizeof(float) * nf);
    memset(tl.count, 0, R);
    tl.total = 0;
    ub_blend_stats stats;
    ub_blend_update(b, on_touched, &tl, out, &stats);
    int bad = stats.receivers != nexp || tl.total != nexp ||
              stats.bytes_written != nexp * S * sizeof(float);
    if (bs) {
      ub_blend_stats ss;
      memset(ts.count, 0, R);
      ts.total = 0;
      ts.last_count = 0;
      /* weights set, not yet updated: the rows are still the last update's */
      bad_rows += row_mismatches(bs, streamed, p.base, tmask, R, S, 200, 0);
      ub_blend_update(bs, on_touched, &ts, NULL, &ss);
      bad_rows += row_mismatches(bs, streamed, p.base, tmask, R, S, 200, 0);
      bad |= ss.receivers != nexp || ts.total != nexp || ss.bytes_written != 0 ||
             memcmp(streamed, out, sizeof(float) * nf) != 0 || memcmp(ts.count, tl.count, R);
    }
    for (uint32_t r = 0; r < R; r++) {
      if (tl.count[r] != expect[r])
        bad = 1; /* written more than once, or the wrong set */
      if (!expect[r] && memcmp(out + (size_t)r * S, prev + (size_t)r * S, sizeof(float) * S))
        bad = 1; /* a row nobody reported changed */
    }
    bad_updates += bad;
    if (bo) {
      bad_rows += row_mismatches(bo, own_out, p.base, tmask, R, S, 200, 1);
      ub_blend_update(bo, NULL, NULL, own_out, NULL);
      bad_own += memcmp(own_out, out, sizeof(float) * nf) != 0;
      bad_rows += row_mismatches(bo, own_out, p.base, tmask, R, S, 200, 1);
    }
    for (int i = 0; i < 300; i++)
      bad_values += !check_receiver(&p, out, rnd_below(R));
  }
  ASSERT_TRUE(bad_updates == 0);
  ASSERT_TRUE(bad_values == 0);
  ASSERT_TRUE(bo != NULL && bad_own == 0);
  if (bo) { /* every receiver's row query after the last update */
    bad_rows += row_mismatches(bo, own_out, p.base, tmask, R, S, R, 1);
    ub_blend_update_all(bo, NULL, NULL, own_out, NULL);
    bad_rows += row_mismatches(bo, own_out, p.base, tmask, R, S, R, 1);
  }
  printf("scenario R=%u S=%u: ub_blend_row differs from the update's rows at %d queries\n", R,
         S, bad_rows);
  ASSERT_TRUE(bad_rows == 0);
  if (bo) { /* all off: the touched rows come back from the engine's copy, bit for bit */
    float z[3] = {0, 0, 0};
    for (uint32_t e = 0; e < E; e++)
      ASSERT_OK(ub_blend_set_weight(bo, e, z));
    ub_blend_update(bo, NULL, NULL, own_out, NULL);
    ASSERT_TRUE(memcmp(own_out, p.base, sizeof(float) * nf) == 0);
    int bad_off = row_mismatches(bo, p.base, p.base, tmask, R, S, R, 1);
    ASSERT_TRUE(bad_off == 0);
  }
  free(tmask);
  ub_blend_free(bo);
  free(own_out);
  free(base_copy);
  ASSERT_TRUE(tl.rows_bad == 0);
  printf("scenario R=%u S=%u: %d streamed pieces over 32 receivers or not joined to the "
         "piece before them\n", R, S, ts.pieces_bad);
  ASSERT_TRUE(ts.pieces_bad == 0);
  ASSERT_TRUE(bs != NULL);
  ub_blend_free(bs);
  int bad_final = 0;
  for (uint32_t r = 0; r < R; r++)
    bad_final += !check_receiver(&p, out, r);
  ASSERT_TRUE(bad_final == 0);

  /* History independence: update_all and a fresh engine give the same bits. */
  float *first = malloc(sizeof(float) * nf);
  memcpy(first, out, sizeof(float) * nf);
  ub_blend_stats sa;
  ub_blend_update_all(b, NULL, NULL, out, &sa);
  ASSERT_TRUE(sa.receivers == info.touched_receivers);
  ASSERT_TRUE(memcmp(out, first, sizeof(float) * nf) == 0);
  float *fresh = malloc(sizeof(float) * nf);
  ub_blend *b2 = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, fresh, &b2));
  for (uint32_t e = 0; b2 && e < E; e++)
    ASSERT_OK(ub_blend_set_weight(b2, e, p.w + (size_t)e * 3));
  if (b2)
    ub_blend_update(b2, NULL, NULL, fresh, NULL);
  ASSERT_TRUE(memcmp(fresh, first, sizeof(float) * nf) == 0);
  ub_blend_free(b2);

  /* Toggling: all off → base bit for bit; back on → the first result bit for bit,
   * repeatedly (no drift). */
  float *saved = malloc(sizeof(float) * E * 3);
  memcpy(saved, p.w, sizeof(float) * E * 3);
  for (int rep_i = 0; rep_i < 5; rep_i++) {
    for (uint32_t e = 0; e < E; e++)
      set_w(&p, b, e, 0, 0, 0);
    ub_blend_update(b, NULL, NULL, out, NULL);
    ASSERT_TRUE(memcmp(out, p.base, sizeof(float) * nf) == 0);
    for (uint32_t e = 0; e < E; e++)
      set_w(&p, b, e, saved[3 * e], saved[3 * e + 1], saved[3 * e + 2]);
    ub_blend_update(b, NULL, NULL, out, NULL);
    ASSERT_TRUE(memcmp(out, first, sizeof(float) * nf) == 0);
  }
  /* Setting unchanged weights dirties nothing. */
  for (uint32_t e = 0; e < E; e++)
    set_w(&p, b, e, saved[3 * e], saved[3 * e + 1], saved[3 * e + 2]);
  ub_blend_stats s0;
  ub_blend_update(b, NULL, NULL, out, &s0);
  ASSERT_TRUE(s0.groups == 0 && s0.receivers == 0);

  ub_blend_free(b);
  free(saved);
  free(first);
  free(fresh);
  free(changed);
  free(expect);
  free(tl.count);
  free(ts.count);
  free(streamed);
  free(out);
  free(prev);
  rep_free(&p);
}

/* ---- 4. validation ----------------------------------------------------------------------- */

static int log_count;
static void count_log(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  (void)level;
  if (msg && msg[0])
    log_count++;
}

static void expect_create(const ub_blend_desc *d, ub_result want)
{
  float out[64];
  for (int i = 0; i < 64; i++)
    out[i] = 1234.5f;
  ub_blend *b = (ub_blend *)(uintptr_t)0x1;
  ub_log log = {count_log, NULL};
  log_count = 0;
  ub_result r = ub_blend_create(d, &log, out, &b);
  ASSERT_TRUE(r == want);
  ASSERT_TRUE(log_count == 1);
  ASSERT_TRUE(b == (ub_blend *)(uintptr_t)0x1); /* untouched */
  int same = 1;
  for (int i = 0; i < 64; i++)
    same &= out[i] == 1234.5f;
  ASSERT_TRUE(same);
}

static void test_validation(void)
{
  float base[4 * 12];
  for (int i = 0; i < 48; i++)
    base[i] = 0.25f;
  float vals[3 * 12];
  uint16_t hv[3 * 12];
  for (int i = 0; i < 36; i++) {
    vals[i] = 0.5f;
    hv[i] = ub_half_from_float(0.5f);
  }
  uint32_t good[3] = {0, 2, 3};
  ub_blend_record rec = {good, vals, 3};
  ub_blend_desc d = {"validation", 4, 12, base, UB_BLEND_FLOAT32, 1, &rec, 0, 0};

  float out[48];
  ub_blend *b = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
  ub_blend_free(b);
  ub_blend_free(NULL);

  uint32_t unsorted[3] = {0, 3, 2}, dup[3] = {0, 2, 2}, range[3] = {0, 2, 4};
  rec.receivers = unsorted;
  expect_create(&d, UB_ERR_INVALID_DATA);
  rec.receivers = dup;
  expect_create(&d, UB_ERR_INVALID_DATA);
  rec.receivers = range;
  expect_create(&d, UB_ERR_INVALID_DATA);
  rec.receivers = good;

  vals[17] = NAN;
  expect_create(&d, UB_ERR_INVALID_DATA);
  vals[17] = INFINITY;
  expect_create(&d, UB_ERR_INVALID_DATA);
  vals[17] = 0.5f;

  d.storage = UB_BLEND_FLOAT16;
  rec.values = hv;
  ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
  ub_blend_free(b);
  hv[30] = 0x7c00; /* +Inf */
  expect_create(&d, UB_ERR_INVALID_DATA);
  hv[30] = 0x7e01; /* NaN */
  expect_create(&d, UB_ERR_INVALID_DATA);
  hv[30] = ub_half_from_float(0.5f);

  base[40] = NAN;
  expect_create(&d, UB_ERR_INVALID_DATA);
  base[40] = 0.25f;

  d.stride = 10;
  expect_create(&d, UB_ERR_INVALID_ARGUMENT);
  d.stride = 51;
  expect_create(&d, UB_ERR_INVALID_ARGUMENT);
  d.stride = 12;
  d.storage = (ub_blend_storage)7;
  expect_create(&d, UB_ERR_INVALID_ARGUMENT);
  d.storage = UB_BLEND_FLOAT16;
  rec.values = NULL;
  expect_create(&d, UB_ERR_INVALID_ARGUMENT);
  rec.values = hv;

  /* Weights: range and finiteness. */
  ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
  float nanw[3] = {1, NAN, 1}, one[3] = {1, 1, 1}, w[3];
  ASSERT_TRUE(ub_blend_set_weight(b, 1, one) == UB_ERR_INVALID_ARGUMENT);
  ASSERT_TRUE(ub_blend_set_weight(b, 0, nanw) == UB_ERR_INVALID_ARGUMENT);
  ub_blend_weight(b, 0, w);
  ASSERT_TRUE(w[0] == 0 && w[1] == 0 && w[2] == 0);
  ASSERT_OK(ub_blend_set_weight(b, 0, one));
  ub_blend_weight(b, 0, w);
  ASSERT_TRUE(w[0] == 1 && w[1] == 1 && w[2] == 1);
  ub_blend_stats st;
  ub_blend_update(b, NULL, NULL, out, &st);
  ASSERT_TRUE(st.groups == 1 && st.receivers == 3 && st.bytes_written == 3 * 48);
  ASSERT_TRUE(out[0] == 0.75f && out[12] == 0.25f && out[24] == 0.75f);
  ub_blend_free(b);

  /* Degenerate shapes: no elements, an empty record, no receivers. */
  ub_blend_record empty = {NULL, NULL, 0};
  ub_blend_desc d0 = {"empty", 4, 12, base, UB_BLEND_FLOAT32, 1, &empty, 0, 0};
  ASSERT_OK(ub_blend_create(&d0, NULL, out, &b));
  ASSERT_OK(ub_blend_set_weight(b, 0, one));
  ub_blend_update(b, NULL, NULL, out, &st);
  ASSERT_TRUE(st.receivers == 0);
  ub_blend_free(b);
  ub_blend_desc d1 = {NULL, 0, 27, NULL, UB_BLEND_FLOAT32, 0, NULL, 0, 0};
  ASSERT_OK(ub_blend_create(&d1, NULL, NULL, &b));
  ub_blend_update_all(b, NULL, NULL, out, &st);
  ASSERT_TRUE(st.receivers == 0);
  ub_blend_free(b);
}

/* ---- 5. compact tables for coherent records ------------------------------------------- */

static void test_compact(void)
{
  /* 4 overlapping contiguous blobs over 100k receivers: few groups, all runs; the tables
   * are far below 4 bytes per membership. */
  const uint32_t R = 100000, E = 4;
  uint8_t **cover = malloc(sizeof(uint8_t *) * E);
  for (uint32_t e = 0; e < E; e++) {
    cover[e] = calloc(R, 1);
    for (uint32_t r = e * 15000; r < e * 15000 + 40000; r++)
      cover[e][r] = 1;
  }
  rep p;
  rep_init(&p, R, 12, E, UB_BLEND_FLOAT32, cover);
  for (uint32_t e = 0; e < E; e++)
    free(cover[e]);
  free(cover);
  ub_blend_desc d = rep_desc(&p, "compact");
  float *out = malloc(sizeof(float) * R * 12);
  ub_blend *b = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
  ub_blend_info in;
  ub_blend_get_info(b, &in);
  ASSERT_TRUE(in.run_groups == in.group_count && in.group_count == 7);
  ASSERT_TRUE(in.engine_bytes < 8192); /* incl. a 3 KB streaming scratch */
  for (uint32_t e = 0; e < E; e++)
    set_w(&p, b, e, 1.0f + e, 0.5f, 2.0f);
  ub_blend_update(b, NULL, NULL, out, NULL);
  int bad = 0;
  for (uint32_t r = 0; r < R; r += 7)
    bad += !check_receiver(&p, out, r);
  ASSERT_TRUE(bad == 0);
  ub_blend_free(b);
  free(out);
  rep_free(&p);
}

/* ---- UB_BLEND_STORE_HALF: float records kept as half = the caller's half records ---- */

static void test_store_half(uint32_t S)
{
  const uint32_t R = 64;
  float *base = calloc((size_t)R * S, sizeof(float));
  float *vf = malloc(sizeof(float) * R * S);
  uint16_t *vh = malloc(sizeof(uint16_t) * R * S);
  uint32_t *idx = malloc(sizeof(uint32_t) * R);
  for (uint32_t i = 0; i < R * S; i++) {
    vf[i] = (float)(sin(0.37 * i) * 1000.0 + 1e-3 * i); /* not all exact halves */
    vh[i] = ub_half_from_float(vf[i]);
    base[i] = (float)(0.5 * cos(0.11 * i));
  }
  for (uint32_t r = 0; r < R; r++)
    idx[r] = r;
  ub_blend_record rf = {idx, vf, R}, rh = {idx, vh, R};
  ub_blend_desc df = {"store half", R, S, base, UB_BLEND_FLOAT32, 1, &rf, UB_BLEND_STORE_HALF, 0};
  ub_blend_desc dh = {"half", R, S, base, UB_BLEND_FLOAT16, 1, &rh, 0, 0};
  float *of = malloc(sizeof(float) * R * S), *oh = malloc(sizeof(float) * R * S);
  ub_blend *bf = NULL, *bh = NULL;
  ASSERT_OK(ub_blend_create(&df, NULL, of, &bf));
  ASSERT_OK(ub_blend_create(&dh, NULL, oh, &bh));
  /* the records may go after create */
  memset(vf, 0xff, sizeof(float) * R * S);
  memset(vh, 0xff, sizeof(uint16_t) * R * S);
  if (bf && bh) {
    const float w[3] = {0.75f, -1.5f, 3.0f};
    ASSERT_OK(ub_blend_set_weight(bf, 0, w));
    ASSERT_OK(ub_blend_set_weight(bh, 0, w));
    ub_blend_update(bf, NULL, NULL, of, NULL);
    ub_blend_update(bh, NULL, NULL, oh, NULL);
    ASSERT_TRUE(memcmp(of, oh, sizeof(float) * R * S) == 0);
    ub_blend_info in;
    ub_blend_get_info(bf, &in);
    ASSERT_TRUE(in.record_bytes == (size_t)R * S * 2);
  }
  /* A float value beyond the half range is bad data with this flag. */
  float big[48];
  for (uint32_t i = 0; i < S; i++)
    big[i] = i == 1 ? 1e6f : 1.0f;
  ub_blend_record rb = {idx, big, 1};
  ub_blend_desc db = {"store half, too big", R, S, base, UB_BLEND_FLOAT32, 1, &rb,
                      UB_BLEND_STORE_HALF, 0};
  ub_blend *bb = NULL;
  ASSERT_TRUE(ub_blend_create(&db, NULL, NULL, &bb) == UB_ERR_INVALID_DATA && bb == NULL);
  ub_blend_free(bf);
  ub_blend_free(bh);
  free(base);
  free(vf);
  free(vh);
  free(idx);
  free(of);
  free(oh);
}

/* ---- UB_BLEND_STORE_Q8: 8-bit rows ------------------------------------------------------ */

/* An engine keeping 8-bit rows (AVX and portable; out array, streaming, row queries, parts)
 * gives the bits of a float engine whose records are ub_blend_q8_row of the given rows,
 * round after round; each kept value is within the stated bound of the given one. */
static void test_q8(uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st)
{
  /* Runs from random starts, every third element scattered (list groups), and a stretch
   * of 40 receivers every element covers: E overlaps. */
  uint8_t **cover = malloc(sizeof(uint8_t *) * E);
  for (uint32_t e = 0; e < E; e++) {
    cover[e] = calloc(R, 1);
    if (e % 3 == 2) {
      for (uint32_t i = 0; i < R / 20; i++)
        cover[e][rnd_below(R)] = 1;
    } else {
      uint32_t start = rnd_below(R), size = 10 + rnd_below(R / 4);
      for (uint32_t r = start; r < R && r < start + size; r++)
        cover[e][r] = rnd() < 0.9;
    }
    memset(cover[e] + R / 2, 1, 40);
  }
  rep p;
  rep_init(&p, R, S, E, st, cover);
  for (uint32_t e = 0; e < E; e++)
    free(cover[e]);
  free(cover);
  const size_t nf = (size_t)R * S;
  /* The dequantized rows, and the bound: DC = the half of the value, others within
   * v_max / 127 of the value (v_max: the row's largest non-DC |value|). */
  float **dq = calloc(E, sizeof *dq);
  ub_blend_record *rq = calloc(E, sizeof *rq);
  int bad_bound = 0, nonzero_err = 0;
  for (uint32_t e = 0; e < E; e++) {
    dq[e] = malloc(sizeof(float) * ((size_t)p.cnt[e] * S + 1));
    for (uint32_t i = 0; i < p.cnt[e]; i++) {
      const float *v = p.vf[e] + (size_t)i * S;
      float *o = dq[e] + (size_t)i * S;
      ub_blend_q8_row(S, v, o);
      float mx = 0.0f;
      for (uint32_t j = 3; j < S; j++)
        mx = fabsf(v[j]) > mx ? fabsf(v[j]) : mx;
      for (uint32_t j = 0; j < S; j++) {
        if (j < 3)
          bad_bound += o[j] != ub_half_to_float(ub_half_from_float(v[j]));
        else
          bad_bound += !(fabsf(o[j] - v[j]) <= mx / 127.0f);
        nonzero_err += j >= 3 && o[j] != v[j];
      }
    }
    rq[e] = (ub_blend_record){p.idx[e], dq[e], p.cnt[e]};
  }
  ASSERT_TRUE(bad_bound == 0);
  ASSERT_TRUE(S == 3 || nonzero_err > 0); /* it does quantize (stride 3: DC only) */
  /* engines: 0 q8 AVX(2) (out), 1 q8 portable (streaming), 2 q8 AVX(2) own half base
   * (parts, streaming), 3 q8 AVX without AVX2, own half base (streaming); 4 float
   * reference on the dequantized rows, 5 its own-half-base twin */
  enum { NQ = 4, NE = 6 };
  ub_blend *b[NE] = {0};
  float *out[NE];
  const uint32_t hbase = UB_BLEND_OWN_BASE | UB_BLEND_BASE_HALF;
  const uint32_t flags[NE] = {UB_BLEND_STORE_Q8 | UB_BLEND_ROW_QUERY,
                              UB_BLEND_STORE_Q8 | UB_BLEND_ROW_QUERY | UB_BLEND_PORTABLE,
                              UB_BLEND_STORE_Q8 | UB_BLEND_ROW_QUERY | hbase,
                              UB_BLEND_STORE_Q8 | UB_BLEND_ROW_QUERY | hbase | UB_BLEND_NO_AVX2,
                              UB_BLEND_ROW_QUERY, UB_BLEND_ROW_QUERY | hbase};
  const int ref_of[NQ] = {4, 4, 5, 5};
  for (int i = 0; i < NE; i++) {
    ub_blend_desc d = rep_desc(&p, "q8");
    if (i >= NQ) {
      d.storage = UB_BLEND_FLOAT32;
      d.elements = rq;
    }
    d.flags = flags[i];
    out[i] = malloc(sizeof(float) * nf);
    ASSERT_OK(ub_blend_create(&d, NULL, out[i], &b[i]));
    if (!b[i])
      return;
  }
  ASSERT_OK(ub_blend_reserve_parts(b[2], 3));
  ub_blend_info in;
  ub_blend_get_info(b[0], &in);
  ASSERT_TRUE(in.row_bytes == ub_blend_q8_row_bytes(S) &&
              in.record_bytes == in.memberships * ub_blend_q8_row_bytes(S));
  ASSERT_TRUE(ub_blend_q8_row_bytes(12) == 16 && ub_blend_q8_row_bytes(27) == 32);
  uint8_t *count = calloc(R, 1);
  int bad_bits = 0, bad_rows = 0, bad_sum = 0;
  float row[UB_BLEND_MAX_STRIDE];
  for (int round = 0; round < 40; round++) {
    const int all = round % 10 == 9;
    for (int c = 1 + (int)rnd_below(6); c > 0; c--) {
      uint32_t e = rnd_below(E);
      float w[3];
      rnd_weight(w);
      for (int i = 0; i < NE; i++)
        ASSERT_OK(ub_blend_set_weight(b[i], e, w));
      memcpy(p.w + (size_t)e * 3, w, sizeof w);
    }
    for (int i = 0; i < NE; i++) /* 1-3 streamed, 2 in 3 parts */
      update_as(b[i], out[i], count, R, S, i == 1 || i == 2 || i == 3, i == 2 ? 3 : 1, all,
                NULL);
    for (int i = 0; i < NQ; i++)
      bad_bits += memcmp(out[i], out[ref_of[i]], sizeof(float) * nf) != 0;
    for (uint32_t r = 0; r < R; r += 1 + rnd_below(5))
      for (int i = 0; i < NQ; i++) {
        if (ub_blend_row(b[i], r, row))
          bad_rows += memcmp(row, out[ref_of[i]] + (size_t)r * S, sizeof(float) * S) != 0;
        else
          bad_rows += p.off[r + 1] > p.off[r]; /* a touched receiver has a row */
      }
  }
  /* the naive sum over the dequantized rows */
  float **vf = p.vf;
  p.vf = dq;
  for (uint32_t r = 0; r < R; r += 3)
    bad_sum += !check_receiver(&p, out[0], r);
  p.vf = vf;
  ub_blend_get_info(b[0], &in);
  printf("q8 R=%u S=%u %s: %d differing updates, %d differing rows, %d bad sums, max overlap "
         "%u, %zu record bytes (%u a row)\n", R, S, st == UB_BLEND_FLOAT16 ? "half" : "float",
         bad_bits, bad_rows, bad_sum, in.max_overlap, in.record_bytes, in.row_bytes);
  ASSERT_TRUE(bad_bits == 0 && bad_rows == 0 && bad_sum == 0 && in.max_overlap == E);
  free(count);
  for (int i = 0; i < NE; i++) {
    ub_blend_free(b[i]);
    free(out[i]);
  }
  for (uint32_t e = 0; e < E; e++)
    free(dq[e]);
  free(dq);
  free(rq);
  rep_free(&p);
}

/* 700 stride-3 elements over one receiver: the decode scratch then holds exactly the
 * chunk's rows (dec_floats = max_overlap × stride), the last row at its end (the AVX
 * decoder writes 4 lanes per DC: a stride of 3 must take the scalar one). Every path
 * against the float engine on the rounded rows. */
static void test_q8_many_overlaps(void)
{
  enum { E = 700, S = 3, R = 2 };
  float base[R * S] = {0.5f, 0.25f, 1.0f, 2.0f, 3.0f, 4.0f};
  static float v[E][S], dq[E][S];
  static ub_blend_record rq[E], rf[E];
  const uint32_t idx[1] = {0};
  for (uint32_t e = 0; e < E; e++) {
    for (uint32_t j = 0; j < S; j++)
      v[e][j] = (float)(0.001 * (e + 1) * (j + 1));
    ub_blend_q8_row(S, v[e], dq[e]);
    rq[e] = (ub_blend_record){idx, v[e], 1};
    rf[e] = (ub_blend_record){idx, dq[e], 1};
  }
  const uint32_t fl[3] = {UB_BLEND_STORE_Q8, UB_BLEND_STORE_Q8 | UB_BLEND_NO_AVX2,
                          UB_BLEND_STORE_Q8 | UB_BLEND_PORTABLE};
  float ref[R * S], out[R * S];
  ub_blend_desc dr = {"q8 many, float", R, S, base, UB_BLEND_FLOAT32, E, rf, 0, 0};
  ub_blend *br = NULL;
  ASSERT_OK(ub_blend_create(&dr, NULL, ref, &br));
  const float w[3] = {0.5f, 1.0f, 2.0f};
  for (uint32_t e = 0; br && e < E; e++)
    ASSERT_OK(ub_blend_set_weight(br, e, w));
  if (br)
    ub_blend_update(br, NULL, NULL, ref, NULL);
  int bad = 0;
  for (int i = 0; i < 3; i++) {
    ub_blend_desc d = {"q8 many", R, S, base, UB_BLEND_FLOAT32, E, rq, fl[i], 0};
    ub_blend *b = NULL;
    ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
    if (!b)
      continue;
    for (uint32_t e = 0; e < E; e++)
      ASSERT_OK(ub_blend_set_weight(b, e, w));
    ub_blend_update(b, NULL, NULL, out, NULL);
    bad += memcmp(out, ref, sizeof out) != 0;
    ub_blend_free(b);
  }
  ASSERT_TRUE(bad == 0);
  ub_blend_free(br);
}

/* Rows at the ends of the float range: huge (1e35, FLT_MAX / 2), tiny (float denormals),
 * zeros: each value within v_max / 127 of the given one, DC its half. */
static void test_q8_extremes(void)
{
  const float rows[][12] = {
      {1, 2, 3, 1e35f, -3e33f, 1e30f, 7e34f, -1e35f, 0, 1, -1, 2e20f},
      {0, 0, 0, 1.7e38f, -1e38f, 3e37f, 0, 0, 0, 0, 0, 1},
      {1e-3f, 0, 0, 1e-40f, -3e-41f, 5e-39f, 0, 1e-45f, 0, 0, 0, 0},
      {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
      {65504, -65504, 1, 127.5f, -127.5f, 63.75f, 0.5f, -0.25f, 1e-8f, 100, -100, 0}};
  int bad = 0;
  for (size_t r = 0; r < sizeof rows / sizeof rows[0]; r++) {
    float o[12];
    ub_blend_q8_row(12, rows[r], o);
    float mx = 0.0f;
    for (int j = 3; j < 12; j++)
      mx = fabsf(rows[r][j]) > mx ? fabsf(rows[r][j]) : mx;
    /* below 2^-119 the step stays 2^-126 (the documented floor) */
    const float tol = mx < 0x1p-119f ? 0x1p-127f : mx / 127.0f;
    for (int j = 0; j < 12; j++) {
      int ok = j < 3 ? o[j] == ub_half_to_float(ub_half_from_float(rows[r][j]))
                     : isfinite(o[j]) && fabsf(o[j] - rows[r][j]) <= tol;
      if (!ok)
        fprintf(stderr, "q8 extremes: row %zu value %d: %g -> %g (v_max %g)\n", r, j,
                rows[r][j], o[j], mx);
      bad += !ok;
    }
  }
  ASSERT_TRUE(bad == 0);
}

/* Q8 inputs: with STORE_HALF refused; a float DC beyond the half range is bad data, a big
 * non-DC value is fine (its row's step grows). */
static void test_q8_validation(void)
{
  const uint32_t S = 12;
  float base[2 * 12] = {0}, v[12];
  uint32_t idx[1] = {1};
  for (uint32_t j = 0; j < S; j++)
    v[j] = j == 0 ? 1e6f : 1.0f;
  ub_blend_record rec = {idx, v, 1};
  ub_blend_desc d = {"q8 validation", 2, S, base, UB_BLEND_FLOAT32, 1, &rec, UB_BLEND_STORE_Q8, 0};
  expect_create(&d, UB_ERR_INVALID_DATA);
  v[0] = 1.0f;
  v[5] = 1e30f;
  float out[2 * 12];
  ub_blend *b = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
  if (b) {
    const float w[3] = {1, 1, 1};
    ASSERT_OK(ub_blend_set_weight(b, 0, w));
    ub_blend_update(b, NULL, NULL, out, NULL);
    float dq[12];
    ub_blend_q8_row(S, v, dq);
    ASSERT_TRUE(memcmp(out + S, dq, sizeof dq) == 0);
    /* the row's step follows its largest value: 1 next to 1e30 is lost (0) */
    ASSERT_TRUE(fabsf(dq[5] - 1e30f) <= 1e30f / 127 && dq[6] == 0.0f && dq[0] == 1.0f);
    ub_blend_free(b);
  }
  d.flags = UB_BLEND_STORE_Q8 | UB_BLEND_STORE_HALF;
  expect_create(&d, UB_ERR_INVALID_ARGUMENT);
}

/* ---- UB_BLEND_ONES_SUM: groups from their all-ones sums --------------------------------- */

/* With most weights 1, groups of 4+ members come from A = base + Σ S: AVX, portable,
 * streaming and parts agree bit for bit, row queries give the update's rows, the values
 * stay within the stated rounding bound of the plain engine's, fewer bytes are read, and a
 * state reached by two different histories has the same bits. */
static void test_ones(uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st, uint32_t xflags,
                      float ow)
{
  /* even elements: long runs without holes over one of three overlapping bands (groups of
   * many members over runs longer than a chunk); odd ones: random runs with holes, every
   * seventh scattered (list groups) */
  uint8_t **cover = malloc(sizeof(uint8_t *) * E);
  for (uint32_t e = 0; e < E; e++) {
    cover[e] = calloc(R, 1);
    if (e % 2 == 0) {
      const uint32_t band = (e / 2) % 3, a = band * R / 4;
      memset(cover[e] + a, 1, R / 2);
    } else if (e % 7 == 6) {
      for (uint32_t i = 0; i < R / 20; i++)
        cover[e][rnd_below(R)] = 1;
    } else {
      uint32_t start = rnd_below(R), size = 10 + rnd_below(R / 4);
      for (uint32_t r = start; r < R && r < start + size; r++)
        cover[e][r] = rnd() < 0.9;
    }
  }
  rep p;
  rep_init(&p, R, S, E, st, cover);
  for (uint32_t e = 0; e < E; e++)
    free(cover[e]);
  free(cover);
  const size_t nf = (size_t)R * S;
  enum { NE = 4 };
  const uint32_t own = UB_BLEND_OWN_BASE | UB_BLEND_ROW_QUERY | xflags;
  const uint32_t flags[NE] = {own | UB_BLEND_ONES_SUM, own | UB_BLEND_ONES_SUM | UB_BLEND_PORTABLE,
                              own | UB_BLEND_ONES_SUM, own};
  ub_blend *b[NE] = {0};
  float *out[NE];
  for (int i = 0; i < NE; i++) {
    ub_blend_desc d = rep_desc(&p, "ones");
    d.flags = flags[i];
    d.ones_weight = ow;
    out[i] = malloc(sizeof(float) * nf);
    ASSERT_OK(ub_blend_create(&d, NULL, out[i], &b[i]));
    if (!b[i])
      return;
  }
  ASSERT_OK(ub_blend_reserve_parts(b[2], 3));
  ub_blend_info in;
  ub_blend_get_info(b[0], &in);
  uint8_t *count = calloc(R, 1);
  int bad_bits = 0, bad_rows = 0, bad_tol = 0, fewer = 0;
  double worst = 0.0;
  float row[UB_BLEND_MAX_STRIDE];
  float *w1 = malloc(sizeof(float) * 3 * E); /* the weights the engines hold */
  for (int round = 0; round < 30; round++) {
    for (uint32_t e = 0; e < E; e++) {
      float w[3] = {ow, ow, ow};
      double x = rnd();
      if (round % 5 == 4)
        rnd_weight(w); /* some rounds: any weights (the plain form wins) */
      else if (x < 0.1)
        w[0] = w[1] = w[2] = 0.0f; /* a few off */
      else if (x < 0.15)
        w[0] = 0.5f, w[1] = 1.0f, w[2] = 1.75f; /* a few tinted */
      memcpy(w1 + 3 * e, w, sizeof w);
      for (int i = 0; i < NE; i++)
        ASSERT_OK(ub_blend_set_weight(b[i], e, w));
    }
    ub_blend_stats sto, stp;
    for (int i = 0; i < NE; i++) /* 1-2 streamed, 2 in 3 parts */
      update_as(b[i], out[i], count, R, S, i == 1 || i == 2, i == 2 ? 3 : 1, 1,
                i == 0 ? &sto : i == 3 ? &stp : NULL);
    bad_bits += memcmp(out[0], out[1], sizeof(float) * nf) != 0;
    bad_bits += memcmp(out[0], out[2], sizeof(float) * nf) != 0;
    fewer += sto.bytes_read < stp.bytes_read;
    for (uint32_t r = 0; r < R; r += 1 + rnd_below(3)) {
      if (ub_blend_row(b[0], r, row))
        bad_rows += memcmp(row, out[0] + (size_t)r * S, sizeof(float) * S) != 0;
      if (ub_blend_row(b[1], r, row))
        bad_rows += memcmp(row, out[0] + (size_t)r * S, sizeof(float) * S) != 0;
    }
    /* against the plain engine: the bound with the values as the engine holds them (the
     * plain engine's rows: base and records are the same bits in both) */
    for (uint32_t r = 0; r < R; r++) {
      uint32_t k = p.off[r + 1] - p.off[r];
      for (uint32_t j = 0; j < S; j++) {
        double mag = 0.0, base = fabs(p.base[(size_t)r * S + j]);
        double sumS = 0.0;
        for (uint32_t q = p.off[r]; q < p.off[r + 1]; q++) {
          uint32_t e = p.m_elem[q];
          double v = fabs(p.vf[e][(size_t)p.m_pos[q] * S + j]);
          double wv = w1[3 * e + j % 3];
          mag += (fabs(wv) + fabs(wv - ow) + fabs(ow)) * v;
          sumS += v;
        }
        mag += 2.0 * base + fabs(ow) * sumS + 1e-30; /* |A| ≤ |base| + |ω1|·Σ|S| */
        double u = 1.0 / 16777216.0, n = k + 2;
        double tol = n * u / (1.0 - n * u) * mag;
        double d = fabs((double)out[0][(size_t)r * S + j] - out[3][(size_t)r * S + j]);
        bad_tol += !(d <= tol);
        worst = d / tol > worst ? d / tol : worst;
      }
    }
  }
  /* history independence: a state reached twice from different states, same bits */
  float *snap = malloc(sizeof(float) * nf);
  for (uint32_t e = 0; e < E; e++)
    ASSERT_OK(ub_blend_set_weight(b[0], e, (const float[3]){ow, ow, ow}));
  ub_blend_update(b[0], NULL, NULL, out[0], NULL);
  memcpy(snap, out[0], sizeof(float) * nf);
  for (uint32_t e = 0; e < E; e++)
    ASSERT_OK(ub_blend_set_weight(b[0], e, (const float[3]){0.25f, 0, 3}));
  ub_blend_update(b[0], NULL, NULL, out[0], NULL);
  for (uint32_t e = 0; e < E; e++)
    ASSERT_OK(ub_blend_set_weight(b[0], e, (const float[3]){ow, ow, ow}));
  ub_blend_update(b[0], NULL, NULL, out[0], NULL);
  const int same = memcmp(snap, out[0], sizeof(float) * nf) == 0;
  printf("ones sums R=%u S=%u %s%s at %g: %d differing updates, %d differing rows, %d values over "
         "the bound (worst %.2f of it), fewer bytes read in %d of 30 rounds, history %s; "
         "engine %zu bytes\n", R, S, st == UB_BLEND_FLOAT16 ? "half" : "float",
         (xflags & UB_BLEND_STORE_Q8) ? " q8" : "", ow, bad_bits, bad_rows, bad_tol, worst, fewer,
         same ? "independent" : "DEPENDENT", in.engine_bytes);
  ASSERT_TRUE(bad_bits == 0 && bad_rows == 0 && bad_tol == 0 && same && fewer >= 20);
  free(snap);
  free(w1);
  free(count);
  for (int i = 0; i < NE; i++) {
    ub_blend_free(b[i]);
    free(out[i]);
  }
  rep_free(&p);
}

/* ---- the reference state ---------------------------------------------------------- */

typedef struct ref_log {
  uint8_t *count;     /* per receiver: times reported */
  uint32_t S;
  float *out;         /* the rows as the caller keeps them */
  const float *kept;  /* the rows at the reference */
  uint64_t at_ref;    /* receivers reported as UB_BLEND_AT_REFERENCE */
  uint32_t *seq;      /* the receivers in the order reported (R entries at most) */
  uint32_t nseq;
  const float *based; /* the rows with every weight 0 (ub_blend_set_base_report) */
  uint64_t at_base;   /* receivers reported as UB_BLEND_AT_BASE */
} ref_log;

static void on_ref(void *user, uint32_t first, uint32_t count, const float *rows)
{
  ref_log *t = user;
  for (uint32_t i = 0; i < count; i++) {
    if (t->count[first + i] < 255)
      t->count[first + i]++;
    if (t->count[first + i] == 1)
      t->seq[t->nseq++] = first + i;
  }
  const size_t at = (size_t)first * t->S, n = (size_t)count * t->S;
  if (rows == UB_BLEND_AT_REFERENCE) {
    memcpy(t->out + at, t->kept + at, sizeof(float) * n);
    t->at_ref += count;
  } else if (rows == UB_BLEND_AT_BASE) {
    memcpy(t->out + at, t->based + at, sizeof(float) * n);
    t->at_base += count;
  } else {
    memcpy(t->out + at, rows, sizeof(float) * n);
  }
}

/* A streaming update of b into log (on_ref): plain, or (parts) in 3 parts run in reverse;
 * *sb: the receivers, those at the reference and those at the base. */
static void update_streaming(ub_blend *b, int parts, ref_log *log, ub_blend_stats *sb)
{
  memset(sb, 0, sizeof *sb);
  if (!parts) {
    ub_blend_update(b, on_ref, log, NULL, sb);
    return;
  }
  ub_blend_update_begin(b, 0);
  for (uint32_t q = 0; q < 3; q++) {
    ub_blend_stats sq;
    ub_blend_update_part(b, 2 - q, 3, on_ref, log, NULL, &sq);
    sb->receivers += sq.receivers;
    sb->receivers_reference += sq.receivers_reference;
    sb->receivers_base += sq.receivers_base;
  }
}

/* ub_blend_set_reference: a streaming engine with a reference state against one without,
 * 60 rounds of a few elements changed (back to their reference weight, off, or any
 * weight), plain and in 3 parts, every update and the whole state: the same rows and the
 * same receivers reported, once each; every receiver at the reference when every weight
 * is, in the same order; refused with a change pending; row queries give the rows. With
 * UB_BLEND_OWN_BASE also an engine updating an out array with ub_blend_set_reference_rows
 * (back rounds in 5 parts, groups at the reference cut between parts): the same rows; and
 * after ub_blend_set_reference its kept rows are gone (not put back stale). */
static void test_reference(uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st,
                           uint32_t xflags)
{
  rep p;
  rep_init_runs(&p, R, S, E, st, 5);
  const size_t nf = (size_t)R * S;
  ub_blend *ba = NULL, *bb = NULL;
  ub_blend_desc d = rep_desc(&p, "reference");
  d.flags = xflags;
  float *oa = malloc(sizeof(float) * nf), *ob = malloc(sizeof(float) * nf);
  float *kept = malloc(sizeof(float) * nf), *wref = malloc(sizeof(float) * 3 * E);
  uint8_t *ca = calloc(R, 1), *cb = calloc(R, 1);
  uint32_t *qa = malloc(sizeof(uint32_t) * R), *qb = malloc(sizeof(uint32_t) * R);
  float row[UB_BLEND_MAX_STRIDE];
  ASSERT_OK(ub_blend_create(&d, NULL, oa, &ba));
  ASSERT_OK(ub_blend_create(&d, NULL, ob, &bb));
  if (!ba || !bb) {
    ub_blend_free(ba);
    ub_blend_free(bb);
    return;
  }
  ASSERT_OK(ub_blend_reserve_parts(bb, 3));
  const int own = (xflags & UB_BLEND_OWN_BASE) != 0;
  ub_blend *bc = NULL; /* out array, rows kept by the engine */
  float *oc = malloc(sizeof(float) * nf);
  uint8_t *cc = calloc(R, 1);
  if (own) {
    ASSERT_OK(ub_blend_create(&d, NULL, oc, &bc));
    ASSERT_OK(ub_blend_reserve_parts(bc, 5));
  } else {
    ASSERT_OK(ub_blend_create(&d, NULL, oc, &bc));
    ASSERT_TRUE(bc && ub_blend_set_reference_rows(bc, oc) == UB_ERR_INVALID_ARGUMENT);
    ub_blend_free(bc);
    bc = NULL;
  }
  for (uint32_t e = 0; e < E; e++) { /* the reference: most elements on, some tinted */
    float w[3] = {1.0f, 1.0f, 1.0f};
    if (e % 4 == 1)
      rnd_weight(w);
    memcpy(wref + 3 * e, w, sizeof w);
    ASSERT_OK(ub_blend_set_weight(ba, e, w));
    ASSERT_OK(ub_blend_set_weight(bb, e, w));
    if (bc)
      ASSERT_OK(ub_blend_set_weight(bc, e, w));
  }
  update_as(ba, oa, ca, R, S, 1, 1, 1, NULL);
  update_as(bb, ob, cb, R, S, 1, 1, 1, NULL);
  if (bc) {
    update_as(bc, oc, cc, R, S, 0, 1, 1, NULL);
    ASSERT_OK(ub_blend_set_reference_rows(bc, oc));
  }
  ASSERT_OK(ub_blend_set_weight(bb, 0, (const float[3]){0.5f, 0.5f, 0.5f}));
  ASSERT_TRUE(ub_blend_set_reference(bb) == UB_ERR_INVALID_ARGUMENT); /* a change pending */
  ASSERT_OK(ub_blend_set_weight(bb, 0, wref));
  update_as(bb, ob, cb, R, S, 1, 1, 0, NULL);
  ASSERT_OK(ub_blend_set_reference(bb));
  memcpy(kept, ob, sizeof(float) * nf);
  int bad_rows = 0, bad_count = 0, all_ref = 1;
  uint64_t at_ref = 0, reported = 0;
  for (int round = 0; round < 60; round++) {
    const int back = round % 15 == 14; /* every weight back to the reference */
    const uint32_t nchg = back ? E : 1 + rnd_below(3);
    for (uint32_t c = 0; c < nchg; c++) {
      const uint32_t e = back ? c : rnd_below(E);
      float w[3];
      const double x = rnd();
      if (back || x < 0.45)
        memcpy(w, wref + 3 * e, sizeof w);
      else if (x < 0.75)
        w[0] = w[1] = w[2] = 0.0f;
      else
        rnd_weight(w);
      ASSERT_OK(ub_blend_set_weight(ba, e, w));
      ASSERT_OK(ub_blend_set_weight(bb, e, w));
      if (bc)
        ASSERT_OK(ub_blend_set_weight(bc, e, w));
    }
    memset(ca, 0, R);
    ref_log ra = {ca, S, oa, NULL, 0, qa, 0, NULL, 0};
    ub_blend_update(ba, on_ref, &ra, NULL, NULL);
    memset(cb, 0, R);
    ref_log rl = {cb, S, ob, kept, 0, qb, 0, NULL, 0};
    ub_blend_stats sb;
    update_streaming(bb, round % 3 == 2, &rl, &sb);
    if (bc) { /* out array: plain or in 3 or 5 parts */
      update_as(bc, oc, cc, R, S, 0, back ? 5 : round % 3 == 1 ? 3 : 1, 0, NULL);
      bad_rows += memcmp(oa, oc, sizeof(float) * nf) != 0;
    }
    bad_rows += memcmp(oa, ob, sizeof(float) * nf) != 0;
    bad_count += ra.nseq != rl.nseq; /* the order too, where bb's parts ran in order */
    bad_count += round % 3 != 2 && memcmp(qa, qb, sizeof(uint32_t) * ra.nseq) != 0;
    if (xflags & UB_BLEND_ROW_QUERY)
      for (uint32_t r = round; r < R; r += 97)
        if (ub_blend_row(bb, r, row))
          bad_rows += memcmp(row, ob + (size_t)r * S, sizeof(float) * S) != 0;
    bad_count += memcmp(ca, cb, R) != 0 || (bc && memcmp(ca, cc, R) != 0);
    for (uint32_t r = 0; r < R; r++)
      bad_count += cb[r] > 1;
    bad_count += sb.receivers_reference != rl.at_ref;
    at_ref += rl.at_ref;
    reported += sb.receivers;
    if (back)
      all_ref &= sb.receivers > 0 && sb.receivers_reference == sb.receivers;
  }
  if (bc) { /* a reference without rows (at another state): the kept rows must go */
    const float w3[3] = {1.5f, 0.25f, 0.5f};
    for (uint32_t e = 0; e < E; e += 2) {
      memcpy(wref + 3 * e, w3, sizeof w3);
      ASSERT_OK(ub_blend_set_weight(ba, e, w3));
      ASSERT_OK(ub_blend_set_weight(bc, e, w3));
    }
    ub_blend_update(ba, NULL, NULL, oa, NULL);
    update_as(bc, oc, cc, R, S, 0, 1, 0, NULL);
    ASSERT_OK(ub_blend_set_reference(bc));
    const float w2[3] = {0.3f, 0.6f, 0.9f};
    for (uint32_t e = 0; e < E; e += 2) {
      ASSERT_OK(ub_blend_set_weight(ba, e, w2));
      ASSERT_OK(ub_blend_set_weight(bc, e, w2));
    }
    ub_blend_update(ba, NULL, NULL, oa, NULL); /* (ba's out array: any state will do) */
    update_as(bc, oc, cc, R, S, 0, 1, 0, NULL);
    for (uint32_t e = 0; e < E; e += 2) {
      ASSERT_OK(ub_blend_set_weight(ba, e, wref + 3 * e));
      ASSERT_OK(ub_blend_set_weight(bc, e, wref + 3 * e));
    }
    ub_blend_update(ba, NULL, NULL, oa, NULL);
    update_as(bc, oc, cc, R, S, 0, 1, 0, NULL);
    bad_rows += memcmp(oa, oc, sizeof(float) * nf) != 0;
  }
  printf("reference R=%u S=%u %s%s: 60 rounds, %d with differing rows, %d with differing "
         "reports (want 0); %llu of %llu receivers put back from the reference, all of them "
         "when every weight is back: %s\n", R, S, st == UB_BLEND_FLOAT16 ? "half" : "float",
         (xflags & UB_BLEND_STORE_Q8) ? " q8" : "", bad_rows, bad_count,
         (unsigned long long)at_ref, (unsigned long long)reported, all_ref ? "yes" : "NO");
  ASSERT_TRUE(bad_rows == 0 && bad_count == 0 && all_ref && at_ref > 0 && at_ref < reported);
  ub_blend_free(ba);
  ub_blend_free(bb);
  ub_blend_free(bc);
  free(oa);
  free(ob);
  free(oc);
  free(cc);
  free(qa);
  free(qb);
  free(kept);
  free(wref);
  free(ca);
  free(cb);
  rep_free(&p);
}

/* ub_blend_set_base_report: a streaming engine reporting its all-zero groups against one
 * streaming them, 60 rounds of a few elements changed (off, on, or any weight; every
 * weight 0 every 15th round), plain and in 3 parts run in reverse: the same rows (the
 * reported ones from the rows an update with every weight 0 streamed) and the same
 * receivers reported, once each; every receiver at the base when every weight is 0. */
static void test_base_report(uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st,
                             uint32_t xflags)
{
  rep p;
  rep_init_runs(&p, R, S, E, st, 5);
  const size_t nf = (size_t)R * S;
  ub_blend_desc d = rep_desc(&p, "base report");
  d.flags = xflags;
  float *oa = calloc(nf, sizeof(float)), *ob = calloc(nf, sizeof(float));
  float *based = calloc(nf, sizeof(float));
  uint8_t *ca = calloc(R, 1), *cb = calloc(R, 1);
  uint32_t *qa = malloc(sizeof(uint32_t) * R), *qb = malloc(sizeof(uint32_t) * R);
  ub_blend *ba = NULL, *bb = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, NULL, &ba));
  ASSERT_OK(ub_blend_create(&d, NULL, NULL, &bb));
  if (!ba || !bb || !oa || !ob || !based || !ca || !cb || !qa || !qb) {
    ASSERT_TRUE(0);
    goto done;
  }
  ASSERT_OK(ub_blend_reserve_parts(bb, 3));
  { /* the caller's base product: what an update with every weight 0 streams */
    ref_log z = {ca, S, based, NULL, 0, qa, 0, NULL, 0};
    ub_blend_update_all(bb, on_ref, &z, NULL, NULL);
    memset(ca, 0, R);
  }
  ub_blend_set_base_report(bb, 1);
  int bad_rows = 0, bad_count = 0, all_base = 1;
  uint64_t at_base = 0, reported = 0;
  for (int round = 0; round < 60; round++) {
    const int zero = round % 15 == 14;
    const uint32_t nchg = zero ? E : 1 + rnd_below(4);
    for (uint32_t c = 0; c < nchg; c++) {
      const uint32_t e = zero ? c : rnd_below(E);
      float w[3] = {0.0f, 0.0f, 0.0f};
      const double x = rnd();
      if (!zero && x >= 0.5) {
        w[0] = w[1] = w[2] = 1.0f;
        if (x >= 0.8)
          rnd_weight(w);
      }
      ASSERT_OK(ub_blend_set_weight(ba, e, w));
      ASSERT_OK(ub_blend_set_weight(bb, e, w));
    }
    memset(ca, 0, R);
    memset(cb, 0, R);
    ref_log ra = {ca, S, oa, NULL, 0, qa, 0, NULL, 0};
    ref_log rb = {cb, S, ob, NULL, 0, qb, 0, based, 0};
    ub_blend_update(ba, on_ref, &ra, NULL, NULL);
    ub_blend_stats sb;
    update_streaming(bb, round % 3 == 2, &rb, &sb);
    bad_rows += memcmp(oa, ob, sizeof(float) * nf) != 0;
    bad_count += ra.nseq != rb.nseq || memcmp(ca, cb, R) != 0;
    bad_count += round % 3 != 2 && memcmp(qa, qb, sizeof(uint32_t) * ra.nseq) != 0;
    for (uint32_t r = 0; r < R; r++)
      bad_count += cb[r] > 1;
    bad_count += sb.receivers_base != rb.at_base || rb.at_ref != 0;
    at_base += rb.at_base;
    reported += sb.receivers;
    if (zero)
      all_base &= sb.receivers > 0 && sb.receivers_base == sb.receivers;
  }
  printf("base report R=%u S=%u %s: 60 rounds, %d with differing rows, %d with differing "
         "reports (want 0); %llu of %llu receivers reported at the base, all of them when "
         "every weight is 0: %s\n", R, S, st == UB_BLEND_FLOAT16 ? "half" : "float", bad_rows,
         bad_count, (unsigned long long)at_base, (unsigned long long)reported,
         all_base ? "yes" : "NO");
  ASSERT_TRUE(bad_rows == 0 && bad_count == 0 && all_base && at_base > 0 && at_base < reported);
done:
  ub_blend_free(ba);
  ub_blend_free(bb);
  free(oa);
  free(ob);
  free(based);
  free(ca);
  free(cb);
  free(qa);
  free(qb);
  rep_free(&p);
}

/* Reference rows with groups cut between parts: a few long runs (bands without holes),
 * elements off and back in 7 parts, against an engine without a reference. */
static void test_reference_parts(void)
{
  enum { R = 3000, S = 12, E = 6 };
  uint8_t **cover = malloc(sizeof(uint8_t *) * E);
  for (uint32_t e = 0; e < E; e++) {
    cover[e] = calloc(R, 1);
    memset(cover[e] + (e % 3) * R / 4, 1, R / 2);
  }
  rep p;
  rep_init(&p, R, S, E, UB_BLEND_FLOAT16, cover);
  for (uint32_t e = 0; e < E; e++)
    free(cover[e]);
  free(cover);
  ub_blend_desc d = rep_desc(&p, "reference parts");
  d.flags = UB_BLEND_OWN_BASE | UB_BLEND_BASE_HALF;
  float *oa = malloc(sizeof(float) * R * S), *ob = malloc(sizeof(float) * R * S);
  uint8_t *cnt = calloc(R, 1);
  ub_blend *ba = NULL, *bb = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, oa, &ba));
  ASSERT_OK(ub_blend_create(&d, NULL, ob, &bb));
  if (!ba || !bb || !oa || !ob || !cnt)
    return;
  ASSERT_OK(ub_blend_reserve_parts(ba, 7));
  ASSERT_OK(ub_blend_reserve_parts(bb, 7));
  const float on[3] = {1.0f, 1.0f, 1.0f}, off[3] = {0.0f, 0.0f, 0.0f};
  for (uint32_t e = 0; e < E; e++) {
    ASSERT_OK(ub_blend_set_weight(ba, e, on));
    ASSERT_OK(ub_blend_set_weight(bb, e, on));
  }
  update_as(ba, oa, cnt, R, S, 0, 1, 1, NULL);
  update_as(bb, ob, cnt, R, S, 0, 1, 1, NULL);
  ASSERT_OK(ub_blend_set_reference_rows(bb, ob));
  int bad = 0;
  uint64_t at_ref = 0;
  for (uint32_t e = 0; e < E; e++)
    for (int ph = 0; ph < 2; ph++) {
      ASSERT_OK(ub_blend_set_weight(ba, e, ph ? on : off));
      ASSERT_OK(ub_blend_set_weight(bb, e, ph ? on : off));
      update_as(ba, oa, cnt, R, S, 0, 7, 0, NULL);
      ub_blend_update_begin(bb, 0);
      for (uint32_t q = 0; q < 7; q++) {
        ub_blend_stats sq;
        ub_blend_update_part(bb, q, 7, NULL, NULL, ob, &sq);
        at_ref += sq.receivers_reference;
      }
      bad += memcmp(oa, ob, sizeof(float) * R * S) != 0;
    }
  printf("reference rows, long runs in 7 parts: %d of %d updates differ (want 0), %llu "
         "receivers put back\n", bad, 2 * E, (unsigned long long)at_ref);
  ASSERT_TRUE(bad == 0 && at_ref > 0);
  ub_blend_free(ba);
  ub_blend_free(bb);
  free(oa);
  free(ob);
  free(cnt);
  rep_free(&p);
}

/* One group of 40 members (more than ub_blend_row lists: its scalar loop) from its
 * all-ones sums: row queries give the update's rows, AVX and portable the same bits, with
 * half and 8-bit records. */
static void test_ones_many(uint32_t S, uint32_t q8)
{
  enum { E = 40, R = 100 };
  float *base = malloc(sizeof(float) * R * S);
  float *vals = malloc(sizeof(float) * E * R * S);
  uint32_t idx[R];
  ub_blend_record rec[E];
  for (uint32_t r = 0; r < R; r++)
    idx[r] = r;
  for (size_t i = 0; i < (size_t)R * S; i++)
    base[i] = (float)(rnd() * 2.0);
  for (uint32_t e = 0; e < E; e++) {
    for (size_t i = 0; i < (size_t)R * S; i++)
      vals[(size_t)e * R * S + i] = rnd_value();
    rec[e] = (ub_blend_record){idx, vals + (size_t)e * R * S, R};
  }
  const uint32_t fl = UB_BLEND_OWN_BASE | UB_BLEND_ROW_QUERY | UB_BLEND_ONES_SUM | q8;
  float *out[2];
  ub_blend *b[2] = {0};
  for (int i = 0; i < 2; i++) {
    ub_blend_desc d = {"ones many", R, S, base, UB_BLEND_FLOAT32, E, rec,
                       fl | (i ? UB_BLEND_PORTABLE : 0u), 0};
    out[i] = malloc(sizeof(float) * R * S);
    ASSERT_OK(ub_blend_create(&d, NULL, out[i], &b[i]));
  }
  int bad = 0;
  float row[UB_BLEND_MAX_STRIDE];
  for (int round = 0; round < 4 && b[0] && b[1]; round++) {
    for (uint32_t e = 0; e < E; e++) {
      float w[3] = {1, 1, 1};
      if ((e + round) % 13 == 0)
        w[0] = w[1] = w[2] = 0.0f; /* a few off: from the sums */
      if (round == 3)
        rnd_weight(w); /* any: the plain form */
      for (int i = 0; i < 2; i++)
        ASSERT_OK(ub_blend_set_weight(b[i], e, w));
    }
    ub_blend_update(b[0], NULL, NULL, out[0], NULL);
    ub_blend_update(b[1], NULL, NULL, out[1], NULL);
    bad += memcmp(out[0], out[1], sizeof(float) * R * S) != 0;
    for (uint32_t r = 0; r < R; r++)
      for (int i = 0; i < 2; i++)
        bad += !ub_blend_row(b[i], r, row) || memcmp(row, out[0] + (size_t)r * S,
                                                     sizeof(float) * S) != 0;
  }
  ASSERT_TRUE(bad == 0);
  for (int i = 0; i < 2; i++) {
    ub_blend_free(b[i]);
    free(out[i]);
  }
  free(base);
  free(vals);
}

/* ---- parallel updates (ub_blend_update_begin / _part) ------------------------------- */

typedef struct part_job {
  ub_blend *b;
  uint32_t part, parts;
  float *out;          /* NULL: streaming into log.copy */
  touch_log log;       /* this part's reports (count shared: disjoint receivers) */
  ub_blend_stats st;
} part_job;

static void *part_main(void *arg)
{
  part_job *j = arg;
  ub_blend_update_part(j->b, j->part, j->parts, on_touched, &j->log, j->out, &j->st);
  return NULL;
}

/* Engines updated in parts on threads (2, 3, 7 parts, out array and streaming) against a
 * plain engine under the same weight changes: every row bit-identical, every touched
 * receiver reported exactly once in all, the parts' stats adding up to the plain update's. */
static void test_parts(uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st)
{
  rep p;
  rep_init_runs(&p, R, S, E, st, 0);
  const size_t nf = (size_t)R * S;
  enum { NE = 4 };
  const uint32_t parts_of[NE] = {1, 2, 3, 7};
  const int stream_of[NE] = {0, 0, 1, 1};
  ub_blend *b[NE + 1] = {0};
  float *out[NE + 1];
  ub_blend_desc d = rep_desc(&p, "parts");
  for (int i = 0; i <= NE; i++) {
    out[i] = malloc(sizeof(float) * nf);
    d.flags = i < NE && (i & 1) ? UB_BLEND_OWN_BASE : 0; /* both ways of holding base rows */
    ASSERT_OK(ub_blend_create(&d, NULL, out[i], &b[i]));
    if (!b[i])
      return;
    if (i < NE)
      ASSERT_OK(ub_blend_reserve_parts(b[i], parts_of[i]));
  }
  ASSERT_TRUE(ub_blend_reserve_parts(b[0], 0) == UB_ERR_INVALID_ARGUMENT);
  ASSERT_TRUE(ub_blend_reserve_parts(b[0], UB_BLEND_MAX_PARTS + 1) == UB_ERR_INVALID_ARGUMENT);
  uint8_t *count = calloc(R, 1), *ref_count = calloc(R, 1);
  int bad_bits = 0, bad_reports = 0, bad_stats = 0, nonempty_parts = 0;
  for (int round = 0; round < 60; round++) {
    int all = round % 10 == 9;
    for (int c = 1 + (int)rnd_below(4); c > 0; c--) {
      uint32_t e = rnd_below(E);
      float w[3];
      rnd_weight(w);
      if (rnd() < 0.3)
        w[0] = w[1] = w[2] = 0.0f;
      for (int i = 0; i <= NE; i++)
        ASSERT_OK(ub_blend_set_weight(b[i], e, w));
    }
    ub_blend_stats ref;
    memset(ref_count, 0, R);
    touch_log rl = {ref_count, 0, S, out[NE], NULL, 0, 0, 0, 0};
    if (all)
      ub_blend_update_all(b[NE], on_touched, &rl, out[NE], &ref);
    else
      ub_blend_update(b[NE], on_touched, &rl, out[NE], &ref);
    for (int i = 0; i < NE; i++) {
      const uint32_t P = parts_of[i];
      part_job jobs[7];
      pthread_t th[7];
      memset(count, 0, R);
      ub_blend_update_begin(b[i], all);
      for (uint32_t q = 0; q < P; q++) {
        jobs[q] = (part_job){b[i], q, P, stream_of[i] ? NULL : out[i],
                             {count, 0, S, stream_of[i] ? NULL : out[i],
                              stream_of[i] ? out[i] : NULL, 0, 0, 0, 0}, {0}};
        ASSERT_TRUE(pthread_create(&th[q], NULL, part_main, &jobs[q]) == 0);
      }
      uint64_t recv = 0, groups = 0, bytes = 0, written = 0, gbase = 0;
      for (uint32_t q = 0; q < P; q++) {
        pthread_join(th[q], NULL);
        recv += jobs[q].st.receivers;
        groups += jobs[q].st.groups;
        bytes += jobs[q].st.bytes_read;
        written += jobs[q].st.bytes_written;
        gbase += jobs[q].st.groups_base;
        bad_reports += jobs[q].log.rows_bad;
        nonempty_parts += jobs[q].st.groups > 0 && P > 1;
      }
      bad_stats += recv != ref.receivers || groups != ref.groups || bytes != ref.bytes_read ||
                   (!stream_of[i] && written != ref.bytes_written) || gbase != ref.groups_base;
      /* the receivers the plain update reported, each once (all: every touched one) */
      for (uint32_t r = 0; r < R; r++) {
        uint32_t touched = p.off[r + 1] > p.off[r];
        bad_reports += count[r] != ref_count[r] || (all && count[r] != touched);
      }
      bad_bits += memcmp(out[i], out[NE], sizeof(float) * nf) != 0;
    }
  }
  printf("parts R=%u S=%u %s: %d of %d engine-updates differ in bits, %d bad reports, "
         "%d bad stats, %d non-empty parts\n", R, S, st == UB_BLEND_FLOAT16 ? "half" : "float",
         bad_bits, 60 * NE, bad_reports, bad_stats, nonempty_parts);
  ASSERT_TRUE(bad_bits == 0 && bad_reports == 0 && bad_stats == 0);
  ASSERT_TRUE(nonempty_parts > 60); /* the splits did split */
  free(count);
  free(ref_count);
  for (int i = 0; i <= NE; i++) {
    ub_blend_free(b[i]);
    free(out[i]);
  }
  rep_free(&p);
}

/* ---- UB_BLEND_BASE_HALF: base rows kept as half × a power of two ------------------- */

/* An engine keeping its base rows as half (AVX, portable, streaming, split into parts)
 * gives the bits of a float engine whose base is the rounded rows, round after round. */
static void test_base_half(uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st)
{
  rep p;
  rep_init_runs(&p, R, S, E, st, 3); /* every third element scattered: list groups */
  const size_t nf = (size_t)R * S;
  uint8_t *tmask = rep_touched_mask(&p);
  /* bright values beyond the half range (a scale > 1) and tiny ones (half subnormals) */
  for (size_t i = 0; i < nf; i++) {
    double x = rnd();
    if (x < 0.01)
      p.base[i] *= 3e5f;
    else if (x < 0.03)
      p.base[i] *= 1e-6f;
  }
  ub_blend_desc d = rep_desc(&p, "base half");
  d.flags = UB_BLEND_BASE_HALF; /* without UB_BLEND_OWN_BASE: refused */
  ub_blend *bad = NULL;
  ASSERT_TRUE(ub_blend_create(&d, NULL, NULL, &bad) == UB_ERR_INVALID_ARGUMENT && !bad);

  enum { NH = 3 };
  const uint32_t flags_of[NH] = {UB_BLEND_ROW_QUERY, UB_BLEND_PORTABLE | UB_BLEND_ROW_QUERY,
                                 0};
  const int stream_of[NH] = {0, 0, 1}, parts_of[NH] = {1, 3, 2};
  ub_blend *h[NH] = {0};
  float *out[NH];
  for (int i = 0; i < NH; i++) {
    out[i] = malloc(sizeof(float) * nf);
    memset(out[i], 0xff, sizeof(float) * nf);
    d.flags = UB_BLEND_OWN_BASE | UB_BLEND_BASE_HALF | flags_of[i];
    ASSERT_OK(ub_blend_create(&d, NULL, stream_of[i] ? NULL : out[i], &h[i]));
    if (!h[i])
      return;
    ASSERT_OK(ub_blend_reserve_parts(h[i], (uint32_t)parts_of[i]));
  }
  /* an engine only marked (ub_blend_mark_part, 3 parts), its rows asked for afterwards */
  ub_blend *hm = NULL;
  d.flags = UB_BLEND_OWN_BASE | UB_BLEND_BASE_HALF | UB_BLEND_ROW_QUERY;
  ASSERT_OK(ub_blend_create(&d, NULL, NULL, &hm));
  if (!hm)
    return;
  ASSERT_OK(ub_blend_reserve_parts(hm, 3));
  uint8_t *mcount = calloc(R, 1);
  int bad_marks = 0;
  ub_blend_info in;
  ub_blend_get_info(h[0], &in);
  const float sc = in.base_scale;
  ASSERT_TRUE(sc > 1.0f && sc == ldexpf(1.0f, ilogbf(sc)));
  /* the reference: a float engine over the rounded rows (touched receivers only) */
  float *rb = malloc(sizeof(float) * nf);
  memcpy(rb, p.base, sizeof(float) * nf);
  int bad_round = 0;
  float mx = 0.0f;
  for (uint32_t r = 0; r < R; r++)
    for (uint32_t j = 0; tmask[r] && j < S; j++) {
      float *v = &rb[(size_t)r * S + j];
      mx = fmaxf(mx, fabsf(*v));
      float q = ub_half_to_float(ub_half_from_float(*v / sc)) * sc;
      bad_round += !(fabsf(q - *v) <= ldexpf(fabsf(*v), -11) + ldexpf(sc, -25));
      *v = q;
    }
  ASSERT_TRUE(bad_round == 0 && mx / sc <= 32768.0f && mx / sc > 16384.0f);
  ub_blend_desc dr = d;
  dr.base = rb;
  dr.flags = 0;
  float *ref = malloc(sizeof(float) * nf);
  ub_blend *bref = NULL, *bown = NULL;
  ASSERT_OK(ub_blend_create(&dr, NULL, ref, &bref));
  dr.flags = UB_BLEND_OWN_BASE | UB_BLEND_ROW_QUERY; /* h[0]'s flags, float rows */
  ASSERT_OK(ub_blend_create(&dr, NULL, NULL, &bown));
  if (!bref || !bown)
    return;
  ub_blend_info io;
  ub_blend_get_info(bown, &io);
  /* the rows at half the bytes (less the base decode scratch) */
  ASSERT_TRUE(io.engine_bytes - in.engine_bytes + (size_t)64 * S * sizeof(float) >=
              (size_t)in.touched_receivers * S * 2);
  ASSERT_TRUE(memcmp(out[0], ref, sizeof(float) * nf) == 0); /* create: the rounded rows */
  ASSERT_TRUE(memcmp(out[1], ref, sizeof(float) * nf) == 0);
  memcpy(out[2], ref, sizeof(float) * nf); /* streaming: filled by the reports */
  uint8_t *count = calloc(R, 1);
  float row[UB_BLEND_MAX_STRIDE];
  int bad_bits = 0, bad_rows = 0, bad_bytes = 0;
  uint32_t list_calls = 0;
  for (int round = 0; round < 50; round++) {
    const int all = round % 10 == 9, off = round == 49;
    for (uint32_t e = 0; e < E; e++)
      if (off || rnd() < 0.15) {
        float w[3] = {0.0f, 0.0f, 0.0f};
        if (!off)
          rnd_weight(w);
        ASSERT_OK(ub_blend_set_weight(bref, e, w));
        for (int i = 0; i < NH; i++)
          ASSERT_OK(ub_blend_set_weight(h[i], e, w));
        ASSERT_OK(ub_blend_set_weight(hm, e, w));
      }
    ub_blend_stats sr, sh;
    (all ? ub_blend_update_all : ub_blend_update)(bref, NULL, NULL, ref, &sr);
    for (int i = 0; i < NH; i++) {
      memset(count, 0, R);
      touch_log tl = {count, 0, S, stream_of[i] ? NULL : out[i], stream_of[i] ? out[i] : NULL,
                      0, 0, 0, 0};
      memset(&sh, 0, sizeof sh);
      ub_blend_update_begin(h[i], all);
      for (int q = 0; q < parts_of[i]; q++) {
        ub_blend_stats sq;
        ub_blend_update_part(h[i], (uint32_t)q, (uint32_t)parts_of[i], on_touched, &tl,
                             stream_of[i] ? NULL : out[i], &sq);
        sh.receivers += sq.receivers;
        sh.bytes_read += sq.bytes_read;
      }
      bad_bits += memcmp(out[i], ref, sizeof(float) * nf) != 0 || tl.rows_bad;
      /* base rows read at 2 bytes a value, not 4 */
      bad_bytes += sh.receivers != sr.receivers ||
                   sh.bytes_read + sr.receivers * S * 2 != sr.bytes_read;
    }
    {
      /* marking reports the receivers the updates recomputed (count: the last engine's),
       * each once, without rows; a row query then gives each the update's bits */
      memset(mcount, 0, R);
      touch_log tm = {mcount, 0, S, NULL, NULL, 0, 0, 0, 0};
      touch_log tlist = {mcount, 0, S, NULL, NULL, 0, 0, 0, 0}; /* odd rounds: lists apart */
      ub_blend_update_begin(hm, all);
      for (uint32_t q = 0; q < 3; q++) {
        ub_blend_stats sq;
        if (round & 1)
          ub_blend_mark_part_ex(hm, q, 3, on_marked, on_listed, &tlist, &sq);
        else
          ub_blend_mark_part(hm, q, 3, on_marked, &tm, &sq);
        bad_marks += sq.bytes_written != 0;
      }
      bad_marks += tlist.rows_bad != 0;
      list_calls += (uint32_t)tlist.pieces_bad;
      bad_marks += tm.rows_bad != 0 || memcmp(mcount, count, R) != 0;
      for (uint32_t r = 0; r < R; r++)
        if (mcount[r])
          bad_marks += !ub_blend_row(hm, r, row) ||
                       memcmp(row, ref + (size_t)r * S, sizeof(float) * S) != 0;
    }
    for (int q = 0; q < 200; q++) {
      uint32_t r = rnd_below(R);
      int ok = ub_blend_row(h[q & 1], r, row);
      bad_rows += tmask[r] ? !ok || memcmp(row, ref + (size_t)r * S, sizeof(float) * S) != 0
                           : ok;
    }
  }
  printf("base half R=%u S=%u %s: scale %g, %d of %d engine-updates differ in bits, %d bad "
         "row queries, %d bad byte counts\n", R, S, st == UB_BLEND_FLOAT16 ? "half" : "float",
         (double)sc, bad_bits, 50 * NH, bad_rows, bad_bytes);
  printf("  marked only (ub_blend_mark_part, 3 parts; _ex with %u list calls on odd rounds), "
         "rows asked for afterwards: %d bad marks or rows\n", list_calls, bad_marks);
  ASSERT_TRUE(bad_bits == 0 && bad_rows == 0 && bad_bytes == 0 && bad_marks == 0);
  ASSERT_TRUE(list_calls > 0);
  ASSERT_TRUE(memcmp(ref, rb, sizeof(float) * nf) == 0); /* all off: the rounded base */
  ub_blend_free(hm);
  free(mcount);
  free(count);
  free(tmask);
  free(rb);
  free(ref);
  ub_blend_free(bref);
  ub_blend_free(bown);
  for (int i = 0; i < NH; i++) {
    ub_blend_free(h[i]);
    free(out[i]);
  }
  rep_free(&p);
}

/* One element over every receiver: one group of one run. Seven parts must each hold a
 * stretch of it (the split cuts the group) and give the plain update's bits. */
static void test_parts_one_group(void)
{
  const uint32_t R = 5000, S = 12;
  uint8_t *cover[1] = {malloc(R)};
  memset(cover[0], 1, R);
  rep p;
  rep_init(&p, R, S, 1, UB_BLEND_FLOAT16, cover);
  free(cover[0]);
  ub_blend_desc d = rep_desc(&p, "one group");
  float *oa = malloc(sizeof(float) * R * S), *ob = malloc(sizeof(float) * R * S);
  ub_blend *a = NULL, *b = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, oa, &a));
  ASSERT_OK(ub_blend_create(&d, NULL, ob, &b));
  if (!a || !b)
    return;
  ASSERT_OK(ub_blend_reserve_parts(b, 7));
  const float w[3] = {0.7f, 1.3f, 0.2f};
  ASSERT_OK(ub_blend_set_weight(a, 0, w));
  ASSERT_OK(ub_blend_set_weight(b, 0, w));
  ub_blend_update(a, NULL, NULL, oa, NULL);
  ub_blend_update_begin(b, 0);
  int filled = 0;
  for (uint32_t q = 0; q < 7; q++) { /* in reverse order: parts are independent */
    ub_blend_stats st;
    ub_blend_update_part(b, 6 - q, 7, NULL, NULL, ob, &st);
    filled += st.receivers > 0 && st.receivers < R;
  }
  ASSERT_TRUE(filled == 7);
  ASSERT_TRUE(memcmp(oa, ob, sizeof(float) * R * S) == 0);
  ub_blend_free(a);
  ub_blend_free(b);
  free(oa);
  free(ob);
  rep_free(&p);
}

/* Parts of equal cost read about equal bytes when all-ones sums serve some groups: element
 * 0 covers every receiver, elements 1-11 the first half (a group of 12 members, kept as
 * an all-ones sum) and element 0 is tinted with the others at ω1. A receiver of the big
 * group then reads its float sum and one record row (72 B), one of the other its base
 * and one row (48 B). Counting every member's row (13 against 2) put the cut far into the
 * small group's side: one part read about twice the other's bytes. */
static void test_parts_balance(void)
{
  const uint32_t R = 20000, S = 12, E = 12;
  uint8_t *cover[E];
  for (uint32_t e = 0; e < E; e++) {
    cover[e] = malloc(R);
    for (uint32_t r = 0; r < R; r++)
      cover[e][r] = e == 0 || r < R / 2;
  }
  rep p;
  rep_init(&p, R, S, E, UB_BLEND_FLOAT16, cover);
  for (uint32_t e = 0; e < E; e++)
    free(cover[e]);
  ub_blend_desc d = rep_desc(&p, "balance");
  d.flags = UB_BLEND_OWN_BASE | UB_BLEND_BASE_HALF | UB_BLEND_ONES_SUM;
  float *out = malloc(sizeof(float) * R * S);
  ub_blend *b = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, out, &b));
  if (!b)
    return;
  ASSERT_OK(ub_blend_reserve_parts(b, 2));
  for (uint32_t e = 0; e < E; e++) /* every element at 1: the load state */
    ASSERT_OK(ub_blend_set_weight(b, e, (const float[3]){1.0f, 1.0f, 1.0f}));
  ub_blend_update(b, NULL, NULL, out, NULL);
  ASSERT_OK(ub_blend_set_weight(b, 0, (const float[3]){0.5f, 0.25f, 2.0f}));
  ub_blend_update_begin(b, 0);
  ub_blend_stats st[2];
  for (uint32_t q = 0; q < 2; q++)
    ub_blend_update_part(b, q, 2, NULL, NULL, out, &st[q]);
  const double a = (double)st[0].bytes_read, c = (double)st[1].bytes_read;
  const double lo = a < c ? a : c, hi = a < c ? c : a;
  printf("parts balance: 2 parts read %llu and %llu bytes (%llu and %llu receivers)\n",
         (unsigned long long)st[0].bytes_read, (unsigned long long)st[1].bytes_read,
         (unsigned long long)st[0].receivers, (unsigned long long)st[1].receivers);
  ASSERT_TRUE(st[0].receivers + st[1].receivers == R);
  ASSERT_TRUE(hi <= 1.1 * lo);
  ub_blend_free(b);
  free(out);
  rep_free(&p);
}

/* ---- ub_blend_create_ex: values handed back as they are copied ------------------------ */

typedef struct done_log {
  ub_blend_record *recs; /* the copies create_ex reads; freed by on_done */
  uint32_t calls, next, out_of_order;
} done_log;

static void on_done(void *user, uint32_t e)
{
  done_log *d = user;
  d->out_of_order += e != d->next;
  d->next = e + 1;
  d->calls++;
  free((void *)(uintptr_t)d->recs[e].values);
  d->recs[e].values = NULL; /* read again, the engine would crash or differ */
}

/* create_ex calls values_done once per element, in order, and the engine it builds from
 * values freed as they are copied gives the bits of ub_blend_create's, update after
 * update, over run and list groups (stores as given, 8-bit rows). */
static void test_values_done(uint32_t R, uint32_t S, uint32_t E, ub_blend_storage st,
                             uint32_t flags)
{
  rep p;
  rep_init_runs(&p, R, S, E, st, 4);
  ub_blend_desc d = rep_desc(&p, "values done");
  d.flags = flags;
  const size_t vs = st == UB_BLEND_FLOAT16 ? 2 : 4;
  ub_blend_record *copy = malloc(sizeof *copy * (E + 1));
  for (uint32_t e = 0; e < E; e++) {
    copy[e] = p.recs[e];
    void *v = malloc((size_t)p.cnt[e] * S * vs + 1);
    memcpy(v, p.recs[e].values, (size_t)p.cnt[e] * S * vs);
    copy[e].values = v;
  }
  ub_blend_desc dc = d;
  dc.elements = copy;
  done_log dl = {copy, 0, 0, 0};
  float *oa = malloc(sizeof(float) * R * S), *ob = malloc(sizeof(float) * R * S);
  ub_blend *ba = NULL, *bb = NULL;
  ASSERT_OK(ub_blend_create(&d, NULL, oa, &ba));
  ASSERT_OK(ub_blend_create_ex(&dc, NULL, ob, on_done, &dl, &bb));
  ASSERT_TRUE(dl.calls == E && dl.out_of_order == 0);
  for (uint32_t e = 0; e < E; e++)
    ASSERT_TRUE(copy[e].values == NULL);
  ASSERT_TRUE(memcmp(oa, ob, sizeof(float) * R * S) == 0);
  for (int round = 0; ba && bb && round < 20; round++) {
    for (int c = 0; c < 3; c++) {
      uint32_t e = rnd_below(E);
      float w[3];
      rnd_weight(w);
      ASSERT_OK(ub_blend_set_weight(ba, e, w));
      ASSERT_OK(ub_blend_set_weight(bb, e, w));
    }
    ub_blend_update(ba, NULL, NULL, oa, NULL);
    ub_blend_update(bb, NULL, NULL, ob, NULL);
    ASSERT_TRUE(memcmp(oa, ob, sizeof(float) * R * S) == 0);
  }
  ub_blend_free(ba);
  ub_blend_free(bb);
  free(copy);
  free(oa);
  free(ob);
  rep_free(&p);
}

int main(void)
{
  const uint32_t strides[] = {12, 27, 9, 48};
  for (int s = 0; s < 4; s++) {
    test_overlaps(strides[s], UB_BLEND_FLOAT32);
    test_overlaps(strides[s], UB_BLEND_FLOAT16);
  }
  test_half_exact(12);
  test_half_exact(27);
  test_store_half(12);
  test_store_half(27);
  test_validation();
  test_compact();
  scenario(100000, 12, 200, UB_BLEND_FLOAT16, 1000);
  scenario(30000, 27, 120, UB_BLEND_FLOAT32, 400);
  test_parts(20000, 12, 40, UB_BLEND_FLOAT16);
  test_parts(6000, 27, 30, UB_BLEND_FLOAT32);
  test_parts_one_group();
  test_parts_balance();
  test_base_half(20000, 12, 30, UB_BLEND_FLOAT16);
  test_base_half(5000, 27, 20, UB_BLEND_FLOAT32);
  test_q8(20000, 12, 30, UB_BLEND_FLOAT16);
  test_q8(5000, 27, 24, UB_BLEND_FLOAT32);
  test_q8(3000, 9, 12, UB_BLEND_FLOAT32);
  test_q8(3000, 48, 12, UB_BLEND_FLOAT16);
  test_q8(2000, 3, 8, UB_BLEND_FLOAT32);
  test_q8(2000, 6, 8, UB_BLEND_FLOAT16);
  test_q8_many_overlaps();
  test_q8_extremes();
  test_ones(20000, 12, 40, UB_BLEND_FLOAT16, UB_BLEND_BASE_HALF, 1.0f);
  test_ones(6000, 27, 24, UB_BLEND_FLOAT32, 0, 1.0f);
  test_ones(20000, 12, 40, UB_BLEND_FLOAT16, UB_BLEND_BASE_HALF | UB_BLEND_STORE_Q8, 1.0f);
  test_ones(4000, 9, 20, UB_BLEND_FLOAT32, UB_BLEND_STORE_Q8, 1.0f);
  test_ones(6000, 27, 24, UB_BLEND_FLOAT16, UB_BLEND_BASE_HALF | UB_BLEND_STORE_Q8, 4.0f);
  test_ones_many(12, 0);
  test_ones_many(27, UB_BLEND_STORE_Q8);
  test_ones_many(12, UB_BLEND_STORE_Q8);
  test_q8_validation();
  test_reference(20000, 12, 40, UB_BLEND_FLOAT16,
                 UB_BLEND_OWN_BASE | UB_BLEND_BASE_HALF | UB_BLEND_ONES_SUM | UB_BLEND_ROW_QUERY);
  test_reference(6000, 27, 24, UB_BLEND_FLOAT32, 0);
  test_reference_parts();
  test_base_report(20000, 12, 40, UB_BLEND_FLOAT16,
                   UB_BLEND_OWN_BASE | UB_BLEND_BASE_HALF | UB_BLEND_ONES_SUM);
  test_base_report(6000, 27, 24, UB_BLEND_FLOAT32, 0);
  test_values_done(20000, 12, 40, UB_BLEND_FLOAT16, 0);
  test_values_done(6000, 27, 24, UB_BLEND_FLOAT32, UB_BLEND_STORE_Q8);
  test_reference(8000, 12, 30, UB_BLEND_FLOAT16,
                 UB_BLEND_OWN_BASE | UB_BLEND_STORE_Q8 | UB_BLEND_PORTABLE);
  TEST_MAIN_END();
}
