#include "ubake/error.h"

#include <stdarg.h>
#include <stdio.h>

const char *ub_result_string(ub_result r)
{
  switch (r) {
  case UB_OK: return "ok";
  case UB_ERR_INVALID_ARGUMENT: return "invalid argument";
  case UB_ERR_INVALID_DATA: return "invalid data";
  case UB_ERR_IO: return "i/o error";
  case UB_ERR_OUT_OF_MEMORY: return "out of memory";
  case UB_ERR_UNSUPPORTED_VERSION: return "unsupported version";
  case UB_ERR_CANCELLED: return "cancelled";
  case UB_ERR_NOT_BAKED: return "not baked";
  case UB_ERR_EXTERNAL: return "external tool failed";
  }
  return "unknown error";
}

void ub_log_printf(const ub_log *log, ub_log_level level, const char *fmt, ...)
{
  if (!log || !log->fn)
    return;
  char buf[1024];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(buf, sizeof buf, fmt, ap);
  va_end(ap);
  log->fn(log->user, level, buf);
}
