/* ubake — the command-line program (thin: parses flags, calls the library). */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "bake/geomstate.h"
#include "bake/lights.h"
#include "bake/output.h"
#include "bake/reference.h"
#include "bake/rt.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"
#include "ubake/scene.h"
#include "ubake/sh.h"
#include "tools/regress.h"
#include "tools/spread.h"
#include "tools/sweep.h"
#include "ubake/glg.h"

/* Where the library's info lines go: stdout (bake's stage lines, info's description),
 * nowhere, or stderr as notes (query and render: their stdout is for scripts). */
enum { CLI_INFO_STDOUT = 0, CLI_INFO_DROP = 1, CLI_INFO_STDERR = 2 };

typedef struct cli_log_state {
  int errors;
  int info; /* CLI_INFO_* */
  int progress_line_open;
} cli_log_state;

static void cli_log(void *user, ub_log_level level, const char *msg)
{
  cli_log_state *st = user;
  if (st->progress_line_open) {
    fputs("\r\033[K", stderr);
    st->progress_line_open = 0;
  }
  if (level == UB_LOG_ERROR) {
    if (st->errors == 0)
      fprintf(stderr, "ubake: %s\n", msg);
    st->errors++;
  } else if (level == UB_LOG_WARNING) {
    fprintf(stderr, "ubake: warning: %s\n", msg);
  } else if (st->info == CLI_INFO_STDERR) {
    fprintf(stderr, "ubake: note: %s\n", msg);
  } else if (st->info == CLI_INFO_STDOUT) {
    printf("%s\n", msg);
    fflush(stdout);
  }
}

static int fail(cli_log_state *st, ub_result r, const char *what)
{
  if (st->errors == 0)
    fprintf(stderr, "ubake: %s: %s\n", what, ub_result_string(r));
  return 1;
}

static int usage_error(const char *cmd, const char *msg)
{
  fprintf(stderr, "ubake %s: %s (see 'ubake %s --help')\n", cmd, msg, cmd);
  return 1;
}

/* A bad value v of option opt: "OPT RULE, not 'V'" (quoted, so a typo or what the shell
 * made of it shows); rule says what opt takes. */
static int bad_value(const char *cmd, const char *opt, const char *v, const char *rule)
{
  char msg[480];
  snprintf(msg, sizeof msg, "%s %s, not '%.200s'", opt, rule, v);
  return usage_error(cmd, msg);
}

/* An argument starting with '-' that no branch took: an unknown option, or (no value
 * after it) perhaps a known one missing its value. */
static int bad_option(const char *cmd, const char *opt, const char *next)
{
  char msg[320];
  if (next)
    snprintf(msg, sizeof msg, "unknown option '%.200s'", opt);
  else
    snprintf(msg, sizeof msg, "option '%.200s' lacks its value, or is unknown", opt);
  return usage_error(cmd, msg);
}

/* A second file where the command takes one. */
static int second_file(const char *cmd, const char *first, const char *second)
{
  char msg[600];
  snprintf(msg, sizeof msg, "one file at a time: '%.250s' and '%.250s' given", first, second);
  return usage_error(cmd, msg);
}

/* A decimal number at s as strtod reads it (*out_end: after it): no leading space, no
 * hexadecimal ("0x10"), no inf or nan. One that underflows (1e-310, 1e-400) is read as
 * the tiny value or 0 it is; one that overflows is refused. */
static int parse_real(const char *s, char **out_end, double *out)
{
  const char *d = s + (*s == '+' || *s == '-');
  if (!((*d >= '0' && *d <= '9') || *d == '.') || (d[0] == '0' && (d[1] == 'x' || d[1] == 'X')))
    return 0;
  double v = strtod(s, out_end);
  if (*out_end == s || !isfinite(v))
    return 0;
  *out = v;
  return 1;
}

static int parse_vec3(const char *s, float out[3])
{
  char *end;
  for (int i = 0; i < 3; i++) {
    double v;
    if (!parse_real(s, &end, &v))
      return 0;
    out[i] = (float)v;
    if (i < 2) {
      if (*end != ',')
        return 0;
      s = end + 1;
    }
  }
  return *end == '\0';
}

/* A point in the level: X,Y,Z within the loader's coordinate limit (ubake/scene.h). */
static int parse_point(const char *s, float out[3])
{
  if (!parse_vec3(s, out))
    return 0;
  for (int i = 0; i < 3; i++)
    if (!(fabsf(out[i]) <= UB_SCENE_MAX_COORDINATE))
      return 0;
  return 1;
}

static int parse_uint(const char *s, long max, long *out)
{
  char *end;
  errno = 0;
  long v = strtol(s, &end, 10);
  if (end == s || *end || errno || v < 0 || v > max)
    return 0;
  *out = v;
  return 1;
}

/* ---- state (--dls NAME=W|R,G,B, --door NAME=T, --object NAME=on|off|W) --------------- */

#define UB_CLI_MAX_STATE 256

enum { CLI_DLS = 0, CLI_DOOR = 1, CLI_OBJECT = 2 };

typedef struct cli_state {
  uint32_t count;
  int kind[UB_CLI_MAX_STATE];
  char name[UB_CLI_MAX_STATE][64];
  float rgb[UB_CLI_MAX_STATE][3]; /* DLS: RGB weight; door: t; object: visibility */
} cli_state;

static const char *cli_kind_name(int kind)
{
  return kind == CLI_DLS ? "dynamic light set" : kind == CLI_DOOR ? "door" : "show/hide object";
}

/* One state option: a = "--dls"|"--door"|"--object", v its value. Returns 1 when taken,
 * 0 when a is not a state option, -1 (message printed, quoting v) for a malformed value or
 * a second value for the same element. Numbers as parse_real reads them: decimal, finite;
 * W in [0, UB_RUNTIME_MAX_WEIGHT], T and V in [0, 1]. */
static int parse_state_arg(const char *cmd, const char *a, const char *v, cli_state *st)
{
  int kind = !strcmp(a, "--dls") ? CLI_DLS : !strcmp(a, "--door") ? CLI_DOOR
             : !strcmp(a, "--object") ? CLI_OBJECT : -1;
  if (kind < 0 || !v)
    return 0;
  static const char *forms[] = {
      "takes NAME=W or NAME=R,G,B, W (or each of R,G,B) a decimal number in [0, 1e6]",
      "takes NAME=T, T a decimal number in [0, 1] (0 closed, 1 open)",
      "takes NAME=on, NAME=off or NAME=V, V a decimal number in [0, 1]"};
  char msg[400];
  const char *eq = strchr(v, '=');
  if (eq && (size_t)(eq - v) >= sizeof st->name[0]) {
    snprintf(msg, sizeof msg, "%s: name '%.40s...' is %zu bytes; names are at most %zu", a, v,
             (size_t)(eq - v), sizeof st->name[0] - 1);
    usage_error(cmd, msg);
    return -1;
  }
  if (!eq || eq == v) {
    bad_value(cmd, a, v, forms[kind]);
    return -1;
  }
  float rgb[3];
  char *end;
  double w;
  int ok = 1;
  if (kind == CLI_OBJECT && (!strcmp(eq + 1, "on") || !strcmp(eq + 1, "off"))) {
    rgb[0] = rgb[1] = rgb[2] = !strcmp(eq + 1, "on") ? 1.0f : 0.0f;
  } else if (parse_real(eq + 1, &end, &w) && *end == '\0') {
    rgb[0] = rgb[1] = rgb[2] = (float)w;
    ok = w >= 0.0 && w <= (kind == CLI_DLS ? UB_RUNTIME_MAX_WEIGHT : 1.0);
  } else {
    ok = kind == CLI_DLS && parse_vec3(eq + 1, rgb);
  }
  ok = ok && rgb[0] >= 0.0f && rgb[1] >= 0.0f && rgb[2] >= 0.0f &&
       rgb[0] <= UB_RUNTIME_MAX_WEIGHT && rgb[1] <= UB_RUNTIME_MAX_WEIGHT &&
       rgb[2] <= UB_RUNTIME_MAX_WEIGHT;
  if (!ok) {
    bad_value(cmd, a, v, forms[kind]);
    return -1;
  }
  size_t len = (size_t)(eq - v);
  for (uint32_t k = 0; k < st->count; k++)
    if (st->kind[k] == kind && strlen(st->name[k]) == len && !memcmp(st->name[k], v, len)) {
      snprintf(msg, sizeof msg, "%s '%.200s': %s '%.63s' given twice (one value each)", a, v,
               cli_kind_name(kind), st->name[k]);
      usage_error(cmd, msg);
      return -1;
    }
  if (st->count >= UB_CLI_MAX_STATE) {
    snprintf(msg, sizeof msg, "%s '%.200s': more than %d --dls, --door and --object values", a,
             v, UB_CLI_MAX_STATE);
    usage_error(cmd, msg);
    return -1;
  }
  st->kind[st->count] = kind;
  memcpy(st->name[st->count], v, len);
  st->name[st->count][len] = '\0';
  memcpy(st->rgb[st->count], rgb, sizeof rgb);
  st->count++;
  return 1;
}

