/* bake/outdir.c — see bake/outdir.h. The order of every step here is what makes an
 * interrupted or failed bake leave nothing: what the signal handler and ub_outdir_close
 * remove is published before the call that makes it. */
#include "bake/outdir.h"

#include <assert.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <sched.h>
#include <signal.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "bake/fsutil.h"

/* Output folders one open creates and removes again when the bake fails (deeper ones than
 * this stay, empty). */
#define UB_OUT_MAX_CREATED 32

/* A signal handler reads these: atomics must not take a lock there. */
_Static_assert(ATOMIC_POINTER_LOCK_FREE == 2 && ATOMIC_INT_LOCK_FREE == 2,
               "lock-free atomics are needed in the signal handler");

typedef struct out_file {
  char *staged; /* where it is written: the staging folder, or the report's temporary */
  char *final;  /* where it goes */
} out_file;

struct ub_outdir {
  char *dir;        /* the output folder as given */
  char *name;       /* the level's name: DIR/NAME.ubk */
  char *staging;    /* DIR/.NAME.staging-PID */
  char *json;       /* the --json path, or NULL */
  char *report_tmp; /* next to json: DIR_J/.BASE.tmp-PID, or NULL */
  char *created[UB_OUT_MAX_CREATED]; /* folders open made, outermost first */
  /* What exists, for ub_outdir_close and the signal handler: each set just before the
   * call that makes the thing it names (a signal during a call is handled as the call
   * returns), cleared again when that call failed; the strings are set before. */
  atomic_uint created_count;
  atomic_int staging_made, report_tmp_made;
  out_file *files; /* file_cap entries, published before file_count leaves 0 */
  uint32_t file_cap;
  atomic_uint file_count;
  atomic_int committing; /* renaming into place: a signal waits for the end (pending) */
  atomic_int committed;  /* everything in place: the created folders stay */
  atomic_int pending;    /* a signal that came while committing, 0 = none */
  int signal_owner;      /* this bake's temporaries are the ones a signal removes */
  int installed[2];      /* our handler is on sig_nums[k] */
};

/* ---- SIGINT / SIGTERM --------------------------------------------------------------------
 * A handler reaches no context, so the bake whose temporaries it removes is the one global
 * state here (the first of the process's bakes open at a time). */
static const int sig_nums[2] = {SIGINT, SIGTERM};
static _Atomic(ub_outdir *) sig_owner;
static atomic_int sig_running; /* handlers between reading sig_owner and being done with it */

/* unlink(p) and unlink(p ".tmp") (the image and .ubk writers write PATH.tmp first). Async-
 * signal-safe: no allocation, no stdio. */
static void unlink_with_tmp(const char *p)
{
  char t[PATH_MAX + 8];
  size_t n = 0;
  unlink(p);
  while (p[n] && n < PATH_MAX)
    n++;
  if (p[n])
    return;
  memcpy(t, p, n);
  memcpy(t + n, ".tmp", 5);
  unlink(t);
}

/* Removes the staged files, the report's temporary, the staging folder and (unless the
 * bake is in place) the folders open created while they are empty. Async-signal-safe. */
static void remove_temporaries(ub_outdir *o)
{
  unsigned n = atomic_load(&o->file_count);
  for (unsigned i = 0; i < n; i++)
    unlink_with_tmp(o->files[i].staged);
  if (atomic_load(&o->report_tmp_made))
    unlink(o->report_tmp);
  if (atomic_load(&o->staging_made))
    rmdir(o->staging);
  if (!atomic_load(&o->committed))
    for (unsigned i = atomic_load(&o->created_count); i-- > 0;)
      rmdir(o->created[i]);
}

/* sig back to its default action. Async-signal-safe. */
static void default_action(int sig)
{
  struct sigaction dfl;
  memset(&dfl, 0, sizeof dfl);
  dfl.sa_handler = SIG_DFL;
  sigemptyset(&dfl.sa_mask);
  sigaction(sig, &dfl, NULL);
}

