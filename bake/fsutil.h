/* bake/fsutil.h — file-system helpers the baker, its tools and its tests share. */
#ifndef UBAKE_BAKE_FSUTIL_H
#define UBAKE_BAKE_FSUTIL_H

/* Removes the entries of dir (files; folders only if empty: not recursive) and then dir.
 * Returns 0 when dir is gone, -1 otherwise (errno from the failing rmdir, or opendir). */
int ub_remove_dir(const char *dir);

#endif