/* The names an unknown one could have been, for its message: "it has none", "it has 3:
 * 'a', 'b', 'c'" or "it has 25; the first 10: ..." (add them in order, then read text). */
#define UB_CLI_LIST_NAMES 10

typedef struct name_list {
  uint32_t count;
  char names[UB_CLI_LIST_NAMES * 68];
  char text[UB_CLI_LIST_NAMES * 68 + 64];
} name_list;

static void name_list_add(name_list *l, const char *name)
{
  size_t n = strlen(l->names);
  if (l->count < UB_CLI_LIST_NAMES)
    snprintf(l->names + n, sizeof l->names - n, "%s'%.63s'", l->count ? ", " : "", name);
  l->count++;
}

static const char *name_list_text(name_list *l)
{
  if (!l->count)
    snprintf(l->text, sizeof l->text, "it has none");
  else if (l->count <= UB_CLI_LIST_NAMES)
    snprintf(l->text, sizeof l->text, "it has %u: %s", l->count, l->names);
  else
    snprintf(l->text, sizeof l->text, "it has %u; the first %d: %s", l->count,
             UB_CLI_LIST_NAMES, l->names);
  return l->text;
}

/* Applies a state to a loaded run-time (then updates it). 0 on success; prints the
 * problem (naming the file and the element) and returns 1 otherwise. */
static int apply_state(ub_runtime *rt, const cli_state *st, const char *path)
{
  for (uint32_t k = 0; k < st->count; k++) {
    ub_result r;
    int32_t idx;
    if (st->kind[k] == CLI_DLS) {
      idx = ub_runtime_dls_find(rt, st->name[k]);
      r = idx < 0 ? UB_ERR_INVALID_ARGUMENT : ub_runtime_set_dls(rt, (uint32_t)idx, st->rgb[k]);
    } else {
      idx = ub_runtime_element_find(rt, st->kind[k] == CLI_DOOR ? UB_ELEMENT_DOOR
                                                                : UB_ELEMENT_OBJECT,
                                    st->name[k]);
      r = idx < 0 ? UB_ERR_INVALID_ARGUMENT : ub_runtime_set_element(rt, (uint32_t)idx, st->rgb[k][0]);
    }
    if (idx < 0) {
      name_list known;
      memset(&known, 0, sizeof known);
      if (st->kind[k] == CLI_DLS)
        for (uint32_t i = 0; i < ub_runtime_dls_count(rt); i++)
          name_list_add(&known, ub_runtime_dls_name(rt, i));
      else
        for (uint32_t i = 0; i < ub_runtime_element_count(rt); i++)
          if (ub_runtime_element_kind(rt, i) ==
              (st->kind[k] == CLI_DOOR ? UB_ELEMENT_DOOR : UB_ELEMENT_OBJECT))
            name_list_add(&known, ub_runtime_element_name(rt, i));
      fprintf(stderr, "ubake: %s: no %s named '%s' in this file (%s)\n", path,
              cli_kind_name(st->kind[k]), st->name[k], name_list_text(&known));
      return 1;
    }
    if (r != UB_OK) {
      fprintf(stderr, "ubake: %s: %s '%s': %s\n", path, cli_kind_name(st->kind[k]),
              st->name[k], ub_result_string(r));
      return 1;
    }
  }
  if (st->count && ub_runtime_update(rt, NULL) != UB_OK) {
    fprintf(stderr, "ubake: %s: run-time update failed\n", path);
    return 1;
  }
  return 0;
}

/* ---- progress ---------------------------------------------------------------------- */

typedef struct progress_state {
  cli_log_state *log;
  int tty;
  int enabled;
  double t0;
  char last_stage[32];
} progress_state;

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int on_progress(void *user, const char *stage, double sf, double tf)
{
  progress_state *p = user;
  if (!p->enabled)
    return 0;
  double el = now_s() - p->t0;
  if (p->tty) {
    int w = 30, fill = (int)(sf * w + 0.5);
    char bar[40];
    for (int i = 0; i < w; i++)
      bar[i] = i < fill ? '#' : '.';
    bar[w] = '\0';
    double eta = tf > 0.01 ? el * (1.0 - tf) / tf : -1.0;
    if (eta >= 0)
      fprintf(stderr, "\r\033[K%-10s [%s] %3.0f%%  total %3.0f%%  ETA %.0f s", stage, bar,
              100 * sf, 100 * tf, eta);
    else
      fprintf(stderr, "\r\033[K%-10s [%s] %3.0f%%", stage, bar, 100 * sf);
    p->log->progress_line_open = 1;
  } else if (strcmp(stage, p->last_stage) != 0) {
    /* Plain lines: one per stage, when it starts. */
    snprintf(p->last_stage, sizeof p->last_stage, "%s", stage);
    fprintf(stderr, "progress: %-10s (total %3.0f%%, %.1f s)\n", stage, 100 * tf, el);
  }
  return 0;
}

/* ---- bake -------------------------------------------------------------------------- */

static const char *BAKE_HELP =
    "usage: ubake bake LEVEL.gltf|.glb -o DIR [options]\n"
    "Bakes the level: DIR/NAME.ubk, DIR/NAME_lm<i>.exr (AHD lightmaps, half float),\n"
    "DIR/NAME_lm<i>.png (irradiance preview), DIR/NAME_error<i>.exr/.png (estimated\n"
    "relative standard error per texel: channels E, covered, rel_se, se; false colour,\n"
    "log scale 0.1% blue .. 10% red) and DIR/NAME.report.json.\n"
    "  -o DIR                  output folder (created if missing)\n"
    "  --quality draft|fast|high  sample budget (default fast)\n"
    "  --bounces N             indirect bounces (default: until a bounce adds < 0.5%)\n"
    "  --threads N             worker threads (default: all cores)\n"
    "  --seed N                random seed (default 1)\n"
    "  --gather-rays N         override gather rays per texel per bounce\n"
    "  --target-error E        adaptive sampling: after each bounce's first round, more\n"
    "                          rounds for the texels and probes whose estimated relative\n"
    "                          standard error is above E (e.g. 0.02), up to 16x the rays\n"
    "  --door-rays N           override guided gather rays per texel of a door pass\n"
    "  --door-no-guiding       door passes gather with cosine rays only (comparison)\n"
    "  --influence-dense       DLS influence passes gather at every candidate texel\n"
    "                          (default: one per 2x2 texels of a surface; comparison)\n"
    "  --dls-full-rays         DLS full passes give every kept receiver the full gather\n"
    "                          rays (default: fewer, down to 1/8, where the set's\n"
    "                          estimated light is faint; comparison)\n"
    "  --bounce-full-rays      every bounce gathers with the full rays (default: from\n"
    "                          bounce 3 on, a receiver whose last bounce brought 2^k x\n"
    "                          less light than its brightest gathers with rays / 2^k,\n"
    "                          down to 1/4; comparison)\n"
    "  --texel-size M          override metres per lightmap texel\n"
    "  --glg-spacing M         override metres between coarse GLG probes\n"
    "  --json FILE             write the report here instead of DIR/NAME.report.json\n"
    "  --plan-only             print the plan (passes, skips and their reasons, estimated\n"
    "                          rays and seconds) and stop; writes nothing\n"
    "  --plan auto|all         auto (default): simulate only what the level calls for;\n"
    "                          all: force every effect on, no culling (to check the plan)\n"
    "  --no-progress           no progress output\n";