static void kill_self(int sig)
{
  default_action(sig);
  raise(sig); /* delivered as the handler returns: "killed by signal", as without us */
}

static void on_signal(int sig)
{
  int saved_errno = errno;
  atomic_fetch_add(&sig_running, 1);
  ub_outdir *o = atomic_load(&sig_owner);
  if (o && atomic_load(&o->committing)) {
    /* Renaming into place (milliseconds): finish it, then die (deliver_pending). */
    atomic_store(&o->pending, sig);
    atomic_fetch_sub(&sig_running, 1);
    errno = saved_errno;
    return;
  }
  if (o)
    remove_temporaries(o);
  kill_self(sig);
  atomic_fetch_sub(&sig_running, 1); /* after: the bake's thread waits for us to be done */
  errno = saved_errno;
}

/* Takes the signal cleanup when no other bake of this process holds it, and installs the
 * handler on the signals whose action is the default (an ignored or caught signal is the
 * program's own business: its cancel path ends in ub_outdir_close). */
static void claim_signals(ub_outdir *o)
{
  ub_outdir *none = NULL;
  if (!atomic_compare_exchange_strong(&sig_owner, &none, o))
    return;
  o->signal_owner = 1;
  for (int k = 0; k < 2; k++) {
    struct sigaction cur, sa;
    if (sigaction(sig_nums[k], NULL, &cur) != 0 || (cur.sa_flags & SA_SIGINFO) ||
        cur.sa_handler != SIG_DFL)
      continue;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaddset(&sa.sa_mask, SIGINT);
    sigaddset(&sa.sa_mask, SIGTERM);
    sa.sa_flags = SA_RESTART;
    o->installed[k] = sigaction(sig_nums[k], &sa, NULL) == 0;
  }
}

static void release_signals(ub_outdir *o)
{
  if (!o->signal_owner)
    return;
  for (int k = 0; k < 2; k++)
    if (o->installed[k])
      default_action(sig_nums[k]);
  atomic_store(&sig_owner, NULL);
  while (atomic_load(&sig_running)) /* a handler in another thread is about to kill us */
    sched_yield();
  o->signal_owner = 0;
}

/* A signal that came while the files were renamed into place: now that they are, die. */
static void deliver_pending(ub_outdir *o)
{
  int sig = atomic_load(&o->pending);
  if (!sig)
    return;
  remove_temporaries(o);
  kill_self(sig);
}

/* ---- folders and names ----------------------------------------------------------------- */

