/* probes/tetgen.c — TetGen driver: clean the probe points, run `tetgen` as a child
 * process in a private temporary directory, read back .ele/.neigh strictly, validate.
 * See probes/tetgen.h. */
#include "probes/tetgen.h"

#include "bake/fsutil.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

extern char **environ;

#define TG_FLAGS "-nQzJNF"
#define TG_FLAT_VOLUME_REL 1e-12 /* |det| ≤ this × longest edge³: flat tet */
#define TG_MAX_FILE_BYTES ((size_t)1 << 34)

/* ---- small double-precision vector helpers (cglm is float-only) ----------------- */

static void v3sub(const double a[3], const double b[3], double o[3])
{
  o[0] = a[0] - b[0];
  o[1] = a[1] - b[1];
  o[2] = a[2] - b[2];
}
static double v3dot(const double a[3], const double b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
static void v3cross(const double a[3], const double b[3], double o[3])
{
  double x = a[1] * b[2] - a[2] * b[1], y = a[2] * b[0] - a[0] * b[2],
         z = a[0] * b[1] - a[1] * b[0];
  o[0] = x;
  o[1] = y;
  o[2] = z;
}
static double v3len(const double a[3]) { return sqrt(v3dot(a, a)); }
static void v3load(const float *p, double o[3])
{
  o[0] = p[0];
  o[1] = p[1];
  o[2] = p[2];
}

/* det[b−a, c−a, d−a] and the longest edge, in double. */
static double tet_det(const float *pts, const uint32_t *v, double *out_lmax)
{
  double a[3], b[3], c[3], d[3], e1[3], e2[3], e3[3], x[3];
  v3load(pts + 3 * (size_t)v[0], a);
  v3load(pts + 3 * (size_t)v[1], b);
  v3load(pts + 3 * (size_t)v[2], c);
  v3load(pts + 3 * (size_t)v[3], d);
  v3sub(b, a, e1);
  v3sub(c, a, e2);
  v3sub(d, a, e3);
  if (out_lmax) {
    const double *q[4] = {a, b, c, d};
    double m = 0.0;
    for (int i = 0; i < 4; i++)
      for (int j = i + 1; j < 4; j++) {
        double e[3];
        v3sub(q[i], q[j], e);
        double l2 = v3dot(e, e);
        if (l2 > m)
          m = l2;
      }
    *out_lmax = sqrt(m);
  }
  v3cross(e1, e2, x);
  return v3dot(x, e3);
}

/* ---- point cleaning ----------------------------------------------------------------- */

static uint64_t cell_key(int64_t x, int64_t y, int64_t z)
{
  return ((uint64_t)x & 0x1FFFFF) | (((uint64_t)y & 0x1FFFFF) << 21) |
         (((uint64_t)z & 0x1FFFFF) << 42);
}

static uint64_t hash64(uint64_t k)
{
  k ^= k >> 33;
  k *= 0xff51afd7ed558ccdull;
  k ^= k >> 33;
  k *= 0xc4ceb9fe1a85ec53ull;
  k ^= k >> 33;
  return k;
}

/* Merges points closer than tol into the first of them. kept_idx receives the input
 * index of each kept point; map receives input → kept. Returns kept count or -1 (OOM). */
static int64_t dedup_points(const float *p, uint32_t n, const double lo[3], double tol,
                            uint32_t *kept_idx, int32_t *map)
{
  if (!(tol > 0.0)) { /* zero extent: everything is one point */
    kept_idx[0] = 0;
    for (uint32_t i = 0; i < n; i++)
      map[i] = 0;
    return 1;
  }
  size_t cap = 16;
  while (cap < 2 * (size_t)n)
    cap <<= 1;
  uint64_t *keys = malloc(cap * sizeof *keys);
  int32_t *head = malloc(cap * sizeof *head);
  int32_t *next = malloc((size_t)n * sizeof *next);
  if (!keys || !head || !next) {
    free(keys);
    free(head);
    free(next);
    return -1;
  }
  for (size_t i = 0; i < cap; i++)
    head[i] = -1;
  const double tol2 = tol * tol, inv = 1.0 / tol;
  uint32_t kept = 0;
  for (uint32_t i = 0; i < n; i++) {
    const float *q = p + 3 * (size_t)i;
    int64_t c[3];
    for (int a = 0; a < 3; a++)
      c[a] = (int64_t)floor(((double)q[a] - lo[a]) * inv);
    int32_t found = -1;
    for (int dz = -1; dz <= 1 && found < 0; dz++)
      for (int dy = -1; dy <= 1 && found < 0; dy++)
        for (int dx = -1; dx <= 1 && found < 0; dx++) {
          uint64_t k = cell_key(c[0] + dx, c[1] + dy, c[2] + dz);
          for (size_t s = hash64(k) & (cap - 1); head[s] >= 0; s = (s + 1) & (cap - 1)) {
            if (keys[s] != k)
              continue;
            for (int32_t j = head[s]; j >= 0; j = next[j]) {
              const float *r = p + 3 * (size_t)kept_idx[j];
              double d0 = (double)q[0] - r[0], d1 = (double)q[1] - r[1],
                     d2 = (double)q[2] - r[2];
              if (d0 * d0 + d1 * d1 + d2 * d2 <= tol2) {
                found = j;
                break;
              }
            }
            break;
          }
        }
    if (found >= 0) {
      map[i] = found;
      continue;
    }
    uint64_t k = cell_key(c[0], c[1], c[2]);
    size_t s = hash64(k) & (cap - 1);
    while (head[s] >= 0 && keys[s] != k)
      s = (s + 1) & (cap - 1);
    keys[s] = k;
    next[kept] = head[s]; /* -1 for a new cell */
    head[s] = (int32_t)kept;
    kept_idx[kept] = i;
    map[i] = (int32_t)kept;
    kept++;
  }
  free(keys);
  free(head);
  free(next);
  return kept;
}

/* The padded oriented box of a degenerate set: axes u, v, w (right-handed; the
 * degenerate directions last), centre and half extents. */
typedef struct tg_frame {
  ub_tetgen_degeneracy kind;
  double center[3], axis[3][3], half[3];
} tg_frame;

/* Classifies the kept points (b: farthest from a; c: farthest from line ab; d: farthest
 * from plane abc) and, for a degenerate set, fills the padded frame. */
static void classify(const float *pts, const uint32_t *kept_idx, uint32_t k, double diag,
                     tg_frame *out)
{
  double a[3], u[3] = {1, 0, 0}, v[3] = {0, 1, 0}, w[3] = {0, 0, 1};
  v3load(pts + 3 * (size_t)kept_idx[0], a);
  const double flat = UB_TETGEN_FLAT_REL * diag;
  ub_tetgen_degeneracy kind = UB_TETGEN_GENERAL;
  double half[3];
  double center[3] = {a[0], a[1], a[2]};

  /* b: farthest from a; c: farthest from line ab; d: farthest from plane abc. */
  double best = 0.0;
  uint32_t ib = 0;
  for (uint32_t i = 1; i < k; i++) {
    double q[3], e[3];
    v3load(pts + 3 * (size_t)kept_idx[i], q);
    v3sub(q, a, e);
    double l = v3len(e);
    if (l > best) {
      best = l;
      ib = i;
    }
  }
  if (k < 2 || best <= flat) {
    kind = UB_TETGEN_SINGLE_POINT;
    half[0] = half[1] = half[2] = UB_TETGEN_POINT_PAD;
  } else {
    double b[3];
    v3load(pts + 3 * (size_t)kept_idx[ib], b);
    v3sub(b, a, u);
    double lu = v3len(u);
    for (int i = 0; i < 3; i++)
      u[i] /= lu;
    best = 0.0;
    uint32_t ic = 0;
    for (uint32_t i = 1; i < k; i++) {
      double q[3], e[3], x[3];
      v3load(pts + 3 * (size_t)kept_idx[i], q);
      v3sub(q, a, e);
      v3cross(e, u, x);
      double l = v3len(x);
      if (l > best) {
        best = l;
        ic = i;
      }
    }
    if (best <= flat) {
      kind = UB_TETGEN_COLLINEAR;
      /* any unit v ⟂ u: cross with the axis least aligned with u */
      double ax[3] = {0, 0, 0};
      int m = fabs(u[0]) <= fabs(u[1]) ? (fabs(u[0]) <= fabs(u[2]) ? 0 : 2)
                                       : (fabs(u[1]) <= fabs(u[2]) ? 1 : 2);
      ax[m] = 1.0;
      v3cross(u, ax, v);
      double lv = v3len(v);
      for (int i = 0; i < 3; i++)
        v[i] /= lv;
      v3cross(u, v, w);
    } else {
      double c[3], e1[3], e2[3];
      v3load(pts + 3 * (size_t)kept_idx[ic], c);
      v3sub(b, a, e1);
      v3sub(c, a, e2);
      v3cross(e1, e2, w);
      double lw = v3len(w);
      for (int i = 0; i < 3; i++)
        w[i] /= lw;
      best = 0.0;
      for (uint32_t i = 1; i < k; i++) {
        double q[3], e[3];
        v3load(pts + 3 * (size_t)kept_idx[i], q);
        v3sub(q, a, e);
        double l = fabs(v3dot(e, w));
        if (l > best)
          best = l;
      }
      if (best > flat) {
        out->kind = UB_TETGEN_GENERAL;
        return;
      }
      kind = UB_TETGEN_COPLANAR;
      v3cross(w, u, v);
    }
    /* Extent of the points along the frame; grow by 10% of the diagonal, lift off the
     * line/plane by 10% of the diagonal in the degenerate directions. */
    double mn[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, mx[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    const double *ax3[3] = {u, v, w};
    for (uint32_t i = 0; i < k; i++) {
      double q[3], e[3];
      v3load(pts + 3 * (size_t)kept_idx[i], q);
      v3sub(q, a, e);
      for (int j = 0; j < 3; j++) {
        double s = v3dot(e, ax3[j]);
        mn[j] = fmin(mn[j], s);
        mx[j] = fmax(mx[j], s);
      }
    }
    for (int j = 0; j < 3; j++) {
      double mid = 0.5 * (mn[j] + mx[j]);
      for (int i = 0; i < 3; i++)
        center[i] += mid * ax3[j][i];
      half[j] = 0.5 * (mx[j] - mn[j]) + 0.1 * diag;
    }
  }
  out->kind = kind;
  for (int i = 0; i < 3; i++) {
    out->center[i] = center[i];
    out->half[i] = half[i];
    out->axis[0][i] = u[i];
    out->axis[1][i] = v[i];
    out->axis[2][i] = w[i];
  }
}

/* Corner c (0..7) of the frame's box: world coordinates and frame coordinates. */
static void frame_corner(const tg_frame *f, int c, double out_world[3], double out_frame[3])
{
  const double s[3] = {(c & 1) ? 1.0 : -1.0, (c & 2) ? 1.0 : -1.0, (c & 4) ? 1.0 : -1.0};
  for (int i = 0; i < 3; i++) {
    out_world[i] = f->center[i];
    for (int j = 0; j < 3; j++)
      out_world[i] += s[j] * f->half[j] * f->axis[j][i];
    out_frame[i] = s[i] * f->half[i];
  }
}

/* ---- temporary directory and child process ------------------------------------------ */

/* Last non-empty line of the child's output, for the error message. */
static void last_line(const char *path, char *out, size_t cap)
{
  out[0] = '\0';
  FILE *f = fopen(path, "rb");
  if (!f)
    return;
  char line[512];
  while (fgets(line, sizeof line, f)) {
    size_t l = strlen(line);
    while (l && (line[l - 1] == '\n' || line[l - 1] == '\r' || line[l - 1] == ' '))
      line[--l] = '\0';
    if (l) {
      snprintf(out, cap, "%s", line);
    }
  }
  fclose(f);
}

/* Runs program on node_path. Returns 0, −1 (could not run it) or −4 (it ran and exited
 * non-zero or was killed); on failure writes a reason to why. */
static int run_tetgen(const char *program, const char *node_path, const char *log_path,
                      char *why, size_t why_cap)
{
  posix_spawn_file_actions_t fa;
  if (posix_spawn_file_actions_init(&fa) != 0) {
    snprintf(why, why_cap, "cannot set up the child process");
    return -1;
  }
  posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 1, log_path, O_WRONLY | O_CREAT | O_TRUNC, 0600);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  char *argv[4] = {(char *)program, (char *)TG_FLAGS, (char *)node_path, NULL};
  pid_t pid;
  int rc = posix_spawnp(&pid, program, &fa, NULL, argv, environ);
  posix_spawn_file_actions_destroy(&fa);
  if (rc != 0) {
    snprintf(why, why_cap, "cannot run '%s': %s", program, strerror(rc));
    return -1;
  }
  int status = 0;
  pid_t w;
  do {
    w = waitpid(pid, &status, 0);
  } while (w < 0 && errno == EINTR);
  if (w < 0) {
    snprintf(why, why_cap, "waitpid: %s", strerror(errno));
    return -1;
  }
  char tail[256];
  if (WIFSIGNALED(status)) {
    last_line(log_path, tail, sizeof tail);
    snprintf(why, why_cap, "killed by signal %d%s%s", WTERMSIG(status), tail[0] ? ": " : "",
             tail);
    return -4;
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    last_line(log_path, tail, sizeof tail);
    snprintf(why, why_cap, "exit status %d%s%s", WIFEXITED(status) ? WEXITSTATUS(status) : -1,
             tail[0] ? ": " : "", tail);
    return -4;
  }
  return 0;
}

/* ---- strict readers for TetGen output ----------------------------------------------- */

static int read_file(const char *path, char **out, size_t *out_len)
{
  int fd = open(path, O_RDONLY);
  if (fd < 0)
    return -1;
  struct stat st;
  if (fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) || st.st_size < 0 ||
      (uint64_t)st.st_size > TG_MAX_FILE_BYTES) {
    close(fd);
    return -1;
  }
  size_t len = (size_t)st.st_size;
  char *buf = malloc(len + 1);
  if (!buf) {
    close(fd);
    return -2;
  }
  size_t got = 0;
  while (got < len) {
    ssize_t r = read(fd, buf + got, len - got);
    if (r < 0 && errno == EINTR)
      continue;
    if (r <= 0)
      break;
    got += (size_t)r;
  }
  close(fd);
  if (got != len) {
    free(buf);
    return -1;
  }
  buf[len] = '\0';
  *out = buf;
  *out_len = len;
  return 0;
}

typedef struct tg_parser {
  const char *p, *end;
  uint32_t line;
} tg_parser;

/* 1: integer read; 0: end of file; −1: malformed token. */
static int tg_int(tg_parser *ps, int64_t *out)
{
  const char *p = ps->p, *e = ps->end;
  for (;;) {
    while (p < e && (*p == ' ' || *p == '\t' || *p == '\r' || *p == '\n')) {
      if (*p == '\n')
        ps->line++;
      p++;
    }
    if (p < e && *p == '#') {
      while (p < e && *p != '\n')
        p++;
      continue;
    }
    break;
  }
  ps->p = p;
  if (p >= e)
    return 0;
  int neg = 0;
  if (*p == '-' || *p == '+') {
    neg = *p == '-';
    p++;
  }
  int64_t v = 0;
  int digits = 0;
  while (p < e && *p >= '0' && *p <= '9') {
    if (++digits > 18)
      return -1;
    v = v * 10 + (*p - '0');
    p++;
  }
  if (!digits || (p < e && !(*p == ' ' || *p == '\t' || *p == '\r' || *p == '\n' || *p == '#')))
    return -1;
  ps->p = p;
  *out = neg ? -v : v;
  return 1;
}

/* Reads .ele (kind 0) or .neigh (kind 1): header, then count records of idx + 4 values.
 * Writes into vals (count × 4). Returns 0 or −1 with why filled. */
static int parse_records(const char *name, const char *buf, size_t len, int kind,
                         uint32_t point_count, uint32_t expect_count, uint32_t *io_count,
                         int64_t **out_vals, char *why, size_t why_cap)
{
  tg_parser ps = {buf, buf + len, 1};
  int64_t h[3] = {0, 0, 0};
  int hn = kind == 0 ? 3 : 2;
  for (int i = 0; i < hn; i++) {
    if (tg_int(&ps, &h[i]) != 1) {
      snprintf(why, why_cap, "%s: bad header (line %u)", name, ps.line);
      return -1;
    }
  }
  if (h[0] < 1 || h[0] > 0x3FFFFFFF || h[1] != 4 || (kind == 0 && h[2] != 0)) {
    snprintf(why, why_cap, "%s: unexpected header %lld %lld%s", name, (long long)h[0],
             (long long)h[1], kind == 0 ? " (want N 4 0)" : " (want N 4)");
    return -1;
  }
  if (expect_count && (uint32_t)h[0] != expect_count) {
    snprintf(why, why_cap, "%s: %lld records but .ele has %u", name, (long long)h[0],
             expect_count);
    return -1;
  }
  uint32_t count = (uint32_t)h[0];
  /* every record takes at least 10 bytes: a cheap bound before allocating */
  if ((size_t)count > len / 10 + 1) {
    snprintf(why, why_cap, "%s: header claims %u records, file too short", name, count);
    return -1;
  }
  int64_t *vals = malloc((size_t)count * 4 * sizeof *vals);
  if (!vals) {
    snprintf(why, why_cap, "out of memory reading %s", name);
    return -2;
  }
  for (uint32_t t = 0; t < count; t++) {
    int64_t idx;
    int r = tg_int(&ps, &idx);
    if (r != 1 || idx != (int64_t)t) {
      snprintf(why, why_cap, "%s line %u: %s (record %u)", name, ps.line,
               r == 0 ? "truncated" : "bad record index", t);
      free(vals);
      return -1;
    }
    for (int i = 0; i < 4; i++) {
      int64_t v;
      r = tg_int(&ps, &v);
      int ok = r == 1 && (kind == 0 ? (v >= 0 && v < (int64_t)point_count)
                                    : (v >= -1 && v < (int64_t)count));
      if (!ok) {
        snprintf(why, why_cap, "%s line %u: %s value in record %u", name, ps.line,
                 r == 0 ? "truncated" : (r < 0 ? "malformed" : "out-of-range"), t);
        free(vals);
        return -1;
      }
      vals[4 * (size_t)t + i] = v;
    }
  }
  int64_t extra;
  if (tg_int(&ps, &extra) != 0) {
    snprintf(why, why_cap, "%s line %u: trailing data", name, ps.line);
    free(vals);
    return -1;
  }
  *io_count = count;
  *out_vals = vals;
  return 0;
}

/* ---- validation --------------------------------------------------------------------- */

static const int face_of[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};

static int same_face(const uint32_t *a, int ia, const uint32_t *b, int ib)
{
  uint32_t fa[3], fb[3];
  for (int k = 0; k < 3; k++) {
    fa[k] = a[face_of[ia][k]];
    fb[k] = b[face_of[ib][k]];
  }
  int hits = 0;
  for (int i = 0; i < 3; i++)
    for (int j = 0; j < 3; j++)
      hits += fa[i] == fb[j];
  return hits == 3;
}

/* |det| below this is "flat": relative to the tet's size, and after a jittered retry
 * also to the jitter (a tet of nearly coplanar points may come out slightly inverted). */
static double flat_tolerance(const ub_tetmesh *m, double lmax)
{
  double tol = TG_FLAT_VOLUME_REL * lmax * lmax * lmax;
  double jt = 8.0 * m->retry_jitter * lmax * lmax;
  return jt > tol ? jt : tol;
}

static ub_result validate_mesh(const ub_tetmesh *m, const ub_log *log, uint32_t *out_unused,
                               uint32_t *out_flat)
{
  if (!m || m->point_count < 4 || m->tet_count < 1 || !m->points || !m->tets || !m->neigh) {
    ub_log_printf(log, UB_LOG_ERROR, "tet mesh: empty or missing arrays");
    return UB_ERR_INVALID_DATA;
  }
  for (size_t i = 0; i < 3 * (size_t)m->point_count; i++)
    if (!isfinite(m->points[i])) {
      ub_log_printf(log, UB_LOG_ERROR, "tet mesh: point %zu is not finite", i / 3);
      return UB_ERR_INVALID_DATA;
    }
  uint32_t flat = 0;
  uint8_t *used = calloc(m->point_count, 1);
  if (!used)
    return UB_ERR_OUT_OF_MEMORY;
  ub_result res = UB_OK;
  for (uint32_t t = 0; t < m->tet_count && res == UB_OK; t++) {
    const uint32_t *v = m->tets + 4 * (size_t)t;
    for (int i = 0; i < 4; i++) {
      if (v[i] >= m->point_count) {
        ub_log_printf(log, UB_LOG_ERROR, "tet mesh: tet %u corner %d index %u out of range",
                      t, i, v[i]);
        res = UB_ERR_INVALID_DATA;
        break;
      }
      for (int j = 0; j < i; j++)
        if (v[i] == v[j]) {
          ub_log_printf(log, UB_LOG_ERROR, "tet mesh: tet %u repeats point %u", t, v[i]);
          res = UB_ERR_INVALID_DATA;
        }
      used[v[i]] = 1;
    }
    if (res != UB_OK)
      break;
    double lmax;
    double det = tet_det(m->points, v, &lmax);
    double tol = flat_tolerance(m, lmax);
    if (!(det > tol)) {
      if (det < -tol || !isfinite(det)) {
        ub_log_printf(log, UB_LOG_ERROR, "tet mesh: tet %u is inverted (6·volume %.3g)", t,
                      det);
        res = UB_ERR_INVALID_DATA;
        break;
      }
      flat++;
    }
    for (int i = 0; i < 4; i++) {
      int32_t u = m->neigh[4 * (size_t)t + i];
      if (u < 0) {
        if (u != -1) {
          ub_log_printf(log, UB_LOG_ERROR, "tet mesh: tet %u neighbour %d invalid", t, u);
          res = UB_ERR_INVALID_DATA;
        }
        continue;
      }
      if ((uint32_t)u >= m->tet_count || (uint32_t)u == t) {
        ub_log_printf(log, UB_LOG_ERROR, "tet mesh: tet %u neighbour %d out of range", t, u);
        res = UB_ERR_INVALID_DATA;
        break;
      }
      int back = -1, backs = 0;
      for (int j = 0; j < 4; j++)
        if (m->neigh[4 * (size_t)u + j] == (int32_t)t) {
          back = j;
          backs++;
        }
      if (backs != 1 || !same_face(v, i, m->tets + 4 * (size_t)u, back)) {
        ub_log_printf(log, UB_LOG_ERROR,
                      "tet mesh: tets %u and %d are not symmetric neighbours sharing a face",
                      t, u);
        res = UB_ERR_INVALID_DATA;
        break;
      }
    }
  }
  uint32_t unused = 0;
  for (uint32_t i = 0; i < m->point_count; i++)
    unused += !used[i];
  free(used);
  if (res == UB_OK && m->input_to_point)
    for (uint32_t i = 0; i < m->input_count; i++)
      if (m->input_to_point[i] < 0 || (uint32_t)m->input_to_point[i] >= m->point_count) {
        ub_log_printf(log, UB_LOG_ERROR, "tet mesh: input point %u maps out of range", i);
        res = UB_ERR_INVALID_DATA;
        break;
      }
  if (out_unused)
    *out_unused = unused;
  if (out_flat)
    *out_flat = flat;
  return res;
}

ub_result ub_tetmesh_validate(const ub_tetmesh *mesh, const ub_log *log)
{
  uint32_t unused = 0, flat = 0;
  ub_result r = validate_mesh(mesh, log, &unused, &flat);
  if (r == UB_OK && (unused || flat))
    ub_log_printf(log, UB_LOG_INFO, "tet mesh: %u unused point(s), %u flat tet(s)", unused,
                  flat);
  return r;
}

void ub_tetmesh_free(ub_tetmesh *m)
{
  if (!m)
    return;
  free(m->points);
  free(m->tets);
  free(m->neigh);
  free(m->input_to_point);
  free(m);
}

/* ---- build -------------------------------------------------------------------------- */

/* ---- spatial order ------------------------------------------------------------------ */

/* 21-bit Morton code of p in the box lo + [0, 1]/inv. */
static uint64_t morton_spread(uint32_t x)
{
  uint64_t v = x & 0x1fffffu;
  v = (v | v << 32) & 0x1f00000000ffffull;
  v = (v | v << 16) & 0x1f0000ff0000ffull;
  v = (v | v << 8) & 0x100f00f00f00f00full;
  v = (v | v << 4) & 0x10c30c30c30c30c3ull;
  v = (v | v << 2) & 0x1249249249249249ull;
  return v;
}
static uint64_t morton_key(const double p[3], const double lo[3], const double inv[3])
{
  uint64_t k = 0;
  for (int a = 0; a < 3; a++) {
    double t = (p[a] - lo[a]) * inv[a] * 2097151.0;
    uint32_t q = t > 0.0 ? (t < 2097151.0 ? (uint32_t)t : 2097151u) : 0u;
    k |= morton_spread(q) << a;
  }
  return k;
}

typedef struct morton_item {
  uint64_t key;
  uint32_t index;
} morton_item;

static int morton_cmp(const void *a, const void *b)
{
  const morton_item *x = a, *y = b;
  if (x->key != y->key)
    return x->key < y->key ? -1 : 1;
  return (x->index > y->index) - (x->index < y->index);
}

/* Puts the kept points [0, added_first) and the tets in Morton order (of positions, of
 * centroids; ties by the old index, so deterministic): neighbouring tets and a tet's
 * corners then sit near each other in memory, which is what a random GLG query's chain
 * of cache misses needs (kaos: ~15% more random queries/s at run time). Added hull points
 * stay at the end. Connectivity, orientation and positions are unchanged; input_to_point
 * and the neighbours are remapped. Returns 0 when out of memory (the mesh is unchanged). */
static int spatial_order(ub_tetmesh *m)
{
  uint32_t np = m->point_count, nt = m->tet_count, nk = m->added_first;
  double lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
  for (uint32_t i = 0; i < np; i++)
    for (int a = 0; a < 3; a++) {
      lo[a] = fmin(lo[a], m->points[3 * (size_t)i + a]);
      hi[a] = fmax(hi[a], m->points[3 * (size_t)i + a]);
    }
  double inv[3];
  for (int a = 0; a < 3; a++)
    inv[a] = hi[a] > lo[a] ? 1.0 / (hi[a] - lo[a]) : 0.0;
  size_t nmax = np > nt ? np : nt;
  morton_item *it = malloc((nmax ? nmax : 1) * sizeof *it);
  uint32_t *pnew = malloc(((size_t)np + 1) * sizeof *pnew);
  uint32_t *tnew = malloc(((size_t)nt + 1) * sizeof *tnew);
  float *pts = malloc(((size_t)np + 1) * 3 * sizeof *pts);
  uint32_t *tets = malloc(((size_t)nt + 1) * 4 * sizeof *tets);
  int32_t *neigh = malloc(((size_t)nt + 1) * 4 * sizeof *neigh);
  if (!it || !pnew || !tnew || !pts || !tets || !neigh) {
    free(it), free(pnew), free(tnew), free(pts), free(tets), free(neigh);
    return 0;
  }
  for (uint32_t i = 0; i < nk; i++) {
    double p[3];
    v3load(m->points + 3 * (size_t)i, p);
    it[i].key = morton_key(p, lo, inv);
    it[i].index = i;
  }
  qsort(it, nk, sizeof *it, morton_cmp);
  for (uint32_t i = 0; i < nk; i++)
    pnew[it[i].index] = i;
  for (uint32_t i = nk; i < np; i++)
    pnew[i] = i;
  for (uint32_t t = 0; t < nt; t++) {
    double c[3] = {0, 0, 0};
    for (int j = 0; j < 4; j++)
      for (int a = 0; a < 3; a++)
        c[a] += 0.25 * m->points[3 * (size_t)m->tets[4 * (size_t)t + j] + a];
    it[t].key = morton_key(c, lo, inv);
    it[t].index = t;
  }
  qsort(it, nt, sizeof *it, morton_cmp);
  for (uint32_t t = 0; t < nt; t++)
    tnew[it[t].index] = t;
  for (uint32_t i = 0; i < np; i++)
    memcpy(pts + 3 * (size_t)pnew[i], m->points + 3 * (size_t)i, 3 * sizeof *pts);
  for (uint32_t t = 0; t < nt; t++) {
    size_t u = tnew[t];
    for (int j = 0; j < 4; j++) {
      tets[4 * u + j] = pnew[m->tets[4 * (size_t)t + j]];
      int32_t nb = m->neigh[4 * (size_t)t + j];
      neigh[4 * u + j] = nb < 0 ? nb : (int32_t)tnew[nb];
    }
  }
  for (uint32_t i = 0; i < m->input_count; i++)
    if (m->input_to_point[i] >= 0)
      m->input_to_point[i] = (int32_t)pnew[m->input_to_point[i]];
  free(m->points);
  free(m->tets);
  free(m->neigh);
  m->points = pts;
  m->tets = tets;
  m->neigh = neigh;
  free(it);
  free(pnew);
  free(tnew);
  return 1;
}

static const char *degeneracy_name(ub_tetgen_degeneracy d)
{
  switch (d) {
  case UB_TETGEN_GENERAL: return "general";
  case UB_TETGEN_COPLANAR: return "coplanar";
  case UB_TETGEN_COLLINEAR: return "collinear";
  case UB_TETGEN_SINGLE_POINT: return "a single point";
  }
  return "?";
}

ub_result ub_tetgen_build(const float *points, uint32_t n, const ub_log *log,
                          ub_tetmesh **out)
{
  return ub_tetgen_build_ex(points, n, NULL, log, out);
}

/* One TetGen run on coords (count × 3 doubles) in dir under base name `base`. Returns 0,
 * −1 (could not run tetgen, or it wrote invalid output), −4 (tetgen exited non-zero or was
 * killed), −2 (out of memory), −3 (cannot write the node file); why says which. */
static int tetgen_attempt(const char *dir, const char *base, const char *program,
                          const double *coords, uint32_t count, uint32_t *out_tet_count,
                          int64_t **out_ele, int64_t **out_nei, char *why, size_t why_cap)
{
  char node_path[4200], ele_path[4200], neigh_path[4200], log_path[4200];
  snprintf(node_path, sizeof node_path, "%s/%s.node", dir, base);
  snprintf(ele_path, sizeof ele_path, "%s/%s.1.ele", dir, base);
  snprintf(neigh_path, sizeof neigh_path, "%s/%s.1.neigh", dir, base);
  snprintf(log_path, sizeof log_path, "%s/%s.log", dir, base);
  FILE *f = fopen(node_path, "wb");
  if (!f) {
    snprintf(why, why_cap, "cannot write the node file: %s", strerror(errno));
    return -3;
  }
  /* %.17g: doubles round-trip exactly, so TetGen's exact predicates see our values */
  int werr = fprintf(f, "%u 3 0 0\n", count) < 0;
  for (uint32_t i = 0; i < count && !werr; i++) {
    const double *p = coords + 3 * (size_t)i;
    werr = fprintf(f, "%u %.17g %.17g %.17g\n", i, p[0], p[1], p[2]) < 0;
  }
  if (fclose(f) != 0 || werr) {
    snprintf(why, why_cap, "cannot write the node file");
    return -3;
  }
  int rc = run_tetgen(program, node_path, log_path, why, why_cap);
  if (rc != 0)
    return rc;
  char *buf = NULL;
  size_t len;
  int64_t *ele = NULL, *nei = NULL;
  uint32_t tet_count = 0, neigh_count = 0;
  int rr = read_file(ele_path, &buf, &len);
  if (rr != 0) {
    snprintf(why, why_cap, "no readable .ele output");
    return rr == -2 ? -2 : -1;
  }
  rr = parse_records(".ele", buf, len, 0, count, 0, &tet_count, &ele, why, why_cap);
  free(buf);
  buf = NULL;
  if (rr != 0)
    return rr;
  rr = read_file(neigh_path, &buf, &len);
  if (rr != 0) {
    free(ele);
    snprintf(why, why_cap, "no readable .neigh output");
    return rr == -2 ? -2 : -1;
  }
  rr = parse_records(".neigh", buf, len, 1, count, tet_count, &neigh_count, &nei, why, why_cap);
  free(buf);
  if (rr != 0) {
    free(ele);
    return rr;
  }
  *out_tet_count = tet_count;
  *out_ele = ele;
  *out_nei = nei;
  return 0;
}

/* Deterministic jitter in [−1, 1] for point i, axis a. */
static double jitter01(uint32_t i, int a)
{
  uint64_t h = hash64(((uint64_t)i << 2 | (uint64_t)a) + 0x9E3779B97F4A7C15ull);
  return (double)(h >> 11) * (2.0 / 9007199254740992.0) - 1.0;
}

ub_result ub_tetgen_build_ex(const float *points, uint32_t n, const ub_tetgen_options *opt,
                             const ub_log *log, ub_tetmesh **out)
{
  if (!out || !points || n == 0) {
    ub_log_printf(log, UB_LOG_ERROR, "tetgen: no probe points");
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (n > 0x3FFFFFF0u) {
    ub_log_printf(log, UB_LOG_ERROR, "tetgen: %u probe points is too many", n);
    return UB_ERR_INVALID_ARGUMENT;
  }
  const char *program = opt && opt->program ? opt->program : "tetgen";
  double lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
  for (uint32_t i = 0; i < n; i++)
    for (int a = 0; a < 3; a++) {
      float x = points[3 * (size_t)i + a];
      if (!isfinite(x)) {
        ub_log_printf(log, UB_LOG_ERROR, "tetgen: probe point %u is not finite", i);
        return UB_ERR_INVALID_DATA;
      }
      lo[a] = fmin(lo[a], x);
      hi[a] = fmax(hi[a], x);
    }
  double ext[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
  double diag = v3len(ext);

  ub_result res = UB_ERR_OUT_OF_MEMORY;
  ub_tetmesh *m = calloc(1, sizeof *m);
  uint32_t *kept_idx = malloc((size_t)n * sizeof *kept_idx);
  int64_t *ele = NULL, *nei = NULL;
  double *coords = NULL;
  char dir[4096] = "";
  char why[1200] = "", why1[512] = "", why2[512] = "";
  if (!m || !kept_idx)
    goto fail;
  m->input_count = n;
  m->input_to_point = malloc((size_t)n * sizeof *m->input_to_point);
  if (!m->input_to_point)
    goto fail;
  int64_t kept = dedup_points(points, n, lo, UB_TETGEN_MERGE_REL * diag, kept_idx,
                              m->input_to_point);
  if (kept < 0)
    goto fail;
  m->merged_count = n - (uint32_t)kept;

  tg_frame frame;
  classify(points, kept_idx, (uint32_t)kept, diag, &frame);
  m->degeneracy = frame.kind;
  m->added_first = (uint32_t)kept;
  m->added_count = frame.kind == UB_TETGEN_GENERAL ? 0 : 8;
  m->point_count = (uint32_t)kept + m->added_count;
  m->points = malloc((size_t)m->point_count * 3 * sizeof *m->points);
  coords = malloc((size_t)m->point_count * 3 * sizeof *coords);
  if (!m->points || !coords)
    goto fail;
  for (uint32_t i = 0; i < (uint32_t)kept; i++)
    memcpy(m->points + 3 * (size_t)i, points + 3 * (size_t)kept_idx[i], 3 * sizeof(float));
  /* TetGen's input: the points themselves, or for a degenerate set their coordinates in
   * the padded frame with the degenerate axes exactly 0 (TetGen 1.5 aborts on large
   * exactly coplanar subsets of tilted planes, but not of axis planes). The connectivity
   * is then used with the real positions. */
  int degenerate_axes = frame.kind == UB_TETGEN_COPLANAR    ? 1
                        : frame.kind == UB_TETGEN_COLLINEAR ? 2
                        : frame.kind == UB_TETGEN_SINGLE_POINT ? 3
                                                               : 0;
  for (uint32_t i = 0; i < (uint32_t)kept; i++) {
    double q[3], e[3];
    v3load(m->points + 3 * (size_t)i, q);
    if (!degenerate_axes) {
      memcpy(coords + 3 * (size_t)i, q, sizeof q);
      continue;
    }
    v3sub(q, frame.center, e);
    for (int j = 0; j < 3; j++)
      coords[3 * (size_t)i + j] = j >= 3 - degenerate_axes ? 0.0 : v3dot(e, frame.axis[j]);
  }
  for (uint32_t c = 0; c < m->added_count; c++) {
    double wpos[3];
    frame_corner(&frame, (int)c, wpos, coords + 3 * ((size_t)kept + c));
    for (int a = 0; a < 3; a++)
      m->points[3 * ((size_t)kept + c) + a] = (float)wpos[a];
  }
  if (m->merged_count)
    ub_log_printf(log, UB_LOG_INFO, "tetgen: merged %u duplicate probe point(s) (tolerance %.3g m)",
                  m->merged_count, UB_TETGEN_MERGE_REL * diag);
  if (m->added_count)
    ub_log_printf(log, UB_LOG_WARNING,
                  "tetgen: probe points are %s; added %u hull points around them",
                  degeneracy_name(m->degeneracy), m->added_count);

  const char *tmp = getenv("TMPDIR");
  if (!tmp || !tmp[0])
    tmp = "/tmp";
  snprintf(dir, sizeof dir, "%s/ubake-tetgen-XXXXXX", tmp);
  if (!mkdtemp(dir)) {
    ub_log_printf(log, UB_LOG_ERROR, "tetgen: cannot create a temporary directory in %s: %s",
                  tmp, strerror(errno));
    dir[0] = '\0';
    res = UB_ERR_IO;
    goto fail;
  }

  /* First attempt on exact coordinates; if TetGen fails on them (it has assertion
   * failures on some exactly degenerate configurations), one retry with a deterministic
   * jitter of UB_TETGEN_RETRY_JITTER × diagonal, written in double so it survives. */
  uint32_t tet_count = 0;
  int rr = tetgen_attempt(dir, "probes", program, coords, m->point_count, &tet_count, &ele,
                          &nei, why1, sizeof why1);
  if (rr == -4) {
    double delta = UB_TETGEN_RETRY_JITTER * (diag > 0.0 ? diag : 2.0 * UB_TETGEN_POINT_PAD);
    for (uint32_t i = 0; i < m->point_count; i++)
      for (int a = 0; a < 3; a++)
        coords[3 * (size_t)i + a] += delta * jitter01(i, a);
    ub_log_printf(log, UB_LOG_WARNING,
                  "tetgen failed on %u probe points (%s); retrying with %.3g m jitter",
                  m->point_count, why1, delta);
    m->retry_jitter = delta;
    rr = tetgen_attempt(dir, "jittered", program, coords, m->point_count, &tet_count, &ele,
                        &nei, why2, sizeof why2);
    if (rr == -4 && !strcmp(why1, why2))
      snprintf(why, sizeof why, "%s (also with jittered coordinates)", why1);
    else if (rr != 0)
      snprintf(why, sizeof why, "%s (retry with jittered coordinates: %s)", why1, why2);
  } else if (rr != 0) {
    snprintf(why, sizeof why, "%s", why1);
  }
  if (rr == -2) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }
  if (rr == -3) {
    ub_log_printf(log, UB_LOG_ERROR, "tetgen: %s", why);
    res = UB_ERR_IO;
    goto fail;
  }
  if (rr != 0)
    goto external;

  m->tet_count = tet_count;
  m->tets = malloc((size_t)tet_count * 4 * sizeof *m->tets);
  m->neigh = malloc((size_t)tet_count * 4 * sizeof *m->neigh);
  if (!m->tets || !m->neigh) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }
  for (size_t i = 0; i < 4 * (size_t)tet_count; i++) {
    m->tets[i] = (uint32_t)ele[i];
    m->neigh[i] = (int32_t)nei[i];
  }
  /* Orientation convention: make det[b−a, c−a, d−a] > 0 on the real positions (swap
   * corners 0 and 1 and their neighbours if the majority of clearly non-flat tets is the
   * other way); validation then rejects any clearly inverted tet. */
  uint32_t pos = 0, neg = 0;
  for (uint32_t t = 0; t < tet_count; t++) {
    double lmax;
    double det = tet_det(m->points, m->tets + 4 * (size_t)t, &lmax);
    double tol = flat_tolerance(m, lmax);
    pos += det > tol;
    neg += det < -tol;
  }
  if (neg > pos) {
    for (uint32_t t = 0; t < tet_count; t++) {
      uint32_t *v = m->tets + 4 * (size_t)t;
      int32_t *nb = m->neigh + 4 * (size_t)t;
      uint32_t tv = v[0];
      v[0] = v[1];
      v[1] = tv;
      int32_t tn = nb[0];
      nb[0] = nb[1];
      nb[1] = tn;
    }
  }
  if (!spatial_order(m)) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }
  res = validate_mesh(m, log, &m->unused_count, &m->flat_tet_count);
  if (res != UB_OK) {
    snprintf(why, sizeof why, "invalid tetrahedralisation (see previous message)");
    res = UB_ERR_EXTERNAL;
    goto external;
  }
  if (m->unused_count)
    ub_log_printf(log, UB_LOG_WARNING, "tetgen: %u probe point(s) are used by no tet",
                  m->unused_count);
  if (m->flat_tet_count)
    ub_log_printf(log, UB_LOG_WARNING, "tetgen: %u nearly flat tet(s)", m->flat_tet_count);
  ub_log_printf(log, UB_LOG_INFO, "tetgen: %u probes (%u input, %u merged, %u added) -> %u tets",
                m->point_count, n, m->merged_count, m->added_count, m->tet_count);
  free(ele);
  free(nei);
  free(coords);
  free(kept_idx);
  ub_remove_dir(dir);
  *out = m;
  return UB_OK;

external:
  ub_log_printf(log, UB_LOG_ERROR, "tetgen failed on %u probe points: %s", m->point_count, why);
  res = UB_ERR_EXTERNAL;
fail:
  if (res == UB_ERR_OUT_OF_MEMORY)
    ub_log_printf(log, UB_LOG_ERROR, "tetgen: out of memory (%u probe points)", n);
  free(ele);
  free(nei);
  free(coords);
  free(kept_idx);
  ub_tetmesh_free(m);
  if (dir[0])
    ub_remove_dir(dir);
  return res;
}