static int cmd_bake(int argc, char **argv)
{
  ub_bake_options opt;
  ub_bake_options_default(&opt);
  const char *level = NULL;
  int progress = 1;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i];
    const char *v = i + 1 < argc ? argv[i + 1] : NULL;
    long n;
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      fputs(BAKE_HELP, stdout);
      return 0;
    } else if (!strcmp(a, "-o") && v) {
      opt.out_dir = v;
      i++;
    } else if (!strcmp(a, "--quality") && v) {
      if (!ub_quality_from_name(v, &opt.quality))
        return bad_value("bake", a, v, "takes draft, fast or high");
      i++;
    } else if (!strcmp(a, "--bounces") && v) {
      if (!parse_uint(v, UB_BAKE_MAX_BOUNCES, &n))
        return bad_value("bake", a, v, "takes 0..64");
      opt.bounces = (int)n;
      i++;
    } else if (!strcmp(a, "--threads") && v) {
      if (!parse_uint(v, 1024, &n) || n < 1)
        return bad_value("bake", a, v, "takes 1..1024");
      opt.threads = (int)n;
      i++;
    } else if (!strcmp(a, "--seed") && v) {
      if (!parse_uint(v, 0xFFFFFFFFL, &n))
        return bad_value("bake", a, v, "takes 0..4294967295");
      opt.seed = (uint32_t)n;
      i++;
    } else if (!strcmp(a, "--gather-rays") && v) {
      if (!parse_uint(v, 1 << 20, &n) || n < 1)
        return bad_value("bake", a, v, "takes 1..1048576");
      opt.gather_rays = (uint32_t)n;
      i++;
    } else if (!strcmp(a, "--target-error") && v) {
      char *end;
      double t;
      if (!parse_real(v, &end, &t) || *end || !(t > 0.0) || !(t < 1.0))
        return bad_value("bake", a, v, "takes a relative error in (0, 1), e.g. 0.02");
      opt.target_error = t;
      i++;
    } else if (!strcmp(a, "--door-rays") && v) {
      if (!parse_uint(v, 1 << 20, &n) || n < 1)
        return bad_value("bake", a, v, "takes 1..1048576");
      opt.door_rays = (uint32_t)n;
      i++;
    } else if (!strcmp(a, "--door-no-guiding")) {
      opt.door_no_guiding = 1;
    } else if (!strcmp(a, "--texel-size") && v) {
      char *end;
      double t;
      if (!parse_real(v, &end, &t) || *end || !(t > 0.0))
        return bad_value("bake", a, v, "takes a positive number of metres");
      opt.texel_size = (float)t;
      i++;
    } else if (!strcmp(a, "--glg-spacing") && v) {
      char *end;
      double t;
      if (!parse_real(v, &end, &t) || *end || !(t > 0.0))
        return bad_value("bake", a, v, "takes a positive number of metres");
      opt.glg_spacing = (float)t;
      i++;
    } else if (!strcmp(a, "--json") && v) {
      opt.json_path = v;
      i++;
    } else if (!strcmp(a, "--no-progress")) {
      progress = 0;
    } else if (!strcmp(a, "--plan-only")) {
      opt.plan_only = 1;
    } else if (!strcmp(a, "--influence-dense")) {
      opt.influence_dense = 1;
    } else if (!strcmp(a, "--dls-full-rays")) {
      opt.dls_full_rays = 1;
    } else if (!strcmp(a, "--bounce-full-rays")) {
      opt.bounce_full_rays = 1;
    } else if (!strcmp(a, "--plan") && v) {
      if (!strcmp(v, "all"))
        opt.plan_all = 1;
      else if (strcmp(v, "auto"))
        return bad_value("bake", a, v, "takes auto or all");
      i++;
    } else if (a[0] == '-') {
      return bad_option("bake", a, v);
    } else if (!level) {
      level = a;
    } else {
      return usage_error("bake", "more than one level given");
    }
  }
  if (!level)
    return usage_error("bake", "no level given");
  if (!opt.out_dir && !opt.plan_only)
    return usage_error("bake", "no output folder given (-o DIR)");
  cli_log_state ls = {0, CLI_INFO_STDOUT, 0};
  ub_log log = {cli_log, &ls};
  progress_state ps = {&ls, isatty(2), progress, now_s(), ""};
  opt.progress = on_progress;
  opt.progress_user = &ps;
  printf("ubake bake %s (quality %s, seed %u)\n", level, ub_quality_name(opt.quality), opt.seed);
  ub_bake_stats st;
  ub_result r = ub_bake_level(level, &opt, &log, &st);
  if (ls.progress_line_open)
    fputs("\r\033[K", stderr);
  if (r != UB_OK)
    return fail(&ls, r, level);
  if (opt.plan_only)
    return 0;
  /* The report's figures (rays.total, seconds, peak_rss_mib), and the base pass's rate */
  double base_rays = (double)(st.rays_gather + st.rays_shadow);
  double rps = st.gather_seconds > 0 ? base_rays / st.gather_seconds : 0;
  printf("baked %s: %u texels, %u bounces, %.2f M rays (base pass %.2f M at %.2f M rays/s), "
         "%.2f s, peak RSS %.1f MiB, %llu clamped\n",
         st.level_name, st.texels, st.bounces, st.rays_total * 1e-6, base_rays * 1e-6,
         rps * 1e-6, st.total_seconds, st.peak_rss_kb / 1024.0,
         (unsigned long long)st.clamped_values);
  printf("estimated error: relative s.e. over lit texels mean %.2f%%, p95 %.2f%%",
         100.0 * st.texel_rel_se_mean, 100.0 * st.texel_rel_se_p95);
  if (opt.target_error > 0.0)
    printf(" (target %.2f%%: adaptive rounds %.2f M rays)", 100.0 * opt.target_error,
           st.rays_adaptive * 1e-6);
  printf("\nwrote %s\n", st.ubk_path);
  return 0;
}

/* Bytes of a record in the file (indices + half SH). */
static unsigned long long record_bytes(const ub_bakefile_record *rc)
{
  return (unsigned long long)rc->texel_count * 28 + (unsigned long long)rc->probe_count * 58 +
         (unsigned long long)rc->llg_probe_count * 58;
}

static const char *element_kind_name(uint32_t kind)
{
  return kind == UB_ELEMENT_DLS ? "set" : kind == UB_ELEMENT_DOOR ? "door"
         : kind == UB_ELEMENT_OBJECT ? "object" : "combination";
}

/* Name of an element in the global numbering (sets, then ELEM records). */
static const char *element_name(const ub_bakefile *bf, int32_t e)
{
  if (e >= 0 && (uint32_t)e < bf->dls_count)
    return bf->dls[e].name;
  if (e >= 0 && (uint32_t)e - bf->dls_count < bf->elem_count)
    return bf->elems[e - (int32_t)bf->dls_count].name;
  return "?";
}

/* "--records half|8bit": the run-time's load flags. 1 when taken (*flags set), -1 on a
 * bad value (message printed), 0 when a is another option. */
static int parse_records_arg(const char *cmd, const char *a, const char *v, unsigned *flags)
{
  if (strcmp(a, "--records") || !v)
    return 0;
  if (!strcmp(v, "half")) {
    *flags &= ~UB_RUNTIME_RECORDS_8BIT;
  } else if (!strcmp(v, "8bit")) {
    *flags |= UB_RUNTIME_RECORDS_8BIT;
  } else {
    bad_value(cmd, a, v, "takes half or 8bit");
    return -1;
  }
  return 1;
}

#define RECORDS_HELP                                                                     \
  "  --records 8bit      the run-time keeps the records of sets, doors and objects in 8\n" \
  "                      bits (UB_RUNTIME_RECORDS_8BIT: ~40% less record memory, slower\n"  \
  "                      updates); default half, as the file stores them\n"

/* ---- info -------------------------------------------------------------------------- */

static const char *INFO_HELP =
    "usage: ubake info DIR/NAME.ubk [--json] [--memory [--records half|8bit] [--keep-state]\n"
    "                                                  [--glg-small-walk] [--no-base-ahd]\n"
    "                                                  [--separate-groups]]\n"
    "Prints what the bake file holds: geometry, atlases, texels, bytes.\n"
    "  --json      the same as one JSON object\n"
    "  --memory    also load it in the run-time and print what the run-time holds, by\n"
    "              part (ub_runtime_memory_usage: geometry, lightmap, GLG, LLG, records,\n"
    "              blend engines), and the load time\n"
    RECORDS_HELP
    "  --keep-state        with the load state kept (UB_RUNTIME_KEEP_STATE: 16 B a texel\n"
    "                      that a set, door or object touches; a return to it copies)\n"
    "  --glg-small-walk    with the GLG's small walk (UB_RUNTIME_GLG_SMALL_WALK: 48 B a\n"
    "                      tet less, slower GLG queries)\n"
    "  --no-base-ahd       without the base state's AHD (UB_RUNTIME_NO_BASE_AHD: 16 B a\n"
    "                      touched texel less; a set turned off then re-encodes the texels\n"
    "                      no other element lights)\n"
    "  --separate-groups   every overlap combination in a group of its own\n"
    "                      (UB_RUNTIME_SEPARATE_GROUPS: no zero rows merging rare ones into\n"
    "                      common ones; more groups, a faster load)\n";