/* The formatted path (malloc; "%s/%s" joins two); NULL when out of memory. */
static char *path_printf(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static char *path_printf(const char *fmt, ...)
{
  va_list ap;
  va_start(ap, fmt);
  int n = vsnprintf(NULL, 0, fmt, ap);
  va_end(ap);
  char *p = n >= 0 ? malloc((size_t)n + 1) : NULL;
  if (p) {
    va_start(ap, fmt);
    vsnprintf(p, (size_t)n + 1, fmt, ap);
    va_end(ap);
  }
  return p;
}

/* Creates o->dir and the folders above it that are missing (recording those it made). A
 * path that exists but is not a folder is an error, not "exists". */
static ub_result make_folders(ub_outdir *o, const ub_log *log)
{
  char *buf = strdup(o->dir);
  if (!buf)
    return UB_ERR_OUT_OF_MEMORY;
  size_t n = strlen(buf);
  ub_result r = UB_OK;
  for (size_t i = 1; i <= n && r == UB_OK; i++) {
    if (i < n && (buf[i] != '/' || buf[i - 1] == '/'))
      continue;
    char c = buf[i];
    buf[i] = '\0';
    struct stat st;
    int e = 0;
    if (stat(buf, &st) == 0) {
      e = S_ISDIR(st.st_mode) ? 0 : ENOTDIR;
    } else {
      /* Recorded before mkdir: a signal during the call is handled as it returns, and the
       * handler must see the folder to remove it. */
      unsigned k = atomic_load(&o->created_count);
      int rec = k < UB_OUT_MAX_CREATED && (o->created[k] = strdup(buf)) != NULL;
      if (rec)
        atomic_store(&o->created_count, k + 1);
      if (mkdir(buf, 0777) != 0) {
        e = errno;
        if (rec) {
          atomic_store(&o->created_count, k);
          free(o->created[k]);
          o->created[k] = NULL;
        }
        if (e == EEXIST) /* made meanwhile by someone else */
          e = stat(buf, &st) == 0 && S_ISDIR(st.st_mode) ? 0 : ENOTDIR;
      }
    }
    if (e == ENOTDIR && i == n)
      ub_log_printf(log, UB_LOG_ERROR, "%s: cannot use as the output folder: it exists and is "
                    "not a folder", o->dir);
    else if (e == ENOTDIR)
      ub_log_printf(log, UB_LOG_ERROR, "%s: cannot create the output folder: %s is not a "
                    "folder", o->dir, buf);
    else if (e && i == n)
      ub_log_printf(log, UB_LOG_ERROR, "%s: cannot create the output folder: %s", o->dir,
                    strerror(e));
    else if (e)
      ub_log_printf(log, UB_LOG_ERROR, "%s: cannot create the output folder: %s: %s", o->dir,
                    buf, strerror(e));
    if (e)
      r = UB_ERR_IO;
    buf[i] = c;
  }
  free(buf);
  return r;
}

/* Removes dir's entries named PREFIX<pid> (decimal) whose process is gone: folders (a
 * staging folder) or regular files (a report's temporary), what a bake killed before it
 * could clean up (SIGKILL, a crash, power) left. own_gone: this process's own PID counts
 * as gone (no other bake of this process is open: a PID reused, say in a container). A PID
 * of another PID namespace sharing the folder looks gone too. */
static void remove_stale(const char *dir, const char *prefix, int folders, int own_gone,
                         const ub_log *log)
{
  DIR *d = opendir(dir);
  if (!d)
    return;
  size_t plen = strlen(prefix);
  struct dirent *e;
  while ((e = readdir(d)) != NULL) {
    if (strncmp(e->d_name, prefix, plen) != 0)
      continue;
    const char *num = e->d_name + plen;
    long pid = 0;
    size_t k = 0;
    for (; num[k] >= '0' && num[k] <= '9' && k < 10; k++)
      pid = pid * 10 + (num[k] - '0');
    if (k == 0 || num[k] || num[0] == '0' || pid > INT_MAX)
      continue;
    if (pid == (long)getpid() ? !own_gone : !(kill((pid_t)pid, 0) != 0 && errno == ESRCH))
      continue; /* alive (or not ours to judge: EPERM means it exists) */
    char *path = path_printf("%s/%s", dir, e->d_name);
    struct stat st;
    if (path && lstat(path, &st) == 0 && (folders ? S_ISDIR(st.st_mode) : S_ISREG(st.st_mode))) {
      if ((folders ? ub_remove_dir(path) : unlink(path)) == 0)
        ub_log_printf(log, UB_LOG_INFO, "  removed %s, left by a bake that was stopped "
                      "(process %ld is gone)", path, pid);
      else
        ub_log_printf(log, UB_LOG_WARNING, "%s: cannot remove what a stopped bake left: %s",
                      path, strerror(errno));
    }
    free(path);
  }
  closedir(d);
}

/* The report's temporary file next to the --json path, made now so that a missing or
 * unwritable folder fails before the bake, and renamed within its own file system later. */
static ub_result open_report_tmp(ub_outdir *o, int own_gone, const ub_log *log)
{
  const char *slash = strrchr(o->json, '/');
  const char *base = slash ? slash + 1 : o->json;
  struct stat st;
  if (!*base || (stat(o->json, &st) == 0 && S_ISDIR(st.st_mode))) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write the report there: it is a folder",
                  o->json);
    return UB_ERR_INVALID_ARGUMENT;
  }
  char *jdir = slash == o->json ? strdup("/")
               : slash ? path_printf("%.*s", (int)(slash - o->json), o->json) : strdup(".");
  char *prefix = path_printf(".%s.tmp-", base);
  o->report_tmp = jdir ? path_printf("%s/%s%ld", jdir, prefix ? prefix : "", (long)getpid())
                       : NULL;
  if (!jdir || !prefix || !o->report_tmp) {
    free(jdir);
    free(prefix);
    return UB_ERR_OUT_OF_MEMORY;
  }
  remove_stale(jdir, prefix, 0, own_gone, log);
  free(jdir);
  free(prefix);
  atomic_store(&o->report_tmp_made, 1); /* before open: see make_folders */
  int fd = open(o->report_tmp, O_WRONLY | O_CREAT | O_TRUNC, 0666);
  if (fd < 0) {
    int e = errno;
    atomic_store(&o->report_tmp_made, 0);
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write the report there: %s", o->json,
                  strerror(e));
    return UB_ERR_IO;
  }
  close(fd);
  return UB_OK;
}

