/* bake/outdir.h — a bake's output folder: files are staged and renamed into place only
 * when every one of them was written.
 *
 * Owns: the output folder DIR (made with its missing parents when the bake starts, so a
 * bad one fails before hours of work), the staging folder DIR/.NAME.staging-PID every file
 * is written into, the report's temporary file next to a --json path (DIR_J/.BASE.tmp-PID:
 * renamed within its own file system, not from the staging folder), and the table of
 * (staged, final) paths of the files registered for the renames.
 * Lifecycle: ub_outdir_open() before the bake's first stage; ub_outdir_reserve() once,
 * then ub_outdir_add() / ub_outdir_add_report() per file, the caller writing each at the
 * staged path returned; ub_outdir_commit() renames them all into place; ub_outdir_close()
 * always: it removes whatever was not moved into place, and (unless committed) the folders
 * open made, while they are empty.
 * Errors: a call the file system fails logs one error naming the user's path (the final
 * one, never a staging path) and the cause, and returns UB_ERR_IO or
 * UB_ERR_INVALID_ARGUMENT; out of memory is UB_ERR_OUT_OF_MEMORY, no message. A failed open
 * leaves nothing behind. Open removes the staging folders of NAME in DIR and the report
 * temporaries next to the --json path that a process now gone left (SIGKILL, a crash), an
 * info line each.
 * Signals: while open, SIGINT and SIGTERM (where their action was the default) remove the
 * staged files, the temporaries and the folders open made, then kill the process as the
 * default action would; one that comes during the renames waits until they are done. Only
 * the process's first open outdir gets this: a handler reaches no context, so its owner is
 * the one global here. Everything the handler reads is a lock-free atomic, set before the
 * thing it names is made; the handler itself only unlinks and rmdirs.
 * Thread safety: one ub_outdir per bake, every call from the bake's thread. */
#ifndef UBAKE_BAKE_OUTDIR_H
#define UBAKE_BAKE_OUTDIR_H

#include <stddef.h>
#include <stdint.h>

#include "ubake/error.h"

typedef struct ub_outdir ub_outdir;

/* NAME of DIR/NAME.* for the level file at level_path: its file name without the extension,
 * into out (cap bytes; the .ubk's level-name field holds 63 and a NUL). A name that does not
 * fit whole is refused (UB_ERR_INVALID_ARGUMENT, a message naming the file and the limit):
 * cut short it could be another level's, whose files the bake would then overwrite. So is
 * an empty one. */
ub_result ub_outdir_level_name(const char *level_path, const ub_log *log, char *out,
                               size_t cap);

/* Opens the output of level_name (non-empty, no '/') in dir (non-empty): makes dir and the
 * folders above it that are missing, removes stale staging folders of the level, makes the
 * staging folder and, with json_path (NULL or non-empty), the report's temporary file next
 * to it. The caller checks the paths are not empty. On failure: one error naming dir (or
 * json_path) and the cause, nothing left behind, *out = NULL. */
ub_result ub_outdir_open(const char *dir, const char *level_name, const char *json_path,
                         const ub_log *log, ub_outdir **out);

/* Removes what od holds that was not moved into place (after a successful commit: only the
 * then empty staging folder), restores SIGINT/SIGTERM and frees od. NULL-safe. Folders open
 * made stay when they hold anything. */
void ub_outdir_close(ub_outdir *od);

/* The level's name open was given. */
const char *ub_outdir_name(const ub_outdir *od);

/* Room for count files; once, before the first add (the signal handler reads the table
 * without a lock, so it never moves). */
ub_result ub_outdir_reserve(ub_outdir *od, uint32_t count);

/* Registers DIR/file_name: *out_staged is where to write it, *out_final (if out_final is
 * not NULL) where commit puts it; both owned by od until close. From here on a signal or
 * close removes the staged file and its PATH.tmp. UB_ERR_OUT_OF_MEMORY, nothing logged. */
ub_result ub_outdir_add(ub_outdir *od, const char *file_name, const char **out_staged,
                        const char **out_final);

/* As ub_outdir_add for the report: DIR/file_name, or at open's json_path when it had one
 * (staged in its temporary file). */
ub_result ub_outdir_add_report(ub_outdir *od, const char *file_name, const char **out_staged);

/* A log forwarding every message to another one with od's staging paths (and the report's
 * temporary) replaced by the final ones: the writers name the files they write, the user knows the final paths. Set
 * up by ub_outdir_wrap_log, kept on the caller's stack (log.user points to it: not to be
 * copied); pass &.log. */
typedef struct ub_outdir_log {
  ub_log log;
  const ub_log *to;
  const ub_outdir *od;
} ub_outdir_log;

void ub_outdir_wrap_log(const ub_outdir *od, const ub_log *to, ub_outdir_log *out);

/* Every registered file is written: renames them into place (a folder in the way of a name
 * fails before the first rename), then removes the same level's NAME_lm<i> and
 * NAME_error<i> (.exr, .png; regular files only) for i >= atlas_count, which an earlier
 * bake with more atlases left, and the then empty staging folder. A rename that fails
 * midway leaves the files renamed before it in place. SIGINT/SIGTERM coming meanwhile wait
 * for the end of this, then clean up and kill the process. */
ub_result ub_outdir_commit(ub_outdir *od, uint32_t atlas_count, const ub_log *log);

#endif