/* The run-time load's notes for ubake info: errors and warnings go to the CLI's log at
 * once, notes are kept (up to 4 KiB) and printed under the run-time memory line, after
 * the header they used to come before; with --json (forward) they go to the CLI's log
 * too, which puts them on stderr. */
typedef struct info_notes {
  const ub_log *cli;
  int forward;
  char text[4096];
  size_t len;
} info_notes;

static void info_notes_log(void *user, ub_log_level level, const char *msg)
{
  info_notes *n = user;
  if (level != UB_LOG_INFO || n->forward) {
    n->cli->fn(n->cli->user, level, msg);
    return;
  }
  int w = snprintf(n->text + n->len, sizeof n->text - n->len, "    note: %s\n", msg);
  if (w > 0)
    n->len = n->len + (size_t)w < sizeof n->text ? n->len + (size_t)w : sizeof n->text - 1;
}

/* The run-time's bytes for path (loads it, first thing in the process): 0 on success.
 * out_peak_mib: how far the resident set rose above the process's while loading (the
 * kernel's peak, reset first; -1 where it cannot be reset). The load's notes go to notes. */
static int info_memory(const char *path, info_notes *notes, unsigned flags,
                       ub_runtime_memory *out, double *out_seconds, double *out_peak_mib)
{
  int reset = ub_peak_rss_reset();
  long rss0 = ub_proc_status_kb("VmRSS:");
  double t0 = now_s();
  ub_runtime *rt = NULL;
  const ub_log log = {info_notes_log, notes};
  if (ub_runtime_load_ex(path, &log, flags, &rt) != UB_OK)
    return 1;
  *out_seconds = now_s() - t0;
  long hwm = ub_proc_status_kb("VmHWM:");
  *out_peak_mib = reset && rss0 >= 0 && hwm >= 0 ? (hwm - rss0) / 1024.0 : -1.0;
  ub_runtime_memory_usage(rt, out);
  ub_runtime_free(rt);
  return 0;
}

static int cmd_info(int argc, char **argv)
{
  const char *path = NULL;
  int json = 0, memory = 0, k;
  unsigned load_flags = 0;
  for (int i = 0; i < argc; i++) {
    if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
      fputs(INFO_HELP, stdout);
      return 0;
    } else if ((k = parse_records_arg("info", argv[i], i + 1 < argc ? argv[i + 1] : NULL,
                                      &load_flags)) != 0) {
      if (k < 0)
        return 1;
      i++;
    } else if (!strcmp(argv[i], "--json")) {
      json = 1;
    } else if (!strcmp(argv[i], "--memory")) {
      memory = 1;
    } else if (!strcmp(argv[i], "--keep-state")) {
      load_flags |= UB_RUNTIME_KEEP_STATE;
    } else if (!strcmp(argv[i], "--glg-small-walk")) {
      load_flags |= UB_RUNTIME_GLG_SMALL_WALK;
    } else if (!strcmp(argv[i], "--no-base-ahd")) {
      load_flags |= UB_RUNTIME_NO_BASE_AHD;
    } else if (!strcmp(argv[i], "--separate-groups")) {
      load_flags |= UB_RUNTIME_SEPARATE_GROUPS;
    } else if (argv[i][0] == '-') {
      return bad_option("info", argv[i], i + 1 < argc ? argv[i + 1] : NULL);
    } else if (path) {
      return second_file("info", path, argv[i]);
    } else {
      path = argv[i];
    }
  }
  if (!path)
    return usage_error("info", "no .ubk given");
  if (load_flags && !memory)
    return usage_error("info", "--records, --keep-state, --glg-small-walk, --no-base-ahd and "
                               "--separate-groups go with --memory (the run-time's bytes)");
  /* --json: stdout holds the JSON only; the loads' notes go to stderr */
  cli_log_state ls = {0, json ? CLI_INFO_STDERR : CLI_INFO_STDOUT, 0};
  ub_log log = {cli_log, &ls};
  /* the run-time first: its load's peak is then its own */
  ub_runtime_memory mem;
  double load_s = 0.0, load_peak = -1.0;
  info_notes notes = {&log, json, {0}, 0};
  if (memory && info_memory(path, &notes, load_flags, &mem, &load_s, &load_peak))
    return fail(&ls, UB_ERR_INVALID_DATA, path);
  ub_bakefile *bf = NULL;
  ub_result r = ub_bakefile_read(path, &log, &bf);
  if (r != UB_OK)
    return fail(&ls, r, path);
  struct stat sb;
  long long bytes = stat(path, &sb) == 0 ? (long long)sb.st_size : -1;
  uint64_t covered = 0, dilated = 0, total = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    size_t npx = (size_t)bf->atlases[a].width * bf->atlases[a].height;
    total += npx;
    for (size_t p = 0; p < npx; p++) {
      covered += bf->atlases[a].coverage[p] == 1;
      dilated += bf->atlases[a].coverage[p] == 2;
    }
  }
  /* On-disk GLG bytes: positions f32, SH L2 half, tets, neighbours, plane refs, planes. */
  unsigned long long glg_bytes =
      (unsigned long long)bf->glg_probe_count * (12 + 54) +
      (unsigned long long)bf->glg_tet_count * (16 + 16 + 4) +
      (unsigned long long)bf->glg_plane_count * 16;
  /* On-disk LLG bytes: per model header, f32 vertices/normals, u32 triangles, half SH,
   * half visibility and gain. */
  unsigned long long llg_bytes = 0, llg_probes = 0, llg_vertices = 0, llg_shared = 0;
  for (uint32_t i = 0; i < bf->llg_count; i++) {
    const ub_bakefile_llg *m = &bf->llgs[i];
    unsigned long long np = (unsigned long long)m->dims[0] * m->dims[1] * m->dims[2];
    llg_probes += np;
    llg_vertices += m->vertex_count;
    llg_bytes += 144 + 54 * np + 48ULL * m->vertex_count + 12ULL * m->triangle_count;
    if (m->vis_shared_from) /* instance: visibility stored once (+40 B headers each) */
      llg_bytes -= 18ULL * m->vertex_count;
    llg_shared += m->vis_shared_from != 0;
  }
  if (llg_shared)
    llg_bytes += 40ULL * bf->llg_count;
  if (json) {
    printf("{\"level\": ");
    ub_json_write_str(stdout, bf->level_name);
    printf(", \"bytes\": %lld, \"seed\": %u, \"bounces\": %u, "
           "\"vertices\": %u, \"triangles\": %u, \"atlases\": [",
           bytes, bf->seed, bf->bounces, bf->vertex_count, bf->triangle_count);
    for (uint32_t a = 0; a < bf->atlas_count; a++)
      printf("%s{\"width\": %u, \"height\": %u}", a ? ", " : "", bf->atlases[a].width,
             bf->atlases[a].height);
    printf("], \"texels\": %llu, \"covered_texels\": %llu, \"dilated_texels\": %llu, "
           "\"glg_probes\": %u, \"glg_tets\": %u, \"glg_leak_planes\": %u, "
           "\"glg_bytes\": %llu, \"llg_models\": %u, \"llg_probes\": %llu, "
           "\"llg_vertices\": %llu, \"llg_bytes\": %llu, \"dls\": [",
           (unsigned long long)total, (unsigned long long)covered,
           (unsigned long long)dilated, bf->glg_probe_count, bf->glg_tet_count,
           bf->glg_plane_count, glg_bytes, bf->llg_count, llg_probes, llg_vertices, llg_bytes);
    for (uint32_t d = 0; d < bf->dls_count; d++) {
      printf("%s{\"name\": ", d ? ", " : "");
      ub_json_write_str(stdout, bf->dls[d].name);
      printf(", \"lights\": %u, \"texels\": %u, \"probes\": %u, "
             "\"llg_probes\": %u, \"bytes\": %llu}",
             bf->dls[d].light_count, bf->dls[d].texel_count, bf->dls[d].probe_count,
             bf->dls[d].llg_probe_count, record_bytes(&bf->dls[d]));
    }
    printf("], \"elements\": [");
    for (uint32_t e = 0; e < bf->elem_count; e++) {
      const ub_bakefile_record *rc = &bf->elems[e];
      printf("%s{\"name\": ", e ? ", " : "");
      ub_json_write_str(stdout, rc->name);
      printf(", \"kind\": \"%s\", \"parents\": [%d, %d], "
             "\"texels\": %u, \"probes\": %u, \"llg_probes\": %u, \"bytes\": %llu}",
             element_kind_name(rc->kind), (int)rc->parent[0], (int)rc->parent[1],
             rc->texel_count, rc->probe_count, rc->llg_probe_count, record_bytes(rc));
    }
    printf("]");
    if (memory)
      printf(", \"runtime_memory\": {\"geometry\": %zu, \"lightmap\": %zu, \"glg\": %zu, "
             "\"llg\": %zu, \"records\": %zu, \"blend\": %zu, \"total\": %zu, "
             "\"load_seconds\": %.3f, \"load_peak_mib\": %.1f}", mem.geometry, mem.lightmap,
             mem.glg, mem.llg, mem.records, mem.blend, mem.total, load_s, load_peak);
    printf("}\n");
  } else {
    printf("%s: level %s, %lld bytes, seed %u, %u bounces\n", path, bf->level_name, bytes,
           bf->seed, bf->bounces);
    printf("  geometry: %u vertices, %u triangles\n", bf->vertex_count, bf->triangle_count);
    for (uint32_t a = 0; a < bf->atlas_count; a++)
      printf("  atlas %u: %u x %u\n", a, bf->atlases[a].width, bf->atlases[a].height);
    printf("  texels: %llu (%llu covered, %llu dilated padding)\n", (unsigned long long)total,
           (unsigned long long)covered, (unsigned long long)dilated);
    if (bf->glg_probe_count)
      printf("  GLG: %u probes, %u tets, %u leak planes, %llu bytes (%.1f bytes/probe)\n",
             bf->glg_probe_count, bf->glg_tet_count, bf->glg_plane_count, glg_bytes,
             (double)glg_bytes / bf->glg_probe_count);
    else
      printf("  GLG: none baked\n");
    if (bf->llg_count) {
      printf("  LLG: %u model(s), %llu probes, %llu vertices, %llu bytes\n", bf->llg_count,
             llg_probes, llg_vertices, llg_bytes);
      for (uint32_t i = 0; i < bf->llg_count; i++)
        printf("    %-20s grid %u x %u x %u, %u vertices, %u triangles%s%s\n", bf->llgs[i].name,
               bf->llgs[i].dims[0], bf->llgs[i].dims[1], bf->llgs[i].dims[2],
               bf->llgs[i].vertex_count, bf->llgs[i].triangle_count,
               bf->llgs[i].vis_shared_from ? ", self-visibility of " : "",
               bf->llgs[i].vis_shared_from ? bf->llgs[bf->llgs[i].vis_shared_from - 1].name : "");
    } else {
      printf("  LLG: none baked\n");
    }
    printf("  dynamic light sets: %u\n", bf->dls_count);
    for (uint32_t d = 0; d < bf->dls_count; d++) {
      const ub_bakefile_record *rc = &bf->dls[d];
      printf("    %-20s %2u light(s), %8u texels, %6u GLG probes, %6u LLG probes, %9llu "
             "bytes\n", rc->name, rc->light_count, rc->texel_count, rc->probe_count,
             rc->llg_probe_count, record_bytes(rc));
    }
    printf("  doors, objects, combinations: %u\n", bf->elem_count);
    for (uint32_t e = 0; e < bf->elem_count; e++) {
      const ub_bakefile_record *rc = &bf->elems[e];
      char parents[160] = "";
      if (rc->kind == UB_ELEMENT_COMBO)
        snprintf(parents, sizeof parents, " (%s × %s)", element_name(bf, rc->parent[0]),
                 element_name(bf, rc->parent[1]));
      printf("    %-11s %-20s %8u texels, %6u GLG probes, %6u LLG probes, %9llu bytes%s\n",
             element_kind_name(rc->kind), rc->name, rc->texel_count, rc->probe_count,
             rc->llg_probe_count, record_bytes(rc), parents);
    }
    if (memory) {
      printf("  run-time memory: %.1f MiB = geometry %.1f + lightmap %.1f + GLG %.1f + LLG %.1f"
             " + records %.1f + blend engines %.1f (loaded in %.2f s", mem.total / 1048576.0,
             mem.geometry / 1048576.0, mem.lightmap / 1048576.0, mem.glg / 1048576.0,
             mem.llg / 1048576.0, mem.records / 1048576.0, mem.blend / 1048576.0, load_s);
      if (load_peak >= 0.0)
        printf(", resident set at most +%.1f MiB while loading", load_peak);
      printf(")\n");
      fputs(notes.text, stdout); /* the load's notes, if any */
    }
  }
  ub_bakefile_free(bf);
  return 0;
}