ub_result ub_outdir_level_name(const char *level_path, const ub_log *log, char *out,
                               size_t cap)
{
  const char *base = strrchr(level_path, '/');
  base = base ? base + 1 : level_path;
  const char *dot = strrchr(base, '.');
  size_t n = dot && dot != base ? (size_t)(dot - base) : strlen(base);
  if (n == 0) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: no file name to name the bake's files after",
                  level_path);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (n >= cap) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: the level's name (the file name without its "
                  "extension) is %zu bytes; at most %zu fit in the .ubk", level_path, n,
                  cap - 1);
    return UB_ERR_INVALID_ARGUMENT;
  }
  memcpy(out, base, n);
  out[n] = '\0';
  return UB_OK;
}

ub_result ub_outdir_open(const char *dir, const char *level_name, const char *json_path,
                         const ub_log *log, ub_outdir **out)
{
  assert(dir && *dir && level_name && *level_name && !strchr(level_name, '/'));
  assert(!json_path || *json_path);
  *out = NULL;
  ub_outdir *o = calloc(1, sizeof *o);
  if (!o)
    return UB_ERR_OUT_OF_MEMORY;
  ub_result r = UB_ERR_OUT_OF_MEMORY;
  o->dir = strdup(dir);
  o->name = strdup(level_name);
  o->staging = path_printf("%s/.%s.staging-%ld", dir, level_name, (long)getpid());
  o->json = json_path ? strdup(json_path) : NULL;
  if (!o->dir || !o->name || !o->staging || (json_path && !o->json))
    goto fail;
  claim_signals(o); /* before the first thing made: a signal from here on removes it */

  r = make_folders(o, log);
  if (r != UB_OK)
    goto fail;
  char *prefix = path_printf(".%s.staging-", level_name);
  if (!prefix) {
    r = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }
  remove_stale(dir, prefix, 1, o->signal_owner, log);
  free(prefix);
  atomic_store(&o->staging_made, 1); /* before mkdir: see make_folders */
  if (mkdir(o->staging, 0777) != 0) {
    int e = errno;
    atomic_store(&o->staging_made, 0);
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write into the output folder: %s", dir,
                  strerror(e));
    r = UB_ERR_IO;
    goto fail;
  }
  if (o->json) {
    r = open_report_tmp(o, o->signal_owner, log);
    if (r != UB_OK)
      goto fail;
  }
  *out = o;
  return UB_OK;
fail:
  ub_outdir_close(o);
  return r;
}

void ub_outdir_close(ub_outdir *o)
{
  if (!o)
    return;
  /* The staging folder with anything else a writer left in it, then the rest. */
  if (atomic_load(&o->staging_made) && ub_remove_dir(o->staging) == 0)
    atomic_store(&o->staging_made, 0);
  remove_temporaries(o);
  release_signals(o);
  for (unsigned i = 0; i < atomic_load(&o->file_count); i++) {
    free(o->files[i].staged);
    free(o->files[i].final);
  }
  free(o->files);
  for (unsigned i = 0; i < atomic_load(&o->created_count); i++)
    free(o->created[i]);
  free(o->dir);
  free(o->name);
  free(o->staging);
  free(o->json);
  free(o->report_tmp);
  free(o);
}

