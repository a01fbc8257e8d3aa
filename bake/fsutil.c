/* bake/fsutil.c — see bake/fsutil.h. */
#include "bake/fsutil.h"

#include <dirent.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

int ub_remove_dir(const char *dir)
{
  DIR *d = opendir(dir);
  if (d) {
    struct dirent *e;
    char path[4096];
    while ((e = readdir(d)) != NULL) {
      if (!strcmp(e->d_name, ".") || !strcmp(e->d_name, ".."))
        continue;
      snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
      remove(path);
    }
    closedir(d);
  }
  return rmdir(dir) == 0 ? 0 : -1;
}