/* ---- query ------------------------------------------------------------------------- */

static const char *QUERY_HELP =
    "usage: ubake query DIR/NAME.ubk --at X,Y,Z --normal X,Y,Z [--source auto|glg|llg|lightmap]\n"
    "                   [--dls NAME=W|R,G,B ...] [--door NAME=T ...] [--object NAME=on|off ...]\n"
    "                   [--records half|8bit]\n"
    "Prints the baked irradiance \"R G B\" (W/m², linear) the run-time uses there; notes\n"
    "(the load's, a point far from what answered) go to stderr.\n"
    "  --dls NAME=W        weight (or RGB tint) of a dynamic light set (default 1: as baked),\n"
    "                      decimal numbers in [0, 1e6]; one value per set (also --door,\n"
    "                      --object)\n"
    "  --door NAME=T       opening fraction of a door, T in [0, 1] (default 0: closed; from\n"
    "                      a hinge angle a: T = 1 - cos a, 1 beyond 90 degrees)\n"
    "  --object NAME=V     on, off, or a visibility in [0, 1] to fade (default on)\n"
    "  --source lightmap   the lightmap of the closest lightmapped surface point the state\n"
    "                      shows (a note on stderr when a hidden one is closer, or when it\n"
    "                      is over 1 m from the point)\n"
    "  --source glg        the global light grid (tetrahedral probes), as a dynamic object\n"
    "                      (a note on stderr when the point is outside the probes' hull)\n"
    "  --source llg        the local light grid of the LLG model whose box holds the point\n"
    "                      (closest box otherwise), with its self-visibility within 5 cm\n"
    "                      of its surface\n"
    "  --source auto       the default: glg (a point in space)\n"
    RECORDS_HELP;

/* Metres from the query point to the lightmapped surface that answered beyond which the
 * answer gets a note (a point in the air, or far outside the level). */
#define UB_CLI_FAR_SURFACE 1.0f