const char *ub_outdir_name(const ub_outdir *o)
{
  return o->name;
}

ub_result ub_outdir_reserve(ub_outdir *o, uint32_t count)
{
  /* Published before any entry: the signal handler reads it once file_count > 0. */
  assert(!o->files);
  o->file_cap = count;
  o->files = calloc(o->file_cap, sizeof *o->files);
  return o->files ? UB_OK : UB_ERR_OUT_OF_MEMORY;
}

/* Registers a file to write: staged (the staging folder, or the given temporary) and final
 * path; the signal handler removes it from here on. 0 when out of memory. */
static int add_file(ub_outdir *o, const char *name, const char *staged, const char *final)
{
  unsigned n = atomic_load(&o->file_count);
  assert(n < o->file_cap);
  out_file *f = &o->files[n];
  f->staged = staged ? strdup(staged) : path_printf("%s/%s", o->staging, name);
  f->final = final ? strdup(final) : path_printf("%s/%s", o->dir, name);
  if (!f->staged || !f->final) {
    free(f->staged);
    free(f->final);
    f->staged = f->final = NULL;
    return 0;
  }
  atomic_store(&o->file_count, n + 1);
  return 1;
}

ub_result ub_outdir_add(ub_outdir *o, const char *file_name, const char **out_staged,
                        const char **out_final)
{
  if (!add_file(o, file_name, NULL, NULL))
    return UB_ERR_OUT_OF_MEMORY;
  const out_file *f = &o->files[atomic_load(&o->file_count) - 1];
  *out_staged = f->staged;
  if (out_final)
    *out_final = f->final;
  return UB_OK;
}

ub_result ub_outdir_add_report(ub_outdir *o, const char *file_name, const char **out_staged)
{
  /* At a --json path, into the temporary file next to it (a rename from the staging folder
   * could cross file systems). */
  if (!add_file(o, file_name, o->report_tmp, o->json))
    return UB_ERR_OUT_OF_MEMORY;
  *out_staged = o->files[atomic_load(&o->file_count) - 1].staged;
  return UB_OK;
}

/* in with every "from" replaced by "to", into out (cap bytes); 0 when it does not fit. */
static int replace_all(const char *in, const char *from, const char *to, char *out, size_t cap)
{
  size_t nf = strlen(from), nt = strlen(to), k = 0;
  if (!nf)
    return 0;
  while (*in) {
    if (!strncmp(in, from, nf)) {
      if (k + nt >= cap)
        return 0;
      memcpy(out + k, to, nt);
      k += nt;
      in += nf;
    } else {
      if (k + 1 >= cap)
        return 0;
      out[k++] = *in++;
    }
  }
  out[k] = '\0';
  return 1;
}

static void final_path_log_fn(void *user, ub_log_level level, const char *msg)
{
  const ub_outdir_log *fl = user;
  const ub_outdir *o = fl->od;
  char a[2048], b[2048], from[PATH_MAX + 2], to[PATH_MAX + 2];
  const char *m = msg;
  snprintf(from, sizeof from, "%s/", o->staging);
  snprintf(to, sizeof to, "%s/", o->dir);
  if (replace_all(m, from, to, a, sizeof a))
    m = a;
  if (o->report_tmp && replace_all(m, o->report_tmp, o->json, b, sizeof b))
    m = b;
  if (fl->to && fl->to->fn)
    fl->to->fn(fl->to->user, level, m);
}

void ub_outdir_wrap_log(const ub_outdir *od, const ub_log *to, ub_outdir_log *out)
{
  out->log.fn = final_path_log_fn;
  out->log.user = out;
  out->to = to;
  out->od = od;
}