static int cmd_query(int argc, char **argv)
{
  const char *path = NULL, *source = "auto";
  unsigned load_flags = 0;
  static cli_state state;
  state.count = 0;
  float at[3], nrm[3];
  const char *nrm_arg = NULL;
  int have_at = 0;
  int k;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i];
    const char *v = i + 1 < argc ? argv[i + 1] : NULL;
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      fputs(QUERY_HELP, stdout);
      return 0;
    } else if (!strcmp(a, "--at") && v) {
      if (!parse_point(v, at))
        return bad_value("query", a, v, "takes X,Y,Z, each within +-1e7 m");
      have_at = 1;
      i++;
    } else if (!strcmp(a, "--normal") && v) {
      if (!parse_vec3(v, nrm))
        return bad_value("query", a, v, "takes X,Y,Z");
      nrm_arg = v;
      i++;
    } else if (!strcmp(a, "--source") && v) {
      source = v;
      i++;
    } else if ((k = parse_state_arg("query", a, v, &state)) != 0 ||
               (k = parse_records_arg("query", a, v, &load_flags)) != 0) {
      if (k < 0)
        return 1;
      i++;
    } else if (a[0] == '-') {
      return bad_option("query", a, v);
    } else if (path) {
      return second_file("query", path, a);
    } else {
      path = a;
    }
  }
  if (!path || !have_at || !nrm_arg)
    return usage_error("query", "need DIR/NAME.ubk, --at and --normal");
  float len = sqrtf(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
  if (!(len > 0.0f) || !isfinite(len))
    return bad_value("query", "--normal", nrm_arg, "takes a non-zero X,Y,Z");
  for (int i = 0; i < 3; i++)
    nrm[i] /= len;
  if (strcmp(source, "auto") && strcmp(source, "lightmap") && strcmp(source, "glg") &&
      strcmp(source, "llg"))
    return bad_value("query", "--source", source, "takes auto, glg, llg or lightmap");
  cli_log_state ls = {0, CLI_INFO_STDERR, 0}; /* stdout is the answer: notes on stderr */
  ub_log log = {cli_log, &ls};
  ub_runtime *rt = NULL;
  ub_result r = ub_runtime_load_ex(path, &log, load_flags, &rt);
  if (r != UB_OK)
    return fail(&ls, r, path);
  if (apply_state(rt, &state, path)) {
    ub_runtime_free(rt);
    return 1;
  }
  float rgb[3];
  ub_runtime_lightmap_hit hit;
  hit.hidden_closer = 0;
  hit.distance = 0.0f;
  ub_glg_locate_info glg_at;
  memset(&glg_at, 0, sizeof glg_at);
  /* auto: a point in space is answered by the GLG, as for a dynamic object. */
  if (!strcmp(source, "lightmap"))
    r = ub_runtime_query_lightmap_ex(rt, at, nrm, rgb, &hit);
  else if (!strcmp(source, "llg"))
    r = ub_runtime_query_llg(rt, at, nrm, rgb);
  else
    r = ub_runtime_query_glg(rt, at, nrm, NULL, rgb);
  if (r == UB_OK && strcmp(source, "lightmap") && strcmp(source, "llg")) {
    float bary[4];
    ub_glg_locate_ex(ub_runtime_glg(rt), at, NULL, bary, &glg_at);
  }
  /* A point far from what answered gets a note: the value is that surface's or the
   * GLG hull's, not the point's. */
  if (r == UB_OK && hit.distance > UB_CLI_FAR_SURFACE)
    fprintf(stderr, "ubake: note: the closest lightmapped surface shown (triangle %u) is %.3g m "
            "from (%g, %g, %g): the answer is that surface's\n", hit.triangle, hit.distance,
            at[0], at[1], at[2]);
  if (r == UB_OK && glg_at.outside)
    fprintf(stderr, "ubake: note: (%g, %g, %g) is outside the GLG probes' hull: answered at "
            "the closest point on the hull\n", at[0], at[1], at[2]);
  if (r == UB_OK && hit.hidden_closer) {
    /* The surface nearest the point is hidden in this state: say so, and which surface
     * answered instead. */
    const char *el = hit.hidden_element >= 0
                         ? ub_runtime_element_name(rt, (uint32_t)hit.hidden_element) : NULL;
    fprintf(stderr,
            "ubake: note: not shown: the closest lightmapped surface (triangle %u of %s, "
            "%.3g m away) is hidden in this state; answered from the closest shown surface, "
            "%.3g m away\n",
            hit.hidden_triangle, el ? el : "?", hit.hidden_distance, hit.distance);
  }
  ub_runtime_free(rt);
  if (r == UB_ERR_NOT_BAKED) {
    fprintf(stderr, "ubake: %s: no %s data baked in this file (or none shown in this state)\n", path,
            !strcmp(source, "lightmap") ? "lightmap" : !strcmp(source, "llg") ? "LLG" : "GLG");
    return 1;
  }
  if (r != UB_OK)
    return fail(&ls, r, path);
  printf("%.6g %.6g %.6g\n", rgb[0], rgb[1], rgb[2]);
  return 0;
}

/* ---- reference --------------------------------------------------------------------- */

static const char *REFERENCE_HELP =
    "usage: ubake reference LEVEL.gltf --at X,Y,Z --normal X,Y,Z [--spp N] [--seed N]\n"
    "          [--bounces N] [--threads N] [--dls NAME=W|R,G,B ...] [--door NAME=0|1 ...]\n"
    "          [--object NAME=on|off ...] [--sh]\n"
    "Brute-force path-traced irradiance (W/m², linear RGB) for the same path classes as the\n"
    "bake. Prints \"R G B\" on the first line and \"se R G B\" (standard error) on the second.\n"
    "  --sh                the best an exact SH L2 probe at the point can answer (the GLG's\n"
    "                      representation floor): traces the incident radiance over the\n"
    "                      whole sphere, projects it to SH L2 and windows it as the GLG\n"
    "                      does; prints that irradiance for --normal, \"se\" (of the\n"
    "                      un-windowed L2 irradiance), then \"raw R G B\" (un-windowed) and\n"
    "                      \"sh\" with the 27 coefficients (W/(m²·sr), coefficient-major)\n"
    "  --door NAME=0       the closed leaf, with its own albedo (default)\n"
    "  --door NAME=1       the leaf removed, or in its open pose (ubake_door_open) if any\n"
    "  --object NAME=off   the show/hide object removed (default: on, as designed)\n";

static int cmd_reference(int argc, char **argv)
{
  const char *level = NULL;
  static cli_state state;
  state.count = 0;
  ub_reference_params rp;
  ub_reference_params_init(&rp);
  int have_at = 0, have_n = 0, want_sh = 0;
  int k;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i];
    const char *v = i + 1 < argc ? argv[i + 1] : NULL;
    long n;
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      fputs(REFERENCE_HELP, stdout);
      return 0;
    } else if (!strcmp(a, "--sh")) {
      want_sh = 1;
    } else if (!strcmp(a, "--at") && v) {
      if (!parse_point(v, rp.position))
        return bad_value("reference", a, v, "takes X,Y,Z, each within +-1e7 m");
      have_at = 1;
      i++;
    } else if (!strcmp(a, "--normal") && v) {
      if (!parse_vec3(v, rp.normal))
        return bad_value("reference", a, v, "takes X,Y,Z");
      have_n = 1;
      i++;
    } else if (!strcmp(a, "--spp") && v) {
      if (!parse_uint(v, UB_REFERENCE_MAX_SPP, &n) || n < 1)
        return bad_value("reference", a, v, "takes 1..2^30");
      rp.spp = (uint32_t)n;
      i++;
    } else if (!strcmp(a, "--seed") && v) {
      if (!parse_uint(v, 0xFFFFFFFFL, &n))
        return bad_value("reference", a, v, "takes 0..4294967295");
      rp.seed = (uint32_t)n;
      i++;
    } else if (!strcmp(a, "--bounces") && v) {
      if (!parse_uint(v, 1 << 20, &n))
        return bad_value("reference", a, v, "takes a count");
      rp.max_bounces = (uint32_t)n;
      i++;
    } else if (!strcmp(a, "--threads") && v) {
      if (!parse_uint(v, 1024, &n) || n < 1)
        return bad_value("reference", a, v, "takes 1..1024");
      rp.threads = (int)n;
      i++;
    } else if ((k = parse_state_arg("reference", a, v, &state)) != 0) {
      if (k < 0)
        return 1;
      i++;
    } else if (a[0] == '-') {
      return bad_option("reference", a, v);
    } else if (level) {
      return second_file("reference", level, a);
    } else {
      level = a;
    }
  }
  if (!level || !have_at || !have_n)
    return usage_error("reference", "need LEVEL, --at and --normal");
  cli_log_state ls = {0, CLI_INFO_DROP, 0};
  ub_log log = {cli_log, &ls};
  ub_scene *scene = NULL;
  ub_rt *rt = NULL;
  ub_emitters *em = NULL;
  ub_result r = ub_scene_load(level, &log, &scene);
  float rgb[3], se[3], sh[27], raw[3];
  float *weights = NULL;
  uint8_t *door_open = NULL, *shown = NULL, *mask = NULL;
  if (r == UB_OK) {
    weights = malloc(((size_t)scene->dls_count + 1) * 3 * sizeof *weights);
    door_open = calloc((size_t)scene->door_count + 1, 1);
    shown = malloc((size_t)scene->object_count + 1);
    if (!weights || !door_open || !shown)
      r = UB_ERR_OUT_OF_MEMORY;
  }
  if (r == UB_OK) {
    for (uint32_t d = 0; d < scene->dls_count * 3; d++)
      weights[d] = 1.0f;
    memset(shown, 1, (size_t)scene->object_count + 1);
    rp.dls_weight = scene->dls_count ? weights : NULL;
  }
  /* The state: DLS weights, and the geometry of doors (closed leaf with its own albedo,
   * or the open pose / nothing) and objects (shown or not), as bake/geomstate.h. */
  for (uint32_t k = 0; r == UB_OK && k < state.count; k++) {
    uint32_t n = state.kind[k] == CLI_DLS ? scene->dls_count
                 : state.kind[k] == CLI_DOOR ? scene->door_count : scene->object_count;
    char **names = state.kind[k] == CLI_DLS ? scene->dls_names
                   : state.kind[k] == CLI_DOOR ? scene->door_names : scene->object_names;
    uint32_t d;
    for (d = 0; d < n; d++)
      if (!strcmp(names[d], state.name[k]))
        break;
    float w = state.rgb[k][0];
    if (d == n) {
      name_list known;
      memset(&known, 0, sizeof known);
      for (d = 0; d < n; d++)
        name_list_add(&known, names[d]);
      fprintf(stderr, "ubake: %s: no %s named '%s' (%s)\n", level, cli_kind_name(state.kind[k]),
              state.name[k], name_list_text(&known));
    } else if (state.kind[k] != CLI_DLS && w != 0.0f && w != 1.0f) {
      fprintf(stderr, "ubake: %s: %s '%s': the reference traces the geometry as it is: "
              "only 0 or 1 (closed/open, off/on)\n", level, cli_kind_name(state.kind[k]),
              state.name[k]);
    } else {
      if (state.kind[k] == CLI_DLS)
        memcpy(weights + 3 * d, state.rgb[k], 3 * sizeof(float));
      else if (state.kind[k] == CLI_DOOR)
        door_open[d] = w == 1.0f;
      else
        shown[d] = w == 1.0f;
      continue;
    }
    ls.errors++;
    r = UB_ERR_INVALID_ARGUMENT;
  }
  if (r == UB_OK) {
    ub_geom_state gs = {door_open, shown};
    mask = ub_geom_mask(scene, &gs);
    r = mask ? ub_rt_create(scene, mask, &log, &rt) : UB_ERR_OUT_OF_MEMORY;
  }
  if (r == UB_OK)
    r = ub_emitters_build(scene, &em);
  if (r == UB_OK && !want_sh)
    r = ub_reference_irradiance(scene, rt, em, &rp, rgb, se, &log);
  if (r == UB_OK && want_sh) {
    r = ub_reference_radiance_sh(scene, rt, em, &rp, sh, raw, se, &log);
    if (r == UB_OK) {
      float win[27];
      memcpy(win, sh, sizeof win);
      ub_sh2_window(win);
      ub_sh2_irradiance(win, rp.normal, rgb);
    }
  }
  free(weights);
  free(door_open);
  free(shown);
  free(mask);
  ub_emitters_free(em);
  ub_rt_free(rt);
  ub_scene_free(scene);
  if (r != UB_OK)
    return fail(&ls, r, level);
  printf("%.6g %.6g %.6g\nse %.6g %.6g %.6g\n", rgb[0], rgb[1], rgb[2], se[0], se[1], se[2]);
  if (want_sh) {
    printf("raw %.6g %.6g %.6g\nsh", raw[0], raw[1], raw[2]);
    for (int c = 0; c < 27; c++)
      printf(" %.6g", sh[c]);
    printf("\n");
  }
  return 0;
}

/* ---- render ------------------------------------------------------------------------ */

#include <stb_image_write.h> /* implementation in libstb: no STB_IMAGE_WRITE_IMPLEMENTATION */

#include "ubake/render.h"

static const char *RENDER_HELP =
    "usage: ubake render DIR/NAME.ubk --camera EX,EY,EZ,TX,TY,TZ,FOVY -o OUT.png\n"
    "          [--size WxH] [--exposure EV] [--samples N] [--dls NAME=W|R,G,B ...]\n"
    "          [--door NAME=T ...] [--object NAME=on|off|V ...] [--records half|8bit]\n"
    "Renders the level from a camera as the run-time shows it: lightmaps on lightmapped\n"
    "geometry, the global light grid on the rest, plus the run-time direct light of the\n"
    "primary lights (with shadows), under the given state. Back faces are black; a\n"
    "warning names what the camera sees when under half of the view meets front faces\n"
    "(a camera in a wall or outside the level), or says so when every pixel is black.\n"
    "Warnings and the load's notes go to stderr.\n"
    "  -o OUT.png          the image (PNG: the path must end in .png)\n"
    "  --camera ...        eye X,Y,Z, target X,Y,Z (metres, Y up), vertical field of view\n"
    "                      in degrees (7 numbers)\n"
    "  --size WxH          image size in pixels (default 960x540)\n"
    "  --exposure EV       fixed exposure: pixels × 2^EV before the filmic curve (default:\n"
    "                      automatic from the 95th percentile of luminance; the EV used is\n"
    "                      printed, pass it back to compare states at the same exposure)\n"
    "  --samples N         N×N rays per pixel (default 1)\n"
    "  --dls NAME=W        weight (or R,G,B tint) of a dynamic light set, in [0, 1e6]\n"
    "                      (default 1); one value per set, door or object\n"
    "  --door NAME=T       opening fraction of a door in [0, 1] (default 0: closed)\n"
    "  --object NAME=V     on, off or a visibility in [0, 1] (default on)\n"
    RECORDS_HELP;