/* NAME_lm<i>.exr/.png or NAME_error<i>.exr/.png (i as "%u" writes it) with i >= count. */
static int stale_atlas_file(const char *entry, const char *name, uint32_t count)
{
  size_t n = strlen(name);
  if (strncmp(entry, name, n) != 0 || entry[n] != '_')
    return 0;
  const char *p = entry + n + 1;
  if (!strncmp(p, "lm", 2))
    p += 2;
  else if (!strncmp(p, "error", 5))
    p += 5;
  else
    return 0;
  if (!(*p >= '0' && *p <= '9') || (p[0] == '0' && p[1] >= '0' && p[1] <= '9'))
    return 0;
  unsigned long long i = 0;
  for (int d = 0; *p >= '0' && *p <= '9'; p++, d++) {
    if (d >= 10)
      return 0;
    i = 10 * i + (unsigned)(*p - '0');
  }
  return (!strcmp(p, ".exr") || !strcmp(p, ".png")) && i >= count;
}

/* After a bake with fewer atlases than the last one in this folder: its NAME_lm<i> and
 * NAME_error<i> for the atlases the new bake does not have would sit next to the new .ubk
 * as if they were its. Regular files of exactly those names only. */
static void remove_stale_atlases(const ub_outdir *o, uint32_t atlas_count, const ub_log *log)
{
  DIR *d = opendir(o->dir);
  if (!d)
    return;
  uint32_t removed = 0;
  char first[256] = "";
  struct dirent *e;
  while ((e = readdir(d)) != NULL) {
    if (!stale_atlas_file(e->d_name, o->name, atlas_count))
      continue;
    char *path = path_printf("%s/%s", o->dir, e->d_name);
    struct stat st;
    if (path && lstat(path, &st) == 0 && S_ISREG(st.st_mode)) {
      if (unlink(path) == 0) {
        if (!removed++)
          snprintf(first, sizeof first, "%s", e->d_name);
      } else {
        ub_log_printf(log, UB_LOG_WARNING, "%s: cannot remove this file of an earlier bake "
                      "with more atlases: %s", path, strerror(errno));
      }
    }
    free(path);
  }
  closedir(d);
  if (removed)
    ub_log_printf(log, UB_LOG_INFO, "  removed %u file(s) of an earlier bake of %s with more "
                  "atlases than %u (%s%s)", removed, o->name, atlas_count, first,
                  removed > 1 ? ", ..." : "");
}

/* Nothing that can fail for lack of room or a bad folder is left here; a folder in the way
 * of a name is found before the first rename. */
ub_result ub_outdir_commit(ub_outdir *o, uint32_t atlas_count, const ub_log *log)
{
  unsigned n = atomic_load(&o->file_count);
  for (unsigned i = 0; i < n; i++) {
    struct stat st;
    if (lstat(o->files[i].final, &st) == 0 && S_ISDIR(st.st_mode)) {
      ub_log_printf(log, UB_LOG_ERROR, "%s: cannot replace a folder with the bake's file",
                    o->files[i].final);
      return UB_ERR_IO;
    }
  }
  atomic_store(&o->committing, 1);
  while (atomic_load(&sig_running)) /* a handler that missed "committing" is killing us */
    sched_yield();
  ub_result r = UB_OK;
  for (unsigned i = 0; i < n && r == UB_OK; i++)
    if (rename(o->files[i].staged, o->files[i].final) != 0) {
      ub_log_printf(log, UB_LOG_ERROR, "%s: cannot move into place: %s", o->files[i].final,
                    strerror(errno));
      r = UB_ERR_IO;
    }
  if (r == UB_OK) {
    atomic_store(&o->committed, 1);
    atomic_store(&o->report_tmp_made, 0); /* renamed */
    remove_stale_atlases(o, atlas_count, log);
    if (rmdir(o->staging) == 0)
      atomic_store(&o->staging_made, 0);
  }
  atomic_store(&o->committing, 0);
  deliver_pending(o);
  return r;
}