static int cmd_render(int argc, char **argv)
{
  const char *path = NULL, *out_png = NULL;
  unsigned load_flags = 0;
  ub_render_params rp;
  ub_render_params_default(&rp);
  int have_camera = 0, auto_exposure = 1;
  float ev = 0.0f;
  static cli_state state;
  state.count = 0;
  int sk;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i];
    const char *v = i + 1 < argc ? argv[i + 1] : NULL;
    char *end;
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      fputs(RENDER_HELP, stdout);
      return 0;
    } else if (!strcmp(a, "--camera") && v) {
      float c[7];
      const char *s = v;
      int ok = 1;
      for (int k = 0; k < 7 && ok; k++) {
        double x = 0.0;
        ok = parse_real(s, &end, &x) && (k == 6 ? *end == '\0' : *end == ',');
        c[k] = (float)x;
        s = end + 1;
      }
      if (!ok) {
        return bad_value("render", a, v, "takes EX,EY,EZ,TX,TY,TZ,FOVY (7 numbers)");
      }
      memcpy(rp.eye, c, sizeof rp.eye);
      memcpy(rp.target, c + 3, sizeof rp.target);
      rp.fovy_degrees = c[6];
      have_camera = 1;
      i++;
    } else if ((!strcmp(a, "-o") || !strcmp(a, "--output")) && v) {
      out_png = v;
      i++;
    } else if (!strcmp(a, "--size") && v) {
      errno = 0;
      unsigned long w = strtoul(v, &end, 10), h = 0;
      int ok = end != v && (*end == 'x' || *end == 'X') && !errno;
      if (ok) {
        const char *s = end + 1;
        h = strtoul(s, &end, 10);
        ok = end != s && *end == '\0' && !errno;
      }
      if (!ok || w < 1 || h < 1 || w > 16384 || h > 16384) {
        return bad_value("render", a, v, "takes WxH, each 1..16384");
      }
      rp.width = (uint32_t)w;
      rp.height = (uint32_t)h;
      i++;
    } else if (!strcmp(a, "--exposure") && v) {
      double x;
      if (!parse_real(v, &end, &x) || *end || fabs(x) > 64.0) {
        return bad_value("render", a, v, "takes an EV in [-64, 64]");
      }
      ev = (float)x;
      auto_exposure = 0;
      i++;
    } else if (!strcmp(a, "--samples") && v) {
      long n;
      if (!parse_uint(v, 16, &n) || n < 1) {
        return bad_value("render", a, v, "takes 1..16");
      }
      rp.samples = (uint32_t)n;
      i++;
    } else if ((sk = parse_state_arg("render", a, v, &state)) != 0 ||
               (sk = parse_records_arg("render", a, v, &load_flags)) != 0) {
      if (sk < 0) {
        return 1;
      }
      i++;
    } else if (a[0] == '-') {
      return bad_option("render", a, v);
    } else if (path) {
      return second_file("render", path, a);
    } else {
      path = a;
    }
  }
  if (!path || !have_camera || !out_png) {
    return usage_error("render", "need DIR/NAME.ubk, --camera and -o OUT.png");
  }
  size_t olen = strlen(out_png);
  if (olen < 4 || strcasecmp(out_png + olen - 4, ".png") != 0)
    return bad_value("render", "-o", out_png, "takes a path ending in .png (the image is "
                     "written as PNG)");
  cli_log_state ls = {0, CLI_INFO_STDERR, 0}; /* stdout: what was written, for scripts */
  ub_log log = {cli_log, &ls};
  if (ub_render_params_check(&rp, 0, &log) != UB_OK) {
    return 1;
  }
  double t0 = now_s();
  ub_runtime *rt = NULL;
  ub_result r = ub_runtime_load_ex(path, &log, load_flags, &rt);
  if (r != UB_OK) {
    return fail(&ls, r, path);
  }
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  uint32_t triangles = bf->triangle_count;
  double t_load = now_s() - t0;

  /* State: one RGB weight per dynamic light set, by name; default 1 (as baked), for the
   * run-time direct light of primary lights; doors and objects through the records. */
  float *weights = malloc(((size_t)bf->dls_count + 1) * 3 * sizeof *weights);
  if (!weights || apply_state(rt, &state, path)) {
    if (!weights)
      fprintf(stderr, "ubake: out of memory\n");
    free(weights);
    ub_runtime_free(rt);
    return 1;
  }
  for (uint32_t s = 0; s < bf->dls_count * 3; s++)
    weights[s] = 1.0f;
  for (uint32_t q = 0; q < state.count; q++)
    if (state.kind[q] == CLI_DLS)
      memcpy(&weights[3 * (size_t)ub_runtime_dls_find(rt, state.name[q])], state.rgb[q],
             3 * sizeof(float));
  if (r != UB_OK) {
    free(weights);
    ub_runtime_free(rt);
    return fail(&ls, r, path);
  }
  rp.dls_weights = weights;

  double t1 = now_s();
  ub_renderer *ren = NULL;
  r = ub_renderer_create(rt, &log, &ren);
  if (r != UB_OK) {
    free(weights);
    ub_runtime_free(rt);
    return fail(&ls, r, path);
  }
  double t_bvh = now_s() - t1;
  size_t npix = (size_t)rp.width * rp.height;
  float *rgb = malloc(npix * 3 * sizeof *rgb);
  uint8_t *srgb = malloc(npix * 3);
  if (!rgb || !srgb) {
    fprintf(stderr, "ubake: out of memory for a %ux%u image\n", rp.width, rp.height);
    free(rgb);
    free(srgb);
    ub_renderer_free(ren);
    free(weights);
    ub_runtime_free(rt);
    return 1;
  }
  /* Bands of rows, one per task: the renderer is thread safe over disjoint rows. */
  double t2 = now_s();
  const uint32_t band = 4;
  long bands = (long)((rp.height + band - 1) / band);
  int render_failed = 0;
#pragma omp parallel for schedule(dynamic, 1)
  for (long b = 0; b < bands; b++) {
    uint32_t y0 = (uint32_t)b * band, y1 = y0 + band < rp.height ? y0 + band : rp.height;
    if (ub_renderer_render(ren, &rp, y0, y1, rgb, NULL) != UB_OK) {
#pragma omp atomic write
      render_failed = 1;
    }
  }
  double t_render = now_s() - t2;
  /* A view that is mostly black for reasons other than light (a camera in a wall, outside
   * the level, looking away from it) gets a warning naming what the camera sees. */
  ub_render_view view = {1.0f, 0.0f, 0.0f};
  size_t lit = 0;
  if (!render_failed) {
    render_failed = ub_renderer_view(ren, &rp, 32, &view, &log) != UB_OK;
    for (size_t i = 0; i < npix * 3; i++)
      lit += rgb[i] > 0.0f;
  }
  float ev_used = ev;
  r = render_failed ? UB_ERR_INVALID_ARGUMENT
                    : ub_render_tonemap(rgb, rp.width, rp.height, auto_exposure, ev, srgb, &ev_used);
  uint32_t nodes = 0, depth = 0;
  ub_bvh_stats(ub_renderer_bvh(ren), &nodes, &depth);
  ub_renderer_free(ren);
  free(weights);
  ub_runtime_free(rt);
  free(rgb);
  if (r != UB_OK) {
    free(srgb);
    return fail(&ls, r, path);
  }
  size_t plen = strlen(out_png);
  char *tmp = malloc(plen + 5);
  int wrote = 0, err = ENOMEM; /* the cause, kept before remove() can change errno */
  if (tmp) {
    memcpy(tmp, out_png, plen);
    memcpy(tmp + plen, ".tmp", 5);
    errno = 0;
    wrote = stbi_write_png(tmp, (int)rp.width, (int)rp.height, 3, srgb, (int)rp.width * 3) != 0;
    err = errno ? errno : EIO;
    if (wrote && rename(tmp, out_png) != 0) {
      err = errno;
      wrote = 0;
    }
    if (!wrote)
      remove(tmp);
  }
  free(tmp);
  free(srgb);
  if (!wrote) {
    fprintf(stderr, "ubake: %s: cannot write the PNG (%s)\n", out_png, strerror(err));
    return 1;
  }
  printf("rendered %s: %ux%u, %u ray(s)/pixel, exposure %.2f EV (%s)\n", out_png, rp.width,
         rp.height, rp.samples * rp.samples, ev_used, auto_exposure ? "auto" : "fixed");
  if (view.front < 0.5f)
    fprintf(stderr,
            "ubake: warning: %s: only %.0f%% of the view meets front faces (%.0f%% back "
            "faces, rendered black; %.0f%% nothing): is the camera at (%g, %g, %g) inside a "
            "wall, outside the level or looking away from it?\n",
            out_png, 100.0 * view.front, 100.0 * view.back, 100.0 * view.miss, rp.eye[0],
            rp.eye[1], rp.eye[2]);
  else if (!lit)
    fprintf(stderr,
            "ubake: warning: %s: every pixel is black: no light reaches the surfaces the "
            "camera sees in this state\n",
            out_png);
  printf("load %.2f s, BVH %.3f s (%u triangles, %u nodes, depth %u), render %.3f s\n", t_load,
         t_bvh, triangles, nodes, depth, t_render);
  return 0;
}

/* ---- main -------------------------------------------------------------------------- */

static const char *MAIN_HELP =
    "usage: ubake COMMAND [options]   (ubake COMMAND --help for each)\n"
    "  bake       bake a glTF level into DIR/NAME.ubk + lightmaps + report\n"
    "  info       describe a .ubk\n"
    "  query      baked irradiance at a point and normal\n"
    "  reference  path-traced ground truth at a point and normal\n"
    "  render     PNG of the level from a camera, as the run-time shows it\n"
    "  sweep      accuracy vs bake time: a ladder of settings measured against ground truth\n"
    "  regress    door-opening regression: query vs reference, doors closed and open\n"
    "  spread     how far dynamic elements' records vary between bakes with other seeds\n";

int main(int argc, char **argv)
{
  if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h") ||
      !strcmp(argv[1], "help")) {
    fputs(MAIN_HELP, argc < 2 ? stderr : stdout);
    return argc < 2 ? 1 : 0;
  }
  const char *cmd = argv[1];
  if (!strcmp(cmd, "bake"))
    return cmd_bake(argc - 2, argv + 2);
  if (!strcmp(cmd, "info"))
    return cmd_info(argc - 2, argv + 2);
  if (!strcmp(cmd, "query"))
    return cmd_query(argc - 2, argv + 2);
  if (!strcmp(cmd, "reference"))
    return cmd_reference(argc - 2, argv + 2);
  if (!strcmp(cmd, "sweep")) return ub_cli_sweep(argc - 2, argv + 2);
  if (!strcmp(cmd, "regress")) return ub_cli_regress(argc - 2, argv + 2);
  if (!strcmp(cmd, "spread")) return ub_cli_spread(argc - 2, argv + 2);
  if (!strcmp(cmd, "render"))
    return cmd_render(argc - 2, argv + 2);
  fprintf(stderr, "ubake: unknown command '%s' (see 'ubake --help')\n", cmd);
  return 1;
}
